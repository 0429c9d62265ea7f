"""Defaults of a scene file's ``[gapfraction]`` section (cameras, views, windows, rendering)."""
from __future__ import annotations

from typing import Any

__all__ = ["DEFAULTS"]

#: Defaults of the ``[gapfraction]`` section (see ``bench/gapfraction_bench.py``
#: for why resolution and spp are what they are).  ``replicates``: one 4 × 4-plant
#: strawberry plot's P0 scatters by SD 0.021–0.046 between seeds (inset window,
#: BENCHMARKS.md §2), so 16 plots bring the SD of their mean to ≤ 0.0115 (target 0.015).
DEFAULTS: dict[str, Any] = {
    "cameras": ["orthographic", "perspective"],
    "zeniths_deg": [0.0, 15.0, 30.0],
    "azimuth_deg": 0.0,
    "resolution": 1024,
    "spp": 4,
    "window": "auto",
    "window_fraction": 1.0,
    "margin_m": None,
    "fov_deg": 60.0,
    "camera_height_m": 1.0,
    "jitter": False,
    "mask_threshold": 0.5,
    "replicates": 16,
}
