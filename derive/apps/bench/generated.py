"""derive's generated filters for the benchmark: the C through cffi (the run loop in C,
compiled with :data:`CFLAGS` on top of derive.build's strict flags) and the Python."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...pipeline import Generated, load_generated
from .cases import Case, Data, Skip, per_copy

CFLAGS = ("-O3", "-march=native")
"""Added to derive.build.STRICT_CFLAGS for the benchmark builds (the later -O3 wins).
Contraction stays off as ISO C has it: the generated code fuses a*b + c itself
(``DERIVE_FMA``), so the operations executed are those the header counts."""


def load(case: Case, workdir: Path, lang: str = "all", options=None) -> Generated:
    """Generate the case's filter (with ``options``) into ``workdir/generated`` and load
    it (the C compiled with :data:`CFLAGS`)."""
    out = workdir / ("generated" if not options else "generated-" + "-".join(sorted(options)))
    return load_generated(case.model, case.filter, dict(options or {}), lang, out,
                          out_label="bench", extra_cflags=CFLAGS)


def python_runner(module, case: Case, data: Data):
    if case.nonlinear:
        return lambda steps: module.run(data.zs[0][:steps], data.us[:steps], data.x0,
                                        data.P0)[0]
    if case.filter == "kf":
        return lambda steps: per_copy(lambda z: module.run(z, data.x0, data.P0)[0], data,
                                      steps)
    return lambda steps: per_copy(lambda z: module.run(z, data.x0), data, steps)


def _c_runner(filter_module, data: Data):
    """Call ``PREFIX_run`` directly with buffers allocated once: the steps argument, the
    inputs by name (z, u, x0, P0) and the outputs (xs; optional ones NULL)."""
    ffi, lib = filter_module.ffi, filter_module.lib
    fn = filter_module.functions["run"]
    n = len(data.x0)
    outputs = [np.empty((data.steps, n)) for _ in data.zs]
    fixed = {"x0": np.ascontiguousarray(data.x0, dtype=float),
             "P0": np.ascontiguousarray(data.P0, dtype=float)}
    if data.us is not None:
        fixed["u"] = np.ascontiguousarray(data.us)
    calls = []
    for z, out in zip(data.zs, outputs):
        inputs = {**fixed, "z": z}
        args = []
        for arg in fn.arguments:
            if arg.output:
                args.append(ffi.NULL if arg.optional else ffi.from_buffer("double[]", out))
            elif arg.name in inputs:
                args.append(ffi.from_buffer("double[]", inputs[arg.name]))
            else:
                raise Skip(f"the generated run takes an argument {arg.name!r} the bench "
                           "does not provide")
        calls.append(args)
    run_c = getattr(lib, fn.name)

    def run(steps):
        for args in calls:
            if run_c(steps, *args):
                raise ArithmeticError(f"{fn.name} failed")
        return outputs
    return run


def generated_c(case: Case, data: Data, workdir: Path):
    return _c_runner(load(case, workdir, "c").c, data)


def generated_python(case: Case, data: Data, workdir: Path):
    return python_runner(load(case, workdir, "python").python, case, data)


def generated_c_latency_schedule(case: Case, data: Data, workdir: Path):
    """The generated C in the latency schedule (``--latency-schedule``)."""
    return _c_runner(load(case, workdir, "c", {"latency_schedule": True}).c, data)
