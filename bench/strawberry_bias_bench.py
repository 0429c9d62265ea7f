"""Strawberry gap-fraction bias and extraction response under the plant-geometry readings
(issue 33; results go to BENCHMARKS.md §2 "Within-plant overlap" and docs/images).

    .venv/bin/python bench/strawberry_bias_bench.py [--png docs/images/strawberry_extraction_response.png]

For each candidate (a geometry reading × an extraction rule, as scene overrides on
``scenes/strawberry_plot.toml``) the scene's 16 replicate plots are rendered with the perspective
camera at 0/15/30°, and printed per candidate:

* the mean P0 over the four canopies per zenith and its bias against the measured means of
  ``scenes/strawberry_manifest.csv`` (Table 5's implied means), with the t-based 95 % interval of
  the virtual side (plot to plot; the measured side's spread is not printed by the paper);
* the extraction response at nadir: −ln P0 of each step over −ln P0 of the full canopy, beside the
  step's leaf area over the full canopy's.  The field's: leaf area from Table 4 (real canopy,
  1.116 / 0.900 / 0.724 / 0.527 m²) and P0 from the text's range of Figure 4 ("passing from 0.15
  to 0.4"), so −ln P0 falls to ln 0.4 / ln 0.15 = 0.483 at 0.472 of the leaf area.

The PNG plots −ln P0 (relative) against leaf area (relative) for every candidate beside the field.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))
from _machine import machine  # noqa: E402

from simlidar_mi.canopy.gapfraction import run_gapfraction  # noqa: E402
from simlidar_mi.canopy.manifest import read_manifest  # noqa: E402
from simlidar_mi.plants.strawberry_extraction import (PAPER_EXTRACTION_SIXTHS,  # noqa: E402
                                                      PAPER_TABLE4_REAL_M2, PAPER_TABLE4_VIRTUAL_M2)

SCENE = REPO / "scenes" / "strawberry_plot.toml"
MANIFEST = REPO / "scenes" / "strawberry_manifest.csv"
SIXTHS = ["strawberry.extraction_fractions=[" + ", ".join(repr(f) for f in PAPER_EXTRACTION_SIXTHS) + "]"]
PHI = ['strawberry.leaf.petiole_zenith="phi"']
THETA = ['strawberry.leaf.petiole_zenith="theta"']
#: Table 4's real leaf area instead of its virtual one: S (and its SD) × 1.116 / 1.241.
FIELD_AREA_SCALE = PAPER_TABLE4_REAL_M2[0] / PAPER_TABLE4_VIRTUAL_M2[0]
FIELD_AREA = [f"strawberry.leaf.area_mean_m2={13.025e-4 * FIELD_AREA_SCALE!r}",
              f"strawberry.leaf.area_sd_m2={5.031e-4 * FIELD_AREA_SCALE!r}"]
#: The field's leaves: 254 a sample area of 8 plants (the text's 44, 39, 44 are its sixths), of the
#: mean area that gives Table 4's real 1.116 m² (S the leaf over 2.836, its SD scaled alike).
FIELD_LEAVES = ["strawberry.leaves_per_plant_mean=31.75",
                f"strawberry.leaf.area_mean_m2={PAPER_TABLE4_REAL_M2[0] / 254 / 2.836!r}",
                f"strawberry.leaf.area_sd_m2={5.031e-4 * PAPER_TABLE4_REAL_M2[0] / 254 / 2.836 / 13.025e-4!r}"]
#: One two-row bed (rows 0.268 m apart), 8 plants a row; the inset window is its central strip.
BED = ["strawberry.rows=2", "strawberry.plants_per_row=8"]

#: (label, overrides).  Geometry: φ = 45 ± 5.6° as the petiole zenith (the earlier default) or
#: θ = 65 ± 45° (the hemisphere reading); extraction: Table 4's shares (default) or sixths.
CANDIDATES = [
    ("φ zenith (cone), sixths", PHI + SIXTHS),
    ("φ zenith (cone), Table 4 shares", PHI),
    ("θ zenith (hemisphere), sixths", THETA + SIXTHS),
    ("θ zenith (hemisphere), Table 4 shares", THETA),
    ("θ zenith, random azimuths (divergence SD 360°), Table 4 shares",
     THETA + ["strawberry.leaf.phi_sd_deg=360.0"]),
    # Leaf per metre of bed and the image (issue 33 follow-up), all θ zenith, Table 4 shares:
    ("θ, leaf area of Table 4's real canopy (S × 1.116/1.241)", THETA + FIELD_AREA),
    ("θ, field's leaves: 31.75 a plant of 43.9 cm² (254 a sample area of 8 plants)", THETA + FIELD_LEAVES),
    ("θ, S as printed in metres (0.001 ± 0.001 m²)",
     THETA + ["strawberry.leaf.area_mean_m2=0.001", "strawberry.leaf.area_sd_m2=0.001"]),
    ("θ, S' the two laterals together (leaf = 1.918 S)", THETA + ["strawberry.leaf.lateral_area_ratio=0.459"]),
    ("θ, one two-row bed (8 plants a row), window its central strip", THETA + BED),
    ("θ, two-row bed and Table 4's real leaf area", THETA + BED + FIELD_AREA),
    ("φ zenith (cone), two-row bed", PHI + BED),
    ("θ, two-row bed and the field's leaves (31.75 a plant of 43.9 cm²)", THETA + BED + FIELD_LEAVES),
    ("θ as the petiole's elevation from the horizontal (zenith 90° − θ)",
     THETA + ["strawberry.leaf.theta_mean_deg=25.0"]),
]

FIELD_SHARES = np.asarray(PAPER_TABLE4_REAL_M2) / PAPER_TABLE4_REAL_M2[0]
FIELD_P0_ENDS = (0.15, 0.40)  # the text's range of Figure 4, full canopy and last extraction
#: Ground of 8 plants on Table 3's grid (2 rows × 4 plants, 0.268 m × 0.227 m each): the plant count
#: that gives Table 4's virtual 1.241 m² with Table 3's leaves (8 × 42 × 36.94 cm² = 1.2412 m²).
BED_M2 = 8 * 0.268 * 0.227
FIELD_BED_LAI = PAPER_TABLE4_REAL_M2[0] / BED_M2
PAPER_BIAS_0 = 0.007  # Table 5, 0°


def paper_virtual_g_omega(mean_p0: float) -> float:
    """G·Ω that makes Beer's law over Table 4's virtual LAIs (on the 8 plants' bed) average to mean_p0."""
    lai = np.asarray(PAPER_TABLE4_VIRTUAL_M2) / BED_M2
    lo, hi = 0.05, 3.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.exp(-mid * lai).mean() > mean_p0 else (lo, mid)
    return 0.5 * (lo + hi)


def t975(df: int) -> float:
    from scipy import stats  # noqa: PLC0415
    return float(stats.t.ppf(0.975, df))


def run(label: str, extra: list[str], zens) -> dict:
    t = time.perf_counter()
    r = run_gapfraction(SCENE, None, ['gapfraction.cameras=["perspective"]',
                                      f"gapfraction.zeniths_deg={list(zens)}", *extra])
    secs = time.perf_counter() - t
    # p0[rep, zenith, step], area[rep, step]
    steps = sorted({im.step for im in r.replicate_images[0]})
    p0 = np.array([[[next(im.p0 for im in rep if im.camera.zenith_deg == z and im.step == s)
                     for s in steps] for z in zens] for rep in r.replicate_images])
    area = np.array([[next(im.leaf_area_m2 for im in rep if im.step == s) for s in steps]
                     for rep in r.replicate_images])
    lai = np.array([next(im.lai for im in rep if im.step == 0) for rep in r.replicate_images])
    return {"label": label, "p0": p0, "area": area, "lai": lai, "seconds": secs}


def table(results, measured, zens) -> str:
    head = ("| candidate | P0 at 0°, steps 0/1/2/3 | mean P0 0° / 15° / 30° | bias 0° / 15° / 30° "
            "(95 % CI, plot to plot) | leaf area steps 1/2/3 (of step 0) | −ln P0 at 0°, steps 1/2/3 "
            "(of step 0) | G·Ω at 0°, step 3 over step 0 | LAI of the planted area, step 0 | G·Ω at 0°, "
            "step 0 (−ln P0 / LAI) | seconds |")
    rows = [head, "|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        p0, area = res["p0"], res["area"]
        n = p0.shape[0]
        per_plot = p0.mean(2)                         # [rep, zenith] step mean
        means = per_plot.mean(0)
        half = t975(n - 1) * per_plot.std(0, ddof=1) / math.sqrt(n)
        bias = [m - measured[z] for m, z in zip(means, zens)]
        mp0 = p0.mean(0)[0]                           # nadir, per step (mean over plots)
        a = area.mean(0)
        lnr = np.log(mp0) / math.log(mp0[0])
        # G·Ω = −ln P0 / LAI: its change from step 0 to 3 is the −ln P0 ratio over the area ratio
        rows.append(
            f"| {res['label']} | " + " / ".join(f"{v:.3f}" for v in mp0) + " | "
            + " / ".join(f"{m:.3f}" for m in means) + " | "
            + " / ".join(f"{b:+.3f} ({b - h:+.3f}…{b + h:+.3f})" for b, h in zip(bias, half)) + " | "
            + " / ".join(f"{v:.3f}" for v in a[1:] / a[0]) + " | "
            + " / ".join(f"{v:.3f}" for v in lnr[1:]) + " | "
            + f"×{(lnr[-1] / (a[-1] / a[0])):.3f} | {res['lai'].mean():.2f} | "
            + f"{-math.log(mp0[0]) / res['lai'].mean():.3f} | {res['seconds']:.0f} |")
    field = (f"| field (Table 4 real leaf area; P0 {FIELD_P0_ENDS[0]} → {FIELD_P0_ENDS[1]} from the text) "
             "| 0.15 / – / – / 0.40 | 0.270 / 0.265 / 0.275 | – | "
             + " / ".join(f"{v:.3f}" for v in FIELD_SHARES[1:]) + " | – / – / "
             + f"{math.log(FIELD_P0_ENDS[1]) / math.log(FIELD_P0_ENDS[0]):.3f} | "
             + f"×{(math.log(FIELD_P0_ENDS[1]) / math.log(FIELD_P0_ENDS[0])) / FIELD_SHARES[-1]:.3f} | "
             + f"{FIELD_BED_LAI:.2f} | {-math.log(FIELD_P0_ENDS[0]) / FIELD_BED_LAI:.3f} | – |")
    rows.append(field)
    k = paper_virtual_g_omega(measured[zens[0]] + PAPER_BIAS_0)
    rows.append(f"| the paper's virtual canopy (Table 4 virtual leaf area on the 8 plants' bed; Beer's law "
                f"through its mean P0 at 0°, {measured[zens[0]] + PAPER_BIAS_0:.3f} = measured + Table 5's bias) | "
                + " / ".join(f"{math.exp(-k * v / BED_M2):.3f}" for v in PAPER_TABLE4_VIRTUAL_M2)
                + " | – | – | – | – | – | " + f"{PAPER_TABLE4_VIRTUAL_M2[0] / BED_M2:.2f} | {k:.3f} | – |")
    return "\n".join(rows)


def plot(results, path: Path) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    fig, ax = plt.subplots(figsize=(7.6, 6.0), dpi=110)
    ax.plot([0, 1], [0, 1], color="0.6", ls="--", lw=1, label="Beer's law (G·Ω constant)")
    colours = plt.get_cmap("tab20").colors
    for i, res in enumerate(results):
        mp0 = res["p0"].mean(0)[0]
        a = res["area"].mean(0)
        ax.plot(a / a[0], np.log(mp0) / math.log(mp0[0]), marker="os^Dv<>"[i % 7], ms=4, lw=1.2,
                color=colours[(2 * i) % 20 + (2 * i) // 20], label=res["label"])
    fr = math.log(FIELD_P0_ENDS[1]) / math.log(FIELD_P0_ENDS[0])
    ax.plot([1.0, FIELD_SHARES[-1]], [1.0, fr], marker="s", ms=8, color="k", lw=2,
            label="field: Table 4 leaf area, P0 0.15 → 0.40 (text)")
    ax.set_xlim(0.4, 1.02)
    ax.set_ylim(0.4, 1.02)
    ax.set_xlabel("leaf area / leaf area of the full canopy")
    ax.set_ylabel("−ln P0 / −ln P0 of the full canopy (nadir)")
    ax.set_title("Strawberry plots: gap fraction's response to leaf removal", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--png", type=Path, default=None)
    ap.add_argument("--only", type=int, nargs="*", default=None, help="candidate indices")
    args = ap.parse_args()
    measured = {r.zenith_deg: r.p0_measured for r in read_manifest(MANIFEST)}
    zens = sorted(measured)
    cands = CANDIDATES if args.only is None else [CANDIDATES[i] for i in args.only]
    results = []
    for label, extra in cands:
        results.append(run(label, extra, zens))
        print(f"done {label}: {results[-1]['seconds']:.0f} s", file=sys.stderr, flush=True)
    print(f"Machine: {machine()}\n")
    print(table(results, measured, zens))
    if args.png is not None:
        plot(results, args.png)


if __name__ == "__main__":
    main()
