"""`derive show MODEL`: a model's matrices, inputs, sensors, values and free parameters."""

import textwrap

NAME = "show"
ORDER = 20
HELP = "print a model's matrices, inputs, sensors, values and free parameters"
EXAMPLE = "derive show cv\n  derive show my_model.toml"


def add_arguments(parser) -> None:
    parser.add_argument("model", help="catalog name or model-file path")


def run(args) -> int:
    from . import load_model

    model = load_model(args.model)
    print(f"{model.name}: {model.kind} model, n = {model.n}, m = {model.m}")
    if model.description:
        print(textwrap.fill(model.description, 88))
    if model.source:
        print(textwrap.fill(f"source: {model.source}", 88))
    print(f"states: {', '.join(model.states)}")
    for component in getattr(model, "manifolds", ()):
        print(f"manifold: {component.describe()}")
    if model.n_tangent != model.n:  # P, P0 and Q are over the tangent space
        print(f"tangent ({model.n_tangent}; P, P0, Q over it): {', '.join(model.tangent)}")
    print(f"measurements: {', '.join(model.measurements)}")
    if getattr(model, "angles", ()):
        print(f"angles (innovations wrapped to (-pi, pi]): {', '.join(model.angles)}")
    inputs = [u.name for u in getattr(model, "inputs", ())]
    print("inputs (u, one row per step): " + (", ".join(inputs) or "none"))
    print("values: " + (", ".join(f"{k} = {v}" for k, v in model.values.items()) or "none"))
    print("free parameters (p order): " + (", ".join(p.name for p in model.parameters)
                                           or "none"))
    if model.examples:
        print("examples: " + ", ".join(f"{k} = {v!r}" for k, v in model.examples.items()))
    mats = (("F", "G", "H", "Q", "R") if model.kind == "linear"
            else ("f", "h", "F_jacobian", "H_jacobian", "Q", "R"))
    if inputs:  # how the inputs enter: B and D (linear), Fu and their noise Qu (nonlinear)
        mats += (("B", "D") if model.kind == "linear" else ("Fu_jacobian", "Qu"))
    for k in mats:
        _matrix(k, getattr(model, k))
    for group in model.sensors:
        print(f"sensor {group.name}: measurements {', '.join(group.measurements)}; inputs "
              + (", ".join(u.name for u in group.inputs) or "none")
              + f"; update {group.update}" + ("; R given per call" if group.R_argument
                                               else ""))
        parts = (("h",) if group.h is not None else ("H", "D") if group.inputs else ("H",))
        for k in parts + (() if group.R_argument else ("R",)):
            _matrix(f"{group.name}.{k}", getattr(group, k))
    return 0


def _matrix(name: str, value) -> None:
    import sympy

    print(f"{name} =")
    print(textwrap.indent(sympy.pretty(value, use_unicode=False), "    "))
