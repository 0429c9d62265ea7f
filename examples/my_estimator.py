"""Example plug-in estimators for ``simlidar-mi evaluate`` (docs/guide/truth-evaluate.md).

A callable plug-in (``--estimator examples/my_estimator.py:contact_frequency``) is a
function ``f(scan_dir, grid)``: ``scan_dir`` holds the scan's ``scan.exr``,
``points.las`` and ``measures.json``; ``grid`` is the
:class:`simlidar_mi.truth.grid.VoxelGrid` the truth is on (``corner_m``, ``voxel_m``,
``shape``, ``centres(axis)``). It returns a dict of arrays of ``grid.shape`` (indexed
[i, j, k] along x, y, z) or an xarray Dataset with dimensions named x, y, z, holding
``PAD_m2_m3`` (or ``LAD_m2_m3``), NaN where it makes no estimate.

A command plug-in (``--estimator-cmd "python examples/my_estimator.py {las} {grid} {out}"``)
reads the files and writes a NetCDF grid with x, y, z voxel-centre coordinates (as
``{grid}`` has them) and a ``PAD_m2_m3`` variable on named dimensions; like our files, this
one stores it on (z, y, x), the CF order. Running this file as a script does that with
:func:`point_density_pad`.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def contact_frequency(scan_dir, grid):
    """The maximum-likelihood PAD of Pimont et al. (2018) from the scan EXR, through the
    package's own pieces (so it scores exactly like the built-in ``contact_mle``)."""
    from simlidar_mi.truth.estimators import beams_from_exr, contact_mle_pad
    from simlidar_mi.truth.traverse import traverse

    beams = beams_from_exr(Path(scan_dir) / "scan.exr")
    return {"PAD_m2_m3": contact_mle_pad(traverse(grid, beams))}


def point_density_pad(points_m: np.ndarray, centres: list[np.ndarray], voxel_m: float,
                      m2_per_point: float = 0.002) -> np.ndarray:
    """A deliberately naive estimator from the points alone: PAD = points per voxel ×
    an assumed area per point / voxel volume, indexed [i, j, k] along x, y, z. Only the
    LAS is needed."""
    edges = [np.append(c - voxel_m / 2, c[-1] + voxel_m / 2) for c in centres]
    count, _ = np.histogramdd(points_m, bins=edges)
    return count * m2_per_point / voxel_m ** 3


def main(las_path: str, grid_path: str, out_path: str) -> None:
    import laspy
    import xarray as xr

    las = laspy.read(las_path)
    veg = np.isin(np.asarray(las.classification), (5, 64))  # leaf (ASPRS high vegetation), wood (64)
    pts = np.column_stack([las.x, las.y, las.z])[veg]
    grid = xr.load_dataset(grid_path)
    centres = [grid[a].values for a in "xyz"]
    voxel = float(grid.attrs["voxel_m"])
    pad = point_density_pad(pts, centres, voxel)
    xr.Dataset({"PAD_m2_m3": (("z", "y", "x"), pad.transpose(2, 1, 0), {"units": "m2 m-3"})},
               coords={a: grid[a] for a in "xyz"}, attrs={"voxel_m": voxel}).to_netcdf(out_path)


if __name__ == "__main__":
    main(*sys.argv[1:4])
