"""Paper mode: the dense filters exactly as the papers count them, generated and run."""


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import catalog, reference
from derive.apps import formulas, paper
from derive.apps.simulate import simulate_linear
from derive.apps.verify import relative_error
from derive.emit.python_printer import python_function
from derive.errors import FilterError, ModelError
from derive.flops import count
from derive.program import Port, Program

TOLERANCE = 1e-10


SIZES = [(n, m) for n in range(1, 9) for m in range(1, n + 1)]


@pytest.mark.parametrize("n,m", SIZES)
@pytest.mark.parametrize("name", ["kf", "lf"])
def test_paper_count_equals_the_formula_for_every_size(name, n, m):
    step = paper.step_program(name, n, m)
    py = count(step, "python")
    want = formulas.burden(name, n, m)
    assert py.flops == want, (name, n, m, py.summary())
    # only + - * /: no negation, comparison or call hides in the papers' algorithm
    assert py.instructions == py.flops and py.calls == 0
    if m in (1, n):  # C (fma, 2 flops each) counts the same flops; spot-checked for time
        assert count(step, "c").flops == want, (name, n, m)


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 4), st.data())
def test_paper_steady_join_and_prediction_counts_equal_the_formulas(n, data):
    m = data.draw(st.integers(1, n))
    for name in ("sskf", "sslf", "jssklf", "pred"):
        assert count(paper.step_program(name, n, m)).flops == formulas.burden(name, n, m)
    N = data.draw(st.integers(1, 6))
    assert count(paper.step_program("fir", n, m, N)).flops == formulas.fir(N, n, m)


@pytest.mark.parametrize("n,m", [(1, 1), (2, 1), (3, 2)])
def test_paper_jklf_count_is_kf_plus_lf_plus_the_join(n, m):
    assert count(paper.step_program("jklf", n, m)).flops == formulas.jklf(n, m)


def _inverse_program(n):
    prog = Program("inv", [Port("A", (n, n)), Port("E", (n, n)), Port("d", (n,))],
                   [Port("X", (n, n))])
    d = prog.matrix("d")
    prog.set_output("X", list(paper.dense_inverse(prog, prog.matrix("A"), prog.matrix("E"), d)))
    return prog.optimize()


@pytest.mark.parametrize("n", range(1, 7))
def test_dense_inverse_costs_the_papers_charge_and_inverts(n):
    prog = _inverse_program(n)
    assert count(prog).flops == formulas.inverse(n)
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, n)) + n * np.eye(n)
    X = np.reshape(python_function(prog)(A.ravel(), np.eye(n).ravel(), np.ones(n)), (n, n))
    np.testing.assert_allclose(X, np.linalg.inv(A), rtol=1e-12, atol=1e-12)


def test_a_one_by_one_inverse_is_charged_two_divisions():
    n = count(_inverse_program(1))
    assert (n.div, n.flops) == (2, 2)


def _simulated(model, steps=150, seed=11):
    num = model.numeric()
    return num, simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed).zs


def _reference(name, num, zs, N):
    args = (num.F, num.G, num.H, num.Q, num.R)
    if name in ("kf", "lf", "jklf"):
        return getattr(reference, name)(*args, num.x0, num.P0, zs)
    if name == "fir":
        return reference.fir(*args, zs, N=N), None
    if name == "pred":
        return reference.pred(*args, num.x0, zs, 1), None
    return getattr(reference, name)(*args, num.x0, zs), None


def _run(module, name, num, zs, p, c=False):
    kw = {"p": p} if c else {}
    args = () if c else (p,)
    if name in ("kf", "lf", "jklf"):
        return module.run(zs, num.x0, num.P0, *args, **kw)
    if name == "fir":
        return module.run(zs, *args, **kw), None
    return module.run(zs, num.x0, *args, **kw), None


def _check(model_name, names, langs, N=4):
    model = catalog.load(model_name)
    num, zs = _simulated(model)
    languages = langs[0] if len(langs) == 1 else "all"
    for name in names:
        order = N if name == "fir" else None
        loaded = paper.load(model, name, languages, N=order)
        pv = paper.parameter_values(model, name, N=order)
        xr, Pr = _reference(name, num, zs, order)
        for lang in langs:
            xs, Ps = _run(loaded.module(lang), name, num, zs, pv, c=lang == "c")
            assert relative_error(xs, xr) <= TOLERANCE, (model_name, name, lang)
            if Pr is not None:
                Ps = np.reshape(Ps, Pr.shape)
                assert relative_error(Ps, Pr) <= TOLERANCE, (model_name, name, lang)


def test_paper_python_equals_the_reference_on_mpt3d_a():
    _check("mpt3d_a", paper.PAPER_FILTERS, ("python",))


@pytest.mark.parametrize("model", ["gsm2d_a", "ca", "gps_static"])
def test_paper_kf_and_lf_equal_the_reference_on_other_sizes(model):
    _check(model, ("kf", "lf", "sskf"), ("python",))


def test_paper_c_equals_the_reference():
    _check("gsm2d_a", ("kf", "lf", "jklf", "jssklf", "fir"), ("c",))


def test_paper_header_states_the_count_and_the_data_layout():
    text = paper.render(catalog.load("mpt3d_a"), "kf", "python")["kf_paper.py"]
    assert f"flops {formulas.kf(6, 3)}," in text
    assert "mode: paper" in text and "Em 3x3" in text and "dm 3x1" in text
    names = paper.parameter_names(paper.layout("kf", 6, 3))
    assert len(names) == len(paper.parameter_values(catalog.load("mpt3d_a"), "kf"))
    assert names[:2] == ["F[0,0]", "F[0,1]"] and names[-1] == "dm[2]"


def test_paper_mode_rejects_bad_requests():
    with pytest.raises(FilterError, match="ekf"):
        paper.layout("ekf", 2, 1)
    with pytest.raises(ModelError, match="n must be a positive integer"):
        paper.step_program("kf", 0, 1)
    with pytest.raises(ModelError, match="order N"):
        paper.step_program("fir", 2, 1)
    with pytest.raises(FilterError, match="linear"):
        paper.model_unit(catalog.load("gnss_pseudorange"), "kf")
    with pytest.raises(FilterError, match="language"):
        paper.render(catalog.load("cv"), "kf", "fortran")


def test_paper_generate_writes_the_files(tmp_path):
    paths = paper.generate("cv", ["kf", "fir"], "all", out=tmp_path)
    assert sorted(p.name for p in paths) == ["fir_paper.c", "fir_paper.h", "fir_paper.py",
                                             "kf_paper.c", "kf_paper.h", "kf_paper.py"]
    text = (tmp_path / "cv" / "fir_paper.py").read_text()
    model = catalog.load("cv")
    N = paper.model_unit(model, "fir").window
    assert f"window: {N}" in text and f"flops {formulas.fir(N, 2, 1)}," in text
    assert len(paper.parameter_values(model, "fir")) == N * 2
