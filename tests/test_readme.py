"""The README's examples run as written: its Python blocks, and every ``simlidar-mi`` line of
its shell command blocks, in a scratch folder laid out like a fresh clone; the README and the
documentation pages together show every sub-command."""
from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from simlidar_mi.cli import COMMANDS
from tests.conftest import REPO, SHARED
from tests.test_docs import PAGES, SLOW_S

README = REPO / "README.md"

# Lines known to take minutes (SLOW_S, shared with the pages' runner) are marked `slow` (deselect
# with -m "not slow") but run by default; the bound only stops a hung command.
BOUND_S = 600


def _commands(text: str) -> list[str]:
    """Each distinct ``simlidar-mi ...`` line of a page's ```sh blocks (also called by its path,
    ``.venv/bin/simlidar-mi``), comment removed, as ``simlidar-mi ...``."""
    seen: list[str] = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():  # a continued line is one command
            cmd = re.sub(r"\s+#.*$", "", line).strip()
            cmd = re.sub(r"^(\./)?\.venv/bin/simlidar-mi ", "simlidar-mi ", cmd)
            if cmd.startswith("simlidar-mi ") and cmd not in seen:
                seen.append(cmd)
    return seen


def _missing_commands(texts: list[str]) -> set[str]:
    """The sub-commands that no ```sh block of these texts shows."""
    used = {shlex.split(c)[1] for text in texts for c in _commands(text) if len(shlex.split(c)) > 1}
    return {name for name, *_ in COMMANDS} - used


COMMAND_LINES = _commands(README.read_text())


def _param(cmd: str):
    slow = [bound for key, bound in SLOW_S.items() if key in cmd]
    marks = [pytest.mark.slow] if slow else []
    return pytest.param(cmd, slow[0] if slow else BOUND_S, marks=marks, id=cmd[len("simlidar-mi "):])


def test_readme_python_example_runs(tmp_path, monkeypatch):
    text = README.read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "README has no python example"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scenes").symlink_to(REPO / "scenes")
    for code in blocks:
        exec(compile(code, "README.md", "exec"), {})
    for name in ("scan.exr", "scan.png", "points.las", "measures.json"):
        assert (tmp_path / "out" / "cylinder_py" / name).stat().st_size > 0


def test_readme_and_docs_together_show_every_command():
    """Every sub-command is shown in a command block of the README or of a guide page, with only
    real arguments (no [optional] notation; a quoted value such as a TOML list is an argument)."""
    texts = [README.read_text()] + [p.read_text() for p in PAGES]
    assert _missing_commands(texts) == set()
    for cmd in [c for text in texts for c in _commands(text)]:
        bare = re.sub(r"'[^']*'|\"[^\"]*\"", "''", cmd)
        assert not re.search(r"\[|\.\.\.|\bDIR\b|\bPHOTO\b", bare), cmd
    assert re.search(r"\[", re.sub(r"'[^']*'|\"[^\"]*\"", "''", "simlidar-mi scan a.toml [--out X]"))


def test_command_coverage_check_can_fail():
    """The check above sees a sub-command missing, and counts `.venv/bin/simlidar-mi` lines."""
    page = "```sh\nsource .venv/bin/activate\nsimlidar-mi scan a.toml --out x  # note\n```\n" \
           "```sh\n.venv/bin/simlidar-mi sensors\n```\nsimlidar-mi study (prose, not a block)\n"
    assert _commands(page) == ["simlidar-mi scan a.toml --out x", "simlidar-mi sensors"]
    missing = _missing_commands([page])
    assert "study" in missing and "evaluate" in missing
    assert "scan" not in missing and "sensors" not in missing


def _clone(tmp_path: Path) -> tuple[Path, dict]:
    """A scratch 'clone' (scenes/ and examples/ linked) with ../shared beside it when the real one exists,
    and a PATH whose simlidar-mi is this interpreter's."""
    clone = tmp_path / "clone"
    clone.mkdir()
    (clone / "scenes").symlink_to(REPO / "scenes")
    (clone / "examples").symlink_to(REPO / "examples")
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    shim = bin_ / "simlidar-mi"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m simlidar_mi.cli "$@"\n')
    shim.chmod(0o755)
    py = bin_ / "python"  # README lines that run `python` (plug-in estimators) get this one too
    py.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    py.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_}{os.pathsep}{os.environ['PATH']}")
    return clone, env


@pytest.mark.parametrize(("cmd", "bound_s"), [_param(c) for c in COMMAND_LINES])
def test_readme_command_runs_as_written(cmd, bound_s, tmp_path):
    if "../shared/" in cmd and not SHARED.is_dir():
        pytest.skip(f"{cmd!r} reads the shared data folder, absent here ({SHARED})")
    clone, env = _clone(tmp_path)
    proc = subprocess.run(["bash", "-c", cmd], cwd=clone, env=env, capture_output=True,
                          text=True, timeout=bound_s)
    assert proc.returncode == 0, f"{cmd}\n{proc.stderr[-3000:]}"
    assert "Traceback" not in proc.stderr
    assert proc.stdout.strip(), "a README command printed no result"
    args = shlex.split(cmd)
    if "--json" in args:
        json.loads(proc.stdout)
    if "--out" in args:  # what it writes lands in the scratch clone, where the line says
        out = clone / args[args.index("--out") + 1]
        assert out.exists() and (out.is_file() or any(out.iterdir())), out


def test_photo_gap_without_results_prints_nothing_on_stdout(tmp_path):
    """A missing photo: one error line on stderr, exit 2, and no '[]' or header on stdout."""
    clone, env = _clone(tmp_path)
    for extra in (["--json"], []):
        proc = subprocess.run(["bash", "-c", "simlidar-mi photo-gap field/*.jpg --method canopeo "
                               + " ".join(extra)], cwd=clone, env=env, capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2
        assert proc.stdout == ""
        assert proc.stderr.strip().splitlines() == [
            "simlidar-mi photo-gap: error: field/*.jpg: no such file"]

