"""Canopy ground truth: exact clipping of triangles and cylinders to voxels (issue #10 part 3)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches, Leaves, Primitive
from simlidar_mi.lidar.survey import SceneGeometry
from simlidar_mi.truth.compute import compute_truth, default_grid
from simlidar_mi.truth.grid import VoxelGrid, grid_values, read_grid, write_grid
from simlidar_mi.truth.row_metrics import canopy_profiles, lwa_m2_ha, trv_m3_ha
from simlidar_mi.truth.voxelize import Accumulator, clip_triangles, voxelize_cylinders, voxelize_discs


def _geom(branches=None, leaves=None, prims=()):
    return SceneGeometry(branches if branches is not None else Branches.empty(),
                         leaves if leaves is not None else Leaves.empty(), list(prims))


def _leaves(tri):
    tri = np.asarray(tri, np.float64)
    return Leaves(tri, np.arange(len(tri), dtype=np.int32), np.zeros(len(tri), np.int32))


def _cyl(p0, p1, r, shape):
    lat, vol = Accumulator(shape), Accumulator(shape)
    voxelize_cylinders(np.array([p0], float), np.array([p1], float), np.array([r], float), lat, vol)
    return lat, vol


def test_square_leaf_across_voxel_boundaries_gives_exact_overlaps():
    # a 0.20 m × 0.12 m horizontal leaf from (0.05, 0.05) at z = 0.03 on a 0.1 m grid
    x0, x1, y0, y1, z = 0.05, 0.25, 0.05, 0.17, 0.03
    tri = [[[x0, y0, z], [x1, y0, z], [x1, y1, z]], [[x0, y0, z], [x1, y1, z], [x0, y1, z]]]
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.1, (3, 2, 1))
    ds = compute_truth(_geom(leaves=_leaves(tri)), grid, progress=False)
    ox = np.array([0.05, 0.10, 0.05])
    oy = np.array([0.05, 0.07])
    np.testing.assert_allclose(grid_values(ds, "leaf_area_m2")[:, :, 0], np.outer(ox, oy), rtol=1e-12, atol=1e-16)
    assert ds.attrs["total_leaf_area_m2"] == pytest.approx(0.2 * 0.12, rel=1e-14)
    np.testing.assert_allclose(ds["LAD_m2_m3"].values, ds["leaf_area_m2"].values / 1e-3)
    assert ds.attrs["leaf_area_outside_m2"] == 0.0


def test_random_triangles_pieces_sum_to_their_area():
    rng = np.random.default_rng(7)
    tri = rng.uniform(-0.3, 4.3, (3000, 3, 3))
    acc = Accumulator((4, 4, 4))
    for ijk, w in clip_triangles(tri):
        acc.add(ijk, w)
    exact = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert acc.total == pytest.approx(exact, rel=1e-12)
    assert acc.outside > 0  # some fell outside the 4³ grid and were counted, not lost
    # each triangle alone also sums exactly
    for t in tri[:20]:
        a = Accumulator((4, 4, 4))
        for ijk, w in clip_triangles(t[None]):
            a.add(ijk, w)
        assert a.total == pytest.approx(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])), rel=1e-12)


@pytest.mark.parametrize("p0,p1,r", [
    ((0.3, 0.2, 0.1), (3.7, 2.9, 4.6), 0.7),   # oblique, many voxels, pokes out of the grid
    ((1.37, 1.52, 0.2), (1.37, 1.52, 3.7), 0.8),  # axis-aligned (vertical)
    ((0.2, 2.0, 1.5), (3.8, 2.0, 1.5), 0.4),   # axis lying exactly in the plane y = 2
    ((0.51, 0.5, 0.5), (3.5, 3.49, 0.52), 0.03),  # thin, almost horizontal, crossing edges
])
def test_cylinder_area_and_volume_sum_to_exact_totals(p0, p1, r):
    lat, vol = _cyl(p0, p1, r, (5, 5, 5))
    L = np.linalg.norm(np.subtract(p1, p0))
    assert lat.total == pytest.approx(2 * np.pi * r * L, rel=1e-9)
    assert vol.total == pytest.approx(np.pi * r * r * L, rel=1e-9)
    assert (lat.data >= -1e-15).all() and (vol.data >= -1e-15).all()
    d = Accumulator((5, 5, 5))
    voxelize_discs(np.array([p0], float), np.array([np.subtract(p1, p0) / L]), np.array([r]), d)
    assert d.total == pytest.approx(np.pi * r * r, rel=1e-9)


def _disc_cell_area(cx, cy, r, x0, x1, y0, y1):
    """Area of the disc ∩ the rectangle, by adaptive quadrature split at every kink."""
    def f(x):
        s = np.sqrt(max(r * r - (x - cx) ** 2, 0.0))
        return max(0.0, min(y1, cy + s) - max(y0, cy - s))
    a, b = max(x0, cx - r), min(x1, cx + r)
    if b <= a:
        return 0.0
    cand = [cx + sg * np.sqrt(r * r - (yy - cy) ** 2) for yy in (y0, y1) for sg in (-1, 1) if abs(yy - cy) < r]
    pts = sorted(p for p in cand if a < p < b)
    return quad(f, a, b, points=pts or None, epsabs=1e-14, epsrel=1e-13, limit=200)[0]


def _arc_in_cell(cx, cy, r, x0, x1, y0, y1):
    """Angle of the circle inside the rectangle: crossings in closed form, classify midpoints."""
    ang = [0.0, 2 * np.pi]
    for c, e in ((cx, x0), (cx, x1)):
        if abs(e - c) < r:
            t = np.arccos((e - c) / r)
            ang += [t, 2 * np.pi - t]
    for c, e in ((cy, y0), (cy, y1)):
        if abs(e - c) < r:
            t = np.arcsin((e - c) / r)
            ang += [np.mod(t, 2 * np.pi), np.pi - t]
    ang = np.sort(ang)
    tot = 0.0
    for a, b in zip(ang[:-1], ang[1:]):
        m = 0.5 * (a + b)
        x, y = cx + r * np.cos(m), cy + r * np.sin(m)
        tot += (b - a) * (x0 <= x < x1 and y0 <= y < y1)
    return tot


def test_vertical_cylinder_per_voxel_matches_closed_form():
    cx, cy, r, z0, z1 = 1.37, 1.52, 0.8, 0.2, 3.7
    lat, vol = _cyl((cx, cy, z0), (cx, cy, z1), r, (4, 4, 4))
    for i in range(4):
        for j in range(4):
            A = _disc_cell_area(cx, cy, r, i, i + 1, j, j + 1)
            th = _arc_in_cell(cx, cy, r, i, i + 1, j, j + 1)
            for k in range(4):
                dz = max(0.0, min(k + 1, z1) - max(k, z0))
                assert vol.data[i, j, k] == pytest.approx(A * dz, abs=1e-10)
                assert lat.data[i, j, k] == pytest.approx(r * th * dz, abs=1e-12)
    # the top end disc, lying in no voxel plane (z = 3.7)
    d = Accumulator((4, 4, 4))
    voxelize_discs(np.array([[cx, cy, z1]]), np.array([[0.0, 0.0, 1.0]]), np.array([r]), d)
    for i in range(4):
        for j in range(4):
            assert d.data[i, j, 3] == pytest.approx(_disc_cell_area(cx, cy, r, i, i + 1, j, j + 1), abs=1e-11)
    assert d.data[:, :, :3].sum() == 0.0


def test_cylinder_on_a_voxel_plane_splits_in_halves():
    r, L = 0.4, 3.6
    lat, vol = _cyl((0.2, 2.0, 1.5), (3.8, 2.0, 1.5), r, (5, 5, 5))
    ox = np.array([0.8, 1.0, 1.0, 0.8, 0.0])
    for j in (1, 2):
        np.testing.assert_allclose(lat.data[:, j, 1], np.pi * r * ox, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(vol.data[:, j, 1], 0.5 * np.pi * r * r * ox, rtol=1e-10, atol=1e-13)
    assert lat.data.sum() == pytest.approx(2 * np.pi * r * L, rel=1e-13)


def test_oblique_cylinder_per_voxel_agrees_with_monte_carlo():
    p0, p1, r = np.array([0.3, 0.6, 0.4]), np.array([3.2, 2.9, 3.6]), 0.45
    lat, vol = _cyl(p0, p1, r, (5, 5, 5))
    rng = np.random.default_rng(3)
    n = 400_000
    a = (p1 - p0) / np.linalg.norm(p1 - p0)
    u = np.cross(a, [0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.cross(a, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    L = np.linalg.norm(p1 - p0)
    for acc, rho, total in ((lat, np.full(n, r), 2 * np.pi * r * L),
                            (vol, r * np.sqrt(rng.uniform(size=n)), np.pi * r * r * L)):
        t, ph = rng.uniform(0, L, n), rng.uniform(0, 2 * np.pi, n)
        pts = p0 + t[:, None] * a + rho[:, None] * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
        ijk = np.floor(pts).astype(int)
        inside = np.all((ijk >= 0) & (ijk < 5), axis=1)  # the cylinder pokes out of the grid
        mc = np.zeros((5, 5, 5))
        np.add.at(mc, tuple(ijk[inside].T), 1.0)
        assert acc.outside / total == pytest.approx(1 - inside.mean(), abs=5e-3)
        share = acc.data / total
        sd = np.sqrt(np.clip(share * (1 - share), 0, None) / n)  # a share may be −1e-17 (rounding)
        assert np.all(np.abs(mc / n - share) <= 5 * sd + 1e-6)


def test_branch_wood_area_counts_exposed_ends():
    # two collinear segments of equal diameter: the joint is covered, base and tip are not
    b = Branches(np.array([[0.5, 0.5, 0.05], [0.5, 0.5, 0.55]]), np.array([[0.5, 0.5, 0.55], [0.5, 0.5, 1.05]]),
                 np.array([0.1, 0.1]), np.ones(2, np.int32), np.zeros(2, np.int32))
    grid = default_grid(_geom(branches=b), 0.1)
    ds = compute_truth(_geom(branches=b), grid, progress=False)
    r, L = 0.05, 1.0
    assert ds.attrs["total_wood_area_m2"] == pytest.approx(2 * np.pi * r * L + 2 * np.pi * r * r, rel=1e-12)
    assert ds.attrs["total_wood_volume_m3"] == pytest.approx(np.pi * r * r * L, rel=1e-12)
    assert ds.attrs["wood_area_outside_m2"] == 0.0
    np.testing.assert_allclose(ds["plant_area_m2"].values, 0.5 * ds["wood_area_m2"].values)


def test_box_primitive_area_and_volume():
    box = Primitive("box", {"min_m": [0.05, 0.12, 0.0], "max_m": [0.31, 0.2, 0.27]}, "wood")
    g = _geom(prims=[box])
    ds = compute_truth(g, default_grid(g, 0.1), progress=False)
    s = np.array([0.26, 0.08, 0.27])
    assert ds.attrs["total_wood_volume_m3"] == pytest.approx(np.prod(s), rel=1e-12)
    assert ds.attrs["total_wood_area_m2"] == pytest.approx(2 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2]), rel=1e-12)
    assert ds.attrs["wood_area_outside_m2"] == 0.0  # the top face on a voxel plane stays inside


def test_random_canopy_lad_sums_to_n_times_a():
    from simlidar_mi.plants.random_leaves import random_leaves
    n, a = 300, 0.002
    rl = random_leaves(n, a, (1.0, 1.0), (0.2, 0.8), "spherical", seed=4)
    g = _geom(leaves=rl.originals)
    grid = default_grid(g, 0.1)
    ds = compute_truth(g, grid, progress=False, ground_area_m2=1.0)
    assert float(ds["LAD_m2_m3"].sum()) * grid.voxel_volume_m3 == pytest.approx(n * a, rel=1e-12)
    assert ds.attrs["LAI"] == pytest.approx(n * a, rel=1e-12)
    assert float(ds["LAD_profile_m2_m3"].sum()) * grid.voxel_m == pytest.approx(n * a, rel=1e-12)


def test_netcdf_round_trip_and_determinism(tmp_path):
    rng = np.random.default_rng(11)
    tri = rng.uniform(0, 0.6, (200, 3, 3))
    b = Branches(np.array([[0.1, 0.1, 0.0]]), np.array([[0.4, 0.5, 0.6]]), np.array([0.04]),
                 np.ones(1, np.int32), np.zeros(1, np.int32))
    g = _geom(b, _leaves(tri))
    grid = default_grid(g, 0.05, margin_m=0.1)
    d1 = compute_truth(g, grid, progress=False)
    d2 = compute_truth(g, grid, progress=False)
    for name in ("leaf_area_m2", "wood_area_m2", "wood_volume_m3"):
        assert d1[name].values.tobytes() == d2[name].values.tobytes()
    write_grid(d1, tmp_path / "t.nc")
    grid2, back = read_grid(tmp_path / "t.nc", "PAD_m2_m3")
    assert grid2.shape == grid.shape and grid2.voxel_m == grid.voxel_m
    np.testing.assert_allclose(grid2.corner_m, grid.corner_m, atol=1e-12)
    np.testing.assert_array_equal(back["leaf_area_m2"].values, d1["leaf_area_m2"].values)
    assert back.attrs["total_leaf_area_m2"] == d1.attrs["total_leaf_area_m2"]
    assert back["leaf_area_m2"].attrs["units"] == "m2"


def test_row_metrics_of_a_box_hedge():
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.1, (10, 20, 30))
    occ = np.zeros(grid.shape, bool)
    occ[3:7, 2:18, 5:25] = True  # 0.4 m wide across x, 0.5 … 2.5 m high, y 0.2 … 1.8 m
    p = canopy_profiles(occ, grid, "y")
    assert p["mean_height_m"] == pytest.approx(2.5)
    assert p["mean_width_m"] == pytest.approx(0.4)
    assert p["occupied"].sum() == 16 and np.isnan(p["height_m"][0])
    assert canopy_profiles(occ, grid, "y", base="canopy")["mean_height_m"] == pytest.approx(2.0)
    assert float(trv_m3_ha(2.5, 0.4, 4.0)) == pytest.approx(2500.0)
    assert float(lwa_m2_ha(2.5, 4.0)) == pytest.approx(12500.0)
    with pytest.raises(ConfigError) as e:
        trv_m3_ha(2.0, 1.0, 0.0)
    assert e.value.key == "row_spacing_m"
    px = canopy_profiles(occ, grid, "x")
    assert px["mean_width_m"] == pytest.approx(1.6)


def test_bad_voxel_size_is_refused_with_key_and_value(tmp_path):
    from simlidar_mi.truth.run import run_truth
    with pytest.raises(ConfigError) as e:
        run_truth("scenes/random_leaves_spherical.toml", None, ["truth.voxel_m=-0.1"])
    assert e.value.key == "truth.voxel_m" and "-0.1" in str(e.value)
    with pytest.raises(ConfigError) as e:
        VoxelGrid((0, 0, 0), float("nan"), (1, 1, 1))
    assert e.value.key == "voxel_m"
    # too fine for the scene: refused before any array is made (the count does not wrap)
    with pytest.raises(ConfigError) as e:
        run_truth("scenes/random_leaves_spherical.toml", None, ["truth.voxel_m=1e-6"])
    assert e.value.key == "truth.voxel_m" and "voxels" in str(e.value)


def test_truth_command_writes_its_files(tmp_path):
    from simlidar_mi.cli import main
    rc = main(["truth", "scenes/random_leaves_spherical.toml", "--out", str(tmp_path / "t"),
               "--voxel", "0.1", "--set", "truth.row_spacing_m=2.0"])
    assert rc == 0
    names = sorted(p.name for p in (tmp_path / "t").iterdir())
    assert names == ["truth.nc", "truth_profiles.png", "truth_summary.csv"]
    rows = {r.split(",")[0]: r.split(",")[1] for r in
            (tmp_path / "t" / "truth_summary.csv").read_text().splitlines()[1:]}
    assert float(rows["total_leaf_area_m2"]) == pytest.approx(1.0, rel=1e-12)
    assert float(rows["LAI"]) == pytest.approx(1.0, rel=1e-12)  # the 1 m² plot
    h = float(rows["mean_canopy_height_m"])
    assert float(rows["LWA_m2_ha"]) == pytest.approx(2 * h * 1e4 / 2.0)


def test_instances_are_expanded_like_the_scene_builder_places_them():
    from simlidar_mi.scene.build import Instances
    b = Branches(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 0.5], [0.3, 0.0, 0.8]]),
                 np.array([0.06, 0.03]), np.array([1, 2], np.int32), np.zeros(2, np.int32))
    lv = _leaves([[[0.3, 0.0, 0.8], [0.4, 0.05, 0.85], [0.35, 0.1, 0.8]]])
    inst = Instances([(b, lv)], np.array([0, 0]), np.array([[1.0, 2.0, 0.0], [3.3, 1.2, 0.0]]),
                     np.array([0.0, 90.0]), np.array([1.0, 1.5]), np.array([0, 1]))
    placed_b, placed_t = [], []
    for t, yaw, s in zip(inst.translation_m, inst.yaw_deg, inst.scale):
        c, sn = np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))
        R = s * np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
        placed_b.append(Branches(b.p0 @ R.T + t, b.p1 @ R.T + t, b.diameter * s, b.order, b.tree_id))
        placed_t.append(lv.vertices @ R.T + t)
    flat = _geom(Branches.concat(placed_b), _leaves(np.concatenate(placed_t)))
    g = SceneGeometry(Branches.empty(), Leaves.empty(), [], instances=inst)
    grid = default_grid(flat, 0.1, margin_m=0.2)
    d_inst = compute_truth(g, grid, progress=False)
    d_flat = compute_truth(flat, grid, progress=False)
    for name in ("leaf_area_m2", "wood_area_m2", "wood_volume_m3"):
        np.testing.assert_allclose(d_inst[name].values, d_flat[name].values, rtol=1e-12, atol=1e-18)
    assert d_inst.attrs["n_trees_expanded"] == 2
    assert d_inst.attrs["wood_area_outside_m2"] == 0.0


def test_truth_files_are_byte_identical_across_runs(tmp_path):
    from simlidar_mi.truth.run import run_truth
    for d in ("a", "b"):
        run_truth("scenes/apple_orchard.toml", tmp_path / d, ["truth.voxel_m=0.25", "orchard.n_trees=1"])
    for name in ("truth.nc", "truth_summary.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_leaf_labelled_primitives_count_as_leaf_area_without_volume():
    box = Primitive("box", {"min_m": [0.0, 0.0, 0.0], "max_m": [0.2, 0.3, 0.05]}, "leaf")
    cyl = Primitive("cylinder", {"p0_m": [0.5, 0.5, 0.0], "p1_m": [0.5, 0.5, 0.4], "diameter_m": 0.1}, "leaf")
    g = _geom(prims=[box, cyl])
    ds = compute_truth(g, default_grid(g, 0.1), progress=False)
    r = 0.05
    box_area = 2 * (0.2 * 0.3 + 0.3 * 0.05 + 0.2 * 0.05)
    assert ds.attrs["total_leaf_area_m2"] == pytest.approx(box_area + 2 * np.pi * r * 0.4 + 2 * np.pi * r * r, rel=1e-12)
    assert ds.attrs["total_wood_area_m2"] == 0.0 and ds.attrs["total_wood_volume_m3"] == 0.0


@pytest.mark.parametrize("scene, ground_m2", [("orchard_leafy", 4 * 2.0 * 4.0),
                                              ("vineyard_vsp", None)])
def test_truth_lai_counts_the_ground_measure_counts(scene, ground_m2):
    """An orchard's LAI is leaf area over n_trees × spacing × row spacing in both `truth`
    and `measure` (not over the voxel grid's snapped row length)."""
    from pathlib import Path

    from simlidar_mi.lidar.survey import generate, load_scene
    from simlidar_mi.truth.run import row_ground_area_of, run_truth
    path = Path(__file__).resolve().parents[1] / "scenes" / f"{scene}.toml"
    cfg = load_scene(path, ["truth.voxel_m=0.25"])
    ground = row_ground_area_of(cfg)
    if ground_m2 is not None:
        assert ground == pytest.approx(ground_m2)
    v = cfg["vineyard"] if scene.startswith("vine") else None
    if v is not None:
        assert ground == pytest.approx(v["n_rows"] * v["vines_per_row"] * v["vine_spacing_m"] * v["row_spacing_m"])
    ds = run_truth(cfg).dataset
    leaf = float(generate(cfg).leaves.triangle_area.sum())
    assert ds.attrs["ground_area_m2"] == pytest.approx(ground)
    assert ds.attrs["LAI"] == pytest.approx(leaf / ground, rel=1e-12)


# ---------------------------------------------------------------- closed-form volume (flux.py)

def test_disc_polygon_moments_of_known_shapes():
    from simlidar_mi.truth.flux import halfplane_disc_moments

    def mom(g, b):
        return [float(x[0]) for x in halfplane_disc_moments(np.array([g], float).reshape(1, -1, 2),
                                                            np.array([b], float).reshape(1, -1))]
    h = 0.37  # the segment y₁ ≥ h
    A, M1, M2 = mom([[-1.0, 0.0]], [-h])
    assert A == pytest.approx(np.arccos(h) - h * np.sqrt(1 - h * h), rel=1e-14)
    assert M1 == pytest.approx(2 / 3 * (1 - h * h) ** 1.5, rel=1e-14) and abs(M2) < 1e-15
    # a square inside the disc: [0, 0.5]²
    A, M1, M2 = mom([[-1, 0], [1, 0], [0, -1], [0, 1]], [0, 0.5, 0, 0.5])
    assert (A, M1, M2) == pytest.approx((0.25, 0.0625, 0.0625), rel=1e-14)
    # the quarter disc y₁, y₂ ≥ 0: area π/4, moments 1/3
    A, M1, M2 = mom([[-1, 0], [0, -1]], [0, 0])
    assert (A, M1, M2) == pytest.approx((np.pi / 4, 1 / 3, 1 / 3), rel=1e-14)
    # a half-plane that misses the disc
    assert mom([[1.0, 0.0]], [-1.2]) == [0.0, 0.0, 0.0]


def test_flux_volume_of_a_vertical_cylinder_matches_the_closed_form_to_rounding():
    cx, cy, r, z0, z1 = 1.37, 1.52, 0.8, 0.2, 3.7
    _, vol = _cyl((cx, cy, z0), (cx, cy, z1), r, (4, 4, 4))
    for i in range(4):
        for j in range(4):
            A = _disc_cell_area(cx, cy, r, i, i + 1, j, j + 1)
            for k in range(4):
                dz = max(0.0, min(k + 1, z1) - max(k, z0))
                assert vol.data[i, j, k] == pytest.approx(A * dz, abs=1e-13)


def _random_cylinders(rng, n, min_axis):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    keep = np.abs(d).min(axis=1) >= min_axis
    d = d[keep]
    p0 = rng.uniform(2, 5, (len(d), 3))
    L = rng.uniform(0.3, 3.5, len(d))
    return p0, p0 + L[:, None] * d, rng.uniform(0.05, 1.4, len(d))


def test_flux_volume_agrees_with_a_high_order_quadrature_on_random_cylinders(monkeypatch):
    import simlidar_mi.truth.voxelize as V

    p0, p1, r = _random_cylinders(np.random.default_rng(11), 40, 0.01)
    monkeypatch.setattr(V, "GL_NODES", 24)  # quadrature error ~1e-15 at 24 nodes (BENCHMARKS §10c)
    monkeypatch.setattr(V, "GL_NODES_SHORT", 24)
    for m in range(len(r)):
        args = (p0[m:m + 1], p1[m:m + 1], r[m:m + 1])
        f, q, lat = Accumulator((12, 12, 12)), Accumulator((12, 12, 12)), Accumulator((12, 12, 12))
        voxelize_cylinders(*args, lat, f)
        voxelize_cylinders(*args, lat, q, volume_method="quadrature")
        total = np.pi * r[m] ** 2 * np.linalg.norm(p1[m] - p0[m])
        assert np.abs(f.data - q.data).max() <= 1e-12 * total
        assert f.total == pytest.approx(total, rel=1e-14)


@pytest.mark.parametrize("ak", [1e-3, 1e-5, 1e-7])
def test_flux_volume_of_a_nearly_horizontal_axis_is_well_conditioned(monkeypatch, ak):
    """A face nearly parallel to the axis carries (r²/|a_k|)·∫a_k t dA: its rounding grows
    like 1/|a_k|, so such faces run in extended precision; the result must agree with an
    all-extended-precision run to rounding."""
    import simlidar_mi.truth.flux as F

    d = np.array([0.6 * np.sqrt(1 - ak * ak), 0.8 * np.sqrt(1 - ak * ak), ak])
    p0 = np.array([[2.3, 2.6, 2.45]])
    p1 = p0 + 3.1 * d
    r = np.array([0.7])
    _, v64 = _cyl(p0[0], p1[0], r[0], (8, 8, 8))
    monkeypatch.setattr(F, "LOW_AK", 2.0)  # every face in np.longdouble
    _, vld = _cyl(p0[0], p1[0], r[0], (8, 8, 8))
    total = np.pi * r[0] ** 2 * 3.1
    assert np.abs(v64.data - vld.data).max() <= 1e-13 * total


def test_exact_disc_area_per_voxel_matches_the_closed_form_to_rounding():
    cy, cz, r = 1.37, 1.52, 0.8  # a disc facing x: disc ∩ cell is a circle ∩ rectangle in (y, z)
    d = Accumulator((4, 4, 4))
    voxelize_discs(np.array([[2.3, cy, cz]]), np.array([[1.0, 0.0, 0.0]]), np.array([r]), d)
    for j in range(4):
        for k in range(4):
            assert d.data[2, j, k] == pytest.approx(_disc_cell_area(cy, cz, r, j, j + 1, k, k + 1), abs=1e-13)
    assert d.total == pytest.approx(np.pi * r * r, rel=1e-14)
    # a disc lying in a voxel plane belongs to the voxel above it
    d = Accumulator((4, 4, 4))
    voxelize_discs(np.array([[1.6, 1.7, 2.0]]), np.array([[0.0, 0.0, -1.0]]), np.array([0.3]), d)
    assert d.data[:, :, 2].sum() == pytest.approx(np.pi * 0.09, rel=1e-14) and d.data[:, :, 1].sum() == 0.0


@pytest.mark.parametrize("up", [True, False])
@pytest.mark.parametrize("dz0, dz1", [(0.0, 0.0), (1.8e-15, 0.0), (0.0, 8.9e-16), (-1.8e-15, -8.9e-16)])
def test_flux_volume_with_end_discs_in_voxel_planes_stays_in_the_cylinder(dz0, dz1, up):
    """Ends on (or a rounding away from) voxel planes, axis on a voxel edge, pointing up or
    down: each quarter of each layer holds πr²/4, nothing leaks beyond the ends."""
    r = 0.125
    ends = [(2.0, 2.0, 2.0 + dz0), (2.0, 2.0, 6.0 + dz1)]
    _, vol = _cyl(*(ends if up else ends[::-1]), r, (4, 4, 8))
    q = np.pi * r * r / 4
    for k in range(8):
        want = q if 2 <= k < 6 else 0.0
        np.testing.assert_allclose(vol.data[1:3, 1:3, k], want, atol=1e-14)


def test_truth_of_random_branches_has_no_negative_voxels():
    """Closed-form volumes and disc areas are differences of face integrals; a voxel a branch
    barely touches must still not come out negative (rounding), while the sums stay exact."""
    rng = np.random.default_rng(4)
    n = 60
    p0 = rng.uniform(0.0, 1.0, (n, 3))
    p1 = p0 + rng.normal(scale=0.3, size=(n, 3))
    b = Branches(p0, p1, rng.uniform(0.01, 0.2, n), np.ones(n, np.int32), np.zeros(n, np.int32))
    grid = default_grid(_geom(branches=b), 0.05)
    ds = compute_truth(_geom(branches=b), grid, progress=False)
    for name in ("wood_area_m2", "wood_volume_m3", "PAD_m2_m3"):
        assert ds[name].values.min() >= 0.0
    a = ds.attrs
    assert a["total_wood_volume_m3"] == pytest.approx(a["exact_wood_volume_m3"], rel=1e-13)
    assert a["total_wood_area_m2"] == pytest.approx(a["exact_wood_area_m2"], rel=1e-13)
