"""The ``evaluate-photo`` sub-command (argument builder and run), registered by :mod:`simlidar_mi.cli`.

Kept beside :mod:`simlidar_mi.truth.photo_scores` so the command line stays one file under the
size limit; it imports nothing heavy until it runs.
"""
from __future__ import annotations

import argparse
from typing import Callable

__all__ = ["cli_command"]

HELP = ("Run the gap-fraction LAI methods (Miller, 57.5°, Lang–Xiang, LAI-2200, Chen–Cihlar) at a "
        "scene's [lai_methods] positions and score them against its truth")


def cli_command(scene_args: Callable[[argparse.ArgumentParser], None],
                overrides: Callable[[argparse.Namespace], list[str]]):
    """``(name, help, add_arguments, run)`` of ``evaluate-photo`` for the CLI's COMMANDS."""
    def add_arguments(p: argparse.ArgumentParser) -> None:
        scene_args(p)
        p.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: photo_scores.csv/json/png, photo_positions.csv")

    def run(args: argparse.Namespace) -> int:
        from .photo_scores import evaluate_photo  # noqa: PLC0415

        out = evaluate_photo(args.scene, args.out, overrides(args), progress=True)
        print(f"{'method':<12} {'target':<6} {'scale':<9} {'n':>4} {'cover':>6} {'truth':>7} "
              f"{'est':>7} {'bias':>7} {'RMSE':>7}   (LAI, PAI: m2/m2)")
        for r in out.scores:
            print(f"{r['method']:<12} {r['target']:<6} {r['scale']:<9} {r['n']:>4} "
                  f"{100 * r['coverage']:5.1f}% {r['truth_mean']:7.3f} {r['estimate_mean']:7.3f} "
                  f"{r['bias']:+7.3f} {r['rmse']:7.3f}")
        print(f"wrote {args.out}/photo_scores.csv and {len(out.files) - 1} more outputs")
        return 0

    return ("evaluate-photo", HELP, add_arguments, run)
