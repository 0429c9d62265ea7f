"""Tree positions from inhomogeneous Poisson processes, one per species (seed 004, §III).

Each species has an intensity (trees per m²) that is a sum of squared-exponential
bumps plus an optional constant background,

    λ(x, y) = background + Σ_k C_k · exp(−[(x − x0_k)²/h_k + (y − y0_k)²/l_k]),

on a rectangle D. Points are drawn by thinning (Lewis & Shedler 1979): draw
N ~ Poisson(λ*·|D|) uniform points with λ* ≥ max_D λ and keep each with
probability λ(s)/λ*. The kept points of all species are then thinned so trees
do not overlap too much (the paper: "one is removed if two trees are too close"):
a minimum distance and, given each point's crown radius ``r``, the crown rule
``d_ij ≥ k·(r_i + r_j)``; that second step is *not* a Poisson process any more,
so counts are reported before and after it.

Randomness comes from the caller's ``numpy.random.Generator``: one child stream
is spawned for the distance thinning and one per species, so appending a species
leaves the candidate points of the earlier ones unchanged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence, overload

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf, erfc

from .._validate import real
from ..errors import ConfigError

__all__ = [
    "Bump", "Domain", "Placement", "SpeciesIntensity", "expected_count", "intensity_grid",
    "place_trees", "sample_ipp", "thin_min_distance", "crown_overlap_share",
]


@dataclass(frozen=True)
class Domain:
    """Axis-aligned rectangle ``[x_min_m, x_max_m] × [y_min_m, y_max_m]`` in metres."""

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float

    def __post_init__(self) -> None:
        for name in ("x_min_m", "x_max_m", "y_min_m", "y_max_m"):
            object.__setattr__(self, name, real(f"domain.{name}", getattr(self, name)))
        if not self.x_max_m > self.x_min_m:
            raise ConfigError(f"must exceed x_min_m = {self.x_min_m} (empty domain)",
                              key="domain.x_max_m", value=self.x_max_m)
        if not self.y_max_m > self.y_min_m:
            raise ConfigError(f"must exceed y_min_m = {self.y_min_m} (empty domain)",
                              key="domain.y_max_m", value=self.y_max_m)

    @classmethod
    def of(cls, domain: "Domain | Sequence[float]") -> "Domain":
        """Accept a Domain or a tuple ``(x_min_m, x_max_m, y_min_m, y_max_m)``."""
        if isinstance(domain, Domain):
            return domain
        try:
            values = tuple(domain)
        except TypeError:
            raise ConfigError("must be (x_min_m, x_max_m, y_min_m, y_max_m)",
                              key="domain", value=domain) from None
        if len(values) != 4:
            raise ConfigError("must be (x_min_m, x_max_m, y_min_m, y_max_m)",
                              key="domain", value=domain)
        return cls(*values)

    @property
    def area_m2(self) -> float:
        return (self.x_max_m - self.x_min_m) * (self.y_max_m - self.y_min_m)


@dataclass(frozen=True)
class Bump:
    """One squared-exponential term ``C·exp(−[(x−x0)²/h + (y−y0)²/l])`` (seed 004).

    Parameters
    ----------
    C_per_m2 : peak intensity in trees per m² (≥ 0).
    x0_m, y0_m : centre in metres (may lie outside the domain).
    h_m2, l_m2 : spreads along x and y in m² (> 0); the bump falls to 1/e at
        ``|x − x0| = sqrt(h)``. Note there is no factor 2: h = 2σ².
    """

    C_per_m2: float
    x0_m: float
    y0_m: float
    h_m2: float
    l_m2: float

    def __post_init__(self) -> None:
        for name in ("C_per_m2", "x0_m", "y0_m", "h_m2", "l_m2"):
            object.__setattr__(self, name, real(f"Bump.{name}", getattr(self, name)))
        if self.C_per_m2 < 0:
            raise ConfigError("peak intensity must be >= 0 trees/m²", key="Bump.C_per_m2",
                              value=self.C_per_m2)
        for name in ("h_m2", "l_m2"):
            if getattr(self, name) <= 0:
                raise ConfigError("spread must be > 0 m²", key=f"Bump.{name}",
                                  value=getattr(self, name))

    def __call__(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return self.C_per_m2 * np.exp(-((np.asarray(x_m) - self.x0_m) ** 2 / self.h_m2
                                        + (np.asarray(y_m) - self.y0_m) ** 2 / self.l_m2))

    def max_over(self, domain: Domain) -> float:
        """Largest value on the domain: at the point of D nearest the centre."""
        dx = min(max(self.x0_m, domain.x_min_m), domain.x_max_m) - self.x0_m
        dy = min(max(self.y0_m, domain.y_min_m), domain.y_max_m) - self.y0_m
        return self.C_per_m2 * math.exp(-(dx * dx / self.h_m2 + dy * dy / self.l_m2))

    def integral(self, domain: Domain) -> float:
        """∫_D of the bump, in trees, closed form with erf (separable Gaussian)."""
        ix = math.sqrt(math.pi * self.h_m2) / 2 * _erf_diff(
            (domain.x_min_m - self.x0_m) / math.sqrt(self.h_m2),
            (domain.x_max_m - self.x0_m) / math.sqrt(self.h_m2))
        iy = math.sqrt(math.pi * self.l_m2) / 2 * _erf_diff(
            (domain.y_min_m - self.y0_m) / math.sqrt(self.l_m2),
            (domain.y_max_m - self.y0_m) / math.sqrt(self.l_m2))
        return self.C_per_m2 * ix * iy


def _erf_diff(a: float, b: float) -> float:
    """erf(b) − erf(a) for a ≤ b without cancellation when both lie in one tail."""
    if a > 0:
        return float(erfc(a) - erfc(b))
    if b < 0:
        return float(erfc(-b) - erfc(-a))
    return float(erf(b) - erf(a))


@dataclass(frozen=True)
class SpeciesIntensity:
    """Intensity of one species: a sum of bumps plus a constant background.

    Parameters
    ----------
    name : species label.
    bumps : the squared-exponential terms (a list is converted to a tuple).
    background_per_m2 : constant intensity added everywhere, trees per m² (≥ 0).
    """

    name: str
    bumps: tuple[Bump, ...] = ()
    background_per_m2: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError("species needs a non-empty name", key="species.name",
                              value=self.name)
        bumps = tuple(self.bumps)
        for i, b in enumerate(bumps):
            if not isinstance(b, Bump):
                raise ConfigError("must be a Bump", key=f"{self.name}.bumps[{i}]", value=b)
        object.__setattr__(self, "bumps", bumps)
        bg = real(f"{self.name}.background_per_m2", self.background_per_m2)
        if bg < 0:
            raise ConfigError("must be >= 0 trees/m²", key=f"{self.name}.background_per_m2",
                              value=bg)
        object.__setattr__(self, "background_per_m2", bg)

    def intensity(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """λ at the given points, trees per m² (broadcasting)."""
        x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
        lam = np.full(np.broadcast_shapes(x_m.shape, y_m.shape), self.background_per_m2)
        for b in self.bumps:
            lam += b(x_m, y_m)
        return lam

    def upper_bound(self, domain: Domain | Sequence[float]) -> float:
        """λ* = background + Σ_k max_D(bump_k) ≥ max_D λ, trees per m².

        Each term is the bump's exact maximum over D (C_k when its centre lies
        in D, so λ* = background + Σ C_k then). A sum of maxima bounds the
        maximum of the sum, which is all thinning needs; it is tight for one
        bump centred in D and wastes candidates only where bumps overlap little.
        """
        d = Domain.of(domain)
        return self.background_per_m2 + sum(b.max_over(d) for b in self.bumps)


@overload
def expected_count(species: SpeciesIntensity, domain: Domain | Sequence[float]) -> float: ...
@overload
def expected_count(species: Sequence[SpeciesIntensity],
                   domain: Domain | Sequence[float]) -> np.ndarray: ...


def expected_count(species, domain):
    """∫_D λ ds: the mean number of trees before the minimum-distance step.

    Parameters
    ----------
    species : SpeciesIntensity or sequence of them.
    domain : Domain or ``(x_min_m, x_max_m, y_min_m, y_max_m)``; any
        sub-rectangle works, e.g. a histogram bin.

    Returns
    -------
    float for one species, else an array with one value per species.
    """
    d = Domain.of(domain)
    if isinstance(species, SpeciesIntensity):
        return species.background_per_m2 * d.area_m2 + sum(b.integral(d) for b in species.bumps)
    return np.array([expected_count(s, d) for s in species], dtype=np.float64)


def intensity_grid(species: Sequence[SpeciesIntensity], domain: Domain | Sequence[float],
                   nx: int, ny: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """λ of every species on a regular grid, for contour plots.

    Returns
    -------
    x_m : (nx,) grid abscissae, from x_min_m to x_max_m inclusive.
    y_m : (ny,) grid ordinates.
    lam_per_m2 : (n_species, ny, nx) intensities (row index = y, as matplotlib expects).
    """
    d = Domain.of(domain)
    if int(nx) < 2 or int(ny) < 2:
        raise ConfigError("grid needs at least 2 points per axis", key="nx, ny",
                          value=(nx, ny))
    x = np.linspace(d.x_min_m, d.x_max_m, int(nx))
    y = np.linspace(d.y_min_m, d.y_max_m, int(ny))
    xx, yy = np.meshgrid(x, y)
    lam = np.stack([s.intensity(xx, yy) for s in species]) if len(species) else \
        np.zeros((0, int(ny), int(nx)))
    return x, y, lam


def sample_ipp(species: SpeciesIntensity, domain: Domain | Sequence[float],
               rng: np.random.Generator, *, max_candidates: int = 20_000_000
               ) -> tuple[np.ndarray, np.ndarray]:
    """Points of one inhomogeneous Poisson process on D, by Lewis–Shedler thinning.

    Parameters
    ----------
    species : the intensity.
    domain : the rectangle.
    rng : random source (consumed: count, x, y, acceptance draws).
    max_candidates : refuse if λ*·|D| exceeds this (memory guard).

    Returns
    -------
    x_m, y_m : float64 arrays of the kept points.
    """
    d = Domain.of(domain)
    lam_max = species.upper_bound(d)
    mean = lam_max * d.area_m2
    if mean > max_candidates:
        raise ConfigError(f"expects {mean:.3g} candidate points (more than "
                          f"{max_candidates}); lower the intensity or the domain",
                          key=f"{species.name}.bumps", value=lam_max)
    n = int(rng.poisson(mean)) if mean > 0 else 0
    x = rng.uniform(d.x_min_m, d.x_max_m, n)
    y = rng.uniform(d.y_min_m, d.y_max_m, n)
    u = rng.uniform(0.0, 1.0, n)
    # Keep with probability λ(s)/λ*. The code published with seed 004 keeps
    # with probability λ(s) itself, which gives intensity λ*·λ(s) instead of λ(s).
    keep = u * lam_max < species.intensity(x, y)
    return x[keep], y[keep]


def thin_min_distance(x_m: np.ndarray, y_m: np.ndarray, min_distance_m: float,
                      rng: np.random.Generator, crown_radius_m: np.ndarray | None = None,
                      crown_factor: float = 0.0) -> np.ndarray:
    """Mask of points kept so that no two kept trees are too close.

    Rule: visit the points in a uniformly random order and keep a point unless an
    already kept point ``j`` conflicts with it: ``d_ij ≤ min_distance_m``, or
    ``d_ij < k·(r_i + r_j)`` with ``k = crown_factor`` and ``r`` the crown radii
    (Matérn type III style). Kept points therefore satisfy
    ``d_ij > min_distance_m`` and ``d_ij ≥ k·(r_i + r_j)``, every dropped point
    conflicts with a kept one, and no species is favoured. ``min_distance_m = 0``
    and ``k = 0`` keep everything.
    """
    d_min = real("min_distance_m", min_distance_m)
    if d_min < 0:
        raise ConfigError("must be >= 0 m", key="min_distance_m", value=min_distance_m)
    k = real("crown_factor", crown_factor)
    if k < 0:
        raise ConfigError("must be >= 0", key="crown_factor", value=crown_factor)
    x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    n = len(x_m)
    r = np.zeros(n) if crown_radius_m is None else np.asarray(crown_radius_m, np.float64)
    if r.shape != (n,) or not (np.isfinite(r).all() and (r >= 0).all()):
        raise ConfigError(f"must be {n} finite radii ≥ 0", key="crown_radius_m", value=r.shape)
    keep = np.ones(n, dtype=bool)
    reach = max(d_min, 2.0 * k * float(r.max(initial=0.0)))   # no conflict beyond this
    if n < 2 or reach == 0:
        return keep
    rank = np.empty(n, dtype=np.int64)
    rank[rng.permutation(n)] = np.arange(n)
    pairs = cKDTree(np.column_stack([x_m, y_m])).query_pairs(reach, output_type="ndarray")
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        d = np.hypot(x_m[i] - x_m[j], y_m[i] - y_m[j])
        pairs = pairs[(d <= d_min) | (d < k * (r[i] + r[j]))]
    if len(pairs) == 0:
        return keep
    # adjacency (CSR) of conflicting pairs; isolated points are kept whatever the order
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = both[np.argsort(both[:, 0], kind="stable")]
    indptr = np.searchsorted(both[:, 0], np.arange(n + 1))
    nbrs = both[:, 1]
    busy = np.unique(pairs)
    keep[busy] = False
    for i in busy[np.argsort(rank[busy])]:
        if not keep[nbrs[indptr[i]:indptr[i + 1]]].any():
            keep[i] = True
    return keep


def crown_overlap_share(x_m: np.ndarray, y_m: np.ndarray, crown_radius_m: np.ndarray) -> float:
    """Share of trees whose nearest neighbour's trunk stands inside their own crown (d_nn < r_i)."""
    x_m, y_m = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    if len(x_m) < 2:
        return 0.0
    d, _ = cKDTree(np.column_stack([x_m, y_m])).query(np.column_stack([x_m, y_m]), 2)
    return float((d[:, 1] < np.asarray(crown_radius_m, np.float64)).mean())


@dataclass(frozen=True)
class Placement:
    """Tree positions of all species after both thinning steps.

    Attributes
    ----------
    x_m, y_m : (n,) float64 positions in metres.
    species : (n,) int32 index into ``species_names``.
    species_names : names in input order.
    count_before : (n_species,) trees per species from the Poisson process,
        before the minimum-distance step (each Poisson with mean ∫_D λ).
    removed : (n_species,) trees per species removed by the minimum-distance step.
    lambda_max_per_m2 : (n_species,) the thinning bounds λ* used.
    min_distance_m : the distance rule applied.
    candidate : (n,) int64 index of each tree among the Poisson points of all species
        (species in input order), the identity its seed is made from.
    crown_radius_m : (n,) the crown radii the crown rule used (zeros without one).
    crown_factor : the ``k`` of the crown rule ``d_ij ≥ k·(r_i + r_j)`` (0: none).
    """

    x_m: np.ndarray
    y_m: np.ndarray
    species: np.ndarray
    species_names: tuple[str, ...]
    count_before: np.ndarray
    removed: np.ndarray
    lambda_max_per_m2: np.ndarray
    min_distance_m: float
    domain: Domain = field(repr=False, default=None)  # type: ignore[assignment]
    candidate: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_radius_m: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_factor: float = 0.0

    def __len__(self) -> int:
        return len(self.x_m)

    @property
    def count_after(self) -> np.ndarray:
        """(n_species,) trees per species that were placed."""
        return self.count_before - self.removed


def place_trees(species: Sequence[SpeciesIntensity], domain: Domain | Sequence[float],
                min_distance_m: float, rng: np.random.Generator, *,
                crown_radius: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
                crown_factor: float = 0.0) -> Placement:
    """Simulate a forest: one Poisson process per species, then distance thinning.

    Parameters
    ----------
    species : intensities, one per species.
    domain : Domain or ``(x_min_m, x_max_m, y_min_m, y_max_m)``.
    min_distance_m : no two trees (of any species) end up closer than this; 0 disables.
    rng : random source. Child streams are spawned from it (one for the distance
        thinning order, then one per species), so the same seed gives the same
        placement and appending a species does not move the others' candidates.
    crown_radius : ``f(x_m, y_m, species) → r_m``, called once with every Poisson point
        (candidate order) before the thinning; with ``crown_factor = k > 0`` kept trees
        also satisfy ``d_ij ≥ k·(r_i + r_j)`` (:func:`thin_min_distance`).
    crown_factor : k (≥ 0; 0 = the plain minimum distance).

    Returns
    -------
    Placement

    Examples
    --------
    >>> sp = [SpeciesIntensity("oak", [Bump(0.01, 50, 50, 400, 900)])]
    >>> p = place_trees(sp, (0, 100, 0, 100), 2.0, np.random.default_rng(1))
    >>> int(p.count_after[0]) == len(p)
    True
    """
    d = Domain.of(domain)
    species = list(species)
    for i, s in enumerate(species):
        if not isinstance(s, SpeciesIntensity):
            raise ConfigError("must be a SpeciesIntensity", key=f"species[{i}]", value=s)
    d_min = real("min_distance_m", min_distance_m)
    if d_min < 0:
        raise ConfigError("must be >= 0 m", key="min_distance_m", value=min_distance_m)
    if not isinstance(rng, np.random.Generator):
        raise ConfigError("must be a numpy.random.Generator", key="rng", value=rng)
    order_rng, *species_rngs = rng.spawn(1 + len(species))
    xs, ys, ids = [], [], []
    for i, (s, r) in enumerate(zip(species, species_rngs)):
        x, y = sample_ipp(s, d, r)
        xs.append(x)
        ys.append(y)
        ids.append(np.full(len(x), i, dtype=np.int32))
    x = np.concatenate(xs) if xs else np.zeros(0)
    y = np.concatenate(ys) if ys else np.zeros(0)
    sp = np.concatenate(ids) if ids else np.zeros(0, np.int32)
    before = np.bincount(sp, minlength=len(species)).astype(np.int64)
    k = real("crown_factor", crown_factor)
    r = np.zeros(len(x)) if crown_radius is None else np.asarray(crown_radius(x, y, sp), np.float64)
    keep = thin_min_distance(x, y, d_min, order_rng, r, k)
    after = np.bincount(sp[keep], minlength=len(species)).astype(np.int64)
    return Placement(
        x_m=x[keep], y_m=y[keep], species=sp[keep],
        species_names=tuple(s.name for s in species),
        count_before=before, removed=before - after,
        lambda_max_per_m2=np.array([s.upper_bound(d) for s in species], dtype=np.float64),
        min_distance_m=d_min, domain=d, candidate=np.flatnonzero(keep).astype(np.int64),
        crown_radius_m=r[keep], crown_factor=k)
