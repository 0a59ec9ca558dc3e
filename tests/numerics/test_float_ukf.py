"""A UKF accurate in float32 (issue 14): the sigma-point spreads in difference form
(derive.filters.difference), D = g(x + δ) - g(x) derived node by node so that g's large
terms cancel before anything is rounded.

* the difference form is g(x + δ) - g(x): symbolically, for the catalog's h's and f's
  and one expression per rule, and in double against an exact (mpmath) evaluation, within
  a few units of roundoff of the terms D sums (where the form written as h(x + δ) - h(x)
  is off by u |h|, orders of magnitude more: measured here too);
* the float32 GNSS UKF (pseudoranges of 2e7 m, float32 spacing 2 m, spreads of metres;
  its P was 72 % off) agrees with the float64 reference within its derived bound, on
  x86 and under qemu-arm;
* the same through a non-affine f (the predict's sigma points: a radial orbit at GPS
  radius under inverse-square gravity);
* a node without a rule falls back to g(a') - g(a), is named in the header, and keeps the
  float32 bound's spread-cancellation term.
"""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
import sympy
from hypothesis import example, given, settings
from hypothesis import strategies as st

from derive import NonlinearModel, catalog
from derive.apps.float_tolerance import condition
from derive.apps.targets.arm import run_under_qemu
from derive.apps.targets.toolchains import TARGETS
from derive.apps.verify import (
    conditioning_run,
    nonlinear_reference,
    nonlinear_scenario,
    verify_filter,
)
from derive.filters import derive_unit
from derive.filters.difference import difference_form
from derive.options import validate
from derive.precision import DOUBLE, FLOAT

FLOAT_OPTIONS = {"precision": "float"}
GNSS = catalog.load("gnss_pseudorange")
INS = catalog.load("ins_gnss")

X, Y, Z = sympy.symbols("x y z", real=True)
S = sympy.Symbol("s", real=True)
#: One expression per rule of the difference form (and one without a rule: exp).
RULES = {
    "sum, product": X * Y * Z + 3 * X - S * Y,
    "square": (X - S) ** 2 + Y ** 2,
    "cube": (X + Y) ** 3,
    "inverse": 1 / (X + 2 * Y),
    "inverse square": (X * Y + 1) ** -2,
    "sqrt": sympy.sqrt(X ** 2 + Y ** 2 + S),
    "inverse sqrt": 1 / sympy.sqrt(X + 2 * Z),
    "sin, cos": sympy.sin(X) * sympy.cos(Y + Z),
    "fallback": sympy.exp(X) + X ** sympy.Rational(1, 3),
}


def _shift(states, deltas):
    return {s: s + d for s, d in zip(states, deltas)}


def _is_zero(expr: sympy.Expr) -> bool:
    if expr.is_polynomial():
        return sympy.expand(expr) == 0
    return sympy.simplify(sympy.radsimp(sympy.expand_trig(expr))) == 0


def _catalog_functions():
    yield "gnss_pseudorange h", GNSS.subs(GNSS.h), GNSS.state_symbols
    yield "ins_gnss f", INS.subs(INS.f), INS.state_symbols
    yield "ins_gnss h", INS.subs(INS.h), INS.state_symbols


@pytest.mark.parametrize("name, values, states", [
    *_catalog_functions(), *((rule, [e], (X, Y, Z)) for rule, e in RULES.items())],
    ids=lambda v: v if isinstance(v, str) else "")
def test_the_difference_form_is_g_at_x_plus_delta_minus_g_at_x(name, values, states):
    form = difference_form(values, states)
    at_x, differences = form.expanded()
    shifted = _shift(states, form.deltas)
    for g, value, D in zip(values, at_x, differences):
        assert value == g
        assert _is_zero(D - (g.xreplace(shifted) - g)), (name, g)
    # every rule applies to the catalog's functions; only the fallback row falls back
    assert bool(form.fallbacks) == (name == "fallback")


def _lambda(expr, symbols):
    return sympy.lambdify(symbols, expr, modules="math")


def _straight_line(form):
    """The form's differences in double, evaluated statement by statement as the generated
    code does (substituted back into one expression, sympy would distribute 2*(x - s)
    into 2*x - 2*s and change the rounding): a function of ({symbol: value}, deltas)."""
    statements = [(sym, sorted(expr.free_symbols, key=str), expr)
                  for sym, expr in form.base + form.steps]
    statements = [(sym, args, _lambda(expr, args)) for sym, args, expr in statements]
    outputs = [(sorted(d.free_symbols, key=str), d) for d in form.differences]
    outputs = [(args, _lambda(d, args)) for args, d in outputs]

    def evaluate(point: dict, deltas) -> list[float]:
        env = {**point, **dict(zip(form.deltas, deltas))}
        for sym, args, fn in statements:
            env[sym] = fn(*[env[a] for a in args])
        return [fn(*[env[a] for a in args]) for args, fn in outputs]
    return evaluate


GNSS_FORM = difference_form(GNSS.subs(GNSS.h)[:1], GNSS.state_symbols)
GNSS_H = GNSS.subs(GNSS.h)[0]
GNSS_SYMBOLS = sorted(GNSS_H.free_symbols, key=lambda s: s.name)
GNSS_DELTAS = list(GNSS_FORM.deltas)
GNSS_D = _straight_line(GNSS_FORM)
GNSS_NAIVE = _lambda(GNSS_H.xreplace(_shift(GNSS.state_symbols, GNSS_DELTAS)) - GNSS_H,
                     GNSS_SYMBOLS + GNSS_DELTAS)
GNSS_EXACT = sympy.lambdify(GNSS_SYMBOLS, GNSS_H, modules="mpmath")
GNSS_JACOBIAN = [_lambda(sympy.diff(GNSS_H, s), GNSS_SYMBOLS) for s in GNSS.state_symbols]


def _exact(expr_text_values: dict, deltas: dict) -> mpmath.mpf:
    """h(x + δ) - h(x) at 1200 bits (x + δ exact for any doubles of these sizes)."""
    with mpmath.workprec(1200):
        at = {s: mpmath.mpf(v) for s, v in expr_text_values.items()}
        moved = {**at, **{s: at[s] + mpmath.mpf(deltas[s]) for s in deltas}}
        return GNSS_EXACT(*[moved[s] for s in GNSS_SYMBOLS]) - \
            GNSS_EXACT(*[at[s] for s in GNSS_SYMBOLS])


def _gnss_case(draw_xyz, sat_xyz, b, delta):
    names = {s.name: s for s in GNSS_SYMBOLS}
    values = {names["x"]: draw_xyz[0], names["y"]: draw_xyz[1], names["z"]: draw_xyz[2],
              names["b"]: b, names["xs1"]: sat_xyz[0], names["ys1"]: sat_xyz[1],
              names["zs1"]: sat_xyz[2]}
    deltas = dict(zip(GNSS.state_symbols, delta))
    args = [values[s] for s in GNSS_SYMBOLS]
    # the scale of what D sums: its first-order terms |dh/dx_j δ_j|, and D itself
    scale = sum(abs(J(*args) * d) for J, d in zip(GNSS_JACOBIAN, delta))
    return values, deltas, args + list(delta), scale


#: Units of roundoff the double difference form may be off, relative to the terms D sums
#: (each term -δ_j (2 r_j - δ_j) and their sum: 2 roundings, the quotient by
#: sqrt(a') + sqrt(a): 3 more, then + δ_b: 1; twice that for slack).
ROUNDINGS = 12


def _unit_sphere(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


coordinate = st.floats(-1.0, 1.0).filter(lambda t: abs(t) > 1e-3)


@settings(max_examples=60, deadline=None)
@given(receiver=st.tuples(coordinate, coordinate, coordinate),
       satellite=st.tuples(coordinate, coordinate, coordinate),
       b=st.floats(-1e5, 1e5), delta=st.tuples(*[st.floats(-1e3, 1e3)] * 4))
def test_the_gnss_difference_form_is_accurate_in_double(receiver, satellite, b, delta):
    """ECEF receivers on the Earth's surface (6.4e6 m), satellites at 2.66e7 m, offsets up
    to 1 km: the difference form is within ROUNDINGS u of the terms it sums."""
    xyz = 6.371e6 * _unit_sphere(receiver)
    sat = 2.656e7 * _unit_sphere(satellite)
    values, deltas, args, scale = _gnss_case(xyz, sat, b, delta)
    exact = _exact(values, deltas)
    error = abs(GNSS_D(values, delta)[0] - exact)
    assert error <= ROUNDINGS * DOUBLE.unit_roundoff * (abs(exact) + scale)


def test_the_form_as_written_is_not_accurate_there():
    """The same check fails h(x + δ) - h(x) computed as written (today's spreads): its
    error is u |h| ~ 2e7 u, thousands of times the difference form's tolerance."""
    rng = np.random.default_rng(3)
    worst_form, worst_naive = 0.0, 0.0
    for _ in range(50):
        xyz = 6.371e6 * _unit_sphere(rng.normal(size=3))
        sat = 2.656e7 * _unit_sphere(rng.normal(size=3))
        values, deltas, args, scale = _gnss_case(xyz, sat, rng.normal(0, 1e3),
                                                 rng.uniform(-3.0, 3.0, 4))
        exact = _exact(values, deltas)
        tolerance = ROUNDINGS * DOUBLE.unit_roundoff * (abs(exact) + scale)
        worst_form = max(worst_form, float(abs(GNSS_D(values, deltas.values())[0] - exact))
                         / tolerance)
        worst_naive = max(worst_naive, float(abs(GNSS_NAIVE(*args) - exact)) / tolerance)
    assert worst_form <= 1.0 < 1e3 <= worst_naive


def _term_sizes(derivative: sympy.Expr) -> sympy.Expr:
    """The sum of the absolute values of a partial derivative's terms: what rounding in the
    form scales with (D = X Z dY - S dY sums two terms of size dY whatever their
    difference), where the derivative itself (X Z - S) may cancel to nothing."""
    return sympy.Add(*[sympy.Abs(term) for term in sympy.Add.make_args(sympy.expand(derivative))])


#: Rules checked in double only: atan2's is an identity modulo 2 pi, which sympy does not
#: prove (its arguments here stay in the first quadrant, where it is the difference).
NUMERIC_RULES = {"atan2": sympy.atan2(Y + S, X * Z + 1)}
#: Per rule: the form in double, g in mpmath and the size of its gradient's terms.
RULE_CHECKS = {
    rule: (_straight_line(difference_form([g], (X, Y, Z))),
           sympy.lambdify([X, Y, Z, S], g, modules="mpmath"),
           [_lambda(_term_sizes(sympy.diff(g, s)), [X, Y, Z, S]) for s in (X, Y, Z)])
    for rule, g in {**RULES, **NUMERIC_RULES}.items()
    if rule != "fallback"}  # the fallback cancels, by design


@settings(max_examples=40, deadline=None)
@given(point=st.tuples(*[st.floats(0.5, 2.0)] * 4),
       delta=st.tuples(*[st.floats(-0.1, 0.1)] * 3))
@example(point=(1.0, 1.0, 1.0, 0.99999), delta=(0.0, 7.53575116441517e-221, 0.0))
def test_every_rule_is_accurate_in_double(point, delta):
    """Each rule's expression in double against mpmath: within 1e-12 of |D| + the first-order
    terms' sizes (each partial derivative's terms in absolute value, times |δ_j|) + |δ|² (a
    wrong rule is off at order δ). Hypothesis found a point where the derivative cancels
    (X Z - S = 1e-5 at X = Z = 1, S = 0.99999): the form sums terms of size δ there, and
    its error follows them, not their difference."""
    at = dict(zip((X, Y, Z, S), point))
    for rule, (form, exact_g, gradient) in RULE_CHECKS.items():
        numeric = form(at, delta)[0]
        with mpmath.workprec(1200):
            exact = exact_g(*[mpmath.mpf(point[i]) + (mpmath.mpf(delta[i]) if i < 3 else 0)
                              for i in range(4)]) - exact_g(*map(mpmath.mpf, point))
        first = sum(abs(dg(*point) * d) for dg, d in zip(gradient, delta))
        scale = abs(float(exact)) + first + sum(d * d for d in delta)
        # plus the subnormal spacing: a D that underflows is exact only to it
        assert abs(numeric - float(exact)) <= 1e-12 * scale + math.ulp(0.0), rule


# -- the float32 GNSS UKF -------------------------------------------------------------------


def test_the_float32_gnss_ukf_agrees_within_its_derived_bound():
    """Failed before the difference form: max rel error 0.72 (P wrong at order 1), bound
    2.9e12 (kappa 5e14, the spreads' cancellation squared). Now its bound is that of the
    conditioning alone, like the EKF's, and the error is float32's."""
    ukf, = verify_filter(GNSS, "ukf", steps=1000, seed=7, langs=("c",), options=FLOAT_OPTIONS)
    ekf, = verify_filter(GNSS, "ekf", steps=1000, seed=7, langs=("c",), options=FLOAT_OPTIONS)
    assert ukf.bound.meaningful and ukf.passed, ukf.line()
    assert ukf.error <= ukf.tolerance == ukf.bound.value
    assert ukf.error > 2.0**-53 * ukf.bound.roundings        # float32 was run
    assert ukf.error < FLOAT.unit_roundoff ** 0.5             # no digits lost to cancellation
    # kappa: cond S and cond P(k+1/k) only (the spread-cancellation term is gone), of the
    # same size as the EKF's on the same data
    assert ukf.bound.condition < 1e3 and ekf.bound.condition < 1e3


needs_qemu = pytest.mark.skipif(bool(TARGETS["arm-linux"].missing()),
                                reason="arm-linux tools missing")


@needs_qemu
def test_the_float32_gnss_ukf_agrees_under_qemu_arm():
    run, = run_under_qemu("gnss_pseudorange", ["ukf"], FLOAT_OPTIONS, steps=200)
    host, = verify_filter(GNSS, "ukf", steps=200, langs=("c",), options=FLOAT_OPTIONS)
    assert run.precision == "float" and run.bound is not None and run.bound.meaningful
    assert run.tolerance == host.tolerance
    assert run.passed and run.error <= run.tolerance, run.line()


#: A radial orbit at GPS radius (2.656e7 m, float32 spacing 2 m) under inverse-square
#: gravity: f is not affine, so the UKF's predict draws sigma points through f, whose spreads
#: of metres were lost to that spacing as written (measured before the difference form:
#: max rel error 1.49, bound 3e10 refused).
ORBIT = NonlinearModel(
    "radial_orbit", ["r", "v"], ["rho"],
    f=["r + dt*v", "v - dt*mu/r**2"], h=["r"],
    Q=[["q", 0], [0, "q"]], R=[["r1"]],
    values={"dt": 1.0, "mu": 3.986004418e14, "q": 0.01, "r1": 25.0},
    x0=[2.656e7, 0.0], P0=[[100, 0], [0, 1]])


def test_the_float32_ukf_through_a_non_affine_f_agrees_within_its_derived_bound():
    assert any("f and h in difference form" in f for f in derive_unit(ORBIT, "ukf").facts)
    run, = verify_filter(ORBIT, "ukf", steps=200, langs=("c",), options=FLOAT_OPTIONS)
    assert run.bound.meaningful and run.passed, run.line()
    assert 2.0**-53 * run.bound.roundings < run.error < FLOAT.unit_roundoff ** 0.5


# -- a node without a rule ------------------------------------------------------------------

EXPONENTIAL = NonlinearModel(
    "exp_range", ["p", "v"], ["r"],
    f=["p + dt*v", "v"], h=["exp(p/1000) + 2*p"],
    Q=[["q", 0], [0, "q"]], R=[["r1"]],
    values={"dt": 0.1, "q": 0.01, "r1": 1.0}, x0=[1.0, 0.5], P0=[[1, 0], [0, 1]])


def test_a_node_without_a_rule_is_named_in_the_header_and_keeps_the_cancellation_term():
    facts = [f for f in derive_unit(EXPONENTIAL, "ukf").facts if f.startswith("spreads")]
    assert len(facts) == 1 and "no rule for h: exp(p/1000)" in facts[0]
    assert "no rule" not in next(f for f in derive_unit(GNSS, "ukf").facts
                                 if f.startswith("spreads"))
    scenario = nonlinear_scenario(EXPONENTIAL, 50, 7)
    xs, Ps = nonlinear_reference(EXPONENTIAL, "ukf", scenario, validate("ukf", {}))
    run = conditioning_run(EXPONENTIAL, scenario.zs, scenario, xs, Ps)
    with_term = condition(EXPONENTIAL, "ukf", run)
    # the term: (max |h| / sqrt(min diag H P Hᵀ))², larger than cond S, cond P here
    without = condition(EXPONENTIAL, "ekf", run)
    assert with_term > without
    assert math.isfinite(with_term)
