"""FIR steady-state filter (GSM2D §7): x(k/k) = sum_{i<N} A^i B z(k-i).

N is the smallest order with ||A^N||_2 < eps (spectral norm; option ``eps``, default
1e-6), or the option ``order`` directly. The order is bounded by what the generated code
can bear (derive.horizon.max_fir_order: N m <= 256 and N n m <= 2048); a larger one is
refused naming the order that would be needed, found without building it. The taps
A^i B are computed offline; the generated step reads a window of the last N
measurements, newest first.
"""

from __future__ import annotations

import sympy

from .. import horizon
from .. import reference as numpy_reference
from ..errors import OptionError, SteadyStateError
from ..horizon import MAX_FIR_TAPS, MAX_FIR_WINDOW, FirOrderError, max_fir_order
from ..options import DEFAULT_EPS, FirOptions
from ..program import Port, Program
from .spec import FilterSpec
from .steady import exact, steady_gains
from .unit import make_unit


def _bound_words(model, bound: int) -> str:
    return (f"the largest order generated for {model.name!r} (n = {model.n}, m = {model.m}) "
            f"is {bound}, from N m <= {MAX_FIR_WINDOW} and N n m <= {MAX_FIR_TAPS}")


def order(model, options: FirOptions) -> int:
    """The FIR order for ``model``: the option ``order``, or the least N with
    ||A^N||_2 < eps; either within :func:`derive.horizon.max_fir_order`."""
    bound = max_fir_order(model.n, model.m)
    if options.order is not None:
        if options.eps != DEFAULT_EPS:
            raise OptionError("options 'eps' (--eps) and 'order' (--order) of fir exclude "
                              "each other: the order is given, or found from eps")
        if options.order > bound:
            raise OptionError(f"option 'order' (--order) is {options.order}, but "
                              f"{_bound_words(model, bound)}")
        return options.order
    A, _ = steady_gains(model, "sskf")
    try:
        return horizon.fir_order(A, options.eps, max_order=bound)
    except FirOrderError as exc:
        needed = (f"order N = {exc.needed}" if exc.needed is not None else
                  "an order beyond 2^64")
        raise SteadyStateError(
            f"FIR: ||A^N||_2 < {options.eps!r} would need {needed}, but "
            f"{_bound_words(model, bound)}; give a larger --eps (option eps) or an --order "
            f"up to {bound}, or use sskf") from None


def derive_unit(model, spec, options: FirOptions):
    A, B = steady_gains(model, "sskf")
    N = order(model, options)
    taps = horizon.fir_taps(A, B, N)
    n, m = model.n, model.m
    prog = Program("step", [Port("zw", (N, m), doc="z(k), z(k-1), ..., z(k-N+1), row-major")],
                   [Port("x_new", (n,), doc="x(k/k)")], doc=f"{spec.title}, N = {N}")
    # each output is built as one sum (adding term by term re-sorts the growing sum)
    prog.set_output("x_new", [sympy.Add(*(exact(taps[i, r, j]) * prog.element("zw", i, j)
                                          for i in range(N) for j in range(m)
                                          if taps[i, r, j] != 0))
                              for r in range(n)])
    constants = {"N": N} if options.order is not None else {"N": N, "eps": options.eps}
    return make_unit(model, spec, {"step": prog.optimize()}, options, window=N,
                     constants=constants)


def reference(model, zs, options):
    """derive.reference.fir of the order the options give: (xs, None)."""
    num = model.numeric()
    return numpy_reference.fir(num.F, num.G, num.H, num.Q, num.R, zs,
                               N=order(model, options)), None


SPECS = (FilterSpec(
    "fir", "steady-state FIR filter", "linear", "windowed", derive_unit, reference,
    options=FirOptions, steady=True, listing=80, check=order,
    about={"python": "Run the steady-state FIR filter: each estimate from the last {window} "
                     "measurements."
                     "\n\n    Measurements before the first are taken as zero.",
           "c": "Run the steady-state FIR filter: each estimate from the last {window} "
                "measurements, newest first; measurements before the first are zero."}),)
