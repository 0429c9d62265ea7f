"""Run the benchmarks behind BENCHMARKS.md, one after the other (what ``make bench`` runs).

    .venv/bin/python bench/run_all.py [--only NAME ...] [--list]

Each bench runs in its own process, in turn (never two at once: they time each other), and
its standard output, the markdown table BENCHMARKS.md shows, goes to ``bench/out/NAME.md``.
The list holds the benches that need no other checkout and finish in minutes; the others
(``--before DIR`` comparisons, the Dask tiles, the photo and truth sweeps) are run by hand
with the command their BENCHMARKS.md section gives.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "out"

#: name -> arguments of ``python bench/...``; the BENCHMARKS.md section in the comment.
BENCHES: dict[str, list[str]] = {
    "scan_reps": ["bench_scan.py", "--only", "reps"],              # §1
    "scan_linear": ["bench_scan.py", "--only", "linear"],          # §1
    "scan_sweep": ["bench_scan.py", "--only", "sweep"],            # §1
    "gapfraction": ["gapfraction_bench.py"],                       # §2
    "table3": ["bench_scan.py", "--only", "table3"],               # §3
    "table3_cover": ["bench_scan.py", "--only", "table3-cover"],   # §3
    "table3_counts": ["bench_table3_counts.py", "--seeds", "200"],  # §3
    "forest": ["bench_forest.py", "--only", "instanced"],          # §4
    "forest_counts": ["bench_forest_counts.py", "--seeds", "10", "--seed-modes", "poisson"],  # §11
    "forest_laws": ["bench_forest_laws.py"],                       # §11, forests page tables
    "forest_repr": ["bench_forest_repr.py"],                       # §16
    "forest_repr_seeds": ["bench_forest_repr.py", "--seeds-only", "--modes", "explicit,k12,k4",
                          "--seeds", "2021,2022,2023,2024"],        # §16 over seeds
    "sensor": ["bench_sensor.py", "--dy", "0.02", "--repeat", "2"],  # §7
    "sensor_readings": ["bench_sensor.py", "--readings", "--dy", "0.02"],  # §7b
    "echo_rules": ["bench_echo_rules.py"],                         # §7c
    "noise_laws": ["bench_noise_laws.py"],                         # §7d
    "scale": ["bench_scale.py", "--repeat", "3", "--repeat-long", "1"],  # §8a
    "scan_breakdown": ["bench_scan_write.py", "--breakdown", "5"],  # §8e
    "build": ["bench_build.py"],                                   # §9
    "leafy": ["bench_leafy.py"],                                   # §10a
    "vineyard": ["bench_vineyard.py"],                             # §10b
    "estimators_g": ["bench_estimators.py", "--only-g"],           # §10e
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=sorted(BENCHES), help="run these benches only")
    ap.add_argument("--list", action="store_true", help="print the benches and their commands")
    a = ap.parse_args()
    names = a.only or list(BENCHES)
    if a.list:
        for name in names:
            print(f"{name}: {' '.join(['bench/' + BENCHES[name][0], *BENCHES[name][1:]])}")
        return 0
    OUT.mkdir(parents=True, exist_ok=True)
    failed = []
    for name in names:
        script, *args = BENCHES[name]
        t0 = time.perf_counter()
        with open(OUT / f"{name}.md", "w") as out:
            rc = subprocess.call([sys.executable, str(REPO / "bench" / script), *args], stdout=out, cwd=REPO)
        print(f"{name}: {'ok' if rc == 0 else f'exit {rc}'} in {time.perf_counter() - t0:.0f} s "
              f"-> {(OUT / f'{name}.md').relative_to(REPO)}", flush=True)
        if rc:
            failed.append(name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
