"""The scan / measure / preview commands, end to end through the CLI entry point."""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from simlidar_mi.cli import main
from tests.conftest import SCENES


def test_scan_command_writes_four_files(tmp_path, capsys):
    out = tmp_path / "orchard"
    rc = main(["scan", str(SCENES / "apple_orchard.toml"), "--out", str(out),
               "--set", "orchard.n_trees=1", "--set", "scan.dtheta_deg=1.0"])
    assert rc == 0
    assert sorted(p.name for p in out.iterdir()) == ["measures.json", "points.las", "scan.exr", "scan.png"]
    m = json.loads((out / "measures.json").read_text())
    assert m["n_branches"] > 100 and m["hits"]["wood"] > 0
    # The paper's inequality A_IM ≤ A_PR holds (hidden branches are not impacted).
    assert 0 < m["A_IM_m2"] <= m["A_PR_m2"]
    png = Image.open(out / "scan.png")
    assert png.size[0] > 400
    assert "beams" in capsys.readouterr().out


def test_scan_command_bad_override_names_key(tmp_path, capsys):
    rc = main(["scan", str(SCENES / "apple_orchard.toml"), "--out", str(tmp_path / "o"),
               "--set", "scan.dtheta_deg=-1"])
    assert rc == 2
    err = capsys.readouterr().err
    # The error names the --set argument that holds the bad value, not the scene file.
    assert "--set scan.dtheta_deg=-1, key 'scan.dtheta_deg'" in err and "apple_orchard.toml" not in err
    assert not (tmp_path / "o").exists()


def test_scan_command_missing_scene_file(tmp_path, capsys):
    rc = main(["scan", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "nope.toml" in capsys.readouterr().err


def test_measure_command_json_matches_api(capsys):
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.survey import measure
    rc = main(["measure", str(SCENES / "apple_orchard.toml"), "--json"])
    assert rc == 0
    printed = json.loads(capsys.readouterr().out)
    api = measure(load_scene(SCENES / "apple_orchard.toml"))
    assert printed["A_PR_m2"] == pytest.approx(api["A_PR_m2"])
    assert len(printed["per_tree"]) == 4
    assert sum(t["A_PR_m2"] for t in printed["per_tree"]) == pytest.approx(printed["A_PR_m2"])


def test_preview_command_draws_the_target(tmp_path):
    out = tmp_path / "p.png"
    assert main(["preview", str(SCENES / "calibration_cylinder.toml"), "--out", str(out),
                 "--width", "200", "--spp", "4"]) == 0
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    dark = (img.sum(axis=2) < 600)
    assert 0.005 < dark.mean() < 0.5          # the cylinder, on a white background
    cols = np.flatnonzero(dark.any(axis=0))
    assert abs((cols.min() + cols.max()) / 2 - img.shape[1] / 2) < 0.05 * img.shape[1]  # centred
