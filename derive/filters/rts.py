"""The Rauch-Tung-Striebel fixed-interval smoother (linear models), staged as two programs.

``forward``: one Kalman filter step (:func:`derive.filters.kf.kf_update`, the KF's own
staging, ``missing`` included) that also outputs the prediction it made:

    x, P, z, [p]  ->  x_new = x(k+1/k+1), P_new = P(k+1/k+1),
                      x_pred = x(k+1/k),  P_pred = P(k+1/k)

``backward``: one smoothing step; it does not see z, so missing measurements only shape the
forward pass:

    x = x(k/k), P = P(k/k), x_pred = x(k+1/k), P_pred = P(k+1/k),
    x_smooth_next = x(k+1/N), P_smooth_next = P(k+1/N), [p]
      ->  x_smooth = x(k/N) = x + C (x_smooth_next - x_pred),
          P_smooth = P(k/N) = P + C (P_smooth_next - P_pred) C^T,

with C^T = P_pred^-1 (F P) solved by an unrolled LDL^T of P_pred (one pivot check each,
never an inverse), so C = P F^T P_pred^-1.  Symmetric results are computed as upper
triangles.  P(k/k) has the KF's pattern: the closure of P0's declared pattern under the
KF step; P(k+1/k) has the pattern the forward program gives it there; P(k/N) has the
closure of the KF's pattern under the backward step (for the catalog models both closures
are the KF's pattern).  Entries outside are not read; the symmetric inputs are checked to
be zero there (upper triangle), as the KF checks P.

Indexing (derive.reference.smoother): x(0/0) = x0, P(0/0) = P0, z(k) = z[k-1] for
k = 1..N, and the run returns xs[k-1] = x(k/N), Ps[k-1] = P(k/N), k = 1..N.

The run ``MODEL_rts_run(steps, z, x0, P0, xs, Ps, work)`` (the kind "smoother"), with
:class:`WorkLayout` giving every offset below.  Generated C marks the ports ``restrict``,
so no output may alias an input: hence the scratch copies.

work (doubles), ``u`` = the upper-triangle entries of P(k+1/k)'s pattern (row-major,
``WorkLayout.prior_entries``, flat indices into an n x n array):

    [0, n)                 x_f   scratch: a copy of x(k/k)
    [n, n + n*n)           P_f   scratch: a copy of P(k/k), full row-major
    [n + n*n, 2n + n*n)    x_p   scratch: x(k+1/k)
    [2n + n*n, 2n + 2n*n)  P_p   scratch: P(k+1/k), full row-major
    then one record per step k = 1..N at 2(n + n*n) + (k-1)(n + u):
                           x(k/k-1) (n doubles), then P(k/k-1) at prior_entries (u doubles)

size = 2 (n + n*n) + steps (n + u)  (``WorkLayout.size(steps)``).

Loop order:

1. (no initialisation: every scratch double is written before it is read; the forward
   program writes P_p in full, zeros outside the pattern included);
2. forward, k = 1..N: ``forward(x_in, P_in, z[k-1], [p]) -> xs[k-1], Ps[k-1], x_p, P_p``
   with (x_in, P_in) = (x0, P0) for k = 1, else (xs[k-2], Ps[k-2]); then x_p and P_p at
   prior_entries are copied into record k.  A failed check stops the run (its status);
3. xs[N-1], Ps[N-1] already hold the smoothed x(N/N), P(N/N): they are the filtered ones;
4. backward, k = N-1 down to 1: xs[k-1], Ps[k-1] are copied to x_f, P_f; record k+1 to x_p
   and to P_p at prior_entries (its lower triangle is not read); then
   ``backward(x_f, P_f, x_p, P_p, xs[k], Ps[k], [p]) -> xs[k-1], Ps[k-1]``.

Record 1 (P(1/0)) is written and never read back: P(1/0) is singular for the catalog's
P0 = 0, so x(0/N) is not part of the run.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy

from .. import staging
from ..errors import FilterError
from ..options import SharedOptions
from ..program import Port, Program
from ..reference.smoother import rts as reference_rts
from . import pattern as pat
from .common import (
    MISSING_FACT,
    bound_matrices,
    masked,
    masked_covariance,
    parameter_port,
    pattern_message,
    time_varying_ports,
)
from .kf import kf_update, prior
from .unit import accepted_P0

TITLE = "Rauch-Tung-Striebel smoother"
MODEL_KIND = "linear"
RUN_KIND = "smoother"
OPTIONS = SharedOptions
REFERENCE = reference_rts

PRIOR_NAME = "P(k+1/k)"
"""How the pivot checks of the backward solve name the matrix they factorise."""


def _forward_build(model, pattern, declared: str, missing: bool):
    """The forward program with P masked to ``pattern``; returns it with its four results."""
    inputs, outputs = time_varying_ports(model)
    n = model.n
    outputs = outputs + [Port("x_pred", (n,), doc="x(k+1/k)"),
                         Port("P_pred", (n, n), symmetric=True, doc="P(k+1/k), row-major")]
    prog = Program("forward", inputs, outputs,
                   doc=f"one forward (Kalman filter) step of the {TITLE}")
    mats = bound_matrices(model, prog)
    x, z = prog.matrix("x"), prog.matrix("z")
    P = masked_covariance(prog, pattern, declared)
    x_pred, P_pred, _, _ = prior(prog, mats["F"], mats["GQGt"], mats["H"], mats["R"], x, P)
    x_new, P_new = kf_update(prog, mats, x, P, z, missing=missing)
    return prog, (x_new, P_new, x_pred, P_pred)


def _checked(prog: Program, port: str, pattern, declared: str) -> sympy.Matrix:
    """The symmetric input ``port`` with entries outside ``pattern`` structurally zero and
    checked to be zero at runtime (upper triangle), as the KF's ``P``."""
    mat = prog.matrix(port)
    message = port + pattern_message(pattern, declared).removeprefix("P")
    for i in range(mat.rows):
        for j in range(i, mat.cols):
            if not pattern[i][j]:
                prog.require_zero(prog.element(port, i, j), message)
    return masked(mat, pattern)


def _backward_build(model, filtered, predicted, smoothed, declared: str):
    """The backward program with P, P_pred and P_smooth_next masked to the three patterns."""
    n = model.n
    inputs = [Port("x", (n,), doc="x(k/k)"),
              Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric"),
              Port("x_pred", (n,), doc="x(k+1/k)"),
              Port("P_pred", (n, n), symmetric=True, doc="P(k+1/k), row-major, symmetric"),
              Port("x_smooth_next", (n,), doc="x(k+1/N)"),
              Port("P_smooth_next", (n, n), symmetric=True,
                   doc="P(k+1/N), row-major, symmetric")]
    outputs = [Port("x_smooth", (n,), doc="x(k/N)"),
               Port("P_smooth", (n, n), symmetric=True, doc="P(k/N), row-major")]
    prog = Program("backward", inputs + parameter_port(model), outputs,
                   doc=f"one backward step of the {TITLE}")
    F = bound_matrices(model, prog)["F"]
    x, x_pred, x_next = (prog.matrix(name) for name in ("x", "x_pred", "x_smooth_next"))
    P = _checked(prog, "P", filtered, declared)
    P_pred = _checked(prog, "P_pred", predicted, declared)
    P_next = _checked(prog, "P_smooth_next", smoothed, declared)
    gain_t = staging.spd_solve(prog, P_pred, staging.matmul(prog, F, P), name=PRIOR_NAME)
    gain = staging.transpose(gain_t)                          # C = P F^T P(k+1/k)^-1
    x_gap = staging.sub(prog, x_next, x_pred)
    x_smooth = staging.add(prog, x, staging.matmul(prog, gain, x_gap))
    P_gap = staging.sub(prog, P_next, P_pred, symmetric_result=True)
    spread = staging.matmul(prog, staging.matmul(prog, gain, P_gap), gain_t,
                            symmetric_result=True)
    P_smooth = staging.add(prog, P, spread, symmetric_result=True)
    return prog, (x_smooth, P_smooth)


def rts_programs(model, options: SharedOptions) -> dict[str, Program]:
    """``{"forward": ..., "backward": ...}``, optimised, for the linear ``model``."""
    if model.kind != "linear":
        raise FilterError(f"filter 'rts' needs a linear model; {model.name!r} is {model.kind}")
    declared = options.P0_pattern or model.P0_pattern
    missing = options.missing

    filtered = pat.closure(
        lambda p: pat.of_matrix(_forward_build(model, p, declared, missing)[1][1]),
        pat.declared(model, declared))
    forward, (x_new, P_new, x_pred, P_pred) = _forward_build(model, filtered, declared, missing)
    predicted = pat.of_matrix(P_pred)
    smoothed = pat.closure(
        lambda p: pat.of_matrix(_backward_build(model, filtered, predicted, p, declared)[1][1]),
        filtered)
    backward, (x_smooth, P_smooth) = _backward_build(model, filtered, predicted, smoothed,
                                                     declared)
    for name, value in (("x_new", x_new), ("P_new", P_new), ("x_pred", x_pred),
                        ("P_pred", P_pred)):
        forward.set_output(name, list(value))
    backward.set_output("x_smooth", list(x_smooth))
    backward.set_output("P_smooth", list(P_smooth))
    return {"forward": forward.optimize(), "backward": backward.optimize()}


def header_facts(model, programs: dict[str, Program], options: SharedOptions) -> list[str]:
    """The header lines a generated smoother states: P0's declared and accepted patterns,
    the work array's size, missing measurements."""
    layout = WorkLayout.of(programs)
    facts = [f"P0 pattern declared: {options.P0_pattern or model.P0_pattern}",
             accepted_P0(programs["forward"]),
             f"work: {layout.formula()} doubles (caller-provided; no allocation)"]
    return facts + ([MISSING_FACT] if options.missing else [])


@dataclass(frozen=True)
class WorkLayout:
    """Offsets of the run's work array (see the module docstring)."""

    n: int
    prior_entries: tuple[int, ...]
    """Flat row-major indices (i*n + j, i <= j) of the P(k+1/k) entries a record stores."""

    @classmethod
    def of(cls, programs: dict[str, Program]) -> WorkLayout:
        forward = programs["forward"]
        n = forward.port("x").shape[0]
        values = forward.results["P_pred"]
        entries = tuple(i * n + j for i in range(n) for j in range(i, n)
                        if values[i * n + j] != 0)
        return cls(n, entries)

    @property
    def x_f(self) -> int:
        return 0

    @property
    def P_f(self) -> int:
        return self.n

    @property
    def x_p(self) -> int:
        return self.n + self.n * self.n

    @property
    def P_p(self) -> int:
        return 2 * self.n + self.n * self.n

    @property
    def scratch(self) -> int:
        """Doubles before the first record: x_f, P_f, x_p, P_p."""
        return 2 * (self.n + self.n * self.n)

    @property
    def record(self) -> int:
        """Doubles per step: x(k/k-1) and the stored entries of P(k/k-1)."""
        return self.n + len(self.prior_entries)

    def record_offset(self, k: int) -> int:
        """Offset of record k (k = 1..N)."""
        return self.scratch + (k - 1) * self.record

    def size(self, steps: int) -> int:
        return self.scratch + steps * self.record

    def formula(self) -> str:
        """``2 (n + n^2) + steps (n + u)`` with the numbers of this layout."""
        return (f"{self.scratch} + {self.record} * steps (2 (n + n^2) + steps (n + u), "
                f"n = {self.n}, u = {len(self.prior_entries)} entries of P(k+1/k))")
