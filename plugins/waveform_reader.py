"""The full-waveform reader of single-surface pulses, in one Dr.Jit kernel.

:func:`read_pulses` reads each beam's S traced sub-rays (the arrays of
``RangeIntegrator.trace_subrays``, laid out beam by beam) as
:func:`simlidar_mi.lidar.waveform.detect_echoes` reads a beam whose valid sub-rays make one
narrow cluster, the case of nearly every beam of a narrow beam: energies by the Lambertian law
(:func:`simlidar_mi.lidar.waveform_fast.subray_energy`), the sub-rays sorted nearest first
(a sorting network on (range, column): the reference's stable order), the waveform W sampled
on the window the reference samples (its bins, its terms, summed in its order), its one peak,
the log-parabola vertex, the half-height walk and the echo rule.  Each beam gets a state:

* 0: no echo (no valid sub-ray, the beam's energy below the threshold, or its one echo
  dropped by the threshold or the range limits);
* 1: one echo, read here (range, energy, width, height and its strongest sub-ray's
  class, ids and incidence);
* 2: anything else (sub-rays spread over more than ``_NARROW_SPAN_BINS`` bins, so maybe
  several clusters or peaks, or a window reading that fails): the host's detector reads it.

The arithmetic is the reference's, operation by operation, in float64, with two exceptions
that change low bits only: ``exp`` and ``log`` are Dr.Jit's (not numpy's), and a sub-ray's
pulse term is stepped from bin to bin by products (two ``exp`` a sub-ray, not one a bin), so
the range, width and amplitude of an echo can differ from the numpy reader's in their last
bits (at most 1e-12 m; the energy, class, ids and incidence are exact: they use no exp).  The numpy reader stays
selectable (``[sensor] waveform_reader = "numpy"``); ``tests/test_waveform_kernel.py``
measures the difference.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

#: Sub-rays per beam the unrolled kernel takes (more: the host reads every beam).
MAX_SUBRAYS = 32
#: Reference constants (simlidar_mi.lidar.waveform): bins per FWHM, kernel half-width in σ,
#: narrow-cluster span and window pad (bins).
BINS_PER_FWHM, KERNEL_SIGMAS, NARROW_SPAN_BINS, NARROW_PAD = 8, 6.0, 9, 6
C_M_S = 299_792_458.0
_T_MAX = NARROW_SPAN_BINS + 2 * NARROW_PAD + 1


def _network(n: int) -> list[tuple[int, int]]:
    """Comparators of Batcher's odd-even merge sort for n inputs (pruned from the next power
    of two: the missing inputs act as +inf at the end)."""
    size = 1
    while size < n:
        size *= 2
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        a, b = i + j, i + j + k
                        if b < n:
                            pairs.append((a, b))
            k //= 2
        p *= 2
    return pairs


def _crossing(w0, wm, wp, wn, level, step: int):
    """``waveform._crossing_values`` in Dr.Jit (the same operations)."""
    Float64 = type(w0)
    gt = w0 > wn
    lin = dr.clip(dr.select(gt, (w0 - level) / dr.select(gt, w0 - wn, 1.0), 1.0), 0.0, 1.0)
    lm, l0, lp, lt = dr.log(wm), dr.log(w0), dr.log(wp), dr.log(level)
    b = step * (lp - lm) / 2.0
    c = (lm - 2 * l0 + lp) / 2.0
    disc = b * b - 4 * c * (l0 - lt)
    x = dr.select(c != 0, (-b - dr.sqrt(disc)) / (2 * c), (lt - l0) / b)
    good = dr.isfinite(x) & (x >= -1e-9) & (x <= 1 + 1e-9) & (c < 0)
    return dr.select(good, dr.clip(x, 0.0, 1.0), Float64(lin))


def _pick(values, index):
    """values[index] for a lane-varying index into a Python list of arrays."""
    out = values[0]
    for i in range(1, len(values)):
        out = dr.select(index == i, values[i], out)
    return out


def read_pulses(out: dict, n_sub: int, weight, *, r_ref_m: float, pulse_length_ns: float,
                detection_threshold: float, range_min_m: float, range_max_m: float,
                echo_rule: str) -> dict:
    """Per beam of the traced sub-rays ``out`` (``t``, ``cos_incidence``, ``reflectance``,
    ``class``, ``element_id``, optional ``tree_id``; ``n_sub`` a beam): ``state`` (UInt32, module
    docstring), and for state 1 ``range_m`` (Float64), ``energy`` (Float64), ``width_ns``
    (Float32), ``height`` (Float64), ``cls`` (UInt32), ``element_id``, ``tree_id`` (UInt32) and
    ``cos_incidence`` (Float32) of the echo.  One kernel, evaluated."""
    S = int(n_sub)
    if S > MAX_SUBRAYS:
        raise ValueError(f"the waveform kernel reads at most {MAX_SUBRAYS} sub-rays a beam, got {S}")
    if echo_rule not in ("amplitude", "basin"):
        raise ValueError(f"echo_rule must be 'amplitude' or 'basin', got {echo_rule!r}")
    arrays = {k: out[k] for k in ("t", "reflectance", "cos_incidence", "class", "element_id", "tree_id") if k in out}
    lane = dr.arange(mi.UInt32, dr.width(out["t"]) // S)
    settings = (S, tuple(float(w) for w in weight), float(r_ref_m), float(pulse_length_ns),
                float(detection_threshold), float(range_min_m), float(range_max_m), echo_rule)
    res = _read(arrays, lane, settings)
    dr.eval(res)
    return res


@dr.freeze
def _read(out: dict, lane, settings: tuple) -> dict:
    """The kernel of :func:`read_pulses`, frozen: traced once per settings and array types (~2,000
    operations, ~10 ms of Python a chunk otherwise), then replayed on each chunk's arrays."""
    S, weight, r_ref_m, pulse_length_ns, detection_threshold, range_min_m, range_max_m, echo_rule = settings
    Float64, Float32, UInt32, Int32 = mi.Float64, mi.Float32, mi.UInt32, mi.Int32
    fwhm = C_M_S * float(pulse_length_ns) * 1e-9 / 2.0
    sigma = fwhm * (1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0))))
    h = fwhm / BINS_PER_FWHM
    kb = int(math.ceil(KERNEL_SIGMAS * sigma / h))
    bs = h / sigma
    lead = (kb + 1) * h
    rref2 = float(r_ref_m) ** 2
    t32 = out["t"]
    base = lane * S

    # Valid sub-rays and their energies (waveform_fast._energy, the same operations).
    r, e, col = [], [], []
    for j in range(S):
        idx = base + j
        t = dr.gather(Float32, t32, idx)
        rho = dr.gather(Float32, out["reflectance"], idx)
        ci = dr.gather(Float32, out["cos_incidence"], idx)
        cand = (t > 0) & (t < dr.inf) & (rho > 0) & (ci != 0)
        r64 = Float64(t)
        ej = float(weight[j]) * Float64(rho) * dr.abs(Float64(ci)) * rref2 * (1.0 / (r64 * r64))
        ok = cand & (ej > 0)
        r.append(dr.select(ok, r64, dr.inf))
        e.append(dr.select(ok, ej, 0.0))
        col.append(UInt32(j))
    # Nearest first, ties by column (the stable order); escapes (inf) last.
    for a, b in _network(S):
        swap = (r[b] < r[a]) | ((r[b] == r[a]) & (col[b] < col[a]))
        r[a], r[b] = dr.select(swap, r[b], r[a]), dr.select(swap, r[a], r[b])
        e[a], e[b] = dr.select(swap, e[b], e[a]), dr.select(swap, e[a], e[b])
        col[a], col[b] = dr.select(swap, col[b], col[a]), dr.select(swap, col[a], col[b])
    valid = [dr.isfinite(x) for x in r]
    c_energy = Float64(0.0)
    r_max = Float64(-dr.inf)
    best, best_e = UInt32(0), Float64(-1.0)
    for m in range(S):
        c_energy = dr.select(valid[m], c_energy + e[m], c_energy)
        r_max = dr.select(valid[m], r[m], r_max)
        top = valid[m] & (e[m] > best_e)  # the first of the most energy: ties keep the nearest
        best, best_e = dr.select(top, col[m], best), dr.select(top, e[m], best_e)
    alive = (c_energy >= detection_threshold) & (c_energy > 0)  # > 0: some sub-ray is valid

    lo = r[0] - lead
    nj, frac = [], []
    for m in range(S):
        p = (r[m] - lo) / h
        k = dr.round(p)
        nj.append(Int32(dr.select(valid[m], k, 0.0)))
        frac.append(p - k)
    nj_min = nj[0]
    nj_max = Int32(dr.round((r_max - lo) / h))
    nb = Int32(dr.floor((r_max - lo) / h)) + kb + 3
    span = nj_max - nj_min
    narrow = alive & (span <= NARROW_SPAN_BINS)
    bin0 = nj_min - NARROW_PAD
    T = span + 2 * NARROW_PAD + 1

    # W on the window's bins: Σ_m E_m·exp(−(((bin0 − nj_m) + t − frac_m)·h/σ)²/2), nearest first.
    # Along the bins, g_m(t + 1) = g_m(t)·ρ_m(t) and ρ_m(t + 1) = ρ_m(t)·exp(−(h/σ)²): two exp
    # a sub-ray, not one a bin (a few ulps per step: low bits only).
    q = math.exp(-bs * bs)
    g, ratio = [], []
    for m in range(S):
        x = (Float64(bin0 - nj[m]) - frac[m]) * bs
        g.append(dr.select(valid[m], dr.exp(-0.5 * (x * x)) * e[m], 0.0))
        ratio.append(dr.select(valid[m], dr.exp(-(x * bs) - 0.5 * bs * bs), 0.0))
    V = []
    for t in range(_T_MAX):
        w = g[0]
        for m in range(1, S):
            w = w + g[m]
        V.append(w)
        if t + 1 < _T_MAX:
            g = [g[m] * ratio[m] for m in range(S)]
            ratio = [ratio[m] * q for m in range(S)]
    # One peak: slope signs with flats carrying the slope before them (waveform._one_peak).
    up = [Int32(1)]
    for t in range(1, _T_MAX):
        s = dr.select(V[t] > V[t - 1], 1, 0) - dr.select(V[t] < V[t - 1], 1, 0)
        up.append(dr.select(s != 0, Int32(s), up[t - 1]))
    count, p = Int32(0), Int32(0)
    for t in range(_T_MAX):
        inside = t < T
        last = T == t + 1
        nxt_down = up[t + 1] < 0 if t + 1 < _T_MAX else (up[t] != up[t])  # past the last bin: never
        is_max = inside & (up[t] > 0) & (last | nxt_down)
        p = dr.select(is_max & (count == 0), t, p)
        count += dr.select(is_max, 1, 0)
    ok = narrow & (count == 1) & (p >= 1) & (p <= T - 2)
    p = dr.clip(p, 1, T - 2)
    w0, wm, wp = _pick(V, p), _pick(V, p - 1), _pick(V, p + 1)
    lm, l0, lp = dr.log(wm), dr.log(w0), dr.log(wp)
    curv = lm - 2 * l0 + lp
    d = 0.5 * (lm - lp) / curv
    okv = dr.isfinite(d) & (curv < 0) & (dr.abs(d) <= 1)
    d = dr.select(okv, d, 0.0)
    height = dr.select(okv, dr.exp(l0 - 0.25 * (lm - lp) * d), w0)
    peak_r = lo + (Float64(bin0 + p) + d) * h
    half = height / 2.0
    n_left, n_right = Int32(0), Int32(0)
    for t in range(_T_MAX):
        above = (t < T) & (V[t] >= half)
        n_left += dr.select(above & (t < p), 1, 0)
        n_right += dr.select(above & (t > p), 1, 0)
    a, b = p - n_left, p + n_right
    ok &= (a >= 1) & (b <= T - 2) & (bin0 >= 1) & (bin0 + T < nb)
    a, b = dr.clip(a, 1, T - 2), dr.clip(b, 1, T - 2)
    va, vam, vap = _pick(V, a), _pick(V, a - 1), _pick(V, a + 1)
    vb, vbm, vbp = _pick(V, b), _pick(V, b - 1), _pick(V, b + 1)
    left = Float64(bin0 + a) + -1 * _crossing(va, vam, vap, vam, half, -1)
    right = Float64(bin0 + b) + 1 * _crossing(vb, vbm, vbp, vbp, half, 1)
    width_m = (right - left) * h

    level = height if echo_rule == "amplitude" else c_energy
    keep = (level >= detection_threshold) & (peak_r >= range_min_m) & (peak_r <= range_max_m)
    state = dr.select(~alive, 0, dr.select(ok, dr.select(keep, 1, 0), 2))
    src = base + best
    res = {"state": UInt32(state), "range_m": peak_r, "energy": c_energy,
           "width_ns": Float32(width_m * 2.0 / C_M_S * 1e9), "height": height,
           "cls": dr.gather(type(out["class"]), out["class"], src)}
    res["element_id"] = dr.gather(UInt32, out["element_id"], src)
    if "tree_id" in out:
        res["tree_id"] = dr.gather(UInt32, out["tree_id"], src)
    res["cos_incidence"] = dr.gather(Float32, out["cos_incidence"], src)
    return res
