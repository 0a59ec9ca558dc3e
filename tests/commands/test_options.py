"""Filter options (derive.options): validated once, from the API and the CLI alike; given
only to the filters that take them; FIR order and prediction horizon bounded, refused fast
and in one line; messages in short decimals."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from derive import catalog, generation
from derive.cli import build_parser, main
from derive.errors import OptionError, SteadyStateError
from derive.filters import FILTERS, derive_unit
from derive.filters.steady import steady_gains
from derive.generation import generate, render_filter
from derive.horizon import MAX_FIR_TAPS, MAX_FIR_WINDOW, FirOrderError, fir_order, max_fir_order
from derive.modelfile import load_model_file
from derive.options import (
    FirOptions,
    KalmanOptions,
    all_specs,
    from_arguments,
    options_type,
    per_filter,
    taken_by,
    takers,
    validate,
)

ROOT = Path(__file__).resolve().parents[2]

# A constant-velocity tracker with a slowly decaying measurement bias (pole 0.999): its
# FIR needs an order of 14156 for ||A^N||_2 < 1e-6.
BIAS_TRACKER = """\
[model]
name = "cvbias"
states = ["s", "v", "b"]
measurements = ["z"]

[discrete]
F = [[1, 1, 0], [0, 1, 0], [0, 0, 0.999]]
G = [[0.5, 0], [1, 0], [0, 1]]
Q = [[0.01, 0], [0, 1e-8]]
H = [[1, 0, 1]]
R = 0.1

[initial]
x0 = [0, 0, 0]
P0 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
"""


@pytest.fixture(scope="module")
def bias_tracker(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("models") / "cvbias.toml"
    path.write_text(BIAS_TRACKER)
    return path


def refused_line(capsys, argv: list[str]) -> str:
    """Run the CLI; assert status 2 and one line on stderr; return it."""
    capsys.readouterr()
    status = main(argv)
    err = capsys.readouterr().err.splitlines()
    assert status == 2 and len(err) == 1, (status, err)
    return err[0]


def run_cli(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    """``python -m derive ARGV`` in a subprocess, killed after ``timeout`` seconds."""
    return subprocess.run([sys.executable, "-m", "derive", *argv], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout)


# -- 1. options are validated -------------------------------------------------------------


def test_the_string_false_for_a_bool_is_refused(tmp_path):
    with pytest.raises(OptionError, match=r"option 'missing' \(--missing\) must be a bool "
                                          r"\(True or False\), got the str 'False'"):
        generate("mpt3d_b", ["kf"], "all", tmp_path, options={"missing": "False"})
    assert not (tmp_path / "mpt3d_b").exists()


@pytest.mark.parametrize("key, value, words", [
    ("joseph", 1, "must be a bool (True or False), got the int 1"),
    ("order", 3.0, "must be an integer, got the float 3.0"),
    ("order", True, "must be an integer, got the bool True"),
    ("eps", "0.1", "must be a real number, got the str '0.1'"),
    ("alpha", None, "must be a real number, got None"),
    ("P0_pattern", "sparse", "must be one of dense, zero, diagonal, block, got 'sparse'"),
    ("P0_pattern", "diagonl", "(did you mean 'diagonal'?)"),
    ("horizon", 2**70, "must be an integer in [1, 4096], got 1180591620717411303424"),
    ("beta", float("nan"), "must be a finite number, got nan"),
])
def test_wrong_types_and_values_are_refused_naming_the_option(key, value, words):
    name = next(f for f in FILTERS if key in taken_by(f))
    with pytest.raises(OptionError) as info:
        validate(name, {key: value})
    assert f"option {key!r}" in str(info.value) and words in str(info.value), str(info.value)


def test_numpy_scalars_are_accepted():
    opts = validate("fir", {"order": np.int64(7)})
    assert opts.order == 7 and type(opts.order) is int
    assert validate("kf", {"joseph": np.bool_(True)}).joseph is True
    assert validate("ukf", {"alpha": np.float32(0.5)}).alpha == 0.5


def test_an_unknown_option_is_refused_with_a_close_match(tmp_path, capsys):
    with pytest.raises(OptionError, match=r"unknown option 'jospeh' \(did you mean "
                                          r"'joseph'\?\); options: P0_pattern, missing"):
        generate("mpt3d_b", ["kf"], "all", tmp_path, options={"jospeh": True})
    with pytest.raises(OptionError, match=r"unknown option 'jospeh' \(did you mean "
                                          r"'joseph'\?\); options of kf: P0_pattern, "
                                          r"missing, loglik, gradient, run_tracks, gate, "
                                          r"gate_sensors, "
                                          r"start, "
                                          r"update, prefix, precision, run, joseph, "
                                          r"latency_schedule$"):
        derive_unit(catalog.load("mpt3d_b"), "kf", {"jospeh": True})
    line = refused_line(capsys, ["generate", "mpt3d_b", "--filter", "kf", "--jospeh",
                                 "--out", str(tmp_path)])
    assert "unrecognized arguments: --jospeh" in line and "did you mean --joseph?" in line


def test_a_former_name_points_to_the_current_one():
    with pytest.raises(OptionError, match=r"unknown option 'N' \(did you mean 'order'\?\)"):
        validate("fir", {"N": 10})
    with pytest.raises(OptionError, match=r"unknown option 'N' \(did you mean 'horizon'\?\)"):
        validate("pred", {"N": 3})


def test_an_option_named_for_a_filter_that_does_not_take_it_is_refused(tmp_path):
    with pytest.raises(OptionError, match="option 'joseph' is taken by kf, not by lf; "
                                          "options of lf: P0_pattern, missing, run_tracks"):
        render_filter(catalog.load("mpt3d_b"), "lf", "all", {"joseph": True})
    with pytest.raises(OptionError, match="option 'missing' is taken by kf, lf, jklf, ikf, "
                                          "udkf, rts, kfp, not by sskf"):
        generate("mpt3d_b", ["kf", "sskf"], "all", tmp_path,
                 per_filter_options={"sskf": {"missing": True}})
    with pytest.raises(OptionError, match="per-filter options for 'fir', which this call "
                                          "does not generate"):
        generate("mpt3d_b", ["kf"], "all", tmp_path, per_filter_options={"fir": {"order": 3}})
    with pytest.raises(OptionError, match="must be a mapping"):
        generate("mpt3d_b", ["kf"], "all", tmp_path, options=["joseph"])
    assert not (tmp_path / "mpt3d_b").exists()


def test_an_option_of_the_call_that_no_named_filter_takes_is_refused(tmp_path, capsys):
    line = refused_line(capsys, ["generate", "mpt3d_b", "--filter", "lf", "--filter", "sskf",
                                 "--joseph", "--out", str(tmp_path)])
    assert line.endswith("option 'joseph' is taken by kf; none of the filters of this call "
                         "(lf, sskf) takes it")
    # all that apply: given to those that take it
    assert per_filter(["kf", "lf"], {"joseph": True}, named=False)["kf"].joseph is True


def test_a_huge_fir_order_is_refused_at_once(tmp_path):
    """{"N": 10**7} hung; now the name and the value are refused before any work."""
    proc = run_cli(["generate", "mpt3d_b", "--filter", "fir", "--order", "10000000",
                    "--out", str(tmp_path)], timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc
    assert ("option 'order' (--order) must be an integer in [1, 256], got 10000000"
            in proc.stderr)
    for options in ({"N": 10**7}, {"order": 10**7}):
        with pytest.raises(OptionError):
            generate("mpt3d_b", ["fir"], "all", tmp_path, per_filter_options={"fir": options})
    assert not (tmp_path / "mpt3d_b").exists()


# -- 2. an option is stated only by the filters that take it -------------------------------


def test_joseph_and_missing_reach_only_the_filters_that_take_them(tmp_path, capsys):
    assert main(["generate", "mpt3d_b", "--filter", "kf", "--filter", "lf", "--filter",
                 "sskf", "--filter", "fir", "--joseph", "--missing", "--out",
                 str(tmp_path)]) == 0
    header = {f: (tmp_path / "mpt3d_b" / f"{f}.h").read_text() for f in ("kf", "lf", "sskf",
                                                                          "fir")}
    assert "covariance update: Joseph form" in header["kf"]
    assert "--joseph" in header["kf"] and "--missing" in header["kf"]
    for name in ("lf", "sskf", "fir"):
        assert "Joseph" not in header[name] and "--joseph" not in header[name], name
    assert "missing measurements" in header["lf"] and "--missing" in header["lf"]
    for name in ("sskf", "fir"):
        assert "missing measurements" not in header[name], name
        assert "--missing" not in header[name], name


def test_the_regenerate_command_gives_back_the_options():
    """Each header's command, parsed by the CLI, gives exactly the filter's options."""
    model = catalog.load("mpt3d_b")
    parser = build_parser()
    cases = {"kf": {"joseph": True, "missing": True, "P0_pattern": "dense",
                    "run_tracks": False},
             "fir": {"eps": 1e-3}, "pred": {"horizon": 3}, "sskf": {"run_tracks": False}}
    for name, options in cases.items():
        files = render_filter(model, name, "python", options, "mpt3d_b", "out")
        command = next(line for line in files[f"{name}.py"].splitlines()
                       if "derive generate" in line)
        argv = command[command.index("derive generate") + len("derive "):].split()
        args = parser.parse_args(argv)
        assert from_arguments(args) == options, (name, command)
        assert validate(name, from_arguments(args)) == validate(name, options)


def test_every_option_has_one_flag_in_generate_burden_and_verify():
    parser = build_parser()
    commands = {a.dest: a for a in parser._actions if a.dest == "command"}["command"].choices
    flags = {spec.flag for spec in all_specs().values()}
    assert len(flags) == len(all_specs())
    for command in ("generate", "burden", "verify"):
        have = {s for a in commands[command]._actions for s in a.option_strings}
        assert flags <= have, (command, flags - have)


def test_declarations_are_consistent_with_the_registry():
    for key in all_specs():
        assert takers(key) and set(takers(key)) <= set(FILTERS), key
        for name in takers(key):
            assert key in options_type(name).specs(), (key, name)
    assert taken_by("kf") == ["P0_pattern", "missing", "loglik", "gradient", "run_tracks", "gate",
                              "gate_sensors", "start", "update", "prefix", "precision", "run",
                              "joseph", "latency_schedule"]
    assert taken_by("fir") == ["prefix", "precision", "run", "eps", "order"]
    assert taken_by("pred") == ["prefix", "precision", "run", "horizon"]
    assert taken_by("ukf") == ["P0_pattern", "prefix", "precision", "run", "alpha", "beta", "kappa"]
    assert taken_by("sskf") == ["run_tracks", "prefix", "precision", "run"]
    assert takers("prefix") == list(FILTERS)  # every filter's C exports names
    assert takers("precision") == list(FILTERS)  # every filter has C


def test_typed_options_are_taken_as_they_are():
    model = catalog.load("mpt3d_b")
    unit = derive_unit(model, "kf", KalmanOptions(joseph=True))
    assert "covariance update: Joseph form" in unit.facts
    with pytest.raises(OptionError, match="option 'joseph' is taken by kf, not by lf"):
        derive_unit(model, "lf", KalmanOptions(joseph=True))


def test_burden_takes_the_same_options(capsys):
    line = refused_line(capsys, ["burden", "mpt3d_b", "--filter", "fir", "--eps", "2"])
    assert "option 'eps' (--eps) must be a finite number in (0, 1), got 2.0" in line
    capsys.readouterr()
    assert main(["burden", "mpt3d_b", "--filter", "kf", "--missing", "--json"]) == 0
    assert '"cmp": 5' in capsys.readouterr().out  # the masks of the missing option


# -- 3. FIR order and prediction horizon bounds ---------------------------------------------


def test_an_ordinary_model_needing_a_huge_fir_order_is_refused_fast(bias_tracker, tmp_path):
    """`derive verify` on this model ran 11 minutes in silence; now: one line naming the
    order that would be needed and the bound."""
    for command in (["generate", str(bias_tracker), "--filter", "fir", "--out", str(tmp_path)],
                    ["verify", str(bias_tracker), "--filter", "fir"]):
        proc = run_cli(command, timeout=60)
        assert proc.returncode == 2, proc
        assert proc.stderr.splitlines() == [proc.stderr.strip()], proc.stderr
        assert "||A^N||_2 < 1e-06 would need order N = 14156" in proc.stderr
        assert "the largest order generated for 'cvbias' (n = 3, m = 1) is 256" in proc.stderr
        assert "Traceback" not in proc.stderr
    assert not (tmp_path / "cvbias").exists()


def test_all_that_apply_refuses_the_fir_order_before_deriving_any_filter(bias_tracker,
                                                                         tmp_path,
                                                                         monkeypatch):
    """Without --filter, the FIR's order is checked before the other filters are derived
    (a 32-state model derived six filters, 57 s, before the FIR refused), and the message
    says the FIR came from all that apply and how to leave it out."""
    derived = []
    monkeypatch.setattr(generation, "render_unit",
                        lambda model, name, *a, **k: derived.append(name))
    with pytest.raises(SteadyStateError) as info:
        generation.generate_units(str(bias_tracker), None, "all", tmp_path)
    assert derived == []
    assert "would need order N = 14156" in str(info.value)
    assert str(info.value).endswith("(filter 'fir' is among all that apply to 'cvbias'; "
                                    "name the filters to derive with --filter)")
    assert not (tmp_path / "cvbias").exists()


def test_the_needed_order_is_found_without_building_it(bias_tracker):
    A, _ = steady_gains(load_model_file(bias_tracker), "sskf")
    for eps in (1e-3, 1e-6, 1e-9):
        exact = fir_order(A, eps, max_order=10**5)
        with pytest.raises(FirOrderError) as info:
            fir_order(A, eps, max_order=100)
        assert info.value.needed == exact and info.value.bound == 100
    with pytest.raises(FirOrderError) as info:      # 690777 iterations never run
        fir_order(A, 1e-300, max_order=10)
    assert 690_000 < info.value.needed < 691_000


def test_a_tiny_epsilon_is_refused_naming_the_needed_order(tmp_path):
    with pytest.raises(SteadyStateError, match=r"\|\|A\^N\|\|_2 < 1e-300 would need order "
                                               r"N = 1628, but the largest order generated "
                                               r"for 'mpt3d_b' \(n = 2, m = 1\) is 256"):
        generate("mpt3d_b", ["fir"], "all", tmp_path, per_filter_options={
            "fir": {"eps": 1e-300}})


def test_the_order_bound_depends_on_the_model():
    assert max_fir_order(2, 1) == MAX_FIR_WINDOW
    assert max_fir_order(6, 3) == min(MAX_FIR_WINDOW // 3, MAX_FIR_TAPS // 18) == 85
    with pytest.raises(OptionError, match="option 'order' \\(--order\\) is 100, but the "
                                          "largest order generated for 'mpt3d_a' \\(n = 6, "
                                          "m = 3\\) is 85"):
        derive_unit(catalog.load("mpt3d_a"), "fir", {"order": 100})
    with pytest.raises(OptionError, match="exclude each other"):
        derive_unit(catalog.load("mpt3d_a"), "fir", {"order": 10, "eps": 1e-3})


def test_the_largest_fir_order_is_generated_in_time(tmp_path):
    proc = run_cli(["generate", "mpt3d_b", "--filter", "fir", "--order", str(MAX_FIR_WINDOW),
                    "--out", str(tmp_path)], timeout=120)
    assert proc.returncode == 0, proc
    assert f"fir: order N = {MAX_FIR_WINDOW} (--order)" in proc.stdout


def test_the_order_used_is_printed(tmp_path, capsys):
    assert main(["generate", "mpt3d_b", "--filter", "fir", "--filter", "pred", "--horizon",
                 "3", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "  fir: order N = 33, the least with ||A^N||_2 < 1e-06" in out
    assert "  pred: horizon N = 3" in out


def test_a_huge_prediction_horizon_is_refused(capsys, tmp_path):
    line = refused_line(capsys, ["generate", "mpt3d_b", "--filter", "pred", "--horizon",
                                 "10000000", "--out", str(tmp_path)])
    assert line.endswith("option 'horizon' (--horizon) must be an integer in [1, 4096], "
                         "got 10000000")


# -- 4. messages print short decimals ----------------------------------------------------


def test_a_tiny_alpha_is_refused_in_a_short_line(capsys, tmp_path):
    line = refused_line(capsys, ["generate", "gnss_pseudorange", "--filter", "ukf", "--alpha",
                                 "1e-300", "--out", str(tmp_path)])
    assert line.endswith("option 'alpha' (--alpha) must be a finite number in [0.0001, 1], "
                         "got 1e-300")
    assert len(line) < 150


@pytest.mark.parametrize("options", [
    {"alpha": 0.123456789, "kappa": -4.0},              # n + kappa = 0
    {"alpha": 0.3, "kappa": -4 + 1e-300},               # rounds to -4: n + kappa = 0
    {"alpha": 0.987654321, "kappa": -4.123456789},      # n + kappa < 0
])
def test_ukf_weight_messages_are_decimals(options):
    with pytest.raises(OptionError) as info:
        derive_unit(catalog.load("gnss_pseudorange"), "ukf", options)
    message = str(info.value)
    assert "UKF" in message and not re.search(r"\d{20,}", message), message
    assert "/" not in message, message


def test_fir_options_in_messages_are_decimals():
    for options in ({"eps": 1e-300}, {"eps": 0.1 + 0.2 - 0.3 + 1e-17}):
        try:
            derive_unit(catalog.load("mpt3d_b"), "fir", options)
        except SteadyStateError as exc:
            assert not re.search(r"\d{20,}", str(exc)), str(exc)


def test_fir_defaults_state_eps_only_when_used():
    model = catalog.load("mpt3d_b")
    assert "eps = 1e-06" in derive_unit(model, "fir", FirOptions()).facts
    assert not any(f.startswith("eps") for f in derive_unit(model, "fir", {"order": 5}).facts)


UNSTABLE = """\
[model]
name = "unstable"
states = ["a"]
measurements = ["y"]

[discrete]
F = [[1.5]]
G = [[1]]
Q = [[0.1]]
H = [[1]]
R = 0.2

[initial]
x0 = [0]
P0 = [[1]]
"""


def test_a_horizon_whose_powers_overflow_is_refused_in_one_line(tmp_path):
    """1.5^1800 overflows: one line naming it (no NumPy warning, no infinite constant)."""
    (tmp_path / "unstable.toml").write_text(UNSTABLE)
    proc = run_cli(["generate", str(tmp_path / "unstable.toml"), "--filter", "pred",
                    "--horizon", "1800", "--out", str(tmp_path / "out")])
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc
    assert "needs F^1800, which overflows a double (spectral radius of F: 1.5)" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_typed_options_are_checked_too():
    with pytest.raises(OptionError, match=r"option 'eps' \(--eps\) must be a finite number "
                                          r"in \(0, 1\), got 5.0"):
        FirOptions(eps=5)
    with pytest.raises(OptionError, match="option 'missing' is taken by kf, lf, jklf, ikf, "
                                          "udkf, rts, kfp, not by fir"):
        validate("fir", FirOptions(missing=True))
    assert type(FirOptions(order=np.int32(4)).order) is int


def test_the_regenerate_command_gives_back_the_language():
    """A file generated for one language says that language in its command (regenerating
    with ``--lang all`` would write files the user did not ask for)."""
    model = catalog.load("mpt3d_b")
    parser = build_parser()
    for lang, file in (("c", "kf.h"), ("python", "kf.py"), ("all", "kf.c")):
        files = render_filter(model, "kf", lang, None, "mpt3d_b", "out")
        command = next(line for line in files[file].splitlines() if "derive generate" in line)
        args = parser.parse_args(command[command.index("derive generate") + 7:].split())
        assert args.lang == lang, (lang, command)


@pytest.mark.parametrize("filters, hint", [
    (["fir"], "(did you mean 'order'?)"), (["pred"], "(did you mean 'horizon'?)"),
    (["fir", "pred"], "(did you mean 'order' (fir) or 'horizon' (pred)?)")])
def test_n_names_the_option_of_the_filters_called(tmp_path, filters, hint):
    """``N`` was the FIR's order and the predictor's horizon: the hint is the one the
    call's filters take (it was 'horizon' for the FIR, by spelling alone)."""
    from derive import generate

    with pytest.raises(OptionError) as info:
        generate("mpt3d_b", filters, out=tmp_path, options={"N": 10})
    assert f"unknown option 'N' {hint};" in str(info.value)


def test_a_flag_of_another_command_is_named_as_such(capsys):
    """``derive size --layout library``: --layout is spelt right, for another command (it
    said "did you mean --layout?")."""
    assert main(["size", "mpt3d_b", "--layout", "library"]) == 2
    err = capsys.readouterr().err
    assert err == ("derive: error: unrecognized arguments: --layout library (--layout is an "
                   "option of derive generate only)\n")
