"""evaluate-als and its parts against exact answers: Sithole-Vosselman errors and Cohen's κ on a
hand-made confusion, 1:1 tree matching on synthetic lists, the progressive morphological filter on
an analytic slope with buildings, CSF on a flat scene with a box, the raster truth of a box scene,
and the whole command on a small airborne forest."""
from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from simlidar_mi.truth import als_ground as G
from simlidar_mi.truth import als_trees as T
from simlidar_mi.truth.als_truth import RasterGrid, flat_ground, overtopped, surface_rasters, write_geotiff
from tests.conftest import SCENES


# --- per-point ground scores ---------------------------------------------------------------------

def test_type_errors_and_kappa_of_a_hand_made_confusion():
    # a = 50 ground kept, b = 10 ground rejected, c = 5 objects accepted, d = 35 objects kept
    true = np.array([True] * 60 + [False] * 40)
    pred = np.array([True] * 50 + [False] * 10 + [True] * 5 + [False] * 35)
    s = G.classification_scores(true, pred)
    assert (s["a"], s["b"], s["c"], s["d"], s["n"]) == (50, 10, 5, 35, 100)
    assert s["type_I"] == pytest.approx(10 / 60, abs=1e-15)
    assert s["type_II"] == pytest.approx(5 / 40, abs=1e-15)
    assert s["total_error"] == pytest.approx(0.15, abs=1e-15)
    # p_o = 0.85, p_e = (60·55 + 40·45)/100² = 0.51 → κ = 0.34/0.49
    assert s["kappa"] == pytest.approx(0.34 / 0.49, abs=1e-12)
    perfect = G.classification_scores(true, true)
    assert perfect["kappa"] == 1.0 and perfect["total_error"] == 0.0
    chance = G.classification_scores(np.array([1, 1, 0, 0], bool), np.array([1, 0, 1, 0], bool))
    assert chance["kappa"] == pytest.approx(0.0, abs=1e-15)


# --- tree matching ------------------------------------------------------------------------------

def test_one_to_one_matching_on_synthetic_tree_lists():
    true = np.array([[0.0, 0.0, 20.0],    # tallest: takes the nearer of two candidates
                     [2.0, 0.0, 18.0],    # its nearest candidate is taken: the other one
                     [10.0, 0.0, 15.0],   # a detection 3.5 m away: beyond the distance tolerance
                     [20.0, 0.0, 12.0],   # a detection 1 m away but 4 m lower: beyond the height tolerance
                     [30.0, 0.0, 8.0]])   # found 0.5 m away
    det = np.array([[0.5, 0.0, 19.0],     # 0: 0.5 m from tree 0, 1.5 m from tree 1
                    [2.9, 0.0, 18.5],     # 1: 0.9 m from tree 1
                    [13.5, 0.0, 15.0],    # 2: too far
                    [21.0, 0.0, 8.0],     # 3: too low
                    [30.0, 0.5, 9.0],     # 4
                    [50.0, 0.0, 10.0]])   # 5: nothing near
    m = T.match_trees(true, det, max_distance_m=3.0, max_height_diff_m=3.0)
    assert m.det_of_true.tolist() == [0, 1, -1, -1, 4]
    assert m.true_of_det.tolist() == [0, 1, -1, -1, 4, -1]
    # tallest first: tree 0 takes detection 0 although tree 1 is nearer to nothing else
    crowded = T.match_trees(np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 20.0]]), np.array([[0.6, 0.0, 15.0]]),
                            max_distance_m=3.0, max_height_diff_m=6.0)
    assert crowded.det_of_true.tolist() == [-1, 0]
    rows = T.detection_scores(true, det, m, species=["a", "a", "b", "b", "b"],
                              overtopped=[False, False, False, True, True])
    allr = rows[0]
    assert (allr["n_true"], allr["n_detected"], allr["n_matched"]) == (5, 6, 3)
    assert allr["detection_rate"] == pytest.approx(3 / 5) and allr["precision"] == pytest.approx(3 / 6)
    assert allr["f_score"] == pytest.approx(2 * 0.6 * 0.5 / 1.1)
    e = np.array([19.0 - 20.0, 18.5 - 18.0, 9.0 - 8.0])
    assert allr["height_rmse_m"] == pytest.approx(np.sqrt(np.mean(e ** 2)))
    assert allr["height_bias_m"] == pytest.approx(np.mean(e))
    by = {r["group"]: r for r in rows}
    assert by["species a"]["detection_rate"] == 1.0 and by["species b"]["detection_rate"] == pytest.approx(1 / 3)
    assert by["dominant"]["detection_rate"] == pytest.approx(2 / 3) and by["overtopped"]["detection_rate"] == 0.5


def test_local_maxima_window_grows_with_height():
    grid = RasterGrid(0.0, 0.0, 0.5, 40, 20)
    xc, yc = grid.centres()
    # two cones 3 m apart: 25 m tall trees (window 2.5 + 0.009·625 = 8.1 m) keep one top,
    # 5 m tall ones (window 2.74 m) keep both
    for h, n in ((25.0, 1), (5.0, 2)):
        chm = np.maximum(h - 2.0 * np.hypot(xc - 8.75, yc - 5.25), h - 0.5 - 2.0 * np.hypot(xc - 11.75, yc - 5.25))
        tops = T.local_maxima_trees(np.maximum(chm, 0.0), grid, min_height_m=2.0)
        assert len(tops) == n
        assert tops[0].tolist() == [8.75, 5.25, h]
    assert T.popescu_window_m(np.array([0.0, 10.0])).tolist() == pytest.approx([2.51503, 2.51503 + 0.901])


# --- ground filters ---------------------------------------------------------------------------

def _slope_with_buildings(spacing=0.5):
    x, y = np.meshgrid(np.arange(0.0, 60.0, spacing) + 0.25, np.arange(0.0, 60.0, spacing) + 0.25)
    x, y = x.ravel(), y.ravel()
    z = 0.1 * x + 0.05 * y + 100.0
    roof = np.zeros(len(x), bool)
    for x0, y0, w, h in ((10, 10, 6, 4.0), (35, 20, 8, 8.0), (20, 42, 5, 3.0)):
        inside = (x > x0) & (x < x0 + w) & (y > y0) & (y < y0 + w)
        z[inside] += h                       # the roof hides the ground under it
        roof |= inside
    return np.column_stack([x, y, z]), ~roof


def test_pmf_separates_buildings_from_an_analytic_slope():
    xyz, ground = _slope_with_buildings()
    assert G.pmf_windows(1.0, 20.0) == [3, 5, 9, 17]
    got = G.pmf_ground(xyz, cell_m=1.0, max_window_m=20.0, slope=0.3, dh0_m=0.3, dh_max_m=3.0)
    s = G.classification_scores(ground, got)
    assert (s["b"], s["c"]) == (0, 0), s
    # too small a window cannot see the 8 m building as an object: its roof stays ground
    small = G.pmf_ground(xyz, cell_m=1.0, max_window_m=5.0)
    assert G.classification_scores(ground, small)["c"] > 0


def test_csf_on_a_flat_scene_with_a_box():
    x, y = np.meshgrid(np.arange(0.0, 40.0, 0.5) + 0.25, np.arange(0.0, 40.0, 0.5) + 0.25)
    x, y, z = x.ravel(), y.ravel(), np.zeros(x.size)
    box = (x > 15) & (x < 21) & (y > 15) & (y < 21)
    z[box] = 3.0
    got = G.csf_ground(np.column_stack([x, y, z]), cloth_resolution_m=0.5, rigidness=3, class_threshold_m=0.5)
    s = G.classification_scores(~box, got)
    assert (s["b"], s["c"]) == (0, 0), s
    assert s["kappa"] == 1.0


def test_dtm_of_ground_points_is_exact_on_a_plane_and_scored_by_stratum():
    grid = RasterGrid(0.0, 0.0, 1.0, 10, 10)
    pts = np.array([[-1, -1], [11, -1], [-1, 11], [11, 11], [5, 5.5]], np.float64)
    xyz = np.column_stack([pts, 0.2 * pts[:, 0] - 0.1 * pts[:, 1] + 3.0])
    dtm = G.dtm_from_ground(xyz, grid)
    xc, yc = grid.centres()
    true = 0.2 * xc - 0.1 * yc + 3.0
    assert np.abs(dtm - true).max() < 1e-12
    under = np.zeros(grid.shape, bool)
    under[:5] = True
    rows = {r["stratum"]: r for r in G.dtm_scores(dtm + 0.5, true, under, 1.0)}
    assert rows["all"]["rmse_m"] == pytest.approx(0.5) and rows["all"]["bias_m"] == pytest.approx(0.5)
    assert rows["under canopy"]["n_cells"] == 50 and rows["open"]["n_cells"] == 50
    # slope atan(|(0.2, -0.1)|) = 12.6°
    assert rows["slope 10-20 deg"]["n_cells"] == 100 and rows["slope 0-10 deg"]["n_cells"] == 0


def _terrain_cloud(**relief):
    """Points on a jittered 0.5 m grid over 40 m × 40 m of the analytic relief (centre (20, 20))
    with four 4 m × 4 m boxes 6 m tall (their roofs replace the ground under them)."""
    from simlidar_mi.io.terrain import relief_m
    rng = np.random.default_rng(1)
    x, y = np.meshgrid(np.arange(0.0, 40.0, 0.5) + 0.25, np.arange(0.0, 40.0, 0.5) + 0.25)
    x, y = x.ravel() + rng.uniform(-0.1, 0.1, x.size), y.ravel() + rng.uniform(-0.1, 0.1, y.size)
    box = np.zeros(x.size, bool)
    for bx, by in ((6, 6), (30, 8), (8, 30), (30, 30)):
        box |= (x > bx) & (x < bx + 4) & (y > by) & (y < by + 4)
    z = relief_m(x, y, centre_m=(20.0, 20.0), **relief) + np.where(box, 6.0, 0.0)
    grid = RasterGrid(2.0, 2.0, 0.5, 72, 72)
    xc, yc = grid.centres()
    under = np.zeros(grid.shape, bool)
    for bx, by in ((6, 6), (30, 8), (8, 30), (30, 30)):
        under |= (xc > bx) & (xc < bx + 4) & (yc > by) & (yc < by + 4)
    return np.column_stack([x, y, z]), ~box, grid, relief_m(xc, yc, centre_m=(20.0, 20.0), **relief), under


def _scored(xyz, ground, pred, grid, true, under):
    rows = {r["stratum"]: r for r in G.dtm_scores(G.dtm_from_ground(xyz[pred], grid), true, under, grid.cell_m)}
    return G.classification_scores(ground, pred), rows


def test_ground_filters_scored_by_slope_class_on_a_step_a_ditch_and_a_40_degree_slope():
    """DTM scores by slope class and under objects vs open on analytic terrain (issue 31 §3).
    The true ground's TIN is exact wherever its triangles do not span a break: everywhere on a
    40° plane (all cells in the 30–45° class), on the terraces of a 2 m step (0–10°, error 0)
    with all its error in the step's own cells (45–90°), on a 1.5 m × 4 m V ditch's planar walls
    (30–45°) with its error at the bottom and rims (the cells whose central differences straddle
    a kink), and under the boxes (the TIN spans
    their 4 m footprints exactly on a plane).  PMF's slope parameter 0.3 (17°) rejects ground
    on the 40° slope (type I), yet the TIN of what it keeps is the same plane: error 0."""
    xyz, ground, grid, true, under = _terrain_cloud(step_m=2.0)
    s, rows = _scored(xyz, ground, ground, grid, true, under)
    assert rows["slope 0-10 deg"]["n_cells"] == 5040 and rows["slope 0-10 deg"]["max_abs_m"] < 1e-12
    assert rows["slope 45-90 deg"]["n_cells"] == 144 and rows["slope 45-90 deg"]["rmse_m"] > 0.05
    assert rows["under canopy"]["n_cells"] == under.sum() == 4 * 64 and rows["under canopy"]["max_abs_m"] < 1e-12
    s, rows = _scored(xyz, ground, G.pmf_ground(xyz), grid, true, under)
    assert s["kappa"] == 1.0 and rows["slope 0-10 deg"]["max_abs_m"] < 1e-12
    xyz, ground, grid, true, under = _terrain_cloud(ditch_depth_m=1.5, ditch_width_m=4.0)
    s, rows = _scored(xyz, ground, ground, grid, true, under)
    assert rows["slope 0-10 deg"]["max_abs_m"] < 1e-12                       # off the ditch
    assert rows["slope 30-45 deg"]["n_cells"] == 288 and rows["slope 30-45 deg"]["max_abs_m"] < 1e-9  # its planar walls
    assert rows["slope 20-30 deg"]["rmse_m"] > 0.005                            # its bottom and rims: the TIN cuts corners
    xyz, ground, grid, true, under = _terrain_cloud(slope_deg=40.0, aspect_deg=90.0)
    s, rows = _scored(xyz, ground, ground, grid, true, under)
    assert rows["slope 30-45 deg"]["n_cells"] == 72 * 72 and rows["all"]["max_abs_m"] < 1e-9
    s, rows = _scored(xyz, ground, G.pmf_ground(xyz), grid, true, under)
    assert s["type_I"] > 0.3 and s["type_II"] == 0.0
    assert rows["all"]["max_abs_m"] < 1e-9 and rows["slope 30-45 deg"]["n_cells"] > 0.8 * 72 * 72


# --- raster truth --------------------------------------------------------------------------------

def _box_scene(tmp_path):
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.survey import build, generate
    p = tmp_path / "box.toml"
    p.write_text('[scene]\nname = "box"\n[[primitive]]\ntype = "box"\nmin_m = [1.0, 1.0, 0.0]\n'
                 'max_m = [2.0, 2.5, 3.0]\n[[primitive]]\ntype = "cylinder"\np0_m = [3.25, 0.75, 0.0]\n'
                 'p1_m = [3.25, 0.75, 1.5]\ndiameter_m = 0.2\n')
    cfg = load_scene(p)
    return build(cfg, generate(cfg), patterns=[])


def test_truth_rasters_of_a_box_and_a_post(tmp_path):
    built = _box_scene(tmp_path)
    grid = RasterGrid(0.0, 0.0, 0.5, 8, 6)
    t = surface_rasters(built, grid, flat_ground(0.0), subsamples=3)
    expect = np.zeros(grid.shape)
    expect[1:4, 2:4] = 3.0          # x 1–2 m: columns 2, 3; y 1–2.5 m: rows 1–3 from the north
    expect[4, 6] = 1.5              # the post (Ø 0.2 m at x 3.25, y 0.75) meets the centre ray of its cell
    assert np.abs(t.dsm - expect).max() < 1e-5
    assert np.abs(t.chm - expect).max() < 1e-5
    assert (t.dtm == 0.0).all() and (t.tree_id == -1).all()
    # on a slope z = 0.1 x (under the box's top): the CHM is the largest height above it,
    # at the cell's western sub-samples, x_s = centre − cell/3
    slope = lambda x, y: 0.1 * np.asarray(x)  # noqa: E731
    s = surface_rasters(built, grid, slope, subsamples=3)
    xc, _ = grid.centres()
    assert np.allclose(s.dtm, 0.1 * xc, atol=1e-12)
    box = expect == 3.0
    assert np.abs(s.chm[box] - (3.0 - 0.1 * (xc[box] - 0.5 / 3))).max() < 1e-5
    open_ = expect == 0.0
    assert np.abs(s.dsm[open_] - 0.1 * (xc[open_] + 0.5 / 3)).max() < 1e-9
    assert np.abs(s.chm[open_]).max() < 1e-12


def test_overtopped_trees_own_no_top_cell():
    ids = np.array([[0, 0, -1], [2, 2, 0]])
    assert overtopped(ids, 4).tolist() == [False, True, False, True]


def test_geotiff_reopens_with_its_crs_and_transform(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    grid = RasterGrid(500000.0, 5200000.0, 0.5, 4, 3)
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    write_geotiff(tmp_path / "a.tif", a, grid, "EPSG:25832", description="test")
    write_geotiff(tmp_path / "b.tif", a, grid, None)
    with rasterio.open(tmp_path / "a.tif") as r:
        assert r.crs.to_epsg() == 25832
        assert r.transform.c == 500000.0 and r.transform.f == 5200001.5 and r.res == (0.5, 0.5)
        assert (r.read(1) == a).all() and r.descriptions == ("test",)
        assert r.xy(2, 0) == (500000.25, 5200000.25)   # row 2 is the southern edge
    with rasterio.open(tmp_path / "b.tif") as r:
        assert r.crs is None
    gdalinfo = subprocess.run(["gdalinfo", str(tmp_path / "a.tif")], capture_output=True, text=True) \
        if __import__("shutil").which("gdalinfo") else None
    if gdalinfo is not None:
        assert gdalinfo.returncode == 0 and "25832" in gdalinfo.stdout


# --- the command ------------------------------------------------------------------------------

# the southern half of the stand (elms and spruces) on a hill and a gentle slope, at a third of
# the across-track pulses and a quarter of the sub-rays of the scene (same along-track spacing)
SMALL = ["forest.domain_m=[0.0, 40.0, 0.0, 20.0]", "platform.end_xy_m=[20.0, 22.0]",
         "platform.pulses_per_line=50", "platform.pulse_rate_hz=10000.0", "sensor.beam_samples=4",
         "terrain.slope_deg=8.0", "terrain.aspect_deg=200.0", "terrain.hills_m=[[14.0, 8.0, 3.0, 6.0]]",
         "terrain.cell_m=1.0"]


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "simlidar_mi.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)


def mine(points):  # a user's ground method: the lowest 70 % of the points
    return points["z"] <= np.quantile(points["z"], 0.7)


@pytest.fixture(scope="module")
def small_forest_run(tmp_path_factory):
    """One scan and one evaluate-als of the small forest on hills, shared by the tests below."""
    pytest.importorskip("rasterio")
    from simlidar_mi.lidar.survey import run_scan
    from simlidar_mi.truth.als_evaluate import evaluate_als
    tmp = tmp_path_factory.mktemp("als_forest")
    run_scan(SCENES / "forest_als_small.toml", tmp / "scan", SMALL, write_png=False)
    run = evaluate_als(SCENES / "forest_als_small.toml", tmp / "scan" / "points.las", tmp / "als", SMALL,
                       ground_plugins=[mine],
                       tree_plugins=[f"{Path(__file__).parent / 'als_plugin.py'}:tallest_cell"])
    return tmp, run


def test_evaluate_als_scores_and_files_on_a_small_forest_on_hills(small_forest_run):
    tmp_path, run = small_forest_run
    g = {r["method"]: r for r in run.ground}
    assert set(g) == {"true-classes", "csf", "pmf", "mine"}
    assert g["true-classes"]["kappa"] == 1.0 and g["true-classes"]["total_error"] == 0.0
    assert g["true-classes"]["dtm_rmse_m"] < 0.05          # the hill's TIN against the true terrain
    # on hills CSF at its flat-terrain rigidness 3 loses ground (κ ≈ 0.65 here, BENCHMARKS §17.1)
    assert g["csf"]["kappa"] > 0.5 and g["pmf"]["kappa"] > 0.5 and 0.0 < g["mine"]["kappa"] < 1.0
    files = {p.name for p in (tmp_path / "als").iterdir()}
    for name in ("als_scores.json", "ground_scores.csv", "dtm_scores.csv", "chm_scores.csv", "tree_scores.csv",
                 "truth_trees.csv", "truth_dtm.tif", "truth_dsm.tif", "truth_chm.tif", "truth_tree_id.tif",
                 "dtm_csf.tif", "chm_pitfree.tif", "dtm_error.png", "chm_trees.png", "detection_by_height.png"):
        assert name in files, name
    summary = json.loads((tmp_path / "als" / "als_scores.json").read_text())
    assert summary["n_trees"] >= 3 and (summary["grid"]["nx"], summary["grid"]["ny"]) == (80, 40)
    tr = {(r["method"], r["group"]): r for r in run.trees}
    n = summary["n_trees"]  # the oracle on the truth CHM misses at most one tree more
    assert tr[("lmf on truth CHM", "all")]["detection_rate"] >= tr[("lmf", "all")]["detection_rate"] - 1.0 / n - 1e-9
    assert ("tallest_cell", "all") in tr and tr[("tallest_cell", "all")]["n_detected"] == 1


def test_evaluate_als_truth_on_hills_is_the_terrain_and_trees(small_forest_run):
    """The truth DTM is the scene's terrain (the hill, 3 m over the slope), the CHM is heights
    above it: no ray meets a tree above its top, and the trees' tops are in the CHM."""
    import csv
    import rasterio
    from simlidar_mi.config import load_scene
    from simlidar_mi.io.terrain import terrain_of
    tmp_path, run = small_forest_run
    ter = terrain_of(load_scene(SCENES / "forest_als_small.toml", SMALL))
    with rasterio.open(tmp_path / "als" / "truth_dtm.tif") as r:
        dtm = r.read(1).astype(np.float64)
        rows, cols = np.indices(dtm.shape)
        xc, yc = r.transform.c + (cols + 0.5) * r.transform.a, r.transform.f + (rows + 0.5) * r.transform.e
    np.testing.assert_allclose(dtm, ter.height_m(xc, yc), rtol=0, atol=1e-4)
    assert np.ptp(dtm) > 3.0
    with rasterio.open(tmp_path / "als" / "truth_chm.tif") as r:
        chm = r.read(1)
        assert r.crs is None and r.shape == (40, 80)
    with rasterio.open(tmp_path / "als" / "truth_tree_id.tif") as r:
        tid = r.read(1)
        assert r.nodata == -1
    trees = list(csv.DictReader(open(tmp_path / "als" / "truth_trees.csv")))
    ang = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    for t in trees:  # the trees a ray meets first own cells (not overtopped); none is met above its top
        own = tid == int(t["tree_id"])
        assert (int(t["top_cells"]) == int(own.sum())) and (t["overtopped"] == str(int(not own.any())))
        if own.any():  # on a slope a crown's downhill edge may stand higher above the terrain under it
            x, y, r = float(t["x_m"]), float(t["y_m"]), float(t["crown_radius_m"])
            rr = r * np.sqrt(np.linspace(0.0, 1.0, 16))[:, None]
            drop = float(ter.height_m(x, y)) - np.nanmin(ter.height_m(x + rr * np.cos(ang), y + rr * np.sin(ang)))
            assert chm[own].max() <= float(t["height_m"]) + max(drop, 0.0) + 0.05
    tops = [float(t["height_m"]) - chm[tid == int(t["tree_id"])].max() for t in trees if int(t["top_cells"])]
    assert np.median(tops) < 0.5
    d = {(r["method"], r["stratum"]): r for r in run.dtm}
    assert d[("true-classes", "under canopy")]["n_cells"] > 0 and d[("true-classes", "open")]["n_cells"] > 0


def test_evaluate_als_bad_inputs_are_one_line(tmp_path):
    scene = SCENES / "forest_als_small.toml"
    for args, words in ((["--points", tmp_path / "none.las"], "no such file"),
                        (["--points", scene], "not a readable LAS file"),
                        (["--points", scene, "--ground-method", "nomodule_xyz:f"], "cannot import"),
                        (["--points", scene, "--cell", "0"], "--cell")):
        proc = _cli("evaluate-als", scene, "--out", tmp_path / "o", *args, cwd=tmp_path)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode != 0 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert words in lines[0], lines[0]


# --- evaluate-als on the scene's terrain -------------------------------------------------------------

_TERRAIN_SCENE = """
[scene]
name = "box_on_terrain"
seed = 3
{crs}
[ground]
z_m = {gz}
[terrain]
{terrain}
[[primitive]]
type = "box"
min_m = [{bx0}, {by0}, {bz0}]
max_m = [{bx1}, {by1}, {bz1}]
[platform]
kind = "airborne"
start_xy_m = [{cx}, {sy0}]
end_xy_m = [{cx}, {sy1}]
altitude_m = 60.0
swath_deg = 30.0
speed_m_s = 10.0
pulse_rate_hz = 4000.0
pulses_per_line = 40
"""


def _terrain_run(tmp_path, terrain: str, origin=(0.0, 0.0), crs: str = "", box_z=(0.0, 15.0), k=None, ground_z=0.0):
    from simlidar_mi.lidar.survey import run_scan
    from simlidar_mi.truth.als_evaluate import evaluate_als
    ox, oy = origin
    text = _TERRAIN_SCENE.format(terrain=terrain, crs=crs, bx0=ox + 8.0, by0=oy + 8.0, bx1=ox + 12.0,
                                 by1=oy + 12.0, bz0=box_z[0], bz1=box_z[1], cx=ox + 10.0, sy0=oy + 0.0,
                                 sy1=oy + 20.0, gz=ground_z)
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    run_scan(scene, tmp_path / "scan", write_png=False)
    run = evaluate_als(scene, tmp_path / "scan" / "points.las", tmp_path / "als", images=False, cell_m=1.0,
                       subsamples=k)
    return scene, run


def _read_truth(folder):
    import rasterio
    out = {}
    for key in ("dtm", "dsm", "chm"):
        with rasterio.open(folder / f"truth_{key}.tif") as r:
            out[key] = r.read(1).astype(np.float64)
            out["crs"], out["transform"] = r.crs, r.transform
    return out


@pytest.mark.parametrize("form", ["plane", "hills"])
def test_evaluate_als_takes_the_scene_terrain(tmp_path, form):
    """With no ``height_m`` given, the truth DTM is the scene's ``[terrain]`` at every cell centre
    (a 35° plane: relief_m's float64 plane; Gaussian hills: the terrain the scan saw, which is
    relief_m at its nodes and linear between them), the CHMs are normalised by it (the true
    classes' DTM and the plain CHM over the open ground are ~0, not the terrain's tens of metres)
    and, with k = 1, the truth CHM is DSM − DTM."""
    from simlidar_mi.config import load_scene
    from simlidar_mi.io.terrain import relief_m, terrain_of
    from simlidar_mi.truth.als_truth import RasterGrid
    terrain = ("slope_deg = 35.0\naspect_deg = 90.0\nextent_m = [-40, 60, -40, 60]\ncell_m = 2.0" if form == "plane"
               else "hills_m = [[10.0, 10.0, 6.0, 5.0], [4.0, 16.0, -3.0, 3.0]]\nextent_m = [-40, 60, -40, 60]\n"
                    "cell_m = 1.0")
    scene, run = _terrain_run(tmp_path, terrain, k=1, box_z=(-30.0, 10.0))
    t = _read_truth(tmp_path / "als")
    g = run.summary["grid"]
    grid = RasterGrid(g["x0_m"], g["y0_m"], g["cell_m"], g["nx"], g["ny"])
    xc, yc = grid.centres()
    ter = terrain_of(load_scene(scene))
    relief = dict(slope_deg=35.0, aspect_deg=90.0, centre_m=(10.0, 10.0)) if form == "plane" else \
        dict(hills=[(10.0, 10.0, 6.0, 5.0), (4.0, 16.0, -3.0, 3.0)], centre_m=(10.0, 10.0))
    exact = relief_m(xc, yc, **relief)
    np.testing.assert_allclose(t["dtm"], ter.height_m(xc, yc), rtol=0, atol=2e-5)    # float32 file
    tol = 1e-5 if form == "plane" else 0.1      # hills: the 1 m grid's linear pieces (the −3 m, σ 3 m dip: 0.07 m)
    assert np.abs(t["dtm"] - exact).max() <= tol + 2e-5
    assert np.ptp(t["dtm"]) > (20.0 if form == "plane" else 5.0)
    np.testing.assert_allclose(t["chm"], t["dsm"] - t["dtm"], rtol=0, atol=5e-5)    # k = 1: one ray a cell
    box = (xc > 8.0) & (xc < 12.0) & (yc > 8.0) & (yc < 12.0)
    np.testing.assert_allclose(t["dsm"][box], 10.0, atol=1e-4)
    assert np.abs(t["chm"][~box]).max() < 1e-4                                       # bare ground: 0
    g_ = {r["method"]: r for r in run.ground}
    assert g_["true-classes"]["dtm_rmse_m"] < (0.05 if form == "plane" else 0.1)
    chm = {(r["chm"], r["stratum"]): r for r in run.chm}
    assert abs(chm[("plain", "all")]["bias_m"]) < 1.0
    assert t["crs"] is None


def test_evaluate_als_rasters_carry_the_dem_crs(tmp_path):
    """A DEM in UTM (EPSG:32633) and a scene that names no CRS: the truth and estimate rasters
    carry the DEM's CRS, and the truth DTM is the DEM's plane at UTM cell centres."""
    rasterio = pytest.importorskip("rasterio")
    from affine import Affine
    e0, n0 = 500_000.0, 5_000_000.0
    xs, ys = e0 - 40.0 + np.arange(101.0), n0 + 60.0 - np.arange(101.0)           # north row first
    z = 300.0 + 0.2 * (xs[None, :] - e0) - 0.1 * (ys[:, None] - n0)
    profile = {"driver": "GTiff", "width": 101, "height": 101, "count": 1, "dtype": "float64", "crs": "EPSG:32633",
               "transform": Affine(1.0, 0.0, e0 - 40.5, 0.0, -1.0, n0 + 60.5)}
    with rasterio.open(tmp_path / "dem.tif", "w", **profile) as dst:
        dst.write(z, 1)
    _, run = _terrain_run(tmp_path, 'file = "dem.tif"', origin=(e0, n0), box_z=(250.0, 320.0),
                          ground_z=300.0)  # the flight: 60 m over z 300 m
    t = _read_truth(tmp_path / "als")
    assert t["crs"].to_epsg() == 32633 and run.summary["crs"] == "EPSG:32633"
    with rasterio.open(tmp_path / "als" / "dtm_csf.tif") as r:
        assert r.crs.to_epsg() == 32633
    tr = t["transform"]
    rows, cols = np.indices(t["dtm"].shape)
    xc, yc = tr.c + (cols + 0.5) * tr.a, tr.f + (rows + 0.5) * tr.e
    np.testing.assert_allclose(t["dtm"], 300.0 + 0.2 * (xc - e0) - 0.1 * (yc - n0), rtol=0, atol=1e-4)
