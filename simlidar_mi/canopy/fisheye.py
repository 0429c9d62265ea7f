"""Virtual hemispherical photographs: fisheye cameras, their pixel angles and ring/sector gap fractions.

Conventions (also in the ``fisheye`` plugin, ``plugins/fisheye_camera.py``):

* θ is the angle of a view direction from the camera's **optical axis** (0–90°): the zenith
  angle for an untilted up-looking camera (DHP under a canopy), the nadir angle looking down.
* φ (``azimuth_deg``) is a **scene azimuth** in [0°, 360°), counter-clockwise from +x seen from
  above: φ = atan2(d_y, d_x) of the view direction d of an untilted camera; a tilted camera
  measures it in its tilted frame (the tilt applied to +x and +y).
* The image: row 0 at the top; the image top points to scene azimuth ``heading_deg``
  (default 90°, +y).  Looking up, +x then appears on the left (the sky seen from below, as a
  real upward photo shows it); looking down, on the right (a map).  Image orientation never
  changes a table: φ is a scene azimuth.
* Formats: ``circular`` (the image circle, θ ≤ 90°, inside a square frame: R = min(W, H)/2)
  and ``fullframe`` (a 3:2 frame whose half-diagonal is the image circle: R = √(W² + H²)/2).
  Pixels whose centre lies outside the circle belong to no ring and are NaN in the coverage.

Gap fractions: a pixel's coverage is the share of its spp sub-samples whose ray meets the
plant (the ``coverage`` integrator), so 1 − coverage is its gap.  A ring or sector's ``gap``
weights each pixel by its solid angle dΩ = sin θ / (R²·ρ·ρ′(θ)) per pixel (an isotropic sky's
transmittance over the ring: the physical reading), ``gap_pixels`` counts pixels equally (what
hemispheR and CAN-EYE report).  The two differ by the projection's change of pixel solid angle
across a ring (equidistant, 60–75°: 11 %; for gap fractions that vary little across a ring the
difference is small).  A pixel counts in the ring and sector that contain its centre's (θ, φ),
computed in float64 by the exact inverse projection.
"""
from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..errors import ConfigError
from .fisheye_lens import Lens, lens as make_lens

__all__ = ["FORMATS", "LOOKING", "DEFAULT_RINGS_DEG", "FisheyeCamera", "PixelAngles", "GapTable",
           "FisheyeImage", "TableSums", "make_fisheye", "gap_table", "gap_runs", "render_fisheye", "ring_bounds"]

FORMATS = ("circular", "fullframe")
LOOKING = ("up", "down")
DEFAULT_RINGS_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0)
FULLFRAME_ASPECT = 1.5  # 3:2, the frame of the DSLRs full-frame fisheyes are sold for


def _cos_sin_deg(a: float) -> tuple[float, float]:
    """cos and sin of ``a`` degrees, exact at multiples of 90° (axes stay exactly axes)."""
    q, r = divmod(float(a), 90.0)
    if r == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(q) % 4]
    t = math.radians(a)
    return math.cos(t), math.sin(t)


def _tilt_rotation(tilt_deg: float, towards_deg: float) -> np.ndarray:
    """Rotation turning +z by ``tilt_deg`` toward the horizontal azimuth ``towards_deg``."""
    if tilt_deg == 0.0:
        return np.eye(3)
    ca, sa = _cos_sin_deg(towards_deg)
    k = np.array([-sa, ca, 0.0])  # horizontal axis ⟂ the lean; z × h = k, k × z = h
    ct, st = _cos_sin_deg(tilt_deg)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return ct * np.eye(3) + st * kx + (1.0 - ct) * np.outer(k, k)


@dataclass(frozen=True)
class FisheyeCamera:
    """A fisheye camera in real scene coordinates (module docstring for the conventions).

    ``position_m`` is the centre of projection (x, y, z) in metres, float64; ``tilt_deg`` leans
    the optical axis from the vertical toward scene azimuth ``tilt_azimuth_deg``.
    """

    lens: Lens
    width: int
    height: int
    position_m: np.ndarray
    format: str = "circular"
    looking: str = "up"
    tilt_deg: float = 0.0
    tilt_azimuth_deg: float = 0.0
    heading_deg: float = 90.0
    # A photo's own circle (x, y of its centre from the top-left corner, and R), pixels; None:
    # centred, R from the format (rendered images always are).
    centre_px: tuple[float, float] | None = None
    circle_radius_px: float | None = None

    @property
    def radius_px(self) -> float:
        """Image-circle radius R in pixels (ρ = 1)."""
        if self.circle_radius_px is not None:
            return float(self.circle_radius_px)
        if self.format == "circular":
            return 0.5 * min(self.width, self.height)
        return 0.5 * math.hypot(self.width, self.height)

    def frame(self) -> np.ndarray:
        """(3, 3) float64: columns are the scene directions of the image right, image top, axis."""
        ch, sh = _cos_sin_deg(self.heading_deg)
        top = np.array([ch, sh, 0.0])
        axis = np.array([0.0, 0.0, 1.0 if self.looking == "up" else -1.0])
        base = np.stack([np.cross(axis, top), top, axis], axis=1)
        sign = 1.0 if self.looking == "up" else -1.0  # "toward tilt_azimuth" for either axis
        return _tilt_rotation(sign * self.tilt_deg, self.tilt_azimuth_deg) @ base

    def azimuth_axes(self) -> np.ndarray:
        """(2, 3): the scene directions φ = 0° and φ = 90° (+x and +y, tilted with the camera)."""
        sign = 1.0 if self.looking == "up" else -1.0
        rot = _tilt_rotation(sign * self.tilt_deg, self.tilt_azimuth_deg)
        return rot[:, :2].T.copy()

    def image_xy(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Image-plane offsets (x right, y up) in pixels of continuous pixel coordinates
        (``col``, ``row``; (0, 0) is the top-left corner, pixel centres at +0.5)."""
        cx, cy = self.centre_px if self.centre_px is not None else (0.5 * self.width, 0.5 * self.height)
        return np.asarray(col, np.float64) - cx, cy - np.asarray(row, np.float64)

    def camera_directions(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame unit directions (..., 3) and ρ of pixel coordinates, float64 (ρ clamped to 1)."""
        x, y = self.image_xy(col, row)
        r = np.hypot(x, y)
        rho = np.minimum(r / self.radius_px, 1.0)
        s, c = self.lens.sin_cos(rho)
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(r > 0, x / r, 0.0)
            uy = np.where(r > 0, y / r, 0.0)
        return np.stack([s * ux, s * uy, c], axis=-1), r / self.radius_px

    def directions(self, col, row) -> np.ndarray:
        """Scene unit directions (..., 3) of pixel coordinates, float64 (the plugin's reference)."""
        d, _ = self.camera_directions(col, row)
        return d @ self.frame().T

    def pixel_angles(self, row0: int = 0, row1: int | None = None) -> "PixelAngles":
        """θ, φ and solid angle of every pixel centre of rows ``row0:row1`` (float64)."""
        rows, cols = np.mgrid[row0:self.height if row1 is None else row1, 0:self.width]
        d, rho = self.camera_directions(cols + 0.5, rows + 0.5)
        inside = rho <= 1.0
        theta = self.lens.theta(np.where(inside, rho, np.nan))
        b = self.azimuth_axes() @ self.frame()  # φ axes in the camera frame
        phi = np.degrees(np.arctan2(d @ b[1], d @ b[0])) % 360.0
        sin_t = np.sin(theta)
        d0 = float(self.lens.drho_dtheta(0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(rho > 1e-12, sin_t / rho, 1.0 / d0)  # sin θ / ρ → 1/ρ′(0) at the centre
            omega = ratio / (self.lens.drho_dtheta(theta) * self.radius_px ** 2)
        omega = np.where(inside, omega, 0.0)
        return PixelAngles(np.where(inside, np.degrees(theta), np.nan), np.where(inside, phi, np.nan),
                           omega, inside)

    def to_dict(self) -> dict:
        return {"lens": self.lens.to_dict(), "width": self.width, "height": self.height,
                "position_m": [float(v) for v in self.position_m], "format": self.format,
                "looking": self.looking, "tilt_deg": self.tilt_deg,
                "tilt_azimuth_deg": self.tilt_azimuth_deg, "heading_deg": self.heading_deg,
                "radius_px": self.radius_px,
                "centre_px": None if self.centre_px is None else [float(v) for v in self.centre_px]}


def _number(value, key: str, lo: float, hi: float) -> float:
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and lo <= value <= hi):
        raise ConfigError(f"must be a number in [{lo:g}, {hi:g}]", key=key, value=value)
    return float(value)


def make_fisheye(position_m, *, projection: str | Lens = "equidistant", coeffs=None,
                 resolution: int = 1024, format: str = "circular", looking: str = "up",
                 tilt_deg: float = 0.0, tilt_azimuth_deg: float = 0.0,
                 heading_deg: float = 90.0) -> FisheyeCamera:
    """A :class:`FisheyeCamera`, checked.  ``resolution``: the side of a circular image, the
    width of a full-frame one (height = width / 1.5)."""
    lens = make_lens(projection, coeffs)
    if format not in FORMATS:
        raise ConfigError(f"unknown format; valid: {', '.join(FORMATS)}", key="fisheye.format", value=format)
    if looking not in LOOKING:
        raise ConfigError(f"valid: {', '.join(LOOKING)}", key="fisheye.looking", value=looking)
    if not (isinstance(resolution, numbers.Integral) and not isinstance(resolution, bool) and resolution >= 8):
        raise ConfigError("must be an integer ≥ 8 pixels", key="fisheye.resolution", value=resolution)
    pos = np.asarray(position_m, np.float64).ravel()
    if pos.shape != (3,) or not np.all(np.isfinite(pos)):
        raise ConfigError("camera position must be 3 finite numbers (x, y, z), metres",
                          key="fisheye.position_m", value=list(np.ravel(position_m)))
    width = int(resolution)
    height = width if format == "circular" else max(1, int(round(width / FULLFRAME_ASPECT)))
    return FisheyeCamera(lens, width, height, pos, format, looking,
                         _number(tilt_deg, "fisheye.tilt_deg", 0.0, 90.0),
                         _number(tilt_azimuth_deg, "fisheye.tilt_azimuth_deg", -360.0, 360.0),
                         _number(heading_deg, "fisheye.heading_deg", -360.0, 360.0))


@dataclass
class PixelAngles:
    """Per pixel centre: θ and φ in degrees (NaN outside the circle), solid angle in sr (0 outside)."""

    theta_deg: np.ndarray
    azimuth_deg: np.ndarray
    solid_angle_sr: np.ndarray
    inside: np.ndarray


def ring_bounds(rings_deg) -> np.ndarray:
    """(R, 2) ring bounds in degrees from increasing edges or from (lo, hi) pairs."""
    a = np.asarray(rings_deg, np.float64)
    if a.ndim == 1:
        if len(a) < 2 or np.any(np.diff(a) <= 0):
            raise ConfigError("ring edges must increase", key="fisheye.rings_deg", value=a.tolist())
        a = np.stack([a[:-1], a[1:]], axis=1)
    if a.ndim != 2 or a.shape[1] != 2 or np.any(a[:, 1] <= a[:, 0]) or a.min() < 0 or a.max() > 90:
        raise ConfigError("rings must be increasing edges or (lo, hi) pairs within 0–90°",
                          key="fisheye.rings_deg", value=a.tolist())
    return a


@dataclass
class GapTable:
    """Ring × sector gap fractions of one image (module docstring for the weighting).

    Rings hold θ ∈ [lo, hi) (the last bound of 90° inclusive), sectors φ ∈ [lo, hi) degrees.
    Arrays are (R, S) unless said otherwise; NaN gap where a cell holds no pixel.
    """

    ring_lo_deg: np.ndarray
    ring_hi_deg: np.ndarray
    sector_lo_deg: np.ndarray
    sector_hi_deg: np.ndarray
    gap: np.ndarray
    gap_pixels: np.ndarray
    n_pixels: np.ndarray
    solid_angle_sr: np.ndarray
    ring_gap: np.ndarray            # (R,) solid-angle weighted over all sectors
    ring_gap_pixels: np.ndarray     # (R,)
    ring_theta_mean_deg: np.ndarray  # (R,) solid-angle-weighted mean θ

    def rows(self, **extra) -> list[dict]:
        """Long-format rows: one per (ring, sector) and one per ring over all sectors (sector
        ``"all"``, 0–360°)."""
        out = []
        for i in range(len(self.ring_lo_deg)):
            cells = [(j, self.sector_lo_deg[j], self.sector_hi_deg[j]) for j in range(len(self.sector_lo_deg))]
            for j, lo, hi in cells + [(None, 0.0, 360.0)]:
                one = j is not None
                out.append({**extra, "ring": i, "sector": j if one else "all",
                            "ring_lo_deg": self.ring_lo_deg[i], "ring_hi_deg": self.ring_hi_deg[i],
                            "sector_lo_deg": lo, "sector_hi_deg": hi,
                            "theta_mean_deg": self.ring_theta_mean_deg[i],
                            "gap": self.gap[i, j] if one else self.ring_gap[i],
                            "gap_pixels": self.gap_pixels[i, j] if one else self.ring_gap_pixels[i],
                            "n_pixels": int(self.n_pixels[i, j] if one else self.n_pixels[i].sum()),
                            "solid_angle_sr": self.solid_angle_sr[i, j] if one else self.solid_angle_sr[i].sum()})
        return out


TABLE_COLUMNS = ("ring", "sector", "ring_lo_deg", "ring_hi_deg", "sector_lo_deg", "sector_hi_deg", "theta_mean_deg",
                 "gap", "gap_pixels", "n_pixels", "solid_angle_sr")


def gap_table(coverage: np.ndarray, angles: PixelAngles, rings_deg=DEFAULT_RINGS_DEG,
              n_sectors: int = 8, *, sector_offset_deg: float = 0.0) -> GapTable:
    """Ring × sector gap fractions of a coverage image (1 = plant, 0 = gap; NaN ignored)."""
    acc = TableSums(rings_deg, n_sectors, sector_offset_deg)
    acc.add(coverage, angles)
    return acc.table()


class TableSums:
    """Sums behind a :class:`GapTable`, added block by block (a large photo in strips)."""

    def __init__(self, rings_deg=DEFAULT_RINGS_DEG, n_sectors: int = 8, sector_offset_deg: float = 0.0):
        self.bounds = ring_bounds(rings_deg)
        if not (isinstance(n_sectors, numbers.Integral) and n_sectors >= 1):
            raise ConfigError("must be an integer ≥ 1", key="fisheye.n_sectors", value=n_sectors)
        self.S, self.offset = int(n_sectors), float(sector_offset_deg)
        shape = (len(self.bounds), self.S)
        self.n = np.zeros(shape, np.int64)
        self.wsum, self.wgap, self.gsum, self.wth = (np.zeros(shape) for _ in range(4))

    def add(self, coverage: np.ndarray, angles: PixelAngles) -> None:
        cov = np.asarray(coverage, np.float64)
        th, ph, w = angles.theta_deg, angles.azimuth_deg, angles.solid_angle_sr
        ok = angles.inside & np.isfinite(cov)
        S, width = self.S, 360.0 / self.S
        sector = np.minimum(((ph - self.offset) % 360.0) // width, S - 1)
        top = self.bounds[:, 1].max()
        for i, (lo, hi) in enumerate(self.bounds):
            sel = ok & (th >= lo) & ((th < hi) | ((hi == top) & (th <= hi)))
            s = sector[sel].astype(np.int64)
            g = 1.0 - cov[sel]
            self.n[i] += np.bincount(s, minlength=S)
            self.wsum[i] += np.bincount(s, w[sel], minlength=S)
            self.wgap[i] += np.bincount(s, w[sel] * g, minlength=S)
            self.gsum[i] += np.bincount(s, g, minlength=S)
            self.wth[i] += np.bincount(s, w[sel] * th[sel], minlength=S)

    def table(self) -> GapTable:
        with np.errstate(invalid="ignore", divide="ignore"):
            gap = self.wgap / self.wsum
            gap_pixels = self.gsum / self.n
            ring_gap = self.wgap.sum(1) / self.wsum.sum(1)
            ring_gap_pixels = self.gsum.sum(1) / self.n.sum(1)
            theta_mean = self.wth.sum(1) / self.wsum.sum(1)
        width = 360.0 / self.S
        lo = (self.offset + width * np.arange(self.S)) % 360.0  # hi may pass 360: a sector across +x
        return GapTable(self.bounds[:, 0].copy(), self.bounds[:, 1].copy(), lo, lo + width,
                        gap, gap_pixels, self.n.copy(), self.wsum.copy(), ring_gap, ring_gap_pixels,
                        theta_mean)


@dataclass
class FisheyeImage:
    """One rendered fisheye image: coverage (H, W) float32 in [0, 1], NaN outside the circle."""

    coverage: np.ndarray
    camera: FisheyeCamera
    angles: PixelAngles = field(repr=False)
    spp: int = 4
    seconds: float = 0.0
    seed: int = 0
    jitter: bool = False

    def table(self, rings_deg=DEFAULT_RINGS_DEG, n_sectors: int = 8, *,
              sector_offset_deg: float = 0.0) -> GapTable:
        return gap_table(self.coverage, self.angles, rings_deg, n_sectors,
                         sector_offset_deg=sector_offset_deg)

    def labels(self) -> np.ndarray:
        """uint8 display labels: 0 gap, 1 plant (coverage ≥ 0.5), 2 outside the circle."""
        lab = np.where(self.coverage >= 0.5, 1, 0).astype(np.uint8)
        lab[~self.angles.inside] = 2
        return lab


def render_fisheye(built, camera: FisheyeCamera, *, spp: int = 4, seed: int = 0, jitter: bool = False,
                   variant: str | None = None, integrator=None) -> FisheyeImage:
    """Render ``camera``'s coverage image of ``built`` (a :class:`~simlidar_mi.scene.build.BuiltScene`)."""
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415
    if camera.centre_px is not None or camera.circle_radius_px is not None:
        raise ConfigError("a rendered fisheye image is centred, its circle set by its format",
                          key="fisheye.format", value=camera.format)
    if not (isinstance(spp, numbers.Integral) and not isinstance(spp, bool) and spp >= 1):
        raise ConfigError("samples per pixel must be an integer ≥ 1", key="fisheye.spp", value=spp)
    mi = mitsuba(variant)
    lens = camera.lens
    sensor = mi.load_dict({
        "type": "fisheye",
        "projection": lens.name or lens.projection,
        "coeffs": ",".join(repr(k) for k in lens.coeffs) if lens.projection == "polynomial" and not lens.name else "",
        "radius_px": float(camera.radius_px),
        "film": {"type": "hdrfilm", "width": int(camera.width), "height": int(camera.height),
                 "pixel_format": "luminance", "rfilter": {"type": "box"}},
        "sampler": {"type": "independent", "sample_count": int(spp)}})
    sensor.set_frame(camera.position_m - np.asarray(built.origin_m, np.float64), camera.frame())
    if integrator is None:
        integrator = mi.load_dict({"type": "coverage", "jitter": bool(jitter)})
    t0 = time.perf_counter()
    cov = integrator.coverage(built.scene, sensor, seed=int(seed), spp=int(spp))
    seconds = time.perf_counter() - t0
    angles = camera.pixel_angles()
    cov = np.where(angles.inside, cov, np.nan).astype(np.float32)
    return FisheyeImage(cov, camera, angles, int(spp), seconds, int(seed), bool(jitter))



def gap_runs(coverage: np.ndarray, camera: FisheyeCamera, theta_deg: float, *, n: int = 3600,
             threshold: float = 0.5) -> np.ndarray:
    """Azimuthal lengths (radians of φ) of the gap runs around the circle θ = ``theta_deg``.

    The circle is sampled at ``n`` evenly spaced azimuths, each reading the pixel it falls in
    (gap where coverage < ``threshold``); runs wrap around 360°.  φ and the image angle differ by
    a rotation (and, looking up, a reflection) about the axis, so lengths are the same in either;
    multiply by sin θ for arc lengths on the unit sphere (Chen–Cihlar gap sizes)."""
    rho = float(camera.lens.rho(math.radians(theta_deg)))
    if not 0.0 < rho <= 1.0:
        raise ConfigError("θ must lie inside the image circle", key="theta_deg", value=theta_deg)
    psi = (np.arange(n) + 0.5) * (2 * math.pi / n)
    r = rho * camera.radius_px
    cx, cy = camera.centre_px if camera.centre_px is not None else (0.5 * camera.width, 0.5 * camera.height)
    col = np.clip(np.floor(cx + r * np.cos(psi)).astype(int), 0, camera.width - 1)
    row = np.clip(np.floor(cy - r * np.sin(psi)).astype(int), 0, camera.height - 1)
    gap = np.asarray(coverage)[row, col] < threshold
    if gap.all():
        return np.array([2 * math.pi])
    gap = np.roll(gap, -int(np.argmin(gap)))  # start on plant: no run is cut by the wrap
    edges = np.diff(np.r_[0, gap.astype(np.int8), 0])
    return (np.nonzero(edges == -1)[0] - np.nonzero(edges == 1)[0]) * (2 * math.pi / n)
