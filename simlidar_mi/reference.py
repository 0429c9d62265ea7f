"""An independent float64 ray caster for closed cylinders: the yardstick for every representation.

Pure numpy, no Mitsuba.  A branch is a finite cylinder with flat end discs (what the
paper's geometry means), intersected analytically in float64.  Used by the tests
and by ``bench/`` to measure hit/miss disagreement and range error of the Mitsuba
representations (k-facet meshes, ``cylinder``, ``linearcurve``).
"""
from __future__ import annotations

import numpy as np

from .geometry import Branches
from .scan import ScanSettings

ESCAPE, GROUND, WOOD = 0, 1, 2
NO_ID = 0xFFFFFFFF


def ray_cylinders(o: np.ndarray, d: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                  radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays (R,3)+(R,3) with closed cylinders (C,…); returns t (R,) and index (R,).

    ``d`` need not be unit; t is in units of |d|.  Misses give t = inf and index −1.
    Works on the full R × C matrix: callers cull candidates first.
    """
    o = o[:, None, :]
    d = d[:, None, :]
    axis = p1 - p0
    h = np.linalg.norm(axis, axis=1)
    a = (axis / h[:, None])[None, :, :]
    w = o - p0[None, :, :]
    wa = np.sum(w * a, axis=2)
    da = np.sum(d * a, axis=2)
    wp = w - wa[..., None] * a
    dp = d - da[..., None] * a
    A = np.sum(dp * dp, axis=2)
    B = np.sum(wp * dp, axis=2)  # half of the usual b
    C = np.sum(wp * wp, axis=2) - radius[None, :] ** 2
    disc = B * B - A * C
    t_best = np.full(A.shape, np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        # Stable roots: q = −(B + sign(B)·√disc); t1 = q/A, t2 = C/q.
        q = -(B + np.copysign(sq, B))
        for t in (q / A, C / q):
            s = wa + t * da
            ok = (disc >= 0) & (A > 0) & np.isfinite(t) & (t > 0) & (s >= 0) & (s <= h[None, :])
            t_best = np.where(ok & (t < t_best), t, t_best)
        for s_cap in (np.zeros_like(h), h):
            t = (s_cap[None, :] - wa) / da
            rel = wp + t[..., None] * dp
            ok = (da != 0) & np.isfinite(t) & (t > 0) & (np.sum(rel * rel, axis=2) <= radius[None, :] ** 2)
            t_best = np.where(ok & (t < t_best), t, t_best)
    idx = np.argmin(t_best, axis=1)
    t_min = t_best[np.arange(len(idx)), idx]
    return t_min, np.where(np.isfinite(t_min), idx, -1)


def reference_scan(branches: Branches, settings: ScanSettings, positions: np.ndarray | None = None,
                   chunk: int = 4_000_000) -> dict[str, np.ndarray]:
    """Float64 first returns for the beams of ``settings`` at the sweep indices ``positions``.

    Returns arrays of shape (len(positions), M): ``range`` (escape distance where
    nothing is hit), ``class`` (0 escape, 1 ground, 2 wood), ``element_id`` (branch row),
    ``hit_fraction``.  Sub-beams follow the sensor plugin's dot matrix exactly.
    """
    s = settings
    positions = np.arange(s.n_positions) if positions is None else np.asarray(positions)
    P = s.footprint
    frac = (np.arange(P + 1) / P - 0.5) if P > 0 else np.zeros(1)
    theta = np.deg2rad(s.theta_deg[:, None] + frac[None, :] * s.dtheta_deg).ravel()  # (M·(P+1),)
    th_deg = (s.theta_deg[:, None] + frac[None, :] * s.dtheta_deg).ravel()
    dirs = np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    vertical = np.isclose(np.abs(th_deg), 90.0, rtol=0, atol=1e-12)
    dirs[vertical] = np.stack([np.zeros(vertical.sum()), np.zeros(vertical.sum()),
                               np.sign(th_deg[vertical])], axis=1)
    r = 0.5 * branches.diameter
    keep = branches.length > 0
    ylo = np.minimum(branches.p0[:, 1], branches.p1[:, 1]) - r
    yhi = np.maximum(branches.p0[:, 1], branches.p1[:, 1]) + r
    M, S1 = s.n_angles, P + 1
    out_rng = np.empty((len(positions), M))
    out_cls = np.empty((len(positions), M), np.uint8)
    out_id = np.empty((len(positions), M), np.uint32)
    out_frac = np.empty((len(positions), M))
    for row, i in enumerate(positions):
        ys = s.y_start_m + i * (s.gap + 1) * s.dy_m + frac * s.dy_m  # (P+1,)
        t_all = np.full((S1, M * S1), np.inf)
        id_all = np.full((S1, M * S1), -1)
        for a, y in enumerate(ys):
            cand = np.flatnonzero(keep & (ylo <= y) & (yhi >= y))
            o = np.broadcast_to(np.array([s.x0_m, y, s.z0_m]), dirs.shape)
            if len(cand):
                step = max(1, chunk // len(cand))
                for lo in range(0, len(dirs), step):
                    t, j = ray_cylinders(o[lo:lo + step], dirs[lo:lo + step], branches.p0[cand],
                                         branches.p1[cand], r[cand])
                    t_all[a, lo:lo + step] = t
                    id_all[a, lo:lo + step] = np.where(j >= 0, cand[np.maximum(j, 0)], -1)
        # (a, k, b) → beam k, sub-beams (a, b)
        t_sub = t_all.reshape(S1, M, S1).transpose(1, 0, 2).reshape(M, -1)
        id_sub = id_all.reshape(S1, M, S1).transpose(1, 0, 2).reshape(M, -1)
        dz = np.tile(dirs[:, 2].reshape(M, S1), (1, S1))
        cls_sub = np.where(np.isfinite(t_sub), WOOD, ESCAPE)
        if s.ground:
            with np.errstate(divide="ignore"):
                tg = np.where(dz < 0, (s.ground_z_m - s.z0_m) / dz, np.inf)
            g = tg < t_sub
            t_sub = np.where(g, tg, t_sub)
            cls_sub = np.where(g, GROUND, cls_sub)
            id_sub = np.where(g, -1, id_sub)
        first = np.argmin(t_sub, axis=1)
        k = np.arange(M)
        t_first = t_sub[k, first]
        out_rng[row] = np.where(np.isfinite(t_first), t_first, s.escape_m)
        out_cls[row] = cls_sub[k, first]
        out_id[row] = np.where(id_sub[k, first] >= 0, id_sub[k, first], NO_ID)
        out_frac[row] = np.mean(cls_sub == WOOD, axis=1)
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
