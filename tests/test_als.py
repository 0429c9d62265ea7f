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

# the southern half of the stand (elms and spruces) at half the work of the whole
SMALL = ["forest.domain_m=[0.0, 40.0, 0.0, 20.0]", "platform.end_xy_m=[20.0, 22.0]"]


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "simlidar_mi.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)


def test_evaluate_als_end_to_end_on_a_small_airborne_forest(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from simlidar_mi.lidar.survey import run_scan
    from simlidar_mi.truth.als_evaluate import evaluate_als
    run_scan(SCENES / "forest_als_small.toml", tmp_path / "scan", SMALL, write_png=False)

    def mine(points):  # a user's ground method: the lowest 70 % of the points
        return points["z"] <= np.quantile(points["z"], 0.7)

    run = evaluate_als(SCENES / "forest_als_small.toml", tmp_path / "scan" / "points.las", tmp_path / "als",
                       SMALL, ground_plugins=[mine], tree_plugins=[f"{Path(__file__).parent / 'als_plugin.py'}:tallest_cell"])
    g = {r["method"]: r for r in run.ground}
    assert set(g) == {"true-classes", "csf", "pmf", "mine"}
    assert g["true-classes"]["kappa"] == 1.0 and g["true-classes"]["total_error"] == 0.0
    assert g["true-classes"]["dtm_rmse_m"] < 0.02          # flat ground: the TIN is the plane
    assert g["csf"]["kappa"] > 0.95 and g["pmf"]["kappa"] > 0.95
    files = {p.name for p in (tmp_path / "als").iterdir()}
    for name in ("als_scores.json", "ground_scores.csv", "dtm_scores.csv", "chm_scores.csv", "tree_scores.csv",
                 "truth_trees.csv", "truth_dtm.tif", "truth_dsm.tif", "truth_chm.tif", "truth_tree_id.tif",
                 "dtm_csf.tif", "chm_pitfree.tif", "dtm_error.png", "chm_trees.png", "detection_by_height.png"):
        assert name in files, name
    summary = json.loads((tmp_path / "als" / "als_scores.json").read_text())
    assert summary["n_trees"] >= 3 and (summary["grid"]["nx"], summary["grid"]["ny"]) == (80, 40)
    with rasterio.open(tmp_path / "als" / "truth_chm.tif") as r:
        chm = r.read(1)
        assert r.crs is None and r.shape == (40, 80)
    with rasterio.open(tmp_path / "als" / "truth_tree_id.tif") as r:
        tid = r.read(1)
        assert r.nodata == -1
    import csv
    trees = list(csv.DictReader(open(tmp_path / "als" / "truth_trees.csv")))
    for t in trees:  # no ray meets a tree above its top; the trees it owns cells of are not overtopped
        own = tid == int(t["tree_id"])
        assert (int(t["top_cells"]) == int(own.sum())) and (t["overtopped"] == str(int(not own.any())))
        if own.any():
            assert chm[own].max() <= float(t["height_m"]) + 1e-3
    tops = [float(t["height_m"]) - chm[tid == int(t["tree_id"])].max() for t in trees if int(t["top_cells"])]
    assert np.median(tops) < 0.5
    tr = {(r["method"], r["group"]): r for r in run.trees}
    assert tr[("lmf on truth CHM", "all")]["detection_rate"] >= tr[("lmf", "all")]["detection_rate"] - 0.2
    assert ("tallest_cell", "all") in tr and tr[("tallest_cell", "all")]["n_detected"] == 1


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
