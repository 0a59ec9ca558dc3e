"""`derive gnss [--sim] [--real]`: the GNSS paper with derive's generated EKF and UKF.

--sim (the default): the paper's RMSE table reproduced by Monte Carlo on a documented
simulated geometry (derive.apps.gnss.sim), derive's numbers beside the paper's.
--real: the real-data run of derive.apps.gnss (RINEX files of the optional package
gnss-benchmark; missing, it is bad input: exit 2).
"""

NAME = "gnss"
ORDER = 60
HELP = ("GNSS paper: Monte Carlo RMSE table with the generated EKF/UKF (--sim, default) "
        "and the real-data run (--real)")
EXAMPLE = "derive gnss --sim --runs 200\n  derive gnss --real --epochs 300"


def add_arguments(parser) -> None:
    from ..apps.gnss import command as real_command

    parser.add_argument("--sim", action="store_true",
                        help="Monte Carlo reproduction of the paper's RMSE table (default)")
    parser.add_argument("--real", action="store_true",
                        help="run the generated filters on real GPS data")
    sim = parser.add_argument_group("simulation (--sim)")
    sim.add_argument("--runs", type=int, default=200, help="Monte Carlo runs (200)")
    sim.add_argument("--seed", type=int, default=2024, help="seed (2024)")
    sim.add_argument("--init-std", type=float, default=10.0,
                     help="initial error std and sqrt of P0's diagonal, m (10)")
    sim.add_argument("--sim-lang", choices=("python", "c"), default="python",
                     help="run the generated Python (all runs at once) or C (python)")
    real = parser.add_argument_group("real data (--real)")
    real_command.add_arguments(real)


def run(args) -> int:
    from ..errors import ModelError

    sim = args.sim or not args.real
    if sim:
        from ..apps.gnss.sim import reproduce

        print(reproduce(args.runs, seed=args.seed, init_std=args.init_std,
                        lang=args.sim_lang).table())
    if args.real:
        from ..apps.gnss import command as real_command

        if sim:
            print()
        try:
            return real_command.run_command(args)
        except ModuleNotFoundError as exc:
            raise ModelError(f"real GNSS data unavailable: {exc}") from exc
    return 0
