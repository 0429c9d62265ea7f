"""Table 3's 7×4 row end to end, before/after, and where its time goes (issue #8).

    .venv/bin/python bench/bench_scan_write.py --before DIR [--repeat 5]
    .venv/bin/python bench/bench_scan_write.py --breakdown 5 [--no-limits]

1. End to end: ``python -P -m simlidar_mi.cli scan SCENE --out TMP`` in fresh processes under
   ``/usr/bin/time``, the tree ``DIR`` ("before") and this checkout ("after") interleaved run
   for run (``-P``: the code comes from ``PYTHONPATH`` only).  Medians of wall, CPU and peak
   RSS, the stage seconds of ``measures.json``, and whether the last pair wrote the same bytes
   (scan.exr, scan.png, points.las; measures.json but for ``seconds``).
2. Breakdown (``--breakdown N``): N fresh processes of this checkout running the same command
   through ``simlidar_mi.cli.main`` with timers wrapped around each component (interpreter
   start, imports, Mitsuba import and variant, scene file, generation, mesh arrays, the
   Mitsuba meshes, Embree's scene load, the scan, the measures, each writer, the folder
   commit, process exit); medians; then the limits of ``bench_scale.py`` in the same run.
   The breakdown imports Mitsuba up front, in turn: it times each component on its own, not
   the command's overlap of generation with that import (simlidar_mi.lidar.survey.run_scan).
Prints markdown; the load average is printed before and after.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

BREAKDOWN = r"""
import sys, time
T = {"spawn": float(sys.argv[1]), "python_up": time.time()}
S = {}
def span(name, t0, t1):
    S.setdefault(name, []).append((t0, t1))
def wrap(mod, attr, name):
    f = getattr(mod, attr)
    def g(*a, **k):
        t0 = time.time()
        try:
            return f(*a, **k)
        finally:
            span(name, t0, time.time())
    setattr(mod, attr, g)
t0 = time.time()
import simlidar_mi.cli as cli
from simlidar_mi._runtime import mitsuba as _mitsuba
from simlidar_mi.lidar import survey, scan as scan_mod
from simlidar_mi.scene import build as build_mod
from simlidar_mi.io import atomic
span("imports: numpy and ours", t0, time.time())
t0 = time.time()
mi = _mitsuba.mitsuba()
span("Mitsuba import, set_variant (AD reload), plugins", t0, time.time())
t0 = time.time()
from simlidar_mi.io import exr, las, plots
span("imports: OpenEXR, PIL (laspy is imported by the LAS writer, in its forked child)", t0, time.time())
orig_load = mi.load_dict
def load_dict(d, *a, **k):
    t0 = time.time()
    try:
        return orig_load(d, *a, **k)
    finally:
        if isinstance(d, dict) and d.get("type") == "scene":
            span("build: Embree, load_dict(scene)", t0, time.time())
mi.load_dict = load_dict
MESH = "build: mesh arrays (exposed_ends, prism_arrays)"
for mod, name, label in [
        (survey, "load_scene", "scene file"), (survey, "generate", "generate (L-systems)"),
        (build_mod, "exposed_ends", MESH), (build_mod, "prism_arrays", MESH),
        (build_mod, "_mi_mesh", "build: Mitsuba meshes (_mi_mesh)"), (survey, "build", "build stage"),
        (scan_mod, "scan", "scan (trace)"),
        (survey, "scan_measures", "measures (A_IM, A_IM_yz, swept share, wood)"),
        (exr, "write_scan_exr", "write: EXR"), (las, "write_scan_las", "write: LAS"),
        (plots, "plot_scan_png", "write: PNG (range image)"), (atomic, "_commit", "folder commit (renames)")]:
    wrap(mod, name, label)
t0 = time.time()
rc = cli.main(["scan", sys.argv[2], "--out", sys.argv[3]])
T["main"] = (t0, time.time())
import json
print(json.dumps({"T": T, "S": S}), flush=True)
cli._exit_now(rc)  # as the command line ends (simlidar_mi/cli.py)
"""


def md5(path: Path) -> str:
    if path.name == "measures.json":
        data = json.loads(path.read_text())
        data.pop("seconds", None)
        return hashlib.md5(json.dumps(data, sort_keys=True).encode()).hexdigest()
    return hashlib.md5(path.read_bytes()).hexdigest()


def one_run(tree: Path, scene: str, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    proc = subprocess.run(["/usr/bin/time", "-f", "TIME %e %U %S %M", sys.executable, "-P", "-m",
                           "simlidar_mi.cli", "scan", scene, "--out", str(out)],
                          capture_output=True, text=True, cwd=REPO, env=env)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    wall, user, system, rss = proc.stderr.strip().splitlines()[-1].split()[1:]
    seconds = json.loads((out / "measures.json").read_text())["seconds"]
    return {"wall": float(wall), "cpu": float(user) + float(system), "rss_mb": int(rss) / 1024,
            **seconds, "digest": {p.name: md5(p) for p in sorted(out.iterdir())}}


def breakdown_run(scene: str, out: Path) -> dict[str, float]:
    """One fresh process of BREAKDOWN: seconds per component (see the module docstring)."""
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    import time  # noqa: PLC0415
    spawn = time.time()
    proc = subprocess.run([sys.executable, "-P", "-c", BREAKDOWN, repr(spawn), scene, str(out)],
                          capture_output=True, text=True, cwd=REPO, env=env)
    end = time.time()
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    d = json.loads(proc.stdout.strip().splitlines()[-1])
    T, S = d["T"], d["S"]
    row = {"interpreter start (python -P, site)": T["python_up"] - spawn}
    for name, spans in S.items():
        row[name] = sum(b - a for a, b in spans)
    build = row.pop("build stage")
    row["build: the rest (origin, checks, shape group, ids)"] = build - sum(
        v for k, v in row.items() if k.startswith("build: "))
    main_s = T["main"][1] - T["main"][0]
    inside = ("scene file", "generate (L-systems)", "scan (trace)", "measures (A_IM, A_IM_yz, swept share, wood)",
              "write: EXR", "write: LAS", "write: PNG (range image)", "folder commit (renames)")
    row["rest of main (argparse, patterns, staging, measures.json)"] = main_s - build - sum(
        row.get(k, 0.0) for k in inside)
    row["process exit (after the last file; cli._exit_now)"] = end - T["main"][1]
    row["total (spawn to exit)"] = end - spawn
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", help="a checkout of the code to compare with (required but for --breakdown)")
    ap.add_argument("--scene", default="scenes/simlidar_table3_7x4.toml")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--breakdown", type=int, default=0, help="fresh processes for the breakdown only")
    ap.add_argument("--no-limits", action="store_true", help="breakdown without the limits")
    args = ap.parse_args()
    if args.breakdown:
        print(machine())
        print(f"load average at start: {os.getloadavg()}\n")
        tmp = Path(tempfile.mkdtemp(prefix="bench_scan_write_"))
        rows = [breakdown_run(args.scene, tmp / "out") for _ in range(args.breakdown)]
        print("| component | median (s) | min (s) | runs (s) |\n|---|---:|---:|---|")
        for k in rows[0]:
            xs = [r.get(k, 0.0) for r in rows]
            print(f"| {k} | {statistics.median(xs):.3f} | {min(xs):.3f} | {', '.join(f'{x:.2f}' for x in xs)} |")
        # The limits of bench_scale.py (BENCHMARKS §8a), in the same run: the process floor
        # (numpy + Mitsuba + variant + a one-triangle scene), the raw ray cast of the scan's
        # own beams, the disk for the same bytes in as many files; Embree is the row above.
        if args.no_limits:
            shutil.rmtree(tmp, ignore_errors=True)
            return
        import bench_scale as bs  # noqa: PLC0415
        breakdown_run(args.scene, tmp / "out")
        n_bytes, n_files = bs.dir_bytes(tmp / "out"), bs.dir_files(tmp / "out")
        floor = statistics.median(bs.in_process(bs.FLOOR)["s"] for _ in range(args.breakdown))
        rays = bs.in_process(bs.RAYS, args.scene, str(args.breakdown))
        disk = statistics.median(bs.disk_write_s(n_bytes, n_files, tmp) for _ in range(args.breakdown))
        print(f"\nlimits: floor {floor:.3f} s; raw rays {rays['raw_s']:.3f} s ({rays['beams']:,} beams; "
              f"the scan itself {rays['scan_s']:.3f} s warm); disk {disk:.3f} s for {n_bytes / 1e6:.1f} MB "
              f"in {n_files} files")
        print(f"\nload average at end: {os.getloadavg()}")
        shutil.rmtree(tmp, ignore_errors=True)
        return
    if not args.before:
        ap.error("--before DIR is needed")
    print(machine())
    print(f"load average at start: {os.getloadavg()}\n")
    tmp = Path(tempfile.mkdtemp(prefix="bench_scan_write_"))
    runs: dict[str, list] = {"before": [], "after": []}
    for _ in range(args.repeat):
        for name, tree in (("before", Path(args.before)), ("after", REPO)):
            runs[name].append(one_run(tree, args.scene, tmp / name))
            r = runs[name][-1]
            print(f"  {name}: wall {r['wall']:.2f} s, CPU {r['cpu']:.2f} s, "
                  + ", ".join(f"{k} {r[k]:.2f}" for k in ("generate", "build", "scan", "write")),
                  flush=True)
    same = runs["before"][-1]["digest"] == runs["after"][-1]["digest"]
    print("\n| tree | wall (s) | CPU (s) | peak RSS (MB) | generate | build | scan | write | outside the stages |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, rs in runs.items():
        med = {k: statistics.median(r[k] for r in rs) for k in ("wall", "cpu", "rss_mb", "generate", "build",
                                                                   "scan", "write")}
        outside = statistics.median(r["wall"] - r["generate"] - r["build"] - r["scan"] - r["write"] for r in rs)
        print(f"| {name} | {med['wall']:.2f} | {med['cpu']:.2f} | {med['rss_mb']:.0f} | {med['generate']:.2f} | "
              f"{med['build']:.2f} | {med['scan']:.2f} | {med['write']:.2f} | {outside:.2f} |")
    ratios = [b["wall"] / a["wall"] for b, a in zip(runs["before"], runs["after"])]
    print(f"\nbefore/after wall, median of pairs: {statistics.median(ratios):.2f}×; same bytes: {same}")
    print("runs (wall/CPU s): " + "; ".join(
        f"{name} " + ", ".join(f"{r['wall']:.2f}/{r['cpu']:.2f}" for r in rs) for name, rs in runs.items()))

    print(f"\nload average at end: {os.getloadavg()}")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
