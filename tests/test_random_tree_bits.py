"""The fast paths of random-tree growth give the bits of the plain numpy forms they replace.

Growth writes cross products out, works on (3, n) columns, notes the crown's leaf radius while
the leaves are made and caches the laws' inverse-CDF constants; the same seed must still give
the same bytes as the straightforward formulas (np.cross, np.linalg.norm, np.stack).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.special import ndtr, ndtri

from simlidar_mi.plants.laws import Discrete, TruncNormal
from simlidar_mi.errors import ConfigError
from simlidar_mi.plants.random_tree import _bend, _len, iter_random_trees, random_tree
from simlidar_mi.plants.tree_leaves import (
    _Z, _cross, _cross_t, _ellipse_fan_t, _make_leaves, _norm_t, _rotate, _rotate_t, ellipse_fan)
from simlidar_mi.plants.tree_params import SPECIES_PRESETS, leaf_polygon_area_factor


def _vectors(n: int, seed: int) -> np.ndarray:
    """Rows of mixed magnitudes, signed zeros and exact axes: where bit differences would show."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-6, 6, size=(n, 3))
    v[::7, 0] = -0.0
    v[::11, 1] = 0.0
    v[::13] = [0.0, 0.0, 1.0]
    v[::17] = [-0.0, 0.0, -1.0]
    return v


def _same(a, b) -> bool:
    """Equal bits (so -0.0 ≠ 0.0), same shape."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_cross_products_and_norms_are_numpys_bits():
    a, b = _vectors(500, 1), _vectors(500, 2)
    assert _same(_cross(a, b), np.cross(a, b))
    assert _same(_cross(a, _Z), np.cross(a, _Z))
    assert _same(_cross_t(a.T, b.T), np.cross(a, b).T)
    assert _same(_cross_t(a.T, _Z[:, None]), np.cross(a, _Z).T)
    assert _same(_norm_t(a.T), np.linalg.norm(a, axis=1))
    assert _same(_len(a), np.linalg.norm(a, axis=1, keepdims=True))


def test_rotations_in_rows_and_columns_agree_with_rodrigues():
    rng = np.random.default_rng(3)
    v, axis = _vectors(300, 4), _vectors(300, 5)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ang = rng.uniform(-7, 7, 300)
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    ref = v * c + np.cross(axis, v) * s + axis * (axis * v).sum(1, keepdims=True) * (1 - c)
    assert _same(_rotate(v, axis, ang), ref)
    assert _same(_rotate_t(v.T, axis.T, ang), ref.T)
    # a quarter turn about z takes x to y (right-handed)
    np.testing.assert_allclose(_rotate(np.array([[1.0, 0, 0]]), np.array([[0, 0, 1.0]]),
                                       np.array([np.pi / 2])), [[0, 1, 0]], atol=1e-15)


def test_bend_keeps_unit_orthogonal_frames_and_its_fallback():
    H = _vectors(200, 6)
    H /= np.linalg.norm(H, axis=1, keepdims=True)
    U = np.cross(H, [0.3, -0.2, 0.9])
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    vertical = (H[:, 0] == 0) & (H[:, 1] == 0)
    U[vertical] = [0.0, 0.0, 1.0]            # U ∥ H after the bend: the fallback ⟂ vector is used
    assert vertical.sum() >= 10
    H2, U2 = _bend(H, U, 0.4)
    # H2 = ±ẑ: the fallback is H2 × x̂ = ±ŷ
    np.testing.assert_array_equal(np.abs(U2[vertical]), [[0.0, 1.0, 0.0]] * int(vertical.sum()))
    np.testing.assert_allclose(np.linalg.norm(H2, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(U2, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose((H2 * U2).sum(1), 0, atol=1e-12)
    # headings move toward +z by the tropism weight, then are normalised
    ok = np.linalg.norm(H + 0.4 * _Z, axis=1) > 1e-6
    ref = (H + 0.4 * _Z) / np.linalg.norm(H + 0.4 * _Z, axis=1, keepdims=True)
    assert _same(H2[ok], ref[ok])


def test_ellipse_fan_from_columns_is_the_row_fan():
    rng = np.random.default_rng(7)
    n, k = 1300, 7                            # more leaves than one write block
    c, h, s = _vectors(n, 8), _vectors(n, 9), _vectors(n, 10)
    hl, hw = rng.random(n), rng.random(n)
    tri, ring = _ellipse_fan_t(c.T, h.T, s.T, hl, hw, k)
    ref = ellipse_fan(c, h, s, hl[:, None, None], hw[:, None, None], k)
    assert _same(tri, ref)
    assert ring.shape == (3, k + 1, n)


def _reference_leaves(P, b0, b1, br, H, U, tpos, phi, lang, ll, lw, roll):
    """The leaf formulas in row form with numpy's own cross, norm and stack."""
    u = _rotate(U, H, phi)
    head = np.cos(lang)[:, None] * H + np.sin(lang)[:, None] * u
    base = b0 + tpos[:, None] * (b1 - b0) + br[:, None] * u
    side = np.cross(head, _Z)
    sn = np.linalg.norm(side, axis=1, keepdims=True)
    fb = np.cross(head, u)
    with np.errstate(invalid="ignore", divide="ignore"):
        fb = fb / np.linalg.norm(fb, axis=1, keepdims=True)
    side = np.where(sn > 1e-6, side / np.maximum(sn, 1e-300), fb)
    up = np.cross(side, head)
    side_r = np.cos(roll)[:, None] * side + np.sin(roll)[:, None] * up
    normal = np.cross(side_r, head)
    centre = base + 0.5 * ll[:, None] * head
    if P.leaf_shape == "rhombus":
        tip = base + ll[:, None] * head
        right = centre + 0.5 * lw[:, None] * side_r
        left = centre - 0.5 * lw[:, None] * side_r
        tri = np.stack([np.stack([base, right, tip], 1), np.stack([base, tip, left], 1)], 1)
    else:
        tri = ellipse_fan(centre, head, side_r, 0.5 * ll[:, None, None], 0.5 * lw[:, None, None],
                          P.leaf_sides)
    return tri, centre, normal, head


@pytest.mark.parametrize("shape", ["rhombus", "ellipse"])
def test_leaves_from_columns_are_the_row_formulas(shape):
    P = dataclasses.replace(SPECIES_PRESETS["broadleaf-monopodial"], leaf_shape=shape, leaf_sides=5)
    rng = np.random.default_rng(11)
    nb, n = 60, 1500
    p0, p1, r = rng.normal(size=(nb, 3)), rng.normal(size=(nb, 3)), rng.random(nb)
    H = _vectors(nb, 12)
    H /= np.linalg.norm(H, axis=1, keepdims=True)
    H[:4] = [0.0, 0.0, 1.0]                   # vertical branches: some vertical leaves
    U = np.cross(H, [0.6, 0.0, 0.8])
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    owner = np.sort(rng.integers(0, nb, n))
    tpos, phi, roll = rng.random(n), rng.uniform(0, 2 * np.pi, n), rng.normal(0, 0.3, n)
    lang = np.where(np.arange(n) % 9 == 0, 0.0, rng.uniform(0, 1.5, n))  # 0: leaf along a branch
    ll, lw = rng.uniform(0.02, 0.1, n), rng.uniform(0.01, 0.05, n)
    leaves, table, xy2 = _make_leaves(P, p0, p1, r, H, U, owner, tpos, phi, lang, ll, lw, roll, 5)
    tri, centre, normal, head = _reference_leaves(P, p0[owner], p1[owner], r[owner], H[owner],
                                                  U[owner], tpos, phi, lang, ll, lw, roll)
    assert _same(leaves.vertices, tri.reshape(-1, 3, 3))
    assert _same(table.centre_m, centre) and _same(table.normal, normal)
    assert _same(table.heading, head)
    assert _same(table.area_m2, leaf_polygon_area_factor(shape, 5) * ll * lw)
    assert (leaves.plant_id == 5).all() and (table.tree_id == 5).all()
    v = leaves.vertices.reshape(-1, 3)
    assert xy2 == (v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]).max()


@pytest.mark.parametrize("name", list(SPECIES_PRESETS))
def test_noted_crown_radius_is_the_scanned_one(name):
    for seed in (3, 4):
        t = random_tree(SPECIES_PRESETS[name], seed)
        assert t.leaf_xy2_max_m2 is not None
        scanned = dataclasses.replace(t, leaf_xy2_max_m2=None)
        assert t.crown_radius_m == scanned.crown_radius_m
        pts = np.concatenate([t.branches.p0, t.branches.p1, t.leaves.vertices.reshape(-1, 3)])
        assert t.crown_radius_m == pytest.approx(np.hypot(pts[:, 0], pts[:, 1]).max(), rel=1e-15)
        # wood scaling moves the leaves: the radius is scanned again, not carried over
        w = t.wood_scaled(1.5)
        assert w.leaf_xy2_max_m2 is None and w.crown_radius_m > t.crown_radius_m


@pytest.mark.parametrize("law", [TruncNormal(1.0, 2.0, -0.5, 4.0), TruncNormal(0.0, 1.0, 2.5, 6.0),
                                 TruncNormal(3.0, 0.5)])
def test_cached_truncated_normal_draws_are_the_direct_inverse_cdf(law):
    def direct(rng, size):
        u = rng.random(size)
        a, b = law._std_bounds()
        if a > 0:
            pa, pb = ndtr(-b), ndtr(-a)
            x = -ndtri(pa + u * (pb - pa))
        else:
            pa, pb = ndtr(a), ndtr(b)
            x = ndtri(pa + u * (pb - pa))
        return np.clip(law.mean + law.sd * x, law.lo, law.hi)
    for size in (None, 1, 1000):
        assert _same(law.sample(np.random.default_rng(9), size), direct(np.random.default_rng(9), size))


def test_cached_discrete_draws_are_the_direct_inverse_cdf():
    law = Discrete((2, 3, 5), (0.2, 0.5, 0.3))
    u = np.random.default_rng(2).random(1000)
    cdf = np.cumsum(law.probs)
    ref = np.asarray(law.values)[np.minimum(np.searchsorted(cdf / cdf[-1], u, side="right"), 2)]
    assert _same(law.sample(np.random.default_rng(2), 1000), ref)
    assert set(np.unique(ref)) == {2, 3, 5}


def _tree_bytes(t) -> bytes:
    b, lv, lt = t.branches, t.leaves, t.leaf_table
    arrays = [b.p0, b.p1, b.diameter, b.order, b.tree_id, lv.vertices, lv.leaf_id, lv.plant_id,
              *(getattr(lt, f.name) for f in dataclasses.fields(lt))]
    if t.draws is not None:
        arrays += [t.draws.locals[k] for k in sorted(t.draws.locals)]
    return b"".join(np.ascontiguousarray(a).tobytes() for a in arrays) + repr(
        (t.seed, t.branching, t.crown_radius_m, sorted(t.draws.globals.items()) if t.draws else None)).encode()


@pytest.mark.parametrize("name,per", [("deciduous-apex", "tree"), ("conifer-whorl", "branch"),
                                      ("small-tree", "tree")])
def test_trees_grown_together_are_the_trees_grown_alone(name, per):
    P = dataclasses.replace(SPECIES_PRESETS[name], lateral_branching_per=per)
    seeds = [11, 5, 2021, 0, 987654321]
    together = list(iter_random_trees(P, seeds, [7, 8, 9, 10, 11], keep_draws=True))
    alone = [random_tree(P, s, tree_id=k, keep_draws=True) for s, k in zip(seeds, [7, 8, 9, 10, 11])]
    assert [_tree_bytes(t) for t in together] == [_tree_bytes(t) for t in alone]
    # the trees differ from each other (the lock step does not share draws)
    assert len({len(t.branches) for t in alone}) > 1


def test_trees_grown_together_name_the_first_tree_that_grows_too_many():
    P = SPECIES_PRESETS["small-tree"]
    sizes = [len(random_tree(P, s).branches) for s in range(12)]
    cap = sizes[0]                       # tree 0 fits; the first larger tree does not
    first = next(k for k, n in enumerate(sizes) if n > cap)
    assert first > 0
    Pc = dataclasses.replace(P, max_branches=cap)
    with pytest.raises(ConfigError, match=f"tree {first} grows more than {cap}"):
        random_tree(Pc, first, tree_id=first)
    with pytest.raises(ConfigError, match=f"tree {first} grows more than {cap}"):
        list(iter_random_trees(Pc, range(12)))


def test_leaves_made_in_blocks_are_the_leaves_made_at_once(monkeypatch):
    """_make_leaves works _LEAF_BLOCK leaves at a time: blocks of 7 give the bits of one pass."""
    import simlidar_mi.plants.tree_leaves as tl  # noqa: PLC0415
    for name, shape in (("deciduous-apex", "rhombus"), ("conifer-whorl", "ellipse")):
        P = dataclasses.replace(SPECIES_PRESETS[name], leaf_shape=shape)
        one = random_tree(P, 3)
        monkeypatch.setattr(tl, "_LEAF_BLOCK", 7)
        blocks = random_tree(P, 3)
        monkeypatch.undo()
        assert len(one.leaf_table) > 7 * 10
        assert _tree_bytes(one) == _tree_bytes(blocks)
        assert one.leaf_xy2_max_m2 == blocks.leaf_xy2_max_m2


def test_trees_finished_on_two_threads_are_the_trees_finished_in_turn(monkeypatch):
    from simlidar_mi._runtime import threads  # noqa: PLC0415
    P = SPECIES_PRESETS["deciduous-apex"]
    seeds = [4, 40, 400, 4000, 7]
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    two = [_tree_bytes(t) for t in iter_random_trees(P, seeds)]
    monkeypatch.setattr(threads, "usable_cores", lambda: 1)
    assert two == [_tree_bytes(t) for t in iter_random_trees(P, seeds)]
    assert list(threads.ordered_map(lambda x: x * x, range(9), 2)) == [x * x for x in range(9)]
    with pytest.raises(ZeroDivisionError):
        list(threads.ordered_map(lambda x: 1 // (x - 5), range(9), 2))
