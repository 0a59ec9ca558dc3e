"""The RTS smoother: the NumPy reference against FilterPy and pykalman, and the derived
forward/backward programs, run through the documented work layout, against the reference."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
import sympy
from filterpy.kalman import KalmanFilter as FilterPyKF
from pykalman import KalmanFilter as PyKalmanKF

from derive import LinearModel, catalog
from derive.apps.simulate import simulate_linear
from derive.apps.verify import relative_error
from derive.build import STRICT_CFLAGS
from derive.emit import c_printer
from derive.emit.python_printer import python_function
from derive.errors import FilterError, ModelError, NumericalError, PatternError
from derive.filters.kf import kf_update, time_varying_program
from derive.filters.rts import rts_programs
from derive.flops import OpCounter, count
from derive.lowering import lower_program
from derive.options import SharedOptions
from derive.reference import kf as reference_kf
from derive.reference.smoother import rts

PEER_TOLERANCE = 1e-10
PROGRAM_TOLERANCE = 1e-12

LINEAR = [name for name in catalog.names() if catalog.load(name).kind == "linear"]

r = sympy.Symbol("r")


def free_noise() -> LinearModel:
    """Two measurements of a constant-velocity axis, the first one's variance r free."""
    return LinearModel("freer", ["s", "v"], ["zs", "zv"], [[1, 1], [0, 1]], [[1, 0], [0, 1]],
                       [[0.01]], [[r, 0], [0, 0.2]], G=[[0.5], [1]], P0=np.eye(2).tolist(),
                       parameters=[r])


def measurements(num, steps: int = 120, seed: int = 3) -> np.ndarray:
    return simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs


def with_gaps(zs: np.ndarray, seed: int, whole_rows: bool) -> np.ndarray:
    """``zs`` with steps 0, 5 and 30..33 absent, plus random absent rows (``whole_rows``) or
    random absent entries."""
    out = zs.copy()
    rng = np.random.default_rng(seed)
    if whole_rows:
        out[rng.random(len(out)) < 0.25] = np.nan
    else:
        out[rng.random(out.shape) < 0.3] = np.nan
    out[[0, 5]] = np.nan
    out[30:34] = np.nan
    return out


# -- the reference against the peers ------------------------------------------------------

def filterpy_smooth(num, zs):
    """FilterPy: batch_filter predicts, then updates (x(0/0) = x0, first z is z(1)), like
    derive; rts_smoother returns x(k/N) for the same k = 1..N. A NaN row is passed as None
    (FilterPy skips the update)."""
    n, m = num.F.shape[0], num.H.shape[0]
    peer = FilterPyKF(dim_x=n, dim_z=m)
    peer.F, peer.H, peer.Q, peer.R = num.F, num.H, num.GQGt, num.R
    peer.x, peer.P = num.x0.copy(), num.P0.copy()
    rows = [None if np.isnan(z).all() else z for z in zs]
    means, covariances, _, _ = peer.batch_filter(rows)
    xs, Ps, _, _ = peer.rts_smoother(np.reshape(means, (len(zs), n)), covariances)
    return xs, Ps


def pykalman_smooth(num, zs):
    """pykalman: its filter updates with its first observation at its initial state, so
    that state is derive's x(1/0) = F x0, P(1/0) = F P0 F^T + G Q G^T; NaN entries are
    masked (pykalman skips a step's whole update when any entry is masked)."""
    W = num.GQGt
    peer = PyKalmanKF(transition_matrices=num.F, observation_matrices=num.H,
                      transition_covariance=W, observation_covariance=num.R,
                      initial_state_mean=num.F @ num.x0,
                      initial_state_covariance=num.F @ num.P0 @ num.F.T + W)
    return peer.smooth(np.ma.masked_invalid(zs))


@pytest.mark.parametrize("name", LINEAR)
@pytest.mark.parametrize("peer", [filterpy_smooth, pykalman_smooth], ids=["filterpy", "pykalman"])
def test_reference_equals_filterpy_and_pykalman(name, peer):
    num = catalog.load(name).numeric()
    zs = measurements(num)
    xs, Ps = rts(num, zs, num.x0, num.P0)
    xp, Pp = peer(num, zs)
    assert relative_error(xs, xp) <= PEER_TOLERANCE
    assert relative_error(Ps, Pp) <= PEER_TOLERANCE
    # the smoother changed the filtered estimates (the comparison is not of two filters)
    xf, _ = reference_kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)
    assert relative_error(xs[:-1], xf[:-1]) > 1e-6
    np.testing.assert_array_equal(xs[-1], xf[-1])


@pytest.mark.parametrize("name", LINEAR)
@pytest.mark.parametrize("peer", [filterpy_smooth, pykalman_smooth], ids=["filterpy", "pykalman"])
def test_reference_skips_missing_steps_like_the_peers(name, peer):
    num = catalog.load(name).numeric()
    zs = with_gaps(measurements(num), seed=5, whole_rows=True)
    xs, Ps = rts(num, zs, num.x0, num.P0, skip_nan=True)
    xp, Pp = peer(num, zs)
    assert np.all(np.isfinite(xs))
    assert relative_error(xs, xp) <= PEER_TOLERANCE
    assert relative_error(Ps, Pp) <= PEER_TOLERANCE


def test_reference_refuses_nan_unless_told_to_skip():
    num = catalog.load("mpt3d_b").numeric()
    zs = with_gaps(measurements(num, steps=40), seed=1, whole_rows=True)
    with pytest.raises(ModelError, match="NaN"):
        rts(num, zs, num.x0, num.P0)


def test_reference_names_a_singular_prediction():
    num = catalog.load("gps_static").numeric()
    frozen = type(num)(F=num.F, G=num.G, H=num.H, Q=0 * num.Q, R=num.R, x0=num.x0,
                       P0=0 * num.P0)
    with pytest.raises(NumericalError, match=r"step 2: P\(3/2\) is singular"):
        rts(frozen, measurements(num, steps=3), frozen.x0, frozen.P0)


# -- the programs, run the way the run loop will run them -----------------------------------

def run_programs(programs, zs, x0, P0, p=()):
    """The run loop of derive.filters.rts's docstring, on one flat work array of exactly
    steps * (2 n + 2 n^2) doubles, one row per step; every double it must not read is
    NaN."""
    forward = python_function(programs["step"])
    backward = python_function(programs["backward"])
    n, steps = programs["step"].port("x").shape[0], len(zs)
    nn, row = n * n, 2 * n + 2 * n * n
    xs, Ps = np.full((steps, n), np.nan), np.full((steps, nn), np.nan)
    work = np.full(steps * row, np.nan)

    def part(k, offset, size):
        return work[k * row + offset:k * row + offset + size]

    for k in range(steps):
        x_in, P_in = (x0, np.ravel(P0)) if k == 0 else (part(k - 1, 0, n), part(k - 1, n, nn))
        (part(k, 0, n)[:], part(k, n, nn)[:], part(k, n + nn, n)[:],
         part(k, 2 * n + nn, nn)[:]) = forward(x_in, P_in, zs[k], *p)
    if steps:
        xs[-1], Ps[-1] = part(steps - 1, 0, n), part(steps - 1, n, nn)
    for k in range(steps - 2, -1, -1):
        xs[k], Ps[k] = backward(part(k, 0, n), part(k, n, nn), part(k + 1, n + nn, n),
                                part(k + 1, 2 * n + nn, nn), xs[k + 1], Ps[k + 1], *p)
    return xs, Ps.reshape(steps, n, n)


@pytest.mark.parametrize("missing", [False, True], ids=["all-present", "missing"])
@pytest.mark.parametrize("name", LINEAR)
def test_programs_equal_the_reference(name, missing):
    model = catalog.load(name)
    num = model.numeric()
    zs = measurements(num)
    if missing:
        zs = with_gaps(zs, seed=7, whole_rows=False)
    programs = rts_programs(model, SharedOptions(missing=missing))
    xs, Ps = run_programs(programs, zs, num.x0, num.P0)
    xr, Pr = rts(num, zs, num.x0, num.P0, skip_nan=missing)
    assert np.all(np.isfinite(xs)) and np.all(np.isfinite(Ps))
    assert relative_error(xs, xr) <= PROGRAM_TOLERANCE
    assert relative_error(Ps, Pr) <= PROGRAM_TOLERANCE


def test_programs_take_the_free_parameters():
    model = free_noise()
    num = model.numeric({"r": 0.4})
    zs = with_gaps(measurements(num), seed=2, whole_rows=False)
    programs = rts_programs(model, SharedOptions(missing=True))
    assert programs["backward"].inputs[-1].name == "p"
    xs, Ps = run_programs(programs, zs, num.x0, num.P0, p=([0.4],))
    xr, Pr = rts(num, zs, num.x0, num.P0, skip_nan=True)
    assert relative_error(xs, xr) <= PROGRAM_TOLERANCE
    assert relative_error(Ps, Pr) <= PROGRAM_TOLERANCE


def test_programs_with_a_dense_P0_on_a_block_model():
    model = catalog.load("gsm2d_a")
    num = model.numeric()
    P0 = np.eye(4) + 0.2          # couples the two axes
    zs = measurements(num)
    programs = rts_programs(model, SharedOptions(P0_pattern="dense"))
    xs, Ps = run_programs(programs, zs, num.x0, P0)
    xr, Pr = rts(num, zs, num.x0, P0)
    assert relative_error(xs, xr) <= PROGRAM_TOLERANCE
    assert relative_error(Ps, Pr) <= PROGRAM_TOLERANCE


# -- structure ------------------------------------------------------------------------------

def test_the_forward_pass_costs_exactly_the_kalman_filter_step():
    for name in LINEAR:
        model = catalog.load(name)
        for missing in (False, True):
            forward = rts_programs(model, SharedOptions(missing=missing))["step"]
            step = time_varying_program(model, _kf_update(missing), "Kalman filter", None)
            assert count(forward, "c") == count(step, "c"), (name, missing)


def _kf_update(missing):
    return lambda prog, mats, x, P, z: kf_update(prog, mats, x, P, z, missing=missing)


def test_block_models_stay_block_diagonal_and_cost_their_blocks():
    a = rts_programs(catalog.load("mpt3d_a"), SharedOptions())
    b = rts_programs(catalog.load("mpt3d_b"), SharedOptions())
    for which in ("step", "backward"):
        assert count(a[which], "c").flops == 3 * count(b[which], "c").flops
    P_smooth = np.reshape(a["backward"].results["P_smooth"], (6, 6))
    for i in range(6):
        for j in range(6):
            assert (P_smooth[i, j] != 0) == (i // 2 == j // 2)


def test_backward_solves_against_the_prediction_and_checks_its_pivots():
    programs = rts_programs(catalog.load("mpt3d_b"), SharedOptions())
    backward = python_function(programs["backward"])
    x, P = [0.0, 0.0], np.eye(2)
    with pytest.raises(NumericalError, match=r"P\(k\+1/k\) is not positive definite"):
        backward(x, P, x, np.zeros((2, 2)), x, P)
    # no explicit inverse: one division per pivot and entry of the solve (2 pivots,
    # 1 multiplier, 2 x 2 right-hand sides divided directly), no reciprocal
    assert count(programs["backward"], "c").div == 5


def test_backward_refuses_covariances_outside_the_pattern():
    programs = rts_programs(catalog.load("gps_static"), SharedOptions())
    backward = python_function(programs["backward"])
    x, P = [0.0] * 3, np.eye(3)
    coupled = P + 0.1
    for args in ((x, coupled, x, P, x, P), (x, P, x, coupled, x, P), (x, P, x, P, x, coupled)):
        with pytest.raises(PatternError, match="outside the pattern"):
            backward(*args)


def test_static_and_dynamic_counts_agree():
    programs = rts_programs(catalog.load("mpt3d_a"), SharedOptions(missing=True))
    P = np.kron(np.eye(3), [[2.0, 0.5], [0.5, 1.0]])
    x = np.arange(6.0)
    counter = OpCounter()
    python_function(programs["backward"])(
        *(counter.wrap(np.ravel(v)) for v in (x, P, x, P + np.eye(6), x, P)))
    assert counter.snapshot() == count(programs["backward"], "python")
    counter = OpCounter()
    python_function(programs["step"])(
        *(counter.wrap(np.ravel(v)) for v in (x, P, [1.0, np.nan, 2.0])))
    assert counter.snapshot() == count(programs["step"], "python")


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")
@pytest.mark.parametrize("use_fma", [False, True], ids=["plain", "fma"])
def test_c_of_both_programs_compiles_under_the_strict_flags(tmp_path, use_fma):
    lines = ["#include <math.h>", *c_printer.FMA_MACRO_LINES]
    for model in (catalog.load("mpt3d_a"), free_noise()):
        programs = rts_programs(model, SharedOptions(missing=True))
        for program in programs.values():
            parts = c_printer.function_parts(lower_program(program, use_fma=use_fma),
                                              model.name)
            lines += [parts["signature"], "{", *("    " + line for line in parts["body"]), "}"]
    source = tmp_path / "rts.c"
    source.write_text("\n".join(lines) + "\n")
    proc = subprocess.run(["gcc", *STRICT_CFLAGS, "-c", str(source), "-o",
                           str(tmp_path / "rts.o")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("steps", [0, 1, 2])
def test_short_runs(steps):
    model = catalog.load("gps_static")
    num = model.numeric()
    zs = measurements(num, steps=5)[:steps]
    xs, Ps = run_programs(rts_programs(model, SharedOptions()), zs, num.x0, num.P0)
    xr, Pr = rts(num, zs, num.x0, num.P0)
    assert xs.shape == xr.shape == (steps, 3)
    assert relative_error(xs, xr) <= PROGRAM_TOLERANCE
    assert relative_error(Ps, Pr) <= PROGRAM_TOLERANCE


def test_a_nonlinear_model_is_refused_with_one_line():
    with pytest.raises(FilterError, match="needs a linear model; 'gnss_pseudorange' is nonlinear"):
        rts_programs(catalog.load("gnss_pseudorange"), SharedOptions())


@pytest.mark.parametrize("name", LINEAR)
def test_smoothed_and_predicted_covariances_stay_in_the_filters_pattern(name):
    programs = rts_programs(catalog.load(name), SharedOptions())
    filtered = programs["step"].results["P_new"]
    for values in (programs["step"].results["P_pred"],
                   programs["backward"].results["P_smooth"]):
        assert [v != 0 for v in values] == [v != 0 for v in filtered]
