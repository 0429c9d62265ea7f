"""The truth's G along the scan's beams (simlidar_mi.truth.leaf_g) against the closed forms of
Ross (1981): horizontal leaves G = |cos theta|, spherical leaf normals 0.5, vertical leaves of
uniform azimuth (2/pi) sin theta; and the oracle runs of evaluate that divide by it."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.geometry import Branches, Leaves
from simlidar_mi.lidar.survey import SceneGeometry
from simlidar_mi.truth.compute import compute_truth
from simlidar_mi.truth.estimators import beer_lambert_pad, contact_mle_pad, with_G
from simlidar_mi.truth.grid import VoxelGrid, grid_values
from simlidar_mi.truth.leaf_g import LeafG, LeafPieces, projection_G
from simlidar_mi.truth.traverse import Beams, traverse

GRID = VoxelGrid((0.0, 0.0, 0.0), 1.0, (2, 1, 1))  # voxel 0: x in [0, 1), voxel 1: [1, 2)


def _L(tri) -> Leaves:
    return Leaves(tri, np.arange(len(tri), dtype=np.int32), np.zeros(len(tri), np.int32))


def _leaves(normals, centres, side=0.01) -> np.ndarray:
    """Small right triangles (n, 3, 3) of the given unit normals at the given centres."""
    n = np.asarray(normals, np.float64)
    helper = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(n, u)
    c = np.asarray(centres, np.float64)
    return np.stack([c, c + side * u, c + side * v], axis=1)


def _centres(k, x0, rng):
    return np.column_stack([rng.uniform(x0 + 0.1, x0 + 0.9, k), rng.uniform(0.1, 0.9, k), rng.uniform(0.1, 0.9, k)])


def _beams(theta_deg, azimuth_deg=30.0, n=400):
    """Escaping first-return beams of zenith angle theta through the middle of both voxels."""
    th, az = np.deg2rad(theta_deg), np.deg2rad(azimuth_deg)
    d = np.array([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)])
    rng = np.random.default_rng(3)
    target = np.column_stack([rng.uniform(0.2, 1.8, n), rng.uniform(0.2, 0.8, n), rng.uniform(0.2, 0.8, n)])
    o = target - 5.0 * d
    return Beams.first_return(o, np.broadcast_to(d, (n, 3)), np.full(n, 10.0), np.zeros(n, np.int8))


def _fibonacci(k):
    i = np.arange(k) + 0.5
    z = 1 - 2 * i / k
    r = np.sqrt(1 - z * z)
    ph = np.pi * (1 + 5 ** 0.5) * i
    return np.column_stack([r * np.cos(ph), r * np.sin(ph), z])


def _truth_G(tri, beams):
    pieces = LeafPieces(GRID)
    truth = compute_truth(SceneGeometry(Branches.empty(), _L(tri), []), GRID, progress=False,
                          leaf_pieces=pieces)
    g = LeafG(pieces, beams)
    traverse(GRID, beams, on_segment=g.segment)
    return g, truth


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0, 85.0])
def test_G_per_voxel_and_canopy_match_the_closed_forms(theta):
    """Voxel 0 holds horizontal leaves, voxel 1 vertical leaves of evenly spaced azimuths: per
    voxel G is |cos theta| and (2/pi) sin theta (to 1e-4, the azimuth sampling); the canopy's G
    is their leaf-area and chord weighted mean."""
    rng = np.random.default_rng(1)
    k = 720
    az = (np.arange(k) + 0.5) * 2 * np.pi / k
    horizontal = _leaves(np.tile([0.0, 0.0, 1.0], (k, 1)), _centres(k, 0.0, rng))
    vertical = _leaves(np.column_stack([np.cos(az), np.sin(az), np.zeros(k)]), _centres(k, 1.0, rng))
    beams = _beams(theta)
    g, truth = _truth_G(np.concatenate([horizontal, vertical]), beams)
    per = g.per_voxel()
    th = np.deg2rad(theta)
    assert per[0, 0, 0] == pytest.approx(abs(np.cos(th)), abs=1e-9)
    assert per[1, 0, 0] == pytest.approx(2 / np.pi * np.sin(th), abs=1e-4)
    w = g.chord_all.reshape(GRID.shape)[:, 0, 0] * grid_values(truth, "leaf_area_m2")[:, 0, 0]
    assert g.canopy() == pytest.approx(float(np.sum(w * per[:, 0, 0]) / w.sum()), rel=1e-12)
    # plant G: no wood here, so the same
    gp, gc = g.plant(grid_values(truth, "leaf_area_m2"), grid_values(truth, "plant_area_m2"))
    np.testing.assert_allclose(gp, per, rtol=1e-12)
    assert gc == pytest.approx(g.canopy(), rel=1e-12)


@pytest.mark.parametrize("theta", [10.0, 45.0, 80.0])
def test_spherical_leaves_have_G_one_half_in_every_direction(theta):
    k = 4000
    rng = np.random.default_rng(2)
    n = _fibonacci(k)
    tri = np.concatenate([_leaves(n, _centres(k, 0.0, rng)), _leaves(n, _centres(k, 1.0, rng))])
    g, _ = _truth_G(tri, _beams(theta, azimuth_deg=70.0))
    np.testing.assert_allclose(g.per_voxel()[:, 0, 0], 0.5, atol=2e-4)
    assert g.canopy() == pytest.approx(0.5, abs=2e-4)
    assert projection_G(n * 1e-4, [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]) == pytest.approx(0.5, abs=2e-4)


def test_a_leaf_cut_by_voxel_planes_keeps_its_normal_and_area():
    """One tilted leaf across the voxel face x = 1: its pieces carry the leaf's normal, the
    areas sum to the leaf's, and both voxels read the same G = |n . Omega|."""
    n = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    tri = _leaves(n[None], [[1.2, 0.2, 0.4]], side=0.6)  # spans x 0.69 ... 1.2
    pieces = LeafPieces(GRID)
    compute_truth(SceneGeometry(Branches.empty(), _L(tri), []), GRID, progress=False, leaf_pieces=pieces)
    flat, va = pieces.arrays()
    assert set(flat.tolist()) == {0, 1}
    assert np.linalg.norm(va, axis=1).sum() == pytest.approx(0.5 * 0.6 ** 2, rel=1e-12)
    np.testing.assert_allclose(va / np.linalg.norm(va, axis=1, keepdims=True), np.tile(n, (len(va), 1)), atol=1e-12)
    beams = _beams(50.0)
    g = LeafG(pieces, beams)
    traverse(GRID, beams, on_segment=g.segment)
    np.testing.assert_allclose(g.per_voxel()[:, 0, 0], abs(n @ beams.dir[0]), rtol=1e-12)


def test_wood_enters_the_plant_G_at_one_half():
    """A voxel of horizontal leaf area L and wood half-area H: G_plant = (L |cos theta| + 0.5 H)/(L + H)."""
    g = LeafG.__new__(LeafG)
    g.grid = VoxelGrid((0.0, 0.0, 0.0), 1.0, (1, 1, 1))
    g.voxels, g.start, g.count = np.array([0]), np.array([0]), np.array([1])
    g.va, g.area = np.array([[0.0, 0.0, 0.3]]), np.array([0.3])
    g.proj, g.weight, g.chord_all = np.array([0.3 * 0.2]), np.array([1.0]), np.array([1.0])
    gp, gc = g.plant(np.full((1, 1, 1), 0.3), np.full((1, 1, 1), 0.3 + 0.1))
    assert gp[0, 0, 0] == pytest.approx((0.3 * 0.2 + 0.5 * 0.1) / 0.4)
    assert gc == pytest.approx(gp[0, 0, 0])


def test_estimators_take_G_per_voxel_and_scale_as_one_over_G():
    """Beer-Lambert and the MLE with an array G equal the constant-G estimate times 0.5/G, per
    voxel (the oracle runs of evaluate are built with with_G)."""
    from simlidar_mi.truth.synthetic import turbid_beams
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.25, (4, 4, 4))
    c = traverse(grid, turbid_beams(4_000, 2.0, seed=5))
    G = np.random.default_rng(0).uniform(0.3, 0.9, grid.shape)
    for f in (beer_lambert_pad, contact_mle_pad):
        half = f(c)
        np.testing.assert_allclose(f(c, G=G), half * 0.5 / G, rtol=1e-12)
        np.testing.assert_allclose(with_G(half, 0.5, G), f(c, G=G), rtol=1e-12)
