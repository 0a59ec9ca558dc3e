"""``--precision float``: the generated C in float32, its literals, its interface, the
wrappers' dtype, and both precisions clean under the strict and the conversion warnings.

The numerical verification of every catalog filter in float32 against the float64
reference is tests/embedded/test_emb_float_verify.py."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from derive import batch, catalog, interface
from derive.build import CONVERSION_CFLAGS, STRICT_CFLAGS
from derive.cli import main
from derive.emit import c_printer
from derive.errors import DtypeError, OptionError
from derive.generation import generate, render_filter, resolve_model
from derive.pipeline import load_generated
from derive.precision import DOUBLE, FLOAT, PrecisionError
from derive.trees import Const

ROOT = Path(__file__).resolve().parents[2]
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _compile_models(root: Path, expected: int | None = None) -> None:
    """One ``gcc -c`` per model folder (its files' names are unique within it)."""
    flags = list(STRICT_CFLAGS) + list(CONVERSION_CFLAGS)
    folders = sorted(p for p in root.iterdir() if p.is_dir() and list(p.glob("*.c")))
    assert len(folders) == (len(catalog.names()) if expected is None else expected)
    for folder in folders:
        sources = sorted(p.name for p in folder.glob("*.c"))
        proc = subprocess.run(["gcc", *flags, "-c", *sources], cwd=folder,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"{folder.name}: {proc.stderr[:3000]}"


@needs_gcc
def test_every_catalog_filter_in_double_compiles_under_the_conversion_warnings(tmp_path):
    """The committed double files (test_generate keeps them up to date), copied: one
    ``gcc -O2`` call per model with -Wdouble-promotion -Wfloat-conversion -Wconversion.
    The float files of every catalog filter are compiled with the same flags, once, by
    tests/embedded/test_emb_float_verify.py, which runs them."""
    for source in (ROOT / "generated").glob("*/*.[ch]"):
        (tmp_path / source.parent.name).mkdir(exist_ok=True)
        shutil.copy(source, tmp_path / source.parent.name / source.name)
    _compile_models(tmp_path)


@needs_gcc
def test_float_files_compile_under_the_conversion_warnings(tmp_path):
    """One model's float files by plain gcc (no cffi): the flags alone, outside build_c."""
    generate("gsm2d_a", lang="c", out=tmp_path, options={"precision": "float"})
    _compile_models(tmp_path, expected=1)


def _files(model: str, name: str, lang: str = "c", options=None) -> dict[str, str]:
    return render_filter(resolve_model(model), name, lang, options, model_ref=model)


def _code(text: str) -> str:
    """The C after the header comment."""
    return text.split("*/", 1)[1]


def test_float_code_has_no_double_anywhere():
    """float arrays, float temporaries, f literals, sqrtf; no ``double`` and no literal
    without its suffix after the header."""
    files = _files("mpt3d_a", "kf", "c", {"precision": "float"})
    code = _code(files["kf.c"])
    assert "double" not in code and "double" not in _code(files["kf.h"])
    assert "const float *restrict P" in code and "const float t0 = " in code
    literals = re.findall(r"(?<![\w.\[])(\d+\.\d*(?:e[-+]?\d+)?|\d+e[-+]?\d+)(f?)", code)
    assert literals and all(suffix == "f" for _, suffix in literals), literals[:5]
    ranges = _code(_files("gnss_pseudorange", "ekf", "c", {"precision": "float"})["ekf.c"])
    assert "sqrtf(" in ranges and "sqrt(" not in ranges and "double" not in ranges


def test_float_fma_macro_is_fmaf_under_fp_fast_fmaf():
    lines = c_printer.fma_macro_lines(FLOAT)
    assert "#if defined(FP_FAST_FMAF)" in lines
    assert "#define DERIVE_FMA(a, b, c) fmaf((a), (b), (c))" in lines
    assert c_printer.fma_macro_lines(DOUBLE) == c_printer.FMA_MACRO_LINES
    assert "#define DERIVE_FMA(a, b, c) fma((a), (b), (c))" in c_printer.FMA_MACRO_LINES


@pytest.mark.parametrize("value", [0.1, 1.0 / 3.0, 2.0**-126, 3.4e38, -123456.789, 1e-30,
                                   0.0033333333333333335, 16777217.0])
def test_a_float_literal_is_the_float_nearest_the_double_and_reads_back(value):
    text = FLOAT.literal(value)
    assert text.endswith("f") and ("." in text or "e" in text)
    assert np.float32(text[:-1]) == np.float32(value)  # the nearest float, exactly
    assert len(text[:-1].lstrip("-").replace(".", "").split("e")[0].lstrip("0")) <= 9
    assert c_printer.CPrinter(precision=FLOAT).expression(Const(value)) == (
        f"({text})" if value < 0 else text)


@pytest.mark.parametrize("value", [2.0**-1022, 1e-40, 1e39])
def test_a_constant_float_cannot_hold_is_refused(value):
    """DBL_MIN would be 0 in float code (0 / 0 in the UD pivots); 1e39 infinite."""
    with pytest.raises(PrecisionError, match=r"is not a normal float32 number"):
        FLOAT.literal(value)


def test_udkf_floors_its_pivots_with_flt_min_in_float():
    files = _files("mpt3d_a", "udkf", "c", {"precision": "float"})
    floor = FLOAT.literal(FLOAT.least_normal)
    assert f"+ {floor}" in files["udkf.c"] or f"{floor} + " in files["udkf.c"]
    assert "d + FLT_MIN (2^-126)" in files["udkf.h"]
    double = _files("mpt3d_a", "udkf", "c")
    assert "d + DBL_MIN (2^-1022)" in double["udkf.h"]


def test_the_interface_line_carries_the_element_type():
    for precision, element in (("float", "float"), ("double", None)):
        header = _files("cv", "kf", "c", {"precision": precision})["kf.h"]
        line = next(x for x in header.splitlines() if interface.MARKER in x)
        data = json.loads(line.split(interface.MARKER, 1)[1])
        assert data.get("element") == element  # absent: double, as before the option
        assert interface.read(header).dtype == ("float32" if element else "float64")
    header = _files("cv", "kf", "c", {"precision": "float"})["kf.h"]
    assert " * precision: float32 (C float)" in header
    assert "operations per call of step (C99 float32" in header
    python = _files("cv", "kf", "python", {"precision": "float"})["kf.py"]
    assert "precision: double (float64); the C of this filter is float32" in python
    assert "--precision float" in python  # the regenerate command


def test_an_unknown_precision_is_refused_naming_the_option():
    with pytest.raises(OptionError, match=r"'precision' \(--precision\) must be one of "
                                          r"double, float, got 'half'"):
        _files("cv", "kf", "c", {"precision": "half"})


@needs_gcc
def test_a_float_kernel_takes_float32_and_refuses_float64_in_one_line():
    kernel = load_generated("cv", "kf", {"precision": "float"}, "c").c
    zs = np.linspace(0.0, 1.0, 8, dtype=np.float32)[:, np.newaxis]
    x0, P0 = np.zeros(2, np.float32), np.eye(2, dtype=np.float32)
    xs, Ps = kernel.run(zs, x0, P0)
    assert xs.dtype == np.float32 and Ps.dtype == np.float32 and xs.shape == (8, 2)
    with pytest.raises(DtypeError) as caught:
        kernel.run(zs.astype(np.float64), x0, P0)
    message = str(caught.value)
    assert "\n" not in message
    assert message == ("cv_kf_run: argument 'z' is a float64 array, but this kernel is "
                       "float32 (C float): pass np.asarray(z, dtype=np.float32)")
    with pytest.raises(DtypeError, match=r"argument 'x' is a float64 list of Python floats"):
        kernel.step([0.0, 0.0], [1.0, 0.0, 0.0, 1.0], [0.5])
    with pytest.raises(DtypeError, match=r"cv_kf_run_tracks: argument 'x0' is a float64"):
        kernel.run_tracks(zs[np.newaxis], x0[np.newaxis].astype(float), P0[np.newaxis])
    tracks, _ = kernel.run_tracks(zs[np.newaxis], x0[np.newaxis], P0[np.newaxis])
    assert np.array_equal(tracks[0], xs)  # run_tracks is bitwise run, in float too


@pytest.mark.parametrize("value, named", [
    ("1e39", "parameter sq2 = 1e+39: the constant 1e+39"),
    ("1e-37", "matrix G Q G^T[0][0] = 2.5e-42: the constant 2.5e-42")])
def test_a_model_float_cannot_hold_is_refused_on_the_command_line(tmp_path, capsys, value,
                                                                  named):
    """A process noise density of 1e39 is infinite as a float, and one of 1e-37 with
    dt = 0.01 puts 2.5e-42 into G Q G^T (the KF bakes them into its code): exit status
    2, one line naming the parameter or the matrix entry (a derived constant was named
    alone), before any derivation; no output directory written; the same model in
    double is generated."""
    text = (ROOT / "derive" / "catalog" / "mpt3d_b.toml").read_text()
    model = tmp_path / "tiny.toml"
    model.write_text(text.replace('name = "mpt3d_b"', 'name = "tiny"').replace(
        "sq2 = { value = 0.01,", f"sq2 = {{ value = {value},").replace(
        "dt = { value = 1,", "dt = { value = 0.01,"))
    out = tmp_path / "out"
    status = main(["generate", str(model), "--filter", "kf", "--precision", "float",
                   "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and "\n" not in err and not out.exists()
    assert err.startswith(f"derive: error: model 'tiny': {named} is not a normal float32 ")
    assert "--precision float" in err
    assert main(["generate", str(model), "--filter", "kf", "--out", str(out)]) == 0


@needs_gcc
def test_batch_run_tracks_threads_a_float_kernel_in_float32():
    """derive.batch on a float kernel: float32 in and out, each track bitwise its run."""
    kernel = load_generated("cv", "kf", {"precision": "float"}, "c").c
    rng = np.random.default_rng(3)
    zs = rng.normal(size=(5, 20, 1)).astype(np.float32)
    x0s, P0 = np.zeros((5, 2), np.float32), np.eye(2, dtype=np.float32)
    xs, Ps = batch.run_tracks(kernel, zs, x0s, P0, workers=2)
    assert xs.dtype == np.float32 and Ps.dtype == np.float32
    for track in range(5):
        assert np.array_equal(xs[track], kernel.run(zs[track], x0s[track], P0)[0])
    with pytest.raises(DtypeError, match=r"argument 'zs' is a float64 array"):
        batch.run_tracks(kernel, zs.astype(np.float64), x0s, P0, workers=2)


@pytest.mark.parametrize("model, name", [("mpt3d_a", "kf"), ("ca", "udkf"), ("cv", "sskf"),
                                         ("gnss_pseudorange", "ukf")])
def test_float_code_counts_the_same_operations_as_double(model, name):
    """Precision changes types, literals and function names, never the operations: every
    count line of the float header is the double header's, with float32 named."""
    def counts(options):
        header = _files(model, name, "c", options)[f"{name}.h"]
        return [line for line in header.splitlines() if "operations per" in line]

    double, single = counts(None), counts({"precision": "float"})
    assert double and single == [line.replace("(C99", "(C99 float32") for line in double]
