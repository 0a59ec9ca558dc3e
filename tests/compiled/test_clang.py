"""The generated C under Clang (the compiler of many flight-controller and receiver
toolchains, and of every Mac): every catalog file of both precisions compiles with the
strict flags (float also with the conversion warnings), its headers as C++, the catalog
filters built by Clang agree with the NumPy reference within ``derive verify``'s bars, and
the Clang branches of the block lanes (vector types, ``__builtin_shufflevector``,
``__builtin_elementwise_fma``) and of run_tracks (``clang loop vectorize``) give the bits
of their scalar runs, and of the GCC build whose DERIVE_FMA is the same operation (Clang 14
defines no FP_FAST_FMA: its DERIVE_FMA is a product and a sum, kept two roundings by the
file's ``#pragma STDC FP_CONTRACT OFF`` against Clang's default -ffp-contract=on).

Skipped, with the reason, where clang is not installed (.ci/run installs it). The catalog
of each precision is one extension (build_c compiles its files one process per core), and
so are the block-lane filters of each build setting.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_perf_block_lanes import CASES, FLAGS, SCALAR, _data, _run

from derive import catalog
from derive.apps.verify import verify_modules
from derive.build import CONVERSION_CFLAGS
from derive.filters import available
from derive.generation import command_unit
from derive.pipeline import load_units

ROOT = Path(__file__).resolve().parents[2]
CLANG, CLANGXX, GCC = shutil.which("clang"), shutil.which("clang++"), shutil.which("gcc")
pytestmark = pytest.mark.skipif(CLANG is None or CLANGXX is None,
                                reason="clang is not installed (Debian: apt-get install clang)")
CXX_FLAGS = ["-std=c++11", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
PRECISIONS = ("double", "float")
#: The block-lane filters (tests/performance/test_perf_block_lanes.py's, and the predictor's).
LANE_CASES = CASES + [("mpt3d_a", "pred"), ("gps_static", "pred")]
#: test_perf_block_lanes' build settings under Clang, less ``contract``: Clang's
#: -ffp-contract=fast disregards the file's pragma by its definition (as -ffast-math
#: would under either compiler), so a build that asks for it gets fused operations the
#: header does not count (docs/generated-code.md); and less ``gnu``: -std=gnu99 changes
#: GCC's contraction default, not Clang's (on, in every mode: the pragma turns it off).
CLANG_FLAGS = {name: flags for name, flags in FLAGS.items() if name not in ("contract", "gnu")}


def _catalog_units(precision: str):
    """Every catalog filter that applies, in ``precision``: (units, their models)."""
    units, models = [], []
    for name in catalog.names():
        model = catalog.load(name)
        for filter_name in available(model):
            units.append(command_unit(model, filter_name, {"precision": precision}, name))
            models.append(model)
    return units, models


@pytest.mark.parametrize("precision", PRECISIONS)
def test_the_catalog_built_by_clang_compiles_strictly_and_agrees_with_the_reference(
        tmp_path, precision):
    """Every catalog filter, written to a folder and built by Clang (build_c's
    ``compiler``) into one extension: each file compiled with ``clang -std=c99 -O2 -Wall
    -Wextra -Werror -pedantic -Wdouble-promotion -Wfloat-conversion -Wconversion`` (the
    double files are the committed ones, tests/emit/test_determinism.py), all headers of the
    precision included together by one C++ file under ``clang++ -std=c++11 -Wall -Wextra
    -Werror -pedantic``, and every filter verified as ``derive verify`` does: double 1e-12
    relative for linear filters (or the double bound where the model's conditioning puts
    it higher), nonlinear 1e-10 or 4x the reference's floor; float32 the tolerance derived
    for each filter (derive.apps.float_tolerance), every catalog bound meaningful.
    One test a precision, so that each catalog is built once under pytest-xdist."""
    options = {"precision": precision}
    units, models = _catalog_units(precision)
    root = tmp_path / "out"
    loaded = load_units(units, "c", root, extra_cflags=CONVERSION_CFLAGS, compiler="clang")

    written = sorted(p.relative_to(root).as_posix() for p in root.glob("*/*.c"))
    committed = sorted(p.relative_to(ROOT / "generated").as_posix()
                       for p in (ROOT / "generated").glob("*/*.c"))
    assert written == committed
    if precision == "double":   # the same code (the comment's regenerate line aside)
        for name in written:
            assert (root / name).read_text().split("*/", 1)[1] == \
                (ROOT / "generated" / name).read_text().split("*/", 1)[1], name

    headers = sorted(p.relative_to(root).as_posix() for p in root.glob("*/*.h"))
    assert len(headers) == len(written)
    source = tmp_path / "headers.cpp"
    source.write_text("".join(f'#include "{h}"\n' for h in headers)
                      + "int main() { return 0; }\n")
    proc = subprocess.run([CLANGXX, *CXX_FLAGS, "-I", str(root), "-c", str(source), "-o",
                           str(tmp_path / "headers.o")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[:3000]

    results = [verify_modules(model, g.unit.filter, {"c": g.c}, 1000, 7, options, g.unit)[0]
               for model, g in zip(models, loaded)]
    failed = [r.line() for r in results if not r.passed]
    assert not failed, "\n".join(failed)
    if precision == "float":
        assert all(r.bound is not None and r.bound.meaningful for r in results)


def _lane_units():
    return [command_unit(catalog.load(model_name), filter_name, None, model_name)
            for model_name, filter_name in LANE_CASES]


@functools.cache
def _lane_builds(compiler: str, flags: tuple[str, ...]):
    """(vector build, scalar build) of every LANE_CASES filter, each one extension."""
    units = _lane_units()
    return (load_units(units, "c", extra_cflags=flags, compiler=compiler),
            load_units(units, "c", extra_cflags=flags + SCALAR, compiler=compiler))


def _outputs(generated, z, x0, P0) -> list[np.ndarray]:
    covariance = "P0" in {a.name for a in generated.c.functions["run"].arguments}
    return _run(generated.c, covariance, z, x0, P0)


def _bitwise(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(np.array_equal(x.view(np.uint64), y.view(np.uint64))
                                    for x, y in zip(a, b))


def _defines_fast_fma(compiler: str, flags: tuple[str, ...]) -> bool:
    """Whether math.h's FP_FAST_FMA is defined under ``flags`` (then the file's DERIVE_FMA
    is fma(), else a product and a sum)."""
    proc = subprocess.run([compiler, "-std=c99", *flags, "-E", "-x", "c", "-"],
                          input="#include <math.h>\n#ifdef FP_FAST_FMA\nfast\n#endif\n",
                          capture_output=True, text=True, check=True)
    return "fast" in proc.stdout.split()


@pytest.fixture(scope="module")
def gcc_lane_runs():
    """The GCC scalar runs of LANE_CASES, by whether their DERIVE_FMA is fma()."""
    if GCC is None:
        return {}
    runs = {}
    for flags in ((), ("-O3", "-march=native")):
        fused = _defines_fast_fma(GCC, flags)
        if fused not in runs:
            scalar = load_units(_lane_units(), "c", extra_cflags=flags + SCALAR,
                                compiler=GCC)
            runs[fused] = [_outputs(g, *_data(m)) for g, (m, _) in zip(scalar, LANE_CASES)]
    return runs


@pytest.mark.parametrize("flags", list(CLANG_FLAGS))
def test_clangs_vector_runs_are_bitwise_its_scalar_runs_and_gccs(flags, gcc_lane_runs):
    """The vector run (DERIVE_VECTOR: Clang's vector types, shuffles and fma) gives
    the bits of the scalar C99 run, as under GCC (tests/performance/test_perf_block_lanes.py); and
    where the build does not define DERIVE_FMA itself, the bits of GCC's scalar run whose
    DERIVE_FMA is the same operation: no operation Clang fused or reordered."""
    vector, scalar = _lane_builds("clang", CLANG_FLAGS[flags])
    own_fma = any(f.startswith("-DDERIVE_FMA") for f in CLANG_FLAGS[flags])
    fused = _defines_fast_fma(CLANG, CLANG_FLAGS[flags])
    for index, (v, s, (model_name, filter_name)) in enumerate(zip(vector, scalar, LANE_CASES)):
        z, x0, P0 = _data(model_name)
        got, want = _outputs(v, z, x0, P0), _outputs(s, z, x0, P0)
        assert _bitwise(got, want), (model_name, filter_name)
        if not own_fma and fused in gcc_lane_runs:
            assert _bitwise(got, gcc_lane_runs[fused][index]), (model_name, filter_name)
    assert own_fma or GCC is None or fused in gcc_lane_runs


@pytest.mark.parametrize("flags", ["plain", "native"])
def test_clangs_run_tracks_gives_each_track_its_run_bitwise(flags):
    """run_tracks' lane loop (``clang loop vectorize(assume_safety)``: no lane depends on
    another) gives each track the bits of run on that track, the last tracks fewer than a
    block of lanes included."""
    vector, _ = _lane_builds("clang", CLANG_FLAGS[flags])
    for generated, (model_name, _) in zip(vector, LANE_CASES):
        if "run_tracks" not in generated.c.functions:
            continue   # the predictor's run alone
        z, x0, P0 = _data(model_name)
        tracks = 67   # two blocks of DERIVE_LANES (AVX-512: 32 doubles), 3 by run
        rng = np.random.default_rng(3)
        zs = z[None] * (1 + 0.01 * rng.standard_normal((tracks, 1, 1)))
        x0s = np.repeat(x0[None], tracks, axis=0) + rng.standard_normal((tracks, len(x0)))
        covariance = "P0" in {a.name for a in generated.c.functions["run"].arguments}
        if covariance:
            P0s = np.repeat(P0[None], tracks, axis=0)
            got = list(generated.c.run_tracks(zs, x0s, P0s))
        else:
            got = [generated.c.run_tracks(zs, x0s)]
        for t in range(tracks):
            want = _run(generated.c, covariance, zs[t], x0s[t], P0 if covariance else None)
            assert _bitwise([g[t] for g in got], want), (model_name, t)
