"""Progress of long commands: one shared helper; a tqdm bar on a terminal, one line per
finished stage when stderr is piped, nothing on stdout, nothing in library calls by default."""
from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from simlidar_mi._runtime.progress import Progress, make_progress
from simlidar_mi.errors import ConfigError
from tests.conftest import REPO, SCENES

SMALL_GAP = ["--set", "gapfraction.replicates=2", "--set", "gapfraction.resolution=64",
             "--set", 'gapfraction.cameras=["orthographic"]', "--set", "gapfraction.zeniths_deg=[0.0]"]
STAGE_LINE = re.compile(r"^[\w -]+: .+ \(\d+\.\d s\)$")


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_lines_mode_prints_one_summary_per_stage():
    out = io.StringIO()
    p = Progress("lines", out)
    assert list(p.iter(range(3), "render", unit="plot")) == [0, 1, 2]
    with p.stage("write", 5, "file") as st:
        st.update(2)
        st.update(3, note="csv and json")
    steps = p.stage("scan", 2, "stage")
    steps.step("generated 10 branches")
    steps.step("written")
    lines = out.getvalue().splitlines()
    assert [re.sub(r" \(\d+\.\d s\)$", "", x) for x in lines] == [
        "render: 3 plots", "write: 5 files, csv and json",
        "scan: generated 10 branches", "scan: written"]
    assert all(STAGE_LINE.match(x) for x in lines), lines


def test_failed_or_abandoned_stage_prints_no_summary():
    out = io.StringIO()
    p = Progress("lines", out)
    with pytest.raises(RuntimeError):
        with p.stage("render", 4, "plot") as st:
            st.update()
            raise RuntimeError("boom")
    it = p.iter(range(5), "photos", unit="photo")
    next(it)
    it.close()                     # the caller stopped early: no summary of a partial stage
    assert out.getvalue() == ""


def test_partial_count_and_plural_units():
    out = io.StringIO()
    p = Progress("lines", out)
    with p.stage("export", 4, "mesh") as st:
        st.update()
    with p.stage("one", None, "photo") as st:
        st.update()
    assert [re.sub(r" \(.*$", "", x) for x in out.getvalue().splitlines()] == [
        "export: 1/4 mesh", "one: 1 photo"]
    out2 = io.StringIO()
    with Progress("lines", out2).stage("export", None, "mesh") as st:
        st.update(3)
    assert out2.getvalue().startswith("export: 3 meshes (")


def test_mode_follows_the_stream_and_off_is_silent():
    assert make_progress(True, io.StringIO()).mode == "lines"     # piped / redirected
    assert make_progress(True, _Tty()).mode == "bar"               # a terminal
    assert make_progress(False).mode == make_progress(None).mode == "off"
    assert make_progress("lines").mode == "lines"
    p = Progress("lines")
    assert make_progress(p) is p
    with pytest.raises(ConfigError, match="progress"):
        make_progress("verbose")
    out = io.StringIO()
    q = Progress("off", out)
    assert list(q.iter([1, 2], "x")) == [1, 2]
    q.stage("y", 1).step("done")
    assert out.getvalue() == ""


def test_bar_mode_draws_a_tqdm_bar_on_the_stream(capsys):
    tty = _Tty()
    p = make_progress(True, tty)
    for _ in p.iter(range(3), "render", unit="plot"):
        pass
    text = tty.getvalue()
    assert "render" in text and "/3 [" in text and "plot/s" in text   # tqdm's own format
    assert capsys.readouterr().out == ""                           # never stdout


def test_only_the_shared_helper_uses_tqdm():
    """One progress helper, not copies: no other module draws its own bar."""
    users = [p.relative_to(REPO) for p in (REPO / "simlidar_mi").rglob("*.py")
             if re.search(r"^\s*(from|import) tqdm", p.read_text(), re.M)
             and p.relative_to(REPO) != Path("simlidar_mi/_runtime/progress.py")]
    assert users == []


# --- the commands, piped ---------------------------------------------------------------

def _cli(args, cwd, **kw):
    return subprocess.run([sys.executable, "-m", "simlidar_mi.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600, **kw)


def _stage_lines(stderr: str, prefix: str) -> list[str]:
    return [x for x in stderr.splitlines() if x.startswith(prefix)]


@pytest.mark.parametrize(("args", "prefix", "expect"), [
    (["scan", SCENES / "calibration_cylinder.toml", "--out", "o"], "scan: ",
     ["generated", "built", "scanned", "written"]),
    (["preview", SCENES / "calibration_cylinder.toml", "--out", "p.png", "--width", "64",
      "--spp", "1"], "preview: ", ["generated", "built", "rendered 64×", "wrote p.png"]),
    (["gapfraction", SCENES / "random_leaves_spherical.toml", "--out", "g", *SMALL_GAP],
     "gapfraction: ", ["rendering: 2 plots", "writing: 5 files"]),
    (["synthetic-photo", SCENES / "random_leaves_spherical.toml", "--out", "s", *SMALL_GAP,
      "--set", "photo_render.spp=1"], "synthetic-photo: ", ["rendering: 1 photo"]),
    (["forest", SCENES / "forest_small.toml", "--out", "f"], "trees: ", ["trees: "]),
])
def test_piped_command_prints_one_line_per_stage(tmp_path, args, prefix, expect):
    proc = _cli(args, tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = _stage_lines(proc.stderr, prefix)
    assert len(lines) == len(expect), proc.stderr
    for line, word in zip(lines, expect):
        assert word in line and STAGE_LINE.match(line), line
    assert not re.search(r"\(\d+\.\d s\)", proc.stdout)          # results only on stdout
    assert "\r" not in proc.stderr                               # no bar when piped


def test_photo_gap_on_several_photos_summarises(tmp_path):
    photos = sorted((REPO / "scenes" / "photos").glob("*.jpg"))
    assert len(photos) == 2
    proc = _cli(["photo-gap", *photos, "missing.jpg", "--method", "canopeo", "--json",
                 "--mask-dir", tmp_path / "m"], tmp_path)
    assert proc.returncode == 2                                  # one photo failed
    assert [r["file"] for r in __import__("json").loads(proc.stdout)] == [str(p) for p in photos]
    err = proc.stderr.strip().splitlines()
    assert err[0] == "simlidar-mi photo-gap: error: missing.jpg: no such file"
    assert re.fullmatch(r"photo-gap: 3 photos, 1 failed \(\d+\.\d s\)", err[1])


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_terminal_shows_a_bar(tmp_path):
    """stderr on a (0 × 0) pseudo-terminal, as in a bare `script` session: a bar is drawn."""
    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "simlidar_mi.cli", "gapfraction",
                             str(SCENES / "random_leaves_spherical.toml"), "--out", "g", *SMALL_GAP],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:
            break
        if not data:
            break
        chunks.append(data)
    out, _ = proc.communicate(timeout=600)
    os.close(master)
    err = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 0, err
    assert "gapfraction: rendering" in err and "/2 [" in err and "\r" in err
    assert not _stage_lines(err.replace("\r", "\n"), "gapfraction: rendering: 2 plots (")
    assert b"%|" not in out
