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


def test_ticks_print_a_line_per_item_or_per_five_percent_when_piped():
    out = io.StringIO()
    with Progress("lines", out).stage("few", 3, "orchard", ticks=True) as st:
        for _ in range(3):
            st.update()
    lines = [re.sub(r"[\d.]+ s\)", "T s)", ln) for ln in out.getvalue().splitlines()]
    assert lines == ["few: 1/3 orchards done (33 %, T s)", "few: 2/3 orchards done (67 %, T s)",
                     "few: 3/3 orchards done (100 %, T s)", "few: 3 orchards (T s)"]
    out = io.StringIO()
    with Progress("lines", out).stage("many", 96, "orchard", ticks=True) as st:
        for _ in range(96):
            st.update()
    ticks = [ln for ln in out.getvalue().splitlines() if " done " in ln]
    assert len(ticks) == 20 and ticks[0].startswith("many: 5/96 orchards done (5 %") \
        and ticks[-1].startswith("many: 96/96 orchards done (100 %")


def test_a_piped_study_prints_a_line_per_finished_orchard(tmp_path):
    """`study` said nothing for minutes when its stderr went to a pipe or a log: one line per
    finished orchard now (no timing asserted)."""
    grid = [["orchard.tree.iterations=3", "orchard.n_trees=1", "scan.dtheta_deg=2.0", f"scan.dy_m={dy}"]
            for dy in (0.05, 0.06, 0.07)]
    code = ("import sys\nfrom simlidar_mi.lidar import study\nfrom simlidar_mi.cli import main\n"
            f"study.paper_grid = lambda: {grid!r}\nmain(sys.argv[1:])\n")
    proc = subprocess.run([sys.executable, "-c", code, "study", str(SCENES / "apple_orchard.toml"),
                           "--out", str(tmp_path / "s"), "--no-readings"],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    ticks = [re.sub(r" \(.*\)$", "", ln) for ln in proc.stderr.splitlines() if " done (" in ln]
    assert ticks == [f"study: scanning: {k}/3 orchards done" for k in (1, 2, 3)]
