"""Streamed physical scans (issue #8 item 2): a [sensor] scan written chunk by chunk gives the
held scan's bytes (scan.exr, scan.png, points.las, measures.json but for its seconds) whatever
the chunk size; the exact streamed sum behind A_IM; echo detection independent of the chunk."""
from __future__ import annotations

import json

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.io.exr import read_exr
from simlidar_mi.lidar.stream import PairwiseSum, StreamedScan
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.lidar.waveform import Echoes, detect_echoes
from tests.conftest import SCENES

# Small versions of the shipped sensor scenes: one tree, coarse steps.
LMS511 = ["orchard.n_trees=1", "scan.dy_m=0.05", "scan.y_start_m=-0.3", "scan.y_end_m=0.3",
          "sensor.beam_samples=4", "sensor.max_returns=3"]
# Three waypoints: two legs, moving and spinning (every beam its own time and origin).
VLP16 = ["orchard.n_trees=1", "platform.waypoints_m=[[0.5, -0.3, 1.5], [0.5, 0.0, 1.5], [0.5, 0.3, 1.5]]"]
# Two prototype trees a species, not the scene's 12: chunking cannot depend on how many
# prototypes there are, and drawing 48 trees is most of the run (about half of its time).
AIRBORNE = ["platform.start_xy_m=[150.0, 150.0]", "platform.end_xy_m=[150.0, 151.0]",
            "forest.domain_m=[130.0, 170.0, 130.0, 170.0]", "forest.prototypes_per_species=2"]


def _runs(tmp_path, scene, overrides, chunks):
    """{chunk: (run, files' bytes, measures without seconds)}; one loaded config, so one
    scene_sha256 in every header; chunk 10**9 is the held (unstreamed) scan, ``chunks`` a
    function of its beams per row."""
    cfg = load_scene(SCENES / scene, overrides)
    out = {}
    sizes = [10**9]
    while sizes:
        chunk = sizes.pop(0)
        cfg["scan"]["chunk_beams"] = chunk
        run = run_scan(cfg, tmp_path / f"c{chunk}")
        files = {p.name: p.read_bytes() for p in sorted((tmp_path / f"c{chunk}").iterdir()) if p.is_file()
                 and p.name != "measures.json"}
        measures = json.loads((tmp_path / f"c{chunk}" / "measures.json").read_text())
        measures.pop("seconds")
        out[chunk] = (run, files, measures)
        if chunk == 10**9:
            sizes = chunks((run.result[0] if isinstance(run.result, list) else run.result).shape[1])
    return out


def _same_as_held(runs):
    held_run, held_files, held_measures = runs[10**9]
    assert not isinstance(held_run.result, StreamedScan)
    for chunk, (run, files, measures) in runs.items():
        if chunk == 10**9:
            continue
        legs = run.result if isinstance(run.result, list) else [run.result]
        assert all(isinstance(r, StreamedScan) for r in legs), chunk
        assert files.keys() == held_files.keys()
        for name in files:
            assert files[name] == held_files[name], (chunk, name)
        assert measures == held_measures, chunk
    return held_run, held_files, held_measures


def test_lms511_streamed_is_the_held_scan_whatever_the_chunk(tmp_path):
    # one row, two rows and a piece, pieces of a row
    runs = _runs(tmp_path, "orchard_lms511.toml", LMS511, lambda m: [m, 2 * m + 100, m // 2 + 1])
    held, files, measures = _same_as_held(runs)
    n, m = held.result.shape
    assert len(runs) == 4 and n > 10 and m > 500
    ch, header = read_exr(runs[m // 2 + 1][0].files["exr"])
    assert {"n_returns", "intensity", "echo2.range", "echo3.class", "echo3.intensity"} <= set(ch)
    assert "simlidar_sensor" in header
    e = measures["echoes"]
    assert e["echoes"] > 1000 and e["beams"] == n * m
    assert e["beams_by_n_returns"].get("2", 0) > 0  # second echoes, in the EXR and the LAS
    assert int((ch["n_returns"] >= 2).sum()) == e["beams_by_n_returns"]["2"] + e["beams_by_n_returns"].get("3", 0)
    assert measures["A_IM_m2"] > 0 and measures["hits"]["wood"] > 0


def test_vlp16_two_moving_legs_streamed(tmp_path):
    runs = _runs(tmp_path, "orchard_vlp16_tractor.toml", VLP16, lambda m: [m * 64, m * 200 + 5])
    held, files, measures = _same_as_held(runs)
    assert {"scan_leg0.exr", "scan_leg1.exr", "scan_leg0.png", "scan_leg1.png", "points.las"} <= set(files)
    assert len(measures["legs"]) == 2 and measures["echoes"]["echoes"] > 100


def test_airborne_echoes_streamed(tmp_path):
    runs = _runs(tmp_path, "forest_airborne_echoes.toml", AIRBORNE, lambda m: [m, 2 * m + 100, m // 3])
    _, _, measures = _same_as_held(runs)
    assert measures["echoes"]["echoes"] > 100


def test_first_return_sensor_streamed(tmp_path):
    """A [sensor] without energies (nearest sub-ray, no echoes): the first-return files."""
    over = LMS511[:5] + ["sensor.max_returns=1", "sensor.intensity=false", "sensor.range_noise_m=0.0",
                         "sensor.detection=\"nearest\""]
    runs = _runs(tmp_path, "orchard_lms511.toml", over, lambda m: [m // 2 + 1])
    _, _, measures = _same_as_held(runs)
    assert "echoes" not in measures and measures["sub_rays_per_beam"] > 1
    ch, _ = read_exr(list(runs.values())[1][0].files["exr"])
    assert set(ch) == {"range", "class", "class_half", "branch_id"}


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 127, 128, 129, 1000, 4099, 65_537, 300_001])
def test_pairwise_sum_is_numpys_sum(n):
    rng = np.random.default_rng(n)
    dense = rng.random(n) * 10.0 ** rng.integers(-6, 7, n)
    sparse = np.where(rng.random(n) < 0.03, rng.random(n), 0.0)  # most beams miss the wood
    for a in (dense, sparse):
        whole = PairwiseSum(n)
        whole.add(a)
        pieces = PairwiseSum(n)
        at = 0
        while at < n:
            step = int(rng.integers(1, 5000))
            pieces.add(a[at:at + step])
            at += step
        assert whole.total() == pieces.total() == np.sum(a)  # the same bits
    grid = rng.random((37, 1016))  # (N, M) fed by rows, as the streamed scan feeds it
    s = PairwiseSum(grid.size)
    for r in range(0, 37, 5):
        s.add(grid[r:r + 5])
    assert s.total() == np.sum(grid)
    with pytest.raises(ValueError):
        PairwiseSum(3).total()


def test_echoes_do_not_depend_on_the_chunk_of_beams():
    """Over 65 536 sub-rays in one call (the old sums were cut there) and widths taken at
    cluster-local bins: every field the same bits, whatever beams share the call."""
    rng = np.random.default_rng(11)
    b, s = 12_000, 8
    # targets 0.7 and 1.6 m behind the first: kernels overlapping, two or three peaks
    r = 5.0 + rng.uniform(0.0, 0.6, (b, 1)) + rng.choice([0.0, 0.7, 1.6], (b, s)) + rng.uniform(0.0, 0.1, (b, s))
    r[rng.random((b, s)) < 0.2] = np.inf
    e = np.where(np.isfinite(r), rng.uniform(0.005, 0.05, (b, s)), 0.0)
    cls = np.full((b, s), 2, np.uint8)
    elem = np.tile(np.arange(s, dtype=np.uint32), (b, 1))

    def detect(a, z):
        return detect_echoes(r[a:z], e[a:z], cls[a:z], elem[a:z], None, np.full((z - a, s), 0.8),
                             np.arange(a, z, dtype=np.int64), pulse_length_ns=3.0,
                             detection_threshold=0.02, max_returns=4)
    whole = detect(0, b)
    assert np.isfinite(r).sum() > 65_536 and (whole.return_number >= 2).sum() > 1000
    for cuts in ((0, 5000, b), (0, 1, 8191, 8200, b), (0, 3333, 6666, 9999, b)):
        parts = Echoes.concat([detect(a, z) for a, z in zip(cuts[:-1], cuts[1:])])
        for name in ("beam", "return_number", "number_of_returns", "range_m", "energy", "width_ns",
                     "cls", "element_id", "cos_incidence"):
            assert getattr(parts, name).tobytes() == getattr(whole, name).tobytes(), (cuts, name)


def test_streamed_sensor_scan_shows_progress_per_chunk(tmp_path, capsys):
    cfg = load_scene(SCENES / "orchard_lms511.toml", LMS511 + ["scan.chunk_beams=2000"])
    run = run_scan(cfg, tmp_path, progress="lines")
    n, m = run.result.shape
    err = capsys.readouterr().err
    assert f"trace + write: {-(-n * m // 2000)} chunks" in err
