"""What a forest representation costs and what it changes: explicit leaves against prototypes.

    .venv/bin/python bench/bench_forest_repr.py [SCENE.toml] [--size 60] [--modes explicit,k4,k12]

On a square of ``--size`` metres cut from the scene's forest (default
``scenes/forest_4species.toml``, its densest corner at (30, 90) m), each representation runs in
a fresh process (peak RSS is its own): ``explicit`` (every tree its own draw and its own mesh,
``instancing = false``), ``explicit-seed2`` (the same with another scene seed: how far two
explicit stands drawn from the same laws lie apart, the floor of every comparison), ``kK``
(``prototypes_per_species = K``) and ``auto`` (at most 5 trees a prototype). Each process
generates the forest, builds the Mitsuba scene, fires an airborne nadir pass (200 m, 60°
swath, 2000 pulses a line, 1 MHz, 30 m/s) and casts hemispherical rays from a 4 × 4 grid of
ground points, and integrates the truth on a fixed 2 m grid.

Against ``explicit`` it reports: the share of vegetation first returns per 2 m height bin
(L1 distance of the two histograms, in %), the gap fraction in the five LAI-2200 rings (largest
absolute difference), the truth's per-voxel PAD (mean |ΔPAD| over voxels where either holds
plant area, relative to their mean PAD) and the stand's LAI. Prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

RINGS_DEG = ((0.0, 13.0), (16.0, 28.0), (32.0, 43.0), (47.0, 58.0), (61.0, 74.0))  # LAI-2200
ROW = r"""
import json, resource, sys, time
import numpy as np
from simlidar_mi.config import load_scene
from simlidar_mi.lidar.survey import generate, build, scan_patterns
from simlidar_mi.lidar.scan import scan
from simlidar_mi.truth.compute import compute_truth
from simlidar_mi.truth.grid import VoxelGrid
x0, y0, size = float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
rings = json.loads(sys.argv[5])
cfg = load_scene(sys.argv[1], sys.argv[6:])
t = time.perf_counter(); geo = generate(cfg); t_gen = time.perf_counter() - t
lo, hi = geo.bounds_m()
t = time.perf_counter(); built = build(cfg, geo); t_build = time.perf_counter() - t
rss_build = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
(pattern,) = scan_patterns(cfg, lo, hi)
scan(built, pattern)  # warm: kernels compiled once
t = time.perf_counter(); res = scan(built, pattern); t_scan = time.perf_counter() - t
veg = res.vegetation()
z = res.points_m()[..., 2][veg]
hist = np.histogram(z, bins=np.arange(0.0, 40.0 + 1e-9, 2.0))[0]
# hemispherical gap fraction: rays from a 4 x 4 grid of ground points, uniform in solid angle per ring
import drjit as dr
from simlidar_mi._runtime.mitsuba import mitsuba
mi = mitsuba()
rng = np.random.default_rng(5)
g = x0 + size * (0.2 + 0.6 * np.arange(4) / 3)
pts = np.array([(a, b, 0.3) for a in g for b in (y0 - x0) + g])
gaps = []
for t0, t1 in rings:
    n = 4000
    mu = rng.uniform(np.cos(np.deg2rad(t1)), np.cos(np.deg2rad(t0)), (len(pts), n))
    ph = rng.uniform(0, 2 * np.pi, (len(pts), n))
    s = np.sqrt(1 - mu ** 2)
    d = np.stack([s * np.cos(ph), s * np.sin(ph), mu], -1).reshape(-1, 3)
    o = np.repeat(pts - built.origin_m, n, axis=0)
    ray = mi.Ray3f(mi.Point3f(*[o[:, i].astype(np.float32) for i in range(3)]),
                   mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)]))
    hit = np.asarray(built.scene.ray_test(ray))
    gaps.append(1.0 - float(hit.mean()))
t = time.perf_counter()
grid = VoxelGrid((x0 - 10.0, y0 - 10.0, 0.0), 2.0, (int((size + 20) / 2), int((size + 20) / 2), 20))
ds = compute_truth(geo, grid, progress=False, ground_area_m2=size * size)
t_truth = time.perf_counter() - t
np.save(sys.argv[1] + ".pad.npy", ds["PAD_m2_m3"].values)
print(json.dumps({"trees": int(len(geo.instances)) if geo.instances is not None else int(geo.branches.tree_id.max()) + 1,
                  "prototypes": len(geo.instances.prototypes) if geo.instances is not None else 0,
                  "triangles_built": int(built.n_triangles), "generate_s": t_gen, "build_s": t_build,
                  "scan_s": t_scan, "pulses": int(pattern.n_beams), "truth_s": t_truth,
                  "hist": hist.tolist(), "gap": gaps, "LAI": float(ds.attrs["LAI"]),
                  "rss_build_mb": rss_build,
                  "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(scene: Path, mode: str, x0: float, y0: float, size: float, tmp: Path, seed: int | None = None) -> dict:
    over = [f"forest.domain_m=[{x0}, {x0 + size}, {y0}, {y0 + size}]",
            'platform.kind="airborne"', f"platform.start_xy_m=[{x0 + size / 2}, {y0 - 5}]",
            f"platform.end_xy_m=[{x0 + size / 2}, {y0 + size + 5}]", "platform.altitude_m=200.0",
            "platform.swath_deg=60.0", "platform.speed_m_s=30.0", "platform.pulse_rate_hz=1000000.0",
            "platform.pulses_per_line=2000", 'forest.export="none"']
    if mode.startswith("explicit"):
        over.append("forest.instancing=false")
        if mode.endswith("seed2"):
            over.append("scene.seed=2022")
    else:
        over += ["forest.instancing=true", "forest.prototypes_per_species=" +
                 ('"auto"' if mode == "auto" else mode[1:])]
    if seed is not None:
        over.append(f"scene.seed={seed}")
    copy = tmp / f"{mode}-{seed}.toml"
    cached = Path(str(copy) + ".json")
    if cached.is_file():     # a run of this scene text and overrides kept by an earlier call
        out = json.loads(cached.read_text())
        if out.get("scene") == scene.read_text() and out.get("over") == over:
            out["pad"] = np.load(str(copy) + ".pad.npy")
            return out
    copy.write_text(scene.read_text())
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", ROW, str(copy), str(x0), str(y0), str(size),
                           json.dumps(RINGS_DEG), *over], capture_output=True, text=True, cwd=REPO)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process_s"] = time.perf_counter() - t
    cached.write_text(json.dumps({**out, "scene": scene.read_text(), "over": over}))
    out["pad"] = np.load(str(copy) + ".pad.npy")
    return out


def load_average() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(REPO / "scenes" / "forest_4species.toml"))
    ap.add_argument("--size", type=float, default=60.0)
    ap.add_argument("--corner", type=float, nargs=2, default=(30.0, 90.0))
    ap.add_argument("--modes", default="explicit,explicit-seed2,auto,k16,k12,k8,k4")
    ap.add_argument("--tmp", default="/tmp/bench_forest_repr")
    ap.add_argument("--seeds", default="", help="comma-separated scene seeds: a second table of "
                    "each mode's stand results averaged over these seeds (explicit-seed2 left out)")
    ap.add_argument("--seeds-only", action="store_true", help="only the table over --seeds")
    a = ap.parse_args()
    tmp = Path(a.tmp)
    tmp.mkdir(parents=True, exist_ok=True)
    modes = a.modes.split(",")
    if a.seeds_only:
        print(over_seeds(Path(a.scene), [m for m in modes if m != "explicit-seed2"],
                         [int(x) for x in a.seeds.split(",")], a, tmp))
        return
    res = {}
    for m in modes:
        load0 = load_average()
        res[m] = run(Path(a.scene), m, a.corner[0], a.corner[1], a.size, tmp)
        res[m]["load"] = f"{load0}–{load_average()}"
        print(m, {k: v for k, v in res[m].items() if k not in ("pad", "hist")}, file=sys.stderr)
    ref = res[modes[0]]
    h0 = np.asarray(ref["hist"], float) / max(1, sum(ref["hist"]))
    rows = ["| representation | trees | prototypes | triangles built | generate s | build s | scan s "
            "(pulses) | peak RSS MB | returns per 2 m bin: L1 vs ref % | gap per ring: max abs diff "
            "(ref gaps) | PAD per voxel: mean abs diff / mean % | LAI (ref) | load |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in modes:
        r = res[m]
        h = np.asarray(r["hist"], float) / max(1, sum(r["hist"]))
        gd = max(abs(a_ - b_) for a_, b_ in zip(r["gap"], ref["gap"]))
        both = (r["pad"] > 0) | (ref["pad"] > 0)
        pad = 100 * float(np.abs(r["pad"] - ref["pad"])[both].mean() /
                          (0.5 * (r["pad"] + ref["pad"])[both].mean())) if both.any() else 0.0
        gaps = " / ".join(f"{g:.3f}" for g in ref["gap"]) if m == modes[0] else f"{gd:.3f}"
        rows.append(f"| {m} | {r['trees']} | {r['prototypes'] or '–'} | {r['triangles_built']:,} | "
                    f"{r['generate_s']:.1f} | {r['build_s']:.1f} | {r['scan_s']:.2f} ({r['pulses']:,}) | "
                    f"{r['rss_peak_mb']:.0f} | {100 * np.abs(h - h0).sum():.1f} | {gaps} | {pad:.0f} | "
                    f"{r['LAI']:.2f} ({ref['LAI']:.2f}) | {r['load']} |")
    print(f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}  \n"
          f"Scene: {a.scene}, {a.size:g} m square at {tuple(a.corner)}\n")
    print("\n".join(rows))
    if a.seeds:
        print()
        print(over_seeds(Path(a.scene), [m for m in modes if m != "explicit-seed2"],
                         [int(x) for x in a.seeds.split(",")], a, tmp))


def over_seeds(scene: Path, modes: list, seeds: list, a, tmp: Path) -> str:
    """Each mode's mean over ``seeds`` of the stand results, against explicit's mean ± its SE."""
    res, loads = {m: [] for m in modes}, []
    for s in seeds:          # seed by seed: every finished seed has all its modes (runs are kept)
        for m in modes:
            loads.append(float(load_average()))
            res[m].append(run(scene, m, a.corner[0], a.corner[1], a.size, tmp, s))
        print("seed", s, "done", time.strftime("%H:%M UTC", time.gmtime()), file=sys.stderr)
    loads.append(float(load_average()))

    def stats(rs):
        h = np.array([np.asarray(r["hist"], float) / max(1, sum(r["hist"])) for r in rs])
        g = np.array([r["gap"] for r in rs])
        prof = np.array([r["pad"].mean(axis=(0, 1)) for r in rs])
        lai = np.array([r["LAI"] for r in rs])
        return h, g, prof, lai
    h0, g0, p0, l0 = stats(res[modes[0]])
    se = lambda x: x.std(axis=0, ddof=1) / np.sqrt(len(x)) if len(x) > 1 else np.zeros(x.shape[1:])  # noqa: E731
    out = [f"Over scene seeds {', '.join(map(str, seeds))} (means of {len(seeds)} stands a mode; "
           f"'SE' is explicit's standard error of the mean; load average {min(loads):.1f}–{max(loads):.1f}, "
           f"until {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}):", "",
           "| representation | triangles built (mean) | peak RSS MB (max) | returns per 2 m bin: L1 of the mean "
           "profiles % | gap per ring: mean, max abs diff (explicit SE, max) | PAD profile per 2 m layer: L1 of "
           "the means % | LAI mean ± SE |", "|---|---|---|---|---|---|---|"]
    for m in modes:
        h, g, p, l_ = stats(res[m])
        dh = 100 * np.abs(h.mean(0) - h0.mean(0)).sum()
        dg = np.abs(g.mean(0) - g0.mean(0)).max()
        dp = 100 * np.abs(p.mean(0) - p0.mean(0)).sum() / p0.mean(0).sum()
        tri = np.mean([r["triangles_built"] for r in res[m]])
        rss = max(r["rss_peak_mb"] for r in res[m])
        gap = (" / ".join(f"{x:.3f}" for x in g0.mean(0)) + f" (SE {se(g0).max():.3f})" if m == modes[0]
               else f"{dg:.3f}")
        out.append(f"| {m} | {tri:,.0f} | {rss:.0f} | {dh:.1f} | {gap} | {dp:.1f} | "
                   f"{l_.mean():.2f} ± {se(l_[:, None])[0]:.2f} |")
    return "\n".join(out)


if __name__ == "__main__":
    main()
