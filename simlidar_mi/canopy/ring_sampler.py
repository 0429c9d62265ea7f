"""Gap fractions by casting rays: ring/sector tables from points, and sunfleck transects.

Two camera-free samplers on a built Mitsuba scene (:func:`~simlidar_mi.scene.build.build_scene`),
for the LAI methods of :mod:`simlidar_mi.canopy.lai_methods` and the oracles in the tests:

:func:`ring_sector_gaps`
    From each point, rays up (or down) in every zenith ring × azimuth sector cell,
    **stratified uniformly in solid angle** (``cos θ`` and φ on a jittered grid inside the
    cell); a cell's gap fraction is the share of its rays that meet nothing. This is a
    fisheye image's ring/sector table without the lens: what an LAI-2200 ring integrates,
    and what a fisheye's solid-angle-weighted table converges to.
:func:`transect_gaps`
    TRAC-style sunfleck transect (Chen & Cihlar 1995): points every ``step_m`` along a
    ground line, each casting one ray toward the sun direction (θ, φ); the gap lengths in
    metres are the runs of unblocked points times the step.

Directions: θ from the vertical (up-looking: zenith angle), φ counter-clockwise from +x
seen from above (the fisheye API's convention). Coordinates are real (scene) metres; the
scene's float64 origin is subtracted here. Same seed, same rays, same table.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from .lai_methods import gap_lengths

__all__ = ["cell_directions", "ring_sector_gaps", "transect_gaps", "any_hit"]

#: Rays traced per Mitsuba call (bounds the temporaries).
RAYS_PER_CALL = 1 << 21


def cell_directions(zenith_bounds_deg, n_sectors: int, rays_per_cell: int, *, seed: int = 0,
                    looking: str = "up", sector_offset_deg: float = 0.0) -> np.ndarray:
    """Unit directions ``(n_rings, n_sectors, rays_per_cell, 3)``, uniform in solid angle per cell.

    Each cell is split into a ``k × m`` grid (``k·m = rays_per_cell``, k along cos θ) and one
    jittered direction is drawn per stratum.
    """
    b = np.asarray(zenith_bounds_deg, float)
    if b.ndim != 2 or b.shape[1] != 2 or (b[:, 0] < 0).any() or (b[:, 1] > 90).any() \
            or (b[:, 1] <= b[:, 0]).any():
        raise ConfigError("ring bounds must be (low, high) pairs within [0, 90] degrees",
                          key="zenith_bounds_deg", value=b.tolist())
    if int(n_sectors) < 1 or int(rays_per_cell) < 1:
        raise ConfigError("need ≥ 1 sector and ≥ 1 ray per cell", key="rays_per_cell",
                          value=(n_sectors, rays_per_cell))
    if looking not in ("up", "down"):
        raise ConfigError("must be 'up' or 'down'", key="looking", value=looking)
    n = int(rays_per_cell)
    k = max(1, int(round(math.sqrt(n))))
    while n % k:
        k -= 1
    m = n // k
    rng = np.random.default_rng(seed)
    n_r, n_s = len(b), int(n_sectors)
    u = (np.arange(k)[:, None] + rng.uniform(size=(n_r, n_s, k, m))) / k
    v = (np.arange(m)[None, :] + rng.uniform(size=(n_r, n_s, k, m))) / m
    c_lo = np.cos(np.radians(b[:, 0]))[:, None, None, None]
    c_hi = np.cos(np.radians(b[:, 1]))[:, None, None, None]
    cos_t = c_lo + u * (c_hi - c_lo)
    width = 2.0 * math.pi / n_s
    phi = math.radians(sector_offset_deg) + (np.arange(n_s)[None, :, None, None] + v) * width
    sin_t = np.sqrt(np.clip(1.0 - cos_t ** 2, 0.0, None))
    d = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi),
                  cos_t if looking == "up" else -cos_t], axis=-1)
    return d.reshape(n_r, n_s, n, 3)


def any_hit(built, origins_m: np.ndarray, dirs: np.ndarray, *, variant: str | None = None) -> np.ndarray:
    """Whether each ray (real-coordinate origin, unit direction) meets any shape; bool array."""
    from .._runtime.mitsuba import mitsuba  # noqa: PLC0415  (imports Mitsuba)
    mi = mitsuba(variant)
    o = np.asarray(origins_m, np.float64).reshape(-1, 3) - built.origin_m
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    o, d = np.broadcast_arrays(o, d)
    out = np.empty(len(d), bool)
    for s in range(0, len(d), RAYS_PER_CALL):
        oo = np.ascontiguousarray(o[s:s + RAYS_PER_CALL], np.float32)
        dd = np.ascontiguousarray(d[s:s + RAYS_PER_CALL], np.float32)
        ray = mi.Ray3f(mi.Point3f(oo[:, 0], oo[:, 1], oo[:, 2]),
                       mi.Vector3f(dd[:, 0], dd[:, 1], dd[:, 2]))
        out[s:s + RAYS_PER_CALL] = np.asarray(built.scene.ray_test(ray), bool)
    return out


def ring_sector_gaps(built, positions_m, zenith_bounds_deg, n_sectors: int = 8,
                     rays_per_cell: int = 256, *, seed: int = 0, looking: str = "up",
                     sector_offset_deg: float = 0.0, variant: str | None = None) -> np.ndarray:
    """Gap fraction of every cell seen from every point: ``(n_positions, n_rings, n_sectors)``.

    All points share one set of stratified directions (drawn from ``seed``).
    """
    pos = np.asarray(positions_m, np.float64).reshape(-1, 3)
    dirs = cell_directions(zenith_bounds_deg, n_sectors, rays_per_cell, seed=seed,
                           looking=looking, sector_offset_deg=sector_offset_deg)
    shape = dirs.shape[:-1]
    flat = dirs.reshape(-1, 3)
    out = np.empty((len(pos),) + shape[:2])
    for i, p in enumerate(pos):
        hit = any_hit(built, p[None, :], flat, variant=variant).reshape(shape)
        out[i] = 1.0 - hit.mean(axis=-1)
    return out


def transect_gaps(built, start_m, end_m, step_m: float, zenith_deg: float, azimuth_deg: float, *,
                  variant: str | None = None) -> tuple[np.ndarray, float]:
    """Sunfleck gap lengths (metres) along a ground line toward the sun at (θ, φ).

    Returns ``(lengths_m, total_length_m)``: the runs of points whose ray to the sun is
    clear, times ``step_m``, and the number of points times ``step_m``.
    """
    a = np.asarray(start_m, np.float64)
    b = np.asarray(end_m, np.float64)
    if a.shape != (3,) or b.shape != (3,):
        raise ConfigError("transect ends must be (x, y, z) in metres", key="start_m",
                          value=(a.tolist(), b.tolist()))
    if not step_m > 0:
        raise ConfigError("must be > 0", key="step_m", value=step_m)
    if not 0.0 <= zenith_deg < 90.0:
        raise ConfigError("must lie in [0, 90) degrees", key="zenith_deg", value=zenith_deg)
    n = max(1, int(math.floor(np.linalg.norm(b - a) / step_m)))
    t = (np.arange(n) + 0.5) / n
    pts = a + t[:, None] * (b - a)
    th, ph = math.radians(zenith_deg), math.radians(azimuth_deg)
    sun = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    clear = ~any_hit(built, pts, np.broadcast_to(sun, pts.shape), variant=variant)
    return gap_lengths(clear) * float(step_m), n * float(step_m)
