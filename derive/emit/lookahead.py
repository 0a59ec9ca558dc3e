"""Two steps per pass for the run loop of an affine step with constant coefficients.

A steady-state filter's step is ``x(k+1) = A x(k) + B z(k) + c``; in a run loop each
step waits for the previous one, so the loop runs at the latency of that chain (two
dependent fmas for a two-state axis), however wide the machine.  Composing the step
with itself gives the two-step map

    x(k+2) = A² x(k) + A B z(k) + B z(k+1) + (A c + c)

whose chain from x(k) is as deep as one step's: a run loop that computes x(k+1) with the
step (exactly as ``step`` does, bit for bit) and x(k+2) with the two-step map carries
only x(k+2) from pass to pass, halving the latency per step (the classic look-ahead of
recursive digital filters).  The products A², A B, A c are taken exactly (the baked
constants are exact binary rationals) and rounded once when printed; x(k+2) then
differs from two rounded steps by a few units in the last place, well inside the
1e-12 that verification holds every generated filter to.

:func:`two_step_program` finds A, B, c from the step's own expressions and declines
(returns None) for anything else: runtime checks, free parameters, or an output that is
not affine in the state and the measurement with numeric coefficients.
"""

from __future__ import annotations

import sympy

from derive.program import Assign, Port, Program

#: The port of the second measurement row (z is row k, ZNEXT row k + 1).
ZNEXT = "zn"


def _expanded_results(step: Program) -> list[sympy.Expr] | None:
    """``x_new`` as expressions in the step's input elements (temporaries substituted)."""
    values: dict[sympy.Symbol, sympy.Expr] = {}
    for st in step.body:
        if not isinstance(st, Assign):
            return None                    # a runtime check: not a pure affine map
        values[st.target] = st.expr.xreplace(values)
    return [sympy.expand(e.xreplace(values)) for e in step.results["x_new"]]


def _affine(expr: sympy.Expr, x: list, z: list):
    """(row of A, row of B, constant) of ``expr`` = a·x + b·z + c, or None."""
    symbols = list(expr.free_symbols)
    allowed = set(x) | set(z)
    if any(s not in allowed for s in symbols):
        return None
    poly = sympy.Poly(expr, *x, *z) if symbols else None
    if poly is not None and poly.total_degree() > 1:
        return None
    coeffs = [sympy.S.Zero if poly is None else poly.coeff_monomial(s) for s in x + z]
    constant = expr if poly is None else poly.coeff_monomial(1)
    numbers = coeffs + [constant]
    if not all(v.is_number and v.is_real for v in numbers):
        return None
    exact = [sympy.Rational(v) if isinstance(v, sympy.Float) else v for v in numbers]
    return exact[:len(x)], exact[len(x):len(x) + len(z)], exact[-1]


def two_step_program(step: Program) -> Program | None:
    """x(k+2) from inputs ``x`` (x(k)), ``z`` (row k) and ``zn`` (row k + 1) by the
    two-step map; None when the step is not affine with constant coefficients.  The
    run loop computes x(k+1) with the step's own statements beside it."""
    names = [p.name for p in step.inputs]
    if names != ["x", "z"] or [p.name for p in step.outputs] != ["x_new"]:
        return None
    outputs = _expanded_results(step)
    if outputs is None:
        return None
    n, m = step.port("x").size, step.port("z").size
    x = [step.element("x", i) for i in range(n)]
    z = [step.element("z", j) for j in range(m)]
    rows = [_affine(e, x, z) for e in outputs]
    if any(r is None for r in rows):
        return None
    A = sympy.Matrix([r[0] for r in rows])
    B = sympy.Matrix([r[1] for r in rows])
    c = sympy.Matrix([r[2] for r in rows])
    prog = Program("step2", [Port("x", (n,), doc="x(k)"), Port("z", (m,), doc="z(k)"),
                             Port(ZNEXT, (m,), doc="z(k+1)")],
                   [Port("x_new", (n,), doc="x(k+2)")],
                   doc="x(k+2) = A^2 x(k) + A B z(k) + B z(k+1) + A c + c")
    xs, zs, zn = prog.matrix("x"), prog.matrix("z"), prog.matrix(ZNEXT)
    two = (A * A) * xs + (A * B) * zs + B * zn + (A * c + c)
    prog.set_output("x_new", [sympy.expand(e) for e in two])
    return prog.optimize()


def run_pass(unit) -> tuple[Program, int]:
    """(program, steps) of the carried chain of one pass of the generated C run loop of
    ``unit``: the two-step map for a steady-state filter or predictor without free
    parameters whose step is affine (x(k+1) beside it is not carried), else the step itself."""
    step = unit.programs["step"]
    if unit.run.lookahead and not unit.parameters:
        two = two_step_program(step)
        if two is not None:
            return two, 2
    return step, 1
