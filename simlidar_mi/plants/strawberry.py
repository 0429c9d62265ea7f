"""Virtual strawberry plants and plots (España Boquera et al., 2014).

The model follows *Modelo informático para la construcción de doseles virtuales de
fresa* (Rev. Mex. Cienc. Agríc., 2014), the "strawberry paper" of the project:

* a **leaf** is three leaflets (a central one and two equal laterals), each a rhomboid
  (kite) of four triangles, 12 triangles a leaf;
* a **plant** is a set of leaves whose petioles start from one point on the ground;
* a **plot** is plants on a row-crop planting grid.

The leaf model (its laws, our reading of the paper's Figure 1 and the paper's
Tables 1–3) is in :mod:`simlidar_mi.plants.strawberry_leaf`; the paper's successive
leaf removals in :mod:`simlidar_mi.plants.strawberry_extraction`.

Geometry only: this module never imports Mitsuba. Lengths are metres, angles are
degrees at the API and radians inside.

Leaf area index and the paper's Table 4
---------------------------------------
LAI is the one-sided leaf area over the planted area ``rows·inter_row_m ×
plants_per_row·intra_row_m`` (:attr:`StrawberryPlot.lai`). A leaf averages
``2.836·E[S] ≈ 37.1 cm²`` (E[S] = 13.10 cm² after truncation), so an even planting at
the paper's Table 3 grid (16.4 plants per m², 42 leaves a plant) gives LAI ≈ 2.6,
about twice Table 4's 1.241 m² of virtual leaves per 1 m² sample: the two tables
conflict for an even planting.  The reading that fits: Table 4 is per m² of ground
*including unplanted space*.  Its virtual canopy lost 47 cm² per removed leaf at
every step ((1.241 − 1.034)/44, (1.034 − 0.849)/39, (0.849 − 0.642)/44), so it held
≈ 264 leaves = 6 plants × 44, and with 47.0 cm² a leaf and the paper's removals
6 × 44 leaves reproduce all four Table 4 values within 0.002 m²; the field's
44 + 39 + 44 = half gives ≈ 254 leaves, ≈ 6 plants of 42.  Why a virtual leaf was
47 cm² when Table 3's S makes it 37 cm² the paper does not say.  Table 3's own values
reproduce Table 4 as well: 8 plants × 42 leaves × 36.94 cm² = 1.2412 m², and removing
56, 50, 56 of them (the field's counts × 1.27) leaves 1.0343, 0.8496, 0.6428 (within
0.0008 m²): one two-row bed of 4 plants a row per 1 m² sample.  Either way a plant
on Table 3's grid carries the paper's virtual leaf area, as ours do.  The gap fraction
was measured in "the central part of the row", i.e. over the planted bed, which is
what an even plot at Table 3's grid models.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..config.checks import real as _real
from ..config.checks import seed_sequence as _root_seed
from ..errors import ConfigError
from ..geometry import Leaves
from .strawberry_leaf import (_MAX_REDRAWS, TRIANGLES_PER_LEAF, StrawberryLeafParams,
                              _check_truncated, _int_at_least, _non_negative, _truncnorm,
                              draw_leaf_traits, leaf_triangles)

__all__ = ["StrawberryPlotParams", "StrawberryPlot", "strawberry_plant", "strawberry_plot"]


# ------------------------------------------------------------------------ parameters
@dataclass(frozen=True)
class StrawberryPlotParams:
    """Planting geometry of a strawberry plot (paper Table 3) and its leaf laws.

    Rows run along ``x``; plants of a row are ``intra_row_m`` apart in ``x`` and rows
    are ``inter_row_m`` apart in ``y``. The planted area is the rectangle
    ``[0, plants_per_row·intra_row_m] × [0, rows·inter_row_m]`` and plant ``(r, j)``
    stands at the centre of its cell, ``((j + ½)·intra_row_m, (r + ½)·inter_row_m)``,
    displaced by an independent normal offset of SD ``intra_row_sd_m/√2`` in ``x`` and
    ``inter_row_sd_m/√2`` in ``y`` so that distances between neighbours have the
    paper's SDs (the difference of two such offsets has the full SD). Offsets are
    truncated to ±0.45 of the spacing (redrawn) so plants stay in their cell.

    Parameters
    ----------
    rows, plants_per_row : int
        Grid size (default 4 × 4: 1.072 m × 0.908 m ≈ the paper's 1 m² sample area).
    inter_row_m, inter_row_sd_m : float
        Distance between rows, metres (0.268 ± 0.03).
    intra_row_m, intra_row_sd_m : float
        Distance between plants of a row, metres (0.227 ± 0.02).
    leaves_per_plant_mean, leaves_per_plant_sd : float
        Leaves per plant (42 ± 5), rounded to an integer ≥ 1.
    base_height_m : float
        Height of the petioles' common start point above the ground (0).
    leaf : StrawberryLeafParams or dict
        Leaf laws; a dict is passed to :class:`StrawberryLeafParams`.
    """

    rows: int = 4
    plants_per_row: int = 4
    inter_row_m: float = 0.268
    inter_row_sd_m: float = 0.03
    intra_row_m: float = 0.227
    intra_row_sd_m: float = 0.02
    leaves_per_plant_mean: float = 42.0
    leaves_per_plant_sd: float = 5.0
    base_height_m: float = 0.0
    leaf: StrawberryLeafParams = field(default_factory=StrawberryLeafParams)

    def __post_init__(self) -> None:
        _int_at_least("rows", self.rows, 1)
        _int_at_least("plants_per_row", self.plants_per_row, 1)
        for k in ("inter_row_m", "intra_row_m"):
            object.__setattr__(self, k, _real(k, getattr(self, k), positive=True))
        for k in ("inter_row_sd_m", "intra_row_sd_m", "leaves_per_plant_sd", "base_height_m"):
            object.__setattr__(self, k, _non_negative(k, getattr(self, k)))
        m = _real("leaves_per_plant_mean", self.leaves_per_plant_mean)
        object.__setattr__(self, "leaves_per_plant_mean", m)
        # Rounded draws are kept when >= 1, i.e. raw draws >= 0.5.
        _check_truncated("leaves_per_plant_mean", m, self.leaves_per_plant_sd, 0.5, math.inf)
        if isinstance(self.leaf, dict):
            object.__setattr__(self, "leaf", StrawberryLeafParams(**self.leaf))
        elif not isinstance(self.leaf, StrawberryLeafParams):
            raise ConfigError("must be a StrawberryLeafParams or a dict of its fields",
                              key="leaf", value=self.leaf)

    @property
    def n_plants(self) -> int:
        return self.rows * self.plants_per_row

    @property
    def ground_area_m2(self) -> float:
        """Planted area (rows·inter_row) × (plants_per_row·intra_row), m²."""
        return self.rows * self.inter_row_m * self.plants_per_row * self.intra_row_m


# ---------------------------------------------------------------------------- plant
def strawberry_plant(params: StrawberryLeafParams, n_leaves: int, rng: np.random.Generator,
                     *, base_xyz_m: Sequence[float] = (0.0, 0.0, 0.0), plant_id: int = 0,
                     first_leaf_id: int = 0) -> Leaves:
    """A plant: ``n_leaves`` leaves whose petioles all start at ``base_xyz_m``.

    Parameters
    ----------
    params : StrawberryLeafParams
    n_leaves : int
    rng : numpy.random.Generator
        The plant's own stream.
    base_xyz_m : sequence of 3 floats
        Crown position, metres.
    plant_id : int
        Stored in :attr:`Leaves.plant_id`.
    first_leaf_id : int
        Leaf ids are ``first_leaf_id, first_leaf_id + 1, …`` (12 triangles each).

    Returns
    -------
    Leaves
        ``12·n_leaves`` triangles.
    """
    traits = draw_leaf_traits(params, rng, n_leaves)
    tri = leaf_triangles(traits, params, base_xyz_m).reshape(-1, 3, 3)
    leaf_id = np.repeat(np.arange(first_leaf_id, first_leaf_id + len(traits), dtype=np.int32),
                        TRIANGLES_PER_LEAF)
    return Leaves(tri, leaf_id, np.full(len(leaf_id), plant_id, np.int32))


# ----------------------------------------------------------------------------- plot
@dataclass(frozen=True)
class StrawberryPlot:
    """A generated strawberry plot.

    Attributes
    ----------
    leaves : Leaves
        All triangles; ``leaf_id`` is unique over the plot, ``plant_id`` is the
        row-major plant index ``r·plants_per_row + j``.
    plant_xy_m : (n_plants, 2) float64
        Crown positions, metres.
    plant_rc : (n_plants, 2) int32
        (row, position in row) of each plant, in ``plant_id`` order.
    leaves_per_plant : (n_plants,) int32
    bounds_m : tuple of 4 floats
        Planted area ``(x_min, y_min, x_max, y_max)``, metres.
    canopy_height_m : float
        Highest leaf vertex above the ground, metres.
    params : StrawberryPlotParams
    seed_entropy : int or tuple of int
        Entropy of the root ``SeedSequence``; reproduces the plot.
    """

    leaves: Leaves
    plant_xy_m: np.ndarray
    plant_rc: np.ndarray
    leaves_per_plant: np.ndarray
    bounds_m: tuple[float, float, float, float]
    canopy_height_m: float
    params: StrawberryPlotParams
    seed_entropy: int | tuple[int, ...]

    @property
    def ground_area_m2(self) -> float:
        """Planted area (rows·inter_row_m)·(plants_per_row·intra_row_m), m²."""
        x0, y0, x1, y1 = self.bounds_m
        return (x1 - x0) * (y1 - y0)

    @property
    def n_leaves(self) -> int:
        return int(self.leaves_per_plant.sum())

    @property
    def leaf_area_m2(self) -> float:
        """One-sided leaf area of the plot, m²."""
        return float(self.leaves.triangle_area.sum())

    @property
    def lai(self) -> float:
        """Leaf area index: one-sided leaf area / planted ground area."""
        return self.leaf_area_m2 / self.ground_area_m2


def strawberry_plot(params: StrawberryPlotParams | None = None,
                    seed: int | np.random.SeedSequence | None = None) -> StrawberryPlot:
    """Build a plot of strawberry plants on a row-crop grid.

    Seeding: the root ``SeedSequence(seed)`` spawns one child per row and each row
    spawns one child per plant, so plant ``(r, j)`` always draws from the same
    stream; adding rows or plants at the end of a row leaves every other plant's
    geometry unchanged. Each plant's stream draws, in order, its number of leaves,
    its position offset, then its leaves.

    Parameters
    ----------
    params : StrawberryPlotParams, optional
        Paper defaults if omitted.
    seed : int, SeedSequence or None
        None draws fresh entropy (recorded in :attr:`StrawberryPlot.seed_entropy`).

    Returns
    -------
    StrawberryPlot
    """
    pp = params if params is not None else StrawberryPlotParams()
    root = _root_seed(seed)
    row_seeds = root.spawn(pp.rows)
    parts, xy, rc, counts = [], [], [], []
    next_leaf = 0
    for r, row_ss in enumerate(row_seeds):
        for j, plant_ss in enumerate(row_ss.spawn(pp.plants_per_row)):
            rng = np.random.default_rng(plant_ss)
            n = _leaf_count(rng, pp)
            dx = _truncnorm(rng, 0.0, pp.intra_row_sd_m / math.sqrt(2), -0.45 * pp.intra_row_m,
                            0.45 * pp.intra_row_m, 1)[0]
            dy = _truncnorm(rng, 0.0, pp.inter_row_sd_m / math.sqrt(2), -0.45 * pp.inter_row_m,
                            0.45 * pp.inter_row_m, 1)[0]
            x = (j + 0.5) * pp.intra_row_m + dx
            y = (r + 0.5) * pp.inter_row_m + dy
            pid = r * pp.plants_per_row + j
            parts.append(strawberry_plant(pp.leaf, n, rng, base_xyz_m=(x, y, pp.base_height_m),
                                          plant_id=pid, first_leaf_id=next_leaf))
            next_leaf += n
            xy.append((x, y))
            rc.append((r, j))
            counts.append(n)
    leaves = Leaves(np.concatenate([p.vertices for p in parts]),
                    np.concatenate([p.leaf_id for p in parts]),
                    np.concatenate([p.plant_id for p in parts]))
    bounds = (0.0, 0.0, pp.plants_per_row * pp.intra_row_m, pp.rows * pp.inter_row_m)
    height = float(leaves.vertices[..., 2].max()) if len(leaves) else 0.0
    entropy = root.entropy if isinstance(root.entropy, int) else tuple(root.entropy)
    return StrawberryPlot(leaves, np.asarray(xy, float).reshape(-1, 2),
                          np.asarray(rc, np.int32).reshape(-1, 2),
                          np.asarray(counts, np.int32), bounds, height, pp, entropy)


def _leaf_count(rng: np.random.Generator, pp: StrawberryPlotParams) -> int:
    """Leaves of one plant: a rounded normal draw, redrawn while below 1."""
    if pp.leaves_per_plant_sd == 0:
        return max(1, int(round(pp.leaves_per_plant_mean)))
    for _ in range(_MAX_REDRAWS):
        n = int(np.rint(rng.normal(pp.leaves_per_plant_mean, pp.leaves_per_plant_sd)))
        if n >= 1:
            return n
    raise ConfigError("could not draw a leaf count >= 1", key="leaves_per_plant_mean",
                      value=pp.leaves_per_plant_mean)
