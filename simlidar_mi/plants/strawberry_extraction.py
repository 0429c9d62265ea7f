"""Leaf extraction (the strawberry paper's density experiment): successive random leaf removals.

Each step removes whole leaves from what the step before left (the paper removed
44, 39 and 44 leaves in turn); :func:`extraction_steps` gives each step's leaf area
and LAI on a :class:`~simlidar_mi.plants.strawberry.StrawberryPlot` (cf. the paper's
Table 4).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .._validate import seed_sequence as _root_seed
from ..errors import ConfigError
from ..geometry import Leaves
from .strawberry import StrawberryPlot

__all__ = ["ExtractionStep", "extract_leaves", "extraction_steps", "PAPER_EXTRACTION_COUNTS"]

#: Leaves removed in the paper's three successive extractions (average of 3 areas).
PAPER_EXTRACTION_COUNTS = (44, 39, 44)


# ----------------------------------------------------------------------- extraction
def extract_leaves(leaves: Leaves, counts: Sequence[int] = PAPER_EXTRACTION_COUNTS,
                   seed: int | np.random.SeedSequence | None = None) -> list[Leaves]:
    """Successive random leaf removals, as in the paper's density experiment.

    Step 0 is the full canopy; step ``k`` removes ``counts[k-1]`` whole leaves (all
    their triangles) chosen uniformly at random, without replacement, among the
    leaves left after step ``k-1``. Each step is therefore a subset of the previous.

    Parameters
    ----------
    leaves : Leaves
        Canopy; leaves are identified by ``leaf_id``.
    counts : sequence of int
        Leaves removed at each step (paper: 44, 39, 44).
    seed : int, SeedSequence or None

    Returns
    -------
    list of Leaves
        ``len(counts) + 1`` canopies.

    Raises
    ------
    ConfigError
        If a count is negative or larger than the number of leaves remaining.
    """
    rng = np.random.default_rng(_root_seed(seed))
    ids = np.unique(leaves.leaf_id)
    remaining = ids
    out = [leaves]
    for k, n in enumerate(counts, start=1):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ConfigError("leaf counts to remove must be integers >= 0",
                              key=f"counts[{k - 1}]", value=n)
        if n > len(remaining):
            raise ConfigError(
                f"step {k} asks to remove {n} leaves but only {len(remaining)} remain "
                f"(the canopy started with {len(ids)})", key=f"counts[{k - 1}]", value=n)
        removed = rng.choice(remaining, size=int(n), replace=False)
        remaining = np.setdiff1d(remaining, removed, assume_unique=True)
        out.append(leaves.subset(np.isin(leaves.leaf_id, remaining)))
    return out


@dataclass(frozen=True)
class ExtractionStep:
    """One canopy of the extraction series.

    Attributes
    ----------
    step : int
        0 = full canopy.
    leaves : Leaves
    n_leaves : int
    leaf_area_m2 : float
        One-sided leaf area, m².
    lai : float
        ``leaf_area_m2`` / planted ground area.
    """

    step: int
    leaves: Leaves
    n_leaves: int
    leaf_area_m2: float
    lai: float


def extraction_steps(plot: StrawberryPlot, counts: Sequence[int] = PAPER_EXTRACTION_COUNTS,
                     seed: int | np.random.SeedSequence | None = None) -> list[ExtractionStep]:
    """Leaf area and LAI of the plot after each extraction (cf. paper Table 4).

    The ground area is the planted area ``rows·inter_row_m × plants_per_row·
    intra_row_m`` (:attr:`StrawberryPlot.ground_area_m2`).
    """
    ground = plot.ground_area_m2
    steps = []
    for k, lv in enumerate(extract_leaves(plot.leaves, counts, seed)):
        area = float(lv.triangle_area.sum())
        steps.append(ExtractionStep(k, lv, int(len(np.unique(lv.leaf_id))), area, area / ground))
    return steps
