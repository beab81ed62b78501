"""The fifth-degree cubature rule: 2n² + 1 fully symmetric points, exact to degree 5.

For N(0, I_n) the rule puts weight 2/(n + 2) at the origin, (4 − n)/(2(n + 2)²) at the 2n
points ±√(n + 2) eᵢ and 1/(n + 2)² at the 2n(n − 1) points √((n + 2)/2)(±eᵢ ± eⱼ), i < j.
Its moments match those of the Gaussian up to degree 5: E zᵢ² = 1, E zᵢ⁴ = 3,
E zᵢ² zⱼ² = 1 and every odd moment 0 by symmetry.  In one dimension it is the
three-point Gauss–Hermite rule.  For n > 4 the axis weights are negative, so, as for
the UT with a negative weight, a covariance can come out indefinite: it is then refused
(:class:`~symmon.errors.IndefiniteCovarianceError`, by :meth:`Transform.moments`).

This module is the worked example of docs/architecture.md: a rule is one file with a
frozen dataclass with its ``_moments`` hook, its declared capabilities and its ``presets``.

References
----------
A. H. Stroud, *Approximate calculation of multiple integrals*, Prentice-Hall, 1971.
B. Jia, M. Xin, Y. Cheng, "High-degree cubature Kalman filter", Automatica 49(2), 2013.
doi:10.1016/j.automatica.2012.11.014
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations, product
from typing import ClassVar

import numpy as np

from .base import Moments, Transform, batch_sqrt, evaluate_points, weighted_moments

__all__ = ["Cubature5"]


@lru_cache(maxsize=32)
def _rule(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (2n² + 1, n) and weights for N(0, I_n)."""
    r2 = n + 2.0
    axis = np.vstack([s * np.sqrt(r2) * np.eye(n)[i] for i in range(n) for s in (1.0, -1.0)])
    pairs = [np.sqrt(r2 / 2) * (si * np.eye(n)[i] + sj * np.eye(n)[j])
             for i, j in combinations(range(n), 2) for si, sj in product((1.0, -1.0), repeat=2)]
    Z = np.vstack([np.zeros((1, n)), axis] + ([np.array(pairs)] if pairs else []))
    w = np.concatenate([[2.0 / r2], np.full(2 * n, (4.0 - n) / (2 * r2**2)), np.full(len(pairs), 1.0 / r2**2)])
    return Z, w


@dataclass(frozen=True)
class Cubature5(Transform):
    """The fifth-degree cubature rule (module notes): exact mean for polynomials of
    degree 5, exact covariance for quadratics.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> from symmon.transforms import Cubature5
    >>> x, y = sp.symbols("x y")
    >>> m = sm.propagate(sm.Model([x, y], [x**2 * y**2 + x**4]), sm.Gaussian([0, 0], [[1, 0], [0, 1]]),
    ...                  transform=Cubature5())
    >>> round(float(m.mean[0]), 12)  # E x²y² + E x⁴ = 1 + 3
    4.0
    """

    exact_degree: ClassVar[float] = 5
    name: ClassVar[str] = "ct5"
    point_rule: ClassVar[bool] = True
    presets: ClassVar[dict] = {"ct5": ("the fifth-degree cubature rule (2n^2 + 1 points)", lambda **_: Cubature5())}

    def cost(self, n_w: int) -> int:
        """2 n_w² + 1 points."""
        return 2 * n_w * n_w + 1

    def unit_rule(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points for N(0, I_n), mean weights and covariance weights (the same)."""
        Z, w = _rule(n)
        return Z, w, w

    def outer_rule(self, mean, cov):
        """The rule's own points and weights over N(mean, cov)."""
        Z, w = _rule(mean.shape[0])
        return mean + Z @ batch_sqrt(cov[None])[0].T, w

    def _moments(self, cm, means, covs, angles, executor):
        K, n = means.shape
        Z, w = _rule(n)
        X = means[:, None, :] + np.einsum("kij,nj->kni", batch_sqrt(covs), Z)
        Y = evaluate_points(cm, X, self, angles)
        mean, cov, cross, scale = weighted_moments(Y, X, means, w, w, angles)
        return Moments(mean, cov, cross, evaluations=K * Z.shape[0], cov_scale=scale)
