"""The renamed copies of a block lower to the block's operations in the same order
(``Program.order_names``, derive.filters.blockwise), so every blockwise filter of identical
blocks is identical up to naming and its C run carries the blocks in vector lanes
(derive.runs.blocks, derive.emit.c_lanes), bitwise the scalar run, with the counts
unchanged."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import sympy
from test_perf_block_lanes import FLAGS, _data, _pair, _run

from derive import LinearModel, catalog
from derive.emit import c_vector
from derive.emit.render import _lowered
from derive.filters import available
from derive.flops import count_lowered
from derive.generation import command_unit
from derive.lowering import lower_program
from derive.program import Port, Program
from derive.runs import blocks as block_split
from derive.statements import Assign, Temporary
from derive.trees import rename_tree

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
#: The time-varying filters derived block by block.
BLOCKWISE = ("kf", "lf", "jklf", "ikf")


def _axes(k: int, model: str) -> LinearModel:
    axis = catalog.load(model)
    return LinearModel.compose(f"{model}_x{k}", [axis] * k, [f"_{i}" for i in range(k)])


def _cases():
    models = {"mpt3d_a": catalog.load("mpt3d_a"), "gps_static": catalog.load("gps_static"),
              "gsm2d_a": catalog.load("gsm2d_a"), "ca_x4": _axes(4, "ca"),
              "cv_x5": _axes(5, "cv")}
    return [(name, model, f) for name, model in models.items() for f in BLOCKWISE
            if f in available(model)]


@pytest.mark.parametrize("name, model, filter_name", _cases(),
                         ids=[f"{c[0]}-{c[2]}" for c in _cases()])
def test_every_blockwise_filter_of_identical_blocks_splits_into_lanes(name, model,
                                                                       filter_name,
                                                                       monkeypatch):
    # two blocks (gsm2d_a) keep the scalar run, but are identical up to naming as well
    monkeypatch.setattr(block_split, "FEWEST_LANES", 2)
    step = _lowered(command_unit(model, filter_name), True)["step"].without_pattern_checks()
    lanes = block_split.split(step)
    assert lanes is not None, f"{name} {filter_name}: blocks differ beyond naming"
    blocks = len(lanes.inputs[("x", 0)])
    assert lanes.lanes == blocks
    whole = count_lowered(step).as_dict()
    one = count_lowered(lanes.block).as_dict()
    assert whole == {kind: blocks * n for kind, n in one.items()}


def test_a_renamed_copy_lowers_in_the_order_of_the_names_it_copies():
    """t10*t2*t7 multiplies (t10*t2)*t7; renamed to t30, t22, t27 sympy's order of the new
    names would multiply (t22*t27)*t30: the copy keeps the original's order."""
    ports = [Port("x", (3,))]
    whole = Program("step", ports, [Port("y", (1,))])
    original = [Temporary(f"t{i}") for i in range(12)]
    copies = [Temporary(f"t{20 + i}") for i in range(12)]
    x = [whole.element("x", i) for i in range(3)]
    body = [Assign(original[i], x[i % 3] + i) for i in range(11)]
    body.append(Assign(original[11], original[2] * original[7] * original[10]))
    renamed = {o: c for o, c in zip(original, copies)}
    copied_body = [Assign(renamed[st.target], st.expr.xreplace(renamed)) for st in body]
    plain = whole.assembled(body, {"y": (original[11],)}, optimize=False)
    copy = whole.assembled(copied_body, {"y": (copies[11],)}, optimize=False,
                           order_names={c: o for o, c in renamed.items()})
    unordered = whole.assembled(copied_body, {"y": (copies[11],)}, optimize=False)
    back = {c.name: o.name for o, c in renamed.items()}
    want = lower_program(plain).body[-1].tree
    got = rename_tree(lower_program(copy).body[-1].tree, lambda v: back.get(v.name, v.name))
    assert got == want
    # the check can fail: without the names copied the product is associated otherwise
    other = rename_tree(lower_program(unordered).body[-1].tree,
                        lambda v: back.get(v.name, v.name))
    assert other != want


def test_an_optimised_assembly_takes_no_order_names():
    ports = [Port("x", (1,))]
    whole = Program("step", ports, [Port("y", (1,))])
    t0 = Temporary("t0")
    with pytest.raises(Exception, match="cannot keep the order"):
        whole.assembled([Assign(t0, whole.element("x", 0) * 2)], {"y": (t0,)},
                        optimize=True, order_names={t0: sympy.Symbol("t9")})


@needs_gcc
@pytest.mark.parametrize("flags", ["plain", "native"])
def test_the_lf_vector_run_of_three_axes_is_bitwise_the_scalar_run(tmp_path, flags):
    vector, scalar = _pair(tmp_path, "mpt3d_a", "lf", FLAGS[flags])
    assert f"#define {c_vector.SWITCH} 1" in (
        tmp_path / "vector" / "mpt3d_a" / "lf.c").read_text()
    z, x0, P0 = _data("mpt3d_a")
    got = _run(vector.c, True, z, x0, P0)
    want = _run(scalar.c, True, z, x0, P0)
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))
