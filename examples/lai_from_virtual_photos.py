"""LAI from virtual hemispherical photographs, each method scored against the exact LAI.

Task: you estimate leaf area index from upward fisheye photos (or an LAI-2200) and want to
know how far each gap-fraction method is from the true LAI on a canopy you control. Here the
canopy is ``scenes/random_leaves_spherical.toml``: 1000 square leaves of 10 cm² with a
spherical leaf-angle law in a 1 m × 1 m periodic plot, so LAI = 1000 × 0.001 m² / 1 m² = 1
exactly. ``evaluate-photo`` renders a virtual fisheye photo at each ``[fisheye]`` position (a
3 × 3 grid, the lens below the leaves looking up), runs Miller's integral, Lang & Xiang's
log-averaging, the 57.5° method, the LAI-2200's rings and Chen & Cihlar's clumping on them,
and scores each against the truth computed from the leaves themselves.

Run from the clone's root (``--quick``: 256-pixel images, a few seconds)::

    .venv/bin/python examples/lai_from_virtual_photos.py --out out/lai_virtual --quick

The same from the command line: ``simlidar-mi evaluate-photo scenes/random_leaves_spherical.toml
--out out/lai_virtual``; the photos alone: ``simlidar-mi fisheye SCENE --out DIR`` (one PNG and
one EXR per position, and their ring × sector gap table).
"""
from __future__ import annotations

import argparse
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENE = HERE.parent / "scenes" / "random_leaves_spherical.toml"
TRUE_LAI = 1000 * 0.001 / (1.0 * 1.0)  # n_leaves × leaf_area_m2 / plot area, from the scene file


def main(argv=None) -> int:
    from simlidar_mi.truth.photo_scores import evaluate_photo

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/lai_virtual", help="output folder")
    ap.add_argument("--quick", action="store_true", help="256-pixel images")
    args = ap.parse_args(argv)
    run = evaluate_photo(SCENE, args.out, ["fisheye.resolution=256"] if args.quick else [], progress=True)
    print(f"true LAI {TRUE_LAI:g} (scene file); the truth computed from the leaves: "
          f"{run.get('miller', 'LAI', 'plot')['truth_mean']:.4f}")
    print(f"{'method':<12} {'LAI':>7} {'bias':>7} {'RMSE per position':>18}")
    for method in ("miller", "miller_lx", "hinge_57", "lai2200", "lai2200_le", "chen_cihlar"):
        plot = run.get(method, "LAI", "plot")
        try:
            rmse = f"{run.get(method, 'LAI', 'position')['rmse']:.3f}"
        except KeyError:  # a plot-level method
            rmse = "-"
        print(f"{method:<12} {plot['estimate_mean']:>7.3f} {plot['bias']:>+7.3f} {rmse:>18}")
    print(f"scores and plots in {args.out}/ (photo_scores.csv, photo_scores.json, photo_scores.png)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
