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
        _check_results(args.results)
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


def _check_results(results: str) -> None:
    """Refuse, before the job, a ``--results`` path the summary could not be written to:
    empty, a directory, not a regular file (``/dev/full``), or in a directory that is
    missing or where no file can be made (read-only, immutable): found by making and
    removing a file beside it (write permission bits do not tell: root ignores them,
    and ``chattr +i`` binds root too)."""
    import os
    import stat
    import tempfile
    from pathlib import Path

    from ..errors import ModelError

    if not results:
        raise ModelError("--results '': an empty path (give the file to write the results "
                         "summary to, e.g. docs/results.md)")
    path = Path(results)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise ModelError(f"--results {results}: {exc.strerror}") from None
    if mode is not None and not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
        raise ModelError(f"--results {results}: it is {kind}; the results summary is written "
                         "to a regular file")
    folder = path.resolve().parent
    if not folder.is_dir():
        raise ModelError(f"--results {results}: directory {folder} does not exist")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".derive-results-"):
            pass
        if mode is not None:
            with open(path, "ab"):
                pass
    except OSError as exc:
        raise ModelError(f"--results {results}: cannot write there: {exc.strerror}") from None


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
