"""NumPy reference filters written straight from the papers' equations, on plain arrays.

Indexing everywhere: zs[k-1] = z(k), k = 1..steps; estimates xs[k-1] = x(k/k)
(pred: x(k+N/k)). Steady-state gains come from derive.riccati.
"""

from derive.reference.linear import ikf, jklf, kf, lf, mdkf_covariance, update_first
from derive.reference.nonlinear import NonlinearResult, ekf, sigma_points, sigma_weights, ukf
from derive.reference.steady import fir, jssklf, pred, sskf, sslf

__all__ = [
    "NonlinearResult",
    "ekf",
    "fir",
    "ikf",
    "jklf",
    "jssklf",
    "kf",
    "lf",
    "mdkf_covariance",
    "pred",
    "sigma_points",
    "sigma_weights",
    "sskf",
    "sslf",
    "ukf",
    "update_first",
]
