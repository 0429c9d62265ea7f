"""Bad input names what the user wrote: --set arguments, the key that made a scan too big,
OBJ primitives (index, file; checked before reading), and a scanner standing inside wood."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from simlidar_mi import cli
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError, SimlidarWarning
from simlidar_mi.geometry import Branches, Leaves, Primitive
from simlidar_mi.lidar.survey import SceneGeometry, generate, run_scan
from simlidar_mi.io import mesh_import as import_mod
from simlidar_mi.io.mesh_import import read_mesh
from tests.conftest import SCENES

CALIB = SCENES / "calibration_cylinder.toml"


# --- --set overrides name the --set argument ------------------------------------------

@pytest.mark.parametrize("item,words", [
    ("scan.dtheta_deg=abc", "expected a number"),
    ("scan.dtheta_deg=-1", "must be > 0"),
    ("scan.dtheta_dg=0.5", "unknown key in [scan]"),
    ("scna.dtheta_deg=0.5", "unknown section 'scna'"),
])
def test_set_errors_name_the_set_argument(item, words):
    with pytest.raises(ConfigError) as exc:
        load_scene(CALIB, [item])
    msg = str(exc.value)
    assert msg.startswith(f"--set {item}, key ") and words in msg
    assert exc.value.file == f"--set {item}"
    assert "calibration_cylinder.toml" not in msg


def test_file_errors_still_name_the_file(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[scan]\ndtheta_deg = -1.0\n")
    with pytest.raises(ConfigError) as exc:
        load_scene(path, ["scan.dy_m=0.01"])  # a valid override does not take the blame
    assert exc.value.file == str(path) and exc.value.key == "scan.dtheta_deg"


# --- too many beams: blame the key that grew the count ------------------------------------

@pytest.mark.parametrize("item,key", [
    ("scan.dtheta_deg=1e-6", "scan.dtheta_deg"),   # 90° / 1e-6 = 9e7 angles × 250 positions
    ("scan.dtheta_deg=5e-324", "scan.dtheta_deg"),  # 90° / 5e-324 overflows a float
    ("scan.dy_m=1e-9", "scan.dy_m"),
    ("scan.footprint=64", "scan.footprint"),  # within its range [0, 64], 3.8e8 sub-beams past max_beams
])
def test_too_many_beams_names_the_key_the_user_changed(item, key):
    """A tiny dtheta_deg used to be reported as a bad scan.dy_m."""
    with pytest.raises(ConfigError) as exc:
        run_scan(CALIB, None, [item])
    assert exc.value.key == key
    assert exc.value.file == f"--set {item}"
    assert "exceeds scan.max_beams = 200000000" in str(exc.value)


def test_too_many_beams_from_the_file_names_the_file(tmp_path):
    path = tmp_path / "fine.toml"
    path.write_text(CALIB.read_text().replace("dtheta_deg = 0.25", "dtheta_deg = 1e-7"))
    with pytest.raises(ConfigError) as exc:
        run_scan(path, None)
    assert exc.value.key == "scan.dtheta_deg" and exc.value.file == str(path)


def test_cli_prints_one_line_naming_the_set_argument(tmp_path, capsys):
    rc = cli.main(["scan", str(CALIB), "--set", "scan.dtheta_deg=1e-9", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("simlidar-mi scan: error: --set scan.dtheta_deg=1e-9, key 'scan.dtheta_deg'")
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "o").exists()


# --- OBJ primitives ------------------------------------------------------------------------

def _obj_scene(tmp_path, obj_path: str):
    scene = tmp_path / "with_obj.toml"
    scene.write_text('[[primitive]]\ntype = "box"\nmin_m = [2.0, -0.5, 0.0]\nmax_m = [3.0, 0.5, 1.0]\n'
                     f'[[primitive]]\ntype = "obj"\npath = "{obj_path}"\n')
    return scene


def test_obj_error_names_primitive_index_scene_and_obj(tmp_path):
    obj = tmp_path / "bent.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    scene = _obj_scene(tmp_path, obj.name)
    with pytest.raises(ConfigError) as exc:
        run_scan(scene, tmp_path / "out")
    msg = str(exc.value)
    assert exc.value.key == "primitive[1].path" and exc.value.file == str(scene)
    assert "bent.obj" in msg and "OBJ mesh of primitive 1" in msg and "line 4" in msg


@pytest.mark.parametrize("make,words", [
    (lambda d: "/etc/passwd", "must end in .obj"),
    (lambda d: (d / "dir.obj").mkdir() or d / "dir.obj", "not a regular file"),
    (lambda d: d / "missing.obj", "cannot read it"),
])
def test_obj_checked_before_reading(tmp_path, monkeypatch, make, words):
    """/etc/passwd given as an OBJ was read line by line before being refused."""
    path = make(tmp_path)

    def no_read(*args, **kwargs):
        raise AssertionError("the file was read")
    monkeypatch.setattr(import_mod, "parse_obj_file", no_read)
    with pytest.raises(ConfigError, match=words) as exc:
        read_mesh(str(path), "obj", source="scene.toml", index=3)
    assert exc.value.key == "primitive[3].path" and exc.value.value == str(path)
    assert exc.value.file == "scene.toml" and "OBJ mesh of primitive 3" in str(exc.value)


def test_obj_size_limit_and_scene_extension_check(tmp_path, monkeypatch):
    obj = tmp_path / "big.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert read_mesh(str(obj), "obj").faces.tolist() == [[0, 1, 2]]
    monkeypatch.setattr(import_mod, "MAX_MESH_BYTES", 16)
    with pytest.raises(ConfigError, match="32 bytes exceed the limit for mesh primitives, 16 bytes"):
        read_mesh(str(obj), "obj")
    # The scene file is refused at load time, naming the primitive.
    with pytest.raises(ConfigError) as exc:
        load_scene(_obj_scene(tmp_path, "/etc/passwd"))
    assert exc.value.key == "primitive[1].path" and ".obj" in str(exc.value)


# --- a scanner inside wood -----------------------------------------------------------------

def test_inside_wood_against_distances():
    """Points against a 0.2 m branch along z from (1, 0, 0) to (1, 0, 2), a cylinder
    primitive and a box primitive."""
    b = Branches(np.array([[1.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 2.0]]), np.array([0.2]),
                 np.ones(1, np.int32), np.zeros(1, np.int32))
    prims = [Primitive("cylinder", {"p0_m": [5.0, 0.0, 0.0], "p1_m": [5.0, 2.0, 0.0], "diameter_m": 0.1}),
             Primitive("box", {"min_m": [8.0, 0.0, 0.0], "max_m": [9.0, 1.0, 1.0]})]
    g = SceneGeometry(b, Leaves.empty(), prims)
    pts = np.array([[1.099, 0.0, 1.0],    # 0.099 m from the axis: inside
                    [1.101, 0.0, 1.0],    # 0.101 m: outside
                    [1.0, 0.0, 2.05],     # beyond the end: outside
                    [5.0, 1.0, 0.049],    # inside the cylinder primitive (element 1 + 0)
                    [8.5, 0.5, 0.5],      # inside the box (element 1 + 1)
                    [8.5, 1.5, 0.5]])
    inside, element = g.inside_wood(pts, chunk=2)
    assert inside.tolist() == [True, False, False, True, True, False]
    assert element.tolist() == [0, -1, -1, 1, 2, -1]


def test_scanner_inside_a_branch_warns_on_one_line(tmp_path, capsys):
    scene = tmp_path / "inside.toml"
    # The calibration cylinder, thickened to 0.3 m and moved onto the scanner line x = 1, y = 0.1.
    scene.write_text(CALIB.read_text().replace("diameter_m = 0.05", "diameter_m = 0.3")
                     .replace("[2.0, 0.0,", "[1.0, 0.1,").replace("dy_m = 0.002", "dy_m = 0.01"))
    rc = cli.main(["scan", str(scene), "--out", str(tmp_path / "o"), "--no-las", "--no-png"])
    err = capsys.readouterr().err
    assert rc == 0
    # y = −0.25 + 0.01·i inside 0.1 ± 0.15: i = 21 … 49, 29 of 50 positions.
    # one warning line; the other stderr lines are the piped progress ("scan: built ...")
    warnings = [ln for ln in err.splitlines() if "warning" in ln]
    assert warnings == ["simlidar-mi scan: warning: 29 of 50 scanner positions lie inside wood, the "
                        "first at [1.0, -0.04, 1.0] m in primitive 0: their beams start inside it and "
                        "report its inner wall; move the scanner (scan.x0_m/z0_m or the platform)"]
    assert all(ln.startswith("scan: ") for ln in err.splitlines() if ln not in warnings)


def test_no_warning_for_the_shipped_scanner_positions():
    cfg = load_scene(SCENES / "apple_orchard.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error", SimlidarWarning)
        g = generate(cfg)
        from simlidar_mi.lidar.survey import scan_patterns, warn_scanner_inside_wood
        lo, hi = g.bounds_m()
        assert warn_scanner_inside_wood(g, scan_patterns(cfg, lo, hi, g.near_x_m)) == 0


def test_one_obj_parser_for_primitives_and_exports(tmp_path):
    """Scene primitives and export round trips read OBJ through the same parser: quads become
    fans, negative indices count back, and objects keep their own vertices."""
    from simlidar_mi.io.mesh_export import read_obj as read_export
    obj = tmp_path / "two.obj"
    obj.write_text("o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
                   "o b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n")
    m = read_mesh(str(obj), "obj")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6]] and m.vertices.shape == (7, 3)
    parts = read_export(obj)
    assert parts["a"][1].tolist() == [[0, 1, 2], [0, 2, 3]]
    assert parts["b"][1].tolist() == [[0, 1, 2]] and parts["b"][0][:, 2].tolist() == [1, 1, 1]
    (tmp_path / "bad.obj").write_text("v 0 0 0\nf 1 2\n")
    with pytest.raises(ConfigError, match="line 2: a face needs three vertices"):
        read_export(tmp_path / "bad.obj")
