"""ABOP turtle: interpret a module string as branches and flat leaves.

The turtle of "The Algorithmic Beauty of Plants" (Prusinkiewicz & Lindenmayer
1990, ABOP, §1.5 and §2.2), vectorised with numpy. The SIMLIDAR apple trees
use their own turtle (:mod:`simlidar_mi.lsystem.turtle`); this one is the
``turtle="abop"`` mode of the presets.

Turtle state
------------
Position ``P`` and a right-handed frame of unit vectors, heading ``H``, left
``L`` and up ``U`` with ``H × L = U``, plus the current width. The initial
frame is the SIMLIDAR one, ``H = +z`` (up), ``L = +x``, ``U = +y``: it is
ABOP's 2D drawing plane (H up the page, L to the right, U into the page)
stood on the ground, seen by a viewer at ``-y`` looking along ``+y``.

Symbols
-------
Angles are degrees (a parameter, or the default ``angle_deg``); lengths are
in the grammar's units times ``length_scale_m``.

``F(l)``   move ``l`` along ``H`` and draw a branch segment (default ``step``).
``f(l)``   move without drawing.
``+(a)``   ``R_U(a)``; ``-(a)`` is ``R_U(-a)``; ``|`` is ``R_U(180)``.
``&(a)``   ``R_L(a)``; ``^(a)`` is ``R_L(-a)``.
``\\(a)``   ``R_H(a)`` (roll left, ABOP); ``/(a)`` is ``R_H(-a)`` (roll right).
``$``      roll about ``H`` so that ``L`` is horizontal: ``L = V × H / |V × H|``,
           ``U = H × L`` with ``V = +z`` (ABOP eq. 2.2; unchanged if ``H ∥ V``).
``!(w)``   set the width (diameter, in width units times ``width_scale_m``).
``[`` ``]`` push / pop the whole state.
``L(l,w)`` a flat leaf of length ``l`` along ``H`` and width ``w`` along ``L``,
           lying in the H–L plane with normal ``U``, its base at ``P``; the
           turtle does not move. ``L(l)`` uses ``w = l · leaf_aspect``.
Every other symbol is ignored (``A``, ``B`` ... are apices).

Roll and turn convention (the one documented and tested)
--------------------------------------------------------
The rotation matrices are ABOP's (p. 19), applied on the right of the frame,
``[H' L' U'] = [H L U] R``::

    R_U(a) = [[ cos a, sin a, 0], [-sin a, cos a, 0], [0, 0, 1]]
    R_L(a) = [[cos a, 0, -sin a], [0, 1, 0], [sin a, 0, cos a]]
    R_H(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]]

so, in vectors:

* ``+(a)``: ``H' = H cos a - L sin a``, ``L' = H sin a + L cos a``;
* ``&(a)``: ``H' = H cos a + U sin a``, ``U' = U cos a - H sin a``;
* ``\\(a)``: ``L' = L cos a + U sin a``, ``U' = U cos a - L sin a`` (a
  right-handed rotation by ``+a`` about ``H``); ``/(a)`` rolls by ``-a``.

From the initial frame, ``\\(90)`` turns ``L`` to ``+y`` and ``U`` to ``-x``;
``+(90)`` turns ``H`` to ``-x``; ``&(90)`` turns ``H`` to ``+y``.

Tropism (ABOP §2.2, Figs 2.7–2.8)
---------------------------------
After every ``F`` (the segment is drawn first), the frame is rotated about
``H × T`` by ``e·|H × T|``: the heading bends toward the vector ``T`` (world
coordinates, ``+z`` up) with susceptibility ``e`` (``elasticity``).

Implementation
--------------
As in :mod:`~simlidar_mi.lsystem.turtle`: every module's state is its base
module's state transformed by the module. Turns are products of small
matrices reduced by pointer jumping. ``$`` and tropism depend on the world
frame (they do not compose as fixed matrices), so they are resolved level by
level: all such modules with the same number of such ancestors at once.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config.checks import real as _real
from ..errors import ConfigError, GrammarError
from ..geometry import Branches, Leaves
from .modules import CLOSE, OPEN, ModuleString
from .turtle import INITIAL_FRAME, _chain_reduce, _nearest_in, match_brackets

#: Turn symbols: symbol -> (axis 0 = H, 1 = L, 2 = U; sign of the angle).
TURNS = {"+": (2, +1), "-": (2, -1), "&": (1, +1), "^": (1, -1), "\\": (0, +1), "/": (0, -1)}
TURN_AROUND = "|"
LEVEL = "$"
WIDTH = "!"
DRAW = "F"
MOVE = "f"
#: World "up" used by ``$`` (ABOP's V, opposite to gravity).
VERTICAL = np.array([0.0, 0.0, 1.0])
LEAF_SHAPES = ("rhombus", "ellipse")


@dataclass(frozen=True)
class TurtleConfig:
    """Settings of the ABOP turtle.

    Attributes
    ----------
    angle_deg : default angle of ``+ - & ^ \\ /`` without a parameter.
    step : default length of ``F`` and ``f`` without a parameter (length units).
    initial_width : width before the first ``!`` (width units).
    length_scale_m : metres per length unit (segment lengths, positions, leaves).
    width_scale_m : metres per width unit (branch diameters).
    tropism : ``T``, world vector (``+z`` up); its length matters (ABOP).
    elasticity : susceptibility ``e`` to tropism (0 = none).
    leaf_symbol : the leaf module.
    leaf_shape : ``'rhombus'`` (2 triangles) or ``'ellipse'`` (``leaf_sides`` triangles).
    leaf_sides : polygon sides of an elliptic leaf (>= 3).
    leaf_length : length of a leaf module without parameters (length units).
    leaf_aspect : width / length of a leaf given only its length.
    """

    angle_deg: float = 45.0
    step: float = 1.0
    initial_width: float = 1.0
    length_scale_m: float = 1.0
    width_scale_m: float = 1.0
    tropism: tuple[float, float, float] = (0.0, 0.0, -1.0)
    elasticity: float = 0.0
    leaf_symbol: str = "L"
    leaf_shape: str = "rhombus"
    leaf_sides: int = 8
    leaf_length: float = 0.1
    leaf_aspect: float = 0.5

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "angle_deg", _real("angle_deg", self.angle_deg))
        set_(self, "step", _real("step", self.step))
        set_(self, "initial_width", _real("initial_width", self.initial_width, nonneg=True))
        set_(self, "length_scale_m", _real("length_scale_m", self.length_scale_m,
                                             positive=True))
        set_(self, "width_scale_m", _real("width_scale_m", self.width_scale_m,
                                            positive=True))
        t = np.asarray(self.tropism, np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ConfigError("must be three finite numbers", key="tropism", value=self.tropism)
        set_(self, "tropism", tuple(float(x) for x in t))
        set_(self, "elasticity", _real("elasticity", self.elasticity))
        if not isinstance(self.leaf_symbol, str) or len(self.leaf_symbol) != 1:
            raise ConfigError("must be one character", key="leaf_symbol",
                              value=self.leaf_symbol)
        if self.leaf_shape not in LEAF_SHAPES:
            raise ConfigError(f"must be one of {', '.join(LEAF_SHAPES)}", key="leaf_shape",
                              value=self.leaf_shape)
        if isinstance(self.leaf_sides, bool) or not isinstance(self.leaf_sides, int) \
                or self.leaf_sides < 3:
            raise ConfigError("must be a whole number >= 3", key="leaf_sides",
                              value=self.leaf_sides)
        set_(self, "leaf_length", _real("leaf_length", self.leaf_length, positive=True))
        set_(self, "leaf_aspect", _real("leaf_aspect", self.leaf_aspect, positive=True))

    @property
    def has_tropism(self) -> bool:
        return self.elasticity != 0.0 and any(self.tropism)


@dataclass(frozen=True)
class LeafTable:
    """One row per leaf: where it is, how it is oriented, how big it is.

    Attributes
    ----------
    base_m, centre_m : (n, 3) leaf base (petiole end) and blade centre, metres.
    heading : (n, 3) unit vector from base to tip.
    normal : (n, 3) unit normal of the blade (the turtle's U).
    length_m, width_m : (n,) blade length and largest width.
    area_m2 : (n,) one-sided area of the leaf's triangles.
    leaf_id : (n,) int32, matching :attr:`Leaves.leaf_id`.
    tree_id : (n,) int32.
    """

    base_m: np.ndarray
    centre_m: np.ndarray
    heading: np.ndarray
    normal: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    area_m2: np.ndarray
    leaf_id: np.ndarray
    tree_id: np.ndarray

    def __len__(self) -> int:
        return len(self.leaf_id)

    @classmethod
    def empty(cls) -> "LeafTable":
        z3, z = np.zeros((0, 3)), np.zeros(0)
        i = np.zeros(0, np.int32)
        return cls(z3, z3, z3, z3, z, z, z, i, i)


@dataclass(frozen=True)
class TurtleGeometry:
    """What the ABOP turtle draws.

    Attributes
    ----------
    branches : one row per ``F`` (order = 1 + bracket depth).
    leaves : the leaf triangles.
    leaf_table : one row per leaf.
    """

    branches: Branches
    leaves: Leaves
    leaf_table: LeafTable = field(default_factory=LeafTable.empty)


def _turn_matrices(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """(m, 3, 3) ABOP matrices R_H / R_L / R_U (module docstring) for each module."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    r = np.zeros((len(axis), 3, 3))
    h, l_, u = axis == 0, axis == 1, axis == 2
    r[h, 0, 0] = 1
    r[h, 1, 1], r[h, 1, 2], r[h, 2, 1], r[h, 2, 2] = c[h], -s[h], s[h], c[h]
    r[l_, 1, 1] = 1
    r[l_, 0, 0], r[l_, 0, 2], r[l_, 2, 0], r[l_, 2, 2] = c[l_], -s[l_], s[l_], c[l_]
    r[u, 2, 2] = 1
    r[u, 0, 0], r[u, 0, 1], r[u, 1, 0], r[u, 1, 1] = c[u], s[u], -s[u], c[u]
    return r


def _rotate_about(vectors: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotate (m, 3, 3) frame columns about unit (m, 3) axes by (m,) angles."""
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    k = axis[:, :, None]                                   # (m, 3, 1)
    kxv = np.cross(axis[:, None, :], np.swapaxes(vectors, 1, 2)).swapaxes(1, 2)
    kdv = np.einsum("mi,mij->mj", axis, vectors)[:, None, :]
    return vectors * c + kxv * s + k * kdv * (1.0 - c)


def _bend(frames: np.ndarray, tropism: np.ndarray, e: float) -> np.ndarray:
    """Tropism: rotate about H × T by e |H × T| (ABOP eq. 2.3)."""
    h = frames[:, :, 0]
    k = np.cross(h, tropism)
    s = np.linalg.norm(k, axis=1)
    ok = s > 1e-15
    out = frames.copy()
    if ok.any():
        out[ok] = _rotate_about(frames[ok], k[ok] / s[ok, None], e * s[ok])
    return out


def _level(frames: np.ndarray) -> np.ndarray:
    """``$``: roll about H so that L is horizontal (unchanged when H is vertical)."""
    h = frames[:, :, 0]
    left = np.cross(VERTICAL, h)
    norm = np.linalg.norm(left, axis=1)
    ok = norm > 1e-12
    out = frames.copy()
    if ok.any():
        left = left[ok] / norm[ok, None]
        out[ok, :, 1] = left
        out[ok, :, 2] = np.cross(h[ok], left)
    return out


def _first_param(modules: ModuleString, idx: np.ndarray, default: float) -> np.ndarray:
    has = modules.nargs[idx] >= 1
    return np.where(has, modules.params[idx, 0] if modules.params.shape[1] else 0.0, default)


def _leaf_triangles(base: np.ndarray, h: np.ndarray, left: np.ndarray, length: np.ndarray,
                    width: np.ndarray, shape: str, sides: int) -> tuple[np.ndarray, int]:
    """(m·t, 3, 3) triangles of m leaves, t per leaf; normals along H × L = U."""
    hl = h * length[:, None]
    wl = left * (width[:, None] / 2.0)
    if shape == "rhombus":
        tip = base + hl
        mid = base + hl / 2.0
        tris = np.stack([np.stack([base, mid - wl, tip], 1),
                         np.stack([base, tip, mid + wl], 1)], 1)
        return tris.reshape(-1, 3, 3), 2
    theta = 2.0 * np.pi * np.arange(sides + 1) / sides
    centre = base + hl / 2.0
    ring = (centre[:, None, :] + np.cos(theta)[None, :, None] * (hl / 2.0)[:, None, :]
            + np.sin(theta)[None, :, None] * wl[:, None, :])          # (m, sides+1, 3)
    tris = np.stack([np.broadcast_to(centre[:, None, :], ring[:, :-1].shape),
                     ring[:, :-1], ring[:, 1:]], 2)                  # (m, sides, 3, 3)
    return tris.reshape(-1, 3, 3), sides


def interpret_abop(modules: ModuleString, config: TurtleConfig | None = None, *,
                   tree_id: int = 0, origin_m=(0.0, 0.0, 0.0),
                   first_leaf_id: int = 0) -> TurtleGeometry:
    """Walk the ABOP turtle over ``modules``.

    Parameters
    ----------
    modules : a derived (and interpreted) word.
    config : turtle settings; default :class:`TurtleConfig()`.
    tree_id : written to every segment and leaf.
    origin_m : the tree base (metres).
    first_leaf_id : id of the first leaf (leaves are numbered in string order).

    Returns
    -------
    TurtleGeometry
        Branches in string order of their ``F``; leaves in string order.

    Raises
    ------
    GrammarError
        unbalanced brackets, ``!`` without a width or a negative width;
        ``position`` is the module index.
    """
    cfg = config or TurtleConfig()
    origin = np.asarray(origin_m, np.float64)
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise ConfigError("must be three finite coordinates (metres)", key="origin_m",
                          value=origin_m)
    n = len(modules)
    codes = modules.codes
    match = match_brackets(modules)
    base = np.arange(n, dtype=np.int64) - 1
    if n:
        after_close = np.flatnonzero(match[:-1] >= 0) + 1
        base[after_close] = match[after_close - 1]      # a pop restores the pushed state

    def mask(sym: str) -> np.ndarray:
        c = modules.code(sym)
        return codes == c if c >= 0 else np.zeros(n, bool)

    # --- local turns -------------------------------------------------------------
    axis = np.full(n, -1, np.int64)
    sign = np.zeros(n)
    for sym, (ax, sg) in TURNS.items():
        m = mask(sym)
        axis[m], sign[m] = ax, sg
    is_around = mask(TURN_AROUND)
    is_turn = (axis >= 0) | is_around
    turn_idx = np.flatnonzero(is_turn)
    angle = np.deg2rad(_first_param(modules, turn_idx, cfg.angle_deg)) * sign[turn_idx]
    around = is_around[turn_idx]
    angle[around] = np.pi
    t_axis = np.where(around, 2, axis[turn_idx])
    mats = _turn_matrices(t_axis, angle)

    # --- frames: linear segments between world-dependent ("key") modules --------------
    is_draw, is_move = mask(DRAW), mask(DRAW) | mask(MOVE)
    is_level = mask(LEVEL)
    is_key = is_level | (is_draw if cfg.has_tropism else np.zeros(n, bool))
    near_tk = _nearest_in(base, is_turn | is_key)
    compact_t = np.full(n + 1, -1, np.int64)
    compact_t[turn_idx] = np.arange(turn_idx.size)
    turn_rel = _chain_reduce(compact_t[near_tk[turn_idx]], mats, np.matmul) \
        if turn_idx.size else np.zeros((0, 3, 3))
    anchor = _nearest_in(base, is_key)

    def pre_rotation(idx: np.ndarray) -> np.ndarray:
        """Turns between each module's anchor and the module (its own turn excluded)."""
        t = compact_t[near_tk[idx]]
        out = np.broadcast_to(np.eye(3), (idx.size, 3, 3)).copy()
        ok = t >= 0
        out[ok] = turn_rel[t[ok]]
        return out

    key_idx = np.flatnonzero(is_key)
    compact_k = np.full(n + 1, -1, np.int64)
    compact_k[key_idx] = np.arange(key_idx.size)
    key_parent = compact_k[anchor[key_idx]]
    key_frames = np.zeros((key_idx.size, 3, 3))
    if key_idx.size:
        level = _chain_reduce(key_parent, np.ones(key_idx.size, np.int64), np.add) - 1
        key_pre = pre_rotation(key_idx)
        key_is_level = is_level[key_idx]
        t_vec = np.asarray(cfg.tropism)
        order = np.argsort(level, kind="stable")
        bounds = np.searchsorted(level[order], np.arange(level.max() + 2))
        for lev in range(level.max() + 1):
            sel = order[bounds[lev]:bounds[lev + 1]]
            par = key_parent[sel]
            w_in = np.where((par >= 0)[:, None, None], key_frames[np.maximum(par, 0)],
                            INITIAL_FRAME)
            w = w_in @ key_pre[sel]
            lv = key_is_level[sel]
            if lv.any():
                w[lv] = _level(w[lv])
            if (~lv).any():
                w[~lv] = _bend(w[~lv], t_vec, cfg.elasticity)
            key_frames[sel] = w

    def frames_before(idx: np.ndarray) -> np.ndarray:
        """World frame in force when each module is reached (before its own action)."""
        a = compact_k[anchor[idx]]
        w_in = np.where((a >= 0)[:, None, None], key_frames[np.maximum(a, 0)]
                        if key_idx.size else INITIAL_FRAME, INITIAL_FRAME)
        return w_in @ pre_rotation(idx)

    # --- positions: chain of moves ---------------------------------------------------
    move_idx = np.flatnonzero(is_move)
    step = _first_param(modules, move_idx, cfg.step) * cfg.length_scale_m
    head = frames_before(move_idx)[:, :, 0] if move_idx.size else np.zeros((0, 3))
    disp = head * step[:, None]
    compact_m = np.full(n + 1, -1, np.int64)
    compact_m[move_idx] = np.arange(move_idx.size)
    p1 = _chain_reduce(compact_m[_nearest_in(base, is_move)[move_idx]], disp, np.add) \
        if move_idx.size else np.zeros((0, 3))
    p0 = p1 - disp

    def position_before(idx: np.ndarray) -> np.ndarray:
        m = compact_m[_nearest_in(base, is_move)[idx]]
        out = np.zeros((idx.size, 3))
        ok = m >= 0
        out[ok] = p1[m[ok]]
        return out

    # --- widths and orders -----------------------------------------------------------
    is_width = mask(WIDTH)
    w_idx = np.flatnonzero(is_width)
    if w_idx.size:
        bad = w_idx[modules.nargs[w_idx] < 1]
        if bad.size:
            raise GrammarError("'!' needs the width, as in !(0.1)", position=int(bad[0]),
                               source="module string")
        neg = w_idx[modules.params[w_idx, 0] < 0]
        if neg.size:
            raise GrammarError(f"width {modules.params[neg[0], 0]!r} must be >= 0",
                               position=int(neg[0]), source="module string")
    width = np.full(n + 1, cfg.initial_width)
    width[w_idx] = modules.params[w_idx, 0] if w_idx.size else 0.0
    depth = np.cumsum(mask(OPEN).astype(np.int64) - mask(CLOSE))

    keep = is_draw[move_idx]
    d_idx = move_idx[keep]
    diameter = width[_nearest_in(base, is_width)[d_idx]] * cfg.width_scale_m
    branches = Branches(p0[keep] + origin, p1[keep] + origin, diameter,
                        (1 + depth[d_idx]).astype(np.int32),
                        np.full(d_idx.size, tree_id, np.int32))

    # --- leaves ----------------------------------------------------------------------
    leaf_idx = np.flatnonzero(mask(cfg.leaf_symbol))
    if not leaf_idx.size:
        return TurtleGeometry(branches, Leaves.empty(), LeafTable.empty())
    nargs = modules.nargs[leaf_idx]
    k = modules.params.shape[1]
    length = np.where(nargs >= 1, modules.params[leaf_idx, 0] if k >= 1 else 0.0,
                      cfg.leaf_length)
    wide = np.where(nargs >= 2, modules.params[leaf_idx, 1] if k >= 2 else 0.0,
                    length * cfg.leaf_aspect)
    if (length <= 0).any() or (wide <= 0).any():
        bad = leaf_idx[(length <= 0) | (wide <= 0)][0]
        raise GrammarError(f"leaf size {modules[int(bad)]} must be > 0", position=int(bad),
                           source="module string")
    length = length * cfg.length_scale_m
    wide = wide * cfg.length_scale_m
    frames = frames_before(leaf_idx)
    h, left, up = frames[:, :, 0], frames[:, :, 1], frames[:, :, 2]
    base_m = position_before(leaf_idx) + origin
    tris, per = _leaf_triangles(base_m, h, left, length, wide, cfg.leaf_shape, cfg.leaf_sides)
    ids = np.arange(first_leaf_id, first_leaf_id + leaf_idx.size, dtype=np.int32)
    leaves = Leaves(tris, np.repeat(ids, per), np.full(len(tris), tree_id, np.int32))
    area = leaves.triangle_area.reshape(-1, per).sum(axis=1)
    table = LeafTable(base_m, base_m + h * (length[:, None] / 2.0), h, up, length, wide,
                      area, ids, np.full(ids.size, tree_id, np.int32))
    return TurtleGeometry(branches, leaves, table)
