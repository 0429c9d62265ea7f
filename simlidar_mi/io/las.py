"""Scan hits → LAS 1.4 point clouds (laspy), in real coordinates.

Point format 6.  Classification follows ASPRS where it can: ground 2, leaves 5
(high vegetation); wood has no ASPRS class and uses 64 (user-definable range).
Extra dimensions: ``range_m`` (float32), ``scan_position`` (uint32, index i of the
sweep), ``scan_angle_index`` (uint32, k), ``branch_id`` (uint32), and ``tree_id``
(uint32) for scenes of several plants.  ``scan_angle``
holds the column angle (θ for the tractor) in the format's 0.006° units;
``point_source_id`` is the leg index for multi-leg scans, else the row index mod 65536.
Escapes are not written.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from ..geometry import CLASS_CODES
from .atomic import atomic_file

if TYPE_CHECKING:  # annotations only: io sits below the workflows
    from ..lidar.scan import ScanResult

LAS_CLASS = {CLASS_CODES["ground"]: 2, CLASS_CODES["leaf"]: 5, CLASS_CODES["wood"]: 64}


def write_scan_las(result: ScanResult | list[ScanResult], path: str | Path) -> Path:
    """Write every non-escape first return of ``result`` (or of several legs) to ``path``.

    With several results, ``point_source_id`` is the leg index and ``scan_position``
    counts rows within each leg.
    """
    results = result if isinstance(result, list) else [result]
    parts = []
    for leg, res in enumerate(results):
        keep = res.cls != CLASS_CODES["escape"]
        i_idx, k_idx = np.nonzero(keep)
        tree = res.tree_id[keep] if res.tree_id is not None else np.full(len(i_idx), 0xFFFFFFFF, np.uint32)
        parts.append((res.points_m()[keep], res.cls[keep], res.pattern.col_angle_deg[k_idx],
                      res.range_m[keep], i_idx, k_idx, res.element_id[keep],
                      np.full(len(i_idx), leg) if len(results) > 1 else i_idx % 65536, tree))
    pts, cls, theta, rng, i_idx, k_idx, elem, source, tree = (np.concatenate(c) for c in zip(*parts))
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
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = np.vectorize(LAS_CLASS.get, otypes=[np.uint8])(cls) if len(cls) else cls
    las.scan_angle = np.round(theta / 0.006).astype(np.int16)
    las.point_source_id = source.astype(np.uint16)
    las.range_m = rng
    las.scan_position = i_idx.astype(np.uint32)
    las.scan_angle_index = k_idx.astype(np.uint32)
    las.branch_id = elem
    if with_tree:
        las.tree_id = tree
    with atomic_file(path) as tmp:
        las.write(str(tmp))
    return Path(path)
