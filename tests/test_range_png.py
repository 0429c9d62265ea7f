"""scan.png without matplotlib: lookup-table colours, the block rule for big scans, and
mask PNGs that read back as the mask written."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from PIL import Image

from simlidar_mi.errors import SimlidarError
from simlidar_mi.io.plots import (ESCAPE_RGB, GROUND_RGB, MIN_DATA_H, MIN_DATA_W, VIRIDIS_LUT,
                                  lut_index, plot_scan_png, range_limits, range_rgb)
from simlidar_mi.io.png import mask_labels, read_mask_png, render_mask_rgb, write_mask_png
from simlidar_mi.lidar.platforms import BeamPattern, elevation_dirs
from simlidar_mi.lidar.scan import ScanResult
from tests.conftest import REPO, SCENES

ESC, GND, WOOD, LEAF = 0, 1, 2, 3


def fake_result(rng_m: np.ndarray, cls: np.ndarray, dy_m: float = 0.01) -> ScanResult:
    """A tractor-like scan with the given (N, M) ranges and classes, θ from −30° up in 1° steps."""
    n, m = rng_m.shape
    y = dy_m * np.arange(n)
    theta = -30.0 + np.arange(m, dtype=np.float64)
    pat = BeamPattern("tractor", np.stack([np.zeros(n), y, np.zeros(n)], axis=1), np.zeros(n), theta,
                      elevation_dirs(theta), np.array([0.0, dy_m, 0.0]), 1.0, 0, y,
                      "scanner position y (m)", "beam elevation θ (°)")
    return ScanResult(None, np.asarray(rng_m, np.float32), np.asarray(cls, np.uint8), None, None,
                      np.zeros(3), pattern=pat)


def test_lut_is_matplotlibs_viridis():
    # the stored table (bench/make_viridis_lut.py) is what matplotlib's imshow wrote before
    from matplotlib import colormaps
    mpl = np.asarray(colormaps["viridis"](np.arange(256), bytes=True))[:, :3]
    assert VIRIDIS_LUT.shape == (256, 3) and VIRIDIS_LUT.dtype == np.uint8
    assert np.array_equal(VIRIDIS_LUT, mpl)
    # matplotlib's Normalize + Colormap pick the same entries on a scale of 2..5 m
    from matplotlib.colors import Normalize
    r = np.array([2.0, 2.0117, 3.0, 3.5, 4.9999, 5.0])
    expect = np.asarray(colormaps["viridis"](Normalize(2.0, 5.0)(r), bytes=True))[:, :3]
    assert np.array_equal(VIRIDIS_LUT[lut_index(r, 2.0, 5.0)], expect)


def test_lut_index_closed_form():
    assert lut_index(np.array([2.0, 5.0]), 2.0, 5.0).tolist() == [0, 255]
    # entry k covers t in [k/256, (k+1)/256): the midpoint of entry 100, and either side of its edge
    t = np.array([100.5, 100.0, 99.999]) / 256
    assert lut_index(2.0 + 3.0 * t, 2.0, 5.0).tolist() == [100, 100, 99]
    assert lut_index(np.array([7.0, 7.0]), 7.0, 7.0).tolist() == [0, 0]  # one range: entry 0


def _scan_with_known_ranges():
    n, m = 40, 20
    rng = np.full((n, m), 1000.0)
    cls = np.zeros((n, m), np.uint8)
    cls[:, :5] = GND                    # the lowest five angles meet the ground
    rng[:, :5] = 3.0
    cls[10, 8], rng[10, 8] = WOOD, 2.0   # nearest vegetation: entry 0
    cls[30, 15], rng[30, 15] = LEAF, 5.0  # farthest: entry 255
    mid = 2.0 + 3.0 * 100.5 / 256
    cls[20, 12], rng[20, 12] = WOOD, mid  # entry 100
    return fake_result(rng, cls)


def test_range_rgb_colours_are_the_lut_of_known_ranges():
    res = _scan_with_known_ranges()
    assert range_limits(res.range_m, res.cls) == (2.0, 5.0)
    img, blocks = range_rgb(res.range_m, res.cls)
    assert blocks == (1, 1) and img.shape == (20, 40, 3)
    px = lambda i, k: img[19 - k, i].tolist()  # noqa: E731  (beam (row i, angle k); angle up)
    assert px(10, 8) == VIRIDIS_LUT[0].tolist()
    assert px(30, 15) == VIRIDIS_LUT[255].tolist()
    assert px(20, 12) == VIRIDIS_LUT[100].tolist()
    assert px(0, 0) == list(GROUND_RGB) and px(39, 4) == list(GROUND_RGB)
    assert px(0, 19) == list(ESCAPE_RGB) and px(5, 8) == list(ESCAPE_RGB)
    # nothing else is coloured: 3 vegetation pixels, 5 rows of ground
    assert (np.all(img == ESCAPE_RGB, axis=2)).sum() == 40 * 15 - 3
    assert (np.all(img == GROUND_RGB, axis=2)).sum() == 40 * 5


def _find(big: np.ndarray, small: np.ndarray) -> list[tuple[int, int]]:
    h, w = small.shape[:2]
    ys, xs = np.nonzero(np.all(big[: big.shape[0] - h + 1, : big.shape[1] - w + 1] == small[0, 0], axis=2))
    return [(y, x) for y, x in zip(ys, xs) if np.array_equal(big[y:y + h, x:x + w], small)]


def test_png_holds_the_data_pixels_framed_with_a_colour_bar(tmp_path):
    res = _scan_with_known_ranges()
    out = plot_scan_png(res, tmp_path / "scan.png", title="known ranges")
    with Image.open(out) as im:
        assert im.mode == "RGB"
        png = np.asarray(im)
    data, _ = range_rgb(res.range_m, res.cls)
    # small scans are enlarged by whole-pixel repetition: every beam keeps its exact colour
    sx, sy = -(-MIN_DATA_W // 40), -(-MIN_DATA_H // 20)
    big = np.repeat(np.repeat(data, sy, axis=0), sx, axis=1)
    found = _find(png, big)
    assert len(found) == 1
    y, x = found[0]
    h, w = big.shape[:2]
    # a black frame just outside the data area, and the colour bar to its right runs from
    # entry 255 (top) to entry 0 (bottom)
    assert (png[y - 1, x - 1:x + w + 1] == 0).all() and (png[y + h, x - 1:x + w + 1] == 0).all()
    right = png[y:y + h, x + w + 1:]
    cols = [j for j in range(right.shape[1]) if (right[0, j] == VIRIDIS_LUT[255]).all()
            and (right[-1, j] == VIRIDIS_LUT[0]).all()]
    assert len(cols) >= 10  # the bar, bar_w pixels wide
    bar = right[:, cols[0]]
    assert {tuple(c) for c in bar} <= {tuple(c) for c in VIRIDIS_LUT}
    # bar colours never go back down the table from top to bottom
    idx = [int(np.flatnonzero((VIRIDIS_LUT == c).all(axis=1))[0]) for c in bar]
    assert idx == sorted(idx, reverse=True) and idx[0] == 255 and idx[-1] == 0
    # the same scan gives the same bytes
    again = plot_scan_png(res, tmp_path / "again.png", title="known ranges")
    assert again.read_bytes() == out.read_bytes()


def test_block_rule_keeps_a_one_beam_line_and_the_nearest_return():
    n, m = 1000, 300
    rng = np.full((n, m), 1000.0)
    cls = np.zeros((n, m), np.uint8)
    cls[:, :31] = GND  # angle block 10 (beams 30..32) holds one ground beam
    rng[:, :31] = 5.0
    cls[537, 100:200], rng[537, 100:200] = WOOD, 3.0      # one beam wide across rows
    cls[100:900, 250], rng[100:900, 250] = LEAF, 9.0       # one beam wide across angles
    cls[40:50, 60:63], rng[40:50, 60:63] = LEAF, 9.0       # far leaves in one block ...
    cls[41, 61], rng[41, 61] = WOOD, 2.0                   # ... and one near beam among them
    img, (fr, fc) = range_rgb(rng, cls, max_px=100)
    assert (fr, fc) == (10, 3) and img.shape == (100, 100, 3)
    lo, hi = 2.0, 9.0
    px = lambda i, k: img[99 - k, i].tolist()  # noqa: E731  (block (i, k))
    c3, c9, c2 = (VIRIDIS_LUT[lut_index(np.array([r]), lo, hi)[0]].tolist() for r in (3.0, 9.0, 2.0))
    # the single row of beams 537 fills block column 53 over its angles 100..199
    assert all(px(53, k) == c3 for k in range(100 // 3, 200 // 3))
    assert px(52, 40) == list(ESCAPE_RGB) and px(54, 40) == list(ESCAPE_RGB)
    # the single column of beams 250 fills block row 83 over rows 100..899
    assert all(px(i, 250 // 3) == c9 for i in range(10, 90))
    # nearest vegetation of a block wins over far vegetation
    assert px(4, 20) == c2 and c2 != c9
    # a block without vegetation: ground if any of its beams met the ground
    assert px(0, 10) == list(GROUND_RGB) and px(0, 11) == list(ESCAPE_RGB)


def test_default_size_rule_bounds_the_image():
    n, m = 9000, 20
    rng = np.full((n, m), 1000.0, np.float32)
    cls = np.zeros((n, m), np.uint8)
    cls[4321, 7], rng[4321, 7] = WOOD, 4.0
    img, (fr, fc) = range_rgb(rng, cls)  # default: at most 4096 px on a side
    assert (fr, fc) == (3, 1) and img.shape == (20, 3000, 3)
    assert img[19 - 7, 4321 // 3].tolist() == VIRIDIS_LUT[0].tolist()


def test_png_of_a_scan_without_vegetation(tmp_path):
    rng = np.full((30, 10), 1000.0)
    cls = np.zeros((30, 10), np.uint8)
    cls[:, :4] = GND
    res = fake_result(rng, cls)
    assert range_limits(res.range_m, res.cls) is None
    img, _ = range_rgb(res.range_m, res.cls)
    assert {tuple(c) for c in img.reshape(-1, 3)} == {GROUND_RGB, ESCAPE_RGB}
    with Image.open(plot_scan_png(res, tmp_path / "s.png")) as im:
        assert im.size[0] > MIN_DATA_W


def test_scan_with_png_does_not_import_matplotlib(tmp_path):
    code = textwrap.dedent(f"""
        import sys
        import simlidar_mi.lidar.survey as survey
        assert "matplotlib" not in sys.modules, "import simlidar_mi.lidar.survey"
        run = survey.run_scan({str(SCENES / 'calibration_cylinder.toml')!r}, {str(tmp_path / 'o')!r},
                              write_las=False)
        assert "png" in run.files and run.files["png"].is_file()
        print(sorted(m for m in sys.modules if m.split(".")[0] == "matplotlib"))
        """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "[]"
    with Image.open(tmp_path / "o" / "scan.png") as im:
        assert im.mode == "RGB" and im.size[0] > MIN_DATA_W


# --- masks ------------------------------------------------------------------------------

@pytest.mark.parametrize("window", [None, (3, 2, 57, 38), (0, 0, 60, 40)])
def test_mask_png_reads_back_as_the_mask(tmp_path, window):
    m = np.random.default_rng(5).random((40, 60)) < 0.45
    m[2, 3:57] = True  # foreground under the window's top outline reads back too
    path = write_mask_png(tmp_path / "m.png", m, window)
    with Image.open(path) as im:
        assert im.mode == "P"
        rgb = np.asarray(im.convert("RGB"))
    assert np.array_equal(read_mask_png(path), m)
    assert np.array_equal(rgb, render_mask_rgb(m, window))


def test_mask_labels_closed_form():
    m = np.zeros((4, 6), bool)
    m[1, 2] = m[0, 0] = m[3, 4] = True
    lab = mask_labels(m, (1, 1, 5, 4))
    assert lab[0, 0] == 3 and lab[0, 1] == 2           # outside the window: dimmed
    assert lab[1, 2] == 6 and lab[1, 3] == 4           # outline over foreground / background
    assert lab[3, 4] == 6 and lab[2, 1] == 4           # the outline is one pixel inside the box
    assert lab[2, 2] == 0 and lab[2, 3] == 0           # inside it: plain labels


def test_read_mask_png_refuses_an_rgb_picture(tmp_path):
    p = tmp_path / "rgb.png"
    Image.fromarray(np.zeros((3, 3, 3), np.uint8)).save(p)
    with pytest.raises(SimlidarError, match="rgb.png"):
        read_mask_png(p)
