"""Gauss–Hermite nodes and weights for N(0, I): the tensor grid and the Smolyak sparse grid
(combination technique), with their sizes known before they are built.

References
----------
G. H. Golub, J. H. Welsch, "Calculation of Gauss quadrature rules", Math. Comp. 23, 1969.
F. Heiss, V. Winschel, "Likelihood approximation by numerical integration on sparse
grids", J. Econometrics 144(1), 2008. doi:10.1016/j.jeconom.2007.12.004
"""

from __future__ import annotations

import itertools
from functools import lru_cache
from math import comb

import numpy as np

from ..errors import ResourceError

__all__ = ["standard_rule", "rule_size", "MAX_NODES", "SPARSE_ABOVE"]

#: Above this dimension the default grid is sparse.
SPARSE_ABOVE = 4

#: The largest rule allowed: order^dim nodes for the tensor grid, the sum of the
#: combination technique's tensor grids for the sparse one.  Each node costs a row of
#: dim floats for the points and an evaluation of g, per Gaussian of the batch, so
#: 10^6 nodes are ~8·dim MB per array; a larger rule raises before it is built.
MAX_NODES = 10**6


@lru_cache(maxsize=64)
def _rule_1d(order: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.hermite_e.hermegauss(order)
    return x, w / np.sqrt(2 * np.pi)


def _tensor(orders: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    rules = [_rule_1d(p) for p in orders]
    X = np.array(list(itertools.product(*[r[0] for r in rules])))
    W = np.prod(np.array(list(itertools.product(*[r[1] for r in rules]))), axis=1)
    return X, W


def _level_tuples(dim: int, max_sum: int):
    """Tuples of ``dim`` positive integers with sum ≤ max_sum, in lexicographic order
    (those of itertools.product, without visiting the level^dim others)."""
    if dim == 0:
        yield ()
        return
    for first in range(1, max_sum - dim + 2):
        for rest in _level_tuples(dim - 1, max_sum - first):
            yield (first,) + rest


def rule_size(dim: int, order: int, sparse: bool) -> int:
    """The number of nodes the rule is built from, without building it.

    ``order**dim`` for the tensor grid; for the sparse grid the total size of the
    combination technique's tensor grids (an upper bound of the merged node count),
    counted level by level: the number of ways to reach each level sum, weighted by
    the grid sizes Π (2 lₖ − 1).
    """
    if not sparse:
        return order**dim
    level = (order + 1) // 2
    q = dim + level - 1
    ways = {0: 1}  # level sum → Σ Π (2 lₖ − 1) over the tuples of the dimensions so far
    for _ in range(dim):
        nxt: dict[int, int] = {}
        for s, c in ways.items():
            for lv in range(1, level + 1):
                if s + lv <= q:
                    nxt[s + lv] = nxt.get(s + lv, 0) + c * (2 * lv - 1)
        ways = nxt
    return sum(c for s, c in ways.items() if s >= q - dim + 1)


def _check_size(dim: int, order: int, sparse: bool) -> None:
    size = rule_size(dim, order, sparse)
    if size <= MAX_NODES:
        return
    kind = "sparse (Smolyak)" if sparse else "tensor"
    hint = "a lower order, UT (2n + 1 points) or Monte Carlo"
    if not sparse:
        # An upper bound: the grids before their common nodes merge (cost() counts the merged ones).
        hint = f"sparse=True (at most {rule_size(dim, order, True)} nodes), " + hint
    raise ResourceError(
        f"the Gauss-Hermite {kind} grid of order {order} in {dim} dimensions has {size} nodes, "
        f"above the limit MAX_NODES = {MAX_NODES}: use {hint}"
    )


@lru_cache(maxsize=64)
def standard_rule(dim: int, order: int, sparse: bool) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (N, dim) and weights (N,) for N(0, I_dim).

    Raises
    ------
    ResourceError
        If the rule has more than ``MAX_NODES`` nodes (:func:`rule_size`), before any
        of them is built.
    """
    _check_size(dim, order, sparse)
    if not sparse:
        return _tensor((order,) * dim)
    level = (order + 1) // 2
    q = dim + level - 1
    acc: dict[tuple, float] = {}
    for levels in _level_tuples(dim, q):
        s = sum(levels)
        if not q - dim + 1 <= s <= q:
            continue
        coef = (-1) ** (q - s) * comb(dim - 1, q - s)
        X, W = _tensor(tuple(2 * l - 1 for l in levels))
        for x, w in zip(np.round(X, 14), W):
            key = tuple(x + 0.0)  # +0.0 folds -0.0 into 0.0
            acc[key] = acc.get(key, 0.0) + coef * w
    keys = [k for k, w in acc.items() if w != 0.0]
    return np.array(keys), np.array([acc[k] for k in keys])
