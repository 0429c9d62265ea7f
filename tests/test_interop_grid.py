"""Our NetCDF grids and scan EXRs opened by independent, real readers (installed by `make test`):

* GDAL (the library QGIS uses), bundled in the ``rasterio`` wheel: ``truth.nc``'s LAD/PAD as an
  x-by-y raster with one band per height, the right geotransform and the scene's CRS;
* the CF checker ``cfchecker`` (CF-1.8, needs the udunits2 C library: `make test` installs
  ``libudunits2-0`` as root): 0 errors, 0 warnings;
* netCDF-C: a NETCDF3_CLASSIC copy through netCDF4 with every type and attribute kept, and
  ``nccopy -k classic`` / ``-k cdf5`` (Debian ``netcdf-bin``, also installed by `make test`);
* the OpenEXR package and OpenImageIO (what ``iinfo``/``oiiotool`` are built on) on scan.exr.
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.truth.grid import VoxelGrid, ascii_text, grid_dataset, grid_values, write_grid

REPO = Path(__file__).resolve().parent.parent
SCENES = sorted(p.name for p in (REPO / "scenes").glob("*.toml"))
VOXEL_M = 0.5  # coarse: every included scene's truth in seconds
# The 300 m forests take minutes even so: a 20 m square around their first bump of trees
SMALLER = {"forest.domain_m": "[51.0, 71.0, 81.0, 101.0]"}


def _import(name: str):
    """A reader module, or a skip naming what to install: only a reader that truly cannot be
    installed may skip (the udunits2 C library behind cfchecker needs apt, as root)."""
    try:
        return __import__(name, fromlist=["_"])
    except (ImportError, OSError) as exc:  # cfunits raises FileNotFoundError without udunits2
        pytest.skip(f"{name} unavailable ({exc}); `make test` installs it (apt: libudunits2-0 as root)")


@pytest.fixture(scope="module")
def cf_checker(tmp_path_factory):
    """cfchecker with the CF standard-name table that the compliance-checker package ships
    (cfchecker fetches its tables from cfconventions.org otherwise). The area-type and region
    tables only list values of ``area_type`` and ``region`` attributes, which our files do not
    use: empty tables keep the check offline."""
    cfchecks = _import("cfchecker.cfchecks")
    from importlib.resources import files
    names = files("compliance_checker") / "data" / "cf-standard-name-table.xml"
    d = tmp_path_factory.mktemp("cf_tables")
    (d / "area.xml").write_text('<?xml version="1.0"?><area_type_table><version_number>0</version_number>'
                                "<date>none</date></area_type_table>")
    (d / "region.xml").write_text('<?xml version="1.0"?><standardized_region_list><version_number>0'
                                  "</version_number><date>none</date></standardized_region_list>")
    checker = cfchecks.CFChecker(cfStandardNamesXML=str(names), cfAreaTypesXML=str(d / "area.xml"),
                                 cfRegionNamesXML=str(d / "region.xml"), silent=True)

    def check(path: Path) -> dict:
        checker.checker(str(path))
        counts = checker.get_counts()
        messages = [f"{where}: {m}" for where, part in (("global", checker.results["global"]),
                                                         *checker.results["variables"].items())
                    for cat in ("FATAL", "ERROR", "WARN") for m in part.get(cat, [])]
        return {"errors": counts["FATAL"] + counts["ERROR"], "warnings": counts["WARN"], "messages": messages}
    return check


def _truth(scene: str, out: Path, *overrides: str) -> Path:
    from simlidar_mi.truth.run import run_truth
    run_truth(REPO / "scenes" / scene, out, [f"truth.voxel_m={VOXEL_M}", *overrides])
    return out / "truth.nc"


def _classic_copy(src: Path, dst: Path) -> None:
    """Copy every dimension, variable (same dtype) and attribute (same value) into a
    NETCDF3_CLASSIC file: netCDF-C refuses 64-bit and unsigned integers and strings there."""
    import netCDF4
    with netCDF4.Dataset(src) as a, netCDF4.Dataset(dst, "w", format="NETCDF3_CLASSIC") as b:
        b.setncatts({k: a.getncattr(k) for k in a.ncattrs()})
        for name, dim in a.dimensions.items():
            b.createDimension(name, len(dim))
        for name, v in a.variables.items():
            v.set_auto_maskandscale(False)
            fill = v.getncattr("_FillValue") if "_FillValue" in v.ncattrs() else None
            w = b.createVariable(name, v.dtype, v.dimensions, fill_value=fill)
            w.setncatts({k: v.getncattr(k) for k in v.ncattrs() if k != "_FillValue"})
            w[...] = v[...]


def _attributes(path: Path) -> list[tuple[str, str, object]]:
    import netCDF4
    with netCDF4.Dataset(path) as ds:
        out = [("global", k, ds.getncattr(k)) for k in ds.ncattrs()]
        for name, v in ds.variables.items():
            out += [(name, k, v.getncattr(k)) for k in v.ncattrs()]
    return out


def _check_classic_and_ascii(path: Path, tmp: Path) -> None:
    for where, key, value in _attributes(path):
        if isinstance(value, str):  # our own texts are ASCII, not escaped non-ASCII
            assert value.isascii() and "\\u" not in value and "\\x" not in value, (where, key, value)
    _classic_copy(path, tmp / "classic.nc")
    if shutil.which("nccopy"):  # netcdf-bin: `make test` installs it as root
        for kind in ("classic", "cdf5"):
            r = subprocess.run(["nccopy", "-k", kind, str(path), str(tmp / f"{kind}.nc")],
                               capture_output=True, text=True)
            assert r.returncode == 0, (kind, r.stderr)


def _check_gdal(path: Path, var: str, epsg: int | None = None) -> None:
    """GDAL opens ``var`` as nx wide, ny high, one band per z layer (its NETCDF_DIM_z tag the
    layer's centre height), north up with the grid's geotransform, and the grid's values."""
    rasterio = _import("rasterio")
    import xarray as xr
    from affine import Affine
    ds = xr.load_dataset(path)
    v = float(ds.attrs["voxel_m"])
    x0, y0, _ = ds.attrs["grid_corner_m"]
    nx, ny, nz = ds.sizes["x"], ds.sizes["y"], ds.sizes["z"]
    with rasterio.open(f"netcdf:{path}:{var}") as r:
        assert (r.width, r.height, r.count) == (nx, ny, nz)
        assert r.transform.almost_equals(Affine(v, 0.0, x0, 0.0, -v, y0 + ny * v), precision=1e-9)
        z_tags = [float(r.tags(b)["NETCDF_DIM_z"]) for b in range(1, nz + 1)]
        np.testing.assert_allclose(z_tags, ds["z"].values, rtol=0, atol=1e-9)
        want = grid_values(ds, var)  # [i, j, k]; a raster row runs along x, top row = largest y
        np.testing.assert_array_equal(r.read(), want[:, ::-1, :].transpose(2, 1, 0))
        if epsg is None:
            assert r.crs is None
        else:
            assert r.crs is not None and r.crs.to_epsg() == epsg


@pytest.mark.parametrize("scene", SCENES)
def test_every_scene_truth_is_cf_classic_and_a_gdal_grid(scene, tmp_path, cf_checker):
    big = "domain_m = [0.0, 300.0" in (REPO / "scenes" / scene).read_text()
    path = _truth(scene, tmp_path / "t", *(f"{k}={v}" for k, v in SMALLER.items() if big))
    got = cf_checker(path)
    assert got["errors"] == 0 and got["warnings"] == 0, got["messages"]
    _check_classic_and_ascii(path, tmp_path)
    crs = load_scene(REPO / "scenes" / scene)["scene"]["crs"]  # scenes/orchard_on_dem.toml's DEM is in UTM
    epsg = int(crs.split(":")[1]) if crs else None
    _check_gdal(path, "LAD_m2_m3", epsg)
    _check_gdal(path, "PAD_m2_m3", epsg)


def test_truth_coordinates_say_what_they_are_in_cf_terms(tmp_path):
    import xarray as xr
    ds = xr.load_dataset(_truth("orchard_leafy.toml", tmp_path / "t"))
    assert ds.attrs["Conventions"] == "CF-1.8"
    for name in ("leaf_area_m2", "wood_area_m2", "wood_volume_m3", "plant_area_m2", "LAD_m2_m3", "PAD_m2_m3"):
        assert ds[name].dims == ("z", "y", "x"), name
    assert {k: ds["x"].attrs[k] for k in ("axis", "units", "standard_name")} == \
        {"axis": "X", "units": "m", "standard_name": "projection_x_coordinate"}
    assert {k: ds["y"].attrs[k] for k in ("axis", "units", "standard_name")} == \
        {"axis": "Y", "units": "m", "standard_name": "projection_y_coordinate"}
    assert {k: ds["z"].attrs[k] for k in ("axis", "units", "standard_name", "positive")} == \
        {"axis": "Z", "units": "m", "standard_name": "height", "positive": "up"}
    coord_attrs = {(w, k) for w, k, _ in _attributes(tmp_path / "t" / "truth.nc") if w in "xyz"}
    assert not {k for _, k in coord_attrs} & {"_FillValue", "missing_value"}  # CF 2.5.1: none on coordinates
    # one word, one meaning: the grid's corner is grid_corner_m; origin_m is the scene origin (EXR)
    assert "origin_m" not in ds.attrs
    np.testing.assert_allclose(ds.attrs["grid_corner_m"], [ds[a].values[0] - VOXEL_M / 2 for a in "xyz"])
    assert "crs" not in ds and "grid_mapping" not in ds["LAD_m2_m3"].attrs  # the scene has no CRS


def test_truth_with_a_scene_crs_has_a_cf_grid_mapping_gdal_reads(tmp_path, cf_checker):
    import pyproj
    import xarray as xr
    path = _truth("apple_orchard.toml", tmp_path / "t", "scene.crs=EPSG:32631", "orchard.n_trees=1")
    got = cf_checker(path)
    assert got["errors"] == 0 and got["warnings"] == 0, got["messages"]
    ds = xr.load_dataset(path)
    assert ds["PAD_m2_m3"].attrs["grid_mapping"] == "crs"
    gm = ds["crs"].attrs
    assert gm["grid_mapping_name"] == "transverse_mercator" and gm["longitude_of_central_meridian"] == 3.0
    assert pyproj.CRS.from_wkt(gm["crs_wkt"]).to_epsg() == 32631
    _check_classic_and_ascii(path, tmp_path)
    _check_gdal(path, "PAD_m2_m3", epsg=32631)


def test_z_is_cf_height_only_above_a_ground_plane_at_zero():
    grid = VoxelGrid((0.0, 0.0, 10.0), 0.5, (2, 3, 4))
    assert grid_dataset(grid, {})["z"].attrs["standard_name"] == "height"
    z = grid_dataset(grid, {}, ground_z_m=10.0)["z"].attrs
    assert "standard_name" not in z and z["axis"] == "Z" and z["positive"] == "up" and "10 m" in z["long_name"]


def test_non_ascii_attributes_are_written_as_ascii_a_classic_copy_keeps(tmp_path):
    assert ascii_text("0 ≤ Σ·x − 2 × 3 ≥ 1°, pêche") == "0 <= sum *x - 2 x 3 >= 1 deg, peche"
    assert ascii_text("果园") == "\\u679c\\u56ed"
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.5, (2, 3, 4))
    path = write_grid(grid_dataset(grid, {"PAD_m2_m3": np.ones(grid.shape),
                                          "n_in": np.arange(24, dtype=np.int64).reshape(grid.shape),
                                          "occupied": np.ones(grid.shape, np.uint8)},
                                   attrs={"scene": "vergers/pêche×2.toml", "n_big": 2**40, "n": np.int64(5),
                                          "flag": True}), tmp_path / "g.nc")
    import netCDF4
    with netCDF4.Dataset(path) as ds:
        assert ds.scene == "vergers/pechex2.toml"
        assert ds.n == 5 and ds.n.dtype == np.int32 and ds.n_big == 2.0**40 and ds.flag == "True"
        assert ds["n_in"].dtype == np.int32 and ds["occupied"].dtype == np.int16
        np.testing.assert_array_equal(ds["n_in"][:].transpose(2, 1, 0), np.arange(24).reshape(grid.shape))
    _check_classic_and_ascii(path, tmp_path)


def test_evaluate_netcdf_outputs_are_cf_classic_and_gdal_grids(tmp_path, cf_checker):
    from simlidar_mi.cli import main
    out = tmp_path / "ev"
    assert main(["evaluate", str(REPO / "scenes" / "orchard_leafy.toml"), "--out", str(out), "--voxel", "0.25",
                 "--set", "scan.dtheta_deg=1.0", "--set", "scan.dy_m=0.04"]) == 0
    files = [out / "truth.nc", out / "grid.nc", *sorted((out / "estimates").glob("*.nc"))]
    assert len(files) == 9  # truth, grid, vcp, beer_lambert, contact_mle and the two G oracle runs of the last two
    for path in files:
        got = cf_checker(path)
        assert got["errors"] == 0 and got["warnings"] == 0, (path.name, got["messages"])
        _check_classic_and_ascii(path, tmp_path)
    _check_gdal(out / "estimates" / "beer_lambert.nc", "n_in")  # float64 counts with NaN nowhere


def test_scan_exr_channels_read_by_openexr_and_openimageio(tmp_path):
    """The OpenEXR package gives ``class`` as uint32 and ``class_half`` as half with the same
    codes; OpenImageIO (iinfo, oiiotool, GIMP's loader) scales the uint32 channel to 0..1, so
    only ``class_half`` shows the classes there."""
    import OpenEXR

    from simlidar_mi.cli import main
    assert main(["scan", str(REPO / "scenes" / "calibration_cylinder.toml"), "--out", str(tmp_path / "s"),
                 "--no-las"]) == 0
    path = tmp_path / "s" / "scan.exr"
    with OpenEXR.File(str(path)) as f:
        ch = {k: np.array(v.pixels) for k, v in f.channels().items()}
    assert ch["class"].dtype == np.uint32 and ch["class_half"].dtype == np.float16
    assert ch["branch_id"].dtype == np.uint32 and ch["range"].dtype == np.float32
    np.testing.assert_array_equal(ch["class_half"], ch["class"])
    assert set(np.unique(ch["class"])) == {0, 1, 2}  # escape, ground, wood: a cylinder on the ground
    oiio = _import("OpenImageIO")
    buf = oiio.ImageBuf(str(path))
    names = list(buf.spec().channelnames)
    stats = oiio.ImageBufAlgo.computePixelStats(buf)
    assert stats.max[names.index("class_half")] == 2.0
    assert stats.max[names.index("class")] == pytest.approx(2 / (2**32 - 1))  # uint32 normalised


def test_estimate_files_are_read_by_dimension_name_in_any_order(tmp_path):
    """The command plug-in contract: a PAD_m2_m3 on dimensions named x, y, z, in the CF order
    (z, y, x) as we write it or in any other, gives the same [i, j, k] array."""
    import xarray as xr

    from simlidar_mi.truth.grid import read_grid
    from simlidar_mi.truth.scoring import check_estimate
    grid = VoxelGrid((1.0, -2.0, 0.0), 0.5, (2, 3, 4))
    pad = np.arange(24, dtype=np.float64).reshape(grid.shape)  # pad[i, j, k]
    coords = {a: grid.centres(i) for i, a in enumerate("xyz")}
    for dims, arr in ((("z", "y", "x"), pad.transpose(2, 1, 0)), (("x", "y", "z"), pad),
                      (("y", "z", "x"), pad.transpose(1, 2, 0))):
        path = tmp_path / f"{''.join(dims)}.nc"
        xr.Dataset({"PAD_m2_m3": (dims, arr)}, coords=coords).to_netcdf(path)
        got_grid, ds = read_grid(path, "PAD_m2_m3")
        assert got_grid == grid and ds["PAD_m2_m3"].dims == ("z", "y", "x")
        np.testing.assert_array_equal(check_estimate(ds, grid, str(path))["PAD_m2_m3"], pad)
