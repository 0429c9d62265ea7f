"""Random-tree species: the laws and constants of one species, scene-file tables, presets.

A tree's parameters are random variables (:mod:`simlidar_mi.plants.laws`), in the
paper's two groups:

global (one draw per tree, §II-C G1–G3)
    ``trunk_length_m``, ``trunk_radius_m`` (truncated normal): the first segment;
    ``growth_level`` (discrete): the number of segment generations ``G``;
    ``length_ratio``, ``radius_ratio`` (truncated normal): daughter / mother length
    and radius; optional ``lateral_length_ratio``, ``lateral_radius_ratio`` for the
    lateral daughters of an axis that also continues with a leader (Honda's r2).
local (draws per branch or per leaf, §II-C L1–L4)
    ``lateral_branching`` (Bernoulli): the branching-pattern flag (L1); true = the
    daughters sprout at random points along the mother, false = all at its apex.
    Drawn once per tree by default (``lateral_branching_per = "tree"``: the paper
    varies the local parameters "for each individual tree" and its Fig. 4 contrasts
    whole trees), or once per growing branch (``"branch"``, the earlier reading);
    ``twist_deg`` (truncated normal): an extra roll of the daughters about the
    mother's axis; ``n_daughters`` (discrete; ``trunk_n_daughters`` on the trunk);
    ``branch_angle_deg`` (truncated normal, per daughter; ``trunk_branch_angle_deg``
    on the trunk); ``leaf_length_m`` (truncated normal) and ``leaf_width_ratio``
    (width = ratio × length, the ratio drawn per leaf); ``leaves_per_branch``
    (discrete); ``leaf_angle_deg`` and ``leaf_roll_deg`` (truncated normal).
per-tree means (one draw per tree, then per-branch or per-leaf draws around them)
    the paper varies "mean leaf sizes; mean for the number of daughter branches and the
    number of leaves" for each tree (seed 004 §II-B). Each tree draws a factor
    ``f ~ N(1, cv²)`` cut to ``1 ± 3cv`` per quantity (``leaf_length_tree_cv``,
    ``n_daughters_tree_cv``, ``leaves_per_branch_tree_cv``): its leaves draw
    ``f × leaf_length_m``, its counts ``floor(f·n + U)`` from the species law's ``n``. The
    spreads (0.10, 0.05, 0.10) are ours: the paper gives no numbers.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

from ..errors import ConfigError
from .laws import Bernoulli, Discrete, TruncNormal, _finite, _whole

__all__ = ["RandomTreeParams", "tree_params_from_dict", "leaf_polygon_area_factor",
           "species_preset", "SPECIES_PRESETS"]


# --- parameters ------------------------------------------------------------------------

# Support of each random parameter: (kind, lo, hi, integer); checked on the law's bounds.
_TN, _DI, _BE = "truncnormal", "discrete", "bernoulli"
_LAWS: dict[str, tuple] = {
    "trunk_length_m": (_TN, 0.0, 100.0, False),
    "trunk_radius_m": (_TN, 0.0, 5.0, False),
    "growth_level": (_DI, 1, 40, True),
    "length_ratio": (_TN, 0.0, 2.0, False),
    "radius_ratio": (_TN, 0.0, 2.0, False),
    "lateral_length_ratio": (_TN, 0.0, 2.0, False),
    "lateral_radius_ratio": (_TN, 0.0, 2.0, False),
    "lateral_branching": (_BE, 0.0, 1.0, False),
    "twist_deg": (_TN, -360.0, 360.0, False),
    "n_daughters": (_DI, 0, 32, True),
    "trunk_n_daughters": (_DI, 0, 32, True),
    "branch_angle_deg": (_TN, -180.0, 180.0, False),
    "trunk_branch_angle_deg": (_TN, -180.0, 180.0, False),
    "leader_angle_deg": (_TN, -180.0, 180.0, False),
    "leaf_length_m": (_TN, 0.0, 2.0, False),
    "leaf_width_ratio": (_TN, 0.0, 10.0, False),
    "leaves_per_branch": (_DI, 0, 10_000, True),
    "leaf_angle_deg": (_TN, -180.0, 180.0, False),
    "leaf_roll_deg": (_TN, -89.0, 89.0, False),
}
# Laws whose draws must be strictly positive (lengths, radii, ratios).
_POSITIVE = {"trunk_length_m", "trunk_radius_m", "length_ratio", "radius_ratio",
             "lateral_length_ratio", "lateral_radius_ratio", "leaf_length_m", "leaf_width_ratio"}
#: Between-tree coefficients of variation of a tree's own mean leaf length, number of
#: daughters and leaves per branch ([[species]] keys of a forest; 0: every tree the species' law).
TREE_CV = ("leaf_length_tree_cv", "n_daughters_tree_cv", "leaves_per_branch_tree_cv")
_OPTIONAL = {"lateral_length_ratio", "lateral_radius_ratio", "trunk_n_daughters",
             "trunk_branch_angle_deg"}


@dataclass(frozen=True)
class RandomTreeParams:
    """All distributions and architecture constants of one random-tree species.

    Every random field is a :class:`TruncNormal`, :class:`Discrete` or
    :class:`Bernoulli` (see the module docstring for what each does); the
    ``lateral_*``, ``trunk_n_daughters`` and ``trunk_branch_angle_deg`` laws may be
    ``None`` (then the general law is used). Defaults are the ``deciduous-apex``
    preset.

    Attributes (constants)
    ----------------------
    name : species label.
    monopodial_orders : axes of order ≤ this continue with a leader (0: sympodial).
    max_order : axes of this order or higher carry no laterals.
    bare_trunk_levels : the first trunk segments carry no laterals (clear bole).
    lateral_position_min : with the flag, daughters sprout at ``U(min, 1)`` along the mother.
    divergence_deg : roll of a leader relative to its mother (phyllotaxis).
    lateral_branching_per : ``"tree"`` (default: one L1 flag per tree) or ``"branch"``
        (one per growing branch).
    tropism : weight of ``+ẑ`` added to every daughter heading (< 0 droops).
    min_length_m : branches shorter than this get no daughters.
    leaf_levels : branches in the last this many generations bear leaves.
    leaf_min_order : branches of this order or higher bear leaves.
    leaf_shape : ``"rhombus"`` (2 triangles) or ``"ellipse"`` (``leaf_sides`` triangles).
    leaf_sides : polygon sides of an ellipse leaf (≥ 4).
    shoot_star : 0: the leaf elements are leaves; in [0.05, 0.25]: each is a conifer shoot
        drawn as one flat element of its silhouette, with this shoot silhouette to total
        needle area ratio (STAR): it stands for ``area / (4·STAR)`` of needle LAI area (half
        the total needle area, :func:`simlidar_mi.plants.foliage.needle_area_factor`).
    max_branches : refuse trees with more segments (memory guard).

    Raises
    ------
    ConfigError
        naming the field (``trunk_length_m.sd``) and value.
    """

    name: str = "deciduous-apex"
    # global laws (G1–G3)
    trunk_length_m: TruncNormal = TruncNormal(4.5, 0.6, 3.0, 6.5)
    trunk_radius_m: TruncNormal = TruncNormal(0.22, 0.04, 0.12, 0.35)
    growth_level: Discrete = Discrete((7, 8), (0.5, 0.5))
    length_ratio: TruncNormal = TruncNormal(0.80, 0.04, 0.68, 0.92)
    radius_ratio: TruncNormal = TruncNormal(0.70, 0.04, 0.58, 0.82)
    lateral_length_ratio: TruncNormal | None = None
    lateral_radius_ratio: TruncNormal | None = None
    # local laws (L1–L4)
    lateral_branching: Bernoulli = Bernoulli(0.1)
    twist_deg: TruncNormal = TruncNormal(0.0, 30.0, -90.0, 90.0)
    n_daughters: Discrete = Discrete((2, 3), (0.6, 0.4))
    trunk_n_daughters: Discrete | None = Discrete((3, 4), (0.5, 0.5))
    branch_angle_deg: TruncNormal = TruncNormal(30.0, 8.0, 10.0, 60.0)
    trunk_branch_angle_deg: TruncNormal | None = None
    leader_angle_deg: TruncNormal = TruncNormal(0.0, 5.0, -15.0, 15.0)
    leaf_length_m: TruncNormal = TruncNormal(0.11, 0.02, 0.06, 0.16)
    leaf_width_ratio: TruncNormal = TruncNormal(0.55, 0.06, 0.35, 0.75)
    leaves_per_branch: Discrete = Discrete((260, 290, 320), (0.25, 0.5, 0.25))
    leaf_angle_deg: TruncNormal = TruncNormal(50.0, 15.0, 10.0, 90.0)
    leaf_roll_deg: TruncNormal = TruncNormal(0.0, 20.0, -60.0, 60.0)
    # architecture constants
    lateral_branching_per: str = "tree"
    monopodial_orders: int = 0
    max_order: int = 99
    bare_trunk_levels: int = 0
    lateral_position_min: float = 0.3
    divergence_deg: float = 137.5
    tropism: float = 0.25
    min_length_m: float = 0.05
    leaf_levels: int = 2
    leaf_min_order: int = 99
    leaf_shape: str = "rhombus"
    leaf_sides: int = 6
    max_branches: int = 200_000
    shoot_star: float = 0.0
    # per-tree means (seed 004 §II-B): between-tree coefficients of variation, ours
    leaf_length_tree_cv: float = 0.10
    n_daughters_tree_cv: float = 0.05
    leaves_per_branch_tree_cv: float = 0.10

    def __post_init__(self) -> None:
        self.validate("")

    def validate(self, prefix: str = "") -> None:
        """Check every field; ConfigError keys are ``prefix + field[.subfield]``."""
        set_ = object.__setattr__
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError("must be a non-empty string", key=f"{prefix}name", value=self.name)
        types = {_TN: TruncNormal, _DI: Discrete, _BE: Bernoulli}
        for fname, (kind, lo, hi, integer) in _LAWS.items():
            law = getattr(self, fname)
            key = f"{prefix}{fname}"
            if law is None and fname in _OPTIONAL:
                continue
            if not isinstance(law, types[kind]):
                raise ConfigError(f"must be a {types[kind].__name__}", key=key, value=law)
            if kind == _TN:
                law.check(key)
                if law.sd == 0:  # a constant: only its value matters
                    if fname in _POSITIVE and not law.mean > 0:
                        raise ConfigError("must be > 0", key=f"{key}.mean", value=law.mean)
                    if not lo <= law.mean <= hi:
                        raise ConfigError(f"must lie in [{lo}, {hi}]", key=f"{key}.mean", value=law.mean)
                    continue
                if fname in _POSITIVE and not law.lo > 0:
                    raise ConfigError("must be > 0: draws must be strictly positive",
                                      key=f"{key}.lo", value=law.lo)
                if law.lo < lo or law.hi > hi:
                    raise ConfigError(f"the law's bounds [lo, hi] must lie within [{lo}, {hi}]",
                                      key=f"{key}.lo" if law.lo < lo else f"{key}.hi",
                                      value=law.lo if law.lo < lo else law.hi)
            elif kind == _DI:
                law.check(key, integer=integer, lo=lo, hi=hi)
            else:
                law.check(key)
        if self.lateral_branching_per not in ("tree", "branch"):
            raise ConfigError("must be 'tree' (one branching-pattern flag per tree) or 'branch'",
                              key=f"{prefix}lateral_branching_per", value=self.lateral_branching_per)
        set_(self, "monopodial_orders", _whole(self.monopodial_orders, f"{prefix}monopodial_orders", 0))
        set_(self, "max_order", _whole(self.max_order, f"{prefix}max_order", 1))
        set_(self, "bare_trunk_levels", _whole(self.bare_trunk_levels, f"{prefix}bare_trunk_levels", 0))
        v = _finite(self.lateral_position_min, f"{prefix}lateral_position_min")
        if not 0 <= v <= 1:
            raise ConfigError("must lie in [0, 1] (fraction of the mother's length)",
                              key=f"{prefix}lateral_position_min", value=v)
        set_(self, "lateral_position_min", v)
        set_(self, "divergence_deg", _finite(self.divergence_deg, f"{prefix}divergence_deg"))
        v = _finite(self.tropism, f"{prefix}tropism")
        if not -0.95 <= v <= 0.95:
            raise ConfigError("must lie in [-0.95, 0.95]", key=f"{prefix}tropism", value=v)
        set_(self, "tropism", v)
        v = _finite(self.min_length_m, f"{prefix}min_length_m")
        if v < 0:
            raise ConfigError("must be ≥ 0 m", key=f"{prefix}min_length_m", value=v)
        set_(self, "min_length_m", v)
        set_(self, "leaf_levels", _whole(self.leaf_levels, f"{prefix}leaf_levels", 0))
        set_(self, "leaf_min_order", _whole(self.leaf_min_order, f"{prefix}leaf_min_order", 1))
        if self.leaf_shape not in ("rhombus", "ellipse"):
            raise ConfigError("must be 'rhombus' or 'ellipse'", key=f"{prefix}leaf_shape",
                              value=self.leaf_shape)
        set_(self, "leaf_sides", _whole(self.leaf_sides, f"{prefix}leaf_sides", 4, 64))
        set_(self, "max_branches", _whole(self.max_branches, f"{prefix}max_branches", 1))
        v = _finite(self.shoot_star, f"{prefix}shoot_star")
        if not (v == 0 or 0.05 <= v <= 0.25):
            raise ConfigError("must be 0 (leaves) or a shoot STAR in [0.05, 0.25] (0.25: a lone "
                              "convex needle's mean projection per unit area)",
                              key=f"{prefix}shoot_star", value=v)
        set_(self, "shoot_star", v)
        for name in TREE_CV:
            v = _finite(getattr(self, name), f"{prefix}{name}")
            if not 0 <= v <= 0.3:
                raise ConfigError("must lie in [0, 0.3] (a tree's factor is cut to 1 ± 3cv > 0)",
                                  key=f"{prefix}{name}", value=v)
            set_(self, name, v)

    @property
    def triangles_per_leaf(self) -> int:
        return 2 if self.leaf_shape == "rhombus" else self.leaf_sides


def leaf_polygon_area_factor(shape: str, sides: int = 6) -> float:
    """Leaf area / (length × width) of a leaf shape: 1/2 (rhombus), (k/8)·sin(2π/k) (k-gon)."""
    if shape == "rhombus":
        return 0.5
    return sides / 8.0 * math.sin(2 * math.pi / sides)


def _law_from_value(kind: str, base, value: Any, key: str):
    """A scene-file value → a law: a table (partial override of ``base``) or a number."""
    if isinstance(value, Mapping):
        if base is None:
            base = {_TN: TruncNormal(0.0, 1.0), _DI: Discrete((0,), (1.0,)),
                    _BE: Bernoulli(0.0)}[kind]
            need = {_TN: {"mean", "sd"}, _DI: {"values"}, _BE: {"p"}}[kind] - set(value)
            if need:
                raise ConfigError(f"needs {', '.join(sorted(need))} (no preset law to override)",
                                  key=key, value=dict(value))
        return base.merged(value, key)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        v = _finite(value, key)
        if kind == _TN:
            return TruncNormal.fixed(v)
        if kind == _BE:
            return base.merged({"p": v}, key) if base is not None else Bernoulli(v).merged({}, key)
        return Discrete.fixed(value).merged({}, key)
    if kind == _BE and isinstance(value, bool):
        return Bernoulli(1.0 if value else 0.0)
    names = {_TN: "{mean, sd, lo, hi}", _DI: "{values, probs}", _BE: "{p} or a probability"}
    raise ConfigError(f"must be a table {names[kind]} or a number", key=key, value=value)


def tree_params_from_dict(table: Mapping[str, Any], base: RandomTreeParams | None = None,
                          key_prefix: str = "") -> RandomTreeParams:
    """Scene-file table → RandomTreeParams, overriding ``base`` (default: the defaults).

    Law fields take an inline table (``{mean = 3, sd = 0.4, lo = 2, hi = 4}``; any
    subset overrides the base law's fields) or a number (a constant); optional laws
    also take ``"none"``. Constants take their plain value.

    Raises
    ------
    ConfigError
        naming ``key_prefix + field`` and the value.
    """
    base = base or RandomTreeParams()
    if not isinstance(table, Mapping):
        raise ConfigError("must be a table", key=key_prefix.rstrip(".") or "tree", value=table)
    names = {f.name for f in dataclasses.fields(RandomTreeParams)}
    changes: dict[str, Any] = {}
    for k, v in table.items():
        key = f"{key_prefix}{k}"
        if k not in names:
            raise ConfigError(f"unknown tree parameter; valid: {', '.join(sorted(names))}",
                              key=key, value=v)
        if k in _LAWS:
            if k in _OPTIONAL and isinstance(v, str) and v.lower() == "none":
                changes[k] = None
            else:
                changes[k] = _law_from_value(_LAWS[k][0], getattr(base, k), v, key)
        else:
            changes[k] = v
    # build without __post_init__ so errors carry the scene-file key prefix
    out = object.__new__(RandomTreeParams)
    for f in dataclasses.fields(RandomTreeParams):
        object.__setattr__(out, f.name, changes.get(f.name, getattr(base, f.name)))
    out.validate(key_prefix)
    return out


# --- species presets -------------------------------------------------------------------

_T = TruncNormal
_D = Discrete

#: Four forest species as random-tree parameter sets. Architecture follows the
#: paper's §II-C: apex branching (flag false) as in elm and birch, branching at
#: random points along the mother (flag true) as in spruce, and Honda's
#: monopodial trees (ABOP Fig. 2.6). Sizes are this project's choice from common
#: field values (heights, trunk radii, leaf lengths), not from the paper, which
#: gives no numbers; "conifer-whorl" foliage is flat shoot elements (a few cm),
#: not single needles. Foliage: each preset's leaf (shoot) size and the range its crown LAI
#: lies in are cited in :data:`simlidar_mi.plants.foliage.SPECIES_FOLIAGE`; the leaf count
#: per leaf-bearing segment (the twigs the generator does not grow) is ours, fitted to it.
SPECIES_PRESETS: dict[str, RandomTreeParams] = {
    # elm/birch-like: sympodial, every split at the apex; ~14–20 m, leaves 6–16 cm (≈ 33 cm²,
    # Dutch elm 29.5–38 cm²), 260–320 a leaf-bearing segment: crown LAI ≈ 3.7, ~750 m² a tree
    # (growth levels 7–8: one more generation of twigs than before, without the 9th whose
    # largest trees carried 3000 m²)
    "deciduous-apex": RandomTreeParams(),
    # spruce-like: a leader trunk with whorls of 4–6 near-horizontal laterals
    # (flag p = 0.3: with one flag per tree, 3 trees in 10 scatter their laterals between
    # whorls), drooping; ~15–24 m; foliage as shoots (shoot_star = 0.16): flat elements 5–11 cm
    # long and 0.6 as wide (the needle cylinder), 84–108 a segment: shoot-element crown LAI ≈ 4.3,
    # needle LAI (half the total needle area) ≈ 6.7
    "conifer-whorl": RandomTreeParams(
        name="conifer-whorl",
        trunk_length_m=_T(1.9, 0.2, 1.4, 2.4), trunk_radius_m=_T(0.20, 0.03, 0.12, 0.30),
        growth_level=_D((12, 13, 14, 15), (0.2, 0.3, 0.3, 0.2)),
        length_ratio=_T(0.93, 0.012, 0.90, 0.96), radius_ratio=_T(0.88, 0.02, 0.82, 0.94),
        lateral_length_ratio=_T(0.30, 0.03, 0.22, 0.38), lateral_radius_ratio=_T(0.30, 0.03, 0.22, 0.38),
        lateral_branching=Bernoulli(0.3), twist_deg=_T(0.0, 15.0, -45.0, 45.0),
        n_daughters=_D((2, 3), (0.5, 0.5)), trunk_n_daughters=_D((4, 5, 6), (0.3, 0.4, 0.3)),
        branch_angle_deg=_T(45.0, 10.0, 20.0, 70.0), trunk_branch_angle_deg=_T(82.0, 6.0, 65.0, 100.0),
        leader_angle_deg=_T(0.0, 1.5, -5.0, 5.0),
        leaf_length_m=_T(0.08, 0.012, 0.05, 0.11), leaf_width_ratio=_T(0.60, 0.06, 0.45, 0.75),
        leaves_per_branch=_D((84, 96, 108), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(40.0, 12.0, 10.0, 80.0), leaf_roll_deg=_T(0.0, 25.0, -70.0, 70.0),
        monopodial_orders=2, max_order=3, bare_trunk_levels=2, lateral_position_min=0.2,
        tropism=-0.04, min_length_m=0.08, leaf_levels=2, leaf_min_order=3, shoot_star=0.16),
    # beech/ash-like Honda monopodial broadleaf: leader trunk and main limbs, laterals
    # at random points along them (flag p = 0.7 of the trees); ~13–18 m, leaves 5–10 cm × 0.65
    # (≈ 21 cm²), 160–200 a leaf-bearing segment: crown LAI ≈ 7, ~250 m² a tree
    "broadleaf-monopodial": RandomTreeParams(
        name="broadleaf-monopodial",
        trunk_length_m=_T(2.6, 0.3, 1.8, 3.4), trunk_radius_m=_T(0.25, 0.04, 0.15, 0.38),
        growth_level=_D((9, 10, 11), (0.25, 0.5, 0.25)),
        length_ratio=_T(0.88, 0.02, 0.82, 0.94), radius_ratio=_T(0.82, 0.03, 0.74, 0.90),
        lateral_length_ratio=_T(0.70, 0.05, 0.55, 0.85), lateral_radius_ratio=_T(0.45, 0.04, 0.35, 0.55),
        lateral_branching=Bernoulli(0.7), twist_deg=_T(0.0, 30.0, -90.0, 90.0),
        n_daughters=_D((2, 3), (0.5, 0.5)), trunk_n_daughters=_D((3, 4), (0.5, 0.5)),
        branch_angle_deg=_T(45.0, 10.0, 20.0, 75.0), trunk_branch_angle_deg=_T(50.0, 8.0, 30.0, 70.0),
        leader_angle_deg=_T(0.0, 4.0, -12.0, 12.0),
        leaf_length_m=_T(0.08, 0.012, 0.05, 0.10), leaf_width_ratio=_T(0.65, 0.06, 0.50, 0.80),
        leaves_per_branch=_D((160, 180, 200), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(55.0, 15.0, 15.0, 90.0), leaf_roll_deg=_T(0.0, 15.0, -45.0, 45.0),
        monopodial_orders=2, max_order=4, bare_trunk_levels=2, lateral_position_min=0.25,
        tropism=0.15, min_length_m=0.10, leaf_levels=3, leaf_min_order=3),
    # hawthorn-like small tree: short trunk, dense apex splits, small leaves (2–6 cm, rhombi of
    # ≈ 6.5 cm²: 2 triangles, not an ellipse's 6, for memory), 300–360 a leaf-bearing segment:
    # crown LAI ≈ 2.6; ~5–8 m
    "small-tree": RandomTreeParams(
        name="small-tree",
        trunk_length_m=_T(1.6, 0.25, 1.0, 2.2), trunk_radius_m=_T(0.09, 0.015, 0.05, 0.14),
        growth_level=_D((6, 7), (0.5, 0.5)),
        length_ratio=_T(0.82, 0.04, 0.70, 0.94), radius_ratio=_T(0.72, 0.04, 0.60, 0.84),
        lateral_branching=Bernoulli(0.25), twist_deg=_T(0.0, 35.0, -90.0, 90.0),
        n_daughters=_D((2, 3), (0.5, 0.5)), trunk_n_daughters=_D((3, 4), (0.5, 0.5)),
        branch_angle_deg=_T(35.0, 10.0, 10.0, 65.0), leader_angle_deg=_T(0.0, 5.0, -15.0, 15.0),
        leaf_length_m=_T(0.04, 0.008, 0.02, 0.06), leaf_width_ratio=_T(0.80, 0.08, 0.60, 1.00),
        leaves_per_branch=_D((300, 330, 360), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(50.0, 15.0, 10.0, 90.0), leaf_roll_deg=_T(0.0, 20.0, -60.0, 60.0),
        leaf_shape="rhombus",
        monopodial_orders=0, tropism=0.2, min_length_m=0.05, leaf_levels=3),
}


def species_preset(name: str) -> RandomTreeParams:
    """A forest species by name (see :data:`SPECIES_PRESETS`).

    Raises
    ------
    ConfigError
        for an unknown name, listing the valid ones.
    """
    try:
        return SPECIES_PRESETS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown species preset; valid: {', '.join(SPECIES_PRESETS)}",
                          key="preset", value=name) from None
