"""Long runs of the generated C filters: 1,000,000 steps of KF, Joseph-form KF and LF on
mpt3d_a and on a poorly conditioned model, illcond (mpt3d_a's structure with measurement
noise 1e-8 and process noise 1e4).

Every step: x finite, P finite, exactly symmetric (symmetric storage) and positive
semidefinite (P + delta I has a Cholesky factor, delta = 64 eps trace(P)); the three
filters agree with one another and, over all 1,000,000 steps, with the NumPy reference.

The reference, ``reference.kf``, needs minutes for a million steps.  Its covariance
recursion does not depend on z, and its post-update P becomes periodic after a few dozen
steps (a bitwise repeat of a deterministic map), so :func:`periodic_reference_kf` does the
reference's own arithmetic, operation for operation, with the gains of one period reused:
bitwise the reference's output (checked on 5,000 steps here, and on all 1,000,000 by the
``slow`` test, run with ``DERIVE_SLOW=1``).
"""
import os
from functools import cache

import numpy as np
import pytest
import sympy

from derive import LinearModel, catalog, reference
from derive.apps.float_tolerance import FloatTolerance, ReferenceRun, float_tolerance
from derive.apps.verify import relative_error
from derive.generation import command_unit
from derive.pipeline import load_generated
from derive.precision import DOUBLE

STEPS = 1_000_000
CHUNK = 100_000
REFERENCE_TOLERANCE = 1e-9
"""The issue's bar: within 1e-9 (normwise relative per step) of the NumPy reference."""
AGREEMENT_TOLERANCE = 1e-12
"""The issue's bar for KF, Joseph-form KF and LF, all generated, against one another."""
CONDITIONING_STEPS = 3000
"""Steps of the reference run the double bound reads kappa from: P is periodic after a few
dozen steps, so these hold every step the million do."""
RUN_SLOW = os.environ.get("DERIVE_SLOW") == "1"
FILTERS = {"kf": ("kf", {}), "kf_joseph": ("kf", {"joseph": True}), "lf": ("lf", {})}


def axis(q: float, r: float) -> LinearModel:
    dt, sq2, sr2 = sympy.symbols("dt sq2 sr2")
    return LinearModel("axis", ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, dt]], [[sq2]],
                       [[sr2]], G=[[dt / 2], [1]], values={"dt": 1, "sq2": q, "sr2": r})


def model(name: str) -> LinearModel:
    if name == "mpt3d_a":
        return catalog.load(name)
    return LinearModel.compose("illcond", [axis(1e4, 1e-8)] * 3, suffixes=["x", "y", "z"])


@cache
def measurements(name: str, steps: int = STEPS, seed: int = 11) -> np.ndarray:
    """z(1..steps) of the model's three constant-velocity axes, simulated in closed form:
    v(k) = sum_{j<k} w(j), s(k) = sum_{j<k} (v(j) + w(j)/2), z(k) = s(k) + v(k) + e(k)."""
    num = model(name).numeric()
    q, r = num.Q[0, 0], num.R[0, 0]
    rng = np.random.default_rng(seed)
    w = rng.normal(scale=np.sqrt(q), size=(steps, 3))
    v = np.cumsum(w, axis=0)                     # v(k), k = 1..steps
    v_before = np.vstack([np.zeros((1, 3)), v[:-1]])
    s = np.cumsum(v_before + w / 2, axis=0)      # s(k), k = 1..steps
    return s + v + rng.normal(scale=np.sqrt(r), size=(steps, 3))


def test_closed_form_measurements_follow_the_model():
    """The closed form is the model's recursion x(k+1) = F x(k) + G w(k), z = H x + e."""
    num = model("mpt3d_a").numeric()
    steps, rng = 1000, np.random.default_rng(11)
    w = rng.normal(scale=np.sqrt(num.Q[0, 0]), size=(steps, 3))
    e = rng.normal(scale=np.sqrt(num.R[0, 0]), size=(steps, 3))
    x, zs = np.zeros(6), np.empty((steps, 3))
    for k in range(steps):
        x = num.F @ x + num.G @ w[k]
        zs[k] = num.H @ x + e[k]
    np.testing.assert_allclose(measurements("mpt3d_a", steps), zs, rtol=1e-12, atol=1e-12)


@cache
def compiled(name: str, key: str, tmp: str):
    filter_name, options = FILTERS[key]
    return load_generated(model(name), filter_name, options, "c", os.path.join(tmp, key)).c


def distinct(Ps: np.ndarray) -> np.ndarray:
    """The distinct matrices of ``Ps`` (bitwise), or all of them where two share a hash.

    A filter's P(k) is a deterministic map of P(k-1) alone, and settles into a cycle of a
    few dozen matrices: the factorisations of a million steps are those of the cycle's.
    Each matrix is hashed by a random weighting of its entries and checked equal, bit for
    bit, to the first matrix of its hash."""
    rows = Ps.reshape(len(Ps), -1)
    hashes = rows @ np.random.default_rng(0).random(rows.shape[1])
    _, first, inverse = np.unique(hashes, return_index=True, return_inverse=True)
    if not np.array_equal(rows, rows[first[inverse.ravel()]]):
        return Ps
    return Ps[first]


def _delta(Ps: np.ndarray) -> np.ndarray:
    return 64 * np.finfo(float).eps * np.trace(Ps, axis1=1, axis2=2)


def _semidefinite(Ps: np.ndarray) -> bool:
    """P + delta I has a Cholesky factor for every P of ``Ps``."""
    try:
        np.linalg.cholesky(Ps + _delta(Ps)[:, None, None] * np.eye(Ps.shape[1]))
    except np.linalg.LinAlgError:
        return False
    return True


def check_covariances(Ps: np.ndarray, where: str) -> None:
    assert np.all(np.isfinite(Ps)), where
    assert np.array_equal(Ps, Ps.transpose(0, 2, 1)), f"{where}: P is not symmetric"
    if not _semidefinite(distinct(Ps)):
        delta = _delta(Ps)
        low = np.linalg.eigvalsh(Ps).min(axis=1) / np.maximum(delta, np.finfo(float).tiny)
        k = int(np.argmin(low))
        pytest.fail(f"{where}: P is not positive semidefinite at step {k} "
                    f"(smallest eigenvalue {low[k]:.3g} delta)")


def test_the_covariance_check_factorises_each_distinct_matrix():
    """A cycle of two matrices over 1000 steps is factorised as two, and an indefinite
    matrix anywhere in it is found at its step."""
    good, bad = np.diag([2.0, 1.0]), np.array([[1.0, 2.0], [2.0, 1.0]])
    Ps = np.stack([good, 3 * good] * 500)
    assert len(distinct(Ps)) == 2
    check_covariances(Ps, "cycle")
    Ps[777] = bad
    assert len(distinct(Ps)) == 3
    with pytest.raises(pytest.fail.Exception, match="at step 777"):
        check_covariances(Ps, "cycle")


def periodic_reference_kf(num, zs):
    """``reference.kf(F, G, H, Q, R, x0, P0, zs)`` for a series without NaN, fast.

    Runs the reference's covariance recursion (same operations) until its post-update P
    repeats bitwise; from then on P, and so the gain K and I - K H of each step, repeat
    with that period.  The state recursion then does the reference's per-step operations
    with the stored gains.  Returns xs (steps, n) and a function giving Ps for a range of
    steps (a million 6 x 6 covariances would take 288 MB).
    """
    F, H, R = num.F, num.H, num.R
    GQG = num.G @ num.Q @ num.G.T
    n = F.shape[0]
    P = np.asarray(num.P0, dtype=float)
    gains, covariances, seen = [], [], {}
    while True:
        P = GQG + F @ P @ F.T                               # P(k+1/k)
        PHt = P @ H.T
        K = np.linalg.solve((H @ PHt + R).T, PHt.T).T
        IKH = np.eye(n) - K @ H
        P = IKH @ P                                         # P(k+1/k+1)
        gains.append((IKH, K))
        covariances.append(P)
        key = P.tobytes()
        if key in seen:
            base, period = seen[key] + 1, len(gains) - 1 - seen[key]
            break
        seen[key] = len(gains) - 1
    step = np.arange(len(zs))
    index = np.where(step < base, step, base + (step - base) % period)
    x = np.asarray(num.x0, dtype=float)
    xs = np.empty((len(zs), n))
    matmul = np.matmul
    for k, (z, i) in enumerate(zip(zs, index.tolist())):
        IKH, K = gains[i]
        x = matmul(IKH, matmul(F, x)) + matmul(K, z)       # x = F x; x = (I-KH) x + K z
        xs[k] = x
    covariances = np.stack(covariances)
    return xs, lambda start, stop: covariances[index[start:stop]]


def test_periodic_reference_is_the_reference_bitwise():
    for name in ("mpt3d_a", "illcond"):
        num = model(name).numeric()
        zs = measurements(name)[:5000]
        xs, Ps = periodic_reference_kf(num, zs)
        xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs,
                              skip_nan=False)
        assert np.array_equal(xs, xr) and np.array_equal(Ps(0, len(zs)), Pr), name


def long_run(name: str, tmp: str) -> dict[str, float]:
    """Run the three filters chunk by chunk over STEPS steps with every check, and compare
    with one another and with the reference.  Returns the worst errors."""
    num = model(name).numeric()
    zs = measurements(name)
    modules = {key: compiled(name, key, tmp) for key in FILTERS}
    state = {key: (num.x0, num.P0) for key in FILTERS}
    xr_all, Pr_chunk = periodic_reference_kf(num, zs)
    worst = {"agreement": 0.0, "reference x": 0.0, "reference P": 0.0}
    for start in range(0, STEPS, CHUNK):
        chunk = zs[start:start + CHUNK]
        outputs = {}
        for key, module in modules.items():
            xs, Ps = module.run(chunk, *state[key])
            assert np.all(np.isfinite(xs)), f"{name} {key}: x not finite after step {start}"
            check_covariances(Ps, f"{name} {key}, steps {start + 1}..{start + CHUNK}")
            state[key] = (xs[-1], Ps[-1])
            outputs[key] = (xs, Ps)
        xk, Pk = outputs["kf"]
        for key in ("kf_joseph", "lf"):
            xs, Ps = outputs[key]
            worst["agreement"] = max(worst["agreement"], relative_error(xs, xk),
                                     relative_error(Ps, Pk))
        xr, Pr = xr_all[start:start + CHUNK], Pr_chunk(start, start + CHUNK)
        for xs, Ps in outputs.values():
            worst["reference x"] = max(worst["reference x"], relative_error(xs, xr))
            worst["reference P"] = max(worst["reference P"], relative_error(Ps, Pr))
    return worst


@cache
def double_bound(name: str) -> float:
    """The largest of the three forms' error bounds in double, c u64 L G kappa
    (derive.apps.float_tolerance, with float64's unit roundoff), over STEPS steps.

    On illcond every update cancels P(k+1/k) ~ 1e4 down to P(k/k) ~ 7e-9: the covariance
    forms' kappa (P(k/k-1) -> P(k/k)) is ~2e12, the known loss of ~log10(P(k+1/k)/P(k/k))
    = 13 digits of the covariance KF, so measured against P(k/k)'s own size (the error
    measure, derive.apps.verify.relative_error) the forms and the NumPy reference (the
    same covariance recursion) agree to ~3e-4 only, within this bound (~2e-2), not to the
    issue's bars. On mpt3d_a the bound is far below the bars, which hold."""
    num = model(name).numeric()
    xs, Ps = periodic_reference_kf(num, measurements(name)[:CONDITIONING_STEPS])
    run = ReferenceRun(xs, Ps(0, CONDITIONING_STEPS), None, num.x0, num.P0)
    bounds = []
    for filter_name, options in FILTERS.values():
        bound = float_tolerance(model(name), command_unit(model(name), filter_name, options),
                                STEPS, run)
        bounds.append(FloatTolerance(bound.roundings, bound.growth, bound.condition,
                                     unit_roundoff=DOUBLE.unit_roundoff).value)
    return max(bounds)


@pytest.mark.parametrize("name", ["mpt3d_a", "illcond"])
def test_million_steps_stay_sane_and_close_to_the_reference(tmp_path_factory, name):
    """The issue's bars, or where the model's conditioning puts them out of reach of
    double, twice :func:`double_bound` (each side of a comparison within it)."""
    worst = long_run(name, str(tmp_path_factory.mktemp(name)))
    reachable = 2 * double_bound(name)
    assert worst["agreement"] <= max(AGREEMENT_TOLERANCE, reachable), (worst, reachable)
    assert worst["reference x"] <= max(REFERENCE_TOLERANCE, reachable), (worst, reachable)
    assert worst["reference P"] <= max(REFERENCE_TOLERANCE, reachable), (worst, reachable)


def test_the_double_bound_is_what_keeps_illcond_from_the_bars():
    """illcond's bound is above the bars (its P(k/k) is cancelled by 13 digits), mpt3d_a's
    far below them: the bars are relaxed only where the conditioning demands it."""
    assert 2 * double_bound("mpt3d_a") < AGREEMENT_TOLERANCE
    assert 2 * double_bound("illcond") > REFERENCE_TOLERANCE


@pytest.mark.slow
@pytest.mark.skipif(not RUN_SLOW, reason="1,000,000 steps of reference.kf take minutes; "
                                         "set DERIVE_SLOW=1")
@pytest.mark.parametrize("name", ["mpt3d_a", "illcond"])
def test_periodic_reference_is_the_reference_all_the_way(name):
    num = model(name).numeric()
    zs = measurements(name)
    xs, Ps = periodic_reference_kf(num, zs)
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs,
                          skip_nan=False)
    assert np.array_equal(xs, xr)
    for start in range(0, STEPS, CHUNK):
        assert np.array_equal(Ps(start, start + CHUNK), Pr[start:start + CHUNK])


def test_the_poorly_conditioned_model_is_poorly_conditioned(tmp_path_factory):
    """In steady state P(k+1/k) has condition number >= 1e10 and each update shrinks it by
    ten orders of magnitude, so the long run exercises heavy cancellation."""
    module = compiled("illcond", "kf", str(tmp_path_factory.mktemp("cond")))
    num = model("illcond").numeric()
    _, Ps = module.run(measurements("illcond")[:2000], num.x0, num.P0)
    predicted = num.F @ Ps[-1] @ num.F.T + num.GQGt
    eig = np.linalg.eigvalsh(predicted)
    assert eig.max() / eig.min() >= 1e10
    assert np.linalg.norm(predicted) / np.linalg.norm(Ps[-1]) >= 1e10
