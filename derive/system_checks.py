"""Checks of a linear system (F, G, H, Q, R) before its steady state is computed.

Plain NumPy on numeric arrays (the equations of MPT3D and SSPRED). The arrays are
coerced and their shapes and
covariances checked (failures raise derive.errors.ModelError subclasses); PBH tests then
require (F, H) detectable and (F, G Q^1/2) stabilisable, i.e. every eigenvalue with
|lambda| >= 1 observable / controllable, and a steady-state transition must be stable.
A failed condition raises derive.errors.SteadyStateError.
"""

from __future__ import annotations

import numpy as np

from derive.errors import MatrixPropertyError, ModelError, ShapeError, SteadyStateError

UNIT_CIRCLE_MARGIN = 1e-9
"""Eigenvalues with |lambda| >= 1 - margin are treated as not asymptotically stable."""
PBH_RANK_TOL = 1e-8
"""PBH tests call a mode unobservable/uncontrollable when sigma_min < tol * scale."""


# ---------------------------------------------------------------- input arrays
def numeric_matrix(name: str, value, rows: int | None, cols: int | None) -> np.ndarray:
    """``value`` as a finite float 2-D array of shape (rows, cols) (None: any); a scalar is
    1×1, a 1-D array a column (a row when ``name`` is "H"). Errors name the matrix."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name} must be a numeric matrix: {exc}") from exc
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    elif arr.ndim == 1:
        arr = arr.reshape(1, -1) if name == "H" else arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise ShapeError(f"{name} must be 2-D, got shape {arr.shape}")
    want = (arr.shape[0] if rows is None else rows, arr.shape[1] if cols is None else cols)
    if arr.shape != want:
        raise ShapeError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains NaN or inf")
    return arr


def _covariance(name: str, value, size: int, definite: bool) -> np.ndarray:
    arr = numeric_matrix(name, value, size, size)
    if not np.allclose(arr, arr.T, rtol=1e-12, atol=1e-14 * max(1.0, np.abs(arr).max())):
        raise MatrixPropertyError(f"{name} must be symmetric")
    low = np.linalg.eigvalsh((arr + arr.T) / 2).min()
    floor = -1e-12 * max(1.0, np.abs(arr).max())
    if low <= (0.0 if definite else floor):
        kind = "positive definite" if definite else "positive semidefinite"
        raise MatrixPropertyError(f"{name} must be {kind}; smallest eigenvalue {low:.3g}")
    return arr


def system_arrays(F, G, H, Q, R):
    """Validate and return (F, G, H, Q, R) as float 2-D arrays (shapes n×n, n×p, m×n, p×p,
    m×m). A 1-D H is a row, a 1-D G a column, a scalar a 1×1 matrix. R must be positive
    definite and Q positive semidefinite; failures raise ModelError subclasses."""
    F = numeric_matrix("F", F, None, None)
    n = F.shape[0]
    if F.shape[1] != n:
        raise ShapeError(f"F must be square, got {F.shape}")
    G = numeric_matrix("G", G, n, None)
    H = numeric_matrix("H", H, None, n)
    Q = _covariance("Q", Q, G.shape[1], definite=False)
    R = _covariance("R", R, H.shape[0], definite=True)
    return F, G, H, Q, R


def psd_sqrt(M: np.ndarray) -> np.ndarray:
    """Symmetric square root of a positive semidefinite matrix (negative rounding clipped)."""
    w, V = np.linalg.eigh((M + M.T) / 2)
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


# ---------------------------------------------------------------- PBH tests
def _eigen_clusters(F: np.ndarray) -> list[complex]:
    """Eigenvalues of F plus the mean of each cluster of close eigenvalues: a defective
    eigenvalue is computed only to ~eps^(1/k), the cluster mean to ~eps."""
    lams = list(np.linalg.eigvals(F))
    scale = max(1.0, np.linalg.norm(F, 2))
    points = list(lams)
    remaining = sorted(lams, key=lambda z: (z.real, z.imag))
    while remaining:
        seed = remaining.pop(0)
        cluster = [seed] + [z for z in remaining if abs(z - seed) < 1e-4 * scale]
        remaining = [z for z in remaining if abs(z - seed) >= 1e-4 * scale]
        if len(cluster) > 1:
            points.append(complex(np.mean(cluster)))
    return points


def _pbh_unobservable(F: np.ndarray, C: np.ndarray) -> complex | None:
    """An eigenvalue of F with |lambda| >= 1 whose mode C cannot see, else None."""
    n = F.shape[0]
    scale = max(1.0, np.linalg.norm(F, 2), np.linalg.norm(C, 2) if C.size else 0.0)
    for lam in _eigen_clusters(F):
        if abs(lam) < 1.0 - UNIT_CIRCLE_MARGIN:
            continue
        pbh = np.vstack([lam * np.eye(n) - F, C.astype(complex)])
        if np.linalg.svd(pbh, compute_uv=False)[-1] < PBH_RANK_TOL * scale:
            return complex(lam)
    return None


def _fmt(lam: complex) -> str:
    return f"{lam.real:.6g}" if abs(lam.imag) < 1e-12 else f"{lam:.6g}"


def check_detectable(F, H) -> None:
    """Raise SteadyStateError if (F, H) is not detectable (PBH test on |lambda| >= 1)."""
    F = np.asarray(F, dtype=float)
    lam = _pbh_unobservable(F, np.atleast_2d(np.asarray(H, dtype=float)))
    if lam is not None:
        raise SteadyStateError(
            f"(F, H) is not detectable: the mode of eigenvalue {_fmt(lam)} of F "
            f"(|lambda| = {abs(lam):.6g} >= 1) is not observed by H; "
            "no steady-state filter exists")


def check_stabilizable(F, G, Q) -> None:
    """Raise SteadyStateError if (F, G Q^1/2) is not stabilisable (PBH on |lambda| >= 1)."""
    F = np.asarray(F, dtype=float)
    B = np.atleast_2d(np.asarray(G, dtype=float)) @ psd_sqrt(np.atleast_2d(Q))
    lam = _pbh_unobservable(F.T, B.T)
    if lam is not None:
        raise SteadyStateError(
            f"(F, G Q^1/2) is not stabilizable: the mode of eigenvalue {_fmt(lam)} of F "
            f"(|lambda| = {abs(lam):.6g} >= 1) is not excited by the process noise; "
            "no steady-state filter exists")


def independent_parts(F, G, H, Q, R) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(states, noise inputs, measurements) of each independent block of the validated
    arrays: the connected components of the graph with an edge wherever a non-zero entry
    of F, G, Q, H or R couples two of them (as derive.structure.find_blocks, on numbers).
    """
    n, q, m = F.shape[0], G.shape[1], H.shape[0]
    parent = list(range(n + q + m))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for mat, row0, col0 in ((F, 0, 0), (G, 0, n), (Q, n, n), (H, n + q, 0),
                            (R, n + q, n + q)):
        for i, j in zip(*np.nonzero(mat)):
            a, b = find(row0 + int(i)), find(col0 + int(j))
            if a != b:
                parent[max(a, b)] = min(a, b)
    groups: dict[int, list[int]] = {}
    for a in range(n + q + m):
        groups.setdefault(find(a), []).append(a)
    parts = []
    for members in groups.values():
        nodes = np.array(members)
        states = nodes[nodes < n]
        if states.size:
            parts.append((states, nodes[(nodes >= n) & (nodes < n + q)] - n,
                          nodes[nodes >= n + q] - n - q))
    return parts


def check_steady_state(F, G, H, Q, R) -> None:
    """Validate the arrays, then check detectability and stabilisability, block by
    independent block (a mode of a block-diagonal system is one block's; the PBH tests
    cost a singular value decomposition per eigenvalue, so whole they grow like n^4)."""
    F, G, H, Q, R = system_arrays(F, G, H, Q, R)
    for states, noises, measurements in independent_parts(F, G, H, Q, R):
        Fb = F[np.ix_(states, states)]
        check_detectable(Fb, H[np.ix_(measurements, states)])
        check_stabilizable(Fb, G[np.ix_(states, noises)], Q[np.ix_(noises, noises)])


# ---------------------------------------------------------------- stability
def check_stable(A: np.ndarray, what: str) -> None:
    """Raise SteadyStateError naming ``what`` if A's spectral radius is >= 1."""
    rho = np.abs(np.linalg.eigvals(A)).max()
    if rho >= 1.0:
        raise SteadyStateError(f"{what} is not stable (spectral radius {rho:.6g} >= 1)")


__all__ = ["PBH_RANK_TOL", "UNIT_CIRCLE_MARGIN", "check_detectable", "check_stabilizable",
           "check_stable", "check_steady_state", "independent_parts", "numeric_matrix",
           "psd_sqrt", "system_arrays"]
