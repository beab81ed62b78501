"""Sufficient statistics of Monte Carlo groups: exact merging and the jackknife.

A group (replicate) of samples is kept as its count, mean and M2 = Σ (z − z̄)(z − z̄)ᵀ
(:class:`Stats`).  Groups merge exactly with Chan's formula, in a fixed order, so the
total does not depend on where they ran; the delete-one-group jackknife over them gives
every Monte Carlo error bar (moments, MoN, figures), and :func:`moments_of` turns the
statistics of z = [y; w; sin y_A; cos y_A] into E y, Cov y, Cov(y, w) and Cov w.

References
----------
T. F. Chan, G. H. Golub, R. J. LeVeque, "Algorithms for computing the sample variance",
The American Statistician 37(3), 1983. doi:10.1080/00031305.1983.10483115
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..errors import SymmonError
from ..core.angles import wrap_angle

__all__ = ["Stats", "merge", "merge_all", "leave_one_out", "leave_one_out_stack", "jackknife", "jackknife_se",
           "moments_of"]


@dataclass(frozen=True)
class Stats:
    """Sufficient statistics of a sample of vectors: count, mean and M2 = Σ (z − z̄)(z − z̄)ᵀ.

    Or of a stack of G samples (:func:`leave_one_out_stack`): n (G,), mean (G, d),
    m2 (G, d, d); :attr:`cov` and :func:`moments_of` work on both.
    """

    n: int | np.ndarray
    mean: np.ndarray
    m2: np.ndarray

    @classmethod
    def of(cls, Z: np.ndarray) -> "Stats":
        """Statistics of the rows of Z (N, d), in two passes (mean, then centred products)."""
        n = Z.shape[0]
        # A BLAS product: numpy's axis-0 reduction of a narrow (N, d) array is ~10x slower.
        mean = np.ones(n) @ Z / n
        D = Z - mean
        return cls(n, mean, D.T @ D)

    @property
    def cov(self) -> np.ndarray:
        """The unbiased sample covariance."""
        return self.m2 / (np.asarray(self.n, dtype=float) - 1)[..., None, None]


def merge(a: Stats, b: Stats) -> Stats:
    """Merge two sets of statistics exactly (Chan, Golub & LeVeque)."""
    if a.n == 0:
        return b
    if b.n == 0:
        return a
    n = a.n + b.n
    delta = b.mean - a.mean
    mean = a.mean + delta * (b.n / n)
    m2 = a.m2 + b.m2 + np.outer(delta, delta) * (a.n * b.n / n)
    return Stats(n, mean, m2)


def merge_all(stats: Sequence[Stats]) -> Stats:
    """Merge a sequence of statistics, left to right (a fixed order: reproducible).

    O(G) merges of O(d²) each; the order fixes the rounding, so the result is the same
    bit for bit wherever the groups ran.
    """
    out = stats[0]
    for s in stats[1:]:
        out = merge(out, s)
    return out


def leave_one_out_stack(groups: Sequence[Stats], total: Stats | None = None) -> Stats:
    """The merged statistics of all groups but group i, for each i, as one stack, in O(G).

    Chan's merge run backwards: the total (n, x̄, M2) minus group i (nᵢ, x̄ᵢ, M2ᵢ) is

        n₋ᵢ = n − nᵢ,   x̄₋ᵢ = x̄ − (nᵢ/n₋ᵢ)(x̄ᵢ − x̄),
        M2₋ᵢ = M2 − M2ᵢ − (nᵢ n / n₋ᵢ)(x̄ᵢ − x̄)(x̄ᵢ − x̄)ᵀ,

    the last term being nᵢ n₋ᵢ/n (x̄ᵢ − x̄₋ᵢ)(x̄ᵢ − x̄₋ᵢ)ᵀ with x̄ᵢ − x̄₋ᵢ = (n/n₋ᵢ)(x̄ᵢ − x̄).
    All groups at once, as (G, d) and (G, d, d) arrays.  Group i is a 1/G share of the
    total, so the subtraction loses no significant digits (the test compares it with
    merging the other G − 1 groups, to 1e-10).

    Parameters
    ----------
    groups : sequence of Stats
    total : Stats, optional
        ``merge_all(groups)``, if the caller has it already.
    """
    if len(groups) < 2:
        raise SymmonError("the jackknife needs at least 2 groups")
    total = merge_all(groups) if total is None else total
    n_i = np.array([g.n for g in groups], dtype=np.int64)
    n_out = total.n - n_i
    if np.any(n_out < 1):
        raise SymmonError("the jackknife needs samples outside every group: all samples are in one group")
    diff = np.stack([g.mean for g in groups]) - total.mean
    mean_out = total.mean - diff * (n_i / n_out)[:, None]
    m2_out = (total.m2 - np.stack([g.m2 for g in groups])
              - (n_i * (total.n / n_out))[:, None, None] * diff[:, :, None] * diff[:, None, :])
    return Stats(n_out, mean_out, m2_out)


def leave_one_out(groups: Sequence[Stats], total: Stats | None = None) -> list[Stats]:
    """The merged statistics of all groups but group i, for each i (see :func:`leave_one_out_stack`)."""
    s = leave_one_out_stack(groups, total)
    return [Stats(int(n), mu, m2) for n, mu, m2 in zip(s.n, s.mean, s.m2)]


def jackknife_se(loo: np.ndarray) -> np.ndarray:
    """Delete-one-group jackknife standard error from the G leave-one-out values (rows)."""
    loo = np.asarray(loo, dtype=float)
    G = loo.shape[0]
    if G < 2:
        raise SymmonError("the jackknife needs at least 2 groups")
    return np.sqrt((G - 1) / G * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))


def jackknife(groups: Sequence[Stats], fn: Callable[[Stats], np.ndarray], total: Stats | None = None) -> np.ndarray:
    """Delete-one-group jackknife standard error of an estimate computed from the merged
    statistics: the one jackknife of every Monte Carlo error bar (moments, MoN, figures).

    Parameters
    ----------
    groups : sequence of Stats
        The replicates (``Moments.replicates`` or ``JointMoments.replicates``).
    fn : callable
        Called once on the stack of the G leave-one-out statistics
        (:func:`leave_one_out_stack`: n (G,), mean (G, d), m2 (G, d, d)); returns the
        estimate for each, with a leading axis G.
    total : Stats, optional
        ``merge_all(groups)``, if the caller has it already.
    """
    return jackknife_se(np.asarray(fn(leave_one_out_stack(groups, total)), dtype=float))


def moments_of(s: Stats, ny: int, nw: int, angles: Sequence[int] = ()
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """E y, Cov y, Cov(y, w) and Cov w from the statistics of z = [y; w; sin y_A; cos y_A]
    (of one sample, or of each of a stack: then every result has a leading axis G).

    An angle output's mean is the circular mean atan2(mean sin y, mean cos y), wrapped to
    (−π, π], as in the UT and Gauss–Hermite rules, and its variance is taken about that
    mean: Cov y + δδᵀ, with δ the (wrapped) difference of the linear mean of the
    unwrapped samples and the circular mean.  δ is of third order in the spread
    (−E e³/6 for a residual e), so the correction is of sixth order.
    """
    C = s.cov
    mean = s.mean[..., :ny].copy()
    cov = C[..., :ny, :ny].copy()
    A = list(angles)
    if A:
        k, o = len(A), ny + nw
        circ = wrap_angle(np.arctan2(s.mean[..., o: o + k], s.mean[..., o + k: o + 2 * k]))
        delta = np.zeros_like(mean)
        delta[..., A] = wrap_angle(mean[..., A] - circ)
        cov += delta[..., :, None] * delta[..., None, :]
        mean[..., A] = circ
    return mean, cov, C[..., :ny, ny: ny + nw], C[..., ny: ny + nw, ny: ny + nw]


def _raw_stats(S: np.ndarray) -> Stats:
    """Statistics of the rows z of A = [z, 1] from S = AᵀA (count, sums, cross-products)."""
    d = S.shape[0] - 1
    n = S[d, d]
    mean = S[:d, d] / n
    return Stats(int(round(n)), mean, S[:d, :d] - np.outer(S[:d, d], mean))
