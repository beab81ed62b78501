"""The transform protocol and the moment computations shared by point-based rules.

Every transform works on a *batch* of K Gaussians of w = [u; v] at once: means (K, n_w)
and covariances (K, n_w, n_w).  It returns the mean (K, n_y), the covariance
(K, n_y, n_y) and the cross-covariance Cov(y, w) (K, n_y, n_w).  A single
:func:`symmon.propagate` is a batch of one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..angles import wrap_angle  # re-exported: defined beside the other angle helpers
from ..compile import CompiledModel
from ..gaussian import matrix_sqrt

__all__ = ["Transform", "BatchMoments", "wrap_angle", "weighted_moments", "batch_sqrt"]


@dataclass(frozen=True)
class BatchMoments:
    """Moments of a batch: mean (K, n_y), cov (K, n_y, n_y), cross (K, n_y, n_w)."""

    mean: np.ndarray
    cov: np.ndarray
    cross: np.ndarray
    stderr: dict | None = None
    info: dict | None = None
    input_cov: np.ndarray | None = None  # Cov w as the transform sees it (MC: the sample covariance)


class Transform:
    """Base class of the transforms: immutable settings plus a batched kernel.

    Subclasses are frozen dataclasses that implement :meth:`batch` and declare
    ``exact_degree``: the polynomial degree of g up to which the mean is exact for a
    Gaussian input.
    """

    exact_degree: ClassVar[float] = 0
    name: ClassVar[str] = "transform"

    def batch(self, cm: CompiledModel, means: np.ndarray, covs: np.ndarray,
              angles: frozenset[int] = frozenset()) -> BatchMoments:
        raise NotImplementedError  # pragma: no cover - abstract


def batch_sqrt(covs: np.ndarray) -> np.ndarray:
    """Square roots L_k L_kᵀ = P_k: batched Cholesky, eigh for singular ones."""
    try:
        return np.linalg.cholesky(covs)
    except np.linalg.LinAlgError:
        return np.stack([matrix_sqrt(P) for P in covs])


def weighted_moments(Y: np.ndarray, X: np.ndarray, mx: np.ndarray, wm: np.ndarray,
                     wc: np.ndarray, angles: frozenset[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moments of weighted points.

    Parameters
    ----------
    Y : (K, N, n_y) transformed points
    X : (K, N, n_w) points
    mx : (K, n_w) the input means
    wm, wc : (N,) mean and covariance weights
    angles : output indices that are angles: circular mean, wrapped residuals

    Returns
    -------
    mean (K, n_y), cov (K, n_y, n_y), cross (K, n_y, n_w)
    """
    # Weights sum to 1: centring on the first point keeps digits when the weights are
    # large and of both signs (ut2's are about ±1e6), so a constant output stays exact.
    Y0 = Y[:, 0, :]
    mean = Y0 + np.einsum("n,kni->ki", wm, Y - Y0[:, None, :])
    if angles:
        idx = sorted(angles)
        s = np.einsum("n,kni->ki", wm, np.sin(Y[..., idx]))
        c = np.einsum("n,kni->ki", wm, np.cos(Y[..., idx]))
        mean[:, idx] = np.arctan2(s, c)
    R = Y - mean[:, None, :]
    if angles:
        R[..., idx] = wrap_angle(R[..., idx])
    D = X - mx[:, None, :]
    cov = np.einsum("n,kni,knj->kij", wc, R, R)
    cross = np.einsum("n,kni,knj->kij", wc, R, D)
    return mean, cov, cross

