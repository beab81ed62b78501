"""Linear-Gaussian Kalman filter: the first stage of the two-stage MMSE estimators.

The model is (eq. (1) of the distance paper)

.. math::

    x_{k+1} = F x_k + w_k,\\qquad y_{k+1} = H x_{k+1} + v_{k+1},
    \\qquad w_k \\sim N(0, Q),\\ v_k \\sim N(0, R),

with the initial state :math:`x_0 \\sim N(\\hat x_0, P_0)` independent of the noises.
The filter (eq. (3)) gives the Kalman estimate :math:`\\hat x_k` and its error covariance
:math:`P_k`; the closed-form estimators of :mod:`symmon.estimation.mmse` (the second stage) take them
as input. The covariances do not depend on the data, so many Monte Carlo runs of the same
model are filtered at once: ``ys`` may carry a leading batch axis.

References
----------
M. Song, W. Choi, V. Shin, "Minimum Mean Square Error Estimation of Distance Functions under
the Kalman Filtering Framework" (the distance paper), eqs. (1) and (3).
P. S. Maybeck, *Stochastic Models, Estimation and Control*, vol. 1 (Joseph form).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar
import numpy as np
from numpy.typing import ArrayLike

from ...core.arrays import readonly
from ...errors import ArgumentError, ArgumentTypeError, CovarianceError, NonFiniteError, ShapeError, SingularMatrixError, plain_repr
from ...core.gaussian import Gaussian, as_covariance, float_array, matrix_sqrt
from ..base import Filter, FilterCall
from ..inputs import check_bank_size
from ..results import KalmanResult, nees_of  # the one result type of the filters

__all__ = ["KalmanFilter", "KalmanResult"]



def _as_matrix(M: ArrayLike, name: str, shape: tuple[int | None, int | None]) -> np.ndarray:
    """Return ``M`` as a finite 2-D float array of the given shape (None: any size)."""
    arr = float_array(M, name)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)  # a scalar is a 1x1 model
    if arr.ndim != 2:
        raise ShapeError(f"{name} must be a 2-D matrix, got shape {arr.shape}")
    for axis, want in enumerate(shape):
        if want is not None and arr.shape[axis] != want:
            raise ShapeError(
                f"{name} must have shape {tuple('*' if s is None else s for s in shape)}, "
                f"got {arr.shape}"
            )
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} contains NaN or inf")
    return arr


def _solve(S: np.ndarray, B: np.ndarray, k: int) -> np.ndarray:
    """S⁻¹ B for the innovation covariance S of step ``k``, or a named error."""
    try:
        return np.linalg.solve(S, B)
    except np.linalg.LinAlgError:
        raise SingularMatrixError(f"KF: the innovation covariance S at step {k} is singular in double "
                                  "precision (H P Hᵀ dwarfs R by more than 1e16)") from None


def _unit_diagonal(d: np.ndarray) -> np.ndarray:
    """diag(d) for each row of ``d`` (G, m): (G, m, m)."""
    out = np.zeros(d.shape + d.shape[-1:])
    idx = np.arange(d.shape[-1])
    out[..., idx, idx] = d
    return out


def _where(group: np.ndarray, g: int, k: int) -> str:
    """"step k", or "run r, step k" with the first run r of group g when the runs' covariances differ."""
    if group.max(initial=0) == 0:
        return f"step {k}"
    return f"run {int(np.argmax(group == g))}, step {k}"


def _cholesky(Ss: np.ndarray, group: np.ndarray) -> np.ndarray:
    """The Cholesky factors of the innovation covariances (G, K, n_y, n_y) of each group of
    runs (``group``: the group of each run), or a named error."""
    try:
        return np.linalg.cholesky(Ss)
    except np.linalg.LinAlgError:
        g, k = np.unravel_index(int(np.argmin(np.linalg.eigvalsh(Ss)[..., 0])), Ss.shape[:2])
        raise SingularMatrixError(f"KF: the innovation covariance S at {_where(group, g, k)} is not positive "
                                  "definite in double precision (H P Hᵀ dwarfs R by more than 1e16)") from None


def _check_finite(x: np.ndarray, P: np.ndarray, loglik: np.ndarray, group: np.ndarray, bank: bool) -> None:
    """Refuse a result with NaN or inf: x (R, K, n), P (G, K, n, n) shared by the runs of
    each group (``group``: the group of each run), loglik (R, K); the first bad run and step
    are named (the step alone when not a ``bank``)."""
    bad = ~(np.isfinite(loglik) & np.isfinite(x).all(axis=-1) & np.isfinite(P).all(axis=(-1, -2))[group])
    if bad.any():
        r, k = (int(i) for i in np.argwhere(bad)[0])
        where = f"run {r}, step {k}" if bank else f"step {k}"
        raise NonFiniteError(f"KF: the filter produced NaN or inf at {where}: the state overflows double "
                             "precision (an unstable F, or measurements or x0 beyond 1e154)")


@dataclass(frozen=True, eq=False, repr=False)
class KalmanFilter(Filter):
    """Kalman filter for a linear-Gaussian state-space model (eqs. (1), (3) of the paper).

    Parameters
    ----------
    F : array_like, shape (n, n), or SDE
        State transition matrix.  A linear :class:`~symmon.SDE` (with ``Q=None``) gives its
        Kalman filter at measurement times instead: a
        :class:`~symmon.ContinuousDiscreteKalmanFilter` with the exact transition e^{A dt}
        and Van Loan's Q(dt) over each interval (``exact=True``), whose ``filter`` takes
        ``times=``.
    Q : array_like, shape (n, n)
        Process noise covariance, symmetric positive semi-definite (singular allowed: a
        component without process noise is a fixed point).
    H : array_like, shape (n_y, n)
        Measurement matrix.
    R : array_like, shape (n_y, n_y)
        Measurement noise covariance, symmetric positive *definite*: the gain inverts
        ``H P Hᵀ + R``, which a singular R can make singular.

    Raises
    ------
    ShapeError
        A matrix has the wrong shape or non-finite entries.
    CovarianceError
        Q is not symmetric PSD or R is not symmetric positive definite.

    Examples
    --------
    >>> kf = KalmanFilter(F=1.0, Q=1.0, H=1.0, R=1.0)
    >>> res = kf.filter([[1.0]], x0=[0.0], P0=[[1.0]])
    >>> round(float(res.x[0, 0]), 12), round(float(res.P[0, 0, 0]), 12)
    (0.666666666667, 0.666666666667)
    """

    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray

    def __post_init__(self) -> None:
        F = _as_matrix(self.F, "F", (None, None))
        n = F.shape[0]
        if F.shape != (n, n):
            raise ShapeError(f"F must be square, got shape {F.shape}")
        H = _as_matrix(self.H, "H", (None, n))
        n_y = H.shape[0]
        Q = as_covariance(self.Q, "Q", dim=n)
        R = as_covariance(self.R, "R", dim=n_y)
        if np.linalg.eigvalsh(R)[0] <= 0.0:
            raise CovarianceError("R must be positive definite (the innovation covariance is inverted)")
        for name, value in (("F", F), ("Q", Q), ("H", H), ("R", R)):
            object.__setattr__(self, name, readonly(value))

    @property
    def n(self) -> int:
        """State dimension."""
        return int(self.F.shape[0])

    @property
    def n_y(self) -> int:
        """Measurement dimension."""
        return int(self.H.shape[0])

    def _initial_mean(self, x0: ArrayLike, batch: int | None) -> np.ndarray:
        arr = float_array(x0, "x0")
        ok = arr.shape == (self.n,) or (batch is not None and arr.shape == (batch, self.n))
        if not ok:
            want = f"({self.n},)" + ("" if batch is None else f" or ({batch}, {self.n})")
            raise ShapeError(f"x0 must have shape {want}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ShapeError("x0 contains NaN or inf")
        return arr

    def __repr__(self) -> str:
        return f"KalmanFilter(n={self.n}, n_y={self.n_y})"

    gaussian_mode: ClassVar[bool] = True

    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y)."""
        return self.n, self.n_y

    def step_cost(self) -> int:
        """The EKF's: TT1's cost for the prediction and for the update."""
        from ...transforms.taylor import TT1

        return TT1().cost(self.n) + TT1().cost(self.n)

    @property
    def method(self) -> str:
        """"KF"."""
        return "KF"

    def as_gaussian_mode(self) -> Any:
        """This filter as the EKF of its linear model (equal to rounding), a mode of :class:`~symmon.IMM`."""
        from .nonlinear import NonlinearKalmanFilter  # the linear filter runs in NumPy without it
        from ...core.model import Model
        from ...transforms.taylor import TT1
        import sympy as sp

        xs = sp.Matrix(sp.symbols(f"x0:{self.n}", real=True))
        f = Model(list(xs), list(sp.Matrix(self.F) * xs), name="linear_F")
        h = Model(list(xs), list(sp.Matrix(self.H) * xs), name="linear_H")
        return NonlinearKalmanFilter(f, h, self.Q, self.R, TT1())

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        # Per run and step: x, x_pred, the innovation, its whitened form, NIS, log-likelihood;
        # the covariances and gains are shared by the runs.
        n, n_y = self.n, self.n_y
        return 2 * n + 2 * n_y + 2, 2 * n * n + n_y * n_y + n * n_y

    def _check_prior(self, x0: Any, P0: ArrayLike | None, runs: int | None) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(x0, Gaussian) == (P0 is not None):
            raise ShapeError("give x0 as a Gaussian, or its mean together with P0")
        if isinstance(x0, Gaussian):
            x0, P0 = x0.mean, x0.cov
        return self._initial_mean(x0, runs), as_covariance(P0, "P0", dim=self.n)

    def _filter(self, call: FilterCall) -> KalmanResult:
        """The recursion (eq. (3)), each step predicting, then updating with the Joseph form
        :math:`P = (I - KH) P^- (I - KH)^T + K R K^T`, which stays symmetric PSD under
        rounding (the short form :math:`(I - KH)P^-` does not).

        A row of NaN in ``ys`` skips the update (the step only predicts, with log-likelihood
        0), a row with some NaN updates on the measured components (with D = diag(measured),
        S̃ = D S D + (I − D) and the rows of H of the missing components zeroed, the gain has
        zero columns there).  The covariances (P, P_pred, S) and gains do not depend on the
        data: a bank's runs share them ((K, n, n)) when they have the same missing
        measurements, and each run has its own ((N, K, n, n)) when they differ.
        """
        kept, batch = call.keep, call.runs
        n, n_y = self.n, self.n_y
        shared = 2 * n * n + n_y * n_y + n * n_y
        x, P0 = call.x0, call.P0
        Yb = call.Y
        runs, K = Yb.shape[0], call.steps
        # The covariances depend on which components are measured, not on the values: one
        # recursion per distinct pattern of missing measurements ("group"), shared by its runs.
        missing = np.isnan(Yb)
        if missing.any():
            patterns, group = np.unique(~missing.reshape(runs, -1), axis=0, return_inverse=True)
            masks = patterns.reshape(-1, K, n_y).astype(float)
            group = group.reshape(-1)
            Yb = np.where(missing, 0.0, Yb)  # masked below; no NaN enters the products
            if len(masks) > 1:
                check_bank_size(runs, K, 2 * n + 2 * n_y + 2 + shared, "KF results (one covariance per run: "
                                "the runs have different missing measurements)",
                                "filter the runs with the same missing measurements together, or in smaller banks")
        else:
            masks, group = np.ones((1, K, n_y)), np.zeros(runs, dtype=np.intp)
        n_groups = len(masks)
        F, Q, H, R = self.F, self.Q, self.H, self.R
        eye = np.eye(n)
        x = np.array(np.broadcast_to(x, (runs, n)))
        P = np.broadcast_to(P0, (n_groups, n, n))
        xs, xps = np.empty((runs, K, n)), np.empty((runs, K, n))
        innovs = np.empty((runs, K, n_y))
        Ps, Pps = np.empty((n_groups, K, n, n)), np.empty((n_groups, K, n, n))
        Ss, gains = np.empty((n_groups, K, n_y, n_y)), np.empty((n_groups, K, n, n_y))
        with np.errstate(over="ignore", invalid="ignore"):  # a non-finite number is refused below
            for k in range(K):
                m = masks[:, k]
                x_pred = x @ F.T
                P_pred = F @ P @ F.T + Q
                P_pred = 0.5 * (P_pred + np.swapaxes(P_pred, -1, -2))
                # D S D + (I − D) and D H P⁻ (the update of the measured block only).
                S = (H @ P_pred @ H.T + R) * (m[:, :, None] * m[:, None, :]) + _unit_diagonal(1.0 - m)
                if not (np.all(np.isfinite(P_pred)) and np.all(np.isfinite(S))):
                    raise NonFiniteError(f"KF: the predicted covariance overflows at step {k} (F, Q or P0 too "
                                         "large for double precision)")
                # K = P⁻Hᵀ S⁻¹ via a solve (S symmetric), not an explicit inverse.
                G = np.swapaxes(_solve(S, (H @ P_pred) * m[:, :, None], k), -1, -2)
                innov = (Yb[:, k] - x_pred @ H.T) * masks[group, k]
                x = x_pred + (innov @ G[0].T if n_groups == 1 else np.einsum("rij,rj->ri", G[group], innov))
                IKH = eye - G @ H
                P = IKH @ P_pred @ np.swapaxes(IKH, -1, -2) + G @ R @ np.swapaxes(G, -1, -2)
                P = 0.5 * (P + np.swapaxes(P, -1, -2))
                xs[:, k], xps[:, k], innovs[:, k] = x, x_pred, innov
                Ps[:, k], Pps[:, k], Ss[:, k], gains[:, k] = P, P_pred, S, G
            # log N(ν_k; 0, S_k) of the measured block: S does not depend on the data, its
            # factor serves every run of its group (the unit diagonal of a missing component
            # adds nothing to log det S nor to νᵀ S⁻¹ ν).
            L = _cholesky(Ss, group)
            log_det = 2 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=-1)
            white = np.linalg.solve(L[0] if n_groups == 1 else L[group], innovs[..., None])[..., 0]
            nis = (white**2).sum(axis=-1)  # νᵀ S⁻¹ ν from the same factor
            loglik = -0.5 * (nis + (log_det + masks.sum(axis=-1) * np.log(2 * np.pi))[group])
        _check_finite(xs, Ps, loglik, group, batch is not None)
        if n_groups == 1:  # shared by the runs
            Ps, Pps, Ss, gains = Ps[0], Pps[0], Ss[0], gains[0]
        else:
            Ps, Pps, Ss, gains = Ps[group], Pps[group], Ss[group], gains[group]
        measured = (~missing).sum(axis=-1) if missing.any() else None
        nees = None if call.truth is None else nees_of(xs, np.broadcast_to(Ps, xs.shape + (n,)), call.truth, ())
        if batch is None:
            xs, xps, innovs, nis, loglik = xs[0], xps[0], innovs[0], nis[0], loglik[0]
            nees = None if nees is None else nees[0]
            measured = None if measured is None else measured[0]
        arrays = {"x": xs, "P": Ps, "x_pred": xps, "P_pred": Pps, "innovation": innovs, "S": Ss,
                  "nis_values": nis}
        arrays = {k: readonly(v) if kept is None or k.removesuffix("_values") in kept else None
                  for k, v in arrays.items()}
        return KalmanResult(**arrays, gain=readonly(gains), loglik=readonly(loglik), n_y=n_y, method="KF",
                            measured=None if measured is None else readonly(measured),
                            nees_values=None if nees is None else readonly(nees))

    def simulate(
        self,
        K: int,
        x0: ArrayLike,
        rng: np.random.Generator,
        *,
        P0: ArrayLike | None = None,
        runs: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw true states and measurements from the model.

        Parameters
        ----------
        K : int
            Number of time steps (K >= 1).
        x0 : array_like, shape (n,)
            Initial state, or its mean if ``P0`` is given.
        rng : numpy.random.Generator
            Source of all random numbers.
        P0 : array_like, shape (n, n), optional
            Covariance of a random initial state; ``None`` means ``x0`` is known exactly.
        runs : int, optional
            Number of independent runs; adds a leading axis to the outputs.

        Returns
        -------
        states : ndarray, shape (K, n) or (runs, K, n)
            True states :math:`x_1, \\dots, x_K`.
        measurements : ndarray, shape (K, n_y) or (runs, K, n_y)
            Measurements :math:`y_1, \\dots, y_K`.

        Raises
        ------
        ResourceError
            runs × K × 2(n + n_y) beyond :data:`~symmon.filters.inputs.MAX_BANK_NUMBERS`.
        NonFiniteError
            The simulated state overflows (an unstable F), naming the run and step.
        """
        if isinstance(K, bool) or not isinstance(K, (int, np.integer)) or K < 1:
            raise ArgumentError(f"K must be a positive integer, got {K!r}")
        if runs is not None and (isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1):
            raise ArgumentError(f"runs must be a positive integer or None, got {plain_repr(runs)}")
        if not isinstance(rng, np.random.Generator):
            raise ArgumentTypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        x = self._initial_mean(x0, None)
        lead = () if runs is None else (int(runs),)
        n, n_y = self.n, self.n_y
        # The noises, states and measurements of every run and step.
        check_bank_size(runs or 1, K, 2 * (n + n_y), "KalmanFilter.simulate", "simulate fewer runs or steps")
        if P0 is not None:
            L0 = matrix_sqrt(as_covariance(P0, "P0", dim=n))
            x = x + rng.standard_normal(lead + (n,)) @ L0.T
        else:
            x = np.broadcast_to(x, lead + (n,))
        # Draw all noise at once (fixed order: process, then measurement) for reproducibility.
        w = rng.standard_normal(lead + (int(K), n)) @ matrix_sqrt(self.Q).T
        v = rng.standard_normal(lead + (int(K), n_y)) @ matrix_sqrt(self.R).T
        states = np.empty(lead + (int(K), n))
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging truth is refused below
            for k in range(int(K)):
                x = x @ self.F.T + w[..., k, :]
                states[..., k, :] = x
            meas = states @ self.H.T + v
        bad = ~(np.isfinite(states).all(axis=-1) & np.isfinite(meas).all(axis=-1))
        if bad.any():
            *r, k = (int(i) for i in np.argwhere(bad)[0])
            where = f"step {k}" if not r else f"run {r[0]}, step {k}"
            raise NonFiniteError(f"KalmanFilter.simulate: the simulated state overflows at {where}: F is unstable "
                                 "over this many steps, or x0, P0 or Q too large for double precision")
        return states, meas
