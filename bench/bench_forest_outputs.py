"""`simlidar-mi forest scenes/forest_4species.toml` end to end, before and after the output work
of issue #8 (§8c): Parquet leaf table, pictures in a forked process, lighter preview and export.

    .venv/bin/python bench/bench_forest_outputs.py --before DIR [--repeat 3] [--scene S]

``DIR`` is a checkout of the commit to compare with; it runs with pyarrow hidden (its leaf table
is the CSV, as installs without pyarrow wrote it). Three variants, each a fresh process under
``/usr/bin/time`` (wall from process start to the last file, CPU, peak RSS), interleaved run for
run so they share the machine's load:

- ``before``: ``python -P -m simlidar_mi.cli forest`` from DIR;
- ``after, in turn``: this tree, ``run_forest(..., parallel=False)`` (pictures drawn in turn);
- ``after``: this tree's CLI (pictures in a forked process).

Prints a markdown table of medians with the stages of ``forest.json`` and the load average.

``--steps``: instead, each output step alone with the forest grown once (matplotlib imported
first), best of 2, in one process per tree (before, then after): wall and CPU seconds.
"""
from __future__ import annotations

import argparse
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

HIDE_PYARROW = ("import runpy, sys; sys.modules['pyarrow'] = sys.modules['pyarrow.parquet'] = None; "
                "sys.argv[0] = 'simlidar-mi'; runpy.run_module('simlidar_mi.cli', run_name='__main__')")
IN_TURN = ("import sys; from simlidar_mi.forest.run import run_forest; "
           "run_forest(sys.argv[2], sys.argv[4], parallel=False)")


STEPS = r"""
import os, shutil, sys, time
from pathlib import Path
from simlidar_mi.config import load_scene
from simlidar_mi.forest import outputs as o
from simlidar_mi.forest.stand import make_forest
forest = make_forest(load_scene(sys.argv[1]))
out = Path(sys.argv[2])
import matplotlib.pyplot  # noqa: F401  (imported outside the timings)
res = {}
def timed(name, fn):
    t, c = time.perf_counter(), time.process_time()
    fn()
    res.setdefault(name, []).append((time.perf_counter() - t, time.process_time() - c))
tables = lambda: (t.leaf_table for t in forest.prototypes)
for rep in range(2):
    timed("leaf table, CSV", lambda: o._leaf_tables_csv(out / "pl.csv", tables(), "prototype"))
    if hasattr(o, "write_leaf_tables"):
        timed("leaf table, Parquet", lambda: o._leaf_tables_parquet(out / "pl.parquet", tables(), "prototype"))
    timed("layout.png", lambda: o.plot_layout(forest, out / "layout.png"))
    timed("preview.png", lambda: o.plot_preview(forest, out / "preview.png", 300))
    shutil.rmtree(out / "prototypes", ignore_errors=True)
    timed("prototype PLYs", lambda: o._write_prototype_meshes(forest, out / "prototypes", "ply", 6))
print(f"load {os.getloadavg()[0]:.1f}; " + "; ".join(
    f"{k}: wall {min(w for w, c in v):.2f} CPU {min(c for w, c in v):.2f}" for k, v in res.items()))
"""


def steps(before: Path, scene: Path) -> None:
    for name, tree in (("before", before), ("after", REPO)):
        with tempfile.TemporaryDirectory() as tmp:
            p = subprocess.run([sys.executable, "-P", "-c", STEPS, str(scene), tmp], capture_output=True,
                               text=True, cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)})
            if p.returncode:
                raise SystemExit(p.stderr[-3000:])
            print(f"{name}: {p.stdout.strip()}")


def run(tree: Path, code: str | None, scene: Path, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    py = [sys.executable, "-P"] + (["-c", code] if code else ["-m", "simlidar_mi.cli"])
    with tempfile.NamedTemporaryFile("r") as tf:
        cmd = ["/usr/bin/time", "-o", tf.name, "-f", "%e %U %S %M", *py, "forest", str(scene),
               "--out", str(out)]
        load = os.getloadavg()[0]
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=tree,
                           env={**os.environ, "PYTHONPATH": str(tree)})
        if p.returncode:
            raise SystemExit(p.stderr[-3000:])
        wall, user, sys_s, rss = tf.read().split()[-4:]
    sec = json.loads((out / "forest.json").read_text())["seconds"]
    return {"wall": float(wall), "cpu": float(user) + float(sys_s), "rss_mb": int(rss) / 1024,
            "load": load, **sec}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, type=Path, help="checkout to compare with")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", type=Path, default=REPO / "scenes" / "forest_4species.toml")
    ap.add_argument("--steps", action="store_true", help="each output step alone (see the docstring)")
    a = ap.parse_args()
    if a.steps:
        return steps(a.before.resolve(), a.scene.resolve())
    variants = {"before": (a.before.resolve(), HIDE_PYARROW), "after, in turn": (REPO, IN_TURN),
                "after": (REPO, None)}
    res: dict[str, list[dict]] = {k: [] for k in variants}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeat):
            for name, (tree, code) in variants.items():
                r = run(tree, code, a.scene.resolve(), Path(tmp) / "out")
                res[name].append(r)
                print(f"# {i} {name}: " + " ".join(f"{k}={v:.2f}" for k, v in r.items()), file=sys.stderr)
    print(f"Machine: {machine()}\n")
    cols = ["wall", "cpu", "rss_mb", "place", "grow", "tables", "plots", "export", "plots_wait", "load"]
    print("| variant | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for name, rows in res.items():
        med = [statistics.median(r[c] for r in rows) if all(c in r for r in rows) else float("nan")
               for c in cols]
        print(f"| {name} | " + " | ".join(f"{v:.0f}" if c == "rss_mb" else f"{v:.2f}"
                                          for c, v in zip(cols, med)) + " |")
    b = statistics.median(r["wall"] for r in res["before"])
    for name in ("after, in turn", "after"):
        print(f"\nbefore / {name} (medians of wall): {b / statistics.median(r['wall'] for r in res[name]):.2f}×")


if __name__ == "__main__":
    main()
