"""Canopies for gap fraction: leaves over a plot, their exact E[P0], those a scene file describes.

A :class:`Canopy` is what every gap-fraction piece looks at (:mod:`.cameras`,
:mod:`.windows`, :mod:`.gapfraction`); :func:`canopies_from_config` turns a scene
file's ``[random_leaves]`` or ``[strawberry]`` section into one canopy per
extraction step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import SceneConfig
from ..errors import ConfigError
from ..geometry import Branches, Leaves

__all__ = ["Canopy", "expected_p0", "canopies_from_config", "canopy_from_random_leaves",
           "replicate_seed"]


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


# ----------------------------------------------------------------------- scene file
def replicate_seed(seed: int, replicate: int, stream: int | None = None) -> int | np.random.SeedSequence:
    """Seed of one replicate plot of a scene (``[gapfraction] replicates``).

    Replicate 0 is the scene seed's own plot (``seed``, or ``SeedSequence([seed,
    stream])`` for a side stream such as the extraction's); replicate ``k ≥ 1`` is the
    ``k``-th child that ``SeedSequence(seed).spawn`` (resp. ``SeedSequence([seed,
    stream]).spawn``) hands out, so adding replicates never changes the earlier ones.
    """
    entropy = seed if stream is None else [seed, stream]
    if replicate == 0:
        return seed if stream is None else np.random.SeedSequence(entropy)
    return np.random.SeedSequence(entropy, spawn_key=(int(replicate),))


def canopies_from_config(cfg: SceneConfig, replicate: int = 0) -> list[Canopy]:
    """The canopies a scene file describes: one per extraction step.

    ``[random_leaves]`` gives one periodic canopy; ``[strawberry]`` a plot and its
    extraction steps (``[strawberry] extraction_fractions``, default the shares of the
    starting leaves that follow Table 4's real leaf area, or ``extraction_counts``).  ``replicate`` selects an
    independent plot of the same scene (:func:`replicate_seed`).
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
                               angle_law=r["angle_law"], shape=r["shape"], n_sides=r["n_sides"],
                               seed=replicate_seed(cfg.seed, replicate))
        except ConfigError as exc:
            raise ConfigError(str(exc), file=cfg.source) from exc
        return [canopy_from_random_leaves(rl)]
    from ..plants import strawberry as sb  # noqa: PLC0415
    from ..plants.strawberry_extraction import extraction_steps  # noqa: PLC0415
    s = dict(cfg["strawberry"])
    fractions, counts = s.pop("extraction_fractions"), s.pop("extraction_counts")
    if fractions is not None and counts is not None:
        raise ConfigError("give strawberry.extraction_fractions (shares of the starting leaves) "
                          "or strawberry.extraction_counts (fixed numbers), not both",
                          file=cfg.source, key="strawberry.extraction_counts", value=counts)
    leaf = {k: v for k, v in cfg["strawberry.leaf"].items() if v is not None}
    try:
        plot = sb.strawberry_plot(sb.StrawberryPlotParams(**s, leaf=leaf),
                                  seed=replicate_seed(cfg.seed, replicate))
        # Its own stream: changing the extraction never changes the plot.
        steps = extraction_steps(plot, counts, seed=replicate_seed(cfg.seed, replicate, 1),
                                 fractions=fractions)
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
