"""Scanner platforms other than the tractor: tripod, multi-leg path, airborne line scanner."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches, Primitive
from simlidar_mi.scene.build import build_scene
from simlidar_mi.lidar.platforms import airborne_pattern, path_patterns, static_pattern
from simlidar_mi.lidar.scan import ScanSettings, scan
from simlidar_mi.lidar.survey import run_scan


def post(x, y, d=0.1, h=2.0) -> Primitive:
    return Primitive("cylinder", {"p0_m": [x, y, 0.0], "p1_m": [x, y, h], "diameter_m": d})


def test_path_leg_along_y_equals_the_tractor_bit_for_bit():
    """A path leg along +y looking right is the tractor scan: same rays, same ranges."""
    rng = np.random.default_rng(5)
    p0 = np.column_stack([rng.uniform(2, 3, 40), rng.uniform(0, 1, 40), rng.uniform(0, 2, 40)])
    b = Branches(p0, p0 + rng.normal(0, 0.3, (40, 3)), rng.uniform(0.005, 0.03, 40),
                 np.ones(40, np.int32), np.zeros(40, np.int32))
    built = build_scene(b)
    s = ScanSettings(1.0, 1.0, 0.0, 0.01, 0, 101, -40.0, 0.5, 161)
    tractor = scan(built, s)
    (leg,) = path_patterns([[1.0, 0.0, 1.0], [1.0, 1.0, 1.0]], 0.01, (-40.0, 40.0, 0.5))
    assert leg.n_rows == 101 and leg.n_cols == 161
    path = scan(built, leg)
    np.testing.assert_array_equal(path.range_m, tractor.range_m)
    np.testing.assert_array_equal(path.cls, tractor.cls)
    np.testing.assert_allclose(path.points_m(), tractor.points_m(), atol=1e-9)


def test_left_and_right_sides_of_a_leg_along_x():
    """Driving along +x, the right side is −y and the left side +y."""
    built = build_scene(Branches.empty(), primitives=[post(5.0, -2.0), post(5.0, 2.0)])
    kw = dict(ground=False)
    (right,) = path_patterns([[0, 0, 1.0], [10, 0, 1.0]], 0.5, (-1.0, 1.0, 1.0), side="right", **kw)
    (left,) = path_patterns([[0, 0, 1.0], [10, 0, 1.0]], 0.5, (-1.0, 1.0, 1.0), side="left", **kw)
    for pat, y_post in ((right, -2.0), (left, 2.0)):
        res = scan(built, pat)
        i = int(np.argmin(np.abs(pat.row_coord - 5.0)))
        assert res.cls[i, 1] == 2
        assert res.range_m[i, 1] == pytest.approx(2.0 - 0.05, abs=1e-3)
        pts = res.points_m()[res.cls == 2]
        assert np.all(np.sign(pts[:, 1]) == np.sign(y_post))


def test_static_3d_scan_ranges_and_ground():
    """A tripod at 1.5 m turning a full circle sees a post 3 m away at azimuth 90° and the ground
    at h / sin|θ| everywhere else."""
    built = build_scene(Branches.empty(), primitives=[post(0.0, 3.0)])
    pat = static_pattern([0.0, 0.0, 1.5], (-45.0, 0.0, 5.0), (0.0, 360.0, 10.0))
    assert pat.n_rows == 36 and pat.n_cols == 10
    res = scan(built, pat)
    k0 = int(np.flatnonzero(pat.col_angle_deg == 0.0)[0])
    i90 = int(np.flatnonzero(pat.row_yaw_deg == 90.0)[0])
    assert res.cls[i90, k0] == 2 and res.range_m[i90, k0] == pytest.approx(3.0 - 0.05, abs=1e-3)
    ground = res.cls == 1
    th = np.deg2rad(pat.col_angle_deg)
    with np.errstate(divide="ignore"):
        expect = np.broadcast_to(1.5 / np.sin(np.abs(th))[None, :], res.shape)
    np.testing.assert_allclose(res.range_m[ground], expect[ground], rtol=2e-6)
    np.testing.assert_allclose(res.points_m()[ground][:, 2], 0.0, atol=2e-5)
    assert (res.cls[:, k0] == 0).sum() == 35  # horizontal beams escape except towards the post


def test_airborne_over_flat_ground_and_a_box():
    """Ranges alt / cos α over flat ground; a 10 m box under the track shortens nadir ranges by 10 m."""
    box = Primitive("box", {"min_m": [-5.0, 40.0, 0.0], "max_m": [5.0, 60.0, 10.0]})
    built = build_scene(Branches.empty(), primitives=[box])
    pat = airborne_pattern([0.0, 0.0], [0.0, 100.0], 500.0, 30.0, 50.0, 100_000.0, 200)
    step = 50.0 / (100_000.0 / 200)
    assert pat.meta["line_step_m"] == pytest.approx(step)
    assert pat.n_rows == math.floor(100.0 / step) + 1 and pat.n_cols == 200
    res = scan(built, pat)
    alpha = np.deg2rad(pat.col_angle_deg)
    ground = res.cls == 1
    np.testing.assert_allclose(res.range_m[ground], np.broadcast_to(500.0 / np.cos(alpha), res.shape)[ground],
                               rtol=2e-6)
    on_box = (pat.row_coord > 41) & (pat.row_coord < 59)
    nadir = np.argmin(np.abs(pat.col_angle_deg))
    assert (res.cls[on_box, nadir] == 2).all()
    np.testing.assert_allclose(res.range_m[on_box, nadir], 490.0 / np.cos(alpha[nadir]), rtol=2e-6)
    # Swath on the ground: beam centres reach ±alt·tan(swath/2 − Δα/2).
    pts = res.points_m()[ground]
    assert pts[:, 0].max() == pytest.approx(500 * math.tan(math.radians(15 - 30 / 400)), rel=1e-5)


def test_airborne_bad_values_name_the_key():
    with pytest.raises(ConfigError, match="platform.speed_m_s"):
        airborne_pattern([0, 0], [0, 100], 500.0, 30.0, -1.0, 1e5, 200)
    with pytest.raises(ConfigError, match="platform.end_xy_m"):
        airborne_pattern([0, 0], [0, 0.01], 500.0, 30.0, 50.0, 1e5, 200)


def test_multi_leg_scene_writes_one_exr_per_leg_and_one_las(tmp_path):
    text = """
[[primitive]]
type = "cylinder"
p0_m = [5.0, -2.0, 0.0]
p1_m = [5.0, -2.0, 2.0]
diameter_m = 0.1
[platform]
kind = "path"
waypoints_m = [[0.0, 0.0, 1.0], [10.0, 0.0, 1.0], [10.0, -10.0, 1.0]]
step_m = 0.05
elevation_deg = [-30.0, 30.0, 1.0]
"""
    scene = tmp_path / "legs.toml"
    scene.write_text(text)
    run = run_scan(load_scene(scene), tmp_path / "out")
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["measures.json", "points.las", "scan_leg0.exr", "scan_leg0.png",
                     "scan_leg1.exr", "scan_leg1.png"]
    m = json.loads((tmp_path / "out" / "measures.json").read_text())
    assert m["platform"] == "path" and len(m["legs"]) == 2
    import laspy
    las = laspy.read(tmp_path / "out" / "points.las")
    assert set(np.unique(las.point_source_id)) == {0, 1}
    wood = las.classification == 64
    xy = np.column_stack([las.x[wood], las.y[wood]])
    # Wood points lie on the post's surface, 5 cm from its axis (12-facet prism: within 1 mm).
    np.testing.assert_allclose(np.hypot(xy[:, 0] - 5.0, xy[:, 1] + 2.0), 0.05, atol=1.5e-3)
    assert len(run.result) == 2


def test_platform_needs_its_keys(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[[primitive]]\ntype = "box"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\n[platform]\nkind = "static"\n')
    with pytest.raises(ConfigError, match="platform.position_m"):
        run_scan(load_scene(scene), tmp_path / "out")
