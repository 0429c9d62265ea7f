"""Leafy apple orchards (issue #10 part 1): leaf shape, angle laws, the outer-crown law,
defoliation, seasons, bad keys and determinism (plants/apple_leaves.py, plants/leaf_angles.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.lidar.survey import generate, measure, run_scan
from simlidar_mi.plants.apple import AppleTreeParams, orchard
from simlidar_mi.plants.apple_leaves import (AppleLeafParams, leaf_area_measures,
                                             orchard_leaves, outer_crown_weights)
from simlidar_mi.plants.leaf_angles import (LEAF_ANGLE_LAWS, leaf_angle_cdf,
                                            sample_leaf_angles)
from tests.conftest import REPO

LEAFY = REPO / "scenes" / "orchard_leafy.toml"
TREE = AppleTreeParams(iterations=5, pruning=True, stochastic=True)
N_TREES, SPACING = 4, 2.0
BASES = np.column_stack([np.full(N_TREES, 2.5), SPACING * np.arange(N_TREES)])


@pytest.fixture(scope="module")
def wood():
    return orchard(TREE, N_TREES, SPACING, row_x_m=2.5, seed=7)


def _leaves(wood, seed=7, **kw):
    return orchard_leaves(wood, TREE.iterations, AppleLeafParams(season="leaf-on", **kw),
                          N_TREES, BASES, seed)


# --- shape ------------------------------------------------------------------------------

@pytest.mark.parametrize("sides", [4, 8, 12])
def test_leaf_area_is_the_polygon_closed_form(wood, sides):
    leaves, table = _leaves(wood, sides=sides, leaves_per_m=5.0)
    assert len(table) > 50 and len(leaves) == sides * len(table)
    area = np.bincount(leaves.leaf_id - table.leaf_id[0], weights=leaves.triangle_area)
    closed = sides / 8 * math.sin(2 * math.pi / sides) * table.length_m * table.width_m
    np.testing.assert_allclose(area, closed, rtol=1e-12)
    np.testing.assert_allclose(table.area_m2, closed, rtol=1e-12)
    # every triangle of a blade faces its upper normal, which points to the sky
    v = leaves.vertices
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(n, np.repeat(table.normal, sides, axis=0), atol=1e-9)
    assert (table.normal[:, 2] >= -1e-12).all()
    # 8 sides: 0.7071·ℓw, the apple factor LA = 0.71·L·W (Litschmann et al. 2016) within 0.5 %
    assert abs(AppleLeafParams(sides=8).area_factor - 0.71) < 0.005


def test_leaf_sizes_follow_the_truncated_laws(wood):
    p = AppleLeafParams(season="leaf-on")
    _, table = _leaves(wood)
    ratio = table.width_m / table.length_m
    lo, hi = p.length_mean_m - 2 * p.length_sd_m, p.length_mean_m + 2 * p.length_sd_m
    assert lo <= table.length_m.min() and table.length_m.max() <= hi
    law = stats.truncnorm(-2, 2, loc=p.length_mean_m, scale=p.length_sd_m)
    assert stats.kstest(table.length_m, law.cdf).pvalue > 1e-3
    law_r = stats.truncnorm(-2, 2, loc=p.width_ratio_mean, scale=p.width_ratio_sd)
    assert stats.kstest(ratio, law_r.cdf).pvalue > 1e-3


# --- angle laws -------------------------------------------------------------------------

def test_named_laws_cdf_match_de_wit_densities():
    t = np.linspace(0, math.pi / 2, 2001)
    dens = {"spherical": np.sin(t), "uniform": np.full_like(t, 2 / math.pi),
            "planophile": 2 / math.pi * (1 + np.cos(2 * t)), "erectophile": 2 / math.pi * (1 - np.cos(2 * t)),
            "plagiophile": 2 / math.pi * (1 - np.cos(4 * t)), "extremophile": 2 / math.pi * (1 + np.cos(4 * t))}
    for law in LEAF_ANGLE_LAWS:
        f = dens[law]
        integral = np.concatenate([[0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(t))])
        np.testing.assert_allclose(leaf_angle_cdf(law, t), integral, atol=1e-6)
        assert leaf_angle_cdf(law, math.pi / 2) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("law", LEAF_ANGLE_LAWS)
def test_inverse_cdf_samples_follow_each_law(law):
    u = np.random.default_rng(10).random(20_000)
    theta = sample_leaf_angles(law, u)
    np.testing.assert_allclose(leaf_angle_cdf(law, theta), u, atol=1e-12)  # exact inverse
    assert stats.kstest(theta, lambda x: leaf_angle_cdf(law, x)).pvalue > 0.01
    others = [o for o in LEAF_ANGLE_LAWS if o != law]
    worst = max(stats.kstest(theta, lambda x, o=o: leaf_angle_cdf(o, x)).pvalue for o in others)
    assert worst < 1e-6  # and they tell the laws apart


def test_measured_table_is_sampled_class_by_class():
    table = [[10.0, 1.0], [30.0, 0.0], [60.0, 3.0], [90.0, 1.0]]  # an empty class 10–30°
    u = np.random.default_rng(3).random(50_000)
    deg = np.degrees(sample_leaf_angles(table, u))
    counts, _ = np.histogram(deg, bins=[0, 10, 30, 60, 90])
    assert counts[1] == 0
    expected = np.array([1, 0, 3, 1]) / 5 * len(u)
    keep = expected > 0
    assert stats.chisquare(counts[keep], expected[keep]).pvalue > 0.01
    within = deg[(deg > 30) & (deg < 60)]  # uniform within its class
    assert stats.kstest(within, stats.uniform(30, 30).cdf).pvalue > 0.01


@pytest.mark.parametrize("law", ["planophile", "erectophile", "spherical"])
def test_leaf_normals_in_the_trees_follow_the_law(wood, law):
    _, table = _leaves(wood, angle_distribution=law)
    theta = np.arccos(np.clip(table.normal[:, 2], -1, 1))
    assert stats.kstest(theta, lambda x: leaf_angle_cdf(law, x)).pvalue > 0.01


# --- the outer-crown law ----------------------------------------------------------------

def _outer_inner_density(wood, table, beta_expected=None):
    """Leaves per metre of bearing shoot in the outer (r > 0.5) and inner crown, per the
    leaf bases' nearest bearing-segment midpoint."""
    bear = wood.order > TREE.iterations - 2
    dens = []
    for k in range(N_TREES):
        b = wood.subset(bear & (wood.tree_id == k))
        mid = 0.5 * (b.p0 + b.p1)
        w, r = outer_crown_weights(mid, b.length, BASES[k], 0.0 if beta_expected is None else beta_expected)
        t = table.tree_id == k
        base = table.centre_m[t] - 0.5 * table.length_m[t, None] * table.heading[t]
        # base = shoot point + bark radius (petiole 0): the segment whose axis is nearest
        d0, d1 = b.p0[None], b.p1[None]
        seg = d1 - d0
        s = np.clip(((base[:, None] - d0) * seg).sum(2) / (seg * seg).sum(2), 0, 1)
        dist = np.linalg.norm(base[:, None] - (d0 + s[..., None] * seg), axis=2)
        owner = np.argmin(dist, axis=1)
        outer = r > 0.5
        dens.append([np.isin(owner, np.flatnonzero(outer)).sum(), b.length[outer].sum(),
                     np.isin(owner, np.flatnonzero(~outer)).sum(), b.length[~outer].sum(),
                     (w * b.length)[outer].sum(), (w * b.length)[~outer].sum()])
    n_out, l_out, n_in, l_in, e_out, e_in = np.sum(dens, axis=0)
    return n_out / l_out, n_in / l_in, (e_out / l_out) / (e_in / l_in), n_out, n_in


def test_outer_crown_law_raises_the_outer_density_as_documented(wood):
    # β = 0: one density everywhere; β = 3: the outer shell's density rises by the law's
    # length-weighted ratio ⟨1 + βr⟩_outer / ⟨1 + βr⟩_inner
    flat = _leaves(wood, outer_weight=0.0, petiole_length_m=0.0, leaves_per_m=60.0)[1]
    d_out, d_in, _, n_out, n_in = _outer_inner_density(wood, flat)
    assert d_out / d_in == pytest.approx(1.0, abs=4 * math.sqrt(1 / n_out + 1 / n_in))
    steep = _leaves(wood, outer_weight=3.0, petiole_length_m=0.0, leaves_per_m=60.0)[1]
    d_out, d_in, want, n_out, n_in = _outer_inner_density(wood, steep, beta_expected=3.0)
    assert want > 1.5
    assert d_out / d_in == pytest.approx(want, rel=4 * math.sqrt(1 / n_out + 1 / n_in))
    # the normalisation keeps the expected leaf count: totals agree within Poisson noise
    assert abs(len(steep) - len(flat)) < 4 * math.sqrt(2 * len(flat))


def test_outer_crown_weights_closed_form():
    mid = np.array([[0.0, 0, 1], [1.0, 0, 1], [0, 2.0, 1], [0, 0.5, 3]])
    length = np.array([1.0, 2.0, 1.0, 4.0])
    w, r = outer_crown_weights(mid, length, (0.0, 0.0), 2.0)
    np.testing.assert_allclose(r, [0, 0.5, 1, 0.25])
    raw = 1 + 2.0 * r
    np.testing.assert_allclose(w, raw / (raw @ length / length.sum()))
    assert (w * length).sum() == pytest.approx(length.sum())


# --- seasons ----------------------------------------------------------------------------

def test_defoliation_removes_the_asked_share_nested(wood):
    full_lv, full = _leaves(wood)
    part_lv, part = _leaves(wood, defoliation=0.3)
    more_lv, more = _leaves(wood, defoliation=0.6)
    for k in range(N_TREES):
        n = int((full.tree_id == k).sum())
        assert (part.tree_id == k).sum() == n - round(0.3 * n)
        assert (more.tree_id == k).sum() == n - round(0.6 * n)
    assert set(more.leaf_id) <= set(part.leaf_id) <= set(full.leaf_id)  # nested, ids kept
    kept = np.isin(full_lv.leaf_id, part.leaf_id)
    np.testing.assert_array_equal(full_lv.vertices[kept], part_lv.vertices)  # the rest unmoved
    assert len(_leaves(wood, defoliation=1.0)[0]) == 0


def test_dormant_is_the_wood_alone_and_leaves_never_change_the_wood():
    on = generate(load_scene(LEAFY))
    off = generate(load_scene(LEAFY, ["orchard.leaves.season=dormant"]))
    old = generate(load_scene(REPO / "scenes" / "apple_orchard.toml"))  # no [orchard.leaves]
    assert len(on.leaves) > 0 and len(off.leaves) == 0 and len(old.leaves) == 0
    for f in ("p0", "p1", "diameter", "order", "tree_id"):
        a = getattr(on.branches, f)
        assert a.tobytes() == getattr(off.branches, f).tobytes() == getattr(old.branches, f).tobytes()
    assert measure(load_scene(LEAFY, ["orchard.leaves.season=dormant"])).keys() == \
        measure(load_scene(REPO / "scenes" / "apple_orchard.toml")).keys()


def test_dormant_scan_is_the_leafless_scan(tmp_path):
    coarse = ["scan.dy_m=0.05", "scan.dtheta_deg=2.0", "orchard.n_trees=1"]
    a = run_scan(load_scene(REPO / "scenes" / "apple_orchard.toml", coarse), tmp_path / "a")
    b = run_scan(load_scene(REPO / "scenes" / "apple_orchard.toml",
                            coarse + ["orchard.leaves.season=dormant"]), tmp_path / "b")
    assert (tmp_path / "a" / "points.las").read_bytes() == (tmp_path / "b" / "points.las").read_bytes()
    np.testing.assert_array_equal(a.result.range_m, b.result.range_m)
    np.testing.assert_array_equal(a.result.cls, b.result.cls)


def test_leaf_on_scan_sees_leaves_and_measures_lai(tmp_path):
    cfg = load_scene(LEAFY, ["scan.dy_m=0.05", "scan.dtheta_deg=2.0", "orchard.n_trees=2"])
    run = run_scan(cfg, tmp_path / "s")
    hits = run.measures["hits"]
    assert hits["leaf"] > 0 and hits["wood"] > 0
    assert (run.result.cls == CLASS_CODES["leaf"]).sum() == hits["leaf"]
    import laspy

    from simlidar_mi.io.exr import read_exr
    from simlidar_mi.io.las import LAS_CLASS
    las = laspy.read(tmp_path / "s" / "points.las")
    assert len(las.points) == hits["leaf"] + hits["wood"] + hits["ground"]
    assert (np.asarray(las.classification) == LAS_CLASS[CLASS_CODES["leaf"]]).sum() == hits["leaf"]
    channels, _ = read_exr(tmp_path / "s" / "scan.exr")
    assert (channels["class"] == CLASS_CODES["leaf"]).sum() == hits["leaf"]
    again = run_scan(cfg, tmp_path / "t")  # same seed, same bytes
    for name in ("scan.exr", "points.las"):
        assert (tmp_path / "s" / name).read_bytes() == (tmp_path / "t" / name).read_bytes()
    assert again.measures["LAI_row"] == run.measures["LAI_row"]
    geo = generate(cfg)
    m = run.measures
    per_tree = np.bincount(geo.leaves.plant_id, weights=geo.leaves.triangle_area)
    np.testing.assert_allclose(m["leaf_area_per_tree_m2"], per_tree, rtol=1e-12)
    assert m["LAI_row"] == pytest.approx(per_tree.sum() / (2 * 2.0 * 4.0), rel=1e-12)
    assert m["row_ground_area_m2"] == 16.0
    assert m["n_leaves"] == len(np.unique(geo.leaves.leaf_id))


def test_leaf_ids_unique_and_plants_are_trees():
    geo = generate(load_scene(LEAFY))
    lv = geo.leaves
    first = lv.leaf_id[::8]
    assert len(np.unique(first)) == len(first) and (np.diff(first) > 0).all()
    assert set(np.unique(lv.plant_id)) == set(range(4))
    m = leaf_area_measures(lv, 4, 2.0, 4.0)
    assert m["leaf_area_m2"] == pytest.approx(lv.triangle_area.sum())


# --- determinism and bad input ----------------------------------------------------------

def test_same_seed_same_leaves_bit_for_bit(wood):
    a, b = _leaves(wood, seed=11)[0], _leaves(wood, seed=11)[0]
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert a.leaf_id.tobytes() == b.leaf_id.tobytes()
    assert _leaves(wood, seed=12)[0].vertices.tobytes() != a.vertices.tobytes()


@pytest.mark.parametrize("override, key", [
    ("orchard.leaves.season='summer'", "orchard.leaves.season"),
    ("orchard.leaves.defoliation=1.5", "orchard.leaves.defoliation"),
    ("orchard.leaves.sides=7", "orchard.leaves.sides"),
    ("orchard.leaves.leaves_per_m=-1.0", "orchard.leaves.leaves_per_m"),
    ("orchard.leaves.angle_distribution='flat'", "orchard.leaves.angle_distribution"),
    ("orchard.leaves.angle_distribution=[[95, 1.0]]", "orchard.leaves.angle_distribution"),
    ("orchard.leaves.angle_distribution=[[30, 1.0], [20, 1.0]]", "orchard.leaves.angle_distribution"),
    ("orchard.leaves.angle_distribution=[[30, 0.0]]", "orchard.leaves.angle_distribution"),
    ("orchard.leaves.last_generations=0", "orchard.leaves.last_generations"),
    ("orchard.row_spacing_m=0.0", "orchard.row_spacing_m"),
    ("orchard.leaves.colour=1", "orchard.leaves.colour"),
])
def test_bad_keys_are_refused_naming_file_key_value(override, key):
    with pytest.raises(ConfigError) as err:
        load_scene(LEAFY, [override])
    assert err.value.key == key and err.value.file == f"--set {override}"  # who gave it
    assert f"key '{key}'" in str(err.value) and "value " in str(err.value)


def test_bad_key_in_a_file_names_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[orchard.leaves]\nseason = "leaf-on"\nsides = 9\n')
    with pytest.raises(ConfigError) as err:
        load_scene(bad)
    assert (err.value.file, err.value.key, err.value.value) == (str(bad), "orchard.leaves.sides", 9)


def test_python_api_refuses_bad_params():
    with pytest.raises(ConfigError, match="orchard.leaves.sides"):
        AppleLeafParams(sides=5)
    with pytest.raises(ConfigError, match="orchard.leaves.angle_distribution"):
        AppleLeafParams(angle_distribution=[[0.0, 1.0]])
    with pytest.raises(ConfigError, match="orchard.leaves.outer_weight"):
        AppleLeafParams(outer_weight=-0.5)
