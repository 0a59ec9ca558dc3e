"""SymForce's generated C++ for the INS/GNSS EKF's three functions (predict, the GNSS update
and the barometer update), a benchmark peer: generation time and operation counts.

The functions are the equations of SPEC.md §8 written with ``symforce.symbolic`` (no code
from SymForce's own examples): predict x' = f(x, u), P' = F P Fᵀ + Fu Qu Fuᵀ + Qb(dt); an
update S = H P Hᵀ + R, K = P Hᵀ S⁻¹ (SymForce's symbolic ``inv``; the baro's S is 1 x 1),
x' = x + K (z − h(x)), P' = P − K H P, then q' ← q'/‖q'‖. P is symmetric: each entry (i, j)
is the symbol of (min(i, j), max(i, j)), like derive's upper-triangle read. Each function is
emitted by ``symforce.codegen.Codegen`` with its C++ backend.

Counts: SymForce's own (the ``// Total ops: N`` its code generator prints), and the count of
its C++ by derive's C rules (derive.flops.count_c_text) after the C++ spellings are mapped
to C: ``x(i, j)`` indexing is a load, ``Scalar(c)`` and ``Scalar(a) / Scalar(b)`` are
constants, ``std::pow(b, k)`` with integer k ≥ 2 is k − 1 multiplications (derive's rule),
``std::pow(b, -1/2)`` a square root and a division, ``std::sqrt`` a square root.
SymForce's C++ has no fma, so its flops are its instructions.
"""

from __future__ import annotations

import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from derive.apps.ins import constants as c
from derive.flops import c_function_body, count_c_text
from derive.trees import OpCount

N = 16
GNSS_ROWS = (7, 8, 9, 4, 5, 6)
BARO_ROW = 9
FUNCTIONS = ("predict", "update_gnss", "update_baro")


@dataclass(frozen=True)
class SymforceFunction:
    name: str
    seconds: float          # Codegen.function + generate_function
    total_ops: int          # SymForce's own count
    count: OpCount          # its C++ counted by derive's rules
    source: str


def _symmetric(sf, P):
    out = sf.Matrix(N, N)
    for i in range(N):
        for j in range(N):
            out[i, j] = P[min(i, j), max(i, j)]
    return out


def _normalised(sf, x):
    norm = sf.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] = x[i] / norm
    return x


def _functions(sf):
    """name -> (the function, its SymForce input types)."""
    vector16, matrix16 = sf.Matrix(N, 1).__class__, sf.Matrix(N, N).__class__

    def predict(x, P, u, dt):
        P = _symmetric(sf, P)
        q0, q1, q2, q3 = (x[i] for i in range(4))
        w = [u[i] - x[10 + i] for i in range(3)]
        a = sf.Matrix([u[3 + i] - x[13 + i] for i in range(3)])
        r = [1, w[0] * dt / 2, w[1] * dt / 2, w[2] * dt / 2]
        quat = [q0 * r[0] - q1 * r[1] - q2 * r[2] - q3 * r[3],
                q0 * r[1] + q1 * r[0] + q2 * r[3] - q3 * r[2],
                q0 * r[2] - q1 * r[3] + q2 * r[0] + q3 * r[1],
                q0 * r[3] + q1 * r[2] - q2 * r[1] + q3 * r[0]]
        rot = sf.Matrix([[1 - 2 * (q2 ** 2 + q3 ** 2), 2 * (q1 * q2 - q0 * q3),
                          2 * (q1 * q3 + q0 * q2)],
                         [2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 ** 2 + q3 ** 2),
                          2 * (q2 * q3 - q0 * q1)],
                         [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1),
                          1 - 2 * (q1 ** 2 + q2 ** 2)]])
        accel = rot * a + sf.Matrix([0, 0, c.GRAVITY])
        x_new = sf.Matrix(quat + [x[4 + i] + accel[i] * dt for i in range(3)]
                          + [x[7 + i] + x[4 + i] * dt for i in range(3)]
                          + [x[10 + i] for i in range(6)])
        F, Fu = x_new.jacobian(x), x_new.jacobian(u)
        Qu = sf.Matrix.diag([c.SIGMA_GYRO ** 2] * 3 + [c.SIGMA_ACCEL ** 2] * 3)
        walk = sf.Matrix.diag([0] * 10 + [c.SIGMA_GYRO_BIAS ** 2 * dt] * 3
                              + [c.SIGMA_ACCEL_BIAS ** 2 * dt] * 3)
        return x_new, F * P * F.T + Fu * Qu * Fu.T + walk

    def update(x, P, z, rows, variances):
        P = _symmetric(sf, P)
        h = sf.Matrix([x[k] for k in rows]) if rows != (BARO_ROW,) else sf.Matrix([-x[BARO_ROW]])
        H = h.jacobian(x)
        S = H * P * H.T + sf.Matrix.diag(variances)
        K = P * H.T * S.inv()
        x_new = _normalised(sf, x + K * (z - h))
        return x_new, P - K * H * P

    def update_gnss(x, P, z):
        return update(x, P, z, GNSS_ROWS, list(c.GNSS_STD ** 2))

    def update_baro(x, P, z):
        return update(x, P, z, (BARO_ROW,), [c.BARO_STD ** 2])

    return {"predict": (predict, [vector16, matrix16, sf.Matrix(6, 1).__class__, sf.Scalar]),
            "update_gnss": (update_gnss, [vector16, matrix16, sf.Matrix(6, 1).__class__]),
            "update_baro": (update_baro, [vector16, matrix16, sf.Matrix(1, 1).__class__])}


def generate(names=FUNCTIONS) -> dict[str, SymforceFunction]:
    """Generate SymForce's C++ for each function (timed one by one) and count it."""
    import symforce  # optional: a benchmark peer

    # its warning about epsilon: these functions divide only by S and ‖q‖, never near zero
    symforce.set_log_level("error")
    import symforce.symbolic as sf
    from symforce.codegen import Codegen, CppConfig

    functions = _functions(sf)
    out = {}
    with tempfile.TemporaryDirectory(prefix="derive-symforce-") as tmp:
        for name in names:
            start = time.perf_counter()
            function, input_types = functions[name]
            codegen = Codegen.function(function, config=CppConfig(), name=name,
                                       input_types=input_types,
                                       output_names=["x_new", "P_new"])
            data = codegen.generate_function(output_dir=str(Path(tmp) / name))
            seconds = time.perf_counter() - start
            header = next(Path(data.function_dir).glob("*.h"))
            source = header.read_text(encoding="utf-8")
            out[name] = SymforceFunction(name, seconds, total_ops(source), count_cpp(source),
                                         source)
    return out


def total_ops(source: str) -> int:
    """SymForce's own count, from its ``// Total ops: N`` comment."""
    found = re.search(r"//\s*Total ops:\s*(\d+)", source)
    if found is None:
        raise ValueError("SymForce's code has no 'Total ops' comment")
    return int(found.group(1))


def _function_name(source: str) -> str:
    found = re.search(r"template <typename Scalar>\s*void\s+(\w+)\s*\(", source)
    if found is None:
        raise ValueError("no SymForce function definition found")
    return found.group(1)


_NUMBER = r"-?\d+(?:\.\d*)?(?:e[-+]?\d+)?"


def _matching(text: str, open_at: int) -> int:
    """Index of the parenthesis closing the one at open_at."""
    depth = 0
    for pos in range(open_at, len(text)):
        depth += {"(": 1, ")": -1}.get(text[pos], 0)
        if depth == 0:
            return pos
    raise ValueError("unbalanced parentheses in SymForce's code")


def _split_top(text: str) -> tuple[str, str]:
    depth = 0
    for pos, ch in enumerate(text):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            return text[:pos], text[pos + 1:]
    raise ValueError(f"std::pow without two arguments: {text!r}")


def _powers(text: str) -> str:
    """std::pow(b, e) as C operations under derive's rules (see the module docstring)."""
    while (start := text.find("std::pow(")) >= 0:
        open_at = start + len("std::pow")
        close = _matching(text, open_at)
        base, exponent = _split_top(text[open_at + 1:close])
        base = f"({_powers(base.strip())})"
        exponent = exponent.strip()
        value = eval(exponent, {"__builtins__": {}})  # a numeric literal or a/b of literals
        if value == int(value) and value >= 2:
            replaced = "*".join([base] * int(value))
        elif value == -0.5:
            replaced = f"1/sqrt{base}"
        elif value == 0.5:
            replaced = f"sqrt{base}"
        elif value == int(value) and value <= -1:
            replaced = "1/(" + "*".join([base] * int(-value)) + ")"
        else:
            replaced = f"pow({base}, {exponent})"
        text = text[:start] + f"({replaced})" + text[close + 1:]
    return text


def to_c(source: str) -> str:
    """The body of SymForce's function with its C++ spellings mapped to C."""
    body = c_function_body(source, _function_name(source))
    body = re.sub(r"//[^\n]*", " ", body)
    body = re.sub(r"if \(\w+ != nullptr\)", " ", body)
    body = re.sub(r"Eigen::Matrix<[^>]*>&\s*\w+\s*=\s*\(\*\w+\);", " ", body)
    # constants: Scalar(a) / Scalar(b) and Scalar(c)
    body = re.sub(rf"Scalar\(({_NUMBER})\)\s*/\s*Scalar\(({_NUMBER})\)", r"(\1/\2)", body)
    body = re.sub(rf"Scalar\(({_NUMBER})\)", r"\1", body)
    body = re.sub(rf"\(({_NUMBER})/({_NUMBER})\)",
                  lambda m: repr(float(m.group(1)) / float(m.group(2))), body)
    body = body.replace("Scalar(", "(").replace("const Scalar", "double")
    body = re.sub(r"\b(\w+)\((\d+),\s*(\d+)\)", r"\1_\2_\3", body)
    body = body.replace("std::sqrt(", "sqrt(")
    return _powers(body)


def count_cpp(source: str) -> OpCount:
    """SymForce's C++ counted by derive's C rules."""
    return count_c_text(to_c(source))
