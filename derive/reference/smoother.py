"""The Rauch-Tung-Striebel fixed-interval smoother, on plain arrays, for the linear models.

Forward pass: the reference Kalman filter (:func:`derive.reference.linear.kf`).  Backward
pass, for k = N-1 down to 1:

    P(k+1/k) = F P(k/k) F^T + G Q G^T,   x(k+1/k) = F x(k/k)
    C(k)     = P(k/k) F^T P(k+1/k)^-1          (a solve, not an inverse)
    x(k/N)   = x(k/k) + C(k) [x(k+1/N) - x(k+1/k)]
    P(k/N)   = P(k/k) + C(k) [P(k+1/N) - P(k+1/k)] C(k)^T

Indexing is derive's KF's: x(0/0) = x0 and P(0/0) = P0 are the initial
conditions, the first measurement is z(1) = zs[0] and is applied after one prediction;
the outputs are xs[k-1] = x(k/N), Ps[k-1] = P(k/N) for k = 1..N, so xs[N-1] is the
filtered x(N/N).  x(0/N) is not computed (it would invert P(1/0), singular for the
catalog's P0 = 0).  FilterPy's ``batch_filter`` then ``rts_smoother`` use the same
indexing; pykalman's filter updates with its first observation at its initial state, so
it matches with ``initial_state_mean = F x0`` and ``initial_state_covariance =
F P0 F^T + G Q G^T`` (x(1/0), P(1/0)).
"""

from __future__ import annotations

import numpy as np

from derive.errors import NumericalError
from derive.reference.linear import kf, update_first


def rts(model_numeric, zs, x0, P0, skip_nan: bool = False, us=None, start: str = "predict"):
    """Smoothed estimates of ``model_numeric`` (a :class:`derive.model.NumericLinear`) from
    ``zs`` (steps, m), starting at x(0/0) = ``x0``, P(0/0) = ``P0``; ``us`` (steps, n_u):
    the model's inputs, row k with zs[k] (x(k+1/k) = F x(k/k) + B us[k]).

    Returns (xs (steps, n), Ps (steps, n, n)) with xs[k-1] = x(k/N).  ``skip_nan``: a NaN
    in z(k) marks that component absent (the forward pass skips it); otherwise NaN is
    refused.  ``start="update"``: the forward pass updates x0, P0 with z(0) without a
    prediction (update-first, pykalman's convention), and xs[0] is x(0/N).  Raises
    NumericalError when a P(k+1/k) is singular."""
    num = model_numeric
    F, W = np.asarray(num.F, float), np.asarray(num.GQGt, float)

    def forward(x, P, rows, inputs_rows):
        inputs = {} if inputs_rows is None else {"B": num.B, "D": num.D, "us": inputs_rows}
        return kf(num.F, num.G, num.H, num.Q, num.R, x, P, rows, skip_nan=skip_nan, **inputs)

    xs, Ps = (update_first(forward, num.H, num.R, x0, P0, zs, skip_nan,
                           D=None if us is None else num.D, us=us)
              if start == "update" else forward(x0, P0, zs, us))
    xs, Ps = xs.copy(), Ps.copy()
    Bu = (np.zeros((len(xs), F.shape[0])) if us is None
          else np.asarray(us, float) @ np.asarray(num.B, float).T)
    for k in range(len(xs) - 2, -1, -1):
        x_pred = F @ xs[k] + Bu[k + 1]  # x(k+2/k+1): the input row of step k + 2
        P_pred = F @ Ps[k] @ F.T + W
        try:
            gain = np.linalg.solve(P_pred, F @ Ps[k]).T   # P F^T P_pred^-1, P_pred symmetric
        except np.linalg.LinAlgError as exc:
            j = k + (start != "update")  # the step of row k: k + 1 when predict-first
            raise NumericalError(f"RTS smoother, step {j}: P({j + 1}/{j}) is singular") \
                from exc
        xs[k] = xs[k] + gain @ (xs[k + 1] - x_pred)
        Ps[k] = Ps[k] + gain @ (Ps[k + 1] - P_pred) @ gain.T
    return xs, Ps
