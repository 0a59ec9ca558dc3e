"""CasADi's generated C for the INS/GNSS EKF's predict and updates (a benchmark peer).

The same equations as derive.apps.ins.reference (docs/navigation.md), built from CasADi SX
expressions with CasADi's symbolic Jacobians and inverse; P is read symmetric (entry (i, j)
is the symbol of (min(i, j), max(i, j)), derive's upper-triangle read), and the quaternion
is renormalised after each update and at the start of predict (as derive's predict).
``casadi.CodeGenerator`` emits one C file holding the three functions ``predict(x, P, u,
dt)``, ``update_gnss(x, P, z)`` and ``update_baro(x, P, z)``, each returning (x_new,
P_new).
"""

from __future__ import annotations

from pathlib import Path

from derive.apps.ins import constants as c

FUNCTIONS = ("predict", "update_gnss", "update_baro")

N = 16
GNSS_ROWS = (7, 8, 9, 4, 5, 6)
"""The rows of x that the GNSS measures (p, then v)."""
BARO_ROW = 9
"""The row of x whose negative the barometer measures."""


def _symmetric(ca, name: str):
    upper = ca.SX.sym(name, N, N)
    out = ca.SX(N, N)
    for i in range(N):
        for j in range(N):
            out[i, j] = upper[min(i, j), max(i, j)]
    return upper, out


def _predict(ca):
    x, u, dt = ca.SX.sym("x", N), ca.SX.sym("u", 6), ca.SX.sym("dt")
    P_in, P = _symmetric(ca, "P")
    q0, q1, q2, q3 = (x[i] for i in range(4))
    w = [u[i] - x[10 + i] for i in range(3)]
    a = ca.vertcat(*[u[3 + i] - x[13 + i] for i in range(3)])
    r = [1, w[0] * dt / 2, w[1] * dt / 2, w[2] * dt / 2]
    quat = [q0 * r[0] - q1 * r[1] - q2 * r[2] - q3 * r[3],
            q0 * r[1] + q1 * r[0] + q2 * r[3] - q3 * r[2],
            q0 * r[2] - q1 * r[3] + q2 * r[0] + q3 * r[1],
            q0 * r[3] + q1 * r[2] - q2 * r[1] + q3 * r[0]]
    rot = ca.vertcat(
        ca.horzcat(1 - 2 * (q2 ** 2 + q3 ** 2), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)),
        ca.horzcat(2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 ** 2 + q3 ** 2), 2 * (q2 * q3 - q0 * q1)),
        ca.horzcat(2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 ** 2 + q2 ** 2)))
    accel = ca.mtimes(rot, a) + ca.DM([0.0, 0.0, c.GRAVITY])
    x_new = ca.vertcat(*quat, x[4:7] + accel * dt, x[7:10] + x[4:7] * dt, x[10:16])
    F, Fu = ca.jacobian(x_new, x), ca.jacobian(x_new, u)
    Qu = ca.diag(ca.DM([c.SIGMA_GYRO ** 2] * 3 + [c.SIGMA_ACCEL ** 2] * 3))
    walk = ca.diag(ca.vertcat(ca.DM.zeros(10), c.SIGMA_GYRO_BIAS ** 2 * dt * ca.DM.ones(3),
                              c.SIGMA_ACCEL_BIAS ** 2 * dt * ca.DM.ones(3)))
    P_new = ca.mtimes([F, P, F.T]) + ca.mtimes([Fu, Qu, Fu.T]) + walk
    at = ca.Function("at", [x, P_in, u, dt], [x_new, P_new])
    # f, F, Fu and Q taken at x with q renormalised, as derive's predict (which uses |q| = 1)
    x_in = ca.SX.sym("x", N)
    unit = ca.vertcat(x_in[0:4] / ca.norm_2(x_in[0:4]), x_in[4:])
    return ca.Function("predict", [x_in, P_in, u, dt], at(unit, P_in, u, dt))


def _update(ca, name: str, rows: tuple[int, ...], variances, sign: float = 1.0):
    x = ca.SX.sym("x", N)
    z = ca.SX.sym("z", len(rows))
    P_in, P = _symmetric(ca, "P")
    h = ca.vertcat(*[sign * x[k] for k in rows])
    H = ca.jacobian(h, x)
    S = ca.mtimes([H, P, H.T]) + ca.diag(ca.DM(list(variances)))
    K = ca.mtimes([P, H.T, ca.inv(S)])
    x_new = x + ca.mtimes(K, z - h)
    x_new = ca.vertcat(x_new[0:4] / ca.norm_2(x_new[0:4]), x_new[4:])
    return ca.Function(name, [x, P_in, z], [x_new, P - ca.mtimes([K, H, P])])


def functions():
    """name -> casadi.Function."""
    import casadi as ca  # optional: a benchmark peer

    return {"predict": _predict(ca),
            "update_gnss": _update(ca, "update_gnss", GNSS_ROWS, c.GNSS_STD ** 2),
            "update_baro": _update(ca, "update_baro", (BARO_ROW,), [c.BARO_STD ** 2], -1.0)}


def generate(folder: Path, name: str = "ins_casadi") -> tuple[Path, dict]:
    """Write CasADi's C of the three functions into folder/NAME.c (with its header); returns
    the C file and the functions."""
    import casadi as ca

    fns = functions()
    folder.mkdir(parents=True, exist_ok=True)
    generator = ca.CodeGenerator(f"{name}.c", {"with_header": True})
    for fn in fns.values():
        generator.add(fn)
    generator.generate(str(folder) + "/")
    return folder / f"{name}.c", fns
