"""Embree build paths for big meshes: top-level mesh vs one shape group with an identity instance.

    .venv/bin/python bench/bench_build.py [--scene scenes/simlidar_table3_7x4.toml] [--set k=v ...]

For each path, in a fresh process: the scene build (numpy meshes + Mitsuba/Embree), the
tractor scan (coherent rays, the scene's own beams) and 4 M incoherent rays (random origins
around the scene, random directions: an airborne/perspective-like load), each timed after
a warm-up.  Prints a markdown table; hits are compared between the paths.
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

ROW = r"""
import json, resource, sys, time, hashlib
import numpy as np
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import generate, build, scan_patterns
from simlidar_mi.lidar.scan import scan
from simlidar_mi.scene import build as build_mod
from simlidar_mi._runtime.mitsuba import mitsuba
build_mod.GROUP_MIN_TRIANGLES = int(sys.argv[1])
cfg = load_scene(sys.argv[2], sys.argv[3:])
geo = generate(cfg)
lo, hi = geo.bounds_m()
(pattern,) = scan_patterns(cfg, lo, hi, geo.near_x_m)
t = time.perf_counter(); built = build(cfg, geo, [pattern]); t_build = time.perf_counter() - t
scan(built, pattern)
t = time.perf_counter(); res = scan(built, pattern); t_scan = time.perf_counter() - t
mi = mitsuba(); import drjit as dr
rng = np.random.default_rng(7); n = 4_000_000
blo, bhi = built.bbox_min_m - built.origin_m, built.bbox_max_m - built.origin_m
o = rng.uniform(blo - 1, bhi + 1, (n, 3)); d = rng.normal(size=(n, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, i].astype(np.float32)) for i in range(3)]),
               mi.Vector3f(*[mi.Float(d[:, i].astype(np.float32)) for i in range(3)]))
built.scene.ray_intersect_preliminary(ray, coherent=False).t.numpy()
t = time.perf_counter(); tt = built.scene.ray_intersect_preliminary(ray, coherent=False).t.numpy(); t_inc = time.perf_counter() - t
digest = hashlib.sha256(res.range_m.tobytes() + res.element_id.tobytes()).hexdigest()[:12]
print(json.dumps({"triangles": int(built.n_triangles), "build_s": t_build, "scan_s": t_scan,
                  "beams": int(res.range_m.size), "incoherent_s": t_inc, "incoherent_hits": int(np.isfinite(tt).sum()),
                  "scan_digest": digest, "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(threshold: int, scene: str, sets: list[str]) -> dict:
    proc = subprocess.run([sys.executable, "-c", ROW, str(threshold), scene, *sets],
                          capture_output=True, text=True, cwd=REPO)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/simlidar_table3_7x4.toml")
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args()
    print(machine())
    print(f"scene {args.scene} {' '.join(args.set)}\n")
    print("| path | triangles | build (s) | tractor scan (s) | beams | 4 M incoherent rays (s) | incoherent hits | scan digest | peak RSS (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---:|")
    for name, threshold in (("top-level mesh", 10**12), ("shape group + identity instance", 1)):
        r = run(threshold, args.scene, args.set)
        print(f"| {name} | {r['triangles']:,} | {r['build_s']:.2f} | {r['scan_s']:.3f} | {r['beams']:,} | "
              f"{r['incoherent_s']:.3f} | {r['incoherent_hits']:,} | {r['scan_digest']} | {r['rss_peak_mb']:.0f} |")


if __name__ == "__main__":
    main()
