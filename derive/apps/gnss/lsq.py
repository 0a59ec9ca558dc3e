"""Per-epoch least-squares position fix from pseudoranges (Gauss–Newton on x, y, z, b)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.apps.gnss.errors import GnssDataError
from derive.apps.simulate import pseudorange, pseudorange_jacobian


@dataclass(frozen=True)
class LsqFix:
    """state [x, y, z, b] (m); residuals ρ − h(state) (m); gdop = sqrt(trace((HᵀH)⁻¹));
    iterations used."""

    state: np.ndarray
    residuals: np.ndarray
    gdop: float
    iterations: int


def least_squares_fix(satellites, pseudoranges, x0=None, max_iterations: int = 20,
                      tolerance: float = 1e-4) -> LsqFix:
    """Unweighted iterative least squares for ρ_i = ||s_i − r|| + b from m >= 4 satellites
    (satellites (m, 3) ECEF m, pseudoranges (m,) m), starting at x0 (default: the Earth's
    centre, b = 0); stops when the update is below `tolerance` metres."""
    sats = np.asarray(satellites, dtype=float)
    rho = np.asarray(pseudoranges, dtype=float).reshape(-1)
    if sats.ndim != 2 or sats.shape[1] != 3 or len(sats) != len(rho):
        raise GnssDataError(f"satellites must have shape ({len(rho)}, 3) for {len(rho)} "
                            f"pseudoranges, got {sats.shape}")
    if len(rho) < 4:
        raise GnssDataError(f"a position fix needs >= 4 satellites, got {len(rho)}")
    x = np.zeros(4) if x0 is None else np.asarray(x0, dtype=float).reshape(4).copy()
    iterations = 0
    while True:
        iterations += 1
        H = pseudorange_jacobian(x, sats)
        dx, *_ = np.linalg.lstsq(H, rho - pseudorange(x, sats), rcond=None)
        x = x + dx
        if np.linalg.norm(dx) < tolerance:
            break
        if iterations == max_iterations:
                raise GnssDataError(f"least squares did not converge in {max_iterations} "
                                f"iterations (last step {np.linalg.norm(dx):.3g} m)")
    H = pseudorange_jacobian(x, sats)
    cofactor = np.linalg.inv(H.T @ H)
    return LsqFix(x, rho - pseudorange(x, sats), float(np.sqrt(np.trace(cofactor))),
                  iterations)
