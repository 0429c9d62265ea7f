"""Mesh arrays of ``build_scene`` and the scan's measures, before/after (§8f, issue #8).

    PYTHONPATH=. .venv/bin/python bench/bench_mesh_measures.py [--before /work/main] [--repeat 7] [--fresh 5]
                                                 [--scene scenes/simlidar_table3_7x4.toml]

The scene's geometry is generated once; then, in this process, the ``BEFORE`` tree's
``scene/build.py``, ``lidar/scan.py`` and ``plants/measures.py`` (loaded under other names)
and this checkout's run interleaved, warm, ``--repeat`` times each; medians of wall and CPU
(``time.process_time``) milliseconds.  "Mesh arrays" is ``build_scene`` less
``mitsuba(variant)`` and Embree's ``load_dict`` of the scene (both timed and taken out).
The first call in a process is slower (fresh pages), so ``--fresh`` pairs of new processes,
before and after alternately, time one ``build_scene`` and one round of measures each.
Every pair of results is checked to be equal (values bit for bit).  Prints markdown.
Relative imports of the BEFORE modules resolve to this checkout (e.g. ``scene/prisms.py``,
which a BEFORE tree's ``build.py`` imports once it has one).
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

MODULES = {"build": "simlidar_mi.scene.{}build", "scan": "simlidar_mi.lidar.{}scan",
           "measures": "simlidar_mi.plants.{}measures"}


def modules(before: str | None) -> dict:
    """This checkout's modules, or BEFORE's loaded as ``_before_<name>`` siblings."""
    out = {}
    for key, name in MODULES.items():
        if before is None:
            out[key] = importlib.import_module(name.format(""))
            continue
        full = name.format("_before_")
        path = Path(before) / (name.format("").replace(".", "/") + ".py")
        spec = importlib.util.spec_from_file_location(full, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[full] = mod
        spec.loader.exec_module(mod)
        out[key] = mod
    return out


class _TimedMitsuba:
    """The Mitsuba module with its scene ``load_dict`` timed (wall, CPU)."""

    def __init__(self, mi):
        self._mi, self.wall, self.cpu = mi, 0.0, 0.0

    def __getattr__(self, name):
        return getattr(self._mi, name)

    def load_dict(self, d, *a, **k):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return self._mi.load_dict(d, *a, **k)
        finally:
            if isinstance(d, dict) and d.get("type") == "scene":
                self.wall += time.perf_counter() - t0
                self.cpu += time.process_time() - c0


def mesh_arrays(build_mod, cfg, geo, scanner_m):
    """(wall, CPU) seconds of one build_scene less mitsuba(variant) and the scene's load."""
    real = build_mod.mitsuba
    timed = {}

    def mitsuba(variant=None):
        t0, c0 = time.perf_counter(), time.process_time()
        timed["mi"] = _TimedMitsuba(real(variant))
        timed["setup"] = (time.perf_counter() - t0, time.process_time() - c0)
        return timed["mi"]
    build_mod.mitsuba = mitsuba
    try:
        sc = cfg["scene"]
        t0, c0 = time.perf_counter(), time.process_time()
        built = build_mod.build_scene(geo.branches, geo.leaves, geo.primitives, representation=sc["representation"],
                                      facets=sc["facets"], origin_m=sc["origin_m"], variant=sc["variant"],
                                      source=cfg.source, instances=geo.instances, scanner_m=scanner_m)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        build_mod.mitsuba = real
    mi = timed["mi"]
    return wall - mi.wall - timed["setup"][0], cpu - mi.cpu - timed["setup"][1], built


def measures(mods, result, branches):
    """(wall, CPU) of each measure scan_measures takes, and the values."""
    s = mods["scan"].ScanSettings(**dataclasses.asdict(result.settings))
    r = mods["scan"].ScanResult(s, result.range_m, result.cls, result.element_id, result.hit_fraction,
                                result.origin_m)
    calls = {"swept_share": lambda: s.swept_share(branches), "impacted_area_m2": r.impacted_area_m2,
             "impacted_area_yz_m2": r.impacted_area_yz_m2, "class_counts": r.class_counts,
             "wood_measures": lambda: mods["measures"].wood_measures(branches).to_dict()}
    out = {}
    for name, f in calls.items():
        t0, c0 = time.perf_counter(), time.process_time()
        value = f()
        out[name] = (time.perf_counter() - t0, time.process_time() - c0, value)
    return out


def setup(scene: str):
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar import survey
    cfg = load_scene(scene)
    geo = survey.generate(cfg)
    lo, hi = geo.bounds_m()
    patterns = survey.scan_patterns(cfg, lo, hi, geo.near_x_m)
    scanner = np.concatenate([survey.scanner_positions_m(p) for p in patterns])
    return cfg, geo, patterns, scanner


def trace(cfg, built, pattern):
    from simlidar_mi.lidar.scan import scan
    return scan(built, pattern, cfg["scene"]["variant"], chunk_beams=cfg["scan"]["chunk_beams"])


def one(args) -> None:
    """A fresh process: one build_scene and one round of measures (first calls)."""
    mods = modules(args.one_before)
    cfg, geo, patterns, scanner = setup(args.scene)
    mods["build"].mitsuba(cfg["scene"]["variant"])  # the import, as the CLI has done by then
    wall, cpu, built = mesh_arrays(mods["build"], cfg, geo, scanner)
    m = measures(mods, trace(cfg, built, patterns[0]), geo.branches)
    print(json.dumps({"mesh arrays": [wall, cpu], **{k: [w, c] for k, (w, c, _) in m.items()}}))


def ms(xs):
    return 1e3 * statistics.median(xs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default="/work/main")
    ap.add_argument("--scene", default="scenes/simlidar_table3_7x4.toml")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--fresh", type=int, default=5)
    ap.add_argument("--one-before", help=argparse.SUPPRESS)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        return one(args)
    print(f"machine: {machine()}; load average before: {os.getloadavg()}")
    old, new = modules(args.before), modules(None)
    cfg, geo, patterns, scanner = setup(args.scene)
    new["build"].mitsuba(cfg["scene"]["variant"])
    times: dict = {}
    result = None
    for _ in range(args.repeat):
        for tag, mods in (("before", old), ("after", new)):
            wall, cpu, built = mesh_arrays(mods["build"], cfg, geo, scanner)
            times.setdefault(("mesh arrays", tag), []).append((wall, cpu))
            if result is None:
                result = trace(cfg, built, patterns[0])
            del built
    values = {}
    for _ in range(args.repeat):
        for tag, mods in (("before", old), ("after", new)):
            for name, (wall, cpu, value) in measures(mods, result, geo.branches).items():
                times.setdefault((name, tag), []).append((wall, cpu))
                values.setdefault(name, {})[tag] = value
    for name, v in values.items():  # the same floats (compared as their JSON text)
        assert json.dumps(v["before"]) == json.dumps(v["after"]), (name, v)
    fresh: dict = {}
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for _ in range(args.fresh):
        for tag in ("before", "after"):
            cmd = [sys.executable, "-P", __file__, "--one", "--scene", args.scene]
            cmd += ["--one-before", args.before] if tag == "before" else []
            out = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, check=True)
            for name, wc in json.loads(out.stdout.strip().splitlines()[-1]).items():
                fresh.setdefault((name, tag), []).append(wc)
    names = ["mesh arrays"] + list(values)
    print(f"\n{args.scene}: {len(geo.branches)} branches, {built_triangles(new, cfg, geo, scanner)} triangles, "
          f"{result.range_m.size} beams; warm: median of {args.repeat} interleaved; first call: median of "
          f"{args.fresh} fresh processes each\n")
    print("| step | warm before ms (CPU) | warm after ms (CPU) | warm ratio | first call before ms (CPU) "
          "| first call after ms (CPU) | first-call ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in names + ["measures, all five"]:
        cells = []
        for src in (times, fresh):
            part = names[1:] if name == "measures, all five" else [name]
            for tag in ("before", "after"):  # per run: the parts' (wall, CPU) summed
                runs = list(zip(*(src[(n, tag)] for n in part)))
                wall = ms([sum(w for w, _ in run) for run in runs])
                cpu = ms([sum(c for _, c in run) for run in runs])
                cells.append(f"{wall:.1f} ({cpu:.1f})")
                ratio = wall if tag == "before" else ratio / wall
            cells.append(f"{ratio:.2f}x")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"\nload average after: {os.getloadavg()}")


def built_triangles(mods, cfg, geo, scanner) -> int:
    return int(mesh_arrays(mods["build"], cfg, geo, scanner)[2].n_triangles)


if __name__ == "__main__":
    main()
