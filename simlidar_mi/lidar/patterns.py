"""The beam patterns a scene's ``[platform]`` asks for, and where their scanners stand.

Plain data from keys and the geometry's bounds (no Mitsuba): the first step of a scan's plan
(:func:`simlidar_mi.lidar.survey.run_scan`), also what a cluster worker and the study rebuild.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from ..config import SceneConfig
from ..errors import ConfigError, SimlidarWarning
from .platforms import AIRBORNE_PULSE_RATE_HZ, AIRBORNE_SPEED_M_S  # noqa: F401  (survey imports them here)


def scanner_positions_m(pattern) -> np.ndarray:
    """(n, 3) real positions a pattern fires from: a platform's row origins, or the
    tractor's first and last stop on its line (``ScanSettings``)."""
    rows = getattr(pattern, "row_origin_m", None)
    if rows is not None:
        return np.asarray(rows, np.float64)
    y = pattern.y_m
    return np.array([[pattern.x0_m, y[0], pattern.z0_m], [pattern.x0_m, y[-1], pattern.z0_m]])


def scan_patterns(cfg: SceneConfig, lo_m, hi_m, near_x_m=None) -> list:
    """The beam patterns the scene's [platform] asks for (tractor: [scan] settings, eqs. 6-8).

    ``near_x_m``: the tractor's nearest wood, see :func:`simlidar_mi.lidar.scan.resolve_settings`
    (:meth:`SceneGeometry.near_x_m` in :func:`run_scan`)."""
    try:
        patterns = _patterns(cfg, lo_m, hi_m, near_x_m)
    except ConfigError as exc:
        raise cfg.relabel(exc) from None
    rule = cfg["scan"]["hit_rule"]
    return [p if p.hit_rule == rule else replace(p, hit_rule=rule) for p in patterns]


def _patterns(cfg: SceneConfig, lo_m, hi_m, near_x_m) -> list:
    from .platforms import (airborne_pattern, path_patterns, rosette_patterns,  # noqa: PLC0415
                            rotating_patterns, static_pattern)
    from .scan import resolve_settings  # noqa: PLC0415
    pf, sc, gr = cfg["platform"], cfg["scan"], cfg["ground"]
    # a [terrain] is the ground (a mesh in the scene): no analytic plane under it
    common = {"footprint": sc["footprint"], "ground": gr["enabled"] and not cfg.has("terrain"),
              "ground_z_m": gr["z_m"],
              "source": cfg.source, "max_beams": sc["max_beams"]}
    kind = pf["kind"]
    sensor_rate = cfg["sensor"]["pulse_rate_hz"]

    def need(key):
        if pf[key] is None:
            raise ConfigError(f"a {kind} platform needs this key", file=cfg.source, key=f"platform.{key}")
        return pf[key]

    def pulse_rate(default):
        """The platform's pulse rate: [platform] pulse_rate_hz, else [sensor]'s, else ``default``."""
        own = pf["pulse_rate_hz"]
        if own is not None and sensor_rate > 0 and own != sensor_rate:
            raise ConfigError(f"disagrees with sensor.pulse_rate_hz = {sensor_rate:g}; give one of them",
                              file=cfg.source, key="platform.pulse_rate_hz", value=own)
        return own if own is not None else (sensor_rate if sensor_rate > 0 else default)
    if kind == "tractor":
        return [resolve_settings(sc, dict(gr, enabled=common["ground"]), lo_m, hi_m, cfg.source, near_x_m, pulse_rate_hz=sensor_rate,
                                 speed_m_s=pf["speed_m_s"], dy_given=cfg.gave("scan.dy_m"))]
    if kind == "static":
        az = pf["azimuth_deg"]
        return [static_pattern(need("position_m"), tuple(pf["elevation_deg"]),
                               tuple(az) if isinstance(az, list) else float(az),
                               escape_m=sc["escape_m"], **common)]
    if kind == "path":
        return path_patterns(need("waypoints_m"), pf["step_m"], tuple(pf["elevation_deg"]),
                             side=pf["side"], escape_m=sc["escape_m"], scan_legs=pf["scan_legs"], **common)
    if kind == "rotating":  # timing from the block period; a [sensor] pulse rate does not enter
        return rotating_patterns(pf["channels_deg"], pf["channel_offsets_us"], pf["block_period_us"],
                                 pf["rotation_hz"], position_m=pf["position_m"], waypoints_m=pf["waypoints_m"],
                                 speed_m_s=pf["speed_m_s"], azimuth_range_deg=pf["azimuth_range_deg"],
                                 duration_s=pf["duration_s"], escape_m=sc["escape_m"], **common)
    if kind == "rosette":
        from .platforms import MID70_PULSE_RATE_HZ  # noqa: PLC0415
        return rosette_patterns(pf["rosette_hz"], pf["fov_deg"], pulse_rate(MID70_PULSE_RATE_HZ), pf["look_deg"],
                                position_m=pf["position_m"], waypoints_m=pf["waypoints_m"],
                                speed_m_s=pf["speed_m_s"], duration_s=pf["duration_s"],
                                escape_m=sc["escape_m"], **common)
    escape = max(sc["escape_m"], 10 * pf["altitude_m"])
    speed = pf["speed_m_s"] if pf["speed_m_s"] is not None else AIRBORNE_SPEED_M_S
    return [airborne_pattern(need("start_xy_m"), need("end_xy_m"), pf["altitude_m"], pf["swath_deg"],
                             speed, pulse_rate(AIRBORNE_PULSE_RATE_HZ), pf["pulses_per_line"],
                             escape_m=escape, **common)]



#: An airborne flight's least clearance over the terrain under its swath, as a share of
#: ``altitude_m``: below it the scan is refused (a plane flying into a hill); below
#: :data:`WARN_CLEARANCE` it is warned of (the footprint and the point density under the hill
#: are then far from those ``altitude_m`` implies).
MIN_CLEARANCE = 0.1
WARN_CLEARANCE = 0.5


def check_clearance(cfg: SceneConfig, patterns: list, terrain) -> None:
    """An airborne platform flies level at ``[ground] z_m + altitude_m`` (a constant barometric
    altitude, not terrain following).  Over a ``[terrain]`` that rises under the swath (the
    ground strip ±``altitude_m``·tan(swath/2) either side of the flight line) the clearance
    shrinks: refuse it below :data:`MIN_CLEARANCE` · ``altitude_m``, warn below
    :data:`WARN_CLEARANCE` · ``altitude_m``.  The terrain's highest node in that strip is its
    exact maximum there (the surface is linear between nodes)."""
    if terrain is None:
        return
    for p in patterns:
        if getattr(p, "kind", None) != "airborne":
            continue
        alt, swath = float(p.meta["altitude_m"]), float(cfg["platform"]["swath_deg"])
        o = np.asarray(p.row_origin_m, np.float64)
        a, b = o[0, :2], o[-1, :2]
        flight_z = float(o[0, 2])
        half = alt * math.tan(math.radians(0.5 * swath)) + max(terrain.dx_m, terrain.dy_m)
        xs, ys = terrain.nodes_m()
        x, y = np.meshgrid(xs, ys)
        u = b - a
        length = float(np.hypot(*u))
        u = u / length if length > 0 else np.array([1.0, 0.0])
        along = (x - a[0]) * u[0] + (y - a[1]) * u[1]
        across = np.abs((x - a[0]) * u[1] - (y - a[1]) * u[0])
        strip = (along >= -half) & (along <= length + half) & (across <= half)
        if not strip.any():
            continue
        top = float(terrain.z_m[strip].max())
        clearance = flight_z - top
        what = (f"the airborne platform flies level at ground.z_m + altitude_m = {flight_z:.6g} m; the terrain "
                f"under its swath rises to {top:.6g} m ({clearance:.3g} m clearance")
        if clearance < MIN_CLEARANCE * alt:
            raise ConfigError(f"{what}, under {MIN_CLEARANCE:g} × altitude_m): "
                              "raise altitude_m", file=cfg.source, key="platform.altitude_m", value=alt)
        if clearance < WARN_CLEARANCE * alt:
            warnings.warn(f"{cfg.source}: {what}, under {WARN_CLEARANCE:g} × altitude_m): footprints and point "
                          f"density there differ from those altitude_m implies", SimlidarWarning, stacklevel=3)
