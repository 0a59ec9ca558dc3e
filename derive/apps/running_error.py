"""A running error bound of a lowered program at numbers: per output element, a bound
``u E`` on the first-order error of its computation in a precision of unit roundoff u,
evaluated at given inputs, many calls at once (each input element an array, one entry per
call).

The bound is Wilkinson's running error analysis (Higham, Accuracy and Stability of
Numerical Algorithms, section 3.3), one rule per operation kind of derive.trees: the
computed ẑ of z = a op b is (â op b̂)(1 + δ), |δ| <= u, so to first order in u

* ``add``, ``sub``:   E(z) = E(a) + E(b) + |z|
* ``mul``:            E(z) = |b| E(a) + |a| E(b) + |z|
* ``div``:            E(z) = (E(a) + |z| E(b)) / |b| + |z|
* ``fma``, ``fnma``:  E(z) = |b| E(a) + |a| E(b) + E(c) + |a b| + |z| (two roundings:
  the C's DERIVE_FMA is the plain ``a * b + c`` where the hardware has no fast fma)
* ``sqrt``:           E(z) = E(a) / (2 |z|) + |z|
* ``neg``, ``call:fabs``: E(a) (exact); ``call:ceil``: 0 (piecewise constant)
* ``call:f``:         E(z) = sum_i |df/da_i| E(a_i) + 4 |z| (:data:`CALL_ULPS`: math.h's
  float functions are within two ulps, 4u relative, of the exact value)
* the choosing kinds (``select``, ``gate``, ``if_gt``, ``if_ge``): the chosen value's E;
  the comparison is taken exact (a choice the rounding flips is not first order).

Inputs carry the E they are given (a value rounded once to the precision: its |value|);
a constant E = |c| unless the precision holds it exactly. The error of the computed
result is then at most u E + O(u^2): nothing is counted by depth, and a division by a
small pivot or a cancellation shows in E as large as it is at those numbers.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..lowering import LoweredAssign, LoweredProgram
from ..trees import Const, Op, Tree, Var, element_name

#: Relative error of a math.h call in units of u: 4u, two ulps (glibc's float functions
#: are within one ulp, newlib's within two).
CALL_ULPS = 4.0


def _derivatives(name: str, args: list[np.ndarray], value: np.ndarray) -> list[np.ndarray]:
    """|df/da_i| of call ``name`` at ``args`` (``value`` = f(args))."""
    if name == "sin":
        return [np.abs(np.cos(args[0]))]
    if name == "cos":
        return [np.abs(np.sin(args[0]))]
    if name == "tan":
        return [1.0 + value**2]
    if name == "exp":
        return [np.abs(value)]
    if name == "log":
        return [1.0 / np.abs(args[0])]
    if name == "atan":
        return [1.0 / (1.0 + args[0] ** 2)]
    if name == "atan2":  # atan2(y, x): d/dy = x / r^2, d/dx = -y / r^2
        y, x = args
        r2 = x**2 + y**2
        return [np.abs(x) / r2, np.abs(y) / r2]
    raise ValueError(f"no running error rule for call {name!r}")


_CALLS = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "exp": np.exp, "log": np.log,
          "atan": np.arctan, "atan2": np.arctan2, "fabs": np.abs, "ceil": np.ceil}


def exact_in(value: float, dtype) -> bool:
    """Whether ``value`` is held exactly in ``dtype`` (np.float32, np.float64)."""
    return bool(np.asarray(value, dtype=dtype).astype(float) == value)


def running_errors(lowered: LoweredProgram, values: Mapping[str, np.ndarray],
                   errors: Mapping[str, np.ndarray], dtype=np.float32
                   ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per output port, (its values, their E) as arrays (calls, elements): the program
    ``lowered`` run on ``values`` (element name ``x[3]`` -> one value per call) whose
    inputs carry ``errors`` (element name -> E per call; missing: 0), in a precision of
    element type ``dtype`` (which constants it holds exactly). The error of each computed
    element is at most u E to first order (the module docstring)."""
    env: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def zero_like(v):
        return np.zeros_like(v, dtype=float)

    def lookup(name: str):
        if name not in env:
            v = np.asarray(values[name], dtype=float)
            e = errors.get(name)
            env[name] = (v, zero_like(v) if e is None else np.asarray(e, dtype=float))
        return env[name]

    def run(tree: Tree):
        if isinstance(tree, Var):
            return lookup(tree.name)
        if isinstance(tree, Const):
            c = float(tree.value)
            return np.float64(c), np.float64(0.0 if exact_in(c, dtype) else abs(c))
        assert isinstance(tree, Op)
        kind = tree.kind
        if kind in ("select", "gate", "if_gt", "if_ge"):
            return _choose(kind, [run(a) for a in tree.args])
        args = [run(a) for a in tree.args]
        vs = [a[0] for a in args]
        es = [a[1] for a in args]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if kind in ("add", "sub"):
                z = vs[0] + vs[1] if kind == "add" else vs[0] - vs[1]
                return z, es[0] + es[1] + np.abs(z)
            if kind == "mul":
                z = vs[0] * vs[1]
                return z, np.abs(vs[1]) * es[0] + np.abs(vs[0]) * es[1] + np.abs(z)
            if kind == "div":
                z = vs[0] / vs[1]
                return z, (es[0] + np.abs(z) * es[1]) / np.abs(vs[1]) + np.abs(z)
            if kind in ("fma", "fnma"):
                a, b, c = vs
                product = a * b
                z = product + c if kind == "fma" else c - product
                return z, (np.abs(b) * es[0] + np.abs(a) * es[1] + es[2] + np.abs(product)
                           + np.abs(z))
            if kind == "sqrt":
                z = np.sqrt(vs[0])
                return z, es[0] / (2.0 * np.abs(z)) + np.abs(z)
            if kind == "neg":
                return -vs[0], es[0]
            if kind.startswith("call:"):
                name = kind[5:]
                z = _CALLS[name](*vs)
                if name == "fabs":
                    return z, es[0]
                if name == "ceil":
                    return z, zero_like(z)
                slopes = _derivatives(name, vs, z)
                return z, sum(s * e for s, e in zip(slopes, es)) + CALL_ULPS * np.abs(z)
        raise ValueError(f"no running error rule for operation {kind!r}")

    for statement in lowered.body:
        if isinstance(statement, LoweredAssign):
            env[statement.target] = run(statement.tree)
    out = {}
    for port, leaves in lowered.results:
        pairs = [run(leaf) for leaf in leaves]
        shape = np.broadcast_shapes(*(np.shape(v) for v, _ in pairs))
        out[port] = (np.stack([np.broadcast_to(v, shape) for v, _ in pairs], -1),
                     np.stack([np.broadcast_to(e, shape) for _, e in pairs], -1))
    return out


def _choose(kind: str, args):
    """The chosen (value, E) of a choosing kind (derive.trees), per call."""
    if kind == "select":  # select(z, a, b): a where z is present (not NaN)
        (z, _), (a, ea), (b, eb) = args
        holds = z == z  # noqa: PLR0124 (false for NaN only)
    elif kind == "gate":  # gate(v, bound, a, b): a where v <= bound
        (v, _), (bound, _), (a, ea), (b, eb) = args
        holds = v <= bound
    else:  # if_gt / if_ge (l, r, a, b): a where l > r (l >= r)
        (left, _), (right, _), (a, ea), (b, eb) = args
        holds = left > right if kind == "if_gt" else left >= right
    return np.where(holds, a, b), np.where(holds, ea, eb)


def port_values(port: str, array: np.ndarray) -> dict[str, np.ndarray]:
    """Element names of ``port`` -> their values per call, from ``array`` (calls, ...)."""
    flat = np.asarray(array, dtype=float).reshape(len(array), -1)
    return {element_name(port, i): flat[:, i] for i in range(flat.shape[1])}


__all__ = ["CALL_ULPS", "exact_in", "port_values", "running_errors"]
