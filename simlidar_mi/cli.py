"""Command line: a thin shell over the Python API.

Each sub-command is a ``(name, help, add_arguments, run)`` entry in COMMANDS;
``run(args)`` makes one API call and prints or writes its result.
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable

from .errors import SimlidarError

Command = tuple[str, str, Callable[[argparse.ArgumentParser], None],
                Callable[[argparse.Namespace], int | None]]
COMMANDS: list[Command] = []


def command(name: str, help: str, add_arguments: Callable[[argparse.ArgumentParser], None]):
    """Decorator registering ``run`` as sub-command ``name``."""
    def deco(run):
        COMMANDS.append((name, help, add_arguments, run))
        return run
    return deco


# --- sub-commands -----------------------------------------------------------------
# (each block: argument builder + run function calling one API function)


def _photo_gap_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("photos", nargs="+", metavar="PHOTO", help="8-bit RGB photos (JPEG, PNG, ...)")
    p.add_argument("--method", required=True, choices=["canopeo", "exg-otsu", "blue-otsu"],
                   help="canopeo / exg-otsu for nadir photos, blue-otsu for upward photos")
    p.add_argument("--crop", default=None, metavar="F|x0,y0,x1,y1",
                   help="central fraction kept in each dimension (0.5) or a pixel box")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list of {file, method, threshold, cover, p0, ...}")
    p.add_argument("--mask-dir", default="photo_masks", metavar="DIR",
                   help="where to write <stem>_<method>_mask.png (default ./photo_masks/)")


@command("photo-gap", "Gap fraction and vegetation cover of real photos (mask PNGs saved)",
         _photo_gap_args)
def _photo_gap_run(args: argparse.Namespace) -> int:
    import json

    from .errors import PhotoError
    from .photo import photo_gap

    results, failed = [], 0
    for photo in args.photos:
        try:  # one bad photo should not hide the others' results
            results.append(photo_gap(photo, args.method, args.crop, mask_dir=args.mask_dir))
        except PhotoError as exc:
            failed += 1
            print(f"simlidar-mi photo-gap: error: {exc}", file=sys.stderr)
    if args.json:
        keys = ("file", "method", "threshold", "cover", "p0", "n_pixels", "crop", "mask_file")
        print(json.dumps([{k: r.to_dict()[k] for k in keys} for r in results], indent=2))
    elif results:
        w = max(len(str(r.file)) for r in results)
        print(f"{'file':<{w}}  {'method':<9}  {'threshold':>9}  {'cover':>6}  {'p0':>6}  "
              f"{'pixels':>9}  mask")
        for r in results:
            t = "-" if r.threshold is None else f"{r.threshold:.4g}"
            print(f"{str(r.file):<{w}}  {r.method:<9}  {t:>9}  {r.cover:6.4f}  {r.p0:6.4f}  "
                  f"{r.n_pixels:>9}  {r.mask_file}")
    return 2 if failed else 0


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    p = argparse.ArgumentParser(prog="simlidar-mi", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"simlidar-mi {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for name, help_, add_args, run in COMMANDS:
        sp = sub.add_parser(name, help=help_, description=help_)
        add_args(sp)
        sp.set_defaults(_run=run)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        rc = args._run(args)
    except SimlidarError as exc:
        print(f"simlidar-mi {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
