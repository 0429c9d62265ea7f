"""The forest's representation (simlidar_mi.forest.representation): one place decides it, the
truth integrates exactly what the sensor sees, fewer prototypes keep same-seed bytes, and a
forest over the memory limit is refused before it is grown or built."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.config.keys import SECTIONS
from simlidar_mi.errors import ConfigError
from simlidar_mi.forest.representation import (DEFAULT_PROTOTYPES_PER_SPECIES, NESTED_INSTANCING,
                                               representation, scene_parts)
from simlidar_mi.forest.stand import make_forest
from simlidar_mi.lidar.survey import SceneGeometry, generate
from simlidar_mi.plants.random_tree import random_tree

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / "scenes"
# forest_small (40 m square, four species) with two prototypes a species
SMALL = ["forest.instancing=true", "forest.prototypes_per_species=2"]


def _area64(v: np.ndarray) -> np.ndarray:
    """Float64 triangle areas of (n, 3, 3) vertices."""
    v = np.asarray(v, np.float64)
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def test_default_is_a_fixed_pool_of_prototypes():
    assert SECTIONS["forest"]["prototypes_per_species"].default == DEFAULT_PROTOTYPES_PER_SPECIES == 12
    cfg = load_scene(SCENES / "forest_4species.toml")
    assert cfg["forest"]["prototypes_per_species"] == 12


def test_mitsuba_refuses_nested_instances():
    """Leaf clusters cannot be instanced inside an instanced tree: Mitsuba 3 refuses a shapegroup
    that holds an instance, so the representation flattens clusters into the tree's mesh."""
    from simlidar_mi._runtime.mitsuba import mitsuba
    mi = mitsuba()
    assert NESTED_INSTANCING is False
    leaf = mi.load_dict({"type": "rectangle"})
    inner = mi.load_dict({"type": "shapegroup", "leaf": leaf})
    with pytest.raises(RuntimeError, match="Nested instancing is not permitted"):
        mi.load_dict({"type": "shapegroup", "a": {"type": "instance", "shapegroup": inner}})


@pytest.fixture(scope="module")
def small():
    cfg = load_scene(SCENES / "forest_small.toml", SMALL)
    return cfg, generate(cfg)


def test_truth_is_the_prototypes_times_their_transforms(small):
    """The truth's leaf area, in total and per voxel, is the sum over the placed prototypes'
    triangles (float64), the same as the stand expanded tree by tree."""
    from simlidar_mi.truth.compute import compute_truth
    from simlidar_mi.truth.run import truth_grid
    cfg, geo = small
    inst = geo.instances
    assert inst is not None and len(geo.leaves) == 0 and len(inst) >= 4
    ref = sum(float(_area64(inst.prototypes[p][1].vertices).sum()) * s ** 2
              for p, s in zip(inst.proto_index, inst.scale))
    grid = truth_grid(cfg, geo, 1.0)
    ds = compute_truth(geo, grid, progress=False)
    assert ds.attrs["exact_leaf_area_m2"] == pytest.approx(ref, rel=1e-12)
    assert ds.attrs["total_leaf_area_m2"] + ds.attrs["leaf_area_outside_m2"] == pytest.approx(ref, rel=1e-9)
    # the same forest expanded tree by tree (what an explicit build holds) gives the same voxels
    forest = make_forest(cfg)
    b, lv = forest.geometry()
    flat = SceneGeometry(b, lv, [], 0.0, None, cfg.source)
    ds_flat = compute_truth(flat, grid, progress=False)
    np.testing.assert_allclose(ds["leaf_area_m2"].values, ds_flat["leaf_area_m2"].values, rtol=1e-9, atol=1e-12)
    assert float(ds_flat["leaf_area_m2"].values.sum()) > 0.5 * ref
    rep = representation(forest)
    assert rep.kind == "instanced" and rep.triangles_placed == len(lv)
    assert rep.triangles_built == sum(len(p[1]) for p in inst.prototypes) < rep.triangles_placed


def test_fewer_prototypes_keep_same_seed_bytes():
    """Prototype k of a species is the same bytes whatever K (its seed is (scene seed, j, k));
    the same seed and K give the same forest, bit for bit."""
    f4 = make_forest(load_scene(SCENES / "forest_small.toml", SMALL[:1] + ["forest.prototypes_per_species=4"]))
    f2 = make_forest(load_scene(SCENES / "forest_small.toml", SMALL))
    f2b = make_forest(load_scene(SCENES / "forest_small.toml", SMALL))
    for a, b in zip(f2.prototypes, f2b.prototypes):
        assert a.leaves.vertices.tobytes() == b.leaves.vertices.tobytes()
    for arr in ("x_m", "y_m", "yaw_deg", "prototype"):
        assert getattr(f2, arr).tobytes() == getattr(f2b, arr).tobytes()
    # kept from the thinning (a fixed K grows each prototype once): the tree its seed grows alone
    for m, t in enumerate(f2.prototypes):
        alone = random_tree(f2.params.species[int(f2.prototype_species[m])].tree, seed=int(f2.prototype_seed[m]))
        assert t.leaves.vertices.tobytes() == alone.leaves.vertices.tobytes()
        assert t.branches.p1.tobytes() == alone.branches.p1.tobytes()
    by_seed = {int(s): t for s, t in zip(f4.prototype_seed, f4.prototypes)}
    shared = [(t, by_seed[int(s)]) for s, t in zip(f2.prototype_seed, f2.prototypes) if int(s) in by_seed]
    assert shared
    for a, b in shared:
        assert a.leaves.vertices.tobytes() == b.leaves.vertices.tobytes()
        assert a.branches.p1.tobytes() == b.branches.p1.tobytes()


def test_scene_over_the_limit_is_refused_before_it_is_built(small):
    cfg = load_scene(SCENES / "forest_small.toml", SMALL + ["forest.memory_limit_gb=1e-4"])
    with pytest.raises(ConfigError) as e:
        generate(cfg)
    assert e.value.key == "forest.memory_limit_gb" and "\n" not in str(e.value)
    # an explicit forest is refused before its kept trees are grown again
    cfg = load_scene(SCENES / "forest_small.toml", ["forest.instancing=false", "forest.memory_limit_gb=1e-3"])
    with pytest.raises(ConfigError, match="forest.memory_limit_gb"):
        make_forest(cfg)
    forest = make_forest(load_scene(SCENES / "forest_small.toml", SMALL))
    b, lv, inst = scene_parts(forest)
    assert len(lv) == 0 and len(inst) == len(forest)


@pytest.mark.parametrize("value", ["0", "-1", '"lots"', "true"])
def test_bad_memory_limit_names_the_key(value):
    with pytest.raises(ConfigError, match="forest.memory_limit_gb"):
        load_scene(SCENES / "forest_small.toml", [f"forest.memory_limit_gb={value}"])


def test_cli_refuses_over_budget_with_one_line(tmp_path):
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "simlidar_mi.cli", "forest", str(SCENES / "forest_small.toml"),
                        "--out", str(out), *sum((["--set", s] for s in SMALL), []),
                        "--set", "forest.memory_limit_gb=1e-4"], capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 2, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "forest.memory_limit_gb" in lines[0] and "value 0.0001" in lines[0], p.stderr
    assert not out.exists()


def test_canopy_G_is_exact_and_memory_bounded():
    """evaluate-photo's G(θ) of a forest's leaf triangles: horizontal leaves give cos θ, random ones
    the float64 sum per direction; the projections are summed in blocks (a whole directions ×
    triangles matrix took 10 GB on forest_small), so 300 k triangles stay far under 100 MB."""
    import tracemalloc
    from simlidar_mi.truth.photo_scores import canopy_G
    rng = np.random.default_rng(3)
    n = 300_000
    base = rng.uniform(-5, 5, (n, 1, 3))
    flat = base + np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.05, 0]])  # horizontal triangles
    zen = np.array([7.0, 23.0, 38.0, 53.0, 68.0])
    np.testing.assert_allclose(canopy_G(flat, zen), np.cos(np.radians(zen)), rtol=1e-12)
    tri = base + rng.normal(0, 0.05, (n, 3, 3))
    tracemalloc.start()
    g = canopy_G(tri, zen)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 100e6, peak
    va = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ph = (np.arange(72) + 0.5) * 2 * np.pi / 72
    for t, got in zip(np.radians(zen), g):
        ref = np.mean([np.abs(va @ np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])).sum()
                       for p in ph]) / np.linalg.norm(va, axis=1).sum()
        assert got == pytest.approx(ref, rel=1e-12)


def test_an_instanced_forest_reports_the_leaf_triangles_it_places(small):
    """scan said '0 leaf triangles' for an instanced forest (its leaves live in prototypes):
    the count is now the triangles every tree places, the stand's own count."""
    from simlidar_mi.lidar.scene_counts import describe, leaf_triangle_counts
    cfg, geo = small
    m = leaf_triangle_counts(geo)
    forest = make_forest(cfg)
    assert len(geo.leaves) == 0 and m["n_leaf_triangles"] == m["n_leaf_triangles_placed"] \
        == int(forest.n_leaf_triangles.sum()) > m["n_leaf_triangles_prototypes"] > 0
    assert m["n_branches_placed"] == int(forest.n_branches.sum())
    assert describe(m) == (f"{m['n_leaf_triangles']:,} leaf triangles ({m['n_leaf_triangles']:,} placed by "
                           f"{len(forest):,} instanced trees from {m['n_leaf_triangles_prototypes']:,} built)")


def test_photo_G_counts_the_instanced_trees_leaves():
    """evaluate-photo's canopy G(θ) of an instanced forest is the G of the stand expanded tree by
    tree (each prototype weighted by the leaf area its placements hold; the azimuth mean does not
    see the yaw), not NaN: the instanced trees' leaves are not in the scene's own leaf table."""
    from simlidar_mi.truth.photo_scores import canopy_G, scene_canopy_G
    cfg = load_scene(SCENES / "forest_small.toml", [*SMALL, "forest.domain_m=[0.0, 40.0, 0.0, 20.0]"])
    geo = generate(cfg)
    assert len(geo.leaves) == 0 and np.bincount(geo.instances.proto_index).max() >= 2  # one placed twice
    zen = np.array([7.0, 53.0])
    assert np.isnan(canopy_G(geo.leaves.vertices, zen)).all()      # the scene's own leaves: none
    _, lv = make_forest(cfg).geometry()
    np.testing.assert_allclose(scene_canopy_G(geo, zen), canopy_G(lv.vertices, zen), atol=2e-6)


def test_prototypes_over_the_limit_are_refused_after_the_first_batch(monkeypatch):
    """A fixed K keeps every prototype the thinning grows: the K × species it will hold are
    projected from the first batch and refused then, not after all of them are grown."""
    import simlidar_mi.forest.stand as stand_mod  # noqa: PLC0415
    grown = []
    real = stand_mod.iter_random_trees

    def counted(*a, **k):
        for t in real(*a, **k):
            grown.append(len(t.leaves))
            yield t
    monkeypatch.setattr(stand_mod, "iter_random_trees", counted)
    cfg = load_scene(SCENES / "forest_small.toml", SMALL + ["forest.memory_limit_gb=1e-4"])
    with pytest.raises(ConfigError, match=r"the forest \(8 of its prototypes") as e:
        make_forest(cfg)
    assert e.value.key == "forest.memory_limit_gb"
    assert 1 <= len(grown) <= 2   # one species' batch of K = 2, of the 4 × 2 the forest would keep
