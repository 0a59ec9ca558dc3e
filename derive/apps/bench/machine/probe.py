"""Operation latencies of this machine, measured: a chain of dependent operations per
kind, compiled with the benchmark's flags, timed over many iterations.

Each probe is a loop ``a = OP(a, b)``: every iteration waits for the previous one, and
without -ffast-math the compiler may not reassociate the chain, so the time per
iteration is the operation's latency (the loop counter runs alongside).  Together with
:func:`derive.apps.latency.carried_bound` this gives the latency bound of a generated run
loop on this machine, in seconds.
"""

from __future__ import annotations

import time

from .c_kernels import compiled_kernels

#: kind -> (C statement on double a and b, iterations per timing)
PROBES = {
    "add": ("a = a + b;", 4_000_000),
    "mul": ("a = a * b;", 4_000_000),
    "fma": ("a = fma(a, b, c);", 4_000_000),
    "div": ("a = b / a;", 1_000_000),
    "sqrt": ("a = sqrt(a) + c;", 1_000_000),
}
#: sqrt's probe includes one add; subtracted after measuring.
_INCLUDES_ADD = ("sqrt",)

_SOURCE = """#include <math.h>
{functions}
"""
_FUNCTION = """double derive_probe_{kind}(long n, double a, double b, double c)
{{
    long i;
    for (i = 0; i < n; ++i) {{
        {statement}
    }}
    (void)b;
    (void)c;
    return a;
}}
"""


def _module(cflags: tuple[str, ...]):
    source = _SOURCE.format(functions="\n".join(
        _FUNCTION.format(kind=k, statement=s) for k, (s, _) in PROBES.items()))
    # the cffi wrapper around the probes is not ISO C
    return compiled_kernels("probe", source, "".join(
        f"double derive_probe_{k}(long n, double a, double b, double c);\n" for k in PROBES),
        ["-std=c99", *cflags])


#: Each repeat's iterations are timed in this many windows, the kinds taking turns in
#: each: under a load average of 6.5 on the 2 cores, whole repeats (a few ms each) read
#: fma 1.86 and div 7.61 ns at their fastest, windows of a fiftieth 1.0 and 3.3 ns, the
#: figures of a quiet moment.
WINDOWS = 50


def measure_latencies(cflags: tuple[str, ...], repeats: int = 7,
                      scale: float = 1.0) -> dict[str, float]:
    """Seconds per dependent operation, per kind (the minimum over ``repeats`` times
    :data:`WINDOWS` short windows).

    The kinds take turns within each window, so that a moment of load on a shared
    machine slows every kind's probe alike rather than one kind's: the ratios between
    kinds, which the chain bounds of two schedules compare, come from the same moments;
    and a short window is likelier than a long one to fall between the other jobs' turns,
    so the least is the operation's latency, not the load's."""
    lib = _module(cflags)
    probes = {kind: (getattr(lib, f"derive_probe_{kind}"),
                     max(1, int(iterations * scale) // WINDOWS))
              for kind, (_, iterations) in PROBES.items()}
    for fn, n in probes.values():
        fn(n + 1, 1.0, 0.999999, 1e-9)                # warm up
    best = dict.fromkeys(probes, float("inf"))
    for _ in range(repeats * WINDOWS):
        for kind, (fn, n) in probes.items():
            start = time.perf_counter()
            fn(n, 1.0, 0.999999, 1e-9)
            best[kind] = min(best[kind], (time.perf_counter() - start) / n)
    seconds = dict(best)
    for kind in _INCLUDES_ADD:
        seconds[kind] = max(seconds[kind] - seconds["add"], 0.0)
    return seconds
