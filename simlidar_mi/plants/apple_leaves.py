"""Leaves on the SIMLIDAR apple trees: the paper's future work ("foliage density higher in the
outer layer"; Méndez et al., conclusions), as a seeded leaf module on young shoots.

Which shoots
    Segments of the last ``last_generations`` generations carry leaves: axis order
    ``n > iterations − last_generations`` (``I(n)`` is written in generation ``n``, so the
    highest orders are the youngest, thinnest shoots).
How many (the outer-crown law)
    Leaves are a Poisson process along each bearing segment with intensity (leaves per metre)

        λ_i = λ₀ · (1 + β·r_i) / ⟨1 + β·r⟩,

    ``λ₀ = leaves_per_m``, ``β = outer_weight`` ≥ 0, ``r_i = ρ_i / ρ_max`` the horizontal
    distance of the segment's midpoint from the tree's trunk axis (the vertical through its
    base) relative to the farthest bearing midpoint of that tree, and ``⟨1 + β·r⟩`` the
    length-weighted mean over the tree's bearing segments. The normalisation keeps the
    expected leaf count of a tree at ``λ₀ × (bearing length)`` for any β; β only moves
    leaves outwards: the density at the crown's edge (r = 1) is ``1 + β`` times that at the
    axis (r = 0). β = 0 is a uniform density.
Where and how
    Positions are uniform along the segment, insertion azimuths uniform about it. A petiole
    of ``petiole_length_m`` leaves the bark at ``petiole_angle_deg`` from the shoot axis; it is
    not drawn (a 2.5 cm × 1.5 mm petiole is ~2 % of a leaf's area, and drawing it as a
    cylinder would change the wood). The blade's base is the petiole's tip.
Orientation
    The inclination ``θ_L`` of the blade's upper normal from the zenith is drawn from the
    chosen law by inverse CDF (:mod:`simlidar_mi.plants.leaf_angles`), exactly. The normal
    leans towards the petiole's horizontal direction (random if the petiole is vertical), so
    the blade runs outwards from its shoot with its tip dipping by ``θ_L``.
Shape and size
    An elliptic blade: the ``sides``-gon inscribed in the ℓ × w ellipse as a fan of ``sides``
    triangles (:func:`simlidar_mi.plants.tree_leaves.ellipse_fan`), one-sided area
    ``(k/8)·sin(2π/k)·ℓ·w``; k = 8 gives 0.7071·ℓw, matching the apple leaf-area factor
    LA = 0.71·L·W measured on scanned leaves of four cultivars by Litschmann et al. (2016),
    Acta Hortic. 1137:241–246, doi:10.17660/ActaHortic.2016.1137.34. ℓ and w/ℓ are truncated
    normals (±2 SD). **Unverified figures**: the default ℓ = 8.5 ± 1.5 cm, w/ℓ = 0.60 ± 0.05,
    40 leaves per metre, 2.5 cm petioles at 45° are typical values for mature apple shoot
    leaves that we could not check against a primary table; set them from your own orchard.
Seasons
    ``season = "dormant"``: no leaves (the wood only, exactly as before this module).
    ``"leaf-on"``: the leaves above, minus ``defoliation`` (a share in [0, 1]):
    ``round(defoliation × n)`` of each tree's ``n`` leaves, chosen at random, are removed;
    the rest keep their ``leaf_id``, and a larger share removes a superset.
Seeds
    Tree ``k`` draws its leaves from ``SeedSequence(seed).spawn(n_trees)[k].spawn(2)``
    (placement, then defoliation): streams apart from its wood's, so leaves never change the
    wood, and the same seed gives the same leaves bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config.checks import real as _real
from ..config.keys import SECTIONS as _KEYS
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from .laws import TruncNormal
from .leaf_angles import leaf_angle_table, sample_leaf_angles
from .tree_leaves import LeafTable, _unit, ellipse_fan
from .tree_params import leaf_polygon_area_factor

__all__ = ["AppleLeafParams", "apple_tree_leaves", "orchard_leaves", "leaf_area_measures",
           "outer_crown_weights"]

_D = {k: v.default for k, v in _KEYS["orchard.leaves"].items()}
_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class AppleLeafParams:
    """The ``[orchard.leaves]`` keys (module docstring: their laws; defaults: the scene keys)."""

    season: str = _D["season"]
    defoliation: float = _D["defoliation"]
    last_generations: int = _D["last_generations"]
    leaves_per_m: float = _D["leaves_per_m"]
    outer_weight: float = _D["outer_weight"]
    petiole_length_m: float = _D["petiole_length_m"]
    petiole_angle_deg: float = _D["petiole_angle_deg"]
    length_mean_m: float = _D["length_mean_m"]
    length_sd_m: float = _D["length_sd_m"]
    width_ratio_mean: float = _D["width_ratio_mean"]
    width_ratio_sd: float = _D["width_ratio_sd"]
    sides: int = _D["sides"]
    angle_distribution: Any = _D["angle_distribution"]

    def __post_init__(self) -> None:
        # the scene-file checks of config.keys_orchard, for Python callers too
        for name, key in _KEYS["orchard.leaves"].items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, key.types):
                raise ConfigError(f"expected {' or '.join(t.__name__ for t in key.types)}",
                                  key=f"orchard.leaves.{name}", value=value)
            problem = key.check(value) if key.check else None
            if problem:
                raise ConfigError(problem, key=f"orchard.leaves.{name}", value=value)
        if not isinstance(self.angle_distribution, str):
            leaf_angle_table(self.angle_distribution, "orchard.leaves.angle_distribution")

    @property
    def leaf_on(self) -> bool:
        return self.season == "leaf-on"

    @property
    def area_factor(self) -> float:
        """Blade area / (ℓ·w): (k/8)·sin(2π/k)."""
        return leaf_polygon_area_factor("ellipse", self.sides)

    def laws(self) -> tuple[TruncNormal, TruncNormal]:
        """(length, width ratio) laws: normals truncated to ±2 SD (and above 0)."""
        m, s = self.length_mean_m, self.length_sd_m
        q, t = self.width_ratio_mean, self.width_ratio_sd
        return (TruncNormal(m, s, max(m - 2 * s, 1e-3 * m), m + 2 * s),
                TruncNormal(q, t, max(q - 2 * t, 1e-3 * q), q + 2 * t))


def outer_crown_weights(mid_m: np.ndarray, length_m: np.ndarray, axis_xy, beta: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """(w, r): the outer-crown law's weights ``(1 + β·r)/⟨1 + β·r⟩`` and relative radii ``r``.

    ``mid_m`` (n, 3) bearing-segment midpoints, ``length_m`` their lengths, ``axis_xy`` the
    trunk axis. ``⟨·⟩`` is the length-weighted mean, so ``Σ w·ℓ = Σ ℓ``.
    """
    rho = np.hypot(mid_m[:, 0] - axis_xy[0], mid_m[:, 1] - axis_xy[1])
    r = rho / rho.max() if len(rho) and rho.max() > 0 else np.zeros_like(rho)
    raw = 1.0 + beta * r
    total = float(np.sum(length_m))
    mean = float(np.sum(raw * length_m)) / total if total > 0 else 1.0
    return raw / mean, r


def _perpendicular(h: np.ndarray) -> np.ndarray:
    """A unit vector normal to each unit row of ``h`` (horizontal unless ``h`` is vertical)."""
    e = np.cross(h, _Z)
    n = np.linalg.norm(e, axis=1, keepdims=True)
    return np.where(n > 1e-9, e / np.maximum(n, 1e-300), np.array([1.0, 0.0, 0.0]))


def apple_tree_leaves(tree: Branches, iterations: int, params: AppleLeafParams,
                      rng: np.random.Generator, axis_xy=None, first_leaf_id: int = 0,
                      tree_id: int = 0) -> tuple[Leaves, LeafTable]:
    """The leaves of one tree, before defoliation (module docstring: the laws).

    Parameters
    ----------
    tree : the tree's branches (only rows of order > iterations − last_generations bear).
    iterations : the tree's ``Ns``.
    rng : the tree's leaf stream.
    axis_xy : trunk axis (default: the x, y of the tree's lowest segment start).
    first_leaf_id : ``leaf_id`` of the first leaf (ids run on, so an orchard's are unique).
    tree_id : written to ``plant_id`` and the table's ``tree_id``.
    """
    bear = tree.order > iterations - params.last_generations
    b = tree.subset(bear)
    if axis_xy is None:
        axis_xy = tree.p0[np.argmin(tree.p0[:, 2]), :2] if len(tree) else (0.0, 0.0)
    seg_len = b.length
    w, _ = outer_crown_weights(0.5 * (b.p0 + b.p1), seg_len, axis_xy, params.outer_weight)
    counts = rng.poisson(params.leaves_per_m * seg_len * w)
    n = int(counts.sum())
    owner = np.repeat(np.arange(len(b)), counts)
    t_pos, psi, u_theta, az = rng.random(n), rng.uniform(0, 2 * np.pi, n), rng.random(n), rng.uniform(0, 2 * np.pi, n)
    len_law, ratio_law = params.laws()
    ll = len_law.sample(rng, n)
    lw = ll * ratio_law.sample(rng, n)
    if n == 0:
        return Leaves.empty(), LeafTable.empty()
    p0, p1 = b.p0[owner], b.p1[owner]
    H = _unit(p1 - p0)
    e1 = _perpendicular(H)
    e2 = np.cross(H, e1)
    u = np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2  # insertion direction
    alpha = math.radians(params.petiole_angle_deg)
    pet = math.cos(alpha) * H + math.sin(alpha) * u
    base = (p0 + t_pos[:, None] * (p1 - p0) + (0.5 * b.diameter[owner])[:, None] * u
            + params.petiole_length_m * pet)
    # the normal leans towards the petiole's horizontal direction: the blade runs outwards
    horiz = np.column_stack([pet[:, 0], pet[:, 1], np.zeros(n)])
    hn = np.linalg.norm(horiz, axis=1, keepdims=True)
    a = np.where(hn > 1e-9, horiz / np.maximum(hn, 1e-300),
                 np.column_stack([np.cos(az), np.sin(az), np.zeros(n)]))
    theta = sample_leaf_angles(params.angle_distribution, u_theta)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    normal = st * a + ct * _Z
    head = ct * a - st * _Z                     # ⊥ normal, dipping by θ_L
    side = np.cross(head, normal)               # side × head = normal: triangles face up
    centre = base + 0.5 * ll[:, None] * head
    tri = ellipse_fan(centre, head, side, 0.5 * ll[:, None, None], 0.5 * lw[:, None, None],
                      params.sides)
    leaf_id = np.arange(first_leaf_id, first_leaf_id + n, dtype=np.int32)
    k = params.sides
    leaves = Leaves(tri.reshape(-1, 3, 3), np.repeat(leaf_id, k), np.full(n * k, tree_id, np.int32))
    table = LeafTable(np.full(n, tree_id, np.int32), leaf_id, centre, ll, lw,
                      params.area_factor * ll * lw, normal, head)
    return leaves, table


def _defoliate(leaves: Leaves, table: LeafTable, share: float, rng: np.random.Generator
               ) -> tuple[Leaves, LeafTable]:
    """Remove ``round(share × n)`` leaves at random (a fixed permutation: nested in ``share``)."""
    n = len(table)
    order = rng.permutation(n)
    gone = np.zeros(n, bool)
    gone[order[:int(round(share * n))]] = True
    if not gone.any():
        return leaves, table
    keep_leaf = ~gone
    kept_ids = table.leaf_id[keep_leaf]
    tri_keep = np.isin(leaves.leaf_id, kept_ids)
    t = table
    return leaves.subset(tri_keep), LeafTable(t.tree_id[keep_leaf], t.leaf_id[keep_leaf],
                                              t.centre_m[keep_leaf], t.length_m[keep_leaf],
                                              t.width_m[keep_leaf], t.area_m2[keep_leaf],
                                              t.normal[keep_leaf], t.heading[keep_leaf])


def orchard_leaves(branches: Branches, iterations: int, params: AppleLeafParams, n_trees: int,
                   bases_xy, seed: int = 0) -> tuple[Leaves, LeafTable]:
    """The leaves of an orchard row from its wood (:func:`simlidar_mi.plants.apple.orchard`).

    ``bases_xy`` (n_trees, 2): trunk axes. Dormant: empty. Leaf ids run over the whole row.
    """
    if not params.leaf_on or n_trees == 0:
        return Leaves.empty(), LeafTable.empty()
    seed = int(_real("seed", seed, nonneg=True))
    streams = np.random.SeedSequence(seed).spawn(n_trees)
    parts, tables, next_id = [], [], 0
    for k in range(n_trees):
        place, strip = (np.random.default_rng(s) for s in streams[k].spawn(2))
        lv, tb = apple_tree_leaves(branches.subset(branches.tree_id == k), iterations, params,
                                   place, bases_xy[k], next_id, k)
        next_id += len(tb)
        if params.defoliation > 0:
            lv, tb = _defoliate(lv, tb, params.defoliation, strip)
        parts.append(lv)
        tables.append(tb)
    leaves = Leaves(np.concatenate([p.vertices for p in parts]),
                    np.concatenate([p.leaf_id for p in parts]),
                    np.concatenate([p.plant_id for p in parts]))
    return leaves, LeafTable.concat(tables)


def leaf_area_measures(leaves: Leaves, n_trees: int, spacing_m: float, row_spacing_m: float) -> dict:
    """Leaf area per tree and the row's LAI, from the triangles (one-sided, m²).

    ``LAI = Σ leaf area / (n_trees × spacing_m × row_spacing_m)``: the row's leaf area over
    the ground it occupies (each tree a ``spacing_m`` × ``row_spacing_m`` rectangle).
    """
    area = leaves.triangle_area
    per_tree = np.bincount(leaves.plant_id, weights=area, minlength=n_trees) if len(leaves) else np.zeros(n_trees)
    n_per_tree = (np.array([len(np.unique(leaves.leaf_id[leaves.plant_id == k])) for k in range(n_trees)])
                  if len(leaves) else np.zeros(n_trees, int))
    ground = n_trees * spacing_m * row_spacing_m
    return {"leaf_area_m2": float(area.sum()), "n_leaves": int(n_per_tree.sum()),
            "row_ground_area_m2": float(ground), "LAI_row": float(area.sum() / ground),
            "leaf_area_per_tree_m2": [float(x) for x in per_tree],
            "n_leaves_per_tree": [int(x) for x in n_per_tree]}


def _params_from_config(cfg) -> AppleLeafParams:
    try:
        return AppleLeafParams(**cfg["orchard.leaves"])
    except ConfigError as exc:
        raise ConfigError(exc.reason, file=cfg.source_of(exc.key), key=exc.key, value=exc.value) from None


def orchard_leaves_from_config(cfg, wood: Branches) -> Leaves:
    """The leaves of a scene's ``[orchard]`` row (``wood`` = its trees), as
    :func:`simlidar_mi.lidar.survey.generate` returns them: ``plant_id`` = tree index."""
    o = cfg["orchard"]
    n = o["n_trees"]
    bases = np.column_stack([np.full(n, o["row_x_m"]), o["y_start_m"] + o["spacing_m"] * np.arange(n)])
    leaves, _ = orchard_leaves(wood, cfg["orchard.tree"]["iterations"], _params_from_config(cfg),
                               n, bases, cfg.seed)
    return leaves


def orchard_leaf_measures(cfg, leaves: Leaves) -> dict:
    """:func:`leaf_area_measures` of a leaf-on ``[orchard]`` scene (``{}`` when dormant)."""
    if not (cfg.has("orchard") or cfg.has("orchard.tree") or cfg.has("orchard.leaves")) \
            or _params_from_config(cfg).season == "dormant":
        return {}
    o = cfg["orchard"]
    return leaf_area_measures(leaves, o["n_trees"], o["spacing_m"], o["row_spacing_m"])
