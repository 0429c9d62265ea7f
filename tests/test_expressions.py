"""Parametric L-system expressions: grammar, precedence, safety, vectorised evaluation."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from simlidar_mi.errors import GrammarError, SimlidarError
from simlidar_mi.lsystem.expr_compile import ExpressionError
from simlidar_mi.lsystem.expressions import (argument_spans, parse_arguments, parse_expression,
                                             split_arguments)


def ev(text: str, **env):
    return parse_expression(text).evaluate(env)


# --- precedence and associativity ------------------------------------------------

@pytest.mark.parametrize("text, value", [
    ("2^3^2", 512.0),            # right-associative power
    ("(2^3)^2", 64.0),
    ("-2^2", -4.0),              # power binds tighter than unary minus (Python, L-Py)
    ("(-2)^2", 4.0),
    ("2^-1", 0.5),               # signed exponent
    ("2**3", 8.0),               # Python spelling of power
    ("-2^-2", -0.25),
    ("1 + 2 * 3", 7.0),
    ("(1 + 2) * 3", 9.0),
    ("10 - 4 - 3", 3.0),         # left-associative
    ("2 / 4 / 2", 0.25),
    ("8 / 2 * 4", 16.0),
    ("--3", 3.0),
    ("+-+3", -3.0),
    ("2 * -3", -6.0),
    ("1e3 + .5 + 2. + 1.5E-1", 1002.65),
])
def test_arithmetic_precedence(text, value):
    assert ev(text) == pytest.approx(value, rel=1e-15)


def test_tree_shows_grouping():
    assert parse_expression("a + b * c").tree == ("+", "a", ("*", "b", "c"))
    assert parse_expression("a - b - c").tree == ("-", ("-", "a", "b"), "c")
    assert parse_expression("a ^ b ^ c").tree == ("^", "a", ("^", "b", "c"))
    assert parse_expression("-a ^ b").tree == ("neg", ("^", "a", "b"))
    assert parse_expression("!a > b").tree == ("!", (">", "a", "b"))
    assert parse_expression("a || b && c").tree == ("||", "a", ("&&", "b", "c"))
    assert parse_expression("not a and b").tree == ("&&", ("!", "a"), "b")


@pytest.mark.parametrize("text, env, value", [
    ("l > 0.1 && w <= 2", dict(l=0.5, w=2), True),
    ("l > 0.1 && w <= 2", dict(l=0.05, w=2), False),
    ("l > 0.1 and w <= 2", dict(l=0.5, w=3), False),
    ("a == 1 || b != 2", dict(a=0, b=2), False),
    ("a == 1 or b != 2", dict(a=1, b=2), True),
    ("!(a < b)", dict(a=1, b=2), False),
    ("not a >= b", dict(a=1, b=2), True),
    ("!a", dict(a=0), True),            # any non-zero number is true
    ("a && b", dict(a=2, b=-1), True),
    ("(a > 1) + (b > 1)", dict(a=2, b=3), 2.0),   # booleans count 0/1 in arithmetic
    ("x + 1 < 2 * x", dict(x=3), True),
])
def test_comparisons_and_logic(text, env, value):
    got = ev(text, **env)
    assert got == value and type(got) is type(value)


def test_short_circuit_avoids_errors():
    assert ev("x != 0 && 1/x > 2", x=0) is False
    assert ev("x == 0 || 1/x > 2", x=0) is True


@pytest.mark.parametrize("text, value", [
    ("sin(pi/6)", 0.5), ("cos(0)", 1.0), ("tan(pi/4)", 1.0),
    ("asin(1)", math.pi / 2), ("acos(1)", 0.0), ("atan(1)", math.pi / 4),
    ("atan2(1, -1)", 3 * math.pi / 4), ("sqrt(16)", 4.0), ("exp(1)", math.e),
    ("log(exp(2))", 2.0), ("abs(-3)", 3.0), ("min(3, 1, 2)", 1.0), ("max(3, 1, 2)", 3.0),
    ("floor(-1.5)", -2.0), ("ceil(-1.5)", -1.0), ("max(1, min(5, 2^2))", 4.0),
    ("sin(30 * pi / 180)", 0.5),        # functions take radians
])
def test_functions(text, value):
    assert ev(text) == pytest.approx(value, abs=1e-15)


def test_names_constants_and_pi():
    e = parse_expression("l*r1 + w*wr", {"l", "w"}, constants={"r1": 0.9, "wr": 0.707})
    assert e.names == frozenset({"l", "w"})
    assert e.tree == ("+", ("*", "l", 0.9), ("*", "w", 0.707))
    assert e.evaluate({"l": 1.0, "w": 10.0}) == pytest.approx(0.9 + 7.07)
    assert parse_expression("2*pi").is_constant
    assert parse_expression("pi").evaluate() == math.pi
    # a declared name shadows pi and function names
    assert parse_expression("pi + min", {"pi", "min"}).evaluate({"pi": 1, "min": 2}) == 3.0
    assert parse_expression("a > 1").is_boolean and not parse_expression("a + 1").is_boolean


def test_split_and_parse_arguments():
    assert split_arguments("l*r1, w*wr") == ["l*r1", "w*wr"]
    assert split_arguments("  min(a, b) ,c*(d+1)") == ["min(a, b)", "c*(d+1)"]
    assert split_arguments("   ") == []
    assert split_arguments("atan2(y, x)") == ["atan2(y, x)"]
    prod = "A(l*r1, w*wr)"
    spans = argument_spans(prod, start=2, end=len(prod) - 1)
    assert [prod[a:b] for a, b in spans] == ["l*r1", "w*wr"]
    exprs = parse_arguments(prod, {"l", "w"}, constants={"r1": 0.5, "wr": 2}, start=2,
                            end=len(prod) - 1)
    assert [e.evaluate({"l": 4, "w": 3}) for e in exprs] == [2.0, 6.0]
    # positions of errors index into the whole production string
    with pytest.raises(GrammarError) as exc:
        parse_arguments(prod.replace("wr", "wq"), {"l", "w", "r1", "wr"}, start=2,
                        end=len(prod) - 1)
    assert exc.value.position == 10


@pytest.mark.parametrize("text, position", [
    ("a,,b", 2), ("a, b,", 5), ("(a, b", 0), ("a), b", 1),
])
def test_split_arguments_errors(text, position):
    with pytest.raises(GrammarError) as exc:
        split_arguments(text)
    assert exc.value.position == position


# --- vectorised evaluation --------------------------------------------------------

VECTOR_CASES = [
    "l*r1 + w^2 / (1 + abs(w))",
    "l > 0.1 && w <= 2 || sin(l)^2 > 0.5",
    "!(l < w) && max(l, w, 0.3) >= 0.5",
    "x != 0 && 1/x > 2",
    "x == 0 || log(abs(x)) < -1",
    "floor(4*l) - ceil(3*w) + atan2(l, w)",
    "-l^2 + (l > w) * 3",
    "min(l, 2) == l",
    "2*pi",                              # constant: broadcast to the array shape
]


@pytest.mark.parametrize("text", VECTOR_CASES)
def test_vectorised_equals_scalar(text):
    rng = np.random.default_rng(3)
    n = 500
    env = {"l": rng.uniform(0, 1, n), "w": rng.uniform(0, 3, n),
           "x": rng.choice([0.0, 0.05, -0.2, 0.3, 1.0], n), "r1": 0.9}
    e = parse_expression(text, {"l", "w", "x", "r1"})
    got = e.evaluate(env)
    want = [e.evaluate({k: (v[i] if isinstance(v, np.ndarray) else v)
                        for k, v in env.items()}) for i in range(n)]
    assert got.shape == (n,)
    assert got.dtype == (bool if isinstance(want[0], bool) else np.float64)
    if got.dtype == bool:
        np.testing.assert_array_equal(got, np.array(want))
    else:   # numpy's and libm's sin/atan2 may differ in the last bit
        np.testing.assert_allclose(got, np.array(want), rtol=1e-14, atol=1e-15)


def test_vectorised_broadcasting_and_lists():
    e = parse_expression("a * b")
    out = e.evaluate({"a": np.arange(3.0)[:, None], "b": [1.0, 10.0]})
    np.testing.assert_array_equal(out, [[0, 0], [1, 10], [2, 20]])
    assert e.evaluate({"a": np.zeros(0), "b": 1.0}).shape == (0,)


def test_many_modules_one_production():
    e = parse_expression("l*r1", {"l"}, constants={"r1": 0.9})
    lengths = np.linspace(0.1, 1, 100_000)
    np.testing.assert_allclose(e.evaluate({"l": lengths}), 0.9 * lengths, rtol=0, atol=0)


# --- parse errors carry a position ---------------------------------------------------

@pytest.mark.parametrize("text, names, position, words", [
    ("a.b", None, 1, "attribute"),
    ("l.__class__", None, 1, "attribute"),
    ("(a).real", None, 3, "attribute"),
    ("1.5.real", None, 3, "attribute"),
    ("x[0]", None, 1, "indexing"),
    ("__import__('os')", None, 0, "'__'"),
    ("a + __x", None, 4, "'__'"),
    ("'abc'", None, 0, "string"),
    ('x + "1"', None, 4, "string"),
    ("(a + b", None, 0, "unclosed"),
    ("sin(a + (b)", None, 3, "unclosed"),
    ("a + b)", None, 5, "unmatched"),
    ("a b", None, 2, "after a complete expression"),
    ("1 2", None, 2, "after a complete expression"),
    ("a + 1)*2", None, 5, "unmatched"),
    ("a, b", None, 1, "','"),
    ("", None, 0, "empty"),
    ("  ", None, 0, "empty"),
    ("a +", None, 3, "ends early"),
    ("* a", None, 0, "unexpected '*'"),
    ("()", None, 1, "unexpected ')'"),
    ("l + q", {"l"}, 4, "unknown name 'q'"),
    ("foo(1)", None, 0, "unknown function"),
    ("eval(1)", None, 0, "unknown function"),
    ("sin + 1", None, 0, "must be called"),
    ("atan2(1)", None, 0, "takes 2"),
    ("sin(1, 2)", None, 0, "takes 1"),
    ("max(1)", None, 0, "at least 2"),
    ("a < b < c", None, 6, "chained"),
    ("a = 1", None, 2, "'=='"),
    ("a & b", None, 2, "'&&'"),
    ("a | b", None, 2, "'||'"),
    ("a % 2", None, 2, "unexpected character"),
    ("1e", None, 0, "malformed number"),
    ("2x", None, 0, "malformed number"),
    ("sin(1 2)", None, 6, "expected ',' or ')'"),
    ("(1 2)", None, 3, "expected ')'"),
    ("lambda: 1", None, 6, "unexpected character"),
])
def test_parse_errors_have_positions(text, names, position, words):
    with pytest.raises(GrammarError) as exc:
        parse_expression(text, names, source="tree.lsys:3")
    err = exc.value
    assert err.position == position, str(err)
    assert words in str(err)
    assert "tree.lsys:3" in str(err)
    assert isinstance(err, SimlidarError)


def test_nesting_limits_are_errors_not_crashes():
    with pytest.raises(GrammarError, match="nested"):
        parse_expression("(" * 500 + "1" + ")" * 500)
    with pytest.raises(GrammarError, match="nested"):
        parse_expression("-" * 500 + "1")
    with pytest.raises(GrammarError, match="nested operations"):
        parse_expression("+".join(["a"] * 1000))
    assert parse_expression("(" * 20 + "1" + ")" * 20).evaluate() == 1.0


def test_not_a_string():
    with pytest.raises(GrammarError):
        parse_expression(3)  # type: ignore[arg-type]


# --- evaluation errors -------------------------------------------------------------

@pytest.mark.parametrize("text, env, words", [
    ("l / w", dict(l=1, w=0), "division by zero in 'w'"),
    ("l / (w - 1)", dict(l=1, w=1), "division by zero in '(w - 1)'"),
    ("sqrt(x)", dict(x=-1), "domain of sqrt"),
    ("log(x)", dict(x=0), "domain of log"),
    ("asin(x)", dict(x=2), "domain of asin"),
    ("exp(x)", dict(x=1000), "overflow in exp"),
    ("x ^ 0.5", dict(x=-2), "non-integer power"),
    ("x ^ -1", dict(x=0), "negative power"),
    ("x * 1e308", dict(x=10), "non-finite"),
    ("10 ^ x", dict(x=400), "overflow"),
    ("l + 1", dict(l=float("nan")), "not finite"),
    ("l + 1", dict(l="a"), "not a number"),
    ("l + w", dict(l=1), "no value given for 'w'"),
])
def test_scalar_evaluation_errors(text, env, words):
    e = parse_expression(text, source="p1")
    with pytest.raises(ExpressionError) as exc:
        e.evaluate(env)
    msg = str(exc.value)
    assert words in msg and text in msg and "p1" in msg
    assert isinstance(exc.value, SimlidarError)


@pytest.mark.parametrize("text, words", [
    ("l / (w - 1)", "division by zero"),
    ("sqrt(w - 2)", "non-finite"),
    ("log(w - 1)", "non-finite"),
    ("exp(l * 300 / w)", "non-finite"),
])
def test_vector_evaluation_errors_name_the_element(text, words):
    l = np.array([1.0, 2.0, 3.0, 4.0])
    w = np.array([5.0, 3.0, 1.0, 0.5])
    e = parse_expression(text)
    with pytest.raises(ExpressionError) as exc:
        e.evaluate({"l": l, "w": w})
    err = exc.value
    assert words in str(err)
    # the values of the expression's own parameters at the failing element
    assert err.index == 2
    assert err.values == {k: v for k, v in {"l": 3.0, "w": 1.0}.items() if k in e.names}
    assert "at element 2" in str(err) and "w=1.0" in str(err)


def test_vector_error_index_survives_short_circuit_subsets():
    x = np.array([0.0, 5.0, 0.0, 1.0])
    y = np.array([1.0, 1.0, 1.0, 0.0])
    with pytest.raises(ExpressionError) as exc:
        parse_expression("x != 0 && x / y > 1").evaluate({"x": x, "y": y})
    assert exc.value.index == 3 and exc.value.values == {"x": 1.0, "y": 0.0}


def test_constant_errors_surface_at_evaluation():
    e = parse_expression("1/0 + a")       # not folded away, not a parse error
    with pytest.raises(ExpressionError, match="division by zero"):
        e.evaluate({"a": 1})
    with pytest.raises(ExpressionError, match="division by zero"):
        e.evaluate({"a": np.ones(3)})


def test_pickle_round_trip():
    e = parse_expression("l*r1 > w", {"l", "w"}, source="x", constants={"r1": 2})
    e2 = pickle.loads(pickle.dumps(e))
    assert e2.text == e.text and e2.names == e.names and e2.source == "x"
    assert e2.evaluate({"l": 1, "w": 1.5}) is True


# --- input too large for float64 or for the parser ------------------------------------

@pytest.mark.parametrize("text", ["1" + "0" * 400, "1e400", "2 * 1.5e309"])
def test_numbers_beyond_float64_are_refused(text):
    """'1' and 400 zeros used to parse as inf and evaluate to inf."""
    with pytest.raises(GrammarError, match="too large") as exc:
        parse_expression(text)
    assert exc.value.position == text.index("1")


def test_overflowing_arithmetic_raises_at_evaluation():
    e = parse_expression("x * 1e308", {"x"})
    assert e.evaluate({"x": 1.0}) == 1e308
    with pytest.raises(ExpressionError, match="non-finite"):
        e.evaluate({"x": 10.0})


def test_huge_expressions_are_refused_before_parsing(monkeypatch):
    """A 500 k-term sum took 88 s to reach the operation limit; now its length decides."""
    import simlidar_mi.lsystem.expr_parser as parser_mod
    from simlidar_mi.lsystem.expr_tokens import MAX_CHARS, MAX_TOKENS

    def no_parse(*args, **kwargs):
        raise AssertionError("the parser ran")
    with monkeypatch.context() as m:  # the length check comes before any tokenizing/parsing
        m.setattr(parser_mod._Parser, "or_expr", no_parse)
        with pytest.raises(GrammarError, match=f"1000003 characters long; the limit is {MAX_CHARS}"):
            parse_expression("+".join(["x"] * 500_000) + "+1+1")
    # Within the length limit but over the token limit (x+x+…: 2 tokens per term).
    text = "+".join(["x"] * (MAX_TOKENS // 2 + 1))
    assert len(text) < MAX_CHARS
    with pytest.raises(GrammarError, match=f"more than {MAX_TOKENS} tokens"):
        parse_expression(text)
    # Long but legal expressions still parse: a call with 300 arguments (1201 tokens).
    e = parse_expression("max(" + ", ".join(f"x*{j}" for j in range(300)) + ")", {"x"})
    assert e.evaluate({"x": 2.0}) == 598.0
