"""trajectory.txt (issue 31 §4): HELIOS++'s seven columns, the platform model's float64 poses bit
for bit, in the time base of the points: every point of points.las lies at its range along its
beam from the trajectory's position at its gps_time (linear between rows on a moving platform),
turned by the trajectory's yaw."""
from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.io.las import BeamGeometry
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.lidar.trajectory import COLUMNS, read_trajectory

SCENES = Path(__file__).resolve().parents[1] / "scenes"
AIRBORNE = ["platform.start_xy_m=[150.0, 150.0]", "platform.end_xy_m=[150.0, 156.0]",
            "forest.domain_m=[120.0, 180.0, 120.0, 180.0]"]
SPINNING = ["orchard.n_trees=1", "platform.waypoints_m=[[0.5, -0.5, 1.5], [0.5, 1.5, 1.5]]"]


def _scan(tmp_path, scene, over):
    run = run_scan(load_scene(SCENES / f"{scene}.toml", [*over, "scan.trajectory=true"]), tmp_path,
                   write_png=False)
    res = run.result[0] if isinstance(run.result, list) else run.result
    return run, res.pattern, read_trajectory(tmp_path / "trajectory.txt"), laspy.read(tmp_path / "points.las")


def _check_points(cloud, traj, pattern):
    """The trajectory at each point's gps_time is its beam's origin in the platform
    model (float64), and the point lies at its range along that beam, to the LAS quantum; the
    row flown at that time is the point's ``scan_position``."""
    i = np.asarray(cloud["scan_position"], np.int64)
    k = np.asarray(cloud["scan_angle_index"], np.int64)
    t = np.asarray(cloud["gps_time"], np.float64)
    assert np.all(np.diff(traj[:, 3]) > 0)  # times increase, row by row
    rows = traj[:pattern.n_rows]  # a moving leg ends with the pose at its last beam
    assert np.array_equal(np.searchsorted(rows[:, 3], t, side="right") - 1, i)  # the row flown at t
    if pattern.moving:  # beams leave from where the platform is: the line between two rows
        origin = np.stack([np.interp(t, traj[:, 3], traj[:, c]) for c in range(3)])
    else:  # a row (an airborne line) fires from one position: its line of the file
        origin = traj[i, :3].T
    model = BeamGeometry(pattern)
    assert np.allclose(origin, model.points_m(i, k, np.zeros(len(i))), rtol=0, atol=1e-9)
    xyz = np.stack([cloud.x, cloud.y, cloud.z])
    rng = np.asarray(cloud["range_m"])  # float32: an echo's float64 range rounded, half an ulp
    err = np.abs(model.points_m(i, k, rng) - xyz)
    assert np.all(err <= cloud.header.scales[:, None] / 2 + rng * 2.0**-24 + 1e-9), err.max(axis=1)


def test_airborne_trajectory_is_the_flight_line(tmp_path):
    run, p, traj, cloud = _scan(tmp_path, "forest_airborne", AIRBORNE)
    assert run.files["trajectory"] == tmp_path / "trajectory.txt"
    assert traj.shape == (p.n_rows, len(COLUMNS))
    assert np.array_equal(traj[:, :3], p.row_origin_m)  # the model's float64 positions, bit for bit
    assert np.all(traj[:, 4:6] == 0.0)
    rate, m = p.meta["pulse_rate_hz"], p.n_cols
    assert np.array_equal(traj[:, 3], np.arange(p.n_rows) * m / rate)  # line i fires pulse i·M first
    # the flight line: start → end at the altitude above the ground, heading +y (yaw 90°)
    assert np.allclose(traj[:, 0], 150.0) and np.all(np.diff(traj[:, 1]) > 0)
    assert np.allclose(traj[:, 2], p.row_origin_m[0, 2]) and np.allclose(traj[:, 6], 90.0)
    assert cloud.header.point_count > 1000
    _check_points(cloud, traj, p)


def test_moving_spinning_head_trajectory_interpolates_to_each_beam_origin(tmp_path):
    """A spinning head on a vehicle: beams leave from row origin + delay · velocity, so the
    trajectory interpolated at a point's time gives its origin."""
    _, p, traj, cloud = _scan(tmp_path, "orchard_vlp16_tractor", SPINNING)
    n = p.n_rows
    assert traj.shape == (n + 1, 7)  # a line per row and the pose at the last beam
    assert p.moving and np.array_equal(traj[:n, 3], p.row_time_s) and np.array_equal(traj[:n, :3], p.row_origin_m)
    last = np.argmax(p.col_time_s)
    assert traj[n, 3] == p.row_time_s[-1] + p.col_time_s[last]
    # driving +y (waypoints (0.5, -0.5) → (0.5, 1.5)): heading 90°, whatever the head's turn
    assert np.allclose(traj[:, 6], 90.0) and np.all(traj[:, 4:6] == 0.0)
    _check_points(cloud, traj, p)


def test_no_trajectory_unless_asked_or_for_a_tripod(tmp_path):
    run = run_scan(load_scene(SCENES / "calibration_cylinder.toml", ["scan.dy_m=0.05"]), tmp_path / "a",
                   write_png=False)
    assert "trajectory" not in run.files and not (tmp_path / "a" / "trajectory.txt").exists()
    over = ['platform.kind="static"', "platform.position_m=[1.0, 0.0, 1.0]", "scan.trajectory=true",
            "platform.elevation_deg=[-40.0, 30.0, 5.0]", "platform.azimuth_deg=[-20.0, 20.0, 5.0]"]
    run = run_scan(load_scene(SCENES / "calibration_cylinder.toml", over), tmp_path / "b", write_png=False)
    assert "trajectory" not in run.files


@pytest.mark.parametrize("bad", ["scan.trajectory=1", 'scan.trajectory="yes"'])
def test_trajectory_key_is_a_boolean(bad):
    from simlidar_mi.errors import SimlidarError
    with pytest.raises(SimlidarError, match="trajectory"):
        load_scene(SCENES / "calibration_cylinder.toml", [bad])
