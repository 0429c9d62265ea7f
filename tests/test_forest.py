"""Random forests (seed 004, §III): placement through make_forest, instancing, the files of
``simlidar-mi forest`` (trees.csv, leaves.parquet / .csv, PLY/OBJ, pictures), staging and bad configs."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.forest.params import (CROWN_FACTOR, ForestParams, ForestSpecies, forest_params_from_scene,
                                       prototype_seed, tree_seed)
from simlidar_mi.forest.run import run_forest
from simlidar_mi.forest.stand import make_forest, place_tree
from simlidar_mi.io.mesh_export import PART_LEAVES, PART_WOOD, read_obj, read_ply
from simlidar_mi.forest.placement import (Bump, Domain, SpeciesIntensity, candidate_points, crown_overlap_share,
                                          expected_count,
                                          place_trees)
from simlidar_mi.plants.random_tree import random_tree
from simlidar_mi.plants.tree_params import species_preset

SCENES = Path(__file__).resolve().parents[1] / "scenes"

TREES_COLUMNS = ["tree_id", "species", "x", "y", "z_base_m", "height_m", "crown_base_m", "dbh_m",
                 "n_branches", "n_leaves", "seed", "prototype", "yaw_deg", "scale", "crown_radius_m",
                 # issue 31: crown radii by compass sector, from the crown projection
                 *(f"crown_radius_{s}_m" for s in ("n", "ne", "e", "se", "s", "sw", "w", "nw")), "branching",
                 # issue 30: foliage per tree (needle area: the scene has a shoot species)
                 "leaf_area_m2", "crown_projection_m2", "needle_area_m2"]
LEAF_COLUMNS = ["tree_id", "leaf_id", "x", "y", "z", "length_m", "width_m", "area_m2",
                "nx", "ny", "nz", "hx", "hy", "hz"]
FACETS = 6


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """The small scene as shipped: every tree its own draw, leaves.parquet, stand.ply."""
    out = tmp_path_factory.mktemp("forest_full")
    return run_forest(SCENES / "forest_small.toml", out), out


@pytest.fixture(scope="module")
def inst_run(tmp_path_factory):
    """The same scene with instancing (auto prototypes, wood scaled by 0.8–1.25 per prototype)."""
    out = tmp_path_factory.mktemp("forest_inst")
    over = ["forest.instancing=true", 'forest.export="none"', 'forest.leaf_table="all"',
            "forest.scale_range=[0.8, 1.25]", "forest.trees_per_prototype=2", 'forest.prototypes_per_species="auto"',
            'forest.leaf_table_format="csv"']
    return run_forest(SCENES / "forest_small.toml", out, over), out


def read_trees(path: Path) -> tuple[list[str], list[dict]]:
    with open(path, newline="") as fh:
        r = csv.DictReader(fh)
        return list(r.fieldnames), list(r)


def read_leaf_table(path: Path) -> tuple[list[str], np.ndarray]:
    """A leaf table file (Parquet or CSV) as its column names and a float64 matrix."""
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq
        t = pq.read_table(path)
        return t.column_names, np.column_stack([t.column(k).to_numpy() for k in t.column_names])
    with open(path) as fh:
        names = fh.readline().strip().split(",")
    return names, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def world_max_z(forest, i: int) -> float:
    b, lv = forest.tree_geometry(i)
    return float(max(b.p0[:, 2].max(), b.p1[:, 2].max(), lv.vertices[..., 2].max()))


def candidates(f):
    """The candidates forest f drew, per species in arrival order: the same streams as make_forest."""
    p = f.params
    return candidate_points([s.intensity for s in p.species], p.domain,
                            np.random.default_rng(np.random.SeedSequence(f.seed, spawn_key=(0,))),
                            f.placement.count_before)


@pytest.mark.parametrize("run", ["full_run", "inst_run"])
def test_placement_keeps_the_distance_and_crown_rules(run, request):
    r, _ = request.getfixturevalue(run)
    f = r.forest
    p = f.params
    assert p.crown_factor == CROWN_FACTOR == 0.65 and p.min_distance_m == 3.0
    cand = candidates(f)
    c = f.placement.candidate
    # the kept trees are candidates of their species, counted per species before and after
    for j, (x, y, _) in enumerate(cand):
        np.testing.assert_array_equal(f.x_m[f.species == j], x[c[f.species == j]])
        np.testing.assert_array_equal(f.y_m[f.species == j], y[c[f.species == j]])
    counts = np.bincount(f.species, minlength=len(p.species))
    np.testing.assert_array_equal(f.placement.count_before - f.placement.removed, counts)
    assert f.placement.removed.sum() > 0               # the rules did something here
    # the radii the thinning used are the placed trees' crown radii
    np.testing.assert_allclose(f.placement.crown_radius_m, f.crown_radius_m, rtol=1e-12)
    # kept pairs: d > d_min and d ≥ k·(r_i + r_j)
    xy = np.column_stack([f.x_m, f.y_m])
    d = pdist(xy)
    rr = pdist(f.crown_radius_m[:, None], lambda a, b: a[0] + b[0])
    assert d.min() > p.min_distance_m and (d >= p.crown_factor * rr).all()
    # fewer than 10 % of trees have their nearest neighbour's trunk inside their crown
    share = crown_overlap_share(f.x_m, f.y_m, f.crown_radius_m)
    assert share <= 0.10 and r.summary["crown_overlap_share"] == share
    dd = np.sqrt(((xy[:, None] - xy[None]) ** 2).sum(-1)) + np.diag(np.full(len(f), np.inf))
    assert share == (dd.min(1) < f.crown_radius_m).mean()
    d = p.domain
    assert (f.x_m >= d.x_min_m).all() and (f.x_m <= d.x_max_m).all()
    s = r.summary
    assert [sp["count"] for sp in s["species"]] == counts.tolist()
    assert [sp["removed_by_thinning"] for sp in s["species"]] == f.placement.removed.tolist()
    # requested against obtained, per species: the scene's ∫λ counts the Poisson points before
    # the thinning here (the paper's process, the default since issue 30 §2; "stand" was)
    ha = d.area_m2 / 1e4
    for j, sp in enumerate(s["species"]):
        assert sp["count_mode"] == "poisson" and sp["requested_count"] == pytest.approx(
            expected_count(p.species[j].intensity, d), rel=1e-12)
        assert sp["density_per_ha"] == pytest.approx(sp["count"] / ha)
        assert sp["requested_density_per_ha"] == pytest.approx(sp["requested_count"] / ha)
        assert sp["target_count"] is None and sp["count_reached"]
        assert sp["candidates_drawn"] == sp["count"] + sp["removed_by_thinning"]
    assert s["removed_by_thinning"] == int(f.placement.removed.sum())


def test_without_the_crown_rule_crowns_overlap_as_before(full_run):
    """crown_factor = 0 is the plain 3 m rule: the placement of place_trees, many trunks in crowns."""
    f0 = make_forest(load_scene(SCENES / "forest_small.toml", ["forest.crown_factor=0.0"]))
    p = f0.params
    direct = place_trees([s.intensity for s in p.species], p.domain, p.min_distance_m,
                         np.random.default_rng(np.random.SeedSequence(f0.seed, spawn_key=(0,))))
    np.testing.assert_array_equal(f0.x_m, direct.x_m)
    np.testing.assert_array_equal(f0.species, direct.species)
    assert f0.placement.count_mode == ("poisson",) * 4    # the paper's count (the scene's)
    # the crown rule does not change the count mode since the paper's count is the default
    # (issue 30 §2; "auto" chose "stand" with a crown rule)
    assert full_run[0].forest.placement.count_mode == ("poisson",) * 4
    assert crown_overlap_share(f0.x_m, f0.y_m, f0.crown_radius_m) >= 0.3


@pytest.mark.parametrize("name, over", [("forest_small.toml", []),
                                        ("forest_small.toml", ["forest.instancing=true"]),
                                        ("forest_road_scan.toml", []),
                                        ("forest_4species.toml", [])])
def test_included_forests_keep_crown_overlap_moderate(name, over):
    f = make_forest(load_scene(SCENES / name, over))
    s = f.summary()
    assert len(f) > 10 and s["crown_overlap_share"] <= 0.10, (name, s["crown_overlap_share"])
    if f.instancing and f.params.prototypes_per_species == "auto":   # at most 5 trees each
        assert s["trees_per_prototype_max"] <= 5 == f.params.trees_per_prototype
    if f.instancing:                       # a fixed K (default 12): at most K a species
        assert len(f.prototypes) <= 12 * len(f.species_names) or f.params.prototypes_per_species == "auto"
        assert np.bincount(f.prototype).max() == s["trees_per_prototype_max"]
        assert np.bincount(f.prototype).min() >= 1         # unused prototypes are not kept


def test_airborne_scene_has_the_4species_forest():
    a, b = (load_scene(SCENES / n) for n in ("forest_4species.toml", "forest_airborne.toml"))
    assert a["forest"] == b["forest"]
    assert a.arrays["species"] == b.arrays["species"]


@pytest.mark.parametrize("run", ["full_run", "inst_run"])
def test_trees_csv_matches_the_geometry(run, request):
    r, out = request.getfixturevalue(run)
    f = r.forest
    cols, rows = read_trees(out / "trees.csv")
    assert cols == TREES_COLUMNS
    assert len(rows) == len(f) > 10
    for i, row in enumerate(rows):
        b, lv = f.tree_geometry(i)
        assert int(row["tree_id"]) == i
        assert row["species"] == f.species_names[f.species[i]]
        assert float(row["x"]) == pytest.approx(f.x_m[i], abs=1e-6)
        assert float(row["y"]) == pytest.approx(f.y_m[i], abs=1e-6)
        assert float(row["height_m"]) == pytest.approx(world_max_z(f, i), abs=2e-6)
        assert int(row["n_branches"]) == len(b)
        assert int(row["n_leaves"]) == len(f.tree_leaf_table(i)) == len(np.unique(lv.leaf_id))
        # the seed grows the placed geometry: the tree's own, or its prototype's
        seed = (f.prototype_seed[f.prototype[i]]
                if f.instancing else tree_seed(f.seed, f.species[i], f.placement.candidate[i]))
        assert int(row["seed"]) == seed
        assert int(row["prototype"]) == f.prototype[i]
        assert float(row["scale"]) == pytest.approx(f.scale[i], abs=1e-8)
        assert float(row["crown_radius_m"]) == pytest.approx(f.crown_radius_m[i], abs=1e-6)
        assert row["branching"] in ("0", "1")            # one L1 flag per tree
        assert float(row["branching"]) == f.local_tree(i).branching
        # the trunk foot stands at (x, y, 0)
        np.testing.assert_allclose(b.p0[0], [f.x_m[i], f.y_m[i], 0.0], atol=1e-9)
        assert 1.0 < float(row["height_m"]) < 35.0


def test_each_tree_is_rebuilt_from_its_own_seed(full_run):
    """Without instancing, tree i is random_tree(species params, seed of its Poisson point)."""
    f = full_run[0].forest
    assert f.instancing is False and (f.prototype == -1).all()
    assert len(set(f.tree_seed.tolist())) == len(f)
    for i in range(0, len(f), 4):
        params = f.params.species[f.species[i]].tree
        again = random_tree(params, int(f.tree_seed[i]), tree_id=i)
        mine = f.trees[i]
        assert int(f.tree_seed[i]) == tree_seed(f.seed, f.species[i], f.placement.candidate[i])
        assert again.branches.p1.tobytes() == mine.branches.p1.tobytes()
        assert again.leaves.vertices.tobytes() == mine.leaves.vertices.tobytes()
        assert mine.leaf_table.tree_id.tolist() == [i] * mine.n_leaves


@pytest.mark.parametrize("run", ["full_run", "inst_run"])
def test_trees_csv_rows_rebuild_the_placed_trees(run, request):
    """The documented call: place_tree(random_tree(P, row.seed), row.x, row.y, row.yaw_deg, row.scale)."""
    r, out = request.getfixturevalue(run)
    f = r.forest
    _, rows = read_trees(out / "trees.csv")
    scene = forest_params_from_scene(load_scene(SCENES / "forest_small.toml"))
    for i, row in enumerate(rows):
        j = f.species_names.index(row["species"])
        P = species_preset(scene.species[j].preset)          # no law is overridden in this scene
        tree = random_tree(P, int(row["seed"]))
        # the local geometry is the placed tree's, bit for bit
        local = f.local_tree(i)
        again = tree.wood_scaled(f.scale[i]) if f.instancing else tree
        assert again.branches.p1.tobytes() == local.branches.p1.tobytes()
        assert again.leaves.vertices.tobytes() == local.leaves.vertices.tobytes()
        # placed from the CSV's rounded numbers: equal to float tolerance
        b, lv = place_tree(tree, float(row["x"]), float(row["y"]), float(row["yaw_deg"]),
                           float(row["scale"]))
        b0, lv0 = f.tree_geometry(i)
        np.testing.assert_allclose(b.p1, b0.p1, atol=2e-5)
        np.testing.assert_allclose(b.diameter, b0.diameter, rtol=1e-7)
        np.testing.assert_allclose(lv.vertices, lv0.vertices, atol=2e-5)


def test_instances_are_their_prototypes_placed(inst_run):
    f = inst_run[0].forest
    p = f.params
    assert p.prototypes_per_species == "auto" and p.trees_per_prototype == 2
    # candidate i of a species places its prototype i // 2; prototypes grown for candidates
    # no kept tree came from are dropped
    assert f.info["n_prototypes_grown"] >= len(f.prototypes)
    for i in range(len(f)):
        assert f.prototype_seed[f.prototype[i]] == prototype_seed(f.seed, f.species[i],
                                                                  f.placement.candidate[i] // 2)
    uses = np.bincount(f.prototype, minlength=len(f.prototypes))
    assert uses.min() >= 1 and uses.max() <= 2
    np.testing.assert_array_equal(f.prototype_species[f.prototype], f.species)
    assert len(set(f.prototype_seed.tolist())) == len(f.prototypes)
    assert (f.yaw_deg >= 0).all() and (f.yaw_deg < 360).all()
    assert (f.scale >= 0.8).all() and (f.scale <= 1.25).all() and np.ptp(f.scale) > 0.1
    np.testing.assert_array_equal(f.instance_scale, 1.0)      # the wood scale is in the prototype
    for i in range(len(f)):
        r = np.random.default_rng(int(f.tree_seed[i]))        # the yaw comes from the tree's own seed
        assert f.yaw_deg[i] == r.uniform(0, 360)
        proto = f.prototypes[f.prototype[i]]
        assert proto.wood_scale == f.scale[i]                 # one scale per prototype
        grown_tree = random_tree(p.species[f.species[i]].tree, int(f.prototype_seed[f.prototype[i]]))
        b, lv = f.tree_geometry(i)
        c, s = np.cos(np.radians(f.yaw_deg[i])), np.sin(np.radians(f.yaw_deg[i]))
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        t = [f.x_m[i], f.y_m[i], 0]
        # wood: scaled by the prototype's factor; leaves: the drawn sizes, moved with their insertion
        np.testing.assert_allclose(b.p1, f.scale[i] * grown_tree.branches.p1 @ R.T + t, atol=1e-9)
        np.testing.assert_allclose(b.diameter, f.scale[i] * grown_tree.branches.diameter, rtol=1e-12)
        lt, lt0 = f.tree_leaf_table(i), grown_tree.leaf_table
        np.testing.assert_array_equal(lt.length_m, lt0.length_m)
        np.testing.assert_array_equal(lt.area_m2, lt0.area_m2)
        base0 = lt0.centre_m - 0.5 * lt0.length_m[:, None] * lt0.heading
        np.testing.assert_allclose(lt.centre_m, (f.scale[i] * base0 + 0.5 * lt0.length_m[:, None]
                                                 * lt0.heading) @ R.T + t, atol=1e-9)
        tri_len = np.linalg.norm(lv.vertices[:, 2] - lv.vertices[:, 0], axis=1)   # base→tip of rhombus
        tri_len0 = np.linalg.norm(grown_tree.leaves.vertices[:, 2] - grown_tree.leaves.vertices[:, 0], axis=1)
        if p.species[f.species[i]].tree.leaf_shape == "rhombus":
            np.testing.assert_allclose(tri_len, tri_len0, rtol=1e-9)
        assert f.height_m[i] == pytest.approx(proto.height_m, rel=1e-12)
    arrays = f.instance_arrays()
    assert len(arrays["prototypes"]) == len(f.prototypes)
    np.testing.assert_array_equal(arrays["proto_index"], f.prototype)
    np.testing.assert_array_equal(arrays["scale"], 1.0)
    np.testing.assert_array_equal(arrays["translation_m"][:, :2], np.column_stack([f.x_m, f.y_m]))
    with pytest.raises(ConfigError, match="forest.instancing"):
        make_forest_small_full().instance_arrays()


def test_whole_tree_scale_is_the_earlier_behaviour():
    """scale_mode = "whole-tree": one scale per tree on the whole instance, leaves included."""
    f = make_forest(load_scene(SCENES / "forest_small.toml", [
        "forest.instancing=true", "forest.scale_range=[0.8, 1.25]", 'forest.scale_mode="whole-tree"',
        "forest.prototypes_per_species=2"]))
    assert len(f.prototypes) <= 8 and np.bincount(f.prototype).max() >= 2
    np.testing.assert_array_equal(f.instance_scale, f.scale)
    for i in range(len(f)):
        r = np.random.default_rng(int(f.tree_seed[i]))
        assert f.yaw_deg[i] == r.uniform(0, 360) and f.scale[i] == r.uniform(0.8, 1.25)
        proto = f.prototypes[f.prototype[i]]
        np.testing.assert_allclose(f.tree_leaf_table(i).length_m, f.scale[i] * proto.leaf_table.length_m)
        b, _ = place_tree(proto, f.x_m[i], f.y_m[i], f.yaw_deg[i], f.scale[i], "whole-tree")
        np.testing.assert_array_equal(b.p1, f.tree_geometry(i)[0].p1)
        assert f.crown_radius_m[i] == pytest.approx(f.scale[i] * proto.crown_radius_m, rel=1e-12)


def make_forest_small_full():
    sp = ForestSpecies("spruce", species_preset("conifer-whorl"),
                       SpeciesIntensity("spruce", [Bump(0.02, 5.0, 5.0, 50.0, 50.0)]))
    return make_forest(ForestParams(Domain(0, 10, 0, 10), (sp,), 2.0, False), seed=3)


@pytest.mark.parametrize("run", ["full_run", "inst_run"])
def test_leaf_table_matches_the_leaf_triangles(run, request):
    r, out = request.getfixturevalue(run)
    f = r.forest
    path = r.files["leaves"]
    assert path.name == ("leaves.parquet" if run == "full_run" else "leaves.csv")
    names, t = read_leaf_table(path)
    assert names == LEAF_COLUMNS
    assert len(t) == int(f.n_leaves.sum()) == r.summary["leaf_rows_written"]
    tree_id = t[:, 0].astype(int)
    b, lv = f.geometry()
    tri_area = np.bincount(lv.plant_id, weights=lv.triangle_area, minlength=len(f))
    table_area = np.bincount(tree_id, weights=t[:, 7], minlength=len(f))
    np.testing.assert_allclose(table_area, tri_area, rtol=1e-6)
    assert table_area.sum() == pytest.approx(lv.triangle_area.sum(), rel=1e-7)
    # per leaf: area = polygon area of its triangles; centres in the world frame
    key = lv.plant_id.astype(np.int64) * 2**32 + lv.leaf_id
    per_leaf = np.bincount(np.unique(key, return_inverse=True)[1], weights=lv.triangle_area)
    np.testing.assert_allclose(t[:, 7], per_leaf, rtol=2e-6)
    world = f.leaf_table()
    np.testing.assert_allclose(t[:, 2:5], world.centre_m, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(t[:, 8:11], axis=1), 1.0, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(t[:, 11:14], axis=1), 1.0, atol=2e-6)
    assert (t[:, 5] > 0.01).all() and (t[:, 5] < 0.3).all()   # lengths of centimetres


def test_ply_stand_rereads_with_the_right_counts(full_run):
    r, out = full_run
    f = r.forest
    m = read_ply(out / "stand.ply")
    nb, nt = f.n_branches, f.n_leaf_triangles
    assert len(m.vertices) == int((2 * FACETS * nb + 3 * nt).sum())
    assert len(m.faces) == int((2 * FACETS * nb + nt).sum()) == r.summary["export_triangles"]
    part = m.face_props["part"]
    assert (part == PART_WOOD).sum() == 2 * FACETS * nb.sum()
    assert (part == PART_LEAVES).sum() == nt.sum()
    np.testing.assert_array_equal(np.bincount(m.face_props["tree_id"]), 2 * FACETS * nb + nt)
    assert m.faces.min() == 0 and m.faces.max() == len(m.vertices) - 1
    b, lv = f.geometry()
    leaf_v = m.vertices[m.faces[part == PART_LEAVES]]       # (n_tri, 3, 3) in file order
    np.testing.assert_allclose(leaf_v, lv.vertices, atol=1e-5)   # float32 at ≤ 60 m
    # wood: every prism vertex lies at the branch radius from its axis
    wood_v = m.vertices[m.faces[part == PART_WOOD]].reshape(-1, 2 * FACETS, 3, 3)[:, 0, 0]
    d = np.cross(wood_v - b.p0, b.p1 - b.p0)
    dist = np.linalg.norm(d, axis=1) / b.length
    np.testing.assert_allclose(dist, b.diameter / 2, atol=2e-5)
    assert any("part 0 = wood" in c for c in m.comments)


def test_obj_stand_rereads_with_wood_and_leaf_objects(tmp_path):
    over = ["forest.instancing=true", "forest.prototypes_per_species=2", 'forest.export_format="obj"',
            'forest.leaf_table="none"', "forest.domain_m=[0.0, 24.0, 0.0, 24.0]"]
    r = run_forest(SCENES / "forest_small.toml", tmp_path, over)
    f = r.forest
    assert len(f) >= 3 and not list(tmp_path.glob("leaves.*"))
    objs = read_obj(tmp_path / "stand.obj")
    assert set(objs) == {"wood", "leaves"}
    wv, wf = objs["wood"]
    lvv, lf = objs["leaves"]
    assert len(wv) == len(wf) == 2 * FACETS * int(f.n_branches.sum())
    assert len(lf) == int(f.n_leaf_triangles.sum()) and len(lvv) == 3 * len(lf)
    assert wf.min() == 0 and wf.max() == len(wv) - 1 and lf.max() == len(lvv) - 1
    b, lv = f.geometry()
    np.testing.assert_allclose(lvv[lf], lv.vertices, atol=2e-6)
    np.testing.assert_allclose(wv[wf].reshape(-1, 2 * FACETS, 3, 3)[:, 0, 0],
                               wv[::2 * FACETS], atol=0)   # each prism starts at its first ring vertex
    assert len(wv) // (2 * FACETS) == len(b)


def test_pictures_and_summary(full_run):
    r, out = full_run
    for name in ("layout.png", "preview.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    s = json.loads((out / "forest.json").read_text())
    assert s["n_trees"] == len(r.forest) and s["leaf_table"] == "all" and s["export"] == "stand"
    assert not any(p.name.startswith(".") for p in out.parent.iterdir() if p.name.startswith(f".{out.name}"))


def test_prototype_tables_and_meshes(scenes_dir, tmp_path):
    over = ["forest.instancing=true", "forest.prototypes_per_species=2", 'forest.leaf_table="prototypes"',
            'forest.export="prototypes"', "forest.domain_m=[0.0, 20.0, 0.0, 20.0]"]
    r = run_forest(scenes_dir / "forest_small.toml", tmp_path / "o", over)
    f = r.forest
    names, t = read_leaf_table(tmp_path / "o" / "prototype_leaves.parquet")
    assert names[:5] == ["prototype", "leaf_id", "x", "y", "z"]
    assert len(t) == sum(p.n_leaves for p in f.prototypes)
    np.testing.assert_array_equal(np.unique(t[:, 0]), np.arange(len(f.prototypes)))
    plys = sorted((tmp_path / "o" / "prototypes").glob("*.ply"))
    assert len(plys) == len(f.prototypes) <= 8
    for path in plys:
        species, k = path.stem.rsplit("_", 1)
        p = f.prototypes[int(k)]
        assert species == f.species_names[f.prototype_species[int(k)]]
        m = read_ply(path)
        assert len(m.faces) == 2 * FACETS * len(p.branches) + len(p.leaves)
        assert len(m.vertices) == 2 * FACETS * len(p.branches) + 3 * len(p.leaves)
        np.testing.assert_allclose(m.vertices[m.faces[m.face_props["part"] == PART_LEAVES]],
                                   p.leaves.vertices, atol=2e-6)   # own frame, untransformed
    assert not list((tmp_path / "o").glob("leaves.*"))


def test_auto_modes_switch_to_prototypes_for_big_instanced_forests(scenes_dir, tmp_path):
    over = ["forest.instancing=true", "forest.prototypes_per_species=1", "forest.leaf_table_max_rows=10",
            'forest.leaf_table="auto"', 'forest.export="auto"',
            "forest.export_max_triangles=10", "forest.domain_m=[0.0, 15.0, 0.0, 15.0]"]
    r = run_forest(scenes_dir / "forest_small.toml", tmp_path / "o", over)
    assert r.summary["leaf_table"] == "prototypes" and r.summary["export"] == "prototypes"
    with pytest.raises(ConfigError, match=r"key 'forest.leaf_table', value 'prototypes'"):
        run_forest(scenes_dir / "forest_small.toml", tmp_path / "p",
                   ['forest.leaf_table="prototypes"', "forest.domain_m=[0.0, 15.0, 0.0, 15.0]"])


def test_a_failed_run_leaves_nothing_behind(scenes_dir, tmp_path, monkeypatch):
    import simlidar_mi.forest.run as forest_mod

    def boom(*a, **k):
        raise RuntimeError("disk full")
    monkeypatch.setattr(forest_mod, "write_stand", boom)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        run_forest(scenes_dir / "forest_small.toml", out, ["forest.domain_m=[0.0, 12.0, 0.0, 12.0]"])
    assert list(tmp_path.iterdir()) == []       # no output folder, no staging folder


def test_cli_forest(scenes_dir, tmp_path, capsys):
    rc = main(["forest", str(scenes_dir / "forest_small.toml"), "--out", str(tmp_path / "c"),
               "--set", "forest.domain_m=[0.0, 15.0, 0.0, 15.0]", "--set", "forest.instancing=true"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "trees" in text and "removed" in text and "wrote" in text
    assert {p.name for p in (tmp_path / "c").iterdir()} == {
        "trees.csv", "leaves.parquet", "layout.png", "preview.png", "stand.ply", "forest.json"}
    rc = main(["forest", str(scenes_dir / "forest_small.toml"), "--out", str(tmp_path / "d"),
               "--set", "forest.min_distance_m=-1"])
    assert rc == 2 and "forest.min_distance_m" in capsys.readouterr().err


def test_the_300m_scene_is_valid(scenes_dir):
    cfg = load_scene(scenes_dir / "forest_4species.toml")
    p = forest_params_from_scene(cfg)
    assert p.domain.area_m2 == 300.0 * 300.0 and p.instancing and len(p.species) == 4
    assert {s.preset for s in p.species} == {"deciduous-apex", "conifer-whorl",
                                              "broadleaf-monopodial", "small-tree"}


BASE = """
[scene]
seed = 1
[forest]
domain_m = [0.0, 20.0, 0.0, 20.0]
{forest}
[[species]]
name = "elm"
preset = "{preset}"
bumps = [{bump}]
{tree}
"""
GOOD_BUMP = "{ C_per_m2 = 0.01, x0_m = 10.0, y0_m = 10.0, h_m2 = 100.0, l_m2 = 100.0 }"


def scene(forest="", preset="deciduous-apex", bump=GOOD_BUMP, tree=""):
    return BASE.format(forest=forest, preset=preset, bump=bump, tree=tree)


@pytest.mark.parametrize("text, key, value", [
    (scene(tree="[species.tree]\nleaf_length_m = { sd = -0.02 }"),
     "species[0].tree.leaf_length_m.sd", "-0.02"),
    (scene(tree="[species.tree]\ngrowth_level = { values = [5, 6], probs = [0.5, 0.6] }"),
     "species[0].tree.growth_level.probs", r"\[0.5, 0.6\]"),
    (scene(tree="[species.tree]\ntrunk_length_m = { lo = -1.0 }"),
     "species[0].tree.trunk_length_m.lo", "-1.0"),
    (scene(tree="[species.tree]\nbranch_angel_deg = 30"), "species[0].tree.branch_angel_deg", "30"),
    (scene(bump="{ C_per_m2 = 0.01, x0_m = 10.0, y0_m = 10.0, h_m2 = 0.0, l_m2 = 100.0 }"),
     "species[0].bumps[0].h_m2", "0.0"),
    (scene(bump="{ C_per_m2 = -0.01, x0_m = 10.0, y0_m = 10.0, h_m2 = 1.0, l_m2 = 100.0 }"),
     "species[0].bumps[0].C_per_m2", "-0.01"),
    (scene(bump="{ C = 0.01 }"), "species[0].bumps[0].C", "0.01"),
    (scene(preset="oak"), "species[0].preset", "'oak'"),
    (scene(forest="scale_range = [1.2, 0.8]"), "forest.scale_range", r"\[1.2, 0.8\]"),
    (scene(forest='leaf_table = "some"'), "forest.leaf_table", "'some'"),
    (scene(forest='leaf_table_format = "feather"'), "forest.leaf_table_format", "'feather'"),
    (scene(forest="min_distance_m = -2.0"), "forest.min_distance_m", "-2.0"),
    (scene(forest="crown_factor = -0.5"), "forest.crown_factor", "-0.5"),
    (scene(forest='prototypes_per_species = "many"'), "forest.prototypes_per_species", "'many'"),
    (scene(forest="prototypes_per_species = 0"), "forest.prototypes_per_species", "0"),
    (scene(forest="trees_per_prototype = 0"), "forest.trees_per_prototype", "0"),
    (scene(forest='scale_mode = "leaves"'), "forest.scale_mode", "'leaves'"),
    (scene(tree='count = "final"'), "species[0].count", "'final'"),
    (scene(tree="leaf_length_tree_cv = 0.5"), "species[0].leaf_length_tree_cv", "0.5"),
    (scene(tree="n_daughters_tree_cv = -0.1"), "species[0].n_daughters_tree_cv", "-0.1"),
    (scene(forest="max_candidate_factor = 0.5"), "forest.max_candidate_factor", "0.5"),
])
def test_bad_scene_values_name_key_and_value(text, key, value):
    with pytest.raises(ConfigError, match=re.escape(f"key '{key}', value ") + value) as exc:
        make_forest(load_scene(text=text))
    assert exc.value.key == key and exc.value.file == "<scene>"


def test_species_count_mode_and_tree_spreads_come_from_the_scene():
    p = forest_params_from_scene(load_scene(text=scene(tree='count = "poisson"\nleaves_per_branch_tree_cv = 0.2')))
    t = p.species[0].tree
    assert p.species[0].count == "poisson" and t.leaves_per_branch_tree_cv == 0.2
    assert (t.leaf_length_tree_cv, t.n_daughters_tree_cv) == (0.10, 0.05)     # the preset's
    # the paper's count is the default since issue 30 §2 (it was "auto")
    assert forest_params_from_scene(load_scene(text=scene())).species[0].count == "poisson"


def test_adding_a_species_does_not_change_the_trees_of_the_others():
    """Each candidate's tree grows from its own SeedSequence (1, species, candidate)."""
    sp = [ForestSpecies(n, species_preset("small-tree"),
                        SpeciesIntensity(n, [Bump(0.02, 10, 10, 40, 40)]), count="poisson")
          for n in ("a", "b")]
    one = make_forest(ForestParams(Domain(0, 20, 0, 20), sp[:1], 0.0, False, crown_factor=0.0), seed=3)
    two = make_forest(ForestParams(Domain(0, 20, 0, 20), sp, 0.0, False, crown_factor=0.0), seed=3)
    a = two.species == 0
    assert len(one) == int(a.sum()) > 0 and (two.species == 1).any()
    np.testing.assert_array_equal(one.tree_seed, two.tree_seed[a])
    for i, k in enumerate(np.flatnonzero(a)):
        assert one.trees[i].leaves.vertices.tobytes() == two.trees[k].leaves.vertices.tobytes()


def test_a_forest_needs_species():
    with pytest.raises(ConfigError, match="at least one"):
        make_forest(load_scene(text="[forest]\nmin_distance_m = 1.0\n"))
