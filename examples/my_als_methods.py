"""Plug-in methods for ``simlidar-mi evaluate-als`` (docs/guide/evaluate-als.md).

A ground method takes the LAS file's points and returns a boolean per point (True: ground); a
tree method takes the pit-free CHM and its grid and returns the tree tops found.
"""
import numpy as np
from scipy import ndimage


def last_return_minimum(points):
    """Ground: last returns within 0.5 m of the lowest last return of their 5 m cell."""
    x, y, z = points["x"], points["y"], points["z"]
    last = points["return_number"] == points["number_of_returns"]
    cell = (np.floor((x - x.min()) / 5.0).astype(np.int64) * 1_000_003
            + np.floor((y - y.min()) / 5.0).astype(np.int64))
    _, inv = np.unique(cell, return_inverse=True)
    low = np.full(inv.max() + 1, np.inf)
    np.minimum.at(low, inv[last], z[last])
    return last & (z - low[inv] <= 0.5)


def fixed_window_maxima(chm, grid):
    """Trees: CHM maxima in a fixed 3 m window, above 2 m (x, y, height rows)."""
    size = max(1, int(round(3.0 / grid.cell_m)))
    top = (chm == ndimage.maximum_filter(chm, size=size)) & (chm >= 2.0)
    rows, cols = np.nonzero(top)
    return np.column_stack([grid.x_centres()[cols], grid.y_centres()[rows], chm[rows, cols]])
