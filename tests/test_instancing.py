"""Instanced trees scan exactly like the same trees built one by one."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.geometry import Branches, Leaves
from simlidar_mi.scene.build import Instances, build_scene
from simlidar_mi.lidar.platforms import airborne_pattern, static_pattern
from simlidar_mi.lidar.scan import scan


def prototype():
    """A 3 m trunk with one side branch and one square leaf (2 triangles)."""
    b = Branches(np.array([[0, 0, 0.0], [0, 0, 1.5]]), np.array([[0, 0, 3.0], [0.8, 0, 2.3]]),
                 np.array([0.12, 0.04]), np.array([1, 2], np.int32), np.zeros(2, np.int32))
    sq = np.array([[0.7, -0.2, 2.5], [1.1, -0.2, 2.5], [1.1, 0.2, 2.5], [0.7, 0.2, 2.5]])
    leaves = Leaves(np.stack([sq[[0, 1, 2]], sq[[0, 2, 3]]]), np.array([0, 0], np.int32), np.zeros(2, np.int32))
    return b, leaves


def placed(b: Branches, leaves: Leaves, pos, yaw_deg, scale, tree):
    c, s = np.cos(np.deg2rad(yaw_deg)), np.sin(np.deg2rad(yaw_deg))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    f = lambda p: (scale * p) @ R.T + np.asarray(pos)  # noqa: E731
    return (Branches(f(b.p0), f(b.p1), b.diameter * scale, b.order, np.full(len(b), tree, np.int32)),
            Leaves(f(leaves.vertices.reshape(-1, 3)).reshape(-1, 3, 3), leaves.leaf_id,
                   np.full(len(leaves), tree, np.int32)))


@pytest.fixture(scope="module")
def forest():
    proto = prototype()
    pos = np.array([[1e4 + 5.0, 2e4 + 0.0, 0.0], [1e4 + 0.0, 2e4 + 6.0, 0.0], [1e4 - 4.0, 2e4 - 3.0, 0.0]])
    yaw, scale, tree = np.array([0.0, 90.0, 200.0]), np.array([1.0, 1.3, 0.8]), np.array([7, 8, 9])
    inst = Instances([proto], np.zeros(3, int), pos, yaw, scale, tree)
    parts = [placed(*proto, pos[t], yaw[t], scale[t], tree[t]) for t in range(3)]
    flat_b = Branches.concat([p[0] for p in parts])
    flat_l = Leaves(np.concatenate([p[1].vertices for p in parts]),
                    np.concatenate([p[1].leaf_id for p in parts]), np.concatenate([p[1].plant_id for p in parts]))
    return inst, flat_b, flat_l, pos


def test_instances_match_explicit_geometry(forest):
    inst, flat_b, flat_l, pos = forest
    origin = [1e4, 2e4, 0.0]
    built_i = build_scene(Branches.empty(), instances=inst, origin_m=origin)
    built_f = build_scene(flat_b, flat_l, origin_m=origin)
    assert built_i.n_instances == 3
    pat = static_pattern([1e4, 2e4, 1.5], (-20.0, 40.0, 0.5), (0.0, 360.0, 0.5))
    ri, rf = scan(built_i, pat), scan(built_f, pat)
    assert (rf.cls == 2).sum() > 500 and (rf.cls == 3).sum() > 0
    # A turned prototype's prism facets turn with it, while explicit prisms keep their own
    # orientation: they may differ by the prism's sagitta R(1 − cos π/k) (≈ 2.7 mm here).
    assert np.mean(ri.cls != rf.cls) < 0.002
    both = (ri.cls >= 2) & (ri.cls == rf.cls)
    d = np.abs(ri.range_m[both] - rf.range_m[both])
    assert np.median(d) < 1e-4 and d.max() < 3e-3
    # Tree ids come from the instance; element ids are rows within the prototype.
    wood = (ri.cls == 2) & (rf.cls == 2)
    np.testing.assert_array_equal(ri.tree_id[wood], flat_b.tree_id[rf.element_id[wood]])
    np.testing.assert_array_equal(ri.element_id[ri.cls == 2] % 2, ri.element_id[ri.cls == 2])
    assert set(np.unique(ri.tree_id[ri.cls == 3])) <= {7, 8, 9}
    assert (ri.tree_id[ri.cls < 2] == 0xFFFFFFFF).all()
    # The flat scene reports the same trees through its per-primitive table.
    same = (ri.cls == rf.cls)
    np.testing.assert_array_equal(rf.tree_id[same], ri.tree_id[same])


def test_instanced_airborne_scan_sees_every_tree_top(forest):
    inst, _, _, pos = forest
    built = build_scene(Branches.empty(), instances=inst)
    pat = airborne_pattern([1e4 - 10.0, 2e4 - 10.0], [1e4 + 10.0, 2e4 + 10.0], 100.0, 60.0, 10.0,
                           200_000.0, 400)
    res = scan(built, pat)
    seen = set(np.unique(res.tree_id[res.cls >= 2]).tolist())
    assert seen == {7, 8, 9}
    # Nothing is above the tallest tree top (3 m × 1.3).
    assert res.points_m()[res.cls >= 2][:, 2].max() <= 3.0 * 1.3 + 0.13
