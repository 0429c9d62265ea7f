"""Safe arithmetic expressions for parametric L-systems (ABOP §1.10).

Successor arguments such as ``l*r1, w*wr`` and conditions such as
``l > 0.1 && w <= 2`` are parsed by a small tokenizer and recursive-descent
parser into a tree, constant-folded and compiled into closures. Nothing is
handed to Python's ``eval``; the only names an expression can reach are its
parameters, caller constants, ``pi`` and the functions listed in
:data:`FUNCTIONS`.

Grammar (lowest to highest precedence)::

    expr       := or_expr
    or_expr    := and_expr  (('||' | 'or')  and_expr)*
    and_expr   := not_expr  (('&&' | 'and') not_expr)*
    not_expr   := ('!' | 'not') not_expr | comparison
    comparison := additive [('<' | '<=' | '>' | '>=' | '==' | '!=') additive]
    additive   := term  (('+' | '-') term)*
    term       := unary (('*' | '/') unary)*
    unary      := ('-' | '+') unary | power
    power      := primary [('^' | '**') unary]            # right-associative
    primary    := NUMBER | NAME | FUNC '(' [expr (',' expr)*] ')' | '(' expr ')'

Precedence choices, all following Python (as L-Py does):

* ``^`` binds tighter than unary minus and is right-associative:
  ``-2^2 == -4``, ``2^3^2 == 512``, and the exponent may carry a sign,
  ``2^-1 == 0.5``.
* ``!`` / ``not`` sit below the comparisons, like Python's ``not``:
  ``!a > b`` means ``!(a > b)``. Write ``!(a) > b`` for the C reading.
* Comparisons do not chain: ``a < b < c`` is rejected (C and Python read it
  differently); write ``a < b && b < c``.
* ``&&`` and ``||`` short-circuit, also element-wise in vectorised
  evaluation, so ``x != 0 && 1/x > 2`` never divides by zero.

Values: numbers are float64; comparisons and logic give booleans; in
arithmetic a boolean counts as 0 or 1, and in logic any non-zero number is
true. Functions take radians (``sin(30*pi/180) == 0.5``); the turtle works in
degrees, so convert with ``pi/180`` where needed.

Evaluation errors (division by zero, a result that is infinite or NaN, a
function outside its domain, a missing parameter) raise
:class:`ExpressionError`, naming the expression, the failing sub-expression
and the parameter values.
"""
from __future__ import annotations

import math
import operator
import re
from dataclasses import dataclass
from functools import reduce
from typing import Any, Callable, Iterable, Mapping, NamedTuple

import numpy as np

from ..errors import GrammarError, SimlidarError

__all__ = [
    "CONSTANTS", "FUNCTIONS", "Expression", "ExpressionError", "argument_spans",
    "parse_arguments", "parse_expression", "split_arguments",
]

#: Constants every expression knows unless the caller declares the same name.
CONSTANTS: dict[str, float] = {"pi": math.pi}

# name -> (min args, max args or None, scalar function, numpy function)
_FUNCS: dict[str, tuple[int, int | None, Callable[..., Any], Callable[..., Any]]] = {
    "sin": (1, 1, math.sin, np.sin),
    "cos": (1, 1, math.cos, np.cos),
    "tan": (1, 1, math.tan, np.tan),
    "asin": (1, 1, math.asin, np.arcsin),
    "acos": (1, 1, math.acos, np.arccos),
    "atan": (1, 1, math.atan, np.arctan),
    "atan2": (2, 2, math.atan2, np.arctan2),
    "sqrt": (1, 1, math.sqrt, np.sqrt),
    "exp": (1, 1, math.exp, np.exp),
    "log": (1, 1, math.log, np.log),
    "abs": (1, 1, abs, np.abs),
    "min": (2, None, min, lambda *a: reduce(np.minimum, a)),
    "max": (2, None, max, lambda *a: reduce(np.maximum, a)),
    "floor": (1, 1, lambda x: float(math.floor(x)), np.floor),
    "ceil": (1, 1, lambda x: float(math.ceil(x)), np.ceil),
}

#: Function names accepted in expressions (all angles in radians).
FUNCTIONS: frozenset[str] = frozenset(_FUNCS)

_KEYWORDS = {"and": "&&", "or": "||", "not": "!"}
_COMPARISONS = ("<", "<=", ">", ">=", "==", "!=")
_OPERATORS = ("&&", "||", "<=", ">=", "==", "!=", "**", "<", ">", "!", "+", "-", "*",
              "/", "^", "(", ")", ",")
_NUMBER = re.compile(r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_NAME = re.compile(r"[A-Za-z_][A-Za-z_0-9]*")
# Nesting depth of parentheses / unary operators; each level costs ~10 parser
# frames, so this keeps well inside Python's recursion limit.
_MAX_NESTING = 50
# Height of the tree (long chains like 1+1+...+1); each level is one closure call.
_MAX_HEIGHT = 200


class ExpressionError(SimlidarError, ArithmeticError):
    """An expression could not be evaluated for the given parameter values.

    Attributes
    ----------
    reason : what went wrong (the message without the location).
    text : the whole expression.
    subexpression : the part that failed (e.g. the divisor).
    values : parameter values at the failing module, ``{name: float}``.
    index : position of the failing element in vectorised evaluation, else None.
    source : where the expression came from (file, production), if known.
    """

    def __init__(self, message: str, *, text: str, subexpression: str | None = None,
                 values: Mapping[str, Any] | None = None, index: int | None = None,
                 source: str | None = None) -> None:
        self.reason = message
        self.text = text
        self.subexpression = subexpression
        self.values = dict(values or {})
        self.index = index
        self.source = source
        where = f"{source}: " if source else ""
        what = f"expression '{text}'"
        if subexpression is not None and subexpression != text:
            what = f"'{subexpression}' of {what}"
        at = f" at element {index}" if index is not None else ""
        vals = ", ".join(f"{k}={_fmt(v)}" for k, v in sorted(self.values.items()))
        with_ = f" with {vals}" if vals else ""
        super().__init__(f"{where}{message} in {what}{at}{with_}")


def _fmt(v: Any) -> str:
    return repr(v.item()) if isinstance(v, np.generic) else repr(v)


# --- tokenizer ----------------------------------------------------------------------

class _Token(NamedTuple):
    kind: str      # 'num', 'name', 'op', 'end'
    value: Any     # float, name, canonical operator
    pos: int       # start offset in the full text
    end: int
    text: str      # spelling in the source, for messages


def _tokenize(text: str, start: int, end: int, source: str | None) -> list[_Token]:
    def fail(msg: str, pos: int) -> GrammarError:
        return GrammarError(msg, text=text, position=pos, source=source)

    toks: list[_Token] = []
    i = start
    while i < end:
        c = text[i]
        if c.isspace():
            i += 1
            continue
        nxt = text[i + 1] if i + 1 < end else ""
        if c == "." and toks and toks[-1].end == i and (
                toks[-1].kind == "name" or toks[-1].value == ")"):
            raise fail("attribute access ('.') is not allowed", i)
        if c.isdigit() or (c == "." and nxt.isdigit()):
            m = _NUMBER.match(text, i, end)
            j = m.end()
            if j < end and (text[j].isalnum() or text[j] == "_"):
                k = j
                while k < end and (text[k].isalnum() or text[k] in "_."):
                    k += 1
                raise fail(f"malformed number {text[i:k]!r}", i)
            toks.append(_Token("num", float(m.group()), i, j, m.group()))
            i = j
            continue
        if c.isalpha() or c == "_":
            m = _NAME.match(text, i, end)
            word = m.group()
            if word.startswith("__"):
                raise fail(f"names starting with '__' are not allowed ({word!r})", i)
            if word in _KEYWORDS:
                toks.append(_Token("op", _KEYWORDS[word], i, m.end(), word))
            else:
                toks.append(_Token("name", word, i, m.end(), word))
            i = m.end()
            continue
        for op in _OPERATORS:
            if text.startswith(op, i, end):
                toks.append(_Token("op", op, i, i + len(op), op))
                i += len(op)
                break
        else:
            if c == ".":
                if nxt.isalpha() or nxt == "_":
                    raise fail("attribute access ('.') is not allowed", i)
                raise fail("unexpected character '.'", i)
            if c in "[]":
                raise fail("indexing ('[...]') is not allowed", i)
            if c in "'\"":
                raise fail("strings are not allowed", i)
            if c == "=":
                raise fail("'=' is not allowed; use '==' to compare", i)
            if c == "&":
                raise fail("'&' is not allowed; use '&&' (or 'and')", i)
            if c == "|":
                raise fail("'|' is not allowed; use '||' (or 'or')", i)
            raise fail(f"unexpected character {c!r}", i)
    toks.append(_Token("end", None, end, end, "end of expression"))
    return toks


# --- tree ---------------------------------------------------------------------------

@dataclass(frozen=True)
class _Node:
    kind: str            # num var neg not bin cmp and or call
    op: Any              # operator symbol, function name, variable name or value
    args: tuple["_Node", ...]
    start: int
    end: int
    height: int = 1


def _node(kind: str, op: Any, args: tuple[_Node, ...], start: int, end: int) -> _Node:
    return _Node(kind, op, args, start, end, 1 + max((a.height for a in args), default=0))


class _Parser:
    def __init__(self, text: str, start: int, end: int, allowed: frozenset[str] | None,
                 constants: Mapping[str, float], source: str | None) -> None:
        self.text, self.start, self.end = text, start, end
        self.allowed = allowed
        self.constants = constants
        self.source = source
        self.toks = _tokenize(text, start, end, source)
        self.k = 0
        self.nesting = 0
        self.free: set[str] = set()

    # helpers
    def fail(self, msg: str, pos: int) -> GrammarError:
        return GrammarError(msg, text=self.text, position=pos, source=self.source)

    def peek(self) -> _Token:
        return self.toks[self.k]

    def take(self) -> _Token:
        tok = self.toks[self.k]
        if tok.kind != "end":
            self.k += 1
        return tok

    def at(self, *ops: str) -> bool:
        tok = self.toks[self.k]
        return tok.kind == "op" and tok.value in ops

    def enter(self, tok: _Token) -> None:
        self.nesting += 1
        if self.nesting > _MAX_NESTING:
            raise self.fail(f"expression nested more than {_MAX_NESTING} levels deep", tok.pos)

    # grammar
    def parse(self) -> _Node:
        if self.peek().kind == "end":
            raise self.fail("empty expression", self.start)
        node = self.or_expr()
        tok = self.peek()
        if tok.kind != "end":
            if tok.value == ")":
                raise self.fail("unmatched ')'", tok.pos)
            if tok.value == ",":
                raise self.fail("unexpected ',' outside a function call "
                                "(split argument lists with split_arguments)", tok.pos)
            raise self.fail(f"unexpected {tok.text!r} after a complete expression "
                            "(missing operator?)", tok.pos)
        if node.height > _MAX_HEIGHT:
            raise self.fail(f"expression has more than {_MAX_HEIGHT} nested operations",
                            self.start)
        return node

    def _binary_chain(self, kind: str, ops: tuple[str, ...],
                      operand: Callable[[], _Node]) -> _Node:
        left = operand()
        while self.at(*ops):
            op = self.take().value
            right = operand()
            left = _node(kind, op, (left, right), left.start, right.end)
        return left

    def or_expr(self) -> _Node:
        return self._binary_chain("or", ("||",), self.and_expr)

    def and_expr(self) -> _Node:
        return self._binary_chain("and", ("&&",), self.not_expr)

    def not_expr(self) -> _Node:
        if self.at("!"):
            tok = self.take()
            self.enter(tok)
            operand = self.not_expr()
            self.nesting -= 1
            return _node("not", "!", (operand,), tok.pos, operand.end)
        return self.comparison()

    def comparison(self) -> _Node:
        left = self.additive()
        if self.at(*_COMPARISONS):
            op = self.take().value
            right = self.additive()
            if self.at(*_COMPARISONS):
                raise self.fail("chained comparisons are ambiguous; write "
                                "'a < b && b < c'", self.peek().pos)
            return _node("cmp", op, (left, right), left.start, right.end)
        return left

    def additive(self) -> _Node:
        return self._binary_chain("bin", ("+", "-"), self.term)

    def term(self) -> _Node:
        return self._binary_chain("bin", ("*", "/"), self.unary)

    def unary(self) -> _Node:
        if self.at("-", "+"):
            tok = self.take()
            self.enter(tok)
            operand = self.unary()
            self.nesting -= 1
            if tok.value == "+":
                return _Node(operand.kind, operand.op, operand.args, tok.pos, operand.end,
                             operand.height)
            return _node("neg", "-", (operand,), tok.pos, operand.end)
        return self.power()

    def power(self) -> _Node:
        base = self.primary()
        if self.at("^", "**"):
            self.take()
            exponent = self.unary()   # right-associative, may carry a sign
            return _node("bin", "^", (base, exponent), base.start, exponent.end)
        return base

    def primary(self) -> _Node:
        tok = self.take()
        if tok.kind == "num":
            return _node("num", tok.value, (), tok.pos, tok.end)
        if tok.kind == "name":
            if self.at("("):
                return self.call(tok)
            return self.name(tok)
        if tok.kind == "op" and tok.value == "(":
            self.enter(tok)
            inner = self.or_expr()
            self.nesting -= 1
            close = self.peek()
            if close.kind == "end":
                raise self.fail("unclosed '('", tok.pos)
            if close.value != ")":
                raise self.fail(f"expected ')' to close '(' at position {tok.pos}, "
                                f"found {close.text!r}", close.pos)
            self.take()
            return _Node(inner.kind, inner.op, inner.args, tok.pos, close.end, inner.height)
        if tok.kind == "end":
            raise self.fail("expression ends early; expected a number, name or '('",
                            tok.pos)
        if tok.value == ")":
            raise self.fail("unexpected ')'; expected a number, name or '('", tok.pos)
        raise self.fail(f"unexpected {tok.text!r}; expected a number, name or '('", tok.pos)

    def _is_variable(self, name: str) -> bool:
        return self.allowed is None or name in self.allowed

    def name(self, tok: _Token) -> _Node:
        name = tok.value
        declared = self.allowed is not None and name in self.allowed
        if name in self.constants and not declared:
            return _node("num", float(self.constants[name]), (), tok.pos, tok.end)
        if name in CONSTANTS and not declared:
            return _node("num", CONSTANTS[name], (), tok.pos, tok.end)
        if name in _FUNCS and not declared:
            raise self.fail(f"function '{name}' must be called, e.g. {name}(x)", tok.pos)
        if not self._is_variable(name):
            known = sorted(set(self.allowed or ()) | set(self.constants) | set(CONSTANTS))
            raise self.fail(f"unknown name '{name}'; known names: {', '.join(known)}",
                            tok.pos)
        self.free.add(name)
        return _node("var", name, (), tok.pos, tok.end)

    def call(self, tok: _Token) -> _Node:
        name = tok.value
        if name not in _FUNCS:
            raise self.fail(f"unknown function '{name}'; functions: "
                            f"{', '.join(sorted(_FUNCS))}", tok.pos)
        open_ = self.take()
        self.enter(open_)
        args: list[_Node] = []
        if not self.at(")"):
            while True:
                args.append(self.or_expr())
                if self.at(","):
                    self.take()
                    continue
                break
        self.nesting -= 1
        close = self.peek()
        if close.kind == "end":
            raise self.fail("unclosed '('", open_.pos)
        if close.value != ")":
            raise self.fail(f"expected ',' or ')' in call of '{name}', found {close.text!r}",
                            close.pos)
        self.take()
        lo, hi = _FUNCS[name][:2]
        if len(args) < lo or (hi is not None and len(args) > hi):
            want = f"{lo}" if lo == hi else f"at least {lo}"
            raise self.fail(f"'{name}' takes {want} argument{'s' if lo > 1 else ''}, "
                            f"got {len(args)}", tok.pos)
        return _node("call", name, tuple(args), tok.pos, close.end)


# --- compilation ----------------------------------------------------------------------

_ARITH = {"+": operator.add, "-": operator.sub, "*": operator.mul}
_CMP = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
        "==": operator.eq, "!=": operator.ne}
_NP_ARITH = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide,
             "^": np.power}
_NP_CMP = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal,
           "==": np.equal, "!=": np.not_equal}

_Scalar = Callable[[dict], Any]
_Vector = Callable[[dict, np.ndarray], Any]


class _Compiler:
    """Turns a tree into scalar closures ``f(env)`` or vector closures ``f(env, idx)``.

    In vector closures every array in ``env`` is 1-D with ``len(idx)`` rows and
    ``idx`` holds the rows' positions in the caller's arrays (subsets arise from
    short-circuit logic); a closure returns a Python scalar or such an array.
    """

    def __init__(self, full_text: str, text: str, names: Iterable[str],
                 source: str | None) -> None:
        self.full_text = full_text
        self.text = text
        self.names = tuple(sorted(names))
        self.source = source

    def sub(self, node: _Node) -> str:
        return self.full_text[node.start:node.end]

    def fail(self, msg: str, node: _Node, env: dict, j: int | None = None,
             idx: np.ndarray | None = None) -> ExpressionError:
        if j is None and idx is not None and len(idx) and any(
                isinstance(env.get(k), np.ndarray) for k in self.names):
            j = 0        # a scalar sub-result failed, so every element fails
        if j is None:
            values = {k: env[k] for k in self.names if k in env}
            index = None
        else:
            values = {k: (env[k][j].item() if isinstance(env[k], np.ndarray) else env[k])
                      for k in self.names if k in env}
            index = int(idx[j])
        return ExpressionError(msg, text=self.text, subexpression=self.sub(node),
                               values=values, index=index, source=self.source)

    # scalar ----------------------------------------------------------------------
    def scalar(self, node: _Node) -> _Scalar:
        kind = node.kind
        if kind == "num":
            value = node.op
            return lambda env: value
        if kind == "var":
            name = node.op
            return lambda env: env[name]
        args = [self.scalar(a) for a in node.args]
        isfinite = math.isfinite
        fail = self.fail
        if kind == "neg":
            (a,) = args
            return lambda env: -a(env)
        if kind == "not":
            (a,) = args
            return lambda env: not a(env)
        if kind == "and":
            a, b = args
            return lambda env: bool(a(env)) and bool(b(env))
        if kind == "or":
            a, b = args
            return lambda env: bool(a(env)) or bool(b(env))
        if kind == "cmp":
            a, b = args
            cmp = _CMP[node.op]
            return lambda env: cmp(a(env), b(env))
        if kind == "bin":
            a, b = args
            op = node.op
            if op == "/":
                den_node = node.args[1]

                def div(env: dict) -> Any:
                    den = b(env)
                    if den == 0:
                        raise fail("division by zero", den_node, env)
                    r = a(env) / den
                    if not isfinite(r):
                        raise fail(f"non-finite result {r}", node, env)
                    return r
                return div
            if op == "^":
                def power(env: dict) -> Any:
                    try:
                        r = float(a(env)) ** b(env)
                    except ZeroDivisionError:
                        raise fail("zero raised to a negative power", node, env) from None
                    except OverflowError:
                        raise fail("overflow", node, env) from None
                    if isinstance(r, complex):
                        raise fail("negative number raised to a non-integer power",
                                   node, env)
                    if not isfinite(r):
                        raise fail(f"non-finite result {r}", node, env)
                    return r
                return power
            fn = _ARITH[op]

            def arith(env: dict) -> Any:
                r = fn(a(env), b(env))
                if not isfinite(r):
                    raise fail(f"non-finite result {r}", node, env)
                return r
            return arith
        if kind == "call":
            name = node.op
            fn = _FUNCS[name][2]

            def call(env: dict) -> Any:
                xs = [f(env) for f in args]
                try:
                    r = fn(*xs)
                except OverflowError:
                    raise fail(f"overflow in {name}("
                               f"{', '.join(_fmt(x) for x in xs)})", node, env) from None
                except (ValueError, ZeroDivisionError):
                    raise fail(f"argument outside the domain of {name}() "
                               f"({', '.join(_fmt(x) for x in xs)})", node, env) from None
                if not isfinite(r):
                    raise fail(f"non-finite result {r}", node, env)
                return r
            return call
        raise AssertionError(kind)

    # vector ----------------------------------------------------------------------
    def check(self, r: Any, node: _Node, env: dict, idx: np.ndarray) -> Any:
        if isinstance(r, np.ndarray):
            bad = ~np.isfinite(r)
            if bad.any():
                j = int(np.argmax(bad))
                raise self.fail(f"non-finite result {_fmt(r[j])}", node, env, j, idx)
        elif not math.isfinite(r):
            raise self.fail(f"non-finite result {_fmt(r)}", node, env, None, idx)
        return r

    def vector(self, node: _Node) -> _Vector:
        kind = node.kind
        if kind == "num":
            value = node.op
            return lambda env, idx: value
        if kind == "var":
            name = node.op
            return lambda env, idx: env[name]
        args = [self.vector(a) for a in node.args]
        check = self.check
        if kind == "neg":
            (a,) = args
            return lambda env, idx: np.negative(_num(a(env, idx)))
        if kind == "not":
            (a,) = args
            return lambda env, idx: np.logical_not(_truth(a(env, idx)))
        if kind == "cmp":
            a, b = args
            cmp = _NP_CMP[node.op]
            return lambda env, idx: cmp(a(env, idx), b(env, idx))
        if kind in ("and", "or"):
            a, b = args
            is_and = kind == "and"

            def logic(env: dict, idx: np.ndarray) -> Any:
                left = _truth(a(env, idx))
                if not isinstance(left, np.ndarray):
                    if bool(left) != is_and:      # decided by the left operand
                        return bool(left)
                    return _truth(b(env, idx))
                # evaluate the right operand only on rows the left leaves open
                todo = left if is_and else ~left
                out = left.copy()
                if todo.any():
                    sub = {k: (v[todo] if isinstance(v, np.ndarray) else v)
                           for k, v in env.items()}
                    out[todo] = _truth(b(sub, idx[todo]))
                return out
            return logic
        if kind == "bin":
            a, b = args
            op = node.op
            fn = _NP_ARITH[op]
            if op == "/":
                den_node = node.args[1]

                def div(env: dict, idx: np.ndarray) -> Any:
                    den = _num(b(env, idx))
                    zero = den == 0
                    if np.any(zero):
                        j = int(np.argmax(zero)) if isinstance(zero, np.ndarray) else None
                        raise self.fail("division by zero", den_node, env, j, idx)
                    return check(fn(_num(a(env, idx)), den), node, env, idx)
                return div

            def arith(env: dict, idx: np.ndarray) -> Any:
                return check(fn(_num(a(env, idx)), _num(b(env, idx))), node, env, idx)
            return arith
        if kind == "call":
            fn = _FUNCS[node.op][3]

            def call(env: dict, idx: np.ndarray) -> Any:
                return check(fn(*[_num(f(env, idx)) for f in args]), node, env, idx)
            return call
        raise AssertionError(kind)


def _num(x: Any) -> Any:
    """Booleans count as 0/1 in arithmetic (numpy would add bools as logical or)."""
    if isinstance(x, np.ndarray):
        return x.astype(np.float64) if x.dtype == bool else x
    return float(x)


def _truth(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x if x.dtype == bool else x != 0
    return bool(x)


def _fold(node: _Node, compiler: _Compiler) -> _Node:
    """Replace sub-trees without variables by their value (``2*pi/360``)."""
    if not node.args:
        return node
    args = tuple(_fold(a, compiler) for a in node.args)
    node = _Node(node.kind, node.op, args, node.start, node.end, node.height)
    if all(a.kind == "num" for a in args):
        try:
            value = compiler.scalar(node)({})
        except ExpressionError:
            return node          # keep it, so the error surfaces at evaluation
        if type(value) is int:       # True + True
            value = float(value)
        return _Node("num", value, (), node.start, node.end, 1)
    return node


def _as_tuple(node: _Node) -> Any:
    if node.kind in ("num", "var"):
        return node.op
    op = {"neg": "neg", "not": "!", "and": "&&", "or": "||"}.get(node.kind, node.op)
    return (op, *(_as_tuple(a) for a in node.args))


# --- public API -----------------------------------------------------------------------

class Expression:
    """A parsed, compiled expression; create with :func:`parse_expression`.

    Attributes
    ----------
    text : str
        The expression as written (surrounding blanks stripped).
    names : frozenset of str
        Free variables that :meth:`evaluate` needs (constants excluded).
    source : str or None
        Where it came from, for messages.
    """

    __slots__ = ("text", "names", "source", "_root", "_compiler", "_scalar", "_vector",
                 "_args")

    def __init__(self, text: str, names: frozenset[str], source: str | None,
                 root: _Node, compiler: _Compiler, args: tuple) -> None:
        self.text = text
        self.names = names
        self.source = source
        self._root = root
        self._compiler = compiler
        self._scalar = compiler.scalar(root)
        self._vector: _Vector | None = None   # compiled on first vector call
        self._args = args

    def __repr__(self) -> str:
        return f"Expression({self.text!r})"

    def __reduce__(self) -> tuple:
        # closures do not pickle; re-parse instead (e.g. for multiprocessing)
        return (_rebuild, self._args)

    @property
    def is_boolean(self) -> bool:
        """True if the top operation is a comparison or logical operator."""
        r = self._root
        return r.kind in ("cmp", "and", "or", "not") or isinstance(r.op, bool)

    @property
    def is_constant(self) -> bool:
        """True if the expression has no free variables (it was folded to a value)."""
        return self._root.kind == "num"

    @property
    def tree(self) -> Any:
        """The (constant-folded) tree as nested tuples, e.g. ``('+', 'a', ('*', 'b', 2.0))``.

        Operators keep their symbol, unary minus is ``'neg'``, calls use the
        function name; meant for inspection and tests.
        """
        return _as_tuple(self._root)

    def evaluate(self, env: Mapping[str, Any] | None = None) -> Any:
        """Evaluate for one module, or for many at once.

        Parameters
        ----------
        env : mapping name -> value
            A value for every name in :attr:`names` (extra entries are ignored).
            If any value in ``env`` is array-like (numpy array, list or tuple),
            all array values are broadcast together and the expression is
            evaluated element-wise, with the same result per element as the
            scalar evaluation.

        Returns
        -------
        float or bool, or an ndarray of float64 or bool with the broadcast shape.

        Raises
        ------
        ExpressionError
            A name has no value or a non-finite value; division by zero; a
            result that is infinite or NaN; a function outside its domain.
        """
        env = {} if env is None else env
        arrays = [k for k, v in env.items()
                  if isinstance(v, (list, tuple)) or (isinstance(v, np.ndarray) and v.ndim)]
        missing = [n for n in self.names if n not in env]
        if missing:
            raise ExpressionError(f"no value given for {', '.join(map(repr, sorted(missing)))}",
                                  text=self.text, source=self.source)
        if not arrays:
            vals = {}
            for n in self.names:
                v = env[n]
                try:
                    v = float(v)
                except (TypeError, ValueError):
                    raise ExpressionError(f"value of '{n}' is not a number: {v!r}",
                                          text=self.text, source=self.source) from None
                if not math.isfinite(v):
                    raise ExpressionError(f"value of '{n}' is not finite",
                                          text=self.text, values={n: v},
                                          source=self.source)
                vals[n] = v
            r = self._scalar(vals)
            return float(r) if type(r) is int else r
        return self._evaluate_vector(env, arrays)

    __call__ = evaluate

    def _evaluate_vector(self, env: Mapping[str, Any], arrays: list[str]) -> np.ndarray:
        try:
            shape = np.broadcast_shapes(*(np.shape(env[k]) for k in arrays))
        except ValueError:
            shapes = ", ".join(f"{k}: {np.shape(env[k])}" for k in arrays)
            raise ExpressionError(f"parameter arrays do not broadcast ({shapes})",
                                  text=self.text, source=self.source) from None
        n = int(np.prod(shape))
        flat: dict[str, Any] = {}
        for k in self.names:
            try:
                a = np.asarray(env[k], dtype=np.float64)
            except (TypeError, ValueError):
                raise ExpressionError(f"value of '{k}' is not numeric",
                                      text=self.text, source=self.source) from None
            bad = ~np.isfinite(a)
            if bad.any():
                j = int(np.argmax(bad.ravel())) if a.ndim else None
                raise ExpressionError(f"value of '{k}' is not finite", text=self.text,
                                      values={k: a.ravel()[j or 0]}, index=j,
                                      source=self.source)
            flat[k] = np.broadcast_to(a, shape).ravel() if a.ndim else float(a)
        if self._vector is None:
            self._vector = self._compiler.vector(self._root)
        with np.errstate(all="ignore"):      # we raise our own, clearer errors
            r = self._vector(flat, np.arange(n))
        if isinstance(r, np.ndarray) and r.shape == (n,):
            out = r.reshape(shape)
        else:
            out = np.full(shape, r)
        if out.dtype != bool and out.dtype != np.float64:
            out = out.astype(np.float64)
        return out


def _parse(text: str, names: Iterable[str] | None, source: str | None,
           constants: Mapping[str, float] | None, start: int, end: int | None) -> Expression:
    if not isinstance(text, str):
        raise GrammarError(f"expression must be a string, got {type(text).__name__}",
                           source=source)
    end = len(text) if end is None else end
    allowed = None if names is None else frozenset(names)
    consts = dict(constants or {})
    for k, v in consts.items():
        if not isinstance(v, (int, float, np.number)) or not math.isfinite(v):
            raise GrammarError(f"constant '{k}' must be a finite number, got {v!r}",
                               source=source)
    parser = _Parser(text, start, end, allowed, consts, source)
    root = parser.parse()
    stripped = text[start:end].strip()
    compiler = _Compiler(text, stripped, parser.free, source)
    root = _fold(root, compiler)
    args = (text[start:end], None if allowed is None else tuple(sorted(allowed)), source,
            consts or None, 0, None)
    return Expression(stripped, frozenset(parser.free), source, root, compiler, args)


def _rebuild(text: str, names: Iterable[str] | None, source: str | None,
             constants: Mapping[str, float] | None, start: int, end: int | None) -> Expression:
    return _parse(text, names, source, constants, start, end)


def parse_expression(text: str, names: Iterable[str] | None = None,
                     source: str | None = None, *,
                     constants: Mapping[str, float] | None = None,
                     start: int = 0, end: int | None = None) -> Expression:
    """Parse and compile one expression.

    Parameters
    ----------
    text : str
        The expression, or a longer string of which ``text[start:end]`` is parsed
        (error positions then index into the whole string, so a production's
        argument list can be parsed in place).
    names : iterable of str, optional
        The parameter names the expression may use (e.g. the module's formal
        parameters plus global variables). ``None`` accepts any name as a free
        variable. A declared name shadows ``pi`` and caller constants; a
        declared name that is also a function name is the variable unless it
        is followed by ``(``.
    source : str, optional
        Where the text came from (file, production), for messages.
    constants : mapping name -> float, optional
        Values known at parse time (e.g. ``r1``, ``wr``, ``d``); they are folded
        into the expression and are not among :attr:`Expression.names`.
    start, end : int
        The slice of ``text`` to parse.

    Returns
    -------
    Expression

    Raises
    ------
    GrammarError
        With the position (into ``text``) of an unknown name or function, a
        name starting with ``__``, attribute access, indexing, a string,
        unbalanced parentheses, a wrong number of function arguments, a
        chained comparison, trailing input, or an empty expression.

    Examples
    --------
    >>> e = parse_expression("l*r1", {"l"}, constants={"r1": 0.9})
    >>> e.evaluate({"l": 2.0})
    1.8
    >>> parse_expression("l > 0.1 && w <= 2").evaluate({"l": 1, "w": 3})
    False
    """
    return _parse(text, names, source, constants, start, end)


def argument_spans(text: str, source: str | None = None, *, start: int = 0,
                   end: int | None = None) -> list[tuple[int, int]]:
    """Offsets ``(a, b)`` of the comma-separated arguments in ``text[start:end]``.

    Commas inside parentheses do not split; blanks around each argument are
    excluded. A blank string has no arguments.

    Raises
    ------
    GrammarError
        Unbalanced parentheses or an empty argument (``a,,b``, trailing comma).
    """
    end = len(text) if end is None else end
    if not text[start:end].strip():
        return []
    open_: list[int] = []
    cuts = [start - 1]
    for i in range(start, end):
        c = text[i]
        if c == "(":
            open_.append(i)
        elif c == ")":
            if not open_:
                raise GrammarError("unmatched ')'", text=text, position=i, source=source)
            open_.pop()
        elif c == "," and not open_:
            cuts.append(i)
    if open_:
        raise GrammarError("unclosed '('", text=text, position=open_[-1], source=source)
    cuts.append(end)
    spans = []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        a, b = lo + 1, hi
        while a < b and text[a].isspace():
            a += 1
        while b > a and text[b - 1].isspace():
            b -= 1
        if a == b:
            raise GrammarError("empty argument", text=text, position=a if hi == end else hi,
                               source=source)
        spans.append((a, b))
    return spans


def split_arguments(text: str, source: str | None = None) -> list[str]:
    """Split ``"l*r1, w*wr"`` at top-level commas: ``['l*r1', 'w*wr']``.

    >>> split_arguments("min(a, b), c*(d+1)")
    ['min(a, b)', 'c*(d+1)']
    """
    return [text[a:b] for a, b in argument_spans(text, source)]


def parse_arguments(text: str, names: Iterable[str] | None = None,
                    source: str | None = None, *,
                    constants: Mapping[str, float] | None = None,
                    start: int = 0, end: int | None = None) -> list[Expression]:
    """Parse a comma-separated argument list (``l*r1, w*wr``) into expressions.

    Error positions index into ``text``, as for :func:`parse_expression`.
    """
    return [_parse(text, names, source, constants, a, b)
            for a, b in argument_spans(text, source, start=start, end=end)]
