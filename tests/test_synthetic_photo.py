"""Synthetic photos: Canopeo on a photo-like RGB render agrees with the coverage render.

The photos are rendered in an ``llvm_ad_rgb`` child process (this process runs
``llvm_ad_mono``); the module-scoped fixture renders every view the agreement tests
need in one child, so the whole file runs in well under 30 s on 2 cores.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simlidar_mi import Branches, ConfigError, SimlidarError
from simlidar_mi.canopy.compare import compare
from simlidar_mi.config import load_scene
from simlidar_mi.canopy.cameras import make_camera
from simlidar_mi.canopy.canopy import canopies_from_config
from simlidar_mi.canopy.gapfraction import gap_images
from simlidar_mi.canopy.synthetic_photo import (CSV_COLUMNS, DEFAULTS, PhotoSettings, canopeo_p0,
                                         check_images, render_photo, run_synthetic_photos,
                                         save_photo_png, srgb_encode)

REPO = Path(__file__).resolve().parents[1]
STRAWBERRY = REPO / "scenes" / "strawberry_plot.toml"
RANDOM_LEAVES = REPO / "scenes" / "random_leaves_spherical.toml"
RES = 512
TOL = 0.01  # the agreement target


@pytest.fixture(scope="module")
def nadir_checks():
    """Strawberry plot (orthographic and perspective) and random leaves, nadir, 512²."""
    sb = canopies_from_config(load_scene(STRAWBERRY))[0]
    rl = canopies_from_config(load_scene(RANDOM_LEAVES))[0]
    images = gap_images(sb, cameras=["orthographic", "perspective"], zeniths_deg=[0.0],
                        resolution=RES, window="inset")
    images += gap_images(rl, cameras=["orthographic"], zeniths_deg=[0.0], resolution=RES)
    checks = check_images(images, [sb, sb, rl])
    return {"sb_ortho": checks[0], "sb_persp": checks[1], "rl_ortho": checks[2]}


@pytest.mark.parametrize("name", ["sb_ortho", "sb_persp", "rl_ortho"])
def test_canopeo_on_photo_agrees_with_coverage(nadir_checks, name: str) -> None:
    chk = nadir_checks[name]
    assert abs(chk.p0_canopeo - chk.p0_coverage) <= TOL, (chk.p0_canopeo, chk.p0_coverage)
    assert chk.difference == pytest.approx(chk.p0_canopeo - chk.p0_coverage)
    # the disagreement lives on leaf edges: pixels whose 4 coverage samples agree are
    # classified right (a few are still partly covered, or steep leaves in dim light)
    cov, green = chk.image.coverage, chk.canopeo_mask
    assert green[cov == 1.0].mean() > 0.995
    assert (~green[cov == 0.0]).mean() > 0.995


def test_photo_looks_like_a_photo(nadir_checks) -> None:
    chk = nadir_checks["sb_ortho"]
    cam = chk.image.camera
    assert chk.rgb.dtype == np.uint8 and chk.rgb.shape == (cam.height, cam.width, 3)
    cov = chk.image.coverage
    leaf = np.median(chk.rgb[cov == 1.0].astype(int), axis=0)
    soil = np.median(chk.rgb[cov == 0.0].astype(int), axis=0)
    assert leaf[1] > leaf[0] and leaf[1] > leaf[2]  # green leaves
    assert soil[0] > soil[1] > soil[2]  # brown soil
    assert 20 < leaf.mean() < 200 and 20 < soil.mean() < 200  # neither black nor clipped


def test_canopeo_p0_is_photo_module_rule(nadir_checks) -> None:
    chk = nadir_checks["rl_ortho"]
    p0, mask = canopeo_p0(chk.rgb, chk.image.window.box_px)
    assert p0 == chk.p0_canopeo and np.array_equal(mask, chk.canopeo_mask)


def test_loop_through_compare_manifest(nadir_checks, tmp_path: Path) -> None:
    """The synthetic photo as a manifest row: compare() reads back Canopeo's P0."""
    chk = nadir_checks["sb_ortho"]
    save_photo_png(chk.rgb, tmp_path / "photo.png")
    # one plot (replicate 0, the one the photo shows), at the photo's resolution
    text = STRAWBERRY.read_text(encoding="utf-8")
    assert "resolution = 512 " in text and "replicates = 16 " in text
    text = text.replace("resolution = 512 ", f"resolution = {RES} ").replace(
        "replicates = 16 ", "replicates = 1 ")
    (tmp_path / "sb.toml").write_text(text, encoding="utf-8")
    x0, y0, x1, y1 = chk.image.window.box_px
    (tmp_path / "m.csv").write_text(
        "scene,camera,zenith_deg,step,photo,method,crop\n"
        f"sb.toml,orthographic,0,0,photo.png,canopeo,\"{x0},{y0},{x1},{y1}\"\n", encoding="utf-8")
    res = compare(tmp_path / "m.csv", tmp_path / "out")
    pair = res.pairs[0]
    assert pair.p0_measured == pytest.approx(chk.p0_canopeo, abs=1e-12)
    assert pair.p0_virtual == pytest.approx(chk.p0_coverage, abs=1e-12)
    assert abs(res.stats_for(0.0)["bias"]) <= TOL


def test_run_synthetic_photos_writes_files(tmp_path: Path) -> None:
    out = tmp_path / "photos"
    checks = run_synthetic_photos(STRAWBERRY, out, [
        "gapfraction.resolution=256", "gapfraction.cameras=['orthographic']",
        "gapfraction.zeniths_deg=[30.0]", "strawberry.extraction_counts=[127]", "photo_render.spp=8"])
    assert [(c.image.camera.zenith_deg, c.image.step) for c in checks] == [(30.0, 0), (30.0, 1)]
    assert all(c.settings.spp == 8 for c in checks)
    assert checks[1].p0_coverage > checks[0].p0_coverage  # 127 leaves fewer
    for c in checks:  # 256²: edge pixels weigh twice as much as at 512², still within 0.01
        assert abs(c.difference) <= TOL
    with open(out / "synthetic_photo.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 2
    assert float(rows[1]["p0_canopeo"]) == pytest.approx(checks[1].p0_canopeo, abs=1e-6)
    cam = checks[0].image.camera
    for stem in ("photo_orthographic_z30_s0", "photo_orthographic_z30_s1"):
        with Image.open(out / f"{stem}.png") as im:
            assert im.mode == "RGB" and im.size == (cam.width, cam.height)
        assert (out / f"{stem}_canopeo.png").is_file()
    assert (out / "synthetic_photo.json").is_file()


def test_same_seed_same_bytes_and_sizes() -> None:
    rl = canopies_from_config(load_scene(RANDOM_LEAVES, ["random_leaves.n_leaves=50"]))[0]
    cam = make_camera("perspective", rl, 15.0, resolution=48)
    from simlidar_mi.canopy.synthetic_photo import _make_job, render_photos  # noqa: PLC0415
    a, b = render_photos([_make_job(rl, cam), _make_job(rl, cam)], PhotoSettings(spp=4), seed=3)
    assert a.shape == (48, 48, 3) and np.array_equal(a, b)


# ----------------------------------------------------------------- pure parts
def test_srgb_encode_known_values() -> None:
    lin = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0, 2.0, -1.0, np.nan])
    got = srgb_encode(np.stack([lin] * 3, axis=-1))[:, 0]
    # 12.92·0.0031308 = 0.04045 → 10; 1.055·0.18^(1/2.4) − 0.055 = 0.4614 → 118;
    # 0.5 → 0.7354 → 188; values above 1 clip, negatives and NaN give 0
    assert got.tolist() == [0, 10, 118, 188, 255, 255, 0, 0]
    assert srgb_encode(np.full((1, 1, 3), 0.25), exposure=2.0)[0, 0, 0] == 188


def test_settings_defaults_and_scene_section() -> None:
    s = PhotoSettings()
    assert list(s.leaf_rgb) == DEFAULTS["leaf_rgb"] and list(s.soil_rgb) == DEFAULTS["soil_rgb"]
    cfg = load_scene(STRAWBERRY, ["photo_render.soil_rgb=[0.3, 0.2, 0.1]", "photo_render.exposure=1.5"])
    s = PhotoSettings.from_config(cfg)
    assert s.soil_rgb == (0.3, 0.2, 0.1) and s.exposure == 1.5 and s.spp == DEFAULTS["spp"]
    with pytest.raises(ConfigError, match="photo_render.soil_rgb"):
        load_scene(STRAWBERRY, ["photo_render.soil_rgb=[0.3, 0.2]"])
    with pytest.raises(ConfigError, match="photo_render.variant"):
        load_scene(STRAWBERRY, ["photo_render.variant='llvm_ad_mono'"])


@pytest.mark.parametrize("kw,key", [
    ({"leaf_rgb": (0.1, 0.2)}, "leaf_rgb"), ({"soil_rgb": (0.1, 0.2, 1.5)}, "soil_rgb"),
    ({"sky_radiance": -1.0}, "sky_radiance"), ({"sun_irradiance": float("nan")}, "sun_irradiance"),
    ({"exposure": 0.0}, "exposure"), ({"sun_zenith_deg": 95.0}, "sun_zenith_deg"),
    ({"spp": 0}, "spp"), ({"max_depth": 0}, "max_depth"), ({"variant": "llvm_ad_mono"}, "variant"),
])
def test_settings_refuse_bad_values(kw, key) -> None:
    with pytest.raises(ConfigError, match=f"photo_render.{key}"):
        PhotoSettings(**kw)


def test_sun_direction() -> None:
    rl = canopies_from_config(load_scene(RANDOM_LEAVES))[0]
    cam = make_camera("orthographic", rl, 30.0, azimuth_deg=90.0, resolution=8)
    assert np.allclose(PhotoSettings().sun_direction(cam), cam.direction)  # behind the camera
    d = PhotoSettings(sun_zenith_deg=30.0, sun_azimuth_deg=0.0).sun_direction(cam)
    assert np.allclose(d, [0.5, 0.0, -np.sqrt(3) / 2])


def test_wood_is_refused() -> None:
    from dataclasses import replace  # noqa: PLC0415
    rl = canopies_from_config(load_scene(RANDOM_LEAVES, ["random_leaves.n_leaves=10"]))[0]
    wood = Branches(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.2]]), np.array([0.01]),
                    np.ones(1, np.int32), np.zeros(1, np.int32))
    cam = make_camera("orthographic", rl, 0.0, resolution=8)
    with pytest.raises(ConfigError, match="wood"):
        render_photo(replace(rl, branches=wood), cam)


def test_child_failure_is_reported() -> None:
    rl = canopies_from_config(load_scene(RANDOM_LEAVES, ["random_leaves.n_leaves=10"]))[0]
    cam = make_camera("orthographic", rl, 0.0, resolution=8)
    with pytest.raises(SimlidarError, match="child process"):
        render_photo(rl, cam, PhotoSettings(variant="no_such_rgb"))


def test_synthetic_photo_cli(tmp_path, capsys):
    """The CLI command renders, classifies and reports agreement within 0.01."""
    import csv as _csv

    from simlidar_mi.cli import main
    from tests.conftest import SCENES
    out = tmp_path / "synth"
    rc = main(["synthetic-photo", str(SCENES / "strawberry_plot.toml"), "--out", str(out),
               "--set", "gapfraction.resolution=384", "--set", "gapfraction.zeniths_deg=[0.0]",
               "--set", 'gapfraction.cameras=["orthographic"]', "--set", "strawberry.extraction_counts=[44]"])
    assert rc == 0
    rows = list(_csv.DictReader(open(out / "synthetic_photo.csv")))
    assert len(rows) == 2
    printed = capsys.readouterr().out
    assert "p0 canopeo" in printed
    for line in printed.splitlines()[1:3]:
        assert abs(float(line.split()[-1])) <= 0.01


def test_child_process_path_is_the_folder_holding_the_package():
    # PYTHONPATH must hold the package's parent: the package folder itself would let its io/
    # shadow the standard library's io in the child (Python 3.10 fails at start-up)
    import simlidar_mi
    from simlidar_mi.canopy.synthetic_photo import _package_parent
    assert _package_parent() == Path(simlidar_mi.__file__).resolve().parents[1]
    assert not (_package_parent() / "io").exists()
