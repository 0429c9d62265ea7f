"""Incidence from the per-triangle normal table equals Mitsuba's surface interaction,
on a flat orchard (meshes in the identity group) and on an instanced forest (turned trees)."""
import numpy as np
import pytest

from simlidar_mi._runtime.mitsuba import mitsuba
from simlidar_mi.lidar.scan import _lidar, _range_integrator
from simlidar_mi.lidar.survey import build, generate, load_scene, scan_patterns


@pytest.mark.parametrize("scene, sets", [
    ("scenes/apple_orchard.toml", ["orchard.n_trees=2", "scan.dy_m=0.02", "scan.dtheta_deg=0.5"]),
    ("scenes/forest_small.toml", ['platform.kind="airborne"', "platform.start_xy_m=[20.0, 0.0]",
                                  "platform.end_xy_m=[20.0, 40.0]", "platform.altitude_m=60.0",
                                  "platform.speed_m_s=10.0", "platform.pulse_rate_hz=40000.0",
                                  "platform.pulses_per_line=400", "platform.swath_deg=60.0"]),
])
def test_table_normals_match_surface_interaction(scene, sets, monkeypatch):
    from simlidar_mi.scene import build as build_mod
    monkeypatch.setattr(build_mod, "GROUP_MIN_TRIANGLES", 1)  # the orchard's meshes in the group too
    cfg = load_scene(scene, sets)
    geo = generate(cfg)
    lo, hi = geo.bounds_m()
    pattern = scan_patterns(cfg, lo, hi, geo.near_x_m)[0]
    built = build(cfg, geo, [pattern])
    mi = mitsuba(cfg["scene"]["variant"])
    _, pat, lidar = _lidar(mi, built, pattern)
    n_beams = min(pat.n_beams, 400_000)
    offsets = np.zeros((1, 2))
    integ = _range_integrator(mi, built, pat)
    integ.set_reflectance(np.array([0, 0.2, 0.35, 0.45]), built.shape_reflectance)
    ref = integ.trace_subrays(built.scene, lidar, offsets, 0, n_beams, normals=True)
    normals = built.prim_normals()
    assert normals is not None
    integ.set_normals(normals, built.instance_yaw_rad)
    got = integ.trace_subrays(built.scene, lidar, offsets, 0, n_beams, normals=True)
    veg = np.isin(ref["class"].numpy(), (2, 3))
    assert veg.sum() > 500
    if built.n_instances:
        assert np.any(built.instance_yaw_rad != 0)
    a, b = ref["cos_incidence"].numpy(), got["cos_incidence"].numpy()
    np.testing.assert_array_equal(ref["t"].numpy(), got["t"].numpy())
    np.testing.assert_allclose(b[veg], a[veg], atol=2e-5)
    np.testing.assert_array_equal(a[~veg], b[~veg])  # ground and escapes untouched
