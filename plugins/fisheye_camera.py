"""Fisheye camera as a Mitsuba sensor plugin: hemispherical photographs of a scene.

One ray per film sample from a single centre of projection.  A sample at film position
(u, v) ∈ [0, 1]² lies at x = u·W − W/2 (to the image right), y = H/2 − v·H (to the image
top) pixels from the image centre; ρ = √(x² + y²) / R is its radius relative to the image
circle's radius R, and the lens (:mod:`simlidar_mi.canopy.fisheye_lens`) gives its angle
θ from the optical axis.  The camera-frame direction (sin θ·x/r, sin θ·y/r, cos θ) is turned
into the scene by a 3 × 3 frame computed in float64 on the host and rounded once
(:meth:`FisheyeCamera.set_frame`), so an untilted camera's axis is exactly vertical.

sin θ and cos θ are taken from ρ by the same closed forms as the float64 reference
(equisolid: s = ρ/√2, cos θ = 1 − 2s², sin θ = 2s√(1 − s²); orthographic: cos θ = √((1 − ρ)(1 + ρ));
stereographic: rational in ρ), so there is no cos of a rounded π/2 at the horizon and no
1 − cos at the zenith.  A polynomial lens is inverted by two float32 Newton steps from a
257-entry float64 table.  Samples beyond the image circle (ρ > 1: the corners of a circular
image, the rim of a pixel that straddles it) are clamped to ρ = 1 (the circle's edge, the
horizon for the standard lenses); the Python API leaves pixels whose centre lies outside
the circle out of every gap fraction.

.. pluginparameters::

 * - projection
   - |string|
   - ``equidistant``, ``equisolid``, ``orthographic``, ``stereographic``, a named lens
     (``FC-E8``, ``Sigma-8`` …) or ``polynomial`` with ``coeffs``.
 * - coeffs
   - |string|
   - Polynomial coefficients k_1 … k_n (ρ = Σ k_i θ^i, θ in radians), comma-separated.
 * - radius_px
   - |float|
   - Image circle radius R in pixels (circular format: min(W, H)/2; full frame: half the diagonal).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from simlidar_mi.canopy.fisheye_lens import closed_sin_cos, lens as make_lens

PLUGIN_NAME = "fisheye"


class FisheyeCamera(mi.Sensor):
    """Fisheye sensor (module docstring); place it with :meth:`set_frame` before rendering."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        coeffs = str(props.get("coeffs", "")).strip()
        k = [float(c) for c in coeffs.split(",")] if coeffs else None
        self.lens = make_lens(str(props.get("projection", "equidistant")), k)
        size = self.film().size()
        self.width, self.height = int(size[0]), int(size[1])
        self.radius_px = float(props.get("radius_px", 0.5 * min(self.width, self.height)))
        if not self.radius_px > 0:
            raise ValueError(f"fisheye: radius_px must be > 0, got {self.radius_px}")
        if self.lens.projection == "polynomial":
            rho, theta = self.lens.table()
            self._tab_n = len(rho)
            self._tab = mi.Float(np.ascontiguousarray(theta, np.float32))
        self.set_frame(np.zeros(3), np.eye(3))

    def set_frame(self, origin, frame) -> None:
        """Centre of projection (3,) in the scene frame (origin already subtracted) and the
        camera frame (3, 3) whose columns are the scene directions of the image right, the
        image top and the optical axis; float64, rounded once here."""
        o = np.asarray(origin, np.float64).ravel()
        m = np.asarray(frame, np.float64).reshape(3, 3)
        self._o = mi.Point3f(*(float(np.float32(v)) for v in o))
        self._m = [[float(np.float32(m[i, j])) for j in range(3)] for i in range(3)]

    def _sin_cos(self, rho):
        p = self.lens.projection
        if p == "equidistant":
            return dr.sincos(rho * (0.5 * dr.pi))
        closed = closed_sin_cos(p, rho, dr.sqrt)
        if closed is not None:
            return closed
        x = rho * (self._tab_n - 1)
        i0 = dr.minimum(mi.UInt32(x), self._tab_n - 2)
        f = x - mi.Float(i0)
        t = dr.lerp(dr.gather(mi.Float, self._tab, i0), dr.gather(mi.Float, self._tab, i0 + 1), f)
        k = self.lens.coeffs
        for _ in range(2):
            val, der = mi.Float(0.0), mi.Float(0.0)
            for i in range(len(k), 0, -1):  # Horner for ρ(t)/t and its derivative
                val = val * t + k[i - 1]
                der = der * t + i * k[i - 1]
            t = t - (val * t - rho) / der
        return dr.sincos(t)

    def direction(self, sample2):
        """Unit scene direction of film position ``sample2`` ∈ [0, 1]²."""
        x = (sample2.x - 0.5) * self.width  # subtract first: offsets near the axis keep their bits
        y = (0.5 - sample2.y) * self.height
        r = dr.sqrt(x * x + y * y)
        rho = dr.minimum(r * (1.0 / self.radius_px), 1.0)
        s, c = self._sin_cos(rho)
        inv_r = dr.select(r > 0.0, 1.0 / r, 0.0)
        dx, dy, dz = s * x * inv_r, s * y * inv_r, c
        m = self._m
        d = mi.Vector3f(m[0][0] * dx + m[0][1] * dy + m[0][2] * dz,
                        m[1][0] * dx + m[1][1] * dy + m[1][2] * dz,
                        m[2][0] * dx + m[2][1] * dy + m[2][2] * dz)
        return dr.normalize(d)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        d = self.direction(sample2)
        return mi.Ray3f(mi.Point3f(self._o), d, time), mi.Spectrum(1.0)

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        return mi.RayDifferential3f(ray), weight

    def needs_aperture_sample(self) -> bool:
        return False

    def to_string(self) -> str:
        return (f"FisheyeCamera[{self.lens.projection}{' ' + self.lens.name if self.lens.name else ''}, "
                f"{self.width}x{self.height}, R={self.radius_px}]")


def register() -> None:
    mi.register_sensor(PLUGIN_NAME, lambda props: FisheyeCamera(props))
