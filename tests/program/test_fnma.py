"""The fused negative multiply-add of the C lowering (``c - a*b`` as ``DERIVE_FNMA``), and
the folding of products and negations read once by a sum (derive.single_use) that lets the
lowering see them: its rules, its counts (as an fma: one instruction, two flops) executed,
in the header and in the C text, its rounding (the plain build bitwise that of the
fma-free lowering, the fused build one rounding), the strict flags in both precisions, and
the generated C against the NumPy reference in the fused build."""

from __future__ import annotations

import ctypes
import json
import re
import shutil
import subprocess
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import sympy

from derive import LinearModel, catalog
from derive.apps.latency import carried_bound
from derive.apps.verify import verify_modules
from derive.build import CONVERSION_CFLAGS, STRICT_CFLAGS, build_c
from derive.emit import c_printer
from derive.emit.render import render_c
from derive.expression_lowering import lower
from derive.filters import derive_unit
from derive.flops import count, count_c_function, count_c_text, count_lowered
from derive.generation import command_unit, generate
from derive.lowering import lower_program
from derive.pipeline import load_generated
from derive.precision import precision
from derive.program import Port, Program
from derive.schedule import REFERENCE_CYCLES, latency_schedule
from derive.trees import Const, Op, Var, count_tree, tree_kinds

ROOT = Path(__file__).resolve().parents[2]
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _has_fma() -> bool:
    try:
        return " fma " in Path("/proc/cpuinfo").read_text() + " "
    except OSError:
        return False


needs_fma_cpu = pytest.mark.skipif(not _has_fma(), reason="needs a CPU with fma (x86 FMA3)")

a, b, c, d, e = sympy.symbols("a b c d e")
A, B, C, D, E = (Var(n) for n in "abcde")


def mul(x, y):
    return Op("mul", (x, y))


# -- the lowering ----------------------------------------------------------------------

@pytest.mark.parametrize("expr, tree", [
    (c - a * b, Op("fnma", (A, B, C))),
    (c - a * b - d * e, Op("fnma", (D, E, Op("fnma", (A, B, C))))),
    (c + a * b - d * e, Op("fnma", (D, E, Op("fma", (A, B, C))))),
    (-a * b, Op("neg", (mul(A, B),))),                       # alone: no sum to fuse into
    (-a * b - d * e, Op("fnma", (D, E, Op("neg", (mul(A, B),))))),
    (d * e - a * b, Op("fnma", (A, B, mul(D, E)))),          # starts at the positive one
    (3 - a * b, Op("fnma", (A, B, Const(3.0)))),             # a constant accumulator
    (c - 2 * a * b, Op("fma", (Const(-2.0), mul(A, B), C))),  # the constant takes the sign
    (c - a * b / d, Op("sub", (C, Op("div", (mul(A, B), D))))),  # a quotient: no fusion
])
def test_negative_products_in_sums_lower_to_fnma(expr, tree):
    assert lower(expr, use_fma=True) == tree


@pytest.mark.parametrize("expr", [c - a * b, c - a * b - d * e, 3 - a * b, -a * b - d * e,
                                  d * e - a * b])
def test_fnma_is_one_instruction_and_two_flops_counted_as_fma(expr):
    fused, plain = count_tree(lower(expr, use_fma=True)), count_tree(lower(expr))
    assert fused.flops == plain.flops
    # each fused product saves exactly its multiplication
    assert fused.instructions == plain.instructions - fused.fma
    assert "fnma" not in tree_kinds(lower(expr))                # Python never fuses


def test_c_text_counts_fnma_as_an_fma():
    tree = lower(c - a * b - d * e, use_fma=True)
    text = f"y[0] = {c_printer.expression(tree)};"
    assert text == "y[0] = DERIVE_FNMA(d, e, DERIVE_FNMA(a, b, c));"
    assert count_c_text(text) == count_tree(tree)


def test_the_macros_define_fnma_beside_fma_in_both_precisions():
    for real in ("double", "float"):
        lines = c_printer.fma_macro_lines(precision(real))
        text = "\n".join(lines)
        assert "#define DERIVE_FNMA(a, b, c) ((c) - (a) * (b))" in text
        assert "#define DERIVE_FNMA(a, b, c) DERIVE_FMA((a), -(b), (c))" in text
        assert f"{precision(real).math('fma')}((a), (b), (c))" in text


# -- folding products and negations read once ---------------------------------------------

def _program(build) -> Program:
    prog = Program("f", [Port("x", (5,))], [Port("y", (3,))])
    x = prog.matrix("x")
    prog.set_output("y", build(prog, x))
    return prog.optimize()


def test_a_product_read_once_by_a_sum_folds_into_it():
    def build(prog, x):
        t = prog.let(x[0] * x[1])
        s = prog.let(x[3] * x[4])
        return [prog.let(x[2] - t), prog.let(x[2] + s), prog.let(x[1] * s)]
    prog = _program(build)
    # s is read twice: it stays; t is read once, by a sum: it folds
    plain, fused = lower_program(prog), lower_program(prog, use_fma=True)
    assert len(fused.body) == len(plain.body) - 1
    assert "fnma" in fused.kinds() and "fnma" not in plain.kinds()
    assert count_lowered(fused).flops == count_lowered(plain).flops
    assert count_lowered(fused).instructions == count_lowered(plain).instructions - 1


def test_a_negation_read_only_by_sums_folds_into_each_of_them():
    def build(prog, x):
        n = prog.let(-x[0])
        return [prog.let(x[1] + n), prog.let(x[2] + 3 * n), prog.let(x[3] + n)]
    prog = _program(build)
    assert count(prog, "python").neg == 1
    fused = lower_program(prog, use_fma=True)
    assert count_lowered(fused).neg == 0
    assert count_lowered(fused).flops == count(prog, "python").flops


def test_a_negation_read_by_a_product_stays():
    def build(prog, x):
        n = prog.let(-x[0])
        return [prog.let(x[1] + n), prog.let(x[2] * n), prog.let(x[3] + x[4])]
    prog = _program(build)
    assert count_lowered(lower_program(prog, use_fma=True)).neg == 1


def test_a_negated_product_read_once_folds_twice():
    """``t = a*b; n = -t; y = c + n``: one fused negative multiply-add."""
    def build(prog, x):
        t = prog.let(x[0] * x[1])
        n = prog.let(-t)
        return [prog.let(x[2] + n), x[3], x[4]]
    prog = _program(build)
    fused = lower_program(prog, use_fma=True)
    assert [s.tree.kind for s in fused.body] == ["fnma"]


# -- the catalog: counts in the header, the C text and executed ---------------------------

_HEADER = re.compile(r"operations per call of (\w+) \((C99|Python)[^)]*\): (.*)\n")


def _header_counts(text: str) -> dict[str, str]:
    return {name: summary for name, _, summary in _HEADER.findall(text)}


def test_every_generated_c_file_counts_as_its_text_and_keeps_the_python_flops():
    """Every committed C filter: each function's header count is the count of its text
    (DERIVE_FNMA an fma), its flops are its Python's, and it has no more instructions."""
    checked = fused = 0
    for header in sorted((ROOT / "generated").glob("*/*.h")):
        c_text = header.with_suffix(".c").read_text()
        py = header.with_suffix(".py")
        if not py.is_file():
            continue
        c_counts, py_counts = _header_counts(header.read_text()), _header_counts(py.read_text())
        prefix = json.loads(re.search(r"derive-interface: (\{.*\})", header.read_text())
                            .group(1))["functions"][0][0].rsplit("_", 1)[0]
        for name, summary in c_counts.items():
            text_count = count_c_function(c_text, f"{prefix}_{name}")
            assert text_count.summary() == summary, (header, name)
            flops = int(re.search(r"flops (\d+)", summary).group(1))
            assert flops == int(re.search(r"flops (\d+)", py_counts[name]).group(1))
            assert text_count.instructions <= int(
                re.search(r"instructions (\d+)", py_counts[name]).group(1))
            checked += 1
        fused += c_text.count("DERIVE_FNMA(") > 1
    assert checked > 50 and fused > 20


def _harness(header: Path, work: Path) -> Path:
    """A program calling each function of a generated C file once (inputs: x 0.1 k, P and
    P0 the identity, other inputs 0.05 k, p 0.01), DERIVE_FMA and DERIVE_FNMA defined to count
    their calls; prints ``name status fma fnma`` per function."""
    described = json.loads(re.search(r"derive-interface: (\{.*\})", header.read_text())
                           .group(1))
    lines = ["#include <stdio.h>", "static long fmas, fnmas;",
             "static double count_fma(double a, double b, double c) "
             "{ fmas++; return a * b + c; }",
             "static double count_fnma(double a, double b, double c) "
             "{ fnmas++; return c - a * b; }",
             "#define DERIVE_FMA(a, b, c) count_fma((a), (b), (c))",
             "#define DERIVE_FNMA(a, b, c) count_fnma((a), (b), (c))",
             f'#include "{header.with_suffix(".c").name}"',
             "int main(void) {", "int k, status = 0;"]
    for c_name, name, has_status, is_run, ports in described["functions"]:
        if is_run:
            continue
        args = []
        for port, shape, *_ in ports:
            size = int(np.prod(shape))
            var = f"{name}_{port}"
            args.append(var)
            lines.append(f"double {var}[{size}];")
            if port.startswith("P") and len(shape) == 2 and shape[0] == shape[1]:
                lines.append(f"for (k = 0; k < {size}; k++) {var}[k] = "
                             f"(k % {shape[-1] + 1} == 0) ? 1.0 : 0.0;")
            else:
                scale = {"x": 0.1, "p": 0.0}.get(port, 0.05)
                lines.append(f"for (k = 0; k < {size}; k++) {var}[k] = {scale} * (k + 1)"
                             + (" + 0.01" if port == "p" else "") + ";")
        call = f"{c_name}({', '.join(args)})"
        lines += ["fmas = fnmas = 0;", f"{'status = ' if has_status else ''}{call};",
                  f'printf("{name} %d %ld %ld\\n", status, fmas, fnmas);']
    lines += ["return 0;", "}"]
    source = work / f"harness_{header.stem}.c"
    source.write_text("\n".join(lines) + "\n")
    shutil.copy(header, work / header.name)
    shutil.copy(header.with_suffix(".c"), work / header.with_suffix(".c").name)
    exe = work / f"harness_{header.stem}"
    # the vector branch of vector rows (what the header counts, lane by lane) on any
    # target: the strict build of x86-64 (SSE2) would take the scalar lanes, which leave
    # out the lanes nothing reads
    subprocess.run(["gcc", *STRICT_CFLAGS, "-DDERIVE_VECTOR=1", "-Wno-unused-function",
                    str(source), "-o", str(exe), "-lm"], check=True, capture_output=True,
                   timeout=600)
    return exe


@needs_gcc
@pytest.mark.parametrize("model, filter_name", [("ins_gnss", "ekf"), ("mpt3d_a", "kf"),
                                                ("ca", "udkf"), ("gnss_pseudorange", "ukf")])
def test_fused_operations_executed_are_the_header_counts(tmp_path, model, filter_name):
    """Each function run once, its fused multiply-adds counted as they execute: their sum
    is the header's fma, the negative ones are the DERIVE_FNMA of the text."""
    header = ROOT / "generated" / model / f"{filter_name}.h"
    if not header.is_file():
        pytest.skip(f"no generated {model}/{filter_name}")
    c_text = header.with_suffix(".c").read_text()
    counts = _header_counts(header.read_text())
    out = subprocess.run([str(_harness(header, tmp_path))], check=True, capture_output=True,
                         text=True, timeout=60).stdout.split("\n")
    prefix = f"{model}_{filter_name}"
    seen = 0
    for line in filter(None, out):
        name, status, fmas, fnmas = line.split()
        assert status == "0", line
        assert int(fmas) + int(fnmas) == int(re.search(r"fma (\d+)", counts[name]).group(1))
        # the text's fmas with DERIVE_FMA and DERIVE_VFMA renamed (calls then): its
        # DERIVE_FNMAs and DERIVE_VFNMAs (once per lane) alone, through the functions it
        # calls (a step's body)
        renamed = c_text.replace("DERIVE_FMA(", "other_fma(").replace("DERIVE_VFMA(",
                                                                      "other_vfma(")
        negative = count_c_function(renamed, f"{prefix}_{name}")
        assert int(fnmas) == negative.fma
        seen += 1
    assert seen == len(counts)


# -- rounding --------------------------------------------------------------------------

def _random_inputs(rng, n=16):
    x = rng.normal(size=n)
    x[:4] /= np.linalg.norm(x[:4])
    root = rng.normal(size=(n, n)) * 0.1
    return x, root @ root.T + 0.01 * np.eye(n)


@needs_gcc
def test_the_plain_build_is_bitwise_the_fma_free_lowering_for_ins_gnss(tmp_path):
    """Without FP_FAST_FMA, DERIVE_FNMA is the product and the subtraction: the INS/GNSS EKF
    lowered with fused negative products computes bitwise what the fma-free lowering does
    (the folded products and the sums keep their order there)."""
    unit = command_unit(catalog.load("ins_gnss"), "ekf", {})
    modules = {}
    for use_fma in (True, False):
        folder = tmp_path / str(use_fma)
        folder.mkdir()
        for name, text in render_c(unit, use_fma=use_fma).items():
            (folder / name).write_text(text)
        modules[use_fma] = build_c(folder / "ekf.c", tmpdir=tmp_path)[unit.prefix]
    assert "DERIVE_FNMA(" in (tmp_path / "True" / "ekf.c").read_text()
    assert "DERIVE_FNMA(" not in (tmp_path / "False" / "ekf.c").read_text()
    rng = np.random.default_rng(3)
    p = np.array([0.01])
    for _ in range(5):
        x, P = _random_inputs(rng)
        for name, given in (("predict", rng.normal(size=6)), ("update_gnss", rng.normal(size=6)),
                            ("update_baro", rng.normal(size=1))):
            fused = modules[True].call(name, x, P, given, p=p)
            plain = modules[False].call(name, x, P, given, p=p)
            for f_out, p_out in zip(fused, plain):
                assert np.array_equal(f_out, p_out), name


def _fnma_library(tmp_path: Path, flags: list[str]) -> ctypes.CDLL:
    prog = Program("f", [Port("x", (3,))], [Port("y", (1,))])
    x = prog.matrix("x")
    prog.set_output("y", [prog.let(x[2] - x[0] * x[1])])
    lowered = lower_program(prog.optimize(), use_fma=True)
    assert lowered.kinds() == {"fnma"}
    lines = ["#include <math.h>", *c_printer.FMA_MACRO_LINES,
             "void f(const double *restrict x, double *restrict y);",
             "void f(const double *restrict x, double *restrict y) {",
             *c_printer.statements(lowered), "}"]
    source = tmp_path / f"fnma{len(flags)}.c"
    source.write_text("\n".join(lines) + "\n")
    library = source.with_suffix(".so")
    subprocess.run(["gcc", *STRICT_CFLAGS, *flags, "-shared", "-fPIC", str(source), "-o",
                    str(library), "-lm"], check=True, capture_output=True, timeout=120)
    return ctypes.CDLL(str(library))


def _call(lib: ctypes.CDLL, values) -> float:
    x = (ctypes.c_double * 3)(*values)
    y = (ctypes.c_double * 1)()
    lib.f(x, y)
    return y[0]


def _cases(rng, count=200):
    """Products that cancel most of c (where one rounding and two differ)."""
    for _ in range(count):
        a_, b_ = rng.uniform(0.5, 2.0, 2)
        yield a_, b_, a_ * b_ * (1 + rng.normal() * 1e-12)


@needs_gcc
def test_plain_fnma_rounds_as_a_product_and_a_subtraction(tmp_path):
    lib = _fnma_library(tmp_path, [])
    for a_, b_, c_ in _cases(np.random.default_rng(5)):
        assert _call(lib, (a_, b_, c_)) == c_ - a_ * b_


@needs_gcc
@needs_fma_cpu
def test_fused_fnma_rounds_once(tmp_path):
    """With FP_FAST_FMA (-mfma), DERIVE_FNMA(a, b, c) is c - a*b rounded once: the exact
    value rounded to the nearest double."""
    lib = _fnma_library(tmp_path, ["-mfma"])
    differs = 0
    for a_, b_, c_ in _cases(np.random.default_rng(5)):
        exact = float(Fraction(c_) - Fraction(a_) * Fraction(b_))
        assert _call(lib, (a_, b_, c_)) == exact
        differs += exact != c_ - a_ * b_
    assert differs > 0   # the cases do tell one rounding from two


# -- the generated C: verified in the fused build, strict in both precisions --------------

@needs_gcc
@needs_fma_cpu
@pytest.mark.parametrize("model, filter_name", [("mpt3d_a", "kf"), ("ca", "lf"),
                                                ("gnss_pseudorange", "ekf")])
def test_the_fused_build_agrees_with_the_reference(tmp_path, model, filter_name):
    generated = load_generated(model, filter_name, {}, "c", tmp_path, extra_cflags=["-mfma"])
    assert "DERIVE_FNMA(" in (tmp_path / model / f"{filter_name}.c").read_text()
    for result in verify_modules(catalog.load(model), filter_name,
                                 {"c": generated.module("c")}, steps=300):
        assert result.passed, result.line()


@needs_gcc
@pytest.mark.parametrize("flags", [[], ["-mfma"]])
def test_ins_gnss_compiles_strictly_in_both_precisions(tmp_path, flags):
    if flags and not _has_fma():
        pytest.skip("needs a CPU with fma")
    for real in ("double", "float"):
        out = tmp_path / real
        generate("ins_gnss", filters=["ekf"], lang="c", out=out, options={"precision": real})
        source = out / "ins_gnss" / "ekf.c"
        assert "DERIVE_FNMA(" in source.read_text()
        proc = subprocess.run(["gcc", *STRICT_CFLAGS, *CONVERSION_CFLAGS, *flags, "-c",
                               source.name], cwd=source.parent, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[:3000]


# -- the latency schedule against the shorter default ---------------------------------------

def test_the_latency_schedule_never_lengthens_the_default_chain():
    """A random model (found by tests/performance/test_perf_latency.py's search) whose default
    chain the fused negative multiply-add shortened below what the latency schedule's rounds reach
    (134 against 136 reference cycles): the schedule keeps the default step."""
    model = LinearModel(
        "rand", [f"x{i}" for i in range(5)], [f"y{i}" for i in range(3)],
        [[0.677, 0, 0, 0, 0.549], [0.178, 0.409, 0, 0.836, 0],
         [0, 0.201, 0.378, -0.017, 0.26], [-0.249, -0.196, 0.029, 0.909, 0.361],
         [-0.015, 0.418, 0, -0.422, 0.773]],
        [[0.429, 1, -0.601, 0, 1.125], [-0.784, -0.213, 0, 1, -0.364], [1, 0, 0, 0, 0.787]],
        [[0.471, 0.344, -0.252, 0.06, -0.301], [0.344, 1.839, -0.481, -1.37, 0.536],
         [-0.252, -0.481, 0.337, 0.231, 0.091], [0.06, -1.37, 0.231, 1.719, -0.577],
         [-0.301, 0.536, 0.091, -0.577, 1.313]],
        [[0.82, 0.289, -0.392], [0.289, 1.249, -0.008], [-0.392, -0.008, 1.18]])
    default = derive_unit(model, "kf", {}).programs["step"]
    scheduled = latency_schedule(default)

    def chain(program):
        return carried_bound(lower_program(program, use_fma=True), REFERENCE_CYCLES).per_step
    assert chain(scheduled) <= chain(default)
