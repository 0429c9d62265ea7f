"""Gap-fraction cameras: orthographic and perspective views of a canopy plot.

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
"""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..errors import ConfigError
from .canopy import Canopy
from .gapfraction_defaults import DEFAULTS

__all__ = ["Camera", "CAMERAS", "make_camera"]

CAMERAS = ("orthographic", "perspective")
MAX_ZENITH_DEG = 80.0  # beyond this a plot-sized orthographic footprint is a sliver


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
