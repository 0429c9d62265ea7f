"""Scene file → geometry → scan → files: the calls behind ``simlidar-mi scan/measure``.

Every function here is one step a user can also call from a notebook::

    from simlidar_mi.lidar.survey import load_scene, generate, build, run_scan
    cfg = load_scene("scenes/apple_orchard.toml", ["scan.dtheta_deg=0.5"])
    run = run_scan(cfg, "out/orchard")          # writes scan.exr, scan.png, points.las, measures.json
    print(run.measures["A_IM_m2"], run.result.shape)
"""
from __future__ import annotations

import contextlib
import functools
import json
import logging
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._runtime.fork import Forked, use_fork
from .._runtime.mitsuba import check_variant, mitsuba
from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError, SimlidarWarning
from ..geometry import Branches, Leaves, Primitive
from ..io.mesh_import import mesh_drop, primitive_mesh_data, ship_meshes, unship_meshes
from ..io.atomic import atomic_file, staged_dir, writes_output
from ..io.terrain import stand_on, terrain_of
from .scene_counts import (generated_line, leaf_triangle_counts, primitive_surfaces, warn_if_unseen,  # noqa: F401
                           warn_scanner_inside_wood)
from .patterns import AIRBORNE_PULSE_RATE_HZ, AIRBORNE_SPEED_M_S, check_clearance, scan_patterns, scanner_positions_m  # noqa: F401
from .trajectory import TRAJECTORY_FILE, has_trajectory, write_trajectory

log = logging.getLogger(__name__)

__all__ = ["SceneGeometry", "ScanRun", "load_scene", "generate", "build", "run_scan",
           "measure", "SCAN_OUTPUTS"]  # preview: simlidar_mi.lidar.preview

# The files a scan owns in its folder (regular expressions of whole names): a re-run
# removes those it does not write again (points.las after --no-las or with points.laz, a leg's EXR when
# the path has fewer legs), so no file of an earlier scan sits beside the new ones.
SCAN_OUTPUTS = (r"scan\.(exr|png)", r"scan_leg\d+\.(exr|png)", r"points\.la[sz]", r"trajectory\.txt",
                r"measures\.json")


@dataclass
class SceneGeometry:
    """Everything a scene file describes, as plain data."""

    branches: Branches
    leaves: Leaves
    primitives: list[Primitive]
    seconds: float = 0.0
    instances: object = None  # mitsuba_scene.Instances for instanced forests
    source: str | None = None  # the scene file, for messages
    trees: dict | None = None  # a forest's trees.csv columns (Forest.trees_columns), when it has one
    terrain: object = None  # io.terrain.Terrain of [terrain] (the ground mesh), None: the [ground] plane

    def boxes_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned boxes (lo, hi), each (n, 3), of every branch (with radius), leaf
        triangle, primitive and placed instance."""
        lo, hi = [], []
        if len(self.branches):
            b = self.branches
            r = (0.5 * b.diameter)[:, None]
            lo.append(np.minimum(b.p0, b.p1) - r)
            hi.append(np.maximum(b.p0, b.p1) + r)
        if len(self.leaves):
            v = self.leaves.vertices
            lo.append(v.min(1))
            hi.append(v.max(1))
        for j, prim in enumerate(self.primitives):
            p = prim.params
            if prim.kind == "cylinder":
                ends = np.array([p["p0_m"], p["p1_m"]], float)
                r = 0.5 * p["diameter_m"]
                lo.append(ends.min(0, keepdims=True) - r)
                hi.append(ends.max(0, keepdims=True) + r)
            elif prim.kind == "box":
                lo.append(np.asarray([p["min_m"]], float))
                hi.append(np.asarray([p["max_m"]], float))
            elif prim.kind in ("obj", "ply"):
                v = primitive_mesh_data(prim, self.source, j).vertices
                lo.append(v.min(0, keepdims=True))
                hi.append(v.max(0, keepdims=True))
        if self.instances is not None and len(self.instances):
            inst = self.instances
            # Each prototype's bounding radius about its own z axis covers any yaw.
            ext = []
            for b, lv in inst.prototypes:
                pts = np.concatenate([b.p0, b.p1, lv.vertices.reshape(-1, 3)]) if len(lv) else np.concatenate([b.p0, b.p1])
                r = float(np.max(np.hypot(pts[:, 0], pts[:, 1]))) + float(b.diameter.max(initial=0.0))
                ext.append((r, float(pts[:, 2].min()), float(pts[:, 2].max())))
            ext = np.array(ext)[inst.proto_index]
            s = np.asarray(inst.scale, float)
            t = np.asarray(inst.translation_m, float)
            lo.append(np.column_stack([t[:, 0] - s * ext[:, 0], t[:, 1] - s * ext[:, 0],
                                       t[:, 2] + s * ext[:, 1]]))
            hi.append(np.column_stack([t[:, 0] + s * ext[:, 0], t[:, 1] + s * ext[:, 0],
                                       t[:, 2] + s * ext[:, 2]]))
        if not lo:
            raise ConfigError("the scene holds no geometry: add [orchard], [forest] or [[primitive]]")
        return np.concatenate(lo), np.concatenate(hi)

    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of branches (with radius), leaves and primitives."""
        lo, hi = self.boxes_m()
        return lo.min(0), hi.max(0)

    def inside_wood(self, points_m, chunk: int = 4096) -> tuple[np.ndarray, np.ndarray]:
        """Which points lie inside a branch or cylinder primitive (flat ends) or a box primitive.

        Returns (inside, element): a bool (n,) mask and, per point, the element id of a
        shape containing it (branch row, ``n_branches + j`` for primitive j; -1 if none).
        Only elements whose box meets the points' box are tested, in chunks of points,
        so a scanner line beside a large scene costs little.  Instanced trees are not
        tested."""
        q_all = np.asarray(points_m, np.float64).reshape(-1, 3)
        b, n_b = self.branches, len(self.branches)
        p0, p1, r = [b.p0], [b.p1], [0.5 * b.diameter]
        ids = [np.arange(n_b)]
        boxes, box_ids = [], []
        for j, prim in enumerate(self.primitives):
            p = prim.params
            if prim.kind == "cylinder":
                p0.append(np.asarray([p["p0_m"]], float))
                p1.append(np.asarray([p["p1_m"]], float))
                r.append(np.array([0.5 * p["diameter_m"]]))
                ids.append(np.array([n_b + j]))
            elif prim.kind == "box":
                boxes.append([p["min_m"], p["max_m"]])
                box_ids.append(n_b + j)
        p0, p1, r, ids = np.concatenate(p0), np.concatenate(p1), np.concatenate(r), np.concatenate(ids)
        lo, hi = np.minimum(p0, p1) - r[:, None], np.maximum(p0, p1) + r[:, None]
        element = np.full(len(q_all), -1, np.int64)
        for a in range(0, len(q_all), chunk):
            q = q_all[a:a + chunk]
            qlo, qhi = q.min(0), q.max(0)
            cand = np.flatnonzero(np.all((hi >= qlo) & (lo <= qhi), axis=1))
            step = max(1, 2_000_000 // len(q))  # bounds the (points × segments) arrays
            for c0 in range(0, len(cand), step):
                c = cand[c0:c0 + step]
                d = p1[c] - p0[c]
                w = q[:, None, :] - p0[c][None]
                dd = np.maximum(np.einsum("cx,cx->c", d, d), 1e-300)  # zero-length: never inside
                t = np.einsum("pcx,cx->pc", w, d) / dd  # along the axis; flat ends at 0 and 1
                dist2 = np.sum((w - t[..., None] * d[None]) ** 2, axis=2)
                hit = (dist2 < r[c][None] ** 2) & (t >= 0.0) & (t <= 1.0)
                rows = np.flatnonzero(hit.any(axis=1))
                element[a + rows] = ids[c[np.argmax(hit[rows], axis=1)]]
        for (bmin, bmax), eid in zip(boxes, box_ids):
            inside = np.all((q_all > np.asarray(bmin)) & (q_all < np.asarray(bmax)), axis=1)
            element[inside] = eid
        return element >= 0, element

    def near_x_m(self, y_min_m: float, y_max_m: float) -> float | None:
        """Smallest x of the geometry whose y extent meets [y_min_m, y_max_m]: the side of the
        wood nearest a scanner that looks along +x (eq. 8's Max(x) in the paper's frame).
        Per-element boxes, so a slanted branch counts with its whole box (the sweep only
        widens).  None when nothing lies in that y range."""
        lo, hi = self.boxes_m()
        sel = (hi[:, 1] >= y_min_m) & (lo[:, 1] <= y_max_m)
        return float(lo[sel, 0].min()) if sel.any() else None


def generate(cfg: SceneConfig, read_meshes: bool = True, forest=None) -> SceneGeometry:
    """Build the plants and primitives a scene file asks for (no Mitsuba).  Mesh primitives
    are read here, once (``read_meshes=False``: when first needed, for callers that may not).
    ``forest``: the scene's :class:`~simlidar_mi.forest.stand.Forest` already made, used as is."""
    t0 = time.perf_counter()
    parts: list[Branches] = []
    leaves, instances, trees = Leaves.empty(), None, None
    terrain = terrain_of(cfg)
    if cfg.has("orchard") or cfg.has("orchard.tree") or cfg.has("orchard.leaves"):
        from ..plants.apple import AppleTreeParams, orchard  # noqa: PLC0415
        try:
            params = AppleTreeParams(**cfg["orchard.tree"])
        except ConfigError as exc:
            raise ConfigError(str(exc), file=cfg.source) from exc
        o = cfg["orchard"]
        parts.append(orchard(params, n_trees=o["n_trees"], spacing_m=o["spacing_m"],
                             row_x_m=o["row_x_m"], y_start_m=o["y_start_m"], seed=cfg.seed))
        if terrain is not None:  # each tree's foot at the terrain height under it (before its leaves)
            ys = o["y_start_m"] + o["spacing_m"] * np.arange(o["n_trees"])
            parts[-1] = stand_on(parts[-1], terrain, np.full(len(ys), o["row_x_m"]), ys, cfg.source)
        if cfg["orchard.leaves"]["season"] != "dormant":  # dormant: the wood alone, as before
            from ..plants.apple_leaves import orchard_leaves_from_config  # noqa: PLC0415
            leaves = orchard_leaves_from_config(cfg, parts[-1])
    if cfg.has("forest") or cfg.arrays.get("species"):
        from ..forest.stand import make_forest  # noqa: PLC0415
        from ..forest.representation import scene_parts  # noqa: PLC0415
        forest = forest if forest is not None else make_forest(cfg, terrain=terrain)
        fb, forest_leaves, instances = scene_parts(forest, cfg.source)
        trees = forest.trees_columns()  # arrays only: the Forest itself is freed as before
        parts.append(fb)
        leaves = Leaves.concat([leaves, forest_leaves])
    prims = []
    for j, p in enumerate(cfg.arrays["primitive"]):
        params = {k: v for k, v in p.items() if k not in ("type", "label") and v is not None}
        prim = Primitive(p["type"], params, p["label"])
        if read_meshes and prim.kind in ("obj", "ply"):  # bounds, build and sensor reuse the arrays
            prim = replace(prim, mesh=primitive_mesh_data(prim, cfg.source, j))
        prims.append(prim)
    if cfg.has("vineyard") or cfg.has("vineyard.canopy"):  # VSP vineyard (plants/vineyard.py)
        from ..plants.vineyard import vineyard_from_config  # noqa: PLC0415
        vy = vineyard_from_config(cfg, terrain)
        parts.append(vy.branches)
        leaves = Leaves.concat([leaves, vy.leaves])
        prims += vy.clusters  # grape clusters: cylinder primitives after the file's own
    return SceneGeometry(Branches.concat(parts), leaves, prims, time.perf_counter() - t0, instances,
                         cfg.source, trees, terrain)



def build(cfg: SceneConfig, geometry: SceneGeometry, patterns: list | None = None):
    """Geometry → Mitsuba scene in the representation the scene file chose.

    The default origin covers the geometry and the scanner positions of ``patterns``
    (by default the scene's own :func:`scan_patterns`; a scene whose scan settings are
    invalid, which only a scan would refuse, is built around its geometry alone)."""
    from ..scene.build import build_scene  # noqa: PLC0415
    sc = cfg["scene"]
    if patterns is None:
        try:
            lo, hi = geometry.bounds_m()
            patterns = scan_patterns(cfg, lo, hi, geometry.near_x_m)
        except ConfigError:
            patterns = []
    scanner = [scanner_positions_m(p) for p in patterns]
    return build_scene(geometry.branches, geometry.leaves, geometry.primitives,
                       representation=sc["representation"], facets=sc["facets"],
                       origin_m=sc["origin_m"], variant=sc["variant"], source=cfg.source,
                       instances=geometry.instances,
                       scanner_m=np.concatenate(scanner) if scanner else None,
                       terrain=geometry.terrain)


def measure(cfg: SceneConfig, geometry: SceneGeometry | None = None) -> dict:
    """Geometry measures (V_L, A_L, A_PR, A_PR_exact) in total and per tree, from geometry alone;
    a leaf-on orchard adds its leaf area per tree and the row's LAI (plants/apple_leaves.py).

    The ``measure`` command (without ``--preset``). ``geometry``: an already generated
    :func:`generate` result, else the scene's is generated (meshes unread). Returns a dict:
    ``n_branches``, ``V_L_m3``, ``A_L_m2``, ``A_PR_m2``, ``A_PR_exact_m2``, ``per_tree`` (a list of
    the same per tree) and, for leaves, ``n_leaves``, ``leaf_area_m2``, ``leaf_area_per_tree_m2``,
    ``LAI_row``, ``row_ground_area_m2``."""
    from ..plants.measures import wood_measures  # noqa: PLC0415
    from ..plants.apple_leaves import orchard_leaf_measures  # noqa: PLC0415
    geometry = geometry or generate(cfg, read_meshes=False)  # meshes are read below, when there are some
    out = {**wood_measures(geometry.branches).to_dict(), **orchard_leaf_measures(cfg, geometry.leaves)}
    if geometry.primitives:  # a mesh tree's leaves and wood, as truth counts them
        out.update(primitive_surfaces(geometry.primitives, geometry.source))
    return out


@dataclass
class ScanRun:
    """What ``run_scan`` produced: the scan product, the measures and the files written."""

    result: object
    measures: dict
    files: dict[str, Path] = field(default_factory=dict)


@writes_output("out_dir")
def run_scan(cfg: SceneConfig | str | Path, out_dir: str | Path | None = None,
             overrides: list[str] | tuple = (), *, write_las: bool = True,
             write_png: bool = True, progress: bool = False, scheduler: str | None = None,
             tile_rows: int | None = None) -> ScanRun:
    """Generate, build, scan and (with ``out_dir``) write the scan's files.

    The tractor writes scan.exr, scan.png, points.las and measures.json.  Other
    platforms write the same, and a multi-leg path one scan_legJ.exr / scan_legJ.png
    per leg with every leg's points in the one LAS file.  Files appear together when
    all are complete; a failure leaves ``out_dir`` as it was.

    On a Dask cluster (``scheduler`` such as ``"tcp://host:8786"``, else an active
    ``distributed.Client``, else ``DASK_SCHEDULER_ADDRESS``; ``"local"`` or none of them:
    this process) the scan runs as tiles of ``tile_rows`` rows on the cluster's workers and
    is merged here into the same result and files (:mod:`simlidar_mi.lidar.tiles`).

    Without a cluster, a scan of more than ``[scan] chunk_beams`` beams written to ``out_dir``
    is traced and written chunk by chunk (:mod:`simlidar_mi.lidar.stream`, with a ``[sensor]``
    :mod:`simlidar_mi.lidar.stream_sensor`; the same bytes): ``run.result`` is then a
    :class:`~simlidar_mi.lidar.stream.StreamedScan` (shape, counts, areas; no beams).
    """
    cfg = _checked_scene(cfg, overrides, scheduler, tile_rows)
    run = _ScanStages(cfg, out_dir, make_progress(progress))
    with run.jobs:  # the measuring child ends with the run, however it ends
        run.generate(scheduler)
        run.scan(scheduler, tile_rows)
        if out_dir is None:
            measures, files = run.measures(), {}
        else:
            measures, files = run.write(write_las=write_las, write_png=write_png)
        warn_if_unseen(cfg, measures["hits"], run.geometry)
        run.bar("written")
        results = run.results
        return ScanRun(results[0] if len(results) == 1 else results, measures, files)


def _checked_scene(cfg: SceneConfig | str | Path, overrides, scheduler: str | None,
                   tile_rows: int | None) -> SceneConfig:
    """The scene, with what can be refused before any work refused: the cluster address, the
    Mitsuba variant, the tile size (even when no cluster would use it)."""
    from .._runtime.cluster import check_scheduler  # noqa: PLC0415
    check_scheduler(scheduler)  # an empty address is refused before any work
    if not isinstance(cfg, SceneConfig):
        cfg = load_scene(cfg, overrides)
    check_variant(cfg["scene"]["variant"], cfg.source)
    if tile_rows is not None:
        from .tiles import tile_plan  # noqa: PLC0415
        tile_plan([], tile_rows)
    return cfg


class _ScanStages:
    """One run of :func:`run_scan`, stage by stage: generate → scan → measure → write.

    Each stage reads what the previous one left on ``self`` and times itself into ``seconds``
    (measures.json's ``seconds``)."""

    STEPS = ("generate", "build", "scan", "write")

    def __init__(self, cfg: SceneConfig, out_dir, shown) -> None:
        self.cfg, self.out_dir, self.shown = cfg, out_dir, shown
        self.bar = shown.stage("scan", len(self.STEPS), "stage").step
        self.seconds: dict[str, float] = {}
        self.geo_job = None
        self.jobs = contextlib.ExitStack()  # the forked children's ends (Forked.within)
        self.streamed = False  # a scan to files traced and written chunk by chunk
        self.points_name = f"points.{cfg['scan']['points_format']}"  # points.las or points.laz

    def generate(self, scheduler: str | None) -> None:
        """Geometry and beam patterns; too large a scan is refused before anything is traced.
        With files to write, the geometry's measures start on the second core."""
        cfg = self.cfg
        t = time.perf_counter()
        early = plan_from_keys(cfg)  # a scan too large is refused here, at once
        if _overlap_generation(cfg, scheduler):  # Mitsuba imported here while a forked child generates
            with mesh_drop() as drop, contextlib.ExitStack() as ends:
                job = Forked.within(ends, "generating the scene", _plan, cfg, early, drop)
                mitsuba(cfg["scene"]["variant"])
                self.geometry, self.patterns = job.wait()
                self.geometry.primitives = unship_meshes(self.geometry.primitives, drop)
        else:
            self.geometry, self.patterns = _plan(cfg, early)
        geometry, patterns = self.geometry, self.patterns
        self.n_beams = sum(p.n_beams for p in patterns)
        if self.n_beams * (cfg["scan"]["footprint"] + 1) ** 2 > cfg["scan"]["max_beams"]:
            raise ConfigError(f"{self.n_beams} beams exceed scan.max_beams = {cfg['scan']['max_beams']}",
                              file=cfg.source_of("scan.max_beams"), key="scan.max_beams",
                              value=cfg["scan"]["max_beams"])
        warn_scanner_inside_wood(geometry, patterns)
        self.seconds["generate"] = time.perf_counter() - t
        self.bar(generated_line(geometry))
        if self.out_dir is not None and len(geometry.branches) + len(geometry.leaves) >= FORK_MEASURES_MIN:
            self.geo_job = Forked.within(self.jobs, "measuring the wood", scene_measures, cfg, geometry, patterns)

    def scan(self, scheduler: str | None, tile_rows: int | None) -> None:
        """Build and trace: in row tiles on a cluster, or here (held in memory, or left to
        :meth:`write` when it streams chunks to files)."""
        from .._runtime.cluster import cluster_client  # noqa: PLC0415
        cfg, geometry, patterns = self.cfg, self.geometry, self.patterns
        with cluster_client(scheduler) as client:
            if client is not None:  # tiles on the cluster's workers, each building the scene once
                from .tiles import scan_on_cluster  # noqa: PLC0415
                scene_sensor(cfg, geometry, patterns)  # a bad [sensor] fails here, before any task
                t = time.perf_counter()
                self.built, self.results, facts = scan_on_cluster(client, cfg, patterns, prepare_scan,
                                                                  tile_rows=tile_rows, progress=self.shown)
                self.seconds["build"] = facts["build_seconds"]  # the slowest worker's (inside the scan's time)
                self.seconds["scan"] = time.perf_counter() - t
                self.bar(f"built {self.built.representation} scene on {len(facts['workers'])} workers")
                self.bar(f"scanned {self.n_beams} beams in {facts['tiles']} tiles")
                self.sensor = None  # the tiles carried it
                return
        from .scan import scan  # noqa: PLC0415
        t = time.perf_counter()
        self.built = build(cfg, geometry, patterns)
        self.seconds["build"] = time.perf_counter() - t
        self.bar(f"built {self.built.representation} scene")
        self.sensor = scene_sensor(cfg, geometry, patterns)
        chunk = cfg["scan"]["chunk_beams"]
        # More than one chunk to files: traced and written chunk by chunk (lidar/stream.py).
        self.streamed = self.out_dir is not None and max(p.n_beams for p in patterns) > chunk
        t = time.perf_counter()
        self.results = [] if self.streamed else [
            scan(self.built, p, cfg["scene"]["variant"], self.sensor, seed=cfg.seed, leg=j, chunk_beams=chunk)
            for j, p in enumerate(patterns)]
        self.seconds["scan"] = time.perf_counter() - t
        if not self.streamed:
            self.bar(f"scanned {self.n_beams} beams")

    def measures(self) -> dict:
        """measures.json's content (the geometry's part from the forked child when it ran),
        timed as a stage of its own."""
        t = time.perf_counter()
        scene = self.geo_job.wait() if self.geo_job is not None else \
            scene_measures(self.cfg, self.geometry, self.patterns)
        out = scan_measures(self.cfg, self.geometry, self.built, self.results, scene)
        self.seconds["measures"] = time.perf_counter() - t
        if self.out_dir is None:
            out["seconds"] = {k: round(v, 4) for k, v in self.seconds.items()}
        return out

    def write(self, *, write_las: bool, write_png: bool) -> tuple[dict, dict[str, Path]]:
        """Every file into a staging folder, moved into ``out_dir`` together at the end; the LAS
        on the second core (forked) while this process measures and writes the EXR and PNG."""
        cfg, out_dir = self.cfg, Path(self.out_dir)
        files: dict[str, Path] = {}
        t = time.perf_counter()
        with staged_dir(out_dir, SCAN_OUTPUTS) as stage, contextlib.ExitStack() as jobs:
            las_job = None
            if self.streamed:
                measures = self._write_streamed(stage, files, write_las=write_las, write_png=write_png)
            else:
                if write_las:  # the longest file: on the second core (simlidar_mi._runtime.fork)
                    from ..io.las import write_scan_las  # noqa: PLC0415
                    results = self.results
                    las_job = Forked.within(jobs, f"writing {self.points_name}",
                                            functools.partial(write_scan_las, crs=cfg["scene"]["crs"]),
                                            results if len(results) > 1 else results[0], stage / self.points_name)
                measures = self.measures()
                # two EXR threads even beside the LAS child: a core is never idle when one writer
                # ends first (fwf, 76 channels: 3.97 -> 2.44 s; single ray 0.41 -> 0.35 s, §8f)
                self._write_images(stage, files, write_png=write_png, threads=2)
            if cfg["scan"]["trajectory"] and has_trajectory(self.patterns):
                write_trajectory(stage / TRAJECTORY_FILE, self.patterns)
                files["trajectory"] = out_dir / TRAJECTORY_FILE
            if las_job is not None:
                las_job.wait()
                files["las"] = out_dir / self.points_name
            self.seconds["write"] = (time.perf_counter() - t - (self.seconds["scan"] if self.streamed else 0.0)
                                     - self.seconds.get("measures", 0.0))
            measures["seconds"] = {k: round(v, 4) for k, v in self.seconds.items()}
            with atomic_file(stage / "measures.json") as tmp:
                tmp.write_text(json.dumps(measures, indent=2, sort_keys=True) + "\n")
            files["measures"] = out_dir / "measures.json"
        return measures, files

    def _exr_extra(self) -> dict:
        return {"scene_file": self.cfg.source, "representation": self.built.representation,
                "facets": self.built.facets}

    def _write_streamed(self, stage: Path, files: dict, *, write_las: bool, write_png: bool) -> dict:
        """Trace and write chunk by chunk: first returns (lidar/stream.py) or a [sensor] scan
        (lidar/stream_sensor.py); the same bytes as a held scan."""
        from .stream import stream_scan  # noqa: PLC0415
        from .stream_sensor import stream_physical_scan  # noqa: PLC0415
        cfg, patterns, chunk = self.cfg, self.patterns, self.cfg["scan"]["chunk_beams"]
        names: dict = {}
        many = len(patterns) > 1
        how = stream_scan if self.sensor is None else functools.partial(stream_physical_scan, model=self.sensor,
                                                                          seed=cfg.seed)
        self.results, self.seconds["scan"] = how(
            self.built, patterns, stage, variant=cfg["scene"]["variant"], chunk_beams=chunk,
            exr_kwargs={"seed": cfg.seed, "scene_sha256": cfg.sha256, "extra": self._exr_extra()},
            png_titles=[f"{cfg['scene']['name']}: range image{f', leg {j}' if many else ''}"
                        for j in range(len(patterns))] if write_png else None,
            las=write_las and self.points_name, crs=cfg["scene"]["crs"], progress=self.shown, files=names)
        files.update({k: Path(self.out_dir) / v for k, v in names.items()})
        if write_las:
            files["las"] = Path(self.out_dir) / self.points_name
        self.bar(f"scanned and wrote {self.n_beams} beams in chunks of {chunk}")
        return self.measures()

    def _write_images(self, stage: Path, files: dict, *, write_png: bool, threads: int) -> None:
        """scan.exr and scan.png (scan_legJ.* for a path of several legs) of a held scan."""
        from ..io.exr import write_scan_exr  # noqa: PLC0415
        results, cfg = self.results, self.cfg
        for j, res in enumerate(results):
            stem = "scan" if len(results) == 1 else f"scan_leg{j}"
            write_scan_exr(res, stage / f"{stem}.exr", seed=cfg.seed, scene_sha256=cfg.sha256,
                           extra=self._exr_extra(), threads=threads)  # a core each with the LAS child
            files[f"exr{'' if len(results) == 1 else j}"] = Path(self.out_dir) / f"{stem}.exr"
            if write_png:
                from ..io.plots import plot_scan_png  # noqa: PLC0415
                leg = "" if len(results) == 1 else f", leg {j}"
                plot_scan_png(res, stage / f"{stem}.png", title=f"{cfg['scene']['name']}: range image{leg}")
                files[f"png{'' if len(results) == 1 else j}"] = Path(self.out_dir) / f"{stem}.png"


def prepare_scan(cfg: SceneConfig) -> tuple[list, object, object]:
    """(patterns, built scene, sensor) of ``cfg`` as :func:`run_scan` makes them: what a
    cluster worker builds once for the tiles it scans (:mod:`simlidar_mi.lidar.tiles`)."""
    geometry, patterns = _plan(cfg)
    return patterns, build(cfg, geometry, patterns), scene_sensor(cfg, geometry, patterns)


def plan_from_keys(cfg: SceneConfig) -> list | None:
    """What the keys alone decide, checked before anything is generated (or Mitsuba imported):
    a vineyard's size, and the beam patterns of every platform but the tractor (whose sweep
    follows the geometry) within ``max_beams`` and ``max_rays``; returns those patterns
    (None for the tractor)."""
    if cfg.has("vineyard") or cfg.has("vineyard.canopy"):
        from ..plants.vineyard import vineyard_params  # noqa: PLC0415
        vineyard_params(cfg)
    if cfg["platform"]["kind"] == "tractor":
        return None
    patterns = scan_patterns(cfg, None, None)
    check_rays(cfg, patterns, None)
    return patterns


def _plan(cfg: SceneConfig, early: list | None = None, drop: str | None = None) -> tuple[SceneGeometry, list]:
    """The geometry and the scan patterns of ``cfg`` (no Mitsuba: a forked child may run it);
    ``early``: :func:`plan_from_keys`'s patterns, when already made; ``drop``: the shared file the
    meshes are left in for a parent (:func:`~simlidar_mi.io.mesh_import.ship_meshes`)."""
    if early is None:
        early = plan_from_keys(cfg)
    geometry = generate(cfg)
    if early is not None:
        patterns = early
    else:
        lo, hi = geometry.bounds_m()
        patterns = scan_patterns(cfg, lo, hi, geometry.near_x_m)
    check_clearance(cfg, patterns, geometry.terrain)
    if cfg.has("sensor"):
        check_rays(cfg, patterns, scene_sensor(cfg, geometry, patterns))
    if drop is not None:
        geometry.primitives = ship_meshes(geometry.primitives, drop)
    return geometry, patterns


def check_rays(cfg: SceneConfig, patterns: list, sensor) -> None:
    """Refuse a scan of more rays than ``[scan] max_rays``: beams × dot-matrix sub-beams ×
    the [sensor]'s sub-rays per beam, before any is traced.  ``sensor`` None: the sub-rays
    the keys alone imply (a given ``beam_samples``, else auto's smallest, 7)."""
    from .sensor import AUTO_S_MIN  # noqa: PLC0415
    s = cfg["sensor"]
    div = cfg.has("sensor") and s["divergence_mrad"] > 0
    if sensor is not None:
        per_beam = sensor.beam_samples if sensor.divergence_mrad > 0 else 1
    else:
        per_beam = (s["beam_samples"] or AUTO_S_MIN) if div else 1
    beams = sum(p.n_beams for p in patterns)
    sub = (cfg["scan"]["footprint"] + 1) ** 2
    limit = cfg["scan"]["max_rays"]
    if beams * sub * per_beam <= limit:
        return
    key = ("sensor.beam_samples" if s["beam_samples"] else "sensor.divergence_mrad") if per_beam > 1 \
        else "scan.max_rays"
    raise ConfigError(f"{beams:,} beams × {sub} sub-beams × {per_beam} sub-rays = {beams * sub * per_beam:.3g} "
                      f"rays exceed scan.max_rays = {limit}; lower beam_samples, coarsen the scan or raise "
                      "scan.max_rays", file=cfg.source_of(key), key=key, value=cfg[key.split(".")[0]][key.split(".")[1]])


#: Geometry elements (branches + leaf triangles) from which a scan with files measures the wood
#: in a forked child while the scene is built (below that the fork costs more than it saves).
FORK_MEASURES_MIN = 20_000


def _overlap_generation(cfg: SceneConfig, scheduler: str | None) -> bool:
    """Generate in a forked child while this process imports Mitsuba: only when Mitsuba is not
    imported yet (a command's fresh process; both steps hold the GIL, so a thread would not
    overlap them) and the scan stays in this process (no cluster)."""
    from .._runtime.cluster import may_use_cluster  # noqa: PLC0415
    from .._runtime.mitsuba import variant_ready  # noqa: PLC0415
    return use_fork(None) and not variant_ready(cfg["scene"]["variant"]) and not may_use_cluster(scheduler)


def scene_sensor(cfg: SceneConfig, geometry: SceneGeometry, patterns: list):
    """The scene's :class:`~simlidar_mi.lidar.sensor.SensorModel` (None: the first-return scan).

    Auto ``beam_samples`` sees the farthest corner of the geometry's box from any scanner
    position and the median branch diameter."""
    from .sensor import resolve_sensor  # noqa: PLC0415
    if not cfg.has("sensor"):
        return None
    lo, hi = geometry.bounds_m()
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    scanners = np.concatenate([scanner_positions_m(p) for p in patterns]) if patterns else np.zeros((1, 3))
    far = float(np.max(np.linalg.norm(corners[None, :, :] - scanners[:, None, :], axis=2)))
    feature = float(np.median(geometry.branches.diameter)) if len(geometry.branches) else None
    try:
        return resolve_sensor(cfg, far_range_m=far, feature_m=feature)
    except ConfigError as exc:
        raise cfg.relabel(exc) from None


def scene_measures(cfg: SceneConfig, geometry: SceneGeometry, patterns: list) -> dict:
    """The part of measures.json that needs the geometry only: the wood measures, the share
    of the wood the tractor's sweep can see, and the leaf area of a leaf-on orchard."""
    out = {}
    if len(geometry.branches):
        from ..plants.measures import wood_measures  # noqa: PLC0415
        wm = wood_measures(geometry.branches).to_dict()
        out = {k: wm[k] for k in ("V_L_m3", "A_L_m2", "A_PR_m2", "A_PR_exact_m2", "per_tree") if k in wm}
        if patterns and hasattr(patterns[0], "swept_share"):  # the tractor's ScanSettings
            out["A_PR_swept_share"] = patterns[0].swept_share(geometry.branches)
    from ..plants.apple_leaves import orchard_leaf_measures  # noqa: PLC0415
    out.update(orchard_leaf_measures(cfg, geometry.leaves))  # leaf area per tree, LAI (leaf-on)
    return out


def scan_measures(cfg: SceneConfig, geometry: SceneGeometry, built, results, scene: dict | None = None) -> dict:
    """measures.json of a run: the scene, what each scan saw, and :func:`scene_measures`
    (``scene``, when already computed)."""
    if scene is None:
        scene = scene_measures(cfg, geometry, [r.settings if r.settings is not None else r.pattern for r in results])
    first = results[0]
    out = {
        "scene": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed,
        "representation": built.representation, "facets": built.facets,
        "origin_m": [float(x) for x in built.origin_m],
        "n_branches": int(len(geometry.branches)), "n_dropped_zero_length": built.n_dropped,
        **leaf_triangle_counts(geometry),  # generated, in meshes, placed by instances (lidar.scene_counts)
        "n_instances": int(built.n_instances), "n_triangles_built": int(built.n_triangles),
        "platform": cfg["platform"]["kind"], "footprint": first.pattern.footprint,
        "hit_rule": first.pattern.hit_rule,
    }
    if first.settings is not None:  # the tractor: the paper's N × M and impacted areas
        n, m = first.shape
        out.update({"N": n, "M": m, "A_IM_m2": first.impacted_area_m2(),
                    "A_IM_yz_m2": first.impacted_area_yz_m2(), "hits": first.class_counts(),
                    "scan": first.settings.to_dict()})
    else:
        out["legs"] = [{"N": r.shape[0], "M": r.shape[1], "hits": r.class_counts(),
                        "pattern": r.pattern.to_dict()} for r in results]
        out["hits"] = {k: sum(leg["hits"][k] for leg in out["legs"]) for k in first.class_counts()}
    if first.sensor is not None:  # a real scanner: what it was and what its echoes were
        out["sensor"] = first.sensor
        out["sub_rays_per_beam"] = first.metadata.get("sub_rays_per_beam")
        if first.echoes is not None:
            from .stream_sensor import scan_echo_statistics  # noqa: PLC0415
            out["echoes"] = scan_echo_statistics(results)
    out.update(scene)
    return out
