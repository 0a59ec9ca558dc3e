"""The EKF's dense covariance work as vector rows (option ``rows="vector"``, the model's
``rows``; derive.rows), for a dense P (P0's pattern closes to dense; otherwise the scalar
rows): :func:`vector_predict` and :func:`vector_update` (a sequential sensor's update).

**Predict**, ``P(k/k-1) = F P F^T + Q``, with P read whole (both triangles: a row of P is
consecutive in memory, so a chunk of it is one load):

1. ``A = F P`` as rows: row i is ``sum_k F[i,k] P[k,:]`` (a row of F that is a unit
   vector e_k copies row k of P: no work);
2. ``P(k/k-1)[r, c] = sum_k F[r,k] A[c,k] + Q[r,c]`` as rows r over the lanes c, whose
   sources are columns of A (a copied row c of A is row c of P, so its lane is
   ``P[k, c]``: consecutive in c); where row c of F is a unit vector e_j the entry is
   ``A[r, j] + Q[r, c]`` (no product), likewise for row r;
3. the upper triangle is taken from these and mirrored, so P(k/k-1) is exactly symmetric.

Each row is computed in chunks of :data:`~derive.rows.VECTOR_LANES` lanes, and only the
chunks whose lanes the result reads are kept (derive.row_program): lanes of a kept chunk
that nothing reads are computed and counted all the same, except that a chunk read in part
is scalar statements: in a row of the upper triangle, the chunk holding the diagonal (rows
1 to 3 of each 4 x 4 diagonal block), and in predict the chunks that also hold columns of
F's unit rows (those entries are ``A[r, j] + Q[r, c]``, not the lanes).
"""

from __future__ import annotations

import sympy

from .. import staging
from ..expression_lowering import IfAtMost
from ..program import Port, Program
from ..row_program import RowBuilder
from ..rows import VECTOR_LANES
from .nonlinear import wrapped
from .sensors import decorrelated


def _signed(coef: sympy.Expr) -> tuple[int, sympy.Expr]:
    """(sign, |coef|) of a numeric coefficient; (1, coef) of a symbol."""
    if coef.is_number and coef < 0:
        return -1, -coef
    return 1, coef


def _unit_column(row: list[sympy.Expr]) -> int | None:
    """k when ``row`` is the unit vector e_k, else None."""
    nonzero = [k for k, e in enumerate(row) if e != 0]
    return nonzero[0] if len(nonzero) == 1 and row[nonzero[0]] == 1 else None


def vector_predict(parts, model, inputs: list[Port], outputs: list[Port], doc: str,
                   bind) -> Program:
    """The EKF predict with its products as vector rows (the module docstring).
    ``parts(prog, mapping, x) -> (f, F, Q)``: the scalar work
    (derive.filters.ekf.ekf_predict_parts; the error-state EKF's f projected onto the
    manifold, F and Q over the tangent space); ``bind(prog) -> mapping`` of the model's
    symbols to the program's inputs (p, u)."""
    # x has the model's n entries, P its n_tangent rows (fewer with manifold states)
    n_x, n = model.n, model.n_tangent
    # the scalar work, optimised as any program: f, F, Q's upper triangle
    upper = [(i, j) for i in range(n) for j in range(i, n)]
    prologue = Program("predict", inputs, [Port("scalars", (n_x + n * n + len(upper),))],
                       doc=doc)
    values, F, Q = parts(prologue, bind(prologue), prologue.matrix("x"))
    prologue.set_output("scalars", list(values) + list(F) + [Q[i, j] for i, j in upper])
    prologue = prologue.optimize()
    atoms = list(prologue.results["scalars"])
    x_new = atoms[:n_x]
    Fa = [atoms[n_x + i * n:n_x + (i + 1) * n] for i in range(n)]
    Qa = [[sympy.S.Zero] * n for _ in range(n)]
    for (i, j), atom in zip(upper, atoms[n_x + n * n:]):
        Qa[i][j] = Qa[j][i] = atom

    shell = Program("predict", inputs, outputs, doc=doc)
    rows = RowBuilder(shell, prologue, VECTOR_LANES)

    def p_row(k: int) -> list[sympy.Expr]:
        return [shell.stored_element("P", k, j) for j in range(n)]

    unit = {i: _unit_column(Fa[i]) for i in range(n)}
    A: dict[int, list[sympy.Expr]] = {}
    for i in range(n):
        if unit[i] is not None:
            A[i] = p_row(unit[i])
            continue
        terms = [(k, Fa[i][k]) for k in range(n) if Fa[i][k] != 0]
        first_one = next((k for k, c in terms if c == 1), None)
        A[i] = rows.row(None if first_one is None else p_row(first_one),
                        [(*_signed(c), p_row(k)) for k, c in terms if k != first_one])

    def a_column(k: int) -> list[sympy.Expr]:
        """Column k of A: lane c is A[c, k]; a copied row c of A (row j of P) gives P[k, j]."""
        return [shell.stored_element("P", k, unit[c]) if unit[c] is not None else A[c][k]
                for c in range(n)]

    B: dict[int, list[sympy.Expr]] = {}
    for r in range(n):
        if unit[r] is not None:
            continue
        terms = [(k, Fa[r][k]) for k in range(n) if Fa[r][k] != 0]
        base = Qa[r] if any(e != 0 for e in Qa[r]) else None
        B[r] = rows.row(base, [(*_signed(c), a_column(k)) for k, c in terms],
                        read=[c for c in range(r, n) if unit[c] is None])
    new = [[sympy.S.Zero] * n for _ in range(n)]
    for r in range(n):
        for c in range(r, n):
            if unit[c] is not None:
                value = rows.scalar(A[r][unit[c]] + Qa[r][c])
            elif unit[r] is not None:
                value = rows.scalar(A[c][unit[r]] + Qa[r][c])
            else:
                value = B[r][c]
            new[r][c] = new[c][r] = value
    return rows.finish({"x_new": x_new, "P_new": [new[r][c] for r in range(n)
                                                  for c in range(n)]})


def vector_update(parts, model, meas, name: str, inputs: list[Port], outputs: list[Port],
                  doc: str, bind) -> Program:
    """A sequential EKF update (R diagonal, or constant and decorrelated) with its dense
    work as vector rows; in exact arithmetic derive.filters.sensors.sequential_update,
    with the same signs (every accumulation one fma):

    1. the columns ``C_i = P H_i^T`` as rows (P read whole; a unit row e_k of H takes row
       k of P), and ``S = H P H^T + R`` from them (for a unit row of H, entries of P);
    2. S factored right-looking as scalars, so that no step waits for a vector lane:
       ``s_i = S_ii`` (checked positive), ``-1/s_i``, the multipliers
       ``l_ij = S_ij (-1/s_i)`` and ``S_jk += l_ij S_ik``; ``S_ij`` at step i is
       ``H_j C_i`` of the column as the earlier updates left it;
    3. the whitened innovations ``nu~_i = nu_i + sum_{j<i} S_ji w_j`` and
       ``w_i = nu~_i (-1/s_i)``;
    4. the columns as the earlier updates left them, ``C_i + sum_{j<i} l_ji C_j``, the
       negated gains ``k_i = C_i (-1/s_i)`` (rows), ``x_new = x - sum_i C_i w_i`` and
       ``P_new[a, b] = P[a, b] + sum_i k_i[a] C_i[b]`` for b >= a (rows over b; the
       lower triangle mirrored); where H_i is a unit row e_j, row j of P after update i
       is ``C_i (1 - C_i[j] / s_i) = C_i R_i / s_i = -R_i k_i`` (s_i = C_i[j] + R_i), so
       row j is ``-R_i k_i + sum_{i'>i} k_i'[j] C_i'`` (i the last such update): a
       product for the i + 1 fmas, and no cancellation where R_i is small against
       P[j, j] (a measurement of -x_j is taken as one of x_j, its innovation negated:
       C_i is then row j of P, not its negation);
    5. gated (``meas.gate``): ``nis = sum nu~_i^2 / s_i``, x and P kept when it exceeds
       the threshold; then the unit-norm groups renormalised.

    ``parts(prog, mapping, meas, x) -> (h, H, R)``: the scalar work
    (derive.filters.ekf.ekf_update_parts); ``bind(prog) -> mapping``."""
    n, m = model.n, len(meas.names)
    prologue = Program(name, inputs, [Port("scalars", (m + m * n + m,))], doc=doc)
    x = prologue.matrix("x")
    values, H, R = parts(prologue, bind(prologue), meas, x)
    innovation = wrapped(prologue, staging.sub(prologue, prologue.matrix("z"), values),
                         meas.angles)
    H, R, innovation, correlated = decorrelated(prologue, H, R, innovation)
    prologue.set_output("scalars", list(innovation) + list(H) + [R[i, i] for i in range(m)])
    prologue = prologue.optimize()
    atoms = list(prologue.results["scalars"])
    nu = atoms[:m]
    Ha = [atoms[m + i * n:m + (i + 1) * n] for i in range(m)]
    Ra = atoms[m + m * n:]

    # a measurement of -x_j (H_i = -e_j) is fused as the measurement of x_j that it is up
    # to its sign: C_i is then row j of P itself, not its negation; the signs cancel in
    # S, the multipliers, the gains and P, and stay with the innovation's terms
    signs = []
    for i in range(m):
        flipped = [-e for e in Ha[i]]
        negative = _unit_column(Ha[i]) is None and _unit_column(flipped) is not None
        signs.append(-1 if negative else 1)
        Ha[i] = flipped if negative else Ha[i]
    # the row of P that a unit row e_j of H_i measures, after update i, is -R_i k_i
    # (module docstring, step 4): j -> the last such i
    measured = {_unit_column(Ha[i]): i for i in range(m)
                if _unit_column(Ha[i]) is not None}

    shell = Program(name, inputs, outputs, doc=doc)
    rows = RowBuilder(shell, prologue, VECTOR_LANES)

    def p_row(k: int) -> list[sympy.Expr]:
        return [shell.stored_element("P", k, j) for j in range(n)]

    def dot(h: list[sympy.Expr], lanes: list[sympy.Expr]) -> sympy.Expr:
        return sympy.Add(*[h[k] * lanes[k] for k in range(n) if h[k] != 0])

    initial = []
    for i in range(m):
        unit = _unit_column(Ha[i])
        initial.append(p_row(unit) if unit is not None else rows.row(
            None, [(*_signed(Ha[i][k]), p_row(k)) for k in range(n) if Ha[i][k] != 0]))
    S = {(i, j): rows.scalar(dot(Ha[j], initial[i]) + (Ra[i] if i == j else 0))
         for i in range(m) for j in range(i, m)}
    at_step: dict[tuple[int, int], sympy.Expr] = {}   # (i, j): S_ij at step i, H_j C_i
    multipliers: dict[tuple[int, int], sympy.Expr] = {}
    negated, weights, nis_terms = [], [], []
    for i in range(m):
        label = meas.names[i] + (", decorrelated by R's LDL^T factor" if correlated else "")
        rows.check(S[i, i], f"S is not positive definite: the variance s of measurement {i} "
                            f"({label}) of the sequential update is not positive")
        negated.append(rows.scalar(-1 / S[i, i]))
        for j in range(i + 1, m):
            at_step[i, j] = S[i, j]
            multipliers[i, j] = rows.scalar(S[i, j] * negated[i])
        for j in range(i + 1, m):
            for k in range(j, m):
                S[j, k] = rows.scalar(S[j, k] + multipliers[i, j] * S[i, k])
        whitened = rows.scalar(nu[i] + sympy.Add(*[signs[i] * signs[j] * at_step[j, i]
                                                   * weights[j] for j in range(i)]))
        weights.append(rows.scalar(whitened * negated[i]))
        nis_terms.append(whitened * weights[i])
    columns: list[list[sympy.Expr]] = []
    for i in range(m):
        columns.append(rows.row(initial[i], [(1, multipliers[j, i], columns[j])
                                             for j in range(i)]))
    gains = [rows.row(None, [(1, negated[i], columns[i])]) for i in range(m)]
    x_prior = list(x)
    x_new = rows.row(x_prior, [(-signs[i], weights[i], columns[i]) for i in range(m)])
    P_rows = []
    for a in range(n):
        if a in measured:
            i = measured[a]
            P_rows.append(rows.row(None, [(1, rows.scalar(-Ra[i]), gains[i])]
                                   + [(1, gains[k][a], columns[k]) for k in range(i + 1, m)],
                                   read=range(a, n)))
        else:
            P_rows.append(rows.row(p_row(a), [(1, gains[i][a], columns[i]) for i in range(m)],
                                   read=range(a, n)))
    P_new = [[P_rows[min(a, b)][max(a, b)] for b in range(n)] for a in range(n)]
    extra = {}
    if meas.gate is not None:
        nis = rows.scalar(-rows.scalar(sympy.Add(*nis_terms)))
        bound = sympy.Float(meas.gate, 17)
        applied = rows.scalar(IfAtMost(nis, bound, sympy.Integer(1), sympy.Integer(0)))
        x_new = [rows.scalar(IfAtMost(nis, bound, a, b)) for a, b in zip(x_new, x_prior)]
        for a in range(n):
            for b in range(a, n):
                P_new[a][b] = P_new[b][a] = rows.scalar(
                    IfAtMost(nis, bound, P_new[a][b], shell.element("P", a, b)))
        extra = {"nis": [nis], "applied": [applied]}
    x_new = _renormalised(rows, model, x_new)
    return rows.finish({"x_new": x_new, "P_new": [e for row in P_new for e in row], **extra})


def rows_fact(programs: dict[str, Program]) -> list[str]:
    """The header line naming the programs of vector rows (none without)."""
    names = [name for name, program in programs.items() if program.rows]
    if not names:
        return []
    return ["vector rows (rows = vector): " + ", ".join(names) + " computed in chunks of "
            f"{VECTOR_LANES} lanes, P read whole; C: GCC/Clang vector statements where "
            "DERIVE_VECTOR is 1, the same lanes as scalar statements where it is 0 (the same "
            "bits)"]


def _renormalised(rows: RowBuilder, model, x: list[sympy.Expr]) -> list[sympy.Expr]:
    """``x`` with each unit-norm group divided by its norm (as
    derive.filters.sensors.renormalised)."""
    out = list(x)
    for group in getattr(model, "unit_norm", ()):
        index = [model.states.index(s) for s in group]
        norm2 = rows.scalar(sympy.Add(*[out[i] ** 2 for i in index]))
        inverse = rows.scalar(1 / sympy.sqrt(norm2))
        for i in index:
            out[i] = rows.scalar(out[i] * inverse)
    return out


__all__ = ["rows_fact", "vector_predict", "vector_update"]
