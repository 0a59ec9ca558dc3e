"""The multi-sensor reference keeps its accuracy where an update cancels.

It judges the generated code, so it must not be the less accurate of the two. The two-sensor
cart with dt = 1e5 s (P(k/k-1) up to 1e13 times P(k/k)) is run by the reference and, for
the truth, by the same Kalman filter in 60-digit arithmetic (mpmath) on the same data:
with ``P - K S K^T`` the reference lost 1e-3 of P and `derive verify` failed the generated
filter (4e-10 from the truth) against it; Joseph's form is within 1e-14.
"""

from __future__ import annotations

import mpmath
import numpy as np
from test_nav_sensors import TWO_SENSORS  # the two-sensor cart of the sensors tests

from derive.apps.verify import relative_error, sensors_case, verify_filter
from derive.modelfile import loads_model
from derive.options import validate

FREE_DT = 'dt = { description = "step, one value per step in p" }'
STEPS = 200
DT = "1e5"


def cart(dt: str):
    return loads_model(TWO_SENSORS.replace(FREE_DT, f"dt = {{ example = {dt} }}"))


def kalman_in_60_digits(args, dt: str, steps: int):
    """The cart's filter (TWO_SENSORS: F, B, Q = q dt I, gps z = p + off, speed z = v) on
    verify's arguments, in 60-digit arithmetic, rounded to double at the end."""
    with mpmath.workdps(60):
        d, q = mpmath.mpf(dt), mpmath.mpf("0.01")
        F = mpmath.matrix([[1, d], [0, 1]])
        B = mpmath.matrix([[d ** 2 / 2, 0], [d, 0]])
        Q = mpmath.matrix([[q * d, 0], [0, q * d]])
        sensors = (("gps", mpmath.matrix([[1, 0]]), mpmath.mpf(4), True),
                   ("speed", mpmath.matrix([[0, 1]]), mpmath.mpf("0.25"), False))
        x = mpmath.matrix([mpmath.mpf(float(v)) for v in args["x0"]])
        P = mpmath.matrix([[mpmath.mpf(float(v)) for v in row] for row in args["P0"]])
        Ps = []
        for k in range(steps):
            u = mpmath.matrix([mpmath.mpf(float(v)) for v in args["u"][k]])
            x, P = F * x + B * u, F * P * F.T + Q
            for name, H, R, offset in sensors:
                z = args[f"z_{name}"][k]
                if np.isnan(z).any():
                    continue
                nu = mpmath.mpf(float(z[0])) - (u[1] if offset else 0) - (H * x)[0]
                S = (H * P * H.T)[0] + R
                K = P * H.T / S
                x, P = x + K * nu, P - K * (H * P)
            Ps.append([[float(P[i, j]) for j in range(2)] for i in range(2)])
    return np.array(Ps)


def test_the_reference_is_accurate_where_the_update_cancels():
    model = cart(DT)
    case = sensors_case(model, "kf", STEPS, 7, validate("kf", {}))
    truth = kalman_in_60_digits(case.arguments(), DT, STEPS)
    cancelled = max(np.abs(step.P_predicted).max() / np.abs(case.reference.Ps[k]).max()
                    for k, step in enumerate(case.trace) if step.P_predicted is not None)
    assert cancelled > 1e12, "the model must cancel for this test"
    assert relative_error(case.reference.Ps, truth) <= 1e-14


def test_verify_passes_the_generated_filter_of_that_model():
    results = verify_filter(cart(DT), "kf", steps=STEPS)
    assert all(v.passed for v in results), [v.line() for v in results]
