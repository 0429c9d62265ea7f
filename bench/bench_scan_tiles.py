"""A big airborne forest scan in one process vs in row tiles on a 2-worker Dask LocalCluster.

    .venv/bin/python bench/bench_scan_tiles.py [--set KEY=VALUE ...] [--tile-rows N]

Scene: scenes/forest_airborne.toml (10 M pulses).  Each mode runs in a fresh process:
``one-process`` is ``run_scan`` as ``simlidar-mi scan`` runs it; ``cluster`` starts a
``LocalCluster`` of 2 worker processes (1 thread each), then times ``run_scan(...,
scheduler=address)`` alone (the cluster's start-up is reported apart).  Both write every
file (EXR, PNG, LAS, measures.json); the script checks that the files are the same bytes
and prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

SCENE = REPO / "scenes" / "forest_airborne.toml"
ROW = r"""
import json, resource, sys, time
t_proc = time.perf_counter()
mode, scene, out, tile_rows, *over = sys.argv[1:]
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import run_scan
kw, extra = {}, {}
if mode == "cluster":
    from distributed import Client, LocalCluster
    t = time.perf_counter()
    lc = LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None)
    client = Client(lc, set_as_default=False)
    extra["cluster_start_s"] = time.perf_counter() - t
    kw = {"scheduler": lc.scheduler_address, "tile_rows": int(tile_rows) if tile_rows != "-" else None}
t = time.perf_counter()
run = run_scan(load_scene(scene, over), out, **kw)
wall = time.perf_counter() - t
if mode == "cluster":
    rss = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    extra["worker_peak_rss_mb"] = sorted(round(v) for v in rss.values())
    client.close(); lc.close()
m = run.measures
print(json.dumps({"mode": mode, "wall_s": wall, "stages_s": m["seconds"], "beams": int(run.result.range_m.size),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "process_s": time.perf_counter() - t_proc, **extra}))
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--tile-rows", default="-")
    ap.add_argument("--out", default="/tmp/bench_scan_tiles")
    args = ap.parse_args()
    rows = []
    for mode in ("one-process", "cluster"):
        out = f"{args.out}/{mode}"
        cmd = [sys.executable, "-c", ROW, mode, str(SCENE), out, args.tile_rows, *args.overrides]
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
        if res.returncode:
            sys.exit(f"{mode} failed:\n{res.stderr[-3000:]}")
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(json.dumps(rows[-1]), file=sys.stderr)
    same = {f: Path(f"{args.out}/cluster/{f}").read_bytes() == Path(f"{args.out}/one-process/{f}").read_bytes()
            for f in ("scan.exr", "scan.png", "points.las")}
    print(machine())
    print(f"files identical: {same}")
    print("| mode | pulses | generate s | build s | scan s | write s | run_scan s | process s | peak RSS MB (client) | workers' peak RSS MB | cluster start s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        s = r["stages_s"]
        print(f"| {r['mode']} | {r['beams']:,} | {s['generate']:.1f} | {s['build']:.1f} | {s['scan']:.1f} | "
              f"{s['write']:.1f} | {r['wall_s']:.1f} | {r['process_s']:.1f} | {r['peak_rss_mb']:.0f} | "
              f"{', '.join(map(str, r.get('worker_peak_rss_mb', []))) or '–'} | "
              f"{r.get('cluster_start_s', 0):.1f} |")


if __name__ == "__main__":
    main()
