"""README's "What the outputs are for" table names what the commands really write: the cheap
commands are run (on the smallest scenes, shrunk by overrides) and every file each writes must
match a name the table gives it, and every name the table gives a command must be written."""
from __future__ import annotations

import fnmatch
import re
from pathlib import Path

import pytest

from simlidar_mi.cli import COMMANDS, main
from tests.conftest import REPO

SMALL_FISHEYE = ["--set", "fisheye.resolution=64", "--set", "fisheye.grid_n=[1, 1]"]


def outputs_table(text: str) -> dict[str, list[str]]:
    """command -> the file names (``<x>`` as ``*``; a name ending in / is a folder) of the rows
    whose "written by" cell names it outside parentheses."""
    names = {n for n, *_ in COMMANDS}
    start = text.index("| file | written by | for |")
    table: dict[str, list[str]] = {}
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        files, by = (c.strip() for c in line.strip("|").split(" | ")[:2])
        by = re.sub(r"\([^)]*\)", "", by)
        for cmd in re.findall(r"`([a-z-]+)`", by):
            assert cmd in names, f"README outputs table: {cmd!r} is not a command"
            table.setdefault(cmd, []).extend(re.sub(r"<[^>]+>", "*", f)
                                             for f in re.findall(r"`([^`]+)`", files))
    return table


def _matches(path: str, pattern: str) -> bool:
    return path.startswith(pattern) if pattern.endswith("/") else fnmatch.fnmatchcase(path, pattern)


def mismatches(written: list[str], patterns: list[str], not_expected: set[str] = frozenset()) -> list[str]:
    """Files written that no pattern names, and patterns (outside ``not_expected``) nothing
    written matches."""
    extra = [f"written, not in the table: {w}" for w in written if not any(_matches(w, p) for p in patterns)]
    missing = [f"in the table, not written: {p}" for p in patterns
               if p not in not_expected and not any(_matches(w, p) for w in written)]
    return extra + missing


def _written(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())


def test_the_check_finds_a_wrong_table():
    table = outputs_table("| file | written by | for |\n|---|---|---|\n"
                          "| `truth.nc`, `truth_summary.csv` | `truth`, `evaluate` | x |\n"
                          "| `scan.exr` | `scan` (and `evaluate`, in `scan/`) | x |\n")
    assert table == {"truth": ["truth.nc", "truth_summary.csv"], "evaluate": ["truth.nc", "truth_summary.csv"],
                     "scan": ["scan.exr"]}
    assert mismatches(["truth.nc", "scan/scan.exr"], table["evaluate"]) == [
        "written, not in the table: scan/scan.exr", "in the table, not written: truth_summary.csv"]


# (name, command line after the output folder is known, patterns this run does not write: why)
RUNS = [
    ("scan", lambda o: ["scan", "scenes/calibration_cylinder.toml", "--out", o],
     {"scan_leg*.exr", "scan_leg*.png"}),  # a tractor: one leg
    ("scan", lambda o: ["scan", "scenes/vineyard_vsp.toml", "--out", o, "--set", "platform.step_m=0.5",
                        "--set", "platform.elevation_deg=[-55.0, 55.0, 5.0]"],
     {"scan.exr", "scan.png"}),  # two legs: one EXR and PNG each instead
    ("truth", lambda o: ["truth", "scenes/calibration_cylinder.toml", "--out", o, "--voxel", "0.1"], set()),
    ("gapfraction", lambda o: ["gapfraction", "scenes/random_leaves_spherical.toml", "--out", o, "--set",
                               "gapfraction.resolution=64", "--set", "gapfraction.replicates=1"], set()),
    ("fisheye", lambda o: ["fisheye", "scenes/random_leaves_spherical.toml", "--out", o, *SMALL_FISHEYE], set()),
    ("evaluate-photo", lambda o: ["evaluate-photo", "scenes/random_leaves_spherical.toml", "--out", o,
                                  *SMALL_FISHEYE], set()),
    ("photo-gap", lambda o: ["photo-gap", "scenes/photos/strawberry_full_nadir.jpg", "--method", "canopeo",
                             "--out", o], set()),
    # a virtual hemispherical image (the binary PNG `fisheye` writes) stands for a field photo
    ("fisheye-photo", lambda o: ["fisheye-photo", f"{o}_fisheye/fisheye_0.png", "--out", o],
     {"fisheye_photo_lai.csv"}),  # only with --lai
    ("evaluate", lambda o: ["evaluate", "scenes/calibration_cylinder.toml", "--out", o, "--voxel", "0.25"],
     set()),
    ("forest", lambda o: ["forest", "scenes/forest_small.toml", "--out", o, "--truth-rasters", "--set",
                          "forest.domain_m=[0.0, 15.0, 0.0, 15.0]"], set()),
]


@pytest.mark.parametrize(("command", "argv", "not_expected"), RUNS,
                         ids=[f"{c}-{i}" for i, (c, *_) in enumerate(RUNS)])
def test_readme_outputs_table_names_what_the_command_writes(command, argv, not_expected, tmp_path,
                                                            monkeypatch):
    monkeypatch.chdir(REPO)
    table = outputs_table((REPO / "README.md").read_text())
    out = tmp_path / "out"
    if command == "fisheye-photo":
        assert main(["fisheye", "scenes/random_leaves_spherical.toml", "--out", f"{out}_fisheye",
                     *SMALL_FISHEYE]) == 0
    assert main(argv(str(out))) == 0
    assert mismatches(_written(out), table[command], not_expected) == []
