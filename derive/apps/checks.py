"""The papers' equivalence claims, checked on the NumPy reference filters for one model.

Each :class:`Check` holds a measured maximum difference and the tolerance it must meet.
These are what `derive check` prints and what the report tabulates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import horizon, reference, riccati, system_checks
from ..errors import SteadyStateError, SymbolError
from .simulate import gnss_scenario, simulate_linear


@dataclass(frozen=True)
class Check:
    model: str
    claim: str
    value: float  # max abs (or relative, as the claim says) difference measured
    tolerance: float
    measure: str = "max diff"

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.value) and self.value <= self.tolerance)

    def line(self) -> str:
        """One printable row; differences are relative to max(1, |reference|)."""
        mark = "ok  " if self.passed else "FAIL"
        return (f"{mark} {self.model:18s} {self.claim:52s} {self.measure} {self.value:9.2e}"
                f" <= {self.tolerance:.0e}")


def _maxdiff(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) if np.size(a) else 0.0


def _relmax(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


def linear_checks(model, steps: int = 500, seed: int = 1) -> list[Check]:
    """KF = LF = JKLF, blocks = whole, A_KF = A_LF, REKF/RELF/doubling, IKF, FIR, prediction."""
    num = model.numeric()
    F, G, H, Q, R, x0, P0 = num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0
    run = simulate_linear(F, G, H, Q, R, x0, steps, seed)
    zs = run.zs
    name = model.name
    out: list[Check] = []
    xk, Pk = reference.kf(F, G, H, Q, R, x0, P0, zs)
    xl, Pl = reference.lf(F, G, H, Q, R, x0, P0, zs)
    xj, Pj = reference.jklf(F, G, H, Q, R, x0, P0, zs)
    out.append(Check(name, f"KF = LF, x and P, {steps} steps",
                     max(_relmax(xk, xl), _relmax(Pk, Pl)), 1e-10))
    out.append(Check(name, f"KF = JKLF, x and P, {steps} steps",
                     max(_relmax(xk, xj), _relmax(Pk, Pj)), 1e-10))
    try:
        blocks = model.blocks()
    except SymbolError:  # a block no measurement observes: filtered whole, not by blocks
        blocks = []
    if len(blocks) > 1:
        xs = np.zeros_like(xk)
        Ps = np.zeros_like(Pk)
        for blk in blocks:
            b = blk.model.numeric()
            s, k = list(blk.states), list(blk.measurements)
            xb, Pb = reference.kf(b.F, b.G, b.H, b.Q, b.R, b.x0, b.P0, zs[:, k])
            xs[:, s] = xb
            Ps[np.ix_(range(steps), s, s)] = Pb
        out.append(Check(name, f"whole model = its {len(blocks)} blocks merged (KF)",
                         max(_relmax(xk, xs), _relmax(Pk, Ps)), 1e-10))
    try:
        system_checks.check_steady_state(F, G, H, Q, R)
    except SteadyStateError:  # no steady state: the time-varying checks are all there is
        return out
    kfs = riccati.kf_steady(F, G, H, Q, R)
    lfs = riccati.lf_steady(F, G, H, Q, R)
    out.append(Check(name, "A_KF = A_LF and B_KF = B_LF",
                     max(_maxdiff(kfs.A, lfs.A), _maxdiff(kfs.B, lfs.B)), 1e-12))
    Pp_it = riccati.rekf_iterate(F, G, H, Q, R)
    out.append(Check(name, "REKF per-step iteration = doubling (Pp)",
                     _relmax(Pp_it, kfs.Pp), 1e-10))
    Pe_it = riccati.relf_iterate(F, G, H, Q, R)
    out.append(Check(name, "RELF per-step iteration = (I-KH)Pp (Pe)",
                     _relmax(Pe_it, kfs.Pe), 1e-10))
    out.append(Check(name, "time-varying KF P(k/k) -> steady Pe",
                     _maxdiff(Pk[-1], kfs.Pe), 1e-8))
    xss = reference.sskf(F, G, H, Q, R, x0, zs)
    xsl = reference.sslf(F, G, H, Q, R, x0, zs)
    out.append(Check(name, "SSKF = SSLF (x)", _relmax(xss, xsl), 1e-10))
    N = horizon.fir_order(kfs.A, 1e-6)
    xf = reference.fir(F, G, H, Q, R, zs, N=N)
    out.append(Check(name, f"FIR (N = {N}, eps 1e-6) = SSKF for the first N steps",
                     _relmax(xf[:N], xss[:N]), 1e-10))
    if abs(np.linalg.det(F)) > 1e-12:
        worst = 0.0
        for n_ahead in range(1, 6):
            xp = reference.pred(F, G, H, Q, R, x0, zs, n_ahead)
            FN = np.linalg.matrix_power(F, n_ahead)
            worst = max(worst, _relmax(xp, xss @ FN.T))
        out.append(Check(name, "N-step prediction = F^N x_SSKF(k/k), N = 1..5", worst,
                         1e-10))
    if np.linalg.eigvalsh(G @ Q @ G.T).min() > 0:
        xi, Pi = reference.ikf(F, G, H, Q, R, x0, P0, zs)
        out.append(Check(name, "information form = covariance form (MDKF)",
                         max(_relmax(xi, xk), _relmax(Pi, Pk)), 1e-10))
    return out


def nonlinear_checks(model, steps: int = 500, seed: int = 1) -> list[Check]:
    """EKF and UKF on the simulated GNSS scenario: both must track the static truth."""
    sc = gnss_scenario(steps=steps, seed=seed)
    fns = model.numeric_functions()
    # per-step inputs in the model's order: satellite-major (xs1, ys1, zs1, xs2, ...)
    ins = list(sc.satellites.reshape(steps, -1))
    ek = reference.ekf(fns["f"], fns["F"], fns["h"], fns["H"], fns["Q"], fns["R"], sc.x0,
                       sc.P0, sc.pseudoranges, inputs=ins)
    uk = reference.ukf(fns["f"], fns["h"], fns["Q"], fns["R"], sc.x0, sc.P0, sc.pseudoranges,
                       inputs=ins)
    truth = sc.truth[0]
    e_ekf = float(np.sqrt(np.mean((ek.xs[-100:, :3] - truth[:3]) ** 2)))
    e_ukf = float(np.sqrt(np.mean((uk.xs[-100:, :3] - truth[:3]) ** 2)))
    return [Check(model.name, "EKF position RMSE, last 100 s (m)", e_ekf, 5.0, "RMSE"),
            Check(model.name, "UKF position RMSE, last 100 s (m)", e_ukf, 5.0, "RMSE")]


def is_pseudorange_model(model) -> bool:
    """Whether ``model`` has the shape of the GNSS paper's scenario (:func:`nonlinear_checks`
    feeds it): a receiver's position and clock (4 states), one pseudorange per satellite,
    and each satellite's three coordinates as inputs of h alone."""
    return (model.n == 4 and not model.f_inputs and not model.sensors
            and len(model.inputs) == 3 * model.m)


def run_checks(model, steps: int = 500, seed: int = 1) -> list[Check]:
    """The papers' claims that apply to ``model``. The nonlinear ones are the GNSS paper's
    (a static receiver, satellite coordinates as inputs of h: :func:`is_pseudorange_model`);
    any other nonlinear model (the INS/GNSS EKFs, the radar tracker) is not that model and
    has no paper claim here (derive verify and its report sections check it)."""
    if model.kind == "linear":
        return linear_checks(model, steps, seed)
    if not is_pseudorange_model(model):
        return []
    return nonlinear_checks(model, steps, seed)
