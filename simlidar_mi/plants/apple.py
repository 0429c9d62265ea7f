"""SIMLIDAR apple trees and orchards (Méndez et al., sections 1, 4 and 5).

Grammars (paper, section 1; axiom ``F``; ``n`` = the generation writing a module):

deterministic
    ``F -> InIn[r+InIn+F]In[R-InF]InF``
stochastic
    ``F -> InIn[r+InIn+F]In[RR-InF]InF`` with probability 0.33,
    ``F -> In[r+InF]In[rr-InF]In[r+InF]F`` with 0.33,
    ``F -> In[r+InF]In[R-InF]In[RR+InF]F`` with 0.34.
    The paper prints ``.33`` three times ("approximately the same probability
    of 1/3"), which sums to 0.99; we give the remainder to the last successor,
    as ABOP does for its Fig. 1.27 (0.33/0.33/0.34).

Geometry: the turtle of :mod:`simlidar_mi.lsystem.turtle` with
``h_n = h0 / 2**(n-1)`` and ``d_n = Ns · d_m / n``.

Default ``h0_m = 0.4``: the paper does not give h0. The main axis is vertical
with 4 elements per generation, so a tree is ``4·h0·(2 − 2**(1−N))`` tall:
3.2 m for 7 deterministic iterations (2.8 m stochastic). Stochastic crowns
are then 1.7–1.95 m long along the row for 4–7 iterations (deterministic
ones 2.3–2.6 m), matching the paper's Table 3: every scan size there is a
multiple of 601 (angular steps), leaving 840–965 tractor steps of
Δy = 2 mm, i.e. 1.7–1.9 m, for one tree (eq. 6).
"""
from __future__ import annotations

import operator
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from ..config.checks import flag as _flag
from ..config.checks import real as _real
from ..errors import ConfigError
from ..geometry import Branches
from ..lsystem import (DEFAULT_MAX_MODULES, Grammar, ModuleString, derive, format_table1,
                       interpret, parse_grammar)
from ..lsystem.turtle import check_prune_mode

SIMLIDAR_APPLE_GRAMMAR = """\
# SIMLIDAR non-stochastic apple tree (Méndez et al., section 1)
alphabet: F I R r T t + -
axiom: F
productions:
F -> InIn[r+InIn+F]In[R-InF]InF
"""

SIMLIDAR_APPLE_STOCHASTIC_GRAMMAR = """\
# SIMLIDAR stochastic apple tree (Méndez et al., section 1); .33/.33/.34
alphabet: F I R r T t + -
axiom: F
productions:
F -> (0.33) InIn[r+InIn+F]In[RR-InF]InF
   | (0.33) In[r+InF]In[rr-InF]In[r+InF]F
   | (0.34) In[r+InF]In[R-InF]In[RR+InF]F
"""


@lru_cache(maxsize=2)
def apple_grammar(stochastic: bool = False) -> Grammar:
    """The parsed SIMLIDAR apple grammar."""
    if stochastic:
        return parse_grammar(SIMLIDAR_APPLE_STOCHASTIC_GRAMMAR, "SIMLIDAR stochastic apple")
    return parse_grammar(SIMLIDAR_APPLE_GRAMMAR, "SIMLIDAR apple")


def _whole(key: str, value, minimum: int) -> int:
    try:
        v = operator.index(value)
    except TypeError:
        raise ConfigError(f"must be a whole number >= {minimum}", key=key, value=value) from None
    if isinstance(value, bool) or v < minimum:
        raise ConfigError(f"must be a whole number >= {minimum}", key=key, value=value)
    return v


@dataclass(frozen=True)
class AppleTreeParams:
    """Parameters of one SIMLIDAR apple tree (paper, section 4).

    Attributes
    ----------
    iterations : number of generations ``Ns`` (the paper studies 4–7).
    angle_deg : turn of ``+``/``-`` about L.
    rotation_deg : turn of ``T``/``t`` (``R``/``r``) about U.
    d_min_m : smallest branch diameter ``d_m`` (paper: 5, 6, 7 mm).
    h0_m : length of an order-1 element (module docstring explains 0.4 m).
    pruning : remove branches that descend in z.
    pruning_mode : "subtree" (default) removes a descending segment with everything
        that grows from it, the only reading in which no wood floats; "segment"
        drops the descending segment only and keeps its children in mid-air
        (this package's behaviour before 2026-12; BENCHMARKS.md measures both).
    stochastic : use the three-successor grammar.
    max_modules : refuse derivations predicted to exceed this many modules.

    Raises
    ------
    ConfigError
        naming the key and value, on construction.
    """

    iterations: int
    angle_deg: float = 20.0
    rotation_deg: float = 20.0
    d_min_m: float = 0.005
    h0_m: float = 0.4
    pruning: bool = False
    stochastic: bool = False
    pruning_mode: str = "subtree"
    max_modules: int = DEFAULT_MAX_MODULES

    def __post_init__(self) -> None:
        set_ = object.__setattr__       # frozen: normalise types once, here
        set_(self, "iterations", _whole("iterations", self.iterations, 1))
        set_(self, "angle_deg", _real("angle_deg", self.angle_deg))
        set_(self, "rotation_deg", _real("rotation_deg", self.rotation_deg))
        set_(self, "d_min_m", _real("d_min_m", self.d_min_m, positive=True))
        set_(self, "h0_m", _real("h0_m", self.h0_m, positive=True))
        set_(self, "pruning", _flag("pruning", self.pruning))
        set_(self, "stochastic", _flag("stochastic", self.stochastic))
        set_(self, "pruning_mode", check_prune_mode(self.pruning_mode))
        set_(self, "max_modules", _whole("max_modules", self.max_modules, 1))


def derive_apple(params: AppleTreeParams, rng: np.random.Generator | None = None
                 ) -> ModuleString:
    """The derived word of one tree (``rng`` required when stochastic)."""
    if params.stochastic and rng is None:
        raise ConfigError("a stochastic tree needs a numpy.random.Generator", key="rng",
                          value=None)
    return derive(apple_grammar(params.stochastic), params.iterations, rng,
                  max_modules=params.max_modules)


def apple_tree(params: AppleTreeParams, rng: np.random.Generator | None = None,
               tree_id: int = 0, base_m: Sequence[float] = (0.0, 0.0, 0.0)) -> Branches:
    """One apple tree as branch cylinders.

    Parameters
    ----------
    params : tree parameters.
    rng : random stream of this tree; required when ``params.stochastic``.
    tree_id : written to every segment.
    base_m : foot of the trunk (metres).

    Returns
    -------
    Branches
    """
    base = np.asarray(base_m, np.float64)
    if base.shape != (3,) or not np.isfinite(base).all():
        raise ConfigError("must be three finite coordinates (metres)", key="base_m",
                          value=base_m)
    word = derive_apple(params, rng)
    tree = interpret(word, h0_m=params.h0_m, d_min_m=params.d_min_m,
                     n_substitutions=params.iterations, angle_deg=params.angle_deg,
                     rotation_deg=params.rotation_deg, prune=params.pruning,
                     prune_mode=params.pruning_mode,
                     tree_id=_whole("tree_id", tree_id, 0))
    # Built at the origin and moved, so a tree's shape never depends on where it stands.
    return tree.translated(base)


def orchard(params: AppleTreeParams, n_trees: int, spacing_m: float, row_x_m: float = 0.0,
            y_start_m: float = 0.0, seed: int = 0) -> Branches:
    """A row of apple trees parallel to the y axis.

    Tree ``k`` (``tree_id = k``) stands at ``(row_x_m, y_start_m + k·spacing_m, 0)``.
    Stochastic trees each get their own stream,
    ``default_rng(SeedSequence(seed).spawn(n_trees)[k])``, so adding trees
    leaves the earlier ones unchanged; deterministic trees are all the same.

    Returns
    -------
    Branches
        All trees, concatenated in tree order.
    """
    n = _whole("n_trees", n_trees, 1)
    spacing = _real("spacing_m", spacing_m, positive=True)
    x = _real("row_x_m", row_x_m)
    y0 = _real("y_start_m", y_start_m)
    seed = _whole("seed", seed, 0)
    bases = [(x, y0 + k * spacing, 0.0) for k in range(n)]
    if not params.stochastic:
        tree = apple_tree(params, None)
        return Branches.concat([
            Branches(tree.p0 + b, tree.p1 + b, tree.diameter, tree.order,
                     np.full(len(tree), k, np.int32)) for k, b in enumerate(bases)])
    children = np.random.SeedSequence(seed).spawn(n)
    return Branches.concat([apple_tree(params, np.random.default_rng(children[k]), k, b)
                            for k, b in enumerate(bases)])


def apple_derivation_string(generations: int, stochastic: bool = False, seed: int = 0) -> str:
    """The apple derivation in the paper's Table 1 notation (``[I01I01[t+...]``).

    ``seed`` feeds ``numpy.random.default_rng`` for the stochastic grammar.
    """
    g = _whole("generations", generations, 0)
    rng = np.random.default_rng(_whole("seed", seed, 0)) if stochastic else None
    return format_table1(derive(apple_grammar(stochastic), g, rng))
