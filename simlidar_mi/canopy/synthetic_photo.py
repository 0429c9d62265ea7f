"""Synthetic photographs: close the loop between the photo classifier and the renderer.

A gap-fraction camera (:mod:`simlidar_mi.canopy.gapfraction`) reports, per pixel, the share
of the pixel whose primary ray meets vegetation.  A real camera instead records
colour, and :mod:`simlidar_mi.canopy.photo` turns the colour back into vegetation vs soil
with the Canopeo rule.  This module renders the *same view* as a photo-like RGB image
(green leaves over brown soil, lit by a sun and a uniform sky) and checks that
Canopeo on the render gives the coverage render's P0: the photo path and the renderer
test each other.

::

    from simlidar_mi.canopy.synthetic_photo import check_photo
    chk = check_photo(canopy, "orthographic", 0.0, resolution=512)
    chk.p0_canopeo, chk.p0_coverage          # agree within 0.01

The render
----------
* Leaves: two-sided Lambertian, linear RGB reflectance ``leaf_rgb``
  (default (0.08, 0.25, 0.06), a dark green leaf).
* Soil: a horizontal Lambertian plane 1 mm below the lowest leaf (or z = 0),
  reflectance ``soil_rgb`` (default (0.35, 0.22, 0.15), a reddish-brown soil).
* Light: a sun of irradiance ``sun_irradiance`` (per channel, on a plane facing it)
  plus a ``constant`` sky of radiance ``sky_radiance`` (0.35: the sky gives about half
  of the light on a horizontal plane, a hazy day).  By default the sun stands *at the
  observer*: the strawberry paper reads its photos' view angles as "equal to the angles
  of illumination, if one considers the sun in the position of the observer", and it
  keeps shadows, which Canopeo calls soil or turns edge pixels green, out of the view.
  For an orthographic camera that is a ``directional`` beam along the view; for a
  perspective camera a ``point`` source at the pinhole, of intensity
  ``sun_irradiance · r²`` (r = pinhole to the view's target), because a parallel beam
  would cast shadows that the off-axis pixels see (measured: Canopeo's P0 then read
  0.012 low at nadir and 0.015 low at 30° on the strawberry plot, 512²).  Give ``sun_zenith_deg`` /
  ``sun_azimuth_deg`` (the beam travels like a camera ray of that zenith and azimuth)
  for a directional sun anywhere else, shadows and all.
* Integrator: ``path`` with ``max_depth`` 3 (direct light plus one interreflection),
  ``spp`` samples per pixel with a box filter, so edge pixels mix leaf and soil as a
  real sensor's pixels do.
* Tone mapping: linear radiance × ``exposure``, clipped to [0, 1], sRGB transfer
  function (IEC 61966-2-1), rounded to 8 bits.  No white balance, no gamma tricks.

Why these numbers
-----------------
Pure leaf and pure soil pixels are classified without error (on the strawberry plot at
nadir leaves sit around sRGB (59, 103, 50), soil around (108, 87, 72); Canopeo needs
R/G < 0.95, B/G < 0.95 and 2G − R − B > 20, and with ``exposure`` 1 the darkest 1 % of
leaf pixels still have 2G − R − B ≥ 70).  What
decides the agreement is the *mixed* pixels on leaf edges (3–13 % of a 512² window):
Canopeo makes each all-or-nothing, so P0 is off by about (edge share) × (0.5 − f*),
where f* is the leaf fraction at which a mix turns green.  With the R/G test deciding,
f* ≈ 0.16 / (0.14·k + 0.16) for these reflectances, k being the leaf's brightness
relative to the soil's: a yellow-brown soil (0.25, 0.2, 0.15) gave f* ≈ 0.3 and a P0
0.009 low on the strawberry plot at nadir, the redder (0.35, 0.22, 0.15) f* ≈ 0.5.
Brightly lit, nearly horizontal strawberry leaves (k > 1) still read a little low, the
tilted leaves of a spherical ``random_leaves`` canopy (k < 1) a little high; more sky
light helps the latter and hurts the former, and ``sky_radiance`` = 0.35 balances the
two.  Measured Canopeo − coverage P0 (16-spp photo vs 4-spp coverage, seed 0):

=========================================  =================  =================
view (zenith 0° and 30°)                   512² image         1024² image
=========================================  =================  =================
strawberry plot, orthographic              −0.003 … −0.004    −0.001 … −0.002
strawberry plot, perspective (60°, 1 m)    −0.006 … −0.008    −0.003
random_leaves_spherical, orthographic      +0.008, +0.006     +0.004, +0.003
random_leaves_spherical, perspective       +0.003, +0.002     +0.002, +0.001
=========================================  =================  =================

(strawberry: ``scenes/strawberry_plot.toml``, full canopy and after removing
44 + 39 + 44 = 127 leaves.)

The error halves with the pixel size, as an edge effect should.

Mitsuba variants
----------------
The project renders coverage with ``llvm_ad_mono``; a colour render needs an RGB
variant (``llvm_ad_rgb``).  A Mitsuba process works with one variant at a time, so
unless the calling process already runs the RGB variant, :func:`render_photos` renders
in a child Python process (one per call, whatever the number of views; about 1–2 s of
start-up).  The parent never switches variant.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._runtime.progress import make_progress
from ..errors import ConfigError, SimlidarError
from ..io.atomic import writes_output
from .cameras import CAMERAS

__all__ = [
    "PhotoSettings", "PhotoJob", "SyntheticPhotoCheck", "DEFAULTS", "CSV_COLUMNS",
    "srgb_encode", "render_photo", "render_photos", "save_photo_png", "canopeo_p0",
    "check_photo", "check_images", "run_synthetic_photos",
]

#: Defaults of the ``[photo_render]`` scene section (see the module docstring for why).
DEFAULTS: dict[str, Any] = {
    "leaf_rgb": [0.08, 0.25, 0.06],
    "soil_rgb": [0.35, 0.22, 0.15],
    "sun_irradiance": 1.0,
    "sky_radiance": 0.35,
    "sun_zenith_deg": None,
    "sun_azimuth_deg": None,
    "exposure": 1.0,
    "spp": 16,
    "max_depth": 3,
    "variant": "llvm_ad_rgb",
}
CSV_COLUMNS = ("camera", "zenith_deg", "step", "p0_coverage", "p0_canopeo", "difference",
               "coverage_spp", "photo_spp", "width", "height", "seconds_photo")
# The files a synthetic-photo run owns in its folder (whole-name regular expressions);
# the camera names keep compare's photo_mask_row*.png out of the set.
SYNTHETIC_PHOTO_OUTPUTS = (r"synthetic_photo\.(csv|json)",
                           rf"photo_({'|'.join(CAMERAS)})_z[^_]+_s[^_.]+(_canopeo)?\.png")
_SOIL_HALF_SIZE_M = 100.0  # soil plane half size: fills any view of a plot-sized scene
_SOIL_BELOW_M = 1e-3  # soil this far below the lowest leaf, so no leaf is buried
_WORKER_FLAG = "--photo-worker"
_DONE_MARK = "simlidar-photo-done"  # the worker's stdout line after each photo (progress)


# ----------------------------------------------------------------------- settings
def _rgb_triple(key: str, value: Any) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in vals):
        raise ConfigError("must be three reflectances in [0, 1] (linear R, G, B)",
                          key=f"photo_render.{key}", value=value)
    return vals  # type: ignore[return-value]


@dataclass(frozen=True)
class PhotoSettings:
    """How a synthetic photo is lit, rendered and tone-mapped.

    Parameters
    ----------
    leaf_rgb, soil_rgb : (r, g, b)
        Linear Lambertian reflectances in [0, 1].
    sun_irradiance : float
        Sun irradiance on a plane facing it, per RGB channel (relative units; only the
        product with ``exposure`` matters).
    sky_radiance : float
        Radiance of the uniform sky, per channel (same units).
    sun_zenith_deg, sun_azimuth_deg : float or None
        Direction the sun's beam travels, in the views' convention (zenith from the
        downward vertical, azimuth relative to the rows).  None: the view's own, i.e.
        the sun stands behind the camera.
    exposure : float
        Linear radiance is multiplied by this before the sRGB transfer function.
    spp : int
        Samples per pixel of the photo (box filter).
    max_depth : int
        Path length of Mitsuba's ``path`` integrator (2 = direct light only).
    variant : str
        Mitsuba RGB variant.
    """

    leaf_rgb: tuple[float, float, float] = tuple(DEFAULTS["leaf_rgb"])  # type: ignore[assignment]
    soil_rgb: tuple[float, float, float] = tuple(DEFAULTS["soil_rgb"])  # type: ignore[assignment]
    sun_irradiance: float = DEFAULTS["sun_irradiance"]
    sky_radiance: float = DEFAULTS["sky_radiance"]
    sun_zenith_deg: float | None = None
    sun_azimuth_deg: float | None = None
    exposure: float = DEFAULTS["exposure"]
    spp: int = DEFAULTS["spp"]
    max_depth: int = DEFAULTS["max_depth"]
    variant: str = DEFAULTS["variant"]

    def __post_init__(self) -> None:
        object.__setattr__(self, "leaf_rgb", _rgb_triple("leaf_rgb", self.leaf_rgb))
        object.__setattr__(self, "soil_rgb", _rgb_triple("soil_rgb", self.soil_rgb))
        for key in ("sun_irradiance", "sky_radiance"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError("must be a finite number ≥ 0", key=f"photo_render.{key}", value=v)
        if not (isinstance(self.exposure, (int, float)) and math.isfinite(self.exposure)
                and self.exposure > 0):
            raise ConfigError("must be a finite number > 0", key="photo_render.exposure",
                              value=self.exposure)
        if self.sun_zenith_deg is not None and not (0.0 <= float(self.sun_zenith_deg) < 90.0):
            raise ConfigError("sun zenith must lie in [0, 90) degrees",
                              key="photo_render.sun_zenith_deg", value=self.sun_zenith_deg)
        if self.sun_azimuth_deg is not None and not math.isfinite(float(self.sun_azimuth_deg)):
            raise ConfigError("must be a finite number of degrees",
                              key="photo_render.sun_azimuth_deg", value=self.sun_azimuth_deg)
        for key, low in (("spp", 1), ("max_depth", 1)):
            v = getattr(self, key)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= low):
                raise ConfigError(f"must be an integer ≥ {low}", key=f"photo_render.{key}", value=v)
        if "rgb" not in self.variant.split("_"):
            raise ConfigError("a colour photo needs an RGB Mitsuba variant such as 'llvm_ad_rgb'",
                              key="photo_render.variant", value=self.variant)

    @classmethod
    def from_config(cls, cfg) -> "PhotoSettings":
        """Settings from a scene's ``[photo_render]`` section (defaults where absent)."""
        sec = dict(DEFAULTS)
        if "photo_render" in cfg.sections:
            sec.update({k: v for k, v in cfg["photo_render"].items() if k in DEFAULTS})
        try:
            return cls(**sec)
        except ConfigError as exc:
            raise ConfigError(str(exc), file=cfg.source) from exc

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["leaf_rgb"], d["soil_rgb"] = list(self.leaf_rgb), list(self.soil_rgb)
        return d

    def sun_direction(self, camera) -> np.ndarray:
        """Unit vector the sun's beam travels along, for ``camera``'s view."""
        if self.sun_zenith_deg is None and self.sun_azimuth_deg is None:
            return np.asarray(camera.direction, float)  # sun behind the camera
        th = math.radians(camera.zenith_deg if self.sun_zenith_deg is None else self.sun_zenith_deg)
        ph = math.radians(camera.azimuth_deg if self.sun_azimuth_deg is None
                          else self.sun_azimuth_deg)
        return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), -math.cos(th)])


# ----------------------------------------------------------------------- tone map
def srgb_encode(linear_rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance → 8-bit sRGB: scale, clip to [0, 1], sRGB transfer, round.

    Parameters
    ----------
    linear_rgb : float array, shape (..., 3)
    exposure : factor applied to the linear values first.

    Returns
    -------
    numpy.ndarray of uint8, same shape
    """
    lin = np.clip(np.nan_to_num(np.asarray(linear_rgb, np.float64) * exposure, nan=0.0), 0.0, 1.0)
    # IEC 61966-2-1: linear segment near black, 1/2.4 power above
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.power(lin, 1.0 / 2.4) - 0.055)
    return np.clip(np.rint(enc * 255.0), 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------- jobs
@dataclass(frozen=True)
class PhotoJob:
    """One view to photograph: leaf triangles relative to ``origin_m`` and a camera."""

    vertices_m: np.ndarray  # (n, 3, 3), relative to origin_m
    origin_m: np.ndarray
    camera: Any  # simlidar_mi.canopy.cameras.Camera
    soil_z_m: float  # relative to origin_m


def _camera_from_dict(d: dict[str, Any]):
    from .cameras import Camera  # noqa: PLC0415
    vec = {"position_m", "target_m", "direction", "right", "up"}
    kw = {}
    for f in fields(Camera):
        v = d[f.name]
        kw[f.name] = np.asarray(v, float) if f.name in vec else (
            tuple(v) if isinstance(v, list) else v)
    return Camera(**kw)


def _make_job(canopy, camera, window=None) -> PhotoJob:
    """Leaves of ``canopy`` as the coverage render sees them (tiled when periodic)."""
    from .windows import analysis_window, tile_offsets  # noqa: PLC0415
    if canopy.branches is not None and len(canopy.branches):
        raise ConfigError("synthetic photos of canopies with wood are not supported yet "
                          "(only leaves are given a reflectance)", key="canopy.branches",
                          value=len(canopy.branches))
    verts = canopy.leaves.vertices
    if canopy.periodic:
        # the coverage render tiles the plot as far as the view's rays reach: do the same
        if window is None or window.mode != "periodic":
            window = analysis_window(camera, canopy, "periodic")
        offsets, _ = tile_offsets(canopy, [window.safe_region_m])
        shift = np.zeros((len(offsets), 1, 1, 3))
        shift[:, 0, 0, :2] = offsets
        verts = (verts[None] + shift).reshape(-1, 3, 3)
    origin = np.round(np.r_[canopy.plot_centre_m, 0.0])  # as gapfraction.build_canopy_scene
    z_lo = canopy.z_range_m()[0] if len(canopy.leaves) else 0.0
    return PhotoJob(verts - origin, origin, camera, min(z_lo, 0.0) - origin[2] - _SOIL_BELOW_M)


# ---------------------------------------------------------------------- rendering
def _sun_dict(settings: PhotoSettings, camera, origin_m: np.ndarray) -> dict[str, Any]:
    """The sun emitter: a directional beam, or a point at a perspective camera's pinhole.

    With the default sun (behind the camera) a perspective view gets a point source at
    its pinhole, of intensity ``sun_irradiance · r²`` (r = pinhole to the view's
    target), so that the irradiance at the target is ``sun_irradiance``: a parallel beam
    would light the scene along the optical axis only, and the off-axis pixels would see
    the shadows it casts (measured: Canopeo's P0 then reads 0.010–0.019 low on the
    strawberry plot, shaded soil beside a leaf edge turning mixed pixels green).
    """
    rgb = {"type": "rgb", "value": [float(settings.sun_irradiance)] * 3}
    if camera.kind == "perspective" and settings.sun_zenith_deg is None \
            and settings.sun_azimuth_deg is None:
        r2 = float(np.sum((np.asarray(camera.target_m) - np.asarray(camera.position_m)) ** 2))
        pos = (np.asarray(camera.position_m, float) - origin_m).tolist()
        return {"type": "point", "position": pos,
                "intensity": {"type": "rgb", "value": [float(settings.sun_irradiance) * r2] * 3}}
    return {"type": "directional", "direction": [float(x) for x in settings.sun_direction(camera)],
            "irradiance": rgb}


def _render_jobs_here(jobs: Sequence[PhotoJob], settings: PhotoSettings, seed: int,
                      done=lambda: None) -> list[np.ndarray]:
    """Render in this process (which must already run, or not yet have, an RGB variant);
    ``done()`` is called after each photo."""
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415
    mi = mitsuba(settings.variant)
    out = []
    for job in jobs:
        shapes: dict[str, Any] = {}
        if len(job.vertices_m):
            v = np.ascontiguousarray(job.vertices_m.reshape(-1, 3), np.float32)
            mesh = mi.Mesh("leaves", len(v), len(v) // 3)
            params = mi.traverse(mesh)
            params["vertex_positions"] = mi.Float(v.ravel())
            params["faces"] = mi.UInt32(np.arange(len(v), dtype=np.uint32))
            params.update()
            mesh.set_bsdf(mi.load_dict({"type": "twosided", "bsdf": {
                "type": "diffuse", "reflectance": {"type": "rgb", "value": list(settings.leaf_rgb)}}}))
            shapes["leaves"] = mesh
        # the soil plane is centred under the camera's target so it fills the view
        tx, ty = (np.asarray(job.camera.target_m, float) - job.origin_m)[:2]
        shapes["soil"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f.translate([float(tx), float(ty), float(job.soil_z_m)])
            @ mi.ScalarTransform4f.scale([_SOIL_HALF_SIZE_M, _SOIL_HALF_SIZE_M, 1.0]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(settings.soil_rgb)}},
        }
        sensor = job.camera.sensor_dict(mi, job.origin_m, settings.spp)
        sensor["film"]["pixel_format"] = "rgb"
        scene = mi.load_dict({
            "type": "scene", **shapes, "sensor": sensor,
            "sun": _sun_dict(settings, job.camera, job.origin_m),
            "sky": {"type": "constant",
                    "radiance": {"type": "rgb", "value": [settings.sky_radiance] * 3}},
            "integrator": {"type": "path", "max_depth": int(settings.max_depth)},
        })
        img = np.array(mi.render(scene, spp=int(settings.spp), seed=int(seed)), dtype=np.float32)
        out.append(srgb_encode(img[..., :3], settings.exposure))
        done()
    return out


def _worker_main(in_path: str, out_path: str) -> int:
    """Child-process entry: read jobs, render, write the uint8 images."""
    with np.load(in_path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        settings = PhotoSettings(**meta["settings"])
        jobs = [PhotoJob(data[f"v{i}"], data[f"o{i}"], _camera_from_dict(j["camera"]), j["soil_z_m"])
                for i, j in enumerate(meta["jobs"])]
    images = _render_jobs_here(jobs, settings, int(meta["seed"]),
                               lambda: print(_DONE_MARK, flush=True))
    np.savez(out_path, **{f"img{i}": im for i, im in enumerate(images)})
    return 0


def _process_variant() -> str | None:
    from .._runtime import mitsuba as _mitsuba  # noqa: PLC0415  (does not import Mitsuba itself)
    return _mitsuba._state.get("variant")


def render_photos(jobs: Sequence[PhotoJob], settings: PhotoSettings | None = None, *,
                  seed: int = 0, isolate: bool | None = None, progress=False) -> list[np.ndarray]:
    """Render several views as 8-bit sRGB photos, in one child process if needed.

    Parameters
    ----------
    jobs : views built with :func:`render_photo`'s rules (see ``_make_job``).
    settings : lighting, reflectances, tone mapping; default :class:`PhotoSettings`.
    seed : Mitsuba sampler seed (same seed, same bytes).
    isolate : render in a child process (True), here (False), or here only when this
        process already runs ``settings.variant`` (None, the default).
    progress : see :func:`simlidar_mi._runtime.progress.make_progress` (photos rendered).

    Returns
    -------
    list of numpy.ndarray of uint8, each (height, width, 3)
    """
    settings = settings or PhotoSettings()
    if isolate is None:
        isolate = _process_variant() != settings.variant
    with make_progress(progress).stage("synthetic-photo: rendering", len(jobs), "photo") as st:
        if not isolate:
            return _render_jobs_here(jobs, settings, seed, st.update)
        return _render_in_child(jobs, settings, seed, st.update)


def _package_parent() -> Path:
    """The folder that holds the ``simlidar_mi`` package (never the package itself: its
    ``io`` sub-package would shadow the standard library's ``io`` in the child)."""
    return Path(__file__).resolve().parents[2]


def _render_in_child(jobs: Sequence[PhotoJob], settings: PhotoSettings, seed: int,
                     done) -> list[np.ndarray]:
    """Render in a child process running ``settings.variant``; ``done()`` after each photo."""
    meta = {"settings": settings.to_dict(), "seed": int(seed),
            "jobs": [{"camera": j.camera.to_dict(), "soil_z_m": float(j.soil_z_m)} for j in jobs]}
    arrays = {"meta": np.array(json.dumps(meta))}
    for i, j in enumerate(jobs):
        arrays[f"v{i}"] = np.asarray(j.vertices_m, np.float64)
        arrays[f"o{i}"] = np.asarray(j.origin_m, np.float64)
    with tempfile.TemporaryDirectory(prefix="simlidar_photo_") as tmp:
        src, dst = Path(tmp) / "jobs.npz", Path(tmp) / "images.npz"
        np.savez(src, **arrays)
        env = dict(os.environ)
        # the child must import this very package, installed or not
        root = str(_package_parent())
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        # stdout streams one line per finished photo; stderr is kept for the error message
        with open(Path(tmp) / "stderr.txt", "w+", encoding="utf-8") as err, subprocess.Popen(
                [sys.executable, "-m", "simlidar_mi.canopy.synthetic_photo", _WORKER_FLAG,
                 str(src), str(dst)], env=env, stdout=subprocess.PIPE, stderr=err,
                text=True) as proc:
            other = []
            for line in proc.stdout:
                if line.strip() == _DONE_MARK:
                    done()
                else:
                    other.append(line)
            returncode = proc.wait()
            err.seek(0)
            stderr = err.read()
        if returncode != 0 or not dst.exists():
            tail = "\n".join((stderr or "".join(other)).strip().splitlines()[-15:])
            raise SimlidarError(f"synthetic photo render failed in the {settings.variant} child "
                                f"process (exit code {returncode}):\n{tail}")
        with np.load(dst) as data:
            return [np.array(data[f"img{i}"]) for i in range(len(jobs))]


def render_photo(canopy, camera, settings: PhotoSettings | None = None, *, window=None,
                 seed: int = 0, isolate: bool | None = None) -> np.ndarray:
    """A photo-like 8-bit sRGB render of ``canopy`` seen by ``camera``.

    Parameters
    ----------
    canopy : simlidar_mi.canopy.canopy.Canopy
        Leaves only (wood is refused).  Periodic canopies are tiled as the coverage
        render tiles them.
    camera : simlidar_mi.canopy.cameras.Camera
        From :func:`simlidar_mi.canopy.cameras.make_camera` or a ``GapImage.camera``.
    settings : PhotoSettings, optional
    window : simlidar_mi.canopy.windows.Window, optional
        The coverage image's window; for periodic canopies its ray extent decides the
        tiling (computed from the camera when omitted).
    seed : sampler seed.
    isolate : see :func:`render_photos`.

    Returns
    -------
    numpy.ndarray of uint8, shape (camera.height, camera.width, 3)
    """
    return render_photos([_make_job(canopy, camera, window)], settings, seed=seed,
                         isolate=isolate)[0]


def save_photo_png(rgb: np.ndarray, path: str | Path) -> Path:
    """Write an (H, W, 3) uint8 array as a PNG (atomically); returns the path."""
    from PIL import Image  # noqa: PLC0415

    from ..io.atomic import atomic_file  # noqa: PLC0415
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"expected an (height, width, 3) uint8 array, got {arr.dtype} {arr.shape}")
    with atomic_file(path) as tmp:
        Image.fromarray(arr).save(tmp, format="PNG")
    return Path(path)


def canopeo_p0(rgb: np.ndarray, box: tuple[int, int, int, int] | None = None,
               **thresholds: float) -> tuple[float, np.ndarray]:
    """Canopeo's gap fraction of an 8-bit RGB array inside ``box`` (x0, y0, x1, y1).

    Uses :func:`simlidar_mi.canopy.photo.classify_rgb`; ``thresholds`` are its
    ``canopeo_rg``, ``canopeo_bg``, ``canopeo_exg``.  Returns (P0, vegetation mask).
    """
    from .photo import classify_rgb  # noqa: PLC0415
    mask, _ = classify_rgb(rgb, "canopeo", box, **thresholds)
    h, w = mask.shape
    x0, y0, x1, y1 = box if box is not None else (0, 0, w, h)
    return 1.0 - float(np.mean(mask[y0:y1, x0:x1], dtype=np.float64)), mask


# ------------------------------------------------------------------------ checks
@dataclass
class SyntheticPhotoCheck:
    """A view rendered twice, as coverage and as a photo, and both P0s.

    Attributes
    ----------
    image : simlidar_mi.canopy.gapfraction.GapImage
        The coverage render (its camera and window were used for the photo).
    rgb : (height, width, 3) uint8
        The synthetic photo.
    canopeo_mask : (height, width) bool
        Canopeo's vegetation mask of the photo.
    p0_coverage, p0_canopeo : float
        Gap fraction of the window from coverage and from Canopeo on the photo.
    settings : PhotoSettings
    seconds_photo : float
        Wall time of the child process that rendered the photos (start-up included),
        divided by the number of photos it rendered.
    """

    image: Any
    rgb: np.ndarray
    canopeo_mask: np.ndarray
    p0_coverage: float
    p0_canopeo: float
    settings: PhotoSettings
    seconds_photo: float = 0.0

    @property
    def difference(self) -> float:
        """``p0_canopeo − p0_coverage``."""
        return self.p0_canopeo - self.p0_coverage

    def row(self) -> dict[str, Any]:
        cam = self.image.camera
        return {"camera": cam.kind, "zenith_deg": f"{cam.zenith_deg:g}", "step": self.image.step,
                "p0_coverage": f"{self.p0_coverage:.6f}", "p0_canopeo": f"{self.p0_canopeo:.6f}",
                "difference": f"{self.difference:+.6f}", "coverage_spp": self.image.spp,
                "photo_spp": self.settings.spp, "width": self.image.width,
                "height": self.image.height, "seconds_photo": f"{self.seconds_photo:.3f}"}


def check_images(images: Sequence, canopies: Sequence, settings: PhotoSettings | None = None, *,
                 seed: int = 0, isolate: bool | None = None,
                 progress=False) -> list[SyntheticPhotoCheck]:
    """Photograph the views of already rendered coverage images and compare the P0s.

    Parameters
    ----------
    images : sequence of simlidar_mi.canopy.gapfraction.GapImage
        Coverage renders; each photo uses the image's camera and window.
    canopies : sequence of Canopy
        The canopy each image shows (same length as ``images``).
    settings, seed, isolate, progress : see :func:`render_photos`.  All photos are rendered
        in one child process.

    Returns
    -------
    list of SyntheticPhotoCheck
    """
    if len(images) != len(canopies):
        raise ConfigError(f"{len(images)} images but {len(canopies)} canopies", key="canopies")
    settings = settings or PhotoSettings()
    jobs = [_make_job(c, im.camera, im.window) for im, c in zip(images, canopies)]
    t0 = time.perf_counter()
    photos = render_photos(jobs, settings, seed=seed, isolate=isolate, progress=progress)
    per = (time.perf_counter() - t0) / max(1, len(jobs))
    out = []
    for im, rgb in zip(images, photos):
        p0, mask = canopeo_p0(rgb, im.window.box_px)
        out.append(SyntheticPhotoCheck(im, rgb, mask, float(im.p0), p0, settings, per))
    return out


def check_photo(canopy, kind: str = "orthographic", zenith_deg: float = 0.0, *,
                settings: PhotoSettings | None = None, seed: int = 0,
                isolate: bool | None = None, **gap_kwargs: Any) -> SyntheticPhotoCheck:
    """Render one view of ``canopy`` as coverage and as a photo; compare the P0s.

    Parameters
    ----------
    canopy : simlidar_mi.canopy.canopy.Canopy
    kind : 'orthographic' or 'perspective'
    zenith_deg : view zenith, degrees.
    settings : PhotoSettings, optional
    seed : sampler seed of the photo.
    isolate : see :func:`render_photos`.
    **gap_kwargs
        Passed to :func:`simlidar_mi.canopy.gapfraction.gap_images` (``resolution``, ``spp``,
        ``azimuth_deg``, ``window``, ``window_fraction``, ``fov_deg`` …).

    Returns
    -------
    SyntheticPhotoCheck
    """
    from .gapfraction import gap_images  # noqa: PLC0415
    img = gap_images(canopy, cameras=[kind], zeniths_deg=[zenith_deg], **gap_kwargs)[0]
    return check_images([img], [canopy], settings, seed=seed, isolate=isolate)[0]


@writes_output("out_dir")
def run_synthetic_photos(scene, out_dir: str | Path | None = None, overrides: Sequence[str] = (),
                         *, isolate: bool | None = None,
                         progress=False) -> list[SyntheticPhotoCheck]:
    """Every gap-fraction view of a scene file, also as a synthetic photo checked by Canopeo.

    The views are those of ``[gapfraction]`` (cameras × zeniths × extraction steps) of the
    scene seed's own plot (replicate 0; ``replicates`` is ignored here);
    lighting and colours come from ``[photo_render]`` (defaults: :data:`DEFAULTS`).
    All photos are rendered in one child process.

    Writes into ``out_dir`` (staged: all files appear together):

    - ``synthetic_photo.csv``: :data:`CSV_COLUMNS`, one line per view;
    - ``photo_<camera>_z<zenith>_s<step>.png``: the synthetic photo;
    - ``photo_<camera>_z<zenith>_s<step>_canopeo.png``: Canopeo's mask, window outlined.

    ``progress``: see :func:`simlidar_mi._runtime.progress.make_progress` (the coverage renders,
    then the photos).
    """
    from ..config import SceneConfig, load_scene  # noqa: PLC0415
    from .gapfraction import run_gapfraction  # noqa: PLC0415
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, list(overrides))
    settings = PhotoSettings.from_config(cfg)
    # one plot: each photo is checked against the coverage render of the same canopy
    run = run_gapfraction(cfg, None, replicates=1, progress=progress)
    by_step = {c.step: c for c in run.canopies}
    canopies = [by_step[im.step] for im in run.images]
    checks = check_images(run.images, canopies, settings, seed=cfg.seed, isolate=isolate,
                          progress=progress)
    if out_dir is None:
        return checks
    from ..io.atomic import atomic_file, staged_dir, write_csv  # noqa: PLC0415
    from ..io.png import write_mask_png  # noqa: PLC0415
    with staged_dir(out_dir, SYNTHETIC_PHOTO_OUTPUTS) as stage:
        write_csv(stage / "synthetic_photo.csv", CSV_COLUMNS, (chk.row() for chk in checks))
        for chk in checks:
            stem = chk.image.stem().replace("gap_", "photo_", 1)
            save_photo_png(chk.rgb, stage / f"{stem}.png")
            write_mask_png(stage / f"{stem}_canopeo.png", chk.canopeo_mask, chk.image.window.box_px)
        with atomic_file(stage / "synthetic_photo.json") as tmp:
            tmp.write_text(json.dumps({"scene": cfg.source, "scene_sha256": cfg.sha256,
                                       "seed": cfg.seed, "settings": settings.to_dict()},
                                      indent=2) + "\n", encoding="utf-8")
    return checks


if __name__ == "__main__" and len(sys.argv) == 4 and sys.argv[1] == _WORKER_FLAG:
    sys.exit(_worker_main(sys.argv[2], sys.argv[3]))
