"""Forest parameters and seeds: species, ForestParams from a scene file, per-tree and prototype seeds.

Seeds: from the scene seed ``S``, the placement uses ``SeedSequence(S, spawn_key=(0,))``,
tree ``t`` the integer ``seed_t`` made from ``SeedSequence(S, spawn_key=(1, t))`` and
prototype ``k`` of species ``j`` one from ``spawn_key=(2, j, k)``. Integer seeds are
53-bit, written to ``trees.csv``; ``random_tree(params, seed_t)`` rebuilds tree ``t``
of a non-instanced forest bit for bit. Changing one tree's seed changes no other tree.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import SceneConfig
from ..errors import ConfigError
from ..plants.tree_params import SPECIES_PRESETS, RandomTreeParams, species_preset, tree_params_from_dict
from .placement import Bump, Domain, SpeciesIntensity

__all__ = ["ForestSpecies", "ForestParams", "forest_params_from_scene", "tree_seed", "prototype_seed"]


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
