"""The fast paths of the EXR and range-image writers (issue #8) equal straightforward
reference implementations bit for bit: the EXR ZIP predictor, whole files written rows at a
time in any feeding, the range image's block reduction and colouring, on random input with
NaN, ±inf, −0.0, empty and one-element edge cases."""
from __future__ import annotations

import zlib

import numpy as np
import pytest

from simlidar_mi.io.exr import ScanlineExrWriter, _header_bytes, _predict, read_exr
from simlidar_mi.io.plots import (ESCAPE_RGB, GROUND_RGB, VIRIDIS_LUT, RangeImageReducer, _block_reduce,
                                  lut_index, range_limits, range_rgb)

# --- EXR --------------------------------------------------------------------------------


def _ref_predict(raw: bytes) -> bytes:
    """The EXR ZIP predictor as the format states it, one byte at a time."""
    split = raw[0::2] + raw[1::2]
    return bytes([split[0]] + [(split[i] - split[i - 1] + 128) % 256 for i in range(1, len(split))]) \
        if split else b""


@pytest.mark.parametrize("size", [0, 1, 2, 3, 4, 17, 64, 1001])
def test_predict_is_the_formats_definition(size):
    raw = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8)
    split, pred = np.full(size, 7, np.uint8), np.full(size, 9, np.uint8)  # stale scratch must not leak
    _predict(raw, split, pred)
    assert pred.tobytes() == _ref_predict(raw.tobytes())
    assert np.array_equal(raw, np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8))


def _ref_exr(path, header, dtypes, n, m, chans) -> bytes:
    """An EXR as the format defines it, block after block, from whole channels."""
    names = sorted(dtypes, key=lambda k: k.encode())
    dt = {k: np.dtype(dtypes[k]).newbyteorder("<") for k in names}
    head = _header_bytes(header, dt, n, m)
    blocks = []
    for y in range(0, n, 16):
        raw = b"".join(np.asarray(chans[k][i], dt[k]).tobytes() for i in range(y, min(n, y + 16)) for k in names)
        packed = zlib.compress(_ref_predict(raw), 4)
        payload = packed if len(packed) < len(raw) else raw
        blocks.append(np.array([y, len(payload)], "<i4").tobytes() + payload)
    at = len(head) + 8 * len(blocks)
    table = []
    for b in blocks:
        table.append(at)
        at += len(b)
    return head + np.asarray(table, "<u8").tobytes() + b"".join(blocks)


def _random_channels(rng, n, m):
    rng_m = (rng.random((n, m)) * 30).astype(np.float32)
    special = np.array([np.nan, np.inf, -np.inf, -0.0], np.float32)[: n * m]
    rng_m.reshape(-1)[: len(special)] = special
    ids = rng.integers(0, 2**32, (n, m), dtype=np.uint64).astype(np.uint32)
    ids.reshape(-1)[:1] = 0xFFFFFFFF  # no element
    return {"range": rng_m,  # float32 as given
            "class": rng.integers(0, 4, (n, m)).astype(np.uint8),  # cast to uint32 by the writer
            "branch_id": ids,
            "hit_fraction": rng.random((n, m)),  # float64, cast to float32
            "half": rng.standard_normal((n, m)).astype(np.float16)}


@pytest.mark.parametrize("n,m", [(0, 5), (1, 1), (15, 3), (16, 7), (37, 11), (70, 1), (49, 40)])
def test_scanline_exr_is_the_reference_file_in_any_feeding(tmp_path, n, m):
    rng = np.random.default_rng(n * 100 + m)
    chans = _random_channels(rng, n, m)
    dtypes = {"range": np.float32, "class": np.uint32, "branch_id": np.uint32, "hit_fraction": np.float32,
              "half": np.float16}
    import OpenEXR
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "seed": 3}
    expect = _ref_exr(tmp_path / "ref.exr", header, dtypes, n, m, chans)
    feeds = [[n], [1] * n, list(rng.integers(0, 20, 40))]
    for j, feed in enumerate(feeds):
        path = tmp_path / f"f{j}.exr"
        with ScanlineExrWriter(path, header, dtypes, n, m, threads=1 + j % 2) as w:
            a = 0
            for r in feed:
                b = min(n, a + int(r))
                rows = {k: v[a:b].copy() for k, v in chans.items()}
                w.write_rows(rows)
                for v in rows.values():  # the caller may reuse its arrays once write_rows returns
                    v[...] = 0
                a = b
                if a == n:
                    break
            if a < n:
                w.write_rows({k: v[a:] for k, v in chans.items()})
        assert path.read_bytes() == expect, feed
    if n:  # OpenEXR's own reader gives the channels back
        got, _ = read_exr(tmp_path / "f0.exr")
        for k, t in dtypes.items():
            assert got[k].tobytes() == np.asarray(chans[k], t).tobytes(), k


# --- range image ------------------------------------------------------------------------


def _ref_range_rgb(range_m, cls, max_px, limits):
    """range_rgb as the module docstring states it: padded blocks, an RGB image painted
    ground/escape then the LUT on finite nearest vegetation ranges, turned angle-up."""
    n, m = range_m.shape
    vmin, vmax = limits if limits is not None else (range_limits(range_m, cls) or (0.0, 0.0))
    fr, fc = -(-n // max_px), -(-m // max_px)
    veg = (cls == 2) | (cls == 3)
    near = np.full((-(-n // fr) * fr, -(-m // fc) * fc), np.inf, np.float32)
    gnd = np.zeros(near.shape, bool)
    near[:n, :m] = np.where(veg, range_m, np.float32(np.inf))
    gnd[:n, :m] = cls == 1
    shape = (near.shape[0] // fr, fr, near.shape[1] // fc, fc)
    near = near.reshape(shape).min(axis=(1, 3))
    gnd = gnd.reshape(shape).any(axis=(1, 3))
    out = np.where(gnd[..., None], np.array(GROUND_RGB, np.uint8), np.array(ESCAPE_RGB, np.uint8))
    hit = np.isfinite(near)
    out[hit] = VIRIDIS_LUT[lut_index(near[hit], vmin, vmax)]
    return np.ascontiguousarray(out.transpose(1, 0, 2)[::-1]), (fr, fc)


def _random_scan(rng, n, m):
    cls = rng.integers(0, 4, (n, m)).astype(rng.choice([np.uint8, np.uint32, np.int64]))
    r = (rng.random((n, m)) * 20).astype(np.float32)
    for value in (np.nan, np.inf, -0.0, 0.0):
        r[rng.random((n, m)) < 0.05] = value
    return r, cls


def test_range_rgb_and_reducer_equal_the_reference():
    rng = np.random.default_rng(8)
    cases = [(1, 1, 1), (1, 1, 4096), (2, 3, 1), (5, 1, 2), (33, 17, 4), (40, 7, 40), (64, 64, 8)]
    cases += [tuple(int(x) for x in (*rng.integers(1, 70, 2), rng.integers(1, 25))) for _ in range(60)]
    with np.errstate(invalid="ignore"):
        for i, (n, m, max_px) in enumerate(cases):
            r, cls = _random_scan(rng, n, m)
            if i % 5 == 1:
                cls[...] = 1  # no vegetation: no limits
            if i % 5 == 2:
                r[...] = 4.5  # one range: the colour scale collapses to entry 0
            limits = None if i % 3 else range_limits(r, cls)
            expect, blocks = _ref_range_rgb(r, cls, max_px, limits)
            got, got_blocks = range_rgb(r, cls, max_px=max_px, limits=limits)
            assert got_blocks == blocks and got.dtype == np.uint8 and np.array_equal(got, expect), (n, m, max_px)
            red = RangeImageReducer(n, m, max_px)
            cuts = sorted({0, n, *(int(c) for c in rng.integers(0, n + 1, 3))})
            for a, b in zip(cuts[:-1], cuts[1:]):
                red.add(a, r[a:b], cls[a:b])
            got, got_blocks = red.rgb()
            # the running limits (a NaN vegetation range drops its whole slice from both limits)
            ref, _ = _ref_range_rgb(r, cls, max_px, red.limits)
            assert got_blocks == blocks and np.array_equal(got, ref), ("reducer", n, m, max_px)


def test_block_reduce_equals_padded_reshape():
    rng = np.random.default_rng(3)
    for n, m, fr, fc in [(1, 1, 1, 2), (7, 5, 3, 2), (8, 9, 4, 3), (9, 4, 2, 1), (3, 10, 1, 4), (2, 2, 5, 5)]:
        a = rng.random((n, m)).astype(np.float32)
        a[rng.random((n, m)) < 0.2] = np.inf
        a[rng.random((n, m)) < 0.1] = np.nan
        pad = np.full((-(-n // fr) * fr, -(-m // fc) * fc), np.inf, np.float32)
        pad[:n, :m] = a
        with np.errstate(invalid="ignore"):
            expect = np.minimum.reduce(np.minimum.reduce(pad.reshape(-1, fr, pad.shape[1] // fc, fc), axis=3), axis=1)
        assert np.array_equal(_block_reduce(a, fr, fc, np.minimum, np.inf), expect, equal_nan=True)
        b = a > 0.5
        padb = np.zeros(pad.shape, bool)
        padb[:n, :m] = b
        expect = padb.reshape(-1, fr, pad.shape[1] // fc, fc).any(axis=(1, 3))
        assert np.array_equal(_block_reduce(b, fr, fc, np.logical_or, False), expect)
