"""`derive verify MODEL [--filter F]`: generated Python and C against the reference.

Takes the filter options of `derive generate` (derive.options), each given to the filters
that take it."""

from ..options import add_arguments as add_option_arguments

NAME = "verify"
ORDER = 45
HELP = ("generate, compile (cffi) and run each filter on simulated data; compare with the "
        "NumPy reference (max relative error <= 1e-12)")
EXAMPLE = "derive verify mpt3d_a --filter kf\n  derive verify all"


def add_arguments(parser) -> None:
    parser.add_argument("model", help="catalog name, model-file path, or 'all'")
    parser.add_argument("--filter", action="append", dest="filters", metavar="F")
    parser.add_argument("--steps", type=int, default=1000, help="steps simulated (1000)")
    parser.add_argument("--seed", type=int, default=7)
    add_option_arguments(parser)


def run(args) -> int:
    from .. import catalog
    from ..apps.verify import verify_filter
    from ..errors import VerificationError
    from ..filters import available, kind
    from ..filters.fir import order
    from ..options import from_arguments, per_filter
    from . import load_model

    options = from_arguments(args)
    refs = catalog.names() if args.model == "all" else [args.model]
    failed = 0
    for ref in refs:
        model = load_model(ref)
        names = args.filters or available(model)
        for name in names:
            kind(name)
        typed = per_filter(names, options, named=bool(args.filters))
        for name in names:
            if "order" in typed[name].specs():  # a FIR: the order its options give
                print(f"{model.name}/fir: order N = {order(model, typed[name])}")
            for v in verify_filter(model, name, steps=args.steps, seed=args.seed,
                                   options=typed[name]):
                print(v.line())
                failed += not v.passed
    if failed:
        raise VerificationError(f"{failed} generated filter(s) disagree with the reference")
    return 0
