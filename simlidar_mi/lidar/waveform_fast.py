"""Echoes of traced sub-rays, fast where a beam meets one surface: the bits of
:func:`~simlidar_mi.lidar.waveform.detect_echoes` on the energies of
:func:`subray_energy` (the law of :mod:`~simlidar_mi.lidar.sensor`).

With a narrow beam nearly every beam's sub-rays meet one surface: their returns form one
cluster of the waveform that spans a few bins (``waveform`` module docstring) and has one
peak.  :func:`detect_subray_echoes` reads the trace's float32 arrays as they come and

1. orders each beam's valid sub-rays (finite range, energy > 0) nearest first with one sort
   of int64 keys (row, range bits, column): the order of the reference's stable per-row
   argsort, as positive float32 ranges sort like their bit patterns;
2. computes energies for those sub-rays only, with the reference's operations in its order;
3. reads beams whose valid sub-rays form one cluster of one sub-ray, or of several within
   ``_NARROW_SPAN_BINS`` bins, with the reference's own single and narrow readers
   (:func:`~simlidar_mi.lidar.waveform._single_echoes`, ``_narrow_echoes``): the same terms
   summed in the same order, so the same bits;
4. hands every other beam (several clusters, a wide one, or one whose window reading fails)
   to :func:`~simlidar_mi.lidar.waveform.detect_echoes` itself, on those rows alone (the
   detector's result for a beam does not depend on the other beams of the call).

tests/test_waveform_fast.py checks the bits against the reference on random beams and on
the included scenes.
"""
from __future__ import annotations

import math

import numpy as np

from . import waveform as wf
from .sensor import SensorModel
from .waveform import Echoes, detect_echoes

#: Key layout of the sort: row | float32 range bits (31) | column.
_RANGE_BITS = 31
#: Clusters of one (span, size) read together; smaller groups take the reference's reader.
_BLOCK = 64
#: Clusters per piece of the block reader (~1 MB of pulse terms at 19 sub-rays).
_TILE = 1024


def subray_energy(model: SensorModel, range_m: np.ndarray, reflectance: np.ndarray,
                  cos_incidence: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """E_j = w_j·ρ_j·|cos i_j|·(R_ref/r_j)² (Lambertian, :mod:`~simlidar_mi.lidar.sensor`);
    0 where the sub-ray escaped."""
    with np.errstate(divide="ignore"):
        inv_r2 = np.where(np.isfinite(range_m) & (range_m > 0), 1.0 / np.square(range_m), 0.0)
    return weight * reflectance * np.abs(cos_incidence) * model.r_ref_m ** 2 * inv_r2


def reference_echoes(model: SensorModel, t, c, e, tr, cos_i, rho, weight, beam_index):
    """Echoes of (B, S) float64 sub-ray arrays by :func:`subray_energy` and
    :func:`~simlidar_mi.lidar.waveform.detect_echoes`, no noise: the scan's detector before,
    which :func:`detect_subray_echoes` reproduces bit for bit."""
    E = subray_energy(model, t, rho, cos_i, weight)
    return detect_echoes(t, E, c, e, tr, cos_i, beam_index, pulse_length_ns=model.pulse_length_ns,
                         detection_threshold=model.detection_threshold,
                         max_returns=model.max_returns, range_min_m=model.range_min_m,
                         range_max_m=model.range_max_m, echo_rule=model.echo_rule)


def _energy(weight, rho, cos_i, range_m, r_ref_m: float) -> np.ndarray:
    """E_j of :func:`subray_energy` for sub-rays with a finite
    range > 0, as float64, with its operations in its order (the same bits)."""
    r = np.asarray(range_m, np.float64)
    return (np.asarray(weight, np.float64) * np.asarray(rho, np.float64) * np.abs(np.asarray(cos_i, np.float64))
            * r_ref_m ** 2 * (1.0 / np.square(r)))


def detect_subray_echoes(model, t, cos_i, rho, cls, element_id, tree_id, weight, beam_index) -> Echoes:
    """``detect_echoes(t, subray_energy(model, ...), ...)`` of B beams of S sub-rays with the
    ``model``'s (:class:`~simlidar_mi.lidar.sensor.SensorModel`) pulse, threshold, range
    limits, returns and echo rule (module docstring).

    ``t`` (B, S) float32 ranges (inf where a sub-ray escaped), ``cos_i`` and ``rho`` (B, S)
    |cos i| and reflectance, ``cls``, ``element_id``, ``tree_id`` (or None) (B, S),
    ``weight`` (S,) sub-ray weights, ``beam_index`` (B,) flat beam indices."""
    t = np.asarray(t)
    n_rows, s = t.shape
    beam_index = np.asarray(beam_index, np.int64).reshape(-1)
    args = (t, cos_i, rho, cls, element_id, tree_id, weight, beam_index)
    col_bits = max(1, int(s - 1).bit_length())
    if t.dtype != np.float32 or n_rows >= 1 << (63 - _RANGE_BITS - col_bits):
        return _reference_rows(model, np.arange(n_rows), *args)
    with_tree = tree_id is not None
    detection_threshold, echo_rule = model.detection_threshold, model.echo_rule
    r_ref_m = model.r_ref_m
    fwhm = wf.range_fwhm_m(model.pulse_length_ns)
    sigma = fwhm * wf._SIGMA_PER_FWHM
    h = fwhm / wf.BINS_PER_FWHM
    kb = int(math.ceil(wf.KERNEL_SIGMAS * sigma / h))

    # 1-2. Candidates (E > 0 needs a finite range > 0, ρ > 0 and |cos i| > 0), nearest first.
    tf = t.ravel()
    cand = (tf > 0) & (tf < np.inf) & (np.asarray(rho).ravel() > 0) & (np.asarray(cos_i).ravel() != 0)
    pos_ = np.flatnonzero(cand)
    if len(pos_) == 0:
        return Echoes.empty(with_tree)
    key = (pos_ // s) << (_RANGE_BITS + col_bits)
    key |= tf.view(np.uint32)[pos_].astype(np.int64) << col_bits
    key |= pos_ % s
    key.sort(kind="stable")  # timsort: the keys come in row order, a few unsorted per row
    col = key & ((1 << col_bits) - 1)
    row = key >> (_RANGE_BITS + col_bits)
    flat = row * s + col
    r32 = ((key >> col_bits) & ((1 << _RANGE_BITS) - 1)).astype(np.uint32).view(np.float32)
    ej = _energy(np.asarray(weight, np.float64)[col], np.asarray(rho).ravel()[flat],
                          np.asarray(cos_i).ravel()[flat], r32, r_ref_m)
    if not (ej > 0).all():  # underflow or a negative reflectance: the reference drops them too
        keep = ej > 0
        flat, row, r32, ej = flat[keep], row[keep], r32[keep], ej[keep]
        if len(flat) == 0:
            return Echoes.empty(with_tree)
    rj = r32.astype(np.float64)

    # 3. One cluster per row where no gap splits it (the reference's criterion).
    first = np.ones(len(flat), bool)
    first[1:] = row[1:] != row[:-1]
    starts = np.flatnonzero(first)
    n_cl = len(starts)
    ends = np.r_[starts[1:], len(flat)] - 1
    crow = row[starts]
    cl = np.cumsum(first) - 1
    split = np.zeros(n_cl, bool)
    gap = np.flatnonzero(~first[1:] & (np.diff(rj) > 2 * kb * h))
    split[cl[gap]] = True
    lo = rj[starts] - (kb + 1) * h
    nb = np.floor((rj[ends] - lo) / h).astype(np.int64) + kb + 3
    offset = np.r_[0, np.cumsum(nb)[:-1]]
    p = (rj - lo[cl]) / h
    nj = np.rint(p).astype(np.int64)
    frac = p - nj
    c_energy = np.bincount(cl, weights=ej, minlength=n_cl)
    alive = (c_energy >= detection_threshold) & (c_energy > 0)
    size = ends - starts + 1
    narrow = ~split & alive & (nj[ends] - nj[starts] <= wf._NARROW_SPAN_BINS)
    single = np.flatnonzero(narrow & (size == 1))
    several = np.flatnonzero(narrow & (size > 1))
    slow = split & alive                                 # rows left to the reference (below the threshold: none)
    fwd = dict(lo=lo, offset=offset, nb=nb, crow=crow, h=h, bin_sigmas=h / sigma)
    parts = []
    if len(single):
        ok, part = wf._single_echoes(single, starts, nj, frac, ej, c_energy, **fwd)
        parts.append(part)
        slow[single[~ok]] = True
    if len(several):
        ok, part = _narrow(several, starts, ends, cl, nj, frac, ej, c_energy, **fwd)
        parts.append(part)
        slow[several[~ok]] = True
    slow |= alive & ~narrow
    fast = _assemble(parts, flat, beam_index, cls, element_id, tree_id, cos_i, echo_rule=echo_rule,
                     threshold=detection_threshold, range_min_m=model.range_min_m, range_max_m=model.range_max_m,
                     with_tree=with_tree)
    slow_rows = crow[slow]
    if len(slow_rows) == 0:
        return fast
    ref = _reference_rows(model, slow_rows, *args)
    return Echoes.concat([fast, ref]) if len(fast) else ref


def _narrow(c, starts, ends, cl, nj, frac, ej, c_energy, **fwd):
    """:func:`~simlidar_mi.lidar.waveform._narrow_echoes` of the clusters ``c`` (rows here:
    their sub-rays are consecutive), the same bits: clusters of one span (window width) and
    one size in blocks of at least ``_BLOCK`` sum their (size, window) pulse terms in sub-ray
    order with one vector add per sub-ray; the rest go to ``_narrow_echoes`` itself."""
    size = ends[c] - starts[c] + 1
    span = nj[ends[c]] - nj[starts[c]]
    key = span * (int(size.max()) + 1) + size
    order = np.argsort(key, kind="stable")
    groups, first = np.unique(key[order], return_index=True)
    bounds = np.r_[first, len(order)]
    ok = np.zeros(len(c), bool)
    parts, rest = [], []
    lo, nb, crow, h, bs = fwd["lo"], fwd["nb"], fwd["crow"], fwd["h"], fwd["bin_sigmas"]
    for g in range(len(groups)):
        sel = order[bounds[g]:bounds[g + 1]]
        if len(sel) < _BLOCK:
            rest.append(sel)
            continue
        m, T = int(size[sel[0]]), int(span[sel[0]]) + 2 * wf._NARROW_PAD + 1
        taps = np.arange(T, dtype=np.float64)
        cs = c[sel]
        bin0 = nj[starts[cs]] - wf._NARROW_PAD
        V = np.empty((len(cs), T))
        for a in range(0, len(cs), _TILE):  # cache-sized pieces: memory bandwidth is the cost
            b0 = bin0[a:a + _TILE]
            sub = (np.arange(m)[:, None] + starts[cs[a:a + _TILE]]).ravel()  # sub-ray j of every cluster, j-major
            t0 = (np.tile(b0, m) - nj[sub]).astype(np.float64)
            vals = wf._pulse(t0[:, None] + taps, frac[sub], ej[sub], bs).reshape(m, len(b0), T)
            v = V[a:a + _TILE]
            np.copyto(v, vals[0])  # W = ((0 + v0) + v1) + …, as the reference's bincount
            for j in range(1, m):
                v += vals[j]
        good, peak_r, width_m, height = wf._one_peak(V, bin0, lo[cs], h)
        good &= (bin0 >= 1) & (bin0 + T < nb[cs])
        ok[sel] = good
        sub = (starts[cs][:, None] + np.arange(m)).ravel()
        strong = starts[cs] + np.argmax(ej[sub].reshape(len(cs), m), axis=1)  # first of the most energy
        cg = cs[good]
        parts.append(wf._Part(fwd["offset"][cg], crow[cg], peak_r[good], c_energy[cg], width_m[good],
                              strong[good], height[good]))
    if rest:
        sel = np.sort(np.concatenate(rest))
        good, part = wf._narrow_echoes(c[sel], starts, ends, cl, nj, frac, ej, c_energy, **fwd)
        ok[sel] = good
        parts.append(part)
    return ok, wf._Part(*(np.concatenate(x) for x in zip(*parts)))


def _assemble(parts, flat, beam_index, cls, element_id, tree_id, cos_i, *, echo_rule, threshold,
              range_min_m, range_max_m, with_tree) -> Echoes:
    """The one echo of each fast row (kept as the reference keeps it), in beam order."""
    if not parts:
        return Echoes.empty(with_tree)
    _key, grow, g_range, g_energy, width_m, strong, g_height = (np.concatenate(c) for c in zip(*parts))
    level = g_height if echo_rule == "amplitude" else g_energy
    keep = (level >= threshold) & (g_range >= range_min_m) & (g_range <= range_max_m)
    if np.any(grow[1:] < grow[:-1]):  # one echo per row here: order by row
        o = np.argsort(grow, kind="stable")
        keep = keep[o]
        grow, g_range, g_energy, width_m, strong = (x[o] for x in (grow, g_range, g_energy, width_m, strong))
    if not keep.all():
        grow, g_range, g_energy, width_m, strong = (x[keep] for x in (grow, g_range, g_energy, width_m, strong))
    n = len(grow)
    src = flat[strong]
    take = (lambda x, dt: np.asarray(x).ravel()[src].astype(dt))
    ones = np.ones(n, np.uint8)
    return Echoes(beam_index[grow], ones, ones.copy(), g_range, g_energy.astype(np.float32),
                  (width_m * 2.0 / wf.C_M_S * 1e9).astype(np.float32), take(cls, np.uint8),
                  take(element_id, np.uint32), take(tree_id, np.uint32) if with_tree else None,
                  take(cos_i, np.float32))


def kernel_echoes(model, read: dict, t, cos_i, rho, cls, element_id, tree_id, weight, beam_index) -> Echoes:
    """Echoes of a chunk read by the Dr.Jit kernel (``read``: its per-beam host arrays,
    ``plugins/waveform_reader.py``): state 1 beams give their one echo as read there, state 2
    beams go to :func:`reference_echoes` on those rows alone (the detector's result for a beam
    does not depend on the other beams of the call)."""
    beam_index = np.asarray(beam_index, np.int64).reshape(-1)
    state = read["state"]
    one = np.flatnonzero(state == 1)
    ones = np.ones(len(one), np.uint8)
    fast = Echoes(beam_index[one], ones, ones.copy(), read["range_m"][one], read["energy"][one].astype(np.float32),
                  read["width_ns"][one], read["cls"][one].astype(np.uint8), read["element_id"][one],
                  read["tree_id"][one] if tree_id is not None else None, read["cos_incidence"][one])
    slow = np.flatnonzero(state == 2)
    if len(slow) == 0:
        return fast
    ref = _reference_rows(model, slow, t, cos_i, rho, cls, element_id, tree_id, weight, beam_index)
    return Echoes.concat([fast, ref]) if len(fast) else ref


def _reference_rows(model, rows, t, cos_i, rho, cls, element_id, tree_id, weight, beam_index) -> Echoes:
    """:func:`reference_echoes` of ``rows``."""
    return reference_echoes(model, np.asarray(t)[rows].astype(np.float64), np.asarray(cls)[rows],
                            np.asarray(element_id)[rows], None if tree_id is None else np.asarray(tree_id)[rows],
                            np.asarray(cos_i)[rows].astype(np.float64), np.asarray(rho)[rows].astype(np.float64),
                            weight, beam_index[rows])
