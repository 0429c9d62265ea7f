"""EXR and LAS outputs of a scan with echoes, read back; without echoes, the bytes of old.

The "old" writers below are main's (commit 0d296f5) first-return writers, kept verbatim as
the expectation: a scan without a ``[sensor]`` must give the same files byte for byte.
"""
from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import OpenEXR
import pytest
from laspy.vlrs.known import WktCoordinateSystemVlr

from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.io.exr import header_value, read_exr, write_scan_exr
from simlidar_mi.io.las import LAS_CLASS, TIME_SCAN_ORDER, crs_wkt, scan_times_s, write_scan_las
from simlidar_mi.io import las_fields
from simlidar_mi.lidar.platforms import path_patterns, static_pattern
from simlidar_mi.lidar.scan import ScanResult
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.lidar.waveform import detect_echoes, first_return_arrays, range_fwhm_m
from tests.conftest import SCENES
from tests.las_conformance import check_las

WOOD, LEAF, GROUND = CLASS_CODES["wood"], CLASS_CODES["leaf"], CLASS_CODES["ground"]
SENSOR = {"preset": None, "divergence_mrad": 2.0, "max_returns": 3, "pulse_length_ns": 3.0,
          "detection_threshold": 0.02, "intensity": True, "wavelength_nm": 905.0,
          "intensity_scale": 300.0, "intensity_range_m": 0.5}


def _echo_result(*, intensity=True, max_returns=3, tree=True) -> ScanResult:
    """A 4 × 5 static pattern; beam b has b % 4 targets 4·FWHM apart (beam 0 escapes), with
    classes wood, leaf, ground and one strong echo (E = 80: 24 000 counts at the scale 300)."""
    pattern = static_pattern([10.0, -3.0, 1.5], (-20.0, 20.0, 10.0), (0.0, 40.0, 10.0))
    n, m = pattern.n_rows, pattern.n_cols
    b, s, fwhm = n * m, 2, range_fwhm_m(3.0)
    r = np.full((b, 3 * s), np.inf)
    e = np.zeros((b, 3 * s))
    cls = np.zeros((b, 3 * s), np.uint8)
    for beam in range(b):
        for j in range(beam % 4):
            r[beam, j * s:(j + 1) * s] = 3.0 + 0.1 * beam + 4 * fwhm * j
            e[beam, j * s:(j + 1) * s] = [0.05 * (j + 1), 0.01 * beam]
            cls[beam, j * s:(j + 1) * s] = (WOOD, LEAF, GROUND)[j]
    e[7, 0] = 80.0  # clipped at 65535 by the old fixed scale (1000 counts per E)
    elem = np.arange(r.size, dtype=np.uint32).reshape(r.shape)
    trees = (elem // 5).astype(np.uint32) if tree else None
    echoes = detect_echoes(r, e, cls, elem, trees, np.full(r.shape, 0.9), np.arange(b),
                           pulse_length_ns=3.0, detection_threshold=0.02, max_returns=max_returns)
    first = first_return_arrays(echoes, (n, m), pattern.escape_m)
    return ScanResult(None, first["range_m"], first["cls"], first["element_id"],
                      np.ones((n, m), np.float32), np.zeros(3), pattern=pattern,
                      tree_id=first["tree_id"], echoes=echoes, n_returns=first["n_returns"],
                      intensity=first["intensity"] if intensity else None,
                      sensor={**SENSOR, "intensity": intensity, "max_returns": max_returns})


def test_exr_has_every_echo_layer_and_the_sensor(tmp_path):
    res = _echo_result()
    n, m = res.shape
    path = write_scan_exr(res, tmp_path / "e.exr", seed=3)
    ch, header = read_exr(path)
    base = {"range", "class", "branch_id", "tree_id"}  # angle and row coordinate: header arrays
    layers = {f"echo{r}.{c}" for r in (2, 3)
              for c in ("range", "class", "class_half", "branch_id", "intensity", "tree_id")}
    assert set(ch) == base | {"class_half", "n_returns", "n_returns_half", "intensity"} | layers
    for c in ("class", "echo2.class", "echo3.class"):  # the half copies image tools read: same codes
        assert ch[f"{c}_half"].dtype == np.float16 and np.array_equal(ch[f"{c}_half"], ch[c]), c
    beam = np.arange(n * m).reshape(n, m)
    np.testing.assert_array_equal(ch["n_returns"], beam % 4)
    assert ch["n_returns"].dtype == np.uint32
    fwhm = range_fwhm_m(3.0)
    for r in (1, 2, 3):
        rng = ch["range"] if r == 1 else ch[f"echo{r}.range"]
        cls = ch["class"] if r == 1 else ch[f"echo{r}.class"]
        has = beam % 4 >= r
        np.testing.assert_allclose(rng[has], (3.0 + 0.1 * beam + 4 * fwhm * (r - 1))[has], atol=2e-6)
        assert np.all(rng[~has] == res.pattern.escape_m)
        np.testing.assert_array_equal(cls, np.where(has, (WOOD, LEAF, GROUND)[r - 1], 0))
    # intensity of echo 2: its two sub-rays' energies, 0.10 + 0.01·b
    np.testing.assert_allclose(ch["echo2.intensity"][beam % 4 >= 2],
                               (0.10 + 0.01 * beam)[beam % 4 >= 2], rtol=1e-6)
    assert np.all(ch["echo3.branch_id"][beam % 4 < 3] == 0xFFFFFFFF)
    assert header["sensor"] == res.sensor


def test_exr_without_intensity_has_no_intensity_channels(tmp_path):
    ch, header = read_exr(write_scan_exr(_echo_result(intensity=False, max_returns=2, tree=False),
                                         tmp_path / "e.exr"))
    assert "intensity" not in ch and "echo2.intensity" not in ch and "echo3.range" not in ch
    assert {"n_returns", "echo2.range", "echo2.class", "echo2.branch_id"} <= set(ch)
    assert header["sensor"]["max_returns"] == 2


def test_las_has_one_point_per_echo(tmp_path):
    res = _echo_result()
    ech = res.echoes
    las = laspy.read(write_scan_las(res, tmp_path / "e.las"))
    assert len(las) == len(ech) == sum(b % 4 for b in range(20))
    order = np.lexsort((np.asarray(las.return_number), np.asarray(las.scan_angle_index),
                        np.asarray(las.scan_position)))
    p = lambda name: np.asarray(las[name])[order]  # noqa: E731
    m = res.shape[1]
    np.testing.assert_array_equal(p("scan_position") * m + p("scan_angle_index"), ech.beam)
    np.testing.assert_array_equal(p("return_number"), ech.return_number)
    np.testing.assert_array_equal(p("number_of_returns"), ech.number_of_returns)
    e_max = float(ech.energy.max())  # 80.07: the strong echo
    scale = 818.4  # the scan's: 65535 / 80.07 = 818.47…, rounded down to 4 significant digits
    assert las_fields.scan_intensity_scale(e_max) == scale
    expected_i = np.rint(scale * ech.energy.astype(float))
    np.testing.assert_array_equal(p("intensity"), expected_i)
    assert 65470 <= p("intensity").max() <= 65535 and 0 < p("intensity").min()
    np.testing.assert_array_equal(p("echo_energy"), ech.energy)  # E unclipped, float32
    np.testing.assert_array_equal(p("classification"), [LAS_CLASS[c] for c in ech.cls])
    np.testing.assert_allclose(p("echo_width_ns"), ech.width_ns)
    np.testing.assert_allclose(p("range_m"), ech.range_m, rtol=1e-7)
    np.testing.assert_array_equal(p("tree_id"), ech.tree_id)
    # every echo of a pulse shares the pulse's time; points lie on the beam centre at the echo range
    i, k = np.divmod(ech.beam, m)
    np.testing.assert_array_equal(p("gps_time"), i + k / m)
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)[order]
    want = res.pattern.row_origin_m[i] + ech.range_m[:, None] * res.pattern.world_dirs()[i, k]
    np.testing.assert_allclose(xyz, want, rtol=0, atol=1e-4)  # 0.1 mm coordinate scale
    text = las.header.vlrs.get_by_id("simlidar-mi", [2])[0].record_data
    assert b"s = 818.4 counts per unit E, chosen for this scan" in text and b"E_max = 80.0699997 " in text  # float32 80.07
    assert json.loads(las.header.vlrs.get_by_id("simlidar-mi", [3])[0].record_data) == res.sensor


def test_las_intensity_off_writes_zero_and_too_many_returns_are_refused(tmp_path):
    las = laspy.read(write_scan_las(_echo_result(intensity=False, tree=False), tmp_path / "e.las"))
    assert np.all(np.asarray(las.intensity) == 0) and las.return_number.max() == 3
    res = _echo_result()
    res.echoes.number_of_returns[:] = 16
    with pytest.raises(ValueError, match="at most 15 returns"):
        write_scan_las(res, tmp_path / "f.las")


# ---- without echoes: main's bytes -------------------------------------------------------

@pytest.fixture(scope="module")
def calibration_scan():
    return run_scan(SCENES / "calibration_cylinder.toml", None, write_las=False, write_png=False).result


def _fake_legs():
    legs = path_patterns([[0, 0, 1], [2, 0, 1], [2, -2, 1]], 0.1, (-10.0, 10.0, 1.0))
    out = []
    for j, p in enumerate(legs):
        n, m = p.n_rows, p.n_cols
        cls = np.tile(np.array([WOOD, LEAF, GROUND, 0], np.uint8), n * m)[: n * m].reshape(n, m)
        out.append(ScanResult(None, np.full((n, m), 5.0 + j, np.float32), cls,
                              np.arange(n * m, dtype=np.uint32).reshape(n, m), np.ones((n, m), np.float32),
                              np.zeros(3), pattern=p, tree_id=np.full((n, m), j + 1, np.uint32)))
    return out


def test_las_without_echoes_keeps_main_values_in_standard_fields(tmp_path, calibration_scan):
    """A first-return file holds main's points and columns; only the fields main wrote against
    LAS 1.4 changed: return numbers 1 of 1 (counted in the header) and scan_angle the angle from
    nadir (both scans look right of their track: 90° + θ, θ the beam's elevation)."""
    for name, res, crs in (("calib", calibration_scan, "EPSG:25832"), ("legs", _fake_legs(), None)):
        new = write_scan_las(res, tmp_path / f"{name}_new.las", crs=crs)
        old = _main_write_scan_las(res, tmp_path / f"{name}_old.las", crs=crs)
        a, b = laspy.read(new), laspy.read(old)
        assert len(a) == len(b) > 100
        np.testing.assert_allclose(a.xyz, b.xyz, rtol=0, atol=1e-9)  # same points (scales may be coarser)
        for dim in ("classification", "gps_time", "point_source_id", "range_m", "scan_position",
                    "scan_angle_index", "branch_id", *(("tree_id",) if name == "legs" else ())):
            assert np.array_equal(np.asarray(a[dim]), np.asarray(b[dim])), (name, dim)
        assert np.all(np.asarray(b.return_number) == 0)  # main: no return numbers
        assert np.all(np.asarray(a.return_number) == 1) and np.all(np.asarray(a.number_of_returns) == 1)
        assert list(a.header.number_of_points_by_return) == [len(a)] + [0] * 14
        theta = np.asarray(b.scan_angle) * 0.006  # main wrote the elevation θ
        np.testing.assert_array_equal(np.asarray(a.scan_angle), np.round((90.0 + theta) / 0.006))
        np.testing.assert_allclose(np.asarray(a.elevation_deg), theta, atol=0.003)
        # the LAS 1.4 check written from the specification passes the new file, not main's
        assert check_las(new) == []
        problems = check_las(old)
        assert any("1 <= return number" in p for p in problems)
        assert any("min not zero while its option bit is clear" in p for p in problems)
        assert any("resolution fluff" in p for p in problems) == (name == "calib")  # y on a 2 mm grid


def test_exr_without_echoes_keeps_main_values(tmp_path, calibration_scan):
    """Issue #8 moved θ and y from N × M channels to 1-D header arrays; read_scan_exr
    (broadcast=True) gives back main's channels exactly, and every other channel and
    header value is main's."""
    from simlidar_mi.lidar.scan import read_scan_exr
    new = write_scan_exr(calibration_scan, tmp_path / "new.exr", seed=1, scene_sha256="x", extra={"a": 1})
    old = _main_write_scan_exr(calibration_scan, tmp_path / "old.exr", seed=1, scene_sha256="x", extra={"a": 1})
    ch_new, h_new = read_scan_exr(new, broadcast=True)
    ch_old, h_old = read_scan_exr(old, broadcast=True)
    assert set(ch_new) - {"class_half"} == set(ch_old) == {"range", "class", "branch_id", "theta_deg", "y_m"}
    for k in ch_old:
        assert ch_new[k].dtype == ch_old[k].dtype and np.array_equal(ch_new[k], ch_old[k]), k
    assert set(read_exr(new)[0]) == {"range", "class", "class_half", "branch_id"}
    assert np.array_equal(ch_new["class_half"], ch_old["class"])  # the half copy for image tools
    s = calibration_scan.settings
    assert np.array_equal(h_new["theta_deg"], s.theta_deg) and np.array_equal(h_new["y_m"], s.y_m)
    for k, v in h_old.items():
        if k in ("y_channel_note", "channels", "settings", "theta_deg", "y_m"):
            continue
        if isinstance(v, (np.ndarray, tuple)):  # origin_m; dataWindow / displayWindow (tuples of arrays)
            assert np.array_equal(np.asarray(h_new[k]), np.asarray(v)), k
        else:
            assert h_new[k] == v, k
    assert new.stat().st_size < 0.8 * old.stat().st_size


def _main_write_scan_las(result, path, crs=None) -> Path:
    """simlidar_mi/io/las.py:write_scan_las at 0d296f5 (first returns only)."""
    results = result if isinstance(result, list) else [result]
    parts, first_row, time_kind = [], 0, TIME_SCAN_ORDER
    for leg, res in enumerate(results):
        keep = res.cls != CLASS_CODES["escape"]
        i_idx, k_idx = np.nonzero(keep)
        tree = res.tree_id[keep] if res.tree_id is not None else np.full(len(i_idx), 0xFFFFFFFF, np.uint32)
        t, time_kind = scan_times_s(res, first_row)
        first_row += res.shape[0]
        parts.append((res.points_m()[keep], res.cls[keep], res.pattern.col_angle_deg[k_idx],
                      res.range_m[keep], i_idx, k_idx, res.element_id[keep],
                      np.full(len(i_idx), leg), tree, t[keep]))
    pts, cls, theta, rng, i_idx, k_idx, elem, source, tree, gps = (np.concatenate(c) for c in zip(*parts))
    with_tree = any(r.tree_id is not None for r in results)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([
        laspy.ExtraBytesParams("range_m", np.float32, description="first-return range (m)"),
        laspy.ExtraBytesParams("scan_position", np.uint32, description="sweep index i"),
        laspy.ExtraBytesParams("scan_angle_index", np.uint32, description="angle index k"),
        laspy.ExtraBytesParams("branch_id", np.uint32, description="element id"),
        *([laspy.ExtraBytesParams("tree_id", np.uint32, description="tree or plant id")] if with_tree else []),
    ])
    # The one change since main (issue #8): no Extra Bytes min/max statistics, which laspy
    # filled from one point per write call, so chunked files differed.
    for eb in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        eb.options &= ~(eb.MIN_BIT_MASK | eb.MAX_BIT_MASK)
    header.scales = np.array([0.0001, 0.0001, 0.0001])
    header.offsets = np.floor(pts.min(axis=0)) if len(pts) else np.zeros(3)
    header.generating_software = "simlidar-mi"
    header.global_encoding.wkt = True
    if crs is not None:
        header.vlrs.append(WktCoordinateSystemVlr(crs_wkt(crs)))
    header.vlrs.append(laspy.VLR("simlidar-mi", 1, "gps_time definition",
                                 (f"gps_time: {time_kind}\0").encode("ascii")))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = np.vectorize(LAS_CLASS.get, otypes=[np.uint8])(cls) if len(cls) else cls
    las.scan_angle = np.round(theta / 0.006).astype(np.int16)
    las.point_source_id = source.astype(np.uint16)
    las.gps_time = gps
    las.range_m = rng
    las.scan_position = i_idx.astype(np.uint32)
    las.scan_angle_index = k_idx.astype(np.uint32)
    las.branch_id = elem
    if with_tree:
        las.tree_id = tree
    las.write(str(path))
    return Path(path)


def _main_write_scan_exr(result, path, *, seed=None, scene_sha256="", extra=None) -> Path:
    """simlidar_mi/io/exr.py:write_scan_exr at 0d296f5 (first returns only)."""
    s, p = result.settings, result.pattern
    n, m = result.shape
    channels = {
        "range": np.ascontiguousarray(result.range_m, np.float32),
        "class": np.ascontiguousarray(result.cls, np.uint32),
        "branch_id": np.ascontiguousarray(result.element_id, np.uint32),
    }
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "origin_m": np.asarray(result.origin_m, np.float64), "scene_sha256": scene_sha256,
              "hit_rule": p.hit_rule}
    if s is not None:
        channels["theta_deg"] = np.ascontiguousarray(np.broadcast_to(s.theta_deg[None, :], (n, m)), np.float32)
        channels["y_m"] = np.ascontiguousarray(
            np.broadcast_to((s.y_m - result.origin_m[1])[:, None], (n, m)), np.float32)
        header["simlidar_settings"] = json.dumps(s.to_dict(), sort_keys=True)
        header["y_channel_note"] = "y_m channel is y minus origin_m[1]; range in metres"
        for key, value in s.to_dict().items():
            header[f"scan_{key}"] = header_value(value)
    else:
        channels["angle_deg"] = np.ascontiguousarray(np.broadcast_to(p.col_angle_deg[None, :], (n, m)), np.float32)
        channels["row_coord"] = np.ascontiguousarray(np.broadcast_to(p.row_coord[:, None], (n, m)), np.float32)
        header["simlidar_pattern"] = json.dumps(p.to_dict(), sort_keys=True)
        header["row_coord_label"] = p.row_label
        header["angle_label"] = p.col_label
    if result.tree_id is not None:
        channels["tree_id"] = np.ascontiguousarray(result.tree_id, np.uint32)
    if p.footprint > 0:
        channels["hit_fraction"] = np.ascontiguousarray(result.hit_fraction, np.float32)
    if seed is not None:
        header["seed"] = header_value(seed)
    for key, value in (extra or {}).items():
        header[key] = header_value(value)
    with OpenEXR.File(dict(header), dict(channels)) as f:
        f.write(str(path))
    return Path(path)
