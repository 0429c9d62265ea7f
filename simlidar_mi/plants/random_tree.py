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

Randomness: every tree draws from its own ``numpy.random.Generator`` (from an
integer seed, a ``SeedSequence`` or a Generator), in a fixed order, so the same
seed gives the same bytes and one tree's seed does not affect another tree.
Nothing here imports Mitsuba. Lengths are metres, angles degrees at the API.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from ..geometry import Branches, Leaves
from .laws import _whole
from .tree_leaves import _Z, LeafTable, _cross, _make_leaves, _rotate, _unit
from .tree_params import _LAWS, RandomTreeParams

__all__ = ["RandomTree", "TreeDraws", "random_tree"]


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


def _len(v: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(v, axis=1, keepdims=True)`` bit for bit (it is sqrt(Σ v·v)), without its overhead."""
    return np.sqrt((v * v).sum(1, keepdims=True))


def _bend(H: np.ndarray, U: np.ndarray, tropism: float) -> tuple[np.ndarray, np.ndarray]:
    """Tropism: pull headings toward ±z, then make U perpendicular to H again."""
    if tropism == 0 or not len(H):
        return H, U
    H2 = H + tropism * _Z
    norm = _len(H2)
    # |τ| ≤ 0.95 keeps H + τẑ away from 0 unless H is nearly ∓ẑ; keep H there
    H2 = np.where(norm > 1e-6, H2 / np.maximum(norm, 1e-300), H)
    U2 = U - (U * H2).sum(1, keepdims=True) * H2
    n = _len(U2)
    ok = n > 1e-9
    U2 = U2 / np.maximum(n, 1e-300)
    if not ok.all():   # U ∥ H after the bend: any unit vector ⟂ H will do
        bad = ~ok[:, 0]
        Hb = H2[bad]
        fallback = _cross(Hb, np.where(np.abs(Hb[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]]))
        U2[bad] = _unit(fallback)
    return H2, U2


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
    tid = _whole(tree_id, "tree_id", 0)
    P = params
    rec: dict[str, list] = {}

    def draw(name: str, law, n: int) -> np.ndarray:
        x = law.sample(rng, n)
        if keep_draws:
            rec.setdefault(name, []).append(np.asarray(x))
        return x

    # global draws, fixed order (G1–G3)
    g = {"trunk_length_m": float(P.trunk_length_m.sample(rng)),
         "trunk_radius_m": float(P.trunk_radius_m.sample(rng)),
         "growth_level": int(P.growth_level.sample(rng)),
         "length_ratio": float(P.length_ratio.sample(rng)),
         "radius_ratio": float(P.radius_ratio.sample(rng))}
    g["lateral_length_ratio"] = (float(P.lateral_length_ratio.sample(rng))
                                 if P.lateral_length_ratio is not None else g["length_ratio"])
    g["lateral_radius_ratio"] = (float(P.lateral_radius_ratio.sample(rng))
                                 if P.lateral_radius_ratio is not None else g["radius_ratio"])
    G = g["growth_level"]
    tau = P.tropism
    per_tree = P.lateral_branching_per == "tree"
    # L1 once per tree: one uniform, after the globals (per-branch mode draws none here)
    tree_flag = bool(draw("lateral_branching", P.lateral_branching, 1)[0]) if per_tree else None
    n_flag = n_flag_true = 0

    # frontier of one generation: start, heading H, reference U ⟂ H, length, radius, order
    start = np.zeros((1, 3))
    H = np.array([[0.0, 0.0, 1.0]])
    U = np.array([[1.0, 0.0, 0.0]])
    length = np.array([g["trunk_length_m"]])
    radius = np.array([g["trunk_radius_m"]])
    order = np.array([1], np.int64)
    out_p0, out_p1, out_r, out_o, out_H, out_U, out_depth, out_kids = [], [], [], [], [], [], [], []
    n_total = 0
    for depth in range(G):
        n = len(length)
        if n == 0:
            break
        n_total += n
        if n_total > P.max_branches:
            raise ConfigError(f"tree {tid} grows more than {P.max_branches} branch segments; lower "
                              "growth_level or n_daughters, or raise max_branches",
                              key=f"{P.name}.max_branches", value=P.max_branches)
        end = start + H * length[:, None]
        out_p0.append(start)
        out_p1.append(end)
        out_r.append(radius)
        out_o.append(order)
        out_H.append(H)
        out_U.append(U)
        out_depth.append(np.full(n, depth))
        grows = (length >= P.min_length_m) if depth < G - 1 else np.zeros(n, bool)
        kids = np.zeros(n, np.int64)
        if not grows.any():
            out_kids.append(kids)
            break
        gi = np.flatnonzero(grows)
        ng = len(gi)
        # local draws of the growing branches (L1, L2, L4)
        flag = (np.full(ng, tree_flag) if per_tree
                else draw("lateral_branching", P.lateral_branching, ng))
        n_flag += ng
        n_flag_true += int(flag.sum())
        twist = np.radians(draw("twist_deg", P.twist_deg, ng))
        is_trunk = order[gi] == 1
        m = np.zeros(ng, np.int64)
        if P.trunk_n_daughters is not None:
            if is_trunk.any():
                m[is_trunk] = draw("trunk_n_daughters", P.trunk_n_daughters, int(is_trunk.sum()))
            if (~is_trunk).any():
                m[~is_trunk] = draw("n_daughters", P.n_daughters, int((~is_trunk).sum()))
        else:
            m[:] = draw("n_daughters", P.n_daughters, ng)
        can_lateral = (order[gi] < P.max_order) & ~(is_trunk & (depth < P.bare_trunk_levels))
        m = np.where(can_lateral, m, 0)
        leader = order[gi] <= P.monopodial_orders

        # lateral daughters: mother index, index within the set, position, angle
        mother = np.repeat(np.arange(ng), m)
        k_in = np.arange(len(mother)) - np.repeat(np.cumsum(m) - m, m)
        nl = len(mother)
        t = np.ones(nl)
        lat_flag = flag[mother]
        if lat_flag.any():
            t[lat_flag] = rng.uniform(P.lateral_position_min, 1.0, int(lat_flag.sum()))
        ang = np.empty(nl)
        trunk_mother = is_trunk[mother]
        if P.trunk_branch_angle_deg is not None:
            if trunk_mother.any():
                ang[trunk_mother] = draw("trunk_branch_angle_deg", P.trunk_branch_angle_deg,
                                         int(trunk_mother.sum()))
            if (~trunk_mother).any():
                ang[~trunk_mother] = draw("branch_angle_deg", P.branch_angle_deg,
                                          int((~trunk_mother).sum()))
        else:
            ang[:] = draw("branch_angle_deg", P.branch_angle_deg, nl)
        # leaders (monopodial axes): opposite the first lateral, rolled by the divergence
        li = np.flatnonzero(leader)
        nL = len(li)
        la = draw("leader_angle_deg", P.leader_angle_deg, nL)

        # the next generation, leaders first then laterals. Every step below is row-wise,
        # so leaders and laterals share one pass: a leader turns by twist + π about its
        # mother's axis and tilts by its leader angle, a lateral turns by its azimuth and
        # tilts by its branch angle.
        srcL, src = gi[li], gi[mother]
        s_all = np.concatenate([srcL, src])
        turn = np.concatenate([twist[li] + np.pi,
                               twist[mother] + 2 * np.pi * k_in / np.maximum(m[mother], 1)])
        tilt = np.radians(np.concatenate([la, ang]))
        Hm, Um = H[s_all], U[s_all]
        u = _rotate(Um, Hm, turn)
        c, s_ = np.cos(tilt)[:, None], np.sin(tilt)[:, None]
        Hn = c * Hm + s_ * u
        Un = c * u - s_ * Hm
        if nL:
            Un[:nL] = _rotate(Un[:nL], Hn[:nL], np.full(nL, math.radians(P.divergence_deg)))
        # the trunk's own leader is not bent: stems stay upright
        bent = np.concatenate([order[srcL] > 1, np.ones(nl, bool)])
        if tau != 0 and bent.all():
            Hn, Un = _bend(Hn, Un, tau)
        elif tau != 0 and bent.any():
            Hn[bent], Un[bent] = _bend(Hn[bent], Un[bent], tau)
        # apex-branching (no leader) daughters continue the axis ratio r1; laterals of a led axis use r2
        led = leader[mother]
        lr = np.concatenate([np.full(nL, g["length_ratio"]),
                             np.where(led, g["lateral_length_ratio"], g["length_ratio"])])
        rr = np.concatenate([np.full(nL, g["radius_ratio"]),
                             np.where(led, g["lateral_radius_ratio"], g["radius_ratio"])])
        kids[gi] = m + leader
        out_kids.append(kids)
        start = np.concatenate([end[srcL], start[src] + t[:, None] * (end[src] - start[src])])
        H, U = Hn, Un
        length, radius = length[s_all] * lr, radius[s_all] * rr
        order = np.concatenate([order[srcL], order[src] + 1])
    if len(out_kids) < len(out_p0):
        out_kids.append(np.zeros(len(out_p0[-1]), np.int64))

    p0 = np.concatenate(out_p0)
    p1 = np.concatenate(out_p1)
    r = np.concatenate(out_r)
    o = np.concatenate(out_o)
    Hb = np.concatenate(out_H)
    Ub = np.concatenate(out_U)
    depth = np.concatenate(out_depth)
    n_kids = np.concatenate(out_kids)
    branches = Branches(p0, p1, 2.0 * r, o.astype(np.int32), np.full(len(r), tid, np.int32))

    # leaves (L3): on terminal branches, the last leaf_levels generations, high orders
    bearing = (n_kids == 0) | (depth >= G - P.leaf_levels) | (o >= P.leaf_min_order)
    bi = np.flatnonzero(bearing)
    counts = draw("leaves_per_branch", P.leaves_per_branch, len(bi)).astype(np.int64)
    owner = np.repeat(bi, counts)
    nleaf = len(owner)
    tpos = rng.random(nleaf)
    phi = rng.uniform(0.0, 2 * np.pi, nleaf)
    lang = np.radians(draw("leaf_angle_deg", P.leaf_angle_deg, nleaf))
    ll = draw("leaf_length_m", P.leaf_length_m, nleaf)
    lw = ll * draw("leaf_width_ratio", P.leaf_width_ratio, nleaf)
    roll = np.radians(draw("leaf_roll_deg", P.leaf_roll_deg, nleaf))
    leaves, table, xy2 = _make_leaves(P, p0, p1, r, Hb, Ub, owner, tpos, phi, lang, ll, lw, roll, tid)
    draws = None
    if keep_draws:
        local = {k: np.zeros(0) for k in _LAWS if k not in g}  # every local law, drawn or not
        local.update({k: np.concatenate(v) for k, v in rec.items()})
        draws = TreeDraws(dict(g), local)
    branching = (float(tree_flag) if per_tree
                 else n_flag_true / n_flag if n_flag else 0.0)
    return RandomTree(branches, leaves, table, int_seed, draws, branching, 1.0, xy2)

