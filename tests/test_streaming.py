"""Streamed scans (issue #8): chunk size never changes a file, and the EXR's 1-D constants."""
from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.io.exr import read_exr
from simlidar_mi.lidar.scan import read_scan_exr
from simlidar_mi.lidar.stream import StreamedScan
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES

CALIB = SCENES / "calibration_cylinder.toml"


def _run(tmp_path, chunk, extra=()):
    out = tmp_path / f"c{chunk}"
    cfg = load_scene(CALIB, [f"scan.chunk_beams={chunk}", *extra])
    cfg_sha = cfg.sha256
    run = run_scan(cfg, out)
    return run, out, cfg_sha


def test_chunk_size_does_not_change_exr_png_or_points(tmp_path):
    whole, out_w, _ = _run(tmp_path, 10**9)
    n, m = whole.result.shape
    assert (n, m) == (250, 360) and not isinstance(whole.result, StreamedScan)
    ch_w, h_w = read_exr(out_w / "scan.exr")
    las_w = laspy.read(out_w / "points.las")
    for chunk in (m, 3 * m, 7, 997):  # one row, three rows, pieces of a row, rows + a piece
        run, out, _ = _run(tmp_path, chunk)
        assert isinstance(run.result, StreamedScan) and run.result.shape == (n, m)
        ch, h = read_exr(out / "scan.exr")
        assert set(ch) == set(ch_w) == {"range", "class", "class_half", "branch_id"}
        for k in ch:
            assert np.array_equal(ch[k], ch_w[k]), (chunk, k)
        assert (out / "scan.png").read_bytes() == (out_w / "scan.png").read_bytes()
        las = laspy.read(out / "points.las")
        assert len(las.points) == len(las_w.points) == int((ch_w["class"] != 0).sum())
        assert np.array_equal(las.header.offsets, las_w.header.offsets)
        for d in las_w.point_format.dimension_names:
            assert np.array_equal(np.asarray(las[d]), np.asarray(las_w[d])), (chunk, d)
        assert run.measures["hits"] == whole.measures["hits"]
        assert run.measures["A_IM_m2"] == whole.measures["A_IM_m2"]  # np.sum's bits (PairwiseSum)
        assert run.measures["A_IM_yz_m2"] == whole.measures["A_IM_yz_m2"]


def test_exr_and_las_bytes_equal_across_chunk_sizes(tmp_path):
    """One scene (one scene_sha256 in the header), chunk_beams set on the loaded config."""
    files = []
    for chunk in (10**9, 360, 7, 1000):
        cfg = load_scene(CALIB)
        cfg["scan"]["chunk_beams"] = chunk
        run = run_scan(cfg, tmp_path / f"o{chunk}")
        files.append({k: run.files[k].read_bytes() for k in ("exr", "png", "las")})
    for f in files[1:]:
        assert f == files[0]  # every byte, the LAS header and its VLRs included
    eb = laspy.read(tmp_path / "o7" / "points.las").header.vlrs.get("ExtraBytesVlr")[0]
    assert [s.options & 6 for s in eb.extra_bytes_structs] == [0] * 6  # no min/max statistics


def test_footprint_and_any_rule_stream_identically(tmp_path):
    extra = ["scan.footprint=1", 'scan.hit_rule="any"', "scan.dtheta_deg=1.0"]
    whole, out_w, _ = _run(tmp_path, 10**9, extra)
    part, out_p, _ = _run(tmp_path, 23, extra)  # pieces of a row (M = 91)
    a, b = read_exr(out_w / "scan.exr")[0], read_exr(out_p / "scan.exr")[0]
    assert "hit_fraction" in a and all(np.array_equal(a[k], b[k]) for k in a)
    assert part.measures["A_IM_m2"] == whole.measures["A_IM_m2"]  # the same sum, bit for bit


def test_constants_are_header_arrays_and_the_helper_broadcasts_them(tmp_path):
    run, out, _ = _run(tmp_path, 10**9)
    s = run.result.settings
    ch, h = read_scan_exr(out / "scan.exr")
    assert "theta_deg" not in ch and "y_m" not in ch
    assert np.array_equal(h["theta_deg"], s.theta_deg) and np.array_equal(h["y_m"], s.y_m)  # float64, exact
    assert json.loads(h["simlidar_theta_deg"])[1] == s.theta_deg[1]
    ch, h = read_scan_exr(out / "scan.exr", broadcast=True)
    n, m = s.n_positions, s.n_angles
    assert ch["theta_deg"].shape == (n, m) and ch["theta_deg"].dtype == np.float32
    assert np.array_equal(ch["theta_deg"][7], s.theta_deg.astype(np.float32))
    assert np.array_equal(ch["y_m"][:, 3], (s.y_m - h["origin_m"][1]).astype(np.float32))


def test_sensor_scan_does_not_depend_on_chunk_beams(tmp_path):
    text = CALIB.read_text() + "\n[sensor]\ndivergence_mrad = 3.0\nbeam_samples = 7\n"
    scene = tmp_path / "s.toml"
    scene.write_text(text)
    runs = [run_scan(load_scene(scene, [f"scan.chunk_beams={c}", "scan.dtheta_deg=1.0"]), tmp_path / f"p{c}",
                     write_png=False) for c in (10**9, 997)]
    a, b = (read_exr(r.files["exr"])[0] for r in runs)
    assert set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)
    la, lb = (laspy.read(r.files["las"]) for r in runs)
    assert len(la.points) > 100 and np.array_equal(np.asarray(la.xyz), np.asarray(lb.xyz))


def test_chunk_beams_is_validated():
    from simlidar_mi.errors import ConfigError
    with pytest.raises(ConfigError, match="chunk_beams"):
        load_scene(CALIB, ["scan.chunk_beams=0"])
