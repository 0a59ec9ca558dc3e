"""generate(): files, layout, the command line, and the committed generated/ tree (whose
freshness tests/emit/test_determinism.py checks, beside its independence of the hash seed)."""

from pathlib import Path

import numpy as np
import pytest

from derive import catalog
from derive.build import load_python
from derive.cli import main
from derive.errors import FilterError, SteadyStateError
from derive.filters import available
from derive.generation import generate

ROOT = Path(__file__).resolve().parents[2]


def test_generate_writes_model_filter_files(tmp_path):
    paths = generate("mpt3d_b", ["kf", "sskf"], "all", tmp_path)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in paths) == [
        "mpt3d_b/kf.c", "mpt3d_b/kf.h", "mpt3d_b/kf.py",
        "mpt3d_b/sskf.c", "mpt3d_b/sskf.h", "mpt3d_b/sskf.py"]
    text = (tmp_path / "mpt3d_b" / "kf.c").read_text()
    assert "void mpt3d_b_kf_run(size_t steps" in text or "int mpt3d_b_kf_run(size_t steps" in text
    assert "derive generate mpt3d_b --filter kf --lang all" in text


def test_generate_one_language(tmp_path):
    paths = generate("cv", ["kf"], "python", tmp_path)
    assert [p.name for p in paths] == ["kf.py"]


def test_unknown_filter_is_named(tmp_path):
    with pytest.raises(FilterError, match="'kff'.*did you mean 'kf'"):
        generate("cv", ["kff"], "all", tmp_path)
    with pytest.raises(FilterError, match=r"^unknown filter 'KF' \(did you mean 'kf'\?\)"):
        generate("cv", ["KF"], "all", tmp_path)
    assert not any(tmp_path.iterdir())


def test_one_filter_may_be_named_as_a_string(tmp_path):
    paths = generate("cv", "sskf", "python", tmp_path)
    assert [p.name for p in paths] == ["sskf.py"]


def test_steady_state_with_a_free_symbol_is_refused(tmp_path):
    import sympy

    from derive import LinearModel

    q = sympy.Symbol("q")
    m = LinearModel("freeq", ["s", "v"], ["z"], [[1, 1], [0, 1]], [[1, 0]], [[q]], [[1]],
                    G=[[0.5], [1]], parameters=["q"])
    with pytest.raises(SteadyStateError, match="'q'"):
        generate(m, ["sskf"], "all", tmp_path)
    generate(m, ["kf"], "python", tmp_path)  # time-varying: q is the runtime p[0]
    mod = load_python(tmp_path / "freeq" / "kf.py")
    xs, Ps = mod.run(np.ones((5, 1)), np.zeros(2), np.eye(2), np.array([0.01]))
    assert xs.shape == (5, 2) and Ps.shape == (5, 2, 2)


def test_run_tracks_can_be_left_out(tmp_path):
    """--no-run-tracks: a smaller C file without MODEL_FILTER_run_tracks, still building and
    running, and the regeneration command says so."""
    from derive.build import build_c

    full = tmp_path / "full"
    assert main(["generate", "mpt3d_b", "--filter", "kf", "--filter", "sskf", "--lang", "c",
                 "--out", str(full)]) == 0
    lean = tmp_path / "lean"
    assert main(["generate", "mpt3d_b", "--filter", "kf", "--filter", "sskf", "--lang", "c",
                 "--no-run-tracks", "--out", str(lean)]) == 0
    for name in ("kf", "sskf"):
        c, h = (lean / "mpt3d_b" / f"{name}{s}" for s in (".c", ".h"))
        assert "_run_tracks(" not in c.read_text() and "_run_tracks(" not in h.read_text()
        assert f"mpt3d_b_{name}_run_tracks(" in (full / "mpt3d_b" / f"{name}.c").read_text()
        assert "--no-run-tracks" in c.read_text()
        assert c.stat().st_size < (full / "mpt3d_b" / f"{name}.c").stat().st_size
    mod = build_c(lean / "mpt3d_b" / "kf.c")
    zs = np.ones((4, 1))
    xs, Ps = mod.run(zs, np.zeros(2), np.eye(2))
    ref = build_c(full / "mpt3d_b" / "kf.c").run(zs, np.zeros(2), np.eye(2))
    np.testing.assert_array_equal(xs, ref[0])
    np.testing.assert_array_equal(Ps, ref[1])


def test_cli_generate_and_errors(tmp_path, capsys):
    assert main(["generate", "gsm2d_b", "--filter", "kf", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "gsm2d_b" / "kf.h").is_file()
    capsys.readouterr()
    assert main(["generate", "no_such_model", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no_such_model" in err[0]


def test_every_catalog_filter_listed_is_generated():
    for name in catalog.names():
        model = catalog.load(name)
        for f in available(model):
            assert (ROOT / "generated" / name / f"{f}.py").is_file(), (name, f)
