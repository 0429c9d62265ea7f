"""What a scene-file key is (:class:`Key`), its value types and the shared checks.

The lowest layer of the key tables: :mod:`simlidar_mi.config.keys` and every feature's
``keys_<feature>.py`` import from here, so a feature module never imports
config.keys (which imports it: that would be an import cycle).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Callable

Check = Callable[[Any], str | None]  # returns a complaint, or None when the value is fine


@dataclass(frozen=True)
class Key:
    """One scene-file key: accepted Python types, default, and an extra check.

    ``knob``: an execution setting (a chunk size, a size limit) that no result depends on:
    left out of the scene's ``sha256`` and of the study's row keys.

    ``range``: the finite interval a number-valued key's value (each number of a list's) lies
    in, a :class:`~simlidar_mi.config.bounds.Bounds`; set for every such key from
    :data:`simlidar_mi.config.bounds.BOUNDS` and checked before ``check``."""

    types: tuple
    default: Any = None
    check: Check | None = None
    doc: str = ""
    knob: bool = False
    range: Any = None


def _finite(v):
    return None if math.isfinite(v) else "must be a finite number"


def positive(v):
    return _finite(v) or (None if v > 0 else "must be > 0")


def nonneg(v):
    return _finite(v) or (None if v >= 0 else "must be ≥ 0")


def unit_interval(v):
    return _finite(v) or (None if 0 <= v <= 1 else "must lie in [0, 1]")


def at_least(n):
    return lambda v: None if v >= n else f"must be ≥ {n}"


def within(lo, hi, why: str = ""):
    """``lo ≤ v ≤ hi`` (finite); ``why`` says where the upper bound comes from."""
    return lambda v: _finite(v) or (f"must be ≥ {lo:g}" if v < lo else None if v <= hi else
                                    f"must be ≤ {hi:g}" + (f" ({why})" if why else ""))


#: A name that becomes part of a file name: letters, digits, '_', '-', '.', starting with a
#: letter or digit, at most 64 characters (no '/', no '..' prefix, no absolute path).
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def safe_name(v):
    """1-64 letters, digits, '_', '-' or '.', starting with a letter or digit (part of a file name)"""
    return None if SAFE_NAME.fullmatch(v) else (
        "becomes part of a file name, so it must be 1-64 letters, digits, '_', '-' or '.', "
        "starting with a letter or digit")


def one_of(*choices):
    return lambda v: None if v in choices else f"must be one of {', '.join(map(repr, choices))}"


def vec3(v):
    if len(v) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return "must be a list of three numbers [x, y, z] in metres"
    return None if all(math.isfinite(x) for x in v) else "must hold finite numbers"


def _numbers(v, n=None):
    return (isinstance(v, list) and (n is None or len(v) == n)
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v))


def range3(v):
    if not _numbers(v, 3):
        return "must be [min, max, step] in degrees"
    return None if v[2] > 0 and v[1] > v[0] else "needs max > min and step > 0"


def vec2(v):
    return None if _numbers(v, 2) else "must be a list of two numbers [x, y] in metres"


def azimuth(v):
    if isinstance(v, list):
        return range3(v)
    return None if math.isfinite(v) else "must be a finite number"


def _epsg(v):
    """'EPSG:<code>' naming a CRS whose horizontal axes are in metres (the scene's units)."""
    m = re.fullmatch(r"EPSG:(\d{1,6})", v.strip(), flags=re.IGNORECASE)
    if m is None:
        return 'must look like "EPSG:<code>", e.g. "EPSG:25832"'
    import pyproj  # noqa: PLC0415 - only scenes that declare a CRS pay for it
    try:
        crs = pyproj.CRS.from_epsg(int(m.group(1)))
    except pyproj.exceptions.CRSError:
        return "is not an EPSG code that PROJ knows"
    units = {a.unit_name for a in crs.axis_info[:2]}
    if not crs.is_projected or units != {"metre"}:
        return (f"is {crs.name}, not a projected CRS in metres; scene coordinates are metres "
                "(use e.g. the UTM zone's EPSG code)")
    return None


def waypoints(v):
    ok = isinstance(v, list) and len(v) >= 2 and all(_numbers(p, 3) for p in v)
    return None if ok else "must be a list of at least two [x, y, z] points"


FLOAT = (int, float)
INT = (int,)
BOOL = (bool,)
STR = (str,)
LIST = (list,)
