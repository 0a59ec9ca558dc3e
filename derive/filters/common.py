"""What every linear filter derivation shares: ports, bound model matrices, P's pattern,
and the masks that skip missing (NaN) measurements."""

from __future__ import annotations

import dataclasses
import math

import sympy

from .. import staging
from ..errors import PATTERN_MESSAGE_START
from ..expression_lowering import IfPresent
from ..program import Port, Program


def parameter_port(model) -> list[Port]:
    """The trailing ``p`` port when the model has free parameters (none otherwise)."""
    if not model.parameters:
        return []
    return [Port("p", (len(model.parameters),),
                 doc="free parameters: " + ", ".join(p.name for p in model.parameters))]


def input_port(model) -> list[Port]:
    """The per-step port ``u`` (the row of inputs that goes with z(k+1)) when a linear model
    declares inputs (none otherwise)."""
    inputs = getattr(model, "inputs", ())
    if model.kind != "linear" or not inputs:
        return []
    return [Port("u", (len(inputs),),
                 doc="u(k): x(k+1) = F x(k) + B u(k), z(k+1) = H x(k+1) + D u(k); "
                     + ", ".join(u.name for u in inputs))]


def linear_step_inputs(model) -> tuple[str, ...]:
    """The per-step inputs of a linear ``step``: z, and u when the model has inputs."""
    return ("z", "u") if input_port(model) else ("z",)


def time_varying_ports(model) -> tuple[list[Port], list[Port]]:
    n, m = model.n, model.m
    inputs = [Port("x", (n,), doc="x(k/k)"),
              Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric"),
              Port("z", (m,), doc="z(k+1)")] + input_port(model)
    outputs = [Port("x_new", (n,), doc="x(k+1/k+1)"),
               Port("P_new", (n, n), symmetric=True, doc="P(k+1/k+1), row-major")]
    return inputs + parameter_port(model), outputs


def bound_matrices(model, prog: Program) -> dict[str, sympy.Matrix]:
    """F, G, H, Q, R, GQGt (and B, D for a model with inputs) with values substituted and
    free symbols bound to ``p``."""
    binding = prog.bind("p", model.parameters) if model.parameters else {}
    out = {}
    for k in ("F", "G", "H", "Q", "R", "GQGt") + (("B", "D") if input_port(model) else ()):
        out[k] = sympy.Matrix(model.matrix(k)).xreplace(binding)
    return out


def masked(mat: sympy.Matrix, pattern) -> sympy.Matrix:
    """``mat`` with the entries outside ``pattern`` (a boolean n x n) set to zero."""
    return sympy.Matrix(mat.rows, mat.cols,
                        lambda i, j: mat[i, j] if pattern[i][j] else sympy.Integer(0))


def pattern_text(pattern) -> str:
    """``xx..|xx..|..xx|..xx``: the rows of a boolean pattern, x where it may be non-zero."""
    return "|".join("".join("x" if v else "." for v in row) for row in pattern)


def pattern_message(pattern, declared: str) -> str:
    """What a P outside ``pattern`` (the closure of the declared P0 pattern) is told."""
    return (f"{PATTERN_MESSAGE_START} this code was generated for "
            f"(P0 pattern {declared!r} closed under the filter; x may be non-zero, "
            f"upper triangle read: {pattern_text(pattern)}); generate with "
            f"--P0-pattern dense for code that accepts any P0")


def masked_covariance(prog: Program, pattern, declared: str) -> sympy.Matrix:
    """The input P with the entries outside ``pattern`` taken as structural zeros, and a
    runtime check that the caller's P is 0 there (upper triangle: P is symmetric storage).

    The code derived from the result never reads those entries, so a P with a non-zero
    entry there would be filtered wrongly; the check refuses it instead (C: a status,
    Python: PatternError). A dense pattern needs no check."""
    P = prog.matrix("P")
    message = pattern_message(pattern, declared)
    for i in range(P.rows):
        for j in range(i, P.cols):
            if not pattern[i][j]:
                prog.require_zero(prog.element("P", i, j), message)
    return masked(P, pattern)


# -- missing measurements ------------------------------------------------------------------
#
# A NaN in z[i] means "no measurement i at this step".  The update must then be the one
# with the rows of the absent measurements dropped from H, R and z.  With the absent set
# a, the masked quantities below give exactly that for any R (correlated or not):
#   S' = S with row and column i zeroed and S'[i, i] = 1 for i in a, so S'^-1 is the
#        inverse of S's present block, and 1 on the absent diagonal, 0 elsewhere;
#   U' = U (an n x m matrix such as P H^T) with column i zeroed for i in a;
#   K  = U' S'^-1 then has zero columns for i in a and the present columns of the
#        reduced update; the masked innovation (0 for i in a) keeps NaN out of x.
# Every mask is a select (derive.expression_lowering.IfPresent): one comparison z[i] == z[i] and no
# flop.  Structurally zero entries stay zero, so block-diagonal S costs no selects.


JOSEPH_FACT = "covariance update: Joseph form"
"""The header line of a KF generated with the option ``joseph``."""

MISSING_FACT = ("missing measurements: a NaN in z(k)[i] means measurement i is absent at "
                "step k; the update skips it (its rows of H and R are dropped)")


def mask_columns(prog: Program, U: sympy.Matrix, z: sympy.Matrix) -> sympy.Matrix:
    """``U`` (any rows x m) with column i replaced by zeros where ``z[i]`` is NaN."""
    masked_u = sympy.Matrix(U.rows, U.cols, lambda i, j: IfPresent(z[j], U[i, j], 0))
    return staging.let_matrix(prog, masked_u, hint="present")


def mask_vector(prog: Program, v: sympy.Matrix, z: sympy.Matrix) -> sympy.Matrix:
    """The m-vector ``v`` with entry i set to 0 where ``z[i]`` is NaN."""
    return mask_columns(prog, v.T, z).T


def mask_symmetric(prog: Program, S: sympy.Matrix, z: sympy.Matrix) -> sympy.Matrix:
    """The symmetric m x m ``S`` with row and column i zeroed and ``S[i, i] = 1`` where
    ``z[i]`` is NaN (upper triangle read and staged, mirrored)."""
    def entry(i: int, j: int) -> sympy.Expr:
        a, b = min(i, j), max(i, j)
        if a == b:
            return IfPresent(z[a], S[a, a], 1)
        return IfPresent(z[a], IfPresent(z[b], S[a, b], 0), 0)

    return staging.let_matrix(prog, sympy.Matrix(S.rows, S.cols, entry),
                              symmetric_result=True, hint="present")


def with_fact(unit, fact: str):
    """``unit`` with one more header fact line."""
    return dataclasses.replace(unit, facts=tuple(unit.facts) + (fact,))


# -- the log-likelihood of the innovations ----------------------------------------------------

LOG_2PI = sympy.Float(math.log(2 * math.pi), 17)
"""log 2 pi in double, the constant of the Gaussian log-density."""

LOGLIK_FACT = ("log-likelihood (option loglik): ll(k) = -1/2 (m_k log 2 pi + log det S + "
               "nu' S^-1 nu) of the innovation nu, from the LDL^T pivots of S (log det S = "
               "sum of their logs) and L^-1 nu; m_k the measurements present; run stores it "
               "per step in lls")


def loglik_port() -> Port:
    """The step's output ``ll``: the log-likelihood of the step's innovation."""
    return Port("ll", (1,), doc="log-likelihood of the innovation, "
                                "-1/2 (m log 2 pi + log det S + nu' S^-1 nu)")


def gaussian_loglik(prog: Program, pivots, whitened, z: sympy.Matrix | None = None):
    """``-1/2 sum_i (log 2 pi + log d_i + w_i^2 / d_i)``: the Gaussian log-density of an
    innovation nu with ``S = L D L^T`` (``pivots``: derive.staging.Pivots, d_i and 1/d_i
    where the step has it, else a division)
    and ``whitened = L^-1 nu`` (w_i); or of sequential scalar updates, d_i their innovation
    variances and w_i their innovations.  ``z``: with missing measurements, the step's z:
    term i is selected where z[i] is present, else 0 (m = the measurements present)."""
    terms = []
    for i, (d, dinv) in enumerate(zip(pivots.D, pivots.Dinv)):
        w = whitened[i]
        term = sympy.log(d) + (w * w / d if dinv is None else w * w * dinv) + LOG_2PI
        terms.append(term if z is None else IfPresent(z[i], prog.let(term, "llt"), 0))
    total = prog.let(sympy.Add(*terms), "lls")
    return prog.let(sympy.Rational(-1, 2) * total, "ll")

LOGLIK_STORE = ("lls", "ll", (), True)
"""run's optional per-step output of the log-likelihood (derive.runs.unit.Unit.extra_stores)."""

GRADIENT_STORE = ("dlls", "dll", ("np",), True)
"""run's optional per-step output of the log-likelihood's gradient with respect to p (the
option gradient, derive.sensitivity)."""
