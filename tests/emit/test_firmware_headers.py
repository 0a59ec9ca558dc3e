"""Headers a firmware project can use: included together from C and C++ (restrict behind a
macro), a status enum per file named from the statuses the header lists, ``--prefix`` in
front of every exported name, and headers of two models on one include path
(``-I OUT``, ``#include "MODEL/FILTER.h"``) that never collide."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from derive import generate, interface
from derive.build import STRICT_CFLAGS, build_c
from derive.cli import main
from derive.emit.render import render_c
from derive.errors import OptionError
from derive.filters import derive_unit
from derive.model import LinearModel

GCC, GXX, NM = shutil.which("gcc"), shutil.which("g++"), shutil.which("nm")
needs_gcc = pytest.mark.skipif(GCC is None, reason="no C compiler")
needs_gxx = pytest.mark.skipif(GXX is None or GCC is None, reason="no C++ compiler")
CXX_FLAGS = ["-std=c++11", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def _axis(name: str) -> LinearModel:
    dt = 0.5
    return LinearModel(name, ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, 0]], [[0.02]], [[0.3]],
                       G=[[dt / 2], [1]], x0=[0, 0], P0=[[1, 0.2], [0.2, 2]],
                       P0_pattern="dense")


#: Both case-differing models and two filters of each, in ONE output directory.
MAIN = """\
#include "Axis/kf.h"
#include "axis/kf.h"
#include "Axis/sskf.h"
#include "axis/sskf.h"
#include "Axis/kf.h"

int main(void)
{
    double x[Axis_kf_N] = {0.0, 0.0}, P[Axis_kf_N * axis_kf_N] = {1.0, 0.0, 0.0, 1.0};
    double z[axis_kf_M] = {1.0}, x1[2], P1[4], x2[2], P2[4], x3[2];
    int status = Axis_kf_step(x, P, z, x1, P1) + axis_kf_step(x, P, z, x2, P2);
    enum Axis_kf_status ok = Axis_kf_STATUS_OK;
    axis_sskf_step(x, z, x3);
    return status != (int)ok || x1[0] != x2[0] || Axis_sskf_N != 2 || !(x3[0] == x3[0]);
}
"""


def _both_models(tmp_path):
    out = tmp_path / "out"
    for name in ("Axis", "axis"):
        generate(_axis(name), ["kf", "sskf"], "c", out)
    return out


def _objects(out, tmp_path) -> list[str]:
    objects = []
    for c_file in sorted(out.glob("*/*.c")):
        obj = tmp_path / f"{c_file.parent.name}_{c_file.stem}.o"
        subprocess.run([GCC, *STRICT_CFLAGS, "-c", str(c_file), "-o", str(obj)], check=True,
                       capture_output=True, text=True)
        objects.append(str(obj))
    return objects


def _link_and_run(compiler, flags, source, out, objects, tmp_path):
    obj = source.with_suffix(".o")
    done = subprocess.run([compiler, *flags, "-I", str(out), "-c", str(source), "-o", str(obj)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    program = source.with_suffix("")
    subprocess.run([compiler, str(obj), *objects, "-o", str(program), "-lm"], check=True)
    assert subprocess.run([str(program)], timeout=60).returncode == 0


@needs_gcc
def test_two_models_differing_in_case_and_two_filters_included_together_from_c(tmp_path):
    out = _both_models(tmp_path)
    assert sorted(p.parent.name + "/" + p.name for p in out.glob("*/*.h")) == [
        "Axis/kf.h", "Axis/sskf.h", "axis/kf.h", "axis/sskf.h"]
    source = tmp_path / "main.c"
    source.write_text(MAIN)
    _link_and_run(GCC, STRICT_CFLAGS, source, out, _objects(out, tmp_path), tmp_path)


@needs_gxx
def test_two_models_differing_in_case_and_two_filters_included_together_from_cpp(tmp_path):
    out = _both_models(tmp_path)
    source = tmp_path / "main.cpp"
    source.write_text(MAIN)
    _link_and_run(GXX, CXX_FLAGS, source, out, _objects(out, tmp_path), tmp_path)


def test_prototypes_spell_restrict_by_the_guarded_macro():
    out_text = _header_text(_axis("Axis"), "kf")
    prototypes = [line for line in out_text.splitlines() if line.startswith(("int ", "void "))]
    assert prototypes and not any(re.search(r"\brestrict\b", p) for p in prototypes)
    assert "const double *DERIVE_RESTRICT x" in prototypes[0]
    assert out_text.count("#ifndef DERIVE_RESTRICT") == 1


def _header_text(model, name, **options) -> str:
    return render_c(derive_unit(model, name, options))[f"{name}.h"]


def _enum(header: str) -> dict[str, int]:
    body = re.search(r"enum \w+_status \{(.*?)\};", header, re.S)[1]
    return {name: int(value) for name, value in re.findall(r"(\w+) = (\d+)", body)}


@needs_gcc
@pytest.mark.parametrize("model, name", [("mpt3d_a", "kf"), ("cv", "udkf"), ("cv", "rts")])
def test_the_status_enum_names_every_status_the_header_lists(tmp_path, model, name):
    generate(model, [name], "c", tmp_path)
    header = (tmp_path / model / f"{name}.h").read_text()
    described = interface.read(header)
    prefix = f"{model}_{name}"
    expected = {f"{prefix}_STATUS_OK": 0} | {
        f"{prefix}_STATUS_{s.identifier()}": s.number for s in described.statuses}
    assert _enum(header) == expected and len(expected) == len(described.statuses) + 1
    # every status the header's list documents ("step 1: S is not positive definite ...")
    # is there by name, with the number C returns: checked by the compiler itself
    listed = re.findall(r"^ \*     (\w+) (\d+): ", header, re.M)
    assert len(listed) == len(described.statuses)
    checks = "".join(f"typedef char check_{i}[({c} == {v}) ? 1 : -1];\n"
                     for i, (c, v) in enumerate(expected.items()))
    source = tmp_path / "enum.c"
    source.write_text(f'#include "{model}/{name}.h"\n{checks}int main(void) {{ return 0; }}\n')
    done = subprocess.run([GCC, *STRICT_CFLAGS, "-Wno-unused-local-typedefs", "-I",
                           str(tmp_path), str(source), "-o", str(tmp_path / "enum")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    names = [s.identifier() for s in described.statuses]
    assert any(n.startswith(("STEP_S_NOT_POSITIVE_DEFINITE_", "ENTER_P_NOT_POSITIVE_SEMIDEFINITE_"))
               for n in names)
    # numbered across the file's programs (a status names one check): 1, 2, ... in order
    assert [s.number for s in described.statuses] == list(range(1, len(names) + 1))


def test_status_names_are_stable():
    assert interface.Status("step", 1, "S is not positive definite: pivot 0 of its LDL^T "
                            "factorisation is not positive").identifier() \
        == "STEP_S_NOT_POSITIVE_DEFINITE_1"
    assert interface.Status("step", 4, "P has a non-zero entry outside the pattern (x..)",
                            (1, 2)).identifier() == "STEP_P_OUTSIDE_PATTERN_4"
    assert interface.Status("backward", 2, "P(k+1/k) is not positive definite: pivot 1"
                            ).identifier() == "BACKWARD_P_K_1_K_NOT_POSITIVE_DEFINITE_2"


@needs_gcc
@pytest.mark.skipif(NM is None, reason="no nm")
def test_prefix_renames_every_exported_name_and_build_c_still_loads_it(tmp_path):
    generate("mpt3d_a", ["kf", "rts"], "all", tmp_path, options={"prefix": "acme_"})
    for name in ("kf", "rts"):
        header = (tmp_path / "mpt3d_a" / f"{name}.h").read_text()
        defined = re.findall(r"^#define (\w+)", header, re.M)
        enum = _enum(header)
        assert defined and enum
        assert all(d.startswith("acme_") for d in defined + list(enum)), defined
        assert re.search(r"^#ifndef (\w+)", header, re.M)[1] == f"acme_DERIVE_mpt3d_a_{name}_H"
        assert f"enum acme_mpt3d_a_{name}_status" in header
        assert "--prefix acme_" in header.split("*/")[0]  # the regenerate command
        obj = tmp_path / f"{name}.o"
        subprocess.run([GCC, *STRICT_CFLAGS, "-c", str(tmp_path / "mpt3d_a" / f"{name}.c"),
                        "-o", str(obj)], check=True)
        symbols = subprocess.run([NM, "-g", "--defined-only", str(obj)], check=True,
                                 capture_output=True, text=True).stdout.split()[2::3]
        assert symbols and all(s.lstrip("_").startswith(f"acme_mpt3d_a_{name}_")
                               for s in symbols), symbols
    module = build_c([tmp_path / "mpt3d_a" / "kf.c", tmp_path / "mpt3d_a" / "rts.c"])
    kf = module["acme_mpt3d_a_kf"]
    x, P = kf.step(np.zeros(6), np.eye(6), np.ones(3))
    assert x.shape == (6,) and P.size == 36 and np.isfinite(P).all()
    assert set(module.filters) == {"acme_mpt3d_a_kf", "acme_mpt3d_a_rts"}


def test_prefix_is_refused_unless_it_makes_identifiers(tmp_path, capsys):
    for bad in ("1x", "_x", "a-b", "a b"):
        with pytest.raises(OptionError, match=r"'prefix' \(--prefix\) must be empty or a "
                                              "letter"):
            generate("cv", ["kf"], "c", tmp_path, options={"prefix": bad})
    assert not (tmp_path / "cv").exists()
    assert main(["generate", "cv", "--filter", "kf", "--out", str(tmp_path), "--prefix",
                 "9"]) == 2
    err = capsys.readouterr().err
    assert "--prefix" in err and "Traceback" not in err and err.count("\n") == 1
