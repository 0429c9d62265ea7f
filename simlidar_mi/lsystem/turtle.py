"""3D turtle interpretation of SIMLIDAR module strings into branch cylinders.

Turtle state
------------
Position ``P`` and a right-handed frame of unit vectors: heading ``H``, left
``L`` and up ``U`` with ``H × L = U`` (ABOP). The initial frame is

    H = +z (up),  L = +x,  U = +y,

at the tree base. There is no roll about ``H`` (the paper: a cylinder does not
change by rolling about its axis).

Symbols (paper, Table 2)
------------------------
``I(n)``  draw a branch of axis order ``n``: move ``h_n`` along ``H`` and emit a
          cylinder of diameter ``d_n`` (laws below).
``+``     rotate about ``L`` by ``+angle``; ``-`` by ``-angle``.
``T``/``R`` rotate about ``U`` by ``+rotation``; ``t``/``r`` by ``-rotation``.
``[`` ``]`` push / pop the turtle state (position and frame).
``F``     leaf: not drawn (leafless study); every other symbol is ignored.

Sign convention: a positive angle is a right-handed rotation about the named
axis. So ``+`` tips the heading toward ``-U`` (``H' = H cos a - U sin a``) and
``T`` tips it toward ``+L`` (``H' = H cos a + L sin a``). From the initial frame,
``+`` leans a branch toward ``-y`` and ``T`` toward ``+x``.

Laws (paper, section 1)
-----------------------
``h_n = h0 / 2**(n-1)`` and ``d_n = Ns · d_m / n`` with ``Ns`` the number of
substitutions (generations) and ``d_m`` the smallest diameter, reached by the
highest order ``n = Ns``.

Implementation
--------------
Vectorised: every module's state is the state after its *base* module (the
previous module, or the matching ``[`` when the previous module is ``]``),
transformed by the module's own turn. Frames are products of the small
rotation matrices along the chain of turn modules, positions are sums of the
steps along the chain of ``I`` modules; both chains are reduced by pointer
jumping, ``O(n log depth)``, and agree with a sequential stack turtle to
rounding.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, GrammarError
from ..geometry import Branches
from .modules import CLOSE, OPEN, ModuleString

#: Initial heading, left and up vectors (columns of the initial frame).
INITIAL_FRAME = np.array([[0.0, 1.0, 0.0],    # x components of H, L, U
                          [0.0, 0.0, 1.0],    # y
                          [1.0, 0.0, 0.0]])   # z
#: Draw a branch.
DRAW_SYMBOL = "I"
#: symbol -> (axis column, sign, uses 'angle' (True) or 'rotation' (False))
TURN_SYMBOLS = {"+": (1, +1, True), "-": (1, -1, True),
                "T": (2, +1, False), "R": (2, +1, False),
                "t": (2, -1, False), "r": (2, -1, False)}
#: Segments that descend by less than this (metres) count as level, not pruned.
PRUNE_TOLERANCE_M = 1e-12
#: Pruning readings: "subtree" removes a descending segment with everything that grows
#: from it (wood cannot float; the default), "segment" drops the descending segment only.
PRUNE_MODES = ("subtree", "segment")


def branch_length_m(order, h0_m: float) -> np.ndarray:
    """Length of an order-``n`` element, ``h0 / 2**(n-1)`` (metres)."""
    return h0_m / 2.0 ** (np.asarray(order, np.float64) - 1.0)


def branch_diameter_m(order, n_substitutions: int, d_min_m: float) -> np.ndarray:
    """Diameter of an order-``n`` element, ``Ns · d_m / n`` (metres)."""
    return n_substitutions * d_min_m / np.asarray(order, np.float64)


def _rot_about(axis: int, angle_rad: float) -> np.ndarray:
    """Right-handed rotation about body axis ``axis`` (0 = H, 1 = L, 2 = U),
    applied on the right of the frame: ``W' = W @ R``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]      # cyclic: rotate e_i toward e_j
    r = np.eye(3)
    r[i, i] = c
    r[j, j] = c
    r[j, i] = s     # e_i -> c e_i + s e_j
    r[i, j] = -s
    return r


def match_brackets(modules: ModuleString) -> np.ndarray:
    """For every ``]``, the index of its ``[`` (``-1`` elsewhere).

    Raises
    ------
    GrammarError
        unbalanced brackets; ``position`` is the module index at fault.
    """
    codes = modules.codes
    n = len(codes)
    match = np.full(n, -1, np.int64)
    is_o = codes == modules.code(OPEN)
    is_c = codes == modules.code(CLOSE)
    if not n or not (is_o.any() or is_c.any()):
        return match
    depth = np.cumsum(is_o.astype(np.int64) - is_c)
    if depth.min() < 0:
        raise GrammarError("unbalanced brackets: ']' without a matching '['",
                           position=int(np.argmax(depth < 0)), source="module string")
    if depth[-1] != 0:
        suffix_min = np.minimum.accumulate(depth[::-1])[::-1]
        bad = np.flatnonzero(is_o & (depth == 1) & (suffix_min >= 1))
        raise GrammarError("unbalanced brackets: '[' is never closed",
                           position=int(bad[0]) if bad.size else None, source="module string")
    idx = np.flatnonzero(is_o | is_c)
    level = np.where(is_o[idx], depth[idx], depth[idx] + 1)
    pairs = idx[np.lexsort((idx, level))].reshape(-1, 2)   # per level: [ ] [ ] ...
    match[pairs[:, 1]] = pairs[:, 0]
    return match


def _chain_reduce(base: np.ndarray, values: np.ndarray, combine) -> np.ndarray:
    """Inclusive reduction of ``values`` along base chains by pointer jumping.

    ``out[i] = combine(out[base[i]], values[i])`` with ``out[root] = values[root]``
    for ``base = -1``; ``combine(a, b)`` must be associative.
    """
    acc = values.copy()
    anc = base.copy()
    active = np.flatnonzero(anc >= 0)
    while active.size:
        a = anc[active]
        acc[active] = combine(acc[a], acc[active])   # right side read before writing
        anc[active] = anc[a]
        active = active[anc[active] >= 0]
    return acc


def turtle_segments(modules: ModuleString, *, angle_deg: float, rotation_deg: float,
                    step_m: np.ndarray, return_parent: bool = False):
    """Walk the turtle; return the segments drawn by ``I`` modules.

    Parameters
    ----------
    modules : the word to interpret.
    angle_deg, rotation_deg : turn of ``+``/``-`` (about L) and ``T``/``t`` (about U).
    step_m : (n,) step length of every module; only ``I`` modules move.
    return_parent : also return each segment's parent.

    Returns
    -------
    p0, p1 : (m, 3) segment ends relative to the tree base, metres.
    index : (m,) module index of each segment, in string order.
    parent : (m,) only with ``return_parent``: row of the segment this one grows
        from (the one whose end is its start), ``-1`` for a segment at the base.
        A parent always precedes its child.
    """
    n = len(modules)
    codes = modules.codes
    match = match_brackets(modules)
    base = np.arange(n, dtype=np.int64) - 1
    after_close = np.flatnonzero(match[:-1] >= 0) + 1
    base[after_close] = match[after_close - 1]      # a pop restores the pushed state

    # Local turn of every module: index into a small table of rotation matrices.
    mats = [np.eye(3)]
    turn = np.zeros(n, np.int64)
    for sym, (axis, sign, is_angle) in TURN_SYMBOLS.items():
        c = modules.code(sym)
        if c < 0:
            continue
        deg = angle_deg if is_angle else rotation_deg
        mats.append(_rot_about(axis, np.deg2rad(sign * deg)))
        turn[codes == c] = len(mats) - 1
    code_i = modules.code(DRAW_SYMBOL)
    draw = codes == code_i if code_i >= 0 else np.zeros(n, bool)
    is_turn = turn > 0

    # Frames change only at turns: reduce along the chain of turn modules only.
    turn_idx = np.flatnonzero(is_turn)
    compact = np.full(n + 1, -1, np.int64)          # module index -> row among turns
    compact[turn_idx] = np.arange(turn_idx.size)
    near_turn = _nearest_in(base, is_turn)
    turn_parent = compact[near_turn[turn_idx]]
    turn_frames = _chain_reduce(turn_parent, np.asarray(mats)[turn[turn_idx]], np.matmul)
    # A drawing module keeps the frame of its nearest turn ancestor (identity if none).
    idx = np.flatnonzero(draw)
    owner = compact[near_turn[idx]]
    head_body = np.where((owner >= 0)[:, None],
                         turn_frames[np.maximum(owner, 0), :, 0] if turn_idx.size
                         else np.zeros((idx.size, 3)), [1.0, 0.0, 0.0])
    # world heading = INITIAL_FRAME @ (body-to-initial frame) @ e_H
    step = np.asarray(step_m, np.float64)[idx]
    disp = (head_body @ INITIAL_FRAME.T) * step[:, None]

    # Positions change only at drawing modules: sum steps along their own chain.
    compact_d = np.full(n + 1, -1, np.int64)
    compact_d[idx] = np.arange(idx.size)
    draw_parent = compact_d[_nearest_in(base, draw)[idx]]
    p1 = _chain_reduce(draw_parent, disp, np.add)
    # A child starts exactly where its parent ends (p1 - disp would differ by rounding).
    p0 = np.where((draw_parent >= 0)[:, None], p1[np.maximum(draw_parent, 0)], 0.0)
    if return_parent:
        return p0, p1, idx, draw_parent
    return p0, p1, idx


def _nearest_in(base: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """For every module, its nearest strict ancestor (along ``base``) with ``mask``,
    or -1. Pointer jumping; a pointer stops as soon as it reaches a masked module."""
    anc = base.copy()
    ok = np.append(mask, False)            # ok[-1] (root sentinel) is False
    todo = np.flatnonzero((anc >= 0) & ~ok[anc])
    while todo.size:
        anc[todo] = anc[anc[todo]]
        a = anc[todo]
        todo = todo[(a >= 0) & ~ok[a]]
    return anc


def check_prune_mode(value, key: str = "pruning_mode") -> str:
    """``value`` checked against :data:`PRUNE_MODES` (ConfigError naming key and value)."""
    if not isinstance(value, str) or value not in PRUNE_MODES:
        raise ConfigError(f"must be one of {', '.join(map(repr, PRUNE_MODES))}", key=key,
                          value=value)
    return value


def prune_descending(branches: Branches, parent: np.ndarray | None = None, *,
                     mode: str = "subtree", tol_m: float = PRUNE_TOLERANCE_M) -> Branches:
    """Remove the segments whose turtle descends in z (``p1.z < p0.z``).

    Parameters
    ----------
    branches : segments of one or more trees.
    parent : (n,) row of each segment's parent, ``-1`` at a base, parents before
        children (:func:`turtle_segments` with ``return_parent``); needed by "subtree".
    mode : "subtree" (default) also removes everything that grows from a descending
        segment, so no kept wood floats; "segment" drops the descending segments only
        and keeps their children, which then start in mid-air.
    tol_m : level segments whose z differs by rounding only are kept.
    """
    mode = check_prune_mode(mode, "mode")
    cut = branches.p1[:, 2] < branches.p0[:, 2] - tol_m
    if mode == "segment":
        return branches.subset(~cut)
    if parent is None:
        raise ConfigError("subtree pruning needs every segment's parent row", key="parent",
                          value=None)
    parent = np.asarray(parent, np.int64)
    if parent.shape != (len(branches),) or ((parent >= np.arange(len(branches)))
                                           | (parent < -1)).any():
        raise ConfigError("must hold one earlier row (or -1) per segment", key="parent",
                          value=f"shape {parent.shape}")
    # A segment goes when it or any ancestor descends: OR along the parent chain.
    cut = _chain_reduce(parent, cut, np.logical_or)
    return branches.subset(~cut)


def interpret(modules: ModuleString, *, h0_m: float, d_min_m: float, n_substitutions: int,
              angle_deg: float = 20.0, rotation_deg: float = 20.0, prune: bool = False,
              prune_mode: str = "subtree", tree_id: int = 0,
              origin_m=(0.0, 0.0, 0.0)) -> Branches:
    """Turn a SIMLIDAR word into branch cylinders.

    Parameters
    ----------
    modules : derived word; every ``I`` must carry its order, ``I(n)``.
    h0_m : length of an order-1 element (metres).
    d_min_m : smallest diameter ``d_m`` (metres).
    n_substitutions : ``Ns``, the number of generations derived.
    angle_deg, rotation_deg : turns of ``+``/``-`` and ``T``/``t``/``R``/``r``.
    prune : remove descending segments (:func:`prune_descending`).
    prune_mode : "subtree" (default: with everything growing from them) or "segment".
    tree_id : written to every segment.
    origin_m : tree base.

    Returns
    -------
    Branches
        One row per ``I`` module (fewer when pruned), in string order.

    Raises
    ------
    GrammarError
        an ``I`` without an order, an order < 1, or unbalanced brackets.
    """
    code_i = modules.code(DRAW_SYMBOL)
    order = np.zeros(len(modules))
    is_i = modules.codes == code_i
    if is_i.any():  # a word without any I draws nothing (its parameter table may have no column)
        if (modules.nargs[is_i] < 1).any():
            bad = int(np.flatnonzero(is_i & (modules.nargs < 1))[0])
            raise GrammarError("'I' needs its axis order, as in I(1)", position=bad,
                               source="module string")
        order[is_i] = modules.params[is_i, 0]
        if (order[is_i] < 1).any() or not np.isfinite(order[is_i]).all():
            bad = int(np.flatnonzero(is_i & ~(order >= 1))[0])
            raise GrammarError(f"axis order {modules.params[bad, 0]!r} must be >= 1",
                               position=bad, source="module string")
    mode = check_prune_mode(prune_mode, "prune_mode")
    for key, v in (("h0_m", h0_m), ("d_min_m", d_min_m)):
        if not np.isfinite(v) or v <= 0:
            raise ConfigError("must be a finite length > 0 (metres)", key=key, value=v)
    step = np.where(order >= 1, branch_length_m(np.maximum(order, 1), h0_m), 0.0)
    p0, p1, idx, parent = turtle_segments(modules, angle_deg=angle_deg,
                                          rotation_deg=rotation_deg, step_m=step,
                                          return_parent=True)
    o = order[idx]
    origin = np.asarray(origin_m, np.float64)
    br = Branches(p0 + origin, p1 + origin, branch_diameter_m(o, n_substitutions, d_min_m),
                  o.astype(np.int32), np.full(len(idx), tree_id, np.int32))
    return prune_descending(br, parent, mode=mode) if prune else br
