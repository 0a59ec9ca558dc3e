"""derive.apps.running_error against float32 arithmetic: the first-order bound u E of each
output holds for the same program evaluated in float32 (inputs rounded to float32, each
operation rounded, a call computed in double and rounded: a correctly rounded libm), on
many calls at once, and is not vacuous (the error reaches a hundredth of it)."""

from __future__ import annotations

import numpy as np
import pytest
from test_float_sensors import FLOAT_OPTIONS, attitude_data
from test_nav_sensors import attitude

from derive.apps.running_error import port_values, running_errors
from derive.filters.sensors import program_name, reference_run
from derive.generation import command_unit
from derive.lowering import LoweredAssign, LoweredProgram, lower_program
from derive.precision import FLOAT
from derive.program import Port
from derive.trees import Const, Op, Var

CALLS = {"sin": np.sin, "cos": np.cos, "atan2": np.arctan2, "exp": np.exp, "log": np.log,
         "atan": np.arctan, "tan": np.tan}


def in_float32(lowered: LoweredProgram, values: dict) -> dict[str, np.ndarray]:
    """Each output of ``lowered`` computed in float32 from ``values`` rounded to it."""
    env = {name: np.asarray(v, dtype=np.float32) for name, v in values.items()}

    def run(tree):
        if isinstance(tree, Var):
            return env[tree.name]
        if isinstance(tree, Const):
            return np.float32(tree.value)
        args = [run(a) for a in tree.args]
        kind = tree.kind
        if kind.startswith("call:"):
            name = kind[5:]
            if name in ("fabs", "ceil"):
                return np.abs(args[0]) if name == "fabs" else np.ceil(args[0])
            return CALLS[name](*[a.astype(float) for a in args]).astype(np.float32)
        ops = {"add": lambda a, b: a + b, "sub": lambda a, b: a - b,
               "mul": lambda a, b: a * b, "div": lambda a, b: a / b, "neg": lambda a: -a,
               "sqrt": np.sqrt, "fma": lambda a, b, c: a * b + c,
               "fnma": lambda a, b, c: c - a * b,
               "select": lambda z, a, b: np.where(z == z, a, b),  # noqa: PLR0124
               "gate": lambda v, t, a, b: np.where(v <= t, a, b),
               "if_gt": lambda left, right, a, b: np.where(left > right, a, b),
               "if_ge": lambda left, right, a, b: np.where(left >= right, a, b)}
        return ops[kind](*args)

    for statement in lowered.body:
        if isinstance(statement, LoweredAssign):
            env[statement.target] = run(statement.tree)
    return {port: np.stack([np.broadcast_to(run(t), np.shape(next(iter(env.values()))))
                            for t in trees], -1) for port, trees in lowered.results}


def check(lowered: LoweredProgram, values: dict) -> float:
    """The largest ratio of float32's error to the bound u E over every output; asserts
    the bound (up to second order: 1e-3 of it)."""
    errors = {name: np.abs(v) for name, v in values.items()}  # each input rounded once
    bound = running_errors(lowered, values, errors)
    f32 = in_float32(lowered, values)
    worst = 0.0
    for port, (exact, E) in bound.items():
        error = np.abs(f32[port].astype(float) - exact)
        limit = FLOAT.unit_roundoff * E
        assert np.all(error <= 1.001 * limit + 1e-300), port
        with np.errstate(divide="ignore", invalid="ignore"):
            worst = max(worst, float(np.nanmax(np.where(limit > 0, error / limit, 0.0))))
    return worst


def test_the_bound_holds_for_calls_divisions_roots_and_guards():
    rng = np.random.default_rng(4)
    a, b, c = (Var(f"x[{i}]") for i in range(3))
    body = (LoweredAssign("t0", Op("call:atan2", (Op("mul", (a, b)), c))),
            LoweredAssign("t1", Op("div", (Op("call:sin", (a,)), Op("add", (c, Const(3.0)))))),
            LoweredAssign("t2", Op("sqrt", (Op("fma", (a, a, Op("mul", (b, b)))),))),
            LoweredAssign("t3", Op("if_gt", (a, b, Op("call:cos", (Var("t1"),)),
                                             Op("sub", (Var("t2"), Const(0.1)))))))
    lowered = LoweredProgram("f", "", (Port("x", (3,)),), (Port("y", (4,)),), body,
                             (("y", tuple(Var(f"t{i}") for i in range(4))),), True)
    values = port_values("x", rng.uniform(-2.0, 2.0, (4000, 3)))
    assert check(lowered, values) > 0.01


@pytest.mark.parametrize("program", ["predict", "update_mag", "update_bias"])
def test_the_bound_holds_for_each_program_of_a_sensors_ekf(program):
    """The attitude EKF's programs (division, square root for the unit norm, fma, the
    missing-measurement select) at the steps of its reference run where each is called."""
    model = attitude()
    unit = command_unit(model, "ekf", FLOAT_OPTIONS)
    us, dt, zs = attitude_data(300, 1)
    trace: list = []
    reference_run(model, FLOAT_OPTIONS, zs, us, dt, np.array([1.0, 0.0, 0.0]),
                  np.diag([0.01, 0.01, 1e-4]), trace=trace)
    lowered = lower_program(unit.programs[program], use_fma=True, state_ports=("x", "P"))
    if program == "predict":
        calls = {"x": [s.x_before for s in trace], "P": [s.P_before for s in trace],
                 "u": [s.u for s in trace], "p": [s.p for s in trace]}
    else:
        sensor = program[len(program_name("")):]
        rows = [(k, t) for k, s in enumerate(trace) for t in s.updates if t.sensor == sensor]
        calls = {"x": [t.x for _, t in rows], "P": [t.P for _, t in rows],
                 "z": [t.z for _, t in rows], "p": [trace[k].p for k, _ in rows]}
    values = {}
    for port in lowered.inputs:
        values.update(port_values(port.name, np.asarray(calls[port.name], dtype=float)))
    assert check(lowered, values) > 0.01
