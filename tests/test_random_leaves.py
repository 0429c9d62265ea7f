"""Random flat leaves in a periodic plot: areas, leaf-angle laws, G and gap fraction."""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Leaves
from simlidar_mi.plants.random_leaves import (
    G_FUNCTIONS, RandomLeavesCanopy, RandomLeavesParams, periodic_copies, random_leaves)


def _normals(v: np.ndarray) -> np.ndarray:
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _view(zenith_deg: float) -> np.ndarray:
    t = math.radians(zenith_deg)
    return np.array([math.sin(t), 0.0, math.cos(t)])


# ------------------------------------------------------------------------ areas
@pytest.mark.parametrize("shape,k", [("square", 2), ("disc", 16), ("disc", 5)])
def test_area_is_exactly_n_times_a(shape, k, seed):
    n, a = 400, 0.004
    c = random_leaves(n, a, (1.0, 0.8), (0.0, 0.5), "spherical", shape, seed,
                      n_sides=k if shape == "disc" else 16)
    assert isinstance(c, RandomLeavesCanopy) and isinstance(c.leaves, Leaves)
    orig = c.originals
    assert len(orig) == n * k
    assert orig.triangle_area.sum() == pytest.approx(n * a, rel=1e-12)
    per_leaf = np.bincount(orig.leaf_id, weights=orig.triangle_area)
    np.testing.assert_allclose(per_leaf, a, rtol=1e-12)
    assert c.lai == pytest.approx(n * a / 0.8)
    # Copies are counted separately, each a whole leaf of area a.
    copies = c.leaves.subset(c.is_copy)
    assert len(copies) == k * c.n_copies
    assert copies.triangle_area.sum() == pytest.approx(c.n_copies * a, rel=1e-12)
    assert c.leaves.vertices.dtype == np.float64
    assert c.leaves.leaf_id.dtype == np.int32 and c.leaves.plant_id.dtype == np.int32


def test_copies_are_exactly_the_leaves_crossing_an_edge(seed):
    w, l = 1.0, 0.7
    c = random_leaves(600, 0.01, (w, l), (0, 1), "vertical", "square", seed)
    v = c.originals.vertices.reshape(600, 2, 3, 3)
    lo, hi = v[..., :2].reshape(600, -1, 2).min(1), v[..., :2].reshape(600, -1, 2).max(1)
    cx = (lo[:, 0] < 0) | (hi[:, 0] > w)
    cy = (lo[:, 1] < 0) | (hi[:, 1] > l)
    assert c.n_copies == int(cx.sum() + cy.sum() + (cx & cy).sum())
    assert c.n_copies > 0
    # Every copy is its source leaf shifted by whole plot sizes.
    copies = c.leaves.vertices[c.is_copy].reshape(-1, 2, 3, 3)
    src = c.leaves.leaf_id[c.is_copy][::2]
    d = copies - v[src]
    np.testing.assert_allclose(d[..., 2], 0, atol=0)
    for axis, size in ((0, w), (1, l)):
        shift = d[..., axis].reshape(len(src), -1)
        assert np.allclose(shift, shift[:, :1], atol=1e-12)
        assert set(np.round(shift[:, 0] / size, 9)) <= {-1.0, 0.0, 1.0}


def _clip_area(tri: np.ndarray, x0, y0, x1, y1) -> float:
    """Area of a 2-D triangle clipped to a rectangle (Sutherland–Hodgman)."""
    poly = [tuple(p) for p in tri]
    for axis, bound, keep_low in ((0, x0, False), (0, x1, True), (1, y0, False), (1, y1, True)):
        out = []
        for i in range(len(poly)):
            p, q = poly[i], poly[(i + 1) % len(poly)]
            pin = p[axis] <= bound if keep_low else p[axis] >= bound
            qin = q[axis] <= bound if keep_low else q[axis] >= bound
            if pin:
                out.append(p)
            if pin != qin:
                t = (bound - p[axis]) / (q[axis] - p[axis])
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        poly = out
        if not poly:
            return 0.0
    xs, ys = np.array(poly).T
    return 0.5 * abs(np.dot(xs, np.roll(ys, -1)) - np.dot(ys, np.roll(xs, -1)))


@pytest.mark.parametrize("shape", ["square", "disc"])
def test_wrapped_canopy_tiles_the_plot(shape, seed):
    """Horizontal leaves: the area inside the plot, copies included, is N·a exactly."""
    w, l, n, a = 1.0, 0.6, 150, 0.01
    c = random_leaves(n, a, (w, l), (0, 1), "horizontal", shape, seed, n_sides=8)
    inside = sum(_clip_area(t[:, :2], 0, 0, w, l) for t in c.leaves.vertices)
    assert inside == pytest.approx(n * a, rel=1e-9)


# --------------------------------------------------------------- leaf-angle laws
def test_horizontal_and_vertical_normals(seed):
    h = random_leaves(500, 0.002, angle_law="horizontal", seed=seed)
    np.testing.assert_allclose(h.normals, np.tile([0, 0, 1.0], (500, 1)), atol=1e-15)
    np.testing.assert_allclose(np.abs(_normals(h.originals.vertices)[:, 2]), 1, atol=1e-12)
    v = random_leaves(500, 0.002, angle_law="vertical", seed=seed, shape="disc")
    assert np.abs(v.normals[:, 2]).max() < 1e-15
    assert np.abs(_normals(v.originals.vertices)[:, 2]).max() < 1e-12
    # Random azimuth: mean horizontal normal direction ~ 0.
    az = np.arctan2(v.normals[:, 1], v.normals[:, 0])
    assert np.hypot(np.cos(az).mean(), np.sin(az).mean()) < 4 / math.sqrt(500)


def test_triangle_normals_match_the_stored_normals(seed):
    c = random_leaves(300, 0.003, angle_law="spherical", shape="disc", seed=seed)
    n_tri = _normals(c.originals.vertices).reshape(300, -1, 3)
    np.testing.assert_allclose(n_tri, np.broadcast_to(c.normals[:, None], n_tri.shape),
                               atol=1e-12)
    assert np.all(c.normals[:, 2] >= 0)


def test_spherical_inclination_density_is_sin(seed):
    n = 40_000
    c = random_leaves(n, 1e-5, angle_law="spherical", seed=seed)
    cos_t = c.normals[:, 2]
    # E[cos θ_L] = 1/2 for the density sin θ_L on [0, π/2].
    assert abs(cos_t.mean() - 0.5) < 3 * cos_t.std() / math.sqrt(n)
    # Histogram of θ_L against the CDF 1 − cos θ_L.
    theta = np.arccos(np.clip(cos_t, 0, 1))
    edges = np.linspace(0, np.pi / 2, 10)
    counts, _ = np.histogram(theta, edges)
    p = np.diff(1 - np.cos(edges))
    chi2 = float(((counts - n * p) ** 2 / (n * p)).sum())
    assert chi2 < 27.9  # χ²(8) at p = 0.0005


@pytest.mark.parametrize("zenith", [0.0, 15.0, 30.0])
def test_g_function_projected_area(zenith, seed):
    """Mean projected area a·|n·v| / a = G(θ)·… for each law (cf. G of notes/science.md)."""
    n, a = 20_000, 1e-5
    v = _view(zenith)
    t = math.radians(zenith)
    for law in ("spherical", "horizontal", "vertical"):
        c = random_leaves(n, a, angle_law=law, seed=seed)
        proj = np.abs(c.normals @ v)
        g = float(G_FUNCTIONS[law](t))
        se = proj.std() / math.sqrt(n)
        assert abs(proj.mean() - g) <= 3 * se + 1e-12, law
        # The same from the triangles themselves: Σ area·|n·v| / (N·a).
        tri = c.originals.vertices
        proj_tri = c.originals.triangle_area * np.abs(_normals(tri) @ v)
        assert proj_tri.sum() / (n * a) == pytest.approx(proj.mean(), rel=1e-9, abs=1e-12)
    # Along the vertical the projected area is N·a·E|cos θ_L|.
    if zenith == 0.0:
        h = random_leaves(100, a, angle_law="horizontal", seed=seed)
        assert (np.abs(h.normals @ v) * a).sum() == pytest.approx(100 * a, rel=1e-12)


# ------------------------------------------------------------------ gap fraction
def _gap_fraction(c: RandomLeavesCanopy, zenith: float, rng, n_points=400) -> float:
    """Orthographic P0 from random ground points: project every original leaf to the
    ground along the view direction, wrap the projections periodically, and test the
    points against the projected triangles."""
    w, l = c.params.plot_size_m
    t = math.radians(zenith)
    v = c.originals.vertices.reshape(c.params.n_leaves, -1, 3, 3).copy()
    v[..., 0] -= v[..., 2] * math.tan(t)
    v[..., 2] = 0.0
    wrapped, _, _ = periodic_copies(v, (w, l), recentre=True)
    tri = wrapped.reshape(-1, 3, 3)[..., :2]
    pts = np.stack([rng.uniform(0, w, n_points), rng.uniform(0, l, n_points)], 1)
    a, b, cc = (tri[None, :, i, :] for i in range(3))
    p = pts[:, None, :]

    def side(p1, p2):
        return (p[..., 0] - p2[..., 0]) * (p1[..., 1] - p2[..., 1]) - \
               (p1[..., 0] - p2[..., 0]) * (p[..., 1] - p2[..., 1])

    d1, d2, d3 = side(a, b), side(b, cc), side(cc, a)
    inside = ~(((d1 < 0) | (d2 < 0) | (d3 < 0)) & ((d1 > 0) | (d2 > 0) | (d3 > 0)))
    return 1.0 - inside.any(axis=1).mean()


@pytest.mark.parametrize("law,zenith", [("horizontal", 0.0), ("spherical", 0.0),
                                        ("spherical", 30.0), ("vertical", 30.0)])
def test_mean_gap_fraction_matches_the_finite_leaf_formula(law, zenith):
    """E[P0] = (1 − a·G/(A·cos θ))^N for N independent leaves in a periodic plot."""
    n, a, (w, l) = 50, 0.02, (1.0, 1.0)
    t = math.radians(zenith)
    expected = (1 - a * float(G_FUNCTIONS[law](t)) / (w * l * math.cos(t))) ** n
    rng = np.random.default_rng(99)
    vals = [_gap_fraction(random_leaves(n, a, (w, l), (0.0, 0.5), law, "square", s), zenith, rng)
            for s in range(60)]
    mean, se = float(np.mean(vals)), float(np.std(vals, ddof=1) / math.sqrt(len(vals)))
    assert abs(mean - expected) < 4 * se, (mean, expected, se)


# ------------------------------------------------------------- seeds and tiling
def test_same_seed_same_bytes(seed):
    a = random_leaves(200, 0.004, (1, 1), (0, 1), "spherical", "disc", seed)
    b = random_leaves(200, 0.004, (1, 1), (0, 1), "spherical", "disc", seed)
    assert a.leaves.vertices.tobytes() == b.leaves.vertices.tobytes()
    assert a.leaves.leaf_id.tobytes() == b.leaves.leaf_id.tobytes()
    assert a.is_copy.tobytes() == b.is_copy.tobytes()
    assert a.seed_entropy == seed
    c = random_leaves(200, 0.004, (1, 1), (0, 1), "spherical", "disc", seed + 1)
    assert a.leaves.vertices.tobytes() != c.leaves.vertices.tobytes()


def test_tiled(seed):
    c = random_leaves(30, 0.01, (1.0, 2.0), (0, 1), "horizontal", seed=seed)
    t = c.tiled(1)
    assert len(t) == 9 * len(c.originals)
    assert t.triangle_area.sum() == pytest.approx(9 * 30 * 0.01)
    xs = t.vertices[..., 0].mean(axis=1)
    assert xs.min() < -0.5 and xs.max() > 1.5
    assert len(c.tiled(0)) == len(c.originals)


def test_heights_and_plot(seed):
    c = random_leaves(1000, 0.001, (2.0, 1.0), (0.2, 0.7), "horizontal", seed=seed)
    assert c.bounds_m == (0.0, 0.0, 2.0, 1.0)
    assert c.centres_m[:, 2].min() >= 0.2 and c.centres_m[:, 2].max() <= 0.7
    assert np.all((c.centres_m[:, 0] >= 0) & (c.centres_m[:, 0] <= 2))
    np.testing.assert_allclose(c.originals.vertices[..., 2].reshape(1000, -1).mean(1),
                               c.centres_m[:, 2], atol=1e-15)


def test_zero_leaves(seed):
    c = random_leaves(0, 0.01, seed=seed)
    assert len(c.leaves) == 0 and c.lai == 0.0 and c.n_copies == 0


# ------------------------------------------------------------------- validation
@pytest.mark.parametrize("kw,key", [
    (dict(n_leaves=-1), "n_leaves"), (dict(n_leaves=2.5), "n_leaves"),
    (dict(leaf_area_m2=0.0), "leaf_area_m2"), (dict(leaf_area_m2=float("nan")), "leaf_area_m2"),
    (dict(plot_size_m=(1.0, -1.0)), "plot_size_m"), (dict(plot_size_m=(1.0,)), "plot_size_m"),
    (dict(height_range_m=(1.0, 0.0)), "height_range_m"), (dict(angle_law="erect"), "angle_law"),
    (dict(shape="star"), "shape"), (dict(n_sides=2), "n_sides"),
    (dict(leaf_area_m2=0.6), "leaf_area_m2"),
])
def test_validation(kw, key):
    d = dict(n_leaves=10, leaf_area_m2=0.01, plot_size_m=(1.0, 1.0))
    d.update(kw)
    with pytest.raises(ConfigError) as e:
        RandomLeavesParams(**d)
    assert e.value.key == key
    with pytest.raises(ConfigError):
        random_leaves(**d)


def test_disc_polygon_is_scaled_to_the_area():
    for k in (3, 4, 7, 32):
        p = RandomLeavesParams(1, 0.01, shape="disc", n_sides=k)
        r = p.leaf_radius_m
        assert 0.5 * k * r * r * math.sin(2 * math.pi / k) == pytest.approx(0.01, rel=1e-14)
