"""SymForce's error-state covariance prediction for a catalog model with one unit quaternion
(``ins_eskf``, ``ins_fc24_eskf``): the peer derive's ``eskf`` predict is held against.

The same function from the same equations: the attitude is a ``sf.Rot3`` (its quaternion
the model's q0..q3), the other states a vector; the nominal prediction is the model's own f
(the quaternion rows renormalised into the Rot3, as derive's predict renormalises), and F and
Fu are SymForce's tangent-space Jacobians of it (``symforce.jacobian_helpers.
tangent_jacobians``: the Rot3's right perturbation R ⊞ δ = R · exp(δ), the body-frame error
of the model's ``error = "local"``); P' = F P Fᵀ + Fu Qu Fuᵀ + Q over the tangent space, P
symmetric (each entry (i, j) the symbol of (min(i, j), max(i, j)), as derive's
upper-triangle read). Emitted by ``symforce.codegen.Codegen`` (C++) and counted by derive's
C rules (derive.apps.ins.symforce_ekf.count_cpp), as derive's own C function body is
(derive.flops.count_c_text): one counter for both.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import sympy

from derive import catalog
from derive.apps.ins.symforce_ekf import SymforceFunction, count_cpp, total_ops
from derive.flops import c_function_body, count_c_text
from derive.manifolds import QUATERNION
from derive.trees import OpCount

FLOPS_BAR = 0.9
"""derive's predict flops over SymForce's, at most."""


def predict_function(sf, model):
    """(the function, its SymForce input types): ``predict(R, rest, P, u, dt) -> (R_new,
    rest_new, P_new)`` for ``model`` (one local-error quaternion; one free parameter, the
    step)."""
    (quaternion,) = [m for m in model.manifolds if m.kind == QUATERNION]
    q_rows = [model.states.index(s) for s in quaternion.states]
    rest_rows = [i for i in range(model.n) if i not in q_rows]
    nt, n_rest = model.n_tangent, len(rest_rows)
    states = list(model.state_symbols)
    inputs = list(model.f_inputs)
    (step,) = model.parameters
    values = {sympy.Symbol(k, real=True): v for k, v in model.values.items()}
    f, Qu, Q = (m.subs(values) for m in (model.f, model.Qu, model.Q))

    def predict(R, rest, P, u, dt):
        q = R.q
        bind = dict(zip([sf.sympify(states[i]) for i in q_rows], [q.w, q.x, q.y, q.z]))
        bind |= {sf.sympify(states[i]): rest[k] for k, i in enumerate(rest_rows)}
        bind |= {sf.sympify(s): u[i] for i, s in enumerate(inputs)}
        bind[sf.sympify(step)] = dt
        new = [sf.sympify(e).subs(bind) for e in f]
        w, x, y, z = (new[i] for i in q_rows)
        norm = sf.sqrt(w ** 2 + x ** 2 + y ** 2 + z ** 2)
        R_new = sf.Rot3(sf.Quaternion(xyz=sf.V3(x / norm, y / norm, z / norm), w=w / norm))
        rest_new = sf.Matrix([new[i] for i in rest_rows])
        F = sf.Matrix(nt, nt)
        Fu = sf.Matrix(nt, len(inputs))
        for r, out in ((0, R_new), (3, rest_new)):
            rows = 3 if r == 0 else n_rest
            jac_R, jac_rest, jac_u = (
                jacobian for jacobian in _jacobians(sf, out, [R, rest, u]))
            F[r:r + rows, 0:3] = jac_R
            F[r:r + rows, 3:nt] = jac_rest
            Fu[r:r + rows, :] = jac_u
        S = sf.Matrix(nt, nt)
        for i in range(nt):
            for j in range(nt):
                S[i, j] = P[min(i, j), max(i, j)]
        noise_u = sf.Matrix([[sf.sympify(e).subs(bind) for e in row] for row in Qu.tolist()])
        noise = sf.Matrix([[sf.sympify(e).subs(bind) for e in row] for row in Q.tolist()])
        return R_new, rest_new, F * S * F.T + Fu * noise_u * Fu.T + noise

    types = [sf.Rot3, sf.Matrix(n_rest, 1).__class__, sf.Matrix(nt, nt).__class__,
             sf.Matrix(len(inputs), 1).__class__, sf.Scalar]
    return predict, types


def _jacobians(sf, out, args):
    """SymForce's tangent-space Jacobians of ``out`` (a Rot3 or a vector) with respect to
    each of ``args`` (epsilon 0: differentiated at zero perturbation, where SymForce's
    storage-tangent maps are exact)."""
    from symforce import jacobian_helpers

    return jacobian_helpers.tangent_jacobians(out, args, epsilon=0)


def generate(model_name: str) -> SymforceFunction:
    """SymForce's C++ of the error-state predict of the catalog model, timed and counted."""
    import symforce  # optional: a benchmark peer

    symforce.set_log_level("error")
    import symforce.symbolic as sf
    from symforce.codegen import Codegen, CppConfig

    model = catalog.load(model_name)
    function, types = predict_function(sf, model)
    with tempfile.TemporaryDirectory(prefix="derive-symforce-") as tmp:
        start = time.perf_counter()
        codegen = Codegen.function(function, config=CppConfig(), name="predict",
                                   input_types=types,
                                   output_names=["R_new", "rest_new", "P_new"])
        data = codegen.generate_function(output_dir=str(Path(tmp) / "predict"))
        seconds = time.perf_counter() - start
        source = next(Path(data.function_dir).glob("*.h")).read_text(encoding="utf-8")
    return SymforceFunction("predict", seconds, total_ops(source), count_cpp(source), source)


def numeric_predict(model_name: str):
    """SymForce's predict of the catalog model as a NumPy function ``(x, P, u, dt) ->
    (x_new, P_new)`` over derive's layout (x the n stored states in the model's order, P
    over the tangent space): its symbolic outputs through its backend's ``Lambdify`` (no code
    generation), to check that it is the function derive's predict computes."""
    import symforce

    symforce.set_log_level("error")
    import symforce.symbolic as sf

    model = catalog.load(model_name)
    function, _ = predict_function(sf, model)
    nt, n_rest = model.n_tangent, model.n - 4
    R = sf.Rot3.symbolic("R")
    rest = sf.Matrix(n_rest, 1).symbolic("r")
    P = sf.Matrix(nt, nt).symbolic("P")
    u = sf.Matrix(len(model.f_inputs), 1).symbolic("u")
    dt = sf.Symbol("dt")
    R_new, rest_new, P_new = function(R, rest, P, u, dt)
    (quaternion,) = [m for m in model.manifolds if m.kind == QUATERNION]
    q_rows = [model.states.index(s) for s in quaternion.states]
    rest_rows = [i for i in range(model.n) if i not in q_rows]
    upper = np.triu_indices(nt)
    lam = sf.sympy.Lambdify(  # SymForce's symbolic backend (symengine)
        [R.q.w, R.q.x, R.q.y, R.q.z, *rest, *(P[int(i), int(j)] for i, j in zip(*upper)), *u,
         dt],
        [R_new.q.w, R_new.q.x, R_new.q.y, R_new.q.z, *rest_new,
         *(P_new[i, j] for i in range(nt) for j in range(nt))], cse=True)

    def predict(x, P_value, u_value, dt_value):
        x = np.asarray(x, dtype=float)
        out = np.asarray(lam(np.concatenate([x[q_rows], x[rest_rows],
                                             np.asarray(P_value, float)[upper],
                                             np.asarray(u_value, float), [dt_value]])),
                         dtype=float).ravel()
        x_new = np.empty(model.n)
        x_new[q_rows], x_new[rest_rows] = out[:4], out[4:model.n]
        return x_new, out[model.n:].reshape(nt, nt)

    return predict


def derive_count(c_source: str, prefix: str) -> OpCount:
    """derive's predict, ``PREFIX_predict`` in its generated C, counted by the same C rules
    as SymForce's C++ (its fma macros an fma each)."""
    return count_c_text(c_function_body(c_source, f"{prefix}_predict"))


__all__ = ["FLOPS_BAR", "derive_count", "generate", "numeric_predict", "predict_function"]
