"""CasADi's own generated C for the same dense filter step, as a benchmark peer.

The step (KF, SSKF, EKF or UKF, the papers' equations with the model's numbers, every
state and covariance entry symbolic) is built from CasADi SX expressions, emitted by
``casadi.CodeGenerator``, and driven by a small C loop written here (ping-pong buffers,
like derive's run loop), compiled with ``gcc`` and :data:`CFLAGS` and loaded with cffi
(ABI mode).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from .... import riccati
from ..cases import Case, Data, Skip

CFLAGS = ("-O3", "-march=native", "-ffp-contract=fast")
"""CasADi's C has no fma of its own: contraction lets GCC fuse its a*b + c, as GCC's
default GNU C mode does for a user (derive's generated C fuses explicitly and is built
without contraction)."""
NAME = "bench_step"


def _step_function(ca, case: Case, data: Data):
    """The CasADi Function of one step: inputs (x[, P], z[, u]) -> (x_new[, P_new])."""
    n, m = len(data.x0), data.zs[0].shape[1]
    x, z = ca.SX.sym("x", n), ca.SX.sym("z", m)
    if case.filter == "sskf":
        a = data.arrays
        ss = riccati.kf_steady(a["F"], a["G"], a["H"], a["Q"], a["R"])
        return ca.Function(NAME, [x, z], [ca.mtimes(ca.DM(ss.A), x) + ca.mtimes(ca.DM(ss.B), z)])
    P = ca.SX.sym("P", n, n)
    if case.filter == "kf":
        a = data.arrays
        F, H = ca.DM(a["F"]), ca.DM(a["H"])
        xp = ca.mtimes(F, x)
        Pp = ca.mtimes([F, P, F.T]) + ca.DM(a["GQGt"])
        PHt = ca.mtimes(Pp, H.T)
        K = ca.mtimes(PHt, ca.inv(ca.mtimes(H, PHt) + ca.DM(a["R"])))
        x_new = xp + ca.mtimes(K, z - ca.mtimes(H, xp))
        return ca.Function(NAME, [x, P, z], [x_new, Pp - ca.mtimes([K, H, Pp])])
    u = ca.SX.sym("u", data.us.shape[1])
    Q, R = ca.DM(data.arrays["Q"]), ca.DM(data.arrays["R"])
    sats = [u[3 * i:3 * i + 3] for i in range(m)]

    def h(state):
        return ca.vertcat(*[ca.norm_2(s - state[:3]) + state[3] for s in sats])

    Pp = P + Q
    if case.filter == "ekf":
        y = h(x)
        Hj = ca.jacobian(y, x)
        K = ca.mtimes([Pp, Hj.T, ca.inv(ca.mtimes([Hj, Pp, Hj.T]) + R)])
        return ca.Function(NAME, [x, P, z, u], [x + ca.mtimes(K, z - y),
                                                Pp - ca.mtimes([K, Hj, Pp])])
    c = 3.0                                   # n + kappa = 3, kappa = 3 - n (the GNSS paper)
    w0, wi = (c - n) / c, 1.0 / (2.0 * c)
    L = ca.chol(c * Pp)                       # upper: L^T L = c (P + Q)
    points = [x] + [x + L[i, :].T for i in range(n)] + [x - L[i, :].T for i in range(n)]
    weights = [w0] + [wi] * (2 * n)
    Y = [h(p) for p in points]
    y = sum(w * yi for w, yi in zip(weights, Y))
    Pvv = R + sum(w * ca.mtimes(yi - y, (yi - y).T) for w, yi in zip(weights, Y))
    Pxy = sum(w * ca.mtimes(p - x, (yi - y).T) for w, p, yi in zip(weights, points, Y))
    K = ca.mtimes(Pxy, ca.inv(Pvv))
    return ca.Function(NAME, [x, P, z, u], [x + ca.mtimes(K, z - y),
                                            Pp - ca.mtimes([K, Pvv, K.T])])


_DRIVER = """\
#include <string.h>
#include "{name}.h"
int casadi_run(long steps, const double *zs, const double *us, const double *x0,
               const double *P0, double *xs)
{{
    static casadi_int iw[{sz_iw} + 1];
    static double w[{sz_w} + 1];
    const double *arg[{sz_arg} + 1];
    double *res[{sz_res} + 1];
    static double P_work[2][{n} * {n} + 1];
    const double *x = x0;
    const double *P = P0;
    long k;
    (void)us; (void)P;
    for (k = 0; k < steps; ++k) {{
        double *P_next = P_work[k % 2];
        int i = 0;
        arg[i++] = x;
        {arg_P}
        arg[i++] = zs + k * {m};
        {arg_u}
        res[0] = xs + k * {n};
        {res_P}
        if ({name}(arg, res, iw, w, 0)) return 1;
        x = xs + k * {n};
        {next_P}
    }}
    return 0;
}}
"""


def build(case: Case, data: Data, workdir: Path):
    """Generate, compile and load CasADi's C for the case; returns (ffi, lib)."""
    try:
        import casadi as ca
        import cffi
    except ImportError as exc:
        raise Skip(f"{exc.name} is not installed") from None
    fn = _step_function(ca, case, data)
    folder = workdir / f"casadi_{case.filter}_{case.model}"
    folder.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{NAME}.c", {"with_header": True})
    cg.add(fn)
    cg.generate(str(folder) + "/")
    has_P = case.filter != "sskf"
    driver = _DRIVER.format(
        name=NAME, n=len(data.x0), m=data.zs[0].shape[1], sz_iw=fn.sz_iw(), sz_w=fn.sz_w(),
        sz_arg=fn.sz_arg(), sz_res=fn.sz_res(),
        arg_P="arg[i++] = P;" if has_P else "",
        arg_u=f"arg[i++] = us + k * {data.us.shape[1]};" if case.nonlinear else "",
        res_P="res[1] = P_next;" if has_P else "",
        next_P="P = P_next;" if has_P else "")
    (folder / "driver.c").write_text(driver)
    library = folder / "libbench.so"
    cmd = ["gcc", *CFLAGS, "-shared", "-fPIC", "-o", str(library), str(folder / f"{NAME}.c"),
           str(folder / "driver.c"), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise Skip(f"gcc failed on CasADi's C: {proc.stderr.strip().splitlines()[-1]}")
    ffi = cffi.FFI()
    ffi.cdef("int casadi_run(long steps, const double *zs, const double *us, "
             "const double *x0, const double *P0, double *xs);")
    return ffi, ffi.dlopen(str(library))


def casadi_c(case: Case, data: Data, workdir: Path):
    ffi, lib = build(case, data, workdir)
    n = len(data.x0)
    x0 = ffi.from_buffer("double[]", np.ascontiguousarray(data.x0, dtype=float))
    P0 = ffi.from_buffer("double[]", np.ascontiguousarray(data.P0, dtype=float))
    us = ffi.from_buffer("double[]", data.us if data.us is not None else np.zeros(1))
    outputs = [np.empty((data.steps, n)) for _ in data.zs]
    calls = [(ffi.from_buffer("double[]", z), ffi.from_buffer("double[]", out))
             for z, out in zip(data.zs, outputs)]

    def run(steps):
        for z, out in calls:
            if lib.casadi_run(steps, z, us, x0, P0, out):
                raise ArithmeticError("CasADi's step failed")
        return outputs
    return run
