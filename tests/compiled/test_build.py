"""derive.build: generated C through cffi, against the generated Python and references."""

import numpy as np
import pytest
from _backend_kf import (
    ekf_like_reference,
    ekf_like_unit,
    fir_reference,
    fir_unit,
    kf_unit,
    pred_reference,
    pred_unit,
    steady_reference,
    steady_unit,
)

from derive import staging
from derive.build import BuildError, build_c, load_python, parse_interface
from derive.emit.render import render_files, render_functions
from derive.emit.write import write_files
from derive.errors import NumericalError, ShapeError
from derive.program import Port, Program


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cffi-cache")


def _write(tmp_path, unit):
    paths = write_files(tmp_path, unit.model, render_files(unit))
    c_file = next(p for p in paths if p.suffix == ".c")
    return c_file, load_python(c_file.with_suffix(".py"))


def test_kf_in_c_matches_the_generated_python(tmp_path, cache):
    c_file, py = _write(tmp_path, kf_unit(axes=3))
    module = build_c(c_file, tmpdir=cache)
    rng = np.random.default_rng(11)
    zs, x0 = rng.normal(size=(60, 3)), rng.normal(size=6)
    A = rng.normal(size=(6, 6))
    P0 = A @ A.T + np.eye(6)
    p = [1.0, 0.01, 0.1]
    xs, Ps = module.run(zs, x0, P0, p=p)
    xp, Pp = py.run(zs, x0, P0, p)
    assert xs.shape == (60, 6) and Ps.shape == (60, 6, 6)
    # C uses fma where the hardware has it: agreement to rounding, not bit for bit
    np.testing.assert_allclose(xs, xp, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(Ps, Pp, rtol=1e-11, atol=1e-12)
    x1, P1 = module.step(x0, P0.ravel(), zs[0], p=p)
    x1p, P1p = py.step(x0, P0.ravel(), zs[0], p)
    np.testing.assert_allclose(x1, x1p, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(P1, P1p, rtol=1e-12, atol=1e-13)
    # the covariance history is optional in C: same estimates without it
    xs_only = module.call("run", zs, x0, P0, p=p, with_covariance=False)
    np.testing.assert_array_equal(xs_only, xs)


def test_builds_are_cached_by_content(tmp_path, cache):
    c_file, _ = _write(tmp_path, steady_unit("sskf"))
    first = build_c(c_file, tmpdir=cache)
    entries = sorted(p.name for p in cache.iterdir())
    second = build_c(str(c_file), tmpdir=cache)
    assert second.path == first.path and sorted(p.name for p in cache.iterdir()) == entries
    other = build_c(c_file, tmpdir=cache, extra_cflags=["-O1"])
    assert other.path != first.path


def test_every_kind_runs_in_c(tmp_path, cache):
    rng = np.random.default_rng(5)
    zs, x0 = rng.normal(size=(30, 1)), rng.normal(size=2)
    paths = [_write(tmp_path, u)[0] for u in (steady_unit("sskf"), fir_unit(), pred_unit(),
                                               ekf_like_unit(), steady_unit("sslf", True))]
    module = build_c(paths, tmpdir=cache)   # several filters in one extension
    tol = {"rtol": 1e-13, "atol": 1e-14}
    np.testing.assert_allclose(module["toy_sskf"].run(zs, x0), steady_reference(zs, x0), **tol)
    np.testing.assert_allclose(module["toy_sslf"].run(zs, x0, p=[0.5]),
                               steady_reference(zs, x0, g=0.5), **tol)
    np.testing.assert_allclose(module["toy_fir"].run(zs), fir_reference(zs), **tol)
    np.testing.assert_allclose(module["toy_pred"].run(zs, x0), pred_reference(zs, x0), **tol)
    us = rng.normal(size=(30, 2))
    xs, Ps = module["toy_ekf"].run(zs, us, x0, np.eye(2))
    xr, Pr = ekf_like_reference(zs, us, x0, np.eye(2))
    np.testing.assert_allclose(xs, xr, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Ps, Pr, rtol=1e-12, atol=1e-13)


def _cholesky_files(tmp_path):
    prog = Program("chol", [Port("S", (3, 3), symmetric=True)], [Port("L", (3, 3))])
    prog.set_output("L", staging.cholesky(prog, prog.matrix("S")))
    prog = prog.optimize()
    c_files = write_files(tmp_path, "lib", render_functions("chol3", [prog], "c"))
    py = write_files(tmp_path, "lib", render_functions("chol3", [prog], "python"))
    return next(p for p in c_files if p.suffix == ".c"), load_python(py[0])


def test_failing_cholesky_pivot_is_a_status_in_c_and_an_error_in_python(tmp_path, cache):
    c_file, py = _cholesky_files(tmp_path)
    module = build_c(c_file, tmpdir=cache)
    good = np.array([[4.0, 2.0, 0.4], [2.0, 5.0, 1.0], [0.4, 1.0, 3.0]])
    L = module.chol(good).reshape(3, 3)
    np.testing.assert_allclose(L, np.linalg.cholesky(good), rtol=1e-14)
    np.testing.assert_allclose(py.chol(good.ravel()), L.ravel(), rtol=1e-14)
    bad = good.copy()
    bad[1, 1] = bad[1, 0] ** 2 / bad[0, 0] - 1.0   # second pivot 4 - 1 - 4 < 0
    ffi, lib = module.ffi, module.lib
    out = np.empty(9)
    status = lib.chol3_chol(ffi.from_buffer("double[]", bad.ravel().copy()),
                            ffi.from_buffer("double[]", out))
    assert status == 2
    with pytest.raises(NumericalError, match="pivot 1"):
        module.chol(bad)
    with pytest.raises(NumericalError, match="pivot 1"):
        py.chol(bad.ravel())


def test_run_reports_a_failing_step(tmp_path, cache):
    c_file, _ = _write(tmp_path, kf_unit(axes=1))
    module = build_c(c_file, tmpdir=cache)
    zs = np.zeros((3, 1))
    with pytest.raises(NumericalError, match="status 1: step: S is not positive definite"):
        module.run(zs, np.zeros(2), -np.eye(2) * 10, p=[1.0, 0.0, 0.0])


def test_wrong_sizes_and_bad_sources_are_reported(tmp_path, cache):
    c_file, _ = _write(tmp_path, steady_unit("sskf"))
    module = build_c(c_file, tmpdir=cache)
    with pytest.raises(ShapeError, match=r"argument 'x0' must have shape \(2,\), got \(3,\)"):
        module.run(np.zeros((4, 1)), np.zeros(3))
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "bad.c").write_text(c_file.read_text()
                                  + "\nstatic int unused(void) { return 0; }\n")  # -Werror
    (broken / "bad.h").write_text(c_file.with_suffix(".h").read_text())
    with pytest.raises(BuildError, match="failed"):
        build_c(broken / "bad.c", tmpdir=cache)
    with pytest.raises(BuildError, match="does not exist"):
        build_c(tmp_path / "missing.c", tmpdir=cache)


def test_parse_interface_reads_the_header():
    unit = kf_unit(axes=1)
    functions, statuses = parse_interface(render_files(unit)["kf.h"])
    step, run, tracks = functions
    assert tracks.name == "cv_kf_run_tracks" and tracks.arguments == run.arguments
    assert step.name == "cv_kf_step" and step.returns_status and not step.has_steps
    assert [(a.name, a.size(), a.output) for a in step.arguments] == [
        ("x", 2, False), ("P", 4, False), ("z", 1, False), ("x_new", 2, True),
        ("P_new", 4, True), ("p", 3, False)]
    assert run.has_steps and run.arguments[-2].optional and run.arguments[-2].size(5) == 20
    assert statuses[1][0].startswith("step: S is not positive definite")
