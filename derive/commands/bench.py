"""`derive bench`: per-step time of the generated filters against their peers, and batch
throughput over many tracks, in one table."""

NAME = "bench"
ORDER = 95
HELP = ("time the generated C and Python filters against the NumPy reference, FilterPy, "
        "pykalman and CasADi's generated C, and batch throughput against simdkalman")
EXAMPLE = ("derive bench\n  derive bench --json > bench.json\n  derive bench --quick\n"
           "  derive bench --only navigation\n  derive bench --only catalog")


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--quick", action="store_true",
                        help="tiny step and repeat counts (a smoke test; times meaningless)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="repeats per measurement (default 7; the median is shown)")
    parser.add_argument("--scale-tracks", type=int, default=None,
                        help="tracks of the every-core batch (derive.batch on threads and a "
                             "Dask LocalCluster; default 1,000,000; 0 leaves it out)")
    parser.add_argument("--scale-steps", type=int, default=None,
                        help="steps per track of the every-core batch (default 100)")
    parser.add_argument("--compile-states", type=int, action="append", default=None,
                        metavar="N", help="a dense random KF of N states (m = N/3) generated "
                        "and compiled: time, peak memory, .c size (repeatable; default 16 and "
                        "24; 0 leaves it out)")
    parser.add_argument("--only", choices=("navigation", "catalog"), default=None,
                        help="run one section alone: navigation (the INS EKFs against "
                             "CasADi, FilterPy and SymForce's C++, timed in four builds) or "
                             "catalog (the catalog's cases against their peers, the batch "
                             "and every-core rows, with their bars)")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress lines (they are shown only when stderr is a "
                             "terminal)")


def run(args) -> int:
    import json
    from dataclasses import replace

    from .. import progress
    from ..apps.bench.run import Settings, run_bench
    from ..errors import ModelError

    settings = Settings.quick() if args.quick else Settings()
    if args.repeats is not None:
        if args.repeats < 1:
            raise ModelError(f"--repeats must be >= 1, got {args.repeats}")
        settings = replace(settings, repeats=args.repeats, batch_repeats=args.repeats,
                           scale_repeats=args.repeats)

    if args.only is not None:
        settings = replace(settings, only=args.only)
    if args.scale_tracks is not None:
        if args.scale_tracks < 0:
            raise ModelError(f"--scale-tracks must be >= 0, got {args.scale_tracks}")
        settings = replace(settings, scale_tracks=args.scale_tracks)
    if args.scale_steps is not None:
        if args.scale_steps < 1:
            raise ModelError(f"--scale-steps must be >= 1, got {args.scale_steps}")
        settings = replace(settings, scale_steps=args.scale_steps)

    if args.compile_states is not None:
        if any(n < 0 for n in args.compile_states):
            raise ModelError(f"--compile-states must be >= 0, got {args.compile_states}")
        settings = replace(settings, compile_states=tuple(n for n in args.compile_states if n))

    def report(text: str) -> None:
        progress.report(f"bench: {text}")

    from ..build import BuildError

    show_progress = not args.no_progress and progress.enabled()
    try:
        result = run_bench(settings, report if show_progress else None)
    except BuildError as exc:
        raise ModelError(f"cannot compile the generated C: {exc}") from exc
    print(json.dumps(result.as_json(), indent=2) if args.json else result.text())
    return 0
