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

and a parametric one (ABOP §1.10; Honda's monopodial tree, ABOP Fig. 2.6)::

    alphabet: A B C F ! & / + - $
    define: r1 = 0.9, r2 = 0.6, a0 = 45, a2 = 45
    define: d = 137.5, wr = 0.707
    axiom: A(1,10)
    derivation length: 10
    productions:
    A(l,w) -> !(w)F(l)[&(a0)B(l*r2,w*wr)]/(d)A(l*r1,w*wr)
    B(l,w) -> !(w)F(l)[-(a2)$C(l*r2,w*wr)]C(l*r1,w*wr)
    C(l,w) -> !(w)F(l)[+(a2)$B(l*r2,w*wr)]B(l*r1,w*wr)

``alphabet:``
    Symbols separated by spaces (or written together). Every symbol is one
    character other than whitespace and ``( ) , # : n``. Without this line
    the alphabet is the SIMLIDAR one, ``F I [ ] + - R r T t``. ``|`` may be
    declared (ABOP's turn-around); see *Stochastic productions* for how it is
    told apart from the alternative separator.
``define:``
    Named constants, ``name = value`` separated by commas; several ``define:``
    lines add up. A value is an expression of numbers and constants defined
    before it (``define: a = 30, b = 2*a``). Names are identifiers other than
    ``n``, ``pi`` and the function names of
    :mod:`~simlidar_mi.lsystem.expr_builtins`. Constants are folded into the
    expressions at parse time; :func:`parse_grammar` can override their values
    (``constants={"r2": 0.9}``), which is how one grammar text serves Honda's
    four parameter sets.
``axiom:``
    The start word (required). Parameters are numbers or constant expressions.
``derivation length:``
    Optional default number of generations (L-Py's ``derivation length``).
``productions:``
    Optional header; every line holding ``->`` (or ``→``) is a production
    ``predecessor [: condition] -> successor``. Symbols without a matching
    production are copied unchanged (identity production).
``interpretation:``
    Header of *interpretation* productions (ABOP's homomorphism, L-Py's
    ``interpretation:``): applied once, after the derivation, to the word
    handed to the turtle, never fed back into the derivation. They turn apex
    modules into leaves or twigs whatever the number of generations. Lines
    after this header are interpretation productions until a ``productions:``
    header.

Predecessors
    One symbol (context-free), optionally with formal parameters, ``A(l,w)``.
    A predecessor with parameters matches only modules with that many
    parameters; one without parentheses matches the symbol whatever its
    parameters (and binds none). ``[`` and ``]`` cannot be rewritten.
Conditions
    ``A(l,w) : l > 0.1 && w < 2 -> ...``; an expression of the formal
    parameters, constants and ``n``; ``*`` means always (cpfg's notation).
    Several productions may share a predecessor symbol: a module is rewritten
    by the *first* one, in grammar order, whose arity matches and whose
    condition holds (ABOP §1.10). A production after an unconditional one of
    the same symbol and arity could never apply and is an error.
Stochastic productions
    Alternatives are separated by ``|``, on the same line or on continuation
    lines starting with ``|``; each alternative carries its probability in
    parentheses in front: ``(0.33)``, ``(.5)``, a fraction ``(1/3)`` or a
    constant expression. One may also repeat ``P -> (p) successor`` (same
    predecessor and condition) on separate lines; they are merged. The
    probabilities of one production must sum to 1 within 1e-6. A single
    successor without a probability is deterministic. Every module rewritten
    draws its successor independently. When ``|`` is in the alphabet it is a
    symbol, and only ``|`` followed by ``(`` separates alternatives (the
    turn-around symbol takes no parameters, so this is unambiguous).
Successor words
    Symbols, optionally followed by parameters in parentheses, ``I(2)``,
    ``A(0.5,3)`` or ``B(l*r2, w*wr)``. A parameter is a number, the
    generation token ``n`` or an expression (:mod:`~simlidar_mi.lsystem.
    expressions`: ``+ - * / ^``, comparisons, ``&& || !``, ``sin`` ...) of the
    predecessor's formal parameters, the constants and ``n``. ``n`` stands for
    the number of the generation that writes the module (the axiom is
    generation 0, the first rewrite generation 1): ``I(n)`` or, as in the
    SIMLIDAR paper, the shorthand ``In``. Whitespace is ignored. Brackets must
    balance inside every successor and in the axiom.

Errors are :class:`~simlidar_mi.errors.GrammarError` carrying the line (in
``source``) and the column (``position``) with a caret under the fault;
expressions are checked at parse time (unknown names, ``__import__``,
attribute access), so a grammar that parses cannot reach Python.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..errors import ConfigError, GrammarError
from .expr_builtins import FUNCTIONS
from .expressions import Expression, argument_spans, parse_expression
from .grammar import (Arg, Const, ExprArg, GenerationArg, Grammar, Production, Successor,
                      Word)
from .modules import (CLOSE, DEFAULT_ALPHABET, GENERATION_TOKEN, OPEN, ModuleString,
                      check_alphabet, format_number)

#: Tolerance on the sum of the probabilities of one predecessor.
PROBABILITY_TOLERANCE = 1e-6
#: ABOP's turn-around symbol, also the alternative separator.
BAR = "|"

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?$")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z_0-9]*$")
_KEY = re.compile(r"^\s*(alphabet|axiom|derivation[ _]length|productions?|define|"
                  r"interpretation)\s*:", re.IGNORECASE)
_ARROWS = ("->", "→")


def _closing_paren(text: str, i: int, end: int) -> int:
    """Index of the ``)`` matching ``text[i] == '('`` before ``end``, or -1."""
    depth = 0
    for j in range(i, end):
        c = text[j]
        if c == "(":
            depth += 1
        elif c == ")":
            depth -= 1
            if depth == 0:
                return j
    return -1


def parse_sequence(text: str, start: int, end: int, index: dict[str, int], *,
                   source: str | None = None, allow_generation: bool = True,
                   names: tuple[str, ...] = (),
                   constants: Mapping[str, float] | None = None) -> Word:
    """Tokenize ``text[start:end]`` into a :class:`Word`.

    Parameters
    ----------
    text, start, end : the word is ``text[start:end]``; error positions index ``text``.
    index : symbol -> code.
    source : for messages.
    allow_generation : accept ``n`` (and ``In``).
    names : formal parameters expressions may use (``n`` is added when allowed).
    constants : folded into expressions.

    Raises
    ------
    GrammarError
        unknown symbol, malformed parameter list or expression, unbalanced brackets.
    """
    def fail(msg: str, pos: int) -> GrammarError:
        return GrammarError(msg, text=text, position=pos, source=source)

    codes: list[int] = []
    args: list[tuple[Arg, ...]] = []
    open_at: list[int] = []          # positions of '[' not yet closed
    bar_is_symbol = BAR in index
    i = start
    while i < end:
        ch = text[i]
        if ch.isspace():
            i += 1
            continue
        if ch == GENERATION_TOKEN:
            raise fail(f"'{GENERATION_TOKEN}' (the generation) must follow a symbol, as in "
                       f"'I{GENERATION_TOKEN}'", i)
        if ch in "()," or (ch == BAR and not bar_is_symbol):
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
            close = _closing_paren(text, i, end)
            if close < 0:
                raise fail("'(' without ')'", i)
            a = _parse_args(text, i + 1, close, source, allow_generation, names, constants)
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


def _parse_args(text: str, lo: int, hi: int, source: str | None, allow_generation: bool,
                names: tuple[str, ...], constants: Mapping[str, float] | None
                ) -> tuple[Arg, ...]:
    out: list[Arg] = []
    allowed = tuple(names) + ((GENERATION_TOKEN,) if allow_generation else ())
    for a, b in argument_spans(text, source, start=lo, end=hi):
        tok = text[a:b]
        if tok == GENERATION_TOKEN and allow_generation:
            out.append(GenerationArg())
        elif _NUMBER.match(tok):
            out.append(Const(float(tok)))
        else:
            if tok == GENERATION_TOKEN:
                raise GrammarError(f"'{GENERATION_TOKEN}' is only allowed in grammar "
                                   f"successors", text=text, position=a, source=source)
            expr = parse_expression(text, allowed, source, constants=constants, start=a, end=b)
            out.append(Const(float(expr.evaluate())) if expr.is_constant else ExprArg(expr))
    return tuple(out)


def parse_modules(text: str, alphabet: Sequence[str] = DEFAULT_ALPHABET) -> ModuleString:
    """Parse ``'I(1)I(1)[r+I(2)F]'`` (numbers or constant expressions; whitespace ignored).

    Raises
    ------
    GrammarError
        with the character position, for unknown symbols, malformed
        parameters or unbalanced brackets.
    """
    alphabet = check_alphabet(alphabet)
    seq = parse_sequence(text, 0, len(text), {s: i for i, s in enumerate(alphabet)},
                         source="module string", allow_generation=False)
    return seq.instantiate(alphabet, generation=0)


def _parse_probability(text: str, lo: int, hi: int, source: str,
                       constants: Mapping[str, float]) -> float | None:
    tok = text[lo:hi].strip()
    if "/" in tok:
        num, _, den = tok.partition("/")
        if _NUMBER.match(num.strip()) and _NUMBER.match(den.strip()) and float(den) != 0:
            return float(num) / float(den)
    if _NUMBER.match(tok):
        return float(tok)
    try:
        expr = parse_expression(text, (), source, constants=constants, start=lo, end=hi)
    except GrammarError:
        return None
    return float(expr.evaluate()) if expr.is_constant else None


def _split_alternatives(line: str, lo: int, bar_is_symbol: bool) -> list[tuple[int, int]]:
    """Spans of the ``|``-separated alternatives of ``line[lo:]`` (outside parentheses).

    When ``|`` is a symbol, only a ``|`` followed by ``(`` separates.
    """
    spans, depth, start = [], 0, lo
    for i in range(lo, len(line)):
        ch = line[i]
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        elif ch == BAR and depth == 0:
            if bar_is_symbol and not line[i + 1:].lstrip().startswith("("):
                continue
            spans.append((start, i))
            start = i + 1
    spans.append((start, len(line)))
    return spans


@dataclass
class _Pending:
    predecessor: str
    formals: tuple[str, ...] | None
    condition: Expression | None
    line_no: int
    line: str
    column: int
    interpretation: bool
    items: list = field(default_factory=list)   # (Word, prob | None, line_no, line, col)


def _parse_defines(body: str, offset: int, line: str, consts: dict[str, float],
                   declared: dict[str, float], overrides: Mapping[str, float],
                   where: str) -> None:
    """Add ``name = expr, ...`` of one ``define:`` line to ``consts`` (in order)."""
    lo = offset
    for a, b in argument_spans(line, where, start=lo, end=len(line)):
        piece = line[a:b]
        name, eq, _ = piece.partition("=")
        if not eq:
            raise GrammarError("a definition is 'name = value', as in 'define: r1 = 0.9'",
                               text=line, position=a, source=where)
        name = name.strip()
        if not _IDENT.match(name) or name.startswith("__"):
            raise GrammarError(f"constant name {name!r} must be an identifier such as 'r1'",
                               text=line, position=a, source=where)
        if name == GENERATION_TOKEN or name == "pi" or name in FUNCTIONS:
            raise GrammarError(f"{name!r} is reserved (the generation, pi or a function) and "
                               f"cannot be a constant", text=line, position=a, source=where)
        if name in declared:
            raise GrammarError(f"constant {name!r} defined twice", text=line, position=a,
                               source=where)
        vstart = a + piece.index("=") + 1
        expr = parse_expression(line, (), where, constants=consts, start=vstart, end=b)
        value = float(expr.evaluate())
        declared[name] = value
        consts[name] = float(overrides[name]) if name in overrides else value


def parse_grammar(text: str, source: str | None = None, *,
                  constants: Mapping[str, float] | None = None) -> Grammar:
    """Parse grammar text (format in the module docstring).

    Parameters
    ----------
    text : the grammar.
    source : a name for messages (a file name); errors say ``source line N``.
    constants : override values of ``define:`` constants (each name must be defined
        in the text); later definitions that use them see the new value.

    Raises
    ------
    GrammarError
        with line and column, for unbalanced brackets, unknown symbols or names,
        malformed expressions, probabilities not summing to 1, unreachable
        productions and malformed statements.
    ConfigError
        an override names a constant the grammar does not define, or is not a
        finite number.
    """
    src = source or "grammar"
    lines = [ln.split("#", 1)[0] for ln in text.splitlines()]
    overrides = dict(constants or {})
    for k, v in overrides.items():
        if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) \
                or not math.isfinite(v):
            raise ConfigError("must be a finite number", key=f"constants.{k}", value=v)

    def fail(msg: str, line_no: int, col: int | None) -> GrammarError:
        return GrammarError(msg, text=lines[line_no] if col is not None else None,
                            position=col, source=f"{src} line {line_no + 1}")

    # pass 1: the alphabet and the constants, which every other statement uses
    alphabet: tuple[str, ...] | None = None
    consts: dict[str, float] = {}
    declared: dict[str, float] = {}
    for no, ln in enumerate(lines):
        m = _KEY.match(ln)
        if not m:
            continue
        key = m.group(1).lower()
        if key == "alphabet":
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
        elif key == "define":
            if not ln[m.end():].strip():
                raise fail("empty definition; write 'define: name = value'", no, m.end())
            _parse_defines(ln[m.end():], m.end(), ln, consts, declared, overrides,
                           f"{src} line {no + 1}")
    unknown = sorted(set(overrides) - set(declared))
    if unknown:
        raise ConfigError(f"the grammar defines no constant {unknown[0]!r}; it defines "
                          f"{', '.join(sorted(declared)) or 'none'}",
                          key=f"constants.{unknown[0]}", value=overrides[unknown[0]])
    if alphabet is None:
        alphabet = DEFAULT_ALPHABET
    index = {s: i for i, s in enumerate(alphabet)}
    bar_is_symbol = BAR in index

    axiom: Word | None = None
    length: int | None = None
    pending: list[_Pending] = []
    last: _Pending | None = None
    in_interpretation = False
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
                                       allow_generation=True, constants=consts)
            elif key.startswith("derivation"):
                tok = ln[m.end():].strip()
                if not tok.isdigit():
                    raise fail(f"derivation length must be a whole number >= 0, got {tok!r}",
                               no, m.end())
                length = int(tok)
            elif key.startswith("production") or key == "interpretation":
                if ln[m.end():].strip():
                    raise fail(f"put productions on the lines after '{key}:'", no, m.end())
                in_interpretation = key == "interpretation"
            continue
        stripped = ln.lstrip()
        if stripped.startswith(BAR) and (not bar_is_symbol
                                         or stripped[1:].lstrip().startswith("(")):
            if last is None:
                raise fail("'|' continues a production, but no production precedes it",
                           no, len(ln) - len(stripped))
            _add_alternatives(last, ln, len(ln) - len(stripped) + 1, no, index, source_ln,
                              consts)
            continue
        arrow = min(((ln.find(a), a) for a in _ARROWS if a in ln), default=None)
        if arrow is None:
            raise fail("expected 'key: value' (alphabet, define, axiom, derivation length, "
                       "productions, interpretation) or a production 'A -> successor'",
                       no, len(ln) - len(stripped))
        at, arrow_text = arrow
        p = _parse_predecessor(ln, at, no, index, alphabet, consts, src, in_interpretation)
        last = _merge(pending, p, src)
        _add_alternatives(last, ln, at + len(arrow_text), no, index, source_ln, consts)

    if axiom is None:
        raise GrammarError("no 'axiom:' line", source=src)

    productions = tuple(_finish(p, src) for p in pending if not p.interpretation)
    interpretation = tuple(_finish(p, src) for p in pending if p.interpretation)
    return Grammar(alphabet, axiom, productions, length, source, text, dict(consts),
                   interpretation)


def _parse_predecessor(ln: str, at: int, no: int, index: dict[str, int],
                       alphabet: tuple[str, ...], consts: Mapping[str, float], src: str,
                       interpretation: bool) -> _Pending:
    """Parse ``A(l,w) : cond`` in ``ln[:at]``."""
    where = f"{src} line {no + 1}"

    def fail(msg: str, col: int) -> GrammarError:
        return GrammarError(msg, text=ln, position=col, source=where)

    head_end = at
    depth, colon = 0, -1
    for j in range(at):
        c = ln[j]
        if c == "(":
            depth += 1
        elif c == ")":
            depth -= 1
        elif c == ":" and depth == 0:
            colon = j
            break
    if colon >= 0:
        head_end = colon
    head = ln[:head_end]
    col = len(head) - len(head.lstrip())
    body = head.strip()
    if not body:
        raise fail("production without a predecessor", at if colon < 0 else colon)
    sym = body[0]
    if sym not in index:
        raise fail(f"unknown symbol {sym!r}; the alphabet is {' '.join(alphabet)!r}", col)
    if sym in (OPEN, CLOSE):
        raise fail(f"{sym!r} cannot be rewritten", col)
    rest = body[1:].strip()
    formals: tuple[str, ...] | None = None
    if rest:
        if any(c in body for c in "<>"):
            raise fail("context-sensitive productions ('<', '>') are not supported; "
                       "write one symbol with optional parameters, as in 'A(l,w) -> ...'",
                       col)
        if not (rest.startswith("(") and rest.endswith(")")):
            raise fail(f"predecessor {body!r} must be one symbol, optionally with formal "
                       f"parameters, as in 'F -> ...' or 'A(l,w) -> ...'", col)
        lo = ln.index("(", col)
        hi = _closing_paren(ln, lo, head_end)
        if hi < 0 or ln[hi + 1:head_end].strip():
            raise fail("malformed formal parameter list", lo)
        names: list[str] = []
        for a, b in argument_spans(ln, where, start=lo + 1, end=hi):
            name = ln[a:b]
            if not _IDENT.match(name) or name.startswith("__"):
                raise fail(f"formal parameter {name!r} must be a name such as 'l'", a)
            if name == GENERATION_TOKEN:
                raise fail(f"'{GENERATION_TOKEN}' is the generation and cannot be a formal "
                           f"parameter", a)
            if name in names:
                raise fail(f"formal parameter {name!r} appears twice", a)
            names.append(name)
        formals = tuple(names)
    condition = None
    if colon >= 0:
        ctext = ln[colon + 1:at]
        if not ctext.strip():
            raise fail("empty condition; write '*' for none, or drop the ':'", colon + 1)
        if ctext.strip() != "*":
            cstart = colon + 1
            label = f"{where}: condition of {body}"
            condition = parse_expression(ln, (formals or ()) + (GENERATION_TOKEN,), label,
                                         constants=consts, start=cstart, end=at)
            if condition.is_constant and bool(condition.evaluate()):
                condition = None        # always true: an unconditional production
    return _Pending(sym, formals, condition, no, ln, col, interpretation)


def _merge(pending: list[_Pending], p: _Pending, src: str) -> _Pending:
    """The pending production ``p`` belongs to (merging repeated stochastic lines)."""
    ctext = None if p.condition is None else "".join(p.condition.text.split())
    for q in pending:
        if q.predecessor != p.predecessor or q.interpretation != p.interpretation:
            continue
        qtext = None if q.condition is None else "".join(q.condition.text.split())
        if q.formals == p.formals and qtext == ctext:
            return q                # 'A -> (p) x' repeated: merge alternatives
        covers = q.formals is None or (p.formals is not None
                                       and len(p.formals) == len(q.formals))
        if q.condition is None and covers:
            raise GrammarError(
                f"this production of {p.predecessor!r} can never apply: the production on "
                f"line {q.line_no + 1} has no condition and matches the same modules first",
                text=p.line, position=p.column, source=f"{src} line {p.line_no + 1}")
    pending.append(p)
    return p


def _add_alternatives(p: _Pending, line: str, lo: int, no: int, index, source_ln: str,
                      consts: Mapping[str, float]) -> None:
    names = p.formals or ()
    label = f"{source_ln}: production {_pred_text(p)}"
    for a, b in _split_alternatives(line, lo, BAR in index):
        j = a
        while j < b and line[j].isspace():
            j += 1
        prob = None
        if j < b and line[j] == "(":
            close = _closing_paren(line, j, b)
            if close < 0:
                raise GrammarError("'(' of a probability without ')'", text=line, position=j,
                                   source=source_ln)
            prob = _parse_probability(line, j + 1, close, source_ln, consts)
            if prob is None or not (0.0 <= prob <= 1.0):
                raise GrammarError(f"probability {line[j + 1:close].strip()!r} must be a "
                                   f"number in [0, 1], such as (0.33) or (1/3)",
                                   text=line, position=j + 1, source=source_ln)
            j = close + 1
        word = parse_sequence(line, j, b, index, source=label, allow_generation=True,
                              names=names, constants=consts)
        p.items.append((word, prob, no, line, a))


def _pred_text(p: _Pending) -> str:
    head = p.predecessor + (f"({','.join(p.formals)})" if p.formals is not None else "")
    return head + (f" : {p.condition.text}" if p.condition is not None else "")


def _finish(p: _Pending, src: str) -> Production:
    items = p.items
    where = dict(text=p.line, position=p.column, source=f"{src} line {p.line_no + 1}")
    label = f"{src} line {p.line_no + 1}: {_pred_text(p)}"
    extra = dict(formals=p.formals, condition=p.condition, label=label)
    if len(items) == 1 and items[0][1] is None:
        return Production(p.predecessor, (Successor(items[0][0], 1.0),), **extra)
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
    return Production(p.predecessor, tuple(Successor(it[0], float(it[1])) for it in items),
                      **extra)
