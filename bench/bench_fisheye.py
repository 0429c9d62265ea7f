"""Virtual DHP (``simlidar-mi fisheye``): render time per image, and ring gap-fraction error
against resolution and samples per pixel.

    .venv/bin/python bench/bench_fisheye.py [--scenes forest_small orchard_leafy] [--positions 3]
                                            [--ref 2048 16] [--res 128 256 512 1024] [--spp 1 4]

Per scene: generate and build once, place the ``[fisheye]`` default 3 × 3 grid (equidistant,
circular, looking up), and render the first ``--positions`` cameras.  Time: wall seconds of
:func:`render_fisheye` (rays cast and reduced, pixel angles; a first warm-up render compiles the
kernels and is not counted), median over positions.  Error: the ring gap fractions (0–15 … 75–90°,
solid-angle weighted) of each (resolution, spp) against the same positions rendered at ``--ref``
(resolution, spp): RMS and largest absolute difference over rings and positions.  Prints markdown.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENES = {"forest_small": "scenes/forest_small.toml", "orchard_leafy": "scenes/orchard_leafy.toml",
          "vineyard_vsp": "scenes/vineyard_vsp.toml"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["forest_small", "orchard_leafy"], choices=list(SCENES))
    ap.add_argument("--positions", type=int, default=3)
    ap.add_argument("--ref", type=int, nargs=2, default=[2048, 16], metavar=("RES", "SPP"))
    ap.add_argument("--res", type=int, nargs="+", default=[128, 256, 512, 1024])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 4])
    args = ap.parse_args()

    from dataclasses import replace

    from simlidar_mi.canopy.fisheye import make_fisheye, render_fisheye
    from simlidar_mi.canopy.fisheye_run import fisheye_cameras
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.survey import build
    from simlidar_mi.truth.run import truth_geometry

    print(machine())
    print()
    timing, errors = [], []
    for name in args.scenes:
        cfg = load_scene(REPO / SCENES[name])
        t0 = time.perf_counter()
        geo, _ = truth_geometry(cfg)
        built = build(cfg, geo, patterns=[])
        t_build = time.perf_counter() - t0
        cams = fisheye_cameras(cfg, *geo.bounds_m())[: args.positions]
        default = cfg["fisheye"]

        def at(cam, res):
            return replace(cam, **{k: getattr(make_fisheye(cam.position_m, resolution=res), k)
                                   for k in ("width", "height")})

        render_fisheye(built, at(cams[0], 64), spp=1)  # warm-up: kernel compilation
        secs = [render_fisheye(built, c, spp=default["spp"]).seconds for c in cams]
        timing.append((name, built.n_triangles, t_build, default["resolution"], default["spp"], statistics.median(secs)))
        ref = [render_fisheye(built, at(c, args.ref[0]), spp=args.ref[1]).table().ring_gap for c in cams]
        for res in args.res:
            for spp in args.spp:
                got = [render_fisheye(built, at(c, res), spp=spp) for c in cams]
                d = np.concatenate([g.table().ring_gap - r for g, r in zip(got, ref)])
                errors.append((name, res, spp, float(np.sqrt(np.mean(d * d))), float(np.abs(d).max()),
                               statistics.median(g.seconds for g in got)))
    print("| scene | triangles | build s | resolution | spp | s per image (median) |")
    print("|---|---|---|---|---|---|")
    for name, tri, tb, res, spp, s in timing:
        print(f"| {name} | {tri:,} | {tb:.1f} | {res}² | {spp} | {s:.3f} |")
    print()
    print(f"Ring gap fraction vs {args.ref[0]}² at spp {args.ref[1]} ({args.positions} positions × 6 rings):")
    print()
    print("| scene | resolution | spp | RMS error | max error | s per image |")
    print("|---|---|---|---|---|---|")
    for name, res, spp, rms, mx, s in errors:
        print(f"| {name} | {res}² | {spp} | {rms:.4f} | {mx:.4f} | {s:.3f} |")


if __name__ == "__main__":
    main()
