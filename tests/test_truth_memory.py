"""evaluate-photo's truth in bounded memory (issue 30): its two arrays are compute_truth's bit for
bit, the position sums are built a layer at a time with np.add.at's bits, and a grid that would
not fit is refused before it is allocated, with one line naming truth.voxel_m."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.errors import ConfigError
from simlidar_mi.truth.compute import compute_truth, leaf_and_plant_area
from simlidar_mi.truth.grid import VoxelGrid, grid_values
from simlidar_mi.truth.photo_scores import RadialSums, evaluate_photo
from simlidar_mi.truth.run import PHOTO_BYTES_PER_VOXEL, TRUTH_BYTES_PER_VOXEL, truth_geometry, truth_grid

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SMALL = ["forest.domain_m=[0.0, 16.0, 0.0, 16.0]", "truth.voxel_m=0.25"]


@pytest.fixture(scope="module")
def forest():
    cfg = load_scene(SCENES / "forest_small.toml", SMALL)
    geometry, _ = truth_geometry(cfg)
    return cfg, geometry, truth_grid(cfg, geometry)


def test_leaf_and_plant_area_are_the_truths_arrays_bit_for_bit(forest):
    cfg, geometry, grid = forest
    ds = compute_truth(geometry, grid, progress=False, ground_area_m2=200.0)
    leaf, plant, lai, pai = leaf_and_plant_area(geometry, grid, progress=False, ground_area_m2=200.0)
    assert leaf.tobytes("A") == grid_values(ds, "leaf_area_m2").tobytes("A")
    assert plant.tobytes("A") == grid_values(ds, "plant_area_m2").tobytes("A")
    assert leaf.strides == grid_values(ds, "leaf_area_m2").strides
    assert (lai, pai) == (ds.attrs["LAI"], ds.attrs["PAI"]) and 0 < lai < pai
    assert float(plant.sum()) > float(leaf.sum()) > 0


def test_position_sums_layer_by_layer_are_the_whole_grid_add_at():
    rng = np.random.default_rng(1)
    g = VoxelGrid((0.3, -1.0, 0.0), 0.1, (37, 41, 23))
    a = (rng.random((23, 41, 37)) * 10.0 ** rng.integers(-8, 3, (23, 41, 37))).T  # F order, as the truth's
    a = a * (rng.random(a.shape) < 0.3)
    for pos in ([1.0, 1.0, 0.2], [0.3, -1.0, 1.0], [5.0, 2.0, 0.0]):
        rs = RadialSums(g, a, pos)
        xc, yc = g.centres(0), g.centres(1)
        r = np.sqrt((xc[:, None] - pos[0]) ** 2 + (yc[None, :] - pos[1]) ** 2).ravel()
        idx = (r / rs.bin_m).astype(np.int64)
        h = np.zeros((idx.max() + 2, g.shape[2]))
        np.add.at(h, idx, np.asarray(a, float).reshape(-1, g.shape[2]))   # the former whole-grid form
        ref = np.vstack([np.zeros((1, g.shape[2])), np.cumsum(h, axis=0)])
        assert ref.tobytes() == rs.cum.tobytes()


def test_a_truth_grid_over_the_memory_is_refused_naming_the_voxel_key(forest, monkeypatch, tmp_path):
    cfg, geometry, grid = forest
    n = int(np.prod(grid.shape))
    assert truth_grid(cfg, geometry, memory=TRUTH_BYTES_PER_VOXEL * n) == grid
    with pytest.raises(ConfigError) as e:
        truth_grid(cfg, geometry, memory=TRUTH_BYTES_PER_VOXEL * n - 1)
    assert e.value.key == "truth.voxel_m" and e.value.value == 0.25 and "\n" not in str(e.value)
    assert "use larger voxels" in str(e.value)
    # evaluate-photo's two arrays need a third of that
    assert truth_grid(cfg, geometry, bytes_per_voxel=PHOTO_BYTES_PER_VOXEL, memory=PHOTO_BYTES_PER_VOXEL * n) == grid
    # the command: refused before the truth or the scene is built, nothing written
    monkeypatch.setattr("simlidar_mi.config.work.memory_budget", lambda: PHOTO_BYTES_PER_VOXEL * n - 1)
    monkeypatch.setattr("simlidar_mi.truth.compute.Totals", None)  # any use would fail differently
    with pytest.raises(ConfigError, match=r"key 'truth.voxel_m', value 0.25: a 0.25 m grid"):
        evaluate_photo(SCENES / "forest_small.toml", tmp_path / "out", SMALL)
    assert not (tmp_path / "out").exists()
