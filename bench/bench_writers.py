"""PNG writers before and after issue #8 (results go to BENCHMARKS.md).

    .venv/bin/python bench/bench_writers.py [--beams 1000000 10000000] [--masks 24] [--repeat 3]

1. Range PNG (``scan.png``): the matplotlib figure of commit 0d296f5 (kept below as
   :func:`old_plot_scan_png`, a verbatim copy) against :func:`simlidar_mi.io.plots.plot_scan_png`
   (lookup table + Pillow), at each beam count. The beams are a real tractor scan of
   ``scenes/simlidar_table3_7x4.toml`` (4196 × 601, the paper's 7×4 row), its rows repeated
   or cut to the beam count (M = 601 angles). Each case runs in a fresh process: seconds to
   import the writer, seconds to write, the process's peak RSS, and the peak above the RSS
   with the scan loaded (the writer's own memory; the peak is reset with /proc/self/clear_refs
   once the scan is in memory). The fastest of ``--repeat`` processes is kept.
2. Gap-fraction mask PNGs: the RGB writer of 0d296f5 (kept below) against the palette
   writer, on the strawberry experiment's masks (``scenes/strawberry_plot.toml``, replicate
   0: the images the experiment writes), milliseconds a mask, and on one 4096² mask made
   by tiling them.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
OUT = REPO / "bench" / "out"
SCAN_NPZ = OUT / "writers_scan.npz"


# --- the writers as they were at 0d296f5 (verbatim but for the imports) -----------------

def old_plot_scan_png(result, path, title: str = ""):
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from simlidar_mi.geometry import CLASS_CODES  # noqa: PLC0415
    from simlidar_mi.io.atomic import atomic_file  # noqa: PLC0415
    p = result.pattern
    img = np.ma.masked_where(~result.vegetation(), result.range_m).T  # (M, N): angle up
    rows, ang = p.row_coord, p.col_angle_deg
    half_row = 0.5 * (rows[1] - rows[0]) if len(rows) > 1 else 0.5
    extent = [rows[0] - half_row, rows[-1] + half_row,
              ang[0] - p.col_span_deg / 2, ang[-1] + p.col_span_deg / 2]
    width = 10 if p.n_rows > p.n_cols else 7
    fig, ax = plt.subplots(figsize=(width, 4.8), dpi=120)
    backdrop = np.where(result.cls.T == CLASS_CODES["ground"], 0.85, 1.0)
    ax.imshow(np.dstack([backdrop, backdrop, backdrop]) *
              np.array([1.0, 0.93, 0.8]), origin="lower", extent=extent, aspect="auto",
              interpolation="nearest")
    im = ax.imshow(img, origin="lower", extent=extent, aspect="auto", cmap="viridis",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="range to vegetation (m)")
    ax.set_xlabel(p.row_label)
    ax.set_ylabel(p.col_label)
    counts = result.class_counts()
    ax.set_title(title or f"{p.n_rows}×{p.n_cols} beams: {counts['wood'] + counts['leaf']} "
                          f"vegetation, {counts['ground']} ground, {counts['escape']} escape")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return Path(path)


_DIM_GREY = np.array([128, 128, 128], dtype=np.float64)


def old_render_mask_rgb(mask, window=None, *, foreground=(0, 128, 0), background=(255, 255, 255),
                        outline=(255, 0, 255)):
    m = np.asarray(mask).astype(bool, copy=False)
    h, w = m.shape
    fg = np.asarray(foreground, dtype=np.float64)
    bg = np.asarray(background, dtype=np.float64)
    rgb = np.where(m[..., None], fg, bg)
    if window is not None:
        x0, y0, x1, y1 = (int(v) for v in window)
        inside = np.zeros((h, w), dtype=bool)
        inside[y0:y1, x0:x1] = True
        rgb[~inside] = 0.5 * rgb[~inside] + 0.5 * _DIM_GREY
        t = max(1, round(min(h, w) / 400))
        t = min(t, (x1 - x0 + 1) // 2, (y1 - y0 + 1) // 2) or 1
        col = np.asarray(outline, dtype=np.float64)
        rgb[y0:y0 + t, x0:x1] = col
        rgb[y1 - t:y1, x0:x1] = col
        rgb[y0:y1, x0:x0 + t] = col
        rgb[y0:y1, x1 - t:x1] = col
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def old_write_mask_png(path, mask, window=None):
    from PIL import Image  # noqa: PLC0415

    from simlidar_mi.io.png import _save_png  # noqa: PLC0415  (unchanged since 0d296f5)
    return _save_png(path, Image.fromarray(old_render_mask_rgb(mask, window)))


# --- range PNG: one case per process ----------------------------------------------------

def _hwm_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _rss_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def range_case(which: str, beams: int, out: Path) -> dict:
    """Load the scan, cut/repeat it to ``beams``, then import and run one writer."""
    from simlidar_mi.lidar.platforms import BeamPattern, elevation_dirs  # noqa: PLC0415
    from simlidar_mi.lidar.scan import ScanResult  # noqa: PLC0415
    d = np.load(SCAN_NPZ)
    n0, m = d["range_m"].shape
    n = max(1, beams // m)
    idx = np.arange(n) % n0
    rng, cls = np.ascontiguousarray(d["range_m"][idx]), np.ascontiguousarray(d["cls"][idx])
    dy, theta = float(d["dy_m"]), d["theta_deg"]
    y = float(d["y0_m"]) + dy * np.arange(n)
    origins = np.stack([np.zeros(n), y, np.zeros(n)], axis=1)
    pat = BeamPattern("tractor", origins, np.zeros(n), theta, elevation_dirs(theta),
                      np.array([0.0, dy, 0.0]), float(d["dtheta_deg"]), 0, y, "scanner position y (m)",
                      "beam elevation θ (°)")
    res = ScanResult(None, rng, cls, None, None, np.zeros(3), pattern=pat)
    del d
    assert "matplotlib" not in sys.modules
    base = _rss_mb()
    try:  # reset the peak to the current RSS: the writer's own memory is what is measured
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        reset = True
    except OSError:
        reset = False
    t0 = time.perf_counter()
    if which == "old":
        import matplotlib.pyplot  # noqa: F401, PLC0415
        write = old_plot_scan_png
    else:
        from simlidar_mi.io.plots import plot_scan_png as write  # noqa: PLC0415
    t1 = time.perf_counter()
    write(res, out, title="simlidar_table3_7x4: range image")  # run_scan passes a title too
    t2 = time.perf_counter()
    return {"which": which, "beams": int(n * m), "N": int(n), "M": int(m), "import_s": t1 - t0,
            "write_s": t2 - t1, "peak_rss_mb": _hwm_mb(), "base_rss_mb": base, "peak_reset": reset,
            "matplotlib_imported": "matplotlib" in sys.modules, "png_bytes": out.stat().st_size}


def make_scan() -> None:
    """The 7×4 orchard's tractor scan (2.5 M beams), kept as range and class arrays."""
    from simlidar_mi.config import load_scene  # noqa: PLC0415
    from simlidar_mi.lidar.scan import scan  # noqa: PLC0415
    from simlidar_mi.lidar.survey import build, generate, scan_patterns  # noqa: PLC0415
    cfg = load_scene(REPO / "scenes" / "simlidar_table3_7x4.toml")
    geo = generate(cfg)
    pats = scan_patterns(cfg, *geo.bounds_m(), geo.near_x_m)
    res = scan(build(cfg, geo, pats), pats[0], cfg["scene"]["variant"])
    s = res.settings
    OUT.mkdir(exist_ok=True)
    np.savez(SCAN_NPZ, range_m=res.range_m, cls=res.cls, dy_m=s.dy_m, y0_m=float(s.y_m[0]),
             theta_deg=s.theta_deg, dtheta_deg=s.dtheta_deg)


# --- masks --------------------------------------------------------------------------------

def mask_rows(n_masks: int) -> list[str]:
    from simlidar_mi.canopy.gapfraction import run_gapfraction  # noqa: PLC0415
    from simlidar_mi.io.png import read_mask_png, write_mask_png  # noqa: PLC0415
    run = run_gapfraction(REPO / "scenes" / "strawberry_plot.toml", None, replicates=1)
    ims = run.images[:n_masks]
    masks = [(im.mask(), im.window.box_px) for im in ims]
    h, w = masks[0][0].shape
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for label, cases in ((f"{len(masks)} masks of {w}×{h} (the experiment's)", masks),
                             ("one 4096×4096 mask (tiled)", [(np.tile(masks[0][0], (-(-4096 // h), -(-4096 // w)))
                                                             [:4096, :4096], (200, 200, 3896, 3896))])):
            res = {}
            for which, write in (("old", old_write_mask_png), ("new", write_mask_png)):
                write(tmp / "warm.png", *cases[0])
                t = time.perf_counter()
                for j, (m, win) in enumerate(cases):
                    write(tmp / f"{which}{j}.png", m, win)
                res[which] = ((time.perf_counter() - t) / len(cases),
                              sum((tmp / f"{which}{j}.png").stat().st_size for j in range(len(cases))) / len(cases))
            same = all(np.array_equal(read_mask_png(tmp / f"new{j}.png"), m) for j, (m, _) in enumerate(cases))
            o, nw = res["old"], res["new"]
            rows.append(f"| {label} | {1e3 * o[0]:.1f} | {o[1] / 1024:.0f} | {1e3 * nw[0]:.1f} | "
                        f"{nw[1] / 1024:.0f} | {o[0] / nw[0]:.1f}× | {'yes' if same else 'NO'} |")
            print(rows[-1], file=sys.stderr)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--beams", type=int, nargs="+", default=[1_000_000, 10_000_000])
    ap.add_argument("--masks", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes per range case (fastest kept)")
    ap.add_argument("--case", nargs=3, metavar=("WHICH", "BEAMS", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(range_case(a.case[0], int(a.case[1]), Path(a.case[2]))))
        return
    from _machine import machine  # noqa: PLC0415
    if not SCAN_NPZ.exists():
        make_scan()
    lines = [f"**Machine:** {machine()}", "",
             "Range PNG (`scan.png`), each case in a fresh process:", "",
             "| beams (N×M) | writer | import s | write s | total s | peak RSS MB | above the loaded scan MB | PNG kB |",
             "|---|---|---|---|---|---|---|---|"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    with tempfile.TemporaryDirectory() as tmp:
        for beams in a.beams:
            got = {}
            for which in ("old", "new"):
                out = Path(tmp) / f"{which}_{beams}.png"
                runs = []
                for _ in range(a.repeat):  # the fastest of fresh processes: the machine is shared
                    p = subprocess.run([sys.executable, __file__, "--case", which, str(beams), str(out)],
                                       capture_output=True, text=True, env=env, check=True)
                    runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
                r = got[which] = min(runs, key=lambda q: q["import_s"] + q["write_s"])
                name = "matplotlib (0d296f5)" if which == "old" else "LUT + Pillow"
                lines.append(f"| {r['beams']:,} ({r['N']}×{r['M']}) | {name} | {r['import_s']:.2f} | "
                             f"{r['write_s']:.2f} | {r['import_s'] + r['write_s']:.2f} | {r['peak_rss_mb']:.0f} | "
                             f"{r['peak_rss_mb'] - r['base_rss_mb']:.0f} | {r['png_bytes'] / 1024:.0f} |")
                print(lines[-1], file=sys.stderr)
            o, nw = got["old"], got["new"]
            lines.append(f"| | **ratio old/new** | | {o['write_s'] / nw['write_s']:.1f}× | "
                         f"{(o['import_s'] + o['write_s']) / (nw['import_s'] + nw['write_s']):.1f}× | | "
                         f"{(o['peak_rss_mb'] - o['base_rss_mb']) / max(nw['peak_rss_mb'] - nw['base_rss_mb'], 1):.1f}× | |")
            assert not nw["matplotlib_imported"], "the new writer imported matplotlib"
    lines += ["", "Gap-fraction mask PNGs (same process, after one warm-up write; the writers fsync):", "",
              "| masks | RGB (0d296f5) ms/mask | kB | palette ms/mask | kB | ratio | reads back equal |",
              "|---|---|---|---|---|---|---|"]
    lines += mask_rows(a.masks)
    text = "\n".join(lines)
    OUT.mkdir(exist_ok=True)
    (OUT / "writers_bench.md").write_text(text + "\n", encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
