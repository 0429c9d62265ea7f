"""What accuracy costs in time for the tractor LiDAR scan (results go to BENCHMARKS.md).

    .venv/bin/python bench/bench_scan.py [--quick] [--only reps|table3|table3-cover|linear|sweep]
                                         [--table3-placement fixed|bisect]

Tables (markdown on stdout, also bench/out/scan_bench.md):
1. representation (mesh k = 6, 8, 12, 24; cylinder; linearcurve) × footprint P = 0..3 on
   the 7-iteration, 4-tree orchard: build s, scan s, beams/s, A_IM, and the error against
   the float64 reference (simlidar_mi.lidar.reference) on a sample of ≥ 100k beams;
2. SIMLIDAR Table 3 (iterations 4–7 × 1–4 trees): branches, N×M, the share of A_PR the
   sweep covers, seconds per stage and end to end, peak RSS (each row in a fresh process),
   next to the paper's minutes.  Every row fires the paper's beam count: its N = N×M / 601
   positions (Δy = 2 mm, gap 0, a y span of N·Δy centred on the trees) and M = 601 angles.
   The Table 3 reading (``--table3-placement fixed``, default): the §5 scanner x0 = 1 m and
   one fixed sweep of 601 beams, θ from −75° to +75° (:func:`table3_fixed`), the same for
   every row, as the paper's one x0 and 601 angles per row suggest.  The other reading
   (``bisect``): eq. 8's near-side limits with the scanner moved per row to the x0 that
   gives M = 601 (:func:`table3_placement`).  The 7×4 row is run again with the paper's dot
   matrix (P = 2, hit rule "any");
2b. (``--only table3-cover``) both readings side by side without scanning: N×M against the
   paper's and the share of A_PR inside the sweep (in y: the N·Δy span; in θ: the limits);
3. scan time against beam count (linearity) at P = 0;
4. eq. 8's near vs far reading and the hit rules: M, A_IM and the share of A_PR swept.
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
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

from simlidar_mi.config import load_scene  # noqa: E402
from simlidar_mi.lidar.reference import compare, reference_scan  # noqa: E402
from simlidar_mi.lidar.scan import resolve_settings, scan  # noqa: E402
from simlidar_mi.lidar.survey import build, generate  # noqa: E402

SCENE = REPO / "scenes" / "simlidar_table3_7x4.toml"
PAPER_TABLE3 = {  # (iterations, trees): (branches, N×M, minutes) — SIMLIDAR Table 3
    (4, 1): (360, 558930, 2), (5, 1): (1497, 561935, 4), (6, 1): (5564, 504840, 11),
    (7, 1): (15168, 579965, 26), (4, 2): (928, 931550, 6), (5, 2): (3056, 1063770, 12),
    (6, 2): (10415, 1039730, 31), (7, 2): (29779, 1319195, 96), (4, 3): (1011, 1271115, 7),
    (5, 3): (5112, 1550580, 24), (6, 3): (15229, 1562600, 61), (7, 3): (48250, 1571615, 174),
    (4, 4): (2064, 1634720, 15), (5, 4): (4991, 2482130, 32), (6, 4): (20020, 2404000, 135),
    (7, 4): (44658, 2467105, 210),
}


def timed(fn, *a, **k):
    t = time.perf_counter()
    out = fn(*a, **k)
    return out, time.perf_counter() - t


def representations(quick: bool) -> str:
    reps = [("mesh", 6), ("mesh", 8), ("mesh", 12), ("mesh", 24), ("cylinder", 8), ("linearcurve", 8)]
    footprints = [0, 1] if quick else [0, 1, 2, 3]
    cfg = load_scene(SCENE)
    geo = generate(cfg)
    lo, hi = geo.bounds_m()
    rows = ["| representation | P | build s | scan s | beams/s | A_IM m² | ref beams | "
            "hit/miss disagree % | false hit % | false miss % | abs Δrange median mm | abs Δrange p99 mm |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    refs = {}
    for P in footprints:
        settings = resolve_settings({**cfg["scan"], "footprint": P}, cfg["ground"], lo, hi)
        # ≥ 100k beams: evenly spaced sweeps across the whole row.
        n_pos = int(np.ceil(100_000 / settings.n_angles))
        positions = np.unique(np.linspace(0, settings.n_positions - 1, n_pos).round().astype(int))
        ref, t_ref = timed(reference_scan, geo.branches, settings, positions)
        refs[P] = (settings, positions, ref)
        print(f"  reference P={P}: {len(positions) * settings.n_angles} beams in {t_ref:.1f} s",
              file=sys.stderr)
    for rep, k in reps:
        cfg_r = load_scene(SCENE, [f'scene.representation="{rep}"', f"scene.facets={k}"])
        built, t_build = timed(build, cfg_r, geo)
        for P in footprints:
            settings, positions, ref = refs[P]
            scan(built, settings)  # warm the kernel cache: timings are steady-state
            res, t_scan = timed(scan, built, settings)
            st = compare(res.range_m[positions], res.cls[positions], ref, settings.escape_m)
            name = f"mesh k={k}" if rep == "mesh" else rep
            rows.append(f"| {name} | {P} | {t_build:.2f} | {t_scan:.3f} | {settings.n_beams / t_scan / 1e6:.1f} M | "
                        f"{res.impacted_area_m2():.4f} | {st['n_beams']} | {st['disagree_pct']:.3f} | "
                        f"{st['false_hit_pct']:.3f} | {st['false_miss_pct']:.3f} | "
                        f"{1e3 * st['drange_median_m']:.3f} | {1e3 * st['drange_p99_m']:.2f} |")
            print(rows[-1], file=sys.stderr)
        del built
    s0 = refs[0][0]
    return (f"Scene `{SCENE.relative_to(REPO)}`: {len(geo.branches)} branches, N×M = "
            f"{s0.n_positions}×{s0.n_angles} = {s0.n_beams} beams, (P+1)² sub-beams each.\n\n" + "\n".join(rows))


ROW_SCRIPT = r"""
import json, sys, time, resource
t0 = time.perf_counter()
from simlidar_mi.lidar.survey import run_scan
from simlidar_mi.config import load_scene
cfg = load_scene(sys.argv[1], sys.argv[3:])
run = run_scan(cfg, sys.argv[2], write_las=False, write_png=False)
m = run.measures
print(json.dumps({"n_branches": m["n_branches"], "N": m["N"], "M": m["M"], "seconds": m["seconds"],
                  "swept": m.get("A_PR_swept_share"), "theta_min_deg": m["scan"]["theta_min_deg"],
                  "wall": time.perf_counter() - t0,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


PAPER_M = 601  # every N×M of Table 3 is a multiple of 601
# The Table 3 reading (ours: the paper gives one x0 and 601 angles, not its θ limits): the §5
# scanner x0 = 1 m and a fixed 150° sweep.  Eq. 7's M = Int((θ_max − θ_min)/Δθ) is 601 for
# θ_max − θ_min = 150.25°; beam centres θ_1 + (k − 1)Δθ run from −75° to +75°.
TABLE3_SWEEP = {"x0_m": 1.0, "theta_min_deg": -75.0, "theta_max_deg": 75.25}


def _table3_y(cfg, geo, n_positions: int) -> tuple[float, float]:
    """(y_start, y_end) of N = ``n_positions`` sweeps Δy apart, centred on the trees (plus half
    a step against rounding in eq. 6)."""
    lo, hi = geo.bounds_m()
    dy = cfg["scan"]["dy_m"]
    y0 = float(0.5 * (lo[1] + hi[1]) - n_positions * dy / 2)
    return y0, float(y0 + (n_positions + 0.5) * dy)


def table3_fixed(cfg, geo, n_positions: int) -> list[str]:
    """Overrides for the Table 3 reading: N = ``n_positions`` sweeps centred on the trees, the
    scanner at x0 = 1 m, θ from −75° to +75° in 601 beams (:data:`TABLE3_SWEEP`)."""
    y0, y1 = _table3_y(cfg, geo, n_positions)
    over = [f"scan.x0_m={TABLE3_SWEEP['x0_m']}", f"scan.y_start_m={y0!r}", f"scan.y_end_m={y1!r}",
            f"scan.theta_min_deg={TABLE3_SWEEP['theta_min_deg']}",
            f"scan.theta_max_deg={TABLE3_SWEEP['theta_max_deg']}"]
    lo, hi = geo.bounds_m()
    got = resolve_settings({**cfg["scan"], **TABLE3_SWEEP, "y_start_m": y0, "y_end_m": y1},
                           cfg["ground"], lo, hi, None, geo.near_x_m)
    assert (got.n_positions, got.n_angles) == (n_positions, PAPER_M), (got.n_positions, got.n_angles)
    return over


def table3_placement(cfg, geo, n_positions: int, n_angles: int = PAPER_M) -> list[str]:
    """Overrides that make ``cfg`` fire ``n_positions`` × ``n_angles`` beams with eq. 8's limits.

    N: a y span of N·Δy (plus half a step against rounding) centred on the trees.  M: eq. 8
    (near side) widens the sweep as the scanner nears the wood, so M grows with x0; the x0
    returned is the middle of the interval where M = ``n_angles`` (bisection on
    :func:`resolve_settings` itself), rounded to 0.1 mm."""
    lo, hi = geo.bounds_m()
    sc, dy = cfg["scan"], cfg["scan"]["dy_m"]
    y0, y1 = _table3_y(cfg, geo, n_positions)
    base = {**sc, "y_start_m": y0, "y_end_m": y1,
            "theta_min_deg": None, "theta_max_deg": None, "theta_limits_side": "near"}

    def m(x0: float) -> int:
        return resolve_settings({**base, "x0_m": x0}, cfg["ground"], lo, hi, None, geo.near_x_m).n_angles

    near = geo.near_x_m(y0 - dy / 2, y0 + (n_positions - 0.5) * dy)

    def last_x0_with_m_at_most(target: int) -> float:
        a, b = near - 50.0, near - 1e-9
        for _ in range(80):
            mid = 0.5 * (a + b)
            a, b = (a, mid) if m(mid) > target else (mid, b)
        return a
    x0 = round(0.5 * (last_x0_with_m_at_most(n_angles - 1) + last_x0_with_m_at_most(n_angles)), 4)
    over = [f"scan.x0_m={x0}", f"scan.y_start_m={y0!r}", f"scan.y_end_m={base['y_end_m']!r}",
            'scan.theta_limits_side="near"']
    got = resolve_settings({**base, "x0_m": x0}, cfg["ground"], lo, hi, None, geo.near_x_m)
    assert (got.n_positions, got.n_angles) == (n_positions, n_angles), (got.n_positions, got.n_angles)
    return over


PLACEMENTS = {"fixed": table3_fixed, "bisect": table3_placement}


def table3_scene(placement: str) -> Path:
    """The Table 3 scene for a reading: as shipped (the fixed sweep), or for ``bisect`` a copy
    in bench/out without its θ limits, so that eq. 8 derives them."""
    if placement == "fixed":
        return SCENE
    import re  # noqa: PLC0415
    path = REPO / "bench" / "out" / "table3" / f"{SCENE.stem}_eq8.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = re.sub(r"(?m)^theta_(min|max)_deg\s*=.*\n", "", SCENE.read_text())
    path.write_text(text.replace('name = "simlidar_table3_7x4"', 'name = "simlidar_table3_7x4_eq8"'))
    return path


def _table3_combos(quick: bool) -> list[tuple[int, int, int]]:
    combos = [(it, n, 0) for n in (1, 2, 3, 4) for it in (4, 5, 6, 7)] + [(7, 4, 2)]
    return [(4, 1, 0), (7, 4, 0), (7, 4, 2)] if quick else combos


def table3(quick: bool, placement: str = "fixed") -> str:
    rows = ["| iterations | trees | P, hit rule | branches (paper) | branches | N×M (paper) | N×M | x0 m | "
            "nearest wood m | θ_1 … θ_M ° | A_PR swept % | generate s | build s | scan s | write EXR s | "
            "end to end s | process s | peak RSS MB | paper min |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    out = REPO / "bench" / "out" / "table3"
    scene = table3_scene(placement)
    for it, n, P in _table3_combos(quick):
        pb, pnm, pmin = PAPER_TABLE3[(it, n)]
        grow = [f"orchard.tree.iterations={it}", f"orchard.n_trees={n}"]
        cfg = load_scene(scene, grow)
        geo = generate(cfg)
        place = PLACEMENTS[placement](cfg, geo, pnm // PAPER_M)
        x0 = float(place[0].split("=")[1])
        rule = [f"scan.footprint={P}", f'scan.hit_rule="{"any" if P else "fraction"}"']
        args = [sys.executable, "-c", ROW_SCRIPT, str(scene), str(out / f"{it}x{n}P{P}"), *grow, *place, *rule]
        t = time.perf_counter()
        proc = subprocess.run(args, capture_output=True, text=True, cwd=REPO)
        wall = time.perf_counter() - t
        if proc.returncode:
            raise SystemExit(proc.stderr)
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        s = r["seconds"]
        e2e = sum(s.values())
        y0 = float(place[1].split("=")[1])
        near = geo.near_x_m(y0 - 0.001, y0 + (pnm // PAPER_M) * 0.002)
        th0 = r["theta_min_deg"]
        rows.append(f"| {it} | {n} | {P}, {'any' if P else '—'} | {pb} | {r['n_branches']} | {pnm:,} | "
                    f"{r['N'] * r['M']:,} | {x0:.4f} | {near - x0:.3f} | {th0:.2f} … {th0 + (r['M'] - 1) * 0.25:.2f} | "
                    f"{100 * r['swept']:.1f} | {s['generate']:.2f} | {s['build']:.2f} | {s['scan']:.2f} | "
                    f"{s['write']:.2f} | {e2e:.2f} | {wall:.2f} | {r['rss_mb']:.0f} | {pmin} |")
        print(rows[-1], file=sys.stderr)
    return "\n".join(rows)


def table3_cover() -> str:
    """Both Table 3 readings per row, without scanning: N×M and the share of A_PR swept."""
    from simlidar_mi.lidar.survey import scan_patterns  # noqa: PLC0415
    rows = ["| iterations | trees | N×M (paper) | fixed: x0 m, θ_1 … θ_M °, N×M | fixed: A_PR swept % | "
            "bisect: x0 m, θ_1 … θ_M °, N×M | bisect: A_PR swept % | all y, fixed sweep: swept % |",
            "|---|---|---|---|---|---|---|---|"]
    for it, n, _ in _table3_combos(False)[:-1]:
        pnm = PAPER_TABLE3[(it, n)][1]
        grow = [f"orchard.tree.iterations={it}", f"orchard.n_trees={n}"]
        geo = generate(load_scene(SCENE, grow))
        lo, hi = geo.bounds_m()
        cells = []
        for name in ("fixed", "bisect"):
            scene = table3_scene(name)
            over = PLACEMENTS[name](load_scene(scene, grow), geo, pnm // PAPER_M)
            (s,) = scan_patterns(load_scene(scene, grow + over), lo, hi, geo.near_x_m)
            assert s.n_positions * s.n_angles == pnm
            th = s.theta_deg
            cells += [f"{s.x0_m:.4f}, {th[0]:.2f} … {th[-1]:.2f}, {s.n_positions}×{s.n_angles}",
                      f"{100 * s.swept_share(geo.branches):.1f}"]
        # the fixed sweep over the trees' whole y extent: what the angles alone leave out
        (whole,) = scan_patterns(load_scene(SCENE, grow + [f"scan.{k}={v}" for k, v in TABLE3_SWEEP.items()]),
                                 lo, hi, geo.near_x_m)
        rows.append(f"| {it} | {n} | {pnm:,} | " + " | ".join(cells)
                    + f" | {100 * whole.swept_share(geo.branches):.1f} |")
        print(rows[-1], file=sys.stderr)
    return "\n".join(rows)


def linearity() -> str:
    cfg = load_scene(SCENE)
    geo = generate(cfg)
    built = build(cfg, geo)
    lo, hi = geo.bounds_m()
    rows = ["| Δy m | Δθ ° | beams | scan s | beams/s | s per M beams |", "|---|---|---|---|---|---|"]
    for dy, dth in [(0.008, 0.5), (0.004, 0.5), (0.004, 0.25), (0.002, 0.25), (0.001, 0.25), (0.001, 0.125)]:
        st = resolve_settings({**cfg["scan"], "dy_m": dy, "dtheta_deg": dth}, cfg["ground"], lo, hi)
        scan(built, st)
        best = min(timed(scan, built, st)[1] for _ in range(3))
        rows.append(f"| {dy} | {dth} | {st.n_beams:,} | {best:.3f} | {st.n_beams / best / 1e6:.1f} M | "
                    f"{best / st.n_beams * 1e6:.4f} |")
        print(rows[-1], file=sys.stderr)
    return "\n".join(rows)


def sweep() -> str:
    """Eq. 8's two readings of Max(x), and the two hit rules, on the shipped orchard scenes."""
    from simlidar_mi.lidar.survey import run_scan  # noqa: PLC0415
    eq8 = table3_scene("bisect").relative_to(REPO)  # the Table 3 row with eq. 8's limits, not its fixed sweep
    cases = [("scenes/apple_orchard.toml", []), (eq8, ["scan.x0_m=0.709"]), (eq8, ["scan.x0_m=1.0"])]
    runs = [("near", 0, "fraction"), ("far", 0, "fraction"), ("near", 2, "fraction"), ("near", 2, "any"),
            ("far", 2, "any")]
    rows = ["| scene | x0 m | eq. 8 side | P, hit rule | θ_min … θ_max ° | N×M | A_PR m² | A_PR swept % | "
            "A_IM m² | A_IM_yz m² | A_PR / A_IM |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scene, extra in cases:
        for side, P, rule in runs:
            over = [*extra, f'scan.theta_limits_side="{side}"', f"scan.footprint={P}", f'scan.hit_rule="{rule}"']
            m = run_scan(load_scene(REPO / scene, over), None).measures
            sc = m["scan"]
            th1 = sc["theta_min_deg"] + (sc["n_angles"] - 1) * sc["dtheta_deg"]
            rows.append(f"| `{Path(scene).stem}` | {sc['x0_m']:g} | {side} | {P}, {rule if P else '—'} | "
                        f"{sc['theta_min_deg']:.2f} … {th1:.2f} | {m['N']}×{m['M']} | {m['A_PR_m2']:.4f} | "
                        f"{100 * m['A_PR_swept_share']:.1f} | {m['A_IM_m2']:.4f} | {m['A_IM_yz_m2']:.4f} | "
                        f"{m['A_PR_m2'] / m['A_IM_m2']:.3f} |")
            print(rows[-1], file=sys.stderr)
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer rows (smoke run)")
    ap.add_argument("--only", choices=["reps", "table3", "table3-cover", "linear", "sweep"])
    ap.add_argument("--table3-placement", choices=sorted(PLACEMENTS), default="fixed",
                    help="Table 3 reading: 'fixed' (x0 = 1 m, θ −75…+75°, default) or 'bisect' "
                         "(eq. 8 near side, x0 moved per row to give M = 601)")
    a = ap.parse_args()
    parts = [f"Machine: {machine()}  \nDate: {time.strftime('%Y-%m-%d')}  \n"
             f"Command: `.venv/bin/python bench/bench_scan.py{' --quick' if a.quick else ''}"
             f"{' --only ' + a.only if a.only else ''}"
             f"{' --table3-placement ' + a.table3_placement if a.table3_placement != 'fixed' else ''}`\n"]
    if a.only in (None, "table3"):
        parts.append("### SIMLIDAR Table 3 on Mitsuba 3\n\n" + table3(a.quick, a.table3_placement))
    if a.only in (None, "table3-cover"):
        parts.append("### Table 3: both readings, and the share of A_PR swept\n\n" + table3_cover())
    if a.only in (None, "reps"):
        parts.append("### Representation × footprint (7 iterations, 4 trees)\n\n" + representations(a.quick))
    if a.only in (None, "linear"):
        parts.append("### Scan time against beam count (default representation, P = 0)\n\n" + linearity())
    if a.only in (None, "sweep"):
        parts.append("### Eq. 8 near vs far side, and the hit rules\n\n" + sweep())
    text = "\n\n".join(parts) + "\n"
    out = REPO / "bench" / "out"
    out.mkdir(parents=True, exist_ok=True)
    (out / f"scan_bench{'_' + a.only if a.only else ''}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
