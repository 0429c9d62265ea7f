"""Coverage integrator plugin: exact coverage on trivial scenes through ``mi.render``.

Every expected value here is exact (a square edge on a pixel or stratum boundary),
so the assertions are equalities, not tolerances.
"""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi._runtime.mitsuba import mitsuba
from simlidar_mi.scene.build import _mi_mesh as _mesh  # the builder's own mesh constructor


@pytest.fixture(scope="module")
def mi():
    return mitsuba("llvm_ad_mono")


def _square(mi, name, x0, x1, y0, y1, z):
    return _mesh(mi, name, [[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], [[0, 1, 2], [0, 2, 3]])


@pytest.fixture(scope="module")
def half_scene(mi):
    """A horizontal square covering x ∈ [0, 1], y ∈ [-1, 1] at z = 0.5: the right
    half of a [-1, 1]² view from above."""
    return mi.load_dict({"type": "scene", "leaf": _square(mi, "leaf", 0, 1, -1, 1, 0.5)})


def _ortho(mi, width, height, rfilter="box", crop=None):
    film = {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": rfilter}}
    if crop:
        film.update(crop)
    # Orthographic film spans ±1 in x and ±(height/width) in y: scale y by the aspect
    # so the view is exactly [-1, 1]².
    to_world = (mi.ScalarTransform4f.look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
                @ mi.ScalarTransform4f.scale([1.0, width / height, 1.0]))
    return mi.load_dict({"type": "orthographic", "to_world": to_world, "film": film})


def _render(mi, scene, sensor, spp, **props):
    integ = mi.load_dict({"type": "coverage", **props})
    img = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=spp))
    assert img.shape[2] == 1 and img.dtype == np.float32
    return img[:, :, 0]


def test_strata(mi):
    from simlidar_mi.plugins.coverage_integrator import strata
    assert [strata(n) for n in (1, 2, 4, 8, 16, 7, 64)] == [
        (1, 1), (1, 2), (2, 2), (2, 4), (4, 4), (1, 7), (8, 8)]
    with pytest.raises(ValueError):
        strata(0)


@pytest.mark.parametrize("spp", [1, 2, 4, 8, 16])
@pytest.mark.parametrize("width,height", [(64, 64), (63, 17)])
def test_orthographic_half_view_is_exactly_half(mi, half_scene, spp, width, height):
    cov = _render(mi, half_scene, _ortho(mi, width, height), spp)
    assert cov.shape == (height, width)
    cols = cov.mean(axis=0)
    # x > 0 is the right half of the image (look_at with up = +y seen from +z)
    assert np.all(cols[: width // 2] == 0.0)
    assert np.all(cols[(width + 1) // 2:] == 1.0)
    if width % 2:  # the middle column straddles the edge: half its strata see the square
        kx = {1: 1, 2: 1, 4: 2, 8: 2, 16: 4}[spp]
        assert cols[width // 2] == (0.5 if kx % 2 == 0 else 1.0)
    else:
        assert cov.mean(dtype=np.float64) == 0.5


def test_film_filter_is_ignored(mi, half_scene):
    """The default gaussian rfilter would blur the edge; coverage never goes through the film."""
    box = _render(mi, half_scene, _ortho(mi, 64, 64, "box"), 4)
    gauss = _render(mi, half_scene, _ortho(mi, 64, 64, "gaussian"), 4)
    assert np.array_equal(box, gauss)
    assert set(np.unique(box)) == {0.0, 1.0}


def test_subpixel_edge_gives_stratum_fraction(mi):
    """An edge a quarter of a pixel into column 40: 4×4 strata give exactly 0.75 there."""
    w = 64
    x_edge = -1.0 + 2.0 * (40 + 0.25) / w
    scene = mi.load_dict({"type": "scene", "leaf": _square(mi, "leaf", x_edge, 2, -2, 2, 0.5)})
    cov = _render(mi, scene, _ortho(mi, w, w), 16)
    assert np.all(cov[:, 40] == 0.75)
    assert np.all(cov[:, :40] == 0.0) and np.all(cov[:, 41:] == 1.0)


def test_perspective_half_view(mi, half_scene):
    sensor = mi.load_dict({"type": "perspective", "fov": 40,
                           "to_world": mi.ScalarTransform4f.look_at(origin=[0, 0, 2], target=[0, 0, 0],
                                                                    up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": 32, "height": 32}})
    cov = _render(mi, half_scene, sensor, 4)
    # the square spans x ≥ 0 far beyond the view: the right half exactly
    assert np.all(cov[:, :16] == 0.0) and np.all(cov[:, 16:] == 1.0)


def test_crop_window_matches_full_image(mi):
    rng = np.random.default_rng(5)
    shapes = {f"q{i}": _square(mi, f"q{i}", x, x + 0.13, y, y + 0.21, 0.5)
              for i, (x, y) in enumerate(rng.uniform(-1, 0.9, (30, 2)))}
    scene = mi.load_dict({"type": "scene", **shapes})
    full = _render(mi, scene, _ortho(mi, 48, 40), 4)
    crop = _render(mi, scene, _ortho(mi, 48, 40, crop={"crop_offset_x": 7, "crop_offset_y": 11,
                                                       "crop_width": 20, "crop_height": 13}), 4)
    assert np.array_equal(crop, full[11:24, 7:27])


@pytest.mark.parametrize("jitter", [False, True])
def test_same_seed_same_bytes_and_banding(mi, jitter):
    rng = np.random.default_rng(1)
    shapes = {f"q{i}": _square(mi, f"q{i}", x, x + 0.05, y, y + 0.07, 0.5)
              for i, (x, y) in enumerate(rng.uniform(-1, 1, (200, 2)))}
    scene = mi.load_dict({"type": "scene", **shapes})
    sensor = _ortho(mi, 40, 30)
    integ = mi.load_dict({"type": "coverage", "jitter": jitter})
    banded = mi.load_dict({"type": "coverage", "jitter": jitter, "max_rays": 1000})
    a = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=8, seed=3))
    b = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=8, seed=3))
    c = np.array(mi.render(scene, sensor=sensor, integrator=banded, spp=8, seed=3))
    d = np.array(mi.render(scene, sensor=sensor, integrator=integ, spp=8, seed=4))
    assert a.tobytes() == b.tobytes() == c.tobytes()  # bands of 4 rows change nothing
    assert (a.tobytes() != d.tobytes()) == jitter  # only jitter depends on the seed


def test_background_shapes_count_as_gaps(mi):
    """A 'soil' square above a leaf hides it; a leaf above the soil is vegetation."""
    scene = mi.load_dict({"type": "scene",
                          "leaf": _square(mi, "leaf", -1, 1, -1, 1, 0.2),
                          "soil": _square(mi, "soil", -1, 0, -1, 1, 0.5)})
    import drjit as dr
    ids = dr.reinterpret_array(mi.UInt32, scene.shapes_dr()).numpy()
    veg = np.zeros(int(ids.max()) + 1, bool)
    for shape, rid in zip(scene.shapes(), ids):
        veg[rid] = shape.id() == "leaf"
    integ = mi.load_dict({"type": "coverage"})
    assert _render(mi, scene, _ortho(mi, 16, 16), 1).mean() == 1.0  # default: every shape
    integ.set_vegetation(veg)
    cov = np.array(mi.render(scene, sensor=_ortho(mi, 16, 16), integrator=integ, spp=1))[:, :, 0]
    assert np.all(cov[:, :8] == 0.0) and np.all(cov[:, 8:] == 1.0)
    integ.set_vegetation(None)
    cov = np.array(mi.render(scene, sensor=_ortho(mi, 16, 16), integrator=integ, spp=1))[:, :, 0]
    assert cov.mean() == 1.0


def test_sample_returns_binary_hit(mi, half_scene):
    integ = mi.load_dict({"type": "coverage"})
    o = mi.Point3f([-0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    d = mi.Vector3f([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-1.0, -1.0, 1.0])
    value, valid, aovs = integ.sample(half_scene, None, mi.Ray3f(o, d))
    assert np.array(value).ravel().tolist() == [0.0, 1.0, 0.0]  # miss, hit, looking up: miss
    assert aovs == []


def test_bad_parameters(mi):
    with pytest.raises(Exception, match="max_rays"):
        mi.load_dict({"type": "coverage", "max_rays": 0})
