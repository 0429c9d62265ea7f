"""Issue 30 §1–2: the species presets' foliage lies in its cited ranges; the paper's Poisson count
is the default and its thinning numbers add up; trees.csv's leaf area is the leaf table's."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.config.keys import ARRAY_SECTIONS
from simlidar_mi.forest.foliage import SECTORS, crown_hull, hull_radii_m, polygon_area_m2, union_area_m2
from simlidar_mi.forest.params import ForestSpecies
from simlidar_mi.forest.placement import Bump, SpeciesIntensity
from simlidar_mi.forest.run import run_forest
from simlidar_mi.plants.foliage import SPECIES_FOLIAGE, needle_area_factor
from simlidar_mi.plants.random_tree import random_tree
from simlidar_mi.plants.tree_params import SPECIES_PRESETS

SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def trees():
    return {name: [random_tree(P, s) for s in SEEDS] for name, P in SPECIES_PRESETS.items()}


@pytest.mark.parametrize("name", list(SPECIES_PRESETS))
def test_preset_foliage_in_its_cited_ranges(trees, name):
    """Mean leaf (element) size and mean crown LAI of four seeded trees inside the cited ranges
    (the old presets: 0.09–0.28 crown LAI, far below every range)."""
    P, F = SPECIES_PRESETS[name], SPECIES_FOLIAGE[name]
    ts = trees[name]
    leaf_cm2 = np.mean([t.leaf_table.area_m2.mean() for t in ts]) * 1e4
    lo, hi = F.leaf_area_cm2.value
    assert lo <= leaf_cm2 <= hi
    # conifer: the crown LAI range is of needle area (half the total, Chen & Black 1992)
    f = needle_area_factor(P.shoot_star)
    lai = np.mean([f * t.leaf_table.area_m2.sum() / polygon_area_m2(crown_hull(t)) for t in ts])
    lo, hi = F.crown_lai.value
    assert lo <= lai <= hi, (name, lai)


def test_a_beech_carries_a_few_hundred_square_metres(trees):
    ts = trees["broadleaf-monopodial"]
    assert 13 < np.mean([t.height_m for t in ts]) < 20
    assert 150 < np.mean([t.leaf_table.area_m2.sum() for t in ts]) < 500


def test_wood_keeps_its_share_of_the_plant_area(trees):
    """With foliage 10–60× richer the wood still holds its share α = W/(W + L) of the plant area
    (W: half the branches' lateral surface, as the truth's PAI counts it): the cited woody shares
    (Kuusinen et al. 2021: Norway spruce 0.09–0.10, broadleaf 0.12–0.20) where the preset has
    one, and 0.05–0.3 for every preset (the old presets' wood was ~70 % of the plant area)."""
    for name, ts in trees.items():
        alpha = []
        for t in ts:
            b = t.branches
            w = 0.5 * float(np.sum(np.pi * b.diameter * np.linalg.norm(b.p1 - b.p0, axis=1)))
            alpha.append(w / (w + float(t.leaf_table.area_m2.sum())))
        a = float(np.mean(alpha))
        assert 0.05 < a < 0.3, (name, a)
        cited = SPECIES_FOLIAGE[name].figures.get("wood_share")
        if cited is not None:
            lo, hi = cited.value
            assert lo <= a <= hi, (name, a, cited.value)


def test_spruce_shoots_stand_for_their_needles():
    # a flat element of area A: mean silhouette A/2, total needle area A/(2 STAR), LAI half of it
    assert SPECIES_PRESETS["conifer-whorl"].shoot_star == SPECIES_FOLIAGE["conifer-whorl"].star.value
    assert needle_area_factor(0.16) == pytest.approx(1 / 0.64)
    assert needle_area_factor(0.25) == 1.0 and needle_area_factor(0.0) == 1.0
    assert all(SPECIES_PRESETS[n].shoot_star == 0 for n in SPECIES_PRESETS if n != "conifer-whorl")


def test_union_and_hull_areas_are_exact_on_squares():
    sq = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
    assert polygon_area_m2(sq) == 16.0
    assert union_area_m2([sq, sq + [2.0, 0.0]]) == pytest.approx(24.0)
    assert union_area_m2([sq, sq[::-1] + [10.0, 10.0]]) == pytest.approx(32.0)


def test_hull_radii_are_exact_on_a_square():
    """Radii from the origin to the edge of a 2 m × 4 m rectangle around it: 1 m east, 2 m
    north, √2·min(1, 2)… along the diagonals (the corner lines), 0 for a degenerate hull."""
    rect = np.array([[-1.0, -2.0], [1.0, -2.0], [1.0, 2.0], [-1.0, 2.0]])
    u = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [np.sqrt(0.5), np.sqrt(0.5)]])
    np.testing.assert_allclose(hull_radii_m(rect, u), [1.0, 2.0, 1.0, 2.0, np.sqrt(2.0)], rtol=1e-12)
    np.testing.assert_allclose(hull_radii_m(rect[::-1], u), [1.0, 2.0, 1.0, 2.0, np.sqrt(2.0)], rtol=1e-12)
    assert (hull_radii_m(rect[:2], u) == 0).all()


@pytest.mark.parametrize("instancing", [True, False])
def test_trees_csv_crown_radii_by_sector_reach_the_placed_crown_edge(tmp_path, instancing):
    """Each tree's eight compass radii (N = +y, clockwise) end on the edge of its crown projection
    as placed in the world (turned by its yaw): just inside at 0.999 r, outside at 1.001 r."""
    over = ["forest.domain_m=[0.0, 40.0, 0.0, 40.0]", 'forest.export="none"', 'forest.leaf_table="none"',
            f"forest.instancing={str(instancing).lower()}"]
    run = run_forest(load_scene("scenes/forest_small.toml", over), tmp_path)
    with open(tmp_path / "trees.csv") as fh:
        rows = list(csv.DictReader(fh))
    hulls = list(run.forest.crown_hulls_world())
    assert len(hulls) == len(rows) > 3
    assert len({r["yaw_deg"] for r in rows}) > 3 if instancing else {r["yaw_deg"] for r in rows} == {"0.000000"}
    for r, h in zip(rows, hulls):
        foot = np.array([float(r["x"]), float(r["y"])])
        e = np.roll(h, -1, axis=0) - h
        for k, name in enumerate(SECTORS):
            rad = float(r[f"crown_radius_{name}_m"])
            b = np.deg2rad(45.0 * k)
            u = np.array([np.sin(b), np.cos(b)])
            assert rad > 0
            for f, inside in ((0.999, True), (1.001, False)):
                q = foot + f * rad * u - h
                assert bool(np.all(e[:, 0] * q[:, 1] - e[:, 1] * q[:, 0] >= 0)) == inside, (r["tree_id"], name)


def test_poisson_is_the_default_count():
    assert ARRAY_SECTIONS["species"]["count"].default == "poisson"
    sp = ForestSpecies("a", SPECIES_PRESETS["small-tree"], SpeciesIntensity("a", [Bump(0.01, 5, 5, 50, 50)]))
    assert sp.count == "poisson"


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("foliage")
    over = ["forest.domain_m=[0.0, 14.0, 0.0, 14.0]", 'forest.export="none"', 'forest.leaf_table="all"',
            'forest.leaf_table_format="csv"']
    return run_forest(load_scene("scenes/forest_small.toml", over), out), out


def test_thinning_numbers_add_up(small_run):
    run, _ = small_run
    p = run.forest.placement
    assert set(p.count_mode) == {"poisson"}
    for j, sp in enumerate(run.summary["species"]):
        th = sp["thinning"]
        assert th["expected"] == pytest.approx(float(p.requested[j]))
        assert th["drawn"] - th["removed"] == th["final"] == sp["count"]
        assert th["final_minus_expected"] == pytest.approx(th["final"] - th["expected"])
    assert sum(s["thinning"]["removed"] for s in run.summary["species"]) == run.summary["removed_by_thinning"]


def test_trees_csv_leaf_area_is_the_leaf_tables(small_run):
    run, out = small_run
    with open(out / "trees.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and "leaf_area_m2" in rows[0] and "needle_area_m2" in rows[0]
    area = np.zeros(len(rows))
    with open(out / "leaves.csv") as fh:
        for r in csv.DictReader(fh):
            area[int(r["tree_id"])] += float(r["area_m2"])
    la = np.array([float(r["leaf_area_m2"]) for r in rows])
    assert la == pytest.approx(area, rel=1e-6)     # the CSV rounds each leaf to 7 digits
    fo = run.summary["foliage"]
    assert fo["leaf_area_m2"] == pytest.approx(la.sum())
    assert fo["lai"] == pytest.approx(la.sum() / 14.0 ** 2)
    # per species: leaf area a tree and crown LAI over the trees' own crown projections
    for sp in fo["species"]:
        own = [r for r in rows if r["species"] == sp["name"]]
        la_s = sum(float(r["leaf_area_m2"]) for r in own)
        cp_s = sum(float(r["crown_projection_m2"]) for r in own)
        assert sp["n_trees"] == len(own) and sp["leaf_area_m2"] == pytest.approx(la_s, rel=1e-6)
        if own:
            assert sp["mean_leaf_area_per_tree_m2"] == pytest.approx(la_s / len(own), rel=1e-6)
            assert sp["crown_lai"] == pytest.approx(la_s / cp_s, rel=1e-6)
    # the stand over the union of crowns: no more than their sum, no less than the largest
    cps = [float(r["crown_projection_m2"]) for r in rows]
    assert max(cps) - 1.0 < fo["crown_union_m2"] <= sum(cps) + 1.0
    assert fo["lai_over_crowns"] == pytest.approx(fo["leaf_area_m2"] / fo["crown_union_m2"])
    for r in rows:
        f = needle_area_factor(0.16) if r["species"] == "spruce" else 1.0
        assert float(r["needle_area_m2"]) == pytest.approx(f * float(r["leaf_area_m2"]))


@pytest.mark.parametrize("bad", [0.3, 0.01, -0.1, float("nan")])
def test_a_shoot_star_outside_its_physical_range_is_refused(bad):
    from simlidar_mi.errors import ConfigError
    from simlidar_mi.plants.tree_params import tree_params_from_dict
    with pytest.raises(ConfigError) as e:
        tree_params_from_dict({"shoot_star": bad}, SPECIES_PRESETS["conifer-whorl"], "species[1].tree.")
    assert e.value.key == "species[1].tree.shoot_star"
