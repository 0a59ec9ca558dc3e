"""`derive reproduce`: the main job — regenerate, verify and report the seed catalog."""

NAME = "reproduce"
ORDER = 90
HELP = ("the main job: regenerate every catalog filter, compile and verify it, run the "
        "papers' experiments and write a report (index.html, index.md, results.md, figures/)")
EXAMPLE = ("derive reproduce\n  derive reproduce --out /tmp/report --generated generated\n"
           "  derive reproduce --results docs/results.md\n  derive reproduce --quick")


def add_arguments(parser) -> None:
    parser.add_argument("--out", default="report", help="report directory (default: report)")
    parser.add_argument("--generated", default=None,
                        help="write the generated code here (default: a scratch directory)")
    parser.add_argument("--results", default=None, metavar="FILE",
                        help="also write the results summary (the report's results.md) to "
                             "FILE, e.g. docs/results.md")
    parser.add_argument("--quick", action="store_true",
                        help="a reduced run (fewer steps and seeds); every figure and table "
                             "is still produced")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (it is shown only when stderr is a terminal)")


def run(args) -> int:
    import shlex
    from pathlib import Path

    from .. import progress
    from ..errors import ModelError, VerificationError

    try:
        import matplotlib  # noqa: F401

        from ..apps.report.job import run as run_report
    except ImportError as exc:
        raise ModelError(f"the report needs matplotlib ({exc}); install derive-filters[report]") \
            from None
    from ..build import BuildError

    if args.results is not None:
        folder = Path(args.results).resolve().parent
        if not folder.is_dir():
            raise ModelError(f"--results {args.results}: directory {folder} does not exist")
    command = shlex.join(["derive", NAME, *_given(args)])
    try:
        result = run_report(args.out, args.generated, quick=args.quick,
                            progress=not args.no_progress and progress.enabled(),
                            command=command, results=args.results)
    except BuildError as exc:
        raise ModelError(f"cannot compile the generated C: {exc}") from exc
    except OSError as exc:
        raise ModelError(f"cannot write the report or the generated code: {exc}") from exc
    print(result.summary())
    if result.failures:
        raise VerificationError(f"{len(result.failures)} verification(s) or check(s) failed; "
                                f"see {result.page}")
    return 0


def _given(args) -> list[str]:
    """The options of ``args`` that differ from their defaults, as command-line words:
    the command the report states."""
    words = []
    for option in ("out", "generated", "results"):
        value = getattr(args, option)
        if value is not None and not (option == "out" and value == "report"):
            words += [f"--{option}", str(value)]
    words += ["--quick"] * bool(args.quick) + ["--no-progress"] * bool(args.no_progress)
    return words
