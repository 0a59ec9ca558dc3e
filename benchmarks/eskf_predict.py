"""Time per call of the error-state predict (``eskf``) of ins_eskf and ins_fc24_eskf
against SymForce's tangent-space version of the same function (derive.apps.ins.symforce_eskf:
the attitude a ``sf.Rot3``, F and Fu its tangent Jacobians). A benchmark, not a test:

    python benchmarks/eskf_predict.py [--model ins_fc24_eskf] [--calls 200] [--repeats 400]

The method and the bars of ``derive bench``'s SymForce peer (derive.apps.bench.peers.symforce_peer):
the same GCC, its four builds (double and float, -O2 and -O2 -march=native) and their bars,
derive's C function and an extern "C" wrapper of SymForce's template, each in its own
translation unit (non-inline calls), called interleaved on the same inputs; per call the
minimum over the repeats of the thread's CPU time. SymForce's header is compiled against
the peer's Eigen shim and a Rot3 of four stored numbers (x, y, z, w: what its generated
code reads and writes); the wrapper moves the quaternion between derive's (w, x, y, z)
rows and that storage. Each build first checks that both give the same x_new and P_new.
The inputs: the state, covariance and IMU sample of step 500 of `derive verify`'s run.
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from derive import catalog
from derive.apps.bench.peers.symforce_peer import BUILDS, EIGEN_SHIM, TIME_BARS, compiler_version
from derive.apps.ins import symforce_eskf
from derive.apps.verify import sensors_case
from derive.generation import generate_units
from derive.manifolds import QUATERNION
from derive.options import validate

ROT3 = """\
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

WRAPPER = """\
#include "sf_predict.h"
typedef REAL real;
extern "C" int sf_predict(const real* x, const real* P, const real* u, real* x_new,
                          real* P_new, const real* p) {{
  Eigen::Matrix<real, 4, 1> q;
  q[0] = x[{q1}]; q[1] = x[{q2}]; q[2] = x[{q3}]; q[3] = x[{q0}];
  real rest[{n_rest}], rest_new[{n_rest}];
  static const int REST[{n_rest}] = {{{rest}}};
  for (int i = 0; i < {n_rest}; ++i) rest[i] = x[REST[i]];
  sym::Rot3<real> R(q), R_new;
  sym::Predict<real>(R, *reinterpret_cast<const Eigen::Matrix<real, {n_rest}, 1>*>(rest),
      *reinterpret_cast<const Eigen::Matrix<real, {nt}, {nt}>*>(P),
      *reinterpret_cast<const Eigen::Matrix<real, {m}, 1>*>(u), p[0], &R_new,
      reinterpret_cast<Eigen::Matrix<real, {n_rest}, 1>*>(rest_new),
      reinterpret_cast<Eigen::Matrix<real, {nt}, {nt}>*>(P_new));
  const Eigen::Matrix<real, 4, 1>& d = R_new.Data();
  x_new[{q0}] = d[3]; x_new[{q1}] = d[0]; x_new[{q2}] = d[1]; x_new[{q3}] = d[2];
  for (int i = 0; i < {n_rest}; ++i) x_new[REST[i]] = rest_new[i];
  return 0;
}}
"""

MAIN = """\
#include <cmath>
#include <cstdio>
#include <ctime>
typedef REAL real;
typedef int (*Call)(const real*, const real*, const real*, real*, real*, const real*);
extern "C" int {prefix}_predict(const real*, const real*, const real*, real*, real*,
                                const real*);
extern "C" int sf_predict(const real*, const real*, const real*, real*, real*, const real*);
static const double DX[{n}] = {x};
static const double DP[{nt} * {nt}] = {P};
static const double DU[{m}] = {u};
alignas(64) static real X[{n}], P[{nt} * {nt}], U[{m}], PAR[1];
alignas(64) static real XD[{n}], PD[{nt} * {nt}], XS[{n}], PS[{nt} * {nt}];
static double now() {{
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}}
static double timed(Call f, real* x_new, real* P_new, int calls) {{
  double start = now();
  for (int i = 0; i < calls; ++i) {{
    f(X, P, U, x_new, P_new, PAR);
    __asm__ volatile("" ::: "memory");
  }}
  return (now() - start) / calls;
}}
int main() {{
  for (int i = 0; i < {n}; ++i) X[i] = (real)DX[i];
  for (int i = 0; i < {nt} * {nt}; ++i) P[i] = (real)DP[i];
  for (int i = 0; i < {m}; ++i) U[i] = (real)DU[i];
  PAR[0] = (real){dt};
  {prefix}_predict(X, P, U, XD, PD, PAR);
  sf_predict(X, P, U, XS, PS, PAR);
  double dx = 0, sx = 0, dp = 0, sp = 0;
  for (int i = 0; i < {n}; ++i) {{
    dx = fmax(dx, fabs((double)XD[i] - XS[i])); sx = fmax(sx, fabs((double)XD[i]));
  }}
  for (int i = 0; i < {nt}; ++i)
    for (int j = i; j < {nt}; ++j) {{  /* both write the whole P; compare the triangle */
      dp = fmax(dp, fabs((double)PD[i * {nt} + j] - PS[i * {nt} + j]));
      sp = fmax(sp, fabs((double)PD[i * {nt} + j]));
    }}
  double best_d = 1e30, best_s = 1e30;
  for (int r = 0; r < {repeats}; ++r) {{
    double d = timed({prefix}_predict, XD, PD, {calls});
    double s = timed(sf_predict, XS, PS, {calls});
    if (d < best_d) best_d = d;
    if (s < best_s) best_s = s;
  }}
  printf("%.3e %.3e %.6e %.6e\\n", dx / sx, dp / sp, best_d, best_s);
  return 0;
}}
"""


def literal(values) -> str:
    return "{" + ", ".join(repr(float(v)) for v in np.ravel(values)) + "}"


def sources(model_name: str, folder: Path, calls: int, repeats: int) -> str:
    """Write SymForce's header, the shims, the wrapper and the main program into
    ``folder``; derive's C in folder/double and folder/float. Returns derive's prefix."""
    model = catalog.load(model_name)
    (quaternion,) = [m for m in model.manifolds if m.kind == QUATERNION]
    q = [model.states.index(s) for s in quaternion.states]
    rest = [i for i in range(model.n) if i not in q]
    case = sensors_case(model, "eskf", 600, 7, validate("eskf", {}), float_c=False)
    step = case.trace[500]
    (folder / "Eigen").mkdir(parents=True, exist_ok=True)
    (folder / "sym").mkdir(exist_ok=True)
    (folder / "Eigen" / "Core").write_text(EIGEN_SHIM.replace(
        "  const Scalar& operator()(long i, long j) const { return m[i + j * Rows]; }\n",
        "  const Scalar& operator()(long i, long j) const { return m[i + j * Rows]; }\n"
        "  Scalar& operator[](long i) { return m[i]; }\n"
        "  const Scalar& operator[](long i) const { return m[i]; }\n"))
    (folder / "sym" / "rot3.h").write_text(ROT3)
    (folder / "sf_predict.h").write_text(symforce_eskf.generate(model_name).source)
    sizes = dict(n=model.n, nt=model.n_tangent, m=len(model.f_inputs))
    (folder / "sf_wrap.cpp").write_text(WRAPPER.format(
        q0=q[0], q1=q[1], q2=q[2], q3=q[3], n_rest=len(rest), rest=", ".join(map(str, rest)),
        **{k: v for k, v in sizes.items() if k != "n"}))
    prefix = f"{model_name}_eskf"
    (folder / "main.cpp").write_text(MAIN.format(
        prefix=prefix, x=literal(step.x_before), P=literal(step.P_before), u=literal(step.u),
        dt=repr(float(step.p[0])), calls=calls, repeats=repeats, **sizes))
    for precision in ("double", "float"):
        generate_units(model_name, ["eskf"], "c", folder / precision, {"precision": precision})
    return prefix


def build(folder: Path, model_name: str, precision: str, flags: tuple[str, ...]) -> Path:
    out = folder / f"build-{precision}-{'-'.join(f.strip('-') for f in flags)}"
    out.mkdir(exist_ok=True)
    real = ("-DREAL=" + precision,)
    steps = [["gcc", "-std=c99", *flags, "-c", str(folder / precision / model_name / "eskf.c"),
              "-o", str(out / "eskf.o")],
             ["g++", "-std=c++17", *flags, *real, "-I", str(folder), "-c",
              str(folder / "sf_wrap.cpp"), "-o", str(out / "sf.o")],
             ["g++", "-std=c++17", *flags, *real, "-c", str(folder / "main.cpp"), "-o",
              str(out / "main.o")],
             ["g++", str(out / "main.o"), str(out / "eskf.o"), str(out / "sf.o"), "-lm", "-o",
              str(out / "program")]]
    for command in steps:
        subprocess.run(command, check=True, timeout=900)
    return out / "program"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="ins_fc24_eskf", choices=["ins_eskf", "ins_fc24_eskf"])
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=400)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="derive-eskf-") as tmp:
        folder = Path(tmp)
        sources(args.model, folder, args.calls, args.repeats)
        print(f"{args.model} eskf predict against SymForce (Rot3), {compiler_version()}")
        for name, precision, flags in BUILDS:
            program = build(folder, args.model, precision, flags)
            dx, dp, d, s = (float(v) for v in subprocess.run(
                [str(program)], check=True, capture_output=True, text=True,
                timeout=900).stdout.split())
            ratio, bar = d / s, TIME_BARS[name]
            verdict = "met" if ratio <= bar else "NOT met"
            print(f"  {name:26s} derive {d * 1e9:7.1f} ns  SymForce {s * 1e9:7.1f} ns  "
                  f"{ratio:.2f} (bar {bar}: {verdict}); outputs agree to x {dx:.1e}, P {dp:.1e}")


if __name__ == "__main__":
    main()
