"""Canopy estimators from LiDAR scans, as agricultural and forest LiDAR papers publish them.

Every estimator maps a scan (its beams, :class:`~simlidar_mi.truth.traverse.Beams`) onto a
:class:`~simlidar_mi.truth.grid.VoxelGrid` and returns arrays of ``grid.shape``, among
them ``PAD_m2_m3`` (plant area density, m²/m³; NaN where too few beams entered the voxel).

Point-based (where the returns are):

``point_count``, ``point_density_m3``
    vegetation returns per voxel and per m³.
``occupied``
    a voxel is canopy when it holds at least ``min_points`` returns: the voxel
    occupancy of Hosoi & Omasa (2006, IEEE TGRS 44(12):3610–3618,
    doi:10.1109/TGRS.2006.881743), and the voxel-grid canopy volume of orchard mobile
    LiDAR (e.g. Chakraborty et al. 2019, Comput. Electron. Agric. 158:284–293,
    doi:10.1016/j.compag.2019.02.012); ``min_points`` > 1 is the noise threshold such
    studies apply (1 by default: any return).
``vcp``
    Hosoi & Omasa's (2006) voxel-based canopy profiling: the contact frequency of a
    layer is the share of the beam-observed voxels that are occupied, and
    LAD = α(θ)·n_I/(n_I + n_P)/Δh with α(θ) = cos θ / G(θ), i.e. 1 / (G × the path
    length of a beam through the layer). Per voxel we use each voxel's own mean beam
    path (``chord_m / n_in``) in place of Δh / cos θ, so PAD = occupied / (G·l̄); its mean
    over a horizontal layer's observed voxels is the published layer LAD.

Beam-based (where the beams went, :func:`~simlidar_mi.truth.traverse.traverse`):

``beer_lambert``
    transmittance T = 1 − I/N (I beams intercepted in the voxel, N beams entering it)
    inverted by Beer–Lambert's law, PAD = −ln T / (G·l̄), with l̄ = the mean chord of the
    entering beams (Béland et al. 2011, Agric. For. Meteorol. 151:1252–1266,
    doi:10.1016/j.agrformet.2011.05.004; Béland et al. 2014, Agric. For. Meteorol.
    184:82–97, doi:10.1016/j.agrformet.2013.09.005; Grau et al. 2017, Remote Sens.
    Environ. 191:373–388, doi:10.1016/j.rse.2017.01.032).
``contact_mle``
    the maximum-likelihood attenuation of Pimont et al. (2018, Remote Sens. Environ.
    215:343–370, doi:10.1016/j.rse.2018.06.024): PAD = I / (G·Σ l_i) with l_i the free
    path each entering beam actually travelled in the voxel (truncated at its return).
    It needs no saturation rule and no equal-path assumption. (Their further small-N
    bias correction is not applied; tests/test_estimators.py measures the bias left.)

G is the mean projection of unit leaf area along the beams, 0.5 for a spherical leaf-angle
distribution (Ross 1981). Every estimator takes ``G`` as a number or as an array of
``grid.shape`` (per voxel); each estimate is proportional to 1/G, so an estimate with another
G is the same estimate times G_old/G_new (:func:`with_G`). ``evaluate`` runs them with the
constant G and again with the truth's own G per voxel (:mod:`simlidar_mi.truth.leaf_g`; the
``*_Gcanopy`` and ``*_Gvoxel`` oracle runs), which separates the error of G from the rest (clumping, finite
leaves, sampling). G estimated from the points is not offered.

Voxels fewer than ``min_beams`` (default 5, :data:`MIN_BEAMS`) beams entered are NaN for the
beam-based estimators: Pimont et al. (2018) find the MLE consistent from about 5 beams, and
below that one grazing beam intercepted after a millimetre of path reads hundreds of m²/m³.

Saturated voxels (I = N, T = 0) have no finite Beer–Lambert estimate. ``saturated =
"cap"`` (default) sets T = 1/(N + 1), as if one more beam had passed: the estimate is
then ln(N + 1)/(G·l̄), a lower bound that grows with N; ``"nan"`` leaves them NaN
(an abstention, scored as 0 by evaluate). Unobserved voxels (N = 0) are NaN for every beam-based
estimator.

Multi-return (``*_multi``; scans with a ``[sensor]``): each echo intercepts a share of
its beam, ``weights = "equal"`` (1/n per echo) or ``"energy"`` (the share of the beam's
cross-section the echo intercepted, from its energy); the beam's remaining weight enters
the next voxels and N, I and the paths are weighted sums (traverse.py).

``"energy"``: an echo's energy is E_j ∝ a_j·ρ_j·|cos i_j|/r_j² (the Lambertian law of
lidar/sensor.py), a_j the intercepted share, so the share is recovered as

    a_j ∝ E_j·r_j² / (ρ_j·|cos i_j|),   normalised over the beam's echoes,

ρ_j the reflectance of the echo's class ([materials]) and cos i_j its incidence (both
known in a simulator; |cos i| is floored at 0.01 so a grazing echo cannot take the whole
beam). This is the reflectance-corrected return-energy ratio of the multi-return
gap-fraction literature (Armston et al. 2013, "Direct retrieval of canopy gap probability
using airborne waveform lidar", Remote Sens. Environ. 134:24–38,
doi:10.1016/j.rse.2013.02.021: P_gap = 1 − R_v/(R_v + (ρ_v/ρ_g)·R_g); Hopkinson & Chasmer
2009, "Testing LiDAR models of fractional cover across multiple forest ecozones", Remote
Sens. Environ. 113:275–288, the intensity-based cover), with the 1/r² and cos i terms they
drop for near-nadir airborne beams restored, since ranges here differ along a beam.
Closure: normalising over the echoes assumes the beam's whole energy came back in its
echoes (the last echo stops the rest, as the ground does in Armston et al.); what escaped
or fell below the threshold is not represented, so a beam ends at its last echo (its
weights sum to 1) under both weightings. The uncorrected E/ΣE share (``"raw-energy"``)
overweights near, bright echoes (a leaf at 1.5 m intercepting half a beam in front of
ground at 3 m gets 0.95 instead of 0.5) and is kept only to measure that.
These are our documented conventions; BENCHMARKS.md §10d measures how far they move the
result from the first-return ones.
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import ConfigError
from .grid import VoxelGrid
from .traverse import BeamCounts, Beams, traverse

__all__ = ["beams_from_scan", "beams_from_exr", "point_occupancy", "beer_lambert_pad",
           "contact_mle_pad", "vcp_pad", "estimate_all", "with_G", "G_SPHERICAL", "BUILTIN", "MIN_BEAMS",
           "ORACLE_G", "ORACLE_SUFFIX"]

G_SPHERICAL = 0.5
#: Built-in estimators: name → (description, needs echoes).
BUILTIN = {
    "vcp": "occupancy (≥ min_points returns) / (G·mean path): voxel canopy profiling, Hosoi & Omasa 2006",
    "beer_lambert": "−ln(1 − I/N)/(G·mean chord), first returns: Béland et al. 2011/2014, Grau et al. 2017",
    "contact_mle": "I/(G·Σ free path), first returns: maximum likelihood, Pimont et al. 2018",
    "beer_lambert_multi": "Beer–Lambert with every echo (weighted beams)",
    "contact_mle_multi": "maximum likelihood with every echo (weighted beams)",
}
#: The oracle runs of ``evaluate``: these estimators with the truth's own G per voxel.
ORACLE_G = ("beer_lambert", "contact_mle", "beer_lambert_multi", "contact_mle_multi")
ORACLE_SUFFIX = {"_Gcanopy": "the truth's plant G of the canopy (oracle; G_plant_canopy in truth.nc)",
                 "_Gvoxel": "the truth's plant G per voxel (oracle; G_plant in truth.nc)"}
BUILTIN.update({f"{k}{suffix}": f"{k} with {what}" for suffix, what in ORACLE_SUFFIX.items() for k in ORACLE_G})

#: Units and long names of the arrays an estimate holds besides ``PAD_m2_m3`` (its NetCDF file).
ESTIMATE_VARIABLES = {
    "PAD_m2_m3": ("m2 m-3", "estimated plant area density"),
    "n_in": ("1", "beams entering the voxel (weighted for multi-return beams)"),
    "hits": ("1", "beams intercepted in the voxel (weighted for multi-return beams)"),
    "path_m": ("m", "free path travelled in the voxel, summed over the beams"),
    "mean_chord_m": ("m", "mean chord of the beams entering the voxel"),
    "point_count": ("1", "vegetation returns in the voxel (weighted for multi-return beams)"),
    "point_density_m3": ("m-3", "vegetation returns per voxel volume"),
    "occupied": ("1", "1 where the voxel holds at least min_points returns, else 0"),
    "G": ("1", "G used per voxel (the oracle runs: the truth's plant G)"),
}


def _veg(c) -> np.ndarray:
    return (c == 2) | (c == 3)


def beams_from_scan(results, weights: str | None = None) -> Beams:
    """The beams of one or several :class:`~simlidar_mi.lidar.scan.ScanResult` (legs).

    Directions and origins come from the pattern as the scan traced them
    (``BeamPattern.beam_origins_m``/``world_dirs``, as ``ScanResult.points_m``).
    ``weights`` None: first returns; ``"equal"`` / ``"energy"`` / ``"raw-energy"``: every
    echo (module docstring), which needs ``result.echoes``."""
    results = results if isinstance(results, (list, tuple)) else [results]
    parts = []
    for res in results:
        p = res.pattern
        n, m = res.shape
        o = np.broadcast_to(p.beam_origins_m(), (n, m, 3)).reshape(-1, 3)
        d = np.asarray(p.world_dirs(), np.float64).reshape(-1, 3)
        if weights is None:
            parts.append(Beams.first_return(o, d, res.range_m, res.cls))
            continue
        if res.echoes is None:
            raise ConfigError("multi-return estimators need a scan with echoes (a [sensor] section with "
                              "energy detection)", key="weights", value=weights)
        e = res.echoes
        parts.append(_echo_beams(o, d, n * m, e.beam, e.return_number, e.range_m, e.cls,
                                 e.energy, p.escape_m, weights, e.cos_incidence,
                                 _class_reflectance(res.sensor)))
    if len(parts) == 1:
        return parts[0]
    k = max(b.ret_range_m.shape[1] for b in parts)

    def pad(a, fill):
        return np.concatenate([np.pad(x, ((0, 0), (0, k - x.shape[1])), constant_values=fill) for x in a])
    return Beams(np.concatenate([b.origin_m for b in parts]), np.concatenate([b.dir for b in parts]),
                 np.concatenate([b.t_end_m for b in parts]), pad([b.ret_range_m for b in parts], np.inf),
                 pad([b.ret_weight for b in parts], 0.0), pad([b.ret_veg for b in parts], False))


#: Echo weightings of the multi-return estimators (module docstring).
ECHO_WEIGHTS = ("equal", "energy", "raw-energy")
#: |cos i| floor of the energy share: a grazing echo's E/cos i stays bounded.
_COS_FLOOR = 0.01


def _class_reflectance(sensor: dict | None) -> np.ndarray:
    """ρ per class code (escape, ground, wood, leaf) from a resolved sensor dict (a scan's
    ``result.sensor`` or an EXR's ``simlidar_sensor`` header); [materials] defaults if absent."""
    from ..lidar.sensor import SensorModel  # noqa: PLC0415
    sensor = sensor or {}
    d = SensorModel()
    return np.array([0.0, sensor.get("reflectance_ground", d.reflectance_ground),
                     sensor.get("reflectance_wood", d.reflectance_wood),
                     sensor.get("reflectance_leaf", d.reflectance_leaf)], np.float64)


def echo_shares(energy, range_m, cos_incidence, reflectance) -> np.ndarray:
    """Unnormalised intercepted share E·r²/(ρ·max(|cos i|, 0.01)) of each echo (module
    docstring); 0 where ρ is 0 (no material to correct for)."""
    e = np.asarray(energy, np.float64)
    r = np.asarray(range_m, np.float64)
    rho = np.asarray(reflectance, np.float64)
    cos = np.maximum(np.abs(np.asarray(cos_incidence, np.float64)), _COS_FLOOR)
    return np.divide(e * r * r, rho * cos, out=np.zeros_like(e), where=rho > 0)


def _echo_beams(o, d, n_beams, beam, ret_no, range_m, cls_code, energy, escape_m, weights,
                cos_incidence=None, reflectance=None) -> Beams:
    """Weighted beams from echo lists (sorted by beam, then return number).
    ``cos_incidence`` (per echo) and ``reflectance`` (per class code) for ``"energy"``."""
    if weights not in ECHO_WEIGHTS:
        raise ConfigError(f"echo weights must be one of {', '.join(ECHO_WEIGHTS)}", key="weights",
                          value=weights)
    beam = np.asarray(beam, np.int64)
    cls_code = np.asarray(cls_code)
    k = int(np.max(ret_no)) if len(beam) else 1
    R = np.full((n_beams, k), np.inf)
    W = np.zeros((n_beams, k))
    V = np.zeros((n_beams, k), bool)
    j = np.asarray(ret_no, np.int64) - 1
    R[beam, j] = range_m
    V[beam, j] = _veg(cls_code)
    if weights == "equal":
        W[beam, j] = 1.0
    elif weights == "raw-energy":
        W[beam, j] = np.asarray(energy, np.float64)
    else:
        rho = np.asarray(reflectance, np.float64)[cls_code.astype(np.int64)]
        W[beam, j] = echo_shares(energy, range_m, cos_incidence, rho)
    tot = W.sum(axis=1, keepdims=True)
    W = np.divide(W, tot, out=np.zeros_like(W), where=tot > 0)
    # A beam ends at its last echo (its weights sum to 1); a beam without echoes escapes.
    t_end = np.where(np.isfinite(R).any(axis=1), np.max(np.where(np.isfinite(R), R, -np.inf), axis=1), escape_m)
    return Beams(o, d, t_end, R, W, V)


def beams_from_exr(path, pattern=None, weights: str | None = None) -> Beams:
    """The beams of a scan EXR (``simlidar-mi scan``'s scan.exr, or a user's file in its
    layout, simlidar_mi/io/exr.py). The tractor's rays follow from its header settings;
    other platforms' EXRs do not hold every ray, so pass their ``pattern``
    (:func:`simlidar_mi.lidar.survey.scan_patterns` of the scene). ``weights`` as in
    :func:`beams_from_scan`, from the ``echo{r}.*`` layers, except ``"energy"`` (the EXR
    holds no per-echo incidence; ``"raw-energy"`` reads the intensity layers)."""
    from ..lidar.scan import read_scan_exr  # noqa: PLC0415
    channels, header = read_scan_exr(path)
    for name in ("range", "class"):
        if name not in channels:
            raise ConfigError(f"not a scan EXR: no '{name}' channel", file=str(path), key=name)
    if pattern is None:
        if "settings" not in header:
            raise ConfigError("this scan is not a tractor scan, whose beams the header describes; pass "
                              "the scan's beam pattern (the scene file) to rebuild its rays",
                              file=str(path), key="simlidar_settings")
        pattern = header["settings"].pattern()
    if not hasattr(pattern, "n_rows"):  # the tractor's ScanSettings (what scan_patterns gives)
        pattern = pattern.pattern()
    n, m = channels["range"].shape
    if (pattern.n_rows, pattern.n_cols) != (n, m):
        raise ConfigError(f"the EXR holds {n}×{m} beams, the pattern {pattern.n_rows}×{pattern.n_cols}",
                          file=str(path), key="range", value=f"{n}x{m}")
    o = np.broadcast_to(pattern.beam_origins_m(), (n, m, 3)).reshape(-1, 3)
    d = np.asarray(pattern.world_dirs(), np.float64).reshape(-1, 3)
    if weights is None:
        return Beams.first_return(o, d, channels["range"], channels["class"])
    if "n_returns" not in channels:
        raise ConfigError("multi-return estimators need an EXR with echo layers (n_returns)",
                          file=str(path), key="n_returns")
    if weights == "energy":  # the share needs each echo's cos i, which scan.exr does not hold
        raise ConfigError("energy weights need each echo's incidence, which a scan EXR does not hold; "
                          "use the scan result (beams_from_scan), or 'raw-energy' / 'equal'",
                          file=str(path), key="weights", value=weights)
    nret = channels["n_returns"].ravel().astype(np.int64)
    beam, ret, rng, cls_, en = [], [], [], [], []
    for r in range(1, int(nret.max(initial=0)) + 1):
        pre = "" if r == 1 else f"echo{r}."
        have = np.nonzero(nret >= r)[0]
        if weights == "raw-energy" and f"{pre}intensity" not in channels:
            raise ConfigError("energy weights need the intensity layers (sensor intensity = true)",
                              file=str(path), key=f"{pre}intensity")
        beam.append(have)
        ret.append(np.full(len(have), r))
        rng.append(channels[f"{pre}range"].ravel()[have].astype(np.float64))
        cls_.append(channels[f"{pre}class"].ravel()[have])
        en.append(channels[f"{pre}intensity"].ravel()[have] if weights == "raw-energy" else np.ones(len(have)))
    cat = np.concatenate
    return _echo_beams(o, d, n * m, cat(beam), cat(ret), cat(rng), cat(cls_), cat(en),
                       pattern.escape_m, weights)


def point_occupancy(grid: VoxelGrid, beams: Beams, min_points: int = 1) -> dict[str, np.ndarray]:
    """``point_count`` (vegetation returns per voxel, weighted for multi-return beams, else
    whole points), ``point_density_m3`` and ``occupied`` (count ≥ ``min_points``)."""
    if int(min_points) < 1:
        raise ConfigError("must be a whole number ≥ 1", key="min_points", value=min_points)
    pts, _ = beams.vegetation_points_m()
    ijk, inside = grid.index(pts)
    flat = np.ravel_multi_index(tuple(ijk[inside].T), grid.shape)
    count = np.bincount(flat, minlength=int(np.prod(grid.shape))).reshape(grid.shape).astype(np.float64)
    return {"point_count": count, "point_density_m3": count / grid.voxel_volume_m3,
            "occupied": (count >= int(min_points)).astype(np.uint8)}


#: Fewest (weighted) beams entering a voxel for a beam-based estimate; fewer → NaN. Pimont et
#: al. (2018) find their MLE consistent from about 5 beams; below that a single grazing beam
#: intercepted after a millimetre of path gives PAD in the hundreds.
MIN_BEAMS = 5


def _observed(counts: BeamCounts, min_beams: float = MIN_BEAMS) -> np.ndarray:
    if not min_beams > 0:
        raise ConfigError("must be a number of beams > 0", key="min_beams", value=min_beams)
    return counts.n_in >= min_beams


def beer_lambert_pad(counts: BeamCounts, G=G_SPHERICAL, saturated: str = "cap",
                     min_beams: float = MIN_BEAMS) -> np.ndarray:
    """PAD = −ln(1 − I/N)/(G·l̄), l̄ = chord_m / N (module docstring; NaN where N < min_beams)."""
    if saturated not in ("cap", "nan"):
        raise ConfigError("saturated must be 'cap' or 'nan'", key="saturated", value=saturated)
    obs = _observed(counts, min_beams)
    N = np.where(obs, counts.n_in, 1.0)
    rdi = np.clip(counts.hits / N, 0.0, 1.0)
    sat = obs & (rdi >= 1.0 - 1e-12)
    T = np.where(sat, 1.0 / (N + 1.0) if saturated == "cap" else np.nan, 1.0 - rdi)
    mean_chord = counts.chord_m / N
    with np.errstate(divide="ignore", invalid="ignore"):
        pad = -np.log(T) / (G * mean_chord)
    pad = np.where(counts.hits == 0, 0.0, pad)  # a clear voxel: 0 even when its chords are ~0
    return np.where(obs & np.isfinite(pad), pad, np.nan)


def contact_mle_pad(counts: BeamCounts, G=G_SPHERICAL, min_beams: float = MIN_BEAMS) -> np.ndarray:
    """PAD = I/(G·Σ free path) (Pimont et al. 2018 maximum likelihood; NaN where N < min_beams)."""
    obs = _observed(counts, min_beams)
    with np.errstate(divide="ignore", invalid="ignore"):
        pad = counts.hits / (G * counts.path_m)
    pad = np.where(counts.hits == 0, 0.0, pad)
    return np.where(obs & np.isfinite(pad), pad, np.nan)


def vcp_pad(counts: BeamCounts, occupied: np.ndarray, G=G_SPHERICAL,
            min_beams: float = MIN_BEAMS) -> np.ndarray:
    """Voxel canopy profiling per voxel: occupied / (G·l̄) over observed voxels (module
    docstring). A voxel is observed when it holds points or ``min_beams`` beams entered it;
    with fewer beams than that, l̄ is the voxel side (a few grazing chords say nothing)."""
    enough = _observed(counts, min_beams)
    obs = enough | (occupied > 0)
    N = np.where(enough, counts.n_in, 1.0)
    mean_chord = np.where(enough, counts.chord_m / N, 0.0)
    mean_chord = np.where(mean_chord > 0, mean_chord, counts.grid.voxel_m)
    pad = np.where(occupied > 0, 1.0 / (G * mean_chord), 0.0)
    return np.where(obs, pad, np.nan)


def with_G(pad: np.ndarray, G_used, G_new) -> np.ndarray:
    """The same estimate under another G (numbers or arrays of the grid): pad·G_used/G_new."""
    return np.asarray(pad, np.float64) * (np.asarray(G_used, np.float64) / np.asarray(G_new, np.float64))


def estimate_all(grid: VoxelGrid, first: Beams, multi: Beams | None = None, *, G=G_SPHERICAL,
                 min_points: int = 1, saturated: str = "cap", min_beams: float = MIN_BEAMS,
                 chunk_beams: int | None = None, progress=None,
                 on_first_segment=None) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, float]]:
    """Every built-in estimator of the scan (:data:`BUILTIN` but the oracle runs): (name →
    arrays on ``grid`` (``PAD_m2_m3`` and the counts behind it), name → seconds including its
    traversal). ``multi``: the weighted every-echo beams, if the scan has echoes. ``G``: a
    number or an array of ``grid.shape``. ``on_first_segment``: passed to the first-return
    traversal (:func:`~simlidar_mi.truth.traverse.traverse`'s ``on_segment``)."""
    kw = {"chunk_beams": chunk_beams} if chunk_beams else {}
    t0 = time.perf_counter()
    c1 = traverse(grid, first, progress=progress, on_segment=on_first_segment, **kw)
    walk_s = time.perf_counter() - t0
    out, sec = {}, {}

    def timed(name, fn):
        t = time.perf_counter()
        out[name] = fn()
        sec[name] = walk_s + time.perf_counter() - t

    base = {"n_in": c1.n_in, "hits": c1.hits}
    timed("vcp", lambda: (lambda occ: {"PAD_m2_m3": vcp_pad(c1, occ["occupied"], G, min_beams), **occ,
                                       "n_in": c1.n_in})(point_occupancy(grid, first, min_points)))
    timed("beer_lambert", lambda: {"PAD_m2_m3": beer_lambert_pad(c1, G, saturated, min_beams), **base,
                                   "mean_chord_m": _mean(c1.chord_m, c1.n_in)})
    timed("contact_mle", lambda: {"PAD_m2_m3": contact_mle_pad(c1, G, min_beams), **base, "path_m": c1.path_m})
    if multi is not None:
        t0 = time.perf_counter()
        cm = traverse(grid, multi, progress=progress, **kw)
        walk_s = time.perf_counter() - t0
        bm = {"n_in": cm.n_in, "hits": cm.hits}
        timed("beer_lambert_multi", lambda: {"PAD_m2_m3": beer_lambert_pad(cm, G, saturated, min_beams), **bm,
                                             "mean_chord_m": _mean(cm.chord_m, cm.n_in)})
        timed("contact_mle_multi", lambda: {"PAD_m2_m3": contact_mle_pad(cm, G, min_beams), **bm, "path_m": cm.path_m})
    return out, sec


def _mean(total: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.divide(total, n, out=np.full(n.shape, np.nan), where=n > 0)
