"""`derive verify MODEL [--filter F]`: generated Python and C against the reference.

Takes the filter options of `derive generate` (derive.options), each given to the filters
that take it."""

import math
import re

from . import add_filter_options

NAME = "verify"
ORDER = 45
HELP = ("generate, compile (cffi) and run each filter on simulated data; compare with the "
        "NumPy reference (max relative error <= 1e-12 for linear filters, or the double "
        "bound c u64 L G kappa where an ill-conditioned model puts that higher, printed on "
        "its line; for nonlinear ones "
        "1e-10, or 4 times the reference's own rounding floor where that is larger; with "
        "--precision float the C is float32, held to the tolerance c u32 L G kappa derived "
        "from its step and the model, printed on its line); check each nonlinear model's "
        "Jacobians against CasADi's automatic differentiation")
EXAMPLE = "derive verify mpt3d_a --filter kf\n  derive verify all"


def add_arguments(parser) -> None:
    parser.add_argument("model", help="catalog name, model-file path, or 'all'")
    parser.add_argument("--filter", action="append", dest="filters", metavar="F",
                        help="verify only this filter (repeatable; default: every filter "
                             "that applies to the model)")
    parser.add_argument("--steps", type=int, default=1000, help="steps simulated (1000)")
    parser.add_argument("--seed", type=int, default=7, help="simulation seed (7)")
    parser.add_argument("--values", action="append", default=[], metavar="NAME=V",
                        help="run free parameter NAME at V (repeatable); a parameter not "
                             "named runs at its example (dt = { example = 0.01 } in a "
                             "model file's [parameters])")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress lines (they are shown only when stderr is a "
                             "terminal)")
    add_filter_options(parser)


def run(args) -> int:
    from .. import catalog, progress
    from ..apps.verify import jacobian_witness, verify_filter
    from ..errors import VerificationError
    from ..filters import available, check_before_deriving, kind
    from ..filters.fir import order
    from ..options import from_arguments, per_filter
    from . import load_model

    options = from_arguments(args)
    values = parameter_values(args.values)
    refs = catalog.names() if args.model == "all" else [args.model]
    show_progress = not args.no_progress and progress.enabled()
    tally = {"passed": 0, "failed": 0, "skipped": 0}
    uncarried = 0   # failed because the precision cannot carry the model (bound >= 1)
    for number, ref in enumerate(refs, 1):
        model = load_model(ref)
        names = args.filters or available(model)
        for name in names:
            kind(name)
        typed = per_filter(names, options, named=bool(args.filters))
        check_before_deriving(model, names, typed, named=bool(args.filters))
        for name in names:
            if show_progress:
                progress.report(f"verify [{number}/{len(refs)}] {model.name}: {name}")
            if "order" in typed[name].specs():  # a FIR: the order its options give
                print(f"{model.name}/fir: order N = {order(model, typed[name])}")
            for v in verify_filter(model, name, steps=args.steps, seed=args.seed,
                                   options=typed[name], values=values):
                print(v.line(), flush=True)
                tally["passed" if v.passed else "failed"] += 1
                uncarried += v.bound is not None and not v.bound.meaningful
        witness = jacobian_witness(model)
        if witness is not None:
            print(witness.line(), flush=True)
            tally["skipped" if witness.check is None
                  else "passed" if witness.passed else "failed"] += 1
    print(summary_line(tally, len(refs)))
    if tally["failed"]:
        why = (f" ({uncarried} of them on a model their precision cannot carry: its rounding "
               f"bound is 1 or more)" if uncarried else "")
        raise VerificationError(f"{tally['failed']} generated filter(s) or Jacobian "
                                f"witness(es) disagree with the reference{why}")
    return 0


def parameter_values(items: list[str]) -> dict[str, float]:
    """``--values NAME=V`` as ``{NAME: V}``; OptionError (exit 2) for an item that is not
    a name, ``=`` and a finite number."""
    from ..errors import OptionError

    values: dict[str, float] = {}
    for item in items:
        name, _, text = item.partition("=")
        try:
            number = float(text)
        except ValueError:
            number = math.nan
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name) or not math.isfinite(number):
            raise OptionError(f"--values {item!r}: expected NAME=V, a parameter's name and a "
                              "finite number (e.g. --values dt=0.1)")
        values[name] = number
    return values


def summary_line(tally: dict[str, int], models: int) -> str:
    """The last line of ``derive verify``: how many comparisons passed, failed, skipped."""
    skipped = f", {tally['skipped']} skipped" if tally["skipped"] else ""
    return (f"derive verify: {tally['passed']} passed, {tally['failed']} failed{skipped} "
            f"({models} model{'s' if models != 1 else ''})")
