"""A scan split into row tiles that run as Dask tasks on a cluster, merged into one result.

:func:`simlidar_mi.lidar.survey.run_scan` calls :func:`scan_on_cluster` when a cluster is
chosen (``scheduler=``, an active ``distributed.Client`` or ``DASK_SCHEDULER_ADDRESS``, see
:func:`simlidar_mi._runtime.cluster.cluster_client`).  Every pattern (leg) of the scan is cut into tiles
of ``tile_rows`` rows (airborne scan lines, path sweeps, tractor positions; by default about
:data:`DEFAULT_TILE_BEAMS` beams a tile).  The validated scene goes to the cluster once, as
data (its OBJ files by content), like the study's; each worker generates and builds it once
(:func:`_prepared` keeps the built scene per worker process, keyed by the scene's digest),
scans the rows of each tile it gets (:func:`simlidar_mi.lidar.scan.scan` with ``rows=``) and
returns the arrays.  This process merges the tiles in row order into the same
:class:`~simlidar_mi.lidar.scan.ScanResult` the one-process scan gives, so the files are
the same bytes (timings aside).

Why the bytes match: a tile fires the very rays of its rows (the whole tractor's float32
tables sliced, a pattern's per-row arrays sliced), every per-beam quantity that depends on
the beam's place in the scan uses the global index (range noise is keyed by the global beam
index; echoes carry it), and what depends on the whole scan (``gps_time``,
``scan_position``, ``point_source_id``, headers) is written here from the whole pattern.
Each worker builds the scene from the same configuration and scanner positions, so its
origin and Embree scene are the ones the one-process scan builds.

Memory: this process holds the merged result, as the one-process scan does.
"""
from __future__ import annotations

import copy
import hashlib
import logging
import pickle
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from .._runtime.progress import make_progress
from ..errors import ConfigError

log = logging.getLogger(__name__)

DEFAULT_TILE_BEAMS = 1 << 20  # ~1 M beams a tile: ~13 MB of first-return arrays to send back


def _whole(p):
    """A pattern of ``scan_patterns`` as a BeamPattern (the tractor's settings give theirs)."""
    return p.pattern() if hasattr(p, "pattern") else p


def tile_plan(patterns: list, tile_rows: int | None = None) -> list[tuple[int, int, int]]:
    """(leg, first row, end row) of every tile, legs in order, rows in order."""
    if tile_rows is not None and (isinstance(tile_rows, bool) or not isinstance(tile_rows, int)
                                  or tile_rows < 1):
        raise ConfigError("must be an integer ≥ 1 (rows of a scan tile)", key="tile_rows", value=tile_rows)
    plan = []
    for j, p in enumerate(patterns):
        pat = _whole(p)
        rows = tile_rows or max(1, DEFAULT_TILE_BEAMS // max(1, pat.n_cols))
        plan += [(j, r0, min(pat.n_rows, r0 + rows)) for r0 in range(0, pat.n_rows, rows)]
    return plan


def scene_bundle(cfg, prepare) -> dict[str, Any]:
    """What a worker needs to build the scene without this machine's files: the validated
    scene and the bytes of its OBJ files, with a digest that names both, and ``prepare``
    (``cfg -> (patterns, built scene, sensor)``, :func:`simlidar_mi.lidar.survey.prepare_scan`;
    passed in, sent by reference, so that this module does not import the workflows)."""
    objs: dict[str, bytes] = {}
    for prim in cfg.arrays.get("primitive", []):
        if prim.get("type") == "obj" and prim.get("path") and prim["path"] not in objs:
            try:
                objs[prim["path"]] = Path(prim["path"]).read_bytes()
            except OSError as exc:
                raise ConfigError(f"cannot read OBJ file: {exc.strerror or exc}", file=cfg.source,
                                  key="primitive.path", value=prim["path"]) from exc
    digest = hashlib.sha256(pickle.dumps(cfg, protocol=5))
    for path in sorted(objs):
        digest.update(path.encode() + b"\0" + objs[path])
    return {"cfg": cfg, "objs": objs, "digest": digest.hexdigest(), "prepare": prepare}


@dataclass
class _Prepared:
    cfg: Any
    patterns: list
    built: Any
    sensor: Any
    seconds: float


# One built scene per worker process (the latest scene's): its tiles reuse it.  The lock also
# keeps one scan at a time in a process (Dr.Jit already uses every core for one).
_SCENES: dict[str, _Prepared] = {}
_LOCK = threading.Lock()


def _prepared(bundle: dict[str, Any]) -> tuple[_Prepared, bool]:
    """The bundle's scene generated, built and its sensor resolved, as ``run_scan`` does;
    (it, whether this call built it).  Call with :data:`_LOCK` held."""
    got = _SCENES.get(bundle["digest"])
    if got is not None:
        return got, False
    _SCENES.clear()  # free the previous scene before building the next
    cfg = copy.deepcopy(bundle["cfg"])
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="simlidar-tiles-") as tmp:
        local = {}
        for j, (path, data) in enumerate(sorted(bundle["objs"].items())):
            local[path] = str(Path(tmp) / f"{j}_{Path(path).name}")
            Path(local[path]).write_bytes(data)
        for prim in cfg.arrays.get("primitive", []):
            if prim.get("type") == "obj" and prim.get("path") in local:
                prim["path"] = local[prim["path"]]
        patterns, built, sensor = bundle["prepare"](cfg)
    got = _Prepared(cfg, patterns, built, sensor, time.perf_counter() - t0)
    _SCENES[bundle["digest"]] = got
    return got, True


def _tile_task(bundle: dict[str, Any], leg: int, r0: int, r1: int, version: str) -> dict[str, Any]:
    """Scan rows r0 … r1 − 1 of leg ``leg`` on a worker; return the tile's arrays.  A worker
    running other code (another simlidar-mi, Mitsuba or Dr.Jit) refuses, as in the study."""
    from .._runtime.cluster import worker_name  # noqa: PLC0415
    from .scan import scan  # noqa: PLC0415
    from .._runtime.cluster import code_version  # noqa: PLC0415
    mine = code_version()
    if mine != version:
        raise ConfigError(f"Dask worker {worker_name()} runs other code ({mine}) than this scan "
                          f"({version}): install the same simlidar-mi, mitsuba and drjit on every worker")
    with _LOCK:
        prep, built_here = _prepared(bundle)
        cfg, b = prep.cfg, prep.built
        res = scan(b, prep.patterns[leg], cfg["scene"]["variant"], prep.sensor, seed=cfg.seed, leg=leg,
                   rows=(r0, r1))
    return {"leg": leg, "r0": r0, "r1": r1, "worker": worker_name(),
            "build_seconds": prep.seconds if built_here else 0.0,
            "built": {"representation": b.representation, "facets": b.facets, "origin_m": b.origin_m.copy(),
                      "n_branches": b.n_branches, "n_dropped": b.n_dropped,
                      "n_instances": b.n_instances, "n_triangles": b.n_triangles},
            **{k: getattr(res, k) for k in ("range_m", "cls", "element_id", "hit_fraction", "tree_id",
                                             "echoes", "n_returns", "intensity", "sensor", "seconds",
                                             "metadata")}}


def merge_tiles(patterns: list, tiles: list[dict[str, Any]]) -> list:
    """One :class:`~simlidar_mi.lidar.scan.ScanResult` per leg from its tiles (any order)."""
    from .scan import ScanResult, ScanSettings  # noqa: PLC0415
    from .waveform import Echoes  # noqa: PLC0415
    results = []
    for j, p in enumerate(patterns):
        mine = sorted((t for t in tiles if t["leg"] == j), key=lambda t: t["r0"])
        pat = _whole(p)
        edges = [0] + [t["r1"] for t in mine]
        if not mine or [t["r0"] for t in mine] != edges[:-1] or edges[-1] != pat.n_rows:
            raise RuntimeError(f"the tiles of leg {j} do not cover its {pat.n_rows} rows once")

        def cat(key):
            parts = [t[key] for t in mine]
            return None if parts[0] is None else np.concatenate(parts, axis=0)
        first = mine[0]
        meta = dict(first["metadata"])
        for key in ("trace_seconds", "echo_seconds"):  # timings: summed over the tiles
            if key in meta:
                meta[key] = sum(t["metadata"][key] for t in mine)
        echoes = Echoes.concat([t["echoes"] for t in mine]) if first["echoes"] is not None else None
        results.append(ScanResult(p if isinstance(p, ScanSettings) else None, cat("range_m"), cat("cls"),
                                  cat("element_id"), cat("hit_fraction"), first["built"]["origin_m"].copy(),
                                  sum(t["seconds"] for t in mine), meta, pat, cat("tree_id"),
                                  echoes=echoes, n_returns=cat("n_returns"), intensity=cat("intensity"),
                                  sensor=first["sensor"]))
    return results


def scan_on_cluster(client: Any, cfg, patterns: list, prepare, *, tile_rows: int | None = None,
                    progress: Any = False) -> tuple[Any, list, dict[str, Any]]:
    """Scan ``patterns`` of ``cfg`` in row tiles on the Dask cluster of ``client``; each
    worker builds the scene with ``prepare`` (see :func:`scene_bundle`).

    Returns (the built scene's description: ``representation``, ``facets``, ``origin_m``,
    ``n_dropped``, ``n_instances``, ``n_triangles``, as attributes; the merged results, one
    per leg; facts of the run: ``tiles``, ``workers``, ``build_seconds``, the longest build
    of one worker)."""
    from .._runtime.cluster import run_on_client  # noqa: PLC0415
    from .._runtime.cluster import code_version  # noqa: PLC0415
    plan = tile_plan(patterns, tile_rows)
    tiles: list[dict[str, Any]] = []
    with make_progress(progress).stage("scan: tiles", len(plan), "tile") as st:
        def got(tile):
            tiles.append(tile)
            st.update()
        run_on_client(client, _tile_task, [(j, r0, r1, code_version()) for j, r0, r1 in plan], got,
                      shared=scene_bundle(cfg, prepare))
    origins = {tuple(t["built"]["origin_m"]) for t in tiles}
    if len(origins) != 1:  # the same scene and positions always give one origin
        raise RuntimeError(f"workers built the scene around different origins: {sorted(origins)}")
    built = SimpleNamespace(**tiles[0]["built"])
    facts = {"tiles": len(plan), "workers": sorted({t["worker"] for t in tiles}),
             "build_seconds": max(t["build_seconds"] for t in tiles)}
    return built, merge_tiles(patterns, tiles), facts
