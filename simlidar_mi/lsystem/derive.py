"""Parallel rewriting of module strings, with a size guard.

One generation rewrites every module at once (the L-system rule), fully
vectorised: each module gets a successor id (``-1`` = copied unchanged), the
output lengths are summed, and the new arrays are gathered from a table of
all successors in one pass. The cost is linear in the output size; there is
no string concatenation.

Stochastic productions draw one uniform number per rewritten module from the
``numpy.random.Generator`` passed in, in string order, production by
production (in grammar order), generation by generation. The same generator
state therefore gives the same word, bit for bit.

Before allocating anything, :func:`predict_size` bounds the final length by
counting per-symbol growth (the longest successor choice, so an upper bound
for stochastic grammars and the exact length for deterministic ones), and
:func:`derive` refuses with :class:`~simlidar_mi.errors.DerivationTooLarge`
when it exceeds ``max_modules``.
"""
from __future__ import annotations

import math
import operator

import numpy as np

from ..errors import ConfigError, DerivationTooLarge
from .grammar import Grammar
from .modules import ModuleString, _pad

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


def predict_size(grammar: Grammar, generations: int | None = None,
                 axiom: ModuleString | None = None) -> int | float:
    """Upper bound of the number of modules after ``generations`` rewrites.

    ``c_0(s) = 1`` for every symbol; ``c_{g+1}(s)`` is the largest, over the
    successors of ``s``, of the summed ``c_g`` of their modules (``c_g(s) = 1``
    for symbols without a production). The bound is the sum of ``c_N`` over the
    axiom; it is exact for deterministic grammars.

    Returns
    -------
    int, or ``math.inf`` when the bound exceeds the float range.
    """
    g = _check_generations(generations, grammar)
    word = axiom.codes if axiom is not None else grammar.axiom.codes
    n_sym = len(grammar.alphabet)
    # Per successor: how many of each symbol it writes (sparse, symbols present only).
    table = []
    for p in grammar.productions:
        succ = []
        for s in p.successors:
            u, c = np.unique(s.word.codes, return_counts=True)
            succ.append((u.astype(np.intp), c.astype(np.float64)))
        table.append((grammar.alphabet.index(p.predecessor), succ))
    # Floats: exact below 2**53 (far above any sensible limit) and no slow bignums.
    word_idx = np.asarray(word, np.intp)
    size = np.ones(n_sym)
    with np.errstate(over="ignore"):        # overflow to inf is the answer "too many"
        for _ in range(g):
            new = size.copy()
            for code, succ in table:
                new[code] = max(float(np.dot(c, size[u])) for u, c in succ)
            if np.array_equal(new, size):
                break           # no growth any more (e.g. only identity-like productions)
            size = new
            if np.isinf(size[word_idx]).any():
                break           # the answer is "more than any float"; stop early
    total = float(np.sum(size[word_idx])) if len(word) else 0.0
    return math.inf if math.isinf(total) else int(total)


def derive(grammar: Grammar, generations: int | None = None,
           rng: np.random.Generator | None = None, *,
           max_modules: int = DEFAULT_MAX_MODULES,
           axiom: ModuleString | None = None) -> ModuleString:
    """Rewrite the axiom ``generations`` times.

    Parameters
    ----------
    grammar : from :func:`~simlidar_mi.lsystem.grammar.parse_grammar`.
    generations : number of rewrites; default the grammar's ``derivation length``.
    rng : required when the grammar is stochastic.
    max_modules : refuse (before allocating) when :func:`predict_size` exceeds it.
    axiom : start from this word instead of the grammar's axiom (same alphabet).

    Returns
    -------
    ModuleString
        The derived word. A module written in generation ``g`` (1-based) has
        ``n`` replaced by ``g``.

    Raises
    ------
    DerivationTooLarge
        predicted size above ``max_modules``; the message gives both.
    ConfigError
        bad ``generations`` or ``max_modules``, or a stochastic grammar without ``rng``.
    """
    g_total = _check_generations(generations, grammar)
    if isinstance(max_modules, bool) or not isinstance(max_modules, (int, np.integer)) \
            or max_modules < 1:
        raise ConfigError("must be a whole number >= 1", key="max_modules", value=max_modules)
    if grammar.stochastic and g_total > 0 and rng is None:
        raise ConfigError("a stochastic grammar needs a numpy.random.Generator",
                          key="rng", value=None)
    if axiom is not None and axiom.alphabet != grammar.alphabet:
        raise ConfigError("the axiom's alphabet differs from the grammar's", key="axiom",
                          value="".join(axiom.alphabet))

    predicted = predict_size(grammar, g_total, axiom)
    if predicted > max_modules:
        kind = "up to" if grammar.stochastic else "exactly"
        pred_txt = f"{predicted:,}" if isinstance(predicted, int) else "more than 1.8e308"
        exc = DerivationTooLarge(
            f"deriving {g_total} generations would produce {kind} {pred_txt} modules, "
            f"above the limit max_modules={max_modules:,}; use fewer generations or raise "
            f"max_modules")
        exc.predicted = predicted
        exc.limit = max_modules
        raise exc

    word = axiom if axiom is not None else grammar.axiom_string()
    k = grammar.width if axiom is None else max(grammar.width, word.params.shape[1])
    codes = word.codes.astype(np.int16)
    nargs = word.nargs.astype(np.uint8)
    params = _pad(word.params.astype(np.float64), k)

    # One table holding every successor of every production, built once.
    succ_words = [s.word for p in grammar.productions for s in p.successors]
    lengths = np.array([len(w) for w in succ_words], np.int64)
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    t_codes = (np.concatenate([w.codes for w in succ_words]).astype(np.int16)
               if succ_words else np.zeros(0, np.int16))
    t_nargs = (np.concatenate([w.nargs for w in succ_words])
               if succ_words else np.zeros(0, np.uint8))
    t_const = (np.concatenate([w.const_params(k) for w in succ_words])
               if succ_words else np.zeros((0, k)))
    t_gen = (np.concatenate([w.generation_mask(k) for w in succ_words])
             if succ_words else np.zeros((0, k), bool))
    # symbol code -> (first successor id, production) ; -1 = no production
    first = np.full(len(grammar.alphabet), -1, np.int64)
    prods = {}
    sid0 = 0
    for p in grammar.productions:
        c = grammar.alphabet.index(p.predecessor)
        first[c] = sid0
        prods[c] = p
        sid0 += len(p.successors)

    for gen in range(1, g_total + 1):
        n = len(codes)
        sid = first[codes]
        for c, p in prods.items():
            if not p.stochastic:
                continue
            where = np.flatnonzero(codes == c)
            if where.size:
                pick = np.searchsorted(p.cumulative, rng.random(where.size), side="right")
                sid[where] += np.minimum(pick, len(p.successors) - 1)
        rewritten = sid >= 0
        out_len = np.where(rewritten, lengths[np.maximum(sid, 0)] if len(lengths) else 1, 1)
        total = int(out_len.sum())
        owner = np.repeat(np.arange(n, dtype=np.int64), out_len)
        start = np.cumsum(out_len) - out_len
        local = np.arange(total, dtype=np.int64) - start[owner]
        from_table = rewritten[owner]
        src = offsets[np.maximum(sid, 0)[owner]] + local if len(offsets) else local
        new_codes = codes[owner]
        new_nargs = nargs[owner]
        new_params = params[owner]
        ti = src[from_table]
        new_codes[from_table] = t_codes[ti]
        new_nargs[from_table] = t_nargs[ti]
        p_tab = t_const[ti]
        p_tab[t_gen[ti]] = gen      # 'n' = the generation writing the module
        new_params[from_table] = p_tab
        codes, nargs, params = new_codes, new_nargs, new_params
    return ModuleString(grammar.alphabet, codes, nargs, params)
