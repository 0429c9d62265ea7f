"""Gap-fraction LAI methods on plain arrays: Miller, 57.5°, Lang–Xiang, Chen–Cihlar, true LAI.

Every method takes plain numbers, so the same code reads virtual fisheye images, real
hemispherical photographs and LAI-2200 readings: zenith ring bounds in degrees, gap
fractions per ring (``(n_rings,)``) or per ring and azimuth sector (``(n_rings,
n_sectors)``), and gap lengths along transects. No Mitsuba, no camera.

Model
-----
Gap fraction of a canopy of leaf area index L in direction θ (Nilson 1971):
``P(θ) = exp(−G(θ)·Ω·L / cos θ)``, G the mean projection of unit leaf area (0.5 for
spherically distributed normals), Ω the clumping index (1 for leaves placed at random,
< 1 clumped, > 1 regular). ``L_e = Ω·L`` is the effective LAI.

Methods
-------
Miller (1967)
    ``L_e = 2 ∫₀^{π/2} −ln P(θ) cos θ sin θ dθ`` (exact whatever G, because
    ``∫ G(θ) sin θ dθ = 1/2`` over the hemisphere). Over rings, with ``K_i = −ln P_i
    cos θ_i`` at the ring centre θ_i and the ring's weight ``w_i = ∫ sin θ dθ = cos θ_lo −
    cos θ_hi``: ``L_e = 2 Σ K_i w_i``. Rings stop short of 90°, so by default the weights
    are normalised to sum to 1 (``weights='normalized'``: the LAI-2000 manual's and
    hemispheR's convention; exact for any ring set when K is constant, e.g. spherical
    leaves). ``weights='quadrature'`` keeps the unnormalised integral over the rings only
    (it reads low by the missing rings' share).
57.5° (Warren Wilson 1963; Bonhomme & Chartier 1972)
    At θ = 57.5°, G ≈ 0.5 for any leaf angle distribution, so
    ``L_e = −ln P(57.5°)·cos 57.5° / 0.5``.
Lang & Xiang (1986) logarithmic averaging
    Over the sectors k of a ring, ``Ω_LX = ln(mean_k P_k) / mean_k(ln P_k)``; the LAI of
    the same rings with ``mean_k(−ln P_k)`` in place of ``−ln(mean_k P_k)`` is
    ``L_LX = L_e / Ω_LX`` (hemispheR's ``LX`` is ``L_e / L``). Jensen's inequality keeps
    ``Ω_LX ≤ 1``: it can reveal clumping between sectors, never regularity.
Chen & Cihlar (1995) gap-size distribution (gap removal)
    From the gap lengths λ along transects of total length T: the measured accumulated
    gap fraction ``F_m(λ) = Σ_{λ_j ≥ λ} λ_j / T``; a random canopy of projected LAI ``L_p``
    and projected element width ``W_p`` has ``F(λ) = (1 + L_p λ/W_p)·exp(−L_p(1 + λ/W_p))``.
    Gaps too large for a random canopy (fewer than 0.05 such gaps expected on the
    transects, or ``F(λ) < cutoff``: :func:`chen_cihlar`) are removed, ``L_p`` is updated
    from the reduced ``F_mr(0)`` and the removal repeated until ``L_p`` settles; then
    ``Ω_CC = [ln F_m(0) / ln F_mr(0)]·[(1 − F_mr(0)) / (1 − F_m(0))]`` (both F over the
    whole length T). ``W_p`` is an input (the truth knows the leaves) or is estimated from
    the probe probability ``P(l) = Σ_j max(λ_j − l, 0)/T = exp(−L_p(1 + l/W_p))`` of short
    probes (Leblanc et al. 2005): ``W_p = L_p / |d ln P/dl|``.
True LAI (Chen et al. 1997)
    ``L = (1 − α)·L_e·γ_E / Ω_E``, α the woody-to-total plant area ratio (wood correction),
    γ_E the needle-to-shoot area ratio (1 for broad leaves).
Nilson's clumping from the truth
    With the canopy's exact G(θ) and L: ``Ω(θ) = −ln P(θ)·cos θ / (G(θ)·L)``; the only
    definition here that can exceed 1 (regular canopies).

Zero gap fraction
-----------------
``ln 0`` is undefined. A ring or sector without gap is given a saturation floor, as the
literature does: ``'pixel'`` one pixel's worth (``1/n_pixels``, needs the pixel counts);
``'pai_sat'`` the gap fraction of a saturating plant area index ``PAI_sat`` (CAN-EYE:
``exp(−0.5·PAI_sat / cos θ)``, default ``PAI_sat = 10``, close to hemispheR's fixed
``4.53e-5 ≈ e^−10``); ``'raise'`` refuses. :func:`floor_gap_fraction` applies it and
counts the floored cells.

References: Miller J.B. 1967, Aust. J. Bot. 15:141–144. Lang A.R.G., Xiang Y. 1986, Agric.
For. Meteorol. 37:229–243. Chen J.M., Cihlar J. 1995, Appl. Opt. 34:6211–6222. Leblanc S.G.
et al. 2005, Agric. For. Meteorol. 129:187–207. Chen J.M. et al. 1997, J. Geophys. Res.
102(D24):29429–29443. Nilson T. 1971, Agric. Meteorol. 8:25–38. CAN-EYE user manual (INRAE,
"Clumping index" FAQ). Chianucci F., Macek M. 2023 (hemispheR).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

__all__ = [
    "ZERO_GAP_RULES", "PAI_SAT", "HINGE_ZENITH_DEG", "ring_centres_deg", "ring_weights",
    "floor_gap_fraction", "ring_gap_fraction", "miller_lai", "hinge_lai", "LangXiang",
    "lang_xiang", "gap_lengths", "accumulated_gap_fraction", "random_gap_fraction",
    "probe_probability", "ChenCihlar", "chen_cihlar", "REMOVAL_RULES",
    "projected_element_width", "table_methods", "true_lai", "nilson_clumping",
]

ZERO_GAP_RULES = ("pixel", "pai_sat", "raise")
PAI_SAT = 10.0          # CAN-EYE's default saturating plant area index
HINGE_ZENITH_DEG = 57.5  # where G(θ) ≈ 0.5 for every leaf angle distribution
_G_HINGE = 0.5


# ------------------------------------------------------------------------- inputs
def _bounds(zenith_bounds_deg) -> np.ndarray:
    b = np.asarray(zenith_bounds_deg, float)
    if b.ndim != 2 or b.shape[1] != 2 or len(b) == 0:
        raise ConfigError("zenith ring bounds must be a list of (low, high) pairs in degrees",
                          key="zenith_bounds_deg", value=zenith_bounds_deg)
    if not np.isfinite(b).all() or (b[:, 0] < 0).any() or (b[:, 1] >= 90).any() \
            or (b[:, 1] <= b[:, 0]).any():
        raise ConfigError("every ring needs 0 ≤ low < high < 90 degrees", key="zenith_bounds_deg",
                          value=b.tolist())
    return b


def _gaps(gap_fraction, n_rings: int, key: str = "gap_fraction") -> np.ndarray:
    p = np.asarray(gap_fraction, float)
    if p.ndim == 1:
        p = p[:, None]
    if p.ndim != 2 or p.shape[0] != n_rings:
        raise ConfigError(f"must have shape (n_rings={n_rings},) or (n_rings, n_sectors)",
                          key=key, value=np.shape(gap_fraction))
    finite = p[np.isfinite(p)]
    if ((finite < 0) | (finite > 1)).any():
        raise ConfigError("gap fractions must lie in [0, 1]", key=key,
                          value=float(finite[(finite < 0) | (finite > 1)][0]))
    return p


def ring_centres_deg(zenith_bounds_deg) -> np.ndarray:
    """Mid-angle of every ring, degrees."""
    return _bounds(zenith_bounds_deg).mean(axis=1)


def ring_weights(zenith_bounds_deg, weights: str = "normalized") -> np.ndarray:
    """``∫ sin θ dθ`` over each ring (``cos θ_lo − cos θ_hi``), normalised to sum 1 by default."""
    b = np.radians(_bounds(zenith_bounds_deg))
    w = np.cos(b[:, 0]) - np.cos(b[:, 1])
    if weights == "normalized":
        return w / w.sum()
    if weights == "quadrature":
        return w
    raise ConfigError("must be 'normalized' or 'quadrature'", key="weights", value=weights)


def floor_gap_fraction(gap_fraction, zenith_deg=None, *, zero_gap: str = "pai_sat",
                       n_pixels=None, pai_sat: float = PAI_SAT) -> tuple[np.ndarray, int]:
    """Replace zero gap fractions by the saturation floor; returns ``(P, n_floored)``.

    ``zenith_deg`` (broadcast against ``gap_fraction``'s first axis) is needed for
    ``'pai_sat'``, ``n_pixels`` (same shape as the gaps, or broadcastable) for ``'pixel'``.
    NaN (a sector with no pixel) stays NaN.
    """
    p = np.array(gap_fraction, float, copy=True)
    zero = p == 0
    n = int(zero.sum())
    if not n:
        return p, 0
    if zero_gap == "raise":
        raise ConfigError("a ring or sector has no gap (ln 0); choose zero_gap 'pixel' or 'pai_sat'",
                          key="zero_gap", value=zero_gap)
    if zero_gap == "pixel":
        if n_pixels is None:
            raise ConfigError("the 'pixel' floor needs the pixel counts", key="n_pixels", value=None)
        npx = np.broadcast_to(np.asarray(n_pixels, float), p.shape)
        if (npx[zero] < 1).any():
            raise ConfigError("pixel counts must be ≥ 1 where a gap fraction is 0", key="n_pixels",
                              value=float(npx[zero].min()))
        p[zero] = 1.0 / npx[zero]
    elif zero_gap == "pai_sat":
        if zenith_deg is None:
            raise ConfigError("the 'pai_sat' floor needs each ring's zenith", key="zenith_deg",
                              value=None)
        if not (math.isfinite(pai_sat) and pai_sat > 0):
            raise ConfigError("must be > 0", key="pai_sat", value=pai_sat)
        z = np.asarray(zenith_deg, float).reshape((-1,) + (1,) * (p.ndim - 1))
        sat = np.broadcast_to(np.exp(-_G_HINGE * pai_sat / np.cos(np.radians(z))), p.shape)
        p[zero] = sat[zero]
    else:
        raise ConfigError(f"must be one of {ZERO_GAP_RULES}", key="zero_gap", value=zero_gap)
    return p, n


def ring_gap_fraction(gap_fraction, sector_weights=None) -> np.ndarray:
    """Mean gap fraction of each ring over its sectors (weighted, e.g. by pixel count).

    Sectors with NaN or zero weight are left out; a ring without any sector gives NaN.
    """
    p = np.asarray(gap_fraction, float)
    if p.ndim == 1:
        return p.copy()
    w = np.ones_like(p) if sector_weights is None else np.broadcast_to(
        np.asarray(sector_weights, float), p.shape).copy()
    w = np.where(np.isfinite(p), w, 0.0)
    tot = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tot > 0, (np.nan_to_num(p) * w).sum(axis=1) / tot, np.nan)


# ------------------------------------------------------------------------ methods
def miller_lai(zenith_bounds_deg, gap_fraction, *, weights: str = "normalized",
               sector_weights=None, zero_gap: str = "pai_sat", n_pixels=None,
               pai_sat: float = PAI_SAT) -> float:
    """Effective LAI by Miller's integral over rings (module docstring).

    ``gap_fraction`` per ring, or per ring and sector (averaged first: the gap fraction
    of the ring, hence the *effective* LAI). ``n_pixels`` per ring for the 'pixel' floor.
    """
    b = _bounds(zenith_bounds_deg)
    p = ring_gap_fraction(_gaps(gap_fraction, len(b)), sector_weights)
    centre = b.mean(axis=1)
    p, _ = floor_gap_fraction(p, centre, zero_gap=zero_gap, pai_sat=pai_sat,
                              n_pixels=None if n_pixels is None else
                              np.asarray(n_pixels, float).reshape(len(b), -1).sum(axis=1))
    ok = np.isfinite(p)
    if not ok.any():
        return float("nan")
    w = ring_weights(b[ok], "quadrature")
    if weights == "normalized":
        w = w / w.sum()
    elif weights != "quadrature":
        raise ConfigError("must be 'normalized' or 'quadrature'", key="weights", value=weights)
    k = -np.log(p[ok]) * np.cos(np.radians(centre[ok]))
    return float(2.0 * np.sum(k * w))


def hinge_lai(gap_fraction_hinge: float, *, zenith_deg: float = HINGE_ZENITH_DEG,
              G: float = _G_HINGE, zero_gap: str = "pai_sat", n_pixels=None,
              pai_sat: float = PAI_SAT) -> float:
    """Effective LAI from the gap fraction at the hinge angle: ``−ln P · cos θ / G``."""
    if not (0.0 <= zenith_deg < 90.0):
        raise ConfigError("must lie in [0, 90) degrees", key="zenith_deg", value=zenith_deg)
    if not G > 0:
        raise ConfigError("must be > 0", key="G", value=G)
    p = _gaps([gap_fraction_hinge], 1)[:, 0]
    p, _ = floor_gap_fraction(p, [zenith_deg], zero_gap=zero_gap, n_pixels=n_pixels, pai_sat=pai_sat)
    return float(-np.log(p[0]) * math.cos(math.radians(zenith_deg)) / G)


@dataclass(frozen=True)
class LangXiang:
    """Lang–Xiang logarithmic averaging over sectors.

    Attributes
    ----------
    omega : float
        ``L_e / L_LX`` over the rings (hemispheR's LX).
    omega_ring : (n_rings,) float
        ``ln(mean P) / mean(ln P)`` per ring (CAN-EYE's CF per ring, inverted).
    lai_effective : float
        Miller's L_e of the sector-averaged gap fractions.
    lai_lx : float
        Miller's integral with the log-averaged ``mean(−ln P)`` per ring.
    n_floored : int
        Sectors whose zero gap fraction was floored.
    """

    omega: float
    omega_ring: np.ndarray
    lai_effective: float
    lai_lx: float
    n_floored: int


def lang_xiang(zenith_bounds_deg, gap_fraction, *, weights: str = "normalized",
               zero_gap: str = "pai_sat", n_pixels=None, pai_sat: float = PAI_SAT) -> LangXiang:
    """Lang & Xiang (1986) clumping from per-ring, per-sector gap fractions ``(n_rings, n_sectors)``.

    Sectors are weighted equally (equal solid angle within a ring); NaN sectors are left out.
    The zero floor applies to the sectors' logarithms and to the ring means alike.
    """
    b = _bounds(zenith_bounds_deg)
    p = _gaps(gap_fraction, len(b))
    centre = b.mean(axis=1)
    pf, n_floor = floor_gap_fraction(p, centre, zero_gap=zero_gap, n_pixels=n_pixels,
                                     pai_sat=pai_sat)
    with np.errstate(invalid="ignore"):
        mean_p = np.nanmean(np.where(np.isfinite(p), p, np.nan), axis=1)
        mean_p, _ = floor_gap_fraction(mean_p, centre, zero_gap=zero_gap, pai_sat=pai_sat,
                                       n_pixels=None if n_pixels is None else np.nansum(
                                           np.broadcast_to(np.asarray(n_pixels, float), p.shape),
                                           axis=1))
        mean_ln = np.nanmean(np.log(pf), axis=1)
    ok = np.isfinite(mean_p) & np.isfinite(mean_ln)
    w = ring_weights(b[ok], "quadrature")
    w = w / w.sum() if weights == "normalized" else w
    cos_c = np.cos(np.radians(centre[ok]))
    le = float(2.0 * np.sum(-np.log(mean_p[ok]) * cos_c * w))
    llx = float(2.0 * np.sum(-mean_ln[ok] * cos_c * w))
    with np.errstate(invalid="ignore", divide="ignore"):
        ring = np.where(ok, np.log(mean_p) / mean_ln, np.nan)
    omega = le / llx if llx > 0 else float("nan")
    return LangXiang(float(omega), ring, le, llx, n_floor)


# ------------------------------------------------------------------- Chen–Cihlar
def gap_lengths(is_gap) -> np.ndarray:
    """Lengths (in samples) of the runs of True along a 1-D boolean transect."""
    g = np.asarray(is_gap, bool).ravel()
    if g.size == 0:
        return np.zeros(0, np.int64)
    d = np.diff(np.r_[0, g.astype(np.int8), 0])
    return (np.flatnonzero(d == -1) - np.flatnonzero(d == 1)).astype(np.int64)


def accumulated_gap_fraction(lengths, total_length: float, at=0.0) -> np.ndarray:
    """``F_m(λ) = Σ_{λ_j ≥ λ} λ_j / T`` for each λ in ``at``."""
    lam = np.sort(np.asarray(lengths, float))
    csum = np.r_[np.cumsum(lam[::-1])[::-1], 0.0]
    idx = np.searchsorted(lam, np.asarray(at, float), side="left")
    return csum[idx] / float(total_length)


def random_gap_fraction(at, lp: float, wp: float) -> np.ndarray:
    """Chen & Cihlar's ``F(λ)`` of a random canopy (projected LAI ``lp``, element width ``wp``)."""
    x = lp * np.asarray(at, float) / wp
    return (1.0 + x) * np.exp(-lp - x)


def probe_probability(lengths, total_length: float, probe) -> np.ndarray:
    """Share of probe positions ``P(l) = Σ_j max(λ_j − l, 0) / T`` fully inside a gap."""
    lam = np.asarray(lengths, float)
    l_ = np.asarray(probe, float)
    return np.clip(lam[None, :] - l_.reshape(-1, 1), 0.0, None).sum(axis=1).reshape(l_.shape) \
        / float(total_length)


@dataclass(frozen=True)
class ChenCihlar:
    """Result of the gap-removal method.

    Attributes: ``omega`` (Ω_CC), ``fm0`` (measured gap fraction F_m(0)), ``fmr0`` (after
    removal), ``lp`` (final projected LAI −ln F_mr(0)), ``wp`` (element width used, same
    unit as the gaps), ``n_removed`` (gaps removed), ``iterations``, ``converged`` (L_p
    settled within ``rtol``; on strongly clumped lines the removal can keep feeding itself).
    """

    omega: float
    fm0: float
    fmr0: float
    lp: float
    wp: float
    n_removed: int
    iterations: int
    converged: bool = True


REMOVAL_RULES = ("expected_count", "fraction")


def chen_cihlar(lengths, total_length: float, *, element_width=None, probe_points: int = 5,
                removal: str = "expected_count", cutoff: float | None = None,
                max_iterations: int = 50, rtol: float = 1e-4) -> ChenCihlar:
    """Chen & Cihlar (1995) clumping index from gap lengths along transects.

    Parameters
    ----------
    lengths : gap lengths λ_j (any unit: metres, pixels), pooled over the transects.
    total_length : T, the transects' total length in the same unit.
    element_width : W_p, the projected width of a foliage element, same unit; None
        estimates it from the probe probability of the ``probe_points`` shortest probes
        (1 … probe_points units; use pixel units then).
    removal, cutoff : which gaps are "too large for a random canopy" (Chen & Cihlar compare
        the distributions graphically, so this is our choice). ``'expected_count'``
        (default, cutoff 0.05): a gap λ goes when a random canopy of the current L_p, W_p
        would hold fewer than ``cutoff`` gaps ≥ λ on the whole length T,
        ``T·(L_p/W_p)·exp(−L_p(1 + λ/W_p)) < cutoff`` — a test at the transects' own length.
        ``'fraction'`` (cutoff 1e-3, as LeafAreaIndex.jl): a gap goes when ``F(λ) < cutoff``;
        on short transects of an open canopy it keeps every gap.
    """
    lam = np.asarray(lengths, float).ravel()
    t = float(total_length)
    if not (math.isfinite(t) and t > 0):
        raise ConfigError("must be > 0", key="total_length", value=total_length)
    if (lam < 0).any() or not np.isfinite(lam).all() or lam.sum() > t * (1 + 1e-9):
        raise ConfigError("gap lengths must be ≥ 0 and sum to at most the total length",
                          key="lengths", value=float(lam.sum()))
    fm0 = float(lam.sum() / t)
    if fm0 <= 0 or fm0 >= 1:
        # No gap, or no foliage: the clumping is undefined; say so rather than invent one.
        return ChenCihlar(float("nan"), fm0, fm0, float("nan"), float("nan"), 0, 0, False)
    lp = -math.log(fm0)
    if element_width is None:
        probes = np.arange(1, int(probe_points) + 1, dtype=float)
        pp = probe_probability(lam, t, probes)
        ok = pp > 0
        if ok.sum() < 2:
            raise ConfigError("too few gaps longer than the probes to estimate W_p; give element_width",
                              key="element_width", value=None)
        slope, intercept = np.polyfit(probes[ok], np.log(pp[ok]), 1)
        wp = -intercept / abs(slope) if slope < 0 else float("nan")
    else:
        wp = float(element_width)
    if not (math.isfinite(wp) and wp > 0):
        raise ConfigError("must be > 0", key="element_width", value=wp)
    if removal not in REMOVAL_RULES:
        raise ConfigError(f"must be one of {REMOVAL_RULES}", key="removal", value=removal)
    cut = (0.05 if removal == "expected_count" else 1e-3) if cutoff is None else float(cutoff)
    if not cut > 0:
        raise ConfigError("must be > 0", key="cutoff", value=cutoff)
    kept = lam
    it = 0
    done = False
    for it in range(1, int(max_iterations) + 1):
        if removal == "expected_count":
            kept = lam[t * (lp / wp) * np.exp(-lp * (1.0 + lam / wp)) >= cut]
        else:
            kept = lam[random_gap_fraction(lam, lp, wp) >= cut]
        fmr0 = float(kept.sum() / t)
        if fmr0 <= 0:
            return ChenCihlar(float("nan"), fm0, 0.0, float("inf"), wp, len(lam), it, False)
        lp_new = -math.log(fmr0)
        done = abs(lp_new - lp) <= rtol * lp_new
        lp = lp_new
        if done:
            break
    fmr0 = float(kept.sum() / t)
    omega = (math.log(fm0) / math.log(fmr0)) * (1.0 - fmr0) / (1.0 - fm0)
    return ChenCihlar(float(omega), fm0, fmr0, float(lp), float(wp), int(len(lam) - len(kept)), it,
                      bool(done))


def projected_element_width(triangles, sun_zenith_deg: float, sun_azimuth_deg: float,
                            transect_azimuth_deg: float, groups=None) -> float:
    """Mean chord ``W_p`` of leaves' sun shadows along a ground transect (same unit as the vertices).

    ``triangles`` is ``(n_leaves, k, 3, 3)`` (each leaf's k triangles), or ``(m, 3, 3)`` with
    ``groups`` (m,) naming each triangle's leaf. Every leaf is projected along the sun
    direction onto the ground; for shapes dropped at random, the mean chord a line cuts
    through them is ``Σ area / Σ breadth`` (Cauchy–Crofton), the breadth taken across the
    transect. This is the W_p the truth gives Chen–Cihlar.
    """
    v = np.asarray(triangles, float)
    if v.ndim == 4 and v.shape[-2:] == (3, 3) and groups is None:
        groups = np.repeat(np.arange(len(v)), v.shape[1])
        v = v.reshape(-1, 3, 3)
    if v.ndim != 3 or v.shape[-2:] != (3, 3) or groups is None or len(groups) != len(v):
        raise ConfigError("must be (n_leaves, k, 3, 3), or (m, 3, 3) with one group per triangle",
                          key="triangles", value=v.shape)
    if not len(v):
        return float("nan")
    th, ph = math.radians(sun_zenith_deg), math.radians(sun_azimuth_deg)
    sun = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    xy = v[..., :2] - v[..., 2:3] * (sun[:2] / sun[2])  # shadow on z = 0
    e1, e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    ta = math.radians(transect_azimuth_deg)
    across = xy @ np.array([-math.sin(ta), math.cos(ta)])          # (m, 3)
    _, g = np.unique(np.asarray(groups), return_inverse=True)
    hi = np.full(g.max() + 1, -np.inf)
    lo = np.full(g.max() + 1, np.inf)
    np.maximum.at(hi, g, across.max(axis=1))
    np.minimum.at(lo, g, across.min(axis=1))
    return float(area.sum() / (hi - lo).sum())


def table_methods(zenith_bounds_deg, gap_fraction, n_pixels=None, *, zero_gap: str = "pai_sat",
                  pai_sat: float = PAI_SAT) -> dict[str, float]:
    """Miller's L_e, Lang–Xiang's Ω and L_LX, and the 57.5° L_e of one ring × sector table.

    For a fisheye image's (or a field photo's) table: ``zenith_bounds_deg`` (R, 2), ``gap_fraction``
    (R, S) and optionally ``n_pixels`` (R, S), which weight the sectors and give the 'pixel'
    floor. The 57.5° value uses the ring that contains 57.5° (NaN when none does).
    """
    b = _bounds(zenith_bounds_deg)
    p = _gaps(gap_fraction, len(b))
    npx = None if n_pixels is None else np.broadcast_to(np.asarray(n_pixels, float), p.shape)
    floor = {"zero_gap": zero_gap, "pai_sat": pai_sat}
    pix = (lambda a: {"n_pixels": a}) if zero_gap == "pixel" else (lambda a: {})
    lx = lang_xiang(b, p, **floor, **pix(npx))
    out = {"miller": miller_lai(b, p, sector_weights=npx, **floor, **pix(npx)),
           "omega_lx": lx.omega, "lai_lx": lx.lai_lx, "hinge_57": float("nan")}
    hit = np.flatnonzero((b[:, 0] <= HINGE_ZENITH_DEG) & (HINGE_ZENITH_DEG < b[:, 1]))
    if hit.size:
        i = int(hit[0])
        pr = ring_gap_fraction(p[i:i + 1], None if npx is None else npx[i:i + 1])[0]
        out["hinge_57"] = hinge_lai(float(pr), zenith_deg=float(b[i].mean()), **floor,
                                    **pix(None if npx is None else float(npx[i].sum())))
    return out


# -------------------------------------------------------------------- true LAI
def true_lai(lai_effective: float, omega: float, *, wood_to_total: float = 0.0,
             needle_to_shoot: float = 1.0) -> float:
    """Chen et al. (1997): ``L = (1 − α)·L_e·γ_E / Ω_E``.

    ``wood_to_total`` α is the woody share of the plant area (0 ≤ α < 1);
    ``needle_to_shoot`` γ_E is 1 for broad leaves.
    """
    if not (0.0 <= wood_to_total < 1.0):
        raise ConfigError("must lie in [0, 1)", key="wood_to_total", value=wood_to_total)
    if not needle_to_shoot > 0:
        raise ConfigError("must be > 0", key="needle_to_shoot", value=needle_to_shoot)
    if not omega > 0:
        raise ConfigError("the clumping index must be > 0", key="omega", value=omega)
    return float((1.0 - wood_to_total) * lai_effective * needle_to_shoot / omega)


def nilson_clumping(zenith_deg, gap_fraction, G, lai: float) -> np.ndarray:
    """``Ω(θ) = −ln P(θ)·cos θ / (G(θ)·L)`` with the canopy's exact G and L (NaN where P = 0)."""
    z = np.radians(np.asarray(zenith_deg, float))
    p = np.asarray(gap_fraction, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -np.log(p) * np.cos(z) / (np.asarray(G, float) * float(lai))
    return np.where(p > 0, out, np.nan)
