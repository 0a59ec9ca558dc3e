"""The time-varying run loop is generic over the unit's carried state: a unit that
carries (x, S) with S = 2 P, enters it from (x0, P0) and stores P = S / 2, runs in the
same templates as the KF and agrees with the textbook KF."""

from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

import numpy as np
import pytest
import sympy
from _backend_kf import cv_axes, dt, kf_unit, q, r, reference_kf, unit_fields

import derive.runs.unit as unit_module
from derive import interface
from derive.build import build_c, load_python
from derive.emit.render import describe, render_files
from derive.emit.write import write_files
from derive.filters.kf import prior
from derive.lowering import lower_program
from derive.program import Port, Program, ProgramError
from derive.runs.unit import Unit, run_arguments

VALUES = {dt: 1, q: sympy.Rational(1, 100), r: sympy.Rational(1, 10)}


def _matrices():
    return [M.subs(VALUES) for M in cv_axes(1)]


def _programs():
    F, W, H, R = _matrices()
    step = Program("step", [Port("x", (2,)), Port("S", (2, 2)), Port("z", (1,))],
                   [Port("x_new", (2,)), Port("S_new", (2, 2))], doc="KF on S = 2 P")
    x, z = step.matrix("x"), step.matrix("z")
    P = step.matrix("S") / 2
    xp, Pp, PHt, S = prior(step, F, W, H, R, x, P)
    K = PHt * S.inv()
    step.set_output("x_new", list(xp + K * (z - H * xp)))
    step.set_output("S_new", list(2 * (Pp - K * PHt.T)))
    enter = Program("enter", [Port("x0", (2,)), Port("P0", (2, 2))],
                    [Port("x", (2,)), Port("S", (2, 2))], doc="S = 2 P0")
    enter.set_output("x", list(enter.matrix("x0")))
    enter.set_output("S", list(2 * enter.matrix("P0")))
    store = Program("store", [Port("x", (2,)), Port("S", (2, 2))], [Port("P_new", (2, 2))],
                    doc="P = S / 2")
    store.set_output("P_new", list(store.matrix("S") / 2))
    return {"step": step.optimize(), "enter": enter.optimize(), "store": store.optimize()}


def _unit(**changes) -> Unit:
    fields = {**unit_fields("kf"), "extra_programs": ("enter", "store"), "run_tracks": False}
    fields.update(changes)
    return Unit(model="toy", filter="skf", n=2, m=1, programs=_programs(),
                carried=(("x", "x_new"), ("S", "S_new")), command="pytest", **fields)


def test_a_factored_state_runs_in_the_time_varying_templates(tmp_path):
    unit = _unit()
    files = render_files(unit)
    assert "toy_skf_enter(x0, P0, x, S);" in files["skf.c"]
    paths = {p.suffix: p for p in write_files(tmp_path, "toy", files)}
    F, W, H, R = (np.array(M, dtype=float) for M in _matrices())
    rng = np.random.default_rng(3)
    zs = rng.normal(size=(40, 1))
    x0, P0 = np.array([0.5, -1.0]), np.array([[2.0, 0.3], [0.3, 1.0]])
    xr, Pr = reference_kf(F, W, H, R, zs, x0, P0)
    for module in (load_python(paths[".py"]), build_c(paths[".c"])):
        xs, Ps = module.run(zs, x0, P0)
        np.testing.assert_allclose(xs, xr, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.reshape(Ps, Pr.shape), Pr, rtol=1e-12, atol=1e-12)


def test_carried_state_needs_its_programs():
    programs = _programs()
    del programs["store"]
    with pytest.raises(ProgramError, match="must have outputs"):
        Unit(model="toy", filter="skf", n=2, m=1, programs=programs,
             carried=(("x", "x_new"), ("S", "S_new")),
             **{**unit_fields("kf"), "extra_programs": ("enter",), "run_tracks": False})
    with pytest.raises(ProgramError, match="run_tracks"):
        _unit(run_tracks=True)


def test_a_run_kind_declares_a_caller_provided_work_array(monkeypatch):
    """A kind entry (here a smoother-like copy of timevarying) declares C run's work
    array by the ports one row holds; run's arguments, the interface and the header's
    machine-readable line carry it, Python's run has none."""
    kinds = dict(unit_module.RUN_KINDS)
    kinds["smoothing"] = replace(kinds["timevarying"], name="smoothing",
                                 work=(("work", ("x_new", "P_new")),), run_tracks=False)
    monkeypatch.setattr(unit_module, "RUN_KINDS", MappingProxyType(kinds))
    step = kf_unit().programs["step"]
    unit = Unit(model="cv", filter="sm", n=2, m=1, programs={"step": step},
                parameters=("dt", "q", "r"),
                **{**unit_fields("kf"), "run_kind": "smoothing", "run_tracks": False})
    args = run_arguments(unit)
    assert [a.c_name for a in args] == ["z", "x0", "P0", "xs", "Ps", "work", "p"]
    work = args[5]
    assert work.dims == ("steps", 6) and work.scratch and work.output
    lowered = {"step": lower_program(step)}
    described = describe(unit.prefix, lowered, args)
    assert "work[steps*6] out" in described.c_lines()[-1]
    assert "work" not in described.python_lines()[-1]
    read = interface.read(" * " + described.block() + "\n */")
    assert [a.scratch for a in read.functions[-1].arguments] == [
        False, False, False, False, False, True, False]
