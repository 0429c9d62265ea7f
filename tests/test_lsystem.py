"""L-system engine: grammar parsing, derivation, size guard, Table 1 notation, turtle."""
from __future__ import annotations

import numpy as np
import pytest

from simlidar_mi.errors import ConfigError, DerivationTooLarge, GrammarError
from simlidar_mi.lsystem import (DEFAULT_MAX_MODULES, Module, ModuleString, derive,
                                 format_table1, interpret, parse_grammar, parse_modules,
                                 predict_size, prune_descending, turtle_segments)
from simlidar_mi.plants.apple import apple_grammar

# Méndez et al., Table 1, copied character for character.
PAPER_TABLE1_N2 = (
    "[I01I01[t+I01I01+I02I02[t+I02I02+F]I02[T-I02F]I02F]I01[T-I01I02I02[t+I02I02+F]"
    "I02[T-I02F]I02F]I01I02I02[t+I02I02+F]I02[T-I02F]I02F]")
PAPER_TABLE1_N3 = (
    "[I01I01[t+I01I01+I02I02[t+I02I02+I03I03[t+I03I03+F]I03[T-I03F]I03F]I02[T-I02I03I03"
    "[t+I03I03+F]I03[T-I03F]I03F]I02I03I03[t+I03I03+F]I03[T-I03F]I03F]I01[T-I01I02I02"
    "[t+I02I02+I03I03[t+I03I03+F]I03[T-I03F]I03F]I02[T-I02I03I03[t+I03I03+F]I03[T-I03F]"
    "I03F]I02I03I03[t+I03I03+F]I03[T-I03F]I03F]I01I02I02[t+I02I02+I03I03[t+I03I03+F]I03"
    "[T-I03F]I03F]I02[T-I02I03I03[t+I03I03+F]I03[T-I03F]I03F]I02I03I03[t+I03I03+F]I03"
    "[T-I03F]I03F]I02I03I03[t+I03I03+F]I03[T-I03F]I03F]")

DET = "axiom: F\nF -> InIn[r+InIn+F]In[R-InF]InF\n"


def naive_table1(generations: int) -> str:
    """Independent reference: plain string rewriting in Table 1 notation."""
    word = "F"
    for g in range(1, generations + 1):
        i = f"I{g:02d}"
        # str.replace rewrites every F of the old word at once (parallel rewriting)
        word = word.replace("F", f"{i}{i}[t+{i}{i}+F]{i}[T-{i}F]{i}F")
    return f"[{word}]"


# --- Table 1 ----------------------------------------------------------------------
def test_table1_two_generations_exact():
    assert format_table1(derive(apple_grammar(False), 2)) == PAPER_TABLE1_N2


def test_table1_three_generations():
    ours = format_table1(derive(apple_grammar(False), 3))
    assert ours == naive_table1(3)
    # The paper's 3-generation string is a typesetting slip: it writes the last group
    # of ours, "I02I03I03[t+I03I03+F]I03[T-I03F]I03F" plus its closing "]", twice.
    # Its brackets do not even balance (one more "]" than "["), so we test against the
    # correct derivation and check that this is the only difference.
    group = "I02I03I03[t+I03I03+F]I03[T-I03F]I03F]"
    assert ours.endswith(group)
    assert PAPER_TABLE1_N3 == ours + group[:-1] + "]"
    assert PAPER_TABLE1_N3.count("[") == PAPER_TABLE1_N3.count("]") - 1
    assert ours.count("[") == ours.count("]")


@pytest.mark.parametrize("n", [0, 1, 4, 6])
def test_deterministic_matches_naive_rewriting(n):
    assert format_table1(derive(apple_grammar(False), n)) == naive_table1(n)


def test_generation_token_is_the_writing_generation():
    g = parse_grammar("axiom: I(n)A\nalphabet: A I\nA -> InA")
    w = derive(g, 3)
    assert [m.params for m in w] == [(0.0,), (1.0,), (2.0,), (3.0,), ()]
    assert w.to_text() == "I(0)I(1)I(2)I(3)A"


# --- grammar syntax ---------------------------------------------------------------
def test_stochastic_grammar_forms_are_equivalent():
    one_line = parse_grammar("axiom: F\nF -> (0.33) I[+F] | (0.33) I[-F] | (0.34) IF")
    continued = parse_grammar("axiom: F\nproductions:\nF -> (0.33) I[+F]\n | (0.33) I[-F]\n"
                              "   | (0.34) IF")
    repeated = parse_grammar("axiom: F\nF -> (0.33) I[+F]\nF -> (0.33) I[-F]\nF->(.34)IF")
    for g in (one_line, continued, repeated):
        p = g.production_for("F")
        assert [s.probability for s in p.successors] == [0.33, 0.33, 0.34]
        assert [s.word.text for s in p.successors] == ["I[+F]", "I[-F]", "IF"]
        w1 = derive(g, 4, np.random.default_rng(5))
        w2 = derive(one_line, 4, np.random.default_rng(5))
        assert w1.same_as(w2)


def test_fraction_probabilities_and_comments():
    g = parse_grammar("# a comment\naxiom: F   # trailing\nF -> (1/3) F | (1/3) FF | (1/3) FFF")
    assert g.stochastic
    assert sum(s.probability for s in g.production_for("F").successors) == pytest.approx(1)


def test_declared_alphabet_and_parameters():
    g = parse_grammar("alphabet: A B\naxiom: A(1.5,2)\nA -> B(n, -0.25)A")
    w = derive(g, 2)
    # non-parametric predecessor: the successor's A is written without parameters
    assert w.to_text() == "B(1,-0.25)B(2,-0.25)A"
    assert w[0] == Module("B", (1.0, -0.25))


def test_unbalanced_close_bracket_position():
    with pytest.raises(GrammarError) as ei:
        parse_grammar("axiom: F\nF -> I[+F]]F")
    assert ei.value.position == 10
    assert "line 2" in str(ei.value) and "^" in str(ei.value)


def test_unclosed_bracket_position():
    with pytest.raises(GrammarError) as ei:
        parse_grammar("axiom: F\nF -> I[+F[-F]")
    assert ei.value.position == 6     # the outer '[' is the one never closed
    with pytest.raises(GrammarError) as ei:
        parse_grammar("axiom: [F")
    assert ei.value.position == 7


def test_unknown_symbol_position():
    with pytest.raises(GrammarError) as ei:
        parse_grammar("axiom: F\nF -> InIn[r+InXn+F]")
    assert ei.value.position == 14
    assert "'X'" in str(ei.value)
    with pytest.raises(GrammarError) as ei:
        parse_grammar("alphabet: F I\naxiom: F\nF -> I+F")
    assert ei.value.position == 6


def test_probabilities_must_sum_to_one():
    with pytest.raises(GrammarError) as ei:
        parse_grammar("axiom: F\nF -> (0.33) IF | (0.33) IIF | (0.33) IIIF")
    assert "sum to 0.99" in str(ei.value)
    assert ei.value.position == 0
    # within the 1e-6 tolerance
    parse_grammar("axiom: F\nF -> (0.3333333) IF | (0.3333333) IIF | (0.3333334) IIIF")
    with pytest.raises(GrammarError, match="sum to"):
        parse_grammar("axiom: F\nF -> (0.33333) IF | (0.33333) IIF | (0.33333) IIIF")


def test_other_grammar_errors():
    with pytest.raises(GrammarError, match="needs a probability"):
        parse_grammar("axiom: F\nF -> IF\nF -> IIF")
    with pytest.raises(GrammarError, match="no 'axiom:'"):
        parse_grammar("F -> IF")
    # parametric syntax is supported (tests/test_parametric.py); names must be bound
    with pytest.raises(GrammarError, match="unknown name 'l'"):
        parse_grammar("alphabet: A\naxiom: A(1)\nA -> A(l*2)")
    with pytest.raises(GrammarError, match="context-sensitive"):
        parse_grammar("alphabet: A B\naxiom: A(1)\nB < A(l) -> A(1)")
    with pytest.raises(GrammarError, match="must follow a symbol"):
        parse_grammar("axiom: F\nF -> nF")
    with pytest.raises(GrammarError, match="takes no parameters"):
        parse_grammar("axiom: F\nF -> [n]")
    with pytest.raises(GrammarError, match="cannot be rewritten"):
        parse_grammar("axiom: F\n[ -> F")
    with pytest.raises(GrammarError, match="probability"):
        parse_grammar("axiom: F\nF -> (1.5) F")
    with pytest.raises(GrammarError, match="expected"):
        parse_grammar("axiom: F\nthis is not a statement")
    with pytest.raises(GrammarError, match="not allowed"):
        parse_grammar("alphabet: F n\naxiom: F")


def test_module_string_text_round_trip():
    text = "I(1)I(1)[r+I(2)F]I(1)[R-I(2)F]F"
    w = parse_modules(text)
    assert w.to_text() == text and len(w) == 16 and w.count("I") == 5
    with pytest.raises(GrammarError) as ei:
        parse_modules("I(1)]")
    assert ei.value.position == 4


# --- stochastic derivation --------------------------------------------------------
def test_stochastic_same_seed_same_word_and_seeds_differ():
    g = apple_grammar(True)
    a = derive(g, 6, np.random.default_rng(11))
    b = derive(g, 6, np.random.default_rng(11))
    c = derive(g, 6, np.random.default_rng(12))
    assert a.codes.tobytes() == b.codes.tobytes()
    assert a.params.tobytes() == b.params.tobytes()
    assert not a.same_as(c)


def test_stochastic_choice_is_per_module_with_the_given_probabilities():
    # one rewrite of 30 000 F's: each picks its successor on its own
    g = parse_grammar("alphabet: F A B C\naxiom: F\nF -> (0.33) A | (0.33) B | (0.34) C")
    axiom = parse_modules("F" * 30000, g.alphabet)
    w = derive(g, 1, np.random.default_rng(2024), axiom=axiom)
    for sym, p in (("A", 0.33), ("B", 0.33), ("C", 0.34)):
        sd = np.sqrt(p * (1 - p) / 30000)
        assert abs(w.count(sym) / 30000 - p) < 5 * sd


def test_stochastic_needs_a_generator():
    with pytest.raises(ConfigError, match="rng"):
        derive(apple_grammar(True), 3)


# --- size guard -------------------------------------------------------------------
def test_predicted_size_is_exact_for_deterministic():
    g = apple_grammar(False)
    for n in range(7):
        assert predict_size(g, n) == len(derive(g, n)) == 9 * 3 ** n - 8


def test_twenty_generations_refused_with_predicted_size():
    with pytest.raises(DerivationTooLarge) as ei:
        derive(apple_grammar(False), 20)
    msg = str(ei.value)
    assert "31,381,059,601" in msg and "50,000,000" in msg
    assert ei.value.predicted == 9 * 3 ** 20 - 8
    # stochastic: worst case c_{g+1} = 19 + 4 c_g (23-module successors with 4 F)
    with pytest.raises(DerivationTooLarge) as ei:
        derive(apple_grammar(True), 20, np.random.default_rng(0))
    assert f"{(22 * 4 ** 20 - 19) // 3:,}" in str(ei.value)
    assert "up to" in str(ei.value)


def test_seven_stochastic_generations_accepted_and_bounded():
    g = apple_grammar(True)
    bound = predict_size(g, 7)
    assert bound == (22 * 4 ** 7 - 19) // 3 < DEFAULT_MAX_MODULES
    for seed in range(3):
        assert len(derive(g, 7, np.random.default_rng(seed))) <= bound


def test_limit_is_checked_before_deriving():
    g = apple_grammar(False)
    exact = 9 * 3 ** 7 - 8
    assert len(derive(g, 7, max_modules=exact)) == exact
    with pytest.raises(DerivationTooLarge):
        derive(g, 7, max_modules=exact - 1)
    assert predict_size(g, 10 ** 6) == float("inf")   # huge requests stay cheap
    with pytest.raises(DerivationTooLarge, match="1.8e308"):
        derive(g, 10 ** 6)


# --- turtle -----------------------------------------------------------------------
def _rodrigues(v, k, a):
    return v * np.cos(a) + np.cross(k, v) * np.sin(a) + k * np.dot(k, v) * (1 - np.cos(a))


def reference_turtle(word: ModuleString, angle_deg, rotation_deg, h0):
    """Sequential stack turtle written independently of the vectorised one."""
    H, L = np.array([0.0, 0, 1]), np.array([1.0, 0, 0])
    U = np.cross(H, L)
    P = np.zeros(3)
    stack, segs = [], []
    a, r = np.deg2rad(angle_deg), np.deg2rad(rotation_deg)
    for m in word:
        s = m.symbol
        if s == "I":
            Q = P + h0 / 2 ** (m.params[0] - 1) * H
            segs.append((P, Q))
            P = Q
        elif s in "+-":
            t = a if s == "+" else -a
            H, U = _rodrigues(H, L, t), _rodrigues(U, L, t)
        elif s in "TRtr":
            t = r if s in "TR" else -r
            H, L = _rodrigues(H, U, t), _rodrigues(L, U, t)
        elif s == "[":
            stack.append((P, H, L, U))
        elif s == "]":
            P, H, L, U = stack.pop()
    return np.array([p for p, _ in segs]), np.array([q for _, q in segs])


def _segments(text, angle=90.0, rotation=90.0):
    w = parse_modules(text)
    step = np.ones(len(w))
    p0, p1, _ = turtle_segments(w, angle_deg=angle, rotation_deg=rotation, step_m=step)
    return p0, p1


@pytest.mark.parametrize("text, heading", [
    ("I(1)", (0, 0, 1)),            # initial heading +z
    ("+I(1)", (0, -1, 0)),          # + : right-handed about L=+x, H tips toward -U = -y
    ("-I(1)", (0, 1, 0)),
    ("TI(1)", (1, 0, 0)),           # T : right-handed about U=+y, H tips toward +L = +x
    ("RI(1)", (1, 0, 0)),           # R is T
    ("tI(1)", (-1, 0, 0)),
    ("rI(1)", (-1, 0, 0)),
    ("T+I(1)", (0, -1, 0)),         # T turns L to -z; + then tips H toward -U
    ("+TI(1)", (1, 0, 0)),
])
def test_turn_signs(text, heading):
    p0, p1 = _segments(text)
    np.testing.assert_allclose(p1[-1] - p0[-1], heading, atol=1e-12)


def test_push_pop_restores_position_and_frame():
    p0, p1 = _segments("I(1)[+I(1)[TI(1)]I(1)]I(1)")
    np.testing.assert_allclose(p0[4], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(p1[4], [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(p0[3], p1[1], atol=1e-12)        # after the inner ]
    np.testing.assert_allclose(p1[3] - p0[3], [0, -1, 0], atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vectorised_turtle_matches_sequential_reference(seed):
    w = derive(apple_grammar(True), 5, np.random.default_rng(seed))
    br = interpret(w, h0_m=0.4, d_min_m=0.005, n_substitutions=5, angle_deg=20,
                   rotation_deg=35)
    r0, r1 = reference_turtle(w, 20, 35, 0.4)
    np.testing.assert_allclose(br.p0, r0, atol=1e-12)
    np.testing.assert_allclose(br.p1, r1, atol=1e-12)


def test_pruning_removes_descending_segments_with_their_subtrees_or_alone():
    # angle 120 deg: '+' and '-' point a branch 30 deg below the horizon;
    # T with rotation 90 deg makes it exactly horizontal (kept: it does not descend).
    w = parse_modules("I(1)[+I(2)]I(1)[-I(2)[+I(3)]][TI(2)]I(1)")
    full = interpret(w, h0_m=1.0, d_min_m=0.01, n_substitutions=3, angle_deg=120,
                     rotation_deg=90)
    s, c = np.sin(np.deg2rad(120)), np.cos(np.deg2rad(120))
    expected_p0 = [[0, 0, 0], [0, 0, 1], [0, 0, 1], [0, 0, 2], [0, s / 2, 2 + c / 2],
                   [0, 0, 2], [0, 0, 2]]
    expected_p1 = [[0, 0, 1], [0, -s / 2, 1 + c / 2], [0, 0, 2], [0, s / 2, 2 + c / 2],
                   [0, s / 2, 2 + c / 2 + 0.25], [0.5, 0, 2], [0, 0, 3]]
    np.testing.assert_allclose(full.p0, expected_p0, atol=1e-12)
    np.testing.assert_allclose(full.p1, expected_p1, atol=1e-12)
    *_, parent = turtle_segments(w, angle_deg=120, rotation_deg=90,
                                 step_m=np.ones(len(w)), return_parent=True)
    np.testing.assert_array_equal(parent, [-1, 0, 0, 2, 3, 2, 2])
    kw = dict(h0_m=1.0, d_min_m=0.01, n_substitutions=3, angle_deg=120, rotation_deg=90,
              prune=True)
    # default "subtree": segments 1 and 3 descend; 4 grows from 3 and goes with it
    pruned = interpret(w, **kw)
    np.testing.assert_array_equal(pruned.p0, full.p0[[0, 2, 5, 6]])
    np.testing.assert_array_equal(pruned.order, [1, 1, 2, 1])
    # "segment": only 1 and 3 go; 4 climbs and is kept, starting in mid-air
    seg = interpret(w, **kw, prune_mode="segment")
    np.testing.assert_array_equal(seg.p0, full.p0[[0, 2, 4, 5, 6]])
    np.testing.assert_array_equal(seg.order, [1, 1, 3, 2, 1])
    assert len(prune_descending(seg, mode="segment")) == len(seg)
    np.testing.assert_array_equal(prune_descending(full, parent).p0, pruned.p0)
    with pytest.raises(ConfigError, match="parent"):
        prune_descending(full)                      # subtree needs the parents
    with pytest.raises(ConfigError, match="parent"):
        prune_descending(full, [-1, 0, 0, 2, 3, 2, 7])   # 7 is not an earlier row
    with pytest.raises(ConfigError, match="prune_mode"):
        interpret(w, **kw, prune_mode="branch")


def test_interpret_needs_orders():
    with pytest.raises(GrammarError, match="axis order"):
        interpret(parse_modules("I(1)I"), h0_m=1, d_min_m=0.01, n_substitutions=1)
    with pytest.raises(GrammarError, match=">= 1"):
        interpret(parse_modules("I(0)"), h0_m=1, d_min_m=0.01, n_substitutions=1)
    with pytest.raises(ConfigError, match="h0_m"):
        interpret(parse_modules("I(1)"), h0_m=0, d_min_m=0.01, n_substitutions=1)


def test_a_word_without_internodes_draws_nothing():
    # no I module at all: an empty tree, not an IndexError from the empty parameter table
    for word in ("F[+F]", "[F]-F", ""):
        for prune in (False, True):
            br = interpret(parse_modules(word), h0_m=0.4, d_min_m=0.005, n_substitutions=2,
                           prune=prune)
            assert len(br) == 0
    assert len(interpret(parse_modules("I(1)F"), h0_m=0.4, d_min_m=0.005, n_substitutions=2)) == 1
