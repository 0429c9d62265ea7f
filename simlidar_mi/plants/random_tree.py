"""Randomised Honda-type trees (Wahed et al., seed 004, §II).

A tree is grown as a stochastic, parametric L-system whose parameters are random
variables, in the paper's two groups:

global (one draw per tree, §II-C G1–G3)
    ``trunk_length_m``, ``trunk_radius_m`` (truncated normal): the first segment;
    ``growth_level`` (discrete): the number of segment generations ``G``;
    ``length_ratio``, ``radius_ratio`` (truncated normal): daughter / mother length
    and radius; optional ``lateral_length_ratio``, ``lateral_radius_ratio`` for the
    lateral daughters of an axis that also continues with a leader (Honda's r2).
local (draws per branch or per leaf, §II-C L1–L4)
    ``lateral_branching`` (Bernoulli): the branching-pattern flag; true = the
    daughters sprout at random points along the mother, false = all at its apex;
    ``twist_deg`` (truncated normal): an extra roll of the daughters about the
    mother's axis; ``n_daughters`` (discrete; ``trunk_n_daughters`` on the trunk);
    ``branch_angle_deg`` (truncated normal, per daughter; ``trunk_branch_angle_deg``
    on the trunk); ``leaf_length_m`` (truncated normal) and ``leaf_width_ratio``
    (width = ratio × length, the ratio drawn per leaf); ``leaves_per_branch``
    (discrete); ``leaf_angle_deg`` and ``leaf_roll_deg`` (truncated normal).

The grammar the generator realises, for a branch module ``A(l, r, o, d)`` of length
``l``, radius ``r``, axis order ``o`` and depth ``d`` (trunk: ``o = 1``, ``d = 0``)::

    A(l,r,o,d) : d < G-1  →  !(r) F(l) [ &(θ_i) A(l·r2, r·wr2, o+1, d+1) ]_{i<m}   (laterals)
                                        /(δ) &(θ_L) A(l·r1, r·wr1, o, d+1)          (leader)

where the leader exists only for axes with ``o ≤ monopodial_orders`` (0 gives a
sympodial, apex-branching tree: every daughter is a lateral using ``r1``), laterals
only for ``o < max_order`` above the first ``bare_trunk_levels`` trunk segments,
and no branch shorter than ``min_length_m`` gets daughters. Daughter ``i`` of ``m``
leaves its mother at azimuth ``twist + 360°·i/m`` about the mother's axis (a whorl
when the flag is false), at position ``t ~ U(lateral_position_min, 1)`` along the
mother when the flag is true, else at its apex. The leader is rolled by
``divergence_deg`` (137.5°: phyllotaxis) so successive whorls interleave. A
``tropism`` weight ``τ`` bends every daughter but the trunk's leader:
``H ← normalise(H + τ·ẑ)``.

It is written as a direct generator (breadth-first, one vectorised numpy pass per
generation) rather than through :mod:`simlidar_mi.lsystem`: each branch needs its
own random draws and frame, which a string-rewriting derivation would only carry
as module parameters, and building the word first would cost memory for nothing.

Leaves
------
Branches that are terminal, or in the last ``leaf_levels`` generations, or of order
``≥ leaf_min_order`` carry ``leaves_per_branch`` leaves each, at uniform positions
along the branch and uniform azimuths about it, attached at the bark. A leaf's
heading ``h`` makes ``leaf_angle_deg`` with the branch; its blade spans ``h`` and
the horizontal side vector ``s = h × ẑ``, rolled by ``leaf_roll_deg`` about ``h``,
so with roll 0 the upper side (normal ``n = s × h``) faces the sky. Shapes:
``"rhombus"`` (2 triangles, base and tip on the midrib, area ``ℓw/2``) or
``"ellipse"`` (an inscribed ``leaf_sides``-gon, a fan of triangles, area
``(k/8)·sin(2π/k)·ℓw``). Triangles are wound so their normal is ``n``.

Randomness: every tree draws from its own ``numpy.random.Generator`` (from an
integer seed, a ``SeedSequence`` or a Generator), in a fixed order, so the same
seed gives the same bytes and one tree's seed does not affect another tree.
Nothing here imports Mitsuba. Lengths are metres, angles degrees at the API.
"""
from __future__ import annotations

import dataclasses
import math
import operator
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.special import ndtr, ndtri

from ..errors import ConfigError
from ..geometry import Branches, Leaves

__all__ = [
    "TruncNormal", "Discrete", "Bernoulli", "RandomTreeParams", "RandomTree", "LeafTable",
    "TreeDraws", "random_tree", "tree_params_from_dict", "species_preset", "SPECIES_PRESETS",
    "leaf_polygon_area_factor",
]

_Z = np.array([0.0, 0.0, 1.0])


# --- distributions ---------------------------------------------------------------------


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool):
        raise ConfigError("must be a number, not a boolean", key=key, value=value)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError("must be a number", key=key, value=value) from None
    if math.isnan(v):
        raise ConfigError("must be a number, not NaN", key=key, value=value)
    return v


def _finite(value: Any, key: str) -> float:
    v = _number(value, key)
    if not math.isfinite(v):
        raise ConfigError("must be a finite number", key=key, value=value)
    return v


def _whole(value: Any, key: str, lo: int, hi: int | None = None) -> int:
    try:
        v = operator.index(value)
    except TypeError:
        raise ConfigError(f"must be a whole number ≥ {lo}", key=key, value=value) from None
    if isinstance(value, bool) or v < lo or (hi is not None and v > hi):
        rng = f"in [{lo}, {hi}]" if hi is not None else f"≥ {lo}"
        raise ConfigError(f"must be a whole number {rng}", key=key, value=value)
    return v


@dataclass(frozen=True)
class TruncNormal:
    """Normal law N(mean, sd²) truncated to ``[lo, hi]``.

    Parameters
    ----------
    mean, sd : of the *untruncated* normal (``sd = 0``: the constant ``mean``).
    lo, hi : truncation bounds (``±inf`` allowed).

    Draws use the inverse CDF on the side of the mean nearer the interval, so
    intervals far in a tail are sampled accurately; they consume exactly one
    uniform per draw, also when ``sd = 0``.
    """

    mean: float
    sd: float
    lo: float = -math.inf
    hi: float = math.inf

    def __post_init__(self) -> None:
        for name in ("mean", "sd", "lo", "hi"):
            object.__setattr__(self, name, _number(getattr(self, name), name))
        self.check("TruncNormal")

    @classmethod
    def fixed(cls, value: float) -> "TruncNormal":
        """The constant ``value`` as a (degenerate) truncated normal."""
        v = _finite(value, "value")
        return cls(v, 0.0, v, v)

    def check(self, key: str) -> None:
        """Raise ConfigError naming ``key.<field>`` if the law is unusable."""
        if not math.isfinite(self.mean):
            raise ConfigError("must be a finite number", key=f"{key}.mean", value=self.mean)
        if not (math.isfinite(self.sd) and self.sd >= 0):
            raise ConfigError("must be a finite number ≥ 0", key=f"{key}.sd", value=self.sd)
        if self.lo > self.hi:
            raise ConfigError(f"must be ≥ lo = {self.lo}", key=f"{key}.hi", value=self.hi)
        if self.sd == 0:
            if not self.lo <= self.mean <= self.hi:
                raise ConfigError(f"with sd = 0 the mean must lie in [lo, hi] = "
                                  f"[{self.lo}, {self.hi}]", key=f"{key}.mean", value=self.mean)
            return
        if self.lo == self.hi:
            raise ConfigError("lo = hi leaves no interval; use sd = 0 for a constant",
                              key=f"{key}.hi", value=self.hi)
        if self._mass() < 1e-12:
            raise ConfigError(f"[lo, hi] = [{self.lo}, {self.hi}] holds almost no probability "
                              f"of N({self.mean}, {self.sd}²)", key=f"{key}.lo", value=self.lo)

    def _std_bounds(self) -> tuple[float, float]:
        return (self.lo - self.mean) / self.sd, (self.hi - self.mean) / self.sd

    def _mass(self) -> float:
        a, b = self._std_bounds()
        return float(ndtr(-a) - ndtr(-b)) if a > 0 else float(ndtr(b) - ndtr(a))

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """``size`` independent draws (float64 array; a 0-d array when size is None)."""
        u = rng.random(size)
        if self.sd == 0:
            return np.full_like(u, self.mean)
        a, b = self._std_bounds()
        if a > 0:  # interval above the mean: sample the mirror image in the lower tail
            pa, pb = ndtr(-b), ndtr(-a)
            x = -ndtri(pa + u * (pb - pa))
        else:
            pa, pb = ndtr(a), ndtr(b)
            x = ndtri(pa + u * (pb - pa))
        return np.clip(self.mean + self.sd * x, self.lo, self.hi)

    def moments(self) -> tuple[float, float]:
        """Exact mean and standard deviation of the truncated law (scipy)."""
        if self.sd == 0:
            return self.mean, 0.0
        from scipy.stats import truncnorm  # noqa: PLC0415
        a, b = self._std_bounds()
        d = truncnorm(a, b, loc=self.mean, scale=self.sd)
        return float(d.mean()), float(d.std())

    def merged(self, table: Mapping[str, Any], key: str) -> "TruncNormal":
        """A copy with the fields in ``table`` replaced (scene-file partial override)."""
        bad = set(table) - {"mean", "sd", "lo", "hi"}
        if bad:
            k = sorted(bad)[0]
            raise ConfigError("unknown field of a truncated normal; valid: mean, sd, lo, hi",
                              key=f"{key}.{k}", value=table[k])
        vals = {f: _number(table[f], f"{key}.{f}") if f in table else getattr(self, f)
                for f in ("mean", "sd", "lo", "hi")}
        out = object.__new__(TruncNormal)
        for f, v in vals.items():
            object.__setattr__(out, f, v)
        out.check(key)
        return out


@dataclass(frozen=True)
class Discrete:
    """A discrete law: ``values[i]`` with probability ``probs[i]`` (probs sum to 1)."""

    values: tuple
    probs: tuple

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", tuple(self.values))
        object.__setattr__(self, "probs", tuple(float(p) for p in self.probs))
        self.check("Discrete")

    @classmethod
    def fixed(cls, value: float) -> "Discrete":
        return cls((value,), (1.0,))

    def check(self, key: str, *, integer: bool = False, lo: float | None = None,
              hi: float | None = None) -> None:
        """Raise ConfigError naming ``key.values`` / ``key.probs`` if unusable."""
        if not self.values:
            raise ConfigError("needs at least one value", key=f"{key}.values", value=list(self.values))
        if len(self.probs) != len(self.values):
            raise ConfigError(f"needs one probability per value ({len(self.values)})",
                              key=f"{key}.probs", value=list(self.probs))
        for v in self.values:
            if integer:
                _whole(v, f"{key}.values", int(lo) if lo is not None else -2**62,
                       int(hi) if hi is not None else None)
            else:
                x = _finite(v, f"{key}.values")
                if (lo is not None and x < lo) or (hi is not None and x > hi):
                    raise ConfigError(f"values must lie in [{lo}, {hi}]", key=f"{key}.values",
                                      value=list(self.values))
        if not all(math.isfinite(p) and p >= 0 for p in self.probs):
            raise ConfigError("probabilities must be finite and ≥ 0", key=f"{key}.probs",
                              value=list(self.probs))
        if abs(sum(self.probs) - 1.0) > 1e-6:
            raise ConfigError(f"probabilities must sum to 1 (they sum to {sum(self.probs):.6g})",
                              key=f"{key}.probs", value=list(self.probs))

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """``size`` draws (one uniform each, inverse CDF)."""
        u = rng.random(size)
        cdf = np.cumsum(self.probs)
        idx = np.minimum(np.searchsorted(cdf / cdf[-1], u, side="right"), len(cdf) - 1)
        return np.asarray(self.values)[idx]

    def moments(self) -> tuple[float, float]:
        v, p = np.asarray(self.values, np.float64), np.asarray(self.probs)
        m = float((v * p).sum())
        return m, float(math.sqrt(max(((v - m) ** 2 * p).sum(), 0.0)))

    def merged(self, table: Mapping[str, Any], key: str) -> "Discrete":
        bad = set(table) - {"values", "probs"}
        if bad:
            k = sorted(bad)[0]
            raise ConfigError("unknown field of a discrete law; valid: values, probs",
                              key=f"{key}.{k}", value=table[k])
        values = table.get("values", self.values)
        probs = table.get("probs", self.probs)
        for name, seq in (("values", values), ("probs", probs)):
            if not isinstance(seq, (list, tuple)):
                raise ConfigError("must be a list", key=f"{key}.{name}", value=seq)
        if "values" in table and "probs" not in table and len(values) != len(self.probs):
            probs = [1.0 / len(values)] * len(values) if values else []
        out = object.__new__(Discrete)
        object.__setattr__(out, "values", tuple(values))
        object.__setattr__(out, "probs", tuple(_number(p, f"{key}.probs") for p in probs))
        out.check(key)
        return out


@dataclass(frozen=True)
class Bernoulli:
    """True with probability ``p``."""

    p: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "p", _number(self.p, "p"))
        self.check("Bernoulli")

    def check(self, key: str) -> None:
        if not 0.0 <= self.p <= 1.0:
            raise ConfigError("must be a probability in [0, 1]", key=f"{key}.p", value=self.p)

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        return rng.random(size) < self.p

    def moments(self) -> tuple[float, float]:
        return self.p, math.sqrt(self.p * (1.0 - self.p))

    def merged(self, table: Mapping[str, Any], key: str) -> "Bernoulli":
        bad = set(table) - {"p"}
        if bad:
            k = sorted(bad)[0]
            raise ConfigError("unknown field of a Bernoulli law; valid: p", key=f"{key}.{k}",
                              value=table[k])
        out = object.__new__(Bernoulli)
        object.__setattr__(out, "p", _number(table.get("p", self.p), f"{key}.p"))
        out.check(key)
        return out


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
    tropism : weight of ``+ẑ`` added to every daughter heading (< 0 droops).
    min_length_m : branches shorter than this get no daughters.
    leaf_levels : branches in the last this many generations bear leaves.
    leaf_min_order : branches of this order or higher bear leaves.
    leaf_shape : ``"rhombus"`` (2 triangles) or ``"ellipse"`` (``leaf_sides`` triangles).
    leaf_sides : polygon sides of an ellipse leaf (≥ 4).
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
    growth_level: Discrete = Discrete((6, 7, 8), (0.25, 0.5, 0.25))
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
    leaf_length_m: TruncNormal = TruncNormal(0.10, 0.02, 0.05, 0.16)
    leaf_width_ratio: TruncNormal = TruncNormal(0.55, 0.06, 0.35, 0.75)
    leaves_per_branch: Discrete = Discrete((16, 20, 24), (0.25, 0.5, 0.25))
    leaf_angle_deg: TruncNormal = TruncNormal(50.0, 15.0, 10.0, 90.0)
    leaf_roll_deg: TruncNormal = TruncNormal(0.0, 20.0, -60.0, 60.0)
    # architecture constants
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


# --- results ---------------------------------------------------------------------------


@dataclass(frozen=True)
class LeafTable:
    """One row per leaf: what a sensor model needs (seed 004 keeps size, position, orientation).

    Attributes
    ----------
    tree_id, leaf_id : (n,) int32.
    centre_m : (n, 3) float64, blade centre (midpoint of base and tip).
    length_m, width_m, area_m2 : (n,) float64; area is the polygon's one-sided area.
    normal : (n, 3) unit upper-side normal of the flat blade.
    heading : (n, 3) unit vector from base to tip.
    """

    tree_id: np.ndarray
    leaf_id: np.ndarray
    centre_m: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    area_m2: np.ndarray
    normal: np.ndarray
    heading: np.ndarray

    COLUMNS = ("tree_id", "leaf_id", "x", "y", "z", "length_m", "width_m", "area_m2",
               "nx", "ny", "nz", "hx", "hy", "hz")

    def __len__(self) -> int:
        return len(self.leaf_id)

    @classmethod
    def empty(cls) -> "LeafTable":
        z3, z = np.zeros((0, 3)), np.zeros(0)
        return cls(np.zeros(0, np.int32), np.zeros(0, np.int32), z3, z, z, z, z3, z3)

    @classmethod
    def concat(cls, parts: Sequence["LeafTable"]) -> "LeafTable":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts])
                     for f in dataclasses.fields(cls)))

    def placed(self, translation_m, yaw_deg: float = 0.0, scale: float = 1.0,
               tree_id: int | None = None) -> "LeafTable":
        """The table of this tree scaled, turned by ``yaw_deg`` about z and moved."""
        R = _rot_z(yaw_deg)
        t = np.asarray(translation_m, np.float64)
        tid = self.tree_id if tree_id is None else np.full(len(self), tree_id, np.int32)
        return LeafTable(tid, self.leaf_id, scale * self.centre_m @ R.T + t, scale * self.length_m,
                         scale * self.width_m, scale * scale * self.area_m2, self.normal @ R.T,
                         self.heading @ R.T)

    def columns(self) -> dict[str, np.ndarray]:
        """Column name → 1-D array, in :attr:`COLUMNS` order."""
        c, n, h = self.centre_m, self.normal, self.heading
        return {"tree_id": self.tree_id, "leaf_id": self.leaf_id, "x": c[:, 0], "y": c[:, 1],
                "z": c[:, 2], "length_m": self.length_m, "width_m": self.width_m,
                "area_m2": self.area_m2, "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2],
                "hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2]}


@dataclass(frozen=True)
class TreeDraws:
    """Every random value one tree drew (kept with ``keep_draws=True``; for tests and audits).

    ``globals`` maps a global law's name to its one draw. ``locals`` maps a local law's
    name to all its draws in the tree: per branch that could grow (``lateral_branching``,
    ``twist_deg``, ``n_daughters``/``trunk_n_daughters``; drawn even where the order
    or bare-trunk rules then forbid laterals), per lateral daughter
    (``branch_angle_deg``/``trunk_branch_angle_deg``), per leader
    (``leader_angle_deg``), per leaf-bearing branch (``leaves_per_branch``) and per
    leaf (``leaf_length_m``, ``leaf_width_ratio``, ``leaf_angle_deg``, ``leaf_roll_deg``).
    """

    globals: dict[str, float]
    locals: dict[str, np.ndarray]


@dataclass(frozen=True)
class RandomTree:
    """One random tree in its own frame (trunk foot at the origin, trunk along +z).

    Attributes
    ----------
    branches : the woody segments (``tree_id`` as given).
    leaves : the leaf triangles (``leaf_id`` 0…n−1 within the tree, ``plant_id`` = tree id).
    leaf_table : one row per leaf.
    seed : the integer seed when the tree was made from one, else None.
    draws : every drawn value when asked for, else None.
    """

    branches: Branches
    leaves: Leaves
    leaf_table: LeafTable
    seed: int | None = None
    draws: TreeDraws | None = field(default=None, repr=False)

    @property
    def height_m(self) -> float:
        """Highest z of branch end points and leaf vertices (radii not added)."""
        zs = [0.0]
        if len(self.branches):
            zs.append(float(max(self.branches.p0[:, 2].max(), self.branches.p1[:, 2].max())))
        if len(self.leaves):
            zs.append(float(self.leaves.vertices[..., 2].max()))
        return max(zs)

    @property
    def crown_radius_m(self) -> float:
        """Largest horizontal distance of branch ends and leaf vertices from the trunk axis."""
        pts = [np.zeros((1, 2))]
        if len(self.branches):
            pts += [self.branches.p0[:, :2], self.branches.p1[:, :2]]
        if len(self.leaves):
            pts.append(self.leaves.vertices[..., :2].reshape(-1, 2))
        return float(np.sqrt(max((p ** 2).sum(1).max() for p in pts)))

    @property
    def n_leaves(self) -> int:
        return len(self.leaf_table)


# --- generation ------------------------------------------------------------------------


def _rot_z(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rotate(v: np.ndarray, axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotate rows of ``v`` about unit rows of ``axis`` (right-handed)."""
    c, s = np.cos(angle_rad)[:, None], np.sin(angle_rad)[:, None]
    return v * c + np.cross(axis, v) * s + axis * (axis * v).sum(1, keepdims=True) * (1 - c)


def _bend(H: np.ndarray, U: np.ndarray, tropism: float) -> tuple[np.ndarray, np.ndarray]:
    """Tropism: pull headings toward ±z, then make U perpendicular to H again."""
    if tropism == 0 or not len(H):
        return H, U
    H2 = H + tropism * _Z
    norm = np.linalg.norm(H2, axis=1, keepdims=True)
    # |τ| ≤ 0.95 keeps H + τẑ away from 0 unless H is nearly ∓ẑ; keep H there
    H2 = np.where(norm > 1e-6, H2 / np.maximum(norm, 1e-300), H)
    U2 = U - (U * H2).sum(1, keepdims=True) * H2
    n = np.linalg.norm(U2, axis=1, keepdims=True)
    fallback = np.cross(H2, np.where(np.abs(H2[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]]))
    U2 = np.where(n > 1e-9, U2 / np.maximum(n, 1e-300), _unit(fallback))
    return H2, U2


def _rng_of(seed) -> tuple[np.random.Generator, int | None]:
    if isinstance(seed, np.random.Generator):
        return seed, None
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed), None
    s = _whole(seed, "seed", 0)
    return np.random.default_rng(s), s


def random_tree(params: RandomTreeParams, seed: int | np.random.SeedSequence | np.random.Generator,
                *, tree_id: int = 0, keep_draws: bool = False) -> RandomTree:
    """Grow one random tree.

    Parameters
    ----------
    params : the species' laws and constants.
    seed : an integer ≥ 0, a ``SeedSequence`` or a ``Generator`` (consumed).
        The same integer gives the same bytes.
    tree_id : written to ``branches.tree_id``, ``leaves.plant_id`` and the leaf table.
    keep_draws : also return every drawn value (:class:`TreeDraws`).

    Returns
    -------
    RandomTree
        in the tree's own frame: trunk foot at the origin, growing along +z.

    Examples
    --------
    >>> t = random_tree(species_preset("conifer-whorl"), seed=7)
    >>> 10 < t.height_m < 30 and len(t.leaves) == 2 * t.n_leaves
    True
    """
    if not isinstance(params, RandomTreeParams):
        raise ConfigError("must be a RandomTreeParams", key="params", value=params)
    rng, int_seed = _rng_of(seed)
    tid = _whole(tree_id, "tree_id", 0)
    P = params
    rec: dict[str, list] = {}

    def draw(name: str, law, n: int) -> np.ndarray:
        x = law.sample(rng, n)
        if keep_draws:
            rec.setdefault(name, []).append(np.asarray(x))
        return x

    # global draws, fixed order (G1–G3)
    g = {"trunk_length_m": float(P.trunk_length_m.sample(rng)),
         "trunk_radius_m": float(P.trunk_radius_m.sample(rng)),
         "growth_level": int(P.growth_level.sample(rng)),
         "length_ratio": float(P.length_ratio.sample(rng)),
         "radius_ratio": float(P.radius_ratio.sample(rng))}
    g["lateral_length_ratio"] = (float(P.lateral_length_ratio.sample(rng))
                                 if P.lateral_length_ratio is not None else g["length_ratio"])
    g["lateral_radius_ratio"] = (float(P.lateral_radius_ratio.sample(rng))
                                 if P.lateral_radius_ratio is not None else g["radius_ratio"])
    G = g["growth_level"]
    tau = P.tropism

    # frontier of one generation: start, heading H, reference U ⟂ H, length, radius, order
    start = np.zeros((1, 3))
    H = np.array([[0.0, 0.0, 1.0]])
    U = np.array([[1.0, 0.0, 0.0]])
    length = np.array([g["trunk_length_m"]])
    radius = np.array([g["trunk_radius_m"]])
    order = np.array([1], np.int64)
    out_p0, out_p1, out_r, out_o, out_H, out_U, out_depth, out_kids = [], [], [], [], [], [], [], []
    n_total = 0
    for depth in range(G):
        n = len(length)
        if n == 0:
            break
        n_total += n
        if n_total > P.max_branches:
            raise ConfigError(f"tree {tid} grows more than {P.max_branches} branch segments; lower "
                              "growth_level or n_daughters, or raise max_branches",
                              key=f"{P.name}.max_branches", value=P.max_branches)
        end = start + H * length[:, None]
        out_p0.append(start)
        out_p1.append(end)
        out_r.append(radius)
        out_o.append(order)
        out_H.append(H)
        out_U.append(U)
        out_depth.append(np.full(n, depth))
        grows = (length >= P.min_length_m) if depth < G - 1 else np.zeros(n, bool)
        kids = np.zeros(n, np.int64)
        if not grows.any():
            out_kids.append(kids)
            break
        gi = np.flatnonzero(grows)
        ng = len(gi)
        # local draws of the growing branches (L1, L2, L4)
        flag = draw("lateral_branching", P.lateral_branching, ng)
        twist = np.radians(draw("twist_deg", P.twist_deg, ng))
        is_trunk = order[gi] == 1
        m = np.zeros(ng, np.int64)
        if P.trunk_n_daughters is not None:
            if is_trunk.any():
                m[is_trunk] = draw("trunk_n_daughters", P.trunk_n_daughters, int(is_trunk.sum()))
            if (~is_trunk).any():
                m[~is_trunk] = draw("n_daughters", P.n_daughters, int((~is_trunk).sum()))
        else:
            m[:] = draw("n_daughters", P.n_daughters, ng)
        can_lateral = (order[gi] < P.max_order) & ~(is_trunk & (depth < P.bare_trunk_levels))
        m = np.where(can_lateral, m, 0)
        leader = order[gi] <= P.monopodial_orders

        # lateral daughters: mother index, index within the set, position, angle
        mother = np.repeat(np.arange(ng), m)
        k_in = np.arange(len(mother)) - np.repeat(np.cumsum(m) - m, m)
        nl = len(mother)
        t = np.ones(nl)
        lat_flag = flag[mother]
        if lat_flag.any():
            t[lat_flag] = rng.uniform(P.lateral_position_min, 1.0, int(lat_flag.sum()))
        ang = np.empty(nl)
        trunk_mother = is_trunk[mother]
        if P.trunk_branch_angle_deg is not None:
            if trunk_mother.any():
                ang[trunk_mother] = draw("trunk_branch_angle_deg", P.trunk_branch_angle_deg,
                                         int(trunk_mother.sum()))
            if (~trunk_mother).any():
                ang[~trunk_mother] = draw("branch_angle_deg", P.branch_angle_deg,
                                          int((~trunk_mother).sum()))
        else:
            ang[:] = draw("branch_angle_deg", P.branch_angle_deg, nl)
        ang = np.radians(ang)
        src = gi[mother]
        az = twist[mother] + 2 * np.pi * k_in / np.maximum(m[mother], 1)
        u = _rotate(U[src], H[src], az)
        Hd = np.cos(ang)[:, None] * H[src] + np.sin(ang)[:, None] * u
        Ud = np.cos(ang)[:, None] * u - np.sin(ang)[:, None] * H[src]
        Hd, Ud = _bend(Hd, Ud, tau)
        # apex-branching (no leader) daughters continue the axis ratio r1; laterals of a led axis use r2
        led = leader[mother]
        lr = np.where(led, g["lateral_length_ratio"], g["length_ratio"])
        rr = np.where(led, g["lateral_radius_ratio"], g["radius_ratio"])
        lat = (start[src] + t[:, None] * (end[src] - start[src]), Hd, Ud, length[src] * lr,
               radius[src] * rr, order[src] + 1)

        # leaders (monopodial axes): opposite the first lateral, rolled by the divergence
        li = np.flatnonzero(leader)
        nL = len(li)
        la = np.radians(draw("leader_angle_deg", P.leader_angle_deg, nL))
        srcL = gi[li]
        uL = _rotate(U[srcL], H[srcL], twist[li] + np.pi)
        HL = np.cos(la)[:, None] * H[srcL] + np.sin(la)[:, None] * uL
        UL = np.cos(la)[:, None] * uL - np.sin(la)[:, None] * H[srcL]
        UL = _rotate(UL, HL, np.full(nL, math.radians(P.divergence_deg)))
        side = order[srcL] > 1  # the trunk's own leader is not bent: stems stay upright
        if side.any():
            HL[side], UL[side] = _bend(HL[side], UL[side], tau)
        lead = (end[srcL], HL, UL, length[srcL] * g["length_ratio"],
                radius[srcL] * g["radius_ratio"], order[srcL])

        kids[gi] = m + leader
        out_kids.append(kids)
        start, H, U, length, radius, order = (np.concatenate([a, b]) for a, b in zip(lead, lat))
    if len(out_kids) < len(out_p0):
        out_kids.append(np.zeros(len(out_p0[-1]), np.int64))

    p0 = np.concatenate(out_p0)
    p1 = np.concatenate(out_p1)
    r = np.concatenate(out_r)
    o = np.concatenate(out_o)
    Hb = np.concatenate(out_H)
    Ub = np.concatenate(out_U)
    depth = np.concatenate(out_depth)
    n_kids = np.concatenate(out_kids)
    branches = Branches(p0, p1, 2.0 * r, o.astype(np.int32), np.full(len(r), tid, np.int32))

    # leaves (L3): on terminal branches, the last leaf_levels generations, high orders
    bearing = (n_kids == 0) | (depth >= G - P.leaf_levels) | (o >= P.leaf_min_order)
    bi = np.flatnonzero(bearing)
    counts = draw("leaves_per_branch", P.leaves_per_branch, len(bi)).astype(np.int64)
    owner = np.repeat(bi, counts)
    nleaf = len(owner)
    tpos = rng.random(nleaf)
    phi = rng.uniform(0.0, 2 * np.pi, nleaf)
    lang = np.radians(draw("leaf_angle_deg", P.leaf_angle_deg, nleaf))
    ll = draw("leaf_length_m", P.leaf_length_m, nleaf)
    lw = ll * draw("leaf_width_ratio", P.leaf_width_ratio, nleaf)
    roll = np.radians(draw("leaf_roll_deg", P.leaf_roll_deg, nleaf))
    leaves, table = _make_leaves(P, p0[owner], p1[owner], r[owner], Hb[owner], Ub[owner],
                                 tpos, phi, lang, ll, lw, roll, tid)
    draws = None
    if keep_draws:
        local = {k: np.zeros(0) for k in _LAWS if k not in g}  # every local law, drawn or not
        local.update({k: np.concatenate(v) for k, v in rec.items()})
        draws = TreeDraws(dict(g), local)
    return RandomTree(branches, leaves, table, int_seed, draws)


def _make_leaves(P: RandomTreeParams, b0, b1, br, H, U, tpos, phi, lang, ll, lw, roll,
                 tid: int) -> tuple[Leaves, LeafTable]:
    n = len(ll)
    if n == 0:
        return Leaves.empty(), LeafTable.empty()
    u = _rotate(U, H, phi)                           # outward direction at the insertion
    head = np.cos(lang)[:, None] * H + np.sin(lang)[:, None] * u
    base = b0 + tpos[:, None] * (b1 - b0) + br[:, None] * u   # attached at the bark
    side = np.cross(head, _Z)
    sn = np.linalg.norm(side, axis=1, keepdims=True)
    # a vertical leaf has no horizontal side vector: use its insertion direction's normal
    side = np.where(sn > 1e-6, side / np.maximum(sn, 1e-300), _unit(np.cross(head, u)))
    up = np.cross(side, head)                        # upper-side normal with roll 0
    side_r = np.cos(roll)[:, None] * side + np.sin(roll)[:, None] * up
    normal = np.cross(side_r, head)
    centre = base + 0.5 * ll[:, None] * head
    half_l, half_w = 0.5 * ll[:, None, None], 0.5 * lw[:, None, None]
    if P.leaf_shape == "rhombus":
        tip = base + ll[:, None] * head
        right = centre + 0.5 * lw[:, None] * side_r
        left = centre - 0.5 * lw[:, None] * side_r
        # (base, right, tip), (base, tip, left): both wound so the normal is side × head
        tri = np.stack([np.stack([base, right, tip], 1), np.stack([base, tip, left], 1)], 1)
    else:
        k = P.leaf_sides
        a = 2 * np.pi * np.arange(k + 1) / k
        ring = (centre[:, None, :] + np.cos(a)[None, :, None] * half_l * head[:, None, :]
                + np.sin(a)[None, :, None] * half_w * side_r[:, None, :])   # (n, k+1, 3)
        c = np.broadcast_to(centre[:, None, :], (n, k, 3))
        tri = np.stack([c, ring[:, 1:], ring[:, :-1]], 2)   # (centre, v_{j+1}, v_j)
    ntri = tri.shape[1]
    area = leaf_polygon_area_factor(P.leaf_shape, P.leaf_sides) * ll * lw
    leaf_id = np.arange(n, dtype=np.int32)
    leaves = Leaves(tri.reshape(-1, 3, 3), np.repeat(leaf_id, ntri),
                    np.full(n * ntri, tid, np.int32))
    table = LeafTable(np.full(n, tid, np.int32), leaf_id, centre, ll, lw, area, normal, head)
    return leaves, table


# --- species presets -------------------------------------------------------------------

_T = TruncNormal
_D = Discrete

#: Four forest species as random-tree parameter sets. Architecture follows the
#: paper's §II-C: apex branching (flag false) as in elm and birch, branching at
#: random points along the mother (flag true) as in spruce, and Honda's
#: monopodial trees (ABOP Fig. 2.6). Sizes are this project's choice from common
#: field values (heights, trunk radii, leaf lengths), not from the paper, which
#: gives no numbers; "conifer-whorl" foliage is flat shoot elements (a few cm),
#: not single needles.
SPECIES_PRESETS: dict[str, RandomTreeParams] = {
    # elm/birch-like: sympodial, every split at the apex; ~13–20 m, leaves 6–14 cm
    "deciduous-apex": RandomTreeParams(),
    # spruce-like: a leader trunk with whorls of 4–6 near-horizontal laterals
    # (some scattered between whorls: flag p = 0.3), drooping; ~15–24 m, shoots 6–10 cm
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
        leaf_length_m=_T(0.08, 0.012, 0.05, 0.11), leaf_width_ratio=_T(0.30, 0.04, 0.20, 0.40),
        leaves_per_branch=_D((12, 16, 20), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(40.0, 12.0, 10.0, 80.0), leaf_roll_deg=_T(0.0, 25.0, -70.0, 70.0),
        monopodial_orders=2, max_order=3, bare_trunk_levels=2, lateral_position_min=0.2,
        tropism=-0.04, min_length_m=0.08, leaf_levels=2, leaf_min_order=3),
    # beech/ash-like Honda monopodial broadleaf: leader trunk and main limbs, laterals
    # at random points along them (flag p = 0.7); ~14–22 m, leaves 5–11 cm
    "broadleaf-monopodial": RandomTreeParams(
        name="broadleaf-monopodial",
        trunk_length_m=_T(2.6, 0.3, 1.8, 3.4), trunk_radius_m=_T(0.25, 0.04, 0.15, 0.38),
        growth_level=_D((8, 9, 10), (0.25, 0.5, 0.25)),
        length_ratio=_T(0.88, 0.02, 0.82, 0.94), radius_ratio=_T(0.82, 0.03, 0.74, 0.90),
        lateral_length_ratio=_T(0.70, 0.05, 0.55, 0.85), lateral_radius_ratio=_T(0.45, 0.04, 0.35, 0.55),
        lateral_branching=Bernoulli(0.7), twist_deg=_T(0.0, 30.0, -90.0, 90.0),
        n_daughters=_D((2, 3), (0.5, 0.5)), trunk_n_daughters=_D((3, 4), (0.5, 0.5)),
        branch_angle_deg=_T(45.0, 10.0, 20.0, 75.0), trunk_branch_angle_deg=_T(50.0, 8.0, 30.0, 70.0),
        leader_angle_deg=_T(0.0, 4.0, -12.0, 12.0),
        leaf_length_m=_T(0.08, 0.015, 0.05, 0.11), leaf_width_ratio=_T(0.60, 0.06, 0.45, 0.75),
        leaves_per_branch=_D((10, 14, 18), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(55.0, 15.0, 15.0, 90.0), leaf_roll_deg=_T(0.0, 15.0, -45.0, 45.0),
        monopodial_orders=2, max_order=4, bare_trunk_levels=2, lateral_position_min=0.25,
        tropism=0.15, min_length_m=0.10, leaf_levels=3, leaf_min_order=3),
    # hawthorn-like small tree: short trunk, dense apex splits, small leaves; ~5–8 m
    "small-tree": RandomTreeParams(
        name="small-tree",
        trunk_length_m=_T(1.6, 0.25, 1.0, 2.2), trunk_radius_m=_T(0.09, 0.015, 0.05, 0.14),
        growth_level=_D((6, 7), (0.5, 0.5)),
        length_ratio=_T(0.82, 0.04, 0.70, 0.94), radius_ratio=_T(0.72, 0.04, 0.60, 0.84),
        lateral_branching=Bernoulli(0.25), twist_deg=_T(0.0, 35.0, -90.0, 90.0),
        n_daughters=_D((2, 3), (0.5, 0.5)), trunk_n_daughters=_D((3, 4), (0.5, 0.5)),
        branch_angle_deg=_T(35.0, 10.0, 10.0, 65.0), leader_angle_deg=_T(0.0, 5.0, -15.0, 15.0),
        leaf_length_m=_T(0.04, 0.008, 0.02, 0.06), leaf_width_ratio=_T(0.80, 0.08, 0.60, 1.00),
        leaves_per_branch=_D((10, 15, 20), (0.3, 0.4, 0.3)),
        leaf_angle_deg=_T(50.0, 15.0, 10.0, 90.0), leaf_roll_deg=_T(0.0, 20.0, -60.0, 60.0),
        leaf_shape="ellipse", leaf_sides=6,
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
