"""The voxel grid that canopy ground truth and every estimate share, and its file format.

A grid is axis-aligned in the scene's real frame (float64 metres): lower corner
``corner_m``, cubic voxels of side ``voxel_m``, ``shape = (nx, ny, nz)``. Voxel
``(i, j, k)`` spans ``corner + [i, i+1)*voxel`` along x (and likewise y, z). In Python
the arrays of a grid are indexed ``[i, j, k]`` (``grid.shape``).

Files are NetCDF-4 written through xarray, following CF-1.8 so that GDAL, QGIS and other
CF readers open them as georeferenced grids:

* each 3-D variable is stored on the dimensions ``(z, y, x)`` (CF section 2.4: x varies
  fastest, so GDAL reads one x-by-y band per height); :func:`grid_values` gives the
  ``(nx, ny, nz)`` array back;
* ``x``, ``y``, ``z`` are the voxel centres in metres with ``axis``, ``units``,
  ``standard_name`` (``projection_x_coordinate``, ``projection_y_coordinate``; ``height``
  with ``positive = "up"`` when the ground plane is z = 0); voxel ``(i, j, k)`` spans its
  centre +- ``voxel_m``/2 along each axis;
* with the scene's ``crs`` a ``crs`` grid-mapping variable (CF grid-mapping attributes and
  ``crs_wkt``), named by every 3-D variable's ``grid_mapping``;
* one variable per quantity with ``units`` and ``long_name``; the grid's ``grid_corner_m``,
  ``voxel_m`` and the definitions (:data:`DEFINITIONS`) as global attributes;
* attributes are ASCII and every type is one the classic formats hold (no 64-bit or
  unsigned integers, no string type), so ``nccopy -k classic`` or ``-k cdf5`` converts it.

Truth and estimates use the same layout, so a user's estimator only has to write a
Dataset with a ``PAD_m2_m3`` (or ``LAD_m2_m3``) variable on the grid it was given
(:func:`grid_dataset`, :func:`write_grid`).

Definitions (written into every file):

leaf area
    one-sided area of the leaf triangles inside the voxel, m2.
wood area
    total (all-sided) surface area of the woody cylinders inside the voxel, m2.
plant area
    leaf area + half the wood area: the half-total-surface convention of
    Chen & Black (1992, Plant Cell Environ. 15:421-429), under which a flat leaf counts
    once and a cylinder counts half its surface, as in plant area index (PAI).
LAD, PAD
    leaf / plant area per unit voxel volume, m2/m3.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, OutputError

__all__ = ["VoxelGrid", "DEFINITIONS", "UNITS", "DIMS", "grid_dataset", "grid_values", "write_grid", "read_grid",
           "ascii_text"]

#: The dimensions of every 3-D variable on file and in a grid Dataset (CF order: x fastest).
DIMS = ("z", "y", "x")

DEFINITIONS = {
    "leaf_area_m2": "one-sided area of leaf triangles inside the voxel",
    "wood_area_m2": "total surface area of woody cylinders (lateral and exposed ends) inside the voxel",
    "wood_volume_m3": "volume of woody cylinders inside the voxel",
    "plant_area_m2": "leaf area + half the wood area (half-total-surface convention, Chen & Black 1992)",
    "LAD_m2_m3": "leaf area density: leaf area / voxel volume",
    "PAD_m2_m3": "plant area density: plant area / voxel volume",
}
UNITS = {"leaf_area_m2": "m2", "wood_area_m2": "m2", "wood_volume_m3": "m3", "plant_area_m2": "m2",
         "LAD_m2_m3": "m2 m-3", "PAD_m2_m3": "m2 m-3"}


@dataclass(frozen=True)
class VoxelGrid:
    """Cubic voxels of side ``voxel_m`` from the lower corner ``corner_m``."""

    corner_m: tuple[float, float, float]
    voxel_m: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_m) and self.voxel_m > 0):
            raise ConfigError("voxel size must be a finite number > 0", key="voxel_m", value=self.voxel_m)
        if len(self.shape) != 3 or any(int(n) < 1 for n in self.shape):
            raise ConfigError("grid shape must be three whole numbers ≥ 1", key="shape", value=self.shape)
        if len(self.corner_m) != 3 or not np.all(np.isfinite(self.corner_m)):
            raise ConfigError("grid corner must be three finite numbers", key="corner_m", value=self.corner_m)
        object.__setattr__(self, "corner_m", tuple(float(v) for v in self.corner_m))
        object.__setattr__(self, "voxel_m", float(self.voxel_m))
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))

    @classmethod
    def covering(cls, lo_m, hi_m, voxel_m: float, max_voxels: int = 200_000_000) -> "VoxelGrid":
        """The grid of ``voxel_m`` voxels snapped to multiples of ``voxel_m`` (so grids of the
        same voxel size over different scenes line up) that covers the box [lo, hi]."""
        if not (np.isfinite(voxel_m) and voxel_m > 0):
            raise ConfigError("voxel size must be a finite number > 0", key="voxel_m", value=voxel_m)
        lo, hi = np.asarray(lo_m, np.float64), np.asarray(hi_m, np.float64)
        with np.errstate(over="ignore", invalid="ignore"):  # a huge box: an infinite count, refused
            corner = np.floor(lo / voxel_m) * voxel_m
            shape = np.maximum(1, np.ceil((hi - corner) / voxel_m - 1e-9))
        if not np.all(np.isfinite(shape)) or float(np.prod(shape)) > 2.0 * max_voxels:
            count = float(np.prod(shape))  # too many to count exactly (or to hold in an int)
        else:
            count = int(shape[0]) * int(shape[1]) * int(shape[2])  # Python ints: np.prod wraps at 2⁶³
        if count > max_voxels:
            shown = f"{count:,}" if isinstance(count, int) else f"{count:.3g}"
            raise ConfigError(f"a {voxel_m} m grid over this scene has {shown} voxels "
                              f"(> {max_voxels:,}); use larger voxels", key="voxel_m", value=voxel_m)
        return cls(tuple(corner), voxel_m, tuple(int(n) for n in shape))

    @property
    def voxel_volume_m3(self) -> float:
        return self.voxel_m ** 3

    def edges(self, axis: int) -> np.ndarray:
        """Voxel boundaries along ``axis`` (n + 1 values, metres)."""
        return self.corner_m[axis] + self.voxel_m * np.arange(self.shape[axis] + 1, dtype=np.float64)

    def centres(self, axis: int) -> np.ndarray:
        return self.corner_m[axis] + self.voxel_m * (np.arange(self.shape[axis], dtype=np.float64) + 0.5)

    @property
    def hi_m(self) -> np.ndarray:
        return np.asarray(self.corner_m) + self.voxel_m * np.asarray(self.shape)

    def index(self, points_m) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) integer voxel indices of points and a mask of those inside the grid."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        ijk = np.floor((p - np.asarray(self.corner_m)) / self.voxel_m).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(self.shape)), axis=1)
        return ijk, inside

    def attrs(self) -> dict:
        return {"grid_corner_m": list(self.corner_m), "voxel_m": self.voxel_m, "shape": list(self.shape)}


# CF coordinate attributes (section 4): GDAL and QGIS find the raster axes by them.
_COORDS = {
    "x": {"axis": "X", "standard_name": "projection_x_coordinate", "units": "m",
          "long_name": "x of the voxel centre (scene frame)"},
    "y": {"axis": "Y", "standard_name": "projection_y_coordinate", "units": "m",
          "long_name": "y of the voxel centre (scene frame)"},
    "z": {"axis": "Z", "standard_name": "height", "positive": "up", "units": "m",
          "long_name": "height of the voxel centre above the ground plane z = 0"},
}


def _coordinates(grid: VoxelGrid, ground_z_m: float, terrain=None) -> dict:
    """x, y, z voxel centres with their CF attributes. (No CF bounds variables: GDAL lists
    them as rasters of their own, and centres +- voxel_m/2 say the same.)"""
    out = {}
    for i, ax in enumerate("xyz"):
        attrs = dict(_COORDS[ax])
        if ax == "z" and terrain is not None:  # the ground is the terrain: z is not a height above it
            del attrs["standard_name"]
            attrs["long_name"] = "z of the voxel centre (scene frame; the ground is the terrain, variable terrain_z_m)"
        elif ax == "z" and ground_z_m != 0:  # CF "height" is above the surface: not this z
            del attrs["standard_name"]
            attrs["long_name"] = f"z of the voxel centre (scene frame; the ground plane is z = {ground_z_m:g} m)"
        out[ax] = (ax, grid.centres(i), attrs)
    return out


def grid_mapping(crs: str) -> dict:
    """The CF grid-mapping attributes (with ``crs_wkt``) of a CRS such as ``"EPSG:32631"``."""
    import pyproj  # noqa: PLC0415

    cf = pyproj.CRS.from_user_input(crs).to_cf()
    return {k: ascii_text(v) if isinstance(v, str) else v for k, v in cf.items()}


def grid_dataset(grid: VoxelGrid, variables: dict[str, np.ndarray], attrs: dict | None = None,
                 units: dict[str, str] | None = None, long_names: dict[str, str] | None = None, *,
                 crs: str | None = None, ground_z_m: float = 0.0, terrain=None):
    """An xarray Dataset on ``grid`` (module docstring): each variable an array of
    ``grid.shape`` (indexed [i, j, k]), held on (z, y, x) as a transposed view (no copy).
    ``crs``: the scene's ``[scene] crs``, written as a CF grid mapping; ``ground_z_m``: the
    scene's ground plane, which decides whether z is CF ``height``; ``terrain`` (an
    :class:`~simlidar_mi.io.terrain.Terrain`): the ground instead, written as ``terrain_z_m``
    (y, x), its height under each voxel column's centre (NaN off the terrain)."""
    import xarray as xr  # noqa: PLC0415 - only truth/evaluate runs pay for it

    data = {}
    for name, arr in variables.items():
        a = np.asarray(arr)
        if a.shape != grid.shape:
            raise ConfigError(f"variable {name!r} has shape {a.shape}, the grid is {grid.shape}",
                              key=name)
        va = {"units": (units or {}).get(name, UNITS.get(name, "1"))}
        if name in DEFINITIONS or (long_names and name in long_names):
            va["long_name"] = (long_names or {}).get(name, DEFINITIONS.get(name))
        if crs is not None:
            va["grid_mapping"] = "crs"
        data[name] = (DIMS, a.transpose(2, 1, 0), va)
    if terrain is not None:
        yc, xc = grid.centres(1), grid.centres(0)
        tz = terrain.height_m(xc[None, :], yc[:, None])
        data["terrain_z_m"] = (("y", "x"), tz, {"units": "m", "long_name": "terrain height under the voxel "
                                                "column's centre (the ground; z of the scene frame)",
                                                **({"grid_mapping": "crs"} if crs is not None else {})})
    if crs is not None:
        data["crs"] = ((), np.int32(0), grid_mapping(crs))
    ga = {"Conventions": "CF-1.8", "grid_corner_m": list(grid.corner_m), "voxel_m": grid.voxel_m,
          "definitions": "; ".join(f"{k}: {v}" for k, v in DEFINITIONS.items())}
    ga.update(attrs or {})
    return xr.Dataset(data, coords=_coordinates(grid, float(ground_z_m), terrain), attrs=ga)


def grid_values(ds, name: str) -> np.ndarray:
    """Variable ``name`` of a grid Dataset as the ``(nx, ny, nz)`` array (a view)."""
    return np.asarray(ds[name].transpose("x", "y", "z").values)


# Readable ASCII for the few non-ASCII characters our texts use; anything else (a scene path)
# is kept as a backslash escape. NetCDF-4 stores a non-ASCII text as a string attribute,
# which the classic formats do not have.
_ASCII = str.maketrans({"\u2265": ">=", "\u2264": "<=", "\u00b7": "*", "\u2212": "-", "\u2013": "-",
                        "\u2014": "-", "\u00d7": "x", "\u03a3": "sum ", "\u2248": "~", "\u2192": "->",
                        "\u00b0": " deg"})


def ascii_text(text: str) -> str:
    """``text`` in ASCII: symbols as above, accents dropped (NFKD), the rest escaped."""
    import unicodedata  # noqa: PLC0415

    if text.isascii():
        return text
    t = unicodedata.normalize("NFKD", text.translate(_ASCII))
    t = "".join(c for c in t if not unicodedata.combining(c))
    return t.encode("ascii", "backslashreplace").decode("ascii")


def _int_type(a: np.ndarray) -> type:
    """int32 when every value fits, else float64 (exact to 2**53): classic formats have no int64."""
    lo, hi = np.iinfo(np.int32).min, np.iinfo(np.int32).max
    return np.int32 if a.size == 0 or (int(a.min()) >= lo and int(a.max()) <= hi) else np.float64


def _classic(v):
    """An attribute value as a classic-format type: ASCII text, int32 (or float64 when it
    does not fit), float64; True/False/None as text."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, str):
        return ascii_text(v)
    if isinstance(v, (int, np.integer, np.bool_, list, tuple, np.ndarray)):
        a = np.asarray(v)
        if a.dtype.kind == "b":
            return str(v) if a.ndim == 0 else a.astype(np.int8)
        if a.dtype.kind in "iu":
            a = a.astype(_int_type(a))
            return a[()] if a.ndim == 0 else a
    return v


def _encoding(ds) -> dict:
    """zlib for data; no _FillValue on coordinates (CF section 2.5.1) or the grid mapping; integer
    data as int32 (or int8/int16 as they are, float64 past int32), which classic formats hold."""
    enc = {}
    for name, var in ds.variables.items():
        e = {"zlib": True, "complevel": 4} if name in ds.data_vars and var.ndim else {}
        if name in ds.dims or name == "crs":
            e["_FillValue"] = None
        kind, size = var.dtype.kind, var.dtype.itemsize
        if kind == "b" or (kind == "u" and size == 1):
            e["dtype"] = "int16" if kind == "u" else "int8"
        elif kind in "iu" and not (kind == "i" and size <= 4):
            e["dtype"] = np.dtype(_int_type(np.asarray(var.values))).name
        enc[name] = e
    return enc


def write_grid(ds, path: str | Path) -> Path:
    """Write a grid Dataset to NetCDF-4 atomically (a temporary file, then a rename), with
    zlib compression, 3-D variables on (z, y, x) and classic-format types and ASCII
    attributes (module docstring); nothing half-written is left at ``path``.

    Ctrl-C and SIGTERM wait for the end of the write: raised inside ``to_netcdf`` they
    deadlocked it (its clean-up waits on a lock the interrupted write holds)."""
    import errno  # noqa: PLC0415

    from .._runtime.signals import interrupts_deferred  # noqa: PLC0415
    from ..io.atomic import atomic_file  # noqa: PLC0415

    path = Path(path)
    ds = ds.transpose(*DIMS, ..., missing_dims="ignore")
    ds = ds.assign_attrs({k: _classic(v) for k, v in ds.attrs.items()})
    for name in ds.variables:
        ds[name].attrs = {k: _classic(v) for k, v in ds[name].attrs.items()}
    try:
        with atomic_file(path) as tmp, interrupts_deferred():
            ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=_encoding(ds))
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):  # said once, for the folder (io.atomic)
            raise
        raise OutputError(f"{path}: cannot write the voxel grid: {exc}") from exc
    return path


def read_grid(path: str | Path, variable: str | None = None):
    """Open a grid file written by us or by a user's estimator -> (VoxelGrid, Dataset).

    The grid comes from the x/y/z centre coordinates (evenly spaced by the ``voxel_m``
    attribute when present, else by their own step); the variables may be on (z, y, x) or
    any order of named dimensions, and come back on (z, y, x). With ``variable``, that
    variable must exist."""
    import xarray as xr  # noqa: PLC0415

    path = Path(path)
    try:
        ds = xr.load_dataset(path)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read a voxel grid: {exc}", file=str(path)) from exc
    for ax in "xyz":
        if ax not in ds.coords:
            raise ConfigError(f"no '{ax}' coordinate (voxel centres in metres)", file=str(path), key=ax)
    c = [np.asarray(ds[ax].values, np.float64) for ax in "xyz"]
    if "voxel_m" in ds.attrs:
        step = float(ds.attrs["voxel_m"])
    else:
        step = float(np.diff(c[0])[0]) if len(c[0]) > 1 else float("nan")
    for ax, ci in zip("xyz", c):
        if len(ci) > 1 and not np.allclose(np.diff(ci), step, rtol=1e-9, atol=1e-9 * max(1.0, abs(step))):
            raise ConfigError(f"'{ax}' centres are not evenly spaced by the voxel size {step} m",
                              file=str(path), key=ax)
    corner = tuple(float(ci[0]) - 0.5 * step for ci in c)
    grid = VoxelGrid(corner, step, tuple(len(ci) for ci in c))
    if variable is not None and variable not in ds.data_vars:
        raise ConfigError(f"no variable '{variable}' (has: {', '.join(ds.data_vars) or 'none'})",
                          file=str(path), key=variable)
    return grid, ds.transpose(*DIMS, ...)
