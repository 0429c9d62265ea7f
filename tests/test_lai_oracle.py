"""Oracles for the gap-fraction LAI methods on rendered canopies of random leaves (Mitsuba rays).

Canopies: N = 3200 square leaves of 0.01 m² (10 cm) in a periodic 4 × 4 m plot (LAI 2), centres
at 0.5–1.0 m, spherical leaf angles (G = 0.5), tiled 5 × 5 (±8 m around the plot). Upward ray
fans from 64 ground points in [0.25, 3.75]² sample the five LAI-2200 rings (≤ 74.1°): a ray
leaves the canopy top (1.07 m with a leaf's half-diagonal) within 1.07·tan 74.1° = 3.8 m of its
point, well inside the tiles, and crosses the 0.64 m canopy slab within 2.3 m < 4 m, so it never
meets one leaf twice on the torus. The expected gap fraction along any ray is exactly
(1 − a·G/(A cos θ))^N; its mean over a ring (uniform in solid angle) is the ring's expectation.

* random: the leaves as drawn — P(θ) as above, Miller's L_e = L, Nilson's Ω(θ) = 1, the
  LAI-2200 reads L with ACF ≈ 1, Chen–Cihlar Ω ≈ 1.
* regular: the same leaves moved onto two staggered square lattices (0.6 and 0.9 m): Ω > 1.
* clumped: the same leaves gathered into 16 crowns of 200 leaves (normal spread 0.3 m): Ω < 1.

Ω definitions: Nilson's Ω(θ) = −ln P(θ) cos θ / (G L) from the exact G and L (the only one that
can exceed 1), Lang–Xiang over 45° sectors, the LAI-2200's ACF over readings, Chen–Cihlar over
sunfleck transects (sun at 30° zenith, eight 4 m transects, 2 mm steps) with the leaves'
exact shadow width W_p (the probes' estimate of W_p is checked on the random canopy).
"""
import math

import numpy as np
import pytest

from simlidar_mi.canopy import lai2200 as li
from simlidar_mi.canopy import lai_methods as lm
from simlidar_mi.canopy import ring_sampler as rs
from simlidar_mi.geometry import Branches, Leaves
from simlidar_mi.plants.random_leaves import random_leaves

W, A_LEAF, LAI, Z = 4.0, 0.01, 2.0, (0.5, 1.0)
N = int(round(LAI * W * W / A_LEAF))
RINGS = li.RING_BOUNDS_DEG


def _build(leaves: Leaves):
    from simlidar_mi.scene.build import build_scene
    return build_scene(Branches.empty(), leaves, [], origin_m=np.array([2.0, 2.0, 0.0]))


def _moved(canopy, xyz) -> Leaves:
    """The canopy's leaves (each keeping its shape and orientation) moved to centres ``xyz``, tiled."""
    v = canopy.originals.vertices.reshape(N, 2, 3, 3)
    v = v - canopy.centres_m[:, None, None, :] + np.asarray(xyz)[:, None, None, :]
    k = np.arange(-2, 3) * W
    shifts = np.stack(np.meshgrid(k, k, indexing="ij"), -1).reshape(-1, 2)
    off = np.c_[shifts, np.zeros(len(shifts))]
    verts = (v.reshape(-1, 3, 3)[None] + off[:, None, None, :]).reshape(-1, 3, 3)
    n = len(verts)
    return Leaves(verts, np.zeros(n, np.int32), np.zeros(n, np.int32))


def canopy_scene(kind: str, seed: int):
    c = random_leaves(N, A_LEAF, (W, W), Z, "spherical", seed=seed)
    if kind == "random":
        return _build(c.tiled(2))
    rng = np.random.default_rng(seed + 100)
    if kind == "regular":
        n = int(round(math.sqrt(N / 2)))
        g = (np.arange(n) + 0.5) * W / n
        xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        xy = np.concatenate([xy, (xy + 0.5 * W / n) % W])
        return _build(_moved(c, np.c_[xy, np.repeat([0.6, 0.9], n * n)]))
    m = 200  # clumped: crowns of m leaves
    crowns = rng.uniform(0, W, (N // m, 2))
    xy = (np.repeat(crowns, m, 0) + rng.normal(0, 0.3, (N, 2))) % W
    return _build(_moved(c, np.c_[xy, c.centres_m[:, 2]]))


def expected_ring_p():
    out = []
    for lo, hi in RINGS:
        c = np.linspace(math.cos(math.radians(lo)), math.cos(math.radians(hi)), 4001)
        out.append(np.mean((1 - A_LEAF * 0.5 / (W * W * c)) ** N))
    return np.array(out)


@pytest.fixture(scope="module")
def measured():
    g = np.linspace(0.25, 3.75, 8)
    pos = np.c_[np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2), np.zeros(64)]
    out = {}
    for kind in ("random", "regular", "clumped"):
        for seed in ((1, 2, 3) if kind == "random" else (1,)):
            built = canopy_scene(kind, seed)
            gaps = rs.ring_sector_gaps(built, pos, RINGS, 8, 256, seed=seed)
            lam, tot = [], 0.0
            for y in np.linspace(0.25, 3.75, 8):
                seg, t = rs.transect_gaps(built, [0, y, 0], [W, y, 0], 0.002, 30.0, 90.0)
                lam.append(seg)
                tot += t
            out[kind, seed] = gaps, np.concatenate(lam), tot
    return out


def truth_wp(seed=1):
    """Mean chord of the leaves' shadows along the transects (sun at 30°, toward +y; lines along x)."""
    c = random_leaves(N, A_LEAF, (W, W), Z, "spherical", seed=seed)
    return lm.projected_element_width(c.originals.vertices.reshape(N, 2, 3, 3), 30.0, 90.0, 0.0)


def _stats(gaps, lam, tot):
    p = gaps.mean(axis=(0, 2))
    return {
        "p": p,
        "miller": lm.miller_lai(RINGS, gaps.mean(axis=0)),
        "nilson": lm.nilson_clumping(li.RING_CENTRES_DEG, p, 0.5, LAI),
        "lx": lm.lang_xiang(RINGS, gaps.transpose(1, 0, 2).reshape(5, -1)),
        "lai2200": li.lai2200(gaps.mean(axis=2)),
        # W_p from the truth's leaves (moving leaves changes neither their shapes nor angles).
        "cc": lm.chen_cihlar(lam, tot, element_width=truth_wp()),
        # W_p from the probes of 1–5 steps of 2 mm.
        "cc_probe": lm.chen_cihlar(lam / 0.002, tot / 0.002),
    }


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_canopy_follows_poisson(measured, seed):
    s = _stats(*measured["random", seed])
    # 64 points over a 4 m plot of 10 cm leaves: the ring means scatter by ~0.005 between seeds.
    np.testing.assert_allclose(s["p"], expected_ring_p(), atol=0.02)
    assert s["miller"] == pytest.approx(LAI, rel=0.03)
    np.testing.assert_allclose(s["nilson"], 1.0, atol=0.06)
    assert s["lai2200"].lai == pytest.approx(LAI, rel=0.04)
    assert 0.98 <= s["lai2200"].acf <= 1.0
    # Sectors of 45° seen from a point hold few leaves: their spread lowers Lang–Xiang's
    # ratio below 1 even for random leaves (Jensen); whole rings (the ACF) read ~0.99.
    assert 0.9 <= s["lx"].omega <= 1.0
    assert s["cc"].omega == pytest.approx(1.0, abs=0.05)
    assert s["cc_probe"].wp * 0.002 == pytest.approx(truth_wp(), rel=0.15)
    assert s["cc_probe"].omega == pytest.approx(1.0, abs=0.05)


def test_regular_canopy_is_anticlumped(measured):
    s = _stats(*measured["regular", 1])
    assert (s["nilson"] > 1.2).all()
    assert s["miller"] > 1.2 * LAI
    # Neither logarithmic averaging nor gap removal can report Ω > 1: both stay ≤ 1.
    assert s["lx"].omega <= 1.0 and s["cc"].omega <= 1.0


def test_clumped_canopy_is_clumped(measured):
    s = _stats(*measured["clumped", 1])
    rnd = [_stats(*measured["random", k]) for k in (1, 2, 3)]
    assert (s["nilson"] < 0.85).all()
    assert s["miller"] < 0.85 * LAI
    assert s["lx"].omega < min(r["lx"].omega for r in rnd) - 0.03
    assert s["lai2200"].acf < min(r["lai2200"].acf for r in rnd)
    assert s["cc"].omega < 0.9
    # The corrections move L_e toward L without reaching it here.
    assert s["miller"] < s["lx"].lai_lx < LAI
