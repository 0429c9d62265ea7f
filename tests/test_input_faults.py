"""Faults around the input and output streams: a study row cut short, and stdout's reader
leaving early (``| head``)."""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

from simlidar_mi.lidar.study import run_study
from tests.conftest import REPO, SCENES

GRID = [["orchard.tree.iterations=4", "orchard.n_trees=1", "scan.dtheta_deg=1.0", "scan.dy_m=0.01"]]
SAME = ("key", "A_IM_m2", "A_PR_m2", "n_branches", "N", "M")


def test_a_truncated_study_row_is_scanned_again_with_a_warning(tmp_path, caplog):
    out = tmp_path / "study"
    first = run_study(SCENES / "apple_orchard.toml", out, GRID, readings=False).rows[0]
    row = out / "rows" / f"{first['key']}.json"
    text = row.read_text()
    row.write_text(text[: len(text) // 2])  # a crash or a full disk cut it short
    with caplog.at_level(logging.WARNING, logger="simlidar_mi.lidar.study"):
        again = run_study(SCENES / "apple_orchard.toml", out, GRID, readings=False).rows[0]
    said = [r.getMessage() for r in caplog.records if "cannot be read" in r.getMessage()]
    assert len(said) == 1 and str(row) in said[0] and "JSONDecodeError" in said[0]
    assert {k: again[k] for k in SAME} == {k: first[k] for k in SAME}
    assert json.loads(row.read_text())["key"] == first["key"]  # whole again


def _closed_stdout(*args: str) -> subprocess.CompletedProcess:
    """The command with stdout a pipe whose reader has already gone (`| head` that has quit)."""
    r, w = os.pipe()
    os.close(r)
    try:
        return subprocess.run([sys.executable, "-c", "from simlidar_mi.cli import main; main()", *args],
                              stdout=w, stderr=subprocess.PIPE, text=True, cwd=REPO, timeout=600)
    finally:
        os.close(w)


def test_a_closed_stdout_ends_quietly_and_the_files_are_written(tmp_path):
    for args in (["sensors"], ["measure", str(SCENES / "apple_orchard.toml"), "--json"]):
        p = _closed_stdout(*args)
        assert p.returncode == 0 and p.stderr == "", (args, p.stderr)
    p = _closed_stdout("scan", str(SCENES / "calibration_cylinder.toml"), "--out", str(tmp_path / "s"))
    assert p.returncode == 0 and "Traceback" not in p.stderr and "Error" not in p.stderr, p.stderr
    assert sorted(f.name for f in (tmp_path / "s").iterdir()) == ["measures.json", "points.las", "scan.exr",
                                                                  "scan.png"]
