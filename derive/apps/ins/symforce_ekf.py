"""SymForce's generated C++ for a derive EKF's functions (predict and one update per sensor),
a benchmark peer: the functions, their generation time and operation counts.

The functions are the model's own equations (its f, h, Qu, Q and R, the sympy expressions of
the catalog model) converted to ``symforce.symbolic`` and differentiated, simplified and
printed by SymForce: predict x' = f(x, u, dt), P' = F P Fᵀ + Fu Qu Fuᵀ + Q(dt) with F and Fu
SymForce's Jacobians, all taken at x with its unit-norm groups renormalised where derive's
predict uses their invariant (derive.filters.sensors.unit_norm_noise); an update
S = H P Hᵀ + R, K = P Hᵀ S⁻¹ (SymForce's symbolic ``inv``: the batch update),
x' = x + K (z − h(x)), P' = P − K H P, then each unit-norm group of the model renormalised.
P is symmetric: each entry (i, j) is the symbol of (min(i, j), max(i, j)), like derive's
upper-triangle read. Each function is emitted by
``symforce.codegen.Codegen`` with its C++ backend.

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

import sympy

from derive import catalog
from derive.filters.sensors import program_name, unit_norm_noise
from derive.flops import c_function_body, count_c_text
from derive.trees import OpCount

MODEL = "ins_gnss"


@dataclass(frozen=True)
class SymforceFunction:
    name: str
    seconds: float          # Codegen.function + generate_function
    total_ops: int          # SymForce's own count
    count: OpCount          # its C++ counted by derive's rules
    source: str

    @property
    def cpp_name(self) -> str:
        """The name of its C++ function template (SymForce's CamelCase of ``name``)."""
        return _function_name(self.source)


def function_names(model) -> tuple[str, ...]:
    """predict and update_<sensor> per sensor, derive's program names."""
    return ("predict",) + tuple(program_name(s.name) for s in model.sensors)


def _symmetric(sf, P, n: int):
    out = sf.Matrix(n, n)
    for i in range(n):
        for j in range(n):
            out[i, j] = P[min(i, j), max(i, j)]
    return out


def model_functions(sf, model) -> dict:
    """name -> (the function, its SymForce input types) for ``model``, a derive
    NonlinearModel whose f uses inputs and whose only free parameter is the step dt (in f,
    Qu and Q; not in h)."""
    n, states = model.n, list(model.state_symbols)
    if len(model.parameters) != 1:
        raise ValueError(f"model {model.name!r}: the SymForce peer takes one free parameter "
                         f"(the step), not {list(model.parameters)}")
    (step,) = model.parameters
    inputs = list(model.f_inputs)
    groups = [[model.states.index(name) for name in g] for g in model.unit_norm]
    values = {sympy.Symbol(k, real=True): v for k, v in model.values.items()}

    def numeric(matrix):
        return matrix.subs(values)

    f, Qu, Q = (numeric(m) for m in (model.f, model.Qu, model.Q))

    def to_sf(expr, bind):
        return sf.sympify(expr).subs(bind)

    first = groups if unit_norm_noise(model) else []  # as derive's predict: at unit q

    def predict(x, P, u, dt):
        P = _symmetric(sf, P, n)
        bind = {sf.sympify(s): x[i] for i, s in enumerate(states)}
        bind |= {sf.sympify(s): u[i] for i, s in enumerate(inputs)}
        bind[sf.sympify(step)] = dt
        x_new = sf.Matrix([to_sf(e, bind) for e in f])
        F, Fu = x_new.jacobian(x), x_new.jacobian(u)
        noise_u = sf.Matrix([[to_sf(e, bind) for e in row] for row in Qu.tolist()])
        noise = sf.Matrix([[to_sf(e, bind) for e in row] for row in Q.tolist()])
        P_new = F * P * F.T + Fu * noise_u * Fu.T + noise
        # f, F, Fu and Q taken at x with its groups renormalised
        stand_in = {x[i]: sf.Symbol(f"unit_{i}") for rows in first for i in rows}
        unit = {}
        for rows in first:
            norm = sf.sqrt(sum(x[i] ** 2 for i in rows))
            unit |= {stand_in[x[i]]: x[i] / norm for i in rows}
        if unit:
            x_new, P_new = (m.subs(stand_in).subs(unit) for m in (x_new, P_new))
        return x_new, P_new

    def update_of(sensor):
        h, R = numeric(sensor.h), numeric(sensor.R)

        def update(x, P, z):
            P = _symmetric(sf, P, n)
            bind = {sf.sympify(s): x[i] for i, s in enumerate(states)}
            hx = sf.Matrix([to_sf(e, bind) for e in h])
            H = hx.jacobian(x)
            S = H * P * H.T + sf.Matrix([[sf.sympify(e) for e in row] for row in R.tolist()])
            K = P * H.T * S.inv()
            x_new = x + K * (z - hx)
            for rows in groups:
                norm = sf.sqrt(sum(x_new[i] ** 2 for i in rows))
                for i in rows:
                    x_new[i] = x_new[i] / norm
            return x_new, P - K * H * P
        return update

    vector, matrix = sf.Matrix(n, 1).__class__, sf.Matrix(n, n).__class__
    out = {"predict": (predict, [vector, matrix, sf.Matrix(len(inputs), 1).__class__,
                                 sf.Scalar])}
    for sensor in model.sensors:
        out[program_name(sensor.name)] = (update_of(sensor), [
            vector, matrix, sf.Matrix(len(sensor.measurements), 1).__class__])
    return out


def generate(names=None, model_name: str = MODEL) -> dict[str, SymforceFunction]:
    """Generate SymForce's C++ for each function of the catalog model (timed one by one)
    and count it."""
    import symforce  # optional: a benchmark peer

    # its warning about epsilon: these functions divide only by S and ‖q‖, never near zero
    symforce.set_log_level("error")
    import symforce.symbolic as sf
    from symforce.codegen import Codegen, CppConfig

    model = catalog.load(model_name)
    functions = model_functions(sf, model)
    out = {}
    with tempfile.TemporaryDirectory(prefix="derive-symforce-") as tmp:
        for name in names or function_names(model):
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
