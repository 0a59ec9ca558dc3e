"""Bounded time and memory for every model input (docs/robustness.md, "Bounds").

Each case is a real file run through ``python -m derive generate`` in a subprocess with a
hang guard (the timeout is not a speed assertion): it either generates (exit 0) or is
refused with exactly one line on stderr naming the culprit (exit 2), never a traceback
and never a partly written output directory.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import catalog
from derive.discretize import METHODS, DiscretizationError, discretize
from derive.errors import ExpressionError
from derive.expressions import check_values, parse_expression
from derive.modelfile import MAX_STATES
from derive.statements import Temporary, rename, substitute
from derive.toml_limits import MAX_DIGITS, MAX_KEY_PARTS, MAX_NESTING, toml_shape_problem

ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD = 60  # seconds; these runs take one or two


def _cli(args, cwd, env_extra=None):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DERIVE_PROGRESS", None)
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "derive", "generate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=HANG_GUARD, env=env,
                          stdin=subprocess.DEVNULL)


def _refused(path: Path, *words: str, filters=("kf",)) -> str:
    """Run `path`; assert exit 2 with one stderr line holding `words`; return the line."""
    out = path.parent / "out"
    args = [path.name] + [f"--filter={f}" for f in filters] + ["--out", str(out)]
    result = _cli(args, path.parent)
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, lines
    for word in words:
        assert word in lines[0], lines[0]
    assert not out.exists()
    return lines[0]


def _generated(path: Path, filters=("kf",)) -> Path:
    out = path.parent / "out"
    args = [path.name] + [f"--filter={f}" for f in filters] + ["--out", str(out)]
    result = _cli(args, path.parent)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    return out


# -- continuous models --------------------------------------------------------------------

def _continuous(tmp_path, name, Phi, states, parameters=""):
    n = len(states)
    H = [[1] + [0] * (n - 1)]
    G = [0] * (n - 1) + [1]
    text = f"""[model]
name = "{name}"
states = {states!r}
measurements = ["z"]
[parameters]
dt = 0.1
q = 0.01
r = 0.1
{parameters}
[continuous]
Phi = {Phi}
G = {G}
Qc = "q"
H = {H}
R = "r"
dt = "dt"
""".replace("'", '"')
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


NUMERIC_PHI = {
    "oscillator2": ("[[0, 1], [-2, -0.3]]", ["s", "v"]),
    "oscillator3": ("[[0, 1, 0], [0, 0, 1], [-1, -2, -0.3]]", ["s", "v", "a"]),
    "numeric4": ("[[-0.5, 1, 0.2, 0], [0.1, -0.3, 1, 0], [0, -0.7, -0.2, 1], "
                 "[-1, 0, -0.4, -0.6]]", ["a", "b", "c", "e"]),
    "valued2": ('[[0, 1], ["-w", "-c"]]', ["s", "v"], "w = 2\nc = 0.3"),
}


@pytest.mark.parametrize("case", sorted(NUMERIC_PHI))
def test_numeric_phi_is_discretised_numerically(tmp_path, case):
    Phi, states, *parameters = NUMERIC_PHI[case]
    path = _continuous(tmp_path, case, Phi, states, *parameters)
    out = _generated(path)
    header = (out / case / "kf.py").read_text()
    assert f"discretisation: {METHODS['numeric-expm']}" in header


def test_catalog_continuous_models_stay_exact(tmp_path):
    for name in ("cv", "ca"):
        model = catalog.load(name)
        assert model.continuous["method"] == "exact-nilpotent"
        assert sympy.Symbol("dt", real=True) in model.F.free_symbols
    out = _cli(["cv", "--filter=kf", "--lang=c", "--out", str(tmp_path)], tmp_path)
    assert out.returncode == 0, out.stderr
    assert f"discretisation: {METHODS['exact-nilpotent']}" in (tmp_path / "cv/kf.h").read_text()


@pytest.mark.parametrize("case, Phi, states, parameters, words", [
    ("free2", '[[0, 1], ["-w", "-c"]]', ["s", "v"],
     'w = { description = "free" }\nc = { description = "free" }',
     ["cannot discretise the 2x2", "square root of c**2 - 4*w", "values for c, w"]),
    ("free3", '[[0, 1, 0], [0, 0, 1], ["-a0", "-a1", "-a2"]]', ["s", "v", "a"],
     'a0 = { description = "free" }\na1 = { description = "free" }\n'
     'a2 = { description = "free" }',
     ["cannot discretise the 3x3", "not triangular", "values for a0, a1, a2"]),
    ("free3tri", '[["-k1", 1, 0], [0, "-k2", 1], [0, 0, "-k3"]]', ["s", "v", "a"],
     'k1 = { description = "free" }\nk2 = { description = "free" }\n'
     'k3 = { description = "free" }',
     ["cannot discretise the 3x3", "3 distinct symbolic eigenvalues", "values for k1, k2, k3"]),
])
def test_symbolic_phi_beyond_the_bounds_is_refused(tmp_path, case, Phi, states, parameters,
                                                   words):
    path = _continuous(tmp_path, case, Phi, states, parameters)
    _refused(path, f"{case}.toml", *words)


def _van_loan_exact(Phi, W, dt):
    n = Phi.rows
    M = sympy.zeros(2 * n, 2 * n)
    M[:n, :n], M[:n, n:], M[n:, n:] = -Phi, W, Phi.T
    E = (M * dt).exp()
    F = E[n:, n:].T
    return (np.array(F.evalf(30).tolist(), dtype=complex).real,
            np.array((F * E[:n, n:]).evalf(30).tolist(), dtype=complex).real)


@pytest.mark.parametrize("Phi", [
    [[0, 1], [-2, sympy.Rational(-3, 10)]],
    [[-1, 2], [sympy.Rational(1, 2), -3]],
    [[0, 1], [-4, 0]],
])
def test_numeric_expm_matches_sympy_exactly_computed(Phi):
    Phi = sympy.Matrix(Phi)
    G = sympy.Matrix([0, 1])
    Qc = sympy.Matrix([[sympy.Rational(1, 100)]])
    dt = sympy.Rational(1, 10)
    F, Qd, method = discretize(Phi, G, Qc, dt, {})
    assert method == "numeric-expm"
    F_exact, Qd_exact = _van_loan_exact(Phi, G * Qc * G.T, dt)
    F_num = np.array(F.tolist(), dtype=float)
    Qd_num = np.array(Qd.tolist(), dtype=float)
    assert np.abs(F_num - F_exact).max() <= 1e-12 * np.abs(F_exact).max()
    assert np.abs(Qd_num - Qd_exact).max() <= 1e-12 * np.abs(Qd_exact).max()
    assert Qd == Qd.T


def test_numeric_expm_keeps_a_noise_symbol_and_structural_zeros():
    q = sympy.Symbol("q", real=True)
    Phi = sympy.Matrix([[-1, 0, 0], [1, -2, 0], [0, 0, -3]])  # state 2 is decoupled
    G = sympy.Matrix([[1, 0], [0, 0], [0, 1]])
    F, Qd, method = discretize(Phi, G, sympy.Matrix([[q, 0], [0, 2]]),
                               sympy.Rational(1, 5), {})
    assert method in ("exact-sympy", "numeric-expm")
    F, Qd, method = discretize(Phi + sympy.Matrix([[0, 1, 0], [0, 0, 0], [0, 0, 0]]), G,
                               sympy.Matrix([[q, 0], [0, 2]]), sympy.Rational(1, 5), {})
    assert method == "numeric-expm"
    assert F[0, 2] == F[2, 0] == F[1, 2] == F[2, 1] == 0
    assert Qd[0, 2] == Qd[2, 0] == 0
    assert Qd[0, 0].free_symbols == {q}
    assert Qd[2, 2].is_Rational and Qd[2, 2] > 0


def test_triangular_phi_is_exact():
    a = sympy.Symbol("a", real=True)
    dt = sympy.Symbol("dt", real=True)
    F, _, method = discretize(sympy.Matrix([[0, 1], [0, -a]]), sympy.Matrix([0, 1]),
                              sympy.Matrix([[1]]), dt)
    assert method == "exact-sympy"
    assert sympy.simplify(F[1, 1] - sympy.exp(-a * dt)) == 0


def test_symbolic_phi_without_values_is_a_discretization_error():
    w, c, dt = sympy.symbols("w c dt", real=True)
    for Qc in (sympy.Matrix([[1]]), sympy.Matrix([[w]])):
        with pytest.raises(DiscretizationError, match="needs values for c, dt, w"):
            discretize(sympy.Matrix([[0, 1], [-w, -c]]), sympy.Matrix([0, 1]), Qc, dt)


# -- nonlinear models and parameter values ------------------------------------------------

def _nonlinear(tmp_path, name, f0="x + dt*v", h="x", parameters=""):
    path = tmp_path / f"{name}.toml"
    path.write_text(f"""[model]
name = "{name}"
states = ["x", "v"]
measurements = ["z"]
[parameters]
dt = 0.1
{parameters}
[nonlinear]
f = ["{f0}", "v"]
h = ["{h}"]
Q = [[0.01, 0], [0, 0.01]]
R = 0.1
""")
    return path


@pytest.mark.parametrize("filters", [("ekf",), ("ukf",)])
def test_deeply_nested_measurement_is_derived(tmp_path, filters):
    h = "x*v"
    for _ in range(15):
        h = f"sin({h})"
    _generated(_nonlinear(tmp_path, "sin15", h=h), filters)


@pytest.mark.parametrize("f0, value, words", [
    ("x + dt*10**k*v", "1e600", ["f[0]", "10**k", "exponent", "limit of 64"]),
    ("x + dt**k*v", "1e8", ["f[0]", "dt**k", "exponent 100000000", "limit of 64"]),
    ("x + dt*exp(exp(exp(k)))*v", "3", ["f[0]", "k = 3", "not finite as a double"]),
    ("x + dt*exp(exp(exp(k)))*v", "1000", ["f[0]", "k = 1000", "exp(k)", "not finite"]),
])
def test_parameter_values_that_explode_are_refused(tmp_path, f0, value, words):
    path = _nonlinear(tmp_path, "explode", f0=f0, parameters=f"k = {value}")
    _refused(path, "explode.toml: [nonlinear]", *words, filters=("ekf",))


def test_values_in_initial_state_are_checked(tmp_path):
    path = _nonlinear(tmp_path, "initial", parameters="k = 1e8\n[initial]\n"
                      'x0 = ["dt**k", 0]\nP0 = [[1, 0], [0, 1]]')
    _refused(path, "[initial] x0[0]", "exponent 100000000", filters=("ekf",))


def test_check_values_accepts_ordinary_values():
    x, k, dt = sympy.symbols("x k dt", real=True)
    names = {"x": x, "k": k, "dt": dt}
    values = {k: sympy.Integer(3), dt: sympy.Rational(1, 10)}
    for text in ("x**k", "dt**k * exp(k) + sin(x*dt)", "sqrt(k) + log(dt)", "atan2(k, dt)"):
        check_values(parse_expression(text, names), values)
    with pytest.raises(ExpressionError, match="not a real number"):
        check_values(parse_expression("sqrt(dt - k)", names), values)


# -- files and TOML shapes ----------------------------------------------------------------

def _compose(path: Path, blocks: list[str]) -> Path:
    entries = ", ".join(blocks)
    path.write_text(f'[model]\nname = "{path.stem}"\n[compose]\nblocks = [{entries}]\n')
    return path


def test_compose_of_300_blocks_is_refused(tmp_path):
    path = _compose(tmp_path / "many.toml",
                    [f'{{ model = "cv", suffix = "b{i}" }}' for i in range(300)])
    assert path.stat().st_size < 12_000
    _refused(path, "many.toml: [compose] blocks: 300 blocks", f"limit of {MAX_STATES}")


def test_compose_amplification_through_two_files_is_refused(tmp_path):
    _compose(tmp_path / "inner.toml",
             [f'{{ model = "cv", suffix = "b{i}" }}' for i in range(20)])
    outer = _compose(tmp_path / "outer.toml",
                     [f'{{ model = "inner.toml", suffix = "a{i}" }}' for i in range(20)])
    inner = 20 * catalog.load("cv").n
    passing = MAX_STATES // inner  # the block that takes the composed model past the limit
    _refused(outer, f"outer.toml: [compose] blocks[{passing}] model",
             f"{(passing + 1) * inner} states", f"limit of {MAX_STATES}")


def test_compose_within_the_limit_reuses_loaded_blocks(tmp_path):
    _compose(tmp_path / "inner.toml",
             [f'{{ model = "cv", suffix = "b{i}" }}' for i in range(2)])
    outer = _compose(tmp_path / "outer.toml",
                     [f'{{ model = "inner.toml", suffix = "a{i}" }}' for i in range(3)])
    out = _generated(outer)
    assert "n: 12 (states)" in (out / "outer" / "kf.py").read_text()


def test_compose_of_a_missing_file_names_the_block(tmp_path):
    path = _compose(tmp_path / "bad.toml", ['{ model = "nope.toml", suffix = "x" }'])
    _refused(path, "bad.toml: [compose] blocks[0] model: 'nope.toml': cannot read model file")


def test_long_dotted_key_is_refused(tmp_path):
    path = tmp_path / "dotted.toml"
    path.write_text("a" + ".a" * 150_000 + " = 1\n")
    _refused(path, "dotted.toml: ", "line 1, column", f"more than {MAX_KEY_PARTS} dotted parts")


def test_deep_nesting_is_refused(tmp_path):
    path = tmp_path / "nested.toml"
    path.write_text("x = " + "[" * 200_000 + "]" * 200_000 + "\n")
    _refused(path, "nested.toml: ", "line 1, column 37", f"more than {MAX_NESTING} deep")


def test_long_integer_is_refused(tmp_path):
    path = tmp_path / "digits.toml"
    path.write_text('[model]\nname = "d"\nstates = ["s"]\nmeasurements = ["z"]\n'
                    f'[parameters]\nk = {"9" * 5000}\n[discrete]\nF = "k"\nH = 1\nQ = 1\n'
                    "R = 1\n")
    _refused(path, "digits.toml: ", "line 6, column", f"more than {MAX_DIGITS} digits")


def test_many_states_are_refused_quickly(tmp_path):
    path = tmp_path / "states.toml"
    names = ", ".join(f'"s{i}"' for i in range(100_000))
    path.write_text(f'[model]\nname = "st"\nstates = [{names}]\nmeasurements = ["z"]\n'
                    "[discrete]\nF = 1\nH = 1\nQ = 1\nR = 1\n")
    _refused(path, "states.toml: [model] states: 100000 names, more than the limit of "
                   f"{MAX_STATES}")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "model.toml"
    os.mkfifo(fifo)
    _refused(fifo, "model.toml: cannot read model file: it is a FIFO")


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
def test_device_is_refused(tmp_path):
    result = _cli(["/dev/zero", "--out", str(tmp_path / "out")], tmp_path)
    assert result.returncode == 2
    assert result.stderr.splitlines() == [
        "derive: error: /dev/zero: cannot read model file: it is a device, and a model file "
        "must be a regular file"]


@pytest.mark.parametrize("text", [
    'a = "x.y.z[[[[" # [[[[ and a.b.c.d\nb = 1',
    'x = """a""""\nb = [1]',
    "x = '''a\n[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[['''\nb = 1",
    'x = "a\\"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["',
    "x = [1.5, 2.5, 3.5, 4.5]",
])
def test_toml_scanner_skips_strings_and_comments(text):
    assert toml_shape_problem(text) is None


def test_toml_scanner_accepts_the_catalog():
    for name in catalog.names():
        assert toml_shape_problem(catalog.read_text(name)) is None


# -- progress -----------------------------------------------------------------------------

def test_progress_lines_only_when_asked(tmp_path):
    _compose(tmp_path / "big.toml", [f'{{ model = "cv", suffix = "b{i}" }}' for i in range(6)])
    quiet = _cli(["big.toml", "--filter=kf", "--lang=python", "--out", "q"], tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == ""
    loud = _cli(["big.toml", "--filter=kf", "--lang=python", "--out", "l"], tmp_path,
                {"DERIVE_PROGRESS": "1"})
    assert loud.returncode == 0
    assert loud.stderr.splitlines() == ["derive: deriving kf for big (12 states, "
                                        "6 measurements)..."]


def test_substitution_into_calls_skips_their_eval(monkeypatch):
    """derive.statements.substitute (how the UKF's sigma-point differences and the
    optimiser put program atoms into expressions): xreplace's result, but a call whose
    new arguments are not all numbers is rebuilt without sympy's eval, which searched
    each argument for multiples of pi and i (a UKF of h = six products of 24 sines
    spent most of its 27 s there); a call of numbers still folds. Where eval would
    rewrite a call (``cos(-2x + t)`` into ``cos(2x - t)``) the two are equal as values."""
    x, d, e = sympy.symbols("x d e", real=True)
    t, u = Temporary("t1"), Temporary("t2")
    exprs = [sympy.sin(x + d) * sympy.cos(2 * x - d), sympy.exp(x * d) + sympy.atan2(x, d + e),
             sympy.sin(x + d + e) ** 2, sympy.sin(d) + sympy.cos(e)]
    mappings = [{d: t}, {d: t, x: u}, {d: sympy.sqrt(3) * t, e: u}, {d: sympy.Integer(0)}]
    calls = []
    real_eval = sympy.sin.eval.__func__

    def counted(cls, arg):
        calls.append(arg)
        return real_eval(cls, arg)
    for expr in exprs:
        for mapping in mappings:
            wanted = expr.xreplace(mapping)
            monkeypatch.setattr(sympy.sin, "eval", classmethod(counted))
            got = substitute(expr, mapping)
            monkeypatch.undo()
            point = {s: 0.1 + 0.7 * k for k, s in enumerate(sorted(wanted.free_symbols, key=str))}
            assert abs(complex(got.evalf(subs=point)) - complex(wanted.evalf(subs=point))) \
                <= 1e-12 * max(1.0, abs(complex(wanted.evalf(subs=point)))), (expr, mapping)
            assert got.free_symbols == wanted.free_symbols
    assert all(arg.is_number for arg in calls)
    assert substitute(sympy.sin(d) + sympy.cos(e), {d: sympy.Integer(0), e: t}) == \
        1 * sympy.cos(t)    # a call of numbers folds: sin(0) is 0


def test_renaming_rebuilds_sums_and_products_as_substitution_does():
    """derive.statements.rename (how the optimiser renumbers temporaries) rebuilds a sum or
    product from its renamed arguments in sympy's order instead of through flatten (an
    injective renaming merges nothing); the expression is substitute's, argument order
    and all, on random sums, products, powers, calls and numbers."""
    rng = np.random.default_rng(5)
    temps = [Temporary(f"t{i}") for i in range(30)]
    atoms = temps + list(sympy.symbols("x0:4")) + [sympy.Integer(2), sympy.Rational(1, 3),
                                                   sympy.Float(0.25)]

    def expr(depth):
        kind = int(rng.integers(0, 6)) if depth else 5
        if kind == 5:
            return atoms[int(rng.integers(0, len(atoms)))]
        parts = [expr(depth - 1) for _ in range(int(rng.integers(2, 4)))]
        return (sympy.Add(*parts) if kind < 2 else sympy.Mul(*parts) if kind < 4 else
                sympy.sin(parts[0]) ** int(rng.choice([1, 2, -1])))
    for _ in range(300):
        e = expr(4)
        names = dict(zip(temps, (Temporary(f"t{i}") for i in rng.permutation(100)[:30] + 100)))
        assert sympy.srepr(rename(e, names)) == sympy.srepr(substitute(e, names))
