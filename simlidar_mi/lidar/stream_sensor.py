"""Streamed physical scans (issue #8 item 2): a ``[sensor]`` scan traced, read and written in chunks.

:class:`~simlidar_mi.lidar.physical.PhysicalTracer` is the physical scanner of
:func:`~simlidar_mi.lidar.scan.scan_physical` (divergent sub-rays, echoes from the waveform,
intensity, range noise), one chunk of at most ``[scan] chunk_beams`` beams (and ``chunk_rays``
sub-rays) at a time; ``scan_physical`` holds its chunks, :func:`stream_physical_scan` writes
them and lets them go:

- the chunks are the held scan's own (the same beam ranges, so the same calls of
  :func:`~simlidar_mi.lidar.waveform.detect_echoes`), regrouped into whole rows
  (:func:`row_blocks`; a row cut by a chunk waits for the next);
- ``scan.exr``: every channel of the held file (first return, ``n_returns``, ``intensity``,
  ``echo{r}.*``) appended rows at a time (:class:`~simlidar_mi.io.exr.ScanlineExrWriter`);
- ``scan.png``: reduced rows at a time (:class:`~simlidar_mi.io.plots.RangeImageReducer`);
- ``points.las``: one point per echo.  Its offsets are floor(min of all points), known only
  at the end, so each block's points (beam, range, class, ids, return numbers, intensity,
  width: 30–40 bytes an echo) go to an unnamed temporary file in the output folder and are
  read back into laspy's chunked writer once the offsets are known (no second trace;
  :class:`~simlidar_mi.lidar.las_spill.PointSpill`, shared with first-return scans);
- measures: class counts, A_IM (:class:`~simlidar_mi.lidar.stream.PairwiseSum`, the held
  sum's bits) and the echo statistics (:class:`EchoTally`: counts, exact).

Memory is the scene, one chunk (sub-rays and echoes) and one row; every file's bytes, and
measures.json but for its seconds, are those of the held scan.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..geometry import CLASS_CODES
from .las_spill import PointSpill
from .scan import physical_tracer
from .stream import StreamedScan, closed_after, feed_block, finish_leg
from .waveform import Echoes, echo_statistics

_ECHO_FIELDS = ("beam", "return_number", "number_of_returns", "range_m", "energy", "width_ns", "cls",
                "element_id", "tree_id", "cos_incidence")


def row_blocks(tracer):
    """Yield (first row, end row, arrays) over whole rows of a
    :class:`~simlidar_mi.lidar.physical.PhysicalTracer`: its chunks joined and cut at row
    ends (echo beams stay global flat indices)."""
    m = tracer.pattern.n_cols
    held, start = [], 0  # chunks not yet handed out, from beam ``start``
    for b0, n, part in tracer.chunks():
        held.append(part)
        end = b0 + n
        r1 = end // m
        if r1 * m <= start:
            continue
        block = _join(held) if len(held) > 1 else held[0]
        cut = r1 * m - start
        if cut == end - start:
            held = []
        else:
            block, rest = _split(block, cut, tracer.beam0 + r1 * m)
            held = [rest]
        yield start // m, r1, block
        start = r1 * m


def _join(parts: list[dict]) -> dict:
    """Consecutive chunks as one (echoes already in beam order: no sort)."""
    out = {}
    for k, v in parts[0].items():
        if k == "echoes":
            out[k] = None if v is None else Echoes(**{f: None if getattr(v, f) is None else
                                                      np.concatenate([getattr(p[k], f) for p in parts])
                                                      for f in _ECHO_FIELDS})
        else:
            out[k] = None if v is None else np.concatenate([p[k] for p in parts])
    return out


def _split(block: dict, cut: int, beam_end: int) -> tuple[dict, dict]:
    """The first ``cut`` beams of a block and the rest; echoes split at global beam ``beam_end``."""
    head, tail = {}, {}
    for k, v in block.items():
        if v is None:
            head[k] = tail[k] = None
        elif k == "echoes":
            i = int(np.searchsorted(v.beam, beam_end))
            head[k], tail[k] = v.take(slice(0, i)), v.take(slice(i, None))
        else:
            head[k], tail[k] = v[:cut], v[cut:]
    return head, tail


class EchoTally:
    """The ``echoes`` block of measures.json (:func:`~simlidar_mi.lidar.waveform.echo_statistics`)
    counted block by block: beams by echo count, echoes by class and return number."""

    def __init__(self):
        self.beams = 0
        self.by_n = np.zeros(1, np.int64)
        self.by_class_return = np.zeros((256, 256), np.int64)

    def add(self, echoes: Echoes, first_beam: int, n_beams: int) -> None:
        per_beam = np.bincount(echoes.beam - first_beam, minlength=n_beams).astype(np.uint8)
        by_n = np.bincount(per_beam)
        if len(by_n) > len(self.by_n):
            self.by_n = np.r_[self.by_n, np.zeros(len(by_n) - len(self.by_n), np.int64)]
        self.by_n[:len(by_n)] += by_n
        key = echoes.cls.astype(np.int64) * 256 + echoes.return_number
        self.by_class_return += np.bincount(key, minlength=256 * 256).reshape(256, 256)
        self.beams += n_beams


def scan_echo_statistics(results) -> dict | None:
    """measures.json's ``echoes`` of held results (``echo_statistics``) or streamed ones."""
    results = results if isinstance(results, (list, tuple)) else [results]
    tallies = [r.echoes for r in results if isinstance(r.echoes, EchoTally)]
    if not tallies:
        return echo_statistics(results)
    n_beams = sum(t.beams for t in tallies)
    by_n = np.zeros(max(len(t.by_n) for t in tallies), np.int64)
    for t in tallies:
        by_n[:len(t.by_n)] += t.by_n
    by_n = by_n[:np.flatnonzero(by_n)[-1] + 1] if by_n.any() else by_n[:0]  # as np.bincount ends
    table = sum(t.by_class_return for t in tallies)
    names = {v: k for k, v in CLASS_CODES.items()}
    per_class = {names.get(int(code), str(int(code))): {str(i): int(c) for i, c in enumerate(table[code]) if c}
                 for code in np.flatnonzero(table.sum(axis=1))}
    return {"beams": int(n_beams), "echoes": int(table.sum()),
            "beams_by_n_returns": {str(i): int(c) for i, c in enumerate(by_n)},
            "share_by_n_returns": {str(i): float(c) / n_beams for i, c in enumerate(by_n)},
            "echoes_by_class_and_return": per_class}


def stream_physical_scan(built, patterns: list, stage: Path, *, model, variant: str | None, seed: int,
                         chunk_beams: int, exr_kwargs: dict, png_titles: list[str] | None, las: bool | str,
                         crs: str | None, progress=None, files: dict | None = None) -> tuple[list[StreamedScan], float]:
    """Trace every pattern with ``model`` in chunks and write scan.exr / scan_legJ.exr, their
    PNGs (``png_titles``) and one points file (``las``: True for
    points.las, or the file's name, points.laz compressed) into ``stage`` (module docstring), as
    :func:`~simlidar_mi.lidar.stream.stream_scan` does for first-return scans.  Returns the
    scans' summaries and the seconds spent tracing and detecting echoes."""
    from ..io.exr import ScanlineExrWriter, scan_exr_layout, sensor_header, with_half_copies  # noqa: PLC0415
    from ..io.plots import RangeImageReducer  # noqa: PLC0415
    tracers = [physical_tracer(built, p, model, seed=seed, leg=j, variant=variant, chunk_beams=chunk_beams)
               for j, p in enumerate(patterns)]
    sensor = model.to_dict()
    max_returns = int(sensor.get("max_returns") or 1)
    spill = PointSpill(stage, intensity=model.intensity) if las else None
    bar = progress.stage("trace + write", sum(t.n_chunks for t in tracers), "chunk") if progress is not None else None
    out, trace_s, first_row = [], 0.0, 0
    with closed_after(spill, bar):
        for j, tr in enumerate(tracers):
            p = tr.pattern
            n, m = p.n_rows, p.n_cols
            summary = StreamedScan(tr.settings, p, built.origin_m.copy(), (n, m), sensor=sensor,
                                   metadata=tr.metadata, echoes=EchoTally() if tr.energy else None)
            stem = "scan" if len(tracers) == 1 else f"scan_leg{j}"
            reducer = RangeImageReducer(n, m) if png_titles is not None else None
            exr, done, blocks = None, 0, row_blocks(tr)
            t = time.perf_counter()
            for a, b, block in blocks:
                trace_s += time.perf_counter() - t
                echoes = block["echoes"]
                if echoes is not None:  # beams relative to the block's first
                    echoes.beam = echoes.beam - (tr.beam0 + a * m)
                if exr is None:  # the channel set needs to know whether there are tree ids
                    summary.tree_id = True if block["tree"] is not None else None
                    hdr, dtypes = scan_exr_layout(summary, **exr_kwargs)
                    if tr.energy:
                        dtypes = with_half_copies({**dtypes, **_echo_dtypes(max_returns, model.intensity,
                                                                            echoes.tree_id is not None)})
                        hdr.update(sensor_header(sensor))
                    exr = ScanlineExrWriter(stage / f"{stem}.exr", hdr, dtypes, n, m)
                exr.write_rows(_exr_rows(block, b - a, m, max_returns, p.escape_m))
                feed_block(block, a, b, reducer, spill, summary, p, j, first_row)
                if echoes is not None:
                    summary.echoes.add(echoes, 0, (b - a) * m)
                if bar is not None:
                    cut = -(-b * m // tr.per_chunk)  # chunks traced so far
                    bar.update(cut - done, f"leg {j}" if len(tracers) > 1 else None)
                    done = cut
                t = time.perf_counter()
            finish_leg(exr, reducer, summary, stage, stem, png_titles[j] if png_titles else None,
                       "" if len(tracers) == 1 else str(j), files)
            summary.metadata.update({"trace_seconds": tr.trace_s, "echo_seconds": tr.echo_s})
            first_row += n
            out.append(summary)
        if spill is not None:
            name = las if isinstance(las, str) else "points.las"
            spill.write(stage / name, [t.pattern for t in tracers], crs=crs, sensor=sensor,
                        with_tree=any(s.tree_id is not None for s in out), with_echoes=tracers[0].energy)
    return out, trace_s


def _echo_dtypes(max_returns: int, intensity: bool, with_tree: bool) -> dict:
    """The echo channels of a physical scan's EXR (:mod:`simlidar_mi.io.exr`)."""
    out = {"n_returns": np.uint32}
    if intensity:
        out["intensity"] = np.float32
    for r in range(2, max_returns + 1):
        out.update({f"echo{r}.range": np.float32, f"echo{r}.class": np.uint32, f"echo{r}.branch_id": np.uint32})
        if intensity:
            out[f"echo{r}.intensity"] = np.float32
        if with_tree:
            out[f"echo{r}.tree_id"] = np.uint32
    return out


def _exr_rows(block: dict, rows: int, m: int, max_returns: int, escape_m: float) -> dict:
    """Every EXR channel of a block of whole rows (echo beams relative to its first)."""
    shape = (rows, m)
    out = {"range": block["range"].reshape(shape), "class": block["cls"].reshape(shape),
           "branch_id": block["elem"].reshape(shape), "hit_fraction": block["frac"].reshape(shape),
           "tree_id": None if block["tree"] is None else block["tree"].reshape(shape)}
    echoes = block["echoes"]
    if echoes is None:
        return out
    out["n_returns"] = block["n_ret"].reshape(shape)
    if block["inten"] is not None:
        out["intensity"] = block["inten"].reshape(shape)
    for r in range(2, max_returns + 1):
        layer = echoes.layer(shape, r, escape_m=escape_m)
        out.update({f"echo{r}.range": layer["range_m"], f"echo{r}.class": layer["cls"],
                    f"echo{r}.branch_id": layer["element_id"], f"echo{r}.intensity": layer["intensity"],
                    f"echo{r}.tree_id": layer["tree_id"]})
    return out
