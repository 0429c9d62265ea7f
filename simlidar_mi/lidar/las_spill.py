"""The points of a streamed scan kept on disk until points.las can be written (issue #8).

A LAS file's offsets are floor(min of every point), known only once the whole scan has been
traced.  :class:`PointSpill` takes each block of rows as it is traced, keeps the minimum and
writes the block's points in packed columns (beam, range, class, ids and, with echoes,
return numbers, echo energy, width: 21–38 bytes a point) to an unnamed temporary file in the
output folder (gone when closed, also after a failure); :meth:`PointSpill.write` reads them
back and writes ``points.las`` once, so the scan is traced once.  The LAS intensities are
made then, from the kept energies, with the scan's scale (65535 / the largest energy,
:func:`~simlidar_mi.io.las_fields.scan_intensity_scale`): the spill keeps only the running
maximum, so memory stays bounded and the bytes do not depend on the blocks.  Used by first-return scans
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

    ``intensity``: whether the ``[sensor]`` records intensity (else intensities 0)."""

    def __init__(self, stage: Path, intensity: bool = False):
        from ..io.las_fields import ScaleChooser  # noqa: PLC0415
        self.f = tempfile.TemporaryFile(dir=stage)
        self.intensity = bool(intensity)
        self.energy_max = 0.0  # the largest echo energy added (float32 values: exact)
        self.index: list[tuple] = []  # (leg, first_row, a, b, columns' dtypes, count)
        self.lo, self.hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.scales = ScaleChooser()
        self._geometry: dict[int, object] = {}  # leg → io.las.BeamGeometry

    def add(self, pattern, leg: int, first_row: int, a: int, b: int, block: dict) -> None:
        """Rows [a, b) of leg ``leg`` (flat ``range``, ``cls``, ``elem``, ``tree`` and, for a
        ``[sensor]`` scan, ``echoes`` with beams relative to the block's first), kept in firing
        order (:func:`~simlidar_mi.io.las_fields.firing_order`, as ``write_scan_las`` writes them)."""
        from ..io.las import CHUNK_POINTS  # noqa: PLC0415
        from ..io.las_fields import firing_order, firing_sort  # noqa: PLC0415
        m = pattern.n_cols
        fire = firing_order(pattern)
        echoes = block.get("echoes")
        if echoes is None:  # first returns: the beams that did not escape
            beam = np.flatnonzero(block["cls"] != CLASS_CODES["escape"])
            if fire is not None:
                beam = beam[firing_sort(beam, m, fire)]
            cols = {"beam": beam, "range": block["range"][beam], "cls": block["cls"][beam],
                    "elem": block["elem"][beam],
                    "tree": block["tree"][beam] if block["tree"] is not None else None}
        else:
            cols = {"beam": echoes.beam, "range": np.asarray(echoes.range_m, np.float64), "cls": echoes.cls,
                    "elem": echoes.element_id, "tree": echoes.tree_id, "ret": echoes.return_number,
                    "nret": echoes.number_of_returns, "energy": np.asarray(echoes.energy, np.float32),
                    "width": np.asarray(echoes.width_ns, np.float32)}
            if fire is not None:
                order = firing_sort(echoes.beam, m, fire)
                cols = {k: (np.asarray(v)[order] if v is not None else None) for k, v in cols.items()}
        cols = {k: v for k, v in cols.items() if v is not None}
        if "energy" in cols and len(cols["energy"]):
            self.energy_max = max(self.energy_max, float(cols["energy"].max()))
        for c0 in range(0, len(cols["beam"]), CHUNK_POINTS):  # min and max of the points, exact in any pieces
            part = slice(c0, c0 + CHUNK_POINTS)
            xyz = self._xyz(pattern, leg, a, m, cols["beam"][part], cols["range"][part])
            self.lo, self.hi = np.minimum(self.lo, xyz.min(axis=1)), np.maximum(self.hi, xyz.max(axis=1))
            self.scales.add(xyz)
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
        """``path`` (points.las, or points.laz compressed) of every point added, with the held scan's header and bytes
        (:class:`~simlidar_mi.io.las.RecordWriter`, as ``write_scan_las`` writes them)."""
        from ..io.las import CHUNK_POINTS, RecordWriter, is_laz, las_header, row_times_s  # noqa: PLC0415
        from ..io.las_fields import BeamAngles, echo_intensity, scan_intensity_scale  # noqa: PLC0415
        any_point = any(entry[-1] for entry in self.index)
        offsets = self.scales.offsets(self.lo) if any_point else np.zeros(3)
        time_kind = row_times_s(patterns[-1], 0, 0, 0)[1]
        header = las_header(offsets, time_kind, with_tree=with_tree, with_echoes=with_echoes, crs=crs,
                            sensor=sensor, scales=self.scales.scales(), energy_max=self.energy_max)
        iscale = scan_intensity_scale(self.energy_max) if self.intensity else None
        self.f.seek(0)
        angles = [BeamAngles(p) for p in patterns]
        with RecordWriter(path, header, *((self.lo, self.hi) if any_point else (None, None)),
                          compress=is_laz(path)) as writer:
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
                           "gps": times[i, k], "i": i + a, "k": k}
                    rec["angle"], rec["elev"], rec["azim"] = angles[leg](i + a, k)
                    if with_echoes:
                        rec.update(ret=part["ret"], nret=part["nret"], intensity=echo_intensity(part["energy"], iscale),
                                   width=part["width"], energy=part["energy"])
                    writer.write(xyz, rec, leg=leg, with_tree=with_tree, with_echoes=with_echoes)

    def close(self) -> None:
        self.f.close()
