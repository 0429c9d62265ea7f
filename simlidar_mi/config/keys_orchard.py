"""Scene-file keys of leafy apple orchards: ``[orchard.leaves]`` and the row spacing in ``[orchard]``.

Merged section by section into :data:`simlidar_mi.config.keys.SECTIONS` at the end of that
file: ``[orchard]`` keeps its own keys and gains ``row_spacing_m``. Key and the checks come
from :mod:`simlidar_mi.config.keys_base`, so this module does not import config.keys (no
import cycle, either import order works). The laws behind the keys are
documented in :mod:`simlidar_mi.plants.apple_leaves` and :mod:`simlidar_mi.plants.leaf_angles`.
"""
from __future__ import annotations

import math

from .keys_base import FLOAT, INT, STR, Key, at_least, nonneg, one_of, positive, unit_interval

#: de Wit's (1965) named leaf inclination laws (plus the uniform one).
LEAF_ANGLE_LAWS = ("spherical", "uniform", "planophile", "erectophile", "plagiophile", "extremophile")


def _angle_law(v) -> str | None:
    if isinstance(v, str):
        return None if v in LEAF_ANGLE_LAWS else (
            f"must be one of {', '.join(LEAF_ANGLE_LAWS)} or a list of [angle_deg, frequency]")
    pairs = [p for p in v if isinstance(p, list) and len(p) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in p)]
    if not v or len(pairs) != len(v):
        return "must be a law name or a non-empty list of [angle_deg, frequency] pairs"
    edges = [p[0] for p in v]
    if edges[0] <= 0 or edges[-1] > 90 or any(b <= a for a, b in zip(edges, edges[1:])):
        return "class upper edges (angle_deg) must increase strictly within (0, 90] degrees"
    if any(p[1] < 0 for p in v) or sum(p[1] for p in v) <= 0:
        return "frequencies must be ≥ 0 and not all zero"
    return None


def _even_sides(v) -> str | None:
    return None if v >= 4 and v % 2 == 0 else "must be an even number ≥ 4"


SECTIONS: dict[str, dict[str, Key]] = {
    "orchard": {  # added to the [orchard] keys of config/keys.py
        "row_spacing_m": Key(FLOAT, 4.0, positive, "distance between rows; the row's ground area "
                             "n_trees × spacing_m × row_spacing_m is the LAI's denominator"),
    },
    "orchard.leaves": {
        "season": Key(STR, "dormant", one_of("dormant", "leaf-on"),
                      "dormant: wood only (the paper's leafless trees); leaf-on: leaves on young shoots"),
        "defoliation": Key(FLOAT, 0.0, unit_interval, "share of each tree's leaves removed at random"),
        "last_generations": Key(INT, 2, at_least(1), "shoots of the last G generations carry leaves "
                                "(segments of order > iterations − G)"),
        "leaves_per_m": Key(FLOAT, 40.0, positive, "mean leaves per metre of leaf-bearing shoot"),
        "outer_weight": Key(FLOAT, 1.0, nonneg, "β of the outer-crown law λ ∝ 1 + β·r "
                            "(r = relative distance from the trunk axis); 0 = uniform"),
        "petiole_length_m": Key(FLOAT, 0.025, nonneg, "bark to blade base (not drawn)"),
        "petiole_angle_deg": Key(FLOAT, 45.0, lambda v: None if 0 <= v <= 180 else "must lie in [0, 180]",
                                 "petiole angle from the shoot axis"),
        "length_mean_m": Key(FLOAT, 0.085, positive, "blade length ℓ (truncated normal, ±2 SD)"),
        "length_sd_m": Key(FLOAT, 0.015, nonneg, "SD of the blade length"),
        "width_ratio_mean": Key(FLOAT, 0.6, positive, "blade width / length (truncated normal, ±2 SD)"),
        "width_ratio_sd": Key(FLOAT, 0.05, nonneg, "SD of the blade width / length"),
        "sides": Key(INT, 8, _even_sides, "blade = a fan of this many triangles (an inscribed "
                     "k-gon of the ℓ × w ellipse; area (k/8)·sin(2π/k)·ℓw, k = 8: 0.707·ℓw)"),
        "angle_distribution": Key((str, list), "spherical", _angle_law,
                                  "leaf inclination law by name (spherical, uniform, planophile, "
                                  "erectophile, plagiophile, extremophile) or a table of "
                                  "[class upper edge in degrees, frequency]"),
    },
}
