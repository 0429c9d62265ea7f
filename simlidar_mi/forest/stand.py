"""The stand: Poisson-placed random trees, each grown or instanced (Wahed et al., seed 004, §III).

A forest is one inhomogeneous Poisson process per species on a rectangle
(:func:`simlidar_mi.forest.placement.place_trees`: squared-exponential bumps,
Lewis–Shedler thinning, then a distance and crown thinning in arrival order whose
removals are reported; each species' ∫λ counts its Poisson points or its final
stand, ``[[species]] count``), and one random tree (:mod:`simlidar_mi.plants.random_tree`) per
position. Two modes:

``instancing = true``
    Each species gets prototype trees, each drawn from its own seed: candidate ``i``
    (arrival order, which is random in space) places prototype ``i mod K`` (a fixed ``K``,
    default 12: :mod:`simlidar_mi.forest.representation`) or ``i // trees_per_prototype``
    (``prototypes_per_species = "auto"``: no prototype serves more than that many trees); each
    tree draws a yaw (uniform 0–360°) from *its* seed. Geometry is built once per
    prototype and placed as instances: the way a 300 m × 300 m forest fits in memory.
    ``scale_range`` other than ``[1, 1]`` scales, with ``scale_mode = "wood"``
    (default), each prototype's wood by one factor drawn for the prototype while its
    leaves keep their drawn size (:meth:`RandomTree.wood_scaled`) — one affine
    instance transform cannot scale positions but not leaf sizes, so the scale is
    baked into the prototype; ``"whole-tree"`` scales each instance as a whole,
    leaves included (the earlier behaviour).
``instancing = false``
    Every tree is its own random draw (yaw 0, scale 1).

Crowns: a candidate's tree (or prototype) is grown when the thinning reaches it and
no kept tree already excludes it, so the thinning keeps ``d_ij ≥ crown_factor·(r_i + r_j)``
besides the minimum distance (:func:`simlidar_mi.forest.placement.place_trees`).

Parameters and seeds are in :mod:`simlidar_mi.forest.params`, the files of
``simlidar-mi forest`` in :mod:`simlidar_mi.forest.run`.

A placed tree's world coordinates are ``p_world = (x, y, 0) + Rz(yaw)·(s·p_local)``
(the same order as Mitsuba's ``translate · rotate · scale``) with ``s = scale`` in
``"whole-tree"`` mode; in ``"wood"`` mode ``p_local`` is the wood-scaled tree and
``s = 1``. :func:`place_tree` is that call.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from .._runtime.progress import bar, make_progress
from .._runtime.threads import ordered_map
from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from ..io.terrain import check_inside, terrain_of
from ..plants.foliage import needle_area_factor
from ..plants.random_tree import RandomTree, iter_random_trees, random_tree
from ..plants.tree_leaves import LeafTable
from .foliage import crown_bases_m, crown_hull, dbhs_m, foliage_summary, polygon_area_m2, sector_radius_columns
from .params import ForestParams, forest_params_from_scene, prototype_scale, prototype_seed, tree_seed
from .placement import Placement, crown_overlap_share, place_trees
from .representation import GROWN_BYTES_PER_TRIANGLE, check_memory, representation

__all__ = ["Forest", "make_forest", "place_tree"]


# --- the forest ------------------------------------------------------------------------


def _rot_z(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _place(points: np.ndarray, t: np.ndarray, yaw_deg: float, scale: float) -> np.ndarray:
    """``t + Rz(yaw)·(scale·p)`` for points of any leading shape (…, 3).

    As one (n, 3) @ (3, 3) product: a (n, 3, 3) leaf-vertex stack @ (3, 3) is n small BLAS
    calls, 2× slower, for the same bits (checked on the forests' PLY exports)."""
    p = scale * np.asarray(points)
    return (p.reshape(-1, 3) @ _rot_z(yaw_deg).T).reshape(p.shape) + t


def _placed(t: RandomTree, tr: np.ndarray, yaw: float, s: float, tid: int) -> tuple[Branches, Leaves]:
    b = t.branches
    br = Branches(_place(b.p0, tr, yaw, s), _place(b.p1, tr, yaw, s), b.diameter * s, b.order,
                  np.full(len(b), tid, np.int32))
    lv = Leaves(_place(t.leaves.vertices, tr, yaw, s), t.leaves.leaf_id,
                np.full(len(t.leaves), tid, np.int32))
    return br, lv


def place_tree(tree: RandomTree, x_m: float, y_m: float, yaw_deg: float = 0.0, scale: float = 1.0,
               scale_mode: str = "wood", tree_id: int = 0, z_m: float = 0.0) -> tuple[Branches, Leaves]:
    """A tree in its own frame placed in the world as a forest places it: a row of ``trees.csv``.

    ``scale_mode = "wood"``: ``tree.wood_scaled(scale)`` (leaves keep their size), then
    turned by ``yaw_deg`` about z and moved to ``(x_m, y_m, z_m)``; ``"whole-tree"``:
    ``(x, y, z) + Rz(yaw)·(scale·p)`` for every point, leaves included.  ``z_m``: the row's
    ``z_base_m`` (the terrain height under the trunk; 0 without a terrain).

    Examples
    --------
    Rebuild tree ``i`` of a forest from its ``trees.csv`` row (``P`` = the species'
    parameters: ``species_preset(preset)`` unless the scene overrides laws, in general
    ``forest_params_from_scene(cfg).species[j].tree``)::

        branches, leaves = place_tree(random_tree(P, seed=row.seed), row.x, row.y,
                                      row.yaw_deg, row.scale, z_m=row.z_base_m)
    """
    if scale_mode not in ("wood", "whole-tree"):
        raise ConfigError("must be 'wood' or 'whole-tree'", key="scale_mode", value=scale_mode)
    tr = np.array([float(x_m), float(y_m), float(z_m)])
    if scale_mode == "wood":
        return _placed(tree.wood_scaled(scale), tr, float(yaw_deg), 1.0, tree_id)
    return _placed(tree, tr, float(yaw_deg), float(scale), tree_id)


@dataclass
class Forest:
    """A placed forest: positions, per-tree seeds and either prototypes or every tree.

    Attributes
    ----------
    params, seed : what it was made from.
    placement : the Poisson placement (counts before/after the distance thinning).
    tree_seed : (n,) int64, each tree's own seed.
    prototype : (n,) int32 index into ``prototypes`` (−1 without instancing).
    yaw_deg, scale : (n,) the placement of each tree (0 and 1 without instancing);
        ``scale`` is the wood scale of its prototype in ``"wood"`` mode.
    prototypes : instancing: the prototype trees placed at least once (own frame, wood
        already scaled in ``"wood"`` mode), ``prototype_species[k]`` their species and
        ``prototype_seed[k]`` their seeds; empty otherwise.
    trees : without instancing, every tree in its own frame (tree_id = its index).
    height_m, crown_radius_m : (n,) of each placed tree.
    n_branches, n_leaves, n_leaf_triangles : (n,) per tree.
    branching : (n,) share of the tree's branching decisions with the L1 flag true (0/1
        with one flag per tree).
    leaf_area_m2, needle_area_m2, crown_projection_m2 : (n,) per tree: one-sided leaf-element
        area, the needle area it stands for (= leaf area for broadleaves), crown projection
        (:mod:`simlidar_mi.forest.foliage`); ``hulls``: the crown hull of each prototype
        (instancing) or tree, own frame.
    seconds : time spent per step.
    info : counts of what was grown (candidates, prototypes or trees).
    """

    params: ForestParams
    seed: int
    placement: Placement
    tree_seed: np.ndarray
    prototype: np.ndarray
    yaw_deg: np.ndarray
    scale: np.ndarray
    prototypes: tuple[RandomTree, ...]
    prototype_species: np.ndarray
    prototype_seed: np.ndarray
    trees: tuple[RandomTree, ...] | None
    height_m: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_radius_m: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    n_branches: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    n_leaves: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    n_leaf_triangles: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    branching: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    leaf_area_m2: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    needle_area_m2: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    crown_projection_m2: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    hulls: list = field(repr=False, default=None)  # type: ignore[assignment]
    base_z_m: np.ndarray = field(repr=False, default=None)  # type: ignore[assignment]
    seconds: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self)
        self.base_z_m = np.zeros(n) if self.base_z_m is None else np.asarray(self.base_z_m, np.float64)
        loc = [self.local_tree(i) for i in range(n)] if self.trees is not None else None
        if self.instancing:
            ph = np.array([t.height_m for t in self.prototypes])
            pc = np.array([t.crown_radius_m for t in self.prototypes])
            pb = np.array([len(t.branches) for t in self.prototypes], np.int64)
            pl = np.array([t.n_leaves for t in self.prototypes], np.int64)
            pt = np.array([len(t.leaves) for t in self.prototypes], np.int64)
            pf = np.array([t.branching for t in self.prototypes])
            p = self.prototype
            self.height_m = ph[p] * self.instance_scale if n else np.zeros(0)
            self.crown_radius_m = pc[p] * self.instance_scale if n else np.zeros(0)
            self.n_branches, self.n_leaves, self.n_leaf_triangles = (
                (a[p] if n else np.zeros(0, np.int64)) for a in (pb, pl, pt))
            self.branching = pf[p] if n else np.zeros(0)
            self._foliage(self.prototypes, self.prototype_species, p)
        else:
            self.height_m = np.array([t.height_m for t in loc])
            self.crown_radius_m = np.array([t.crown_radius_m for t in loc])
            self.n_branches = np.array([len(t.branches) for t in loc], np.int64)
            self.n_leaves = np.array([t.n_leaves for t in loc], np.int64)
            self.n_leaf_triangles = np.array([len(t.leaves) for t in loc], np.int64)
            self.branching = np.array([t.branching for t in loc], np.float64)
            self._foliage(loc, self.species, np.arange(n))

    def _foliage(self, local, local_species, p) -> None:
        """Per-tree leaf and needle area and crown projection from the ``local`` trees
        (prototypes or trees; tree ``i`` is ``local[p[i]]``, scaled by its instance scale)."""
        hulls = list(ordered_map(crown_hull, local))  # qhull frees the GIL: two at a time
        la = np.array([float(t.leaf_table.area_m2.sum()) for t in local])
        nf = np.array([needle_area_factor(self.params.species[int(j)].tree.shoot_star)
                       for j in local_species])
        cp = np.array([polygon_area_m2(h) for h in hulls])
        s2 = self.instance_scale ** 2
        n = len(self)
        self.hulls = hulls
        self.leaf_area_m2 = la[p] * s2 if n else np.zeros(0)
        self.needle_area_m2 = (la * nf)[p] * s2 if n else np.zeros(0)
        self.crown_projection_m2 = cp[p] * s2 if n else np.zeros(0)

    def crown_hulls_world(self) -> Iterator[np.ndarray]:
        """Each tree's crown hull placed in the world (x, y)."""
        for i in range(len(self)):
            h = self.hulls[int(self.prototype[i]) if self.instancing else i]
            if len(h):
                yield _place(np.column_stack([h, np.zeros(len(h))]), self.translation_m(i),
                             float(self.yaw_deg[i]), float(self.instance_scale[i]))[:, :2]

    def __len__(self) -> int:
        return len(self.placement)

    @property
    def instancing(self) -> bool:
        return self.trees is None

    @property
    def instance_scale(self) -> np.ndarray:
        """(n,) the scale of each tree's instance transform: ``scale`` in ``"whole-tree"``
        mode, else 1 (the wood scale is already in the prototype)."""
        if self.params.scale_mode == "whole-tree":
            return self.scale
        return np.ones(len(self))

    @property
    def geometry_seed(self) -> np.ndarray:
        """(n,) the seed that grows each tree's geometry: its prototype's, or its own."""
        if self.instancing:
            return self.prototype_seed[self.prototype] if len(self) else np.zeros(0, np.int64)
        return self.tree_seed

    @property
    def x_m(self) -> np.ndarray:
        return self.placement.x_m

    @property
    def y_m(self) -> np.ndarray:
        return self.placement.y_m

    @property
    def species(self) -> np.ndarray:
        """(n,) species index of each tree (into ``species_names``)."""
        return self.placement.species

    @property
    def species_names(self) -> tuple[str, ...]:
        return self.placement.species_names

    def translation_m(self, i: int | None = None) -> np.ndarray:
        """Tree foot(s) ``(x, y, z_base)``: (3,) for one tree, (n, 3) for all; ``z_base`` is the
        terrain height under the trunk (``base_z_m``; 0 without a terrain)."""
        if i is None:
            return np.column_stack([self.x_m, self.y_m, self.base_z_m])
        return np.array([self.x_m[i], self.y_m[i], self.base_z_m[i]])

    def local_tree(self, i: int) -> RandomTree:
        """Tree ``i`` in its own frame (its prototype when instancing)."""
        if self.trees is None:
            return self.prototypes[int(self.prototype[i])]
        return self.trees[i]

    def tree_geometry(self, i: int) -> tuple[Branches, Leaves]:
        """Tree ``i`` placed in the world (tree_id / plant_id = ``i``)."""
        return _placed(self.local_tree(i), self.translation_m(i), float(self.yaw_deg[i]),
                       float(self.instance_scale[i]), i)

    def tree_leaf_table(self, i: int) -> LeafTable:
        """The leaf table of tree ``i`` in the world frame."""
        return self.local_tree(i).leaf_table.placed(self.translation_m(i), float(self.yaw_deg[i]),
                                                    float(self.instance_scale[i]), tree_id=i)

    def geometry(self, progress: bool = False) -> tuple[Branches, Leaves]:
        """Every tree placed in the world, in one Branches and one Leaves (tree order).

        This expands instances (a 300 m forest: ~2 GB of leaf triangles); arrays are
        allocated once and filled tree by tree, so the peak is the result plus one tree.
        """
        nb, nt = int(self.n_branches.sum()), int(self.n_leaf_triangles.sum())
        p0, p1, dia = np.empty((nb, 3)), np.empty((nb, 3)), np.empty(nb)
        order, tid = np.empty(nb, np.int32), np.empty(nb, np.int32)
        verts, lid, pid = np.empty((nt, 3, 3)), np.empty(nt, np.int32), np.empty(nt, np.int32)
        ib = il = 0
        for i in _bar(range(len(self)), progress, "placing trees", len(self)):
            b, lv = self.tree_geometry(i)
            sl = slice(ib, ib + len(b))
            p0[sl], p1[sl], dia[sl], order[sl], tid[sl] = b.p0, b.p1, b.diameter, b.order, b.tree_id
            sl = slice(il, il + len(lv))
            verts[sl], lid[sl], pid[sl] = lv.vertices, lv.leaf_id, lv.plant_id
            ib += len(b)
            il += len(lv)
        return Branches(p0, p1, dia, order, tid), Leaves(verts, lid, pid)

    def leaf_table(self, progress: bool = False) -> LeafTable:
        """One row per leaf of every tree, world frame (tree order)."""
        n = int(self.n_leaves.sum())
        cols = {"tree_id": np.empty(n, np.int32), "leaf_id": np.empty(n, np.int32),
                "centre_m": np.empty((n, 3)), "length_m": np.empty(n), "width_m": np.empty(n),
                "area_m2": np.empty(n), "normal": np.empty((n, 3)), "heading": np.empty((n, 3))}
        j = 0
        for i in _bar(range(len(self)), progress, "leaf table", len(self)):
            t = self.tree_leaf_table(i)
            for k, a in cols.items():
                a[j:j + len(t)] = getattr(t, k)
            j += len(t)
        return LeafTable(**cols)

    def instance_arrays(self) -> dict[str, Any]:
        """Keyword arguments of ``mitsuba_scene.Instances`` (instancing forests only).

        ``prototypes`` is a list of (Branches, Leaves) in the prototypes' own frames;
        tree ``t`` places ``prototypes[proto_index[t]]`` scaled by ``scale[t]`` (the
        instance scale: 1 in ``"wood"`` mode, whose prototypes carry their scale), turned
        by ``yaw_deg[t]`` about z and moved to ``translation_m[t]``.
        """
        if not self.instancing:
            raise ConfigError("this forest was made without instancing; use geometry()",
                              key="forest.instancing", value=False)
        return {"prototypes": [(t.branches, t.leaves) for t in self.prototypes],
                "proto_index": self.prototype.astype(np.int32),
                "translation_m": self.translation_m(), "yaw_deg": self.yaw_deg.astype(np.float64),
                "scale": self.instance_scale.astype(np.float64),
                "tree_id": np.arange(len(self), dtype=np.int32)}

    def trees_columns(self) -> dict[str, np.ndarray]:
        """The columns of ``trees.csv``."""
        names = np.array(self.species_names, dtype=object)
        return {"tree_id": np.arange(len(self)), "species": names[self.species] if len(self) else
                np.zeros(0, object), "x": self.x_m, "y": self.y_m, "z_base_m": self.base_z_m,
                "height_m": self.height_m, "crown_base_m": crown_bases_m(self), "dbh_m": dbhs_m(self),
                "n_branches": self.n_branches, "n_leaves": self.n_leaves, "seed": self.geometry_seed,
                "prototype": self.prototype, "yaw_deg": self.yaw_deg, "scale": self.scale,
                "crown_radius_m": self.crown_radius_m, **sector_radius_columns(
                    self.hulls, self.prototype if self.instancing else np.arange(len(self)), self.yaw_deg,
                    self.instance_scale), "branching": self.branching,
                "leaf_area_m2": self.leaf_area_m2, "crown_projection_m2": self.crown_projection_m2,
                **({"needle_area_m2": self.needle_area_m2}
                   if any(s.tree.shoot_star > 0 for s in self.params.species) else {})}

    def summary(self) -> dict[str, Any]:
        """Counts per species and totals (JSON-ready)."""
        p = self.placement
        ha = self.params.domain.area_m2 / 1e4
        per = []
        for j, s in enumerate(self.params.species):
            m = self.species == j
            req = float(p.requested[j])
            per.append({"name": s.name, "preset": s.preset,
                        # what the scene's ∫λ counts: Poisson points or trees of the final stand
                        "count_mode": p.count_mode[j],
                        "requested_count": req, "requested_density_per_ha": req / ha,
                        "count": int(m.sum()), "density_per_ha": float(m.sum()) / ha,
                        "count_over_requested": float(m.sum()) / req if req > 0 else None,
                        "target_count": int(p.target[j]) if p.target[j] >= 0 else None,
                        "count_reached": bool(p.reached[j]),
                        "candidates_drawn": int(p.count_before[j]),
                        "candidate_factor": float(p.candidate_factor[j]),
                        "removed_by_thinning": int(p.removed[j]),
                        # how far the thinning moves the count from ∫λ (poisson: drawn is the
                        # Poisson draw N ~ Poisson(∫λ); stand: the candidates it took)
                        "thinning": {"expected": req, "drawn": int(p.count_before[j]),
                                     "removed": int(p.removed[j]), "final": int(m.sum()),
                                     "final_minus_expected": float(m.sum()) - req},
                        "n_leaves": int(self.n_leaves[m].sum()),
                        "mean_height_m": float(self.height_m[m].mean()) if m.any() else None,
                        "mean_crown_radius_m": float(self.crown_radius_m[m].mean()) if m.any() else None,
                        "branching_flag_share": float(self.branching[m].mean()) if m.any() else None})
        tpp = np.bincount(self.prototype, minlength=len(self.prototypes)) if self.instancing else None
        return {"seed": int(self.seed), "n_trees": len(self), "instancing": self.instancing,
                "domain_m": [self.params.domain.x_min_m, self.params.domain.x_max_m,
                             self.params.domain.y_min_m, self.params.domain.y_max_m],
                "min_distance_m": self.params.min_distance_m,
                "crown_factor": self.params.crown_factor,
                # removed by the thinning step: minimum distance and crown rule together
                "removed_by_thinning": int(p.removed.sum()),
                "max_candidate_factor": self.params.max_candidate_factor,
                # share of trees with their nearest neighbour's trunk inside their own crown
                "crown_overlap_share": crown_overlap_share(self.x_m, self.y_m, self.crown_radius_m),
                "n_prototypes": len(self.prototypes),
                "trees_per_prototype_max": int(tpp.max(initial=0)) if tpp is not None else None,
                "trees_per_prototype_mean": (float(len(self) / len(self.prototypes))
                                             if tpp is not None and len(self.prototypes) else None),
                "scale_range": list(self.params.scale_range), "scale_mode": self.params.scale_mode,
                **self.info,
                "n_branches": int(self.n_branches.sum()), "n_leaves": int(self.n_leaves.sum()),
                "n_leaf_triangles": int(self.n_leaf_triangles.sum()),
                # geometry actually built (the prototypes, or every tree)
                "n_branches_built": (sum(len(t.branches) for t in self.prototypes) if self.instancing
                                     else int(self.n_branches.sum())),
                "n_leaf_triangles_built": (sum(len(t.leaves) for t in self.prototypes)
                                           if self.instancing else int(self.n_leaf_triangles.sum())),
                "representation": representation(self).as_dict(),
                "species": per, "foliage": foliage_summary(self), "seconds": dict(self.seconds)}


def _bar(it: Iterable, progress, desc: str, total: int | None = None) -> Iterable:
    """Trees of ``it`` as one stage of the shared progress helper (:mod:`simlidar_mi._runtime.progress`)."""
    return bar(it, progress, desc, total, unit="tree")


def _grow(params: ForestParams, species: np.ndarray, seeds: np.ndarray, tree_ids: np.ndarray,
          progress, desc: str) -> list[RandomTree]:
    """Tree k is ``random_tree(params.species[species[k]].tree, seeds[k], tree_id=tree_ids[k])``.

    The trees of a species grow together (:func:`iter_random_trees`: one numpy pass per
    generation for all of them); each draws from its own seed, so they are the trees grown
    one by one, bit for bit.
    """
    species = np.asarray(species)
    out: list[Any] = [None] * len(seeds)

    def grown():
        for j in np.unique(species):
            idx = np.flatnonzero(species == j)
            yield from zip(idx, iter_random_trees(params.species[int(j)].tree,
                                                  [int(seeds[k]) for k in idx],
                                                  [int(tree_ids[k]) for k in idx]))

    for k, t in _bar(grown(), progress, desc, total=len(seeds)):
        out[k] = t
    return out


def _with_tree_id(t: RandomTree, tid: int) -> RandomTree:
    """``t`` with its tree id set to ``tid`` (branches, leaves, leaf table); geometry untouched."""
    b, lv, lt = t.branches, t.leaves, t.leaf_table
    return dataclasses.replace(
        t, branches=Branches(b.p0, b.p1, b.diameter, b.order, np.full(len(b), tid, np.int32)),
        leaves=Leaves(lv.vertices, lv.leaf_id, np.full(len(lv), tid, np.int32)),
        leaf_table=dataclasses.replace(lt, tree_id=np.full(len(lt), tid, np.int32)))


def _resolve(config_or_params, seed) -> tuple[ForestParams, int]:
    if isinstance(config_or_params, (str, Path)):
        config_or_params = load_scene(config_or_params)
    if isinstance(config_or_params, SceneConfig):
        params = forest_params_from_scene(config_or_params)
        seed = config_or_params.seed if seed is None else seed
    elif isinstance(config_or_params, ForestParams):
        params = config_or_params
        if seed is None:
            raise ConfigError("make_forest(ForestParams, seed) needs a seed", key="seed", value=None)
    else:
        raise ConfigError("must be a SceneConfig, a scene path or ForestParams",
                          key="config_or_params", value=config_or_params)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError("must be a whole number ≥ 0", key="seed", value=seed)
    return params, int(seed)


def make_forest(config_or_params: SceneConfig | ForestParams | str | Path, seed: int | None = None,
                *, progress: bool = False, terrain=None) -> Forest:
    """Place and grow a forest.

    Order: the candidates of every species arrive in a random order; each one a kept
    tree does not already exclude gets its tree (grown from its own seed without
    instancing, else its prototype ``i // trees_per_prototype``), so its crown radius is
    known, and is kept or removed by the minimum distance and crown rule; a species stops
    at t = 1 (``count = "poisson"``) or when its stand is complete (``"stand"``).
    Instancing: prototypes no kept tree uses are dropped.

    Parameters
    ----------
    config_or_params : a scene (SceneConfig or path) with ``[forest]`` and ``[[species]]``,
        or ForestParams.
    seed : master seed (default: the scene's ``scene.seed``; required with ForestParams).
    progress : see :func:`simlidar_mi._runtime.progress.make_progress` (trees, prototypes).
    terrain : an :class:`~simlidar_mi.io.terrain.Terrain` the trees stand on (each trunk foot at
        the terrain height under it); default the scene's ``[terrain]``, if any.

    Returns
    -------
    Forest

    Examples
    --------
    >>> from simlidar_mi.forest.placement import Bump, Domain, SpeciesIntensity
    >>> from simlidar_mi.forest.params import ForestParams, ForestSpecies
    >>> from simlidar_mi.plants.tree_params import species_preset
    >>> sp = ForestSpecies("spruce", species_preset("conifer-whorl"),
    ...                    SpeciesIntensity("spruce", [Bump(0.02, 10, 10, 100, 100)]))
    >>> f = make_forest(ForestParams(Domain(0, 20, 0, 20), (sp,), 3.0, True, 2), seed=1)
    >>> len(f.prototypes) <= 2, bool((f.prototype >= 0).all())
    (True, True)
    """
    src = (config_or_params.source if isinstance(config_or_params, SceneConfig) else
           str(config_or_params) if isinstance(config_or_params, (str, Path)) else None)
    if isinstance(config_or_params, (str, Path)):
        config_or_params = load_scene(config_or_params)
    if terrain is None and isinstance(config_or_params, SceneConfig):
        terrain = terrain_of(config_or_params)
    params, seed = _resolve(config_or_params, seed)
    seconds: dict[str, float] = {}
    t_grow = 0.0
    lo, hi = params.scale_range
    whole = params.scale_mode == "whole-tree"
    tpp = params.trees_per_prototype
    fixed_k = None if params.prototypes_per_species == "auto" else int(params.prototypes_per_species)
    # only crown radii are kept while thinning (the grown candidates of a 300 m stand are
    # 2886 prototypes, 7.8 GB); the kept trees and used prototypes are grown again after it,
    # from the same seeds, so they are the same bytes. A fixed K (default 12) grows at most K
    # prototypes a species: those are kept from the thinning instead of grown twice
    tree_r: dict[tuple[int, int], float] = {}      # (species, candidate) → crown radius (no instancing)
    proto_r: dict[tuple[int, int], float] = {}     # (species, k) → prototype crown radius, wood scaled
    proto_scale: dict[tuple[int, int], float] = {}
    n_tri: dict[tuple[str, int, int], int] = {}   # leaf triangles of what was grown: memory check
    kept_protos: dict[tuple[int, int], RandomTree] = {}   # fixed K: the prototypes grown while thinning
    n_grown = [0]
    # one progress stage for all the batches the thinning asks for
    stage = make_progress(progress).stage("trees" if not params.instancing else "prototypes",
                                          unit="tree")

    def proto_of(i: np.ndarray) -> np.ndarray:
        """Prototype k of a species' candidates (arrival index i): blocks of trees_per_prototype
        ("auto": no prototype serves more), or i mod K; arrival order is already random."""
        return i // tpp if fixed_k is None else i % fixed_k

    def grow_trees(j: int, idx) -> list[RandomTree]:
        """Candidates ``idx`` of species ``j``, each grown from its own seed."""
        seeds = np.array([tree_seed(seed, j, int(i)) for i in idx], np.int64)
        out = _grow(params, np.full(len(idx), j), seeds, np.zeros(len(idx), np.int64), False, "trees")
        stage.update(len(idx))
        return out

    def grow_protos(j: int, ks) -> list[RandomTree]:
        """Prototypes ``ks`` of species ``j``, wood scaled (their scale noted)."""
        sc = [1.0 if whole else prototype_scale(seed, j, k, (lo, hi)) for k in ks]
        grown = _grow(params, np.full(len(ks), j), np.array([prototype_seed(seed, j, k) for k in ks],
                                                              np.int64), np.zeros(len(ks), np.int64),
                      False, "prototypes")
        proto_scale.update({(j, k): s_ for k, s_ in zip(ks, sc)})
        stage.update(len(ks))
        return [t.wood_scaled(s_) for t, s_ in zip(grown, sc)]

    def crown(x, y, j: int, idx: np.ndarray) -> np.ndarray:
        """The crown radii of candidates ``idx`` of species ``j``, growing what they need."""
        nonlocal t_grow
        t0 = time.perf_counter()
        n_grown[0] += len(idx)
        if n_grown[0] > params.max_trees * 4 + 1000:   # growing candidates costs memory; refuse early
            raise ConfigError(f"the Poisson processes drew {n_grown[0]} trees, far more than "
                              "forest.max_trees", key="forest.max_trees", value=params.max_trees)
        if not params.instancing:
            for i, t in zip(idx, grow_trees(j, idx)):
                tree_r[(j, int(i))], n_tri[("t", j, int(i))] = t.crown_radius_m, len(t.leaves)
            t_grow += time.perf_counter() - t0
            return np.array([tree_r[(j, int(i))] for i in idx])
        ks = sorted({int(k) for k in proto_of(idx)} - {k for (jj, k) in proto_r if jj == j})
        for k, t in zip(ks, grow_protos(j, ks)):
            proto_r[(j, k)], n_tri[("p", j, k)] = t.crown_radius_m, len(t.leaves)
            if fixed_k is not None:
                kept_protos[(j, k)] = t
        if fixed_k is not None and ks:  # the K × species prototypes the thinning keeps, projected
            # from those grown so far: refused after the first batch, not after all of them
            known = [n for (kind, _, _), n in n_tri.items() if kind == "p"]
            _check_grown(known + [None] * (fixed_k * len(params.species) - len(known)), params,
                         "its prototypes", src)
        r = np.array([proto_r[(j, int(k))] for k in proto_of(idx)])
        if whole:   # each tree's scale comes from its own seed (after its yaw)
            r = r * np.array([_yaw_scale(tree_seed(seed, j, int(i)), lo, hi)[1] for i in idx])
        t_grow += time.perf_counter() - t0
        return r

    t0 = time.perf_counter()
    use_crowns = params.crown_factor > 0 or params.instancing
    placement = place_trees([s.intensity for s in params.species], params.domain,
                            params.min_distance_m,
                            np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))),
                            crown_radius=crown if use_crowns else None,
                            crown_factor=params.crown_factor,
                            count=[s.count for s in params.species],
                            max_candidate_factor=params.max_candidate_factor)
    n = len(placement)
    if n > params.max_trees:
        raise ConfigError(f"the placement holds {n} trees, more than forest.max_trees",
                          key="forest.max_trees", value=params.max_trees)
    sp, cand = placement.species, placement.candidate
    base_z = None
    if terrain is not None:
        check_inside(terrain, placement.x_m, placement.y_m, "trees", src)
        base_z = terrain.height_m(placement.x_m, placement.y_m)
    seeds = np.array([tree_seed(seed, int(j), int(c)) for j, c in zip(sp, cand)], np.int64)
    seconds["place"] = time.perf_counter() - t0 - t_grow

    t0 = time.perf_counter()
    info: dict[str, Any] = {"n_candidates": int(placement.count_before.sum()),
                            **({"terrain": terrain.describe()} if terrain is not None else {})}
    if params.instancing:
        keys = [(int(j), int(k)) for j, k in zip(sp, proto_of(cand))]
        used = sorted(set(keys))
        _check_grown([n_tri.get(("p", j, k)) for j, k in used], params, "its prototypes", src)
        where = {key: m for m, key in enumerate(used)}
        prototype = np.array([where[key] for key in keys], np.int32)
        grown = {key: kept_protos[key] for key in used if key in kept_protos}
        kept_protos.clear()
        for j in sorted({j for j, _ in used}):
            ks = [k for jj, k in used if jj == j and (jj, k) not in grown]
            grown.update({(j, k): t for k, t in zip(ks, grow_protos(j, ks))})
        protos_used = tuple(_with_tree_id(grown[key], m) for m, key in enumerate(used))
        proto_sp = np.array([j for j, _ in used], np.int32)
        proto_seed = np.array([prototype_seed(seed, j, k) for j, k in used], np.int64)
        info["n_prototypes_grown"] = len(proto_r)
        ys = [_yaw_scale(int(s_), lo, hi) for s_ in seeds]
        yaw = np.array([a for a, _ in ys], np.float64)
        scale = np.array([b if whole else proto_scale[key] for (_, b), key in zip(ys, keys)], np.float64)
        placed = None
    else:
        proto_sp, proto_seed, protos_used = np.zeros(0, np.int32), np.zeros(0, np.int64), ()
        grown = {}
        _check_grown([n_tri.get(("t", int(j), int(c))) for j, c in zip(sp, cand)], params, "its trees", src)
        for j in np.unique(sp):
            idx = cand[sp == j]
            grown.update({(int(j), int(i)): t for i, t in zip(idx, grow_trees(int(j), idx))})
        placed = tuple(_with_tree_id(grown[(int(j), int(c))], i) for i, (j, c) in enumerate(zip(sp, cand)))
        info["n_trees_grown"] = len(tree_r) or n
        prototype = np.full(n, -1, np.int32)
        yaw, scale = np.zeros(n), np.ones(n)
    stage.close()
    seconds["grow"] = t_grow + time.perf_counter() - t0
    return Forest(params, seed, placement, seeds, prototype, yaw, scale, protos_used, proto_sp,
                  proto_seed, placed, base_z_m=base_z, seconds=seconds, info=info)


def _check_grown(n_tri: list, params: ForestParams, what: str, src: str | None) -> None:
    """Refuse, before they are grown again and kept, trees whose leaf triangles (counted when the
    thinning grew them; None where it did not) would hold more than ``forest.memory_limit_gb``."""
    known = [n for n in n_tri if n is not None]
    if known:  # trees the thinning did not grow count as the mean of those it did
        need = GROWN_BYTES_PER_TRIANGLE * sum(known) * len(n_tri) / len(known)
        check_memory(need, params.memory_limit_gb, f"the forest ({len(n_tri)} of {what}, "
                     f"~{round(sum(known) * len(n_tri) / len(known)):,} leaf triangles)", src)


def _yaw_scale(seed: int, lo: float, hi: float) -> tuple[float, float]:
    """A tree's yaw (uniform 0–360°) and whole-tree scale, from its own seed."""
    r = np.random.default_rng(seed)
    return float(r.uniform(0.0, 360.0)), float(r.uniform(lo, hi))
