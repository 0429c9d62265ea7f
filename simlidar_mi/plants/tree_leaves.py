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


# --- rotations -------------------------------------------------------------------------


def _rot_z(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rotate(v: np.ndarray, axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotate rows of ``v`` about unit rows of ``axis`` (right-handed)."""
    c, s = np.cos(angle_rad)[:, None], np.sin(angle_rad)[:, None]
    return v * c + np.cross(axis, v) * s + axis * (axis * v).sum(1, keepdims=True) * (1 - c)


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
    c = np.broadcast_to(centre[:, None, :], (n, k, 3))
    return np.stack([c, ring[:, 1:], ring[:, :-1]], 2)   # (centre, v_{j+1}, v_j)


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


def _make_leaves(P: RandomTreeParams, b0, b1, br, H, U, tpos, phi, lang, ll, lw, roll,
                 tid: int) -> tuple[Leaves, LeafTable]:
    n = len(ll)
    if n == 0:
        return Leaves.empty(), LeafTable.empty()
    u = _rotate(U, H, phi)                           # outward direction at the insertion
    head = np.cos(lang)[:, None] * H + np.sin(lang)[:, None] * u
    base = b0 + tpos[:, None] * (b1 - b0) + br[:, None] * u   # attached at the bark
    side = np.cross(head, _Z)
    sn = np.linalg.norm(side, axis=1, keepdims=True)
    # a vertical leaf has no horizontal side vector: use its insertion direction's normal
    side = np.where(sn > 1e-6, side / np.maximum(sn, 1e-300), _unit(np.cross(head, u)))
    up = np.cross(side, head)                        # upper-side normal with roll 0
    side_r = np.cos(roll)[:, None] * side + np.sin(roll)[:, None] * up
    normal = np.cross(side_r, head)
    centre = base + 0.5 * ll[:, None] * head
    half_l, half_w = 0.5 * ll[:, None, None], 0.5 * lw[:, None, None]
    if P.leaf_shape == "rhombus":
        tip = base + ll[:, None] * head
        right = centre + 0.5 * lw[:, None] * side_r
        left = centre - 0.5 * lw[:, None] * side_r
        # (base, right, tip), (base, tip, left): both wound so the normal is side × head
        tri = np.stack([np.stack([base, right, tip], 1), np.stack([base, tip, left], 1)], 1)
    else:
        tri = ellipse_fan(centre, head, side_r, half_l, half_w, P.leaf_sides)
    ntri = tri.shape[1]
    area = leaf_polygon_area_factor(P.leaf_shape, P.leaf_sides) * ll * lw
    leaf_id = np.arange(n, dtype=np.int32)
    leaves = Leaves(tri.reshape(-1, 3, 3), np.repeat(leaf_id, ntri),
                    np.full(n * ntri, tid, np.int32))
    table = LeafTable(np.full(n, tid, np.int32), leaf_id, centre, ll, lw, area, normal, head)
    return leaves, table

