"""Streamed first-return scans (issue #8): traced and written in chunks, memory flat.

:func:`stream_scan` traces each pattern in blocks of whole rows (at most ``[scan]
chunk_beams`` beams per trace, :meth:`~simlidar_mi.lidar.scan.BeamTracer.row_blocks`) and
hands every block to the writers before tracing the next:

- ``scan.exr``: appended 16 scanlines at a time (:class:`~simlidar_mi.io.exr.ScanlineExrWriter`);
- ``points.las``: its offsets are floor(min of the points), as for a held scan, known only
  once the scan is traced, so each block's kept beams (beam, range, class, ids: 17–21 bytes a
  point) go to an unnamed temporary file in the output folder
  (:class:`~simlidar_mi.lidar.las_spill.PointSpill`, shared with ``[sensor]`` scans) and are
  written through laspy's chunked writer at the end: the scan is traced once;
- ``scan.png``: reduced block by block (:class:`~simlidar_mi.io.plots.RangeImageReducer`);
- measures: class counts, and A_IM summed as ``np.sum`` sums the held scan's N × M array
  (:class:`PairwiseSum`: the same bits from values fed in pieces).

Nothing of size N × M is held: memory is the scene, one chunk's arrays (~60 B a beam) and
the reduced image (≤ 4096² pixels); disk, besides the files, the spilled points.  Every
file's bytes, and measures.json but for its seconds, are those of the held scan whatever the
chunk size.  What ``run_scan`` returns is a :class:`StreamedScan`: shape, settings, pattern, counts and areas, no per-beam arrays
(read them from scan.exr with :func:`~simlidar_mi.lidar.scan.read_scan_exr`).
Scans with a ``[sensor]`` stream the same way (:mod:`simlidar_mi.lidar.stream_sensor`).
"""
from __future__ import annotations

import contextlib
import functools
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import CLASS_CODES
from .scan import CLASS_NAMES, BeamTracer, ScanSettings


#: Beams per piece when summing a block's area terms (StreamedScan.add): small temporaries,
#: reused from cache instead of page-faulted fresh; the sums' bits do not depend on it.
_SUM_BEAMS = 1 << 16


class PairwiseSum:
    """``np.sum`` of n float64 values fed in order, piece by piece, with the same bits.

    numpy sums a contiguous float64 array (of any shape, ``axis=None``) by pairwise
    summation (``pairwise_sum`` in numpy's ``loops_utils.h.src``): a run of at most 128
    values is summed with eight running partial sums r0 … r7 over its first multiple of 8,
    combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the rest added one by
    one (fewer than 8: one by one from 0); a longer run is split after n2 = ⌊n/2⌋ rounded down
    to a multiple of 8 and the two halves' sums added; the reduction adds that to 0.  The
    runs (leaves) depend on n only, so each leaf is summed as soon as its values are in and
    the tree is added up at the end: memory is one float per leaf (a leaf holds 64 to 128
    values), the tree (about 24 bytes a leaf, shared by the sums of one n) and the values of
    one unfinished leaf: about 0.5 byte a value.  The numpy version in use (2.x) was checked,
    and ``tests/test_sensor_stream.py`` checks it against ``np.sum`` on arrays of many sizes,
    fed in pieces (a numpy that sums otherwise fails there).
    """

    def __init__(self, n: int):
        self.n = int(n)
        self._levels, self._start, self._end = _pairwise_tree(self.n)
        self._sums = np.zeros(len(self._start))
        self._pos = self._next = 0
        self._carry = np.zeros(0)

    def add(self, values) -> None:
        """The next values (any shape, C order; cast to float64)."""
        v = np.asarray(values, np.float64).ravel()
        at = self._pos                                  # global index of v[0]
        self._pos += len(v)
        if self._pos > self.n:
            raise ValueError(f"{self._pos} values fed to a sum of {self.n}")
        last = int(np.searchsorted(self._end, self._pos, side="right"))  # leaves complete now
        if last == self._next:
            self._carry = np.concatenate([self._carry, v])
            return
        if len(self._carry):  # the leaf begun in an earlier piece
            i = self._next
            leaf = np.concatenate([self._carry, v[:self._end[i] - at]])
            self._sums[i] = _leaf_sums(leaf, leaf[:len(leaf) // 8 * 8].reshape(-1, 8), np.zeros(1, np.int64),
                                       len(leaf))[0]
            self._next += 1
        ids = np.arange(self._next, last)
        if len(ids):
            # Leaves start at multiples of 8 (every split does): from the first one, v in rows
            # of 8.  A leaf of zeros sums to 0 (the sums start at 0): most beams miss the wood.
            base = int(self._start[ids[0]])
            w = v[base - at:self._end[last - 1] - at]
            v8 = w[:len(w) // 8 * 8].reshape(-1, 8)
            nz = np.r_[0, np.cumsum(v8.any(axis=1)), 0]
            b0, b1 = (self._start[ids] - base) // 8, -(-(self._end[ids] - base) // 8)
            live = (nz[np.minimum(b1, len(v8))] > nz[b0]) | (self._end[ids] - base > len(v8) * 8)
            ids = ids[live]
            lens = self._end[ids] - self._start[ids]
            for length in np.unique(lens):
                sel = ids[lens == length]
                self._sums[sel] = _leaf_sums(w, v8, self._start[sel] - base, int(length))
        self._next = last
        self._carry = v[self._start[last] - at:].copy() if last < len(self._start) else np.zeros(0)

    def total(self) -> float:
        if self._pos != self.n:
            raise ValueError(f"{self._pos} of {self.n} values fed")
        if self.n == 0:
            return 0.0
        vals = None
        for leaf, ids in reversed(self._levels):
            out = np.empty(len(leaf))
            out[leaf] = self._sums[ids]
            if vals is not None:
                out[~leaf] = vals[0::2] + vals[1::2]
            vals = out
        return float(0.0 + vals[0])


@functools.lru_cache(maxsize=4)
def _pairwise_tree(n: int):
    """numpy's pairwise tree over n values (:class:`PairwiseSum`): per level (top first) which
    nodes are leaves (≤ 128 values) and those leaves' indices in start order; the leaves'
    starts and ends.  Shared by the sums of one scan (about 24 bytes a leaf)."""
    starts, lens = np.zeros(1, np.int64), np.array([n], np.int64)
    levels, leaf_starts = [], []
    while len(starts):
        leaf = lens <= 128
        levels.append(leaf)
        leaf_starts.append(starts[leaf])
        s, m = starts[~leaf], lens[~leaf]
        n2 = m // 2 - (m // 2) % 8
        starts = np.stack([s, s + n2], axis=1).ravel()  # left, right child of each node
        lens = np.stack([n2, m - n2], axis=1).ravel()
    order = np.concatenate(leaf_starts)
    rank = np.argsort(order, kind="stable")
    ids = np.empty(len(order), np.int64)
    ids[rank] = np.arange(len(order))
    bounds = np.cumsum([0] + [len(x) for x in leaf_starts])
    start = order[rank]
    return ([(leaf, ids[a:b]) for leaf, a, b in zip(levels, bounds[:-1], bounds[1:])], start,
            np.r_[start[1:], n])


def _leaf_sums(v: np.ndarray, v8: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """numpy's sum of each leaf v[s : s + length], s in ``starts`` (multiples of 8), length ≤
    128 (:class:`PairwiseSum`); ``v8``: v's first whole rows of 8."""
    if length < 8:  # one by one from 0
        res = np.zeros(len(starts))
        for i in range(length):
            res += v[starts + i]
        return res
    top = length - length % 8
    rows = starts // 8
    r = v8[rows]  # the eight running sums, one block of 8 at a time
    for i in range(1, top // 8):
        r += v8[rows + i]
    res = ((r[:, 0] + r[:, 1]) + (r[:, 2] + r[:, 3])) + ((r[:, 4] + r[:, 5]) + (r[:, 6] + r[:, 7]))
    for i in range(top, length):
        res += v[starts + i]
    return res


@dataclass
class StreamedScan:
    """A scan written as it was traced: what measures and pictures need, no beams."""

    settings: ScanSettings | None
    pattern: object
    origin_m: np.ndarray
    shape: tuple[int, int]
    counts: np.ndarray = field(default_factory=lambda: np.zeros(4, np.int64))
    seconds: float = 0.0
    metadata: dict = field(default_factory=dict)
    sensor: dict | None = None
    echoes: object = None   # a [sensor] scan's EchoTally (lidar/stream_sensor.py)
    tree_id: object = None  # True when the scan has tree ids (the EXR's channel set)

    def __post_init__(self) -> None:
        n = self.shape[0] * self.shape[1] if self.settings is not None else 0
        self._area = PairwiseSum(n)     # Σ w·l·Δsin θ over every beam (tractor)
        self._area_yz = PairwiseSum(n)  # Σ w·x·Δtan θ

    def class_counts(self) -> dict[str, int]:
        return {CLASS_NAMES[c]: int(self.counts[c]) for c in range(4)}

    def impacted_area_m2(self) -> float:
        """:meth:`ScanResult.impacted_area_m2`, the same bits."""
        self._tractor()
        return float(self.settings.dy_m * self._area.total())

    def impacted_area_yz_m2(self) -> float:
        self._tractor()
        return float(self.settings.dy_m * self._area_yz.total())

    def _tractor(self):
        if self.settings is None:
            raise ValueError("impacted areas are defined for the tractor scan (paper eq. 2) only")

    def add(self, a: int, block: dict) -> None:
        """Counts and area terms of rows a … of ``block`` (flat ``cls``, ``range``, ``frac``),
        fed in row order: the terms of :meth:`ScanResult.impacted_area_m2`, element for element."""
        self.counts += np.bincount(block["cls"], minlength=4)[:4]
        s = self.settings
        if s is None:
            return
        m = self.shape[1]
        th = np.deg2rad(s.theta_deg)
        half = np.deg2rad(s.dtheta_deg) / 2
        dsin = np.sin(th + half) - np.sin(th - half)
        with np.errstate(over="ignore", invalid="ignore"):
            dtan = np.tan(th + half) - np.tan(th - half)
        cos_th = np.cos(th)
        fraction = s.footprint > 0 and s.hit_rule == "fraction"
        cls_all, rng_all = block["cls"].reshape(-1, m), block["range"].reshape(-1, m)
        frac_all = block["frac"].reshape(-1, m) if fraction else None
        step = max(1, _SUM_BEAMS // m)  # rows at a time: the temporaries stay in cache (same bits)
        for r0 in range(0, len(cls_all), step):
            cls, rng = cls_all[r0:r0 + step], rng_all[r0:r0 + step]
            veg = (cls == CLASS_CODES["wood"]) | (cls == CLASS_CODES["leaf"])
            if fraction:
                w = np.where(veg, frac_all[r0:r0 + step], 0.0).astype(np.float64)
            else:
                w = veg.astype(np.float64)
            self._area.add(w * rng * dsin[None, :])
            with np.errstate(over="ignore", invalid="ignore"):
                x = rng * cos_th[None, :]
                area = w * x * dtan[None, :]
            term = np.where(w > 0, area, 0.0)
            self._area_yz.add(np.where(np.isnan(term), 0.0, term))  # np.nansum's zeros


@contextlib.contextmanager
def closed_after(*things):
    """Close each of ``things`` that is not None (a point spill, a progress bar) when the block
    ends, however it ends: both streams' cleanup."""
    try:
        yield
    finally:
        for thing in things:
            if thing is not None:
                thing.close()


def feed_block(block: dict, a: int, b: int, reducer, spill, summary: StreamedScan, pattern, leg: int,
               first_row: int) -> None:
    """Hand rows a … b − 1 of a leg to the PNG reduction, the LAS point spill (None: no LAS) and
    the running measures. Shared by first-return and ``[sensor]`` streams."""
    if reducer is not None:
        reducer.add(a, block["range"], block["cls"])
    if spill is not None:
        spill.add(pattern, leg, first_row, a, b, block)
    summary.add(a, block)


def finish_leg(exr, reducer, summary: StreamedScan, stage: Path, stem: str, title: str | None, key: str,
               files: dict | None) -> None:
    """Close a streamed leg's EXR and draw its PNG from the reduced image (``reducer`` None: no
    PNG); name both in ``files`` (``exr``/``png`` + ``key``, the leg's number when there are
    several). Shared by first-return and ``[sensor]`` streams."""
    from ..io.plots import plot_scan_png  # noqa: PLC0415
    exr.close()
    if files is not None:
        files[f"exr{key}"] = f"{stem}.exr"
    if reducer is not None:
        plot_scan_png(summary, stage / f"{stem}.png", title=title, reduced=reducer)
        if files is not None:
            files[f"png{key}"] = f"{stem}.png"


def stream_scan(built, patterns: list, stage: Path, *, variant: str | None, chunk_beams: int,
                exr_kwargs: dict, png_titles: list[str] | None, las: bool | str, crs: str | None,
                progress=None, files: dict | None = None) -> tuple[list[StreamedScan], float]:
    """Trace every pattern in chunks and write scan.exr / scan_legJ.exr, their PNGs
    (``png_titles``) and one points file (``las``: True for
    points.las, or the file's name, points.laz compressed) into ``stage`` (module docstring).
    Returns the scans' summaries and the seconds spent tracing."""
    from ..io.exr import ScanlineExrWriter, scan_exr_layout  # noqa: PLC0415
    from ..io.plots import RangeImageReducer  # noqa: PLC0415
    from .las_spill import PointSpill  # noqa: PLC0415
    tracers = [BeamTracer(built, p, variant) for p in patterns]
    trace_s = 0.0

    def blocks(tracer):
        nonlocal trace_s
        t = time.perf_counter()
        for a, b, block in tracer.row_blocks(chunk_beams):
            trace_s += time.perf_counter() - t
            yield a, b, block
            t = time.perf_counter()

    n_blocks = [len(range(0, t.pattern.n_rows, max(1, chunk_beams // t.pattern.n_cols))) for t in tracers]
    spill = PointSpill(stage) if las else None
    out, first_row = [], 0
    bar = None
    if progress is not None:
        bar = progress.stage("trace + write", sum(n_blocks), "chunk")
    with closed_after(spill, bar):
        for j, tr in enumerate(tracers):
            p = tr.pattern
            n, m = p.n_rows, p.n_cols
            summary = StreamedScan(tr.settings, p, built.origin_m.copy(), (n, m),
                                   metadata={"representation": built.representation, "facets": built.facets,
                                             "n_branches": built.n_branches, "n_dropped": built.n_dropped})
            stem = "scan" if len(tracers) == 1 else f"scan_leg{j}"
            reducer = RangeImageReducer(n, m) if png_titles is not None else None
            exr = None
            for a, b, block in blocks(tr):
                if exr is None:  # the channel set needs to know whether there are tree ids
                    summary.tree_id = True if block["tree"] is not None else None
                    hdr, dtypes = scan_exr_layout(summary, **exr_kwargs)
                    exr = ScanlineExrWriter(stage / f"{stem}.exr", hdr, dtypes, n, m)
                exr.write_rows({"range": block["range"].reshape(-1, m), "class": block["cls"].reshape(-1, m),
                                "branch_id": block["elem"].reshape(-1, m), "hit_fraction": block["frac"].reshape(-1, m),
                                "tree_id": None if block["tree"] is None else block["tree"].reshape(-1, m)})
                feed_block(block, a, b, reducer, spill, summary, p, j, first_row)
                if bar is not None:
                    bar.update(1, f"leg {j}" if len(tracers) > 1 else None)
            finish_leg(exr, reducer, summary, stage, stem, png_titles[j] if png_titles else None,
                       "" if len(tracers) == 1 else str(j), files)
            first_row += n
            out.append(summary)
        if spill is not None:
            name = las if isinstance(las, str) else "points.las"
            spill.write(stage / name, [t.pattern for t in tracers], crs=crs,
                        with_tree=any(s.tree_id is not None for s in out))
    return out, trace_s
