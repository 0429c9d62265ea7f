"""points.las read back with laspy: WKT bit, gps_time, CRS record, point_source_id."""
from __future__ import annotations

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.io.las import write_scan_las
from simlidar_mi.lidar.platforms import airborne_pattern, path_patterns
from simlidar_mi.lidar.scan import ScanResult
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES


def _fake_result(pattern, *, escape_every: int = 7) -> ScanResult:
    """A ScanResult over ``pattern`` with every beam a 5 m wood return except every
    ``escape_every``-th beam (escapes are not written)."""
    n, m = pattern.n_rows, pattern.n_cols
    cls = np.full((n, m), CLASS_CODES["wood"], np.uint8)
    cls.reshape(-1)[::escape_every] = CLASS_CODES["escape"]
    return ScanResult(None, np.full((n, m), 5.0, np.float32), cls,
                      np.zeros((n, m), np.uint32), np.ones((n, m), np.float32),
                      np.zeros(3), pattern=pattern)


def _scan_order(las):
    """gps_time sorted by (leg, row, column): the order in which the beams were fired."""
    order = np.lexsort((np.asarray(las.scan_angle_index), np.asarray(las.scan_position),
                        np.asarray(las.point_source_id)))
    return np.asarray(las.gps_time)[order]


@pytest.fixture(scope="module")
def calibration_las(tmp_path_factory):
    out = tmp_path_factory.mktemp("las") / "calib"
    run = run_scan(load_scene(SCENES / "calibration_cylinder.toml", ['scene.crs="EPSG:25832"']),
                   out, write_png=False)
    return run.result, laspy.read(out / "points.las")


def test_tractor_las_wkt_bit_crs_time_and_source(calibration_las):
    res, las = calibration_las
    assert res.shape[0] > 200  # enough rows that the old "row index mod 65536" would vary
    assert las.header.global_encoding.wkt
    assert not las.header.global_encoding.gps_time_type  # a time from the scan start, not GPS
    assert las.header.parse_crs().to_epsg() == 25832
    # one leg: a single source; the row is in scan_position
    assert set(np.unique(las.point_source_id)) == {0}
    # scan-order time: i + k/M on a nominal 1 s per row
    m = res.shape[1]
    np.testing.assert_array_equal(las.gps_time, np.asarray(las.scan_position) +
                                  np.asarray(las.scan_angle_index) / m)
    assert np.all(np.diff(_scan_order(las)) > 0)
    text = las.header.vlrs.get_by_id("simlidar-mi", [1])[0].record_data
    assert b"scan-order time" in text


def test_las_without_crs_has_wkt_bit_and_no_crs_record(tmp_path):
    pattern = path_patterns([[0, 0, 1], [1, 0, 1]], 0.1, (-10.0, 10.0, 1.0))[0]
    write_scan_las(_fake_result(pattern), tmp_path / "p.las")
    las = laspy.read(tmp_path / "p.las")
    assert las.header.global_encoding.wkt
    assert las.header.parse_crs() is None
    assert not las.header.vlrs.get("WktCoordinateSystemVlr")


def test_airborne_gps_time_is_the_pulse_time(tmp_path):
    rate, per_line = 1000.0, 20
    pattern = airborne_pattern([0, 0], [0, 5], 100.0, 30.0, 10.0, rate, per_line)
    write_scan_las(_fake_result(pattern), tmp_path / "a.las", crs="EPSG:32633")
    las = laspy.read(tmp_path / "a.las")
    i, k = np.asarray(las.scan_position), np.asarray(las.scan_angle_index)
    np.testing.assert_allclose(las.gps_time, (i * per_line + k) / rate, rtol=0, atol=1e-12)
    assert np.all(np.diff(_scan_order(las)) > 0)
    assert las.header.parse_crs().to_epsg() == 32633
    assert b"pulse time" in las.header.vlrs.get_by_id("simlidar-mi", [1])[0].record_data


def test_path_legs_follow_each_other_in_time(tmp_path):
    legs = path_patterns([[0, 0, 1], [2, 0, 1], [2, -2, 1]], 0.1, (-10.0, 10.0, 1.0))
    write_scan_las([_fake_result(p) for p in legs], tmp_path / "legs.las")
    las = laspy.read(tmp_path / "legs.las")
    src = np.asarray(las.point_source_id)
    assert set(np.unique(src)) == {0, 1}
    assert np.all(np.diff(_scan_order(las)) > 0)
    # leg 1 starts after all of leg 0's rows
    assert las.gps_time[src == 1].min() >= legs[0].n_rows


@pytest.mark.parametrize("value,words", [
    ('"25832"', 'must look like "EPSG:<code>"'),
    ('"EPSG:4326"', "not a projected CRS in metres"),
    ('"EPSG:999999"', "not an EPSG code"),
    ("25832", "expected a string"),
])
def test_scene_crs_is_checked(value, words):
    with pytest.raises(ConfigError, match="scene.crs") as e:
        load_scene(text=f"[scene]\ncrs = {value}\n")
    assert words in str(e.value)
