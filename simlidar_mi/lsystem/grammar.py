"""L-system grammars: a small text format and its parser.

Grammar text
------------
One statement a line; ``#`` starts a comment; keys are case-insensitive::

    # SIMLIDAR apple tree, stochastic (Méndez et al., section 1)
    alphabet: F I R r T t + -          # optional; brackets are always in it
    axiom: F
    derivation length: 7               # optional default for derive()
    productions:
    F -> (0.33) InIn[r+InIn+F]In[RR-InF]InF
       | (0.33) In[r+InF]In[rr-InF]In[r+InF]F
       | (0.34) In[r+InF]In[R-InF]In[RR+InF]F

``alphabet:``
    Symbols separated by spaces (or written together). Every symbol is one
    character other than whitespace and ``( ) | , # : n``. Without this line
    the alphabet is the SIMLIDAR one, ``F I [ ] + - R r T t``.
``axiom:``
    The start word (required).
``derivation length:``
    Optional default number of generations (L-Py's ``derivation length``).
``productions:``
    Optional header; every line holding ``->`` (or ``→``) is a production
    ``P -> successor``. ``P`` is one symbol (context-free, non-parametric
    predecessors; ``[`` and ``]`` cannot be rewritten). Symbols without a
    production are copied unchanged (identity production).

Stochastic productions
    Alternatives are separated by ``|``, on the same line or on continuation
    lines starting with ``|``; each alternative carries its probability in
    parentheses in front: ``(0.33)``, ``(.5)`` or a fraction ``(1/3)``. One may
    also repeat ``P -> (p) successor`` on separate lines; they are merged. The
    probabilities of one predecessor must sum to 1 within 1e-6. A single
    successor without a probability is deterministic. Every module rewritten
    draws its successor independently.

Successor words
    Symbols, optionally followed by parameters in parentheses, ``I(2)`` or
    ``A(0.5,3)``. The reserved token ``n`` stands for the number of the
    generation that writes the module (the axiom is generation 0, the first
    rewrite generation 1): ``I(n)`` or, as in the paper, the shorthand ``In``.
    So ``In`` written in generation 3 becomes ``I(3)``. Whitespace is ignored.
    Brackets must balance inside every successor and in the axiom.

Errors are :class:`~simlidar_mi.errors.GrammarError` carrying the line (in
``source``) and the column (``position``) with a caret under the fault.

Extension point: parameters are stored as argument objects (:class:`Const`,
:class:`GenerationArg`); ABOP parametric productions ``A(l,w) : cond ->
B(l*r1,w*wr)`` need only a new argument kind (an expression of the
predecessor's parameters) and formal parameters on :class:`Production`. They
are rejected with a clear message for now.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import GrammarError
from .modules import (CLOSE, DEFAULT_ALPHABET, GENERATION_TOKEN, OPEN, ModuleString,
                      check_alphabet, format_number)

#: Tolerance on the sum of the probabilities of one predecessor.
PROBABILITY_TOLERANCE = 1e-6

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?$")
_KEY = re.compile(r"^\s*(alphabet|axiom|derivation[ _]length|productions?)\s*:", re.IGNORECASE)
_ARROWS = ("->", "→")


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


Arg = Const | GenerationArg


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

    def const_params(self, k: int) -> np.ndarray:
        """(m, k) constant parameters (0 where a parameter is the generation)."""
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
        """The module string this word writes in ``generation``."""
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
    """``predecessor -> successors`` (context-free, non-parametric predecessor)."""

    predecessor: str
    successors: tuple[Successor, ...]

    @property
    def stochastic(self) -> bool:
        return len(self.successors) > 1

    @cached_property
    def cumulative(self) -> np.ndarray:
        """Cumulative probabilities normalised to end exactly at 1."""
        c = np.cumsum([s.probability for s in self.successors])
        return c / c[-1]


@dataclass(frozen=True, eq=False)
class Grammar:
    """A parsed L-system: alphabet, axiom and productions.

    Build one with :func:`parse_grammar`.
    """

    alphabet: tuple[str, ...]
    axiom: Word
    productions: tuple[Production, ...]
    derivation_length: int | None = None
    source: str | None = None
    text: str = field(default="", repr=False)

    @property
    def stochastic(self) -> bool:
        """True when any production has several successors."""
        return any(p.stochastic for p in self.productions)

    @cached_property
    def width(self) -> int:
        """Widest module (parameters) of the axiom and successors."""
        return max([self.axiom.width] + [s.word.width for p in self.productions
                                         for s in p.successors])

    def production_for(self, symbol: str) -> Production | None:
        for p in self.productions:
            if p.predecessor == symbol:
                return p
        return None

    def axiom_string(self) -> ModuleString:
        """The axiom as a module string (generation 0)."""
        return self.axiom.instantiate(self.alphabet, generation=0)

    def __str__(self) -> str:
        return self.text or f"<Grammar {self.source or ''}>"


# --- parsing ------------------------------------------------------------------------
def parse_sequence(text: str, start: int, end: int, index: dict[str, int], *,
                   source: str | None = None, allow_generation: bool = True) -> Word:
    """Tokenize ``text[start:end]`` into a :class:`Word`.

    Positions in errors are offsets into ``text``.

    Raises
    ------
    GrammarError
        unknown symbol, malformed parameter list, unbalanced brackets.
    """
    def fail(msg: str, pos: int) -> GrammarError:
        return GrammarError(msg, text=text, position=pos, source=source)

    codes: list[int] = []
    args: list[tuple[Arg, ...]] = []
    open_at: list[int] = []          # positions of '[' not yet closed
    i = start
    while i < end:
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        if ch == GENERATION_TOKEN:
            raise fail(f"'{GENERATION_TOKEN}' (the generation) must follow a symbol, as in "
                       f"'I{GENERATION_TOKEN}'", i)
        if ch in "(),|":
            raise fail(f"unexpected {ch!r}: parameters follow a symbol, as in 'I(2)'", i)
        if ch not in index:
            raise fail(f"unknown symbol {ch!r}; the alphabet is "
                       f"{' '.join(sorted(index, key=index.get))!r}", i)
        sym_pos = i
        i += 1
        a: tuple[Arg, ...] = ()
        if i < end and text[i] == GENERATION_TOKEN:            # shorthand In == I(n)
            if not allow_generation:
                raise fail(f"'{GENERATION_TOKEN}' is only allowed in grammar successors", i)
            a = (GenerationArg(),)
            i += 1
        elif i < end and text[i] == "(":
            close = text.find(")", i, end)
            if close < 0:
                raise fail("'(' without ')'", i)
            a = _parse_args(text, i + 1, close, fail, allow_generation)
            i = close + 1
        if ch in (OPEN, CLOSE):
            if a:
                raise fail(f"{ch!r} takes no parameters", sym_pos)
            if ch == OPEN:
                open_at.append(sym_pos)
            elif not open_at:
                raise fail("unbalanced brackets: ']' without a matching '['", sym_pos)
            else:
                open_at.pop()
        codes.append(index[ch])
        args.append(a)
    if open_at:
        raise fail("unbalanced brackets: '[' is never closed", open_at[-1])
    return Word(np.array(codes, np.int16), tuple(args), text[start:end].strip())


def _parse_args(text: str, lo: int, hi: int, fail, allow_generation: bool) -> tuple[Arg, ...]:
    out: list[Arg] = []
    pos = lo
    for piece in text[lo:hi].split(","):
        tok = piece.strip()
        where = pos + (len(piece) - len(piece.lstrip()))
        if tok == GENERATION_TOKEN and allow_generation:
            out.append(GenerationArg())
        elif _NUMBER.match(tok):
            out.append(Const(float(tok)))
        elif not tok:
            raise fail("empty parameter", where)
        else:
            raise fail(f"parameter {tok!r} is not supported: use a number"
                       + (f" or '{GENERATION_TOKEN}'" if allow_generation else "")
                       + " (parametric expressions are not implemented yet)", where)
        pos += len(piece) + 1
    return tuple(out)


def _parse_probability(tok: str) -> float | None:
    tok = tok.strip()
    if "/" in tok:
        num, _, den = tok.partition("/")
        if _NUMBER.match(num.strip()) and _NUMBER.match(den.strip()) and float(den) != 0:
            return float(num) / float(den)
        return None
    return float(tok) if _NUMBER.match(tok) else None


def _split_alternatives(line: str, lo: int) -> list[tuple[int, int]]:
    """Spans of the ``|``-separated alternatives of ``line[lo:]`` (outside parentheses)."""
    spans, depth, start = [], 0, lo
    for i in range(lo, len(line)):
        ch = line[i]
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        elif ch == "|" and depth == 0:
            spans.append((start, i))
            start = i + 1
    spans.append((start, len(line)))
    return spans


@dataclass
class _Pending:
    predecessor: str
    line_no: int
    line: str
    column: int
    items: list = field(default_factory=list)   # (Word, prob | None, line_no, line, col)


def parse_grammar(text: str, source: str | None = None) -> Grammar:
    """Parse grammar text (format in the module docstring).

    Parameters
    ----------
    text : the grammar.
    source : a name for messages (a file name); errors say ``source line N``.

    Raises
    ------
    GrammarError
        with line and column, for unbalanced brackets, unknown symbols,
        probabilities not summing to 1, and malformed statements.
    """
    src = source or "grammar"
    lines = [ln.split("#", 1)[0] for ln in text.splitlines()]

    def fail(msg: str, line_no: int, col: int | None) -> GrammarError:
        return GrammarError(msg, text=lines[line_no] if col is not None else None,
                            position=col, source=f"{src} line {line_no + 1}")

    # pass 1: the alphabet, which every other statement is checked against
    alphabet: tuple[str, ...] | None = None
    for no, ln in enumerate(lines):
        m = _KEY.match(ln)
        if m and m.group(1).lower() == "alphabet":
            if alphabet is not None:
                raise fail("alphabet given twice", no, m.start(1))
            body = ln[m.end():]
            syms = [c for c in body if not c.isspace() and c != ","]
            if not syms:
                raise fail("empty alphabet", no, m.end())
            for j, c in enumerate(body):
                if c.isspace() or c == ",":
                    continue
                try:
                    check_alphabet([c])
                except GrammarError as exc:
                    raise fail(str(exc), no, m.end() + j) from None
            alphabet = check_alphabet(syms)
    if alphabet is None:
        alphabet = DEFAULT_ALPHABET
    index = {s: i for i, s in enumerate(alphabet)}

    axiom: Word | None = None
    length: int | None = None
    pending: dict[str, _Pending] = {}
    last: _Pending | None = None
    for no, ln in enumerate(lines):
        if not ln.strip():
            continue
        source_ln = f"{src} line {no + 1}"
        m = _KEY.match(ln)
        if m:
            key = m.group(1).lower()
            last = None
            if key == "axiom":
                if axiom is not None:
                    raise fail("axiom given twice", no, m.start(1))
                if not ln[m.end():].strip():
                    raise fail("empty axiom", no, m.end())
                axiom = parse_sequence(ln, m.end(), len(ln), index, source=source_ln,
                                       allow_generation=True)
            elif key.startswith("derivation"):
                tok = ln[m.end():].strip()
                if not tok.isdigit():
                    raise fail(f"derivation length must be a whole number >= 0, got {tok!r}",
                               no, m.end())
                length = int(tok)
            elif key.startswith("production") and ln[m.end():].strip():
                raise fail("put productions on the lines after 'productions:'", no, m.end())
            continue
        stripped = ln.lstrip()
        if stripped.startswith("|"):
            if last is None:
                raise fail("'|' continues a production, but no production precedes it",
                           no, len(ln) - len(stripped))
            _add_alternatives(last, ln, len(ln) - len(stripped) + 1, no, index, source_ln)
            continue
        arrow = next(((ln.find(a), a) for a in _ARROWS if a in ln), None)
        if arrow is None:
            raise fail("expected 'key: value' (alphabet, axiom, derivation length, "
                       "productions) or a production 'A -> successor'",
                       no, len(ln) - len(stripped))
        at, arrow_text = arrow
        pred_text = ln[:at]
        pred = pred_text.strip()
        col = len(pred_text) - len(pred_text.lstrip())
        if not pred:
            raise fail("production without a predecessor", no, at)
        if "(" in pred or ":" in pred:
            raise fail("parametric or conditional predecessors are not supported yet; "
                       "write one symbol, as in 'F -> ...'", no, col)
        if len(pred) != 1:
            raise fail(f"predecessor {pred!r} must be one symbol (context-free L-system)",
                       no, col)
        if pred not in index:
            raise fail(f"unknown symbol {pred!r}; the alphabet is {' '.join(alphabet)!r}",
                       no, col)
        if pred in (OPEN, CLOSE):
            raise fail(f"{pred!r} cannot be rewritten", no, col)
        last = pending.setdefault(pred, _Pending(pred, no, ln, col))
        _add_alternatives(last, ln, at + len(arrow_text), no, index, source_ln)

    if axiom is None:
        raise GrammarError("no 'axiom:' line", source=src)

    productions = tuple(_finish(p, src) for p in pending.values())
    return Grammar(alphabet, axiom, productions, length, source, text)


def _add_alternatives(p: _Pending, line: str, lo: int, no: int, index, source_ln: str) -> None:
    for a, b in _split_alternatives(line, lo):
        j = a
        while j < b and line[j].isspace():
            j += 1
        prob = None
        if j < b and line[j] == "(":
            close = line.find(")", j, b)
            if close < 0:
                raise GrammarError("'(' of a probability without ')'", text=line, position=j,
                                   source=source_ln)
            prob = _parse_probability(line[j + 1:close])
            if prob is None or not (0.0 <= prob <= 1.0):
                raise GrammarError(f"probability {line[j + 1:close].strip()!r} must be a "
                                   f"number in [0, 1], such as (0.33) or (1/3)",
                                   text=line, position=j + 1, source=source_ln)
            j = close + 1
        word = parse_sequence(line, j, b, index, source=source_ln, allow_generation=True)
        p.items.append((word, prob, no, line, a))


def _finish(p: _Pending, src: str) -> Production:
    items = p.items
    where = dict(text=p.line, position=p.column, source=f"{src} line {p.line_no + 1}")
    if len(items) == 1 and items[0][1] is None:
        return Production(p.predecessor, (Successor(items[0][0], 1.0),))
    for word, prob, no, line, col in items:
        if prob is None:
            raise GrammarError(
                f"'{p.predecessor}' has {len(items)} successors; each needs a probability "
                f"in front, such as (0.33)", text=line, position=col,
                source=f"{src} line {no + 1}")
    total = sum(it[1] for it in items)
    if abs(total - 1.0) > PROBABILITY_TOLERANCE:
        probs = " + ".join(format_number(it[1]) for it in items)
        raise GrammarError(
            f"probabilities of '{p.predecessor}' sum to {total:.9g} ({probs}), "
            f"not 1 (tolerance {PROBABILITY_TOLERANCE:g})", **where)
    return Production(p.predecessor, tuple(Successor(it[0], float(it[1])) for it in items))
