"""`derive check [MODEL]`: the papers' equivalence claims on the reference filters."""

NAME = "check"
ORDER = 30
HELP = ("run the NumPy reference filters on simulated data and print the papers' "
        "equivalence checks")
EXAMPLE = "derive check mpt3d_a"


def add_arguments(parser) -> None:
    parser.add_argument("model", nargs="?", default="all",
                        help="catalog name, model-file path, or 'all' (default)")
    parser.add_argument("--steps", type=int, default=500, help="steps simulated (500)")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed (1)")


def run(args) -> int:
    from .. import catalog
    from ..apps.checks import run_checks
    from ..errors import VerificationError
    from . import load_model

    refs = catalog.names() if args.model == "all" else [args.model]
    passed = failed = 0
    for ref in refs:
        for check in run_checks(load_model(ref), steps=args.steps, seed=args.seed):
            print(check.line())
            passed += check.passed
            failed += not check.passed
    print(summary_line(passed, failed, len(refs)))
    if failed:
        raise VerificationError(f"{failed} equivalence check(s) failed")
    return 0


def summary_line(passed: int, failed: int, models: int) -> str:
    """The last line of ``derive check``: how many claims passed and failed."""
    return (f"derive check: {passed} passed, {failed} failed "
            f"({models} model{'s' if models != 1 else ''})")
