"""Checks shared by every parameter dataclass: one message style, ConfigError with key and value."""
from __future__ import annotations

import math

import numpy as np

from .errors import ConfigError


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
