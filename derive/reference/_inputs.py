"""Shape checks for the reference filters' initial conditions and measurement series."""

from __future__ import annotations

import numpy as np

from derive.errors import ModelError, ShapeError


def state_vector(name: str, value, n: int) -> np.ndarray:
    """A length-n float vector (a scalar or (n, 1) column is accepted)."""
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (n,):
        raise ShapeError(f"{name} must have {n} entries, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains NaN or inf")
    return arr


def square(name: str, value, n: int) -> np.ndarray:
    """An n×n float matrix (a scalar is accepted when n = 1)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    if arr.shape != (n, n):
        raise ShapeError(f"{name} must have shape ({n}, {n}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name} contains NaN or inf")
    return arr


def measurement_series(zs, m: int, allow_nan: bool = True) -> np.ndarray:
    """Measurements as a (steps, m) array; a 1-D series is accepted when m = 1.
    NaN marks an absent component (allowed unless allow_nan is False); inf is refused."""
    arr = np.asarray(zs, dtype=float)
    if arr.ndim == 1 and m == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2 or arr.shape[1] != m:
        raise ShapeError(f"zs must have shape (steps, {m}), got {arr.shape}")
    if np.any(np.isinf(arr)) or (not allow_nan and np.any(np.isnan(arr))):
        raise ModelError("zs contains inf" if allow_nan else "zs contains NaN or inf")
    return arr


def inputs_series(inputs, steps: int) -> list:
    """Per-step inputs u_k (k = 1..steps) or a list of None."""
    if inputs is None:
        return [None] * steps
    if len(inputs) != steps:
        raise ShapeError(f"inputs must have one entry per measurement ({steps}), "
                         f"got {len(inputs)}")
    return list(inputs)
