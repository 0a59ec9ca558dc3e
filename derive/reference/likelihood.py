"""The Gaussian log-likelihood of a filter's innovations, from its definition.

Step k contributes log N(nu; 0, S) = -1/2 (m log 2 pi + log det S + nu' S^-1 nu) over the m
measurements present at step k (nothing at a step with none); the log-likelihood of a run is
the sum over its steps.

Two correct filters' ll(k) differ by more than its own size suggests: nu = z - z_pred is a
difference, so the prediction's absolute rounding error reaches ll through |S^-1 nu|' |z_pred|,
which grows with the state while ll does not. :func:`loglik_scale` is that first-order
sensitivity plus the size of the sum's terms: the scale an ll(k) error is relative to.
"""

from __future__ import annotations

import numpy as np

from derive.errors import NumericalError


def gaussian_loglik(nu: np.ndarray, S: np.ndarray) -> float:
    """log N(nu; 0, S) for a positive-definite ``S`` (slogdet and a solve)."""
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0:
        raise NumericalError("innovation covariance S is not positive definite")
    return float(-0.5 * (len(nu) * np.log(2 * np.pi) + logdet + nu @ np.linalg.solve(S, nu)))


def loglik_scale(z: np.ndarray, nu: np.ndarray, S: np.ndarray) -> float:
    """1/2 (m log 2 pi + |log det S| + nu' S^-1 nu) + |S^-1 nu|' |z - nu|: the terms' size
    and the sensitivity of log N(nu; 0, S) to a relative error of the prediction z - nu."""
    solved = np.linalg.solve(S, nu)
    logdet = np.linalg.slogdet(S)[1]
    return float(0.5 * (len(nu) * np.log(2 * np.pi) + abs(logdet) + nu @ solved)
                 + np.abs(solved) @ np.abs(z - nu))


def innovations_loglik(innovations: np.ndarray, covariances: np.ndarray,
                       zs: np.ndarray | None = None):
    """Per-step log-likelihood of recorded innovations (steps, m) and their covariances
    (steps, m, m), NaN where a measurement was absent (derive.reference.NonlinearResult);
    with the measurements ``zs``: (lls, each step's :func:`loglik_scale`, 0 without any)."""
    out, scales = np.zeros(len(innovations)), np.zeros(len(innovations))
    for k, (nu, S) in enumerate(zip(innovations, covariances)):
        present = ~np.isnan(nu)
        if present.any():
            block = S[np.ix_(present, present)]
            out[k] = gaussian_loglik(nu[present], block)
            if zs is not None:
                scales[k] = loglik_scale(zs[k][present], nu[present], block)
    return out if zs is None else (out, scales)
