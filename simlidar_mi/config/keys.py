"""Every scene-file key: its type, default, check and one line of documentation.

:data:`SECTIONS` maps ``[section]`` names to their keys and :data:`ARRAY_SECTIONS` the
``[[array]]`` tables; :mod:`simlidar_mi.config` loads and validates files against them.
Feature modules with many keys keep them in their own ``*_keys`` module and are merged
at the end of this file.
"""
from __future__ import annotations

import math

# Key, the value types and the checks live in keys_base (feature key modules import
# them from there without importing this module); re-exported here for config.py and others.
from .keys_base import (BOOL, FLOAT, INT, LIST, STR, Check, Key, _epsg,  # noqa: F401
                               _finite, _numbers, at_least, azimuth, nonneg, one_of, positive,
                               range3, safe_name, unit_interval, vec2, vec3, waypoints, within)

#: Bounds of the [sensor] keys that size a scan's arrays, checked when the scene is read.
MAX_BEAM_SAMPLES = 4096  # sub-rays per beam; auto S stops at 256 (lidar/sensor.py)
MAX_RETURNS = 15  # LAS 1.4 point formats 6-10 hold return numbers 1-15 (4 bits)
#: Full-angle divergence: survey and automotive scanners lie within 0.1-25 mrad (the presets:
#: 0.35-15); beyond 0.1 rad the sub-ray layout (tangent offsets about the axis) and one echo
#: per surface stop describing a laser beam.
MAX_DIVERGENCE_MRAD = 100.0

SECTIONS: dict[str, dict[str, Key]] = {
    "scene": {
        "name": Key(STR, "scene", None, "the scene's name, shown in titles and file headers"),
        "seed": Key(INT, 0, nonneg, "master seed; every tree/plant gets a child stream"),
        "representation": Key(STR, "mesh", one_of("mesh", "cylinder", "linearcurve"),
                             "branch geometry: k-facet prism mesh, analytic cylinders or round curves"),
        "facets": Key(INT, 12, at_least(3), "prism facets k of the mesh representation"),
        "origin_m": Key(LIST, None, vec3, "float64 scene origin; default bbox centre"),
        "variant": Key(STR, "llvm_ad_mono", None, "Mitsuba variant (cuda_ad_mono on an NVIDIA GPU)"),
        "crs": Key(STR, None, _epsg, '"EPSG:<code>" of a projected CRS in metres that the scene '
                   "coordinates are in; written to points.las as an OGC WKT record"),
    },
    "orchard": {
        "n_trees": Key(INT, 1, at_least(1), "trees in the row"),
        "spacing_m": Key(FLOAT, 2.5, positive, "distance between trees along the row"),
        "row_x_m": Key(FLOAT, 3.0, _finite, "x of the tree row (the scanner looks along +x)"),
        "y_start_m": Key(FLOAT, 0.0, _finite, "y of the first tree"),
    },
    "orchard.tree": {
        "iterations": Key(INT, 5, at_least(1), "L-system generations Ns (the paper studies 4-7)"),
        "angle_deg": Key(FLOAT, 20.0, _finite, "turn of +/- about L"),
        "rotation_deg": Key(FLOAT, 20.0, _finite, "turn of T/t (R/r) about U"),
        "d_min_m": Key(FLOAT, 0.005, positive, "smallest branch diameter d_m (paper: 5, 6, 7 mm)"),
        "h0_m": Key(FLOAT, 0.4, positive, "trunk element length (order 1)"),
        "pruning": Key(BOOL, False, None, "remove the branches that descend in z"),
        "stochastic": Key(BOOL, False, None, "use the three-successor (stochastic) grammar"),
        "pruning_mode": Key(STR, "subtree", one_of("subtree", "segment"),
                            "subtree: a descending segment goes with everything growing from it; "
                            "segment: only the segment goes, its children float"),
    },
    # --- random forests (simlidar_mi.forest.params, seed 004 §III); species are [[species]] tables
    "forest": {
        "domain_m": Key(LIST, [0.0, 300.0, 0.0, 300.0], lambda v: None if _numbers(v, 4)
                        and v[1] > v[0] and v[3] > v[2]
                        else "must be [x_min, x_max, y_min, y_max] in metres with max > min",
                        "the rectangle trees are placed on"),
        "min_distance_m": Key(FLOAT, 3.0, nonneg, "no two trees closer than this (0: no thinning)"),
        "instancing": Key(BOOL, True, None, "true: K prototypes per species, placed with yaw/scale; "
                          "false: every tree its own random draw"),
        "prototypes_per_species": Key((int, str), 12, lambda v: None if v == "auto" or (
                                      isinstance(v, int) and 1 <= v <= 1000)
                                      else "must be 'auto' or a whole number in [1, 1000]",
                                      "K distinct trees per species (candidate i places i mod K); "
                                      "auto: candidate i places i // trees_per_prototype"),
        "trees_per_prototype": Key(INT, 5, at_least(1), "most trees placed per prototype (auto K)"),
        "scale_range": Key(LIST, [1.0, 1.0], lambda v: None if _numbers(v, 2) and 0 < v[0] <= v[1]
                           else "must be [min, max] with 0 < min ≤ max",
                           "uniform scale of instanced trees ([1, 1]: none)"),
        "scale_mode": Key(STR, "wood", one_of("wood", "whole-tree"),
                          "wood: one scale per prototype, wood only, leaves keep their size; "
                          "whole-tree: one per tree, leaves scaled too (earlier behaviour)"),
        "crown_factor": Key(FLOAT, 0.65, nonneg, "k of the crown rule d_ij ≥ k·(r_i + r_j); 0: none"),
        "max_candidate_factor": Key(FLOAT, 20.0, within(1, 1000),
                                    "(×, 1–1000) a [[species]] with count = 'stand' draws Poisson "
                                    "candidates up to this multiple of its intensity λ; if the thinning "
                                    "still keeps too few, forest.json reports the shortfall"),
        "max_trees": Key(INT, 100_000, at_least(1), "refuse forests with more trees", knob=True),
        "memory_limit_gb": Key((float, int, str), "auto", lambda v: None if v == "auto" or (
                               isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < 1e6)
                               else "must be 'auto' or a number of GB in (0, 1e6)",
                               "refuse, before growing or building it, a forest whose trees and scene "
                               "would hold more (GB; auto: 90 % of physical memory)", knob=True),
        "leaf_table": Key(STR, "auto", one_of("auto", "all", "prototypes", "none"),
                          "auto: 'all' up to leaf_table_max_rows leaves, else 'prototypes' (instancing) or 'all'"),
        "leaf_table_max_rows": Key(INT, 1_000_000, at_least(0), "limit of leaf_table = 'auto'"),
        "leaf_table_format": Key(STR, "auto", one_of("auto", "parquet", "csv"),
                                 "auto: parquet (csv only where pyarrow cannot be imported)"),
        "export": Key(STR, "auto", one_of("auto", "stand", "prototypes", "none"),
                      "auto: the whole stand up to export_max_triangles, else one file per prototype"),
        "export_format": Key(STR, "ply", one_of("ply", "obj"), "binary PLY or text OBJ"),
        "export_facets": Key(INT, 6, at_least(3), "prism facets of exported branches"),
        "export_max_triangles": Key(INT, 20_000_000, at_least(0), "limit of export = 'auto'"),
        "preview_max_trees": Key(INT, 300, at_least(1), "trees drawn in preview.png (a central strip)"),
        "truth_rasters": Key(BOOL, False, None, "also cast the truth rasters over the domain (truth_dtm, "
                             "truth_dsm, truth_chm, truth_tree_id .tif at [truth] raster_cell_m and "
                             "raster_subsamples) and add top_cells and overtopped to trees.csv: a Mitsuba "
                             "scene and k² vertical rays a cell (the forest command's --truth-rasters)"),
    },
    "ground": {
        "enabled": Key(BOOL, True, None, "a ground plane under the scene"),
        "z_m": Key(FLOAT, 0.0, _finite, "height of the ground plane"),
    },
    "scan": {
        "x0_m": Key(FLOAT, 1.0, _finite, "scanner line x"),
        "z0_m": Key(FLOAT, 1.0, _finite, "scanner height"),
        "y_start_m": Key(FLOAT, None, _finite, "first beam-centre y; default min y of the scene"),
        "y_end_m": Key(FLOAT, None, _finite, "last y; default max y of the scene"),
        "dy_m": Key(FLOAT, 0.002, positive, "tractor advance Δy between two sweeps"),
        "gap": Key(INT, 0, nonneg, "sweeps skipped between two recorded ones"),
        "dtheta_deg": Key(FLOAT, 0.25, positive, "angle step Δθ between two beams of a sweep"),
        "theta_min_deg": Key(FLOAT, None, _finite, "default −atan((z0 − ground z)/(x_near − x0)) (eq. 8)"),
        "theta_max_deg": Key(FLOAT, None, _finite, "default atan((max z − z0)/(x_near − x0)) (eq. 8)"),
        "theta_limits_side": Key(STR, "near", one_of("near", "far"),
                                 "x_near of eq. 8: 'near' = the wood nearest the scanner in the "
                                 "scanned y range (the paper's Max(x); the sweep covers the wood), "
                                 "'far' = the far side of the scene's bounding box (a narrower sweep)"),
        "footprint": Key(INT, 0, nonneg, "dot-matrix precision P: (P+1)² sub-beams"),
        "hit_rule": Key(STR, "fraction", one_of("fraction", "any"),
                        "P > 0: 'any' = a beam hits vegetation when any sub-beam does (the paper's "
                        "§3.1; A_IM counts the whole beam), 'fraction' = A_IM weights the beam by "
                        "its share of sub-beams that hit"),
        "escape_m": Key(FLOAT, 1000.0, positive, "range reported for beams that hit nothing"),
        "max_beams": Key(INT, 200_000_000, at_least(1), "refuse scans of more beams (dot-matrix "
                         "sub-beams counted) than this", knob=True),
        "max_rays": Key(INT, 1_000_000_000, at_least(1), "refuse scans of more rays than this: beams "
                        "× dot-matrix sub-beams × [sensor] sub-rays per beam; and renders of more "
                        "(images × pixels × samples; BENCHMARKS §15: about 20 min of tracing on 2 cores)",
                        knob=True),
        "points_format": Key(STR, "las", one_of("las", "laz"),
                             "the points file: 'las' = points.las (LAS 1.4), 'laz' = points.laz, the "
                             "same header and points LAZ-compressed (laspy's lazrs backend)"),
        "trajectory": Key(BOOL, False, None,
                          "write trajectory.txt: the platform's position and attitude per scan row "
                          "(x y z gps_time roll pitch yaw, HELIOS++'s columns; not for a static tripod)"),
        "chunk_beams": Key(INT, 1 << 22, at_least(1),
                           "beams traced and written per chunk (memory stays flat as scans grow; "
                           "results do not depend on it)", knob=True),
    },
    # --- gap fraction (simlidar_mi.canopy.gapfraction); generators validate their own laws too
    "platform": {  # where the scanner is; "tractor" uses [scan]'s x0_m/z0_m/dy_m/dtheta_deg
        "kind": Key(STR, "tractor", one_of("tractor", "static", "path", "airborne", "rotating", "rosette"),
                    "the scanner's platform (the keys below say which kinds they apply to)"),
        "position_m": Key(LIST, None, vec3, "static/rotating/rosette: scanner position (z = mount height)"),
        "elevation_deg": Key(LIST, [-30.0, 60.0, 0.25], range3, "static/path: [min, max, step]"),
        "azimuth_deg": Key((int, float, list), 0.0, azimuth, "static: one angle (2D) or [start, stop, step] (3D)"),
        "waypoints_m": Key(LIST, None, waypoints, "path/rotating/rosette: [[x, y, z], ...] straight legs "
                           "between points (z = mount height)"),
        "step_m": Key(FLOAT, 0.01, positive, "path: distance between sweeps"),
        "side": Key(STR, "right", one_of("right", "left"), "path: side the scanner looks to"),
        "scan_legs": Key(LIST, None, lambda v: None if v and all(
                         isinstance(j, int) and not isinstance(j, bool) and j >= 0 for j in v)
                         and v == sorted(set(v)) else "must be a non-empty list of increasing leg indices ≥ 0",
                         "path: legs scanned (leg j: waypoint j → j+1; default all); the others "
                         "are driven unscanned (headland turns); point_source_id = position in this list"),
        "start_xy_m": Key(LIST, None, vec2, "airborne: start of the flight line"),
        "end_xy_m": Key(LIST, None, vec2, "airborne: end of the flight line"),
        "altitude_m": Key(FLOAT, 100.0, positive, "airborne: height above the ground"),
        "swath_deg": Key(FLOAT, 40.0, positive, "airborne: full scan angle across track"),
        "speed_m_s": Key(FLOAT, None, positive, "platform speed; airborne default 30; tractor: with "
                         "[sensor] pulse_rate_hz, the tractor moves while it sweeps (default: it does not); "
                         "rotating/rosette along waypoints_m: required"),
        "pulse_rate_hz": Key(FLOAT, None, positive, "airborne (default 300000) and rosette (default "
                             "[sensor] pulse_rate_hz, else 100000): pulses per second"),
        "pulses_per_line": Key(INT, 400, at_least(1), "airborne: pulses across one scan line"),
        "channels_deg": Key(LIST, [-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0,
                                   13.0, -1.0, 15.0],
                            lambda v: None if v and _numbers(v) and all(-90 <= x <= 90 for x in v)
                            else "must be a non-empty list of elevations in [-90, 90] degrees",
                            "rotating: channel elevations (default the VLP-16's, in firing order)"),
        "channel_offsets_us": Key(LIST, [round(2.304 * k, 3) for k in range(16)],
                                  lambda v: None if _numbers(v) and all(x >= 0 for x in v)
                                  else "must be a list of firing delays ≥ 0 in microseconds",
                                  "rotating: each channel's firing delay within a block (VLP-16: k·2.304 µs)"),
        "block_period_us": Key(FLOAT, 55.296, positive, "rotating: time between firing blocks (VLP-16: 55.296 µs)"),
        "rotation_hz": Key(FLOAT, 10.0, lambda v: _finite(v) or (None if v != 0 else "must not be 0"),
                           "rotating: head turns per second (> 0 counter-clockwise seen from above)"),
        "azimuth_range_deg": Key(LIST, None, lambda v: None if _numbers(v, 2) and v[0] < v[1] <= v[0] + 360
                                 else "must be [start, stop] degrees with start < stop ≤ start + 360",
                                 "rotating: keep only firing blocks in this sector of head azimuth "
                                 "(from the heading, counter-clockwise; [-135, -45] = right-hand side)"),
        "duration_s": Key(FLOAT, None, positive, "static rotating/rosette: scan time (default one "
                          "revolution / one 0.1 s frame)"),
        "rosette_hz": Key(LIST, [7294.0 / 60.0, -4664.0 / 60.0],
                          lambda v: None if _numbers(v, 2) and v[0] != 0 and v[1] != 0 and v[0] != v[1]
                          else "must be [f1, f2], two different non-zero prism speeds in Hz",
                          "rosette: the two prisms' turns per second (Livox Mid-70: 7294 and −4664 rpm)"),
        "fov_deg": Key(FLOAT, 70.4, lambda v: None if 0 < v < 180 else "must lie in (0, 180) degrees",
                       "rosette: full angle of the circular field of view (Mid-70: 70.4°)"),
        "look_deg": Key(LIST, [0.0, 0.0], lambda v: None if _numbers(v, 2) and -90 <= v[1] <= 90
                        else "must be [azimuth, elevation] in degrees, elevation in [-90, 90]",
                        "rosette: axis of the field of view (azimuth from the heading / +x)"),
    },
    # --- real scanners (simlidar_mi.lidar.sensor): every effect off by default, and a scene
    # without [sensor] (or with every effect off) scans exactly as before
    "sensor": {
        "preset": Key(STR, None, lambda v: None if v.strip() else "must be a preset name or a path",
                      "a built-in sensor name or a preset .toml; the scene's own keys win"),
        "divergence_mrad": Key(FLOAT, 0.0, within(0, MAX_DIVERGENCE_MRAD, "a laser beam of at most "
                                                  "0.1 rad; real scanners: 0.1-25 mrad"),
                               "full-angle beam divergence γ (1/e² of a Gaussian "
                               "beam, edge of a uniform one); 0 = one ray per beam"),
        "beam_profile": Key(STR, "gaussian", one_of("gaussian", "uniform"),
                            "energy profile across the beam's cross-section"),
        "beam_samples": Key(INT, 0, within(0, MAX_BEAM_SAMPLES, "sub-rays per beam"),
                            "sub-rays S per beam when divergence > 0 (0 = auto, see "
                            "simlidar_mi.lidar.sensor.auto_beam_samples)"),
        "max_returns": Key(INT, 1, within(1, MAX_RETURNS, "LAS 1.4 holds return numbers 1-15"),
                           "1 = first return only; > 1 = echoes from the waveform"),
        "detection": Key(STR, "waveform", one_of("waveform", "nearest"),
                         "with divergence > 0: 'waveform' = a beam returns only echoes of its "
                         "waveform above detection_threshold (a real receiver), even with "
                         "max_returns = 1; 'nearest' = its nearest sub-ray hit, however small "
                         "its share of the beam (geometric, no energies)"),
        "pulse_length_ns": Key(FLOAT, 3.0, positive, "FWHM pulse duration τ; echoes closer than "
                               "c·τ/2 merge"),
        "detection_threshold": Key(FLOAT, 0.02, lambda v: _finite(v) or (
                                   None if 0 < v < 1 else "must lie in (0, 1)"),
                                   "echoes weaker than this share of the emitted energy are dropped"),
        "range_min_m": Key(FLOAT, 0.0, nonneg, "no return nearer than this"),
        "range_max_m": Key(FLOAT, None, positive, "no return farther than this (default unlimited)"),
        "echo_rule": Key(STR, "amplitude", one_of("amplitude", "basin"),
                         "waveform echoes: 'amplitude' = local maxima of the waveform reaching "
                         "detection_threshold, later peaks within c·τ/2 of a trigger join it (a "
                         "receiver); 'basin' = peaks merged by single linkage within c·τ/2, kept "
                         "when their integrated energy reaches the threshold (the former rule)"),
        "waveform_reader": Key(STR, "kernel", one_of("kernel", "numpy"),
                               "who reads a beam whose sub-rays meet one surface: 'kernel' = a Dr.Jit "
                               "kernel beside the trace (fast; range, width and amplitude may differ "
                               "from 'numpy' in their last bits: Dr.Jit's exp and log); 'numpy' = the "
                               "host detector for every beam (the bits before 0.1.0's kernel)"),
        "noise_model": Key(STR, "snr", one_of("snr", "range"),
                           "'snr': σ = range_noise_m·(width/τ)·sqrt(max(noise_ref_snr/SNR, 1)), SNR = "
                           "threshold_snr·E/detection_threshold (lidar/noise.py); 'range': σ = "
                           "(range_noise_m + range_noise_per_m·(r − 1 m))/max(|cos i|, 0.1)"),
        "range_noise_m": Key(FLOAT, 0.0, nonneg, "Gaussian range σ: at noise_ref_snr ('snr'), at 1 m "
                             "and normal incidence ('range')"),
        "range_noise_per_m": Key(FLOAT, 0.0, nonneg, "growth of σ per metre beyond 1 m ('range' only)"),
        "noise_ref_snr": Key(FLOAT, 100.0, positive, "'snr': the SNR from which range_noise_m holds (its floor)"),
        "threshold_snr": Key(FLOAT, 10.0, positive, "'snr': the SNR of an echo at detection_threshold "
                             "(an assumption where a data sheet gives none)"),
        "intensity": Key(BOOL, False, None, "compute echo energies (Lambertian law, sensor.py)"),
        "pulse_rate_hz": Key(FLOAT, 0.0, nonneg, "with a platform speed: each beam its own time and pose"),
        "range_at_10pct_m": Key(FLOAT, 40.0, positive, "datasheet range of a 10 % Lambertian target; "
                                "sets the energy constant R_ref"),
        "wavelength_nm": Key(FLOAT, None, positive, "informational, written to the headers"),
    },
    "materials": {  # reflectance at the sensor's wavelength, per class
        **{k: Key(FLOAT, d, unit_interval, f"{k} reflectance in [0, 1]")
           for k, d in (("wood", 0.35), ("leaf", 0.45), ("ground", 0.20))},
    },
    "random_leaves": {
        "n_leaves": Key(INT, 1000, nonneg, "number of flat leaves N (before periodic copies)"),
        "leaf_area_m2": Key(FLOAT, 0.001, positive, "one-sided area a of every leaf, m²"),
        "plot_size_m": Key(LIST, [1.0, 1.0], lambda v: None if len(v) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0
            for x in v) else "must be [width_x, length_y], two numbers > 0 (metres)",
            "periodic plot [0, w] × [0, l]"),
        "height_range_m": Key(LIST, [0.0, 0.5], lambda v: None if len(v) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in v) and v[0] <= v[1] else "must be [z_min, z_max], finite, z_min ≤ z_max (metres)",
            "leaf-centre heights, uniform"),
        "angle_law": Key(STR, "spherical", one_of("horizontal", "vertical", "spherical"),
                          "leaf inclination law"),
        "shape": Key(STR, "square", one_of("square", "disc"), "leaf outline"),
        "n_sides": Key(INT, 16, at_least(3), "polygon sides of a disc leaf"),
    },
    "strawberry": {
        "rows": Key(INT, 4, at_least(1), "rows run along x"),
        "plants_per_row": Key(INT, 4, at_least(1), "plants along each row"),
        "inter_row_m": Key(FLOAT, 0.268, positive, "Table 3: 0.268 ± 0.03 m"),
        "inter_row_sd_m": Key(FLOAT, 0.03, nonneg, "SD of the distance between rows"),
        "intra_row_m": Key(FLOAT, 0.227, positive, "Table 3: 0.227 ± 0.02 m"),
        "intra_row_sd_m": Key(FLOAT, 0.02, nonneg, "SD of the distance between plants of a row"),
        "leaves_per_plant_mean": Key(FLOAT, 42.0, positive, "Table 3: 42 ± 5"),
        "leaves_per_plant_sd": Key(FLOAT, 5.0, nonneg, "SD of the leaves per plant"),
        "base_height_m": Key(FLOAT, 0.0, nonneg, "petioles' start point above the ground"),
        "extraction_fractions": Key(LIST, None, lambda v: None if all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x <= 1 for x in v)
            and sum(v) <= 1 + 1e-9 else "must be a list of numbers in [0, 1] adding up to ≤ 1 "
            "(shares of the starting leaves removed at each step)",
            "default [0.1935, 0.1577, 0.1765]: shares of the starting leaves that make leaf area "
            "follow Table 4's real canopy (0.806/0.649/0.472 of the first); [1/6, 1/6, 1/6] is "
            "the text's sixths"),
        "extraction_counts": Key(LIST, None, lambda v: None if all(
            isinstance(x, int) and not isinstance(x, bool) and x >= 0 for x in v)
            else "must be a list of integers ≥ 0 (leaves removed at each step)",
            "option: fixed numbers of leaves removed (the paper's 44, 39, 44 fit only a "
            "~254-leaf canopy); excludes extraction_fractions"),
    },
    "strawberry.leaf": {  # StrawberryLeafParams; omitted keys keep the paper's Tables 1–3
        **{k: Key(FLOAT, None, _finite, doc) for k, doc in (
            ("area_mean_m2", "central-leaflet area S, mean (Table 3)"), ("area_sd_m2", "its SD"),
            ("b_over_a_mean", "central-leaflet length/width ratio, mean (Table 1)"), ("b_over_a_sd", "its SD"),
            ("c_over_b_mean", "relative position of the axes' crossing along the midrib, from the "
             "leaflet base, mean (Table 1)"), ("c_over_b_sd", "its SD"),
            ("p_over_a_mean", "petiole length / central-leaflet width, mean (Table 1)"), ("p_over_a_sd", "its SD"),
            ("lateral_area_ratio", "S'/S, lateral over central leaflet area (Table 1)"),
            ("lateral_b_over_a_factor", "(b'/a')/(b/a) (Table 1)"),
            ("lateral_c_over_b_factor", "(c'/b')/(c/b) (Table 1)"),
            ("alpha_mean_deg", "central-leaflet midrib fold α, mean (Table 2)"), ("alpha_sd_deg", "its SD"),
            ("beta_mean_deg", "lateral-leaflet midrib fold β, mean (Table 2)"), ("beta_sd_deg", "its SD"),
            ("gamma_mean_deg", "lift γ of the lateral leaflets out of the leaf plane, mean (Table 2)"),
            ("gamma_sd_deg", "its SD"),
            ("lambda_mean_deg", "leaf-plane inclination λ to the horizontal, mean (Table 2)"),
            ("lambda_sd_deg", "its SD"),
            ("theta_mean_deg", "petiole angle θ, mean (Table 2)"), ("theta_sd_deg", "its SD"),
            ("phi_mean_deg", "petiole angle φ, mean (Table 2)"), ("phi_sd_deg", "its SD"))},
        "petiole_zenith": Key(STR, None, one_of("phi", "theta"),
                              "which petiole angle is the zenith; the other is the divergence"),
    },
    "gapfraction": {
        "cameras": Key(LIST, ["orthographic", "perspective"], lambda v: None if v and all(
            x in ("orthographic", "perspective") for x in v) and len(set(v)) == len(v)
            else "must be a non-empty list of distinct 'orthographic' / 'perspective'",
            "camera models rendered"),
        "zeniths_deg": Key(LIST, [0.0, 15.0, 30.0], lambda v: None if v and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x <= 80 for x in v)
            and len(set(v)) == len(v) else "must be a non-empty list of distinct angles in [0, 80] degrees",
            "view zenith angles"),
        "azimuth_deg": Key(FLOAT, 0.0, _finite, "view azimuth relative to the rows (0 = along them)"),
        "resolution": Key(INT, 1024, at_least(1), "pixels on the long image side"),
        "spp": Key(INT, 4, at_least(1), "samples per pixel (stratified)"),
        "window": Key(STR, "auto", one_of("auto", "inset", "periodic"),
                      "analysis window: inset from the plot edges, or a periodic tiling"),
        "window_fraction": Key(FLOAT, 1.0, lambda v: None if 0 < v <= 1 else "must lie in (0, 1]",
                               "window within this central fraction of the image"),
        "margin_m": Key(FLOAT, None, nonneg, "inset from the plot edges; default one leaf size"),
        "fov_deg": Key(FLOAT, 60.0, lambda v: None if 0 < v < 170 else "must lie in (0, 170) degrees",
                       "perspective field of view along each image axis"),
        "camera_height_m": Key(FLOAT, 1.0, positive, "perspective camera above the highest leaf"),
        "jitter": Key(BOOL, False, None, "jitter samples in their strata (seeded by scene.seed)"),
        "replicates": Key(INT, 16, at_least(1), "independent plots (child seeds of scene.seed) "
                          "rendered and averaged: p0 = mean, p0_sd = its seed-to-seed SD"),
        "mask_threshold": Key(FLOAT, 0.5, lambda v: None if 0 < v <= 1 else "must lie in (0, 1]",
                              "coverage drawn as vegetation in mask PNGs (display only)"),
    },
    # --- synthetic photos (simlidar_mi.canopy.synthetic_photo): a photo-like RGB render of
    # every [gapfraction] view, checked with Canopeo against the coverage render
    "photo_render": {
        **{k: Key(LIST, d, lambda v: None if len(v) == 3 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x <= 1 for x in v)
            else "must be [r, g, b], three linear reflectances in [0, 1]", doc)
           for k, d, doc in (("leaf_rgb", [0.08, 0.25, 0.06], "leaf reflectance (two-sided Lambertian)"),
                             ("soil_rgb", [0.35, 0.22, 0.15], "soil reflectance (Lambertian plane)"))},
        "sun_irradiance": Key(FLOAT, 1.0, nonneg, "sun irradiance per RGB channel (relative units)"),
        "sky_radiance": Key(FLOAT, 0.35, nonneg, "uniform sky radiance per RGB channel"),
        "sun_zenith_deg": Key(FLOAT, None, lambda v: None if 0 <= v < 90 else "must lie in [0, 90) degrees",
                              "sun beam zenith; default: the sun at the observer (see synthetic_photo)"),
        "sun_azimuth_deg": Key(FLOAT, None, _finite, "sun beam azimuth relative to the rows; default the view's"),
        "exposure": Key(FLOAT, 1.0, positive, "linear radiance × exposure before the sRGB curve"),
        "spp": Key(INT, 16, at_least(1), "samples per pixel of the photo (box filter)"),
        "max_depth": Key(INT, 3, at_least(1), "path length (2 = direct light only)"),
        "variant": Key(STR, "llvm_ad_rgb", lambda v: None if "rgb" in v.split("_")
                       else "must be an RGB Mitsuba variant such as 'llvm_ad_rgb'",
                       "Mitsuba variant of the photo render"),
    },
}
def _mesh_labels(v):
    """{class: [OBJ name patterns (str) or PLY property values (int)]}, classes wood/leaf/ground."""
    for cls, items in v.items():
        if cls not in ("wood", "leaf", "ground"):
            return f"unknown class '{cls}'; valid: wood, leaf, ground"
        if not isinstance(items, list) or not items or \
                not (all(isinstance(x, str) for x in items) or
                     all(isinstance(x, int) and not isinstance(x, bool) for x in items)):
            return f"'{cls}' must be a non-empty list of name patterns (OBJ) or of integers (PLY)"
    return None


# Sections that hold a list of tables ([[primitive]]).
ARRAY_SECTIONS: dict[str, dict[str, Key]] = {
    "primitive": {
        "type": Key(STR, None, one_of("cylinder", "box", "obj", "ply"), "shape of the primitive: a "
                    "cylinder, a box, or a triangle mesh from a Wavefront OBJ or PLY file"),
        "p0_m": Key(LIST, None, vec3, "cylinder: centre of one end"),
        "p1_m": Key(LIST, None, vec3, "cylinder: centre of the other end"),
        "diameter_m": Key(FLOAT, None, positive, "cylinder: diameter"),
        "min_m": Key(LIST, None, vec3, "box: lowest corner"),
        "max_m": Key(LIST, None, vec3, "box: highest corner"),
        "path": Key(STR, None, None, "obj/ply: the mesh file (relative to the scene file); OBJ text, "
                    "or PLY binary (either byte order) or ASCII; polygons become triangle fans"),
        "label": Key(STR, "wood", one_of("wood", "leaf"), "class of the hits on this shape (a mesh's "
                     "faces that no 'labels' entry matches)"),
        "labels": Key((dict,), None, _mesh_labels,
                      "obj/ply: classes of a mesh's faces, {wood|leaf|ground = [...]}: OBJ name patterns "
                      "('*', '?', '[...]'; case-sensitive) matched against a face's usemtl material, "
                      "else its g group, else its o object; PLY integer values of 'label_property'. "
                      "The first class listed that matches wins"),
        "label_property": Key(STR, None, None, "ply: the integer face property 'labels' reads "
                              "('part' in simlidar-mi forest exports: 0 wood, 1 leaves)"),
        "reflectance": Key(FLOAT, None, unit_interval, "this shape's reflectance in [0, 1] "
                           "(default: [materials] of its label)"),
    },
    # [[species]] of a [forest]: a random-tree preset, optional overrides, an intensity
    "species": {
        "name": Key(STR, None, safe_name, "names the species' prototype mesh files "
                    "(<name>_<k>.ply): letters, digits, '_', '-', '.'"),
        "preset": Key(STR, None, None, "random-tree preset (simlidar_mi.plants.tree_params)"),
        "bumps": Key(LIST, None, lambda v: None if all(isinstance(b, dict) for b in v) else
                     "must be a list of tables {C_per_m2, x0_m, y0_m, h_m2, l_m2}",
                     "squared-exponential intensity terms C·exp(−[(x−x0)²/h + (y−y0)²/l])"),
        "background_per_m2": Key(FLOAT, 0.0, nonneg, "constant intensity added everywhere"),
        "count": Key(STR, "poisson", one_of("auto", "poisson", "stand"),
                     "what ∫λ (trees) counts: 'poisson' (default), the Poisson points before the "
                     "thinning (the paper's process: N ~ Poisson(∫λ), then close pairs thinned); "
                     "'stand', the trees of the final stand (C solved after the thinning: candidates "
                     "drawn until a Poisson(∫λ) target is kept); 'auto': 'stand' when "
                     "forest.crown_factor > 0, else 'poisson'"),
        "leaf_length_tree_cv": Key(FLOAT, None, within(0, 0.3),
                                   "(1, 0–0.3; default: the preset's) between-tree coefficient of "
                                   "variation of a tree's mean leaf length: each tree draws a factor "
                                   "f ~ N(1, cv²) cut to 1 ± 3cv and its leaves draw f × leaf_length_m"),
        "n_daughters_tree_cv": Key(FLOAT, None, within(0, 0.3),
                                   "(1, 0–0.3; default: the preset's) the same for a tree's mean number "
                                   "of daughter branches (per-branch counts f × draw, rounded at random)"),
        "leaves_per_branch_tree_cv": Key(FLOAT, None, within(0, 0.3),
                                         "(1, 0–0.3; default: the preset's) the same for a tree's mean "
                                         "number of leaves per leaf-bearing branch"),
        "tree": Key((dict,), None, None, "overrides of the preset's laws and constants"),
    },
}
PRIMITIVE_NEEDS = {"cylinder": ("p0_m", "p1_m", "diameter_m"), "box": ("min_m", "max_m"), "obj": ("path",),
                   "ply": ("path",)}

# Feature modules keep their keys in keys_<feature>.py (a dict SECTIONS whose keys
# come from keys_base, so there is no import cycle) and are merged here: a new
# section is added, an existing one (e.g. [orchard]) gains the feature's keys.
def _merge(feature: dict[str, dict[str, Key]]) -> None:
    for name, keys in feature.items():
        clash = set(keys) & set(SECTIONS.get(name, {}))
        if clash:  # a programming error, caught by any test that imports the package
            raise RuntimeError(f"[{name}] keys defined twice: {sorted(clash)}")
        SECTIONS.setdefault(name, {}).update(keys)


from .keys_lai import SECTIONS as _LAI  # noqa: E402
from .keys_orchard import SECTIONS as _ORCHARD  # noqa: E402  ([orchard.leaves]; [orchard] row_spacing_m)
from .keys_fisheye import SECTIONS as _FISHEYE  # noqa: E402
from .keys_truth import SECTIONS as _TRUTH  # noqa: E402
from .keys_terrain import SECTIONS as _TERRAIN  # noqa: E402
from .keys_vineyard import SECTIONS as _VINEYARD  # noqa: E402

_merge(_ORCHARD)
_merge(_VINEYARD)
_merge(_TRUTH)
_merge(_TERRAIN)
_merge(_FISHEYE)
_merge(_LAI)

# Every number-valued key's range (config/bounds.py), stored in its Key: checked at load, printed
# by the docs' key reference.
from .bounds import apply as _apply_bounds  # noqa: E402

_apply_bounds(SECTIONS, ARRAY_SECTIONS)
