"""Mesh arrays of branch prisms: vertices, faces and caps (used by :mod:`.build`).

:func:`prism_arrays` makes the k-facet prisms of the ``mesh`` representation (and the end
caps of the ``cylinder`` one); :func:`exposed_ends` says which ends get a cap.  Both are
plain numpy; :mod:`.build` turns the arrays into Mitsuba meshes.
"""
from __future__ import annotations

import numpy as np

# Branches per block in prism_arrays: its temporaries stay in the cache, and no full-size
# float64 vertex or all-faces array is ever made (fresh pages cost more than the arithmetic).
PRISM_BLOCK = 4096


def _orthonormal(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each row of ``axis`` (unit rows)."""
    helper = np.where(np.abs(axis[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axis, u)


def prism_arrays(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray, k: int, caps=True,
                 sides: bool = True, dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V,3) of ``dtype``, faces (F,3) uint32 and faces per segment (n,) of k-gon
    prisms around segments (see :func:`prism_mesh`, which gives an owner per face instead).

    The vertices are computed in float64 whatever ``dtype`` is and rounded once on the way
    in, so float32 vertices have the bits of the float64 ones converted afterwards."""
    n = len(radius)
    phi = 2 * np.pi * np.arange(k) / k
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    j = np.arange(k)
    jn = (j + 1) % k
    if isinstance(caps, (bool, np.bool_)):
        caps = (np.full(n, bool(caps)), np.full(n, bool(caps)))
    local = []  # the sides (2k faces, if any), then the cap at p0 (k − 2), then the cap at p1
    if sides:
        local += [np.stack([j, jn, k + j], 1), np.stack([jn, k + jn, k + j], 1)]
    t = np.arange(1, k - 1)
    local += [np.stack([np.zeros_like(t), t + 1, t], 1), np.stack([k + np.zeros_like(t), k + t, k + t + 1], 1)]
    local = np.concatenate(local).astype(np.uint32).reshape(1, -1)  # Mitsuba's index type
    n_side = 2 * k if sides else 0
    at_p0, at_p1 = slice(n_side, n_side + k - 2), slice(n_side + k - 2, None)
    cap0, cap1 = np.asarray(caps[0], bool), np.asarray(caps[1], bool)
    counts = n_side + (k - 2) * (cap0.astype(np.int64) + cap1)
    all_caps = bool(cap0.all() and cap1.all())
    verts = np.empty((n, 2 * k, 3), dtype)
    faces = np.empty((int(counts.sum()), 3), np.uint32)
    item = np.dtype((np.void, 12))  # a face as one 12-byte item: 2.7x faster to select than (3,) rows
    f0 = 0
    for a in range(0, n, PRISM_BLOCK):
        b = min(a + PRISM_BLOCK, n)
        _prism_vertices(p0[a:b], p1[a:b], radius[a:b], cos_phi, sin_phi, verts[a:b])
        # (m, 3F): each branch's faces in one row, so the add runs over long rows
        f = local + (2 * k * np.arange(a, b, dtype=np.uint32))[:, None]
        f1 = f0 + int(counts[a:b].sum())
        if all_caps:
            faces[f0:f1] = f.reshape(-1, 3)
        else:
            keep = np.ones((b - a, local.shape[1] // 3), bool)
            keep[:, at_p0] = cap0[a:b, None]
            keep[:, at_p1] = cap1[a:b, None]
            faces[f0:f1].view(item)[:, 0] = f.view(item)[keep]  # (np.compress(out=) is 3x slower)
        f0 = f1
    return verts.reshape(-1, 3), faces, counts


def _prism_vertices(p0, p1, radius, cos_phi, sin_phi, out) -> None:
    """Fill ``out`` (m, 2k, 3) with the rings around p0 (first k) and p1 (last k)."""
    k = len(cos_phi)
    axis = p1 - p0
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    u, v = _orthonormal(axis)
    # One coordinate at a time as (k, m) arrays (long inner loops; numpy's broadcasting over
    # a last axis of 3 was 1.6x slower), the same float64 operations in the same order:
    # ring = (cos·u + sin·v)·r, then ring + p0 and ring + p1, rounded once into ``out``.
    end = np.empty((k, len(radius)))
    for c in range(3):
        ring = np.multiply.outer(cos_phi, u[:, c])
        ring += np.multiply.outer(sin_phi, v[:, c])
        ring *= radius
        np.add(ring, p1[:, c], out=end)
        out[:, k:, c] = end.T
        ring += p0[:, c]
        out[:, :k, c] = ring.T


def prism_mesh(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray, k: int,
               caps=True, sides: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V,3), faces (F,3) and owner (F,) of k-gon prisms around segments.

    ``radius`` is the circumradius used as given (callers scale it).  ``caps`` is a bool,
    or a pair of (n,) bool arrays saying which p0 and p1 ends get a k-gon cap.
    Coordinates stay float64 here; the caller converts after subtracting the origin.
    """
    v, f, counts = prism_arrays(p0, p1, radius, k, caps, sides)
    return v, f, np.repeat(np.arange(len(radius)), counts)


def exposed_ends(p0: np.ndarray, p1: np.ndarray, diameter: np.ndarray,
                 tol_m: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """Which segment ends need a cap: those not continued by a segment at least as thick.

    A joint where the next segment (same or larger diameter) starts covers the end
    disc up to a thin wedge on the outer side of the bend; free tips, bases and steps
    down in diameter stay open to beams and are capped.
    """
    n = len(diameter)
    keys = np.concatenate([p0, p1])
    keys /= tol_m
    keys = np.round(keys, out=keys).astype(np.int64)  # in place: the same round(x / tol)
    order, new = _group_order(keys)
    inv = np.empty(len(keys), np.int64)
    inv[order] = np.cumsum(new) - 1
    start_d = np.zeros(inv.max() + 1 if n else 0)  # thickest segment starting at each point
    end_d = np.zeros_like(start_d)  # thickest segment ending at each point
    np.maximum.at(start_d, inv[:n], diameter)
    np.maximum.at(end_d, inv[n:], diameter)
    cap0 = end_d[inv[:n]] < diameter
    cap1 = start_d[inv[n:]] < diameter
    return cap0, cap1


# Odd 64-bit multipliers (splitmix64/xxhash constants) mixing a point's three integer keys.
_KEY_MIX = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9], np.uint64)


def _group_order(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An order of the (m, 3) int64 ``keys`` that puts equal rows next to each other, and
    a bool (m,) marking the first row of each run in that order.

    Sorts one 64-bit hash of each row (numpy's vectorised sort: 10x faster than a 3-key
    lexsort); equal rows have equal hashes, so unless two different rows share a hash and
    meet in the sorted order (then the exact lexicographic sort is used), each run of equal
    hashes is one run of equal rows."""
    u = keys.view(np.uint64)
    h = u[:, 0] * _KEY_MIX[0]  # wraps modulo 2**64: a hash
    h ^= u[:, 1] * _KEY_MIX[1]
    h ^= u[:, 2] * _KEY_MIX[2]
    order = np.argsort(h)
    hs = h[order]
    new = np.ones(len(hs), bool)
    np.not_equal(hs[1:], hs[:-1], out=new[1:])
    # Equal hashes side by side must be equal rows; else (a collision) sort the rows themselves.
    same = np.flatnonzero(~new[1:])
    if np.any(keys[order[same]] != keys[order[same + 1]]):
        order = np.lexsort(keys.T[::-1])
        ks = keys[order]
        new[1:] = np.any(ks[1:] != ks[:-1], axis=1)
    return order, new
