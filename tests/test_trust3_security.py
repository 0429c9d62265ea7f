"""Trust round 3, security and data loss (issue #29, section 1): the output folder's lock never
follows a link, a run removes only what an earlier run recorded as its own output, ``--out ""``
is refused; and two silent wrong results of section 2 (mesh coordinates beyond float32, a
``--set`` value holding a line break)."""
from __future__ import annotations

import json
import logging
import os
import warnings
from pathlib import Path

import numpy as np
import plyfile
import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene, parse_override
from simlidar_mi.errors import ConfigError, OutputError, SimlidarWarning
from simlidar_mi.io import atomic
from simlidar_mi.io.atomic import LOCK_NAME, atomic_file, claim_output, staged_dir
from simlidar_mi.io.mesh_import import read_mesh
from tests.conftest import SCENES

CYLINDER = str(SCENES / "calibration_cylinder.toml")
VICTIM = b"precious: not a lock\n"


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


# --- the lock file is never followed, truncated or written through another name ------------


def test_a_symlinked_lock_is_refused_and_its_target_untouched(tmp_path, capsys):
    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    out = tmp_path / "d"
    out.mkdir()
    (out / LOCK_NAME).symlink_to(victim)
    assert main(["scan", CYLINDER, "--out", str(out)]) == 2
    err = _one_line(capsys)
    assert "symbolic link" in err and LOCK_NAME in err
    assert victim.read_bytes() == VICTIM
    assert (out / LOCK_NAME).is_symlink() and sorted(p.name for p in out.iterdir()) == [LOCK_NAME]


def test_a_dangling_symlinked_lock_creates_nothing(tmp_path):
    out = tmp_path / "d"
    out.mkdir()
    (out / LOCK_NAME).symlink_to(tmp_path / "made-by-us")
    with pytest.raises(OutputError, match="symbolic link"):
        with claim_output(out):
            pass
    assert not (tmp_path / "made-by-us").exists()


def test_a_hard_linked_lock_is_refused_and_the_other_name_untouched(tmp_path):
    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    out = tmp_path / "d"
    out.mkdir()
    os.link(victim, out / LOCK_NAME)
    with pytest.raises(OutputError, match="2 hard links"):
        with claim_output(out):
            pass
    assert victim.read_bytes() == VICTIM


@pytest.mark.parametrize("make", [os.mkfifo, os.mkdir])
def test_a_lock_that_is_not_a_regular_file_is_refused_in_one_line(tmp_path, make):
    out = tmp_path / "d"
    out.mkdir()
    make(out / LOCK_NAME)
    with pytest.raises(OutputError, match="is not a regular file"):
        with claim_output(out):
            pass


def test_a_lock_still_works_and_goes(tmp_path):
    out = tmp_path / "d"
    with claim_output(out):
        info = json.loads((out / LOCK_NAME).read_text())
        assert info["pid"] == os.getpid()
    assert not (out / LOCK_NAME).exists()


def test_atomic_file_sets_its_mode_by_descriptor_not_by_name(tmp_path, monkeypatch):
    # a name can be swapped for a link between mkstemp and chmod; fchmod cannot be redirected
    def by_name(*a, **k):
        raise AssertionError("chmod by name")
    monkeypatch.setattr(os, "chmod", by_name)
    with atomic_file(tmp_path / "x.txt") as tmp:
        tmp.write_text("1")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "x.txt").stat().st_mode & 0o777 == 0o666 & ~umask


# --- the study's rows/ ------------------------------------------------------------------------


def test_a_study_refuses_rows_that_is_a_link_and_writes_nothing_through_it(tmp_path):
    from simlidar_mi.lidar.study import run_study
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "study"
    out.mkdir()
    (out / "rows").symlink_to(elsewhere)
    grid = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=2.0", "scan.dy_m=0.05"]]
    with pytest.raises(OutputError, match="symbolic link"):
        run_study(SCENES / "apple_orchard.toml", out, grid, readings=False)
    assert list(elsewhere.iterdir()) == []


def test_a_row_named_by_a_link_is_not_read(tmp_path):
    from simlidar_mi.lidar.study import _read_row
    target = tmp_path / "other.json"
    target.write_text(json.dumps({"key": "abc", "A_IM_m2": 1.0}))
    (tmp_path / "abc.json").symlink_to(target)
    assert _read_row(tmp_path / "abc.json", quiet=True) is None
    (tmp_path / "abc.json").unlink()
    (tmp_path / "abc.json").write_text(target.read_text())  # the same row as a file: read
    assert _read_row(tmp_path / "abc.json", quiet=True) == {"key": "abc", "A_IM_m2": 1.0}


# --- a run removes only what an earlier run recorded as its output ------------------------


OWNS = [r"a\.txt", r"b\.txt", r"sub"]


def test_a_users_file_at_an_output_name_is_left_with_a_note(tmp_path, caplog):
    out = tmp_path / "o"
    out.mkdir()
    (out / "b.txt").write_text("the user's")
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.io.atomic"):
        with staged_dir(out, OWNS) as stage:
            (stage / "a.txt").write_text("1")
    assert (out / "b.txt").read_text() == "the user's"
    notes = [r.getMessage() for r in caplog.records if "b.txt" in r.getMessage()]
    assert len(notes) == 1 and notes[0].startswith("left ") and "\n" not in notes[0]
    assert atomic.recorded_output(out / "a.txt") and not atomic.recorded_output(out / "b.txt")


def test_an_earlier_output_is_removed_but_not_once_replaced_or_rewritten(tmp_path):
    out = tmp_path / "o"
    with staged_dir(out, OWNS) as stage:
        for name in ("a.txt", "b.txt"):
            (stage / name).write_text("run 1")
    with staged_dir(out, OWNS) as stage:  # b.txt not written again: it was ours, it goes
        (stage / "a.txt").write_text("run 2")
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"]
    (out / "b.txt").write_text("the user's")  # a user's file of the name since
    with out.joinpath("a.txt").open("a") as fh:  # and our own output rewritten in place (same inode)
        fh.write(", edited")
    with staged_dir(out, [r"a\.txt", r"b\.txt"]) as stage:
        pass
    assert (out / "a.txt").read_text() == "run 2, edited" and (out / "b.txt").read_text() == "the user's"


def test_a_link_at_an_output_name_is_left_and_its_target_untouched(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    (out / "b.txt").symlink_to(victim)
    (out / "a.txt").symlink_to(victim)
    with staged_dir(out, OWNS) as stage:
        (stage / "a.txt").write_text("ours")
    assert victim.read_bytes() == VICTIM
    assert (out / "b.txt").is_symlink()  # not ours: left
    assert not (out / "a.txt").is_symlink() and (out / "a.txt").read_text() == "ours"  # replaced, not written through


def test_a_users_folder_at_an_output_folder_name_is_refused_not_removed(tmp_path):
    out = tmp_path / "o"
    (out / "sub").mkdir(parents=True)
    (out / "sub" / "mine.ply").write_text("the user's")
    with pytest.raises(OutputError, match="holds a folder 'sub' that no earlier run wrote"):
        with staged_dir(out, OWNS) as stage:
            (stage / "a.txt").write_text("1")
            (stage / "sub").mkdir()
    assert (out / "sub" / "mine.ply").read_text() == "the user's"
    assert not (out / "a.txt").exists()  # all or nothing: no output moved
    # an output folder an earlier run wrote is still replaced as a whole
    (out / "sub" / "mine.ply").unlink()
    (out / "sub").rmdir()
    for text in ("1", "2"):
        with staged_dir(out, OWNS) as stage:
            (stage / "sub").mkdir()
            (stage / "sub" / f"{text}.ply").write_text(text)
    assert sorted(p.name for p in (out / "sub").iterdir()) == ["2.ply"]


def test_no_las_leaves_a_points_las_this_program_never_wrote(tmp_path, caplog):
    out = tmp_path / "d"
    out.mkdir()
    (out / "points.las").write_bytes(b"a user's LAS")
    (out / "scan_leg1.exr").write_bytes(b"a user's EXR")
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.io.atomic"):
        assert main(["scan", CYLINDER, "--out", str(out), "--no-las", "--no-png"]) == 0
    assert (out / "points.las").read_bytes() == b"a user's LAS"
    assert (out / "scan_leg1.exr").read_bytes() == b"a user's EXR"
    said = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("left ") and "points.las" in m for m in said)
    assert not any(m.startswith("removed ") for m in said)
    # the scan's own points.las of a run with LAS is removed by the next run without
    assert main(["scan", CYLINDER, "--out", str(out), "--no-png"]) == 0
    assert (out / "points.las").read_bytes()[:4] == b"LASF"
    assert main(["scan", CYLINDER, "--out", str(out), "--no-las", "--no-png"]) == 0
    assert not (out / "points.las").exists()


# --- --out "" ---------------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [
    ["scan", CYLINDER], ["study", str(SCENES / "apple_orchard.toml")],
    ["gapfraction", str(SCENES / "strawberry_plot.toml")], ["fisheye", str(SCENES / "strawberry_plot.toml")],
    ["synthetic-photo", str(SCENES / "strawberry_plot.toml")], ["forest", str(SCENES / "forest_small.toml")],
    ["compare", str(SCENES / "strawberry_manifest.csv")], ["truth", CYLINDER], ["preview", CYLINDER],
    ["evaluate", CYLINDER], ["evaluate-photo", str(SCENES / "strawberry_plot.toml")],
    ["fisheye-photo", "missing.jpg"], ["photo-gap", "missing.jpg", "--method", "canopeo"],
    ["evaluate-als", str(SCENES / "forest_als_small.toml"), "--points", "missing.las"],
])
@pytest.mark.parametrize("empty", ["", "  "])
def test_an_empty_out_is_refused_in_one_line(tmp_path, monkeypatch, capsys, argv, empty):
    monkeypatch.chdir(tmp_path)  # were it taken for '.', the files would land here
    assert main(argv + ["--out", empty]) == 2
    assert "--out" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_every_command_with_out_is_covered():
    from simlidar_mi.cli import build_parser
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices
    with_out = {name for name, p in sub.items() if any("--out" in a.option_strings for a in p._actions)}
    covered = {"scan", "study", "gapfraction", "fisheye", "synthetic-photo", "forest", "compare",
               "truth", "preview", "evaluate", "evaluate-photo", "fisheye-photo", "photo-gap", "evaluate-als"}
    assert with_out <= covered, with_out - covered


def test_an_empty_mask_dir_is_refused(tmp_path, monkeypatch, capsys):
    """--mask-dir, photo-gap's older name for --out, is refused empty as --out is."""
    monkeypatch.chdir(tmp_path)
    assert main(["photo-gap", "missing.jpg", "--method", "canopeo", "--mask-dir", ""]) == 2
    assert "--out ''" in _one_line(capsys) and list(tmp_path.iterdir()) == []


def test_the_library_refuses_an_empty_output_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputError, match="names nothing"):
        with claim_output(""):
            pass
    assert list(tmp_path.iterdir()) == []


# --- --set with a line break ----------------------------------------------------------------


def test_a_set_value_with_a_line_break_is_refused(capsys, tmp_path):
    for item in ("scan.dtheta_deg=0.5\nscan.x0_m=3", "scene.name=a\r\nb", 'scene.name="""a\nb"""'):
        with pytest.raises(ConfigError, match="holds a line break"):
            parse_override(item)
    with pytest.raises(ConfigError, match="holds a line break"):
        load_scene(CYLINDER, ["scan.dtheta_deg=0.5\nscan.x0_m=3"])
    assert main(["scan", CYLINDER, "--out", str(tmp_path / "o"), "--set", "scan.dtheta_deg=0.5\nscan.x0_m=3"]) == 2
    err = _one_line(capsys)
    assert "--set" in err and "line break" in err
    assert parse_override("scene.name=a\\nb") == ("scene.name", "a\\nb")  # an escape is no line break


# --- mesh coordinates -------------------------------------------------------------------------


@pytest.mark.parametrize("big", ["1e39", "-1e300", "inf", "nan"])
def test_an_obj_vertex_beyond_float32_is_refused_naming_its_line(tmp_path, big):
    p = tmp_path / "m.obj"
    p.write_text(f"# a mesh\nv 0 0 0\nv 1 0 0\n\nv 1 {big} 0\nv 0 1 0\nf 1 2 3 4\n")
    with pytest.raises(ConfigError) as exc:
        read_mesh(p, "obj", source="s.toml", index=0)
    msg = str(exc.value)
    assert "vertex 2 (0-based), line 5" in msg and str(p) in msg and "\n" not in msg
    assert ("non-finite" if big in ("inf", "nan") else "beyond float32's range") in msg


def test_a_ply_vertex_beyond_float32_is_refused_naming_its_index(tmp_path):
    v = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 1e39)], [("x", "f8"), ("y", "f8"), ("z", "f8")])
    face = np.empty(1, [("vertex_indices", "O")])
    face["vertex_indices"][0] = np.array([0, 1, 2, 3], np.int32)
    p = tmp_path / "m.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(face, "face")]).write(str(p))
    with pytest.raises(ConfigError, match=r"beyond float32's range .*: vertex 3 \(0-based\)"):
        read_mesh(p, "ply")
    v["z"][3] = 3.4e38  # within float32: read (the precision check speaks at build)
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(face, "face")]).write(str(p))
    assert read_mesh(p, "ply").vertices[3, 2] == 3.4e38


def _mesh_scene(tmp_path, x_m: float) -> str:
    (tmp_path / "m.obj").write_text(f"v {x_m} 0 0\nv {x_m} 0.005 0\nv {x_m} 0 0.005\nf 1 2 3\n")
    return (f'[scene]\nname = "far"\n[[primitive]]\ntype = "obj"\npath = "m.obj"\n'
            '[scan]\nx0_m = 0.0\nz0_m = 1.0\ny_start_m = 0.0\ny_end_m = 0.1\ndy_m = 0.05\n'
            'theta_min_deg = -5.0\ntheta_max_deg = 5.0\ndtheta_deg = 5.0\n')


def test_an_imported_mesh_far_from_the_scanner_gets_the_precision_warning(tmp_path):
    from simlidar_mi.lidar.survey import build, generate
    for x_m, warned in ((1e5, True), (2.0, False)):  # 5 mm edges: float32 spacing 3.9 mm at 5e4 m
        (tmp_path / "s.toml").write_text(_mesh_scene(tmp_path, x_m))
        cfg = load_scene(tmp_path / "s.toml")
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            build(cfg, generate(cfg))
        said = [str(w.message) for w in got if issubclass(w.category, SimlidarWarning)]
        assert any("float32 coordinates" in m and "primitive 0's shortest mesh edge" in m for m in said) == warned, said
