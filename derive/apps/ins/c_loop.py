"""C loops that call one filter function many times (predict, or an update), for per-call
timings free of the Python call's overhead: derive's generated C and CasADi's C.

Each loop starts from (x0, P0) and feeds every call's (x_new, P_new) to the next through
two buffers, the other inputs (u or z, p) fixed; ``NAME_result`` gives the last output.
The library is built with gcc and loaded with cffi (ABI mode).
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from derive.interface import Function

N = 16

_LOOP = """\
static double {name}_x[2][{n}], {name}_P[2][{n} * {n}];
void {name}_result(long calls, double *x, double *P)
{{
    memcpy(x, {name}_x[calls & 1], sizeof {name}_x[0]);
    memcpy(P, {name}_P[calls & 1], sizeof {name}_P[0]);
}}
int {name}(long calls, const double *x0, const double *P0, const double *arg, const double *p)
{{
    long k;
{declarations}    memcpy({name}_x[0], x0, sizeof {name}_x[0]);
    memcpy({name}_P[0], P0, sizeof {name}_P[0]);
    for (k = 0; k < calls; ++k) {{
        const double *x = {name}_x[k & 1], *P = {name}_P[k & 1];
        double *x_new = {name}_x[(k + 1) & 1], *P_new = {name}_P[(k + 1) & 1];
{call}
    }}
    (void)arg; (void)p;
    return 0;
}}
"""


@dataclass(frozen=True)
class Loop:
    """A loop named ``name`` and the C statements of one call inside it (they see x, P,
    x_new, P_new, arg and p)."""

    name: str
    call: str
    declarations: str = ""


def derive_call(function: Function, loop: str) -> Loop:
    """The loop of one generated derive function: x, P, x_new, P_new by name; its u or z
    is ``arg``; p is ``p``; other outputs (an update's NIS, say) go to a scratch array."""
    args, scratch = [], 0
    for a in function.arguments:
        if a.name in ("x", "P", "x_new", "P_new", "p"):
            args.append(a.name)
        elif a.name in ("u", "z") and not a.output:
            args.append("arg")
        elif a.output:
            args.append(f"{loop}_scratch + {scratch}")
            scratch += a.size()
        else:
            raise ValueError(f"{function.name} takes {a.name!r}, which the loop cannot give")
    call = f"{function.name}({', '.join(args)})"
    text = f"        if ({call}) return 1;" if function.returns_status else f"        {call};"
    declarations = f"    static double {loop}_scratch[{scratch}];\n" if scratch else ""
    return Loop(loop, text, declarations)


def casadi_call(name: str, function, loop: str) -> Loop:
    """The loop of one CasADi function with inputs (x, P, u or z[, dt]) and outputs
    (x_new, P_new): dt comes from p[0]."""
    inputs = ["x", "P", "arg", "p"][:function.n_in()]
    declarations = (f"    static casadi_int iw[{function.sz_iw()} + 1];\n"
                    f"    static double w[{function.sz_w()} + 1];\n"
                    f"    const double *a[{function.sz_arg()} + 1];\n"
                    f"    double *r[{function.sz_res()} + 1];\n")
    call = "".join(f"        a[{i}] = {v};\n" for i, v in enumerate(inputs))
    call += "        r[0] = x_new; r[1] = P_new;\n"
    call += f"        if ({name}(a, r, iw, w, 0)) return 1;"
    return Loop(loop, call, declarations)


class Loops:
    """The built library: ``run(name, calls, x0, P0, arg, p)`` and ``result(calls)``."""

    def __init__(self, library: Path, loops: Sequence[Loop]):
        import cffi  # C builds load cffi only when something is compiled

        self.ffi = cffi.FFI()
        self.ffi.cdef("\n".join(
            f"int {lp.name}(long calls, const double *x0, const double *P0, "
            f"const double *arg, const double *p);\n"
            f"void {lp.name}_result(long calls, double *x, double *P);" for lp in loops))
        self.lib = self.ffi.dlopen(str(library))

    def runner(self, name: str, x0, P0, arg, p):
        """A callable ``run(calls)`` returning the last (x, P)."""
        buffers = [np.ascontiguousarray(v, dtype=float) for v in (x0, P0, arg, p)]
        pointers = [self.ffi.from_buffer("double[]", b) for b in buffers]
        loop, result = getattr(self.lib, name), getattr(self.lib, f"{name}_result")
        x_out, P_out = np.empty(N), np.empty((N, N))

        def run(calls: int):
            if loop(calls, *pointers):
                raise ArithmeticError(f"{name}: a call returned a failure status")
            result(calls, self.ffi.from_buffer("double[]", x_out),
                   self.ffi.from_buffer("double[]", P_out))
            return x_out.copy(), P_out.copy()
        return run


def build(folder: Path, headers: Sequence[str], sources: Sequence[Path], loops: Sequence[Loop],
          cflags: Sequence[str]) -> Loops:
    """Write the loops' C file (including ``headers``), compile it with ``sources`` and load
    it."""
    folder.mkdir(parents=True, exist_ok=True)
    text = "#include <string.h>\n" + "".join(f'#include "{h}"\n' for h in headers)
    text += "".join(_LOOP.format(name=lp.name, n=N, call=lp.call, declarations=lp.declarations)
                    for lp in loops)
    driver = folder / "loops.c"
    driver.write_text(text, encoding="utf-8")
    library = folder / "libloops.so"
    cmd = ["gcc", *cflags, "-shared", "-fPIC", "-I", str(folder), "-o", str(library),
           *(str(s) for s in sources), str(driver), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"gcc failed on the timing loops: {proc.stderr.strip()[-500:]}")
    return Loops(library, loops)
