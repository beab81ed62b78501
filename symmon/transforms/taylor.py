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

from ..compile.compiled import CompiledModel
from ..core.angles import wrap_angle
from ..core.arrays import all_finite
from ..errors import DerivativeError, SymmonError
from .base import Moments, Transform

__all__ = ["TT1", "TT2"]


def _check_finite(cm: CompiledModel, means: np.ndarray, arr: np.ndarray, owner: np.ndarray | None, what: str) -> None:
    """Raise DerivativeError naming the output and point of the first non-finite entry.

    ``arr`` is (K, m) and ``owner[c]`` the output to which column c belongs (None: output c).
    """
    if all_finite(arr):
        return
    bad = ~np.isfinite(arr)
    if bad.any():
        k, c = np.argwhere(bad)[0]
        i = int(c if owner is None else owner[c])
        point = ", ".join(f"{s}={x:.6g}" for s, x in zip(cm.symbols, means[k]))
        expr = cm.source_exprs[i] if i < len(cm.source_exprs) else "?"
        raise DerivativeError(
            f"the {what} of output {i} ({expr}) is NaN or inf at the point ({point}); the function is "
            "not differentiable there (e.g. sqrt at 0 or atan2(0, 0)): use a sampling "
            "transform (UT, Gauss-Hermite, Monte Carlo) or move the expansion point"
        )


def second_order_terms(cm: CompiledModel, H_nz: np.ndarray, covs: np.ndarray,
                       method: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """½ tr(H_i P) (K, n_y) and ½ tr(H_i P H_j P) (K, n_y, n_y) from the Hessian nonzeros.

    Two exact evaluations of the second-order terms of TT2 (module docstring;
    Gustafsson & Hendeby 2012).  ``"blocks"``: with S_i the support of H_i (s inputs at most),
    tr(H_i P H_j P) = tr(B_i P[S_i, S_j] B_j P[S_j, S_i]) with the blocks
    B_i = H_i[S_i, S_i], in n_y² s³ operations.  ``"dense"``: H_i P for each i, then the
    Frobenius products ⟨H_i P, (H_j P)ᵀ⟩, in n_y n³ + n_y² n² operations.  The default
    takes the cheaper one.

    Parameters
    ----------
    cm : CompiledModel
    H_nz : (K, nnz) Hessian nonzeros, laid out by ``cm.hess_index``
    covs : (K, n_w, n_w)
    method : {"blocks", "dense"}, optional
    """
    K, n = covs.shape[0], cm.n_w
    ny, s = cm.hess_support.shape
    if s == 0:  # affine g: no second-order terms
        return np.zeros((K, ny)), np.zeros((K, ny, ny))
    if method is None:
        method = "blocks" if ny * ny * s**3 <= ny * n**3 + ny * ny * n * n else "dense"
    if method not in ("blocks", "dense"):
        raise SymmonError(f"method must be 'blocks' or 'dense', got {method!r}")
    if method == "blocks":
        B = cm.hessian_blocks(H_nz)  # (K, ny, s, s)
        flat = cm.hess_support.ravel()
        # Rows of block i of Q = P[S, S]: Q[k, i, a, (j, b)] = P[S_i[a], S_j[b]]; padded
        # entries meet zero rows of B.
        Q = covs[:, flat[:, None], flat[None, :]].reshape(K, ny, s, ny * s)
        R = np.matmul(B, Q).reshape(K, ny, s, ny, s)  # R[k, i, :, j, :] = B_i P[S_i, S_j]
        first = np.einsum("kiaia->ki", R)
        # tr(R_ij R_ji) = Σ_ac R_ij[a, c] R_ji[c, a]
        second = (R * R.transpose(0, 3, 4, 1, 2)).sum(axis=(2, 4))
    else:
        HP = np.matmul(cm.dense_hessians(H_nz), covs[:, None])  # (K, ny, n, n)
        first = np.einsum("kiaa->ki", HP)
        F = HP.reshape(K, ny, n * n)
        Ft = HP.transpose(0, 1, 3, 2).reshape(K, ny, n * n)
        second = np.matmul(F, Ft.transpose(0, 2, 1))
    return 0.5 * first, 0.5 * second


def _taylor(cm: CompiledModel, means: np.ndarray, covs: np.ndarray, angles, second: bool):
    y, J_nz, H_nz = cm.eval_derivatives(means)
    _check_finite(cm, means, y, None, "value")
    _check_finite(cm, means, J_nz, cm.jac_index[0], "Jacobian")
    J = cm.dense_jacobian(J_nz)
    JP = np.matmul(J, covs)
    cov = np.matmul(JP, J.transpose(0, 2, 1))
    # The scale of the rounding of Cov y (Moments.cov_scale): with s the standard deviations,
    # |P| ≤ s sᵀ entrywise, so |J||P||J|ᵀ ≤ (|J|s)(|J|s)ᵀ and |tr(H_i P H_j P)| ≤
    # (sᵀ|H_i|s)(sᵀ|H_j|s); a product of sums of such terms is what the entries are made of.
    s = np.sqrt(np.maximum(np.diagonal(covs, axis1=1, axis2=2), 0.0))
    scale = np.einsum("kij,kj->ki", np.abs(J), s) ** 2
    mean = y.copy()
    if second:
        _check_finite(cm, means, H_nz, cm.hess_index[0], "Hessian")
        half_tr, half_tr2 = second_order_terms(cm, H_nz, covs)
        mean = mean + half_tr
        cov = cov + half_tr2
        scale = scale + 0.5 * _hessian_spread(cm, H_nz, s) ** 2
    if angles:
        idx = sorted(angles)
        mean[:, idx] = wrap_angle(mean[:, idx])
    return Moments(mean, cov, JP, evaluations=means.shape[0], cov_scale=scale)


def _hessian_spread(cm: CompiledModel, H_nz: np.ndarray, s: np.ndarray) -> np.ndarray:
    """sᵀ|H_i|s (K, n_y) from the lower-triangle nonzeros of the Hessians."""
    out, rows, cols = cm.hess_index
    terms = np.abs(H_nz) * s[:, rows] * s[:, cols] * np.where(rows == cols, 1.0, 2.0)
    spread = np.zeros((H_nz.shape[0], cm.n_y))
    np.add.at(spread.T, out, terms.T)
    return spread


@dataclass(frozen=True)
class TT1(Transform):
    """First-order Taylor transform (the EKF's linearisation). Exact for affine g.

    Note that every measure of nonlinearity computed with TT1 is 0 by construction:
    TT1 *is* the best linear approximation at the mean.
    """

    exact_degree: ClassVar[float] = 1
    name: ClassVar[str] = "tt1"
    presets: ClassVar[dict] = {"tt1": ("first-order Taylor (the EKF's linearisation)", lambda **_: TT1())}
    taylor_order: ClassVar[int | None] = 1

    def semidefinite(self, n: int) -> bool:
        """True: Cov y = J P Jᵀ is positive semi-definite by construction."""
        return True

    def _moments(self, cm, means, covs, angles, executor):
        return _taylor(cm, means, covs, angles, second=False)

    def cost(self, n_w: int) -> int:
        """g and J: 1 + n_w (a forward-mode Jacobian costs about one evaluation per column)."""
        return 1 + n_w

    def filter_label(self) -> str:
        """The extended Kalman filter."""
        return "EKF"

    def nested_inner(self) -> Transform:
        """TT2: TT1's E[g | v] is g at the mean of u, blind to the curvature in u that
        the inner integral of a nested rule is there to see."""
        return TT2()


@dataclass(frozen=True)
class TT2(Transform):
    """Second-order Taylor transform. Exact mean and covariance for quadratic g."""

    exact_degree: ClassVar[float] = 2
    name: ClassVar[str] = "tt2"
    presets: ClassVar[dict] = {"tt2": ("second-order Taylor", lambda **_: TT2())}
    taylor_order: ClassVar[int | None] = 2

    def semidefinite(self, n: int) -> bool:
        """True: Cov y = J P Jᵀ plus the Gram matrix ½ [tr(H_i P H_j P)] is positive semi-definite by construction."""
        return True

    def _moments(self, cm, means, covs, angles, executor):
        return _taylor(cm, means, covs, angles, second=True)

    def filter_label(self) -> str:
        """The second-order extended Kalman filter."""
        return "EKF2"

    def cost(self, n_w: int) -> int:
        """g, J and the n_w(n_w + 1)/2 distinct second derivatives."""
        return 1 + n_w + n_w * (n_w + 1) // 2
