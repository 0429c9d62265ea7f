"""scene.build.prism_mesh: the (k, n) per-coordinate vertices and the 12-byte face selection give
the bits of the direct broadcast formulation (issue #8 build speed), and the prism is right."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.scene.prisms import _orthonormal, prism_mesh


def _broadcast_prisms(p0, p1, radius, k, caps, sides=True):
    """The formulation before issue #8's change: (n, 2k, 3) broadcasting, (n, F, 3) faces."""
    n = len(radius)
    axis = p1 - p0
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    u, v = _orthonormal(axis)
    phi = 2 * np.pi * np.arange(k) / k
    ring = np.cos(phi)[None, :, None] * u[:, None, :]
    ring += np.sin(phi)[None, :, None] * v[:, None, :]
    ring *= radius[:, None, None]
    verts = np.concatenate([ring + p0[:, None, :], ring + p1[:, None, :]], axis=1)
    j = np.arange(k)
    jn = (j + 1) % k
    t = np.arange(1, k - 1)
    local = ([np.stack([j, jn, k + j], 1), np.stack([jn, k + jn, k + j], 1)] if sides else []) + \
        [np.stack([np.zeros_like(t), t + 1, t], 1), np.stack([k + np.zeros_like(t), k + t, k + t + 1], 1)]
    which = ([0] * (2 * k) if sides else []) + [1] * len(t) + [2] * len(t)
    local, which = np.concatenate(local).astype(np.uint32), np.asarray(which)
    faces = local[None, :, :] + (2 * k * np.arange(n, dtype=np.uint32))[:, None, None]
    keep = np.ones((n, len(local)), bool)
    keep[:, which == 1] = np.asarray(caps[0])[:, None]
    keep[:, which == 2] = np.asarray(caps[1])[:, None]
    return verts.reshape(-1, 3), faces[keep], np.repeat(np.arange(n), keep.sum(axis=1))


@pytest.mark.parametrize("k, sides", [(3, True), (12, True), (7, False)])
def test_same_bits_as_the_broadcast_formulation(k, sides):
    rng = np.random.default_rng(k)
    n = 500
    p0 = rng.uniform(-3, 3, (n, 3))
    p1 = p0 + rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.5, (n, 1))
    p1[:5] = p0[:5] + [0.0, 0.0, 0.3]  # vertical segments take the other helper axis
    radius = rng.uniform(0.001, 0.05, n)
    caps = (rng.random(n) < 0.3, rng.random(n) < 0.6)
    for c in (caps, True, False):
        cc = (np.full(n, c), np.full(n, c)) if isinstance(c, bool) else c
        got = prism_mesh(p0, p1, radius, k, caps=c, sides=sides)
        want = _broadcast_prisms(p0, p1, radius, k, cc, sides)
        assert got[0].dtype == np.float64 and got[1].dtype == np.uint32
        assert np.array_equal(got[0].view(np.uint64), want[0].view(np.uint64))
        assert np.array_equal(got[1], want[1]) and np.array_equal(got[2], want[2])


def test_prism_vertices_on_the_circle_around_each_end():
    p0 = np.array([[1.0, 2.0, 3.0]])
    p1 = np.array([[1.0, 2.0, 5.0]])
    v, f, owner = prism_mesh(p0, p1, np.array([0.25]), 6)
    assert v.shape == (12, 3) and len(f) == 2 * 6 + 2 * 4 and (owner == 0).all()
    bottom, top = v[:6], v[6:]
    assert np.allclose(np.hypot(bottom[:, 0] - 1.0, bottom[:, 1] - 2.0), 0.25)
    assert np.allclose(bottom[:, 2], 3.0) and np.allclose(top[:, 2], 5.0)
    assert np.allclose(top[:, :2], bottom[:, :2])
