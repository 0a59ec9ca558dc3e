"""What ``derive bench`` times: filters on catalog models, their data and the protocol an
implementation follows.

An implementation is prepared once per case (``prepare(case, data, workdir)``) and returns
``run(steps) -> outputs``: the filter over the first ``steps`` measurements of every copy,
one state array per copy (at least ``steps`` rows; buffers may be reused between calls, so
nothing is allocated or copied while it is timed); :func:`states` joins them. It raises
:class:`Skip` with a reason when it cannot run (a peer not installed, a filter it does
not have).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ... import catalog
from ..simulate import gnss_scenario, simulate_linear


class Skip(Exception):
    """An implementation that cannot run here; the message says why."""


@dataclass(frozen=True)
class Case:
    """Filter ``filter`` on catalog model ``model``, run on ``copies`` independent axes."""

    filter: str
    model: str
    copies: int = 1

    @property
    def label(self) -> str:
        return f"{self.filter.upper()} {self.model}" + (f" x {self.copies}"
                                                        if self.copies > 1 else "")

    @property
    def nonlinear(self) -> bool:
        return self.filter in ("ekf", "ukf")


CASES = (Case("kf", "mpt3d_a"), Case("kf", "mpt3d_b", 3), Case("sskf", "mpt3d_a"),
         Case("sskf", "mpt3d_b", 3), Case("ekf", "gnss_pseudorange"),
         Case("ukf", "gnss_pseudorange"))


@dataclass
class Data:
    """Measurements per copy (each (steps, m), C-contiguous), per-step inputs ``us`` (GNSS
    satellite positions, (steps, 12)) and the model's numbers."""

    model: object
    zs: list[np.ndarray]
    x0: np.ndarray
    P0: np.ndarray
    us: np.ndarray | None = None
    arrays: dict[str, np.ndarray] = field(default_factory=dict)   # F, G, H, Q, R, GQGt

    @property
    def steps(self) -> int:
        return len(self.zs[0])


def make_data(case: Case, steps: int, seed: int = 11) -> Data:
    """Seeded measurements for ``steps`` steps of every copy."""
    model = catalog.load(case.model)
    if case.nonlinear:
        sc = gnss_scenario(steps=steps, seed=seed)
        fns = model.numeric_functions()
        return Data(model, [np.ascontiguousarray(sc.pseudoranges)], sc.x0, sc.P0,
                    np.ascontiguousarray(sc.satellites.reshape(steps, -1)),
                    {"Q": np.asarray(fns["Q"], float), "R": np.asarray(fns["R"], float)})
    num = model.numeric()
    zs = [np.ascontiguousarray(simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0,
                                               steps, seed + c).zs)
          for c in range(case.copies)]
    arrays = {k: np.asarray(getattr(num, k), float) for k in ("F", "G", "H", "Q", "R")}
    arrays["GQGt"] = arrays["G"] @ arrays["Q"] @ arrays["G"].T
    return Data(model, zs, np.asarray(num.x0, float), np.asarray(num.P0, float), None, arrays)


def per_copy(run_one, data: Data, steps: int) -> list:
    """``run_one(zs_of_copy[:steps])`` for every copy."""
    return [run_one(z[:steps]) for z in data.zs]


def states(outputs, steps: int) -> np.ndarray:
    """The states of every copy side by side, (steps, n * copies)."""
    if not isinstance(outputs, list):
        outputs = [outputs]
    return np.hstack([np.asarray(a)[:steps].reshape(steps, -1) for a in outputs])
