"""The robustness audit of the features of the last stops (several sensors, gating,
inputs, per-step parameters, batches, Dask, the library layout): each silent wrong answer,
crash or ambiguity found has a test here that failed before its fix, and each behaviour
found right has one that keeps it so."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import NonlinearModel, Sensor, catalog
from derive.apps.simulate import simulate_linear
from derive.apps.targets.library import CMAKE_RESERVED_TARGETS, render_library
from derive.batch import run_tracks
from derive.cli import main
from derive.errors import DtypeError, NameError_, OptionError, SymbolError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.modelfile import loads_model
from derive.pipeline import load_generated

TWO_SENSORS = """
[model]
name = "cart"
states = ["p", "v"]

[parameters]
q = 0.01

[discrete]
F = [[1, 0.1], [0, 1]]
Q = [["q", 0], [0, "q"]]

[sensors.gps]
measurements = ["e", "n"]
H = [[1, 0], [1, 0]]
R = [[4, 1], [1, 4]]

[sensors.speed]
measurements = ["zv"]
H = [[0, 1]]
R = 0.25

[initial]
x0 = [0, 0]
P0 = [[1, 0], [0, 1]]
"""


def one_line_exit_2(capsys, argv: list[str], *words: str) -> str:
    """Run the CLI: status 2, one line on stderr holding ``words``, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)
    return err


def tree_hash(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


# -- gating: a sensor named twice in gate_sensors -----------------------------------------


def test_gate_sensors_naming_a_sensor_twice_is_refused(tmp_path, capsys):
    """``gps=0.9,gps=0.5``: which probability holds was a guess (the last, silently)."""
    model = loads_model(TWO_SENSORS)
    with pytest.raises(OptionError, match=r"option 'gate_sensors' \(--gate-sensors\) names "
                                          r"sensor 'gps' twice"):
        derive_unit(model, "kf", {"gate_sensors": "gps=0.9,gps=0.5"})
    derive_unit(model, "kf", {"gate_sensors": "gps=0.9,speed=0.5"})  # each once: taken
    path = tmp_path / "cart.toml"
    path.write_text(TWO_SENSORS)
    one_line_exit_2(capsys, ["generate", str(path), "--filter", "kf", "--out",
                             str(tmp_path / "out"), "--gate-sensors", "gps=0.9,gps=0.5"],
                    "names sensor 'gps' twice")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("gate", [0.0, 1.0, float("nan"), 1.5, -0.25, float("inf")])
def test_gate_outside_the_open_unit_interval_is_refused(gate):
    with pytest.raises(OptionError, match=r"option 'gate' \(--gate\) must be a finite number "
                                          r"in \(0, 1\)"):
        derive_unit(loads_model(TWO_SENSORS), "kf", {"gate": gate})


# -- sensor names ------------------------------------------------------------------------


def test_sensor_names_differing_only_in_case_are_refused(tmp_path, capsys):
    """gps and GPS are one name in generated C (PREFIX_M_GPS, the status enum): it failed
    to compile (a BuildError from gcc) instead of naming the sensors."""
    text = TWO_SENSORS.replace("[sensors.speed]", "[sensors.GPS]")
    with pytest.raises(SymbolError, match=r"sensor names 'gps' and 'GPS' differ only in "
                                          r"case"):
        loads_model(text)
    path = tmp_path / "cart.toml"
    path.write_text(text)
    one_line_exit_2(capsys, ["generate", str(path), "--filter", "kf", "--out",
                             str(tmp_path / "out")], "cart.toml", "'gps' and 'GPS'")
    assert not (tmp_path / "out").exists()


def test_a_sensor_named_predict_with_its_own_inputs_compiles_and_matches():
    """The C run gathers a function's subset of u into a local named for the function:
    a sensor named predict (its update: update_predict) declared predict's ``u_predict``
    a second time (a BuildError) when both took a subset of u."""
    p, v, a, off = sympy.symbols("p v a off", real=True)
    model = NonlinearModel(
        "slide", ["p", "v"], f=[p + v / 10, v + a / 10], Q=sympy.diag(1e-3, 1e-3),
        inputs=["a", "off"], x0=[0, 0], P0=sympy.eye(2),
        sensors=[Sensor("predict", ["zp"], h=[p + off], R=[[1]]),
                 Sensor("speed", ["zv"], h=[v], R=[[0.5]])])
    generated = load_generated(model, "ekf")
    rng = np.random.default_rng(4)
    steps = 30
    us = rng.normal(size=(steps, 2))
    zs = {"predict": rng.normal(size=(steps, 1)), "speed": rng.normal(size=(steps, 1))}
    zs["predict"][::3] = np.nan
    x0, P0 = np.zeros(2), np.eye(2)
    ref = reference_run(model, {}, zs, us, None, x0, P0)
    for module in (generated.python, generated.c):
        xs, Ps = module.run(zs["predict"], zs["speed"], us, x0, P0)
        assert np.max(np.abs(xs - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))
        assert np.max(np.abs(Ps - ref.Ps)) <= 1e-12 * np.max(np.abs(ref.Ps))


# -- a sensor's row partly NaN ------------------------------------------------------------


@pytest.fixture(scope="module")
def two_sensor_filter():
    model = loads_model(TWO_SENSORS)
    return model, load_generated(model, "kf", {"gate": 0.999})


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 39), st.integers(0, 1)), min_size=1, max_size=12),
       st.integers(0, 1000))
def test_a_row_partly_nan_is_skipped_whole_never_half_applied(two_sensor_filter, holes,
                                                              seed):
    """A NaN anywhere in a sensor's row k means no measurement of that sensor at step k:
    the same x, P, NIS and applied as the whole row NaN, in Python, C and the reference
    (the present component is not applied alone)."""
    model, generated = two_sensor_filter
    num = model.numeric()
    rng = np.random.default_rng(seed)
    steps = 40
    zs = {"gps": rng.normal(size=(steps, 2)), "speed": rng.normal(size=(steps, 1))}
    part = {k: v.copy() for k, v in zs.items()}
    whole = {k: v.copy() for k, v in zs.items()}
    for step, column in holes:
        part["gps"][step, column] = np.nan
        whole["gps"][step] = np.nan
    x0, P0 = np.zeros(2), np.asarray(num.P0, dtype=float)
    ref = reference_run(model, {"gate": 0.999}, whole, x0=x0, P0=P0)
    for module in (generated.python, generated.c):
        xs_part, Ps_part, nis_part, applied_part, *_ = module.run(part["gps"], part["speed"],
                                                                  x0, P0)
        xs_whole, Ps_whole, nis_whole, applied_whole, *_ = module.run(
            whole["gps"], whole["speed"], x0, P0)
        assert np.array_equal(xs_part, xs_whole) and np.array_equal(Ps_part, Ps_whole)
        assert np.array_equal(nis_part, nis_whole, equal_nan=True)
        assert np.array_equal(applied_part, applied_whole)
        assert np.all(applied_part[[step for step, _ in holes]] == 0)
        assert np.max(np.abs(xs_part - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))


# -- Dask: a chunk of no tracks ------------------------------------------------------------


def test_a_dask_chunk_of_zero_tracks_gives_the_numpy_result(tmp_path):
    """Ragged chunks, one of them empty (as a filtered Dask array has): each track bitwise
    the NumPy path's; the empty chunk raised a bare ValueError (reshape of size 0 with -1)
    inside the task."""
    dask = pytest.importorskip("dask")
    import dask.array as da

    load_generated("cv", "kf", lang="c", directory=tmp_path)
    kernel = str(tmp_path / "cv" / "kf.c")
    num = catalog.load("cv").numeric()
    tracks, steps = 23, 15
    zs = np.stack([simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps,
                                   seed).zs for seed in range(tracks)])
    x0s, P0s = np.zeros((tracks, 2)), np.tile(np.eye(2), (tracks, 1, 1))
    xs, Ps = run_tracks(kernel, zs, x0s, P0s, workers=1)
    for chunks in ((0, 10, 13), (10, 0, 13), (5, 7, 11, 0)):
        lazy = run_tracks(kernel, da.from_array(zs, chunks=(chunks, steps, 1)),
                          da.from_array(x0s, chunks=(chunks, 2)), P0s)
        got_xs, got_Ps = dask.compute(*lazy, scheduler="synchronous")
        assert np.array_equal(got_xs, xs) and np.array_equal(got_Ps, Ps), chunks


# -- the library layout: names CMake reserves ---------------------------------------------


@pytest.mark.parametrize("name", ["test", "all", "clean", "install", "ALL_BUILD",
                                  "Experimental", "Nightly", "Continuous",
                                  "NightlyMemoryCheck", "ExperimentalSubmit"])
def test_the_library_layout_refuses_a_model_named_like_a_reserved_cmake_target(
        name, tmp_path, capsys):
    """``add_library(test ...)`` is refused by CMake ("The target name "test" is reserved
    when CTest testing is enabled"): the library was written and failed at configure."""
    assert name in CMAKE_RESERVED_TARGETS
    text = (Path(catalog.__file__).parent / "cv.toml").read_text()
    text = text.replace('name = "cv"', f'name = "{name}"')
    with pytest.raises(NameError_, match=rf"model name '{name}' is reserved by CMake"):
        render_library(loads_model(text), ["kf"])
    path = tmp_path / "m.toml"
    path.write_text(text)
    out = tmp_path / "out"
    (out / "keep").mkdir(parents=True)
    (out / "keep" / "kf.c").write_text("previous")
    before = tree_hash(out)
    one_line_exit_2(capsys, ["generate", str(path), "--filter", "kf", "--layout", "library",
                             "--lang", "c", "--out", str(out)], f"'{name}'", "CMake")
    assert tree_hash(out) == before


# -- compiled kernels: arrays that are not the kernel's real numbers ----------------------


@pytest.fixture(scope="module")
def cv_kernels():
    return (load_generated("cv", "kf", lang="c").c,
            load_generated("cv", "kf", {"precision": "float"}, lang="c").c)


def test_a_kernel_refuses_values_it_would_change_silently(cv_kernels):
    """complex (the imaginary part was dropped), bool, str (parsed as numbers), object
    (None became NaN) and integers the dtype cannot hold exactly (2^53 + 1 in double,
    2^24 + 1 in float: rounded) are refused with DtypeError naming the argument; integers
    it holds exactly, and narrower floats, are taken."""
    double, single = cv_kernels
    eye = np.eye(2)
    cases = [(double, np.ones((2, 1), np.complex64), "complex64"),
             (double, np.array([[True], [False]]), "bool"),
             (double, np.array([["1.5"]]), "<U3"),
             (double, [[1.0], [None]], "object"),
             (double, np.array([[2**53 + 1]]), "9007199254740993"),
             (single, np.array([[2**24 + 1]], dtype=np.int32), "16777217")]
    for kernel, zs, words in cases:
        P0 = eye.astype(kernel.dtype)
        with pytest.raises(DtypeError, match=rf"_run: argument 'z' .*{re.escape(words)}"):
            kernel.run(zs, np.zeros(2, kernel.dtype), P0)
    exact = double.run([[1], [2]], [0, 0], [[1, 0], [0, 1]])[0]
    assert np.array_equal(exact, double.run([[1.0], [2.0]], [0.0, 0.0], eye)[0])
    small = single.run(np.array([[2**24]], dtype=np.int32), np.zeros(2, np.float32),
                       eye.astype(np.float32))[0]
    assert np.all(np.isfinite(small))


@pytest.mark.parametrize("first, second", [("x", "P"), ("z", "p"), ("status", "k")])
def test_sensors_named_like_the_generated_codes_own_names_run_right(first, second):
    """Sensor names only ever appear inside longer identifiers (update_x, z_x, nis_x,
    PREFIX_M_X), so a sensor named as a port, a local or a parameter array is harmless:
    Python and C agree with the reference to 1e-12."""
    text = TWO_SENSORS.replace("[sensors.gps]", f"[sensors.{first}]").replace(
        "[sensors.speed]", f"[sensors.{second}]")
    model = loads_model(text)
    generated = load_generated(model, "kf", {"gate": 0.999})
    rng = np.random.default_rng(8)
    steps = 25
    zs = {first: rng.normal(size=(steps, 2)), second: rng.normal(size=(steps, 1))}
    zs[first][::4] = np.nan
    x0, P0 = np.zeros(2), np.eye(2)
    ref = reference_run(model, {"gate": 0.999}, zs, x0=x0, P0=P0)
    for module in (generated.python, generated.c):
        xs, Ps, *_ = module.run(zs[first], zs[second], x0, P0)
        assert np.max(np.abs(xs - ref.xs)) <= 1e-12 * np.max(np.abs(ref.xs))
        assert np.max(np.abs(Ps - ref.Ps)) <= 1e-12 * np.max(np.abs(ref.Ps))
