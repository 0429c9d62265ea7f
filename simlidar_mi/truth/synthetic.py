"""Canopies of known plant area density for checking estimators (tests, BENCHMARKS §10d).

``turbid_beams``
    beams through an ideal turbid medium (Ross 1981): PAD uniform in a box, elements
    infinitely small and spherically oriented, so a beam's free path is exponential
    with rate G·PAD, G = 0.5 in every direction. The estimator sees nothing but its
    own statistics; its errors are the sampling errors of the estimator itself.
``leaf_box_scan``
    a real scan (Mitsuba, the tractor's beams) of random flat leaves with spherical
    leaf angles (:func:`simlidar_mi.plants.random_leaves.random_leaves`) filling a box:
    finite leaves, periodic plot, PAD = N·a/V on average.
"""
from __future__ import annotations

import numpy as np

from .grid import VoxelGrid
from .traverse import Beams

__all__ = ["turbid_beams", "leaf_box_scan"]


def turbid_beams(n: int, pad_m2_m3: float, seed: int, *, G: float = 0.5, box_m=(1.0, 1.0, 1.0),
                 spread_deg: float = 30.0, escape_m: float = 100.0) -> Beams:
    """``n`` beams from the plane x = −1 m towards +x (directions within ±``spread_deg``
    in azimuth and elevation) through a turbid medium of ``pad_m2_m3`` filling the box
    [0, bx] × [0, by] × [0, bz]; first returns where the exponential free path ends."""
    rng = np.random.default_rng(seed)
    bx, by, bz = box_m
    o = np.column_stack([np.full(n, -1.0), rng.uniform(-0.5 * by, 1.5 * by, n), rng.uniform(-0.5 * bz, 1.5 * bz, n)])
    th, ph = np.deg2rad(rng.uniform(-spread_deg, spread_deg, (2, n)))
    d = np.column_stack([np.cos(th) * np.cos(ph), np.sin(th) * np.cos(ph), np.sin(ph)])
    with np.errstate(divide="ignore"):
        a, b = (0.0 - o) / d, (np.asarray(box_m) - o) / d
    t_in = np.maximum(np.minimum(a, b).max(1), 0.0)
    t_out = np.maximum(a, b).min(1)
    s = rng.exponential(1.0 / (G * pad_m2_m3), n)
    hit = (t_in < t_out) & (s < t_out - t_in)
    return Beams.first_return(o, d, np.where(hit, t_in + s, escape_m), np.where(hit, 3, 0))


def leaf_box_scan(n_leaves: int = 2000, leaf_area_m2: float = 0.001, *, seed: int = 1,
                  dy_m: float = 0.01, dtheta_deg: float = 0.2, voxel_m: float = 0.25,
                  variant: str | None = None):
    """Scan random spherical leaves in the unit cube [0, 1]³ (PAD = N·a on average) from a
    tractor at x = −1 m, z = 0.5 m. Returns (beams, grid over the cube, leaf-centre PAD
    per voxel, canopy): each leaf's area is counted in the voxel of its centre (leaves
    of side √a ≪ voxel; the exact clipped truth is :func:`simlidar_mi.truth.voxelize.compute_truth`)."""
    from ..geometry import Branches  # noqa: PLC0415
    from ..lidar.scan import ScanSettings, scan  # noqa: PLC0415
    from ..plants.random_leaves import random_leaves  # noqa: PLC0415
    from ..scene.build import build_scene  # noqa: PLC0415
    from .estimators import beams_from_scan  # noqa: PLC0415
    canopy = random_leaves(n_leaves, leaf_area_m2, (1.0, 1.0), (0.0, 1.0), "spherical", "square", seed=seed)
    th_max = float(np.degrees(np.arctan(0.5 / 1.0)))  # the near face's corners, z 0 … 1
    n_ang = int(np.floor(2 * th_max / dtheta_deg + 1e-9))
    n_pos = int(np.floor(0.9 / dy_m + 1e-9))
    s = ScanSettings(-1.0, 0.5, 0.05, dy_m, 0, n_pos, -th_max, dtheta_deg, n_ang, ground=False)
    built = build_scene(Branches.empty(), canopy.leaves, [], variant=variant,
                        scanner_m=np.array([[-1.0, 0.0, 0.5], [-1.0, 1.0, 0.5]]))
    result = scan(built, s, variant)
    grid = VoxelGrid((0.0, 0.0, 0.0), voxel_m, tuple([int(round(1.0 / voxel_m))] * 3))
    ijk, inside = grid.index(canopy.centres_m)
    area = np.zeros(grid.shape)
    np.add.at(area, tuple(ijk[inside].T), leaf_area_m2)
    return beams_from_scan(result), grid, area / grid.voxel_volume_m3, canopy
