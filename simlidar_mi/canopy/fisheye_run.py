"""Virtual DHP of a scene: camera placement from ``[fisheye]``, rendering, and the output files.

::

    from simlidar_mi.config import load_scene
    from simlidar_mi.truth.run import truth_geometry
    from simlidar_mi.canopy.fisheye_run import fisheye_scene, run_fisheye
    cfg = load_scene("scenes/orchard_leafy.toml")
    geometry, _ = truth_geometry(cfg)
    run = run_fisheye(cfg, fisheye_scene(cfg, geometry), geometry.bounds_m(), "out/fisheye")

(``simlidar-mi fisheye`` does exactly this.)  Keys and the placement protocol:
:mod:`simlidar_mi.config.keys_fisheye`; conventions: :mod:`simlidar_mi.canopy.fisheye`.

Files written (atomically, in one staged folder):

- ``fisheye_<k>.exr``: float32 channels ``coverage`` (NaN outside the image circle),
  ``theta_deg`` and ``azimuth_deg`` (pixel centres, NaN outside); header: the lens
  (``projection``, ``lens_coeffs``, ``theta_edge_deg``), ``format``, ``radius_px``,
  ``camera_position_m`` (float64), ``looking``, ``tilt_deg``, ``tilt_azimuth_deg``,
  ``heading_deg``, ``spp`` and ``simlidar_fisheye`` (all of it as JSON);
- ``fisheye_<k>.png``: the binary image (plant green, gap white, outside the circle black);
- ``fisheye_gap.csv``: per position, ring and sector the gap fractions
  (:data:`CSV_COLUMNS`; a ring's total over all sectors has sector ``all``, 0–360°);
- ``fisheye_positions.csv``: per position k its x, y, z and the render time.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._runtime.progress import make_progress
from ..config import SceneConfig
from ..errors import ConfigError, SimlidarError
from ..io.atomic import staged_dir, write_csv, writes_output
from ..io.exr import header_value, read_exr
from ..io.terrain import check_inside, terrain_of
from .fisheye import TABLE_COLUMNS, FisheyeCamera, FisheyeImage, GapTable, make_fisheye, render_fisheye

__all__ = ["CSV_COLUMNS", "FisheyeRun", "fisheye_positions", "fisheye_cameras", "fisheye_scene", "run_fisheye",
           "leaf_length_m", "warn_leaves_near_lenses",
           "write_fisheye_exr", "read_fisheye_exr"]

CSV_COLUMNS = ("position", "x_m", "y_m", "z_m") + TABLE_COLUMNS
POSITION_COLUMNS = ("position", "x_m", "y_m", "z_m", "looking", "width", "height", "spp", "seconds")
FISHEYE_OUTPUTS = (r"fisheye_gap\.csv", r"fisheye_positions\.csv", r"fisheye_\d+\.(exr|png)")
PLANT_RGB, GAP_RGB, OUTSIDE_RGB = (0, 128, 0), (255, 255, 255), (0, 0, 0)
DEFAULT_HEIGHT_M = 1.0  # lens above the ground looking up; above the highest plant looking down
# A periodic plot is tiled for rays to this zenith (or the outermost ring edge below 90°, if
# larger): beyond it a ray leaves the copies and sees open sky (the 85–90° band).
TILE_ZENITH_DEG = 85.0
# A leaf this many leaf lengths or nearer to a lens fills whole rings (its gap 0): warned.
NEAR_LEAF_LENGTHS = 2.0
# The default lens under a [random_leaves] layer: this many leaf lengths below its lowest leaf.
BELOW_LEAF_LENGTHS = 3.0


def fisheye_positions(cfg: SceneConfig, lo_m, hi_m) -> np.ndarray:
    """(n, 3) camera positions (x, y, z), metres, from ``[fisheye]`` and the geometry's bounds."""
    f = cfg["fisheye"]
    lo, hi = np.asarray(lo_m, np.float64), np.asarray(hi_m, np.float64)
    # A key of another layout would be silently ignored: refuse it.
    for key, layout in (("points_m", "points"), ("transect_m", "transect")):
        if f[key] is not None and f["layout"] != layout:
            raise ConfigError(f"is used only with fisheye.layout = '{layout}', and the layout is "
                              f"'{f['layout']}': set the layout or drop fisheye.{key}",
                              file=cfg.source, key=f"fisheye.{key}", value=f[key])
    x0, y0, x1, y1 = f["area_m"] if f["area_m"] is not None else (lo[0], lo[1], hi[0], hi[1])
    if f["layout"] == "grid":
        nx, ny = f["grid_n"]
        xs = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
        ys = y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny
        gx, gy = np.meshgrid(xs, ys)  # row-major in y: positions go along x first
        xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    elif f["layout"] == "transect":
        t = f["transect_m"] if f["transect_m"] is not None else (x0, 0.5 * (y0 + y1), x1, 0.5 * (y0 + y1))
        n = f["transect_n"]
        s = np.full(1, 0.5) if n == 1 else np.linspace(0.0, 1.0, n)
        xy = np.stack([t[0] + s * (t[2] - t[0]), t[1] + s * (t[3] - t[1])], axis=1)
    else:
        if f["points_m"] is None:
            raise ConfigError("layout 'points' needs fisheye.points_m", file=cfg.source,
                              key="fisheye.points_m", value=None)
        xy = np.asarray(f["points_m"], np.float64)
    ground = float(cfg["ground"]["z_m"]) if "ground" in cfg.sections else 0.0
    if f["height_m"] is not None:
        z = ground + f["height_m"]
    else:
        # looking up: 1 m above the ground under a canopy taller than 2 m, else at the ground (a crop)
        up = DEFAULT_HEIGHT_M if hi[2] - ground >= 2 * DEFAULT_HEIGHT_M else 0.0
        z = ground + up if f["looking"] == "up" else float(hi[2]) + DEFAULT_HEIGHT_M
        if f["looking"] == "up" and cfg.has("random_leaves"):
            # A lens inside the leaf layer has leaves millimetres above it (whole rings dark):
            # the default sits below the layer, as a lens in the field goes below the lowest leaves.
            from ..plants.random_leaves import RandomLeavesParams  # noqa: PLC0415
            r = cfg["random_leaves"]
            p = RandomLeavesParams(r["n_leaves"], r["leaf_area_m2"], tuple(r["plot_size_m"]),
                                   tuple(r["height_range_m"]), r["angle_law"], r["shape"], r["n_sides"])
            z = min(z, float(lo[2]) - BELOW_LEAF_LENGTHS * 2.0 * p.leaf_radius_m)
    z = np.full(len(xy), z)
    if f["looking"] == "up" and cfg.has("terrain"):  # on a terrain: the same height above it, lens by lens
        t = terrain_of(cfg)
        check_inside(t, xy[:, 0], xy[:, 1], "lenses", cfg.source)
        z += t.height_m(xy[:, 0], xy[:, 1]) - ground
    return np.column_stack([xy, z])


def fisheye_cameras(cfg: SceneConfig, lo_m, hi_m) -> list[FisheyeCamera]:
    """One :class:`FisheyeCamera` per position of :func:`fisheye_positions`."""
    f = cfg["fisheye"]
    if f["projection"] == "polynomial" and f["coeffs"] is None:
        raise ConfigError("projection 'polynomial' needs fisheye.coeffs", file=cfg.source,
                          key="fisheye.coeffs", value=None)
    try:
        return [make_fisheye(p, projection=f["projection"], coeffs=f["coeffs"], resolution=f["resolution"],
                             format=f["format"], looking=f["looking"], tilt_deg=f["tilt_deg"],
                             tilt_azimuth_deg=f["tilt_azimuth_deg"], heading_deg=f["heading_deg"])
                for p in fisheye_positions(cfg, lo_m, hi_m)]
    except ConfigError as exc:
        raise cfg.relabel(ConfigError(exc.reason, file=cfg.source, key=exc.key, value=exc.value)) from None


def leaf_length_m(leaves) -> float:
    """Median leaf length: twice the largest distance from a leaf's mean vertex to its vertices
    (the diagonal of a square leaf, the circumdiameter of a regular disc), metres."""
    if not len(leaves):
        return 0.0
    key = leaves.plant_id.astype(np.int64) * (2**32) + leaves.leaf_id.astype(np.int64)
    order = np.argsort(key, kind="stable")
    k = key[order]
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    v = leaves.vertices[order]
    n = np.diff(np.r_[starts, len(k)])
    mean = np.add.reduceat(v.sum(axis=1), starts, axis=0) / (3 * n)[:, None]
    d = np.linalg.norm(v - np.repeat(mean, n, axis=0)[:, None, :], axis=2).max(axis=1)
    return float(2.0 * np.median(np.maximum.reduceat(d, starts)))


def warn_leaves_near_lenses(cfg: SceneConfig, leaves, lenses_m, period_m=None) -> int:
    """Warn (one :class:`~simlidar_mi.errors.SimlidarWarning` line) when leaves lie within
    :data:`NEAR_LEAF_LENGTHS` leaf lengths of a lens on the side it looks to; returns how many
    lenses have one.  ``period_m``: (w, l) of a periodic plot (distances across its edges)."""
    import warnings  # noqa: PLC0415
    from ..errors import SimlidarWarning  # noqa: PLC0415
    lenses = np.asarray(lenses_m, np.float64).reshape(-1, 3)
    if not len(leaves) or not len(lenses):
        return 0
    from scipy.spatial import cKDTree  # noqa: PLC0415
    near = NEAR_LEAF_LENGTHS * leaf_length_m(leaves)
    v = leaves.vertices.reshape(-1, 3)
    sign = 1.0 if cfg["fisheye"]["looking"] == "up" else -1.0
    zl = lenses[:, 2]
    # Only vertices in the slab a lens could see within `near` on its side (bounded work).
    lo_z, hi_z = (zl.min(), zl.max() + near) if sign > 0 else (zl.min() - near, zl.max())
    cand = v[(v[:, 2] >= lo_z) & (v[:, 2] <= hi_z)].copy()
    pts = lenses.copy()
    if period_m is not None and len(cand):  # distances across a periodic plot's edges
        w = np.asarray(period_m, np.float64)
        cand[:, :2] %= w
        pts[:, :2] %= w
        shifts = np.array([(i, j, 0.0) for i in (-1, 0, 1) for j in (-1, 0, 1)]) * np.r_[w, 0.0]
        cand = (cand[None] + shifts[:, None]).reshape(-1, 3)
    dist = np.full(len(lenses), np.inf)
    if len(cand):
        tree = cKDTree(cand)
        for i, (p, idx) in enumerate(zip(pts, tree.query_ball_point(pts, near))):
            d = cand[np.asarray(idx, np.int64)] - p
            d = d[sign * d[:, 2] >= 0.0]
            if len(d):
                dist[i] = float(np.sqrt((d * d).sum(axis=1)).min())
    hit = np.flatnonzero(dist < near)
    if len(hit):
        k = int(hit[np.argmin(dist[hit])])
        x, y, z = lenses[k]
        side = "above" if sign > 0 else "below"
        edge = float(v[:, 2].min()) if sign > 0 else float(v[:, 2].max())
        warnings.warn(SimlidarWarning(
            f"fisheye.height_m: {len(hit)} of {len(lenses)} lenses have leaves within {NEAR_LEAF_LENGTHS:g} leaf "
            f"lengths ({near:.3g} m) {side} them, the nearest {dist[k]:.3g} m from lens {k} at ({x:.3g}, {y:.3g}, "
            f"{z:.3g}) m: such a leaf fills whole rings and the LAI read is too high; place the lenses "
            f"{'below' if sign > 0 else 'above'} the leaves (the {'lowest' if sign > 0 else 'highest'} at z = {edge:.3g} m)"), stacklevel=2)
    return len(hit)


def fisheye_scene(cfg: SceneConfig, geometry):
    """The scene the cameras see: a ``[random_leaves]`` plot tiled around the lenses (the
    tiling of ``evaluate-photo``, :func:`~simlidar_mi.canopy.gapfraction.tiled_sky_scene`),
    otherwise ``geometry`` (the scene's plants and primitives) as it stands.  Warns when
    leaves lie close to a lens (:func:`warn_leaves_near_lenses`)."""
    lenses = fisheye_positions(cfg, *geometry.bounds_m())
    if cfg.has("random_leaves"):
        from .canopy import canopies_from_config  # noqa: PLC0415
        from .gapfraction import tiled_sky_scene  # noqa: PLC0415
        f = cfg["fisheye"]
        canopy = canopies_from_config(cfg)[0]
        x0, y0, x1, y1 = canopy.plot_bounds_m
        warn_leaves_near_lenses(cfg, geometry.leaves, lenses, (x1 - x0, y1 - y0))
        theta = max([TILE_ZENITH_DEG] + [e for e in f["rings_deg"] if e < 90.0])
        return tiled_sky_scene(canopy, lenses, theta, key="fisheye.rings_deg", variant=cfg["scene"]["variant"])
    from ..scene.build import build_scene  # noqa: PLC0415
    warn_leaves_near_lenses(cfg, geometry.leaves, lenses)
    sc = cfg["scene"]  # as lidar.survey.build with no scanner: the lenses sit inside the geometry's origin
    return build_scene(geometry.branches, geometry.leaves, geometry.primitives,
                       representation=sc["representation"], facets=sc["facets"],
                       origin_m=sc["origin_m"], variant=sc["variant"], source=cfg.source,
                       instances=geometry.instances, terrain=getattr(geometry, "terrain", None))


@dataclass
class FisheyeRun:
    """Every rendered image of a scene, its gap table and the files written."""

    images: list[FisheyeImage]
    tables: list[GapTable]
    files: dict[str, Path] = field(default_factory=dict)
    seconds: float = 0.0

    def rows(self) -> list[dict]:
        out = []
        for k, (img, tab) in enumerate(zip(self.images, self.tables)):
            x, y, z = (float(v) for v in img.camera.position_m)
            out += tab.rows(position=k, x_m=x, y_m=y, z_m=z)
        return out


@writes_output("out_dir")
def run_fisheye(cfg: SceneConfig, built, bounds_m, out_dir: str | Path | None = None, *,
                write_images: bool = True, progress=False) -> FisheyeRun:
    """Render every ``[fisheye]`` position of ``built`` (the scene of ``cfg``) and tabulate its rings.

    The ``fisheye`` command is this call after :func:`simlidar_mi.truth.run.truth_geometry` and
    :func:`fisheye_scene` (see the commands reference for the three calls).

    Parameters
    ----------
    cfg : the loaded scene; its ``[fisheye]`` keys give the lens, resolution, samples per pixel,
        positions (grid, transect or points), rings and sectors.
    built : the scene the lenses see (:func:`fisheye_scene`).
    bounds_m : (lo, hi) of the geometry (``SceneGeometry.bounds_m()``), for the default area
        and the down-looking height.
    out_dir : with a folder, fisheye_gap.csv, fisheye_positions.csv and, with ``write_images``,
        fisheye_<k>.exr (coverage, pixel angles, lens and pose in the header) and fisheye_<k>.png
        (sky, plant, outside the circle) per position, all together when complete.
    progress : see :func:`simlidar_mi._runtime.progress.make_progress` (a count of images).

    Returns
    -------
    FisheyeRun
        ``images`` (one :class:`~simlidar_mi.canopy.fisheye.FisheyeImage` per position, with its
        camera), ``tables`` (their ring × sector gap fractions: ``ring_gap``, ``ring_lo_deg``,
        ``ring_hi_deg``, ...), ``files`` and ``seconds``.
    """
    f = cfg["fisheye"]
    cameras = fisheye_cameras(cfg, *bounds_m)
    prog = make_progress(progress)
    t0 = time.perf_counter()
    images, tables = [], []
    for cam in prog.iter(cameras, "fisheye: rendering", unit="image"):
        img = render_fisheye(built, cam, spp=f["spp"], seed=cfg.seed or 0, variant=cfg["scene"]["variant"])
        images.append(img)
        tables.append(img.table(f["rings_deg"], f["n_sectors"]))
    run = FisheyeRun(images, tables, seconds=time.perf_counter() - t0)
    if out_dir is None:
        return run
    from ..io.png import write_label_png  # noqa: PLC0415
    out = Path(out_dir)
    with staged_dir(out, FISHEYE_OUTPUTS) as stage:
        write_csv(stage / "fisheye_gap.csv", CSV_COLUMNS, run.rows())
        write_csv(stage / "fisheye_positions.csv", POSITION_COLUMNS, (
            {"position": k, **dict(zip(("x_m", "y_m", "z_m"), (float(v) for v in img.camera.position_m))),
             "looking": img.camera.looking, "width": img.camera.width, "height": img.camera.height,
             "spp": img.spp, "seconds": img.seconds} for k, img in enumerate(images)))
        if write_images:
            for k, img in enumerate(images):
                write_fisheye_exr(img, stage / f"fisheye_{k}.exr", extra={"scene": str(cfg.source or "")})
                write_label_png(stage / f"fisheye_{k}.png", img.labels(), (GAP_RGB, PLANT_RGB, OUTSIDE_RGB))
    run.files = {"csv": out / "fisheye_gap.csv", "positions": out / "fisheye_positions.csv"}
    if write_images:
        run.files.update({f"exr_{k}": out / f"fisheye_{k}.exr" for k in range(len(images))})
        run.files.update({f"png_{k}": out / f"fisheye_{k}.png" for k in range(len(images))})
    return run


def write_fisheye_exr(image: FisheyeImage, path: str | Path, *, extra: dict | None = None) -> Path:
    """Write ``image``'s coverage and pixel angles (float32) with the lens and pose in the header."""
    import OpenEXR  # noqa: PLC0415
    from ..io.atomic import atomic_file  # noqa: PLC0415
    cam = image.camera
    meta = {**cam.to_dict(), "spp": image.spp, "seed": image.seed, "jitter": image.jitter,
            "seconds": image.seconds}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "simlidar_fisheye": json.dumps(meta, sort_keys=True)}
    flat = {"projection": cam.lens.name or cam.lens.projection, "lens_coeffs": list(cam.lens.coeffs) or "",
            "theta_edge_deg": float(np.degrees(cam.lens.theta_edge_rad)), "format": cam.format,
            "radius_px": float(cam.radius_px), "camera_position_m": cam.position_m, "looking": cam.looking,
            "tilt_deg": cam.tilt_deg, "tilt_azimuth_deg": cam.tilt_azimuth_deg,
            "heading_deg": cam.heading_deg, "spp": image.spp}
    for key, value in {**flat, **(extra or {})}.items():
        header[key] = header_value(value)
    a = image.angles
    channels = {"coverage": np.ascontiguousarray(image.coverage, np.float32),
                "theta_deg": np.ascontiguousarray(a.theta_deg, np.float32),
                "azimuth_deg": np.ascontiguousarray(a.azimuth_deg, np.float32)}
    with atomic_file(path) as tmp:
        with OpenEXR.File(dict(header), dict(channels)) as fh:  # it modifies the dicts: copies
            fh.write(str(tmp))
    return Path(path)


def read_fisheye_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Channels and header of a fisheye EXR; ``header['metadata']`` is the parsed JSON."""
    channels, header = read_exr(path)
    if "coverage" not in channels or "simlidar_fisheye" not in header:
        raise SimlidarError(f"{path}: not a fisheye EXR (no 'coverage' channel or 'simlidar_fisheye' header)")
    header["metadata"] = json.loads(header["simlidar_fisheye"])
    return channels, header
