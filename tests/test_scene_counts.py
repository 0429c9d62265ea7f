"""Counts and messages of what a scan sees: mesh leaves counted by scan and measure as truth
counts them, placed instanced leaves, hits printed readably, a scan that hits nothing warned."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.scene_counts import leaf_triangle_counts, placed_counts
from simlidar_mi.lidar.survey import generate, measure

# A mesh tree as a modelling tool writes it: a square trunk (usemtl Bark) and 8 leaf quads
# (usemtl Leaves), each 0.2 m × 0.5 m = 0.1 m² one-sided: 16 leaf triangles, 0.8 m² of leaf.
TRUNK = [(x, y, z) for z in (0.0, 1.5) for x, y in ((-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05))]


def _tree_obj(path):
    lines = ["o my_tree", "usemtl Bark"] + [f"v {x} {y} {z}" for x, y, z in TRUNK]
    lines += [f"f {a + 1} {(a + 1) % 4 + 1} {(a + 1) % 4 + 5} {a + 5}" for a in range(4)]  # four sides
    lines.append("usemtl Leaves")
    for k in range(8):
        z = 1.0 + 0.1 * k
        x0 = 0.2 if k % 2 else -0.4
        n = 9 + 4 * k
        lines += [f"v {x0} -0.25 {z}", f"v {x0 + 0.2} -0.25 {z}", f"v {x0 + 0.2} 0.25 {z}", f"v {x0} 0.25 {z}",
                  f"f {n} {n + 1} {n + 2} {n + 3}"]
    path.write_text("\n".join(lines) + "\n")


SCENE = ('[scene]\nname = "mesh tree"\n[[primitive]]\ntype = "obj"\npath = "tree.obj"\n'
         'labels = {leaf = ["Leaves*"], wood = ["Bark*"]}\n'
         '[scan]\nx0_m = -1.5\nz0_m = 1.2\ny_start_m = -0.4\ny_end_m = 0.4\ndy_m = 0.02\n'
         'theta_min_deg = -40.0\ntheta_max_deg = 40.0\ndtheta_deg = 1.0\n')


@pytest.fixture()
def mesh_tree(tmp_path):
    _tree_obj(tmp_path / "tree.obj")
    (tmp_path / "tree.toml").write_text(SCENE)
    return tmp_path / "tree.toml"


def test_a_mesh_trees_leaves_are_counted_by_scan_and_measure_as_truth_counts_them(mesh_tree, capsys):
    """'0 leaf triangles' and a table of zeros for a tree whose leaves truth counts: now the
    mesh's 16 leaf triangles and its 0.8 m² (truth's own total), and the trunk's 0.6 m² of bark."""
    from simlidar_mi.truth.compute import compute_truth
    from simlidar_mi.truth.run import truth_grid
    cfg = load_scene(mesh_tree)
    geo = generate(cfg)
    counts = leaf_triangle_counts(geo)
    assert counts["n_leaf_triangles"] == counts["n_leaf_triangles_meshes"] == 16
    m = measure(cfg)
    assert m["primitive_leaf_area_m2"] == pytest.approx(0.8, rel=1e-12)
    assert m["primitive_wood_area_m2"] == pytest.approx(4 * 0.1 * 1.5, rel=1e-12)  # four sides
    truth = compute_truth(geo, truth_grid(cfg, geo, 0.1), progress=False)
    assert truth.attrs["exact_leaf_area_m2"] == pytest.approx(m["primitive_leaf_area_m2"], rel=1e-12)
    assert main(["measure", str(mesh_tree)]) == 0
    out = capsys.readouterr().out
    assert out == "primitives: 16 leaf triangles in meshes, leaf area 0.8 m² (one-sided), wood surface 0.6 m²\n"
    assert main(["scan", str(mesh_tree), "--out", str(mesh_tree.parent / "scan")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "40×80 beams (tractor), 0 branches (mesh), 16 leaf triangles (16 in meshes)"
    hits = {k: int(v.replace(",", "")) for v, k in
            (part.split() for part in out[1].removeprefix("hits: ").split("; ")[0].split(", "))}
    import json
    said = json.loads((mesh_tree.parent / "scan" / "measures.json").read_text())
    assert hits == {k: said["hits"][k] for k in ("wood", "leaf", "ground")} and hits["leaf"] > 0
    assert out[1].endswith(f"; {said['hits']['escape']:,} beams hit nothing (escape)") and "{" not in out[1]
    assert said["n_leaf_triangles"] == 16


def test_placed_counts_count_each_tree_once_per_placement():
    class Inst:  # two prototypes: 3 branches / 10 leaf triangles and 1 / 4; placed 0, 1, 1, 0, 1
        prototypes = [(range(3), range(10)), (range(1), range(4))]
        proto_index = np.array([0, 1, 1, 0, 1])

        def __len__(self):
            return 5
    assert placed_counts(Inst()) == {"n_instances": 5, "n_branches_placed": 9, "n_leaf_triangles_placed": 32,
                                     "n_leaf_triangles_prototypes": 14}


def test_a_static_scan_that_hits_nothing_is_warned_with_the_scene_bounds(tmp_path, capsys):
    """The static scanner's default 2D profile looks along +x; a scene behind it was scanned
    without a word (every beam escaped)."""
    scene = tmp_path / "behind.toml"
    scene.write_text('[[primitive]]\ntype = "box"\nmin_m = [-6, -1, 0]\nmax_m = [-5, 1, 2]\nlabel = "leaf"\n'
                     '[ground]\nenabled = false\n'
                     '[platform]\nkind = "static"\nposition_m = [0, 0, 1]\nelevation_deg = [-10, 10, 1]\n')
    assert main(["scan", str(scene), "--out", str(tmp_path / "o"), "--no-las", "--no-png"]) == 0
    err = capsys.readouterr().err
    assert (f"simlidar-mi scan: warning: {scene}: the scan hit nothing: all 21 beams escaped; the scene's "
            "plants and primitives lie in x [-6, -5] m, y [-1, 1] m, z [0, 2] m; aim the sensor (static: "
            "platform.position_m and platform.azimuth_deg (0° looks along +x, 90° along +y)") in err
    # turned to face it: no warning
    assert main(["scan", str(scene), "--out", str(tmp_path / "o"), "--no-las", "--no-png",
                 "--set", "platform.azimuth_deg=180"]) == 0
    assert "warning" not in capsys.readouterr().err
