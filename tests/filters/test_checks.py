"""The papers' equivalence claims as derive check measures them."""

import sympy

from derive import LinearModel, catalog
from derive.apps.checks import is_pseudorange_model, run_checks


def test_mpt3d_a_claims_all_hold_including_the_three_axes():
    checks = run_checks(catalog.load("mpt3d_a"), steps=200)
    assert all(c.passed for c in checks), [c.line() for c in checks if not c.passed]
    claims = [c.claim for c in checks]
    assert "whole model = its 3 blocks merged (KF)" in claims
    assert "A_KF = A_LF and B_KF = B_LF" in claims


def test_a_model_without_steady_state_gets_only_the_time_varying_claims():
    """F unstable and unobserved: no steady state, so no steady-state claim is measured."""
    m = LinearModel("undetectable", ["a", "b"], ["y"], [[1.2, 0], [0, 0.5]], [[0, 1]],
                    sympy.eye(2), [[1]], values=None)
    checks = run_checks(m, steps=50)
    assert [c.claim.split(",")[0] for c in checks] == ["KF = LF", "KF = JKLF"]
    assert all(c.passed for c in checks)


def test_only_the_pseudorange_model_gets_the_gnss_papers_claims():
    """The GNSS paper's scenario feeds satellites' coordinates to h: a nonlinear model of
    another shape (the radar tracker, the INS/GNSS EKFs) has no claim of it, rather than a
    shape error from its scenario."""
    nonlinear = {name: catalog.load(name) for name in catalog.names()
                 if catalog.load(name).kind != "linear"}
    assert [n for n, m in nonlinear.items() if is_pseudorange_model(m)] == ["gnss_pseudorange"]
    assert run_checks(nonlinear["ctrv_radar"], steps=50) == []
