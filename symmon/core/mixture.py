"""Inputs beyond one Gaussian: a Gaussian mixture and a weighted sample (particles).

The measure of nonlinearity is defined for any known densities p(u) and p(v) (Straka &
Havlík 2024, Sec. II); these two classes are the densities a Gaussian-sum (IMM,
range-parameterised) filter and a particle filter hold.  Both are validated and
immutable, and offer what the front ends read of a :class:`~symmon.core.gaussian.Gaussian`
(``mean``, ``cov``, ``dim``, ``marginal``, ``sample``):

- :class:`GaussianMixture`: p(x) = Σ_k w_k N(x; μ_k, P_k), its mean Σ_k w_k μ_k and its
  covariance by the law of total covariance, Σ_k w_k (P_k + (μ_k − μ)(μ_k − μ)ᵀ);
- :class:`Empirical`: the weighted empirical measure Σ_i w_i δ(x − x_i) of N particles,
  its weighted mean and covariance, and its effective sample size (Σ w_i)² / Σ w_i².

How they are propagated and measured (the exact mixing of per-component moments) is
:mod:`symmon.propagation.mixing` and docs/guide/mixtures.md.

References
----------
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ArgumentError, ArgumentTypeError, ShapeError, WeightError, plain_repr
from .gaussian import Gaussian, float_array, _fmt, _frozen_reduce, as_covariance, as_generator, as_vector, check_indices, matrix_sqrt

__all__ = ["GaussianMixture", "Empirical", "mixture_moments", "WEIGHT_SUM_ATOL", "MAX_SHOWN", "SPLITS", "split_weights"]

#: How far the mixture weights may sum from 1: rounding of weights computed in double
#: precision (K·eps ≈ 1e-14 for K = 64) passes by five orders of magnitude, while a weight
#: typed wrongly (0.33 + 0.33 + 0.33) is refused.  The weights are then divided by their sum.
WEIGHT_SUM_ATOL = 1e-9
#: Components (or particles' summary lines) a repr shows before it elides the rest.
MAX_SHOWN = 6


#: The univariate splits of N(0, 1) into m narrower components Σ ω_j N(μ_j, σ²), for the
#: Gaussian-sum filter's splitting (:mod:`symmon.filters.mixture.gaussian_sum`) and the component
#: counts of :func:`symmon.advise`: m ↦ (σ, the outer weights of one side, nearest first),
#: computed by ``derivations/gaussian_split.py`` (L2 distance + 10⁻³ σ, after DeMars, Bishop &
#: Jah 2013, with the variance kept exactly); the centre weight and the spacing δ follow from
#: Σ ω = 1 and σ² + Σ ω μ² = 1 (:func:`split_weights`).
SPLITS: dict[int, tuple[float, tuple[float, ...]]] = {
    3: (0.7303827025415317, (0.20224354212317014,)),
    5: (0.5472166585274427, (0.23721882185007498, 0.04842309990180618)),
}


def split_weights(m: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(ω (m,), μ (m,), σ) of the tabulated split of N(0, 1) into m components: symmetric, so
    Σ ω μ = 0, and δ from the variance, σ² + Σ ω μ² = 1."""
    sigma, outer = SPLITS[m]
    o = np.array(outer)
    idx = np.arange(1, len(o) + 1)
    w = np.concatenate([o[::-1], [1.0 - 2.0 * o.sum()], o])
    delta = float(np.sqrt((1.0 - sigma**2) / (2.0 * float(o @ idx**2))))
    mu = np.concatenate([-idx[::-1], [0], idx]) * delta
    return w, mu, sigma


def _check_weights(weights: ArrayLike, n: int | None, name: str, sum_to_one: bool) -> np.ndarray:
    """Weights as a float vector: finite, non-negative, not all zero (and, for a mixture,
    summing to 1 within :data:`WEIGHT_SUM_ATOL`), returned divided by their sum."""
    w = float_array(weights, name, WeightError)
    if w.ndim == 0:
        w = w.reshape(1)
    if w.ndim != 1:
        raise ShapeError(f"{name} must be a vector (1-D), got shape {w.shape}")
    if w.size == 0:
        raise ShapeError(f"{name} is empty: at least one component is needed")
    if n is not None and w.size != n:
        raise ShapeError(f"{name} has {w.size} entries but there are {n} components")
    if not np.all(np.isfinite(w)):
        raise WeightError(f"{name} contains NaN or inf at index {int(np.argmax(~np.isfinite(w)))}")
    if np.any(w < 0):
        i = int(np.argmax(w < 0))
        raise WeightError(f"{name} must be non-negative: {name}[{i}] = {w[i]:.6g}")
    total = float(np.sum(w))
    if total <= 0 or not np.isfinite(total):
        raise WeightError(f"{name} are all zero (or their sum overflows: {total:.3g})")
    if sum_to_one and abs(total - 1.0) > WEIGHT_SUM_ATOL:
        raise WeightError(f"{name} must sum to 1 (within {WEIGHT_SUM_ATOL:g}), they sum to {total:.12g}")
    return w / total


def mixture_moments(weights: np.ndarray, means: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of Σ_k w_k N(μ_k, P_k) (the law of total covariance).

    μ = Σ_k w_k μ_k,  P = Σ_k w_k (P_k + (μ_k − μ)(μ_k − μ)ᵀ), returned symmetric.  The
    deviations are taken from μ (not raw second moments minus μμᵀ), so a mean far from 0
    costs no digits.  ``weights`` (K,), ``means`` (K, n), ``covs`` (K, n, n); the weights
    are used as given (normalised by the caller).
    """
    mean = weights @ means
    d = means - mean
    cov = np.einsum("k,kij->ij", weights, covs) + (d * weights[:, None]).T @ d
    return mean, 0.5 * (cov + cov.T)


class _WeightedMeasure:
    """What a mixture and a weighted sample share: normalised weights, the overall mean
    and covariance (read-only), immutability, the moment-matched Gaussian."""

    __slots__ = ("_weights", "_mean", "_cov")

    def __setattr__(self, key, value):  # immutable
        raise AttributeError(f"{type(self).__name__} is immutable")

    __reduce__ = _frozen_reduce  # pickles: __setattr__ refuses the default restore

    def _freeze(self, **arrays: np.ndarray) -> None:
        for name, arr in arrays.items():
            arr = np.array(arr, dtype=float)  # own copy: freezing it cannot affect the caller
            arr.setflags(write=False)
            object.__setattr__(self, "_" + name, arr)

    @property
    def weights(self) -> np.ndarray:
        """The weights, summing to 1."""
        return self._weights

    @property
    def dim(self) -> int:
        """The dimension n."""
        return int(self._mean.shape[0])

    @property
    def mean(self) -> np.ndarray:
        """The overall mean, shape (n,)."""
        return self._mean

    @property
    def cov(self) -> np.ndarray:
        """The overall covariance, shape (n, n)."""
        return self._cov

    def as_gaussian(self) -> Gaussian:
        """N(mean, cov): the moment-matched Gaussian (what a Kalman-type filter would carry)."""
        return Gaussian(self._mean, self._cov)


def _draws(n: int) -> int:
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ArgumentError(f"n must be a positive integer, got {plain_repr(n)}")
    return int(n)


class GaussianMixture(_WeightedMeasure):
    """A Gaussian mixture Σ_k w_k N(μ_k, P_k), immutable and validated.

    Parameters
    ----------
    weights : array_like, shape (K,)
        Non-negative, summing to 1 within :data:`WEIGHT_SUM_ATOL` (they are then divided
        by their sum, so the mixing is exact).
    means : array_like, shape (K, n)
        The component means; for a scalar mixture (n = 1) also shape (K,) together with
        ``covs`` of shape (K,).
    covs : array_like, shape (K, n, n)
        The component covariances, each symmetric positive semi-definite (a zero
        covariance, a point mass, is allowed); for n = 1 also shape (K,), the variances.
    psd : {"raise", "clip", "jitter"}, default "raise"
        Repair policy for a component covariance that is not PSD
        (:func:`~symmon.core.gaussian.as_covariance`).

    Attributes
    ----------
    weights, means, covs : ndarray (read-only)
    components : tuple of Gaussian
        N(μ_k, P_k) for each k.
    mean, cov : ndarray (read-only)
        The mixture's mean and covariance (law of total covariance).

    Raises
    ------
    ShapeError
        For inconsistent or empty shapes, a non-finite mean (naming ``means[k]``).
    CovarianceError
        For a covariance that is not symmetric, PSD or finite (naming ``covs[k]``).
    WeightError
        For negative, non-finite or all-zero weights, or weights not summing to 1.

    Examples
    --------
    >>> g = GaussianMixture([0.5, 0.5], [[-1.0], [1.0]], [[[1.0]], [[1.0]]])
    >>> g.mean.tolist(), g.cov.tolist()   # Var = E Var + Var E = 1 + 1
    ([0.0], [[2.0]])
    """

    __slots__ = ("_means", "_covs", "_components")

    def __init__(self, weights: ArrayLike, means: ArrayLike, covs: ArrayLike, psd: str = "raise") -> None:
        M = float_array(means, "means", ShapeError)
        P = float_array(covs, "covs", ShapeError)
        if M.ndim == 1 and P.ndim == 1:  # a scalar mixture: K means and K variances
            M, P = M[:, None], P[:, None, None]
        if M.ndim != 2:
            raise ShapeError(f"means must have shape (K, n), one row per component, got {M.shape}")
        K, n = M.shape
        if K == 0 or n == 0:
            raise ShapeError(f"means must hold at least one component of dimension >= 1, got shape {M.shape}")
        if P.shape != (K, n, n):
            raise ShapeError(f"covs must have shape (K, n, n) = {(K, n, n)} to match means {M.shape}, got {P.shape}")
        w = _check_weights(weights, K, "weights", sum_to_one=True)
        comps = tuple(Gaussian(as_vector(M[k], f"means[{k}]"), as_covariance(P[k], f"covs[{k}]", dim=n, psd=psd))
                      for k in range(K))
        self._set(w, comps)

    def _set(self, w: np.ndarray, comps: tuple[Gaussian, ...]) -> None:
        M = np.array([g.mean for g in comps])
        P = np.array([g.cov for g in comps])
        mean, cov = mixture_moments(w, M, P)
        self._freeze(weights=w, means=M, covs=P, mean=mean, cov=cov)
        object.__setattr__(self, "_components", comps)

    @classmethod
    def from_components(cls, weights: ArrayLike, components: Sequence[Gaussian]) -> "GaussianMixture":
        """The mixture Σ_k w_k ``components[k]`` of Gaussians of one dimension."""
        comps = tuple(components) if isinstance(components, (list, tuple)) else None
        if not comps or not all(isinstance(g, Gaussian) for g in comps):
            raise ArgumentTypeError("components must be a non-empty list of symmon.Gaussian")
        if len({g.dim for g in comps}) != 1:
            raise ShapeError(f"components have different dimensions: {[g.dim for g in comps]}")
        w = _check_weights(weights, len(comps), "weights", sum_to_one=True)
        out = cls.__new__(cls)
        out._set(w, comps)
        return out

    @property
    def means(self) -> np.ndarray:
        """The component means μ_k, shape (K, n)."""
        return self._means

    @property
    def covs(self) -> np.ndarray:
        """The component covariances P_k, shape (K, n, n)."""
        return self._covs

    @property
    def components(self) -> tuple[Gaussian, ...]:
        """The components N(μ_k, P_k) as Gaussians."""
        return self._components

    @property
    def n_components(self) -> int:
        """The number of components K."""
        return int(self._weights.shape[0])

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Draw ``n`` samples, shape (n, dim): a component by its weight, then a draw of it."""
        n = _draws(n)
        gen = as_generator(rng)
        k = gen.choice(self.n_components, size=n, p=self._weights)
        z = gen.standard_normal((n, self.dim))
        L = np.array([matrix_sqrt(P) for P in self._covs])
        return self._means[k] + np.einsum("nij,nj->ni", L[k], z)

    def marginal(self, idx: Sequence[int] | int) -> "GaussianMixture":
        """The marginal mixture of the components ``idx``: Σ_k w_k N(μ_k[idx], P_k[idx, idx])."""
        return GaussianMixture.from_components(self._weights, [g.marginal(idx) for g in self._components])

    def __repr__(self) -> str:
        lines = [f"  {_fmt(w)} * {g!r}" for w, g in zip(self._weights[:MAX_SHOWN], self._components[:MAX_SHOWN])]
        if self.n_components > MAX_SHOWN:
            lines.append(f"  ... ({self.n_components - MAX_SHOWN} more)")
        K, n = self.n_components, self.dim
        head = f"GaussianMixture({K} component{'s' * (K != 1)} in {n} dimension{'s' * (n != 1)}:"
        return head + "\n" + "\n".join(lines) + ")"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GaussianMixture):
            return NotImplemented
        return all(np.array_equal(a, b) for a, b in ((self._weights, other._weights), (self._means, other._means),
                                                      (self._covs, other._covs)))

    def __hash__(self) -> int:
        return hash((self._weights.tobytes(), self._means.tobytes(), self._covs.tobytes()))


class Empirical(_WeightedMeasure):
    """A weighted sample (particles): the empirical measure Σ_i w_i δ(x − x_i).

    Parameters
    ----------
    samples : array_like, shape (N, n)
        One row a particle (shape (N,) for n = 1); finite.
    weights : array_like, shape (N,), optional
        Non-negative, not all zero; any scale (they are divided by their sum).  Default:
        equal weights.

    Attributes
    ----------
    samples, weights : ndarray (N, n) and (N,), read-only
        The particles, and their weights normalised to sum to 1.
    mean, cov : ndarray (n,) and (n, n), read-only
        Σ_i w_i x_i, and Σ_i w_i (x_i − mean)(x_i − mean)ᵀ: the covariance *of the empirical
        measure* (no N/(N − 1) correction; it is what the moments of y are exact for).
    ess : float
        The effective sample size 1 / Σ w_i² (the particle-filter convention) for the normalised
        weights: N for equal weights, 1 when one particle holds all the weight.

    Raises
    ------
    ShapeError
        For an empty, non-numeric or non-finite sample, or weights of the wrong length.
    WeightError
        For negative, non-finite or all-zero weights.

    Examples
    --------
    >>> e = Empirical([[0.0], [2.0]], weights=[1, 3])
    >>> e.mean.tolist(), e.cov.tolist(), e.ess
    ([1.5], [[0.75]], 1.6)
    """

    __slots__ = ("_samples", "_ess")

    def __init__(self, samples: ArrayLike, weights: ArrayLike | None = None) -> None:
        X = float_array(samples, "samples", ShapeError)
        if X.ndim == 1:
            X = X[:, None]
        if X.ndim != 2 or X.shape[0] == 0 or X.shape[1] == 0:
            raise ShapeError(f"samples must have shape (N, n) with N, n >= 1 (one row a particle), got {X.shape}")
        bad = ~np.isfinite(X)
        if bad.any():
            raise ShapeError(f"samples contain NaN or inf: {int(bad.any(axis=1).sum())} of {X.shape[0]} particles,"
                             f" the first at row {int(np.argmax(bad.any(axis=1)))}")
        N = X.shape[0]
        w = np.full(N, 1.0 / N) if weights is None else _check_weights(weights, N, "weights", sum_to_one=False)
        mean = w @ X
        if not np.all(np.isfinite(mean)):
            raise ShapeError("samples: the weighted mean overflows a float; rescale the units")
        D = X - mean
        with np.errstate(over="ignore", invalid="ignore"):
            cov = (D * w[:, None]).T @ D
        if not np.all(np.isfinite(cov)):
            raise ShapeError("samples: the weighted covariance overflows a float; rescale the units")
        self._freeze(samples=X, weights=w, mean=mean, cov=0.5 * (cov + cov.T))
        object.__setattr__(self, "_ess", float(1.0 / np.sum(w * w)))

    @property
    def samples(self) -> np.ndarray:
        """The particles x_i, shape (N, n)."""
        return self._samples

    @property
    def n_samples(self) -> int:
        """The number of particles N."""
        return int(self._samples.shape[0])

    @property
    def ess(self) -> float:
        """The effective sample size 1 / Σ w_i² of the normalised weights."""
        return self._ess

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Draw ``n`` particles with replacement, each with probability w_i (multinomial resampling)."""
        return self._samples[as_generator(rng).choice(self.n_samples, size=_draws(n), p=self._weights)]

    def marginal(self, idx: Sequence[int] | int) -> "Empirical":
        """The particles' components ``idx``, with the same weights."""
        ix = check_indices(idx, self.dim)
        return Empirical(self._samples[:, ix], self._weights)

    def __repr__(self) -> str:
        m = ", ".join(_fmt(x) for x in self._mean)
        return (f"Empirical({self.n_samples} particle{'s' * (self.n_samples != 1)} in {self.dim} "
                f"dimension{'s' * (self.dim != 1)}, ESS {self._ess:.4g}, mean [{m}])")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Empirical):
            return NotImplemented
        return bool(np.array_equal(self._samples, other._samples) and np.array_equal(self._weights, other._weights))

    def __hash__(self) -> int:
        return hash((self._samples.tobytes(), self._weights.tobytes()))
