"""A tree-detection plug-in for tests/test_als.py: one tree at the CHM's highest cell."""
import numpy as np


def tallest_cell(chm, grid):
    r, c = np.unravel_index(int(np.argmax(chm)), chm.shape)
    return [[grid.x_centres()[c], grid.y_centres()[r], float(chm[r, c])]]
