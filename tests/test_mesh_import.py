"""Meshes users bring: OBJ and PLY primitives read once, checked, labelled, scanned."""
from __future__ import annotations

import os
import warnings

import numpy as np
import plyfile
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError, SimlidarWarning
from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.io import mesh_import
from simlidar_mi.io.mesh_import import read_mesh
from simlidar_mi.lidar.survey import generate, run_scan

QUAD = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
SCAN = ('[scan]\nx0_m = 1.0\nz0_m = 0.5\ny_start_m = -1.0\ny_end_m = 1.0\ndy_m = 0.05\n'
        'theta_min_deg = -5.0\ntheta_max_deg = 5.0\ndtheta_deg = 1.0\n')


def _ply(path, faces, fmt="binary_little_endian", face_props=None, vertices=None):
    v = np.array(vertices if vertices is not None else [(2, -1, 0), (2, 1, 0), (2, 1, 1), (2, -1, 1)], float)
    vert = np.empty(len(v), [("x", "f8"), ("y", "f8"), ("z", "f8")])
    vert["x"], vert["y"], vert["z"] = v.T
    fields = [("vertex_indices", "O")] + [(k, a.dtype.str) for k, a in (face_props or {}).items()]
    face = np.empty(len(faces), fields)
    for i, f in enumerate(faces):
        face["vertex_indices"][i] = np.asarray(f, np.int32)
    for k, a in (face_props or {}).items():
        face[k] = a
    plyfile.PlyData([plyfile.PlyElement.describe(vert, "vertex"), plyfile.PlyElement.describe(face, "face")],
                    text=fmt == "ascii", byte_order={"binary_little_endian": "<", "binary_big_endian": ">",
                                                     "ascii": "="}[fmt]).write(str(path))
    return path


# --- reading ------------------------------------------------------------------------------

@pytest.mark.parametrize("text", [
    QUAD + "f 1 2 3 4\n",                          # the fast block path
    QUAD + "f 1/1/1 2/1/1 3/1/1\nf 1//1 3//1 4//1\n",  # corners with texture/normal indices
    QUAD + "f -4 -3 -2\nf 1 -2 -1\n",              # negative: back from the last vertex read
    "v  0 0 0\nv 1 0 0\r\nv 1 1 0 1.0\nv 0 1 0\n\tf 1 2 3\nf -4 -2 -1\n",  # the general path
])
def test_obj_faces_are_fans_in_file_order(tmp_path, text):
    p = tmp_path / "m.obj"
    p.write_bytes(text.encode())
    m = read_mesh(p, "obj")
    assert m.faces.dtype == np.uint32 and m.vertices.dtype == np.float64
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert m.vertices.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]] and m.face_class is None


def test_obj_labels_without_names_leave_the_primitive_label(tmp_path):
    p = tmp_path / "plain.obj"
    p.write_text(QUAD + "f 1 2 3 4\n")
    with pytest.warns(SimlidarWarning, match="names no usemtl, g or o"):
        assert read_mesh(p, "obj", label="leaf", labels={"wood": ["Bark*"]}).face_class is None
    p.write_text("g Bark.001\n" + QUAD + "f 1 2 3\ng other\nf 1 3 4\n")
    assert read_mesh(p, "obj", label="leaf", labels={"wood": ["Bark*"]}).face_class.tolist() == [2, 3]


def test_obj_label_patterns_that_match_nothing_are_warned_with_the_names_found(tmp_path):
    """Patterns that match no name made every face wood without a word: a warning names the
    patterns and the file's names; patterns that match say nothing."""
    p = tmp_path / "tree.obj"
    p.write_text("o tree\nusemtl bark_mat\n" + QUAD + "f 1 2 3\nusemtl leaves_mat\nf 1 3 4\n")
    with pytest.warns(SimlidarWarning) as said:
        m = read_mesh(p, "obj", labels={"leaf": ["Leaf*"]})
    assert m.face_class is None  # every face wood, as before: but now said
    assert len(said) == 1 and str(said[0].message) == (
        f"{p}: labels.leaf patterns ['Leaf*'] match no name in the file, so no face is leaf (unmatched "
        "faces are wood); the file names usemtl bark_mat, leaves_mat; o tree (patterns are "
        "case-sensitive, '*' any text)")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_mesh(p, "obj", labels={"leaf": ["leaves*"]}).face_class.tolist() == [2, 3]
    # a PLY's label values alike: the values its faces hold are listed
    q = _ply(tmp_path / "t.ply", [[0, 1, 2], [0, 2, 3]], face_props={"part": np.array([0, 2], np.uint8)})
    with pytest.warns(SimlidarWarning) as said:
        read_mesh(q, "ply", labels={"wood": [0], "leaf": [1]}, label_property="part")
    assert [str(w.message) for w in said] == [
        f"{q}: labels.leaf values [1] match no face's part, so no face is leaf (unmatched faces are wood); "
        "its faces hold part 0, 2"]


def test_obj_keeps_float64_coordinates(tmp_path):
    """Far from the origin, the file's digits survive (no float32 before the scene origin)."""
    p = tmp_path / "far.obj"
    p.write_text("v 654321.123456 5432109.987654 100.25\nv 654322 5432110 100\nv 654321 5432111 100\nf 1 2 3\n")
    assert read_mesh(p, "obj").vertices[0].tolist() == [654321.123456, 5432109.987654, 100.25]


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_ply_encodings_read_alike(tmp_path, fmt):
    p = _ply(tmp_path / f"{fmt}.ply", [[0, 1, 2], [0, 2, 3]], fmt, {"class": np.array([0, 1], np.uint8)})
    m = read_mesh(p, "ply", labels={"leaf": [1]}, label_property="class")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert m.vertices[2].tolist() == [2, 1, 1]
    assert m.face_class.tolist() == [CLASS_CODES["wood"], CLASS_CODES["leaf"]]


def test_ply_polygons_become_fans(tmp_path):
    p = _ply(tmp_path / "quad.ply", [[0, 1, 2, 3]], face_props={"part": np.array([1], np.uint8)})
    m = read_mesh(p, "ply", labels={"leaf": [1]}, label_property="part")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert m.face_class is not None and m.face_class.tolist() == [3, 3]


def test_our_forest_export_reads_back(tmp_path):
    from simlidar_mi.io.mesh_export import write_ply
    v = np.random.default_rng(1).random((9, 3))
    write_ply(tmp_path / "s.ply", v, np.arange(9).reshape(3, 3), np.array([0, 1, 1], np.uint8))
    m = read_mesh(tmp_path / "s.ply", "ply", labels={"wood": [0], "leaf": [1]}, label_property="part")
    np.testing.assert_array_equal(m.vertices, v.astype(np.float32))
    assert m.face_class.tolist() == [2, 3, 3]


# --- bad input names the file, the key and the value ---------------------------------------

@pytest.mark.parametrize("text,words", [
    ("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "a non-finite vertex"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "a face index out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", "a face index out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n", "every face is degenerate"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4: a face index is not an integer"),
    ("v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", "line 2: a vertex coordinate is not a number"),
    ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: a vertex needs three coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: face index 0"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "a face index is not an integer"),
])
def test_obj_errors(tmp_path, text, words):
    p = tmp_path / "bad.obj"
    p.write_text(text)
    with pytest.raises(ConfigError, match=words) as exc:
        read_mesh(p, "obj", source="scene.toml", index=2)
    assert exc.value.key == "primitive[2].path" and exc.value.value == str(p) and exc.value.file == "scene.toml"


def test_obj_not_utf8(tmp_path):
    p = tmp_path / "bin.obj"
    p.write_bytes(b"v 0 0 0\n\xff\xfe\x00\x01 binary\n")
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        read_mesh(p, "obj")


@pytest.mark.parametrize("make,words", [
    (lambda d: (d / "junk.ply").write_bytes(b"not a ply at all\n") and d / "junk.ply", "not a readable PLY file"),
    (lambda d: _ply(d / "oor.ply", [[0, 1, 7]]), "a face index out of range"),
    (lambda d: _ply(d / "inf.ply", [[0, 1, 2]], vertices=[(0, 0, 0), (1, 0, np.inf), (0, 1, 0)]),
     "a non-finite vertex"),
    (lambda d: _ply(d / "line.ply", [[0, 1]]), "fewer than three vertices"),
    (lambda d: d / "missing.ply", "cannot read it"),
    (lambda d: d / "wrong.obj", r"must end in \.ply"),
])
def test_ply_errors(tmp_path, make, words):
    p = make(tmp_path)
    with pytest.raises(ConfigError, match=words) as exc:
        read_mesh(p, "ply", source="scene.toml", index=0)
    assert exc.value.key == "primitive[0].path" and "PLY mesh of primitive 0" in str(exc.value)


def test_ply_label_property_must_exist(tmp_path):
    p = _ply(tmp_path / "a.ply", [[0, 1, 2]])
    with pytest.raises(ConfigError, match="no face property 'class'"):
        read_mesh(p, "ply", labels={"leaf": [1]}, label_property="class")


def test_size_limit_is_checked_before_reading(tmp_path, monkeypatch):
    p = _ply(tmp_path / "a.ply", [[0, 1, 2]])
    monkeypatch.setattr(mesh_import, "MAX_MESH_BYTES", 16)
    monkeypatch.setattr(mesh_import, "read_ply_arrays", lambda *a: pytest.fail("read"))
    with pytest.raises(ConfigError, match="exceed the limit for mesh primitives, 16 bytes"):
        read_mesh(p, "ply")


@pytest.mark.parametrize("prim,key,words", [
    ('type = "box"\nmin_m = [0, 0, 0]\nmax_m = [1, 1, 1]\nlabels = {leaf = ["a"]}', "labels", "only mesh primitives"),
    ('type = "obj"\npath = "m.obj"\nlabels = {leaf = [1]}', "labels", "name patterns"),
    ('type = "ply"\npath = "m.ply"\nlabels = {leaf = [1]}', "label_property", "need label_property"),
    ('type = "ply"\npath = "m.ply"\nlabels = {bark = [1]}\nlabel_property = "part"', "labels", "unknown class"),
    ('type = "ply"\npath = "m.obj"', "path", r"must end in \.ply"),
])
def test_label_keys_checked_at_load(tmp_path, prim, key, words):
    scene = tmp_path / "s.toml"
    scene.write_text(f"[[primitive]]\n{prim}\n")
    with pytest.raises(ConfigError, match=words) as exc:
        load_scene(scene)
    assert exc.value.key == f"primitive[0].{key}"


# --- read once; hits report the face's class ------------------------------------------------

@pytest.mark.parametrize("grouped", [False, True])
def test_obj_groups_give_classes_and_hits_report_them(tmp_path, monkeypatch, grouped):
    """A wall at x = 2: its y < 0 half in group 'Bark', its y > 0 half in 'Leaves_1'. The file
    is read once per run (counted in a file: generation may run in a forked child). Grouped:
    as a big mesh is built, inside one shape group (the classes and ids through its tables)."""
    if grouped:
        from simlidar_mi.scene import build as build_mod
        monkeypatch.setattr(build_mod, "GROUP_MIN_TRIANGLES", 1)
    obj = tmp_path / "wall.obj"
    obj.write_text("o tree\n"
                   "v 2 -1 0\nv 2 0 0\nv 2 0 1\nv 2 -1 1\nv 2 1 0\nv 2 1 1\n"
                   "g Bark\nf 1 2 3 4\n"
                   "g Leaves_1\nf 2 5 6\nf 2 6 3\n")
    scene = tmp_path / "wall.toml"
    scene.write_text(f'[[primitive]]\ntype = "box"\nmin_m = [5, -1, 0]\nmax_m = [6, 1, 1]\n'
                     f'[[primitive]]\ntype = "obj"\npath = "{obj.name}"\nlabels = {{leaf = ["Leaves*"]}}\n'
                     '[ground]\nenabled = false\n' + SCAN)
    log = tmp_path / "reads"
    real = mesh_import.parse_obj_file

    def counted(p, **kw):
        with open(log, "a") as fh:
            fh.write("read\n")
        return real(p, **kw)
    monkeypatch.setattr(mesh_import, "parse_obj_file", counted)
    cfg = load_scene(scene)
    assert generate(cfg).primitives[1].mesh.face_class.tolist() == [2, 2, 3, 3]
    log.unlink()
    r = run_scan(cfg, None).result
    assert log.read_text() == "read\n"  # bounds, build and sensor set-up reuse the arrays
    centre = int(np.argmin(np.abs(r.settings.theta_deg)))
    y = r.settings.y_m
    assert (r.cls[(y < -0.05) & (y > -0.95), centre] == CLASS_CODES["wood"]).all()
    assert (r.cls[(y > 0.05) & (y < 0.95), centre] == CLASS_CODES["leaf"]).all()
    hit = r.cls[:, centre] > 0
    assert (r.element_id[hit, centre] == 1).all()  # primitive 1: its element id, whatever the class
    np.testing.assert_allclose(r.range_m[hit, centre], 1.0, atol=1e-5)


def test_ply_face_property_gives_classes_in_hits(tmp_path):
    ply = _ply(tmp_path / "wall.ply", [[0, 1, 2], [0, 2, 3]], face_props={"class": np.array([7, 9], np.uint8)},
               vertices=[(2, -1, 0), (2, 1, 0), (2, 1, 1), (2, -1, 1)])
    scene = tmp_path / "wall.toml"
    scene.write_text(f'[[primitive]]\ntype = "ply"\npath = "{ply.name}"\nlabel = "leaf"\n'
                     'labels = {wood = [7]}\nlabel_property = "class"\n[ground]\nenabled = false\n' + SCAN)
    r = run_scan(load_scene(scene), None).result
    centre = int(np.argmin(np.abs(r.settings.theta_deg)))
    # triangle 0 (0, 1, 2) lies below the diagonal z = (y + 1) / 2 of the wall, triangle 1 above
    y, z = r.settings.y_m, 0.5
    below = (y > -1) & (y < 1) & (z < (y + 1) / 2 - 0.03)
    above = (y > -1) & (y < 1) & (z > (y + 1) / 2 + 0.03)
    assert below.sum() > 5 and above.sum() > 5
    assert (r.cls[below, centre] == CLASS_CODES["wood"]).all()
    assert (r.cls[above, centre] == CLASS_CODES["leaf"]).all()  # 9 is unlisted: the primitive's label


def test_forest_exported_as_ply_scans_like_the_forest(tmp_path):
    """`simlidar-mi forest`'s PLY scanned as a mesh primitive (faces labelled by `part`) against the
    same forest scanned natively. Leaves and ground agree; wood agrees within 2 %: the export's
    prisms are open and keep the branch radius, the scene's are capped and widened by
    π/(k·sin(π/k)) (+1.2 % at k = 12) to the cylinder's mean silhouette."""
    from simlidar_mi.forest.outputs import write_stand
    from simlidar_mi.forest.stand import make_forest
    from tests.conftest import SCENES
    over = ["platform.waypoints_m=[[0.0, -2.0, 2.0], [20.0, -2.0, 2.0]]", "platform.step_m=0.2",
            "platform.elevation_deg=[-30.0, 60.0, 0.5]", "scene.facets=12"]
    text = (SCENES / "forest_road_scan.toml").read_text()
    cfg = load_scene(SCENES / "forest_road_scan.toml", over + ["forest.domain_m=[0.0, 20.0, 0.0, 20.0]"])
    write_stand(make_forest(cfg), tmp_path / "stand.ply", "ply", facets=12)
    (tmp_path / "ply.toml").write_text(text[:text.index("[forest]")] + '[[primitive]]\ntype = "ply"\n'
                                       'path = "stand.ply"\nlabels = {wood = [0], leaf = [1]}\n'
                                       'label_property = "part"\n')
    native = run_scan(cfg, None).measures["hits"]
    mesh = run_scan(load_scene(tmp_path / "ply.toml", over), None).measures["hits"]
    assert native["wood"] > 1000 and native["leaf"] > 100 and native["ground"] > 1000
    assert abs(mesh["leaf"] - native["leaf"]) <= 0.01 * native["leaf"]
    assert abs(mesh["ground"] - native["ground"]) <= 0.01 * native["ground"]
    assert 0.98 * native["wood"] <= mesh["wood"] <= native["wood"]


def test_meshes_cross_from_a_forked_child_through_a_nameless_file(tmp_path):
    """run_scan generates in a forked child: its meshes come back whole through a file that has
    no name (nothing to leave behind if either process is killed)."""
    from simlidar_mi._runtime.fork import Forked
    from simlidar_mi.io.mesh_import import mesh_drop, unship_meshes
    from simlidar_mi.lidar.survey import _plan
    obj = tmp_path / "m.obj"
    obj.write_text("g Leaves\n" + QUAD + "f 1 2 3\ng Bark\nf 1 3 4\n")
    scene = tmp_path / "s.toml"
    scene.write_text(f'[[primitive]]\ntype = "obj"\npath = "{obj.name}"\nlabels = {{leaf = ["Leaves"]}}\n' + SCAN)
    cfg = load_scene(scene)
    want = generate(cfg).primitives[0].mesh
    with mesh_drop() as drop:
        job = Forked("generating", _plan, cfg, None, drop, parallel=True)
        geometry, _ = job.wait()
        job.close()
        assert os.fstat(drop).st_nlink == 0  # nameless
        assert os.fstat(drop).st_size == 4 * 3 * 8 + 2 * 3 * 4 + 2  # vertices, faces, classes
        got = unship_meshes(geometry.primitives, drop)[0].mesh
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.faces, want.faces)
    np.testing.assert_array_equal(got.face_class, [3, 2])
