"""derive.emit: rendering (both languages, every family), ruff and gcc cleanliness,
determinism, numerics of the generated Python, and atomic writing."""

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jinja2
import numpy as np
import pytest
from _backend_kf import (
    cv_axes,
    dt,
    ekf_like_reference,
    ekf_like_unit,
    fir_reference,
    fir_unit,
    gcc_strict,
    kf_program,
    kf_unit,
    numeric,
    pred_reference,
    pred_unit,
    q,
    r,
    reference_kf,
    steady_reference,
    steady_unit,
    unit_fields,
)

from derive import LinearModel, NonlinearModel, Sensor, catalog
from derive.build import load_python
from derive.emit.render import derive_version, environment, render_files
from derive.emit.write import write_files
from derive.errors import OutputPathError
from derive.filters import FILTERS, derive_unit
from derive.flops import count
from derive.program import Port, Program, ProgramError
from derive.runs.unit import RUN_KINDS, Unit

ROOT = Path(__file__).resolve().parents[2]
RUFF = shutil.which("ruff")


def _units():
    units = [kf_unit(axes=2), steady_unit("sskf"), steady_unit("jssklf", params=True),
             fir_unit(), pred_unit(), ekf_like_unit()]
    step = kf_unit(axes=1).programs["step"]
    for family in ("lf", "jklf", "ikf", "ukf"):
        units.append(Unit(model="cv", filter=family, **unit_fields(family), n=2, m=1,
                          programs={"step": step}, parameters=("dt", "q", "r")))
    units.append(steady_unit("sslf"))
    units.append(derive_unit(catalog.load("cv"), "rts"))  # the smoother's run kind
    units.append(derive_unit(catalog.load("cv"), "kfp"))  # filtered and predicted
    units.append(derive_unit(catalog.load("mpt3d_b"), "udkf", {"missing": True}))
    two_sensors = LinearModel(  # the sensors run kind: inputs, two sensors, a gate
        "cart", ["p", "v"], F=[[1, "dt"], [0, 1]], Q=[[1, 0], [0, 1]], inputs=["a", "o"],
        B=[["dt**2/2", 0], ["dt", 0]],
        sensors=[Sensor("gps", ["zp"], H=[[1, 0]], R=4, inputs=["o"], D=[[1]]),
                 Sensor("speed", ["zv"], H=[[0, 1]], R=1)], parameters=["dt"])
    units.append(derive_unit(two_sensors, "kf", {"gate_sensors": "gps=0.99",
                                                 "start": "update"}))
    attitude = NonlinearModel(  # a quaternion: x of 4 numbers, P 3 x 3 (the tangent space)
        "att", ["q0", "q1", "q2", "q3"], ["gz"], inputs=["wx", "wy", "wz"],
        f=["q0 - q1*wx/2 - q2*wy/2 - q3*wz/2", "q1 + q0*wx/2 + q2*wz/2 - q3*wy/2",
           "q2 + q0*wy/2 - q1*wz/2 + q3*wx/2", "q3 + q0*wz/2 + q1*wy/2 - q2*wx/2"],
        h=["1 - 2*(q1**2 + q2**2)"], Q=[[1, 0, 0], [0, 1, 0], [0, 0, 1]], R=[[1]],
        x0=[1, 0, 0, 0], manifolds=[{"quaternion": ["q0", "q1", "q2", "q3"]}])
    units.append(derive_unit(attitude, "eskf", {"reset": True}))
    return units


UNITS = _units()


def test_every_family_has_a_unit_here():
    assert {u.family for u in UNITS} == set(FILTERS)
    assert {u.kind for u in UNITS} == set(RUN_KINDS)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("generated")
    paths = []
    for unit in UNITS:
        paths += write_files(out, unit.model, render_files(unit))
    return paths


@pytest.mark.skipif(RUFF is None, reason="ruff not installed")
def test_generated_python_passes_ruff(written):
    py = [str(p) for p in written if p.suffix == ".py"]
    proc = subprocess.run([RUFF, "check", "--isolated", *py], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.skipif(RUFF is None, reason="ruff not installed")
def test_committed_generated_python_passes_ruff_defaults():
    """The catalog's files as committed, vector rows among them (their lanes past a row's
    end are computed and never read), under ruff's defaults as a user's project runs it."""
    py = sorted(str(p) for p in (ROOT / "generated").glob("*/*.py"))
    assert any("ins_fc24" in p for p in py)
    proc = subprocess.run([RUFF, "check", "--isolated", *py], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("extra", [(), ("-march=native",)])
def test_generated_c_compiles_with_strict_flags(written, extra):
    for path in (p for p in written if p.suffix == ".c"):
        proc = gcc_strict(path, *extra)
        assert proc.returncode == 0, f"{path.name}:\n{proc.stderr}"


def test_headers_state_the_facts():
    unit = kf_unit(axes=2, command="derive generate cv --filter kf")
    files = render_files(unit)
    step = unit.programs["step"]
    for name, text in files.items():
        lang = "python" if name.endswith(".py") else "c"
        head = text[:text.index("*/") if lang == "c" else text.index('"""', 3)]
        for fact in ("model: cv", "filter: kf (Kalman filter)", "n: 4", "m: 2",
                     "parameters: p = [dt, q, r]", "derive generate cv --filter kf",
                     f"derive {derive_version()}", "test: backend example", "step 1: S"):
            assert fact in head, (name, fact)
        assert count(step, lang).summary() in head
    assert "int cv_kf_step(x[4], P[4*4], z[2], x_new[4] out, P_new[4*4] out, p[3])" in files[
        "kf.h"]
    assert ("run(zs[steps, 2], x0[4], P0[4, 4], p[3] or p[steps, 3]) -> (xs[steps, 4], "
            "Ps[steps, 4, 4])") in files[
        "kf.py"]


def test_rendering_is_deterministic_in_process():
    assert render_files(kf_unit(axes=2)) == render_files(kf_unit(axes=2))


_RENDER = """
import hashlib, sys
sys.path.insert(0, {root!r}); sys.path.insert(0, {tests!r})
from _backend_kf import kf_unit
from derive.emit.render import render_files
files = render_files(kf_unit(axes=3))
print(hashlib.sha256(repr(sorted(files.items())).encode()).hexdigest())
"""


def test_rendering_is_identical_across_hash_seeds():
    here = hashlib.sha256(repr(sorted(render_files(kf_unit(axes=3)).items())).encode())
    code = _RENDER.format(root=str(ROOT), tests=str(ROOT / "tests"))
    for seed in ("0", "777"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True).stdout.strip()
        assert out == here.hexdigest()


def _module(written, stem):
    return load_python(next(p for p in written if p.name == f"{stem}.py"))


def test_generated_kf_matches_the_reference(written):
    module = _module(written, "kf")
    F, W, H, R = (numeric(M, {dt: 0.5, q: 0.02, r: 0.3}) for M in cv_axes(2))
    rng = np.random.default_rng(7)
    zs = rng.normal(size=(40, 2))
    x0, P0 = rng.normal(size=4), np.eye(4) * 2
    xs, Ps = module.run(zs, x0, P0, [0.5, 0.02, 0.3])
    xr, Pr = reference_kf(F, W, H, R, zs, x0, P0)
    np.testing.assert_allclose(xs, xr, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(Ps, Pr, rtol=1e-11, atol=1e-12)
    # a trailing track axis filters several tracks at once, each exactly as alone
    zt = np.stack([zs, 2 * zs, -zs], axis=-1)
    xt, Pt = module.run(zt, np.stack([x0] * 3, -1), np.stack([P0] * 3, -1), [0.5, 0.02, 0.3])
    for k, scale in enumerate((1, 2, -1)):
        xk, Pk = module.run(scale * zs, x0, P0, [0.5, 0.02, 0.3])
        np.testing.assert_array_equal(xt[..., k], xk)
        np.testing.assert_array_equal(Pt[..., k], Pk)


def test_generated_steady_fir_pred_and_two_input_runs(written):
    rng = np.random.default_rng(3)
    zs, x0 = rng.normal(size=(25, 1)), rng.normal(size=2)
    np.testing.assert_allclose(_module(written, "sskf").run(zs, x0),
                               steady_reference(zs, x0), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(_module(written, "jssklf").run(zs, x0, [1.5]),
                               steady_reference(zs, x0, g=1.5), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(_module(written, "fir").run(zs), fir_reference(zs),
                               rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(_module(written, "pred").run(zs, x0),
                               pred_reference(zs, x0), rtol=1e-13, atol=1e-14)
    us = rng.normal(size=(25, 2))
    xs, Ps = _module(written, "ekf").run(zs, us, x0, np.eye(2))
    xr, Pr = ekf_like_reference(zs, us, x0, np.eye(2))
    np.testing.assert_allclose(xs, xr, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Ps, Pr, rtol=1e-12, atol=1e-13)


def test_templates_fail_on_undefined_variables():
    with pytest.raises(jinja2.UndefinedError):
        environment().from_string("{{ missing }}").render()


def test_unit_validates_the_family_interface():
    step = kf_program(*cv_axes(1)).optimize()
    with pytest.raises(ProgramError, match="unknown run kind"):
        Unit(model="cv", filter="kf", **{**unit_fields("kf"), "run_kind": "nope"}, n=2, m=1,
             programs={"step": step})
    with pytest.raises(ProgramError, match="must have inputs"):
        Unit(model="cv", filter="sskf", **unit_fields("sskf"), n=2, m=1, programs={"step": step},
             parameters=("dt", "q", "r"))
    with pytest.raises(ProgramError, match=r"shape \(3,\)"):
        Unit(model="cv", filter="kf", **unit_fields("kf"), n=3, m=1, programs={"step": step},
             parameters=("dt", "q", "r"))
    with pytest.raises(ProgramError, match="window"):
        Unit(model="toy", filter="fir", **unit_fields("fir"), n=2, m=1,
             programs={"step": fir_unit().programs["step"]})
    with pytest.raises(ProgramError, match="init"):
        Unit(model="toy", filter="pred", **unit_fields("pred"), n=2, m=1,
             programs={"step": steady_unit().programs["step"]})
    with pytest.raises(ProgramError, match="identifier"):
        Unit(model="../x", filter="kf", **unit_fields("kf"), n=2, m=1, programs={"step": step},
             parameters=("dt", "q", "r"))


def test_unused_parameter_port_still_compiles(tmp_path):
    prog = Program("step", [Port("x", (2,)), Port("z", (1,)), Port("p", (2,))],
                   [Port("x_new", (2,))])
    prog.set_output("x_new", [prog.element("x", 0), prog.element("z", 0)])
    unit = Unit(model="ident", filter="sskf", **unit_fields("sskf"), n=2, m=1,
                programs={"step": prog.optimize()}, parameters=("a", "b"))
    paths = write_files(tmp_path, "ident", render_files(unit))
    c_file = next(p for p in paths if p.suffix == ".c")
    assert "(void)p;" in c_file.read_text()
    proc = gcc_strict(c_file)
    assert proc.returncode == 0, proc.stderr


# -- writing -------------------------------------------------------------------------


def test_write_files_replaces_atomically(tmp_path):
    first = write_files(tmp_path, "cv", {"a.py": "one\n", "a.c": "two\n"})
    assert [p.name for p in first] == ["a.c", "a.py"]
    assert (tmp_path / "cv" / "a.py").read_text() == "one\n"
    # a file that cannot be written (unencodable text) leaves every previous file intact
    with pytest.raises(UnicodeEncodeError):
        write_files(tmp_path, "cv", {"a.c": "new\n", "a.py": "bad \ud800\n"})
    assert (tmp_path / "cv" / "a.c").read_text() == "two\n"
    assert sorted(p.name for p in (tmp_path / "cv").iterdir()) == ["a.c", "a.py"]
    write_files(tmp_path, "cv", {"a.c": "three\n"})
    assert (tmp_path / "cv" / "a.c").read_text() == "three\n"


@pytest.mark.parametrize("model", ["..", "/etc", "a/b", "a\\b", "", "x.y", "for"])
def test_write_files_rejects_bad_model_names(tmp_path, model):
    with pytest.raises(OutputPathError):
        write_files(tmp_path, model, {"a.py": ""})


@pytest.mark.parametrize("name", ["../a.py", "sub/a.py", "..", "."])
def test_write_files_rejects_bad_file_names(tmp_path, name):
    with pytest.raises(OutputPathError):
        write_files(tmp_path, "cv", {name: ""})


def test_write_files_rejects_symlinks_leading_outside(tmp_path):
    out, outside = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    outside.mkdir()
    (out / "cv").symlink_to(outside)
    with pytest.raises(OutputPathError, match="outside"):
        write_files(out, "cv", {"a.py": "x = 1\n"})
    assert not list(outside.iterdir())
    (out / "ok").mkdir()
    (out / "ok" / "a.py").symlink_to(outside / "target.py")
    with pytest.raises(OutputPathError, match="outside"):
        write_files(out, "ok", {"a.py": "x = 1\n"})
    # a symlink that stays inside the output directory is fine
    (out / "real").mkdir()
    (out / "alias").symlink_to(out / "real")
    write_files(out, "alias", {"a.py": "x = 1\n"})
    assert (out / "real" / "a.py").read_text() == "x = 1\n"
