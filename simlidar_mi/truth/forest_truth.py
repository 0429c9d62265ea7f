"""The truth rasters of a forest just made: ``simlidar-mi forest SCENE --out DIR --truth-rasters``.

:func:`run_forest` is :func:`simlidar_mi.forest.run.run_forest` with the raster truth of
:mod:`simlidar_mi.truth.als_truth` added when ``[forest] truth_rasters`` is true (or
``truth_rasters=True``): the forest the run made (not made again) is built into a Mitsuba scene
with the rest of the scene's geometry, as ``scan`` and ``evaluate-als`` build it, and cast from
above over the forest's domain at ``[truth] raster_cell_m`` and ``raster_subsamples``, on the
scene's terrain (``[terrain]``, else the plane ``[ground] z_m``).  Into the forest's folder go
``truth_dtm.tif``, ``truth_dsm.tif``, ``truth_chm.tif`` and ``truth_tree_id.tif`` (the files,
names and CRS of ``evaluate-als``: :func:`raster_crs`), and ``trees.csv`` gains ``top_cells``
and ``overtopped`` (:func:`~simlidar_mi.truth.als_truth.top_cells`).

The forest room (rank 4) cannot import the scene builder and the ray caster above it; the
forest run takes this module's :func:`forest_truth` as its ``truth`` hook instead.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

from .._runtime.progress import make_progress
from ..config import Override, SceneConfig, load_scene
from ..forest.run import ForestExtras, ForestRun
from ..forest.run import run_forest as _run_forest
from ..forest.stand import Forest
from ..io.atomic import writes_output
from ..io.terrain import ground_height, terrain_of
from .als_truth import HeightFn, RasterGrid, SurfaceTruth, surface_rasters, top_cells, write_truth_rasters

__all__ = ["run_forest", "forest_truth", "cast_truth", "raster_crs"]


def raster_crs(cfg: SceneConfig, terrain=None) -> str | None:
    """The truth rasters' CRS: the scene's ``[scene] crs``, else its DEM's (``read_dem`` refuses
    the two when they differ), else None (the scene's local frame, metres)."""
    return cfg["scene"]["crs"] or (terrain.crs if terrain is not None else None)


def cast_truth(cfg: SceneConfig, grid: RasterGrid, height_m: HeightFn, subsamples: int, shown, label: str,
               forest: Forest | None = None) -> tuple[SurfaceTruth, dict | None, dict[str, float]]:
    """The scene's geometry (:func:`simlidar_mi.lidar.survey.generate`, with ``forest`` when it
    is already made) built into a Mitsuba scene and cast from above on ``grid``
    (:func:`~.als_truth.surface_rasters`), with the progress ``shown`` (``label``: the
    command); geometry and scene are freed on return.  Returns the truth, the trees' columns
    (:attr:`~simlidar_mi.lidar.survey.SceneGeometry.trees`) and the seconds of the ``scene``
    (generation and build) and the ``truth_rasters`` steps."""
    from ..lidar.survey import build, generate  # noqa: PLC0415  (Mitsuba: only when cast)
    t0 = time.perf_counter()
    with shown.stage(f"{label}: scene", None, "step"):
        geometry = generate(cfg, forest=forest)
        built = build(cfg, geometry, patterns=[])
    seconds = {"scene": time.perf_counter() - t0}
    t0 = time.perf_counter()
    with shown.stage(f"{label}: truth rasters", grid.ny, "row") as bar:
        one = geometry.trees is not None and len(geometry.trees["tree_id"]) == 1
        truth = surface_rasters(built, grid, height_m, subsamples, variant=cfg["scene"]["variant"],
                                progress=bar.update, lone_tree=0 if one else None)
    del built
    seconds["truth_rasters"] = time.perf_counter() - t0
    return truth, geometry.trees, seconds


def forest_truth(forest: Forest, cfg: SceneConfig, folder: Path, progress: Any = False) -> ForestExtras:
    """The truth rasters of ``forest`` (made from ``cfg``) written into ``folder`` and its
    ``trees.csv`` columns ``top_cells`` and ``overtopped`` (the module docstring): the
    ``truth`` hook of :func:`simlidar_mi.forest.run.run_forest`."""
    terrain = terrain_of(cfg)
    height_m = terrain.height_m if terrain is not None else ground_height(cfg)
    d = forest.params.domain
    grid = RasterGrid.cover(d.x_min_m, d.x_max_m, d.y_min_m, d.y_max_m, float(cfg["truth"]["raster_cell_m"]))
    k = int(cfg["truth"]["raster_subsamples"])
    truth, _, s = cast_truth(cfg, grid, height_m, k, make_progress(progress), "forest", forest)
    seconds = {"truth_scene": s["scene"], "truth_rasters": s["truth_rasters"]}
    crs = raster_crs(cfg, terrain)
    t0 = time.perf_counter()
    files = {f"truth_{key}": path.name for key, path in write_truth_rasters(truth, folder, crs).items()}
    seconds["truth_write"] = time.perf_counter() - t0
    owned, over = top_cells(truth.tree_id, len(forest))
    summary = {"grid": grid.to_dict(), "subsamples": k, "crs": crs or "none (the scene's local frame, metres)",
               "n_trees": len(forest), "n_overtopped": int(over.sum())}
    return ForestExtras({"top_cells": owned, "overtopped": over.astype(int)}, files, summary, seconds)


@writes_output("out_dir")
def run_forest(cfg: SceneConfig | str | Path, out_dir: str | Path, overrides: Sequence[str] = (),
               *, progress=False, parallel: bool | None = None, truth_rasters: bool | None = None) -> ForestRun:
    """Make the forest of a scene file and write its files (:mod:`simlidar_mi.forest.run`), and
    with ``[forest] truth_rasters`` the truth rasters too (module docstring).  ``truth_rasters``:
    True or False overrides the scene's key (as ``--set forest.truth_rasters=...``); None keeps
    it.  ``progress`` and ``parallel``: as :func:`simlidar_mi.forest.run.run_forest`."""
    on = None if truth_rasters is None else bool(truth_rasters)
    if not isinstance(cfg, SceneConfig):
        extra = [] if on is None else [Override(f"forest.truth_rasters={str(on).lower()}", f"truth_rasters={on}")]
        cfg = load_scene(cfg, [*overrides, *extra])
    elif on is not None and on != cfg["forest"]["truth_rasters"]:  # the key in a copy of the scene
        cfg = replace(cfg, sections={**cfg.sections, "forest": {**cfg["forest"], "truth_rasters": on}},
                      overridden={**cfg.overridden, "forest.truth_rasters": f"truth_rasters={on}"})
    return _run_forest(cfg, out_dir, progress=progress, parallel=parallel, truth=forest_truth)
