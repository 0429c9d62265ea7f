"""Names every expression knows: the constant ``pi`` and the function table."""
from __future__ import annotations

import math
from functools import reduce
from typing import Any, Callable

import numpy as np

__all__ = ["CONSTANTS", "FUNCTIONS"]

#: Constants every expression knows unless the caller declares the same name.
CONSTANTS: dict[str, float] = {"pi": math.pi}

# name -> (min args, max args or None, scalar function, numpy function)
_FUNCS: dict[str, tuple[int, int | None, Callable[..., Any], Callable[..., Any]]] = {
    "sin": (1, 1, math.sin, np.sin),
    "cos": (1, 1, math.cos, np.cos),
    "tan": (1, 1, math.tan, np.tan),
    "asin": (1, 1, math.asin, np.arcsin),
    "acos": (1, 1, math.acos, np.arccos),
    "atan": (1, 1, math.atan, np.arctan),
    "atan2": (2, 2, math.atan2, np.arctan2),
    "sqrt": (1, 1, math.sqrt, np.sqrt),
    "exp": (1, 1, math.exp, np.exp),
    "log": (1, 1, math.log, np.log),
    "abs": (1, 1, abs, np.abs),
    "min": (2, None, min, lambda *a: reduce(np.minimum, a)),
    "max": (2, None, max, lambda *a: reduce(np.maximum, a)),
    "floor": (1, 1, lambda x: float(math.floor(x)), np.floor),
    "ceil": (1, 1, lambda x: float(math.ceil(x)), np.ceil),
}

#: Function names accepted in expressions (all angles in radians).
FUNCTIONS: frozenset[str] = frozenset(_FUNCS)
