"""Scan hits → LAS 1.4 point clouds (laspy), in real coordinates.

Point format 6.  Classification follows ASPRS where it can: ground 2, leaves 5
(high vegetation); wood has no ASPRS class and uses 64 (user-definable range).
Extra dimensions: ``range_m`` (float32), ``scan_position`` (uint32, index i of the
sweep), ``scan_angle_index`` (uint32, k), ``branch_id`` (uint32), and ``tree_id``
(uint32) for scenes of several plants.  ``scan_angle``
holds the column angle (θ for the tractor) in the format's 0.006° units.
Escapes are not written.

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

``point_source_id`` is the leg index j of a multi-leg path (0, 1, …); a one-leg scan
(every other platform) has a single source, so it is 0 for every point, and
``scan_position`` holds the row.  A ``simlidar-mi`` VLR (record 1) repeats the
``gps_time`` definition used, as text.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np
from laspy.vlrs.known import WktCoordinateSystemVlr

from ..geometry import CLASS_CODES
from .atomic import atomic_file

if TYPE_CHECKING:  # annotations only: io sits below the workflows
    from ..lidar.scan import ScanResult

LAS_CLASS = {CLASS_CODES["ground"]: 2, CLASS_CODES["leaf"]: 5, CLASS_CODES["wood"]: 64}
#: Nominal duration of one row (sweep, azimuth step) for platforms without a pulse rate.
ROW_PERIOD_S = 1.0
TIME_PULSE = "pulse time: (i*M + k) / pulse_rate_hz seconds from the first pulse"
TIME_SCAN_ORDER = ("scan-order time, not measured: i + k/M on a nominal 1 s per row "
                   "(row i, column k of M), legs following each other")
TIME_BEAM = "beam emission time in seconds from the first beam (BeamPattern.beam_times_s)"


def scan_times_s(result: ScanResult, first_row: int = 0) -> tuple[np.ndarray, str]:
    """(N, M) float64 ``gps_time`` of every beam of ``result`` and the definition used.

    ``first_row`` shifts a path leg by the rows of the legs before it.  A pattern with a
    timing table (a tractor with a pulse rate, ``rotating``, ``rosette``) gives each beam its
    emission time, :meth:`~simlidar_mi.lidar.platforms.BeamPattern.beam_times_s`, already
    continuous across legs; else the airborne pattern's pulse times, else the scan-order time.
    """
    times = result.pattern.beam_times_s()
    if times is not None:
        how = (result.pattern.meta or {}).get("timing")
        return times, f"{TIME_BEAM}: {how}" if how else TIME_BEAM
    n, m = result.shape
    i = np.arange(n, dtype=np.float64)[:, None]
    k = np.arange(m, dtype=np.float64)[None, :]
    rate = (result.pattern.meta or {}).get("pulse_rate_hz")
    if rate:
        return (i * m + k) / float(rate), TIME_PULSE
    return (first_row + i + k / m) * ROW_PERIOD_S, TIME_SCAN_ORDER


def crs_wkt(crs: str) -> str:
    """OGC WKT (WKT1, as GDAL writes it) of an ``"EPSG:<code>"`` string, via pyproj."""
    import pyproj  # noqa: PLC0415 - only scenes that declare a CRS need it
    return pyproj.CRS.from_user_input(crs).to_wkt("WKT1_GDAL")


def write_scan_las(result: ScanResult | list[ScanResult], path: str | Path,
                   crs: str | None = None) -> Path:
    """Write every non-escape first return of ``result`` (or of several legs) to ``path``.

    With several results, ``point_source_id`` is the leg index and ``scan_position``
    counts rows within each leg.  ``crs`` (``"EPSG:<code>"``, the scene's
    ``[scene] crs``) is written as an OGC WKT record; None writes none.
    """
    results = result if isinstance(result, list) else [result]
    parts, first_row, time_kind = [], 0, TIME_SCAN_ORDER
    for leg, res in enumerate(results):
        keep = res.cls != CLASS_CODES["escape"]
        i_idx, k_idx = np.nonzero(keep)
        tree = res.tree_id[keep] if res.tree_id is not None else np.full(len(i_idx), 0xFFFFFFFF, np.uint32)
        t, time_kind = scan_times_s(res, first_row)
        first_row += res.shape[0]
        parts.append((res.points_m()[keep], res.cls[keep], res.pattern.col_angle_deg[k_idx],
                      res.range_m[keep], i_idx, k_idx, res.element_id[keep],
                      np.full(len(i_idx), leg), tree, t[keep]))
    pts, cls, theta, rng, i_idx, k_idx, elem, source, tree, gps = (np.concatenate(c) for c in zip(*parts))
    with_tree = any(r.tree_id is not None for r in results)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([
        laspy.ExtraBytesParams("range_m", np.float32, description="first-return range (m)"),
        laspy.ExtraBytesParams("scan_position", np.uint32, description="sweep index i"),
        laspy.ExtraBytesParams("scan_angle_index", np.uint32, description="angle index k"),
        laspy.ExtraBytesParams("branch_id", np.uint32, description="element id"),
        *([laspy.ExtraBytesParams("tree_id", np.uint32, description="tree or plant id")] if with_tree else []),
    ])
    header.scales = np.array([0.0001, 0.0001, 0.0001])  # 0.1 mm
    header.offsets = np.floor(pts.min(axis=0)) if len(pts) else np.zeros(3)
    header.generating_software = "simlidar-mi"
    # LAS 1.4 R15: the WKT bit must be set for point formats 6-10, CRS or not
    header.global_encoding.wkt = True
    if crs is not None:
        header.vlrs.append(WktCoordinateSystemVlr(crs_wkt(crs)))
    header.vlrs.append(laspy.VLR("simlidar-mi", 1, "gps_time definition",
                                 (f"gps_time: {time_kind}\0").encode("ascii")))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = np.vectorize(LAS_CLASS.get, otypes=[np.uint8])(cls) if len(cls) else cls
    las.scan_angle = np.round(theta / 0.006).astype(np.int16)
    las.point_source_id = source.astype(np.uint16)
    las.gps_time = gps
    las.range_m = rng
    las.scan_position = i_idx.astype(np.uint32)
    las.scan_angle_index = k_idx.astype(np.uint32)
    las.branch_id = elem
    if with_tree:
        las.tree_id = tree
    with atomic_file(path) as tmp:
        las.write(str(tmp))
    return Path(path)
