"""The landscape stand (bench/scenes/forest_landscape_1km2.toml, issue 31 §4) in tiles on a Dask
cluster: a corner of it flown in one process (streamed: traced and written chunk by chunk) and
as row tiles on a 2-worker LocalCluster gives the same points.laz, trajectory.txt and scan.exr,
byte for byte, and each tile's points are the one-process run's points of those rows.  The stand
is on the scene's terrain (Gaussian hills on a slope): the ground returns lie on it, not on z = 0."""
from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from simlidar_mi._runtime import cluster as _dask
from simlidar_mi.config import load_scene
from simlidar_mi.io.terrain import terrain_of
from simlidar_mi.lidar import tiles
from simlidar_mi.lidar.survey import run_scan

SCENE = Path(__file__).resolve().parents[1] / "bench" / "scenes" / "forest_landscape_1km2.toml"
# a 30 m square of the stand (its four species, real foliage, 2 prototypes a species to stay
# quick), flown as the bench flies every size: 120 pulses a line, 20 pulses/m²
SMALL = ["forest.domain_m=[485.0, 515.0, 485.0, 515.0]", "forest.prototypes_per_species=2",
         "platform.start_xy_m=[500.0, 485.0]", "platform.end_xy_m=[500.0, 515.0]",
         "platform.altitude_m=25.98", "platform.pulses_per_line=120", "platform.pulse_rate_hz=30000.0"]


@pytest.fixture(autouse=True)
def _no_env_scheduler(monkeypatch):
    monkeypatch.delenv(_dask.ENV, raising=False)


def _measures(out: Path) -> dict:
    m = json.loads((out / "measures.json").read_text())
    m.pop("seconds")
    return m


def test_landscape_scene_is_twenty_pulses_per_m2_over_1km2():
    cfg = load_scene(SCENE)
    p = cfg["platform"]
    assert cfg["forest"]["domain_m"] == [0.0, 1000.0, 0.0, 1000.0]
    swath_m = 2 * p["altitude_m"] * np.tan(np.deg2rad(p["swath_deg"] / 2))
    assert abs(swath_m - 1000.0) < 1.0  # the swath covers the square's width
    across = swath_m / p["pulses_per_line"]
    along = p["speed_m_s"] * p["pulses_per_line"] / p["pulse_rate_hz"]  # between two lines
    assert abs(1 / (across * along) - 20.0) < 0.05
    assert {s["preset"] for s in cfg.arrays["species"]} == {"deciduous-apex", "conifer-whorl", "broadleaf-monopodial",
                                                     "small-tree"}
    assert cfg["scan"]["points_format"] == "laz" and cfg["scan"]["trajectory"]
    lo, hi = terrain_of(cfg).z_range_m  # on terrain: tens of metres of relief under the stand
    assert lo < -20.0 and 40.0 < hi < 0.1 * p["altitude_m"]


def test_landscape_tiles_on_a_cluster_are_the_one_machine_points(tmp_path, cluster):
    local = run_scan(load_scene(SCENE, [*SMALL, "scan.chunk_beams=5000"]), tmp_path / "local", write_png=False)
    got = []
    real_merge = tiles.merge_tiles

    def spy(patterns, parts):
        got.extend(parts)
        return real_merge(patterns, parts)
    tiles.merge_tiles = spy
    try:
        run_scan(load_scene(SCENE, SMALL), tmp_path / "cluster", write_png=False,
                 scheduler=cluster.scheduler_address, tile_rows=40)
    finally:
        tiles.merge_tiles = real_merge
    n_rows = local.result[0].shape[0] if isinstance(local.result, list) else local.result.shape[0]
    assert len(got) == -(-n_rows // 40) >= 3  # tiles of 40 lines, the last one shorter
    for name in ("points.laz", "trajectory.txt", "scan.exr"):
        assert (tmp_path / "cluster" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name
    assert _measures(tmp_path / "cluster") == _measures(tmp_path / "local")
    one, tiled = laspy.read(tmp_path / "local" / "points.laz"), laspy.read(tmp_path / "cluster" / "points.laz")
    assert one.header.point_count > 15_000 and (np.asarray(one.classification) == 5).any()  # leaves hit
    ground = np.asarray(one.classification) == 2  # on the terrain, its height under each point
    terrain = terrain_of(load_scene(SCENE, SMALL))
    z_ground = terrain.height_m(np.asarray(one.x)[ground], np.asarray(one.y)[ground])
    assert ground.sum() > 1000 and np.ptp(z_ground) > 1.0
    assert np.abs(np.asarray(one.z)[ground] - z_ground).max() < 0.005
    for tile in got:  # each tile's points: the one-process run's points of its rows
        rows = (tile["r0"], tile["r1"])
        pick = [(np.asarray(c["scan_position"]) >= rows[0]) & (np.asarray(c["scan_position"]) < rows[1])
                for c in (one, tiled)]
        assert pick[0].any()
        assert one.points.array[pick[0]].tobytes() == tiled.points.array[pick[1]].tobytes()
