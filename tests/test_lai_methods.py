"""Gap-fraction LAI methods and the LAI-2200 emulation on analytic gap fractions (exact)."""
import math

import numpy as np
import pytest

from simlidar_mi.canopy import lai2200 as li
from simlidar_mi.canopy import lai_methods as lm
from simlidar_mi.errors import ConfigError

G_LAWS = {"spherical": lambda t: 0.5 + 0 * t, "horizontal": np.cos,
          "vertical": lambda t: (2 / np.pi) * np.sin(t)}
HEMISPHER_RINGS = [(10 * i, 10 * i + 10) for i in range(7)]  # hemispheR's default 0–70°, 7 rings


def poisson_p(bounds, lai, law="spherical", omega=1.0):
    t = np.radians(np.asarray(bounds, float).mean(axis=1))
    return np.exp(-G_LAWS[law](t) * omega * lai / np.cos(t))


@pytest.mark.parametrize("lai", [0.5, 2.0, 5.0])
def test_miller_spherical_any_rings(lai):
    # −ln P cos θ = G·L is constant for spherical leaves: normalised weights are exact.
    for rings in (HEMISPHER_RINGS, li.RING_BOUNDS_DEG, [(55, 60)]):
        assert lm.miller_lai(rings, poisson_p(rings, lai)) == pytest.approx(lai, rel=1e-12)


@pytest.mark.parametrize("law", ["horizontal", "vertical", "spherical"])
def test_miller_full_hemisphere_any_law(law):
    # Miller's theorem: the integral over the whole hemisphere is L whatever G.
    edges = np.linspace(0, 89.9, 900)
    rings = np.stack([edges[:-1], edges[1:]], 1)
    p = poisson_p(rings, 3.0, law)
    # 89.9°–90° is left out: at most 2·G·L·cos 89.9° = 0.007 for vertical leaves.
    assert lm.miller_lai(rings, p, weights="quadrature") == pytest.approx(3.0, abs=0.008)


def test_miller_truncated_quadrature_reads_low():
    p = poisson_p(HEMISPHER_RINGS, 2.0)
    assert lm.miller_lai(HEMISPHER_RINGS, p, weights="quadrature") == pytest.approx(
        2.0 * (1 - math.cos(math.radians(70))), rel=1e-12)


def test_miller_sectors_average_gap_fraction_first():
    p = np.array([[0.1, 0.5]] * 7)
    le = lm.miller_lai(HEMISPHER_RINGS, p)
    assert le == pytest.approx(lm.miller_lai(HEMISPHER_RINGS, np.full(7, 0.3)))


def test_hinge():
    lai = 2.5
    p = math.exp(-0.5 * lai / math.cos(math.radians(57.5)))
    assert lm.hinge_lai(p) == pytest.approx(lai, rel=1e-12)
    t = math.radians(57.5)
    for law in ("horizontal", "vertical"):  # G(57.5°) = 0.537: the method's 7 % error
        pl = math.exp(-G_LAWS[law](t) * lai / math.cos(t))
        assert lm.hinge_lai(pl) == pytest.approx(lai, rel=0.08)


def test_lang_xiang_values():
    rings = [(0, 10), (10, 20)]
    same = lm.lang_xiang(rings, np.full((2, 8), 0.3))
    assert same.omega == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(same.omega_ring, 1.0)
    two = lm.lang_xiang(rings, [[0.1, 0.9], [0.1, 0.9]])
    expect = math.log(0.5) / (0.5 * (math.log(0.1) + math.log(0.9)))
    np.testing.assert_allclose(two.omega_ring, expect, rtol=1e-12)
    assert two.omega == pytest.approx(expect, rel=1e-12)
    assert two.lai_effective == pytest.approx(two.lai_lx * two.omega, rel=1e-12)


def test_lang_xiang_poisson_sectors_is_one():
    p = np.repeat(poisson_p(HEMISPHER_RINGS, 3.0)[:, None], 16, axis=1)
    res = lm.lang_xiang(HEMISPHER_RINGS, p)
    assert res.omega == pytest.approx(1.0, abs=1e-12)
    assert res.lai_lx == pytest.approx(3.0, rel=1e-12)


def test_zero_gap_floors():
    p, n = lm.floor_gap_fraction([0.0, 0.5], [0.0, 60.0], zero_gap="pai_sat")
    assert n == 1 and p[0] == pytest.approx(math.exp(-5.0)) and p[1] == 0.5
    p, n = lm.floor_gap_fraction([[0.0, 0.2]], zero_gap="pixel", n_pixels=[[400, 400]])
    assert n == 1 and p[0, 0] == pytest.approx(1 / 400)
    with pytest.raises(ConfigError, match="zero_gap"):
        lm.floor_gap_fraction([0.0], [10.0], zero_gap="raise")
    with pytest.raises(ConfigError, match="n_pixels"):
        lm.floor_gap_fraction([0.0], zero_gap="pixel")
    # A closed ring reads the saturating PAI's gap fraction: Miller returns PAI_sat there.
    assert lm.miller_lai([(50, 60)], [0.0]) == pytest.approx(lm.PAI_SAT, rel=1e-12)
    assert lm.miller_lai([(50, 60)], [0.0], zero_gap="pixel", n_pixels=[1000]) == pytest.approx(
        -2 * math.log(1e-3) * math.cos(math.radians(55)), rel=1e-12)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="zenith_bounds_deg"):
        lm.miller_lai([(10, 5)], [0.5])
    with pytest.raises(ConfigError, match="gap_fraction"):
        lm.miller_lai([(0, 10)], [1.5])
    with pytest.raises(ConfigError, match="gap_fraction"):
        lm.miller_lai([(0, 10), (10, 20)], [0.5])
    with pytest.raises(ConfigError, match="wood_to_total"):
        lm.true_lai(1.0, 1.0, wood_to_total=1.0)


def test_true_lai_and_nilson():
    assert lm.true_lai(3.0, 0.75, wood_to_total=0.2) == pytest.approx(0.8 * 3.0 / 0.75)
    z = np.array([10.0, 40.0, 65.0])
    p = np.exp(-0.5 * 0.8 * 2.0 / np.cos(np.radians(z)))
    np.testing.assert_allclose(lm.nilson_clumping(z, p, 0.5, 2.0), 0.8, rtol=1e-12)


# ------------------------------------------------------------------- Chen–Cihlar
def boolean_transect(rng, length, density, width, clusters=None):
    """Gap lengths of a 1-D Boolean model: segments of ``width`` with starts at rate ``density``.

    With ``clusters=(n_per_cluster, spread)`` the starts are grouped (Neyman–Scott).
    """
    if clusters is None:
        starts = rng.uniform(0, length, rng.poisson(density * length))
    else:
        k, spread = clusters
        parents = rng.uniform(0, length, rng.poisson(density * length / k))
        starts = (parents[:, None] + rng.uniform(0, spread, (len(parents), k))).ravel() % length
    s = np.sort(starts)
    ends = np.maximum.accumulate(s + width)
    gaps = s[1:] - ends[:-1]
    lead = s[0] + max(0.0, length - (ends[-1] - length)) - length if ends[-1] > length else s[0]
    out = np.r_[gaps[gaps > 0], lead, max(0.0, length - ends[-1])]
    return out[out > 0]


def test_random_line_gap_distribution_matches_theory():
    rng = np.random.default_rng(3)
    lp, w, t = 1.2, 10.0, 2e6
    lam = boolean_transect(rng, t, lp / w, w)
    at = np.array([0.0, 5.0, 10.0, 20.0])
    np.testing.assert_allclose(lm.accumulated_gap_fraction(lam, t, at),
                               lm.random_gap_fraction(at, lp, w), rtol=0.03)
    np.testing.assert_allclose(lm.probe_probability(lam, t, at),
                               np.exp(-lp * (1 + at / w)), rtol=0.03)


def test_chen_cihlar_random_and_clumped():
    rng = np.random.default_rng(5)
    lp, w, t = 1.0, 10.0, 2e6
    rnd = lm.chen_cihlar(boolean_transect(rng, t, lp / w, w), t, element_width=w)
    assert rnd.omega == pytest.approx(1.0, abs=0.01)
    est = lm.chen_cihlar(boolean_transect(rng, t, lp / w, w), t)  # W_p from probes
    assert est.wp == pytest.approx(w, rel=0.05) and est.omega == pytest.approx(1.0, abs=0.02)
    lam = boolean_transect(rng, t, lp / w, w, clusters=(8, 80.0))
    clumped = lm.chen_cihlar(lam, t, element_width=w)
    # Nilson's Ω of this line is −ln F_m(0)/L_p = 0.67; gap removal finds 0.75 (0.59 with
    # LeafAreaIndex.jl's F(λ) < 1e-3 rule): it sees the clumping, not all of it.
    assert -math.log(lam.sum() / t) / lp == pytest.approx(0.67, abs=0.02)
    assert 0.6 < clumped.omega < 0.85 and clumped.n_removed > 0 and clumped.converged
    frac = lm.chen_cihlar(lam, t, element_width=w, removal="fraction")
    assert 0.5 < frac.omega < clumped.omega
    with pytest.raises(ConfigError, match="removal"):
        lm.chen_cihlar(lam, t, element_width=w, removal="largest")


def test_projected_element_width():
    sq = np.array([[[0, 0, 1], [0.1, 0, 1], [0.1, 0.1, 1]], [[0, 0, 1], [0.1, 0.1, 1], [0, 0.1, 1]]])
    assert lm.projected_element_width(sq[None], 0.0, 0.0, 0.0) == pytest.approx(0.1)
    # Sun at 60° toward +x stretches the horizontal square's shadow along x by nothing
    # (a flat horizontal leaf's shadow keeps its shape), whatever the transect.
    assert lm.projected_element_width(sq[None], 60.0, 0.0, 90.0) == pytest.approx(0.1)


def test_gap_lengths_runs():
    np.testing.assert_array_equal(lm.gap_lengths([1, 1, 0, 1, 0, 0, 1, 1, 1]), [2, 1, 3])
    assert lm.gap_lengths([]).size == 0


# ------------------------------------------------------------------------ LAI-2200
def test_lai2200_weights_follow_the_manuals_formula():
    t = np.radians(li.RING_CENTRES_DEG)
    dt = np.asarray(li.RING_WIDTHS_DEG)
    w = np.sin(t) * dt
    np.testing.assert_allclose(w / w.sum(), li.LAI_WEIGHTS, atol=1.5e-3)
    wd = np.sin(t) * np.cos(t) * dt
    np.testing.assert_allclose(wd / wd.sum() / 2, li.DIFN_WEIGHTS, atol=1e-3)
    assert sum(li.LAI_WEIGHTS) == pytest.approx(1.0, abs=1e-12)
    for (lo, hi), c in zip(li.RING_BOUNDS_DEG, li.RING_CENTRES_DEG):
        assert lo < c < hi


@pytest.mark.parametrize("masked", [(), (5,), (1, 5)])
def test_lai2200_poisson(masked):
    lai = 3.0
    p = poisson_p(li.RING_BOUNDS_DEG, lai)
    t = np.exp(-0.5 * lai / np.cos(np.radians(li.RING_CENTRES_DEG)))
    above = np.full((4, 5), 1234.0)
    res = li.lai2200(above * t, above, masked_rings=masked)
    assert res.lai == pytest.approx(lai, rel=1e-12)
    assert res.acf == pytest.approx(1.0, abs=1e-12)
    assert res.weights.sum() == pytest.approx(1.0)
    assert np.isnan(res.contact_number[[m - 1 for m in masked]]).all()
    np.testing.assert_allclose(res.avg_trans, t)
    del p


def test_lai2200_acf_and_difn():
    t1 = np.full(5, 0.1)
    t2 = np.full(5, 0.9)
    res = li.lai2200(np.stack([t1, t2]))
    s = np.asarray(li.PATH_LENGTHS)
    w = np.asarray(li.LAI_WEIGHTS)
    lai = 2 * np.sum(w * -(np.log(0.1) + np.log(0.9)) / 2 / s)
    assert res.lai == pytest.approx(lai, rel=1e-12)
    assert res.acf == pytest.approx(2 * np.sum(w * -np.log(0.5) / s) / lai, rel=1e-12)
    assert res.lai_effective == pytest.approx(res.lai * res.acf)
    assert res.difn == pytest.approx(0.5, rel=1e-12)
    assert li.lai2200(np.ones((1, 5))).difn == pytest.approx(1.0)
    with pytest.raises(ConfigError, match="masked_rings"):
        li.lai2200(np.ones((1, 5)), masked_rings=(6,))
    with pytest.raises(ConfigError, match="below"):
        li.lai2200(np.ones((1, 4)))


def test_view_caps_select_azimuths():
    az = np.arange(8) * 45.0 + 22.5
    assert li.cap_mask(az, 90, 0).tolist() == [True] + [False] * 6 + [True]
    assert li.cap_mask(az, 180, 90).sum() == 4
    assert li.cap_mask(az, 270, 0).sum() == 6
    assert li.cap_mask(az, 360).all()
    gaps = np.tile(np.arange(8) / 10.0, (5, 1))
    t = li.ring_transmittance(gaps, az, view_cap_deg=90, heading_deg=0)
    np.testing.assert_allclose(t, 0.35)
    t45 = li.ring_transmittance(gaps, az, view_cap_deg=45, heading_deg=100)
    np.testing.assert_allclose(t45, 0.2)  # the sector centred at 112.5° is nearest
    np.testing.assert_allclose(li.ring_transmittance(np.stack([gaps, gaps]), az), 0.35)


def test_table_methods_on_a_poisson_table():
    rings = np.array([[0, 15], [15, 30], [30, 45], [45, 60], [60, 75]], float)
    p = np.repeat(poisson_p(rings, 2.0)[:, None], 8, axis=1)
    out = lm.table_methods(rings, p, np.full(p.shape, 500))
    assert out["miller"] == pytest.approx(2.0, rel=1e-12)
    assert out["omega_lx"] == pytest.approx(1.0) and out["lai_lx"] == pytest.approx(2.0)
    # The 45–60° ring holds 57.5°; its centre (52.5°) is the zenith used.
    assert out["hinge_57"] == pytest.approx(2.0, rel=1e-12)
    assert math.isnan(lm.table_methods(rings[:3], p[:3])["hinge_57"])
    closed = p.copy()
    closed[0, 0] = 0.0
    with_pixel = lm.table_methods(rings, closed, np.full(p.shape, 500), zero_gap="pixel")
    assert with_pixel["omega_lx"] < 1.0
