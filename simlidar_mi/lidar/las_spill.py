"""The points of a streamed scan kept on disk until points.las can be written (issue #8).

A LAS file's offsets are floor(min of every point), known only once the whole scan has been
traced.  :class:`PointSpill` takes each block of rows as it is traced, keeps the minimum and
writes the block's points in packed columns (beam, range, class, ids and, with echoes,
return numbers, intensity, width: 21–40 bytes a point) to an unnamed temporary file in the
output folder (gone when closed, also after a failure); :meth:`PointSpill.write` reads them
back and writes ``points.las`` once, so the scan is traced once.  Used by first-return scans
(:func:`~simlidar_mi.lidar.stream.stream_scan`) and ``[sensor]`` scans
(:func:`~simlidar_mi.lidar.stream_sensor.stream_physical_scan`).

Points are computed from the kept beams only, :data:`~simlidar_mi.io.las.CHUNK_POINTS` at a
time (the temporaries stay in cache), with the float64 operations of
``ScanResult.points_m()`` / ``write_scan_las``: the bytes of the held scan's file.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from ..geometry import CLASS_CODES
from .waveform import NO_ID


class PointSpill:
    """The LAS points of a streamed scan, kept on disk until the offsets are known (module docstring).

    ``intensity``: whether echo energies become LAS intensities (a ``[sensor]`` with intensity)."""

    def __init__(self, stage: Path, intensity: bool = False):
        self.f = tempfile.TemporaryFile(dir=stage)
        self.intensity = intensity
        self.index: list[tuple] = []  # (leg, first_row, a, b, columns' dtypes, count)
        self.lo, self.hi = np.full(3, np.inf), np.full(3, -np.inf)
        self._geometry: dict[int, object] = {}  # leg → io.las.BeamGeometry

    def add(self, pattern, leg: int, first_row: int, a: int, b: int, block: dict) -> None:
        """Rows [a, b) of leg ``leg`` (flat ``range``, ``cls``, ``elem``, ``tree`` and, for a
        ``[sensor]`` scan, ``echoes`` with beams relative to the block's first)."""
        from ..io.las import CHUNK_POINTS  # noqa: PLC0415
        m = pattern.n_cols
        echoes = block.get("echoes")
        if echoes is None:  # first returns: the beams that did not escape
            keep = block["cls"] != CLASS_CODES["escape"]
            beam = np.flatnonzero(keep)
            cols = {"beam": beam, "range": block["range"][keep], "cls": block["cls"][keep],
                    "elem": block["elem"][keep],
                    "tree": block["tree"][keep] if block["tree"] is not None else None}
        else:
            from ..io.las import INTENSITY_SCALE  # noqa: PLC0415
            energy = np.asarray(echoes.energy, np.float64)
            cols = {"beam": echoes.beam, "range": np.asarray(echoes.range_m, np.float64), "cls": echoes.cls,
                    "elem": echoes.element_id, "tree": echoes.tree_id, "ret": echoes.return_number,
                    "nret": echoes.number_of_returns,
                    "intensity": (np.minimum(65535.0, np.rint(INTENSITY_SCALE * energy)).astype(np.uint16)
                                  if self.intensity else np.zeros(len(energy), np.uint16)),
                    "width": np.asarray(echoes.width_ns, np.float32)}
        cols = {k: v for k, v in cols.items() if v is not None}
        for c0 in range(0, len(cols["beam"]), CHUNK_POINTS):  # min and max of the points, exact in any pieces
            part = slice(c0, c0 + CHUNK_POINTS)
            xyz = self._xyz(pattern, leg, a, m, cols["beam"][part], cols["range"][part])
            self.lo, self.hi = np.minimum(self.lo, xyz.min(axis=1)), np.maximum(self.hi, xyz.max(axis=1))
        for v in cols.values():
            self.f.write(np.ascontiguousarray(v).data)
        self.index.append((leg, first_row, a, b, {k: v.dtype for k, v in cols.items()}, len(cols["beam"])))

    def _xyz(self, pattern, leg: int, a: int, m: int, beam, range_m) -> np.ndarray:
        """(3, n) points at ``range_m`` along beams (block-relative flat index) of rows a …, by
        :class:`~simlidar_mi.io.las.BeamGeometry`: the float64 operations of
        ``ScanResult.points_m()`` / ``write_scan_las``, bit for bit."""
        from ..io.las import BeamGeometry  # noqa: PLC0415
        if leg not in self._geometry:
            self._geometry = {leg: BeamGeometry(pattern)}  # legs come one after the other
        i, k = np.divmod(np.asarray(beam, np.int64), m)
        return self._geometry[leg].points_m(i + a, k, np.asarray(range_m))

    def write(self, path: Path, patterns: list, *, crs: str | None, sensor: dict | None = None,
              with_tree: bool, with_echoes: bool = False) -> None:
        """``points.las`` of every point added, with the held scan's header and bytes
        (:class:`~simlidar_mi.io.las.RecordWriter`, as ``write_scan_las`` writes them)."""
        from ..io.las import CHUNK_POINTS, RecordWriter, las_header, row_times_s  # noqa: PLC0415
        any_point = any(entry[-1] for entry in self.index)
        offsets = np.floor(self.lo) if any_point else np.zeros(3)
        time_kind = row_times_s(patterns[-1], 0, 0, 0)[1]
        header = las_header(offsets, time_kind, with_tree=with_tree, with_echoes=with_echoes, crs=crs,
                            sensor=sensor)
        self.f.seek(0)
        angles = [np.round(p.col_angle_deg / 0.006).astype(np.int16) for p in patterns]  # per column
        with RecordWriter(path, header, *((self.lo, self.hi) if any_point else (None, None))) as writer:
            for leg, first_row, a, b, dtypes, count in self.index:
                cols = {k: np.frombuffer(self.f.read(count * dt.itemsize), dt) for k, dt in dtypes.items()}
                if not count:
                    continue
                p = patterns[leg]
                m = p.n_cols
                times, _ = row_times_s(p, first_row, a, b)
                for c0 in range(0, count, CHUNK_POINTS):
                    part = {key: v[c0:c0 + CHUNK_POINTS] for key, v in cols.items()}
                    n = len(part["beam"])
                    i, k = np.divmod(np.asarray(part["beam"], np.int64), m)
                    xyz = self._xyz(p, leg, a, m, part["beam"], part["range"])
                    rec = {"cls": part["cls"], "range": part["range"].astype(np.float32), "elem": part["elem"],
                           "tree": part["tree"] if "tree" in part else np.full(n, NO_ID, np.uint32),
                           "gps": times[i, k], "angle": angles[leg][k], "i": i + a, "k": k}
                    if with_echoes:
                        rec.update(ret=part["ret"], nret=part["nret"], intensity=part["intensity"],
                                   width=part["width"])
                    writer.write(xyz, rec, leg=leg, with_tree=with_tree, with_echoes=with_echoes)

    def close(self) -> None:
        self.f.close()
