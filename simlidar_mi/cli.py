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
