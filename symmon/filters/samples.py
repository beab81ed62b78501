"""Weighted samples of a state, shared by the filters that carry them (the particle filter's
particles, an ensemble filter's members): draws of a prior, weighted and circular moments, and
the Cholesky factor of a semidefinite sample covariance."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.angles import wrap_angle
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from .statespace import rows_times

__all__ = ["prior_samples", "weighted_moments", "circular_means", "semidefinite_cholesky"]


def prior_samples(x0: Gaussian | GaussianMixture | Empirical, N: int, g: np.random.Generator) -> np.ndarray:
    """N draws of x0 from ``g``: ``x0.sample``, except that a Gaussian's rows are multiplied
    by its square root L without BLAS (the same normals; OpenBLAS would split the product
    over threads that then spin against the compiled recursion's, statespace.rows_times),
    and by one broadcast product where L is diagonal (einsum's loop over the zeros of a
    diagonal L of 20 states took most of a short filter call's Python time)."""
    if not isinstance(x0, Gaussian):
        return np.asarray(x0.sample(N, g), dtype=float)
    Z, L = g.standard_normal((N, x0.dim)), x0.sqrt_cov()
    d = np.diag(L)
    if np.count_nonzero(L) == np.count_nonzero(d):  # diagonal
        Z *= d
        return Z + np.asarray(x0.mean, dtype=float)
    return np.asarray(x0.mean, dtype=float) + rows_times(Z, L)


def weighted_moments(X: np.ndarray, W: np.ndarray, angles: Sequence[int] = (),
                     cov: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """The weighted mean (circular for the ``angles`` components) and covariance (deviations
    wrapped; None without ``cov``) of samples X (R, N, n) with normalised weights W (R, N), per
    run R."""
    mean = np.matmul(W[:, None, :], X)[:, 0]
    angles = list(angles)
    if angles:
        mean[:, angles] = circular_means(W, X[..., angles])
    if not cov:
        return mean, None
    D = X - mean[:, None, :]
    if angles:
        D[..., angles] = wrap_angle(D[..., angles])
    C = np.matmul((D * W[..., None]).transpose(0, 2, 1), D)  # BLAS: einsum's loop took 10x as long
    return mean, 0.5 * (C + C.transpose(0, 2, 1))


def circular_means(W: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The weighted mean directions atan2(Σ W sin A, Σ W cos A) of angles A (R, N, i) with
    weights W (R, N), per run: :func:`symmon.core.angles.circular_mean` with one weight
    vector per run."""
    return np.arctan2(np.einsum("rn,rni->ri", W, np.sin(A)), np.einsum("rn,rni->ri", W, np.cos(A)))


def semidefinite_cholesky(C: np.ndarray) -> np.ndarray:
    """The lower Cholesky factor L (L Lᵀ = C) of a positive semidefinite C, a zero column
    where a pivot is not positive (the kernel's C twin, pf_kernel's ``_chol``)."""
    n = C.shape[0]
    L = np.zeros_like(C)
    for j in range(n):
        d = C[j, j] - L[j, :j] @ L[j, :j]
        if not (d > 1e-14 * C[j, j] and d > 0):
            continue
        L[j, j] = math.sqrt(d)
        L[j + 1:, j] = (C[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    return L
