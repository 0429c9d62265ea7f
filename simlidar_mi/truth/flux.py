"""Exact per-voxel volume of cylinder pieces by the divergence theorem (closed form).

Work is in voxel units (voxel ``(i, j, k)`` is ``[i, i+1) × [j, j+1) × [k, k+1)``). A
piece starts at ``c``, has unit axis ``a`` (with ``u, v`` completing an orthonormal
frame), length ``L`` and radius ``r``; ``t = (x − c)·a`` is the axial coordinate.

The field ``F = t·a`` has divergence ``a·a = 1``, so the volume of the piece inside a
voxel is the outward flux of ``F`` through the boundary of (piece ∩ voxel)
(Gauss's divergence theorem). On that boundary

* the lateral surface contributes nothing (``a·n = 0`` there);
* the start disc contributes nothing (``t = 0``);
* the end disc (``t = L``, ``n = a``) contributes ``L × area(end disc ∩ voxel)``;
* a voxel face ``x_k = w`` with outward normal ``±e_k`` contributes
  ``±a_k ∫ t dA`` over the piece's cross-section in that face.

A face is shared by two voxels with opposite normals, so each face integral is computed
once and added to the voxel below it and subtracted from the voxel above it; per-voxel
volumes therefore sum to ``L·πr²`` to rounding. Both kinds of term are integrals over
the unit disc of the piece's cross-section coordinates ``y = ((x−c)·u, (x−c)·v)/r``
clipped to a convex polygon (the voxel, the face square and ``0 ≤ t ≤ L`` are
half-planes in ``y``): a cross-section in the plane ``x_k = w`` maps to ``y`` with the
area factor ``r²/|a_k|``, and ``a_k·t = w − c_k − r(u_k, v_k)·y``, so a face term is
``sgn(a_k)·r²·[(w − c_k)·A − r(u_k M₁ + v_k M₂)]`` with ``A, M₁, M₂`` the area and
first moments of (unit disc ∩ polygon). Those come from Green's theorem edge by edge:
each polygon edge contributes its part inside the disc as a straight segment and its
parts outside as the arc between the same polar angles (the radial pieces cancel
between consecutive edges), both integrated in closed form. No quadrature: the
result is exact to rounding.
"""
from __future__ import annotations

import numpy as np

__all__ = ["disc_polygon_moments", "clip_halfplanes", "halfplane_disc_moments", "disc_areas", "flux_volume"]

MAX_V = 10  # a square clipped by six half-planes has at most 10 vertices
ROWS_PER_CHUNK = 25_000  # rows of (10-vertex polygon) work per numpy batch: ~30 MB peak
LOW_AK = 1e-2  # faces with |a_k| below this are integrated in np.longdouble


def clip_halfplanes(g: np.ndarray, b: np.ndarray, half: float = 2.0):
    """Convex polygons {y ∈ [−half, half]²: g_m·y ≤ b_m for every m} (Sutherland & Hodgman
    1974), g (n, m, 2), b (n, m). Returns vertices (n, MAX_V, 2), counter-clockwise,
    and counts (n,)."""
    n, m = b.shape
    if m + 4 > MAX_V:
        raise ValueError(f"at most {MAX_V - 4} half-planes")
    poly = np.zeros((n, MAX_V, 2), g.dtype)
    poly[:, :4] = np.array([[-half, -half], [half, -half], [half, half], [-half, half]], g.dtype)
    cnt = np.full(n, 4)
    j = np.arange(MAX_V)
    for h in range(m):
        valid = j[None, :] < cnt[:, None]
        nxt = np.where(j[None, :] + 1 < cnt[:, None], j[None, :] + 1, 0)
        q = np.take_along_axis(poly, nxt[..., None], axis=1)
        gh, bh = g[:, h][:, None, :], b[:, h][:, None]
        d0 = bh - (poly * gh).sum(axis=2)  # ≥ 0 inside
        d1 = bh - (q * gh).sum(axis=2)
        in0, in1 = d0 >= 0, d1 >= 0
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(in0 != in1, d0 / (d0 - d1), 0.0)
        out = np.empty((n, MAX_V, 2, 2), g.dtype)
        out[:, :, 0] = poly
        out[:, :, 1] = poly + s[..., None] * (q - poly)
        emit = np.stack([valid & in0, valid & (in0 != in1)], axis=2).reshape(n, 2 * MAX_V)
        order = np.argsort(~emit, axis=1, kind="stable")[:, :MAX_V]
        poly = np.take_along_axis(out.reshape(n, 2 * MAX_V, 2), order[..., None], axis=1)
        cnt = np.minimum(emit.sum(axis=1), MAX_V)
    return poly, cnt


def _unit(p):
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def _arc(a, b):
    """Area, ∫y₁, ∫y₂ contributions of the unit-circle arc from direction a to b (the
    short way): ½Δθ, ½[sin θ − sin³θ/3], ½[−cos θ + cos³θ/3]."""
    a, b = _unit(a), _unit(b)
    d = np.arctan2(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], (a * b).sum(axis=-1))
    m1 = 0.5 * ((b[..., 1] - b[..., 1] ** 3 / 3) - (a[..., 1] - a[..., 1] ** 3 / 3))
    m2 = 0.5 * ((-b[..., 0] + b[..., 0] ** 3 / 3) - (-a[..., 0] + a[..., 0] ** 3 / 3))
    return 0.5 * d, m1, m2


def disc_polygon_moments(poly: np.ndarray, cnt: np.ndarray):
    """Area A and first moments M₁ = ∫y₁ dA, M₂ = ∫y₂ dA of (unit disc ∩ convex polygon),
    polygons (n, V, 2) counter-clockwise with ``cnt`` vertices (fewer than 3: empty)."""
    n, V, _ = poly.shape
    j = np.arange(V)
    valid = (j[None, :] < cnt[:, None]) & (cnt[:, None] >= 3)
    nxt = np.where(j[None, :] + 1 < cnt[:, None], j[None, :] + 1, 0)
    P = poly
    Q = np.take_along_axis(poly, nxt[..., None], axis=1)
    D = Q - P
    DD, pD, pp = (D * D).sum(-1), (P * D).sum(-1), (P * P).sum(-1)
    disc = pD * pD - DD * (pp - 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        s0 = np.clip((-pD - sq) / DD, 0.0, 1.0)
        s1 = np.clip((-pD + sq) / DD, 0.0, 1.0)
    line = valid & (DD > 0) & (disc > 0) & (s1 > s0)
    s0 = np.where(line, s0, 1.0)  # no segment inside: one arc from P to Q
    s1 = np.where(line, s1, 1.0)
    X0 = P + s0[..., None] * D
    X1 = P + s1[..., None] * D
    # straight part X0 → X1 inside the disc
    E = X1 - X0
    A = 0.5 * (X0[..., 0] * X1[..., 1] - X0[..., 1] * X1[..., 0])
    M1 = 0.5 * E[..., 1] * (X0[..., 0] ** 2 + X0[..., 0] * E[..., 0] + E[..., 0] ** 2 / 3)
    M2 = -0.5 * E[..., 0] * (X0[..., 1] ** 2 + X0[..., 1] * E[..., 1] + E[..., 1] ** 2 / 3)
    A, M1, M2 = (np.where(line, x, 0.0) for x in (A, M1, M2))  # new arrays
    # arcs P → X0 (P outside) and X1 → Q (Q outside)
    # (a repeated vertex, D = 0, contributes nothing; P and Q of an arc lie outside the disc)
    for on, a, b in ((valid & (DD > 0) & (s0 > 0), P, X0), (line & (s1 < 1), X1, Q)):
        da, d1, d2 = _arc(a[on], b[on])
        A[on] += da
        M1[on] += d1
        M2[on] += d2
    return A.sum(axis=1), M1.sum(axis=1), M2.sum(axis=1)


def halfplane_disc_moments(g: np.ndarray, b: np.ndarray):
    """A, M₁, M₂ of {unit disc: g_m·y ≤ b_m for every m} (g (n, m, 2), b (n, m)). Rows
    with a half-plane that misses the disc are 0 without clipping."""
    miss = np.any(b < -np.linalg.norm(g, axis=2), axis=1)
    out = [np.zeros(len(b), g.dtype) for _ in range(3)]
    keep = ~miss
    if keep.any():
        for o, x in zip(out, disc_polygon_moments(*clip_halfplanes(g[keep], b[keep]))):
            o[keep] = x
    return out


def _ranges(lo, hi):
    """Voxel index ranges [floor(lo), max(floor(lo), ceil(hi) − 1)] per row and axis."""
    a = np.floor(lo).astype(np.int64)
    return a, np.maximum(a, np.ceil(hi).astype(np.int64) - 1) - a + 1


def _expand(start, count):
    """Rows × the cells of their index boxes: (owner, ijk (m, 3)). count (n, 3) ≥ 1."""
    tot = count.prod(axis=1)
    owner = np.repeat(np.arange(len(tot)), tot)
    local = np.arange(len(owner)) - np.repeat(np.cumsum(tot) - tot, tot)
    c = count[owner]
    ijk = np.stack([local // (c[:, 1] * c[:, 2]), (local // c[:, 2]) % c[:, 1], local % c[:, 2]], axis=1)
    return owner, start[owner] + ijk


def _slices(rows):
    """Consecutive slices of pieces holding about ROWS_PER_CHUNK rows each (≥ 1 piece)."""
    cum = np.cumsum(rows)
    s = 0
    while s < len(rows):
        base = cum[s - 1] if s else 0
        e = max(s + 1, int(np.searchsorted(cum, base + ROWS_PER_CHUNK, side="right")))
        yield slice(s, e)
        s = e


def disc_areas(centre, a, u, v, r, add, scale=None) -> None:
    """Area of flat discs (centre (n, 3), unit normal a, in-plane frame u, v, radius r;
    voxel units) in each voxel they meet, times ``scale`` (n,) if given, passed to
    ``add(ijk, w)``: r²·area(unit disc ∩ the voxel's six half-planes), closed form. A disc
    lying in a voxel plane belongs to the voxel above it (its index range there is the
    one voxel ``floor``)."""
    w0 = r ** 2 if scale is None else scale * r ** 2
    uv = np.stack([u, v], axis=2)
    ext = r[:, None] * np.sqrt(np.clip(1.0 - a ** 2, 0.0, None))
    start, count = _ranges(centre - ext, centre + ext)
    for sl in _slices(count.prod(axis=1)):
        own, ijk = _expand(start[sl], count[sl])
        g = r[sl][own, None, None] * uv[sl][own]  # x_i = e_i + g_i·y
        e = centre[sl][own]
        G = np.concatenate([-g, g], axis=1)  # x_i ≥ i0 and x_i ≤ i0 + 1
        B = np.concatenate([e - ijk, ijk + 1.0 - e], axis=1)
        A, _, _ = halfplane_disc_moments(G, B)
        add(ijk, w0[sl][own] * A)


def flux_volume(P: dict, add) -> None:
    """Per-voxel volume of cylinder pieces (dict of arrays as from
    :func:`simlidar_mi.truth.voxelize.cylinder_pieces`: c, a, u, v, L, r), passed to
    ``add(ijk (m, 3), volume (m,))`` in voxel units³."""
    c, a, u, v, L, r = P["c"], P["a"], P["u"], P["v"], P["L"], P["r"]
    if not len(L):
        return
    e1 = c + L[:, None] * a
    uv = np.stack([u, v], axis=2)  # (n, 3, 2): (u_i, v_i) per axis

    # end discs: L × area(end disc ∩ voxel)
    disc_areas(e1, a, u, v, r, add, scale=L)
    for k in range(3):
        i, j = [x for x in range(3) if x != k]
        cut = np.flatnonzero(a[:, k] != 0)  # a face parallel to the axis gets no flux
        if not len(cut):
            continue
        ak = a[cut, k]
        ext = r[cut, None] * np.sqrt(np.clip(1.0 - a[cut] ** 2, 0.0, None))
        lo, hi = np.minimum(c[cut], e1[cut]) - ext, np.maximum(c[cut], e1[cut]) + ext
        start, count = _ranges(lo, hi)
        # faces: planes w with lo_k ≤ w ≤ hi_k (the end disc may lie in one), squares in i, j
        start[:, k] = np.ceil(lo[:, k]).astype(np.int64)
        count[:, k] = np.floor(hi[:, k]).astype(np.int64) - start[:, k] + 1
        has = count[:, k] > 0
        cut, ak, start, count = cut[has], ak[has], start[has], count[has]

        for sl in _slices(count.prod(axis=1)):
            own, ijk = _expand(start[sl], count[sl])
            p = cut[sl][own]
            akp = ak[sl][own]
            w = ijk[:, k].astype(np.float64)
            dw = w - c[p, k]
            rr = r[p]
            qk = uv[p, k]  # (u_k, v_k)
            # 0 ≤ t ≤ L ⇔ x_k at the axis, w − r(u_k, v_k)·y, within [c_k, e1_k] (either order);
            # bounded by the same e1_k that places the end disc, so an end disc lying in a
            # voxel plane and that plane's face flux agree on the side (no rounding split)
            rows = [rr[:, None] * qk, -rr[:, None] * qk]
            bs = [w - np.minimum(c[p, k], e1[p, k]), np.maximum(c[p, k], e1[p, k]) - w]
            for ax in (i, j):  # x_ax = h + g·y on the face, within [n, n + 1]
                ratio = a[p, ax] / akp
                h = c[p, ax] + ratio * dw
                g = rr[:, None] * (uv[p, ax] - ratio[:, None] * qk)
                n0 = ijk[:, ax]
                rows += [-g, g]
                bs += [h - n0, n0 + 1.0 - h]
            G, B = np.stack(rows, axis=1), np.stack(bs, axis=1)
            flux = np.empty(len(p))
            # the face integral is (r²/|a_k|)·∫ a_k·t dA_y: rounding grows like 1/|a_k|, so
            # faces nearly parallel to the axis are done in extended precision
            for rows_, dt in ((np.abs(akp) >= LOW_AK, np.float64), (np.abs(akp) < LOW_AK, np.longdouble)):
                if rows_.any():
                    A, M1, M2 = halfplane_disc_moments(G[rows_].astype(dt), B[rows_].astype(dt))
                    rq, q_ = rr[rows_].astype(dt), qk[rows_].astype(dt)
                    fl = rq ** 2 / np.abs(akp[rows_]).astype(dt) * (dw[rows_].astype(dt) * A - rq * (q_[:, 0] * M1 + q_[:, 1] * M2))
                    flux[rows_] = fl.astype(np.float64)
            # An end disc lying in the face (axis along −e_k, t = L at x_k = w) is placed in
            # the voxel above w (floor), where the piece is: its flux is that end disc's term,
            # not also a face's (with the axis along +e_k the face term moves it below).
            flux[(akp < 0) & np.all(qk == 0, axis=1) & (w == e1[p, k])] = 0.0
            below = ijk.copy()
            below[:, k] -= 1
            add(np.concatenate([below, ijk]), np.concatenate([flux, -flux]))
