"""The generated RTS smoother (filter ``rts``, run kind ``smoother``): generated Python and
C against the NumPy reference (missing measurements included), against FilterPy's
``rts_smoother`` and pykalman's ``smooth``, the caller's work array, the header, and the
registration through the seams only (spec, kind entry, one template per language)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from test_rts import (
    PEER_TOLERANCE,
    filterpy_smooth,
    free_noise,
    measurements,
    pykalman_smooth,
    with_gaps,
)

from derive import LinearModel, catalog
from derive.apps.verify import relative_error
from derive.errors import NumericalError, PatternError
from derive.filters import FILTERS, available, derive_unit
from derive.pipeline import load_generated
from derive.reference.smoother import rts
from derive.runs.unit import RUN_KINDS, run_arguments

LINEAR = [name for name in catalog.names() if catalog.load(name).kind == "linear"]
GENERATED_TOLERANCE = 1e-12
ROOT = Path(__file__).resolve().parents[2]


def smoothed(module, zs, x0, P0, **kw):
    xs, Ps = module.run(zs, x0, P0, **kw)
    xs, Ps = np.asarray(xs), np.asarray(Ps)
    return xs, Ps.reshape(len(zs), len(x0), len(x0))


@pytest.fixture(scope="module", params=LINEAR)
def missing_generated(request):
    return request.param, load_generated(request.param, "rts", {"missing": True})


@pytest.mark.parametrize("lang", ["python", "c"])
def test_generated_equals_the_reference_with_missing_measurements(missing_generated, lang):
    name, generated = missing_generated
    num = catalog.load(name).numeric()
    for whole_rows in (True, False):
        zs = with_gaps(measurements(num), seed=11, whole_rows=whole_rows)
        xs, Ps = smoothed(generated.module(lang), zs, num.x0, num.P0)
        xr, Pr = rts(num, zs, num.x0, num.P0, skip_nan=True)
        assert np.all(np.isfinite(xs)) and np.all(np.isfinite(Ps))
        assert relative_error(xs, xr) <= GENERATED_TOLERANCE, (name, lang, whole_rows)
        assert relative_error(Ps, Pr) <= GENERATED_TOLERANCE, (name, lang, whole_rows)


@pytest.mark.parametrize("name", ["gsm2d_a", "mpt3d_a", "gps_static"])
@pytest.mark.parametrize("peer", [filterpy_smooth, pykalman_smooth], ids=["filterpy", "pykalman"])
def test_generated_equals_filterpy_and_pykalman(name, peer):
    num = catalog.load(name).numeric()
    generated = load_generated(name, "rts", {"missing": True})
    for zs in (measurements(num), with_gaps(measurements(num), seed=5, whole_rows=True)):
        xp, Pp = peer(num, zs)
        for lang in ("python", "c"):
            xs, Ps = smoothed(generated.module(lang), zs, num.x0, num.P0)
            assert relative_error(xs, xp) <= PEER_TOLERANCE, (name, lang)
            assert relative_error(Ps, Pp) <= PEER_TOLERANCE, (name, lang)


def test_free_parameters_one_row_or_one_per_step():
    model = free_noise()
    generated = load_generated(model, "rts", {"missing": True})
    num = model.numeric({"r": 0.4})
    zs = with_gaps(measurements(num, steps=80), seed=2, whole_rows=False)
    xr, Pr = rts(num, zs, num.x0, num.P0, skip_nan=True)
    per_step = {}
    for lang in ("python", "c"):
        module = generated.module(lang)
        for p in ([0.4], np.full((80, 1), 0.4)):
            xs, Ps = smoothed(module, zs, num.x0, num.P0, p=p)
            assert relative_error(xs, xr) <= GENERATED_TOLERANCE
            assert relative_error(Ps, Pr) <= GENERATED_TOLERANCE
        per_step[lang] = smoothed(module, zs, num.x0, num.P0,
                                  p=np.linspace(0.2, 0.6, 80)[:, np.newaxis])
    assert relative_error(per_step["c"][0], per_step["python"][0]) <= GENERATED_TOLERANCE
    assert relative_error(per_step["c"][0], xr) > 1e-6


def test_c_work_array_is_the_kinds_rows_and_the_header_states_it():
    model = catalog.load("mpt3d_a")
    unit = derive_unit(model, "rts")
    work = [a for a in run_arguments(unit) if a.scratch]
    n = model.n
    assert [(a.c_name, a.dims) for a in work] == [("work", ("steps", 2 * n + 2 * n * n))]
    header = (ROOT / "generated" / "mpt3d_a" / "rts.h").read_text()
    assert ("mpt3d_a_rts_run(steps, z[steps*3], x0[6], P0[6*6], xs[steps*6] out, "
            "Ps[steps*6*6] out, work[steps*84] out)") in header
    assert "work: steps * 84 doubles, steps * (2 n + 2 n^2)" in header
    source = (ROOT / "generated" / "mpt3d_a" / "rts.c").read_text()
    run = source[source.index("int mpt3d_a_rts_run(size_t steps"):]
    assert "malloc" not in source and "[steps" not in run
    assert "mpt3d_a_rts_backward(" in run and "mpt3d_a_rts_step(" in run


def test_c_reads_no_work_double_it_did_not_write(tmp_path):
    """The C run on a caller's work array filled with NaN (and xs, Ps too): every double
    it reads was written first, so the result equals the reference."""
    model = catalog.load("gsm2d_a")
    num = model.numeric()
    generated = load_generated(model, "rts", {})
    c = generated.c
    ffi, lib = c.ffi, c.lib
    zs = measurements(num, steps=30)
    steps, n = len(zs), model.n
    work = np.full(steps * (2 * n + 2 * n * n), np.nan)
    xs, Ps = np.full(steps * n, np.nan), np.full(steps * n * n, np.nan)

    def buf(a):
        return ffi.from_buffer("double[]", a)

    status = lib.gsm2d_a_rts_run(steps, buf(np.ascontiguousarray(zs).ravel()), buf(num.x0),
                                 buf(np.ascontiguousarray(num.P0).ravel()), buf(xs), buf(Ps),
                                 buf(work))
    assert status == 0
    xr, Pr = rts(num, zs, num.x0, num.P0)
    assert relative_error(xs.reshape(steps, n), xr) <= GENERATED_TOLERANCE
    assert relative_error(Ps.reshape(steps, n, n), Pr) <= GENERATED_TOLERANCE


@pytest.mark.parametrize("steps", [0, 1, 2])
def test_short_runs(steps):
    num = catalog.load("gps_static").numeric()
    generated = load_generated("gps_static", "rts", {})
    zs = measurements(num, steps=5)[:steps]
    xr, Pr = rts(num, zs, num.x0, num.P0)
    for lang in ("python", "c"):
        xs, Ps = smoothed(generated.module(lang), zs, num.x0, num.P0)
        assert xs.shape == xr.shape == (steps, 3)
        assert relative_error(xs, xr) <= GENERATED_TOLERANCE
        assert relative_error(Ps, Pr) <= GENERATED_TOLERANCE


def test_python_runs_many_tracks_at_once():
    num = catalog.load("cv").numeric()
    module = load_generated("cv", "rts", {}, lang="python").python
    zs = [measurements(num, steps=40, seed=s) for s in (1, 2)]
    xs, Ps = module.run(np.stack(zs, axis=-1), num.x0, num.P0)
    for t, z in enumerate(zs):
        xr, Pr = rts(num, z, num.x0, num.P0)
        assert relative_error(xs[..., t], xr) <= GENERATED_TOLERANCE
        assert relative_error(Ps[..., t], Pr) <= GENERATED_TOLERANCE


def test_a_singular_prediction_stops_the_backward_pass_with_its_check():
    """Q = 0 and P0 = 0: P(k+1/k) = 0, the backward solve's first pivot fails."""
    frozen = LinearModel("frozen", ["a"], ["z"], [[1.0]], [[1.0]], [[0.0]], [[0.5]],
                         P0=[[0.0]])
    generated = load_generated(frozen, "rts", {})
    zs = np.ones((4, 1))
    with pytest.raises(NumericalError, match=r"P\(k\+1/k\) is not positive definite"):
        generated.python.run(zs, [0.0], [[0.0]])
    with pytest.raises(NumericalError, match=r"P\(k\+1/k\) is not positive definite"):
        generated.c.run(zs, [0.0], [[0.0]])


def test_P0_outside_the_pattern_is_refused_in_both_languages():
    num = catalog.load("gps_static").numeric()
    generated = load_generated("gps_static", "rts", {})
    P0 = np.eye(3) + 0.1
    for lang in ("python", "c"):
        with pytest.raises(PatternError, match="outside the pattern"):
            generated.module(lang).run(measurements(num, steps=5), num.x0, P0)


def test_registered_through_the_seams():
    spec = FILTERS["rts"]
    assert (spec.run_kind, spec.model_kind, spec.missing, spec.run_tracks) == (
        "smoother", "linear", True, False)
    assert RUN_KINDS["smoother"].work == (("work", ("x_new", "P_new", "x_pred", "P_pred")),)
    for name in LINEAR:
        assert "rts" in available(catalog.load(name))
        for suffix in ("py", "c", "h"):
            assert (ROOT / "generated" / name / f"rts.{suffix}").is_file()
    for path in (ROOT / "derive" / "emit").glob("*.py"):
        assert not re.search(r"\brts\b", path.read_text()), path
    for path in (ROOT / "derive" / "runs").glob("*.py"):
        assert not re.search(r"\brts\b", path.read_text()), path
