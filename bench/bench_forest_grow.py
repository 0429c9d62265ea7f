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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, type=Path, help="checkout to compare with")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out-root", type=Path, default=Path("/tmp/bench_forest_grow"))
    a = ap.parse_args()
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
    med = {t: {k: statistics.median(r[k] for r in rs) for k in ("grow", "wall", "cpu")}
           for t, rs in rows.items()}
    for k in ("grow", "wall", "cpu"):
        b, f = med["before"][k], med["after"][k]
        pairs = [x[k] / y[k] for x, y in zip(rows["before"], rows["after"])]
        print(f"median {k}: before {b:.2f} s, after {f:.2f} s; before/after per pair "
              f"{', '.join(f'{p:.2f}' for p in pairs)} (median {statistics.median(pairs):.2f}×)")


if __name__ == "__main__":
    main()
