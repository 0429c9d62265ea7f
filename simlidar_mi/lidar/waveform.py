"""Full-waveform echo detection: sub-ray returns of each beam → discrete echoes.

A beam is S sub-rays (divergence × dot matrix, see ``sensor.py``); sub-ray j returns at
range r_j with energy E_j (Lambertian law in ``sensor.py``; 0 for an escape).  The
receiver sees the waveform

    W(r) = Σ_j E_j · exp(−(r − r_j)² / 2σ²),   FWHM = 2·sqrt(2 ln 2)·σ = c·τ/2,

the emitted pulse (Gaussian, duration τ = ``pulse_length_ns`` at half maximum, c =
299 792 458 m/s) mapped to range.  W is sampled on bins of FWHM/8 and read like a
digitiser does:

1. **echoes** are the local maxima of W; an echo's energy is Σ E_j over the sub-rays
   whose nearest bin lies in its basin (between the minima either side), so the energies
   of all echoes of a beam add up to the beam's returned energy;
2. its **range** is the vertex of the parabola through the logarithms of the three bins
   around the peak (exact for one Gaussian, i.e. one target at one range);
3. its **width** (ns) is the full width of W at half the peak height, walked outward from
   the peak and interpolated the same way (τ for one target at one range);
4. its class, element id, tree id and cos incidence are those of the sub-ray that brought
   the most energy into it;
5. peaks closer than c·τ/2 merge (chains merge too: single linkage): energies add, the
   higher peak gives range and width;
6. echoes with energy below ``detection_threshold`` are dropped, then those outside
   [range_min_m, range_max_m]; the nearest ``max_returns`` are kept and numbered 1..n.

Each sub-ray's pulse is evaluated exactly on the bins within ±6σ of it (the tail beyond is
below 1.5e-8 of its peak); sub-rays of one beam more than that apart form independent
clusters, laid end to end in one flat array, so ``np.bincount`` over chunks of sub-rays
builds every waveform at once (no loop over beams).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..geometry import CLASS_CODES

C_M_S = 299_792_458.0
#: Bins per range FWHM of the pulse.
BINS_PER_FWHM = 8
#: The pulse kernel is evaluated out to this many σ either side of a sub-ray's range.
KERNEL_SIGMAS = 6.0
NO_ID = 0xFFFFFFFF
_SIGMA_PER_FWHM = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


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
                  range_min_m: float = 0.0, range_max_m: float = math.inf) -> Echoes:
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
    fwhm = range_fwhm_m(pulse_length_ns)
    sigma = fwhm * _SIGMA_PER_FWHM
    h = fwhm / BINS_PER_FWHM
    kb = int(math.ceil(KERNEL_SIGMAS * sigma / h))  # kernel half-width in bins (21)
    n_rows, s = r.shape
    with_tree = tree_id is not None

    # Valid sub-rays, per beam nearest first, in one flat list (beams in row order).
    valid = np.isfinite(r) & (e > 0)
    order = np.argsort(np.where(valid, r, np.inf), axis=1, kind="stable")
    flat = (np.arange(n_rows, dtype=np.int64)[:, None] * s + order)[np.take_along_axis(valid, order, 1)]
    if len(flat) == 0:
        return Echoes.empty(with_tree)
    rj, ej = r.ravel()[flat], e.ravel()[flat]
    row = flat // s

    # Clusters: a new one at each beam and wherever two kernels cannot overlap.
    new = np.ones(len(flat), bool)
    new[1:] = (row[1:] != row[:-1]) | (np.diff(rj) > 2 * kb * h)
    cl = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    ends = np.r_[starts[1:], len(flat)] - 1
    lo = rj[starts] - (kb + 1) * h                      # centre of the cluster's bin 0 (W = 0 there)
    nb = np.floor((rj[ends] - lo) / h).astype(np.int64) + kb + 3
    offset = np.r_[0, np.cumsum(nb)[:-1]]
    total = int(nb.sum())
    pos = (rj - lo[cl]) / h
    nj = np.rint(pos).astype(np.int64)
    frac = pos - nj                                     # sub-bin offset of r_j, in bins
    gbin = offset[cl] + nj
    wave = _waveforms(gbin, frac, ej, total, kb, h / sigma)

    # Slopes, flats carrying the slope before them; a cluster starts rising and ends falling.
    up = np.empty(total, np.int8)
    up[0] = 1
    up[1:] = (wave[1:] > wave[:-1]).view(np.int8) - (wave[1:] < wave[:-1]).view(np.int8)
    up[offset] = 1
    idx = np.where(up != 0, np.arange(total), 0)
    up = up[np.maximum.accumulate(idx)]
    nxt = np.empty_like(up)
    nxt[:-1] = up[1:]
    nxt[offset + nb - 1] = -1
    is_max = (up > 0) & (nxt < 0)
    is_min = (up < 0) & (nxt > 0)
    start_bin = np.zeros(total, bool)
    start_bin[offset] = True
    basin = np.cumsum(is_min | start_bin) - 1          # one maximum per basin
    peak = np.flatnonzero(is_max)
    cl_bin = np.repeat(np.arange(len(starts)), nb)
    pcl = cl_bin[peak]

    # Peak position and height: vertex of the parabola through ln W at peak−1, peak, peak+1.
    with np.errstate(divide="ignore", invalid="ignore"):
        lm, l0, lp = np.log(wave[peak - 1]), np.log(wave[peak]), np.log(wave[peak + 1])
        curv = lm - 2 * l0 + lp
        d = 0.5 * (lm - lp) / curv
        ok = np.isfinite(d) & (curv < 0) & (np.abs(d) <= 1)
        d = np.where(ok, d, 0.0)
        height = np.where(ok, np.exp(l0 - 0.25 * (lm - lp) * d), wave[peak])
    peak_r = lo[pcl] + (peak - offset[pcl] + d) * h
    beam_row = row[starts][pcl]

    # Merge peaks closer than c·τ/2 within a beam; the highest peak of a group represents it.
    gnew = np.ones(len(peak), bool)
    gnew[1:] = (beam_row[1:] != beam_row[:-1]) | (np.diff(peak_r) >= fwhm)
    group = np.cumsum(gnew) - 1
    n_groups = int(group[-1]) + 1
    by_height = np.lexsort((height, group))
    rep = by_height[np.r_[np.flatnonzero(np.diff(group[by_height])), len(peak) - 1]]

    # Energy and attributes from the sub-rays: sub-ray → basin (= peak) → group.  Sub-rays
    # are in (beam, range) order, so each group's sub-rays are one run of this list.
    gsub = group[basin[gbin]]
    g_energy = np.bincount(gsub, weights=ej, minlength=n_groups)
    run = np.flatnonzero(np.r_[True, gsub[1:] != gsub[:-1]])
    top = np.maximum.reduceat(ej, run)
    hit = np.flatnonzero(ej == np.repeat(top, np.diff(np.r_[run, len(ej)])))
    first_hit = hit[np.r_[True, gsub[hit][1:] != gsub[hit][:-1]]]  # ties: the nearest
    strongest = np.full(n_groups, -1, np.int64)        # a group can hold no sub-ray (a ripple)
    strongest[gsub[first_hit]] = flat[first_hit]

    g_range = peak_r[rep]
    keep = ((g_energy >= detection_threshold) & (g_energy > 0) & (strongest >= 0)
            & (g_range >= range_min_m) & (g_range <= range_max_m))
    g = np.flatnonzero(keep)
    if len(g) == 0:
        return Echoes.empty(with_tree)
    width_m = _fwhm_bins(wave, peak[rep[g]], height[rep[g]], offset[pcl[rep[g]]],
                         offset[pcl[rep[g]]] + nb[pcl[rep[g]]]) * h
    beam = beam_index[beam_row[rep[g]]]
    rng = g_range[g]
    srt = np.lexsort((rng, beam))
    g, beam, rng, width_m = g[srt], beam[srt], rng[srt], width_m[srt]
    first = np.r_[True, beam[1:] != beam[:-1]]
    begin = np.maximum.accumulate(np.where(first, np.arange(len(beam)), 0))
    rank = np.arange(len(beam)) - begin
    counts = np.bincount(np.cumsum(first) - 1)
    n_ret = np.minimum(counts, int(max_returns))[np.cumsum(first) - 1]
    k = rank < int(max_returns)
    src = strongest[g[k]]
    take = (lambda x, dt: np.asarray(x).ravel()[src].astype(dt))
    return Echoes(beam[k], (rank[k] + 1).astype(np.uint8), n_ret[k].astype(np.uint8), rng[k],
                  g_energy[g[k]].astype(np.float32),
                  (width_m[k] * 2.0 / C_M_S * 1e9).astype(np.float32),
                  take(cls, np.uint8), take(element_id, np.uint32),
                  take(tree_id, np.uint32) if with_tree else None,
                  take(cos_incidence, np.float32))


def _waveforms(gbin, frac, ej, total, kb, bin_sigmas, chunk=1 << 16) -> np.ndarray:
    """W on all bins: sub-ray j adds E_j·exp(−((t − frac_j)·h/σ)²/2) to bin gbin_j + t,
    |t| ≤ kb.  ``gbin`` never decreases, so a chunk of sub-rays touches one stretch of bins:
    one bincount over that stretch per chunk (memory ∝ chunk·(2·kb + 1))."""
    taps = np.arange(-kb, kb + 1)
    wave = np.zeros(total)
    for a in range(0, len(gbin), chunk):
        g, f = gbin[a:a + chunk], frac[a:a + chunk]
        base = int(g[0]) - kb
        span = int(g[-1]) + kb + 1 - base
        vals = ej[a:a + chunk, None] * np.exp(-0.5 * ((taps[None, :] - f[:, None]) * bin_sigmas) ** 2)
        idx = (g - base)[:, None] + taps[None, :]
        wave[base:base + span] += np.bincount(idx.ravel(), vals.ravel(), minlength=span)
    return wave


def _fwhm_bins(wave, peak, height, lo_bin, hi_bin) -> np.ndarray:
    """Full width (in bins) at height/2 around each ``peak``, walked outward while W ≥
    height/2 (inside the cluster [lo_bin, hi_bin)), each crossing interpolated on the
    parabola through ln W at the three bins around the last bin above half."""
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
        edges.append(at + step * _crossing(wave, at, half, step))
    return edges[1] - edges[0]


def _crossing(wave, k, level, step) -> np.ndarray:
    """Distance (bins, in [0, 1]) from bin k (W ≥ level) towards k + step (W < level) where
    W crosses ``level``: on the parabola through ln W at k−1, k, k+1 (exact for a Gaussian),
    else linearly."""
    n = len(wave)
    w0, wm, wp = wave[k], wave[np.clip(k - 1, 0, n - 1)], wave[np.clip(k + 1, 0, n - 1)]
    wn = wave[np.clip(k + step, 0, n - 1)]
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
    """The ``echoes`` block of measures.json for one scan result or several legs.

    Beams with 0, 1, 2, … returns and their shares; echoes per class per return number;
    None when no result carries echoes.  Needs only ``.echoes`` and ``.shape``.
    """
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
