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


def test_table_normals_are_numpys_float64_normals():
    """The Dr.Jit kernel of BuiltScene.prim_normals gives the bits of numpy's float64 cross
    product and norm (its former code), degenerate triangles (zero normal) included."""
    cfg = load_scene("scenes/apple_orchard.toml", ["orchard.n_trees=2"])
    geo = generate(cfg)
    lo, hi = geo.bounds_m()
    built = build(cfg, geo, scan_patterns(cfg, lo, hi, geo.near_x_m))
    mi = mitsuba(cfg["scene"]["variant"])
    zero = mi.Mesh("zero", 3, 2)  # a degenerate triangle beside a real one
    params = mi.traverse(zero)
    params["vertex_positions"] = mi.Float(np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], np.float32))
    params["faces"] = mi.UInt32(np.array([0, 1, 1, 0, 1, 2], np.uint32))
    params.update()
    built.prim_shapes = [*built.prim_shapes, zero]
    got = built.prim_normals()
    parts = []
    for mesh in built.prim_shapes:
        p = mi.traverse(mesh)
        v = p["vertex_positions"].numpy().reshape(-1, 3).astype(np.float64)
        f = p["faces"].numpy().reshape(-1, 3)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        parts.append(np.divide(n, norm, out=np.zeros_like(n), where=norm > 0).astype(np.float32))
    ref = np.concatenate(parts)
    assert len(ref) > 10_000 and np.array_equal(ref[-2:], [[0, 0, 0], [0, 0, 1]])
    assert np.array_equal(got.view(np.uint32), ref.view(np.uint32))
