"""``forest --truth-rasters`` (issue 31 §2): the forest just made, cast from above as ``evaluate-als``
casts its scene. ``trees.csv``'s ``top_cells`` and ``overtopped`` are the cells of the written
``truth_tree_id.tif`` (read back with rasterio: transform, CRS), the rasters are those of the scene
made again (evaluate-als's path), a small tree moved under a big crown is overtopped, and without
the flag the run writes today's files only."""
from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

import simlidar_mi as sm
from simlidar_mi.cli import main
from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.forest import run as forest_run
from simlidar_mi.io.terrain import terrain_of
from simlidar_mi.truth.als_truth import RasterGrid
from simlidar_mi.truth.forest_truth import cast_truth, forest_truth
from tests.conftest import SCENES

rasterio = pytest.importorskip("rasterio")

SCENE = SCENES / "forest_small.toml"
# the 40 m four-species stand from 2 prototypes a species, on a hill over a gentle slope
HILLS = ["forest.instancing=true", "forest.prototypes_per_species=2", 'forest.leaf_table="none"',
         'forest.export="none"', "terrain.slope_deg=8.0", "terrain.aspect_deg=200.0",
         "terrain.hills_m=[[14.0, 8.0, 3.0, 6.0]]", "terrain.cell_m=1.0"]
RASTERS = ("truth_dtm.tif", "truth_dsm.tif", "truth_chm.tif", "truth_tree_id.tif")


def _trees(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _read(path):
    with rasterio.open(path) as r:
        return r.read(1), r.transform, r.crs, r.nodata


@pytest.fixture(scope="module")
def flagged(tmp_path_factory):
    out = tmp_path_factory.mktemp("forest_truth") / "forest"
    run = sm.run_forest(SCENE, out, HILLS, truth_rasters=True, parallel=False)
    return out, run


def test_top_cells_and_overtopped_are_the_written_tree_id_raster(flagged):
    out, run = flagged
    trees = _trees(out / "trees.csv")
    assert list(trees[0])[-2:] == ["top_cells", "overtopped"] and len(trees) == len(run.forest) >= 10
    tid, tr, crs, nodata = _read(out / "truth_tree_id.tif")
    # the grid covers the forest's domain [0, 40]² in 0.5 m cells, north row first; no CRS given
    assert tid.shape == (80, 80) and (tr.a, tr.b, tr.c, tr.d, tr.e, tr.f) == (0.5, 0.0, 0.0, 0.0, -0.5, 40.0)
    assert crs is None and nodata == -1 and tid.dtype == np.int32
    ids, counts = np.unique(tid[tid >= 0], return_counts=True)
    owned = dict(zip(ids.tolist(), counts.tolist()))
    for t in trees:
        n = owned.get(int(t["tree_id"]), 0)
        assert (int(t["top_cells"]), int(t["overtopped"])) == (n, int(n == 0)), t["tree_id"]
    assert sum(int(t["top_cells"]) for t in trees) == int((tid >= 0).sum())
    summary = json.loads((out / "forest.json").read_text())["truth_rasters"]
    assert summary["n_overtopped"] == sum(int(t["overtopped"]) for t in trees) and summary["subsamples"] == 8
    assert {p.name for p in run.files.values()} >= set(RASTERS) | {"trees.csv", "forest.json"}


def test_rasters_are_the_terrain_and_those_of_the_scene_made_again(flagged):
    """The DTM is the hill's height at the cell centres; DSM, CHM and tree ids are, bit for bit,
    what evaluate-als's path gives from the scene generated anew (the forest is not made twice
    by the run, and reusing it changes nothing)."""
    out, _ = flagged
    cfg = load_scene(SCENE, HILLS)
    ter = terrain_of(cfg)
    dtm, tr, _, _ = _read(out / "truth_dtm.tif")
    rows, cols = np.indices(dtm.shape)
    xc, yc = tr @ (cols + 0.5, rows + 0.5)
    np.testing.assert_allclose(dtm, ter.height_m(xc, yc), rtol=0, atol=1e-4)
    assert np.ptp(dtm) > 3.0
    grid = RasterGrid.cover(0.0, 40.0, 0.0, 40.0, 0.5)
    again, trees, _ = cast_truth(cfg, grid, ter.height_m, 8, _quiet(), "test")
    assert len(trees["tree_id"]) == len(_trees(out / "trees.csv"))
    for name, key in (("truth_dsm.tif", "dsm"), ("truth_chm.tif", "chm"), ("truth_tree_id.tif", "tree_id")):
        a = _read(out / name)[0]
        b = getattr(again, key)
        assert np.array_equal(a, b.astype(a.dtype)), name
    chm = _read(out / "truth_chm.tif")[0]
    assert chm.max() > 10.0 and chm.min() >= 0.0


def _quiet():
    from simlidar_mi._runtime.progress import make_progress
    return make_progress(False)


def test_a_small_tree_moved_under_the_big_crown_is_overtopped(flagged, tmp_path):
    """The shortest tree of the stand, seen from above where it stands, moved to the point of the
    widest crown's top area farthest from its edge (its foot on the terrain there): it owns no
    cell any more; the big tree still owns every cell it owned."""
    out, run = flagged
    forest = run.forest
    cfg = load_scene(SCENE, HILLS)
    before = _trees(out / "trees.csv")
    tall = int(np.argmax([int(t["top_cells"]) for t in before]))  # the widest crown from above
    short = int(np.argmin(forest.height_m))
    assert forest.height_m[short] < 0.5 * forest.height_m[tall]
    assert before[short]["overtopped"] == "0" and before[tall]["overtopped"] == "0"
    tid, tr, _, _ = _read(out / "truth_tree_id.tif")
    from scipy.ndimage import distance_transform_edt
    depth = distance_transform_edt(tid == tall)
    r, c = np.unravel_index(np.argmax(depth), depth.shape)
    x, y = forest.placement.x_m.copy(), forest.placement.y_m.copy()
    x[short], y[short] = tr @ (c + 0.5, r + 0.5)
    moved = replace(forest, placement=replace(forest.placement, x_m=x, y_m=y),
                    base_z_m=terrain_of(cfg).height_m(x, y))
    extras = forest_truth(moved, cfg, tmp_path)
    top, over = extras.columns["top_cells"], extras.columns["overtopped"]
    assert (top[short], over[short]) == (0, 1)
    assert over[tall] == 0 and top[tall] == int(before[tall]["top_cells"])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(RASTERS)


def test_without_the_flag_no_rasters_and_no_new_columns(flagged, tmp_path):
    """Run again into a copy of the flagged folder without the flag: the rasters go (the run owns
    them), trees.csv is the flagged one less its last two columns, forest.json says nothing of them."""
    out, _ = flagged
    again = tmp_path / "forest"
    shutil.copytree(out, again)
    run = sm.run_forest(SCENE, again, HILLS, parallel=False)
    names = {p.name for p in again.iterdir()}
    assert not names & set(RASTERS) and not {p.name for p in run.files.values()} & set(RASTERS)
    with_flag = [line.rsplit(",", 2)[0] for line in (out / "trees.csv").read_text().splitlines()]
    assert (again / "trees.csv").read_text().splitlines() == with_flag
    assert "truth_rasters" not in json.loads((again / "forest.json").read_text())
    # the key without the forest room's caller (it cannot cast): one clear error
    with pytest.raises(ConfigError, match="forest.truth_rasters"):
        forest_run.run_forest(SCENE, tmp_path / "x", HILLS + ["forest.truth_rasters=true"])


def test_cli_rasters_carry_the_scene_crs(tmp_path, capsys):
    """GDAL (rasterio) reads the rasters in the scene's [scene] crs; a 15 m corner holds one tree,
    which owns the cells it tops."""
    out = tmp_path / "o"
    assert main(["forest", str(SCENE), "--out", str(out), "--truth-rasters",
                        "--set", "forest.domain_m=[0.0, 15.0, 0.0, 15.0]", "--set", 'forest.leaf_table="none"',
                        "--set", 'forest.export="none"', "--set", 'scene.crs="EPSG:25832"',
                        "--set", "truth.raster_cell_m=1.0", "--set", "truth.raster_subsamples=4"]) == 0
    assert "truth rasters: 15 × 15 cells of 1 m, 4² rays a cell; 0 of 1 trees overtopped; CRS EPSG:25832" \
        in capsys.readouterr().out
    for name in RASTERS:
        with rasterio.open(out / name) as r:
            assert r.crs.to_epsg() == 25832 and r.shape == (15, 15) and r.transform.f == 15.0
    tid = _read(out / "truth_tree_id.tif")[0]
    (tree,) = _trees(out / "trees.csv")
    assert int(tree["top_cells"]) == int((tid == 0).sum()) > 20 and tree["overtopped"] == "0"


def test_cli_refuses_rasters_past_the_ray_budget(tmp_path, capsys):
    """The work estimate counts the k² rays of every cell: one line naming the key, nothing made."""
    rc = main(["forest", str(SCENE), "--out", str(tmp_path / "o"), "--truth-rasters",
                      "--set", "truth.raster_cell_m=0.01", "--set", "truth.raster_subsamples=32"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "truth.raster_cell_m" in err[0] and "rays" in err[0], err
    assert not (tmp_path / "o").exists()


def test_the_argument_overrides_the_scene_key(tmp_path):
    """``truth_rasters=False`` turns off a scene's ``truth_rasters = true``, a SceneConfig's too."""
    corner = ["forest.domain_m=[0.0, 15.0, 0.0, 15.0]", 'forest.leaf_table="none"', 'forest.export="none"',
              "forest.truth_rasters=true"]
    run = sm.run_forest(load_scene(SCENE, corner), tmp_path / "o", truth_rasters=False, parallel=False)
    assert not {p.name for p in (tmp_path / "o").iterdir()} & set(RASTERS) and "truth_rasters" not in run.summary
    assert "top_cells" not in _trees(tmp_path / "o" / "trees.csv")[0]
