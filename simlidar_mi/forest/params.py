"""Forest parameters and seeds: species, ForestParams from a scene file, per-tree and prototype seeds.

Seeds: from the scene seed ``S``, the placement uses ``SeedSequence(S, spawn_key=(0,))``;
candidate ``i`` (arrival index) of species ``j`` gets the integer seed made from
``SeedSequence(S, spawn_key=(1, j, i))`` (it grows the tree without instancing, and draws
its yaw, and its scale with ``scale_mode = "whole-tree"``, with instancing);
prototype ``k`` of species ``j`` grows from ``spawn_key=(2, j, k)`` and draws its wood
scale from ``spawn_key=(3, j, k)``; candidate ``i`` places prototype ``i // trees_per_prototype``
(``"auto"``) or ``i mod K``. Integer seeds are 53-bit. The ``seed`` column of
``trees.csv`` is the seed of the placed geometry (the tree's own, or its prototype's):
``place_tree(random_tree(params, seed), x, y, yaw_deg, scale)`` rebuilds that tree
(:func:`simlidar_mi.forest.stand.place_tree`). Changing one tree's seed changes no
other tree.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import SceneConfig
from ..errors import ConfigError
from ..plants.tree_params import SPECIES_PRESETS, TREE_CV, RandomTreeParams, species_preset, tree_params_from_dict
from .representation import DEFAULT_PROTOTYPES_PER_SPECIES, memory_limit_bytes
from .placement import COUNT_MODES, MAX_CANDIDATE_FACTOR, Bump, Domain, SpeciesIntensity

__all__ = ["ForestSpecies", "ForestParams", "forest_params_from_scene", "tree_seed", "prototype_seed",
           "prototype_scale", "CROWN_FACTOR"]

#: Default k of the crown rule d_ij ≥ k·(r_i + r_j): the smallest of 0.05 steps that keeps
#: the share of trees with a neighbour's trunk inside their crown ≤ 10 % on every
#: forest in scenes/ (measured in docs/guide/forests.md, "crown rule").
CROWN_FACTOR = 0.65


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
    count: str = "poisson"

    def __post_init__(self) -> None:
        if self.count not in ("auto", *COUNT_MODES):
            raise ConfigError("must be 'auto', 'poisson' or 'stand'", key=f"{self.name}.count",
                              value=self.count)
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
    prototypes_per_species : K (candidate i of a species places prototype ``i mod K``; default
        12, :data:`~simlidar_mi.forest.representation.DEFAULT_PROTOTYPES_PER_SPECIES`), or
        ``"auto"``: candidate i places prototype ``i // trees_per_prototype``, so no
        prototype is placed more than ``trees_per_prototype`` times.
    scale_range : ``(min, max)`` of the uniform scale of instanced trees (``(1, 1)``:
        none; every placed tree is then a tree the species' laws drew).
    max_trees : refuse placements with more trees.
    trees_per_prototype : the bound of ``prototypes_per_species = "auto"``.
    scale_mode : ``"wood"`` (each prototype draws one scale, applied to its wood; leaves
        keep their drawn size and move with their insertion point) or ``"whole-tree"``
        (each tree draws a scale applied to the whole instance, leaves included: the
        earlier behaviour).
    crown_factor : k of the crown rule ``d_ij ≥ k·(r_i + r_j)`` (0: the minimum distance only).
    max_candidate_factor : a ``count = "stand"`` species draws candidates at most up to this
        multiple of its intensity (:func:`~simlidar_mi.forest.placement.place_trees`).
    memory_limit_gb : the trees grown and the scene built may hold at most this (GB, or
        ``"auto"``: 90 % of physical memory); a forest over it is refused before it is grown
        or built (:mod:`simlidar_mi.forest.representation`).
    """

    domain: Domain
    species: tuple[ForestSpecies, ...]
    min_distance_m: float = 3.0
    instancing: bool = True
    prototypes_per_species: int | str = DEFAULT_PROTOTYPES_PER_SPECIES
    scale_range: tuple[float, float] = (1.0, 1.0)
    max_trees: int = 100_000
    trees_per_prototype: int = 5
    scale_mode: str = "wood"
    crown_factor: float = CROWN_FACTOR
    max_candidate_factor: float = MAX_CANDIDATE_FACTOR
    memory_limit_gb: float | str = "auto"

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
        memory_limit_bytes(self.memory_limit_gb)  # refuses a bad value
        if not isinstance(self.instancing, (bool, np.bool_)):
            raise ConfigError("must be true or false", key="forest.instancing", value=self.instancing)
        k = self.prototypes_per_species
        if k != "auto" and (isinstance(k, bool) or not isinstance(k, (int, np.integer))
                            or not 1 <= k <= 1000):
            raise ConfigError("must be 'auto' or a whole number in [1, 1000]",
                              key="forest.prototypes_per_species", value=k)
        t = self.trees_per_prototype
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or t < 1:
            raise ConfigError("must be a whole number ≥ 1", key="forest.trees_per_prototype", value=t)
        if self.scale_mode not in ("wood", "whole-tree"):
            raise ConfigError("must be 'wood' or 'whole-tree'", key="forest.scale_mode",
                              value=self.scale_mode)
        c = self.crown_factor
        if isinstance(c, bool) or not isinstance(c, (int, float, np.floating)) \
                or not (math.isfinite(c) and c >= 0):
            raise ConfigError("must be a finite number ≥ 0", key="forest.crown_factor", value=c)
        object.__setattr__(self, "crown_factor", float(c))
        m = self.max_candidate_factor
        if isinstance(m, bool) or not isinstance(m, (int, float, np.floating)) \
                or not (math.isfinite(m) and 1 <= m <= 1000):
            raise ConfigError("must be a number in [1, 1000]", key="forest.max_candidate_factor", value=m)
        object.__setattr__(self, "max_candidate_factor", float(m))
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
            # the per-tree spreads are [[species]] keys (None: the preset's)
            spread = {k: sp[k] for k in TREE_CV if sp.get(k) is not None}
            tree = tree_params_from_dict({"name": name, **(sp.get("tree") or {}), **spread},
                                         species_preset(sp["preset"]), f"{key}.tree.")
        except ConfigError as exc:
            raise ConfigError(_bare(exc), file=src, key=exc.key, value=exc.value) from None
        bumps = [_bump(b, f"{key}.bumps[{i}]", src) for i, b in enumerate(sp.get("bumps") or [])]
        if not bumps and not sp.get("background_per_m2"):
            raise ConfigError("a species needs bumps or a background intensity", file=src,
                              key=f"{key}.bumps", value=sp.get("bumps"))
        species.append(ForestSpecies(name, tree, SpeciesIntensity(name, bumps,
                                                                  sp.get("background_per_m2") or 0.0),
                                     sp["preset"], sp.get("count") or "poisson"))
    if not species:
        raise ConfigError("a [forest] needs at least one [[species]] table", file=src, key="species")
    try:
        return ForestParams(Domain(*f["domain_m"]), tuple(species), f["min_distance_m"], f["instancing"],
                            f["prototypes_per_species"], tuple(f["scale_range"]), f["max_trees"],
                            f["trees_per_prototype"], f["scale_mode"], f["crown_factor"],
                            f["max_candidate_factor"], f["memory_limit_gb"])
    except ConfigError as exc:
        raise ConfigError(_bare(exc), file=src, key=exc.key, value=exc.value) from None


# --- seeds -----------------------------------------------------------------------------


def _seed53(seed: int, spawn_key: tuple[int, ...]) -> int:
    ss = np.random.SeedSequence(int(seed), spawn_key=spawn_key)
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(11))


def tree_seed(forest_seed: int, species_index: int, candidate: int) -> int:
    """The 53-bit integer seed of candidate ``candidate`` (arrival index) of species
    ``species_index`` in a forest with seed ``forest_seed``."""
    return _seed53(forest_seed, (1, int(species_index), int(candidate)))


def prototype_seed(forest_seed: int, species_index: int, k: int) -> int:
    """The integer seed of prototype ``k`` of species ``species_index``."""
    return _seed53(forest_seed, (2, int(species_index), int(k)))


def prototype_scale(forest_seed: int, species_index: int, k: int, scale_range: tuple[float, float]) -> float:
    """The wood scale of prototype ``k`` of species ``species_index`` (uniform in ``scale_range``)."""
    lo, hi = scale_range
    if lo == hi:
        return float(lo)
    ss = np.random.SeedSequence(int(forest_seed), spawn_key=(3, int(species_index), int(k)))
    return float(np.random.default_rng(ss).uniform(lo, hi))
