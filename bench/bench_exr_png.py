"""scan.exr and scan.png writers: main's against this tree's, in one process (BENCHMARKS §8f).

    .venv/bin/python bench/bench_exr_png.py [--scene scenes/simlidar_table3_7x4.toml]
        [--main /work/main] [--repeat 9]

The scan of ``--scene`` is traced once in process (``run_scan`` without ``out_dir``); then
``write_scan_exr`` and ``plot_scan_png`` (the arguments ``survey.py`` passes) of main's
``simlidar_mi/io/exr.py`` and ``plots.py`` (loaded from ``--main`` under other module names)
and of this tree run alternately, old/new then new/old, ``--repeat`` times each: medians of
wall time and of CPU time (``time.process_time``: every thread of the process, which is what
counts when the second core is busy with the forked LAS writer). Before timing, both write
the scan and the files must be the same bytes.

The floors, on the same scan: ``zlib.compress`` at level 4 of the EXR's blocks (the
predictor's output, one thread: the level fixes the bytes), and Pillow encoding the same
picture at compress_level 3 (the saved PNG re-encoded: same pixels, same work).
"""
from __future__ import annotations

import argparse
import importlib.util
import io
import os
import statistics
import sys
import tempfile
import time
import zlib
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))


def load_main(main: Path, name: str):
    """``simlidar_mi/io/<name>.py`` of the main tree as ``simlidar_mi.io._main_<name>``
    (its relative imports resolve to this tree's unchanged modules)."""
    spec = importlib.util.spec_from_file_location(f"simlidar_mi.io._main_{name}",
                                                  main / "simlidar_mi" / "io" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def timed(fn) -> tuple[float, float]:
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def zlib_floor(result, exr_mod) -> float:
    """CPU seconds of zlib.compress(level 4) alone over the EXR blocks of ``result``."""
    header, dtypes = exr_mod.scan_exr_layout(result)
    rows = exr_mod.result_rows(result, 0, result.shape[0])
    names = sorted(dtypes, key=lambda k: k.encode())
    lines = np.concatenate([np.ascontiguousarray(rows[k], np.dtype(dtypes[k]).newbyteorder("<"))
                            .view(np.uint8).reshape(result.shape[0], -1) for k in names], axis=1)
    blocks = []
    for y in range(0, len(lines), 16):
        raw = lines[y:y + 16].ravel()
        split, pred = np.empty_like(raw), np.empty_like(raw)
        exr_mod._predict(raw, split, pred)
        blocks.append(pred.tobytes())
    c = time.process_time()
    for b in blocks:
        zlib.compress(b, 4)
    return time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default=str(REPO / "scenes" / "simlidar_table3_7x4.toml"))
    ap.add_argument("--main", type=Path, default=Path("/work/main"))
    ap.add_argument("--repeat", type=int, default=9)
    a = ap.parse_args()
    from _machine import machine

    from simlidar_mi.config import load_scene
    from simlidar_mi.io import exr as new_exr
    from simlidar_mi.io import plots as new_plots
    from simlidar_mi.lidar.survey import run_scan
    old_exr, old_plots = load_main(a.main, "exr"), load_main(a.main, "plots")
    run = run_scan(a.scene)
    res, cfg = run.result, load_scene(a.scene)
    kw = {"seed": cfg.seed, "scene_sha256": cfg.sha256,
          "extra": {"scene_file": cfg.source, "representation": "mesh", "facets": cfg["scene"]["facets"]}}
    title = f"{cfg['scene']['name']}: range image"
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        jobs = {
            ("exr", "main"): lambda: old_exr.write_scan_exr(res, d / "old.exr", **kw),
            ("exr", "new"): lambda: new_exr.write_scan_exr(res, d / "new.exr", **kw),
            ("exr1", "new"): lambda: new_exr.write_scan_exr(res, d / "new1.exr", threads=1, **kw),
            ("png", "main"): lambda: old_plots.plot_scan_png(res, d / "old.png", title=title),
            ("png", "new"): lambda: new_plots.plot_scan_png(res, d / "new.png", title=title),
        }
        for job in jobs.values():
            job()
        for old, new in (("old.exr", "new.exr"), ("old.exr", "new1.exr"), ("old.png", "new.png")):
            if (d / old).read_bytes() != (d / new).read_bytes():
                sys.exit(f"{old} and {new}: main and this tree wrote different bytes")
        times: dict = {k: [] for k in jobs}
        for i in range(a.repeat):
            for what in ("exr", "png"):
                for who in (("main", "new") if i % 2 == 0 else ("new", "main")):
                    times[(what, who)].append(timed(jobs[(what, who)]))
            times[("exr1", "new")].append(timed(jobs[("exr1", "new")]))
        from PIL import Image
        with Image.open(d / "new.png") as im:
            im.load()
            enc = [timed(lambda: im.save(io.BytesIO(), format="PNG", compress_level=3))[1] for _ in range(a.repeat)]
    z = statistics.median(zlib_floor(res, new_exr) for _ in range(max(3, a.repeat // 3)))

    def med(k, j):
        return 1e3 * statistics.median(t[j] for t in times[k])
    print(f"machine: {machine()}")
    print(f"date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, load average {os.getloadavg()[0]:.2f} "
          f"{os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}; scene {Path(a.scene).name}, "
          f"{res.shape[0]} × {res.shape[1]} beams, median of {a.repeat} interleaved repeats")
    print("| writer | main wall ms | main CPU ms | new wall ms | new CPU ms | CPU new/main |")
    print("|---|---:|---:|---:|---:|---:|")
    tot = {"main": [0.0, 0.0], "new": [0.0, 0.0]}
    for what in ("exr", "png"):
        for who in ("main", "new"):
            tot[who][0] += med((what, who), 0)
            tot[who][1] += med((what, who), 1)
        print(f"| scan.{what} | {med((what, 'main'), 0):.1f} | {med((what, 'main'), 1):.1f} | "
              f"{med((what, 'new'), 0):.1f} | {med((what, 'new'), 1):.1f} | "
              f"{med((what, 'new'), 1) / med((what, 'main'), 1):.2f} |")
    print(f"| both (sum of medians) | {tot['main'][0]:.1f} | {tot['main'][1]:.1f} | {tot['new'][0]:.1f} | "
          f"{tot['new'][1]:.1f} | {tot['new'][1] / tot['main'][1]:.2f} |")
    print(f"scan.exr with threads=1 (this tree): wall {med(('exr1', 'new'), 0):.1f} ms, "
          f"CPU {med(('exr1', 'new'), 1):.1f} ms")
    print(f"floors (CPU ms): zlib level 4 of the EXR blocks {1e3 * z:.1f}; "
          f"Pillow encoding the PNG {1e3 * statistics.median(enc):.1f}")


if __name__ == "__main__":
    main()
