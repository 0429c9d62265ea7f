"""The worked examples of examples/ run from a clone (no ../shared), with their quick settings,
and print what their files hold: one per user task (score an estimator, a VLP-16 vineyard read
with laspy, LAI from virtual fisheye photos, a tree mesh scanned)."""
from __future__ import annotations

import csv
import json
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO

EXAMPLES = REPO / "examples"


def _run(script: str, *args: str, cwd) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    return proc


def test_score_my_estimator(tmp_path):
    out = tmp_path / "score"
    lines = _run("score_my_estimator.py", "--out", str(out), "--quick", cwd=tmp_path).stdout.splitlines()
    rows = {r["estimator"]: r for r in csv.DictReader(open(out / "scores.csv"))
            if r["scale"] == "voxel" and r["variable"] == "PAD_m2_m3"}
    mine = rows["returns_per_voxel"]
    assert mine["n"] == rows["contact_mle"]["n"] and int(mine["n"]) > 100  # scored on the same voxels
    printed = next(ln for ln in lines if ln.startswith("returns_per_voxel")).split()
    assert printed[1:5] == [mine["n"], f"{float(mine['r2']):.3f}", f"{float(mine['rmse']):.3f}",
                            f"{float(mine['bias']):.3f}"]
    assert (out / "estimates" / "returns_per_voxel.nc").is_file()


def test_vlp16_vineyard_read_with_laspy(tmp_path):
    out = tmp_path / "vlp"
    lines = _run("vlp16_vineyard_laspy.py", "--out", str(out), "--quick", cwd=tmp_path).stdout.splitlines()
    echoes = json.loads((out / "measures.json").read_text())["echoes"]
    assert json.loads((out / "measures.json").read_text())["sensor"]["preset"] == "velodyne-vlp16"
    head = lines.index(next(ln for ln in lines if ln.startswith("class")))
    table = {}
    for ln in lines[head + 1:head + 4]:
        name, *counts = ln.split()
        table[name] = {str(r): int(c.replace(",", "")) for r, c in enumerate(counts[:-1], 1) if c != "0"}
    # laspy's count of the LAS points per class and return = the scan's own count of its echoes
    assert table == echoes["echoes_by_class_and_return"]
    assert table["leaf"]["1"] > 1000 and table["wood"]["1"] > 100 and "2" in table["ground"]


def test_lai_from_virtual_photos(tmp_path):
    out = tmp_path / "lai"
    lines = _run("lai_from_virtual_photos.py", "--out", str(out), "--quick", cwd=tmp_path).stdout.splitlines()
    assert lines[0] == "true LAI 1 (scene file); the truth computed from the leaves: 1.0000"
    lai = {ln.split()[0]: float(ln.split()[1]) for ln in lines[2:8]}
    assert set(lai) == {"miller", "miller_lx", "hinge_57", "lai2200", "lai2200_le", "chen_cihlar"}
    # a random (Poisson) canopy: Miller's integral recovers the LAI (tests/test_lai_oracle.py: within 3 %)
    assert lai["miller"] == pytest.approx(1.0, abs=0.03) and lai["lai2200"] == pytest.approx(1.0, abs=0.03)
    assert (out / "photo_scores.csv").is_file()


def test_scan_my_tree_mesh(tmp_path):
    out = tmp_path / "tree"
    proc = _run("scan_my_tree_mesh.py", "--out", str(out), "--quick", cwd=tmp_path)
    lines = proc.stdout.splitlines()
    # 300 quads of 8 cm × 5 cm: 600 leaf triangles, 1.2 m²; the trunk's eight sides 2·0.05·sin(π/8) × 1.5 m
    assert lines[0] == "demo_tree.obj: 600 leaf triangles, leaf area 1.2 m² (one-sided), wood surface 0.4593 m²"
    said = json.loads((out / "scan" / "measures.json").read_text())
    assert said["n_leaf_triangles"] == 600 and said["hits"]["leaf"] > 100 and said["hits"]["wood"] > 10
    assert f"hits {said['hits']['leaf']:,} leaf, {said['hits']['wood']:,} wood" in lines[1]
    assert re.search(r"exactly 1\.2 m² \(the mesh's leaf faces\)", lines[2])
    # your own mesh whose names the patterns miss: the warning lists the names in the file
    mine = tmp_path / "mine.obj"
    mine.write_text((out / "demo_tree.obj").read_text().replace("usemtl Leaves", "usemtl leaf_mat"))
    proc = _run("scan_my_tree_mesh.py", str(mine), "--out", str(tmp_path / "mine"), "--quick", cwd=tmp_path)
    assert "labels.leaf patterns ['Leaves*'] match no name in the file" in proc.stderr
    assert "usemtl Bark, leaf_mat; o demo_tree" in proc.stderr
    assert proc.stdout.startswith("mine.obj: 0 leaf triangles")
