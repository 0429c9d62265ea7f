"""L-system grammars as data: parameter templates, words, productions and the grammar."""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Mapping

import numpy as np

from ..errors import GrammarError
from .expressions import Expression
from .modules import GENERATION_TOKEN, ModuleString, format_number


# --- parameters ---------------------------------------------------------------------
@dataclass(frozen=True)
class Const:
    """A literal parameter value."""

    value: float

    def __str__(self) -> str:
        return format_number(self.value)


@dataclass(frozen=True)
class GenerationArg:
    """The generation that writes the module (``n`` in a successor)."""

    def __str__(self) -> str:
        return GENERATION_TOKEN


@dataclass(frozen=True, eq=False)
class ExprArg:
    """A parameter computed from the predecessor's parameters (``l*r1``).

    Attributes
    ----------
    expression : compiled; its free names are formal parameters and ``n``.
    """

    expression: Expression

    def __str__(self) -> str:
        return self.expression.text


Arg = Const | GenerationArg | ExprArg


@dataclass(frozen=True, eq=False)
class Word:
    """A successor (or axiom) template: symbols with argument templates.

    Attributes
    ----------
    codes : (m,) int16, symbol codes in the grammar's alphabet.
    args : one tuple of :data:`Arg` per module.
    text : the source text of the word.
    """

    codes: np.ndarray
    args: tuple[tuple[Arg, ...], ...]
    text: str = ""

    def __len__(self) -> int:
        return len(self.codes)

    @cached_property
    def width(self) -> int:
        """Largest number of parameters of one module."""
        return max((len(a) for a in self.args), default=0)

    @cached_property
    def nargs(self) -> np.ndarray:
        return np.array([len(a) for a in self.args], np.uint8)

    @cached_property
    def expression_slots(self) -> tuple[tuple[int, int, Expression], ...]:
        """``(module index, parameter index, expression)`` of every computed parameter."""
        return tuple((i, j, arg.expression) for i, a in enumerate(self.args)
                     for j, arg in enumerate(a) if isinstance(arg, ExprArg))

    def const_params(self, k: int) -> np.ndarray:
        """(m, k) constant parameters (0 where a parameter is ``n`` or computed)."""
        out = np.zeros((len(self), k))
        for i, a in enumerate(self.args):
            for j, arg in enumerate(a):
                if isinstance(arg, Const):
                    out[i, j] = arg.value
        return out

    def generation_mask(self, k: int) -> np.ndarray:
        """(m, k) bool, True where a parameter is the generation ``n``."""
        out = np.zeros((len(self), k), bool)
        for i, a in enumerate(self.args):
            for j, arg in enumerate(a):
                out[i, j] = isinstance(arg, GenerationArg)
        return out

    def instantiate(self, alphabet: tuple[str, ...], generation: int) -> ModuleString:
        """The module string this word writes in ``generation`` (no computed parameters)."""
        if self.expression_slots:
            i, j, e = self.expression_slots[0]
            raise GrammarError(f"parameter {j + 1} of module {i + 1} ({e.text!r}) needs the "
                               f"parameters of a predecessor; only constants are allowed here",
                               source=e.source)
        k = self.width
        params = self.const_params(k)
        params[self.generation_mask(k)] = generation
        return ModuleString(alphabet, self.codes.astype(np.int16), self.nargs.copy(), params)


@dataclass(frozen=True, eq=False)
class Successor:
    """One right-hand side with its probability (1 for a deterministic production)."""

    word: Word
    probability: float


@dataclass(frozen=True, eq=False)
class Production:
    """``predecessor[(formals)] [: condition] -> successors``.

    Attributes
    ----------
    predecessor : the symbol rewritten.
    successors : alternatives with probabilities (one for a deterministic production).
    formals : formal parameter names; ``None`` (no parentheses) matches any arity.
    condition : must hold for the module to be rewritten; ``None`` = always.
    label : where the production is, for messages (``grammar line 4: A(l,w)``).
    """

    predecessor: str
    successors: tuple[Successor, ...]
    formals: tuple[str, ...] | None = None
    condition: Expression | None = None
    label: str = ""

    @property
    def stochastic(self) -> bool:
        return len(self.successors) > 1

    @property
    def parametric(self) -> bool:
        """True when the production binds parameters or has a condition."""
        return self.formals is not None or self.condition is not None

    @cached_property
    def cumulative(self) -> np.ndarray:
        """Cumulative probabilities normalised to end exactly at 1."""
        c = np.cumsum([s.probability for s in self.successors])
        return c / c[-1]


@dataclass(frozen=True, eq=False)
class Grammar:
    """A parsed L-system: alphabet, constants, axiom, productions.

    Build one with :func:`~.grammar_parse.parse_grammar`.

    Attributes
    ----------
    alphabet : symbols; module codes index into it.
    axiom : the start word.
    productions : in grammar order (the first applicable one rewrites a module).
    derivation_length : default number of generations, if given.
    source : name used in messages.
    text : the grammar text.
    constants : the ``define:`` values after overrides.
    interpretation : productions applied once, after the derivation.
    """

    alphabet: tuple[str, ...]
    axiom: Word
    productions: tuple[Production, ...]
    derivation_length: int | None = None
    source: str | None = None
    text: str = field(default="", repr=False)
    constants: Mapping[str, float] = field(default_factory=dict)
    interpretation: tuple[Production, ...] = ()

    @property
    def stochastic(self) -> bool:
        """True when any production has several successors."""
        return any(p.stochastic for p in self.productions)

    @property
    def parametric(self) -> bool:
        """True when any production binds parameters or has a condition."""
        return any(p.parametric for p in self.productions + self.interpretation)

    @cached_property
    def width(self) -> int:
        """Widest module (parameters) of the axiom and successors."""
        return max([self.axiom.width] + [s.word.width for p in
                                         self.productions + self.interpretation
                                         for s in p.successors])

    def production_for(self, symbol: str) -> Production | None:
        """The first production of ``symbol`` (``None`` if it has none)."""
        for p in self.productions:
            if p.predecessor == symbol:
                return p
        return None

    def productions_for(self, symbol: str) -> tuple[Production, ...]:
        """Every production of ``symbol``, in the order they are tried."""
        return tuple(p for p in self.productions if p.predecessor == symbol)

    def axiom_string(self) -> ModuleString:
        """The axiom as a module string (generation 0)."""
        return self.axiom.instantiate(self.alphabet, generation=0)

    def __str__(self) -> str:
        return self.text or f"<Grammar {self.source or ''}>"
