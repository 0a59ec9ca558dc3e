"""`derive reproduce`: the main job — regenerate, verify and report the seed catalog."""

NAME = "reproduce"
ORDER = 90
HELP = "the main job: regenerate every catalog filter, verify it and report"
EXAMPLE = "derive reproduce --out report"


def add_arguments(parser) -> None:
    parser.add_argument("--out", default="report", help="report directory (report)")
    parser.add_argument("--generated", default=None,
                        help="write the generated code here (default: a scratch directory)")


def run(args) -> int:
    import tempfile

    from .. import catalog
    from ..checks import run_checks
    from ..errors import VerificationError
    from ..filters import available
    from ..generate import generate
    from ..verify import verify_filter

    failed = 0
    with tempfile.TemporaryDirectory() as scratch:
        out = args.generated or scratch
        for name in catalog.names():
            model = catalog.load(name)
            for check in run_checks(model):
                print(check.line())
                failed += not check.passed
            paths = generate(name, None, "all", out)
            print(f"generated {len(paths)} files for {name}")
            for f in available(model):
                if model.kind != "linear":
                    continue
                for v in verify_filter(model, f):
                    print(v.line())
                    failed += not v.passed
    if failed:
        raise VerificationError(f"{failed} check(s) failed")
    return 0
