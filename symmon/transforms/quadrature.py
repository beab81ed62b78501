"""Gauss–Hermite quadrature: a tensor grid, or a Smolyak sparse grid above 4 dimensions.

A one-dimensional rule of order p integrates polynomials of degree 2p − 1 exactly against
N(0, 1); the tensor grid inherits this per coordinate.  The sparse grid uses the
combination technique with rules of order 1, 3, 5, ... and is exact for total degree
2·level − 1, with p^d replaced by a number of points polynomial in d.

Error estimate from two orders: with ``error_estimate=True`` the rule of order p + 2 is
evaluated as well and the result's ``error`` holds ``ERROR_SAFETY · |Q_p − Q_{p+2}|``
for the mean, covariance and cross-covariance.  Writing e_p = Q_p − I for the error of the
order-p rule, |e_p| ≤ |Q_p − Q_{p+2}| + |e_{p+2}|; whenever the rule has started to
converge, |e_{p+2}| ≤ |e_p| / 2, and then |e_p| ≤ 2 |Q_p − Q_{p+2}|.  For a polynomial g
of degree ≤ 2p + 3 (per coordinate) Q_{p+2} is exact and the estimate is twice the error.

References
----------
G. H. Golub, J. H. Welsch, "Calculation of Gauss quadrature rules", Math. Comp. 23, 1969.
F. Heiss, V. Winschel, "Likelihood approximation by numerical integration on sparse
grids", J. Econometrics 144(1), 2008. doi:10.1016/j.jeconom.2007.12.004
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..core.angles import wrap_angle
from ..errors import QuadratureWarning, SymmonError, plain_repr
from .nodes import MAX_NODES, SPARSE_ABOVE, rule_size, standard_rule
from .base import _WARNED, Moments, Transform, batch_sqrt, evaluate_points, weighted_moments

__all__ = ["GaussHermite", "standard_rule", "rule_size", "ERROR_SAFETY", "MAX_NODES"]


#: Factor on |Q_p − Q_{p+2}|: it bounds |Q_p − I| once |Q_{p+2} − I| ≤ |Q_p − I| / 2.
ERROR_SAFETY = 2.0


@dataclass(frozen=True)
class GaussHermite(Transform):
    """Gauss–Hermite quadrature of the moments.

    Parameters
    ----------
    order : int, default 5
        Points per dimension of the one-dimensional rule (exact to degree 2·order − 1).
        The tensor grid has order^n nodes; a rule of more than ``MAX_NODES`` = 10^6
        nodes (tensor or sparse) raises a :class:`~symmon.errors.ResourceError` before
        it is built.
    sparse : bool or None
        Use a Smolyak sparse grid; ``None`` picks it above 4 dimensions, with a
        :class:`~symmon.errors.QuadratureWarning`.  The sparse grid is exact to *total*
        degree 2·⌊(order + 1)/2⌋ − 1 only (:meth:`degree`, the result's
        ``info["degree"]``): order 3 gives degree 3, a covariance exact for affine g only,
        and its weights are of both signs, so a covariance can come out indefinite; it
        is then refused (:class:`~symmon.errors.IndefiniteCovarianceError`).
    error_estimate : bool, default False
        Also evaluate the rule of order ``order + 2`` and report the result's
        ``error = {"mean", "cov", "cross_cov"}``, each ``ERROR_SAFETY · |Q_order −
        Q_{order+2}|`` (see the module notes for when it is a bound).  The moments
        returned are those of ``order``.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> m = sm.propagate(sm.Model([x], [x**6]), sm.Gaussian([0.0], [[1.0]]),
    ...                  transform=sm.GaussHermite(3, error_estimate=True))
    >>> round(float(m.mean[0]), 10), round(float(m.error["mean"][0]), 10)  # E x⁶ = 15
    (9.0, 12.0)
    """

    order: int = 5
    sparse: bool | None = None
    error_estimate: bool = False

    name: ClassVar[str] = "gh"
    point_rule: ClassVar[bool] = True
    presets: ClassVar[dict] = {"gh": ("Gauss-Hermite quadrature of a given order", lambda order, **_: GaussHermite(order))}

    def __post_init__(self) -> None:
        if not isinstance(self.order, (int, np.integer)) or self.order < 1:
            raise SymmonError(f"GaussHermite order must be a positive integer, got {plain_repr(self.order)}")
        if not isinstance(self.error_estimate, (bool, np.bool_)):
            raise SymmonError(f"GaussHermite error_estimate must be True or False, got {self.error_estimate!r}")

    @property
    def exact_degree(self) -> float:  # type: ignore[override]
        """The degree of exactness in every dimension: 2·order − 1 (per coordinate) for the
        tensor grid, total degree 2·level − 1, level = (order + 1) // 2, for the sparse grid,
        and with ``sparse=None`` the sparse value, which it falls to above 4 dimensions
        (:meth:`degree` gives the degree in a given dimension)."""
        if self.sparse is False:
            return 2 * self.order - 1
        return 2 * ((self.order + 1) // 2) - 1

    def degree(self, n: int) -> float:
        """The degree of exactness of the grid used in ``n`` dimensions (:attr:`exact_degree`)."""
        return 2 * ((self.order + 1) // 2) - 1 if self._sparse(n) else 2 * self.order - 1

    def _sparse(self, n: int) -> bool:
        return bool(n > SPARSE_ABOVE if self.sparse is None else self.sparse)

    def _announce(self, n: int) -> None:
        """Warn (once per order and dimension) when ``sparse=None`` falls to the sparse grid."""
        key = ("gh-sparse", self.order, n)
        if self.sparse is None and n > SPARSE_ABOVE and key not in _WARNED:
            _WARNED.add(key)
            w = standard_rule(n, int(self.order), True)[1]
            signs = ", with negative weights" if (w < 0).any() else ""
            warnings.warn(
                f"GaussHermite(order={self.order}) in {n} dimensions uses the Smolyak sparse grid "
                f"({len(w)} nodes{signs}), exact to total "
                f"degree {self.degree(n)} only, not the tensor grid ({self.order}^{n} = {self.order**n} nodes, "
                f"degree {2 * self.order - 1} per coordinate): pass sparse=True to accept it, or sparse=False",
                QuadratureWarning, stacklevel=5)

    def cost(self, n_w: int) -> int:
        """The nodes of the rule (and of the order + 2 rule with ``error_estimate``);
        a tensor grid is counted without being built."""
        def nodes(order: int) -> int:
            return order**n_w if not self._sparse(n_w) else len(standard_rule(n_w, order, True)[1])

        return nodes(int(self.order)) + (nodes(int(self.order) + 2) if self.error_estimate else 0)

    def for_dimension(self, n: int, max_nodes: int) -> tuple["GaussHermite", str]:
        """With ``sparse=None``: the tensor grid while it (and the order + 2 grid of the error
        estimate) has at most ``max_nodes`` nodes in ``n`` dimensions, else the sparse grid,
        named "sparse"; an explicit ``sparse`` is kept."""
        if self.sparse is not None:
            return self, ""
        top = self.order + 2 if self.error_estimate else self.order
        sparse = bool(top**n > max_nodes)
        return GaussHermite(self.order, sparse=sparse, error_estimate=self.error_estimate), "sparse" if sparse else ""

    def filter_label(self) -> str:
        """The Gauss–Hermite Kalman filter, ``GHKF(order=…)``."""
        return f"GHKF(order={self.order})"

    def unit_rule(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The nodes for N(0, I_n) (sparse as :meth:`moments` picks it) and the weights, twice."""
        self._announce(n)
        Z, w = standard_rule(n, int(self.order), self._sparse(n))
        return Z, w, w

    def outer_rule(self, mean, cov):
        """This order's nodes and weights over N(mean, cov), sparse above 4 dimensions."""
        n = mean.shape[0]
        Z, w = standard_rule(n, int(self.order), n > SPARSE_ABOVE)
        return mean + Z @ batch_sqrt(cov[None])[0].T, w

    def _moments(self, cm, means, covs, angles, executor):
        K, n = means.shape
        self._announce(n)
        sparse = self._sparse(n)
        L = batch_sqrt(covs)
        mean, cov, cross, scale, evals = _rule_moments(cm, means, L, int(self.order), sparse, angles, self)
        info: dict[str, Any] = {"sparse": sparse, "degree": self.degree(n)}
        error = None
        if self.error_estimate:
            m2, c2, x2, _, e2 = _rule_moments(cm, means, L, int(self.order) + 2, sparse, angles, self)
            dm = mean - m2
            if angles:
                idx = sorted(angles)
                dm[:, idx] = wrap_angle(dm[:, idx])
            error = {
                "mean": ERROR_SAFETY * np.abs(dm),
                "cov": ERROR_SAFETY * np.abs(cov - c2),
                "cross_cov": ERROR_SAFETY * np.abs(cross - x2),
            }
            evals += e2
        return Moments(mean, cov, cross, evaluations=evals, details=info, error=error, cov_scale=scale)


def _rule_moments(cm, means: np.ndarray, L: np.ndarray, order: int, sparse: bool, angles: frozenset[int],
                  transform: Transform) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int]:
    """Mean, covariance, cross-covariance, the covariance's rounding scale
    (:func:`weighted_moments`) and the number of evaluations of one rule."""
    K, n = means.shape
    Z, w = standard_rule(n, order, sparse)
    X = means[:, None, :] + np.einsum("kij,nj->kni", L, Z)
    N = Z.shape[0]
    Y = evaluate_points(cm, X, transform, angles)
    mean, cov, cross, scale = weighted_moments(Y, X, means, w, w, angles)
    return mean, cov, cross, scale, K * N
