"""Photo gap fraction: real photos with published values, rules, crops, bad files, masks.

Real photos live beside the repository in ``../shared/data/photos`` (see its
PROVENANCE.md); tests that need them skip when the folder is absent. They are
never copied into the repository.
"""
from __future__ import annotations

import json
import os
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simlidar_mi import PhotoError, SimlidarError
from simlidar_mi.cli import main
from simlidar_mi.io.png import (BACKGROUND_RGB, FOREGROUND_RGB, WINDOW_RGB, render_mask_rgb,
                                write_mask_png)
from simlidar_mi.canopy.photo import (METHODS, PhotoGapResult, classify_rgb, crop_box, parse_crop,
                                      photo_gap, read_rgb)

PHOTOS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "photos"
needs_photos = pytest.mark.skipif(
    not PHOTOS.is_dir(),
    reason=f"real test photos not found at {PHOTOS} (shared data folder beside the repo)")
# the two MIT-licensed photos shipped in the repository (examples/photos/README.md): no ../shared needed
EXAMPLE_PHOTOS = Path(__file__).resolve().parents[1] / "examples" / "photos"
TOL = 0.002  # JPEG decoders differ by +-1 in pixel values (PROVENANCE.md)


# --- helpers -------------------------------------------------------------------

def _save_rgb(path: Path, rgb: np.ndarray, **kw) -> Path:
    Image.fromarray(np.asarray(rgb, dtype=np.uint8)).save(path, **kw)
    return path


def _png16_rgb(path: Path, arr: np.ndarray) -> Path:
    """A 16-bit-per-channel RGB PNG (Pillow cannot write one)."""
    h, w, _ = arr.shape
    raw = b"".join(b"\x00" + arr[y].astype(">u2").tobytes() for y in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + tag + data
                + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))

    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    return path


def _imagej_otsu(values: np.ndarray) -> int:
    """Independent oracle: ImageJ Auto Threshold 'Otsu' as autothresholdr calls it.

    Histogram with one bin per integer over [min, max]; threshold = the level k
    maximising the between-class variance (mu_T * w(k) - mu(k))^2 / (w(k) (1 - w(k))),
    first maximum, returned as min + k; foreground = value > threshold.
    """
    v = values.astype(np.int64).ravel()
    lo, hi = int(v.min()), int(v.max())
    p = np.bincount(v - lo, minlength=hi - lo + 1) / v.size
    w = np.cumsum(p)
    mu = np.cumsum(np.arange(p.size) * p)
    with np.errstate(divide="ignore", invalid="ignore"):
        bcv = (mu[-1] * w - mu) ** 2 / (w * (1.0 - w))
    bcv = np.where(np.isfinite(bcv), bcv, 0.0)
    return lo + int(np.argmax(bcv))


@pytest.fixture
def masks(tmp_path: Path) -> Path:
    return tmp_path / "masks"


# --- real photos with published values -------------------------------------------

@needs_photos
@pytest.mark.parametrize("name, cover", [("corn_tillage.jpg", 0.1594), ("grassland.jpg", 0.5593)])
def test_canopeo_cover_matches_reference(name: str, cover: float, masks: Path) -> None:
    r = photo_gap(PHOTOS / "canopeo" / name, "canopeo", mask_dir=masks)
    assert r.cover == pytest.approx(cover, abs=TOL)
    assert r.p0 == pytest.approx(1 - cover, abs=TOL)
    assert r.n_pixels == 512 * 512 and r.crop == (0, 0, 512, 512)
    assert r.threshold is None and dict(r.params) == {"rg": 0.95, "bg": 0.95, "exg": 20.0}
    assert r.mask_file == masks / f"{Path(name).stem}_canopeo_mask.png" and r.mask_file.is_file()


@needs_photos
@pytest.mark.parametrize("name, published", [("corn_tillage.jpg", 0.1596),
                                             ("grassland.jpg", 0.5664)])
def test_canopeo_ratio_tests_only_reproduce_notebook(name: str, published: float,
                                                     masks: Path) -> None:
    # The author's notebook dropped the 2G-R-B test (np.logical_and's third argument
    # is the output array); switching that test off must give its published numbers.
    r = photo_gap(PHOTOS / "canopeo" / name, "canopeo", canopeo_exg=-np.inf, mask_dir=masks)
    assert r.cover == pytest.approx(published, abs=TOL)


def test_blue_otsu_img1_matches_cover2(masks: Path) -> None:
    r = photo_gap(EXAMPLE_PHOTOS / "coveR2" / "IMG1.JPG", "blue-otsu", mask_dir=masks)
    assert r.threshold == 104
    assert r.p0 == pytest.approx(0.435, abs=TOL)
    assert r.cover == pytest.approx(0.565, abs=TOL)  # coveR2 README: FC 0.565
    assert r.image_size == (1072, 712)


@needs_photos
def test_blue_otsu_img3_matches_cover2_readme(masks: Path) -> None:
    # coveR2 README batch example: IMG3.JPG FC 0.711
    r = photo_gap(PHOTOS / "coveR2" / "IMG3.JPG", "blue-otsu", mask_dir=masks)
    assert r.cover == pytest.approx(0.711, abs=TOL)


@needs_photos
@pytest.mark.parametrize("name", ["IMG1.JPG", "IMG3.JPG"])
def test_blue_otsu_equals_imagej_otsu_oracle(name: str) -> None:
    rgb = read_rgb(PHOTOS / "coveR2" / name)
    _, t = classify_rgb(rgb, "blue-otsu")
    assert t == _imagej_otsu(rgb[..., 2])


@needs_photos
def test_exg_otsu_fails_on_near_full_cover(masks: Path) -> None:
    # documented limitation: alfalfa is near-full cover, the ExG histogram is
    # unimodal and Otsu splits the vegetation itself
    f = PHOTOS / "canopeo" / "alfalfa.jpg"
    canopeo = photo_gap(f, "canopeo", mask_dir=masks).cover
    exg = photo_gap(f, "exg-otsu", mask_dir=masks).cover
    assert canopeo > 0.9
    assert exg < canopeo - 0.3


@needs_photos
def test_exg_otsu_close_to_canopeo_on_bimodal_photo(masks: Path) -> None:
    f = PHOTOS / "canopeo" / "corn_tillage.jpg"
    r = photo_gap(f, "exg-otsu", mask_dir=masks)
    assert r.threshold is not None and 0.0 < r.threshold < 1.0
    assert r.cover == pytest.approx(photo_gap(f, "canopeo", mask_dir=masks).cover, abs=0.03)


@needs_photos
def test_cli_json_on_real_photo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["photo-gap", str(PHOTOS / "coveR2" / "IMG1.JPG"),
               str(PHOTOS / "canopeo" / "grassland.jpg"), "--method", "blue-otsu", "--json",
               "--mask-dir", str(tmp_path / "m")])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert [Path(d["file"]).name for d in out] == ["IMG1.JPG", "grassland.jpg"]
    d = out[0]
    assert {"file", "method", "threshold", "cover", "p0"} <= set(d)
    assert d["method"] == "blue-otsu" and d["threshold"] == 104
    assert d["p0"] == pytest.approx(0.435, abs=TOL)
    assert d["cover"] + d["p0"] == pytest.approx(1.0)
    assert Path(d["mask_file"]).is_file()
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == [
        "IMG1_blue-otsu_mask.png", "grassland_blue-otsu_mask.png"]


@needs_photos
def test_cli_table_and_crop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["photo-gap", str(PHOTOS / "canopeo" / "corn_tillage.jpg"), "--method", "canopeo",
               "--crop", "0.5", "--mask-dir", str(tmp_path)])
    assert rc == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:5] == ["file", "method", "threshold", "cover", "p0"]
    assert "corn_tillage.jpg" in lines[1] and " 65536 " in lines[1]  # 256 x 256 pixels


@needs_photos
def test_photo_folder_is_never_written(masks: Path, monkeypatch: pytest.MonkeyPatch,
                                       tmp_path: Path) -> None:
    before = sorted(os.listdir(PHOTOS / "canopeo"))
    monkeypatch.chdir(tmp_path)
    r = photo_gap(PHOTOS / "canopeo" / "grassland.jpg", "canopeo")  # default mask dir
    assert r.mask_file == Path("photo_masks") / "grassland_canopeo_mask.png"
    assert (tmp_path / r.mask_file).is_file()
    assert sorted(os.listdir(PHOTOS / "canopeo")) == before


# --- classification rules on hand-made pixels --------------------------------------

def test_canopeo_rule_boundaries_and_g_zero() -> None:
    px = np.array([[
        [50, 100, 50],    # clearly green
        [95, 100, 50],    # R/G = 0.95 exactly: not < 0.95
        [50, 100, 95],    # B/G = 0.95 exactly
        [90, 100, 90],    # ratios pass, 2G-R-B = 20 exactly: not > 20 (the logical_and trap)
        [89, 100, 90],    # 2G-R-B = 21
        [0, 0, 0],        # G = 0, black
        [10, 0, 10],      # G = 0, ratios undefined
        [255, 255, 255],  # white
    ]], dtype=np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division warnings for G = 0
        mask, t = classify_rgb(px, "canopeo")
    assert t is None
    assert mask[0].tolist() == [True, False, False, False, True, False, False, False]


def test_canopeo_thresholds_are_options() -> None:
    px = np.array([[[97, 100, 50]]], dtype=np.uint8)  # R/G = 0.97
    assert not classify_rgb(px, "canopeo")[0][0, 0]
    assert classify_rgb(px, "canopeo", canopeo_rg=0.98)[0][0, 0]
    assert not classify_rgb(px, "canopeo", canopeo_rg=0.98, canopeo_exg=60)[0][0, 0]


def test_exg_otsu_separates_green_from_soil_and_handles_black() -> None:
    rng = np.random.default_rng(3)
    img = np.empty((40, 50, 3), dtype=np.uint8)
    img[:] = (120, 100, 80) + rng.integers(-8, 9, size=(40, 50, 3))  # soil
    img[:, :20] = (60, 140, 50) + rng.integers(-8, 9, size=(40, 20, 3))  # plants
    img[0, 0] = img[39, 49] = (0, 0, 0)  # black pixels: ExG defined as 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mask, t = classify_rgb(img, "exg-otsu")
    assert t is not None
    assert mask[1:, :20].all() and not mask[:, 20:].any()
    assert not mask[0, 0]


def test_blue_otsu_gap_is_above_threshold() -> None:
    blue = np.array([[10, 20, 30, 200, 210, 220]], dtype=np.uint8)
    img = np.zeros((1, 6, 3), dtype=np.uint8)
    img[..., 2] = blue
    mask, t = classify_rgb(img, "blue-otsu")
    assert t == _imagej_otsu(blue) == 30  # last level of the dark class
    assert mask[0].tolist() == [True, True, True, False, False, False]  # vegetation = not gap


@pytest.mark.parametrize("seed", range(5))
def test_blue_otsu_matches_imagej_oracle_on_random_images(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 3000
    blue = np.concatenate([rng.normal(60 + 10 * seed, 15, n), rng.normal(180, 25, n // (seed + 1))])
    img = np.zeros((1, blue.size, 3), dtype=np.uint8)
    img[..., 2] = np.clip(np.rint(blue), 0, 255)
    assert classify_rgb(img, "blue-otsu")[1] == _imagej_otsu(img[..., 2])


@pytest.mark.parametrize("method", ["exg-otsu", "blue-otsu"])
def test_otsu_on_uniform_crop_is_an_error(tmp_path: Path, method: str) -> None:
    f = _save_rgb(tmp_path / "flat.png", np.full((40, 40, 3), 90))
    with pytest.raises(PhotoError, match=r"flat\.png.*uniform"):
        photo_gap(f, method, mask_dir=tmp_path)


def test_unknown_method(tmp_path: Path) -> None:
    f = _save_rgb(tmp_path / "a.png", np.zeros((4, 4, 3)))
    with pytest.raises(PhotoError, match=r"a\.png.*unknown method 'ndvi'.*canopeo"):
        photo_gap(f, "ndvi", mask_dir=tmp_path)  # type: ignore[arg-type]


# --- crops ----------------------------------------------------------------------------

def test_crop_fraction_and_box() -> None:
    assert crop_box(None, 100, 80) == (0, 0, 100, 80)
    assert crop_box(0.5, 100, 80) == (25, 20, 75, 60)
    assert crop_box("0.5", 100, 80) == (25, 20, 75, 60)
    assert crop_box(1.0, 100, 80) == (0, 0, 100, 80)
    assert crop_box("10, 5, 30, 25", 100, 80) == (10, 5, 30, 25)
    assert crop_box((0, 0, 100, 80), 100, 80) == (0, 0, 100, 80)
    assert crop_box(0.001, 100, 80) == (49, 39, 50, 40)  # at least one pixel
    assert parse_crop("0.25") == 0.25


@pytest.mark.parametrize("crop", [(0, 0, 101, 80), (-1, 0, 10, 10), (10, 10, 10, 20),
                                  (30, 10, 20, 20), "0,0,100,81", 0.0, 1.5, -0.5, "half",
                                  "1,2,3", "1.5,2,3,4", (1, 2, 3), (0.0, 0.0, 1.0, 1.0), True])
def test_bad_crop_names_file_and_crop(tmp_path: Path, crop) -> None:
    f = _save_rgb(tmp_path / "p.png", np.zeros((80, 100, 3)))
    with pytest.raises(PhotoError, match=r"p\.png.*crop") as exc:
        photo_gap(f, "canopeo", crop, mask_dir=tmp_path)
    if isinstance(crop, tuple) and len(crop) == 4 and isinstance(crop[0], int):
        assert ",".join(str(v) for v in crop) in str(exc.value)
        assert "100x80" in str(exc.value)


def test_cover_counts_only_the_crop(tmp_path: Path) -> None:
    img = np.full((64, 128, 3), (120, 100, 80), dtype=np.uint8)  # soil
    img[:, :32] = (40, 150, 40)  # a green strip on the left quarter
    f = _save_rgb(tmp_path / "strip.png", img)
    assert photo_gap(f, "canopeo", mask_dir=tmp_path).cover == pytest.approx(0.25)
    r = photo_gap(f, "canopeo", "0,0,64,64", mask_dir=tmp_path)
    assert (r.cover, r.n_pixels, r.n_vegetation) == (0.5, 4096, 2048)
    r = photo_gap(f, "canopeo", 0.5, mask_dir=tmp_path)  # columns 32..96: no green
    assert r.crop == (32, 16, 96, 48) and r.cover == 0.0 and r.p0 == 1.0


# --- unreadable and non-RGB files ---------------------------------------------------

def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(PhotoError, match=r"nope\.jpg: no such file"):
        photo_gap(tmp_path / "nope.jpg", "canopeo", mask_dir=tmp_path)


def test_directory_is_not_a_photo(tmp_path: Path) -> None:
    with pytest.raises(PhotoError, match="directory"):
        read_rgb(tmp_path)


def test_truncated_jpeg(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    full = _save_rgb(tmp_path / "full.jpg", rng.integers(0, 256, (128, 128, 3)), quality=95)
    data = full.read_bytes()
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(PhotoError, match=r"cut\.jpg.*truncated"):
        photo_gap(cut, "canopeo", mask_dir=tmp_path / "m")
    assert not (tmp_path / "m").exists()  # no mask for a photo we could not read


def test_text_file_named_jpg(tmp_path: Path) -> None:
    f = tmp_path / "notes.jpg"
    f.write_text("not a photo\n")
    with pytest.raises(PhotoError, match=r"notes\.jpg: not an image"):
        photo_gap(f, "canopeo", mask_dir=tmp_path)


def test_empty_file(tmp_path: Path) -> None:
    f = tmp_path / "empty.jpg"
    f.write_bytes(b"")
    with pytest.raises(PhotoError, match=r"empty\.jpg"):
        read_rgb(f)


@pytest.mark.parametrize("mode", ["L", "LA", "I;16", "1", "F"])
def test_greyscale_is_refused(tmp_path: Path, mode: str) -> None:
    f = tmp_path / f"grey_{mode.replace(';', '')}.{'tif' if mode == 'F' else 'png'}"
    Image.new(mode, (8, 8)).save(f)
    with pytest.raises(PhotoError, match=rf"{f.name}: greyscale image \(mode {mode}"):
        photo_gap(f, "canopeo", mask_dir=tmp_path)


def test_16bit_rgb_is_refused(tmp_path: Path) -> None:
    f = _png16_rgb(tmp_path / "deep.png", np.full((4, 5, 3), 40000, dtype=np.uint16))
    with pytest.raises(PhotoError, match=r"deep\.png: more than 8 bits per channel"):
        read_rgb(f)


def test_cmyk_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "print.jpg"
    Image.new("CMYK", (8, 8)).save(f)
    with pytest.raises(PhotoError, match=r"print\.jpg: CMYK"):
        read_rgb(f)


def test_rgba_alpha_is_a_mask_and_palette_is_expanded(tmp_path: Path) -> None:
    rgba = np.zeros((40, 40, 4), dtype=np.uint8)
    rgba[..., :3] = (40, 150, 40)   # green everywhere ...
    rgba[:, :20, :3] = (120, 100, 80)  # ... but soil on the left half
    rgba[..., 3] = 255
    rgba[:10, :20, 3] = 0           # a transparent quarter of the soil: not analysed
    rgba[10:20, :20, 3] = 1         # barely opaque still counts
    f = tmp_path / "a.png"
    Image.fromarray(rgba).save(f)
    assert read_rgb(f).shape == (40, 40, 3)
    r = photo_gap(f, "canopeo", mask_dir=tmp_path)
    assert (r.n_pixels, r.n_transparent, r.n_vegetation) == (1400, 200, 800)
    assert r.cover == pytest.approx(800 / 1400)
    mask = np.asarray(Image.open(r.mask_file).convert("RGB"))
    assert mask[5, 5].tolist() == [0, 0, 0]  # transparent pixels are black in the mask
    rgba[..., 3] = 0  # nothing opaque left: refused, not P0 = 1
    Image.fromarray(rgba).save(f)
    for method in METHODS:
        with pytest.raises(PhotoError, match=r"a\.png: 0 pixels to analyse once the 1600 transparent"):
            photo_gap(f, method, mask_dir=tmp_path)
    g = tmp_path / "p.png"
    Image.fromarray(rgba[..., :3]).convert("P", palette=Image.Palette.ADAPTIVE).save(g)
    assert read_rgb(g)[0, 0].tolist() == [120, 100, 80]
    assert read_rgb(g)[0, 39].tolist() == [40, 150, 40]


def test_exif_orientation_is_applied(tmp_path: Path) -> None:
    img = np.zeros((2, 4, 3), dtype=np.uint8)
    img[0, 0] = (255, 0, 0)
    exif = Image.Exif()
    exif[0x0112] = 6  # stored landscape, shown rotated 90 degrees clockwise
    f = tmp_path / "rot.jpg"
    Image.fromarray(img).save(f, exif=exif, quality=100)
    assert read_rgb(f).shape == (4, 2, 3)


# --- masks ------------------------------------------------------------------------------

def test_mask_png_colours_window_and_dimming(tmp_path: Path) -> None:
    m = np.zeros((400, 600), dtype=bool)
    m[:, :300] = True
    out = write_mask_png(tmp_path / "sub" / "m.png", m, (100, 100, 500, 300))
    assert out == tmp_path / "sub" / "m.png"
    assert os.listdir(out.parent) == ["m.png"]  # no temporary file left behind
    with Image.open(out) as im:  # a palette PNG (one byte a pixel); viewers show the colours
        assert im.format == "PNG" and im.mode == "P"
        a = np.asarray(im.convert("RGB"))
    assert a.shape == (400, 600, 3)
    assert a[200, 200].tolist() == list(FOREGROUND_RGB)  # inside window, vegetation
    assert a[200, 400].tolist() == list(BACKGROUND_RGB)  # inside window, background
    assert a[100, 200].tolist() == list(WINDOW_RGB)      # outline, top edge
    assert a[200, 499].tolist() == list(WINDOW_RGB)      # outline, right edge (x1 - 1)
    # outside the window: halfway to grey, still two distinguishable colours
    assert a[50, 50].tolist() == [64, 128, 64]
    assert a[50, 550].tolist() == [192, 192, 192]


def test_mask_png_without_window_is_two_colours(tmp_path: Path) -> None:
    m = np.eye(5, dtype=bool)
    a = np.asarray(Image.open(write_mask_png(tmp_path / "e.png", m)).convert("RGB"))
    assert {tuple(c) for c in a.reshape(-1, 3)} == {FOREGROUND_RGB, BACKGROUND_RGB}


def test_mask_png_overwrites_atomically(tmp_path: Path) -> None:
    p = tmp_path / "m.png"
    write_mask_png(p, np.ones((3, 3), bool))
    write_mask_png(p, np.zeros((3, 3), bool))
    assert np.asarray(Image.open(p).convert("RGB"))[1, 1].tolist() == list(BACKGROUND_RGB)
    assert os.listdir(tmp_path) == ["m.png"]


@pytest.mark.parametrize("window", [(0, 0, 7, 3), (2, 2, 2, 3), (-1, 0, 2, 2), (0, 0, 1)])
def test_mask_png_bad_window(tmp_path: Path, window) -> None:
    with pytest.raises(ValueError, match="window"):
        write_mask_png(tmp_path / "m.png", np.ones((3, 6), bool), window)
    assert not (tmp_path / "m.png").exists()


def test_mask_png_bad_mask(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="2-D"):
        render_mask_rgb(np.ones((2, 2, 2), bool))


def test_mask_png_unwritable_destination(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SimlidarError, match="cannot write PNG"):
        write_mask_png(blocker / "m.png", np.ones((2, 2), bool))


def test_photo_gap_mask_path_and_unwritable_mask(tmp_path: Path) -> None:
    img = np.full((40, 40, 3), (40, 150, 40), dtype=np.uint8)
    f = _save_rgb(tmp_path / "leaf.png", img)
    r = photo_gap(f, "canopeo", mask_path=tmp_path / "out" / "leaf_mask.png")
    assert r.mask_file == tmp_path / "out" / "leaf_mask.png" and r.mask_file.is_file()
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    with pytest.raises(PhotoError, match=r"leaf\.png: cannot save the classification mask"):
        photo_gap(f, "canopeo", mask_dir=blocker)


def test_mask_matches_counts(tmp_path: Path) -> None:
    img = np.full((40, 80, 3), (120, 100, 80), dtype=np.uint8)
    img[10:30, 10:50] = (40, 150, 40)
    f = _save_rgb(tmp_path / "patch.png", img)
    r = photo_gap(f, "canopeo", (0, 0, 60, 40), mask_dir=tmp_path / "m")
    a = np.asarray(Image.open(r.mask_file).convert("RGB"))
    assert r.n_vegetation == 800
    assert (a == FOREGROUND_RGB).all(axis=2).sum() == r.n_vegetation


# --- result object and CLI errors ---------------------------------------------------

def test_result_is_frozen_and_json_ready(tmp_path: Path) -> None:
    f = _save_rgb(tmp_path / "x.png", np.full((32, 32, 3), (40, 150, 40)))
    r = photo_gap(f, "canopeo", mask_dir=tmp_path)
    assert isinstance(r, PhotoGapResult)
    with pytest.raises(AttributeError):
        r.cover = 0.0  # type: ignore[misc]
    d = json.loads(json.dumps(r.to_dict()))
    assert d["file"] == str(f) and d["crop"] == [0, 0, 32, 32] and d["cover"] == 1.0


def test_cli_reports_bad_files_and_continues(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    good = _save_rgb(tmp_path / "good.png", np.full((32, 32, 3), (40, 150, 40)))
    bad = tmp_path / "bad.jpg"
    bad.write_text("text")
    rc = main(["photo-gap", str(bad), str(good), "--method", "canopeo", "--json",
               "--mask-dir", str(tmp_path / "m")])
    cap = capsys.readouterr()
    assert rc == 2
    assert "bad.jpg: not an image" in cap.err
    assert [d["file"] for d in json.loads(cap.out)] == [str(good)]


def test_cli_writes_masks_only_under_out(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """photo-gap wrote ./photo_masks into whatever folder it ran in: now nothing is written
    without --out, and the masks go under --out when given (the photo's folder never)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    good = _save_rgb(photos / "g.png", np.full((32, 32, 3), (40, 150, 40)))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["photo-gap", str(good), "--method", "canopeo", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["mask_file"] is None
    assert os.listdir(work) == [] and os.listdir(photos) == ["g.png"]
    assert main(["photo-gap", str(good), "--method", "canopeo", "--out", "res"]) == 0
    assert os.listdir(work) == ["res"] and os.listdir(work / "res") == ["g_canopeo_mask.png"]
    assert capsys.readouterr().out.splitlines()[1].endswith(str(Path("res") / "g_canopeo_mask.png"))
    assert os.listdir(photos) == ["g.png"]


# --- large photos: strips, orientation, downscale, size limits ----------------------

def _field(h: int, w: int, seed: int = 5) -> np.ndarray:
    """Green blobs on soil with pixel noise: both classes, many distinct levels."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    green = (np.sin(xx / 7.0) + np.cos(yy / 5.0) + rng.normal(0, 0.3, (h, w))) > 0.4
    img = np.where(green[..., None], (60, 140, 45), (120, 95, 70)).astype(np.int16)
    return np.clip(img + rng.integers(-25, 26, (h, w, 3)), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("method", ["canopeo", "exg-otsu", "blue-otsu"])
@pytest.mark.parametrize("crop", [None, (13, 7, 140, 101)])
def test_strips_give_the_whole_array_result(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            method: str, crop) -> None:
    import simlidar_mi.canopy.photo as photo
    f = _save_rgb(tmp_path / "field.png", _field(120, 150))
    rgb = read_rgb(f)
    box = crop_box(crop, 150, 120)
    mask, t = classify_rgb(rgb, method, box)
    x0, y0, x1, y1 = box
    seen = []
    real = photo._exg if method == "exg-otsu" else photo._canopeo
    monkeypatch.setattr(photo, "_exg" if method == "exg-otsu" else "_canopeo",
                        lambda a, *k: seen.append(a.shape[0] * a.shape[1]) or real(a, *k))
    monkeypatch.setattr(photo, "TILE_PIXELS", 7 * 150 + 3)  # strips of 7 rows
    r = photo_gap(f, method, crop, mask_dir=tmp_path)
    assert r.threshold == t  # the strip-accumulated histogram gives Otsu's exact threshold
    assert r.n_vegetation == int(mask[y0:y1, x0:x1].sum()) and r.n_pixels == (x1 - x0) * (y1 - y0)
    if method != "blue-otsu":  # never the whole photo at once
        assert seen and max(seen) <= 7 * 150
    labels = np.asarray(Image.open(r.mask_file).convert("RGB"))
    inner = labels[y0 + 1:y1 - 1, x0 + 1:x1 - 1]  # inside the outline
    assert ((inner == FOREGROUND_RGB).all(axis=2) == mask[y0 + 1:y1 - 1, x0 + 1:x1 - 1]).all()


@needs_photos
@pytest.mark.parametrize("name, method", [("coveR2/IMG1.JPG", "blue-otsu"),
                                          ("canopeo/corn_tillage.jpg", "exg-otsu"),
                                          ("canopeo/grassland.jpg", "canopeo")])
def test_strips_on_real_photos(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str,
                               method: str) -> None:
    import simlidar_mi.canopy.photo as photo
    whole = photo_gap(PHOTOS / name, method, 0.8, mask_dir=tmp_path / "a")
    monkeypatch.setattr(photo, "TILE_PIXELS", 5000)
    strips = photo_gap(PHOTOS / name, method, 0.8, mask_dir=tmp_path / "b")
    assert (strips.threshold, strips.n_vegetation) == (whole.threshold, whole.n_vegetation)
    rgb = read_rgb(PHOTOS / name)
    mask, t = classify_rgb(rgb, method, whole.crop)
    x0, y0, x1, y1 = whole.crop
    assert (t, int(mask[y0:y1, x0:x1].sum())) == (whole.threshold, whole.n_vegetation)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_every_exif_orientation_matches_pillow(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               orientation: int) -> None:
    from PIL import ImageOps
    import simlidar_mi.canopy.photo as photo
    img = _field(37, 53, seed=orientation)
    exif = Image.Exif()
    exif[0x0112] = orientation
    f = tmp_path / f"o{orientation}.png"
    Image.fromarray(img).save(f, exif=exif)
    with Image.open(f) as im:
        want = np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
    np.testing.assert_array_equal(read_rgb(f), want)
    monkeypatch.setattr(photo, "TILE_PIXELS", 1)  # one upright row per strip
    mask, _ = classify_rgb(want, "canopeo")
    r = photo_gap(f, "canopeo", mask_dir=tmp_path)
    assert r.image_size == (want.shape[1], want.shape[0]) and r.n_vegetation == int(mask.sum())


def test_too_small_photos_and_crops_are_refused(tmp_path: Path) -> None:
    f = _save_rgb(tmp_path / "thumb.png", _field(31, 33))  # 1023 pixels
    with pytest.raises(PhotoError, match=r"thumb\.png: 33x31 pixels to analyse.*at least 1024"):
        photo_gap(f, "canopeo", mask_dir=tmp_path)
    g = _save_rgb(tmp_path / "ok.png", _field(32, 32))
    assert photo_gap(g, "exg-otsu", mask_dir=tmp_path).n_pixels == 1024
    with pytest.raises(PhotoError, match=r"ok\.png: 16x16 pixels to analyse"):
        photo_gap(g, "canopeo", 0.5, mask_dir=tmp_path)


def test_downscale_decodes_jpeg_smaller_and_scales_pixel_boxes(tmp_path: Path) -> None:
    img = np.full((160, 240, 3), (120, 95, 70), dtype=np.uint8)
    img[:, :80] = (60, 140, 45)  # green third, on 8-pixel block edges
    f = _save_rgb(tmp_path / "big.jpg", img, quality=95)
    full = photo_gap(f, "canopeo", mask_dir=tmp_path / "1")
    for ds in (2, 4):
        r = photo_gap(f, "canopeo", (0, 0, 240, 160), mask_dir=tmp_path / str(ds), downscale=ds)
        assert r.downscale == ds and r.image_size == (240 // ds, 160 // ds)
        assert r.crop == (0, 0, 240 // ds, 160 // ds)
        assert r.cover == pytest.approx(full.cover, abs=0.01)
    png = _save_rgb(tmp_path / "big.png", img)  # not a JPEG: decoded, then block-averaged
    r = photo_gap(png, "canopeo", (1, 1, 239, 159), mask_dir=tmp_path, downscale=4)
    assert r.image_size == (60, 40) and r.crop == (0, 0, 60, 40)
    assert r.cover == pytest.approx(1 / 3)
    with pytest.raises(PhotoError, match=r"big\.png: downscale 3 must be one of 1, 2, 4, 8"):
        photo_gap(png, "canopeo", mask_dir=tmp_path, downscale=3)
    with pytest.raises(PhotoError, match=r"pixels to analyse at downscale 8"):
        photo_gap(png, "canopeo", mask_dir=tmp_path, downscale=8)  # 30 x 20


def test_progress_bar_on_request(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    import simlidar_mi.canopy.photo as photo
    monkeypatch.setattr(photo, "PROGRESS_DELAY_S", 0.0)
    f = _save_rgb(tmp_path / "p.png", _field(40, 40))
    photo_gap(f, "canopeo", mask_dir=tmp_path)
    assert capsys.readouterr().err == ""
    photo_gap(f, "canopeo", mask_dir=tmp_path, progress=True)
    assert "p.png" in capsys.readouterr().err


def test_cli_downscale_in_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _save_rgb(tmp_path / "f.jpg", _field(128, 128), quality=95)
    assert main(["photo-gap", str(f), "--method", "canopeo", "--downscale", "2", "--json",
                 "--mask-dir", str(tmp_path / "m")]) == 0
    (d,) = json.loads(capsys.readouterr().out)
    assert (d["downscale"], d["n_pixels"], d["n_transparent"]) == (2, 64 * 64, 0)
