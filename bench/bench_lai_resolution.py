"""What fisheye resolution costs in LAI: each method's plot LAI at 128²…1024² against 2048².

The same scene, positions and truth; only ``[fisheye] resolution`` (and ``spp``) change, so the
differences are the discretisation's alone (the truth is the same in every row).  Prints one
Markdown table: per resolution, the seconds of the run and each method's plot-scale estimate
minus the 2048² one.  Usage::

    .venv/bin/python bench/bench_lai_resolution.py [SCENE] [--spp N]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from simlidar_mi.truth.photo_scores import evaluate_photo

RESOLUTIONS = (128, 256, 512, 1024, 2048)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="scenes/orchard_leafy.toml")
    ap.add_argument("--spp", type=int, default=4)
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for res in RESOLUTIONS:
            t = time.perf_counter()
            run = evaluate_photo(args.scene, Path(tmp) / str(res),
                                 [f"fisheye.resolution={res}", f"fisheye.spp={args.spp}"])
            seconds = time.perf_counter() - t
            est = {r["method"]: r["estimate_mean"] for r in run.scores
                   if r["scale"] == "plot" and r["target"] == "LAI"}
            rows[res] = (seconds, est)
            print(f"# {res}²: {seconds:.1f} s", flush=True)
    ref = rows[RESOLUTIONS[-1]][1]
    methods = list(ref)
    print(f"\n{args.scene}, spp {args.spp}; plot LAI at 2048²: "
          + ", ".join(f"{m} {ref[m]:.3f}" for m in methods))
    print("| resolution | run s | " + " | ".join(f"{m} − ref" for m in methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for res in RESOLUTIONS[:-1]:
        seconds, est = rows[res]
        print(f"| {res}² | {seconds:.1f} | " + " | ".join(f"{est[m] - ref[m]:+.4f}" for m in methods) + " |")


if __name__ == "__main__":
    main()
