"""Platforms with timing (issue #7, part D): a tractor that moves while it sweeps, a spinning
multi-channel head, a two-prism rosette, and LAS gps_time from the beams' own times.

Every expected value is a closed form of the scan geometry, checked on hit points."""
from __future__ import annotations

import math

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches, Primitive
from simlidar_mi.io.las import write_scan_las
from simlidar_mi.lidar.platforms import rosette_patterns, rotating_patterns
from simlidar_mi.lidar.scan import scan
from simlidar_mi.lidar.survey import run_scan, scan_patterns
from simlidar_mi.scene.build import build_scene

PLATE = """
[scene]
name = "plate"
[ground]
enabled = false
[[primitive]]
type = "box"
min_m = [2.0, -1.0, -1.0]
max_m = [2.02, 3.0, 3.0]
[scan]
x0_m = 0.0
z0_m = 1.0
y_start_m = 0.0
y_end_m = 0.5
dtheta_deg = 1.0
theta_min_deg = -20.0
theta_max_deg = 20.0
"""
RATE_HZ, SPEED_M_S = 36_000.0, 1.0   # f = 36 000·1°/360° = 100 sweeps/s → v/f = 0.01 m


def _plate(extra: str = "", overrides=()):
    return load_scene(text=PLATE + extra, overrides=list(overrides))


def _read_las(path):
    las = laspy.read(str(path))
    return (np.asarray(las.scan_position), np.asarray(las.scan_angle_index),
            np.asarray(las.point_source_id), np.asarray(las.gps_time), las)


def _slanted_plate(tmp_path) -> str:
    """A plate x = 2 + y/2 (two triangles, y and z in [−1, 3]) as an OBJ primitive: the range of a
    beam depends on the y it starts from, so hit points test where the sensor fired it from."""
    obj = tmp_path / "slanted.obj"
    obj.write_text("v 1.5 -1 -1\nv 3.5 3 -1\nv 3.5 3 3\nv 1.5 -1 3\nf 1 2 3\nf 1 3 4\n")
    return PLATE.replace('type = "box"\nmin_m = [2.0, -1.0, -1.0]\nmax_m = [2.02, 3.0, 3.0]',
                         f'type = "obj"\npath = "{obj}"')


def test_moving_tractor_profiles_advance_by_v_over_f_and_slant_within_a_sweep(tmp_path):
    """Hit points on the slanted plate x = 2 + y/2 (beams have no y component): beam (i, k)
    starts at y = y_start + i·v/f + k·v/pulse_rate and hits the plate there, at x = 2 + y/2 and
    z = z0 + (x − x0)·tan θ_k; its time is i/f + k/pulse_rate (gps_time in the LAS)."""
    cfg = load_scene(text=_slanted_plate(tmp_path) + f"[sensor]\npulse_rate_hz = {RATE_HZ}\n"
                     f"[platform]\nspeed_m_s = {SPEED_M_S}\n")
    run = run_scan(cfg, tmp_path / "out", write_png=False)
    res = run.result
    f = RATE_HZ * 1.0 / 360.0
    assert res.settings.sweep_rate_hz == pytest.approx(100.0)
    assert res.settings.dy_m == pytest.approx(SPEED_M_S / f)
    n, m = res.shape
    assert (n, m) == (50, 40) and np.all(res.cls == 2)
    pts = res.points_m()
    i, k = np.arange(n)[:, None], np.arange(m)[None, :]
    y_expected = i * SPEED_M_S / f + k * SPEED_M_S / RATE_HZ
    np.testing.assert_allclose(pts[..., 1], y_expected, atol=2e-6)
    np.testing.assert_allclose(pts[..., 0], 2.0 + y_expected / 2, atol=2e-6)   # on the plate: fired from there
    theta = np.deg2rad(-20.0 + np.arange(m))[None, :]
    np.testing.assert_allclose(pts[..., 2], 1.0 + pts[..., 0] * np.tan(theta), atol=2e-6)
    np.testing.assert_allclose(np.diff(pts[..., 1], axis=0), SPEED_M_S / f, atol=4e-6)        # per sweep
    np.testing.assert_allclose(np.diff(pts[..., 1], axis=1), SPEED_M_S / RATE_HZ, atol=4e-6)  # within it
    # The slant of one profile: v·(M − 1)/pulse_rate = 1.083 mm, a tenth of the row step.
    assert pts[0, -1, 1] - pts[0, 0, 1] == pytest.approx(SPEED_M_S * (m - 1) / RATE_HZ, abs=4e-6)
    row, col, _, gps, las = _read_las(run.files["las"])
    np.testing.assert_allclose(gps, row / f + col / RATE_HZ, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(las.y), row * SPEED_M_S / f + col * SPEED_M_S / RATE_HZ, atol=2e-4)
    vlr = next(v for v in las.header.vlrs if v.user_id == "simlidar-mi")
    assert b"beam emission time" in vlr.record_data and b"tractor sweep" in vlr.record_data


def test_a_pulse_rate_alone_times_the_beams_of_the_unchanged_stop_and_go_scan(tmp_path):
    """Without a speed, each sweep is fired from one pose (same ranges and points as without a
    [sensor]); rows skipped by gap = 1 still take their sweep time: t = 2i/f + k/pulse_rate."""
    plain = run_scan(_plate(overrides=["scan.gap=1"]), tmp_path / "plain", write_png=False)
    timed = run_scan(_plate(f"[sensor]\npulse_rate_hz = {RATE_HZ}\n", ["scan.gap=1"]),
                     tmp_path / "timed", write_png=False)
    np.testing.assert_array_equal(timed.result.range_m, plain.result.range_m)
    np.testing.assert_array_equal(timed.result.points_m(), plain.result.points_m())
    row, col, _, gps, _ = _read_las(timed.files["las"])
    np.testing.assert_allclose(gps, 2 * row / 100.0 + col / RATE_HZ, rtol=0, atol=1e-12)
    _, _, _, gps_plain, _ = _read_las(plain.files["las"])
    np.testing.assert_allclose(gps_plain, row + col / 40.0)  # the nominal scan-order time, as before


def test_moving_tractor_keys_are_checked_together():
    sensor = f"[sensor]\npulse_rate_hz = {RATE_HZ}\n"
    lo, hi = np.array([2.0, -1.0, -1.0]), np.array([2.02, 3.0, 3.0])
    # An explicit dy_m must match v/f; naming both keys.
    cfg = _plate(sensor + f"[platform]\nspeed_m_s = {SPEED_M_S}\n", ["scan.dy_m=0.002"])
    with pytest.raises(ConfigError, match=r"scan\.dy_m.*platform\.speed_m_s|platform\.speed_m_s.*") as e:
        scan_patterns(cfg, lo, hi)
    assert e.value.key == "scan.dy_m" and "speed_m_s" in str(e.value) and "pulse_rate_hz" in str(e.value)
    (ok,) = scan_patterns(_plate(sensor + f"[platform]\nspeed_m_s = {SPEED_M_S}\n", ["scan.dy_m=0.01"]), lo, hi)
    assert ok.dy_m == pytest.approx(0.01)
    # A speed without a pulse rate has no sweep rate.
    with pytest.raises(ConfigError) as e:
        scan_patterns(_plate(f"[platform]\nspeed_m_s = {SPEED_M_S}\n"), lo, hi)
    assert e.value.key == "platform.speed_m_s"
    with pytest.raises(ConfigError) as e:
        load_scene(text=PLATE + "[sensor]\npulse_rate_hz = -1.0\n")
    assert e.value.key == "sensor.pulse_rate_hz"


def test_airborne_defaults_unchanged_by_kind_dependent_speed():
    """speed_m_s and pulse_rate_hz default by kind: airborne still flies 30 m/s at 300 kHz."""
    text = ("[scene]\nname='a'\n[[primitive]]\ntype='box'\nmin_m=[0.0,0.0,0.0]\nmax_m=[1.0,1.0,1.0]\n"
            "[platform]\nkind='airborne'\nstart_xy_m=[0.0,0.0]\nend_xy_m=[100.0,0.0]\n")
    lo, hi = np.zeros(3), np.ones(3)
    (default,) = scan_patterns(load_scene(text=text), lo, hi)
    (given,) = scan_patterns(load_scene(text=text + "speed_m_s = 30.0\npulse_rate_hz = 300000.0\n"), lo, hi)
    assert default.meta["speed_m_s"] == 30.0 and default.meta["pulse_rate_hz"] == 300_000.0
    np.testing.assert_array_equal(default.row_origin_m, given.row_origin_m)
    assert default.beam_times_s() is None  # the airborne LAS keeps its own pulse-time formula


def test_rotating_16_channels_elevations_and_azimuth_step():
    """A VLP-16 at the centre of a vertical cylinder (r = 3 m): every hit point's elevation seen
    from the sensor is its channel's (−15…15° every 2°), and its azimuth is
    360°·rotation_hz·(t_block + offset_k): rows step by 360°·rotation_hz·block_period."""
    z0, rot = 1.5, 10.0
    built = build_scene(Branches.empty(), primitives=[Primitive(
        "cylinder", {"p0_m": [0.0, 0.0, -1.0], "p1_m": [0.0, 0.0, 4.0], "diameter_m": 6.0})],
        representation="cylinder")
    (pat,) = rotating_patterns(rotation_hz=rot, position_m=[0.0, 0.0, z0], ground=False)
    step = rot * 360.0 * 55.296e-6
    assert pat.n_cols == 16 and pat.n_rows == math.floor(0.1 / 55.296e-6)
    np.testing.assert_allclose(np.diff(pat.row_yaw_deg), step, rtol=1e-12)
    res = scan(built, pat)
    assert np.all(res.cls == 2)
    pts = res.points_m()
    horiz = np.hypot(pts[..., 0], pts[..., 1])
    np.testing.assert_allclose(horiz, 3.0, atol=5e-3)  # the built cylinder's surface; angles need no radius
    elev = np.degrees(np.arctan2(pts[..., 2] - z0, horiz))
    np.testing.assert_allclose(elev, np.broadcast_to(np.arange(-15.0, 16.0, 2.0), elev.shape), atol=1e-4)
    az = np.degrees(np.arctan2(pts[..., 1], pts[..., 0]))
    expected = rot * 360.0 * pat.beam_times_s()
    np.testing.assert_allclose(np.mod(az - expected + 180.0, 360.0) - 180.0, 0.0, atol=1e-4)
    # Firing order kept per channel: the ring at +1° (column 8) fires 2.304 µs after −15° (column 0).
    assert pat.col_time_s[8] - pat.col_time_s[0] == pytest.approx(2.304e-6)


def test_rotating_sector_and_moving_legs_with_las_times(tmp_path):
    """Driving two legs at 2 m/s past a wall, keeping the right-hand sector: blocks lie in the
    sector, time and head azimuth run on across legs, origins follow the platform at each beam's
    own time, and the LAS gps_time equals the beam times."""
    wall = Primitive("box", {"min_m": [-5.0, -3.0, 0.0], "max_m": [15.0, -2.9, 3.0]})
    built = build_scene(Branches.empty(), primitives=[wall])
    legs = rotating_patterns(waypoints_m=[[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [4.0, 0.0, 1.0]],
                             speed_m_s=2.0, azimuth_range_deg=[-120.0, -60.0], ground=False)
    assert len(legs) == 2
    T = 55.296e-6
    for j, leg in enumerate(legs):
        phi = np.mod(leg.row_yaw_deg + 180.0, 360.0) - 180.0
        assert np.all((phi >= -120.0 - 1e-9) & (phi <= -60.0 + 1e-9))
        blocks = leg.row_time_s / T
        np.testing.assert_allclose(blocks, np.round(blocks), atol=1e-6)
        assert np.all((leg.row_time_s >= j * 1.0) & (leg.row_time_s <= (j + 1) * 1.0))
        np.testing.assert_allclose(leg.row_origin_m[:, 0], 2.0 * leg.row_time_s, atol=1e-12)
        np.testing.assert_allclose(leg.beam_origins_m()[..., 0], 2.0 * leg.beam_times_s(), atol=1e-12)
    assert legs[0].row_time_s[-1] < legs[1].row_time_s[0]
    results = [scan(built, leg) for leg in legs]
    for res in results:  # the wall at y = −2.9: hit points on it, from the moving origins
        hit = res.cls == 2
        assert hit.mean() > 0.4
        np.testing.assert_allclose(res.points_m()[hit][:, 1], -2.9, atol=1e-4)
    path = write_scan_las(results, tmp_path / "p.las")
    row, col, leg_id, gps, _ = _read_las(path)
    expected = np.concatenate([legs[j].beam_times_s()[row[leg_id == j], col[leg_id == j]] for j in (0, 1)])
    order = np.concatenate([np.flatnonzero(leg_id == j) for j in (0, 1)])
    np.testing.assert_array_equal(gps[order], expected)


def test_rotating_bad_input_names_the_key():
    with pytest.raises(ConfigError) as e:
        rotating_patterns([-1.0, 1.0], [0.0], 10.0, 10.0, position_m=[0, 0, 1])
    assert e.value.key == "platform.channel_offsets_us"
    with pytest.raises(ConfigError) as e:
        rotating_patterns([-1.0, 1.0], [0.0, 12.0], 10.0, 10.0, position_m=[0, 0, 1])
    assert e.value.key == "platform.channel_offsets_us"
    with pytest.raises(ConfigError) as e:
        rotating_patterns(waypoints_m=[[0, 0, 1], [1, 0, 1]])
    assert e.value.key == "platform.speed_m_s"
    with pytest.raises(ConfigError) as e:
        rotating_patterns(position_m=[0, 0, 1], waypoints_m=[[0, 0, 1], [1, 0, 1]], speed_m_s=1.0)
    assert e.value.key == "platform.waypoints_m"
    with pytest.raises(ConfigError) as e:
        load_scene(text="[platform]\nkind = 'rotating'\nrotation_hz = 0.0\n")
    assert e.value.key == "platform.rotation_hz"


def test_rosette_off_axis_angle_follows_the_two_prism_closed_form():
    """Looking along +x at a wall 5 m away: each pulse lands at radius 5·tan ρ from the axis,
    ρ = (fov/2)·|cos(π(f₁ − f₂)t)| (two equal thin prisms), t = its beam time."""
    fov, f1, f2, rate = 70.4, 7294 / 60, -4664 / 60, 100_000.0
    built = build_scene(Branches.empty(), primitives=[
        Primitive("box", {"min_m": [5.0, -10.0, -10.0], "max_m": [5.1, 10.0, 10.0]})])
    (pat,) = rosette_patterns([f1, f2], fov, rate, (0.0, 0.0), position_m=[0.0, 0.0, 0.0],
                              duration_s=0.25, ground=False)
    assert (pat.n_rows, pat.n_cols) == (2, 10_000)  # two whole 0.1 s frames; the last 0.05 s dropped
    t = pat.beam_times_s()
    np.testing.assert_allclose(t.ravel(), np.arange(20_000) / rate, atol=1e-15)
    res = scan(built, pat)
    assert np.all(res.cls == 2)
    pts = res.points_m()
    np.testing.assert_allclose(pts[..., 0], 5.0, atol=1e-4)
    rho = np.deg2rad(fov / 2) * np.abs(np.cos(np.pi * (f1 - f2) * t))
    np.testing.assert_allclose(np.hypot(pts[..., 1], pts[..., 2]), 5.0 * np.tan(rho), atol=2e-4)
    # Non-repetitive: the second frame's directions are not the first's.
    assert np.max(np.abs(pat.beam_dirs[1] - pat.beam_dirs[0])) > 0.1


def test_moving_rosette_beams_start_where_the_platform_is_at_their_time():
    (pat,) = rosette_patterns(position_m=None, waypoints_m=[[0.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
                              speed_m_s=5.0, look_deg=(-90.0, 0.0), ground=False)
    o = pat.beam_origins_m()
    np.testing.assert_allclose(o[..., 1], 5.0 * pat.beam_times_s(), atol=1e-12)
    # The look axis turns with the heading (+y): azimuth −90° from it is +x.
    mean_dir = pat.beam_dirs.reshape(-1, 3).mean(axis=0)
    assert mean_dir[0] > 0.8 and abs(mean_dir[1]) < 0.05
    with pytest.raises(ConfigError) as e:
        rosette_patterns(position_m=[0, 0, 1], footprint=2)
    assert e.value.key == "scan.footprint"


def test_scene_without_timing_keys_writes_the_same_files_with_sensor_rate_zero(tmp_path):
    """[sensor] pulse_rate_hz = 0 is today's scan: the same LAS bytes and EXR channels and header
    (but the scene's hash) as a scene without [sensor]."""
    from simlidar_mi.io.exr import read_exr
    a = run_scan(_plate(), tmp_path / "a", write_png=False)
    b = run_scan(_plate("[sensor]\npulse_rate_hz = 0.0\n"), tmp_path / "b", write_png=False)
    assert a.files["las"].read_bytes() == b.files["las"].read_bytes()
    (ca, ha), (cb, hb) = read_exr(a.files["exr"]), read_exr(b.files["exr"])
    assert sorted(ca) == sorted(cb) and all(np.array_equal(ca[k], cb[k]) for k in ca)
    ha.pop("scene_sha256"), hb.pop("scene_sha256")
    assert str(ha) == str(hb) and "pulse_rate_hz" not in ha["simlidar_settings"]
