"""Gauss–Hermite quadrature: a tensor grid, or a Smolyak sparse grid above 4 dimensions.

A one-dimensional rule of order p integrates polynomials of degree 2p − 1 exactly against
N(0, 1); the tensor grid inherits this per coordinate.  The sparse grid uses the
combination technique with rules of order 1, 3, 5, ... and is exact for total degree
2·level − 1, with p^d replaced by a number of points polynomial in d.

References
----------
G. H. Golub, J. H. Welsch, "Calculation of Gauss quadrature rules", Math. Comp. 23, 1969.
F. Heiss, V. Winschel, "Likelihood approximation by numerical integration on sparse
grids", J. Econometrics 144(1), 2008. doi:10.1016/j.jeconom.2007.12.004
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from math import comb
from typing import ClassVar

import numpy as np

from ..errors import SymmonError
from .base import BatchMoments, Transform, batch_sqrt, weighted_moments

__all__ = ["GaussHermite", "standard_rule"]

#: Above this dimension the default grid is sparse.
SPARSE_ABOVE = 4


@lru_cache(maxsize=64)
def _rule_1d(order: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.hermite_e.hermegauss(order)
    return x, w / np.sqrt(2 * np.pi)


def _tensor(orders: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    rules = [_rule_1d(p) for p in orders]
    X = np.array(list(itertools.product(*[r[0] for r in rules])))
    W = np.prod(np.array(list(itertools.product(*[r[1] for r in rules]))), axis=1)
    return X, W


@lru_cache(maxsize=64)
def standard_rule(dim: int, order: int, sparse: bool) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (N, dim) and weights (N,) for N(0, I_dim)."""
    if not sparse:
        return _tensor((order,) * dim)
    level = (order + 1) // 2
    q = dim + level - 1
    acc: dict[tuple, float] = {}
    for levels in itertools.product(range(1, level + 1), repeat=dim):
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


@dataclass(frozen=True)
class GaussHermite(Transform):
    """Gauss–Hermite quadrature of the moments.

    Parameters
    ----------
    order : int, default 5
        Points per dimension of the one-dimensional rule (exact to degree 2·order − 1).
    sparse : bool or None
        Use a Smolyak sparse grid; ``None`` picks it above 4 dimensions.
    """

    order: int = 5
    sparse: bool | None = None

    name: ClassVar[str] = "gh"

    def __post_init__(self) -> None:
        if not isinstance(self.order, (int, np.integer)) or self.order < 1:
            raise SymmonError(f"GaussHermite order must be a positive integer, got {self.order!r}")

    @property
    def exact_degree(self) -> float:  # type: ignore[override]
        """Degree of exactness: 2·order − 1 per coordinate for the tensor grid; total
        degree 2·level − 1, level = (order + 1) // 2, for the sparse grid.  With
        ``sparse=None`` the tensor value is given (the grid is tensor up to 4 dimensions).
        """
        if self.sparse:
            return 2 * ((self.order + 1) // 2) - 1
        return 2 * self.order - 1

    def batch(self, cm, means, covs, angles=frozenset()):
        K, n = means.shape
        sparse = n > SPARSE_ABOVE if self.sparse is None else self.sparse
        Z, w = standard_rule(n, int(self.order), bool(sparse))
        L = batch_sqrt(covs)
        X = means[:, None, :] + np.einsum("kij,nj->kni", L, Z)
        N = Z.shape[0]
        Y = cm.eval_g(X.reshape(K * N, n)).reshape(K, N, -1)
        mean, cov, cross = weighted_moments(Y, X, means, w, w, angles)
        return BatchMoments(mean, cov, cross, info={"evaluations": K * N, "sparse": bool(sparse)})
