"""Time per step of the generated GNSS EKF/UKF in C (the run loop in C, through cffi)
against FilterPy's EKF and UKF on the same scenario. A benchmark, not a test:

    python benchmarks/gnss_ekf.py [--steps 200000] [--native]

--native compiles with -O2 -march=native (fma in hardware); the default is the strict
portable flags of derive.build. Prints ns per step and the generated step's op count.
"""

from __future__ import annotations

import argparse
import tempfile
import time

from derive import catalog
from derive.apps.simulate import gnss_scenario, pseudorange, pseudorange_jacobian
from derive.filters import derive_unit
from derive.flops import count
from derive.pipeline import load_units


def best_of(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def generated(unit, cflags, workdir: str):
    return load_units([unit], "c", workdir, extra_cflags=cflags)[0].c


def filterpy_ekf(sc, steps: int) -> float:
    from filterpy.kalman import ExtendedKalmanFilter

    kf = ExtendedKalmanFilter(4, 4)
    kf.x, kf.P, kf.Q, kf.R = sc.x0.copy(), sc.P0.copy(), sc.Q, sc.R
    sats, zs = sc.satellites, sc.pseudoranges

    def loop():
        for k in range(steps):
            kf.predict()
            kf.update(zs[k], pseudorange_jacobian, pseudorange, args=(sats[k],),
                      hx_args=(sats[k],))
    return best_of(loop, 3) / steps


def filterpy_ukf(sc, steps: int) -> float:
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    points = MerweScaledSigmaPoints(4, alpha=1.0, beta=0.0, kappa=-1.0)
    kf = UnscentedKalmanFilter(4, 4, 1.0, pseudorange, lambda x, dt: x, points)
    kf.x, kf.P, kf.Q, kf.R = sc.x0.copy(), sc.P0.copy(), sc.Q, sc.R
    sats, zs = sc.satellites, sc.pseudoranges

    def loop():
        for k in range(steps):
            kf.predict()
            kf.update(zs[k], sats=sats[k])
    return best_of(loop, 3) / steps


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--native", action="store_true")
    args = parser.parse_args(argv)
    model = catalog.load("gnss_pseudorange")
    cflags = ("-march=native",) if args.native else ()
    sc = gnss_scenario(args.steps, seed=3, moving=True)
    zs, us = sc.pseudoranges, sc.satellites.reshape(args.steps, 12)
    print(f"GNSS model, 4 satellites, {args.steps} steps; C flags: strict"
          + (" + -march=native" if args.native else ""))
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("ekf", "ukf"):
            unit = derive_unit(model, name, {})
            ops = count(unit.programs["step"], "c").summary()
            module = generated(unit, cflags, tmp)
            seconds = best_of(lambda m=module: m.run(zs, us, sc.x0, sc.P0, with_covariance=False))
            print(f"generated C {name} step: {seconds / args.steps * 1e9:8.1f} ns/step  ({ops})")
    few = min(args.steps, 2000)
    print(f"FilterPy EKF predict+update:  {filterpy_ekf(sc, few) * 1e9:8.0f} ns/step")
    print(f"FilterPy UKF predict+update:  {filterpy_ukf(sc, few) * 1e9:8.0f} ns/step")


if __name__ == "__main__":
    main()
