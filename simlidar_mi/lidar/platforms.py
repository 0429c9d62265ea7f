"""Scanner platforms: where each beam starts and where it points (HELIOS++'s scanner/platform split).

A platform turns its settings into a :class:`BeamPattern`: N rows (platform poses) ×
M columns (beam angles), in real float64 coordinates.  Row i starts at
``row_origin_m[i]`` and turns the platform-frame column directions about the vertical
by ``row_yaw_deg[i]`` (0 = platform x along world +x).  The tractor LiDAR is one such
pattern (:meth:`simlidar_mi.lidar.scan.ScanSettings.pattern`); the others here are

``static_pattern``
    a tripod: rows are azimuth steps (3D) or one azimuth (2D), columns elevations;
``path_patterns``
    a straight multi-leg ground path: one tractor-like pattern per leg, looking to one
    side of the direction of travel;
``airborne_pattern``
    a nadir line scanner on an aircraft: rows are scan lines along the track, columns
    the pulses across the swath (SIMLIDAR's stated future work).

Sub-beams of a footprint P > 0 sit at −1/2 … +1/2 of a step in both the row
coordinate (origin moves along the platform's row step) and the column angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError


def sub_offsets(footprint: int) -> np.ndarray:
    P = int(footprint)
    return (np.arange(P + 1) / P - 0.5) if P > 0 else np.zeros(1)


def elevation_dirs(theta_deg) -> np.ndarray:
    """(cos θ, 0, sin θ) in float64, exactly vertical at ±90° (cos 90° is 6e-17, not 0)."""
    theta_deg = np.asarray(theta_deg, np.float64)
    th = np.deg2rad(theta_deg)
    d = np.stack([np.cos(th), np.zeros_like(th), np.sin(th)], axis=-1)
    vertical = np.isclose(np.abs(theta_deg), 90.0, rtol=0, atol=1e-12)
    d[vertical] = 0.0
    d[vertical, 2] = np.sign(theta_deg[vertical])
    return d


def swath_dirs(alpha_deg) -> np.ndarray:
    """Nadir-looking directions tilted by α across track: (sin α, 0, −cos α)."""
    a = np.deg2rad(np.asarray(alpha_deg, np.float64))
    d = np.stack([np.sin(a), np.zeros_like(a), -np.cos(a)], axis=-1)
    d[np.asarray(alpha_deg) == 0] = [0.0, 0.0, -1.0]
    return d


@dataclass(frozen=True)
class BeamPattern:
    """An N × M grid of beams in real coordinates (module docstring).

    A beam's footprint spans ``row_span_m`` (a vector: the platform's step) and
    ``row_span_deg`` of yaw across rows, and ``col_span_deg`` across columns; a footprint
    P > 0 spreads its sub-beams over ±1/2 of those spans.
    """

    kind: str
    row_origin_m: np.ndarray     # (N, 3) float64
    row_yaw_deg: np.ndarray      # (N,)
    col_angle_deg: np.ndarray    # (M,) the angle that defines each column
    col_dir: np.ndarray          # (M, 3) platform-frame unit directions
    row_span_m: np.ndarray       # (3,) origin offset spanned by one beam's footprint
    col_span_deg: float
    footprint: int = 0
    row_coord: np.ndarray | None = None  # (N,) a plotting coordinate (y, azimuth, along-track m)
    row_label: str = "row"
    col_label: str = "angle (°)"
    escape_m: float = 1000.0
    ground: bool = True
    ground_z_m: float = 0.0
    meta: dict = field(default_factory=dict)
    row_span_deg: float = 0.0    # yaw spanned by one beam's footprint (static 3D scans)
    hit_rule: str = "fraction"   # footprint: "any" sub-beam on vegetation makes a hit (paper §3.1)

    @property
    def n_rows(self) -> int:
        return len(self.row_origin_m)

    @property
    def n_cols(self) -> int:
        return len(self.col_angle_deg)

    @property
    def n_beams(self) -> int:
        return self.n_rows * self.n_cols

    def world_dirs(self) -> np.ndarray:
        """(N, M, 3) beam-centre directions in the world frame."""
        yaw = np.deg2rad(self.row_yaw_deg)
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        d = self.col_dir[None, :, :]
        return np.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1],
                         np.broadcast_to(d[..., 2], (len(yaw), len(self.col_dir)))], axis=-1)

    def sub_tables(self, origin_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sensor tables relative to the scene origin: origins (N·(P+1), 3), platform-frame
        directions (M·(P+1), 3) and yaw in radians (N·(P+1),)."""
        frac = sub_offsets(self.footprint)
        o = (self.row_origin_m[:, None, :] + frac[None, :, None] * self.row_span_m[None, None, :]
             - np.asarray(origin_m, np.float64)).reshape(-1, 3)
        yaw = np.deg2rad(self.row_yaw_deg[:, None] + frac[None, :] * self.row_span_deg).ravel()
        ang = (self.col_angle_deg[:, None] + frac[None, :] * self.col_span_deg).ravel()
        dirs = (swath_dirs(ang) if self.meta.get("angle_kind") == "swath" else elevation_dirs(ang))
        return o, dirs, yaw

    def to_dict(self) -> dict:
        return {"kind": self.kind, "n_rows": self.n_rows, "n_cols": self.n_cols,
                "footprint": self.footprint, "hit_rule": self.hit_rule, "col_span_deg": self.col_span_deg,
                "row_span_deg": self.row_span_deg,
                "col_angle_first_deg": float(self.col_angle_deg[0]),
                "row_origin_first_m": self.row_origin_m[0].tolist(),
                "row_origin_last_m": self.row_origin_m[-1].tolist(),
                "row_span_m": self.row_span_m.tolist(), "escape_m": self.escape_m,
                "ground": self.ground, "ground_z_m": self.ground_z_m, **self.meta}


def _steps(lo: float, hi: float, step: float, key: str, source, inclusive: bool = True) -> np.ndarray:
    """lo, lo+step, … up to hi (inclusive) or below it (half-open, for full turns of azimuth)."""
    if not (math.isfinite(step) and step > 0):
        raise ConfigError("the step must be > 0", file=source, key=key, value=step)
    if not hi > lo:
        raise ConfigError(f"the range must be increasing ({lo} … {hi})", file=source, key=key, value=step)
    n = int(math.floor((hi - lo) / step + 1e-9)) + (1 if inclusive else 0)
    if not inclusive and lo + n * step < hi - 1e-9 * step:
        n += 1
    return lo + np.arange(n) * step


def static_pattern(position_m, elevation_deg: tuple[float, float, float],
                   azimuth_deg: tuple[float, float, float] | float = 0.0, *, footprint: int = 0,
                   escape_m: float = 1000.0, ground: bool = True, ground_z_m: float = 0.0,
                   source=None) -> BeamPattern:
    """A tripod scanner: elevations (min, max, step) in degrees, both ends included; azimuth a
    single value (2D profile) or (start, stop, step) with stop excluded (3D, so [0, 360, 1]
    gives 360 rows).  Azimuth 0 looks along +x, 90 along +y."""
    pos = np.asarray(position_m, np.float64)
    el = _steps(*elevation_deg, "platform.elevation_deg", source)
    if np.any(np.abs(el) > 90):
        raise ConfigError("elevations must lie in [-90, 90] degrees", file=source,
                          key="platform.elevation_deg", value=list(elevation_deg))
    if np.isscalar(azimuth_deg):
        az, az_step = np.array([float(azimuth_deg)]), 0.0
    else:
        az = _steps(*azimuth_deg, "platform.azimuth_deg", source, inclusive=False)
        az_step = float(azimuth_deg[2])
    return BeamPattern("static", np.repeat(pos[None, :], len(az), axis=0), az, el, elevation_dirs(el),
                       np.zeros(3), float(elevation_deg[2]), footprint, az, "azimuth (°)",
                       "elevation (°)", escape_m, ground, ground_z_m,
                       {"angle_kind": "elevation"}, az_step)


def path_patterns(waypoints_m, step_m: float, elevation_deg: tuple[float, float, float], *,
                  side: str = "right", footprint: int = 0, escape_m: float = 1000.0,
                  ground: bool = True, ground_z_m: float = 0.0, source=None) -> list[BeamPattern]:
    """A ground vehicle along straight legs between waypoints (x, y, z), sweeping elevations in
    the vertical plane perpendicular to its travel, on its ``side`` ('right' or 'left')."""
    wp = np.asarray(waypoints_m, np.float64)
    if wp.ndim != 2 or wp.shape[1] != 3 or len(wp) < 2:
        raise ConfigError("waypoints must be a list of at least two [x, y, z] points", file=source,
                          key="platform.waypoints_m", value=np.asarray(waypoints_m).tolist())
    if side not in ("right", "left"):
        raise ConfigError("side must be 'right' or 'left'", file=source, key="platform.side", value=side)
    el = _steps(*elevation_deg, "platform.elevation_deg", source)
    legs = []
    for j in range(len(wp) - 1):
        a, b = wp[j], wp[j + 1]
        length = float(np.linalg.norm(b - a))
        if length < step_m:
            raise ConfigError(f"leg {j} is shorter than one step", file=source,
                              key="platform.waypoints_m", value=[a.tolist(), b.tolist()])
        unit = (b - a) / length
        s = _steps(0.0, length, step_m, "platform.step_m", source)
        heading = math.degrees(math.atan2(unit[1], unit[0]))
        yaw = heading - 90.0 if side == "right" else heading + 90.0
        legs.append(BeamPattern(f"path_leg{j}", a[None, :] + s[:, None] * unit[None, :],
                                np.full(len(s), yaw), el, elevation_dirs(el), unit * step_m,
                                float(elevation_deg[2]), footprint, s, "distance along leg (m)",
                                "elevation (°)", escape_m, ground, ground_z_m,
                                {"angle_kind": "elevation", "leg": j, "heading_deg": heading, "side": side}))
    return legs


def airborne_pattern(start_xy_m, end_xy_m, altitude_m: float, swath_deg: float, speed_m_s: float,
                     pulse_rate_hz: float, pulses_per_line: int, *, footprint: int = 0,
                     escape_m: float = 10000.0, ground: bool = True, ground_z_m: float = 0.0,
                     source=None) -> BeamPattern:
    """A nadir line scanner flying a straight line at ``altitude_m`` above the ground.

    Each line fires ``pulses_per_line`` pulses evenly across ±swath/2 (beam centres at
    the middles of equal angular steps); lines follow at pulse_rate / pulses_per_line Hz,
    so the ground advances speed / line_rate between lines.  A line is fired from one
    platform position (its duration is far shorter than the step between lines).
    """
    for key, v in (("platform.altitude_m", altitude_m), ("platform.speed_m_s", speed_m_s),
                   ("platform.pulse_rate_hz", pulse_rate_hz), ("platform.swath_deg", swath_deg)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError("must be a finite number > 0", file=source, key=key, value=v)
    if swath_deg >= 180:
        raise ConfigError("the swath must be below 180°", file=source, key="platform.swath_deg", value=swath_deg)
    if int(pulses_per_line) < 1:
        raise ConfigError("must be ≥ 1", file=source, key="platform.pulses_per_line", value=pulses_per_line)
    a = np.array([*start_xy_m, 0.0], np.float64)
    b = np.array([*end_xy_m, 0.0], np.float64)
    length = float(np.linalg.norm(b - a))
    M = int(pulses_per_line)
    line_rate = pulse_rate_hz / M
    step = speed_m_s / line_rate
    if length < step:
        raise ConfigError(f"the flight line ({length:.3g} m) is shorter than one line step ({step:.3g} m)",
                          file=source, key="platform.end_xy_m", value=list(end_xy_m))
    unit = (b - a) / length
    s = _steps(0.0, length, step, "platform.speed_m_s", source)
    origins = a[None, :] + s[:, None] * unit[None, :]
    origins[:, 2] = ground_z_m + altitude_m
    dalpha = swath_deg / M
    alpha = -swath_deg / 2 + (np.arange(M) + 0.5) * dalpha
    heading = math.degrees(math.atan2(unit[1], unit[0]))
    return BeamPattern("airborne", origins, np.full(len(s), heading - 90.0), alpha, swath_dirs(alpha),
                       unit * step, dalpha, footprint, s, "distance along track (m)",
                       "swath angle (°)", escape_m, ground, ground_z_m,
                       {"angle_kind": "swath", "altitude_m": altitude_m, "speed_m_s": speed_m_s,
                        "pulse_rate_hz": pulse_rate_hz, "line_rate_hz": line_rate,
                        "line_step_m": step, "heading_deg": heading})
