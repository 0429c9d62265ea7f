"""Forest generation, scene build and a 10 M-pulse airborne scan, with and without instancing.

    .venv/bin/python bench/bench_forest.py [--only instanced|instanced-auto|instanced-k12|flat]

``instanced``: the scene's defaults (12 prototypes a species since issue 30);
``instanced-auto``: ``prototypes_per_species = "auto"`` (at most 5 trees a prototype);
``instanced-k12``: 12 prototypes a species, whatever the scene says; ``flat``: every tree its own
draw (BENCHMARKS §16 compares these on a small square, with their accuracy).

Each mode runs in a fresh process (peak RSS is the process's own); prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENE = REPO / "scenes" / "forest_airborne.toml"
ROW = r"""
import json, resource, sys, time
import numpy as np
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import generate, build, scan_patterns
from simlidar_mi.lidar.scan import scan
cfg = load_scene(sys.argv[1], sys.argv[2:])
t = time.perf_counter(); geo = generate(cfg); t_gen = time.perf_counter() - t
lo, hi = geo.bounds_m()
rss_gen = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
t = time.perf_counter(); built = build(cfg, geo); t_build = time.perf_counter() - t
rss_build = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
(pattern,) = scan_patterns(cfg, lo, hi)
scan(built, pattern)  # warm: kernels compiled once
t = time.perf_counter(); res = scan(built, pattern); t_scan = time.perf_counter() - t
inst = geo.instances
n_leaves = sum(len(l) for _, l in inst.prototypes) if inst is not None else len(geo.leaves)
print(json.dumps({"trees": len(inst) if inst is not None else int(geo.branches.tree_id.max()) + 1,
                  "prototypes": len(inst.prototypes) if inst is not None else 0,
                  "max_trees_per_prototype": int(np.bincount(inst.proto_index).max()) if inst is not None else 1,
                  "leaf_triangles_built": int(n_leaves) if inst is None else int(built.n_triangles),
                  "triangles_built": int(built.n_triangles), "generate_s": t_gen, "build_s": t_build,
                  "scan_s": t_scan, "pulses": pattern.n_beams,
                  "veg_returns": int((res.cls >= 2).sum()),
                  "rss_after_generate_mb": rss_gen, "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(mode: str) -> dict:
    over = [f"forest.instancing={'false' if mode == 'flat' else 'true'}"]
    if mode == "instanced-k12":
        over.append("forest.prototypes_per_species=12")
    elif mode == "instanced-auto":
        over.append('forest.prototypes_per_species="auto"')
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", ROW, str(SCENE), *over], capture_output=True, text=True, cwd=REPO)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process_s"] = time.perf_counter() - t
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["instanced", "instanced-auto", "instanced-k12", "flat"])
    a = ap.parse_args()
    rows = ["| mode | trees | prototypes (most trees on one) | triangles built | generate s | build s | "
            "generate + build s | airborne scan s (pulses) | vegetation returns | peak RSS MB | process s |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for mode in ([a.only] if a.only else ["instanced", "instanced-auto", "flat"]):
        r = run(mode)
        protos = f"{r['prototypes']} ({r['max_trees_per_prototype']})" if r["prototypes"] else "–"
        rows.append(f"| {mode} | {r['trees']} | {protos} | {r['triangles_built']:,} | {r['generate_s']:.1f} | "
                    f"{r['build_s']:.1f} | {r['generate_s'] + r['build_s']:.1f} | {r['scan_s']:.2f} "
                    f"({r['pulses']:,}) | {r['veg_returns']:,} | {r['rss_peak_mb']:.0f} | {r['process_s']:.1f} |")
        print(rows[-1], file=sys.stderr)
    text = (f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d')}  \n"
            f"Command: `.venv/bin/python bench/bench_forest.py`\n\n" + "\n".join(rows) + "\n")
    (REPO / "bench" / "out").mkdir(parents=True, exist_ok=True)
    (REPO / "bench" / "out" / "forest_bench.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
