"""Scanning forests: a ground path with leaves, and an airborne pass over instanced trees."""
from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import generate, run_scan
from tests.conftest import SCENES


def test_road_scan_returns_wood_leaf_and_ground(tmp_path):
    cfg = load_scene(SCENES / "forest_road_scan.toml",
                     ["platform.step_m=0.5", "platform.elevation_deg=[-30.0, 60.0, 1.0]"])
    run = run_scan(cfg, tmp_path / "road")
    m = json.loads((tmp_path / "road" / "measures.json").read_text())
    assert m["platform"] == "path" and len(m["legs"]) == 2
    assert m["hits"]["wood"] > 0 and m["hits"]["leaf"] > 0 and m["hits"]["ground"] > 0
    las = laspy.read(tmp_path / "road" / "points.las")
    assert set(np.unique(las.classification)) == {2, 5, 64}
    # Ground points lie on z = 0; every return is in front of the scanner, on the forest side (left).
    ground = las.classification == 2
    np.testing.assert_allclose(np.asarray(las.z)[ground], 0.0, atol=2e-4)
    leg0 = np.asarray(las.point_source_id) == 0
    assert (np.asarray(las.y)[leg0] > -2.0).all()
    assert len(run.result) == 2


def test_airborne_over_instanced_forest_reports_trees(tmp_path):
    over = ["platform.pulses_per_line=200", "platform.pulse_rate_hz=20000.0", "platform.speed_m_s=30.0",
            "platform.start_xy_m=[60.0, 60.0]", "platform.end_xy_m=[60.0, 160.0]"]
    cfg = load_scene(SCENES / "forest_airborne.toml", over)
    geo = generate(cfg)
    assert geo.instances is not None and len(geo.instances) > 500
    # 12 prototypes a species (issue 30), each placed with its own yaw; no instance scale
    assert len(geo.instances.prototypes) <= 4 * 12 and np.bincount(geo.instances.proto_index).max() > 5
    np.testing.assert_array_equal(geo.instances.scale, 1.0)
    run = run_scan(cfg, tmp_path / "air", write_png=False)
    res = run.result
    veg = res.cls >= 2
    assert veg.sum() > 1000 and res.tree_id is not None
    assert (res.tree_id[~veg] == 0xFFFFFFFF).all()
    ids = res.tree_id[veg]
    inst = geo.instances
    assert ids.max() < len(inst)
    # Each vegetation return lies within its own tree's crown (prototype extent × scale).
    pts = res.points_m()[veg]
    d = np.hypot(pts[:, 0] - inst.translation_m[ids, 0], pts[:, 1] - inst.translation_m[ids, 1])
    assert np.percentile(d, 99) < 15.0
    # Tops are no higher than the tallest tree.
    assert pts[:, 2].max() < 40.0
    las = laspy.read(tmp_path / "air" / "points.las")
    assert "tree_id" in las.point_format.dimension_names
    np.testing.assert_array_equal(np.sort(np.unique(las.tree_id[las.classification != 2])), np.unique(ids))
