"""Gap-fraction images of virtual canopies: cameras, analysis windows, coverage renders.

The pipeline behind ``simlidar-mi gapfraction``::

    from simlidar_mi.canopy.gapfraction import run_gapfraction
    run = run_gapfraction("scenes/random_leaves_spherical.toml", "out/gap")
    for img in run.images:
        print(img.camera.kind, img.camera.zenith_deg, img.p0)

and the pieces a notebook can use on its own (:class:`Canopy`, :func:`make_camera`,
:func:`analysis_window`, :func:`build_canopy_scene`, :func:`render_gap`).

Conventions
-----------
Rows run along +x (as in :mod:`simlidar_mi.plants.strawberry`).  A view is given by
its zenith θ (angle of the optical axis from the downward vertical) and its
azimuth φ *relative to the rows*: the horizontal part of the viewing direction
(camera → scene) is ``h = (cos φ, sin φ, 0)``, so φ = 0 looks along the rows and
φ = 90° across them.  Images are oriented with ``h`` pointing to the top of the
image and ``h × z`` to the right; pixel (0, 0) is the top-left corner.

``orthographic``
    Parallel rays (like the sun's beam) of direction ``d = (sin θ·h, −cos θ)``.
    The film plane is perpendicular to ``d`` and pixels are square on it, so a
    pixel's footprint on the ground is 1/cos θ longer along ``h``.  The image is
    centred on the plot centre at mid-canopy height and covers the plot.
``perspective``
    A pinhole (photo-like) at ``camera_height_m`` above the canopy top, its optical
    axis through the plot centre at mid-canopy height; square image, field of view
    ``fov_deg`` along each image axis.  Each pixel sees the canopy at its own view
    angle, so a wide window reads a P0 averaged over those angles.

Analysis window (the part of the image whose background share is P0)
--------------------------------------------------------------------
``inset``
    The paper crops "the central part of the row".  Here the window is the
    largest box, centred in the image and within the central ``window_fraction``
    of it, whose rays cross the whole canopy layer [lowest leaf, highest leaf]
    inside the plot shrunk by ``margin_m`` (default: one leaf size, the largest
    horizontal extent of a single leaf).  For an orthographic view this is the
    plot inset by ``margin_m`` on every side plus canopy height × tan θ along
    ``h`` (half on each side, the image being centred at mid-canopy).  Near the
    plot edge a point misses the leaves of plants beyond the plot, which is why
    the margin is needed.
``periodic``
    For canopies that are periodic by construction (``random_leaves``): the
    plot is tiled by translated copies as far as any ray of the image needs to
    see an infinite canopy, and the window is the central ``window_fraction`` of
    the image (the whole plot for an orthographic view).  At view azimuths 0° and
    90° that orthographic window is one period of the tiling; at others it is a
    plot-sized box turned against it: P0's expectation is unchanged, its scatter
    between seeds larger (SD 0.0079 instead of 0.0059 for N = 1000, LAI 1, 20°).
``auto``
    ``periodic`` for periodic canopies, ``inset`` otherwise.

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
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..config import SceneConfig, load_scene
from ..errors import ConfigError, SimlidarError
from ..geometry import Branches, Leaves
from ..io.atomic import atomic_file, staged_dir, write_csv
from ..io.exr import header_value

log = logging.getLogger(__name__)

__all__ = [
    "Canopy", "Camera", "Window", "GapImage", "GapFractionRun",
    "CAMERAS", "WINDOW_MODES", "CSV_COLUMNS", "DEFAULTS",
    "make_camera", "analysis_window", "tile_offsets", "build_canopy_scene", "render_gap",
    "gap_images", "canopies_from_config", "canopy_from_random_leaves", "run_gapfraction", "expected_p0",
    "write_gap_exr", "read_gap_exr",
]

CAMERAS = ("orthographic", "perspective")
WINDOW_MODES = ("auto", "inset", "periodic")
CSV_COLUMNS = ("camera", "zenith_deg", "step", "p0", "leaf_area_m2", "lai", "spp",
               "width", "height", "seconds")
#: Defaults of the ``[gapfraction]`` section (see ``bench/gapfraction_bench.py``
#: for why resolution and spp are what they are).
DEFAULTS: dict[str, Any] = {
    "cameras": ["orthographic", "perspective"],
    "zeniths_deg": [0.0, 15.0, 30.0],
    "azimuth_deg": 0.0,
    "resolution": 1024,
    "spp": 4,
    "window": "auto",
    "window_fraction": 1.0,
    "margin_m": None,
    "fov_deg": 60.0,
    "camera_height_m": 1.0,
    "jitter": False,
    "mask_threshold": 0.5,
}
MAX_ZENITH_DEG = 80.0  # beyond this a plot-sized orthographic footprint is a sliver
MAX_TILED_TRIANGLES = 20_000_000  # periodic tiling beyond this would take GBs of RAM
_EPS_M = 1e-9


# ------------------------------------------------------------------------- canopy
@dataclass(frozen=True)
class Canopy:
    """Leaves (and optional wood) over a rectangular plot, with what P0 needs to know.

    Parameters
    ----------
    leaves : Leaves
        Leaf triangles, real coordinates in metres.
    plot_bounds_m : (x_min, y_min, x_max, y_max)
        The plot (ground) rectangle, metres.  LAI = leaf area / its area.
    periodic : bool
        True when leaves were placed in a periodic plot (tiling is exact).
    step : int
        Extraction step (0 = full canopy).
    name : str
        What generated it, for file headers.
    branches : Branches, optional
        Woody parts; they count as vegetation too.
    leaf_area_m2 : float, optional
        One-sided leaf area; computed from the triangles when omitted.
    """

    leaves: Leaves
    plot_bounds_m: tuple[float, float, float, float]
    periodic: bool = False
    step: int = 0
    name: str = "canopy"
    branches: Branches | None = None
    leaf_area_m2: float | None = None

    def __post_init__(self) -> None:
        b = tuple(float(v) for v in self.plot_bounds_m)
        if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[2] <= b[0] or b[3] <= b[1]:
            raise ConfigError("plot bounds must be finite (x_min, y_min, x_max, y_max) with "
                              "x_max > x_min and y_max > y_min", key="plot_bounds_m",
                              value=self.plot_bounds_m)
        object.__setattr__(self, "plot_bounds_m", b)
        if self.leaf_area_m2 is None:
            object.__setattr__(self, "leaf_area_m2", float(self.leaves.triangle_area.sum()))

    @property
    def plot_area_m2(self) -> float:
        x0, y0, x1, y1 = self.plot_bounds_m
        return (x1 - x0) * (y1 - y0)

    @property
    def lai(self) -> float:
        """One-sided leaf area / plot area."""
        return float(self.leaf_area_m2) / self.plot_area_m2

    @property
    def plot_centre_m(self) -> np.ndarray:
        x0, y0, x1, y1 = self.plot_bounds_m
        return np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])

    def z_range_m(self) -> tuple[float, float]:
        """Lowest and highest vegetation point (leaf vertices, branch ends ± radius)."""
        zs = []
        if len(self.leaves):
            z = self.leaves.vertices[..., 2]
            zs += [z.min(), z.max()]
        if self.branches is not None and len(self.branches):
            r = 0.5 * self.branches.diameter
            for p in (self.branches.p0, self.branches.p1):
                zs += [(p[:, 2] - r).min(), (p[:, 2] + r).max()]
        if not zs:
            return 0.0, 0.0
        return float(min(zs)), float(max(zs))

    def leaf_size_m(self) -> float:
        """Largest horizontal extent (bounding-box diagonal in x, y) of one leaf, metres."""
        if not len(self.leaves):
            return 0.0
        key = self.leaves.plant_id.astype(np.int64) * (2**32) + self.leaves.leaf_id.astype(np.int64)
        order = np.argsort(key, kind="stable")
        k = key[order]
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        xy = self.leaves.vertices[order][..., :2]
        lo = np.minimum.reduceat(xy.min(axis=1), starts, axis=0)
        hi = np.maximum.reduceat(xy.max(axis=1), starts, axis=0)
        return float(np.linalg.norm(hi - lo, axis=1).max())


def expected_p0(n_leaves: int, leaf_area_m2: float, plot_area_m2: float, zenith_deg,
                angle_law: str = "spherical") -> np.ndarray:
    """E[P0] of N flat leaves placed independently and uniformly in a periodic plot.

    ``(1 − a·G(θ)/(A·cos θ))^N`` with G = cos θ (horizontal), 0.5 (spherical) or
    (2/π)·sin θ (vertical, random azimuth); exact for a finite N (science notes).
    ``zenith_deg`` may be an array (a perspective image's per-sample zeniths).
    """
    th = np.deg2rad(np.asarray(zenith_deg, float))
    c = np.cos(th)
    if angle_law == "horizontal":
        g_over_c = np.ones_like(c)
    elif angle_law == "spherical":
        g_over_c = 0.5 / c
    elif angle_law == "vertical":
        g_over_c = (2.0 / np.pi) * np.tan(th)
    else:
        raise ConfigError("angle law must be 'horizontal', 'spherical' or 'vertical'",
                          key="angle_law", value=angle_law)
    return (1.0 - leaf_area_m2 * g_over_c / plot_area_m2) ** n_leaves


# ------------------------------------------------------------------------- camera
@dataclass(frozen=True)
class Camera:
    """A gap-fraction camera in real (scene) coordinates, metres and degrees.

    ``position_m`` is the pinhole of a perspective camera and, for an orthographic
    one, the centre of the film plane (placed above the canopy).  ``direction``
    is the optical axis (camera → scene), ``right`` and ``up`` the image axes.
    ``half_extent_m`` is the orthographic film's half width and half height;
    ``fov_deg`` the perspective field of view along each image axis.
    """

    kind: str
    zenith_deg: float
    azimuth_deg: float
    width: int
    height: int
    position_m: np.ndarray
    target_m: np.ndarray
    direction: np.ndarray
    right: np.ndarray
    up: np.ndarray
    half_extent_m: tuple[float, float] = (0.0, 0.0)
    fov_deg: float = 0.0
    camera_height_m: float = 0.0

    def rays(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Float64 origins and unit directions for image fractions ``u`` (→ right), ``v`` (↓).

        (0, 0) is the top-left corner of the image, (1, 1) the bottom-right.
        """
        u = np.asarray(u, float)[..., None]
        v = np.asarray(v, float)[..., None]
        if self.kind == "orthographic":
            hx, hy = self.half_extent_m
            o = self.position_m + (2 * u - 1) * hx * self.right + (1 - 2 * v) * hy * self.up
            d = np.broadcast_to(self.direction, o.shape)
            return o, np.array(d)
        tx = math.tan(math.radians(self.fov_deg) / 2)
        ty = tx * self.height / self.width
        d = self.direction + (2 * u - 1) * tx * self.right + (1 - 2 * v) * ty * self.up
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return np.broadcast_to(self.position_m, d.shape).copy(), d

    def points_at_z(self, u, v, z_m: float) -> np.ndarray:
        """Where the rays of image fractions (u, v) cross the plane z = z_m; (..., 3)."""
        o, d = self.rays(u, v)
        t = (z_m - o[..., 2]) / d[..., 2]
        return o + t[..., None] * d

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly settings (lists for vectors)."""
        out = {}
        for k, v in asdict(self).items():
            out[k] = v.tolist() if isinstance(v, np.ndarray) else (list(v) if isinstance(v, tuple) else v)
        return out

    def sensor_dict(self, mi, origin_m: np.ndarray, spp: int) -> dict:
        """Mitsuba sensor description in the scene frame (``origin_m`` subtracted)."""
        pos = (self.position_m - origin_m).tolist()
        tgt = (self.position_m + self.direction - origin_m).tolist()
        to_world = mi.ScalarTransform4f.look_at(origin=pos, target=tgt, up=self.up.tolist())
        film = {"type": "hdrfilm", "width": int(self.width), "height": int(self.height),
                "pixel_format": "luminance", "rfilter": {"type": "box"}}
        sampler = {"type": "independent", "sample_count": int(spp)}
        if self.kind == "orthographic":
            hx, hy = self.half_extent_m
            # Mitsuba's orthographic film spans ±sx by ±sy/aspect before this scale.
            scale = mi.ScalarTransform4f.scale([hx, hy * self.width / self.height, 1.0])
            return {"type": "orthographic", "to_world": to_world @ scale, "near_clip": 1e-3,
                    "far_clip": 1e5, "film": film, "sampler": sampler}
        return {"type": "perspective", "to_world": to_world, "fov": float(self.fov_deg),
                "fov_axis": "x", "near_clip": 1e-3, "far_clip": 1e5, "film": film,
                "sampler": sampler}


def _view_frame(zenith_deg: float, azimuth_deg: float) -> tuple[np.ndarray, ...]:
    """(h, d, up, right): horizontal view direction, optical axis and image axes."""
    th, ph = math.radians(zenith_deg), math.radians(azimuth_deg)
    h = np.array([math.cos(ph), math.sin(ph), 0.0])
    s, c = math.sin(th), math.cos(th)  # exact 0 and 1 at nadir: rays exactly vertical
    d = np.array([s * h[0], s * h[1], -c])
    up = np.array([c * h[0], c * h[1], s])
    right = np.cross(h, [0.0, 0.0, 1.0])
    return h, d, up, right


def make_camera(kind: str, canopy: Canopy, zenith_deg: float, *, azimuth_deg: float = 0.0,
                resolution: int = DEFAULTS["resolution"], fov_deg: float = DEFAULTS["fov_deg"],
                camera_height_m: float = DEFAULTS["camera_height_m"],
                periodic: bool | None = None) -> Camera:
    """A camera looking at the centre of ``canopy``'s plot.

    Parameters
    ----------
    kind : 'orthographic' or 'perspective'
    canopy : Canopy
    zenith_deg : view zenith θ, 0 ≤ θ ≤ 80 degrees.
    azimuth_deg : view azimuth relative to the rows (0 = along the rows).
    resolution : pixels along the longer image side (perspective images are square).
    fov_deg : perspective field of view along each image axis, degrees.
    camera_height_m : perspective pinhole height above the highest leaf, metres.
    periodic : orthographic only: the image covers a plot-sized box (True) or the
        plot's whole footprint (False); default ``canopy.periodic``.
    """
    if kind not in CAMERAS:
        raise ConfigError(f"unknown camera; valid: {', '.join(CAMERAS)}", key="gapfraction.cameras",
                          value=kind)
    if not (isinstance(zenith_deg, numbers.Real) and not isinstance(zenith_deg, bool)
            and 0.0 <= zenith_deg <= MAX_ZENITH_DEG):
        raise ConfigError(f"view zenith must lie in [0, {MAX_ZENITH_DEG:g}] degrees",
                          key="gapfraction.zeniths_deg", value=zenith_deg)
    if not (isinstance(resolution, numbers.Integral) and not isinstance(resolution, bool)
            and resolution >= 1):
        raise ConfigError("resolution must be an integer ≥ 1 pixel", key="gapfraction.resolution",
                          value=resolution)
    zenith_deg, azimuth_deg, resolution = float(zenith_deg), float(azimuth_deg), int(resolution)
    h, d, up, right = _view_frame(zenith_deg, azimuth_deg)
    z_lo, z_hi = canopy.z_range_m()
    z_ref = 0.5 * (z_lo + z_hi)
    cx, cy = canopy.plot_centre_m
    target = np.array([cx, cy, z_ref])
    cos_t = -d[2]
    if kind == "orthographic":
        periodic = canopy.periodic if periodic is None else periodic
        x0, y0, x1, y1 = canopy.plot_bounds_m
        if periodic:
            # A plot-sized box: the plot's x extent along whichever image axis is
            # closer to the rows, so that at φ = 0° or 90° the image is the plot.
            along_rows_is_up = abs(h[0]) >= abs(h[1])
            gx, gy = (y1 - y0, x1 - x0) if along_rows_is_up else (x1 - x0, y1 - y0)
            hx, hy_ground = 0.5 * gx, 0.5 * gy
        else:
            corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]) - [cx, cy]
            hx = float(np.abs(corners @ right[:2]).max())
            hy_ground = float(np.abs(corners @ h[:2]).max())
        hy = hy_ground * cos_t  # film-plane extent of a ground length along h
        long_side = max(hx, hy)
        width = max(1, int(round(resolution * hx / long_side)))
        height = max(1, int(round(resolution * hy / long_side)))
        lift = (z_hi - z_ref) + 1.0  # start the parallel rays 1 m above the canopy
        position = target - (lift / cos_t) * d
        return Camera(kind, zenith_deg, azimuth_deg, width, height, position, target, d, right, up,
                      (hx, hy))
    if not (0.0 < fov_deg < 170.0):
        raise ConfigError("field of view must lie in (0, 170) degrees", key="gapfraction.fov_deg",
                          value=fov_deg)
    if not camera_height_m > 0:
        raise ConfigError("camera height above the canopy must be > 0 metres",
                          key="gapfraction.camera_height_m", value=camera_height_m)
    z_cam = z_hi + camera_height_m
    position = target - ((z_cam - z_ref) / cos_t) * d
    return Camera(kind, zenith_deg, azimuth_deg, resolution, resolution, position, target, d,
                  right, up, fov_deg=float(fov_deg), camera_height_m=float(camera_height_m))


# ------------------------------------------------------------------------- window
@dataclass(frozen=True)
class Window:
    """The analysed part of an image.

    ``box_px`` is the half-open pixel box (x0, y0, x1, y1); ``safe_region_m`` the
    ground rectangle every analysed ray stays inside between the canopy's lowest
    and highest points (inset mode; the tiled extent in periodic mode).
    """

    mode: str
    box_px: tuple[int, int, int, int]
    fraction: float
    margin_m: float
    safe_region_m: tuple[float, float, float, float]
    z_range_m: tuple[float, float]
    tiles: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def n_pixels(self) -> int:
        x0, y0, x1, y1 = self.box_px
        return (x1 - x0) * (y1 - y0)

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


def _box_inside(camera: Camera, a: float, b: float, zs: Sequence[float],
                region: tuple[float, float, float, float]) -> bool:
    """Do the rays of the centred box of half sizes (a, b) (image fractions) stay in region?

    For a fixed height, image → plane is projective, so a box's image is a convex
    quadrilateral and its corners decide; a ray segment between two heights stays
    inside the convex region when both ends do.
    """
    u = np.array([0.5 - a, 0.5 + a, 0.5 - a, 0.5 + a])
    v = np.array([0.5 - b, 0.5 - b, 0.5 + b, 0.5 + b])
    x0, y0, x1, y1 = region
    for z in zs:
        p = camera.points_at_z(u, v, z)
        if not (np.all(p[:, 0] >= x0 - _EPS_M) and np.all(p[:, 0] <= x1 + _EPS_M)
                and np.all(p[:, 1] >= y0 - _EPS_M) and np.all(p[:, 1] <= y1 + _EPS_M)):
            return False
    return True


def _grow(ok, lo: float, hi: float, iters: int = 50) -> float:
    """Largest x in [lo, hi] with ok(x), given ok(lo) (bisection)."""
    if ok(hi):
        return hi
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def _pixel_box(camera: Camera, a: float, b: float) -> tuple[int, int, int, int]:
    """Pixels whose whole area lies inside the centred box of half sizes (a, b)."""
    w, h = camera.width, camera.height
    x0 = math.ceil((0.5 - a) * w - 1e-9)
    x1 = math.floor((0.5 + a) * w + 1e-9)
    y0 = math.ceil((0.5 - b) * h - 1e-9)
    y1 = math.floor((0.5 + b) * h + 1e-9)
    return x0, y0, x1, y1


def analysis_window(camera: Camera, canopy: Canopy, mode: str = "auto", *,
                    fraction: float = 1.0, margin_m: float | None = None) -> Window:
    """The window of ``camera``'s image whose background share is reported as P0.

    Parameters
    ----------
    camera, canopy : what is viewed.
    mode : 'inset', 'periodic' or 'auto' (periodic for periodic canopies).
    fraction : the window lies within the central ``fraction`` of the image in
        each dimension (0 < fraction ≤ 1).
    margin_m : inset from the plot edges (inset mode); default one leaf size.

    Raises
    ------
    ConfigError
        When no window of at least one pixel fits (plot too small for the view).
    """
    if mode not in WINDOW_MODES:
        raise ConfigError(f"unknown window mode; valid: {', '.join(WINDOW_MODES)}",
                          key="gapfraction.window", value=mode)
    if not (0.0 < fraction <= 1.0):
        raise ConfigError("window fraction must lie in (0, 1]", key="gapfraction.window_fraction",
                          value=fraction)
    if mode == "auto":
        mode = "periodic" if canopy.periodic else "inset"
    z_range = canopy.z_range_m()
    half = 0.5 * fraction
    if mode == "periodic":
        a = b = half
        region = _ray_extent(camera, z_range)
        box = _pixel_box(camera, a, b)
        margin = 0.0
    else:
        margin = canopy.leaf_size_m() if margin_m is None else float(margin_m)
        if not (math.isfinite(margin) and margin >= 0):
            raise ConfigError("margin must be ≥ 0 metres", key="gapfraction.margin_m", value=margin_m)
        x0, y0, x1, y1 = canopy.plot_bounds_m
        region = (x0 + margin, y0 + margin, x1 - margin, y1 - margin)
        if region[2] <= region[0] or region[3] <= region[1]:
            raise ConfigError(f"the plot ({x1 - x0:.3g} × {y1 - y0:.3g} m) is narrower than twice "
                              f"the margin; use a larger plot, a smaller margin or window = 'periodic'",
                              key="gapfraction.margin_m", value=margin)
        zs = z_range

        def fits(s: float, a0: float = half, b0: float = half) -> bool:
            return _box_inside(camera, s * a0, s * b0, zs, region)
        if not fits(1e-9):
            raise ConfigError(f"the {camera.kind} view at zenith {camera.zenith_deg:g}° does not see "
                              "the plot's safe centre; lower the zenith or the margin",
                              key="gapfraction.zeniths_deg", value=camera.zenith_deg)
        s = _grow(fits, 0.0, 1.0)
        a, b = s * half, s * half
        # then widen each axis on its own (the safe region need not be square)
        a = _grow(lambda x: _box_inside(camera, x, b, zs, region), a, half)
        b = _grow(lambda y: _box_inside(camera, a, y, zs, region), b, half)
        box = _pixel_box(camera, a, b)
    if box[2] <= box[0] or box[3] <= box[1]:
        raise ConfigError(f"the analysis window of the {camera.kind} view at zenith "
                          f"{camera.zenith_deg:g}° holds no whole pixel; raise the resolution "
                          "or lower the margin", key="gapfraction.resolution", value=camera.width)
    return Window(mode, box, float(fraction), float(margin), tuple(float(v) for v in region),
                  z_range)


def _ray_extent(camera: Camera, z_range: tuple[float, float]) -> tuple[float, float, float, float]:
    """Bounding rectangle of every image ray between the canopy's lowest and highest points."""
    u = np.array([0.0, 1.0, 0.0, 1.0])
    v = np.array([0.0, 0.0, 1.0, 1.0])
    pts = np.concatenate([camera.points_at_z(u, v, z)[:, :2] for z in z_range])
    lo, hi = pts.min(0), pts.max(0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def tile_offsets(canopy: Canopy, extents: Sequence[tuple[float, float, float, float]],
                 pad_m: float | None = None) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Plot translations that cover every rectangle in ``extents`` (periodic canopies).

    ``pad_m`` (default one leaf size) extends the rectangles so that leaves of the
    outermost copies reaching inwards are present.  Returns the (n, 2) offsets in
    metres and the tile index range (i0, j0, i1, j1), inclusive.
    """
    x0, y0, x1, y1 = canopy.plot_bounds_m
    w, l = x1 - x0, y1 - y0
    pad = canopy.leaf_size_m() if pad_m is None else pad_m
    ext = np.asarray(extents, float).reshape(-1, 4)
    i0 = int(math.floor((ext[:, 0].min() - pad - x0) / w))
    i1 = int(math.floor((ext[:, 2].max() + pad - x0) / w))
    j0 = int(math.floor((ext[:, 1].min() - pad - y0) / l))
    j1 = int(math.floor((ext[:, 3].max() + pad - y0) / l))
    n_tiles = (i1 - i0 + 1) * (j1 - j0 + 1)
    if n_tiles * max(len(canopy.leaves), 1) > MAX_TILED_TRIANGLES:
        raise ConfigError(f"the views need {n_tiles} copies of the periodic plot "
                          f"({n_tiles * len(canopy.leaves):,} triangles, limit "
                          f"{MAX_TILED_TRIANGLES:,}); lower the perspective camera height or "
                          "field of view, or use a larger plot", key="gapfraction.camera_height_m")
    ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
    offsets = np.stack([ii.ravel() * w, jj.ravel() * l], axis=1)
    return offsets, (i0, j0, i1, j1)


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
        """One line of gap_fraction.csv."""
        return {"camera": self.camera.kind, "zenith_deg": self.camera.zenith_deg,
                "step": self.step, "p0": self.p0, "leaf_area_m2": self.leaf_area_m2,
                "lai": self.lai, "spp": self.spp, "width": self.width, "height": self.height,
                "seconds": self.seconds}

    def metadata(self) -> dict[str, Any]:
        """Everything but the pixels, JSON-friendly."""
        return {**self.row(), "azimuth_deg": self.camera.azimuth_deg, "jitter": self.jitter,
                "seed": self.seed, "camera_settings": self.camera.to_dict(),
                "window": self.window.to_dict()}


def render_gap(built, canopy: Canopy, camera: Camera, window: Window, *, spp: int = DEFAULTS["spp"],
               jitter: bool = False, seed: int = 0, variant: str | None = None,
               integrator=None) -> GapImage:
    """Render ``camera``'s coverage image of ``built`` (from :func:`build_canopy_scene`)."""
    from .._mitsuba import mitsuba  # noqa: PLC0415
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


def gap_images(canopy: Canopy, *, cameras: Sequence[str] = DEFAULTS["cameras"],
               zeniths_deg: Sequence[float] = DEFAULTS["zeniths_deg"],
               azimuth_deg: float = DEFAULTS["azimuth_deg"],
               resolution: int = DEFAULTS["resolution"], spp: int = DEFAULTS["spp"],
               window: str = DEFAULTS["window"], window_fraction: float = DEFAULTS["window_fraction"],
               margin_m: float | None = DEFAULTS["margin_m"], fov_deg: float = DEFAULTS["fov_deg"],
               camera_height_m: float = DEFAULTS["camera_height_m"], jitter: bool = False,
               seed: int = 0, variant: str | None = None,
               reference: Canopy | None = None) -> list[GapImage]:
    """Every (camera, zenith) image of one canopy; the Mitsuba scene is built once.

    Cameras and windows are placed from ``reference`` (default ``canopy``): pass the
    full canopy when rendering its extraction steps, so that every step is seen
    through the same cameras and windows, as the paper photographed the same area.
    In periodic mode the plot is tiled once for the union of all views' ray extents.
    """
    ref = canopy if reference is None else reference
    mode = window if window != "auto" else ("periodic" if ref.periodic else "inset")
    views = []
    for kind in cameras:
        for zen in zeniths_deg:
            cam = make_camera(kind, ref, zen, azimuth_deg=azimuth_deg, resolution=resolution,
                              fov_deg=fov_deg, camera_height_m=camera_height_m,
                              periodic=mode == "periodic")
            views.append((cam, analysis_window(cam, ref, mode, fraction=window_fraction,
                                               margin_m=margin_m)))
    offsets = None
    if mode == "periodic":
        offsets, tiles = tile_offsets(ref, [w.safe_region_m for _, w in views])
        views = [(c, replace(w, tiles=tiles)) for c, w in views]
    built = build_canopy_scene(canopy, offsets, variant=variant)
    from .._mitsuba import mitsuba  # noqa: PLC0415
    mi = mitsuba(variant)
    integrator = mi.load_dict({"type": "coverage", "jitter": bool(jitter)})
    return [render_gap(built, canopy, cam, win, spp=spp, jitter=jitter, seed=seed,
                       variant=variant, integrator=integrator) for cam, win in views]


# ----------------------------------------------------------------------- scene file
def canopies_from_config(cfg: SceneConfig) -> list[Canopy]:
    """The canopies a scene file describes: one per extraction step.

    ``[random_leaves]`` gives one periodic canopy; ``[strawberry]`` a plot and its
    extraction steps (``[strawberry] extraction``).
    """
    has_rl, has_sb = cfg.has("random_leaves"), cfg.has("strawberry")
    if has_rl == has_sb:
        raise ConfigError("a gap-fraction scene needs exactly one of [random_leaves] or "
                          "[strawberry]", file=cfg.source)
    if has_rl:
        from ..plants.random_leaves import random_leaves  # noqa: PLC0415
        r = cfg["random_leaves"]
        try:
            rl = random_leaves(r["n_leaves"], r["leaf_area_m2"], plot_size_m=tuple(r["plot_size_m"]),
                               height_range_m=tuple(r["height_range_m"]),
                               angle_law=r["angle_law"], shape=r["shape"], seed=cfg.seed)
        except ConfigError as exc:
            raise ConfigError(str(exc), file=cfg.source) from exc
        return [canopy_from_random_leaves(rl)]
    from ..plants import strawberry as sb  # noqa: PLC0415
    s = dict(cfg["strawberry"])
    extraction = [int(n) for n in s.pop("extraction")]
    leaf = {k: v for k, v in cfg["strawberry.leaf"].items() if v is not None}
    try:
        plot = sb.strawberry_plot(sb.StrawberryPlotParams(**s, leaf=leaf), seed=cfg.seed)
        # Its own stream: changing the extraction counts never changes the plot.
        steps = sb.extraction_steps(plot, extraction, seed=np.random.SeedSequence([cfg.seed, 1]))
    except ConfigError as exc:
        raise ConfigError(str(exc), file=cfg.source) from exc
    return [Canopy(st.leaves, plot.bounds_m, periodic=False, step=st.step, name="strawberry",
                   leaf_area_m2=st.leaf_area_m2) for st in steps]


def canopy_from_random_leaves(rl) -> Canopy:
    """A periodic :class:`Canopy` of a :class:`~simlidar_mi.plants.random_leaves.RandomLeavesCanopy`.

    Only the N original leaves are kept: the plot is tiled with whole copies of them
    (which also supplies the wrapped copies the generator adds at the edges).
    """
    p = rl.params
    return Canopy(rl.originals, tuple(rl.bounds_m), periodic=True, step=0, name="random_leaves",
                  leaf_area_m2=p.n_leaves * p.leaf_area_m2)


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
    import OpenEXR  # noqa: PLC0415
    try:
        with OpenEXR.File(str(path)) as f:
            header = dict(f.header())  # emptied when the file closes
            cov = np.array(f.channels()["coverage"].pixels)
    except Exception as exc:  # OpenEXR raises plain exceptions for unreadable files
        raise SimlidarError(f"{path}: cannot read gap-fraction EXR: {exc}") from exc
    if "simlidar_gap" in header:
        header["metadata"] = json.loads(header["simlidar_gap"])
    return cov, header


@dataclass
class GapFractionRun:
    """What :func:`run_gapfraction` produced."""

    images: list[GapImage]
    canopies: list[Canopy]
    files: dict[str, Path] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)


def _settings(cfg: SceneConfig) -> dict[str, Any]:
    g = dict(DEFAULTS)
    if "gapfraction" in cfg.sections:
        g.update({k: v for k, v in cfg["gapfraction"].items()})
    for kind in g["cameras"]:
        if kind not in CAMERAS:
            raise ConfigError(f"unknown camera; valid: {', '.join(CAMERAS)}", file=cfg.source,
                              key="gapfraction.cameras", value=kind)
    return g


def run_gapfraction(scene: SceneConfig | str | Path, out_dir: str | Path | None = None,
                    overrides: Sequence[str] = (), *, write_images: bool = True) -> GapFractionRun:
    """Scene file → canopies (one per extraction step) → gap images → files.

    Writes into ``out_dir`` (all files appear together when complete; a failure
    leaves ``out_dir`` as it was):

    - ``gap_fraction.csv``: ``camera, zenith_deg, step, p0, leaf_area_m2, lai, spp,
      width, height, seconds``, one line per image;
    - ``gap_fraction.json``: the same plus every camera setting and window;
    - ``gap_<camera>_z<zenith>_s<step>.png``: vegetation mask (coverage ≥
      ``mask_threshold``, display only) with the window outlined;
    - ``gap_<camera>_z<zenith>_s<step>.exr``: float32 coverage with the settings
      in the header.
    """
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, list(overrides))
    g = _settings(cfg)
    variant = cfg["scene"]["variant"]
    t0 = time.perf_counter()
    canopies = canopies_from_config(cfg)
    seconds = {"generate": time.perf_counter() - t0}
    images: list[GapImage] = []
    t0 = time.perf_counter()
    for canopy in canopies:
        try:
            images += gap_images(canopy, cameras=g["cameras"], zeniths_deg=g["zeniths_deg"],
                                 azimuth_deg=g["azimuth_deg"], resolution=g["resolution"],
                                 spp=g["spp"], window=g["window"],
                                 window_fraction=g["window_fraction"], margin_m=g["margin_m"],
                                 fov_deg=g["fov_deg"], camera_height_m=g["camera_height_m"],
                                 jitter=g["jitter"], seed=cfg.seed, variant=variant,
                                 reference=canopies[0])
        except ConfigError as exc:
            if exc.file is None:
                raise ConfigError(str(exc), file=cfg.source) from exc
            raise
    seconds["render"] = time.perf_counter() - t0
    run = GapFractionRun(images, canopies, {}, seconds)
    if out_dir is None:
        return run
    from ..io.png import write_mask_png  # noqa: PLC0415
    out = Path(out_dir)
    t0 = time.perf_counter()
    with staged_dir(out) as stage:
        write_csv(stage / "gap_fraction.csv", CSV_COLUMNS, (
            {**img.row(), "p0": f"{img.p0:.6f}", "leaf_area_m2": f"{img.leaf_area_m2:.6g}",
             "lai": f"{img.lai:.6g}", "seconds": f"{img.seconds:.4f}",
             "zenith_deg": f"{img.camera.zenith_deg:g}"} for img in images))
        run.files["csv"] = out / "gap_fraction.csv"
        extra = {"scene_file": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed}
        meta = {"scene": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed,
                "settings": g, "images": []}
        for img in images:
            stem = img.stem()
            if write_images:
                write_mask_png(stage / f"{stem}.png", img.mask(g["mask_threshold"]), img.window.box_px)
                write_gap_exr(img, stage / f"{stem}.exr", extra=extra)
                run.files[f"{stem}.png"] = out / f"{stem}.png"
                run.files[f"{stem}.exr"] = out / f"{stem}.exr"
            meta["images"].append({"stem": stem, **img.metadata()})
        with atomic_file(stage / "gap_fraction.json") as tmp:
            tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        run.files["json"] = out / "gap_fraction.json"
    seconds["write"] = time.perf_counter() - t0
    return run
