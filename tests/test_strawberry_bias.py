"""Issue 33: the strawberry comparison's readings and uncertainty.

* the extraction follows Table 4's real leaf areas by default (1/6 steps an option);
* the petiole reading is the paper's hemisphere (θ = 65 ± 45° the petiole zenith, φ = 45 ± 5.6°
  the divergence), whose petiole zeniths and azimuth steps follow those laws;
* ``compare``'s bias interval (t, Welch–Satterthwaite) against a hand computation, its bootstrap
  intervals' limits, and the manifest's measured-spread columns.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from simlidar_mi.canopy.compare import Pair, _stats_row, bias_interval
from simlidar_mi.canopy.manifest import ManifestError, ManifestRow, read_manifest
from simlidar_mi.plants.strawberry import StrawberryPlotParams, strawberry_plant, strawberry_plot
from simlidar_mi.plants.strawberry_extraction import (PAPER_EXTRACTION_FRACTIONS, PAPER_TABLE4_REAL_M2,
                                                      extraction_steps, fraction_counts,
                                                      table4_fractions)
from simlidar_mi.plants.strawberry_leaf import StrawberryLeafParams, draw_leaf_traits

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------- extraction
def test_default_extraction_shares_reproduce_table4_real_leaf_areas():
    """Table 4, real canopy: 1.116, 0.900, 0.724, 0.527 m².  The default shares, removed from
    the start, give those areas back exactly (1.116·(1 − Σ f)), i.e. 0.806 / 0.649 / 0.472 of
    the first, not the text's 5/6, 4/6, 3/6 (the old default)."""
    f = PAPER_EXTRACTION_FRACTIONS
    assert f == table4_fractions(PAPER_TABLE4_REAL_M2)
    assert PAPER_TABLE4_REAL_M2 == (1.116, 0.900, 0.724, 0.527)
    left = 1.116 * (1 - np.cumsum(f))
    np.testing.assert_allclose(left, (0.900, 0.724, 0.527), atol=1e-12)
    np.testing.assert_allclose(1 - np.cumsum(f), (0.806452, 0.648746, 0.472222), atol=1e-6)
    assert abs(f[0] - 1 / 6) > 0.02  # not sixths
    # Leaf counts on a plot: after step k exactly round(n0·Σf) leaves are gone.
    n0 = 682
    gone = np.cumsum(fraction_counts(n0, f))
    assert list(gone) == [math.floor(n0 * x + 0.5) for x in np.cumsum(f)] == [132, 240, 360]


def test_default_extraction_leaf_area_follows_table4_in_expectation():
    """Leaves are removed by count; leaf area falls by Table 4's shares in expectation (each
    step's survivors are a uniform random subset).  Mean over K = 100 extraction seeds of one
    plot within 4·SD/√K + 1/n0 of 0.806 / 0.649 / 0.472."""
    plot = strawberry_plot(StrawberryPlotParams(rows=2, plants_per_row=3), seed=11)
    n0, a0 = plot.n_leaves, plot.leaf_area_m2
    ratio = np.array([[s.leaf_area_m2 / a0 for s in extraction_steps(plot, seed=k)[1:]]
                      for k in range(100)])
    want = np.asarray(PAPER_TABLE4_REAL_M2[1:]) / PAPER_TABLE4_REAL_M2[0]
    tol = 4 * ratio.std(0, ddof=1) / math.sqrt(len(ratio)) + 1 / n0
    assert np.all(np.abs(ratio.mean(0) - want) < tol), (ratio.mean(0), want)
    # the area at 1 m² of Table 4's full real canopy, followed step by step
    np.testing.assert_allclose(1.116 * ratio.mean(0), (0.900, 0.724, 0.527), atol=1.116 * tol.max())


# --------------------------------------------------------------------- geometry
def test_default_petiole_zenith_is_the_papers_hemisphere():
    """Default: θ = π/2.769 ± π/4 (65.0 ± 45°) is the petiole zenith, truncated to (0°, 90°):
    mean 50.76°, SD 23.92°, 22.6 % of the petioles within 30° of the vertical (analytic
    truncated normal), measured on the meshes (petiole tip = the leaves' shared base corner).
    Azimuth steps between consecutive leaves follow φ = π/4 ± π/32 (45 ± 5.625°)."""
    p = StrawberryLeafParams()
    assert p.petiole_zenith == "theta"
    law = stats.truncnorm((0 - 65.0) / 45, (90 - 65.0) / 45, loc=180 / 2.769, scale=45)
    rng = np.random.default_rng(33)
    tips, steps = [], []
    for k in range(300):  # 300 plants of 42 leaves
        plant = strawberry_plant(p, 42, rng)
        tip = plant.vertices.reshape(42, 12, 3, 3)[:, 0, 0]
        tips.append(tip)
    tips = np.concatenate(tips)
    zen = np.degrees(np.arccos(tips[:, 2] / np.linalg.norm(tips, axis=1)))
    n = len(zen)
    assert abs(zen.mean() - law.mean()) < 4 * law.std() / math.sqrt(n)
    assert law.mean() == pytest.approx(50.76, abs=0.01) and law.std() == pytest.approx(23.92, abs=0.01)
    assert abs(zen.std() - law.std()) < 0.5
    assert abs(np.mean(zen < 30) - law.cdf(30)) < 4 * math.sqrt(law.cdf(30) * (1 - law.cdf(30)) / n)
    # The old reading (φ the zenith) is a cone: SD 5.6°, nothing within 30° of the vertical.
    old = draw_leaf_traits(StrawberryLeafParams(petiole_zenith="phi"), rng, 5000).zenith_deg
    assert abs(old.std() - 5.625) < 0.3 and np.mean(old < 30) < 0.01
    # Divergence: φ's law, from the drawn azimuths of one plant's consecutive leaves.
    t = [draw_leaf_traits(p, rng, 42) for _ in range(200)]
    d = np.concatenate([(np.diff(x.azimuth_deg) + 180) % 360 - 180 for x in t])
    assert abs(d.mean() - 45.0) < 4 * 5.625 / math.sqrt(len(d))
    assert abs(d.std() - 5.625) < 0.2


# ------------------------------------------------------------------ uncertainty
def test_bias_interval_against_a_hand_computation():
    """Two pairs of one scene (4 replicate plots), the second measured as the mean of 3 photos
    with SD 0.02:
      bias = (0.21 + 0.31)/2 − (0.25 + 0.35)/2 = −0.04;
      per-plot sums 0.50, 0.55, 0.47, 0.56: variance (ddof 1) 0.0054/3 = 0.0018,
        plot-to-plot part 0.0018/4/2² = 1.125e-4 (df 3);
      photo-to-photo part 0.02²/3/2² = 3.3333e-5 (df 2);
      se = √1.458333e-4 = 0.0120761; df = (1.458333e-4)² / ((1.125e-4)²/3 + (3.3333e-5)²/2)
         = 4.45455;  t_0.975(4.45455) · se = half-width."""
    v = [[0.20, 0.22, 0.18, 0.24], [0.30, 0.33, 0.29, 0.32]]
    got = bias_interval(v, ["a", "a"], [0.25, 0.35], [None, 0.02], [None, 3])
    var = 0.0018 / 4 / 4 + 0.02 ** 2 / 3 / 4
    df = var ** 2 / ((0.0018 / 16) ** 2 / 3 + (0.0004 / 12) ** 2 / 2)
    assert got["bias"] == pytest.approx(-0.04, abs=1e-15)
    assert got["se"] == pytest.approx(math.sqrt(var), rel=1e-12) == pytest.approx(0.0120761, abs=1e-7)
    assert got["df"] == pytest.approx(df, rel=1e-12) == pytest.approx(4.45455, abs=1e-5)
    half = stats.t.ppf(0.975, df) * math.sqrt(var)
    assert (got["low"], got["high"]) == pytest.approx((-0.04 - half, -0.04 + half), abs=1e-14)
    # Independent scenes: each its own plot-to-plot part, no measured spread: df = 3 + 3 by
    # Welch–Satterthwaite with equal parts.
    ind = bias_interval(v, ["a", "b"], [0.25, 0.35], [None, None], [None, None])
    c1, c2 = np.var(v[0], ddof=1) / 4 / 4, np.var(v[1], ddof=1) / 4 / 4
    assert ind["se"] == pytest.approx(math.sqrt(c1 + c2), rel=1e-12)
    assert ind["df"] == pytest.approx((c1 + c2) ** 2 / (c1 ** 2 / 3 + c2 ** 2 / 3), rel=1e-12)
    # One replicate and no measured spread: no interval.
    assert math.isnan(bias_interval([[0.2]], ["a"], [0.25], [None], [None])["low"])


def _pair(z, p0_m, reps, sd=None, n=None, scene="s.toml"):
    row = ManifestRow(2, Path(scene), "perspective", z, None, None, "", None, p0_m,
                      p0_measured_sd=sd, n_measured=n)
    return Pair(row, p0_m, float(np.mean(reps)), 1.0, None, float(np.std(reps, ddof=1)),
                len(reps), tuple(reps))


def test_stats_row_intervals_and_verdict():
    """One pair: RMSE = |bias|, its bootstrap interval lies inside |the bias's range of
    replicate means|; replicates without spread collapse every interval onto the value; a
    manifest row with n_measured only takes the virtual plots' SD as the measured stand-in."""
    reps = [0.20, 0.22, 0.18, 0.24, 0.21, 0.19]
    st = _stats_row(0.0, [_pair(0.0, 0.27, reps)])
    ci = bias_interval([reps], ["s"], [0.27], [None], [None])
    assert (st["bias_ci_low"], st["bias_ci_high"]) == (ci["low"], ci["high"])
    assert st["bias_inside_ci"] == "no" and st["ci_basis"].startswith("plots")
    assert min(reps) <= 0.27 - st["rmse_ci_high"] <= 0.27 - st["rmse_ci_low"] <= max(reps)
    assert math.isnan(st["r"]) and math.isnan(st["r_ci_low"])  # one pair per zenith
    flat = _stats_row(0.0, [_pair(0.0, 0.25, [0.2] * 5)])
    assert flat["rmse_ci_low"] == pytest.approx(0.05) and flat["rmse_ci_high"] == pytest.approx(0.05)
    # stand-in: n_measured = 3, no SD: the measured part is sd_plot²/3 with df 2
    stand = _stats_row(0.0, [_pair(0.0, 0.23, reps, n=3)])
    sd = np.std(reps, ddof=1)
    var = sd ** 2 / 6 + sd ** 2 / 3
    assert stand["bias_ci_high"] - stand["bias"] == pytest.approx(
        stats.t.ppf(0.975, var ** 2 / ((sd ** 2 / 6) ** 2 / 5 + (sd ** 2 / 3) ** 2 / 2)) * math.sqrt(var),
        rel=1e-12)
    assert "stand-in" in stand["ci_basis"] and stand["bias_inside_ci"] == "yes"
    # r per zenith across steps: computed once a zenith has two rows
    two = _stats_row(0.0, [_pair(0.0, 0.15, [0.12, 0.14, 0.13]), _pair(0.0, 0.40, [0.33, 0.35, 0.34])])
    assert two["r"] == pytest.approx(1.0) and two["r_ci_low"] == pytest.approx(1.0)


def test_manifest_measured_spread_columns(tmp_path):
    (tmp_path / "s.toml").write_text("[scene]\n")
    head = "scene,camera,zenith_deg,step,p0_measured,p0_measured_sd,n_measured\n"

    def rows(line):
        (tmp_path / "m.csv").write_text(head + line + "\n")
        return read_manifest(tmp_path / "m.csv")
    r = rows("s.toml,perspective,0,0,0.2,0.03,3")[0]
    assert (r.p0_measured_sd, r.n_measured) == (0.03, 3)
    assert rows("s.toml,perspective,0,0,0.2,,3")[0].p0_measured_sd is None
    for line, col in (("s.toml,perspective,0,0,0.2,0.03,", "n_measured"),
                      ("s.toml,perspective,0,0,0.2,0.03,1", "n_measured"),
                      ("s.toml,perspective,0,0,0.2,x,3", "p0_measured_sd"),
                      ("s.toml,perspective,0,0,0.2,,2.5", "n_measured")):
        with pytest.raises(ManifestError) as e:
            rows(line)
        assert e.value.column == col and "m.csv" in str(e.value) and "row 2" in str(e.value)
    shipped = read_manifest(REPO / "scenes" / "strawberry_manifest.csv")
    assert [(x.n_measured, x.p0_measured_sd) for x in shipped] == [(3, None)] * 3
