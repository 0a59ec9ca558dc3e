"""FIR steady-state filter (GSM2D §7): x(k/k) = sum_{i<N} A^i B z(k-i).

N is the smallest order with ||A^N||_2 < eps (spectral norm; option ``eps``,
default 1e-6, or ``N`` directly). The taps A^i B are computed offline; the
generated step reads a window of the last N measurements, newest first.
"""

from __future__ import annotations

import sympy

from .. import riccati
from ..errors import SteadyStateError
from ..program import Port, Program
from .steady import baked, steady_gains

DEFAULT_EPS = 1e-6


def order(model, options) -> int:
    A, _ = steady_gains(model, "sskf")
    if options.get("N") is not None:
        N = options["N"]
        if not isinstance(N, int) or isinstance(N, bool) or N < 1:
            raise SteadyStateError(f"FIR order N must be a positive integer, got {N!r}")
        return N
    return riccati.fir_order(A, options.get("eps", DEFAULT_EPS))


def derive_unit(model, name, options):
    from .unit import make_unit

    A, B = steady_gains(model, "sskf")
    N = order(model, options)
    taps = riccati.fir_taps(A, B, N)
    n, m = model.n, model.m
    prog = Program("step", [Port("zw", (N, m), doc="z(k), z(k-1), ..., z(k-N+1), row-major")],
                   [Port("x_new", (n,), doc="x(k/k)")], doc=f"FIR steady-state filter, N = {N}")
    zw = [sympy.Matrix([prog.element("zw", i, j) for j in range(m)]) for i in range(N)]
    total = sympy.zeros(n, 1)
    for i in range(N):
        total += baked(taps[i]) * zw[i]
    prog.set_output("x_new", [sympy.expand(e) for e in total])
    return make_unit(model, name, {"step": prog.optimize()}, {**options, "N": N},
                     constants={"N": N, "eps": options.get("eps", DEFAULT_EPS)})
