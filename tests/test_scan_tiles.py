"""Scans split into row tiles on a Dask cluster: the tiles run on the cluster's workers and
merge into the same files, byte for byte, as the one-process scan (timings aside)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi._runtime import cluster as _dask
from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.lidar import tiles
from simlidar_mi.lidar.scan import scan
from simlidar_mi.lidar.survey import build, generate, prepare_scan, run_scan, scan_patterns, scene_sensor
from tests.conftest import SCENES

# A 40 m airborne pass over a 40 m × 40 m corner of the instanced four-species forest
# (11 trees with leaves): 134 lines × 200 pulses; 2 prototype trees a species, not 12 (tiling
# does not depend on how many; drawing 48 trees is about half of the run).
AIRBORNE = (SCENES / "forest_airborne.toml",
            ["forest.domain_m=[40.0, 80.0, 70.0, 110.0]", "forest.prototypes_per_species=2",
             "platform.pulses_per_line=200",
             "platform.pulse_rate_hz=20000.0", "platform.speed_m_s=30.0",
             "platform.start_xy_m=[60.0, 70.0]", "platform.end_xy_m=[60.0, 110.0]"])
# A small tractor orchard scan with a real scanner: divergence, echoes, intensity and range
# noise (keyed by the global beam index), a 2 × 2 dot matrix.
SENSOR = (SCENES / "apple_orchard.toml",
          ["orchard.n_trees=1", "orchard.tree.iterations=4", "scan.dy_m=0.01", "scan.dtheta_deg=1.0",
           "scan.footprint=1", "sensor.divergence_mrad=3.0", "sensor.beam_samples=4", "sensor.max_returns=3",
           "sensor.intensity=true", "sensor.range_noise_m=0.01", "sensor.range_noise_per_m=0.001",
           'sensor.noise_model="range"'])
FILES = ("scan.exr", "scan.png", "points.las")


@pytest.fixture(autouse=True)
def _no_env_scheduler(monkeypatch):
    monkeypatch.delenv(_dask.ENV, raising=False)



def _measures(out: Path) -> dict:
    m = json.loads((out / "measures.json").read_text())
    m.pop("seconds")  # timings: the only part that may differ
    return m


def _assert_same_files(out: Path, ref: Path) -> None:
    for name in FILES:
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name
    assert _measures(out) == _measures(ref)


def _workers(cluster) -> set[str]:
    import distributed  # noqa: PLC0415
    with distributed.Client(cluster, set_as_default=False) as c:
        return set(c.scheduler_info(n_workers=-1)["workers"])


@pytest.mark.parametrize("scene", [AIRBORNE, SENSOR], ids=["airborne-forest", "tractor-sensor"])
def test_cluster_scan_is_the_one_process_scan(tmp_path, cluster, scene):
    path, over = scene
    ref = run_scan(load_scene(path, over), tmp_path / "local")
    workers = set()
    real_merge = tiles.merge_tiles

    def spy(patterns, got):
        workers.update(t["worker"] for t in got)
        return real_merge(patterns, got)
    tiles.merge_tiles = spy
    try:
        run = run_scan(load_scene(path, over), tmp_path / "cluster", scheduler=cluster.scheduler_address,
                       tile_rows=40)
    finally:
        tiles.merge_tiles = real_merge
    _assert_same_files(tmp_path / "cluster", tmp_path / "local")
    # the tiles ran on the cluster's worker processes, not here
    assert workers and workers <= _workers(cluster)
    n_rows = ref.result.shape[0]
    assert n_rows > 2 * 40  # several tiles of 40 rows each, the last one shorter
    np.testing.assert_array_equal(run.result.range_m, ref.result.range_m)
    if ref.result.echoes is not None:  # every echo, noise included, keyed by its global beam
        assert len(run.result.echoes) == len(ref.result.echoes) > ref.result.shape[0]
        np.testing.assert_array_equal(run.result.echoes.beam, ref.result.echoes.beam)
        np.testing.assert_array_equal(run.result.echoes.range_m, ref.result.echoes.range_m)
        assert (ref.result.n_returns > 1).any()
    else:
        assert (ref.result.cls == 3).any() and ref.result.tree_id is not None  # leaves, tree ids


def test_active_client_and_env_choose_the_cluster(tmp_path, cluster, monkeypatch):
    """An active distributed Client is used (and left open); DASK_SCHEDULER_ADDRESS too; the
    CLI's --scheduler and --tile-rows reach the tiles; 'local' forces this process."""
    import distributed  # noqa: PLC0415
    path, over = AIRBORNE
    over = over + ["platform.end_xy_m=[60.0, 90.0]"]  # 67 lines
    ref = run_scan(load_scene(path, over), tmp_path / "ref")
    plans = []
    real_plan = tiles.tile_plan
    monkeypatch.setattr(tiles, "tile_plan", lambda p, rows=None: (p and plans.append(rows)) or real_plan(p, rows))
    with distributed.Client(cluster) as client:
        run_scan(load_scene(path, over), tmp_path / "active", tile_rows=30)
        assert client.status == "running"
    _assert_same_files(tmp_path / "active", tmp_path / "ref")
    monkeypatch.setenv(_dask.ENV, cluster.scheduler_address)
    args = ["scan", str(path), "--out", str(tmp_path / "cli"), "--tile-rows", "25", "--no-png"]
    for o in over:
        args += ["--set", o]
    assert main(args) == 0
    for name in ("scan.exr", "points.las"):
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "ref" / name).read_bytes()
    assert plans == [30, 25]
    run_scan(load_scene(path, over), tmp_path / "forced", scheduler="local")
    assert plans == [30, 25]  # no tiles: this process scanned
    _assert_same_files(tmp_path / "forced", tmp_path / "ref")


def _prepared(text_or_path, over=()):
    cfg = load_scene(text_or_path, list(over))
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    return cfg, pats, build(cfg, g, pats), scene_sensor(cfg, g, pats)


@pytest.mark.parametrize("scene", [
    (SCENES / "forest_road_scan.toml", ["platform.step_m=1.0", "platform.elevation_deg=[-30.0, 60.0, 2.0]"]),
    (SCENES / "apple_orchard.toml", ["orchard.n_trees=1", "orchard.tree.iterations=3", "scan.dy_m=0.02",
                                     "scan.footprint=2", "scan.dtheta_deg=1.0"]),
    (SCENES / "apple_orchard.toml", ["orchard.n_trees=1", "orchard.tree.iterations=3", "scan.dy_m=0.02",
                                     "scan.dtheta_deg=1.0", "sensor.pulse_rate_hz=36000.0",
                                     "platform.speed_m_s=2.0", "sensor.max_returns=2",
                                     "sensor.range_noise_m=0.02"]),
], ids=["path-legs", "tractor-dot-matrix", "moving-tractor-noise"])
def test_row_tiles_concatenate_to_the_whole_scan(scene):
    """In one process: scan(rows=(r0, r1)) of every tile, concatenated, is the whole scan
    (the same rays: sliced tractor tables, sliced pattern rows, moving poses, global noise)."""
    cfg, pats, built, sensor = _prepared(*scene)
    for j, p in enumerate(pats):
        whole = scan(built, p, None, sensor, seed=cfg.seed, leg=j)
        n = whole.shape[0]
        cuts = [0, 1, n // 3, n // 3 + 7, n]
        parts = [scan(built, p, None, sensor, seed=cfg.seed, leg=j, rows=(a, b)) for a, b in zip(cuts, cuts[1:])]
        got = tiles.merge_tiles([p], [{"leg": 0, "r0": a, "r1": b, "built": {"origin_m": built.origin_m},
                                      **{k: getattr(r, k) for k in ("range_m", "cls", "element_id", "hit_fraction",
                                                                    "tree_id", "echoes", "n_returns", "intensity",
                                                                    "sensor", "seconds", "metadata")}}
                                     for (a, b), r in zip(zip(cuts, cuts[1:]), parts)])[0]
        for key in ("range_m", "cls", "element_id", "hit_fraction", "tree_id", "n_returns", "intensity"):
            a, b = getattr(got, key), getattr(whole, key)
            assert (a is None) == (b is None), key
            if a is not None:
                np.testing.assert_array_equal(a, b, err_msg=key)
        assert (whole.cls >= 2).any()  # the scan sees wood
        if whole.echoes is not None:
            for f in ("beam", "return_number", "range_m", "energy", "cls"):
                np.testing.assert_array_equal(getattr(got.echoes, f), getattr(whole.echoes, f), err_msg=f)


def test_tile_plan_and_bad_tile_rows():
    cfg, pats, *_ = _prepared(SCENES / "forest_road_scan.toml", ["platform.step_m=1.0"])
    plan = tiles.tile_plan(pats, 7)
    for j, p in enumerate(pats):
        mine = [(a, b) for leg, a, b in plan if leg == j]
        assert mine[0][0] == 0 and mine[-1][1] == p.n_rows
        assert all(b - a == 7 for a, b in mine[:-1]) and all(x[1] == y[0] for x, y in zip(mine, mine[1:]))
    # default: about DEFAULT_TILE_BEAMS beams a tile
    big = tiles.tile_plan(pats)
    assert big[0][2] == min(pats[0].n_rows, tiles.DEFAULT_TILE_BEAMS // pats[0].n_cols)
    for bad in (0, -3, 2.5, True, "10"):
        with pytest.raises(ConfigError, match="tile_rows"):
            tiles.tile_plan(pats, bad)
    with pytest.raises(ConfigError, match="tile_rows"):  # also with no cluster to use it
        run_scan(cfg, None, tile_rows=0)


def test_worker_of_other_code_refuses(tmp_path):
    cfg, *_ = _prepared(*SENSOR)
    with pytest.raises(ConfigError, match="runs other code"):
        tiles._tile_task(tiles.scene_bundle(cfg, prepare_scan), 0, 0, 1, "0.0+other mitsuba ? drjit ?")
