"""Leaf extraction (the strawberry paper's density experiment): successive random leaf removals.

The paper pulled leaves out of each sample area three times: "se arrancaron aleatoriamente un
sexto de las hojas, en tres extracciones sucesivas, quedando la mitad de las hojas iniciales al
final de la última extracción" (one sixth of the leaves were pulled out at random in three
successive extractions, half of the starting leaves remaining after the last).  Its Table 4 then
prints what the field canopy's leaf area actually did, averaged over the 3 sample areas: 1.116,
0.900, 0.724 and 0.527 m², i.e. 0.806, 0.649 and 0.472 of the first, not 5/6, 4/6, 3/6.  The
gap fractions measured in the field belong to those canopies, so by default the virtual
extraction removes at each step the share of the starting leaves that Table 4's real leaf area
lost (:data:`PAPER_EXTRACTION_FRACTIONS`, from :data:`PAPER_TABLE4_REAL_M2`: 0.1935, 0.1577,
0.1765 of the start; 52.8 % gone after three steps).  Sixths (:data:`PAPER_EXTRACTION_SIXTHS`,
the procedure as the text states it) and absolute counts (:data:`PAPER_EXTRACTION_COUNTS`, the
44, 39, 44 leaves of a ~254-leaf sample area) stay available as options
(``[strawberry] extraction_fractions`` / ``extraction_counts``).

Leaves are removed whole and at random, each step from what the step before left, so
every step is a subset of the previous one.  Counts are exact (see
:func:`fraction_counts`); leaf area falls by the same share *in expectation* (leaves
differ in size), which is what the paper's field procedure, counting leaves, did too.
:func:`extraction_steps` gives each step's leaf area and LAI on a
:class:`~simlidar_mi.plants.strawberry.StrawberryPlot` (cf. the paper's Table 4).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..config.checks import seed_sequence as _root_seed
from ..errors import ConfigError
from ..geometry import Leaves
from .strawberry import StrawberryPlot

__all__ = ["ExtractionStep", "extract_leaves", "extraction_steps", "fraction_counts",
           "PAPER_EXTRACTION_COUNTS", "PAPER_EXTRACTION_FRACTIONS", "PAPER_EXTRACTION_SIXTHS",
           "PAPER_TABLE4_REAL_M2", "PAPER_TABLE4_VIRTUAL_M2", "table4_fractions"]

#: Leaves removed in the paper's three successive extractions (average of its 3 sample
#: areas of ~254 leaves each): right only for a canopy of that size.
PAPER_EXTRACTION_COUNTS = (44, 39, 44)

#: Table 4, "Dosel real, promedio de las 3 áreas de muestreo": the field canopy's leaf area,
#: m² (per 1 m² sample area), full and after each extraction.
PAPER_TABLE4_REAL_M2 = (1.116, 0.900, 0.724, 0.527)

#: Table 4, "Dosel virtual": the paper's virtual canopy, m² (it removed the field's leaf counts).
PAPER_TABLE4_VIRTUAL_M2 = (1.241, 1.034, 0.849, 0.642)

#: "One sixth of the leaves … leaving half" as the text states the procedure (an option).
PAPER_EXTRACTION_SIXTHS = (1 / 6, 1 / 6, 1 / 6)


def table4_fractions(areas_m2: Sequence[float] = PAPER_TABLE4_REAL_M2) -> tuple[float, ...]:
    """Shares of the starting leaves to remove per step so that leaf area follows ``areas_m2``.

    Step ``k`` removes ``(A_{k-1} − A_k)/A_0``; after step ``k`` the canopy holds ``A_k/A_0`` of
    its leaves (and, in expectation, of its leaf area).  With Table 4's real canopy:
    0.193548, 0.157706, 0.176523 (the areas fall to 0.806, 0.649, 0.472 of the first).
    """
    a = [float(x) for x in areas_m2]
    return tuple((a[k - 1] - a[k]) / a[0] for k in range(1, len(a)))


#: Share of the *starting* leaves removed at each of the paper's three extractions so that the
#: leaf area falls as Table 4's real canopy did (the default; see the module docstring).
PAPER_EXTRACTION_FRACTIONS = table4_fractions(PAPER_TABLE4_REAL_M2)


# ----------------------------------------------------------------------- extraction
def fraction_counts(n_leaves: int, fractions: Sequence[float]) -> list[int]:
    """Leaves to remove at each step when step ``k`` removes ``fractions[k]`` of the start.

    Cumulative rounding: after step ``k`` exactly ``floor(n0·Σ_{i≤k} f_i + ½)`` leaves
    are gone, so rounding never accumulates (1/6 three times leaves exactly
    ``n0 − floor(n0/2 + ½)``, "half"), and each step's count is within one of
    ``n0·f_k``.

    Raises
    ------
    ConfigError
        A fraction outside [0, 1] or fractions adding up to more than 1.
    """
    total = 0.0
    for k, f in enumerate(fractions):
        if isinstance(f, bool) or not isinstance(f, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(f) and 0.0 <= f <= 1.0):
            raise ConfigError("extraction fractions must be numbers in [0, 1] (shares of the "
                              "starting leaves)", key=f"fractions[{k}]", value=f)
        total += float(f)
    if total > 1.0 + 1e-9:
        raise ConfigError(f"extraction fractions add up to {total:.6g} > 1 (they are shares "
                          "of the starting leaves)", key="fractions", value=list(fractions))
    out, done, acc = [], 0, 0.0
    for f in fractions:
        acc += float(f)
        # the 1e-9 absorbs float error in n0·Σf (e.g. 6·(1/6 + 1/6 + 1/6))
        gone = min(int(n_leaves), int(math.floor(n_leaves * acc + 0.5 + 1e-9)))
        out.append(gone - done)
        done = gone
    return out


def extract_leaves(leaves: Leaves, counts: Sequence[int] | None = None,
                   seed: int | np.random.SeedSequence | None = None, *,
                   fractions: Sequence[float] | None = None) -> list[Leaves]:
    """Successive random leaf removals, as in the paper's density experiment.

    Step 0 is the full canopy; step ``k`` removes whole leaves (all their triangles)
    chosen uniformly at random, without replacement, among the leaves left after step
    ``k-1``. Each step is therefore a subset of the previous.

    Parameters
    ----------
    leaves : Leaves
        Canopy; leaves are identified by ``leaf_id``.
    counts : sequence of int, optional
        Leaves removed at each step (the paper's absolute numbers were 44, 39, 44).
        Give either ``counts`` or ``fractions``.
    seed : int, SeedSequence or None
    fractions : sequence of float, optional
        Share of the starting leaves removed at each step (default, when neither is
        given: :data:`PAPER_EXTRACTION_FRACTIONS`); counts from :func:`fraction_counts`.

    Returns
    -------
    list of Leaves
        One canopy per step plus the full one.

    Raises
    ------
    ConfigError
        Both or bad counts/fractions, or a count larger than the leaves remaining.
    """
    ids = np.unique(leaves.leaf_id)
    if counts is not None and fractions is not None:
        raise ConfigError("give extraction counts or fractions, not both", key="counts",
                          value=list(counts))
    if counts is None:
        counts = fraction_counts(len(ids), PAPER_EXTRACTION_FRACTIONS if fractions is None
                                 else fractions)
    rng = np.random.default_rng(_root_seed(seed))
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


def extraction_steps(plot: StrawberryPlot, counts: Sequence[int] | None = None,
                     seed: int | np.random.SeedSequence | None = None, *,
                     fractions: Sequence[float] | None = None) -> list[ExtractionStep]:
    """Leaf area and LAI of the plot after each extraction (cf. paper Table 4).

    ``counts`` / ``fractions`` as in :func:`extract_leaves` (default: Table 4's real-canopy
    shares, :data:`PAPER_EXTRACTION_FRACTIONS`). The ground area is the planted area
    ``rows·inter_row_m × plants_per_row·intra_row_m``
    (:attr:`StrawberryPlot.ground_area_m2`).
    """
    ground = plot.ground_area_m2
    steps = []
    for k, lv in enumerate(extract_leaves(plot.leaves, counts, seed, fractions=fractions)):
        area = float(lv.triangle_area.sum())
        steps.append(ExtractionStep(k, lv, int(len(np.unique(lv.leaf_id))), area, area / ground))
    return steps
