"""Scan arrays are views of Dr.Jit memory (no copy), and the integrator's beam rays are the
sensor's own rays.

``BeamTracer.trace`` returns ``.numpy()`` views instead of copies: the view's base keeps the
Dr.Jit array alive.  If that ever stopped being true, the values would be overwritten once
Dr.Jit reuses the memory; these tests fill that memory again and compare.  ``beam_ray`` (the
range integrator's path) must give the bits ``sample_ray`` gives at the beam's centre sample.
"""
from __future__ import annotations

import gc

import numpy as np
import pytest

from simlidar_mi._runtime.mitsuba import mitsuba
from simlidar_mi.geometry import Branches
from simlidar_mi.lidar.scan import ScanSettings, scan
from simlidar_mi.scene.build import build_scene


def _settings(n: int = 40, m: int = 61) -> ScanSettings:
    return ScanSettings(x0_m=0.0, z0_m=1.0, y_start_m=-0.2, dy_m=0.01, gap=0, n_positions=n,
                        theta_min_deg=-30.0, dtheta_deg=1.0, n_angles=m)


def _two_trees() -> Branches:
    p0 = np.array([[1.0, -0.1, 0.0], [1.5, 0.1, 0.0]])
    p1 = np.array([[1.0, -0.1, 2.0], [1.5, 0.1, 1.5]])
    return Branches(p0, p1, np.array([0.08, 0.05]), np.ones(2, np.int32), np.array([0, 1], np.int32))


def test_scan_arrays_survive_later_dr_jit_work():
    mi = mitsuba()
    import drjit as dr
    built = build_scene(_two_trees())
    res = scan(built, _settings())
    kept = {k: np.array(getattr(res, k), copy=True) for k in ("range_m", "cls", "element_id", "hit_fraction", "tree_id")}
    assert (res.cls == 2).any() and (res.cls == 1).any()  # the test sees wood and ground
    assert res.range_m.flags.writeable
    del built
    gc.collect()
    for j in range(4):  # reuse of the freed Dr.Jit memory would overwrite unowned views
        junk = dr.full(mi.Float, 123.0 + j, res.range_m.size) * 2.0
        dr.eval(junk)
        _ = scan(build_scene(_two_trees()), _settings()).range_m.sum()
        del junk
    for k, v in kept.items():
        assert np.array_equal(getattr(res, k), v), k


@pytest.mark.parametrize("footprint", [0, 2])
@pytest.mark.parametrize("moving", [False, True])
def test_beam_ray_is_sample_ray_at_the_beam_centre(footprint, moving):
    mi = mitsuba()
    import drjit as dr
    from simlidar_mi.plugins.range_integrator import _beam_ray
    n, m, P1 = 7, 9, footprint + 1
    sensor = mi.load_dict({"type": "lidar_pattern", "n_positions": n, "n_angles": m, "footprint": footprint,
                           "film": {"type": "hdrfilm", "width": m, "height": n, "rfilter": {"type": "box"}}})
    rng = np.random.default_rng(3)
    d = rng.normal(size=(m * P1, 3))
    sensor.set_tables(rng.normal(size=(n * P1, 3)) * 10, d / np.linalg.norm(d, axis=1, keepdims=True),
                      yaw_rad=rng.uniform(-3, 3, n * P1))
    if moving:
        sensor.set_motion(rng.uniform(0, 1e-3, m * P1), [2.0, -1.0, 0.5])
    S = P1 ** 2
    idx = dr.arange(mi.UInt32, n * m * S)
    beam, sub = (idx // S, idx % S) if S > 1 else (idx, None)
    new = _beam_ray(sensor, beam, sub)
    i, k = beam // m, beam % m
    pos = mi.Vector2f((mi.Float(k) + 0.5) / m, (mi.Float(i) + 0.5) / n)
    ap = mi.Vector2f(0.5, 0.5) if sub is None else \
        mi.Vector2f(mi.Float(sub % P1) / footprint, mi.Float(sub // P1) / footprint)
    old, _ = sensor.sample_ray(0.0, 0.0, pos, ap)
    for a, b in ((new.o, old.o), (new.d, old.d)):
        for c in range(3):
            assert np.array_equal(a[c].numpy(), b[c].numpy())


def test_mi_render_through_the_range_integrator_gives_the_scan():
    """``mi.render`` (the plugin's ``render``) returns range, class, element id and hit fraction
    as floats: the scan's arrays (class now leaves the kernel as uint8)."""
    mi = mitsuba()
    from simlidar_mi.lidar.scan import BeamTracer
    built = build_scene(_two_trees())
    tracer = BeamTracer(built, _settings())
    img = np.array(mi.render(built.scene, sensor=tracer._lidar, integrator=tracer._integrator))
    res = scan(built, _settings())
    assert img.shape == (*res.shape, 4)
    assert np.array_equal(img[..., 0], res.range_m)
    assert np.array_equal(img[..., 1], res.cls.astype(np.float32))
    assert np.array_equal(img[..., 2], np.where(res.element_id == 0xFFFFFFFF, -1.0, res.element_id).astype(np.float32))
    assert np.array_equal(img[..., 3], res.hit_fraction)
