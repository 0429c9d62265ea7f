"""The range of every numeric scene-file key: one finite interval per key, checked at load.

Each entry of :data:`BOUNDS` is ``"section.key": (interval, why)``; the interval is written as
in mathematics, ``"[0, 1]"``, ``"(0, 1e4]"``, and applies to the key's value, or to every
number in it when the value is a list (``fisheye.grid_n``, ``forest.domain_m``, waypoints: each
element).  ``why`` says where the upper bound comes from.  :func:`apply` stores the parsed
:class:`Bounds` in each :class:`~simlidar_mi.config.keys_base.Key` (``Key.range``), so the schema
is the one source: :func:`simlidar_mi.config.load_scene` refuses a value outside it (or NaN,
infinity) with one line naming the file, the key, the value and the interval, and the docs'
scene-key reference prints the same interval.

The bounds are physical or machine limits on one key alone: the products of several keys
(pixels × samples × replicates, beams × sub-rays) are bounded by the work estimate of each
command (:mod:`simlidar_mi.config.work`).  Kept beside the key tables rather than in each
``Key(...)`` line so that the feature modules stay as they are.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Bounds:
    """A finite interval ``lo .. hi`` (each end open or closed) and why its upper end is there."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False
    why: str = ""

    def __str__(self) -> str:
        return (f"{'(' if self.lo_open else '['}{_num(self.lo)}, {_num(self.hi)}"
                f"{')' if self.hi_open else ']'}")

    def text(self) -> str:
        """The interval and its reason: ``[1, 15] (LAS 1.4 holds return numbers 1-15)``."""
        return str(self) + (f" ({self.why})" if self.why else "")

    def holds(self, v: float) -> bool:
        return (math.isfinite(v) and (v > self.lo if self.lo_open else v >= self.lo)
                and (v < self.hi if self.hi_open else v <= self.hi))

    def complaint(self, v, where: str = "") -> str | None:
        """None when every number in ``v`` lies inside; else why not (one line)."""
        for path, x in numbers(v):
            if not self.holds(x):
                at = f"element {path} " if path else ""
                if not math.isfinite(x):
                    side = "be a finite number"
                elif x < self.lo or (self.lo_open and x == self.lo):
                    side = f"be {'>' if self.lo_open else '≥'} {_num(self.lo)}"
                else:
                    side = f"be {'<' if self.hi_open else '≤'} {_num(self.hi)}"
                return f"{at}must {side}, range {self.text()}" + (f", got {x!r}" if path else "")
        return None


def _num(x: float) -> str:
    """1, 0.5, 1e9, 9e18, 1073741824: exact, and short where that is exact."""
    short = f"{x:g}"
    if float(x).is_integer() and (abs(x) < 1e6 or float(short) != x):
        return str(int(x))
    return short.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def numbers(v, path: str = ""):
    """Every number (not a boolean) in ``v`` with its place: ``("", v)`` for a scalar,
    ``("[1]", v[1])``, ``("[0][2]", …)`` in nested lists, ``("[0].x0_m", …)`` in tables."""
    if isinstance(v, bool):
        return
    if isinstance(v, (int, float)):
        yield path, v
    elif isinstance(v, list):
        for i, x in enumerate(v):
            yield from numbers(x, f"{path}[{i}]")
    elif isinstance(v, dict):
        for k, x in v.items():
            yield from numbers(x, f"{path}.{k}")


_INTERVAL = re.compile(r"\s*([\[(])\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*([\])])\s*")


def parse(text: str, why: str = "") -> Bounds:
    """``"(0, 1e4]"`` → Bounds(0, 1e4, lo_open=True)."""
    m = _INTERVAL.fullmatch(text)
    if m is None:
        raise ValueError(f"not an interval: {text!r}")
    lo, hi = float(m.group(2)), float(m.group(3))
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"not a finite interval: {text!r}")
    return Bounds(lo, hi, m.group(1) == "(", m.group(4) == ")", why)


# --- shared limits, each with its reason --------------------------------------------------
#: Scene coordinates, metres: a projected CRS's eastings and northings stay below 1e7 m
#: (UTM northings: 0-10 000 km); the float64 origin keeps such scenes precise.
COORD = ("[-1e7, 1e7]", "projected coordinates: UTM northings stay below 10 000 km")
ANGLE = ("[-360, 360]", "one turn either way")
SIZE = ("(0, 1000]", "metres: larger than any plant, post or plot spacing")
SMALL = ("(0, 10]", "metres: larger than any stem, leaf or wire")
SD = ("[0, 1000]", "a spread no plant layout reaches")
SHARE = ("[0, 1]", "a share")
REFL = ("[0, 1]", "a reflectance")
SPP = ("[1, 4096]", "samples per pixel: 4096 resolve a pixel's coverage to 1/4096, finer than "
                    "an 8-bit image's 1/255")
PIXELS = ("[8, 16384]", "16384² float32 pixels are 1 GiB per image")
SEED = ("[0, 9e18]", "TOML integers are 64-bit, below 2⁶³ ≈ 9.2e18")
KNOB_COUNT = ("[1, 1e13]", "a count no machine traces")

BOUNDS: dict[str, tuple[str, str]] = {
    # [scene]
    "scene.seed": SEED,
    "scene.facets": ("[3, 64]", "a 64-sided prism's area is within 0.2 % of the cylinder's"),
    "scene.origin_m": COORD,
    # [orchard], [orchard.tree], [orchard.leaves]
    "orchard.n_trees": ("[1, 10000]", "a 25 km row at the default spacing"),
    "orchard.spacing_m": SIZE, "orchard.row_x_m": COORD, "orchard.y_start_m": COORD,
    "orchard.row_spacing_m": SIZE,
    "orchard.tree.iterations": ("[1, 10]", "the paper studies 4-7; each generation multiplies "
                                          "the segments"),
    "orchard.tree.angle_deg": ANGLE, "orchard.tree.rotation_deg": ANGLE,
    "orchard.tree.d_min_m": ("(0, 1]", "metres: a branch diameter"),
    "orchard.tree.h0_m": ("(0, 10]", "metres: a trunk element"),
    "orchard.leaves.defoliation": SHARE,
    "orchard.leaves.last_generations": ("[1, 10]", "at most orchard.tree.iterations' bound"),
    "orchard.leaves.leaves_per_m": ("(0, 1000]", "a leaf per millimetre of shoot"),
    "orchard.leaves.outer_weight": ("[0, 100]", "β: λ grows 101-fold to the crown's edge"),
    "orchard.leaves.petiole_length_m": ("[0, 1]", "metres: a petiole"),
    "orchard.leaves.petiole_angle_deg": ("[0, 180]", "an angle from the shoot axis"),
    "orchard.leaves.length_mean_m": ("(0, 1]", "metres: a leaf blade"),
    "orchard.leaves.length_sd_m": ("[0, 1]", "metres: a leaf blade"),
    "orchard.leaves.width_ratio_mean": ("(0, 10]", "width / length of a blade"),
    "orchard.leaves.width_ratio_sd": ("[0, 10]", "width / length of a blade"),
    "orchard.leaves.sides": ("[4, 256]", "a 256-gon is the ellipse within 0.01 % of its area"),
    "orchard.leaves.angle_distribution": ("[0, 1e6]", "class edges ≤ 90°, frequencies"),
    # [forest], [[species]]
    "forest.domain_m": COORD,
    "forest.min_distance_m": ("[0, 1000]", "metres: no stand thins trees farther apart"),
    "forest.prototypes_per_species": ("[1, 1000]", "distinct trees drawn per species"),
    "forest.trees_per_prototype": ("[1, 1e6]", "more than any stand holds"),
    "forest.scale_range": ("(0, 100]", "a tree scaled 100-fold"),
    "forest.crown_factor": ("[0, 10]", "crowns 10 radii apart"),
    "forest.max_candidate_factor": ("[1, 1000]", "candidates drawn per tree kept"),
    "forest.max_trees": ("[1, 1e8]", "100 M trees: beyond one machine's memory"),
    "forest.leaf_table_max_rows": ("[0, 1e10]", "rows of a leaf table on disk"),
    "forest.export_facets": ("[3, 64]", "as scene.facets"),
    "forest.memory_limit_gb": ("(0, 1e6)", "GB: or 'auto', 90 % of physical memory"),
    "forest.export_max_triangles": ("[0, 1e10]", "triangles of one exported mesh file"),
    "forest.preview_max_trees": ("[1, 1e6]", "trees drawn in one picture"),
    "species.background_per_m2": ("[0, 100]", "trees per m²: more than one per 0.01 m²"),
    "species.bumps": ("[-1e14, 1e14]", "C_per_m2, x0_m, y0_m, h_m2, l_m2: finite, (h, l in m²: "
                                      "a 10 000 km wide bump)"),
    "species.leaf_length_tree_cv": ("[0, 0.3]", "a coefficient of variation of at most 30 %"),
    "species.n_daughters_tree_cv": ("[0, 0.3]", "a coefficient of variation of at most 30 %"),
    "species.leaves_per_branch_tree_cv": ("[0, 0.3]", "a coefficient of variation of at most 30 %"),
    # [ground], [terrain], [scan]
    "ground.z_m": COORD,
    "terrain.extent_m": COORD, "terrain.centre_m": COORD, "terrain.hills_m": COORD,
    "terrain.cell_m": ("(0, 1000]", "metres: a grid cell larger than any plot"),
    "terrain.slope_deg": ("[0, 89]", "degrees: a vertical wall has no height function"),
    "terrain.aspect_deg": ANGLE, "terrain.line_azimuth_deg": ANGLE,
    "terrain.ditch_depth_m": ("[0, 1e4]", "metres: deeper than any ditch"),
    "terrain.ditch_width_m": ("(0, 1e4]", "metres: wider than any ditch"),
    "terrain.step_m": ("[-1e4, 1e4]", "metres: higher than any cliff"),
    "scan.x0_m": COORD, "scan.z0_m": COORD, "scan.y_start_m": COORD, "scan.y_end_m": COORD,
    "scan.dy_m": ("(0, 1000]", "metres between sweeps"),
    "scan.gap": ("[0, 1e9]", "sweeps skipped"),
    "scan.dtheta_deg": ("(0, 360]", "one turn"),
    "scan.theta_min_deg": ("[-180, 180]", "a half turn either way"),
    "scan.theta_max_deg": ("[-180, 180]", "a half turn either way"),
    "scan.footprint": ("[0, 64]", "(P+1)² = 4225 sub-beams per beam"),
    "scan.escape_m": ("(0, 1e7]", "metres: a range beyond any scene"),
    "scan.max_beams": KNOB_COUNT, "scan.max_rays": KNOB_COUNT,
    "scan.chunk_beams": ("[1, 1073741824]", "2³⁰ beams per chunk"),
    # [platform]
    "platform.position_m": COORD, "platform.waypoints_m": COORD,
    "platform.start_xy_m": COORD, "platform.end_xy_m": COORD,
    "platform.elevation_deg": ANGLE, "platform.azimuth_deg": ANGLE,
    "platform.step_m": ("(0, 1e4]", "metres between sweeps"),
    "platform.scan_legs": ("[0, 1e6]", "leg indices"),
    "platform.altitude_m": ("(0, 1e5]", "metres: above any aircraft"),
    "platform.swath_deg": ("(0, 180]", "a half turn across track"),
    "platform.speed_m_s": ("(0, 1000]", "m/s: faster than any survey aircraft"),
    "platform.pulse_rate_hz": ("(0, 1e8]", "100 MHz: 10× the fastest scanners"),
    "platform.pulses_per_line": ("[1, 1e7]", "pulses across one scan line"),
    "platform.channels_deg": ("[-90, 90]", "elevations"),
    "platform.channel_offsets_us": ("[0, 1e6]", "µs: one second"),
    "platform.block_period_us": ("(0, 1e6]", "µs: one second"),
    "platform.rotation_hz": ("[-1000, 1000]", "head turns per second"),
    "platform.azimuth_range_deg": ("[-720, 720]", "two turns either way"),
    "platform.duration_s": ("(0, 86400]", "one day"),
    "platform.rosette_hz": ("[-1e5, 1e5]", "prism turns per second"),
    "platform.fov_deg": ("(0, 180)", "a hemisphere"),
    "platform.look_deg": ANGLE,
    # [sensor], [materials]
    "sensor.divergence_mrad": ("[0, 100]", "a laser beam of at most 0.1 rad; real scanners: "
                                          "0.1-25 mrad"),
    "sensor.beam_samples": ("[0, 4096]", "sub-rays per beam"),
    "sensor.max_returns": ("[1, 15]", "LAS 1.4 holds return numbers 1-15"),
    "sensor.pulse_length_ns": ("(0, 1000]", "ns: a 150 m long pulse"),
    "sensor.detection_threshold": ("(0, 1)", "a share of the emitted energy"),
    "sensor.range_min_m": ("[0, 1e7]", "metres: a range beyond any scene"),
    "sensor.range_max_m": ("(0, 1e7]", "metres: a range beyond any scene"),
    "sensor.range_noise_m": ("[0, 100]", "metres of range σ"),
    "sensor.range_noise_per_m": ("[0, 1]", "σ growing by the range itself"),
    "sensor.noise_ref_snr": ("(0, 1e12]", "an SNR of 120 dB"),
    "sensor.threshold_snr": ("(0, 1e12]", "an SNR of 120 dB"),
    "sensor.pulse_rate_hz": ("[0, 1e8]", "100 MHz: 10× the fastest scanners"),
    "sensor.range_at_10pct_m": ("(0, 1e5]", "metres: beyond any scanner's datasheet"),
    "sensor.wavelength_nm": ("[100, 20000]", "ultraviolet to far infrared lasers"),
    "materials.wood": REFL, "materials.leaf": REFL, "materials.ground": REFL,
    # [random_leaves]
    "random_leaves.n_leaves": ("[0, 1e9]", "leaves drawn; their memory is bounded by the work "
                                          "estimate"),
    "random_leaves.leaf_area_m2": ("(0, 100]", "m²: a 10 m leaf"),
    "random_leaves.plot_size_m": ("(0, 1e5]", "metres: a 100 km plot"),
    "random_leaves.height_range_m": ("[-1e4, 1e4]", "metres: any canopy's heights"),
    "random_leaves.n_sides": ("[3, 1024]", "a 1024-gon is the disc within 0.001 % of its area"),
    # [strawberry], [strawberry.leaf]
    "strawberry.rows": ("[1, 100000]", "rows of one plot"),
    "strawberry.plants_per_row": ("[1, 100000]", "plants of one row"),
    "strawberry.inter_row_m": ("(0, 100]", "metres between rows"),
    "strawberry.inter_row_sd_m": ("[0, 100]", "metres between rows"),
    "strawberry.intra_row_m": ("(0, 100]", "metres between plants"),
    "strawberry.intra_row_sd_m": ("[0, 100]", "metres between plants"),
    "strawberry.leaves_per_plant_mean": ("(0, 10000]", "leaves of one plant"),
    "strawberry.leaves_per_plant_sd": ("[0, 10000]", "leaves of one plant"),
    "strawberry.base_height_m": ("[0, 100]", "metres above the ground"),
    "strawberry.extraction_fractions": SHARE,
    "strawberry.extraction_counts": ("[0, 1e9]", "leaves removed"),
    **{f"strawberry.leaf.{k}": ("[0, 1]", "m²: a leaflet") for k in ("area_mean_m2", "area_sd_m2")},
    **{f"strawberry.leaf.{k}": ("[-100, 100]", "a ratio of leaflet lengths") for k in (
        "b_over_a_mean", "b_over_a_sd", "c_over_b_mean", "c_over_b_sd", "p_over_a_mean",
        "p_over_a_sd", "lateral_area_ratio", "lateral_b_over_a_factor", "lateral_c_over_b_factor")},
    **{f"strawberry.leaf.{a}_{s}_deg": ANGLE for a in ("alpha", "beta", "gamma", "lambda", "theta", "phi")
       for s in ("mean", "sd")},
    # [gapfraction], [photo_render]
    "gapfraction.zeniths_deg": ("[0, 80]", "a view 10° above the horizon"),
    "gapfraction.azimuth_deg": ANGLE,
    "gapfraction.resolution": ("[1, 16384]", PIXELS[1]),
    "gapfraction.spp": SPP,
    "gapfraction.window_fraction": ("(0, 1]", "a share of the image"),
    "gapfraction.margin_m": ("[0, 1e4]", "metres: wider than any plot"),
    "gapfraction.fov_deg": ("(0, 170)", "a perspective camera"),
    "gapfraction.camera_height_m": ("(0, 1e4]", "metres above the canopy"),
    "gapfraction.replicates": ("[1, 10000]", "plots averaged: the SD of the mean falls 100-fold"),
    "gapfraction.mask_threshold": ("(0, 1]", "a coverage"),
    "photo_render.leaf_rgb": REFL, "photo_render.soil_rgb": REFL,
    "photo_render.sun_irradiance": ("[0, 1e6]", "relative units"),
    "photo_render.sky_radiance": ("[0, 1e6]", "relative units"),
    "photo_render.sun_zenith_deg": ("[0, 90)", "a sun above the horizon"),
    "photo_render.sun_azimuth_deg": ANGLE,
    "photo_render.exposure": ("(0, 1e6]", "a linear gain"),
    "photo_render.spp": SPP,
    "photo_render.max_depth": ("[1, 64]", "after 64 bounces a canopy's albedo⁶⁴ < 1e-20"),
    # [vineyard], [vineyard.canopy]
    "vineyard.n_rows": ("[1, 10000]", "rows of one vineyard"),
    "vineyard.row_spacing_m": SIZE, "vineyard.first_row_x_m": COORD, "vineyard.y_start_m": COORD,
    "vineyard.vines_per_row": ("[1, 100000]", "vines of one row"),
    "vineyard.vine_spacing_m": SIZE, "vineyard.post_spacing_m": SIZE,
    "vineyard.post_height_m": ("(0, 100]", "metres: a trellis post"),
    "vineyard.post_diameter_m": SMALL, "vineyard.wire_diameter_m": SMALL,
    "vineyard.fruiting_wire_height_m": ("(0, 100]", "metres: a trellis wire"),
    "vineyard.catch_wire_heights_m": ("(0, 100]", "metres: a trellis wire"),
    "vineyard.catch_wire_spacing_m": SMALL,
    "vineyard.trunk_height_m": ("(0, 100]", "metres: a vine trunk"),
    "vineyard.trunk_diameter_m": SMALL, "vineyard.cordon_diameter_m": SMALL,
    "vineyard.cordon_gap_m": ("[0, 100]", "metres between arm tips"),
    "vineyard.max_elements": ("[1, 1e10]", "elements of one vineyard"),
    "vineyard.canopy.canopy_height_m": ("(0, 100]", "metres: a hedge"),
    "vineyard.canopy.canopy_width_m": ("(0, 100]", "metres: a hedge"),
    "vineyard.canopy.shoots_per_m": ("(0, 1000]", "a shoot per millimetre of cordon"),
    "vineyard.canopy.leaves_per_shoot": ("[1, 1000]", "nodes of one shoot"),
    "vineyard.canopy.shoot_diameter_m": SMALL,
    "vineyard.canopy.shoot_inclination_sd_deg": ("[0, 60]", "degrees"),
    "vineyard.canopy.shoot_azimuth_spread_deg": ("[0, 180]", "degrees"),
    "vineyard.canopy.leaf_area_mean_m2": ("(0, 1]", "m²: a vine leaf"),
    "vineyard.canopy.leaf_area_sd_m2": ("[0, 1]", "m²: a vine leaf"),
    "vineyard.canopy.leaf_inclination_mean_deg": ("[0, 90]", "degrees"),
    "vineyard.canopy.leaf_inclination_sd_deg": ("[0, 90]", "degrees"),
    "vineyard.canopy.leaf_azimuth_sd_deg": ("[0, 180]", "degrees"),
    "vineyard.canopy.leaf_roll_sd_deg": ("[0, 180]", "degrees"),
    "vineyard.canopy.petiole_length_ratio": ("(0, 10]", "petiole / midrib"),
    "vineyard.canopy.petiole_diameter_m": SMALL,
    "vineyard.canopy.petiole_elevation_deg": ("[-90, 90]", "degrees"),
    "vineyard.canopy.clusters_per_shoot": ("[0, 100]", "clusters of one shoot"),
    "vineyard.canopy.cluster_length_m": SMALL, "vineyard.canopy.cluster_diameter_m": SMALL,
    # [truth]
    "truth.voxel_m": ("(0, 1000]", "metres: a voxel wider than any plot"),
    "truth.margin_m": ("[0, 1e4]", "metres around the geometry"),
    "truth.row_spacing_m": SIZE,
    "truth.ground_area_m2": ("(0, 1e12]", "m²: a million km²"),
    "truth.raster_cell_m": ("[0.01, 1000]", "metres: 1 cm (finer than any scan's point spacing) to 1 km"),
    "truth.raster_subsamples": ("[1, 32]", "rays per cell side: 1024 rays a cell"),
    # [fisheye], [lai_methods]
    "fisheye.coeffs": ("[-100, 100]", "lens polynomial coefficients (published lenses: |k| < 2)"),
    "fisheye.resolution": PIXELS,
    "fisheye.spp": SPP,
    "fisheye.height_m": ("[0, 1e4]", "metres above the ground"),
    "fisheye.tilt_deg": ("[0, 90]", "degrees from the vertical"),
    "fisheye.tilt_azimuth_deg": ANGLE, "fisheye.heading_deg": ANGLE,
    "fisheye.area_m": COORD, "fisheye.transect_m": COORD, "fisheye.points_m": COORD,
    "fisheye.grid_n": ("[1, 1000]", "positions along one axis"),
    "fisheye.transect_n": ("[1, 100000]", "positions on a transect"),
    "fisheye.rings_deg": ("[0, 90]", "zenith angles"),
    "fisheye.n_sectors": ("[1, 3600]", "sectors of 0.1°"),
    "lai_methods.rings_deg": ("[0, 90)", "zenith angles"),
    "lai_methods.n_sectors": ("[1, 3600]", "sectors of 0.1°"),
    "lai_methods.rays_per_cell": ("[1, 10000000]", "rays per ring × sector cell"),
    "lai_methods.pai_sat": ("(0, 100]", "a plant area index"),
    "lai_methods.wood_to_total": ("[0, 1)", "a share"),
    "lai_methods.view_cap_deg": ("(0, 360]", "one turn"),
    "lai_methods.heading_deg": ANGLE, "lai_methods.sun_azimuth_deg": ANGLE,
    "lai_methods.sun_zenith_deg": ("[0, 80]", "at most 80°"),
    "lai_methods.transect_step_m": ("(0, 100]", "metres between sample points"),
    # [[primitive]]
    "primitive.p0_m": COORD, "primitive.p1_m": COORD, "primitive.min_m": COORD,
    "primitive.max_m": COORD,
    "primitive.diameter_m": ("(0, 1e4]", "metres: a cylinder"),
    "primitive.reflectance": REFL,
}

#: List-valued keys that hold no numbers (and so no range).
NOT_NUMERIC = frozenset({"gapfraction.cameras"})


def numeric(types: tuple, default) -> bool:
    """Whether a key of these types (and this default) holds numbers."""
    return (any(t in types for t in (int, float)) or
            (list in types and default is not None and any(True for _ in numbers(default))))


def apply(sections: dict, array_sections: dict) -> None:
    """Store each :data:`BOUNDS` entry in its Key (``Key.range``); a bound for a key that does
    not exist is a programming error, caught by any import of the package."""
    import dataclasses
    tables = {**sections, **array_sections}
    for dotted, (text, why) in BOUNDS.items():
        section, _, leaf = dotted.rpartition(".")
        if leaf not in tables.get(section, {}):
            raise RuntimeError(f"bounds for an unknown key {dotted}")
        tables[section][leaf] = dataclasses.replace(tables[section][leaf], range=parse(text, why))


# --- command-line options ------------------------------------------------------------------
def option(kind: type, interval: str, why: str = ""):
    """An argparse ``type=`` that reads an ``int`` or ``float`` and refuses a value outside
    ``interval`` (NaN and infinity included): argparse then names the option in one line."""
    import argparse
    bounds = parse(interval, why)

    def convert(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if kind is int else 'a number'} in {bounds.text()}, got {text!r}") from None
        problem = bounds.complaint(v)
        if problem:
            raise argparse.ArgumentTypeError(f"{problem}, got {text!r}")
        return v

    convert.__name__ = kind.__name__  # argparse's "invalid int value" names the type
    convert.bounds = bounds
    return convert


def option_list(interval: str, why: str = "", sizes: tuple[int, ...] = ()):
    """An argparse ``type=`` for comma-separated numbers, each inside ``interval``, their count
    one of ``sizes`` (any count ≥ 1 when empty)."""
    import argparse
    bounds = parse(interval, why)

    def convert(text: str) -> list[float]:
        try:
            vs = [float(t) for t in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
        if sizes and len(vs) not in sizes:
            raise argparse.ArgumentTypeError(
                f"expected {' or '.join(map(str, sizes))} comma-separated numbers, got {text!r}")
        problem = bounds.complaint(vs)
        if problem:
            raise argparse.ArgumentTypeError(problem)
        return vs

    convert.__name__ = "numbers"
    convert.bounds = bounds
    return convert
