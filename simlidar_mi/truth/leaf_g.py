"""The truth's own G: the projection function of its leaf area along the scan's beams.

For unit one-sided leaf area with normals n_i and areas a_i, the mean area projected on the
plane normal to a beam direction Omega is (Ross 1981, *The Radiation Regime and Architecture
of Plant Stands*, ch. 2; Nilson 1971)

    G(Omega) = sum_i a_i |n_i . Omega| / sum_i a_i

(0.5 for spherically distributed leaf normals, |cos theta| for horizontal leaves and
(2/pi) sin theta for vertical leaves of uniform azimuth, theta the beam's zenith angle). It
is what Beer-Lambert and the contact estimators divide by; they assume 0.5.

The truth has every leaf triangle, so G is exact: each triangle's clipped pieces carry its
normal, and for every beam segment the walk counts (:func:`~simlidar_mi.truth.traverse.traverse`'s
``on_segment``) sum_i a_i |n_i . Omega_b| over the pieces in that voxel. Per voxel
(``G_leaf``), the mean over the first-return beams that entered it, **weighted by each beam's
entering weight times its chord** in the voxel (w_b l_b, the weights of ``n_in`` and
``chord_m``):

    G_v = sum_b w_b l_b sum_(i in v) a_i |n_i . Omega_b| / (sum_b w_b l_b . sum_(i in v) a_i)

Chord weighting is our choice: for a voxel of small optical depth both estimators read
lambda . sum_b G_b l_b / sum_b l_b, so this is the G that cancels in them; a beam that only
grazes a corner says little and weighs little. The canopy's figure (``G_leaf_canopy``) is
the same sum over every leafy voxel (leaf area x beam chord weighted). NaN where a voxel
holds no leaf area or no beam entered it.

Leaf triangles are ``geometry.leaves``, instanced trees' leaves and ``leaf``-labelled mesh
primitives (not ``leaf``-labelled cylinders). **Wood is not traced**: the plant G that the
estimators of plant area need (``G_plant``, :meth:`LeafG.plant`) gives the wood's half-surface
area (plant area = leaf + wood/2, Chen & Black 1992) the G of randomly oriented cylinders, 0.5
(a cylinder's silhouette over half its surface is (2/pi) sin psi, psi the beam-axis angle,
whose mean over isotropic axes is 0.5):

    G_plant,v = (L_v G_leaf,v + 0.5 (P_v - L_v)) / P_v      (L leaf, P plant area)

and the canopy's ``G_plant_canopy`` the same weighted by each voxel's beam chord sum. A vertical
trunk seen horizontally has 2/pi = 0.64 instead; with wood 12 % of the plant area (leafy
orchard) that moves the canopy's plant G by at most 0.02.
"""
from __future__ import annotations

import numpy as np

from .grid import VoxelGrid

__all__ = ["LeafPieces", "LeafG", "projection_G"]

#: Leaf pieces x beam segments expanded at a time (bounds the temporaries to ~100 MB).
PAIRS_PER_BATCH = 2_000_000


def projection_G(vector_area_m2: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """G(Omega) of leaves given by their vector areas a_i n_i (m, 3), for directions (k, 3).

    The (k, m) projections are summed in blocks of leaves (``PAIRS_PER_BATCH`` pairs): a whole
    (k, m) matrix of 360 directions by a forest's 1.7 M leaf triangles was 5 GB, twice."""
    va = np.asarray(vector_area_m2, np.float64).reshape(-1, 3)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    area = np.linalg.norm(va, axis=1).sum()
    if not area > 0:
        return np.full(len(d), np.nan)
    step = max(1, PAIRS_PER_BATCH // max(1, len(d)))
    total = np.zeros(len(d))
    for a in range(0, len(va), step):
        total += np.abs(d @ va[a:a + step].T).sum(axis=1)
    return total / area


class LeafPieces:
    """Leaf triangle pieces per voxel (flat voxel index, vector area in m2), collected by
    :func:`~simlidar_mi.truth.compute.compute_truth` (``leaf_pieces=``)."""

    def __init__(self, grid: VoxelGrid):
        self.grid = grid
        self._flat: list[np.ndarray] = []
        self._va: list[np.ndarray] = []

    def add(self, tri_m: np.ndarray, ijk: np.ndarray, area_vox: np.ndarray, owner: np.ndarray) -> None:
        """Pieces of ``tri_m`` (n, 3, 3): voxel ``ijk``, area in voxel units, owner triangle."""
        n = np.cross(tri_m[:, 1] - tri_m[:, 0], tri_m[:, 2] - tri_m[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(self.grid.shape)), axis=1) & (area_vox > 0)
        self._flat.append(np.ravel_multi_index(tuple(ijk[inside].T), self.grid.shape))
        self._va.append(n[owner[inside]] * (area_vox[inside] * self.grid.voxel_m ** 2)[:, None])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(flat voxel index, vector area (m, 3)), sorted by voxel."""
        flat = np.concatenate(self._flat) if self._flat else np.zeros(0, np.int64)
        va = np.concatenate(self._va) if self._va else np.zeros((0, 3))
        order = np.argsort(flat, kind="stable")
        return flat[order], va[order]


class LeafG:
    """Accumulates sum_b w_b l_b sum_i a_i |n_i . Omega_b| per leafy voxel over beam segments
    (pass :meth:`segment` as ``on_segment`` to the traversal of ``beams``)."""

    def __init__(self, pieces: LeafPieces, beams):
        self.grid = pieces.grid
        flat, self.va = pieces.arrays()
        self.voxels, self.start, self.count = np.unique(flat, return_index=True, return_counts=True)
        self.area = np.add.reduceat(np.linalg.norm(self.va, axis=1), self.start) if len(flat) else np.zeros(0)
        self.dir = beams.dir
        self.proj = np.zeros(len(self.voxels))   # sum of w l sum a |n . Omega|
        self.weight = np.zeros(len(self.voxels))  # sum of w l
        self.beam_seen = np.zeros(len(beams.dir), bool)
        self.chord_all = np.zeros(int(np.prod(self.grid.shape)))  # sum of w l, every voxel

    def segment(self, beam, flat, w_in, chord_m) -> None:
        self._bincount(self.chord_all, flat, w_in * chord_m)
        if not len(self.voxels):
            return
        v = np.searchsorted(self.voxels, flat)
        v = np.minimum(v, len(self.voxels) - 1)
        keep = (self.voxels[v] == flat) & (w_in * chord_m > 0)
        beam, v, w = beam[keep], v[keep], (w_in * chord_m)[keep]
        self.beam_seen[beam] = True
        self._bincount(self.weight, v, w)
        cnt = self.count[v]
        ends = np.cumsum(cnt)
        a = 0
        while a < len(v):  # batches of segments whose expansion fits PAIRS_PER_BATCH
            b = int(np.searchsorted(ends, (ends[a - 1] if a else 0) + PAIRS_PER_BATCH, side="right"))
            b = max(b, a + 1)
            c = cnt[a:b]
            seg = np.repeat(np.arange(a, b), c)
            first = np.repeat(self.start[v[a:b]] - (np.cumsum(c) - c), c)
            piece = first + np.arange(len(seg))
            dots = np.abs(np.einsum("ij,ij->i", self.va[piece], self.dir[beam[seg]]))
            self._bincount(self.proj, v[seg], dots * w[seg])
            a = b

    @staticmethod
    def _bincount(acc, idx, val) -> None:
        acc += np.bincount(idx, val, minlength=len(acc))

    def per_voxel(self) -> np.ndarray:
        """``G_leaf`` on the grid (module docstring): NaN where no leaf or no beam."""
        out = np.full(self.grid.shape, np.nan)
        ok = self.weight > 0
        g = np.divide(self.proj, self.weight * self.area, out=np.full(len(self.proj), np.nan),
                      where=ok & (self.area > 0))
        out.reshape(-1)[self.voxels] = g
        return out

    def canopy(self) -> float:
        """The canopy's G: leaf area x beam chord weighted over every leafy voxel."""
        den = float(np.sum(self.weight * self.area))
        return float(self.proj.sum()) / den if den > 0 else float("nan")

    def plant(self, leaf_area_m2: np.ndarray, plant_area_m2: np.ndarray,
              wood_G: float = 0.5) -> tuple[np.ndarray, float]:
        """(``G_plant`` per voxel, ``G_plant_canopy``): leaf G and ``wood_G`` mixed by area
        (module docstring); NaN where a voxel holds no plant area or no beam entered it."""
        L = np.asarray(leaf_area_m2, np.float64)
        P = np.asarray(plant_area_m2, np.float64)
        gl = self.per_voxel()
        W = self.chord_all.reshape(self.grid.shape)
        num = np.where(L > 0, L * gl, 0.0) + wood_G * np.maximum(P - L, 0.0)
        g = np.divide(num, P, out=np.full(P.shape, np.nan), where=(P > 0) & (W > 0))
        ok = np.isfinite(g)
        den = float(np.sum(W[ok] * P[ok]))
        return g, float(np.sum(W[ok] * num[ok])) / den if den > 0 else float("nan")

    def along_beams(self, n_dirs: int = 256) -> np.ndarray:
        """The whole canopy's G(Omega) (every leaf) for up to ``n_dirs`` beam directions, evenly
        spaced in scan order among the beams that entered a leafy voxel."""
        seen = np.flatnonzero(self.beam_seen)
        if not len(seen) or not len(self.va):
            return np.zeros(0)
        pick = seen[np.unique(np.linspace(0, len(seen) - 1, min(n_dirs, len(seen))).astype(np.int64))]
        return projection_G(self.va, self.dir[pick])
