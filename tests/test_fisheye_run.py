"""Fisheye runs: [fisheye] keys, camera placement, the written EXR/PNG/CSV, and the CLI."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from simlidar_mi.canopy.fisheye_lens import LENSES, PROJECTIONS
from simlidar_mi.canopy.fisheye_run import fisheye_cameras, fisheye_positions, read_fisheye_exr, run_fisheye
from simlidar_mi.config import load_scene
from simlidar_mi.config.keys_fisheye import PROJECTION_CHOICES
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches, Leaves
from tests.conftest import REPO

SCENE = REPO / "scenes" / "random_leaves_spherical.toml"


def _cfg(*overrides):
    return load_scene(SCENE, list(overrides))


def test_projection_key_lists_every_lens():
    assert set(PROJECTION_CHOICES) == set(PROJECTIONS) | set(LENSES)


def test_grid_transect_and_points():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([6.0, 3.0, 5.0])
    plants = load_scene(REPO / "scenes" / "strawberry_plot.toml")  # not a [random_leaves] layer
    p = fisheye_positions(plants, lo, hi)  # default 3 × 3 at cell centres, 1 m up under a tall canopy
    np.testing.assert_allclose(p[:3, 0], [1.0, 3.0, 5.0])
    np.testing.assert_allclose(p[::3, 1], [0.5, 1.5, 2.5])
    np.testing.assert_array_equal(p[:, 2], 1.0)
    assert fisheye_positions(plants, lo, np.array([6.0, 3.0, 0.4]))[0, 2] == 0.0  # a crop: at the ground
    t = fisheye_positions(_cfg('fisheye.layout="transect"', "fisheye.transect_m=[0, 1, 4, 1]",
                               "fisheye.transect_n=3", "fisheye.height_m=0.5"), lo, hi)
    np.testing.assert_allclose(t, [[0, 1, 0.5], [2, 1, 0.5], [4, 1, 0.5]])
    d = fisheye_positions(_cfg('fisheye.looking="down"', 'fisheye.layout="points"', "fisheye.points_m=[[1, 2]]"), lo, hi)
    np.testing.assert_allclose(d, [[1, 2, 6.0]])
    with pytest.raises(ConfigError, match="points_m"):
        fisheye_positions(_cfg('fisheye.layout="points"'), lo, hi)
    with pytest.raises(ConfigError, match="coeffs"):
        fisheye_cameras(_cfg('fisheye.projection="polynomial"'), lo, hi)
    with pytest.raises(ConfigError, match="grid_n"):
        _cfg("fisheye.grid_n=[0, 2]")


def test_run_writes_tables_and_images(tmp_path):
    from simlidar_mi.scene.build import build_scene
    a = np.linspace(0, 2 * np.pi, 65)
    ring = np.stack([0.5 * np.cos(a), 0.5 * np.sin(a), np.full(65, 3.0)], 1)
    tri = np.stack([np.broadcast_to([0.0, 0.0, 3.0], (64, 3)), ring[:-1], ring[1:]], 1)
    leaves = Leaves(tri, np.zeros(64, np.int32), np.zeros(64, np.int32))
    built = build_scene(Branches.empty(), leaves, [], origin_m=np.zeros(3))
    cfg = _cfg('fisheye.layout="points"', "fisheye.points_m=[[0, 0], [5, 0]]", "fisheye.height_m=1.0",
               "fisheye.resolution=40", "fisheye.spp=1", "fisheye.n_sectors=4", 'fisheye.projection="Sigma-8"')
    run = run_fisheye(cfg, built, (np.zeros(3), np.full(3, 3.0)), tmp_path)
    rows = list(csv.DictReader(open(tmp_path / "fisheye_gap.csv")))
    assert len(rows) == 2 * 6 * (4 + 1)
    first = [r for r in rows if r["position"] == "0" and r["sector"] == "all"]
    assert float(first[0]["gap"]) < 0.2 and float(first[1]["gap"]) == 1.0  # the disc spans θ < 14°
    far = [float(r["gap"]) for r in rows if r["position"] == "1"]
    assert min(far) > 0.9  # 5 m aside: the disc is a speck low in the sky
    ch, hdr = read_fisheye_exr(tmp_path / "fisheye_0.exr")
    np.testing.assert_array_equal(ch["coverage"], run.images[0].coverage)
    assert np.isnan(ch["coverage"][0, 0]) and np.isnan(ch["theta_deg"][0, 0])
    assert hdr["projection"] == "Sigma-8" and hdr["format"] == "circular"
    np.testing.assert_array_equal(hdr["camera_position_m"], [0.0, 0.0, 1.0])
    assert hdr["metadata"]["lens"]["coeffs"] == [0.75276, -0.073937]
    from PIL import Image
    png = np.asarray(Image.open(tmp_path / "fisheye_0.png"))
    assert png.shape == (40, 40) and png[0, 0] == 2 and png[20, 20] == 1


def test_cli_renders_every_position(tmp_path, capsys):
    from simlidar_mi.cli import main
    rc = main(["fisheye", str(SCENE), "--out", str(tmp_path), "--set", "fisheye.resolution=32",
               "--set", "fisheye.grid_n=[2, 1]", "--set", "fisheye.spp=1"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "2 images" in out
    assert {p.name for p in tmp_path.iterdir()} >= {"fisheye_gap.csv", "fisheye_positions.csv", "fisheye_0.exr",
                                                   "fisheye_1.png"}
    rows = list(csv.DictReader(open(tmp_path / "fisheye_gap.csv")))
    totals = [float(r["gap"]) for r in rows if r["sector"] == "all"]
    assert min(totals) < 1.0  # under the leaf layer (camera at the ground), leaves are seen


def test_fisheye_exr_reads_in_openimageio(tmp_path):
    """An independent reader (OpenImageIO: iinfo, oiiotool, GIMP's loader) sees the channels,
    their float32 values and the lens in the header, as we wrote them."""
    oiio = pytest.importorskip("OpenImageIO")
    from simlidar_mi.scene.build import build_scene
    tri = np.array([[[-2.0, -2.0, 3.0], [2.0, -2.0, 3.0], [0.0, 2.0, 3.0]]])
    built = build_scene(Branches.empty(), Leaves(tri, np.zeros(1, np.int32), np.zeros(1, np.int32)), [],
                        origin_m=np.zeros(3))
    cfg = _cfg('fisheye.layout="points"', "fisheye.points_m=[[0, 0]]", "fisheye.height_m=1.0",
               "fisheye.resolution=32", "fisheye.spp=1", 'fisheye.projection="FC-E8"')
    run = run_fisheye(cfg, built, (np.full(3, -2.0), np.full(3, 3.0)), tmp_path)
    buf = oiio.ImageBuf(str(tmp_path / "fisheye_0.exr"))
    spec = buf.spec()
    names = list(spec.channelnames)
    assert {"coverage", "theta_deg", "azimuth_deg"} <= set(names)
    assert (spec.width, spec.height) == (32, 32) and spec.format == oiio.FLOAT
    pixels = buf.get_pixels(oiio.FLOAT)  # (H, W, C)
    np.testing.assert_array_equal(pixels[..., names.index("coverage")], run.images[0].coverage)
    assert "FC-E8" in " ".join(str(a.value) for a in spec.extra_attribs)


def test_a_hillside_above_the_horizon_is_not_sky():
    """On a 30° slope rising towards +x, a looking-up lens 1 m above it sees the hillside where a
    view's elevation is below atan(tan 30° · cos φ): those pixels are covered (terrain hits are
    opaque, as a real photo shows a hill), every other pixel is sky.  Checked pixel by pixel
    against that float64 answer (away from the edge curve by 0.5° and from views that leave the
    ±600 m terrain); the flat ground, below the horizon of an up-looking lens, is never seen."""
    from simlidar_mi.canopy.fisheye_run import fisheye_scene
    from simlidar_mi.lidar.survey import generate
    text = """
[scene]
seed = 1
{terrain}
[[primitive]]
type = "box"
min_m = [500.0, 500.0, 500.0]
max_m = [501.0, 501.0, 501.0]
[fisheye]
layout = "points"
points_m = [[0.0, 0.0]]
height_m = 1.0
resolution = 160
spp = 1
n_sectors = 4
"""
    hill = "[terrain]\nslope_deg = 30\naspect_deg = 270\nextent_m = [-600, 600, -600, 600]\ncell_m = 100.0"
    runs = []
    for terrain in (hill, ""):
        cfg = load_scene(text=text.format(terrain=terrain))
        g = generate(cfg)
        runs.append(run_fisheye(cfg, fisheye_scene(cfg, g), g.bounds_m(), None))
    img = runs[0].images[0]
    a = img.angles
    th, ph = np.radians(a.theta_deg), np.radians(a.azimuth_deg)
    edge = np.degrees(np.arctan(np.tan(np.radians(30.0)) * np.cos(ph)))   # the hillside's elevation
    elev = 90.0 - a.theta_deg
    rise = np.tan(np.radians(30.0)) * np.sin(th) * np.cos(ph) - np.cos(th)  # t = 1 m / rise
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.where(rise > 0, np.sin(th) / rise, np.inf)              # horizontal distance to the hit
    clear = a.inside & (np.abs(elev - edge) > 0.5) & (reach < 500.0) | a.inside & (elev > edge + 0.5)
    expect = (elev < edge).astype(np.float32)
    assert clear.sum() > 0.9 * a.inside.sum()
    np.testing.assert_array_equal(img.coverage[clear], expect[clear])
    assert expect[clear].sum() > 0.1 * clear.sum()                      # the hill fills a real share
    tab = runs[0].tables[0]
    assert tab.ring_gap[-1] < 0.7                                       # the 75–90° ring: the hill is not sky
    assert np.all(runs[1].images[0].coverage[a.inside] == 0.0)          # no terrain: all sky
