"""Ground filters for airborne point clouds and their scores against the truth.

Scores per point, as Sithole & Vosselman (2004, ISPRS J. Photogramm. Remote Sens. 59:85–101,
doi:10.1016/j.isprsjprs.2004.05.004) tabulate a filter: with a = ground kept as ground,
b = ground rejected as object, c = object accepted as ground, d = object kept as object,

- **type I** error b / (a + b) (bare earth rejected), **type II** c / (c + d) (objects accepted),
- **total** error (b + c) / n,
- **Cohen's κ** = (p_o − p_e) / (1 − p_e), p_o = (a + d)/n, p_e = ((a + b)(a + c) + (c + d)(b + d))/n².

Baselines:

``csf``
    the Cloth Simulation Filter of Zhang et al. (2016, Remote Sens. 8:501,
    doi:10.3390/rs8060501) through its authors' package (PyPI ``cloth-simulation-filter``).
``pmf``
    the progressive morphological filter of Zhang et al. (2003, IEEE TGRS 41:872–882,
    doi:10.1109/TGRS.2003.810682), implemented here from the paper: the lowest point per
    cell (empty cells from their nearest filled cell), then grey openings (square windows,
    ``scipy.ndimage.grey_opening``) of growing size w_k = 2·b^k + 1 cells (k = 0, 1, 2, … until
    ``max_window_m``) with the elevation-difference threshold dh_k = dh₀ for w_k ≤ 3 and
    s·(w_k − w_{k−1})·c + dh₀ after, capped at dh_max; a point higher than dh_k above the
    opened surface of its cell at any step is an object.  The defaults (c = 1 m, b = 2,
    s = 0.3, dh₀ = 0.3 m, dh_max = 3 m, 20 m window) are ours, not the paper's, which tunes
    them per site.

A DTM from ground points (:func:`dtm_from_ground`) is their Delaunay triangulation
interpolated linearly at the cell centres (NaN outside the triangulation), the TIN most
filters' DTMs are.
"""
from __future__ import annotations

import contextlib
import os
import sys

import numpy as np

#: Slope classes (degrees, lower bounds) of the DTM scores.
SLOPE_CLASSES_DEG = (0.0, 10.0, 20.0, 30.0, 45.0)


def confusion(true_ground, pred_ground) -> dict:
    """Sithole & Vosselman's a, b, c, d (module docstring) as ints."""
    t = np.asarray(true_ground, bool)
    p = np.asarray(pred_ground, bool)
    if t.shape != p.shape:
        raise ValueError(f"{p.shape} predictions for {t.shape} points")
    return {"a": int(np.sum(t & p)), "b": int(np.sum(t & ~p)), "c": int(np.sum(~t & p)), "d": int(np.sum(~t & ~p))}


def classification_scores(true_ground, pred_ground) -> dict:
    """Type I, type II and total error and Cohen's κ of a ground classification (module docstring)."""
    m = confusion(true_ground, pred_ground)
    a, b, c, d = m["a"], m["b"], m["c"], m["d"]
    n = a + b + c + d
    nan = float("nan")
    po = (a + d) / n if n else nan
    pe = ((a + b) * (a + c) + (c + d) * (b + d)) / n ** 2 if n else nan
    return {**m, "n": n,
            "type_I": b / (a + b) if a + b else nan, "type_II": c / (c + d) if c + d else nan,
            "total_error": (b + c) / n if n else nan,
            "kappa": (po - pe) / (1.0 - pe) if n and pe != 1.0 else nan}


# --- progressive morphological filter (Zhang et al. 2003) ------------------------------------

def _lowest_grid(xyz: np.ndarray, cell_m: float):
    """The lowest z per cell (empty cells from their nearest filled one) and each point's cell."""
    from scipy import ndimage  # noqa: PLC0415
    x0, y0 = xyz[:, 0].min(), xyz[:, 1].min()
    col = np.floor((xyz[:, 0] - x0) / cell_m).astype(np.int64)
    row = np.floor((xyz[:, 1] - y0) / cell_m).astype(np.int64)
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    flat = row * shape[1] + col
    low = np.full(shape[0] * shape[1], np.inf)
    np.minimum.at(low, flat, xyz[:, 2])
    low = low.reshape(shape)
    empty = ~np.isfinite(low)
    if empty.any():
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        low = low[tuple(idx)]
    return low, flat


def pmf_windows(cell_m: float, max_window_m: float, base: float = 2.0) -> list[int]:
    """Window sizes (cells) w_k = 2·b^k + 1, k = 0, 1, 2, …, while w_k·cell_m ≤ max_window_m (at least w_1)."""
    out, k = [], 0
    while True:
        w = int(round(2 * base ** k + 1))
        if out and w * cell_m > max_window_m:
            return out
        out.append(w)
        k += 1


def pmf_ground(xyz: np.ndarray, *, cell_m: float = 1.0, max_window_m: float = 20.0, base: float = 2.0,
               slope: float = 0.3, dh0_m: float = 0.3, dh_max_m: float = 3.0) -> np.ndarray:
    """Ground mask of the points ``xyz`` (n, 3) by the progressive morphological filter (module docstring)."""
    from scipy import ndimage  # noqa: PLC0415
    xyz = np.asarray(xyz, np.float64)
    if not len(xyz):
        return np.zeros(0, bool)
    surface, flat = _lowest_grid(xyz, cell_m)
    ground = np.ones(len(xyz), bool)
    w_prev = 1
    for w in pmf_windows(cell_m, max_window_m, base):
        dh = dh0_m if w <= 3 else min(dh_max_m, slope * (w - w_prev) * cell_m + dh0_m)
        surface = ndimage.grey_opening(surface, size=(w, w), mode="nearest")
        ground &= xyz[:, 2] - surface.ravel()[flat] <= dh
        w_prev = w
    return ground


# --- cloth simulation filter (Zhang et al. 2016) -------------------------------------------------

@contextlib.contextmanager
def _quiet_stdout():
    """Silence a C++ library's prints on file descriptor 1 (CSF reports its steps there)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def csf_ground(xyz: np.ndarray, *, cloth_resolution_m: float = 0.5, rigidness: int = 3,
               class_threshold_m: float = 0.5, iterations: int = 500, time_step: float = 0.65,
               slope_smooth: bool = False) -> np.ndarray:
    """Ground mask of the points ``xyz`` (n, 3) by the Cloth Simulation Filter (the authors'
    ``CSF`` package; rigidness 3 is their choice for flat terrain, 1 for steep)."""
    import CSF  # noqa: PLC0415  (PyPI cloth-simulation-filter)
    xyz = np.ascontiguousarray(np.asarray(xyz, np.float64))
    ground = np.zeros(len(xyz), bool)
    if not len(xyz):
        return ground
    csf = CSF.CSF()
    p = csf.params
    p.bSloopSmooth, p.cloth_resolution, p.rigidness = bool(slope_smooth), float(cloth_resolution_m), int(rigidness)
    p.class_threshold, p.interations, p.time_step = float(class_threshold_m), int(iterations), float(time_step)
    # CSF works in its own frame; centre the cloud so float32 inside it keeps millimetres
    csf.setPointCloud(xyz - xyz.mean(axis=0))
    g, ng = CSF.VecInt(), CSF.VecInt()
    with _quiet_stdout():
        csf.do_filtering(g, ng, False)  # False: write no cloth_nodes.txt into the working folder
    ground[np.asarray(list(g), np.int64)] = True
    return ground


GROUND_FILTERS = {"csf": csf_ground, "pmf": pmf_ground}


# --- DTMs and their scores --------------------------------------------------------------------

def dtm_from_ground(xyz_ground: np.ndarray, grid) -> np.ndarray:
    """The ground points' TIN at the cell centres of ``grid`` (NaN outside it; module docstring)."""
    from scipy.interpolate import LinearNDInterpolator  # noqa: PLC0415
    from scipy.spatial import QhullError  # noqa: PLC0415
    xyz_ground = np.asarray(xyz_ground, np.float64)
    xc, yc = grid.centres()
    if len(xyz_ground) < 3:
        return np.full(grid.shape, np.nan)
    try:
        f = LinearNDInterpolator(xyz_ground[:, :2], xyz_ground[:, 2])
    except QhullError:  # collinear ground points: no triangle
        return np.full(grid.shape, np.nan)
    return np.asarray(f(xc, yc), np.float64).reshape(grid.shape)


def slope_deg(dtm: np.ndarray, cell_m: float) -> np.ndarray:
    """Terrain slope (degrees) of a DTM by central differences."""
    gy, gx = np.gradient(np.asarray(dtm, np.float64), cell_m)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def _stats(err: np.ndarray) -> dict:
    n = int(err.size)
    return {"n_cells": n, "rmse_m": float(np.sqrt(np.mean(err ** 2))) if n else float("nan"),
            "bias_m": float(np.mean(err)) if n else float("nan"),
            "max_abs_m": float(np.max(np.abs(err))) if n else float("nan")}


def dtm_scores(dtm_est: np.ndarray, dtm_true: np.ndarray, under_canopy: np.ndarray, cell_m: float,
               mask: np.ndarray | None = None) -> list[dict]:
    """RMSE, bias (estimate − truth) and the largest error of a DTM: over every scored cell, per
    slope class of the true terrain (:data:`SLOPE_CLASSES_DEG`) and under canopy vs open
    (``under_canopy``: cells whose truth top is a crown).  Cells where the estimate is NaN are
    not scored; ``coverage`` is the share of the (masked) cells scored."""
    est, true = np.asarray(dtm_est, np.float64), np.asarray(dtm_true, np.float64)
    base = np.ones(true.shape, bool) if mask is None else np.asarray(mask, bool)
    ok = base & np.isfinite(est)
    err = est - true
    slope = slope_deg(true, cell_m)
    cover = float(ok.sum() / base.sum()) if base.sum() else float("nan")
    rows = [{"stratum": "all", **_stats(err[ok]), "coverage": cover}]
    bounds = list(SLOPE_CLASSES_DEG) + [90.01]
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        sel = ok & (slope >= lo) & (slope < hi)
        rows.append({"stratum": f"slope {lo:g}-{min(hi, 90):g} deg", **_stats(err[sel]), "coverage": cover})
    for name, sel in (("under canopy", under_canopy), ("open", ~np.asarray(under_canopy, bool))):
        rows.append({"stratum": name, **_stats(err[ok & sel]), "coverage": cover})
    return rows
