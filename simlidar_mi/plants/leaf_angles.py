"""Leaf inclination laws: de Wit's named distributions and measured tables, sampled exactly.

The leaf inclination ``θ_L`` is the angle between a leaf's upper normal and the zenith
(0° = a horizontal blade, 90° = a vertical one), in ``[0, π/2]``. de Wit's (1965) canopy
types (*Photosynthesis of leaf canopies*, Agric. Res. Rep. 663, Pudoc, Wageningen), used here
in their exact trigonometric form; Goel & Strebel (1984, Agron. J. 76:800–802,
doi:10.2134/agronj1984.00021962007600050021x) represent the same types by two-parameter beta
distributions, and Wang, Li & Su (2007, Agric. For. Meteorol. 143:106–122,
doi:10.1016/j.agrformet.2006.12.003) compare both forms. Densities and CDFs:

=============  ===========================  ==================================
law            density f(θ)                 CDF F(θ)
=============  ===========================  ==================================
spherical      sin θ                        1 − cos θ
uniform        2/π                          2θ/π
planophile     (2/π)(1 + cos 2θ)            (2/π)(θ + sin(2θ)/2)
erectophile    (2/π)(1 − cos 2θ)            (2/π)(θ − sin(2θ)/2)
plagiophile    (2/π)(1 − cos 4θ)            (2/π)(θ − sin(4θ)/4)
extremophile   (2/π)(1 + cos 4θ)            (2/π)(θ + sin(4θ)/4)
=============  ===========================  ==================================

Sampling is by the inverse CDF: ``θ = F⁻¹(u)`` with ``u`` uniform. Spherical and uniform
invert in closed form; the four trigonometric laws are inverted by bisection to the
last bit of a double (their CDFs are strictly increasing on ``[0, π/2]``), so the samples
follow ``F`` exactly up to floating-point rounding, one uniform per leaf.

A measured table is a list of ``[angle_deg, frequency]`` pairs: ``angle_deg`` is the
*upper edge* of a class that starts at the previous pair's edge (the first at 0°), edges
strictly increasing in ``(0, 90]``, frequencies ≥ 0 (any scale, not all zero). Within a
class the angle is uniform, so the CDF is piecewise linear through the cumulated
frequencies and its inverse is exact linear interpolation.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..config.keys_orchard import LEAF_ANGLE_LAWS
from ..errors import ConfigError

__all__ = ["LEAF_ANGLE_LAWS", "leaf_angle_cdf", "leaf_angle_table", "sample_leaf_angles"]

# law → (a, k): F(θ) = (2/π)(θ + a·sin(kθ)/k)
_TRIG = {"planophile": (1.0, 2.0), "erectophile": (-1.0, 2.0), "plagiophile": (-1.0, 4.0),
         "extremophile": (1.0, 4.0)}


def leaf_angle_table(table: Any, key: str = "angle_distribution") -> tuple[np.ndarray, np.ndarray]:
    """A measured table → (edges_rad with a leading 0, CDF at the edges); ConfigError if unusable."""
    try:
        arr = np.asarray(table, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0 or not np.isfinite(arr).all():
        raise ConfigError("must be a law name or a list of [angle_deg, frequency] pairs",
                          key=key, value=table)
    edges, freq = arr[:, 0], arr[:, 1]
    if edges[0] <= 0 or edges[-1] > 90 or (np.diff(edges) <= 0).any():
        raise ConfigError("class upper edges must increase strictly within (0, 90] degrees",
                          key=key, value=table)
    if (freq < 0).any() or freq.sum() <= 0:
        raise ConfigError("frequencies must be ≥ 0 and not all zero", key=key, value=table)
    cdf = np.concatenate([[0.0], np.cumsum(freq)]) / freq.sum()
    return np.radians(np.concatenate([[0.0], edges])), cdf


def _law(law: str | Sequence, key: str):
    if isinstance(law, str):
        if law not in LEAF_ANGLE_LAWS:
            raise ConfigError(f"must be one of {', '.join(LEAF_ANGLE_LAWS)} or a table",
                              key=key, value=law)
        return law
    return leaf_angle_table(law, key)


def leaf_angle_cdf(law: str | Sequence, theta_rad, key: str = "angle_distribution") -> np.ndarray:
    """``F(θ)``: the share of leaves inclined less than ``theta_rad`` (clipped to [0, π/2])."""
    spec = _law(law, key)
    t = np.clip(np.asarray(theta_rad, np.float64), 0.0, math.pi / 2)
    if isinstance(spec, tuple):
        return np.interp(t, spec[0], spec[1])
    if spec == "spherical":
        return 1.0 - np.cos(t)
    if spec == "uniform":
        return 2.0 * t / math.pi
    a, k = _TRIG[spec]
    return (2.0 / math.pi) * (t + a * np.sin(k * t) / k)


def sample_leaf_angles(law: str | Sequence, u, key: str = "angle_distribution") -> np.ndarray:
    """Inclinations ``F⁻¹(u)`` in radians for uniforms ``u`` in [0, 1) (one per leaf)."""
    spec = _law(law, key)
    u = np.asarray(u, np.float64)
    if isinstance(spec, tuple):
        edges, cdf = spec
        # the class whose CDF step holds u (side="right" skips classes of zero frequency)
        j = np.clip(np.searchsorted(cdf, u, side="right") - 1, 0, len(cdf) - 2)
        share = (u - cdf[j]) / (cdf[j + 1] - cdf[j])
        return edges[j] + share * (edges[j + 1] - edges[j])
    if spec == "spherical":
        return np.arccos(1.0 - u)
    if spec == "uniform":
        return 0.5 * math.pi * u
    lo, hi = np.zeros_like(u), np.full_like(u, 0.5 * math.pi)
    for _ in range(64):  # halves [0, π/2] to below one ulp of π/2
        mid = 0.5 * (lo + hi)
        below = leaf_angle_cdf(spec, mid) < u
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)
