"""Output folders: a run owns its output set, checks the location first, takes a lock,
cleans what killed runs left, and ends with one line and exit 130 on Ctrl-C (issue #9,
items 3, 6, 7, 9)."""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from simlidar_mi.cli import main
from simlidar_mi.errors import OutputError
from simlidar_mi.io.atomic import (LOCK_NAME, atomic_file, claim_output, clean_stale_partials,
                                   staged_dir)
from tests.conftest import REPO, SCENES

CYLINDER = str(SCENES / "calibration_cylinder.toml")
SCAN_FILES = ["measures.json", "points.las", "scan.exr", "scan.png"]
CLI = Path(sys.executable).with_name("simlidar-mi")


def _visible(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait(timeout=60)
    return p.pid


# --- item 3: a run owns its output set -----------------------------------------------


def test_rerun_without_las_removes_the_earlier_las(tmp_path, caplog):
    out = tmp_path / "scan"
    assert main(["scan", CYLINDER, "--out", str(out)]) == 0
    assert _visible(out) == SCAN_FILES
    # files the scan does not own stay: the user's, another command's
    (out / "notes.txt").write_text("mine")
    (out / "gap_fraction.csv").write_text("a,b\n")
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.io.atomic"):
        assert main(["scan", CYLINDER, "--out", str(out), "--no-las", "--no-png"]) == 0
    assert _visible(out) == ["gap_fraction.csv", "measures.json", "notes.txt", "scan.exr"]
    said = [r.getMessage() for r in caplog.records]
    assert any("points.las" in m and "removed" in m for m in said)
    assert any("scan.png" in m and "removed" in m for m in said)
    assert not any("notes.txt" in m or "gap_fraction" in m for m in said)


def test_staged_dir_removes_only_owned_names_and_replaces_subfolders(tmp_path):
    out = tmp_path / "o"
    with staged_dir(out, owns=[r"a\.txt", r"b\.txt", r"sub"]) as stage:
        for name in ("a.txt", "b.txt"):
            (stage / name).write_text("1")
        (stage / "sub").mkdir()
        (stage / "sub" / "old.ply").write_text("1")
    (out / "c.txt").write_text("user")
    with staged_dir(out, owns=[r"a\.txt", r"b\.txt", r"sub"]) as stage:
        (stage / "a.txt").write_text("2")
        (stage / "sub").mkdir()  # a non-empty folder of the same name is replaced whole
        (stage / "sub" / "new.ply").write_text("2")
    assert _visible(out) == ["a.txt", "c.txt", "sub"]
    assert (out / "a.txt").read_text() == "2"
    assert _visible(out / "sub") == ["new.ply"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_forest_rerun_switching_export_removes_the_other_mesh(tmp_path):
    from simlidar_mi.forest.run import run_forest
    out = tmp_path / "f"
    small = ["forest.domain_m=[0.0, 15.0, 0.0, 15.0]", 'forest.leaf_table="none"']
    run_forest(SCENES / "forest_small.toml", out, small + ['forest.export="stand"'])
    assert "stand.ply" in _visible(out)
    run_forest(SCENES / "forest_small.toml", out,
               small + ['forest.export="prototypes"', "forest.instancing=true"])
    assert "stand.ply" not in _visible(out) and (out / "prototypes").is_dir()
    run_forest(SCENES / "forest_small.toml", out,   # a folder replaces the earlier folder
               small + ['forest.export="prototypes"', "forest.instancing=true"])
    assert (out / "prototypes").is_dir()


# --- item 6: the output location is checked before any work -------------------------


@pytest.fixture
def no_work(monkeypatch):
    """Any scene generation fails the test: the output check must come first."""
    import simlidar_mi.lidar.survey as survey

    def boom(*a, **k):
        raise AssertionError("work started before the output location was checked")
    monkeypatch.setattr(survey, "generate", boom)


def test_scan_out_is_a_file(tmp_path, capsys, no_work):
    f = tmp_path / "taken"
    f.write_text("x")
    assert main(["scan", CYLINDER, "--out", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "is not a folder" in err and str(f) in err
    assert f.read_text() == "x"


def test_scan_out_under_a_file(tmp_path, capsys, no_work):
    f = tmp_path / "taken"
    f.write_text("x")
    assert main(["scan", CYLINDER, "--out", str(f / "sub")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{f} is a file" in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_scan_out_not_writable(tmp_path, capsys, no_work):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["scan", CYLINDER, "--out", str(ro / "o")]) == 2
    finally:
        ro.chmod(0o755)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not writable" in err


def test_scan_out_cannot_be_made(capsys, no_work):
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc")
    assert main(["scan", CYLINDER, "--out", "/proc/simlidar-mi-test/o"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot make output folder" in err


@pytest.mark.parametrize("argv", [
    ["gapfraction", str(SCENES / "strawberry_plot.toml")],
    ["synthetic-photo", str(SCENES / "strawberry_plot.toml")],
    ["forest", str(SCENES / "forest_small.toml")],
    ["compare", str(SCENES / "strawberry_manifest.csv")],
    ["study", str(SCENES / "apple_orchard.toml")],
    ["preview", CYLINDER],
])
def test_every_writing_command_checks_its_output_first(tmp_path, capsys, argv):
    # a missing input would be reported first if the output were checked later
    argv = [argv[0], str(tmp_path / "missing" / Path(argv[1]).name)]
    out = tmp_path / "out"
    out.mkdir() if argv[0] == "preview" else out.write_text("x")
    assert main(argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out) in err and "missing" not in err


def test_photo_gap_checks_its_mask_folder_first(tmp_path, capsys):
    taken = tmp_path / "masks"
    taken.write_text("x")
    rc = main(["photo-gap", str(tmp_path / "missing.jpg"), "--method", "canopeo",
               "--out", str(taken)])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(taken) in err and "missing.jpg" not in err


def test_output_errors_are_simlidar_errors(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(OutputError):
        with claim_output(tmp_path / "f"):
            pass


# --- item 9: one run per folder; item 7: what a killed run left -----------------------

_HOLDER = textwrap.dedent("""
    import os, sys, time
    from simlidar_mi.io.atomic import claim_output, staged_dir
    with staged_dir(sys.argv[1]) as stage:
        (stage / "half.exr").write_text("half")
        print("ready", flush=True)
        sys.stdin.readline()
""")


def _holder(out: Path) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True, cwd=REPO)
    assert p.stdout.readline().strip() == "ready"  # returns when the child holds the lock
    return p


def test_second_run_into_a_busy_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "o"
    holder = _holder(out)
    try:
        assert main(["scan", CYLINDER, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"in use by process {holder.pid}" in err
        assert LOCK_NAME in err
        info = json.loads((out / LOCK_NAME).read_text())
        assert info["pid"] == holder.pid and "-c" in info["command"]
    finally:
        holder.communicate("\n", timeout=60)
    assert holder.returncode == 0
    assert not (out / LOCK_NAME).exists()       # released, and the holder's file moved in
    assert _visible(out) == ["half.exr"]
    assert main(["scan", CYLINDER, "--out", str(out)]) == 0


def test_killed_run_leaves_nothing_the_next_run_keeps(tmp_path, caplog):
    out = tmp_path / "o"
    holder = _holder(out)
    assert [p.name for p in out.iterdir() if p.name.startswith(".partial-")]
    holder.kill()                               # SIGKILL: no clean-up at all
    holder.wait(timeout=60)
    holder.stdout.close()
    holder.stdin.close()
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.io.atomic"):
        assert main(["scan", CYLINDER, "--out", str(out)]) == 0  # the kernel dropped the lock
    assert sorted(p.name for p in out.iterdir()) == SCAN_FILES
    assert any(f"process {holder.pid}" in r.getMessage() for r in caplog.records)


def test_stale_partials_only_of_dead_processes(tmp_path):
    dead, alive = _dead_pid(), os.getppid()
    (tmp_path / f".partial-{dead}-abc").mkdir()
    (tmp_path / f".partial-{dead}-abc" / "scan.exr").write_text("")
    (tmp_path / f".partial-{alive}-def").mkdir()
    (tmp_path / f".scan.exr.{dead}-x1.partial").write_text("")
    (tmp_path / "rows").mkdir()
    (tmp_path / "rows" / f".k.json.{dead}-y2.partial").write_text("")
    (tmp_path / "rows" / "k.json").write_text("{}")
    (tmp_path / ".partial-notapid").mkdir()     # not ours to judge
    removed = clean_stale_partials(tmp_path)
    assert sorted(p.name for p in removed) == sorted(
        [f".partial-{dead}-abc", f".scan.exr.{dead}-x1.partial", f".k.json.{dead}-y2.partial"])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [f".partial-{alive}-def", ".partial-notapid", "rows"])
    assert _visible(tmp_path / "rows") == ["k.json"]


def test_atomic_file_names_carry_the_pid(tmp_path):
    with atomic_file(tmp_path / "a.txt") as tmp:
        assert f".a.txt.{os.getpid()}-" in tmp.name and tmp.name.endswith(".partial")
        tmp.write_text("x")


def test_failed_first_run_leaves_no_folder(tmp_path):
    out = tmp_path / "new"
    assert main(["scan", CYLINDER, "--out", str(out), "--set", "scan.dtheta_deg=-1"]) == 2
    assert not out.exists()


# --- item 7: Ctrl-C ------------------------------------------------------------------

# Sends SIGINT to the process itself when a chosen module is first imported: during the
# package's own imports (numpy), inside Mitsuba's import (drjit), while the plugins
# register (build), or while the files are written (laspy, inside the staging folder).
_SITECUSTOMIZE = textwrap.dedent("""
    import os, signal, sys
    _target = os.environ.get("SIMLIDAR_TEST_SIGINT_ON")

    class _Interrupter:
        def find_spec(self, name, path=None, target=None):
            global _target
            if name == _target:
                _target = None
                os.kill(os.getpid(), signal.SIGINT)
            return None

    sys.meta_path.insert(0, _Interrupter())
""")


@pytest.mark.parametrize("module, prefix", [
    ("numpy", "simlidar-mi scan: interrupted"),                   # the first heavy import, in main
    ("drjit", "simlidar-mi scan: interrupted"),                   # inside Mitsuba's import
    ("simlidar_mi.plugins.tractor_lidar", "simlidar-mi scan: interrupted"),  # build
    ("laspy", "simlidar-mi scan: interrupted"),                   # writing, files staged
])
def test_ctrl_c_exits_130_with_one_line(tmp_path, module, prefix):
    out = tmp_path / "o"
    assert main(["scan", CYLINDER, "--out", str(out), "--no-png"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(_SITECUSTOMIZE)
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "site"), "SIMLIDAR_TEST_SIGINT_ON": module}
    # a changed scene, so that a run that was not interrupted would change the files
    proc = subprocess.run([str(CLI), "scan", CYLINDER, "--out", str(out), "--set",
                           "scan.dtheta_deg=1.0"], env=env, capture_output=True, text=True,
                          timeout=300, cwd=REPO)
    lines = proc.stderr.splitlines()
    # one line for the interrupt, last; before it only the piped progress of finished stages
    assert (proc.returncode, lines[-1]) == (130, prefix)
    assert all(ln.startswith("scan: ") for ln in lines[:-1]), proc.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no lock, no partial


def test_interrupts_deferred_delivers_after_the_block():
    from simlidar_mi._runtime.signals import interrupts_deferred
    seen = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            seen.append("block finished")  # not interrupted inside
    assert seen == ["block finished"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
