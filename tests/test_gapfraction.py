"""Gap-fraction cameras, windows and pipeline against exact references.

Exact checks (science notes, "Gap fraction physics"): for N flat leaves of area a
placed uniformly in a periodic plot of area A, E[P0(θ)] = (1 − a·G(θ)/(A·cos θ))^N.
A single plot scatters about that by an SD that does not shrink with the pixel count
(neighbouring pixels are correlated), so the mean over K seeds is tested against
4·SD/√K with the notes' SDs at 256², LAI 1 (N = 100: 0.019, N = 1000: 0.006; both
reproduced by the exact two-point integral, and measured over 40 seeds here: 0.018–0.025
and 0.0059–0.0073).  Seeds are fixed, so every test is deterministic.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi import ConfigError, Leaves
from simlidar_mi.cli import main
from simlidar_mi.config import SECTIONS, load_scene
from simlidar_mi.canopy.cameras import make_camera
from simlidar_mi.canopy.canopy import (Canopy, canopies_from_config, canopy_from_random_leaves,
                                       expected_p0, replicate_seed)
from simlidar_mi.canopy.gapfraction import (CSV_COLUMNS, REPLICATE_COLUMNS, build_canopy_scene,
                                            gap_images, read_gap_exr, render_gap, run_gapfraction)
from simlidar_mi.canopy.gapfraction_defaults import DEFAULTS
from simlidar_mi.canopy.windows import analysis_window
from simlidar_mi.io.png import read_mask_png, render_mask_rgb
from simlidar_mi.plants.random_leaves import random_leaves

REPO = Path(__file__).resolve().parents[1]
SD_256 = {100: 0.019, 1000: 0.006}


def _rl(n, law, seed, height=(0.0, 0.5), size=(1.0, 1.0), lai=1.0):
    return canopy_from_random_leaves(random_leaves(n, lai * size[0] * size[1] / n, size, height,
                                                   law, seed=seed))


def _mean_p0(n, law, zeniths, k, *, azimuth_deg=0.0, spp=4, resolution=256, seed0=0):
    vals = []
    for seed in range(seed0, seed0 + k):
        imgs = gap_images(_rl(n, law, seed), cameras=["orthographic"], zeniths_deg=zeniths,
                          azimuth_deg=azimuth_deg, resolution=resolution, spp=spp)
        vals.append([im.p0 for im in imgs])
    return np.mean(vals, axis=0)


# --------------------------------------------------------------- exact expectations
@pytest.mark.parametrize("n,k", [(100, 16), (1000, 12)])
@pytest.mark.parametrize("azimuth_deg", [0.0, 90.0])
def test_horizontal_leaves_any_zenith(n, k, azimuth_deg):
    zen = [0.0, 15.0, 30.0]
    got = _mean_p0(n, "horizontal", zen, k, azimuth_deg=azimuth_deg)
    want = expected_p0(n, 1.0 / n, 1.0, zen, "horizontal")  # (1 − a/A)^N at every θ
    assert np.allclose(want, (1 - 1.0 / n) ** n)
    assert np.all(np.abs(got - want) < 4 * SD_256[n] / math.sqrt(k)), (got, want)


def test_spherical_leaves_zeniths():
    zen, n, k = [0.0, 15.0, 30.0], 1000, 12
    got = _mean_p0(n, "spherical", zen, k, seed0=100)
    want = expected_p0(n, 1.0 / n, 1.0, zen, "spherical")  # (1 − a·0.5/(A cos θ))^N
    assert np.all(np.diff(want) < 0)
    assert np.all(np.abs(got - want) < 4 * SD_256[n] / math.sqrt(k)), (got, want)


def test_vertical_leaves_oblique():
    """G = (2/π)·sin θ: at 30° the vertical law intercepts like (1 − a·(2/π)·tan θ/A)^N."""
    n, k = 1000, 12
    got = _mean_p0(n, "vertical", [30.0], k, seed0=200)
    want = expected_p0(n, 1.0 / n, 1.0, [30.0], "vertical")
    assert abs(got[0] - want[0]) < 4 * SD_256[n] / math.sqrt(k)


# ----------------------------------------------------------- numerically hard views
def _vertical_squares(n, side, seed, azimuth_deg=None):
    """Vertical squares with vertical and horizontal edges: each triangle's corners share
    two (x, y) positions exactly, so its footprint seen from straight above is a segment."""
    rng = np.random.default_rng(seed)
    c = np.c_[rng.uniform(0, 1, (n, 2)), rng.uniform(0.1, 0.4, n)]
    phi = rng.uniform(0, 2 * np.pi, n) if azimuth_deg is None else np.full(n, math.radians(azimuth_deg))
    u = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], 1) * side / 2
    w = np.array([0.0, 0.0, side / 2])
    p = [c - u - w, c + u - w, c + u + w, c - u + w]
    tri = np.stack([np.stack([p[0], p[1], p[2]], 1), np.stack([p[0], p[2], p[3]], 1)], 1).reshape(-1, 3, 3)
    leaves = Leaves(tri, np.repeat(np.arange(n, dtype=np.int32), 2), np.zeros(2 * n, np.int32))
    return Canopy(leaves, (0.0, 0.0, 1.0, 1.0), periodic=True)


@pytest.mark.parametrize("azimuth_deg", [0.0, 37.0])
def test_edge_on_leaves_at_nadir_give_exactly_one(azimuth_deg):
    canopy = _vertical_squares(2000, 0.03, seed=4)
    img = gap_images(canopy, cameras=["orthographic"], zeniths_deg=[0], resolution=256, spp=16,
                     azimuth_deg=azimuth_deg)[0]
    assert img.p0 == 1.0 and img.coverage.max() == 0.0
    # the same leaves seen at 30° do intercept
    assert gap_images(canopy, cameras=["orthographic"], zeniths_deg=[30], resolution=128, spp=1)[0].p0 < 0.95


def test_random_vertical_law_at_nadir():
    """random_leaves' vertical squares keep vertical edges, so they stay exactly edge-on in float32."""
    for seed in range(3):
        img = gap_images(_rl(1000, "vertical", seed), cameras=["orthographic"], zeniths_deg=[0],
                         resolution=256, spp=4)[0]
        assert img.p0 == 1.0


def test_zenith_exactly_zero():
    from simlidar_mi._runtime.mitsuba import mitsuba
    mi = mitsuba()
    canopy = _rl(300, "spherical", 7)
    built = build_canopy_scene(canopy)
    for az in (0.0, 37.0, 90.0):
        cam = make_camera("orthographic", canopy, 0.0, azimuth_deg=az, resolution=64)
        assert cam.direction.tolist() == [0.0, 0.0, -1.0]
        sensor = mi.load_dict(cam.sensor_dict(mi, built.origin_m, 1))
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f([0.0, 0.3, 1.0], [0.0, 0.7, 1.0]), mi.Point2f(0.5))
        d = np.broadcast_to(np.array(ray.d), (3, 3))
        assert np.array_equal(d, [[0.0] * 3, [0.0] * 3, [-1.0] * 3])  # exactly vertical
    p_zero = gap_images(canopy, cameras=["orthographic"], zeniths_deg=[0.0], resolution=256, spp=4)[0].p0
    p_tiny = gap_images(canopy, cameras=["orthographic"], zeniths_deg=[1e-6], resolution=256, spp=4)[0].p0
    assert abs(p_zero - p_tiny) < 1e-4


def test_half_covered_plot_is_exactly_half():
    """One horizontal square over the half x < 0.5 of a 1 m plot: P0 = 0.5 at nadir."""
    v = np.array([[0, 0, 0.2], [0.5, 0, 0.2], [0.5, 1, 0.2], [0, 1, 0.2]], float)
    tri = np.stack([v[[0, 1, 2]], v[[0, 2, 3]]])
    canopy = Canopy(Leaves(tri, np.zeros(2, np.int32), np.zeros(2, np.int32)), (0, 0, 1, 1))
    for kind in ("orthographic", "perspective"):
        cam = make_camera(kind, canopy, 0.0, resolution=128, fov_deg=40)
        win = analysis_window(cam, canopy, "inset", margin_m=0.0)
        img = render_gap(build_canopy_scene(canopy), canopy, cam, win, spp=4)
        assert img.p0 == 0.5, kind


def test_small_leaves_large_pixels():
    """5 mm leaves, 6 cm pixels: each pixel averages many leaves; the spp average keeps
    the mean exact.  SD of one plot's P0, measured over 30 seeds: 0.0027 at spp 64 (mostly
    the binomial noise of 16384 nearly independent samples) and 0.022 at spp 1 (256)."""
    n, a = 20000, 2.5e-5  # LAI 0.5
    vals = {1: [], 64: []}
    for seed in range(6):
        canopy = canopy_from_random_leaves(random_leaves(n, a, (1.0, 1.0), (0.0, 0.3), "spherical",
                                                         seed=300 + seed))
        imgs = {spp: gap_images(canopy, cameras=["orthographic"], zeniths_deg=[0], resolution=16,
                                spp=spp)[0] for spp in (1, 64)}
        frac = imgs[64].coverage
        assert np.mean((frac > 0) & (frac < 1)) > 0.9  # sub-pixel coverage, not 0/1 pixels
        for spp, im in imgs.items():
            vals[spp].append(im.p0)
    want = expected_p0(n, a, 1.0, 0.0, "spherical")
    assert abs(np.mean(vals[64]) - want) < 4 * 0.0027 / math.sqrt(6)
    assert abs(np.mean(vals[1]) - want) < 4 * 0.022 / math.sqrt(6)


# ------------------------------------------------------------ perspective vs ortho
def _window_p0(img, fraction, canopy):
    win = analysis_window(img.camera, canopy, "periodic", fraction=fraction)
    x0, y0, x1, y1 = win.box_px
    return win, 1.0 - float(img.coverage[y0:y1, x0:x1].mean(dtype=np.float64))


def _expected_window_p0(cam, win, n, a, law, k=2):
    """Mean over the window's samples of the exact P0 at each sample's own view zenith."""
    x0, y0, x1, y1 = win.box_px
    u = (np.arange(x0 * k, x1 * k) + 0.5) / (cam.width * k)
    v = (np.arange(y0 * k, y1 * k) + 0.5) / (cam.height * k)
    _, d = cam.rays(*np.meshgrid(u, v))
    return float(expected_p0(n, a, 1.0, np.degrees(np.arccos(-d[..., 2])), law).mean())


def test_perspective_reads_lower_and_converges_as_window_narrows():
    """Spherical leaves, LAI 1, 60° field of view at nadir: every pixel sees the canopy at
    its own zenith, so P0_persp − P0_ortho ≈ −0.030 (whole image), −0.008 (central half),
    −0.002 (central quarter).  The exact expectations are checked for sign and trend,
    the measured mean differences against them (K = 8 seeds; SDs of one plot's
    difference measured over 16 seeds: 0.0026, 0.0042, 0.011)."""
    n, k, fractions = 10000, 8, (1.0, 0.5, 0.25)
    sd = (0.0026, 0.0042, 0.011)
    diffs, expected = [], None
    for seed in range(k):
        canopy = _rl(n, "spherical", 400 + seed)
        ortho, persp = gap_images(canopy, zeniths_deg=[0], resolution=256, spp=1)
        row = [_window_p0(persp, f, canopy)[1] - ortho.p0 for f in fractions]
        diffs.append(row)
        if expected is None:
            p_ortho = expected_p0(n, 1.0 / n, 1.0, 0.0, "spherical")
            expected = [_expected_window_p0(persp.camera, _window_p0(persp, f, canopy)[0], n,
                                            1.0 / n, "spherical") - p_ortho for f in fractions]
    mean = np.mean(diffs, axis=0)
    assert expected[0] < expected[1] < expected[2] < 0  # lower, less so as the window narrows
    assert -0.035 < expected[0] < -0.025 and -0.003 < expected[2]
    for m, e, s in zip(mean, expected, sd):
        assert abs(m - e) < 4 * s / math.sqrt(k), (mean, expected)
    assert mean[0] < mean[1] < 0  # resolved by the measurement itself


# ---------------------------------------------------------------- cameras, windows
@pytest.mark.parametrize("kind", ["orthographic", "perspective"])
@pytest.mark.parametrize("zenith,azimuth", [(0.0, 0.0), (15.0, 90.0), (30.0, 37.0)])
def test_numpy_camera_matches_mitsuba_sensor(kind, zenith, azimuth):
    from simlidar_mi._runtime.mitsuba import mitsuba
    mi = mitsuba()
    canopy = _rl(50, "spherical", 1, size=(1.2, 0.8))
    cam = make_camera(kind, canopy, zenith, azimuth_deg=azimuth, resolution=64)
    origin = np.array([3.0, -2.0, 0.0])
    sensor = mi.load_dict(cam.sensor_dict(mi, origin, 1))
    uv = np.array([[0, 0], [1, 1], [0.5, 0.5], [0.2, 0.9], [1, 0]], float)
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(uv[:, 0], uv[:, 1]), mi.Point2f(0.5))
    o_mi, d_mi = np.array(ray.o).T + origin, np.array(ray.d).T
    o, d = cam.rays(uv[:, 0], uv[:, 1])
    assert np.allclose(d_mi, d, atol=2e-6)
    t_mi = (0.25 - o_mi[:, 2]) / d_mi[:, 2]
    t = (0.25 - o[:, 2]) / d[:, 2]
    assert np.allclose(o_mi + t_mi[:, None] * d_mi, o + t[:, None] * d, atol=2e-5)


def test_inset_window_orthographic():
    canopy = _rl(200, "horizontal", 2, height=(0.1, 0.3))
    canopy = Canopy(canopy.leaves, canopy.plot_bounds_m, periodic=False)
    z0, z1 = canopy.z_range_m()
    cam = make_camera("orthographic", canopy, 0.0, resolution=200)
    win = analysis_window(cam, canopy, "inset", margin_m=0.1)
    assert win.box_px == (20, 20, 180, 180)  # plot inset 0.1 m on each side
    assert analysis_window(cam, canopy).margin_m == pytest.approx(canopy.leaf_size_m())
    # at 30° along the rows (+x, image up) the window loses (z1 − z0)·tan 30° of ground
    cam = make_camera("orthographic", canopy, 30.0, resolution=200)
    win = analysis_window(cam, canopy, "inset", margin_m=0.1)
    x0, y0, x1, y1 = win.box_px
    assert (x0, x1) == (20, 180)
    rows_m = (y1 - y0) / cam.height * 1.0  # the image spans the 1 m plot along x
    assert 0.8 - (z1 - z0) * math.tan(math.radians(30)) - 2 / cam.height <= rows_m
    assert rows_m <= 0.8 - (z1 - z0) * math.tan(math.radians(30)) + 1e-9
    # every window corner's ray stays inside the safe region through the canopy layer
    u = np.array([x0, x1, x0, x1]) / cam.width
    v = np.array([y0, y0, y1, y1]) / cam.height
    for z in (z0, z1):
        p = cam.points_at_z(u, v, z)
        assert np.all(p[:, :2] >= 0.1 - 1e-9) and np.all(p[:, :2] <= 0.9 + 1e-9)


@pytest.mark.parametrize("zenith", [15.0, 30.0])
def test_inset_window_on_a_long_narrow_plot_is_the_largest_box(zenith):
    """A tilted perspective image maps a box to a trapezoid widening away from the camera, so
    on a 1.8 m × 0.54 m bed (two rows, tilted along them) the window as wide as the strip allows
    cannot grow along it.  The window is the largest box whose rays stay in the safe region:
    checked against a brute-force search over (width, height) pairs in pixels.  (Widening one
    axis after the other kept a 98-pixel square at 15°, a tenth of this window's area.)"""
    leaves = _rl(300, "horizontal", 5, height=(0.0, 0.25), size=(1.816, 0.536)).leaves
    canopy = Canopy(leaves, (0.0, 0.0, 1.816, 0.536), periodic=False)
    cam = make_camera("perspective", canopy, zenith, resolution=256, fov_deg=60.0, camera_height_m=1.0)
    win = analysis_window(cam, canopy, "inset", margin_m=0.19)
    x0, y0, x1, y1 = win.box_px
    zs = canopy.z_range_m()
    rx0, ry0, rx1, ry1 = win.safe_region_m

    def inside(w, h):  # the centred pixel box of w × h pixels
        u = (cam.width / 2 + np.array([-w, w, -w, w]) / 2) / cam.width
        v = (cam.height / 2 + np.array([-h, -h, h, h]) / 2) / cam.height
        return all(np.all((p[:, 0] >= rx0 - 1e-9) & (p[:, 0] <= rx1 + 1e-9) & (p[:, 1] >= ry0 - 1e-9)
                          & (p[:, 1] <= ry1 + 1e-9)) for p in (cam.points_at_z(u, v, z) for z in zs))
    assert inside(x1 - x0, y1 - y0)
    best = max(w * max((h for h in range(2, cam.height + 1, 2) if inside(w, h)), default=0)
               for w in range(2, cam.width + 1, 2))
    assert (x1 - x0) * (y1 - y0) >= 0.95 * best
    assert (y1 - y0) > 4 * (x1 - x0)  # a strip along the bed, not a square


def test_empty_canopy_and_tiling_limit():
    canopy = canopy_from_random_leaves(random_leaves(0, 0.001, seed=1))
    assert [im.p0 for im in gap_images(canopy, resolution=16, spp=1)] == [1.0] * 6
    with pytest.raises(ConfigError, match="copies of the periodic plot"):
        gap_images(_rl(1000, "spherical", 1, size=(0.2, 0.2)), cameras=["perspective"],
                   zeniths_deg=[0], camera_height_m=500.0, resolution=16, spp=1)


def test_window_too_small_is_a_config_error():
    canopy = Canopy(_rl(50, "horizontal", 3).leaves, (0.0, 0.0, 1.0, 1.0), periodic=False)
    cam = make_camera("orthographic", canopy, 0.0, resolution=64)
    with pytest.raises(ConfigError, match="margin"):
        analysis_window(cam, canopy, "inset", margin_m=0.6)
    with pytest.raises(ConfigError, match="zenith"):
        make_camera("orthographic", canopy, 85.0)
    with pytest.raises(ConfigError, match="camera"):
        make_camera("fisheye", canopy, 0.0)


# ---------------------------------------------------------------- pipeline, files
RL_SCENE = """
[scene]
seed = 5
[random_leaves]
n_leaves = 400
leaf_area_m2 = 0.0025
height_range_m = [0.0, 0.4]
[gapfraction]
resolution = 96
spp = 4
jitter = {jitter}
replicates = 2
"""


@pytest.mark.parametrize("jitter", ["false", "true"])
def test_same_seed_same_bytes(tmp_path, jitter):
    path = tmp_path / "rl.toml"
    path.write_text(RL_SCENE.format(jitter=jitter))
    run_a = run_gapfraction(path, tmp_path / "a")
    run_b = run_gapfraction(path, tmp_path / "b")
    for a, b in zip(run_a.images, run_b.images):
        assert a.coverage.tobytes() == b.coverage.tobytes()
    for im in run_a.images:  # EXR headers hold render seconds, so compare the pixels
        cov = [read_gap_exr(tmp_path / d / f"{im.stem()}.exr")[0] for d in "ab"]
        assert cov[0].tobytes() == cov[1].tobytes() == im.coverage.tobytes()
        assert (tmp_path / "a" / f"{im.stem()}.png").read_bytes() == \
            (tmp_path / "b" / f"{im.stem()}.png").read_bytes()
    rows = [list(csv.DictReader(open(tmp_path / d / "gap_fraction.csv"))) for d in "ab"]
    assert [r["p0"] for r in rows[0]] == [r["p0"] for r in rows[1]]


def test_run_writes_csv_png_exr(tmp_path):
    path = tmp_path / "rl.toml"
    path.write_text(RL_SCENE.format(jitter="false"))
    run = run_gapfraction(path, tmp_path / "out", ["gapfraction.zeniths_deg=[0, 30]"])
    out = tmp_path / "out"
    with open(out / "gap_fraction.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == CSV_COLUMNS
        rows = list(reader)
    assert [(r["camera"], r["zenith_deg"]) for r in rows] == [
        ("orthographic", "0"), ("orthographic", "30"), ("perspective", "0"), ("perspective", "30")]
    assert all(float(r["lai"]) == pytest.approx(1.0) for r in rows)
    assert sorted(p.name for p in out.glob("*.png")) == sorted(f"{im.stem()}.png" for im in run.images)
    from PIL import Image
    for im in run.images:
        cov, header = read_gap_exr(out / f"{im.stem()}.exr")
        assert np.array_equal(cov, im.coverage)
        meta = header["metadata"]
        assert meta["window"]["box_px"] == list(im.window.box_px)
        assert meta["p0"] == pytest.approx(im.p0) and header["camera"] == im.camera.kind
        # a palette PNG: the colours of render_mask_rgb, and the mask itself reads back
        with Image.open(out / f"{im.stem()}.png") as png:
            assert png.mode == "P"
            rgb = np.asarray(png.convert("RGB"))
        assert np.array_equal(rgb, render_mask_rgb(im.mask(), im.window.box_px))
        assert np.array_equal(read_mask_png(out / f"{im.stem()}.png"), im.mask())
    assert not list(tmp_path.glob(".out.partial-*")) and not list(out.glob(".partial-*"))


def test_failed_run_leaves_nothing(tmp_path):
    path = tmp_path / "rl.toml"
    path.write_text(RL_SCENE.format(jitter="false") + 'window = "inset"\nmargin_m = 0.6\n')
    with pytest.raises(ConfigError) as exc:
        run_gapfraction(path, tmp_path / "out")
    assert exc.value.file == str(path)
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))


def test_config_errors_name_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[random_leaves]\n[gapfraction]\ncameras = ["fisheye"]\n')
    with pytest.raises(ConfigError) as exc:
        load_scene(path)
    assert exc.value.key == "gapfraction.cameras" and str(path) in str(exc.value)
    path.write_text("[random_leaves]\n[gapfraction]\nzeniths_deg = [0, 85]\n")
    with pytest.raises(ConfigError, match="zeniths_deg"):
        load_scene(path)
    path.write_text("[gapfraction]\n")
    with pytest.raises(ConfigError, match="random_leaves"):
        run_gapfraction(path)


def test_defaults_agree_with_scene_schema():
    assert {k: v.default for k, v in SECTIONS["gapfraction"].items()} == DEFAULTS


def test_cli(tmp_path, capsys):
    path = tmp_path / "rl.toml"
    path.write_text(RL_SCENE.format(jitter="false"))
    rc = main(["gapfraction", str(path), "--out", str(tmp_path / "out"),
               "--set", "gapfraction.cameras=['orthographic']", "--no-images"])
    assert rc == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "gap_fraction.csv", "gap_fraction.json", "gap_fraction_replicates.csv"]
    assert "orthographic" in capsys.readouterr().out
    assert main(["gapfraction", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "x")]) == 2


def test_shipped_random_leaves_scene(tmp_path):
    run = run_gapfraction(REPO / "scenes" / "random_leaves_spherical.toml", None,
                          ["gapfraction.resolution=128", "gapfraction.spp=1"], replicates=1)
    assert len(run.images) == 6 and run.canopies[0].lai == pytest.approx(1.0)
    ortho = [im.p0 for im in run.images if im.camera.kind == "orthographic"]
    want = expected_p0(1000, 0.001, 1.0, [0, 15, 30], "spherical")
    assert np.all(np.abs(np.array(ortho) - want) < 4 * 0.006 * 1.5)  # one plot, coarse image


# ------------------------------------------------------------------- strawberry
def test_strawberry_steps_share_views_and_p0_never_falls():
    """Each extraction step is a subset of the previous one and is seen through the same
    cameras and windows, so no ray can become covered: P0 is non-decreasing, exactly."""
    run = run_gapfraction(REPO / "scenes" / "strawberry_plot.toml", None,
                          ["gapfraction.resolution=160", "gapfraction.spp=1",
                           "strawberry.rows=3", "strawberry.plants_per_row=3"], replicates=1)
    by_view: dict = {}
    for im in run.images:
        by_view.setdefault((im.camera.kind, im.camera.zenith_deg), []).append(im)
    assert len(by_view) == 6 and all(len(v) == 4 for v in by_view.values())
    for ims in by_view.values():
        assert [im.step for im in ims] == [0, 1, 2, 3]
        assert len({im.window.box_px for im in ims}) == 1
        assert len({tuple(im.camera.position_m) for im in ims}) == 1
        p0 = [im.p0 for im in ims]
        assert all(b >= a for a, b in zip(p0, p0[1:])) and p0[-1] > p0[0]
        lai = [im.lai for im in ims]
        assert all(b < a for a, b in zip(lai, lai[1:]))


def test_strawberry_extraction_in_scene_files(tmp_path):
    """Default (issue 33): the shares of the starting leaves that make leaf area follow Table
    4's real canopy (0.806 / 0.649 / 0.472 of the first); sixths and extraction_counts are
    options; both keys at once is refused, naming the file and key."""
    def counts(extra):
        cfg = load_scene(REPO / "scenes" / "strawberry_plot.toml", extra)
        return [len(np.unique(c.leaves.leaf_id)) for c in canopies_from_config(cfg)]
    n = counts([])
    assert n == [n[0] - math.floor(n[0] * (1 - a / 1.116) + 0.5 + 1e-9)
                 for a in (1.116, 0.900, 0.724, 0.527)] and n[0] > 600
    sixths = counts(["strawberry.extraction_fractions=[0.16666666666666666, 0.16666666666666666, "
                     "0.16666666666666666]"])
    assert sixths == [n[0] - math.floor(n[0] * k / 6 + 0.5) for k in range(4)]
    assert counts(["strawberry.extraction_fractions=[0.5]"]) == [n[0], n[0] - n[0] // 2]
    assert counts(["strawberry.extraction_counts=[44, 39, 44]"]) == [n[0] - c for c in (0, 44, 83, 127)]
    cfg = load_scene(REPO / "scenes" / "strawberry_plot.toml", ["strawberry.extraction_counts=[44]"])
    cfg["strawberry"]["extraction_fractions"] = [0.2]
    with pytest.raises(ConfigError, match="not both") as e:
        canopies_from_config(cfg)
    assert e.value.file.endswith("strawberry_plot.toml")
    with pytest.raises(ConfigError, match="extraction_fractions"):
        load_scene(REPO / "scenes" / "strawberry_plot.toml", ["strawberry.extraction_fractions=[0.6, 0.6]"])


def test_replicate_seeds():
    assert replicate_seed(7, 0) == 7
    assert replicate_seed(7, 0, 1).entropy == [7, 1]
    kids = np.random.SeedSequence(7).spawn(3)
    for k in (1, 2):
        a, b = replicate_seed(7, k), kids[k]
        assert (a.entropy, a.spawn_key) == (b.entropy, b.spawn_key)
    assert replicate_seed(7, 2, 1).spawn_key == (2,)


def test_replicates_mean_sd_and_files(tmp_path):
    """gap_fraction.csv: p0 = mean over replicate plots, p0_sd_plot = their SD (ddof 1),
    p0_sd = p0_sd_plot/√n; the replicate values are in gap_fraction_replicates.csv.
    Replicate 0 is the scene seed's own plot, and adding replicates keeps the others."""
    path = tmp_path / "rl.toml"
    path.write_text(RL_SCENE.format(jitter="false"))
    run = run_gapfraction(path, tmp_path / "out", ["gapfraction.replicates=3"])
    rows = list(csv.DictReader(open(tmp_path / "out" / "gap_fraction.csv", newline="")))
    reps = list(csv.DictReader(open(tmp_path / "out" / "gap_fraction_replicates.csv", newline="")))
    assert len(rows) == 6 and len(reps) == 18
    assert tuple(reps[0]) == REPLICATE_COLUMNS
    for r in rows:
        v = [float(x["p0"]) for x in reps if (x["camera"], x["zenith_deg"], x["step"])
             == (r["camera"], r["zenith_deg"], r["step"])]
        assert len(v) == 3 and int(r["replicates"]) == 3
        assert float(r["p0"]) == pytest.approx(np.mean(v), abs=2e-6)
        assert float(r["p0_sd_plot"]) == pytest.approx(np.std(v, ddof=1), abs=2e-6)
        assert float(r["p0_sd"]) == pytest.approx(np.std(v, ddof=1) / math.sqrt(3), abs=2e-6)
        assert float(r["p0_sd_plot"]) > 0.002  # independent plots really differ
    one = run_gapfraction(path, None, ["gapfraction.replicates=1"])
    two = run_gapfraction(path, None, ["gapfraction.replicates=2"])
    assert [im.p0 for im in one.images] == [im.p0 for im in run.replicate_images[0]]
    assert [im.p0 for im in two.replicate_images[1]] == [im.p0 for im in run.replicate_images[1]]
    assert all(math.isnan(s.p0_sd_plot) for s in one.summary)
    with pytest.raises(ConfigError, match="replicates"):
        load_scene(path, ["gapfraction.replicates=0"])
