"""``simlidar-mi evaluate-als``: ground filters, CHMs and tree detectors scored against a scene's truth.

:func:`evaluate_als` reads a scan's points (a LAS file whose classification holds the true
class, as ``scan`` writes it: ASPRS 2 = ground) and the scene file, computes the scene's raster
truth (:mod:`simlidar_mi.truth.als_truth`) and writes into ``out_dir``:

``als_scores.json``
    every table below, the grid, the options and the seconds of each step.
``ground_scores.csv``
    per ground filter (``csf``, ``pmf``, plug-ins; ``true-classes`` is the TIN of the truly
    ground points, the interpolation error alone): type I / II / total error, Cohen's κ
    (:mod:`simlidar_mi.truth.als_ground`), its DTM's RMSE and bias, seconds.
``dtm_scores.csv``
    per filter and stratum (all, slope classes, under canopy / open): RMSE, bias, largest error.
``chm_scores.csv``
    the plain and the pit-free CHM (:mod:`simlidar_mi.truth.als_trees`) against the truth CHM,
    over every cell and over canopy cells (truth CHM ≥ ``min_height_m``), and the pit-free −
    plain difference.  Both CHMs normalise heights by the true terrain, so they carry no
    ground-filter error.
``tree_scores.csv`` / ``detection_by_height.csv`` / ``detected_trees.csv``
    per detector (``lmf``, ``watershed``, plug-ins) run on the pit-free CHM (and, as an oracle
    row, on the truth CHM): detection rate, precision, F-score, matched trees' height RMSE and
    bias, by species and dominant vs overtopped; the rate per 2 m height class; every detected
    tree with the true tree it matched (−1: none).
``truth_trees.csv``
    the scene's trees (``tree_id, species, x_m, y_m, height_m, crown_radius_m``) with
    ``top_cells`` (cells of ``truth_tree_id.tif`` the tree owns) and ``overtopped`` (owns none;
    ``forest --truth-rasters`` adds the same two columns to ``trees.csv``).
``truth_dtm.tif``, ``truth_dsm.tif``, ``truth_chm.tif``, ``truth_tree_id.tif``
    the raster truth; ``dtm_<filter>.tif``, ``chm_plain.tif``, ``chm_pitfree.tif`` the estimates.
``dtm_error.png``, ``chm_trees.png``, ``detection_by_height.png``
    the DTM error map of each filter, the pit-free CHM with the true and the detected tree
    tops, and the detection rate by tree height.

Plug-ins: ``ground_plugins`` are ``module:function`` specs (or callables) ``f(points) -> bool
array`` (True: ground), ``points`` a dict of numpy arrays ``x, y, z`` (float64, metres),
``return_number``, ``number_of_returns``, ``intensity`` of every point of the LAS file;
``tree_plugins`` are ``f(chm, grid) -> (n, 3)`` tree tops (x, y, height in metres), ``chm`` the
pit-free CHM (a 2-D array, north row first) on ``grid`` (:class:`~.als_truth.RasterGrid`).
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..io.atomic import staged_dir, writes_output
from . import als_ground as G
from . import als_trees as T
from ..io.terrain import ground_height, terrain_of
from .als_truth import HeightFn, RasterGrid, top_cells, write_geotiff, write_truth_rasters
from .forest_truth import cast_truth, raster_crs
from .scoring import load_plugin

ALS_OUTPUTS = (r"als_scores\.json", r"ground_scores\.csv", r"dtm_scores\.csv", r"chm_scores\.csv",
               r"tree_scores\.csv", r"detection_by_height\.csv", r"detected_trees\.csv", r"truth_trees\.csv",
               r"truth_(dtm|dsm|chm|tree_id)\.tif", r"dtm_[A-Za-z0-9_.-]+\.tif", r"chm_(plain|pitfree)\.tif",
               r"dtm_error\.png", r"chm_trees\.png", r"detection_by_height\.png")
LAS_GROUND = 2


@dataclass
class AlsRun:
    """What :func:`evaluate_als` scored (the tables of the module docstring) and wrote."""

    ground: list = field(default_factory=list)
    dtm: list = field(default_factory=list)
    chm: list = field(default_factory=list)
    trees: list = field(default_factory=list)
    by_height: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)


def read_points(path: str | Path) -> dict[str, np.ndarray]:
    """x, y, z (float64), classification, return_number, number_of_returns, intensity of a LAS/LAZ file."""
    import laspy  # noqa: PLC0415
    p = Path(path)
    if not p.is_file():
        raise ConfigError("no such file", file=p, key="--points", value=str(p))
    try:
        las = laspy.read(p)
    except Exception as exc:  # noqa: BLE001  (laspy's own errors: one line)
        raise ConfigError(f"not a readable LAS file ({type(exc).__name__}: {' '.join(str(exc).split())})",
                          file=p, key="--points") from None
    if not len(las.points):
        raise ConfigError("the file holds no points", file=p, key="--points")
    return {"x": np.asarray(las.x, np.float64), "y": np.asarray(las.y, np.float64),
            "z": np.asarray(las.z, np.float64), "classification": np.asarray(las.classification, np.uint8),
            "return_number": np.asarray(las.return_number, np.uint8),
            "number_of_returns": np.asarray(las.number_of_returns, np.uint8),
            "intensity": np.asarray(las.intensity, np.uint16)}


def _plugin(spec, option: str):
    if callable(spec):
        return getattr(spec, "__name__", "plugin"), spec
    try:
        f = load_plugin(spec)
    except ConfigError as exc:
        raise ConfigError(exc.reason, key=option, value=spec) from None
    return spec.rpartition(":")[2], f


def _call(f, label: str, option: str, *args):
    try:
        return f(*args)
    except Exception as exc:  # noqa: BLE001  (the plug-in's own failure: one line)
        raise ConfigError(f"the method failed: {type(exc).__name__}: {' '.join(str(exc).split())}",
                          key=option, value=label) from None


def _ground_mask(out, n: int, label: str) -> np.ndarray:
    a = np.asarray(out)
    if a.shape != (n,) or not (a.dtype == bool or np.isin(a, (0, 1)).all()):
        raise ConfigError(f"a ground method returns {n} booleans (True: ground), got shape {a.shape} of {a.dtype}",
                          key="--ground-method", value=label)
    return a.astype(bool)


def _tree_array(out, label: str) -> np.ndarray:
    a = np.asarray(out, np.float64) if not hasattr(out, "keys") else np.column_stack(
        [np.asarray(out[k], np.float64) for k in ("x_m", "y_m", "height_m")])
    if a.ndim != 2 or a.shape[1] != 3 or not np.isfinite(a).all():
        raise ConfigError(f"a tree method returns finite (n, 3) tree tops x, y, height; got shape {a.shape}",
                          key="--tree-method", value=label)
    return a


def _grid(cfg: SceneConfig, pts: dict, cell_m: float) -> RasterGrid:
    if cfg.has("forest") and cfg["forest"].get("domain_m"):
        x0, x1, y0, y1 = (float(v) for v in cfg["forest"]["domain_m"])
    else:
        x0, x1, y0, y1 = pts["x"].min(), pts["x"].max(), pts["y"].min(), pts["y"].max()
    return RasterGrid.cover(x0, x1, y0, y1, cell_m)


def _chm_rows(name: str, est: np.ndarray, truth: np.ndarray, min_height_m: float) -> list[dict]:
    rows = []
    for stratum, sel in (("all", np.isfinite(est)), ("canopy", np.isfinite(est) & (truth >= min_height_m))):
        e = est[sel] - truth[sel]
        rows.append({"chm": name, "stratum": stratum, "n_cells": int(e.size),
                     "rmse_m": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
                     "bias_m": float(np.mean(e)) if e.size else float("nan")})
    return rows


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows([{k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()} for r in rows])


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


@writes_output("out_dir")
def evaluate_als(scene, points: str | Path, out_dir: str | Path, overrides: Sequence = (), *,
                 ground_plugins=(), tree_plugins=(), cell_m: float | None = None, subsamples: int | None = None,
                 max_distance_m: float = 3.0, max_height_diff_m: float = 3.0, min_height_m: float = 2.0,
                 height_m: HeightFn | None = None, images: bool = True, progress=False) -> AlsRun:
    """Score ground filters, CHMs and tree detectors of ``points`` against the truth of ``scene``
    and write the files of the module docstring into ``out_dir``.  ``height_m``: the terrain
    (default: the flat plane ``[ground] z_m``); ``cell_m``/``subsamples`` override
    ``[truth] raster_cell_m``/``raster_subsamples``."""
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, list(overrides))
    shown = make_progress(progress)
    cell_m = float(cell_m if cell_m is not None else cfg["truth"]["raster_cell_m"])
    k = int(subsamples if subsamples is not None else cfg["truth"]["raster_subsamples"])
    for name, v, ok in (("--cell", cell_m, 0.01 <= cell_m <= 1000), ("--subsamples", k, 1 <= k <= 32),
                        ("--max-distance", max_distance_m, max_distance_m > 0),
                        ("--max-height-diff", max_height_diff_m, max_height_diff_m > 0)):
        if not (ok and np.isfinite(v)):
            raise ConfigError("out of range (cell 0.01-1000 m, subsamples 1-32, tolerances > 0)", key=name, value=v)
    grounds = [("csf", G.csf_ground), ("pmf", G.pmf_ground)] + [_plugin(s, "--ground-method") for s in ground_plugins]
    detectors = [("lmf", T.local_maxima_trees), ("watershed", T.watershed_trees)] + \
        [_plugin(s, "--tree-method") for s in tree_plugins]
    pts = read_points(points)
    terrain = terrain_of(cfg)
    height_m = height_m or (terrain.height_m if terrain is not None else ground_height(cfg))
    seconds: dict[str, float] = {}

    grid = _grid(cfg, pts, cell_m)
    truth, trees, s = cast_truth(cfg, grid, height_m, k, shown, "evaluate-als")
    seconds.update(s)

    xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
    true_ground = pts["classification"] == LAS_GROUND
    # DTMs and CHMs from the points over the grid and a margin (the TINs cost most of the run)
    pad = 2.0 * grid.cell_m + 1.0
    near = ((pts["x"] >= grid.x0_m - pad) & (pts["x"] <= grid.x0_m + grid.nx * grid.cell_m + pad)
            & (pts["y"] >= grid.y0_m - pad) & (pts["y"] <= grid.y0_m + grid.ny * grid.cell_m + pad))
    under = truth.tree_id >= 0
    run = AlsRun()
    dtms = {}
    bar = shown.stage("evaluate-als: ground filters", len(grounds) + 1, "filter")
    for name, f in [("true-classes", None)] + grounds:
        t0 = time.perf_counter()
        if f is None:
            pred = true_ground
        elif f in (G.csf_ground, G.pmf_ground):
            pred = f(xyz)
        else:
            shown_pts = {k: v for k, v in pts.items() if k != "classification"}  # not the answer
            pred = _ground_mask(_call(f, name, "--ground-method", shown_pts), len(xyz), name)
        secs = time.perf_counter() - t0
        dtm = G.dtm_from_ground(xyz[pred & near], grid)
        dtms[name] = dtm
        rows = G.dtm_scores(dtm, truth.dtm, under, grid.cell_m)
        run.dtm += [{"method": name, **r} for r in rows]
        cls = G.classification_scores(true_ground, pred)
        run.ground.append({"method": name, **cls, "dtm_rmse_m": rows[0]["rmse_m"], "dtm_bias_m": rows[0]["bias_m"],
                           "dtm_coverage": rows[0]["coverage"], "seconds": secs})
        bar.update()
    bar.close()

    t0 = time.perf_counter()
    h = pts["z"] - height_m(pts["x"], pts["y"])
    first = (pts["return_number"] <= 1) & near
    chm_plain = T.chm_plain(pts["x"][near], pts["y"][near], h[near], grid)
    seconds["chm_plain"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    chm_pf = T.chm_pitfree(pts["x"][first], pts["y"][first], h[first], grid)
    seconds["chm_pitfree"] = time.perf_counter() - t0
    run.chm = _chm_rows("plain", chm_plain, truth.chm, min_height_m) + _chm_rows("pitfree", chm_pf, truth.chm,
                                                                                 min_height_m)
    diff = chm_pf - chm_plain
    chm_diff = {"mean_m": float(np.nanmean(diff)), "rmse_m": float(np.sqrt(np.nanmean(diff ** 2))),
                "share_cells_over_0.5m": float(np.nanmean(diff > 0.5))}

    detected, det_rows = {}, []
    if trees is not None and len(trees["tree_id"]):
        n = len(trees["tree_id"])
        owned, over = top_cells(truth.tree_id, n)
        true_xyh = np.column_stack([trees["x"], trees["y"], trees["height_m"]]).astype(np.float64)
        bar = shown.stage("evaluate-als: tree detection", 2 * len(detectors), "run")
        for chm_name, chm in (("pitfree", chm_pf), ("truth", truth.chm)):
            for name, f in detectors:
                t0 = time.perf_counter()
                if f in (T.local_maxima_trees, T.watershed_trees):
                    det = f(chm, grid, min_height_m=min_height_m)
                else:
                    det = _tree_array(_call(f, name, "--tree-method", chm, grid), name)
                secs = time.perf_counter() - t0
                m = T.match_trees(true_xyh, det, max_distance_m=max_distance_m, max_height_diff_m=max_height_diff_m)
                label = name if chm_name == "pitfree" else f"{name} on truth CHM"
                run.trees += [{"method": label, **r, "seconds": secs}
                              for r in T.detection_scores(true_xyh, det, m, trees["species"], over)]
                run.by_height += [{"method": label, **r} for r in T.detection_by_height(true_xyh[:, 2], m)]
                if chm_name == "pitfree":
                    detected[name] = det
                    det_rows += [{"method": name, "x_m": float(d[0]), "y_m": float(d[1]), "height_m": float(d[2]),
                                  "true_tree_id": int(m.true_of_det[j])} for j, d in enumerate(det)]
                bar.update()
        bar.close()
        tree_table = [{"tree_id": int(trees["tree_id"][i]), "species": str(trees["species"][i]),
                       "x_m": float(trees["x"][i]), "y_m": float(trees["y"][i]), "height_m": float(trees["height_m"][i]),
                       "crown_radius_m": float(trees["crown_radius_m"][i]), "top_cells": int(owned[i]),
                       "overtopped": int(over[i])} for i in range(n)]
    else:
        true_xyh, tree_table = np.zeros((0, 3)), []

    crs = raster_crs(cfg, terrain)
    run.summary = {"scene": str(cfg.source), "points": str(points), "n_points": int(len(xyz)),
                   "n_true_ground": int(true_ground.sum()), "grid": grid.to_dict(), "subsamples": k,
                   "crs": crs or "none (the scene's local frame, metres)",
                   "options": {"max_distance_m": max_distance_m, "max_height_diff_m": max_height_diff_m,
                               "min_height_m": min_height_m},
                   "n_trees": len(tree_table), "n_overtopped": int(sum(r["overtopped"] for r in tree_table)),
                   "ground": run.ground, "dtm": run.dtm, "chm": run.chm, "chm_pitfree_minus_plain": chm_diff,
                   "trees": run.trees, "detection_by_height": run.by_height, "seconds": seconds}
    out = Path(out_dir)
    with staged_dir(out, ALS_OUTPUTS) as stage:
        _write_csv(stage / "ground_scores.csv", run.ground)
        _write_csv(stage / "dtm_scores.csv", run.dtm)
        _write_csv(stage / "chm_scores.csv", run.chm)
        names = ["ground_scores.csv", "dtm_scores.csv", "chm_scores.csv"]
        for name, rows in (("tree_scores.csv", run.trees), ("detection_by_height.csv", run.by_height),
                           ("detected_trees.csv", det_rows), ("truth_trees.csv", tree_table)):
            if rows:
                _write_csv(stage / name, rows)
                names.append(name)
        names += [p.name for p in write_truth_rasters(truth, stage, crs).values()]
        for name, dtm in dtms.items():
            if name != "true-classes":
                fn = f"dtm_{name}.tif"
                write_geotiff(stage / fn, dtm.astype(np.float32), grid, crs, nodata=float("nan"),
                              description=f"DTM of the {name} ground points (TIN)")
                names.append(fn)
        for name, chm in (("plain", chm_plain), ("pitfree", chm_pf)):
            write_geotiff(stage / f"chm_{name}.tif", chm.astype(np.float32), grid, crs,
                          description=f"{name} CHM (height above the true terrain)")
            names.append(f"chm_{name}.tif")
        if images:
            from .als_plots import plot_all  # noqa: PLC0415
            names += plot_all(stage, grid, truth, dtms, chm_pf, true_xyh, detected, run.by_height)
        (stage / "als_scores.json").write_text(json.dumps(_plain(run.summary), indent=1, allow_nan=False))
        names.append("als_scores.json")
    run.files = {n: out / n for n in names}
    return run
