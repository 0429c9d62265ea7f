"""The notation of Table 1 of Méndez et al. (SIMLIDAR).

The paper prints derivations with ``R -> T``, ``r -> t``, axis orders as two
digits (``I01``) and the whole word wrapped in ``[ ]``.
"""
from __future__ import annotations

from .modules import ModuleString, format_number

#: Symbol renaming of Table 1.
TABLE1_RENAME = {"R": "T", "r": "t"}


def _two_digits(symbol: str, params: tuple[float, ...]) -> str:
    if not params:
        return ""
    if symbol == "I" and len(params) == 1 and float(params[0]).is_integer():
        return f"{int(params[0]):02d}"
    return f"({','.join(format_number(p) for p in params)})"


def format_table1(modules: ModuleString) -> str:
    """Format a derived SIMLIDAR word as in the paper's Table 1.

    >>> from simlidar_mi.lsystem import parse_modules
    >>> format_table1(parse_modules("I(1)[r+I(2)F]"))
    '[I01[t+I02F]]'
    """
    return "[" + modules.to_text(rename=TABLE1_RENAME, param_format=_two_digits) + "]"
