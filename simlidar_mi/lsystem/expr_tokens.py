"""Tokenizer of expressions: numbers, names, keywords and operators with their offsets."""
from __future__ import annotations

import re
from typing import Any, NamedTuple

from ..errors import GrammarError

_KEYWORDS = {"and": "&&", "or": "||", "not": "!"}
_OPERATORS = ("&&", "||", "<=", ">=", "==", "!=", "**", "<", ">", "!", "+", "-", "*",
              "/", "^", "(", ")", ",")
_NUMBER = re.compile(r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_NAME = re.compile(r"[A-Za-z_][A-Za-z_0-9]*")
# Expressions are a production's arguments or condition: far shorter than these.  The
# limits are checked before the parser runs, so huge input fails in milliseconds.
MAX_CHARS = 10_000
MAX_TOKENS = 2_000


class _Token(NamedTuple):
    kind: str      # 'num', 'name', 'op', 'end'
    value: Any     # float, name, canonical operator
    pos: int       # start offset in the full text
    end: int
    text: str      # spelling in the source, for messages


def _tokenize(text: str, start: int, end: int, source: str | None) -> list[_Token]:
    def fail(msg: str, pos: int) -> GrammarError:
        return GrammarError(msg, text=text, position=pos, source=source)

    if end - start > MAX_CHARS:
        raise fail(f"expression is {end - start} characters long; the limit is {MAX_CHARS}", start)
    toks: list[_Token] = []
    i = start
    while i < end:
        if len(toks) >= MAX_TOKENS:
            raise fail(f"expression has more than {MAX_TOKENS} tokens (numbers, names, operators)",
                       toks[-1].pos)
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
            value = float(m.group())
            if value == float("inf"):  # '1e400', or 1 and 400 zeros: not a float64
                raise fail(f"number {m.group()[:20]}{'…' if j - i > 20 else ''} is too large "
                           "(float64 holds at most 1.8e308)", i)
            toks.append(_Token("num", value, i, j, m.group()))
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
