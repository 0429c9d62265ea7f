"""SIMLIDAR apple trees and orchards: laws, seeds, validation, guard, CLI."""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.cli import main
from simlidar_mi.errors import ConfigError, DerivationTooLarge
from simlidar_mi.plants.apple import (AppleTreeParams, apple_derivation_string, apple_grammar,
                                      apple_tree, orchard)

# Méndez et al., Table 1, 2 generations (also in test_lsystem.py).
PAPER_TABLE1_N2 = (
    "[I01I01[t+I01I01+I02I02[t+I02I02+F]I02[T-I02F]I02F]I01[T-I01I02I02[t+I02I02+F]"
    "I02[T-I02F]I02F]I01I02I02[t+I02I02+F]I02[T-I02F]I02F]")


def _same(a, b) -> bool:
    return all(getattr(a, f).tobytes() == getattr(b, f).tobytes()
               for f in ("p0", "p1", "diameter", "order", "tree_id"))


# --- laws -------------------------------------------------------------------------
@pytest.mark.parametrize("stochastic", [False, True])
def test_length_and_diameter_laws_per_order(stochastic):
    n, h0, dm = 6, 0.4, 0.006
    p = AppleTreeParams(n, h0_m=h0, d_min_m=dm, stochastic=stochastic)
    t = apple_tree(p, np.random.default_rng(7))
    assert set(np.unique(t.order)) == set(range(1, n + 1))
    for o in range(1, n + 1):
        sel = t.order == o
        np.testing.assert_allclose(t.length[sel], h0 / 2 ** (o - 1), rtol=1e-12)  # h_n
        np.testing.assert_allclose(t.diameter[sel], n * dm / o, rtol=1e-15)      # d_n
    assert t.diameter.min() == pytest.approx(dm)        # d_m at the highest order


def test_deterministic_tree_counts_and_height():
    for n in range(1, 7):
        t = apple_tree(AppleTreeParams(n, h0_m=0.5))
        # 7 I modules per rewrite, 3**(g-1) rewrites in generation g
        assert len(t) == 7 * (3 ** n - 1) // 2
        for o in range(1, n + 1):
            assert np.count_nonzero(t.order == o) == 7 * 3 ** (o - 1)
        # the main axis is vertical, 4 elements a generation
        assert t.p1[:, 2].max() == pytest.approx(4 * 0.5 * (2 - 2.0 ** (1 - n)))
        np.testing.assert_array_equal(t.p0[0], [0, 0, 0])


def _parents_by_end_points(br) -> np.ndarray:
    """Parent of each segment found geometrically, independent of the turtle: the
    segment of the same tree whose end is exactly this one's start (-1: none)."""
    ends = {}
    for i, (k, p) in enumerate(zip(br.tree_id, br.p1)):
        ends.setdefault((int(k), p.tobytes()), i)
    return np.array([ends.get((int(k), p.tobytes()), -1)
                     for k, p in zip(br.tree_id, br.p0)], np.int64)


def _floating(br, bases) -> int:
    """Segments neither at their tree's base nor starting where a kept segment ends.
    Asserts one trunk base per tree."""
    parent = _parents_by_end_points(br)
    at_base = (br.p0 == np.asarray(bases, np.float64)[br.tree_id]).all(axis=1)
    for k in range(len(bases)):
        assert np.count_nonzero(at_base & (br.tree_id == k)) == 1   # the trunk base
    return int(np.count_nonzero((parent < 0) & ~at_base))


def test_pruning_removes_descending_segments_with_everything_growing_from_them():
    full = apple_tree(AppleTreeParams(6))
    descending = full.p1[:, 2] < full.p0[:, 2]
    # reference: walk the geometric parents in string order (parents come first)
    parent = _parents_by_end_points(full)
    assert (parent < np.arange(len(full))).all() and np.count_nonzero(parent < 0) == 1
    cut = descending.copy()
    for i, p in enumerate(parent):
        cut[i] |= p >= 0 and cut[p]
    pruned = apple_tree(AppleTreeParams(6, pruning=True))
    np.testing.assert_array_equal(pruned.p0, full.p0[~cut])
    np.testing.assert_array_equal(pruned.p1, full.p1[~cut])
    # 6 deterministic iterations: 2548 segments, 450 descend, 62 more grow from them
    assert (len(full), descending.sum(), cut.sum() - descending.sum()) == (2548, 450, 62)
    assert len(pruned) == 2036
    assert (pruned.p1[:, 2] >= pruned.p0[:, 2]).all()


def test_segment_pruning_drops_descending_segments_only_and_leaves_wood_floating():
    full = apple_tree(AppleTreeParams(6))
    descending = full.p1[:, 2] < full.p0[:, 2]
    seg = apple_tree(AppleTreeParams(6, pruning=True, pruning_mode="segment"))
    assert len(seg) == len(full) - descending.sum() == 2098
    np.testing.assert_array_equal(seg.p0, full.p0[~descending])
    assert (seg.p1[:, 2] >= seg.p0[:, 2]).all()
    assert _floating(seg, [(0, 0, 0)]) == 30     # children of descending segments, in mid-air
    assert _floating(apple_tree(AppleTreeParams(6, pruning=True)), [(0, 0, 0)]) == 0


@pytest.mark.parametrize("iterations", [4, 5, 6, 7])
@pytest.mark.parametrize("stochastic, seed", [(False, 0), (True, 1), (True, 2), (True, 3)])
def test_every_pruned_segment_is_connected_to_its_trunk_base(iterations, stochastic, seed):
    # Every segment is the trunk base or starts exactly where a kept segment ends, so by
    # induction in string order every kept segment hangs from its tree's trunk base.
    p = AppleTreeParams(iterations, stochastic=stochastic, pruning=True)
    bases = [(2.5, 0.75 + 2.0 * k, 0.0) for k in range(2)]
    trees = orchard(p, 2, 2.0, row_x_m=2.5, y_start_m=0.75, seed=seed)
    assert _floating(trees, bases) == 0
    full = orchard(AppleTreeParams(iterations, stochastic=stochastic), 2, 2.0,
                   row_x_m=2.5, y_start_m=0.75, seed=seed)
    assert len(trees) < len(full)               # pruning did remove wood


# --- seeds ------------------------------------------------------------------------
def test_same_seed_same_bytes():
    p = AppleTreeParams(6, stochastic=True, pruning=True)
    a = orchard(p, 3, 2.0, row_x_m=1.5, y_start_m=-1.0, seed=42)
    b = orchard(p, 3, 2.0, row_x_m=1.5, y_start_m=-1.0, seed=42)
    c = orchard(p, 3, 2.0, row_x_m=1.5, y_start_m=-1.0, seed=43)
    assert _same(a, b)
    assert not _same(a, c)


def test_adding_a_tree_keeps_the_others_and_children_come_from_spawn():
    p = AppleTreeParams(5, stochastic=True)
    two = orchard(p, 2, 2.5, row_x_m=3.0, y_start_m=1.0, seed=9)
    three = orchard(p, 3, 2.5, row_x_m=3.0, y_start_m=1.0, seed=9)
    assert _same(two, three.subset(three.tree_id < 2))
    children = np.random.SeedSequence(9).spawn(3)
    for k in range(3):
        tree = apple_tree(p, np.random.default_rng(children[k]), tree_id=k,
                          base_m=(3.0, 1.0 + 2.5 * k, 0.0))
        assert _same(tree, three.subset(three.tree_id == k))


def test_stochastic_trees_differ_deterministic_trees_are_copies():
    sto = orchard(AppleTreeParams(5, stochastic=True), 4, 2.0, seed=1)
    counts = [np.count_nonzero(sto.tree_id == k) for k in range(4)]
    assert len(set(counts)) > 1
    det = orchard(AppleTreeParams(4), 3, 2.0, row_x_m=1.0, y_start_m=0.5)
    t0 = det.subset(det.tree_id == 0)
    for k in range(3):
        tk = det.subset(det.tree_id == k)
        np.testing.assert_allclose(tk.p0 - t0.p0, np.tile([0, 2.0 * k, 0], (len(t0), 1)),
                                   atol=1e-12)
        np.testing.assert_array_equal(tk.p0[0], [1.0, 0.5 + 2.0 * k, 0.0])   # tree base


def test_stochastic_tree_needs_a_generator():
    with pytest.raises(ConfigError, match="rng"):
        apple_tree(AppleTreeParams(3, stochastic=True))


# --- guard ------------------------------------------------------------------------
def test_guard_refuses_twenty_accepts_seven_stochastic():
    with pytest.raises(DerivationTooLarge, match="50,000,000"):
        apple_tree(AppleTreeParams(20))
    with pytest.raises(DerivationTooLarge, match="8,063,085,270,351"):
        apple_tree(AppleTreeParams(20, stochastic=True), np.random.default_rng(0))
    t = apple_tree(AppleTreeParams(7, stochastic=True), np.random.default_rng(0))
    assert len(t) > 7 * (3 ** 7 - 1) // 2 / 2
    with pytest.raises(DerivationTooLarge, match="max_modules=1,000"):
        apple_tree(AppleTreeParams(7, max_modules=1000))


# --- validation -------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, key", [
    (dict(iterations=0), "iterations"),
    (dict(iterations=2.5), "iterations"),
    (dict(iterations=True), "iterations"),
    (dict(iterations=4, d_min_m=float("nan")), "d_min_m"),
    (dict(iterations=4, d_min_m=0.0), "d_min_m"),
    (dict(iterations=4, h0_m=-0.5), "h0_m"),
    (dict(iterations=4, h0_m=float("inf")), "h0_m"),
    (dict(iterations=4, angle_deg=float("nan")), "angle_deg"),
    (dict(iterations=4, rotation_deg="x"), "rotation_deg"),
    (dict(iterations=4, pruning="yes"), "pruning"),
    (dict(iterations=4, stochastic=1), "stochastic"),
    (dict(iterations=4, pruning_mode="branch"), "pruning_mode"),
    (dict(iterations=4, pruning_mode=True), "pruning_mode"),
    (dict(iterations=4, max_modules=0), "max_modules"),
])
def test_params_validation_names_key_and_value(kwargs, key):
    with pytest.raises(ConfigError) as ei:
        AppleTreeParams(**kwargs)
    assert ei.value.key == key
    assert f"'{key}'" in str(ei.value) and repr(kwargs[key]) in str(ei.value)


@pytest.mark.parametrize("kwargs, key", [
    (dict(n_trees=0, spacing_m=2.0), "n_trees"),
    (dict(n_trees=2, spacing_m=0.0), "spacing_m"),
    (dict(n_trees=2, spacing_m=2.0, row_x_m=math.nan), "row_x_m"),
    (dict(n_trees=2, spacing_m=2.0, seed=-1), "seed"),
])
def test_orchard_validation(kwargs, key):
    with pytest.raises(ConfigError) as ei:
        orchard(AppleTreeParams(3), **kwargs)
    assert ei.value.key == key


def test_params_keep_defaults_of_the_paper():
    p = AppleTreeParams(5)
    assert (p.angle_deg, p.rotation_deg, p.d_min_m) == (20.0, 20.0, 0.005)
    assert isinstance(p.iterations, int)
    g = apple_grammar(True)
    assert [s.probability for s in g.production_for("F").successors] == [0.33, 0.33, 0.34]


# --- CLI --------------------------------------------------------------------------
def test_cli_derive_prints_table1(capsys):
    assert main(["derive", "--generations", "2"]) == 0
    assert capsys.readouterr().out.strip() == PAPER_TABLE1_N2


def test_cli_derive_stochastic_is_seeded(capsys):
    assert main(["derive", "--generations", "3", "--stochastic", "--seed", "5"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == apple_derivation_string(3, stochastic=True, seed=5)
    assert out.startswith("[I01") and out.endswith("]") and "I03" in out
    assert main(["derive", "-n", "3", "--stochastic", "--seed", "6"]) == 0
    assert capsys.readouterr().out.strip() != out


def test_cli_derive_refuses_huge(capsys):
    # --generations is bounded to [1, 12] by its option type (one line, exit 2); the module
    # budget (max_modules) still guards the derivation itself
    with pytest.raises(SystemExit) as exc:
        main(["derive", "--generations", "20"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--generations" in err and "≤ 12" in err and len(err.splitlines()) == 1


# --- scene files ------------------------------------------------------------------
def test_scene_pruning_mode_reaches_the_trees_and_bad_values_are_refused(tmp_path):
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.survey import generate
    from tests.conftest import SCENES
    scene = SCENES / "apple_orchard.toml"
    base = ["orchard.n_trees=1", "orchard.tree.iterations=6", "orchard.tree.stochastic=false"]
    default = generate(load_scene(scene, base)).branches
    seg = generate(load_scene(scene, base + ['orchard.tree.pruning_mode="segment"'])).branches
    assert (len(default), len(seg)) == (2036, 2098)       # as in the tests above
    bad = tmp_path / "bad.toml"
    bad.write_text('[orchard.tree]\npruning = true\npruning_mode = "branch"\n')
    with pytest.raises(ConfigError) as ei:
        load_scene(bad)
    msg = str(ei.value)
    assert str(bad) in msg and "orchard.tree.pruning_mode" in msg and "branch" in msg
    assert "subtree" in msg and "segment" in msg
