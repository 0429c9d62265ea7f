"""The fast LAS writer (issue #8, §8f): ``write_scan_las`` writes, byte for byte, what the
straightforward writer writes: every point from ``ScanResult.points_m()`` picked, packed by
``las_record`` (laspy's setters, tests/test_stream_las.py) in one record, through laspy's own
``write_points`` (header statistics from ``header.grow``)."""
from __future__ import annotations

import laspy
import numpy as np
import pytest

from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.io import las, las_fields
from simlidar_mi.lidar.platforms import airborne_pattern, rosette_patterns, rotating_patterns
from simlidar_mi.lidar.scan import ScanResult, ScanSettings
from simlidar_mi.lidar.waveform import Echoes

ESCAPE = CLASS_CODES["escape"]


def _patterns():
    """A tractor (one yaw: the direction table), a moving tractor with pulse times, a swath (a
    yaw per line), a moving spinning head (a yaw per row: directions per point) and a moving
    rosette (a direction per beam)."""
    tractor = dict(x0_m=-1.5, z0_m=1.2, y_start_m=-2.0, dy_m=0.05, gap=0, n_positions=70,
                   theta_min_deg=-80.0, dtheta_deg=1.0, n_angles=161)
    yield "tractor", ScanSettings(**tractor).pattern()
    yield "tractor-moving", ScanSettings(**tractor, pulse_rate_hz=20000.0, speed_m_s=1.0).pattern()
    yield "airborne", airborne_pattern([0, 0], [3, 5], 100.0, 30.0, 10.0, 1000.0, 20)
    yield "rotating", rotating_patterns(waypoints_m=[[0.0, 0.0, 1.0], [2.0, 0.5, 1.0]], speed_m_s=2.0,
                                        azimuth_range_deg=[-120.0, -60.0], ground=False)[0]
    yield "rosette", rosette_patterns(position_m=None, waypoints_m=[[0.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
                                      speed_m_s=5.0, look_deg=(-90.0, 0.0), ground=False)[0]


PATTERNS = dict(_patterns())


def _result(pattern, seed: int, escape_share: float = 0.5, tree: bool = True) -> ScanResult:
    n, m = pattern.n_rows, pattern.n_cols
    rng = np.random.default_rng(seed)
    cls = rng.choice(np.array([1, 2, 3], np.uint8), size=(n, m))
    cls[rng.random((n, m)) < escape_share] = ESCAPE
    rng_m = rng.uniform(0.3, 80.0, (n, m)).astype(np.float32)
    return ScanResult(None, rng_m, cls, rng.integers(0, 2**32, (n, m), dtype=np.uint32),
                      np.ones((n, m), np.float32), np.zeros(3), pattern=pattern,
                      tree_id=rng.integers(0, 50, (n, m), dtype=np.uint32) if tree else None)


def _reference(results, path, crs=None):
    """The straightforward writer: full (N, M, 3) points picked (in firing order), one
    ``las_record``, laspy's writer."""
    with_echoes = any(r.echoes is not None for r in results)
    parts, first_row = [], 0
    for leg, res in enumerate(results):
        t, time_kind = las.scan_times_s(res, first_row)
        first_row += res.shape[0]
        if res.echoes is not None:
            parts.append(las._echo_points(res, leg, t))
            continue
        keep = res.cls != ESCAPE  # every beam's point, gps time and angle, then picked
        i, k = np.nonzero(keep)
        fire = las.firing_order(res.pattern)
        if fire is not None:
            order = las.firing_sort(i * res.shape[1] + k, res.shape[1], fire)
            i, k = i[order], k[order]
        n = len(i)
        cols = {"xyz": res.points_m()[i, k], "cls": res.cls[i, k], "range": res.range_m[i, k],
                "elem": res.element_id[i, k],
                "tree": res.tree_id[i, k] if res.tree_id is not None else np.full(n, 0xFFFFFFFF, np.uint32),
                "gps": t[i, k], "i": i, "k": k, "source": np.full(n, leg)}
        cols["angle"], cols["elev"], cols["azim"] = las.BeamAngles(res.pattern)(i, k)
        if with_echoes:  # a first-return leg among echo legs: one return per pulse
            cols.update(ret=np.ones(n, np.uint8), nret=np.ones(n, np.uint8), intensity=np.zeros(n, np.uint16),
                        width=np.zeros(n, np.float32), energy=np.zeros(n, np.float32))
        parts.append(cols)
    sensor = next((r.sensor for r in results if r.sensor is not None), None)
    e_max = max((float(p["energy"].max()) for p in parts if "energy" in p and len(p["energy"])), default=0.0)
    for p in parts:  # the scan's intensity scale, from its largest echo energy (io/las_fields.py)
        if "energy" in p and "intensity" not in p:
            p["intensity"] = np.rint(las_fields.scan_intensity_scale(e_max) * p["energy"].astype(np.float64)
                                     if sensor and sensor.get("intensity") else 0 * p["energy"]).astype(np.uint16)
    cols = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    with_tree = any(r.tree_id is not None for r in results)
    chooser = las.ScaleChooser()
    chooser.add(cols["xyz"].T)
    offsets = chooser.offsets(cols["xyz"].min(axis=0)) if len(cols["xyz"]) else np.zeros(3)
    header = las.las_header(offsets, time_kind, with_tree=with_tree, with_echoes=with_echoes, crs=crs,
                            sensor=sensor, scales=chooser.scales(), energy_max=e_max)
    with laspy.open(str(path), mode="w", header=header) as w:
        las.zero_extra_bytes_stats(w.header)
        w.write_points(las.las_record(header, cols, with_tree=with_tree, with_echoes=with_echoes))
    return path.read_bytes()


@pytest.mark.parametrize("name", list(PATTERNS))
def test_fast_writer_equals_the_straightforward_one(tmp_path, name):
    res = _result(PATTERNS[name], seed=len(name))
    fast = las.write_scan_las(res, tmp_path / "fast.las").read_bytes()
    assert fast == _reference([res], tmp_path / "ref.las")
    back = laspy.read(tmp_path / "fast.las")
    i, k = np.asarray(back.scan_position), np.asarray(back.scan_angle_index)
    assert back.header.point_count == np.count_nonzero(res.cls != ESCAPE) == len(set(zip(i, k))) > 0
    assert np.allclose(back.xyz, res.points_m()[i, k], atol=0.5e-4)  # 0.1 mm grid at most
    assert np.array_equal(back.tree_id, res.tree_id[i, k])
    assert np.all(np.diff(back.gps_time) >= 0)  # firing order: time never steps back
    assert np.all(back.return_number == 1) and np.all(back.number_of_returns == 1)


def test_fast_writer_legs_blocks_and_edge_cases(tmp_path, monkeypatch):
    p = PATTERNS["tractor"]
    legs = [_result(p, 1, tree=False), _result(p, 2), _result(p, 3, escape_share=1.0)]  # one leg all escapes
    assert las.write_scan_las(legs, tmp_path / "a.las").read_bytes() == _reference(legs, tmp_path / "r.las")
    monkeypatch.setattr(las, "CHUNK_POINTS", 7)  # blocks of one row, records reallocated: the same bytes
    assert las.write_scan_las(legs, tmp_path / "b.las").read_bytes() == _reference(legs, tmp_path / "r.las")
    monkeypatch.undo()
    empty = _result(p, 4, escape_share=1.0)
    assert las.write_scan_las(empty, tmp_path / "e.las").read_bytes() == _reference([empty], tmp_path / "r.las")
    assert laspy.read(tmp_path / "e.las").header.point_count == 0
    one = _result(p, 5, escape_share=1.0)
    one.cls[3, 7] = CLASS_CODES["wood"]
    assert las.write_scan_las(one, tmp_path / "o.las").read_bytes() == _reference([one], tmp_path / "r.las")
    assert laspy.read(tmp_path / "o.las").header.point_count == 1


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # inf · 0 in the points
def test_fast_writer_refuses_nonfinite_and_out_of_range_points(tmp_path):
    p = PATTERNS["tractor"]
    res = _result(p, 6, escape_share=0.0)
    res.range_m[2, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        las.write_scan_las(res, tmp_path / "n.las")
    res.range_m[2, 3] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        las.write_scan_las(res, tmp_path / "i.las")
    res.range_m[2, 3] = 5e5  # 500 km from the others: beyond int32 at 0.1 mm
    with pytest.raises(OverflowError, match="does not fit"):
        las.write_scan_las(res, tmp_path / "o.las")
    assert sorted(x.name for x in tmp_path.iterdir()) == []  # nothing left behind


def test_fast_writer_with_echoes_equals_the_straightforward_one(tmp_path):
    """A [sensor] leg (echoes, returns 1-15, intensities) after a first-return leg."""
    p = PATTERNS["airborne"]
    n, m = p.n_rows, p.n_cols
    rng = np.random.default_rng(7)
    first = _result(p, 8)
    per_beam = rng.integers(0, 16, n * m)
    beam = np.repeat(np.arange(n * m), per_beam)
    ret = np.concatenate([np.arange(1, c + 1) for c in per_beam if c]).astype(np.uint8)
    k = len(beam)
    echoes = Echoes(beam, ret, np.repeat(per_beam, per_beam).astype(np.uint8),
                    np.sort(rng.uniform(1.0, 90.0, k)), rng.uniform(0.0, 80.0, k).astype(np.float32),
                    rng.uniform(0.5, 9.0, k).astype(np.float32), rng.choice(np.array([1, 2, 3], np.uint8), k),
                    rng.integers(0, 2**32, k, dtype=np.uint32), rng.integers(0, 9, k, dtype=np.uint32),
                    np.ones(k, np.float32))
    second = _result(p, 9)
    second.echoes, second.intensity, second.sensor = echoes, np.ones((n, m), np.float32), {"model": "t"}
    legs = [first, second]
    assert las.write_scan_las(legs, tmp_path / "a.las").read_bytes() == _reference(legs, tmp_path / "r.las")
    back = laspy.read(tmp_path / "a.las")
    counts = np.bincount(np.concatenate([np.ones(np.count_nonzero(first.cls != ESCAPE), np.uint8), ret]),
                         minlength=16)[1:]
    assert list(back.header.number_of_points_by_return) == list(counts)
    assert back.header.point_count == counts.sum()


@pytest.mark.parametrize("name", list(PATTERNS))
def test_beam_geometry_is_points_m_bit_for_bit(name):
    """The float64 points themselves (the LAS keeps them to 0.1 mm only): the direction table
    of the tractors and the swath, the per-point directions of the rotating head, the rosette's."""
    res = _result(PATTERNS[name], seed=11)
    keep = res.cls != ESCAPE
    i, k = np.nonzero(keep)
    geometry = las.BeamGeometry(res.pattern)
    assert (geometry.table is not None) == (name in ("tractor", "tractor-moving", "airborne"))
    assert geometry.points_m(i, k, res.range_m[i, k]).T.tobytes() == res.points_m()[keep].tobytes()
