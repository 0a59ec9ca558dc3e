"""The exact gradient of a filter step's log-likelihood with respect to its free parameters.

For a step ``(x, P, z[, u], p) -> (x_new, P_new, ll)`` whose free parameters are the q
entries of ``p`` (theta), :func:`sensitivity_step` builds the step that also carries the
sensitivities ``dx[j] = d x / d theta_j`` and ``dP[j] = d P / d theta_j`` and returns
``d ll / d theta`` (``dll``): forward-mode differentiation of the staged statements, one
at a time.  For a statement ``t = e(a_1, ..., a_r)`` over atoms (input elements and
earlier temporaries), ``dt_j = sum_i (d e / d a_i) da_i_j``: each partial derivative is
sympy's ``diff`` of the statement's own expression (a few operations), let once and
shared by the q parameters; ``dx``, ``dP`` and ``dp_j = e_j`` start the chain, ``dz = du
= 0``.  A select (``IfPresent``, a gate, a guard) differentiates branch by branch.

Structure the filter has, the sensitivities keep: ``dP[j]`` is symmetric (its upper
triangle computed, mirrored as P_new is) and zero outside P's pattern; and which entries
of ``dx[j]``, ``dP[j]`` can be non-zero at all is the closure, from ``dx = dP = 0`` at
the start, of the step's dependency of its outputs on its inputs and on theta_j
(:func:`support`): the others are neither read nor computed.  The whole program is then
optimised (folding the zeros, sharing, dead code) as every step is.

The log-likelihood of a run is the sum of its steps' ll; its gradient the sum of their
dll (run stores both per step).
"""

from __future__ import annotations

import sympy
from sympy import default_sort_key

from derive.errors import OptionError
from derive.expression_lowering import IfAtMost, IfPresent
from derive.guards import IfAtLeast, IfGreater
from derive.program import PARAMETER_PORT, Port, Program, ProgramError
from derive.statements import Assign, Check, InputElement, Temporary

#: select functions -> the indices of their branch arguments (the others are conditions)
SELECTS = {IfPresent: (1, 2), IfAtMost: (2, 3), IfGreater: (2, 3), IfAtLeast: (2, 3)}

#: functions whose derivative is zero where they are used (the wrap of an angle's turns)
PIECEWISE_CONSTANT = (sympy.ceiling, sympy.floor)

DX, DP, DX_NEW, DP_NEW, DLL = "dx", "dP", "dx_new", "dP_new", "dll"

#: The state a unit with the gradient carries from step to step (its ``enter`` starts it).
SENSITIVITY_CARRIED = (("x", "x_new"), ("P", "P_new"), (DX, DX_NEW), (DP, DP_NEW))

GRADIENT_FACT = ("gradient (option gradient): dll(k) = d ll(k) / d p, the exact derivative "
                 "of each step's log-likelihood with respect to the free parameters p, by the "
                 "sensitivity recursion (dx = dx/dp and dP = dP/dp carried beside x and P, "
                 "zero at the start: x0 and P0 do not depend on p); run stores it per step "
                 "in dlls")


def _element_index(symbol: sympy.Symbol) -> tuple[str, int] | None:
    """``("P", 3)`` for the input element ``P[3]``; None for a temporary or number."""
    if not isinstance(symbol, InputElement):
        return None
    name, _, rest = symbol.name.partition("[")
    return name, int(rest[:-1])


def _upper(k: int, n: int) -> int:
    """The flat index of the upper triangle's element for flat index ``k`` of an n x n."""
    i, j = divmod(k, n)
    return min(i, j) * n + max(i, j)


def support(step: Program, n: int, q: int) -> tuple[list[set[int]], list[set[int]]]:
    """For each parameter j, the entries of dx[j] (indices of x) and of dP[j] (upper flat
    indices of P) that can be non-zero in some step of a run started at dx = dP = 0: the
    closure of the step's dependency (a statement depends on theta_j when an atom it reads
    does; p[j] depends on theta_j) — conservative, no cancellation is assumed."""
    sx: list[set[int]] = [set() for _ in range(q)]
    sP: list[set[int]] = [set() for _ in range(q)]
    results = step.results
    def of(atom, deps) -> frozenset[int]:
        if atom in deps:
            return deps[atom]
        where = _element_index(atom)
        if where is None:
            return frozenset()
        port, k = where
        if port == PARAMETER_PORT:
            return frozenset({k})
        if port == "x":
            return frozenset(j for j in range(q) if k in sx[j])
        if port == "P":
            return frozenset(j for j in range(q) if _upper(k, n) in sP[j])
        return frozenset()

    while True:
        deps: dict[sympy.Symbol, frozenset[int]] = {}
        for st in step.body:
            if isinstance(st, Assign):
                found: set[int] = set()
                for atom in st.expr.free_symbols:
                    found |= of(atom, deps)
                deps[st.target] = frozenset(found)
        grown = False
        for k, atom in enumerate(results["x_new"]):
            for j in of(atom, deps) if isinstance(atom, sympy.Symbol) else ():
                if k not in sx[j]:
                    sx[j].add(k)
                    grown = True
        for k, atom in enumerate(results["P_new"]):
            if k != _upper(k, n):
                continue
            for j in of(atom, deps) if isinstance(atom, sympy.Symbol) else ():
                if k not in sP[j]:
                    sP[j].add(k)
                    grown = True
        if not grown:
            return sx, sP


class _Tangents:
    """The tangent of every atom of a program being differentiated, per parameter."""

    def __init__(self, prog: Program, q: int, sx, sP, n: int) -> None:
        self.prog, self.q, self.n = prog, q, n
        self.sx, self.sP = sx, sP
        self.temps: dict[sympy.Symbol, list[sympy.Expr]] = {}

    def of(self, atom: sympy.Symbol, j: int) -> sympy.Expr:
        if atom in self.temps:
            return self.temps[atom][j]
        where = _element_index(atom)
        if where is None:
            raise ProgramError(f"sensitivity: {atom} is neither an input element nor a "
                               "temporary defined before it")
        port, k = where
        if port == PARAMETER_PORT:
            return sympy.Integer(1 if k == j else 0)
        if port == "x":
            return self.prog.element(DX, j, k) if k in self.sx[j] else sympy.Integer(0)
        if port == "P":
            u = _upper(k, self.n)
            return self.prog.element(DP, j, u) if u in self.sP[j] else sympy.Integer(0)
        return sympy.Integer(0)  # z, u: data

    def differentiate(self, expr: sympy.Expr) -> list[sympy.Expr]:
        """The tangents of ``expr`` for every parameter (expressions over the program's
        atoms, the partial derivatives let as temporaries, once each)."""
        if expr.is_number:
            return [sympy.Integer(0)] * self.q
        if isinstance(expr, sympy.Symbol):
            return [self.of(expr, j) for j in range(self.q)]
        # a select or a piecewise-constant function inside expr: a fresh symbol each, its
        # tangent by branch
        inner: dict[sympy.Expr, sympy.Symbol] = {}
        inner_tangents: dict[sympy.Symbol, list[sympy.Expr]] = {}
        for node in sympy.preorder_traversal(expr):
            if node in inner:
                continue
            if (type(node) in SELECTS or isinstance(node, PIECEWISE_CONSTANT)
                    or isinstance(node, sympy.Abs)):
                inner[node] = sympy.Dummy("select")
        if inner:
            for node, symbol in inner.items():
                if isinstance(node, PIECEWISE_CONSTANT):
                    inner_tangents[symbol] = [sympy.Integer(0)] * self.q
                    continue
                if isinstance(node, sympy.Abs):  # d|a| = da where a > 0, else -da
                    (a,) = node.args
                    inner_tangents[symbol] = [IfGreater(a, 0, t, -t) if t != 0 else t
                                              for t in self.differentiate(a)]
                    continue
                branches = [self.differentiate(node.args[i]) for i in SELECTS[type(node)]]
                tangents = []
                for j in range(self.q):
                    args = list(node.args)
                    for i, branch in zip(SELECTS[type(node)], branches):
                        args[i] = branch[j]
                    tangents.append(type(node)(*args))
                inner_tangents[symbol] = tangents
        total: list[sympy.Expr] = [sympy.Integer(0)] * self.q
        replaced = expr.xreplace(inner) if inner else expr
        back = {symbol: node for node, symbol in inner.items()}
        for atom in sorted(replaced.free_symbols, key=default_sort_key):
            tangents = (inner_tangents[atom] if atom in inner_tangents
                        else [self.of(atom, j) for j in range(self.q)])
            if all(t == 0 for t in tangents):
                continue
            partial = sympy.diff(replaced, atom)
            if partial.has(sympy.Derivative, sympy.Subs):
                raise ProgramError(f"sensitivity: cannot differentiate {expr} in {atom}")
            partial = partial.xreplace(back) if back else partial
            if partial == 0:
                continue
            partial = self.prog.let(partial, "dpart")
            for j, t in enumerate(tangents):
                if t != 0:
                    total[j] = total[j] + partial * t
        return total


def sensitivity_step(step: Program, n: int) -> Program:
    """``step`` (inputs ``x, P, z[, u], p``, outputs ``x_new, P_new, ll``) with the
    sensitivities carried and the gradient returned: inputs ``x, P, dx, dP, z[, u], p``,
    outputs ``x_new, P_new, dx_new, dP_new, ll, dll``; ``dx`` is (q, n), ``dP`` (q, n*n),
    row j of each the derivative with respect to ``p[j]`` (dP's row an n x n, row-major,
    symmetric: its upper triangle read, both written)."""
    names = [p.name for p in step.inputs]
    if PARAMETER_PORT not in names or [p.name for p in step.outputs] != ["x_new", "P_new",
                                                                          "ll"]:
        raise ProgramError("sensitivity: the step must take p and return x_new, P_new, ll")
    q = step.port(PARAMETER_PORT).size
    sx, sP = support(step, n, q)
    ins = list(step.inputs)
    ins[2:2] = [Port(DX, (q, n), doc="dx/dp: row j the derivative of x by p[j]"),
                Port(DP, (q, n * n), doc="dP/dp: row j the derivative of P by p[j], an n x "
                                         "n row-major, symmetric (upper triangle read)")]
    outs = [step.port("x_new"), step.port("P_new"),
            Port(DX_NEW, (q, n), doc="dx_new/dp"), Port(DP_NEW, (q, n * n), doc="dP_new/dp"),
            step.port("ll"),
            Port(DLL, (q,), doc="d ll / d p: the gradient of the step's log-likelihood")]
    prog = Program("step", ins, outs, doc=step.doc + ", with the gradient of its "
                                                     "log-likelihood")
    tangents = _Tangents(prog, q, sx, sP, n)
    renamed: dict[sympy.Symbol, sympy.Expr] = {}

    def own(expr):
        return expr.xreplace(renamed) if renamed else expr

    for st in step.body:
        if isinstance(st, Check):
            value = own(st.value)
            if st.relation == "zero":
                prog.require_zero(value, st.message)
            elif st.parameter:
                prog.require_domain(value, st.parameter, st.relation)
            else:
                prog.require_positive(value, st.message)
            continue
        expr = own(st.expr)
        target = prog.let(expr, "s")
        renamed[st.target] = target
        d = tangents.differentiate(expr)
        if isinstance(target, Temporary):
            tangents.temps[target] = [prog.let(t, "d") for t in d]
    results = {name: [own(v) for v in values] for name, values in step.results.items()}
    for name, values in results.items():
        prog.set_output(name, values)

    def tangent(atom, j):
        if isinstance(atom, sympy.Symbol):
            return tangents.of(atom, j)
        return sympy.Integer(0)

    prog.set_output(DX_NEW, [tangent(a, j) if k in sx[j] else 0
                             for j in range(q) for k, a in enumerate(results["x_new"])])
    prog.set_output(DP_NEW, [tangent(results["P_new"][_upper(k, n)], j)
                             if _upper(k, n) in sP[j] else 0
                             for j in range(q) for k in range(n * n)])
    prog.set_output(DLL, [tangent(results["ll"][0], j) for j in range(q)])
    return prog.optimize()


def enter_program(step: Program, n: int, q: int) -> Program:
    """``enter(x0, P0) -> (x, P, dx, dP)``: x = x0, P = P0 (checked zero outside P's
    pattern, as the step checks P) and the sensitivities zero (x0 and P0 do not depend on
    the parameters)."""
    prog = Program("enter", [Port("x0", (n,), doc="initial state estimate"),
                             Port("P0", (n, n), symmetric=True,
                                  doc="initial covariance (symmetric)")],
                   [Port("x", (n,)), Port("P", (n, n), symmetric=True),
                    Port(DX, (q, n)), Port(DP, (q, n * n))],
                   doc="run's first state: x0, P0 and zero sensitivities")
    for st in step.body:
        if isinstance(st, Check) and st.relation == "zero":
            port, k = _element_index(st.value)
            if port == "P":
                i, j = divmod(k, n)
                prog.require_zero(prog.element("P0", i, j), st.message)
    prog.set_output("x", list(prog.matrix("x0")))
    prog.set_output("P", list(prog.matrix("P0")))
    prog.set_output(DX, [0] * (q * n))
    prog.set_output(DP, [0] * (q * n * n))
    return prog.optimize()


def with_gradient(model, programs: dict) -> tuple[dict, tuple[tuple[str, str], ...]]:
    """A filter's ``programs`` (its ``step`` returning ``ll``) with the gradient: ``step``
    carrying the sensitivities (:func:`sensitivity_step`) and ``enter`` starting them;
    with the carried state the unit declares (:data:`SENSITIVITY_CARRIED`)."""
    if not model.parameters:
        raise OptionError(f"option 'gradient': model {model.name!r} has no free parameters "
                          "(declare the ones to differentiate by without a value)")
    if model.n_tangent != model.n:
        raise OptionError("option 'gradient' is not taken for a model with manifold states")
    step = programs["step"]
    return ({**programs, "step": sensitivity_step(step, model.n),
             "enter": enter_program(step, model.n, len(model.parameters))},
            SENSITIVITY_CARRIED)
