"""Model files: the documented examples load, every format error is a ModelFileError that
names the file, table and key, and no input gives anything but a model or a ModelError."""

import os
import re
from pathlib import Path

import pytest
import sympy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from derive import catalog
from derive.errors import (
    ExpressionError,
    MatrixPropertyError,
    ModelError,
    ModelFileError,
    ShapeError,
)
from derive.model import LinearModel, NonlinearModel
from derive.modelfile import load_model_file, loads_model

DOCS = Path(__file__).resolve().parents[2] / "docs" / "model-files.md"
dt, sq2, sr2, r = (sympy.Symbol(n, real=True) for n in ("dt", "sq2", "sr2", "r"))

AXIS = """\
[model]
name = "axis"
description = "one axis"
states = ["s", "v"]
measurements = ["z"]

[parameters]
dt = 1
sq2 = { value = 0.01, description = "process noise" }
sr2 = { value = 0.1 }

[discrete]
F = [[1, "dt"], [0, 1]]
G = [["dt/2"], [1]]
H = [[1, "dt"]]
Q = "sq2"
R = "sr2"

[initial]
x0 = [0, 0]
P0 = [[0, 0], [0, 0]]
P0_pattern = "zero"
"""

NONLINEAR = """\
[model]
name = "range"
states = ["x", "y"]
measurements = ["d"]

[parameters]
q = 0.01
s2 = { description = "free range variance" }

[nonlinear]
inputs = ["xs", "ys"]
f = ["x", "y"]
h = ["sqrt((xs - x)**2 + (ys - y)**2)"]
Q = [["q", 0], [0, "q"]]
R = "s2"
"""


def doc_examples() -> list[tuple[str, str]]:
    """(file name, text) of every ```toml block of docs/model-files.md."""
    blocks = re.findall(r"```toml\n(.*?)```", DOCS.read_text(encoding="utf-8"), re.S)
    return [(re.match(r"# file: (\S+)", block).group(1), block) for block in blocks]


def test_documented_examples_load(tmp_path):
    examples = doc_examples()
    assert [name for name, _ in examples] == ["axis.toml", "cart.toml", "ca.toml", "gnss.toml",
                                              "plane.toml", "unicycle.toml", "cart2.toml",
                                              "attitude.toml"]
    for name, text in examples:
        (tmp_path / name).write_text(text, encoding="utf-8")
    axis = load_model_file(tmp_path / "axis.toml")
    assert isinstance(axis, LinearModel) and (axis.n, axis.m) == (2, 1)
    assert [p.name for p in axis.parameters] == ["r"]
    ca = load_model_file(tmp_path / "ca.toml")
    half = sympy.Rational(1, 2)
    assert ca.matrix("F") == sympy.Matrix([[1, half, half**2 / 2], [0, 1, half], [0, 0, 1]])
    gnss = load_model_file(tmp_path / "gnss.toml")
    assert isinstance(gnss, NonlinearModel) and (gnss.n, gnss.m) == (4, 4)
    assert gnss.P0 == sympy.eye(4) * 10**4
    plane = load_model_file(str(tmp_path / "plane.toml"))
    assert plane.states == ("sx", "vx", "sy", "vy")
    assert [p.name for p in plane.parameters] == ["r"]
    assert plane.R == sympy.diag(sr2, r)
    unicycle = load_model_file(tmp_path / "unicycle.toml")
    assert [u.name for u in unicycle.f_inputs] == ["v", "w"]
    assert unicycle.subs(unicycle.Qu) == sympy.diag(sympy.Rational(1, 100),
                                                    sympy.Rational(4, 10000))


def test_discrete_file_gives_the_declared_matrices_exactly():
    model = loads_model(AXIS, source="axis.toml")
    assert model.F == sympy.Matrix([[1, dt], [0, 1]])
    assert model.G == sympy.Matrix([[dt / 2], [1]])
    assert model.H == sympy.Matrix([[1, dt]])
    assert model.Q == sympy.Matrix([[sq2]]) and model.R == sympy.Matrix([[sr2]])
    assert model.values == {"dt": 1, "sq2": sympy.Rational(1, 100), "sr2": sympy.Rational(1, 10)}
    assert model.P0_pattern == "zero" and model.P0 == sympy.zeros(2, 2)
    assert model.description == "one axis"


def test_toml_floats_are_exact_rationals():
    text = AXIS.replace('F = [[1, "dt"], [0, 1]]', 'F = [[1, 0.1], [0, 1]]')
    text = text.replace('H = [[1, "dt"]]', 'H = [[1, "dt * 0.3"]]')
    model = loads_model(text)
    assert model.F[0, 1] == sympy.Rational(1, 10)
    assert model.H[0, 1] == sympy.Rational(3, 10) * dt


def test_scalars_flat_columns_and_free_parameters():
    text = AXIS.replace('G = [["dt/2"], [1]]', 'G = ["dt/2", 1]').replace(
        "sr2 = { value = 0.1 }", 'sr2 = { description = "free" }')
    model = loads_model(text)
    assert model.G == sympy.Matrix([[dt / 2], [1]])
    assert [p.name for p in model.parameters] == ["sr2"]


def test_initial_values_use_valued_parameters():
    text = AXIS.replace("P0 = [[0, 0], [0, 0]]", 'P0 = [["sr2", 0], [0, "2*sq2"]]').replace(
        'P0_pattern = "zero"', 'P0_pattern = "diagonal"')
    model = loads_model(text)
    assert model.P0 == sympy.diag(sympy.Rational(1, 10), sympy.Rational(1, 50))


def test_parameter_used_only_in_initial_is_substituted_not_passed():
    text = AXIS.replace("[parameters]", "[parameters]\np0 = 5").replace(
        "P0 = [[0, 0], [0, 0]]", 'P0 = [["p0", 0], [0, "p0"]]').replace(
        'P0_pattern = "zero"', 'P0_pattern = "dense"')
    model = loads_model(text)
    assert model.P0 == 5 * sympy.eye(2)
    assert "p0" not in model.values


def test_nonlinear_file():
    model = loads_model(NONLINEAR)
    x, y, xs, ys = (sympy.Symbol(n, real=True) for n in ("x", "y", "xs", "ys"))
    assert model.h[0] == sympy.sqrt((xs - x) ** 2 + (ys - y) ** 2)
    assert model.inputs == (xs, ys)
    assert [p.name for p in model.parameters] == ["s2"]
    assert model.Q == sympy.eye(2) * sympy.Symbol("q", real=True)


def test_continuous_file_discretises():
    text = """
[model]
name = "cv"
states = ["s", "v"]
measurements = ["z"]
[parameters]
dt = { description = "free step" }
sq2 = 0.01
sr2 = 0.1
[continuous]
Phi = [[0, 1], [0, 0]]
G = [0, 1]
Qc = "sq2"
H = [[1, 0]]
R = "sr2"
dt = "dt"
"""
    model = loads_model(text)
    # the free time step of [continuous] is nonnegative by default (its declared domain)
    step = sympy.Symbol("dt", real=True, nonnegative=True)
    assert model.F == sympy.Matrix([[1, step], [0, 1]])
    expected = sq2 * sympy.Matrix([[step**3 / 3, step**2 / 2], [step**2 / 2, step]])
    assert (model.Q - expected).applyfunc(sympy.simplify) == sympy.zeros(2, 2)


# -- errors ------------------------------------------------------------------------------

def _edit(old, new, base=AXIS):
    assert old in base, old
    return base.replace(old, new)


ERRORS = [
    ("not toml", "[model\nname = 1", ModelFileError, ["not valid TOML", "line 1"]),
    ("empty", "", ModelFileError, ["empty"]),
    ("duplicate key", _edit("description = ", 'name = "again"\ndescription = '),
     ModelFileError, ["not valid TOML", "the key 'name' is set twice"]),
    ("blank", " \n\n", ModelFileError, ["empty"]),
    ("unknown key", _edit("description = ", "descripton = "), ModelFileError,
     ["[model]", "unknown key 'descripton'", "did you mean 'description'?"]),
    ("unknown table", _edit("[discrete]", "[discrate]"), ModelFileError,
     ["unknown table 'discrate'", "did you mean 'discrete'?"]),
    ("unknown matrix", _edit('G = [["dt/2"], [1]]', 'g = [["dt/2"], [1]]'), ModelFileError,
     ["[discrete]", "unknown key 'g'", "did you mean 'G'?"]),
    ("unknown parameter key", _edit("{ value = 0.1 }", "{ valeu = 0.1 }"), ModelFileError,
     ["[parameters] sr2", "unknown key 'valeu'", "did you mean 'value'?"]),
    ("unknown initial key", _edit("x0 = [0, 0]", "xo = [0, 0]"), ModelFileError,
     ["[initial]", "unknown key 'xo'", "did you mean 'x0'?"]),
    ("missing key", _edit('H = [[1, "dt"]]\n', ""), ModelFileError,
     ["[discrete]", "missing required key 'H'"]),
    ("missing name", _edit('name = "axis"\n', ""), ModelFileError,
     ["[model]", "missing required key 'name'"]),
    ("missing states", _edit('states = ["s", "v"]\n', ""), ModelFileError,
     ["[model]", "missing required key 'states'"]),
    ("missing model", AXIS[AXIS.index("[parameters]"):], ModelFileError,
     ["[model]", "missing table"]),
    ("no kind", AXIS[:AXIS.index("[discrete]")], ModelFileError,
     ["exactly one of [discrete]", "found none"]),
    ("two kinds", AXIS + "[nonlinear]\nf = [1]\n", ModelFileError,
     ["found [discrete], [nonlinear]"]),
    ("states not list", _edit('states = ["s", "v"]', 'states = "s"'), ModelFileError,
     ["[model] states", "must be a list of strings", "got string"]),
    ("states not strings", _edit('states = ["s", "v"]', 'states = ["s", 3]'), ModelFileError,
     ["[model] states", "must be a list of strings"]),
    ("states empty", _edit('states = ["s", "v"]', "states = []"), ModelFileError,
     ["[model] states", "must not be empty"]),
    ("state twice", _edit('states = ["s", "v"]', 'states = ["s", "s"]'), ModelFileError,
     ["[model] states", "'s' appears twice"]),
    ("bad state name", _edit('states = ["s", "v"]', 'states = ["s", "2v"]'), ModelFileError,
     ["[model] states", "'2v' is not an identifier"]),
    ("underscore name", _edit('states = ["s", "v"]', 'states = ["s", "_v"]'), ModelFileError,
     ["[model] states", "underscore"]),
    ("model name type", _edit('name = "axis"', "name = 3"), ModelFileError,
     ["[model] name", "must be a string"]),
    ("description type", _edit('description = "one axis"', "description = 1"), ModelFileError,
     ["[model] description", "must be a string"]),
    ("model not a table", "model = 3\n" + AXIS[AXIS.index("[parameters]"):], ModelFileError,
     ["[model]", "must be a table, got int"]),
    ("ragged", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[1, "dt"], [0]]'), ModelFileError,
     ["[discrete] F", "not rectangular", "row 1 has 1"]),
    ("flat F", _edit('F = [[1, "dt"], [0, 1]]', 'F = [1, "dt"]'), ModelFileError,
     ["[discrete] F", "list of rows"]),
    ("mixed rows", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[1, "dt"], 0]'), ModelFileError,
     ["[discrete] F[1]", "must be a row"]),
    ("empty matrix", _edit('F = [[1, "dt"], [0, 1]]', "F = []"), ModelFileError,
     ["[discrete] F", "must not be empty"]),
    ("empty row", _edit('F = [[1, "dt"], [0, 1]]', "F = [[], []]"), ModelFileError,
     ["[discrete] F[0]", "row is empty"]),
    ("bool entry", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[true, "dt"], [0, 1]]'),
     ModelFileError, ["[discrete] F[0][0]", "must be a number or an expression string"]),
    ("table entry", _edit('Q = "sq2"', "Q = { a = 1 }"), ModelFileError,
     ["[discrete] Q", "got table"]),
    ("undeclared symbol", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[1, "dtt"], [0, 1]]'),
     ExpressionError, ["[discrete] F[0][1]", "unknown symbol 'dtt'", "did you mean 'dt'?"]),
    ("state in linear matrix", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[1, "s"], [0, 1]]'),
     ExpressionError, ["[discrete] F[0][1]", "unknown symbol 's'"]),
    ("unsafe expression", _edit('Q = "sq2"', "Q = \"__import__('os').system('true')\""),
     ExpressionError, ["[discrete] Q", "attribute access"]),
    ("inf entry", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[inf, "dt"], [0, 1]]'),
     ExpressionError, ["[discrete] F[0][0]", "'inf' is not a finite"]),
    ("nan value", _edit("dt = 1", "dt = nan"), ExpressionError,
     ["[parameters] dt", "'nan' is not a finite"]),
    ("string value", _edit("dt = 1", 'dt = "1"'), ModelFileError,
     ["[parameters] dt", "value must be a number, got string"]),
    ("bool value", _edit("dt = 1", "dt = false"), ModelFileError,
     ["[parameters] dt", "value must be a number, got bool"]),
    ("unused parameter", _edit("dt = 1", "dt = 1\nk = 2"), ModelFileError,
     ["[parameters] k", "used in no expression"]),
    ("parameter is a state", _edit("dt = 1", "dt = 1\ns = 2"), ModelFileError,
     ["[parameters] s", "also a state"]),
    ("parameter is a function", _edit("dt = 1", "dt = 1\nexp = 2"), ModelFileError,
     ["[parameters] exp", "reserved"]),
    ("parameter is pi", _edit("dt = 1", "dt = 1\npi = 3"), ModelFileError,
     ["[parameters] pi", "reserved"]),
    ("parameter is a C keyword", _edit("dt = 1", "dt = 1\nint = 2"), ModelFileError,
     ["[parameters] int", "reserved word"]),
    ("parameters not a table",
     "parameters = 3\n" + AXIS[:AXIS.index("[parameters]")] + AXIS[AXIS.index("[discrete]"):],
     ModelFileError, ["[parameters]", "must be a table, got int"]),
    ("pattern", _edit('"zero"', '"zeros"'), ModelFileError,
     ["[initial] P0_pattern", "'zeros' is not one of", "did you mean 'zero'?"]),
    ("pattern type", _edit('"zero"', "0"), ModelFileError,
     ["[initial] P0_pattern", "must be a string"]),
    ("x0 not list", _edit("x0 = [0, 0]", "x0 = 0"), ModelFileError,
     ["[initial] x0", "non-empty list"]),
    ("free parameter in P0", _edit("sr2 = { value = 0.1 }", "sr2 = {}").replace(
        "P0 = [[0, 0], [0, 0]]", 'P0 = [["sr2", 0], [0, 0]]'), ModelFileError,
     ["[initial] P0[0][0]", "free parameter 'sr2'"]),
    ("dt list", _edit("[discrete]", "[continuous]").replace(
        'F = [[1, "dt"], [0, 1]]', "Phi = [[0, 1], [0, 0]]\ndt = [1]\nQc = \"sq2\""
    ).replace('Q = "sq2"\n', ""), ModelFileError, ["[continuous] dt", "must be a number"]),
    ("input is a parameter", _edit("q = 0.01", "q = 0.01\nxs = 1", NONLINEAR), ModelFileError,
     ["[parameters] xs", "also an input"]),
    ("input is a state", _edit('inputs = ["xs", "ys"]', 'inputs = ["xs", "x"]', NONLINEAR),
     ModelFileError, ["[nonlinear] inputs", "'x' is also a state"]),
    ("f not a list", _edit('f = ["x", "y"]', 'f = "x"', NONLINEAR), ModelFileError,
     ["[nonlinear] f", "non-empty list"]),
    ("unknown symbol in nonlinear Q", _edit('Q = [["q", 0], [0, "q"]]',
                                            'Q = [["qq", 0], [0, "q"]]', NONLINEAR),
     ExpressionError, ["[nonlinear] Q[0][0]", "unknown symbol 'qq'"]),
    # Errors the model classes find keep their class and name the file.
    ("shape", _edit('F = [[1, "dt"], [0, 1]]', 'F = [[1, "dt", 0], [0, 1, 0]]'), ShapeError,
     ["m.toml: ", "F must be 2x2", "got 2x3"]),
    ("not positive", _edit('R = "sr2"', 'R = "-sr2"'), MatrixPropertyError,
     ["m.toml: ", "R must be positive definite"]),
    ("Qu shape", _edit('f = ["x", "y"]', 'f = ["x", "y + xs"]\nQu = [[1]]', NONLINEAR),
     ShapeError, ["m.toml: ", "matrix Qu must be 2x2"]),
]


@pytest.mark.parametrize("label, text, error, words", ERRORS, ids=[e[0] for e in ERRORS])
def test_errors_name_the_file_table_and_key(label, text, error, words):
    with pytest.raises(error) as info:
        loads_model(text, source="m.toml")
    message = str(info.value)
    assert message.startswith("m.toml: ")
    for word in words:
        assert word in message, (word, message)


def test_file_errors(tmp_path):
    with pytest.raises(ModelFileError, match=r"nope\.toml: cannot read model file"):
        load_model_file(tmp_path / "nope.toml")
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(AXIS.replace("one axis", "caf\xe9").encode("latin-1"))
    with pytest.raises(ModelFileError, match=r"latin1\.toml: not UTF-8 text"):
        load_model_file(bad)
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * 1_000_001 + "\n")
    with pytest.raises(ModelFileError, match=r"big\.toml: model file is more than \d+ bytes"):
        load_model_file(big)
    with pytest.raises(ModelFileError, match="cannot read model file"):
        load_model_file(tmp_path)


# -- composition -------------------------------------------------------------------------

def _compose(*blocks, states=None):
    lines = ['[model]', 'name = "both"']
    if states:
        lines.append(f"states = {states}")
    lines.append("[compose]")
    entries = ", ".join("{ " + ", ".join(f'{k} = "{v}"' for k, v in b.items()) + " }"
                        for b in blocks)
    lines.append(f"blocks = [{entries}]")
    return "\n".join(lines) + "\n"


def test_compose_files_and_catalog(tmp_path):
    (tmp_path / "axis.toml").write_text(AXIS)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "axis.toml").write_text(AXIS)
    (tmp_path / "both.toml").write_text(_compose(
        {"model": "axis.toml", "suffix": "x"}, {"model": "sub/axis.toml", "suffix": "y"},
        {"model": "mpt3d_b", "suffix": "z"}, states='["sx", "vx", "sy", "vy", "sz", "vz"]'))
    model = load_model_file(tmp_path / "both.toml")
    axis = loads_model(AXIS)
    assert model.F == sympy.diag(axis.F, axis.F, axis.F)
    assert model.measurements == ("zx", "zy", "zz")
    no_suffix = loads_model(_compose({"model": "mpt3d_b"}, {"model": "gsm2d_b"}))
    assert no_suffix.states == ("s0", "v0", "s1", "v1")


@pytest.mark.parametrize(
    "blocks, words",
    [
        ([{"model": "/etc/passwd"}], ["blocks[0] model", "relative path"]),
        ([{"model": "../outside.toml"}], ["blocks[0] model", "leaves the directory"]),
        ([{"model": "sub/../../outside.toml"}], ["leaves the directory"]),
        ([{"model": "link.toml"}], ["leaves the directory"]),
        ([{"model": "missing.toml"}], ["cannot read model file"]),
        ([{"model": "mpt3d_c"}], ["blocks[0] model", "unknown catalog model 'mpt3d_c'",
                                  "did you mean 'mpt3d_b'?"]),
        ([{"model": "gnss_pseudorange"}], ["is not a linear model"]),
        ([{"model": "self.toml"}], ["cycle", "self.toml -> ", "self.toml"]),
        ([{"model": "a.toml"}], ["cycle"]),
        ([{"model": "mpt3d_b", "suffix": "x"}, {"model": "mpt3d_b"}],
         ["suffix for every block or for none"]),
        ([{"model": "mpt3d_b", "sufix": "x"}], ["blocks[0]", "unknown key 'sufix'",
                                                "did you mean 'suffix'?"]),
        ([{"suffix": "x"}], ["blocks[0]", "missing required key 'model'"]),
    ],
)
def test_compose_errors(tmp_path, blocks, words):
    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    (tmp_path / "outside.toml").write_text(AXIS)
    os.symlink(tmp_path / "outside.toml", work / "link.toml")
    (work / "a.toml").write_text(_compose({"model": "b.toml"}))
    (work / "b.toml").write_text(_compose({"model": "a.toml"}))
    (work / "self.toml").write_text(_compose(*blocks))
    with pytest.raises(ModelFileError) as info:
        load_model_file(work / "self.toml")
    for word in words:
        assert word in str(info.value), (word, str(info.value))


def test_compose_rules():
    with pytest.raises(ModelFileError, match="needs a model file"):
        loads_model(_compose({"model": "axis.toml"}))
    with pytest.raises(ModelFileError, match=r"\[parameters\]: not allowed with \[compose\]"):
        loads_model("[parameters]\nk = 1\n" + _compose({"model": "mpt3d_b"}))
    with pytest.raises(ModelFileError, match=r"\[model\] states: declares \['s'\]"):
        loads_model(_compose({"model": "mpt3d_b"}, states='["s"]'))
    with pytest.raises(ModelFileError, match="non-empty list"):
        loads_model('[model]\nname = "a"\n[compose]\nblocks = []\n')
    with pytest.raises(ModelFileError, match=r"blocks\[0\]: must be a table"):
        loads_model('[model]\nname = "a"\n[compose]\nblocks = ["mpt3d_b"]\n')


def test_catalog_file_by_path_equals_catalog_load():
    for name in ("mpt3d_b", "mpt3d_a", "gnss_pseudorange"):
        by_path, by_name = load_model_file(catalog.path(name)), catalog.load(name)
        assert type(by_path) is type(by_name)
        for key in ("F", "H", "Q", "R") if name != "gnss_pseudorange" else ("f", "h", "Q", "R"):
            assert getattr(by_path, key) == getattr(by_name, key)


# -- fuzz: mutated model files give a model or a ModelError, nothing else ----------------

TOML_PIECES = ["[", "]", "{", "}", "\"", "'", "=", ",", "\n", "#", "0.1", "1e400", "inf",
               "nan", "true", "[[1]]", "\"dt\"", "\"__import__('os')\"", "x.y", "[model]",
               "[initial]", "P0_pattern", "\"zero\"", "states", "-", "**64", "\\", "\"\"\""]


@st.composite
def _mutated_file(draw):
    text = draw(st.sampled_from([AXIS, NONLINEAR, catalog.read_text("gps_static"),
                                 catalog.read_text("mpt3d_a")]))
    for _ in range(draw(st.integers(1, 3))):
        position = draw(st.integers(0, len(text)))
        piece = draw(st.sampled_from(TOML_PIECES) | st.text(max_size=3))
        action = draw(st.sampled_from(["insert", "delete", "replace"]))
        if action == "insert":
            text = text[:position] + piece + text[position:]
        elif action == "delete":
            text = text[:position] + text[position + draw(st.integers(1, 12)):]
        else:
            text = text[:position] + piece + text[position + len(piece):]
    return text


@settings(max_examples=300, deadline=5000, suppress_health_check=[HealthCheck.too_slow])
@given(_mutated_file())
def test_fuzz_mutated_model_files(text):
    try:
        model = loads_model(text, source="fuzz.toml")
    except ModelError as error:
        assert str(error).startswith("fuzz.toml: ") or "<catalog>/" in str(error)
        return
    assert isinstance(model, (LinearModel, NonlinearModel))


@settings(max_examples=200, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=200))
def test_fuzz_random_text_as_model_file(text):
    with pytest.raises(ModelError):
        loads_model(text, source="fuzz.toml")
