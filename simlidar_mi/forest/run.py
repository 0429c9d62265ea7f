"""The ``simlidar-mi forest`` command: make a scene's forest and write its files.

``run_forest`` (``simlidar-mi forest SCENE.toml --out DIR``) writes into ``DIR``:

``trees.csv``
    ``tree_id, species, x, y, z_base_m, height_m, crown_base_m, dbh_m, n_branches, n_leaves,
    seed, prototype, yaw_deg, scale, crown_radius_m, branching, leaf_area_m2, crown_projection_m2``
    (and ``needle_area_m2`` when a species models conifer shoots: see
    :mod:`simlidar_mi.forest.foliage`; and ``top_cells, overtopped`` with the truth rasters,
    below) (metres, degrees; ``prototype = -1``
    without instancing; (x, y, ``z_base_m``) is the trunk foot, ``z_base_m`` the terrain height
    under it (0 without ``[terrain]``); ``height_m`` (total height) is the highest z of the
    tree's branch end points and leaf vertices above the foot, ``crown_base_m`` the lowest leaf
    vertex above it (empty for a leafless tree), ``dbh_m`` the trunk's diameter at 1.3 m
    above the foot (empty where the trunk is shorter), ``crown_radius_m`` the largest
    horizontal distance of branch ends and leaves from the trunk; ``branching`` the L1 flag, 0 or 1, or with ``lateral_branching_per =
    "branch"`` the share of branches that drew it true). ``seed`` grows exactly the
    placed tree: ``place_tree(random_tree(P, seed), x, y, yaw_deg, scale)``
    (:func:`simlidar_mi.forest.stand.place_tree`; ``P`` the species' parameters, and
    ``scale_mode="whole-tree"`` when the scene says so).
``leaves.parquet`` (``leaves.csv`` with ``leaf_table_format = "csv"``)
    ``tree_id, leaf_id, x, y, z, length_m, width_m, area_m2, nx, ny, nz, hx, hy, hz``:
    blade centre, size, one-sided polygon area, upper-side unit normal and unit
    base→tip heading, world frame; int32 ids and float64 values in Parquet (zstd), the
    CSV rounds them (``%.5f`` positions, ``%.6g`` sizes, ``%.7g`` area, ``%.6f``
    vectors). ``leaf_table = "prototypes"`` writes ``prototype_leaves.parquet`` instead
    (column ``prototype`` for ``tree_id``, prototype frame; place rows with the
    transforms of ``trees.csv``). ``"auto"`` (default) writes all leaves up to
    ``leaf_table_max_rows`` (1 M rows ≈ 110 MB of CSV, 95 MB of Parquet), else the
    prototypes' leaves when instancing; ``"none"`` writes nothing.
``layout.png``
    trees as crown-sized discs coloured by species, over the intensity contours.
``preview.png``
    side and top views of a central strip of at most ``preview_max_trees`` trees
    (branches as lines, leaves as dots), every crown outlined in the top view.
``stand.ply`` / ``stand.obj``
    the whole stand (branches as open prisms, leaves as triangles; PLY faces carry
    ``part`` 0 = wood / 1 = leaves and ``tree_id``; OBJ has ``o wood`` and
    ``o leaves``) — see :mod:`simlidar_mi.io.mesh_export`. ``export = "auto"``
    writes the stand up to ``export_max_triangles``, else (instancing only) one
    ``prototypes/<species>_<k>.ply`` per prototype in its own frame.
``truth_dtm.tif``, ``truth_dsm.tif``, ``truth_chm.tif``, ``truth_tree_id.tif``
    with ``[forest] truth_rasters = true`` (``--truth-rasters``) only: the raster truth over the
    domain, as ``evaluate-als`` writes it, and ``trees.csv`` gains ``top_cells`` (cells of
    ``truth_tree_id.tif`` the tree owns) and ``overtopped`` (1: it owns none).  The ray casting
    lives above this room (:mod:`simlidar_mi.truth.forest_truth`): it comes in as ``truth``.
``forest.json``
    counts per species (expected, before and removed by the thinning, placed, mean
    height and crown radius, share of trees with the L1 flag), totals,
    ``crown_overlap_share`` (share of trees whose nearest neighbour's trunk stands
    inside their crown), prototypes and trees per prototype, the modes chosen and
    the seconds per step; per species ``thinning`` (``expected`` ∫λ, ``drawn``,
    ``removed``, ``final``) and ``foliage``: leaf area and LAI per species and for the
    stand (:func:`simlidar_mi.forest.foliage.foliage_summary`).

The two pictures are drawn in a forked process while this one writes the tables and
meshes (they are independent; same bytes as drawn in turn): see :func:`_start_pictures`.
"""
from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from .._runtime.fork import Forked, use_fork
from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..io.atomic import staged_dir, writes_output
from ..plants.tree_leaves import LeafTable
from .outputs import (_write_prototype_meshes, _write_trees_csv, leaf_table_format, plot_layout,
                      plot_preview, write_leaf_tables, write_stand)
from .stand import Forest, _bar, make_forest

__all__ = ["ForestRun", "ForestExtras", "run_forest", "FOREST_OUTPUTS"]

# The files a forest run owns in its folder (whole-name regular expressions): a re-run
# removes those it does not write again (the stand mesh after switching to prototypes,
# the leaf table after leaf_table = "none", the other format's files).
FOREST_OUTPUTS = (r"trees\.csv", r"(prototype_)?leaves\.(csv|parquet)", r"layout\.png",
                  r"preview\.png", r"stand\.(ply|obj)", r"prototypes", r"forest\.json",
                  r"truth_(dtm|dsm|chm|tree_id)\.tif")


# --- the command -----------------------------------------------------------------------


@dataclass
class ForestRun:
    """What ``run_forest`` produced."""

    forest: Forest
    files: dict[str, Path]
    summary: dict[str, Any]


@dataclass
class ForestExtras:
    """What a layer above this one adds to a forest run (the truth rasters:
    :func:`simlidar_mi.truth.forest_truth.forest_truth`), given by its ``truth`` hook."""

    columns: dict[str, np.ndarray]  # per tree, appended to trees.csv in this order
    files: dict[str, str]           # kind -> name of a file it wrote in the staging folder
    summary: dict[str, Any]         # forest.json's "truth_rasters"
    seconds: dict[str, float]


#: ``truth(forest, cfg, stage, progress)``: writes its files into the staging folder ``stage``.
TruthHook = Callable[[Forest, SceneConfig, Path, Any], ForestExtras]


def _resolve_modes(forest: Forest, f: dict, src: str, where=None) -> tuple[str, str]:
    where = where or (lambda key: src)  # where a key's value came from (SceneConfig.source_of)
    leaf_mode = f["leaf_table"]
    n_leaves = int(forest.n_leaves.sum())
    if leaf_mode == "auto":
        leaf_mode = "all" if n_leaves <= f["leaf_table_max_rows"] or not forest.instancing else "prototypes"
    if leaf_mode == "prototypes" and not forest.instancing:
        raise ConfigError("needs instancing = true (without it there are no prototypes)", file=src,
                          key="forest.leaf_table", value="prototypes")
    export = f["export"]
    k = f["export_facets"]
    n_tri = int((2 * k * forest.n_branches + forest.n_leaf_triangles).sum())
    if export == "auto":
        export = "stand" if n_tri <= f["export_max_triangles"] or not forest.instancing else "prototypes"
    if export == "prototypes" and not forest.instancing:
        raise ConfigError("needs instancing = true (without it there are no prototypes)", file=src,
                          key="forest.export", value="prototypes")
    if export in ("stand", "prototypes") and f["export_format"] == "ply":
        # a PLY's int32 indices: refuse before any file is written, naming the key that sizes it
        per_tree = 2 * k * forest.n_branches + 3 * forest.n_leaf_triangles  # a mesh's vertices
        n_v = int(per_tree.sum()) if export == "stand" else int(per_tree.max(initial=0))
        if n_v >= 2**31:
            raise ConfigError(f"the {'stand' if export == 'stand' else 'largest prototype'}'s PLY would hold "
                              f"{n_v:.3g} vertices ({k} per branch end), past the 2^31 − 1 that its "
                              "int32 indices reach; lower it", file=where("forest.export_facets"),
                              key="forest.export_facets", value=k)
    return leaf_mode, export


class _Beside:
    """``fn(*args)`` run in a thread while this one does other work; ``wait()`` gives its result
    and seconds or raises its exception. Its ``tables`` iterable (the third argument) stops at
    the next table once :meth:`stop` is called (this thread failed or was interrupted)."""

    def __init__(self, fn, path: Path, tables: Iterable, *args) -> None:
        import threading  # noqa: PLC0415
        self._stop = threading.Event()
        self._out: list = []

        def run() -> None:
            t0 = time.perf_counter()
            try:
                self._out.append((fn(path, self._until(tables), *args), time.perf_counter() - t0))
            except BaseException as e:  # noqa: BLE001  (handed to wait())
                self._out.append(e)

        self._thread = threading.Thread(target=run, name="simlidar-forest-tables", daemon=True)
        self._thread.start()

    def _until(self, tables: Iterable) -> Iterator:
        for t in tables:
            if self._stop.is_set():
                raise ConfigError("stopped: the forest run failed beside it", key="forest.leaf_table")
            yield t

    def wait(self) -> tuple[Any, float]:
        self._thread.join()
        out = self._out[0]
        if isinstance(out, BaseException):
            raise out
        return out

    def stop(self) -> None:
        """This thread failed: the other stops at its next table and is waited for (its own
        error, if any, is dropped: this thread's is the one to report)."""
        self._stop.set()
        self._thread.join()


def _draw_pictures(forest: Forest, stage: Path, max_trees: int) -> float:
    t0 = time.perf_counter()
    plot_layout(forest, stage / "layout.png")
    plot_preview(forest, stage / "preview.png", max_trees)
    return time.perf_counter() - t0


def _one_blas_thread():
    """BLAS limited to one thread while the two processes share the cores: OpenBLAS's own
    threads spin between calls and took the other process's time (after growth, load ≈ 4: 2.3–2.9 s
    in turn, forked 1.5–2.5 s with OpenBLAS's threads, 1.3–2.0 s with one; BENCHMARKS.md §8c)."""
    from threadpoolctl import threadpool_limits  # noqa: PLC0415
    return threadpool_limits(1, user_api="blas")


def _use_fork(parallel: bool | None) -> bool:
    return use_fork(parallel)


def _pictures(ends: contextlib.ExitStack, forest: Forest, stage: Path, max_trees: int,
              parallel: bool | None) -> Forked:
    """``layout.png`` and ``preview.png`` drawn into a staged folder, in a forked process when
    :func:`simlidar_mi._runtime.fork.use_fork` allows, while the caller writes the tables and meshes:
    the child shares the forest's memory and alone imports matplotlib; the bytes are those of
    drawing in turn. ``wait()`` gives the drawing's seconds; a failed or dead child raises
    :class:`~simlidar_mi.errors.SimlidarError` with its traceback (the staged folder is then
    discarded); ended by ``ends``."""
    return Forked.within(ends, "drawing layout.png and preview.png", _draw_pictures, forest, stage,
                         max_trees, parallel=parallel, setup=_one_blas_thread)


@writes_output("out_dir")
def run_forest(cfg: SceneConfig | str | Path, out_dir: str | Path, overrides: Sequence[str] = (),
               *, progress=False, parallel: bool | None = None, truth: TruthHook | None = None) -> ForestRun:
    """Make the forest of a scene file and write its files (see the module docstring).

    All files appear together when complete (staged); a failure leaves ``out_dir``
    as it was.  ``progress``: see :func:`simlidar_mi._runtime.progress.make_progress`.
    ``parallel``: draw the pictures in a forked process (None: when fork is available
    and the process may use two or more cores; False: in turn, in this process).
    ``truth``: what casts the truth rasters when ``[forest] truth_rasters`` is true
    (:func:`simlidar_mi.run_forest` passes it; the ray casting is above this room).
    """
    if not isinstance(cfg, SceneConfig):
        cfg = load_scene(cfg, list(overrides))
    if not (cfg.has("forest") or cfg.has("species")):
        raise ConfigError("the scene has no [forest] section or [[species]] tables", file=cfg.source,
                          key="forest")
    f = cfg["forest"]
    if f["truth_rasters"] and truth is None:
        raise ConfigError("the truth rasters are cast by simlidar_mi.run_forest (the forest command), not by "
                          "simlidar_mi.forest.run.run_forest", file=cfg.source_of("forest.truth_rasters"),
                          key="forest.truth_rasters", value=True)
    ext = leaf_table_format(f["leaf_table_format"], cfg.source)
    forest = make_forest(cfg, progress=progress)
    leaf_mode, export = _resolve_modes(forest, f, cfg.source, cfg.source_of)
    seconds = dict(forest.seconds)
    files: dict[str, Path] = {}
    out = Path(out_dir)
    extras: ForestExtras | None = None
    with staged_dir(out, FOREST_OUTPUTS) as stage, contextlib.ExitStack() as ends:
        pictures = _pictures(ends, forest, stage, f["preview_max_trees"], parallel)
        if pictures.child is not None:
            ends.enter_context(_one_blas_thread())
        try:
            extras = truth(forest, cfg, stage, progress) if f["truth_rasters"] and truth is not None else None
            if extras is not None:
                seconds.update(extras.seconds)
                files.update({kind: out / name for kind, name in extras.files.items()})
            _write_trees_csv(stage / "trees.csv", forest, extras.columns if extras is not None else None)
            files["trees"] = out / "trees.csv"
            rows = 0
            # the leaf table (zstd in pyarrow) is written in a thread beside the meshes: both
            # free the GIL for most of their time (BENCHMARKS.md §16)
            tables_job = None
            if leaf_mode != "none":
                if leaf_mode == "all":
                    name, id_name = f"leaves.{ext}", "tree_id"
                    tables: Iterable[LeafTable] = (forest.tree_leaf_table(i) for i in
                                                   _bar(range(len(forest)), progress, "leaves", len(forest)))
                else:
                    name, id_name = f"prototype_leaves.{ext}", "prototype"
                    tables = (t.leaf_table for t in forest.prototypes)
                tables_job = _Beside(write_leaf_tables, stage / name, tables, id_name, ext)
                files["leaves"] = out / name
            try:
                t0 = time.perf_counter()
                fmt, k = f["export_format"], f["export_facets"]
                if export == "stand":
                    write_stand(forest, stage / f"stand.{fmt}", fmt, k, progress)
                    files["stand"] = out / f"stand.{fmt}"
                elif export == "prototypes":
                    with make_progress(progress).stage("prototype meshes", unit="mesh") as st:
                        _write_prototype_meshes(forest, stage / "prototypes", fmt, k)
                        st.update(len(forest.prototypes))
                    files["prototypes"] = out / "prototypes"
                t_export = time.perf_counter() - t0
            except BaseException:
                if tables_job is not None:
                    tables_job.stop()
                raise
            rows, t_tables = tables_job.wait() if tables_job is not None else (0, 0.0)
            seconds["tables"], seconds["export"] = t_tables, t_export  # each its own time
            t0 = time.perf_counter()
            with make_progress(progress).stage("pictures", 2, "picture") as st:
                seconds["plots"] = pictures.wait()  # the drawing's own time
                st.update(2)
            seconds["plots_wait"] = time.perf_counter() - t0  # what this process waited for it
        finally:
            ends.close()  # BLAS's threads back, the pictures' child ended
        files["layout"], files["preview"] = out / "layout.png", out / "preview.png"

        summary = forest.summary()
        summary.update({"scene_file": cfg.source, "scene_sha256": cfg.sha256, "leaf_table": leaf_mode,
                        "leaf_table_format": ext if leaf_mode != "none" else None,
                        "leaf_rows_written": rows, "export": export, "export_format": fmt,
                        "export_facets": k, "seconds": seconds,
                        "export_triangles": int((2 * k * forest.n_branches
                                                 + forest.n_leaf_triangles).sum())
                        if export == "stand" else int(sum(2 * k * len(t.branches) + len(t.leaves)
                                                          for t in forest.prototypes))
                        if export == "prototypes" else 0,
                        "transform": "p_world = (x, y, 0) + Rz(yaw_deg) · (scale · p_local)"})
        if extras is not None:
            summary["truth_rasters"] = extras.summary
        with open(stage / "forest.json", "w") as fh:
            json.dump(summary, fh, indent=2)
        files["summary"] = out / "forest.json"
    return ForestRun(forest, files, summary)
