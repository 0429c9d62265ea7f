"""Raster truth of a scene seen from above: DTM, DSM, CHM and the topmost tree per cell, exact
from the geometry, and which trees are overtopped.

The rasters cover a :class:`RasterGrid` (square cells of ``cell_m``; array row 0 is the
northern edge, as GeoTIFF stores it).  Every cell is sampled by ``k × k`` vertical rays cast
down onto the Mitsuba scene through its shapes (tree ids from the scene builder's tables,
:class:`~simlidar_mi.lidar.scan.BeamTracer`), at the centres of a regular k × k split of the
cell; the terrain is a callable ``height_m(x, y)`` (float64 arrays, metres), by default the flat
plane ``[ground] z_m``.  Per sub-sample s the top surface is z_s = max(first hit, terrain):

``dtm``
    the terrain height at the cell centre (exact; no sampling).
``dsm``
    max over the cell's sub-samples of z_s: the highest surface the k × k rays meet.
``chm``
    max over the sub-samples of z_s − terrain(x_s, y_s) (the normalised heights' maximum, as
    a CHM from height-normalised points is built; on flat ground dsm − dtm).
``tree_id``
    the tree id of the sub-sample that gives ``dsm`` (int32; −1 where that is the ground or a
    shape of no tree).

A tree is **overtopped** when it owns no cell of ``tree_id``: no vertical ray from above meets
it first, so a CHM cannot show its top.  With a finite k a tree whose exposed crown is smaller
than a sub-sample spacing (``cell_m / k``) can be counted overtopped; ``k`` and ``cell_m`` set
that resolution.

GeoTIFFs (:func:`write_geotiff`) carry the scene's ``[scene] crs`` (an EPSG code) when it has
one; without it they carry no CRS at all (the scene's own local engineering frame, metres,
which GDAL reports as having no coordinate system) rather than a guessed one.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..geometry import NO_ID

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: Sub-samples a cell per side by default (k × k vertical rays a cell).
DEFAULT_SUBSAMPLES = 8  # BENCHMARKS.md §17: the max-in-cell CHM of a porous crown grows with k
#: Rays traced at once (bounds the sensor tables and the per-ray arrays: ~60 bytes a ray).
CHUNK_RAYS = 1 << 21
NODATA_ID = -1


def flat_ground(z_m: float = 0.0) -> HeightFn:
    """The flat terrain z = ``z_m`` as a height function."""
    z = float(z_m)
    return lambda x, y: np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, z, np.float64)


@dataclass(frozen=True)
class RasterGrid:
    """``nx × ny`` square cells of ``cell_m`` whose south-west corner is (``x0_m``, ``y0_m``)."""

    x0_m: float
    y0_m: float
    cell_m: float
    nx: int
    ny: int

    @classmethod
    def cover(cls, x_min: float, x_max: float, y_min: float, y_max: float, cell_m: float) -> "RasterGrid":
        """The grid of ``cell_m`` cells from (x_min, y_min) that covers the box (at least one cell)."""
        nx = max(1, int(np.ceil((x_max - x_min) / cell_m - 1e-9)))
        ny = max(1, int(np.ceil((y_max - y_min) / cell_m - 1e-9)))
        return cls(float(x_min), float(y_min), float(cell_m), nx, ny)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.ny, self.nx)

    def x_centres(self) -> np.ndarray:
        return self.x0_m + (np.arange(self.nx) + 0.5) * self.cell_m

    def y_centres(self) -> np.ndarray:
        """Cell-centre y of each array row, north (largest y) first."""
        return self.y0_m + (self.ny - 0.5 - np.arange(self.ny)) * self.cell_m

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of every cell centre, each of :attr:`shape`."""
        return np.meshgrid(self.x_centres(), self.y_centres())

    def cell_of(self, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) of points: the cell holding each (x, y), and whether it is on the grid."""
        col = np.floor((np.asarray(x, np.float64) - self.x0_m) / self.cell_m).astype(np.int64)
        row = self.ny - 1 - np.floor((np.asarray(y, np.float64) - self.y0_m) / self.cell_m).astype(np.int64)
        inside = (col >= 0) & (col < self.nx) & (row >= 0) & (row < self.ny)
        return np.clip(row, 0, self.ny - 1), np.clip(col, 0, self.nx - 1), inside

    def transform(self):
        """The GDAL/rasterio affine geotransform (north-up)."""
        from affine import Affine  # noqa: PLC0415  (rasterio's own dependency)
        return Affine(self.cell_m, 0.0, self.x0_m, 0.0, -self.cell_m, self.y0_m + self.ny * self.cell_m)

    def to_dict(self) -> dict:
        return {"x0_m": self.x0_m, "y0_m": self.y0_m, "cell_m": self.cell_m, "nx": self.nx, "ny": self.ny}


@dataclass
class SurfaceTruth:
    """The truth rasters of :func:`surface_rasters` (each of ``grid.shape``; module docstring)."""

    grid: RasterGrid
    dtm: np.ndarray
    dsm: np.ndarray
    chm: np.ndarray
    tree_id: np.ndarray
    subsamples: int

    def overtopped(self, n_trees: int) -> np.ndarray:
        """Per tree 0 … n_trees − 1: True when it owns no ``tree_id`` cell (module docstring)."""
        return overtopped(self.tree_id, n_trees)


def top_cells(tree_id_raster: np.ndarray, n_trees: int) -> tuple[np.ndarray, np.ndarray]:
    """Per tree id 0 … ``n_trees`` − 1: the cells of a top tree-id raster it owns (int64) and
    whether it is overtopped (owns none; bool): ``trees.csv``'s and ``truth_trees.csv``'s
    ``top_cells`` and ``overtopped``."""
    ids = np.asarray(tree_id_raster).ravel()
    ids = ids[(ids >= 0) & (ids < n_trees)].astype(np.int64)
    owned = np.bincount(ids, minlength=n_trees)[:n_trees]
    return owned, owned == 0


def overtopped(tree_id_raster: np.ndarray, n_trees: int) -> np.ndarray:
    """True for each tree id 0 … ``n_trees`` − 1 that owns no cell of a top tree-id raster."""
    return top_cells(tree_id_raster, n_trees)[1]


def _vertical_pattern(origins_m: np.ndarray, escape_m: float):
    from ..lidar.platforms import BeamPattern  # noqa: PLC0415
    n = len(origins_m)
    return BeamPattern(kind="raster", row_origin_m=origins_m, row_yaw_deg=np.zeros(n),
                       col_angle_deg=np.array([-90.0]), col_dir=np.array([[0.0, 0.0, -1.0]]),
                       row_span_m=np.zeros(3), col_span_deg=0.0, escape_m=escape_m, ground=False)


def first_hits_down(built, x_m: np.ndarray, y_m: np.ndarray, variant: str | None = None,
                    lone_tree: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Height of the first surface (NaN: none) and its tree id (uint32, NO_ID: none or no tree)
    met by a vertical ray cast down at each (x, y) from above the scene's bounding box.
    A scene of one plant has no tree ids in the scene builder's tables: ``lone_tree`` is then
    the id of every hit (a forest of one tree: 0)."""
    from ..lidar.scan import BeamTracer  # noqa: PLC0415
    x_m, y_m = np.asarray(x_m, np.float64).ravel(), np.asarray(y_m, np.float64).ravel()
    z = np.full(len(x_m), np.nan)
    tree = np.full(len(x_m), NO_ID, np.uint32)
    lo, hi = np.asarray(built.bbox_min_m, np.float64), np.asarray(built.bbox_max_m, np.float64)
    if not len(x_m) or not np.all(np.isfinite(hi)) or np.any(hi < lo):
        return z, tree
    top = float(hi[2]) + 1.0
    escape = 2.0 * (top - float(lo[2])) + 10.0
    for a in range(0, len(x_m), CHUNK_RAYS):
        b = min(len(x_m), a + CHUNK_RAYS)
        origins = np.stack([x_m[a:b], y_m[a:b], np.full(b - a, top)], axis=1)
        out = BeamTracer(built, _vertical_pattern(origins, escape), variant).trace()
        hit = out["cls"] != 0
        z[a:b] = np.where(hit, top - out["range"].astype(np.float64), np.nan)
        if out["tree"] is not None:
            tree[a:b] = np.where(hit, out["tree"], NO_ID)
        elif lone_tree is not None:
            tree[a:b] = np.where(hit, np.uint32(lone_tree), NO_ID)
    return z, tree


def surface_rasters(built, grid: RasterGrid, height_m: HeightFn | None = None,
                    subsamples: int = DEFAULT_SUBSAMPLES, variant: str | None = None,
                    progress=None, lone_tree: int | None = None) -> SurfaceTruth:
    """DTM, DSM, CHM and top tree id of ``built`` (a :class:`~simlidar_mi.scene.build.BuiltScene`)
    on ``grid`` (module docstring); ``height_m`` the terrain (default: z = 0).  Raster rows are
    traced a band at a time; ``progress(rows)`` is called after each band; ``lone_tree``:
    see :func:`first_hits_down`."""
    height_m = height_m or flat_ground(0.0)
    k = int(subsamples)
    if k < 1:
        raise ValueError(f"subsamples must be ≥ 1, got {subsamples}")
    ny, nx = grid.shape
    xc, yc = grid.centres()
    dtm = np.asarray(height_m(xc, yc), np.float64).reshape(grid.shape)
    dsm, chm = np.empty(grid.shape), np.empty(grid.shape)
    tid = np.full(grid.shape, NODATA_ID, np.int32)
    off = ((np.arange(k) + 0.5) / k - 0.5) * grid.cell_m
    band = max(1, CHUNK_RAYS // max(1, nx * k * k))
    for r0 in range(0, ny, band):
        r1 = min(ny, r0 + band)
        # sub-samples (rows, cols, k, k): x varies along the last axis, y along the one before
        xs = (xc[r0:r1, :, None, None] + off[None, None, None, :]) + np.zeros((1, 1, k, 1))
        ys = (yc[r0:r1, :, None, None] - off[None, None, :, None]) + np.zeros((1, 1, 1, k))
        ground = np.asarray(height_m(xs, ys), np.float64).reshape(xs.shape)
        z, tree = first_hits_down(built, xs, ys, variant, lone_tree)
        z, tree = z.reshape(xs.shape), tree.reshape(xs.shape)
        above = np.isfinite(z) & (z > ground)
        surf = np.where(above, z, ground).reshape(r1 - r0, nx, k * k)
        norm = (surf - ground.reshape(surf.shape))
        pick = np.argmax(surf, axis=2)
        dsm[r0:r1] = np.take_along_axis(surf, pick[..., None], 2)[..., 0]
        chm[r0:r1] = norm.max(axis=2)
        t = np.where(above, tree, NO_ID).reshape(surf.shape)
        t = np.take_along_axis(t, pick[..., None], 2)[..., 0]
        tid[r0:r1] = np.where(t == NO_ID, NODATA_ID, t.astype(np.int64)).astype(np.int32)
        if progress is not None:
            progress(r1 - r0)
    return SurfaceTruth(grid, dtm, dsm, chm, tid, k)


# --- GeoTIFF ---------------------------------------------------------------------------------

def write_geotiff(path: str | Path, array: np.ndarray, grid: RasterGrid, crs: str | None = None, *,
                  nodata=None, description: str = "", units: str = "m") -> Path:
    """One band (``array`` of ``grid.shape``, north row first) as a DEFLATE GeoTIFF with the
    grid's geotransform, ``crs`` (an "EPSG:<code>"; None: no CRS, the scene's local frame) and
    the band's description and unit."""
    import rasterio  # noqa: PLC0415
    a = np.asarray(array)
    if a.shape != grid.shape:
        raise ValueError(f"raster of shape {a.shape} is not the grid's {grid.shape}")
    profile = {"driver": "GTiff", "width": grid.nx, "height": grid.ny, "count": 1, "dtype": a.dtype.name,
               "transform": grid.transform(), "compress": "deflate"}
    if crs:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.Env(GTIFF_SRS_SOURCE="EPSG"), rasterio.open(path, "w", **profile) as dst:
        dst.write(a, 1)
        if description:
            dst.set_band_description(1, description)
        if units:
            dst.set_band_unit(1, units)
        dst.update_tags(AREA_OR_POINT="Area")
    return Path(path)


RASTER_FILES = {"dtm": ("truth_dtm.tif", "terrain height at the cell centre", "m"),
                "dsm": ("truth_dsm.tif", "highest surface over the cell's k x k vertical rays", "m"),
                "chm": ("truth_chm.tif", "largest height above the terrain over the cell's k x k vertical rays",
                        "m"),
                "tree_id": ("truth_tree_id.tif", "tree id of the topmost crown in the cell (-1: none)", "")}


def write_truth_rasters(truth: SurfaceTruth, folder: str | Path, crs: str | None = None) -> dict[str, Path]:
    """The four truth rasters as GeoTIFFs (:data:`RASTER_FILES`) in ``folder``."""
    out = {}
    for key, (name, what, unit) in RASTER_FILES.items():
        a = getattr(truth, key)
        a = a.astype(np.float32) if a.dtype.kind == "f" else a
        out[key] = write_geotiff(Path(folder) / name, a, truth.grid, crs, description=what, units=unit,
                                 nodata=NODATA_ID if key == "tree_id" else None)
    return out
