"""Gap-fraction images of virtual canopies: coverage renders, the P0 table and the gap EXRs.

The pipeline behind ``simlidar-mi gapfraction``::

    from simlidar_mi.canopy.gapfraction import run_gapfraction
    run = run_gapfraction("scenes/random_leaves_spherical.toml", "out/gap")
    for img in run.images:
        print(img.camera.kind, img.camera.zenith_deg, img.p0)

and the pieces a notebook can use on its own (:class:`~simlidar_mi.canopy.canopy.Canopy`,
:func:`~simlidar_mi.canopy.cameras.make_camera`,
:func:`~simlidar_mi.canopy.windows.analysis_window`, :func:`build_canopy_scene`,
:func:`render_gap`).  View conventions and the camera kinds are described in
:mod:`simlidar_mi.canopy.cameras`, the analysis window modes in
:mod:`simlidar_mi.canopy.windows`.

P0 of a window is ``1 − mean(coverage)`` over its pixels, where a pixel's coverage
is the share of its samples whose primary ray meets a leaf (see
``plugins/coverage_integrator.py``).  Averaging binary coverage is exact for gap
fraction; the display threshold of 0.5 used for the mask PNGs is never used for P0.
"""
from __future__ import annotations

import json
import logging
import math
import numbers
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._runtime.mitsuba import check_variant
from .._runtime.progress import make_progress
from ..config import SceneConfig, load_scene
from ..errors import ConfigError, SimlidarError
from ..geometry import Branches, Leaves
from ..io.atomic import atomic_file, staged_dir, write_csv, writes_output
from ..io.exr import header_value, read_exr
from .cameras import CAMERAS, Camera, make_camera
from .canopy import Canopy, canopies_from_config
from .gapfraction_defaults import DEFAULTS
from .windows import Window, analysis_window, tile_offsets

log = logging.getLogger(__name__)

__all__ = [
    "GapImage", "GapFractionRun", "GapSummary", "CSV_COLUMNS", "REPLICATE_COLUMNS",
    "build_canopy_scene", "tiled_sky_scene", "render_gap", "gap_views", "gap_images", "run_gapfraction",
    "replicate_sd", "summarise", "write_gap_exr", "read_gap_exr",
]

CSV_COLUMNS = ("camera", "zenith_deg", "step", "p0", "p0_sd", "p0_sd_plot", "replicates",
               "leaf_area_m2", "lai", "spp", "width", "height", "seconds")
REPLICATE_COLUMNS = ("replicate", "camera", "zenith_deg", "step", "p0", "leaf_area_m2", "lai",
                     "seconds")
# The files a gap-fraction run owns in its folder (whole-name regular expressions): a
# re-run removes those it does not write again (images after --no-images, other views).
GAPFRACTION_OUTPUTS = (r"gap_fraction(_replicates)?\.csv", r"gap_fraction\.json",
                       rf"gap_({'|'.join(CAMERAS)})_z[^_]+_s[^_.]+\.(png|exr)")


def _tiled_leaves(leaves: Leaves, offsets: np.ndarray) -> Leaves:
    if len(offsets) == 1 and not offsets.any():
        return leaves
    shift = np.zeros((len(offsets), 1, 1, 3))
    shift[:, 0, 0, :2] = offsets
    verts = (leaves.vertices[None] + shift).reshape(-1, 3, 3)
    n = len(offsets)
    return Leaves(verts, np.tile(leaves.leaf_id, n), np.tile(leaves.plant_id, n))


def build_canopy_scene(canopy: Canopy, offsets: np.ndarray | None = None, *,
                       variant: str | None = None):
    """A Mitsuba scene of ``canopy`` (tiled by ``offsets`` if given).

    The float64 origin is the plot centre at z = 0 rounded to whole metres, so the
    cameras' real coordinates only need that origin subtracted.
    """
    from ..scene.build import build_scene  # noqa: PLC0415  (imports Mitsuba)
    leaves = canopy.leaves if offsets is None else _tiled_leaves(canopy.leaves, offsets)
    branches = canopy.branches if canopy.branches is not None else Branches.empty()
    if offsets is not None and len(branches) and not (len(offsets) == 1 and not offsets.any()):
        parts = [branches.translated([dx, dy, 0.0]) for dx, dy in offsets]
        branches = Branches.concat(parts)
    origin = np.round(np.r_[canopy.plot_centre_m, 0.0])
    return build_scene(branches, leaves, [], origin_m=origin, variant=variant)


def tiled_sky_scene(canopy: Canopy, lenses_m, theta_max_deg: float, *, key: str,
                    variant: str | None = None):
    """A periodic ``canopy`` tiled for hemispherical views from ``lenses_m`` ((n, 3) metres).

    Every ray from a lens within ``theta_max_deg`` of the vertical meets the periodic canopy
    until it leaves the leaf layer: the plot and the lenses are covered out to the reach
    ``Δz·tan θ_max``, Δz the largest height from a lens to the far side of the layer (the top
    leaf looking up, the lowest looking down).  ``simlidar-mi fisheye`` and ``evaluate-photo``
    both see a ``[random_leaves]`` plot through this, so the two read the same sky.  ``key``:
    the scene key that sets ``theta_max_deg`` (named if the tiling grows too large).
    """
    lenses = np.asarray(lenses_m, np.float64).reshape(-1, 3)
    z = canopy.leaves.vertices[..., 2] if len(canopy.leaves) else np.zeros(1)
    dz = max(float(z.max()) - float(lenses[:, 2].min()), float(lenses[:, 2].max()) - float(z.min()), 0.0)
    reach = dz * math.tan(math.radians(theta_max_deg))
    x0, y0, x1, y1 = canopy.plot_bounds_m
    lo = np.minimum([x0, y0], lenses[:, :2].min(axis=0)) - reach
    hi = np.maximum([x1, y1], lenses[:, :2].max(axis=0)) + reach
    try:
        offsets, _ = tile_offsets(canopy, [(lo[0], lo[1], hi[0], hi[1])])
    except ConfigError as exc:
        raise ConfigError(f"views to {theta_max_deg:g}° from the lenses need too many copies of the "
                          f"periodic plot: {exc.reason.split(';')[0]}; lower the lenses' distance below "
                          "the leaves or the outermost ring", key=key, value=theta_max_deg) from None
    return build_canopy_scene(canopy, offsets, variant=variant)


# -------------------------------------------------------------------------- image
@dataclass
class GapImage:
    """One rendered gap-fraction image and the settings that produced it.

    Attributes
    ----------
    coverage : (height, width) float32
        Share of each pixel's samples that met vegetation (0 = gap).
    window : Window
    camera : Camera
    p0 : float
        Gap fraction of the window: 1 − mean coverage over its pixels.
    spp : int
        Samples per pixel.
    seconds : float
        Wall time of the render (rays cast and reduced; no scene building).
    step : int
        Extraction step of the canopy.
    leaf_area_m2, lai : float
        Of the (untiled) canopy.
    jitter : bool
        Whether samples were jittered inside their strata.
    seed : int
        Seed of the jitter (irrelevant without jitter).
    replicate : int
        Which replicate plot of the scene (0 = the scene seed's own plot).
    """

    coverage: np.ndarray
    window: Window
    camera: Camera
    p0: float
    spp: int
    seconds: float
    step: int = 0
    leaf_area_m2: float = 0.0
    lai: float = 0.0
    jitter: bool = False
    seed: int = 0
    replicate: int = 0

    @property
    def zenith_deg(self) -> float:
        return self.camera.zenith_deg

    @property
    def width(self) -> int:
        return int(self.coverage.shape[1])

    @property
    def height(self) -> int:
        return int(self.coverage.shape[0])

    def window_coverage(self) -> np.ndarray:
        x0, y0, x1, y1 = self.window.box_px
        return self.coverage[y0:y1, x0:x1]

    def mask(self, threshold: float = 0.5) -> np.ndarray:
        """Boolean vegetation mask for display (coverage ≥ threshold); not used for P0."""
        return self.coverage >= threshold

    def stem(self) -> str:
        """File-name stem: ``gap_<camera>_z<zenith>_s<step>``."""
        return f"gap_{self.camera.kind}_z{self.camera.zenith_deg:g}_s{self.step}"

    def row(self) -> dict[str, Any]:
        """This image's values (unformatted; gap_fraction.csv averages them over replicates)."""
        return {"camera": self.camera.kind, "zenith_deg": self.camera.zenith_deg,
                "step": self.step, "p0": self.p0, "leaf_area_m2": self.leaf_area_m2,
                "lai": self.lai, "spp": self.spp, "width": self.width, "height": self.height,
                "seconds": self.seconds}

    def metadata(self) -> dict[str, Any]:
        """Everything but the pixels, JSON-friendly."""
        return {**self.row(), "azimuth_deg": self.camera.azimuth_deg, "jitter": self.jitter,
                "seed": self.seed, "replicate": self.replicate, "camera_settings": self.camera.to_dict(),
                "window": self.window.to_dict()}


def render_gap(built, canopy: Canopy, camera: Camera, window: Window, *, spp: int = DEFAULTS["spp"],
               jitter: bool = False, seed: int = 0, variant: str | None = None,
               integrator=None) -> GapImage:
    """Render ``camera``'s coverage image of ``built`` (from :func:`build_canopy_scene`)."""
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415
    if not (isinstance(spp, numbers.Integral) and not isinstance(spp, bool) and spp >= 1):
        raise ConfigError("samples per pixel must be an integer ≥ 1", key="gapfraction.spp", value=spp)
    mi = mitsuba(variant)
    sensor = mi.load_dict(camera.sensor_dict(mi, built.origin_m, spp))
    if integrator is None:
        integrator = mi.load_dict({"type": "coverage", "jitter": bool(jitter)})
    t0 = time.perf_counter()
    cov = integrator.coverage(built.scene, sensor, seed=int(seed), spp=int(spp))
    seconds = time.perf_counter() - t0
    x0, y0, x1, y1 = window.box_px
    p0 = 1.0 - float(np.mean(cov[y0:y1, x0:x1], dtype=np.float64))
    return GapImage(cov, window, camera, p0, int(spp), seconds, canopy.step,
                    float(canopy.leaf_area_m2), canopy.lai, bool(jitter), int(seed))


def gap_views(reference: Canopy, *, cameras: Sequence[str] = DEFAULTS["cameras"],
              zeniths_deg: Sequence[float] = DEFAULTS["zeniths_deg"],
              azimuth_deg: float = DEFAULTS["azimuth_deg"],
              resolution: int = DEFAULTS["resolution"], window: str = DEFAULTS["window"],
              window_fraction: float = DEFAULTS["window_fraction"],
              margin_m: float | None = DEFAULTS["margin_m"], fov_deg: float = DEFAULTS["fov_deg"],
              camera_height_m: float = DEFAULTS["camera_height_m"]):
    """Every (camera, zenith) view of ``reference``: ``(views, offsets)``.

    ``views`` is a list of (Camera, Window); ``offsets`` the periodic tiling (None in
    inset mode).  Computed once and shared by all extraction steps of a plot.
    """
    mode = window if window != "auto" else ("periodic" if reference.periodic else "inset")
    views = []
    for kind in cameras:
        for zen in zeniths_deg:
            cam = make_camera(kind, reference, zen, azimuth_deg=azimuth_deg, resolution=resolution,
                              fov_deg=fov_deg, camera_height_m=camera_height_m,
                              periodic=mode == "periodic")
            views.append((cam, analysis_window(cam, reference, mode, fraction=window_fraction,
                                               margin_m=margin_m)))
    offsets = None
    if mode == "periodic":
        offsets, tiles = tile_offsets(reference, [w.safe_region_m for _, w in views])
        views = [(c, replace(w, tiles=tiles)) for c, w in views]
    return views, offsets


def gap_images(canopy: Canopy, *, cameras: Sequence[str] = DEFAULTS["cameras"],
               zeniths_deg: Sequence[float] = DEFAULTS["zeniths_deg"],
               azimuth_deg: float = DEFAULTS["azimuth_deg"],
               resolution: int = DEFAULTS["resolution"], spp: int = DEFAULTS["spp"],
               window: str = DEFAULTS["window"], window_fraction: float = DEFAULTS["window_fraction"],
               margin_m: float | None = DEFAULTS["margin_m"], fov_deg: float = DEFAULTS["fov_deg"],
               camera_height_m: float = DEFAULTS["camera_height_m"], jitter: bool = False,
               seed: int = 0, variant: str | None = None,
               reference: Canopy | None = None, views=None) -> list[GapImage]:
    """Every (camera, zenith) image of one canopy; the Mitsuba scene is built once.

    Cameras and windows are placed from ``reference`` (default ``canopy``): pass the
    full canopy when rendering its extraction steps, so that every step is seen
    through the same cameras and windows, as the paper photographed the same area.
    In periodic mode the plot is tiled once for the union of all views' ray extents.
    ``views`` (from :func:`gap_views`) skips placing them again.
    """
    if views is None:
        views = gap_views(canopy if reference is None else reference, cameras=cameras,
                          zeniths_deg=zeniths_deg, azimuth_deg=azimuth_deg,
                          resolution=resolution, window=window, window_fraction=window_fraction,
                          margin_m=margin_m, fov_deg=fov_deg, camera_height_m=camera_height_m)
    views, offsets = views
    built = build_canopy_scene(canopy, offsets, variant=variant)
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415
    mi = mitsuba(variant)
    integrator = mi.load_dict({"type": "coverage", "jitter": bool(jitter)})
    return [render_gap(built, canopy, cam, win, spp=spp, jitter=jitter, seed=seed,
                       variant=variant, integrator=integrator) for cam, win in views]


# ----------------------------------------------------------------------------- files
def write_gap_exr(image: GapImage, path: str | Path, *, extra: dict | None = None) -> Path:
    """Write the coverage of ``image`` (float32 channel ``coverage``) with its settings.

    Header: ``simlidar_gap`` (JSON of :meth:`GapImage.metadata`) plus flat attributes
    ``camera``, ``zenith_deg``, ``azimuth_deg``, ``p0``, ``spp``, ``window_px`` …
    """
    import OpenEXR  # noqa: PLC0415
    meta = image.metadata()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "simlidar_gap": json.dumps(meta, sort_keys=True)}
    cam = image.camera
    flat = {"camera": cam.kind, "zenith_deg": cam.zenith_deg, "azimuth_deg": cam.azimuth_deg,
            "p0": image.p0, "spp": image.spp, "step": image.step, "lai": image.lai,
            "leaf_area_m2": image.leaf_area_m2, "window_mode": image.window.mode,
            "window_px": list(image.window.box_px), "window_safe_region_m": list(image.window.safe_region_m),
            "camera_position_m": cam.position_m, "camera_direction": cam.direction,
            "fov_deg": cam.fov_deg, "camera_height_m": cam.camera_height_m,
            "ortho_half_extent_m": list(cam.half_extent_m)}
    for key, value in {**flat, **(extra or {})}.items():
        header[key] = header_value(value)
    channels = {"coverage": np.ascontiguousarray(image.coverage, np.float32)}
    with atomic_file(path) as tmp:
        # OpenEXR.File modifies the dicts it is given: pass copies.
        with OpenEXR.File(dict(header), dict(channels)) as f:
            f.write(str(tmp))
    return Path(path)


def read_gap_exr(path: str | Path) -> tuple[np.ndarray, dict]:
    """Coverage array and header of a gap EXR; ``header['metadata']`` is the parsed JSON."""
    channels, header = read_exr(path)
    if "coverage" not in channels:
        raise SimlidarError(f"{path}: not a gap-fraction EXR (no 'coverage' channel)")
    if "simlidar_gap" in header:
        header["metadata"] = json.loads(header["simlidar_gap"])
    return channels["coverage"], header


@dataclass
class GapSummary:
    """One line of gap_fraction.csv: a view and step averaged over the replicate plots.

    ``p0`` is the mean of ``p0_values`` (one per replicate), ``p0_sd_plot`` their sample SD
    (ddof 1; nan for one replicate): how much one plot's P0 scatters between seeds.
    ``p0_sd = p0_sd_plot/√n`` is the seed-to-seed SD of ``p0`` itself.
    """

    camera: str
    zenith_deg: float
    step: int
    p0_values: tuple[float, ...]
    leaf_area_m2: float
    lai: float
    spp: int
    width: int
    height: int
    seconds: float

    @property
    def replicates(self) -> int:
        return len(self.p0_values)

    @property
    def p0(self) -> float:
        return float(np.mean(self.p0_values))

    @property
    def p0_sd_plot(self) -> float:
        return replicate_sd(self.p0_values)

    @property
    def p0_sd(self) -> float:
        return self.p0_sd_plot / math.sqrt(self.replicates)

    def row(self) -> dict[str, Any]:
        """One line of gap_fraction.csv (formatted)."""
        return {"camera": self.camera, "zenith_deg": f"{self.zenith_deg:g}", "step": self.step,
                "p0": f"{self.p0:.6f}", "p0_sd_plot": f"{self.p0_sd_plot:.6f}", "p0_sd": f"{self.p0_sd:.6f}",
                "replicates": self.replicates, "leaf_area_m2": f"{self.leaf_area_m2:.6g}",
                "lai": f"{self.lai:.6g}", "spp": self.spp, "width": self.width,
                "height": self.height, "seconds": f"{self.seconds:.4f}"}


def replicate_sd(values: Sequence[float]) -> float:
    """Sample SD (ddof 1) of replicate values; nan for fewer than two."""
    v = np.asarray(values, np.float64)
    return float(np.std(v, ddof=1)) if v.size >= 2 else math.nan


def summarise(replicate_images: Sequence[Sequence[GapImage]]) -> list[GapSummary]:
    """Average each (camera, zenith, step) over replicates (image lists in the same order)."""
    out = []
    for i, im in enumerate(replicate_images[0]):
        ims = [rep[i] for rep in replicate_images]
        assert all((x.camera.kind, x.camera.zenith_deg, x.step) ==
                   (im.camera.kind, im.camera.zenith_deg, im.step) for x in ims)
        out.append(GapSummary(im.camera.kind, float(im.camera.zenith_deg), im.step,
                              tuple(float(x.p0) for x in ims),
                              float(np.mean([x.leaf_area_m2 for x in ims])),
                              float(np.mean([x.lai for x in ims])), im.spp, im.width, im.height,
                              float(sum(x.seconds for x in ims))))
    return out


@dataclass
class GapFractionRun:
    """What :func:`run_gapfraction` produced.

    ``images`` and ``canopies`` are those of replicate 0 (the scene seed's own plot,
    whose PNG/EXR files are written); ``replicate_images[k]`` the images of replicate
    ``k`` in the same order; ``summary`` the per-view means and SDs over replicates.
    """

    images: list[GapImage]
    canopies: list[Canopy]
    files: dict[str, Path] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    replicate_images: list[list[GapImage]] = field(default_factory=list)
    summary: list[GapSummary] = field(default_factory=list)


def _settings(cfg: SceneConfig) -> dict[str, Any]:
    g = dict(DEFAULTS)
    if "gapfraction" in cfg.sections:
        g.update({k: v for k, v in cfg["gapfraction"].items()})
    for kind in g["cameras"]:
        if kind not in CAMERAS:
            raise ConfigError(f"unknown camera; valid: {', '.join(CAMERAS)}", file=cfg.source,
                              key="gapfraction.cameras", value=kind)
    return g


def _render_replicate(cfg: SceneConfig, g: dict[str, Any], replicate: int,
                      seconds: dict[str, float]):
    t0 = time.perf_counter()
    canopies = canopies_from_config(cfg, replicate)
    seconds["generate"] = seconds.get("generate", 0.0) + time.perf_counter() - t0
    t0 = time.perf_counter()
    kw = dict(cameras=g["cameras"], zeniths_deg=g["zeniths_deg"], azimuth_deg=g["azimuth_deg"],
              resolution=g["resolution"], window=g["window"], window_fraction=g["window_fraction"],
              margin_m=g["margin_m"], fov_deg=g["fov_deg"], camera_height_m=g["camera_height_m"])
    images: list[GapImage] = []
    try:
        views = gap_views(canopies[0], **kw)
        for canopy in canopies:
            images += gap_images(canopy, spp=g["spp"], jitter=g["jitter"], seed=cfg.seed,
                                 variant=cfg["scene"]["variant"], views=views, **kw)
    except ConfigError as exc:
        if exc.file is None:
            err = ConfigError(str(exc), file=cfg.source)  # the message already names key, value
            err.key, err.value = exc.key, exc.value
            raise err from exc
        raise
    for im in images:
        im.replicate = replicate
    seconds["render"] = seconds.get("render", 0.0) + time.perf_counter() - t0
    return canopies, images


@writes_output("out_dir")
def run_gapfraction(scene: SceneConfig | str | Path, out_dir: str | Path | None = None,
                    overrides: Sequence[str] = (), *, write_images: bool = True,
                    replicates: int | None = None, progress=False) -> GapFractionRun:
    """Scene file → canopies (one per extraction step) of each replicate plot → images → files.

    ``[gapfraction] replicates`` (or ``replicates=``) independent plots of the scene
    (:func:`~simlidar_mi.canopy.canopy.replicate_seed`) are rendered through their own
    cameras and windows; every P0 reported is the mean over them, with their SD.

    Writes into ``out_dir`` (all files appear together when complete; a failure
    leaves ``out_dir`` as it was):

    - ``gap_fraction.csv``: ``camera, zenith_deg, step, p0, p0_sd, p0_sd_plot, replicates,
      leaf_area_m2, lai, spp, width, height, seconds``, one line per view and step;
      ``p0`` is the mean over replicates, ``p0_sd_plot`` the SD between them,
      ``p0_sd = p0_sd_plot/√replicates``; leaf area, LAI are means, seconds a sum;
    - ``gap_fraction_replicates.csv``: ``replicate, camera, zenith_deg, step, p0,
      leaf_area_m2, lai, seconds``, one line per rendered image;
    - ``gap_fraction.json``: the settings and every image's settings and window;
    - ``gap_<camera>_z<zenith>_s<step>.png``: vegetation mask of replicate 0
      (coverage ≥ ``mask_threshold``, display only) with the window outlined;
    - ``gap_<camera>_z<zenith>_s<step>.exr``: replicate 0's float32 coverage with the
      settings in the header.

    ``progress``: see :func:`simlidar_mi._runtime.progress.make_progress` (a count of replicate
    plots rendered, then the files written).
    """
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, list(overrides))
    check_variant(cfg["scene"]["variant"], cfg.source)  # before any work
    g = _settings(cfg)
    if replicates is not None:
        if isinstance(replicates, bool) or not isinstance(replicates, int) or replicates < 1:
            raise ConfigError("replicates must be an integer ≥ 1", key="gapfraction.replicates",
                              value=replicates)
        g["replicates"] = replicates
    seconds: dict[str, float] = {}
    prog = make_progress(progress)
    reps = [_render_replicate(cfg, g, k, seconds) for k in
            prog.iter(range(g["replicates"]), "gapfraction: rendering", unit="plot")]
    canopies, images = reps[0]
    run = GapFractionRun(images, canopies, {}, seconds, [r[1] for r in reps],
                         summarise([r[1] for r in reps]))
    if out_dir is None:
        return run
    from ..io.png import write_mask_png  # noqa: PLC0415
    out = Path(out_dir)
    t0 = time.perf_counter()
    n_files = 3 + (2 * len(images) if write_images else 0)
    with staged_dir(out, GAPFRACTION_OUTPUTS) as stage, prog.stage("gapfraction: writing", n_files, "file") as st:
        write_csv(stage / "gap_fraction.csv", CSV_COLUMNS, (s.row() for s in run.summary))
        run.files["csv"] = out / "gap_fraction.csv"
        write_csv(stage / "gap_fraction_replicates.csv", REPLICATE_COLUMNS, (
            {"replicate": im.replicate, "camera": im.camera.kind,
             "zenith_deg": f"{im.camera.zenith_deg:g}", "step": im.step, "p0": f"{im.p0:.6f}",
             "leaf_area_m2": f"{im.leaf_area_m2:.6g}", "lai": f"{im.lai:.6g}",
             "seconds": f"{im.seconds:.4f}"} for rep in run.replicate_images for im in rep))
        run.files["replicates_csv"] = out / "gap_fraction_replicates.csv"
        extra = {"scene_file": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed}
        meta = {"scene": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed,
                "settings": g, "images": [],
                "summary": [{**s.row(), "p0_values": list(s.p0_values)} for s in run.summary]}
        for img in images:
            stem = img.stem()
            if write_images:
                write_mask_png(stage / f"{stem}.png", img.mask(g["mask_threshold"]), img.window.box_px)
                write_gap_exr(img, stage / f"{stem}.exr", extra=extra)
                run.files[f"{stem}.png"] = out / f"{stem}.png"
                run.files[f"{stem}.exr"] = out / f"{stem}.exr"
                st.update(2)
            meta["images"].append({"stem": stem, **img.metadata()})
        with atomic_file(stage / "gap_fraction.json") as tmp:
            tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        run.files["json"] = out / "gap_fraction.json"
        st.update(n_files - st.n)
    seconds["write"] = time.perf_counter() - t0
    return run
