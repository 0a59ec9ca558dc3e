"""The catalog model ``ins_gnss`` (derive/catalog/ins_gnss.toml) states SPEC §8: its numbers
agree with the application's (derive.apps.ins.constants), and its f, Fu Qu Fuᵀ + Q and h
agree with the hand-written NumPy reference at random points."""

from __future__ import annotations

import numpy as np
import sympy

from derive import catalog
from derive.apps.ins import constants as c
from derive.apps.ins import reference as ref
from derive.cli import main


def test_sizes_sensors_parameters_and_unit_norm():
    model = catalog.load("ins_gnss")
    assert tuple(model.states) == c.STATES
    assert tuple(u.name for u in model.inputs) == c.INPUTS
    assert [s.name for s in model.sensors] == ["gnss", "baro"]
    assert [len(s.measurements) for s in model.sensors] == [6, 1]
    assert tuple(p.name for p in model.parameters) == ("dt",)
    assert [tuple(group) for group in model.unit_norm] == [("q0", "q1", "q2", "q3")]


def test_numbers_agree_with_spec_constants():
    model = catalog.load("ins_gnss")
    values = {k: float(v) for k, v in model.values.items()}
    assert values["g"] == c.GRAVITY
    assert np.isclose(values["sg2"], c.SIGMA_GYRO ** 2, rtol=1e-15, atol=0)
    assert np.isclose(values["sa2"], c.SIGMA_ACCEL ** 2, rtol=1e-15, atol=0)
    assert np.isclose(values["sbg2"], c.SIGMA_GYRO_BIAS ** 2, rtol=1e-15, atol=0)
    assert np.isclose(values["sba2"], c.SIGMA_ACCEL_BIAS ** 2, rtol=1e-15, atol=0)
    gnss, baro = model.sensors
    assert np.allclose(np.array(gnss.R, dtype=float), np.diag(c.GNSS_STD ** 2),
                       rtol=1e-15, atol=0)
    assert float(baro.R[0, 0]) == c.BARO_STD ** 2
    assert np.array_equal(np.array(model.x0, dtype=float).ravel(), c.X0)
    assert np.allclose(np.array(model.P0, dtype=float), c.p0(), rtol=1e-15, atol=0)


def test_model_equations_agree_with_the_reference():
    model = catalog.load("ins_gnss")
    xs, us = list(model.state_symbols), list(model.inputs)
    (dt,) = model.parameters
    values = {sympy.Symbol(k, real=True): v for k, v in model.values.items()}
    f = sympy.lambdify([xs, us, dt], model.f.subs(values), "numpy")
    fu = sympy.lambdify([xs, us, dt], model.f.subs(values).jacobian(us), "numpy")
    q = sympy.lambdify([dt], model.Q.subs(values), "numpy")
    qu = np.array(model.Qu.subs(values), dtype=float)
    h = {s.name: sympy.lambdify([xs], s.h, "numpy") for s in model.sensors}
    rng = np.random.default_rng(5)
    for _ in range(3):
        quat = rng.normal(size=4)
        x = np.concatenate([quat, rng.normal(size=12)])
        u = rng.normal(size=6)
        step = float(rng.uniform(0.001, 0.05))
        expected = ref.f(x, u, step)
        assert np.allclose(np.ravel(f(x, u, step)), expected, rtol=1e-14, atol=1e-14)
        jac_u = np.array(fu(x, u, step), dtype=float)
        noise = jac_u @ qu @ jac_u.T + np.array(q(step), dtype=float)
        assert np.allclose(noise, ref.process_noise(x, u, step), rtol=1e-13, atol=1e-22)
        assert np.allclose(np.ravel(h["gnss"](x)), ref.h_gnss(x), rtol=0, atol=0)
        assert np.allclose(np.ravel(h["baro"](x)), ref.h_baro(x), rtol=0, atol=0)


def test_derive_check_has_no_paper_claim_for_ins_gnss(capsys):
    # the GNSS paper's claims need its static-receiver scenario; ins_gnss is not that model
    assert main(["check", "ins_gnss"]) == 0
    assert capsys.readouterr().out.strip() == "derive check: 0 passed, 0 failed (1 model)"
