"""The Dr.Jit waveform reader (plugins/waveform_reader.py, ``[sensor] waveform_reader =
"kernel"``) against the numpy detector (``waveform_fast.reference_echoes``): the same echoes,
the same energies, classes, ids and incidences bit for bit; ranges and widths within a few ulps
(Dr.Jit's exp and log are not numpy's); and, on the included sensor scenes, the same output data."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simlidar_mi._runtime.mitsuba import mitsuba
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.scan import physical_tracer
from simlidar_mi.lidar.sensor import SensorModel
from simlidar_mi.lidar.survey import build, generate, run_scan, scan_patterns, scene_sensor
from simlidar_mi.lidar.waveform_fast import kernel_echoes, reference_echoes
from tests.conftest import SCENES
from tests.test_waveform_fast import SCENE_CASES, _beams

NUMPY = 'sensor.waveform_reader="numpy"'


def _read(model, t, cos_i, rho, cls, elem, tree, weight):
    """The kernel's per-beam reading of (B, S) host arrays, as host arrays."""
    mi = mitsuba()
    import drjit as dr  # noqa: PLC0415  (after the variant is set)
    from simlidar_mi.plugins.waveform_reader import read_pulses  # noqa: PLC0415
    out = {"t": mi.Float32(np.ravel(t)), "cos_incidence": mi.Float32(np.ravel(cos_i)),
           "reflectance": mi.Float32(np.ravel(rho)),
           "class": dr.uint8_array_t(mi.UInt32)(mi.UInt32(np.ravel(cls).astype(np.uint32))),
           "element_id": mi.UInt32(np.ravel(elem))}
    if tree is not None:
        out["tree_id"] = mi.UInt32(np.ravel(tree))
    read = read_pulses(out, t.shape[1], weight, r_ref_m=model.r_ref_m, pulse_length_ns=model.pulse_length_ns,
                       detection_threshold=model.detection_threshold, range_min_m=model.range_min_m,
                       range_max_m=model.range_max_m, echo_rule=model.echo_rule)
    return {k: v.numpy() for k, v in read.items()}


def _assert_close(ref, got):
    """Same echoes; energy, class, ids, incidence, return numbers bit for bit; range within a
    picometre (the log-parabola's vertex moves by ulps of a bin, whatever the range), width
    within 2 float32 ulps."""
    assert len(ref) == len(got)
    for k in ("beam", "return_number", "number_of_returns", "energy", "cls", "element_id", "cos_incidence"):
        assert np.array_equal(getattr(ref, k), getattr(got, k)), k
    assert (ref.tree_id is None) == (got.tree_id is None)
    if ref.tree_id is not None:
        assert np.array_equal(ref.tree_id, got.tree_id)
    assert np.all(np.abs(ref.range_m - got.range_m) <= 1e-12)
    assert np.all(np.abs(ref.width_ns - got.width_ns) <= 2 * np.spacing(np.abs(ref.width_ns)))


def _random_case(s, seed=0):
    rng = np.random.default_rng(100 + s + seed)
    b = 2000
    t = np.concatenate([_beams(rng, b, s, spread_m=0.01, far_share=0.0, escape_share=0.05, tie_share=0.2),
                        _beams(rng, b, s, spread_m=0.3, far_share=0.0, escape_share=0.1),
                        _beams(rng, b, s, spread_m=0.02, far_share=0.3, escape_share=0.2),
                        _beams(rng, b, s, spread_m=2.0, far_share=0.5, escape_share=0.0)])
    n = len(t)
    cos_i = rng.uniform(0, 1, (n, s)).astype(np.float32)
    cos_i[rng.random((n, s)) < 0.03] = 0.0
    cls = rng.integers(1, 4, (n, s)).astype(np.uint8)
    rho = np.array([0.0, 0.2, 0.35, 0.45], np.float32)[cls]
    rho[rng.random((n, s)) < 0.02] = 0.0
    cos_i[~np.isfinite(t)], cls[~np.isfinite(t)] = 0.0, 0
    elem = rng.integers(0, 1 << 20, (n, s)).astype(np.uint32)
    tree = rng.integers(0, 9, (n, s)).astype(np.uint32)
    return t, cos_i, rho, cls, elem, tree, np.full(s, 1.0 / s), np.arange(n, dtype=np.int64) * 3 + 7


@pytest.mark.parametrize("s", [1, 4, 19, 32])
@pytest.mark.parametrize("rule", ["amplitude", "basin"])
def test_random_beams_read_as_numpy_reads_them(s, rule):
    t, cos_i, rho, cls, elem, tree, weight, beam = _random_case(s)
    for tr in (None, tree):
        for kw in ({}, {"max_returns": 1}, {"range_min_m": 2.0, "range_max_m": 40.0},
                   {"detection_threshold": 0.002, "pulse_length_ns": 5.0}):
            model = replace(SensorModel(divergence_mrad=1.0, beam_samples=s, max_returns=3, echo_rule=rule), **kw)
            read = _read(model, t, cos_i, rho, cls, elem, tr, weight)
            ref = reference_echoes(model, t.astype(np.float64), cls, elem, tr, cos_i.astype(np.float64),
                                   rho.astype(np.float64), weight, beam)
            got = kernel_echoes(model, read, t, cos_i, rho, cls, elem, tr, weight, beam)
            assert len(ref) > 100
            _assert_close(ref, got)
            # state 1: exactly the reference's one echo; state 0: none; state 2 read by the host
            per_beam = np.bincount((ref.beam - 7) // 3, minlength=len(t))
            state = read["state"]
            assert np.all(per_beam[state == 1] == 1) and np.all(per_beam[state == 0] == 0)
            assert np.count_nonzero(state == 1) > 0.3 * len(t)


def test_the_frozen_kernel_follows_each_call():
    """The kernel is frozen (traced once, replayed): calls of other widths, tree ids or no tree
    ids, and other settings in one process read each beam as a call of its own does."""
    t, cos_i, rho, cls, elem, tree, weight, beam = _random_case(19, seed=7)
    model = SensorModel(divergence_mrad=1.0, beam_samples=19, max_returns=3)
    whole = _read(model, t, cos_i, rho, cls, elem, tree, weight)
    for a, b in ((0, 777), (777, len(t)), (5, 6), (0, 777)):
        part = _read(model, t[a:b], cos_i[a:b], rho[a:b], cls[a:b], elem[a:b], tree[a:b], weight)
        for k, v in part.items():
            assert np.array_equal(v, whole[k][a:b]), (a, b, k)
    basin = replace(model, echo_rule="basin", detection_threshold=0.05)
    other = _read(basin, t[:500], cos_i[:500], rho[:500], cls[:500], elem[:500], None, weight)
    ref = reference_echoes(basin, t[:500].astype(np.float64), cls[:500], elem[:500], None,
                           cos_i[:500].astype(np.float64), rho[:500].astype(np.float64), weight, np.arange(500))
    _assert_close(ref, kernel_echoes(basin, other, t[:500], cos_i[:500], rho[:500], cls[:500], elem[:500], None,
                                     weight, np.arange(500)))
    assert "tree_id" not in other


def test_tied_energies_keep_the_nearest_sub_ray():
    """Equal energies (equal ranges, reflectances and incidences): the strongest is the nearest,
    then the lowest column (the reference's stable order)."""
    s, n = 6, 50
    t = np.full((n, s), 12.0, np.float32)
    t[:, 3] = 11.99
    ones = np.ones((n, s), np.float32)
    elem = np.tile(np.arange(s, dtype=np.uint32) + 10, (n, 1))
    model = SensorModel(divergence_mrad=0.3, beam_samples=s, range_at_10pct_m=100.0)
    args = (t, ones * 0.5, ones * 0.4, np.full((n, s), 2, np.uint8), elem, None, np.full(s, 1.0 / s))
    read = _read(model, *args)
    ref = reference_echoes(model, t.astype(np.float64), args[3], elem, None, args[1].astype(np.float64),
                           args[2].astype(np.float64), args[6], np.arange(n))
    got = kernel_echoes(model, read, *args, np.arange(n))
    _assert_close(ref, got)
    assert np.all(read["state"] == 1) and np.all(got.element_id == 13)  # column 3 is the nearest


def test_no_valid_sub_ray_reads_nothing():
    t = np.full((5, 4), np.inf, np.float32)
    z = np.zeros((5, 4), np.float32)
    model = SensorModel(divergence_mrad=1.0, beam_samples=4)
    read = _read(model, t, z, z, z.astype(np.uint8), z.astype(np.uint32), None, np.full(4, 0.25))
    assert np.all(read["state"] == 0)
    assert len(kernel_echoes(model, read, t, z, z, z.astype(np.uint8), z.astype(np.uint32), None,
                             np.full(4, 0.25), np.arange(5))) == 0


def test_wide_beams_fall_back_to_numpy():
    """More sub-rays than the kernel unrolls, or the numpy reader asked for: no kernel."""
    cfg = load_scene(SCENES / "simlidar_table3_7x4.toml",
                     ["scan.y_start_m=1.0", "scan.y_end_m=1.02", "sensor.divergence_mrad=0.3",
                      "sensor.beam_samples=40", "sensor.intensity=true"])
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    built = build(cfg, g, pats)
    model = scene_sensor(cfg, g, pats)
    assert not physical_tracer(built, pats[0], model).kernel_reader
    assert physical_tracer(built, pats[0], replace(model, beam_samples=19)).kernel_reader
    assert not physical_tracer(built, pats[0], replace(model, beam_samples=19, waveform_reader="numpy")).kernel_reader


def _data(folder):
    """Every output's data: LAS point records, EXR pixels, measures without timings, hash and reader."""
    import json  # noqa: PLC0415

    import laspy  # noqa: PLC0415
    import OpenEXR  # noqa: PLC0415
    out = {}
    for p in sorted(folder.iterdir()):
        if p.suffix == ".las":
            las = laspy.read(p)
            out[p.name] = (bytes(las.points.array), las.header.point_count)
        elif p.suffix == ".exr":
            out[p.name] = {k: c.pixels.tobytes() for k, c in OpenEXR.File(str(p)).channels().items()}
        elif p.name == "measures.json":
            out[p.name] = _without(json.loads(p.read_text()), {"seconds", "scene_sha256", "waveform_reader"})
    return out


def _without(o, keys):
    if isinstance(o, dict):
        return {k: _without(v, keys) for k, v in o.items() if k not in keys}
    return [_without(v, keys) for v in o] if isinstance(o, list) else o


@pytest.mark.parametrize("scene,overrides", SCENE_CASES, ids=[c[0] for c in SCENE_CASES])
def test_included_scenes_write_the_same_data(tmp_path, scene, overrides):
    """Ranges differ from numpy's in float64's last bits at most: the files (float32 EXR, LAS
    integers at 0.1 mm) hold the same data with either reader."""
    run_scan(load_scene(SCENES / scene, overrides), tmp_path / "kernel")
    run_scan(load_scene(SCENES / scene, [*overrides, NUMPY]), tmp_path / "numpy")
    a, b = _data(tmp_path / "kernel"), _data(tmp_path / "numpy")
    assert a.keys() == b.keys() and any(k.endswith(".las") or k.endswith(".exr") for k in a)
    for k in a:
        assert a[k] == b[k], k
