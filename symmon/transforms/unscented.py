"""The unscented transform (UT) and its presets ut1, ut2 and cubature.

With n = dim w and λ = α²(n + κ) − n, the sigma points are μ and μ ± √(n + λ)·Lᵢ
(Lᵢ the columns of a square root of P), with mean weights w₀ = λ/(n + λ),
wᵢ = 1/(2(n + λ)) and covariance weight w₀ᶜ = w₀ + 1 − α² + β.

The centre weight is negative when λ < 0 (ut1 above 3 dimensions, where κ = 3 − n; ut2).
The covariance is S + (β − α²) d dᵀ, S = Σ_{i≥1} wᵢ eᵢ eᵢᵀ and d = Σ_{i≥1} wᵢ eᵢ with
eᵢ = Yᵢ − Y₀, PSD whenever β ≥ α² (ut2); otherwise it can be indefinite, and is then
refused (:class:`~symmon.errors.IndefiniteCovarianceError`, by :meth:`Transform.moments`).

References
----------
S. J. Julier, J. K. Uhlmann, "Unscented filtering and nonlinear estimation",
Proc. IEEE 92(3), 2004. doi:10.1109/JPROC.2003.823141
R. van der Merwe, *Sigma-point Kalman filters for probabilistic inference in dynamic
state-space models*, PhD thesis, OGI, 2004 (the scaled UT).
"""

from __future__ import annotations

import functools

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import sympy as sp

from ..errors import SymmonError
from .base import Moments, Transform, batch_sqrt, evaluate_points, weighted_moments

__all__ = ["UT"]


@dataclass(frozen=True)
class UT(Transform):
    """The scaled unscented transform.

    Parameters
    ----------
    alpha : float, default 1
        Spread of the sigma points (α > 0).
    beta : float, default 0
        Prior knowledge of the distribution (β = 2 is optimal for a Gaussian).
    kappa : float or None, default None
        Secondary scaling; ``None`` means κ = 3 − n (the ut1 rule), resolved per model.

    Examples
    --------
    >>> UT.ut1(), UT.ut2(), UT.cubature()  # the named rules print as their constructors
    (UT.ut1(), UT.ut2(), UT.cubature())
    >>> UT(alpha=0.5, beta=2.0), UT(0.5, 2.0, 1.0)  # no kappa: κ = 3 − n
    (UT(alpha=0.5, beta=2.0), UT(alpha=0.5, beta=2.0, kappa=1.0))
    """

    alpha: float = 1.0
    beta: float = 0.0
    kappa: float | None = None

    exact_degree: ClassVar[float] = 3
    name: ClassVar[str] = "ut"
    point_rule: ClassVar[bool] = True
    presets: ClassVar[dict] = {
        "ut1": ("unscented transform, alpha = 1, beta = 0, kappa = 3 - n", lambda **_: UT.ut1()),
        "ut2": ("unscented transform, alpha = 1e-3, beta = 2, kappa = 0", lambda **_: UT.ut2()),
        "ct": ("the third-degree cubature rule (2n points)", lambda **_: UT.cubature()),
    }

    def __post_init__(self) -> None:
        for k in ("alpha", "beta") + (("kappa",) if self.kappa is not None else ()):
            v = getattr(self, k)
            if not np.isfinite(v):
                raise SymmonError(f"UT {k} must be finite, got {v}")
            object.__setattr__(self, k, float(v))
        if self.alpha <= 0:
            raise SymmonError(f"UT alpha must be positive, got {self.alpha}")

    def __repr__(self) -> str:
        for preset in ("ut1", "ut2", "cubature"):
            if self == getattr(UT, preset)():
                return f"UT.{preset}()"
        kappa = "" if self.kappa is None else f", kappa={self.kappa!r}"
        return f"UT(alpha={self.alpha!r}, beta={self.beta!r}{kappa})"

    @classmethod
    def ut1(cls) -> "UT":
        """SigSys 'ut1': α = 1, β = 0, κ = 3 − n."""
        return cls(1.0, 0.0, None)

    @classmethod
    def ut2(cls) -> "UT":
        """SigSys 'ut2': α = 10⁻³, β = 2, κ = 0."""
        return cls(1e-3, 2.0, 0.0)

    @classmethod
    def cubature(cls) -> "UT":
        """The cubature rule ('ct'): α = 1, β = 0, κ = 0."""
        return cls(1.0, 0.0, 0.0)

    def weights(self, n: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Mean weights, covariance weights and the scale √(n + λ) for dimension n (read-only
        arrays, made once per rule and dimension)."""
        return _weights(self.alpha, self.beta, self.kappa, n)

    def filter_label(self) -> str:
        """``CKF`` for the cubature rule, ``UKF(alpha=…, beta=…, kappa=…)`` otherwise."""
        if self == UT.cubature():
            return "CKF"
        return f"UKF(alpha={self.alpha!r}, beta={self.beta!r}, kappa={self.kappa!r})"

    def settings(self, n: int) -> str:
        """α, β and κ, with κ = 3 − n resolved for ``kappa=None``."""
        kappa = 3.0 - n if self.kappa is None else self.kappa
        return f"alpha = {self.alpha!r}, beta = {self.beta!r}, kappa = {kappa!r}"

    def sigma_points(self, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
        """Sigma points (K, 2n + 1, n): μ, μ + c·Lᵢ, then μ − c·Lᵢ."""
        K, n = means.shape
        _, _, c = self.weights(n)
        D = c * np.swapaxes(batch_sqrt(covs), 1, 2)  # rows = the columns of L, the directions
        X = np.empty((K, 2 * n + 1, n))
        m = means[:, None, :]
        X[:, :1] = m
        np.add(m, D, out=X[:, 1:n + 1])
        np.subtract(m, D, out=X[:, n + 1:])
        return X

    def cost(self, n_w: int) -> int:
        """2 n_w + 1 sigma points."""
        return 2 * n_w + 1

    def unit_rule(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sigma points of N(0, I_n): 0, then +c eᵢ, then −c eᵢ; mean and covariance weights."""
        wm, wc, c = self.weights(n)
        return np.vstack([np.zeros(n), c * np.eye(n), -c * np.eye(n)]), wm, wc

    def symbolic_unit_rule(self, n: int) -> tuple[sp.Matrix, list, list]:
        """:meth:`unit_rule` in exact arithmetic: α, β and κ read as the decimals they print
        as (1e-3 is 1/1000), λ = α²(n + κ) − n, the points 0, ±√(n + λ) eᵢ, the weights
        λ/(n + λ) and 1/(2(n + λ)), and w₀ᶜ = w₀ + 1 − α² + β (module doc)."""
        self.weights(n)  # the same refusal of a degenerate rule as the numeric one
        a, b = sp.Rational(repr(self.alpha)), sp.Rational(repr(self.beta))
        k = sp.Integer(3 - n) if self.kappa is None else sp.Rational(repr(self.kappa))
        lam = a**2 * (n + k) - n
        c = sp.sqrt(n + lam)
        points = sp.Matrix.vstack(sp.zeros(1, n), c * sp.eye(n), -c * sp.eye(n))
        wm = [lam / (n + lam)] + [1 / (2 * (n + lam))] * (2 * n)
        wc = [wm[0] + 1 - a**2 + b] + wm[1:]
        return points, wm, wc

    def outer_rule(self, mean, cov):
        """The sigma points and mean weights over N(mean, cov)."""
        return self.sigma_points(mean[None], cov[None])[0], self.weights(mean.shape[0])[0]

    def _moments(self, cm, means, covs, angles, executor):
        K, n = means.shape
        wm, wc, _ = self.weights(n)
        X = self.sigma_points(means, covs)
        Y = evaluate_points(cm, X, self, angles)
        mean, cov, cross, scale = weighted_moments(Y, X, means, wm, wc, angles, negative=wc[0] < 0)  # wcᵢ > 0 for i ≥ 1
        info = {"sigma_points": X, "transformed_points": Y}
        return Moments(mean, cov, cross, evaluations=K * (2 * n + 1), details=info, cov_scale=scale)


@functools.lru_cache(maxsize=256)
def _weights(alpha: float, beta: float, kappa: float | None, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    """:meth:`UT.weights` of ``UT(alpha, beta, kappa)`` in dimension n."""
    kappa = 3.0 - n if kappa is None else kappa
    with np.errstate(over="ignore"):  # α beyond ~1e154: α² is inf, refused just below
        a2 = np.float64(alpha) ** 2
        lam = a2 * (n + kappa) - n
    if not np.isfinite(lam) or not np.isfinite(a2):
        raise SymmonError(
            f"UT with alpha={alpha}, kappa={kappa} gives lambda = alpha^2 (n + kappa) - n = {lam} "
            f"for n = {n}: the sigma points and weights overflow; choose a moderate alpha and kappa (the presets use alpha = 1e-3 and 1)"
        )
    if n + lam <= 0:
        raise SymmonError(
            f"UT with alpha={alpha}, kappa={kappa} gives n + lambda = {n + lam:.3g} <= 0 "
            f"for n = {n}: choose a larger kappa"
        )
    wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1 - a2 + beta
    wm.flags.writeable = wc.flags.writeable = False  # shared by every call
    return wm, wc, float(np.sqrt(n + lam))
