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
    the pulses across the swath (SIMLIDAR's stated future work);
``rotating_patterns``
    a spinning multi-channel scanner (Velodyne/Ouster style): rows are firing blocks
    (the head's azimuth is the row's yaw), columns the channels; static or driven along
    straight legs;
``rosette_patterns``
    a two-prism (Risley) scanner drawing a non-repetitive rosette (Livox Mid-70 style):
    rows are 0.1 s frames, columns the pulses of a frame, each beam with its own direction.

Timing (optional): ``row_time_s`` (N,) and ``col_time_s`` (M,) give beam (i, k) the
emission time row_time_s[i] + col_time_s[k] (seconds from the first beam), and
``velocity_m_s`` (3,) moves its origin to row_origin_m[i] + velocity·col_time_s[k]:
a sweep fired while the platform moves.  None (every pattern built before these
existed, and the tractor without a pulse rate) fires each row from one pose.

Sub-beams of a footprint P > 0 sit at −1/2 … +1/2 of a step in both the row
coordinate (origin moves along the platform's row step) and the column angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..config.keys import SECTIONS
from ..errors import ConfigError

#: The beam limit of a pattern made without one (``max_beams=None``): [scan] max_beams's default.
DEFAULT_MAX_BEAMS = SECTIONS["scan"]["max_beams"].default


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
    row_time_s: np.ndarray | None = None    # (N,) emission time of each row's column-0 beam
    col_time_s: np.ndarray | None = None    # (M,) delay of column k within its row
    velocity_m_s: np.ndarray | None = None  # (3,) platform velocity while a row fires
    col_azimuth_deg: np.ndarray | None = None  # (M,) platform-frame azimuth of each column (spinning heads)
    beam_dirs: np.ndarray | None = None     # (N, M, 3) world directions when no row/column split exists (rosette)

    @property
    def n_rows(self) -> int:
        return len(self.row_origin_m)

    @property
    def n_cols(self) -> int:
        return len(self.col_angle_deg)

    @property
    def n_beams(self) -> int:
        return self.n_rows * self.n_cols

    @property
    def moving(self) -> bool:
        """True when beams of one row start from different positions (velocity × column delay)."""
        return self.velocity_m_s is not None and self.col_time_s is not None

    def rows(self, r0: int, r1: int) -> "BeamPattern":
        """Rows r0 … r1 − 1 of this pattern (a tile of a scan split over a cluster): every
        per-row array sliced, columns and timing per column unchanged, so each beam of the
        tile is the same ray as in the whole pattern."""
        if not 0 <= r0 < r1 <= self.n_rows:
            raise ValueError(f"rows {r0}…{r1} outside 0…{self.n_rows}")
        cut = lambda a: None if a is None else a[r0:r1]  # noqa: E731
        return replace(self, row_origin_m=self.row_origin_m[r0:r1], row_yaw_deg=self.row_yaw_deg[r0:r1],
                       row_coord=cut(self.row_coord), row_time_s=cut(self.row_time_s),
                       beam_dirs=cut(self.beam_dirs))

    def beam_times_s(self) -> np.ndarray | None:
        """(N, M) float64 emission time of every beam (seconds from the first), or None
        for patterns without timing."""
        if self.row_time_s is None:
            return None
        col = self.col_time_s if self.col_time_s is not None else np.zeros(self.n_cols)
        return np.asarray(self.row_time_s, np.float64)[:, None] + np.asarray(col, np.float64)[None, :]

    def beam_origins_m(self) -> np.ndarray:
        """(N, M, 3) real origin of every beam (broadcast (N, 1, 3) when a row fires from one pose)."""
        o = self.row_origin_m[:, None, :]
        if not self.moving:
            return o
        return o + self.col_time_s[None, :, None] * np.asarray(self.velocity_m_s, np.float64)[None, None, :]

    def world_dirs(self) -> np.ndarray:
        """(N, M, 3) beam-centre directions in the world frame."""
        if self.beam_dirs is not None:
            return self.beam_dirs
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
        kind = self.meta.get("angle_kind")
        if kind == "direction":  # per-beam directions (set_beam_dirs); these are placeholders
            return o, np.repeat(self.col_dir, len(frac), axis=0), yaw
        dirs = swath_dirs(ang) if kind == "swath" else elevation_dirs(ang)
        if self.col_azimuth_deg is not None:  # a spinning head turns on while its channels fire
            phi = np.deg2rad(np.repeat(np.asarray(self.col_azimuth_deg, np.float64), len(frac)))
            c, s = np.cos(phi), np.sin(phi)
            dirs = np.stack([c * dirs[:, 0] - s * dirs[:, 1], s * dirs[:, 0] + c * dirs[:, 1], dirs[:, 2]], axis=1)
        return o, dirs, yaw

    def motion_tables(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(column delays repeated for each sub-beam (M·(P+1),), velocity (3,)) for a moving
        pattern, else None.  Sub-beams of a column share its time."""
        if not self.moving:
            return None
        frac = sub_offsets(self.footprint)
        return (np.repeat(np.asarray(self.col_time_s, np.float64), len(frac)),
                np.asarray(self.velocity_m_s, np.float64))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "n_rows": self.n_rows, "n_cols": self.n_cols,
                "footprint": self.footprint, "hit_rule": self.hit_rule, "col_span_deg": self.col_span_deg,
                "row_span_deg": self.row_span_deg,
                "col_angle_first_deg": float(self.col_angle_deg[0]),
                "row_origin_first_m": self.row_origin_m[0].tolist(),
                "row_origin_last_m": self.row_origin_m[-1].tolist(),
                "row_span_m": self.row_span_m.tolist(), "escape_m": self.escape_m,
                "ground": self.ground, "ground_z_m": self.ground_z_m, **self.meta,
                # timing only for patterns that have it (older patterns keep their headers)
                **({"time_first_s": float(self.row_time_s[0]), "time_last_s": float(self.beam_times_s()[-1, -1])}
                   if self.row_time_s is not None else {}),
                **({"velocity_m_s": [float(v) for v in self.velocity_m_s]} if self.moving else {})}


def _n_steps(lo: float, hi: float, step: float, key: str, source, inclusive: bool = True) -> int:
    """How many values :func:`_steps` gives (counted, nothing allocated)."""
    if not (math.isfinite(step) and step > 0):
        raise ConfigError("the step must be > 0", file=source, key=key, value=step)
    if not hi > lo:
        raise ConfigError(f"the range must be increasing ({lo} … {hi})", file=source, key=key, value=step)
    n = int(math.floor((hi - lo) / step + 1e-9)) + (1 if inclusive else 0)
    if not inclusive and lo + n * step < hi - 1e-9 * step:
        n += 1
    return n


def _steps(lo: float, hi: float, step: float, key: str, source, inclusive: bool = True) -> np.ndarray:
    """lo, lo+step, … up to hi (inclusive) or below it (half-open, for full turns of azimuth)."""
    return lo + np.arange(_n_steps(lo, hi, step, key, source, inclusive)) * step


def _check_beams(factors: dict[str, tuple[int, str, object]], footprint: int, max_beams: int | None,
                 source) -> None:
    """Refuse, before any array is made, a pattern of more beams than ``max_beams`` (default
    :data:`DEFAULT_MAX_BEAMS`); dot-matrix sub-beams count.  ``factors`` maps what is counted
    ("sweeps") to (count, the key that sets it, its value): the largest count's key is blamed."""
    limit = DEFAULT_MAX_BEAMS if max_beams is None else int(max_beams)
    sub = (int(footprint) + 1) ** 2
    total = sub
    for n, _, _ in factors.values():
        total *= n
    if total <= limit:
        return
    what = " × ".join(f"{n:,} {name}" for name, (n, _, _) in factors.items())
    what += f" × {sub} sub-beams" if sub > 1 else ""
    _, key, value = max(factors.values(), key=lambda f: f[0])
    raise ConfigError(f"{what} = {total:.3g} beams exceed scan.max_beams = {limit}; change this key "
                      "or raise scan.max_beams", file=source, key=key, value=value)


def static_pattern(position_m, elevation_deg: tuple[float, float, float],
                   azimuth_deg: tuple[float, float, float] | float = 0.0, *, footprint: int = 0,
                   escape_m: float = 1000.0, ground: bool = True, ground_z_m: float = 0.0,
                   max_beams: int | None = None, source=None) -> BeamPattern:
    """A tripod scanner: elevations (min, max, step) in degrees, both ends included; azimuth a
    single value (2D profile) or (start, stop, step) with stop excluded (3D, so [0, 360, 1]
    gives 360 rows).  Azimuth 0 looks along +x, 90 along +y."""
    pos = np.asarray(position_m, np.float64)
    n_az = 1 if np.isscalar(azimuth_deg) else _n_steps(*azimuth_deg, "platform.azimuth_deg", source,
                                                       inclusive=False)
    _check_beams({"azimuths": (n_az, "platform.azimuth_deg", azimuth_deg if np.isscalar(azimuth_deg)
                               else list(azimuth_deg)),
                  "elevations": (_n_steps(*elevation_deg, "platform.elevation_deg", source),
                                 "platform.elevation_deg", list(elevation_deg))}, footprint, max_beams, source)
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
                  ground: bool = True, ground_z_m: float = 0.0, scan_legs=None,
                  max_beams: int | None = None, source=None) -> list[BeamPattern]:
    """A ground vehicle along straight legs between waypoints (x, y, z), sweeping elevations in
    the vertical plane perpendicular to its travel, on its ``side`` ('right' or 'left').

    Leg j runs from waypoint j to j + 1.  ``scan_legs`` (increasing leg indices; default
    all) lists the legs the scanner fires on; the others are driven without scanning (a
    headland turn between two passes).  The patterns returned are the scanned legs in
    order, so pattern s (``point_source_id`` s in points.las, scan_leg{s}.exr) is leg
    ``scan_legs[s]``; ``meta['leg']`` keeps the leg index.  Both passes of a U-turn around a
    row look at the row with the same ``side``: right of the heading is +x going +y and −x
    coming back."""
    wp = np.asarray(waypoints_m, np.float64)
    if wp.ndim != 2 or wp.shape[1] != 3 or len(wp) < 2:
        raise ConfigError("waypoints must be a list of at least two [x, y, z] points", file=source,
                          key="platform.waypoints_m", value=np.asarray(waypoints_m).tolist())
    if side not in ("right", "left"):
        raise ConfigError("side must be 'right' or 'left'", file=source, key="platform.side", value=side)
    el = _steps(*elevation_deg, "platform.elevation_deg", source)
    n_legs = len(wp) - 1
    if scan_legs is None:
        scan_legs = list(range(n_legs))
    if (not scan_legs or any(isinstance(j, bool) or not isinstance(j, (int, np.integer)) for j in scan_legs)
            or list(scan_legs) != sorted(set(scan_legs)) or scan_legs[0] < 0 or scan_legs[-1] >= n_legs):
        raise ConfigError(f"must be increasing leg indices in 0 … {n_legs - 1} (leg j runs from "
                          "waypoint j to j + 1)", file=source, key="platform.scan_legs", value=scan_legs)
    lengths = [float(np.linalg.norm(wp[j + 1] - wp[j])) for j in scan_legs]
    sweeps = sum(_n_steps(0.0, x, step_m, "platform.step_m", source) for x in lengths if x >= step_m)
    _check_beams({"sweeps": (sweeps, "platform.step_m", step_m),
                  "elevations": (len(el), "platform.elevation_deg", list(elevation_deg))},
                 footprint, max_beams, source)
    legs = []
    for j in range(n_legs):
        a, b = wp[j], wp[j + 1]
        length = float(np.linalg.norm(b - a))
        if j not in scan_legs:  # driven, not scanned
            if length <= 0:
                raise ConfigError(f"leg {j} has zero length", file=source, key="platform.waypoints_m",
                                  value=[a.tolist(), b.tolist()])
            continue
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


#: Airborne defaults (the [platform] keys are shared by every kind, so their defaults depend on it).
AIRBORNE_SPEED_M_S = 30.0
AIRBORNE_PULSE_RATE_HZ = 300_000.0


def airborne_pattern(start_xy_m, end_xy_m, altitude_m: float, swath_deg: float, speed_m_s: float,
                     pulse_rate_hz: float, pulses_per_line: int, *, footprint: int = 0,
                     escape_m: float = 10000.0, ground: bool = True, ground_z_m: float = 0.0,
                     max_beams: int | None = None, source=None) -> BeamPattern:
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
    if length < step:  # blame the first key whose default gives a step that fits, else the line
        terms = (("pulses_per_line", M, M, SECTIONS["platform"]["pulses_per_line"].default),
                 ("speed_m_s", speed_m_s, speed_m_s, AIRBORNE_SPEED_M_S),
                 ("pulse_rate_hz", pulse_rate_hz, 1 / pulse_rate_hz, 1 / AIRBORNE_PULSE_RATE_HZ))
        key, value = next(((f"platform.{k}", v) for k, v, q, d in terms if q != d and step * d / q <= length),
                          ("platform.end_xy_m", list(end_xy_m)))
        raise ConfigError(f"the flight line ({length:.3g} m) is shorter than one line step, speed_m_s · "
                          f"pulses_per_line / pulse_rate_hz = {speed_m_s:g} · {M} / {pulse_rate_hz:g} = "
                          f"{step:.3g} m", file=source, key=key, value=value)
    unit = (b - a) / length
    _check_beams({"lines": (_n_steps(0.0, length, step, "platform.speed_m_s", source), "platform.speed_m_s",
                            speed_m_s),
                  "pulses": (M, "platform.pulses_per_line", pulses_per_line)}, footprint, max_beams, source)
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


# --- spinning and rosette scanners: one pattern per leg, time continuous across legs ---------

def _legs(position_m, waypoints_m, speed_m_s, duration_s, default_duration_s: float, source):
    """[(start (3,), unit (3,) or None, heading_deg, t0_s, t1_s, speed)] for a static scanner
    (one 'leg' of ``duration_s``) or a vehicle driving straight legs at ``speed_m_s``."""
    if (position_m is None) == (waypoints_m is None):
        raise ConfigError("give either position_m (a static scanner) or waypoints_m (a moving one)",
                          file=source, key="platform.waypoints_m" if waypoints_m is not None else "platform.position_m",
                          value=None if waypoints_m is None else np.asarray(waypoints_m).tolist())
    if position_m is not None:
        d = default_duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(d) and d > 0):
            raise ConfigError("must be a finite number > 0", file=source, key="platform.duration_s", value=d)
        return [(np.asarray(position_m, np.float64), None, 0.0, 0.0, d, 0.0)]
    if duration_s is not None:
        raise ConfigError("a moving scanner's duration follows from its waypoints and speed; drop duration_s",
                          file=source, key="platform.duration_s", value=duration_s)
    if speed_m_s is None:
        raise ConfigError("a scanner moving along waypoints_m needs this key", file=source, key="platform.speed_m_s")
    if not (math.isfinite(speed_m_s) and speed_m_s > 0):
        raise ConfigError("must be a finite number > 0", file=source, key="platform.speed_m_s", value=speed_m_s)
    wp = np.asarray(waypoints_m, np.float64)
    if wp.ndim != 2 or wp.shape[1] != 3 or len(wp) < 2:
        raise ConfigError("waypoints must be a list of at least two [x, y, z] points", file=source,
                          key="platform.waypoints_m", value=np.asarray(waypoints_m).tolist())
    legs, t = [], 0.0
    for j in range(len(wp) - 1):
        a, b = wp[j], wp[j + 1]
        length = float(np.linalg.norm(b - a))
        if length <= 0:
            raise ConfigError(f"leg {j} has zero length", file=source, key="platform.waypoints_m",
                              value=[a.tolist(), b.tolist()])
        unit = (b - a) / length
        legs.append((a, unit, math.degrees(math.atan2(unit[1], unit[0])), t, t + length / speed_m_s, speed_m_s))
        t += length / speed_m_s
    return legs


def _leg_events(t0: float, t1: float, period: float, last: bool) -> tuple[int, int]:
    """(first, end) indices n of the events n·period in [t0, t1) ([t0, t1] on the last leg).
    Both ends are rounded the same way, so consecutive legs share no event and miss none."""
    n0 = int(math.ceil(t0 / period - 1e-9))
    n1 = int(math.floor(t1 / period + 1e-9)) + 1 if last else int(math.ceil(t1 / period - 1e-9))
    return n0, max(n0, n1)


def _static_events(t1: float, period: float) -> tuple[int, int]:
    """(0, end): the events n·period in [0, t1) of a static scanner, at least one."""
    return 0, max(1, int(math.floor(t1 / period + 1e-9)))


def _timed_key(static: bool, duration_s, fallback: tuple[str, object], speed_m_s) -> tuple[str, object]:
    """The key that made a timed scanner fire so often: its duration, else ``fallback``
    (static), or its speed (moving: the duration is the path over the speed)."""
    if not static:
        return "platform.speed_m_s", speed_m_s
    return ("platform.duration_s", duration_s) if duration_s is not None else fallback


#: Velodyne VLP-16 (User Manual 63-9243 Rev. E, "Laser firing sequence" and "Vertical angles"):
#: 16 lasers at −15…+15° every 2°, fired in this order every 2.304 µs, one sequence every 55.296 µs.
VLP16_CHANNELS_DEG = [-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0]
VLP16_OFFSETS_US = [round(2.304 * k, 3) for k in range(16)]
VLP16_BLOCK_US = 55.296


def rotating_patterns(channels_deg=VLP16_CHANNELS_DEG, channel_offsets_us=VLP16_OFFSETS_US,
                      block_period_us: float = VLP16_BLOCK_US, rotation_hz: float = 10.0, *,
                      position_m=None, waypoints_m=None, speed_m_s: float | None = None,
                      azimuth_range_deg=None, duration_s: float | None = None, footprint: int = 0,
                      escape_m: float = 1000.0, ground: bool = True, ground_z_m: float = 0.0,
                      max_beams: int | None = None, source=None) -> list[BeamPattern]:
    """A spinning multi-channel scanner.

    Channel k has elevation ``channels_deg[k]`` and fires ``channel_offsets_us[k]`` after the
    start of its firing block; blocks start every ``block_period_us`` while the head turns at
    ``rotation_hz`` (> 0 counter-clockwise seen from above, < 0 clockwise).  Block i starts at
    t_i = i·T (T = block period) with the head at azimuth φ_i = 360°·rotation_hz·t_i, measured
    from the direction of travel (static: from +x), so consecutive rows step by
    360°·rotation_hz·T.  Channel k fires at t_i + offset_k from the origin the platform has
    then, in the direction of elevation θ_k and azimuth φ_i + 360°·rotation_hz·offset_k (the head
    keeps turning within a block).  Columns are the channels sorted by elevation (ring 0 the
    lowest), each keeping its own offset.  ``azimuth_range_deg`` = [a, b] keeps only the blocks whose
    φ_i lies in that sector (modulo 360°; e.g. [-135, -45] is the right-hand side).

    Static (``position_m``): blocks over ``duration_s`` (default one revolution).  Moving
    (``waypoints_m``, ``speed_m_s``): straight legs driven at constant speed, one pattern per
    leg, time and head azimuth running on across legs.  The mount height is the z of
    ``position_m`` / the waypoints (the optical centre).
    """
    el = np.asarray(channels_deg, np.float64).ravel()
    off = np.asarray(channel_offsets_us, np.float64).ravel()
    if len(el) < 1 or not np.all(np.isfinite(el)) or np.any(np.abs(el) > 90):
        raise ConfigError("channel elevations must be finite angles in [-90, 90] degrees", file=source,
                          key="platform.channels_deg", value=list(channels_deg))
    if len(off) != len(el):
        raise ConfigError(f"give one firing offset per channel ({len(el)} channels, {len(off)} offsets)",
                          file=source, key="platform.channel_offsets_us", value=list(channel_offsets_us))
    T_us = float(block_period_us)
    if not (math.isfinite(T_us) and T_us > 0):
        raise ConfigError("must be a finite number > 0", file=source, key="platform.block_period_us", value=T_us)
    if not np.all(np.isfinite(off)) or np.any(off < 0) or np.any(off >= T_us):
        raise ConfigError(f"offsets must lie in [0, block_period_us = {T_us:g}) µs", file=source,
                          key="platform.channel_offsets_us", value=list(channel_offsets_us))
    if not (math.isfinite(rotation_hz) and rotation_hz != 0):
        raise ConfigError("must be a finite, non-zero number of turns per second", file=source,
                          key="platform.rotation_hz", value=rotation_hz)
    if azimuth_range_deg is not None:
        a0, a1 = (float(x) for x in azimuth_range_deg)
        if not (a1 > a0 and a1 - a0 <= 360):
            raise ConfigError("must be [start, stop] in degrees with start < stop ≤ start + 360", file=source,
                              key="platform.azimuth_range_deg", value=list(azimuth_range_deg))
    order = np.argsort(el, kind="stable")  # column k = ring k, lowest elevation first (as drivers number rings)
    el, off = el[order], off[order]
    T = T_us * 1e-6
    deg_per_s = 360.0 * float(rotation_hz)
    legs = _legs(position_m, waypoints_m, speed_m_s, duration_s, 1.0 / abs(rotation_hz), source)
    col_time = off * 1e-6
    col_az = deg_per_s * col_time
    ph = np.deg2rad(col_az)
    col_dir = elevation_dirs(el)
    col_dir = np.stack([col_dir[:, 0] * np.cos(ph), col_dir[:, 0] * np.sin(ph), col_dir[:, 2]], axis=1)
    uniq = np.unique(el)
    col_span = float(np.median(np.diff(uniq))) if len(uniq) > 1 else 0.0
    share = 1.0 if azimuth_range_deg is None else (a1 - a0) / 360.0  # blocks the sector keeps
    spans = [_static_events(t1, T) if unit is None else _leg_events(t0, t1, T, j == len(legs) - 1)
             for j, (_, unit, _, t0, t1, _) in enumerate(legs)]
    _check_beams({"blocks": (int(sum(b - a for a, b in spans) * share),
                             *_timed_key(position_m is not None, duration_s,
                                         ("platform.block_period_us", block_period_us), speed_m_s)),
                  "channels": (len(el), "platform.channels_deg", list(channels_deg))},
                 footprint, max_beams, source)
    patterns = []
    for j, (start, unit, heading, t0, t1, v) in enumerate(legs):
        n = np.arange(*spans[j], dtype=np.int64)
        t = n * T
        phi = deg_per_s * t
        if azimuth_range_deg is not None:
            keep = np.mod(phi - a0, 360.0) <= a1 - a0
            t, phi = t[keep], phi[keep]
        if not len(t):
            if (turned := abs(deg_per_s) * (t1 - t0)) < 360.0:  # a head too slow to reach the sector
                raise ConfigError(f"the head turns only {turned:.3g}° during leg {j} ({t1 - t0:.3g} s), "
                                  f"never into the sector azimuth_range_deg = {list(azimuth_range_deg)}",
                                  file=source, key="platform.rotation_hz", value=rotation_hz)
            raise ConfigError(f"no firing block of leg {j} falls in the sector", file=source,
                              key="platform.azimuth_range_deg", value=list(azimuth_range_deg))
        vel = unit * v if unit is not None else None
        origins = (start[None, :] + (t - t0)[:, None] * vel[None, :] if vel is not None
                   else np.repeat(start[None, :], len(t), axis=0))
        row_coord, row_label = ((t - t0) * v, "distance along leg (m)") if vel is not None else (phi, "head azimuth (°)")
        meta = {"angle_kind": "elevation", "rotation_hz": float(rotation_hz), "block_period_us": T_us,
                "n_channels": int(len(el)), "heading_deg": heading,
                "timing": "firing block i at i*block_period, channel k offset_k later; head azimuth "
                          "360*rotation_hz*t from the heading"}
        if vel is not None:
            meta.update({"leg": j, "speed_m_s": float(v)})
        patterns.append(BeamPattern(
            "rotating" if unit is None else f"rotating_leg{j}", origins, heading + phi, el, col_dir,
            (vel * T) if vel is not None else np.zeros(3), col_span, footprint, row_coord, row_label,
            "channel elevation (°)", escape_m, ground, ground_z_m, meta, row_span_deg=abs(deg_per_s) * T,
            row_time_s=t, col_time_s=col_time, velocity_m_s=vel, col_azimuth_deg=col_az))
    return patterns


#: Livox Mid-70 (datasheet: 70.4° circular field of view, 100 000 points/s); prism speeds
#: 7294 and −4664 rpm as HELIOS++ models the Mid-70's Risley pair (3dgeo-heidelberg/helios,
#: XmlAssetsLoader defaults rotorFreq 121.567 / −77.733 Hz).
MID70_ROSETTE_HZ = [7294.0 / 60.0, -4664.0 / 60.0]
MID70_FOV_DEG = 70.4
MID70_PULSE_RATE_HZ = 100_000.0
#: A rosette row is one frame of this length (the Mid-70's default 10 Hz point-cloud frame).
ROSETTE_FRAME_S = 0.1


def rosette_directions(t_s, rosette_hz, fov_deg: float, look_deg=(0.0, 0.0)) -> np.ndarray:
    """(n, 3) platform-frame unit directions of a two-prism rosette at times ``t_s``.

    First-order (thin-prism) Risley model: each prism deviates the beam by δ towards its
    own orientation, and the deviations add as vectors (Marshall, "Risley prism scan
    patterns", Proc. SPIE 3787, 1999; the Livox pattern: Liu, Zhang & Hong, "Low-cost
    retina-like robotic lidars based on incommensurable scanning", IEEE/ASME Trans.
    Mechatronics 27(1), 2022).  With two equal prisms and δ = fov/4, the deflection from
    the look axis is

        (ξ, η) = δ·(cos 2πf₁t + cos 2πf₂t,  sin 2πf₁t + sin 2πf₂t),

    |(ξ, η)| = 2δ·|cos(π(f₁ − f₂)t)| ≤ fov/2: petals through the centre at |f₁ − f₂| Hz, the
    pattern turning at (f₁ + f₂)/2 Hz, never repeating when f₁/f₂ is irrational.  The beam
    leaves at the polar angle ρ = |(ξ, η)| from the look axis a, towards ψ = atan2(η, ξ):
    d = cos ρ·a + sin ρ·(cos ψ·u + sin ψ·w), u horizontal and w = a × u "up" for a level look.
    ``look_deg`` = [azimuth, elevation] of a (azimuth from the heading / +x, counter-clockwise).
    """
    t = np.asarray(t_s, np.float64)
    f1, f2 = (float(f) for f in rosette_hz)
    delta = np.deg2rad(fov_deg) / 4.0
    xi = delta * (np.cos(2 * np.pi * f1 * t) + np.cos(2 * np.pi * f2 * t))
    eta = delta * (np.sin(2 * np.pi * f1 * t) + np.sin(2 * np.pi * f2 * t))
    rho, psi = np.hypot(xi, eta), np.arctan2(eta, xi)
    az, el = np.deg2rad(float(look_deg[0])), np.deg2rad(float(look_deg[1]))
    a = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    u = np.array([-np.sin(az), np.cos(az), 0.0])
    w = np.cross(a, u)
    d = (np.cos(rho)[:, None] * a[None, :]
         + np.sin(rho)[:, None] * (np.cos(psi)[:, None] * u[None, :] + np.sin(psi)[:, None] * w[None, :]))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def rosette_patterns(rosette_hz=MID70_ROSETTE_HZ, fov_deg: float = MID70_FOV_DEG,
                     pulse_rate_hz: float = MID70_PULSE_RATE_HZ, look_deg=(0.0, 0.0), *,
                     position_m=None, waypoints_m=None, speed_m_s: float | None = None,
                     duration_s: float | None = None, footprint: int = 0, escape_m: float = 1000.0,
                     ground: bool = True, ground_z_m: float = 0.0, max_beams: int | None = None,
                     source=None) -> list[BeamPattern]:
    """A two-prism rosette scanner (:func:`rosette_directions`) pulsing at ``pulse_rate_hz``.

    Pulse n fires at t = n / pulse_rate_hz.  Rows are frames of ROSETTE_FRAME_S (0.1 s),
    columns the pulses of a frame; the pulses after a leg's last whole frame are not fired
    (a shorter leg or duration is one frame of all its pulses).  Static (``position_m``):
    ``duration_s`` (default one frame); moving (``waypoints_m``, ``speed_m_s``): one pattern
    per leg, each beam from the position at its own time.  Every beam has its own direction,
    so the dot-matrix footprint (a grid of row/column steps) does not apply: use [sensor]
    divergence for a beam's footprint.  The column angle written to outputs is 0 (a rosette
    has no per-column angle).
    """
    f = [float(x) for x in rosette_hz] if len(rosette_hz) == 2 else None
    if f is None or not all(math.isfinite(x) and x != 0 for x in f) or f[0] == f[1]:
        raise ConfigError("must be [f1, f2], two different non-zero prism speeds in Hz (opposite signs: "
                          "counter-rotating)", file=source, key="platform.rosette_hz", value=list(rosette_hz))
    if not (0 < fov_deg < 180):
        raise ConfigError("must lie in (0, 180) degrees", file=source, key="platform.fov_deg", value=fov_deg)
    if not (math.isfinite(pulse_rate_hz) and pulse_rate_hz > 0):
        raise ConfigError("must be a finite number > 0", file=source, key="platform.pulse_rate_hz", value=pulse_rate_hz)
    if len(look_deg) != 2 or not (-90 <= float(look_deg[1]) <= 90):
        raise ConfigError("must be [azimuth, elevation] in degrees, elevation in [-90, 90]", file=source,
                          key="platform.look_deg", value=list(look_deg))
    if footprint:
        raise ConfigError("the dot-matrix footprint needs a row/column grid, which a rosette has not; "
                          "use [sensor] divergence_mrad", file=source, key="scan.footprint", value=footprint)
    legs = _legs(position_m, waypoints_m, speed_m_s, duration_s, ROSETTE_FRAME_S, source)
    dt = 1.0 / float(pulse_rate_hz)
    per_frame = max(1, int(round(ROSETTE_FRAME_S * pulse_rate_hz)))
    spans = [_static_events(t1, dt) if unit is None else _leg_events(t0, t1, dt, j == len(legs) - 1)
             for j, (_, unit, _, t0, t1, _) in enumerate(legs)]
    _check_beams({"pulses": (sum(b - a for a, b in spans),
                             *_timed_key(position_m is not None, duration_s,
                                         ("platform.pulse_rate_hz", pulse_rate_hz), speed_m_s))},
                 0, max_beams, source)
    patterns = []
    for j, (start, unit, heading, t0, t1, v) in enumerate(legs):
        n = np.arange(*spans[j], dtype=np.int64)
        m = min(per_frame, len(n))
        rows = len(n) // m
        t = (n[:rows * m] * dt).reshape(rows, m)
        d = rosette_directions(t.ravel(), f, fov_deg, look_deg)
        h = np.deg2rad(heading)  # the look direction turns with the vehicle
        d = np.stack([np.cos(h) * d[:, 0] - np.sin(h) * d[:, 1], np.sin(h) * d[:, 0] + np.cos(h) * d[:, 1],
                      d[:, 2]], axis=1).reshape(rows, m, 3)
        row_t, col_t = t[:, 0].copy(), t[0] - t[0, 0]
        vel = unit * v if unit is not None else None
        origins = (start[None, :] + (row_t - t0)[:, None] * vel[None, :] if vel is not None
                   else np.repeat(start[None, :], rows, axis=0))
        meta = {"angle_kind": "direction", "rosette_hz": f, "fov_deg": float(fov_deg),
                "pulse_rate_hz": float(pulse_rate_hz), "look_deg": [float(x) for x in look_deg],
                "heading_deg": heading, "timing": "pulse n at n/pulse_rate_hz; rows are 0.1 s frames"}
        if vel is not None:
            meta.update({"leg": j, "speed_m_s": float(v)})
        patterns.append(BeamPattern(
            "rosette" if unit is None else f"rosette_leg{j}", origins, np.zeros(rows), np.zeros(m),
            np.tile([1.0, 0.0, 0.0], (m, 1)), np.zeros(3), 0.0, 0, row_t, "frame start time (s)",
            "pulse of the frame", escape_m, ground, ground_z_m, meta,
            row_time_s=row_t, col_time_s=col_t, velocity_m_s=vel, beam_dirs=d))
    return patterns
