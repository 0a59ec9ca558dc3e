"""The UD filter registered by the recipe (issue 12, "The house"): ``udkf`` is in the
registry, generated for every linear catalog model, its ``run`` takes and returns P (P0
entered as U D Uᵀ, P stored from U and D) around a factored ``step``, and the generated
Python and C agree with the covariance KF (derive.reference.kf) to 1e-12 on the catalog
and on random stable models; the header states how pivots are checked (d + DBL_MIN > 0)
and divided by."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _random_models import stable_models
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import catalog, reference
from derive.apps.simulate import simulate_linear
from derive.apps.verify import relative_error
from derive.build import build_c, load_python
from derive.errors import PatternError
from derive.filters import FILTERS, available
from derive.options import taken_by
from derive.pipeline import load_generated

ROOT = Path(__file__).resolve().parents[2]
TOLERANCE = 1e-12
LINEAR = [name for name in catalog.names() if catalog.load(name).kind == "linear"]


def series(num, steps, seed):
    return simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs


def spd(n, seed):
    A = np.random.default_rng(seed).normal(size=(n, n))
    return A @ A.T / n + 0.5 * np.eye(n)


def test_udkf_is_registered_with_its_carried_state_and_options():
    spec = FILTERS["udkf"]
    assert spec.run_kind == "timevarying" and spec.model_kind == "linear"
    # no run_tracks: U, D
    assert taken_by("udkf") == ["P0_pattern", "missing", "loglik", "gradient", "start",
                                "prefix", "precision", "run"]
    for name in LINEAR:
        assert "udkf" in available(catalog.load(name)), name


@pytest.mark.parametrize("name", LINEAR)
def test_generated_udkf_matches_the_covariance_kf_on_the_catalog(name):
    """generated/MODEL/udkf.{py,c}, from the catalog's P0 (mostly 0: zero pivots) and
    from a positive diagonal P0; C with Ps NULL gives the same xs."""
    num = catalog.load(name).numeric()
    directory = ROOT / "generated" / name
    zs = series(num, 300, 11)
    header = (directory / "udkf.h").read_text()
    assert "udkf_run(steps, z[steps*" in header and "UD pivots: each pivot d is checked as " \
        "d + DBL_MIN" in header
    assert "U D U^T" in (directory / "udkf.py").read_text()
    c_module = build_c(directory / "udkf.c")
    for module in (load_python(directory / "udkf.py"), c_module):
        for P0 in (num.P0, np.diag(np.diag(spd(len(num.x0), 2)))):
            xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs)
            xs, Ps = module.run(zs, num.x0, P0)
            assert relative_error(xs, xr) <= TOLERANCE
            assert relative_error(np.reshape(Ps, Pr.shape), Pr) <= TOLERANCE
    xr, _ = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs)
    xs = c_module.run(zs, num.x0, num.P0, with_covariance=False)
    assert relative_error(xs, xr) <= TOLERANCE


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stable_models(), st.integers(0, 1000), st.booleans(), st.booleans())
def test_generated_udkf_matches_the_covariance_kf_on_random_models(model, seed, missing, c):
    """Dense P0 (P0_pattern dense), dense Q and correlated R, absent measurements or not;
    Python always, C in some examples (a compile each)."""
    num = model.numeric()
    zs = series(num, 60, seed)
    if missing:
        zs[np.random.default_rng(seed).random(zs.shape) < 0.3] = np.nan
    P0 = spd(model.n, seed)
    options = {"P0_pattern": "dense", "missing": missing}
    loaded = load_generated(model, "udkf", options, lang="all" if c else "python")
    xr, Pr = reference.kf(num.F, num.G, num.H, num.Q, num.R, num.x0, P0, zs)
    for module in [loaded.python] + ([loaded.c] if c else []):
        xs, Ps = module.run(zs, num.x0, P0)
        assert relative_error(xs, xr) <= TOLERANCE
        assert relative_error(np.reshape(Ps, Pr.shape), Pr) <= TOLERANCE


def test_run_refuses_p0_outside_the_pattern_naming_the_entry():
    """mpt3d_a's axes are independent: a P0 coupling two axes is refused by enter, as
    PatternError naming P0's entry, in Python and in C."""
    directory = ROOT / "generated" / "mpt3d_a"
    num = catalog.load("mpt3d_a").numeric()
    P0 = np.eye(6)
    P0[0, 2] = P0[2, 0] = 0.25
    zs = series(num, 5, 1)
    for module in (load_python(directory / "udkf.py"), build_c(directory / "udkf.c")):
        with pytest.raises(PatternError, match=r"P0\[0\]\[2\] = 0\.25"):
            module.run(zs, num.x0, P0)
