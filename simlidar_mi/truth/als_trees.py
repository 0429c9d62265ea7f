"""Canopy height models from points, individual tree detection, and matching to the true trees.

CHMs (cells of a :class:`~simlidar_mi.truth.als_truth.RasterGrid`; heights above the terrain):

``plain``
    the highest normalised point per cell; empty cells from their nearest filled cell.
``pitfree``
    Khosravipour et al. (2014, Photogramm. Eng. Remote Sens. 80:863–872,
    doi:10.14358/PERS.80.9.863): partial CHMs, each the TIN of the first returns at least
    t above the terrain (t in ``thresholds``, default 0, 2, 5, 10, 15 m) interpolated at the
    cell centres, those above 0 m without triangles that have an edge longer than
    ``max_edge_m`` (1.5 m, lidR's default for the method), stacked by their maximum.

Tree detection (baselines; any function of the same form plugs in):

``lmf``
    local maxima of the CHM in a circular window whose diameter grows with the height,
    Popescu & Wynne (2004, Photogramm. Eng. Remote Sens. 70:589–604): their equation for
    deciduous and pine trees together, crown width = 2.51503 + 0.00901·h² (m); cells below
    ``min_height_m`` are not trees; a plateau of equal maxima is one tree (its first cell).
``watershed``
    marker-controlled watershed crowns (scikit-image): markers are the local maxima at least
    ``min_distance_m`` apart of the CHM smoothed by a Gaussian of σ = one cell, the crowns the
    watershed of the negated smoothed CHM over cells above ``min_height_m``; a tree is its
    crown's highest raw CHM cell.

Matching (:func:`match_trees`): true and detected trees 1:1 within a horizontal distance and a
height difference, the restricted nearest-neighbour matching of the Eysn et al. (2015,
Forests 6:1721–1747, doi:10.3390/f6051721) benchmark as we read it: true trees from the
tallest down each take the nearest detected tree not yet taken that is within both
tolerances.  The tolerances (3 m, 3 m by default) are ours.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PITFREE_THRESHOLDS_M = (0.0, 2.0, 5.0, 10.0, 15.0)


def _nearest_fill(a: np.ndarray) -> np.ndarray:
    from scipy import ndimage  # noqa: PLC0415
    empty = ~np.isfinite(a)
    if not empty.any() or empty.all():
        return a
    idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
    return a[tuple(idx)]


def chm_plain(x, y, h, grid) -> np.ndarray:
    """Highest normalised height ``h`` per cell; empty cells from the nearest filled cell."""
    row, col, inside = grid.cell_of(x, y)
    out = np.full(grid.shape, -np.inf)
    np.maximum.at(out, (row[inside], col[inside]), np.asarray(h, np.float64)[inside])
    out[~np.isfinite(out)] = np.nan
    return _nearest_fill(out)


def chm_pitfree(x, y, h, grid, thresholds=PITFREE_THRESHOLDS_M, max_edge_m: float = 1.5) -> np.ndarray:
    """The pit-free CHM of Khosravipour et al. (2014) from first returns (module docstring)."""
    from scipy.interpolate import LinearNDInterpolator  # noqa: PLC0415
    from scipy.spatial import Delaunay, QhullError  # noqa: PLC0415
    x, y, h = (np.asarray(a, np.float64) for a in (x, y, h))
    xc, yc = grid.centres()
    q = np.column_stack([xc.ravel(), yc.ravel()])
    best = np.full(q.shape[0], -np.inf)
    for t in thresholds:
        sel = h >= t
        if sel.sum() < 3:
            continue
        pts = np.column_stack([x[sel], y[sel]])
        try:
            tri = Delaunay(pts)
        except QhullError:
            continue
        val = LinearNDInterpolator(tri, h[sel])(q)
        if t > 0:
            s = tri.find_simplex(q)
            v = pts[tri.simplices]  # (m, 3, 2)
            edge = np.max(np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2), axis=1)
            val = np.where((s >= 0) & (edge[np.maximum(s, 0)] <= max_edge_m), val, np.nan)
        best = np.fmax(best, val)
    best[~np.isfinite(best)] = np.nan
    return _nearest_fill(best.reshape(grid.shape))


def popescu_window_m(h: np.ndarray) -> np.ndarray:
    """Popescu & Wynne's (2004) crown width from height, both in metres (module docstring)."""
    h = np.asarray(h, np.float64)
    return 2.51503 + 0.00901 * h ** 2


def _disk(r: int) -> np.ndarray:
    i = np.arange(-r, r + 1)
    return (i[:, None] ** 2 + i[None, :] ** 2) <= r * r + 1e-9


def _one_per_plateau(mask: np.ndarray, chm: np.ndarray) -> list[tuple[int, int]]:
    from scipy import ndimage  # noqa: PLC0415
    lab, n = ndimage.label(mask, structure=np.ones((3, 3)))
    if not n:
        return []
    flat = np.flatnonzero(lab.ravel())
    first = {}
    for f in flat:  # row-major: the first cell of each plateau
        first.setdefault(int(lab.flat[f]), f)
    return [divmod(int(f), chm.shape[1]) for _, f in sorted(first.items())]


def _trees_at(cells, chm, grid) -> np.ndarray:
    if not cells:
        return np.zeros((0, 3))
    r, c = np.array(cells).T
    return np.column_stack([grid.x_centres()[c], grid.y_centres()[r], chm[r, c]])


def local_maxima_trees(chm: np.ndarray, grid, *, min_height_m: float = 2.0, window=popescu_window_m) -> np.ndarray:
    """Tree tops (n, 3: x, y, height) as CHM maxima in a height-dependent circular window (module docstring)."""
    from scipy import ndimage  # noqa: PLC0415
    chm = np.nan_to_num(np.asarray(chm, np.float64), nan=0.0)
    radius = np.maximum(0, np.round(window(chm) / 2.0 / grid.cell_m)).astype(np.int64)
    top = np.zeros(chm.shape, bool)
    tall = chm >= min_height_m
    for r in np.unique(radius[tall]):
        sel = tall & (radius == r)
        m = ndimage.maximum_filter(chm, footprint=_disk(int(r)), mode="constant", cval=-np.inf) if r else chm
        top |= sel & (chm >= m)
    return _trees_at(_one_per_plateau(top, chm), chm, grid)


def watershed_trees(chm: np.ndarray, grid, *, min_height_m: float = 2.0, min_distance_m: float = 2.0,
                    return_labels: bool = False):
    """Tree tops (n, 3) of marker-controlled watershed crowns (module docstring); with
    ``return_labels`` also the crown label raster (0: no crown)."""
    from scipy import ndimage  # noqa: PLC0415
    from skimage.feature import peak_local_max  # noqa: PLC0415
    from skimage.segmentation import watershed  # noqa: PLC0415
    chm = np.nan_to_num(np.asarray(chm, np.float64), nan=0.0)
    smooth = ndimage.gaussian_filter(chm, 1.0)
    mask = chm >= min_height_m
    peaks = peak_local_max(smooth, min_distance=max(1, int(round(min_distance_m / grid.cell_m))),
                           threshold_abs=min_height_m, labels=mask.astype(np.int32), exclude_border=False)
    markers = np.zeros(chm.shape, np.int32)
    markers[tuple(peaks.T)] = np.arange(1, len(peaks) + 1)
    labels = watershed(-smooth, markers, mask=mask) if len(peaks) else np.zeros(chm.shape, np.int32)
    cells = []
    if len(peaks):
        idx = ndimage.maximum_position(chm, labels, index=np.arange(1, len(peaks) + 1))
        cells = [tuple(int(v) for v in p) for p in idx]
    trees = _trees_at(cells, chm, grid)
    return (trees, labels) if return_labels else trees


TREE_DETECTORS = {"lmf": local_maxima_trees, "watershed": watershed_trees}


@dataclass
class Match:
    """``det_of_true[i]``: the detected tree matched to true tree i (−1: none); ``true_of_det`` the inverse."""

    det_of_true: np.ndarray
    true_of_det: np.ndarray

    @property
    def n_matched(self) -> int:
        return int(np.sum(self.det_of_true >= 0))


def match_trees(true_xyh: np.ndarray, det_xyh: np.ndarray, *, max_distance_m: float = 3.0,
                max_height_diff_m: float = 3.0) -> Match:
    """1:1 matching of true to detected trees, each (n, 3) x, y, height (module docstring)."""
    from scipy.spatial import cKDTree  # noqa: PLC0415
    t = np.asarray(true_xyh, np.float64).reshape(-1, 3)
    d = np.asarray(det_xyh, np.float64).reshape(-1, 3)
    det_of_true = np.full(len(t), -1, np.int64)
    true_of_det = np.full(len(d), -1, np.int64)
    if not len(t) or not len(d):
        return Match(det_of_true, true_of_det)
    near = cKDTree(d[:, :2]).query_ball_point(t[:, :2], r=max_distance_m)
    for i in np.argsort(-t[:, 2], kind="stable"):
        cand = [j for j in near[i] if true_of_det[j] < 0 and abs(d[j, 2] - t[i, 2]) <= max_height_diff_m]
        if cand:
            dist = np.hypot(d[cand, 0] - t[i, 0], d[cand, 1] - t[i, 1])
            j = cand[int(np.argmin(dist))]
            det_of_true[i], true_of_det[j] = j, i
    return Match(det_of_true, true_of_det)


def _rates(n_true: int, n_det: int | None, matched: int) -> dict:
    nan = float("nan")
    r = matched / n_true if n_true else nan
    out = {"n_true": n_true, "n_matched": matched, "detection_rate": r}
    if n_det is not None:
        p = matched / n_det if n_det else nan
        out.update(n_detected=n_det, precision=p,
                   f_score=2 * r * p / (r + p) if n_true and n_det and r + p > 0 else nan)
    return out


def detection_scores(true_xyh, det_xyh, match: Match, species=None, overtopped=None) -> list[dict]:
    """Detection rate (recall), precision, F-score and matched trees' height RMSE and bias
    (detected − true): over all trees, then per species and for dominant vs overtopped trees
    (recall only: a detection has no species or layer of its own, so a precision per group is undefined)."""
    t = np.asarray(true_xyh, np.float64).reshape(-1, 3)
    d = np.asarray(det_xyh, np.float64).reshape(-1, 3)
    m = match.det_of_true

    def heights(sel):
        ok = sel & (m >= 0)
        e = d[m[ok], 2] - t[ok, 2]
        return {"height_rmse_m": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
                "height_bias_m": float(np.mean(e)) if e.size else float("nan")}

    every = np.ones(len(t), bool)
    rows = [{"group": "all", **_rates(len(t), len(d), match.n_matched), **heights(every)}]
    groups = []
    if species is not None:
        sp = np.asarray(species, object)
        groups += [(f"species {s}", sp == s) for s in dict.fromkeys(sp.tolist())]
    if overtopped is not None:
        ov = np.asarray(overtopped, bool)
        groups += [("dominant", ~ov), ("overtopped", ov)]
    for name, sel in groups:
        rows.append({"group": name, **_rates(int(sel.sum()), None, int(np.sum(m[sel] >= 0))), **heights(sel)})
    return rows


def detection_by_height(true_h, match: Match, bin_m: float = 2.0) -> list[dict]:
    """Detection rate of the true trees per height bin of ``bin_m``."""
    h = np.asarray(true_h, np.float64)
    if not h.size:
        return []
    edges = np.arange(np.floor(h.min() / bin_m) * bin_m, h.max() + bin_m, bin_m)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (h >= lo) & (h < hi)
        if sel.any():
            rows.append({"height_from_m": float(lo), "height_to_m": float(hi), "n_true": int(sel.sum()),
                         "detection_rate": float(np.mean(match.det_of_true[sel] >= 0))})
    return rows
