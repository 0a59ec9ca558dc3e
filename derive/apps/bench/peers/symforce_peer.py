"""SymForce's generated C++ as a timed peer of derive's generated C, for the navigation EKFs
(``ins_gnss`` and ``ins_fc24``): the same functions (predict and each sensor's update) from
the same equations (derive.apps.ins.symforce_ekf), compiled by the same GCC, checked against
each other and the NumPy references, timed in one process; and for their error-state
versions (``ins_eskf``, ``ins_fc24_eskf``, filter ``eskf``) the predict against SymForce's
with the attitude a ``sf.Rot3`` and its tangent-space Jacobians
(derive.apps.ins.symforce_eskf; :data:`ROT3`, the part of sym::Rot3 it uses, and
:data:`_ESKF_WRAPPER`, which moves the quaternion between derive's rows and the Rot3).

- Builds: double ``-O2``, float ``-O2``, double ``-O2 -march=native`` and float ``-O2
  -march=native``. derive's C is generated in the build's precision; SymForce's function
  templates are instantiated with that scalar. SymForce's code indexes ``Eigen::Matrix``
  only (``x(i, j)``, the default column-major layout), so it is compiled against a small
  header of ours (:data:`EIGEN_SHIM`: a fixed-size array with that indexing, 16-byte
  aligned as Eigen's), not Eigen itself; P is symmetric, so its column-major read is P.
- Timing: one C++ program per build calls every function through non-inline calls (derive's
  C functions and one extern "C" wrapper per SymForce function, each in its own translation
  unit: the wrapper reinterprets the arrays as the matrices, no copy), interleaved: each
  repeat times ``calls`` calls of derive's function, then of SymForce's, for each function
  in turn; per call the minimum over the repeats of this thread's CPU time
  (``CLOCK_THREAD_CPUTIME_ID``: on a shared machine the time others run is not counted,
  and short windows of calls, many repeats, let the minimum find one undisturbed). Inputs
  are the same every call (the operating point of the model's flight).
- Agreement: in each build, the outputs (x_new and P_new) of both on the operating point,
  against each other and against the model's NumPy reference (derive.apps.ins.reference,
  derive.apps.ins.fc24), by the measure of navigation._agreement.
- Code size: per function, the bytes of code of its symbols in the object (``nm -S``):
  derive's function and its clones (``name.part.0``, ``name.cold``); all code of the
  SymForce wrapper's translation unit (the wrapper and the instantiated template). On
  x86-64 per build; for Cortex-M4F (float, ``arm-none-eabi-gcc``/``g++`` with
  derive.apps.targets.toolchains.CORTEX_M4_FLAGS) at ``-Os`` and ``-O2``.
- L1i misses per call: valgrind's cachegrind (its cache simulation of this machine's L1i)
  on the double ``-O2`` program calling one function K1 and K2 times; (misses(K2) −
  misses(K1)) / (K2 − K1), so the program's start and the first call's cold misses cancel.
- Flops under one counter: both codes compiled once more with a counting scalar type
  (:data:`COUNTED`: every +, −, ×, ÷, √, fma, negation and comparison tallied; derive's
  C compiled as C++ with its element type replaced by it and its fma macros by counting
  functions, its vector rows as their scalar lanes; SymForce's template instantiated with
  it, ``std::pow(b, k)`` with integer k ≥ 1 tallied as k − 1 multiplications). derive's
  tallies must equal its header's counts (checked and printed).

The bars (issue 25): flops ≤ 0.9x SymForce's; time ≤ 0.8x SymForce's in double -O2 and ≤
0.5x in the other three builds; x86-64 code (double -O2) and Cortex-M4F .text (float, -Os)
≤ SymForce's; each printed met or NOT met with the figures.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .... import catalog
from ....build import cache_dir
from ....filters.sensors import program_name
from ....generation import generate_units
from ....manifolds import QUATERNION
from ....trees import OpCount
from ...ins import symforce_ekf, symforce_eskf
from ...targets.toolchains import CORTEX_M4_FLAGS, SIZE_LEVELS
from ..bars import BARS
from ..timing import columns, human

MODELS = ("ins_gnss", "ins_fc24", "ins_eskf", "ins_fc24_eskf")
FLOPS_BAR = BARS["symforce_flops_share"]
TIME_BARS = {"double -O2": BARS["symforce_time_double_O2"],
             "float -O2": BARS["symforce_time_float_O2"],
             "double -O2 -march=native": BARS["symforce_time_double_native"],
             "float -O2 -march=native": BARS["symforce_time_float_native"]}
"""Bar per build: derive's time per call over SymForce's, at most."""
BUILDS = (("double -O2", "double", ("-O2",)), ("float -O2", "float", ("-O2",)),
          ("double -O2 -march=native", "double", ("-O2", "-march=native")),
          ("float -O2 -march=native", "float", ("-O2", "-march=native")))
"""(name, precision, flags) of the timed builds."""
SIZE_BUILD = "double -O2"
"""The build whose x86-64 code sizes the code-size bar compares (and cachegrind runs)."""
M4F_BAR_LEVEL = "-Os"
CACHE_CALLS = (10, 60)
"""K1 and K2 of the L1i misses per call."""
CXXFLAGS = ("-std=c++17", "-Wall", "-Wextra", "-Wno-unused-parameter")

EIGEN_SHIM = """\
// The part of Eigen that SymForce's generated functions use: a fixed-size matrix indexed
// (i, j), column-major (Eigen's default), 16-byte aligned (Eigen's fixed-size alignment);
// <cmath>, which Eigen/Core includes (SymForce calls std::sqrt and std::pow).
#pragma once
#include <cmath>
namespace Eigen {
template <typename Scalar, int Rows, int Cols, int Options = 0, int MaxRows = Rows,
          int MaxCols = Cols>
struct Matrix {
  alignas(16) Scalar m[Rows * Cols];
  Scalar& operator()(long i, long j) { return m[i + j * Rows]; }
  const Scalar& operator()(long i, long j) const { return m[i + j * Rows]; }
  Scalar& operator[](long i) { return m[i]; }
  const Scalar& operator[](long i) const { return m[i]; }
};
}  // namespace Eigen
"""

ROT3 = """\
// The part of sym::Rot3 that SymForce's generated functions use: its four stored numbers
// (x, y, z, w), what the generated code reads (Data()) and writes (the constructor).
#pragma once
#include <Eigen/Core>
namespace sym {
template <typename Scalar> class Rot3 {
 public:
  Rot3() {}
  explicit Rot3(const Eigen::Matrix<Scalar, 4, 1>& d) : data_(d) {}
  const Eigen::Matrix<Scalar, 4, 1>& Data() const { return data_; }
 private:
  Eigen::Matrix<Scalar, 4, 1> data_;
};
}  // namespace sym
"""

COUNTED = """\
// A scalar that tallies every arithmetic operation on it (derive's operation kinds).
#pragma once
#include <cmath>
struct Tally { long add, sub, mul, div, sqrt, fma, neg, cmp, calls; };
extern Tally tally;
struct Counted {
  double v;
  Counted() = default;
  Counted(double x) : v(x) {}
  explicit operator double() const { return v; }
};
inline Counted operator+(Counted a, Counted b) { ++tally.add; return a.v + b.v; }
inline Counted operator-(Counted a, Counted b) { ++tally.sub; return a.v - b.v; }
inline Counted operator*(Counted a, Counted b) { ++tally.mul; return a.v * b.v; }
inline Counted operator/(Counted a, Counted b) { ++tally.div; return a.v / b.v; }
inline Counted operator-(Counted a) { ++tally.neg; return -a.v; }
inline Counted operator+(Counted a) { return a; }
inline Counted& operator+=(Counted& a, Counted b) { a = a + b; return a; }
inline Counted& operator-=(Counted& a, Counted b) { a = a - b; return a; }
inline Counted& operator*=(Counted& a, Counted b) { a = a * b; return a; }
inline Counted& operator/=(Counted& a, Counted b) { a = a / b; return a; }
inline bool operator<(Counted a, Counted b) { ++tally.cmp; return a.v < b.v; }
inline bool operator<=(Counted a, Counted b) { ++tally.cmp; return a.v <= b.v; }
inline bool operator>(Counted a, Counted b) { ++tally.cmp; return a.v > b.v; }
inline bool operator>=(Counted a, Counted b) { ++tally.cmp; return a.v >= b.v; }
inline bool operator==(Counted a, Counted b) { ++tally.cmp; return a.v == b.v; }
inline bool operator!=(Counted a, Counted b) { ++tally.cmp; return a.v != b.v; }
inline Counted counted_fma(Counted a, Counted b, Counted c) {
  ++tally.fma; return a.v * b.v + c.v;
}
inline Counted counted_fnma(Counted a, Counted b, Counted c) {
  ++tally.fma; return c.v - a.v * b.v;
}
// in std, declared before <math.h>, whose `using std::sqrt` (and sin, ...) then brings them
// to the global namespace too (derive's C calls sqrt, SymForce's std::sqrt); the functions
// other than sqrt are derive's "calls"
namespace std {
inline Counted sqrt(Counted a) { ++tally.sqrt; return std::sqrt(a.v); }
inline Counted sin(Counted a) { ++tally.calls; return std::sin(a.v); }
inline Counted cos(Counted a) { ++tally.calls; return std::cos(a.v); }
inline Counted exp(Counted a) { ++tally.calls; return std::exp(a.v); }
inline Counted log(Counted a) { ++tally.calls; return std::log(a.v); }
inline Counted atan2(Counted a, Counted b) { ++tally.calls; return std::atan2(a.v, b.v); }
inline Counted pow(Counted b, Counted e) {
  // an integer power k >= 1 as k - 1 multiplications (what GCC emits for small k)
  double k = e.v;
  if (k >= 1.0 && k == static_cast<long>(k)) {
    tally.mul += static_cast<long>(k) - 1;
    return std::pow(b.v, k);
  }
  ++tally.div; ++tally.sqrt;  // b^(-1/2), the only other power in these functions
  return std::pow(b.v, e.v);
}
}  // namespace std
"""

_WRAPPER = """\
#ifdef COUNTING
#include "counted.h"
#include "{counting_header}"
#else
#include "{header}"
#endif
typedef REAL real;
extern "C" int sf_{model}_{function}(const real* x, const real* P, const real* arg,
                                    real* x_new, real* P_new, const real* p) {{
  sym::{cpp_name}<real>(
      *reinterpret_cast<const Eigen::Matrix<real, {n}, 1>*>(x),
      *reinterpret_cast<const Eigen::Matrix<real, {n}, {n}>*>(P),
      *reinterpret_cast<const Eigen::Matrix<real, {m}, 1>*>(arg),{dt}
      reinterpret_cast<Eigen::Matrix<real, {n}, 1>*>(x_new),
      reinterpret_cast<Eigen::Matrix<real, {n}, {n}>*>(P_new));
  (void)p;
  return 0;
}}
"""

_ESKF_WRAPPER = """\
#ifdef COUNTING
#include "counted.h"
#include "{counting_header}"
#else
#include "{header}"
#endif
typedef REAL real;
extern "C" int sf_{model}_{function}(const real* x, const real* P, const real* u,
                                    real* x_new, real* P_new, const real* p) {{
  Eigen::Matrix<real, 4, 1> q;
  q[0] = x[{q1}]; q[1] = x[{q2}]; q[2] = x[{q3}]; q[3] = x[{q0}];
  Eigen::Matrix<real, {n_rest}, 1> rest, rest_new;
  static const int REST[{n_rest}] = {{{rest}}};
  for (int i = 0; i < {n_rest}; ++i) rest[i] = x[REST[i]];
  sym::Rot3<real> R(q), R_new;
  sym::{cpp_name}<real>(R, rest, *reinterpret_cast<const Eigen::Matrix<real, {nt}, {nt}>*>(P),
      *reinterpret_cast<const Eigen::Matrix<real, {m}, 1>*>(u), p[0], &R_new, &rest_new,
      reinterpret_cast<Eigen::Matrix<real, {nt}, {nt}>*>(P_new));
  const Eigen::Matrix<real, 4, 1>& d = R_new.Data();
  x_new[{q0}] = d[3]; x_new[{q1}] = d[0]; x_new[{q2}] = d[1]; x_new[{q3}] = d[2];
  for (int i = 0; i < {n_rest}; ++i) x_new[REST[i]] = rest_new[i];
  return 0;
}}
"""
"""The wrapper of SymForce's error-state predict (derive.apps.ins.symforce_eskf): the
quaternion moved between derive's (w, x, y, z) rows of x and a Rot3's (x, y, z, w), the
other states gathered into and scattered from their own vector (a copy of 20 numbers)."""

_MAIN = """\
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <cstring>
{headers}
typedef REAL real;
typedef int (*Call)(const real*, const real*, const real*, real*, real*, const real*);
{declarations}
struct Fn {{ const char* model; const char* name; Call derive; Call peer; int n; int nt;
            int m; }};
static const Fn FNS[] = {{
{table}
}};
static const int COUNT = {count};
{data}
alignas(64) static real X[{n_max}], P[{nt_max} * {nt_max}], ARG[16], PAR[1];
alignas(64) static real X_NEW[{n_max}], P_NEW[{nt_max} * {nt_max}];
{tally}
static void load(int f) {{
  for (int i = 0; i < FNS[f].n; ++i) X[i] = (real)DATA_X[f][i];
  for (int i = 0; i < FNS[f].nt * FNS[f].nt; ++i) P[i] = (real)DATA_P[f][i];
  for (int i = 0; i < FNS[f].m; ++i) ARG[i] = (real)DATA_ARG[f][i];
  PAR[0] = (real)DATA_DT[f];
}}
static double now() {{
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}}
static double seconds(Call call, long calls) {{
  double start = now();
  for (long k = 0; k < calls; ++k) call(X, P, ARG, X_NEW, P_NEW, PAR);
  return now() - start;
}}
static void print_out(int f, const char* impl, int status, bool column_major) {{
  int n = FNS[f].n, nt = FNS[f].nt;
  std::printf("out %s %s %s %d", FNS[f].model, FNS[f].name, impl, status);
  for (int i = 0; i < n; ++i) std::printf(" %.17g", (double)X_NEW[i]);
  for (int i = 0; i < nt; ++i)
    for (int j = 0; j < nt; ++j)
      std::printf(" %.17g", (double)(column_major ? P_NEW[j * nt + i] : P_NEW[i * nt + j]));
  std::printf("\\n");
}}
int main(int argc, char** argv) {{
  const char* mode = argc > 1 ? argv[1] : "out";
  if (!std::strcmp(mode, "out")) {{
    for (int f = 0; f < COUNT; ++f) {{
      load(f);
      std::memset(X_NEW, 0, sizeof X_NEW); std::memset(P_NEW, 0, sizeof P_NEW);
      {reset}int s = FNS[f].derive(X, P, ARG, X_NEW, P_NEW, PAR);
      {show_derive}print_out(f, "derive", s, false);
      load(f);
      std::memset(X_NEW, 0, sizeof X_NEW); std::memset(P_NEW, 0, sizeof P_NEW);
      {reset}s = FNS[f].peer(X, P, ARG, X_NEW, P_NEW, PAR);
      {show_peer}print_out(f, "symforce", s, true);
    }}
    return 0;
  }}
  if (!std::strcmp(mode, "time") && argc == 4) {{
    long calls = std::atol(argv[2]), repeats = std::atol(argv[3]);
    double best[2 * {count_max}];
    for (int i = 0; i < 2 * COUNT; ++i) best[i] = 1e30;
    for (long r = 0; r < repeats; ++r)
      for (int f = 0; f < COUNT; ++f) {{
        load(f);
        double t = seconds(FNS[f].derive, calls) / calls;
        if (t < best[2 * f]) best[2 * f] = t;
        t = seconds(FNS[f].peer, calls) / calls;
        if (t < best[2 * f + 1]) best[2 * f + 1] = t;
      }}
    for (int f = 0; f < COUNT; ++f)
      std::printf("time %s %s %.6e %.6e\\n", FNS[f].model, FNS[f].name, best[2 * f],
                  best[2 * f + 1]);
    return 0;
  }}
  if (!std::strcmp(mode, "one") && argc == 6) {{
    for (int f = 0; f < COUNT; ++f)
      if (!std::strcmp(FNS[f].model, argv[2]) && !std::strcmp(FNS[f].name, argv[3])) {{
        load(f);
        Call call = std::strcmp(argv[4], "derive") ? FNS[f].peer : FNS[f].derive;
        seconds(call, std::atol(argv[5]));
        return 0;
      }}
    return 3;
  }}
  return 2;
}}
"""

_TALLY = """\
Tally tally;
static void show(const char* impl, int f) {
  std::printf("count %s %s %s %ld %ld %ld %ld %ld %ld %ld %ld %ld\\n", FNS[f].model,
              FNS[f].name, impl, tally.add, tally.sub, tally.mul, tally.div, tally.sqrt,
              tally.fma, tally.neg, tally.cmp, tally.calls);
}
"""


@dataclass(frozen=True)
class Point:
    """Where each function is called: x, P, its u or z, dt."""

    x: np.ndarray
    P: np.ndarray
    args: dict[str, np.ndarray]
    dt: float


@dataclass
class FunctionResult:
    model: str
    function: str
    header: OpCount | None = None            # derive's header count
    counted: dict[str, OpCount] = field(default_factory=dict)   # impl -> one counter
    times: dict[str, tuple[float, float]] = field(default_factory=dict)  # build -> (d, s)
    agreement: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    # build -> (derive vs reference, SymForce vs reference, derive vs SymForce)
    x86_bytes: dict[str, tuple[int, int]] = field(default_factory=dict)  # build -> (d, s)
    m4f_bytes: dict[str, tuple[int, int]] = field(default_factory=dict)  # level -> (d, s)
    l1i_misses: tuple[float, float] | None = None
    floor: int | None = None   # the fewest flops any code takes (unit_row_floor), if known

    @property
    def label(self) -> str:
        return f"{self.model} {self.function}"

    @property
    def derive_flops(self) -> int | None:
        """derive's flops for the bar: the counter's tally, or its header's count where that
        is larger (vector rows: the vector statements compute lanes that nothing reads,
        which the scalar fallback the counter runs skips)."""
        counted = self.counted.get("derive")
        if counted is None:
            return None
        return max(counted.flops, self.header.flops if self.header is not None else 0)


@dataclass
class PeerResult:
    functions: list[FunctionResult] = field(default_factory=list)
    symforce_seconds: dict[str, float] = field(default_factory=dict)   # model -> codegen
    derive_seconds: dict[str, tuple[float, float]] = field(default_factory=dict)
    # model -> (wall, CPU) seconds generating its EKF's C
    notes: list[str] = field(default_factory=list)
    calls: int = 0
    repeats: int = 0
    symforce: dict = field(default_factory=dict)   # model -> {function: SymforceFunction}

    def lines(self) -> list[str]:
        out = [f"SymForce's C++ as a timed peer (derive.apps.bench.peers.symforce_peer): the same "
               f"functions from the same equations, both compiled by {compiler_version()}, "
               f"called through non-inline calls in one process, interleaved; per call the "
               f"minimum of {self.repeats} repeats of {self.calls:,} calls (thread CPU time); "
               "flops from one "
               "counting scalar type; code: bytes of the function's symbols (nm); L1i: "
               f"cachegrind's misses per call ({SIZE_BUILD})", ""]
        gen = ", ".join(f"{m} derive {w:.2f} s (CPU {c:.2f} s), SymForce "
                        f"{self.symforce_seconds.get(m, float('nan')):.2f} s"
                        for m, (w, c) in self.derive_seconds.items())
        out.append(f"generation of each EKF's functions (C; SymForce C++): {gen}")
        out.append("")
        head = ["function", "flops d/SF (one counter)", "derive's header = counted"]
        for name, _, _ in BUILDS:
            head.append(f"{name}: d / SF (ratio)")
        head += ["x86 code d/SF", "L1i miss/call d/SF", "M4F .text -Os d/SF",
                 "M4F .text -O2 d/SF", "agrees d, SF, d-SF (double -O2)"]
        body = []
        for r in self.functions:
            d, s = r.counted.get("derive"), r.counted.get("symforce")
            row = [r.label, "n/a" if d is None or s is None else
                   f"{r.derive_flops} / {s.flops} ({r.derive_flops / s.flops:.2f}"
                   + ("" if r.floor is None else
                      f"; floor {r.floor}, {r.floor / s.flops:.3f}") + ")",
                   "n/a" if d is None or r.header is None else
                   ("yes" if d == r.header else
                    f"no: counted {d.flops}, header {r.header.flops} (vector lanes)")]
            for name, _, _ in BUILDS:
                t = r.times.get(name)
                row.append("n/a" if t is None else
                           f"{human(t[0])} / {human(t[1])} ({t[0] / t[1]:.2f})")
            b = r.x86_bytes.get(SIZE_BUILD)
            row.append("n/a" if b is None else f"{b[0]:,} / {b[1]:,}")
            row.append("n/a" if r.l1i_misses is None else
                       f"{r.l1i_misses[0]:.0f} / {r.l1i_misses[1]:.0f}")
            for level in SIZE_LEVELS:
                b = r.m4f_bytes.get(level)
                row.append("n/a" if b is None else f"{b[0]:,} / {b[1]:,}")
            a = r.agreement.get(SIZE_BUILD)
            row.append("n/a" if a is None else f"{a[0]:.1e}, {a[1]:.1e}, {a[2]:.1e}")
            body.append(row)
        out += columns(head, body)
        floats = [f"{r.label} {name}: {a[0]:.1e}, {a[1]:.1e}, {a[2]:.1e}"
                  for r in self.functions for name, a in r.agreement.items()
                  if name != SIZE_BUILD]
        if floats:
            out.append("agreement in the other builds (derive vs reference, SymForce vs "
                       "reference, derive vs SymForce): " + "; ".join(floats))
        out += [f"note: {n}" for n in self.notes]
        return out

    def bars(self, bar_type) -> list:
        out = []
        for r in self.functions:
            d, s = r.derive_flops, r.counted.get("symforce")
            note = "" if d is None or s is None else f"derive {d}, SymForce {s.flops}"
            if r.header is not None and d is not None and d > r.counted["derive"].flops:
                note += (f" (derive's header count: its vector rows compute every lane of a "
                         f"chunk, its scalar fallback, counted, {r.counted['derive'].flops})")
            if r.floor is not None and s is not None:
                note += (f"; no code takes fewer than {r.floor} flops ({r.floor / s.flops:.3f}x "
                         "SymForce's: docs/performance.md, \"The floor of a unit-row update\")")
            out.append(bar_type(f"{r.label}: flops over SymForce's (one counter)",
                                None if d is None or s is None else d / s.flops,
                                FLOPS_BAR, "share", note))
            for name, limit in TIME_BARS.items():
                t = r.times.get(name)
                out.append(bar_type(f"{r.label}: time per call over SymForce's, {name}",
                                    None if t is None else t[0] / t[1], limit, "share",
                                    "" if t is None else
                                    f"derive {human(t[0])}, SymForce {human(t[1])}"))
            for what, sizes, key in (("x86-64 code, " + SIZE_BUILD, r.x86_bytes, SIZE_BUILD),
                                     (f"Cortex-M4F .text, float {M4F_BAR_LEVEL}", r.m4f_bytes,
                                      M4F_BAR_LEVEL)):
                b = sizes.get(key)
                out.append(bar_type(f"{r.label}: {what} over SymForce's",
                                    None if b is None else b[0] / b[1],
                                    BARS["symforce_code_share"], "share",
                                    "" if b is None else
                                    f"derive {b[0]:,} bytes, SymForce {b[1]:,} bytes"))
        for model, (wall, cpu) in self.derive_seconds.items():
            if model == "ins_fc24":
                out.append(bar_type(f"generating {model}'s EKF (C)", wall,
                                    BARS["ins_fc24_generation"], "time",
                                    f"CPU time of this process {human(cpu)}"))
        return out

    def as_json(self) -> dict:
        return {"functions": [{"model": r.model, "function": r.function,
                               "header": None if r.header is None else r.header.__dict__,
                               "counted": {k: v.__dict__ for k, v in r.counted.items()},
                               "times": r.times, "agreement": r.agreement,
                               "x86_bytes": r.x86_bytes, "m4f_bytes": r.m4f_bytes,
                               "l1i_misses": r.l1i_misses} for r in self.functions],
                "symforce_seconds": self.symforce_seconds,
                "derive_seconds": self.derive_seconds, "notes": self.notes}


def compiler_version() -> str:
    try:
        first = subprocess.run(["gcc", "--version"], capture_output=True, text=True,
                               timeout=30).stdout.splitlines()[0]
    except (OSError, IndexError, subprocess.SubprocessError):
        return "gcc"
    return first


def _compile(command: list[str]) -> str:
    """Run a compile command (``... -c SOURCE -o OBJECT``) through a cache of objects in
    derive.build.cache_dir(): keyed by the command (paths by their names) and the bytes of
    the source and of every header beside it and in its -I directories (``*.h``, and
    files without a suffix: ``Eigen/Core``), so a second bench run compiles
    only what changed (the bench times the code, not the compiler)."""
    obj = Path(command[command.index("-o") + 1])
    source = Path(command[command.index("-c") + 1])
    folders = {source.parent, *(Path(command[i + 1]) for i, a in enumerate(command)
                                if a == "-I")}
    headers = sorted({p for f in folders for p in f.rglob("*")
                      if p.is_file() and p.suffix in (".h", "")})
    digest = hashlib.sha256()
    for part in command:
        digest.update((Path(part).name if "/" in part else part).encode() + b"\0")
    for path in [source, *headers]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    cached = cache_dir() / "bench-peer" / f"{digest.hexdigest()}.o"
    if cached.is_file():
        shutil.copyfile(cached, obj)
        return ""
    out = _run(command)
    cached.parent.mkdir(mode=0o700, exist_ok=True)
    partial = cached.with_suffix(f".{os.getpid()}.tmp")
    shutil.copyfile(obj, partial)
    os.replace(partial, cached)
    return out


def _run(command: list[str], cwd: Path | None = None, timeout: float = 900) -> str:
    done = subprocess.run(command, capture_output=True, text=True, cwd=cwd, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:3])} ... failed: {done.stderr.strip()[-800:]}")
    return done.stdout + done.stderr


# -- parsing of the programs' output (tested on small inputs) ------------------------------

def parse_lines(text: str) -> dict:
    """The program's lines by kind: ``out`` -> {(model, fn, impl): (status, values)},
    ``time`` -> {(model, fn): (derive s, SymForce s)}, ``count`` -> {(model, fn, impl):
    OpCount}."""
    out: dict = {"out": {}, "time": {}, "count": {}}
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "out":
            out["out"][tuple(parts[1:4])] = (int(parts[4]),
                                             np.array([float(v) for v in parts[5:]]))
        elif parts[0] == "time":
            out["time"][tuple(parts[1:3])] = (float(parts[3]), float(parts[4]))
        elif parts[0] == "count":
            add, sub, mul, div, sqrt, fma, neg, cmp, calls = (int(v) for v in parts[4:13])
            out["count"][tuple(parts[1:4])] = OpCount(add=add, sub=sub, mul=mul, div=div,
                                                      sqrt=sqrt, fma=fma, neg=neg, cmp=cmp,
                                                      calls=calls)
    return out


def split_output(values: np.ndarray, n: int, nt: int | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """x_new (n) and P_new (nt x nt, row-major; nt: n unless given) of one ``out`` line's
    values."""
    nt = n if nt is None else nt
    if len(values) != n + nt * nt:
        raise ValueError(f"an output line has {len(values)} values, not {n + nt * nt}")
    return values[:n], values[n:].reshape(nt, nt)


def agreement(got: tuple[np.ndarray, np.ndarray], expected: tuple[np.ndarray, np.ndarray]
              ) -> float:
    """max(|x − x_ref| / max|x_ref|, max |P − P_ref| / sqrt(P_ref,ii P_ref,jj))."""
    x, P = got
    x_ref, P_ref = expected
    sd = np.sqrt(np.diag(P_ref))
    return float(max(np.abs(x - x_ref).max() / np.abs(x_ref).max(),
                     (np.abs(P - P_ref) / np.outer(sd, sd)).max()))


def cachegrind_misses(text: str) -> int:
    """The I1 misses of cachegrind's summary (``==pid== I1  misses:   1,234``)."""
    found = re.search(r"I1\s+misses:\s+([\d,]+)", text)
    if found is None:
        raise ValueError("no 'I1 misses' line in cachegrind's output")
    return int(found.group(1).replace(",", ""))


def code_bytes(symbols: dict[str, tuple[str, int]], name: str | None) -> int:
    """Bytes of code of the function ``name`` and its clones (``name.part.0``,
    ``name.cold``) among ``symbols`` (name -> (nm type, size)); ``name`` None: all code
    (types T, t, W, w)."""
    return sum(size for sym, (kind, size) in symbols.items() if kind in "TtWw"
               and (name is None or sym == name or sym.startswith(name + ".")))


def read_symbols(nm: str, obj: Path) -> dict[str, tuple[str, int]]:
    out = {}
    for line in _run([nm, "--size-sort", "-S", str(obj)]).splitlines():
        parts = line.split()
        if len(parts) == 4:
            out[parts[3]] = (parts[2], int(parts[1], 16))
    return out


def counting_source(c_text: str) -> str:
    """derive's generated C (double) as C++ over the counting scalar: ``double`` ->
    ``Counted``, ``restrict`` dropped."""
    text = re.sub(r"\bdouble\b", "Counted", c_text)
    text = re.sub(r"\brestrict\b", "", text)
    return '#include "counted.h"\n' + text


_CONSTANT_RATIO = re.compile(r"Scalar\((-?\d+(?:\.\d*)?(?:e[-+]?\d+)?)\)\s*/\s*"
                             r"Scalar\((-?\d+(?:\.\d*)?(?:e[-+]?\d+)?)\)")


def folded_constants(source: str) -> str:
    """SymForce's C++ with each ``Scalar(a) / Scalar(b)`` of two literals written as the one
    constant it is (``Scalar(double(a) / double(b))``): the compiler folds it, so over the
    counting scalar it must not be tallied as a division."""
    return _CONSTANT_RATIO.sub(r"Scalar(double(\1) / double(\2))", source)


# -- the work --------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Model:
    name: str
    n: int
    nt: int                          # P's rows: n, or the tangent space's (error state)
    quaternion: tuple[int, ...]      # error state: the rows of x of the Rot3 (w, x, y, z)
    functions: tuple[str, ...]
    arg_sizes: dict[str, int]
    prefix: str                      # derive's C function prefix, e.g. ins_fc24_ekf
    sources: dict[str, Path]         # precision -> derive's .c
    headers: dict[str, Path]         # precision -> derive's .h
    symforce: dict                   # function -> SymforceFunction
    point: Point
    expected: dict[str, tuple[np.ndarray, np.ndarray]]


def _derive_sources(model: str, workdir: Path, result: PeerResult, filter_name: str = "ekf"):
    paths = {}
    for precision in ("double", "float"):
        start, cpu = time.perf_counter(), time.process_time()
        written, _ = generate_units(model, [filter_name], "c", workdir / precision,
                                    {"precision": precision})
        if precision == "double":
            result.derive_seconds[model] = (time.perf_counter() - start,
                                            time.process_time() - cpu)
        paths[precision] = written
    return ({p: next(x for x in w if x.suffix == ".c") for p, w in paths.items()},
            {p: next(x for x in w if x.suffix == ".h") for p, w in paths.items()})


def _prepare(model_name: str, point: Point, expected, workdir: Path, result: PeerResult
             ) -> _Model:
    model = catalog.load(model_name)
    quaternion: tuple[int, ...] = ()
    if model.manifolds:  # the error-state predict (SymForce: its Rot3 tangent Jacobians)
        (rot,) = [m for m in model.manifolds if m.kind == QUATERNION]
        quaternion = tuple(model.states.index(s) for s in rot.states)
        functions, filter_name = ("predict",), "eskf"
        symforce = {"predict": symforce_eskf.generate(model_name)}
    else:
        functions, filter_name = symforce_ekf.function_names(model), "ekf"
        symforce = symforce_ekf.generate(functions, model_name)
    sources, headers = _derive_sources(model_name, workdir / model_name, result, filter_name)
    result.symforce_seconds[model_name] = sum(f.seconds for f in symforce.values())
    result.symforce[model_name] = symforce
    sizes = {name: len(point.args[name]) for name in functions}
    return _Model(model_name, model.n, model.n_tangent, quaternion, functions, sizes,
                  f"{model_name}_{filter_name}", sources, headers, symforce, point, expected)


def _write_symforce(models: list[_Model], folder: Path) -> list[tuple[str, str, Path]]:
    """SymForce's headers, the Eigen shim and one wrapper per function: (model, function,
    wrapper path)."""
    (folder / "Eigen").mkdir(parents=True, exist_ok=True)
    (folder / "Eigen" / "Core").write_text(EIGEN_SHIM, encoding="utf-8")
    (folder / "counted.h").write_text(COUNTED, encoding="utf-8")
    if any(m.quaternion for m in models):
        (folder / "sym").mkdir(exist_ok=True)
        (folder / "sym" / "rot3.h").write_text(ROT3, encoding="utf-8")
    out = []
    for m in models:
        for function in m.functions:
            sf = m.symforce[function]
            header = folder / f"sf_{m.name}_{function}.h"
            header.write_text(sf.source, encoding="utf-8")
            counting = folder / f"sf_{m.name}_{function}_counting.h"
            counting.write_text(folded_constants(sf.source), encoding="utf-8")
            wrapper = folder / f"sf_{m.name}_{function}.cpp"
            common = dict(header=header.name, counting_header=counting.name, model=m.name,
                          function=function, cpp_name=sf.cpp_name, m=m.arg_sizes[function])
            if m.quaternion:
                q = m.quaternion
                rest = [i for i in range(m.n) if i not in q]
                text = _ESKF_WRAPPER.format(**common, nt=m.nt, q0=q[0], q1=q[1], q2=q[2],
                                            q3=q[3], n_rest=len(rest),
                                            rest=", ".join(map(str, rest)))
            else:
                text = _WRAPPER.format(**common, n=m.n,
                                       dt=" p[0]," if function == "predict" else "")
            wrapper.write_text(text, encoding="utf-8")
            out.append((m.name, function, wrapper))
    return out


def _main_source(models: list[_Model], headers: list[str], counting: bool) -> str:
    rows, data_x, data_p, data_arg, data_dt, declarations = [], [], [], [], [], []
    for m in models:
        for function in m.functions:
            name = f"sf_{m.name}_{function}"
            declarations.append(f'extern "C" int {name}(const real*, const real*, '
                                f"const real*, real*, real*, const real*);")
            rows.append(f'  {{"{m.name}", "{function}", {m.prefix}_{function}, {name}, {m.n}, '
                        f"{m.nt}, {m.arg_sizes[function]}}},")
            p = m.point
            data_x.append(_literal(p.x))
            data_p.append(_literal(p.P.ravel()))
            data_arg.append(_literal(p.args[function]))
            data_dt.append(repr(float(p.dt)))
    n_max, nt_max = max(m.n for m in models), max(m.nt for m in models)
    data = (f"static const double DATA_X[][{n_max}] = {{{', '.join(data_x)}}};\n"
            f"static const double DATA_P[][{nt_max * nt_max}] = {{{', '.join(data_p)}}};\n"
            f"static const double DATA_ARG[][16] = {{{', '.join(data_arg)}}};\n"
            f"static const double DATA_DT[] = {{{', '.join(data_dt)}}};\n")
    return _MAIN.format(
        headers="".join(f'#include "{h}"\n' for h in headers),
        declarations="\n".join(declarations), table="\n".join(rows), count=len(rows),
        count_max=len(rows), data=data, n_max=n_max, nt_max=nt_max,
        tally=_TALLY if counting else "",
        reset="tally = Tally(); " if counting else "",
        show_derive='show("derive", f); ' if counting else "",
        show_peer='show("symforce", f); ' if counting else "")


def _literal(values) -> str:
    return "{" + ", ".join(repr(float(v)) for v in np.ravel(values)) + "}"


def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)))


def _build(models: list[_Model], wrappers, folder: Path, precision: str, flags: tuple[str, ...],
           counting: bool = False) -> tuple[Path, dict, dict]:
    """Compile derive's C, SymForce's wrappers and the main program; link. (program,
    {model: derive object}, {(model, function): SymForce object})."""
    folder.mkdir(parents=True, exist_ok=True)
    real = "Counted" if counting else precision
    jobs, derive_objects, peer_objects, headers = [], {}, {}, []
    for m in models:
        source = m.sources["double" if counting else precision]
        header = m.headers["double" if counting else precision]
        local_h = folder / f"{m.name}_ekf.h"
        local_c = folder / (f"{m.name}_ekf.cpp" if counting else f"{m.name}_ekf.c")
        h_text = header.read_text(encoding="utf-8")
        c_text = source.read_text(encoding="utf-8").replace(f'#include "{header.name}"',
                                                            f'#include "{local_h.name}"')
        if counting:
            h_text, c_text = counting_source(h_text), counting_source(c_text)
        local_h.write_text(h_text, encoding="utf-8")
        local_c.write_text(c_text, encoding="utf-8")
        headers.append(local_h.name)
        obj = folder / f"{m.name}_ekf.o"
        derive_objects[m.name] = obj
        if counting:
            jobs.append(["g++", *CXXFLAGS, "-O0", "-I", str(wrappers[0][2].parent),
                         "-DDERIVE_VECTOR=0", "-DDERIVE_FMA(a,b,c)=counted_fma(a,b,c)",
                         "-DDERIVE_FNMA(a,b,c)=counted_fnma(a,b,c)", "-c", str(local_c), "-o",
                         str(obj)])
        else:
            jobs.append(["gcc", "-std=c99", *flags, "-c", str(local_c), "-o", str(obj)])
    for model, function, wrapper in wrappers:
        obj = folder / f"sf_{model}_{function}.o"
        peer_objects[(model, function)] = obj
        jobs.append(["g++", *CXXFLAGS, *(("-O0", "-DCOUNTING") if counting else flags),
                     f"-DREAL={real}", "-I", str(wrapper.parent), "-c", str(wrapper), "-o",
                     str(obj)])
    main = folder / "main.cpp"
    if counting:
        headers = ["counted.h", *headers]
    main.write_text(_main_source(models, headers, counting), encoding="utf-8")
    main_obj = folder / "main.o"
    jobs.append(["g++", *CXXFLAGS, *(("-O0",) if counting else flags), f"-DREAL={real}",
                 "-I", str(folder), "-I", str(wrappers[0][2].parent), "-c", str(main), "-o",
                 str(main_obj)])
    with _pool() as pool:
        list(pool.map(_compile, jobs))
    program = folder / "bench"
    _run(["g++", *(("-O0",) if counting else flags), str(main_obj),
          *map(str, derive_objects.values()), *map(str, peer_objects.values()), "-lm", "-o",
          str(program)])
    return program, derive_objects, peer_objects


def _m4f_sizes(models: list[_Model], wrappers, folder: Path) -> dict:
    """(model, function) -> {level: (derive bytes, SymForce bytes)} of Cortex-M4F code."""
    if shutil.which("arm-none-eabi-gcc") is None or shutil.which("arm-none-eabi-g++") is None:
        raise FileNotFoundError("arm-none-eabi-gcc/g++ not on PATH")
    folder.mkdir(parents=True, exist_ok=True)
    jobs, objects = [], {}
    for level in SIZE_LEVELS:
        tag = level.lstrip("-")
        for m in models:
            obj = folder / f"{m.name}_ekf_{tag}.o"
            objects[(m.name, None, level)] = obj
            jobs.append(["arm-none-eabi-gcc", "-std=c99", *CORTEX_M4_FLAGS, level,
                         "-I", str(m.headers["float"].parent), "-c", str(m.sources["float"]),
                         "-o", str(obj)])
        for model, function, wrapper in wrappers:
            obj = folder / f"sf_{model}_{function}_{tag}.o"
            objects[(model, function, level)] = obj
            jobs.append(["arm-none-eabi-g++", *CXXFLAGS, "-fno-exceptions", "-fno-rtti",
                         *CORTEX_M4_FLAGS, level, "-DREAL=float", "-I", str(wrapper.parent),
                         "-c", str(wrapper), "-o", str(obj)])
    with _pool() as pool:
        list(pool.map(_compile, jobs))
    out: dict = {}
    for level in SIZE_LEVELS:
        for m in models:
            derive_syms = read_symbols("arm-none-eabi-nm", objects[(m.name, None, level)])
            for function in m.functions:
                peer = read_symbols("arm-none-eabi-nm", objects[(m.name, function, level)])
                out.setdefault((m.name, function), {})[level] = (
                    code_bytes(derive_syms, f"{m.prefix}_{function}"), code_bytes(peer, None))
    return out


def l1i_size() -> str:
    """This machine's L1 instruction cache per core, as sysfs gives it (or "unknown")."""
    base = Path("/sys/devices/system/cpu/cpu0/cache")
    for index in sorted(base.glob("index*")) if base.is_dir() else ():
        try:
            if (index / "type").read_text().strip() == "Instruction" and \
                    (index / "level").read_text().strip() == "1":
                return (index / "size").read_text().strip()
        except OSError:
            continue
    return "unknown"


def _l1i(program: Path, model: str, function: str, impl: str) -> float:
    misses = []
    for calls in CACHE_CALLS:
        text = _run(["valgrind", "--tool=cachegrind", "--cache-sim=yes",
                     "--cachegrind-out-file=/dev/null", str(program), "one", model, function,
                     impl, str(calls)])
        misses.append(cachegrind_misses(text))
    return (misses[1] - misses[0]) / (CACHE_CALLS[1] - CACHE_CALLS[0])


def run_peer(points: dict[str, tuple[Point, dict]], workdir: Path, calls: int, repeats: int,
             tick=lambda text: None) -> PeerResult:
    """Everything above for the models of ``points`` (model -> (Point, {function: (x, P)
    of the NumPy reference})); ``calls`` per timing, ``repeats`` interleaved repeats."""
    result = PeerResult(calls=calls, repeats=repeats)
    models = []
    for name, (point, expected) in points.items():
        tick(f"SymForce peer: derive and SymForce generate {name}")
        models.append(_prepare(name, point, expected, workdir, result))
    wrappers = _write_symforce(models, workdir / "symforce")
    by_key = {}
    for m in models:
        for function in m.functions:
            r = FunctionResult(m.name, function,
                               header=header_count(
                                   m.headers["double"].read_text(encoding="utf-8"), function),
                               floor=unit_row_floor(catalog.load(m.name), function))
            result.functions.append(r)
            by_key[(m.name, function)] = r
    sizes_of = {m.name: (m.n, m.nt) for m in models}
    tick("SymForce peer: the counting build")
    program, _, _ = _build(models, wrappers, workdir / "counting", "double", (), counting=True)
    parsed = parse_lines(_run([str(program), "out"]))
    for (model, function, impl), count in parsed["count"].items():
        by_key[(model, function)].counted[impl] = count
    for name, precision, flags in BUILDS:
        tick(f"SymForce peer: build {name}")
        folder = workdir / re.sub(r"\W+", "_", name)
        program, derive_objects, peer_objects = _build(models, wrappers, folder, precision,
                                                       flags)
        parsed = parse_lines(_run([str(program), "out"]))
        for (model, function), r in by_key.items():
            n, nt = sizes_of[model]
            d_status, d_values = parsed["out"][(model, function, "derive")]
            s_status, s_values = parsed["out"][(model, function, "symforce")]
            got_d, got_s = split_output(d_values, n, nt), split_output(s_values, n, nt)
            ref = next(m.expected[function] for m in models if m.name == model)
            if d_status:
                result.notes.append(f"{r.label} ({name}): derive's function returned status "
                                    f"{d_status}")
            r.agreement[name] = (agreement(got_d, ref), agreement(got_s, ref),
                                 agreement(got_d, got_s))
        tick(f"SymForce peer: timing {name}")
        parsed = parse_lines(_run([str(program), "time", str(calls), str(repeats)]))
        for key, times in parsed["time"].items():
            by_key[key].times[name] = times
        derive_syms = {model: read_symbols("nm", obj) for model, obj in derive_objects.items()}
        for (model, function), r in by_key.items():
            prefix = next(m.prefix for m in models if m.name == model)
            r.x86_bytes[name] = (code_bytes(derive_syms[model], f"{prefix}_{function}"),
                                 code_bytes(read_symbols("nm", peer_objects[(model, function)]),
                                            None))
        if name == SIZE_BUILD:
            result.notes.append(f"L1i of this machine: {l1i_size()} (cachegrind simulates "
                                "the host's cache geometry)")
            if shutil.which("valgrind") is None:
                result.notes.append("L1i misses not measured: valgrind is not installed")
            else:
                tick("SymForce peer: cachegrind")
                jobs = [(program, model, function, impl) for (model, function) in by_key
                        for impl in ("derive", "symforce")]
                with _pool() as pool:
                    misses = dict(zip(jobs, pool.map(lambda job: _l1i(*job), jobs)))
                for key, r in by_key.items():
                    r.l1i_misses = (misses[(program, *key, "derive")],
                                    misses[(program, *key, "symforce")])
    tick("SymForce peer: Cortex-M4F sizes")
    try:
        for key, levels in _m4f_sizes(models, wrappers, workdir / "m4f").items():
            by_key[key].m4f_bytes = levels
    except (FileNotFoundError, RuntimeError) as exc:  # no cross C++ or its headers
        result.notes.append(f"Cortex-M4F sizes not measured: {str(exc).splitlines()[0]} "
                            "(Debian: gcc-arm-none-eabi libstdc++-arm-none-eabi-dev)")
    return result


def unit_row_floor(model, function: str) -> int | None:
    """The fewest flops under the counter of any code computing ``function``, an update of
    one measurement ``h = ±x_j`` of a model whose P is dense (None for any other function):
    with N = n - 1 states besides j (docs/performance.md, "The floor of a unit-row update"),
    N (N + 1) for the entries P[a][b] - P[a][j] P[b][j] / s off row j (an fma, or a
    product and a sum, each its own), n for row j (P[b][j] R / s, one operation each), N
    for a factor of each diagonal's P[a][j]^2 / s, 2 n for x, 2 for s = P[j][j] + R and
    nu, and 3 g for each unit-norm group of g states (its g squares and g - 1 sums, a
    square root and g scalings)."""
    sensor = next((g for g in model.sensors if program_name(g.name) == function), None)
    if sensor is None or sensor.h is None or len(sensor.measurements) != 1:
        return None
    h = model.subs(sensor.h)[0]
    states = list(model.state_symbols)
    if not (h in states or -h in states) or model.subs(sensor.R)[0, 0].free_symbols:
        return None
    n = model.n
    groups = sum(3 * len(group) for group in model.unit_norm)
    return (n - 1) * n + n + (n - 1) + 2 * n + 2 + groups


def header_count(text: str, function: str) -> OpCount | None:
    """The count of ``function`` in derive's generated header ``text`` (None: none)."""
    line = re.search(rf"operations per call of {function} \(C99[^)]*\): ([^\n]*) \(flops",
                     text)
    if line is None:
        return None
    fields = dict((k, int(v)) for v, k in (part.strip().split(" ")[::-1]
                                             for part in line.group(1).split(",")))
    return OpCount(**fields)
