"""Parallel rewriting of module strings, with a size guard.

One generation rewrites every module at once (the L-system rule), fully
vectorised: each module gets a successor id (``-1`` = copied unchanged), the
output lengths are summed, and the new arrays are gathered from a table of
all successors in one pass. The cost is linear in the output size; there is
no string concatenation.

Parametric productions (ABOP §1.10)
    For each symbol, its productions are tried in grammar order on the modules
    not yet claimed: the arity must match the formal parameters, then the
    condition is evaluated once for all candidate modules as numpy arrays.
    Computed successor parameters (``l*r1``) are evaluated the same way, once
    per successor slot for every module that chose that successor, so the
    Python overhead per generation is per production, not per module.
    Evaluation errors (division by zero, a non-finite result) raise
    :class:`~simlidar_mi.lsystem.expr_compile.ExpressionError` naming the
    production (grammar line), the generation and the module.

Stochastic productions draw one uniform number per rewritten module from the
``numpy.random.Generator`` passed in, in string order, production by
production (in grammar order), generation by generation. The same generator
state therefore gives the same word, bit for bit.

Before allocating anything, :func:`predict_size` bounds the final length by
counting per-symbol growth (the longest successor choice, ignoring
conditions: an upper bound for stochastic and parametric grammars and the
exact length for deterministic, non-parametric ones), and :func:`derive`
refuses with :class:`~simlidar_mi.errors.DerivationTooLarge` when it exceeds
``max_modules``. Every generation also checks its exact output length before
allocating it.
"""
from __future__ import annotations

import math
import operator

import numpy as np

from ..errors import ConfigError, DerivationTooLarge
from .expr_compile import ExpressionError
from .expressions import Expression
from .grammar import Grammar, Production
from .modules import GENERATION_TOKEN, ModuleString, _pad

#: Default refusal threshold: 50 million modules (~0.6 GB for one-parameter words).
DEFAULT_MAX_MODULES = 50_000_000


def _check_generations(generations, grammar: Grammar) -> int:
    if generations is None:
        generations = grammar.derivation_length
        if generations is None:
            raise ConfigError("no number of generations given and the grammar has no "
                              "'derivation length'", key="generations", value=None)
    try:
        g = operator.index(generations)
    except TypeError:
        raise ConfigError("must be a whole number >= 0", key="generations",
                          value=generations) from None
    if isinstance(generations, bool) or g < 0:
        raise ConfigError("must be a whole number >= 0", key="generations", value=generations)
    return g


def _check_max_modules(max_modules) -> int:
    if isinstance(max_modules, bool) or not isinstance(max_modules, (int, np.integer)) \
            or max_modules < 1:
        raise ConfigError("must be a whole number >= 1", key="max_modules", value=max_modules)
    return int(max_modules)


def _growth_table(grammar: Grammar, productions: tuple[Production, ...]):
    """Per symbol code: (successor symbol counts, may a module stay unrewritten)."""
    table: dict[int, list] = {}
    for p in productions:
        code = grammar.alphabet.index(p.predecessor)
        entry = table.setdefault(code, [[], True])
        for s in p.successors:
            u, c = np.unique(s.word.codes, return_counts=True)
            entry[0].append((u.astype(np.intp), c.astype(np.float64)))
        if p.formals is None and p.condition is None:
            entry[1] = False        # this production claims every remaining module
    return table


def predict_size(grammar: Grammar, generations: int | None = None,
                 axiom: ModuleString | None = None) -> int | float:
    """Upper bound of the number of modules after ``generations`` rewrites.

    ``c_0(s) = 1`` for every symbol; ``c_{g+1}(s)`` is the largest, over the
    successors of every production of ``s``, of the summed ``c_g`` of their
    modules, and at least ``c_g(s)`` when a module of ``s`` may be left
    unrewritten (a condition or an arity that does not match); symbols without
    a production keep ``c_g(s) = 1``. The bound is the sum of ``c_N`` over the
    axiom; conditions are ignored, and it is exact for deterministic,
    non-parametric grammars.

    Returns
    -------
    int, or ``math.inf`` when the bound exceeds the float range.
    """
    g = _check_generations(generations, grammar)
    word = axiom.codes if axiom is not None else grammar.axiom.codes
    n_sym = len(grammar.alphabet)
    table = _growth_table(grammar, grammar.productions)
    # Floats: exact below 2**53 (far above any sensible limit) and no slow bignums.
    word_idx = np.asarray(word, np.intp)
    size = np.ones(n_sym)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow to inf = "too many"
        for _ in range(g):
            new = size.copy()
            for code, (succ, may_stay) in table.items():
                best = max((float(np.dot(c, size[u])) for u, c in succ), default=0.0)
                new[code] = max(best, size[code]) if may_stay else best
            if np.array_equal(new, size):
                break           # no growth any more (e.g. only identity-like productions)
            size = new
            if np.isinf(size[word_idx]).any():
                break           # the answer is "more than any float"; stop early
    total = float(np.sum(size[word_idx])) if len(word) else 0.0
    return math.inf if math.isinf(total) else int(total)


def _too_large(predicted, limit: int, what: str, exact: bool) -> DerivationTooLarge:
    kind = "exactly" if exact else "up to"
    pred_txt = f"{predicted:,}" if isinstance(predicted, int) else "more than 1.8e308"
    exc = DerivationTooLarge(
        f"{what} would produce {kind} {pred_txt} modules, above the limit "
        f"max_modules={limit:,}; use fewer generations or raise max_modules")
    exc.predicted = predicted
    exc.limit = limit
    return exc


def _as_rows(value, n: int) -> np.ndarray:
    v = np.asarray(value)
    return np.full(n, v) if v.ndim == 0 else v


class _Rewriter:
    """One parallel rewriting step for a fixed set of productions (built once)."""

    def __init__(self, grammar: Grammar, productions: tuple[Production, ...], k: int) -> None:
        self.productions = productions
        self.k = k
        succ_words = [s.word for p in productions for s in p.successors]
        self.lengths = np.array([len(w) for w in succ_words], np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)[:-1]]).astype(np.int64)
        self.t_codes = (np.concatenate([w.codes for w in succ_words]).astype(np.int16)
                        if succ_words else np.zeros(0, np.int16))
        self.t_nargs = (np.concatenate([w.nargs for w in succ_words])
                        if succ_words else np.zeros(0, np.uint8))
        self.t_const = (np.concatenate([w.const_params(k) for w in succ_words])
                        if succ_words else np.zeros((0, k)))
        self.t_gen = (np.concatenate([w.generation_mask(k) for w in succ_words])
                      if succ_words else np.zeros((0, k), bool))
        self.first_sid = []
        self.by_code: dict[int, list[int]] = {}
        sid0 = 0
        for pi, p in enumerate(productions):
            self.by_code.setdefault(grammar.alphabet.index(p.predecessor), []).append(pi)
            self.first_sid.append(sid0)
            sid0 += len(p.successors)

    @staticmethod
    def _env(p: Production, params: np.ndarray, rows: np.ndarray, gen: int) -> dict:
        env = {name: params[rows, j] for j, name in enumerate(p.formals or ())}
        env[GENERATION_TOKEN] = float(gen)
        return env

    @staticmethod
    def _evaluate(expr: Expression, env: dict, rows: np.ndarray, gen: int) -> np.ndarray:
        try:
            return _as_rows(expr.evaluate(env), rows.size)
        except ExpressionError as exc:
            module = f", module {int(rows[exc.index])} of the word" \
                if exc.index is not None else ""
            raise ExpressionError(f"{exc.reason} (generation {gen}{module})", text=exc.text,
                                  subexpression=exc.subexpression, values=exc.values,
                                  source=exc.source) from None

    def choose(self, codes, nargs, params, gen: int, rng) -> tuple[np.ndarray, list]:
        """Successor id of every module (-1: copied) and, per production, its modules."""
        sid = np.full(len(codes), -1, np.int64)
        chosen: list = [None] * len(self.productions)
        for c, plist in self.by_code.items():
            idx = np.flatnonzero(codes == c)
            for pi in plist:
                if not idx.size:
                    break
                p = self.productions[pi]
                ok = np.ones(idx.size, bool)
                if p.formals is not None:
                    ok &= nargs[idx] == len(p.formals)
                if p.condition is not None and ok.any():
                    rows = idx[ok]
                    val = self._evaluate(p.condition, self._env(p, params, rows, gen), rows,
                                         gen)
                    ok[ok] = val if val.dtype == bool else val != 0
                if ok.any():
                    chosen[pi] = idx[ok]
                    sid[idx[ok]] = self.first_sid[pi]
                    idx = idx[~ok]
        picks: list = [None] * len(self.productions)
        for pi, p in enumerate(self.productions):      # grammar order: fixed RNG use
            if p.stochastic and chosen[pi] is not None:
                where = chosen[pi]
                pick = np.searchsorted(p.cumulative, rng.random(where.size), side="right")
                pick = np.minimum(pick, len(p.successors) - 1)
                sid[where] += pick
                picks[pi] = pick
        return sid, [(pi, chosen[pi], picks[pi]) for pi in range(len(self.productions))
                     if chosen[pi] is not None]

    def step(self, codes, nargs, params, gen: int, rng, max_modules: int, what: str):
        """Rewrite every module once; returns the new (codes, nargs, params)."""
        n = len(codes)
        sid, claimed = self.choose(codes, nargs, params, gen, rng)
        rewritten = sid >= 0
        out_len = np.where(rewritten, self.lengths[np.maximum(sid, 0)]
                           if len(self.lengths) else 1, 1)
        total = int(out_len.sum())
        if total > max_modules:
            raise _too_large(total, max_modules, what, exact=True)
        owner = np.repeat(np.arange(n, dtype=np.int64), out_len)
        start = np.cumsum(out_len) - out_len
        local = np.arange(total, dtype=np.int64) - start[owner]
        from_table = rewritten[owner]
        src = (self.offsets[np.maximum(sid, 0)[owner]] + local if len(self.offsets)
               else local)
        new_codes = codes[owner]
        new_nargs = nargs[owner]
        new_params = params[owner]
        ti = src[from_table]
        new_codes[from_table] = self.t_codes[ti]
        new_nargs[from_table] = self.t_nargs[ti]
        p_tab = self.t_const[ti]
        p_tab[self.t_gen[ti]] = gen      # 'n' = the generation writing the module
        new_params[from_table] = p_tab
        # Computed parameters: one vectorised evaluation per successor slot.
        for pi, rows_all, pick in claimed:
            p = self.productions[pi]
            for a, succ in enumerate(p.successors):
                slots = succ.word.expression_slots
                if not slots:
                    continue
                rows = rows_all if pick is None else rows_all[pick == a]
                if not rows.size:
                    continue
                env = self._env(p, params, rows, gen)
                base = start[rows]
                for i, j, expr in slots:
                    new_params[base + i, j] = self._evaluate(expr, env, rows, gen)
        return new_codes, new_nargs, new_params


def _start(grammar: Grammar, axiom: ModuleString | None):
    word = axiom if axiom is not None else grammar.axiom_string()
    if axiom is not None and axiom.alphabet != grammar.alphabet:
        raise ConfigError("the axiom's alphabet differs from the grammar's", key="axiom",
                          value="".join(axiom.alphabet))
    k = max(grammar.width, word.params.shape[1])
    return (word.codes.astype(np.int16), word.nargs.astype(np.uint8),
            _pad(word.params.astype(np.float64), k), k)


def derive(grammar: Grammar, generations: int | None = None,
           rng: np.random.Generator | None = None, *,
           max_modules: int = DEFAULT_MAX_MODULES,
           axiom: ModuleString | None = None) -> ModuleString:
    """Rewrite the axiom ``generations`` times.

    Parameters
    ----------
    grammar : from :func:`~simlidar_mi.lsystem.grammar_parse.parse_grammar`.
    generations : number of rewrites; default the grammar's ``derivation length``.
    rng : required when the grammar is stochastic.
    max_modules : refuse (before allocating) when :func:`predict_size` exceeds it.
    axiom : start from this word instead of the grammar's axiom (same alphabet).

    Returns
    -------
    ModuleString
        The derived word. A module written in generation ``g`` (1-based) has
        ``n`` replaced by ``g``. Interpretation productions are not applied
        (see :func:`apply_interpretation`).

    Raises
    ------
    DerivationTooLarge
        predicted size above ``max_modules``; the message gives both.
    ConfigError
        bad ``generations`` or ``max_modules``, or a stochastic grammar without ``rng``.
    ExpressionError
        a condition or successor parameter cannot be evaluated (names the production).
    """
    g_total = _check_generations(generations, grammar)
    max_modules = _check_max_modules(max_modules)
    if grammar.stochastic and g_total > 0 and rng is None:
        raise ConfigError("a stochastic grammar needs a numpy.random.Generator",
                          key="rng", value=None)
    codes, nargs, params, k = _start(grammar, axiom)

    predicted = predict_size(grammar, g_total, axiom)
    if predicted > max_modules:
        exact = not grammar.stochastic and not any(p.parametric for p in grammar.productions)
        raise _too_large(predicted, max_modules, f"deriving {g_total} generations", exact)

    rewriter = _Rewriter(grammar, grammar.productions, k)
    for gen in range(1, g_total + 1):
        codes, nargs, params = rewriter.step(codes, nargs, params, gen, rng, max_modules,
                                             f"generation {gen}")
    return ModuleString(grammar.alphabet, codes, nargs, params)


def apply_interpretation(grammar: Grammar, word: ModuleString,
                         rng: np.random.Generator | None = None, *, generation: int = 0,
                         max_modules: int = DEFAULT_MAX_MODULES) -> ModuleString:
    """Apply the grammar's ``interpretation:`` productions once (ABOP's homomorphism).

    Parameters
    ----------
    grammar : the grammar whose interpretation productions are used.
    word : a derived word (same alphabet).
    rng : required when an interpretation production is stochastic.
    generation : the value of ``n`` in the interpretation productions (pass the
        number of generations derived).
    max_modules : refuse a result longer than this.

    Returns
    -------
    ModuleString
        ``word`` itself when the grammar has no interpretation productions.
    """
    if not grammar.interpretation:
        return word
    max_modules = _check_max_modules(max_modules)
    if any(p.stochastic for p in grammar.interpretation) and rng is None:
        raise ConfigError("stochastic interpretation productions need a "
                          "numpy.random.Generator", key="rng", value=None)
    codes, nargs, params, k = _start(grammar, word)
    rewriter = _Rewriter(grammar, grammar.interpretation, k)
    codes, nargs, params = rewriter.step(codes, nargs, params, int(generation), rng,
                                         max_modules, "the interpretation productions")
    return ModuleString(grammar.alphabet, codes, nargs, params)
