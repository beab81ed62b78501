"""The one result of the Kalman filters and its consistency tests: NEES, NIS and their χ² bounds.

:class:`KalmanResult` holds the filtered and predicted means and covariances, the
innovations and their covariances (and, for the linear filter, the gains) of one run or a
bank of runs of :class:`symmon.KalmanFilter` or :class:`symmon.NonlinearKalmanFilter`; its
:meth:`~KalmanResult.nees`, :meth:`~KalmanResult.nis`, :meth:`~KalmanResult.anees` and
:meth:`~KalmanResult.anis` are the consistency statistics, the averages returned as a
:class:`ConsistencyTest` with its two-sided χ² acceptance interval.

References
----------
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley, 2001, §5.4 (NEES, NIS and their χ² tests).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Sequence, Union

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from ..core.angles import wrap_angle
from ..errors import ArgumentError, NonFiniteError, ShapeError, SingularMatrixError, SymmonError, plain_repr
from ..measures.weights import SINGULAR_CORR
from ..core.arrays import readonly
from ..core.gaussian import Gaussian
from .inputs import check_truth

__all__ = ["KalmanResult", "NonlinearKalmanResult", "SmootherResult", "ConsistencyTest", "Credibility", "step_nees",
           "windowed_nis", "moving_sum", "CREDIBILITY_WINDOW", "CREDIBILITY_CONFIDENCE"]


@dataclass(frozen=True, eq=False)
class ConsistencyTest:
    """An averaged NEES or NIS with its two-sided χ² acceptance interval.

    With N independent terms of dimension d averaged, N·value ~ χ²(N d) for a consistent
    filter (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2, (5.4.2-5) and (5.4.2-9)), so the
    interval is [χ²_{Nd}(α/2), χ²_{Nd}(1 − α/2)] / N with α = 1 − ``confidence``.  With
    missing measurements N counts only the terms that measured something (per step over the
    runs of a bank), so the value is the mean over what was measured.

    The interval assumes the N terms independent: true of the runs of a bank, and of the
    NIS of one run (the innovations of a consistent filter are white), but not of the NEES
    of one run, whose errors are correlated from step to step: its interval is then too
    narrow, and :attr:`note` says so (average over a bank of independent runs instead).

    Attributes
    ----------
    value : ndarray
        The average: shape (K,) over the runs of a bank at each step; shape () over the
        K steps of a single run.
    lower, upper : float, or ndarray of shape (K,)
        The bounds of the interval (per step when the dimension varies: missing
        measurements in a bank).
    dof : int, or ndarray of shape (K,)
        N·d, or the sum of the averaged terms' dimensions.
    confidence : float
    note : str
        A caveat on the interval ("" when none): a single run's ANEES.
    """

    value: np.ndarray
    lower: float | np.ndarray
    upper: float | np.ndarray
    dof: int | np.ndarray
    confidence: float
    note: str = ""

    @property
    def inside(self) -> np.ndarray:
        """Whether each value lies in [lower, upper]."""
        return (self.value >= self.lower) & (self.value <= self.upper)

    def __repr__(self) -> str:
        frac = float(np.mean(self.inside))
        v = np.asarray(self.value)
        shown = f"{float(v):.4g}" if v.ndim == 0 else f"mean {float(v.mean()):.4g} over {v.size} steps"
        if np.ndim(self.lower) == 0:
            interval = f"[{self.lower:.4g}, {self.upper:.4g}], dof {self.dof}"
        else:
            interval = f"per step, [{float(np.min(self.lower)):.4g}, {float(np.max(self.upper)):.4g}] at widest"
        note = f"; {self.note}" if self.note else ""
        return f"ConsistencyTest({shown}, {self.confidence:.0%} interval {interval}, {frac:.0%} inside{note})"


#: The caveat of a single run's ANEES (:class:`ConsistencyTest`).
ONE_RUN_NEES = ("one run: its K NEES are correlated from step to step, the interval treats them as "
                "independent and is too narrow; average over a bank of independent runs")


def _consistency(stat: np.ndarray, d: int | np.ndarray, confidence: float, note: str = "") -> ConsistencyTest:
    """Average ``stat`` (K,) over K steps or (R, K) over the R runs; χ² bounds (§5.4.2).

    ``d`` is the dimension of each term, or an array of the shape of ``stat`` when it varies
    (missing measurements): a term with nothing measured (dimension 0) is left out of the
    average and of N, so the value is the mean over the terms measured, and the degrees of
    freedom are the sum of their dimensions; a step with none measured is refused."""
    if not 0.0 < confidence < 1.0:
        raise SymmonError(f"confidence must lie in (0, 1), got {plain_repr(confidence)}")
    N = stat.shape[0]
    if np.ndim(d) == 0:
        value = stat.mean(axis=0)
        dof = N * int(d)
        lo, hi = stats.chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof) / N
        return ConsistencyTest(readonly(value), float(lo), float(hi), int(dof), float(confidence), note)
    d = np.asarray(d)
    if stat.ndim == 1:  # one run: drop the steps with nothing measured
        stat, d = stat[d > 0], d[d > 0]
    dof = d.sum(axis=0)
    if np.any(dof == 0):
        k = int(np.flatnonzero(dof == 0)[0])
        raise SymmonError(f"step {k} has no measured component in any run: its average NIS has no degrees of "
                          "freedom; average over the other steps, e.g. res.nis()[:, res.measured.any(axis=0)]")
    N = np.count_nonzero(d > 0, axis=0)  # the terms that measured something (per step of a bank)
    value = np.where(d > 0, stat, 0.0).sum(axis=0) / N
    lo, hi = (stats.chi2.ppf(q, dof) / N for q in ((1 - confidence) / 2, (1 + confidence) / 2))
    if np.ndim(dof) == 0:
        return ConsistencyTest(readonly(np.asarray(value)), float(lo), float(hi), int(dof), float(confidence), note)
    return ConsistencyTest(readonly(value), readonly(lo), readonly(hi), readonly(dof), float(confidence), note)


def _step_index(k: int, steps: int, run: int | None, runs: int | None) -> tuple[int, int | None]:
    """``k`` (and ``run``) as indices of a result of ``steps`` steps (and ``runs`` runs);
    negative ones count from the end, as in Python.

    Raises
    ------
    ArgumentError
        For a non-integer, or an index outside the steps (or runs), naming the range.
    """
    out = []
    for name, i, size in (("k", k, steps), ("run", run, runs)):
        if i is None:
            out.append(None)
            continue
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
            raise ArgumentError(f"{name} must be an integer, got {i!r}")
        if not -size <= i < size:
            raise ArgumentError(f"{name} = {i} is outside the {size} {'steps' if name == 'k' else 'runs'} of this "
                                f"result: use 0 to {size - 1} (or -{size} to -1 from the end)")
        out.append(int(i))
    return out[0], out[1]


def _where(index: tuple[int, ...], batch_ndim: int) -> str:
    """"step k" or "run r, step k" for an index into the leading (R, K) axes of a result."""
    if batch_ndim >= 2:
        return f"run {index[-2]}, step {index[-1]}"
    return f"step {index[-1]}" if batch_ndim == 1 else "the estimate"


@np.errstate(over="ignore", invalid="ignore")  # a non-finite form is refused below
def quadratic_forms(e: np.ndarray, C: np.ndarray, what: str = "covariance") -> np.ndarray:
    """eᵀ C⁻¹ e for batches e (..., d), C (..., d, d), in the same way in any units.

    The form is computed on the correlation matrix, (e/σ)ᵀ Ρ⁻¹ (e/σ) with σ = √diag C and
    Ρ = C / σσᵀ, and C is singular when Ρ is: a smallest eigenvalue at or below
    :data:`~symmon.measures.weights.SINGULAR_CORR`.  So a standard deviation of 1e-200
    beside one of 1 is fine (its variance 1e-400 is not: it underflows to 0), and two
    states in mm and in km are no more singular than in m.

    Raises
    ------
    SingularMatrixError
        If a covariance has a zero (or underflowed, or NaN) variance, or a correlation
        matrix that is singular: the normalised error is undefined there.
    NonFiniteError
        If a form overflows (an error of more than ~1e154 standard deviations).
    """
    batch = C.ndim - 2
    if not np.all(np.isfinite(C)):
        idx = tuple(int(j) for j in np.argwhere(~np.isfinite(C).all(axis=(-1, -2)))[0])
        raise NonFiniteError(f"the {what} at {_where(idx, batch)} holds NaN or inf")
    d = np.diagonal(C, axis1=-2, axis2=-1)
    flat = ~(d >= np.finfo(float).tiny)  # zero, subnormal (digits lost to underflow) or NaN
    if flat.any():
        *idx, i = (int(j) for j in np.argwhere(flat)[0])
        raise SingularMatrixError(
            f"the {what} at {_where(tuple(idx), batch)} is singular: it has variance {d[tuple(idx) + (i,)]:.3g} "
            f"in component {i} "
            f"(zero, or below {np.finfo(float).tiny:.3g} where doubles lose their digits: a component known "
            "exactly, or a variance that underflowed): its normalised error squared is undefined")
    r = 1.0 / np.sqrt(d)
    corr = r[..., :, None] * C * r[..., None, :]
    lam = np.linalg.eigvalsh(0.5 * (corr + np.swapaxes(corr, -1, -2)))[..., 0]
    singular = ~(lam > SINGULAR_CORR)
    if singular.any():
        idx = tuple(int(j) for j in np.argwhere(singular)[0])
        raise SingularMatrixError(
            f"the {what} at {_where(idx, batch)} is singular (smallest eigenvalue of its correlation "
            f"matrix {lam[idx]:.3g}): a combination of components is known exactly, so the normalised "
            "error squared is undefined")
    z = e * r
    return _finite_forms(np.einsum("...i,...i->...", z, np.linalg.solve(corr, z[..., None])[..., 0]))


def _finite_forms(q: np.ndarray) -> np.ndarray:
    """``q``, the normalised errors squared of a batch, refused where one overflowed.

    Raises
    ------
    NonFiniteError
        Naming the first run and step whose form is not finite.
    """
    if not np.all(np.isfinite(q)):
        idx = tuple(int(j) for j in np.argwhere(~np.isfinite(q))[0])
        raise NonFiniteError(f"the normalised error squared at {_where(idx, q.ndim)} overflows: the error is "
                             "beyond 1e154 standard deviations")
    return q


def nees_of(x: np.ndarray, P: np.ndarray, x_true: ArrayLike, angle_states: Sequence[int]) -> np.ndarray:
    """(x_true − x)ᵀ P⁻¹ (x_true − x) per step, the angle components of the error wrapped."""
    e = check_truth(x_true, x.shape) - x
    if angle_states:
        idx = list(angle_states)
        e[..., idx] = wrap_angle(e[..., idx])
    return quadratic_forms(e, P, "state covariance P")


def step_nees(values: np.ndarray, trace: np.ndarray) -> np.ndarray:
    """The NEES computed inside a compiled filter step, checked: ``values`` (R, K) or (K,) and
    ``trace`` = tr Ρ⁻¹ of each step's correlation matrix Ρ (:func:`symmon.filters.gaussian.step.nees_graph`).

    A covariance counts as singular when tr Ρ⁻¹ ≥ 1 / :data:`~symmon.measures.weights.SINGULAR_CORR`
    (infinite for a failed factor, NaN for a zero variance): every Ρ whose smallest eigenvalue is
    at most SINGULAR_CORR (the test of :meth:`KalmanResult.nees` on stored x and P) and,
    since tr Ρ⁻¹ ≤ n / λ_min, some with λ_min up to n times that.

    Raises
    ------
    SingularMatrixError
        At the first step whose P is singular in this sense, naming it.
    NonFiniteError
        If a NEES overflows.
    """
    singular = ~(trace < 1.0 / SINGULAR_CORR)
    if singular.any():
        idx = tuple(int(j) for j in np.argwhere(singular)[0])
        raise SingularMatrixError(
            f"the state covariance P at {_where(idx, values.ndim)} is singular (a zero variance, or a "
            f"correlation matrix whose inverse has trace {trace[idx]:.3g} ≥ {1 / SINGULAR_CORR:.0e}): a "
            "combination of components is known exactly, so the normalised error squared is undefined")
    return _finite_forms(values)


#: The sliding window, in steps, of :attr:`KalmanResult.credibility`: long enough that a
#: consistent filter's windowed NIS rarely leaves its band, short enough to follow a track.
CREDIBILITY_WINDOW = 10
#: The two-sided confidence of the windowed NIS band of :attr:`KalmanResult.credibility`: a
#: consistent filter flags about 1 % of its steps.
CREDIBILITY_CONFIDENCE = 0.99


@dataclass(frozen=True, eq=False)
class Credibility:
    """A filter's credibility, flagged online: the steps where a statistic over a sliding
    window leaves the band a credible filter keeps it in (:attr:`KalmanResult.credibility`).

    The statistic is the mean NIS over the last ``window`` steps (fewer at the start): for a
    consistent filter its sum is χ² with the summed measured dimensions as degrees of
    freedom (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2), so the band is the two-sided
    ``confidence`` interval of that χ² divided by the steps in the window.  Above the band
    the filter is overconfident (its covariance too small for its errors), below it too
    cautious.  A particle filter also flags the steps where its mean effective sample size
    over the window falls below ``ess_floor`` particles (a degenerate cloud, whatever its NIS).

    Attributes
    ----------
    steps : ndarray of bool, shape (K,) or (R, K)
        True at each step (of each run) where the filter is flagged as not credible.
    statistic : ndarray, shape (K,) or (R, K)
        The windowed mean NIS (unitless; NaN where the window measured nothing).
    band : tuple of two ndarrays, shape of ``statistic``
        Its lower and upper bounds.
    window : int
        Steps in the sliding window.
    confidence : float
        Of the χ² band.
    ess : ndarray or None
        A particle filter's windowed mean ESS (particles); None for the others.
    ess_floor : float or None
        The ESS below which a particle filter's step is flagged.
    """

    steps: np.ndarray
    statistic: np.ndarray
    band: tuple[np.ndarray, np.ndarray]
    window: int
    confidence: float
    ess: np.ndarray | None = None
    ess_floor: float | None = None

    @property
    def fraction(self) -> float:
        """The share of steps (over all runs) flagged, in [0, 1]."""
        return float(np.mean(self.steps))

    @property
    def flagged(self) -> np.ndarray:
        """The indices of the flagged steps: (k,) for one run, (run, k) rows for a bank."""
        return np.flatnonzero(self.steps) if self.steps.ndim == 1 else np.argwhere(self.steps)

    def __repr__(self) -> str:
        what = "NIS" if self.ess is None else f"NIS and ESS (floor {self.ess_floor:.3g} particles)"
        return (f"Credibility({what}, window {self.window} steps, {self.confidence:.0%} band: "
                f"{self.fraction:.1%} of {self.steps.size} steps flagged)")


def moving_sum(a: np.ndarray, window: int) -> np.ndarray:
    """The sum of ``a`` over the last ``window`` entries of its last axis, ending at each
    entry (fewer at the start)."""
    c = np.cumsum(a, axis=-1)
    out = c.copy()
    out[..., window:] -= c[..., :-window]
    return out


def windowed_nis(nis: np.ndarray, dof: int | np.ndarray, window: int, confidence: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mean NIS over a sliding window of ``window`` steps ending at each step, and its
    χ² band (:class:`Credibility`).

    Parameters
    ----------
    nis : ndarray, shape (K,) or (R, K)
    dof : int or ndarray of the shape of ``nis``
        The measured dimension of each step (0: nothing measured, left out).
    window : int
    confidence : float in (0, 1)

    Returns
    -------
    statistic, lower, upper : ndarray, shape of ``nis``
        NaN where the window measured nothing.

    Examples
    --------
    >>> import numpy as np
    >>> s, lo, hi = windowed_nis(np.array([1.0, 3.0, 2.0]), 1, 2, 0.95)
    >>> s.tolist(), bool(lo[1] < 1 < hi[1])
    ([1.0, 2.0, 2.5], True)
    """
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ArgumentError(f"window must be a positive integer of steps, got {plain_repr(window)}")
    if not 0.0 < confidence < 1.0:
        raise ArgumentError(f"confidence must lie in (0, 1), got {plain_repr(confidence)}")
    d = np.broadcast_to(np.asarray(dof, dtype=float), nis.shape)
    measured = d > 0
    total = moving_sum(np.where(measured, nis, 0.0), window)
    dofs = moving_sum(d, window)
    count = moving_sum(measured.astype(float), window)
    with np.errstate(invalid="ignore", divide="ignore"):
        stat = np.where(count > 0, total / np.where(count > 0, count, 1.0), np.nan)
        alpha = 1.0 - confidence
        lo = np.where(count > 0, stats.chi2.ppf(alpha / 2, np.where(dofs > 0, dofs, 1.0)) / np.maximum(count, 1.0), np.nan)
        hi = np.where(count > 0, stats.chi2.ppf(1 - alpha / 2, np.where(dofs > 0, dofs, 1.0)) / np.maximum(count, 1.0),
                      np.nan)
    return stat, lo, hi


#: Which state components a block of :meth:`KalmanResult.cross_cov` selects.
Block = Union[slice, Sequence[int]]

@dataclass(frozen=True, eq=False)
class KalmanResult:
    """The result of every Kalman filter of symmon: :meth:`KalmanFilter.filter
    <symmon.KalmanFilter.filter>` and :meth:`NonlinearKalmanFilter.filter
    <symmon.NonlinearKalmanFilter.filter>`.

    Shapes are for one run; a bank of R runs adds a leading axis R to every array
    (``x`` is (R, K, n)), except the covariances of the linear filter, which do not depend on
    the data and are shared by the runs (``P`` stays (K, n, n); the methods broadcast).
    An array the filter was told not to keep (``filter(..., keep=...)``) is None, and a
    method that needs it says so.

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
    gain : ndarray, shape (K, n, n_y), or None
        Kalman gains K_k (the linear filter; None for the nonlinear ones).
    loglik : ndarray, shape (K,), or None
        log N(ν_k; 0, S_k) of each step, computed in the compiled step (its sum is
        :attr:`log_likelihood`).
    angle_states : tuple of int
        State components that are angles (their estimation errors are wrapped).
    method : str
        The filter: ``"KF"``, ``"EKF"``, ``"UKF(alpha=1, beta=0, kappa=None)"``, ...
    choices : ndarray of str, shape (K,) or (R, K), or None
        For an :class:`Adaptive` filter: the filter used at each step (of each run), e.g.
        ``"EKF"`` or ``"CKF"``; None for a fixed transform.
    measured : ndarray of int, shape (K,) or (R, K), or None
        With missing measurements (NaN in ``ys``): how many components were measured at
        each step (the degrees of freedom of its NIS); None when all were.
    nis_values : ndarray, shape (K,) or (R, K), or None
        νᵀ S⁻¹ ν of each step, computed inside the compiled step of the nonlinear filters
        (kept with ``keep=("nis", ...)``, so a bank need not keep ν and S for its NIS test).
    n_y : int or None
        The measurement dimension (set by the nonlinear filters).
    nees_values : ndarray, shape (K,) or (R, K), or None
        (x_k − x̂_k)ᵀ P_k⁻¹ (x_k − x̂_k) of each step against the true states given to
        ``filter(..., x_true=...)``, computed inside the compiled step (so a bank need not
        keep x and P for its NEES test); None without ``x_true``.
    n_x : int or None
        The state dimension (set by the nonlinear filters, so that :meth:`anees` works on
        a result that keeps no state array).
    P_chol, P_pred_chol : ndarray, shape (K, n, n), or None
        The lower Cholesky factors S of ``P`` and ``P_pred`` (P = S Sᵀ) that a square-root
        filter (``NonlinearKalmanFilter(..., square_root=True)``) propagated, kept with
        ``P`` and ``P_pred``; None for the other filters.
    """

    x: np.ndarray | None = None
    P: np.ndarray | None = None
    x_pred: np.ndarray | None = None
    P_pred: np.ndarray | None = None
    innovation: np.ndarray | None = None
    S: np.ndarray | None = None
    gain: np.ndarray | None = None
    loglik: np.ndarray | None = None
    angle_states: tuple[int, ...] = ()
    method: str = ""
    choices: np.ndarray | None = None
    measured: np.ndarray | None = None
    nis_values: np.ndarray | None = None
    n_y: int | None = None
    nees_values: np.ndarray | None = None
    n_x: int | None = None
    P_chol: np.ndarray | None = None
    P_pred_chol: np.ndarray | None = None

    #: Fields that a filter may share between the runs of a bank (no run axis: (K, ·, ·)).
    shared_fields: ClassVar[tuple[str, ...]] = ("P", "P_pred", "S", "gain")
    #: Fields with a component axis (axis 2) as long as the most components of any run, zero
    #: beyond a run's own (a Gaussian-sum filter's mixtures).
    component_fields: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def concat(cls, results: Sequence[KalmanResult], n_y: int) -> KalmanResult:
        """The results of consecutive shards of a bank's runs, joined along the run axis:
        the result of the whole bank (``n_y`` components count as measured in a shard
        without a missing measurement)."""
        first = results[0]
        fields = {}
        for f in dataclasses.fields(first):
            if not f.init:
                continue
            values = [getattr(r, f.name) for r in results]
            v0 = values[0]
            if f.name == "measured":
                if all(v is None for v in values):
                    fields[f.name] = None
                    continue
                # A shard without a missing measurement has none: every component counted.
                like = next(v for v in values if v is not None)
                values = [np.full(r.loglik.shape, n_y, dtype=like.dtype) if v is None else v
                          for v, r in zip(values, results)]
                fields[f.name] = readonly(np.concatenate(values))
            elif isinstance(v0, np.ndarray):
                if f.name in cls.shared_fields and v0.ndim == 3:  # the same for every run
                    v0.flags.writeable = False  # (a worker's result arrives writeable)
                    fields[f.name] = v0
                else:
                    if f.name in cls.component_fields:  # the shards' longest: zeros beyond
                        M = max(v.shape[2] for v in values)
                        values = [np.pad(v, [(0, 0), (0, 0), (0, M - v.shape[2])] + [(0, 0)] * (v.ndim - 3))
                                  for v in values]
                    joined = np.concatenate(values)  # its own dtype (booleans stay booleans)
                    joined.flags.writeable = False
                    fields[f.name] = joined
            else:
                fields[f.name] = v0  # method, dimensions, angle states: the filter's
        return type(first)(**fields)

    def _need(self, *names: str) -> None:
        missing = [k for k in names if getattr(self, k) is None]
        if missing:
            raise SymmonError(f"this result does not hold {', '.join(missing)}: the filter ran with keep= "
                              "without it; run it again keeping it")

    @property
    def runs(self) -> int | None:
        """Number of runs of a bank; None for a single run."""
        if self.loglik is not None:
            return int(self.loglik.shape[0]) if self.loglik.ndim == 2 else None
        return int(self.x.shape[0]) if self.x.ndim == 3 else None

    @property
    def steps(self) -> int:
        """Number of steps K."""
        return int(self.loglik.shape[-1]) if self.loglik is not None else int(self.x.shape[-2])

    @property
    def n(self) -> int:
        """State dimension."""
        for a in (self.x, self.x_pred, self.P, self.P_pred):
            if a is not None:
                return int(a.shape[-1])
        if self.n_x is not None:
            return self.n_x
        raise SymmonError("this result holds no state array (keep= named none of x, P, x_pred, P_pred)")

    @property
    def log_likelihood(self) -> float | np.ndarray:
        """The marginal log-likelihood of the measurements, Σ_k log N(ν_k; 0, S_k) (the
        prediction-error decomposition): a float for one run, shape (R,) for a bank.

        Raises
        ------
        SymmonError
            If the result carries no per-step values (built by hand without ``loglik``).
        """
        if self.loglik is None:
            raise SymmonError("this result has no per-step log-likelihood (loglik)")
        total = self.loglik.sum(axis=-1)
        return float(total) if np.ndim(total) == 0 else total

    def estimate(self, k: int, run: int | None = None) -> Gaussian:
        """N(x̂_{k|k}, P_{k|k}) at step k (0-based, negative from the end), of run ``run`` for a bank.

        Raises
        ------
        ArgumentError
            For a step (or run) outside the result, naming its range.
        """
        if (run is None) != (self.runs is None):
            raise ShapeError("give run= for a bank of runs, and only then")
        self._need("x", "P")
        k, run = _step_index(k, self.steps, run, self.runs)
        x = self.x if run is None else self.x[run]
        P = self.P if self.P.ndim == 3 else self.P[run]
        return Gaussian(x[k], P[k])

    def _block_index(self, block: Block, name: str) -> np.ndarray:
        n = self.n
        if isinstance(block, slice):
            idx = np.arange(n)[block]
        else:
            idx = np.asarray(block)
            if idx.ndim == 1 and idx.size == 0:
                idx = idx.astype(int)  # np.asarray([]) is float; report it as empty below
            if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
                raise ShapeError(f"{name} must be a slice or a 1-D sequence of integers, got {block!r}")
        if idx.size == 0:
            raise ShapeError(f"{name} selects no state component")
        if np.any(idx < -n) or np.any(idx >= n):
            raise ShapeError(f"{name} has an index outside the state of dimension {n}: {block!r}")
        return idx

    def cross_cov(self, block_a: Block, block_b: Block) -> np.ndarray:
        """Sub-blocks ``P_k[a][:, b]`` of the filtered covariances.

        The composite estimators of :mod:`symmon.estimation.mmse` (Theorem 3, Example 7) need
        the error cross-covariance :math:`P_{xy}` of two state blocks, e.g. two objects
        stacked in one state vector.

        Parameters
        ----------
        block_a, block_b : slice or sequence of int
            State components of the two blocks.

        Returns
        -------
        ndarray, shape (K, len(a), len(b)) (with the leading run axis of ``P``, if any)

        Examples
        --------
        >>> import numpy as np, symmon as sm
        >>> kf = sm.KalmanFilter(np.eye(2), 0.1 * np.eye(2), np.eye(2), np.eye(2))
        >>> res = kf.filter(np.zeros((3, 2)), np.zeros(2), np.eye(2))
        >>> res.cross_cov([0], [1]).shape
        (3, 1, 1)
        """
        self._need("P")
        a = self._block_index(block_a, "block_a")
        b = self._block_index(block_b, "block_b")
        return self.P[..., a[:, None], b[None, :]]

    def nees(self, x_true: ArrayLike | None = None) -> np.ndarray:
        """Normalised estimation error squared ε_k = (x_k − x̂_k)ᵀ P_k⁻¹ (x_k − x̂_k).

        Parameters
        ----------
        x_true : array_like, shape of ``x``, optional
            The true states x_k ((K, n), or (R, K, n) for a bank), against the stored ``x``
            and ``P``.  Without it: :attr:`nees_values`, computed in the compiled step
            against the ``x_true`` given to ``filter``.

        Returns
        -------
        ndarray, shape (K,) or (R, K)

        Raises
        ------
        SymmonError
            Without ``x_true`` when the filter was given none, or with it when x or P
            were not kept.
        """
        if x_true is None:
            if self.nees_values is None:
                raise SymmonError("give x_true, or filter with x_true= to have the NEES computed in the step")
            return self.nees_values
        self._need("x", "P")
        return nees_of(self.x, self.P, x_true, self.angle_states)

    def nis(self) -> np.ndarray:
        """Normalised innovation squared ν_kᵀ S_k⁻¹ ν_k, shape (K,) or (R, K): from the compiled
        step when it was kept (:attr:`nis_values`), else from ``innovation`` and ``S``."""
        if self.nis_values is not None:
            return self.nis_values
        self._need("innovation", "S")
        return quadratic_forms(self.innovation, self.S, "innovation covariance S")

    def anees(self, x_true: ArrayLike | None = None, confidence: float = 0.95) -> ConsistencyTest:
        """Average NEES with its χ² interval: per step over the runs of a bank, or over the
        steps of a single run (Bar-Shalom et al. 2001, §5.4.2); ``x_true`` as :meth:`nees`.

        The interval takes the averaged NEES as independent: the runs of a bank are, but the
        K steps of a single run are not (the estimation errors are correlated in time), so a
        single run's interval is too narrow and the result's ``note`` and printout say so.
        """
        nees = self.nees(x_true)
        return _consistency(nees, self.n, confidence, ONE_RUN_NEES if nees.ndim == 1 else "")

    def anis(self, confidence: float = 0.95) -> ConsistencyTest:
        """Average NIS with its χ² interval, averaged as :meth:`anees`.

        With missing measurements (:attr:`measured`) each step's average is over the runs
        that measured something (a missing row counts neither as a zero nor in N), and the
        degrees of freedom are the components measured; a single run's NIS are independent
        for a consistent filter (white innovations), so its interval holds."""
        return _consistency(self.nis(), self.measured_dims(), confidence)

    def measured_dims(self) -> int | np.ndarray:
        """The measured dimension of each step: :attr:`measured`, or n_y when every component was."""
        if self.measured is not None:
            return self.measured
        for a in (self.innovation, self.S):
            if a is not None:
                return int(a.shape[-1])
        if self.n_y is not None:
            return self.n_y
        raise SymmonError("this result does not hold the measurement dimension: keep innovation or S too")

    def check_credibility(self, window: int = CREDIBILITY_WINDOW,
                          confidence: float = CREDIBILITY_CONFIDENCE) -> Credibility:
        """The steps where the filter leaves its credibility (:class:`Credibility`): where the
        mean NIS over the last ``window`` steps leaves its two-sided χ² band.
        :attr:`credibility` is this with the defaults.

        Raises
        ------
        SymmonError
            When the result holds no innovations (a filter that reports none, or one run with
            ``keep=`` without ``"nis"`` or ``"innovation"`` and ``"S"``).
        ArgumentError
            For a bad ``window`` or ``confidence``.
        """
        if self.nis_values is None and (self.innovation is None or self.S is None):
            raise SymmonError(f"{self.method or 'this filter'}: the result holds no innovations, so its NIS and "
                              "its credibility cannot be checked; keep 'nis' (or 'innovation' and 'S') when "
                              "filtering")
        stat, lo, hi = windowed_nis(np.asarray(self.nis(), dtype=float), self.measured_dims(), window, confidence)
        with np.errstate(invalid="ignore"):
            flags = (stat < lo) | (stat > hi)
        flags.flags.writeable = False
        return Credibility(flags, readonly(stat), (readonly(lo), readonly(hi)), int(window),
                           float(confidence))

    @cached_property
    def credibility(self) -> Credibility:
        """The steps flagged as not credible, computed once from the result's arrays:
        :meth:`check_credibility` with a window of :data:`CREDIBILITY_WINDOW` steps and a
        :data:`CREDIBILITY_CONFIDENCE` band."""
        return self.check_credibility()

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        head = f"KalmanResult({self.method}, {runs}steps={self.steps}, n={self.n}"
        if self.innovation is None or self.S is None:
            return head + ")"
        n_y = self.innovation.shape[-1]
        return head + f", n_y={n_y}, mean NIS {float(self.nis().mean()):.4g} (expected {n_y}))"


#: The nonlinear filters' name for the one result type.
NonlinearKalmanResult = KalmanResult


@dataclass(frozen=True, eq=False)
class SmootherResult:
    """The result of :meth:`NonlinearKalmanFilter.smooth <symmon.NonlinearKalmanFilter.smooth>`:
    the smoothed means and covariances, and the filter's result they came from.

    Attributes
    ----------
    x : ndarray, shape (K, n), or (R, K, n) for a bank
        Smoothed means x̂_{k|K}.
    P : ndarray, shape (K, n, n), or (R, K, n, n)
        Smoothed covariances P_{k|K}.
    filtered : KalmanResult
        The forward pass (its x, P and log-likelihood).
    angle_states : tuple of int
    method : str
        The filter, e.g. ``"UKF(alpha=1.0, beta=2.0, kappa=0.0)"``; the smoother is its RTS
        smoother (extended, second-order, unscented, Gauss–Hermite).
    P_chol : ndarray, shape of ``P``, or None
        The smoothed lower Cholesky factors (P = S Sᵀ) of a square-root smoother; None for
        the others.
    """

    x: np.ndarray
    P: np.ndarray
    filtered: KalmanResult
    angle_states: tuple[int, ...] = ()
    method: str = ""
    P_chol: np.ndarray | None = None

    @property
    def runs(self) -> int | None:
        """Number of runs of a bank; None for a single run."""
        return int(self.x.shape[0]) if self.x.ndim == 3 else None

    @property
    def steps(self) -> int:
        return int(self.x.shape[-2])

    @property
    def n(self) -> int:
        return int(self.x.shape[-1])

    @property
    def log_likelihood(self) -> float | np.ndarray:
        """The filter's marginal log-likelihood (the smoother does not change it)."""
        return self.filtered.log_likelihood

    def estimate(self, k: int, run: int | None = None) -> Gaussian:
        """N(x̂_{k|K}, P_{k|K}) at step k (0-based, negative from the end), of run ``run`` for a bank
        (an index outside the result: ArgumentError)."""
        if (run is None) != (self.runs is None):
            raise ShapeError("give run= for a bank of runs, and only then")
        k, run = _step_index(k, self.steps, run, self.runs)
        x = self.x if run is None else self.x[run]
        P = self.P if run is None else self.P[run]
        return Gaussian(x[k], P[k])

    def nees(self, x_true: ArrayLike) -> np.ndarray:
        """NEES of the smoothed estimates, (x_k − x̂_{k|K})ᵀ P_{k|K}⁻¹ (x_k − x̂_{k|K}),
        shape (K,) or (R, K)."""
        return nees_of(self.x, self.P, x_true, self.angle_states)

    def anees(self, x_true: ArrayLike, confidence: float = 0.95) -> ConsistencyTest:
        """Average smoothed NEES with its χ² interval, averaged as :meth:`KalmanResult.anees`
        (a single run's interval is too narrow: its errors are correlated in time)."""
        nees = self.nees(x_true)
        return _consistency(nees, self.n, confidence, ONE_RUN_NEES if nees.ndim == 1 else "")

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return f"SmootherResult({self.method}, {runs}steps={self.steps}, n={self.n})"
