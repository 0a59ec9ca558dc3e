"""The navigation rows of ``derive bench`` (derive.apps.bench.peers.navigation) and the peers they
time and count: the SymForce, CasADi and FilterPy versions of the INS EKF compute the NumPy
reference's numbers, SymForce's C++ is counted by derive's C rules, and the rows and bars
come out of one run. No wall-clock assertions."""

from __future__ import annotations

import re

import numpy as np
import pytest

from derive import catalog
from derive.apps.bench.bars import BARS
from derive.apps.bench.peers.navigation import (
    BATCH_FORM,
    FUNCTIONS,
    SCALAR_ROWS,
    TIMED,
    run_navigation,
    sequential_updates,
)
from derive.apps.bench.run import Bar
from derive.apps.ins import constants as c
from derive.apps.ins import reference, symforce_ekf
from derive.trees import OpCount


def _point(seed=2):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    x = np.concatenate([q / np.linalg.norm(q), rng.normal(size=12) * 0.1])
    a = rng.normal(size=(16, 16)) * 0.1
    return x, a @ a.T + c.p0(), rng.normal(size=6), rng.normal(size=6)


def _evaluate(sf, function, values):
    """The function's symbolic outputs (what SymForce generates code from) at ``values``."""
    symbols = [sf.Matrix(*np.shape(v)).symbolic(name) if np.ndim(v) else sf.Symbol(name)
               for name, v in values]
    mapping = {}
    for sym, (_, value) in zip(symbols, values):
        if np.ndim(value):
            for index in np.ndindex(*np.shape(value)):
                mapping[sym[index]] = float(value[index])
        else:
            mapping[sym] = float(value)
    return [np.array(out.subs(mapping).to_numpy(), dtype=float) for out in function(*symbols)]


def test_symforce_functions_compute_the_reference_numbers():
    sf = pytest.importorskip("symforce.symbolic")
    functions = symforce_ekf.model_functions(sf, catalog.load("ins_gnss"))
    x, P, u, z = _point()
    column = x.reshape(-1, 1)
    upper = np.triu(P)  # the functions read the upper triangle only
    got_x, got_P = _evaluate(sf, functions["predict"][0],
                             [("x", column), ("P", upper), ("u", u.reshape(-1, 1)), ("dt", 0.01)])
    x_ref, P_ref = reference.predict(x, P, u, 0.01)
    assert np.allclose(got_x.ravel(), x_ref, rtol=1e-13, atol=1e-15)
    assert np.allclose(got_P, P_ref, rtol=1e-12, atol=1e-15)
    for name, measured in (("gnss", z), ("baro", z[:1])):
        got_x, got_P = _evaluate(sf, functions[f"update_{name}"][0],
                                 [("x", column), ("P", upper), ("z", measured.reshape(-1, 1))])
        x_ref, P_ref, _, _ = reference.update(x, P, measured, name)
        assert np.allclose(got_x.ravel(), x_ref, rtol=1e-12, atol=1e-14)
        assert np.allclose(got_P, P_ref, rtol=1e-11, atol=1e-14)


def test_symforce_cpp_is_counted_by_derives_c_rules():
    source = """
template <typename Scalar>
void Demo(const Eigen::Matrix<Scalar, 2, 1>& x, Eigen::Matrix<Scalar, 2, 1>* const out = nullptr) {
  // Total ops: 9
  const Scalar _tmp0 = (Scalar(1) / Scalar(2)) * x(0, 0);
  const Scalar _tmp1 = std::pow(x(1, 0), Scalar(3)) - _tmp0;
  if (out != nullptr) {
    Eigen::Matrix<Scalar, 2, 1>& _out = (*out);
    _out(0, 0) = -_tmp1 + Scalar(2.5);
    _out(1, 0) = std::pow(Scalar(std::pow(_tmp0, Scalar(2)) + 1), Scalar(Scalar(-1) / Scalar(2)));
  }
}
"""
    assert symforce_ekf.total_ops(source) == 9
    # 1 mul (the constant half), 2 mul (cube), 1 sub; neg + add; 1 mul (square), 1 add,
    # sqrt and div (the inverse square root)
    assert symforce_ekf.count_cpp(source) == OpCount(add=2, sub=1, mul=4, div=1, sqrt=1,
                                                     neg=1)


def test_symforce_codegen_of_the_baro_update():
    pytest.importorskip("symforce")
    generated = symforce_ekf.generate(("update_baro",))["update_baro"]
    assert generated.seconds > 0 and "Total ops" in generated.source
    # its own count and derive's rules differ only in what they call an operation
    assert abs(generated.count.flops - generated.total_ops) < 0.1 * generated.total_ops


@pytest.fixture(scope="module")
def navigation(tmp_path_factory):
    pytest.importorskip("cffi")
    return run_navigation(tmp_path_factory.mktemp("nav"), calls=50, python_calls=2, repeats=1,
                          symforce=False)


def test_rows_agree_with_the_reference_and_ratios_are_per_generated_c(navigation):
    assert [r.function for r in navigation.counts] == list(FUNCTIONS)
    for r in navigation.counts:
        assert r.derive.flops > 0 and r.symforce is None and r.ratio is None
    assert {(r.function, r.implementation) for r in navigation.times} == {
        (f, i) for f in TIMED for i in ("generated C", "CasADi C", "FilterPy")} | {
        (f, BATCH_FORM) for f in sequential_updates()} | {
        (f, SCALAR_ROWS) for f in TIMED}  # the catalog derives both as vector rows
    assert navigation.vector == frozenset(FUNCTIONS)  # baro: one measurement, rows too
    assert any(n.startswith("predict is vector rows") for n in navigation.notes)
    assert sequential_updates() == ("update_gnss",)  # the catalog fuses GNSS sequentially
    assert any(n.startswith("update_gnss is sequential") for n in navigation.notes)
    for r in navigation.times:
        if r.timing is None:
            assert r.note.startswith("skipped: ")
            continue
        assert r.agreement <= 1e-12, (r.function, r.implementation, r.agreement)
        if r.implementation == "CasADi C":   # the minima of the two timed in turns
            ours = re.search(r"calls timed in turns with derive's \(([\d.]+) (ns|µs)\)", r.note)
            seconds = float(ours[1]) * (1e-9 if ours[2] == "ns" else 1e-6)
            assert r.ratio == pytest.approx(r.timing.low / seconds, rel=6e-3)  # 3 digits
            continue
        base = navigation.time_row(r.function, "generated C").timing.median
        assert r.ratio == pytest.approx(r.timing.median / base)
    assert navigation.generation_seconds > 0
    assert any("SymForce" in n for n in navigation.notes)


def test_bars_and_text(navigation):
    bars = navigation.bars(Bar)
    claims = [b.claim for b in bars]
    assert claims[0].startswith("generating ins_gnss EKF")
    assert bars[0].bar == BARS["ins_gnss_generation"]
    for function in TIMED:
        for peer, need in (("FilterPy", BARS["ins_over_filterpy"]),
                           ("CasADi C", BARS["ins_over_casadi"])):
            bar = next(b for b in bars if b.claim.endswith(f"{function} faster per call than "
                                                          f"{peer}"))
            assert bar.bar == need
            assert bar.value == navigation.time_row(function, peer).ratio
    text = "\n".join(navigation.lines())
    assert "update_gnss" in text and "SymForce" in text
    assert set(navigation.as_json()) >= {"generation_seconds", "counts", "times"}
