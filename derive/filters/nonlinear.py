"""What the EKF and the UKF share: Jacobians, measurement forms, the program frame.

The Jacobians are derived by sympy (an entry is replaced by its simplified form when that
has fewer operations) and evaluated together with f and h through common subexpressions
(:func:`linearise`): a pseudorange's square root is computed once and reused by its row
of H. The UKF stages f and h the same way, without Jacobians.

A unit has three programs (:func:`nonlinear_programs`; a filter supplies only its
:data:`Predict` and :data:`Update` stages): ``step(x, P, z, u)`` predicts and updates with
all m measurements; ``predict(x, P[, u])`` (u: the inputs f uses, when it uses any: the
row given with the next z) and ``update1(x, P, z[1], u[k])`` are the sequential
form: one scalar measurement per call, so a step may use any number of measurements (6 to
12 satellites in view, in any order). ``update1`` exists when every row of h is the same
function of its own inputs and R is diagonal with equal entries
(:func:`scalar_measurement`); it returns the innovation and its variance beside x and P.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial

import sympy

from .. import staging
from ..errors import FilterError
from ..guards import has_guards, selects
from ..options import SharedOptions
from ..program import Port, Program
from ..symbols import real_stand_ins
from . import pattern as pat
from .common import loglik_port, masked_covariance, parameter_port
from .sensors import program_name, renormalised

# -- the Jacobians -----------------------------------------------------------------------

#: The run function's note for filters with predict and update1, per language.
NOTE_PY = ("\n\n    For a varying number of measurements per step, call predict, then update1"
           "\n    once per measurement.")
NOTE_C = ("\n * For a varying number of measurements per step, call predict, then update1"
          "\n * once per measurement.")


@dataclass(frozen=True)
class Linearisation:
    """A vector function and its Jacobian over shared subexpressions.

    ``shared``: ``(symbol, expression)`` pairs in evaluation order (each may use the
    earlier symbols); ``values`` (k entries) and ``jacobian`` (k x n) are written over
    the model's symbols and the shared symbols.
    """

    shared: tuple[tuple[sympy.Symbol, sympy.Expr], ...]
    values: tuple[sympy.Expr, ...]
    jacobian: sympy.ImmutableMatrix

    def expanded(self) -> tuple[sympy.Matrix, sympy.Matrix]:
        """(values, Jacobian) with the shared symbols substituted back (for checks)."""
        subs: dict[sympy.Symbol, sympy.Expr] = {}
        for sym, expr in self.shared:
            subs[sym] = expr.xreplace(subs)
        return (sympy.Matrix([v.xreplace(subs) for v in self.values]),
                sympy.Matrix(self.jacobian).xreplace(subs))


MAX_SIMPLIFY_OPERATIONS = 24
"""Largest Jacobian entry (sympy ``count_ops``) that is offered to ``sympy.simplify``, whose
time grows exponentially with nested functions (a 9-deep ``sin`` chain's derivative, 63
operations, takes seconds; 15 deep, minutes). Larger entries are kept as derived."""
MAX_SIMPLIFY_BUDGET = 2000
"""Most operations simplified per Jacobian; past that, entries are kept as derived."""


class _Simplifier:
    """``expr`` or its simplified form, whichever has strictly fewer operations, within
    the bounds above (deterministic: the same model is always simplified the same way).

    A polynomial entry is kept as derived: differentiating a polynomial leaves the
    products and differences f or h is written with (``(wx - bgx)*dt/2``), which the
    program shares with f's own evaluation and across entries, while ``simplify`` only
    factors or flips signs (``dt*(bgx - wx)/2``), fewer operations alone but a new
    subexpression in the program (ins_gnss: 11 more flops in predict), and most of the
    generation time."""

    def __init__(self) -> None:
        self.spent = 0

    def __call__(self, expr: sympy.Expr) -> sympy.Expr:
        if has_guards(expr):  # selects as derived: simplify would rewrite their conditions
            return selects(expr, "a Jacobian entry")
        if expr.is_Atom or expr.is_polynomial():
            return expr
        operations = sympy.count_ops(expr)
        if operations > MAX_SIMPLIFY_OPERATIONS or \
                self.spent + operations > MAX_SIMPLIFY_BUDGET:
            return expr
        self.spent += operations
        candidate = sympy.simplify(expr)
        return candidate if sympy.count_ops(candidate) < operations else expr


def _is_zero(expr: sympy.Expr) -> bool:
    """Whether ``expr`` is zero, decided by ``sympy.simplify`` only within
    `MAX_SIMPLIFY_OPERATIONS` (a larger nonzero-looking difference counts as nonzero:
    the caller then takes its general, always correct path)."""
    if expr == 0:
        return True
    return sympy.count_ops(expr) <= MAX_SIMPLIFY_OPERATIONS and sympy.simplify(expr) == 0


def linearise(values: sympy.MatrixBase, wrt: Sequence[sympy.Symbol],
              with_jacobian: bool = True) -> Linearisation:
    """``values`` and (unless ``with_jacobian`` is False) ``∂values/∂wrt``, sharing work."""
    vals = [sympy.sympify(v) for v in values]
    if with_jacobian:  # over real stand-ins: model entries are real (d|x|/dx = sign(x))
        simpler = _Simplifier()
        real, back = real_stand_ins(set(wrt).union(*(v.free_symbols for v in vals)))
        rvals = [v.xreplace(real) for v in vals]
        jac = sympy.Matrix(len(vals), len(wrt), lambda i, j: simpler(
            sympy.diff(rvals[i], real.get(wrt[j], wrt[j]))).xreplace(back))
    else:
        jac = sympy.zeros(len(vals), 0)
    names = sympy.numbered_symbols("_shared", real=True)
    pairs, reduced = sympy.cse(vals + list(jac), symbols=names, order="canonical")
    k = len(vals)
    return Linearisation(tuple(pairs), tuple(reduced[:k]),
                         sympy.ImmutableMatrix(len(vals), jac.cols, reduced[k:]))


def stage_linearisation(prog: Program, lin: Linearisation, mapping: Mapping,
                        hint: str = "t") -> tuple[sympy.Matrix, sympy.Matrix]:
    """Stage ``lin`` with model symbols replaced by program atoms (``mapping``).

    Returns (values as a k x 1 matrix of atoms, Jacobian as a k x n matrix of atoms).
    """
    subs = dict(mapping)
    for sym, expr in lin.shared:
        subs[sym] = prog.let(expr.xreplace(subs), hint)
    values = sympy.Matrix([prog.let(v.xreplace(subs), hint) for v in lin.values])
    jac = sympy.Matrix(lin.jacobian).xreplace(subs)
    return values, staging.let_matrix(prog, jac, hint=hint)


def state_jacobian(model) -> Linearisation:
    """f and F = ∂f/∂x of a NonlinearModel (valued symbols substituted); when f uses
    inputs, the Jacobian's last columns are ∂f/∂u over ``model.f_inputs``."""
    return linearise(model.subs(model.f), model.state_symbols + model.f_inputs)


# -- measurements: all rows, or one row with its own inputs --------------------------------


@dataclass(frozen=True)
class Measurement:
    """The measurement rows a program uses: h (k x 1), their inputs in port order, R."""

    h: sympy.Matrix
    inputs: tuple[sympy.Symbol, ...]
    R: sympy.Matrix
    names: tuple[str, ...]
    gate: float | None = None  # the NIS threshold of a gated update (None: not gated)
    R_port: bool = False  # R is the update's input port R (R holds its stand-in symbols)
    sequential: bool = False  # fused one scalar measurement at a time (R diagonal)
    angles: tuple[bool, ...] = ()  # per row: an angle, its innovation wrapped to (-pi, pi]


def all_measurements(model) -> Measurement:
    return Measurement(sympy.Matrix(model.subs(model.h)), tuple(model.inputs),
                       sympy.Matrix(model.subs(model.R)), tuple(model.measurements),
                       angles=model.angle_rows())


def wrap_angle(y: sympy.Expr) -> sympy.Expr:
    """``y`` wrapped to (-pi, pi]: ``y - 2 pi ceil((y - pi)/(2 pi))`` (any y; a NaN stays
    NaN)."""
    return y - 2 * sympy.pi * sympy.ceiling((y - sympy.pi) / (2 * sympy.pi))


#: The header's line on wrapped innovations.
WRAP_FACT = ("angle measurements {names}: innovations wrapped to "
             "(-pi, pi] as y - 2 pi ceil((y - pi)/(2 pi))")


def wrapped(prog: Program, values: sympy.Matrix, angles: Sequence[bool]) -> sympy.Matrix:
    """``values`` with the rows that are angles wrapped to (-pi, pi] (:func:`wrap_angle`),
    each staged."""
    if not any(angles):
        return values
    return sympy.Matrix([prog.let(wrap_angle(v), "wrap") if angle else v
                         for v, angle in zip(values, angles)])


def angle_facts(model) -> list[str]:
    """The header's line on the model's angle measurements (none: no line)."""
    return [WRAP_FACT.format(names=", ".join(model.angles))] if model.angles else []


def noise_fact(model, where_Q: str, where_R: str) -> list[str]:
    """The header's line on where a state- or input-dependent Q or R is evaluated."""
    moving = set(model.state_symbols) | set(model.inputs)
    parts = [f"{name} at {where}" for name, matrix, where in (("Q", model.Q, where_Q),
                                                             ("R", model.R, where_R))
             if matrix.free_symbols & moving]
    if not parts:
        return []
    return ["noise that depends on the state or the inputs, evaluated with them: "
            + ", ".join(parts)]


def _row_inputs(model, i: int) -> tuple[sympy.Symbol, ...]:
    used = model.h[i, 0].free_symbols
    return tuple(s for s in model.inputs if s in used)


def scalar_measurement(model) -> tuple[Measurement | None, str]:
    """The one-measurement form used by ``update1``, or (None, why not).

    It exists when R is diagonal with equal entries and every row i of h is row 0 with
    row 0's inputs replaced by row i's own (disjoint, same count, in ``model.inputs``
    order): then a step's measurements can be processed one at a time, in any number.
    """
    R = sympy.Matrix(model.subs(model.R))
    m = model.m
    if any(R[i, j] != 0 for i in range(m) for j in range(m) if i != j):
        return None, "R is not diagonal, so measurements cannot be processed one at a time"
    if not all(_is_zero(R[i, i] - R[0, 0]) for i in range(m)):
        return None, "the diagonal of R is not constant"
    first = _row_inputs(model, 0)
    if bool(first) != bool(model.inputs):
        return None, "the model declares inputs that h does not use"
    seen: set[sympy.Symbol] = set()
    for i in range(m):
        own = _row_inputs(model, i)
        if len(own) != len(first) or seen & set(own):
            return None, (f"measurement {model.measurements[i]!r} does not have its own "
                          f"inputs of the same kind as {model.measurements[0]!r}")
        seen |= set(own)
        renamed = model.h[i, 0].xreplace(dict(zip(own, first)))
        if not _is_zero(renamed - model.h[0, 0]):
            return None, (f"measurement {model.measurements[i]!r} is not "
                          f"{model.measurements[0]!r} of its own inputs")
    angles = model.angle_rows()
    if len(set(angles)) > 1:
        return None, (f"measurement {model.measurements[angles.index(True)]!r} is an angle "
                      f"and {model.measurements[angles.index(False)]!r} is not")
    meas = Measurement(sympy.Matrix([model.subs(model.h[0, 0])]), first,
                       sympy.Matrix([[R[0, 0]]]), (model.measurements[0],),
                       angles=angles[:1])
    return meas, ""


# -- the program frame shared by the EKF and the UKF ---------------------------------------


Predict = Callable[[Program, dict, sympy.Matrix, sympy.Matrix], tuple]
"""``predict(prog, mapping, x, P) -> (x(k/k-1), P(k/k-1))``; mapping binds parameters."""
Update = Callable[[Program, dict, Measurement, sympy.Matrix, sympy.Matrix, sympy.Matrix],
                  tuple]
"""``update(prog, mapping, meas, x, P, z) -> (x_new, P_new, innovation, variance)``;
mapping binds parameters and the measurement's inputs; variance is S (or Pvv), k x k."""


def R_stand_ins(m: int) -> sympy.Matrix:
    """Symmetric m x m symbols standing for an R given per call (bound to the port R)."""
    return sympy.Matrix(m, m, lambda i, j: sympy.Symbol(f"_R{min(i, j)}_{max(i, j)}",
                                                        real=True))


def sensor_measurement(model, group, gate: float | None = None,
                       sequential: bool = False) -> Measurement:
    """A sensor's rows (derive.model.SensorGroup) as the Measurement its update uses."""
    R = (R_stand_ins(group.m) if group.R_argument else sympy.Matrix(model.subs(group.R)))
    return Measurement(sympy.Matrix(model.subs(group.h)), tuple(group.inputs), R,
                       tuple(group.measurements), gate, group.R_argument, sequential,
                       model.angle_rows(group.measurements))


def _sensor_ports(model, name: str, meas: Measurement) -> tuple[list[Port], list[Port]]:
    """``update_<sensor>(x, P, z[, u][, p]) -> (x_new, P_new[, nis, applied])``; P is
    n_tangent x n_tangent (n, or fewer with quaternion states)."""
    n, nt = model.n, model.n_tangent
    inputs = [Port("x", (n,), doc="x before the update (x(k/k-1))"),
              Port("P", (nt, nt), symmetric=True, doc="its covariance, row-major, symmetric"),
              Port("z", (len(meas.names),), doc=", ".join(meas.names))]
    if meas.R_port:
        inputs.append(Port("R", (len(meas.names),) * 2, symmetric=True,
                           doc="its noise covariance R, given per call, symmetric"))
    if meas.inputs:
        inputs.append(Port("u", (len(meas.inputs),),
                           doc="its inputs " + ", ".join(s.name for s in meas.inputs)))
    outputs = [Port("x_new", (n,), doc="x after the update"),
               Port("P_new", (nt, nt), symmetric=True, doc="its covariance, row-major")]
    if meas.gate is not None:
        outputs += [Port("nis", (1,), doc="normalised innovation squared nu' S^-1 nu"),
                    Port("applied", (1,), doc="1 when the update was applied (nis within "
                                              "the gate), else 0 (x, P unchanged)")]
    return inputs + parameter_port(model), outputs


def _ports(model, name: str, meas: Measurement | None, loglik: bool = False
           ) -> tuple[list[Port], list[Port]]:
    if name.startswith("update_"):
        return _sensor_ports(model, name, meas)
    n, nt = model.n, model.n_tangent
    inputs = [Port("x", (n,), doc="x(k-1/k-1)" if name != "update1" else "x before the update"),
              Port("P", (nt, nt), symmetric=True, doc="its covariance, row-major, symmetric")]
    outputs = [Port("x_new", (n,), doc="x(k/k)" if name == "step" else
                    "x(k/k-1)" if name == "predict" else "x after this measurement"),
               Port("P_new", (nt, nt), symmetric=True, doc="its covariance, row-major")]
    if meas is not None and name == "update1":
        inputs.append(Port("z", (1,),
                           doc=f"one measurement, any of {', '.join(model.measurements)}"))
        if meas.inputs:
            inputs.append(Port("u", (len(meas.inputs),), doc="its inputs (for "
                               f"{meas.names[0]}: {', '.join(s.name for s in meas.inputs)})"))
    elif meas is not None:
        inputs.append(Port("z", (len(meas.names),), doc=", ".join(meas.names)))
        if meas.inputs:
            inputs.append(Port("u", (len(meas.inputs),),
                               doc="inputs " + ", ".join(s.name for s in meas.inputs)))
    elif name == "predict" and model.f_inputs:
        inputs.append(Port("u", (len(model.f_inputs),), doc="u(k), the inputs f uses: "
                           + ", ".join(s.name for s in model.f_inputs)))
    if name == "update1":
        outputs += [Port("innovation", (1,), doc="z - its prediction"),
                    Port("variance", (1,), doc="the innovation's variance")]
    if loglik:
        outputs.append(loglik_port())
    return inputs + parameter_port(model), outputs


_DOCS = {"step": "One step of the {title}: predict, then update with all {m} measurements.",
         "predict": "Predict only: x(k/k-1) and P(k/k-1) of the {title}.",
         "update1": "Sequential {title} update with one measurement (any number a step)."}


def _build(model, name: str, meas: Measurement | None, predict: Predict | None,
           update: Update | None, P_pattern, title: str, declared: str,
           loglik: bool = False):
    """(program, x_new, P_new, extra): extra is (innovation, variance[, gated]), with
    ``loglik`` (innovation, variance, (), ll), ll the update's log-likelihood."""
    doc = (_DOCS[name].format(title=title, m=model.m) if name in _DOCS else
           f"The {title} update with the measurements of sensor {name[7:]!r}.")
    prog = Program(name, *_ports(model, name, meas, loglik), doc=doc)
    params = prog.bind("p", model.parameters) if model.parameters else {}
    x, P = prog.matrix("x"), masked_covariance(prog, P_pattern, declared)
    extra = ()
    mapping = dict(params)
    if predict is not None and model.f_inputs:  # u(k) drives the prediction into step k
        mapping.update(prog.bind("u", meas.inputs if meas is not None else model.f_inputs))
    if predict is not None:
        x, P = predict(prog, dict(mapping), x, P)
    if update is not None:
        if meas.inputs and not (predict is not None and model.f_inputs):
            mapping.update(prog.bind("u", meas.inputs))
        if meas.R_port:  # the stand-ins of R: the port's upper triangle
            given = prog.matrix("R")
            mapping.update({sym: given[min(i, j), max(i, j)]
                            for (i, j), sym in zip(
                                [(i, j) for i in range(meas.R.rows) for j in range(meas.R.cols)],
                                meas.R)})
        if loglik:
            x, P, innovation, variance, ll = update(prog, mapping, meas, x, P,
                                                    prog.matrix("z"), loglik=True)
            gated = [(), ll]
        else:
            x, P, innovation, variance, *gated = update(prog, mapping, meas, x, P,
                                                        prog.matrix("z"))
        x = renormalised(prog, model, x)
        extra = (innovation, variance, *gated)
    return prog, x, P, extra


def nonlinear_programs(model, predict: Predict, update: Update, options: SharedOptions,
                       title: str, sensors: dict[str, Measurement] | None = None,
                       vector_predict=None, vector_update=None
                       ) -> tuple[dict[str, Program], list[str]]:
    """``step``, ``predict`` and (when it exists) ``update1``, optimised; and header facts.
    With ``sensors`` (``{sensor name: its Measurement}``): ``predict`` and one
    ``update_<sensor>`` each (the run kind ``sensors``).

    P's pattern is the closure of P0's declared pattern (option ``P0_pattern``) under
    every program, so entries outside it are never read.  The option ``loglik``: step
    also returns ``ll``, its update's log-likelihood (``update(..., loglik=True)``).
    ``vector_predict(model, inputs, outputs, doc, bind)`` and ``vector_update(model, meas,
    name, inputs, outputs, doc, bind)``: build ``predict`` and the sequential sensor
    updates (and those of one measurement) instead when P is dense (vector rows:
    derive.filters.vector_rows).
    """
    if sensors is not None:  # the run kind sensors: predict and one update per sensor
        specs = {"predict": (None, predict, None)}
        for meas_name, meas in sensors.items():
            specs[program_name(meas_name)] = (meas, None, update)
    else:
        scalar, why = scalar_measurement(model)
        specs = {"step": (all_measurements(model), predict, update),
                 "predict": (None, predict, None)}
        if scalar is not None:
            specs["update1"] = (scalar, None, update)

    loglik = bool(options.get("loglik") or options.get("gradient"))

    def grow(pattern):
        out = pattern
        for name, (meas, pr, up) in specs.items():
            out = pat.union(out, pat.of_matrix(_build(model, name, meas, pr, up, pattern,
                                                      title, declared)[2]))
        return out

    declared = options.P0_pattern or model.P0_pattern
    start = pat.declared(model, declared)
    dense = all(all(row) for row in start)
    closed = start if dense else pat.closure(grow, start)
    programs = {}
    for name, (meas, pr, up) in specs.items():
        if name == "predict" and vector_predict is not None and dense:
            programs[name] = vector_predict(model, *_ports(model, name, None),
                                            _DOCS["predict"].format(title=title, m=model.m),
                                            partial(_predict_mapping, model))
            continue
        # a sensor of one measurement is one scalar update in either form, so with vector
        # rows it is built as rows too (ins_gnss's baro, Intel Xeon, against its batch form:
        # float -O2 39 against 83 ns, double -O2 -march=native 47 against 84, float 37
        # against 104; double -O2, scalar lanes either way, 83 against 80)
        if (name.startswith("update_") and vector_update is not None and dense
                and (meas.sequential or (len(meas.names) == 1 and not meas.R_port))):
            programs[name] = vector_update(model, meas, name, *_ports(model, name, meas),
                                           f"The {title} update with the measurements of "
                                           f"sensor {name[7:]!r}.",
                                           partial(_update_mapping, model, meas))
            continue
        prog, x, P, extra = _build(model, name, meas, pr, up, closed, title, declared,
                                   loglik and name == "step")
        prog.set_output("x_new", list(x))
        prog.set_output("P_new", list(P))
        if name == "update1":
            prog.set_output("innovation", [extra[0][0, 0]])
            prog.set_output("variance", [extra[1][0, 0]])
        if len(extra) > 2 and extra[2]:  # a gated update: nis, applied
            prog.set_output("nis", [extra[2][0]])
            prog.set_output("applied", [extra[2][1]])
        if len(extra) > 3:  # the option loglik
            prog.set_output("ll", [extra[3]])
        programs[name] = prog.optimize()
    facts = ["per-step input u: " + ", ".join(s.name for s in model.inputs)
             if model.inputs else "per-step input u: none"]
    if model.f_inputs:
        facts.append("row k of us goes with row k of zs: u(k) drives the prediction into step "
                     "k (f uses " + ", ".join(s.name for s in model.f_inputs) + "; predict "
                     "takes those) and step k's measurement; Q(x, u) = Fu Qu Fu^T + Q, "
                     "Fu = df/du at x(k-1/k-1), u(k)")
    if sensors is not None:
        return programs, facts
    if scalar is not None:
        facts.append("varying measurement count: call predict once per step, then update1 "
                     f"once per measurement (z = one {scalar.names[0]}-like measurement, "
                     "u = its inputs " + ", ".join(s.name for s in scalar.inputs) + ")")
    else:
        facts.append(f"no update1 (sequential scalar updates): {why}")
    return programs, facts


def _predict_mapping(model, prog: Program) -> dict:
    """The model's parameters and the inputs f uses -> the predict program's elements (as
    :func:`_build` binds them)."""
    mapping = prog.bind("p", model.parameters) if model.parameters else {}
    if model.f_inputs:
        mapping.update(prog.bind("u", model.f_inputs))
    return mapping


def _update_mapping(model, meas: Measurement, prog: Program) -> dict:
    """The model's parameters and the sensor's inputs -> the update program's elements (as
    :func:`_build` binds them; a sequential update takes no R port)."""
    mapping = prog.bind("p", model.parameters) if model.parameters else {}
    if meas.inputs:
        mapping.update(prog.bind("u", meas.inputs))
    return mapping


def step_inputs(model) -> tuple[str, ...]:
    """The per-step inputs of ``step``: z, and u when the model has inputs."""
    return ("z", "u") if model.inputs else ("z",)


# -- helpers of both filters ---------------------------------------------------------------


def state_mapping(model, x: sympy.Matrix) -> dict:
    """The model's state symbols -> the entries of ``x`` (program atoms)."""
    return dict(zip(model.state_symbols, list(x)))


def check_nonlinear(model, name: str) -> None:
    """FilterError unless ``model`` is a NonlinearModel."""
    if getattr(model, "kind", None) != "nonlinear":
        raise FilterError(f"filter {name!r} needs a nonlinear model, got {model!r}")


__all__ = ["Linearisation", "Measurement", "Predict", "Update", "all_measurements",
           "angle_facts", "check_nonlinear", "linearise", "noise_fact", "nonlinear_programs",
           "scalar_measurement", "stage_linearisation", "state_jacobian", "state_mapping",
           "step_inputs", "wrap_angle", "wrapped"]
