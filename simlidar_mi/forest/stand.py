"""Random forests: Poisson-placed random trees (Wahed et al., seed 004, §III).

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

Seeds: from the scene seed ``S``, the placement uses ``SeedSequence(S, spawn_key=(0,))``,
tree ``t`` the integer ``seed_t`` made from ``SeedSequence(S, spawn_key=(1, t))`` and
prototype ``k`` of species ``j`` one from ``spawn_key=(2, j, k)``. Integer seeds are
53-bit, written to ``trees.csv``; ``random_tree(params, seed_t)`` rebuilds tree ``t``
of a non-instanced forest bit for bit. Changing one tree's seed changes no other tree.

A placed tree's world coordinates are ``p_world = (x, y, 0) + Rz(yaw)·(scale·p_local)``
(the same order as Mitsuba's ``translate · rotate · scale``).

``run_forest`` (``simlidar-mi forest SCENE.toml --out DIR``) writes into ``DIR``:

``trees.csv``
    ``tree_id, species, x, y, height_m, n_branches, n_leaves, seed, prototype,
    yaw_deg, scale, crown_radius_m`` (metres, degrees; ``prototype = -1`` without
    instancing; ``height_m`` is the highest z of the tree's branch end points and
    leaf vertices).
``leaves.csv`` (``leaves.parquet`` when pyarrow is importable)
    ``tree_id, leaf_id, x, y, z, length_m, width_m, area_m2, nx, ny, nz, hx, hy, hz``:
    blade centre, size, one-sided polygon area, upper-side unit normal and unit
    base→tip heading, world frame. ``leaf_table = "prototypes"`` writes
    ``prototype_leaves.csv`` instead (column ``prototype`` for ``tree_id``, prototype
    frame; place rows with the transforms of ``trees.csv``). ``"auto"`` (default)
    writes all leaves up to ``leaf_table_max_rows`` (1 M rows ≈ 110 MB of CSV),
    else the prototypes' leaves when instancing; ``"none"`` writes nothing.
``layout.png``
    trees as crown-sized discs coloured by species, over the intensity contours.
``preview.png``
    side and top views of a central strip of at most ``preview_max_trees`` trees
    (branches as lines, leaves as dots), every crown outlined in the top view.
``stand.ply`` / ``stand.obj``
    the whole stand (branches as open prisms, leaves as triangles; PLY faces carry
    ``part`` 0 = wood / 1 = leaves and ``tree_id``; OBJ has ``o wood`` and
    ``o leaves``) — see :mod:`simlidar_mi.io.mesh_export`. ``export = "auto"``
    writes the stand up to ``export_max_triangles``, else (instancing only) one
    ``prototypes/<species>_<k>.ply`` per prototype in its own frame.
``forest.json``
    counts per species (expected, before and removed by the distance thinning,
    placed), totals, the modes chosen and the seconds per step.
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from ..io.atomic import staged_dir
from ..io.mesh_export import (PART_LEAVES, PART_WOOD, prism_tubes, tube_faces, write_obj_stream,
                             write_ply_stream)
from .placement import (Bump, Domain, Placement, SpeciesIntensity, expected_count,
                             intensity_grid, place_trees)
from ..plants.random_tree import (SPECIES_PRESETS, LeafTable, RandomTree, RandomTreeParams,
                                 random_tree, species_preset, tree_params_from_dict)

__all__ = ["ForestSpecies", "ForestParams", "Forest", "ForestRun", "make_forest",
           "forest_params_from_scene", "run_forest", "tree_seed", "prototype_seed",
           "plot_layout", "plot_preview", "write_stand"]


def _bare(exc: ConfigError) -> str:
    """The message of a ConfigError without its 'file, key, value: ' prefix."""
    where = []
    if exc.file:
        where.append(exc.file)
    if exc.key:
        where.append(f"key '{exc.key}'")
    if exc.key is not None or exc.value is not None:
        where.append(f"value {exc.value!r}")
    prefix = ", ".join(where) + ": " if where else ""
    s = str(exc)
    return s[len(prefix):] if s.startswith(prefix) else s


# --- parameters ------------------------------------------------------------------------


@dataclass(frozen=True)
class ForestSpecies:
    """One species of a forest: its random-tree laws and its intensity (names must match).

    ``preset`` records the random-tree preset the laws started from (informative).
    """

    name: str
    tree: RandomTreeParams
    intensity: SpeciesIntensity
    preset: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.tree, RandomTreeParams):
            raise ConfigError("must be a RandomTreeParams", key=f"{self.name}.tree", value=self.tree)
        if not isinstance(self.intensity, SpeciesIntensity):
            raise ConfigError("must be a SpeciesIntensity", key=f"{self.name}.intensity",
                              value=self.intensity)
        if self.intensity.name != self.name:
            raise ConfigError(f"intensity is named {self.intensity.name!r}, species {self.name!r}",
                              key=f"{self.name}.intensity.name", value=self.intensity.name)


@dataclass(frozen=True)
class ForestParams:
    """Everything ``make_forest`` needs besides the seed.

    Parameters
    ----------
    domain : rectangle (Domain or ``(x_min, x_max, y_min, y_max)``, metres).
    species : at least one, distinct names.
    min_distance_m : minimum distance between any two trees (0: no thinning).
    instancing : prototypes + per-tree transforms (true) or one draw per tree (false).
    prototypes_per_species : K.
    scale_range : ``(min, max)`` of the uniform per-tree scale of instanced trees.
    max_trees : refuse placements with more trees.
    """

    domain: Domain
    species: tuple[ForestSpecies, ...]
    min_distance_m: float = 3.0
    instancing: bool = True
    prototypes_per_species: int = 12
    scale_range: tuple[float, float] = (0.85, 1.15)
    max_trees: int = 100_000

    def __post_init__(self) -> None:
        object.__setattr__(self, "domain", Domain.of(self.domain))
        sp = tuple(self.species)
        if not sp:
            raise ConfigError("a forest needs at least one species", key="species", value=[])
        names = [s.name for s in sp]
        for s in sp:
            if not isinstance(s, ForestSpecies):
                raise ConfigError("must be a ForestSpecies", key="species", value=s)
            if names.count(s.name) > 1:
                raise ConfigError("species names must be distinct", key="species.name", value=s.name)
        object.__setattr__(self, "species", sp)
        d = float(self.min_distance_m)
        if not (math.isfinite(d) and d >= 0):
            raise ConfigError("must be a finite number ≥ 0 m", key="forest.min_distance_m",
                              value=self.min_distance_m)
        object.__setattr__(self, "min_distance_m", d)
        if not isinstance(self.instancing, (bool, np.bool_)):
            raise ConfigError("must be true or false", key="forest.instancing", value=self.instancing)
        k = self.prototypes_per_species
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= 1000:
            raise ConfigError("must be a whole number in [1, 1000]",
                              key="forest.prototypes_per_species", value=k)
        lo, hi = (float(v) for v in self.scale_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ConfigError("must be [min, max] with 0 < min ≤ max", key="forest.scale_range",
                              value=self.scale_range)
        object.__setattr__(self, "scale_range", (lo, hi))
        if isinstance(self.max_trees, bool) or not isinstance(self.max_trees, (int, np.integer)) \
                or self.max_trees < 1:
            raise ConfigError("must be a whole number ≥ 1", key="forest.max_trees", value=self.max_trees)


_BUMP_KEYS = ("C_per_m2", "x0_m", "y0_m", "h_m2", "l_m2")


def _bump(table: Any, key: str, src: str) -> Bump:
    if not isinstance(table, dict):
        raise ConfigError("must be a table {C_per_m2, x0_m, y0_m, h_m2, l_m2}", file=src, key=key,
                          value=table)
    for k in table:
        if k not in _BUMP_KEYS:
            raise ConfigError(f"unknown bump field; valid: {', '.join(_BUMP_KEYS)}", file=src,
                              key=f"{key}.{k}", value=table[k])
    vals = {}
    for k in _BUMP_KEYS:
        if k not in table:
            raise ConfigError("missing", file=src, key=f"{key}.{k}")
        v = table[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError("must be a finite number", file=src, key=f"{key}.{k}", value=v)
        vals[k] = float(v)
    if vals["C_per_m2"] < 0:
        raise ConfigError("peak intensity must be ≥ 0 trees/m²", file=src, key=f"{key}.C_per_m2",
                          value=vals["C_per_m2"])
    for k in ("h_m2", "l_m2"):
        if vals[k] <= 0:
            raise ConfigError("spread must be > 0 m²", file=src, key=f"{key}.{k}", value=vals[k])
    return Bump(**vals)


def forest_params_from_scene(cfg: SceneConfig) -> ForestParams:
    """The ``[forest]`` section and ``[[species]]`` tables of a scene → ForestParams.

    Raises
    ------
    ConfigError
        naming the file, the key (``species[1].tree.leaf_length_m.sd``) and value.
    """
    src = cfg.source
    f = cfg["forest"]
    species = []
    for j, sp in enumerate(cfg.arrays.get("species", [])):
        key = f"species[{j}]"
        if not sp.get("name"):
            raise ConfigError("every species needs a name", file=src, key=f"{key}.name")
        name = sp["name"]
        if sp.get("preset") is None:
            raise ConfigError(f"missing; valid presets: {', '.join(SPECIES_PRESETS)}", file=src,
                              key=f"{key}.preset")
        if sp["preset"] not in SPECIES_PRESETS:
            raise ConfigError(f"unknown preset; valid: {', '.join(SPECIES_PRESETS)}", file=src,
                              key=f"{key}.preset", value=sp["preset"])
        try:
            tree = tree_params_from_dict({"name": name, **(sp.get("tree") or {})},
                                         species_preset(sp["preset"]), f"{key}.tree.")
        except ConfigError as exc:
            raise ConfigError(_bare(exc), file=src, key=exc.key, value=exc.value) from None
        bumps = [_bump(b, f"{key}.bumps[{i}]", src) for i, b in enumerate(sp.get("bumps") or [])]
        if not bumps and not sp.get("background_per_m2"):
            raise ConfigError("a species needs bumps or a background intensity", file=src,
                              key=f"{key}.bumps", value=sp.get("bumps"))
        species.append(ForestSpecies(name, tree, SpeciesIntensity(name, bumps,
                                                                  sp.get("background_per_m2") or 0.0),
                                     sp["preset"]))
    if not species:
        raise ConfigError("a [forest] needs at least one [[species]] table", file=src, key="species")
    try:
        return ForestParams(Domain(*f["domain_m"]), tuple(species), f["min_distance_m"], f["instancing"],
                            f["prototypes_per_species"], tuple(f["scale_range"]), f["max_trees"])
    except ConfigError as exc:
        raise ConfigError(_bare(exc), file=src, key=exc.key, value=exc.value) from None


# --- seeds -----------------------------------------------------------------------------


def _seed53(seed: int, spawn_key: tuple[int, ...]) -> int:
    ss = np.random.SeedSequence(int(seed), spawn_key=spawn_key)
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(11))


def tree_seed(forest_seed: int, tree_id: int) -> int:
    """The 53-bit integer seed of tree ``tree_id`` of a forest with seed ``forest_seed``."""
    return _seed53(forest_seed, (1, int(tree_id)))


def prototype_seed(forest_seed: int, species_index: int, k: int) -> int:
    """The integer seed of prototype ``k`` of species ``species_index``."""
    return _seed53(forest_seed, (2, int(species_index), int(k)))


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


# --- writers ---------------------------------------------------------------------------

_LEAF_FMT = ["%d", "%d", "%.5f", "%.5f", "%.5f", "%.6g", "%.6g", "%.7g",
             "%.6f", "%.6f", "%.6f", "%.6f", "%.6f", "%.6f"]


def _leaf_tables_csv(path: Path, tables: Iterable[LeafTable], id_name: str) -> int:
    """Write leaf tables as one CSV (streamed); returns the rows written."""
    cols = list(LeafTable.COLUMNS)
    cols[0] = id_name
    rows = 0
    with open(path, "w") as fh:
        fh.write(",".join(cols) + "\n")
        for t in tables:
            if not len(t):
                continue
            c = t.columns()
            arr = np.column_stack([c[k] for k in LeafTable.COLUMNS])
            np.savetxt(fh, arr, fmt=_LEAF_FMT, delimiter=",")
            rows += len(t)
    return rows


def _leaf_tables_parquet(path: Path, tables: Iterable[LeafTable], id_name: str) -> int:
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.parquet as pq  # noqa: PLC0415
    rows = 0
    writer = None
    try:
        for t in tables:
            if not len(t):
                continue
            c = t.columns()
            c = {(id_name if k == "tree_id" else k): v for k, v in c.items()}
            tab = pa.table({k: pa.array(np.ascontiguousarray(v)) for k, v in c.items()})
            if writer is None:
                writer = pq.ParquetWriter(str(path), tab.schema)
            writer.write_table(tab)
            rows += len(t)
        if writer is None:
            schema = pa.schema([(id_name, pa.int32()), ("leaf_id", pa.int32())] +
                               [(k, pa.float64()) for k in LeafTable.COLUMNS[2:]])
            writer = pq.ParquetWriter(str(path), schema)
    finally:
        if writer is not None:
            writer.close()
    return rows


def _have_pyarrow() -> bool:
    try:
        import pyarrow.parquet  # noqa: F401, PLC0415  (only asking whether it imports)
    except ImportError:
        return False
    return True


def _write_trees_csv(path: Path, forest: Forest) -> None:
    c = forest.trees_columns()
    fmt = {"x": "{:.6f}", "y": "{:.6f}", "height_m": "{:.6f}", "yaw_deg": "{:.6f}",
           "scale": "{:.8f}", "crown_radius_m": "{:.6f}"}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(c))
        for i in range(len(forest)):
            w.writerow([fmt[k].format(v[i]) if k in fmt else v[i] for k, v in c.items()])


@dataclass
class _Stand:
    """Trees to mesh: tree ``i`` is ``local(i)`` placed by ``place(i) = (t, yaw, scale)``;
    ``key(i)`` names identical geometry (a prototype) so its prisms are built once."""

    n: int
    local: Any
    place: Any
    key: Any

    @classmethod
    def of(cls, forest: Forest) -> "_Stand":
        return cls(len(forest), forest.local_tree,
                   lambda i: (forest.translation_m(i), float(forest.yaw_deg[i]), float(forest.scale[i])),
                   (lambda i: int(forest.prototype[i])) if forest.instancing else (lambda i: None))


def _write_mesh(stand: _Stand, path: Path, fmt: str, facets: int, progress: bool,
                comments: list[str]) -> Path:
    k = int(facets)
    n = stand.n
    nb = np.array([len(stand.local(i).branches) for i in range(n)], np.int64)
    nt = np.array([len(stand.local(i).leaves) for i in range(n)], np.int64)
    cache: dict = {}

    def mesh(i: int) -> tuple[np.ndarray, np.ndarray]:
        """World vertices of tree ``i``: wood prisms, leaf triangles (3 per triangle)."""
        t, key = stand.local(i), stand.key(i)
        wood = cache.get(key) if key is not None else None
        if wood is None:
            wood = prism_tubes(t.branches, k)
            if key is not None:
                cache[key] = wood
        tr, yaw, s = stand.place(i)
        return _place(wood, tr, yaw, s), _place(t.leaves.vertices.reshape(-1, 3), tr, yaw, s)

    if fmt == "ply":
        def verts() -> Iterator[np.ndarray]:
            for i in _bar(range(n), progress, path.name, total=n):
                yield from mesh(i)

        def faces() -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
            off = 0
            for i in range(n):
                b, ntri = int(nb[i]), int(nt[i])
                f = np.concatenate([tube_faces(b, k, off),
                                    off + 2 * k * b + np.arange(3 * ntri, dtype=np.int64).reshape(-1, 3)])
                part = np.concatenate([np.full(2 * k * b, PART_WOOD, np.uint8),
                                       np.full(ntri, PART_LEAVES, np.uint8)])
                yield f, part, np.full(len(f), i, np.int32)
                off += 2 * k * b + 3 * ntri

        return write_ply_stream(path, int((2 * k * nb + 3 * nt).sum()), int((2 * k * nb + nt).sum()),
                                verts(), faces(), comments)
    if fmt == "obj":
        def wood() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for i in _bar(range(n), progress, path.name, total=n):
                yield mesh(i)[0], tube_faces(int(nb[i]), k)

        def leaves() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for i in range(n):
                t = stand.local(i)
                tr, yaw, s = stand.place(i)
                v = _place(t.leaves.vertices.reshape(-1, 3), tr, yaw, s)
                yield v, np.arange(len(v), dtype=np.int64).reshape(-1, 3)

        return write_obj_stream(path, [("wood", wood), ("leaves", leaves)], comments)
    raise ConfigError("must be 'ply' or 'obj'", key="forest.export_format", value=fmt)


def write_stand(forest: Forest, path: str | Path, fmt: str = "ply", facets: int = 6,
                progress: bool = False) -> Path:
    """Export every tree of the forest as one mesh (wood and leaf parts), streamed per tree.

    ``fmt`` is ``"ply"`` (binary; faces carry ``part`` 0 = wood / 1 = leaves and
    ``tree_id``) or ``"obj"`` (``o wood`` then ``o leaves``). Branches are open
    ``facets``-prisms, leaf triangles keep their own vertices; in PLY tree ``i``'s
    wood vertices precede its leaf vertices, trees in order.
    """
    return _write_mesh(_Stand.of(forest), Path(path), fmt, facets, progress,
                       ["simlidar-mi forest stand, metres", "part 0 = wood (open prisms), 1 = leaves",
                        f"seed {forest.seed}, {len(forest)} trees"])


def _write_prototype_meshes(forest: Forest, folder: Path, fmt: str, facets: int) -> list[Path]:
    """One mesh per prototype, in its own frame (place with the transforms of trees.csv)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    names = forest.species_names
    origin = np.zeros(3)
    for p, t in enumerate(forest.prototypes):
        stand = _Stand(1, lambda i, t=t: t, lambda i: (origin, 0.0, 1.0), lambda i: None)
        species = names[int(forest.prototype_species[p])]
        out.append(_write_mesh(stand, folder / f"{species}_{p:03d}.{fmt}", fmt, facets, False,
                               [f"simlidar-mi forest prototype {p} ({species}), own frame, metres",
                                "part 0 = wood (open prisms), 1 = leaves"]))
    return out


# --- pictures --------------------------------------------------------------------------


def _colours(n: int) -> list:
    import matplotlib  # noqa: PLC0415
    cmap = matplotlib.colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def plot_layout(forest: Forest, path: str | Path) -> Path:
    """Trees as crown-sized discs by species over the intensity contours (``layout.png``)."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import EllipseCollection  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415

    d = forest.params.domain
    sp = [s.intensity for s in forest.params.species]
    x, y, lam = intensity_grid(sp, d, 200, 200)
    cols = _colours(len(sp))
    w, h = d.x_max_m - d.x_min_m, d.y_max_m - d.y_min_m
    fig, ax = plt.subplots(figsize=(7.5 * min(2.0, max(0.6, w / h)) + 1.8, 7.5), dpi=120)
    total = lam.sum(0)
    cf = ax.contourf(x, y, total, levels=12, cmap="Greys", alpha=0.45)
    fig.colorbar(cf, ax=ax, label="total intensity λ (trees per m²)", shrink=0.8)
    for j in range(len(sp)):
        if lam[j].max() > 0:
            ax.contour(x, y, lam[j], levels=4, colors=[cols[j]], linewidths=0.8, alpha=0.9)
    handles = []
    for j, name in enumerate(forest.species_names):
        m = forest.species == j
        if m.any():
            diam = 2 * forest.crown_radius_m[m]
            ax.add_collection(EllipseCollection(diam, diam, np.zeros(m.sum()), units="xy",
                                                offsets=np.column_stack([forest.x_m[m], forest.y_m[m]]),
                                                offset_transform=ax.transData, facecolors=[cols[j]],
                                                edgecolors="k", linewidths=0.2, alpha=0.55))
            ax.plot(forest.x_m[m], forest.y_m[m], ".", ms=1.5, color="k")
        pl = forest.placement
        handles.append(Line2D([], [], marker="o", ls="", color=cols[j], markeredgecolor="k",
                              label=f"{name}: {int(m.sum())} trees ({int(pl.removed[j])} removed)"))
    ax.set_xlim(d.x_min_m, d.x_max_m)
    ax.set_ylim(d.y_min_m, d.y_max_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{len(forest)} trees; discs = crown diameter; lines = intensity per species; "
                 f"min distance {forest.params.min_distance_m:g} m", fontsize=9)
    ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return Path(path)


def _strip(forest: Forest, max_trees: int) -> np.ndarray:
    """Indices of the at most ``max_trees`` trees nearest the domain's middle line y = y_mid."""
    d = forest.params.domain
    order = np.argsort(np.abs(forest.y_m - 0.5 * (d.y_min_m + d.y_max_m)), kind="stable")
    return np.sort(order[:max_trees])


def plot_preview(forest: Forest, path: str | Path, max_trees: int = 300,
                 max_leaf_points: int = 200_000) -> Path:
    """Side (x–z) and top (x–y) views; branches as lines, leaves as dots (``preview.png``).

    Big forests show a central strip of ``max_trees`` trees (all crowns outlined in the
    top view) and a subsample of at most ``max_leaf_points`` leaf centres.
    """
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import EllipseCollection, LineCollection  # noqa: PLC0415

    d = forest.params.domain
    idx = _strip(forest, max_trees)
    cols = _colours(len(forest.species_names))
    n_leaves = int(forest.n_leaves[idx].sum()) if len(idx) else 0
    step = max(1, math.ceil(n_leaves / max_leaf_points))
    segs_side, segs_top, lw, leaf_pts, leaf_col = [], [], [], [], []
    for i in idx:
        br, _ = forest.tree_geometry(int(i))
        segs_side.append(np.stack([br.p0[:, [0, 2]], br.p1[:, [0, 2]]], 1))
        segs_top.append(np.stack([br.p0[:, :2], br.p1[:, :2]], 1))
        lw.append(np.clip(br.diameter * 4.0, 0.1, 1.5))
        lt = forest.tree_leaf_table(int(i))
        leaf_pts.append(lt.centre_m[::step])
        leaf_col.append(np.repeat([cols[int(forest.species[i])]], len(leaf_pts[-1]), axis=0))
    fig, (a_side, a_top) = plt.subplots(2, 1, figsize=(12, 12), dpi=110,
                                        gridspec_kw={"height_ratios": [1, 2.0]})
    dot = 0.6 * math.sqrt(min(step, 16))  # thinned leaves drawn bigger to keep the crown's tone
    if len(idx):
        pts = np.concatenate(leaf_pts) if leaf_pts else np.zeros((0, 3))
        lc = np.concatenate(leaf_col) if leaf_col else np.zeros((0, 4))
        a_side.add_collection(LineCollection(np.concatenate(segs_side), linewidths=np.concatenate(lw),
                                             colors="saddlebrown"))
        a_side.scatter(pts[:, 0], pts[:, 2], s=dot, c=lc, alpha=0.35, linewidths=0, zorder=3)
        a_top.add_collection(LineCollection(np.concatenate(segs_top), linewidths=np.concatenate(lw),
                                            colors="saddlebrown", alpha=0.8))
        a_top.scatter(pts[:, 0], pts[:, 1], s=dot, c=lc, alpha=0.35, linewidths=0, zorder=3)
    diam = 2 * forest.crown_radius_m
    a_top.add_collection(EllipseCollection(diam, diam, np.zeros(len(forest)), units="xy",
                                           offsets=np.column_stack([forest.x_m, forest.y_m]),
                                           offset_transform=a_top.transData, facecolors="none",
                                           edgecolors=[cols[int(s)] for s in forest.species],
                                           linewidths=0.4))
    zmax = float(forest.height_m.max()) if len(forest) else 1.0
    a_side.set_xlim(d.x_min_m, d.x_max_m)
    a_side.set_ylim(0, 1.05 * zmax)
    # wide stands would be a thin strip at 1:1; exaggerate z so the side view stays readable
    exag = max(1.0, 0.3 * (d.x_max_m - d.x_min_m) / max(zmax, 1e-9))
    a_side.set_aspect(exag)
    a_side.set_xlabel("x (m)")
    a_side.set_ylabel("z (m)")
    y_lo = float(forest.y_m[idx].min()) if len(idx) else d.y_min_m
    y_hi = float(forest.y_m[idx].max()) if len(idx) else d.y_max_m
    a_side.set_title(f"side view (looking along +y) of {len(idx)} of {len(forest)} trees, "
                     f"y in [{y_lo:.0f}, {y_hi:.0f}] m; leaf dots 1 in {step}"
                     + (f"; z exaggerated ×{exag:.1f}" if exag > 1 else ""), fontsize=9)
    a_top.set_xlim(d.x_min_m, d.x_max_m)
    a_top.set_ylim(d.y_min_m, d.y_max_m)
    a_top.set_aspect("equal")
    a_top.set_xlabel("x (m)")
    a_top.set_ylabel("y (m)")
    a_top.set_title("top view: the same trees drawn, every crown outlined; leaves coloured by species",
                    fontsize=9)
    from matplotlib.lines import Line2D  # noqa: PLC0415
    a_side.legend(handles=[Line2D([], [], marker="o", ls="", color=cols[j], label=nm)
                           for j, nm in enumerate(forest.species_names)], loc="upper right",
                  fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
    return Path(path)


# --- the command -----------------------------------------------------------------------


@dataclass
class ForestRun:
    """What ``run_forest`` produced."""

    forest: Forest
    files: dict[str, Path]
    summary: dict[str, Any]


def _resolve_modes(forest: Forest, f: dict, src: str) -> tuple[str, str]:
    leaf_mode = f["leaf_table"]
    n_leaves = int(forest.n_leaves.sum())
    if leaf_mode == "auto":
        leaf_mode = "all" if n_leaves <= f["leaf_table_max_rows"] or not forest.instancing else "prototypes"
    if leaf_mode == "prototypes" and not forest.instancing:
        raise ConfigError("needs instancing = true (without it there are no prototypes)", file=src,
                          key="forest.leaf_table", value="prototypes")
    export = f["export"]
    k = f["export_facets"]
    n_tri = int((2 * k * forest.n_branches + forest.n_leaf_triangles).sum())
    if export == "auto":
        export = "stand" if n_tri <= f["export_max_triangles"] or not forest.instancing else "prototypes"
    if export == "prototypes" and not forest.instancing:
        raise ConfigError("needs instancing = true (without it there are no prototypes)", file=src,
                          key="forest.export", value="prototypes")
    return leaf_mode, export


def run_forest(cfg: SceneConfig | str | Path, out_dir: str | Path, overrides: Sequence[str] = (),
               *, progress: bool = False) -> ForestRun:
    """Make the forest of a scene file and write its files (see the module docstring).

    All files appear together when complete (staged); a failure leaves ``out_dir``
    as it was.
    """
    if not isinstance(cfg, SceneConfig):
        cfg = load_scene(cfg, list(overrides))
    if not (cfg.has("forest") or cfg.has("species")):
        raise ConfigError("the scene has no [forest] section or [[species]] tables", file=cfg.source,
                          key="forest")
    f = cfg["forest"]
    forest = make_forest(cfg, progress=progress)
    leaf_mode, export = _resolve_modes(forest, f, cfg.source)
    seconds = dict(forest.seconds)
    files: dict[str, Path] = {}
    out = Path(out_dir)
    with staged_dir(out) as stage:
        t0 = time.perf_counter()
        _write_trees_csv(stage / "trees.csv", forest)
        files["trees"] = out / "trees.csv"
        rows = 0
        if leaf_mode != "none":
            ext = "parquet" if _have_pyarrow() else "csv"
            if leaf_mode == "all":
                name, id_name = f"leaves.{ext}", "tree_id"
                tables: Iterable[LeafTable] = (forest.tree_leaf_table(i) for i in
                                               _bar(range(len(forest)), progress, "leaves", len(forest)))
            else:
                name, id_name = f"prototype_leaves.{ext}", "prototype"
                tables = (t.leaf_table for t in forest.prototypes)
            writer = _leaf_tables_parquet if ext == "parquet" else _leaf_tables_csv
            rows = writer(stage / name, tables, id_name)
            files["leaves"] = out / name
        seconds["tables"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        plot_layout(forest, stage / "layout.png")
        plot_preview(forest, stage / "preview.png", f["preview_max_trees"])
        files["layout"], files["preview"] = out / "layout.png", out / "preview.png"
        seconds["plots"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        fmt, k = f["export_format"], f["export_facets"]
        if export == "stand":
            write_stand(forest, stage / f"stand.{fmt}", fmt, k, progress)
            files["stand"] = out / f"stand.{fmt}"
        elif export == "prototypes":
            _write_prototype_meshes(forest, stage / "prototypes", fmt, k)
            files["prototypes"] = out / "prototypes"
        seconds["export"] = time.perf_counter() - t0

        summary = forest.summary()
        summary.update({"scene_file": cfg.source, "scene_sha256": cfg.sha256, "leaf_table": leaf_mode,
                        "leaf_rows_written": rows, "export": export, "export_format": fmt,
                        "export_facets": k, "seconds": seconds,
                        "export_triangles": int((2 * k * forest.n_branches
                                                 + forest.n_leaf_triangles).sum())
                        if export == "stand" else int(sum(2 * k * len(t.branches) + len(t.leaves)
                                                          for t in forest.prototypes))
                        if export == "prototypes" else 0,
                        "transform": "p_world = (x, y, 0) + Rz(yaw_deg) · (scale · p_local)"})
        with open(stage / "forest.json", "w") as fh:
            json.dump(summary, fh, indent=2)
        files["summary"] = out / "forest.json"
    return ForestRun(forest, files, summary)
