"""points.las of a held scan: this checkout's ``write_scan_las`` against another tree's (§8f).

    PYTHONPATH=. .venv/bin/python bench/bench_las_write.py [--before /work/main] [--repeat 9]
        [--scene scenes/simlidar_table3_7x4.toml]

The scene is scanned once in process (``run_scan`` without an output folder).  Then, in the
same process, warm, interleaved call for call: the ``--before`` tree's ``simlidar_mi/io/las.py``
(loaded as another module of this package, so everything it imports is this checkout's) and
this checkout's, each into a fresh file name beside the other (no file replaced); medians of
wall and CPU seconds (``time.process_time``), their ratio, and whether the files are the same
bytes.  Also: both in a forked child as ``run_scan`` runs them (``simlidar_mi._runtime.fork.Forked``,
wall from the fork to the child's answer), the two passes of the new writer alone (points;
records packed without the file), a forked child that does nothing, and the import cost of
laspy and pyproj in fresh processes.
Prints markdown; the load average before and after.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

IMPORTS = ("import time, sys; t0 = time.perf_counter(); import numpy; t1 = time.perf_counter(); "
           "import laspy; t2 = time.perf_counter(); import pyproj; t3 = time.perf_counter(); "
           "import simlidar_mi.io.las; t4 = time.perf_counter(); "
           "print(t2 - t1, t3 - t2, t4 - t3)")


def _load_before(tree: Path):
    """The ``las.py`` of ``tree`` as ``simlidar_mi.io._las_before`` (its relative imports: ours)."""
    spec = importlib.util.spec_from_file_location("simlidar_mi.io._las_before",
                                                  tree / "simlidar_mi" / "io" / "las.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _timed(fn, *args):
    w, c = time.perf_counter(), time.process_time()
    fn(*args)
    return time.perf_counter() - w, time.process_time() - c


def _forked(fn, res, path):
    from simlidar_mi._runtime.fork import Forked
    w = time.perf_counter()
    job = Forked("writing points.las", fn, res, path, parallel=True)
    try:
        job.wait()
    finally:
        job.close()
    return time.perf_counter() - w, 0.0


def _passes(las, res):
    """The new writer's two passes without the file: points, then records packed (not written)."""
    lp = las._LegPoints(res, 0, 0, False)
    xyz = np.empty((3, lp.n))
    w = time.perf_counter()
    lp.points(xyz)
    t_points = time.perf_counter() - w
    header = las.las_header([0.0, 0.0, 0.0], "t", with_tree=res.tree_id is not None)
    rec = las.RecordWriter(os.devnull, header, None, None)
    rec.writer.point_writer.write_points = lambda r: None  # pack only
    w = time.perf_counter()
    at = 0
    for cols in lp.columns():
        n = len(cols["cls"])
        rec.write(xyz[:, at:at + n], cols, leg=0, with_tree=res.tree_id is not None, with_echoes=False)
        at += n
    return t_points, time.perf_counter() - w


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--before", type=Path, default=Path("/work/main"))
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--scene", default=str(REPO / "scenes" / "simlidar_table3_7x4.toml"))
    args = ap.parse_args()
    print(f"machine: {machine()}\nload average before: {os.getloadavg()}\n")
    from simlidar_mi.io import las
    from simlidar_mi.lidar.survey import run_scan
    before = _load_before(args.before)
    res = run_scan(args.scene).result
    crs = None
    kept = int((res.cls != 0).sum())
    print(f"scene {Path(args.scene).name}: {res.shape[0]} × {res.shape[1]} beams, {kept} points\n")
    out = {}
    with tempfile.TemporaryDirectory(dir=REPO) as tmp:  # the disk the outputs go to
        for label, run in (("in process", _timed), ("forked child", _forked)):
            for rep in range(args.repeat + 1):
                for name, mod in (("before", before), ("after", las)):
                    path = Path(tmp) / f"{name}{rep}.las"
                    t = (run(mod.write_scan_las, res, path) if run is _forked
                         else run(lambda r, p, m=mod: m.write_scan_las(r, p, crs=crs), res, path))
                    if rep:  # the first pair warms up
                        out.setdefault((label, name), []).append(t)
                same = (Path(tmp) / f"before{rep}.las").read_bytes() == (Path(tmp) / f"after{rep}.las").read_bytes()
                for name in ("before", "after"):
                    os.remove(Path(tmp) / f"{name}{rep}.las")
        passes = [_passes(las, res) for _ in range(args.repeat)]
        noop = [_forked(lambda r, p: None, res, None)[0] for _ in range(args.repeat)]
    imports = [subprocess.run([sys.executable, "-c", IMPORTS], capture_output=True, text=True, check=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)}).stdout.split()
               for _ in range(5)]
    med = {k: (statistics.median(t[0] for t in v), statistics.median(t[1] for t in v)) for k, v in out.items()}
    print("| write_scan_las | before wall ms (CPU) | after wall ms (CPU) | ratio (wall) |\n|---|---|---|---|")
    for label in ("in process", "forked child"):
        b, a = med[(label, "before")], med[(label, "after")]
        cpu = lambda x: f" ({1e3 * x[1]:.0f})" if label == "in process" else ""  # noqa: E731
        print(f"| {label}, median of {args.repeat} | {1e3 * b[0]:.0f}{cpu(b)} | {1e3 * a[0]:.0f}{cpu(a)} "
              f"| {b[0] / a[0]:.2f}× |")
    print(f"\nsame bytes (last pair): {same}")
    print(f"after, its passes (median): points {1e3 * statistics.median(p[0] for p in passes):.0f} ms, "
          f"records packed {1e3 * statistics.median(p[1] for p in passes):.0f} ms (the rest: the file)")
    print(f"a forked child that does nothing (fork, answer, join): {1e3 * statistics.median(noop):.0f} ms")
    names = ("laspy (it imports pyproj)", "pyproj (after laspy)", "simlidar_mi.io.las and the package (after laspy)")
    print("imports in a fresh process (median of 5): " +
          ", ".join(f"{n} {1e3 * statistics.median(float(r[i]) for r in imports):.0f} ms"
                    for i, n in enumerate(names)))
    print(f"\nload average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
