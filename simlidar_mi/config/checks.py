"""Checks shared by every parameter dataclass: one message style, ConfigError with key and value."""
from __future__ import annotations

import math

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as a package
    import tomli as tomllib

import numpy as np

from ..errors import ConfigError


def real(key: str, value, *, positive: bool = False, nonneg: bool = False) -> float:
    """``value`` as a finite float (booleans refused), optionally > 0 or ≥ 0."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError("must be a real number", key=key, value=value) from None
    if isinstance(value, (bool, np.bool_)) or not math.isfinite(v):
        raise ConfigError("must be a finite real number", key=key, value=value)
    if positive and v <= 0:
        raise ConfigError("must be > 0", key=key, value=value)
    if nonneg and v < 0:
        raise ConfigError("must be >= 0", key=key, value=value)
    return v


def flag(key: str, value) -> bool:
    """``value`` as a bool; numbers and strings are refused."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError("must be true or false", key=key, value=value)
    return bool(value)


def seed_sequence(seed, key: str = "seed") -> np.random.SeedSequence:
    """A fresh SeedSequence from an int ≥ 0, a SeedSequence (copied) or None (OS entropy)."""
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                             or seed < 0):
        raise ConfigError("seed must be a non-negative integer, a SeedSequence or None",
                          key=key, value=seed)
    return np.random.SeedSequence(None if seed is None else int(seed))


#: Deepest nesting of arrays and tables a scene, preset or --set value may hold: real files
#: nest 4 levels (a table of waypoint lists); deeper nesting only exhausts recursion.
MAX_TOML_DEPTH = 32


_UTF16_32_BOMS = {b"\xff\xfe\x00\x00": "UTF-32", b"\x00\x00\xfe\xff": "UTF-32",
                  b"\xff\xfe": "UTF-16", b"\xfe\xff": "UTF-16"}


def decode_toml(raw: bytes, src: str, what: str = "scene file") -> str:
    """The text of a TOML file's bytes: UTF-8, with or without the byte-order mark some Windows
    editors write (TOML itself forbids it; dropped here); one ConfigError line otherwise."""
    for bom, name in _UTF16_32_BOMS.items():
        if raw.startswith(bom):
            raise ConfigError(f"{what} is {name} text (it starts with a {name} byte-order mark); "
                              "save it as UTF-8", file=src)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{what} is not UTF-8 text", file=src) from exc


def parse_toml(text: str, src: str, key: str | None = None, value=None) -> dict:
    """``tomllib.loads(text)``, every failure one ConfigError naming ``src`` (and ``key``,
    ``value``): invalid TOML, and arrays or tables nested deeper than :data:`MAX_TOML_DEPTH`
    (a RecursionError in the parser, or later in code that walks the values)."""
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))  # a byte-order mark: see decode_toml
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", file=src, key=key, value=value) from None
    except RecursionError:
        data = None
    if data is None or nesting_depth(data) > MAX_TOML_DEPTH:
        raise ConfigError(f"arrays or tables nested more than {MAX_TOML_DEPTH} deep", file=src,
                          key=key, value=value if value is None or len(str(value)) < 80
                          else str(value)[:60] + "…")
    return data


def nesting_depth(value) -> int:
    """Levels of lists and dicts in ``value`` (a scalar: 0), walked without recursion."""
    best, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        items = v.values() if isinstance(v, dict) else v if isinstance(v, list) else None
        if items is not None:
            best = max(best, d + 1)
            stack.extend((x, d + 1) for x in items)
    return best
