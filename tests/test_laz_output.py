"""``[scan] points_format = "laz"`` (issue 31 §4): points.laz holds exactly points.las's header,
VLRs (the CRS WKT among them) and every point dimension, compressed; held and streamed scans,
first returns and echoes; and a reader that is not laspy (PDAL) opens it when installed."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import SimlidarError
from simlidar_mi.io import las
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.lidar.platforms import airborne_pattern
from tests.test_las_fast import _result

SCENES = Path(__file__).resolve().parents[1] / "scenes"
CALIB = ["scan.dy_m=0.01", 'scene.crs="EPSG:25832"']


def _same_clouds(a_path: Path, b_path: Path) -> laspy.LasData:
    """Every header field, VLR and point dimension of the two files equal; the LAZ one compressed."""
    a, b = laspy.read(a_path), laspy.read(b_path)
    assert not a.header.are_points_compressed and b.header.are_points_compressed
    assert b_path.stat().st_size < a_path.stat().st_size
    for field in ("version", "point_format", "point_count", "scales", "offsets", "mins", "maxs",
                  "number_of_points_by_return", "system_identifier", "generating_software",
                  "creation_date", "min_gps_time", "max_gps_time"):
        va, vb = getattr(a.header, field), getattr(b.header, field)
        assert np.array_equal(np.asarray(va), np.asarray(vb)) if isinstance(va, np.ndarray) else va == vb, field
    assert a.header.global_encoding.value == b.header.global_encoding.value
    assert [(v.user_id, v.record_id, v.description, v.record_data_bytes()) for v in a.header.vlrs] == \
        [(v.user_id, v.record_id, v.description, v.record_data_bytes()) for v in b.header.vlrs]
    assert list(a.point_format.dimension_names) == list(b.point_format.dimension_names)
    assert a.points.array.tobytes() == b.points.array.tobytes()  # every dimension, bit for bit
    return b


@pytest.mark.parametrize("chunk", [1 << 22, 500])  # held, then streamed (spilled) points
def test_scan_writes_laz_equal_to_las(tmp_path, chunk):
    over = [*CALIB, f"scan.chunk_beams={chunk}"]
    las_dir, laz_dir = tmp_path / "las", tmp_path / "laz"
    run_scan(load_scene(SCENES / "calibration_cylinder.toml", over), las_dir, write_png=False)
    run = run_scan(load_scene(SCENES / "calibration_cylinder.toml", [*over, 'scan.points_format="laz"']),
                   laz_dir, write_png=False)
    assert run.files["las"] == laz_dir / "points.laz" and not (laz_dir / "points.las").exists()
    back = _same_clouds(las_dir / "points.las", laz_dir / "points.laz")
    assert back.header.point_count > 1000
    wkt = back.header.parse_crs()
    assert wkt is not None and wkt.to_epsg() == 25832  # the CRS record survives compression
    # a re-run as LAS replaces the scan's LAZ (SCAN_OUTPUTS): no stale cloud beside the new one
    run_scan(load_scene(SCENES / "calibration_cylinder.toml", over), laz_dir, write_png=False)
    assert sorted(p.name for p in laz_dir.iterdir() if p.name.startswith("points")) == ["points.las"]


def test_echo_legs_laz_equal_to_las(tmp_path):
    """Two airborne legs, the second with echoes 1-15, intensities and the sensor VLR."""
    p = airborne_pattern([0, 0], [3, 80], 100.0, 30.0, 10.0, 1000.0, 20)
    n, m = p.n_rows, p.n_cols
    rng = np.random.default_rng(3)
    first, second = _result(p, 4), _result(p, 5)
    from simlidar_mi.lidar.waveform import Echoes
    per_beam = rng.integers(0, 16, n * m)
    beam = np.repeat(np.arange(n * m), per_beam)
    ret = np.concatenate([np.arange(1, c + 1) for c in per_beam if c]).astype(np.uint8)
    k = len(beam)
    second.echoes = Echoes(beam, ret, np.repeat(per_beam, per_beam).astype(np.uint8),
                           np.sort(rng.uniform(1.0, 90.0, k)), rng.uniform(0.0, 80.0, k).astype(np.float32),
                           rng.uniform(0.5, 9.0, k).astype(np.float32), rng.choice(np.array([1, 2, 3], np.uint8), k),
                           rng.integers(0, 2**32, k, dtype=np.uint32), rng.integers(0, 9, k, dtype=np.uint32),
                           np.ones(k, np.float32))
    second.intensity, second.sensor = np.ones((n, m), np.float32), {"model": "t", "intensity": True}
    legs = [first, second]
    a = las.write_scan_las(legs, tmp_path / "a.las", crs="EPSG:32633")
    b = las.write_scan_las(legs, tmp_path / "a.laz", crs="EPSG:32633")
    back = _same_clouds(a, b)
    assert back.header.point_count > 50_000  # more than one LAZ chunk (50 000 points)
    assert json.loads(back.header.vlrs[-1].record_data_bytes()) == {"model": "t", "intensity": True}


def test_points_format_refuses_other_values():
    with pytest.raises(SimlidarError, match="points_format"):
        load_scene(SCENES / "calibration_cylinder.toml", ['scan.points_format="e57"'])


@pytest.mark.skipif(shutil.which("pdal") is None, reason="pdal is not installed (Debian: pdal)")
def test_pdal_reads_the_laz(tmp_path):
    run_scan(load_scene(SCENES / "calibration_cylinder.toml", [*CALIB, 'scan.points_format="laz"']),
             tmp_path, write_png=False)
    info = json.loads(subprocess.run(["pdal", "info", "--summary", str(tmp_path / "points.laz")],
                                     check=True, capture_output=True, text=True).stdout)
    back = laspy.read(tmp_path / "points.laz")
    assert info["summary"]["num_points"] == back.header.point_count
    assert np.isclose(info["summary"]["bounds"]["minx"], back.header.mins[0])
