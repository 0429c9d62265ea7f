"""Leafy vs dormant orchards: generation, scene build and tractor scan of scenes/orchard_leafy.toml.

    .venv/bin/python bench/bench_leafy.py [--repeats 3] [--set k=v ...]

Each row runs in a fresh process: generate (L-system wood + leaves), build (Mitsuba mesh),
then the scene's tractor scan timed after one warm-up scan; the median of ``--repeats``
fresh processes is printed. Rows: dormant (wood only), leaf-on with 4, 8 (default) and 12
triangles a leaf, at the scene's grid (Δy = 1 cm, Δθ = 0.5°) and at the paper's (2 mm, 0.25°).
Prints a markdown table. ``--sensitivity``: instead, how the leaf-angle law and the
outer-crown weight β move what the scene's scan sees (leaf and wood hits, A_IM), one process.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

ROW = r"""
import json, sys, time
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import generate, build, scan_patterns
from simlidar_mi.lidar.scan import scan
cfg = load_scene(sys.argv[1], sys.argv[2:])
t = time.perf_counter(); geo = generate(cfg); t_gen = time.perf_counter() - t
lo, hi = geo.bounds_m()
(pattern,) = scan_patterns(cfg, lo, hi, geo.near_x_m)
t = time.perf_counter(); built = build(cfg, geo, [pattern]); t_build = time.perf_counter() - t
scan(built, pattern)
t = time.perf_counter(); res = scan(built, pattern); t_scan = time.perf_counter() - t
print(json.dumps({"generate": t_gen, "build": t_build, "scan": t_scan, "beams": int(res.range_m.size),
                  "leaves": int(len(set(geo.leaves.leaf_id.tolist()))), "leaf_triangles": len(geo.leaves),
                  "triangles": int(built.n_triangles), "hits": res.class_counts()}))
"""

ROWS = [("dormant", ["orchard.leaves.season=dormant"]),
        ("leaf-on, 4 triangles a leaf", ["orchard.leaves.sides=4"]),
        ("leaf-on, 8 (default)", []),
        ("leaf-on, 12", ["orchard.leaves.sides=12"])]
GRIDS = [("scene grid 1 cm × 0.5°", []), ("paper grid 2 mm × 0.25°", ["scan.dy_m=0.002", "scan.dtheta_deg=0.25"])]


SENSITIVITY = r"""
import sys
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import run_scan
print("| angle law | β (outer_weight) | leaves | leaf hits | wood hits | wood hits / dormant | A_IM (m²) |")
print("|---|---:|---:|---:|---:|---:|---:|")
dormant = run_scan(load_scene(sys.argv[1], ["orchard.leaves.season=dormant"])).measures["hits"]["wood"]
for law in ("planophile", "spherical", "erectophile"):
    for beta in (0.0, 1.0, 3.0):
        m = run_scan(load_scene(sys.argv[1], [f"orchard.leaves.angle_distribution='{law}'",
                                              f"orchard.leaves.outer_weight={beta}"])).measures
        print(f"| {law} | {beta:g} | {m['n_leaves']:,} | {m['hits']['leaf']:,} | {m['hits']['wood']:,} | "
              f"{m['hits']['wood'] / dormant:.3f} | {m['A_IM_m2']:.4f} |", flush=True)
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(REPO / "scenes" / "orchard_leafy.toml"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--sensitivity", action="store_true")
    args = ap.parse_args()
    print(f"**Machine:** {machine()}\n")
    if args.sensitivity:
        subprocess.run([sys.executable, "-c", SENSITIVITY, args.scene], check=True, cwd=REPO)
        return
    print("| grid | trees | leaves | leaf triangles | triangles built | generate (s) | build (s) | scan (s) "
          "| beams | leaf hits | wood hits |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for grid, gset in GRIDS:
        for name, rset in ROWS:
            runs = []
            for _ in range(args.repeats):
                out = subprocess.run([sys.executable, "-c", ROW, args.scene, *gset, *rset, *args.set],
                                     check=True, capture_output=True, text=True, cwd=REPO)
                runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
            med = {k: statistics.median(r[k] for r in runs) for k in ("generate", "build", "scan")}
            r = runs[0]
            print(f"| {grid} | {name} | {r['leaves']:,} | {r['leaf_triangles']:,} | {r['triangles']:,} | "
                  f"{med['generate']:.3f} | {med['build']:.3f} | {med['scan']:.3f} | {r['beams']:,} | "
                  f"{r['hits']['leaf']:,} | {r['hits']['wood']:,} |", flush=True)


if __name__ == "__main__":
    main()
