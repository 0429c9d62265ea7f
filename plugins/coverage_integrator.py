"""Coverage integrator: the share of each pixel where the primary ray meets vegetation.

A gap-fraction camera only needs to know, per pixel, which part of it sees
vegetation (leaf or wood) and which sees the background.  This integrator casts
the primary rays of any sensor that implements ``sample_ray`` (stock
``orthographic`` and ``perspective`` included) and returns, per pixel, the mean
of a binary hit over the pixel's samples: no BSDF, emitter, medium or second
bounce is ever evaluated.  Averaging a *binary* coverage is exact for gap
fraction (P0 of a window = 1 − mean coverage of its pixels), unlike averaging
ranges or ids.

.. pluginparameters::

 * - max_rays
   - |int|
   - Rays cast in one pass; larger images are rendered in bands of rows so that
     2048² pixels at 64 spp do not need gigabytes of ray state.  Default 2**22.
 * - jitter
   - |bool|
   - Jitter every sample inside its stratum with a PCG32 stream seeded by the
     ``seed`` given to ``render``.  Default false: samples sit at the centres of
     a kx × ky grid of strata (kx·ky = spp), so the image does not depend on the
     seed at all.  Either way the same seed gives the same bytes.

Why ``render`` is overridden rather than leaving the work to the film: a film's
reconstruction filter (Mitsuba's default is ``gaussian``) spreads a sample over
neighbouring pixels, so an edge pixel would not report its own coverage, and a
``box`` filter would be needed on every film a user builds.  Here the samples of
a pixel are generated inside that pixel (relative to the film's crop window, as
Mitsuba's own sampling integrators do) and reduced with ``dr.block_reduce``; the
film's size and crop window are read, its filter and pixel format are ignored.
:meth:`sample` is still implemented (hit = 1, miss = 0) so the integrator behaves
like any other ``SamplingIntegrator`` when a caller drives it through a film;
use a ``box`` rfilter then.

Spp need not be a square: spp = kx·ky with kx the largest divisor of spp not
above √spp (8 → 2 × 4 strata; a prime spp gives 1 × spp strips).

``mi.render`` returns a ``(height, width, 1)`` float32 tensor of coverage in
[0, 1].  Which shapes count as vegetation is every shape by default; a scene
that also holds background shapes (a soil mesh, a ridge) can declare them
through :meth:`set_vegetation`, after which a ray whose *first* hit is a
background shape counts as a gap.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

PLUGIN_NAME = "coverage"


def strata(spp: int) -> tuple[int, int]:
    """(kx, ky) with kx·ky = spp and kx the largest divisor of spp ≤ √spp."""
    if spp < 1:
        raise ValueError(f"coverage: spp must be ≥ 1, got {spp}")
    kx = int(np.sqrt(spp))
    while spp % kx:
        kx -= 1
    return kx, spp // kx


class CoverageIntegrator(mi.SamplingIntegrator):
    """Per-pixel vegetation coverage of the primary rays (see module docstring)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.max_rays = int(props.get("max_rays", 2**22))
        self.jitter = bool(props.get("jitter", False))
        if self.max_rays < 1:
            raise ValueError(f"coverage: max_rays must be ≥ 1, got {self.max_rays}")
        self._veg: mi.Bool | None = None  # None: every shape is vegetation

    def set_vegetation(self, is_vegetation: np.ndarray | None) -> None:
        """Declare which shapes are vegetation, indexed by Dr.Jit registry id.

        ``None`` (or all true) restores the fast path where any hit counts.
        """
        if is_vegetation is None or bool(np.all(is_vegetation)):
            self._veg = None
        else:
            self._veg = mi.Bool(np.ascontiguousarray(is_vegetation, bool))

    def _hit(self, scene: mi.Scene, ray: mi.Ray3f, active=True) -> mi.Bool:
        if self._veg is None:
            return scene.ray_test(ray, active)  # any-hit query: cheapest Embree call
        pi = scene.ray_intersect_preliminary(ray, coherent=True, active=active)
        valid = pi.is_valid()
        sid = dr.reinterpret_array(mi.UInt32, pi.shape)
        return valid & dr.gather(mi.Bool, self._veg, sid, valid)

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """1 where ``ray`` meets vegetation, else 0 (for film-driven rendering)."""
        hit = self._hit(scene, mi.Ray3f(ray), active)
        return mi.Spectrum(dr.select(hit, 1.0, 0.0)), mi.Bool(active), []

    def coverage(self, scene: mi.Scene, sensor: mi.Sensor | int = 0, seed: int = 0,
                 spp: int = 0) -> np.ndarray:
        """Coverage of every pixel of ``sensor``'s crop window as a (height, width) float32 array."""
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        spp = int(spp) or int(sensor.sampler().sample_count())
        kx, ky = strata(spp)
        film = sensor.film()
        width, height = (int(v) for v in film.crop_size())
        rows_per_pass = max(1, min(height, self.max_rays // (width * spp)))
        out = np.empty((height, width), np.float32)
        for row0 in range(0, height, rows_per_pass):
            rows = min(rows_per_pass, height - row0)
            n = rows * width * spp
            idx = dr.arange(mi.UInt32, n)
            pix = idx // spp if spp > 1 else idx
            sub = idx % spp if spp > 1 else mi.UInt32(0)
            ox, oy = mi.Float(sub % kx) + 0.5, mi.Float(sub // kx) + 0.5
            if self.jitter:
                # One stream per sample, keyed by (seed, absolute sample index) as
                # Mitsuba's independent sampler does: passes do not change the result.
                gidx = idx + row0 * width * spp
                rng = mi.PCG32(size=n)
                # seed() rather than the constructor, which would add arange(n) per pass
                rng.seed(mi.sample_tea_64(mi.UInt32(int(seed) & 0xFFFFFFFF), gidx), mi.UInt64(gidx))
                ox = ox + rng.next_float32() - 0.5
                oy = oy + rng.next_float32() - 0.5
            x = mi.Float(pix % width) + ox / kx
            y = mi.Float(row0 + pix // width) + oy / ky
            pos = mi.Vector2f(x / width, y / height)
            ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Vector2f(0.5, 0.5))
            hit = dr.select(self._hit(scene, ray), 1.0, 0.0)
            cov = dr.block_reduce(dr.ReduceOp.Add, hit, spp) / spp if spp > 1 else hit
            out[row0:row0 + rows] = cov.numpy().reshape(rows, width)  # numpy() is a view: copied here
        return out

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        """For ``mi.render``: a (height, width, 1) tensor of coverage in [0, 1]."""
        cov = self.coverage(scene, sensor, int(seed), int(spp))
        return mi.TensorXf(cov[:, :, None])

    def aov_names(self):
        return ["coverage"]

    def to_string(self) -> str:
        return f"CoverageIntegrator[max_rays={self.max_rays}, jitter={self.jitter}]"


def register() -> None:
    mi.register_integrator(PLUGIN_NAME, lambda props: CoverageIntegrator(props))
