"""Row-crop canopy metrics used to dose orchard and vineyard sprays: TRV and LWA.

Both treat a row of trees as a continuous hedge of foliage (the "tree row volume"
concept of Byers et al. 1971, Virginia Fruit 60:19–23; described e.g. in the Penn State
Tree Fruit Production Guide). With canopy height ``H`` (m), canopy width across the
row ``W`` (m) and row spacing ``D`` (m, centre to centre of neighbouring rows):

tree row volume (TRV), m³ per hectare of ground
    ``TRV = H · W · 10 000 / D`` (Byers et al. 1971; the form used for dose expression
    by Garcerá et al. 2020, "Dose expression for pesticide application in citrus",
    Agronomy (MDPI), and by the CitrusVol tool, Garcerá et al. 2017, Int. J. Environ.
    Res. Public Health 14:715).
leaf wall area (LWA), m² per hectare of ground
    ``LWA = 2 · H · 10 000 / D``: both sides of the hedge, the dose expression chosen
    for efficacy trials of wall-forming crops in northern Europe (Koch 2007, Aspects of
    Applied Biology 84; Walklate et al. 2011; both as cited by Garcerá et al. 2020).

Canopy height and width are read from a 3-D occupancy grid (truth: voxels holding leaf
or wood; estimates: voxels holding LiDAR points) per slice along the row
(:func:`canopy_profiles`):

* height of a slice = top of its highest occupied voxel − ``base_m``. ``base_m`` is the
  ground by default (0 m, the convention of the TRV definition, where H is the tree
  height); pass ``base='canopy'`` to measure from the bottom of the lowest occupied voxel
  instead (the foliage wall's own height, for LWA of trellised crops with a bare trunk).
* width of a slice = extent across the row from the lowest to the highest occupied
  voxel index (outer faces), metres.

Empty slices give NaN. The mean over non-empty slices is what the formulas take.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError

__all__ = ["canopy_profiles", "trv_m3_ha", "lwa_m2_ha", "M2_PER_HA"]

M2_PER_HA = 10_000.0
_AXES = {"x": 0, "y": 1}


def _check_spacing(row_spacing_m) -> np.ndarray:
    d = np.asarray(row_spacing_m, np.float64)
    if not np.all(np.isfinite(d) & (d > 0)):
        raise ConfigError("row spacing must be a finite number > 0 metres", key="row_spacing_m",
                          value=np.asarray(row_spacing_m).tolist())
    return d


def trv_m3_ha(height_m, width_m, row_spacing_m):
    """Tree row volume, m³/ha: ``H · W · 10 000 / D`` (Byers et al. 1971)."""
    d = _check_spacing(row_spacing_m)
    return np.asarray(height_m, np.float64) * np.asarray(width_m, np.float64) * M2_PER_HA / d


def lwa_m2_ha(height_m, row_spacing_m):
    """Leaf wall area, m²/ha: ``2 · H · 10 000 / D`` (Koch 2007; Walklate et al. 2011)."""
    d = _check_spacing(row_spacing_m)
    return 2.0 * np.asarray(height_m, np.float64) * M2_PER_HA / d


def canopy_profiles(occupied, grid, row_axis: str = "y", base: str | float = "ground",
                    ground_z_m: float = 0.0, terrain=None) -> dict:
    """Canopy height and width per slice along the row from a (nx, ny, nz) occupancy grid.

    ``grid`` is a :class:`~simlidar_mi.truth.grid.VoxelGrid`; ``row_axis`` is 'x' or 'y'
    (the other horizontal axis is across the row). ``base``: 'ground' (heights from
    ``ground_z_m``), 'canopy' (from each slice's lowest occupied voxel) or a number (a
    fixed z in metres); with a ``terrain`` (:class:`~simlidar_mi.io.terrain.Terrain`), 'ground'
    measures each voxel column's top above the terrain under its centre and a slice's height
    is the highest of its columns'. Returns arrays over the slices: ``along_m`` (slice centres),
    ``top_m``, ``bottom_m``, ``height_m``, ``width_m``, ``left_m``/``right_m`` (outer
    faces across the row) and ``occupied`` (bool: slice holds anything), plus the means
    over occupied slices ``mean_height_m`` and ``mean_width_m`` (NaN if none).
    """
    occ = np.asarray(occupied, bool)
    if occ.shape != tuple(grid.shape):
        raise ConfigError(f"occupancy has shape {occ.shape}, the grid is {tuple(grid.shape)}",
                          key="occupied")
    if row_axis not in _AXES:
        raise ConfigError("row axis must be 'x' or 'y'", key="row_axis", value=row_axis)
    a = _AXES[row_axis]
    c = 1 - a
    occ = np.moveaxis(occ, a, 0)  # (along, across, z)
    h = grid.voxel_m
    z_edges = grid.edges(2)
    across_edges = grid.edges(c)
    any_z = occ.any(axis=1)  # (along, z)
    any_c = occ.any(axis=2)  # (along, across)
    has = any_z.any(axis=1)
    nz, ncx = occ.shape[2], occ.shape[1]
    k_top = np.where(has, nz - 1 - np.argmax(any_z[:, ::-1], axis=1), 0)
    k_bot = np.where(has, np.argmax(any_z, axis=1), 0)
    i_lo = np.where(has, np.argmax(any_c, axis=1), 0)
    i_hi = np.where(has, ncx - 1 - np.argmax(any_c[:, ::-1], axis=1), 0)
    nan = np.full(len(has), np.nan)
    top = np.where(has, z_edges[k_top + 1], nan)
    bottom = np.where(has, z_edges[k_bot], nan)
    if base == "ground":
        ref = np.full(len(has), float(ground_z_m))
    elif base == "canopy":
        ref = bottom
    else:
        try:
            ref = np.full(len(has), float(base))
        except (TypeError, ValueError):
            raise ConfigError("canopy base must be 'ground', 'canopy' or a height in metres",
                              key="base", value=base) from None
    height = np.where(has, np.maximum(top - ref, 0.0), nan)
    if base == "ground" and terrain is not None:
        col = occ.any(axis=2)  # (along, across) columns holding anything
        k_col = nz - 1 - np.argmax(occ[:, :, ::-1], axis=2)
        along_c, across_c = grid.centres(a), grid.centres(c)
        xy = (along_c[:, None], across_c[None, :]) if a == 0 else (across_c[None, :], along_c[:, None])
        above = np.where(col, z_edges[k_col + 1] - terrain.height_m(*xy), -np.inf)
        best = above.max(axis=1)
        height = np.where(has & np.isfinite(best), np.maximum(best, 0.0), nan)
    left = np.where(has, across_edges[i_lo], nan)
    right = np.where(has, across_edges[i_hi + 1], nan)
    width = right - left
    mean = (lambda v: float(np.mean(v[has])) if has.any() else float("nan"))
    return {"along_m": grid.centres(a), "top_m": top, "bottom_m": bottom, "height_m": height,
            "width_m": width, "left_m": left, "right_m": right, "occupied": has,
            "mean_height_m": mean(height), "mean_width_m": mean(width), "row_axis": row_axis,
            "voxel_m": h}
