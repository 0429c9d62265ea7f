"""Randomised Honda-type trees (Wahed et al., seed 004, §II): the generator and the tree it grows.

The species' laws are :class:`~simlidar_mi.plants.tree_params.RandomTreeParams`;
the leaves are made by :mod:`simlidar_mi.plants.tree_leaves`.

The grammar the generator realises, for a branch module ``A(l, r, o, d)`` of length
``l``, radius ``r``, axis order ``o`` and depth ``d`` (trunk: ``o = 1``, ``d = 0``)::

    A(l,r,o,d) : d < G-1  →  !(r) F(l) [ &(θ_i) A(l·r2, r·wr2, o+1, d+1) ]_{i<m}   (laterals)
                                        /(δ) &(θ_L) A(l·r1, r·wr1, o, d+1)          (leader)

where the leader exists only for axes with ``o ≤ monopodial_orders`` (0 gives a
sympodial, apex-branching tree: every daughter is a lateral using ``r1``), laterals
only for ``o < max_order`` above the first ``bare_trunk_levels`` trunk segments,
and no branch shorter than ``min_length_m`` gets daughters. Daughter ``i`` of ``m``
leaves its mother at azimuth ``twist + 360°·i/m`` about the mother's axis (a whorl
when the flag is false), at position ``t ~ U(lateral_position_min, 1)`` along the
mother when the flag is true, else at its apex; the flag (L1) is drawn once per tree,
right after the global draws (``lateral_branching_per = "tree"``, default), or once
per growing branch (``"branch"``). The leader is rolled by
``divergence_deg`` (137.5°: phyllotaxis) so successive whorls interleave. A
``tropism`` weight ``τ`` bends every daughter but the trunk's leader:
``H ← normalise(H + τ·ẑ)``.

It is written as a direct generator (breadth-first, one vectorised numpy pass per
generation) rather than through :mod:`simlidar_mi.lsystem`: each branch needs its
own random draws and frame, which a string-rewriting derivation would only carry
as module parameters, and building the word first would cost memory for nothing.
:func:`iter_random_trees` grows many trees of one species in lock step (the wood's numpy
pass covers all of them: :mod:`simlidar_mi.plants.tree_growth`); each is the tree
:func:`random_tree` grows from its seed, bit for bit.

Randomness: every tree draws from its own ``numpy.random.Generator`` (from an
integer seed, a ``SeedSequence`` or a Generator), in a fixed order, so the same
seed gives the same bytes and one tree's seed does not affect another tree.
Nothing here imports Mitsuba. Lengths are metres, angles degrees at the API.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from .._runtime.threads import ordered_map
from ..errors import ConfigError
from ..geometry import Branches, Leaves
from .laws import _whole
from .tree_growth import _bend, _grow_wood, _len, _start, _Tree, scaled_count  # noqa: F401  (_bend, _len: tests)
from .tree_leaves import LeafTable, _make_leaves
from .tree_params import _LAWS, RandomTreeParams

__all__ = ["RandomTree", "TreeDraws", "iter_random_trees", "random_tree"]


# --- results ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TreeDraws:
    """Every random value one tree drew (kept with ``keep_draws=True``; for tests and audits).

    ``globals`` maps a global law's name to its one draw. ``locals`` maps a local law's
    name to all its draws in the tree: ``lateral_branching`` once per tree (one value)
    or, with ``lateral_branching_per = "branch"``, per branch that could grow; per
    branch that could grow (``twist_deg``, ``n_daughters``/``trunk_n_daughters``; drawn even where the order
    or bare-trunk rules then forbid laterals), per lateral daughter
    (``branch_angle_deg``/``trunk_branch_angle_deg``), per leader
    (``leader_angle_deg``), per leaf-bearing branch (``leaves_per_branch``) and per
    leaf (``leaf_length_m``, ``leaf_width_ratio``, ``leaf_angle_deg``, ``leaf_roll_deg``).
    """

    globals: dict[str, float]
    locals: dict[str, np.ndarray]


@dataclass(frozen=True)
class RandomTree:
    """One random tree in its own frame (trunk foot at the origin, trunk along +z).

    Attributes
    ----------
    branches : the woody segments (``tree_id`` as given).
    leaves : the leaf triangles (``leaf_id`` 0…n−1 within the tree, ``plant_id`` = tree id).
    leaf_table : one row per leaf.
    seed : the integer seed when the tree was made from one, else None.
    draws : every drawn value when asked for, else None.
    branching : share of the tree's branching decisions made with the L1 flag true:
        the flag itself (0 or 1) when it is drawn per tree.
    wood_scale : the factor :meth:`wood_scaled` applied (1 for a grown tree).
    leaf_xy2_max_m2 : largest ``x² + y²`` of the leaf vertices, noted while they are made
        (they are then still in cache; read back later they come from memory) so
        :attr:`crown_radius_m` need not scan them; None: scan them.
    """

    branches: Branches
    leaves: Leaves
    leaf_table: LeafTable
    seed: int | None = None
    draws: TreeDraws | None = field(default=None, repr=False)
    branching: float = 0.0
    wood_scale: float = 1.0
    leaf_xy2_max_m2: float | None = field(default=None, repr=False, compare=False)

    def wood_scaled(self, scale: float) -> "RandomTree":
        """This tree with its wood scaled by ``scale`` about the trunk foot; leaves keep their size.

        Branch ends and diameters are multiplied by ``scale``. Every leaf moves rigidly with
        its insertion point on the bark (``b → scale·b``; its blade is ``v → v + (scale − 1)·b``),
        so leaf length, width, area and orientation are the drawn ones. ``scale = 1`` returns
        the tree itself.
        """
        s = float(scale)
        if not (math.isfinite(s) and s > 0):
            raise ConfigError("must be a finite number > 0", key="scale", value=scale)
        if s == 1.0:
            return self
        b, lt = self.branches, self.leaf_table
        base = lt.centre_m - 0.5 * lt.length_m[:, None] * lt.heading   # insertion point on the bark
        shift = (s - 1.0) * base
        lv = self.leaves
        leaves = Leaves(lv.vertices + shift[lv.leaf_id][:, None, :], lv.leaf_id, lv.plant_id)
        table = dataclasses.replace(lt, centre_m=lt.centre_m + shift)
        return RandomTree(Branches(s * b.p0, s * b.p1, s * b.diameter, b.order, b.tree_id), leaves,
                          table, self.seed, self.draws, self.branching, self.wood_scale * s)

    @property
    def height_m(self) -> float:
        """Highest z of branch end points and leaf vertices (radii not added)."""
        zs = [0.0]
        if len(self.branches):
            zs.append(float(max(self.branches.p0[:, 2].max(), self.branches.p1[:, 2].max())))
        if len(self.leaves):
            zs.append(float(self.leaves.vertices[..., 2].max()))
        return max(zs)

    @property
    def crown_radius_m(self) -> float:
        """Largest horizontal distance of branch ends and leaf vertices from the trunk axis."""
        pts = [np.zeros((1, 2))]
        if len(self.branches):
            pts += [self.branches.p0[:, :2], self.branches.p1[:, :2]]
        if self.leaf_xy2_max_m2 is None and len(self.leaves):
            v = self.leaves.vertices.reshape(-1, 3)
            # in blocks: the temporaries stay in cache (a tree has ~10⁵ leaf vertices)
            pts += [v[i:i + 8192] for i in range(0, len(v), 8192)]
        # x·x + y·y per point: the same floats as (p ** 2).sum(1), without the (n, 2) temporaries
        r2 = [(p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1]).max() for p in pts]
        if self.leaf_xy2_max_m2 is not None:
            r2.append(self.leaf_xy2_max_m2)
        return float(np.sqrt(max(r2)))

    @property
    def n_leaves(self) -> int:
        return len(self.leaf_table)


# --- generation ------------------------------------------------------------------------


def _rng_of(seed) -> tuple[np.random.Generator, int | None]:
    if isinstance(seed, np.random.Generator):
        return seed, None
    if isinstance(seed, np.random.SeedSequence):
        return np.random.default_rng(seed), None
    s = _whole(seed, "seed", 0)
    return np.random.default_rng(s), s


def random_tree(params: RandomTreeParams, seed: int | np.random.SeedSequence | np.random.Generator,
                *, tree_id: int = 0, keep_draws: bool = False) -> RandomTree:
    """Grow one random tree.

    Parameters
    ----------
    params : the species' laws and constants.
    seed : an integer ≥ 0, a ``SeedSequence`` or a ``Generator`` (consumed).
        The same integer gives the same bytes.
    tree_id : written to ``branches.tree_id``, ``leaves.plant_id`` and the leaf table.
    keep_draws : also return every drawn value (:class:`TreeDraws`).

    Returns
    -------
    RandomTree
        in the tree's own frame: trunk foot at the origin, growing along +z.

    Examples
    --------
    >>> from simlidar_mi.plants.tree_params import species_preset
    >>> t = random_tree(species_preset("conifer-whorl"), seed=7)
    >>> 10 < t.height_m < 30 and len(t.leaves) == 2 * t.n_leaves
    True
    """
    if not isinstance(params, RandomTreeParams):
        raise ConfigError("must be a RandomTreeParams", key="params", value=params)
    rng, int_seed = _rng_of(seed)
    t = _start(params, rng, _whole(tree_id, "tree_id", 0), keep_draws)
    (wood,) = _grow_wood(params, [t])
    return _finish(params, t, wood, int_seed)


def iter_random_trees(params: RandomTreeParams, seeds, tree_ids=None, *,
                      keep_draws: bool = False) -> Iterator[RandomTree]:
    """The trees ``random_tree(params, seeds[k], tree_id=tree_ids[k])``, grown together.

    The wood of all of them grows in lock step (:mod:`simlidar_mi.plants.tree_growth`: one
    numpy pass per generation), then each tree's leaves are made as it is yielded. Every tree
    draws from its own generator in its own order: the trees are those :func:`random_tree`
    grows, bit for bit. ``seeds``: integers ≥ 0 or SeedSequences (not Generators: a tree
    that grows more than ``max_branches`` segments makes them all regrow one by one, so the
    error names the first such tree as :func:`random_tree` would).
    """
    if not isinstance(params, RandomTreeParams):
        raise ConfigError("must be a RandomTreeParams", key="params", value=params)
    seeds = list(seeds)
    tids = list(range(len(seeds))) if tree_ids is None else [int(t) for t in tree_ids]
    if len(tids) != len(seeds):
        raise ConfigError(f"needs one tree id per seed ({len(seeds)})", key="tree_ids", value=tids)
    if any(isinstance(s, np.random.Generator) for s in seeds):
        raise ConfigError("seeds must be integers or SeedSequences", key="seeds", value=seeds)
    if not seeds:
        return
    rngs = [_rng_of(s) for s in seeds]
    trees = [_start(params, rng, _whole(tid, "tree_id", 0), keep_draws)
             for (rng, _), tid in zip(rngs, tids)]
    try:
        woods = _grow_wood(params, trees)
    except ConfigError:
        for s, tid in zip(seeds, tids):   # raises for the first tree that grows too many
            random_tree(params, s, tree_id=tid)
        raise
    # each tree's leaves from its own generator: two trees at a time on two cores, same bits
    yield from ordered_map(lambda a: _finish(params, *a),
                           zip(trees, woods, (int_seed for _, int_seed in rngs)))


def _finish(P: RandomTreeParams, t: _Tree, wood: tuple, int_seed: int | None) -> RandomTree:
    """The leaves (L3) of a tree whose wood has grown, and the tree."""
    p0, p1, r, o, Hb, Ub, depth, n_kids = wood
    tid, rng, draw, G = t.tid, t.rng, t.draw, t.g["growth_level"]
    branches = Branches(p0, p1, 2.0 * r, o.astype(np.int32), np.full(len(r), tid, np.int32))

    # leaves (L3): on terminal branches, the last leaf_levels generations, high orders
    bearing = (n_kids == 0) | (depth >= G - P.leaf_levels) | (o >= P.leaf_min_order)
    bi = np.flatnonzero(bearing)
    counts = scaled_count(t, "leaves_per_branch",
                          draw("leaves_per_branch", P.leaves_per_branch, len(bi)).astype(np.int64))
    owner = np.repeat(bi, counts)
    nleaf = len(owner)
    tpos = rng.random(nleaf)
    phi = rng.uniform(0.0, 2 * np.pi, nleaf)
    lang = np.radians(draw("leaf_angle_deg", P.leaf_angle_deg, nleaf))
    ll = t.g["leaf_length_tree_factor"] * draw("leaf_length_m", P.leaf_length_m, nleaf)
    lw = ll * draw("leaf_width_ratio", P.leaf_width_ratio, nleaf)
    roll = np.radians(draw("leaf_roll_deg", P.leaf_roll_deg, nleaf))
    leaves, table, xy2 = _make_leaves(P, p0, p1, r, Hb, Ub, owner, tpos, phi, lang, ll, lw, roll, tid)
    draws = None
    if t.keep_draws:
        local = {k: np.zeros(0) for k in _LAWS if k not in t.g}  # every local law, drawn or not
        local.update({k: np.concatenate(v) for k, v in t.rec.items()})
        draws = TreeDraws(dict(t.g), local)
    branching = (float(t.tree_flag) if P.lateral_branching_per == "tree"
                 else t.n_flag_true / t.n_flag if t.n_flag else 0.0)
    return RandomTree(branches, leaves, table, int_seed, draws, branching, 1.0, xy2)
