"""Scoring on one voxel set fixed before any estimator runs, abstentions (NaN) scored explicitly
(simlidar_mi.truth.scoring.score): an estimator cannot improve its headline score by leaving
out the voxels it estimates worst."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simlidar_mi.truth.scoring import score

REPO = Path(__file__).resolve().parents[1]


def test_an_abstention_is_scored_as_zero_with_its_coverage():
    """Four observed voxels (truth 1, 2, 3, 0) and one unobserved: an estimator that answers
    (1.5, NaN, 3, 0) is scored as (1.5, 0, 3, 0) over all four, with 3 of 4 voxels and 4 of
    6 m2/m3 of the truth covered; the "where estimated" figures use the three it answered."""
    t = np.array([1.0, 2.0, 3.0, 0.0, 5.0]).reshape(5, 1, 1)
    e = np.array([1.5, np.nan, 3.0, 0.0, np.nan]).reshape(5, 1, 1)
    obs = np.array([True, True, True, True, False]).reshape(5, 1, 1)
    v = score(t, e, obs)["voxel"]
    assert v["n"] == 4 and v["n_estimated"] == 3
    assert v["coverage_voxels"] == 0.75 and v["coverage_area"] == pytest.approx(4 / 6)
    assert v["bias"] == pytest.approx((0.5 - 2.0 + 0 + 0) / 4)
    assert v["rmse"] == pytest.approx(np.sqrt((0.25 + 4.0) / 4))
    assert v["rmse_estimated"] == pytest.approx(np.sqrt(0.25 / 3))
    assert v["bias_estimated"] == pytest.approx(0.5 / 3)
    zero = score(t, np.nan_to_num(e), obs)["voxel"]  # answering 0 scores the same
    assert {k: zero[k] for k in ("r2", "rmse", "bias")} == {k: v[k] for k in ("r2", "rmse", "bias")}
    assert zero["coverage_voxels"] == 1.0


@pytest.fixture(scope="module")
def orchard_bl():
    """Beer-Lambert on the leafy orchard at 0.1 m (a coarser scan than the scene's), with the
    truth on the same grid and the beams each voxel saw."""
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.survey import run_scan
    from simlidar_mi.truth.compute import compute_truth
    from simlidar_mi.truth.estimators import beams_from_scan, beer_lambert_pad
    from simlidar_mi.truth.grid import grid_values
    from simlidar_mi.truth.run import truth_geometry, truth_grid
    from simlidar_mi.truth.traverse import traverse
    import tempfile
    cfg = load_scene(REPO / "scenes" / "orchard_leafy.toml", ["scan.dtheta_deg=0.5", "scan.dy_m=0.04"])
    geometry, _ = truth_geometry(cfg)
    grid = truth_grid(cfg, geometry, 0.1)
    with tempfile.TemporaryDirectory() as tmp:
        res = run_scan(cfg, Path(tmp) / "scan", write_png=False).result
    c = traverse(grid, beams_from_scan(res))
    truth = grid_values(compute_truth(geometry, grid, progress=False), "PAD_m2_m3")
    return truth, beer_lambert_pad(c), c.n_in


@pytest.mark.parametrize("fewest", [10, 20, 50, 200])
def test_blanking_the_voxels_few_beams_entered_cannot_improve_the_headline(orchard_bl, fewest):
    """The gaming the old rule allowed (it scored only where the estimate is finite): blanking
    the voxels fewer than 10 ... 200 beams entered, the least trustworthy ones, lowers the RMSE
    "where estimated" (0.95 -> 0.75 -> 0.36 at 0.1 m in the scene's own scan) while the share of
    plant area scored collapses. Scored on the fixed set with abstentions as 0, the headline
    RMSE, R² and |bias| only get worse."""
    truth, bl, n_in = orchard_bl
    observed = n_in >= 5  # the scored set: fixed by the scan, not by the estimate
    full = score(truth, bl, observed)["voxel"]
    blank = score(truth, np.where(n_in >= fewest, bl, np.nan), observed)["voxel"]
    assert full["coverage_area"] == 1.0 and blank["coverage_area"] < 0.97
    assert blank["rmse_estimated"] < full["rmse_estimated"]  # what the old score reported
    assert blank["rmse"] > full["rmse"] and blank["r2"] < full["r2"]
    assert abs(blank["bias"]) > abs(full["bias"])
    assert blank["n"] == full["n"]


def test_blanking_the_worst_voxels_cannot_improve_the_headline(orchard_bl):
    """The voxels Beer-Lambert gets most wrong, blanked in turn (worst 1 %, 5 %, 20 %): the
    headline never improves. (Where an estimate exceeds twice the truth, answering 0 is
    closer, and abstaining is scored as answering 0: so the worst voxels here are taken among
    the estimates within a factor 2 of the truth, and the test also shows that the headline
    of every blanked estimate equals that of the estimate with 0 written in.)"""
    truth, bl, n_in = orchard_bl
    observed = n_in >= 5
    full = score(truth, bl, observed)["voxel"]
    err = np.where(observed & (bl <= 2 * truth), np.abs(bl - truth), -1.0)
    order = np.argsort(-err, axis=None)
    n_ok = int((err > 0).sum())
    for share in (0.01, 0.05, 0.2):
        worst = np.zeros(truth.size, bool)
        worst[order[:max(1, int(share * n_ok))]] = True
        blanked = np.where(worst.reshape(truth.shape), np.nan, bl)
        s = score(truth, blanked, observed)["voxel"]
        assert s["rmse"] >= full["rmse"] and s["r2"] <= full["r2"]
        assert s["rmse"] == score(truth, np.nan_to_num(blanked), observed)["voxel"]["rmse"]
