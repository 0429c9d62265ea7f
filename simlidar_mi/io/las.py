"""Scan hits → LAS 1.4 point clouds (laspy), in real coordinates.

Point format 6, every field as LAS 1.4 R15 defines it (§2.6, "Point Data Record Format 6"):

* ``return_number`` / ``number_of_returns``: 1 / 1 for every point of a first-return scan
  (a system that records one return, §2.6 "Return Number"); a ``[sensor]`` scan numbers its
  echoes 1 … n ≤ 15 per pulse.  The header's Number of Points by Return (§2.4) counts them;
  its legacy counts stay 0, as §2.4 requires for point formats 6–10.
* ``scan_angle`` (0.006° units): the beam's angle from nadir, 0 straight down, ±180° straight
  up, positive when the beam points to the right of the platform's forward direction
  (:func:`~simlidar_mi.io.las_fields.forward_heading_deg`), negative to its left
  (counter-clockwise seen from behind, §2.6 "Scan Angle").  For beams in the plane across the
  track (tractor, path, airborne) this is the standard's rotation about the track; for beams out
  of that plane (spinning heads, rosettes, tripods) it is the full angle from nadir with the
  side's sign, so |scan_angle| is always the off-nadir angle and a near-nadir filter keeps
  near-vertical beams only.  Beams in the vertical plane through the track count as right.
* ``intensity``: ``round(s·E)``, E the echo energy (lidar/sensor.py), s chosen per scan from the
  echoes it holds: 65535 / E_max rounded down to 4 significant digits
  (:func:`~simlidar_mi.io.las_fields.scan_intensity_scale`), so no echo clips, however near, and
  the strongest reads 65470 … 65535 however weak the scan's echoes (§2.6 "Intensity": normalised
  to the dynamic range).  Counts compare within a file; across files divide by s first.  VLR
  record 2 states s and E_max; ``echo_energy`` holds E itself.  0 without a ``[sensor]`` with
  intensity on.
* classification: ground 2, leaves 5 (high vegetation); wood has no ASPRS class and uses 64
  (user-definable range).  Escapes are not written.

Extra bytes (§4 "Extra Bytes", no min/max statistics: options bits 1 and 2 are 0 and the fields
zero, so a file's bytes do not depend on how many chunks wrote it): ``range_m`` (float32),
``scan_position`` (uint32, row i of the pattern), ``scan_angle_index`` (uint32, column k),
``elevation_deg`` and ``azimuth_deg`` (float32: the beam direction's elevation above the
horizon and its azimuth counter-clockwise from +x, in [-180, 180)), ``branch_id`` (uint32),
``tree_id`` (uint32) for scenes of several plants (both 4294967295 for none, declared as the
descriptor's no_data value: option bit 0, §4) and, with echoes, ``echo_width_ns`` (float32)
and, with intensity, ``echo_energy`` (float32, E unclipped).

Coordinates: offsets floor(min) per axis (whole metres, on the grid of every scale used); the
scale per axis is the coarsest of 0.1 mm … 1 m (powers of ten) that every point's 0.1 mm
coordinate is a whole multiple of, unless that leaves LAStools' "resolution fluff": every stored
integer with the same last digit, as on an axis on a regular grid (a tractor's rows 2 mm apart
from the scene's edge: 0.1 mm integers f_0 + 20 i).  Such an axis gets 0.25 mm, 0.5 mm, … (the
scales LAStools accepts) so that the grid step is not a multiple of 10 stored units, when the
whole axis moves by at most 0.5 mm for it (the rounding of a 1 mm file; at most 0.1 mm for
rows 2 mm apart) (:class:`~simlidar_mi.io.las_fields.ScaleChooser`);
a constant axis keeps the fluff, as any scale would.

Header: the global-encoding WKT bit is always set (LAS 1.4 requires it for point
formats 6–10); its GPS-time-type bit stays 0, since ``gps_time`` is a time from the
scan's start, not a GPS time.  A scene that declares ``[scene] crs = "EPSG:…"`` gets
that CRS as an OGC WKT record (``LASF_Projection`` 2112, WKT1 as GDAL writes it); the
coordinates are the scene's own, so the CRS only says what they mean.

``gps_time`` (seconds from the scan's first beam):

* airborne: the pulse's firing time, (i·M + k) / pulse_rate_hz (lines at
  pulse_rate / M Hz, pulses evenly spaced within a line);
* tractor, static and path: these platforms have no pulse rate (SIMLIDAR's scan has
  no speed), so the time is a scan-order time on a nominal 1 s per row: i + k / M for
  row i and column k, each leg of a path following the rows of the legs before it.
  It orders the points as they were scanned; it is not a measured time.

Points are written row by row in firing order: a spinning head's channels (columns, sorted by
elevation) in the order they fire (:func:`~simlidar_mi.io.las_fields.firing_order`), so
``gps_time`` never steps back.
``point_source_id`` is the leg index j of a multi-leg path (0, 1, …; with ``[platform]
scan_legs``, the position in that list: legs driven without scanning get none); a one-leg scan
(every other platform) has a single source, so it is 0 for every point, and
``scan_position`` holds the row.  A ``simlidar-mi`` VLR (record 1) repeats the
``gps_time`` definition used, as text.  A pattern that knows each beam's emission time
(``beam_times_s()`` not None: a moving platform with a pulse rate) gives that time.

A scan with a ``[sensor]`` (``result.echoes`` set) writes one point per echo, at the
echo's range along the beam centre, with the beam's ``gps_time``; ``range_m`` is then the
echo's range.  VLR record 2 states the intensity scale, record 3 holds the resolved sensor as
JSON.

``[scan] points_format = "laz"`` writes ``points.laz`` instead: the same header, VLRs and
point records, compressed by laspy's LAZ writer with the lazrs backend (LAZ 1.4 point format
6 layered chunks of 50 000 points); any LAZ reader (laspy, PDAL, LAStools) reads back the LAS
file's points exactly (tests/test_laz_output.py).

laspy is imported on first use, not with this module: with pyproj, which laspy imports, it takes
0.1 s, and ``run_scan`` writes the LAS in a forked child (simlidar_mi._runtime.fork), so the child pays
it, not the process that writes the EXR and the PNG meanwhile (issue #8, BENCHMARKS.md §8f).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..geometry import CLASS_CODES, NO_ID  # NO_ID: the no_data of branch_id, tree_id
from .atomic import atomic_file
from .las_fields import (SCALES_M, BeamAngles, ScaleChooser, echo_intensity, firing_order, firing_sort,
                         intensity_text, scan_intensity_scale)
from .scan_record import ScanRecord

if TYPE_CHECKING:  # annotations only: laspy loads in the LAS writer's child
    import laspy

LAS_CLASS = {CLASS_CODES["ground"]: 2, CLASS_CODES["leaf"]: 5, CLASS_CODES["wood"]: 64}
#: Nominal duration of one row (sweep, azimuth step) for platforms without a pulse rate.
ROW_PERIOD_S = 1.0
TIME_PULSE = "pulse time: (i*M + k) / pulse_rate_hz seconds from the first pulse"
TIME_SCAN_ORDER = ("scan-order time, not measured: i + k/M on a nominal 1 s per row "
                   "(row i, column k of M), legs following each other")
TIME_BEAM = "beam emission time in seconds from the first beam (BeamPattern.beam_times_s)"
#: Points per block when computing points and packing LAS records: small enough that the
#: temporaries are reused from cache instead of page-faulted fresh (bytes do not depend on it).
CHUNK_POINTS = 1 << 16
#: ASPRS code of each class code (geometry.CLASS_CODES) as a lookup table; escapes are not written.
LAS_CLASS_LUT = np.zeros(256, np.uint8)
LAS_CLASS_LUT[list(LAS_CLASS)] = list(LAS_CLASS.values())
_INT32 = np.iinfo(np.int32)

def scan_times_s(result: ScanRecord, first_row: int = 0) -> tuple[np.ndarray, str]:
    """(N, M) float64 ``gps_time`` of every beam of ``result`` and the definition used.

    ``first_row`` shifts a path leg by the rows of the legs before it.  A pattern with a
    timing table (a tractor with a pulse rate, ``rotating``, ``rosette``) gives each beam its
    emission time, :meth:`~simlidar_mi.lidar.platforms.BeamPattern.beam_times_s`, already
    continuous across legs; else the airborne pattern's pulse times, else the scan-order time.
    """
    return row_times_s(result.pattern, first_row, 0, result.shape[0])


def row_times_s(pattern, first_row: int, a: int, b: int) -> tuple[np.ndarray, str]:
    """:func:`scan_times_s` of rows [a, b) only, (b − a, M)."""
    m = pattern.n_cols
    if pattern.row_time_s is not None:
        col = pattern.col_time_s if pattern.col_time_s is not None else np.zeros(m)
        times = np.asarray(pattern.row_time_s, np.float64)[a:b, None] + np.asarray(col, np.float64)[None, :]
        how = (pattern.meta or {}).get("timing")
        return times, f"{TIME_BEAM}: {how}" if how else TIME_BEAM
    i = np.arange(a, b, dtype=np.float64)[:, None]
    k = np.arange(m, dtype=np.float64)[None, :]
    rate = (pattern.meta or {}).get("pulse_rate_hz")
    if rate:
        return (i * m + k) / float(rate), TIME_PULSE
    return (first_row + i + k / m) * ROW_PERIOD_S, TIME_SCAN_ORDER


class BeamGeometry:
    """Points along the beams of one pattern, ``origin + r · direction`` with the float64
    operations of ``ScanRecord.points_m()`` (origin moved by ``col_time · velocity`` on a moving
    platform; direction the column's, turned by the row's yaw through cos/sin of every row),
    one axis at a time.

    Rows whose (cos, sin) of the yaw are the same bits share one direction per column, so
    their directions are computed once per group (a tractor has one yaw: one row of M
    directions) and picked: the same operations on the same values, the same bits."""

    def __init__(self, pattern):
        p = self.pattern = pattern
        self.m = p.n_cols
        self.origin = [np.ascontiguousarray(p.row_origin_m[:, c]) for c in range(3)]
        self.velocity = np.asarray(p.velocity_m_s, np.float64) if p.moving else None
        self.table = self.cos_sin = self.group = None
        if p.beam_dirs is not None:
            return
        yaw = np.deg2rad(p.row_yaw_deg)
        cos_yaw, sin_yaw = np.cos(yaw), np.sin(yaw)
        pairs = np.ascontiguousarray(np.stack([cos_yaw, sin_yaw], axis=1))
        keys = pairs.view(np.dtype((np.void, pairs.itemsize * 2))).ravel()
        _, first, group = np.unique(keys, return_index=True, return_inverse=True)
        cd = p.col_dir
        if len(first) * 8 > len(yaw) or len(first) * self.m > 1 << 20:  # yaws mostly distinct: per point
            self.cos_sin = (cos_yaw, sin_yaw)
            return
        c, s = cos_yaw[first][:, None], sin_yaw[first][:, None]
        self.group = group.ravel().astype(np.int64) * self.m
        self.table = [(c * cd[None, :, 0] - s * cd[None, :, 1]).ravel(),
                      (s * cd[None, :, 0] + c * cd[None, :, 1]).ravel(), cd[:, 2]]

    def points_m(self, i: np.ndarray, k: np.ndarray, range_m: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(3, n) float64 points at ``range_m`` along beams (row i, column k), into ``out`` if given."""
        p = self.pattern
        r = range_m.astype(np.float64)
        out = np.empty((3, len(i)), np.float64) if out is None else out
        if p.beam_dirs is not None:
            d = p.beam_dirs[i, k]
        elif self.table is None:
            c, s = self.cos_sin[0][i], self.cos_sin[1][i]
            cd = p.col_dir[k]
            d = np.stack([c * cd[:, 0] - s * cd[:, 1], s * cd[:, 0] + c * cd[:, 1], cd[:, 2]], axis=-1)
        else:
            at = self.group[i] + k
        for c in range(3):
            if p.beam_dirs is not None or self.table is None:
                dc = d[:, c]
            else:
                dc = self.table[c].take(k if c == 2 else at)
            np.multiply(r, dc, out=out[c])
            o = self.origin[c].take(i)
            if self.velocity is not None:  # fired from where the platform was
                o = o + p.col_time_s[k] * self.velocity[c]
            np.add(o, out[c], out=out[c])
        return out


def crs_wkt(crs: str) -> str:
    """OGC WKT (WKT1, as GDAL writes it) of an ``"EPSG:<code>"`` string, via pyproj."""
    import pyproj  # noqa: PLC0415 - only scenes that declare a CRS need it
    return pyproj.CRS.from_user_input(crs).to_wkt("WKT1_GDAL")


def is_laz(path: str | Path) -> bool:
    """Whether the points file ``path`` is a LAZ one (its name ends in ``.laz``)."""
    return Path(path).suffix.lower() == ".laz"


def write_scan_las(result: ScanRecord | list[ScanRecord], path: str | Path,
                   crs: str | None = None) -> Path:
    """Write every non-escape first return of ``result`` (or of several legs) to ``path``;
    with echoes (a ``[sensor]`` scan), every echo.  A ``path`` ending in ``.laz`` gets the same
    points LAZ-compressed (:func:`is_laz`).

    With several results, ``point_source_id`` is the leg index and ``scan_position``
    counts rows within each leg.  ``crs`` (``"EPSG:<code>"``, the scene's
    ``[scene] crs``) is written as an OGC WKT record; None writes none.

    Two passes over blocks of rows (or of :data:`CHUNK_POINTS` echoes), so that every
    temporary stays in cache: the points first (their minimum gives the offsets), then the
    records, packed into one reused buffer and written as they are filled (:class:`RecordWriter`).
    The bytes are those of :func:`las_record` through laspy's writer (tests/test_las_fast.py).
    """
    results = result if isinstance(result, list) else [result]
    with_echoes = any(getattr(r, "echoes", None) is not None for r in results)
    with_tree = any(r.tree_id is not None for r in results)
    legs, first_row = [], 0
    for leg, res in enumerate(results):
        legs.append(_LegPoints(res, leg, first_row, with_echoes))
        first_row += res.shape[0]
    time_kind = row_times_s(results[-1].pattern, 0, 0, 0)[1]
    xyz = np.empty((3, sum(lp.n for lp in legs)), np.float64)  # (3, n): each axis contiguous
    lo, hi, at = np.full(3, np.inf), np.full(3, -np.inf), 0
    for lp in legs:
        leg_lo, leg_hi = lp.points(xyz[:, at:at + lp.n])
        lo, hi, at = np.minimum(lo, leg_lo), np.maximum(hi, leg_hi), at + lp.n
    chooser = ScaleChooser()
    for a in range(0, at, CHUNK_POINTS):
        chooser.add(xyz[:, a:a + CHUNK_POINTS])
    offsets = chooser.offsets(lo) if at else np.zeros(3)
    sensor = next((r.sensor for r in results if getattr(r, "sensor", None) is not None), None)
    e_max = set_echo_intensities([lp.echo_cols for lp in legs if lp.echo_cols is not None], sensor)
    header = las_header(offsets, time_kind, with_tree=with_tree, with_echoes=with_echoes, crs=crs,
                        sensor=sensor, scales=chooser.scales(), energy_max=e_max)
    with atomic_file(path) as tmp, RecordWriter(tmp, header, *((lo, hi) if at else (None, None)),
                                                compress=is_laz(path)) as w:
        at = 0
        for lp in legs:
            for cols in lp.columns():
                n = len(cols["cls"])
                w.write(xyz[:, at:at + n], cols, leg=lp.leg, with_tree=with_tree, with_echoes=with_echoes)
                at += n
    return Path(path)


def set_echo_intensities(echo_cols: list[dict], sensor: dict | None) -> float:
    """Fill ``intensity`` of every leg's echo columns (:func:`_echo_points`) with the scan's
    scale (:func:`~simlidar_mi.io.las_fields.scan_intensity_scale` of the largest echo energy of
    all legs; zeros when the sensor's intensity is off); the largest energy."""
    e_max = max((float(c["energy"].max()) for c in echo_cols if len(c["energy"])), default=0.0)
    scale = scan_intensity_scale(e_max) if (sensor or {}).get("intensity") else None
    for c in echo_cols:
        c["intensity"] = echo_intensity(c["energy"], scale)
    return e_max


class _LegPoints:
    """The points of one leg for :func:`write_scan_las`, in pieces: first returns by blocks of
    rows (the kept beams of each block found again in the second pass, which is cheaper than
    keeping their indices), echoes (a ``[sensor]`` leg) by :data:`CHUNK_POINTS`."""

    def __init__(self, res: ScanRecord, leg: int, first_row: int, with_echoes: bool):
        self.res, self.leg, self.first_row, self.with_echoes = res, leg, first_row, with_echoes
        self.m = res.shape[1]
        self.echo_cols = None
        self.fire = firing_order(res.pattern)
        self.angles = BeamAngles(res.pattern)
        if getattr(res, "echoes", None) is not None:
            self.echo_cols = _echo_points(res, leg, scan_times_s(res, first_row)[0])
            self.n = len(self.echo_cols["cls"])
        else:
            self.geometry = BeamGeometry(res.pattern)
            self.n = int(np.count_nonzero(res.cls != CLASS_CODES["escape"]))

    def _blocks(self):
        """(a, b, kept beams of rows [a, b) as flat indices from row a, their rows, columns),
        in firing order."""
        rows = max(1, CHUNK_POINTS // self.m)
        for a in range(0, self.res.shape[0], rows):
            b = min(a + rows, self.res.shape[0])
            cls = self.res.cls[a:b] if self.fire is None else self.res.cls[a:b][:, self.fire]
            flat = np.flatnonzero(cls != CLASS_CODES["escape"])
            i = flat // self.m  # not np.divmod: a third slower
            k = flat - i * self.m
            if self.fire is not None:  # position in firing order → column
                k = self.fire.take(k)
                flat = i * self.m + k
            yield a, b, flat, i + a, k

    def points(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fill ``xyz`` (3, n) with the points; their per-axis minimum and maximum."""
        lo, hi, at = np.full(3, np.inf), np.full(3, -np.inf), 0
        if self.echo_cols is not None:
            xyz[:] = self.echo_cols["xyz"].T
            return (xyz.min(axis=1), xyz.max(axis=1)) if self.n else (lo, hi)
        for a, b, flat, i, k in self._blocks():
            part = self.geometry.points_m(i, k, self.res.range_m[a:b].reshape(-1).take(flat),
                                          out=xyz[:, at:at + len(flat)])
            if len(flat):  # while the block is in cache
                lo, hi = np.minimum(lo, part.min(axis=1)), np.maximum(hi, part.max(axis=1))
            at += len(flat)
        return lo, hi

    def columns(self):
        """The other columns of :func:`las_record` (but ``xyz``, ``source``), piece by piece."""
        if self.echo_cols is not None:
            cols = self.echo_cols
            for a in range(0, self.n, CHUNK_POINTS):
                part = {key: v[a:a + CHUNK_POINTS] for key, v in cols.items() if key != "xyz"}
                yield part
            return
        res = self.res
        for a, b, flat, i, k in self._blocks():
            n = len(flat)
            cols = {"cls": res.cls[a:b].reshape(-1).take(flat), "range": res.range_m[a:b].reshape(-1).take(flat),
                    "elem": res.element_id[a:b].reshape(-1).take(flat),
                    "tree": (res.tree_id[a:b].reshape(-1).take(flat) if res.tree_id is not None
                             else np.full(n, NO_ID, np.uint32)),
                    "gps": row_times_s(res.pattern, self.first_row, a, b)[0].reshape(-1).take(flat),
                    "i": i, "k": k}
            cols["angle"], cols["elev"], cols["azim"] = self.angles(i, k)
            if self.with_echoes:  # a first-return leg among echo legs: one return per pulse
                cols.update(ret=np.ones(n, np.uint8), nret=np.ones(n, np.uint8), intensity=np.zeros(n, np.uint16),
                            width=np.zeros(n, np.float32), energy=np.zeros(n, np.float32))
            yield cols


class RecordWriter:
    """laspy's writer for ``header``, fed blocks of points packed into one reused record.

    ``lo_m``, ``hi_m``: the per-axis minimum and maximum of every point to be written (None:
    no points), known beforehand (the offsets need the minimum anyway).  X = round((x − offset)
    / scale) is monotone in x, so the extremes of X, which laspy's ``header.grow`` takes from the
    records of every ``write_points`` call, are those of x: the header gets the same statistics
    (point count, mins, maxs, gps-time range, points by return) without a pass over the records,
    and the records go to laspy's point writer as they are.  Same bytes as
    ``write_points(las_record(…))`` (tests/test_las_fast.py).
    """

    def __init__(self, path: str | Path, header: laspy.LasHeader, lo_m, hi_m, *, compress: bool = False):
        self.ext = None
        if lo_m is not None:
            if not np.all(np.isfinite(np.concatenate([lo_m, hi_m]))):
                raise ValueError("a LAS point has a non-finite coordinate")
            self.ext = np.round((np.array([lo_m, hi_m], np.float64) - header.offsets) / header.scales)
            for c, name in enumerate("xyz"):
                if self.ext[1, c] > _INT32.max or self.ext[0, c] < _INT32.min:
                    raise OverflowError(f"{name} does not fit LAS int32 after offset and scale")
        # an empty file (atomic_file's) is opened without O_TRUNC: ext4 starts the write-back
        # of a file truncated to zero when it is closed (auto_da_alloc), 2-30 ms here
        empty = Path(path).is_file() and Path(path).stat().st_size == 0
        import laspy  # noqa: PLC0415 - on first use (module docstring)
        # LAZ: laspy's LAZ writer over lazrs, fed the same packed records (chunks of 50 000
        # points compressed as they fill, so the write stays streamed; module docstring)
        laz = {"do_compress": True, "laz_backend": laspy.LazBackend.LazrsParallel} if compress else {}
        self.writer = laspy.open(open(path, "r+b" if empty else "wb"), mode="w", header=header, **laz)
        zero_extra_bytes_stats(self.writer.header)
        self.packed = laspy.PackedPointRecord
        self.record = np.zeros(0, header.point_format.dtype())
        self.gps = [np.inf, -np.inf]
        self.returns = np.zeros(16, np.uint64)

    def write(self, xyz: np.ndarray, cols: dict, *, leg: int, with_tree: bool, with_echoes: bool) -> None:
        """Points ``xyz`` (3, n) and their ``cols`` (``las_record``'s but ``xyz`` and ``source``)."""
        n = xyz.shape[1]
        if not n:
            return
        if len(self.record) < n:
            self.record = np.zeros(max(n, CHUNK_POINTS), self.record.dtype)
        arr = self.record[:n]  # every field written below is written for every point
        h, t = self.writer.header, np.empty(n, np.float64)
        for c, name in enumerate("XYZ"):  # laspy's x setter: round((x - offset) / scale)
            np.subtract(xyz[c], h.offsets[c], out=t)
            np.divide(t, h.scales[c], out=t)
            np.round(t, out=t)
            arr[name] = t
        arr["point_source_id"] = leg
        rec = self.packed(arr, h.point_format)
        _fill_fields(arr, rec, cols, with_tree=with_tree, with_echoes=with_echoes)
        if with_echoes:
            self.returns += np.bincount(cols["ret"], minlength=16).astype(np.uint64)
        else:  # first returns: return 1 of 1
            self.returns[1] += n
        self.gps = [min(self.gps[0], cols["gps"].min()), max(self.gps[1], cols["gps"].max())]
        self.writer.point_writer.write_points(rec)  # laspy 2.x: what write_points does after grow
        h.point_count += n

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        h = self.writer.header
        if h.point_count and exc_type is None:  # header.grow's statistics (class docstring)
            h.mins = self.ext[0] * h.scales + h.offsets
            h.maxs = self.ext[1] * h.scales + h.offsets
            h.min_gps_time, h.max_gps_time = self.gps
            h.number_of_points_by_return += self.returns[1:]
        self.writer.__exit__(exc_type, exc, tb)


def las_header(offsets_m, time_kind: str, *, with_tree: bool, with_echoes: bool = False,
               crs: str | None = None, sensor: dict | None = None, scales=None,
               energy_max: float = 0.0) -> laspy.LasHeader:
    """The LAS header of a scan (module docstring) with the given offsets and scales (default
    0.1 mm; :class:`~simlidar_mi.io.las_fields.ScaleChooser`); ``energy_max``, the scan's largest
    echo energy, sets the intensity scale that VLR record 2 states."""
    import laspy  # noqa: PLC0415 - on first use (module docstring)
    from laspy.vlrs.known import WktCoordinateSystemVlr  # noqa: PLC0415
    header = laspy.LasHeader(point_format=6, version="1.4")
    range_text = "echo range (m)" if with_echoes else "first-return range (m)"
    with_energy = with_echoes and bool((sensor or {}).get("intensity"))
    header.add_extra_dims([
        laspy.ExtraBytesParams("range_m", np.float32, description=range_text),
        laspy.ExtraBytesParams("scan_position", np.uint32, description="sweep index i"),
        laspy.ExtraBytesParams("scan_angle_index", np.uint32, description="angle index k"),
        laspy.ExtraBytesParams("elevation_deg", np.float32, description="beam elevation above horizon"),
        laspy.ExtraBytesParams("azimuth_deg", np.float32, description="beam azimuth, ccw from +x"),
        laspy.ExtraBytesParams("branch_id", np.uint32, description="element id", no_data=[NO_ID]),
        *([laspy.ExtraBytesParams("tree_id", np.uint32, description="tree or plant id", no_data=[NO_ID])]
          if with_tree else []),
        *([laspy.ExtraBytesParams("echo_width_ns", np.float32, description="echo FWHM width (ns)")]
          if with_echoes else []),
        *([laspy.ExtraBytesParams("echo_energy", np.float32, description="echo energy E, unclipped")]
          if with_energy else []),
    ])
    # No min/max statistics in the Extra Bytes record: laspy 2.7 fills them from one
    # point per write_points call, so they were wrong and changed with the chunk size
    # (issue #8). With the option bits clear, readers ignore those fields.
    for eb in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        eb.options &= ~(eb.MIN_BIT_MASK | eb.MAX_BIT_MASK)
    header.scales = np.full(3, SCALES_M[-1]) if scales is None else np.asarray(scales, np.float64)
    header.offsets = np.asarray(offsets_m, np.float64)
    header.generating_software = "simlidar-mi"
    header.system_identifier = "SIMULATION"  # §2.4: "a string identifying the operation"
    # LAS 1.4 R15: the WKT bit must be set for point formats 6-10, CRS or not
    header.global_encoding.wkt = True
    if crs is not None:
        header.vlrs.append(WktCoordinateSystemVlr(crs_wkt(crs)))
    header.vlrs.append(laspy.VLR("simlidar-mi", 1, "gps_time definition",
                                 (f"gps_time: {time_kind}\0").encode("ascii")))
    if with_echoes:
        text = (intensity_text(scan_intensity_scale(energy_max), energy_max) if with_energy
                else "intensity = 0: [sensor] intensity is off")
        header.vlrs.append(laspy.VLR("simlidar-mi", 2, "intensity scale", (text + "\0").encode("ascii")))
        header.vlrs.append(laspy.VLR("simlidar-mi", 3, "sensor (JSON)",
                                     json.dumps(sensor, sort_keys=True, default=_plain).encode("utf-8")))
    return header


def zero_extra_bytes_stats(header: laspy.LasHeader) -> None:
    """Zero the min and max fields of every Extra Bytes descriptor, which laspy's writer sets
    to ±float max: LAS 1.4 §4 ("Extra Bytes") requires unused fields to be zero."""
    for eb in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        np.frombuffer(eb._min, np.uint8)[:] = 0  # laspy's ctypes fields, 24 bytes each
        np.frombuffer(eb._max, np.uint8)[:] = 0


def las_record(header: laspy.LasHeader, cols: dict, *, with_tree: bool, with_echoes: bool = False):
    """One point record of ``cols`` (:func:`_echo_points`' columns), packed field by field into the
    record's numpy array (``PackedPointRecord.array``) with the operations laspy's setters use
    (x = round((x − offset) / scale), plain fields cast on assignment): the same bytes, without
    laspy's per-field dispatch (issue #8: a third of the streamed LAS write)."""
    pts = cols["xyz"]
    import laspy  # noqa: PLC0415 - on first use (module docstring)
    rec = laspy.ScaleAwarePointRecord.zeros(len(pts), header=header)
    arr = rec.array
    for c, name in enumerate("XYZ"):
        v = np.round((pts[:, c] - header.offsets[c]) / header.scales[c])
        if len(v) and (v.max() > _INT32.max or v.min() < _INT32.min):
            raise OverflowError(f"{name.lower()} does not fit LAS int32 after offset and scale")
        arr[name] = v
    arr["point_source_id"] = cols["source"]
    _fill_fields(arr, rec, cols, with_tree=with_tree, with_echoes=with_echoes)
    return rec


def _fill_fields(arr: np.ndarray, rec, cols: dict, *, with_tree: bool, with_echoes: bool) -> None:
    """The fields both writers fill alike from ``cols`` (all but X/Y/Z, scan angle and source):
    into the record's array ``arr``, the return bit fields through ``rec`` (laspy's setter)."""
    arr["scan_angle"] = cols["angle"]
    arr["elevation_deg"] = cols["elev"]
    arr["azimuth_deg"] = cols["azim"]
    arr["classification"] = LAS_CLASS_LUT[cols["cls"]]
    arr["gps_time"] = cols["gps"]
    arr["range_m"] = cols["range"]
    arr["scan_position"] = cols["i"]
    arr["scan_angle_index"] = cols["k"]
    arr["branch_id"] = cols["elem"]
    if with_tree:
        arr["tree_id"] = cols["tree"]
    if with_echoes:
        if len(arr) and max(cols["ret"].max(), cols["nret"].max()) > 15:
            raise ValueError("LAS point format 6 holds at most 15 returns per pulse; "
                             f"this scan has {int(cols['nret'].max())}")
        rec["return_number"] = cols["ret"]  # bit fields: laspy's own setter
        rec["number_of_returns"] = cols["nret"]
        arr["intensity"] = cols["intensity"]
        arr["echo_width_ns"] = cols["width"]
        if "echo_energy" in arr.dtype.names:
            arr["echo_energy"] = cols["energy"]
    else:  # a first-return scan: return 1 of 1 (LAS 1.4 §2.6 "Return Number")
        arr["bit_fields"] = 0x11  # return number (bits 0-3) 1, number of returns (bits 4-7) 1


def _echo_points(res: ScanRecord, leg: int, times_s: np.ndarray) -> dict:
    """Per-point columns of a ``[sensor]`` leg: its echoes (module docstring), in firing order."""
    m = res.shape[1]
    echoes = res.echoes
    p = res.pattern
    fire = firing_order(p)
    order = firing_sort(echoes.beam, m, fire) if fire is not None else None
    pick = (lambda v: v) if order is None else (lambda v: np.asarray(v)[order])  # noqa: E731
    i_idx, k_idx = np.divmod(pick(np.asarray(echoes.beam, np.int64)), m)
    origin = p.row_origin_m[i_idx]
    velocity, col_time = getattr(p, "velocity_m_s", None), getattr(p, "col_time_s", None)
    if velocity is not None and col_time is not None:  # fired from where the platform was
        origin = origin + np.asarray(col_time, np.float64)[k_idx, None] * np.asarray(velocity, np.float64)
    rng = pick(np.asarray(echoes.range_m, np.float64))
    energy = pick(echoes.energy)
    cols = {"xyz": origin + rng[:, None] * p.world_dirs()[i_idx, k_idx],
            "cls": pick(echoes.cls), "range": rng.astype(np.float32), "elem": pick(echoes.element_id),
            "tree": (pick(echoes.tree_id) if echoes.tree_id is not None
                     else np.full(len(i_idx), NO_ID, np.uint32)),
            "gps": times_s[i_idx, k_idx], "ret": pick(echoes.return_number), "nret": pick(echoes.number_of_returns),
            "energy": np.asarray(energy, np.float32),  # intensity: set_echo_intensities
            "width": pick(np.asarray(echoes.width_ns, np.float32))}
    cols["angle"], cols["elev"], cols["azim"] = BeamAngles(p)(i_idx, k_idx)
    cols["i"], cols["k"] = i_idx, k_idx
    cols["source"] = np.full(len(i_idx), leg)
    return cols


def _plain(value):
    """numpy scalars and arrays as JSON values."""
    return value.tolist() if hasattr(value, "tolist") else str(value)
