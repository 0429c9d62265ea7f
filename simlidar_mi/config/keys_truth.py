"""Scene-file keys of ``[truth]``: the canopy ground-truth grid (``simlidar-mi truth``)."""
from __future__ import annotations

from .keys_base import FLOAT, INT, STR, Key, at_least, nonneg, one_of, positive

SECTIONS = {
    "truth": {
        "voxel_m": Key(FLOAT, 0.1, positive, "voxel side of the ground-truth grid, metres"),
        "margin_m": Key(FLOAT, 0.0, nonneg, "grid margin around the geometry's bounds, metres"),
        "row_axis": Key(STR, "y", one_of("x", "y"), "horizontal axis along the tree row"),
        "row_spacing_m": Key(FLOAT, None, positive, "distance between rows for TRV and LWA "
                             "(default: the scene's row spacing when it has one, else TRV/LWA "
                             "are not reported)"),
        "canopy_base": Key(STR, "ground", one_of("ground", "canopy"),
                           "canopy height measured from the ground or from the lowest "
                           "occupied voxel of each slice"),
        "occupancy": Key(STR, "plant", one_of("plant", "leaf"),
                         "voxels that make the canopy envelope: any plant area, or leaves only"),
        "ground_area_m2": Key(FLOAT, None, positive, "ground area for LAI (default: the plot of a "
                              "gap-fraction scene; an orchard's n_trees × spacing_m × row_spacing_m "
                              "and a vineyard's rows × vines × vine_spacing_m × row_spacing_m, as "
                              "`measure` counts them; else the grid's row length × row_spacing_m "
                              "when that is known; else the grid footprint)"),
        "raster_cell_m": Key(FLOAT, 0.5, positive, "cell side of the truth rasters (DTM, DSM, CHM, top "
                             "tree id) and of the CHMs and DTMs evaluate-als builds, metres"),
        "raster_subsamples": Key(INT, 8, at_least(1), "vertical rays per cell side for the truth DSM, CHM "
                                 "and tree-id rasters (k x k rays a cell)"),
    },
}
