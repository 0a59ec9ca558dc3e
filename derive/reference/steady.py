"""Steady-state filters written from the papers' equations: SSKF, SSLF, JSSKLF, the FIR steady-state
filter and the steady-state N-step predictor.

Indexing: zs[k-1] = z(k) for k = 1..steps. Estimators return xs[k-1] = x(k/k); the
predictor returns xs[k-1] = x(k+N/k). The gains come from derive.riccati (doubling by
default), which raises SteadyStateError for an undetectable or unstabilisable model.
"""

from __future__ import annotations

import numpy as np

from derive.errors import SteadyStateError
from derive.horizon import fir_order, fir_taps, pred_constants
from derive.reference._inputs import measurement_series, state_vector
from derive.riccati import kf_steady, lf_steady
from derive.system_checks import system_arrays


def _run(A: np.ndarray, B: np.ndarray, x: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """x(k+1) = A x(k) + B z(k+1) over the series; returns the states after each z."""
    xs = np.empty((len(Z), A.shape[0]))
    for k, z in enumerate(Z):
        x = A @ x + B @ z
        xs[k] = x
    return xs


def _setup(F, G, H, Q, R, x0, zs):
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    return (F, G, H, Q, R, state_vector("x0", x0, F.shape[0]),
            measurement_series(zs, H.shape[0], allow_nan=False))


def sskf(F, G, H, Q, R, x0, zs, method: str = "doubling") -> np.ndarray:
    """Steady-state KF: x(k+1/k+1) = A_KF x(k/k) + B_KF z(k+1), x(0/0) = x0."""
    F, G, H, Q, R, x, Z = _setup(F, G, H, Q, R, x0, zs)
    ss = kf_steady(F, G, H, Q, R, method=method)
    return _run(ss.A, ss.B, x, Z)


def sslf(F, G, H, Q, R, x0, zs, method: str = "doubling") -> np.ndarray:
    """Steady-state LF: x(k+1/k+1) = A_LF x(k/k) + B_LF z(k+1), x(0/0) = x0."""
    F, G, H, Q, R, x, Z = _setup(F, G, H, Q, R, x0, zs)
    ss = lf_steady(F, G, H, Q, R, method=method)
    return _run(ss.A, ss.B, x, Z)


def jssklf(F, G, H, Q, R, x0, zs, method: str = "doubling") -> np.ndarray:
    """Join steady-state Kalman-Lainiotis filter: x = (x_SSKF + x_SSLF) / 2."""
    return (sskf(F, G, H, Q, R, x0, zs, method) + sslf(F, G, H, Q, R, x0, zs, method)) / 2


def fir(F, G, H, Q, R, zs, N: int | None = None, eps: float | None = None,
        norm=2) -> np.ndarray:
    """FIR steady-state filter of order N: x(k/k) = sum_{i=0}^{N-1} A^i B z(k-i), with
    A = A_KF, B = B_KF. Give N, or eps in (0, 1) to use the smallest N with ||A^N|| < eps
    (riccati.fir_order; norm 2, 'fro' or 'inf'). Measurements before k = 1 are taken as 0,
    so with x0 = 0 the first N outputs equal the SSKF's exactly."""
    if (N is None) == (eps is None):
        raise SteadyStateError("fir needs exactly one of N (order) or eps (tolerance)")
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    Z = measurement_series(zs, H.shape[0], allow_nan=False)
    ss = kf_steady(F, G, H, Q, R)
    order = fir_order(ss.A, eps, norm) if N is None else N
    taps = fir_taps(ss.A, ss.B, order)
    padded = np.vstack([np.zeros((len(taps) - 1, Z.shape[1])), Z])
    xs = np.empty((len(Z), F.shape[0]))
    for k in range(len(Z)):
        window = padded[k:k + len(taps)][::-1]      # z(k+1), z(k), ..., z(k+2-N)
        xs[k] = np.einsum("inm,im->n", taps, window)
    return xs


def pred(F, G, H, Q, R, x0, zs, N: int, method: str = "doubling") -> np.ndarray:
    """Steady-state N-step prediction (SSPRED §4): x(k+N/k) = A_N x(k+N-1/k-1) + B_N z(k),
    k = 1..steps, from x(N/0) = F^N x0. Returns xs[k-1] = x(k+N/k), which equals F^N times
    the SSKF estimate x(k/k)."""
    F, G, H, Q, R, x, Z = _setup(F, G, H, Q, R, x0, zs)
    ss = kf_steady(F, G, H, Q, R, method=method)
    A_N, B_N = pred_constants(F, ss.K, H, N)
    return _run(A_N, B_N, np.linalg.matrix_power(F, int(N)) @ x, Z)
