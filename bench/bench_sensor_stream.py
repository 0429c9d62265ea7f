"""Peak RSS and wall time of streamed [sensor] scans against a held "before" (BENCHMARKS.md §8b).

    .venv/bin/python bench/bench_sensor_stream.py --before DIR [--dy 0.01 0.00167 0.00042]

Runs ``simlidar-mi scan scenes/orchard_lms511.toml --set sensor.beam_samples=4 --set
sensor.max_returns=3 --set scan.dy_m=DY`` under ``/usr/bin/time -v``, each in a fresh process
(``python -P -m simlidar_mi.cli``, so the code comes from ``PYTHONPATH`` only), "before" from
DIR (e.g. ``git archive <base> | tar -x -C DIR`` plus the ``simlidar_mi/plugins`` symlink),
"after" from this checkout, interleaved; prints one markdown row per run with the load average
at its start, and whether the two folders' files are the same bytes (measures.json without its
seconds and scene path).  ``--after-only`` runs this checkout alone (scans too big to hold).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SETS = ["sensor.beam_samples=4", "sensor.max_returns=3"]


def run(tree: Path, dy: float, out: Path) -> dict:
    cmd = ["/usr/bin/time", "-v", sys.executable, "-P", "-m", "simlidar_mi.cli", "scan",
           "scenes/orchard_lms511.toml", *[a for s in SETS + [f"scan.dy_m={dy}"] for a in ("--set", s)],
           "--out", str(out)]
    load = Path("/proc/loadavg").read_text().split()[0]
    p = subprocess.run(cmd, cwd=tree, env=dict(os.environ, PYTHONPATH=str(tree)), capture_output=True, text=True)
    if p.returncode:
        raise SystemExit(p.stderr[-2000:])
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", p.stderr).group(1)
    secs = sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall.split(":"))))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1))
    cpu = sum(float(re.search(rf"{k} time \(seconds\): (\S+)", p.stderr).group(1)) for k in ("User", "System"))
    m = json.loads((out / "measures.json").read_text())
    return {"wall_s": secs, "cpu_s": cpu, "rss_gb": rss * 1024 / 1e9, "load": load, "beams": m["N"] * m["M"],
            "stages": m["seconds"], "las_mb": (out / "points.las").stat().st_size / 1e6}


def same_files(a: Path, b: Path) -> bool:
    for f in sorted(p.name for p in a.iterdir()):
        x, y = (a / f).read_bytes(), (b / f).read_bytes()
        if f == "measures.json":
            x, y = (json.loads(v) for v in (x, y))
            for d in (x, y):
                d.pop("seconds"), d.pop("scene")
        if x != y:
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path)
    ap.add_argument("--dy", type=float, nargs="+", default=[0.01, 0.00167, 0.00042])
    ap.add_argument("--after-only", action="store_true", help="no before run (scans too big to hold)")
    args = ap.parse_args()
    print("| beams | before: wall / CPU / peak RSS | after: wall / CPU / peak RSS | after stages (s) | load | same bytes |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(dir=REPO / "bench") as d:
        for dy in args.dy:
            b = None if args.after_only else run(args.before.resolve(), dy, Path(d) / f"b{dy}")
            a = run(REPO, dy, Path(d) / f"a{dy}")
            before = "–" if b is None else f"{b['wall_s']:.1f} s / {b['cpu_s']:.1f} s / {b['rss_gb']:.2f} GB"
            same = "–" if b is None else same_files(Path(d) / f"b{dy}", Path(d) / f"a{dy}")
            print(f"| {a['beams'] / 1e6:.2f} M | {before} | {a['wall_s']:.1f} s / {a['cpu_s']:.1f} s / "
                  f"{a['rss_gb']:.2f} GB | {a['stages']} | {'–' if b is None else b['load']}, {a['load']} | "
                  f"{same} |", flush=True)
            shutil.rmtree(d, ignore_errors=True)
            Path(d).mkdir()


if __name__ == "__main__":
    main()
