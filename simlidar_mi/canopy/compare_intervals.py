"""The bias of virtual against measured gap fractions with its t-based interval
(Welch–Satterthwaite), for :mod:`simlidar_mi.canopy.compare` (kept apart so compare stays one idea:
running and tabulating the comparison)."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError

__all__ = ["bias_interval"]


def bias_interval(virtual: Sequence[Sequence[float]], groups: Sequence[Any],
                  observed: Sequence[float], observed_sd: Sequence[float | None],
                  observed_n: Sequence[int | None], level: float = 0.95) -> dict[str, float]:
    """Bias = mean(s − o) of k pairs with a t-based confidence interval (Welch–Satterthwaite).

    Parameters
    ----------
    virtual : k sequences of float
        Each pair's virtual P0 per replicate plot; its simulated value is their mean.
    groups : k hashables
        Pairs of one group (one scene) come from the same replicate plots, replicate ``j`` of
        each being plot ``j``: their per-plot sums are taken together, so the correlation
        between, say, a zenith's extraction steps is kept.  Groups are independent.
    observed : k floats
    observed_sd, observed_n : k values
        SD among the ``n`` photos / sample areas each observed value is the mean of (None:
        not known, that value is taken as exact).
    level : float
        Confidence level.

    Returns
    -------
    dict
        ``bias``; ``se`` = √(Σ_g var_j(Σ_{i∈g} v_ij)/(R_g·k²) + Σ_i sd_i²/(n_i·k²)); ``df`` the
        Welch–Satterthwaite degrees of freedom (R_g − 1 per group, n_i − 1 per observed value);
        ``low``, ``high`` = bias ∓ t_{(1+level)/2, df}·se.  nan where no component has a spread
        (one replicate and no SDs).
    """
    from scipy import stats as _st  # noqa: PLC0415
    k = len(observed)
    v = [np.asarray(x, np.float64) for x in virtual]
    bias = float(np.mean([x.mean() for x in v]) - np.mean(np.asarray(observed, np.float64)))
    comps: list[tuple[float, float]] = []   # (variance contribution, df)
    for g in dict.fromkeys(groups):
        members = [x for x, gg in zip(v, groups) if gg == g]
        lengths = {len(x) for x in members}
        if len(lengths) != 1:
            raise ConfigError("pairs of one scene must have the same replicates", key="virtual")
        n_rep = lengths.pop()
        if n_rep < 2:
            continue
        tot = np.sum(members, axis=0)
        comps.append((float(np.var(tot, ddof=1)) / n_rep / k ** 2, n_rep - 1))
    for sd, n in zip(observed_sd, observed_n):
        if sd is not None and n is not None and n >= 2 and math.isfinite(sd):
            comps.append((sd * sd / n / k ** 2, n - 1))
    var = sum(c for c, _ in comps)
    if not comps:
        return {"bias": bias, "se": math.nan, "df": math.nan, "low": math.nan, "high": math.nan}
    den = sum(c * c / d for c, d in comps)
    df = var * var / den if den > 0 else float(min(d for _, d in comps))
    se = math.sqrt(var)
    t = float(_st.t.ppf(0.5 + level / 2, df)) if se > 0 else 0.0
    return {"bias": bias, "se": se, "df": df, "low": bias - t * se, "high": bias + t * se}
