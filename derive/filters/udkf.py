"""The UD (Bierman-Thornton) Kalman filter, staged as straight-line programs.

P = U D Uᵀ is carried as a unit upper-triangular U and a diagonal D; nothing takes a
square root.  Storage: ``U`` is an (n, n) row-major array of which only the strictly
upper triangle is read (the diagonal is 1 and the lower triangle 0 by definition; the
outputs write them so), ``D`` an n-vector of the diagonal.  Entries of U outside U's
pattern (the closure of the declared P0 pattern's factor under the step, as for P in
derive.filters.kf) are neither read nor computed, and are checked to be 0 at runtime.

Programs (:func:`udkf_programs`):

- ``step`` (x[n], U[n, n], D[n], z[m] (+ p)) -> (x_new, U_new, D_new): the time update by
  Thornton's modified weighted Gram-Schmidt (MWGS) on the rows of W = [F U | G Lq] in
  the weights diag(D, Dq), Q = Lq Dq Lqᵀ (Q diagonal: Lq = I); then Bierman's scalar
  updates, one measurement component at a time, of the measurement whitened with
  R = L Dr Lᵀ (z' = L⁻¹ z, H' = L⁻¹ H, R' = Dr; nothing to do when R is diagonal).
  Bierman's divisors, the innovation variances, are checked positive
  (``Program.require_positive``); the MWGS pivots d'_j (P(k+1/k) = U' D' U'ᵀ) are checked
  not negative (d'_j + DBL_MIN > 0) and divide as d'_j itself, or as 1 where d'_j <= 0,
  so that a singular P(k+1/k) (P0 = 0 with a rank-deficient G Q Gᵀ, the catalog's usual
  start) gives D'_j = 0 and a zero column of U' instead of 0 / 0 (PIVOT_FLOOR), and a
  tiny positive pivot is divided by exactly (P ~ 1e-300 is filtered as P ~ 1);
- ``enter`` (x0, P0) -> (x, U, D): x = x0 and the UD factorisation of P0, last column
  first, pivots checked not negative and divided by as in the step (P0 = 0 enters as U = I,
  D = 0); P0 outside the pattern of U D Uᵀ is refused (PatternError / status);
- ``store`` (x, U, D) -> P_new: U D Uᵀ, the upper triangle computed and mirrored.

Registered as ``udkf`` (:data:`SPECS`): the time-varying run loop carries (x, U, D);
``run`` takes x0 and P0 (entered once) and returns xs and Ps (P stored from U and D after
each step; C: only when Ps is given); ``step`` is the factored step.  The header states
how pivots divide (:data:`PIVOT_FACT`).  No product of two variances is formed (Bierman's
new D_j is D_j (alpha_(j-1) / alpha_j), the ratio first), so nothing underflows before P
itself does.

With ``missing`` a NaN in z[i] marks component i absent.  With a diagonal R each scalar
update's results are kept only where z[i] is present (selects, no flop).  With a
correlated R, as in the KF, R's present block is what is whitened (R masked by
derive.filters.common.mask_symmetric), and the absent components get h' = 0, z' = 0,
r' = 1, so their scalar update changes nothing, exactly.
"""

from __future__ import annotations

import numpy as np
import sympy

from .. import staging
from ..errors import FilterError, OptionError
from ..expression_lowering import IfAtMost, IfPresent
from ..options import SharedOptions
from ..precision import DOUBLE, precision
from ..program import Port, Program
from ..reference.linear import update_first
from ..reference.ud import ud_kf
from . import pattern as pat
from .common import (
    MISSING_FACT,
    bound_matrices,
    gaussian_loglik,
    loglik_port,
    mask_columns,
    mask_symmetric,
    mask_vector,
    masked,
    parameter_port,
    pattern_message,
    pattern_text,
    with_fact,
)
from .kf import loglik_reference
from .spec import INNOVATION, Conditioned, FilterSpec
from .unit import make_unit

TITLE = "UD (Bierman-Thornton) Kalman filter"
MODEL_KIND = "linear"
CARRIED = (("x", "x_new"), ("U", "U_new"), ("D", "D_new"))
"""The state the time-varying run loop carries from step to step (input, output)."""
OPTIONS = SharedOptions
REFERENCE = ud_kf
"""``ud_kf(numeric_model, zs, x0, P0) -> (xs, Ps)``, derive.reference.ud."""

_ONE, _ZERO = sympy.Integer(1), sympy.Integer(0)


def _dot(terms) -> sympy.Expr:
    return sympy.Add(*terms)


def _stage(prog: Program, expr, hint: str = "t") -> sympy.Expr:
    """One temporary for ``expr`` (atoms pass through); as staging stages matrix entries."""
    return staging.let_matrix(prog, sympy.Matrix([[expr]]), hint=hint)[0, 0]


def _is_diagonal(M: sympy.Matrix) -> bool:
    return all(M[i, j] == 0 for i in range(M.rows) for j in range(M.cols) if i != j)


PIVOT_FLOOR = sympy.Float(DOUBLE.least_normal)
"""DBL_MIN, the least positive normal double: each pivot d of a UD factorisation is
checked as d + DBL_MIN > 0, which refuses a negative (or NaN) pivot and lets a zero one
through.  The pivot then divides as d itself where d > 0 (every quotient is num / d, for
a subnormal d too), and as 1 where d <= 0 (a select, no flop): a zero pivot (a singular
P, such as P0 = 0, or a singular P(k+1/k)) has an exactly zero numerator when its row is
zero in the weights, so its column of U is 0, as in the reference, instead of 0 / 0; when
d is 0 only because every term of it underflowed, its column of U is finite and only ever
read multiplied by D_j = 0 (in U D Uᵀ, in the weights of the next time update, in
Bierman's v_j = D_j f_j), so it changes nothing.  (The floor was once added to the
divisor, d + DBL_MIN, which is not d below 2^-968, about 4e-292: a wrong P, status 0.)
A normal number, so flush-to-zero arithmetic keeps it.

In float code (``--precision float``) the floor is FLT_MIN (2^-126) instead
(:func:`pivot_floor`): DBL_MIN is zero as a float."""


def pivot_floor(name: str = DOUBLE.name) -> sympy.Float:
    """The pivot floor of the C precision ``name``: its least positive normal number
    (DBL_MIN, :data:`PIVOT_FLOOR`, or FLT_MIN)."""
    return sympy.Float(precision(name).least_normal)


def pivot_fact(name: str = DOUBLE.name) -> str:
    """The header line that states how the UD pivots of the C precision ``name`` are
    checked and divided by (the same floor in both files of a unit)."""
    real = precision(name)
    exponent = int(np.log2(real.least_normal))
    return (f"UD pivots: each pivot d is checked as d + {real.c_least_normal} "
            f"(2^{exponent}) > 0 (a negative pivot is refused) and divides as d itself, "
            "or as 1 where d <= 0: a zero pivot (singular P, e.g. P0 = 0) gives a zero "
            "column of U, as the reference's, read only times D_j = 0")


PIVOT_FACT = pivot_fact()
"""The header line that states :data:`PIVOT_FLOOR`."""


def _pivot(prog: Program, d, message: str, floor: sympy.Float = PIVOT_FLOOR) -> sympy.Expr:
    """The divisor of the pivot ``d``: ``d`` itself where ``d > 0`` (so every quotient is
    num / d, however small d is), 1 where ``d <= 0`` (a select, no flop: a zero pivot's
    column of U is multiplied by D_j = 0 wherever it is read, see :data:`PIVOT_FLOOR`).
    Checked first: ``d + floor > 0`` (DBL_MIN, or FLT_MIN in float code) refuses a negative
    or NaN pivot and lets a zero one through."""
    if d.is_number:
        prog.require_positive(d, message)
        return d
    prog.require_positive(_stage(prog, d + floor, "pivot"), message)
    return _stage(prog, IfAtMost(d, _ZERO, _ONE, d), "pivot")


def _quotients(prog: Program, numerators, divisor, hint: str = "t") -> list[sympy.Expr]:
    """``numerators / divisor``: divided directly when at most two are non-zero, else
    multiplied by one shared reciprocal (as staging.spd_solve does)."""
    nonzero = sum(1 for v in numerators if v != 0)
    if nonzero <= staging.DIRECT_DIVISIONS:
        return [_stage(prog, v / divisor, hint) for v in numerators]
    inverse = _stage(prog, 1 / divisor, "inv")
    return [_stage(prog, v * inverse, hint) for v in numerators]


# -- the three factorisations -----------------------------------------------------------


def ud_factor(prog: Program, P: sympy.Matrix, floor: sympy.Float = PIVOT_FLOOR
              ) -> tuple[sympy.Matrix, list[sympy.Expr]]:
    """``P = U diag(D) Uᵀ`` (upper triangle of P read), U unit upper triangular, last
    column first; a negative pivot is refused at runtime, a zero one gives a zero column
    (PIVOT_FLOOR)."""
    n = P.rows
    U = sympy.eye(n)
    E = sympy.zeros(n, n)  # E[i, k] = U[i, k] D[k], the numerators
    D: list[sympy.Expr] = [_ZERO] * n
    for j in reversed(range(n)):
        D[j] = _stage(prog, P[j, j] - _dot(E[j, k] * U[j, k] for k in range(j + 1, n)), "d")
        divisor = _pivot(prog, D[j], f"P is not positive semidefinite: pivot {j} of its "
                                     "UD factorisation is negative", floor)
        for i in range(j):
            E[i, j] = _stage(prog, P[i, j] - _dot(E[i, k] * U[j, k] for k in range(j + 1, n)))
        column = _quotients(prog, [E[i, j] for i in range(j)], divisor, "u")
        for i in range(j):
            U[i, j] = column[i]
    return U, D


def ud_compose(prog: Program, U: sympy.Matrix, D) -> sympy.Matrix:
    """``U diag(D) Uᵀ`` (upper triangle staged, mirrored)."""
    UD = staging.let_matrix(prog, sympy.Matrix(U.rows, U.cols, lambda i, k: U[i, k] * D[k]))
    return staging.matmul(prog, UD, U.T, symmetric_result=True)


def mwgs(prog: Program, W: sympy.Matrix, weights, floor: sympy.Float = PIVOT_FLOOR
         ) -> tuple[sympy.Matrix, list[sympy.Expr]]:
    """Thornton's modified weighted Gram-Schmidt: U, D with U diag(D) Uᵀ = W diag(weights) Wᵀ.

    Rows are orthogonalised from the last to the first; each pivot (the weighted squared
    norm of a row, >= 0 in exact arithmetic) is checked not negative, and a zero pivot
    (singular P(k+1/k)) gives a zero column of U (PIVOT_FLOOR)."""
    n, N = W.rows, W.cols
    W = sympy.Matrix(W)
    U = sympy.eye(n)
    D: list[sympy.Expr] = [_ZERO] * n
    for j in reversed(range(n)):
        c = [_stage(prog, weights[k] * W[j, k]) for k in range(N)]
        D[j] = _stage(prog, _dot(W[j, k] * c[k] for k in range(N)), "d")
        divisor = _pivot(prog, D[j], f"P(k+1/k) is not positive semidefinite: pivot {j} of "
                                     "the time update (MWGS) is negative", floor)
        numerators = [_stage(prog, _dot(W[i, k] * c[k] for k in range(N))) for i in range(j)]
        column = _quotients(prog, numerators, divisor, "u")
        for i in range(j):
            U[i, j] = column[i]
            if column[i] != 0:
                for k in range(N):
                    W[i, k] = _stage(prog, W[i, k] - column[i] * W[j, k], "w")
    return U, D


def bierman(prog: Program, x, U: sympy.Matrix, D, z, h, r, innovations: list | None = None):
    """Bierman's update of (x, U, D) with the scalar measurement z = h x + v, var(v) = r.

    Each innovation variance alpha_j = r + sum_{k<=j} D_k f_k^2 is checked positive; one
    reciprocal each, shared by the new D_j, the next column's multiplier and the gain.
    ``innovations``: a list that gets (alpha, 1/alpha, z - h x) of this update appended,
    its innovation's variance, reciprocal and value (the log-likelihood's terms)."""
    n = len(x)
    U = sympy.Matrix(U)
    D = list(D)
    f = [_stage(prog, _dot(U[i, j] * h[i] for i in range(j + 1)), "f") for j in range(n)]
    v = [_stage(prog, D[j] * f[j], "v") for j in range(n)]
    b: list[sympy.Expr] = [_ZERO] * n
    alpha = _stage(prog, r, "alpha")
    prog.require_positive(alpha, "a measurement noise variance (of R, or of its LDL^T "
                                 "factor when R is not diagonal) is not positive")
    inverse = None
    for j in range(n):
        if f[j] == 0:
            b[j] = v[j]
            continue
        before, before_inverse = alpha, inverse
        alpha = _stage(prog, before + f[j] * v[j], "alpha")
        prog.require_positive(alpha, f"innovation variance {j} of a scalar update is not "
                                     "positive (D or R not positive)")
        inverse = _stage(prog, 1 / alpha, "inv")
        # D_j before / alpha as D_j (before / alpha): the ratio is in (0, 1], while
        # D_j before is a product of two variances, which underflows for P ~ 1e-154
        D[j] = _stage(prog, D[j] * _stage(prog, before * inverse, "ratio"), "d")
        gain = _stage(prog, -f[j] * (before_inverse if before_inverse is not None
                                      else 1 / before), "g")
        for i in range(j):
            old = U[i, j]
            U[i, j] = _stage(prog, old + b[i] * gain, "u")
            b[i] = _stage(prog, b[i] + old * v[j], "b")
        b[j] = v[j]
    if inverse is None:  # h is structurally zero: nothing to update
        if innovations is not None:
            innovations.append((alpha, _stage(prog, 1 / alpha, "inv"), z))
        return x, U, D
    innovation = _stage(prog, z - _dot(h[i] * x[i] for i in range(n)), "e")
    if innovations is not None:
        innovations.append((alpha, inverse, innovation))
    scaled = _stage(prog, innovation * inverse, "e")
    x = [_stage(prog, x[i] + b[i] * scaled, "x") for i in range(n)]
    return x, U, D


# -- the step ---------------------------------------------------------------------------


def _process_noise(prog: Program, G: sympy.Matrix, Q: sympy.Matrix):
    """``G Lq`` and Dq with Q = Lq diag(Dq) Lqᵀ (Q diagonal: G and Q's diagonal)."""
    if _is_diagonal(Q):
        return G, [Q[k, k] for k in range(Q.rows)]
    Lq, Dq = staging.ldl(prog, Q, name="Q")
    return staging.matmul(prog, G, Lq), [Dq[k, k] for k in range(Q.rows)]


def _whitened(prog: Program, H: sympy.Matrix, R: sympy.Matrix, z: sympy.Matrix,
              missing: bool):
    """H', z' and the variances r' of the decorrelated measurement (R = L Dr Lᵀ)."""
    if missing:
        R = mask_symmetric(prog, R, z)
        H = mask_columns(prog, H.T, z).T
        z = mask_vector(prog, z, z)
    if _is_diagonal(R):
        return H, z, [R[i, i] for i in range(R.rows)]
    L, Dr = staging.ldl(prog, R, name="R")
    m = R.rows
    Hw, zw = sympy.zeros(m, H.cols), sympy.zeros(m, 1)
    for i in range(m):  # forward substitution L [Hw | zw] = [H | z]
        for c in range(H.cols):
            Hw[i, c] = _stage(prog, H[i, c] - _dot(L[i, k] * Hw[k, c] for k in range(i)))
        zw[i] = _stage(prog, z[i] - _dot(L[i, k] * zw[k] for k in range(i)))
    return Hw, zw, [Dr[i, i] for i in range(m)]


def udkf_update(prog: Program, mats, x, U, D, z, missing: bool = False,
                floor: sympy.Float = PIVOT_FLOOR, loglik: bool = False):
    """Stage one UD step; returns (x_new, U_new, D_new): a column, a matrix, a list;
    ``floor``: the pivot floor (:func:`pivot_floor`).  ``loglik``: (x_new, U_new, D_new,
    ll), ll the log-likelihood of the step's innovations from the scalar updates' (the
    chain rule over the decorrelated measurements, whose whitening has determinant 1)."""
    innovations = [] if loglik else None
    x_new, U_new, D_new = _updated(prog, mats, x, U, D, z, missing, floor, innovations)
    if not loglik:
        return x_new, U_new, D_new
    alpha, inverse, nu = zip(*innovations)
    ll = gaussian_loglik(prog, staging.Pivots(alpha, inverse), nu, z if missing else None)
    return x_new, U_new, D_new, ll


def _updated(prog: Program, mats, x, U, D, z, missing: bool, floor: sympy.Float,
             innovations: list | None):
    F, G, H, Q, R = (mats[k] for k in ("F", "G", "H", "Q", "R"))
    n = F.rows
    Gw, Dq = _process_noise(prog, G, Q)
    FU = staging.matmul(prog, F, U)
    W = FU.row_join(Gw)
    U, D = mwgs(prog, W, list(D) + Dq, floor)
    x = list(staging.matmul(prog, F, x))
    if missing and _is_diagonal(R):
        # independent components: run each update and keep its result only where z[i]
        # is present (selects, no flop; the model's zeros and ones still fold)
        for i in range(H.rows):
            updated = bierman(prog, x, U, D, z[i], [H[i, c] for c in range(n)], R[i, i],
                              innovations)
            x, U, D = _kept(prog, z[i], updated, (x, U, D))
        return sympy.Matrix(x), U, D
    Hw, zw, r = _whitened(prog, H, R, z, missing)
    for i in range(Hw.rows):
        x, U, D = bierman(prog, x, U, D, zw[i], [Hw[i, c] for c in range(n)], r[i],
                          innovations)
    return sympy.Matrix(x), U, D


def _kept(prog: Program, z_i, updated, old):
    """(x, U, D) ``updated`` where the measurement ``z_i`` is present, else ``old``."""
    def select(new: sympy.Matrix, before: sympy.Matrix) -> sympy.Matrix:
        chosen = sympy.Matrix([[IfPresent(z_i, new[i, j], before[i, j])
                                for j in range(new.cols)] for i in range(new.rows)])
        return staging.let_matrix(prog, chosen, hint="present")

    x = select(sympy.Matrix(updated[0]), sympy.Matrix(old[0]))
    U = select(updated[1], old[1])
    D = select(sympy.Matrix(updated[2]), sympy.Matrix(old[2]))
    return list(x), U, list(D)


def _unit_upper(prog: Program, pattern) -> sympy.Matrix:
    """The input U as a unit upper-triangular matrix, entries outside ``pattern`` zero."""
    n = prog.port("U").shape[0]
    return sympy.Matrix([[_ONE if i == j else
                          (prog.element("U", i, j) if i < j and pattern[i][j] else _ZERO)
                          for j in range(n)] for i in range(n)])


def _check_unit_upper(prog: Program, pattern, declared: str) -> None:
    """Runtime: U is 0 above the diagonal outside ``pattern`` (its lower triangle and
    diagonal are not read)."""
    n = prog.port("U").shape[0]
    message = (f"U has a non-zero entry outside the pattern this code was generated for "
               f"(P0 pattern "
               f"{declared!r} closed under the UD filter; strictly upper triangle read: "
               f"{pattern_text(pattern)}); generate with --P0-pattern dense for code that "
               "accepts any P0")
    for i in range(n):
        for j in range(i + 1, n):
            if not pattern[i][j]:
                prog.require_zero(prog.element("U", i, j), message)


def _flat(U: sympy.Matrix) -> list[sympy.Expr]:
    n = U.rows
    return [U[i, j] if i < j else (_ONE if i == j else _ZERO)
            for i in range(n) for j in range(n)]


def factor_ports(n: int) -> tuple[Port, Port]:
    return (Port("U", (n, n), doc="U, unit upper triangular, row-major (strictly upper "
                                  "triangle read; written with 1 on the diagonal, 0 below)"),
            Port("D", (n,), doc="D, the diagonal of P = U D U^T"))


def step_ports(model) -> tuple[list[Port], list[Port]]:
    n, m = model.n, model.m
    U, D = factor_ports(n)
    inputs = [Port("x", (n,), doc="x(k/k)"), Port(U.name, U.shape, doc=U.doc + ", at k/k"),
              Port(D.name, D.shape, doc=D.doc + ", at k/k"), Port("z", (m,), doc="z(k+1)")]
    outputs = [Port("x_new", (n,), doc="x(k+1/k+1)"),
               Port("U_new", (n, n), doc="U(k+1/k+1), as U"),
               Port("D_new", (n,), doc="D(k+1/k+1)")]
    return inputs + parameter_port(model), outputs


def _factor_pattern(P_pattern) -> pat.Pattern:
    """The pattern of U for P with pattern ``P_pattern`` (the symbolic factorisation)."""
    n = len(P_pattern)
    prog = Program("pattern", [Port("P", (n, n), symmetric=True)], [Port("D", (n,))])
    P = sympy.Matrix([[prog.element("P", i, j) if P_pattern[i][j] else _ZERO
                       for j in range(n)] for i in range(n)])
    U, _ = ud_factor(prog, P)
    return pat.of_matrix(U)


def _product_pattern(U_pattern) -> pat.Pattern:
    """The pattern of U D Uᵀ for U with pattern ``U_pattern`` (and any D)."""
    n = len(U_pattern)
    return tuple(tuple(i == j or any((U_pattern[i][k] or i == k) and (U_pattern[j][k] or j == k)
                                     for k in range(n)) for j in range(n)) for i in range(n))


def _decidable_pattern(P_pattern) -> pat.Pattern:
    """``P_pattern`` with its diagonal (a UD factor needs every pivot)."""
    n = len(P_pattern)
    return tuple(tuple(P_pattern[i][j] or i == j for j in range(n)) for i in range(n))


def udkf_programs(model, options: SharedOptions | None = None) -> dict[str, Program]:
    """``step``, ``enter`` and ``store`` of the UD filter for the linear ``model``."""
    if model.kind != MODEL_KIND:
        raise FilterError(f"the {TITLE} needs a linear model; {model.name!r} is {model.kind}")
    options = options or SharedOptions()
    missing, loglik = options.missing, bool(options.get("loglik"))
    if options.get("gradient"):
        raise OptionError("option 'gradient' is taken by kf and ekf (the UD filter carries "
                          "factors of P, whose sensitivities it does not derive)")
    declared = options.P0_pattern or model.P0_pattern
    floor = pivot_floor(options.precision)
    n = model.n
    inputs, outputs = step_ports(model)
    outputs += [loglik_port()] if loglik else []

    def build(U_pattern):
        prog = Program("step", inputs, outputs, doc=f"one step of the {TITLE}")
        mats = bound_matrices(model, prog)
        _check_unit_upper(prog, U_pattern, declared)
        U = _unit_upper(prog, U_pattern)
        D = list(prog.matrix("D"))
        return prog, udkf_update(prog, mats, prog.matrix("x"), U, D, prog.matrix("z"),
                                 missing, floor, loglik)

    def step_pattern(U_pattern):
        return pat.of_matrix(build(U_pattern)[1][1])

    start = _factor_pattern(_decidable_pattern(pat.declared(model, declared)))
    U_pattern = pat.closure(step_pattern, start)
    prog, (x_new, U_new, D_new, *ll) = build(U_pattern)
    prog.set_output("x_new", list(x_new))
    prog.set_output("U_new", _flat(U_new))
    prog.set_output("D_new", D_new)
    if ll:
        prog.set_output("ll", ll)
    P_pattern = _product_pattern(U_pattern)
    return {"step": prog.optimize(), "enter": enter_program(n, P_pattern, declared, floor),
            "store": store_program(n, U_pattern, declared)}


def enter_program(n: int, P_pattern, declared: str, floor: sympy.Float = PIVOT_FLOOR
                  ) -> Program:
    """(x0, P0) -> (x, U, D): x = x0, P0 = U D Uᵀ; P0 outside ``P_pattern`` (that of
    U D Uᵀ over U's pattern; upper triangle read) is refused (the pattern status)."""
    U_port, D_port = factor_ports(n)
    prog = Program("enter", [Port("x0", (n,), doc="initial state estimate"),
                             Port("P0", (n, n), symmetric=True,
                                  doc="initial covariance, row-major, symmetric")],
                   [Port("x", (n,), doc="x0"), U_port, D_port],
                   doc=f"x = x0 and P0 = U D U^T for the {TITLE}")
    P0 = prog.matrix("P0")
    message = pattern_message(P_pattern, declared)
    for i in range(n):
        for j in range(i, n):
            if not P_pattern[i][j]:
                prog.require_zero(prog.element("P0", i, j), message)
    U, D = ud_factor(prog, masked(P0, P_pattern), floor)
    prog.set_output("x", list(prog.matrix("x0")))
    prog.set_output("U", _flat(U))
    prog.set_output("D", D)
    return prog.optimize()


def store_program(n: int, U_pattern, declared: str) -> Program:
    """(x, U, D) -> P_new = U D Uᵀ (upper triangle computed, mirrored; x not read)."""
    U_port, D_port = factor_ports(n)
    prog = Program("store", [Port("x", (n,), doc="x (not read)"), U_port, D_port],
                   [Port("P_new", (n, n), symmetric=True, doc="P = U D U^T, row-major")],
                   doc=f"P = U D U^T from the factors of the {TITLE}")
    U = _unit_upper(prog, U_pattern)
    _check_unit_upper(prog, U_pattern, declared)
    prog.set_output("P_new", ud_compose(prog, U, list(prog.matrix("D"))))
    return prog.optimize()


# -- the family: spec, derivation, reference --------------------------------------------


def derive_unit(model, spec: FilterSpec, options: SharedOptions):
    """The Unit of the UD filter: the factored step, P0 entered and P stored."""
    unit = make_unit(model, spec, udkf_programs(model, options), options, carried=CARRIED)
    unit = with_fact(unit, pivot_fact(options.precision))
    return with_fact(unit, MISSING_FACT) if options.missing else unit


def reference(model, zs, options):
    """derive.reference.ud.ud_kf from the model's x0 and P0 (update-first with
    start=update): (xs, Ps)."""
    num = model.numeric()
    if options.get("start", "predict") == "update":
        return update_first(lambda x0, P0, rest, _: REFERENCE(num, rest, x0, P0),
                            num.H, num.R, num.x0, num.P0, zs, skip_nan=options.missing)
    return REFERENCE(num, zs)


SPECS = (FilterSpec(
    "udkf", TITLE, MODEL_KIND, "timevarying", derive_unit, reference,
    options=OPTIONS, covariance=True, missing=True, start=True,
    loglik=loglik_reference,  # the KF's: the same likelihood
    extra_programs=("enter", "store"),
    # Bierman's scalar updates divide by the innovation variances (S's LDL^T pivots);
    # P is only ever factored (enter: its U D U^T, backward stable as LDL^T) and carried as
    # factors (Thornton's weighted Gram-Schmidt): never inverted, never cancelled
    conditioning=(Conditioned(INNOVATION, "ldl"),),
    listing=45,
    about={"python": f"Run the {TITLE}: P0 factored as U D U^T, each step on U and D "
                     "(Thornton's time update, Bierman's scalar updates), P = U D U^T "
                     "stored.",
           "c": f"Run the {TITLE} over steps steps from x0 and P0 (factored once); Ps "
                "(P = U D U^T after each step) may be NULL."}),)
