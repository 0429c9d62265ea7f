"""LiDAR canopy estimators (issue #10 §4): the voxel walk, Beer–Lambert and the contact-frequency
MLE on a turbid medium of known PAD, multi-return weights, and plug-in scoring."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi.errors import ConfigError
from simlidar_mi.truth.estimators import (beams_from_exr, beams_from_scan, beer_lambert_pad,
                                          contact_mle_pad, point_occupancy, vcp_pad)
from simlidar_mi.truth.grid import VoxelGrid, grid_dataset
from simlidar_mi.truth.synthetic import turbid_beams
from simlidar_mi.truth.traverse import RANGE_TOL_M as TOL
from simlidar_mi.truth.traverse import Beams, _slab, traverse, walk

REPO = Path(__file__).resolve().parents[1]
GRID = VoxelGrid((-1.0, 0.5, 0.0), 0.25, (8, 6, 5))


def _brute(grid, o, d, t_end):
    """Float64 reference: every plane crossing along the ray, sorted; each piece's midpoint
    names its voxel. A different algorithm from the walk."""
    ts = [0.0, t_end]
    for ax in range(3):
        if d[ax] != 0:
            ts += [(e - o[ax]) / d[ax] for e in grid.edges(ax)]
    ts = np.array(sorted(t for t in ts if 0 <= t <= t_end))
    out = {}
    for a, b in zip(ts[:-1], ts[1:]):
        if b > a:
            ijk = np.floor((o + 0.5 * (a + b) * d - np.asarray(grid.corner_m)) / grid.voxel_m).astype(int)
            if np.all((ijk >= 0) & (ijk < grid.shape)):
                f = int(np.ravel_multi_index(tuple(ijk), grid.shape))
                out[f] = out.get(f, 0.0) + (b - a)
    return out


def _walked(grid, o, d, t_end):
    segs = {}
    for idx, flat, t0, t1 in walk(grid, o, d, t_end):
        length = np.minimum(t1, t_end[idx]) - t0
        for i, f, ln in zip(idx, flat, length):
            if ln > 0:
                segs.setdefault(int(i), {}).setdefault(int(f), 0.0)
                segs[int(i)][int(f)] += ln
    return segs


def test_walk_matches_a_brute_force_reference():
    rng = np.random.default_rng(3)
    n = 600
    o = rng.uniform(-3, 3, (n, 3)) + [0.0, 1.25, 0.6]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    # axis-parallel beams, some exactly along voxel faces and edges (grazing)
    o[:60] = [-2.0, 1.0, 0.5]
    d[:60] = [1.0, 0.0, 0.0]
    o[:60, 1] = 0.5 + 0.25 * rng.integers(0, 7, 60)
    o[:60, 2] = 0.25 * rng.integers(0, 6, 60)
    d[60:80] = [0.0, 0.0, -1.0]
    o[60:80] = [-0.5, 1.0, 3.0]
    # beams starting inside the grid, some on inner faces, heading anywhere
    o[80:160] = rng.uniform([-1, 0.5, 0], [1, 2, 1.25], (80, 3))
    o[140:160, 0] = -0.5
    # diagonal through voxel corners
    o[160:170] = [-1.5, 0.0, -0.5]
    d[160:170] = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    t_end = rng.uniform(0.3, 9.0, n)
    t_end[::7] = 1000.0  # escapes run through the whole grid
    segs = _walked(GRID, o, d, t_end)
    t_in, t_out = _slab(GRID, o, d)
    worst = 0.0
    for i in range(n):
        ref = _brute(GRID, o[i], d[i], t_end[i])
        got = segs.get(i, {})
        assert set(got) == set(ref), i
        worst = max([worst] + [abs(got[k] - ref[k]) for k in ref])
        # the pieces sum to the beam's length inside the grid
        inside = max(0.0, min(t_out[i], t_end[i]) - max(t_in[i], 0.0))
        assert sum(got.values()) == pytest.approx(inside, abs=1e-12)
    assert worst < 1e-12


def test_equal_chords_closed_form():
    """Beams along +x through a 1-voxel-thick slab: every chord is the voxel side, so
    Beer–Lambert is −ln(1 − I/N)/(G·v) and the MLE I/(G·Σ path), exactly."""
    g = VoxelGrid((0.0, 0.0, 0.0), 0.5, (1, 1, 1))
    n = 10
    o = np.column_stack([np.full(n, -1.0), np.linspace(0.05, 0.45, n), np.full(n, 0.25)])
    d = np.tile([1.0, 0.0, 0.0], (n, 1))
    r = np.full(n, 1000.0)
    cls = np.zeros(n, np.uint8)
    r[:4] = 1.0 + np.array([0.1, 0.2, 0.3, 0.4])  # four hits inside the voxel (x = 0.1 … 0.4)
    cls[:4] = 3
    c = traverse(g, Beams.first_return(o, d, r, cls))
    assert c.n_in.item() == 10 and c.hits.item() == 4
    assert c.chord_m.item() == pytest.approx(10 * 0.5)
    # returns are placed TOL before their range (traverse.RANGE_TOL_M)
    assert c.path_m.item() == pytest.approx(6 * 0.5 + 1.0 - 4 * TOL, rel=1e-12)
    assert beer_lambert_pad(c).item() == pytest.approx(-np.log(0.6) / (0.5 * 0.5))
    assert contact_mle_pad(c).item() == pytest.approx(4 / (0.5 * (4.0 - 4 * TOL)), rel=1e-12)
    # saturation: every beam intercepted → cap T = 1/(N + 1), or NaN
    cs = traverse(g, Beams.first_return(o, d, np.full(n, 1.25), np.full(n, 3)))
    assert beer_lambert_pad(cs).item() == pytest.approx(np.log(11) / (0.5 * 0.5))
    assert np.isnan(beer_lambert_pad(cs, saturated="nan")).item()


def test_unobserved_voxels_are_nan_and_occupancy_counts_points():
    g = VoxelGrid((0.0, 0.0, 0.0), 1.0, (3, 1, 1))
    b = Beams.first_return([[-1.0, 0.5, 0.5]], [[1.0, 0.0, 0.0]], [2.5], [2])  # stops in voxel 1
    c = traverse(g, b)
    assert c.n_in.ravel().tolist() == [1.0, 1.0, 0.0]
    for pad in (beer_lambert_pad(c, min_beams=1), contact_mle_pad(c, min_beams=1)):
        assert pad[0, 0, 0] == 0.0 and pad[1, 0, 0] > 0 and np.isnan(pad[2, 0, 0])
    for pad in (beer_lambert_pad(c), contact_mle_pad(c)):  # default: ≥ 5 beams
        assert np.isnan(pad).all()
    occ = point_occupancy(g, b, min_points=1)
    assert occ["point_count"].ravel().tolist() == [0.0, 1.0, 0.0]
    assert vcp_pad(c, occ["occupied"], min_beams=1).ravel()[1] == pytest.approx(1 / (0.5 * 1.0))
    # too few beams for a path: an occupied voxel's path is the voxel side (here the same)
    assert vcp_pad(c, occ["occupied"]).ravel().tolist()[1] == pytest.approx(1 / (0.5 * 1.0))
    with pytest.raises(ConfigError):
        point_occupancy(g, b, min_points=0)


def test_multi_return_weights_split_the_beam():
    """One beam, echoes in voxels 0 and 1 with equal weights: voxel 1 receives half a beam
    and intercepts it; voxel 2 (after the last echo) receives nothing."""
    g = VoxelGrid((0.0, 0.0, 0.0), 1.0, (3, 1, 1))
    b = Beams([[-1.0, 0.5, 0.5]], [[1.0, 0.0, 0.0]], [2.75], [[1.5, 2.75]], [[0.5, 0.5]], [[True, True]])
    c = traverse(g, b)
    assert c.n_in.ravel().tolist() == [1.0, 0.5, 0.0]
    assert c.hits.ravel().tolist() == [0.5, 0.5, 0.0]
    # path: voxel 0: 1·0.5 + 0.5·(0.5 − TOL); voxel 1: 0.5·(0.75 − TOL)
    assert c.path_m.ravel() == pytest.approx([0.75 - TOL / 2, 0.375 - TOL / 2, 0.0], rel=1e-12)


def test_turbid_medium_estimates_converge_to_the_truth():
    """PAD = 2 m²/m³ in 64 voxels of 0.25 m. Measured (BENCHMARKS §10d, 5 seeds): the MLE is
    unbiased (mean 1.999 at 64 k beams, 2.005 at 256 k) with a per-voxel RMS error falling
    as 1/√N (8 % at ≈ 870 beams per voxel, 4.5 % at ≈ 3 500); Beer–Lambert with the mean
    chord keeps a −2 % bias (Jensen: E[e^{−λl}] > e^{−λ·E l} for unequal chords).
    Tolerances: 64 voxels at 8 % each give a mean good to 1 % (1σ); we allow 3 %."""
    g = VoxelGrid((0.0, 0.0, 0.0), 0.25, (4, 4, 4))
    c = traverse(g, turbid_beams(64_000, 2.0, seed=11))
    mle, bl = contact_mle_pad(c), beer_lambert_pad(c)
    assert np.all(np.isfinite(mle)) and np.median(c.n_in) > 800
    assert np.mean(mle) == pytest.approx(2.0, rel=0.03)
    assert np.mean(bl) == pytest.approx(1.96, rel=0.03)
    assert np.sqrt(np.mean((mle - 2) ** 2)) / 2 < 0.12
    c4 = traverse(g, turbid_beams(4_000, 2.0, seed=11))
    err4 = np.sqrt(np.mean((contact_mle_pad(c4) - 2) ** 2))
    err64 = np.sqrt(np.mean((mle - 2) ** 2))
    assert 2.5 < err4 / err64 < 6.5  # 1/√N: √16 = 4


@pytest.fixture(scope="module")
def cylinder_scan(tmp_path_factory):
    from simlidar_mi.lidar.survey import load_scene, run_scan
    out = tmp_path_factory.mktemp("cyl") / "scan"
    cfg = load_scene(REPO / "scenes" / "calibration_cylinder.toml",
                     ["scan.dy_m=0.02", "scan.dtheta_deg=1.0"])
    run = run_scan(cfg, out, write_png=False)
    return out, run.result


def test_exr_beams_equal_scan_beams(cylinder_scan):
    out, result = cylinder_scan
    a, b = beams_from_scan(result), beams_from_exr(out / "scan.exr")
    assert len(a) == len(b) == result.range_m.size
    np.testing.assert_allclose(a.origin_m, b.origin_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.dir, b.dir, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(a.t_end_m, b.t_end_m)
    np.testing.assert_array_equal(a.ret_veg, b.ret_veg)
    assert a.ret_veg.sum() > 0


def test_plugin_is_scored_like_the_builtin_and_bad_output_is_refused(cylinder_scan, tmp_path):
    from simlidar_mi.truth.evaluate import evaluate_beams
    out, result = cylinder_scan
    grid = VoxelGrid.covering([1.9, -0.1, 0.4], [2.1, 0.1, 1.6], 0.05)
    truth = grid_dataset(grid, {"PAD_m2_m3": np.random.default_rng(0).uniform(0, 5, grid.shape)})
    sys.path.insert(0, str(REPO))
    try:
        run = evaluate_beams(grid, truth, beams_from_scan(result), stage=tmp_path, scan_dir=out,
                             plugins=["examples.my_estimator:contact_frequency"],
                             commands=[f"{sys.executable} {REPO / 'examples/my_estimator.py'} {{las}} {{grid}} {{out}}"])
    finally:
        sys.path.remove(str(REPO))
    for scale in ("voxel", "profile"):
        mine, builtin = run.get("contact_frequency", scale), run.get("contact_mle", scale)
        assert {k: mine[k] for k in ("n", "r2", "rmse", "bias")} == {k: builtin[k] for k in ("n", "r2", "rmse", "bias")}
    assert run.get("contact_mle")["n"] > 0
    # one voxel set for every estimator, fixed by the scan
    assert run.get("cmd1")["n"] == run.get("contact_mle")["n"] == run.summary["n_observed_voxels"]
    assert run.get("cmd1")["n_estimated"] == run.get("cmd1")["n"]
    for name in ("scores.csv", "scores.json", "profiles.csv", "profiles.png", "scatter.png", "truth.nc",
                 "grid.nc", "estimates/contact_mle.nc", "estimates/cmd1.nc"):
        assert (tmp_path / name).is_file(), name

    def wrong_shape(scan_dir, g):
        return {"PAD_m2_m3": np.zeros((g.shape[0] + 1, g.shape[1], g.shape[2]))}

    with pytest.raises(ConfigError) as e:
        evaluate_beams(grid, truth, beams_from_scan(result), scan_dir=out, plugins=[wrong_shape])
    assert e.value.file == "wrong_shape" and e.value.key == "PAD_m2_m3"
    assert e.value.value == [grid.shape[0] + 1, grid.shape[1], grid.shape[2]]
    with pytest.raises(ConfigError) as e:
        evaluate_beams(grid, truth, beams_from_scan(result), scan_dir=out, plugins=[lambda s, g: {"x": 1}])
    assert e.value.key == "PAD_m2_m3" and "has: x" in str(e.value)


def test_real_leaves_in_a_box():
    """Mitsuba scan of 2000 spherical leaves of 10 cm² in the unit cube (PAD = 2 m²/m³ on
    average): the MLE over the 32 voxels of the two inner layers (no leaf spills out of
    them) measured 2.047 against the leaf-centre truth 2.008 (+2 %, 814 beams per voxel;
    BENCHMARKS §10d). 5 % allows for finite leaves (3 cm in 25 cm voxels) at this seed."""
    from simlidar_mi.truth.synthetic import leaf_box_scan
    beams, grid, truth, canopy = leaf_box_scan(dy_m=0.01, dtheta_deg=0.2)
    c = traverse(grid, beams)
    inner = (slice(None), slice(None), slice(1, 3))
    assert truth[inner].mean() == pytest.approx(2.0, rel=0.01)
    assert np.nanmean(contact_mle_pad(c)[inner]) == pytest.approx(truth[inner].mean(), rel=0.05)
    assert np.nanmean(beer_lambert_pad(c)[inner]) == pytest.approx(truth[inner].mean(), rel=0.05)


def test_multi_return_beams_from_exr_equal_the_scan(tmp_path):
    """Echo layers of scan.exr (float32 ranges) rebuild the weighted beams of the scan."""
    from simlidar_mi.lidar.survey import load_scene, run_scan
    cfg = load_scene(REPO / "scenes" / "orchard_lms511.toml", ["scan.dy_m=0.2", "sensor.beam_samples=8"])
    res = run_scan(cfg, tmp_path / "scan", write_png=False).result
    assert res.echoes is not None and res.echoes.return_number.max() >= 2
    for w in ("equal", "raw-energy"):
        a, b = beams_from_scan(res, w), beams_from_exr(tmp_path / "scan" / "scan.exr", weights=w)
        assert a.ret_range_m.shape == b.ret_range_m.shape
        np.testing.assert_array_equal(np.isfinite(a.ret_range_m), np.isfinite(b.ret_range_m))
        fin = np.isfinite(a.ret_range_m)
        np.testing.assert_allclose(a.ret_range_m[fin], b.ret_range_m[fin], rtol=1e-6)
        np.testing.assert_allclose(a.ret_weight, b.ret_weight, rtol=1e-6)
        np.testing.assert_allclose(a.ret_weight.sum(axis=1)[fin[:, 0]], 1.0)
        np.testing.assert_array_equal(a.ret_veg, b.ret_veg)
    with pytest.raises(ConfigError):
        beams_from_scan(res, "loudest")
    with pytest.raises(ConfigError, match="incidence"):  # the EXR holds no per-echo cos i
        beams_from_exr(tmp_path / "scan" / "scan.exr", weights="energy")
    w = beams_from_scan(res, "energy").ret_weight
    fin = np.isfinite(beams_from_scan(res, "equal").ret_range_m[:, 0])
    np.testing.assert_allclose(w.sum(axis=1)[fin], 1.0)


def test_energy_weights_are_the_intercepted_share_two_target_closed_form():
    """A leaf at 1.5 m (ρ 0.45, normal incidence) intercepts half of a beam in front of ground
    at 3 m (ρ 0.2, cos i 0.5). Through the waveform detector (two sub-rays of weight ½, the
    energy law of lidar/sensor.py) the echo energies are E ∝ ½·ρ·|cos i|/r²: E/ΣE gives the
    leaf 0.947 (its voxel's PAD ~4× too high); E·r²/(ρ·|cos i|) normalised gives ½ and ½."""
    from simlidar_mi.lidar.waveform import detect_echoes
    from simlidar_mi.truth.estimators import _echo_beams
    r = np.array([[1.5, 3.0]])
    rho, cos = np.array([0.45, 0.2]), np.array([1.0, 0.5])
    r_ref = 40.0 * np.sqrt(0.02 / 0.1)
    e = 0.5 * rho * cos * (r_ref / r) ** 2
    ech = detect_echoes(r, e, np.array([[3, 1]], np.uint8), np.zeros((1, 2), np.uint32), None,
                        cos[None, :], np.array([0]), pulse_length_ns=3.0, detection_threshold=0.02,
                        max_returns=5)
    assert list(ech.range_m.round(6)) == [1.5, 3.0] and list(ech.cls) == [3, 1]
    refl = np.array([0.0, 0.2, 0.35, 0.45])
    args = (np.zeros((1, 3)), np.array([[1.0, 0, 0]]), 1, ech.beam, ech.return_number, ech.range_m,
            ech.cls, ech.energy, 100.0)
    share = _echo_beams(*args, "energy", ech.cos_incidence, refl).ret_weight[0]
    np.testing.assert_allclose(share, [0.5, 0.5], rtol=1e-6)
    raw = _echo_beams(*args, "raw-energy").ret_weight[0]
    np.testing.assert_allclose(raw[0], 0.45 / 2.25 / (0.45 / 2.25 + 0.1 / 9), rtol=1e-6)
    assert raw[0] > 0.94


def test_bad_plugins_are_refused_naming_what_is_wrong(tmp_path):
    from simlidar_mi.truth.grid import write_grid
    from simlidar_mi.truth.scoring import check_command, load_plugin, run_command
    for spec in ("no_colon", "examples/none.py:f", "json:no_such_function"):
        with pytest.raises(ConfigError) as e:
            load_plugin(spec)
        assert e.value.key == "--estimator" and e.value.value == spec
    for cmd in ("python x.py {las}", "python x.py {bogus} {out}"):
        with pytest.raises(ConfigError) as e:
            check_command(cmd)
        assert e.value.key == "--estimator-cmd"
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.5, (2, 3, 4))
    other = VoxelGrid((0.0, 0.0, 0.0), 0.5, (2, 3, 5))
    theirs = write_grid(grid_dataset(other, {"PAD_m2_m3": np.zeros(other.shape)}), tmp_path / "theirs.nc")
    out = tmp_path / "out.nc"
    cmd = f"{sys.executable} -c \"import shutil, sys; shutil.copy(sys.argv[1], sys.argv[2])\" {theirs} {{out}}"
    with pytest.raises(ConfigError) as e:
        run_command(cmd, las=tmp_path / "p.las", exr=tmp_path / "s.exr", grid_file=tmp_path / "g.nc",
                    out=out, grid=grid)
    # named by the command the user typed: {out} and {grid} are staging files, deleted by then
    assert e.value.file == f"--estimator-cmd {cmd}" and e.value.value == [2, 3, 5]
    assert str(out) not in str(e.value) and "g.nc" not in str(e.value) and "grid.nc" in str(e.value)
    with pytest.raises(ConfigError) as e:
        run_command(f"{sys.executable} -c \"raise SystemExit('boom')\" {{out}}", las=out, exr=out,
                    grid_file=out, out=tmp_path / "none.nc", grid=grid)
    assert "status 1" in str(e.value) and "boom" in str(e.value)


def test_a_return_on_a_voxel_face_counts_in_the_voxel_the_beam_came_from():
    """A surface on the face z = 1 m met from above, its float32 range rounded one step (0.24 µm) long:
    the hit belongs to the upper voxel, and the lower one is not entered at all."""
    g = VoxelGrid((0.0, 0.0, 0.0), 1.0, (1, 1, 2))
    r = float(np.nextafter(np.float32(2.0), np.float32(3.0)))  # one float32 step long
    assert r > 2.0
    c = traverse(g, Beams.first_return([[0.5, 0.5, 3.0]], [[0.0, 0.0, -1.0]], [r], [2]))
    assert c.hits.ravel().tolist() == [0.0, 1.0]
    assert c.n_in.ravel().tolist() == [0.0, 1.0]


def test_evaluate_command_end_to_end(tmp_path):
    """`simlidar-mi evaluate` on the leafy orchard, coarsely: every output, the plug-in scored
    like its built-in, the truth from compute_truth, TRV/LWA of truth and points."""
    import json

    from simlidar_mi.cli import main
    from simlidar_mi.truth.grid import read_grid
    out = tmp_path / "ev"
    rc = main(["evaluate", str(REPO / "scenes" / "orchard_leafy.toml"), "--out", str(out), "--voxel", "0.25",
               "--set", "scan.dtheta_deg=1.0", "--set", "scan.dy_m=0.04",
               "--estimator", f"{REPO / 'examples' / 'my_estimator.py'}:contact_frequency"])
    assert rc == 0
    d = json.loads((out / "scores.json").read_text())
    rows = {(r["estimator"], r["scale"]): r for r in d["scores"]}
    assert rows[("contact_frequency", "voxel")]["rmse"] == rows[("contact_mle", "voxel")]["rmse"]
    assert rows[("beer_lambert", "profile")]["r2"] > 0.5
    env = d["summary"]["envelope"]
    assert env["row_spacing_m"] == 4.0 and env["truth"]["TRV_m3_ha"] > 0 and env["points"]["LWA_m2_ha"] > 0
    grid, truth = read_grid(out / "truth.nc", "PAD_m2_m3")
    _, est = read_grid(out / "estimates" / "beer_lambert.nc", "PAD_m2_m3")
    assert est["PAD_m2_m3"].dims == truth["PAD_m2_m3"].dims == ("z", "y", "x")  # CF order, as on file
    assert est["PAD_m2_m3"].shape == truth["PAD_m2_m3"].shape == grid.shape[::-1]
    # the truth's G along the beams, and the oracle runs that divide by it (PAD ~ 1/G)
    g_leaf = truth["G_leaf"].values
    assert truth["G_leaf"].dims == ("z", "y", "x") and np.nanmin(g_leaf) >= 0 and np.nanmax(g_leaf) <= 1
    assert np.isfinite(g_leaf).sum() > 0 and np.all(np.isfinite(g_leaf) <= (truth["leaf_area_m2"].values > 0))
    g_canopy = d["summary"]["G_plant_canopy"]
    assert truth.attrs["G_plant_canopy"] == pytest.approx(g_canopy) and 0.3 < g_canopy < 0.6
    for name in ("beer_lambert", "contact_mle"):
        assert rows[(f"{name}_Gcanopy", "voxel")]["estimate_mean"] == pytest.approx(
            rows[(name, "voxel")]["estimate_mean"] * 0.5 / g_canopy, rel=1e-9)
        assert rows[(f"{name}_Gvoxel", "voxel")]["n"] == rows[(name, "voxel")]["n"]
    for name in ("scores.csv", "profiles.csv", "profiles.png", "scatter.png", "grid.nc", "scan/scan.exr",
                 "scan/points.las"):
        assert (out / name).is_file(), name
    assert main(["evaluate", str(REPO / "scenes" / "orchard_leafy.toml"), "--out", str(tmp_path / "bad"),
                 "--estimator", "no_colon"]) == 2
    assert not (tmp_path / "bad" / "scan").exists()
    # a scan streamed to files (more beams than chunk_beams) is read back from scan.exr: same scores
    assert main(["evaluate", str(REPO / "scenes" / "orchard_leafy.toml"), "--out", str(tmp_path / "streamed"),
                 "--voxel", "0.25", "--set", "scan.dtheta_deg=1.0", "--set", "scan.dy_m=0.04",
                 "--set", "scan.chunk_beams=5000"]) == 0
    d2 = json.loads((tmp_path / "streamed" / "scores.json").read_text())
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows  # noqa: E731
                          if r["estimator"] != "contact_frequency"]
    assert strip(d2["scores"]) == strip(d["scores"])


def test_plugin_failures_are_one_line_and_odd_estimates_are_refused_or_reported(cylinder_scan, tmp_path):
    """A plug-in that does not compile or raises, one giving infinities, or one that scores
    nothing or gives negative PAD: a one-line error or warning, never a traceback or a silent n = 0."""
    import warnings

    from simlidar_mi.errors import SimlidarWarning
    from simlidar_mi.truth.evaluate import evaluate_beams
    from simlidar_mi.truth.scoring import load_plugin
    (tmp_path / "broken.py").write_text("def f(scan_dir, grid)\n    return {}\n")
    (tmp_path / "raises_on_import.py").write_text("raise RuntimeError('no licence')\n")
    for spec, words in ((f"{tmp_path / 'broken.py'}:f", "SyntaxError"),
                        (f"{tmp_path / 'raises_on_import.py'}:f", "RuntimeError: no licence")):
        with pytest.raises(ConfigError) as e:
            load_plugin(spec)
        first, *rest = str(e.value).split("\n")
        assert e.value.key == "--estimator" and e.value.value == spec and words in first
    assert rest == ["  in your code (most recent call last):",  # the module's own frame, none of ours
                    f'    File "{tmp_path / "raises_on_import.py"}", line 1, in <module>',
                    "      raise RuntimeError('no licence')"]
    out, result = cylinder_scan
    grid = VoxelGrid.covering([1.9, -0.1, 0.4], [2.1, 0.1, 1.6], 0.05)
    truth = grid_dataset(grid, {"PAD_m2_m3": np.ones(grid.shape)})
    beams = beams_from_scan(result)

    def raises(scan_dir, g):
        raise ZeroDivisionError("division by zero")

    with pytest.raises(ConfigError) as e:
        evaluate_beams(grid, truth, beams, scan_dir=out, plugins=[raises])
    first, *rest = str(e.value).split("\n")
    assert e.value.key == "--estimator" and first.endswith("ZeroDivisionError: division by zero")
    assert rest[0] == "  in your code (most recent call last):" and "in raises" in rest[1]
    assert not any("simlidar_mi" in line for line in rest)  # the user's frames, not ours
    with pytest.raises(ConfigError) as e:
        evaluate_beams(grid, truth, beams, scan_dir=out,
                       plugins=[lambda s, g: {"PAD_m2_m3": np.full(g.shape, np.inf)}])
    assert e.value.key == "PAD_m2_m3" and f"{np.prod(grid.shape)} of {np.prod(grid.shape)} values are infinite" \
        in str(e.value)

    def nothing(scan_dir, g):
        return {"PAD_m2_m3": np.full(g.shape, np.nan)}

    def negative(scan_dir, g):
        return {"PAD_m2_m3": np.full(g.shape, -2.0)}

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = evaluate_beams(grid, truth, beams, scan_dir=out, plugins=[nothing, negative])
    said = [str(w.message) for w in caught if issubclass(w.category, SimlidarWarning)]
    n_obs = run.summary["n_observed_voxels"]
    assert run.get("nothing")["n_estimated"] == 0 and run.get("nothing")["n"] == n_obs > 0
    assert run.get("nothing")["coverage_voxels"] == 0.0
    assert run.get("nothing")["bias"] == pytest.approx(-1.0)  # abstentions scored as 0 against 1
    assert f"estimator nothing: no finite PAD_m2_m3 in the {n_obs} voxels the scan observed" in said[0]
    assert said[1] == (f"estimator negative: {n_obs} voxels hold a negative PAD_m2_m3 (down to -2); "
                       "scored as given")
    assert run.get("negative")["bias"] == pytest.approx(-3.0)  # scored as given: -2 against 1
    assert len(said) == 2  # the built-in estimators give neither


def test_a_plugin_that_raises_shows_its_own_frames_not_ours(tmp_path):
    """'the estimator failed: ValueError: my bug' alone left the user guessing which line of
    theirs failed: the error names it, with their frames only (innermost last)."""
    from simlidar_mi.truth.scoring import call_plugin, load_plugin
    (tmp_path / "mine.py").write_text("def helper(x):\n    raise ValueError('my bug')\n\n\n"
                                      "def f(scan_dir, grid):\n    return helper(1)\n")
    spec = f"{tmp_path / 'mine.py'}:f"
    with pytest.raises(ConfigError) as e:
        call_plugin(load_plugin(spec), spec, tmp_path, VoxelGrid.covering([0, 0, 0], [1, 1, 1], 0.5))
    lines = str(e.value).split("\n")
    assert lines[0].endswith("the estimator failed: ValueError: my bug")
    files = [ln.strip() for ln in lines if ln.strip().startswith("File ")]
    assert files == [f'File "{tmp_path / "mine.py"}", line 6, in f',
                     f'File "{tmp_path / "mine.py"}", line 2, in helper']
    assert "raise ValueError('my bug')" in lines[-1] and "simlidar_mi" not in "".join(lines[1:])
