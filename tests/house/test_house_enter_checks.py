"""A unit whose carried state is started by an ``enter`` program (the UD filter's seam):
enter checks run's start arguments itself, so run adds no check of its own (the step's
pattern checks are about the carried state, not about P0), and a pattern status of enter
returned by run is read back as PatternError naming P0 (derive.build.status_error), in
Python and in C. The header's "P0 accepted" line is read from enter's checks of P0."""

from __future__ import annotations

import numpy as np
import pytest
from _backend_kf import reference_kf, unit_fields
from test_house_carried import _matrices

from derive.build import build_c, load_python
from derive.emit.render import render_files
from derive.emit.write import write_files
from derive.errors import PatternError
from derive.filters.kf import prior
from derive.filters.unit import accepted_P0
from derive.program import Port, Program
from derive.runs.unit import Unit

MESSAGE = "P has a non-zero entry outside the pattern of this toy"


def _programs():
    """The S = 2 P toy of test_house_carried, with a zero check on the step's S[0][1] and
    on enter's P0[0][1] (P0 must be diagonal)."""
    F, W, H, R = _matrices()
    step = Program("step", [Port("x", (2,)), Port("S", (2, 2)), Port("z", (1,))],
                   [Port("x_new", (2,)), Port("S_new", (2, 2))], doc="KF on S = 2 P")
    step.require_zero(step.element("S", 0, 1), "S has a non-zero entry outside the toy's")
    x, z = step.matrix("x"), step.matrix("z")
    xp, Pp, PHt, S = prior(step, F, W, H, R, x, step.matrix("S") / 2)
    K = PHt * S.inv()
    step.set_output("x_new", list(xp + K * (z - H * xp)))
    step.set_output("S_new", list(2 * (Pp - K * PHt.T)))
    enter = Program("enter", [Port("x0", (2,)), Port("P0", (2, 2))],
                    [Port("x", (2,)), Port("S", (2, 2))], doc="S = 2 P0, P0 diagonal")
    enter.require_zero(enter.element("P0", 0, 1), MESSAGE)
    enter.set_output("x", list(enter.matrix("x0")))
    P0 = enter.matrix("P0")
    P0[0, 1] = P0[1, 0] = 0
    enter.set_output("S", list(2 * P0))
    store = Program("store", [Port("x", (2,)), Port("S", (2, 2))], [Port("P_new", (2, 2))],
                    doc="P = S / 2")
    store.set_output("P_new", list(store.matrix("S") / 2))
    return {"step": step.optimize(), "enter": enter.optimize(), "store": store.optimize()}


def test_enter_checks_p0_and_run_reports_its_pattern_status(tmp_path):
    unit = Unit(model="toy", filter="dkf", n=2, m=1, programs=_programs(),
                carried=(("x", "x_new"), ("S", "S_new")), command="pytest",
                **{**unit_fields("kf"), "extra_programs": ("enter", "store"), "run_tracks": False})
    paths = {p.suffix: p for p in write_files(tmp_path, "toy", render_files(unit))}
    F, W, H, R = (np.array(M, dtype=float) for M in _matrices())
    zs = np.random.default_rng(5).normal(size=(30, 1))
    x0, P0 = np.array([0.5, -1.0]), np.diag([2.0, 1.0])
    xr, Pr = reference_kf(F, W, H, R, zs, x0, P0)
    coupled = np.array([[2.0, 0.25], [0.25, 1.0]])
    for module in (load_python(paths[".py"]), build_c(paths[".c"])):
        xs, Ps = module.run(zs, x0, P0)  # the loop's S is coupled: no step check in run
        np.testing.assert_allclose(xs, xr, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.reshape(Ps, Pr.shape), Pr, rtol=1e-12, atol=1e-12)
        with pytest.raises(PatternError, match=r"P0\[0\]\[1\] = 0\.25.*pattern of this toy"):
            module.run(zs, x0, coupled)


def test_the_accepted_line_reads_enters_checks_of_p0():
    line = accepted_P0(_programs()["enter"], "P0")
    assert line.startswith("P0 accepted: exactly those zero outside P's pattern x.|.x")


def test_a_one_state_p0_is_entered_flat_in_python(tmp_path):
    """n = 1: run's P0 of shape (1, 1) reaches enter flattened (not as a track axis)."""
    step = Program("step", [Port("x", (1,)), Port("S", (1, 1)), Port("z", (1,))],
                   [Port("x_new", (1,)), Port("S_new", (1, 1))], doc="scalar KF on S = 2 P")
    x, P, z = step.matrix("x")[0], step.matrix("S")[0] / 2, step.matrix("z")[0]
    Pp = P + 1
    gain = Pp / (Pp + 1)
    step.set_output("x_new", [x + gain * (z - x)])
    step.set_output("S_new", [2 * (Pp - gain * Pp)])
    enter = Program("enter", [Port("x0", (1,)), Port("P0", (1, 1))],
                    [Port("x", (1,)), Port("S", (1, 1))], doc="S = 2 P0")
    enter.set_output("x", list(enter.matrix("x0")))
    enter.set_output("S", [2 * enter.matrix("P0")[0]])
    store = Program("store", [Port("x", (1,)), Port("S", (1, 1))], [Port("P_new", (1, 1))],
                    doc="P = S / 2")
    store.set_output("P_new", [store.matrix("S")[0] / 2])
    unit = Unit(model="toy", filter="one", n=1, m=1,
                programs={"step": step.optimize(), "enter": enter.optimize(),
                          "store": store.optimize()},
                carried=(("x", "x_new"), ("S", "S_new")), command="pytest",
                **{**unit_fields("kf"), "extra_programs": ("enter", "store"), "run_tracks": False})
    paths = {p.suffix: p for p in write_files(tmp_path, "toy", render_files(unit))}
    zs = np.array([[1.0], [2.0], [0.5]])
    one = np.ones((1, 1))
    xr, Pr = reference_kf(one, one, one, one, zs, np.zeros(1), 2 * one)
    xs, Ps = load_python(paths[".py"]).run(zs, np.zeros(1), 2 * one)
    assert xs.shape == (3, 1) and Ps.shape == (3, 1, 1)
    np.testing.assert_allclose(xs, xr, rtol=1e-14)
    np.testing.assert_allclose(Ps, Pr, rtol=1e-14)
