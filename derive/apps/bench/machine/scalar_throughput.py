"""Scalar floating-point throughput of this machine, measured: how many independent scalar
multiply-adds, additions, and the two mixed, it retires per second, compiled with the
benchmark's flags. From it, the floor of a straight-line scalar function with a known
operation count: no scalar code of that count runs faster here.

Each kernel runs ``CHAINS`` independent chains per loop iteration (``a = fma(a, b, c)``
for the multiply pipes, ``s = s + c`` for the add pipes), enough of them to hide each
operation's latency, so the time per operation is the inverse of the pipes' throughput.
The kernels are compiled with ``-fno-tree-vectorize`` so that the chains stay scalar (the
generated code is scalar), and without -ffast-math the compiler may not merge the chains.

The floor of a count (:func:`floor_seconds`): a multiplication and an fma issue on the
multiply pipes, an addition and a subtraction on the add pipes, so the function needs at
least ``(mul + fma) x fma time``, ``(add + sub) x add time`` and ``(all four) x mixed
time`` — the largest of the three. Loads, stores, divisions and register moves come on
top; the floor leaves them out, so it is below any real scalar code's time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from ....trees import OpCount
from .c_kernels import compiled_kernels

#: independent chains per kernel: multiply pipes, add pipes (``mixed`` runs both sets)
CHAINS = {"fma": (12, 0), "add": (0, 12), "mixed": (8, 8)}
#: loop iterations per timing
ITERATIONS = 2_000_000
#: the chains' constants: b close to one and a small c keep every value normal
B, C = 0.999999, 1e-9

_FUNCTION = """double derive_throughput_{kind}(long n, double b, double c)
{{
    {declarations}
    long i;
    for (i = 0; i < n; ++i) {{
        {body}
    }}
    return {total};
}}
"""


def start_values(kind: str) -> tuple[list[float], list[float]]:
    """The starting values of a kernel's multiply chains and add chains."""
    multiplies, adds = CHAINS[kind]
    return [1.0 + i * 1e-3 for i in range(multiplies)], [float(i) for i in range(adds)]


def kernel_source(kind: str) -> str:
    """The C function ``derive_throughput_KIND(n, b, c)``: ``n`` iterations of the kernel's
    chains; it returns the sum of the chains' final values (multiply chains first)."""
    multiplies, adds = start_values(kind)
    names = [f"a{i}" for i in range(len(multiplies))] + [f"s{i}" for i in range(len(adds))]
    values = multiplies + adds
    declarations = "double " + ", ".join(f"{n} = {v!r}" for n, v in zip(names, values)) + ";"
    body = " ".join([f"a{i} = fma(a{i}, b, c);" for i in range(len(multiplies))]
                    + [f"s{i} = s{i} + c;" for i in range(len(adds))])
    return _FUNCTION.format(kind=kind, declarations=declarations, body=body,
                            total=" + ".join(names))


def _module(cflags: tuple[str, ...]):
    source = "#include <math.h>\n" + "\n".join(kernel_source(k) for k in CHAINS)
    # the cffi wrapper is not ISO C; the chains stay scalar like the generated code
    return compiled_kernels("throughput", source, "".join(
        f"double derive_throughput_{k}(long n, double b, double c);\n" for k in CHAINS),
        ["-std=c99", *cflags, "-fno-tree-vectorize"])


def kernels(cflags: tuple[str, ...]) -> dict:
    """kind -> the compiled kernel ``f(n, b, c)``."""
    lib = _module(cflags)
    return {kind: getattr(lib, f"derive_throughput_{kind}") for kind in CHAINS}


@dataclass(frozen=True)
class Throughput:
    """Seconds per scalar operation when many independent ones are in flight."""

    fma: float     # a multiply or an fma (the multiply pipes)
    add: float     # an addition or a subtraction (the add pipes)
    mixed: float   # either, the two kinds interleaved (all pipes)

    def per_ns(self, kind: str) -> float:
        """Operations of ``kind`` per nanosecond."""
        return 1e-9 / getattr(self, kind)

    def floor_seconds(self, count: OpCount) -> float:
        """The least time scalar code with ``count``'s operations takes here (see the
        module's text)."""
        multiplies, adds = count.mul + count.fma, count.add + count.sub
        return max(multiplies * self.fma, adds * self.add, (multiplies + adds) * self.mixed)

    def floor_text(self, count: OpCount) -> str:
        """The floor and the terms it comes from, in one line."""
        multiplies, adds = count.mul + count.fma, count.add + count.sub
        return (f"{self.floor_seconds(count) * 1e9:.0f} ns ({multiplies} mul+fma at "
                f"{self.per_ns('fma'):.2f}/ns, {adds} add+sub at {self.per_ns('add'):.2f}/ns, "
                f"both at {self.per_ns('mixed'):.2f}/ns)")


def measure_throughput(cflags: tuple[str, ...], repeats: int = 5,
                       scale: float = 1.0) -> Throughput:
    """The minimum over ``repeats`` of each kernel's seconds per operation; the kernels take
    turns within each repeat, so a moment of load slows them alike."""
    fns = kernels(cflags)
    n = max(1, int(ITERATIONS * scale))
    for fn in fns.values():
        fn(n // 10 + 1, B, C)        # warm up
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(max(1, repeats)):
        for kind, fn in fns.items():
            start = time.perf_counter()
            fn(n, B, C)
            operations = n * sum(CHAINS[kind])
            best[kind] = min(best[kind], (time.perf_counter() - start) / operations)
    return Throughput(**best)
