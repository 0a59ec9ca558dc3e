"""Stage 1 of the report: regenerate every catalog filter, compile and verify it.

For each catalog model every filter that applies is written to the generated directory
(``derive generate``), its C compiled through cffi (one extension per model) and its
Python imported; the experiments that follow run these modules. Each written filter is
verified against the NumPy reference with ``derive verify``'s scenario, reference,
tolerance and error measure (:func:`verify_built`, the comparison half of
:func:`derive.apps.verify.verify_filter`), and the papers' equivalence claims are measured
(``derive check``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ... import catalog
from ...filters import available
from ...generation import command_unit
from ...pipeline import load_units
from ..checks import run_checks
from ..verify import jacobian_witness, verify_modules
from .document import DIFFERS, MATCHED, Section, Table, Text, sci

VERIFY_STEPS = 1000   # derive verify's default
VERIFY_SEED = 7       # derive verify's default
QUICK_VERIFY_STEPS = 200


@dataclass
class GenerationResult:
    models: list[str] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    verifications: list = field(default_factory=list)   # derive.apps.verify.Verification
    checks: list = field(default_factory=list)          # derive.apps.checks.Check
    witnesses: list = field(default_factory=list)       # derive.apps.verify.JacobianWitness

    @property
    def filters(self) -> int:
        return len({(v.model, v.filter) for v in self.verifications})

    @property
    def failures(self) -> list[str]:
        return ([v.line() for v in self.verifications if not v.passed]
                + [w.line() for w in self.witnesses if w.check is not None and not w.passed]
                + [c.line() for c in self.checks if not c.passed])

    @property
    def max_error(self) -> float:
        return max((v.error for v in self.verifications), default=float("nan"))


def generate_model(ctx, name: str, result: GenerationResult) -> None:
    """Write, build and import every filter of catalog model ``name`` into ``ctx``.

    As ``derive generate NAME --out DIR``; in a scratch directory the files name
    ``generated`` as their output directory (a stable text, so the cffi build cache,
    keyed by the sources, is reused from one run to the next)."""
    model = catalog.load(name)
    label = str(ctx.generated) if ctx.label is None else ctx.label
    units = [command_unit(model, f, {}, name, label) for f in available(model)]
    for generated in load_units(units, "all", ctx.generated):
        key = (name, generated.unit.filter)
        ctx.c[key], ctx.python[key] = generated.c, generated.python
        ctx.sources[key] = generated.paths[".c"]
        result.files += sorted(generated.paths.values())
    result.models.append(name)


def verify_built(model, name: str, modules: dict, steps: int, seed: int) -> list:
    """derive verify's comparison for modules already built ({lang: module})."""
    return verify_modules(model, name, modules, steps, seed)


def verify_model(ctx, name: str, result: GenerationResult) -> None:
    """derive verify (on the files written and built) and derive check for ``name``."""
    model = catalog.load(name)
    steps = QUICK_VERIFY_STEPS if ctx.quick else VERIFY_STEPS
    for f in available(model):
        modules = {"python": ctx.py_filter(name, f), "c": ctx.c_filter(name, f)}
        result.verifications += verify_built(model, f, modules, steps, VERIFY_SEED)
    witness = jacobian_witness(model)
    if witness is not None:
        result.witnesses.append(witness)
    result.checks += run_checks(model)


def witness_verdict(witnesses: list) -> tuple[str, str] | None:
    """(verdict, evidence) of the CasADi Jacobian witnesses for the report's summary; None
    when none ran (casadi absent): the appendix table and the command's summary say why,
    and a skipped witness is no outcome of the papers' claims."""
    ran = [w for w in witnesses if w.check is not None]
    if not ran:
        return None
    failed = sum(not w.passed for w in ran)
    skipped = len(witnesses) - len(ran)
    return (DIFFERS if failed else MATCHED,
            f"{len(ran)} models, {failed} failed, {skipped} skipped, largest relative "
            f"difference {max(w.check.worst for w in ran):.1e}")


def section(result: GenerationResult) -> Section:
    s = Section("verification", "Appendix: generated filters verified, equivalence claims "
                "measured")
    failed_v = sum(not v.passed for v in result.verifications)
    s.outcome("every generated filter (Python and C) equals the NumPy reference written "
              "from the papers", DIFFERS if failed_v else MATCHED,
              f"{result.filters} filters of {len(result.models)} models, "
              f"{len(result.verifications)} runs, {failed_v} failed, largest relative error "
              f"{result.max_error:.1e}")
    verdict = witness_verdict(result.witnesses)
    if verdict is not None:
        s.outcome("every nonlinear model's sympy Jacobians equal CasADi's automatic "
                  "differentiation (an independent witness)", *verdict)
    failed_c = sum(not c.passed for c in result.checks)
    s.outcome("the papers' equivalence claims, on the reference filters (`derive check`)",
              DIFFERS if failed_c else MATCHED,
              f"{len(result.checks)} claims measured, {failed_c} failed")
    langs: dict[tuple[str, str], dict[str, object]] = {}
    for v in result.verifications:
        langs.setdefault((v.model, v.filter), {})[v.lang] = v
    rows = []
    for (model, f), by_lang in langs.items():
        py, c = by_lang.get("python"), by_lang.get("c")
        any_v = py or c
        ok = all(v.passed for v in by_lang.values())
        rows.append((model, f, str(any_v.steps), sci(py.error) if py else "–",
                     sci(c.error) if c else "–", f"{any_v.tolerance:.0e}",
                     "ok" if ok else "**FAIL**"))
    s.add(Text(f"{len(result.files)} files written for {result.filters} filters of "
               f"{len(result.models)} catalog models; each generated Python module and "
               "C file (built with `gcc -std=c99 -O2 -Wall -Wextra -Werror -pedantic` through "
               "cffi) was run on simulated data and compared with the NumPy reference "
               "written from the papers, exactly as `derive verify` does. Error: "
               "max over steps of ‖gen − ref‖∞ / max(‖ref‖∞, 1), for x and for P."),
          Table(("model", "filter", "steps", "Python max rel err", "C max rel err",
                 "tolerance", "status"), tuple(rows),
                "Generated code against the NumPy reference", collapsed=True))
    if result.witnesses:
        s.add(Text("The Jacobians of f and h that the EKF is generated from, against CasADi's "
                   "automatic differentiation of the same f and h at random points, as "
                   "`derive verify` prints them (skipped, with the reason, without the "
                   "`casadi` extra)."),
              Table(("model", "points", "max rel diff", "tolerance", "status"),
                    tuple((w.model, str(w.check.points) if w.check else "–",
                           sci(w.check.worst) if w.check else "–", f"{w.tolerance:.0e}",
                           "skipped: " + w.skipped if w.check is None
                           else "ok" if w.passed else "**FAIL**") for w in result.witnesses),
                    "Jacobians against CasADi", collapsed=True))
    s.add(Text("The papers' equivalence claims, measured on the reference filters over 500 "
               "simulated steps (seed 1), as `derive check` prints them; differences are "
               "relative to max(1, |reference|)."),
          Table(("model", "claim", "measure", "value", "tolerance", "status"),
                tuple((c.model, c.claim, c.measure, sci(c.value), f"{c.tolerance:.0e}",
                       "ok" if c.passed else "**FAIL**") for c in result.checks),
                "Equivalence checks (max differences)", collapsed=True))
    return s
