"""Streamed first-return scans (issue #8): traced and written in chunks, memory flat.

:func:`stream_scan` traces each pattern in blocks of whole rows (at most ``[scan]
chunk_beams`` beams per trace, :meth:`~simlidar_mi.lidar.scan.BeamTracer.row_blocks`) and
hands every block to the writers before tracing the next:

- ``scan.exr``: appended 16 scanlines at a time (:class:`~simlidar_mi.io.exr.ScanlineExrWriter`);
- ``points.las``: appended through laspy's chunked writer (``laspy.open(mode="w")`` +
  ``write_points``), which keeps the header's counts and bounds.  Its offsets are
  floor(min of the points), as for a held scan, so a first pass traces the scan once more
  and keeps only that minimum (a scan of one chunk is traced once);
- ``scan.png``: reduced block by block (:class:`~simlidar_mi.io.plots.RangeImageReducer`);
- measures: class counts and A_IM summed per row, then over rows.

Nothing of size N × M is held: memory is the scene, one chunk's arrays (~60 B a beam) and
the reduced image (≤ 4096² pixels).  Every file's bytes are those of the held scan's
writers whatever the chunk size; only measures.json's A_IM may differ from a held
scan's in the last digits (a sum per row, then over rows).  What ``run_scan`` returns is
a :class:`StreamedScan`: shape, settings, pattern, counts and areas, no per-beam arrays
(read them from scan.exr with :func:`~simlidar_mi.lidar.scan.read_scan_exr`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import CLASS_CODES
from .scan import CLASS_NAMES, BeamTracer, ScanSettings


@dataclass
class StreamedScan:
    """A scan written as it was traced: what measures and pictures need, no beams."""

    settings: ScanSettings | None
    pattern: object
    origin_m: np.ndarray
    shape: tuple[int, int]
    counts: np.ndarray = field(default_factory=lambda: np.zeros(4, np.int64))
    area_rows: np.ndarray | None = None      # (N,) Σ_k w·l·Δsin θ per row (tractor)
    area_yz_rows: np.ndarray | None = None   # (N,) Σ_k w·x·Δtan θ per row (tractor)
    seconds: float = 0.0
    metadata: dict = field(default_factory=dict)
    sensor: dict | None = None
    echoes: object = None
    tree_id: object = None  # True when the scan has tree ids (the EXR's channel set)

    def class_counts(self) -> dict[str, int]:
        return {CLASS_NAMES[c]: int(self.counts[c]) for c in range(4)}

    def impacted_area_m2(self) -> float:
        """:meth:`ScanResult.impacted_area_m2`, summed per row then over rows."""
        self._tractor()
        return float(self.settings.dy_m * np.sum(self.area_rows))

    def impacted_area_yz_m2(self) -> float:
        self._tractor()
        return float(self.settings.dy_m * np.sum(self.area_yz_rows))

    def _tractor(self):
        if self.settings is None:
            raise ValueError("impacted areas are defined for the tractor scan (paper eq. 2) only")

    def add(self, a: int, block: dict) -> None:
        """Counts and per-row areas of rows a … of ``block``."""
        self.counts += np.bincount(block["cls"], minlength=4)[:4]
        s = self.settings
        if s is None:
            return
        m = self.shape[1]
        cls = block["cls"].reshape(-1, m)
        rng = block["range"].reshape(-1, m)
        veg = (cls == CLASS_CODES["wood"]) | (cls == CLASS_CODES["leaf"])
        if s.footprint > 0 and s.hit_rule == "fraction":
            w = np.where(veg, block["frac"].reshape(-1, m), 0.0).astype(np.float64)
        else:
            w = veg.astype(np.float64)
        th = np.deg2rad(s.theta_deg)
        half = np.deg2rad(s.dtheta_deg) / 2
        dsin = np.sin(th + half) - np.sin(th - half)
        rows = slice(a, a + len(cls))
        self.area_rows[rows] = np.sum(w * rng * dsin[None, :], axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            dtan = np.tan(th + half) - np.tan(th - half)
            x = rng * np.cos(th)[None, :]
            area = w * x * dtan[None, :]
        self.area_yz_rows[rows] = np.nansum(np.where(w > 0, area, 0.0), axis=1)


def stream_scan(built, patterns: list, stage: Path, *, variant: str | None, chunk_beams: int,
                exr_kwargs: dict, png_titles: list[str] | None, las: bool, crs: str | None,
                progress=None, files: dict | None = None) -> tuple[list[StreamedScan], float]:
    """Trace every pattern in chunks and write scan.exr / scan_legJ.exr, their PNGs
    (``png_titles``) and one points.las (``las``) into ``stage`` (module docstring).
    Returns the scans' summaries and the seconds spent tracing."""
    from ..io.exr import ScanlineExrWriter, scan_exr_layout  # noqa: PLC0415
    from ..io.las import block_points, las_header, las_record, row_points_m, row_times_s  # noqa: PLC0415
    from ..io.plots import RangeImageReducer, plot_scan_png  # noqa: PLC0415
    import laspy  # noqa: PLC0415
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
    cached: dict[int, tuple] = {}
    writer = header = None
    with_tree = False
    if las:  # pass 1: the offsets, floor(min of the points), as write_scan_las takes them
        lo = np.full(3, np.inf)
        time_kind = ""
        for j, tr in enumerate(tracers):
            time_kind = row_times_s(tr.pattern, 0, 0, 0)[1]
            for a, b, block in blocks(tr):
                with_tree |= block["tree"] is not None
                keep = block["cls"] != CLASS_CODES["escape"]
                if keep.any():
                    pts = row_points_m(tr.pattern, block["range"], a, b).reshape(-1, 3)[keep]
                    lo = np.minimum(lo, pts.min(axis=0))
                if n_blocks[j] == 1:
                    cached[j] = (a, b, block)
        offsets = np.floor(lo) if np.all(np.isfinite(lo)) else np.zeros(3)
        header = las_header(offsets, time_kind, with_tree=with_tree, crs=crs)
        # a LasData made before the writer sets the header as write_scan_las's does (same bytes)
        laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(0, header=header))
        writer = laspy.open(str(stage / "points.las"), mode="w", header=header)
    out, first_row = [], 0
    bar = None
    if progress is not None:
        bar = progress.stage("trace + write", sum(n_blocks), "chunk")
    try:
        for j, tr in enumerate(tracers):
            p = tr.pattern
            n, m = p.n_rows, p.n_cols
            summary = StreamedScan(tr.settings, p, built.origin_m.copy(), (n, m),
                                   area_rows=np.zeros(n) if tr.settings is not None else None,
                                   area_yz_rows=np.zeros(n) if tr.settings is not None else None,
                                   metadata={"representation": built.representation, "facets": built.facets,
                                             "n_branches": built.n_branches, "n_dropped": built.n_dropped})
            stem = "scan" if len(tracers) == 1 else f"scan_leg{j}"
            reducer = RangeImageReducer(n, m) if png_titles is not None else None
            exr = None
            source = [cached[j]] if j in cached else blocks(tr)
            for a, b, block in source:
                if exr is None:  # the channel set needs to know whether there are tree ids
                    summary.tree_id = True if block["tree"] is not None else None
                    hdr, dtypes = scan_exr_layout(summary, **exr_kwargs)
                    exr = ScanlineExrWriter(stage / f"{stem}.exr", hdr, dtypes, n, m)
                exr.write_rows({"range": block["range"].reshape(-1, m), "class": block["cls"].reshape(-1, m),
                                "branch_id": block["elem"].reshape(-1, m), "hit_fraction": block["frac"].reshape(-1, m),
                                "tree_id": None if block["tree"] is None else block["tree"].reshape(-1, m)})
                if reducer is not None:
                    reducer.add(a, block["range"], block["cls"])
                if writer is not None:
                    times, _ = row_times_s(p, first_row, a, b)
                    cols = block_points(p, j, a, b, block, times)
                    writer.write_points(las_record(header, cols, with_tree=with_tree))
                summary.add(a, block)
                if bar is not None:
                    bar.update(1, f"leg {j}" if len(tracers) > 1 else None)
            exr.close()
            cached.pop(j, None)
            if files is not None:
                files[f"exr{'' if len(tracers) == 1 else j}"] = f"{stem}.exr"
            if reducer is not None:
                plot_scan_png(summary, stage / f"{stem}.png", title=png_titles[j], reduced=reducer)
                if files is not None:
                    files[f"png{'' if len(tracers) == 1 else j}"] = f"{stem}.png"
            first_row += n
            out.append(summary)
    finally:
        if writer is not None:
            writer.close()
        if bar is not None:
            bar.close()
    return out, trace_s
