"""Module strings: the words an L-system rewrites.

A *module* is a one-character symbol with an optional tuple of numeric
parameters, written ``I(1)`` (ABOP's parametric notation). A
:class:`ModuleString` stores a whole bracketed word column-wise, so derivation
and interpretation run on numpy arrays instead of Python strings:

``codes``
    ``(n,)`` int16, index of each module's symbol in ``alphabet``.
``nargs``
    ``(n,)`` uint8, how many parameters each module carries.
``params``
    ``(n, k)`` float64, parameters, left-aligned; ``k`` is the widest module
    (``k = 0`` for a non-parametric word). Entries past ``nargs`` are 0.

This layout carries everything an ABOP parametric L-system needs (``A(l,w)``
is the code of ``A`` with two parameters): parametric productions only
compute new parameter columns (:mod:`simlidar_mi.lsystem.derive`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, NamedTuple, Sequence

import numpy as np

from ..errors import GrammarError

OPEN = "["
CLOSE = "]"
#: Reserved successor token: "the generation that wrote this module" (``In``).
GENERATION_TOKEN = "n"
#: Characters that can never be symbols (syntax of grammars and module strings).
#: ``|`` separates stochastic alternatives, but it may be declared as a symbol (ABOP's
#: turn-around); the grammar then reads ``|`` as a separator only before ``(p)``.
RESERVED_CHARS = frozenset("(),#:" + GENERATION_TOKEN)
#: Symbols of the SIMLIDAR apple grammar and its turtle (paper, Table 2).
DEFAULT_ALPHABET: tuple[str, ...] = ("F", "I", OPEN, CLOSE, "+", "-", "R", "r", "T", "t")


class Module(NamedTuple):
    """One module: a symbol and its parameters (``Module('I', (1.0,))`` is ``I(1)``)."""

    symbol: str
    params: tuple[float, ...] = ()

    def __str__(self) -> str:
        if not self.params:
            return self.symbol
        return f"{self.symbol}({','.join(format_number(p) for p in self.params)})"


def format_number(value: float) -> str:
    """Shortest faithful text of a parameter: ``1.0`` -> ``'1'``, ``0.5`` -> ``'0.5'``."""
    v = float(value)
    if v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    return repr(v)


def check_alphabet(symbols: Sequence[str]) -> tuple[str, ...]:
    """Validate and normalise an alphabet; brackets are always included.

    Raises
    ------
    GrammarError
        for a symbol that is not one character or is a reserved character.
    """
    out: list[str] = []
    for s in list(symbols) + [OPEN, CLOSE]:
        if len(s) != 1 or s.isspace() or s in RESERVED_CHARS:
            raise GrammarError(
                f"alphabet symbol {s!r} is not allowed: symbols are single characters other "
                f"than whitespace and {''.join(sorted(RESERVED_CHARS))!r}")
        if s not in out:
            out.append(s)
    if len(out) > np.iinfo(np.int16).max:
        raise GrammarError(f"alphabet has {len(out)} symbols, at most 32767 are supported")
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ModuleString:
    """A bracketed word of modules stored as arrays (see the module docstring).

    Attributes
    ----------
    alphabet : symbols, ``codes`` index into it.
    codes : (n,) int16.
    nargs : (n,) uint8.
    params : (n, k) float64.
    """

    alphabet: tuple[str, ...]
    codes: np.ndarray
    nargs: np.ndarray
    params: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.codes)
        if self.codes.ndim != 1 or self.nargs.shape != (n,) or self.params.ndim != 2 \
                or self.params.shape[0] != n:
            raise GrammarError(
                f"ModuleString arrays disagree: codes {self.codes.shape}, "
                f"nargs {self.nargs.shape}, params {self.params.shape}")
        if n and (self.codes.min() < 0 or self.codes.max() >= len(self.alphabet)):
            raise GrammarError("ModuleString codes outside the alphabet")

    # --- construction -----------------------------------------------------------
    @classmethod
    def from_modules(cls, modules: Sequence[Module | tuple], alphabet: Sequence[str]
                     = DEFAULT_ALPHABET) -> "ModuleString":
        """Build from ``Module`` objects or ``(symbol, params)`` tuples."""
        alphabet = check_alphabet(alphabet)
        index = {s: i for i, s in enumerate(alphabet)}
        mods = [Module(m[0], tuple(float(p) for p in (m[1] if len(m) > 1 else ())))
                for m in modules]
        k = max((len(m.params) for m in mods), default=0)
        codes = np.empty(len(mods), np.int16)
        nargs = np.zeros(len(mods), np.uint8)
        params = np.zeros((len(mods), k))
        for i, m in enumerate(mods):
            if m.symbol not in index:
                raise GrammarError(f"unknown symbol {m.symbol!r} (alphabet {''.join(alphabet)!r})",
                                   position=i)
            codes[i] = index[m.symbol]
            nargs[i] = len(m.params)
            params[i, :len(m.params)] = m.params
        return cls(alphabet, codes, nargs, params)

    # --- access -----------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.codes)

    def __getitem__(self, i: int) -> Module:
        j = int(self.nargs[i])
        return Module(self.alphabet[int(self.codes[i])],
                      tuple(float(p) for p in self.params[i, :j]))

    def __iter__(self) -> Iterator[Module]:
        return (self[i] for i in range(len(self)))

    def code(self, symbol: str) -> int:
        """Code of ``symbol`` in this string's alphabet, ``-1`` if absent."""
        try:
            return self.alphabet.index(symbol)
        except ValueError:
            return -1

    def count(self, symbol: str) -> int:
        """How many modules carry ``symbol``."""
        c = self.code(symbol)
        return 0 if c < 0 else int(np.count_nonzero(self.codes == c))

    def to_text(self, rename: dict[str, str] | None = None, param_format=None) -> str:
        """The word as text, ``I(1)I(1)[r+...``.

        Parameters
        ----------
        rename : optional symbol -> text map applied while writing.
        param_format : optional ``f(symbol, params) -> str`` replacing ``(p, q)``.
        """
        rename = rename or {}
        sym = [rename.get(s, s) for s in self.alphabet]
        if param_format is None and not self.params.shape[1]:
            return "".join(np.asarray(sym, dtype=object)[self.codes].tolist())
        parts = []
        for i in range(len(self)):
            m = self[i]
            if param_format is not None:
                parts.append(sym[int(self.codes[i])] + param_format(m.symbol, m.params))
            elif m.params:
                parts.append(sym[int(self.codes[i])]
                             + f"({','.join(format_number(p) for p in m.params)})")
            else:
                parts.append(sym[int(self.codes[i])])
        return "".join(parts)

    def __str__(self) -> str:
        return self.to_text()

    def __repr__(self) -> str:
        if len(self) <= 60:
            return f"ModuleString({len(self)} modules: {self.to_text()!r})"
        return f"ModuleString({len(self)} modules)"

    def same_as(self, other: "ModuleString") -> bool:
        """Exact equality of alphabet, symbols and parameters."""
        if self.alphabet != other.alphabet or len(self) != len(other):
            return False
        k = max(self.params.shape[1], other.params.shape[1])
        return (np.array_equal(self.codes, other.codes) and np.array_equal(self.nargs, other.nargs)
                and np.array_equal(_pad(self.params, k), _pad(other.params, k)))


def _pad(params: np.ndarray, k: int) -> np.ndarray:
    if params.shape[1] == k:
        return params
    out = np.zeros((params.shape[0], k))
    out[:, :params.shape[1]] = params
    return out
