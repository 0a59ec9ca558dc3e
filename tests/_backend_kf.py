"""A minimal Kalman-filter derivation on the backend API, and a NumPy reference, for the
backend's own tests (the real derivations live in derive/filters/)."""

from __future__ import annotations

import numpy as np
import sympy

from derive import staging
from derive.filters import kind as filter_spec
from derive.filters.kf import prior
from derive.program import Port, Program
from derive.runs.unit import Unit

# real, no declared domain: the backend tests count and check the filter alone
dt, q, r = sympy.symbols("dt q r", real=True)


def unit_fields(name: str, window: int | None = None) -> dict:
    """The Unit fields the registry's spec of filter ``name`` decides."""
    return filter_spec(name).unit_fields(window=window)


def cv_axes(axes: int = 1):
    """Constant-velocity axes, block diagonal: F, GQG^T, H, R with symbols dt, q, r."""
    F1 = sympy.Matrix([[1, dt], [0, 1]])
    W1 = q * sympy.Matrix([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    H1 = sympy.Matrix([[1, 0]])
    F = sympy.diag(*[F1] * axes)
    W = sympy.diag(*[W1] * axes)
    H = sympy.diag(*[H1] * axes)
    R = r * sympy.eye(axes)
    return F, W, H, R


def kf_program(F, W, H, R, parameters=(dt, q, r)) -> Program:
    """One KF step (predict, then update) staged with derive.staging."""
    n, m = F.rows, H.rows
    inputs = [Port("x", (n,), doc="x(k/k)"), Port("P", (n, n), symmetric=True, doc="P(k/k)"),
              Port("z", (m,), doc="z(k+1)")]
    if parameters:
        inputs.append(Port("p", (len(parameters),), doc="dt, q, r"))
    prog = Program("step", inputs,
                   [Port("x_new", (n,)), Port("P_new", (n, n), symmetric=True)],
                   doc="One Kalman filter step.")
    bind = prog.bind("p", parameters) if parameters else {}
    F, W, H, R = (staging.let_matrix(prog, M.xreplace(bind)) for M in (F, W, H, R))
    x, P, z = prog.matrix("x"), prog.matrix("P"), prog.matrix("z")
    xp, Pp, PHt, S = prior(prog, F, W, H, R, x, P)
    K = staging.transpose(staging.spd_solve(prog, S, staging.transpose(PHt)))
    innovation = staging.sub(prog, z, staging.matmul(prog, H, xp))
    prog.set_output("x_new", staging.add(prog, xp, staging.matmul(prog, K, innovation)))
    KPHt = staging.matmul(prog, K, staging.transpose(PHt), symmetric_result=True)
    prog.set_output("P_new", staging.sub(prog, Pp, KPHt, symmetric_result=True))
    return prog


def kf_unit(model: str = "cv", axes: int = 1, command: str = "pytest backend") -> Unit:
    F, W, H, R = cv_axes(axes)
    step = kf_program(F, W, H, R).optimize()
    return Unit(model=model, filter="kf", **unit_fields("kf"), n=F.rows, m=H.rows,
                programs={"step": step}, parameters=("dt", "q", "r"),
                facts=("test: backend example",), command=command)


def numeric(M, values) -> np.ndarray:
    return np.array(M.subs(values).evalf(), dtype=float)


def reference_kf(F, W, H, R, zs, x0, P0):
    """Textbook KF with explicit inverses (independent of the generated code)."""
    x, P = np.array(x0, float), np.array(P0, float)
    xs, Ps = [], []
    for z in zs:
        x = F @ x
        P = F @ P @ F.T + W
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (z - H @ x)
        P = (np.eye(len(x)) - K @ H) @ P
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)


STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def gcc_strict(c_file, *extra):
    """Compile one generated C file with the strict flags; returns the completed process."""
    import subprocess

    return subprocess.run(["gcc", *STRICT, *extra, "-c", str(c_file), "-o",
                           str(c_file) + ".o"], capture_output=True, text=True)


# -- one small unit per family, with a NumPy reference run ---------------------------

A_SS = sympy.Matrix([[sympy.Rational(9, 10), sympy.Rational(1, 5)], [0, sympy.Rational(4, 5)]])
B_SS = sympy.Matrix([[sympy.Rational(1, 10)], [sympy.Rational(1, 4)]])


def _steady_step(params: bool) -> Program:
    inputs = [Port("x", (2,)), Port("z", (1,))] + ([Port("p", (1,))] if params else [])
    prog = Program("step", inputs, [Port("x_new", (2,))], doc="x_new = A x + B z (g z)")
    z = prog.matrix("z")
    if params:
        z = staging.scale(prog, z, prog.element("p", 0))
    prog.set_output("x_new", staging.add(prog, staging.matmul(prog, A_SS, prog.matrix("x")),
                                         staging.matmul(prog, B_SS, z)))
    return prog.optimize()


def steady_unit(family: str = "sskf", params: bool = False) -> Unit:
    return Unit(model="toy", filter=family, **unit_fields(family), n=2, m=1,
                programs={"step": _steady_step(params)},
                parameters=("g",) if params else (), command="pytest")


def steady_reference(zs, x0, g=1.0):
    A, B = numeric(A_SS, {}), numeric(B_SS, {})
    x, out = np.array(x0, float), []
    for z in zs:
        x = A @ x + B @ (g * np.atleast_1d(z))
        out.append(x)
    return np.array(out)


WINDOW = 3


def fir_unit() -> Unit:
    prog = Program("step", [Port("zw", (WINDOW, 1))], [Port("x_new", (2,))],
                   doc="x = sum_i A^i B z(k-i)")
    zw = prog.matrix("zw")
    taps = [A_SS**i * B_SS for i in range(WINDOW)]
    total = sympy.zeros(2, 1)
    for i, C in enumerate(taps):
        total = staging.add(prog, total, staging.matmul(prog, C, zw[i, :].T))
    prog.set_output("x_new", total)
    return Unit(model="toy", filter="fir", **unit_fields("fir", WINDOW), n=2, m=1,
                programs={"step": prog.optimize()}, options={"window": WINDOW},
                command="pytest")


def fir_reference(zs):
    A, B = numeric(A_SS, {}), numeric(B_SS, {})
    taps = [np.linalg.matrix_power(A, i) @ B for i in range(WINDOW)]
    return np.array([sum(taps[i] @ zs[k - i] for i in range(WINDOW) if k - i >= 0)
                     for k in range(len(zs))])


def pred_unit() -> Unit:
    init = Program("init", [Port("x0", (2,))], [Port("x_new", (2,))], doc="x(N/0) = A^2 x0")
    init.set_output("x_new", staging.matmul(init, A_SS**2, init.matrix("x0")))
    return Unit(model="toy", filter="pred", **unit_fields("pred"), n=2, m=1,
                programs={"init": init.optimize(), "step": _steady_step(False)},
                options={"horizon": 2}, command="pytest")


def pred_reference(zs, x0):
    A = numeric(A_SS, {})
    return steady_reference(zs, np.linalg.matrix_power(A, 2) @ np.array(x0, float))


def ekf_like_unit() -> Unit:
    """A time-varying unit with a second per-step input u (x(k+1/k) = F x + u)."""
    F, W, H, R = (M.subs({dt: 1, q: sympy.Rational(1, 100), r: sympy.Rational(1, 10)})
                  for M in cv_axes(1))
    prog = Program("step", [Port("x", (2,)), Port("P", (2, 2), symmetric=True),
                            Port("z", (1,)), Port("u", (2,))],
                   [Port("x_new", (2,)), Port("P_new", (2, 2), symmetric=True)])
    xp = staging.add(prog, staging.matmul(prog, F, prog.matrix("x")), prog.matrix("u"))
    Pp = staging.add(prog, staging.matmul(prog, staging.matmul(prog, F, prog.matrix("P")), F.T,
                                          symmetric_result=True), W, symmetric_result=True)
    PHt = staging.matmul(prog, Pp, H.T)
    S = staging.add(prog, staging.matmul(prog, H, PHt), R)
    K = staging.transpose(staging.spd_solve(prog, S, PHt.T))
    inn = staging.sub(prog, prog.matrix("z"), staging.matmul(prog, H, xp))
    prog.set_output("x_new", staging.add(prog, xp, staging.matmul(prog, K, inn)))
    prog.set_output("P_new", staging.sub(prog, Pp, staging.matmul(prog, K, PHt.T,
                                                                 symmetric_result=True),
                                         symmetric_result=True))
    return Unit(model="toy", filter="ekf", **unit_fields("ekf"), n=2, m=1,
                programs={"step": prog.optimize()}, step_inputs=("z", "u"), command="pytest")


def ekf_like_reference(zs, us, x0, P0):
    F, W, H, R = (numeric(M, {dt: 1, q: 0.01, r: 0.1}) for M in cv_axes(1))
    x, P, xs, Ps = np.array(x0, float), np.array(P0, float), [], []
    for z, u in zip(zs, us):
        x, P = F @ x + u, F @ P @ F.T + W
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x, P = x + K @ (z - H @ x), P - K @ H @ P
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)
