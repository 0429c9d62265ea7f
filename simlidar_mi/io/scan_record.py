"""What the scan writers read of a scan, as a protocol: io sits below lidar and names no lidar type.

:class:`simlidar_mi.lidar.scan.ScanResult` satisfies it; so would any object with these arrays
(a user's own scan, a test's stand-in), which is the point of a writer layer.
"""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class ScanRecord(Protocol):
    """An N × M scan: per-beam first-return arrays, the beam pattern, and optional echoes."""

    settings: Any                      # the tractor's settings, or None for other platforms
    pattern: Any                       # beam origins, directions, timing (lidar.platforms.BeamPattern)
    range_m: np.ndarray                # float32 (N, M)
    cls: np.ndarray                    # uint8 (N, M): 0 escape, 1 ground, 2 wood, 3 leaf
    element_id: np.ndarray             # uint32 (N, M)
    hit_fraction: np.ndarray           # float32 (N, M)
    origin_m: np.ndarray               # float64 (3,): the scene's shift to real coordinates
    tree_id: np.ndarray | None
    echoes: Any                        # every echo (lidar.waveform.Echoes) or None
    n_returns: np.ndarray | None
    intensity: np.ndarray | None
    sensor: dict | None

    @property
    def shape(self) -> tuple[int, int]: ...

    def class_counts(self) -> dict[str, int]: ...
