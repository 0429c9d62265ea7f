"""VSP vineyards (plants/vineyard.py, plants/vine_leaf.py) and the two-side path scan."""
from __future__ import annotations

import math

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar.platforms import path_patterns
from simlidar_mi.lidar.survey import generate, run_scan, scan_patterns
from simlidar_mi.plants.vine_leaf import OUTLINE_AREA_FACTOR, OUTLINE_WIDTH_FACTOR
from simlidar_mi.plants.vineyard import (ORDER_CORDON, ORDER_PETIOLE, ORDER_SHOOT, ORDER_TRELLIS,
                                         ORDER_TRUNK, TRELLIS_TREE_ID, VineyardParams, trellis_mask,
                                         vineyard)
from tests.conftest import REPO

SCENE = REPO / "scenes" / "vineyard_vsp.toml"
SMALL = dict(n_rows=2, vines_per_row=3, vine_spacing_m=1.2, post_spacing_m=1.5, row_spacing_m=2.5,
             first_row_x_m=4.0, y_start_m=-1.0)


@pytest.fixture(scope="module")
def small():
    P = VineyardParams(**SMALL)
    return P, vineyard(P, seed=5)


def test_outline_area_factor_is_the_fan_closed_form():
    # Fan of 8 triangles about the petiole junction: Σ ½ r_j r_j+1 sin Δα, written out.
    s = math.sin
    r = math.radians
    k = 2 * (0.5 * 0.60 * 0.45 * s(r(25)) + 0.5 * 0.45 * 0.85 * s(r(35))
             + 0.5 * 0.85 * 0.55 * s(r(30)) + 0.5 * 0.55 * 1.00 * s(r(30)))
    assert OUTLINE_AREA_FACTOR == pytest.approx(k, rel=1e-12)
    assert OUTLINE_WIDTH_FACTOR == pytest.approx(2 * 0.85 * math.sin(math.radians(60)), rel=1e-12)


def test_trellis_posts_and_wires(small):
    P, v = small
    b = v.branches
    t = b.subset(trellis_mask(b))
    assert set(t.tree_id) == {TRELLIS_TREE_ID} and set(t.order) == {ORDER_TRELLIS}
    L = 3 * 1.2
    n_bays = math.ceil(L / 1.5)  # 3 bays of 1.2 m
    n_wires = 1 + 2 * 3
    assert len(t) == 2 * (n_bays + 1 + n_wires)
    for r, x in enumerate((4.0, 6.5)):
        row = t.subset(np.isclose(t.p0[:, 0], x, atol=0.2))
        posts = row.subset(row.p0[:, 2] == 0)
        np.testing.assert_allclose(posts.p0[:, 1], -1.0 + L * np.arange(n_bays + 1) / n_bays, atol=1e-12)
        np.testing.assert_allclose(posts.length, P.post_height_m, atol=1e-12)
        np.testing.assert_allclose(posts.diameter, P.post_diameter_m)
        wires = row.subset(row.p0[:, 2] > 0)
        np.testing.assert_allclose(wires.length, L, atol=1e-12)
        np.testing.assert_allclose(wires.p1[:, 2] - wires.p0[:, 2], 0.0)
        hs = sorted(wires.p0[:, 2])
        assert hs == pytest.approx([0.9, 1.25, 1.25, 1.6, 1.6, 1.95, 1.95])
        catch = wires.subset(wires.p0[:, 2] > 1.0)
        np.testing.assert_allclose(np.abs(catch.p0[:, 0] - x), 0.15, atol=1e-12)


def test_vines_trunks_cordons_and_shoot_counts(small):
    P, v = small
    b = v.branches
    trunks = b.subset(b.order == ORDER_TRUNK)
    assert sorted(trunks.tree_id) == list(range(6))
    zc = 0.9 + 0.5 * (0.0025 + 0.03)
    np.testing.assert_allclose(trunks.p1[:, 2], zc, atol=1e-12)
    for tid in range(6):
        r, k = divmod(tid, 3)
        np.testing.assert_allclose(trunks.p0[tid], [4.0 + 2.5 * r, -1.0 + (k + 0.5) * 1.2, 0.0], atol=1e-12)
    arms = b.subset(b.order == ORDER_CORDON)
    np.testing.assert_allclose(arms.length, 0.5 * (1.2 - 0.06), atol=1e-12)
    ns = round(14.0 * 0.57)
    shoots = b.subset(b.order == ORDER_SHOOT)
    assert len(shoots) == 6 * 2 * ns * P.leaves_per_shoot
    assert len(b.subset(b.order == ORDER_PETIOLE)) == len(v.leaf_table) == 6 * 2 * ns * P.leaves_per_shoot
    # Every shoot ends at the hedge (shoot radius below the canopy top).
    tips = shoots.p1.reshape(-1, P.leaves_per_shoot, 3)[:, -1]
    np.testing.assert_allclose(tips[:, 2], P.canopy_top_z_m - 0.5 * P.shoot_diameter_m, atol=1e-12)


def test_canopy_stays_in_the_shoot_zone(small):
    P, v = small
    vert = v.leaves.vertices.reshape(-1, 3)
    x_row = np.array([P.row_x_m(r) for r in range(P.n_rows)])
    dx = vert[:, 0][:, None] - x_row[None, :]
    near = np.abs(dx).min(1)
    assert near.max() <= 0.5 * P.canopy_width_m + 1e-9
    assert vert[:, 2].min() >= P.canopy_base_z_m - 1e-9 and vert[:, 2].max() <= P.canopy_top_z_m + 1e-9
    sh = v.branches.subset(v.branches.order == ORDER_SHOOT)
    for ends in (sh.p0, sh.p1):
        d = np.abs(ends[:, 0][:, None] - x_row[None, :]).min(1)
        assert d.max() <= 0.5 * (P.canopy_width_m - P.shoot_diameter_m) + 1e-9
        assert ends[:, 2].max() <= P.canopy_top_z_m + 1e-9
    # the hedge: the wall is as tall as configured (to 2 cm)
    assert vert[:, 2].max() > P.canopy_top_z_m - 0.02


def test_free_leaves_leave_the_envelope_with_the_same_draws():
    kw = dict(vines_per_row=2)
    hedged = vineyard(VineyardParams(**kw), seed=2)
    free = vineyard(VineyardParams(**kw, confine_leaves=False), seed=2)
    P = VineyardParams(**kw)
    assert free.leaves.vertices[..., 2].max() > P.canopy_top_z_m + 0.01
    assert free.leaf_table.area_m2.tobytes() == hedged.leaf_table.area_m2.tobytes()
    assert free.leaf_table.normal.tobytes() == hedged.leaf_table.normal.tobytes()
    moved = np.any(free.leaves.vertices != hedged.leaves.vertices, axis=(1, 2)).reshape(-1, 8).all(1)
    assert 0.02 < moved.mean() < 0.5  # the hedge moves the top leaves, not the wall


def test_leaf_area_per_leaf_is_the_outline_closed_form(small):
    P, v = small
    tab, lv = v.leaf_table, v.leaves
    per_leaf = lv.triangle_area.reshape(-1, 8).sum(1)
    np.testing.assert_allclose(per_leaf, OUTLINE_AREA_FACTOR * tab.length_m ** 2, rtol=1e-9)
    np.testing.assert_allclose(per_leaf, tab.area_m2, rtol=1e-9)
    # every triangle faces the leaf's upper normal (winding), and the petiole ends at the blade
    t = lv.vertices
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(n, np.repeat(tab.normal, 8, axis=0), atol=1e-9)
    pet = v.branches.subset(v.branches.order == ORDER_PETIOLE)
    np.testing.assert_allclose(pet.p1, t[::8, 0], atol=1e-12)
    assert np.all(lv.plant_id[::8] == tab.tree_id)


def test_leaf_areas_follow_the_lognormal_mean_and_sd():
    P = VineyardParams(vines_per_row=30)
    a = vineyard(P, seed=1).leaf_table.area_m2
    assert len(a) == 30 * 14 * 24
    assert a.mean() == pytest.approx(P.leaf_area_mean_m2, rel=0.02)
    assert a.std() == pytest.approx(P.leaf_area_sd_m2, rel=0.06)
    fixed = vineyard(VineyardParams(vines_per_row=1, leaf_area_sd_m2=0.0), seed=1).leaf_table.area_m2
    np.testing.assert_allclose(fixed, 0.0095, rtol=1e-12)


def test_same_seed_same_bytes_and_vines_are_independent():
    P = VineyardParams(vines_per_row=3)
    a, b = vineyard(P, seed=9), vineyard(P, seed=9)
    assert a.leaves.vertices.tobytes() == b.leaves.vertices.tobytes()
    assert a.branches.p1.tobytes() == b.branches.p1.tobytes()
    c = vineyard(P, seed=10)
    assert a.leaves.vertices.tobytes() != c.leaves.vertices.tobytes()
    more = vineyard(VineyardParams(vines_per_row=4), seed=9)  # adding a vine keeps the others
    keep = more.leaves.plant_id < 3
    np.testing.assert_array_equal(more.leaves.vertices[keep], a.leaves.vertices)


def test_api_checks_match_the_keys():
    with pytest.raises(ConfigError, match="degrees") as err:
        VineyardParams(leaf_inclination_mean_deg=95.0)
    assert err.value.key == "vineyard.canopy.leaf_inclination_mean_deg"
    with pytest.raises(ConfigError) as err:
        VineyardParams(vines_per_row=2.5)
    assert err.value.key == "vineyard.vines_per_row"


def test_the_vineyard_stands_on_the_ground_plane():
    P = VineyardParams(vines_per_row=2, clusters=True)
    a, b = vineyard(P, seed=4), vineyard(P, seed=4, ground_z_m=-3.5)
    np.testing.assert_allclose(b.leaves.vertices[..., 2], a.leaves.vertices[..., 2] - 3.5, atol=1e-12)
    np.testing.assert_allclose(b.branches.p0[:, 2], a.branches.p0[:, 2] - 3.5, atol=1e-12)
    np.testing.assert_allclose(b.leaf_table.centre_m[:, 2], a.leaf_table.centre_m[:, 2] - 3.5, atol=1e-12)
    assert b.clusters[0].params["p1_m"][2] == pytest.approx(a.clusters[0].params["p1_m"][2] - 3.5)
    assert b.branches.p0[b.branches.order == ORDER_TRUNK, 2] == pytest.approx(-3.5)


def test_clusters_are_primitives_outside_leaves_and_branches():
    off = vineyard(VineyardParams(vines_per_row=2), seed=3)
    on = vineyard(VineyardParams(vines_per_row=2, clusters=True, clusters_per_shoot=2), seed=3)
    n_shoots = len(on.branches.subset(on.branches.order == ORDER_SHOOT)) // 24
    assert len(on.clusters) == 2 * n_shoots and not off.clusters
    assert all(c.kind == "cylinder" and c.label == "wood" for c in on.clusters)
    np.testing.assert_allclose([np.subtract(c.params["p0_m"], c.params["p1_m"])[2] for c in on.clusters], 0.15)
    # clusters draw no random numbers: leaves and wood are the same bytes with and without them
    assert on.leaves.vertices.tobytes() == off.leaves.vertices.tobytes()
    assert on.branches.p0.tobytes() == off.branches.p0.tobytes()


@pytest.mark.parametrize("override, key", [
    ("vineyard.fruiting_wire_height_m=2.5", "vineyard.fruiting_wire_height_m"),
    ("vineyard.catch_wire_heights_m=[1.0, 0.95]", "vineyard.catch_wire_heights_m"),
    ("vineyard.catch_wire_heights_m=[1.2, 3.0]", "vineyard.catch_wire_heights_m"),
    ("vineyard.canopy.leaves_per_shoot=0", "vineyard.canopy.leaves_per_shoot"),
    ("vineyard.canopy.catch_wire_spacing_m=0.5", "vineyard.canopy.catch_wire_spacing_m"),
    ("vineyard.catch_wire_spacing_m=0.6", "vineyard.catch_wire_spacing_m"),
    ("vineyard.cordon_gap_m=1.5", "vineyard.cordon_gap_m"),
    ("vineyard.trunk_height_m=1.5", "vineyard.trunk_height_m"),
    ("vineyard.vine_spacing_m=-1", "vineyard.vine_spacing_m"),
    ("vineyard.canopy.leaf_area_mean_m2=0.2", "vineyard.canopy.leaf_area_mean_m2"),
    ("vineyard.canopy.shoot_inclination_sd_deg=70", "vineyard.canopy.shoot_inclination_sd_deg"),
    ("vineyard.canopy.shoot_azimuth_spread_deg=200", "vineyard.canopy.shoot_azimuth_spread_deg"),
    ("platform.scan_legs=[2, 0]", "platform.scan_legs"),
    ("platform.scan_legs=[0, 3]", "platform.scan_legs"),
])
def test_bad_keys_are_refused(override, key):
    with pytest.raises(ConfigError) as err:
        cfg = load_scene(SCENE, [override])
        lo, hi = generate(cfg).bounds_m()
        scan_patterns(cfg, lo, hi)
    e = err.value
    assert e.key == key and e.file is not None and e.value is not None


def test_unscanned_headland_and_both_sides_face_the_row():
    wp = [[-1.1, -1.0, 1.4], [-1.1, 5.0, 1.4], [1.1, 5.0, 1.4], [1.1, -1.0, 1.4]]
    legs = path_patterns(wp, 0.5, (-10.0, 10.0, 5.0), side="right", scan_legs=[0, 2])
    assert [p.meta["leg"] for p in legs] == [0, 2]
    for p, x, look_x in zip(legs, (-1.1, 1.1), (1.0, -1.0)):
        np.testing.assert_allclose(p.row_origin_m[:, 0], x)
        d = p.world_dirs()[:, 2]  # the horizontal column (elevation 0)
        np.testing.assert_allclose(d, np.tile([look_x, 0.0, 0.0], (len(d), 1)), atol=1e-12)
    assert len(path_patterns(wp, 0.5, (-10.0, 10.0, 5.0))) == 3  # default: every leg
    with pytest.raises(ConfigError, match="shorter than one step"):
        path_patterns(wp, 3.0, (-10.0, 10.0, 5.0), scan_legs=[1])  # a scanned 2.2 m leg


def test_two_side_scan_one_las(tmp_path):
    fast = ["platform.step_m=0.1", "platform.elevation_deg=[-55.0, 55.0, 1.0]",
            "vineyard.vines_per_row=4", "platform.waypoints_m=[[-1.1, -1.0, 1.4], [-1.1, 5.0, 1.4], "
            "[1.1, 5.0, 1.4], [1.1, -1.0, 1.4]]"]
    run = run_scan(SCENE, tmp_path / "v", fast, write_png=False)
    assert [leg["pattern"]["leg"] for leg in run.measures["legs"]] == [0, 2]
    las = laspy.read(tmp_path / "v" / "points.las")
    src = np.asarray(las.point_source_id)
    assert set(src) == {0, 1}
    x, y, cls = np.asarray(las.x), np.asarray(las.y), np.asarray(las.classification)
    leaf, wood = cls == 5, cls == 64
    # each side sees only what lies ahead of its scanner line…
    assert x[src == 0].min() > -1.1 and x[src == 1].max() < 1.1
    # …the near half of the leaf wall more than the far half (seen through gaps), and the
    # near faces of trunks and posts
    assert np.median(x[leaf & (src == 0)]) < -0.02 and np.median(x[leaf & (src == 1)]) > 0.02
    assert np.mean(x[wood & (src == 0)] < 0) > 0.75 and np.mean(x[wood & (src == 1)] > 0) > 0.75
    # no headland: the unscanned leg at y = 5 would look back along −y from the row's end
    assert not (tmp_path / "v" / "scan_leg2.exr").exists()
    both = run_scan(SCENE, tmp_path / "h", fast + ["platform.scan_legs=[0, 1, 2]"], write_png=False,
                    write_las=True)
    src3 = np.asarray(laspy.read(tmp_path / "h" / "points.las").point_source_id)
    assert set(src3) == {0, 1, 2}
    head = laspy.read(tmp_path / "h" / "points.las")
    assert np.asarray(head.y)[src3 == 1].max() < 5.0  # the headland leg looks at the row from its end
    # the two passes are the same scans with or without the headland between them
    assert np.sum(src3 == 0) == np.sum(src == 0) and np.sum(src3 == 2) == np.sum(src == 1)


def test_the_two_side_scan_is_the_same_bytes_twice(tmp_path):
    fast = ["platform.step_m=0.2", "platform.elevation_deg=[-55.0, 55.0, 2.0]", "vineyard.vines_per_row=2",
            "platform.waypoints_m=[[-1.1, -1.0, 1.4], [-1.1, 3.0, 1.4], [1.1, 3.0, 1.4], [1.1, -1.0, 1.4]]"]
    for name in ("a", "b"):
        run_scan(SCENE, tmp_path / name, fast, write_png=False)
    for f in ("points.las", "scan_leg0.exr", "scan_leg1.exr"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
