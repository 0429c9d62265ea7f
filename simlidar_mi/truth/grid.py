"""The voxel grid that canopy ground truth and every estimate share, and its file format.

A grid is axis-aligned in the scene's real frame (float64 metres): lower corner
``origin_m``, cubic voxels of side ``voxel_m``, ``shape = (nx, ny, nz)``. Voxel
``(i, j, k)`` spans ``origin + [i, i+1)·voxel`` along x (and likewise y, z).

Files are NetCDF-4 written through xarray: dimensions ``x, y, z`` whose coordinates
are the voxel centres in metres, one variable per quantity with ``units`` and
``long_name`` attributes, and the grid's ``origin_m``, ``voxel_m`` and the
definitions (:data:`DEFINITIONS`) as global attributes. Truth and estimates use the
same layout, so a user's estimator only has to write a Dataset with a
``PAD_m2_m3`` (or ``LAD_m2_m3``) variable on the grid it was given
(:func:`grid_dataset`, :func:`write_grid`).

Definitions (written into every file):

leaf area
    one-sided area of the leaf triangles inside the voxel, m².
wood area
    total (all-sided) surface area of the woody cylinders inside the voxel, m².
plant area
    leaf area + half the wood area: the half-total-surface convention of
    Chen & Black (1992, Plant Cell Environ. 15:421–429), under which a flat leaf counts
    once and a cylinder counts half its surface, as in plant area index (PAI).
LAD, PAD
    leaf / plant area per unit voxel volume, m²/m³.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, OutputError

__all__ = ["VoxelGrid", "DEFINITIONS", "UNITS", "grid_dataset", "write_grid", "read_grid"]

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
    """Cubic voxels of side ``voxel_m`` from the lower corner ``origin_m``."""

    origin_m: tuple[float, float, float]
    voxel_m: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_m) and self.voxel_m > 0):
            raise ConfigError("voxel size must be a finite number > 0", key="voxel_m", value=self.voxel_m)
        if len(self.shape) != 3 or any(int(n) < 1 for n in self.shape):
            raise ConfigError("grid shape must be three whole numbers ≥ 1", key="shape", value=self.shape)
        if len(self.origin_m) != 3 or not np.all(np.isfinite(self.origin_m)):
            raise ConfigError("grid origin must be three finite numbers", key="origin_m", value=self.origin_m)
        object.__setattr__(self, "origin_m", tuple(float(v) for v in self.origin_m))
        object.__setattr__(self, "voxel_m", float(self.voxel_m))
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))

    @classmethod
    def covering(cls, lo_m, hi_m, voxel_m: float, max_voxels: int = 200_000_000) -> "VoxelGrid":
        """The grid of ``voxel_m`` voxels snapped to multiples of ``voxel_m`` (so grids of the
        same voxel size over different scenes line up) that covers the box [lo, hi]."""
        if not (np.isfinite(voxel_m) and voxel_m > 0):
            raise ConfigError("voxel size must be a finite number > 0", key="voxel_m", value=voxel_m)
        lo, hi = np.asarray(lo_m, np.float64), np.asarray(hi_m, np.float64)
        origin = np.floor(lo / voxel_m) * voxel_m
        shape = np.maximum(1, np.ceil((hi - origin) / voxel_m - 1e-9))
        count = int(shape[0]) * int(shape[1]) * int(shape[2])  # Python ints: np.prod wraps at 2⁶³
        if count > max_voxels:
            raise ConfigError(f"a {voxel_m} m grid over this scene has {count:,} voxels "
                              f"(> {max_voxels:,}); use larger voxels", key="voxel_m", value=voxel_m)
        return cls(tuple(origin), voxel_m, tuple(int(n) for n in shape))

    @property
    def voxel_volume_m3(self) -> float:
        return self.voxel_m ** 3

    def edges(self, axis: int) -> np.ndarray:
        """Voxel boundaries along ``axis`` (n + 1 values, metres)."""
        return self.origin_m[axis] + self.voxel_m * np.arange(self.shape[axis] + 1, dtype=np.float64)

    def centres(self, axis: int) -> np.ndarray:
        return self.origin_m[axis] + self.voxel_m * (np.arange(self.shape[axis], dtype=np.float64) + 0.5)

    @property
    def hi_m(self) -> np.ndarray:
        return np.asarray(self.origin_m) + self.voxel_m * np.asarray(self.shape)

    def index(self, points_m) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) integer voxel indices of points and a mask of those inside the grid."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        ijk = np.floor((p - np.asarray(self.origin_m)) / self.voxel_m).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(self.shape)), axis=1)
        return ijk, inside

    def attrs(self) -> dict:
        return {"origin_m": list(self.origin_m), "voxel_m": self.voxel_m, "shape": list(self.shape)}


def grid_dataset(grid: VoxelGrid, variables: dict[str, np.ndarray], attrs: dict | None = None,
                 units: dict[str, str] | None = None, long_names: dict[str, str] | None = None):
    """An xarray Dataset on ``grid``: 3-D variables of shape ``grid.shape`` on (x, y, z)."""
    import xarray as xr  # noqa: PLC0415 - only truth/evaluate runs pay for it

    coords = {ax: (ax, grid.centres(i), {"units": "m", "long_name": f"voxel centre {ax}"})
              for i, ax in enumerate("xyz")}
    data = {}
    for name, arr in variables.items():
        a = np.asarray(arr)
        if a.shape != grid.shape:
            raise ConfigError(f"variable {name!r} has shape {a.shape}, the grid is {grid.shape}",
                              key=name)
        va = {"units": (units or {}).get(name, UNITS.get(name, "1"))}
        if name in DEFINITIONS or (long_names and name in long_names):
            va["long_name"] = (long_names or {}).get(name, DEFINITIONS.get(name))
        data[name] = (("x", "y", "z"), a, va)
    ga = {"Conventions": "CF-1.8", "origin_m": list(grid.origin_m), "voxel_m": grid.voxel_m,
          "definitions": "; ".join(f"{k}: {v}" for k, v in DEFINITIONS.items())}
    ga.update(attrs or {})
    return xr.Dataset(data, coords=coords, attrs=ga)


def write_grid(ds, path: str | Path) -> Path:
    """Write a grid Dataset to NetCDF-4 atomically (a temporary file, then a rename), with
    zlib compression; nothing half-written is left at ``path``.

    Ctrl-C and SIGTERM wait for the end of the write: raised inside ``to_netcdf`` they
    deadlocked it (its clean-up waits on a lock the interrupted write holds)."""
    import errno  # noqa: PLC0415

    from .._signals import interrupts_deferred  # noqa: PLC0415
    from ..io.atomic import atomic_file  # noqa: PLC0415

    path = Path(path)
    enc = {name: {"zlib": True, "complevel": 4} for name in ds.data_vars}
    attrs = {k: (str(v) if isinstance(v, bool) or v is None else v) for k, v in ds.attrs.items()}
    try:
        with atomic_file(path) as tmp, interrupts_deferred():
            ds.assign_attrs(attrs).to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=enc)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):  # said once, for the folder (io.atomic)
            raise
        raise OutputError(f"{path}: cannot write the voxel grid: {exc}") from exc
    return path


def read_grid(path: str | Path, variable: str | None = None):
    """Open a grid file written by us or by a user's estimator → (VoxelGrid, Dataset).

    The grid comes from the ``origin_m``/``voxel_m`` attributes when present, else from
    the x/y/z centre coordinates (which must be evenly spaced with one step). With
    ``variable``, that variable must exist."""
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
    origin = tuple(float(ci[0]) - 0.5 * step for ci in c)
    grid = VoxelGrid(origin, step, tuple(len(ci) for ci in c))
    if variable is not None and variable not in ds.data_vars:
        raise ConfigError(f"no variable '{variable}' (has: {', '.join(ds.data_vars) or 'none'})",
                          file=str(path), key=variable)
    return grid, ds.transpose("x", "y", "z", ...)
