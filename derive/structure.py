"""Independent blocks of a linear model, and block-diagonal composition.

A model splits into independent blocks when F, G Q G^T, H and R are block
diagonal up to a permutation of states and measurements. Blocks are the
connected components of the graph whose nodes are states, noise inputs and
measurements, with an edge wherever a (substituted) matrix entry couples two of
them and is not identically zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy

from .errors import ModelError, SymbolError
from .symbols import decimal


@dataclass(frozen=True)
class Block:
    """One independent block: indices into the parent's states and measurements."""

    states: tuple[int, ...]
    measurements: tuple[int, ...]
    noises: tuple[int, ...]
    model: object  # LinearModel of the block


def _components(size: int, edges) -> list[list[int]]:
    parent = list(range(size))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for a in range(size):
        groups.setdefault(find(a), []).append(a)
    return sorted(groups.values())


def _nonzero(mat) -> list[tuple[int, int]]:
    """The positions of the entries of ``mat`` that are not zero, read from its sparse form
    (a k-block model holds k blocks' entries, not n^2; todok keeps a 0.0, which != 0
    drops)."""
    return [position for position, value in mat.todok().items() if value != 0]


def find_blocks(model) -> list[Block]:
    """Split ``model`` into independent blocks, ordered by their first state.

    A model that does not split returns one block holding the whole model. A
    measurement that depends on no state cannot be filtered and is reported.
    """
    F, G, H, Q, R = (model.matrix(k) for k in ("F", "G", "H", "Q", "R"))
    n, m, q = model.n, model.m, G.cols
    st = list(range(n))
    ns = [n + c for c in range(q)]
    me = [n + q + k for k in range(m)]
    edges = []
    edges += [(st[i], st[j]) for i, j in _nonzero(F)]
    edges += [(st[i], ns[c]) for i, c in _nonzero(G)]
    edges += [(ns[c], ns[d]) for c, d in _nonzero(Q)]
    edges += [(me[k], st[i]) for k, i in _nonzero(H)]
    edges += [(me[k], me[j]) for k, j in _nonzero(R)]
    blocks = []
    for comp in _components(n + q + m, edges):
        s = tuple(a for a in comp if a < n)
        c = tuple(a - n for a in comp if n <= a < n + q)
        k = tuple(a - n - q for a in comp if a >= n + q)
        if not s:
            if k:
                raise SymbolError(
                    f"measurement {model.measurements[k[0]]!r} of model {model.name!r} "
                    "depends on no state")
            continue
        blocks.append((s, k, c))
    if len(blocks) == 1:
        s, k, c = blocks[0]
        return [Block(s, k, c, model)]
    return [_sub_block(model, i, s, k, c) for i, (s, k, c) in enumerate(blocks)]


def largest_block_size(model) -> int:
    """The size (states or measurements, the larger) of the largest part of ``model`` a
    filter may have to derive at once: its largest independent block (all of a nonlinear
    model, or of one whose blocks :func:`find_blocks` refuses)."""
    if model.kind != "linear":
        return max(model.n, model.m)
    try:
        blocks = find_blocks(model)
    except SymbolError:
        return max(model.n, model.m)
    return max(block_size(block) for block in blocks)


def block_size(block: Block) -> int:
    """The larger of a block's numbers of states and measurements."""
    return max(len(block.states), len(block.measurements))


def _sub_block(model, index: int, s, k, c) -> Block:
    if not k:
        raise SymbolError(f"states {[model.states[i] for i in s]} of model {model.name!r} "
                          "are observed by no measurement")
    if not c:
        c = (0,)  # a block without process noise still needs a (zero) noise input
        G = sympy.zeros(len(s), 1)
        Q = sympy.zeros(1, 1)
    else:
        G = model.G.extract(list(s), list(c))
        Q = model.Q.extract(list(c), list(c))
    sub_values = model.values
    cls = type(model)
    used = set()
    for mat in (model.F.extract(list(s), list(s)), G, model.H.extract(list(k), list(s)), Q,
                model.R.extract(list(k), list(k))):
        used |= {x.name for x in mat.free_symbols}
    sub = cls(
        f"{model.name}_block{index}",
        [model.states[i] for i in s],
        [model.measurements[j] for j in k],
        model.F.extract(list(s), list(s)),
        model.H.extract(list(k), list(s)),
        Q,
        model.R.extract(list(k), list(k)),
        G=G,
        values={nm: v for nm, v in sub_values.items() if nm in used},
        x0=model.x0.extract(list(s), [0]),
        P0=model.P0.extract(list(s), list(s)),
        P0_pattern=model.P0_pattern,
        description=f"block {index} of {model.name}",
        source=model.source,
        parameters=[p.name for p in model.parameters if p.name in used],
    )
    return Block(s, k, c, sub)


def compose(cls, name, models, suffixes=None, description="", source=""):
    """Block-diagonal composition; names get ``suffixes``; same-name symbols are shared.

    The free parameters keep the order of the blocks (the first block's, then the new
    ones of the next...). The composed P0 is block diagonal; its declared pattern is the
    narrowest of ``zero``, ``diagonal``, ``block``, ``dense`` that contains every block's
    declared pattern, so no entry a block allows is dropped.
    """
    models = list(models)
    if not models:
        raise SymbolError("compose needs at least one model")
    if suffixes is None:
        suffixes = [str(i) for i in range(len(models))]
    suffixes = list(suffixes)
    if len(suffixes) != len(models):
        raise SymbolError(f"compose: {len(models)} models but {len(suffixes)} suffixes")
    values: dict[str, sympy.Expr] = {}
    for mdl in models:
        for nm, v in mdl.values.items():
            if nm in values and values[nm] != v:
                raise SymbolError(f"symbol {nm!r} has two values: {decimal(values[nm])} and "
                                  f"{decimal(v)}")
            values[nm] = v
    order = list(dict.fromkeys(p.name for mdl in models for p in mdl.parameters))
    composed = cls(
        name,
        [s + sfx for mdl, sfx in zip(models, suffixes) for s in mdl.states],
        [s + sfx for mdl, sfx in zip(models, suffixes) for s in mdl.measurements],
        sympy.diag(*[mdl.F for mdl in models]),
        sympy.diag(*[mdl.H for mdl in models]),
        sympy.diag(*[mdl.Q for mdl in models]),
        sympy.diag(*[mdl.R for mdl in models]),
        G=sympy.diag(*[mdl.G for mdl in models]),
        values=values,
        x0=sympy.Matrix.vstack(*[mdl.x0 for mdl in models]),
        P0=sympy.diag(*[mdl.P0 for mdl in models]),
        P0_pattern="dense",
        description=description,
        source=source,
        parameters=[nm for nm in order if nm not in values],
    )
    wanted = _diagonal_union([mdl.pattern_mask() for mdl in models])
    for pattern in ("zero", "diagonal", "block"):
        try:
            mask = composed.pattern_mask(pattern)
        except ModelError:  # no independent blocks to speak of: "block" does not apply
            continue
        if _contains(mask, wanted):
            composed.P0_pattern = pattern
            break
    return composed


def _diagonal_union(masks) -> list[list[bool]]:
    """The block-diagonal boolean matrix with ``masks`` on its diagonal."""
    n = sum(len(mask) for mask in masks)
    out = [[False] * n for _ in range(n)]
    start = 0
    for mask in masks:
        for i, row in enumerate(mask):
            for j, flag in enumerate(row):
                out[start + i][start + j] = flag
        start += len(mask)
    return out


def _contains(outer, inner) -> bool:
    return all(o or not i for ro, ri in zip(outer, inner) for o, i in zip(ro, ri))
