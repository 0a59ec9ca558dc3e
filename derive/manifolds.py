"""State components on a manifold: unit quaternions and angles, and the tangent space.

A nonlinear model may declare some of its states to live on a manifold
(``NonlinearModel(manifolds=...)``, ``[nonlinear] manifolds`` in a model file):

- a **unit quaternion**, four stored states, scalar first, with three tangent coordinates
  (a rotation vector δθ); its ``error`` says in which frame the error is taken:
  ``local`` (body): ``q_true = q ⊗ δq(δθ)``, ``global`` (world): ``q_true = δq(δθ) ⊗ q``;
- an **angle**, one stored state wrapped to (-π, π], one tangent coordinate.

Every other state is Euclidean (its own tangent coordinate). The tangent coordinates are
in state order, a quaternion's three at the place of its first component
(:class:`TangentLayout`). The covariance of an error-state filter lives in the tangent
space (n_tangent x n_tangent), x in the storage space (n).

The operations, in both sympy (for the derivation) and NumPy (for the simulation and the
references):

- ``x ⊞ δ`` (:func:`boxplus`): δq(δθ) = [1, δθ/2] (first order), the product renormalised,
  so the injected quaternion is the exact rotation of the unit quaternion along
  [1, δθ/2]; an angle's x + δ wrapped; a Euclidean x + δ;
- the projection onto the manifold (:func:`project`), applied to the predicted nominal
  state: a quaternion renormalised, an angle wrapped;
- ``N(x) = ∂(x ⊞ δ)/∂δ`` at δ = 0 (n x n_tangent, :func:`retraction_jacobian`) for a unit
  x: a local quaternion's ½ L(q)[:, 1:], a global one's ½ R(q)[:, 1:] (L(q) p = q ⊗ p,
  R(p) q = q ⊗ p);
- ``M(y) = ∂(y' ⊟ y)/∂y'`` at y' = y (n_tangent x n, :func:`lift_jacobian`), where y is a
  quaternion not necessarily of unit norm (the prediction before its projection) and the
  error is taken from the projections of both: local (2/|y|²) L(y*)[1:, :], global
  (2/|y|²) R(y*)[1:, :].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import sympy

from .errors import ModelError, SymbolError
from .symbols import check_names

QUATERNION, ANGLE = "quaternion", "angle"
KINDS = (QUATERNION, ANGLE)
LOCAL, GLOBAL = "local", "global"
ERRORS = (LOCAL, GLOBAL)

#: The injection's form, stated in the headers of the filters that use it (ASCII: the
#: headers are C comments): [+] is ⊞, (x) the quaternion product ⊗, dth the δθ.
INJECTION = ("x [+] dx: quaternion q (x) [1, dth/2] (local error) or [1, dth/2] (x) q "
             "(global), renormalised (a first-order dq, made unit); angle x + d wrapped to "
             "(-pi, pi]; others x + d")


@dataclass(frozen=True)
class Manifold:
    """One declared manifold component: ``kind`` (quaternion or angle), its stored
    ``states`` (a quaternion's four, scalar first), its ``tangent`` coordinates' names and,
    for a quaternion, the frame of its ``error`` (local or global)."""

    kind: str
    states: tuple[str, ...]
    tangent: tuple[str, ...]
    error: str = ""

    def describe(self) -> str:
        """``quaternion (q0, q1, q2, q3), local error q_true = q (x) dq(dth), tangent (th1,
        th2, th3)`` (ASCII, for C comments)."""
        if self.kind == ANGLE:
            return f"angle {self.states[0]} wrapped to (-pi, pi]"
        frame = "q_true = q (x) dq(dth)" if self.error == LOCAL else "q_true = dq(dth) (x) q"
        return (f"quaternion ({', '.join(self.states)}), {self.error} error {frame}, "
                f"tangent ({', '.join(self.tangent)})")


def _quaternion_tangent(states: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"d{s}" for s in states[1:])


def parse_manifolds(declared, states: Sequence[str]) -> tuple[Manifold, ...]:
    """The manifold components of ``declared``: a list of tables, each
    ``{"quaternion": [four states], "error": "local" | "global", "tangent": [three names]}``
    (``error`` local and ``tangent`` d<q1>, d<q2>, d<q3> when not given) or
    ``{"angle": "state"}``. Refused, in one line naming the component: a quaternion of
    other than four states, a name that is not a state, a state in two components."""
    if declared is None:
        return ()
    if isinstance(declared, (str, Mapping)) or not isinstance(declared, Sequence):
        raise ModelError("manifolds must be a list of tables, e.g. [{quaternion = ['q0', "
                         "'q1', 'q2', 'q3']}, {angle = 'psi'}], got "
                         f"{type(declared).__name__} {declared!r}")
    out: list[Manifold] = []
    owner: dict[str, int] = {}
    for i, item in enumerate(declared):
        where = f"manifolds[{i}]"
        if not isinstance(item, Mapping):
            raise ModelError(f"{where} must be a table with a key quaternion or angle, got "
                             f"{type(item).__name__} {item!r}")
        kinds = [k for k in KINDS if k in item]
        if len(kinds) != 1:
            raise ModelError(f"{where} must have exactly one of the keys quaternion, angle; "
                             f"got {sorted(item)}")
        kind = kinds[0]
        allowed = {QUATERNION: {QUATERNION, "error", "tangent"}, ANGLE: {ANGLE}}[kind]
        stray = sorted(set(item) - allowed)
        if stray:
            raise ModelError(f"{where} ({kind}): unknown key {stray[0]!r}; a {kind} takes "
                             f"{', '.join(sorted(allowed))}")
        value = item[kind]
        if kind == ANGLE:
            if not isinstance(value, str):
                raise ModelError(f"{where}: angle must name one state, got {value!r}")
            names = check_names([value], f"{where} angle")
        else:
            if isinstance(value, str) or not isinstance(value, Sequence):
                raise ModelError(f"{where}: quaternion must list its four states (scalar "
                                 f"first), got {value!r}")
            names = check_names(value, f"{where} quaternion")
            if len(names) != 4:
                raise ModelError(f"{where}: a quaternion has 4 components (scalar first), "
                                 f"got {len(names)}: {list(names)}")
        for nm in names:
            if nm not in states:
                raise SymbolError(f"{where} ({kind}) names {nm!r}, which is not a state")
            if nm in owner:
                raise SymbolError(f"{where} ({kind}): state {nm!r} is already in "
                                  f"manifolds[{owner[nm]}]")
            owner[nm] = i
        if kind == ANGLE:
            out.append(Manifold(ANGLE, tuple(names), tuple(names)))
            continue
        error = item.get("error", LOCAL)
        if error not in ERRORS:
            raise ModelError(f"{where}: error must be one of {', '.join(ERRORS)} (q ⊗ δq or "
                             f"δq ⊗ q), got {error!r}")
        tangent = (check_names(item["tangent"], f"{where} tangent") if "tangent" in item
                   else _quaternion_tangent(tuple(names)))
        if len(tangent) != 3:
            raise ModelError(f"{where}: a quaternion's tangent has 3 coordinates, got "
                             f"{len(tangent)}: {list(tangent)}")
        out.append(Manifold(QUATERNION, tuple(names), tuple(tangent), error))
    return tuple(out)


@dataclass(frozen=True)
class TangentLayout:
    """Where each stored state's tangent coordinates are: ``tangent`` the names of the
    n_tangent coordinates in order; ``manifolds`` the components; ``slots`` for each
    component (in ``manifolds`` order) its stored indices and its tangent indices."""

    states: tuple[str, ...]
    manifolds: tuple[Manifold, ...]
    tangent: tuple[str, ...]
    slots: tuple[tuple[tuple[int, ...], tuple[int, ...]], ...]
    euclidean: tuple[tuple[int, int], ...]  # (stored index, tangent index)

    @classmethod
    def of(cls, states: Sequence[str], manifolds: tuple[Manifold, ...]) -> TangentLayout:
        first = {m.states[0]: m for m in manifolds}
        inside = {s for m in manifolds for s in m.states}
        tangent: list[str] = []
        at: dict[Manifold, tuple[int, ...]] = {}
        euclidean = []
        for i, s in enumerate(states):
            if s in first:
                m = first[s]
                at[m] = tuple(range(len(tangent), len(tangent) + len(m.tangent)))
                tangent += m.tangent
            elif s not in inside:
                euclidean.append((i, len(tangent)))
                tangent.append(s)
        slots = tuple((tuple(states.index(s) for s in m.states), at[m]) for m in manifolds)
        return cls(tuple(states), manifolds, tuple(tangent), slots, tuple(euclidean))

    @property
    def n(self) -> int:
        return len(self.states)

    @property
    def n_tangent(self) -> int:
        return len(self.tangent)


# -- quaternion algebra (sympy or NumPy entries alike) -------------------------------------


def left(q) -> list[list]:
    """L(q): L(q) p = q ⊗ p (Hamilton, scalar first)."""
    a, b, c, d = q
    return [[a, -b, -c, -d], [b, a, -d, c], [c, d, a, -b], [d, -c, b, a]]


def right(p) -> list[list]:
    """R(p): R(p) q = q ⊗ p."""
    a, b, c, d = p
    return [[a, -b, -c, -d], [b, a, d, -c], [c, -d, a, b], [d, c, -b, a]]


def conjugate(q) -> list:
    return [q[0], -q[1], -q[2], -q[3]]


def _product(matrix, vector) -> list:
    return [sum((row[j] * vector[j] for j in range(4)), 0 * vector[0]) for row in matrix]


# -- sympy: the derivation's forms ---------------------------------------------------------


def wrap(angle: sympy.Expr) -> sympy.Expr:
    """``angle`` wrapped to (-π, π]: angle - 2π ceil((angle - π) / 2π), branch-free and
    exact for an angle already inside."""
    two_pi = 2 * sympy.pi
    return angle - two_pi * sympy.ceiling((angle - sympy.pi) / two_pi)


def boxplus(layout: TangentLayout, x: Sequence, delta: Sequence) -> list:
    """x ⊞ δ (see the module docstring), as sympy expressions of ``x`` and ``delta``."""
    out = list(x)
    for i, t in layout.euclidean:
        out[i] = x[i] + delta[t]
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            out[stored[0]] = wrap(x[stored[0]] + delta[tangent[0]])
            continue
        q = [x[i] for i in stored]
        dq = [sympy.Integer(1)] + [delta[t] / 2 for t in tangent]
        product = _product(left(q), dq) if m.error == LOCAL else _product(right(q), dq)
        norm = sympy.sqrt(sum(e ** 2 for e in product))
        for i, e in zip(stored, product):
            out[i] = e / norm
    return out


def project(layout: TangentLayout, y: Sequence) -> list:
    """``y`` on the manifold: each quaternion divided by its norm, each angle wrapped."""
    out = list(y)
    for m, (stored, _) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            out[stored[0]] = wrap(y[stored[0]])
            continue
        norm = sympy.sqrt(sum(y[i] ** 2 for i in stored))
        for i in stored:
            out[i] = y[i] / norm
    return out


def retraction_jacobian(layout: TangentLayout, x: Sequence) -> sympy.Matrix:
    """N(x) = ∂(x ⊞ δ)/∂δ at δ = 0 for a unit quaternion (n x n_tangent)."""
    N = sympy.zeros(layout.n, layout.n_tangent)
    for i, t in layout.euclidean:
        N[i, t] = 1
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            N[stored[0], tangent[0]] = 1
            continue
        q = [x[i] for i in stored]
        basis = left(q) if m.error == LOCAL else right(q)
        for r, i in enumerate(stored):
            for c, t in enumerate(tangent):
                N[i, t] = basis[r][c + 1] / 2
    return N


def lift_jacobian(layout: TangentLayout, y: Sequence) -> tuple[sympy.Matrix, dict]:
    """(A, scale): M(y) = ∂(y' ⊟ y)/∂y' at y' = y is A with each quaternion's rows times its
    scale 2/|y|² (n_tangent x n); ``scale`` maps those rows' tangent indices to
    (|y|², the quaternion's stored indices), so the caller may reduce the numerators and
    the norm apart."""
    A = sympy.zeros(layout.n_tangent, layout.n)
    scale = {}
    for i, t in layout.euclidean:
        A[t, i] = 1
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            A[tangent[0], stored[0]] = 1
            continue
        star = conjugate([y[i] for i in stored])
        basis = left(star) if m.error == LOCAL else right(star)
        norm2 = sum(y[i] ** 2 for i in stored)
        for r, t in enumerate(tangent):
            for c, i in enumerate(stored):
                A[t, i] = 2 * basis[r + 1][c]
            scale[t] = (norm2, stored)
    return A, scale


# -- NumPy: the simulation's and the references' forms ------------------------------------


def wrap_numeric(angle):
    """``angle`` wrapped to (-π, π] (NumPy)."""
    return angle - 2 * np.pi * np.ceil((angle - np.pi) / (2 * np.pi))


def boxplus_numeric(layout: TangentLayout, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """x ⊞ δ in NumPy (the module docstring's form)."""
    out = np.array(x, dtype=float)
    for i, t in layout.euclidean:
        out[i] = x[i] + delta[t]
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            out[stored[0]] = wrap_numeric(x[stored[0]] + delta[tangent[0]])
            continue
        q = np.asarray(x, dtype=float)[list(stored)]
        dq = np.concatenate(([1.0], 0.5 * np.asarray(delta, dtype=float)[list(tangent)]))
        basis = np.array(left(q) if m.error == LOCAL else right(q))
        product = basis @ dq
        out[list(stored)] = product / np.linalg.norm(product)
    return out


def project_numeric(layout: TangentLayout, y: np.ndarray) -> np.ndarray:
    """``y`` on the manifold (NumPy)."""
    out = np.array(y, dtype=float)
    for m, (stored, _) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            out[stored[0]] = wrap_numeric(y[stored[0]])
        else:
            out[list(stored)] = out[list(stored)] / np.linalg.norm(out[list(stored)])
    return out


def retraction_numeric(layout: TangentLayout, x: np.ndarray) -> np.ndarray:
    """N(x) in NumPy."""
    N = np.zeros((layout.n, layout.n_tangent))
    for i, t in layout.euclidean:
        N[i, t] = 1.0
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            N[stored[0], tangent[0]] = 1.0
            continue
        q = np.asarray(x, dtype=float)[list(stored)]
        basis = np.array(left(q) if m.error == LOCAL else right(q))
        N[np.ix_(stored, tangent)] = 0.5 * basis[:, 1:]
    return N


def lift_numeric(layout: TangentLayout, y: np.ndarray) -> np.ndarray:
    """M(y) in NumPy."""
    M = np.zeros((layout.n_tangent, layout.n))
    for i, t in layout.euclidean:
        M[t, i] = 1.0
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            M[tangent[0], stored[0]] = 1.0
            continue
        q = np.asarray(y, dtype=float)[list(stored)]
        star = np.array(conjugate(q))
        basis = np.array(left(star) if m.error == LOCAL else right(star))
        M[np.ix_(tangent, stored)] = 2.0 * basis[1:, :] / float(q @ q)
    return M


def boxminus_numeric(layout: TangentLayout, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """x ⊟ ref, the tangent coordinates of ``x`` about ``ref`` (both on the manifold): a
    quaternion's 2 vec(ref* ⊗ x) (local) or 2 vec(x ⊗ ref*) (global) with the sign of the
    scalar part made positive (the rotation's short way), an angle's wrapped difference."""
    out = np.zeros(layout.n_tangent)
    for i, t in layout.euclidean:
        out[t] = x[i] - ref[i]
    for m, (stored, tangent) in zip(layout.manifolds, layout.slots):
        if m.kind == ANGLE:
            out[tangent[0]] = wrap_numeric(x[stored[0]] - ref[stored[0]])
            continue
        q, r = np.asarray(x, float)[list(stored)], np.asarray(ref, float)[list(stored)]
        if m.error == LOCAL:
            e = np.array(left(conjugate(r))) @ q
        else:
            e = np.array(right(conjugate(r))) @ q
        out[list(tangent)] = 2.0 * np.sign(e[0] or 1.0) * e[1:]
    return out


__all__ = ["ANGLE", "ERRORS", "GLOBAL", "INJECTION", "KINDS", "LOCAL", "QUATERNION",
           "Manifold", "TangentLayout", "boxminus_numeric", "boxplus", "boxplus_numeric",
           "conjugate", "left", "lift_jacobian", "lift_numeric", "parse_manifolds", "project",
           "project_numeric", "retraction_jacobian", "retraction_numeric", "right", "wrap",
           "wrap_numeric"]
