"""Shared fixtures: the MPT3D axis built in Python (independent of the catalog files)."""

import pytest
import sympy

from derive import LinearModel

dt, sq2, sr2 = sympy.symbols("dt sq2 sr2", real=True)
AXIS_VALUES = {"dt": 1, "sq2": 0.01, "sr2": 0.1}


def axis_model(name="axis", values=AXIS_VALUES, **kw):
    """One MPT3D axis (SPEC §2): F=[[1,dt],[0,1]], G=[dt/2,1]^T, H=[1,dt]."""
    kw.setdefault("parameters", [s for s in AXIS_VALUES if s not in (values or {})])
    return LinearModel(name, ["s", "v"], ["z"], [[1, dt], [0, 1]], [[1, dt]], [[sq2]], [[sr2]],
                       G=[[dt / 2], [1]], values=values, **kw)


@pytest.fixture
def axis():
    return axis_model()
