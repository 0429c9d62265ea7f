"""The stand: Poisson-placed random trees, each grown or instanced (Wahed et al., seed 004, §III).

A forest is one inhomogeneous Poisson process per species on a rectangle
(:func:`simlidar_mi.forest.placement.place_trees`: squared-exponential bumps,
Lewis–Shedler thinning, then a minimum-distance thinning whose removals are
reported), and one random tree (:mod:`simlidar_mi.plants.random_tree`) per
position. Two modes:

``instancing = true``
    Each species gets ``K = prototypes_per_species`` prototype trees, each drawn
    from its own seed; tree ``t`` picks one of its species' prototypes and a yaw
    (uniform 0–360°) and uniform scale (uniform in ``scale_range``) from *its* seed.
    Geometry is built K times a species and placed as instances: the way a
    300 m × 300 m forest fits in memory.
``instancing = false``
    Every tree is its own random draw (yaw 0, scale 1).

Parameters and seeds are in :mod:`simlidar_mi.forest.params`, the files of
``simlidar-mi forest`` in :mod:`simlidar_mi.forest.run`.

A placed tree's world coordinates are ``p_world = (x, y, 0) + Rz(yaw)·(scale·p_local)``
(the same order as Mitsuba's ``translate · rotate · scale``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from ..plants.random_tree import RandomTree, random_tree
from ..plants.tree_leaves import LeafTable
from .params import ForestParams, forest_params_from_scene, prototype_seed, tree_seed
from .placement import Placement, expected_count, place_trees

__all__ = ["Forest", "make_forest"]


# --- the forest ------------------------------------------------------------------------


def _rot_z(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _place(points: np.ndarray, t: np.ndarray, yaw_deg: float, scale: float) -> np.ndarray:
    """``t + Rz(yaw)·(scale·p)`` for points of any leading shape (…, 3)."""
    return (scale * points) @ _rot_z(yaw_deg).T + t


@dataclass
class Forest:
    """A placed forest: positions, per-tree seeds and either prototypes or every tree.

    Attributes
    ----------
    params, seed : what it was made from.
    placement : the Poisson placement (counts before/after the distance thinning).
    tree_seed : (n,) int64, each tree's own seed.
    prototype : (n,) int32 index into ``prototypes`` (−1 without instancing).
    yaw_deg, scale : (n,) the placement transform of each tree (0 and 1 without instancing).
    prototypes : instancing: the prototype trees (own frame), ``prototype_species[k]``
        their species and ``prototype_seed[k]`` their seeds; empty otherwise.
    trees : without instancing, every tree in its own frame (tree_id = its index).
    height_m, crown_radius_m : (n,) of each placed tree.
    n_branches, n_leaves, n_leaf_triangles : (n,) per tree.
    seconds : time spent per step.
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
    seconds: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self)
        loc = [self.local_tree(i) for i in range(n)] if self.trees is not None else None
        if self.instancing:
            ph = np.array([t.height_m for t in self.prototypes])
            pc = np.array([t.crown_radius_m for t in self.prototypes])
            pb = np.array([len(t.branches) for t in self.prototypes], np.int64)
            pl = np.array([t.n_leaves for t in self.prototypes], np.int64)
            pt = np.array([len(t.leaves) for t in self.prototypes], np.int64)
            p = self.prototype
            self.height_m = ph[p] * self.scale if n else np.zeros(0)
            self.crown_radius_m = pc[p] * self.scale if n else np.zeros(0)
            self.n_branches, self.n_leaves, self.n_leaf_triangles = (
                (a[p] if n else np.zeros(0, np.int64)) for a in (pb, pl, pt))
        else:
            self.height_m = np.array([t.height_m for t in loc])
            self.crown_radius_m = np.array([t.crown_radius_m for t in loc])
            self.n_branches = np.array([len(t.branches) for t in loc], np.int64)
            self.n_leaves = np.array([t.n_leaves for t in loc], np.int64)
            self.n_leaf_triangles = np.array([len(t.leaves) for t in loc], np.int64)

    def __len__(self) -> int:
        return len(self.placement)

    @property
    def instancing(self) -> bool:
        return self.trees is None

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
        """Tree foot(s) ``(x, y, 0)``: (3,) for one tree, (n, 3) for all."""
        if i is None:
            return np.column_stack([self.x_m, self.y_m, np.zeros(len(self))])
        return np.array([self.x_m[i], self.y_m[i], 0.0])

    def local_tree(self, i: int) -> RandomTree:
        """Tree ``i`` in its own frame (its prototype when instancing)."""
        if self.trees is None:
            return self.prototypes[int(self.prototype[i])]
        return self.trees[i]

    def tree_geometry(self, i: int) -> tuple[Branches, Leaves]:
        """Tree ``i`` placed in the world (tree_id / plant_id = ``i``)."""
        t = self.local_tree(i)
        tr, yaw, s = self.translation_m(i), float(self.yaw_deg[i]), float(self.scale[i])
        b = t.branches
        br = Branches(_place(b.p0, tr, yaw, s), _place(b.p1, tr, yaw, s), b.diameter * s, b.order,
                      np.full(len(b), i, np.int32))
        lv = Leaves(_place(t.leaves.vertices, tr, yaw, s), t.leaves.leaf_id,
                    np.full(len(t.leaves), i, np.int32))
        return br, lv

    def tree_leaf_table(self, i: int) -> LeafTable:
        """The leaf table of tree ``i`` in the world frame."""
        return self.local_tree(i).leaf_table.placed(self.translation_m(i), float(self.yaw_deg[i]),
                                                    float(self.scale[i]), tree_id=i)

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
        tree ``t`` places ``prototypes[proto_index[t]]`` scaled by ``scale[t]``, turned
        by ``yaw_deg[t]`` about z and moved to ``translation_m[t]``.
        """
        if not self.instancing:
            raise ConfigError("this forest was made without instancing; use geometry()",
                              key="forest.instancing", value=False)
        return {"prototypes": [(t.branches, t.leaves) for t in self.prototypes],
                "proto_index": self.prototype.astype(np.int32),
                "translation_m": self.translation_m(), "yaw_deg": self.yaw_deg.astype(np.float64),
                "scale": self.scale.astype(np.float64), "tree_id": np.arange(len(self), dtype=np.int32)}

    def trees_columns(self) -> dict[str, np.ndarray]:
        """The columns of ``trees.csv``."""
        names = np.array(self.species_names, dtype=object)
        return {"tree_id": np.arange(len(self)), "species": names[self.species] if len(self) else
                np.zeros(0, object), "x": self.x_m, "y": self.y_m, "height_m": self.height_m,
                "n_branches": self.n_branches, "n_leaves": self.n_leaves, "seed": self.tree_seed,
                "prototype": self.prototype, "yaw_deg": self.yaw_deg, "scale": self.scale,
                "crown_radius_m": self.crown_radius_m}

    def summary(self) -> dict[str, Any]:
        """Counts per species and totals (JSON-ready)."""
        p = self.placement
        exp = expected_count([s.intensity for s in self.params.species], self.params.domain)
        per = []
        for j, s in enumerate(self.params.species):
            m = self.species == j
            per.append({"name": s.name, "preset": s.preset,
                        "expected_before_thinning": float(exp[j]),
                        "count_before_thinning": int(p.count_before[j]),
                        "removed_by_min_distance": int(p.removed[j]),
                        "count": int(m.sum()),
                        "n_leaves": int(self.n_leaves[m].sum()),
                        "mean_height_m": float(self.height_m[m].mean()) if m.any() else None})
        return {"seed": int(self.seed), "n_trees": len(self), "instancing": self.instancing,
                "domain_m": [self.params.domain.x_min_m, self.params.domain.x_max_m,
                             self.params.domain.y_min_m, self.params.domain.y_max_m],
                "min_distance_m": self.params.min_distance_m,
                "removed_by_min_distance": int(p.removed.sum()),
                "n_prototypes": len(self.prototypes),
                "n_branches": int(self.n_branches.sum()), "n_leaves": int(self.n_leaves.sum()),
                "n_leaf_triangles": int(self.n_leaf_triangles.sum()),
                # geometry actually built (the prototypes, or every tree)
                "n_branches_built": (sum(len(t.branches) for t in self.prototypes) if self.instancing
                                     else int(self.n_branches.sum())),
                "n_leaf_triangles_built": (sum(len(t.leaves) for t in self.prototypes)
                                           if self.instancing else int(self.n_leaf_triangles.sum())),
                "species": per, "seconds": dict(self.seconds)}


def _bar(it: Iterable, enabled: bool, desc: str, total: int | None = None) -> Iterable:
    """A tqdm bar over ``it`` when enabled (CLI on a terminal), else ``it``."""
    if not enabled:
        return it
    from tqdm import tqdm  # noqa: PLC0415
    return tqdm(it, desc=desc, total=total, unit="tree", leave=False)


def make_forest(config_or_params: SceneConfig | ForestParams | str | Path, seed: int | None = None,
                *, progress: bool = False) -> Forest:
    """Place and grow a forest.

    Parameters
    ----------
    config_or_params : a scene (SceneConfig or path) with ``[forest]`` and ``[[species]]``,
        or ForestParams.
    seed : master seed (default: the scene's ``scene.seed``; required with ForestParams).
    progress : tqdm bar over the trees (or prototypes).

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
    >>> len(f.prototypes), bool((f.prototype >= 0).all())
    (2, True)
    """
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
    seed = int(seed)
    seconds: dict[str, float] = {}

    t0 = time.perf_counter()
    placement = place_trees([s.intensity for s in params.species], params.domain,
                            params.min_distance_m,
                            np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))))
    n = len(placement)
    if n > params.max_trees:
        raise ConfigError(f"the placement holds {n} trees, more than forest.max_trees",
                          key="forest.max_trees", value=params.max_trees)
    seeds = np.array([tree_seed(seed, i) for i in range(n)], np.int64)
    seconds["place"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    K = int(params.prototypes_per_species)
    if params.instancing:
        proto_sp = np.repeat(np.arange(len(params.species), dtype=np.int32), K)
        proto_seed = np.array([prototype_seed(seed, j, k) for j in range(len(params.species))
                               for k in range(K)], np.int64)
        protos = tuple(random_tree(params.species[int(j)].tree, int(s), tree_id=p)
                       for p, (j, s) in _bar(list(enumerate(zip(proto_sp, proto_seed))), progress,
                                             "prototypes"))
        lo, hi = params.scale_range
        prototype = np.empty(n, np.int32)
        yaw = np.empty(n)
        scale = np.empty(n)
        for i in range(n):  # each tree's choice comes from its own seed
            r = np.random.default_rng(int(seeds[i]))
            prototype[i] = int(placement.species[i]) * K + int(r.integers(K))
            yaw[i] = r.uniform(0.0, 360.0)
            scale[i] = r.uniform(lo, hi)
        trees = None
    else:
        proto_sp = np.zeros(0, np.int32)
        proto_seed = np.zeros(0, np.int64)
        protos = ()
        trees = tuple(random_tree(params.species[int(placement.species[i])].tree, int(seeds[i]),
                                  tree_id=i)
                      for i in _bar(range(n), progress, "trees", total=n))
        prototype = np.full(n, -1, np.int32)
        yaw = np.zeros(n)
        scale = np.ones(n)
    seconds["grow"] = time.perf_counter() - t0
    return Forest(params, seed, placement, seeds, prototype, yaw, scale, protos, proto_sp,
                  proto_seed, trees, seconds=seconds)
