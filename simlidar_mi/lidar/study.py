"""SIMLIDAR's §5 study: many virtual orchards, their scans, and how A_PR and A_L follow A_IM.

The paper scanned 42 orchards (iterations 4–7, d_m 5/6/7 mm, 1 or 4 trees, pruning and
stochastic on/off) and fitted A_PR = 3.6166·A_IM (R² 0.70) and A_L = 10.812·A_IM
(R² 0.78).  :func:`run_study` runs the full factorial grid (or any list of overrides)
on a base scene, one orchard per task, with Dask as the engine (``workers`` > 1 runs
tasks in separate processes).  Every finished orchard is written at once to
``rows/<key>.json``, so an interrupted study resumes where it stopped.  Outputs:
``study.csv`` (one row per orchard), ``regression.json`` and ``correlations.png``.

Every orchard is scanned with the paper's hit test by default: a dot matrix of precision
P = 2 (3 × 3 sub-beams, footprint 2) and ``scan.hit_rule = "any"`` (§3.1: a beam hits
when any point of its dot matrix lies inside a branch).  ``hit_rule="fraction"`` keeps
the scene's own footprint and weights each beam by its share of sub-beams that hit.
"""
from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import load_scene
from ..errors import ConfigError
from ..io.atomic import atomic_file, write_csv

PAPER = {"A_PR": (3.6166, 0.7002), "A_L": (10.812, 0.7756)}  # slope, R² (paper eq. 15)
COLUMNS = ["key", "iterations", "d_min_m", "n_trees", "pruning", "stochastic", "n_branches",
           "N", "M", "footprint", "hit_rule", "V_L_m3", "A_L_m2", "A_PR_m2", "A_PR_exact_m2",
           "A_IM_m2", "A_IM_yz_m2", "A_PR_swept_share", "scan_seconds"]
PAPER_FOOTPRINT = 2  # SIMLIDAR §3.1 takes P = 2


def paper_grid(iterations=(4, 5, 6, 7), d_min_m=(0.005, 0.006, 0.007), n_trees=(1, 4),
               pruning=(False, True), stochastic=(False, True)) -> list[list[str]]:
    """Override lists for the §5 factorial grid (96 orchards with the defaults)."""
    grid = []
    for it, d, n, pr, st in itertools.product(iterations, d_min_m, n_trees, pruning, stochastic):
        grid.append([f"orchard.tree.iterations={it}", f"orchard.tree.d_min_m={d}",
                     f"orchard.n_trees={n}", f"orchard.tree.pruning={str(pr).lower()}",
                     f"orchard.tree.stochastic={str(st).lower()}"])
    return grid


def _key(overrides: list[str]) -> str:
    return hashlib.sha256("\n".join(overrides).encode()).hexdigest()[:16]


def run_one(scene: str, overrides: list[str], rows_dir: str) -> dict:
    """Scan one orchard and write its row; returns the row (a Dask task, so module-level)."""
    from .survey import run_scan  # noqa: PLC0415  (imports Mitsuba in the worker)
    cfg = load_scene(scene, overrides)
    run = run_scan(cfg, None)
    m = run.measures
    t = cfg["orchard.tree"]
    row = {"key": _key(overrides), "iterations": t["iterations"], "d_min_m": t["d_min_m"],
           "n_trees": cfg["orchard"]["n_trees"], "pruning": t["pruning"], "stochastic": t["stochastic"],
           "n_branches": m["n_branches"], "N": m["N"], "M": m["M"], "footprint": m["footprint"],
           "hit_rule": m["hit_rule"], "A_PR_swept_share": m.get("A_PR_swept_share"), "V_L_m3": m["V_L_m3"],
           "A_L_m2": m["A_L_m2"], "A_PR_m2": m["A_PR_m2"], "A_PR_exact_m2": m["A_PR_exact_m2"],
           "A_IM_m2": m["A_IM_m2"], "A_IM_yz_m2": m["A_IM_yz_m2"], "scan_seconds": m["seconds"]["scan"],
           "overrides": overrides}
    with atomic_file(Path(rows_dir) / f"{row['key']}.json") as tmp:
        tmp.write_text(json.dumps(row, sort_keys=True))
    return row


def fit_through_origin(x: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """y = b·x by least squares through the origin; R² = 1 − SS_res / SS_tot (about the mean)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    b = float(np.dot(x, y) / np.dot(x, x))
    ss_res = float(np.sum((y - b * x) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {"slope": b, "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
            "pearson_r": float(np.corrcoef(x, y)[0, 1]) if len(x) > 1 else float("nan"), "n": int(len(x))}


@dataclass
class StudyResult:
    rows: list[dict]
    regression: dict
    files: dict[str, Path]


def scan_overrides(hit_rule: str = "any", footprint: int | None = None) -> list[str]:
    """The overrides that set the study's hit test: ``"any"`` with P = 2 (the paper's) by
    default; ``"fraction"`` with the scene's own footprint unless ``footprint`` is given."""
    if hit_rule not in ("any", "fraction"):
        raise ConfigError("must be 'any' or 'fraction'", key="hit_rule", value=hit_rule)
    if footprint is None and hit_rule == "any":
        footprint = PAPER_FOOTPRINT
    if footprint is not None and (isinstance(footprint, bool) or not isinstance(footprint, int) or footprint < 0):
        raise ConfigError("must be an integer ≥ 0", key="footprint", value=footprint)
    return [f'scan.hit_rule="{hit_rule}"'] + ([f"scan.footprint={footprint}"] if footprint is not None else [])


def run_study(scene: str | Path, out_dir: str | Path, grid: list[list[str]] | None = None, *,
              workers: int = 1, progress: bool = False, hit_rule: str = "any",
              footprint: int | None = None) -> StudyResult:
    """Run (or resume) the study of ``grid`` (default :func:`paper_grid`) on ``scene``.

    ``hit_rule`` and ``footprint`` (see :func:`scan_overrides`) come before each grid
    entry's overrides, so an entry may still set its own; they are part of each row's key,
    so rows scanned under another rule are never reused."""
    scene = str(Path(scene).resolve())
    load_scene(scene)  # fail early, before any task, on a bad base scene
    grid = paper_grid() if grid is None else grid
    if not grid:
        raise ConfigError("the study grid is empty", file=scene)
    rule = scan_overrides(hit_rule, footprint)
    grid = [rule + list(g) for g in grid]
    out = Path(out_dir)
    rows_dir = out / "rows"
    rows_dir.mkdir(parents=True, exist_ok=True)
    todo = [o for o in grid if not (rows_dir / f"{_key(o)}.json").exists()]
    if todo:
        import dask  # noqa: PLC0415
        from dask.diagnostics import ProgressBar  # noqa: PLC0415
        tasks = [dask.delayed(run_one)(scene, o, str(rows_dir)) for o in todo]
        scheduler = "processes" if workers > 1 else "synchronous"
        if progress:
            with ProgressBar():
                dask.compute(*tasks, scheduler=scheduler, num_workers=workers)
        else:
            dask.compute(*tasks, scheduler=scheduler, num_workers=workers)
    rows = [json.loads((rows_dir / f"{_key(o)}.json").read_text()) for o in grid]
    a_im = np.array([r["A_IM_m2"] for r in rows])
    regression = {
        "A_PR_vs_A_IM": fit_through_origin(a_im, [r["A_PR_m2"] for r in rows]),
        "A_L_vs_A_IM": fit_through_origin(a_im, [r["A_L_m2"] for r in rows]),
        "A_PR_exact_vs_A_IM": fit_through_origin(a_im, [r["A_PR_exact_m2"] for r in rows]),
        "scan": {"hit_rule": sorted({r["hit_rule"] for r in rows}),
                 "footprint": sorted({r["footprint"] for r in rows})},
        "paper": {"A_PR_vs_A_IM": {"slope": PAPER["A_PR"][0], "r2": PAPER["A_PR"][1]},
                  "A_L_vs_A_IM": {"slope": PAPER["A_L"][0], "r2": PAPER["A_L"][1]}},
    }
    files = {"csv": out / "study.csv", "regression": out / "regression.json", "png": out / "correlations.png"}
    write_csv(files["csv"], COLUMNS, rows, extrasaction="ignore")
    with atomic_file(files["regression"]) as tmp:
        tmp.write_text(json.dumps(regression, indent=2) + "\n")
    _plot(rows, regression, files["png"])
    return StudyResult(rows, regression, files)


def _plot(rows: list[dict], regression: dict, path: Path) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    a_im = np.array([r["A_IM_m2"] for r in rows])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), dpi=120)
    for ax, (col, name, key) in zip(axes, [("A_PR_m2", "A_PR", "A_PR_vs_A_IM"), ("A_L_m2", "A_L", "A_L_vs_A_IM")]):
        y = np.array([r[col] for r in rows])
        trees = np.array([r["n_trees"] for r in rows])
        for n, marker in ((1, "o"), (4, "s")):
            sel = trees == n
            ax.scatter(a_im[sel], y[sel], s=18, marker=marker, alpha=0.8, label=f"{n} tree{'s' * (n > 1)}")
        xs = np.linspace(0, a_im.max() * 1.05, 50)
        fit = regression[key]
        ax.plot(xs, fit["slope"] * xs, "k-", lw=1, label=f"this run: {fit['slope']:.3f}·A_IM (R² {fit['r2']:.2f})")
        ax.plot(xs, PAPER[name][0] * xs, "r--", lw=1, label=f"paper: {PAPER[name][0]}·A_IM (R² {PAPER[name][1]})")
        ax.set_xlabel("impacted area A_IM (m²)")
        ax.set_ylabel(f"{name} (m²)")
        ax.legend(fontsize=8)
    fig.suptitle(f"SIMLIDAR §5 study: {len(rows)} virtual orchards")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
