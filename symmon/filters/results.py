"""The result of a nonlinear Kalman filter and its consistency tests: NEES, NIS and their χ² bounds.

:class:`NonlinearKalmanResult` holds the filtered and predicted means and covariances, the
innovations and their covariances of one run or a bank of runs of
:class:`symmon.NonlinearKalmanFilter`; its :meth:`~NonlinearKalmanResult.nees`,
:meth:`~NonlinearKalmanResult.nis`, :meth:`~NonlinearKalmanResult.anees` and
:meth:`~NonlinearKalmanResult.anis` are the consistency statistics, the averages returned as a
:class:`ConsistencyTest` with its two-sided χ² acceptance interval.

References
----------
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley, 2001, §5.4 (NEES, NIS and their χ² tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from ..core.angles import wrap_angle
from ..errors import ShapeError, SymmonError
from ..core.checks import readonly
from ..core.gaussian import Gaussian

__all__ = ["NonlinearKalmanResult", "ConsistencyTest"]


@dataclass(frozen=True, eq=False)
class ConsistencyTest:
    """An averaged NEES or NIS with its two-sided χ² acceptance interval.

    With N independent terms of dimension d averaged, N·value ~ χ²(N d) for a consistent
    filter (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2), so the interval is
    [χ²_{Nd}(α/2), χ²_{Nd}(1 − α/2)] / N with α = 1 − ``confidence``.

    Attributes
    ----------
    value : ndarray
        The average: shape (K,) over the runs of a bank at each step; shape () over the
        K steps of a single run.
    lower, upper : float
        The bounds of the interval.
    dof : int
        N·d.
    confidence : float
    """

    value: np.ndarray
    lower: float
    upper: float
    dof: int
    confidence: float

    @property
    def inside(self) -> np.ndarray:
        """Whether each value lies in [lower, upper]."""
        return (self.value >= self.lower) & (self.value <= self.upper)

    def __repr__(self) -> str:
        frac = float(np.mean(self.inside))
        v = np.asarray(self.value)
        shown = f"{float(v):.4g}" if v.ndim == 0 else f"mean {float(v.mean()):.4g} over {v.size} steps"
        return (f"ConsistencyTest({shown}, {self.confidence:.0%} interval [{self.lower:.4g}, "
                f"{self.upper:.4g}], dof {self.dof}, {frac:.0%} inside)")


def _consistency(stat: np.ndarray, d: int, confidence: float) -> ConsistencyTest:
    """Average ``stat`` (K,) over K steps or (R, K) over the R runs; χ² bounds (§5.4.2)."""
    if not 0.0 < confidence < 1.0:
        raise SymmonError(f"confidence must lie in (0, 1), got {confidence!r}")
    value = stat.mean(axis=0)
    N = stat.shape[0]
    dof = N * d
    lo, hi = stats.chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof) / N
    return ConsistencyTest(readonly(value), float(lo), float(hi), int(dof), float(confidence))


def _quadratic_forms(e: np.ndarray, C: np.ndarray) -> np.ndarray:
    """eᵀ C⁻¹ e for batches e (..., d), C (..., d, d), by a solve."""
    return np.einsum("...i,...i->...", e, np.linalg.solve(C, e[..., None])[..., 0])


@dataclass(frozen=True, eq=False)
class NonlinearKalmanResult:
    """Output of :meth:`NonlinearKalmanFilter.filter`.

    Shapes are for one run; a bank of R runs adds a leading axis R to every array
    (``x`` is (R, K, n), ``P`` is (R, K, n, n)).

    Attributes
    ----------
    x : ndarray, shape (K, n)
        Filtered means x̂_{k|k}.
    P : ndarray, shape (K, n, n)
        Filtered covariances P_{k|k}.
    x_pred : ndarray, shape (K, n)
        Predicted means x̂_{k|k−1}.
    P_pred : ndarray, shape (K, n, n)
        Predicted covariances P_{k|k−1}.
    innovation : ndarray, shape (K, n_y)
        Innovations ν_k = y_k − ŷ_{k|k−1} (angle components wrapped).
    S : ndarray, shape (K, n_y, n_y)
        Innovation covariances S_k.
    angle_states : tuple of int
        State components that are angles (their estimation errors are wrapped).
    method : str
        The filter, e.g. ``"UKF(alpha=1, beta=0, kappa=None)"``.
    choices : ndarray of str, shape (K,) or (R, K), or None
        For an :class:`Adaptive` filter: the filter used at each step (of each run), e.g.
        ``"EKF"`` or ``"CKF"``; None for a fixed transform.
    """

    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray
    P_pred: np.ndarray
    innovation: np.ndarray
    S: np.ndarray
    angle_states: tuple[int, ...] = ()
    method: str = ""
    choices: np.ndarray | None = None

    @property
    def runs(self) -> int | None:
        """Number of runs of a bank; None for a single run."""
        return int(self.x.shape[0]) if self.x.ndim == 3 else None

    def estimate(self, k: int, run: int | None = None) -> Gaussian:
        """N(x̂_{k|k}, P_{k|k}) at step k (0-based), of run ``run`` for a bank."""
        if (run is None) != (self.runs is None):
            raise ShapeError("give run= for a bank of runs, and only then")
        x, P = (self.x, self.P) if run is None else (self.x[run], self.P[run])
        return Gaussian(x[k], P[k])

    def nees(self, x_true: ArrayLike) -> np.ndarray:
        """Normalised estimation error squared ε_k = (x_k − x̂_k)ᵀ P_k⁻¹ (x_k − x̂_k).

        Parameters
        ----------
        x_true : array_like, shape of ``x``
            The true states x_k ((K, n), or (R, K, n) for a bank).

        Returns
        -------
        ndarray, shape (K,) or (R, K)
        """
        X = np.asarray(x_true, dtype=float)
        if X.shape != self.x.shape:
            raise ShapeError(f"x_true must have the shape of x, {self.x.shape}, got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ShapeError("x_true contains NaN or inf")
        e = X - self.x
        if self.angle_states:
            idx = list(self.angle_states)
            e[..., idx] = wrap_angle(e[..., idx])
        return _quadratic_forms(e, self.P)

    def nis(self) -> np.ndarray:
        """Normalised innovation squared ν_kᵀ S_k⁻¹ ν_k, shape (K,) or (R, K)."""
        return _quadratic_forms(self.innovation, self.S)

    def anees(self, x_true: ArrayLike, confidence: float = 0.95) -> ConsistencyTest:
        """Average NEES with its χ² interval: per step over the runs of a bank, or over the
        steps of a single run (Bar-Shalom et al. 2001, §5.4.2)."""
        return _consistency(self.nees(x_true), self.x.shape[-1], confidence)

    def anis(self, confidence: float = 0.95) -> ConsistencyTest:
        """Average NIS with its χ² interval, averaged as :meth:`anees`."""
        return _consistency(self.nis(), self.innovation.shape[-1], confidence)

    def __repr__(self) -> str:
        n, n_y = self.x.shape[-1], self.innovation.shape[-1]
        K = self.x.shape[-2]
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return (f"NonlinearKalmanResult({self.method}, {runs}steps={K}, n={n}, n_y={n_y}, "
                f"mean NIS {float(self.nis().mean()):.4g} (expected {n_y}))")
