"""Full-waveform echo detection: sub-ray returns of each beam → discrete echoes.

A beam is S sub-rays (divergence × dot matrix, see ``sensor.py``); sub-ray j returns at
range r_j with energy E_j (Lambertian law in ``sensor.py``; 0 for an escape).  The
receiver sees the waveform

    W(r) = Σ_j E_j · exp(−(r − r_j)² / 2σ²),   FWHM = 2·sqrt(2 ln 2)·σ = c·τ/2,

the emitted pulse (Gaussian, duration τ = ``pulse_length_ns`` at half maximum, c =
299 792 458 m/s) mapped to range.  W is sampled on bins of FWHM/8 and read like a
digitiser does:

1. **peaks** are the local maxima of W; a peak's energy is Σ E_j over the sub-rays whose
   nearest bin lies in its basin (between the minima either side);
2. its **range** and **amplitude** are the vertex of the parabola through ln W at the three
   bins around it (exact for one Gaussian: r and E of one target at one range);
3. its **width** (ns) is the full width of W at half the peak height, walked outward and
   interpolated the same way (τ for one target at one range);
4. an echo's class, ids and cos incidence are those of its strongest sub-ray;
5. peaks become echoes by ``echo_rule``.  ``"amplitude"`` (default; a receiver's
   discriminator): a peak whose amplitude reaches ``detection_threshold`` triggers an echo,
   later peaks within c·τ/2 of the trigger (dead time) join it with their basin energies,
   and the echo keeps the trigger's range, width and amplitude, so merging never moves a
   return past its group's first surface; sub-threshold peaks report nothing.  HELIOS++'s
   ``FullWaveformPulseRunnable::digestFullWaveform`` also takes local maxima above a minimum
   energy (it keeps the higher of two peaks within ±``winSize_ns``, we keep the first).
   ``"basin"`` (former rule): peaks closer than c·τ/2 merge by single linkage, the highest
   gives range and width, and an echo stays if its integrated energy reaches the threshold:
   grazing, range-smeared echoes pass more easily, and a chain can move a return past its
   first surface (10.00, 10.42, 10.84 m → one echo near 10.8 m, tests/test_waveform.py);
6. echoes outside [range_min_m, range_max_m] are dropped; the nearest ``max_returns`` are
   kept and numbered 1..n.  A cluster with energy below the threshold gives no echo (W ≤ Σ E_j).

Each sub-ray's pulse is evaluated exactly on the bins within ±6σ of it (the tail beyond is
below 1.5e-8 of its peak); sub-rays of one beam more than that apart form independent
clusters, laid end to end in one flat array, so ``np.bincount`` over chunks of sub-rays
builds every waveform at once (no loop over beams).

Most clusters skip the whole waveform, with the same bits: one of a single sub-ray is read
on its 11 bins, one spanning ≤ 9 bins on a window 6 bins wider each side when W has one peak
there (:func:`_one_peak`); the rest take :func:`_general_echoes`.  Every path sums a cluster's
pulse terms in the same order and reads widths at cluster-local bins, so the result depends
neither on the path nor on the other beams in the call (a scan's chunk: issue #8).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, fields

import numpy as np

from ..geometry import CLASS_CODES

C_M_S = 299_792_458.0
#: Bins per range FWHM of the pulse.
BINS_PER_FWHM = 8
#: The pulse kernel is evaluated out to this many σ either side of a sub-ray's range.
KERNEL_SIGMAS = 6.0
from ..geometry import NO_ID  # noqa: E402  (one definition: uint32 "none")
_SIGMA_PER_FWHM = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
#: Pieces of about this many sub-rays keep the kernel temporaries in cache.
_TILE_SUBRAYS = 1 << 12
#: One-sub-ray clusters: W on the 11 bins around the sub-ray (peak ± 5).
_SINGLE_TAPS = 11
#: Narrow clusters (sub-rays within 9 bins): W from 6 bins before the first to 6 after the last.
_NARROW_SPAN_BINS, _NARROW_PAD = 9, 6
_Part = namedtuple("_Part", "key row range energy width_m strongest height")
#: Echo rules of :func:`detect_echoes` (module docstring, item 5).
ECHO_RULES = ("amplitude", "basin")


def range_fwhm_m(pulse_length_ns: float) -> float:
    """Range FWHM c·τ/2 (m) of a pulse of FWHM duration τ (ns): the merge distance."""
    return C_M_S * float(pulse_length_ns) * 1e-9 / 2.0


@dataclass
class Echoes:
    """Discrete echoes of a set of beams; every array has one entry per echo.

    Sorted by ``beam`` (flat index row·M + col within one pattern), then by
    ``return_number`` (1-based, nearest first); ``number_of_returns`` is the beam's echo
    count after every drop.  ``energy`` is the echo energy E (the intensity, law in
    ``sensor.py``); ``width_ns`` the waveform's FWHM around the echo's peak.
    """

    beam: np.ndarray               # int64
    return_number: np.ndarray      # uint8
    number_of_returns: np.ndarray  # uint8
    range_m: np.ndarray            # float64
    energy: np.ndarray             # float32
    width_ns: np.ndarray           # float32
    cls: np.ndarray                # uint8
    element_id: np.ndarray         # uint32
    tree_id: np.ndarray | None     # uint32
    cos_incidence: np.ndarray      # float32

    def __len__(self) -> int:
        return len(self.beam)

    @classmethod
    def empty(cls, with_tree: bool = False) -> Echoes:
        return cls(np.zeros(0, np.int64), np.zeros(0, np.uint8), np.zeros(0, np.uint8),
                   np.zeros(0, np.float64), np.zeros(0, np.float32), np.zeros(0, np.float32),
                   np.zeros(0, np.uint8), np.zeros(0, np.uint32),
                   np.zeros(0, np.uint32) if with_tree else None, np.zeros(0, np.float32))

    @classmethod
    def concat(cls, parts) -> Echoes:
        """One Echoes from chunks of the same pattern (disjoint beams), re-sorted by
        (beam, return_number).  A tree id missing from some chunks becomes 0xFFFFFFFF."""
        parts = list(parts)
        with_tree = any(p.tree_id is not None for p in parts)
        if not parts:
            return cls.empty()
        cols = {}
        for f in fields(cls):
            if f.name == "tree_id":
                cols[f.name] = (np.concatenate([p.tree_id if p.tree_id is not None
                                                else np.full(len(p), NO_ID, np.uint32) for p in parts])
                                if with_tree else None)
            else:
                cols[f.name] = np.concatenate([getattr(p, f.name) for p in parts])
        order = np.lexsort((cols["return_number"], cols["beam"]))
        if np.any(np.diff(order) != 1):
            cols = {k: (v[order] if v is not None else None) for k, v in cols.items()}
        return cls(**cols)

    def take(self, index) -> Echoes:
        """The echoes at ``index`` (a boolean mask or integer indices), fields unchanged."""
        return Echoes(**{f.name: (getattr(self, f.name)[index] if getattr(self, f.name) is not None
                                  else None) for f in fields(self)})

    def returns_per_beam(self, n_beams: int) -> np.ndarray:
        """uint8 (n_beams,): echoes of each flat beam index."""
        return np.bincount(self.beam, minlength=n_beams).astype(np.uint8)

    def layer(self, shape: tuple[int, int], return_number: int = 1, *,
              escape_m: float = 1000.0) -> dict[str, np.ndarray]:
        """Per-beam arrays of echo ``return_number`` over an N × M ``shape``.

        Keys: ``range_m`` float32 (``escape_m`` where the beam has no such echo), ``cls``
        uint8 (0 = escape), ``element_id`` uint32 (0xFFFFFFFF), ``tree_id`` uint32 or None,
        ``intensity`` float32 (0), ``width_ns`` float32 (0), ``cos_incidence`` float32 (0).
        """
        n, m = shape
        sel = self.return_number == return_number
        beam = self.beam[sel]
        if len(beam) and (beam.min() < 0 or beam.max() >= n * m):
            raise ValueError(f"echo beam indices {beam.min()}…{beam.max()} outside a {n}×{m} pattern")

        def fill(values, default, dtype):
            out = np.full(n * m, default, dtype)
            out[beam] = values[sel]
            return out.reshape(n, m)

        return {"range_m": fill(self.range_m, escape_m, np.float32),
                "cls": fill(self.cls, CLASS_CODES["escape"], np.uint8),
                "element_id": fill(self.element_id, NO_ID, np.uint32),
                "tree_id": fill(self.tree_id, NO_ID, np.uint32) if self.tree_id is not None else None,
                "intensity": fill(self.energy, 0.0, np.float32),
                "width_ns": fill(self.width_ns, 0.0, np.float32),
                "cos_incidence": fill(self.cos_incidence, 0.0, np.float32)}


def first_return_arrays(echoes: Echoes, shape: tuple[int, int], escape_m: float) -> dict[str, np.ndarray]:
    """The N × M first-return arrays a :class:`~simlidar_mi.lidar.scan.ScanResult` holds:
    ``range_m``, ``cls``, ``element_id``, ``tree_id``, ``intensity`` (echo 1; escape where
    a beam has none) and ``n_returns`` (uint8)."""
    out = echoes.layer(shape, 1, escape_m=escape_m)
    out["n_returns"] = echoes.returns_per_beam(shape[0] * shape[1]).reshape(shape)
    return {k: out[k] for k in ("range_m", "cls", "element_id", "tree_id", "intensity", "n_returns")}


def detect_echoes(range_m, energy, cls, element_id, tree_id, cos_incidence, beam_index, *,
                  pulse_length_ns: float, detection_threshold: float, max_returns: int,
                  range_min_m: float = 0.0, range_max_m: float = math.inf,
                  echo_rule: str = "amplitude") -> Echoes:
    """Echoes of B beams from their S sub-rays each (module docstring).

    ``range_m``, ``energy``, ``cls``, ``element_id``, ``tree_id`` (or None),
    ``cos_incidence``: (B, S) arrays, range inf and/or energy 0 where a sub-ray escaped;
    ``beam_index``: (B,) int64 flat beam index of each row.
    """
    r = np.asarray(range_m, np.float64)
    if r.ndim != 2:
        raise ValueError(f"range_m must be a (beams, sub-rays) array, got shape {r.shape}")
    e = np.asarray(energy, np.float64)
    beam_index = np.asarray(beam_index, np.int64).reshape(-1)
    if e.shape != r.shape or len(beam_index) != r.shape[0]:
        raise ValueError(f"energy {e.shape} and beam_index {beam_index.shape} must match range_m {r.shape}")
    if not (math.isfinite(pulse_length_ns) and pulse_length_ns > 0):
        raise ValueError(f"pulse_length_ns must be > 0, got {pulse_length_ns}")
    if int(max_returns) < 1:
        raise ValueError(f"max_returns must be ≥ 1, got {max_returns}")
    if echo_rule not in ECHO_RULES:
        raise ValueError(f"echo_rule must be one of {ECHO_RULES}, got {echo_rule!r}")
    fwhm = range_fwhm_m(pulse_length_ns)
    sigma = fwhm * _SIGMA_PER_FWHM
    h = fwhm / BINS_PER_FWHM
    kb = int(math.ceil(KERNEL_SIGMAS * sigma / h))  # kernel half-width in bins (21)
    n_rows, s = r.shape
    with_tree = tree_id is not None

    # Valid sub-rays, per beam nearest first, in one flat list (beams in row order).
    valid = np.isfinite(r) & (e > 0)
    if s == 1:
        flat = np.flatnonzero(valid.ravel())
    else:
        order = _row_order(np.where(valid, r, np.inf))
        flat = (np.arange(n_rows, dtype=np.int64)[:, None] * s + order)[np.take_along_axis(valid, order, 1)]
    if len(flat) == 0:
        return Echoes.empty(with_tree)
    rj, ej = r.ravel()[flat], e.ravel()[flat]
    row = np.repeat(np.arange(n_rows, dtype=np.int64), valid.sum(axis=1)) if s > 1 else flat

    # Clusters: a new one at each beam and wherever two kernels cannot overlap.  Each has
    # its own bins (offset, nb); bin indices are global over all clusters.
    new = np.ones(len(flat), bool)
    new[1:] = (row[1:] != row[:-1]) | (np.diff(rj) > 2 * kb * h)
    starts = np.flatnonzero(new)
    n_cl = len(starts)
    cl = np.repeat(np.arange(n_cl), np.diff(np.r_[starts, len(flat)])) if n_cl < len(flat) else np.arange(n_cl)
    ends = np.r_[starts[1:], len(flat)] - 1
    lo = rj[starts] - (kb + 1) * h                      # centre of the cluster's bin 0 (W = 0 there)
    nb = np.floor((rj[ends] - lo) / h).astype(np.int64) + kb + 3
    offset = np.r_[0, np.cumsum(nb)[:-1]]
    pos = (rj - lo[cl]) / h
    nj = np.rint(pos).astype(np.int64)                  # bin of r_j within its cluster
    frac = pos - nj                                     # sub-bin offset of r_j, in bins

    # Energy of each cluster, summed in sub-ray order (as the echo energies are): every echo
    # of a cluster holds a subset of its sub-rays, so a cluster below the threshold gives none.
    c_energy = np.bincount(cl, weights=ej, minlength=n_cl)
    alive = (c_energy >= detection_threshold) & (c_energy > 0)
    size = ends - starts + 1
    narrow = alive & (nj[ends] - nj[starts] <= _NARROW_SPAN_BINS)
    single = np.flatnonzero(narrow & (size == 1))
    several = np.flatnonzero(narrow & (size > 1))
    general = alive & ~narrow
    fwd = dict(lo=lo, offset=offset, nb=nb, crow=row[starts], h=h, bin_sigmas=h / sigma)
    parts = []
    if len(single):
        ok, part = _single_echoes(single, starts, nj, frac, ej, c_energy, **fwd)
        parts.append(part)
        general[single[~ok]] = True
    if len(several):
        ok, part = _narrow_echoes(several, starts, ends, cl, nj, frac, ej, c_energy, **fwd)
        parts.append(part)
        general[several[~ok]] = True
    if general.any():
        parts.append(_general_echoes(np.flatnonzero(general), starts, cl, nj, frac, ej, fwhm, kb,
                                     echo_rule=echo_rule, threshold=detection_threshold, **fwd))
    if not parts:
        return Echoes.empty(with_tree)
    # Per echo: order key (its peak's global bin), row, range, energy, width (m), strongest, amplitude.
    key, grow, g_range, g_energy, width_m, strong, g_height = (np.concatenate(c) for c in zip(*parts))
    strong = strong.copy()
    if len(parts) > 1:
        o = np.argsort(key, kind="stable")
        grow, g_range, g_energy, width_m, strong, g_height = (
            x[o] for x in (grow, g_range, g_energy, width_m, strong, g_height))
    level = g_height if echo_rule == "amplitude" else g_energy
    keep = (level >= detection_threshold) & (g_range >= range_min_m) & (g_range <= range_max_m)
    if not keep.all():
        grow, g_range, g_energy, width_m, strong = (x[keep] for x in (grow, g_range, g_energy, width_m, strong))
    if len(grow) == 0:
        return Echoes.empty(with_tree)
    beam = beam_index[grow]
    srt = np.lexsort((g_range, beam))
    if np.any(np.diff(srt) != 1):
        beam, g_range, g_energy, width_m, strong = (x[srt] for x in (beam, g_range, g_energy, width_m, strong))
    first = np.r_[True, beam[1:] != beam[:-1]]
    beam_no = np.cumsum(first) - 1
    begin = np.flatnonzero(first)
    rank = np.arange(len(beam)) - begin[beam_no]
    n_ret = np.minimum(np.diff(np.r_[begin, len(beam)]), int(max_returns))[beam_no]
    k = rank < int(max_returns)
    if not k.all():
        beam, g_range, g_energy, width_m, strong, rank, n_ret = (
            x[k] for x in (beam, g_range, g_energy, width_m, strong, rank, n_ret))
    src = flat[strong]
    take = (lambda x, dt: np.asarray(x).ravel()[src].astype(dt))
    return Echoes(beam, (rank + 1).astype(np.uint8), n_ret.astype(np.uint8), g_range,
                  g_energy.astype(np.float32), (width_m * 2.0 / C_M_S * 1e9).astype(np.float32),
                  take(cls, np.uint8), take(element_id, np.uint32),
                  take(tree_id, np.uint32) if with_tree else None,
                  take(cos_incidence, np.float32))


def _vertex(wm, w0, wp):
    """Offset d (bins) and height of the vertex of the parabola through ln W at a peak's
    bins k−1, k, k+1 (exact for one Gaussian); d = 0 and the bin's height when the three
    do not bracket a vertex."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lm, l0, lp = np.log(wm), np.log(w0), np.log(wp)
        curv = lm - 2 * l0 + lp
        d = 0.5 * (lm - lp) / curv
        ok = np.isfinite(d) & (curv < 0) & (np.abs(d) <= 1)
        d = np.where(ok, d, 0.0)
        height = np.where(ok, np.exp(l0 - 0.25 * (lm - lp) * d), w0)
    return d, height


def _row_order(key):
    """``np.argsort(key, axis=1, kind="stable")``, faster: the unstable (SIMD) sort, then
    the stable one again for the rows where two finite keys tie (only there can the two
    orders differ; infinite keys are escapes, dropped after sorting)."""
    order = np.argsort(key, axis=1)
    srt = np.take_along_axis(key, order, 1)
    tie = np.flatnonzero(((srt[:, 1:] == srt[:, :-1]) & np.isfinite(srt[:, 1:])).any(axis=1))
    if len(tie):
        order[tie] = np.argsort(key[tie], axis=1, kind="stable")
    return order


def _pulse(taps, frac, ej, bin_sigmas):
    """E_j·exp(−((t − frac_j)·h/σ)²/2) for the (n, T) taps t (integers, held as float64:
    exact) of n sub-rays: the operations of every path in the same order, so every path
    gets the same bits."""
    x = np.subtract(taps, frac[:, None], out=taps if taps.ndim == 2 else None)  # 2D: a temporary
    x *= bin_sigmas
    np.square(x, out=x)
    x *= -0.5
    np.exp(x, out=x)
    x *= ej[:, None]
    return x


def _one_peak(V, bin0, lo, h):
    """Echo of clusters whose waveform is known on a window V (n, T) of bins bin0 … bin0+T−1
    (cluster-local): W rises into the window and falls out of it (the pulse tails), so the
    detector of :func:`_general_echoes` finds exactly one peak iff the slope signs in the
    window (flats carrying the slope before them) change once from + to −; then W rises to
    it and falls after it, and the half-height walk is read off the window.  Returns ``ok``
    (else the cluster goes to the general path), the peak's range, the width (m) and the
    peak's amplitude."""
    n, T = V.shape
    up = np.empty((n, T), np.int8)
    up[:, 0] = 1
    up[:, 1:] = (V[:, 1:] > V[:, :-1]).view(np.int8) - (V[:, 1:] < V[:, :-1]).view(np.int8)
    if not up.all():  # flats carry the slope before them
        idx = np.where(up != 0, np.arange(T), 0)
        np.maximum.accumulate(idx, axis=1, out=idx)
        up = np.take_along_axis(up, idx, 1)
    is_max = np.zeros((n, T), bool)
    is_max[:, :-1] = (up[:, :-1] > 0) & (up[:, 1:] < 0)
    is_max[:, -1] = up[:, -1] > 0
    p = np.argmax(is_max, axis=1)
    rows = np.arange(n)
    ok = (is_max.sum(axis=1) == 1) & (p >= 1) & (p <= T - 2)
    p = np.clip(p, 1, T - 2)
    w0 = V[rows, p]
    d, height = _vertex(V[rows, p - 1], w0, V[rows, p + 1])
    peak_r = lo + (bin0 + p + d) * h
    # Half-height walk: W ≥ half is a run around p (W rises to p and falls after it).
    half = height / 2.0
    above = V >= half[:, None]
    cols = np.arange(T)
    n_left = (above & (cols < p[:, None])).sum(axis=1)
    n_right = (above & (cols > p[:, None])).sum(axis=1)
    a, b = p - n_left, p + n_right
    ok &= (a >= 1) & (b <= T - 2)                      # the walk stopped inside the window
    a, b = np.clip(a, 1, T - 2), np.clip(b, 1, T - 2)
    g0 = bin0                                          # cluster-local bin of column 0
    left = (g0 + a) + -1 * _crossing_values(V[rows, a], V[rows, a - 1], V[rows, a + 1],
                                            V[rows, a - 1], half, -1)
    right = (g0 + b) + 1 * _crossing_values(V[rows, b], V[rows, b - 1], V[rows, b + 1],
                                            V[rows, b + 1], half, 1)
    return ok, peak_r, (right - left) * h, height


def _single_echoes(c, starts, nj, frac, ej, c_energy, *, lo, offset, nb, crow, h, bin_sigmas):
    """Clusters ``c`` of one sub-ray: one Gaussian of the sub-ray's energy, evaluated on the
    11 bins around it (the peak, the log-parabola and the half-height walk: FWHM = 8 bins,
    so the half-height crossings are ≤ 4.5 bins out) — the same bits as the full kernel."""
    j = starts[c]
    taps = np.arange(-(_SINGLE_TAPS // 2), _SINGLE_TAPS // 2 + 1)
    V = _pulse(taps.astype(np.float64), frac[j], ej[j], bin_sigmas)
    bin0 = nj[j] + taps[0]
    ok, peak_r, width_m, height = _one_peak(V, bin0, lo[c], h)
    ok &= (bin0 >= 1) & (bin0 + _SINGLE_TAPS < nb[c])
    gpeak = offset[c] + nj[j]
    return ok, _Part(gpeak[ok], crow[c][ok], peak_r[ok], c_energy[c][ok], width_m[ok], j[ok], height[ok])


def _members(c, cl, n_cl):
    """Sub-rays (positions in the flat list, increasing) of the clusters ``c`` (increasing)
    and the rank in ``c`` of each one's cluster."""
    rank = np.full(n_cl, -1, np.int64)
    rank[c] = np.arange(len(c))
    k = rank[cl]
    sub = np.flatnonzero(k >= 0)
    return sub, k[sub]


def _narrow_echoes(c, starts, ends, cl, nj, frac, ej, c_energy, *, lo, offset, nb, crow, h, bin_sigmas):
    """Clusters ``c`` of several sub-rays within ``_NARROW_SPAN_BINS`` bins of each other:
    their waveform on a window from ``_NARROW_PAD`` bins before the first sub-ray to as many
    after the last, accumulated like :func:`_waveforms` (every window bin is within the
    kernel of every sub-ray of the cluster, so each bin gets the same terms in the same
    order, never cut inside a cluster: the same bits).  Clusters with one peak (almost all:
    Gaussians within 2σ of each other have a log-concave sum) are read off the window
    (:func:`_one_peak`); the rest go to the general path."""
    span = nj[ends[c]] - nj[starts[c]]
    sub_all, k_all = _members(c, cl, len(nb))
    nsub = ends[c] - starts[c] + 1
    strong = _strongest(ej, sub_all, k_all, np.r_[0, np.cumsum(nsub)[:-1]])
    ok = np.zeros(len(c), bool)
    spans = np.unique(span)
    local = np.empty(len(c), np.int64)                 # rank of each cluster in its span
    for s in spans:
        sel = span == s
        local[sel] = np.arange(np.count_nonzero(sel))
    by_span = np.argsort(span[k_all].astype(np.int16), kind="stable")
    cut = np.searchsorted(span[k_all][by_span], np.r_[spans, spans[-1] + 1])
    parts = []
    for i, s in enumerate(spans):  # one window width per span
        sel = np.flatnonzero(span == s)
        cs = c[sel]
        T = int(s) + 2 * _NARROW_PAD + 1
        o = by_span[cut[i]:cut[i + 1]]
        sub, k = sub_all[o], local[k_all[o]]
        bin0 = nj[starts[cs]] - _NARROW_PAD
        t0 = bin0[k] - nj[sub]                         # tap of window column 0, per sub-ray
        taps = np.arange(T)
        t0f, tapsf = t0.astype(np.float64), taps.astype(np.float64)
        V = np.zeros(len(cs) * T)
        nsub = ends[cs] - starts[cs] + 1
        for a, b in _pieces(sub, k, np.r_[0, np.cumsum(nsub)[:-1]]):
            vals = _pulse(t0f[a:b, None] + tapsf, frac[sub[a:b]], ej[sub[a:b]], bin_sigmas)
            base = int(k[a]) * T
            idx = (k[a:b] * T - base)[:, None] + taps
            span_bins = (int(k[b - 1]) + 1) * T - base
            V[base:base + span_bins] += np.bincount(idx.ravel(), vals.ravel(), minlength=span_bins)
        V = V.reshape(len(cs), T)
        good, peak_r, width_m, height = _one_peak(V, bin0, lo[cs], h)
        good &= (bin0 >= 1) & (bin0 + T < nb[cs])
        ok[sel] = good
        cg = cs[good]
        # one echo per cluster: the cluster's bin offset orders it among the others
        parts.append(_Part(offset[cg], crow[cg], peak_r[good], c_energy[cg], width_m[good],
                           strong[sel[good]], height[good]))
    return ok, _Part(*(np.concatenate(x) for x in zip(*parts)))


def _strongest(ej, sub, k, run):
    """Per cluster k (the sub-rays ``sub`` grouped by k = 0, 1, …, each starting at
    ``run[k]``): the position of its first sub-ray with the most energy (ties: the nearest)."""
    e = ej[sub]
    top = np.maximum.reduceat(e, run)
    hit = np.flatnonzero(e == np.repeat(top, np.diff(np.r_[run, len(e)])))
    return sub[hit[np.r_[True, k[hit][1:] != k[hit][:-1]]]]


def _pieces(sub, k, row_start=None, tile=_TILE_SUBRAYS):
    """Pieces [a, b) of the sub-rays ``sub`` (positions in the flat list, increasing) for
    one bincount each, cache-sized: cut at a cluster start about every ``tile`` sub-rays.
    A cluster is never cut, so each bin of W is its own cluster's pulse terms added in
    sub-ray order from 0, whatever else the call holds."""
    n = len(sub)
    if row_start is None:                              # first sub-ray of each cluster
        row_start = np.r_[0, np.flatnonzero(np.diff(k)) + 1]
    out, a = [], 0
    while a < n:
        if n - a <= tile:
            b = n
        else:
            q = np.searchsorted(row_start, a + tile)
            b = int(row_start[q]) if q < len(row_start) else n
        out.append((a, b))
        a = b
    return out


def _no_part() -> _Part:
    return _Part(*(np.zeros(0, dt) for dt in (np.int64,) * 2 + (np.float64,) * 3 + (np.int64, np.float64)))


def _dead_time_leaders(r, row, dead_m) -> np.ndarray:
    """Per peak (sorted by row, then range): True where it triggers an echo (first of its beam,
    or ≥ ``dead_m`` beyond the last trigger).  One pass per echo depth, not per peak."""
    lead = np.zeros(len(r), bool)
    todo = np.arange(len(r))
    while len(todo):
        first = todo[np.r_[True, row[todo][1:] != row[todo][:-1]]]
        lead[first] = True
        trig = first[np.searchsorted(first, todo, side="right") - 1]
        todo = todo[r[todo] - r[trig] >= dead_m]
    return lead


def _general_echoes(c, starts, cl, nj, frac, ej, fwhm, kb, *, lo, offset, nb, crow, h, bin_sigmas,
                    echo_rule="amplitude", threshold=0.0):
    """Clusters ``c`` (any shape) read on all their bins: the full detector of the module
    docstring.  Bins are laid out compactly here; widths are taken at cluster-local bin
    indices and no sum is cut inside a cluster, so every path gives the bits the
    whole-list detector gives, in any call."""
    sub, ccl = _members(c, cl, len(nb))               # ccl: compact cluster of each sub-ray
    cnb = nb[c]
    coff = np.r_[0, np.cumsum(cnb)[:-1]]
    shift = offset[c] - coff                           # compact → global bin index
    total = int(cnb.sum())
    gbin = coff[ccl] + nj[sub]
    wave = _waveforms(gbin, frac[sub], ej[sub], total, kb, bin_sigmas, _pieces(sub, ccl))
    ej_s = ej[sub]

    # Slopes, flats carrying the slope before them; a cluster starts rising and ends falling.
    up = np.empty(total, np.int8)
    up[0] = 1
    up[1:] = (wave[1:] > wave[:-1]).view(np.int8) - (wave[1:] < wave[:-1]).view(np.int8)
    up[coff] = 1
    idx = np.where(up != 0, np.arange(total), 0)
    up = up[np.maximum.accumulate(idx)]
    nxt = np.empty_like(up)
    nxt[:-1] = up[1:]
    nxt[coff + cnb - 1] = -1
    is_max = (up > 0) & (nxt < 0)
    is_min = (up < 0) & (nxt > 0)
    is_min[coff] = True
    basin = np.cumsum(is_min) - 1                      # one maximum per basin
    peak = np.flatnonzero(is_max)
    pcl = np.repeat(np.arange(len(c)), cnb)[peak]

    d, height = _vertex(wave[peak - 1], wave[peak], wave[peak + 1])
    peak_r = lo[c][pcl] + (peak - coff[pcl] + d) * h
    beam_row = crow[c][pcl]

    if echo_rule == "amplitude":  # triggers ≥ threshold; peaks within c·τ/2 after one join it
        cand = np.flatnonzero(height >= threshold)
        if len(cand) == 0:
            return _no_part()
        lead = _dead_time_leaders(peak_r[cand], beam_row[cand], fwhm)
        group = np.full(len(peak), -1, np.int64)
        group[cand] = np.cumsum(lead) - 1
        n_groups = int(np.count_nonzero(lead))
        rep = cand[lead]
    else:  # single linkage within c·τ/2 in a beam; the highest peak represents its group
        gnew = np.ones(len(peak), bool)
        gnew[1:] = (beam_row[1:] != beam_row[:-1]) | (np.diff(peak_r) >= fwhm)
        group = np.cumsum(gnew) - 1
        n_groups = int(group[-1]) + 1
        by_height = np.lexsort((height, group))
        rep = by_height[np.r_[np.flatnonzero(np.diff(group[by_height])), len(peak) - 1]]

    # Energy and attributes from the sub-rays: sub-ray → basin (= peak) → group.  Sub-rays
    # are in (beam, range) order, so each group's sub-rays are one run of this list.
    gsub = group[basin[gbin]]
    if echo_rule == "amplitude":  # drop the sub-rays of peaks that reported nothing
        mine = gsub >= 0
        gsub, sub, ej_s = gsub[mine], sub[mine], ej_s[mine]
        if len(gsub) == 0:
            return _no_part()
    g_energy = np.bincount(gsub, weights=ej_s, minlength=n_groups)
    run = np.flatnonzero(np.r_[True, gsub[1:] != gsub[:-1]])
    top = np.maximum.reduceat(ej_s, run)
    hit = np.flatnonzero(ej_s == np.repeat(top, np.diff(np.r_[run, len(ej_s)])))
    first_hit = hit[np.r_[True, gsub[hit][1:] != gsub[hit][:-1]]]  # ties: the nearest
    strongest = np.full(n_groups, -1, np.int64)        # a group can hold no sub-ray (a ripple)
    strongest[gsub[first_hit]] = sub[first_hit]

    g = np.flatnonzero((g_energy > 0) & (strongest >= 0))
    rp = rep[g]
    width_m = _fwhm_bins(wave, peak[rp], height[rp], coff[pcl[rp]], coff[pcl[rp]] + cnb[pcl[rp]],
                         -coff[pcl[rp]]) * h
    return _Part(peak[rp] + shift[pcl[rp]], beam_row[rp], peak_r[rp], g_energy[g], width_m, strongest[g],
                 height[rp])


def _waveforms(gbin, frac, ej, total, kb, bin_sigmas, pieces) -> np.ndarray:
    """W on all bins: sub-ray j adds E_j·exp(−((t − frac_j)·h/σ)²/2) to bin gbin_j + t,
    |t| ≤ kb.  ``gbin`` never decreases, so a piece of sub-rays touches one stretch of bins:
    one bincount over that stretch per piece (:func:`_pieces`)."""
    taps = np.arange(-kb, kb + 1)
    tapsf = taps.astype(np.float64)
    wave = np.zeros(total)
    for a, b in pieces:
        g = gbin[a:b]
        base = int(g[0]) - kb
        span = int(g[-1]) + kb + 1 - base
        vals = _pulse(tapsf, frac[a:b], ej[a:b], bin_sigmas)
        idx = (g - base)[:, None] + taps
        wave[base:base + span] += np.bincount(idx.ravel(), vals.ravel(), minlength=span)
    return wave


def _fwhm_bins(wave, peak, height, lo_bin, hi_bin, shift) -> np.ndarray:
    """Full width (in bins) at height/2 around each ``peak``, walked outward while W ≥
    height/2 (inside the cluster [lo_bin, hi_bin)), each crossing interpolated on the
    parabola through ln W at the three bins around the last bin above half.  ``shift``
    maps the bins to cluster-local indices (the edges are summed there)."""
    half = height / 2.0
    edges = []
    for step in (-1, 1):
        at = peak.copy()
        live = np.arange(len(peak))
        while len(live):
            nxt = at[live] + step
            inside = (nxt >= lo_bin[live]) & (nxt < hi_bin[live])
            ok = inside & (wave[np.clip(nxt, 0, len(wave) - 1)] >= half[live])
            at[live[ok]] = nxt[ok]
            live = live[ok]
        edges.append((at + shift) + step * _crossing(wave, at, half, step))
    return edges[1] - edges[0]


def _crossing(wave, k, level, step) -> np.ndarray:
    n = len(wave)
    return _crossing_values(wave[k], wave[np.clip(k - 1, 0, n - 1)], wave[np.clip(k + 1, 0, n - 1)],
                            wave[np.clip(k + step, 0, n - 1)], level, step)


def _crossing_values(w0, wm, wp, wn, level, step) -> np.ndarray:
    """Distance (bins, in [0, 1]) from bin k (W = w0 ≥ level; wm, wp, wn: W at k−1, k+1,
    k + step) towards k + step (W < level) where W crosses ``level``: on the parabola
    through ln W at k−1, k, k+1 (exact for a Gaussian), else linearly."""
    lin = np.clip(np.where(w0 > wn, (w0 - level) / np.where(w0 > wn, w0 - wn, 1.0), 1.0), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lm, l0, lp, lt = np.log(wm), np.log(w0), np.log(wp), np.log(level)
        b = step * (lp - lm) / 2.0                     # slope towards the step side
        c = (lm - 2 * l0 + lp) / 2.0
        disc = b * b - 4 * c * (l0 - lt)
        x = np.where(c != 0, (-b - np.sqrt(disc)) / (2 * c), (lt - l0) / b)
        # −b − sqrt: of the two roots of c·x² + b·x + (l0 − lt) with c < 0, the one ahead
        good = np.isfinite(x) & (x >= -1e-9) & (x <= 1 + 1e-9) & (c < 0)
    return np.where(good, np.clip(x, 0.0, 1.0), lin)


def echo_statistics(results) -> dict | None:
    """The ``echoes`` block of measures.json for one scan result or several legs: beams with
    0, 1, 2, … returns and their shares, echoes per class per return number; None when no
    result carries echoes.  Needs only ``.echoes`` and ``.shape``."""
    results = results if isinstance(results, (list, tuple)) else [results]
    results = [res for res in results if getattr(res, "echoes", None) is not None]
    if not results:
        return None
    n_beams = sum(res.shape[0] * res.shape[1] for res in results)
    per_beam = np.concatenate([res.echoes.returns_per_beam(res.shape[0] * res.shape[1]) for res in results])
    by_n = np.bincount(per_beam)
    echoes = Echoes.concat([res.echoes for res in results]) if len(results) > 1 else results[0].echoes
    names = {v: k for k, v in CLASS_CODES.items()}
    per_class = {}
    for code in np.unique(echoes.cls):
        rn = np.bincount(echoes.return_number[echoes.cls == code])
        per_class[names.get(int(code), str(int(code)))] = {str(i): int(c) for i, c in enumerate(rn) if c}
    return {"beams": int(n_beams), "echoes": int(len(echoes)),
            "beams_by_n_returns": {str(i): int(c) for i, c in enumerate(by_n)},
            "share_by_n_returns": {str(i): float(c) / n_beams for i, c in enumerate(by_n)},
            "echoes_by_class_and_return": per_class}
