"""Write scenes/terrain_dem.tif: the small GeoTIFF DEM of scenes/orchard_on_dem.toml.

A 48 × 40 cell DEM, 1 m cells, in UTM zone 32N (EPSG:32632) with its north-west corner at
(500 000 E, 5 000 040 N): a 15 % (8.5°) slope falling to the east, a 2.5 m high knoll and a
0.8 m deep drainage ditch running north-south, heights around 412 m; four cells of nodata
(−9999) in the south-east corner, which the scene fills from their nearest valid cells.
Float32, DEFLATE: a few kB.  Run from the repository root: ``python bench/make_terrain_dem.py``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

from simlidar_mi.io.terrain import relief_m

X0, Y_TOP, CELL, NX, NY = 500_000.0, 5_000_040.0, 1.0, 48, 40
NODATA = -9999.0


def main(path: Path = Path(__file__).resolve().parents[1] / "scenes" / "terrain_dem.tif") -> None:
    x = X0 + CELL * (np.arange(NX) + 0.5)
    y = Y_TOP - CELL * (np.arange(NY) + 0.5)    # row 0 is the northern row
    z = relief_m(x[None, :], y[:, None], z_m=412.0, centre_m=(X0 + 24.0, Y_TOP - 20.0),
                 slope_deg=float(np.degrees(np.arctan(0.15))), aspect_deg=90.0,
                 hills=[(X0 + 14.0, Y_TOP - 12.0, 2.5, 5.0)], ditch_depth_m=0.8, ditch_width_m=3.0,
                 line_azimuth_deg=0.0)
    z = np.round(z, 3).astype(np.float32)
    z[-2:, -2:] = NODATA
    with rasterio.open(path, "w", driver="GTiff", width=NX, height=NY, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(CELL, 0.0, X0, 0.0, -CELL, Y_TOP),
                       nodata=NODATA, compress="deflate", predictor=3) as ds:
        ds.write(z, 1)
    print(f"wrote {path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
