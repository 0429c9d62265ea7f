"""Issue 29 §3, misattributed messages: each bad input ends in one line naming the key the user
set, its value and where it came from (the scene file or the ``--set``), exit 2 from the CLI;
an unreachable ``--scheduler`` leaves no output folder behind."""
from __future__ import annotations

import os
import socket
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi._runtime import cluster as _dask
from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.io.mesh_import import read_mesh
from simlidar_mi.lidar.platforms import airborne_pattern
from tests.conftest import SCENES

CALIB = str(SCENES / "calibration_cylinder.toml")
CLI = Path(sys.executable).with_name("simlidar-mi")


def _one_line(capsys, command: str, argv: list[str]) -> str:
    """Run the CLI; it must exit 2 with exactly one error line on stderr (which is returned)."""
    try:
        rc = main([command, *argv])
    except SystemExit as exc:  # argparse refuses an option's value itself (one line, exit 2)
        rc = exc.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("simlidar-mi ")]  # not progress lines
    assert rc == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"simlidar-mi {command}: error: ") and "Traceback" not in err
    return lines[0]


# --- meshes whose faces have no area, geometry that spans nothing ---------------------------

def _mesh_scene(tmp_path: Path, obj_text: str) -> str:
    (tmp_path / "m.obj").write_text(obj_text)
    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nname = "m"\n[[primitive]]\ntype = "obj"\npath = "m.obj"\n'
                     "[scan]\nx0_m = 1.0\nz0_m = 1.0\n")
    return str(scene)


def test_a_mesh_of_zero_area_faces_only_names_its_file(tmp_path, capsys):
    """Three vertices on one line (or one point): no beam can hit; the scan used to run to exit 0."""
    for i, obj in enumerate(["v 2 0 1.5\nv 2 0.1 1.5\nv 2 0.2 1.5\nf 1 2 3\n",
                             "v 2 0 1\nv 2 0 1\nv 2 0 1\nf 1 2 3\nf 3 2 1\n"]):
        scene = _mesh_scene(tmp_path, obj)
        line = _one_line(capsys, "scan", [scene, "--out", str(tmp_path / f"o{i}")])
        assert f"{scene}, key 'primitive[0].path', value '{tmp_path / 'm.obj'}': " in line
        assert "every face is degenerate (zero area" in line
        assert not (tmp_path / f"o{i}").exists()


def test_a_mesh_on_the_ground_does_not_blame_theta_min(tmp_path, capsys):
    """Eq. 8 derives both θ limits from the geometry; the user gave neither: name the geometry."""
    scene = _mesh_scene(tmp_path, "v 2 0 0\nv 3 0 0\nv 2 1 0\nf 1 2 3\n")
    line = _one_line(capsys, "scan", [scene, "--out", str(tmp_path / "o")])
    assert line.startswith(f"simlidar-mi scan: error: {scene}: eq. 8 derives θ limits -45.0000° … -45.0000°")
    assert "its top (z = 0 m) is not above the ground (z = 0.0 m)" in line and "key '" not in line


def test_a_mesh_with_no_y_extent_does_not_blame_y_end(tmp_path, capsys):
    scene = _mesh_scene(tmp_path, "v 2 0 0.5\nv 3 0 0.5\nv 2 0 1.5\nf 1 2 3\n")
    line = _one_line(capsys, "scan", [scene, "--out", str(tmp_path / "o")])
    assert line == (f"simlidar-mi scan: error: {scene}: the scene's geometry spans no y (from 0.0 to 0.0 m): "
                    "the tractor's line has no length; give scan.y_start_m and scan.y_end_m")


def test_given_theta_limits_in_the_wrong_order_name_the_one_given(tmp_path):
    with pytest.raises(ConfigError) as exc:
        from simlidar_mi.lidar.survey import run_scan
        run_scan(CALIB, None, ["scan.theta_max_deg=-70.0"])  # the file gives theta_min_deg = -60
    assert exc.value.file == CALIB and exc.value.key == "scan.theta_min_deg" and exc.value.value == -60.0


# --- the key that sized the step ------------------------------------------------------------

def test_a_huge_gap_blames_scan_gap_and_its_set(tmp_path, capsys):
    # past the key's range (schema bounds) and inside it (the step check): scan.gap either way
    item = "scan.gap=1000000000000000000"
    line = _one_line(capsys, "scan", [CALIB, "--out", str(tmp_path / "o"), "--set", item])
    assert line.startswith(f"simlidar-mi scan: error: --set {item}, key 'scan.gap', value 1000000000000000000: ")
    item = "scan.gap=1000000000"
    line = _one_line(capsys, "scan", [CALIB, "--out", str(tmp_path / "o"), "--set", item])
    assert line.startswith(f"simlidar-mi scan: error: --set {item}, key 'scan.gap', value 1000000000: "
                           "y span 0.5 m is shorter than one step (gap + 1)·dy_m = ")
    # a step too long without any gap is still dy_m's
    line = _one_line(capsys, "scan", [CALIB, "--out", str(tmp_path / "o"), "--set", "scan.dy_m=1.0"])
    assert ", key 'scan.dy_m', value 1.0: y span 0.5 m is shorter" in line


def test_pulses_per_line_blames_itself_not_the_flight_line(tmp_path, capsys):
    item = "platform.pulses_per_line=1000000000000"
    line = _one_line(capsys, "scan", [str(SCENES / "forest_airborne.toml"), "--out", str(tmp_path / "o"),
                                      "--set", item])
    # the schema's range now refuses it first; either way the key the user set is named
    assert line.startswith(f"simlidar-mi scan: error: --set {item}, key 'platform.pulses_per_line', "
                           "value 1000000000000: ")
    assert "end_xy_m" not in line


@pytest.mark.parametrize("speed,rate,ppl,key", [
    (1e9, 3e5, 400, "platform.speed_m_s"),       # 1e9 · 400 / 3e5 = 1.3e6 m
    (30.0, 1e-3, 400, "platform.pulse_rate_hz"),  # 30 · 400 / 1e-3 = 1.2e7 m
    (30.0, 3e5, 400, "platform.end_xy_m"),        # 0.04 m steps: the line (1 cm) is at fault
])
def test_the_airborne_step_blames_the_key_that_made_it_long(speed, rate, ppl, key):
    end = [0.0, 1000.0] if key != "platform.end_xy_m" else [0.0, 0.01]
    with pytest.raises(ConfigError) as exc:
        airborne_pattern([0.0, 0.0], end, 100.0, 40.0, speed, rate, ppl, source="s.toml")
    assert exc.value.key == key


def test_a_crawling_head_blames_rotation_hz(tmp_path, capsys):
    item = "platform.rotation_hz=1e-9"
    line = _one_line(capsys, "scan", [str(SCENES / "orchard_vlp16_tractor.toml"), "--out",
                                      str(tmp_path / "o"), "--set", item])
    assert line.startswith(f"simlidar-mi scan: error: --set {item}, key 'platform.rotation_hz', value 1e-09: "
                           "the head turns only 3.6e-06° during leg 0 (10 s), never into the sector "
                           "azimuth_range_deg = [-135.0, -45.0]")


def test_export_facets_past_a_ply_names_the_key_and_its_set(tmp_path, capsys):
    item = "forest.export_facets=1000000000"
    out = tmp_path / "o"
    line = _one_line(capsys, "forest", [str(SCENES / "forest_small.toml"), "--out", str(out), "--set", item])
    # the schema's range ([3, 64]) refuses it before the PLY's int32 check would
    assert line.startswith(f"simlidar-mi forest: error: --set {item}, key 'forest.export_facets', "
                           "value 1000000000: ")
    assert "n_vertices" not in line
    assert not out.exists()


def test_bad_fisheye_coeffs_name_coeffs_and_the_set(tmp_path, capsys):
    coeffs = "fisheye.coeffs=[-1.0]"
    line = _one_line(capsys, "fisheye", [str(SCENES / "random_leaves_spherical.toml"), "--out",
                                         str(tmp_path / "o"), "--set", "fisheye.projection=polynomial",
                                         "--set", coeffs])
    assert line.startswith(f"simlidar-mi fisheye: error: --set {coeffs}, key 'fisheye.coeffs', value [-1.0]: "
                           "polynomial lens needs finite coefficients")


def test_bad_fisheye_coeffs_in_the_file_name_the_file(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text((SCENES / "random_leaves_spherical.toml").read_text()
                     + '\n[fisheye]\nprojection = "polynomial"\ncoeffs = [0.0, 1.0]\n')
    if "[fisheye]" in (SCENES / "random_leaves_spherical.toml").read_text():
        pytest.skip("the scene has its own [fisheye] table")
    from simlidar_mi.canopy.fisheye_run import fisheye_cameras
    with pytest.raises(ConfigError) as exc:
        fisheye_cameras(load_scene(scene), np.zeros(3), np.ones(3))
    assert exc.value.file == str(scene) and exc.value.key == "fisheye.coeffs"


# --- PLY counts -----------------------------------------------------------------------------

def _ply(path: Path, n_vertex: str, n_face: str, body: bytes, fmt: str = "ascii") -> Path:
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex {n_vertex}\nproperty float x\nproperty float y\n"
                     f"property float z\nelement face {n_face}\nproperty list uchar int vertex_indices\n"
                     "end_header\n".encode() + body)
    return path


ASCII_TRI = b"2 0 0\n2 1 0\n2 0 1\n3 0 1 2\n"
BINARY_TRI = struct.pack("<9f", 2, 0, 0, 2, 1, 0, 2, 0, 1) + struct.pack("<Biii", 3, 0, 1, 2)


@pytest.mark.parametrize("n_vertex,n_face,fmt,words", [
    ("-3", "1", "ascii", "header line 'element vertex -3': an element count must be a whole number ≥ 0"),
    ("3", "-1", "binary_little_endian", "header line 'element face -1': an element count must be a whole number ≥ 0"),
    ("3", "1.5", "ascii", "header line 'element face 1.5': an element count must be a whole number ≥ 0"),
    ("300000000", "1", "binary_little_endian", "header line 'element vertex 300000000': the file holds only 49 "
                                               "bytes after its header, too few for 300000000 vertex rows"),
    ("5", "1", "ascii", "its header announces 5 vertex and 1 face rows: a count larger than the data"),
    ("3", "5", "binary_little_endian", "its header announces 3 vertex and 5 face rows: a count larger"),
])
def test_ply_counts_that_do_not_match_say_so(tmp_path, n_vertex, n_face, fmt, words):
    path = _ply(tmp_path / "m.ply", n_vertex, n_face, ASCII_TRI if fmt == "ascii" else BINARY_TRI, fmt)
    with pytest.raises(ConfigError) as exc:
        read_mesh(path, "ply", source="s.toml", index=0)
    assert exc.value.file == "s.toml" and exc.value.key == "primitive[0].path"
    assert words in str(exc.value) and "negative dimensions" not in str(exc.value)


def test_a_ply_with_a_negative_count_is_one_cli_line(tmp_path, capsys):
    _ply(tmp_path / "m.ply", "-3", "1", BINARY_TRI, "binary_little_endian")
    scene = tmp_path / "s.toml"
    scene.write_text('[scene]\nname = "m"\n[[primitive]]\ntype = "ply"\npath = "m.ply"\n')
    line = _one_line(capsys, "scan", [str(scene), "--out", str(tmp_path / "o")])
    assert line.startswith(f"simlidar-mi scan: error: {scene}, key 'primitive[0].path', ")
    assert line.endswith("header line 'element vertex -3': an element count must be a whole number ≥ 0")


# --- a byte-order mark ----------------------------------------------------------------------

def test_a_utf8_byte_order_mark_is_accepted(tmp_path, capsys):
    """Windows editors write one; TOML forbids it, we drop it: same scene, same digest."""
    plain = Path(CALIB).read_bytes()
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + plain)
    a, b = load_scene(CALIB), load_scene(bom)
    assert a.sha256 == b.sha256 and a["scan"] == b["scan"]
    assert load_scene(text="\ufeff" + plain.decode()).sha256 == a.sha256
    assert main(["measure", str(bom)]) == 0


@pytest.mark.parametrize("encoding,name", [("utf-16", "UTF-16"), ("utf-32", "UTF-32")])
def test_a_utf16_or_utf32_file_is_one_line(tmp_path, capsys, encoding, name):
    path = tmp_path / "s.toml"
    path.write_bytes(Path(CALIB).read_text().encode(encoding))  # Python writes the BOM first
    line = _one_line(capsys, "measure", [str(path)])
    assert line == (f"simlidar-mi measure: error: {path}: scene file is {name} text (it starts with a "
                    f"{name} byte-order mark); save it as UTF-8")


# --- fisheye photos -------------------------------------------------------------------------

PHOTO = str(SCENES / "photos" / "strawberry_full_nadir.jpg")


@pytest.mark.parametrize("circle", ["nan,nan,100", "100,nan,100", "100,100,inf"])
def test_a_non_finite_circle_is_one_line_naming_it(tmp_path, capsys, circle):
    """nan,nan,100 used to be blamed on a uniform blue channel; 100,100,inf ran to exit 0 with NaN rings."""
    line = _one_line(capsys, "fisheye-photo", [PHOTO, "--out", str(tmp_path / "o"), "--circle", circle])
    # the option's own type refuses it (argparse, one line), before any photo is read
    assert line.startswith("simlidar-mi fisheye-photo: error: argument --circle: ") and "finite" in line
    assert not (tmp_path / "o" / "fisheye_photo_gap.csv").exists()


def test_a_uniformly_lit_photo_is_one_line(tmp_path, capsys):
    """No dark surround: no circle edge anywhere (an IndexError in the circle fit before)."""
    from PIL import Image
    path = tmp_path / "sky.png"
    Image.fromarray(np.full((120, 160, 3), 200, np.uint8)).save(path)
    line = _one_line(capsys, "fisheye-photo", [str(path), "--out", str(tmp_path / "o")])
    assert line == (f"simlidar-mi fisheye-photo: error: {path}: no image circle found (the photo is lit up "
                    "to its frame, with no dark surround); give the circle (--circle XC,YC,R), or --format "
                    "fullframe")


# --- Dask addresses -------------------------------------------------------------------------

def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("address,words", [
    ("inproc://foo", "an inproc:// address names a scheduler inside this same Python process"),
    ("inproc://127.0.0.1/1/1", "an inproc:// address names a scheduler inside this same Python process"),
    ("ucx://127.0.0.1:1", "the ucx:// protocol needs the distributed-ucxx package"),
    ("garbage!!", "(not an address: missing port number in address 'garbage!!')"),
    ("http://127.0.0.1:1", "(unknown address scheme 'http' (known schemes: "),
])
def test_inproc_and_ucx_addresses_are_one_clear_line(address, words):
    pytest.importorskip("distributed")
    if address.startswith("ucx") and __import__("importlib").util.find_spec("distributed_ucxx"):
        pytest.skip("distributed-ucxx is installed")
    with pytest.raises(ConfigError) as exc:
        _dask._connect(address, 2.0)
    msg = str(exc.value)
    assert exc.value.key == "scheduler" and exc.value.value == address and words in msg
    for internal in ("ValueError", "TypeError", "unpack", "abstract"):
        assert internal not in msg


@pytest.mark.parametrize("command", ["study", "scan"])
@pytest.mark.parametrize("form", ["tcp", "bare", "inproc", "ucx", "garbage"])
def test_an_unreachable_scheduler_leaves_no_study_folder(tmp_path, capsys, monkeypatch, form, command):
    """study made out/rows/ before it asked the scheduler; nothing is made until one answers
    (scan, whose row tiles go to the cluster, already made nothing: kept so)."""
    pytest.importorskip("distributed")
    monkeypatch.setenv(_dask.TIMEOUT_ENV, "2")
    port = _closed_port()
    address = {"tcp": f"tcp://127.0.0.1:{port}", "bare": f"127.0.0.1:{port}", "inproc": "inproc://x",
               "ucx": f"ucx://127.0.0.1:{port}", "garbage": "garbage!!"}[form]
    out = tmp_path / "o"

    def study() -> str:
        scene = SCENES / ("apple_orchard.toml" if command == "study" else "calibration_cylinder.toml")
        argv = [str(scene), "--out", str(out), "--scheduler", address]
        if form not in ("tcp", "bare"):
            return _one_line(capsys, command, argv)
        # a Client that tried a port keeps threads that complain when the interpreter ends: the
        # program's own exit skips that, so run the program
        proc = subprocess.run([str(CLI), command, *argv], capture_output=True, text=True, timeout=300,
                              env={**os.environ, _dask.TIMEOUT_ENV: "2"})
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("simlidar-mi ")]
        assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        return lines[0]
    line = study()
    assert f"key 'scheduler', value '{address}': cannot reach the Dask scheduler" in line
    assert not out.exists()
    # a folder the user had keeps what it held, and gains nothing
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    study()
    assert sorted(os.listdir(out)) == ["mine.txt"] and (out / "mine.txt").read_text() == "keep"
