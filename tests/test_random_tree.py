"""Randomised trees (seed 004, §II): the drawn parameters follow their laws, draws shape the
geometry, seeds are independent and reproducible, leaves are consistent, bad laws are refused."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from simlidar_mi.errors import ConfigError
from simlidar_mi.plants.laws import Bernoulli, Discrete, TruncNormal
from simlidar_mi.plants.random_tree import random_tree
from simlidar_mi.plants.tree_growth import TREE_MEANS, tree_factor_law
from simlidar_mi.plants.tree_params import (SPECIES_PRESETS, RandomTreeParams, leaf_polygon_area_factor,
                                            species_preset, tree_params_from_dict)

# Every law set, several truncated asymmetrically so the truncated moments differ from
# (mean, sd); small trees so many of them are cheap.
TEST_PARAMS = RandomTreeParams(
    name="test",
    trunk_length_m=TruncNormal(3.0, 1.0, 2.5, 5.0),
    trunk_radius_m=TruncNormal(0.10, 0.03, 0.05, 0.12),
    growth_level=Discrete((3, 4, 5), (0.2, 0.5, 0.3)),
    length_ratio=TruncNormal(0.8, 0.1, 0.75, 0.95),
    radius_ratio=TruncNormal(0.7, 0.05, 0.5, 0.72),
    lateral_length_ratio=TruncNormal(0.5, 0.1, 0.3, 0.55),
    lateral_radius_ratio=TruncNormal(0.4, 0.08, 0.35, 0.7),
    lateral_branching=Bernoulli(0.4),
    twist_deg=TruncNormal(10.0, 30.0, -20.0, 80.0),
    n_daughters=Discrete((1, 2, 3), (0.3, 0.3, 0.4)),
    trunk_n_daughters=Discrete((2, 4), (0.5, 0.5)),
    branch_angle_deg=TruncNormal(40.0, 15.0, 30.0, 90.0),
    trunk_branch_angle_deg=TruncNormal(70.0, 10.0, 50.0, 75.0),
    leader_angle_deg=TruncNormal(0.0, 5.0, -3.0, 10.0),
    leaf_length_m=TruncNormal(0.08, 0.03, 0.06, 0.2),
    leaf_width_ratio=TruncNormal(0.5, 0.2, 0.2, 0.6),
    leaves_per_branch=Discrete((2, 3, 7), (0.5, 0.25, 0.25)),
    leaf_angle_deg=TruncNormal(45.0, 20.0, 0.0, 60.0),
    leaf_roll_deg=TruncNormal(5.0, 30.0, -40.0, 60.0),
    monopodial_orders=1, max_order=3, bare_trunk_levels=1, min_length_m=0.0,
    leaf_levels=1, leaf_min_order=3,
    # every tree on the species' means here; the per-tree means are tested on their own
    leaf_length_tree_cv=0.0, n_daughters_tree_cv=0.0, leaves_per_branch_tree_cv=0.0)
GLOBAL_LAWS = ("trunk_length_m", "trunk_radius_m", "growth_level", "length_ratio", "radius_ratio",
               "lateral_length_ratio", "lateral_radius_ratio")
LOCAL_LAWS = ("lateral_branching", "twist_deg", "n_daughters", "trunk_n_daughters",
              "branch_angle_deg", "trunk_branch_angle_deg", "leader_angle_deg", "leaf_length_m",
              "leaf_width_ratio", "leaves_per_branch", "leaf_angle_deg", "leaf_roll_deg")
N_TREES = 400


def law_moments(law) -> tuple[float, float, float]:
    """Mean, SD and central 4th moment of a law (truncated normals via scipy.stats.truncnorm)."""
    if isinstance(law, TruncNormal):
        a, b = (law.lo - law.mean) / law.sd, (law.hi - law.mean) / law.sd
        d = stats.truncnorm(a, b, loc=law.mean, scale=law.sd)
        m, s = float(d.mean()), float(d.std())
        return m, s, float(d.expect(lambda x: (x - m) ** 4))
    if isinstance(law, Bernoulli):
        v, p = np.array([0.0, 1.0]), np.array([1 - law.p, law.p])
    else:
        v, p = np.asarray(law.values, float), np.asarray(law.probs)
    m = float((v * p).sum())
    return m, float(math.sqrt(((v - m) ** 2 * p).sum())), float(((v - m) ** 4 * p).sum())


def check_sample(x: np.ndarray, law, what: str) -> None:
    """Sample mean and SD within 4 standard errors of the law's."""
    x = np.asarray(x, float)
    n = len(x)
    assert n >= 100, f"{what}: only {n} draws"
    m, s, m4 = law_moments(law)
    se_mean = s / math.sqrt(n)
    assert abs(x.mean() - m) < 4 * se_mean, f"{what}: mean {x.mean():.5g} vs {m:.5g} (SE {se_mean:.3g})"
    # SE of the sample SD by the delta method: Var(s²) = (μ4 − σ⁴·(n − 3)/(n − 1))/n
    se_sd = math.sqrt(max(m4 - s ** 4 * (n - 3) / (n - 1), 0.0) / n) / (2 * s)
    assert abs(x.std(ddof=1) - s) < 4 * se_sd + 1e-12, \
        f"{what}: SD {x.std(ddof=1):.5g} vs {s:.5g} (SE {se_sd:.3g})"


@pytest.fixture(scope="module")
def trees():
    return [random_tree(TEST_PARAMS, seed=s, tree_id=s, keep_draws=True) for s in range(N_TREES)]


def test_truncated_moments_differ_from_untruncated():
    """The test laws are truncated enough that comparing with (mean, sd) would be wrong."""
    m, s, _ = law_moments(TEST_PARAMS.radius_ratio)
    assert abs(m - 0.7) > 0.01 and s < 0.04


@pytest.mark.parametrize("name", GLOBAL_LAWS)
def test_global_draws_follow_their_laws(trees, name):
    draws = np.array([t.draws.globals[name] for t in trees])
    check_sample(draws, getattr(TEST_PARAMS, name), name)


@pytest.mark.parametrize("name", LOCAL_LAWS)
def test_local_draws_follow_their_laws(trees, name):
    draws = np.concatenate([t.draws.locals[name] for t in trees])
    check_sample(draws, getattr(TEST_PARAMS, name), name)


def test_draws_stay_inside_truncation_and_support(trees):
    for name in GLOBAL_LAWS + LOCAL_LAWS:
        law = getattr(TEST_PARAMS, name)
        x = (np.array([t.draws.globals[name] for t in trees]) if name in GLOBAL_LAWS
             else np.concatenate([t.draws.locals[name] for t in trees]))
        if isinstance(law, TruncNormal):
            assert law.lo <= x.min() and x.max() <= law.hi, name
        elif isinstance(law, Discrete):
            assert set(np.unique(x)) <= set(law.values), name


def test_sampler_matches_scipy_distribution_in_a_far_tail():
    """Interval 3–5 SD above the mean: inverse CDF on the mirrored side (KS test vs scipy)."""
    law = TruncNormal(1.0, 2.0, 7.0, 11.0)
    x = law.sample(np.random.default_rng(3), 20_000)
    a, b = (7.0 - 1.0) / 2.0, (11.0 - 1.0) / 2.0
    assert stats.kstest(x, stats.truncnorm(a, b, loc=1.0, scale=2.0).cdf).pvalue > 1e-3
    check_sample(x, law, "far-tail truncnormal")
    assert law.moments() == pytest.approx(law_moments(law)[:2], rel=1e-9)


def test_draws_shape_the_geometry(trees):
    P = TEST_PARAMS
    for t in trees[:50]:
        g, b = t.draws.globals, t.branches
        trunk = np.flatnonzero(b.order == 1)
        # monopodial trunk: one segment per generation, lengths and radii scale by r1, wr1
        assert len(trunk) == g["growth_level"]
        ln = b.length[trunk]
        assert ln[0] == pytest.approx(g["trunk_length_m"], rel=1e-12)
        assert b.diameter[trunk[0]] == pytest.approx(2 * g["trunk_radius_m"], rel=1e-12)
        np.testing.assert_allclose(ln[1:] / ln[:-1], g["length_ratio"], rtol=1e-9)
        np.testing.assert_allclose(b.diameter[trunk][1:] / b.diameter[trunk][:-1], g["radius_ratio"],
                                   rtol=1e-9)
        # laterals of the trunk: r2 and wr2 of the trunk segment they grow from
        lat = np.flatnonzero(b.order == 2)
        if len(lat):
            ratios = b.length[lat] / ln[:, None]
            assert np.isclose(ratios, g["lateral_length_ratio"], rtol=1e-9).any(axis=0).all()
            dr = b.diameter[lat] / b.diameter[trunk][:, None]
            assert np.isclose(dr, g["lateral_radius_ratio"], rtol=1e-9).any(axis=0).all()
        # no laterals on the bare first trunk segment: order-2 daughters start above it
        assert P.bare_trunk_levels == 1 and (b.p0[lat, 2] >= ln[0] - 1e-9).all()
        # leaves: sizes are the drawn ones
        lt = t.leaf_table
        assert len(lt) == int(t.draws.locals["leaves_per_branch"].sum())
        np.testing.assert_array_equal(lt.length_m, t.draws.locals["leaf_length_m"])
        np.testing.assert_allclose(lt.width_m / lt.length_m, t.draws.locals["leaf_width_ratio"],
                                   rtol=1e-12)


def test_leaves_are_consistent_flat_polygons(trees):
    for shape, k in (("rhombus", 2), ("ellipse", 8)):
        P = tree_params_from_dict({"leaf_shape": shape, "leaf_sides": 8}, TEST_PARAMS)
        t = random_tree(P, 11, tree_id=5)
        lv, lt = t.leaves, t.leaf_table
        assert len(lv) == k * len(lt)
        assert (lv.plant_id == 5).all() and (lt.tree_id == 5).all()
        np.testing.assert_array_equal(lv.leaf_id, np.repeat(lt.leaf_id, k))
        area = np.bincount(lv.leaf_id, weights=lv.triangle_area)
        np.testing.assert_allclose(area, lt.area_m2, rtol=1e-9)
        np.testing.assert_allclose(lt.area_m2, leaf_polygon_area_factor(shape, 8) * lt.length_m * lt.width_m,
                                   rtol=1e-12)
        for v in (lt.normal, lt.heading):
            np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
        assert np.abs((lt.normal * lt.heading).sum(1)).max() < 1e-12
        assert (lt.normal[:, 2] >= -1e-12).all()          # roll within ±90°: upper side up
        v = lv.vertices
        tri_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        tri_n /= np.linalg.norm(tri_n, axis=1, keepdims=True)
        np.testing.assert_allclose(tri_n, np.repeat(lt.normal, k, axis=0), atol=1e-9)  # winding
        # extent along the heading is the length and across it the width (an even polygon
        # has its base, tip and side points as vertices), centred on the centre
        rel = v.reshape(len(lt), -1, 3) - lt.centre_m[:, None, :]
        along = (rel * lt.heading[:, None, :]).sum(2)
        np.testing.assert_allclose(along.max(1), 0.5 * lt.length_m, rtol=1e-9)
        np.testing.assert_allclose(along.min(1), -0.5 * lt.length_m, rtol=1e-9)
        across = (rel * np.cross(lt.normal, lt.heading)[:, None, :]).sum(2)
        np.testing.assert_allclose(across.max(1) - across.min(1), lt.width_m, rtol=1e-9)
        assert np.abs((rel * lt.normal[:, None, :]).sum(2)).max() < 1e-12   # flat


def test_same_seed_same_bytes_and_trees_are_independent():
    P = species_preset("conifer-whorl")
    a = [random_tree(P, s, tree_id=i) for i, s in enumerate((10, 11, 12))]
    b = [random_tree(P, s, tree_id=i) for i, s in enumerate((10, 99, 12))]   # tree 1's seed changed
    c = [random_tree(P, s, tree_id=i) for i, s in enumerate((10, 11, 12))]

    def raw(t):
        return b"".join(x.tobytes() for x in (t.branches.p0, t.branches.p1, t.branches.diameter,
                                               t.branches.order, t.leaves.vertices, t.leaves.leaf_id,
                                               t.leaf_table.centre_m, t.leaf_table.normal))
    assert [raw(t) for t in a] == [raw(t) for t in c]
    assert raw(a[0]) == raw(b[0]) and raw(a[2]) == raw(b[2])
    assert raw(a[1]) != raw(b[1])
    # a Generator or SeedSequence works too, and the integer seed is recorded
    assert a[0].seed == 10
    g = random_tree(P, np.random.default_rng(10))
    assert raw(g) == raw(random_tree(P, 10))


@pytest.mark.parametrize("name", list(SPECIES_PRESETS))
def test_presets_are_realistic_trees(name):
    hs, rs, leaf = [], [], []
    for s in range(12):
        t = random_tree(species_preset(name), s)
        hs.append(t.height_m)
        rs.append(t.branches.diameter[0] / 2)
        leaf.append(t.leaf_table.length_m.mean())
        assert t.branches.p0[0].tolist() == [0.0, 0.0, 0.0]
        assert t.branches.order[0] == 1 and len(t.leaves) > 1000
    lo_h = 4.0 if name == "small-tree" else 10.0
    assert lo_h < min(hs) and max(hs) < 30.0, (name, hs)
    assert 0.04 < min(rs) and max(rs) < 0.4            # trunk radii of centimetres
    assert 0.01 < min(leaf) and max(leaf) < 0.2        # leaves of centimetres
    assert species_preset(name).name == name


def test_bad_laws_are_refused_naming_key_and_value():
    with pytest.raises(ConfigError, match=r"key 'TruncNormal.sd', value -1.0"):
        TruncNormal(1.0, -1.0)
    with pytest.raises(ConfigError, match=r"key 'trunk_length_m.lo', value -1.0.*strictly positive"):
        RandomTreeParams(trunk_length_m=TruncNormal(1.0, 0.5, -1.0, 2.0))
    with pytest.raises(ConfigError, match=r"key 'Discrete.probs'.*sum to 1"):
        Discrete((3, 4), (0.5, 0.6))                 # a law alone knows no field name
    with pytest.raises(ConfigError, match=r"key 'sp.tree.growth_level.probs', value \[0.5, 0.6\].*sum to 1"):
        tree_params_from_dict({"growth_level": {"values": [3, 4], "probs": [0.5, 0.6]}},
                              key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'sp.tree.growth_level.values', value 0"):
        tree_params_from_dict({"growth_level": {"values": [0, 4]}}, key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'n_daughters.values', value 1.5"):
        RandomTreeParams(n_daughters=Discrete((1.5, 2), (0.5, 0.5)))
    with pytest.raises(ConfigError, match=r"key 'Bernoulli.p', value 1.5"):
        Bernoulli(1.5)
    with pytest.raises(ConfigError, match=r"key 'sp.tree.lateral_branching.p', value 1.5"):
        tree_params_from_dict({"lateral_branching": 1.5}, key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'leaf_roll_deg.hi'"):
        RandomTreeParams(leaf_roll_deg=TruncNormal(0.0, 10.0, -10.0, 95.0))
    with pytest.raises(ConfigError, match=r"key 'TruncNormal.lo', value 50.0.*almost no probability"):
        TruncNormal(0.0, 1.0, 50.0, 60.0)
    with pytest.raises(ConfigError, match=r"key 'sp\[0\].tree.leaf_length_m.sd', value -0.1"):
        tree_params_from_dict({"leaf_length_m": {"sd": -0.1}}, key_prefix="sp[0].tree.")
    with pytest.raises(ConfigError, match=r"key 'sp.tree.leaf_length_m.median'"):
        tree_params_from_dict({"leaf_length_m": {"median": 0.1}}, key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'sp.tree.branch_angel_deg'.*unknown tree parameter"):
        tree_params_from_dict({"branch_angel_deg": 30}, key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'sp.tree.leaf_shape', value 'square'"):
        tree_params_from_dict({"leaf_shape": "square"}, key_prefix="sp.tree.")
    with pytest.raises(ConfigError, match=r"key 'preset', value 'oak'.*deciduous-apex"):
        species_preset("oak")
    with pytest.raises(ConfigError, match=r"key 'seed', value -3"):
        random_tree(TEST_PARAMS, -3)


def test_overrides_merge_into_the_preset():
    base = species_preset("deciduous-apex")
    p = tree_params_from_dict({"leaf_length_m": {"mean": 0.12}, "growth_level": 5,
                               "lateral_branching": 0.5, "lateral_length_ratio": {"mean": 0.6, "sd": 0.0}},
                              base)
    assert p.leaf_length_m == TruncNormal(0.12, base.leaf_length_m.sd, base.leaf_length_m.lo,
                                          base.leaf_length_m.hi)
    assert p.growth_level == Discrete((5,), (1.0,))
    assert p.lateral_branching == Bernoulli(0.5)
    assert p.lateral_length_ratio.moments() == (0.6, 0.0)
    assert p.trunk_radius_m == base.trunk_radius_m


def test_branch_guard():
    P = tree_params_from_dict({"max_branches": 10}, TEST_PARAMS)
    with pytest.raises(ConfigError, match="max_branches"):
        for s in range(20):
            random_tree(P, s)


def _lateral_offsets(t) -> np.ndarray:
    """For each branch but the trunk's first, its distance to the nearest branch end (0 at an apex)."""
    from scipy.spatial import cKDTree
    d, _ = cKDTree(t.branches.p1).query(t.branches.p0[1:])
    return d


@pytest.mark.parametrize("per", ["tree", "branch"])
def test_branching_flag_is_drawn_once_per_tree_by_default(per):
    """L1 (§II-C): per tree, all daughters of a tree sprout at apices or all along mothers."""
    P = tree_params_from_dict({"lateral_branching_per": per} if per == "branch" else {},
                              species_preset("broadleaf-monopodial"))
    assert RandomTreeParams().lateral_branching_per == "tree" and P.lateral_branching.p == 0.7
    shares = []
    for s in range(24):
        t = random_tree(P, s, keep_draws=True)
        flags = t.draws.locals["lateral_branching"]
        off = _lateral_offsets(t)
        if per == "tree":
            assert flags.shape == (1,) and t.branching == float(flags[0])
            if t.branching == 0:             # every daughter at its mother's apex
                assert off.max() < 1e-9
            else:                            # laterals at U(0.25, 1) along their mothers
                assert (off > 1e-3).mean() > 0.3
        else:
            assert len(flags) > 50 and t.branching == pytest.approx(flags.mean())
        shares.append(t.branching)
    shares = np.array(shares)
    if per == "tree":      # whole trees of both kinds (p = 0.7)
        assert set(shares) == {0.0, 1.0}
    else:                  # every tree mixes both kinds, near p
        assert ((shares > 0.5) & (shares < 0.9)).all()


def test_wood_scaled_keeps_leaf_sizes_and_insertions():
    t = random_tree(species_preset("deciduous-apex"), 3)
    s = 1.2
    w = t.wood_scaled(s)
    assert t.wood_scaled(1.0) is t and w.wood_scale == s
    np.testing.assert_array_equal(w.branches.p1, s * t.branches.p1)
    np.testing.assert_array_equal(w.branches.diameter, s * t.branches.diameter)
    # each leaf is its drawn blade moved by (s − 1)·(insertion point): same size and orientation
    lt, lw = t.leaf_table, w.leaf_table
    np.testing.assert_array_equal(lw.length_m, lt.length_m)
    np.testing.assert_array_equal(lw.normal, lt.normal)
    moved = w.leaves.vertices - t.leaves.vertices                # (n_tri, 3, 3)
    np.testing.assert_allclose(moved - moved[:, :1], 0.0, atol=1e-12)  # a rigid shift per leaf
    base = lt.centre_m - 0.5 * lt.length_m[:, None] * lt.heading
    np.testing.assert_allclose(moved[:, 0], (s - 1) * base[t.leaves.leaf_id], atol=1e-12)
    # the insertion point stays on the (scaled) bark: its distance to the trunk axis scales by s
    assert w.crown_radius_m == pytest.approx(s * t.crown_radius_m, rel=0.02)
    with pytest.raises(ConfigError, match="scale"):
        t.wood_scaled(0.0)


def test_bad_branching_mode_is_refused():
    with pytest.raises(ConfigError, match=r"key 'sp.tree.lateral_branching_per', value 'leaf'"):
        tree_params_from_dict({"lateral_branching_per": "leaf"}, key_prefix="sp.tree.")


# --- per-tree means (seed 004 §II-B: "mean leaf sizes; mean for the number of daughter
# branches and the number of leaves" vary per tree) -----------------------------------------

SPREAD = {"leaf_length_tree_cv": 0.15, "n_daughters_tree_cv": 0.10, "leaves_per_branch_tree_cv": 0.20}


@pytest.fixture(scope="module")
def spread_trees():
    P = dataclasses.replace(TEST_PARAMS, **SPREAD)
    return P, [random_tree(P, seed=s, tree_id=s, keep_draws=True) for s in range(N_TREES)]


def test_each_tree_draws_its_own_means_around_the_species_law(spread_trees, trees):
    P, ts = spread_trees
    for name in TREE_MEANS:
        f = np.array([t.draws.globals[f"{name}_tree_factor"] for t in ts])
        law = tree_factor_law(SPREAD[f"{name}_tree_cv"])
        assert law.moments()[0] == pytest.approx(1.0, abs=1e-12)   # symmetric cut: species mean kept
        check_sample(f, law, f"{name} factor")
    # leaf length: every leaf is the tree's factor times a draw of the species law, so the
    # within-tree draws centre on the tree's mean f·μ
    mu, sd = TEST_PARAMS.leaf_length_m.moments()
    f = np.array([t.draws.globals["leaf_length_tree_factor"] for t in ts])
    for t, ft in zip(ts, f):
        raw = t.draws.locals["leaf_length_m"]
        assert t.leaf_table.length_m.tobytes() == (ft * raw).tobytes()
    check_sample(np.concatenate([t.leaf_table.length_m / ft for t, ft in zip(ts, f)]),
                 TEST_PARAMS.leaf_length_m, "leaf length / tree factor")
    # between trees: SD of the per-tree mean leaf length = sqrt(μ²·Var f + E[σ²/n]), against
    # only sqrt(E[σ²/n]) when every tree takes the species' mean (the trees of TEST_PARAMS)
    def between(sample, factors):
        keep = [k for k, t in enumerate(sample) if t.n_leaves >= 2]
        means = np.array([sample[k].leaf_table.length_m.mean() for k in keep])
        noise = np.mean([(factors[k] * sd) ** 2 / sample[k].n_leaves for k in keep])
        return means.std(ddof=1), noise
    got, noise = between(ts, f)
    want = math.sqrt(mu ** 2 * f.var(ddof=1) + noise)
    assert got == pytest.approx(want, rel=0.15)     # SD of 400 trees: relative SE ≈ 4 %
    got0, noise0 = between(trees, np.ones(len(trees)))
    assert got0 == pytest.approx(math.sqrt(noise0), rel=0.2) and got > 2 * got0
    # leaves per branch: floor(f·k + U), mean f·k per branch
    f = np.array([t.draws.globals["leaves_per_branch_tree_factor"] for t in ts])
    drawn = np.array([t.draws.locals["leaves_per_branch"].sum() for t in ts])
    nb = np.array([len(t.draws.locals["leaves_per_branch"]) for t in ts])
    n = np.array([t.n_leaves for t in ts])
    assert (n >= np.floor(f * drawn) - nb).all() and (n <= f * drawn + nb).all()
    assert abs((n - f * drawn).sum()) < 4 * math.sqrt(0.25 * nb.sum())
    # daughters: a tree whose factor is high grows more branches than its growth level's mean
    f = np.array([t.draws.globals["n_daughters_tree_factor"] for t in ts])
    G = np.array([t.draws.globals["growth_level"] for t in ts])
    nbr = np.log([len(t.branches) for t in ts])
    z = np.concatenate([(nbr[G == g] - nbr[G == g].mean()) for g in np.unique(G)])
    fz = np.concatenate([f[G == g] for g in np.unique(G)])
    assert stats.spearmanr(fz, z)[0] > 0.2


def test_tree_means_keep_bytes_and_independence(spread_trees):
    P, ts = spread_trees
    again = random_tree(P, seed=5, tree_id=5, keep_draws=True)
    assert again.leaves.vertices.tobytes() == ts[5].leaves.vertices.tobytes()
    assert again.branches.p1.tobytes() == ts[5].branches.p1.tobytes()
    # a spread of 0 draws no factor: the tree is the species-law tree, bit for bit
    flat = dataclasses.replace(P, **{k: 0.0 for k in SPREAD})
    base = random_tree(TEST_PARAMS, seed=5)
    assert random_tree(flat, seed=5).leaves.vertices.tobytes() == base.leaves.vertices.tobytes()


@pytest.mark.parametrize("name, value", [("leaf_length_tree_cv", 0.31), ("n_daughters_tree_cv", -0.1),
                                         ("leaves_per_branch_tree_cv", float("nan"))])
def test_bad_tree_spread_is_refused(name, value):
    with pytest.raises(ConfigError) as e:
        tree_params_from_dict({name: value}, TEST_PARAMS, "species[0].tree.")
    assert e.value.key == f"species[0].tree.{name}"
