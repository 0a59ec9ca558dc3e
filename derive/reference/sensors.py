"""NumPy reference of the multi-sensor Kalman filter and EKF, with gating, update-first
start and unit-norm groups, written from the equations on plain arrays and callables.

Per step k (0-based rows): predict with u(k) and p(k) (skipped at k = 0 with
``update_first``), then for each sensor in order whose row k of z has no NaN:
``nu = z - h(x, u_s)``, ``S = H P H^T + R``, ``nis = nu^T S^-1 nu``; the update
``K = P H^T S^-1``, ``x + K nu`` and Joseph's ``(I - K H) P (I - K H)^T + K R K^T`` are
applied unless a gate is given and ``nis`` exceeds it (or is NaN); then each unit-norm
group of x is divided by its norm (after every update of a present row, applied or not,
as the generated update does). Joseph's form keeps the reference accurate where an
update cancels: with P(k/k-1) 1e13 times P(k/k), ``P - K S K^T`` lost 1e-3 of P (rounding
of P(k/k-1)), Joseph's form 2e-16 (against 60-digit arithmetic), and the generated
``P - K (H P)`` 4e-10; the reference judges the generated code, so it must not be the
less accurate of the two.

With a ``trace`` list, :func:`run` also records each step's :class:`StepTrace` (the state
it predicted from, P(k/k-1), and each present sensor's H, S, gain K and the P it
updated): what the float32 tolerance of derive.apps.float_tolerance reads the run's
conditioning and error growth from.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from derive.domains import check_rows


@dataclass(frozen=True)
class SensorFunctions:
    """One sensor at numbers: ``h(x, u, p)`` (m,), ``H(x, u, p)`` (m, n), ``R(x, u, p)``
    (m, m; at the x the update starts from, as h), or None when R is given per step (run's
    ``Rs``); ``columns``: the columns of u(k) it
    takes; ``gate``: the NIS threshold or None; ``angles``: per measurement, whether it is
    an angle (its innovation wrapped to (-pi, pi])."""

    name: str
    h: Callable
    H: Callable
    R: Callable | None
    columns: tuple[int, ...] = ()
    gate: float | None = None
    angles: tuple[bool, ...] = ()


@dataclass(frozen=True)
class SensorsResult:
    """x(k) and P(k) after each step; per sensor the NIS (NaN where absent) and whether
    its update was applied (1.0, else 0.0)."""

    xs: np.ndarray
    Ps: np.ndarray
    nis: dict[str, np.ndarray]
    applied: dict[str, np.ndarray]


@dataclass(frozen=True)
class UpdateTrace:
    """One sensor's update of a step: its H, S = H P H^T + R, the gain K = P H^T S^-1,
    whether it was applied (not gated out), the P and x it started from, its row z and
    the innovation nu."""

    sensor: str
    H: np.ndarray
    S: np.ndarray
    K: np.ndarray
    applied: bool
    P: np.ndarray
    x: np.ndarray
    z: np.ndarray
    nu: np.ndarray


@dataclass(frozen=True)
class StepTrace:
    """One step of a run: x, u and p it predicted from (``P_predicted`` None: no
    prediction, the update-first step 0), P(k/k-1), its updates in order, the P it
    started from (P(k-1/k-1)) and the x and P it ended with (x(k/k), P(k/k))."""

    x_before: np.ndarray
    u: np.ndarray
    p: np.ndarray
    P_predicted: np.ndarray | None
    updates: tuple[UpdateTrace, ...]
    P_before: np.ndarray
    x_after: np.ndarray
    P_after: np.ndarray


def innovation(z, h, angles=()):
    """z - h, the entries flagged in ``angles`` wrapped to (-pi, pi]."""
    nu = z - h
    if any(angles):
        flags = np.asarray(angles, dtype=bool)
        nu[flags] = np.pi - np.mod(np.pi - nu[flags], 2 * np.pi)
    return nu


def _update(x, P, z, h, H, R, gate=None, inject=None, reset=None, angles=()):
    """One update with all of z: (x, P, nis, S, K, applied); ``inject(x, dx)``: x ⊞ dx
    (default x + dx), ``reset(dx)``: G applied as G P G^T after it (default none); the
    innovations of the measurements flagged in ``angles`` wrapped to (-pi, pi]."""
    nu = innovation(z, h, angles)
    S = H @ P @ H.T + R
    nis = float(nu @ np.linalg.solve(S, nu))
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S symmetric)
    if gate is not None and not nis <= gate:
        return x, P, nis, S, K, False
    dx = K @ nu
    x = x + dx if inject is None else inject(x, dx)
    IKH = np.eye(len(P)) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    if reset is not None:
        G = reset(dx)
        P = G @ P @ G.T
    return x, (P + P.T) / 2, nis, S, K, True


def update(x, P, z, h, H, R, gate=None):
    """One update with all of z: (x, P, nis, applied)."""
    x, P, nis, _, _, applied = _update(x, P, z, h, H, R, gate)
    return x, P, nis, applied


def renormalise(x, groups: Sequence[Sequence[int]]):
    """x with each group of entries divided by its Euclidean norm."""
    x = np.array(x, dtype=float)
    for group in groups:
        index = list(group)
        x[index] = x[index] / np.sqrt(np.sum(x[index] ** 2))
    return x


def run(predict: Callable, sensors: Sequence[SensorFunctions], x0, P0, zs: dict, us=None,
        ps=None, update_first: bool = False, unit_norm: Sequence[Sequence[int]] = (),
        Rs: dict | None = None, trace: list | None = None,
        domains: Sequence[tuple[int, str, str]] = (), inject: Callable | None = None,
        reset: Callable | None = None) -> SensorsResult:
    """The multi-sensor filter over ``zs`` (``{sensor: (steps, m_s)}``, rows of NaN:
    absent); ``predict(x, P, u, p) -> (x, P)``; ``us`` (steps, n_u) and ``ps`` (steps, np)
    one row per step (None: empty rows); ``Rs``: ``{sensor: (steps, m_s, m_s)}`` for the
    sensors whose R is given per step; ``trace``: a list :class:`StepTrace` s are appended
    to, one per step; ``domains``: the declared domains of p's entries, ``(index, name,
    domain)`` (derive.domains.parameter_domains): a row outside them raises DomainError
    (a NumericalError) naming its step, the parameter and the value, as generated code
    refuses it. An error-state filter (derive.reference.eskf) gives ``inject(x, dx) -> x ⊞
    dx`` and optionally ``reset(dx) -> G``; its P (and H's columns) are over the tangent
    space, P0's size."""
    steps = len(next(iter(zs.values())))
    x, P = np.array(x0, dtype=float), np.array(P0, dtype=float)
    n, nt = x.shape[0], P.shape[0]
    us = np.zeros((steps, 0)) if us is None else np.asarray(us, dtype=float)
    ps = np.zeros((steps, 0)) if ps is None else np.asarray(ps, dtype=float)
    xs, Ps = np.empty((steps, n)), np.empty((steps, nt, nt))
    nis = {s.name: np.full(steps, np.nan) for s in sensors}
    applied = {s.name: np.zeros(steps) for s in sensors}
    check_rows(domains, ps)
    for k in range(steps):
        x_before, P_start, predicted, updates = x, P, None, []
        if k or not update_first:
            x, P = predict(x, P, us[k], ps[k])
            predicted = P
        for s in sensors:
            z = np.asarray(zs[s.name][k], dtype=float)
            if np.isnan(z).any():
                continue
            u = us[k, list(s.columns)]
            H = np.asarray(s.H(x, u, ps[k]), dtype=float).reshape(len(z), nt)
            P_before, x_start = P, x
            h = np.asarray(s.h(x, u, ps[k]), dtype=float).ravel()
            x, P, nis[s.name][k], S, K, done = _update(
                x, P, z, h, H,
                np.asarray(s.R(x, u, ps[k]) if s.R is not None else Rs[s.name][k],
                           dtype=float).reshape(len(z), len(z)), s.gate, inject, reset,
                 s.angles)
            applied[s.name][k] = float(done)
            updates.append(UpdateTrace(s.name, H, S, K, done, P_before, x_start, z,
                                       innovation(z, h, s.angles)))
            x = renormalise(x, unit_norm)  # after every update call, applied or not
        xs[k], Ps[k] = x, P
        if trace is not None:
            trace.append(StepTrace(x_before, us[k], ps[k], predicted, tuple(updates),
                                   P_start, x, P))
    return SensorsResult(xs, Ps, nis, applied)


__all__ = ["SensorFunctions", "SensorsResult", "StepTrace", "UpdateTrace", "innovation",
           "renormalise",
           "run", "update"]
