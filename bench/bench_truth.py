"""Canopy ground truth (``simlidar-mi truth``): time and peak memory against voxel size.

    .venv/bin/python bench/bench_truth.py [--only NAME ...] [--voxels 0.05 0.1 0.25]
                                          [--set KEY=VALUE ...] [--repeat N]

Each (scene, voxel) runs in a fresh process (peak RSS is the process's own): generate
the geometry, then :func:`compute_truth` on the default grid. Scenes written by other
features (leafy orchard, vineyard) are included when their files exist; ``--set``
adds scene-key overrides to every case. With ``--repeat N`` each case runs N times
(fresh processes): the table gives the median truth time and the largest peak RSS.
Prints a markdown table.
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
import json, resource, sys, time
from simlidar_mi.truth.run import truth_geometry
from simlidar_mi.config import load_scene
from simlidar_mi.truth.compute import compute_truth, default_grid
cfg = load_scene(sys.argv[1], sys.argv[3:])
t = time.perf_counter(); geo, plot = truth_geometry(cfg); t_gen = time.perf_counter() - t
grid = default_grid(geo, float(sys.argv[2]))
t = time.perf_counter(); ds = compute_truth(geo, grid, progress=False, ground_area_m2=plot); t_truth = time.perf_counter() - t
a = ds.attrs
n_inst = len(geo.instances) if geo.instances is not None else 0
print(json.dumps({"branches": a["n_branches"], "leaf_triangles": a["n_leaf_triangles"], "trees_expanded": n_inst,
                  "voxels": int(grid.shape[0] * grid.shape[1] * grid.shape[2]), "generate_s": t_gen,
                  "truth_s": t_truth, "leaf_m2": a["total_leaf_area_m2"], "wood_m2": a["total_wood_area_m2"],
                  "wood_m3": a["total_wood_volume_m3"],
                  "rel_err_leaf": abs(a["total_leaf_area_m2"] - a["exact_leaf_area_m2"]) / max(a["exact_leaf_area_m2"], 1e-300),
                  "rel_err_wood": abs(a["total_wood_area_m2"] - a["exact_wood_area_m2"]) / max(a["exact_wood_area_m2"], 1e-300),
                  "rel_err_vol": abs(a["total_wood_volume_m3"] - a["exact_wood_volume_m3"]) / max(a["exact_wood_volume_m3"], 1e-300),
                  "outside": a["leaf_area_outside_m2"] + a["wood_area_outside_m2"] + a["wood_volume_outside_m3"],
                  "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

CASES = {
    "apple_orchard": ("scenes/apple_orchard.toml", []),
    "apple_orchard_8it": ("scenes/apple_orchard.toml", ["orchard.tree.iterations=8"]),
    "random_leaves": ("scenes/random_leaves_spherical.toml", []),
    "forest_small": ("scenes/forest_small.toml", []),
    # written by the leafy-orchard and vineyard features; run when present
    "orchard_leafy": ("scenes/orchard_leafy.toml", []),
    "vineyard_vsp": ("scenes/vineyard_vsp.toml", []),
    # a 50 m row: 50 vines 1 m apart (the scene's vine_spacing_m)
    "vineyard_vsp_50m": ("scenes/vineyard_vsp.toml", ["vineyard.vines_per_row=50", "vineyard.vine_spacing_m=1.0"]),
}


def run(name: str, voxel: float, timeout_s: float, extra=()) -> dict:
    scene, over = CASES[name]
    try:
        proc = subprocess.run([sys.executable, "-c", ROW, scene, str(voxel), *over, *extra], capture_output=True,
                              text=True, cwd=REPO, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"error": f"> {timeout_s:.0f} s (stopped)"}
    if proc.returncode:
        return {"error": proc.stderr.strip().splitlines()[-1][:120]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, choices=list(CASES))
    ap.add_argument("--voxels", nargs="*", type=float, default=[0.25, 0.1, 0.05])
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per case")
    ap.add_argument("--set", dest="overrides", nargs="*", default=[], metavar="KEY=VALUE",
                    help="scene-key overrides added to every case")
    ap.add_argument("--repeat", type=int, default=1, help="runs per case (median time, largest RSS)")
    args = ap.parse_args()
    print(machine())
    print("| scene | voxel m | branches | leaf triangles | voxels | generate s | truth s | peak RSS MB "
          "| rel. error leaf / wood / volume | outside |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.only or CASES:
        if not (REPO / CASES[name][0]).exists():
            print(f"| {name} | – | scene file {CASES[name][0]} not present | | | | | | | |")
            continue
        for vox in args.voxels:
            runs = [run(name, vox, args.timeout, args.overrides) for _ in range(max(1, args.repeat))]
            r = next((x for x in runs if "error" in x), None) or dict(
                runs[0], truth_s=statistics.median(x["truth_s"] for x in runs),
                rss_peak_mb=max(x["rss_peak_mb"] for x in runs))
            if "error" in r:
                print(f"| {name} | {vox} | {r['error']} | | | | | | | |", flush=True)
                continue
            print(f"| {name} | {vox} | {r['branches']:,} | {r['leaf_triangles']:,} | {r['voxels']:,} "
                  f"| {r['generate_s']:.2f} | {r['truth_s']:.2f} | {r['rss_peak_mb']:.0f} "
                  f"| {r['rel_err_leaf']:.1e} / {r['rel_err_wood']:.1e} / {r['rel_err_vol']:.1e} "
                  f"| {r['outside']:.1g} |", flush=True)


if __name__ == "__main__":
    main()
