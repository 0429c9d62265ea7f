"""Partial traces align on the whole scan's packets (simlidar_mi.lidar.packets), so a chunk, a
tile or a worker gives the whole-scan bytes even where Embree's packet traversal rounds a
hit one ulp differently with other neighbours."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.lidar.packets import PACKET_ALIGN, aligned_span, padded_rows
from simlidar_mi.lidar.scan import BeamTracer
from simlidar_mi.lidar.survey import prepare_scan
from tests.conftest import SCENES


@pytest.mark.parametrize("base", [0, PACKET_ALIGN * 3, 1000])
def test_aligned_span_covers_the_beams_and_starts_and_ends_on_packets(base):
    rng = np.random.default_rng(5)
    total = 5000
    for _ in range(2000):
        first = int(rng.integers(0, total))
        count = int(rng.integers(1, total - first + 1))
        start, n, skip = aligned_span(first, count, total, base)
        assert 0 <= start <= first and start + skip == first and skip + count <= n
        assert start + n <= total and start + n >= first + count
        assert (base + start) % PACKET_ALIGN == 0 or start == 0  # a packet boundary or the sensor's start
        assert (base + start + n) % PACKET_ALIGN == 0 or start + n == total
        assert skip < PACKET_ALIGN and n - skip - count < PACKET_ALIGN
    assert aligned_span(0, total, total) == (0, total, 0)  # the whole scan: nothing widened


def test_padded_rows_hold_the_aligned_span_of_a_tile():
    for n_rows, n_cols in ((100, 601), (40, 3), (7, 1000)):
        for r0 in range(n_rows):
            for r1 in (r0 + 1, min(n_rows, r0 + 5), n_rows):
                ra, rb = padded_rows(r0, r1, n_rows, n_cols)
                assert 0 <= ra <= r0 < r1 <= rb <= n_rows
                start, n, skip = aligned_span(r0 * n_cols - ra * n_cols, (r1 - r0) * n_cols,
                                              (rb - ra) * n_cols, ra * n_cols)
                g0 = ra * n_cols + start  # the widened trace in global beams: packet edges or scan ends
                assert g0 % PACKET_ALIGN == 0
                assert (g0 + n) % PACKET_ALIGN == 0 or g0 + n == n_rows * n_cols


@pytest.fixture(scope="module")
def table3():
    cfg = load_scene(SCENES / "simlidar_table3_7x4.toml")
    patterns, built, _ = prepare_scan(cfg)
    tracer = BeamTracer(built, patterns[0], cfg["scene"]["variant"])
    return cfg, patterns[0], built, tracer, tracer.trace()


def test_an_unaligned_chunk_gives_the_whole_scan_bits(table3):
    """Beam 1,070,982 + 40,000 on the 7×4 row: before the alignment one range there came out one
    float32 ulp from the whole-scan trace (AVX-512, Embree 4 in Mitsuba 3.9.1)."""
    tracer, whole = table3[3:]
    for start, count in ((1070982, 40000), (1, 601), (12345, 7), (tracer.n_beams - 1000, 1000)):
        part = tracer.trace(start, count)
        for k in ("range", "cls", "elem", "frac"):
            assert np.array_equal(part[k], whole[k][start:start + count]), (start, k)
    rows = [block for _, _, block in tracer.row_blocks(16384)]  # 27 rows a chunk, as streamed
    assert np.array_equal(np.concatenate([b["range"] for b in rows]), whole["range"])


def test_a_tile_gives_the_whole_scan_bits(table3):
    cfg, settings, built, tracer, whole = table3
    M, N = tracer.pattern.n_cols, tracer.pattern.n_rows
    for r0, r1 in ((1781, 1790), (0, 3), (N - 2, N)):
        tile = BeamTracer(built, settings, cfg["scene"]["variant"], rows=(r0, r1))
        assert tile.n_beams == (r1 - r0) * M
        got = tile.trace()
        for k in ("range", "cls", "elem"):
            assert np.array_equal(got[k], whole[k][r0 * M:r1 * M]), (r0, k)
