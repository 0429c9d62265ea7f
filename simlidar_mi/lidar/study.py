"""SIMLIDAR's §5 study: many virtual orchards, their scans, and how A_PR and A_L follow A_IM.

The paper scanned 42 orchards (iterations 4–7, d_m 5/6/7 mm, 1 or 4 trees, pruning and
stochastic on/off) and fitted A_PR = 3.6166·A_IM (R² 0.70) and A_L = 10.812·A_IM
(R² 0.78).  :func:`run_study` runs the full factorial grid (or any list of overrides)
on a base scene, one orchard per task, with Dask as the engine (``workers`` > 1 runs
tasks in separate processes; ``scheduler``, ``DASK_SCHEDULER_ADDRESS`` or an active
``distributed.Client`` runs them on a cluster, see :mod:`simlidar_mi._runtime.cluster`).  Every finished
orchard is written at once to ``rows/<key>.json``, so an interrupted study resumes where it
stopped; each row names the ``worker`` that computed it.  Outputs:
``study.csv`` (one row per orchard), ``regression.json`` and ``correlations.png``.

A row's key hashes what it was computed from: the resolved scene (every key of the
validated scene after the overrides, OBJ files by content, see :func:`scene_table`), the
code (:func:`code_version`), the row schema and the readings flag.  A row is reused only
when all of these match; rows of this grid scanned from another scene or by other code
are recomputed (``on_mismatch="recompute"``, the default) or refused
(``on_mismatch="refuse"``), and either way the message names the orchards and what
differs.  Worker processes end when the study process dies, even by SIGKILL
(:mod:`simlidar_mi._runtime.pool`; a Dask worker: :func:`_die_with_parent`).

Each orchard is also scanned under the other readings of the paper that move the result
(:data:`READINGS`: the fraction rule, eq. 8's far-side limits, and the study as it was
before both were corrected), from the same built scene, so ``regression.json`` can say how
much each choice moves the slope.  It also holds centred and uncentred R², fits per
iteration count, number of trees and trunk distance, and seeded percentile-bootstrap 95 %
intervals of the slope (:func:`bootstrap_slopes`): of this grid's slope, and of a study of
the paper's 42 orchards drawn from this grid.

Where the trees stand is not in the paper, and it moves the slope (nearer trees hide less of
their own wood from the beams' wide angles): ``trunk_distances_m`` makes the trunks' distance
from the scanner line, ``orchard.row_x_m − scan.x0_m``, a dimension of the grid, and
``regression.json`` fits each distance on its own (``by_trunk_distance``).  The default is the
scene's own placement (1.5 m in ``scenes/apple_orchard.toml``), a choice of ours.

Every orchard is scanned with the paper's hit test by default: a dot matrix of precision
P = 2 (3 × 3 sub-beams, footprint 2) and ``scan.hit_rule = "any"`` (§3.1: a beam hits
when any point of its dot matrix lies inside a branch).  ``hit_rule="fraction"`` keeps
the scene's own footprint and weights each beam by its share of sub-beams that hit.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import logging
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._runtime.cluster import code_version  # noqa: F401  (rows record it; tests patch it here)
from .._version import __version__  # noqa: F401
from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..io.atomic import atomic_file, read_nofollow, refuse_linked_dir, staged_dir, write_csv, writes_output

log = logging.getLogger(__name__)

PAPER = {"A_PR": (3.6166, 0.7002), "A_L": (10.812, 0.7756)}  # slope, R² (paper eq. 15)
COLUMNS = ["key", "iterations", "d_min_m", "n_trees", "pruning", "stochastic", "trunk_distance_m", "n_branches",
           "N", "M", "footprint", "hit_rule", "V_L_m3", "A_L_m2", "A_PR_m2", "A_PR_exact_m2",
           "A_IM_m2", "A_IM_yz_m2", "A_PR_swept_share", "scan_seconds"]
PAPER_FOOTPRINT = 2  # SIMLIDAR §3.1 takes P = 2
PAPER_N_ORCHARDS = 42  # the paper's study size (§5)
N_BOOTSTRAP = 2000  # resamples behind each bootstrap interval
# Bump when a row's contents change, so that rows of an older study are never reused.
# 3: keys hash the resolved scene and the code version; rows record both.
ROW_SCHEMA = 3
# Scene keys that cannot change a row (left out of its key); execution knobs (Key.knob:
# chunk sizes, size limits) are left out too.
NOT_IN_KEY = {"scene.name"}
# Other readings of the paper, each a re-scan of the same built orchard: (scan-setting
# changes, what it is).  The primary scan is the study's own (by default P = 2, "any",
# near-side eq. 8 limits).
READINGS = {
    "fraction": ({"hit_rule": "fraction"}, "sub-beam share instead of the any-point rule"),
    "far": ({"theta_limits_side": "far"}, "eq. 8 limits from the far side of the wood"),
    "old": ({"hit_rule": "fraction", "theta_limits_side": "far", "footprint": 0},
            "the study before the fidelity fixes: far-side limits, one ray per beam"),
}
COLUMNS += [f"A_IM_{name}_m2" for name in READINGS]
# Who computed the row ("tcp://10.0.0.5:39001" on a cluster, "local:<host>:<pid>" locally):
# like the timings, the only column that may differ between two runs of the same study.
COLUMNS += ["worker"]


def paper_grid(iterations=(4, 5, 6, 7), d_min_m=(0.005, 0.006, 0.007), n_trees=(1, 4),
               pruning=(False, True), stochastic=(False, True)) -> list[list[str]]:
    """Override lists for the §5 factorial grid (96 orchards with the defaults)."""
    grid = []
    for it, d, n, pr, st in itertools.product(iterations, d_min_m, n_trees, pruning, stochastic):
        grid.append([f"orchard.tree.iterations={it}", f"orchard.tree.d_min_m={d}",
                     f"orchard.n_trees={n}", f"orchard.tree.pruning={str(pr).lower()}",
                     f"orchard.tree.stochastic={str(st).lower()}"])
    return grid


def _legacy_key(overrides: list[str], readings: bool = True) -> str:
    """The key of a row-schema-2 row (overrides only), to say why such rows are not reused."""
    text = "\n".join(["row-schema 2", f"readings {readings}", *overrides])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _file_sha256(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "unreadable"  # the scan itself will say what is wrong with the file


def scene_table(cfg: SceneConfig) -> dict[str, Any]:
    """The resolved scene as a flat ``{"section.key": value}`` table: every validated key
    after defaults and overrides (so the same effective scene gives the same table however
    it was written), OBJ primitives by the SHA-256 of their file, and the sections the file
    declares (they choose what is generated)."""
    from ..config.keys import SECTIONS  # noqa: PLC0415
    table: dict[str, Any] = {"sections": sorted(cfg.declared)}
    for section, values in cfg.sections.items():
        for key, value in values.items():
            if f"{section}.{key}" not in NOT_IN_KEY and not SECTIONS[section][key].knob:
                table[f"{section}.{key}"] = value
    for name, items in cfg.arrays.items():
        for j, item in enumerate(items):
            for key, value in item.items():
                if name == "primitive" and key == "path" and value is not None:
                    value = "sha256:" + _file_sha256(value)
                table[f"{name}[{j}].{key}"] = value
    return table


def _key(table: dict[str, Any], readings: bool = True, version: str | None = None) -> str:
    """A row's key: the resolved scene, the code, the row schema and the readings flag."""
    text = json.dumps({"row_schema": ROW_SCHEMA, "readings": readings,
                       "code": code_version() if version is None else version, "scene": table},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _die_with_parent(parent_pid: int) -> None:
    """Dask worker initializer: end this worker as soon as the study process dies, even by
    SIGKILL, so that no orphan keeps scanning and writing rows."""
    from .._runtime.fork import die_with_parent  # noqa: PLC0415
    die_with_parent(parent_pid)


def run_one(scene: str, overrides: list[str], rows_dir: str | None, readings: bool = True,
            version: str | None = None, *, text: str | None = None,
            obj_files: dict[str, str] | None = None) -> dict:
    """Scan one orchard (and its other readings), write its row (unless ``rows_dir`` is
    None) and return it.

    A Dask task, so module-level.  The orchard is generated and built once; each reading
    of :data:`READINGS` is one more scan of the same Mitsuba scene.  ``version`` is the
    study's :func:`code_version` (default: this process's).  ``text`` is the scene file's
    text (then ``scene`` only names it), ``obj_files`` maps the scene's OBJ paths to local
    copies: how a cluster worker scans a scene it cannot read from disk.  The row records
    the ``worker`` that computed it (:func:`simlidar_mi._runtime.cluster.worker_name`).
    """
    from dataclasses import replace  # noqa: PLC0415

    from .._runtime.cluster import worker_name  # noqa: PLC0415
    from .scan import resolve_settings, scan  # noqa: PLC0415  (imports Mitsuba in the worker)
    from .survey import build, generate, scan_measures, scan_patterns  # noqa: PLC0415
    cfg = load_scene(scene, overrides, text=text)
    for prim in cfg.arrays.get("primitive", []):
        if prim.get("type") in ("obj", "ply") and obj_files and prim.get("path") in obj_files:
            prim["path"] = obj_files[prim["path"]]
    version = code_version() if version is None else version
    table = scene_table(cfg)
    if cfg["platform"]["kind"] != "tractor":
        raise ConfigError("the §5 study scans with the tractor", file=cfg.source,
                          key="platform.kind", value=cfg["platform"]["kind"])
    t0 = time.perf_counter()
    geometry = generate(cfg)
    lo, hi = geometry.bounds_m()
    settings = scan_patterns(cfg, lo, hi, geometry.near_x_m)[0]
    built = build(cfg, geometry, [settings])  # the origin covers these scanner positions
    t1 = time.perf_counter()
    result = scan(built, settings, cfg["scene"]["variant"])
    seconds = time.perf_counter() - t1
    m = scan_measures(cfg, geometry, built, [result])
    t = cfg["orchard.tree"]
    row = {"key": _key(table, readings, version), "iterations": t["iterations"], "d_min_m": t["d_min_m"],
           "n_trees": cfg["orchard"]["n_trees"], "pruning": t["pruning"], "stochastic": t["stochastic"],
           "trunk_distance_m": trunk_distance_m(cfg["orchard"]["row_x_m"], cfg["scan"]["x0_m"]),
           "n_branches": m["n_branches"], "N": m["N"], "M": m["M"], "footprint": m["footprint"],
           "hit_rule": m["hit_rule"], "A_PR_swept_share": m.get("A_PR_swept_share"), "V_L_m3": m["V_L_m3"],
           "A_L_m2": m["A_L_m2"], "A_PR_m2": m["A_PR_m2"], "A_PR_exact_m2": m["A_PR_exact_m2"],
           "A_IM_m2": m["A_IM_m2"], "A_IM_yz_m2": m["A_IM_yz_m2"], "scan_seconds": seconds,
           "overrides": overrides, "readings": readings, "row_schema": ROW_SCHEMA,
           "code_version": version, "scene": table}
    if readings:
        for name, (change, _) in READINGS.items():
            sc = {**cfg["scan"], **change}
            s = (resolve_settings(sc, dict(cfg["ground"], enabled=settings.ground), lo, hi, cfg.source,
                                  geometry.near_x_m)
                 if "theta_limits_side" in change else settings)
            s = replace(s, hit_rule=sc["hit_rule"], footprint=sc["footprint"])
            row[f"A_IM_{name}_m2"] = scan(built, s, cfg["scene"]["variant"]).impacted_area_m2()
    row["seconds"] = time.perf_counter() - t0
    row["worker"] = worker_name()
    if rows_dir is not None:
        _save_row(Path(rows_dir), row)
    return row


def _read_row(path: Path, quiet: bool = False) -> dict | None:
    """The row saved at ``path``; None when there is none, or when it cannot be read (a file cut
    short by a crash or a full disk, another program's): then it counts as missing, is scanned
    again and overwritten, and a warning says so."""
    try:  # never through a link: a row named by a link is not read, and is replaced when rescanned
        row = json.loads(read_nofollow(path, None))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        row, why = None, f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    else:
        why = None if isinstance(row, dict) and row.get("key") == path.stem else "not a row of this key"
    if why is None:
        return row
    if not quiet:
        log.warning("study: %s cannot be read (%s); its orchard is scanned again", path, why)
    return None


def _save_row(rows_dir: Path, row: dict) -> None:
    """``rows/<key>.json``: the same bytes whoever writes it (a local worker or the study
    process for a cluster's worker)."""
    from .._runtime.signals import interrupts_deferred  # noqa: PLC0415
    with interrupts_deferred(), atomic_file(rows_dir / f"{row['key']}.json") as tmp:
        tmp.write_text(json.dumps(row, sort_keys=True, default=str))  # whole, or not at all


def _scene_bundle(scene: str, cfgs: list[SceneConfig]) -> dict[str, Any]:
    """What a cluster worker needs to scan the study's scene without this machine's files:
    the scene file's text and the bytes of every OBJ file the grid's orchards use."""
    objs: dict[str, bytes] = {}
    for cfg in cfgs:
        for prim in cfg.arrays.get("primitive", []):
            if prim.get("type") in ("obj", "ply") and prim.get("path") and prim["path"] not in objs:
                try:
                    objs[prim["path"]] = Path(prim["path"]).read_bytes()
                except OSError as exc:
                    raise ConfigError(f"cannot read mesh file: {exc.strerror or exc}", file=scene,
                                      key="primitive.path", value=prim["path"]) from exc
    return {"scene": scene, "text": Path(scene).read_bytes().decode("utf-8"), "objs": objs}


def _cluster_task(bundle: dict[str, Any], overrides: list[str], readings: bool, version: str) -> dict:
    """:func:`run_one` on a cluster worker: the scene comes as data (``bundle``), the row goes
    back to the study process, which writes it.  A worker running other code (another
    simlidar-mi, Mitsuba or Dr.Jit) refuses, so that no row is filed under the wrong version."""
    import tempfile  # noqa: PLC0415

    from .._runtime.cluster import worker_name  # noqa: PLC0415
    mine = code_version()
    if mine != version:
        raise ConfigError(f"Dask worker {worker_name()} runs other code ({mine}) than the study "
                          f"({version}): install the same simlidar-mi, mitsuba and drjit on every "
                          "worker")
    with tempfile.TemporaryDirectory(prefix="simlidar-study-") as tmp:
        local = {}
        for j, (path, data) in enumerate(sorted(bundle["objs"].items())):
            local[path] = str(Path(tmp) / f"{j}_{Path(path).name}")
            Path(local[path]).write_bytes(data)
        return run_one(bundle["scene"], overrides, None, readings, version, text=bundle["text"],
                       obj_files=local)


def fit_through_origin(x: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """y = b·x by least squares through the origin.

    ``r2`` is centred, 1 − SS_res / Σ(y − ȳ)², the usual reading of a reported R²;
    ``r2_uncentred`` is 1 − SS_res / Σy², what many tools report for a fit without an
    intercept (and always the larger of the two)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    b = float(np.dot(x, y) / np.dot(x, x))
    ss_res = float(np.sum((y - b * x) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    ss_unc = float(np.sum(y ** 2))
    return {"slope": b, "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan"),
            "r2_uncentred": 1.0 - ss_res / ss_unc if ss_unc > 0 else float("nan"),
            "pearson_r": float(np.corrcoef(x, y)[0, 1]) if len(x) > 1 and x.std() > 0 and y.std() > 0
            else float("nan"), "n": int(len(x))}


def bootstrap_slopes(x, y, size: int | None = None, n_resamples: int = N_BOOTSTRAP,
                     seed: int = 0) -> dict[str, Any]:
    """Percentile-bootstrap 95 % interval of the through-origin slope (Efron & Tibshirani
    1993, *An Introduction to the Bootstrap*, ch. 13): ``n_resamples`` draws of ``size`` rows
    *with* replacement (default: all n rows, the interval of this grid's slope; ``size`` = 42:
    where a study of the paper's size drawn from the same population of orchards could land).

    Drawing 42 of 96 without replacement, as this study did before, understates that spread
    by the finite-population factor √((96 − 42)/(96 − 1)) = √(54/95)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    n = len(x)
    size = n if size is None else int(size)
    out: dict[str, Any] = {"method": "percentile bootstrap, rows drawn with replacement",
                           "size": size, "n_resamples": 0, "seed": seed,
                           "slope_2.5%": float("nan"), "slope_97.5%": float("nan")}
    if n < 2 or size < 1:
        return out
    idx = np.random.default_rng(seed).integers(0, n, size=(n_resamples, size))
    den = np.sum(x[idx] ** 2, axis=1)
    slopes = np.sum(x[idx] * y[idx], axis=1)[den > 0] / den[den > 0]  # an all-zero draw has no slope
    lo, hi = np.percentile(slopes, [2.5, 97.5])
    out.update({"n_resamples": n_resamples, "slope_2.5%": float(lo), "slope_97.5%": float(hi)})
    return out


def trunk_distance_m(row_x_m: float, x0_m: float) -> float:
    """The trunks' distance from the scanner line (``orchard.row_x_m − scan.x0_m``), rounded
    to 0.1 mm so that 2.5 − 1.0 and 1.5 name the same group."""
    return round(float(row_x_m) - float(x0_m), 4)


def _row_trunk_distance(row: dict) -> float | None:
    """A row's trunk distance (rows saved before the column existed: from their scene; None
    when neither says)."""
    if row.get("trunk_distance_m") is not None:
        return float(row["trunk_distance_m"])
    sc = row.get("scene", {})
    if "orchard.row_x_m" in sc and "scan.x0_m" in sc:
        return trunk_distance_m(sc["orchard.row_x_m"], sc["scan.x0_m"])
    return None


def regression_report(rows: list[dict]) -> dict:
    """Everything ``regression.json`` holds, from the study's rows."""
    col = {k: np.array([r[k] for r in rows], float) for k in ("A_IM_m2", "A_IM_yz_m2", "A_PR_m2",
                                                             "A_L_m2", "A_PR_exact_m2")}
    a_im = col["A_IM_m2"]
    report = {
        "A_PR_vs_A_IM": fit_through_origin(a_im, col["A_PR_m2"]),
        "A_L_vs_A_IM": fit_through_origin(a_im, col["A_L_m2"]),
        "A_PR_exact_vs_A_IM": fit_through_origin(a_im, col["A_PR_exact_m2"]),
        "scan": {"hit_rule": sorted({r["hit_rule"] for r in rows}),
                 "footprint": sorted({r["footprint"] for r in rows})},
        "paper": {"A_PR_vs_A_IM": {"slope": PAPER["A_PR"][0], "r2": PAPER["A_PR"][1]},
                  "A_L_vs_A_IM": {"slope": PAPER["A_L"][0], "r2": PAPER["A_L"][1]}},
    }
    groups: dict[str, dict] = {}
    trunk = [_row_trunk_distance(r) for r in rows]
    for field_, values in (("iterations", [r["iterations"] for r in rows]),
                           ("n_trees", [r["n_trees"] for r in rows]), ("trunk_distance_m", trunk)):
        for value in sorted(set(values) - {None}):
            sel = np.array([v == value for v in values])
            groups[f"{field_}={value}"] = {
                "A_PR_vs_A_IM": fit_through_origin(a_im[sel], col["A_PR_m2"][sel]),
                "A_L_vs_A_IM": fit_through_origin(a_im[sel], col["A_L_m2"][sel])}
    report["subgroups"] = groups
    # The slope against where the trees stand (the paper does not say): one fit per distance,
    # each with its own bootstrap interval.
    report["by_trunk_distance"] = [
        {"trunk_distance_m": d, **groups[f"trunk_distance_m={d}"]["A_PR_vs_A_IM"],
         "bootstrap": bootstrap_slopes(a_im[np.array(trunk) == d], col["A_PR_m2"][np.array(trunk) == d])}
        for d in sorted(set(trunk) - {None})]
    report["bootstrap"] = {
        key: {"grid": bootstrap_slopes(a_im, col[ycol]),
              "paper_size": bootstrap_slopes(a_im, col[ycol], size=PAPER_N_ORCHARDS)}
        for key, ycol in (("A_PR_vs_A_IM", "A_PR_m2"), ("A_L_vs_A_IM", "A_L_m2"))}
    readings = {"study": {"what": "the study's own scan", **fit_through_origin(a_im, col["A_PR_m2"])},
                "A_IM_yz": {"what": "A_IM projected exactly on the YZ plane (not eq. 1's l·Δsin θ)",
                            **fit_through_origin(col["A_IM_yz_m2"], col["A_PR_m2"])}}
    for name, (_, what) in READINGS.items():
        key = f"A_IM_{name}_m2"
        if all(key in r for r in rows):
            readings[name] = {"what": what, **fit_through_origin([r[key] for r in rows], col["A_PR_m2"])}
    report["A_PR_vs_A_IM_by_reading"] = readings
    report["notes"] = [
        "A_L = π·A_PR for every orchard by definition (A_L = Σπdh, A_PR = Σdh), so the two fits "
        "have the same R² and slopes in the ratio π. The paper's 10.812 / 3.6166 = 2.990 and its "
        "two R² (0.78 vs 0.70) show that its two fits did not use identical data.",
        "r2 is centred (about the mean of y); r2_uncentred is about zero, as many tools report "
        "for a fit through the origin. The paper does not say which it printed.",
        "trunk_distance_m (orchard.row_x_m - scan.x0_m) is not in the paper: the scene's own "
        "placement is our choice; by_trunk_distance fits each distance on its own, and the "
        "headline fits pool every distance of the grid.",
        f"bootstrap: {N_BOOTSTRAP} seeded resamples with replacement; 'grid' is the interval of "
        f"this grid's slope, 'paper_size' where a study of {PAPER_N_ORCHARDS} orchards drawn from "
        "the same population could land.",
    ]
    return report


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


def _ranges(indices: list[int]) -> str:
    """[1, 2, 3, 7] → '#1–3, #7' (1-based grid positions)."""
    parts, i = [], 0
    while i < len(indices):
        j = i
        while j + 1 < len(indices) and indices[j + 1] == indices[j] + 1:
            j += 1
        parts.append(f"#{indices[i]}" if i == j else f"#{indices[i]}–{indices[j]}")
        i = j + 1
    return ", ".join(parts)


def _why(old: dict, table: dict[str, Any], version: str) -> str:
    """What differs between an old row and the orchard it would stand for."""
    if old.get("row_schema", 2) != ROW_SCHEMA or "scene" not in old:
        return (f"an earlier row format (schema {old.get('row_schema', 2)}, now {ROW_SCHEMA}) that "
                "did not record its scene or code")
    why = []
    if old.get("code_version") != version:
        why.append(f"other code ({old.get('code_version')}, now {version})")
    new = json.loads(json.dumps(table, default=str))
    diff = [k for k in sorted(set(new) | set(old["scene"])) if new.get(k) != old["scene"].get(k)]
    if diff:
        shown = ", ".join(f"{k} {old['scene'].get(k)!r} → {new.get(k)!r}" for k in diff[:4])
        why.append(f"another scene ({shown}{f', and {len(diff) - 4} more keys' if len(diff) > 4 else ''})")
    return " and ".join(why) or "another key"


def _stale(rows_dir: Path, grid: list[list[str]], keys: list[str], tables: list[dict],
           readings: bool, version: str) -> tuple[dict[str, list[int]], int]:
    """Rows in ``rows_dir`` that stand for orchards of this grid (same overrides and readings
    flag) but were computed from another scene or code: ``{reason: [grid positions]}``, and
    the number of other rows that belong to no orchard of this grid."""
    wanted = set(keys)
    by_overrides: dict[tuple, list[dict]] = {}
    n_other = 0
    for f in sorted(rows_dir.glob("*.json"), key=lambda f: -f.stat().st_mtime_ns):  # newest first
        if f.stem in wanted:
            continue
        try:
            old = json.loads(f.read_text())
        except (OSError, ValueError):
            old = {}
        n_other += 1
        if "overrides" in old:
            by_overrides.setdefault(tuple(old["overrides"]), []).append(old)
    reasons: dict[str, list[int]] = {}
    for i, (o, key, table) in enumerate(zip(grid, keys, tables)):
        if (rows_dir / f"{key}.json").exists():
            continue
        for old in by_overrides.get(tuple(o), []):
            same_flag = (old.get("readings") == readings if "readings" in old
                         else old.get("key") == _legacy_key(o, readings))
            if same_flag:
                reasons.setdefault(_why(old, table, version), []).append(i + 1)
                n_other -= 1
                break
    return reasons, max(n_other, 0)


def with_trunk_distances(scene: str, grid: list[list[str]], distances_m) -> list[list[str]]:
    """``grid`` repeated once per trunk distance d (outer loop), each entry with
    ``orchard.row_x_m = scan.x0_m + d`` (its own x0, after its overrides)."""
    ds = list(distances_m)
    if not ds:
        raise ConfigError("give at least one trunk distance", key="trunk_distances_m", value=ds)
    for d in ds:
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not np.isfinite(d) or d <= 0:
            raise ConfigError("a trunk distance must be a number of metres > 0", key="trunk_distances_m",
                              value=d)
    out = []
    for d in ds:
        for g in grid:
            x0 = load_scene(scene, g)["scan"]["x0_m"]
            out.append(list(g) + [f"orchard.row_x_m={round(float(x0) + float(d), 9)!r}"])
    return out


@writes_output("out_dir")
def run_study(scene: str | Path, out_dir: str | Path, grid: list[list[str]] | None = None, *,
              workers: int = 1, progress: bool = False, hit_rule: str = "any",
              footprint: int | None = None, readings: bool = True,
              on_mismatch: str = "recompute", scheduler: str | None = None,
              trunk_distances_m: list[float] | None = None) -> StudyResult:
    """Run (or resume) the study of ``grid`` (default :func:`paper_grid`) on ``scene``.

    ``hit_rule`` and ``footprint`` (see :func:`scan_overrides`) come before each grid
    entry's overrides, so an entry may still set its own.  ``readings=False`` skips the
    re-scans under :data:`READINGS` (about half the scan time).

    ``trunk_distances_m`` (e.g. ``[1.5, 2.0, 2.5]``) repeats the grid with the trunks at each
    distance from the scanner line: ``orchard.row_x_m = scan.x0_m + d``, after each entry's
    own overrides (None: the scene's own placement).

    A row in ``out_dir/rows`` is reused only when its key matches: same resolved scene,
    code, row schema and readings flag.  When rows of this grid's orchards were scanned
    from another scene or by other code, ``on_mismatch="recompute"`` (default) rescans
    them and logs a warning naming the orchards (grid positions) and what differs; the
    old rows stay in ``rows/``, unused, so nothing computed is lost.
    ``on_mismatch="refuse"`` raises :class:`ConfigError` saying the same, before any scan.

    Where the orchards are scanned (:func:`simlidar_mi._runtime.cluster.cluster_client`): the Dask
    scheduler at ``scheduler`` (``"tcp://host:8786"``; ``"local"`` forces the local pool),
    else an active ``distributed.Client``, else ``DASK_SCHEDULER_ADDRESS``, else ``workers``
    local processes.  On a cluster the scene file and its OBJ files are sent to the workers
    as data (they need simlidar-mi, the same version, but not this machine's files) and
    each row comes back to be written here as soon as its orchard is done."""
    if on_mismatch not in ("recompute", "refuse"):
        raise ConfigError("must be 'recompute' or 'refuse'", key="on_mismatch", value=on_mismatch)
    from .._runtime.cluster import check_scheduler  # noqa: PLC0415
    check_scheduler(scheduler)  # an empty address is refused before any work
    scene = str(Path(scene).resolve())
    load_scene(scene)  # fail early, before any task, on a bad base scene
    grid = paper_grid() if grid is None else grid
    if not grid:
        raise ConfigError("the study grid is empty", file=scene)
    rule = scan_overrides(hit_rule, footprint)
    grid = [rule + list(g) for g in grid]
    if trunk_distances_m is not None:
        grid = with_trunk_distances(scene, grid, trunk_distances_m)
    version = code_version()
    cfgs = [load_scene(scene, o) for o in grid]
    tables = [scene_table(c) for c in cfgs]
    keys = [_key(t, readings, version) for t in tables]
    out = Path(out_dir)
    rows_dir = out / "rows"
    refuse_linked_dir(rows_dir, "the study writes its rows there")
    if rows_dir.is_dir():
        reasons, n_other = _stale(rows_dir, grid, keys, tables, readings, version)
        if reasons:
            what = "; ".join(f"orchard{'s' * (len(ix) > 1)} {_ranges(ix)} of the grid "
                             f"{'were' if len(ix) > 1 else 'was'} scanned from {why}"
                             for why, ix in reasons.items())
            n = sum(map(len, reasons.values()))
            if on_mismatch == "refuse":
                raise ConfigError(f"holds rows for {n} of this study's {len(grid)} orchards that were "
                                  f"computed from something else: {what}; rescan them with "
                                  "--on-mismatch recompute, or choose another --out", file=rows_dir)
            log.warning("study: %s: recomputing %d of %d orchards (the old rows stay there, unused): %s",
                        rows_dir, n, len(grid), what)
        if n_other:
            log.warning("study: %s also holds %d rows of other grids or options, unused", rows_dir, n_other)
    todo = [(o, k) for o, k in zip(grid, keys) if _read_row(rows_dir / f"{k}.json") is None]
    if todo:
        from .._runtime.cluster import cluster_client, run_on_client  # noqa: PLC0415
        with cluster_client(scheduler) as client:
            # only once the scheduler (if any) answered: an unreachable one leaves no folder behind
            rows_dir.mkdir(parents=True, exist_ok=True)
            if client is None:
                _run_local(scene, todo, rows_dir, readings, version, workers, progress)
            else:
                if workers > 1:
                    log.warning("study: workers=%d ignored: the Dask cluster's workers scan", workers)
                calls = [(o, readings, version) for o, _ in todo]
                with make_progress(progress).stage("study: scanning", len(todo), "orchard", ticks=True) as st:
                    # each row is saved here the moment it arrives: an interrupted study resumes
                    run_on_client(client, _cluster_task, calls, shared=_scene_bundle(scene, cfgs),
                                  on_result=lambda row: (_save_row(rows_dir, row), st.update()))
        missing = [k for _, k in todo if _read_row(rows_dir / f"{k}.json", quiet=True) is None]
        if missing:  # a task keys its row by what it scanned: the inputs moved under us
            raise ConfigError(f"{len(missing)} rows were written under other keys than planned: the "
                              "scene or one of its OBJ files changed while the study ran; run it again",
                              file=scene)
    rows = [_read_row(rows_dir / f"{k}.json", quiet=True) for k in keys]
    regression = regression_report(rows)
    regression["code_version"] = version
    # The final set is replaced as one: an interrupt or a failure while it is written leaves
    # the earlier study.csv, regression.json and correlations.png together (rows/ is not in it).
    with staged_dir(out, [re.escape(name) for name in FINAL_FILES.values()]) as stage:
        write_csv(stage / FINAL_FILES["csv"], COLUMNS, rows, extrasaction="ignore")
        (stage / FINAL_FILES["regression"]).write_text(json.dumps(regression, indent=2) + "\n")
        _plot(rows, regression, stage / FINAL_FILES["png"])
    return StudyResult(rows, regression, {k: out / name for k, name in FINAL_FILES.items()})


#: The files a study writes at its end, from its rows.
FINAL_FILES = {"csv": "study.csv", "regression": "regression.json", "png": "correlations.png"}


def _run_local(scene: str, todo: list[tuple[list[str], str]], rows_dir: Path, readings: bool,
               version: str, workers: int, progress: Any) -> None:
    """The orchards of ``todo`` on Dask's local scheduler: this process, or ``workers``
    processes; each task writes its own row."""
    import dask  # noqa: PLC0415
    from dask.callbacks import Callback  # noqa: PLC0415
    tasks = [dask.delayed(run_one)(scene, o, str(rows_dir), readings, version) for o, _ in todo]
    # one tick per finished orchard, through the package's progress (never on stdout)
    with make_progress(progress).stage("study: scanning", len(todo), "orchard", ticks=True) as st, \
            Callback(posttask=lambda *_: st.update()):
        if workers <= 1:
            dask.compute(*tasks, scheduler="synchronous")
            return
        from dask.multiprocessing import initialize_worker_process  # noqa: PLC0415

        from .._runtime.pool import worker_pool  # noqa: PLC0415
        # Workers start deaf to Ctrl-C, die with this process (SIGKILL included) and are
        # ended by it when it is interrupted (simlidar_mi._runtime.pool).
        with worker_pool(workers, initialize_worker_process) as pool:
            dask.compute(*tasks, scheduler="processes", pool=pool)


def _plot(rows: list[dict], regression: dict, path: Path) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    a_im = np.array([r["A_IM_m2"] for r in rows])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), dpi=120)
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
    # How much each reading of the paper moves the A_PR slope, against the paper's.
    ax = axes[2]
    by = regression["A_PR_vs_A_IM_by_reading"]
    names = list(by)
    ax.barh(names, [by[n]["slope"] for n in names], color="0.6")
    sub = regression["bootstrap"]["A_PR_vs_A_IM"]["paper_size"]
    if sub["n_resamples"]:
        ax.errorbar([by["study"]["slope"]], [names.index("study")], fmt="none", ecolor="k", capsize=4,
                    xerr=[[by["study"]["slope"] - sub["slope_2.5%"]], [sub["slope_97.5%"] - by["study"]["slope"]]])
    ax.axvline(PAPER["A_PR"][0], color="r", ls="--", lw=1, label=f"paper {PAPER['A_PR'][0]}")
    ax.set_xlabel(f"A_PR / A_IM slope (bar: bootstrap 95 % of a {PAPER_N_ORCHARDS}-orchard study)")
    ax.invert_yaxis()
    ax.legend(fontsize=8)
    fig.suptitle(f"SIMLIDAR §5 study: {len(rows)} virtual orchards")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
