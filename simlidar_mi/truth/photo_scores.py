"""``simlidar-mi evaluate-photo``: the gap-fraction LAI methods on a scene, scored against its truth.

Upward-looking sensors at the ``[fisheye]`` positions sample the sky through the scene's
plants: the fisheye camera's images and their solid-angle-weighted ring × sector tables
(:mod:`simlidar_mi.canopy.fisheye`; ``[lai_methods] sampler = "fisheye"``), or ray fans
uniform in solid angle per cell (:mod:`simlidar_mi.canopy.ring_sampler`; ``"rays"``: no
lens, no pixels). Sunfleck transects run along x through the positions, and the
methods of :mod:`simlidar_mi.canopy.lai_methods` and :mod:`simlidar_mi.canopy.lai2200`
turn them into LAI. The exact truth of the same scene (:func:`~simlidar_mi.truth.compute.compute_truth`)
scores them.

Methods (``method`` column)
---------------------------
``miller``        Miller's L_e over ``rings_deg`` (sector-averaged gap fraction).
``miller_lx``     Lang–Xiang's log-averaged LAI over the same rings and sectors, times (1 − α).
``hinge_57``      L_e from the 55–60° ring (57.5° method, G = 0.5).
``lai2200``       The LAI-2200's LAI of each position's reading (five rings, ``view_cap_deg``);
                  at plot scale the instrument's log average over all readings.
``lai2200_le``    Plot scale only: LAI × ACF, the instrument's effective LAI.
``chen_cihlar``   Plot scale only: (1 − α)·mean(L_e of ``miller``)/Ω_CC, Ω_CC from the
                  transects with the leaves' exact shadow width W_p.

Truth (``target`` column: ``LAI`` or ``PAI``)
--------------------------------------------
Footprint of a position for a method whose outermost ring ends at θ_max: in every layer k of
the truth grid above the sensor, the disc of radius ``R_k = (z_k − z_s)·tan θ_max`` around the
position; ``LAI_fp = Σ_k leaf area in the disc_k / (π R_k²)``,
the leaf area per unit ground area of the cone the sensor sees (a homogeneous canopy gives
its LAI). The 57.5° method's footprint is the annulus its 55–60° ring sees. Columns count
by their share of the disc (8 × 8 sample points a voxel);
beyond the grid there is no plant. PAI the same with plant area (leaf + wood/2). Periodic plots (``[random_leaves]``)
are homogeneous by construction: their footprint truth is the plot's LAI above the sensor
(voxel layers whose centre is higher). Plot scale: the
mean footprint truth over the positions. Sensors outside the plants' horizontal extent (outside the
plot of a periodic scene) or above the highest plant are refused, naming the ``[fisheye]`` key that placed them: they would
score the empty sky beside the canopy.

The JSON adds the truth's woody share of the plant area (``wood_to_total_truth``, the α of
the true-LAI correction) and, per ring, the canopy's exact G(θ) (azimuth mean of Σ a_i|n_i·Ω|/Σ a_i over
the scene's leaf triangles, instanced trees' leaves included: :func:`scene_canopy_G`), the measured mean
gap fraction, the Poisson gap fraction ``exp(−G(θ)·L/cos θ)`` of the truth's plot LAI and
Nilson's clumping ``Ω(θ) = −ln P(θ)·cos θ/(G(θ)·L)``: the truth's clumping of the rings. Wood
blocks the sky too, so in a woody canopy that leaf-only Ω can exceed 1; ``omega_nilson_plant``
uses the plot's PAI and the plant G (wood's half-surface at G = 0.5, as
:mod:`simlidar_mi.truth.leaf_g`).

Plot-scale estimates are the mean of the positions' estimates, except the LAI-2200's (the
instrument's log average over its readings) and Chen–Cihlar's. A leaf just above a lens fills
whole rings: their gap fraction is 0 and takes the ``zero_gap`` floor (a PAI of 10 by default),
so sensors inside the canopy (a crop scene's lens at the ground) read high; in the field the lens
goes below the lowest leaves.

Scores per method, target and scale: n, coverage (share of positions with a finite
estimate), bias and RMSE of estimate − truth, the means (``photo_scores.csv``/``.json``),
one row per position and method (``photo_positions.csv``) and ``photo_scores.png``.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..canopy import lai2200 as li
from ..canopy import lai_methods as lm
from ..canopy import lai_table as lt
from ..canopy import ring_sampler as rs
from ..errors import ConfigError
from ..io.atomic import atomic_file, staged_dir, write_csv, writes_output
from .grid import VoxelGrid
from .leaf_g import projection_G

__all__ = ["PhotoRun", "RadialSums", "footprint_index", "canopy_G", "scene_canopy_G", "ray_sampler", "fisheye_sampler", "score_positions",
           "evaluate_photo", "PHOTO_OUTPUTS", "METHODS"]

PHOTO_OUTPUTS = (r"photo_scores\.(csv|json|png)", r"photo_positions\.csv")
METHODS = ("miller", "miller_lx", "hinge_57", "lai2200", "lai2200_le", "chen_cihlar")
HINGE_RING_DEG = lt.HINGE_RING_DEG
SCORE_FIELDS = ("method", "target", "scale", "n", "coverage", "bias", "rmse", "truth_mean",
                "estimate_mean")


@dataclass
class PhotoRun:
    """Scores (rows of photo_scores.csv), per-position rows, the summary and the files."""

    scores: list[dict]
    positions: list[dict]
    summary: dict
    files: dict[str, Path] = field(default_factory=dict)

    def get(self, method: str, target: str = "LAI", scale: str = "position") -> dict:
        for row in self.scores:
            if (row["method"], row["target"], row["scale"]) == (method, target, scale):
                return row
        raise KeyError(f"no score for {method!r}, {target!r}, {scale!r}")


class RadialSums:
    """Each layer's plant area binned by the distance of its column centres from a position.

    Bins are a quarter voxel wide; ``sum_over`` reads a layer's area within a radius range
    as a cumulative-sum difference, so one position serves every method's footprint.
    """

    def __init__(self, grid: VoxelGrid, area: np.ndarray, position_m):
        cx, cy, cz = grid.corner_m
        v = grid.voxel_m
        nx, ny, nz = grid.shape
        xc = cx + (np.arange(nx) + 0.5) * v
        yc = cy + (np.arange(ny) + 0.5) * v
        self.z = cz + (np.arange(nz) + 0.5) * v
        self.pz = float(position_m[2])
        self.bin_m = 0.25 * v
        r = np.sqrt((xc[:, None] - position_m[0]) ** 2 + (yc[None, :] - position_m[1]) ** 2).ravel()
        idx = (r / self.bin_m).astype(np.int64)
        nb = int(idx.max()) + 2
        h = np.empty((nb, nz))
        for k in range(nz):   # a layer at a time: bincount adds its columns in (x, y) order from
            # 0, the additions np.add.at made over the (x·y, z) copy of the whole grid
            h[:, k] = np.bincount(idx, np.asarray(area[:, :, k], float).ravel(), minlength=nb)
        self.cum = np.vstack([np.zeros((1, nz)), np.cumsum(h, axis=0)])  # cum[i]: bins < i

    def sum_over(self, layers, t_in: float, t: float) -> float:
        """``Σ_k area(r_in,k ≤ r < R_k) / (π (R_k² − r_in,k²))`` over ``layers``."""
        dz = self.z[layers] - self.pz
        rk, rin = dz * t, dz * t_in
        n = self.cum.shape[0] - 1
        hi = np.minimum(np.floor(rk / self.bin_m).astype(np.int64) + 1, n)
        lo = np.minimum(np.floor(rin / self.bin_m).astype(np.int64), n) if t_in > 0 else np.zeros_like(hi)
        got = self.cum[hi, layers] - self.cum[lo, layers]
        return float(np.sum(got / (math.pi * (rk ** 2 - rin ** 2))))


def footprint_index(grid: VoxelGrid, area: np.ndarray, position_m, theta_max_deg: float,
                    supersample: int = 8, theta_min_deg: float = 0.0, *,
                    radial: RadialSums | None = None) -> float:
    """``Σ_k area in disc_k / area of disc_k`` over the layers above the sensor (module docstring).

    A disc under ten voxels across counts each column by its share of the disc, measured on
    ``supersample²`` points per voxel; one under two voxels is normalised by its sampled area
    (so it still reads the column it lies in). A larger disc counts the columns whose centre
    it holds (in quarter-voxel distance bins, :class:`RadialSums`; error ~ voxel/radius) and
    is normalised by π R²: the part beyond the grid is bare ground. ``radial`` reuses one
    position's :class:`RadialSums` of the same ``area``. With ``theta_min_deg`` > 0 the footprint is the annulus between the two view
    zeniths.
    """
    cx, cy, cz = grid.corner_m
    v = grid.voxel_m
    nx, ny, nz = grid.shape
    zc = cz + (np.arange(nz) + 0.5) * v
    px, py, pz = (float(c) for c in position_m)
    t = math.tan(math.radians(theta_max_deg))
    t_in = math.tan(math.radians(theta_min_deg))
    sub = (np.arange(supersample) + 0.5) / supersample
    layers = np.flatnonzero(zc > pz)
    big = layers[(zc[layers] - pz) * (t - t_in) >= 5 * v]
    total = 0.0
    if big.size:
        rad = radial if radial is not None else RadialSums(grid, area, position_m)
        total += rad.sum_over(big, t_in, t)
    for k in np.setdiff1d(layers, big):
        rk = (zc[k] - pz) * t
        i0 = max(0, int(math.floor((px - rk - cx) / v)))
        i1 = min(nx, int(math.floor((px + rk - cx) / v)) + 1)
        j0 = max(0, int(math.floor((py - rk - cy) / v)))
        j1 = min(ny, int(math.floor((py + rk - cy) / v)) + 1)
        if i1 <= i0 or j1 <= j0:
            continue
        xs = cx + (np.arange(i0, i1)[:, None] + sub[None, :]).ravel() * v
        ys = cy + (np.arange(j0, j1)[:, None] + sub[None, :]).ravel() * v
        r2 = (xs[:, None] - px) ** 2 + (ys[None, :] - py) ** 2
        r_in = (zc[k] - pz) * t_in
        inside = (r2 <= rk * rk) & (r2 >= r_in * r_in)
        w = inside.reshape(i1 - i0, supersample, j1 - j0, supersample).mean(axis=(1, 3))
        if not w.any() and theta_min_deg > 0:
            continue
        if not w.any():  # a disc between the sample points: the column under the sensor
            w = np.zeros_like(w)
            w[min(max(int((px - cx) // v) - i0, 0), i1 - i0 - 1),
              min(max(int((py - cy) // v) - j0, 0), j1 - j0 - 1)] = 1.0
        # A disc of a few voxels is normalised by its sampled area, a larger one by π R², so
        # that the part of it beyond the grid (no plants there) counts as bare ground.
        disc = math.pi * (rk * rk - r_in * r_in) if rk - r_in >= 2 * v else float(w.sum()) * v * v
        total += float((area[i0:i1, j0:j1, k] * w).sum()) / disc
    return total


def canopy_G(triangles: np.ndarray, zenith_deg, n_azimuth: int = 72) -> np.ndarray:
    """Azimuth-mean G(θ) of leaf triangles ``(m, 3, 3)``: ``Σ a_i |n_i·Ω| / Σ a_i``."""
    v = np.asarray(triangles, float).reshape(-1, 3, 3)
    if not len(v):
        return np.full(np.shape(zenith_deg), np.nan)
    va = 0.5 * np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # vector areas a_i n_i
    th = np.radians(np.asarray(zenith_deg, float)).reshape(-1, 1)
    ph = (np.arange(n_azimuth) + 0.5) * 2 * math.pi / n_azimuth
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph),
                  np.broadcast_to(np.cos(th), (len(th), n_azimuth))], -1).reshape(-1, 3)
    g = projection_G(va, d)  # in blocks of leaves: memory bounded however many triangles
    return g.reshape(len(th), n_azimuth).mean(axis=1).reshape(np.shape(zenith_deg))


def scene_canopy_G(geometry, zenith_deg, n_azimuth: int = 72) -> np.ndarray:
    """G(θ) of all a scene's leaves: its own triangles and its instanced trees'.

    An instance turns its prototype about z (yaw) and scales it: the azimuth mean of
    ``|n·Ω|`` does not depend on the yaw (to the ``n_azimuth`` quadrature's steps) nor on the
    scale, so each prototype's :func:`canopy_G` enters weighted by the leaf area its placements
    hold (its area × Σ scale²). The cost grows with the triangles built, not those placed."""
    parts = []
    if len(geometry.leaves):
        v = geometry.leaves.vertices
        parts.append((_leaf_area(v), canopy_G(v, zenith_deg, n_azimuth)))
    inst = geometry.instances
    if inst is not None and len(inst):
        w = np.bincount(np.asarray(inst.proto_index, np.int64), weights=np.asarray(inst.scale, float) ** 2,
                        minlength=len(inst.prototypes))
        for k, (_, lv) in enumerate(inst.prototypes):
            if w[k] > 0 and lv is not None and len(lv):
                parts.append((w[k] * _leaf_area(lv.vertices), canopy_G(lv.vertices, zenith_deg, n_azimuth)))
    total = sum(a for a, _ in parts)
    if not parts or total <= 0:
        return np.full(np.shape(zenith_deg), np.nan)
    if len(parts) == 1:     # a scene without instances: its canopy_G, bit for bit
        return parts[0][1]
    return sum(a * g for a, g in parts) / total


def _leaf_area(v) -> float:
    v = np.asarray(v, float).reshape(-1, 3, 3)
    return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())


def ray_sampler(built, positions_m, n_sectors: int, rays_per_cell: int, seed: int = 0):
    """``sample(rings) -> (gaps (n, R, S), n_per_cell)`` by ray fans (:func:`ring_sampler.ring_sector_gaps`)."""
    def sample(rings):
        return (rs.ring_sector_gaps(built, positions_m, rings, n_sectors, rays_per_cell, seed=seed),
                np.full((len(positions_m), len(rings), n_sectors), float(rays_per_cell)))
    return sample


def fisheye_sampler(built, cameras, n_sectors: int, *, spp: int = 4, seed: int = 0, progress=None):
    """``sample(rings) -> (gaps, n_pixels)`` from one rendered fisheye image per camera.

    ``gaps`` are the images' solid-angle-weighted cell gap fractions (``GapTable.gap``). Each
    image is tabulated as soon as it is rendered and dropped: memory holds one image, however
    many positions.
    """
    from ..canopy.fisheye import render_fisheye  # noqa: PLC0415  (imports Mitsuba)

    def sample(rings):
        gaps, npix = [], []
        for k, cam in enumerate(cameras):
            t = render_fisheye(built, cam, spp=spp, seed=seed).table(rings, n_sectors)
            gaps.append(t.gap)
            npix.append(t.n_pixels)
            if progress:
                progress(k + 1, len(cameras))
        return np.stack(gaps), np.stack(npix).astype(float)
    return sample


def score_positions(sample, built, positions_m: np.ndarray, settings: dict, *, truth_lai, truth_pai,
                    plot_lai: float, plot_pai: float | None = None, leaf_triangles=None, leaf_groups=None,
                    transect_x_m=None, canopy_g=None) -> PhotoRun:
    """Run every method at ``positions_m`` and score them.

    ``sample(rings)`` gives each position's gap fraction per ring and sector and the pixels
    (or rays) in each cell (:func:`ray_sampler`, :func:`fisheye_sampler`); ``built`` casts
    the sunfleck transects.

    ``truth_lai(position, theta_min_deg, theta_max_deg)`` and ``truth_pai(...)`` give the
    footprint truth;
    ``plot_lai`` is the truth's plot LAI (for G·L and Nilson's Ω); ``leaf_triangles``
    (and their leaf ``leaf_groups``) give G(θ) and W_p; ``canopy_g(zenith_deg)``, when given,
    gives G(θ) instead (:func:`scene_canopy_G`: with the instanced trees' leaves); ``transect_x_m`` = (x0, x1) of the
    sunfleck transects (one per distinct position y).
    """
    s = settings
    hemi = lt.hemisphere_rings(s["rings_deg"])
    rings = lt.method_rings(s["rings_deg"])
    n_h = len(hemi)
    floor = {"zero_gap": s["zero_gap"], "pai_sat": float(s["pai_sat"])}
    alpha = float(s["wood_to_total"])
    t0 = time.perf_counter()
    gaps, npix = sample(rings)
    view = lt.method_views(s["rings_deg"])
    estimates, readings, read_px = lt.estimate_methods(gaps, npix, s)
    pix = lt.pixel_floor(s)
    rows = []
    for i, (pos, est) in enumerate(zip(positions_m, estimates)):
        for m, e in est.items():
            rows.append({"position": i, "x_m": pos[0], "y_m": pos[1], "z_m": pos[2], "method": m,
                         "estimate": e, "LAI_fp": truth_lai(pos, *view[m]),
                         "PAI_fp": truth_pai(pos, *view[m])})
    # Plot scale.
    plot = {m: float(np.mean([r["estimate"] for r in rows if r["method"] == m])) for m in view}
    ins = lt.lai2200_of(readings, read_px, s)
    plot["lai2200"], plot["lai2200_le"] = ins.lai, ins.lai_effective
    cc = None
    if transect_x_m is not None:
        lam, tot = [], 0.0
        for y in np.unique(positions_m[:, 1]):
            seg, t = rs.transect_gaps(built, [transect_x_m[0], y, positions_m[0, 2]],
                                      [transect_x_m[1], y, positions_m[0, 2]], s["transect_step_m"],
                                      s["sun_zenith_deg"], s["sun_azimuth_deg"])
            lam.append(seg)
            tot += t
        wp = (lm.projected_element_width(leaf_triangles, s["sun_zenith_deg"], s["sun_azimuth_deg"], 0.0,
                                         groups=leaf_groups) if leaf_triangles is not None and
              len(leaf_triangles) else None)
        cc = lm.chen_cihlar(np.concatenate(lam), tot, element_width=wp)
        plot["chen_cihlar"] = lm.true_lai(plot["miller"], cc.omega, wood_to_total=alpha) \
            if math.isfinite(cc.omega) and cc.omega > 0 else float("nan")
    plot_truth = {}
    for m in plot:
        key = m if m in view else ("lai2200" if m.startswith("lai2200") else "miller")
        sel = [r for r in rows if r["method"] == key]
        plot_truth[m] = (float(np.mean([r["LAI_fp"] for r in sel])), float(np.mean([r["PAI_fp"] for r in sel])))
    scores = []
    for m in METHODS:
        sel = [r for r in rows if r["method"] == m]
        for target in ("LAI", "PAI"):
            if sel:
                scores.append(_score(m, target, "position", [r["estimate"] for r in sel],
                                     [r[f"{target}_fp"] for r in sel]))
            if m in plot:
                scores.append(_score(m, target, "plot", [plot[m]], [plot_truth[m][target == "PAI"]]))
    # Rings: the canopy's exact G, measured P, the Poisson P of the truth, Nilson's Ω.
    centres = np.array([0.5 * (a + b) for a, b in rings])
    with np.errstate(invalid="ignore"):
        p_mean = np.nansum(gaps * npix, axis=(0, 2)) / npix.sum(axis=(0, 2))
    if canopy_g is not None:
        G = canopy_g(centres)
    else:
        G = canopy_G(leaf_triangles, centres) if leaf_triangles is not None else np.full(len(rings), np.nan)
    cos_c = np.cos(np.radians(centres))
    pai = plot_lai if plot_pai is None else plot_pai
    # Plant G: the wood's half-surface counts with G = 0.5 (random cylinders; truth.leaf_g).
    Gp = (plot_lai * G + 0.5 * (pai - plot_lai)) / pai if pai > 0 else G
    ring_rows = [{"ring_lo_deg": a, "ring_hi_deg": b, "G_truth": float(G[j]), "P_measured": float(p_mean[j]),
                  "P_poisson_truth": float(np.exp(-G[j] * plot_lai / cos_c[j])),
                  "omega_nilson": float(lm.nilson_clumping(centres[j], p_mean[j], G[j], plot_lai)),
                  "G_plant_truth": float(Gp[j]),
                  "omega_nilson_plant": float(lm.nilson_clumping(centres[j], p_mean[j], Gp[j], pai))}
                 for j, (a, b) in enumerate(rings)]
    summary = {"plot_lai_truth": plot_lai, "plot_pai_truth": pai, "rings": ring_rows,
               "lai2200": {"lai": ins.lai, "acf": ins.acf, "lai_effective": ins.lai_effective, "difn": ins.difn,
                           "view_cap_deg": s["view_cap_deg"], "heading_deg": s["heading_deg"]},
               "lang_xiang_plot": lm.lang_xiang(hemi, gaps[:, :n_h].transpose(1, 0, 2).reshape(n_h, -1),
                                                **floor, **pix(npix[:, :n_h].transpose(1, 0, 2)
                                                               .reshape(n_h, -1))).omega,
               "chen_cihlar": None if cc is None else {k: getattr(cc, k) for k in (
                   "omega", "fm0", "fmr0", "lp", "wp", "n_removed", "iterations", "converged")},
               "plot_estimates": plot, "settings": {k: s[k] for k in s},
               "seconds": round(time.perf_counter() - t0, 3)}
    return PhotoRun(scores, rows, summary)


def _score(method, target, scale, est, truth) -> dict:
    e = np.asarray(est, float)
    t = np.asarray(truth, float)
    ok = np.isfinite(e) & np.isfinite(t)
    d = e[ok] - t[ok]
    return {"method": method, "target": target, "scale": scale, "n": int(len(e)),
            "coverage": float(ok.mean()) if len(e) else float("nan"),
            "bias": float(d.mean()) if ok.any() else float("nan"),
            "rmse": float(np.sqrt(np.mean(d * d))) if ok.any() else float("nan"),
            "truth_mean": float(t[ok].mean()) if ok.any() else float("nan"),
            "estimate_mean": float(e[ok].mean()) if ok.any() else float("nan")}


def _plot(run: PhotoRun, stage: Path, title: str) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.8))
    fig.suptitle(title)
    for m in ("miller", "miller_lx", "hinge_57", "lai2200"):
        sel = [r for r in run.positions if r["method"] == m]
        ax.scatter([r["LAI_fp"] for r in sel], [r["estimate"] for r in sel], s=14, label=m)
    lims = [0, max([r["LAI_fp"] for r in run.positions] + [r["estimate"] for r in run.positions
                                                            if math.isfinite(r["estimate"])] + [1e-3]) * 1.05]
    ax.plot(lims, lims, "k--", lw=0.8)
    ax.set(xlabel="footprint LAI (truth)", ylabel="estimated LAI", title="per position")
    ax.legend(fontsize=8)
    rings = run.summary["rings"]
    c = [0.5 * (r["ring_lo_deg"] + r["ring_hi_deg"]) for r in rings]
    ax2.plot(c, [r["P_measured"] for r in rings], "o", label="measured (mean of positions)")
    ax2.plot(c, [r["P_poisson_truth"] for r in rings], "x", label="exp(−G·L/cos θ), truth G and L")
    ax2.set(xlabel="ring zenith (°)", ylabel="gap fraction", title="rings")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    with atomic_file(stage / "photo_scores.png") as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _refuse_outside(cfg, positions: np.ndarray, bounds, what: str, top_m: float) -> None:
    """Refuse sensor positions outside the canopy, beside it or above its top ``top_m``: their
    estimates and footprint truths would score the empty sky (once NaN scores and exit 0)."""
    f = cfg["fisheye"]
    if len(positions) and float(positions[:, 2].min()) >= top_m:
        raise ConfigError(f"puts the lenses at z = {positions[0, 2]:.4g} m, above the highest plant (z = "
                          f"{top_m:.4g} m): no canopy above them to score; evaluate-photo scores sensors "
                          "under the canopy", file=cfg.source, key="fisheye.height_m", value=f["height_m"])
    x0, y0, x1, y1 = (float(b) for b in bounds)
    out = np.flatnonzero((positions[:, 0] < x0) | (positions[:, 0] > x1) |
                         (positions[:, 1] < y0) | (positions[:, 1] > y1))
    if not len(out):
        return
    key = {"grid": "fisheye.area_m", "transect": "fisheye.transect_m"}.get(f["layout"], "fisheye.points_m")
    k = int(out[0])
    raise ConfigError(f"{len(out)} of {len(positions)} sensor positions lie outside the {what}, x {x0:.4g} to "
                      f"{x1:.4g} m, y {y0:.4g} to {y1:.4g} m (position {k} at x {positions[k, 0]:.4g}, "
                      f"y {positions[k, 1]:.4g} m); evaluate-photo scores sensors under the canopy",
                      file=cfg.source, key=key, value=f[key.split(".")[1]])


@writes_output("out_dir")
def evaluate_photo(scene, out_dir, overrides=(), *, progress=False) -> PhotoRun:
    """The ``evaluate-photo`` command: virtual hemispherical photographs scored against the truth.

    Computes ``scene``'s truth, renders a fisheye image at each ``[fisheye]`` position, runs the
    gap-fraction LAI methods on it with the ``[lai_methods]`` settings (Miller, 57.5°,
    Lang–Xiang, LAI-2200, Chen–Cihlar with a sun direction) and scores each against the truth's
    LAI and PAI over the camera's footprint and over the plot.

    Parameters
    ----------
    scene : a scene file's path or a loaded :class:`~simlidar_mi.config.SceneConfig`.
    out_dir : photo_scores.csv, photo_scores.json, photo_scores.png and photo_positions.csv are
        written there, all together when complete.
    overrides : ``"section.key=value"`` strings, as ``--set`` takes them.
    progress : see :func:`simlidar_mi._runtime.progress.make_progress`.

    Returns
    -------
    PhotoRun
        ``scores`` (one row per method, target LAI or PAI, and scale ``position`` or
        ``plot``: n, coverage, truth and estimate means, bias, RMSE; :meth:`PhotoRun.get`
        picks one), ``positions`` (per camera), ``summary`` and ``files``.
    """
    from .._runtime.progress import make_progress  # noqa: PLC0415
    from ..canopy.fisheye_run import fisheye_cameras, fisheye_positions, warn_leaves_near_lenses  # noqa: PLC0415
    from ..canopy.canopy import canopies_from_config  # noqa: PLC0415
    from ..canopy.gapfraction import tiled_sky_scene  # noqa: PLC0415
    from ..config import SceneConfig, load_scene  # noqa: PLC0415
    from ..lidar.survey import build  # noqa: PLC0415
    from .compute import leaf_and_plant_area  # noqa: PLC0415
    from .run import PHOTO_BYTES_PER_VOXEL, truth_geometry, truth_grid  # noqa: PLC0415
    cfg = scene if isinstance(scene, SceneConfig) else load_scene(scene, overrides)
    s = dict(cfg["lai_methods"])
    geometry, ground_area = truth_geometry(cfg)
    lo, hi = geometry.bounds_m()
    if cfg["fisheye"]["looking"] != "up":
        raise ConfigError("the LAI methods read sensors looking up", file=cfg.source,
                          key="fisheye.looking", value=cfg["fisheye"]["looking"])
    positions = fisheye_positions(cfg, lo, hi)
    z_s = float(positions[0, 2])
    periodic = cfg.has("random_leaves")
    canopy = canopies_from_config(cfg)[0] if periodic else None
    bounds = canopy.plot_bounds_m if periodic else (lo[0], lo[1], hi[0], hi[1])
    _refuse_outside(cfg, positions, bounds, "plot" if periodic else "plants' horizontal extent", float(hi[2]))
    warn_leaves_near_lenses(cfg, geometry.leaves, positions,
                            (bounds[2] - bounds[0], bounds[3] - bounds[1]) if periodic else None)
    grid = truth_grid(cfg, geometry, bytes_per_voxel=PHOTO_BYTES_PER_VOXEL)
    shown = make_progress(progress)
    # the two arrays scored here, not the truth's six (BENCHMARKS.md §16: 32 bytes a voxel less)
    leaf, plant, truth_lai_attr, truth_pai_attr = leaf_and_plant_area(
        geometry, grid, progress=shown, ground_area_m2=cfg["truth"]["ground_area_m2"] or ground_area)
    if periodic:
        built = tiled_sky_scene(canopy, positions, max(li.RING_BOUNDS_DEG[-1][1], float(s["rings_deg"][-1])),
                                key="lai_methods.rings_deg")
        above = grid.corner_m[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel_m > z_s
        plot_lai = float(leaf[:, :, above].sum() / canopy.plot_area_m2)
        plot_pai = float(plant[:, :, above].sum() / canopy.plot_area_m2)

        def truth_lai(pos, theta_min, theta_max):
            return plot_lai

        def truth_pai(pos, theta_min, theta_max):
            return plot_pai
    else:
        built = build(cfg, geometry)
        plot_lai, plot_pai = truth_lai_attr, truth_pai_attr

        sums: dict = {}

        def _fp(area, name, pos, theta_min, theta_max):
            key = (name, tuple(pos))
            if key not in sums:
                sums[key] = RadialSums(grid, area, pos)
            return footprint_index(grid, area, pos, theta_max, theta_min_deg=theta_min, radial=sums[key])

        def truth_lai(pos, theta_min, theta_max):
            return _fp(leaf, "leaf", pos, theta_min, theta_max)

        def truth_pai(pos, theta_min, theta_max):
            return _fp(plant, "plant", pos, theta_min, theta_max)
    if s["sampler"] == "fisheye":
        sample = fisheye_sampler(built, fisheye_cameras(cfg, lo, hi), s["n_sectors"],
                                 spp=cfg["fisheye"]["spp"], seed=cfg.seed or 0)
    else:
        sample = ray_sampler(built, positions, s["n_sectors"], s["rays_per_cell"], seed=cfg.seed or 0)
    lv = geometry.leaves
    groups = lv.plant_id.astype(np.int64) * (1 << 32) + lv.leaf_id.astype(np.int64)
    with staged_dir(out_dir, PHOTO_OUTPUTS) as stage:
        run = score_positions(sample, built, positions, s, truth_lai=truth_lai, truth_pai=truth_pai,
                              plot_lai=plot_lai, plot_pai=plot_pai,
                              leaf_triangles=lv.vertices if len(lv) else None,
                              leaf_groups=groups, transect_x_m=(bounds[0], bounds[2]),
                              canopy_g=lambda zen: scene_canopy_G(geometry, zen))
        run.summary.update({"scene": cfg.source, "scene_sha256": cfg.sha256, "seed": cfg.seed,
                            "periodic": periodic, "sensor_z_m": z_s,
                            # the α a user would need: the wood's share of the plant area
                            "wood_to_total_truth": float(1.0 - leaf.sum() / plant.sum()) if plant.sum() > 0
                            else float("nan"),
                            "fisheye": {k: cfg["fisheye"][k] for k in cfg["fisheye"]}})
        write_csv(stage / "photo_scores.csv", SCORE_FIELDS, run.scores)
        write_csv(stage / "photo_positions.csv", ("position", "x_m", "y_m", "z_m", "method", "estimate",
                                                  "LAI_fp", "PAI_fp"), run.positions)
        with atomic_file(stage / "photo_scores.json") as tmp:
            Path(tmp).write_text(json.dumps({"scores": run.scores, **run.summary}, indent=1, default=float))
        _plot(run, stage, cfg["scene"]["name"])
    run.files = {n: Path(out_dir) / n for n in ("photo_scores.csv", "photo_scores.json", "photo_scores.png",
                                                "photo_positions.csv")}
    return run
