"""The verification data of one filter as the C ``run`` takes it, with the reference.

The same scenario, reference and tolerance as ``derive verify`` (derive.apps.verify):
linear filters on the seeded simulated run, nonlinear filters on their scenario with the
reference's rounding floor, float32 code (``precision`` float) the bound of
derive.apps.float_tolerance; a unit of the run kind ``sensors`` on its
derive.apps.verify.sensors_case (each sensor at its period, NaN rows between; free
parameters at their examples, one ``p`` row per step). The inputs are keyed by the C
``run`` function's argument names (``z``, ``u``, ``x0``, ``P0``; ``z_<sensor>``,
``R_<sensor>``, ``p``) and the reference by its output names (``xs``, ``Ps``), so a
program generated from the header's interface can hold both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import SymbolError
from ...filters import kind
from ...filters.sensors import uses_sensor_run
from ...generation import command_unit
from ...options import validate
from ...precision import DOUBLE
from ...runs.unit import Unit
from ..float_tolerance import FloatTolerance, PropagatedTolerance, float_tolerance
from ..verify import (
    FLOOR_MARGIN,
    LINEAR_TOLERANCE,
    NONLINEAR_TOLERANCE,
    InputRun,
    conditioning_run,
    linear_run,
    nonlinear_scenario,
    parameter_values,
    reference_run,
    rounding_floor,
    sensors_case,
)

#: Steps of the verification data a generated test program embeds (``derive verify``
#: runs 1000; 200 steps of a 6-state KF with its P are ~150 kB of C).
TEST_STEPS = 200
SEED = 7


@dataclass(frozen=True)
class VerificationData:
    """``inputs``: {C run argument: float64 array}; ``reference``: {C run output: array
    (steps, ...)} of the NumPy reference; ``tolerance``: the bar of ``derive verify``
    for the error measure of derive.apps.verify.relative_error; ``bound``: for float32
    code, the derivation of that bar (c u32 L G kappa)."""

    model: str
    filter: str
    steps: int
    inputs: dict[str, np.ndarray]
    reference: dict[str, np.ndarray]
    tolerance: float
    bound: FloatTolerance | PropagatedTolerance | None = None

    @property
    def meaningful(self) -> bool:
        """False when the float32 bound is 1 or more: float32 cannot carry the filter."""
        return self.bound is None or self.bound.meaningful


def require_examples(model) -> None:
    """SymbolError naming the free parameters of ``model`` without an example: the
    verification data run them at their examples (``dt = { example = 0.01 }``)."""
    missing = [p.name for p in model.parameters if p.name not in model.examples]
    if missing:
        raise SymbolError(
            f"model {model.name!r}: free parameters {missing} have no example, so there is "
            f"no verification data to run its C on (give each one, e.g. {missing[0]} = "
            "{ example = ... } in [parameters])")


def verification_data(model, name: str, options=None, steps: int = TEST_STEPS,
                      seed: int = SEED, unit: Unit | None = None) -> VerificationData:
    """The data ``derive verify`` runs filter ``name`` of ``model`` on, the reference, and
    the tolerance ``derive verify`` holds the C to: for ``precision`` float the float32
    bound of derive.apps.float_tolerance (``unit``: the filter's unit, derived again when
    not given)."""
    opts = validate(name, options)
    require_examples(model)
    if kind(name).sensors and uses_sensor_run(model, opts):
        case = sensors_case(model, name, steps, seed, opts, unit)
        reference = {"xs": np.asarray(case.reference.xs, dtype=float),
                     "Ps": np.asarray(case.reference.Ps, dtype=float).reshape(
                         steps, model.n_tangent, model.n_tangent)}
        tolerance = case.bound.value if case.bound is not None else case.tolerance
        return VerificationData(model.name, name, steps,
                                {k: np.asarray(v, dtype=float)
                                 for k, v in case.arguments().items()},
                                reference, float(tolerance), case.bound)
    rows = None
    if model.parameters:  # simulated at the examples; the filter takes them as p rows
        given = parameter_values(model)
        rows = np.tile([given[q.name] for q in model.parameters], (steps, 1))
        model = model.at_values(given)
    scenario = None
    if kind(name).model_kind == "nonlinear":
        scenario = nonlinear_scenario(model, steps, seed)
        zs, tolerance = scenario.zs, NONLINEAR_TOLERANCE
        values = {"z": scenario.zs, "u": scenario.us, "x0": scenario.x0, "P0": scenario.P0}
    else:
        zs, tolerance = linear_run(model, steps, seed), LINEAR_TOLERANCE
        num = model.numeric()
        measured = zs.zs if isinstance(zs, InputRun) else zs
        values = {"z": measured, "x0": num.x0, "P0": num.P0}
        if isinstance(zs, InputRun):
            values["u"] = zs.us
    if rows is not None:
        values["p"] = rows
    xs_ref, Ps_ref = reference_run(model, name, zs, opts, scenario)
    if scenario is not None:
        floor = rounding_floor(model, name, scenario, opts, xs_ref, Ps_ref)
        tolerance = max(tolerance, FLOOR_MARGIN * floor)
    bound = None
    if opts.precision != DOUBLE.name:   # the float32 bound of derive verify --precision float
        unit = unit if unit is not None else command_unit(model, name, opts)
        bound = float_tolerance(model, unit, steps,
                                conditioning_run(model, zs, scenario, xs_ref, Ps_ref))
        tolerance = bound.value
    reference = {"xs": np.asarray(xs_ref, dtype=float)}
    if Ps_ref is not None:
        nt = model.n_tangent
        reference["Ps"] = np.asarray(Ps_ref, dtype=float).reshape(steps, nt, nt)
    return VerificationData(model.name, name, steps,
                            {k: np.asarray(v, dtype=float) for k, v in values.items()},
                            reference, float(tolerance), bound)
