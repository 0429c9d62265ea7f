"""Real fisheye photographs through the virtual camera's ring/sector table."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from PIL import Image

from simlidar_mi.canopy.fisheye import gap_table, make_fisheye, render_fisheye
from simlidar_mi.canopy.photo_fisheye import detect_circle, fisheye_photo_gap, run_fisheye_photos
from simlidar_mi.errors import PhotoError
from simlidar_mi.geometry import Branches, Leaves
from tests.conftest import REPO, SHARED

HEMI = SHARED / "data" / "photos" / "hemispheR"
# shipped with its MIT licence in examples/photos (its README): these tests need no ../shared
CHESTNUT = REPO / "examples" / "photos" / "hemispheR" / "circular_coolpix4500+FC-E8_chestnut.jpg"
BEECH = HEMI / "fullframe_D90_Nikkor-10.5_beech.jpg"
GRASS = HEMI / "circular_downward_D90-8-15.jpg"
needs_photos = pytest.mark.skipif(not HEMI.is_dir(), reason=f"hemispheR photos absent ({HEMI})")


def _disc_photo(path, w, h, xc, yc, r, blobs=()):
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    inside = np.hypot(xx - xc, yy - yc) <= r
    for bx, by, br in blobs:  # dark foliage at the rim
        inside &= np.hypot(xx - bx, yy - by) > br
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[inside] = (200, 220, 255)
    Image.fromarray(rgb).save(path)


def test_detect_circle_of_a_synthetic_photo(tmp_path):
    p = tmp_path / "disc.png"
    _disc_photo(p, 400, 300, 203.0, 148.0, 120.0, blobs=[(203 + 120, 148, 25), (203, 148 - 120, 18)])
    xc, yc, r = detect_circle(p)
    assert (xc, yc, r) == pytest.approx((203.0, 148.0, 120.0), abs=0.6)
    q = tmp_path / "black.png"
    Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(q)
    with pytest.raises(PhotoError, match="no image circle"):
        detect_circle(q)


def test_a_rendered_image_saved_as_a_photo_gives_the_same_table(tmp_path):
    from simlidar_mi.scene.build import build_scene
    quad = np.array([[[-100, 0, 2.0], [100, 0, 2.0], [100, 100, 2.0]], [[-100, 0, 2.0], [100, 100, 2.0], [-100, 100, 2.0]]])
    built = build_scene(Branches.empty(), Leaves(quad, np.zeros(2, np.int32), np.zeros(2, np.int32)), [],
                        origin_m=np.zeros(3))
    cam = make_fisheye([0.3, 0.0, 1.0], projection="FC-E8", resolution=120)
    img = render_fisheye(built, cam, spp=1)
    virtual = img.table(n_sectors=4)
    rgb = np.zeros((120, 120, 3), np.uint8)
    rgb[img.coverage == 0.0] = 255  # sky white, plant and outside black
    photo = tmp_path / "virtual.png"
    Image.fromarray(rgb).save(photo)
    real = fisheye_photo_gap(photo, "FC-E8", circle=(60, 60, 60), n_sectors=4).table
    np.testing.assert_array_equal(real.n_pixels, virtual.n_pixels)
    np.testing.assert_allclose(real.gap, virtual.gap, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(real.ring_gap, virtual.ring_gap, rtol=1e-12)
    # and the photo's azimuths are the scene's: the half plane y > 0 fills sectors 0–180°
    np.testing.assert_allclose(real.gap[:4], np.tile([0.0, 0.0, 1.0, 1.0], (4, 1)), atol=0.02)


def test_chestnut_circular_fc_e8():
    # hemispheR's camera_fisheye('Coolpix4500+FC-E8'): xc 1136, yc 852, rc 754 (full-size pixels)
    r = fisheye_photo_gap(CHESTNUT, "FC-E8", circle=(1136, 852, 754), downscale=4, keep_labels=True)
    assert r.n_inside == pytest.approx(math.pi * (754 / 4) ** 2, rel=0.01)
    assert 0.02 < r.gap_fraction < 0.3 and 0 < r.threshold < 255
    assert np.all((r.table.ring_gap >= 0) & (r.table.ring_gap <= 1))
    assert r.table.gap.shape == (6, 8) and not np.isnan(r.table.gap).any()
    assert r.labels.shape == (426, 568) and r.labels[0, 0] == 2
    xc, yc, rad = detect_circle(CHESTNUT, downscale=4)
    assert abs(xc - 1136) < 40 and 600 < rad < 800
    # the detected circle holds the whole lit disc: beyond its rim the surround is black
    from simlidar_mi.canopy.photo import read_rgb
    bright = read_rgb(CHESTNUT, 4).max(axis=2)
    yy, xx = np.mgrid[0:bright.shape[0], 0:bright.shape[1]] + 0.5
    assert bright[np.hypot(xx - xc / 4, yy - yc / 4) > rad / 4 + 3].mean() < 0.5


@needs_photos
def test_beech_fullframe_every_pixel_counts(tmp_path):
    res = run_fisheye_photos([BEECH], tmp_path, lens="Nikkor-10.5", format="fullframe", downscale=2)
    r = res[0]
    w, h = 2144 // 2, 1424 // 2
    assert r.n_inside == w * h and not r.detected
    assert r.circle_px == pytest.approx((1072, 712, 0.5 * math.hypot(2144, 1424)))
    assert 0.1 < r.gap_fraction < 0.6
    rows = list(csv.DictReader(open(tmp_path / "fisheye_photo_gap.csv")))
    assert len(rows) == 6 * 9 and rows[0]["lens"] == "Nikkor-10.5"
    assert (tmp_path / "fullframe_D90_Nikkor-10.5_beech_fisheye_mask.png").is_file()


@needs_photos
def test_downward_grass_circle_cut_by_the_frame():
    r = fisheye_photo_gap(GRASS, "equisolid", method="canopeo", looking="down", downscale=4)
    xc, yc, rad = r.circle_px
    assert r.detected and abs(xc - 2144) < 100 and abs(yc - 1424) < 100 and rad > 1424  # wider than the frame is tall
    assert 0.3 < r.gap_fraction < 0.95
    assert r.table.n_pixels.sum() == r.n_inside


def test_a_photo_and_a_virtual_image_give_the_same_lai(tmp_path):
    """Field photos go through the LAI methods by the code evaluate-photo runs on virtual images:
    a rendered image saved as a photo gives the same LAI by every method."""
    from simlidar_mi.canopy.lai_table import estimate_methods, method_rings
    from simlidar_mi.canopy.photo_fisheye import lai_spec, photo_lai
    from simlidar_mi.config.keys import SECTIONS
    from simlidar_mi.scene.build import build_scene
    rng = np.random.default_rng(5)
    centres = rng.uniform([-3, -3, 1.5], [3, 3, 3.0], (300, 3))
    tri = centres[:, None, :] + rng.normal(0, 0.15, (300, 3, 3))
    built = build_scene(Branches.empty(), Leaves(tri, np.arange(300, dtype=np.int32), np.zeros(300, np.int32)),
                        [], origin_m=np.zeros(3))
    cam = make_fisheye([0.0, 0.0, 1.0], projection="equidistant", resolution=240)
    img = render_fisheye(built, cam, spp=1)
    settings = {k: key.default for k, key in SECTIONS["lai_methods"].items()}
    t = img.table(method_rings(settings["rings_deg"]), int(settings["n_sectors"]))
    virtual = estimate_methods(t.gap[None], t.n_pixels[None].astype(float), settings)[0][0]
    rgb = np.zeros((240, 240, 3), np.uint8)
    rgb[img.coverage == 0.0] = 255
    photo = tmp_path / "virtual.png"
    Image.fromarray(rgb).save(photo)
    got = photo_lai(fisheye_photo_gap(photo, "equidistant", circle=(120, 120, 120), lai_spec=lai_spec()))
    assert 0.05 < virtual["miller"] < 5  # leaves were seen
    for m, v in virtual.items():
        assert got[m] == pytest.approx(v, rel=1e-9), m
    assert 0 < got["lai2200_acf"] <= 1.0 + 1e-9


def test_chestnut_lai_by_every_method(tmp_path):
    out = tmp_path / "dhp"
    (r,) = run_fisheye_photos([CHESTNUT], out, lens="FC-E8", downscale=4, lai=True)
    rows = list(csv.DictReader(open(out / "fisheye_photo_lai.csv")))
    assert [row["method"] for row in rows] == ["miller", "miller_lx", "hinge_57", "lai2200"]
    lai = {row["method"]: float(row["lai"]) for row in rows}
    # a closed chestnut canopy (gap ≈ 0.07): effective LAI of a few, log-averaging reads higher
    assert 1.0 < lai["miller"] < 8.0 and lai["miller_lx"] >= lai["miller"] - 1e-9
    assert r.labels is None and r.lai["lai2200"] == pytest.approx(lai["lai2200"])
