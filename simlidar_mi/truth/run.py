"""``simlidar-mi truth SCENE --out DIR``: the canopy ground truth of a scene file, on disk.

Writes, atomically (one staged folder):

``truth.nc``
    the per-voxel Dataset of :func:`simlidar_mi.truth.compute.compute_truth` plus the
    canopy height/width profiles along the row (1-D over the along-row slices);
``truth_summary.csv``
    quantity, value, unit: totals, LAI, mean canopy height and width, TRV and LWA (when
    the row spacing is known), the grid;
``truth_profiles.png``
    LAD and PAD against height; canopy height and width along the row.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError
from ..io.atomic import staged_dir, write_csv, writes_output
from .compute import compute_truth, default_grid
from .grid import grid_values, write_grid
from .row_metrics import canopy_profiles, lwa_m2_ha, trv_m3_ha

log = logging.getLogger(__name__)

__all__ = ["TruthRun", "run_truth", "truth_geometry", "truth_grid", "row_spacing_of", "TRUTH_OUTPUTS"]

TRUTH_OUTPUTS = (r"truth\.nc", r"truth_summary\.csv", r"truth_profiles\.png")


@dataclass
class TruthRun:
    """What :func:`run_truth` computed: ``dataset``, the ``xarray.Dataset`` written as truth.nc
    (leaf and wood area, wood volume, LAD and PAD per voxel, canopy height and width per slice);
    ``summary``, the rows of truth_summary.csv (``quantity``, ``value``, ``unit``); ``files``,
    the paths written (empty without an output folder)."""

    dataset: object
    summary: list[dict]
    files: dict = field(default_factory=dict)


def truth_geometry(cfg: SceneConfig):
    """(SceneGeometry, plot ground area or None) of a scene: its plants and primitives, or
    for a gap-fraction scene ([random_leaves], [strawberry]) the first canopy's leaves
    (the N original random leaves, whose total is exactly N·a) and its plot area."""
    from ..geometry import Branches
    from ..lidar.survey import SceneGeometry, generate

    if cfg.has("random_leaves") or cfg.has("strawberry"):
        from ..canopy.canopy import canopies_from_config
        can = canopies_from_config(cfg)[0]
        b = can.branches if can.branches is not None else Branches.empty()
        return SceneGeometry(b, can.leaves, [], source=cfg.source), can.plot_area_m2
    return generate(cfg), None


#: Bytes a voxel of the truth holds at once: its six float64 arrays (``truth``, ``evaluate``).
TRUTH_BYTES_PER_VOXEL = 48
#: ``evaluate-photo`` keeps two float64 arrays (leaf and plant area) and builds them one at a time.
PHOTO_BYTES_PER_VOXEL = 16


def truth_grid(cfg: SceneConfig, geometry, voxel_m: float | None = None, *,
               bytes_per_voxel: int = TRUTH_BYTES_PER_VOXEL, memory: int | None = None):
    """The ``[truth]`` grid over ``geometry`` (:func:`~simlidar_mi.truth.compute.default_grid`),
    ``voxel_m`` (evaluate's ``--voxel``) instead of ``[truth] voxel_m`` when given; an error
    names what the user gave: ``--voxel``, the ``--set`` argument or the scene's key, and the
    margin when the margin made the grid too large. A grid whose arrays (``bytes_per_voxel``)
    would hold more than half the memory available (:func:`simlidar_mi.config.work.memory_budget`,
    or ``memory`` bytes) is refused here, before anything is allocated, naming the same key."""
    from ..config.work import memory_budget  # noqa: PLC0415
    t = cfg["truth"]
    try:
        grid = default_grid(geometry, t["voxel_m"] if voxel_m is None else voxel_m, t["margin_m"])
        need = bytes_per_voxel * float(np.prod(grid.shape))
        budget = memory_budget() if memory is None else memory
        if need > budget:
            nx, ny, nz = grid.shape
            raise ConfigError(f"a {grid.voxel_m:g} m grid over this scene ({nx} × {ny} × {nz} voxels) "
                              f"would hold ~{need / 1e9:.3g} GB, more than half the memory available "
                              f"({budget / 1e9:.3g} GB); use larger voxels", key="voxel_m", value=grid.voxel_m)
        return grid
    except ConfigError as exc:
        if exc.key != "margin_m" and voxel_m is not None:
            raise ConfigError(exc.reason, key="--voxel", value=voxel_m) from None
        key = "truth.margin_m" if exc.key == "margin_m" else "truth.voxel_m"
        raise cfg.relabel(ConfigError(exc.reason, file=cfg.source, key=key, value=t[key[6:]])) from None


def row_spacing_of(cfg: SceneConfig) -> float | None:
    """``[truth] row_spacing_m``, else a ``row_spacing_m`` key of a section the scene file
    gives (e.g. a vineyard's), else None."""
    if cfg["truth"]["row_spacing_m"] is not None:
        return float(cfg["truth"]["row_spacing_m"])
    for name, keys in cfg.sections.items():
        if name != "truth" and cfg.has(name) and isinstance(keys, dict) and keys.get("row_spacing_m"):
            return float(keys["row_spacing_m"])
    return None


def row_ground_area_of(cfg: SceneConfig) -> float | None:
    """The ground a row scene's plants own, as ``measure`` counts it: an orchard's
    n_trees × spacing_m × row_spacing_m, a vineyard's n_rows × vines_per_row × vine_spacing_m
    × row_spacing_m; None for other scenes."""
    if cfg.has("vineyard") or cfg.has("vineyard.canopy"):
        v = cfg["vineyard"]
        return v["n_rows"] * v["vines_per_row"] * v["vine_spacing_m"] * v["row_spacing_m"]
    if cfg.has("orchard") or cfg.has("orchard.tree") or cfg.has("orchard.leaves"):
        o = cfg["orchard"]
        return o["n_trees"] * o["spacing_m"] * o["row_spacing_m"]
    return None


def _summary(ds, grid, prof: dict, spacing: float | None, t: dict) -> list[dict]:
    a = ds.attrs
    rows = [("total_leaf_area_m2", a["total_leaf_area_m2"], "m2"),
            ("total_wood_area_m2", a["total_wood_area_m2"], "m2"),
            ("total_wood_volume_m3", a["total_wood_volume_m3"], "m3"),
            ("total_plant_area_m2", a["total_plant_area_m2"], "m2"),
            ("leaf_area_outside_m2", a["leaf_area_outside_m2"], "m2"),
            ("wood_area_outside_m2", a["wood_area_outside_m2"], "m2"),
            ("wood_volume_outside_m3", a["wood_volume_outside_m3"], "m3"),
            ("ground_area_m2", a["ground_area_m2"], "m2"),
            ("LAI", a["LAI"], "m2 m-2"), ("PAI", a["PAI"], "m2 m-2"),
            ("mean_canopy_height_m", prof["mean_height_m"], "m"),
            ("mean_canopy_width_m", prof["mean_width_m"], "m"),
            ("canopy_base", t["canopy_base"], ""), ("occupancy", t["occupancy"], ""),
            ("row_axis", t["row_axis"], ""),
            ("row_spacing_m", "" if spacing is None else spacing, "m"),
            ("TRV_m3_ha", "" if spacing is None else float(trv_m3_ha(prof["mean_height_m"],
                                                                       prof["mean_width_m"], spacing)), "m3 ha-1"),
            ("LWA_m2_ha", "" if spacing is None else float(lwa_m2_ha(prof["mean_height_m"], spacing)), "m2 ha-1"),
            ("voxel_m", grid.voxel_m, "m"),
            ("grid_corner_x_m", grid.corner_m[0], "m"), ("grid_corner_y_m", grid.corner_m[1], "m"),
            ("grid_corner_z_m", grid.corner_m[2], "m"),
            ("nx", grid.shape[0], ""), ("ny", grid.shape[1], ""), ("nz", grid.shape[2], "")]
    return [{"quantity": q, "value": v, "unit": u} for q, v, u in rows]


def _figure(ds, prof: dict, path: Path, title: str) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    z = ds["z"].values
    ax0.plot(ds["LAD_profile_m2_m3"].values, z, label="LAD")
    ax0.plot(ds["PAD_profile_m2_m3"].values, z, label="PAD", ls="--")
    ax0.set_xlabel("area density over the ground area (m² m⁻³)")
    ax0.set_ylabel("height z (m)")
    ax0.legend()
    ax0.set_title("vertical profile")
    ax1.plot(prof["along_m"], prof["height_m"], label="canopy height")
    ax1.plot(prof["along_m"], prof["width_m"], label="canopy width")
    ax1.set_xlabel(f"{prof['row_axis']} along the row (m)")
    ax1.set_ylabel("m")
    ax1.legend()
    ax1.set_title("canopy envelope per slice")
    fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


@writes_output("out_dir")
def run_truth(cfg: SceneConfig | str | Path, out_dir: str | Path | None = None,
              overrides: list[str] | tuple = (), progress=False) -> TruthRun:
    """The exact canopy truth of a scene on a voxel grid: the ``truth`` command.

    Parameters
    ----------
    cfg : a scene file's path or a loaded :class:`~simlidar_mi.config.SceneConfig`; its
        ``[truth]`` keys (voxel size, margin, row axis, canopy base, occupancy, row spacing,
        ground area) shape the grid and the summary.
    out_dir : with a folder, truth.nc, truth_summary.csv and truth_profiles.png are written
        there, all together when complete (a failure leaves the folder as it was).
    overrides : ``"section.key=value"`` strings, as ``--set`` takes them (with a path only).
    progress : see :func:`simlidar_mi._runtime.progress.make_progress`.

    Returns
    -------
    TruthRun
        The dataset, the summary rows (totals, LAI over the ground area, mean canopy height
        and width, TRV and LWA with a row spacing) and the files.
    """
    if not isinstance(cfg, SceneConfig):
        cfg = load_scene(cfg, list(overrides))
    t = cfg["truth"]
    prog = make_progress(progress)
    geometry, plot_area = truth_geometry(cfg)
    grid = truth_grid(cfg, geometry)
    spacing = row_spacing_of(cfg)
    ground = t["ground_area_m2"] if t["ground_area_m2"] is not None else plot_area
    if ground is None:  # a row scene: the ground its plants own, as `measure` counts it
        ground = row_ground_area_of(cfg)
    if ground is None and spacing is not None:  # a row's ground: its length × the row spacing
        a = {"x": 0, "y": 1}[t["row_axis"]]
        ground = grid.shape[a] * grid.voxel_m * spacing
    ground_z = float(cfg["ground"]["z_m"]) if "ground" in cfg.sections else 0.0
    ds = compute_truth(geometry, grid, progress=prog, ground_area_m2=ground, crs=cfg["scene"]["crs"],
                       ground_z_m=ground_z)
    key = "leaf_area_m2" if t["occupancy"] == "leaf" else "plant_area_m2"
    prof = canopy_profiles(grid_values(ds, key) > 0, grid, t["row_axis"], base=t["canopy_base"],
                           ground_z_m=ground_z, terrain=geometry.terrain)
    dim = f"along_{t['row_axis']}"
    ds = ds.assign_coords({dim: (dim, prof["along_m"], {"units": "m", "long_name": "slice centre along the row"})})
    for name, long in (("height_m", "canopy height per slice"), ("width_m", "canopy width across the row")):
        ds[f"canopy_{name}"] = (dim, prof[name], {"units": "m", "long_name": long})
    ds.attrs.update({"scene": str(cfg.source or ""), "canopy_base": t["canopy_base"],
                     "occupancy": t["occupancy"], "row_axis": t["row_axis"],
                     "mean_canopy_height_m": prof["mean_height_m"],
                     "mean_canopy_width_m": prof["mean_width_m"],
                     "row_spacing_m": float("nan") if spacing is None else spacing})
    summary = _summary(ds, grid, prof, spacing, t)
    run = TruthRun(ds, summary)
    if out_dir is None:
        return run
    with staged_dir(out_dir, TRUTH_OUTPUTS) as stage:
        write_grid(ds, stage / "truth.nc")
        write_csv(stage / "truth_summary.csv", ["quantity", "value", "unit"], summary)
        _figure(ds, prof, stage / "truth_profiles.png",
                f"{cfg['scene']['name']}: ground truth at {grid.voxel_m:g} m voxels")
    out = Path(out_dir)
    run.files = {"truth": out / "truth.nc", "summary": out / "truth_summary.csv",
                 "profiles": out / "truth_profiles.png"}
    return run
