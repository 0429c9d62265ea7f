"""LiDAR sensors as Mitsuba sensor plugins: SIMLIDAR's tractor scanner and general beam patterns.

Both fire an N × M grid of beams: row i is a platform pose (a tractor position, a
tripod azimuth, an aircraft scan line), column k a beam angle within it.  The film is
M × N (width = columns, height = rows).  Beam (i, k) starts at ``origin[i]`` and
points along ``R_z(yaw[i]) · dir[k]``: a platform-frame direction turned about the
vertical by the pose's yaw.  All tables are computed in float64 on the host (scene
origin already subtracted) and rounded once, so θ = 0 and ±90° give exactly
horizontal and vertical beams and yaw = 0 leaves directions untouched.

``lidar_pattern`` receives its tables from Python (:meth:`PatternLidar.set_tables`,
used by :mod:`simlidar_mi.lidar.platforms`); ``tractor_lidar`` builds SIMLIDAR's tables
from scalar properties:

.. pluginparameters::

 * - n_positions, n_angles
   - |int|
   - N positions along y and M angles per sweep.
 * - y_start, dy, gap
   - |float|, |float|, |int|
   - Beam-centre y of the first sweep, its step (metres, scene frame), and the paper's
     gap parameter, the sweeps skipped between two recorded ones: y_i = y_start + i·(gap+1)·dy.
 * - theta_min_deg, dtheta_deg
   - |float|
   - Elevation θ of the first beam and the angular step; direction (cos θ, 0, sin θ).
 * - x0, z0
   - |float|
   - Scanner line in the scene frame.
 * - footprint
   - |int|
   - Precision P of the paper's dot matrix: beam (i, k) covers [y_i ± dy/2] × [θ_k ± Δθ/2]
     and sub-beam (a, b), 0 ≤ a, b ≤ P, sits at offsets (a/P − 1/2, b/P − 1/2) of a step.
     P = 0: one ray at the beam centre.

Moving platforms (:meth:`PatternLidar.set_motion`): beam (i, k) starts at
``origin[i] + velocity · col_time[k]``, the position the platform has when the column fires.
Per-beam directions (:meth:`PatternLidar.set_beam_dirs`, the rosette): beam (i, k) points
along ``dirs[i·M + k]`` instead of the row/column product.  Only patterns that set them pay
for either.

``sample_ray`` reads the beam from ``sample2`` (snapped, so jitter never moves a beam
into its neighbour) and the sub-beam from ``sample3``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from simlidar_mi.lidar.platforms import elevation_dirs, sub_offsets

PLUGIN_NAME = "tractor_lidar"
PATTERN_PLUGIN_NAME = "lidar_pattern"


def beam_tables(n_positions: int, n_angles: int, y_start: float, dy: float, gap: int,
                theta_min_deg: float, dtheta_deg: float, footprint: int):
    """SIMLIDAR's sub-beam directions (M·(P+1), 3) and y positions (N·(P+1),), float64."""
    frac = sub_offsets(footprint)
    theta_deg = theta_min_deg + np.arange(n_angles)[:, None] * dtheta_deg + frac[None, :] * dtheta_deg
    y = y_start + np.arange(n_positions)[:, None] * (gap + 1) * dy + frac[None, :] * dy
    return elevation_dirs(theta_deg.ravel()), y.ravel()


class PatternLidar(mi.Sensor):
    """N × M beams from per-row origins and yaws and per-column directions (module docstring).

    Properties: ``n_positions`` (N), ``n_angles`` (M), ``footprint`` (P); the tables come
    later through :meth:`set_tables`.
    """

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.n_positions = int(props.get("n_positions"))
        self.n_angles = int(props.get("n_angles"))
        self.footprint = int(props.get("footprint", 0))
        size = self.film().size()
        if (size[0], size[1]) != (self.n_angles, self.n_positions):
            raise ValueError(f"{type(self).__name__}: film must be {self.n_angles}×{self.n_positions} "
                             f"(angles × positions), got {size[0]}×{size[1]}")
        self._has_yaw = False
        self._velocity = None
        self._beam_dirs = None
        # Index of this sensor's beam 0 in the whole scan (a tile's sensor: simlidar_mi.lidar.scan
        # sets it), so traces align on the whole scan's packets (simlidar_mi.lidar.packets).
        self.first_beam = 0

    def set_motion(self, col_time_s: np.ndarray, velocity_m_s) -> None:
        """Column delays (M·(P+1),) in seconds and the platform velocity (3,) in m/s, float64;
        the offset velocity·delay is computed on the host and rounded once."""
        t = np.asarray(col_time_s, np.float64).ravel()
        if len(t) != self.n_angles * (self.footprint + 1):
            raise ValueError(f"{type(self).__name__}: expected {self.n_angles * (self.footprint + 1)} "
                             f"column times, got {len(t)}")
        v = np.asarray(velocity_m_s, np.float64).ravel()
        self._velocity = [mi.Float(np.ascontiguousarray(t * v[j], np.float32)) for j in range(3)]

    def set_beam_dirs(self, directions: np.ndarray) -> None:
        """World directions of every beam (N·M, 3), float64, row-major (footprint 0 only)."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        if self.footprint or len(d) != self.n_positions * self.n_angles:
            raise ValueError(f"{type(self).__name__}: per-beam directions need footprint 0 and "
                             f"{self.n_positions * self.n_angles} rows, got {len(d)}")
        self._beam_dirs = [mi.Float(np.ascontiguousarray(d[:, j], np.float32)) for j in range(3)]

    def set_tables(self, origins: np.ndarray, directions: np.ndarray, yaw_rad: np.ndarray | None = None) -> None:
        """Sub-beam origins (N·(P+1), 3), platform-frame directions (M·(P+1), 3) and optional
        yaw per origin (N·(P+1),), all float64 in the scene frame."""
        P1 = self.footprint + 1
        origins = np.asarray(origins, np.float64).reshape(-1, 3)
        directions = np.asarray(directions, np.float64).reshape(-1, 3)
        if len(origins) != self.n_positions * P1 or len(directions) != self.n_angles * P1:
            raise ValueError(f"{type(self).__name__}: expected {self.n_positions * P1} origins and "
                             f"{self.n_angles * P1} directions, got {len(origins)} and {len(directions)}")
        self._o = [mi.Float(np.ascontiguousarray(origins[:, j], np.float32)) for j in range(3)]
        self._d = [mi.Float(np.ascontiguousarray(directions[:, j], np.float32)) for j in range(3)]
        self._has_yaw = yaw_rad is not None and bool(np.any(np.asarray(yaw_rad) != 0))
        if self._has_yaw:
            yaw = np.asarray(yaw_rad, np.float64).ravel()
            self._cos = mi.Float(np.cos(yaw).astype(np.float32))
            self._sin = mi.Float(np.sin(yaw).astype(np.float32))

    def sub_beam_count(self) -> int:
        return (self.footprint + 1) ** 2

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        k = dr.minimum(mi.UInt32(sample2.x * self.n_angles), self.n_angles - 1)
        i = dr.minimum(mi.UInt32(sample2.y * self.n_positions), self.n_positions - 1)
        if self.footprint > 0:
            b = mi.UInt32(dr.round(sample3.x * self.footprint))
            a = mi.UInt32(dr.round(sample3.y * self.footprint))
        else:
            a = b = mi.UInt32(0)
        return self._ray(i, k, a, b, time, active), mi.Spectrum(1.0)

    def beam_ray(self, beam, sub=None):
        """The ray of beam index ``beam`` (row-major: position, angle) through dot-matrix
        sub-beam ``sub`` (a·(P+1) + b; None: the beam's centre), from the integers directly:
        the range integrator's path, with no round trip through film coordinates (the same
        ray as :meth:`sample_ray` at the beam's centre sample, for less arithmetic)."""
        M, P1 = self.n_angles, self.footprint + 1
        i, k = beam // M, beam % M
        if sub is None or P1 == 1:
            a = b = mi.UInt32(0)
        else:
            a, b = sub // P1, sub % P1
        return self._ray(i, k, a, b, 0.0, True)

    def _ray(self, i, k, a, b, time, active):
        P1 = self.footprint + 1
        row, col = i * P1 + a, k * P1 + b
        o = mi.Point3f(*(dr.gather(mi.Float, t, row, active) for t in self._o))
        if self._velocity is not None:  # only moving platforms pay for the per-column offset
            o += mi.Vector3f(*(dr.gather(mi.Float, t, col, active) for t in self._velocity))
        if self._beam_dirs is not None:
            beam = i * self.n_angles + k
            return mi.Ray3f(o, mi.Vector3f(*(dr.gather(mi.Float, t, beam, active) for t in self._beam_dirs)), time)
        dx, dy, dz = (dr.gather(mi.Float, t, col, active) for t in self._d)
        if self._has_yaw:  # only platforms that turn pay for the rotation
            c = dr.gather(mi.Float, self._cos, row, active)
            s = dr.gather(mi.Float, self._sin, row, active)
            dx, dy = c * dx - s * dy, s * dx + c * dy
        return mi.Ray3f(o, mi.Vector3f(dx, dy, dz), time)

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        return mi.RayDifferential3f(ray), weight

    def needs_aperture_sample(self) -> bool:
        return self.footprint > 0

    def to_string(self) -> str:
        return f"{type(self).__name__}[N={self.n_positions}, M={self.n_angles}, P={self.footprint}]"


class TractorLidar(PatternLidar):
    """Lateral 2D LiDAR on a tractor moving along +y (SIMLIDAR; module docstring)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.y_start = float(props.get("y_start", 0.0))
        self.dy = float(props.get("dy", 0.002))
        self.gap = int(props.get("gap", 0))
        self.theta_min_deg = float(props.get("theta_min_deg"))
        self.dtheta_deg = float(props.get("dtheta_deg", 0.25))
        self.x0 = float(props.get("x0", 0.0))
        self.z0 = float(props.get("z0", 1.0))
        dirs, y = beam_tables(self.n_positions, self.n_angles, self.y_start, self.dy, self.gap,
                              self.theta_min_deg, self.dtheta_deg, self.footprint)
        origins = np.stack([np.full_like(y, self.x0), y, np.full_like(y, self.z0)], axis=1)
        self.set_tables(origins, dirs)

    def bbox(self) -> mi.ScalarBoundingBox3f:
        y1 = self.y_start + (self.n_positions - 1) * (self.gap + 1) * self.dy
        return mi.ScalarBoundingBox3f([self.x0, self.y_start, self.z0], [self.x0, y1, self.z0])

    def to_string(self) -> str:
        return (f"TractorLidar[N={self.n_positions}, M={self.n_angles}, x0={self.x0}, z0={self.z0}, "
                f"y_start={self.y_start}, dy={self.dy}, gap={self.gap}, "
                f"theta_min_deg={self.theta_min_deg}, dtheta_deg={self.dtheta_deg}, P={self.footprint}]")


def register() -> None:
    mi.register_sensor(PLUGIN_NAME, lambda props: TractorLidar(props))
    mi.register_sensor(PATTERN_PLUGIN_NAME, lambda props: PatternLidar(props))
