"""The terrain: a height grid triangulated two triangles a cell, read from a GeoTIFF DEM or
sampled from analytic relief (``[terrain]``, :mod:`simlidar_mi.config.keys_terrain`).

:class:`Terrain` is plain data.  Its nodes are the DEM's cell centres (or the analytic
relief's samples every ``cell_m``); each cell (i, j)–(i+1, j+1) is split along the diagonal
from its lower-left to its upper-right node, and :meth:`Terrain.height_m` interpolates
linearly on those triangles — in float64, the very surface the scene's ground mesh
(:meth:`Terrain.mesh`) is made of, so the truth and the scan agree to float32 rounding of the
recentred mesh.  A plane is reproduced exactly by any grid; curved relief, a ditch's edges and
a step are the grid's piecewise-linear approximation (a step is a ramp one cell wide).

Coordinates are the scene's (metres, a projected CRS: UTM eastings and northings are fine;
the mesh is recentred on the scene's float64 origin before it becomes float32).  Outside the
grid :meth:`Terrain.height_m` is NaN.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, SimlidarWarning
from ..geometry import Branches

__all__ = ["Terrain", "terrain_of", "ground_height", "read_dem", "analytic_terrain", "relief_m", "check_inside",
           "DEFAULT_EXTENT_M", "FOREST_MARGIN_M"]

DEFAULT_EXTENT_M = (-50.0, 50.0, -50.0, 50.0)
FOREST_MARGIN_M = 20.0
#: Points :meth:`Terrain.height_m` interpolates at once (its temporaries stay in cache).
CHUNK = 1 << 16


@dataclass(frozen=True)
class Terrain:
    """Heights ``z_m[j, i]`` at nodes ``(x0_m + i·dx_m, y0_m + j·dy_m)`` (float64, dx, dy > 0).

    ``crs``: the DEM's CRS as ``"EPSG:<code>"`` (or WKT), None for analytic terrain;
    ``source``: what it was made from (a file, or the analytic form), for messages;
    ``n_filled``: nodata cells filled from their nearest valid cell."""

    x0_m: float
    y0_m: float
    dx_m: float
    dy_m: float
    z_m: np.ndarray
    crs: str | None = None
    source: str = ""
    n_filled: int = 0

    def __post_init__(self) -> None:
        z = np.asarray(self.z_m, np.float64)
        if z.ndim != 2 or z.shape[0] < 2 or z.shape[1] < 2:
            raise ConfigError("a terrain grid needs at least 2 × 2 nodes", file=self.source or None,
                              value=list(z.shape))
        if not (self.dx_m > 0 and self.dy_m > 0):
            raise ConfigError("terrain cells must have positive sizes", file=self.source or None,
                              value=[self.dx_m, self.dy_m])
        if not np.isfinite(z).all():
            raise ConfigError("terrain heights must be finite", file=self.source or None)
        object.__setattr__(self, "z_m", z)

    @property
    def shape(self) -> tuple[int, int]:
        return self.z_m.shape

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the nodes: where :meth:`height_m` is defined."""
        ny, nx = self.z_m.shape
        return (self.x0_m, self.x0_m + (nx - 1) * self.dx_m, self.y0_m, self.y0_m + (ny - 1) * self.dy_m)

    @property
    def z_range_m(self) -> tuple[float, float]:
        return float(self.z_m.min()), float(self.z_m.max())

    def contains(self, x_m, y_m) -> np.ndarray:
        x0, x1, y0, y1 = self.extent_m
        x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
        return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)

    def _locate(self, x_m, y_m):
        """Cell (i, j), fractions (u, v) in it, and the inside mask, for points (x, y)."""
        x, y = np.broadcast_arrays(np.asarray(x_m, np.float64), np.asarray(y_m, np.float64))
        ny, nx = self.z_m.shape
        fx, fy = (x - self.x0_m) / self.dx_m, (y - self.y0_m) / self.dy_m
        inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        i = np.clip(np.floor(np.where(inside, fx, 0.0)), 0, nx - 2).astype(np.int64)
        j = np.clip(np.floor(np.where(inside, fy, 0.0)), 0, ny - 2).astype(np.int64)
        return i, j, fx - i, fy - j, inside

    def height_m(self, x_m, y_m) -> np.ndarray:
        """Terrain height (float64, metres) under each point (x, y), vectorised (broadcast); NaN
        outside :attr:`extent_m`.  Linear on the mesh's triangles (module docstring); computed
        :data:`CHUNK` points at a time (bounded temporaries)."""
        x, y = np.broadcast_arrays(np.asarray(x_m, np.float64), np.asarray(y_m, np.float64))
        if x.size <= CHUNK:
            return self._height(x, y)
        xf, yf = x.ravel(), y.ravel()
        out = np.empty(xf.size)
        for a in range(0, xf.size, CHUNK):
            out[a:a + CHUNK] = self._height(xf[a:a + CHUNK], yf[a:a + CHUNK])
        return out.reshape(x.shape)

    def _height(self, x_m, y_m) -> np.ndarray:
        i, j, u, v, inside = self._locate(x_m, y_m)
        nx, zf = self.z_m.shape[1], self.z_m.ravel()
        k = j * nx + i  # flat gathers: a third of the time of z[j, i]
        z00, z10, z01, z11 = zf.take(k), zf.take(k + 1), zf.take(k + nx), zf.take(k + nx + 1)
        lower = u >= v  # triangle (00, 10, 11) below the diagonal, else (00, 11, 01)
        h = np.where(lower, z00 + u * (z10 - z00) + v * (z11 - z10),
                     z00 + v * (z01 - z00) + u * (z11 - z01))
        return np.where(inside, h, np.nan)

    def slope_deg(self, x_m, y_m) -> np.ndarray:
        """Slope (degrees from horizontal) of the triangle under each point; NaN outside."""
        i, j, u, v, inside = self._locate(x_m, y_m)
        z = self.z_m
        z00, z10, z01, z11 = z[j, i], z[j, i + 1], z[j + 1, i], z[j + 1, i + 1]
        lower = u >= v
        gx = np.where(lower, z10 - z00, z11 - z01) / self.dx_m
        gy = np.where(lower, z11 - z10, z01 - z00) / self.dy_m
        return np.where(inside, np.degrees(np.arctan(np.hypot(gx, gy))), np.nan)

    def nodes_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Node coordinates: x (nx,) and y (ny,), float64."""
        ny, nx = self.z_m.shape
        return self.x0_m + self.dx_m * np.arange(nx), self.y0_m + self.dy_m * np.arange(ny)

    def mesh(self, origin_m=(0.0, 0.0, 0.0), dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (ny·nx, 3) relative to ``origin_m`` — subtracted in float64, rounded once
        to ``dtype`` —, faces (2·(ny−1)·(nx−1), 3) uint32), counter-clockwise seen from above."""
        ny, nx = self.z_m.shape
        if ny * nx >= 2 ** 32:
            raise ConfigError("the terrain grid has more nodes than a mesh can index", file=self.source or None,
                              value=[ny, nx])
        o = np.asarray(origin_m, np.float64)
        xs, ys = self.nodes_m()
        v = np.empty((ny, nx, 3), dtype)
        v[..., 0] = (xs - o[0])[None, :]
        v[..., 1] = (ys - o[1])[:, None]
        v[..., 2] = self.z_m - o[2]
        idx = np.arange(ny * nx, dtype=np.uint32).reshape(ny, nx)
        a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()    # (i, j), (i+1, j)
        c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()      # (i, j+1), (i+1, j+1)
        faces = np.stack([np.stack([a, b, d], 1), np.stack([a, d, c], 1)], 1).reshape(-1, 3)
        return v.reshape(-1, 3), faces

    def corners_m(self) -> np.ndarray:
        """(4·2, 3) corners of the terrain's bounding box (for the scene origin)."""
        x0, x1, y0, y1 = self.extent_m
        z0, z1 = self.z_range_m
        return np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], np.float64)

    def describe(self) -> str:
        x0, x1, y0, y1 = self.extent_m
        z0, z1 = self.z_range_m
        return (f"terrain {self.source}: {self.shape[1]} × {self.shape[0]} nodes, cell {self.dx_m:g} × "
                f"{self.dy_m:g} m, x {x0:.10g}…{x1:.10g}, y {y0:.10g}…{y1:.10g}, z {z0:.6g}…{z1:.6g} m"
                + (f", {self.n_filled} nodata cells filled" if self.n_filled else ""))


# --- analytic relief ------------------------------------------------------------------------

def relief_m(x_m, y_m, *, z_m: float = 0.0, centre_m=(0.0, 0.0), slope_deg: float = 0.0,
             aspect_deg: float = 0.0, hills=(), line_azimuth_deg: float = 0.0, ditch_depth_m: float = 0.0,
             ditch_width_m: float = 2.0, step_m: float = 0.0) -> np.ndarray:
    """The analytic relief in float64 (the keys of ``[terrain]``): a plane through
    (centre, z_m) falling at ``slope_deg`` towards ``aspect_deg`` (clockwise from +y), Gaussian
    hills, a V ditch and a step along the line through the centre at ``line_azimuth_deg``
    (the step up on the line's right)."""
    x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    cx, cy = float(centre_m[0]), float(centre_m[1])
    a = math.radians(aspect_deg)
    z = z_m - math.tan(math.radians(slope_deg)) * ((x - cx) * math.sin(a) + (y - cy) * math.cos(a))
    for hx, hy, hh, hs in hills:
        z = z + hh * np.exp(-((x - hx) ** 2 + (y - hy) ** 2) / (2.0 * hs * hs))
    b = math.radians(line_azimuth_deg)
    d = (x - cx) * math.cos(b) - (y - cy) * math.sin(b)  # signed distance, + right of the line
    if ditch_depth_m:
        z = z - ditch_depth_m * np.maximum(0.0, 1.0 - np.abs(d) / (0.5 * ditch_width_m))
    if step_m:
        z = z + np.where(d > 0, step_m, 0.0)
    return z + np.zeros_like(x)


def analytic_terrain(extent_m, cell_m: float, source: str = "analytic", **relief) -> Terrain:
    """:func:`relief_m` sampled on a grid over ``extent_m`` = (x_min, x_max, y_min, y_max): nodes
    every ``cell_m`` from (x_min, y_min), the last row/column at x_max / y_max (cells as near
    ``cell_m`` as a whole number of them allows)."""
    x0, x1, y0, y1 = (float(e) for e in extent_m)
    nx = max(1, int(math.ceil((x1 - x0) / cell_m - 1e-9))) + 1
    ny = max(1, int(math.ceil((y1 - y0) / cell_m - 1e-9))) + 1
    if nx * ny > 100_000_000:
        raise ConfigError(f"the terrain grid would hold {nx} × {ny} nodes; give a larger cell",
                          file=source, key="terrain.cell_m", value=cell_m)
    dx, dy = (x1 - x0) / (nx - 1), (y1 - y0) / (ny - 1)
    xs, ys = x0 + dx * np.arange(nx), y0 + dy * np.arange(ny)
    relief.setdefault("centre_m", (0.5 * (x0 + x1), 0.5 * (y0 + y1)))
    z = relief_m(xs[None, :], ys[:, None], **relief)
    return Terrain(x0, y0, dx, dy, z, None, source)


# --- GeoTIFF --------------------------------------------------------------------------------

def read_dem(path, nodata: str = "refuse", source: str | None = None, key: str = "terrain.file",
             scene_crs: str | None = None) -> Terrain:
    """A GeoTIFF DEM (band 1) as a :class:`Terrain`: nodes at the cell centres of its
    transform (north-up, no rotation), heights in metres, its CRS projected in metres (and
    the scene's ``[scene] crs`` when that is given).  Cells without data (the file's nodata
    value, NaN) are refused or, with ``nodata = "nearest"``, filled from the nearest valid
    cell (:class:`~simlidar_mi.errors.SimlidarWarning` says how many)."""
    import rasterio  # noqa: PLC0415

    src = source or str(path)
    try:
        with rasterio.open(path) as ds:
            band = ds.read(1, masked=False).astype(np.float64)
            t, crs, nd = ds.transform, ds.crs, ds.nodatavals[0]
    except rasterio.errors.RasterioError as exc:
        raise ConfigError(f"cannot read the DEM: {exc}", file=src, key=key, value=str(path)) from None
    if t.b != 0 or t.d != 0 or t.a <= 0 or t.e == 0:
        raise ConfigError("the DEM must be north-up without rotation or shear (transform b = d = 0, "
                          f"a > 0); it has {tuple(t)[:6]}", file=src, key=key, value=str(path))
    crs_text = None
    if crs is not None:
        units = crs.linear_units.lower() if crs.is_projected else ""
        if not crs.is_projected or units not in ("metre", "meter", "m"):
            raise ConfigError(f"the DEM's CRS ({crs.to_string()}) is not projected in metres; reproject "
                              "it (e.g. gdalwarp -t_srs EPSG:<UTM zone>)", file=src, key=key, value=str(path))
        epsg = crs.to_epsg()
        crs_text = f"EPSG:{epsg}" if epsg else crs.to_wkt()
        if scene_crs is not None and crs_text.upper() != scene_crs.strip().upper():
            raise ConfigError(f"the DEM is in {crs_text}, the scene in {scene_crs} (scene.crs)",
                              file=src, key=key, value=str(path))
    bad = ~np.isfinite(band)
    if nd is not None and np.isfinite(nd):
        bad |= band == nd
    dx, dy = float(t.a), abs(float(t.e))
    ny, nx = band.shape
    x0 = float(t.c) + 0.5 * dx
    if t.e < 0:  # rows run south: turn them so row j is y0 + j·dy
        band, bad = band[::-1], bad[::-1]
        y0 = float(t.f) + (ny - 0.5) * float(t.e)
    else:
        y0 = float(t.f) + 0.5 * dy
    n_bad = int(bad.sum())
    if n_bad == bad.size:
        raise ConfigError("the DEM holds no valid height", file=src, key=key, value=str(path))
    if n_bad:
        if nodata != "nearest":
            j, i = np.argwhere(bad)[0]
            raise ConfigError(f"the DEM has {n_bad} nodata cell(s), the first at x = {x0 + i * dx:.10g}, "
                              f"y = {y0 + j * dy:.10g}; set terrain.nodata = \"nearest\" to fill them",
                              file=src, key=key, value=str(path))
        from scipy.ndimage import distance_transform_edt  # noqa: PLC0415
        _, (jj, ii) = distance_transform_edt(bad, sampling=(dy, dx), return_indices=True)
        band = band[jj, ii]
        where = src if src == str(path) else f"{src}: terrain.file {path}"
        warnings.warn(SimlidarWarning(f"{where}: filled {n_bad} nodata cell(s) "
                                      "from the nearest valid cell (terrain.nodata = \"nearest\")"), stacklevel=2)
    return Terrain(x0, y0, dx, dy, band, crs_text, str(path), n_bad)


# --- from a scene -----------------------------------------------------------------------------

def terrain_of(cfg) -> Terrain | None:
    """The terrain a scene (:class:`~simlidar_mi.config.SceneConfig`) declares, or None
    without ``[terrain]`` (the ground is then the plane z = ``[ground] z_m``)."""
    if not cfg.has("terrain"):
        return None
    t = cfg["terrain"]
    analytic = ("extent_m", "cell_m", "centre_m", "slope_deg", "aspect_deg", "hills_m", "line_azimuth_deg",
                "ditch_depth_m", "ditch_width_m", "step_m")
    if t["file"] is not None:
        given = [k for k in analytic if cfg.gave(f"terrain.{k}")]
        if given:
            raise ConfigError("applies to analytic terrain only, not with terrain.file",
                              file=cfg.source, key=f"terrain.{given[0]}", value=t[given[0]])
        base = Path(cfg.path).parent if cfg.path is not None else Path.cwd()
        path = base / t["file"]
        if not path.is_file():
            raise ConfigError("no such DEM file", file=cfg.source, key="terrain.file", value=t["file"])
        return read_dem(path, t["nodata"], cfg.source, scene_crs=cfg["scene"]["crs"])
    extent = t["extent_m"]
    if extent is None:
        if cfg.has("forest") or cfg.arrays.get("species"):
            x0, x1, y0, y1 = cfg["forest"]["domain_m"]
            m = FOREST_MARGIN_M
            extent = [x0 - m, x1 + m, y0 - m, y1 + m]
        else:
            extent = list(DEFAULT_EXTENT_M)
    relief = {k: t[k] for k in ("slope_deg", "aspect_deg", "line_azimuth_deg", "ditch_depth_m",
                                "ditch_width_m", "step_m")}
    relief["hills"] = [tuple(h) for h in t["hills_m"]]
    if t["centre_m"] is not None:
        relief["centre_m"] = tuple(t["centre_m"])
    parts = [f"slope {t['slope_deg']:g}° to {t['aspect_deg']:g}°" if t["slope_deg"] else "",
             f"{len(t['hills_m'])} hill(s)" if t["hills_m"] else "",
             f"ditch {t['ditch_depth_m']:g} m deep" if t["ditch_depth_m"] else "",
             f"step {t['step_m']:g} m" if t["step_m"] else ""]
    what = "analytic (" + (", ".join(p for p in parts if p) or "flat") + ")"
    return analytic_terrain(extent, t["cell_m"], what, z_m=float(cfg["ground"]["z_m"]), **relief)


def ground_height(cfg):
    """The ground's height function of a scene, ``f(x_m, y_m) -> float64 array``: its
    terrain's :meth:`Terrain.height_m`, else the ``[ground]`` plane's constant ``z_m``."""
    terrain = terrain_of(cfg)
    if terrain is not None:
        return terrain.height_m
    z = float(cfg["ground"]["z_m"])
    return lambda x_m, y_m: np.full(np.broadcast(np.asarray(x_m), np.asarray(y_m)).shape, z)


def check_inside(terrain: Terrain, x_m, y_m, what: str, source=None, key: str = "terrain.extent_m") -> None:
    """Refuse points (plant bases) outside the terrain: they would stand on nothing."""
    x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    out = ~terrain.contains(x, y)
    if out.any():
        k = int(np.argmax(out))
        x0, x1, y0, y1 = terrain.extent_m
        raise ConfigError(f"{int(out.sum())} {what} stand outside the terrain (x {x0:.10g}…{x1:.10g}, "
                          f"y {y0:.10g}…{y1:.10g}), the first at ({float(x.flat[k]):.10g}, {float(y.flat[k]):.10g})",
                          file=source, key=key, value=[x0, x1, y0, y1])


def stand_on(branches: Branches, terrain, x_m, y_m, source=None) -> Branches:
    """Plants ``tree_id`` = k (feet at (x_m[k], y_m[k], 0)) raised by the terrain height under
    their feet, so each stands on it; rows of other ids (trellis) stay."""
    check_inside(terrain, x_m, y_m, "plants", source)
    dz = terrain.height_m(x_m, y_m)
    k = branches.tree_id
    own = (k >= 0) & (k < len(dz))
    shift = np.zeros(len(k))
    shift[own] = dz[k[own]]
    lift = np.column_stack([np.zeros((len(k), 2)), shift])
    return Branches(branches.p0 + lift, branches.p1 + lift, branches.diameter, branches.order, k)
