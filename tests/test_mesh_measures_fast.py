"""The fast mesh arrays and measures (issue #8, BENCHMARKS §8g) give the bits of their
straightforward formulations: float32 prism vertices written block by block, the hashed
grouping of segment ends (and its exact fallback on a hash collision), the one-sample-at-a-
time swept share, the in-place impacted areas, the uint8 class counts and the sliced
per-tree wood sums."""
from __future__ import annotations

import json

import numpy as np
import pytest

from simlidar_mi.geometry import CLASS_CODES, Branches, Leaves
from simlidar_mi.lidar.scan import ScanResult, ScanSettings
from simlidar_mi.plants.measures import _per_cylinder, _summary, _unit_view, wood_measures
from simlidar_mi.scene import prisms
from simlidar_mi.scene.prisms import exposed_ends, prism_arrays, prism_mesh


def _segments(rng, n):
    p0 = rng.uniform(-3, 3, (n, 3))
    p1 = p0 + rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.5, (n, 1))
    return p0, p1, rng.uniform(0.001, 0.05, n)


@pytest.mark.parametrize("n, k, sides", [(0, 12, True), (1, 12, True), (50, 3, True), (50, 12, True),
                                         (50, 7, False)])
def test_float32_prisms_in_blocks_are_the_rounded_float64_ones(monkeypatch, n, k, sides):
    monkeypatch.setattr(prisms, "PRISM_BLOCK", 7)  # several blocks and a short last one
    rng = np.random.default_rng(n + k)
    p0, p1, r = _segments(rng, n)
    caps = (rng.random(n) < 0.3, rng.random(n) < 0.6)
    for c in (caps, True, False):
        v64, f64, owner = prism_mesh(p0, p1, r, k, caps=c, sides=sides)
        v32, f32, per = prism_arrays(p0, p1, r, k, caps=c, sides=sides, dtype=np.float32)
        assert v32.dtype == np.float32 and f32.dtype == np.uint32 and v32.shape == (2 * k * n, 3)
        assert np.array_equal(v32.view(np.uint32), v64.astype(np.float32).view(np.uint32))
        assert np.array_equal(f32, f64)
        assert np.array_equal(np.repeat(np.arange(n), per), owner) and per.sum() == len(f32)


def _exposed_reference(p0, p1, d, tol_m=1e-7):
    """exposed_ends with np.unique's grouping (the exact, slow one)."""
    n = len(d)
    keys = np.round(np.concatenate([p0, p1]) / tol_m).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    start_d, end_d = np.zeros(n and inv.max() + 1), np.zeros(n and inv.max() + 1)
    np.maximum.at(start_d, inv[:n], d)
    np.maximum.at(end_d, inv[n:], d)
    return end_d[inv[:n]] < d, start_d[inv[n:]] < d


def _chains(rng, n):
    """Segments joined end to start (with 1e-9 m jitter, within the 1e-7 m tolerance), some
    forks and some loose ones; diameters that grow, shrink and tie."""
    pts = rng.uniform(-2, 2, (n // 2 + 1, 3))
    a = rng.integers(0, len(pts), n)
    b = rng.integers(0, len(pts), n)
    b[b == a] = (b[b == a] + 1) % len(pts)
    p0 = pts[a] + rng.uniform(-1e-9, 1e-9, (n, 3))
    p1 = pts[b] + rng.uniform(-1e-9, 1e-9, (n, 3))
    d = rng.choice([0.01, 0.02, 0.03], n)
    return p0, p1, d


@pytest.mark.parametrize("n", [0, 1, 2, 300])
def test_exposed_ends_equal_the_unique_grouping(monkeypatch, n):
    rng = np.random.default_rng(n)
    p0, p1, d = _chains(rng, n)
    want = _exposed_reference(p0, p1, d)
    got = exposed_ends(p0, p1, d)
    assert all(np.array_equal(g, w) for g, w in zip(got, want))
    if n > 2:  # the grouping is not trivial: some ends are covered, some are not
        assert 0 < got[1].sum() < n
    # Every row one hash (all collide): the exact lexicographic sort takes over.
    monkeypatch.setattr(prisms, "_KEY_MIX", np.zeros(3, np.uint64))
    got = exposed_ends(p0, p1, d)
    assert all(np.array_equal(g, w) for g, w in zip(got, want))


def _settings(**kw):
    base = dict(x0_m=-1.0, z0_m=1.0, y_start_m=0.0, dy_m=0.01, gap=0, n_positions=150,
                theta_min_deg=-30.0, dtheta_deg=0.5, n_angles=121)
    return ScanSettings(**{**base, **kw})


def test_swept_share_is_the_broadcast_mean_bit_for_bit():
    rng = np.random.default_rng(3)
    n = 2000
    p0 = rng.uniform([-3, -1, -1], [4, 3, 4], (n, 3))
    p1 = p0 + rng.normal(size=(n, 3)) * 0.3
    b = Branches(p0, p1, rng.uniform(0.005, 0.05, n), np.ones(n, np.int32), np.zeros(n, np.int32))
    s = _settings()
    t = np.linspace(0.0, 1.0, 17)
    pts = b.p0[:, None, :] + t[None, :, None] * (b.p1 - b.p0)[:, None, :]
    inside = s.covers(pts).reshape(n, 17).mean(axis=1)
    apr = b.diameter * np.linalg.norm(b.p1 - b.p0, axis=1)
    want = float(np.sum(apr * inside) / np.sum(apr))
    assert 0.05 < want < 0.95  # partly swept: the sum has something to get wrong
    assert s.swept_share(b).hex() == want.hex()
    assert np.isnan(s.swept_share(Branches.empty()))
    # covers: NaN points are outside, points behind the scanner too
    assert not s.covers([[np.nan, 0.5, 1.0], [-2.0, 0.5, 1.0]]).any()


def _areas_reference(r: ScanResult):
    """The impacted areas, weights and counts as first written (full temporaries)."""
    s = r.settings
    veg = (r.cls == 2) | (r.cls == 3)
    if s.footprint > 0 and s.hit_rule == "fraction":
        w = np.where(veg, r.hit_fraction, 0.0).astype(np.float64)
    else:
        w = veg.astype(np.float64)
    th = np.deg2rad(s.theta_deg)
    half = np.deg2rad(s.dtheta_deg) / 2
    dsin = np.sin(th + half) - np.sin(th - half)
    a_im = float(s.dy_m * np.sum(w * r.range_m * dsin[None, :]))
    with np.errstate(over="ignore", invalid="ignore"):
        dtan = np.tan(th + half) - np.tan(th - half)
        area = w * (r.range_m * np.cos(th)[None, :]) * dtan[None, :]
    a_yz = float(s.dy_m * np.nansum(np.where(w > 0, area, 0.0)))
    counts = np.bincount(r.cls.ravel(), minlength=4)
    return a_im, a_yz, {name: int(counts[c]) for c, name in enumerate(("escape", "ground", "wood", "leaf"))}


@pytest.mark.parametrize("footprint, rule", [(0, "fraction"), (2, "fraction"), (2, "any")])
def test_impacted_areas_and_counts_bit_for_bit(footprint, rule):
    rng = np.random.default_rng(footprint)
    # θ up to past 90°: tan overflows and changes sign, as the eq. 8 limits never give but
    # the measures must survive
    s = _settings(footprint=footprint, hit_rule=rule, theta_min_deg=-40.0, n_angles=271)
    shape = (s.n_positions, s.n_angles)
    cls = rng.integers(0, 4, shape).astype(np.uint8)
    rng_m = rng.uniform(0.5, 30.0, shape).astype(np.float32)
    rng_m[cls == 0] = s.escape_m
    frac = rng.random(shape).astype(np.float32)
    frac[cls < 2] = 0.0
    nan_frac = frac.copy()
    nan_frac[0, :3] = np.nan  # a NaN weight is no hit in A_IM_yz and NaN in A_IM, as before
    one = _settings(footprint=footprint, hit_rule=rule, n_positions=1, n_angles=1)
    full = ScanResult(s, rng_m, cls, np.zeros(shape, np.uint32), frac, np.zeros(3))
    assert np.isfinite(full.impacted_area_m2()) and np.isfinite(full.impacted_area_yz_m2())
    for r in (full, ScanResult(s, rng_m, np.where(nan_frac != nan_frac, 2, cls).astype(np.uint8),
                               np.zeros(shape, np.uint32), nan_frac, np.zeros(3)),
              ScanResult(one, rng_m[1:2, 7:8], cls[1:2, 7:8], np.zeros((1, 1), np.uint32), frac[1:2, 7:8],
                         np.zeros(3))):
        got = (r.impacted_area_m2(), r.impacted_area_yz_m2(), r.class_counts())
        assert json.dumps(got) == json.dumps(_areas_reference(r))
    r0 = ScanResult(s, rng_m[:0], cls[:0], np.zeros((0, s.n_angles), np.uint32), frac[:0], np.zeros(3))
    assert (r0.impacted_area_m2(), r0.impacted_area_yz_m2()) == (0.0, 0.0)
    assert r0.class_counts() == {"escape": 0, "ground": 0, "wood": 0, "leaf": 0}


def test_vegetation_is_wood_or_leaf_for_every_code():
    cls = np.arange(256, dtype=np.uint8).reshape(16, 16)
    r = ScanResult(_settings(n_positions=16, n_angles=16), np.ones((16, 16), np.float32), cls,
                   np.zeros((16, 16), np.uint32), np.zeros((16, 16), np.float32), np.zeros(3))
    assert np.array_equal(r.vegetation(), (cls == CLASS_CODES["wood"]) | (cls == CLASS_CODES["leaf"]))
    assert sum(r.class_counts().values()) == 4  # one beam of each class code 0..3


@pytest.mark.parametrize("order", ["sorted", "shuffled", "one"])
def test_per_tree_sums_are_the_masked_sums(order):
    rng = np.random.default_rng(5)
    n = 1 if order == "one" else 500
    p0, p1, d = _segments(rng, n)
    ids = np.sort(rng.integers(0, 6, n)).astype(np.int32)
    if order == "shuffled":
        rng.shuffle(ids)
    b = Branches(p0, p1, d, np.ones(n, np.int32), ids)
    values = _per_cylinder(b, _unit_view((1.0, 0.0, 0.0)))
    want = {int(t): _summary(values[ids == t]) for t in np.unique(ids)}
    got = wood_measures(b)
    assert list(got.per_tree) == list(want) and got.per_tree == want


def test_built_scene_tables_repeat_the_branch_rows():
    """The flat mesh's element ids and tree ids (np.repeat per branch) equal gathers by owner."""
    from simlidar_mi.scene.build import build_scene
    rng = np.random.default_rng(9)
    n = 40
    p0 = rng.uniform(0, 2, (n, 3))
    p1 = p0 + [0.0, 0.0, 0.5]
    p1[3] = p0[3]  # zero length: dropped, so element ids skip row 3
    ids = np.repeat(np.arange(4, dtype=np.int32), 10)
    b = Branches(p0, p1, rng.uniform(0.01, 0.05, n), np.ones(n, np.int32), ids)
    leaves = Leaves(rng.uniform(0, 2, (6, 3, 3)), np.arange(6, dtype=np.int32), np.full(6, 7, np.int32))
    built = build_scene(b, leaves, facets=6)
    kept = np.flatnonzero(np.linalg.norm(p1 - p0, axis=1) > 0)
    caps = exposed_ends(p0[kept], p1[kept], b.diameter[kept])
    _, f, owner = prism_mesh(p0[kept], p1[kept], b.diameter[kept], 6, caps=caps)
    wood = kept[owner]
    assert np.array_equal(built.prim_element, np.concatenate([wood, np.arange(6)]).astype(np.uint32))
    assert np.array_equal(built.prim_tree, np.concatenate([ids[wood], np.full(6, 7)]).astype(np.uint32))
