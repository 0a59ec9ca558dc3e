"""`derive show MODEL`: a model's matrices, values and free parameters."""

import textwrap

NAME = "show"
ORDER = 20
HELP = "print a model's matrices, values and free parameters"
EXAMPLE = "derive show cv\n  derive show my_model.toml"


def add_arguments(parser) -> None:
    parser.add_argument("model", help="catalog name or model-file path")


def run(args) -> int:
    import sympy

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
    print("values: " + (", ".join(f"{k} = {v}" for k, v in model.values.items()) or "none"))
    print("free parameters (p order): " + (", ".join(p.name for p in model.parameters)
                                           or "none"))
    mats = (("F", "G", "H", "Q", "R") if model.kind == "linear"
            else ("f", "h", "F_jacobian", "H_jacobian", "Q", "R"))
    if getattr(model, "f_inputs", ()):  # inputs in f: their Jacobian and noise
        mats += ("Fu_jacobian", "Qu")
    for k in mats:
        print(f"{k} =")
        print(textwrap.indent(sympy.pretty(getattr(model, k), use_unicode=False), "    "))
    return 0
