"""Scene-file keys of ``[fisheye]``: virtual hemispherical photographs (``simlidar-mi fisheye``).

Placement: camera positions are laid out independently of where the plants stand, as regularly
spaced points on a grid or a transect (the Hemisfer guide's advice for hemispherical photographs,
P. Schleppi, https://www.schleppi.ch/patrick/hemisfer/help/en/photo.htm; in row plantations a
transect across the rows covers positions from the row to mid-alley).  The default is a 3 × 3
grid at the cell centres of the plants' horizontal extent, the camera looking up 1 m above the
ground (at the ground under plants lower than 2 m), north (+y) at the image top.
"""
from __future__ import annotations

import math

from .keys_base import FLOAT, INT, LIST, STR, Key, at_least, nonneg, one_of, within

PROJECTION_CHOICES = ("equidistant", "equisolid", "orthographic", "stereographic", "polynomial",
                      "FC-E8", "Nikkor-10.5", "Sigma-4.5", "Sigma-8", "FC-E9", "Nikkor-8")


def _finite_list(v, n=None) -> bool:
    return (isinstance(v, list) and (n is None or len(v) == n)
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v))


def coeffs(v):
    """list of numbers k_1 … k_n (ρ = Σ k_i θ^i, θ in radians, ρ relative to the image circle)"""
    return None if _finite_list(v) and len(v) >= 1 else "must be a non-empty list of numbers"


def box(v):
    """[x0, y0, x1, y1] in metres, x1 > x0 and y1 > y0"""
    if not _finite_list(v, 4):
        return "must be [x0, y0, x1, y1] in metres"
    return None if v[2] > v[0] and v[3] > v[1] else "needs x1 > x0 and y1 > y0"


def segment(v):
    """[x0, y0, x1, y1] in metres: the transect's first and last position"""
    return None if _finite_list(v, 4) else "must be [x0, y0, x1, y1] in metres"


def counts2(v):
    """[nx, ny], integers ≥ 1"""
    ok = isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) and x >= 1 for x in v)
    return None if ok else "must be two integers [nx, ny] ≥ 1"


def points2(v):
    """list of [x, y] positions in metres (at least one)"""
    ok = isinstance(v, list) and len(v) >= 1 and all(_finite_list(p, 2) for p in v)
    return None if ok else "must be a list of [x, y] pairs in metres"


def ring_edges(v):
    """increasing zenith edges within [0, 90] degrees (at least two)"""
    ok = _finite_list(v) and len(v) >= 2 and all(b > a for a, b in zip(v, v[1:])) and v[0] >= 0 and v[-1] <= 90
    return None if ok else "must be at least two increasing angles within [0, 90] degrees"


SECTIONS = {
    "fisheye": {
        "projection": Key(STR, "equidistant", one_of(*PROJECTION_CHOICES),
                          "lens projection: a standard one, a named calibrated lens (coefficients as "
                          "published; see simlidar_mi/canopy/fisheye_lens.py), or 'polynomial' with coeffs"),
        "coeffs": Key(LIST, None, coeffs, "polynomial lens coefficients k_1 … k_n: ρ = Σ k_i θ^i, θ in "
                      "radians, ρ the radius relative to the image circle's"),
        "format": Key(STR, "circular", one_of("circular", "fullframe"),
                      "circular: the 180° image circle inside a square image; fullframe: a 3:2 "
                      "frame whose diagonal spans 180°"),
        "resolution": Key(INT, 1024, at_least(8), "image width in pixels (circular images are square; "
                          "full-frame height = width / 1.5)"),
        "spp": Key(INT, 4, at_least(1), "samples (rays) per pixel; a pixel's coverage is their hit share"),
        "looking": Key(STR, "up", one_of("up", "down"), "up: a DHP from under the canopy; down: from above"),
        "height_m": Key(FLOAT, None, nonneg, "lens height above the ground (ground.z_m, else z = 0), "
                        "metres (default looking up: 1.0 under plants taller than 2 m, else 0 (a crop), and a "
                        "[random_leaves] plot's lens 3 leaf lengths below its lowest leaf; looking down: "
                        "1.0 above the highest plant)"),
        "tilt_deg": Key(FLOAT, 0.0, within(0, 90), "optical axis lean from the vertical, degrees"),
        "tilt_azimuth_deg": Key(FLOAT, 0.0, within(-360, 360), "scene azimuth the axis leans toward "
                                "(counter-clockwise from +x), degrees"),
        "heading_deg": Key(FLOAT, 90.0, within(-360, 360), "scene azimuth at the image top "
                           "(counter-clockwise from +x; 90 = +y), degrees"),
        "layout": Key(STR, "grid", one_of("grid", "transect", "points"),
                      "camera positions: a grid over area_m, a transect, or points_m"),
        "area_m": Key(LIST, None, box, "grid area [x0, y0, x1, y1], metres (default: the plants' "
                      "horizontal extent)"),
        "grid_n": Key(LIST, [3, 3], counts2, "grid positions along x and y, at the cell centres"),
        "transect_m": Key(LIST, None, segment, "transect from (x0, y0) to (x1, y1), metres (default: "
                          "across the middle of area_m along x)"),
        "transect_n": Key(INT, 5, at_least(1), "positions on the transect, evenly spaced, both ends included"),
        "points_m": Key(LIST, None, points2, "explicit positions [[x, y], ...], metres (layout 'points')"),
        "rings_deg": Key(LIST, [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0], ring_edges,
                         "zenith ring edges of the gap table, degrees from the optical axis"),
        "n_sectors": Key(INT, 8, at_least(1), "azimuth sectors of the gap table (the first starts at φ = 0, +x)"),
    },
}
