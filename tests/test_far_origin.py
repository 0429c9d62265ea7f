"""Scenes far from the coordinate origin: the default scene origin covers every shape and
the scanner, and float32 rounding that cannot resolve the scene's features is warned about."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import SimlidarWarning
from simlidar_mi.geometry import Branches, Primitive
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.scene.build import FLOAT32_FEATURE_SHARE, build_scene
from tests.conftest import SCENES


def _calibration_at(dx_m: float, dy_m: float):
    """The calibration scene with cylinder and scanner moved by (dx, dy)."""
    text = (SCENES / "calibration_cylinder.toml").read_text()
    for old, new in (("p0_m = [2.0, 0.0, 0.5]", f"p0_m = [{2.0 + dx_m!r}, {dy_m!r}, 0.5]"),
                     ("p1_m = [2.0, 0.0, 1.5]", f"p1_m = [{2.0 + dx_m!r}, {dy_m!r}, 1.5]"),
                     ("x0_m = 1.0", f"x0_m = {1.0 + dx_m!r}"),
                     ("y_start_m = -0.25", f"y_start_m = {-0.25 + dy_m!r}"),
                     ("y_end_m = 0.25", f"y_end_m = {0.25 + dy_m!r}")):
        assert old in text
        text = text.replace(old, new)
    return load_scene(text=text)


def _scan_quietly(cfg):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = run_scan(cfg)
    return run, [w for w in caught if issubclass(w.category, SimlidarWarning)]


@pytest.fixture(scope="module")
def at_origin():
    run, warned = _scan_quietly(_calibration_at(0.0, 0.0))
    assert not warned
    return run


@pytest.mark.parametrize("offset_m", [1e5, 1e6])
def test_calibration_cylinder_far_away_scans_like_at_the_origin(at_origin, offset_m):
    """Before the fix the origin ignored [[primitive]] shapes: 1e6 m in x and y gave 0 wood hits."""
    near = at_origin.result
    run, warned = _scan_quietly(_calibration_at(offset_m, offset_m))
    far = run.result
    assert not warned
    assert near.class_counts()["wood"] > 5000
    assert far.class_counts() == near.class_counts()
    np.testing.assert_array_equal(far.cls, near.cls)
    hit = near.cls == 2
    assert np.max(np.abs(far.range_m[hit] - near.range_m[hit])) < 1e-3
    # The origin sits on the scene, in whole metres.
    np.testing.assert_array_equal(run.measures["origin_m"], [offset_m + 2.0, offset_m, 1.0])


def test_default_origin_covers_primitives_and_scanner():
    post = Primitive("cylinder", {"p0_m": [5e5 + 3.0, 2e5, 0.0], "p1_m": [5e5 + 3.0, 2e5, 2.0],
                                  "diameter_m": 0.1})
    built = build_scene(Branches.empty(), primitives=[post])
    np.testing.assert_array_equal(built.origin_m, [5e5 + 3.0, 2e5, 1.0])
    # A scanner 4 m in front of it (x from 5e5 − 1 to 5e5 + 3.05): the box centre moves.
    built = build_scene(Branches.empty(), primitives=[post],
                        scanner_m=[[5e5 - 1.0, 2e5, 1.0], [5e5 - 1.0, 2e5 + 2.0, 1.0]])
    np.testing.assert_array_equal(built.origin_m, [5e5 + 1.0, 2e5 + 1.0, 1.0])


def _branch(x_m: float, d_m: float) -> Branches:
    return Branches(np.array([[x_m, 0.0, 0.0]]), np.array([[x_m, 0.0, 1.0]]), np.array([d_m]),
                    np.ones(1, np.int32), np.zeros(1, np.int32))


def test_float32_spacing_warning():
    # Two 5 mm branches 2e6 m apart: origin midway, float32 steps of 1/16 m at 1e6 m.
    two = Branches.concat([_branch(0.0, 0.005), _branch(2e6, 0.005)])
    with pytest.warns(SimlidarWarning, match=r"0\.0625 m apart at 1e\+06 m.*1250\.0 % .*branch diameter 0\.005 m"):
        build_scene(two)
    # A user origin 1e5 m from a 5 mm branch: spacing 7.8e-3 m > 1 % of 5 mm.
    with pytest.warns(SimlidarWarning, match="float32"):
        build_scene(_branch(0.0, 0.005), origin_m=[1e5, 0.0, 0.0])
    # Within the limit: 1 km from a 5 cm branch (spacing 6.1e-5 m, 0.12 %).
    assert np.spacing(np.float32(1000.0)) < FLOAT32_FEATURE_SHARE * 0.05
    with warnings.catch_warnings():
        warnings.simplefilter("error", SimlidarWarning)
        build_scene(_branch(0.0, 0.05), origin_m=[1000.0, 0.0, 0.0])
