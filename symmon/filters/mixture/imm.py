"""Interacting multiple models (IMM) over symmon's Kalman filters.

A target that switches between motion models (constant velocity, a coordinated turn) is a
jump-Markov system: the mode m_k ∈ {1, …, M} follows a Markov chain with transition
probabilities p_ij = P(m_k = j | m_{k−1} = i), and in mode j the state follows that mode's
f_j, Q_j and is measured by h_j, R_j.  The IMM estimator (Blom & Bar-Shalom 1988) keeps one
Gaussian per mode and, at each step k (Bar-Shalom, Li & Kirubarajan 2001, §11.6.6):

1. **mixing probabilities**: c̄_j = Σ_i p_ij μ_i (the predicted mode probabilities) and
   μ_{i|j} = p_ij μ_i / c̄_j;
2. **mixing**: x⁰_j = Σ_i μ_{i|j} x_i, P⁰_j = Σ_i μ_{i|j} (P_i + (x_i − x⁰_j)(x_i − x⁰_j)ᵀ);
3. **mode-matched filtering**: mode j's filter predicts and updates from N(x⁰_j, P⁰_j), giving
   x_j, P_j and the likelihood Λ_j = N(ν_j; 0, S_j) of its innovation;
4. **mode probabilities**: μ_j = Λ_j c̄_j / c with c = Σ_j Λ_j c̄_j, the step's likelihood
   (log c is the step's term of the log-likelihood; computed in log space, so a likelihood
   below 1e-308 does not underflow to a zero probability);
5. **combination**: x = Σ_j μ_j x_j, P = Σ_j μ_j (P_j + (x_j − x)(x_j − x)ᵀ).

Angle states (the angle states of the modes' filters, which must agree) are mixed and
combined with the weighted circular mean atan2(Σ w sin θ, Σ w cos θ) (Mardia & Jupp 2000,
§2.2.1), and their deviations θ_i − θ̄ are wrapped.  The predicted measurement of the IMM is
the mixture Σ_j c̄_j N(ŷ_j, S_j); its moment-matched innovation ν = Σ_j c̄_j ν_j and
covariance S = Σ_j c̄_j (S_j + (ν_j − ν)(ν_j − ν)ᵀ) give the combined NIS.  A missing
measurement (NaN) skips every mode's update on the missing components (as in
:meth:`symmon.NonlinearKalmanFilter.filter`); a row of NaN leaves μ = c̄.

Each mode-matched step is the mode's own compiled predict + update step
(:mod:`symmon.filters.gaussian.step`).  When every mode runs one compiled rule, the recursion of a
whole bank (mixing, the modes' steps, the mode probabilities) is one generated C loop around
those steps (``_FusedLoop``), and the combination is vectorised over the runs and steps
afterwards; otherwise (an adaptive mode, a square-root mode, no compiler) each mode's step
is called per time step on all the runs, NumPy between the calls.  A square-root mode
(``square_root=True``, :mod:`symmon.filters.gaussian._sqrtstep`) takes the lower Cholesky factor of
its mixed P⁰_j (refused, naming the mode, run and step, when P⁰_j is not positive definite)
and its step's factor S_j gives P_j = S_j S_jᵀ for the mixing and the combination.

References
----------
H. A. P. Blom, Y. Bar-Shalom, "The interacting multiple model algorithm for systems with
Markovian switching coefficients", IEEE Trans. Autom. Control 33(8), 1988.
doi:10.1109/9.1299
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley, 2001, §11.6.6 (the IMM), §11.7 (the coordinated turn).
K. V. Mardia, P. E. Jupp, *Directional Statistics*, Wiley, 2000, §2.2.1 (the circular mean).
"""

from __future__ import annotations

import ctypes
import hashlib
import threading
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
from numpy.typing import ArrayLike

from ...core.angles import wrap_angle
from ...core.arrays import readonly
from ...core.gaussian import float_array
from ...compile.ccache import NativeLibrary
from ...compile.ckernels import STOPPED
from ...compile.compiled import WorkArrays, generated_c, run_stoppable
from ...compile.csource import c_defines, c_file
from ...errors import (ArgumentError, ArgumentTypeError, CovarianceError, ModelError, NonFiniteError, ShapeError,
                      SymmonError)
from ..base import Filter
from ..inputs import FilterCall, param_values
from ..results import KalmanResult, nees_of, quadratic_forms
from ..gaussian.step import compiled_step, chunk_runs, long_bank
from ..gaussian.strategy import RuleStrategy

__all__ = ["IMM", "IMMResult"]

#: How far the rows of the transition matrix and the initial probabilities may sum from 1.
PROBABILITY_ATOL = 1e-9


@dataclass(frozen=True, eq=False)
class IMMResult(KalmanResult):
    """The result of :meth:`IMM.filter`: the combined estimate, as a :class:`KalmanResult`
    (``x``, ``P``, NEES, NIS and their χ² tests, ``log_likelihood``), with the modes.

    The combined ``x`` and ``P`` are the moment-matched mixture Σ_j μ_j N(x_j, P_j);
    ``x_pred`` and ``P_pred`` that of the mode-matched predictions weighted by c̄_j;
    ``innovation`` and ``S`` the moment-matched predicted measurement Σ_j c̄_j N(ŷ_j, S_j)
    (so :meth:`nis` is the combined NIS); ``loglik`` the IMM's log c_k.

    Attributes
    ----------
    mode_probabilities : ndarray, shape (K, M) or (R, K, M)
        μ_j after each step's update.
    predicted_probabilities : ndarray, shape (K, M) or (R, K, M)
        c̄_j, the mode probabilities before each step's update.
    mode_x : ndarray, shape (K, M, n) or (R, K, M, n)
        Each mode-matched filter's x_j.
    mode_P : ndarray, shape (K, M, n, n) or (R, K, M, n, n)
        Each mode-matched filter's P_j.
    mode_loglik : ndarray, shape (K, M) or (R, K, M)
        log Λ_j, each mode's log-likelihood of the step's measurement.
    modes : tuple of str
        The modes' filters, e.g. ``("EKF(cv)", "UKF(...)(ct)")``.
    """

    mode_probabilities: np.ndarray | None = None
    predicted_probabilities: np.ndarray | None = None
    mode_x: np.ndarray | None = None
    mode_P: np.ndarray | None = None
    mode_loglik: np.ndarray | None = None
    modes: tuple[str, ...] = ()

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return f"IMMResult({', '.join(self.modes)}; {runs}steps={self.steps}, n={self.n})"


def _probabilities(p: ArrayLike, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``p`` as finite, non-negative probabilities of ``shape`` whose last axis sums to 1
    (within :data:`PROBABILITY_ATOL`), normalised exactly."""
    arr = float_array(p, name, ArgumentError)
    if arr.shape != shape:
        raise ShapeError(f"{name} must have shape {shape} (one entry per mode), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ArgumentError(f"{name} must hold finite probabilities ≥ 0, got {arr.tolist()}")
    sums = arr.sum(axis=-1)
    bad = np.flatnonzero(np.abs(np.atleast_1d(sums) - 1.0) > PROBABILITY_ATOL)
    if bad.size:
        where = f"row {bad[0]} of {name}" if arr.ndim == 2 else name
        raise ArgumentError(f"{where} sums to {float(np.atleast_1d(sums)[bad[0]]):.12g}, not 1: give probabilities "
                            + ("P(mode j at k | mode i at k−1) in row i" if arr.ndim == 2 else "of the modes"))
    return readonly(arr / sums[..., None] if arr.ndim == 2 else arr / sums)


def _mix(w: np.ndarray, xs: np.ndarray, Ps: np.ndarray, angles: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The moment-matched mixtures Σ_i w[:, i, j] N(xs[:, i], Ps[:, i]) for each j: means
    (R, J, n) and covariances (R, J, n, n), for ``w`` (R, I, J) with columns summing to 1,
    xs (R, I, n), Ps (R, I, n, n).  Angle components: the weighted circular mean and
    wrapped deviations."""
    R, I, n = xs.shape
    wt = np.swapaxes(w, 1, 2)  # (R, J, I): the sums over i as batched products
    mean = wt @ xs
    if angles:
        th = xs[..., angles]
        mean[..., angles] = np.arctan2(wt @ np.sin(th), wt @ np.cos(th))
    d = xs[:, None, :, :] - mean[:, :, None, :]  # (R, J, I, n)
    if angles:
        d[..., angles] = wrap_angle(d[..., angles])
    cov = (wt @ Ps.reshape(R, I, n * n)).reshape(R, -1, n, n) + np.swapaxes(d * wt[..., None], -1, -2) @ d
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


@dataclass(frozen=True, eq=False)
class IMM(Filter):
    """Interacting multiple models (Blom & Bar-Shalom 1988) over symmon's Kalman filters.

    Parameters
    ----------
    filters : sequence of NonlinearKalmanFilter or KalmanFilter
        One filter per mode, on the same state vector (n states) and the same measurement
        (n_y components), each with its own f, Q, h, R, transform (EKF, iterated EKF, EKF2,
        UKF, CKF, Gauss–Hermite, adaptive; square-root or not) and parameters.  A linear :class:`KalmanFilter`
        runs as the EKF of its linear model (equal to rounding).  The modes must agree on
        which states are angles and which measurement components are angles.
    transition : array_like, shape (M, M)
        p_ij = P(mode j at step k | mode i at step k − 1): each row sums to 1 (FilterPy's
        ``IMMEstimator`` ``M``).
    probabilities : array_like, shape (M,)
        The mode probabilities of x0, before the first step; they sum to 1.

    Raises
    ------
    ArgumentTypeError
        A mode is not a symmon Kalman filter.
    ShapeError
        The modes differ in state or measurement dimension, in their angle states or
        angle outputs, or ``transition``/``probabilities`` have the wrong shape.
    ArgumentError
        Probabilities that are negative, not finite, or do not sum to 1.

    Examples
    --------
    >>> import numpy as np, symmon as sm
    >>> F = np.array([[1.0, 1.0], [0.0, 1.0]]); H = np.array([[1.0, 0.0]])
    >>> quiet = sm.KalmanFilter(F, 1e-4 * np.eye(2), H, [[1.0]])
    >>> agile = sm.KalmanFilter(F, 1.0 * np.eye(2), H, [[1.0]])
    >>> imm = sm.IMM([quiet, agile], [[0.95, 0.05], [0.05, 0.95]], [0.5, 0.5])
    >>> ys = np.r_[np.arange(10.0), 10 + 3 * np.arange(10.0)][:, None]   # the speed jumps at step 10
    >>> res = imm.filter(ys, sm.Gaussian([0.0, 1.0], np.eye(2)))
    >>> res.mode_probabilities[[10, 13], 1].round(2).tolist()   # P(agile) before and after
    [0.09, 0.9]
    """

    filters: tuple
    transition: np.ndarray
    probabilities: np.ndarray

    def __post_init__(self) -> None:
        if isinstance(self.filters, Filter) or not isinstance(self.filters, Iterable):
            raise ArgumentTypeError("filters must be a sequence of filters, one per mode")
        filters = tuple(self.filters)
        if not filters:
            raise ArgumentError("filters must hold at least one filter (one per mode)")
        modes = []
        for j, kf in enumerate(filters):
            if not getattr(type(kf), "gaussian_mode", False):
                raise ArgumentTypeError(f"mode {j}: filters must be symmon KalmanFilter or NonlinearKalmanFilter "
                                        f"objects (a Gaussian filter that IMM can mix), got {type(kf).__name__}")
            modes.append(kf.as_gaussian_mode())
        first = modes[0]
        n, n_y = first.f_model.n_u, first.h_model.n_y
        for j, kf in enumerate(modes[1:], start=1):
            if kf.f_model.n_u != n or kf.h_model.n_y != n_y:
                raise ShapeError(f"mode {j} has {kf.f_model.n_u} states and {kf.h_model.n_y} measurement components, "
                                 f"mode 0 has {n} and {n_y}: the modes of an IMM share the state vector and the "
                                 "measurement")
            if kf.angle_states != first.angle_states:
                raise ShapeError(f"mode {j} has angle states {sorted(kf.angle_states)}, mode 0 "
                                 f"{sorted(first.angle_states)}: the mixing needs one answer; declare the same angles "
                                 "in every mode's models")
            if kf.h_model.angle_outputs != first.h_model.angle_outputs:
                raise ShapeError(f"mode {j} measures angles at outputs {sorted(kf.h_model.angle_outputs)}, mode 0 at "
                                 f"{sorted(first.h_model.angle_outputs)}: the modes measure the same quantities")
        M = len(modes)
        object.__setattr__(self, "filters", tuple(modes))
        object.__setattr__(self, "transition", _probabilities(self.transition, "transition", (M, M)))
        object.__setattr__(self, "probabilities", _probabilities(self.probabilities, "probabilities", (M,)))

    @property
    def n(self) -> int:
        """The state dimension."""
        return self.filters[0].f_model.n_u

    @property
    def n_y(self) -> int:
        """The measurement dimension."""
        return self.filters[0].h_model.n_y

    @property
    def angle_states(self) -> frozenset[int]:
        """The state components that are angles (the same in every mode)."""
        return self.filters[0].angle_states

    @property
    def modes(self) -> tuple[str, ...]:
        """Each mode's filter and dynamics, e.g. ``"EKF(ct)"``."""
        return tuple(f"{kf.method}({kf.f_model.name})" for kf in self.filters)

    def __repr__(self) -> str:
        return f"IMM({', '.join(self.modes)}; n={self.n}, n_y={self.n_y})"

    def _mode_params(self, params, runs: int | None, K: int) -> list:
        """Each mode's parameter values (R, K, n_p), or None: ``params`` is one dict by name
        (each mode takes the names its models declare) or one dict (or None) per mode."""
        M = len(self.filters)
        if params is None or isinstance(params, dict):
            given = {} if params is None else {str(k): v for k, v in params.items()}
            declared = {str(s) for kf in self.filters for s in kf.params}
            unknown = sorted(set(given) - declared)
            if unknown:
                raise ModelError(f"params {unknown} are declared by no mode's models (they declare "
                                 f"{sorted(declared)})")
            per_mode = [{k: v for k, v in given.items() if k in {str(s) for s in kf.params}} for kf in self.filters]
        elif isinstance(params, (list, tuple)) and len(params) == M:
            per_mode = list(params)
        else:
            raise ModelError(f"params must be a dict by name or a sequence of {M} dicts (one per mode), got "
                             f"{type(params).__name__}")
        out = []
        for j, (kf, p) in enumerate(zip(self.filters, per_mode)):
            try:
                out.append(param_values(kf.params, p, runs, K))
            except (ModelError, ShapeError) as err:
                raise type(err)(f"mode {j} ({self.modes[j]}): {err}") from None
        return out

    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.n, self.n_y

    def step_cost(self) -> int:
        """The modes' costs, summed."""
        return sum(kf.step_cost() for kf in self.filters)

    def _check_params(self, params: Any, runs: int | None, steps: int) -> list:
        return self._mode_params(params, runs, steps)

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        n, n_y, M = self.n, self.n_y, len(self.filters)
        # Combined x, P, x_pred, P_pred, ν, S, NIS, log c; per mode μ, c̄, log Λ, x, P, x⁻, P⁻, ν, S.
        return 2 * (n + n * n) + n_y + n_y * n_y + 2 + M * (3 + 2 * (n + n * n) + n_y + n_y * n_y), 0

    def _filter(self, call: FilterCall) -> IMMResult:
        """Run the IMM over the checked ``call`` (predict, then update, at each step): the
        state before the first step is the same in every mode; ``params`` is one dict by
        name (each mode taking the names its models declare) or one dict (or None) per mode.

        Raises
        ------
        NonFiniteError
            A mode-matched filter produced NaN or inf, naming the mode, the run and the step.
        CovarianceError
            The mixed covariance P⁰_j of a square-root mode is not positive definite (no
            Cholesky factor), naming the mode, the run and the step.
        SingularMatrixError
            With ``x_true``: a combined P is singular.
        """
        n, n_y = self.n, self.n_y
        runs = call.runs
        m0, C0, truth, pvs = call.x0, call.P0, call.truth, call.pv
        Yb = call.Y
        angles = sorted(self.angle_states)
        loop = self._fused_loop()
        # a running build of the loop is waited for (as the PF and the GSF do): the fallback agrees
        # with it to rounding, not to the bit, so a call's numbers must not depend on the build's timing
        if loop is not None:
            loop.wait()
        run = None if loop is None else loop.native()
        if run is not None:
            modes, failed = loop(run, m0, C0, Yb, [kf.Q for kf in self.filters], [kf.R for kf in self.filters], pvs,
                                 self.transition, self.probabilities)
        else:
            modes, failed = self._python_loop(m0, C0, Yb, pvs, runs is not None)
        if (failed[:, 0] >= 0).any():
            k = failed[failed[:, 0] >= 0, 0].min()  # the first step that failed, in its first run
            r = int(np.argmax(failed[:, 0] == k))
            j = int(failed[r, 1])
            where = f"step {k}" if runs is None else f"run {r}, step {k}"
            raise NonFiniteError(
                f"IMM: mode {j} ({self.modes[j]}) produced NaN or inf at {where} (its innovation covariance "
                "S is singular or not positive definite, a covariance lost positive definiteness, or a "
                "derivative is undefined there)")
        out = _combine(modes, angles)
        # The combined NIS, on the measured block (a missing component has ν = 0, a unit S entry).
        out["nis"] = quadratic_forms(out["innovation"], out["S"], "combined innovation covariance S")
        measured = readonly((~np.isnan(Yb)).sum(axis=-1)) if np.isnan(Yb).any() else None
        nees = None
        if truth is not None:
            nees = nees_of(out["x"], out["P"], truth, angles)
        if runs is None:
            out = {k: v[0] for k, v in out.items()}
            measured = None if measured is None else measured[0]
            nees = None if nees is None else nees[0]
        out = {k: readonly(v) for k, v in out.items()}
        for k in ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis"):  # what keep= leaves out
            if call.keep is not None and k not in call.keep:
                out[k] = None
        return IMMResult(x=out["x"], P=out["P"], x_pred=out["x_pred"], P_pred=out["P_pred"],
                         innovation=out["innovation"], S=out["S"], loglik=out["loglik"],
                         angle_states=tuple(angles), method="IMM(" + ", ".join(self.modes) + ")",
                         measured=measured, nis_values=out["nis"], n_y=n_y,
                         nees_values=None if nees is None else readonly(nees), n_x=n,
                         mode_probabilities=out["mu"], predicted_probabilities=out["cbar"], mode_x=out["mode_x"],
                         mode_P=out["mode_P"], mode_loglik=out["mode_loglik"], modes=self.modes)

    def _fused_loop(self) -> "_FusedLoop | None":
        """The compiled loop over the steps and runs of a bank with every mode's step inside
        it, when every mode runs one compiled standard step (None: an adaptive or a
        square-root mode, or more than :data:`FUSED_MAX_MODES` modes, which run in
        :meth:`_python_loop`)."""
        if (len(self.filters) > FUSED_MAX_MODES
                or not all(isinstance(kf.strategy, RuleStrategy) and not kf.square_root for kf in self.filters)):
            return None
        steps = tuple(compiled_step(kf.f_model, kf.h_model, kf.strategy.transform, kf.angle_states, kf.iterations)
                      for kf in self.filters)
        key = (tuple(st.f.name() for st in steps), tuple(sorted(self.angle_states)))
        with _loops_lock:
            loop = _loops.get(key)
            if loop is None:
                loop = _loops[key] = _FusedLoop(steps, sorted(self.angle_states))
        return loop

    def _python_loop(self, m0: np.ndarray, C0: np.ndarray, Yb: np.ndarray, pvs: list, bank: bool = True):
        """The IMM recursion with each mode's compiled step called per time step on all the runs
        (the fallback of the fused loop: an adaptive or a square-root mode, or no compiled C
        yet).  Returns the modes' arrays (R, K, M, ...) and, per run, the first failed step and
        its mode (or −1); ``bank`` says whether errors name the run."""
        R, K, _ = Yb.shape
        n, n_y, M = self.n, self.n_y, len(self.filters)
        angles = sorted(self.angle_states)
        T = self.transition
        xm = np.array(np.broadcast_to(m0, (R, M, n)) if m0.ndim == 1 else np.repeat(m0[:, None], M, axis=1))
        Pm = np.array(np.broadcast_to(C0, (R, M, n, n)) if C0.ndim == 2 else np.repeat(C0[:, None], M, axis=1))
        mu = np.array(np.broadcast_to(self.probabilities, (R, M)))
        modes = _mode_arrays(R, K, M, n, n_y)
        failed = np.full((R, 2), -1, dtype=np.int64)
        for k in range(K):
            # 1–2: the mixing probabilities μ_{i|j} = p_ij μ_i / c̄_j and the mixed Gaussians.
            joint = mu[:, :, None] * T  # (R, i, j)
            cbar = joint.sum(axis=1)
            # A mode no other mode can reach (c̄_j = 0) keeps its own posterior; its weight is 0.
            w = np.divide(joint, cbar[:, None, :], out=np.eye(M)[None].repeat(R, axis=0), where=cbar[:, None, :] > 0)
            x_mix, P_mix = _mix(w, xm, Pm, angles)
            # 3: each mode's compiled predict + update step, on all the runs at once.
            Yk = Yb[:, k:k + 1]
            for j, kf in enumerate(self.filters):
                pv = None if pvs[j] is None else np.ascontiguousarray(pvs[j][:, k:k + 1])
                if kf.square_root:
                    step = compiled_step(kf.f_model, kf.h_model, kf.strategy.transform, kf.angle_states,
                                          kf.iterations, True)
                    S0 = self._mixed_factor(P_mix[:, j], j, k, bank)
                    res = step(x_mix[:, j], S0, Yk, kf.Q, kf.R, params=pv, check_finite=True, factored=True)
                else:
                    extra = {} if pv is None else {"params": pv}
                    res, _ = kf.strategy.run(kf, Yk, x_mix[:, j], P_mix[:, j], None, **extra)
                for name in _MODE_OUTPUTS:
                    modes[name][:, k, j] = res[name][:, 0]
                bad = ~(np.isfinite(modes["loglik"][:, k, j]) & np.isfinite(modes["x"][:, k, j]).all(axis=-1)
                        & np.isfinite(modes["P"][:, k, j]).all(axis=(-1, -2)))
                if bad.any():
                    failed[bad & (failed[:, 0] < 0)] = (k, j)
                    return modes, failed
            mu = _mode_probabilities(cbar, modes["loglik"][:, k])[0]
            modes["mu"][:, k], modes["cbar"][:, k] = mu, cbar
            xm, Pm = modes["x"][:, k], modes["P"][:, k]
        return modes, failed

    def _mixed_factor(self, P: np.ndarray, j: int, k: int, bank: bool) -> np.ndarray:
        """The lower Cholesky factors (R, n, n) of mode j's mixed covariances P⁰_j (R, n, n) at
        step k, for its square-root step; a P⁰_j that is not positive definite is refused
        (its square-root filter would start from a factor of a different matrix)."""
        try:
            return np.linalg.cholesky(P)
        except np.linalg.LinAlgError:
            pass
        r = next(r for r in range(P.shape[0]) if not _positive_definite(P[r]))  # the first run that failed
        where = f"run {r}, step {k}" if bank else f"step {k}"
        raise CovarianceError(
            f"IMM: the mixed covariance P⁰ of mode {j} ({self.modes[j]}) is not positive definite at {where}, so "
            "its square-root step has no Cholesky factor to start from: give x0 a positive definite covariance, "
            "or the mode square_root=False")


def _positive_definite(P: np.ndarray) -> bool:
    """Whether the symmetric P (n, n) has a Cholesky factor."""
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    return True


#: The outputs of a mode's step that the IMM keeps, (R, K, M, ...) each.
_MODE_OUTPUTS = ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik")


def _mode_arrays(R: int, K: int, M: int, n: int, n_y: int) -> dict[str, np.ndarray]:
    """Empty arrays for the modes' step outputs and probabilities."""
    shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n), "innovation": (n_y,), "S": (n_y, n_y),
              "loglik": ()}
    out = {k: np.empty((R, K, M) + s) for k, s in shapes.items()}
    out["mu"], out["cbar"] = np.empty((R, K, M)), np.empty((R, K, M))
    return out


def _mode_probabilities(cbar: np.ndarray, loglik: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """μ_j ∝ c̄_j Λ_j and log c = log Σ_j c̄_j Λ_j, for c̄ and log Λ (..., M).

    The Λ_j are scaled by the largest (no underflow); c̄ sums to 1 up to rounding, and
    dividing by its sum makes a step without a measurement (every Λ_j = 1) give μ = c̄ and
    log c = 0 exactly."""
    top = loglik.max(axis=-1)
    e = cbar * np.exp(loglik - top[..., None])
    total = e.sum(axis=-1)
    return e / total[..., None], top + np.log(total / cbar.sum(axis=-1))


def _combine(modes: dict[str, np.ndarray], angles: list[int]) -> dict[str, np.ndarray]:
    """The combined estimate of every step of every run from the modes' arrays (R, K, M, ...):
    x, P with μ; x_pred, P_pred and the predicted measurement (ν, S) with c̄; log c."""
    R, K, M, n = modes["x"].shape
    n_y = modes["innovation"].shape[-1]
    flat = {k: v.reshape((R * K,) + v.shape[2:]) for k, v in modes.items()}
    mu, cbar = flat["mu"][:, :, None], flat["cbar"][:, :, None]
    x, P = _mix(mu, flat["x"], flat["P"], angles)
    xp, Pp = _mix(cbar, flat["x_pred"], flat["P_pred"], angles)
    nu, S = _mix(cbar, flat["innovation"], flat["S"], [])
    log_c = _mode_probabilities(flat["cbar"], flat["loglik"])[1]
    out = {"x": x.reshape(R, K, n), "P": P.reshape(R, K, n, n), "x_pred": xp.reshape(R, K, n),
           "P_pred": Pp.reshape(R, K, n, n), "innovation": nu.reshape(R, K, n_y), "S": S.reshape(R, K, n_y, n_y),
           "loglik": log_c.reshape(R, K)}
    out.update(mu=modes["mu"], cbar=modes["cbar"], mode_x=modes["x"], mode_P=modes["P"], mode_loglik=modes["loglik"])
    return out


# The fused loop (imm.c): for each run, K steps of the IMM recursion, each calling the modes' steps.
_DRIVER_C = c_file(__package__, "imm.c")
#: The modes of the fused loop at most (imm.c's switch over the modes' steps); an IMM of more
#: modes runs in :meth:`IMM._python_loop`.
FUSED_MAX_MODES = 16


class _FusedLoop:
    """The IMM recursion over the steps and runs of a bank in one compiled C loop, with the
    modes' compiled steps (:mod:`symmon.filters.gaussian.step`) inside it: the mixing (circular means
    for angle states), each mode's predict + update and the mode probabilities run in C; the
    combination of the modes' outputs is done afterwards, vectorised (:func:`_combine`).
    Built by the compile policy of every generated function (docs/compile.md); without
    compiled code (no compiler, the never policy, a failed build, or while a background build
    runs) :meth:`native` is None; :meth:`wait` waits for that build."""

    def __init__(self, steps: tuple, angles: list[int]) -> None:
        fns = list({st.f.name(): st.f for st in steps}.values())  # a step two modes share: once
        names = [st.f.name() for st in steps]
        self.n, self.n_y, self.M = steps[0].n, steps[0].n_y, len(steps)
        self.p_sizes = np.array([max(st.n_p, 1) for st in steps], dtype=np.int64)
        key = repr((names, angles))
        name = "sm_imm_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        defines = c_defines(
            IMM_BAD=f"{name}_bad", IMM_WRAP=f"{name}_wrap", IMM_STEP=f"{name}_step", IMM_RUN=f"{name}_run",
            **{f"IMM_STEP_{j}": nm for j, nm in enumerate(names)}, IMM_M=self.M, IMM_N=self.n, IMM_NY=self.n_y,
            IMM_N_ANG=len(angles), IMM_ANGLES=tuple(angles or [0]),
            IMM_SZ_ARG=max(max(f.sz_arg() for f in fns), 7), IMM_SZ_RES=max(max(f.sz_res() for f in fns), 8),
            IMM_STOPPED=STOPPED)
        code = generated_c(*fns) + defines + _DRIVER_C
        self._work = WorkArrays(*fns)
        self._name = name
        self._lib = NativeLibrary(code, name, self._load, stacklevel=5)

    def _load(self, so):
        run = getattr(ctypes.CDLL(str(so)), f"{self._name}_run")
        run.argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong]
                        + [ctypes.c_void_p] * 9 + [ctypes.c_longlong] * 2 + [ctypes.c_void_p] * 4)
        run.restype = ctypes.c_int
        return run

    def wait(self) -> None:
        """Wait for a running background build of the loop (return at once without one)."""
        self._lib.wait()

    def native(self):
        """The compiled loop, or None while it is not (evaluate with the modes' steps)."""
        return self._lib.get()

    def __call__(self, run, m0: np.ndarray, C0: np.ndarray, Yb: np.ndarray, Qs: list, Rs: list, pvs: list,
                 T: np.ndarray, mu0: np.ndarray):
        """The modes' arrays (R, K, M, ...) and (R, 2) the first failed step of each run and
        its mode (−1: none) of the bank Yb (R, K, n_y), NaN for a missing measurement.

        Raises
        ------
        KeyboardInterrupt
            On a Ctrl-C while the loops run: they stop before their next step
            (:func:`~symmon.compile.compiled.run_stoppable`), and no result is returned."""
        R, K, _ = Yb.shape
        n, n_y, M = self.n, self.n_y, self.M
        measured = ~np.isnan(Yb)
        mask = np.ascontiguousarray(measured, dtype=float)
        Y = np.ascontiguousarray(np.where(measured, Yb, 0.0))
        modes = _mode_arrays(R, K, M, n, n_y)
        blocks = [modes[k] for k in _MODE_OUTPUTS] + [modes["mu"], modes["cbar"]]
        x0, P0 = np.ascontiguousarray(m0, dtype=float), np.ascontiguousarray(C0, dtype=float)
        x_step, P_step = (n if x0.ndim == 2 else 0), (n * n if P0.ndim == 3 else 0)
        Qs = [np.ascontiguousarray(Q, dtype=float) for Q in Qs]
        Rs = [np.ascontiguousarray(Rm, dtype=float) for Rm in Rs]
        ps = [np.zeros((R, K, 1)) if p is None else np.ascontiguousarray(p, dtype=float) for p in pvs]
        T, mu0 = np.ascontiguousarray(T, dtype=float), np.ascontiguousarray(mu0, dtype=float)
        failed = np.empty((R, 2), dtype=np.int64)
        chunks = chunk_runs(R, K * M, n)

        def pointers(arrays):
            return (ctypes.c_void_p * len(arrays))(*[a.ctypes.data for a in arrays])

        Qp, Rp = pointers(Qs), pointers(Rs)

        def part(c: int, stop: int) -> int:
            a, b = chunks[c]
            outs = (ctypes.c_void_p * len(blocks))(*[blk[a].ctypes.data for blk in blocks])
            iw, w = self._work.addresses()
            return run(x0.ctypes.data + 8 * a * x_step, x_step, P0.ctypes.data + 8 * a * P_step, P_step,
                       Y[a].ctypes.data, mask[a].ctypes.data, Qp, Rp, pointers([p[a] for p in ps]),
                       self.p_sizes.ctypes.data, T.ctypes.data, mu0.ctypes.data, outs, b - a, K, iw, w,
                       failed[a].ctypes.data, stop)

        # a Ctrl-C stops the loops before their next step (run_stoppable: KeyboardInterrupt)
        if any(run_stoppable(part, list(range(len(chunks))), long_bank(R, K * M, n))):
            raise SymmonError(f"the compiled IMM loop {self._name} returned an error")
        return modes, failed


_loops: dict[tuple, _FusedLoop] = {}
_loops_lock = threading.Lock()
