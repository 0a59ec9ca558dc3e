"""Banded models whose P fills (each state moved by the next two, every fourth measured):
the latency schedule's largest sums, in Python and as a model file; and a hang guard for
the tests that derive them (it catches a hang, it does not time)."""

from __future__ import annotations

import signal
from contextlib import contextmanager

import sympy

from derive import LinearModel


@contextmanager
def hang_guard(seconds: int):
    def stop(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")
    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def band_model(n: int) -> LinearModel:
    """n states, each moved by the next two (dt, dt**2/2): one block whose P fills."""
    dt, q, r = sympy.symbols("dt q r", positive=True)
    F = [[1 if i == j else dt if j == i + 1 else dt ** 2 / 2 if j == i + 2 else 0
          for j in range(n)] for i in range(n)]
    H = [[1 if j == 4 * i else 0 for j in range(n)] for i in range((n + 3) // 4)]
    m = len(H)
    return LinearModel(f"band{n}", [f"x{i}" for i in range(n)], [f"z{i}" for i in range(m)],
                       F, H, sympy.eye(n) * q, sympy.eye(m) * r,
                       values={"dt": 0.1, "q": 0.01, "r": 0.1})


def band_file(n: int) -> str:
    """The same shape as a model file, F's entries numbers (dt = 0.1)."""
    def rows(matrix) -> str:
        return "[" + ", ".join("[" + ", ".join(row) + "]" for row in matrix) + "]"

    def diagonal(k: int, value: str) -> list[list[str]]:
        return [[value if i == j else "0" for j in range(k)] for i in range(k)]

    F = [["1" if i == j else "0.1" if j - i == 1 else "0.005" if j - i == 2 else "0"
          for j in range(n)] for i in range(n)]
    H = [["1" if j == 4 * i else "0" for j in range(n)] for i in range((n + 3) // 4)]
    names = ", ".join(f'"x{i}"' for i in range(n))
    measured = ", ".join(f'"z{i}"' for i in range(len(H)))
    return (f'[model]\nname = "band{n}"\nstates = [{names}]\nmeasurements = [{measured}]\n'
            f"[discrete]\nF = {rows(F)}\nH = {rows(H)}\nQ = {rows(diagonal(n, '0.01'))}\n"
            f"R = {rows(diagonal(len(H), '0.1'))}\n"
            f"[initial]\nx0 = [{', '.join(['0'] * n)}]\nP0 = {rows(diagonal(n, '1'))}\n")
