"""What each [sensor] effect costs on the SIMLIDAR 7×4 orchard (BENCHMARKS.md §7).

    .venv/bin/python bench/bench_sensor.py [--dy 0.02] [--repeat 2]

Each row runs in its own process (peak RSS is per process) with the kernel cache warm
(one untimed scan first); beams/s from the best of ``--repeat`` scans of the whole
pattern.  The accuracy rows compare the hit share of a 2 cm stem 10 m away with float64
sub-rays on the exact cylinder (tests/test_sensor_physics.py does the same with asserts).
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "scenes" / "simlidar_table3_7x4.toml"
# --scene forest: the airborne forest (scenes/forest_airborne.toml: 200 m, 60° swath), the
# first 30 m of its line (1 M pulses), with the rows' 11.9 mrad replaced by an ALS-like
# 0.9 mrad (an 18 cm footprint at 200 m) and a 10 % range of 400 m (the default 40 m would
# detect nothing from 200 m: a sensor section alone, with no effect on, keeps the old path).
FOREST = REPO / "scenes" / "forest_airborne.toml"
FOREST_SET = ["platform.end_xy_m=[150.0, 30.0]", "sensor.range_at_10pct_m=400.0"]
ROWS = [
    ("off (no [sensor])", []),
    ("divergence 11.9 mrad, S = 16", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=16"]),
    ("divergence 11.9 mrad, S = 64", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=64"]),
    ("divergence S = 16, detection nearest", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=16",
                                              "sensor.detection=nearest"]),
    ("divergence S = 64, detection nearest", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=64",
                                              "sensor.detection=nearest"]),
    ("echoes (max_returns 5), S = 1", ["sensor.max_returns=5"]),
    ("intensity, S = 1", ["sensor.intensity=true"]),
    ("range noise 1 cm, S = 1", ["sensor.range_noise_m=0.01"]),
    ("divergence S = 16 + echoes", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=16", "sensor.max_returns=5"]),
    ("divergence S = 64 + echoes", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=64", "sensor.max_returns=5"]),
    ("all: S = 64, echoes, intensity, noise", ["sensor.divergence_mrad=11.9", "sensor.beam_samples=64",
                                               "sensor.max_returns=5", "sensor.intensity=true",
                                               "sensor.range_noise_m=0.01"]),
]


def _scene_overrides(scene: str, overrides: list[str], dy: float) -> tuple[Path, list[str]]:
    if scene == "forest":
        return FOREST, FOREST_SET + [o.replace("divergence_mrad=11.9", "divergence_mrad=0.9") for o in overrides]
    return SCENE, [f"scan.dy_m={dy}", *overrides]


def one(overrides: list[str], dy: float, repeat: int, scene: str = "orchard") -> dict:
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.scan import scan
    from simlidar_mi.lidar.survey import build, generate, scan_patterns, scene_sensor
    cfg = load_scene(*_scene_overrides(scene, overrides, dy))
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    built = build(cfg, g, pats)
    model = scene_sensor(cfg, g, pats)
    scan(built, pats[0], sensor=model, seed=cfg.seed)  # warm the kernel cache
    best, res = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        res = scan(built, pats[0], sensor=model, seed=cfg.seed)
        best = min(best, time.perf_counter() - t)
    n = res.range_m.size
    out = {"beams": n, "seconds": best, "beams_per_s": n / best,
           "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
           "trace_s": res.metadata.get("trace_seconds"), "echo_s": res.metadata.get("echo_seconds"),
           "sub_rays": res.metadata.get("sub_rays_per_beam", (pats[0].footprint + 1) ** 2)}
    if res.echoes is not None:
        out["echoes_per_beam"] = len(res.echoes) / n
    return out


def accuracy() -> list[dict]:
    import math

    import numpy as np
    sys.path.insert(0, str(REPO))
    from tests.test_sensor_physics import run, static
    from simlidar_mi.lidar.reference import ray_cylinder_pairs
    from simlidar_mi.lidar.sensor import subray_offsets
    R, d_m, step = 10.0, 0.02, 0.01
    az = np.arange(-0.3, 0.3 + 1e-9, step)
    text = static(f"[{az[0]}, {az[-1] + step / 2}, {step}]") + (
        f'[[primitive]]\ntype = "cylinder"\np0_m = [{R}, 0.0, -2.0]\np1_m = [{R}, 0.0, 2.0]\ndiameter_m = {d_m}\n')
    rows = []
    for S in (16, 64, 256):
        res, model = run(text + f"[sensor]\ndivergence_mrad = 6.0\nbeam_samples = {S}\n")
        thin, _ = run(text, sensor=False)
        off, w = subray_offsets(model)
        ref = []
        for a in np.deg2rad(res.pattern.row_yaw_deg):
            d = np.array([math.cos(a), math.sin(a), 0.0])
            u = np.cross([0.0, 0.0, 1.0], d)
            u /= np.linalg.norm(u)
            dirs = d + np.tan(off[:, :1]) * u + np.tan(off[:, 1:]) * np.cross(d, u)
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            n = len(dirs)
            t = ray_cylinder_pairs(np.zeros((n, 3)), dirs, np.tile([R, 0, -2.0], (n, 1)),
                                   np.tile([R, 0, 2.0], (n, 1)), np.full(n, d_m / 2))
            ref.append(w[np.isfinite(t)].sum())
        ref = np.array(ref)
        h = math.atan(d_m / 2 / R)
        from simlidar_mi.lidar.sensor import gaussian_share
        closed = np.array([gaussian_share(a + h, 6.0) - gaussian_share(a - h, 6.0)
                           for a in np.deg2rad(res.pattern.row_yaw_deg)])
        rows.append({"S": S, "mean_abs_vs_ref": float(np.mean(np.abs(res.hit_fraction[:, 0] - ref))),
                     "mean_abs_vs_erf": float(np.mean(np.abs(res.hit_fraction[:, 0] - closed))),
                     "thin_ray_mean_abs_vs_erf": float(np.mean(np.abs(thin.hit_fraction[:, 0] - closed)))})
    return rows


def readings(dy: float) -> list[dict]:
    """How far ``detection = "waveform"`` (default) moves results from ``"nearest"``: the
    orchard's vegetation returns and A_IM at 11.9 mrad (S = 64), and beams returning a 2 cm
    stem at 10 m and 30 m (γ = 6 mrad, S = 64; wood ρ = 0.35) against the closed form:
    a beam whose stem share f has f·ρ·R_ref²/r² ≥ threshold is detected."""
    import math

    import numpy as np
    sys.path.insert(0, str(REPO))
    from tests.test_sensor_physics import run, static
    from simlidar_mi.config import load_scene
    from simlidar_mi.lidar.scan import scan
    from simlidar_mi.lidar.survey import build, generate, scan_patterns, scene_sensor
    rows = []
    for det in ("nearest", "waveform"):
        cfg = load_scene(SCENE, [f"scan.dy_m={dy}", "sensor.divergence_mrad=11.9", "sensor.beam_samples=64",
                                 f"sensor.detection={det}"])
        g = generate(cfg)
        lo, hi = g.bounds_m()
        pats = scan_patterns(cfg, lo, hi, g.near_x_m)
        res = scan(build(cfg, g, pats), pats[0], sensor=scene_sensor(cfg, g, pats), seed=cfg.seed)
        row = {"detection": det, "orchard_vegetation_returns": int(res.vegetation().sum()),
               "orchard_A_IM_m2": res.impacted_area_m2(), "orchard_beams": int(res.range_m.size),
               "orchard_mean_vegetation_range_m": float(res.range_m[res.vegetation()].mean())}
        for R in (10.0, 30.0):
            d_m, step = 0.02, 0.005
            az = np.arange(-0.3, 0.3 + 1e-9, step)
            text = static(f"[{az[0]}, {az[-1] + step / 2}, {step}]") + (
                f'[[primitive]]\ntype = "cylinder"\np0_m = [{R}, 0.0, -2.0]\np1_m = [{R}, 0.0, 2.0]\n'
                f'diameter_m = {d_m}\n')
            stem, model = run(text + f"[sensor]\ndivergence_mrad = 6.0\nbeam_samples = 64\ndetection = \"{det}\"\n")
            # Closed form: E(a) = ρ·(R_ref/R)²·∫ p(x − a)·cos i(x) dx over the stem's angular
            # half-width h, p the Gaussian's 1D marginal (sd w/2), cos i = √(1 − (x/h)²).
            h = math.atan(d_m / 2 / R)
            x = np.linspace(-h, h, 4001)
            sd = 0.5 * 0.5 * 6.0e-3
            e_beam = np.array([np.trapezoid(np.exp(-0.5 * ((x - a) / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
                                            * np.sqrt(np.clip(1 - (x / h) ** 2, 0, 1)), x)
                               for a in np.deg2rad(stem.pattern.row_yaw_deg)])
            e_beam *= model.reflectance_wood * (model.r_ref_m / R) ** 2
            row[f"stem_{R:.0f}m_beams"] = int(stem.range_m.shape[0])
            row[f"stem_{R:.0f}m_touched"] = int((stem.hit_fraction[:, 0] > 0).sum())
            row[f"stem_{R:.0f}m_returns"] = int(stem.vegetation()[:, 0].sum())
            row[f"stem_{R:.0f}m_closed_form"] = int((e_beam >= model.detection_threshold).sum())
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dy", type=float, default=0.02)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--row", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--readings", action="store_true", help="only the detection-readings table")
    ap.add_argument("--scene", choices=("orchard", "forest"), default="orchard",
                    help="forest: the effects table on the airborne forest (no accuracy tables)")
    args = ap.parse_args()
    if args.row is not None:
        print(json.dumps(one(ROWS[args.row][1], args.dy, args.repeat, args.scene)))
        return
    if args.readings:
        for r in readings(args.dy):
            print(r)
        return
    sys.path.insert(0, str(REPO / "bench"))
    from _machine import machine
    print(f"machine: {machine()}")
    scene_path, sets = _scene_overrides(args.scene, [], args.dy)
    print(f"scene: {scene_path.name} {' '.join(sets)}")
    print("| effect | sub-rays/beam | beams/s | trace s | echoes s | peak RSS MB | echoes/beam |")
    print("|---|---|---|---|---|---|---|")
    for j, (name, _) in enumerate(ROWS):
        out = subprocess.run([sys.executable, __file__, "--row", str(j), "--dy", str(args.dy),
                              "--repeat", str(args.repeat), "--scene", args.scene],
                             capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        fmt = lambda v: "–" if v is None else f"{v:.2f}"  # noqa: E731
        print(f"| {name} | {r['sub_rays']} | {r['beams_per_s']:,.0f} | {fmt(r['trace_s'])} | {fmt(r['echo_s'])} "
              f"| {r['rss_mb']:.0f} | {r.get('echoes_per_beam', float('nan')):.3f} |", flush=True)
    if args.scene == "forest":
        return
    print("\nthin stem (2 cm at 10 m, γ = 6 mrad): mean |hit share − reference|")
    for r in accuracy():
        print(r)
    print("\ndetection readings (orchard 11.9 mrad S = 64; 2 cm stem 6 mrad S = 64)")
    for r in readings(args.dy):
        print(r)


if __name__ == "__main__":
    main()
