"""VSP vineyard: generation, scene build and the two-side path scan, for the default scene
(scenes/vineyard_vsp.toml, a 12 m row) and a 50 m row.

    .venv/bin/python bench/bench_vineyard.py

Each mode runs ``run_scan`` (as ``simlidar-mi scan`` does: EXR, PNG and LAS written) in a
fresh process, so peak RSS is the process's own; prints a markdown table.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENE = REPO / "scenes" / "vineyard_vsp.toml"
MODES = {
    "default (12 m row, 12 vines)": [],
    "50 m row (50 vines)": ["vineyard.vines_per_row=50",
                            "platform.waypoints_m=[[-1.1, -1.0, 1.4], [-1.1, 51.0, 1.4], "
                            "[1.1, 51.0, 1.4], [1.1, -1.0, 1.4]]"],
}
ROW = r"""
import json, resource, sys
import laspy
from simlidar_mi.lidar.survey import run_scan
run = run_scan(sys.argv[1], sys.argv[2], sys.argv[3:])
m = run.measures
print(json.dumps({"seconds": m["seconds"], "branches": m["n_branches"], "leaf_triangles": m["n_leaf_triangles"],
                  "triangles_built": m["n_triangles_built"], "beams": sum(l["N"] * l["M"] for l in m["legs"]),
                  "points": int(laspy.read(sys.argv[2] + "/points.las").header.point_count),
                  "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(over: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", ROW, str(SCENE), str(Path(tmp) / "out"), *over],
                              capture_output=True, text=True, cwd=REPO)
        wall = time.perf_counter() - t
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process_s"] = wall
    return out


def main() -> None:
    print(f"Machine: {machine()}. Date: {time.strftime('%Y-%m-%d')}.\n")
    print("| scene | branches | leaf triangles | triangles built | beams (2 legs) | LAS points | generate s "
          "| build s | scan s | write s | process s | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, over in MODES.items():
        r = run(over)
        s = r["seconds"]
        print(f"| {name} | {r['branches']:,} | {r['leaf_triangles']:,} | {r['triangles_built']:,} | {r['beams']:,} "
              f"| {r['points']:,} | {s['generate']:.2f} | {s['build']:.2f} | {s['scan']:.2f} | {s['write']:.2f} "
              f"| {r['process_s']:.1f} | {r['rss_peak_mb']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
