"""evaluate-photo: footprint truth, the canopy's G, and the whole run on the random-leaves scene."""
import json
import math

import numpy as np
import pytest

from simlidar_mi.plants.random_leaves import random_leaves
from simlidar_mi.truth import photo_scores as ps
from simlidar_mi.truth.grid import VoxelGrid


def test_footprint_of_uniform_layers_is_the_lai():
    grid = VoxelGrid((-20.0, -20.0, 0.0), 0.1, (400, 400, 10))
    area = np.full(grid.shape, 0.01 * 0.02)  # 0.02 m² leaf per m² per 0.1 m layer: LAI 0.2
    for theta in (30.0, 60.0):
        assert ps.footprint_index(grid, area, np.array([0.0, 0.0, 0.0]), theta) == pytest.approx(
            0.2, rel=0.03)
    # The 57.5° method's annulus of a uniform canopy reads the same LAI.
    assert ps.footprint_index(grid, area, np.array([0.0, 0.0, 0.0]), 60.0,
                              theta_min_deg=55.0) == pytest.approx(0.2, rel=0.05)
    # Only the layers above the sensor count.
    assert ps.footprint_index(grid, area, np.array([0.0, 0.0, 0.5]), 60.0) == pytest.approx(
        0.1, rel=0.05)


@pytest.mark.parametrize("law,expect", [("spherical", lambda t: 0.5 + 0 * t),
                                        ("horizontal", np.cos),
                                        ("vertical", lambda t: 2 / np.pi * np.sin(t))])
def test_canopy_G_of_the_leaf_laws(law, expect):
    c = random_leaves(20000, 1e-4, (1.0, 1.0), (0.0, 1.0), law, seed=4)
    z = np.array([0.0, 30.0, 57.5, 75.0])
    np.testing.assert_allclose(ps.canopy_G(c.originals.vertices, z), expect(np.radians(z)),
                               atol=0.01)


@pytest.mark.parametrize("sampler", ["rays", "fisheye"])
def test_evaluate_photo_random_leaves(tmp_path, sampler):
    run = ps.evaluate_photo("scenes/random_leaves_spherical.toml", tmp_path / "out",
                            ["fisheye.grid_n=[3, 3]", "fisheye.height_m=0.1", f"lai_methods.sampler={sampler!r}",
                             "lai_methods.rays_per_cell=64", "fisheye.resolution=256"])
    for name in ("photo_scores.csv", "photo_scores.json", "photo_scores.png", "photo_positions.csv"):
        assert (tmp_path / "out" / name).is_file()
    truth = run.get("miller", "LAI", "plot")["truth_mean"]
    assert truth == pytest.approx(0.8, abs=0.05)  # leaves above the 0.1 m sensor: 80 % of LAI 1
    for m in ("miller", "hinge_57", "lai2200", "lai2200_le", "chen_cihlar"):
        row = run.get(m, "LAI", "plot")
        assert row["coverage"] == 1.0 and abs(row["bias"]) < 0.15, (m, row)
    d = json.loads((tmp_path / "out" / "photo_scores.json").read_text())
    g = [r["G_truth"] for r in d["rings"]]
    np.testing.assert_allclose(g, 0.5, atol=0.02)
    assert math.isfinite(d["lai2200"]["acf"]) and d["chen_cihlar"]["omega"] <= 1.0


def test_footprint_beyond_the_grid_is_bare():
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.1, (20, 20, 10))  # a 2 × 2 m block of LAI 0.2
    area = np.full(grid.shape, 0.01 * 0.02)
    # A sensor at the block's corner sees it in a quarter of each large disc.
    got = ps.footprint_index(grid, area, np.array([0.0, 0.0, 0.0]), 30.0)
    assert 0.05 < got < 0.2


@pytest.mark.parametrize("override,key", [
    ("lai_methods.view_cap_deg=0", "lai_methods.view_cap_deg"),
    ("lai_methods.zero_gap='none'", "lai_methods.zero_gap"),
    ("lai_methods.wood_to_total=1.0", "lai_methods.wood_to_total"),
    ("lai_methods.rings_deg=[0, 50, 40]", "lai_methods.rings_deg"),
    ("fisheye.looking='down'", "fisheye.looking"),
])
def test_bad_lai_method_keys_are_named(tmp_path, override, key):
    from simlidar_mi.errors import ConfigError
    with pytest.raises(ConfigError) as err:
        ps.evaluate_photo("scenes/random_leaves_spherical.toml", tmp_path / "out", [override])
    assert key in str(err.value)
