"""Vector rows (option ``rows = "vector"``, ``NonlinearModel(rows=)``, a model file's
``[nonlinear] rows``): the EKF predict and sequential updates derived as rows of four lanes,
printed in C as GCC/Clang vector statements with their scalar lanes as the fallback.

Checked: the vector form against the scalar form of the same model (random models with
inputs in f, sparse and dense Jacobians, unit and dense rows of H, diagonal and correlated
R, lengths that 4 does not divide: an overlapping last chunk), against the NumPy reference
over a run, the vector branch bitwise against its scalar lanes (plain, fused and
-DDERIVE_VECTOR=0 builds), P_new exactly symmetric, P0 read by its upper triangle only,
gating, the counts (header = Python's executed count = the C text's vector branch, lane by
lane), and the refusals."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import NonlinearModel, Sensor
from derive.build import CONVERSION_CFLAGS, STRICT_CFLAGS
from derive.catalog import load as load_catalog
from derive.cli import main
from derive.errors import ModelError, ModelFileError, NumericalError, OptionError
from derive.filters import derive_unit
from derive.filters.sensors import reference_run
from derive.flops import OpCounter, c_function_body, count, count_c_function, count_c_text
from derive.generation import render_filter
from derive.modelfile import loads_model
from derive.pipeline import load_generated
from derive.program import Port, Program
from derive.row_program import RowBuilder
from derive.rows import VECTOR_LANES, LaneSum, chunk_bounds
from derive.statements import Temporary

ROOT = Path(__file__).resolve().parents[2]
VECTOR, SCALAR = {"rows": "vector"}, {"rows": "scalar"}
AGREEMENT = 1e-12
"""The vector form against the scalar form (the same algebra, rounded in another order),
relative to the largest entry: double, well-conditioned random models."""
NATIVE = ("-O2", "-march=native")
#: AVX without FMA: registers that hold four doubles (DERIVE_VECTOR is 1), fma plain
AVX = ("-mavx",)


def relative(got, expected) -> float:
    got, expected = np.asarray(got, float), np.asarray(expected, float)
    return float(np.max(np.abs(got - expected)) / np.max(np.abs(expected)))


def random_model(rng, n: int, m: int, correlated: bool) -> NonlinearModel:
    """A random EKF model: f = F x + B u (F stable, spectral radius 0.9) + a product of two
    states on row 0 (so F's entries are partly temporaries), inputs with noise Qu; sensor
    ``a`` sequential with m linear measurements (unit and dense rows of H; R diagonal, or
    correlated and constant), sensor ``b`` a nonlinear scalar (batch)."""
    x = sympy.symbols(f"x0:{n}", real=True)
    u = sympy.symbols("u0:2", real=True)
    F = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.45) * 0.3 + np.eye(n)
    F = np.round(F * 0.9 / max(1.0, np.max(np.abs(np.linalg.eigvals(F)))), 3)  # stable
    B = np.round(rng.normal(size=(n, 2)) * (rng.random((n, 2)) < 0.5), 3)
    f = [sum(sympy.Float(F[i, j], 3) * x[j] for j in range(n) if F[i, j])
         + sum(sympy.Float(B[i, k], 3) * u[k] for k in range(2) if B[i, k]) for i in range(n)]
    f[0] += x[0] * x[n - 1] / 100 + u[0] / 10  # f uses both inputs
    f[1] += u[1] / 10
    H = np.round(rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.6), 3)
    unit_rows = rng.random(m) < 0.5
    for i, k in enumerate(rng.permutation(n)[:m]):
        if unit_rows[i]:
            H[i] = 0.0
        H[i, k] = 1.0 if not unit_rows[i] or rng.random() < 0.5 else -1.0  # e_k or -e_k
    R = np.diag(np.round(rng.uniform(0.2, 2.0, m), 3))
    if correlated and m > 1:
        A = np.round(rng.normal(size=(m, m)), 2)
        R = R + np.round(A @ A.T / m, 3)
    h = [sum(sympy.Float(H[i, j], 3) * x[j] for j in range(n) if H[i, j]) for i in range(m)]
    L = rng.normal(size=(n, n))
    Q = np.round(L @ L.T / n * 0.01 + 0.01 * np.eye(n), 4)
    return NonlinearModel(
        "vec", [s.name for s in x], f=f, Q=((Q + Q.T) / 2).tolist(), inputs=["u0", "u1"],
        Qu=[[0.01, 0], [0, 0.02]],
        sensors=[Sensor("a", [f"a{i}" for i in range(m)], h=h, R=R.tolist(),
                        update="sequential"),
                 Sensor("b", ["zb"], h=[x[0] ** 2 / 10 + x[n - 1]], R=[[0.5]])],
        x0=np.zeros(n).tolist(), P0=np.eye(n).tolist())


def spd(rng, n: int) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.5 * np.eye(n)


@settings(max_examples=10, deadline=None)
@given(n=st.integers(3, 9), m=st.integers(1, 4), correlated=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_random_models_agree_with_the_scalar_form_and_the_reference(n, m, correlated, seed):
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, min(m, n), correlated)
    # the scalar form is the expectation in Python only: its C is not built
    vector, scalar = load_generated(model, "ekf", VECTOR), load_generated(model, "ekf",
                                                                          SCALAR, "python")
    x, P, us = 0.3 * rng.normal(size=n), spd(rng, n), rng.normal(size=2)
    expected = scalar.python.predict(x, P.ravel(), us)
    for module in (vector.python, vector.c):
        got = module.predict(x, P.ravel(), us)
        assert relative(got[0], expected[0]) <= AGREEMENT
        assert relative(got[1], expected[1]) <= AGREEMENT
    z = rng.normal(size=min(m, n))
    expected = scalar.python.update_a(x, P.ravel(), z)
    for module in (vector.python, vector.c):
        got = module.update_a(x, P.ravel(), z)
        assert relative(got[0], expected[0]) <= AGREEMENT
        assert relative(got[1], expected[1]) <= AGREEMENT
    steps = 30  # a run at two rates against the NumPy reference (batch updates)
    za = rng.normal(size=(steps, min(m, n)))
    za[np.arange(steps) % 2 == 1] = np.nan
    zb = rng.normal(size=(steps, 1))
    zb[np.arange(steps) % 3 != 0] = np.nan
    u = rng.normal(size=(steps, 2))
    ref = reference_run(model, {}, {"a": za, "b": zb}, u)
    for module in (vector.python, vector.c):
        xs, Ps = module.run(za, zb, u, np.zeros(n), np.eye(n))
        assert relative(xs, ref.xs) <= 1e-10
        assert relative(Ps, ref.Ps) <= 1e-10


def test_unit_rows_of_either_sign_and_a_state_measured_twice():
    """Measurements of x2, -x2 (the same state again, negated: taken as x2 with its
    innovation negated) and -x4, fused sequentially: the vector form, whose rows 2 and 4
    of P_new are -R_i k_i of the last update measuring them (no fma, no cancellation),
    against the scalar form, x and P, and its update has no negation at all."""
    x = sympy.symbols("x0:5", real=True)
    model = NonlinearModel(
        "twice", [s.name for s in x], f=[x[0] + x[1] / 10, x[1], x[2] + x[3] / 10, x[3],
                                         x[4] + x[0] * x[1] / 100],
        Q=(0.01 * np.eye(5)).tolist(),
        sensors=[Sensor("a", ["a0", "a1", "a2"], h=[x[2], -x[2], -x[4]],
                        R=np.diag([0.5, 0.02, 0.3]).tolist(), update="sequential"),
                 Sensor("b", ["zb"], h=[x[0] ** 2 / 10 + x[1]], R=[[0.5]])],
        x0=np.zeros(5).tolist(), P0=np.eye(5).tolist())
    vector, scalar = (load_generated(model, "ekf", o) for o in (VECTOR, SCALAR))
    rng = np.random.default_rng(7)
    x0, P, z = rng.normal(size=5), spd(rng, 5), rng.normal(size=3)
    expected = scalar.python.update_a(x0, P.ravel(), z)
    for module in (vector.python, vector.c):
        got = module.update_a(x0, P.ravel(), z)
        assert relative(got[0], expected[0]) <= AGREEMENT
        assert relative(got[1], expected[1]) <= AGREEMENT
    files = render_filter(model, "ekf", "c", VECTOR)
    assert "neg 0," in re.search(r"operations per call of update_a [^\n]*", files["ekf.c"])[0]


@pytest.mark.parametrize("cflags", [AVX, NATIVE], ids=["plain", "native"])
def test_the_vector_branch_computes_its_scalar_lanes_bit_for_bit(cflags, tmp_path):
    """The same file built with DERIVE_VECTOR 1 and 0: identical bits, P_new exactly
    symmetric (the lower triangle written by transposition), on the catalog's INS/GNSS EKF
    (which declares rows = vector) and random models whose length 4 does not divide (its
    last chunk overlaps the one before; at 9 states P_new's last four columns go out as
    blocks whose first lanes an earlier block wrote)."""
    rng = np.random.default_rng(7)
    dt = (np.array([0.01]),)
    cases = [("ins_gnss", {}, 16, 6, "update_gnss", 6, dt),
             (random_model(rng, 7, 3, correlated=True), VECTOR, 7, 2, "update_a", 3, ()),
             (random_model(np.random.default_rng(3), 9, 2, correlated=False), VECTOR, 9, 2,
              "update_a", 2, ())]
    for k, (model, options, n, nu, update, m, p) in enumerate(cases):
        vector, lanes = (load_generated(model, "ekf", options, "c", tmp_path / f"{k}{label}",
                                        extra_cflags=flags).c
                         for label, flags in (("v", cflags),
                                              ("s", (*cflags, "-DDERIVE_VECTOR=0"))))
        for _ in range(5):
            x = 0.1 * rng.normal(size=n)
            x[:4] /= np.linalg.norm(x[:4])
            P = spd(rng, n)
            for function, args in (("predict", (x, P.ravel(), rng.normal(size=nu), *p)),
                                   (update, (x, P.ravel(), rng.normal(size=m), *p))):
                a = getattr(vector, function)(*args)
                b = getattr(lanes, function)(*args)
                for got, expected in zip(a, b):
                    assert np.array_equal(np.asarray(got), np.asarray(expected)), function
                P_new = np.asarray(a[1]).reshape(n, n)
                assert np.array_equal(P_new, P_new.T), function


def _vector_branch_writes(body: str, port: str) -> dict[int, int]:
    """{entry: times written} of ``port`` in the vector form of a C function body: its
    lines outside ``#else ... #endif`` (a vector store writes four entries)."""
    written: dict[int, int] = {}
    scalar = False
    for line in body.splitlines():
        text = line.strip()
        if text in ("#else", "#endif"):
            scalar = text == "#else"
            continue
        if scalar:
            continue
        found = re.match(rf"(\*\(derive_v[df]_unaligned \*\)&)?{port}\[(\d+)\] = ", text)
        if found:
            first = int(found[2])
            for k in range(first, first + (VECTOR_LANES if found[1] else 1)):
                written[k] = written.get(k, 0) + 1
    return written


@pytest.mark.parametrize("case", ["ins_fc24_eskf", "random n = 9"])
def test_the_vector_form_writes_each_entry_of_P_new_once(case):
    """A symmetric P_new of a size 4 does not divide: its 4 x 4 blocks go out as vector
    stores (those below the diagonal as transpositions), the last four columns' blocks as
    well (the rows' overlapping last chunks), and an entry of a run that a block store
    covers in part is written alone, not again with the run's others. Written twice: only
    an entry in the columns or rows that the last blocks overlap (the same value)."""
    if case == "ins_fc24_eskf":
        source, n = (ROOT / "generated" / case / "eskf.c").read_text(), 23
        functions = ["ins_fc24_eskf_eskf_predict"]
    else:
        n = 9
        source = render_filter(random_model(np.random.default_rng(3), n, 2, False), "ekf",
                               "c", VECTOR)["ekf.c"]
        functions = ["vec_ekf_predict", "vec_ekf_update_a"]
    for function in functions:
        written = _vector_branch_writes(c_function_body(source, function), "P_new")
        assert sorted(written) == list(range(n * n)), function
        overlap = range(n - 4, 4 * (n // 4))
        twice = {divmod(k, n) for k, times in written.items() if times > 1}
        assert set(written.values()) <= {1, 2}, function
        assert all(i in overlap or j in overlap for i, j in twice), (function, twice)


def test_run_reads_the_upper_triangle_of_P0_only():
    """The programs read P whole; run mirrors P0's upper triangle first, so a P0 whose
    lower triangle holds anything filters as the symmetric one (Python and C)."""
    rng = np.random.default_rng(3)
    model = random_model(rng, 6, 2, correlated=False)
    generated = load_generated(model, "ekf", VECTOR)
    P0 = spd(rng, 6)
    garbage = np.triu(P0) + np.tril(rng.normal(size=(6, 6)), -1)
    steps = 12
    u = rng.normal(size=(steps, 2))
    za, zb = rng.normal(size=(steps, 2)), rng.normal(size=(steps, 1))
    for module in (generated.python, generated.c):
        xs, Ps = module.run(za, zb, u, np.zeros(6), P0)
        xg, Pg = module.run(za, zb, u, np.zeros(6), garbage)
        assert np.array_equal(xs, xg) and np.array_equal(Ps, Pg)


def test_gated_vector_update_rejects_an_outlier_as_the_scalar_form_does():
    rng = np.random.default_rng(11)
    model = random_model(rng, 5, 3, correlated=True)
    options = {"gate": 0.999}
    vector = load_generated(model, "ekf", {**VECTOR, **options})
    scalar = load_generated(model, "ekf", {**SCALAR, **options})
    x, P = 0.1 * rng.normal(size=5), spd(rng, 5)
    for z, applied in ((rng.normal(size=3) * 0.1, 1.0), (np.full(3, 1e3), 0.0)):
        expected = scalar.python.update_a(x, P.ravel(), z)
        for module in (vector.python, vector.c):
            got = module.update_a(x, P.ravel(), z)
            assert float(np.asarray(got[3])[0]) == applied
            assert relative(got[2], expected[2]) <= AGREEMENT  # nis
            assert relative(got[0], expected[0]) <= AGREEMENT
            assert relative(got[1], expected[1]) <= AGREEMENT
    got = vector.c.update_a(x, P.ravel(), np.full(3, 1e3))  # not applied: x, P as given
    assert np.array_equal(np.asarray(got[0]), x) and np.array_equal(np.asarray(got[1]), P)


def test_counts_are_the_lanes_executed_and_the_c_text_lane_by_lane():
    """Header = Python's executed count (every lane of a kept chunk) = the C text's vector
    branch, a vector statement counted once per lane; the scalar branch leaves out the
    lanes nothing reads, so it never counts more."""
    rng = np.random.default_rng(5)
    model = random_model(rng, 9, 3, correlated=False)
    unit = derive_unit(model, "ekf", VECTOR)
    files = render_filter(model, "ekf", "all", VECTOR)
    scope: dict = {}
    exec(compile(files["ekf.py"], "ekf.py", "exec"), scope)  # derive's own generated code
    for name in ("predict", "update_a"):
        program = unit.programs[name]
        assert program.rows, name
        static_py, static_c = count(program, "python"), count(program, "c")
        counter = OpCounter()
        args = [spd(rng, p.shape[0]).ravel() if p.symmetric else rng.uniform(0.5, 1.0, p.size)
                for p in program.inputs]
        scope[name](*[counter.wrap(v) for v in args])
        assert counter.snapshot() == static_py, name
        function = f"{unit.prefix}_{name}"
        assert count_c_function(files["ekf.c"], function) == static_c, name
        assert f"operations per call of {name} (C99, fma through DERIVE_FMA and " \
               f"DERIVE_FNMA): {static_c.summary()}" in files["ekf.c"]
        scalar = count_c_text(c_function_body(files["ekf.c"], function), vector=False)
        assert scalar.flops <= static_c.flops and scalar.instructions <= static_c.instructions


@pytest.mark.parametrize("read_from, chunks", [(0, 2), (1, 1), (3, 1), (4, 1), (6, 0)])
def test_a_row_read_from_inside_a_chunk_computes_that_chunk_as_scalars(read_from, chunks):
    """RowBuilder.row(read=lanes r on), as a row of a symmetric result's upper triangle:
    the chunk holding lane r, unless r is its first lane, is scalar statements (lanes
    before r left out); the chunks after it stay chunks."""
    inputs = [Port("P", (8, 8)), Port("c", (1,))]
    shell = Program("t", inputs, [Port("y", (8,))])
    prologue = Program("t", inputs, [Port("s", (1,))])
    prologue.set_output("s", [prologue.element("c", 0) * 2])
    prologue = prologue.optimize()
    rows = RowBuilder(shell, prologue, 4)
    base = [shell.stored_element("P", 0, j) for j in range(8)]
    source = [shell.stored_element("P", 1, j) for j in range(8)]
    y = rows.row(base, [(1, prologue.results["s"][0], source)], read=range(read_from, 8))
    program = rows.finish({"y": [y[j] if j >= read_from else sympy.S.Zero for j in range(8)]})
    assert len(program.rows) == chunks
    assert all(len(chunk.targets) == 4 for chunk in program.rows)


def test_a_lane_is_the_sum_of_its_terms_added_one_by_one():
    """LaneSum.expr builds each lane as one Add of its products (two distinct symbols'
    product as the canonical Mul directly): the same expression, equal and of the same
    arguments, as adding the terms one by one with sympy's own operators."""
    P = [sympy.Symbol(f"P[{j}]", real=True) for j in range(8)]
    t = [Temporary(f"t{j}") for j in range(4)]
    forms = [LaneSum(tuple(P[:4]), ((1, t[0], tuple(P[4:])), (-1, t[1], tuple(t)),
                                    (1, sympy.Integer(1), (P[0], t[2], P[5], P[6])),
                                    (-1, sympy.Float(0.5), tuple(P[2:6])),
                                    (1, P[1], (P[1], P[3], t[3], P[7])))),
             LaneSum(None, ((-1, t[2], (t[2], P[0], P[1], t[3])),))]
    for form in forms:
        for lane in range(4):
            value = sympy.S.Zero if form.base is None else form.base[lane]
            for sign, coef, sources in form.terms:
                value = value + sign * coef * sources[lane]
            assert form.expr(lane) == value and form.expr(lane).args == value.args


def test_catalog_ins_gnss_declares_vector_rows():
    """The catalog model declares rows = vector (predict and the sequential GNSS update,
    and the baro update of one measurement, declared batch); its header says P is read
    whole; the option rows = scalar overrides the model."""
    model = load_catalog("ins_gnss")
    header = render_filter(model, "ekf", "c")["ekf.c"]
    assert "symmetric in predict: P, P_new (inputs: P read whole, both triangles" in header
    assert "#if DERIVE_VECTOR" in header
    assert model.rows == "vector"
    unit = derive_unit(model, "ekf")
    assert unit.programs["predict"].rows and unit.programs["update_gnss"].rows
    assert unit.programs["update_baro"].rows  # one measurement: the same update, as rows
    assert not derive_unit(model, "ekf", SCALAR).programs["predict"].rows


@pytest.mark.skipif(shutil.which("clang") is None, reason="clang is not installed")
@pytest.mark.parametrize("precision", ["double", "float"])
def test_vector_code_compiles_strictly_under_gcc_and_clang(precision, tmp_path):
    rng = np.random.default_rng(9)
    model = random_model(rng, 6, 3, correlated=True)
    files = render_filter(model, "ekf", "c", {**VECTOR, "precision": precision})
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    for cc in ("gcc", "clang"):
        for extra in ((), ("-O3", "-march=native"), ("-DDERIVE_VECTOR=0",)):
            cmd = [cc, *STRICT_CFLAGS, *CONVERSION_CFLAGS, *extra, "-c", str(tmp_path / "ekf.c"),
                   "-o", str(tmp_path / "ekf.o")]
            done = subprocess.run(cmd, capture_output=True, text=True)
            assert done.returncode == 0, (cmd, done.stderr[:2000])


def test_rows_are_refused_in_one_line_where_they_do_not_apply(capsys):
    with pytest.raises(ModelError, match=r"rows must be one of scalar, vector, got 'rows'"):
        NonlinearModel("m", ["x"], ["z"], f=["x"], Q=[[1]], h=["x"], R=[[1]], rows="rows")
    text = BAD_FILE.replace("ROWS", '"diagonal"')
    with pytest.raises(ModelFileError, match=r"\[nonlinear\] rows: 'diagonal' is not one of "
                                             r"scalar, vector"):
        loads_model(text)
    with pytest.raises(OptionError, match=r"rows"):
        derive_unit(load_catalog("ins_gnss"), "ukf", VECTOR)
    assert main(["generate", "ins_gnss", "--filter", "ekf", "--rows", "diagonal",
                 "--out", "/nonexistent"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rows" in err[0] and "diagonal" in err[0]


BAD_FILE = """
[model]
name = "m"
states = ["x"]
measurements = ["z"]

[nonlinear]
f = ["x"]
h = ["x"]
Q = [[1]]
R = [[1]]
rows = ROWS
"""


def test_a_model_file_declares_rows():
    assert loads_model(BAD_FILE.replace("ROWS", '"vector"')).rows == "vector"
    assert loads_model(BAD_FILE.replace("rows = ROWS", "")).rows == "scalar"


def test_a_negative_dt_is_refused_by_the_vector_predict_naming_step_and_value():
    """ins_gnss declares dt nonnegative: its predict of vector rows keeps the domain check
    with its parameter (Python names the value; C run names the step and the value)."""
    model = load_catalog("ins_gnss")
    generated = load_generated(model, "ekf")
    assert derive_unit(model, "ekf").programs["predict"].rows
    x = np.zeros(16)
    x[0] = 1.0
    P = np.eye(16)
    with pytest.raises(NumericalError, match=re.escape("parameter dt must be nonnegative, "
                                                       "got -0.01")):
        generated.python.predict(x, P.ravel(), np.zeros(6), np.array([-0.01]))
    steps, bad = 6, 4
    rows = np.full((steps, 1), 0.01)
    rows[bad, 0] = -0.25
    us = np.zeros((steps, 6))
    gnss, baro = np.full((steps, 6), np.nan), np.full((steps, 1), np.nan)
    text = f"step {bad}: parameter dt must be nonnegative, got -0.25"
    for module in (generated.python, generated.c):
        with pytest.raises(NumericalError, match=re.escape(text) if module is generated.c
                           else r"parameter dt must be nonnegative, got -0\.25"):
            module.run(gnss, baro, us, x, P, rows)



@pytest.mark.parametrize("length", [0, 3, 4, 15, 23, 24])
def test_chunks_cover_the_row_with_a_last_one_that_overlaps(length):
    """Every chunk is 4 lanes wide (a row shorter than that: one chunk), they cover the row,
    and only the last overlaps the one before it, ending at the row's end."""
    bounds = chunk_bounds(length, VECTOR_LANES)
    covered = sorted({lane for start, stop in bounds for lane in range(start, stop)})
    assert covered == list(range(length))
    if length >= VECTOR_LANES:
        assert all(stop - start == VECTOR_LANES for start, stop in bounds)
        assert bounds[-1][1] == length
        assert all(a[1] == b[0] for a, b in zip(bounds[:-2], bounds[1:-1]))
    else:
        assert bounds == ([(0, length)] if length else [])
