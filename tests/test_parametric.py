"""Parametric L-systems (ABOP §1.10) and the ABOP turtle (branches, leaves, tropism)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.errors import (ConfigError, DerivationTooLarge, GrammarError,
                                SimlidarError)
from simlidar_mi.lsystem import (ExpressionError, ModuleString, TurtleConfig,
                                 apply_interpretation, derive, interpret_abop, parse_grammar,
                                 parse_modules, predict_size)
from simlidar_mi.lsystem.abop import INITIAL_FRAME

HONDA = """\
alphabet: A B C F ! & / + - $
define: r1 = 0.9, r2 = 0.6, a0 = 45, a2 = 45
define: d = 137.5, wr = 0.707
axiom: A(1,10)
A(l,w) -> !(w)F(l)[&(a0)B(l*r2,w*wr)]/(d)A(l*r1,w*wr)
B(l,w) -> !(w)F(l)[-(a2)$C(l*r2,w*wr)]C(l*r1,w*wr)
C(l,w) -> !(w)F(l)[+(a2)$B(l*r2,w*wr)]B(l*r1,w*wr)
"""
ABOP_SYMBOLS = tuple("F f + - & ^ \\ / | $ ! L A B".split())


def _params(word: ModuleString, symbol: str) -> np.ndarray:
    return word.params[word.codes == word.code(symbol)]


# --- grammar: constants, formal parameters, conditions ------------------------------
def test_expressions_use_predecessor_parameters_and_constants():
    g = parse_grammar(HONDA)
    assert g.constants == {"r1": 0.9, "r2": 0.6, "a0": 45.0, "a2": 45.0, "d": 137.5,
                           "wr": 0.707}
    w = derive(g, 2)
    # generation 1: !(10)F(1)[&(45)B(0.6,7.07)]/(137.5)A(0.9,7.07); generation 2 rewrites B, A
    r1, r2, wr = 0.9, 0.6, 0.707
    np.testing.assert_allclose(_params(w, "F")[:, 0], [1, r2, r1])
    np.testing.assert_allclose(_params(w, "!")[:, 0], [10, 10 * wr, 10 * wr])
    np.testing.assert_allclose(_params(w, "C")[:, :2], [[r2 * r2, 10 * wr * wr],
                                                      [r2 * r1, 10 * wr * wr]])
    np.testing.assert_allclose(_params(w, "A")[:, :2], [[r1 * r1, 10 * wr * wr]])
    np.testing.assert_allclose(_params(w, "/")[:, 0], [137.5, 137.5])
    assert w.to_text().startswith("!(10)F(1)[&(45)!(")


def test_constants_are_expressions_and_can_be_overridden():
    text = "alphabet: A F\ndefine: a = 2, b = 3*a\ndefine: c = b + pi*0\naxiom: A(b)\n" \
           "A(x) -> F(x*c)A(x)\n"
    g = parse_grammar(text)
    assert g.constants == {"a": 2.0, "b": 6.0, "c": 6.0}
    assert derive(g, 1).to_text() == "F(36)A(6)"
    g2 = parse_grammar(text, constants={"a": 1})       # later definitions see the override
    assert g2.constants == {"a": 1.0, "b": 3.0, "c": 3.0}
    g3 = parse_grammar(text, constants={"b": 10})
    assert derive(g3, 1).to_text() == "F(100)A(10)"
    with pytest.raises(ConfigError, match="no constant 'q'"):
        parse_grammar(text, constants={"q": 1})
    with pytest.raises(ConfigError, match="finite"):
        parse_grammar(text, constants={"a": float("nan")})


@pytest.mark.parametrize("line, words", [
    ("define: n = 1", "reserved"),
    ("define: sin = 1", "reserved"),
    ("define: a = 1, a = 2", "twice"),
    ("define: 1a = 2", "identifier"),
    ("define: a 2", "name = value"),
    ("define: a = b", "unknown name 'b'"),
])
def test_bad_definitions(line, words):
    with pytest.raises(GrammarError, match=words):
        parse_grammar(f"alphabet: A\n{line}\naxiom: A\n")


def test_conditions_select_productions_in_order():
    g = parse_grammar("alphabet: A F\naxiom: A(0)\n"
                      "A(k) : k < 2 -> F(k)A(k+1)\n"
                      "A(k) : k >= 2 && k < 4 -> F(10*k)A(k+1)\n"
                      "A(k) : * -> F(-1)\n")
    assert derive(g, 6).to_text() == "F(0)F(1)F(20)F(30)F(-1)"
    # a module no production accepts is copied unchanged
    g2 = parse_grammar("alphabet: A F\naxiom: A(0)A(5)\nA(k) : k < 3 -> A(k+1)\n")
    assert derive(g2, 5).to_text() == "A(3)A(5)"


def test_arity_and_nonparametric_predecessors():
    g = parse_grammar("alphabet: A B\naxiom: A(1)A(1,2)A\n"
                      "A(x,y) -> B(x+y)\nA(x) -> B(10*x)\n")
    assert derive(g, 1).to_text() == "B(10)B(3)A"
    # without parentheses the predecessor matches any arity and binds nothing
    g2 = parse_grammar("alphabet: A B\naxiom: A(1)A(1,2)A\nA -> B(n)\n")
    assert derive(g2, 1).to_text() == "B(1)B(1)B(1)"


def test_generation_token_in_expressions():
    g = parse_grammar("alphabet: A I\naxiom: A(1)\nA(x) -> I(n)I(n*x+1)A(x*2)\n")
    assert derive(g, 2).to_text() == "I(1)I(2)I(2)I(5)A(4)"


def test_unreachable_and_merged_productions():
    with pytest.raises(GrammarError, match="can never apply") as ei:
        parse_grammar("alphabet: A\naxiom: A(1)\nA(x) -> A(x)\nA(x) : x > 1 -> A(1)\n")
    assert "line 4" in str(ei.value)
    g = parse_grammar("alphabet: A B C\naxiom: A(1)\n"
                      "A(x) : x > 0 -> (0.5) B(x)\nA(x) : x > 0 -> (0.5) C(x)\n")
    assert len(g.productions) == 1 and g.stochastic


def test_stochastic_parametric_choice_is_per_module():
    g = parse_grammar("alphabet: A B C\ndefine: p = 0.25\naxiom: A(2)\n"
                      "A(x) -> (p) B(x) | (1-p) C(x*3)\n")
    axiom = parse_modules("A(2)" * 20000, g.alphabet)
    w = derive(g, 1, np.random.default_rng(5), axiom=axiom)
    frac_b = w.count("B") / len(w)
    assert abs(frac_b - 0.25) < 4 * math.sqrt(0.25 * 0.75 / 20000)
    np.testing.assert_array_equal(_params(w, "C")[:, 0], 6.0)
    assert derive(g, 1, np.random.default_rng(5), axiom=axiom).same_as(w)


def test_bar_is_a_symbol_when_declared():
    g = parse_grammar("alphabet: F | +\naxiom: F\nF -> F|F\n")
    assert derive(g, 1).to_text() == "F|F"
    g = parse_grammar("alphabet: F | +\naxiom: F\nF -> (0.5) F|F | (0.5) +F\n   | (0) FF\n")
    assert [len(s.word) for s in g.production_for("F").successors] == [3, 2, 2]
    # without declaring it, '|' separates alternatives as before
    g = parse_grammar("alphabet: F +\naxiom: F\nF -> (0.5) FF | (0.5) +F\n")
    assert len(g.production_for("F").successors) == 2


def test_interpretation_productions_apply_once_after_derivation():
    g = parse_grammar("alphabet: A F L\naxiom: A(1)\nA(x) -> F(x)A(x+1)\n"
                      "interpretation:\nA(x) : x > 2 -> L(x)L(n)\nF(x) : x < 2 -> F(x)L(0)\n")
    w = derive(g, 3)
    assert w.to_text() == "F(1)F(2)F(3)A(4)"                # not used while deriving
    assert apply_interpretation(g, w, generation=3).to_text() == "F(1)L(0)F(2)F(3)L(4)L(3)"


# --- grammar errors: positions in the grammar text --------------------------------
@pytest.mark.parametrize("succ, column, words", [
    ("A(__import__(1))", 10, "'__'"),
    ("A(l.real)", 11, "attribute"),
    ("A(q*2)", 10, "unknown name 'q'"),
    ("A(l, foo(l))", 13, "unknown function 'foo'"),
    ("A(l*)", 12, "expected a number"),
    ("A('x')", 10, "strings"),
])
def test_expression_errors_have_line_and_column(succ, column, words):
    text = f"alphabet: A\naxiom: A(1)\nA(l) -> {succ}\n"
    with pytest.raises(GrammarError, match=words) as ei:
        parse_grammar(text)
    assert ei.value.position == column
    assert "line 3" in str(ei.value) and "^" in str(ei.value)


def test_condition_and_predecessor_errors_have_positions():
    with pytest.raises(GrammarError, match="unknown name 'x'") as ei:
        parse_grammar("alphabet: A\naxiom: A(1)\nA(l) : x > 1 -> A(l)\n")
    assert ei.value.position == 7
    with pytest.raises(GrammarError, match="formal parameter") as ei:
        parse_grammar("alphabet: A\naxiom: A(1)\nA(l, 2) -> A(l)\n")
    assert ei.value.position == 5
    with pytest.raises(GrammarError, match="twice"):
        parse_grammar("alphabet: A\naxiom: A(1)\nA(l, l) -> A(l)\n")
    with pytest.raises(GrammarError, match="generation"):
        parse_grammar("alphabet: A\naxiom: A(1)\nA(n) -> A(n)\n")
    with pytest.raises(GrammarError, match="empty condition"):
        parse_grammar("alphabet: A\naxiom: A(1)\nA(l) : -> A(l)\n")
    with pytest.raises(GrammarError, match="needs the parameters"):
        parse_grammar("alphabet: A\naxiom: A(n+1)\n").axiom_string()


@pytest.mark.parametrize("axiom, succ, words", [
    ("A(1)", "A(1/(l-1))", "division by zero"),
    ("A(1e300)", "A(l*1e300)", "non-finite"),
    ("A(-1)", "A(sqrt(l))", "non-finite"),
    ("A(0)", "A(l^-1)", "non-finite|zero raised"),
])
def test_evaluation_errors_name_the_production(axiom, succ, words):
    g = parse_grammar(f"alphabet: A\naxiom: {axiom}A(2)\nA(l) -> {succ}\n", "tree.lsys")
    with pytest.raises(ExpressionError, match=words) as ei:
        derive(g, 1)
    msg = str(ei.value)
    assert isinstance(ei.value, SimlidarError)
    assert "tree.lsys line 3" in msg and "production A(l)" in msg
    assert "generation 1" in msg and "module 0" in msg


def test_condition_evaluation_errors_name_the_production():
    g = parse_grammar("alphabet: A\naxiom: A(0)\nA(l) : 1/l > 2 -> A(l)\n")
    with pytest.raises(ExpressionError, match="division by zero") as ei:
        derive(g, 1)
    assert "condition of A(l)" in str(ei.value)


# --- derivation: vectorised result equals a naive one; size guard -----------------
def naive_derive(grammar, word: ModuleString, generations: int) -> list[tuple]:
    """Sequential reference: module by module, scalar evaluation, first match wins."""
    mods = [(m.symbol, m.params) for m in word]
    for gen in range(1, generations + 1):
        out = []
        for sym, params in mods:
            for p in grammar.productions:
                if p.predecessor != sym:
                    continue
                if p.formals is not None and len(p.formals) != len(params):
                    continue
                env = dict(zip(p.formals or (), params), n=float(gen))
                if p.condition is not None and not p.condition.evaluate(env):
                    continue
                word_t = p.successors[0].word
                for code, args in zip(word_t.codes, word_t.args):
                    vals = []
                    for a in args:
                        kind = type(a).__name__
                        vals.append(a.value if kind == "Const" else float(gen)
                                    if kind == "GenerationArg" else a.expression.evaluate(env))
                    out.append((grammar.alphabet[code], tuple(vals)))
                break
            else:
                out.append((sym, params))
        mods = out
    return mods


def test_vectorised_parametric_derivation_matches_naive_reference():
    g = parse_grammar(HONDA.replace("A(l,w) -> ", "A(l,w) : l > 0.6 -> ")
                      + "A(l,w) : l <= 0.6 -> F(l/2)[+(n)B(l,w)]A(l*1.1,w)\n")
    w = derive(g, 7)
    ref = naive_derive(g, g.axiom_string(), 7)
    assert [m.symbol for m in w] == [s for s, _ in ref]
    np.testing.assert_allclose(np.concatenate([m.params for m in w]),
                               np.concatenate([p for _, p in ref]), rtol=1e-15)


def test_size_guard_bounds_parametric_grammars():
    g = parse_grammar(HONDA)
    assert predict_size(g, 10) == len(derive(g, 10))          # every module matches
    cond = parse_grammar(HONDA.replace("A(l,w) -> ", "A(l,w) : l > 0.5 -> "))
    assert predict_size(cond, 10) >= len(derive(cond, 10))
    with pytest.raises(DerivationTooLarge, match="up to"):
        derive(g, 40)
    with pytest.raises(DerivationTooLarge):
        derive(g, 10, max_modules=1000)


# --- ABOP turtle ----------------------------------------------------------------------
def _geo(text: str, **cfg):
    return interpret_abop(parse_modules(text, ABOP_SYMBOLS), TurtleConfig(**cfg))


def _dirs(text: str, **cfg) -> np.ndarray:
    b = _geo(text, **cfg).branches
    return b.p1 - b.p0


@pytest.mark.parametrize("text, heading", [
    ("F(1)", (0, 0, 1)),              # H = +z initially (L = +x, U = +y)
    ("+(90)F(1)", (-1, 0, 0)),        # R_U(a): H' = H cos a - L sin a
    ("-(90)F(1)", (1, 0, 0)),
    ("&(90)F(1)", (0, 1, 0)),         # R_L(a): H' = H cos a + U sin a
    ("^(90)F(1)", (0, -1, 0)),
    ("\\(90)+(90)F(1)", (0, -1, 0)),  # roll left: L' = L cos a + U sin a = +y, then turn
    ("/(90)+(90)F(1)", (0, 1, 0)),    # roll right: L' = -y
    ("\\(90)&(90)F(1)", (-1, 0, 0)),  # U' = U cos a - L sin a = -x
    ("|F(1)", (0, 0, -1)),            # turn around
    ("+F", (-math.sin(math.radians(30)), 0, math.cos(math.radians(30)))),  # default angle
])
def test_roll_and_turn_convention(text, heading):
    np.testing.assert_allclose(_dirs(text, angle_deg=30)[-1], heading, atol=1e-12)


def test_roll_convention_frame_from_a_leaf():
    # after \(90) the frame is H = +z, L = +y, U = -x; a leaf lies along H, normal U
    t = _geo("\\(90)L(1,0.5)").leaf_table
    np.testing.assert_allclose(t.heading[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(t.normal[0], [-1, 0, 0], atol=1e-12)
    t = _geo("/(90)L(1,0.5)").leaf_table
    np.testing.assert_allclose(t.normal[0], [1, 0, 0], atol=1e-12)
    # rolling does not move the heading
    np.testing.assert_allclose(_dirs("\\(37)/(11)F(2)")[0], [0, 0, 2], atol=1e-12)


def test_turn_around_reverses_heading():
    d = _dirs("&(33)+(21)F(1)|F(1)")
    np.testing.assert_allclose(d[1], -d[0], atol=1e-12)


def test_level_makes_left_horizontal():
    rng = np.random.default_rng(0)
    text = "".join(f"{s}({a:.3f})" for s, a in zip(rng.choice(list("+-&^\\/"), 30),
                                                   rng.uniform(-170, 170, 30)))
    t = _geo(text + "$L(1,0.5)").leaf_table
    h, u = t.heading[0], t.normal[0]
    left = np.cross(u, h)                      # H x L = U  =>  L = U x H
    assert abs(left[2]) < 1e-12
    assert u[2] >= 0                           # U = H x L points upward
    np.testing.assert_allclose(h, _geo(text + "L(1,0.5)").leaf_table.heading[0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(left), 1.0, atol=1e-12)


def test_tropism_bends_toward_t():
    e, t = 0.2, np.array([0.0, 0.0, -1.0])
    d = _dirs("&(90)" + "F(1)" * 12, elasticity=e, tropism=tuple(t))
    d /= np.linalg.norm(d, axis=1)[:, None]
    np.testing.assert_allclose(d[0], [0, 1, 0], atol=1e-12)     # drawn before bending
    angle_to_t = np.arccos(np.clip(d @ t, -1, 1))
    assert (np.diff(angle_to_t) < 0).all()                      # always closer to T
    # first bend: rotation by e |H x T| = e (H is perpendicular to T)
    assert angle_to_t[0] - angle_to_t[1] == pytest.approx(e, abs=1e-12)
    # a heading along T is not bent; no tropism without elasticity
    np.testing.assert_allclose(_dirs("|F(1)F(1)", elasticity=e)[1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(_dirs("&(90)F(1)F(1)")[1], [0, 1, 0], atol=1e-12)


def _rot(v, k, a):
    return v * np.cos(a) + np.cross(k, v) * np.sin(a) + k * np.dot(k, v) * (1 - np.cos(a))


def reference_abop(word: ModuleString, cfg: TurtleConfig):
    """Sequential stack turtle, written from the documented vector formulas."""
    h, l, u = (INITIAL_FRAME[:, i].copy() for i in range(3))
    p, w, stack, segs = np.zeros(3), cfg.initial_width, [], []
    t = np.asarray(cfg.tropism)
    for m in word:
        s = m.symbol
        a = math.radians(m.params[0] if m.params else cfg.angle_deg)
        if s in "+-|":
            a = math.pi if s == "|" else (a if s == "+" else -a)
            h, l = h * math.cos(a) - l * math.sin(a), h * math.sin(a) + l * math.cos(a)
        elif s in "&^":
            a = a if s == "&" else -a
            h, u = h * math.cos(a) + u * math.sin(a), u * math.cos(a) - h * math.sin(a)
        elif s in "\\/":
            a = a if s == "\\" else -a
            l, u = l * math.cos(a) + u * math.sin(a), u * math.cos(a) - l * math.sin(a)
        elif s == "$":
            left = np.cross([0, 0, 1.0], h)
            if np.linalg.norm(left) > 1e-12:
                l = left / np.linalg.norm(left)
                u = np.cross(h, l)
        elif s == "!":
            w = m.params[0]
        elif s in "Ff":
            q = p + (m.params[0] if m.params else cfg.step) * h
            if s == "F":
                segs.append((p, q, w))
                k = np.cross(h, t)
                if cfg.elasticity and np.linalg.norm(k) > 1e-15:
                    ang = cfg.elasticity * np.linalg.norm(k)
                    k = k / np.linalg.norm(k)
                    h, l, u = _rot(h, k, ang), _rot(l, k, ang), _rot(u, k, ang)
            p = q
        elif s == "[":
            stack.append((p, h, l, u, w))
        elif s == "]":
            p, h, l, u, w = stack.pop()
    return (np.array([s[0] for s in segs]), np.array([s[1] for s in segs]),
            np.array([s[2] for s in segs]))


@pytest.mark.parametrize("elasticity", [0.0, 0.15])
def test_vectorised_abop_turtle_matches_sequential_reference(elasticity):
    # Honda's grammar with every turtle symbol: f, rolls, pitch up, turn-around
    g = parse_grammar(HONDA.replace("alphabet: A B C F ! & / + - $",
                                    "alphabet: A B C F f ! & ^ \\ / + - $ |")
                      .replace("C(l,w) -> !(w)F(l)", "C(l,w) -> !(w)F(l)f(l/3)\\(17)^(12)")
                      .replace("B(l,w) -> !(w)F(l)", "B(l,w) -> !(w)F(l)|F(l/4)|"))
    w = derive(g, 8)
    cfg = TurtleConfig(elasticity=elasticity, tropism=(0.3, -0.2, -1.0))
    geo = interpret_abop(w, cfg)
    r0, r1, rw = reference_abop(w, cfg)
    np.testing.assert_allclose(geo.branches.p0, r0, atol=1e-10)
    np.testing.assert_allclose(geo.branches.p1, r1, atol=1e-10)
    np.testing.assert_allclose(geo.branches.diameter, rw, rtol=1e-15)


def test_widths_moves_orders_and_scales():
    geo = _geo("!(4)F(1)[!(2)+(90)F(2)[F(1)]]f(5)F(1)", length_scale_m=0.5,
               width_scale_m=0.01, initial_width=3)
    b = geo.branches
    np.testing.assert_allclose(b.diameter, [0.04, 0.02, 0.02, 0.04])
    np.testing.assert_array_equal(b.order, [1, 2, 3, 1])
    np.testing.assert_allclose(b.p0[3], [0, 0, 3.0])            # f moved 2.5 m undrawn
    np.testing.assert_allclose(b.length, [0.5, 1.0, 0.5, 0.5])
    assert _geo("F").branches.diameter[0] == 1.0               # initial width, default step
    with pytest.raises(GrammarError, match="needs the width"):
        _geo("!F")
    with pytest.raises(GrammarError, match=">= 0"):
        _geo("!(-1)F")


@pytest.mark.parametrize("shape, sides, factor", [
    ("rhombus", 8, 0.5),
    ("ellipse", 8, 8 / 2 * math.sin(2 * math.pi / 8) / 4),
    ("ellipse", 5, 5 / 2 * math.sin(2 * math.pi / 5) / 4),
])
def test_leaf_polygons(shape, sides, factor):
    geo = _geo("F(2)[&(30)L(0.1,0.04)]/(90)L(0.2)", leaf_shape=shape, leaf_sides=sides,
               leaf_aspect=0.5)
    t, lv = geo.leaf_table, geo.leaves
    per = 2 if shape == "rhombus" else sides
    assert len(t) == 2 and len(lv) == 2 * per
    np.testing.assert_array_equal(lv.leaf_id, np.repeat([0, 1], per))
    np.testing.assert_allclose(t.length_m, [0.1, 0.2])
    np.testing.assert_allclose(t.width_m, [0.04, 0.1])         # L(0.2): width = aspect · l
    np.testing.assert_allclose(t.area_m2, factor * t.length_m * t.width_m, rtol=1e-12)
    np.testing.assert_allclose(t.base_m, [[0, 0, 2], [0, 0, 2]], atol=1e-12)
    np.testing.assert_allclose(t.centre_m - t.base_m, t.heading * t.length_m[:, None] / 2,
                               atol=1e-12)
    # every triangle's normal is the turtle's U; the blade lies in the H-L plane
    v = lv.vertices
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    np.testing.assert_allclose(n, np.repeat(t.normal, per, axis=0), atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", t.heading, t.normal), 0, atol=1e-12)
    np.testing.assert_allclose(t.heading[0], [0, math.sin(math.radians(30)),
                                              math.cos(math.radians(30))], atol=1e-12)


def test_turtle_config_is_validated():
    with pytest.raises(ConfigError, match="leaf_shape"):
        TurtleConfig(leaf_shape="star")
    with pytest.raises(ConfigError, match="width_scale_m"):
        TurtleConfig(width_scale_m=0)
    with pytest.raises(ConfigError, match="tropism"):
        TurtleConfig(tropism=(0, 1))
    with pytest.raises(GrammarError, match="leaf size"):
        _geo("L(0,1)")
