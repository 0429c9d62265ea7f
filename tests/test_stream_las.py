"""Streamed first-return LAS (issue #8): traced once through the point spill, nothing left
behind, and the numpy-packed record equal to laspy's own setters byte for byte."""
from __future__ import annotations

import os

import laspy
import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.io.las import LAS_CLASS_LUT, las_header, las_record
from simlidar_mi.lidar import las_spill
from simlidar_mi.lidar.scan import BeamTracer
from simlidar_mi.lidar.stream import StreamedScan
from simlidar_mi.lidar.survey import run_scan
from tests.conftest import SCENES

CALIB = SCENES / "calibration_cylinder.toml"


def test_streamed_scan_is_traced_once_and_its_spill_has_no_name(tmp_path, monkeypatch):
    held = run_scan(load_scene(CALIB), tmp_path / "held")
    traces, seen = [], []
    row_blocks = BeamTracer.row_blocks

    def counted(self, chunk_beams):
        traces.append(chunk_beams)
        yield from row_blocks(self, chunk_beams)

    write = las_spill.PointSpill.write

    def looked(self, path, *args, **kwargs):
        seen.append(sorted(os.listdir(path.parent)))  # the stage while the spill is open
        return write(self, path, *args, **kwargs)

    monkeypatch.setattr(BeamTracer, "row_blocks", counted)
    monkeypatch.setattr(las_spill.PointSpill, "write", looked)
    for chunk in (7, 360, 1000):  # pieces of a row, one row (M = 360), rows + a piece
        cfg = load_scene(CALIB)
        cfg["scan"]["chunk_beams"] = chunk
        run = run_scan(cfg, tmp_path / f"s{chunk}")
        assert isinstance(run.result, StreamedScan)
        assert (run.files["las"].read_bytes() == held.files["las"].read_bytes())
        assert sorted(os.listdir(tmp_path / f"s{chunk}")) == ["measures.json", "points.las", "scan.exr", "scan.png"]
    assert traces == [7, 360, 1000]  # one pass each: no second trace for the offsets
    assert seen == [["scan.exr", "scan.png"]] * 3  # the spilled points are in an unnamed file


def test_failed_streamed_scan_leaves_nothing(tmp_path, monkeypatch):
    def broken(self, *args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(las_spill.PointSpill, "write", broken)
    cfg = load_scene(CALIB)
    cfg["scan"]["chunk_beams"] = 1000
    with pytest.raises(RuntimeError, match="disk full"):
        run_scan(cfg, tmp_path / "out")
    assert os.listdir(tmp_path) == []  # no output folder, no stage, no spill


@pytest.mark.parametrize("with_tree,with_echoes", [(False, False), (True, False), (True, True)])
def test_packed_record_equals_laspy_setters(with_tree, with_echoes):
    rng = np.random.default_rng(3)
    n = 5000
    cols = {"xyz": rng.uniform(-20.0, 40.0, (n, 3)), "cls": rng.choice([1, 2, 3], n).astype(np.uint8),
            "angle": rng.integers(-30000, 30001, n).astype(np.int16), "source": rng.integers(0, 3, n),
            "elev": rng.uniform(-90.0, 90.0, n).astype(np.float32),
            "azim": rng.uniform(-180.0, 180.0, n).astype(np.float32),
            "gps": rng.uniform(0.0, 1e4, n), "range": rng.uniform(0.0, 60.0, n).astype(np.float32),
            "i": rng.integers(0, 10**6, n), "k": rng.integers(0, 4000, n),
            "elem": rng.integers(0, 2**32, n, dtype=np.uint32), "tree": rng.integers(0, 2**32, n, dtype=np.uint32),
            "ret": rng.integers(1, 16, n).astype(np.uint8), "nret": rng.integers(1, 16, n).astype(np.uint8),
            "intensity": rng.integers(0, 65536, n).astype(np.uint16),
            "width": rng.uniform(0.0, 9.0, n).astype(np.float32),
            "energy": rng.uniform(0.0, 500.0, n).astype(np.float32)}
    sensor = {"intensity": True, "intensity_scale": 12.5, "intensity_range_m": 0.5} if with_echoes else None
    header = las_header(np.floor(cols["xyz"].min(axis=0)), "t", with_tree=with_tree, with_echoes=with_echoes,
                        sensor=sensor)
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(n, header=header))
    las.x, las.y, las.z = cols["xyz"][:, 0], cols["xyz"][:, 1], cols["xyz"][:, 2]
    las.classification = LAS_CLASS_LUT[cols["cls"]]
    las.scan_angle = cols["angle"]
    las.elevation_deg = cols["elev"]
    las.azimuth_deg = cols["azim"]
    las.point_source_id = cols["source"].astype(np.uint16)
    las.gps_time = cols["gps"]
    las.range_m = cols["range"]
    las.scan_position = cols["i"].astype(np.uint32)
    las.scan_angle_index = cols["k"].astype(np.uint32)
    las.branch_id = cols["elem"]
    if with_tree:
        las.tree_id = cols["tree"]
    if with_echoes:
        las.return_number = cols["ret"]
        las.number_of_returns = cols["nret"]
        las.intensity = cols["intensity"]
        las.echo_width_ns = cols["width"]
        las.echo_energy = cols["energy"]
    else:  # first returns: 1 of 1
        las.return_number = np.ones(n, np.uint8)
        las.number_of_returns = np.ones(n, np.uint8)
    packed = las_record(header, cols, with_tree=with_tree, with_echoes=with_echoes)
    assert packed.array.tobytes() == las.points.array.tobytes()
    assert np.any(packed.array["X"] != 0) and np.all(packed.array["X"] >= 0)  # offsets are floor(min)


def test_packed_record_refuses_coordinates_beyond_int32():
    header = las_header(np.zeros(3), "t", with_tree=False)
    cols = {"xyz": np.array([[1e6, 0.0, 0.0]]), "cls": np.array([2], np.uint8), "angle": np.zeros(1, np.int16),
            "elev": np.zeros(1, np.float32), "azim": np.zeros(1, np.float32),
            "source": np.zeros(1, np.int64), "gps": np.zeros(1), "range": np.zeros(1, np.float32),
            "i": np.zeros(1, np.int64), "k": np.zeros(1, np.int64), "elem": np.zeros(1, np.uint32)}
    with pytest.raises(OverflowError, match="x does not fit"):
        las_record(header, cols, with_tree=False)


def test_streamed_spinning_head_is_the_held_file_in_firing_order(tmp_path):
    """A first-return VLP-16 turn (columns sorted by elevation, fired interleaved): the spill
    keeps each block's points in firing order, as the held writer does, so the files are the
    same bytes and gps_time never steps back."""
    over = ['platform.kind="rotating"', "platform.position_m=[1.0, 0.0, 1.0]"]
    files = []
    for chunk in (10**9, 500, 16 * 7 + 3):  # held; blocks of rows; rows and a piece
        cfg = load_scene(CALIB, over)
        cfg["scan"]["chunk_beams"] = chunk
        run = run_scan(cfg, tmp_path / f"c{chunk}", write_png=False)
        assert isinstance(run.result, StreamedScan) == (chunk < 10**9)
        files.append(run.files["las"].read_bytes())
    assert files[1] == files[0] and files[2] == files[0]
    las = laspy.read(tmp_path / f"c{10**9}" / "points.las")
    assert np.all(np.diff(las.gps_time) >= 0) and len(las.points) > 100
    ring = np.asarray(las.scan_angle_index, np.int64)
    assert np.any(np.diff(ring[np.asarray(las.scan_position) == las.scan_position[0]]) < 0)  # not ring order
