"""How an INS/GNSS filter run is measured: agreement of two runs (generated code against the
NumPy reference) and the filter against the truth (errors, 3σ bounds, NIS).

Agreement, per state i over the whole flight: max_k |a[k, i] − b[k, i]| divided by
max(max_k |b[k, i]|, scale_i), scale_i = sqrt(P0[i, i]) (the state's prior standard
deviation: a bias near zero is measured against its own uncertainty, not against its
tiny value); covariances: max_k |A[k, i, j] − B[k, i, j]| / sqrt(B[k, i, i] B[k, j, j]),
the difference as a fraction of the standard deviations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from derive.apps.ins import constants as c
from derive.apps.ins.quaternion import attitude_error, conjugate
from derive.apps.ins.reference import P_ROWS, Q_ROWS, V_ROWS, right_matrix

STATE_SCALE = c.P0_STD
"""scale_i of the agreement measure: the prior standard deviations."""

INSIDE_BAR = 0.95
"""Fraction of GNSS epochs whose position error must be inside the filter's 3σ."""


def state_agreement(got: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Per state: max_k |got − expected| / max(max_k |expected|, scale)."""
    denominator = np.maximum(np.abs(expected).max(axis=0), STATE_SCALE)
    return np.abs(got - expected).max(axis=0) / denominator


def covariance_agreement(got: np.ndarray, expected: np.ndarray) -> float:
    """max over k, i, j of |got − expected| / sqrt(expected_ii expected_jj)."""
    sd = np.sqrt(np.diagonal(expected, axis1=1, axis2=2))
    return float((np.abs(got - expected) / (sd[:, :, None] * sd[:, None, :])).max())


def attitude_sigma(xs: np.ndarray, Ps: np.ndarray) -> np.ndarray:
    """Standard deviations (rad) of the NED attitude error (the rotation vector of
    q̂ ⊗ q⁻¹) from P's quaternion block: J P_qq Jᵀ with J = 2 R(q̂*)[1:4] (first order)."""
    q = xs[:, Q_ROWS] / np.linalg.norm(xs[:, Q_ROWS], axis=1, keepdims=True)
    out = np.empty((len(xs), 3))
    for k in range(len(xs)):
        jac = 2.0 * right_matrix(conjugate(q[k]))[1:]
        out[k] = np.sqrt(np.diag(jac @ Ps[k][Q_ROWS, Q_ROWS] @ jac.T))
    return out


@dataclass(frozen=True)
class Errors:
    """A run against the truth after each step (rows k: the estimate at t[k+1])."""

    position: NDArray
    velocity: NDArray
    attitude: NDArray
    biases: NDArray
    position_sigma: NDArray
    velocity_sigma: NDArray
    attitude_sigma: NDArray
    bias_sigma: NDArray


def errors(flight, xs: np.ndarray, Ps: np.ndarray) -> Errors:
    truth = flight.states[1:]
    sd = np.sqrt(np.diagonal(Ps, axis1=1, axis2=2))
    return Errors(xs[:, P_ROWS] - truth[:, P_ROWS], xs[:, V_ROWS] - truth[:, V_ROWS],
                  attitude_error(xs[:, Q_ROWS], truth[:, Q_ROWS]), xs[:, 10:],
                  sd[:, P_ROWS], sd[:, V_ROWS], attitude_sigma(xs, Ps), sd[:, 10:])


def inside_fraction(flight, err: Errors) -> float:
    """Fraction of GNSS epochs at which every position component's error is inside ±3σ
    of the filter's own P (after that epoch's updates)."""
    rows = flight.gnss_rows
    inside = np.all(np.abs(err.position[rows]) <= 3.0 * err.position_sigma[rows], axis=1)
    return float(inside.mean())
