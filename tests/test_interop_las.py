"""Every included scene's points.las read by independent readers: a LAS 1.4 conformance check
written from the specification (tests/las_conformance.py), laspy with the lazrs LAZ backend
(compress, decompress, same points), pyproj for the WKT CRS, and PDAL when it is installed.

Scenes are shrunk by ``--set`` overrides (fewer trees, coarser steps, shorter tracks), every
platform kind covered: tractor, path, airborne, rotating, and static and rosette (the
calibration cylinder seen from a tripod and from a Mid-70, since no included scene uses them).
"""
from __future__ import annotations

import json
import shutil
import subprocess

import laspy
import numpy as np
import OpenEXR
import pyproj
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.io.las_fields import BeamAngles, ScaleChooser, forward_heading_deg, scan_intensity_scale
from simlidar_mi.lidar.platforms import (airborne_pattern, path_patterns, rosette_patterns, rotating_patterns,
                                         static_pattern)
from simlidar_mi.lidar.scan import ScanSettings
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES
from tests.las_conformance import check_las, wkt_text

CALIB_STATIC = ['platform.kind="static"', "platform.position_m=[1.0, 0.0, 1.0]",
                "platform.elevation_deg=[-40.0, 30.0, 1.0]", "platform.azimuth_deg=[-20.0, 20.0, 1.0]"]
#: 2 prototype trees a species, not the airborne scenes' 12: the LAS does not depend on how
#: many, and drawing 48 trees is about half of such a run.
FEW_PROTOTYPES = "forest.prototypes_per_species=2"
#: scene file → (overrides, platform kind).  Every included scene that writes points.las.
RUNS = {
    "apple_orchard": ("apple_orchard", ["orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.05"], "tractor"),
    "calibration_cylinder": ("calibration_cylinder", ["scan.dy_m=0.01", 'scene.crs="EPSG:25832"'], "tractor"),
    "orchard_leafy": ("orchard_leafy", ["orchard.n_trees=1", "scan.dy_m=0.05", "scan.dtheta_deg=2.0"], "tractor"),
    "orchard_lms511": ("orchard_lms511", ["orchard.n_trees=1", "scan.dy_m=0.05", "sensor.beam_samples=8"],
                       "tractor"),
    "simlidar_table3_7x4": ("simlidar_table3_7x4", ["orchard.n_trees=1", "scan.dy_m=0.05", "scan.dtheta_deg=1.0"],
                            "tractor"),
    "vineyard_vsp": ("vineyard_vsp", ["vineyard.vines_per_row=3", "platform.step_m=0.1",
                                      "platform.elevation_deg=[-55.0, 55.0, 2.0]",
                                      "platform.waypoints_m=[[-1.1, -1.0, 1.4], [-1.1, 4.0, 1.4], "
                                      "[1.1, 4.0, 1.4], [1.1, -1.0, 1.4]]"], "path"),
    "forest_road_scan": ("forest_road_scan", ["platform.step_m=0.5", "platform.elevation_deg=[-30.0, 60.0, 2.0]"],
                         "path"),
    "forest_airborne": ("forest_airborne", ["platform.start_xy_m=[150.0, 150.0]", "platform.end_xy_m=[150.0, 156.0]",
                                            "forest.domain_m=[120.0, 180.0, 120.0, 180.0]",
                                            FEW_PROTOTYPES], "airborne"),
    "forest_airborne_echoes": ("forest_airborne_echoes", ["platform.start_xy_m=[150.0, 150.0]",
                                                          "platform.end_xy_m=[150.0, 152.0]",
                                                          "forest.domain_m=[120.0, 180.0, 120.0, 180.0]",
                                                          FEW_PROTOTYPES], "airborne"),
    "orchard_vlp16_tractor": ("orchard_vlp16_tractor", ["orchard.n_trees=1",
                                                        "platform.waypoints_m=[[0.5, -0.5, 1.5], [0.5, 1.5, 1.5]]"],
                              "rotating"),
    "static_tripod": ("calibration_cylinder", CALIB_STATIC, "static"),
    # issue 31: a terrain (UTM DEM with a CRS; Gaussian hills under a forest)
    "orchard_on_dem": ("orchard_on_dem", ["platform.elevation_deg=[-40.0, 50.0, 2.0]",
                                          "platform.azimuth_deg=[-60.0, 60.0, 2.0]"], "static"),
    "forest_hills": ("forest_hills", ["platform.start_xy_m=[20.0, 18.0]", "platform.end_xy_m=[20.0, 22.0]"],
                     "airborne"),
    # issue 31: the small airborne stand evaluate-als scores (multi-echo RIEGL preset), a corner of it
    "forest_als_small": ("forest_als_small", ["forest.domain_m=[0.0, 40.0, 0.0, 20.0]",
                                              "platform.end_xy_m=[20.0, 22.0]", "platform.pulses_per_line=50",
                                              "platform.pulse_rate_hz=10000.0", "sensor.beam_samples=4"],
                         "airborne"),
    "rosette_mid70": ("calibration_cylinder", ['platform.kind="rosette"', "platform.position_m=[1.0, 0.0, 1.0]"],
                      "rosette"),
}
WITH_ECHOES = {"orchard_lms511", "forest_airborne_echoes", "orchard_vlp16_tractor", "forest_als_small"}


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """name → output folder, each scene scanned once for the whole module."""
    done = {}

    def get(name):
        if name not in done:
            scene, over, kind = RUNS[name]
            out = tmp_path_factory.mktemp(name)
            run = run_scan(load_scene(SCENES / f"{scene}.toml", over), out, write_png=False)
            assert run.measures["platform"] == kind
            done[name] = out
        return done[name]
    return get


def test_every_included_scan_scene_is_covered():
    """A new scene that writes points.las joins RUNS; these write none (forests for the
    `forest` command, gap-fraction canopies)."""
    no_las = {"forest_4species", "forest_small", "random_leaves_spherical", "strawberry_plot", "strawberry_bed"}
    assert {p.stem for p in SCENES.glob("*.toml")} - no_las == {scene for scene, _, _ in RUNS.values()}
    assert {kind for _, _, kind in RUNS.values()} == {"tractor", "static", "path", "airborne", "rotating", "rosette"}


def _fluff_no_scale_can_mend(problem: str, las) -> bool:
    """LAStools' x10 fluff on an axis on a regular grid whose start lies off every accepted
    scale's grid by more than ScaleChooser's MAX_SHIFT_M (these runs' 5 cm rows: io/las.py)."""
    if not problem.startswith("resolution fluff (x10) in "):
        return False
    c = "XYZ".index(problem.split(" in ")[1][0])
    chooser = ScaleChooser()
    chooser.add(np.asarray(las.xyz, np.float64).T)
    return not chooser.fluff_free()[c] and chooser.scales()[c] == las.header.scales[c]


@pytest.mark.parametrize("name", sorted(RUNS))
def test_las_conforms_and_reads_the_same_in_laspy_and_after_laz(name, outputs, tmp_path):
    path = outputs(name) / "points.las"
    las = laspy.read(path)
    assert [p for p in check_las(path) if not _fluff_no_scale_can_mend(p, las)] == []
    n = len(las.points)
    assert n > 100 and las.header.point_count == n
    rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    # a PDAL-style first-return selection (filters.range ReturnNumber[1:1]) keeps one point per pulse
    pulses = np.unique(np.stack([las.point_source_id, las.scan_position, las.scan_angle_index]), axis=1).shape[1]
    assert np.count_nonzero(rn == 1) == pulses
    if name not in WITH_ECHOES:
        assert np.all(rn == 1) and np.all(nr == 1) and pulses == n
    assert list(las.header.number_of_points_by_return) == np.bincount(rn, minlength=16)[1:].tolist()
    # |scan_angle| is the angle from nadir: 90° + the beam's elevation (extra bytes)
    off = np.abs(np.asarray(las.scan_angle, np.float64)) * 0.006
    np.testing.assert_allclose(off, 90.0 + np.asarray(las.elevation_deg, np.float64), atol=0.0031)
    # LAZ round trip through lazrs: every record byte and the header counts come back
    laz = tmp_path / "points.laz"
    las.write(laz, laz_backend=laspy.LazBackend.Lazrs)
    assert laz.stat().st_size < path.stat().st_size
    back = laspy.read(laz, laz_backend=laspy.LazBackend.Lazrs)
    assert back.points.array.tobytes() == las.points.array.tobytes()
    assert list(back.header.number_of_points_by_return) == list(las.header.number_of_points_by_return)
    assert list(back.point_format.extra_dimension_names) == list(las.point_format.extra_dimension_names)


def test_wkt_crs_reads_in_pyproj(outputs):
    path = outputs("calibration_cylinder") / "points.las"
    crs = pyproj.CRS.from_wkt(wkt_text(path))
    assert crs.to_epsg() == 25832 and laspy.read(path).header.global_encoding.wkt
    assert wkt_text(outputs("apple_orchard") / "points.las") is None  # no [scene] crs: no CRS record


def test_rotating_head_points_are_in_firing_order(outputs):
    """VLP-16 points follow the firing sequence (channels interleaved −15, 1, −13, …), so gps_time
    never steps back within a scan line (a leg's rows)."""
    las = laspy.read(outputs("orchard_vlp16_tractor") / "points.las")
    t, src = np.asarray(las.gps_time), np.asarray(las.point_source_id)
    for s in np.unique(src):
        assert np.all(np.diff(t[src == s]) >= 0)
    first = np.asarray(las.scan_position) == np.asarray(las.scan_position)[0]
    assert len(np.unique(np.asarray(las.scan_angle_index)[first])) > 1


@pytest.mark.parametrize("name", sorted(WITH_ECHOES))
def test_intensity_has_the_scans_scale_and_never_clips(name, outputs):
    """The scale is the scan's own (issue #29: 65535 / its largest echo energy, 4 significant
    digits), stated in VLR record 2; no longer in the EXR header, written before the echoes."""
    out = outputs(name)
    las = laspy.read(out / "points.las")
    energy = np.asarray(las.echo_energy, np.float64)
    scale = scan_intensity_scale(float(np.asarray(las.echo_energy).max()))
    np.testing.assert_array_equal(np.asarray(las.intensity), np.rint(scale * energy))
    assert 65470 <= np.asarray(las.intensity).max() <= 65535
    exr = OpenEXR.File(str(out / "scan.exr")).header()
    assert "las_intensity_scale" not in exr
    text = las.header.vlrs.get_by_id("simlidar-mi", [2])[0].record_data.decode("ascii")
    assert f"s = {scale:.9g} counts per unit E" in text


#: (x of the face, y range, reflectance) of three plates, one per azimuth −10°, 0°, 10°
PLATES = ((1.52, (-0.5, -0.1), 1.0), (2.5, (-0.08, 0.08), 0.4), (6.0, (0.8, 1.4), 0.2))


def _plate_scene(r_min: float) -> str:
    """A tripod at the origin and three Lambertian plates facing it (normal −x), each met by
    the beams of one azimuth (−10°, 0°, 10°) at elevations 0° and 40°."""
    plates = "".join(f'[[primitive]]\ntype = "box"\nmin_m = [{x}, {y0}, -5.0]\nmax_m = [{x + 0.05}, {y1}, 8.0]\n'
                     f"reflectance = {rho}\n" for x, (y0, y1), rho in PLATES)
    return ('[scene]\nname = "plates"\n[ground]\nenabled = false\n[platform]\nkind = "static"\n'
            'position_m = [0.0, 0.0, 0.0]\nelevation_deg = [0.0, 40.0, 40.0]\nazimuth_deg = [-10.0, 11.0, 10.0]\n'
            f"[sensor]\nintensity = true\nrange_min_m = {r_min}\n" + plates)


def test_intensity_ratios_on_plates_follow_rho_cos_over_r2(tmp_path):
    """Intensity ∝ ρ·cos i / r² within 1 %; the strongest echo reads 65470 … 65535: the scan's
    scale (issue #29) maps its own echoes into 16 bits without clipping (the old 1000 counts per
    unit E clipped the nearest echo at 65535)."""
    r_min = 1.5
    run = run_scan(load_scene(text=_plate_scene(r_min)), tmp_path / "p", write_png=False)
    las = laspy.read(tmp_path / "p" / "points.las")
    assert len(las.points) == 6
    az, el = np.deg2rad(np.asarray(las.azimuth_deg, np.float64)), np.deg2rad(np.asarray(las.elevation_deg, np.float64))
    r = np.asarray(las.range_m, np.float64)
    cos_i = np.cos(el) * np.cos(az)  # plate normal −x
    np.testing.assert_allclose(r * cos_i, [PLATES[int(round(a / 10.0)) + 1][0] for a in np.degrees(az)], rtol=1e-5)
    rho = np.array([PLATES[int(round(a / 10.0)) + 1][2] for a in np.degrees(az)])
    expected = rho * cos_i / r ** 2
    got = np.asarray(las.intensity, np.float64)
    np.testing.assert_allclose(got / got.max(), expected / expected.max(), rtol=0.01)
    # absolute: s·E with E = ρ·cos i·(R_ref/r)² and s the scan's (65535 / its largest E)
    r_ref = run.measures["sensor"]["r_ref_m"]
    s = scan_intensity_scale(float(np.asarray(las.echo_energy).max()))
    np.testing.assert_allclose(got, s * expected * r_ref ** 2, rtol=0.01)
    assert 65470 <= got.max() <= 65535
    assert np.count_nonzero(1000.0 * np.asarray(las.echo_energy) > 65535) == 1  # the old rule clipped it
    assert run.measures["sensor"]["intensity_scale"] == pytest.approx(
        65535.0 * (r_min / run.measures["sensor"]["r_ref_m"]) ** 2)


# --- scan_angle against beams of known direction, every platform kind --------------------

def _kinds():
    tractor = ScanSettings(x0_m=1.0, z0_m=1.2, y_start_m=0.0, dy_m=0.1, gap=0, n_positions=3,
                           theta_min_deg=-90.0, dtheta_deg=45.0, n_angles=5).pattern()
    yield "tractor", tractor
    yield "static", static_pattern([0, 0, 1], (-90.0, 90.0, 45.0), (0.0, 360.0, 90.0))
    yield "path", path_patterns([[0, 0, 1], [0, 5, 1]], 1.0, (-90.0, 90.0, 45.0), side="left")[0]
    yield "airborne", airborne_pattern([0, 0], [0, 50], 100.0, 40.0, 10.0, 100.0, 4)
    yield "rotating", rotating_patterns(waypoints_m=[[0, 0, 1], [5, 0, 1]], speed_m_s=5.0)[0]
    yield "rosette", rosette_patterns(waypoints_m=[[0, 0, 1], [0, 5, 1]], speed_m_s=5.0, look_deg=(-90.0, -30.0))[0]


@pytest.mark.parametrize("kind,pattern", list(_kinds()), ids=[k for k, _ in _kinds()])
def test_scan_angle_is_the_angle_from_nadir_signed_by_side(kind, pattern):
    """Independent geometry: |angle| = arccos(−d_z), positive when d points right of the forward
    direction h (d·(sin h, −cos h, 0) > 0), or in the vertical plane through it."""
    n, m = pattern.n_rows, pattern.n_cols
    i, k = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(m), indexing="ij"))
    d = pattern.world_dirs()[i, k]
    h = np.deg2rad(forward_heading_deg(pattern))
    side = d[:, 0] * np.sin(h) - d[:, 1] * np.cos(h)
    off = np.degrees(np.arccos(np.clip(-d[:, 2], -1.0, 1.0)))
    want = np.where(side < -1e-12, -off, off)
    scan, elev, azim = BeamAngles(pattern)(i, k)
    got = scan.astype(np.float64) * 0.006
    near_up = off > 179.99  # ±180° are both straight up
    np.testing.assert_allclose(got[~near_up], want[~near_up], atol=0.0031)
    np.testing.assert_allclose(np.abs(got[near_up]), 180.0, atol=0.0031)
    np.testing.assert_allclose(elev, np.degrees(np.arcsin(np.clip(d[:, 2], -1, 1))), atol=1e-4)
    horiz = np.hypot(d[:, 0], d[:, 1]) > 1e-9
    np.testing.assert_allclose(np.cos(np.deg2rad(azim[horiz])), d[horiz, 0] / np.hypot(d[horiz, 0], d[horiz, 1]),
                               atol=1e-5)


def test_scan_angle_of_named_beams():
    """Beams whose angle is known by construction."""
    tractor = dict(_kinds())["tractor"]  # drives +y, looks +x (its right): θ = −90, −45, 0, 45, 90
    scan = BeamAngles(tractor)(np.zeros(5, int), np.arange(5))[0] * 0.006
    np.testing.assert_allclose(scan, [0.0, 45.0, 90.0, 135.0, 180.0], atol=1e-9)
    air = dict(_kinds())["airborne"]  # flies +y; pulses at α = −15, −5, 5, 15 (positive: right, +x)
    assert np.allclose(air.world_dirs()[0, -1, 0], np.sin(np.deg2rad(15.0)))
    np.testing.assert_allclose(BeamAngles(air)(np.zeros(4, int), np.arange(4))[0] * 0.006, [-15, -5, 5, 15], atol=0.003)
    # a VLP-16 channel at 1° looking straight ahead is 91° from nadir, not 0 or 1
    head = dict(_kinds())["rotating"]
    k = int(np.flatnonzero(head.col_angle_deg == 1.0)[0])
    assert abs(BeamAngles(head)(np.zeros(1, int), np.array([k]))[0][0] * 0.006) == pytest.approx(91.0, abs=0.1)
    left = dict(_kinds())["path"]  # looks left of +y, i.e. −x: negative angles
    assert np.all(BeamAngles(left)(np.zeros(3, int), np.arange(1, 4))[0] < 0)


@pytest.mark.skipif(shutil.which("pdal") is None, reason="PDAL not installed (optional reader)")
def test_pdal_reads_first_returns(outputs, tmp_path):
    """PDAL's usual first-return step keeps every point of a first-return scan."""
    path = outputs("apple_orchard") / "points.las"
    out = tmp_path / "first.las"
    subprocess.run(["pdal", "translate", str(path), str(out), "range",
                    "--filters.range.limits=ReturnNumber[1:1]"], check=True, timeout=120)
    info = json.loads(subprocess.run(["pdal", "info", "--summary", str(out)], check=True, capture_output=True,
                                     text=True, timeout=120).stdout)
    assert info["summary"]["num_points"] == len(laspy.read(path).points)
