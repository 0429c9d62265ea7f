"""Score your own voxel estimator against the exact truth of a virtual orchard.

Task: you have an idea for estimating plant area density (PAD, m²/m³) per voxel from a LiDAR
scan, and want to know how good it is. ``simlidar-mi evaluate`` scans a scene, computes its
exact truth on a voxel grid, runs the built-in estimators and yours on the same scan, and
scores each against the truth on the same voxels (R², RMSE, bias, coverage).

Your estimator is a function ``f(scan_dir, grid)``: ``scan_dir`` holds the scan's
``points.las``, ``scan.exr`` and ``measures.json``; ``grid`` is the truth's
:class:`simlidar_mi.truth.grid.VoxelGrid`. It returns ``{"PAD_m2_m3": array of grid.shape}``
indexed [i, j, k] along x, y, z (NaN where it makes no estimate). Here it is a naive one that
reads the LAS file with laspy, as most users' code starts: vegetation returns per voxel times
an assumed area per return.

Run from the clone's root (``--quick``: a coarser scan, a few seconds)::

    .venv/bin/python examples/score_my_estimator.py --out out/score_my_estimator --quick

The same from the command line: ``simlidar-mi evaluate SCENE --out DIR --estimator
examples/score_my_estimator.py:returns_per_voxel``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SCENE = HERE.parent / "scenes" / "orchard_leafy.toml"
M2_PER_RETURN = 0.002  # the assumed plant area behind one vegetation return (your calibration)
QUICK = ["scan.dtheta_deg=1.0", "scan.dy_m=0.04"]  # a coarser scan: seconds instead of minutes


def returns_per_voxel(scan_dir, grid):
    """Your estimator: vegetation returns in each voxel × M2_PER_RETURN / voxel volume (0 where
    none; return NaN for a voxel to abstain, which is scored as 0 too)."""
    import laspy

    las = laspy.read(Path(scan_dir) / "points.las")
    veg = np.isin(np.asarray(las.classification), (5, 64))  # leaf (ASPRS high vegetation), wood (64)
    pts = np.column_stack([las.x, las.y, las.z])[veg]
    edges = [np.append(grid.centres(a) - grid.voxel_m / 2, grid.centres(a)[-1] + grid.voxel_m / 2)
             for a in range(3)]
    count, _ = np.histogramdd(pts, bins=edges)
    return {"PAD_m2_m3": count * M2_PER_RETURN / grid.voxel_m ** 3}


def main(argv=None) -> int:
    from simlidar_mi.truth.evaluate import evaluate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/score_my_estimator", help="output folder")
    ap.add_argument("--quick", action="store_true", help="a coarser scan (seconds)")
    ap.add_argument("--voxel", type=float, default=0.5, help="voxel size, m")
    args = ap.parse_args(argv)
    run = evaluate(SCENE, args.out, QUICK if args.quick else (), estimators=[returns_per_voxel],
                   voxel_m=args.voxel, progress=True)
    print(f"{'estimator':<20} {'n':>5} {'R²':>7} {'RMSE':>7} {'bias':>7} {'coverage':>8}   (PAD, m²/m³)")
    for row in run.scores:
        if row["scale"] == "voxel" and row["variable"] == "PAD_m2_m3":
            print(f"{row['estimator']:<20} {row['n']:>5} {row['r2']:>7.3f} {row['rmse']:>7.3f} "
                  f"{row['bias']:>7.3f} {row['coverage_voxels']:>8.2f}")
    print(f"scores, profiles and plots in {args.out}/ (scores.csv, profiles.png, scatter.png)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
