"""Random flat leaves in a periodic plot: the analytic validation canopy.

``N`` flat leaves of one-sided area ``a`` are placed independently with centres
uniform in the plot ``[0, w] × [0, l]`` and heights uniform in ``[z0, z1]``. Their
normals follow a leaf-angle law. For such a canopy the expected gap fraction in
direction θ is exactly ``(1 − a·G(θ)/(A·cos θ))^N`` with ``A = w·l`` (see
``notes/science.md``), provided the plot is seen as a torus; this module makes the
plot periodic by copying every leaf that crosses an edge to the opposite side.

Leaf-angle laws (θ_L = zenith of the upper-side normal, φ_L its azimuth)
-----------------------------------------------------------------------
``'horizontal'``  θ_L = 0 (G(θ) = cos θ).
``'vertical'``    θ_L = 90°, φ_L uniform (G(θ) = (2/π) sin θ).
``'spherical'``   normals uniform on the upper hemisphere: cos θ_L uniform in
                  [0, 1], i.e. density sin θ_L on [0, π/2], φ_L uniform (G = 0.5).

Shapes
------
``'square'``  2 triangles, side ``√a``.
``'disc'``    a regular ``n_sides``-gon fan (``n_sides`` triangles) whose circumradius
              ``r = √(2a / (k·sin(2π/k)))`` makes its area exactly ``a``.
Every leaf also gets a uniform random rotation in its own plane.

Periodicity
-----------
Leaves are wrapped: a leaf whose vertices cross ``x = 0`` (``x = w``) is duplicated
shifted by ``+w`` (``−w``), likewise in ``y`` with ``l``, and a leaf crossing a corner
gets the diagonal copy too. Within the plot's vertical prism the canopy then tiles
seamlessly; a renderer should window the central plot ``[0, w] × [0, l]``. For
oblique views rays also cross the prism's sides: use :meth:`RandomLeavesCanopy.tiled`
(whole copies of the plot around it) or keep the window at least
``(z1 + leaf size)·tan θ`` from the edges. Leaves near the top or bottom of the
height range may extend slightly beyond ``[z0, z1]`` (by their radius).

Lengths in metres, angles in degrees at the API, radians inside. No Mitsuba.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..config.checks import real as _real
from ..config.checks import seed_sequence as _root_seed
from ..errors import ConfigError
from ..geometry import Leaves

__all__ = ["RandomLeavesParams", "RandomLeavesCanopy", "random_leaves",
           "random_leaves_from_params", "periodic_copies",
           "ANGLE_LAWS", "SHAPES", "G_FUNCTIONS"]

ANGLE_LAWS = ("horizontal", "vertical", "spherical")
SHAPES = ("square", "disc")

#: Analytic G(θ) (θ in radians) of each leaf-angle law, for tests and references.
G_FUNCTIONS = {
    "horizontal": lambda t: np.cos(t),
    "vertical": lambda t: (2.0 / np.pi) * np.sin(t),
    "spherical": lambda t: 0.5 + 0.0 * np.asarray(t, float),
}


def _pair(key: str, value) -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ConfigError("must be a pair of numbers", key=key, value=value) from None
    return _real(key, a), _real(key, b)


@dataclass(frozen=True)
class RandomLeavesParams:
    """Validated settings of a random-leaves canopy (see the module docstring).

    Parameters
    ----------
    n_leaves : int
        Number of leaves N (≥ 0), before periodic copies.
    leaf_area_m2 : float
        One-sided area a of every leaf, m² (> 0).
    plot_size_m : (float, float)
        Plot width w (x) and length l (y), metres (> 0).
    height_range_m : (float, float)
        Leaf-centre heights are uniform in [z0, z1], metres (z0 ≤ z1).
    angle_law : {'horizontal', 'vertical', 'spherical'}
    shape : {'square', 'disc'}
    n_sides : int
        Polygon sides for ``shape='disc'`` (≥ 3).
    """

    n_leaves: int
    leaf_area_m2: float
    plot_size_m: tuple[float, float] = (1.0, 1.0)
    height_range_m: tuple[float, float] = (0.0, 1.0)
    angle_law: str = "spherical"
    shape: str = "square"
    n_sides: int = 16

    def __post_init__(self) -> None:
        n = self.n_leaves
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ConfigError("must be an integer >= 0", key="n_leaves", value=n)
        object.__setattr__(self, "n_leaves", int(n))
        a = _real("leaf_area_m2", self.leaf_area_m2)
        if a <= 0:
            raise ConfigError("must be > 0", key="leaf_area_m2", value=self.leaf_area_m2)
        object.__setattr__(self, "leaf_area_m2", a)
        w, l = _pair("plot_size_m", self.plot_size_m)
        if w <= 0 or l <= 0:
            raise ConfigError("both sizes must be > 0", key="plot_size_m",
                              value=self.plot_size_m)
        object.__setattr__(self, "plot_size_m", (w, l))
        z0, z1 = _pair("height_range_m", self.height_range_m)
        if z1 < z0:
            raise ConfigError("must be (z_min, z_max) with z_min <= z_max",
                              key="height_range_m", value=self.height_range_m)
        object.__setattr__(self, "height_range_m", (z0, z1))
        if self.angle_law not in ANGLE_LAWS:
            raise ConfigError(f"must be one of {ANGLE_LAWS}", key="angle_law",
                              value=self.angle_law)
        if self.shape not in SHAPES:
            raise ConfigError(f"must be one of {SHAPES}", key="shape", value=self.shape)
        k = self.n_sides
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 3:
            raise ConfigError("must be an integer >= 3", key="n_sides", value=k)
        object.__setattr__(self, "n_sides", int(k))
        # A leaf wider than the plot would need copies beyond the neighbouring tiles.
        if 2.0 * self.leaf_radius_m >= min(w, l):
            raise ConfigError(
                f"a leaf of {a} m² ({2 * self.leaf_radius_m:.4g} m across) must be "
                f"smaller than the plot {w} × {l} m", key="leaf_area_m2", value=a)

    @property
    def leaf_radius_m(self) -> float:
        """Largest distance from a leaf's centre to its corners, metres."""
        if self.shape == "square":
            return math.sqrt(self.leaf_area_m2 / 2.0)
        k = self.n_sides
        return math.sqrt(2.0 * self.leaf_area_m2 / (k * math.sin(2.0 * math.pi / k)))

    @property
    def lai(self) -> float:
        """N·a / (w·l)."""
        w, l = self.plot_size_m
        return self.n_leaves * self.leaf_area_m2 / (w * l)


@dataclass(frozen=True)
class RandomLeavesCanopy:
    """A random-leaves canopy.

    Attributes
    ----------
    leaves : Leaves
        The ``N`` original leaves first (``leaf_id`` 0…N−1, triangles grouped by
        leaf), then the periodic copies, which keep the ``leaf_id`` of the leaf they
        copy. ``plant_id`` is 0 throughout (there are no plants).
    is_copy : (n_triangles,) bool
        True for triangles of periodic copies.
    centres_m : (N, 3) float64
        Leaf centres, metres.
    normals : (N, 3) float64
        Unit upper-side normals (z ≥ 0) of the original leaves.
    bounds_m : tuple of 4 floats
        Plot ``(x_min, y_min, x_max, y_max)`` = ``(0, 0, w, l)``, metres.
    params : RandomLeavesParams
    seed_entropy : int or tuple of int
        Entropy of the ``SeedSequence`` that produced the canopy.
    """

    leaves: Leaves
    is_copy: np.ndarray
    centres_m: np.ndarray
    normals: np.ndarray
    bounds_m: tuple[float, float, float, float]
    params: RandomLeavesParams
    seed_entropy: int | tuple[int, ...]

    @property
    def lai(self) -> float:
        """Leaf area index N·a/(w·l) (copies not counted)."""
        return self.params.lai

    @property
    def ground_area_m2(self) -> float:
        w, l = self.params.plot_size_m
        return w * l

    @property
    def originals(self) -> Leaves:
        """The N leaves without periodic copies."""
        return self.leaves.subset(~self.is_copy)

    @property
    def n_copies(self) -> int:
        """Number of periodic copies (leaves, not triangles)."""
        return int(self.is_copy.sum()) // _triangles_per_leaf(self.params)

    def tiled(self, reps: int = 1) -> Leaves:
        """The original leaves repeated on a ``(2·reps+1)²`` grid of plots around the plot.

        For oblique views: every ray that ends in the central plot and crosses the
        canopy within ``reps`` plot widths of it sees the periodic canopy.
        """
        if isinstance(reps, bool) or not isinstance(reps, (int, np.integer)) or reps < 0:
            raise ConfigError("must be an integer >= 0", key="reps", value=reps)
        w, l = self.params.plot_size_m
        base = self.originals
        k = np.arange(-reps, reps + 1)
        shifts = np.stack(np.meshgrid(k * w, k * l, indexing="ij"), -1).reshape(-1, 2)
        off = np.concatenate([shifts, np.zeros((len(shifts), 1))], axis=1)
        verts = (base.vertices[None] + off[:, None, None, :]).reshape(-1, 3, 3)
        return Leaves(verts, np.tile(base.leaf_id, len(off)), np.tile(base.plant_id, len(off)))


def _triangles_per_leaf(p: RandomLeavesParams) -> int:
    return 2 if p.shape == "square" else p.n_sides


def _template(p: RandomLeavesParams) -> np.ndarray:
    """Triangles (k, 3, 3) of one leaf of area a centred at the origin in z = 0."""
    a = p.leaf_area_m2
    if p.shape == "square":
        h = 0.5 * math.sqrt(a)
        c = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
        return np.stack([c[[0, 1, 2]], c[[0, 2, 3]]])
    k = p.n_sides
    r = p.leaf_radius_m
    t = 2.0 * np.pi * np.arange(k + 1) / k
    ring = np.stack([r * np.cos(t), r * np.sin(t), np.zeros(k + 1)], axis=1)
    return np.stack([np.zeros((k, 3)), ring[:-1], ring[1:]], axis=1)


def _rotations(theta: np.ndarray, phi: np.ndarray, spin: np.ndarray) -> np.ndarray:
    """Matrices Rz(φ)·Ry(θ)·Rz(spin): maps +z to the normal (θ, φ)."""
    def rz(t):
        c, s, o, z = np.cos(t), np.sin(t), np.ones_like(t), np.zeros_like(t)
        return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                         np.stack([z, z, o], -1)], -2)

    c, s, o, z = np.cos(theta), np.sin(theta), np.ones_like(theta), np.zeros_like(theta)
    ry = np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                   np.stack([-s, z, c], -1)], -2)
    return rz(phi) @ ry @ rz(spin)


def periodic_copies(leaf_vertices: np.ndarray, plot_size_m: Sequence[float],
                    origin_m: Sequence[float] = (0.0, 0.0), recentre: bool = False):
    """Copies of leaves that cross the edges of a periodic plot.

    Parameters
    ----------
    leaf_vertices : (N, k, 3, 3) float64
        ``k`` triangles per leaf, metres.
    plot_size_m : (w, l)
        Plot size, metres.
    origin_m : (x0, y0)
        Lower corner of the plot, metres.
    recentre : bool
        First shift every leaf by whole plot sizes so the mean of its vertices lies
        in the plot (for leaves not generated inside it, e.g. projected ones).

    Returns
    -------
    vertices : (N + M, k, 3, 3) float64
        The (recentred) leaves followed by the ``M`` copies.
    source : (N + M,) int64
        Index of the original leaf of every row.
    is_copy : (N + M,) bool
    """
    v = np.asarray(leaf_vertices, float).copy()
    w, l = (float(s) for s in plot_size_m)
    x0, y0 = (float(o) for o in origin_m)
    size = np.array([w, l])
    lo = np.array([x0, y0])
    n = len(v)
    if n == 0:
        return v, np.zeros(0, np.int64), np.zeros(0, bool)
    if recentre:
        mean = v[..., :2].reshape(n, -1, 2).mean(axis=1)
        shift = np.floor((mean - lo) / size) * size
        v[..., :2] -= shift[:, None, None, :]
    xy = v[..., :2].reshape(n, -1, 2)
    vmin, vmax = xy.min(axis=1), xy.max(axis=1)
    # Shift for the copy on each axis: +size when the leaf sticks out below the
    # lower edge, −size when it sticks out above the upper edge, 0 otherwise.
    s = np.where(vmin < lo, size, 0.0) + np.where(vmax > lo + size, -size, 0.0)
    need = s != 0
    groups = [(need[:, 0], np.stack([s[:, 0], np.zeros(n)], 1)),
              (need[:, 1], np.stack([np.zeros(n), s[:, 1]], 1)),
              (need[:, 0] & need[:, 1], s)]
    verts, src, flag = [v], [np.arange(n)], [np.zeros(n, bool)]
    for mask, shift in groups:
        idx = np.flatnonzero(mask)
        c = v[idx].copy()
        c[..., :2] += shift[idx][:, None, None, :]
        verts.append(c)
        src.append(idx)
        flag.append(np.ones(len(idx), bool))
    return np.concatenate(verts), np.concatenate(src), np.concatenate(flag)


def random_leaves_from_params(params: RandomLeavesParams,
                              seed: int | np.random.SeedSequence | None = None
                              ) -> RandomLeavesCanopy:
    """Build the canopy described by validated ``params`` (see :func:`random_leaves`)."""
    p = params
    root = _root_seed(seed)
    rng = np.random.default_rng(root)
    n = p.n_leaves
    w, l = p.plot_size_m
    z0, z1 = p.height_range_m
    # Fixed draw order: centres, normals' zenith and azimuth, in-plane spin.
    centres = np.stack([rng.uniform(0.0, w, n), rng.uniform(0.0, l, n),
                        rng.uniform(z0, z1, n)], axis=1)
    if p.angle_law == "horizontal":
        theta = np.zeros(n)
    elif p.angle_law == "vertical":
        theta = np.full(n, 0.5 * np.pi)
    else:
        # cos θ_L uniform on [0, 1] ⇔ density sin θ_L on [0, π/2]; 1 − U keeps
        # cos θ_L in (0, 1] so normals stay on the upper side.
        theta = np.arccos(1.0 - rng.uniform(0.0, 1.0, n))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    spin = rng.uniform(0.0, 2.0 * np.pi, n)
    if p.angle_law == "vertical" and p.shape == "square":
        # Edges vertical and horizontal: corners above one another share x, y exactly, so
        # after float32 rounding a leaf is still edge-on at nadir (P0 = 1 exactly).  The
        # in-plane spin does not change projected areas, so the law's G is unchanged.
        spin = np.floor(spin / (0.5 * np.pi)) * (0.5 * np.pi)
    rot = _rotations(theta, phi, spin)                     # (n, 3, 3)
    tmpl = _template(p)                                    # (k, 3, 3)
    leaf_v = np.einsum("nij,tcj->ntci", rot, tmpl) + centres[:, None, None, :]
    normals = rot[:, :, 2]
    verts, src, is_copy = periodic_copies(leaf_v, (w, l))
    k = tmpl.shape[0]
    leaves = Leaves(verts.reshape(-1, 3, 3), np.repeat(src.astype(np.int32), k),
                    np.zeros(len(src) * k, np.int32))
    return RandomLeavesCanopy(leaves, np.repeat(is_copy, k), centres, normals,
                              (0.0, 0.0, w, l), p,
                              root.entropy if isinstance(root.entropy, int) else tuple(root.entropy))


def random_leaves(n_leaves: int, leaf_area_m2: float,
                  plot_size_m: tuple[float, float] = (1.0, 1.0),
                  height_range_m: tuple[float, float] = (0.0, 1.0),
                  angle_law: str = "spherical", shape: str = "square",
                  seed: int | np.random.SeedSequence | None = None, *,
                  n_sides: int = 16) -> RandomLeavesCanopy:
    """N random flat leaves in a periodic plot.

    Parameters
    ----------
    n_leaves : int
        Number of leaves N.
    leaf_area_m2 : float
        One-sided area of each leaf, m².
    plot_size_m : (float, float)
        Plot width (x) and length (y), metres; the plot is ``[0, w] × [0, l]``.
    height_range_m : (float, float)
        Leaf centres' heights are uniform in this range, metres.
    angle_law : {'horizontal', 'vertical', 'spherical'}
        Leaf-angle distribution (module docstring).
    shape : {'square', 'disc'}
    seed : int, SeedSequence or None
        Same seed, same bytes.
    n_sides : int
        Polygon sides of a 'disc' leaf.

    Returns
    -------
    RandomLeavesCanopy
        Its ``lai`` is ``N·a/(w·l)``.

    Examples
    --------
    >>> c = random_leaves(100, 0.01, (1.0, 1.0), (0.0, 0.5), 'horizontal', seed=1)
    >>> round(float(c.originals.triangle_area.sum()), 12)
    1.0
    """
    return random_leaves_from_params(
        RandomLeavesParams(n_leaves, leaf_area_m2, plot_size_m, height_range_m, angle_law,
                           shape, n_sides), seed)
