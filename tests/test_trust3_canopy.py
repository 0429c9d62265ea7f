"""Trust round 3 (issue 29 §2), canopies and cameras: n_sides used, fisheye.points_m only with
layout 'points', evaluate-photo refuses positions outside the canopy, fisheye tiles a periodic
plot like evaluate-photo, a lens in the leaf layer is warned about and the default lens sits
below it."""
import math

import numpy as np
import pytest

from simlidar_mi.canopy.canopy import canopies_from_config, expected_p0
from simlidar_mi.config import load_scene

SCENE = "scenes/random_leaves_spherical.toml"


# ------------------------------------------------------------------ random_leaves.n_sides
@pytest.mark.parametrize("k", [3, 5, 16])
def test_disc_leaves_have_n_sides_and_the_exact_area(k):
    cfg = load_scene(SCENE, ["random_leaves.shape='disc'", f"random_leaves.n_sides={k}",
                             "random_leaves.n_leaves=50"])
    leaves = canopies_from_config(cfg)[0].leaves
    assert len(leaves) == 50 * k  # a fan of k triangles per leaf
    v = leaves.vertices.reshape(50, k, 3, 3)
    centre = v[:, :, 0].mean(axis=1)  # every triangle of a fan starts at the centre
    r = np.linalg.norm(v[:, :, 1] - centre[:, None], axis=2)
    # The circumradius is the one that makes the k-gon's area (k/2) r² sin(2π/k) exactly a.
    r_exact = math.sqrt(2 * 0.001 / (k * math.sin(2 * math.pi / k)))
    np.testing.assert_allclose(r, r_exact, rtol=1e-12)
    area = leaves.triangle_area.reshape(50, k).sum(axis=1)
    np.testing.assert_allclose(area, 0.5 * k * r_exact ** 2 * math.sin(2 * math.pi / k), rtol=1e-12)
    np.testing.assert_allclose(area, 0.001, rtol=1e-12)


def test_n_sides_changes_the_rendered_gap_fraction_not_its_expectation():
    from simlidar_mi.canopy.gapfraction import run_gapfraction
    p0 = {}
    for k in (3, 16):
        run = run_gapfraction(SCENE, None, [
            "random_leaves.shape='disc'", f"random_leaves.n_sides={k}", "gapfraction.cameras=['orthographic']",
            "gapfraction.zeniths_deg=[0.0]", "gapfraction.resolution=256", "gapfraction.replicates=4",
            "gapfraction.spp=1"], write_images=False)
        (s,) = run.summary
        p0[k] = s.p0
        # Area-preserving discs: the exact E[P0] = (1 − a G/A)^N is the same for every k.
        assert s.p0 == pytest.approx(float(expected_p0(1000, 0.001, 1.0, 0.0)), abs=0.01)
    assert p0[3] != p0[16]  # the triangles differ, so one plot's pixels do too


# ------------------------------------------------------------------ fisheye.points_m
@pytest.mark.parametrize("sets,key,layout", [
    (["fisheye.points_m=[[0.2, 0.2]]"], "fisheye.points_m", "grid"),
    (["fisheye.layout='transect'", "fisheye.points_m=[[0.2, 0.2]]"], "fisheye.points_m", "transect"),
    (["fisheye.transect_m=[0, 0.5, 1, 0.5]"], "fisheye.transect_m", "grid"),
])
def test_a_position_key_of_another_layout_is_refused(sets, key, layout):
    from simlidar_mi.canopy.fisheye_run import fisheye_positions
    from simlidar_mi.errors import ConfigError
    cfg = load_scene(SCENE, sets)
    with pytest.raises(ConfigError) as err:
        fisheye_positions(cfg, np.zeros(3), np.ones(3))
    assert err.value.key == key and f"layout is '{layout}'" in str(err.value)
    assert "\n" not in str(err.value)


def test_fisheye_cli_refuses_points_m_without_the_points_layout(tmp_path, capsys):
    from simlidar_mi import cli
    rc = cli.main(["fisheye", SCENE, "--out", str(tmp_path / "o"), "--set", "fisheye.points_m=[[0.2, 0.2]]",
                   "--set", "fisheye.resolution=16"])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "fisheye.points_m" in line and "layout" in line, line
    assert not (tmp_path / "o" / "fisheye_gap.csv").exists()


# ------------------------------------------------------------------ fisheye tiles a periodic plot
def _csv(path):
    import csv
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_fisheye_and_evaluate_photo_read_the_same_sky_of_a_periodic_plot(tmp_path):
    from simlidar_mi import cli
    sets = ["fisheye.layout='points'", "fisheye.points_m=[[0.5, 0.5]]", "fisheye.resolution=256",
            "fisheye.rings_deg=[0, 15, 30, 45, 60, 75, 90]", "lai_methods.rings_deg=[0, 15, 30, 45, 60, 75]"]
    args = [a for s in sets for a in ("--set", s)]
    assert cli.main(["fisheye", SCENE, "--out", str(tmp_path / "f"), "--no-images", *args]) == 0
    assert cli.main(["evaluate-photo", SCENE, "--out", str(tmp_path / "e"), *args]) == 0
    import json
    rings = {(r["ring_lo_deg"], r["ring_hi_deg"]): r["P_measured"]
             for r in json.loads((tmp_path / "e" / "photo_scores.json").read_text())["rings"]}
    rows = [r for r in _csv(tmp_path / "f" / "fisheye_gap.csv") if r["sector"] != "all"]
    for lo in (0, 15, 30, 45, 60):
        cells = [r for r in rows if float(r["ring_lo_deg"]) == lo]
        n = np.array([float(r["n_pixels"]) for r in cells])
        fisheye = float(np.sum(n * np.array([float(r["gap"]) for r in cells])) / n.sum())
        # The same camera, seed and tiled canopy: the same rays, the same hits.
        assert fisheye == pytest.approx(rings[(lo, lo + 15)], abs=1e-9), lo
    # The 45–60° ring sees the tiled canopy, not open sky beyond one plot: near the Poisson
    # value exp(−G·L/cos θ) at 52.5° (G = 0.5, L = 1), 0.44, not 0.70.
    assert rings[(45, 60)] == pytest.approx(math.exp(-0.5 / math.cos(math.radians(52.5))), abs=0.12)


# ------------------------------------------------------------------ evaluate-photo outside the canopy
@pytest.mark.parametrize("scene,sets,key", [
    (SCENE, ["fisheye.layout='points'", "fisheye.points_m=[[0.5, 0.5], [5.0, 5.0]]"], "fisheye.points_m"),
    ("scenes/strawberry_plot.toml", ["fisheye.layout='points'", "fisheye.points_m=[[50.0, 50.0]]"],
     "fisheye.points_m"),
    ("scenes/strawberry_plot.toml", ["fisheye.layout='transect'", "fisheye.transect_m=[-30, 0, -20, 0]"],
     "fisheye.transect_m"),
    (SCENE, ["fisheye.area_m=[2, 2, 3, 3]"], "fisheye.area_m"),
])
def test_evaluate_photo_refuses_sensors_outside_the_canopy(tmp_path, capsys, scene, sets, key):
    from simlidar_mi import cli
    out = tmp_path / "o"
    out.mkdir()
    (out / "photo_scores.csv").write_text("earlier\n")
    rc = cli.main(["evaluate-photo", scene, "--out", str(out), "--set", "lai_methods.sampler='rays'",
                   "--set", "lai_methods.rays_per_cell=8", *[a for s in sets for a in ("--set", s)]])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and key in line and "outside" in line, line
    assert (out / "photo_scores.csv").read_text() == "earlier\n"  # nothing written, nothing lost
