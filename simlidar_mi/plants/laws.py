"""Probability laws of random-tree parameters (TruncNormal, Discrete, Bernoulli) and number checks."""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Mapping

import numpy as np

from ..errors import ConfigError

__all__ = ["TruncNormal", "Discrete", "Bernoulli"]


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
        # Φ(x) = erfc(−x/√2)/2 from the standard library: this only guards the interval at
        # validation (laws are built at import), where scipy's 0.15 s import is not worth it.
        a, b = self._std_bounds()
        phi = lambda x: 0.5 * math.erfc(-x / math.sqrt(2.0))  # noqa: E731
        return phi(-a) - phi(-b) if a > 0 else phi(b) - phi(a)

    @cached_property
    def _inverse(self) -> tuple[bool, Any, Any]:
        """(mirror, Φ(a), Φ(b) − Φ(a)) of the inverse-CDF draw, computed once per law.

        A random tree draws from each law a few times per generation; recomputing these
        two ``ndtr`` values each time cost more than the draws themselves.
        """
        from scipy.special import ndtr  # noqa: PLC0415 - not at import: see _mass
        a, b = self._std_bounds()
        if a > 0:  # interval above the mean: sample the mirror image in the lower tail
            pa, pb = ndtr(-b), ndtr(-a)
        else:
            pa, pb = ndtr(a), ndtr(b)
        return bool(a > 0), pa, pb - pa

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """``size`` independent draws (float64 array; a 0-d array when size is None)."""
        u = rng.random(size)
        if self.sd == 0:
            return np.full_like(u, self.mean)
        from scipy.special import ndtri  # noqa: PLC0415 - not at import: see _mass
        mirror, pa, width = self._inverse
        x = ndtri(pa + u * width)
        if mirror:
            x = -x
        # np.clip's elementwise min(max(x, lo), hi), without its Python-level dispatch
        return np.minimum(np.maximum(self.mean + self.sd * x, self.lo), self.hi)

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
        cdf, values = self._table
        idx = np.minimum(np.searchsorted(cdf, u, side="right"), len(cdf) - 1)
        return values[idx]

    @cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        """The normalised CDF and the values as an array, computed once per law."""
        cdf = np.cumsum(self.probs)
        return cdf / cdf[-1], np.asarray(self.values)

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
