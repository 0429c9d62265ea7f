"""io/text_columns.format_rows gives np.savetxt's bytes, ties and odd values included."""
import io

import numpy as np
import pytest

from simlidar_mi.io.text_columns import format_rows

# ties of the exact binary value (0.25 → "0.2" at %.1f, 1/128 at %.6f), carries (999999.5),
# −0 and negatives that round to zero, %g's switch to the exponent style, non-finite values
SPECIAL = np.array([0.0, -0.0, 0.25, 0.125, 1 / 128, -1 / 128, 0.5, 1.5, 2.5, 999999.5, 0.9999995,
                    0.00001234, 0.0001, 1e-5, 123456789.0, 1e10, -1e-9, 5e-7, -5e-7, 0.000123456789,
                    0.99999995, 9.9999996, 1234567.5, 0.0009999996, 1e21, np.nan, np.inf, -np.inf])


def savetxt_bytes(cols, fmts, delimiter=","):
    buf = io.BytesIO()
    np.savetxt(buf, np.column_stack(cols), fmt=fmts, delimiter=delimiter)
    return buf.getvalue()


@pytest.mark.parametrize("fmt", ["%d", "%.0f", "%.1f", "%.5f", "%.6f", "%.2g", "%.6g", "%.7g", "%.4e"])
def test_one_column_matches_savetxt(fmt):
    rng = np.random.default_rng(7)
    x = np.concatenate([SPECIAL, *(rng.standard_normal(3000) * s for s in (1e-6, 1e-3, 1.0, 1e3, 1e6))])
    x = np.concatenate([x, np.round(x, 3), np.round(x * 128) / 128])  # many exact ties
    if fmt == "%d":
        x = x[np.isfinite(x) & (np.abs(x) < 1e18)]
    assert format_rows([x], [fmt]) == savetxt_bytes([x], [fmt])


def test_leaf_table_row_layout():
    rng = np.random.default_rng(3)
    n = 5000
    fmts = ["%d", "%d", "%.5f", "%.5f", "%.5f", "%.6g", "%.6g", "%.7g"] + ["%.6f"] * 6
    cols = [np.full(n, 12), np.arange(n)] + [rng.uniform(-300, 300, n) for _ in range(3)] \
        + [rng.uniform(0.001, 0.3, n) for _ in range(2)] + [rng.uniform(1e-6, 0.02, n)] \
        + [rng.uniform(-1, 1, n) for _ in range(6)]
    cols[7][::97] = 3e-5  # exponent style in some rows: spliced in from Python's %
    out = format_rows(cols, fmts)
    assert out == savetxt_bytes(cols, fmts)
    assert out.count(b"\n") == n and b"3e-05" in out


def test_empty_and_mismatch():
    assert format_rows([np.zeros(0), np.zeros(0)], ["%d", "%.3f"]) == b""
    with pytest.raises(ValueError, match="2 columns but 1 formats"):
        format_rows([np.zeros(2), np.zeros(2)], ["%d"])
