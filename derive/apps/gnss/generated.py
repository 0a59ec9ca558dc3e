"""The generated EKF and UKF as (predict, update1) pairs for derive.apps.gnss.drive / run_real.

The filters are derived from :func:`scalar_model`: one pseudorange
``ρ = ||s − [x, y, z]|| + b`` with the satellite position ``s`` as its per-step input and
``Q = diag(q_position, q_position, q_position, q_clock)``, ``R = σ²`` as free parameters
(``p``), so one generated file serves any FilterSettings. An epoch is one ``predict`` and
one ``update1`` per pseudorange: any number of satellites per epoch (sequential scalar
updates; no variants per satellite count). The NumPy pair of derive.apps.gnss.scalar_updates
is the reference these must equal.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from derive.apps.gnss.run import FilterSettings
from derive.apps.gnss.scalar_updates import ScalarUpdate
from derive.errors import ModelError
from derive.flops import LANGUAGES
from derive.model import NonlinearModel
from derive.pipeline import load_generated

PARAMETERS = ("q_clock", "q_position", "sigma2")
"""The free parameters of scalar_model, in the order of p."""



def scalar_model() -> NonlinearModel:
    """The GNSS model with one pseudorange and free noise parameters (see the module)."""
    return NonlinearModel(
        "gnss_scalar", ["x", "y", "z", "b"], ["rho"],
        f=["x", "y", "z", "b"],
        h=["sqrt((sx - x)**2 + (sy - y)**2 + (sz - z)**2) + b"],
        Q=[["q_position", 0, 0, 0], [0, "q_position", 0, 0], [0, 0, "q_position", 0],
           [0, 0, 0, "q_clock"]],
        R=[["sigma2"]], inputs=["sx", "sy", "sz"], parameters=PARAMETERS,
        description="One GNSS pseudorange per update; noise variances are runtime "
                    "parameters.",
        source="the GNSS paper with Q and R free (derive.apps.gnss.generated)")


def parameters(settings: FilterSettings) -> np.ndarray:
    """p for the generated filters: q_clock, q_position, σ²."""
    return np.array([settings.q_clock, settings.q_position, settings.sigma ** 2])


def _options(name: str, settings: FilterSettings) -> dict:
    if name == "ekf":
        return {}
    return {"alpha": settings.alpha, "beta": settings.beta, "kappa": settings.kappa}


def _load(name: str, settings: FilterSettings, lang: str, workdir: str | Path | None):
    return load_generated(scalar_model(), name, _options(name, settings), lang,
                          workdir).module(lang)


def _pair(module, p: np.ndarray):
    def predict(x, P):
        x_new, P_new = module.predict(x, np.reshape(P, 16), p)
        return np.asarray(x_new, dtype=float), np.reshape(np.asarray(P_new, dtype=float), (4, 4))

    def update1(x, P, rho, sat):
        out = module.update1(x, np.reshape(P, 16), [float(rho)],
                             np.asarray(sat, dtype=float).reshape(3), p)
        x_new, P_new, nu, var = (np.asarray(a, dtype=float) for a in out)
        return ScalarUpdate(x_new, P_new.reshape(4, 4), float(nu[0]), float(var[0]))

    return predict, update1


def generated_filters(settings: FilterSettings | None = None, lang: str = "c",
                      workdir: str | Path | None = None) -> dict[str, tuple]:
    """{'EKF': (predict, update1), 'UKF': (predict, update1)} from generated code.

    ``lang``: "c" (compiled with cffi) or "python". The files go to ``workdir`` (default:
    a temporary directory removed once the modules are loaded)."""
    if lang not in LANGUAGES:
        raise ModelError(f"lang must be one of {LANGUAGES}, got {lang!r}")
    settings = FilterSettings() if settings is None else settings
    p = parameters(settings)
    return {name.upper(): _pair(_load(name, settings, lang, workdir), p)
            for name in ("ekf", "ukf")}
