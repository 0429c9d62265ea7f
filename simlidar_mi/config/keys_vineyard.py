"""Scene-file keys of the VSP vineyard (:mod:`simlidar_mi.plants.vineyard`).

``[vineyard]`` lays out rows, trellis and vine wood; ``[vineyard.canopy]`` the shoots,
leaves and clusters.  Cross-key rules (wires below the post top, catch-wire spacing
within the canopy width, …) are checked by :class:`~simlidar_mi.plants.vineyard.VineyardParams`.
"""
from __future__ import annotations

from .keys_base import BOOL, FLOAT, INT, LIST, Key, _finite, _numbers, at_least, nonneg, positive


def _heights(v):
    if not _numbers(v) or any(x <= 0 for x in v) or sorted(set(v)) != list(v):
        return "must be a list of increasing heights > 0 in metres (may be empty)"
    return None


def _angle(lo, hi):
    return lambda v: _finite(v) or (None if lo <= v <= hi else f"must lie in [{lo}, {hi}] degrees")


SECTIONS: dict[str, dict[str, Key]] = {
    "vineyard": {
        "n_rows": Key(INT, 1, at_least(1), "rows run along +y, side by side along x"),
        "row_spacing_m": Key(FLOAT, 2.2, positive, "distance between row centrelines (x)"),
        "first_row_x_m": Key(FLOAT, 0.0, _finite, "x of the first row's centreline"),
        "y_start_m": Key(FLOAT, 0.0, _finite, "y of the first end post"),
        "vines_per_row": Key(INT, 12, at_least(1), "row length = vines_per_row × vine_spacing_m"),
        "vine_spacing_m": Key(FLOAT, 1.0, positive, "distance between vines along the row"),
        "post_spacing_m": Key(FLOAT, 5.0, positive, "largest distance between posts (equal bays)"),
        "post_height_m": Key(FLOAT, 2.1, positive, "post top above the ground"),
        "post_diameter_m": Key(FLOAT, 0.08, positive, "trellis post diameter"),
        "wire_diameter_m": Key(FLOAT, 0.0025, positive, "every trellis wire"),
        "fruiting_wire_height_m": Key(FLOAT, 0.9, positive, "the cordon lies on this wire"),
        "catch_wire_heights_m": Key(LIST, [1.25, 1.6, 1.95], _heights,
                                    "foliage (catch) wire pairs, one wire each side of the canopy"),
        "catch_wire_spacing_m": Key(FLOAT, 0.3, positive, "distance between the two wires of a pair (x)"),
        "trunk_height_m": Key(FLOAT, None, positive, "head of the trunk; default the cordon's axis "
                              "height (fruiting wire + half wire and cordon diameters)"),
        "trunk_diameter_m": Key(FLOAT, 0.05, positive, "vine trunk diameter"),
        "cordon_diameter_m": Key(FLOAT, 0.03, positive, "the two arms along the fruiting wire"),
        "cordon_gap_m": Key(FLOAT, 0.06, nonneg, "gap between the arm tips of neighbouring vines"),
        "max_elements": Key(INT, 20_000_000, at_least(1), "refuse vineyards of more cylinders and leaf "
                            "triangles than this (counted from the keys before generating)", knob=True),
    },
    "vineyard.canopy": {
        "canopy_height_m": Key(FLOAT, 1.1, positive, "shoot zone: from the cordon's top to the hedge"),
        "canopy_width_m": Key(FLOAT, 0.45, positive, "shoot zone width across the row (x)"),
        "shoots_per_m": Key(FLOAT, 14.0, positive, "shoots per metre of cordon (Kliewer & Dokoozlian "
                            "2005, VSP: 14.0)"),
        "leaves_per_shoot": Key(INT, 24, at_least(1), "primary leaves per shoot, one per node (Kliewer & "
                                "Dokoozlian 2005, VSP: 24.0 nodes)"),
        "shoot_diameter_m": Key(FLOAT, 0.009, positive, "shoot (internode) diameter"),
        "shoot_inclination_sd_deg": Key(FLOAT, 12.0, _angle(0, 60),
                                        "SD of each internode's tilt from the vertical"),
        "shoot_azimuth_spread_deg": Key(FLOAT, 90.0, _angle(0, 180),
                                        "internode tilt azimuths uniform in ±spread/2 about the "
                                        "row direction, +y or −y (180: any direction)"),
        "leaf_area_mean_m2": Key(FLOAT, 0.0095, positive, "one-sided area of a leaf blade, mean "
                                 "(Kliewer & Dokoozlian 2005, VSP: 2280 cm² / 24 leaves)"),
        "leaf_area_sd_m2": Key(FLOAT, 0.00285, nonneg, "SD of the log-normal leaf area (30 %, unverified)"),
        "leaf_inclination_mean_deg": Key(FLOAT, 60.0, _angle(0, 90),
                                         "blade normal's angle from the vertical, mean"),
        "leaf_inclination_sd_deg": Key(FLOAT, 15.0, _angle(0, 90), "its SD"),
        "leaf_azimuth_sd_deg": Key(FLOAT, 30.0, _angle(0, 180),
                                   "SD of a petiole's azimuth about its distichous side"),
        "leaf_roll_sd_deg": Key(FLOAT, 20.0, _angle(0, 180), "SD of the midrib's turn in the blade plane"),
        "petiole_length_ratio": Key(FLOAT, 0.7, positive, "petiole length / blade midrib length"),
        "petiole_diameter_m": Key(FLOAT, 0.003, positive, "leaf petiole diameter"),
        "petiole_elevation_deg": Key(FLOAT, 30.0, _angle(-90, 90), "petiole above the horizontal"),
        "confine_leaves": Key(BOOL, True, None, "move blades that would leave the shoot zone back "
                              "into it (a hedged, positioned wall); false: they hang freely"),
        "clusters": Key(BOOL, False, None, "grape clusters as cylinder primitives labelled wood "
                        "(neither leaf area nor Branches wood in a ground truth)"),
        "clusters_per_shoot": Key(INT, 2, at_least(0), "on the basal nodes 2, 3, …"),
        "cluster_length_m": Key(FLOAT, 0.15, positive, "grape cluster length"),
        "cluster_diameter_m": Key(FLOAT, 0.08, positive, "grape cluster diameter"),
    },
}
