"""derive.program (the straight-line IR and its passes) and derive.staging."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from derive import staging
from derive.emit.python_printer import python_function
from derive.errors import MatrixPropertyError, NumericalError, ShapeError
from derive.expression_lowering import lower
from derive.flops import count
from derive.program import Assign, Check, Port, Program, ProgramError, Temporary
from derive.trees import count_tree

ROOT = Path(__file__).resolve().parents[2]


def vec_program(n=3, out=1):
    return Program("f", [Port("a", (n,))], [Port("y", (out,))])


def raw_count(prog):
    """(flops, instructions) of the program as built, lowered statement by statement."""
    flops = instr = 0
    for s in prog.body:
        n = count_tree(lower(s.expr)) if isinstance(s, Assign) else None
        flops += n.flops if n else 0
        instr += n.instructions if n else 1
    return flops, instr


# -- the IR --------------------------------------------------------------------------


def test_symmetric_port_elements_share_the_upper_symbol():
    prog = Program("f", [Port("P", (3, 3), symmetric=True)], [Port("y", (1,))])
    assert prog.element("P", 2, 0) is prog.element("P", 0, 2)
    assert prog.element("P", 0, 2).name == "P[2]"
    M = prog.matrix("P")
    assert M == M.T and M[2, 1].name == "P[5]"


def test_ports_are_validated():
    with pytest.raises(ProgramError):
        Port("t3", (2,))
    with pytest.raises(ProgramError):
        Port("for", (2,))
    with pytest.raises(ShapeError):
        Port("P", (2, 3), symmetric=True)
    with pytest.raises(ShapeError):
        Port("x", (0,))
    with pytest.raises(ProgramError, match="last input"):
        Program("f", [Port("p", (1,)), Port("x", (1,))], [Port("y", (1,))])
    with pytest.raises(ProgramError, match="twice"):
        Program("f", [Port("x", (1,))], [Port("x", (1,))])


def test_let_returns_atoms_unchanged_and_names_temporaries():
    prog = vec_program()
    a0 = prog.element("a", 0)
    assert prog.let(a0) is a0
    assert prog.let(sympy.Integer(3)) == 3
    assert prog.let(sympy.sqrt(2)) == sympy.sqrt(2)
    t = prog.let(a0 * prog.element("a", 1))
    assert isinstance(t, Temporary) and len(prog.body) == 1


def test_unbound_model_symbols_are_named():
    prog = vec_program()
    with pytest.raises(ProgramError, match="'dt'"):
        prog.let(sympy.Symbol("dt") * prog.element("a", 0))
    # a model symbol that happens to look like a temporary is still not one
    with pytest.raises(ProgramError, match="'t0'"):
        prog.let(sympy.Symbol("t0") + 1)


def test_bind_maps_model_symbols_to_parameters():
    prog = Program("f", [Port("x", (1,)), Port("p", (2,))], [Port("y", (1,))])
    dt, q = sympy.symbols("dt q")
    binding = prog.bind("p", [dt, q])
    assert binding[q].name == "p[1]"
    with pytest.raises(ShapeError, match="'p'"):
        prog.bind("p", [dt])


def test_set_output_checks_length_and_symmetry():
    prog = Program("f", [Port("a", (2,))], [Port("S", (2, 2), symmetric=True)])
    a0, a1 = prog.element("a", 0), prog.element("a", 1)
    with pytest.raises(ShapeError, match="4 values"):
        prog.set_output("S", [a0, a1])
    with pytest.raises(MatrixPropertyError, match=r"\(0, 1\)"):
        prog.set_output("S", [a0, a1, a0, a1])
    prog.set_output("S", [a0 * a0, a0 * a1, a0 * a1, a1 * a1])
    results = prog.results["S"]
    assert results[1] is results[2] and len(prog.body) == 3
    with pytest.raises(ProgramError, match="twice"):
        prog.set_output("S", [a0, a1, a1, a0])


def test_require_positive_decides_numbers_statically():
    prog = vec_program()
    prog.require_positive(sympy.Integer(2), "fine")
    assert not prog.body
    with pytest.raises(MatrixPropertyError, match="pivot"):
        prog.require_positive(sympy.Integer(0), "pivot is zero")
    prog.require_positive(prog.element("a", 0) - 1, "a0 > 1")
    assert isinstance(prog.body[-1], Check)


def test_structural_division_by_zero_is_reported():
    prog = vec_program()
    with pytest.raises(MatrixPropertyError, match="not finite"):
        prog.let(prog.element("a", 0) / sympy.Integer(0))


# -- the passes ----------------------------------------------------------------------


def test_folding_copy_propagation_and_dead_code():
    prog = Program("f", [Port("a", (2,))], [Port("y", (2,))])
    a0, a1 = prog.element("a", 0), prog.element("a", 1)
    dead = prog.let(a0 * a1 * 7)
    t1 = prog.let(a0 + a1)
    t2 = prog.let(a0 + a1)          # identical right-hand side: merged
    prog.set_output("y", [t1 * t2, dead * 0])
    opt = prog.optimize()
    assert [s.target.name for s in opt.body] == ["t0", "t1"]
    assert opt.body[1].expr == opt.body[0].target ** 2
    assert opt.results["y"][1] == 0
    assert opt.optimize() is opt
    with pytest.raises(ProgramError, match="final"):
        opt.let(a0 + 1)


def test_sharing_lowers_the_count_and_only_then():
    prog = Program("f", [Port("a", (4,))], [Port("y", (2,))])
    a = [prog.element("a", i) for i in range(4)]
    prog.set_output("y", [a[0] * a[1] + a[2], a[3] - a[0] * a[1]])
    opt = prog.optimize()
    assert len(opt.body) == 3 and opt.body[0].expr == a[0] * a[1]
    assert count(opt).flops == 3 < raw_count(prog)[0]
    # sharing 1/a3 would trade two divisions for one division and two multiplications
    prog = Program("f", [Port("a", (4,))], [Port("y", (2,))])
    a = [prog.element("a", i) for i in range(4)]
    prog.set_output("y", [a[0] / a[3], a[1] / a[3]])
    assert count(prog.optimize()).as_dict()["div"] == 2 and count(prog).mul == 0


def test_sharing_sees_through_numeric_coefficients():
    prog = Program("f", [Port("a", (4,))], [Port("y", (2,))])
    a = [prog.element("a", i) for i in range(4)]
    prog.set_output("y", [a[2] - 2 * a[0] * a[1], a[3] + 3 * a[0] * a[1]])
    opt = prog.optimize()
    assert opt.body[0].expr == a[0] * a[1]
    assert count(opt).flops == 5 < raw_count(prog)[0]


def test_powers_are_built_by_squaring():
    prog = vec_program(1)
    a0 = prog.element("a", 0)
    prog.set_output("y", [a0 ** 5 + a0 ** 2])
    opt = prog.optimize()
    n = count(opt)
    assert (n.mul, n.add) == (3, 1)   # a^2, a^4 = (a^2)^2, a^5 = a^4 a; a^2 shared
    f = python_function(opt)
    assert f([1.5])[0] == pytest.approx(1.5 ** 5 + 1.5 ** 2, rel=1e-15)


def _random_program(data, n_inputs=4, n_temps=8):
    prog = Program("f", [Port("a", (n_inputs,))], [Port("y", (2,))])
    atoms = [prog.element("a", i) for i in range(n_inputs)] + [sympy.Integer(2),
                                                              sympy.Integer(0),
                                                              sympy.Integer(1)]
    ops = [lambda u, v: u + v, lambda u, v: u - v, lambda u, v: u * v,
           lambda u, v: u * v + atoms[0], lambda u, v: 3 * u * v - atoms[1]]
    for _ in range(n_temps):
        u, v = data.draw(st.sampled_from(atoms)), data.draw(st.sampled_from(atoms))
        atoms.append(prog.let(data.draw(st.sampled_from(ops))(u, v)))
    prog.set_output("y", [data.draw(st.sampled_from(atoms)) for _ in range(2)])
    return prog


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_optimize_never_increases_the_count_and_keeps_values(data):
    prog = _random_program(data)
    opt = prog.optimize()
    before, after = raw_count(prog), count(opt)
    assert (after.flops, after.instructions) <= before
    values = [0.3, -1.7, 2.5, 0.9]
    env = {prog.element("a", i): v for i, v in enumerate(values)}
    for s in prog.body:
        env[s.target] = float(s.expr.xreplace(env))
    want = [float(sympy.sympify(y).xreplace(env)) for y in prog.results["y"]]
    got = python_function(opt)(values)
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


_LISTING = """
import sys
sys.path.insert(0, {root!r})
sys.path.insert(0, {tests!r})
from _backend_kf import cv_axes, kf_program
print(kf_program(*cv_axes(2)).optimize().listing())
"""


def test_optimize_is_independent_of_the_hash_seed():
    code = _LISTING.format(root=str(ROOT), tests=str(ROOT / "tests"))
    outputs = []
    for seed in ("1", "2", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True).stdout
        outputs.append(out)
    assert outputs[0] == outputs[1] == outputs[2] and "t0 =" in outputs[0]


# -- staging -------------------------------------------------------------------------


def _spd(rng, m):
    A = rng.normal(size=(m, m))
    return A @ A.T + m * np.eye(m)


def solve_program(m, k):
    prog = Program("solve", [Port("S", (m, m), symmetric=True), Port("B", (m, k))],
                   [Port("X", (m, k))])
    prog.set_output("X", staging.spd_solve(prog, prog.matrix("S"), prog.matrix("B")))
    return prog


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 4), st.integers(1, 3), st.integers(0, 2**32 - 1))
def test_spd_solve_matches_numpy(m, k, seed):
    rng = np.random.default_rng(seed)
    S, B = _spd(rng, m), rng.normal(size=(m, k))
    X = np.array(python_function(solve_program(m, k))(S.ravel(), B.ravel())).reshape(m, k)
    np.testing.assert_allclose(X, np.linalg.solve(S, B), rtol=1e-12, atol=1e-12)


def test_spd_solve_of_a_scalar_shares_one_reciprocal_from_three_entries():
    n = count(solve_program(1, 3))
    assert (n.div, n.mul, n.add, n.sub) == (1, 3, 0, 0)
    n = count(solve_program(1, 2))  # two entries: two divisions beat 1/S and two products
    assert (n.div, n.mul, n.add, n.sub) == (2, 0, 0, 0)


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_spd_inverse_cholesky_and_lu_inverse_match_numpy(m):
    rng = np.random.default_rng(m)
    S = _spd(rng, m)
    A = rng.normal(size=(m, m)) + 3 * np.eye(m)
    prog = Program("f", [Port("S", (m, m), symmetric=True), Port("A", (m, m))],
                   [Port("Sinv", (m, m), symmetric=True), Port("L", (m, m)),
                    Port("Ainv", (m, m))])
    prog.set_output("Sinv", staging.spd_inverse(prog, prog.matrix("S")))
    prog.set_output("L", staging.cholesky(prog, prog.matrix("S")))
    prog.set_output("Ainv", staging.lu_inverse(prog, prog.matrix("A")))
    Sinv, L, Ainv = (np.array(v).reshape(m, m)
                     for v in python_function(prog)(S.ravel(), A.ravel()))
    np.testing.assert_allclose(Sinv, np.linalg.inv(S), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(L, np.linalg.cholesky(S), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Ainv, np.linalg.inv(A), rtol=1e-11, atol=1e-12)


def test_ldl_reconstructs_and_keeps_blocks_decoupled():
    prog = Program("f", [Port("S", (4, 4), symmetric=True)],
                   [Port("L", (4, 4)), Port("D", (4,))])
    S = prog.matrix("S")
    block = sympy.Matrix(4, 4, lambda i, j: S[i, j] if (i < 2) == (j < 2) else 0)
    L, D = staging.ldl(prog, block)
    # exact structural zeros outside the blocks, no temporaries for them
    assert all(L[i, j] == 0 for i in range(2, 4) for j in range(2))
    prog.set_output("L", L)
    prog.set_output("D", [D[i, i] for i in range(4)])
    rng = np.random.default_rng(0)
    Sn = np.zeros((4, 4))
    Sn[:2, :2], Sn[2:, 2:] = _spd(rng, 2), _spd(rng, 2)
    Ln, Dn = python_function(prog)(Sn.ravel())
    Ln = np.array(Ln).reshape(4, 4)
    np.testing.assert_allclose(Ln @ np.diag(Dn) @ Ln.T, Sn, rtol=1e-13, atol=1e-13)
    # the two blocks cost exactly what two separate 2x2 factorisations cost
    small = Program("f", [Port("S", (2, 2), symmetric=True)],
                    [Port("L", (2, 2)), Port("D", (2,))])
    L2, D2 = staging.ldl(small, small.matrix("S"))
    small.set_output("L", L2)
    small.set_output("D", [D2[0, 0], D2[1, 1]])
    assert count(prog) == count(small) + count(small)


def test_ldl_failure_raises_in_python():
    prog = Program("f", [Port("S", (2, 2), symmetric=True)], [Port("X", (2, 1))])
    prog.set_output("X", staging.spd_solve(prog, prog.matrix("S"), sympy.Matrix([1, 0])))
    f = python_function(prog)
    with pytest.raises(NumericalError, match="pivot 1"):
        f([1.0, 2.0, 2.0, 1.0])
    with pytest.raises(NumericalError, match="pivot 0"):
        f([float("nan"), 0.0, 0.0, 1.0])


def test_lu_inverse_rejects_a_structurally_singular_matrix():
    prog = Program("f", [Port("a", (1,))], [Port("Y", (2, 2))])
    a0 = prog.element("a", 0)
    with pytest.raises(MatrixPropertyError, match="structurally singular"):
        staging.lu_inverse(prog, sympy.Matrix([[a0, 1], [0, 0]]), name="M")


def test_staging_shape_errors_name_the_shapes():
    prog = vec_program()
    with pytest.raises(ShapeError, match=r"\(2, 3\).*\(2, 1\)"):
        staging.matmul(prog, sympy.zeros(2, 3), sympy.zeros(2, 1))
    with pytest.raises(ShapeError, match="square"):
        staging.ldl(prog, sympy.zeros(2, 3))


def test_matmul_with_symmetric_result_computes_the_upper_triangle_only():
    prog = Program("f", [Port("A", (3, 2))], [Port("Y", (3, 3), symmetric=True)])
    A = prog.matrix("A")
    Y = staging.matmul(prog, A, A.T, symmetric_result=True)
    assert len(prog.body) == 6 and Y == Y.T


def test_the_module_docstring_example_runs_and_is_right():
    import textwrap

    import derive.program as module
    from derive.flops import OpCounter

    doc = module.__doc__
    scope: dict = {}
    exec(textwrap.dedent(doc[doc.index("    import sympy"):doc.index("``step`` is what")]), scope)
    step = scope["step"]
    x, P, z, r = np.array([1.0, 2.0]), np.array([[2.0, 0.5], [0.5, 1.0]]), 3.0, 0.5
    H = np.array([[1.0, 0.0]])
    K = P @ H.T / (H @ P @ H.T + r)
    x_new, P_new = python_function(step)(x, P.ravel(), [z], [r])
    np.testing.assert_allclose(x_new, x + (K * (z - x[0])).ravel(), rtol=1e-15)
    np.testing.assert_allclose(np.reshape(P_new, (2, 2)), P - K @ H @ P, rtol=1e-15)
    counter = OpCounter()
    python_function(step)(*(counter.wrap(v) for v in (x, P.ravel(), [z], [r])))
    assert counter.snapshot() == count(step) and count(step).div == 2


def test_a_banded_times_dense_product_builds_only_its_nonzero_products(monkeypatch):
    """A staged product costs the nonzero entries of its factors: F (1 on the diagonal,
    dt above it) times a dense P builds n (n - 1) products and no product with a zero or a
    one, and the staged entries are sympy's own sums of those products."""
    n = 6
    dt = sympy.Rational(1, 10)
    F = sympy.Matrix(n, n, lambda i, j: 1 if i == j else dt if j == i + 1 else 0)
    prog = Program("f", [Port("P", (n, n))], [Port("y", (n, n))])
    P = prog.matrix("P")
    built = []
    product = staging.product

    def counted(a, b):
        built.append((a, b))
        return product(a, b)
    monkeypatch.setattr(staging, "product", counted)
    FP = staging.matmul(prog, F, P)
    assert len(built) == n * (n - 1)
    assert all(a != 0 and b != 0 and a != 1 and b != 1 for a, b in built)
    defined = {st.target: st.expr for st in prog.body}
    for i in range(n):
        for j in range(n):
            expected = sympy.Add(*[F[i, k] * P[k, j] for k in range(n)])
            assert defined.get(FP[i, j], FP[i, j]) == expected
