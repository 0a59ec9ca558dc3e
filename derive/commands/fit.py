"""`derive fit MODEL DATA...`: maximum-likelihood estimates of a model's free parameters."""

from contextlib import contextmanager

NAME = "fit"
ORDER = 47
HELP = ("maximum-likelihood estimates of a model's free parameters from measurement "
        "files (CSV or .npy, one row per step: the measurements, NaN where missing, then the "
        "model's inputs), with the exact gradient of the Kalman filter's (a nonlinear "
        "model: the EKF's) log-likelihood; "
        "several files are tracks sharing the parameters; prints the estimates and their "
        "standard errors and writes the fitted model file with --out")
EXAMPLE = ("derive fit cv track.csv --free sq2 --free sr2 --positive sq2 --positive sr2 "
           "--out cv_fitted.toml\n"
           "  derive fit model.toml a.npy b.npy --start q=0.1\n"
           "  derive fit --anchor robot --bench")

#: The data sets built in (derive.apps.fit_anchors): name -> (model text, data) makers.
ANCHORS = ("robot", "receiver")


def add_arguments(parser) -> None:
    parser.add_argument("model", nargs="?", help="catalog name or model-file path")
    parser.add_argument("data", nargs="*", help="measurement files (.csv or .npy), one per "
                                                "track")
    parser.add_argument("--anchor", choices=ANCHORS,
                        help="fit a data set derive is checked on instead of MODEL DATA: "
                             "robot (pykalman's load_robot, Q and R scales free) or receiver "
                             "(gnss-benchmark's moving receiver, constant velocity, q and r "
                             "free per axis)")
    parser.add_argument("--free", action="append", default=[], metavar="NAME",
                        help="fit this valued parameter too, starting from its value "
                             "(repeatable)")
    parser.add_argument("--positive", action="append", default=[], metavar="NAME",
                        help="declare parameter NAME positive (domain = \"positive\"): the "
                             "fit optimises its logarithm, and the fitted file keeps the "
                             "domain (repeatable)")
    parser.add_argument("--start", action="append", default=[], metavar="NAME=V",
                        help="start free parameter NAME at V (default: its example, or the "
                             "value of a --free one)")
    parser.add_argument("--out", metavar="FILE",
                        help="write the model file with the fitted values (derive generate "
                             "takes it)")
    parser.add_argument("--bench", action="store_true",
                        help="time the fit (generation and compilation apart) and "
                             "statsmodels' fit of the same likelihood (MLEModel.fit "
                             "defaults) on the first track, in five turns (derive four "
                             "times, statsmodels once), and print the least CPU time of each "
                             "and their ratio")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress line (it is shown only when stderr is a terminal)")


def run(args) -> int:
    from ..errors import ModelError
    from ..fitting import (
        fit,
        fitted_text,
        free_text,
        model_text,
        read_data,
        split_columns,
        write_model_file,
    )
    from ..generation import is_model_file
    from ..modelfile import load_model_file, loads_model
    from .verify import parameter_values

    if args.anchor:
        if args.model or args.data:
            raise ModelError("--anchor takes no MODEL or DATA (it brings its own)")
        from ..apps import fit_anchors  # the anchors' data sets are optional packages

        with optional(f"--anchor {args.anchor}"):
            text = getattr(fit_anchors, f"{args.anchor}_model_text")()
            label, tracks = args.anchor, [getattr(fit_anchors, f"{args.anchor}_data")()]
    else:
        if not args.model or not args.data:
            raise ModelError("derive fit takes MODEL and at least one DATA file (or --anchor)")
        text, label = model_text(args.model)
        tracks = [read_data(path) for path in args.data]
    if args.free or args.positive:
        text = free_text(text, args.free, args.positive)
    # a model file as a file (its [compose] paths relative to it), unless its text changed
    model = (loads_model(text, source=label) if args.anchor or args.free or args.positive
             or not is_model_file(args.model) else load_model_file(args.model))
    if args.out:  # refused before the work: a parameter the file's text cannot set
        fitted_text(text, {p.name: 1.0 for p in model.parameters})
    for i, track in enumerate(tracks):
        split_columns(model, track, args.data[i] if args.data else label)
    start = parameter_values(args.start)
    timed = None
    if args.bench:  # first: its generation from cold, before the fit's warms any cache
        with optional("--bench"):
            from ..apps.fit_peer import bench  # statsmodels: an optional peer
        timed = bench(model, tracks[0], start=start)
    result = fit(model, tracks if len(tracks) > 1 else tracks[0], start=start,
                 progress=False if args.no_progress else None)
    print(result.table())
    print(f"time: fit {result.seconds:.3f} s, generation and compilation "
          f"{result.generation_seconds:.3f} s")
    if args.out:
        write_model_file(args.out, fitted_text(text, result.values()))
        print(f"wrote {args.out}")
    for line in timed.lines() if timed is not None else ():
        print(line)
    return 0


@contextmanager
def optional(what: str):
    """An optional package missing for ``what``: one line naming it (ModelError, exit 2)."""
    from ..errors import ModelError

    try:
        yield
    except ModuleNotFoundError as exc:
        package = (exc.name or "").split(".")[0].replace("_", "-")
        raise ModelError(f"{what} needs the package {package} (pip install {package})"
                         ) from None
