"""Ready-made L-system plants by name: ABOP figures, SIMLIDAR apples, forest species.

A :class:`Preset` bundles a grammar text, its constants, the turtle that
draws it (``"abop"``: :mod:`~simlidar_mi.lsystem.abop`; ``"simlidar"``: the
apple turtle of :mod:`~simlidar_mi.lsystem.turtle`), the default number of
generations, the units and the sources of every constant.

========================== =====================================================
name                       what
========================== =====================================================
simlidar-apple             SIMLIDAR apple tree (Méndez et al., section 1)
simlidar-apple-stochastic  the same, three successors 0.33/0.33/0.34
honda-a ... honda-d        Honda's monopodial trees, ABOP Fig. 2.6 / Table 2.1
sympodial                  Aono & Kunii's sympodial tree, ABOP Fig. 2.7
ternary                    ternary tree with tropism, ABOP Fig. 2.8a
deciduous-apex             forest species: apex-branching broadleaf (elm-like), ~12 m
conifer-whorl              forest species: spruce-like conifer with whorls, ~15 m
broadleaf-monopodial       forest species: Honda-type monopodial broadleaf, ~20 m
shrub                      forest species: multi-stemmed shrub, ~4 m
========================== =====================================================

Units: ABOP gives abstract lengths and line widths. Honda's and the
sympodial trees read lengths as metres and widths (``!(10)`` on the trunk) as
centimetres (``width_scale_m = 0.01``): a 6.5 m Honda tree with a 10 cm
trunk. The ternary tree's ``F(200)`` and ``F(50)`` read as centimetres and its
widths as centimetres. Forest species are written in metres throughout.

Forest species are this project's own grammars (not from a paper), with sizes
from common field values: trunk diameters of 5–45 cm, heights of 4–20 m,
leaves of 6–12 cm. Each is stochastic (a seed gives one tree) and puts leaves
on its young shoots and apices with an ``interpretation:`` section; one tree
has 7–80 thousand leaves (one-sided leaf area 40–180 m²).

Example
-------
>>> from simlidar_mi.plants.presets import preset_measures
>>> m = preset_measures("honda-a")
>>> m["n_segments"], round(m["height"], 3)
(1023, 6.513)
"""
from __future__ import annotations

import json
import math
import operator
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Mapping

import numpy as np

from ..errors import ConfigError
from ..geometry import Leaves
from ..lsystem.abop import LeafTable, TurtleConfig, TurtleGeometry, interpret_abop
from ..lsystem.derive import DEFAULT_MAX_MODULES, apply_interpretation, derive
from ..lsystem.grammar import Grammar
from ..lsystem.grammar_parse import parse_grammar
from ..lsystem.modules import ModuleString

TURTLES = ("abop", "simlidar")


@dataclass(frozen=True)
class Preset:
    """A named plant.

    Attributes
    ----------
    name : registry key.
    description : one line.
    grammar : grammar text (:mod:`~simlidar_mi.lsystem.grammar_parse` format).
    turtle : ``'abop'`` or ``'simlidar'``.
    generations : default number of generations; ``None``: the grammar's
        ``derivation length``.
    units : how grammar lengths and widths map to metres.
    source : where the grammar and every constant come from.
    constants : overrides of the grammar's ``define:`` values.
    turtle_config : ABOP turtle settings (``turtle='abop'``).
    simlidar : apple-turtle settings (``turtle='simlidar'``): keyword arguments of
        :class:`~simlidar_mi.plants.apple.AppleTreeParams` other than ``iterations``.
    """

    name: str
    description: str
    grammar: str
    turtle: str
    generations: int | None
    units: str
    source: str
    constants: Mapping[str, float] = field(default_factory=dict)
    turtle_config: TurtleConfig | None = None
    simlidar: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.turtle not in TURTLES:
            raise ConfigError(f"must be one of {', '.join(TURTLES)}", key="turtle",
                              value=self.turtle)


# --- ABOP chapter 2 --------------------------------------------------------------------
HONDA_GRAMMAR = """\
# Honda's monopodial tree-like structures (ABOP Fig. 2.6, L-system p. 56)
alphabet: A B C F ! & / + - $
define: r1 = 0.9, r2 = 0.6, a0 = 45, a2 = 45   # Table 2.1, set a
define: d = 137.5, wr = 0.707                  # divergence angle, width decrease rate
axiom: A(1,10)
derivation length: 10
productions:
A(l,w) -> !(w)F(l)[&(a0)B(l*r2,w*wr)]/(d)A(l*r1,w*wr)
B(l,w) -> !(w)F(l)[-(a2)$C(l*r2,w*wr)]C(l*r1,w*wr)
C(l,w) -> !(w)F(l)[+(a2)$B(l*r2,w*wr)]B(l*r1,w*wr)
"""

#: ABOP Table 2.1: (r1, r2, a0, a2) of Fig. 2.6 a-d.
HONDA_TABLE_2_1 = {"a": (0.9, 0.6, 45.0, 45.0), "b": (0.9, 0.9, 45.0, 45.0),
                   "c": (0.9, 0.8, 45.0, 45.0), "d": (0.9, 0.7, 30.0, -30.0)}

SYMPODIAL_GRAMMAR = """\
# Sympodial tree-like structure of Aono and Kunii (ABOP Fig. 2.7, L-system p. 59)
alphabet: A B F ! & / + - $
define: r1 = 0.9, r2 = 0.7     # contraction ratios
define: a1 = 10, a2 = 60       # branching angles
define: wr = 0.707             # width decrease rate
axiom: A(1,10)
derivation length: 10
productions:
A(l,w) -> !(w)F(l)[&(a1)B(l*r1,w*wr)]/(180)[&(a2)B(l*r2,w*wr)]
B(l,w) -> !(w)F(l)[+(a1)$B(l*r1,w*wr)][-(a2)$B(l*r2,w*wr)]
"""

TERNARY_GRAMMAR = """\
# Tree-like structure with ternary branching and tropism (ABOP Fig. 2.8, p. 60)
alphabet: A F ! & /
define: d1 = 94.74, d2 = 132.63   # divergence angles
define: a = 18.95                 # branching angle
define: lr = 1.109, vr = 1.732    # elongation rate, width increase rate
axiom: !(1)F(200)/(45)A
derivation length: 6
productions:
A -> !(vr)F(50)[&(a)F(50)A]/(d1)[&(a)F(50)A]/(d2)[&(a)F(50)A]
F(l) -> F(l*lr)
!(w) -> !(w*vr)
"""

# --- forest species (this project; metres) ---------------------------------------------
DECIDUOUS_APEX_GRAMMAR = """\
# Apex-branching deciduous tree (elm-like vase): every axis ends in a fork of two
# or three daughters at its apex (Wahed et al. 2021, L1 = false), one of them
# nearly upright; secondary growth elongates and thickens old wood (ABOP Fig.
# 2.8 scheme); leaves on the two youngest internodes and at every apex. Metres.
alphabet: A F f ! & ^ / L
define: d1 = 94.74, d2 = 132.63   # divergence angles (ABOP Fig. 2.8)
define: a = 22                    # branching angle, degrees
define: lr = 1.06                 # yearly elongation of older internodes
define: vr = 1.45                 # yearly width increase of older wood
define: w0 = 0.008                # diameter of a new shoot, m
define: s0 = 0.38                 # length of a new internode, m
define: ll = 0.09, lw = 0.05      # leaf blade length and width, m
axiom: !(w0)F(2.2)/(45)A
derivation length: 9
productions:
A -> (0.6) !(w0)F(s0)[&(a*0.25)F(s0)A]/(d1)[&(a)F(s0)A]/(d2)[&(a)F(s0)A]
   | (0.4) !(w0)F(s0)[&(a*0.25)F(s0)A]/(180)[&(a*1.2)F(s0)A]
F(l) -> F(l*lr)
!(w) -> !(w*vr)
interpretation:
F(l) : l < s0*1.1 -> F(l)[&(50)L(ll,lw)][/(137.5)f(-l*0.25)&(50)L(ll,lw)][/(275)f(-l*0.5)&(50)L(ll,lw)][/(52.5)f(-l*0.75)&(50)L(ll,lw)]
F(l) : l < s0*lr*1.05 -> F(l)[&(55)L(ll,lw)][/(137.5)f(-l*0.33)&(55)L(ll,lw)][/(275)f(-l*0.67)&(55)L(ll,lw)]
A -> [&(20)L(ll,lw)][/(90)&(40)L(ll,lw)][/(180)&(40)L(ll,lw)][/(270)&(40)L(ll,lw)]
"""

CONIFER_WHORL_GRAMMAR = """\
# Spruce-like conifer: a monopodial leader adds one internode and a whorl of
# 4-5 branches a year; branches grow one segment a year and carry side shoots
# that stop after 5 years; foliage is modelled as flat needle shoots. Widths
# are !(w, g): diameter w (m) growing by the factor g a year. Metres.
alphabet: A B C F ! & ^ / + - $ L
define: h = 0.6          # leader internode, m a year
define: lb = 0.13        # branch segment, m a year
define: ls = 0.09        # side-shoot segment, m a year
define: gt = 1.15, gb = 1.07    # yearly diameter growth of trunk and branch wood
define: pa = 82          # branch angle from the trunk, degrees
define: nl = 0.12, nw = 0.045   # needle shoot length and width, m
axiom: !(0.012,gt)F(0.3)A
derivation length: 25
productions:
A -> (0.5) !(0.012,gt)F(h)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(36)A
   | (0.3) !(0.012,gt)F(h*0.85)[&(pa)B(0)]/(90)[&(pa)B(0)]/(90)[&(pa)B(0)]/(90)[&(pa)B(0)]/(45)A
   | (0.2) !(0.012,gt)F(h*1.15)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(72)[&(pa)B(0)]/(36)A
B(k) -> !(0.006,gb)F(lb)[-(55)$C(0)][+(55)$C(0)]B(k+1)
C(k) : k < 5 -> !(0.003,1)F(ls)[^(35)L(nl,nw)][&(35)L(nl,nw)][-(40)L(nl,nw)][+(40)L(nl,nw)]C(k+1)
C(k) : k >= 5 -> L(nl,nw)
!(w,g) -> !(w*g,g)
interpretation:
A -> [L(nl,nw)]
B(k) -> [-(40)L(nl,nw)][+(40)L(nl,nw)]L(nl,nw)
C(k) -> L(nl,nw)
"""

BROADLEAF_MONOPODIAL_GRAMMAR = """\
# Monopodial broadleaf (beech/ash-like), Honda's model (ABOP Fig. 2.6) in
# metres on a 3 m bole, with occasional abortion of laterals; leaves along the
# thin outer shoots and a leafy shoot at every apex. Metres.
alphabet: A B C F f ! & ^ / + - $ L
define: r1 = 0.9, r2 = 0.65     # contraction ratios of the trunk and the laterals
define: a0 = 50, a2 = 40        # branching angles from the trunk and of laterals
define: d = 137.5, wr = 0.66    # divergence angle, width decrease rate
define: ll = 0.085, lw = 0.05   # leaf blade length and width, m
define: sl = 0.45               # internodes shorter than this (m) carry leaves
axiom: !(0.45)F(3)A(2.2,0.45)
derivation length: 13
productions:
A(l,w) -> !(w)F(l)[&(a0)B(l*r2,w*wr)]/(d)A(l*r1,w*wr)
B(l,w) -> (0.85) !(w)F(l)[-(a2)$C(l*r2,w*wr)]C(l*r1,w*wr)
        | (0.15) !(w)F(l)C(l*r1,w*wr)
C(l,w) -> (0.85) !(w)F(l)[+(a2)$B(l*r2,w*wr)]B(l*r1,w*wr)
        | (0.15) !(w)F(l)B(l*r1,w*wr)
interpretation:
F(l) : l < sl -> F(l)[&(60)L(ll,lw)][/(90)f(-l*0.15)&(60)L(ll,lw)][/(180)f(-l*0.3)&(60)L(ll,lw)][/(270)f(-l*0.45)&(60)L(ll,lw)][/(45)f(-l*0.6)&(60)L(ll,lw)][/(135)f(-l*0.75)&(60)L(ll,lw)][/(225)f(-l*0.9)&(60)L(ll,lw)]
A(l,w) -> !(0.006)F(0.1)[&(45)L(ll,lw)]/(137.5)[&(45)L(ll,lw)]/(137.5)F(0.1)[&(50)L(ll,lw)]/(137.5)[&(50)L(ll,lw)]L(ll,lw)
B(l,w) -> !(0.005)F(0.1)[&(45)L(ll,lw)]/(137.5)[&(45)L(ll,lw)]/(137.5)F(0.1)[&(50)L(ll,lw)]/(137.5)[&(50)L(ll,lw)]/(137.5)F(0.08)[&(55)L(ll,lw)]/(137.5)[&(55)L(ll,lw)]L(ll,lw)
C(l,w) -> !(0.005)F(0.1)[&(45)L(ll,lw)]/(137.5)[&(45)L(ll,lw)]/(137.5)F(0.1)[&(50)L(ll,lw)]/(137.5)[&(50)L(ll,lw)]/(137.5)F(0.08)[&(55)L(ll,lw)]/(137.5)[&(55)L(ll,lw)]L(ll,lw)
"""

SHRUB_GRAMMAR = """\
# Multi-stemmed shrub (hazel-like): five stems from the ground, each a
# sympodial axis (ABOP Fig. 2.7 scheme) that forks in two, sometimes one,
# arching under gravitropism; leafy shoots at the apices. Metres.
alphabet: S F f ! & / + - $ L
define: r1 = 0.86, r2 = 0.72    # contraction ratios
define: a1 = 18, a2 = 42        # branching angles
define: wr = 0.74               # width decrease rate
define: ll = 0.10, lw = 0.08    # leaf blade length and width, m
axiom: [&(10)S(0.8,0.045)]/(72)[&(16)S(0.7,0.04)]/(72)[&(6)S(0.9,0.05)]/(72)[&(20)S(0.65,0.035)]/(72)[&(13)S(0.75,0.045)]
derivation length: 9
productions:
S(l,w) -> (0.8) !(w)F(l)[+(a1)$S(l*r1,w*wr)][-(a2)$S(l*r2,w*wr)]
        | (0.2) !(w)F(l)[+(a1*0.5)$S(l*r1,w*wr)]
interpretation:
F(l) : l < 0.3 -> F(l)[&(55)L(ll,lw)][/(137.5)f(-l*0.33)&(55)L(ll,lw)][/(275)f(-l*0.67)&(55)L(ll,lw)]
S(l,w) -> !(0.004)F(0.1)[&(45)L(ll,lw)]/(137.5)[&(45)L(ll,lw)]/(137.5)F(0.1)[&(50)L(ll,lw)]/(137.5)[&(50)L(ll,lw)]/(137.5)F(0.08)[&(55)L(ll,lw)]/(137.5)[&(55)L(ll,lw)]L(ll,lw)
"""


def _simlidar_text(stochastic: bool) -> str:
    from .apple import (SIMLIDAR_APPLE_GRAMMAR,  # lazy: plants imports lsystem
                                SIMLIDAR_APPLE_STOCHASTIC_GRAMMAR)
    return SIMLIDAR_APPLE_STOCHASTIC_GRAMMAR if stochastic else SIMLIDAR_APPLE_GRAMMAR


_ABOP_SOURCE = ("Prusinkiewicz & Lindenmayer (1990), The Algorithmic Beauty of Plants "
                "(ABOP), ch. 2")
_HONDA_WIDTHS = TurtleConfig(width_scale_m=0.01)
_FOREST_SOURCE = ("simlidar-mi forest species (own grammar, issue #4); structure after "
                  "ABOP ch. 2 and Wahed et al. (2021) §II; sizes are typical field values, "
                  "not fitted to measurements")


def _build_registry() -> dict[str, Preset]:
    reg: dict[str, Preset] = {}
    for stochastic, name in ((False, "simlidar-apple"), (True, "simlidar-apple-stochastic")):
        reg[name] = Preset(
            name, "SIMLIDAR apple tree" + (", stochastic (0.33/0.33/0.34)" if stochastic
                                          else ""),
            grammar="", turtle="simlidar", generations=7,
            units="metres: h0_m = 0.4 m order-1 element, d_min_m = 5 mm",
            source="Méndez et al. (SIMLIDAR), section 1 and Table 2; angles 20° (section 4); "
                   "h0_m = 0.4 m chosen in simlidar_mi.plants.apple (the paper gives none)",
            simlidar={"stochastic": stochastic})
    for key, (r1, r2, a0, a2) in HONDA_TABLE_2_1.items():
        reg[f"honda-{key}"] = Preset(
            f"honda-{key}", f"Honda's monopodial tree, ABOP Fig. 2.6{key}",
            HONDA_GRAMMAR, "abop", None,
            units="lengths in metres (axiom A(1,10): 1 m), widths in cm (width_scale_m 0.01)",
            source=f"{_ABOP_SOURCE}: L-system of Fig. 2.6 (d = 137.5°, wr = 0.707, axiom "
                   f"A(1,10), n = 10) and Table 2.1 set {key}: r1 = {r1}, r2 = {r2}, "
                   f"a0 = {a0:g}°, a2 = {a2:g}°",
            constants={"r1": r1, "r2": r2, "a0": a0, "a2": a2},
            turtle_config=_HONDA_WIDTHS)
    reg["sympodial"] = Preset(
        "sympodial", "Aono & Kunii's sympodial tree, ABOP Fig. 2.7",
        SYMPODIAL_GRAMMAR, "abop", None,
        units="lengths in metres (axiom A(1,10): 1 m), widths in cm (width_scale_m 0.01)",
        source=f"{_ABOP_SOURCE}: L-system of Fig. 2.7 (p. 59): r1 = 0.9, r2 = 0.7, "
               f"a1 = 10°, a2 = 60°, wr = 0.707, axiom A(1,10), n = 10",
        turtle_config=_HONDA_WIDTHS)
    reg["ternary"] = Preset(
        "ternary", "Ternary branching tree with tropism, ABOP Fig. 2.8a",
        TERNARY_GRAMMAR, "abop", None,
        units="lengths and widths in cm (F(200) = 2 m; length_scale_m = width_scale_m = 0.01)",
        source=f"{_ABOP_SOURCE}: L-system of Fig. 2.8 (p. 60): d1 = 94.74°, d2 = 132.63°, "
               f"a = 18.95°, lr = 1.109, vr = 1.732; Fig. 2.8a: T = (0, -1, 0) with ABOP's "
               f"y up, i.e. (0, 0, -1) here, e = 0.22, n = 6",
        turtle_config=TurtleConfig(length_scale_m=0.01, width_scale_m=0.01,
                                   tropism=(0.0, 0.0, -1.0), elasticity=0.22))
    reg["deciduous-apex"] = Preset(
        "deciduous-apex", "Apex-branching deciduous tree (elm-like vase), ~12 m, leaves",
        DECIDUOUS_APEX_GRAMMAR, "abop", None, units="metres",
        source=f"{_FOREST_SOURCE}. Divergence angles d1, d2 from ABOP Fig. 2.8; leaves "
               f"9 × 5 cm (elm), trunk ~0.23 m",
        turtle_config=TurtleConfig(tropism=(0.0, 0.0, -1.0), elasticity=0.03,
                                   leaf_shape="rhombus"))
    reg["conifer-whorl"] = Preset(
        "conifer-whorl", "Spruce-like conifer with whorls, ~15 m, needle shoots",
        CONIFER_WHORL_GRAMMAR, "abop", None, units="metres",
        source=f"{_FOREST_SOURCE}. 4-5 branches a whorl and a 0.6 m leader a year "
               f"(Norway spruce); foliage as 12 × 4.5 cm needle shoots",
        turtle_config=TurtleConfig(tropism=(0.0, 0.0, -1.0), elasticity=0.03,
                                   leaf_shape="rhombus"))
    reg["broadleaf-monopodial"] = Preset(
        "broadleaf-monopodial", "Monopodial broadleaf (beech/ash-like), ~20 m, leaves",
        BROADLEAF_MONOPODIAL_GRAMMAR, "abop", None, units="metres",
        source=f"{_FOREST_SOURCE}. Honda's scheme and d = 137.5° from ABOP Fig. 2.6; "
               f"leaves 8.5 × 5 cm (beech)",
        turtle_config=TurtleConfig(tropism=(0.0, 0.0, -1.0), elasticity=0.02,
                                   leaf_shape="ellipse", leaf_sides=6))
    reg["shrub"] = Preset(
        "shrub", "Multi-stemmed shrub (hazel-like), ~4 m, leaves",
        SHRUB_GRAMMAR, "abop", None, units="metres",
        source=f"{_FOREST_SOURCE}. Sympodial scheme from ABOP Fig. 2.7; leaves 10 × 8 cm "
               f"(hazel)",
        turtle_config=TurtleConfig(tropism=(0.0, 0.0, -1.0), elasticity=0.04,
                                   leaf_shape="ellipse", leaf_sides=6))
    return reg


PRESETS: dict[str, Preset] = _build_registry()
#: The forest species (presets with leaves, in metres).
FOREST_SPECIES = ("deciduous-apex", "conifer-whorl", "broadleaf-monopodial", "shrub")


def preset_names() -> list[str]:
    """Names of every preset, in registry order."""
    return list(PRESETS)


def get_preset(name: str) -> Preset:
    """The preset called ``name``.

    Raises
    ------
    ConfigError
        unknown name; the message lists the valid ones.
    """
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown preset; choose one of {', '.join(PRESETS)}",
                          key="preset", value=name) from None


@lru_cache(maxsize=64)
def _grammar(name: str, constants: tuple[tuple[str, float], ...]) -> Grammar:
    p = get_preset(name)
    text = _simlidar_text(bool(p.simlidar.get("stochastic"))) if p.turtle == "simlidar" \
        else p.grammar
    merged = {**p.constants, **dict(constants)}
    return parse_grammar(text, f"preset {name}", constants=merged or None)


def preset_grammar(name: str, constants: Mapping[str, float] | None = None) -> Grammar:
    """The parsed grammar of a preset (cached), with optional constant overrides."""
    return _grammar(name, tuple(sorted((constants or {}).items())))


def _generations(p: Preset, generations) -> int:
    if generations is None:
        if p.generations is not None:
            return p.generations
        return int(preset_grammar(p.name).derivation_length)
    try:
        g = operator.index(generations)
    except TypeError:
        raise ConfigError("must be a whole number >= 0", key="generations",
                          value=generations) from None
    if isinstance(generations, bool) or g < 0 or (p.turtle == "simlidar" and g < 1):
        raise ConfigError("must be a whole number >= " + ("1" if p.turtle == "simlidar"
                                                         else "0"),
                          key="generations", value=generations)
    return g


def preset_word(name: str, generations: int | None = None, seed: int = 0, *,
                constants: Mapping[str, float] | None = None,
                max_modules: int = DEFAULT_MAX_MODULES) -> ModuleString:
    """The derived word of a preset, interpretation productions applied.

    Parameters
    ----------
    name : preset name (:func:`preset_names`).
    generations : default the preset's.
    seed : ``numpy.random.default_rng(seed)`` drives the stochastic choices.
    constants : overrides of the grammar's constants.
    max_modules : size guard of :func:`~simlidar_mi.lsystem.derive.derive`.
    """
    p = get_preset(name)
    g = _generations(p, generations)
    grammar = preset_grammar(name, constants)
    rng = np.random.default_rng(_seed(seed))
    word = derive(grammar, g, rng, max_modules=max_modules)
    return apply_interpretation(grammar, word, rng, generation=g, max_modules=max_modules)


def _seed(seed) -> int:
    try:
        s = operator.index(seed)
    except TypeError:
        raise ConfigError("must be a whole number >= 0", key="seed", value=seed) from None
    if isinstance(seed, bool) or s < 0:
        raise ConfigError("must be a whole number >= 0", key="seed", value=seed)
    return s


def preset_geometry(name: str, generations: int | None = None, seed: int = 0, *,
                    constants: Mapping[str, float] | None = None, tree_id: int = 0,
                    origin_m=(0.0, 0.0, 0.0),
                    max_modules: int = DEFAULT_MAX_MODULES) -> TurtleGeometry:
    """Branches, leaves and the leaf table of one preset plant.

    Parameters
    ----------
    name : preset name (:func:`preset_names`).
    generations : default the preset's.
    seed : drives every stochastic choice; the same seed gives the same bytes.
    constants : overrides of the grammar's constants (ABOP presets).
    tree_id : written to every segment and leaf.
    origin_m : the plant's base, metres.
    max_modules : size guard.

    Returns
    -------
    TurtleGeometry
        ``.branches`` (:class:`~simlidar_mi.geometry.Branches`), ``.leaves``
        (:class:`~simlidar_mi.geometry.Leaves`, empty for leafless presets) and
        ``.leaf_table`` (base, centre, heading, normal, length, width, area per leaf).

    Raises
    ------
    ConfigError
        unknown preset or bad argument.
    DerivationTooLarge
        too many generations for ``max_modules``.
    """
    p = get_preset(name)
    g = _generations(p, generations)
    if p.turtle == "simlidar":
        from .apple import AppleTreeParams, apple_tree
        if constants:
            raise ConfigError("the SIMLIDAR presets have no grammar constants",
                              key="constants", value=dict(constants))
        params = AppleTreeParams(g, max_modules=max_modules, **p.simlidar)
        rng = np.random.default_rng(_seed(seed)) if params.stochastic else None
        branches = apple_tree(params, rng, tree_id=tree_id, base_m=origin_m)
        return TurtleGeometry(branches, Leaves.empty(), LeafTable.empty())
    word = preset_word(name, g, seed, constants=constants, max_modules=max_modules)
    return interpret_abop(word, p.turtle_config, tree_id=tree_id, origin_m=origin_m)


def geometry_measures(geometry: TurtleGeometry, base_z_m: float = 0.0) -> dict:
    """Size measures of one plant's geometry (JSON-ready).

    Returns
    -------
    dict
        ``n_segments``, ``total_length`` (m, sum of segment lengths), ``height``
        (m, highest point of wood or leaves above ``base_z_m``), ``min_width``
        (m, smallest branch diameter), ``n_leaves``, ``leaf_area`` (m², one-sided)
        and the wood measures of :func:`simlidar_mi.plants.measures.wood_measures`
        (``V_L_m3``, ``A_L_m2``, ``A_PR_m2``, ``A_PR_exact_m2``).
    """
    from .measures import wood_measures
    b, table = geometry.branches, geometry.leaf_table
    top = [b.p0[:, 2].max(), b.p1[:, 2].max()] if len(b) else []
    if len(geometry.leaves):
        top.append(geometry.leaves.vertices[:, :, 2].max())
    wood = wood_measures(b).total.to_dict()
    wood.pop("n_branches")
    return {"n_segments": int(len(b)), "total_length": float(b.length.sum()),
            "height": float(max(top) - base_z_m) if top else 0.0,
            "min_width": float(b.diameter.min()) if len(b) else 0.0,
            "n_leaves": int(len(table)), "leaf_area": float(table.area_m2.sum()), **wood}


def preset_measures(name: str, generations: int | None = None, seed: int = 0, *,
                    constants: Mapping[str, float] | None = None) -> dict:
    """:func:`geometry_measures` of :func:`preset_geometry`, with the preset's settings.

    Returns
    -------
    dict
        The measures plus ``preset``, ``generations``, ``seed`` and ``units``
        (the unit of every measure).
    """
    p = get_preset(name)
    g = _generations(p, generations)
    m = geometry_measures(preset_geometry(name, g, seed, constants=constants))
    units = {"total_length": "m", "height": "m", "min_width": "m", "leaf_area": "m2",
             "V_L_m3": "m3", "A_L_m2": "m2", "A_PR_m2": "m2", "A_PR_exact_m2": "m2"}
    return {"preset": name, "generations": g, "seed": _seed(seed), **m, "units": units}


def format_measures(m: dict) -> str:
    """A small text table of :func:`preset_measures` (for the CLI)."""
    rows = [("preset", m["preset"]), ("generations", m["generations"]), ("seed", m["seed"])]
    for k, v in m.items():
        if k in ("preset", "generations", "seed", "units"):
            continue
        unit = m["units"].get(k, "")
        rows.append((k + (f" [{unit}]" if unit and not k.endswith(unit) else ""),
                     f"{v:.6g}" if isinstance(v, float) else v))
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def measures_json(m: dict) -> str:
    """:func:`preset_measures` as JSON text (non-finite numbers refused)."""
    for k, v in m.items():
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError("is not finite", key=k, value=v)
    return json.dumps(m, indent=2)
