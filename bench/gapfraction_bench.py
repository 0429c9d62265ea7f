"""What gap-fraction accuracy costs in time (results go to BENCHMARKS.md).

    .venv/bin/python bench/gapfraction_bench.py [--quick] [--scene scenes/strawberry_plot.toml]

Prints markdown tables:

1. P0 error against a converged reference and render seconds, for resolutions
   256–2048 and 1–64 samples per pixel, orthographic and perspective, on the
   strawberry plot.  Error = max |P0 − P0_ref| over view zeniths 0/15/30° and
   extraction steps 0 and 3 (the densest and the sparsest canopy); the reference is
   the same view at 4096² × 16 spp (1024² × 16 with --quick).  Cameras and windows
   are the scene file's (inset window, 60° perspective), so the windows cover the
   same ground at every resolution.
2. The paper's whole experiment (4 canopies × 3 zeniths × 2 cameras) at the
   default settings: seconds per stage, without and with writing the files.

Seconds are wall time of one render (rays cast and reduced) after a warm-up
render of the same view, so the Dr.Jit kernel compile is not counted.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

from simlidar_mi._mitsuba import mitsuba  # noqa: E402
from simlidar_mi.config import load_scene  # noqa: E402
from simlidar_mi.canopy.cameras import make_camera  # noqa: E402
from simlidar_mi.canopy.canopy import canopies_from_config  # noqa: E402
from simlidar_mi.canopy.gapfraction import build_canopy_scene, render_gap, run_gapfraction  # noqa: E402
from simlidar_mi.canopy.gapfraction_defaults import DEFAULTS  # noqa: E402
from simlidar_mi.canopy.windows import analysis_window  # noqa: E402

SCENE = REPO / "scenes" / "strawberry_plot.toml"


def accuracy_table(scene: Path, resolutions, spps, zeniths, steps, ref_res: int, ref_spp: int):
    cfg = load_scene(scene)
    g = cfg["gapfraction"]
    canopies = canopies_from_config(cfg)
    ref_canopy = canopies[0]
    mi = mitsuba(cfg["scene"]["variant"])
    integ = mi.load_dict({"type": "coverage"})
    err: dict[tuple, list[float]] = {}
    secs: dict[tuple, list[float]] = {}
    for step in steps:
        canopy = canopies[step]
        built = build_canopy_scene(canopy)
        for kind in ("orthographic", "perspective"):
            for zen in zeniths:
                def view(res):
                    cam = make_camera(kind, ref_canopy, zen, azimuth_deg=g["azimuth_deg"],
                                      resolution=res, fov_deg=g["fov_deg"],
                                      camera_height_m=g["camera_height_m"])
                    return cam, analysis_window(cam, ref_canopy, g["window"],
                                                fraction=g["window_fraction"], margin_m=g["margin_m"])
                cam, win = view(ref_res)
                ref = render_gap(built, canopy, cam, win, spp=ref_spp, integrator=integ).p0
                for res in resolutions:
                    cam, win = view(res)
                    for spp in spps:
                        render_gap(built, canopy, cam, win, spp=spp, integrator=integ)  # warm-up
                        img = render_gap(built, canopy, cam, win, spp=spp, integrator=integ)
                        err.setdefault((kind, res, spp), []).append(abs(img.p0 - ref))
                        secs.setdefault((kind, res, spp), []).append(img.seconds)
                print(f"  done step {step} {kind} {zen:g}° (P0_ref = {ref:.4f})", file=sys.stderr)
    lines = ["| camera | resolution (long side) | spp | max \\|P0 − P0_ref\\| | mean \\|P0 − P0_ref\\| "
             "| seconds / image |", "|---|---|---|---|---|---|"]
    for (kind, res, spp), e in err.items():
        s = secs[(kind, res, spp)]
        lines.append(f"| {kind} | {res} | {spp} | {max(e):.5f} | {np.mean(e):.5f} | {np.mean(s):.3f} |")
    return "\n".join(lines)


def experiment_table(scene: Path):
    rows = ["| what | seconds |", "|---|---|"]
    t = time.perf_counter()
    run = run_gapfraction(scene, None)
    total = time.perf_counter() - t
    n = len(run.images)
    rows.append(f"| {n} images at {DEFAULTS['resolution']}², spp {DEFAULTS['spp']}: generate plot + "
                f"extraction steps | {run.seconds['generate']:.2f} |")
    rows.append(f"| build 4 scenes + render {n} images (incl. kernel compile) | {run.seconds['render']:.2f} |")
    rows.append(f"| of which rendering only (sum of per-image seconds) | "
                f"{sum(i.seconds for i in run.images):.2f} |")
    rows.append(f"| end to end, no files | {total:.2f} |")
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        run = run_gapfraction(scene, Path(tmp) / "out")
        total = time.perf_counter() - t
    rows.append(f"| end to end, writing CSV + JSON + {n} PNG + {n} EXR | {total:.2f} "
                f"(write {run.seconds['write']:.2f}) |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--quick", action="store_true", help="256–1024, spp 1–16, 1024² reference")
    args = ap.parse_args()
    if args.quick:
        res, spps, ref = [256, 512, 1024], [1, 4, 16], (1024, 16)
    else:
        res, spps, ref = [256, 512, 1024, 2048], [1, 4, 16, 64], (4096, 16)
    print(f"## Gap fraction: accuracy against time\n\nMachine: {machine()}; scene "
          f"`{args.scene.relative_to(REPO) if args.scene.is_relative_to(REPO) else args.scene}`; "
          f"reference {ref[0]}² × {ref[1]} spp.\n")
    print(accuracy_table(args.scene, res, spps, [0.0, 15.0, 30.0], [0, 3], *ref))
    print("\n## The paper's experiment (4 canopies × 3 zeniths × 2 cameras) at the defaults\n")
    print(experiment_table(args.scene))


if __name__ == "__main__":
    main()
