"""NumPy EKF and UKF for the GNSS model X = [x, y, z, b] with one pseudorange at a time.

Model (the GNSS paper): X(k) = X(k−1) + W(k), W ~ N(0, Q); one pseudorange
ρ = ||s − [x, y, z]|| + b + v, v ~ N(0, σ²), per scalar update, with the satellite
position s an input of that update. An epoch is one predict followed by one update1 per
satellite, so any number of satellites per epoch works.

Sequential scalar updates re-linearise (EKF) or redraw sigma points (UKF) after every
pseudorange, so they differ slightly from one batch update with all of an epoch's
pseudoranges (by second-order terms; for a linear h and diagonal R they coincide). For the
UKF this is the usual sequential-measurement variant: each scalar update is the GNSS paper's
update with m = 1, sigma points drawn from the current (X, P).

These are the stand-ins for the generated filters: predict(X, P) -> (X, P + Q) and
update1(X, P, rho, sat_xyz) -> (X, P, innovation, innovation variance).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from derive.errors import ShapeError
from derive.reference.nonlinear import sigma_points, sigma_weights

STATE_SIZE = 4


class ScalarUpdate(NamedTuple):
    """Result of one scalar update: the new state and covariance, the innovation
    ρ − ρ̂ and its variance (H P Hᵀ + σ² for the EKF, Pvv for the UKF)."""

    x: np.ndarray
    P: np.ndarray
    innovation: float
    variance: float


def _range_and_jacobian(x: np.ndarray, sat: np.ndarray) -> tuple[float, np.ndarray]:
    diff = sat - x[:3]
    dist = float(np.linalg.norm(diff))
    return dist + x[3], np.append(-diff / dist, 1.0)


def _satellite(sat_xyz) -> np.ndarray:
    sat = np.asarray(sat_xyz, dtype=float)
    if sat.shape != (3,):
        raise ShapeError(f"sat_xyz must be an ECEF position of shape (3,), got {sat.shape}")
    return sat


def ekf_predict(x, P, Q) -> tuple[np.ndarray, np.ndarray]:
    """Identity dynamics: X(k/k−1) = X(k−1/k−1), P(k/k−1) = P(k−1/k−1) + Q."""
    return np.array(x, dtype=float), np.asarray(P, dtype=float) + Q


def ekf_update1(x, P, rho: float, sat_xyz, R: float) -> ScalarUpdate:
    """One pseudorange: H = ∂ρ/∂X at x, S = H P Hᵀ + R, K = P Hᵀ / S,
    x + K (ρ − h(x)), P − K H P."""
    x, P = np.asarray(x, dtype=float), np.asarray(P, dtype=float)
    predicted, H = _range_and_jacobian(x, _satellite(sat_xyz))
    PH = P @ H
    S = float(H @ PH) + R
    K = PH / S
    nu = float(rho) - predicted
    return ScalarUpdate(x + K * nu, P - np.outer(K, H @ P), nu, S)


def ukf_update1(x, P, rho: float, sat_xyz, R: float, alpha: float = 1.0, beta: float = 0.0,
                kappa: float | None = None) -> ScalarUpdate:
    """One pseudorange, unscented: sigma points from (x, P) with the scaled weights of
    derive.reference.nonlinear.sigma_weights (default the plain UKF, n + κ = 3),
    ŷ = Σ Wm h(Xi), Pvv = Σ Wc (h(Xi) − ŷ)² + R, Pxy = Σ Wc (Xi − x)(h(Xi) − ŷ),
    K = Pxy / Pvv, x + K (ρ − ŷ), P − K Pvv Kᵀ. A covariance that is not positive
    definite raises NumericalError."""
    x, P = np.asarray(x, dtype=float), np.asarray(P, dtype=float)
    sat = _satellite(sat_xyz)
    n = STATE_SIZE
    c, Wm, Wc = sigma_weights(n, alpha, beta, 3.0 - n if kappa is None else kappa)
    X = sigma_points(x, P, c, 0)
    Y = np.linalg.norm(sat - X[:, :3], axis=1) + X[:, 3]
    y_hat = float(Wm @ Y)
    dy = Y - y_hat
    Pvv = float(Wc @ dy ** 2) + R
    K = ((X - x).T @ (Wc * dy)) / Pvv
    nu = float(rho) - y_hat
    return ScalarUpdate(x + K * nu, P - Pvv * np.outer(K, K), nu, Pvv)


class ScalarEkf:
    """EKF with fixed Q (4×4) and σ (m): the (predict, update1) pair run_real drives."""

    def __init__(self, Q, sigma: float):
        self.Q = np.asarray(Q, dtype=float)
        if self.Q.shape != (STATE_SIZE, STATE_SIZE):
            raise ShapeError(f"Q must be 4×4, got shape {self.Q.shape}")
        self.R = float(sigma) ** 2

    def predict(self, x, P):
        return ekf_predict(x, P, self.Q)

    def update1(self, x, P, rho, sat_xyz) -> ScalarUpdate:
        return ekf_update1(x, P, rho, sat_xyz, self.R)


class ScalarUkf(ScalarEkf):
    """UKF with fixed Q, σ and weights (alpha, beta, kappa; kappa=None: 3 − n)."""

    def __init__(self, Q, sigma: float, alpha: float = 1.0, beta: float = 0.0,
                 kappa: float | None = None):
        super().__init__(Q, sigma)
        self.alpha, self.beta, self.kappa = alpha, beta, kappa

    def update1(self, x, P, rho, sat_xyz) -> ScalarUpdate:
        return ukf_update1(x, P, rho, sat_xyz, self.R, self.alpha, self.beta, self.kappa)
