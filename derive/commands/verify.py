"""`derive verify MODEL [--filter F]`: generated Python and C against the reference."""

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


def run(args) -> int:
    from .. import catalog
    from ..errors import VerificationError
    from ..filters import available
    from ..verify import verify_filter
    from . import load_model

    refs = catalog.names() if args.model == "all" else [args.model]
    failed = 0
    for ref in refs:
        model = load_model(ref)
        for name in args.filters or available(model):
            for v in verify_filter(model, name, steps=args.steps, seed=args.seed):
                print(v.line())
                failed += not v.passed
    if failed:
        raise VerificationError(f"{failed} generated filter(s) disagree with the reference")
    return 0
