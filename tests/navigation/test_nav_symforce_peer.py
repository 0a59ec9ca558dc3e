"""SymForce's C++ as a timed peer (derive.apps.bench.peers.symforce_peer), on small inputs: the
programs' lines are parsed, outputs split and compared as the bench does, cachegrind's and
nm's figures read; the counting scalar type tallies derive's generated C exactly as its
header counts (a small EKF) and SymForce's spellings as derive's C rules count them. No
wall-clock assertions."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from derive import catalog
from derive.apps.bench.bars import BARS
from derive.apps.bench.peers import symforce_peer as sp
from derive.apps.bench.peers.navigation import NavigationResult, error_state_point
from derive.apps.bench.run import Bar, BenchResult, Settings
from derive.apps.ins import symforce_ekf
from derive.build import load_python
from derive.generation import generate_units
from derive.interface import read as read_interface
from derive.model import NonlinearModel, Sensor
from derive.trees import OpCount

ROOT = Path(__file__).resolve().parents[2]

needs_gpp = pytest.mark.skipif(shutil.which("g++") is None, reason="g++ is not installed")


def test_program_lines_are_parsed_by_kind():
    text = ("out ins_gnss predict derive 0 1 2 3 4 5\n"
            "time ins_gnss predict 1.5e-07 3.0e-07\n"
            "count ins_gnss predict symforce 1 2 3 4 5 6 7 8 9\n\n")
    parsed = sp.parse_lines(text)
    status, values = parsed["out"][("ins_gnss", "predict", "derive")]
    assert status == 0 and values.tolist() == [1, 2, 3, 4, 5]
    assert parsed["time"][("ins_gnss", "predict")] == (1.5e-07, 3.0e-07)
    assert parsed["count"][("ins_gnss", "predict", "symforce")] == OpCount(
        add=1, sub=2, mul=3, div=4, sqrt=5, fma=6, neg=7, cmp=8, calls=9)
    x, P = sp.split_output(np.arange(6.0), 2)
    assert x.tolist() == [0, 1] and P.tolist() == [[2, 3], [4, 5]]
    with pytest.raises(ValueError):
        sp.split_output(np.arange(5.0), 2)
    x, P = sp.split_output(np.arange(7.0), 3, 2)  # an error state: P over 2 tangent rows
    assert x.tolist() == [0, 1, 2] and P.tolist() == [[3, 4], [5, 6]]


def test_error_state_point_is_the_generated_predicts_input_and_reference():
    """The peer's ins_eskf predict point: its expected (x, P) is what the generated predict
    (vector rows over the 15 tangent rows) returns there, 1e-13 (the peer's agreement
    measure), and x is of storage size, P tangent-sized."""
    point, expected = error_state_point("ins_eskf")
    assert point.x.shape == (16,) and point.P.shape == (15, 15)
    module = load_python(ROOT / "generated" / "ins_eskf" / "eskf.py")
    x_new, P_new = (np.asarray(v, dtype=float) for v in
                    module.predict(point.x, point.P, point.args["predict"], [point.dt]))
    assert sp.agreement((x_new, P_new.reshape(15, 15)), expected["predict"]) <= 1e-13


def test_agreement_is_relative_to_x_and_to_the_standard_deviations():
    x_ref, P_ref = np.array([2.0, -4.0]), np.diag([4.0, 1.0])
    P = P_ref.copy()
    P[0, 1] = P[1, 0] = 1e-6  # sd 2 and 1: 1e-6 / 2
    assert sp.agreement((x_ref + [0.0, 4e-8], P), (x_ref, P_ref)) == pytest.approx(5e-7)
    assert sp.agreement((x_ref + [0.0, 4e-6], P_ref), (x_ref, P_ref)) == pytest.approx(1e-6)


def test_cachegrind_summary_and_nm_symbols_are_read():
    summary = "==12== I   refs:      1,234,567\n==12== I1  misses:        8,765\n"
    assert sp.cachegrind_misses(summary) == 8765
    with pytest.raises(ValueError):
        sp.cachegrind_misses("==12== I refs: 3\n")
    symbols = {"m_ekf_predict": ("T", 100), "m_ekf_predict.cold": ("t", 20),
               "m_ekf_predict_other": ("T", 7), "data": ("D", 50),
               "_ZN3sym7PredictIdEEvRK": ("W", 300)}
    assert sp.code_bytes(symbols, "m_ekf_predict") == 120
    assert sp.code_bytes(symbols, None) == 427


def test_constant_ratios_are_folded_and_derives_c_becomes_counted_cpp():
    source = "const Scalar a = (Scalar(1) / Scalar(2)) * x(0, 0) / (Scalar(3) + b);"
    assert sp.folded_constants(source) == ("const Scalar a = (Scalar(double(1) / double(2))) "
                                           "* x(0, 0) / (Scalar(3) + b);")
    c_text = "int f(const double *restrict x, double *restrict y) { y[0] = 2.0*x[0]; }"
    assert sp.counting_source(c_text) == ('#include "counted.h"\nint f(const Counted * x, '
                                          'Counted * y) { y[0] = 2.0*x[0]; }')


def _compile_and_run(folder: Path, sources: list[Path], extra: tuple[str, ...] = ()) -> str:
    program = folder / "counted"
    subprocess.run(["g++", *sp.CXXFLAGS, "-O0", "-I", str(folder), *extra, *map(str, sources),
                    "-o", str(program)], check=True, capture_output=True, timeout=300)
    return subprocess.run([str(program)], check=True, capture_output=True, text=True,
                          timeout=60).stdout


def _unicycle() -> NonlinearModel:
    """A 3-state EKF with inputs in f and Qu, and two sensors: one fused sequentially, one
    batch with a square root in h."""
    return NonlinearModel(
        "unicycle", ["px", "py", "th"],
        f=["px + dt*v*cos(th)", "py + dt*v*sin(th)", "th + dt*w"],
        Q=[["q", 0, 0], [0, "q", 0], [0, 0, "q"]], values={"dt": 0.1, "q": 1e-6, "sv": 0.01,
                                                         "sw": 0.001},
        inputs=["v", "w"], Qu=[["sv", 0], [0, "sw"]],
        sensors=[Sensor("pos", ["zx", "zy"], h=["px", "py"], R=[[0.25, 0], [0, 0.25]],
                        update="sequential"),
                 Sensor("range", ["r"], h=["sqrt(px**2 + py**2 + 1)"], R=[[0.5]])])


def _call_block(function) -> str:
    """One C++ block: the function's arrays, the tally reset, the call, the tally printed."""
    lines, args = ["  {"], []
    for a in function.arguments:
        values = (np.eye(3).ravel() * 2.0 + 0.1 if a.name == "P"
                  else np.linspace(0.3, 0.9, a.size()))
        lines.append(f"    static Counted {a.name}[{a.size()}] = "
                     f"{{{', '.join(repr(float(v)) for v in values)}}};")
        args.append(a.name)
    lines += ["    tally = Tally();", f"    {function.name}({', '.join(args)});",
              f'    std::printf("count m {function.program} derive %ld %ld %ld %ld %ld %ld %ld '
              '%ld %ld\\n", tally.add, tally.sub, tally.mul, tally.div, tally.sqrt, '
              "tally.fma, tally.neg, tally.cmp, tally.calls);", "  }"]
    return "\n".join(lines)


@needs_gpp
def test_counting_scalar_tallies_derives_c_as_its_header_counts(tmp_path):
    paths, _ = generate_units(_unicycle(), ["ekf"], "c", tmp_path / "gen")
    header = next(p for p in paths if p.suffix == ".h")
    source = next(p for p in paths if p.suffix == ".c")
    (tmp_path / "counted.h").write_text(sp.COUNTED)
    (tmp_path / header.name).write_text(sp.counting_source(header.read_text()))
    cpp = tmp_path / "ekf.cpp"
    cpp.write_text(sp.counting_source(source.read_text()))
    functions = [f for f in read_interface(header.read_text()).functions if f.program != "run"]
    main = tmp_path / "main.cpp"
    main.write_text(f'#include <cstdio>\n#include "counted.h"\n#include "{header.name}"\n'
                    "Tally tally;\nint main() {\n"
                    + "\n".join(_call_block(f) for f in functions) + "\n  return 0;\n}\n")
    out = _compile_and_run(tmp_path, [cpp, main], ("-DDERIVE_VECTOR=0",
                                                    "-DDERIVE_FMA(a,b,c)=counted_fma(a,b,c)",
                                                    "-DDERIVE_FNMA(a,b,c)=counted_fnma(a,b,c)"))
    counted = sp.parse_lines(out)["count"]
    assert {p for _, p, _ in counted} == {"predict", "update_pos", "update_range"}
    for (_, program, _), count in counted.items():
        assert count == sp.header_count(header.read_text(), program), program
        assert count.fma > 0 and count.calls == 2 * (program == "predict")  # cos, sin


@needs_gpp
def test_counting_scalar_tallies_symforce_spellings_as_derives_c_rules(tmp_path):
    source = """
#pragma once
#include <Eigen/Core>
namespace sym {
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
}
"""
    (tmp_path / "Eigen").mkdir()
    (tmp_path / "Eigen" / "Core").write_text(sp.EIGEN_SHIM)
    (tmp_path / "counted.h").write_text(sp.COUNTED)
    (tmp_path / "demo.h").write_text(sp.folded_constants(source))
    main = tmp_path / "main.cpp"
    main.write_text('#include <cstdio>\n#include "counted.h"\n#include "demo.h"\n'
                    "Tally tally;\nint main() {\n"
                    "  Eigen::Matrix<Counted, 2, 1> x, out;\n  x(0, 0) = 0.5; x(1, 0) = 2.0;\n"
                    "  sym::Demo<Counted>(x, &out);\n"
                    '  std::printf("count m demo symforce %ld %ld %ld %ld %ld %ld %ld %ld %ld\\n", '
                    "tally.add, tally.sub, tally.mul, tally.div, tally.sqrt, tally.fma, "
                    "tally.neg, tally.cmp, tally.calls);\n"
                    '  std::printf("out m demo symforce 0 %.17g %.17g\\n", (double)out(0, 0), '
                    "(double)out(1, 0));\n  return 0;\n}\n")
    parsed = sp.parse_lines(_compile_and_run(tmp_path, [main]))
    assert parsed["count"][("m", "demo", "symforce")] == symforce_ekf.count_cpp(source)
    half = 0.25
    assert parsed["out"][("m", "demo", "symforce")][1] == pytest.approx(
        [-(8.0 - half) + 2.5, 1.0 / np.sqrt(half * half + 1.0)], rel=1e-15)


def test_bars_are_printed_with_both_figures_and_the_vector_count_decides_flops():
    r = sp.FunctionResult("m", "predict", header=OpCount(mul=10, fma=45),   # 100 flops
                          counted={"derive": OpCount(mul=10, fma=40),      # 90 (fallback)
                                   "symforce": OpCount(add=50, mul=70)})   # 120
    for name, _, _ in sp.BUILDS:
        r.times[name] = (1e-7, 2e-7)
    r.times["float -O2"] = (1.2e-7, 2e-7)
    r.x86_bytes[sp.SIZE_BUILD] = (900, 1000)
    r.m4f_bytes = {"-Os": (1100, 1000), "-O2": (1, 2)}
    result = sp.PeerResult(functions=[r], derive_seconds={"ins_fc24": (2.5, 2.0)})
    bars = {b.claim: b for b in result.bars(Bar)}
    flops = bars["m predict: flops over SymForce's (one counter)"]
    assert flops.value == pytest.approx(100 / 120) and flops.met
    assert "scalar fallback, counted, 90" in flops.note
    double = bars["m predict: time per call over SymForce's, double -O2"]
    assert double.value == pytest.approx(0.5) and double.met
    assert double.bar == BARS["symforce_time_double_O2"]
    single = bars["m predict: time per call over SymForce's, float -O2"]
    assert single.value == pytest.approx(0.6) and not single.met
    assert single.bar == BARS["symforce_time_float_O2"]
    assert bars["m predict: x86-64 code, double -O2 over SymForce's"].met
    m4f = bars["m predict: Cortex-M4F .text, float -Os over SymForce's"]
    assert not m4f.met and m4f.text().startswith(
        "bar: m predict: Cortex-M4F .text, float -Os over SymForce's: 1.10x (<= 1x: NOT met)")
    generation = bars["generating ins_fc24's EKF (C)"]
    assert generation.met and generation.kind == "time"
    assert any("no: counted 90, header 100" in line for line in result.lines())


def test_the_floor_of_a_unit_row_update_is_under_derives_count_and_printed():
    """unit_row_floor: the barometer's update (one measurement, h = -pd) has a floor, no
    other function has; it is at most the count of derive's generated update, and the
    flops bar's note and the table print it beside the figures."""
    model = catalog.load("ins_gnss")
    floors = {f: sp.unit_row_floor(model, f) for f in symforce_ekf.function_names(model)}
    assert [f for f, v in floors.items() if v is not None] == ["update_baro"]
    header = sp.header_count((ROOT / "generated/ins_gnss/ekf.h").read_text(encoding="utf-8"),
                             "update_baro")
    assert floors["update_baro"] <= header.flops
    r = sp.FunctionResult("ins_gnss", "update_baro", header=header,
                          counted={"derive": header, "symforce": OpCount(add=400)},
                          floor=floors["update_baro"])
    (bar,) = [b for b in sp.PeerResult(functions=[r]).bars(Bar) if "flops" in b.claim]
    assert f"no code takes fewer than {floors['update_baro']} flops" in bar.note
    assert any(f"floor {floors['update_baro']}, " in line
               for line in sp.PeerResult(functions=[r]).lines())


def test_only_navigation_prints_that_section_and_its_bars_alone():
    r = sp.FunctionResult("m", "update_x", header=OpCount(mul=3),
                          counted={"derive": OpCount(mul=3), "symforce": OpCount(mul=6)})
    machine = {"cpu": "a CPU", "cores": 2, "load": "0.5", "python": "3", "numpy": "2",
               "generated_cflags": []}
    result = BenchResult(Settings(only="navigation"), machine)
    result.navigation = NavigationResult(peer=sp.PeerResult(functions=[r]))
    text = result.text()
    assert "machine: a CPU, 2 cores" in text and "SymForce's C++ as a timed peer" in text
    bars = [line for line in text.splitlines() if line.startswith("bar: ")]
    assert bars and all("m update_x" in line or "ins_gnss" in line for line in bars)
    assert "bar: m update_x: flops over SymForce's (one counter): 0.50x (<= 0.9x: met)" in text
    assert not any("mpt3d" in line for line in bars)  # the catalog's bars are not this run's
