"""LI-COR LAI-2200 plant canopy analyser, emulated on ring transmittances.

The instrument's optical sensor sees the sky through five concentric rings; a reading is
the blue-light (< 490 nm) radiance of each ring. With an above-canopy reading A and a
below-canopy reading B, each ring's transmittance is ``T = B/A``. Under a uniform overcast
sky (the manual's recommended condition) T is the ring's gap fraction, which is what a
virtual fisheye image gives: :func:`ring_transmittance` turns a per-ring, per-sector gap
table into the readings the instrument would take with a view cap.

Constants
---------
Ring widths dθ_i and weights W_i, W'_i: LI-COR, LAI-2200C instruction manual, "Computing
LAI", Table 7-1 "Ring widths and weighting factors" (online:
https://www.licor.com/env/support/LAI-2200C/topics/computing-lai.html; the table is quoted
at https://stafor.frama.io/docs/lai/). Ring bounds and centres: the LAI-2200 manual
(publication 984-10633), as coded in AMAPVox (``org.amapvox.canopy.lai2xxx.LAI2200``,
which cites it) with the same W_i and W'_i.
=====  ==============  ========  =========  ========  =========  =======
ring   zenith (°)      θ_i (°)   dθ_i (°)   W_i       W'_i       S_i
=====  ==============  ========  =========  ========  =========  =======
1      0 – 12.3        7         12.2       0.041     0.033      1.008
2      16.7 – 28.6     23        12.2       0.131     0.097      1.087
3      32.4 – 43.4     38        11.8       0.201     0.127      1.269
4      47.3 – 58.1     53        13.2       0.290     0.141      1.662
5      62.3 – 74.1     68        13.2       0.337     0.102      2.669
=====  ==============  ========  =========  ========  =========  =======

S_i is computed as ``1/cos θ_i`` (the manual: "for L we use S(θ) = 1/cos θ"; 1.008, 1.087,
1.269, 1.662, 2.669). ``W_i = sin θ_i dθ_i / Σ sin θ dθ`` (LAI weights, normalised to sum 1 over the rings in
use: masking a ring raises the others), ``W'_i = sin θ_i cos θ_i dθ_i / (2 Σ …)`` (DIFN
weights, summing to 1/2), ``S_i = 1/cos θ_i`` the relative path length of a horizontally
uniform canopy (the manual's standard "DIST"). View caps block all but 270°, 180°, 90° or
45° of azimuth (the manual's caps), centred on the sensor's heading.

Method (manual, "LAI-2000 Method")
----------------------------------
For n above/below pairs j and ring i: the contact value ``K_ij = −ln(B_ij/A_ij)/S_i``, the
mean contact number ``K_i = mean_j K_ij`` and

    LAI = 2 Σ_i K_i W_i.

Averaging the logarithms over the readings is the instrument's own clumping correction, so
LAI lies between the effective and the true LAI. The apparent clumping factor (manual's ACF)

    ACF = Σ_i W_i (−ln(mean_j T_ij) / S_i) / Σ_i W_i K_i

is Lang & Xiang's ratio over the readings; ``L_e = LAI·ACF``. ``DIFN = Σ mean_j T_ij W'_i /
Σ W'_i`` is the diffuse non-interceptance, the canopy's sky openness. A ring with T = 0 at a
reading is floored (:func:`~simlidar_mi.canopy.lai_methods.floor_gap_fraction`).

What we do not emulate: the sensor's angular response within a ring (the manual does not
publish it; a ring's transmittance here is its solid-angle mean gap fraction), the
scattered blue light that makes field T slightly positive under full cover, and the sky's
radiance distribution (uniform: A cancels).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .lai_methods import PAI_SAT, floor_gap_fraction

__all__ = [
    "RING_BOUNDS_DEG", "RING_CENTRES_DEG", "RING_WIDTHS_DEG", "LAI_WEIGHTS", "DIFN_WEIGHTS",
    "PATH_LENGTHS", "VIEW_CAPS_DEG", "LAI2200Result", "lai2200", "ring_transmittance",
    "cap_mask",
]

RING_BOUNDS_DEG = ((0.0, 12.3), (16.7, 28.6), (32.4, 43.4), (47.3, 58.1), (62.3, 74.1))
RING_CENTRES_DEG = (7.0, 23.0, 38.0, 53.0, 68.0)
RING_WIDTHS_DEG = (12.2, 12.2, 11.8, 13.2, 13.2)
LAI_WEIGHTS = (0.041, 0.131, 0.201, 0.290, 0.337)
DIFN_WEIGHTS = (0.033, 0.097, 0.127, 0.141, 0.102)
PATH_LENGTHS = tuple(1.0 / math.cos(math.radians(t)) for t in RING_CENTRES_DEG)
VIEW_CAPS_DEG = (360.0, 270.0, 180.0, 90.0, 45.0)
N_RINGS = 5


@dataclass(frozen=True)
class LAI2200Result:
    """The instrument's outputs for a set of above/below pairs.

    Attributes
    ----------
    lai : float
        ``2 Σ K_i W_i`` (log-averaged over readings).
    acf : float
        Apparent clumping factor; ``lai_effective = lai·acf``.
    lai_effective : float
    difn : float
        Diffuse non-interceptance.
    contact_number : (5,) float
        ``K_i`` per ring (NaN when masked).
    avg_trans : (5,) float
        ``mean_j T_ij`` per ring.
    acf_ring : (5,) float
        ``ln(mean T) / mean(ln T)`` per ring.
    lai_per_reading : (n,) float
        ``2 Σ K_ij W_i`` for each pair.
    weights : (5,) float
        LAI weights used (0 for masked rings).
    n_floored : int
        Ring readings with T = 0 that were floored.
    """

    lai: float
    acf: float
    lai_effective: float
    difn: float
    contact_number: np.ndarray
    avg_trans: np.ndarray
    acf_ring: np.ndarray
    lai_per_reading: np.ndarray
    weights: np.ndarray
    n_floored: int


def _masked(masked_rings) -> np.ndarray:
    keep = np.ones(N_RINGS, bool)
    for r in masked_rings:
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or not 1 <= r <= N_RINGS:
            raise ConfigError("ring numbers run from 1 to 5", key="masked_rings", value=r)
        keep[int(r) - 1] = False
    if not keep.any():
        raise ConfigError("at least one ring must stay unmasked", key="masked_rings",
                          value=list(masked_rings))
    return keep


def lai2200(below, above=1.0, *, masked_rings=(), path_lengths=PATH_LENGTHS,
            zero_gap: str = "pai_sat", n_pixels=None, pai_sat: float = PAI_SAT) -> LAI2200Result:
    """LAI, ACF and DIFN from below (and above) readings, ``(n_readings, 5)`` each.

    ``above`` defaults to 1 (``below`` are then transmittances, e.g. from
    :func:`ring_transmittance`). ``masked_rings`` are ring numbers 1–5 left out, as the
    FV2200 software allows. ``path_lengths`` S_i default to the horizontally uniform canopy.
    """
    b = np.atleast_2d(np.asarray(below, float))
    a = np.broadcast_to(np.asarray(above, float), b.shape)
    if b.shape[1] != N_RINGS:
        raise ConfigError("readings need one value per ring (5 columns)", key="below",
                          value=b.shape)
    if not (np.isfinite(a).all() and (a > 0).all()):
        raise ConfigError("above-canopy readings must be finite and > 0", key="above",
                          value=float(a.min()))
    if not np.isfinite(b).all() or (b < 0).any():
        raise ConfigError("below-canopy readings must be finite and ≥ 0", key="below",
                          value=float(np.nanmin(b)))
    s = np.asarray(path_lengths, float)
    if s.shape != (N_RINGS,) or not (s > 0).all():
        raise ConfigError("need five path lengths > 0", key="path_lengths", value=path_lengths)
    keep = _masked(masked_rings)
    t = np.minimum(b / a, 1.0)  # a reading brighter below than above is clipped, as T ≤ 1
    tf, n_floor = floor_gap_fraction(t.T, RING_CENTRES_DEG, zero_gap=zero_gap,
                                     n_pixels=None if n_pixels is None else
                                     np.broadcast_to(np.asarray(n_pixels, float), b.shape).T,
                                     pai_sat=pai_sat)
    tf = tf.T
    w = np.where(keep, LAI_WEIGHTS, 0.0)
    w = w / w.sum()
    wd = np.where(keep, DIFN_WEIGHTS, 0.0)
    k_ij = -np.log(tf) / s
    k = k_ij.mean(axis=0)
    avg = t.mean(axis=0)
    avg_f, _ = floor_gap_fraction(avg, RING_CENTRES_DEG, zero_gap="pai_sat", pai_sat=pai_sat)
    k_avg = -np.log(avg_f) / s
    lai = float(2.0 * np.sum((k * w)[keep]))
    num = float(2.0 * np.sum((k_avg * w)[keep]))
    acf = num / lai if lai > 0 else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        acf_ring = np.log(avg_f) / np.log(tf).mean(axis=0)
    per = 2.0 * (k_ij[:, keep] * w[keep]).sum(axis=1)
    difn = float(np.sum((avg * wd)[keep]) / wd[keep].sum())
    nanm = np.where(keep, 1.0, np.nan)
    return LAI2200Result(lai, acf, lai * acf if math.isfinite(acf) else float("nan"), difn,
                         k * nanm, avg, acf_ring * nanm, per, w, n_floor)


def cap_mask(sector_centres_deg, view_cap_deg: float = 360.0, heading_deg: float = 0.0) -> np.ndarray:
    """Sectors whose centre azimuth lies within ``±view_cap_deg/2`` of ``heading_deg``."""
    if not (0.0 < view_cap_deg <= 360.0):
        raise ConfigError("must lie in (0, 360] degrees", key="view_cap_deg", value=view_cap_deg)
    az = np.asarray(sector_centres_deg, float)
    if view_cap_deg >= 360.0:
        return np.ones(az.shape, bool)
    d = (az - heading_deg + 180.0) % 360.0 - 180.0
    return np.abs(d) <= 0.5 * view_cap_deg + 1e-9


def ring_transmittance(gap_fraction, sector_centres_deg, *, view_cap_deg: float = 360.0,
                       heading_deg: float = 0.0, sector_weights=None) -> np.ndarray:
    """Readings (transmittance per LAI-2200 ring) from a gap table on the instrument's rings.

    Parameters
    ----------
    gap_fraction : (5, n_sectors) or (n_positions, 5, n_sectors)
        Gap fraction of each LAI-2200 ring (:data:`RING_BOUNDS_DEG`) and azimuth sector.
    sector_centres_deg : (n_sectors,)
        Azimuth of each sector's centre, degrees, in the same frame as ``heading_deg``.
    view_cap_deg : 360, 270, 180, 90 or 45 (any value in (0, 360] is accepted).
    heading_deg : azimuth the open part of the cap faces.
    sector_weights : solid angle (or pixel count) of each sector, broadcast like the gaps;
        default equal (equal sectors of a ring have equal solid angle).

    Returns
    -------
    (5,) or (n_positions, 5) transmittances; a cap narrower than one sector keeps the sector
    whose centre is nearest the heading.
    """
    p = np.asarray(gap_fraction, float)
    az = np.asarray(sector_centres_deg, float)
    single = p.ndim == 2
    p = p[None] if single else p
    if p.ndim != 3 or p.shape[1] != N_RINGS or p.shape[2] != az.size:
        raise ConfigError("gap table must be (5, n_sectors) or (n_positions, 5, n_sectors) with "
                          "one azimuth per sector", key="gap_fraction", value=np.shape(gap_fraction))
    sel = cap_mask(az, view_cap_deg, heading_deg)
    if not sel.any():
        sel = np.zeros(az.shape, bool)
        sel[np.argmin(np.abs((az - heading_deg + 180.0) % 360.0 - 180.0))] = True
    w = np.ones(p.shape) if sector_weights is None else np.broadcast_to(
        np.asarray(sector_weights, float), p.shape)
    w = np.where(sel[None, None, :] & np.isfinite(p), w, 0.0)
    tot = w.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(tot > 0, (np.nan_to_num(p) * w).sum(axis=2) / tot, np.nan)
    return t[0] if single else t
