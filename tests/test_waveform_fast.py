"""The scan's echo detector (waveform_fast.detect_subray_echoes) gives the bits of the
reference path (waveform_fast.reference_echoes: subray_energy + waveform.detect_echoes on float64
arrays): every echo array on random beams and on the included sensor scenes, and the bytes of
their output files."""
from __future__ import annotations

import json
from dataclasses import fields, replace

import numpy as np
import pytest

import simlidar_mi.lidar.physical as physical
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.scan import scan_physical
from simlidar_mi.lidar.sensor import SensorModel
from simlidar_mi.lidar.survey import build, generate, run_scan, scan_patterns, scene_sensor
from simlidar_mi.lidar.waveform_fast import detect_subray_echoes, reference_echoes
from tests.conftest import SCENES
from tests.test_sensor_stream import AIRBORNE, LMS511, VLP16


def _reference(model, t, cos_i, rho, cls, elem, tree, weight, beam):
    """The scan's detector before: float64 copies, energies of every sub-ray, detect_echoes."""
    return reference_echoes(model, np.asarray(t, np.float64), cls, elem, tree, np.asarray(cos_i, np.float64),
                            np.asarray(rho, np.float64), weight, beam)


def _assert_same(a, b):
    assert len(a) == len(b)
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is None or y is None:
            assert x is None and y is None, f.name
            continue
        assert x.dtype == y.dtype and x.shape == y.shape, f.name
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), f.name  # bits, NaN included


def _beams(rng, b, s, *, spread_m, far_share, escape_share, tie_share=0.0):
    """(B, S) float32 ranges: one surface per beam (within ``spread_m``), a second one
    0.1–3 m farther for a ``far_share`` of the sub-rays, escapes, and repeated ranges."""
    base = rng.uniform(0.5, 60.0, (b, 1))
    r = base + rng.uniform(0, spread_m, (b, s))
    far = rng.random((b, s)) < far_share
    r = np.where(far, r + rng.uniform(0.1, 3.0, (b, 1)), r)
    tie = rng.random((b, s)) < tie_share
    r = np.where(tie, r[:, :1], r)
    r[rng.random((b, s)) < escape_share] = np.inf
    return r.astype(np.float32)


@pytest.mark.parametrize("s", [1, 4, 19, 64])
@pytest.mark.parametrize("rule", ["amplitude", "basin"])
def test_random_beams_give_the_reference_bits(s, rule):
    rng = np.random.default_rng(s)
    b = 3000
    parts = [_beams(rng, b, s, spread_m=0.01, far_share=0.0, escape_share=0.05, tie_share=0.2),
             _beams(rng, b, s, spread_m=0.3, far_share=0.0, escape_share=0.1),
             _beams(rng, b, s, spread_m=0.02, far_share=0.3, escape_share=0.2),
             _beams(rng, b, s, spread_m=2.0, far_share=0.5, escape_share=0.0)]
    t = np.concatenate(parts)
    n = len(t)
    cos_i = rng.uniform(0, 1, (n, s)).astype(np.float32)
    cos_i[rng.random((n, s)) < 0.03] = 0.0                 # grazing: no energy
    cls = rng.integers(1, 4, (n, s)).astype(np.uint8)
    rho = np.array([0.0, 0.2, 0.35, 0.45], np.float32)[cls]
    rho[rng.random((n, s)) < 0.02] = 0.0
    cos_i[~np.isfinite(t)], cls[~np.isfinite(t)] = 0.0, 0
    elem = rng.integers(0, 1 << 20, (n, s)).astype(np.uint32)
    weight = np.full(s, 1.0 / s)
    beam = np.arange(n, dtype=np.int64) * 3 + 7
    for tree in (None, rng.integers(0, 9, (n, s)).astype(np.uint32)):
        for kw in ({}, {"max_returns": 1}, {"range_min_m": 2.0, "range_max_m": 40.0},
                   {"detection_threshold": 0.002, "pulse_length_ns": 5.0}):
            model = replace(SensorModel(divergence_mrad=1.0, beam_samples=s, max_returns=3, echo_rule=rule), **kw)
            ref = _reference(model, t, cos_i, rho, cls, elem, tree, weight, beam)
            fast = detect_subray_echoes(model, t, cos_i, rho, cls, elem, tree, weight, beam)
            assert len(ref) > 100
            _assert_same(ref, fast)


def test_single_surface_beams_alone_come_in_beam_order():
    """Every beam one narrow cluster (the blocks of several spans and sizes): one echo per
    beam, in beam order, as the reference."""
    rng = np.random.default_rng(5)
    s, n = 19, 4000
    t = _beams(rng, n, s, spread_m=0.2, far_share=0.0, escape_share=0.0)
    gone = rng.random((n, s)) < 0.05
    gone[:, :3] = False                    # sizes 16-19, none of one sub-ray
    t[gone] = np.inf
    cos_i = np.where(np.isfinite(t), 0.9, 0.0).astype(np.float32)
    rho = np.where(np.isfinite(t), 0.3, 0.0).astype(np.float32)
    z = np.zeros((n, s), np.uint32)
    model = SensorModel(divergence_mrad=0.3, beam_samples=s, max_returns=5, range_at_10pct_m=200.0)
    args = (t, cos_i, rho, z.astype(np.uint8), z, None, np.full(s, 1.0 / s), np.arange(n))
    ref, fast = _reference(model, *args), detect_subray_echoes(model, *args)
    assert len(ref) == n and np.all(np.diff(fast.beam) > 0)
    _assert_same(ref, fast)


def test_no_valid_sub_ray_gives_no_echo():
    t = np.full((5, 4), np.inf, np.float32)
    z = np.zeros((5, 4), np.float32)
    out = detect_subray_echoes(SensorModel(divergence_mrad=1.0, beam_samples=4), t, z, z, z.astype(np.uint8),
                               z.astype(np.uint32), None, np.full(4, 0.25), np.arange(5))
    assert len(out) == 0 and out.tree_id is None


def _reference_patch(model, t, cos_i, rho, cls, elem, tree, weight, beam):
    return _reference(model, t, cos_i, rho, cls, elem, tree, weight, beam)


SCENE_CASES = [("orchard_lms511.toml", LMS511), ("orchard_vlp16_tractor.toml", VLP16),
               ("forest_airborne_echoes.toml", AIRBORNE),
               # the 0.3 mrad, 19-sub-ray tractor of BENCHMARKS.md (bench/bench_fullwave.py), a slice
               ("simlidar_table3_7x4.toml", ["scan.y_start_m=1.0", "scan.y_end_m=1.4", "sensor.divergence_mrad=0.3",
                                             "sensor.beam_samples=19", "sensor.max_returns=5",
                                             "sensor.intensity=true"])]


@pytest.mark.parametrize("scene,overrides", SCENE_CASES, ids=[c[0] for c in SCENE_CASES])
def test_included_scenes_same_echoes_and_files(tmp_path, monkeypatch, scene, overrides):
    overrides = [*overrides, 'sensor.waveform_reader="numpy"']  # the kernel: tests/test_waveform_kernel.py
    cfg = load_scene(SCENES / scene, overrides)
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    built = build(cfg, g, pats)
    model = scene_sensor(cfg, g, pats)
    assert model is not None and model.needs_energy and model.waveform_reader == "numpy"
    fast = [scan_physical(built, p, model, seed=cfg.seed, leg=j, chunk_beams=5000) for j, p in enumerate(pats)]
    files = {}
    for name in ("fast", "reference"):
        if name == "reference":
            monkeypatch.setattr(physical, "detect_subray_echoes", _reference_patch)
        run_scan(load_scene(SCENES / scene, overrides), tmp_path / name)
        files[name] = {p.name: p.read_bytes() for p in sorted((tmp_path / name).iterdir())
                       if p.is_file() and p.name != "measures.json"}
        m = json.loads((tmp_path / name / "measures.json").read_text())
        m.pop("seconds")
        files[name]["measures"] = m
    ref = [scan_physical(built, p, model, seed=cfg.seed, leg=j, chunk_beams=5000) for j, p in enumerate(pats)]
    for a, b in zip(ref, fast):
        assert len(a.echoes) > 100
        _assert_same(a.echoes, b.echoes)
        for k in ("range_m", "cls", "element_id", "n_returns", "intensity", "hit_fraction"):
            x, y = getattr(a, k), getattr(b, k)
            assert (x is None and y is None) or np.array_equal(x, y), k
    assert {"scan.exr", "points.las"} <= set(files["fast"]) or any(k.startswith("scan_leg") for k in files["fast"])
    assert files["fast"].keys() == files["reference"].keys()
    for k in files["fast"]:
        assert files["fast"][k] == files["reference"][k], k
