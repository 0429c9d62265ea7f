"""Tractor-mounted 2D LiDAR sensor (SIMLIDAR's lateral scanner) as a Mitsuba sensor plugin.

The scanner sits at (x0, y_i, z0) and sweeps its beam in the XZ plane, at elevation
θ above the horizon, direction (cos θ, 0, sin θ): θ < 0 looks down at the ground,
θ > 0 up into the canopy.  The film is M × N (width = angles, height = positions), so
pixel (k, i) is beam θ_k at position y_i, and the (N, M) range matrix l_ik comes out
row = position, column = angle.

.. pluginparameters::

 * - n_positions, n_angles
   - |int|
   - N positions along y and M angles per sweep.
 * - y_start, dy, gap
   - |float|, |float|, |int|
   - Beam-centre position of the first sweep, its step (metres, scene frame), and the
     paper's gap parameter: sweeps skipped between two recorded ones, so
     y_i = y_start + i·(gap+1)·dy.
 * - theta_min_deg, dtheta_deg
   - |float|
   - Beam-centre angle of the first beam and the angular step.
 * - x0, z0
   - |float|
   - Scanner line in the scene frame (the scene's float64 origin already subtracted).
 * - footprint
   - |int|
   - Precision P of the paper's dot matrix: beam (i, k) covers
     [y_i − dy/2, y_i + dy/2] × [θ_k − Δθ/2, θ_k + Δθ/2] and sub-beam (a, b), 0 ≤ a, b ≤ P,
     sits at offsets (a/P − 1/2, b/P − 1/2) of a step.  P = 0: one ray at the beam centre.

``sample_ray`` reads the pixel from ``sample2`` (snapped to the beam, so jitter never
moves a beam into its neighbour) and the sub-beam from ``sample3``; angles and
positions come from tables computed in float64 on the host, so θ = 0 and ±90° give
exactly horizontal and vertical beams.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

PLUGIN_NAME = "tractor_lidar"


def beam_tables(n_positions: int, n_angles: int, y_start: float, dy: float, gap: int,
                theta_min_deg: float, dtheta_deg: float, footprint: int):
    """Float64 sub-beam tables: (cos θ, sin θ) of shape (M·(P+1),) and y of shape (N·(P+1),)."""
    P = int(footprint)
    frac = (np.arange(P + 1) / P - 0.5) if P > 0 else np.zeros(1)
    theta_deg = theta_min_deg + np.arange(n_angles)[:, None] * dtheta_deg + frac[None, :] * dtheta_deg
    theta = np.deg2rad(theta_deg).ravel()
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    # cos(90°) is 6e-17 in float64, not 0: make vertical beams exactly vertical.
    exact = np.isclose(np.abs(theta_deg.ravel()), 90.0, rtol=0, atol=1e-12)
    cos_t[exact] = 0.0
    sin_t[exact] = np.sign(theta_deg.ravel()[exact])
    y = y_start + np.arange(n_positions)[:, None] * (gap + 1) * dy + frac[None, :] * dy
    return cos_t, sin_t, y.ravel()


class TractorLidar(mi.Sensor):
    """Lateral 2D LiDAR on a tractor moving along +y (see module docstring)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.n_positions = int(props.get("n_positions"))
        self.n_angles = int(props.get("n_angles"))
        self.y_start = float(props.get("y_start", 0.0))
        self.dy = float(props.get("dy", 0.002))
        self.gap = int(props.get("gap", 0))
        self.theta_min_deg = float(props.get("theta_min_deg"))
        self.dtheta_deg = float(props.get("dtheta_deg", 0.25))
        self.x0 = float(props.get("x0", 0.0))
        self.z0 = float(props.get("z0", 1.0))
        self.footprint = int(props.get("footprint", 0))
        size = self.film().size()
        if (size[0], size[1]) != (self.n_angles, self.n_positions):
            raise ValueError(f"tractor_lidar: film must be {self.n_angles}×{self.n_positions} "
                             f"(angles × positions), got {size[0]}×{size[1]}")
        cos_t, sin_t, y = beam_tables(self.n_positions, self.n_angles, self.y_start, self.dy,
                                      self.gap, self.theta_min_deg, self.dtheta_deg, self.footprint)
        self._cos = mi.Float(cos_t.astype(np.float32))
        self._sin = mi.Float(sin_t.astype(np.float32))
        self._y = mi.Float(y.astype(np.float32))

    def sub_beam_count(self) -> int:
        return (self.footprint + 1) ** 2

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        P1 = self.footprint + 1
        k = dr.minimum(mi.UInt32(sample2.x * self.n_angles), self.n_angles - 1)
        i = dr.minimum(mi.UInt32(sample2.y * self.n_positions), self.n_positions - 1)
        if self.footprint > 0:
            b = mi.UInt32(dr.round(sample3.x * self.footprint))
            a = mi.UInt32(dr.round(sample3.y * self.footprint))
        else:
            a = b = mi.UInt32(0)
        cos_t = dr.gather(mi.Float, self._cos, k * P1 + b, active)
        sin_t = dr.gather(mi.Float, self._sin, k * P1 + b, active)
        y = dr.gather(mi.Float, self._y, i * P1 + a, active)
        origin = mi.Point3f(self.x0, y, self.z0)
        ray = mi.Ray3f(origin, mi.Vector3f(cos_t, 0.0, sin_t), time)
        return ray, mi.Spectrum(1.0)

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        return mi.RayDifferential3f(ray), weight

    def needs_aperture_sample(self) -> bool:
        return self.footprint > 0

    def bbox(self) -> mi.ScalarBoundingBox3f:
        y1 = self.y_start + (self.n_positions - 1) * (self.gap + 1) * self.dy
        return mi.ScalarBoundingBox3f([self.x0, self.y_start, self.z0], [self.x0, y1, self.z0])

    def to_string(self) -> str:
        return (f"TractorLidar[N={self.n_positions}, M={self.n_angles}, x0={self.x0}, z0={self.z0}, "
                f"y_start={self.y_start}, dy={self.dy}, gap={self.gap}, "
                f"theta_min_deg={self.theta_min_deg}, dtheta_deg={self.dtheta_deg}, P={self.footprint}]")


def register() -> None:
    mi.register_sensor(PLUGIN_NAME, lambda props: TractorLidar(props))
