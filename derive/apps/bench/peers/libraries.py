"""Peers for the benchmark: derive's NumPy reference, FilterPy and pykalman.

Each is set up to compute the same filter from the same x(0/0), P(0/0) as derive (the papers'
conventions: z(k) observes x(k) = F x(k−1)); the agreement column of the table checks it.
"""

from __future__ import annotations

import importlib

import numpy as np

from .... import reference
from ...simulate import pseudorange, pseudorange_jacobian
from ..cases import Case, Data, Skip, per_copy


def _need(module: str):
    try:
        return importlib.import_module(module)
    except ImportError:
        raise Skip(f"{module.split('.')[0]} is not installed") from None


def _gnss_functions(data: Data):
    def hx(x, sats):
        return pseudorange(x, sats.reshape(-1, 3))

    def jac(x, sats):
        return pseudorange_jacobian(x, sats.reshape(-1, 3))

    return hx, jac


def numpy_reference(case: Case, data: Data, workdir=None):
    """derive.reference, written from the papers (NumPy, one step per loop iteration)."""
    if case.nonlinear:
        hx, jac = _gnss_functions(data)
        Q, R = data.arrays["Q"], data.arrays["R"]

        def run(steps):
            ins = list(data.us[:steps])
            if case.filter == "ekf":
                res = reference.ekf(None, None, hx, jac, Q, R, data.x0, data.P0,
                                    data.zs[0][:steps], inputs=ins)
            else:
                res = reference.ukf(None, hx, Q, R, data.x0, data.P0, data.zs[0][:steps],
                                    inputs=ins)
            return res.xs
        return run
    a = data.arrays
    args = (a["F"], a["G"], a["H"], a["Q"], a["R"], data.x0)
    if case.filter == "kf":
        return lambda steps: per_copy(lambda z: reference.kf(*args, data.P0, z)[0], data,
                                      steps)
    return lambda steps: per_copy(lambda z: reference.sskf(*args, z), data, steps)


def filterpy(case: Case, data: Data, workdir=None):
    """FilterPy's KalmanFilter, ExtendedKalmanFilter or UnscentedKalmanFilter (predict,
    then update, per step)."""
    kalman = _need("filterpy.kalman")
    if case.filter == "sskf":
        raise Skip("FilterPy has no steady-state filter")
    if case.filter == "kf":
        a = data.arrays

        def one(zs):
            kf = kalman.KalmanFilter(dim_x=len(data.x0), dim_z=zs.shape[1])
            kf.F, kf.H, kf.Q, kf.R = a["F"], a["H"], a["GQGt"], a["R"]
            kf.x, kf.P = data.x0.copy(), data.P0.copy()
            out = np.empty((len(zs), len(data.x0)))
            for k, z in enumerate(zs):
                kf.predict()
                kf.update(z)
                out[k] = kf.x
            return out
        return lambda steps: per_copy(one, data, steps)
    hx, jac = _gnss_functions(data)
    Q, R = data.arrays["Q"], data.arrays["R"]
    if case.filter == "ekf":
        def run(steps):
            kf = kalman.ExtendedKalmanFilter(dim_x=4, dim_z=4)
            kf.x, kf.P, kf.Q, kf.R = data.x0.copy(), data.P0.copy(), Q, R
            out = np.empty((steps, 4))
            for k in range(steps):
                kf.predict()
                kf.update(data.zs[0][k], jac, hx, args=(data.us[k],), hx_args=(data.us[k],))
                out[k] = kf.x
            return out
        return run

    def run(steps):   # UKF: Julier points with kappa = -1 (n + kappa = 3, the paper's)
        points = kalman.JulierSigmaPoints(4, kappa=-1.0)
        kf = kalman.UnscentedKalmanFilter(4, 4, 1.0, hx, lambda x, dt: x, points)
        kf.x, kf.P, kf.Q, kf.R = data.x0.copy(), data.P0.copy(), Q, R
        out = np.empty((steps, 4))
        for k in range(steps):
            kf.predict()
            kf.update(data.zs[0][k], sats=data.us[k])
            out[k] = kf.x
        return out
    return run


def pykalman(case: Case, data: Data, workdir=None):
    """pykalman's KalmanFilter.filter over the whole series (its loop is in Python).
    pykalman's first measurement observes its initial state, so it starts from the
    prediction x(1/0) = F x0, P(1/0) = F P0 Fᵀ + G Q Gᵀ."""
    module = _need("pykalman")
    if case.filter != "kf":
        raise Skip("pykalman has only the linear time-varying KF")
    a = data.arrays
    F, W = a["F"], a["GQGt"]
    kf = module.KalmanFilter(transition_matrices=F, observation_matrices=a["H"],
                             transition_covariance=W, observation_covariance=a["R"],
                             initial_state_mean=F @ data.x0,
                             initial_state_covariance=F @ data.P0 @ F.T + W)
    return lambda steps: per_copy(lambda z: kf.filter(z)[0], data, steps)
