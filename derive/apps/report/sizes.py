"""Generated C on ARM: every catalog filter the report wrote, cross-compiled for Cortex-M4F
at -Os and -O2 (bytes per function read from the objects), and run under qemu-arm against
the NumPy reference (derive.apps.targets.arm). Without the cross tools the section says
which are missing and measures nothing."""

from __future__ import annotations

from ..targets.arm import SIZE_COLUMNS, file_sizes, run_under_qemu, size_rows, sizes
from ..targets.toolchains import TARGETS
from .document import DIFFERS, MATCHED, Section, Table, Text, sci

#: The models a quick report cross-compiles and runs (every model in the full one).
QUICK_MODELS = ("cv",)


def section(ctx) -> Section:
    s = Section("arm", "ARM: the generated C on Cortex-M4F and under qemu-arm")
    m4, linux = TARGETS["cortex-m4"], TARGETS["arm-linux"]
    missing = m4.missing() + linux.missing()
    if missing:
        s.add(Text(f"Not measured: {', '.join(missing)} not found on PATH (Debian packages "
                   "gcc-arm-none-eabi, libnewlib-arm-none-eabi, gcc-arm-linux-gnueabihf, "
                   "qemu-user)."))
        return s
    models = sorted({model for model, _ in ctx.sources})
    if ctx.quick:
        models = [m for m in models if m in QUICK_MODELS]
    rows = []
    for model in models:   # float32: what the FPU runs; generated here, as derive size does
        rows += sizes(model, sorted(n for m, n in ctx.sources if m == model),
                      {"precision": "float"})
    for (model, name), source in sorted(ctx.sources.items()):
        if model in models:
            rows += file_sizes(source, model, name, "double")
    which = ("every catalog model" if not ctx.quick else
             f"a quick run: the model(s) {', '.join(models)} only")
    s.add(Text(f"The generated C of each filter ({which}), in float32 (`--precision float`) and as "
               f"written above in double, compiled by `{m4.cc} {' '.join(m4.flags)}` with "
               f"the strict flags at -Os and -O2; bytes read from each object by `{m4.size}` "
               f"(text, data, bss) and `{m4.nm} --size-sort -S` (code per function, literal "
               "pools included). The FPU is single precision: double arithmetic is done in "
               "software, hence the larger double code."))
    s.add(Table(SIZE_COLUMNS, tuple(size_rows(rows)),
                "Cortex-M4F: code and data bytes of each generated filter", collapsed=True))
    runs = []
    for model in models:
        for precision in ("float", "double"):
            runs += run_under_qemu(model, sorted(n for m, n in ctx.sources if m == model),
                                   {"precision": precision})
    failed = [r for r in runs if not r.passed]
    worst = max((r.error / r.tolerance for r in runs), default=0.0)
    s.outcome("the generated C, float32 and double, runs on ARM (arm-linux-gnueabihf under "
              "qemu-arm) and agrees with the NumPy reference within derive verify's "
              "tolerance",
              MATCHED if runs and not failed else DIFFERS,
              f"{len(runs) - len(failed)} of {len(runs)} runs ({len(models)} model(s)) "
              f"within tolerance; largest error / tolerance {sci(worst)}"
              + "".join(f"; {r.model} {r.filter} {r.precision} failed" for r in failed))
    s.add(Table(("model", "filter", "precision", "steps", "max rel error", "tolerance",
                 "float32 bound c u32 L G kappa", "verdict"),
                tuple((r.model, r.filter, r.precision, str(r.steps), sci(r.error),
                       sci(r.tolerance), "–" if r.bound is None else r.bound.text(),
                       "ok" if r.passed else "**FAIL**") for r in runs),
                "qemu-arm: the states the ARM program printed against the NumPy reference"))
    return s
