"""Named L-system presets: Honda/ABOP closed forms, determinism, forest species, CLI."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simlidar_mi.cli import main
from simlidar_mi.errors import ConfigError, DerivationTooLarge
from simlidar_mi.lsystem import TurtleConfig, derive, interpret_abop, parse_grammar
from simlidar_mi.plants.presets import (FOREST_SPECIES, HONDA_TABLE_2_1, get_preset,
                                         preset_geometry, preset_grammar, preset_measures,
                                         preset_names, preset_word)
from simlidar_mi.plants.apple import AppleTreeParams, apple_tree

REQUIRED = ("simlidar-apple", "simlidar-apple-stochastic", "honda-a", "honda-b", "honda-c",
            "honda-d", "sympodial", "ternary")


def _same(a, b) -> bool:
    fields = ("p0", "p1", "diameter", "order", "tree_id")
    return (all(getattr(a.branches, f).tobytes() == getattr(b.branches, f).tobytes()
                for f in fields)
            and a.leaves.vertices.tobytes() == b.leaves.vertices.tobytes())


def test_registry_holds_the_required_presets_and_forest_species():
    names = preset_names()
    assert set(REQUIRED) <= set(names)
    assert len(FOREST_SPECIES) >= 4 and set(FOREST_SPECIES) <= set(names)
    for name in names:
        p = get_preset(name)
        assert p.source and p.units and p.turtle in ("abop", "simlidar")
    with pytest.raises(ConfigError, match="honda-a"):
        get_preset("honda-z")


# --- Honda's monopodial trees (ABOP Fig. 2.6, Table 2.1) --------------------------
@pytest.mark.parametrize("key", ["a", "b", "c", "d"])
def test_honda_closed_forms(key):
    r1, r2, a0, a2 = HONDA_TABLE_2_1[key]
    n = 10
    p = get_preset(f"honda-{key}")
    assert preset_grammar(p.name).constants["r2"] == r2
    assert preset_grammar(p.name).constants["a2"] == a2
    geo = preset_geometry(p.name)
    b = geo.branches
    ls, ws = p.turtle_config.length_scale_m, p.turtle_config.width_scale_m
    # every A/B/C writes one F and, before the last generation, two children of
    # lengths l·r1 and l·r2: 2^k modules in generation k, lengths summing to (r1+r2)^k
    assert len(b) == 2 ** n - 1
    assert b.length.sum() == pytest.approx(ls * sum((r1 + r2) ** k for k in range(n)),
                                           rel=1e-12)
    # the trunk (order 1) is A's own F, continued straight up (a roll keeps H)
    trunk = b.subset(b.order == 1)
    assert len(trunk) == n
    np.testing.assert_allclose(trunk.p1[:, :2], 0, atol=1e-12)
    assert trunk.p1[:, 2].max() == pytest.approx(ls * sum(r1 ** k for k in range(n)),
                                                 rel=1e-12)
    np.testing.assert_allclose(trunk.length, ls * r1 ** np.arange(n), rtol=1e-12)
    # widths: 10·wr^k in generation k; the thinnest in the last
    wr = preset_grammar(p.name).constants["wr"]
    assert b.diameter.min() == pytest.approx(ws * 10 * wr ** (n - 1), rel=1e-12)
    assert b.diameter.max() == pytest.approx(ws * 10, rel=1e-12)
    m = preset_measures(p.name)
    assert m["n_segments"] == 2 ** n - 1 and m["n_leaves"] == 0 and m["leaf_area"] == 0
    assert m["height"] >= trunk.p1[:, 2].max() - 1e-12


def test_honda_constants_override_and_generations():
    # set a with r2 = 0.9 is set b
    assert _same(preset_geometry("honda-a", constants={"r2": 0.9}),
                 preset_geometry("honda-b"))
    assert len(preset_geometry("honda-c", generations=4).branches) == 2 ** 4 - 1
    with pytest.raises(ConfigError, match="generations"):
        preset_geometry("honda-a", generations=-1)
    with pytest.raises(DerivationTooLarge):
        preset_geometry("honda-a", generations=40)


def test_sympodial_and_ternary_closed_forms():
    n = 10
    c = preset_grammar("sympodial").constants
    b = preset_geometry("sympodial").branches
    assert len(b) == 2 ** n - 1
    assert b.length.sum() == pytest.approx(sum((c["r1"] + c["r2"]) ** k for k in range(n)),
                                           rel=1e-12)
    assert b.diameter.min() == pytest.approx(0.01 * 10 * c["wr"] ** (n - 1), rel=1e-12)
    # ternary: the axiom's F plus 4 F per A, 3^(g-1) A rewritten in generation g; every
    # F(l) grows by lr a generation and every width by vr
    n, c = 6, preset_grammar("ternary").constants
    t = get_preset("ternary")
    b = preset_geometry("ternary").branches
    assert len(b) == 1 + 4 * (3 ** n - 1) // 2
    lr, vr, s = c["lr"], c["vr"], t.turtle_config.length_scale_m
    total = 200 * lr ** n + sum(4 * 3 ** (g - 1) * 50 * lr ** (n - g) for g in range(1, n + 1))
    assert b.length.sum() == pytest.approx(s * total, rel=1e-12)
    assert b.diameter.max() == pytest.approx(0.01 * vr ** n, rel=1e-12)
    assert t.turtle_config.elasticity == 0.22
    # tropism (T pointing down) bends the ternary tree: without it, the same word
    # stands taller; lengths do not change
    straight = interpret_abop(preset_word("ternary"),
                              TurtleConfig(length_scale_m=0.01, width_scale_m=0.01)).branches
    assert b.p1[:, 2].mean() < straight.p1[:, 2].mean() - 0.3
    np.testing.assert_allclose(b.length, straight.length, rtol=1e-12)


# --- ABOP's stochastic example (Fig. 1.27) ---------------------------------------
def test_abop_stochastic_mean_and_variance_pin_the_per_module_choice():
    g = parse_grammar("alphabet: F + -\naxiom: F\n"
                      "F -> (0.33) F[+F]F[-F]F | (0.33) F[+F]F | (0.34) F[-F]F\n")
    n, seeds = 5, 1500
    counts = np.array([derive(g, n, np.random.default_rng(s)).count("F")
                       for s in range(seeds)])
    assert counts.min() >= 3 ** n and counts.max() <= 5 ** n
    # offspring of one F: 5 with p = 0.33, 3 with p = 0.67
    m = 0.33 * 5 + 0.33 * 3 + 0.34 * 3
    s2 = 0.33 * 25 + 0.67 * 9 - m * m
    mean = m ** n
    # independent choices per module: a Galton-Watson process
    var_module = s2 * m ** (n - 1) * (m ** n - 1) / (m - 1)
    # one choice per generation for all modules would give the same mean, but
    var_generation = (0.33 * 25 + 0.67 * 9) ** n - m ** (2 * n)
    assert abs(counts.mean() - mean) < 4 * math.sqrt(var_module / seeds)
    assert counts.var(ddof=1) == pytest.approx(var_module, rel=0.2)
    assert var_generation > 3 * var_module


# --- every preset ------------------------------------------------------------------
@pytest.mark.parametrize("name", preset_names())
def test_every_preset_derives_and_is_deterministic(name):
    gens = min(get_preset(name).generations or preset_grammar(name).derivation_length, 6)
    a = preset_geometry(name, generations=gens, seed=11)
    b = preset_geometry(name, generations=gens, seed=11)
    assert len(a.branches) > 0 and _same(a, b)
    assert np.isfinite(a.branches.p1).all() and (a.branches.diameter > 0).all()
    if preset_grammar(name).stochastic:
        c = preset_geometry(name, generations=gens, seed=12)
        assert not _same(a, c)
    m = preset_measures(name, generations=gens, seed=11)
    assert m["n_segments"] == len(a.branches)
    for key in ("total_length", "height", "min_width", "V_L_m3", "A_L_m2", "A_PR_m2"):
        assert math.isfinite(m[key]) and m[key] > 0


@pytest.mark.parametrize("stochastic", [False, True])
def test_simlidar_presets_are_the_apple_trees(stochastic):
    name = "simlidar-apple-stochastic" if stochastic else "simlidar-apple"
    geo = preset_geometry(name, generations=5, seed=3)
    tree = apple_tree(AppleTreeParams(5, stochastic=stochastic),
                      np.random.default_rng(3) if stochastic else None)
    for f in ("p0", "p1", "diameter", "order"):
        assert getattr(geo.branches, f).tobytes() == getattr(tree, f).tobytes()
    assert len(geo.leaves) == 0


@pytest.mark.parametrize("name", FOREST_SPECIES)
def test_forest_species_have_leaves_and_realistic_sizes(name):
    geo = preset_geometry(name, seed=5, tree_id=7, origin_m=(10.0, -3.0, 0.0))
    b, lv, t = geo.branches, geo.leaves, geo.leaf_table
    m = preset_measures(name, seed=5)
    assert 3.0 <= m["height"] <= 30.0                           # metres
    assert 0.03 <= b.diameter.max() <= 0.6                      # trunk: centimetres
    assert 0.001 <= b.diameter.min() <= 0.02                    # twigs: millimetres
    assert len(t) >= 1000 and m["n_leaves"] == len(t)
    assert (t.area_m2 > 0).all() and m["leaf_area"] == pytest.approx(t.area_m2.sum())
    assert 0.02 <= t.length_m.min() and t.length_m.max() <= 0.2   # a few centimetres
    assert (t.width_m <= t.length_m).all()
    np.testing.assert_array_equal(t.tree_id, 7)
    np.testing.assert_array_equal(np.unique(lv.leaf_id), t.leaf_id)
    np.testing.assert_array_equal(b.tree_id, 7)
    assert b.p0[0] == pytest.approx([10.0, -3.0, 0.0])
    # leaf table and triangles agree: centre inside the crown, unit vectors
    np.testing.assert_allclose(np.linalg.norm(t.heading, axis=1), 1, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(t.normal, axis=1), 1, atol=1e-9)
    assert m["leaf_area"] == pytest.approx(lv.triangle_area.sum(), rel=1e-12)
    lo = np.minimum(b.p0.min(0), b.p1.min(0)) - 0.3
    hi = np.maximum(b.p0.max(0), b.p1.max(0)) + 0.3
    assert ((t.centre_m >= lo) & (t.centre_m <= hi)).all()


# --- CLI ---------------------------------------------------------------------------
def test_cli_measure_preset_json(capsys):
    assert main(["measure", "--preset", "honda-b", "--generations", "6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    want = preset_measures("honda-b", 6)
    for key in ("n_segments", "total_length", "height", "min_width", "n_leaves", "leaf_area",
                "V_L_m3", "A_L_m2", "A_PR_m2"):
        assert out[key] == pytest.approx(want[key])
    assert out["n_segments"] == 2 ** 6 - 1 and out["generations"] == 6
    assert out["units"]["height"] == "m"


def test_cli_measure_preset_table_and_errors(capsys):
    assert main(["measure", "--preset", "shrub", "-n", "3", "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert "n_leaves" in out and "leaf_area [m2]" in out
    assert main(["measure", "--preset", "no-such-tree"]) == 2
    assert "choose one of" in capsys.readouterr().err
    assert main(["measure"]) == 2
    assert "--preset" in capsys.readouterr().err
    assert main(["measure", "scene.toml", "--preset", "honda-a"]) == 2
    with pytest.raises(SystemExit) as exc:  # -n is range-checked by its option type (argparse)
        main(["measure", "--preset", "honda-a", "-n", "-2"])
    assert exc.value.code == 2 and "--generations" in capsys.readouterr().err
