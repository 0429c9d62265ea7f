"""Beams through a voxel grid: exact traversal and per-voxel beam statistics.

Every beam is a ray ``o + t·d`` (``d`` a unit vector, ``t`` in metres) that ends at
``t_end`` (its last return, or the escape range when nothing stopped it). Along it lie
its returns ``R_j`` with weights ``W_j`` (Σ W ≤ 1; a first-return scan has one return
of weight 1) that are vegetation (``V_j``) or not (ground). The weight still travelling
at distance t is ``w(t) = 1 − Σ_{R_j < t} W_j``.

The traversal is the voxel walk of Amanatides & Woo (1987, "A fast voxel traversal
algorithm for ray tracing", Eurographics '87, 3–10), vectorised over arrays of beams:
every active beam takes one step per iteration to the nearest voxel face along x, y or
z. The face distances are recomputed from the integer voxel index at each step (not
accumulated), so no error builds up along a beam; each beam's segments tile its in-grid
path [t_in, min(t_out, t_end)] exactly.

Per voxel v the walk accumulates (:class:`BeamCounts`), over beams b crossing v on
[t0, t1] (t1 the voxel exit, ``l = min(t1, t_end) − t0``):

``n_in``      Σ w_b(t0): beams (beam weight) entering v;
``hits``      Σ W_j·V_j over vegetation returns with t0 ≤ R_j < t1: beams intercepted in v;
``path_m``    Σ ∫_{t0}^{min(t1,t_end)} w_b(t) dt: the free path length actually travelled
              in v (truncated at each return), the exposure of Pimont et al. (2018);
``chord_m``   Σ w_b(t0)·(t1 − t0) minus the part cut off by non-vegetation returns
              (ground): the chord each entering beam would cross if the vegetation in v
              did not stop it, whose mean is the "mean path length" of Beer–Lambert
              (Béland et al. 2011, 2014; Grau et al. 2017).

Returns are pulled back along their beam by :data:`RANGE_TOL_M` (10 µm) before they are
placed, so a surface lying on a voxel face (the ground, a trunk's base, a post's foot) counts
in the voxel the beam came from, not in the one a float32 range rounds it into (a beam that
enters a voxel for 3 µm and "hits" there would read PAD ~10⁶ m²/m³). Zero-length segments (a
beam grazing an edge or a corner) enter nothing unless a return lies in them. Returns before the grid reduce the weight entering it; returns
beyond it are ignored.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from .grid import VoxelGrid

__all__ = ["Beams", "BeamCounts", "walk", "traverse", "DEFAULT_CHUNK_BEAMS", "RANGE_TOL_M"]

#: Returns are placed this far before their range (module docstring): above float32's
#: rounding of ranges up to ~150 m (6e-8 relative), far below any voxel.
RANGE_TOL_M = 1e-5

#: Beams walked together: ~(chunk × 25 float64) per array of the walk, ≈ 100 MB at 2**18.
DEFAULT_CHUNK_BEAMS = 1 << 18


@dataclass
class Beams:
    """Rays with their returns (module docstring). Arrays over n beams and K returns per beam.

    ``ret_range_m`` (n, K) is +inf where a beam has fewer than K returns (weight 0)."""

    origin_m: np.ndarray    # (n, 3) float64
    dir: np.ndarray         # (n, 3) float64 unit vectors
    t_end_m: np.ndarray     # (n,) float64
    ret_range_m: np.ndarray  # (n, K) float64
    ret_weight: np.ndarray   # (n, K) float64
    ret_veg: np.ndarray      # (n, K) bool
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.origin_m = np.asarray(self.origin_m, np.float64).reshape(-1, 3)
        d = np.asarray(self.dir, np.float64).reshape(-1, 3)
        norm = np.linalg.norm(d, axis=1)
        if np.any(~np.isfinite(norm) | (norm == 0)):
            raise ConfigError("beam directions must be finite and non-zero", key="dir")
        self.dir = d / norm[:, None]
        n = len(self.dir)
        self.t_end_m = np.broadcast_to(np.asarray(self.t_end_m, np.float64), (n,)).copy()
        r = np.asarray(self.ret_range_m, np.float64).reshape(n, -1)
        self.ret_range_m = r
        self.ret_weight = np.asarray(self.ret_weight, np.float64).reshape(r.shape)
        self.ret_veg = np.asarray(self.ret_veg, bool).reshape(r.shape)
        if len(self.origin_m) not in (1, n):
            raise ConfigError(f"{len(self.origin_m)} origins for {n} beams", key="origin_m")
        if len(self.origin_m) == 1 and n > 1:
            self.origin_m = np.repeat(self.origin_m, n, axis=0)

    def __len__(self) -> int:
        return len(self.dir)

    @classmethod
    def first_return(cls, origin_m, dir, range_m, cls_code, meta: dict | None = None) -> "Beams":
        """Beams of a first-return scan: class 0 escape (travels to ``range_m``, the escape
        range), 1 ground (stops there, not vegetation), 2 wood / 3 leaf (intercepted)."""
        r = np.asarray(range_m, np.float64).ravel()
        c = np.asarray(cls_code).ravel()
        stop = c != 0
        return cls(origin_m, dir, r, np.where(stop, r, np.inf)[:, None], stop.astype(np.float64)[:, None],
                   ((c == 2) | (c == 3))[:, None], meta or {})

    def take(self, sl) -> "Beams":
        return Beams(self.origin_m[sl], self.dir[sl], self.t_end_m[sl], self.ret_range_m[sl],
                     self.ret_weight[sl], self.ret_veg[sl], self.meta)

    def vegetation_points_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(points (m, 3), weights (m,)) of every vegetation return, each :data:`RANGE_TOL_M`
        before its range as the walk places it."""
        b, j = np.nonzero(self.ret_veg & np.isfinite(self.ret_range_m) & (self.ret_weight > 0))
        p = self.origin_m[b] + (self.ret_range_m[b, j] - RANGE_TOL_M)[:, None] * self.dir[b]
        return p, self.ret_weight[b, j]


@dataclass
class BeamCounts:
    """Per-voxel sums of the walk (module docstring), arrays of ``grid.shape``."""

    grid: VoxelGrid
    n_in: np.ndarray
    hits: np.ndarray
    path_m: np.ndarray
    chord_m: np.ndarray
    n_beams: int = 0

    @classmethod
    def zeros(cls, grid: VoxelGrid) -> "BeamCounts":
        z = lambda: np.zeros(grid.shape, np.float64)  # noqa: E731
        return cls(grid, z(), z(), z(), z())


def _slab(grid: VoxelGrid, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances of rays through the grid's box (t_in > t_out or NaN: a miss)."""
    lo = np.asarray(grid.corner_m)
    hi = grid.hi_m
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        a = (lo - o) * inv
        b = (hi - o) * inv
    # An axis-parallel ray inside the slab: (−inf, +inf); outside it: a miss (nan → excluded).
    par = d == 0
    inside = (o >= lo) & (o < hi)  # voxels are half-open [lo, hi): a ray on the top face is out
    a = np.where(par, np.where(inside, -np.inf, np.nan), a)
    b = np.where(par, np.where(inside, np.inf, np.nan), b)
    return np.minimum(a, b).max(axis=1), np.maximum(a, b).min(axis=1)


def walk(grid: VoxelGrid, origin_m, dir, t_end_m):
    """Yield per step arrays ``(beam, flat_voxel, t0, t1)`` of the voxel segments of the rays
    ``origin + t·dir`` for t in [0, t_end] (Amanatides & Woo 1987, vectorised); ``t1`` is the
    voxel exit (not clipped to t_end). Beams are indices into the inputs."""
    o = np.asarray(origin_m, np.float64).reshape(-1, 3)
    d = np.asarray(dir, np.float64).reshape(-1, 3)
    t_end = np.asarray(t_end_m, np.float64).ravel()
    t_in, t_out = _slab(grid, o, d)
    t_in = np.maximum(t_in, 0.0)
    t_stop = np.minimum(t_out, t_end)
    live = np.nonzero(t_in <= t_stop)[0]
    if not len(live):
        return
    shape = np.asarray(grid.shape)
    origin = np.asarray(grid.corner_m)
    v = grid.voxel_m
    o, d, t = o[live], d[live], t_in[live]
    stop, idx = t_stop[live], live
    step = np.where(d > 0, 1, np.where(d < 0, -1, 0)).astype(np.int64)
    # The entry voxel, clamped for entry points on (or a rounding error outside) the box;
    # a ray starting on an inner face heading down gets a zero-length first segment.
    ijk = np.clip(np.floor((o + t[:, None] * d - origin) / v).astype(np.int64), 0, shape - 1)
    nxt = (ijk + (step > 0)).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(d != 0, 1.0 / np.where(d != 0, d, 1.0), np.inf)
    while len(idx):
        face = origin + nxt * v
        with np.errstate(invalid="ignore"):  # 0·inf on axes the ray does not cross
            tmax = np.where(step != 0, (face - o) * inv, np.inf)
        axis = np.argmin(tmax, axis=1)
        rows = np.arange(len(idx))
        t1 = np.maximum(tmax[rows, axis], t)  # never behind the entry (float round-off)
        flat = (ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2]
        yield idx, flat, t, t1
        ijk[rows, axis] += step[rows, axis]
        nxt[rows, axis] += step[rows, axis]
        t = t1
        keep = np.all((ijk >= 0) & (ijk < shape), axis=1) & (t <= stop) & np.isfinite(t)
        if not keep.all():
            o, d, inv, t, stop, idx, ijk, nxt, step = (a[keep] for a in (o, d, inv, t, stop, idx, ijk, nxt, step))


def traverse(grid: VoxelGrid, beams: Beams, counts: BeamCounts | None = None, *,
             chunk_beams: int = DEFAULT_CHUNK_BEAMS, progress=None, on_segment=None) -> BeamCounts:
    """Accumulate ``beams`` into per-voxel :class:`BeamCounts` (module docstring), walking
    ``chunk_beams`` beams at a time so memory stays bounded; ``progress(n)`` is called
    with the beams done after each chunk. ``on_segment(beam, flat_voxel, w_in, chord_m)``,
    if given, sees every segment counted in ``n_in`` (beam indices into ``beams``), e.g. to
    weight a per-beam quantity as the counts are weighted (:mod:`~simlidar_mi.truth.leaf_g`)."""
    counts = counts or BeamCounts.zeros(grid)
    size = int(np.prod(grid.shape))
    acc = {k: getattr(counts, k).reshape(-1) for k in ("n_in", "hits", "path_m", "chord_m")}
    for a in range(0, len(beams), max(1, int(chunk_beams))):
        b = beams.take(slice(a, a + chunk_beams))
        R, W, V = b.ret_range_m - RANGE_TOL_M, b.ret_weight, b.ret_veg
        stops = np.any(np.isfinite(b.ret_range_m) & (b.ret_range_m >= b.t_end_m[:, None]), axis=1)
        t_end = np.where(stops, b.t_end_m - RANGE_TOL_M, b.t_end_m)
        for idx, flat, t0, t1 in walk(grid, b.origin_m, b.dir, t_end):
            r, w, veg = R[idx], W[idx], V[idx]
            end = np.minimum(t1, t_end[idx])
            w_in = 1.0 - np.sum(np.where(r < t0[:, None], w, 0.0), axis=1)
            inside = (r >= t0[:, None]) & (r < t1[:, None])
            w_here = np.where(inside, w, 0.0)
            hit = np.sum(np.where(veg, w_here, 0.0), axis=1)
            cut = np.where(inside, w * (end[:, None] - np.minimum(r, end[:, None])), 0.0)
            path = w_in * (end - t0) - np.sum(cut, axis=1)
            ground_cut = np.where(veg, 0.0, w_here * (t1[:, None] - np.minimum(r, t1[:, None])))
            chord = w_in * (t1 - t0) - np.sum(ground_cut, axis=1)
            used = ((end - t0) > 0) | inside.any(axis=1)
            used &= w_in > 0
            if not used.all():
                flat, w_in, hit, path, chord = flat[used], w_in[used], hit[used], path[used], chord[used]
                idx = idx[used]
            if on_segment is not None:
                on_segment(a + idx, flat, w_in, np.maximum(chord, 0.0))
            acc["n_in"] += np.bincount(flat, w_in, size)
            acc["hits"] += np.bincount(flat, hit, size)
            acc["path_m"] += np.bincount(flat, np.maximum(path, 0.0), size)
            acc["chord_m"] += np.bincount(flat, np.maximum(chord, 0.0), size)
        counts.n_beams += len(b)
        if progress is not None:
            progress(len(b))
    return counts
