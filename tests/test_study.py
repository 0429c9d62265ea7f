"""The §5 study: orchards in a grid, resumable rows, regressions through the origin."""
from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar.study import (READINGS, bootstrap_slopes, fit_through_origin, paper_grid,
                                    regression_report, run_study, scan_overrides, with_trunk_distances)
from tests.conftest import SCENES


def test_paper_grid_is_the_full_factorial():
    grid = paper_grid()
    assert len(grid) == 4 * 3 * 2 * 2 * 2
    assert len({tuple(g) for g in grid}) == len(grid)


def test_fit_through_origin_matches_least_squares():
    rng = np.random.default_rng(1)
    x = rng.uniform(0.1, 2, 40)
    y = 3.6 * x + rng.normal(0, 0.2, 40)
    fit = fit_through_origin(x, y)
    slope = np.linalg.lstsq(x[:, None], y, rcond=None)[0][0]
    assert fit["slope"] == pytest.approx(slope, rel=1e-12)
    assert fit["r2"] == pytest.approx(1 - np.sum((y - slope * x) ** 2) / np.sum((y - y.mean()) ** 2))
    assert fit_through_origin(x, 2 * x)["r2"] == pytest.approx(1.0)


def test_small_study_runs_and_resumes(tmp_path):
    grid = [[f"orchard.tree.iterations={it}", "orchard.n_trees=1", "scan.dtheta_deg=1.0",
             "scan.dy_m=0.01", f"orchard.tree.d_min_m={d}"] for it in (4, 5) for d in (0.005, 0.007)]
    out = tmp_path / "study"
    res = run_study(SCENES / "apple_orchard.toml", out, grid)
    assert sorted(p.name for p in out.iterdir()) == ["correlations.png", "regression.json", "rows", "study.csv"]
    assert len(res.rows) == 4
    for r in res.rows:
        # A_L = π·Σdh > A_PR.  No A_IM ≤ A_PR here: under the "any" rule a 1 cm × 1° beam counts
        # whole when one of its 9 points touches a 5 mm twig (see the fraction test below).
        assert 0 < r["A_IM_m2"] and r["A_PR_m2"] < r["A_L_m2"]
        assert r["A_L_m2"] == pytest.approx(np.pi * r["A_PR_m2"])
        # The paper's hit test by default, and eq. 8's near-side limits sweep the wood (eqs. 6-7's
        # Int() may leave less than one of these coarse 1 cm / 1° steps at the ends).
        assert (r["footprint"], r["hit_rule"]) == (2, "any") and r["A_PR_swept_share"] > 0.995
    # Thicker branches (d_m 7 vs 5 mm) scale A_PR by exactly 7/5 with the same seed.
    by = {(r["iterations"], r["d_min_m"]): r for r in res.rows}
    assert by[(4, 0.007)]["A_PR_m2"] == pytest.approx(by[(4, 0.005)]["A_PR_m2"] * 7 / 5)
    reg = json.loads((out / "regression.json").read_text())
    assert reg["scan"] == {"hit_rule": ["any"], "footprint": [2]}
    assert "footprint,hit_rule" in (out / "study.csv").read_text().splitlines()[0]
    assert reg["A_L_vs_A_IM"]["slope"] == pytest.approx(np.pi * reg["A_PR_vs_A_IM"]["slope"])
    # Resume: only the missing row is computed again.
    rows = sorted((out / "rows").iterdir())
    kept_mtime = rows[1].stat().st_mtime_ns
    os.unlink(rows[0])
    again = run_study(SCENES / "apple_orchard.toml", out, grid)
    assert rows[1].stat().st_mtime_ns == kept_mtime and rows[0].exists()
    assert [r["A_IM_m2"] for r in again.rows] == [r["A_IM_m2"] for r in res.rows]


def test_fraction_rule_reproduces_the_old_study_and_reads_lower(tmp_path):
    grid = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01"]]
    any_rule = run_study(SCENES / "apple_orchard.toml", tmp_path / "any", grid).rows[0]
    old = run_study(SCENES / "apple_orchard.toml", tmp_path / "old", grid, hit_rule="fraction").rows[0]
    frac2 = run_study(SCENES / "apple_orchard.toml", tmp_path / "f2", grid, hit_rule="fraction",
                      footprint=2).rows[0]
    assert (old["footprint"], old["hit_rule"]) == (0, "fraction")  # the scene's own P = 0
    assert (frac2["footprint"], frac2["hit_rule"]) == (2, "fraction")
    # Same beams, same wood: only the weighting of partly hit beams differs.
    assert any_rule["N"] == frac2["N"] and any_rule["M"] == frac2["M"]
    assert any_rule["A_IM_m2"] > frac2["A_IM_m2"] > 0
    assert frac2["A_IM_m2"] <= frac2["A_PR_m2"] and old["A_IM_m2"] <= old["A_PR_m2"]  # paper: A_IM ≤ A_PR
    assert scan_overrides() == ['scan.hit_rule="any"', "scan.footprint=2"]
    assert scan_overrides("fraction") == ['scan.hit_rule="fraction"']
    with pytest.raises(ConfigError, match="hit_rule"):
        scan_overrides("all")


def test_bad_base_scene_is_refused_before_any_task(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[scan]\ndy_m = -1\n")
    with pytest.raises(ConfigError, match="scan.dy_m"):
        run_study(bad, tmp_path / "out", [["orchard.n_trees=1"]])
    assert not (tmp_path / "out").exists()


def test_uncentred_r2_and_bootstrap_slopes_against_direct_formulas():
    rng = np.random.default_rng(7)
    x = rng.uniform(0.2, 3, 96)
    y = 1.5 * x + rng.normal(0, 0.3, 96)
    fit = fit_through_origin(x, y)
    res = y - fit["slope"] * x
    assert fit["r2_uncentred"] == pytest.approx(1 - np.sum(res ** 2) / np.sum(y ** 2), rel=1e-12)
    assert fit["r2_uncentred"] > fit["r2"]
    boot = bootstrap_slopes(x, y, n_resamples=500, seed=3)
    # the same draws, directly: 500 × 96 row indices with replacement
    idx = np.random.default_rng(3).integers(0, 96, size=(500, 96))
    slopes = [np.dot(x[i], y[i]) / np.dot(x[i], x[i]) for i in idx]
    assert boot["slope_2.5%"] == pytest.approx(np.percentile(slopes, 2.5), rel=1e-12)
    assert boot["slope_97.5%"] == pytest.approx(np.percentile(slopes, 97.5), rel=1e-12)
    assert boot["slope_2.5%"] < fit["slope"] < boot["slope_97.5%"]
    assert (boot["size"], boot["n_resamples"], boot["seed"]) == (96, 500, 3)
    # Same seed, same interval, bit for bit.
    assert bootstrap_slopes(x, y, n_resamples=500, seed=3) == boot


def test_bootstrap_of_a_42_orchard_study_is_wider_than_subsets_by_the_finite_population_factor():
    """42 of 96 without replacement (the old subset range) understates where a 42-orchard study
    could land by √((96 − 42)/(96 − 1)) = √(54/95) = 0.754; drawing with replacement does not."""
    rng = np.random.default_rng(7)
    x = rng.uniform(0.2, 3, 96)
    y = 1.5 * x * rng.lognormal(0, 0.3, 96)
    boot = bootstrap_slopes(x, y, size=42, n_resamples=20000, seed=1)
    draw = np.random.default_rng(2)
    idx = np.array([draw.choice(96, 42, replace=False) for _ in range(20000)])
    sub = np.sum(x[idx] * y[idx], axis=1) / np.sum(x[idx] ** 2, axis=1)
    width_sub = np.subtract(*np.percentile(sub, [97.5, 2.5]))
    width_boot = boot["slope_97.5%"] - boot["slope_2.5%"]
    assert width_sub / width_boot == pytest.approx(np.sqrt(54 / 95), rel=0.04)
    # Too few rows: no interval rather than a wrong one.
    assert bootstrap_slopes(x[:1], y[:1])["n_resamples"] == 0


def test_trunk_distance_is_a_study_dimension(tmp_path):
    base = ["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01"]
    grid = with_trunk_distances(str(SCENES / "apple_orchard.toml"), [base], [1.5, 2.5])
    # apple_orchard.toml has scan.x0_m = 1: trunks at x = 2.5 (its own placement) and 3.5
    assert grid == [base + ["orchard.row_x_m=2.5"], base + ["orchard.row_x_m=3.5"]]
    res = run_study(SCENES / "apple_orchard.toml", tmp_path / "s", [base], trunk_distances_m=[1.5, 2.5],
                    readings=False)
    near, far = res.rows
    assert (near["trunk_distance_m"], far["trunk_distance_m"]) == (1.5, 2.5)
    # The same tree moved 1 m away: the same wood, a different scan.
    assert near["A_PR_m2"] == pytest.approx(far["A_PR_m2"], rel=1e-12) and near["A_IM_m2"] != far["A_IM_m2"]
    by = res.regression["by_trunk_distance"]
    assert [b["trunk_distance_m"] for b in by] == [1.5, 2.5] and [b["n"] for b in by] == [1, 1]
    assert by[1]["slope"] == pytest.approx(far["A_PR_m2"] / far["A_IM_m2"], rel=1e-12)
    assert "trunk_distance_m" in (tmp_path / "s" / "study.csv").read_text().splitlines()[0]
    # The scene's own placement is the default, and is the 1.5 m row (same key: reused).
    own = run_study(SCENES / "apple_orchard.toml", tmp_path / "s", [base], readings=False)
    assert own.rows[0]["key"] == near["key"]
    for bad in ([], [0.0], [-1.0], [float("nan")]):
        with pytest.raises(ConfigError, match="trunk_distances_m"):
            with_trunk_distances(str(SCENES / "apple_orchard.toml"), [base], bad)


def test_cli_refuses_a_bad_trunk_distance(tmp_path, capsys):
    from simlidar_mi.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["study", str(SCENES / "apple_orchard.toml"), "--out", str(tmp_path / "o"),
              "--trunk-distances", "1.5,0"])
    assert exc.value.code == 2
    assert "--trunk-distances" in capsys.readouterr().err and not (tmp_path / "o").exists()


def _row(it, n, a_im, a_pr):
    return {"iterations": it, "n_trees": n, "A_IM_m2": a_im, "A_IM_yz_m2": 2 * a_im, "A_PR_m2": a_pr,
            "A_L_m2": np.pi * a_pr, "A_PR_exact_m2": a_pr, "hit_rule": "any", "footprint": 2,
            **{f"A_IM_{k}_m2": a_im / 2 for k in READINGS}}


def test_regression_report_subgroups_readings_and_the_pi_note():
    rows = [_row(4, 1, 1.0, 2.0), _row(4, 4, 2.0, 4.4), _row(5, 1, 1.0, 3.0), _row(5, 4, 3.0, 9.0)]
    rep = regression_report(rows)
    assert set(rep["subgroups"]) == {"iterations=4", "iterations=5", "n_trees=1", "n_trees=4"}
    assert rep["subgroups"]["iterations=5"]["A_PR_vs_A_IM"]["slope"] == pytest.approx(30 / 10)
    assert rep["subgroups"]["n_trees=1"]["A_PR_vs_A_IM"]["slope"] == pytest.approx(2.5)
    # A_L = π·A_PR: same R², slopes in the ratio π
    assert rep["A_L_vs_A_IM"]["slope"] == pytest.approx(np.pi * rep["A_PR_vs_A_IM"]["slope"])
    assert rep["A_L_vs_A_IM"]["r2"] == pytest.approx(rep["A_PR_vs_A_IM"]["r2"])
    by = rep["A_PR_vs_A_IM_by_reading"]
    assert set(by) == {"study", "A_IM_yz", *READINGS}
    # half the A_IM doubles the slope; the YZ projection (twice A_IM here) halves it
    assert by["far"]["slope"] == pytest.approx(2 * by["study"]["slope"])
    assert by["A_IM_yz"]["slope"] == pytest.approx(by["study"]["slope"] / 2)
    assert any("π" in n for n in rep["notes"])


def test_study_rows_carry_every_reading_and_the_old_reading_is_the_old_study(tmp_path):
    grid = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01"]]
    row = run_study(SCENES / "apple_orchard.toml", tmp_path / "r", grid).rows[0]
    for name in READINGS:
        assert row[f"A_IM_{name}_m2"] > 0
    # far-side limits sweep less of the tree; the fraction rule weights part-hit beams down
    assert row["A_IM_far_m2"] < row["A_IM_m2"] and row["A_IM_fraction_m2"] < row["A_IM_m2"]
    old = run_study(SCENES / "apple_orchard.toml", tmp_path / "o",
                    [grid[0] + ['scan.theta_limits_side="far"']], hit_rule="fraction",
                    readings=False).rows[0]
    assert old["A_IM_m2"] == pytest.approx(row["A_IM_old_m2"], rel=1e-12)
    reg = json.loads((tmp_path / "r" / "regression.json").read_text())
    assert set(reg["A_PR_vs_A_IM_by_reading"]) == {"study", "A_IM_yz", *READINGS}
    header = (tmp_path / "r" / "study.csv").read_text().splitlines()[0]
    assert all(f"A_IM_{k}_m2" in header for k in READINGS)


def test_study_progress_is_a_stderr_line_per_orchard_and_per_stage_when_piped(tmp_path, capsys):
    grid = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01",
             f"orchard.tree.d_min_m={d}"] for d in (0.005, 0.006)]
    run_study(SCENES / "apple_orchard.toml", tmp_path / "s", grid, readings=False, progress="lines")
    out, err = capsys.readouterr()
    assert out == ""  # results go to files; stdout stays clean (Dask's own bar printed there)
    assert re.fullmatch(r"study: scanning: 1/2 orchards done \(50 %, \d+\.\d s\)\n"
                        r"study: scanning: 2/2 orchards done \(100 %, \d+\.\d s\)\n"
                        r"study: scanning: 2 orchards \(\d+\.\d s\)\n", err)
