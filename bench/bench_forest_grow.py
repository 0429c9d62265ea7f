"""Forest growth stage, before and after: ``simlidar-mi forest scenes/forest_4species.toml``.

    .venv/bin/python bench/bench_forest_grow.py --before DIR [--repeat 3] [--out-root /tmp]

``DIR`` is a checkout of the code to compare with (e.g. ``git worktree add DIR main``).
Each repeat runs the command once from ``DIR`` and once from this checkout, interleaved, each in
a fresh process (``python -P -m simlidar_mi.cli forest …``). Per run: the growth seconds the
command reports (``forest.json`` → ``seconds.grow``: every prototype's tree and leaves, and
their crown radii), the other stages, wall seconds from process start to exit, and the child's
CPU seconds (user + system); the 1-minute load average before the run. The last pair's output
folders are compared with ``bench/same_outputs.py`` (same data bytes but for ``seconds``).
Prints a markdown table: per-run rows, then medians and before/after ratios.

``--grow-only`` runs just ``make_forest`` (placement and growth, no files) in each fresh
process and reports its wall and CPU seconds (``resource.getrusage`` of the process around the
call): on a shared machine the CPU seconds of the stage move far less with the load than the
wall seconds do.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENE = "scenes/forest_4species.toml"


def run(root: Path, out: Path) -> dict:
    """One fresh ``forest`` command from checkout ``root`` writing to ``out``."""
    env = dict(os.environ, PYTHONPATH=str(root))
    load = os.getloadavg()[0]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-P", "-m", "simlidar_mi.cli", "forest", SCENE,
                           "--out", str(out)], cwd=root, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    sec = json.loads((out / "forest.json").read_text())["seconds"]
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"load": load, "wall": wall, "cpu": cpu, **sec}


GROW = r"""
import json, resource, sys, time
from simlidar_mi.config import load_scene
from simlidar_mi.forest.stand import make_forest
cfg = load_scene(sys.argv[1])
r0 = resource.getrusage(resource.RUSAGE_SELF); t0 = time.perf_counter()
f = make_forest(cfg)
wall = time.perf_counter() - t0; r1 = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"wall": wall, "user": r1.ru_utime - r0.ru_utime, "sys": r1.ru_stime - r0.ru_stime,
                  **f.seconds}))
"""


def run_grow(root: Path) -> dict:
    """``make_forest`` alone in a fresh process from checkout ``root``."""
    env = dict(os.environ, PYTHONPATH=str(root))
    load = os.getloadavg()[0]
    proc = subprocess.run([sys.executable, "-P", "-c", GROW, SCENE], cwd=root, env=env,
                          capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"load": load, "cpu": r["user"] + r["sys"], **r}


def grow_only(before: Path, repeat: int) -> None:
    rows = {"before": [], "after": []}
    print("| pair | code | load | grow s | place s | make_forest wall s | CPU s (user + sys) |")
    print("|---|---|---|---|---|---|---|")
    for i in range(repeat):
        for tag, root in (("before", before), ("after", REPO)):
            r = run_grow(root)
            rows[tag].append(r)
            print(f"| {i + 1} | {tag} | {r['load']:.1f} | {r['grow']:.2f} | {r['place']:.2f} | "
                  f"{r['wall']:.2f} | {r['cpu']:.2f} ({r['user']:.2f} + {r['sys']:.2f}) |", flush=True)
    _ratios(rows, ("grow", "wall", "cpu"))


def _ratios(rows: dict, keys) -> None:
    for k in keys:
        b = statistics.median(r[k] for r in rows["before"])
        f = statistics.median(r[k] for r in rows["after"])
        pairs = [x[k] / y[k] for x, y in zip(rows["before"], rows["after"])]
        print(f"median {k}: before {b:.2f} s, after {f:.2f} s; before/after per pair "
              f"{', '.join(f'{p:.2f}' for p in pairs)} (median {statistics.median(pairs):.2f}×)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, type=Path, help="checkout to compare with")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out-root", type=Path, default=Path("/tmp/bench_forest_grow"))
    ap.add_argument("--grow-only", action="store_true", help="time make_forest alone (no files)")
    a = ap.parse_args()
    if a.grow_only:
        return grow_only(a.before.resolve(), a.repeat)
    print("| pair | code | load | grow s | place s | tables s | plots s | export s | wall s | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = {"before": [], "after": []}
    for i in range(a.repeat):
        for tag, root in (("before", a.before.resolve()), ("after", REPO)):
            out = a.out_root / f"{tag}{i}"
            subprocess.run(["rm", "-rf", str(out)], check=True)
            rows[tag].append(run(root, out))
            r = rows[tag][-1]
            print(f"| {i + 1} | {tag} | {r['load']:.1f} | {r['grow']:.2f} | {r['place']:.2f} | "
                  f"{r.get('tables', 0):.2f} | {r.get('plots', 0):.2f} | {r.get('export', 0):.2f} | "
                  f"{r['wall']:.2f} | {r['cpu']:.2f} |", flush=True)
    last = a.repeat - 1
    same = subprocess.run([sys.executable, str(REPO / "bench" / "same_outputs.py"),
                           str(a.out_root / f"before{last}"), str(a.out_root / f"after{last}")],
                          capture_output=True, text=True)
    print("\nsame_outputs:", same.stdout.strip().splitlines()[-1] if same.stdout.strip() else same.stderr[-500:])
    _ratios(rows, ("grow", "wall", "cpu"))


if __name__ == "__main__":
    main()
