"""Scene-file keys of ``[lai_methods]``: gap-fraction LAI methods scored against the truth
(``simlidar-mi evaluate-photo``)."""
from __future__ import annotations

from .keys_base import FLOAT, INT, LIST, STR, Key, _finite, at_least, one_of, positive, within


def _ring_edges(v):
    if len(v) < 2 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return "must be a list of at least two zenith angles"
    if any(b <= a for a, b in zip(v, v[1:])) or v[0] < 0 or v[-1] >= 90:
        return "must increase strictly within [0, 90) degrees"
    return None


def _below_one(v):
    return _finite(v) or (None if 0 <= v < 1 else "must lie in [0, 1)")


def _opening(v):
    return _finite(v) or (None if 0 < v <= 360 else "must lie in (0, 360] degrees")


SECTIONS = {
    "lai_methods": {
        "sampler": Key(STR, "fisheye", one_of("fisheye", "rays"),
                       "how the sky is sampled at each [fisheye] position: the fisheye camera's "
                       "images (solid-angle-weighted ring/sector tables), or ray fans uniform in "
                       "solid angle per cell (no lens, no pixels)"),
        "rings_deg": Key(LIST, [0, 10, 20, 30, 40, 50, 60, 70], _ring_edges,
                         "zenith ring edges of the hemispherical methods (hemispheR's default: "
                         "7 rings to 70°), degrees"),
        "n_sectors": Key(INT, 8, at_least(1), "azimuth sectors per ring (Lang–Xiang averaging)"),
        "rays_per_cell": Key(INT, 256, at_least(1), "rays per ring × sector cell of the 'rays' sampler"),
        "zero_gap": Key(STR, "pai_sat", one_of("pai_sat", "pixel", "raise"),
                        "floor for a cell without gap: the saturating PAI's gap fraction, one pixel's "
                        "(or ray's) worth, or refuse"),
        "pai_sat": Key(FLOAT, 10.0, positive, "saturating plant area index of the 'pai_sat' floor "
                       "(CAN-EYE's default)"),
        "wood_to_total": Key(FLOAT, 0.0, _below_one, "woody share α of the plant area in the true-LAI "
                             "correction L = (1 − α)·L_e/Ω"),
        "view_cap_deg": Key(FLOAT, 360.0, _opening,
                            "LAI-2200 view cap: the azimuth opening left free (360, 270, 180, 90, 45)"),
        "heading_deg": Key(FLOAT, 0.0, _finite, "azimuth the open side of the view cap faces "
                           "(counter-clockwise from +x), degrees"),
        "sun_zenith_deg": Key(FLOAT, 30.0, within(0, 80, "at most 80°"),
                              "sun zenith of the Chen–Cihlar sunfleck transects, degrees"),
        "sun_azimuth_deg": Key(FLOAT, 90.0, _finite, "sun azimuth of the transects (counter-clockwise "
                               "from +x; the transects run along x), degrees"),
        "transect_step_m": Key(FLOAT, 0.002, positive, "spacing of the transects' sample points, metres"),
    },
}
