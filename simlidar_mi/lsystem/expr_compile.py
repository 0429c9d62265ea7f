"""Compiling expression trees: constant folding, scalar and vector closures, ExpressionError."""
from __future__ import annotations

import math
import operator
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from ..errors import SimlidarError
from .expr_builtins import _FUNCS
from .expr_parser import _Node

__all__ = ["ExpressionError"]


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
