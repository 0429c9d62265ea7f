"""L-systems: module strings, grammars, parallel derivation and the 3D turtles.

Parametric, conditional and stochastic productions (ABOP §1.10) are in
:mod:`.grammar` (read by :mod:`.grammar_parse`) and :mod:`.derive`; the
SIMLIDAR apple turtle is :mod:`.turtle`, the ABOP turtle (branches, leaves,
tropism) is :mod:`.abop`, and named plants are in :mod:`.presets`.

Pure numpy; nothing here imports Mitsuba.

>>> from simlidar_mi.lsystem import parse_grammar, derive, format_table1
>>> g = parse_grammar("axiom: F\\nF -> InIn[r+InIn+F]In[R-InF]InF")
>>> format_table1(derive(g, 1))
'[I01I01[t+I01I01+F]I01[T-I01F]I01F]'
"""
from __future__ import annotations

from .abop import LeafTable, TurtleConfig, TurtleGeometry, interpret_abop
from .derive import DEFAULT_MAX_MODULES, apply_interpretation, derive, predict_size
from .expr_compile import ExpressionError
from .grammar import Const, ExprArg, GenerationArg, Grammar, Production, Successor, Word
from .grammar_parse import parse_grammar, parse_modules
from .modules import DEFAULT_ALPHABET, Module, ModuleString
from .notation import format_table1
from .turtle import (INITIAL_FRAME, PRUNE_MODES, branch_diameter_m, branch_length_m,
                     interpret, match_brackets, prune_descending, turtle_segments)

__all__ = [
    "Module", "ModuleString", "DEFAULT_ALPHABET",
    "Grammar", "Production", "Successor", "Word", "Const", "GenerationArg", "ExprArg",
    "parse_grammar", "parse_modules", "ExpressionError",
    "derive", "apply_interpretation", "predict_size", "DEFAULT_MAX_MODULES",
    "interpret_abop", "TurtleConfig", "TurtleGeometry", "LeafTable",
    "format_table1",
    "interpret", "turtle_segments", "prune_descending", "PRUNE_MODES", "match_brackets",
    "branch_length_m", "branch_diameter_m", "INITIAL_FRAME",
]
