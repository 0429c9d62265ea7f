"""Leaves of random trees: the per-leaf table, the blade triangles and the rotations they use.

Branches that are terminal, or in the last ``leaf_levels`` generations, or of order
``≥ leaf_min_order`` carry ``leaves_per_branch`` leaves each, at uniform positions
along the branch and uniform azimuths about it, attached at the bark. A leaf's
heading ``h`` makes ``leaf_angle_deg`` with the branch; its blade spans ``h`` and
the horizontal side vector ``s = h × ẑ``, rolled by ``leaf_roll_deg`` about ``h``,
so with roll 0 the upper side (normal ``n = s × h``) faces the sky. Shapes:
``"rhombus"`` (2 triangles, base and tip on the midrib, area ``ℓw/2``) or
``"ellipse"`` (an inscribed ``leaf_sides``-gon, a fan of triangles, area
``(k/8)·sin(2π/k)·ℓw``). Triangles are wound so their normal is ``n``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry import Leaves
from .tree_params import RandomTreeParams, leaf_polygon_area_factor

__all__ = ["LeafTable", "ellipse_fan"]

_Z = np.array([0.0, 0.0, 1.0])
_BLOCK = 512   # leaves per block when (3, n) columns are written into (n, …, 3) triangles


# --- rotations -------------------------------------------------------------------------


def _rot_z(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# np.cross(a, b) is a1·b2 − a2·b1, a2·b0 − a0·b2, a0·b1 − a1·b0: the same products and
# differences written out give the same bits without np.cross's moveaxis/broadcast set-up,
# which dominates on the few-row arrays of a growing tree.
_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (n, 3) rows (or a (3,) ``b``), bit for bit."""
    return (a.take(_I1, axis=-1) * b.take(_I2, axis=-1)
            - a.take(_I2, axis=-1) * b.take(_I1, axis=-1))


def _cross_t(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The same cross product for vectors stored as columns: (3, n) arrays (or a (3, 1) ``b``)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a
    b0, b1, b2 = b
    np.subtract(a1 * b2, a2 * b1, out=out[0])
    np.subtract(a2 * b0, a0 * b2, out=out[1])
    np.subtract(a0 * b1, a1 * b0, out=out[2])
    return out


def _norm_t(a: np.ndarray) -> np.ndarray:
    """(n,) lengths of the columns of a (3, n) array: ``np.linalg.norm(a.T, axis=1)``'s bits.

    That norm is ``sqrt(add.reduce(x·x))``, which sums three terms left to right.
    """
    q = a * a
    return np.sqrt((q[0] + q[1]) + q[2])


def _rotate(v: np.ndarray, axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotate rows of ``v`` about unit rows of ``axis`` (right-handed)."""
    c, s = np.cos(angle_rad)[:, None], np.sin(angle_rad)[:, None]
    return v * c + _cross(axis, v) * s + axis * (axis * v).sum(1, keepdims=True) * (1 - c)


def _rotate_t(v: np.ndarray, axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """:func:`_rotate` for (3, n) column vectors, with the same operations in the same order."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    p = axis * v
    return v * c + _cross_t(axis, v) * s + axis * ((p[0] + p[1]) + p[2]) * (1 - c)


def ellipse_fan(centre: np.ndarray, head: np.ndarray, side: np.ndarray, half_l: np.ndarray,
                half_w: np.ndarray, k: int) -> np.ndarray:
    """(n, k, 3, 3) triangles of ``k``-gons inscribed in ellipses: a fan from each centre.

    Vertex ``j`` is ``centre + cos(2πj/k)·half_l·head + sin(2πj/k)·half_w·side``
    (``half_l``, ``half_w``: (n, 1, 1)); triangles are (centre, v_{j+1}, v_j), so their
    normal is ``side × head``. Area ``(k/8)·sin(2π/k)·ℓw`` for ``ℓ = 2·half_l``, ``w = 2·half_w``.
    """
    n = len(centre)
    a = 2 * np.pi * np.arange(k + 1) / k
    ring = (centre[:, None, :] + np.cos(a)[None, :, None] * half_l * head[:, None, :]
            + np.sin(a)[None, :, None] * half_w * side[:, None, :])   # (n, k+1, 3)
    out = np.empty((n, k, 3, 3))
    out[:, :, 0] = centre[:, None, :]
    out[:, :, 1] = ring[:, 1:]
    out[:, :, 2] = ring[:, :-1]          # (centre, v_{j+1}, v_j)
    return out


def _ellipse_fan_t(centre: np.ndarray, head: np.ndarray, side: np.ndarray, half_l: np.ndarray,
                   half_w: np.ndarray, k: int, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`ellipse_fan` from (3, n) columns and (n,) half axes (same vertex arithmetic).

    Returns the triangles (written into ``out``, (n, k, 3, 3), when given) and the
    (3, k+1, n) polygon vertices.
    """
    n = centre.shape[1]
    a = 2 * np.pi * np.arange(k + 1) / k
    ca, sa = np.cos(a)[:, None], np.sin(a)[:, None]
    ring = (centre[:, None, :] + (ca * half_l)[None] * head[:, None, :]
            + (sa * half_w)[None] * side[:, None, :])   # (3, k+1, n)
    out = np.empty((n, k, 3, 3)) if out is None else out
    o = out.transpose(3, 1, 2, 0)        # (3, k, 3, n) view: coordinate, triangle, vertex, leaf
    for i in range(0, n, _BLOCK):        # blocks of leaves: the scattered writes stay in cache
        j = i + _BLOCK
        o[:, :, 0, i:j] = centre[:, None, i:j]
        o[:, :, 1, i:j] = ring[:, 1:, i:j]
        o[:, :, 2, i:j] = ring[:, :-1, i:j]
    return out, ring


# --- leaves ----------------------------------------------------------------------------


@dataclass(frozen=True)
class LeafTable:
    """One row per leaf: what a sensor model needs (seed 004 keeps size, position, orientation).

    Attributes
    ----------
    tree_id, leaf_id : (n,) int32.
    centre_m : (n, 3) float64, blade centre (midpoint of base and tip).
    length_m, width_m, area_m2 : (n,) float64; area is the polygon's one-sided area.
    normal : (n, 3) unit upper-side normal of the flat blade.
    heading : (n, 3) unit vector from base to tip.
    """

    tree_id: np.ndarray
    leaf_id: np.ndarray
    centre_m: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    area_m2: np.ndarray
    normal: np.ndarray
    heading: np.ndarray

    COLUMNS = ("tree_id", "leaf_id", "x", "y", "z", "length_m", "width_m", "area_m2",
               "nx", "ny", "nz", "hx", "hy", "hz")

    def __len__(self) -> int:
        return len(self.leaf_id)

    @classmethod
    def empty(cls) -> "LeafTable":
        z3, z = np.zeros((0, 3)), np.zeros(0)
        return cls(np.zeros(0, np.int32), np.zeros(0, np.int32), z3, z, z, z, z3, z3)

    @classmethod
    def concat(cls, parts: Sequence["LeafTable"]) -> "LeafTable":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts])
                     for f in dataclasses.fields(cls)))

    def placed(self, translation_m, yaw_deg: float = 0.0, scale: float = 1.0,
               tree_id: int | None = None) -> "LeafTable":
        """The table of this tree scaled, turned by ``yaw_deg`` about z and moved."""
        R = _rot_z(yaw_deg)
        t = np.asarray(translation_m, np.float64)
        tid = self.tree_id if tree_id is None else np.full(len(self), tree_id, np.int32)
        return LeafTable(tid, self.leaf_id, scale * self.centre_m @ R.T + t, scale * self.length_m,
                         scale * self.width_m, scale * scale * self.area_m2, self.normal @ R.T,
                         self.heading @ R.T)

    def columns(self) -> dict[str, np.ndarray]:
        """Column name → 1-D array, in :attr:`COLUMNS` order."""
        c, n, h = self.centre_m, self.normal, self.heading
        return {"tree_id": self.tree_id, "leaf_id": self.leaf_id, "x": c[:, 0], "y": c[:, 1],
                "z": c[:, 2], "length_m": self.length_m, "width_m": self.width_m,
                "area_m2": self.area_m2, "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2],
                "hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2]}


_LEAF_BLOCK = 8192   # leaves made at a time: their (3, n) temporaries stay in cache (BENCHMARKS.md §16)


def _make_leaves(P: RandomTreeParams, p0, p1, r, H, U, owner, tpos, phi, lang, ll, lw, roll,
                 tid: int) -> tuple[Leaves, LeafTable, float | None]:
    """Leaves on branches ``owner`` (rows of the (nb, 3) ``p0``, ``p1``, ``H``, ``U`` and (nb,) ``r``).

    Returns the leaves, their table and the largest ``x² + y²`` of their vertices (None
    without leaves), taken from the distinct vertices while they are in cache.

    The vectors are handled as (3, n) columns: every operation then runs over contiguous
    (n,) rows instead of n rows of 3, with the per-element arithmetic of the row form.
    They are made ``_LEAF_BLOCK`` leaves at a time into the output arrays: every operation
    is per leaf, so the bits are those of one pass, while the temporaries stay small (one
    pass over a 140 k-leaf tree allocated and zeroed fresh pages for each of ~60 (3, n)
    temporaries).
    """
    n = len(ll)
    if n == 0:
        return Leaves.empty(), LeafTable.empty(), None
    ntri = 2 if P.leaf_shape == "rhombus" else P.leaf_sides
    tri = np.empty((n, ntri, 3, 3))
    centre_m, normal_m, head_m = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    # the bearing branches' ends, heading and reference as (12, nb) columns, gathered per block
    g_all = np.ascontiguousarray(np.concatenate([p0, p1, H, U], 1).T)
    xy2 = -np.inf
    for i in range(0, n, _LEAF_BLOCK):
        j = min(i + _LEAF_BLOCK, n)
        xy2 = max(xy2, _leaf_block(P, g_all, r, owner[i:j], tpos[i:j], phi[i:j], lang[i:j],
                                   ll[i:j], lw[i:j], roll[i:j], tri[i:j], centre_m[i:j],
                                   normal_m[i:j], head_m[i:j]))
    area = leaf_polygon_area_factor(P.leaf_shape, P.leaf_sides) * ll * lw
    leaf_id = np.arange(n, dtype=np.int32)
    leaves = Leaves(tri.reshape(-1, 3, 3), np.repeat(leaf_id, ntri),
                    np.full(n * ntri, tid, np.int32))
    table = LeafTable(np.full(n, tid, np.int32), leaf_id, centre_m, ll, lw, area, normal_m, head_m)
    return leaves, table, xy2


def _leaf_block(P: RandomTreeParams, g_all, r, owner, tpos, phi, lang, ll, lw, roll,
                tri, centre_m, normal_m, head_m) -> float:
    """One block of :func:`_make_leaves`: writes its rows of ``tri`` (n, k, 3, 3) and of the
    (n, 3) ``centre_m``, ``normal_m``, ``head_m``; returns the block's largest ``x² + y²``."""
    n = len(ll)
    g = g_all[:, owner]
    b0, b1, H, U, br = g[0:3], g[3:6], g[6:9], g[9:12], r[owner]
    u = _rotate_t(U, H, phi)                         # outward direction at the insertion
    head = np.cos(lang) * H + np.sin(lang) * u
    base = b0 + tpos * (b1 - b0) + br * u            # attached at the bark
    side = _cross_t(head, _Z[:, None])
    sn = _norm_t(side)
    ok = sn > 1e-6
    side = side / np.maximum(sn, 1e-300)
    if not ok.all():
        # a vertical leaf has no horizontal side vector: use its insertion direction's normal
        bad = ~ok
        f = _cross_t(head[:, bad], u[:, bad])
        side[:, bad] = f / _norm_t(f)
    up = _cross_t(side, head)                        # upper-side normal with roll 0
    side_r = np.cos(roll) * side + np.sin(roll) * up
    normal = _cross_t(side_r, head)
    centre = base + 0.5 * ll * head
    if P.leaf_shape == "rhombus":
        tip = base + ll * head
        right = centre + 0.5 * lw * side_r
        left = centre - 0.5 * lw * side_r
        # (base, right, tip), (base, tip, left): both wound so the normal is side × head
        o = tri.transpose(3, 1, 2, 0)                # (3, 2, 3, n) view
        for i in range(0, n, 2 * _BLOCK):            # blocks: the scattered writes stay in cache
            j = i + 2 * _BLOCK
            o[:, 0, 0, i:j] = o[:, 1, 0, i:j] = base[:, i:j]
            o[:, 0, 1, i:j] = right[:, i:j]
            o[:, 0, 2, i:j] = o[:, 1, 1, i:j] = tip[:, i:j]
            o[:, 1, 2, i:j] = left[:, i:j]
        corners = (base, right, tip, left)
    else:
        _, ring = _ellipse_fan_t(centre, head, side_r, 0.5 * ll, 0.5 * lw, P.leaf_sides, tri)
        corners = (centre, ring.reshape(3, -1))
    centre_m[...] = centre.T
    normal_m[...] = normal.T
    head_m[...] = head.T
    return max(float((c[0] * c[0] + c[1] * c[1]).max()) for c in corners)
