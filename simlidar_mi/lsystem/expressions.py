"""Safe arithmetic expressions for parametric L-systems (ABOP §1.10).

Successor arguments such as ``l*r1, w*wr`` and conditions such as
``l > 0.1 && w <= 2`` are parsed by a small tokenizer (:mod:`.expr_tokens`)
and recursive-descent parser (:mod:`.expr_parser`) into a tree,
constant-folded and compiled into closures (:mod:`.expr_compile`). Nothing is
handed to Python's ``eval``; the only names an expression can reach are its
parameters, caller constants, ``pi`` and the functions listed in
:data:`~.expr_builtins.FUNCTIONS`.

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
:class:`~.expr_compile.ExpressionError`, naming the expression, the failing sub-expression
and the parameter values.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

import numpy as np

from ..errors import GrammarError
from .expr_compile import ExpressionError, _Compiler, _fold, _Vector
from .expr_parser import _Node, _Parser

__all__ = [
    "Expression", "argument_spans", "parse_arguments", "parse_expression",
    "split_arguments",
]


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
        chained comparison, trailing input, or an empty expression; a number
        beyond float64 (``1e400``); more than
        :data:`~.expr_tokens.MAX_CHARS` characters or
        :data:`~.expr_tokens.MAX_TOKENS` tokens (checked before parsing, so
        huge input fails at once).

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
