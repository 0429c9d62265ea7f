"""A full-waveform scan against the raw cast of its own sub-rays (BENCHMARKS.md §7e).

The SIMLIDAR Table 3 orchard (``scenes/simlidar_table3_7x4.toml``) scanned by a tractor line
scanner of 601 pulses a sweep from −70.25° to 80° and 4200 sweeps (2,524,200 pulses; ``--rows``
takes the first rows only), a 0.3 mrad Gaussian beam of 19 sub-rays, 5 returns, intensity (the
settings of the side-by-side with HELIOS++):

- ``raw``: the bare cast of the same sub-rays (``ray_intersect_preliminary``, range and hit
  read back, nothing else), chunk by chunk as the scan traces them;
- ``scan``: the held scan (sub-rays, energies, echoes, first-return arrays), with its set-up
  (the table of triangle normals; "loop" leaves it out); ``--other REPO`` also scans with another checkout's code
  (``REPO/.venv/bin/python``, e.g. the main branch) in the same rounds;
- ``numpy`` (``--numpy-reader``): the held scan with ``[sensor] waveform_reader = "numpy"``
  (every beam read by the host's numpy detector, the bits before the Dr.Jit reader);
- ``single``: the single-ray scan of the same pulses without ``[sensor]`` (one ray a pulse);
- ``--end-to-end``: the ``simlidar-mi scan`` command (every file), this checkout (and with the
  numpy reader) and ``--other``.

Children run OpenBLAS on one thread, as the ``simlidar-mi`` command does.

Each figure runs in its own process (peak RSS per process), after an untimed warm-up of a few
rows in that process; kinds alternate round by round so ratios are taken pair by pair.

    .venv/bin/python bench/bench_fullwave.py [--rows 416] [--repeat 3] [--numpy-reader] [--other /work/main] [--end-to-end]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENE = "scenes/simlidar_table3_7x4.toml"
SETS = ["scan.theta_min_deg=-70.25", "scan.theta_max_deg=80.0", "scan.y_start_m=-1.5", "scan.y_end_m=6.9",
        "sensor.divergence_mrad=0.3", "sensor.beam_samples=19", "sensor.max_returns=5", "sensor.intensity=true"]
SINGLE_SETS = SETS[:4]
NUMPY_SETS = [*SETS, 'sensor.waveform_reader="numpy"']  # every beam read on the host (--numpy-reader)
WARM_ROWS = 8


def child(kind: str, rows: int | None) -> dict:
    """One figure in this process (run with the checkout's own interpreter, from its root)."""
    import resource  # noqa: PLC0415

    import drjit as dr  # noqa: PLC0415

    from simlidar_mi.config import load_scene  # noqa: PLC0415
    from simlidar_mi.lidar.scan import physical_tracer, scan  # noqa: PLC0415
    from simlidar_mi.lidar.survey import build, generate, scan_patterns, scene_sensor  # noqa: PLC0415
    cfg = load_scene(SCENE, {"single": SINGLE_SETS, "numpy": NUMPY_SETS}.get(kind, SETS))
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    built = build(cfg, g, pats)
    model = None if kind == "single" else scene_sensor(cfg, g, pats)
    n_rows = pats[0].n_positions if rows is None else min(rows, pats[0].n_positions)

    tracer = physical_tracer(built, pats[0], model, rows=(0, n_rows)) if kind == "raw" else None

    def run(r):
        if kind != "raw":  # scan, numpy, single
            res = scan(built, pats[0], sensor=model, seed=cfg.seed, rows=(0, r))
            return res.range_m.size, (len(res.echoes) if res.echoes is not None else None), res.seconds
        tr = tracer  # made before the clock starts (its normal table is the scan's set-up)
        n = tr.n_beams if r == n_rows else r * pats[0].n_angles
        for b0 in range(0, n, tr.per_chunk):
            t, hit = tr._integrator.cast_subrays(tr._scene, tr._lidar, tr._offsets,
                                                 tr.beam0 - tr._lidar.first_beam + b0, min(tr.per_chunk, n - b0))
            t.numpy(), hit.numpy()  # read back, as a scan does
        dr.sync_thread()
        return n, None, None

    run(WARM_ROWS)
    t0 = time.perf_counter()
    beams, echoes, loop_s = run(n_rows)
    seconds = time.perf_counter() - t0
    return {"kind": kind, "seconds": seconds, "loop_s": loop_s, "beams": beams, "echoes": echoes,
            "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _spawn(repo: Path, args: list[str]) -> dict:
    py = repo / ".venv" / "bin" / "python"
    # OpenBLAS with one thread, as the simlidar-mi command sets it (_runtime/signals.py): its idle
    # workers spin after each hit-fraction product and took ~40 % of the scan from Dr.Jit's threads
    env = dict(os.environ, PYTHONPATH=str(repo), OPENBLAS_NUM_THREADS=os.environ.get("OPENBLAS_NUM_THREADS", "1"))
    out = subprocess.run([str(py), str(Path(__file__).resolve()), *args], cwd=repo, check=True,
                         capture_output=True, text=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _end_to_end(repo: Path, out_dir: Path, sets: list[str] = SETS) -> dict:
    exe = repo / ".venv" / "bin" / "simlidar-mi"
    cmd = [str(exe), "scan", SCENE, "--out", str(out_dir)] + [a for s in sets for a in ("--set", s)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=repo, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"{cmd} failed: {proc.stderr.read()}")
    m = json.loads((out_dir / "measures.json").read_text())
    return {"seconds": seconds, "rss_mb": usage.ru_maxrss / 1024, "echoes": m.get("echoes", {}).get("echoes")}


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--one", choices=("raw", "scan", "numpy", "single"), help=argparse.SUPPRESS)
    ap.add_argument("--rows", type=int, default=None, help="sweeps to scan (default: all 4200)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--other", type=Path, default=None, help="another checkout to scan with (its .venv)")
    ap.add_argument("--end-to-end", action="store_true", help="also time the simlidar-mi scan command")
    ap.add_argument("--no-single", action="store_true")
    ap.add_argument("--numpy-reader", action="store_true",
                    help="also scan with [sensor] waveform_reader = \"numpy\" (every beam read on the host)")
    a = ap.parse_args()
    if a.one:
        print(json.dumps(child(a.one, a.rows)))
        return
    sys.path.insert(0, str(REPO / "bench"))
    from _machine import machine  # noqa: PLC0415
    print(machine())
    rows = ["--rows", str(a.rows)] if a.rows else []
    kinds = ([("raw", REPO), ("scan", REPO)] + ([("numpy", REPO)] if a.numpy_reader else [])
             + ([("scan", a.other)] if a.other else []))
    if not a.no_single:
        kinds += [("single", REPO)] + ([("single", a.other)] if a.other else [])
    figs: dict[tuple, list] = {}
    for r in range(a.repeat):
        for kind, repo in kinds:
            load = _load()
            f = _spawn(repo, ["--one", kind, *rows])
            f["load"] = load
            figs.setdefault((kind, str(repo)), []).append(f)
            print(f"round {r}: {kind:6s} {repo.name:10s} {f['seconds']:7.2f} s  rss {f['rss_mb']:6.0f} MB  "
                  f"echoes {f['echoes']}  load {load}", flush=True)
    raw = figs[("raw", str(REPO))]
    print(f"\n{raw[0]['beams']:,} pulses × 19 sub-rays; medians of {a.repeat} rounds, ratios to the raw cast "
          "taken round by round")
    print("| run | code | seconds | × raw cast (median, min–max) | loop s (× raw) | peak RSS MB | echoes |")
    print("|---|---|---|---|---|---|---|")
    for (kind, repo), fs in figs.items():
        ratios = [f["seconds"] / x["seconds"] for f, x in zip(fs, raw)]
        loop = [f["loop_s"] / x["seconds"] for f, x in zip(fs, raw) if f.get("loop_s") is not None]
        loop_txt = (f"{statistics.median(f['loop_s'] for f in fs):.2f} ({statistics.median(loop):.2f})"
                    if loop else "")
        print(f"| {kind} | {Path(repo).name} | {statistics.median(f['seconds'] for f in fs):.2f} | "
              f"{statistics.median(ratios):.2f} ({min(ratios):.2f}–{max(ratios):.2f}) | {loop_txt} | "
              f"{max(f['rss_mb'] for f in fs):.0f} | {fs[0]['echoes']} |")
    if a.end_to_end:
        e2e: dict[str, list] = {}
        with tempfile.TemporaryDirectory() as tmp:
            runs = ([(REPO.name, REPO, SETS)] + ([(f"{REPO.name} (numpy reader)", REPO, NUMPY_SETS)] if a.numpy_reader else [])
                    + ([(a.other.name, a.other, SETS)] if a.other else []))
            for r in range(a.repeat):
                for name, repo, sets in runs:
                    load = _load()
                    f = _end_to_end(repo, Path(tmp) / f"{len(e2e)}_{r}", sets)
                    e2e.setdefault(name, []).append(f)
                    print(f"end to end round {r}: {name:10s} {f['seconds']:7.2f} s  rss {f['rss_mb']:6.0f} MB  "
                          f"echoes {f['echoes']}  load {load}", flush=True)
        print("\n| end to end (simlidar-mi scan, every file) | seconds (median) | peak RSS MB | echoes |")
        print("|---|---|---|---|")
        for name, fs in e2e.items():
            print(f"| {name} | {statistics.median(f['seconds'] for f in fs):.2f} | "
                  f"{max(f['rss_mb'] for f in fs):.0f} | {fs[0]['echoes']} |")
        if a.other:
            mine, other = e2e[REPO.name], e2e[a.other.name]
            ratios = [x["seconds"] / y["seconds"] for x, y in zip(mine, other)]
            print(f"\nend to end, this checkout / {a.other.name}, pair by pair: median {statistics.median(ratios):.2f} "
                  f"({min(ratios):.2f}–{max(ratios):.2f})")


if __name__ == "__main__":
    main()
