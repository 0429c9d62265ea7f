"""``simlidar-mi evaluate``: scan a scene, compute its truth, run the estimators, score them.

:func:`evaluate` is the whole run; :func:`evaluate_beams` the part after the scan and
the truth (any beams, any truth Dataset on a grid), which tests and benchmarks call.

Output folder (written atomically: every file appears together when all are done):

``scores.csv``, ``scores.json``
    per estimator and scale (``voxel``, ``profile``) over the voxels the scan observed (at
    least ``min_beams`` first-return beams entered, fixed before any estimator runs): n,
    the coverage (shares of voxels and of true area with an estimate), R², RMSE, bias and
    means with abstentions scored as 0, the same where estimated (definitions in
    :mod:`simlidar_mi.truth.scoring`), the seconds it took; the JSON adds the z profiles,
    the canopy envelope (height, width, TRV and LWA when a row spacing is given) of the
    truth and of the point cloud, the truth's G and the run's settings. With the truth's
    leaf pieces (``leaf_pieces``), the G-proportional built-ins are scored a second time
    with the truth's own G per voxel (``*_Gtruth``, :mod:`simlidar_mi.truth.leaf_g`).
``profiles.csv``, ``profiles.png``, ``scatter.png``
    truth vs estimate per height bin, and per voxel.
``truth.nc``, ``estimates/<name>.nc``, ``grid.nc``
    the truth (with ``G_leaf``, its G along the scan's beams, when computed), each estimate and the empty grid (coordinates only, what a command
    plug-in receives as ``{grid}``), NetCDF (:mod:`simlidar_mi.truth.grid`).
``scan/``
    the scan's scan.exr, points.las and measures.json (what plug-ins read).
"""
from __future__ import annotations

import json
import re
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._runtime.progress import make_progress
from ..errors import ConfigError, SimlidarWarning
from ..io.atomic import atomic_file, staged_dir, write_csv, writes_output
from .estimators import (BUILTIN, ESTIMATE_VARIABLES, G_SPHERICAL, MIN_BEAMS, ORACLE_G, estimate_all,
                         with_G)
from .grid import DIMS, VoxelGrid, grid_dataset, grid_values, write_grid
from .scoring import call_plugin, check_command, layer_profile, load_plugin, run_command, score

__all__ = ["EvaluateRun", "evaluate", "evaluate_beams", "EVALUATE_OUTPUTS"]

EVALUATE_OUTPUTS = (r"scores\.(csv|json)", r"profiles\.(csv|png)", r"scatter\.png", r"truth\.nc",
                    r"grid\.nc", r"estimates", r"scan")
SCORE_FIELDS = ("estimator", "variable", "scale", "n", "coverage_voxels", "coverage_area", "r2", "rmse", "bias",
                "truth_mean", "estimate_mean", "n_estimated", "r2_estimated", "rmse_estimated", "bias_estimated",
                "seconds")


@dataclass
class EvaluateRun:
    """Scores (rows of scores.csv), the estimates (name → arrays), the summary and files."""

    scores: list[dict]
    estimates: dict[str, dict[str, np.ndarray]]
    summary: dict
    files: dict[str, Path] = field(default_factory=dict)

    def get(self, estimator: str, scale: str = "voxel") -> dict:
        for row in self.scores:
            if row["estimator"] == estimator and row["scale"] == scale:
                return row
        raise KeyError(f"no score for {estimator!r} at scale {scale!r}")


def _name(spec: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", spec.rpartition(":")[2] or spec)


def evaluate_beams(grid: VoxelGrid, truth, first, multi=None, *, stage: Path | None = None,
                   scan_dir: Path | None = None, plugins=(), commands=(), G: float = G_SPHERICAL,
                   min_points: int = 1, saturated: str = "cap", min_beams: float = MIN_BEAMS,
                   row_spacing_m: float | None = None, row_axis: str = "y", canopy_base: str = "ground",
                   ground_z_m: float = 0.0, progress=None, title: str = "",
                   extra: dict | None = None, crs: str | None = None, leaf_pieces=None,
                   terrain=None) -> EvaluateRun:
    """Run the built-in estimators on ``first`` (and ``multi``) beams, the plug-ins
    (``plugins``: "module:function" specs or callables; ``commands``: command templates,
    which need ``scan_dir``), score all against ``truth`` (a Dataset on ``grid``) and,
    with ``stage`` (a folder), write the files of the module docstring there (``crs``, the
    scene's, and ``ground_z_m`` or ``terrain`` describe their frame: :func:`~simlidar_mi.truth.grid.grid_dataset`).
    ``leaf_pieces`` (a :class:`~simlidar_mi.truth.leaf_g.LeafPieces` filled by ``compute_truth``):
    the truth's G along these beams is added to ``truth`` (``G_leaf``) and the oracle runs scored."""
    from .leaf_g import LeafG  # noqa: PLC0415
    shown = make_progress(progress)
    walked = shown.stage("evaluate: beams through the grid", len(first) + (len(multi) if multi is not None else 0),
                         "beam")
    leaf_g = LeafG(leaf_pieces, first) if leaf_pieces is not None else None
    estimates, seconds = estimate_all(grid, first, multi, G=G, min_points=min_points,
                                      saturated=saturated, min_beams=min_beams, progress=walked.update,
                                      on_first_segment=leaf_g.segment if leaf_g is not None else None)
    walked.close()
    # The scored voxels, fixed by the scan alone before any estimate is looked at.
    observed = estimates["beer_lambert"]["n_in"] >= min_beams
    g_summary = {"G": G}
    if leaf_g is not None:
        truth, g_summary = _add_truth_G(truth, grid, leaf_g, estimates, seconds, G)
    if stage is not None:
        grid_file = write_grid(grid_dataset(grid, {}, attrs={"title": "the evaluation's voxel grid"}, crs=crs,
                                            ground_z_m=ground_z_m, terrain=terrain), Path(stage) / "grid.nc")
    for j, spec in enumerate(plugins):
        f = spec if callable(spec) else load_plugin(spec)
        label = spec if isinstance(spec, str) else getattr(f, "__name__", f"plugin{j}")
        if scan_dir is None:
            raise ConfigError("plug-in estimators need the scan's folder", key="--estimator", value=label)
        t = time.perf_counter()
        name = _unique(_name(label), estimates)
        estimates[name] = call_plugin(f, label, scan_dir, grid)
        seconds[name] = time.perf_counter() - t
    for j, cmd in enumerate(commands):
        if scan_dir is None or stage is None:
            raise ConfigError("command estimators need the scan's files", key="--estimator-cmd", value=cmd)
        t = time.perf_counter()
        name = _unique(f"cmd{j + 1}", estimates)
        scan_dir = Path(scan_dir)
        out = Path(stage) / f".{name}.nc"
        estimates[name] = run_command(cmd, las=scan_dir / "points.las", exr=scan_dir / "scan.exr",
                                      grid_file=grid_file, out=out, grid=grid)
        out.unlink(missing_ok=True)
        seconds[name] = time.perf_counter() - t
    rows, profiles = [], []
    z = grid.centres(2)
    bar = shown.stage("evaluate: scoring", len(estimates), "estimator")
    for name, arrays in estimates.items():
        var = "PAD_m2_m3" if "PAD_m2_m3" in arrays else "LAD_m2_m3"
        if var not in truth:
            raise ConfigError(f"the truth has no {var}", key=var)
        s = score(grid_values(truth, var), arrays[var], observed)
        _say_what_is_odd(name, var, np.asarray(arrays[var], np.float64), observed, s["voxel"]["n_estimated"])
        for scale in ("voxel", "profile"):
            rows.append({"estimator": name, "variable": var, "scale": scale, **s[scale],
                         "seconds": round(seconds.get(name, float("nan")), 4)})
        profiles += [{"estimator": name, "variable": var, "z_m": float(zk), "truth": float(a), "estimate": float(b)}
                     for zk, a, b in zip(z, s["z_truth"], s["z_estimate"])]
        bar.update()
    bar.close()
    truth_area = grid_values(truth, "PAD_m2_m3")
    summary = {"grid": grid.attrs(), **g_summary, "min_points": min_points, "saturated": saturated,
               "min_beams": min_beams, "n_beams": len(first), "n_observed_voxels": int(observed.sum()),
               "scored_voxels": f"the voxels >= min_beams ({min_beams:g}) first-return beams entered; an "
                                "estimator's NaN there is an abstention, scored as 0 in r2/rmse/bias",
               "observed_share_of_plant_area": float(truth_area[observed].sum() / truth_area.sum())
               if truth_area.sum() > 0 else float("nan"),
               "n_voxels": int(np.prod(grid.shape)), "estimators": {k: BUILTIN.get(k, "plug-in") for k in estimates},
               "envelope": _envelope(grid, truth, estimates["vcp"]["occupied"], row_spacing_m, row_axis,
                                     canopy_base, ground_z_m, terrain)}
    summary.update(extra or {})
    run = EvaluateRun(rows, estimates, summary)
    if stage is not None:
        _write(run, Path(stage), grid, truth, profiles, title, {"crs": crs, "ground_z_m": ground_z_m,
                                                                "terrain": terrain})
    return run


def _add_truth_G(truth, grid, leaf_g, estimates, seconds, G):
    """The truth's G along the beams (``G_leaf``, ``G_plant``) added to the truth Dataset,
    and the oracle runs (:data:`ORACLE_G` with the truth's plant G of the canopy, and per
    voxel with the constant ``G`` where a voxel has none) added to ``estimates``."""
    t = time.perf_counter()
    g_leaf = leaf_g.per_voxel()
    g_plant, g_canopy = leaf_g.plant(grid_values(truth, "leaf_area_m2"), grid_values(truth, "plant_area_m2"))
    along = leaf_g.along_beams()
    summary = {"G": G, "G_leaf_canopy": leaf_g.canopy(), "G_plant_canopy": g_canopy,
               "G_leaf_along_beams": {"min": float(along.min()), "max": float(along.max()), "n_directions": len(along)}
               if len(along) else None,
               "G_definition": "simlidar_mi.truth.leaf_g: sum a|n.Omega|/sum a over leaf triangles per voxel, "
                               "weighted by first-return beam chord; plant G: wood half-area at G 0.5; canopy: "
                               "area x beam chord weighted"}
    gm = {"grid_mapping": truth["PAD_m2_m3"].attrs["grid_mapping"]} if "grid_mapping" in truth["PAD_m2_m3"].attrs else {}
    truth = truth.assign(
        G_leaf=(DIMS, g_leaf.transpose(2, 1, 0), {"units": "1", **gm, "long_name":
                "G of the leaves: mean projection of unit one-sided leaf area along the first-return beams "
                "that entered the voxel, weighted by beam chord (NaN: no leaf or no beam)"}),
        G_plant=(DIMS, g_plant.transpose(2, 1, 0), {"units": "1", **gm, "long_name":
                 "G of the plant area: G_leaf and 0.5 for the wood half-area, weighted by area (NaN: no "
                 "plant area or no beam)"}))
    truth.attrs.update({"G_leaf_canopy": summary["G_leaf_canopy"], "G_plant_canopy": g_canopy,
                        "G_definition": summary["G_definition"]})
    secs = time.perf_counter() - t
    for suffix, g in (("_Gcanopy", g_canopy), ("_Gvoxel", np.where(np.isfinite(g_plant), g_plant, G))):
        for name in ORACLE_G:
            if name in estimates and np.all(np.isfinite(g)):
                e = estimates[name]
                estimates[name + suffix] = {"PAD_m2_m3": with_G(e["PAD_m2_m3"], G, g),
                                            "G": np.broadcast_to(np.float64(g), grid.shape),
                                            **{k: v for k, v in e.items() if k != "PAD_m2_m3"}}
                seconds[name + suffix] = seconds[name] + secs
    return truth, summary


def _say_what_is_odd(name: str, var: str, estimate: np.ndarray, observed: np.ndarray, n: int) -> None:
    """One warning line for an estimate that abstains everywhere or holds negative densities."""
    seen = estimate[observed]
    if n == 0 and observed.any():
        warnings.warn(SimlidarWarning(f"estimator {name}: no finite {var} in the {int(observed.sum())} voxels "
                                      "the scan observed, so it abstains in all (scored as 0 there)"), stacklevel=3)
    neg = seen[np.isfinite(seen) & (seen < 0)]
    if len(neg):
        warnings.warn(SimlidarWarning(f"estimator {name}: {len(neg)} voxels hold a negative {var} (down to "
                                      f"{neg.min():.4g}); scored as given"), stacklevel=3)


def _unique(name: str, taken) -> str:
    out, k = name, 2
    while out in taken:
        out, k = f"{name}_{k}", k + 1
    return out


def _envelope(grid, truth, occupied_points, row_spacing_m, row_axis, base, ground_z_m, terrain=None) -> dict:
    """Canopy height/width per slice along the row (and TRV, LWA with a row spacing) of the
    truth (voxels holding plant area) and of the point cloud (occupied voxels)."""
    from .row_metrics import canopy_profiles, lwa_m2_ha, trv_m3_ha  # noqa: PLC0415
    var = "plant_area_m2" if "plant_area_m2" in truth else "PAD_m2_m3"
    out = {}
    for label, occ in (("truth", grid_values(truth, var) > 0), ("points", occupied_points > 0)):
        p = canopy_profiles(occ, grid, row_axis=row_axis, base=base, ground_z_m=ground_z_m, terrain=terrain)
        e = {"mean_height_m": p["mean_height_m"], "mean_width_m": p["mean_width_m"]}
        if row_spacing_m is not None:
            e["TRV_m3_ha"] = float(trv_m3_ha(p["mean_height_m"], p["mean_width_m"], row_spacing_m))
            e["LWA_m2_ha"] = float(lwa_m2_ha(p["mean_height_m"], row_spacing_m))
        out[label] = e
    out.update({"row_axis": row_axis, "row_spacing_m": row_spacing_m, "canopy_base": base,
                "definition": "canopy height and width per slice along the row from occupied voxels "
                              "(truth: plant area > 0; points: ≥ min_points returns), "
                              "TRV = H·W·10000/D, LWA = 2·H·10000/D (simlidar_mi.truth.row_metrics)"})
    return out


def _write(run: EvaluateRun, stage: Path, grid, truth, profiles, title, frame: dict) -> None:
    write_csv(stage / "scores.csv", SCORE_FIELDS, [{k: r[k] for k in SCORE_FIELDS} for r in run.scores])
    write_csv(stage / "profiles.csv", ("estimator", "variable", "z_m", "truth", "estimate"), profiles)
    with atomic_file(stage / "scores.json") as tmp:
        tmp.write_text(json.dumps({"scores": run.scores, "summary": run.summary, "profiles": profiles},
                                  indent=2, default=_plain) + "\n")
    write_grid(truth, stage / "truth.nc")
    (stage / "estimates").mkdir(exist_ok=True)
    for name, arrays in run.estimates.items():
        arr = {k: np.asarray(v, np.float64 if np.asarray(v).dtype.kind == "f" else np.asarray(v).dtype)
               for k, v in arrays.items() if np.shape(v) == tuple(grid.shape)}
        known = {k: ESTIMATE_VARIABLES.get(k, ("1", k.replace("_", " "))) for k in arr}
        write_grid(grid_dataset(grid, arr, attrs={"estimator": name,
                                                  "description": run.summary["estimators"][name]},
                                units={k: u for k, (u, _) in known.items()},
                                long_names={k: n for k, (_, n) in known.items()}, **frame),
                   stage / "estimates" / f"{name}.nc")
    _plots(run, stage, truth, profiles, title)


def _plain(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


def _plots(run: EvaluateRun, stage: Path, truth, profiles, title) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    names = list(run.estimates)
    fig, ax = plt.subplots(figsize=(6, 5), dpi=110)
    observed = run.estimates["beer_lambert"]["n_in"] >= run.summary["min_beams"]
    var0 = "PAD_m2_m3"
    z = np.unique([p["z_m"] for p in profiles])
    ax.plot(layer_profile(grid_values(truth, var0), observed), z, "k-", lw=2.5,
            label=f"truth (voxels ≥ {run.summary['min_beams']:g} beams entered)")
    for name in names:
        pr = [p for p in profiles if p["estimator"] == name]
        ax.plot([p["estimate"] for p in pr], [p["z_m"] for p in pr], lw=1.2, label=name)
    ax.set_xlabel("mean PAD over observed voxels, abstentions as 0 (m²/m³)")
    ax.set_ylabel("height z (m)")
    ax.set_title(f"{title}: profiles".strip(": "))
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_file(stage / "profiles.png") as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    n = len(names)
    cols = min(3, n)
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(4 * cols, 3.8 * ((n + cols - 1) // cols)),
                             dpi=100, squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        arrays = run.estimates[name]
        var = "PAD_m2_m3" if "PAD_m2_m3" in arrays else "LAD_m2_m3"
        t = grid_values(truth, var)
        e = arrays[var]
        m = observed & np.isfinite(e)
        ax.scatter(t[m], e[m], s=3, alpha=0.4)
        hi = float(max(np.nanmax(t[m], initial=0), np.nanmax(e[m], initial=0), 1e-9))
        ax.plot([0, hi], [0, hi], "k--", lw=0.8)
        r = run.get(name)
        ax.set_title(f"{name}\nR² {r['r2']:.2f}, RMSE {r['rmse']:.2f}, bias {r['bias']:+.2f}, "
                     f"coverage {100 * r['coverage_area']:.0f} %", fontsize=9)
        ax.set_xlabel(f"truth {var}")
        ax.set_ylabel("estimate (where estimated)")
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    with atomic_file(stage / "scatter.png") as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


@writes_output("out_dir")
def evaluate(scene, out_dir, overrides=(), *, estimators=(), commands=(), voxel_m: float | None = None,
             G: float = G_SPHERICAL, min_points: int = 1, saturated: str = "cap", min_beams: float = MIN_BEAMS,
             row_spacing_m: float | None = None, weights: str = "equal", progress=False) -> EvaluateRun:
    """Scan ``scene``, compute its truth (:func:`simlidar_mi.truth.compute.compute_truth`) on
    the ``[truth]`` grid (``voxel_m`` overrides ``[truth] voxel_m``), run the built-in
    estimators (multi-return ones when the scan has echoes, with echo ``weights``), the
    plug-ins ``estimators`` ("module:function") and ``commands``, and write the files of
    the module docstring to ``out_dir``. TRV and LWA use ``row_spacing_m``, else the
    scene's (:func:`simlidar_mi.truth.run.row_spacing_of`).

    The other options are the command's: ``G`` the mean projection of unit plant area along the
    beams (0.5: spherical leaf angles), ``min_beams`` the beams that must enter a voxel for it
    to be scored, ``weights`` the echo weights of the multi-return estimators ("equal" or
    "energy"); ``min_points``, the returns that make a voxel occupied (``vcp``, the envelope),
    and ``saturated`` (``"cap"``: T = 1/(N + 1) in a voxel every
    beam was stopped in, ``"nan"``: no estimate) tune the built-in estimators.
    Bad options, scenes and plug-ins are refused before the scan.

    Returns
    -------
    EvaluateRun
        ``scores`` (one row per estimator and scale, ``voxel`` or ``profile``: n, coverage of
        the true area, R², RMSE, bias; :meth:`EvaluateRun.get` picks one), ``estimates``,
        ``summary`` (the grid, the truth's totals, the envelope, seconds) and ``files``.
    """
    from ..config import SceneConfig, load_scene  # noqa: PLC0415
    from ..lidar.survey import run_scan, scan_patterns  # noqa: PLC0415
    from .compute import compute_truth  # noqa: PLC0415
    from .estimators import beams_from_exr, beams_from_scan  # noqa: PLC0415
    from .leaf_g import LeafPieces  # noqa: PLC0415
    from .run import row_spacing_of, truth_geometry, truth_grid  # noqa: PLC0415
    # The options first (each named as typed), then the scene and its grid: all before the scan.
    if voxel_m is not None and not (_real(voxel_m) and voxel_m > 0):
        raise ConfigError("the voxel size must be a number > 0 metres", key="--voxel", value=voxel_m)
    if not (_real(min_beams) and min_beams > 0):
        raise ConfigError("must be a number of beams > 0", key="--min-beams", value=min_beams)
    if row_spacing_m is not None and not (_real(row_spacing_m) and row_spacing_m > 0):
        raise ConfigError("the row spacing must be a number > 0 metres", key="--row-spacing", value=row_spacing_m)
    if weights not in ("equal", "energy"):
        raise ConfigError("echo weights must be 'equal' or 'energy'", key="--weights", value=weights)
    if not (np.isfinite(G) and 0 < G <= 1):
        raise ConfigError("G (mean projection of unit plant area) must lie in (0, 1]", key="--G", value=G)
    for spec in estimators:  # refuse a bad plug-in before minutes of scanning
        if isinstance(spec, str):
            load_plugin(spec)
    for cmd in commands:
        check_command(cmd)
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, overrides)
    tc = cfg["truth"]
    geometry, ground_area = truth_geometry(cfg)
    grid = truth_grid(cfg, geometry, voxel_m)  # a voxel too fine for the scene: refused before the scan
    shown = make_progress(progress)
    with staged_dir(out_dir, EVALUATE_OUTPUTS) as stage:
        t = time.perf_counter()
        run = run_scan(cfg, stage / "scan", write_png=False, progress=shown)
        scan_s = time.perf_counter() - t
        t = time.perf_counter()
        pieces = LeafPieces(grid)
        truth = compute_truth(geometry, grid, progress=shown, ground_area_m2=tc["ground_area_m2"] or ground_area,
                              crs=cfg["scene"]["crs"], ground_z_m=cfg["ground"]["z_m"], leaf_pieces=pieces)
        truth_s = time.perf_counter() - t
        results = run.result if isinstance(run.result, list) else [run.result]
        if all(hasattr(r, "range_m") for r in results):
            first = beams_from_scan(results)
            multi = beams_from_scan(results, weights) if results[0].echoes is not None else None
        else:  # streamed to files: rebuild the rays from the patterns and read the EXRs
            lo, hi = geometry.bounds_m()
            patterns = scan_patterns(cfg, lo, hi, geometry.near_x_m)
            exrs = [stage / "scan" / ("scan.exr" if len(patterns) == 1 else f"scan_leg{j}.exr")
                    for j in range(len(patterns))]
            parts = [beams_from_exr(p, pat) for p, pat in zip(exrs, patterns)]
            first = parts[0] if len(parts) == 1 else _concat(parts)
            multi = None
        extra = {"scene": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed,
                 "multi_return_weights": weights if multi is not None else None,
                 "seconds": {"scan": round(scan_s, 3), "truth": round(truth_s, 3)}}
        spacing = row_spacing_m if row_spacing_m is not None else row_spacing_of(cfg)
        out = evaluate_beams(grid, truth, first, multi, stage=stage, scan_dir=stage / "scan",
                             plugins=estimators, commands=commands, G=G, min_points=min_points,
                             saturated=saturated, min_beams=min_beams, row_spacing_m=spacing,
                             row_axis=tc["row_axis"], canopy_base=tc["canopy_base"],
                             ground_z_m=cfg["ground"]["z_m"], progress=shown, title=cfg["scene"]["name"],
                             extra=extra, crs=cfg["scene"]["crs"], leaf_pieces=pieces, terrain=geometry.terrain)
    out.files = {n: Path(out_dir) / n for n in ("scores.csv", "scores.json", "profiles.csv", "profiles.png",
                                                "scatter.png", "truth.nc", "grid.nc", "estimates", "scan")}
    return out


def _real(v) -> bool:
    """A finite real number (not a boolean)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _concat(parts):
    from .traverse import Beams  # noqa: PLC0415
    return Beams(*(np.concatenate([getattr(b, f) for b in parts]) for f in
                   ("origin_m", "dir", "t_end_m", "ret_range_m", "ret_weight", "ret_veg")))
