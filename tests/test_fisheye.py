"""Fisheye cameras: lens round trips, plugin rays against a float64 reference, analytic gap fractions."""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.canopy.fisheye import gap_runs, gap_table, make_fisheye, render_fisheye, ring_bounds
from simlidar_mi.canopy.fisheye_lens import LENSES, PROJECTIONS, lens
from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches, Leaves, Primitive

ALL_LENSES = list(PROJECTIONS[:-1]) + list(LENSES)


@pytest.mark.parametrize("name", ALL_LENSES)
def test_lens_round_trip_and_edges(name):
    ln = lens(name)
    theta = np.r_[0.0, 1e-9, 1e-6, np.linspace(0.001, ln.theta_edge_rad - 1e-6, 500), ln.theta_edge_rad - 1e-9]
    rho = ln.rho(theta)
    assert np.all(np.diff(rho) > 0)
    # orthographic: ρ = sin θ is flat at 90°, so θ(ρ) there is only good to √ε (the
    # projection's own conditioning); the direction (sin θ, cos θ) from ρ stays exact.
    atol = 3e-8 if name == "orthographic" else 1e-13
    np.testing.assert_allclose(ln.theta(rho), theta, rtol=1e-12, atol=atol)
    s, c = ln.sin_cos(rho)
    np.testing.assert_allclose(s, np.sin(theta), rtol=1e-12, atol=1e-15)
    if name == "orthographic":  # cos θ of the rounded ρ, in extended precision
        exact = np.sqrt(1 - rho.astype(np.longdouble) ** 2).astype(np.float64)
        np.testing.assert_allclose(c, exact, rtol=1e-12, atol=1e-18)
    else:
        np.testing.assert_allclose(c, np.cos(theta), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(s * s + c * c, 1.0, atol=4e-16)
    assert ln.rho(ln.theta_edge_rad) == pytest.approx(1.0, abs=1e-12)
    assert np.isnan(ln.theta(1.0 + 1e-9))
    # derivative against a central difference
    t = np.linspace(0.05, ln.theta_edge_rad - 0.05, 50)
    np.testing.assert_allclose(ln.drho_dtheta(t), (ln.rho(t + 1e-6) - ln.rho(t - 1e-6)) / 2e-6, rtol=1e-6)


def test_standard_projections_are_the_textbook_formulas():
    t = np.radians([0.0, 10.0, 45.0, 80.0, 90.0])
    np.testing.assert_allclose(lens("equidistant").rho(t), t / (np.pi / 2))
    np.testing.assert_allclose(lens("equisolid").rho(t), 2 * np.sin(t / 2) / (2 * np.sin(np.pi / 4)))
    np.testing.assert_allclose(lens("orthographic").rho(t), np.sin(t))
    np.testing.assert_allclose(lens("stereographic").rho(t), np.tan(t / 2))
    # FC-E8 (Pekin & Macfarlane 2009, in θ/90°): ρ(90°) = 1.06 + 0.00498 − 0.0639
    assert lens("FC-E8").rho(np.pi / 2) == pytest.approx(1.06 + 0.00498 - 0.0639, rel=1e-12)


def test_bad_lenses_are_refused():
    with pytest.raises(ConfigError, match="monoton"):
        lens("polynomial", [0.5, -0.5])
    with pytest.raises(ConfigError, match="unknown lens"):
        lens("fisheye-9000")
    with pytest.raises(ConfigError):
        lens("polynomial")


def test_pixel_angles_of_an_untilted_up_camera():
    cam = make_fisheye([0, 0, 1], resolution=65)  # odd: a pixel centre on the axis
    a = cam.pixel_angles()
    assert a.theta_deg[32, 32] == 0.0
    assert a.solid_angle_sr.sum() == pytest.approx(2 * np.pi, rel=5e-3)
    # image top = +y (φ = 90°); looking up, +x (φ = 0°) is on the left of the image
    assert a.azimuth_deg[5, 32] == pytest.approx(90.0)
    assert a.azimuth_deg[32, 5] == pytest.approx(0.0)
    assert a.azimuth_deg[32, 60] == pytest.approx(180.0)
    down = make_fisheye([0, 0, 1], resolution=65, looking="down").pixel_angles()
    assert down.azimuth_deg[32, 60] == pytest.approx(0.0)  # a map: +x on the right
    assert not a.inside[0, 0] and np.isnan(a.theta_deg[0, 0])
    full = make_fisheye([0, 0, 1], resolution=90, format="fullframe").pixel_angles()
    assert full.inside.all() and np.nanmax(full.theta_deg) > 85.0


def test_ring_bounds_forms():
    np.testing.assert_array_equal(ring_bounds([0, 10, 20]), [[0, 10], [10, 20]])
    np.testing.assert_array_equal(ring_bounds([[0, 13], [16, 28]]), [[0, 13], [16, 28]])
    with pytest.raises(ConfigError):
        ring_bounds([10, 5])


# ----------------------------------------------------------------------------- plugin
@pytest.fixture(scope="module")
def mi():
    from simlidar_mi._runtime.mitsuba import mitsuba
    return mitsuba()


@pytest.mark.parametrize("name", ALL_LENSES)
@pytest.mark.parametrize("looking, tilt", [("up", 0.0), ("down", 0.0), ("up", 17.0)])
def test_plugin_rays_match_float64_reference(mi, name, looking, tilt):
    cam = make_fisheye([0.3, -0.2, 1.2], projection=name, resolution=48, looking=looking,
                      tilt_deg=tilt, tilt_azimuth_deg=30.0)
    sensor = mi.load_dict({"type": "fisheye", "projection": name, "radius_px": cam.radius_px,
                           "film": {"type": "hdrfilm", "width": 48, "height": 48}})
    sensor.set_frame(cam.position_m, cam.frame())
    rng = np.random.default_rng(1)
    # random points, the axis and points a hair from it, and the horizon (ρ → 1) in four azimuths
    eps = np.array([1e-7, 1e-5, 1e-3])
    u = np.r_[rng.random(400), 0.5, 0.5 + eps, np.full(3, 0.5), 1.0, 0.0, 0.5, 0.5, 0.5 + (0.5 - 1e-6)]
    v = np.r_[rng.random(400), 0.5, np.full(3, 0.5), 0.5 + eps, 0.5, 0.5, 0.0, 1.0, np.full(1, 0.5)]
    u, v = u.astype(np.float32), v.astype(np.float32)  # the plugin's inputs, exactly
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Vector2f(u, v), mi.Vector2f(0.5, 0.5))
    d = np.stack([ray.d.x.numpy(), ray.d.y.numpy(), ray.d.z.numpy()], 1).astype(np.float64)
    ref = cam.directions(u.astype(np.float64) * 48, v.astype(np.float64) * 48)
    # float32 rounding of the sample position (~1e-7 of ρ) moves θ by δρ/ρ′(θ): a lens that is flat
    # near its edge (orthographic: ρ′ = cos θ) cannot place a horizon ray better than that
    _, rho = cam.camera_directions(u.astype(np.float64) * 48, v.astype(np.float64) * 48)
    slope = lens(name).drho_dtheta(lens(name).theta(np.minimum(rho, 1.0)))
    tol = 1e-6 + 2e-7 / slope
    assert np.all(np.abs(d - ref).max(axis=1) < tol)
    o = np.array([ray.o.x.numpy()[0], ray.o.y.numpy()[0], ray.o.z.numpy()[0]])
    np.testing.assert_allclose(o, cam.position_m, atol=1e-6)
    if tilt == 0.0:  # the axis is exactly vertical and the horizon exactly horizontal
        axis = d[400]
        assert axis[0] == 0.0 and axis[1] == 0.0 and abs(axis[2]) == 1.0
        if lens(name).theta_edge_rad == math.pi / 2:
            assert np.abs(d[407:411, 2]).max() < 1e-7


# ----------------------------------------------------------------------------- renders
def _built(leaves=None, prims=()):
    from simlidar_mi.scene.build import build_scene
    return build_scene(Branches.empty(), leaves, list(prims), origin_m=np.zeros(3))


def _polygon(cx, cy, z, radius, n=256):
    a = np.linspace(0, 2 * np.pi, n + 1)
    p = np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a), np.full(n + 1, z)], 1)
    c = np.array([cx, cy, z])
    tri = np.stack([np.broadcast_to(c, (n, 3)), p[:-1], p[1:]], 1)
    return tri


def _leaves(tri):
    return Leaves(tri, np.zeros(len(tri), np.int32), np.zeros(len(tri), np.int32))


def test_empty_sky_gives_gap_one_and_box_gives_zero(mi):
    far = _leaves(_polygon(0, 0, -50.0, 1.0, 8))  # something in the scene, below the camera
    cam = make_fisheye([0, 0, 1.0], resolution=48)
    img = render_fisheye(_built(far), cam, spp=1)
    t = img.table()
    np.testing.assert_array_equal(t.ring_gap, 1.0)
    assert np.isnan(img.coverage[0, 0])
    box = Primitive("box", {"min_m": [-5, -5, -1], "max_m": [5, 5, 3]}, "leaf")
    img = render_fisheye(_built(prims=[box]), cam, spp=2)
    t = img.table()
    np.testing.assert_array_equal(t.ring_gap, 0.0)
    np.testing.assert_array_equal(t.gap, 0.0)


@pytest.mark.parametrize("name", ["equidistant", "equisolid", "FC-E8"])
def test_disc_overhead_gives_the_analytic_ring_gap(mi, name):
    h, alpha = 2.0, math.radians(14.0)
    disc = _leaves(_polygon(0.0, 0.0, 1.0 + h, h * math.tan(alpha)))
    cam = make_fisheye([0, 0, 1.0], projection=name, resolution=160)
    img = render_fisheye(_built(disc), cam, spp=4)
    t = img.table(rings_deg=[0, 20, 40], n_sectors=4)
    expected = 1 - (1 - math.cos(alpha)) / (1 - math.cos(math.radians(20)))
    # pixel error: the disc's rim crosses ~2π·r_px pixels, each off by at most half a pixel's share
    assert t.ring_gap[0] == pytest.approx(expected, abs=0.01)
    assert t.ring_gap[1] == 1.0
    np.testing.assert_allclose(t.gap[0], expected, atol=0.02)  # every sector of the centred disc


@pytest.mark.parametrize("looking", ["up", "down"])
def test_half_plane_fills_the_sectors_of_its_azimuths(mi, looking):
    z = 2.0 if looking == "up" else 0.0
    quad = np.array([[[-100, 0, z], [100, 0, z], [100, 100, z]], [[-100, 0, z], [100, 100, z], [-100, 100, z]]], float)
    cam = make_fisheye([0.0, 0.0, 1.0], resolution=96, looking=looking)
    t = render_fisheye(_built(_leaves(quad)), cam, spp=4).table(rings_deg=[0, 60], n_sectors=4)
    # y > 0 is φ ∈ (0°, 180°): sectors 0–90 and 90–180 covered, 180–360 open
    np.testing.assert_allclose(t.gap[0], [0.0, 0.0, 1.0, 1.0], atol=0.01)


def test_gap_table_weights():
    cam = make_fisheye([0, 0, 1.0], resolution=64)
    a = cam.pixel_angles()
    cov = np.where(a.theta_deg > 45.0, 1.0, 0.0)
    t = gap_table(cov, a, rings_deg=[0, 90], n_sectors=1)
    # open cap θ < 45° over the hemisphere: solid-angle share 1 − cos 45°; pixel share (equidistant) 1/4
    assert t.ring_gap[0] == pytest.approx(1 - math.cos(math.pi / 4), abs=0.01)
    assert t.ring_gap_pixels[0] == pytest.approx(0.25, abs=0.01)


def test_gap_runs_around_a_ring():
    cam = make_fisheye([0, 0, 1.0], resolution=200)
    a = cam.pixel_angles()
    cov = np.where((a.azimuth_deg >= 30.0) & (a.azimuth_deg < 120.0), 1.0, 0.0)  # one 90° plant sector
    runs = gap_runs(cov, cam, 45.0)
    assert len(runs) == 1 and runs[0] == pytest.approx(np.radians(270.0), abs=0.02)


@pytest.mark.parametrize("looking, sign", [("up", 1.0), ("down", -1.0)])
def test_tilt_leans_the_axis_toward_its_azimuth(looking, sign):
    cam = make_fisheye([0, 0, 1.0], resolution=64, looking=looking, tilt_deg=30.0, tilt_azimuth_deg=90.0)
    axis = cam.directions(32.0, 32.0)
    np.testing.assert_allclose(axis, [0.0, 0.5, sign * math.sqrt(3) / 2], atol=1e-15)
    a = cam.pixel_angles()
    assert np.nanmin(a.theta_deg) == pytest.approx(90 * math.hypot(0.5, 0.5) / 32)  # from the tilted axis
    # φ axes tilt with the camera (⟂ the axis): +x stays +x (the lean is toward +y), +y turns with it
    np.testing.assert_allclose(cam.azimuth_axes(), [[1, 0, 0], [0, math.sqrt(3) / 2, -0.5 * sign]], atol=1e-15)


def test_same_scene_same_bytes(mi):
    disc = _leaves(_polygon(0.2, 0.1, 2.5, 0.8, 64))
    cam = make_fisheye([0, 0, 1.0], projection="equisolid", resolution=48, tilt_deg=5.0)
    a = render_fisheye(_built(disc), cam, spp=4)
    b = render_fisheye(_built(disc), cam, spp=4)
    assert a.coverage.tobytes() == b.coverage.tobytes()
