"""Beam ranges that start and end on packet boundaries, so a chunk traces what the whole scan does.

Dr.Jit's LLVM backend hands rays to Embree in packets of its SIMD width (16 lanes with
AVX-512, 8 with AVX2), cut from the traced array in order. Embree's packet traversal can
finish a ray with the packet or with the single-ray intersector depending on how many lanes
are still active, and the two round differently: a ray's hit distance can move by one float32
ulp with the rays that share its packet. Measured on ``scenes/simlidar_table3_7x4.toml``
(2.5 M beams, AVX-512): a trace started at beam 1,070,982 (≡ 6 mod 16) gave 1 range of 40,000
one ulp away from the whole-scan trace; starts on multiples of 16 gave none over 32 windows,
on multiples of 8 one.

So every partial trace is widened to global beam indices that are multiples of
:data:`PACKET_ALIGN` (clipped to the scan) and the extra beams are dropped: each ray then
meets the neighbours it meets in the whole-scan trace, whatever the chunk, the tile or the
worker. The widening costs at most ``2 · PACKET_ALIGN`` extra beams a trace.
"""
from __future__ import annotations

PACKET_ALIGN = 256  # a multiple of every SIMD width Dr.Jit's LLVM backend uses (≤ 16 lanes)


def aligned_span(first: int, count: int, total: int, base: int = 0) -> tuple[int, int, int]:
    """Which beams to trace for beams ``[first, first + count)`` of a sensor holding ``total``
    beams whose beam 0 is beam ``base`` of the whole scan (a tile's sensor; 0 otherwise).

    Returns ``(start, n, skip)``: trace the sensor's beams ``[start, start + n)`` and keep
    ``[skip, skip + count)`` of them. The widened range starts and ends on multiples of
    :data:`PACKET_ALIGN` in the whole scan, or at the sensor's own ends."""
    if count <= 0:
        return first, 0, 0
    g0, g1 = base + first, base + first + count
    a0 = max(base, g0 - g0 % PACKET_ALIGN)
    a1 = min(base + total, -(-g1 // PACKET_ALIGN) * PACKET_ALIGN)
    return a0 - base, a1 - a0, g0 - a0


def padded_rows(r0: int, r1: int, n_rows: int, n_cols: int) -> tuple[int, int]:
    """Rows ``(ra, rb)`` ⊇ ``(r0, r1)`` of a scan of ``n_rows × n_cols`` beams that hold the
    packet-aligned widening of rows r0 … r1 − 1: the rows a tile's sensor needs so that
    :func:`aligned_span` never has to stop at the tile's own ends inside a packet."""
    g0, g1 = r0 * n_cols, r1 * n_cols
    a0 = g0 - g0 % PACKET_ALIGN
    a1 = min(n_rows * n_cols, -(-g1 // PACKET_ALIGN) * PACKET_ALIGN)
    return a0 // n_cols, min(n_rows, -(-a1 // n_cols))
