"""First- and second-order Taylor transforms, TT1 and TT2.

TT1: E z ≈ g(μ), Cov z ≈ J P Jᵀ, Cov(z, u) ≈ J P.
TT2: E z_i ≈ g_i(μ) + ½ tr(H_i P), Cov(z_i, z_j) ≈ J_i P J_jᵀ + ½ tr(H_i P H_j P),
Cov(z, u) ≈ J P (third central moments of a Gaussian vanish).

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman
filters", IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..compile import CompiledModel
from ..errors import DerivativeError
from .base import Moments, Transform, wrap_angle

__all__ = ["TT1", "TT2"]


def _check_finite(cm: CompiledModel, means: np.ndarray, arr: np.ndarray, what: str) -> None:
    bad = ~np.isfinite(arr.reshape(arr.shape[0], arr.shape[1], -1)).all(axis=2)
    if bad.any():
        k, i = np.argwhere(bad)[0]
        point = ", ".join(f"{s}={x:.6g}" for s, x in zip(cm.symbols, means[k]))
        expr = cm.source_exprs[i] if i < len(cm.source_exprs) else "?"
        raise DerivativeError(
            f"the {what} of output {i} ({expr}) is NaN or inf at the point ({point}); the function is "
            "not differentiable there (e.g. sqrt at 0 or atan2(0, 0)): use a sampling "
            "transform (UT, Gauss-Hermite, Monte Carlo) or move the expansion point"
        )


def _taylor(cm: CompiledModel, means: np.ndarray, covs: np.ndarray, angles, second: bool):
    y, J, H = cm.eval_gjh(means)
    _check_finite(cm, means, y[:, :, None], "value")
    _check_finite(cm, means, J, "Jacobian")
    JP = np.einsum("kij,kjl->kil", J, covs)
    cov = np.einsum("kil,kjl->kij", JP, J)
    mean = y.copy()
    if second:
        _check_finite(cm, means, H, "Hessian")
        HP = np.einsum("kiab,kbc->kiac", H, covs)
        mean = mean + 0.5 * np.einsum("kiaa->ki", HP)
        cov = cov + 0.5 * np.einsum("kiab,kjba->kij", HP, HP)
    if angles:
        idx = sorted(angles)
        mean[:, idx] = wrap_angle(mean[:, idx])
    return Moments(mean, cov, JP, evaluations=means.shape[0])


@dataclass(frozen=True)
class TT1(Transform):
    """First-order Taylor transform (the EKF's linearisation). Exact for affine g.

    Note that every measure of nonlinearity computed with TT1 is 0 by construction:
    TT1 *is* the best linear approximation at the mean.
    """

    exact_degree: ClassVar[float] = 1
    name: ClassVar[str] = "tt1"
    taylor_order: ClassVar[int | None] = 1

    def moments(self, cm, means, covs, angles=frozenset(), executor=None):
        return _taylor(cm, means, covs, angles, second=False)

    def cost(self, n_w: int) -> int:
        """g and J: 1 + n_w (a forward-mode Jacobian costs about one evaluation per column)."""
        return 1 + n_w

    def nested_inner(self) -> Transform:
        """TT2: TT1's E[g | v] is g at the mean of u, blind to the curvature in u that
        the inner integral of a nested rule is there to see."""
        return TT2()


@dataclass(frozen=True)
class TT2(Transform):
    """Second-order Taylor transform. Exact mean and covariance for quadratic g."""

    exact_degree: ClassVar[float] = 2
    name: ClassVar[str] = "tt2"
    taylor_order: ClassVar[int | None] = 2

    def moments(self, cm, means, covs, angles=frozenset(), executor=None):
        return _taylor(cm, means, covs, angles, second=True)

    def cost(self, n_w: int) -> int:
        """g, J and the n_w(n_w + 1)/2 distinct second derivatives."""
        return 1 + n_w + n_w * (n_w + 1) // 2
