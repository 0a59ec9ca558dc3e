"""Manifold states and the error-state EKF (derive.manifolds, derive.filters.eskf): the
declarations and their refusals, the manifold maps against finite differences, the reset
Jacobian against Solà's formula, a small model with a global-error quaternion and an angle
generated and run against derive.reference.eskf, and the catalog's ins_eskf (generated/)
over a 30 s flight against the error-state EKF written by hand from Solà's kinematics,
with its estimate inside its 3σ (the 10-seed figure is the report's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import interface, manifolds
from derive.apps.ins import error_state, flight
from derive.apps.verify import relative_error, sensors_case
from derive.build import load_python
from derive.catalog import load as load_catalog
from derive.cli import main
from derive.errors import ModelError
from derive.filters import FILTERS, why_not
from derive.filters.eskf import reset_jacobian
from derive.model import NonlinearModel
from derive.options import validate
from derive.pipeline import load_generated
from derive.reference.eskf import quaternion_reset

GENERATED = Path(__file__).resolve().parents[2] / "generated" / "ins_eskf"
QUATERNION = {"quaternion": ["q0", "q1", "q2", "q3"]}
F_GYRO = ["q0 - q1*wx*dt/2 - q2*wy*dt/2 - q3*wz*dt/2",
          "q1 + q0*wx*dt/2 + q2*wz*dt/2 - q3*wy*dt/2",
          "q2 + q0*wy*dt/2 - q1*wz*dt/2 + q3*wx*dt/2",
          "q3 + q0*wz*dt/2 + q1*wy*dt/2 - q2*wx*dt/2"]
DOWN = ["2*(q1*q3 - q0*q2)", "2*(q2*q3 + q0*q1)", "1 - 2*(q1**2 + q2**2)"]


def attitude_and_heading(manifolds_declared=None, **changes) -> NonlinearModel:
    """A quaternion driven by a gyro (global error) and an angle driven by a rate that
    wraps it every few steps; gravity's direction in the body and the angle measured."""
    arguments = dict(
        name="ah", states=["q0", "q1", "q2", "q3", "psi"],
        measurements=["gx", "gy", "gz", "zpsi"],
        f=F_GYRO + ["psi + r*dt*30"], h=DOWN + ["psi"], inputs=["wx", "wy", "wz", "r"],
        Q=np.diag([1e-8] * 3 + [1e-6]), Qu=np.diag([1e-4] * 3 + [1e-4]),
        R=np.diag([1e-3] * 3 + [1e-2]), values={"dt": 0.01}, x0=[1, 0, 0, 0, 3.0],
        P0=np.diag([0.01] * 3 + [0.01]),
        manifolds=manifolds_declared if manifolds_declared is not None else [
            {**QUATERNION, "error": "global"}, {"angle": "psi"}])
    return NonlinearModel(**{**arguments, **changes})


@pytest.mark.parametrize("declared, words", [
    ([{"quaternion": ["q1", "q2", "q3"]}], "a quaternion has 4 components"),
    ([{"quaternion": ["q0", "q1", "q2", "qx"]}], "names 'qx', which is not a state"),
    ([QUATERNION, {"angle": "q2"}], "manifolds[1] (angle): state 'q2' is already in"),
    ([{**QUATERNION, "error": "body"}], "error must be one of local, global"),
    ([{**QUATERNION, "angle": "psi"}], "exactly one of the keys quaternion, angle"),
])
def test_bad_declarations_name_the_component(declared, words):
    with pytest.raises(ModelError, match=None) as caught:
        attitude_and_heading(declared)
    assert words in str(caught.value)
    assert "\n" not in str(caught.value)


def test_a_quaternion_in_unit_norm_or_off_unit_norm_is_refused():
    with pytest.raises(ModelError, match="'q0' is in a manifold component"):
        attitude_and_heading(unit_norm=[["q0", "q1", "q2", "q3"]])
    with pytest.raises(ModelError, match="must have unit norm, got 2.0"):
        attitude_and_heading(x0=[2, 0, 0, 0, 0])


def test_bad_declaration_in_a_model_file_is_one_line_exit_2(tmp_path, capsys):
    text = (Path(__file__).resolve().parents[2] / "derive" / "catalog" / "ins_eskf.toml"
            ).read_text().replace('quaternion = ["q0", "q1", "q2", "q3"]',
                                  'quaternion = ["q0", "q1", "q2"]')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["generate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manifolds[0]: a quaternion has 4 components" in err[0], err
    assert not (tmp_path / "out").exists()


def test_every_other_filter_refuses_a_manifold_model_and_eskf_a_plain_one():
    model = attitude_and_heading()
    assert model.n == 5 and model.n_tangent == 4 and model.tangent == ("dq1", "dq2", "dq3",
                                                                       "psi")
    assert why_not(model, "eskf") is None
    for name, spec in FILTERS.items():
        if name != "eskf" and spec.model_kind == "nonlinear":
            reason = why_not(model, name)
            assert reason is not None and "does not handle manifold states" in reason, name
    assert "declares none" in why_not(load_catalog("ins_gnss"), "eskf")


@pytest.mark.parametrize("error", ["local", "global"])
def test_manifold_maps_are_the_derivatives_of_the_injection(error):
    layout = attitude_and_heading([{**QUATERNION, "error": error}, {"angle": "psi"}]).layout
    rng = np.random.default_rng(3)
    q = rng.standard_normal(4)
    x = np.concatenate([q / np.linalg.norm(q), [3.1]])
    N, M = manifolds.retraction_numeric(layout, x), manifolds.lift_numeric(layout, x)
    h = 1e-6
    for t in range(layout.n_tangent):
        step = np.zeros(layout.n_tangent)
        step[t] = h
        fd = (manifolds.boxplus_numeric(layout, x, step)
              - manifolds.boxplus_numeric(layout, x, -step)) / (2 * h)
        assert np.allclose(fd, N[:, t], atol=1e-8)
        moved = manifolds.boxplus_numeric(layout, x, step * 1e3)
        assert np.allclose(manifolds.boxminus_numeric(layout, moved, x), step * 1e3,
                           atol=1e-8)
    assert np.allclose(M @ N, np.eye(layout.n_tangent), atol=1e-15)
    # M of a prediction off the unit sphere: the derivative of the error of its projection
    y = x * np.array([1.01] * 4 + [1.0])
    M = manifolds.lift_numeric(layout, y)
    ref = manifolds.project_numeric(layout, y)
    for i in range(4):
        step = np.zeros(5)
        step[i] = h
        fd = (manifolds.boxminus_numeric(layout, manifolds.project_numeric(layout, y + step),
                                         ref)
              - manifolds.boxminus_numeric(layout, manifolds.project_numeric(layout, y - step),
                                           ref)) / (2 * h)
        assert np.allclose(fd, M[:, i], atol=1e-8)


@pytest.mark.parametrize("error", ["local", "global"])
def test_reset_jacobian_is_solas_over_the_norm_of_the_increment(error):
    layout = attitude_and_heading([{**QUATERNION, "error": error}]).layout
    d = sympy.symbols("a b c", real=True)
    G = sympy.lambdify([d], reset_jacobian(layout, list(d) + [0]), "numpy")
    for delta in np.random.default_rng(5).normal(0, 0.3, (4, 3)):
        expected = np.eye(4)
        expected[:3, :3] = quaternion_reset(delta, local=error == "local")
        assert np.allclose(np.asarray(G(delta), float), expected, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("rows", ["scalar", "vector"])
def test_quaternion_and_angle_model_against_its_reference(tmp_path, rows):
    """Global-error quaternion and a wrapping angle, with the reset: the generated Python
    against derive.reference.eskf (run kind sensors, 300 steps), 1e-12; with either
    option rows (at n_tangent 4 every chunk of the vector form is read in part: scalar
    statements; ins_eskf's predict is vector rows, checked below)."""
    model = attitude_and_heading()
    options = validate("eskf", {"reset": True, "rows": rows})
    generated = load_generated(model, "eskf", options, "python", tmp_path)
    case = sensors_case(model, "eskf", 300, 7, options)
    assert np.ptp(case.run.truth[:, 4]) > 6.0  # the angle wraps
    xs, Ps = generated.python.run(*case.arguments().values())
    assert np.abs(np.asarray(xs)[:, 4]).max() <= np.pi
    assert relative_error(np.asarray(xs), case.reference.xs) <= 1e-12
    assert relative_error(np.asarray(Ps).reshape(300, 4, 4), case.reference.Ps) <= 1e-12
    assert np.allclose(np.linalg.norm(np.asarray(xs)[:, :4], axis=1), 1, rtol=0, atol=4e-16)


@pytest.fixture(scope="module")
def short_flight():
    fl = flight.simulate(seed=0, duration=30.0)
    module = load_python(GENERATED / "eskf.py")
    return fl, error_state.generated_run(module, fl), error_state.run(fl)


def test_ins_eskf_equals_the_error_state_ekf_from_solas_kinematics(short_flight):
    """The generated ins_eskf (its predict as vector rows over the 15 tangent rows, x of 16
    entries; its updates scalar rows) against Solà's kinematics, 1e-12."""
    text = (GENERATED / "eskf.h").read_text()
    assert "vector rows (rows = vector): predict computed in chunks" in text
    fl, (xs, Ps), ref = short_flight
    scale = np.maximum(np.abs(ref.xs).max(axis=0), 1e-2)
    assert (np.abs(xs - ref.xs).max(axis=0) / scale).max() <= 1e-12
    sd = np.sqrt(np.diagonal(ref.Ps, axis1=1, axis2=2))
    assert (np.abs(Ps - ref.Ps) / (sd[:, :, None] * sd[:, None, :])).max() <= 1e-12
    assert np.abs(np.linalg.norm(xs[:, :4], axis=1) - 1).max() < 4 * np.finfo(float).eps


def test_ins_eskf_estimate_inside_its_three_sigma(short_flight):
    fl, (xs, Ps), _ = short_flight
    inside = error_state.inside_steps(error_state.error_state(fl, xs),
                                      np.sqrt(np.diagonal(Ps, axis1=1, axis2=2)))
    for name, steps in inside.items():
        assert steps.mean() >= 0.99, (name, steps.mean())


def test_interface_says_which_arrays_are_storage_and_which_tangent():
    described = interface.read((GENERATED / "eskf.h").read_text())
    assert described.spaces == {"storage": 16, "tangent": 15}
    run = next(f for f in described.functions if f.program == "run")
    spaces = {a.name: (a.space, a.dims) for a in run.arguments}
    assert spaces["x0"] == ("storage", (16,)) and spaces["P0"] == ("tangent", (15, 15))
    assert spaces["xs"] == ("storage", ("steps", 16))
    assert spaces["Ps"] == ("tangent", ("steps", 15, 15))
    assert spaces["z_gnss"][0] == ""
    assert "P0[15*15] tangent" in (GENERATED / "eskf.h").read_text()


def test_symforce_rot3_predict_is_the_function_eskf_computes():
    """The flops peer of ins_fc24_eskf's predict (SymForce's Rot3 tangent-space Jacobians of
    the model's f, derive.apps.ins.symforce_eskf) computes what derive's generated predict
    does, at a random unit quaternion and a random covariance (its count is the report's)."""
    pytest.importorskip("symforce")
    from derive.apps.ins.symforce_eskf import numeric_predict

    peer = numeric_predict("ins_fc24_eskf")
    module = load_python(GENERATED.parent / "ins_fc24_eskf" / "eskf.py")
    rng = np.random.default_rng(11)
    q = rng.standard_normal(4)
    x = np.concatenate([q / np.linalg.norm(q), rng.normal(0, 0.1, 20)])
    A = rng.standard_normal((23, 23))
    P = A @ A.T
    u = np.concatenate([rng.normal(0, 0.01, 3), [0.0, 0.0, -0.098] + rng.normal(0, 0.01, 3)])
    x_peer, P_peer = peer(x, P, u, 0.01)
    x_new, P_new = (np.asarray(v, dtype=float) for v in module.predict(x, P, u, [0.01]))
    assert np.abs(x_peer - x_new).max() <= 1e-15 * np.abs(x_new).max() * 8
    assert np.abs(P_peer - P_new.reshape(23, 23)).max() <= 1e-14 * np.abs(P_new).max()


def test_eskf_wraps_angle_measurements_and_takes_a_state_dependent_r(tmp_path):
    """An angle measurement (psi's, whose truth wraps through ±pi every few steps) has its
    innovation wrapped to (-pi, pi] in the generated Python and C and in the reference
    (1e-12 apart, 300 steps), and an R that depends on the state is evaluated at
    x(k/k-1); without the declaration the same filter's heading is off by turns."""
    psi = sympy.Symbol("psi", real=True)
    R = sympy.diag(1e-3, 1e-3, 1e-3, 1e-2 * (1 + sympy.cos(psi) ** 2 / 2))
    model = attitude_and_heading(angles=["zpsi"], R=R)
    options = validate("eskf", {})
    generated = load_generated(model, "eskf", options, "all", tmp_path)
    assert any("innovations wrapped" in fact for fact in generated.unit.facts)
    assert any("R at x(k/k-1)" in fact for fact in generated.unit.facts)
    case = sensors_case(model, "eskf", 300, 7, options)
    assert np.ptp(case.run.truth[:, 4]) > 6.0  # the angle wraps
    for module in (generated.python, generated.c):
        xs, Ps = module.run(*case.arguments().values())
        assert relative_error(np.asarray(xs), case.reference.xs) <= 1e-12
        assert relative_error(np.asarray(Ps).reshape(300, 4, 4), case.reference.Ps) <= 1e-12

    def heading_error(xs):
        return np.abs(manifolds.wrap_numeric(np.asarray(xs)[:, 4] - case.run.truth[1:, 4]))

    assert heading_error(case.reference.xs).max() < 0.5
    plain = attitude_and_heading(R=R)
    unwrapped = sensors_case(plain, "eskf", 300, 7, options).reference.xs
    assert heading_error(unwrapped).max() > 1.0

