"""Burden formulas derived by exact interpolation (`derive burden --formula`) and any formula
audited against them (`derive audit --formula`). Counts are cached per process
(derive.apps.burden_formula.paper_count), so the paper-mode sizes test_audit.py counted are
not counted again; the fits here use small grids and few check sizes."""

from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest
import sympy

from derive import catalog
from derive.apps import burden_formula as bf
from derive.apps import formulas
from derive.cli import main
from derive.filters import derive_unit
from derive.flops import OpCount, count

CHECKS = bf.CHECKS[("n", "m")][:2]   # paper-mode sizes test_audit.py's audit counted


def _synthetic(rule, variables=("n", "m")):
    """A family whose step 'counts' ``rule(sizes)`` additions: the mechanism alone."""
    return bf.Family("toy", "paper", variables, "a rule",
                     lambda sizes, lang: OpCount(add=rule(*sizes)))


def test_interpolation_recovers_exact_rational_coefficients():
    fam = _synthetic(lambda n, m: (16 * m**3 - 3 * m**2 - m) // 6 + 4 * n**2 * m + 7)
    derived = bf.derive_formula(fam, check=((9, 4), (11, 2)), series=("python.add",))
    poly = derived.polynomial("python.add")
    want = {(0, 3): Fraction(8, 3), (0, 2): Fraction(-1, 2), (0, 1): Fraction(-1, 6),
            (2, 1): Fraction(4), (0, 0): Fraction(7)}
    assert dict(poly.terms) == want
    # a total degree <= 3 in two variables: 10 coefficients, fit on the 10 smallest sizes
    assert len(derived.fit_sizes) == 10 and max(map(sum, derived.fit_sizes)) == 5
    assert not set(derived.fit_sizes) & set(derived.check_sizes)
    # printed as a formula that parses back to itself
    assert bf.parse_claim(str(poly), fam) == poly


def test_a_rule_that_changes_at_small_sizes_holds_from_a_raised_smallest_size():
    fam = _synthetic(lambda n, m: n * m + (1 if n == 1 else 0))
    fit = bf.derive_formula(fam, check=((6, 3), (4, 5)), series=("python.add",)).fits[
        "python.add"]
    assert (fit.minimum, str(fit.polynomial)) == (2, "n*m")


def test_a_count_no_polynomial_fits_names_the_sizes_where_the_fit_fails():
    fam = _synthetic(lambda n, m: n * m + (n * m) % 3)
    derived = bf.derive_formula(fam, max_degree=4, check=((6, 5), (8, 7)),
                                series=("python.add",))
    fit = derived.fits["python.add"]
    assert fit.polynomial is None and fit.degree == 4
    assert fit.failures and {s for s, _, _ in fit.failures} <= set(derived.check_sizes)
    for (n, m), counted, predicted in fit.failures:
        assert counted == n * m + (n * m) % 3 != predicted
    line = next(ln for ln in bf.formula_lines(derived) if "python.add" in ln)
    assert "no polynomial of total degree <= 4" in line
    assert "(n = {}, m = {})".format(*fit.failures[0][0]) in line


@pytest.fixture(scope="module")
def kf_paper():
    fam = bf.family("kf", "paper")
    return bf.derive_formula(fam, check=CHECKS, series=("flops",))


def test_a_wrong_coefficient_is_flagged_with_its_term(kf_paper, capsys):
    text = formulas.PRINTED["kf"].replace("3*n*m**2", "4*n*m**2")
    check = bf.audit_formula(text, kf_paper.family, derived=kf_paper)
    assert not check.equal and check.terms == [("n*m**2", 4, 3)]
    assert str(check.difference) == "n*m**2"
    sizes, claimed, counted = check.first
    assert sizes == (1, 1) and claimed - counted == 1
    assert counted == bf.paper_count("kf", (1, 1)).flops
    argv = ["audit", "--formula", text, "--filter", "kf", "--paper"] + [
        arg for sizes in CHECKS for arg in ("--check", ",".join(map(str, sizes)))]
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert "differs in 1 term(s): n*m**2: formula 4, derived 3" in out
    assert "smallest sizes where they differ: n = 1, m = 1" in out
    assert main(argv[:2] + [formulas.PRINTED["kf"]] + argv[3:]) == 0
    assert "equal: the formula is the derived polynomial" in capsys.readouterr().out
    api = bf.check_formula(text, "kf", "paper", check=CHECKS)
    assert api.terms == check.terms and api.first == check.first


HOSTILE = [
    ("n**99999", "exponent 99999 is too large"),
    ("n + q", "unknown symbol 'q'"),
    ("__import__('os')", "call of '__import__' is not allowed"),
    ("__import__('os').system('true')", "not allowed"),
    ("-" * 100 + "n", "nested more than"),
    ("(n + " * 70 + "n" + ")" * 70, "nested more than"),
    ("n + " * 700 + "n", "characters long"),
    ("(n + m + 1)**64", "total degree 64"),
    ("sqrt(n)", "not a polynomial in n, m"),
    ("2**n", "not a polynomial in n, m"),
    ("1/n + n", "a division by n"),
    ("N*n", "unknown symbol 'N'"),
]


@pytest.mark.parametrize("formula, words", HOSTILE)
def test_hostile_formulas_get_one_line_and_exit_2(formula, words, capsys):
    assert main(["audit", f"--formula={formula}", "--filter", "kf", "--paper"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured
    assert words in captured.err and "Traceback" not in captured.err


@pytest.mark.parametrize("argv, words", [
    (["audit", "--formula", "n", "--paper"], "needs --filter"),
    (["audit", "--formula", "n", "--filter", "ekf", "--paper"], "paper mode has no filter"),
    (["audit", "--formula", "n", "--filter", "kf", "--kind", "c.flops"], "--kind 'c.flops'"),
    (["audit", "--paper"], "--paper applies to --formula EXPR only"),
    (["burden", "--formula", "--paper"], "needs --filter"),
    (["burden", "--formula", "--filter", "kf", "--family", "blocks"], "needs MODEL"),
    (["burden", "cv", "--formula", "--filter", "kf", "--paper"], "takes no MODEL"),
    (["burden", "--formula", "--filter", "kf", "--paper", "--check", "5"], "need 2 integers"),
    (["burden", "--formula", "--filter", "kf", "--paper", "--check", "a,b"], "--check 'a,b'"),
    (["burden", "--formula", "--filter", "kf", "--paper", "--degree", "9", "--max-degree",
      "4"], "degree bounds"),
    (["burden"], "needs MODEL"),
    (["burden", "cv", "--check", "5,5"], "--check applies to --formula only"),
    (["audit", "--degree", "4"], "--degree applies to --formula EXPR only"),
    (["burden", "--formula", "--filter", "kf", "--paper", "--measure"], "--measure"),
    (["burden", "--formula", "--filter", "kf", "--paper", "--check", "17,1"], "from 1 to 16"),
])
def test_bad_requests_get_one_line_and_exit_2(argv, words, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def test_burden_formula_of_paper_mode_by_kind(capsys):
    assert main(["burden", "--formula", "--paper", "--filter", "sskf", "--json",
                 "--check", "5,5", "--check", "6,3"]) == 0
    (data,) = json.loads(capsys.readouterr().out)
    series = data["series"]
    fam = bf.family("sskf", "paper")
    assert series["flops"]["formula"] == str(bf.Polynomial.from_expr(
        formulas.claim("sskf"), fam.variables))
    # the C lowering fuses nothing in a one-term dot product: its kinds obey a polynomial
    # from n, m >= 2 on, and (1, 1) is where that polynomial misses
    for kind in ("c.add", "c.mul", "c.fma"):
        assert series[kind]["from"] == 2, kind
        poly = bf.parse_claim(series[kind]["formula"], fam)
        assert poly((1, 1)) != getattr(bf.paper_count("sskf", (1, 1), "c"), kind[2:])
        assert poly((6, 4)) == getattr(bf.paper_count("sskf", (6, 4), "c"), kind[2:])
    for kind in ("python.add", "python.mul"):
        assert series[kind]["from"] == 1
    # the kinds of each lowering add up to the flops, an fma two
    flops = bf.parse_claim(series["flops"]["formula"], fam)
    c_sum = sum((bf.parse_claim(series[f"c.{k}"]["formula"], fam).expr() * (2 if k == "fma"
                                                                             else 1)
                 for k in ("add", "sub", "mul", "div", "sqrt", "fma")), sympy.S.Zero)
    assert sympy.expand(c_sum - flops.expr()) == 0


def test_burden_formula_of_dense_models_says_which_kinds_are_not_polynomial(capsys):
    argv = ["burden", "--formula", "--filter", "sskf", "--max-degree", "3", "--check", "4,3",
            "--check", "5,2"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "flops (the papers' convention" in out
    assert "= 2*n**2 + 2*n*m - n" in out   # the steady state: A x + B z, dense
    # which entries are negative (a subtraction rather than an addition) depends on the
    # numbers, not the sizes: no polynomial, and the sizes where the fit fails
    add = next(ln for ln in out.splitlines() if "python.add" in ln)
    assert "no polynomial of total degree <= 3" in add and "(n = 4, m = 3)" in add
    for n, m in ((4, 3), (5, 2)):
        unit = derive_unit(bf.dense_model(n, m), "sskf", {})
        assert count(unit.programs["step"]).flops == formulas.sskf(n, m)


def test_dense_models_are_dense_and_repeatable():
    a, b = bf.dense_model(4, 2, seed=3), bf.dense_model(4, 2, seed=3)
    num = a.numeric()
    for matrix in (num.F, num.H, num.Q, num.R):
        assert np.all(matrix != 0) and not np.any(np.abs(matrix) == 1)
    assert np.array_equal(num.F, b.numeric().F)
    assert max(abs(np.linalg.eigvals(num.F))) < 1


def test_blocks_family_is_k_times_one_block(capsys):
    assert main(["burden", "mpt3d_b", "--formula", "--family", "blocks", "--filter", "kf",
                 "--json", "--check", "6"]) == 0
    (data,) = json.loads(capsys.readouterr().out)
    one = count(derive_unit(catalog.load("mpt3d_b"), "kf", {}).programs["step"])
    fam = bf.family("kf", "blocks", catalog.load("mpt3d_b"))
    assert bf.parse_claim(data["series"]["flops"]["formula"], fam) == \
        bf.parse_claim(f"{one.flops}*k", fam)
    three = count(derive_unit(catalog.load("mpt3d_a"), "kf", {}).programs["step"])
    assert three.flops == 3 * one.flops


def test_a_model_fixes_n_and_m(capsys):
    assert main(["audit", "--formula", formulas.PRINTED["sskf"], "--filter", "sskf",
                 "--model", "ca"]) == 0
    assert "ca (n = 3, m = 1): the formula gives 21" in capsys.readouterr().out
    check = bf.audit_at_model(formulas.PRINTED["kf"], "kf", catalog.load("mpt3d_a"), "paper")
    assert check.equal and check.count == bf.paper_count("kf", (6, 3)).flops
    check = bf.audit_at_model("2*N*n*m - n", "fir", catalog.load("cv"), "dense")
    assert check.sizes["N"] >= 1 and check.claim == formulas.fir(check.sizes["N"], 2, 1)
