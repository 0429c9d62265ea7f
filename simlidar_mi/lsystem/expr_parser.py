"""Syntax tree of expressions and the recursive-descent parser that builds it."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ..errors import GrammarError
from .expr_builtins import _FUNCS, CONSTANTS
from .expr_tokens import _Token, _tokenize

_COMPARISONS = ("<", "<=", ">", ">=", "==", "!=")
# Nesting depth of parentheses / unary operators; each level costs ~10 parser
# frames, so this keeps well inside Python's recursion limit.
_MAX_NESTING = 50
# Height of the tree (long chains like 1+1+...+1); each level is one closure call.
_MAX_HEIGHT = 200


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
