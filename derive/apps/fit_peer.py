"""statsmodels' maximum-likelihood fit of the likelihood derive fit maximises: the peer of
derive.fit (``pip install statsmodels``).

The same model and the same likelihood: statsmodels' state-space form ``y_t = Z a_t + d_t
+ e_t``, ``a_{t+1} = T a_t + c_t + R eta_t`` with derive's matrices at the parameters
(each a NumPy function of them, lambdified once, so the peer spends no time in SymPy),
initialised known at derive's first prediction ``a_1 = F x0 + B u_0``, ``P_1 = F P0 F' +
G Q G'`` (it depends on the parameters through Q, so it is set at every update), the
inputs as the intercepts ``c_t = B u_{t+1}``, ``d_t = D u_t``, a NaN measurement missing.
A parameter with a declared domain is estimated as its logarithm, as derive.fit does.
statsmodels' own defaults otherwise: ``MLEModel.fit`` (L-BFGS-B, gradients by finite
differences of its log-likelihood) and, for :func:`statsmodels_score`, the score of its
``score`` method.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass

import numpy as np
import sympy
from statsmodels.tsa.statespace.mlemodel import MLEModel

from derive.domains import declared_domain
from derive.fitting import KERNEL_CFLAGS, fit, kernel, kernel_filter, split_columns
from derive.pipeline import load_generated


@dataclass(frozen=True)
class PeerFit:
    """statsmodels' estimates, log-likelihood at them, and the seconds its fit took."""

    estimates: np.ndarray
    loglik: float
    seconds: float


def _functions(model):
    """F, G, H, Q, R, B, D as NumPy functions of the free parameters (in the order of p)."""
    params = list(model.parameters)
    names = ("F", "G", "H", "Q", "R") + (("B", "D") if model.inputs else ())
    return {k: sympy.lambdify(params, model.matrix(k), "numpy") for k in names}


class DeriveStateSpace(MLEModel):
    """A derive linear model as a statsmodels MLEModel (one track)."""

    def __init__(self, model, zs, us=None, x0=None, P0=None, start=None):
        n, G = model.n, model.matrix("G")
        super().__init__(np.asarray(zs, dtype=float), k_states=n, k_posdef=G.shape[1])
        self.derive_model, self.us = model, us
        self.fns = _functions(model)
        self.x0 = np.array(model.x0, dtype=float).ravel() if x0 is None else np.asarray(x0)
        self.P0 = np.array(model.P0, dtype=float) if P0 is None else np.asarray(P0)
        self.logs = np.array([declared_domain(p) is not None for p in model.parameters])
        self._start = np.asarray(start, dtype=float)
        self.ssm.initialize_known(np.zeros(n), np.eye(n))

    @property
    def param_names(self):
        return [p.name for p in self.derive_model.parameters]

    @property
    def start_params(self):
        return self._start

    def transform_params(self, unconstrained):
        return np.where(self.logs, np.exp(np.where(self.logs, unconstrained, 0.0)),
                        unconstrained)

    def untransform_params(self, constrained):
        return np.where(self.logs, np.log(np.where(self.logs, constrained, 1.0)), constrained)

    def update(self, params, **kwargs):
        params = super().update(params, **kwargs)
        # complex while statsmodels differentiates by complex steps
        kind = complex if np.iscomplexobj(params) else float
        mats = {k: np.asarray(f(*params), dtype=kind) for k, f in self.fns.items()}
        F, G, Q = mats["F"], mats["G"], mats["Q"]
        self["transition"], self["design"] = F, mats["H"]
        self["selection"], self["state_cov"], self["obs_cov"] = G, Q, mats["R"]
        a1 = F @ self.x0
        if self.us is not None:
            B, D = mats["B"], mats["D"]
            a1 = a1 + B @ self.us[0]
            c = np.zeros((self.k_states, self.nobs), dtype=kind)
            c[:, :-1] = (self.us[1:] @ B.T).T
            self["state_intercept"] = c
            self["obs_intercept"] = (self.us @ D.T).T
        self.ssm.initialize_known(a1, F @ self.P0 @ F.T + G @ Q @ G.T)


def statsmodels_fit(model, tracks, *, start=None, x0=None, P0=None, exact: bool = True,
                    **fit_options) -> PeerFit:
    """statsmodels' MLE of ``model``'s free parameters on one track (an array as derive
    fit reads it: the measurements, then the inputs), from the parameters' examples or
    ``start`` (name -> value), timed; ``exact``: as :func:`peer_model`."""
    data = tracks[0] if isinstance(tracks, (list, tuple)) else tracks
    peer = peer_model(model, data, start=start, x0=x0, P0=P0, exact=exact)
    began = time.perf_counter()
    result = peer.fit(disp=False, **fit_options)
    seconds = time.perf_counter() - began
    return PeerFit(np.asarray(result.params), float(result.llf), seconds)


def peer_model(model, data, *, start=None, x0=None, P0=None,
               exact: bool = True) -> DeriveStateSpace:
    """The statsmodels model of ``model`` on ``data`` (measurements, then inputs);
    ``exact``: its filter never switches to the steady state (statsmodels' default stops
    updating P once it changes by less than 1e-19, which moves log L by ~1e-11 relative;
    False keeps the default, as the timing does)."""
    data = np.asarray(data, dtype=float)
    zs, us = data[:, :model.m], (data[:, model.m:] if model.inputs else None)
    start = dict(start or {})
    theta = [start.get(p.name, model.examples.get(p.name)) for p in model.parameters]
    peer = DeriveStateSpace(model, zs, us, x0, P0, theta)
    if exact:
        peer.ssm.tolerance = 0.0
    return peer


def statsmodels_score(model, data, theta, *, x0=None, P0=None,
                      method: str = "approx") -> np.ndarray:
    """statsmodels' score d log L / d theta of ``model`` on ``data`` at ``theta``: by
    default its complex-step derivative of its log-likelihood (``"harvey"``: Harvey's
    score of its filter, which gives NaN where a measurement is missing)."""
    theta = np.asarray(theta, dtype=float)
    peer = peer_model(model, data, start=dict(zip([p.name for p in model.parameters],
                                                  theta)), x0=x0, P0=P0)
    return np.asarray(peer.score(theta, transformed=True, method=method))


@dataclass(frozen=True)
class FitBench:
    """Seconds to fit one track: derive's fit (the filter generated once) and statsmodels'
    fit with its defaults, measured in ``repeats`` turns (derive's four fits and
    statsmodels' one in each), each the least CPU time
    of the process over the turns (both fit on one thread; CPU time leaves out the time a
    shared machine gives to others) and the median wall time; derive's generation and
    compilation once, from cold (a build cache of its own), wall time, a separate
    column; both log-likelihoods at their estimates."""

    derive_cpu: float
    derive_wall: float
    statsmodels_cpu: float
    statsmodels_wall: float
    generation_seconds: float
    derive_loglik: float
    statsmodels_loglik: float
    repeats: int

    @property
    def ratio(self) -> float:
        """statsmodels' CPU time over derive's (generation excluded)."""
        return self.statsmodels_cpu / self.derive_cpu

    def lines(self) -> list[str]:
        return [f"derive fit   {self.derive_cpu * 1e3:10.2f} ms CPU (least of "
                f"{4 * self.repeats}; wall median {self.derive_wall * 1e3:.2f} ms)   generation "
                f"and compilation {self.generation_seconds:.2f} s (once)",
                f"statsmodels  {self.statsmodels_cpu * 1e3:10.2f} ms CPU (least of "
                f"{self.repeats}; wall median {self.statsmodels_wall * 1e3:.2f} ms; "
                "MLEModel.fit defaults)",
                f"statsmodels / derive: {self.ratio:.1f}x CPU time (log-likelihoods "
                f"{self.derive_loglik:.12g} and {self.statsmodels_loglik:.12g})"]


def _timed(call):
    cpu, wall = time.process_time(), time.perf_counter()
    out = call()
    return out, time.process_time() - cpu, time.perf_counter() - wall


def bench(model, data, *, start=None, repeats: int = 5) -> FitBench:
    """Time derive's fit and statsmodels' fit of ``model`` on one track ``data``, in
    turns."""
    zs = [split_columns(model, data)[0]]
    with tempfile.TemporaryDirectory() as tmp:  # generation and a compilation from cold
        began = time.perf_counter()
        name, options = kernel_filter(model, zs)
        load_generated(model, name, options, "c", tmp, extra_cflags=KERNEL_CFLAGS, cache=tmp)
        generation = time.perf_counter() - began
    generated = kernel(model, zs)
    ours, theirs = [], []
    for _ in range(repeats):  # a turn: derive's fit (ten times shorter) four times
        ours += [_timed(lambda: fit(model, data, start=start, progress=False,
                                    generated=generated, workers=1)) for _ in range(4)]
        theirs.append(_timed(lambda: statsmodels_fit(model, data, start=start,
                                                     exact=False)))
    return FitBench(min(t[1] for t in ours), float(np.median([t[2] for t in ours])),
                    min(t[1] for t in theirs), float(np.median([t[2] for t in theirs])),
                    generation, ours[0][0].loglik, theirs[0][0].loglik, repeats)
