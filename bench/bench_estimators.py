"""LiDAR estimators against the truth (BENCHMARKS.md §10d): accuracy vs cost.

    .venv/bin/python bench/bench_estimators.py [--quick] [--out bench_estimators.json]

1. Turbid medium (simlidar_mi.truth.synthetic.turbid_beams: PAD = 2 m²/m³ in 64 voxels of
   0.25 m, spherical elements): per-voxel RMS error and bias of Beer–Lambert and the MLE
   against beams per voxel, 5 seeds; the beam count for 5 % RMS error.
2. Random spherical leaves in a 1 m cube, scanned by Mitsuba (synthetic.leaf_box_scan),
   exact truth (compute_truth): each estimator against voxel size and angular step.
3. ``evaluate`` end to end on scenes (default orchard_leafy, vineyard_vsp, apple_orchard) at voxel
   sizes 0.05/0.1/0.25 m and at half the beam density: seconds, R², RMSE, bias; canopy envelope,
   TRV and LWA of the truth and of the point cloud.
4. Multi-return: a [sensor] scene (scenes/orchard_lms511.toml, coarsened) first return vs
   every echo, equal vs energy weights.
5. G (``--only-g`` runs this alone): the truth's G along the scan's beams on the leafy orchard
   and the vineyard at 0.25 and 0.1 m, and the bias of Beer-Lambert and the MLE with G = 0.5,
   with the truth's canopy G and with its G per voxel (the ``*_Gcanopy`` / ``*_Gvoxel`` runs).
Prints markdown tables.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

from simlidar_mi.truth.estimators import beer_lambert_pad, contact_mle_pad, point_occupancy, vcp_pad  # noqa: E402
from simlidar_mi.truth.grid import VoxelGrid  # noqa: E402
from simlidar_mi.truth.scoring import score  # noqa: E402
from simlidar_mi.truth.synthetic import leaf_box_scan, turbid_beams  # noqa: E402
from simlidar_mi.truth.traverse import traverse  # noqa: E402


def turbid(quick: bool) -> list[dict]:
    g = VoxelGrid((0.0, 0.0, 0.0), 0.25, (4, 4, 4))
    rows = []
    for n in ([4_000, 64_000] if quick else [1_000, 4_000, 16_000, 64_000, 256_000, 1_024_000]):
        acc = []
        for seed in range(3 if quick else 5):
            t = time.perf_counter()
            c = traverse(g, turbid_beams(n, 2.0, seed))
            walk_s = time.perf_counter() - t
            bl, ml = beer_lambert_pad(c), contact_mle_pad(c)
            # over the voxels ≥ min_beams (5) beams entered (all of them from 4,000 beams on)
            acc.append([np.nanmean(bl) / 2 - 1, np.nanmean(ml) / 2 - 1, np.sqrt(np.nanmean((bl - 2) ** 2)) / 2,
                        np.sqrt(np.nanmean((ml - 2) ** 2)) / 2, np.median(c.n_in), walk_s])
        a = np.mean(acc, axis=0)
        rows.append({"beams": n, "beams_per_voxel": float(a[4]), "bias_BL": float(a[0]), "bias_MLE": float(a[1]),
                     "rms_BL": float(a[2]), "rms_MLE": float(a[3]), "walk_s": float(a[5])})
    print("\n| beams | entering / voxel (median) | bias BL | bias MLE | RMS err BL | RMS err MLE | walk s |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['beams']:,} | {r['beams_per_voxel']:.0f} | {100 * r['bias_BL']:+.2f} % | {100 * r['bias_MLE']:+.2f} % | "
              f"{100 * r['rms_BL']:.1f} % | {100 * r['rms_MLE']:.1f} % | {r['walk_s']:.2f} |")
    return rows


def leaf_box(quick: bool) -> list[dict]:
    from simlidar_mi.geometry import Branches
    from simlidar_mi.lidar.survey import SceneGeometry
    from simlidar_mi.truth.compute import compute_truth
    from simlidar_mi.truth.grid import grid_values
    rows = []
    steps = [(0.02, 0.4), (0.01, 0.2)] if quick else [(0.02, 0.4), (0.01, 0.2), (0.005, 0.1)]
    for dy, dth in steps:
        for voxel in (0.05, 0.1, 0.25):
            t = time.perf_counter()
            beams, grid, _, canopy = leaf_box_scan(dy_m=dy, dtheta_deg=dth, voxel_m=voxel)
            scan_s = time.perf_counter() - t
            truth = compute_truth(SceneGeometry(Branches.empty(), canopy.leaves, []), grid, progress=False)
            pad_t = grid_values(truth, "PAD_m2_m3")  # [i, j, k], as the estimates
            t = time.perf_counter()
            c = traverse(grid, beams)
            walk_s = time.perf_counter() - t
            occ = point_occupancy(grid, beams)["occupied"]
            for name, est in (("beer_lambert", beer_lambert_pad(c)), ("contact_mle", contact_mle_pad(c)),
                              ("vcp", vcp_pad(c, occ))):
                s = score(pad_t, est, c.n_in >= 5)  # the voxels evaluate scores (min_beams 5)
                rows.append({"dy_m": dy, "dtheta_deg": dth, "beams": len(beams), "voxel_m": voxel,
                             "estimator": name, "n_in_median": float(np.median(c.n_in[c.n_in > 0])),
                             **{f"{k}": s["voxel"][k] for k in ("n", "r2", "rmse", "bias")},
                             "profile_bias": s["profile"]["bias"], "profile_rmse": s["profile"]["rmse"],
                             "truth_mean": s["voxel"]["truth_mean"], "scan_s": scan_s, "walk_s": walk_s})
    print("\n| Δθ (°) / Δy (m) | beams | voxel (m) | beams in / voxel | estimator | R² | RMSE | bias | profile RMSE | walk s |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['dtheta_deg']} / {r['dy_m']} | {r['beams']:,} | {r['voxel_m']} | {r['n_in_median']:.0f} | "
              f"{r['estimator']} | {r['r2']:.3f} | {r['rmse']:.3f} | {r['bias']:+.3f} | {r['profile_rmse']:.3f} | "
              f"{r['walk_s']:.2f} |")
    return rows


def end_to_end(scenes: list[str], quick: bool) -> list[dict]:
    from simlidar_mi.truth.evaluate import evaluate
    rows = []
    runs = [(0.25, False)] if quick else [(0.25, False), (0.1, False), (0.05, False), (0.1, True)]
    for scene in scenes:
        for voxel, coarse in runs:
            over = _coarser(scene) if coarse else []
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                run = evaluate(scene, Path(tmp) / "ev", over, voxel_m=voxel)
                total = time.perf_counter() - t
            sec = run.summary["seconds"]
            for r in run.scores:
                rows.append({"scene": Path(scene).stem, "voxel_m": voxel, "sampling": "2× coarser" if coarse else "scene's",
                             "beams": run.summary["n_beams"], "total_s": total, "scan_s": sec["scan"],
                             "truth_s": sec["truth"], "envelope": run.summary["envelope"], **r})
    print("\n| scene | voxel (m) | sampling | beams | total s | scan s | truth s | estimator | est. s | n | R² voxel | RMSE | bias | truth mean | R² profile | profile RMSE |")
    print("|---|---:|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    by = {(r["scene"], r["voxel_m"], r["sampling"], r["estimator"], r["scale"]): r for r in rows}
    for r in rows:
        if r["scale"] != "voxel":
            continue
        p = by[(r["scene"], r["voxel_m"], r["sampling"], r["estimator"], "profile")]
        print(f"| {r['scene']} | {r['voxel_m']} | {r['sampling']} | {r['beams']:,} | {r['total_s']:.1f} | {r['scan_s']:.1f} | "
              f"{r['truth_s']:.1f} | {r['estimator']} | {r['seconds']:.1f} | {r['n']} | {r['r2']:.3f} | {r['rmse']:.3f} | "
              f"{r['bias']:+.3f} | {r['truth_mean']:.3f} | {p['r2']:.3f} | {p['rmse']:.3f} |")
    print("\n| scene | voxel (m) | sampling | H truth (m) | H points | W truth (m) | W points | TRV truth (m³/ha) | TRV points | LWA truth (m²/ha) | LWA points |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    seen = set()
    for r in rows:
        key = (r["scene"], r["voxel_m"], r["sampling"])
        e = r["envelope"]
        if key in seen or "truth" not in e:
            continue
        seen.add(key)
        t, q = e["truth"], e["points"]
        f = lambda d, k: f"{d[k]:.0f}" if k in d else "–"  # noqa: E731
        print(f"| {r['scene']} | {r['voxel_m']} | {r['sampling']} | {t['mean_height_m']:.3f} | {q['mean_height_m']:.3f} | "
              f"{t['mean_width_m']:.3f} | {q['mean_width_m']:.3f} | {f(t, 'TRV_m3_ha')} | {f(q, 'TRV_m3_ha')} | "
              f"{f(t, 'LWA_m2_ha')} | {f(q, 'LWA_m2_ha')} |")
    return rows


def _coarser(scene: str) -> list[str]:
    """Overrides that halve the beam density along both scan directions."""
    from simlidar_mi.config import load_scene
    cfg = load_scene(scene)
    if cfg["platform"]["kind"] == "tractor":
        return [f"scan.dtheta_deg={2 * cfg['scan']['dtheta_deg']}", f"scan.dy_m={2 * cfg['scan']['dy_m']}"]
    lo, hi, step = cfg["platform"]["elevation_deg"]
    return [f"platform.step_m={2 * cfg['platform']['step_m']}", f"platform.elevation_deg=[{lo}, {hi}, {2 * step}]"]


def multi_return(scene: str, sets: list[str]) -> list[dict]:
    from simlidar_mi.truth.evaluate import evaluate
    rows = []
    for weights in ("equal", "energy"):
        with tempfile.TemporaryDirectory() as tmp:
            run = evaluate(scene, Path(tmp) / "ev", sets, voxel_m=0.1, weights=weights)
        rows += [{"weights": weights, **r} for r in run.scores if r["scale"] == "voxel"]
    print(f"\n`evaluate {scene} {' '.join('--set ' + s for s in sets)} --voxel 0.1`")
    print("\n| echo weights | estimator | R² | RMSE | bias | truth mean | estimate mean |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['weights']} | {r['estimator']} | {r['r2']:.3f} | {r['rmse']:.4f} | {r['bias']:+.4f} | "
              f"{r['truth_mean']:.4f} | {r['estimate_mean']:.4f} |")
    return rows


def g_oracle(scenes: list[str], voxels=(0.25, 0.1)) -> list[dict]:
    from simlidar_mi.truth.evaluate import evaluate
    from simlidar_mi.truth.grid import grid_values
    rows = []
    for scene in scenes:
        for voxel in voxels:
            with tempfile.TemporaryDirectory() as tmp:
                run = evaluate(scene, Path(tmp) / "ev", voxel_m=voxel)
                import xarray as xr
                with xr.open_dataset(Path(tmp) / "ev" / "truth.nc") as t:
                    obs = run.estimates["beer_lambert"]["n_in"] >= run.summary["min_beams"]
                    leaf, plant = grid_values(t, "leaf_area_m2"), grid_values(t, "plant_area_m2")
                    leaf_share = float(leaf[obs].sum() / plant[obs].sum())
            s = run.summary
            r = {"scene": Path(scene).stem, "voxel_m": voxel, "G_leaf_canopy": s["G_leaf_canopy"],
                 "G_plant_canopy": s["G_plant_canopy"], "G_along": s["G_leaf_along_beams"], "leaf_share": leaf_share}
            for est in ("beer_lambert", "contact_mle"):
                for suffix in ("", "_Gcanopy", "_Gvoxel"):
                    v = run.get(est + suffix)
                    r[est + suffix] = {k: v[k] for k in ("r2", "rmse", "bias", "truth_mean", "coverage_area")}
            rows.append(r)
    print("\n| scene | voxel (m) | G leaf, canopy | G along beams (min–max) | leaf share | G plant, canopy |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        a = r["G_along"]
        print(f"| {r['scene']} | {r['voxel_m']} | {r['G_leaf_canopy']:.3f} | {a['min']:.3f}–{a['max']:.3f} | "
              f"{100 * r['leaf_share']:.0f} % | {r['G_plant_canopy']:.3f} |")
    print("\n| scene | voxel (m) | estimator | bias G = 0.5 | bias canopy G | bias voxel G | R² G = 0.5 | R² canopy G | R² voxel G |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        for est in ("beer_lambert", "contact_mle"):
            a, b, c = (r[est + x] for x in ("", "_Gcanopy", "_Gvoxel"))
            tm = a["truth_mean"]
            print(f"| {r['scene']} | {r['voxel_m']} | {est} | {100 * a['bias'] / tm:+.0f} % | {100 * b['bias'] / tm:+.0f} % | "
                  f"{100 * c['bias'] / tm:+.0f} % | {a['r2']:.3f} | {b['r2']:.3f} | {c['r2']:.3f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scene", action="append", default=None,
                    help="scenes for the end-to-end table (default: orchard_leafy, vineyard_vsp, apple_orchard)")
    ap.add_argument("--multi-scene", default=str(REPO / "scenes" / "orchard_lms511.toml"))
    ap.add_argument("--out", default=None)
    ap.add_argument("--only-g", action="store_true", help="only part 5 (the truth's G and the oracle runs)")
    args = ap.parse_args()
    print(machine())
    g_scenes = [str(REPO / "scenes" / f"{n}.toml") for n in ("orchard_leafy", "vineyard_vsp")]
    if args.only_g:
        out = {"G": g_oracle(g_scenes)}
        if args.out:
            Path(args.out).write_text(json.dumps(out, indent=1, default=float) + "\n")
        return
    out = {"G": g_oracle(g_scenes),"turbid": turbid(args.quick), "leaf_box": leaf_box(args.quick),
           "end_to_end": end_to_end(args.scene or [str(REPO / "scenes" / f"{n}.toml") for n in
                                                   ("orchard_leafy", "vineyard_vsp", "apple_orchard")], args.quick),
           "multi_return": multi_return(args.multi_scene, ["scan.dy_m=0.04", "sensor.beam_samples=8"])}
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
