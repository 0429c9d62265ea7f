"""The wood of random trees, grown for many trees of one species in lock step.

:func:`simlidar_mi.plants.random_tree.random_tree` describes the grammar. Here each
generation is one numpy pass over the growing branches of *all* the trees given, so a
forest's hundreds of prototypes cost one set of array operations per generation instead
of one per tree. Every tree still draws from its own generator, in the order a tree grown
alone draws (per generation: L1 flags, twists, daughter counts, then lateral positions,
branch angles, leader angles), and every geometric step is row-wise, so a tree grown with
others has the bytes it has grown alone.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from .tree_leaves import _Z, _cross, _rotate, _unit
from .laws import TruncNormal
from .tree_params import RandomTreeParams


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


@dataclass
class _Tree:
    """One tree's generator, global draws and counters while it grows."""

    rng: np.random.Generator
    tid: int
    keep_draws: bool
    g: dict = field(default_factory=dict)
    rec: dict = field(default_factory=dict)
    tree_flag: bool | None = None
    n_flag: int = 0
    n_flag_true: int = 0
    n_total: int = 0

    def draw(self, name: str, law, n: int) -> np.ndarray:
        x = law.sample(self.rng, n)
        if self.keep_draws:
            self.rec.setdefault(name, []).append(np.asarray(x))
        return x


def _start(P: RandomTreeParams, rng: np.random.Generator, tid: int, keep_draws: bool) -> _Tree:
    """The global draws (G1–G3, fixed order) and, per tree, the L1 flag."""
    t = _Tree(rng, tid, keep_draws)
    g = t.g
    g["trunk_length_m"] = float(P.trunk_length_m.sample(rng))
    g["trunk_radius_m"] = float(P.trunk_radius_m.sample(rng))
    g["growth_level"] = int(P.growth_level.sample(rng))
    g["length_ratio"] = float(P.length_ratio.sample(rng))
    g["radius_ratio"] = float(P.radius_ratio.sample(rng))
    g["lateral_length_ratio"] = (float(P.lateral_length_ratio.sample(rng))
                                 if P.lateral_length_ratio is not None else g["length_ratio"])
    g["lateral_radius_ratio"] = (float(P.lateral_radius_ratio.sample(rng))
                                 if P.lateral_radius_ratio is not None else g["radius_ratio"])
    if P.lateral_branching_per == "tree":
        # L1 once per tree: one uniform, after the globals (per-branch mode draws none here)
        t.tree_flag = bool(t.draw("lateral_branching", P.lateral_branching, 1)[0])
    # the tree's own means (seed 004 §II-B varies "mean leaf sizes; mean for the number of
    # daughter branches and the number of leaves" per tree): one factor each, one uniform
    # each, and none when the spread is 0 (so such trees keep their bytes)
    for name in TREE_MEANS:
        cv = getattr(P, f"{name}_tree_cv")
        g[f"{name}_tree_factor"] = float(tree_factor_law(cv).sample(rng)) if cv > 0 else 1.0
    return t


#: The laws whose mean each tree draws for itself (``<name>_tree_cv`` in RandomTreeParams).
TREE_MEANS = ("leaf_length", "n_daughters", "leaves_per_branch")


@functools.lru_cache(maxsize=64)
def tree_factor_law(cv: float) -> TruncNormal:
    """A tree's factor on a law's mean: N(1, cv²) cut to [1 − 3cv, 1 + 3cv] (mean 1 exactly:
    the cut is symmetric), so the species' mean is the law's and trees spread about it by cv."""
    return TruncNormal(1.0, cv, 1.0 - 3.0 * cv, 1.0 + 3.0 * cv)


def scaled_count(t: "_Tree", name: str, counts: np.ndarray) -> np.ndarray:
    """Counts drawn from a species law, moved to the tree's mean: ``floor(f·n + U)``, U uniform
    (mean f·n exactly: randomised rounding). Draws nothing when the tree's factor is 1."""
    f = t.g[f"{name}_tree_factor"]
    if f == 1.0 or not len(counts):
        return counts
    return np.floor(f * counts + t.rng.random(len(counts))).astype(np.int64)


def _segments(ids: np.ndarray, n: int) -> np.ndarray:
    """Start offsets (n + 1) of the runs of ``ids`` (sorted) equal to 0, 1, …, n − 1."""
    return np.concatenate([[0], np.cumsum(np.bincount(ids, minlength=n))])


def _grow_wood(P: RandomTreeParams, trees: list[_Tree]) -> list[tuple[np.ndarray, ...]]:
    """The branch segments of ``trees`` (one species): per tree (p0, p1, r, order, H, U, depth, kids).

    Rows of a generation are grouped by tree, in the order a tree grown alone has them
    (its leaders, then its laterals, each in their mothers' order).
    """
    T = len(trees)
    per_tree = P.lateral_branching_per == "tree"
    G = np.array([t.g["growth_level"] for t in trees])
    LR = np.array([t.g["length_ratio"] for t in trees])
    RR = np.array([t.g["radius_ratio"] for t in trees])
    LLR = np.array([t.g["lateral_length_ratio"] for t in trees])
    LRR = np.array([t.g["lateral_radius_ratio"] for t in trees])
    tau = P.tropism
    # frontier of one generation: tree, start, heading H, reference U ⟂ H, length, radius, order
    tree = np.arange(T)
    start = np.zeros((T, 3))
    H = np.tile([0.0, 0.0, 1.0], (T, 1))
    U = np.tile([1.0, 0.0, 0.0], (T, 1))
    length = np.array([t.g["trunk_length_m"] for t in trees])
    radius = np.array([t.g["trunk_radius_m"] for t in trees])
    order = np.ones(T, np.int64)
    out = []
    for depth in range(int(G.max())):
        n = len(length)
        if n == 0:
            break
        counts = np.bincount(tree, minlength=T)
        for i in np.flatnonzero(counts):
            t = trees[i]
            t.n_total += int(counts[i])
            if t.n_total > P.max_branches:
                raise ConfigError(f"tree {t.tid} grows more than {P.max_branches} branch segments; "
                                  "lower growth_level or n_daughters, or raise max_branches",
                                  key=f"{P.name}.max_branches", value=P.max_branches)
        end = start + H * length[:, None]
        grows = (length >= P.min_length_m) & (depth < G[tree] - 1)
        kids = np.zeros(n, np.int64)
        out.append([tree, start, end, radius, order, H, U, np.full(n, depth), kids])
        gi = np.flatnonzero(grows)
        ng = len(gi)
        if ng == 0:
            break
        gt = tree[gi]
        seg = _segments(gt, T)
        growing = np.flatnonzero(np.diff(seg))
        is_trunk = order[gi] == 1
        # local draws of the growing branches (L1, L2, L4), tree by tree
        flag = np.empty(ng, bool)
        twist = np.empty(ng)
        m = np.zeros(ng, np.int64)
        for i in growing:
            t, sl = trees[i], slice(seg[i], seg[i + 1])
            k = int(seg[i + 1] - seg[i])
            f = (np.full(k, t.tree_flag) if per_tree
                 else t.draw("lateral_branching", P.lateral_branching, k))
            flag[sl] = f
            t.n_flag += k
            t.n_flag_true += int(f.sum())
            twist[sl] = np.radians(t.draw("twist_deg", P.twist_deg, k))
            if P.trunk_n_daughters is not None:
                it, mi = is_trunk[sl], m[sl]
                if it.any():
                    mi[it] = t.draw("trunk_n_daughters", P.trunk_n_daughters, int(it.sum()))
                if (~it).any():
                    mi[~it] = t.draw("n_daughters", P.n_daughters, int((~it).sum()))
            else:
                m[sl] = t.draw("n_daughters", P.n_daughters, k)
            m[sl] = scaled_count(t, "n_daughters", m[sl])
        can_lateral = (order[gi] < P.max_order) & ~(is_trunk & (depth < P.bare_trunk_levels))
        m = np.where(can_lateral, m, 0)
        leader = order[gi] <= P.monopodial_orders

        # lateral daughters: mother index, index within the set, position, angle
        mother = np.repeat(np.arange(ng), m)
        k_in = np.arange(len(mother)) - np.repeat(np.cumsum(m) - m, m)
        nl = len(mother)
        lt = gt[mother]
        t_pos = np.ones(nl)
        lat_flag = flag[mother]
        ang = np.empty(nl)
        trunk_mother = is_trunk[mother]
        li = np.flatnonzero(leader)
        nL = len(li)
        la = np.empty(nL)
        segl, segL = _segments(lt, T), _segments(gt[li], T)
        for i in growing:
            t = trees[i]
            sl, sL = slice(segl[i], segl[i + 1]), slice(segL[i], segL[i + 1])
            lf = lat_flag[sl]
            if lf.any():
                t_pos[sl][lf] = t.rng.uniform(P.lateral_position_min, 1.0, int(lf.sum()))
            tm, ai = trunk_mother[sl], ang[sl]
            if P.trunk_branch_angle_deg is not None:
                if tm.any():
                    ai[tm] = t.draw("trunk_branch_angle_deg", P.trunk_branch_angle_deg, int(tm.sum()))
                if (~tm).any():
                    ai[~tm] = t.draw("branch_angle_deg", P.branch_angle_deg, int((~tm).sum()))
            else:
                ai[:] = t.draw("branch_angle_deg", P.branch_angle_deg, segl[i + 1] - segl[i])
            # leaders (monopodial axes): opposite the first lateral, rolled by the divergence
            la[sL] = t.draw("leader_angle_deg", P.leader_angle_deg, segL[i + 1] - segL[i])

        # the next generation: per tree its leaders, then its laterals. Every step below is
        # row-wise, so all share one pass: a leader turns by twist + π about its mother's
        # axis and tilts by its leader angle, a lateral turns by its azimuth and tilts by
        # its branch angle.
        srcL, src = gi[li], gi[mother]
        nxt = np.concatenate([gt[li], lt])
        perm = np.argsort(2 * nxt + (np.arange(nL + nl) >= nL), kind="stable")
        s_all = np.concatenate([srcL, src])[perm]
        turn = np.concatenate([twist[li] + np.pi,
                               twist[mother] + 2 * np.pi * k_in / np.maximum(m[mother], 1)])[perm]
        tilt = np.radians(np.concatenate([la, ang]))[perm]
        is_lead = perm < nL
        Hm, Um = H[s_all], U[s_all]
        u = _rotate(Um, Hm, turn)
        c, s_ = np.cos(tilt)[:, None], np.sin(tilt)[:, None]
        Hn = c * Hm + s_ * u
        Un = c * u - s_ * Hm
        if nL:
            Un[is_lead] = _rotate(Un[is_lead], Hn[is_lead], np.full(nL, math.radians(P.divergence_deg)))
        # the trunk's own leader is not bent: stems stay upright
        bent = np.concatenate([order[srcL] > 1, np.ones(nl, bool)])[perm]
        if tau != 0 and bent.all():
            Hn, Un = _bend(Hn, Un, tau)
        elif tau != 0 and bent.any():
            Hn[bent], Un[bent] = _bend(Hn[bent], Un[bent], tau)
        # apex-branching (no leader) daughters continue the axis ratio r1; laterals of a led axis use r2
        led = leader[mother]
        lr = np.concatenate([LR[gt[li]], np.where(led, LLR[lt], LR[lt])])[perm]
        rr = np.concatenate([RR[gt[li]], np.where(led, LRR[lt], RR[lt])])[perm]
        kids[gi] = m + leader
        start = np.concatenate([end[srcL], start[src] + t_pos[:, None] * (end[src] - start[src])])[perm]
        H, U = Hn, Un
        length, radius = length[s_all] * lr, radius[s_all] * rr
        order = np.concatenate([order[srcL], order[src] + 1])[perm]
        tree = nxt[perm]

    # per tree, its rows generation by generation
    cols = [np.concatenate(c) for c in zip(*out)]
    by = np.argsort(cols[0], kind="stable")
    seg = _segments(cols[0][by], T)
    cols = [c[by] for c in cols[1:]]
    return [tuple(c[seg[i]:seg[i + 1]] for c in cols) for i in range(T)]
