"""Scene-file keys of ``[terrain]``: the ground as a DEM (GeoTIFF) or analytic relief.

A scene without ``[terrain]`` keeps the flat analytic plane of ``[ground]``; with it, the
ground is a triangulated height grid (:mod:`simlidar_mi.io.terrain`) on which trees and rows
stand.  Analytic forms add up: z = ground.z_m + plane + hills + ditch + step.
"""
from __future__ import annotations

import math

from .keys_base import FLOAT, LIST, STR, Key, _numbers, nonneg, one_of, positive, vec2, within


def _extent(v):
    return None if _numbers(v, 4) and v[1] > v[0] and v[3] > v[2] else \
        "must be [x_min, x_max, y_min, y_max] in metres with max > min"


def _hills(v):
    ok = isinstance(v, list) and all(_numbers(h, 4) and h[3] > 0 for h in v)
    return None if ok else "must be a list of [x_m, y_m, height_m, sigma_m] with sigma_m > 0"


def _azimuth(v):
    return None if math.isfinite(v) else "must be a finite number"


SECTIONS = {
    "terrain": {
        "file": Key(STR, None, None, "a GeoTIFF DEM (band 1, heights in metres, north-up, projected CRS "
                    "in metres; relative to the scene file); else the analytic keys below"),
        "nodata": Key(STR, "refuse", one_of("refuse", "nearest"),
                      "DEM cells without data: 'refuse' the file, or 'nearest': fill each from the "
                      "nearest valid cell (a warning says how many)"),
        "extent_m": Key(LIST, None, _extent, "analytic terrain: [x_min, x_max, y_min, y_max] it covers "
                        "(default: the forest domain and 20 m around it, else [-50, 50, -50, 50])"),
        "cell_m": Key(FLOAT, 1.0, positive, "analytic terrain: grid cell the relief is sampled on, "
                      "metres (the mesh is that grid, two triangles a cell)"),
        "centre_m": Key(LIST, None, vec2, "analytic terrain: [x, y] the plane turns about and the "
                        "ditch/step line passes through (default: the extent's centre)"),
        "slope_deg": Key(FLOAT, 0.0, within(0, 89), "analytic plane: slope, degrees from horizontal"),
        "aspect_deg": Key(FLOAT, 0.0, _azimuth, "analytic plane: the downhill direction, degrees "
                          "clockwise from north (+y); 90 faces east (+x)"),
        "hills_m": Key(LIST, [], _hills, "Gaussian hills [[x_m, y_m, height_m, sigma_m], …]: "
                     "height·exp(−r²/2σ²) each (a negative height: a hollow)"),
        "line_azimuth_deg": Key(FLOAT, 0.0, _azimuth, "ditch/step line direction, degrees clockwise "
                                "from north (+y), through centre_m"),
        "ditch_depth_m": Key(FLOAT, 0.0, nonneg, "V-shaped ditch along the line: depth at its axis"),
        "ditch_width_m": Key(FLOAT, 2.0, positive, "the ditch's width at the surface, metres"),
        "step_m": Key(FLOAT, 0.0, lambda v: None if math.isfinite(v) else "must be a finite number",
                      "a step up by this much right of the line (a ramp one cell wide on the grid)"),
    },
}
