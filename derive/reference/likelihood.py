"""The Gaussian log-likelihood of a filter's innovations, from its definition.

Step k contributes log N(nu; 0, S) = -1/2 (m log 2 pi + log det S + nu' S^-1 nu) over the m
measurements present at step k (nothing at a step with none); the log-likelihood of a run is
the sum over its steps.
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


def innovations_loglik(innovations: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Per-step log-likelihood of recorded innovations (steps, m) and their covariances
    (steps, m, m), NaN where a measurement was absent (derive.reference.NonlinearResult)."""
    out = np.zeros(len(innovations))
    for k, (nu, S) in enumerate(zip(innovations, covariances)):
        present = ~np.isnan(nu)
        if present.any():
            out[k] = gaussian_loglik(nu[present], S[np.ix_(present, present)])
    return out
