"""The bytes ``np.savetxt`` writes for ``%d``, ``%.Nf`` and ``%.Pg`` columns, formatted with numpy.

``np.savetxt`` formats row by row with Python's ``%`` (about 0.2 µs a number): a forest's
2.3 M-row, 14-column leaf table took 7.6 s.  Here each column becomes a (rows, width) matrix
of ASCII characters computed with integer arithmetic, NUL-padded, and the NULs are dropped at
the end.  numpy has no vectorised printf and pandas' ``to_csv`` formats each float in Python
too, hence this module.

Rounding is Python's (and C's): the exact binary value rounded half to even.  A number is
scaled to an integer in float64; for |scaled| < 1e9 one float64 rounding moves it by less than
1.2e-7, so when its fraction lies more than 1e-6 from a half the nearest integer is the exactly
rounded one.  Numbers within 1e-6 of a half (possible ties), out of that range, not finite, or
needing ``%g``'s exponent style are formatted by Python's ``%`` instead, so every byte is the
one ``np.savetxt`` writes.
"""
from __future__ import annotations

import re

import numpy as np

_FMT = re.compile(r"%(?:(d)|\.(\d+)([fg]))$")
_SAFE = 1e9  # scaled magnitudes below this are exact to < 1.2e-7 in float64
_TIE = 1e-6  # scaled fractions this close to a half go to Python's %
_POW10 = np.array([float(10 ** i) for i in range(23)])  # exact powers of ten in float64
_ZERO, _DOT, _MINUS = 48, 46, 45


def _digits(q: np.ndarray, n_digits: int, *, lead_zeros: bool) -> np.ndarray:
    """(n, n_digits) ASCII digits of the non-negative int64 ``q``; without ``lead_zeros``
    the zeros before the first significant digit are NUL (the units digit is always kept)."""
    out = np.empty((len(q), n_digits), np.uint8)
    rest = q
    for j in range(n_digits - 1, -1, -1):  # // by a scalar is fast in numpy, divmod is not
        high = rest // 10
        out[:, j] = rest - high * 10 + _ZERO
        rest = high
    if not lead_zeros:
        for j in range(n_digits - 1):
            out[q < 10 ** (n_digits - 1 - j), j] = 0
    return out


def _n_digits(q: np.ndarray) -> int:
    return len(str(int(q.max()))) if len(q) else 1


def _sign(neg: np.ndarray) -> np.ndarray:
    return np.where(neg, _MINUS, 0).astype(np.uint8)[:, None]


def _int_column(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``%d`` of float64 values (Python truncates towards zero)."""
    bad = ~(np.abs(x) < 2.0 ** 53)
    t = np.trunc(np.where(bad, 0.0, x))
    q = np.abs(t).astype(np.int64)
    return np.hstack([_sign(t < 0), _digits(q, _n_digits(q), lead_zeros=False)]), bad


def _fixed_column(x: np.ndarray, n_dec: int) -> tuple[np.ndarray, np.ndarray]:
    """``%.<n_dec>f``: sign (also of −0 and of negatives that round to zero), integer digits,
    point, ``n_dec`` digits."""
    y = np.abs(x) * _POW10[n_dec]
    with np.errstate(invalid="ignore"):
        bad = ~(y < _SAFE) | (np.abs(y - np.floor(y) - 0.5) < _TIE)
    q = np.rint(np.where(bad, 0.0, y)).astype(np.int64)
    ip = q // 10 ** n_dec
    fp = q - ip * 10 ** n_dec
    parts = [_sign(np.signbit(x)), _digits(ip, _n_digits(ip), lead_zeros=False)]
    if n_dec:
        parts += [np.full((len(x), 1), _DOT, np.uint8), _digits(fp, n_dec, lead_zeros=True)]
    return np.hstack(parts), bad


def _general_column(x: np.ndarray, prec: int) -> tuple[np.ndarray, np.ndarray]:
    """``%.<prec>g`` in its fixed style (exponent −4 ≤ X < prec; others go to Python):
    ``prec`` significant digits, trailing zeros and a bare point dropped."""
    a = np.abs(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        e0 = np.floor(np.log10(a))
        k = prec - 1 - e0
        ok = np.isfinite(e0) & (k >= 0) & (k <= 22)
        y = a * _POW10[np.where(ok, k, 0).astype(np.int64)]
        bad = ~ok | ~(y >= 10.0 ** (prec - 1)) | ~(y < 10.0 ** prec)  # log10 off by one
        bad |= np.abs(y - np.floor(y) - 0.5) < _TIE
    zero = a == 0  # "0" (or "-0"): all digits zero, then stripped
    bad &= ~zero
    q = np.rint(np.where(bad | zero, 0.0, y)).astype(np.int64)
    exp = np.where(zero | bad, 0, e0).astype(np.int64)
    carry = q == 10 ** prec  # 999999.5 → 1000000: one more digit before the point
    q[carry] //= 10
    exp[carry] += 1
    bad |= (exp < -4) | (exp >= prec)  # exponent style
    n_dec = np.where(bad, 0, prec - 1 - exp)  # decimals before stripping, 0 … prec + 3
    d_max = int(n_dec.max()) if len(x) else 0
    scaled = np.where(bad, 0, q) * (10 ** (d_max - n_dec))  # < 10**(2·prec + 3)
    ip = scaled // 10 ** d_max
    fp = scaled - ip * 10 ** d_max
    parts = [_sign(np.signbit(x)), _digits(ip, _n_digits(ip), lead_zeros=False)]
    if d_max:
        frac = _digits(fp, d_max, lead_zeros=True)
        for j in range(d_max):  # a digit stays if it or a later one is non-zero
            frac[fp % 10 ** (d_max - j) == 0, j] = 0
        dot = np.where(fp != 0, _DOT, 0).astype(np.uint8)[:, None]
        parts += [dot, frac]
    return np.hstack(parts), bad


def format_rows(columns: list[np.ndarray], fmts: list[str], delimiter: str = ",") -> bytes:
    """``np.savetxt(fh, np.column_stack(columns), fmt=fmts, delimiter=delimiter)``'s bytes.

    Formats: ``%d``, ``%.<N>f`` and ``%.<P>g`` (P ≤ 7); any other goes to Python's ``%``.
    Columns are taken as float64, as ``np.column_stack`` of mixed columns makes them."""
    if len(columns) != len(fmts):
        raise ValueError(f"{len(columns)} columns but {len(fmts)} formats")
    n = len(columns[0]) if columns else 0
    if n == 0:
        return b""
    cols = [np.asarray(c, np.float64).reshape(n) for c in columns]
    sep = np.full((n, 1), ord(delimiter), np.uint8) if len(delimiter) == 1 else None
    if sep is None or delimiter.encode() == b"\0":
        raise ValueError(f"delimiter must be one printable character, not {delimiter!r}")
    parts, bad = [], np.zeros(n, bool)
    for j, (x, fmt) in enumerate(zip(cols, fmts)):
        m = _FMT.match(fmt)
        if m is None or (m.group(3) == "g" and int(m.group(2)) > 7):
            chars, col_bad = np.zeros((n, 0), np.uint8), np.ones(n, bool)
        elif m.group(1):
            chars, col_bad = _int_column(x)
        elif m.group(3) == "f":
            chars, col_bad = _fixed_column(x, int(m.group(2)))
        else:
            chars, col_bad = _general_column(x, int(m.group(2)))
        parts += [sep, chars] if j else [chars]
        bad |= col_bad
    parts.append(np.full((n, 1), 10, np.uint8))
    text = np.hstack(parts)
    if not bad.any():
        return text[text != 0].tobytes()
    text[bad] = 0  # rows with a number for Python: spliced in below, in order
    ends = np.cumsum(np.count_nonzero(text, axis=1))
    body = text[text != 0].tobytes()
    row_fmt = delimiter.join(fmts) + "\n"
    pieces, prev = [], 0
    for r in np.flatnonzero(bad):
        pieces.append(body[prev:ends[r]])
        pieces.append((row_fmt % tuple(c[r] for c in cols)).encode())
        prev = ends[r]
    pieces.append(body[prev:])
    return b"".join(pieces)
