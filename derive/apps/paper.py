"""Paper mode: the dense, unspecialised filters exactly as the papers count them (MPT3D Tables 2-3).

Every model matrix (and, for the LF, every off-line constant) is a runtime input
in the parameter port ``p``, so nothing folds: the generated code is the papers'
algorithm operation for operation, whatever the model. Its exact count (by
:func:`derive.flops.count`, like every generated program) is what the audit sets
against the papers' formulas (:mod:`derive.apps.formulas`); the formulas never produce
a count.

What the papers charge, and how paper mode executes it:

- products and sums of dense matrices, with only the upper triangle of a product
  or sum that is symmetric (``(FP)F^T``, ``H(PH^T)``, ``+ GQG^T``, ``(I-KH)P``, ...);
- ``I - KH`` and ``I + POn`` on the diagonal only (n operations);
- the inverse as an unpivoted Doolittle LU plus, for each column ``e_c`` of the
  identity, a forward solve ``L y = e_c`` and a backward solve ``U x = y``, each a
  general triangular solve of n² operations, (16n³ - 3n² - n)/6 in all. To execute
  what the papers charge, the identity ``E`` (the right-hand sides) and the unit
  diagonal ``d`` of L are read from ``p`` as data: the forward solve divides by
  ``d[i] = 1`` and works on the zeros of ``e_c``. These n² operations are the
  papers' overcount (a 1 x 1 inverse is charged 2 where one division does); derive's
  own code never performs them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np
import sympy

from .. import horizon, riccati, staging
from ..emit.render import render_files
from ..emit.write import write_files
from ..errors import FilterError, ModelError
from ..filters import kind as filter_spec
from ..filters.kf import prior
from ..generation import LANG_CHOICES, check_lang, resolve_model
from ..options import DEFAULT_EPS
from ..pipeline import Generated, load_units
from ..program import Port, Program
from ..runs.unit import Unit

#: The filters paper mode generates (derive's names).
PAPER_FILTERS = ("kf", "lf", "jklf", "sskf", "sslf", "jssklf", "pred", "fir")

_HALF = sympy.Rational(1, 2)


@dataclass(frozen=True)
class Block:
    """One matrix of the parameter port: name, shape (rows, cols), meaning."""

    name: str
    rows: int
    cols: int
    doc: str
    vector: bool = False

    @property
    def size(self) -> int:
        return self.rows * self.cols


def _need(name: str, value) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ModelError(f"paper mode: {name} must be a positive integer, got {value!r}")
    return value


def _check(name: str, n: int, m: int, N: int | None) -> None:
    if name not in PAPER_FILTERS:
        raise FilterError(f"paper mode has no filter {name!r}; paper filters: "
                          f"{', '.join(PAPER_FILTERS)}")
    _need("n", n)
    _need("m", m)
    if name == "fir":
        _need("the FIR order N", N)
    elif N is not None and name != "pred":
        raise ModelError(f"paper mode: filter {name!r} takes no order N (got {N!r})")


def _inverse_blocks(k: int, tag: str) -> list[Block]:
    return [Block(f"E{tag}", k, k, "identity: the right-hand sides of the solves (data)"),
            Block(f"d{tag}", k, 1, "ones: the unit diagonal of L (data)", vector=True)]


def layout(name: str, n: int, m: int, N: int | None = None) -> list[Block]:
    """The blocks of ``p``, in order, for paper-mode filter ``name``."""
    _check(name, n, m, N)
    kf = [Block("F", n, n, "F"), Block("H", m, n, "H"), Block("R", m, m, "R"),
          Block("W", n, n, "G Q G^T")] + _inverse_blocks(m, "m")
    lf = [Block("Kn", n, m, "Kn"), Block("Km", n, m, "Km"), Block("Pn", n, n, "Pn"),
          Block("Fn", n, n, "Fn"), Block("On", n, n, "On")] + _inverse_blocks(n, "n")
    steady = [Block("A", n, n, "A"), Block("B", n, m, "B")]
    return {
        "kf": kf,
        "lf": lf,
        "jklf": kf + lf,
        "sskf": steady,
        "sslf": steady,
        "pred": [Block("A", n, n, "A_N"), Block("B", n, m, "B_N"), Block("FN", n, n, "F^N")],
        "jssklf": [Block("A_KF", n, n, "A_KF"), Block("B_KF", n, m, "B_KF"),
                   Block("A_LF", n, n, "A_LF"), Block("B_LF", n, m, "B_LF")],
        "fir": [Block(f"C{i}", n, m, f"C{i} = A^{i} B") for i in range(N or 0)],
    }[name]


def parameter_names(blocks: Sequence[Block]) -> list[str]:
    """Names of the elements of ``p``: ``F[0,1]``, row-major within each block."""
    return [f"{b.name}[{i}]" if b.vector else f"{b.name}[{i},{j}]"
            for b in blocks for i in range(b.rows) for j in range(b.cols)]


def _bind(prog: Program, blocks: Sequence[Block]) -> dict[str, sympy.Matrix]:
    out, offset = {}, 0
    for b in blocks:
        out[b.name] = sympy.Matrix(b.rows, b.cols,
                                   [prog.element("p", offset + k) for k in range(b.size)])
        offset += b.size
    return out


# -- the dense algorithms ---------------------------------------------------------------


def _dot(terms) -> sympy.Expr:
    return sympy.Add(*terms)


def dense_inverse(prog: Program, A: sympy.Matrix, E: sympy.Matrix,
                  d: sympy.Matrix) -> sympy.Matrix:
    """``A^-1`` as the papers charge it: Doolittle LU (a division per entry of L), then per
    column ``c`` the forward solve ``L y = E[:, c]`` dividing by ``d`` (L's unit diagonal,
    read as data) and the backward solve ``U x = y``. Costs (16n³ - 3n² - n)/6 exactly."""
    n = A.rows
    L, U = sympy.zeros(n, n), sympy.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            U[i, j] = prog.let(A[i, j] - _dot(L[i, k] * U[k, j] for k in range(i)), "u")
        for j in range(i + 1, n):
            L[j, i] = prog.let((A[j, i] - _dot(L[j, k] * U[k, i] for k in range(i))) / U[i, i],
                               "l")
        L[i, i] = d[i]
    X = sympy.zeros(n, n)
    for c in range(n):
        y = [sympy.S.Zero] * n
        for i in range(n):
            y[i] = prog.let((E[i, c] - _dot(L[i, k] * y[k] for k in range(i))) / L[i, i], "y")
        for i in reversed(range(n)):
            X[i, c] = prog.let((y[i] - _dot(U[i, k] * X[k, c] for k in range(i + 1, n)))
                               / U[i, i], "inv")
    return X


def kf_step(prog: Program, b: dict, x, P, z):
    """The KF as MPT3D lists it: Fx; FP; (FP)F^T; + GQG^T; PH^T; H(PH^T); + R; inverse;
    K; KH; I - KH; (I-KH)x; Kz; add; (I-KH)P."""
    F, H, R, W = b["F"], b["H"], b["R"], b["W"]
    n = F.rows
    xp, Pp, PHt, S = prior(prog, F, W, H, R, x, P)
    K = staging.matmul(prog, PHt, dense_inverse(prog, S, b["Em"], b["dm"]))
    IKH = staging.sub(prog, sympy.eye(n), staging.matmul(prog, K, H))
    x_new = staging.add(prog, staging.matmul(prog, IKH, xp), staging.matmul(prog, K, z))
    return x_new, staging.matmul(prog, IKH, Pp, symmetric_result=True)


def lf_step(prog: Program, b: dict, x, P, z):
    """The LF as MPT3D lists it: POn; I + POn; inverse; M = Fn[.]^-1; MP; (MP)Fn^T;
    + Pn; Km z; P(Km z); + x; M(.); Kn z; add."""
    n = x.rows
    I_POn = staging.add(prog, sympy.eye(n), staging.matmul(prog, P, b["On"]))
    M = staging.matmul(prog, b["Fn"], dense_inverse(prog, I_POn, b["En"], b["dn"]))
    P_new = staging.add(prog, staging.matmul(prog, staging.matmul(prog, M, P), b["Fn"].T,
                                             symmetric_result=True), b["Pn"],
                        symmetric_result=True)
    inner = staging.add(prog, staging.matmul(prog, P, staging.matmul(prog, b["Km"], z)), x)
    x_new = staging.add(prog, staging.matmul(prog, b["Kn"], z), staging.matmul(prog, M, inner))
    return x_new, P_new


def _half_sum(prog: Program, a, b, symmetric: bool = False):
    total = staging.add(prog, a, b, symmetric_result=symmetric)
    return staging.scale(prog, total, _HALF, symmetric_result=symmetric)


def _affine(prog: Program, A, B, x, z):
    return staging.add(prog, staging.matmul(prog, A, x), staging.matmul(prog, B, z))


def _time_varying(name: str, n: int, m: int, blocks: list[Block]) -> Program:
    inputs = [Port("x", (n,), doc="x(k/k)"),
              Port("P", (n, n), symmetric=True, doc="P(k/k), row-major, symmetric"),
              Port("z", (m,), doc="z(k+1)"),
              Port("p", (sum(b.size for b in blocks),), doc="model data, see the header")]
    outputs = [Port("x_new", (n,), doc="x(k+1/k+1)"),
               Port("P_new", (n, n), symmetric=True, doc="P(k+1/k+1), row-major")]
    prog = Program("step", inputs, outputs, doc=f"one step of the dense {name.upper()} "
                                                "as the papers count it")
    b = _bind(prog, blocks)
    x, P, z = prog.matrix("x"), prog.matrix("P"), prog.matrix("z")
    if name == "kf":
        x_new, P_new = kf_step(prog, b, x, P, z)
    elif name == "lf":
        x_new, P_new = lf_step(prog, b, x, P, z)
    else:
        xk, Pk = kf_step(prog, b, x, P, z)
        xl, Pl = lf_step(prog, b, x, P, z)
        x_new, P_new = _half_sum(prog, xk, xl), _half_sum(prog, Pk, Pl, symmetric=True)
    prog.set_output("x_new", list(x_new))
    prog.set_output("P_new", list(P_new))
    return prog


def _steady(name: str, n: int, m: int, blocks: list[Block]) -> Program:
    size = sum(b.size for b in blocks)
    prog = Program("step", [Port("x", (n,), doc="x(k/k)"), Port("z", (m,), doc="z(k+1)"),
                            Port("p", (size,), doc="gains, see the header")],
                   [Port("x_new", (n,), doc="x(k+1/k+1)")],
                   doc=f"one step of the dense {name.upper()} as the papers count it")
    b = _bind(prog, blocks)
    x, z = prog.matrix("x"), prog.matrix("z")
    if name == "jssklf":
        x_new = _half_sum(prog, _affine(prog, b["A_KF"], b["B_KF"], x, z),
                          _affine(prog, b["A_LF"], b["B_LF"], x, z))
    else:
        x_new = _affine(prog, b["A"], b["B"], x, z)
    prog.set_output("x_new", list(x_new))
    return prog


def _fir(n: int, m: int, N: int, blocks: list[Block]) -> Program:
    size = sum(b.size for b in blocks)
    prog = Program("step", [Port("zw", (N, m), doc="z(k), z(k-1), ..., z(k-N+1), row-major"),
                            Port("p", (size,), doc="taps C_i = A^i B, see the header")],
                   [Port("x_new", (n,), doc="x(k/k)")],
                   doc=f"the dense FIR filter of order {N} as the papers count it")
    b = _bind(prog, blocks)
    zw = prog.matrix("zw")
    terms = [staging.matmul(prog, b[f"C{i}"], zw[i, :].T) for i in range(N)]
    total = terms[0]
    for term in terms[1:]:
        total = staging.add(prog, total, term)
    prog.set_output("x_new", list(total))
    return prog


def _pred_init(n: int, blocks: list[Block]) -> Program:
    size = sum(b.size for b in blocks)
    prog = Program("init", [Port("x0", (n,), doc="x(0/0)"),
                            Port("p", (size,), doc="gains, see the header")],
                   [Port("x_new", (n,), doc="x(N/0) = F^N x(0/0)")], doc="start of the run")
    b = _bind(prog, blocks)
    prog.set_output("x_new", list(staging.matmul(prog, b["FN"], prog.matrix("x0"))))
    return prog


def programs(name: str, n: int, m: int, N: int | None = None) -> dict[str, Program]:
    """The optimised programs (``step``, and ``init`` for pred) of paper-mode ``name``."""
    return dict(_programs(name, n, m, N))


@cache
def _programs(name: str, n: int, m: int, N: int | None) -> dict[str, Program]:
    _check(name, n, m, N)
    blocks = layout(name, n, m, N)
    if name in ("kf", "lf", "jklf"):
        progs = {"step": _time_varying(name, n, m, blocks)}
    elif name == "fir":
        progs = {"step": _fir(n, m, N, blocks)}
    else:
        progs = {"step": _steady(name, n, m, blocks)}
        if name == "pred":
            progs["init"] = _pred_init(n, blocks)
    return {k: v.optimize() for k, v in progs.items()}


def step_program(name: str, n: int, m: int, N: int | None = None) -> Program:
    """The optimised ``step`` of paper-mode ``name`` for sizes n, m (FIR: order N)."""
    return programs(name, n, m, N)["step"]


# -- units, files and the data for a model ----------------------------------------------


def unit(name: str, n: int, m: int, model_name: str | None = None, N: int | None = None,
         command: str = "") -> Unit:
    """The renderer's Unit of paper-mode ``name`` (files ``NAME_paper.{py,c,h}``)."""
    blocks = layout(name, n, m, N)
    facts = ["mode: paper (dense, unspecialised; every model matrix is read from p, so "
             "nothing folds)",
             "p holds, row-major: " + "; ".join(f"{b.name} {b.rows}x{b.cols}: {b.doc}"
                                                for b in blocks)]
    if name in ("kf", "lf", "jklf"):
        facts.append("inverse: Doolittle LU plus a forward and a backward solve per column of "
                     "the identity E, dividing by L's unit diagonal d, as the papers charge it")
    return Unit(model=model_name or f"dense_n{n}_m{m}", filter=f"{name}_paper",
                **filter_spec(name).unit_fields(window=N if name == "fir" else None), n=n, m=m,
                programs=programs(name, n, m, N if name == "fir" else None),
                parameters=tuple(parameter_names(blocks)), facts=tuple(facts),
                command=command, options={"window": N} if name == "fir" else {})


def _fir_order(model, eps: float | None, N: int | None) -> int:
    if N is not None:
        return _need("the FIR order N", N)
    num = model.numeric()
    ss = riccati.kf_steady(num.F, num.G, num.H, num.Q, num.R)
    return horizon.fir_order(ss.A, DEFAULT_EPS if eps is None else eps)


def parameter_values(model, name: str, N: int | None = None, params=None) -> np.ndarray:
    """The numbers of ``p`` for ``model`` (free parameters given in ``params``; FIR: the
    order N, by default the model's for derive's default epsilon)."""
    if model.kind != "linear":
        raise FilterError(f"paper mode needs a linear model; {model.name!r} is {model.kind}")
    if name == "fir":
        N = _fir_order(model, None, N)
    num = model.numeric(params)
    F, G, H, Q, R = num.F, num.G, num.H, num.Q, num.R
    n, m = F.shape[0], H.shape[0]
    values: dict[str, np.ndarray] = {
        "F": F, "H": H, "R": R, "W": G @ Q @ G.T,
        "Em": np.eye(m), "dm": np.ones(m), "En": np.eye(n), "dn": np.ones(n)}
    if name in ("lf", "jklf"):
        c = riccati.lf_constants(F, G, H, Q, R)
        values.update(Kn=c.Kn, Km=c.Km, Pn=c.Pn, Fn=c.Fn, On=c.On)
    if name in ("sskf", "pred", "jssklf", "fir"):
        ss = riccati.kf_steady(F, G, H, Q, R)
        values.update(A=ss.A, B=ss.B, A_KF=ss.A, B_KF=ss.B)
        if name == "pred":  # N: the prediction horizon (default 1)
            pc = horizon.pred_constants(F, ss.K, H, N or 1)
            values.update(A=pc.A_N, B=pc.B_N, FN=np.linalg.matrix_power(F, N or 1))
        if name == "fir":
            taps = horizon.fir_taps(ss.A, ss.B, N)
            values.update({f"C{i}": tap for i, tap in enumerate(taps)})
    if name in ("sslf", "jssklf"):
        ss = riccati.lf_steady(F, G, H, Q, R)
        values.update(A=ss.A, B=ss.B, A_LF=ss.A, B_LF=ss.B)
    blocks = layout(name, n, m, N if name == "fir" else None)
    return np.concatenate([np.asarray(values[b.name], dtype=float).reshape(-1)
                           for b in blocks])


def model_unit(model, name: str, N: int | None = None, eps: float | None = None) -> Unit:
    """The paper-mode Unit for ``model`` (the FIR order from ``N`` or ``eps``)."""
    if model.kind != "linear":
        raise FilterError(f"paper mode needs a linear model; {model.name!r} is {model.kind}")
    order = _fir_order(model, eps, N) if name == "fir" else (N if name == "pred" else None)
    command = (f"python -c \"from derive.apps import paper; paper.generate('{model.name}', "
               f"['{name}'])\"")
    return unit(name, model.n, model.m, model.name, order, command)


def render(model, name: str, lang: str = "all", N: int | None = None,
           eps: float | None = None) -> dict[str, str]:
    """``{file name: text}`` of paper-mode ``name`` for ``model`` (lang python, c or all)."""
    check_lang(lang)
    return render_files(model_unit(model, name, N, eps), LANG_CHOICES[lang])


def load(model, name: str, lang: str = "all", N: int | None = None, eps: float | None = None,
         directory=None) -> Generated:
    """Paper-mode ``name`` for ``model`` rendered, written and loaded (derive.pipeline);
    ``directory``: where ``MODEL/FILTER_paper.*`` go (default: a temporary one)."""
    return load_units([model_unit(model, name, N, eps)], lang, directory)[0]


def generate(model, filters: Sequence[str] = ("kf", "lf"), lang: str = "all",
             out="generated"):
    """Write paper-mode files ``OUT/MODEL/FILTER_paper.*``; returns the paths."""
    model = resolve_model(model)
    files: dict[str, str] = {}
    for name in filters:
        files.update(render(model, name, lang))
    return write_files(out, model.name, files)
