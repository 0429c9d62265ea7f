"""An independent float64 ray caster for closed cylinders: the yardstick for every representation.

Pure numpy, no Mitsuba.  A branch is a finite cylinder with flat end discs (what the
paper's geometry means), intersected analytically in float64.  Used by the tests
and by ``bench/`` to measure hit/miss disagreement and range error of the Mitsuba
representations (k-facet meshes, ``cylinder``, ``linearcurve``).
"""
from __future__ import annotations

import numpy as np

from ..geometry import Branches
from .scan import ScanSettings

ESCAPE, GROUND, WOOD = 0, 1, 2
from ..geometry import NO_ID  # noqa: E402  (one definition: uint32 "none")


def ray_cylinder_pairs(o: np.ndarray, d: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                       radius: np.ndarray) -> np.ndarray:
    """Float64 hit distance for each (ray, cylinder) pair given row by row; inf on a miss."""
    axis = p1 - p0
    h = np.linalg.norm(axis, axis=1)
    a = axis / h[:, None]
    w = o - p0
    wa = np.einsum("ij,ij->i", w, a)
    da = np.einsum("ij,ij->i", d, a)
    wp = w - wa[:, None] * a
    dp = d - da[:, None] * a
    A = np.einsum("ij,ij->i", dp, dp)
    B = np.einsum("ij,ij->i", wp, dp)
    C = np.einsum("ij,ij->i", wp, wp) - radius ** 2
    disc = B * B - A * C
    best = np.full(len(A), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        q = -(B + np.copysign(sq, B))  # stable roots q/A and C/q
        for t in (q / A, C / q):
            s = wa + t * da
            ok = (disc >= 0) & (A > 0) & np.isfinite(t) & (t > 0) & (s >= 0) & (s <= h)
            best = np.where(ok & (t < best), t, best)
        for s_cap in (np.zeros_like(h), h):
            t = (s_cap - wa) / da
            rel = wp + t[:, None] * dp
            ok = (da != 0) & np.isfinite(t) & (t > 0) & (np.einsum("ij,ij->i", rel, rel) <= radius ** 2)
            best = np.where(ok & (t < best), t, best)
    return best


def _angular_ranges(x0: float, z0: float, p0, p1, r) -> tuple[np.ndarray, np.ndarray]:
    """Conservative elevation range [lo, hi] (radians) under which each cylinder's XZ bounding
    rectangle is seen from the scanner; beams only travel towards +x."""
    xlo = np.minimum(p0[:, 0], p1[:, 0]) - r
    xhi = np.maximum(p0[:, 0], p1[:, 0]) + r
    zlo = np.minimum(p0[:, 2], p1[:, 2]) - r
    zhi = np.maximum(p0[:, 2], p1[:, 2]) + r
    xs = np.stack([xlo, xhi], 1).clip(min=x0) - x0
    zs = np.stack([zlo, zhi], 1) - z0
    ang = np.arctan2(zs[:, :, None], xs[:, None, :]).reshape(len(r), 4)
    lo, hi = ang.min(1) - 1e-9, ang.max(1) + 1e-9
    inside = (xlo <= x0) & (zlo <= z0) & (zhi >= z0)
    lo = np.where(inside, -np.pi, lo)
    hi = np.where(inside, np.pi, hi)
    behind = xhi < x0
    return np.where(behind, np.inf, lo), np.where(behind, -np.inf, hi)


def reference_scan(branches: Branches, settings: ScanSettings,
                   positions: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Float64 first returns for the beams of ``settings`` at the sweep indices ``positions``.

    Returns arrays of shape (len(positions), M): ``range`` (escape distance where
    nothing is hit), ``class`` (0 escape, 1 ground, 2 wood), ``element_id`` (branch row),
    ``hit_fraction``.  Sub-beams follow the sensor plugin's dot matrix exactly.
    Candidates are culled by y slab and by elevation range before the exact test.
    """
    s = settings
    positions = np.arange(s.n_positions) if positions is None else np.asarray(positions)
    P = s.footprint
    S1 = P + 1
    M = s.n_angles
    frac = (np.arange(S1) / P - 0.5) if P > 0 else np.zeros(1)
    th_deg = (s.theta_deg[:, None] + frac[None, :] * s.dtheta_deg).ravel()  # (M·S1,) k-major
    theta = np.deg2rad(th_deg)
    dirs = np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    vertical = np.isclose(np.abs(th_deg), 90.0, rtol=0, atol=1e-12)
    dirs[vertical] = 0.0
    dirs[vertical, 2] = np.sign(th_deg[vertical])
    order = np.argsort(theta, kind="stable")
    theta_sorted = theta[order]
    keep = branches.length > 0
    r = 0.5 * branches.diameter
    ylo = np.minimum(branches.p0[:, 1], branches.p1[:, 1]) - r
    yhi = np.maximum(branches.p0[:, 1], branches.p1[:, 1]) + r
    lo_all, hi_all = _angular_ranges(s.x0_m, s.z0_m, branches.p0, branches.p1, r)
    out_rng = np.empty((len(positions), M))
    out_cls = np.empty((len(positions), M), np.uint8)
    out_id = np.empty((len(positions), M), np.uint32)
    out_frac = np.empty((len(positions), M))
    n_dir = len(dirs)
    for row, i in enumerate(positions):
        ys = s.y_start_m + i * (s.gap + 1) * s.dy_m + frac * s.dy_m
        t_sub = np.full((n_dir, S1), np.inf)   # (direction, y sub-position)
        id_sub = np.full((n_dir, S1), -1)
        for a, y in enumerate(ys):
            cand = np.flatnonzero(keep & (ylo <= y) & (yhi >= y))
            if not len(cand):
                continue
            # Rays whose elevation falls in each candidate's range: contiguous in sorted order.
            first = np.searchsorted(theta_sorted, lo_all[cand], "left")
            last = np.searchsorted(theta_sorted, hi_all[cand], "right")
            counts = np.maximum(last - first, 0)
            if counts.sum() == 0:
                continue
            c_rep = np.repeat(cand, counts)
            starts = np.repeat(first - np.cumsum(counts) + counts, counts)
            ray = order[np.arange(counts.sum()) + starts]
            o = np.broadcast_to(np.array([s.x0_m, y, s.z0_m]), (len(ray), 3))
            t = ray_cylinder_pairs(o, dirs[ray], branches.p0[c_rep], branches.p1[c_rep], r[c_rep])
            hit = np.isfinite(t)
            ray, t, c_rep = ray[hit], t[hit], c_rep[hit]
            srt = np.lexsort((t, ray))  # nearest hit per ray first
            ray, t, c_rep = ray[srt], t[srt], c_rep[srt]
            firsts = np.ones(len(ray), bool)
            firsts[1:] = ray[1:] != ray[:-1]
            t_sub[ray[firsts], a] = t[firsts]
            id_sub[ray[firsts], a] = c_rep[firsts]
        # direction index = k·S1 + b; sub-beams of beam k: all (b, a)
        t_beam = t_sub.reshape(M, S1 * S1)
        id_beam = id_sub.reshape(M, S1 * S1)
        dz = np.repeat(dirs[:, 2].reshape(M, S1), S1, axis=1)
        cls_beam = np.where(np.isfinite(t_beam), WOOD, ESCAPE)
        if s.ground:
            with np.errstate(divide="ignore"):
                tg = np.where(dz < 0, (s.ground_z_m - s.z0_m) / dz, np.inf)
            g = tg < t_beam
            t_beam = np.where(g, tg, t_beam)
            cls_beam = np.where(g, GROUND, cls_beam)
            id_beam = np.where(g, -1, id_beam)
        first = np.argmin(t_beam, axis=1)
        k = np.arange(M)
        t_first = t_beam[k, first]
        out_rng[row] = np.where(np.isfinite(t_first), t_first, s.escape_m)
        out_cls[row] = cls_beam[k, first]
        out_id[row] = np.where(id_beam[k, first] >= 0, id_beam[k, first], NO_ID)
        out_frac[row] = np.mean(cls_beam == WOOD, axis=1)
    return {"range": out_rng, "class": out_cls, "element_id": out_id, "hit_fraction": out_frac}


def compare(result_range, result_cls, ref: dict, escape_m: float) -> dict[str, float]:
    """Hit/miss disagreement (% of beams whose wood/not-wood verdict differs) and
    |Δrange| median and p99 (metres) over beams both call wood."""
    hit_a = np.asarray(result_cls) == WOOD
    hit_b = ref["class"] == WOOD
    both = hit_a & hit_b
    dr = np.abs(np.asarray(result_range, np.float64)[both] - ref["range"][both])
    return {
        "n_beams": int(hit_a.size),
        "n_hits_ref": int(hit_b.sum()),
        "disagree_pct": float(100.0 * np.mean(hit_a != hit_b)),
        "false_hit_pct": float(100.0 * np.mean(hit_a & ~hit_b)),
        "false_miss_pct": float(100.0 * np.mean(~hit_a & hit_b)),
        "drange_median_m": float(np.median(dr)) if dr.size else 0.0,
        "drange_p99_m": float(np.percentile(dr, 99)) if dr.size else 0.0,
    }
