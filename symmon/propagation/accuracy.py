"""The accuracy of a quadrature: Gauss–Hermite moments with their two-order error estimate."""

from __future__ import annotations

from ..transforms.quadrature import GaussHermite
from .front import propagate
from .joint import JointMoments

__all__ = ["quadrature_error"]


def quadrature_error(model, u, v=None, order: int = 5, sparse: bool | None = None) -> "JointMoments":
    """Gauss–Hermite moments of order ``order`` with their error estimate from order + 2.

    The same as ``propagate(model, u, v, transform=GaussHermite(order, sparse,
    error_estimate=True))``.

    Parameters
    ----------
    model : Model
    u : Gaussian
    v : Gaussian, optional
        Required when the model has noise symbols.
    order : int
        The order of the rule whose moments and error are returned.
    sparse : bool or None
        As in :class:`GaussHermite`.

    Returns
    -------
    JointMoments
        The order-``order`` moments; ``error`` holds ``"mean"`` (n_y,), ``"cov"``
        (n_y, n_y) and ``"cross_cov"`` (n_y, n_u): ``ERROR_SAFETY · |Q_order −
        Q_{order+2}|``, a bound on their error once the rule converges (the notes of
        :mod:`symmon.transforms.quadrature`).

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> m = quadrature_error(sm.Model([x], [x**4]), sm.Gaussian([0.0], [[1.0]]), order=2)
    >>> round(float(m.mean[0]), 10), round(float(m.error["mean"][0]), 10)  # E x⁴ = 3; 2 points give 1
    (1.0, 4.0)
    """
    return propagate(model, u, v, transform=GaussHermite(order, sparse, error_estimate=True))
