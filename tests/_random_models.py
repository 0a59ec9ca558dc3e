"""A Hypothesis strategy of random stable linear models (n <= 6, m <= n, random sparsity),
shared by the tests that compare generated filters with the NumPy reference."""

import numpy as np
from hypothesis import strategies as st

from derive import LinearModel


@st.composite
def stable_models(draw):
    n = draw(st.integers(1, 6))
    m = draw(st.integers(1, n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    F = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.6)
    F += np.eye(n)
    F *= 0.95 / max(1.0, np.max(np.abs(np.linalg.eigvals(F))))
    H = rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.7)
    H[np.arange(m), rng.permutation(n)[:m]] = 1.0
    L = rng.normal(size=(n, n))
    Q = L @ L.T / n + 0.1 * np.eye(n)
    Lr = rng.normal(size=(m, m))
    R = Lr @ Lr.T / m + 0.2 * np.eye(m)
    rnd = np.round  # short decimals keep the exact constants small
    model = LinearModel("rand", [f"x{i}" for i in range(n)], [f"y{i}" for i in range(m)],
                        rnd(F, 3).tolist(), rnd(H, 3).tolist(), rnd((Q + Q.T) / 2, 3).tolist(),
                        rnd((R + R.T) / 2, 3).tolist())
    return model
