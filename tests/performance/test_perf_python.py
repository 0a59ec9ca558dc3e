"""The single-track generated Python ``run`` (derive.emit.python_loop): fewer names and
packs per step, same operations in the same order, so the results stay those of calling
``step`` once per step, bit for bit; a failed check still names its step."""

from __future__ import annotations

import re

import numpy as np
import pytest

from derive import catalog
from derive.errors import NumericalError
from derive.generation import render_filter
from derive.pipeline import load_generated

CASES = [("mpt3d_b", "kf", {}), ("mpt3d_a", "kf", {}), ("mpt3d_a", "lf", {}),
         ("mpt3d_a", "jklf", {}), ("mpt3d_a", "sskf", {}), ("ca", "kf", {"joseph": True}),
         ("mpt3d_a", "kf", {"latency_schedule": True}), ("gsm2d_a", "kf", {})]


def _loop_body(text: str) -> list[str]:
    branch = text[text.index("if not track:"):]
    lines = branch.splitlines()
    start = next(k for k, line in enumerate(lines) if line.lstrip().startswith("for "))
    indent = len(lines[start + 1]) - len(lines[start + 1].lstrip())
    body = []
    for line in lines[start + 1:]:
        if line.strip() and len(line) - len(line.lstrip()) < indent:
            break
        body.append(line.strip())
    return body


@pytest.mark.parametrize("model, name, options", CASES)
def test_a_temporary_read_once_is_printed_inside_its_reader(model, name, options):
    """Each temporary the loop names is read at least twice, or read once across a check
    (kept apart so nothing divides by a value before it is checked)."""
    text = render_filter(catalog.load(model), name, "python", options)[f"{name}.py"]
    body = _loop_body(text)
    for k, line in enumerate(body):
        found = re.match(r"(t\d+) = ", line)
        if not found:
            continue
        temp = found.group(1)
        readers = [j for j, other in enumerate(body)
                   if j != k and re.search(rf"\b{temp}\b", other)]
        reads = sum(len(re.findall(rf"\b{temp}\b", body[j])) for j in readers)
        if reads == 1:
            assert any(body[j].startswith("if not ") for j in range(k + 1, readers[0])), \
                (model, name, line)


def test_the_loop_keeps_each_step_in_one_pack_and_counts_steps_by_it():
    text = render_filter(catalog.load("mpt3d_b"), "kf", "python", {})["kf.py"]
    body = _loop_body(text)
    assert sum(line.startswith("keep(pack(") for line in body) == 1
    assert not any("enumerate(" in line for line in body)
    # the new state is written where it is computed when the old value is dead by then
    assert "x_0 = t0 + t11*t14" in body and "P_0 = t4 - t11*t7" in body
    assert not any(re.match(r"(x|P)_\d+ = t\d+$", line) for line in body)


def _stepped(module, name, zs, x0, P0):
    x = list(x0)
    P = None if P0 is None else list(np.asarray(P0).reshape(-1))
    xs, Ps = [], []
    for z in zs:
        if P is None:
            x = module.step(x, z)
        else:
            x, P = module.step(x, P, z)
            Ps.append(P)
        xs.append(x)
    return np.array(xs), (np.array(Ps) if Ps else None)


@pytest.mark.parametrize("model, name, options", CASES)
def test_run_is_step_by_step_bitwise(model, name, options, tmp_path):
    module = load_generated(model, name, options, "python", tmp_path).python
    num = catalog.load(model).numeric()
    rng = np.random.default_rng(17)
    zs = rng.normal(size=(400, num.H.shape[0])) * 3.0
    x0 = np.asarray(num.x0, float) + rng.normal(size=len(num.x0))
    if name.startswith("ss"):
        xs = module.run(zs, x0)
        xr, _ = _stepped(module, name, zs, x0, None)
        np.testing.assert_array_equal(xs, xr)
        return
    P0 = np.eye(len(x0)) * 2.0
    xs, Ps = module.run(zs, x0, P0)
    xr, Pr = _stepped(module, name, zs, x0, P0)
    np.testing.assert_array_equal(xs, xr)
    np.testing.assert_array_equal(Ps, Pr)


def test_a_check_failing_at_a_later_step_names_that_step(tmp_path):
    """The step index comes from the rows kept so far (no enumerate): the P0 is found
    with ``step`` itself, passing the first step's check and failing the second's."""
    module = load_generated("mpt3d_b", "kf", {}, "python", tmp_path).python
    zs = np.zeros((6, 1))
    chosen = None
    for q in -np.geomspace(1e-3, 10.0, 60):
        P0 = np.diag([1.0, q])
        try:
            x, P = module.step([0.0, 0.0], P0.reshape(-1), zs[0])
        except NumericalError:
            continue
        try:
            module.step(x, P, zs[1])
        except NumericalError:
            chosen = P0
            break
    assert chosen is not None
    with pytest.raises(NumericalError, match=r"^step 1: S is not positive definite"):
        module.run(zs, np.zeros(2), chosen)
