"""The README's examples run as written: its Python blocks, and every ``simlidar-mi`` line of
its shell command blocks, in a scratch folder laid out like a fresh clone."""
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

README = REPO / "README.md"

# Lines known to take minutes (2 shared cores): marked `slow` (deselect with -m "not slow")
# but run by default; the bound only stops a hung command, it asserts no timing.
SLOW_S = {"simlidar-mi study ": 3600, "simlidar-mi synthetic-photo ": 2400,
          "scenes/forest_4species.toml": 900, "scenes/forest_airborne.toml": 900}
BOUND_S = 600


def _readme_commands() -> list[str]:
    """Each distinct ``simlidar-mi ...`` line of the README's ```sh blocks, comment removed."""
    seen: list[str] = []
    for block in re.findall(r"```sh\n(.*?)```", README.read_text(), re.S):
        for line in block.splitlines():
            cmd = re.sub(r"\s+#.*$", "", line).strip()
            if cmd.startswith("simlidar-mi ") and cmd not in seen:
                seen.append(cmd)
    return seen


COMMAND_LINES = _readme_commands()


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
    assert (tmp_path / "out" / "two_trees.exr").stat().st_size > 0


def test_readme_command_blocks_cover_every_command():
    """The blocks show every sub-command, and only real arguments (no [optional] notation)."""
    used = {shlex.split(c)[1] for c in COMMAND_LINES}
    assert used == {name for name, *_ in COMMANDS}
    for cmd in COMMAND_LINES:
        assert not re.search(r"\[|\.\.\.|\bDIR\b|\bPHOTO\b", cmd), cmd


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


def _faults_table() -> list[tuple[str, str, str]]:
    text = README.read_text()
    section = text[text.index("## Faults and bad input"):]
    section = section[:section.index("\n## ", 1)]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) == 3 and cells[2].startswith("tests/"):
            rows.append((cells[0], cells[1], cells[2]))
    return rows


def test_faults_table_names_tests_that_exist():
    """Every row of the README's "Faults and bad input" table is backed by a real test."""
    import ast
    rows = _faults_table()
    assert len(rows) >= 30
    for case, seen, ref in rows:
        path, name = ref.split("::")
        tree = ast.parse((REPO / path).read_text())
        names = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        assert name.split("[")[0] in names, f"README faults table: {case!r} names missing test {ref}"
