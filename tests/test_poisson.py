"""Inhomogeneous Poisson tree placement: counts, positions, distance thinning, validation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist

from simlidar_mi.errors import ConfigError
from simlidar_mi.forest.placement import (Bump, Domain, SpeciesIntensity, expected_count,
                                        intensity_grid, place_trees, sample_ipp,
                                        thin_min_distance)

DOMAIN = Domain(0.0, 100.0, 0.0, 80.0)
OAK = SpeciesIntensity("oak", [Bump(0.04, 30.0, 40.0, 300.0, 150.0)])
# two bumps, one centred outside the domain, plus a background
PINE = SpeciesIntensity("pine", [Bump(0.02, 90.0, 10.0, 500.0, 800.0),
                                 Bump(0.015, 120.0, 60.0, 400.0, 400.0)],
                        background_per_m2=0.002)
SPECIES = [OAK, PINE]
N_SEEDS = 400


def poisson_count_check(counts: np.ndarray, mu: float) -> tuple[bool, str]:
    """Counts over independent runs look Poisson(mu): mean within 4 SE, dispersion ≈ 1.

    The dispersion statistic Σ(n_i − n̄)²/n̄ is χ²(k − 1) for Poisson counts;
    it is accepted inside the central 99.9 % of that law.
    """
    k = len(counts)
    mean = counts.mean()
    se = math.sqrt(mu / k)
    disp = ((counts - mean) ** 2).sum() / mean
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], k - 1)
    ok = abs(mean - mu) < 4 * se and lo < disp < hi
    return ok, f"mean {mean:.3f} vs {mu:.3f} (SE {se:.3f}), dispersion {disp / (k - 1):.3f}"


@pytest.fixture(scope="module")
def runs():
    """place_trees over many seeds, with and without the distance step."""
    with_dmin = [place_trees(SPECIES, DOMAIN, 2.5, np.random.default_rng(s))
                 for s in range(N_SEEDS)]
    without = [place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(10_000 + s))
               for s in range(N_SEEDS)]
    return with_dmin, without


def test_expected_count_matches_numerical_integration():
    cases = [
        (OAK, DOMAIN),
        (PINE, DOMAIN),
        (PINE, (20.0, 35.0, 50.0, 52.5)),      # a small sub-rectangle
        # centre far left and above: both erf arguments in one tail (erfc branch)
        (SpeciesIntensity("tail", [Bump(1.0, -30.0, 120.0, 100.0, 200.0)]), DOMAIN),
    ]
    for sp, dom in cases:
        d = Domain.of(dom)
        num, _ = integrate.dblquad(lambda y, x: float(sp.intensity(x, y)),
                                   d.x_min_m, d.x_max_m, d.y_min_m, d.y_max_m,
                                   epsabs=0, epsrel=1e-11)
        assert expected_count(sp, dom) == pytest.approx(num, rel=1e-8), sp.name
    np.testing.assert_allclose(expected_count(SPECIES, DOMAIN),
                               [expected_count(OAK, DOMAIN), expected_count(PINE, DOMAIN)])


def test_upper_bound_bounds_the_intensity():
    x, y, lam = intensity_grid(SPECIES, DOMAIN, 401, 321)
    assert x.shape == (401,) and y.shape == (321,) and lam.shape == (2, 321, 401)
    np.testing.assert_allclose(lam[1, 7, 11], PINE.intensity(x[11], y[7]))
    for sp, grid in zip(SPECIES, lam):
        assert grid.max() <= sp.upper_bound(DOMAIN)
    # exact for a single bump centred in the domain
    assert OAK.upper_bound(DOMAIN) == 0.04
    assert lam[0].max() == pytest.approx(0.04, rel=1e-12)
    # a bump centred outside contributes its maximum over D, not its peak
    assert PINE.upper_bound(DOMAIN) == pytest.approx(
        0.002 + 0.02 + 0.015 * math.exp(-20.0 ** 2 / 400.0))


def test_counts_before_distance_step_are_poisson(runs):
    with_dmin, _ = runs
    counts = np.array([p.count_before for p in with_dmin])
    for i, sp in enumerate(SPECIES):
        ok, why = poisson_count_check(counts[:, i], expected_count(sp, DOMAIN))
        assert ok, f"{sp.name}: {why}"


def test_buggy_acceptance_rule_would_be_caught():
    """The published code keeps a candidate with probability λ(s), not λ(s)/λ*."""
    def buggy_count(sp: SpeciesIntensity, rng: np.random.Generator) -> int:
        lam_max = sp.upper_bound(DOMAIN)
        n = rng.poisson(lam_max * DOMAIN.area_m2)
        x = rng.uniform(DOMAIN.x_min_m, DOMAIN.x_max_m, n)
        y = rng.uniform(DOMAIN.y_min_m, DOMAIN.y_max_m, n)
        return int((rng.uniform(size=n) < sp.intensity(x, y)).sum())

    for sp in SPECIES:
        mu = expected_count(sp, DOMAIN)
        # with λ < 1 tree/m² the bug yields intensity λ*·λ(s), mean λ*·∫λ
        mu_bug = sp.upper_bound(DOMAIN) * mu
        assert abs(mu_bug - mu) > 20 * math.sqrt(mu / N_SEEDS)
        counts = np.array([buggy_count(sp, np.random.default_rng(s)) for s in range(N_SEEDS)])
        assert counts.mean() == pytest.approx(mu_bug, abs=5 * math.sqrt(mu_bug / N_SEEDS))
        assert not poisson_count_check(counts, mu)[0]


def test_binned_positions_follow_the_intensity(runs):
    _, without = runs
    xe = np.linspace(DOMAIN.x_min_m, DOMAIN.x_max_m, 9)
    ye = np.linspace(DOMAIN.y_min_m, DOMAIN.y_max_m, 9)
    for i, sp in enumerate(SPECIES):
        x = np.concatenate([p.x_m[p.species == i] for p in without])
        y = np.concatenate([p.y_m[p.species == i] for p in without])
        observed, _, _ = np.histogram2d(x, y, bins=[xe, ye])
        expected = N_SEEDS * np.array([[expected_count(sp, (xe[a], xe[a + 1], ye[b], ye[b + 1]))
                                        for b in range(8)] for a in range(8)])
        assert expected.sum() == pytest.approx(N_SEEDS * expected_count(sp, DOMAIN))
        # bin counts pooled over independent runs are independent Poisson variables;
        # sparse bins are lumped so each cell expects at least 5
        small = expected < 5
        obs = np.append(observed[~small], observed[small].sum())
        exp = np.append(expected[~small], expected[small].sum())
        if exp[-1] == 0:
            obs, exp = obs[:-1], exp[:-1]
        stat = ((obs - exp) ** 2 / exp).sum()
        p = stats.chi2.sf(stat, len(exp))
        assert p > 0.001, f"{sp.name}: chi2 {stat:.1f} on {len(exp)} cells, p = {p:.2g}"


def test_minimum_distance_holds(runs):
    with_dmin, without = runs
    removed = 0
    for p in with_dmin:
        if len(p) > 1:
            assert pdist(np.column_stack([p.x_m, p.y_m])).min() > 2.5
        np.testing.assert_array_equal(np.bincount(p.species, minlength=2), p.count_after)
        removed += p.removed.sum()
    assert removed > 0                          # the step did something
    assert all(p.removed.sum() == 0 for p in without)


def test_distance_thinning_rule():
    rng = np.random.default_rng(5)
    x, y = rng.uniform(0, 50, 1500), rng.uniform(0, 50, 1500)
    keep = thin_min_distance(x, y, 3.0, np.random.default_rng(6))
    pts = np.column_stack([x, y])
    assert 0 < keep.sum() < len(x)
    assert pdist(pts[keep]).min() > 3.0
    # maximal: every dropped point has a kept point within the distance
    dist, _ = cKDTree(pts[keep]).query(pts[~keep])
    assert (dist <= 3.0).all()
    np.testing.assert_array_equal(keep, thin_min_distance(x, y, 3.0, np.random.default_rng(6)))
    assert thin_min_distance(x, y, 0.0, rng).all()


def test_same_seed_same_forest_and_stable_streams():
    a = place_trees(SPECIES, DOMAIN, 2.0, np.random.default_rng(42))
    b = place_trees(SPECIES, DOMAIN, 2.0, np.random.default_rng(42))
    c = place_trees(SPECIES, DOMAIN, 2.0, np.random.default_rng(43))
    for f in ("x_m", "y_m", "species", "count_before", "removed"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert a.x_m.tobytes() == b.x_m.tobytes()
    assert len(a.x_m) != len(c.x_m) or not np.array_equal(a.x_m, c.x_m)
    # appending a species leaves the earlier species' Poisson points unchanged
    one = place_trees([OAK], DOMAIN, 0.0, np.random.default_rng(7))
    two = place_trees([OAK, PINE], DOMAIN, 0.0, np.random.default_rng(7))
    np.testing.assert_array_equal(one.x_m, two.x_m[two.species == 0])
    assert a.species_names == ("oak", "pine") and a.species.dtype == np.int32


def test_sample_ipp_single_species_and_degenerate_cases():
    x, y = sample_ipp(OAK, (0, 100, 0, 80), np.random.default_rng(0))
    assert len(x) == len(y) > 0
    assert (x >= 0).all() and (x <= 100).all() and (y >= 0).all() and (y <= 80).all()
    empty = SpeciesIntensity("none", [Bump(0.0, 0, 0, 1, 1)])
    assert len(sample_ipp(empty, DOMAIN, np.random.default_rng(0))[0]) == 0
    p = place_trees([], DOMAIN, 1.0, np.random.default_rng(0))
    assert len(p) == 0 and p.count_before.shape == (0,)


@pytest.mark.parametrize("make, key, value", [
    (lambda: Bump(-0.1, 0, 0, 1, 1), "Bump.C_per_m2", -0.1),
    (lambda: Bump(0.1, 0, 0, 0, 1), "Bump.h_m2", 0.0),
    (lambda: Bump(0.1, 0, 0, 1, -2), "Bump.l_m2", -2.0),
    (lambda: Bump(0.1, float("nan"), 0, 1, 1), "Bump.x0_m", float("nan")),
    (lambda: Bump(float("inf"), 0, 0, 1, 1), "Bump.C_per_m2", float("inf")),
    (lambda: Bump("a", 0, 0, 1, 1), "Bump.C_per_m2", "a"),
    (lambda: SpeciesIntensity("x", [], background_per_m2=-1), "x.background_per_m2", -1.0),
    (lambda: SpeciesIntensity("", []), "species.name", ""),
    (lambda: SpeciesIntensity("x", [(1, 2, 3, 4, 5)]), "x.bumps[0]", (1, 2, 3, 4, 5)),
    (lambda: Domain(0, 0, 0, 1), "domain.x_max_m", 0.0),
    (lambda: Domain(0, 1, 5, 2), "domain.y_max_m", 2.0),
    (lambda: Domain(0, float("nan"), 0, 1), "domain.x_max_m", float("nan")),
    (lambda: Domain.of((0, 1, 0)), "domain", (0, 1, 0)),
    (lambda: place_trees([OAK], DOMAIN, -1.0, np.random.default_rng(0)), "min_distance_m",
     -1.0),
    (lambda: place_trees([OAK], DOMAIN, 1.0, 42), "rng", 42),
    (lambda: place_trees([OAK], (0, 10, 3, 3), 1.0, np.random.default_rng(0)),
     "domain.y_max_m", 3.0),
    (lambda: sample_ipp(SpeciesIntensity("dense", [], 1e3), (0, 1e3, 0, 1e3),
                        np.random.default_rng(0)), "dense.bumps", 1e3),
])
def test_bad_parameters_name_key_and_value(make, key, value):
    with pytest.raises(ConfigError) as exc:
        make()
    assert exc.value.key == key
    v = exc.value.value
    assert v == value or (isinstance(v, float) and math.isnan(v) and math.isnan(value))
    assert key in str(exc.value)


# --- what the intensity counts: the Poisson points (the paper's reading) or the final stand ---

def crowns(x, y, j, idx):
    """Crown radii by species (oak 3.5 m, pine 2.5 m) for the crown rule."""
    return np.full(len(idx), (3.5, 2.5)[j])


@pytest.fixture(scope="module")
def crowned():
    """The crown-aware thinning (k = 0.65) over many seeds, in both count modes."""
    return {mode: [place_trees(SPECIES, DOMAIN, 2.0, np.random.default_rng(20_000 + s),
                               crown_radius=crowns, crown_factor=0.65, count=mode)
                   for s in range(N_SEEDS)] for mode in ("poisson", "stand")}


def test_stand_count_is_the_requested_poisson_count_after_crown_thinning(crowned):
    mu = expected_count(SPECIES, DOMAIN)
    stand = np.array([p.count_after for p in crowned["stand"]])
    for j in range(2):
        ok, msg = poisson_count_check(stand[:, j], mu[j])
        assert ok, f"stand {SPECIES[j].name}: {msg}"
    assert all(p.reached.all() and p.count_mode == ("stand", "stand") for p in crowned["stand"])
    np.testing.assert_array_equal(stand, np.array([p.target for p in crowned["stand"]]))
    # more candidates than the Poisson process: C is solved upwards by the factor T > 1
    factor = np.array([p.candidate_factor for p in crowned["stand"]])
    assert (factor.mean(0) > 1.1).all()
    # the paper's reading: the Poisson count is drawn, the final stand falls short of it
    poisson = crowned["poisson"]
    drawn = np.array([p.count_before for p in poisson])
    for j in range(2):
        ok, msg = poisson_count_check(drawn[:, j], mu[j])
        assert ok, f"poisson {SPECIES[j].name}: {msg}"
    kept = np.array([p.count_after for p in poisson])
    assert (kept.mean(0) < 0.9 * mu).all()
    # the crown rule holds in both modes
    for p in crowned["stand"][:20] + poisson[:20]:
        r = np.array([3.5, 2.5])[p.species]
        i, j = np.triu_indices(len(p), 1)
        d = np.hypot(p.x_m[i] - p.x_m[j], p.y_m[i] - p.y_m[j])
        assert (d > 2.0).all() and (d >= 0.65 * (r[i] + r[j])).all()


def test_both_count_modes_are_the_poisson_process_without_thinning():
    a = place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3), count="poisson")
    b = place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3), count="stand")
    assert a.count_mode == ("poisson",) * 2 and a.removed.sum() == b.removed.sum() == 0
    # the default is the paper's count, with or without a crown rule (issue 30)
    assert place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3)).count_mode == ("poisson",) * 2
    assert place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3), crown_radius=crowns,
                       crown_factor=0.5).count_mode == ("poisson",) * 2
    # auto: "stand" with a crown rule, "poisson" without
    assert place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3), count="auto").count_mode == ("poisson",) * 2
    assert place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(3), crown_radius=crowns,
                       crown_factor=0.5, count="auto").count_mode == ("stand",) * 2
    # the stand keeps the candidates in arrival order until its target: a prefix of the stream
    np.testing.assert_array_equal(b.candidate[b.species == 0], np.arange(b.count_after[0]))


def test_a_stand_the_crowns_cannot_hold_is_reported_short():
    dense = SpeciesIntensity("dense", [], 0.05)            # 320 trees on 100 × 80 m of 4 m crowns
    p = place_trees([dense], DOMAIN, 0.0, np.random.default_rng(1), count="stand",
                    crown_radius=lambda x, y, j, i: np.full(len(i), 4.0), crown_factor=1.0,
                    max_candidate_factor=3.0)
    assert not p.reached[0] and p.count_after[0] < p.target[0]
    assert p.candidate_factor[0] == 3.0 and p.count_before[0] > 2 * p.target[0]


def test_bad_count_mode_is_refused_naming_the_species():
    with pytest.raises(ConfigError) as e:
        place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(0), count=["stand", "final"])
    assert e.value.key == "species[1].count" and e.value.value == "final"
    with pytest.raises(ConfigError) as e:
        place_trees(SPECIES, DOMAIN, 0.0, np.random.default_rng(0), max_candidate_factor=0.5)
    assert e.value.key == "max_candidate_factor"
