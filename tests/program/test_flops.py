"""derive.flops: the static count, checked dynamically (CountingFloat) and on the C text."""

import numpy as np
import pytest
import sympy
from _backend_kf import cv_axes, kf_program, kf_unit
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import staging
from derive.build import load_python
from derive.emit.python_printer import python_function
from derive.emit.render import render_functions, render_unit
from derive.emit.write import write_files
from derive.flops import CountingFloat, OpCounter, count, count_c_function, count_c_text
from derive.program import Port, Program
from derive.trees import OpCount


def test_opcount_totals():
    n = OpCount(add=1, sub=2, mul=3, div=4, sqrt=5, fma=6, neg=7, cmp=8, calls=9)
    assert n.flops == 1 + 2 + 3 + 4 + 5 + 2 * 6
    assert n.instructions == 1 + 2 + 3 + 4 + 5 + 6 + 7 + 8
    assert (n + n).as_dict() == {k: 2 * v for k, v in n.as_dict().items()}
    assert "fma 6" in n.summary() and "flops 27" in n.summary()


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 4), st.integers(1, 4), st.integers(1, 4))
def test_dense_products_cost_what_the_papers_charge(n, m, k):
    """SPEC §5: (n x m)(m x k) costs 2nmk - nk; symmetric (n x m)(m x n) n^2 m + nm - (n^2+n)/2."""
    prog = Program("f", [Port("A", (n, m)), Port("B", (m, k))],
                   [Port("Y", (n, k)), Port("S", (n, n), symmetric=True)])
    A, B = prog.matrix("A"), prog.matrix("B")
    prog.set_output("Y", staging.matmul(prog, A, B))
    prog.set_output("S", staging.matmul(prog, A, A.T, symmetric_result=True))
    assert count(prog).flops == (2 * n * m * k - n * k) + (n * n * m + n * m - (n * n + n) // 2)


def _dynamic(program, *inputs):
    counter = OpCounter()
    python_function(program)(*(counter.wrap(np.ravel(v)) for v in inputs))
    return counter.snapshot()


def _kf_inputs(n, m, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    return (rng.normal(size=n), A @ A.T + np.eye(n), rng.normal(size=m), [0.5, 0.01, 0.1])


@pytest.mark.parametrize("axes", [1, 2, 3])
def test_counting_float_reproduces_the_static_count_of_a_kf(axes):
    prog = kf_program(*cv_axes(axes))
    dynamic = _dynamic(prog, *_kf_inputs(2 * axes, axes))
    assert dynamic == count(prog, "python")
    # one pivot per axis; with a dense P each pivot divides 2*axes entries: one shared
    # reciprocal from three entries on, two direct divisions for a single axis
    assert dynamic.cmp == axes and dynamic.div == (2 if axes == 1 else axes)


def _factor_program(m):
    prog = Program("factor", [Port("S", (m, m), symmetric=True), Port("A", (m, m))],
                   [Port("L", (m, m)), Port("X", (m, 2)), Port("Sinv", (m, m), symmetric=True),
                    Port("Ainv", (m, m))])
    S, A = prog.matrix("S"), prog.matrix("A")
    prog.set_output("L", staging.cholesky(prog, S))
    prog.set_output("X", staging.spd_solve(prog, S, A[:, :2] if m > 1 else A.row_join(A)))
    prog.set_output("Sinv", staging.spd_inverse(prog, S))
    prog.set_output("Ainv", staging.lu_inverse(prog, A))
    return prog


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_counting_float_reproduces_factorisation_counts(m):
    rng = np.random.default_rng(m)
    B = rng.normal(size=(m, m))
    prog = _factor_program(m)
    assert _dynamic(prog, B @ B.T + np.eye(m), B + 3 * np.eye(m)) == count(prog, "python")


def test_counting_float_counts_each_operation():
    counter = OpCounter()
    a, b = counter.wrap([2.0, 8.0])
    r = (a + b) * 2.0 - b / a
    _ = -r, (1.0 - a), b ** 0.5, a > 0, abs(a)
    assert counter.snapshot() == OpCount(add=1, mul=1, sub=2, div=1, neg=1, sqrt=1, cmp=1,
                                         calls=1)
    assert isinstance(r, CountingFloat) and r.value == pytest.approx(16.0)


@pytest.mark.parametrize("text, expected", [
    ("const double t0 = a*b + c - d/e;", OpCount(add=1, sub=1, mul=1, div=1)),
    ("const double t1 = -x[0] + (-2.0)*y;", OpCount(add=1, neg=1, mul=1)),
    ("t = DERIVE_FMA(a, -b, c) - sqrt(d);", OpCount(fma=1, neg=1, sub=1, sqrt=1)),
    ("if (!(t3 > 0.0)) {\n return 2; /* a - b */\n}", OpCount(cmp=1)),
    ("y = sin(x) * 1e-05;", OpCount(calls=1, mul=1)),
])
def test_c_text_counter(text, expected):
    assert count_c_text(text) == expected


def _c_source(files):
    return next(text for name, text in files.items() if name.endswith(".c"))


@pytest.mark.parametrize("use_fma", [True, False])
def test_c_text_count_equals_the_static_c_count(use_fma):
    unit = kf_unit(axes=2)
    source = _c_source(render_unit(unit, "c", use_fma=use_fma))
    step = unit.programs["step"]
    assert count_c_function(source, "cv_kf_step") == count(step, "c", use_fma=use_fma)
    for m in (1, 3):
        prog = _factor_program(m).optimize()
        source = _c_source(render_functions("lib", [prog], "c", use_fma=use_fma))
        assert count_c_function(source, "lib_factor") == count(prog, "c", use_fma=use_fma)


def test_fma_keeps_flops_and_saves_instructions():
    prog = kf_program(*cv_axes(3))
    fused, plain = count(prog, "c"), count(prog, "c", use_fma=False)
    assert fused.fma > 0 and fused.flops == plain.flops
    assert fused.instructions == plain.instructions - fused.fma
    assert plain == count(prog, "python")


def test_generated_file_reproduces_its_header_count(tmp_path):
    unit = kf_unit(axes=2)
    text = render_unit(unit, "python")["kf.py"]
    static = count(unit.programs["step"], "python")
    assert f"operations per call of step (Python): {static.summary()}" in text
    (path,) = write_files(tmp_path, "cv", {"kf.py": text})
    module = load_python(path)
    counter = OpCounter()
    x, P, z, p = _kf_inputs(4, 2, seed=3)
    module.step(*(counter.wrap(np.ravel(v)) for v in (x, P, z, p)))
    assert counter.snapshot() == static


def test_count_rejects_unknown_languages():
    prog = kf_program(*cv_axes(1))
    with pytest.raises(ValueError):
        count(prog, "fortran")
    with pytest.raises(ValueError):
        count(prog, "python", use_fma=True)


def test_calls_are_counted_separately():
    prog = Program("f", [Port("a", (1,))], [Port("y", (1,))])
    a0 = prog.element("a", 0)
    prog.set_output("y", [sympy.sin(a0) * 2 + sympy.cos(a0)])
    n = count(prog)
    assert (n.calls, n.flops) == (2, 2)
    counter = OpCounter()
    python_function(prog)(counter.wrap([0.3]))
    assert counter.snapshot() == n
