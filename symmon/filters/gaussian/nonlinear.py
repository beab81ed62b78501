"""Nonlinear Kalman filters compiled to C: EKF, second-order EKF, UKF, CKF and Gauss–Hermite.

The model is x_{k+1} = f(x_k, w_k), y_k = h(x_k, e_k), w_k ~ N(0, Q), e_k ~ N(0, R); without
noise symbols the noises are additive, x_{k+1} = f(x_k) + w_k and y_k = h(x_k) + e_k.  The
time update is a nonlinear transformation (NLT) of the dynamics and the measurement update
is the indirect step of Gustafsson & Hendeby (Lemma 7.1), so the transform picks the filter:

============================  =====================================================
transform                     filter
============================  =====================================================
``TT1()``                     extended Kalman filter (EKF)
``TT2()``                     second-order EKF
``UT(alpha, beta, kappa)``    unscented Kalman filter (UKF); ``UT.cubature()``: CKF
``GaussHermite(order)``       Gauss–Hermite Kalman filter
============================  =====================================================

With noise symbols (general noise) the rule runs on the augmented vector [x; w] with
covariance blkdiag(P, Q) (resp. [x; e], blkdiag(P⁻, R)); with additive noise Q and R are
added to the covariances.

Angles: the outputs of h that the model declares as angles get a circular mean
atan2(Σ wᵢ sin, Σ wᵢ cos) (point rules) or a wrapped mean (TT1, TT2), wrapped residuals and a
wrapped innovation; the *angle states* (the outputs of f declared as angles, or the inputs of f
or h declared as angles) get the same treatment in the time update, and x⁺ is wrapped.

This module holds the filter, :class:`NonlinearKalmanFilter`; the parts are in their own
modules, and their public names are re-exported here:

- :mod:`symmon.filters.gaussian.step`: one predict + update step as a CasADi function, compiled to C
  once (cached on disk), with a C loop that runs all the steps of all the runs of a filter
  bank in one call;
- :mod:`symmon.filters.results`: :class:`KalmanResult` (the one result type of the linear
  and nonlinear filters, also named NonlinearKalmanResult), NEES and NIS, and
  :class:`ConsistencyTest` (their χ² acceptance intervals);
- :mod:`symmon.filters.gaussian.adaptive`: :class:`Adaptive`, the filter that picks the cheapest adequate
  transform at each step of each run.

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
S. J. Julier, J. K. Uhlmann, "Unscented filtering and nonlinear estimation", Proc. IEEE 92(3),
2004. doi:10.1109/JPROC.2003.823141
I. Arasaratnam, S. Haykin, "Cubature Kalman filters", IEEE Trans. Autom. Control 54(6), 2009.
doi:10.1109/TAC.2009.2019800
K. Ito, K. Xiong, "Gaussian filters for nonlinear filtering problems", IEEE Trans. Autom.
Control 45(5), 2000 (the Gauss–Hermite filter). doi:10.1109/9.855552
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley, 2001, §5.4 (NEES, NIS and their χ² tests).
D. F. Crouse, "Cubature/unscented/sigma point Kalman filtering with angular measurement
models", FUSION 2015 (wrapped residuals).
B. M. Bell, F. W. Cathey, "The iterated Kalman filter update as a Gauss–Newton method", IEEE
Trans. Autom. Control 38(2), 1993. doi:10.1109/9.250476
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Iterable
from functools import cached_property

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike

from ...errors import AngleWarning, ArgumentTypeError, SymmonError, plain_repr
from ...core.arrays import all_finite, readonly
from ...core.checks import noise_cov
from .diagnose import locate_nonfinite
from ..base import Filter
from .export import export_filter_c
from .fit import FitResult, fit_parameters
from ..inputs import FilterCall, FilterInputs, check_keep, check_state_models, filter_inputs, kept_numbers
from ..results import ConsistencyTest, KalmanResult, NonlinearKalmanResult, SmootherResult, step_nees, nees_of
from .smoother import compiled_smoother
from .step import filter_params, first_nonfinite
from .strategy import FilterStrategy, RuleStrategy
from ...core.gaussian import Gaussian, as_covariance
from ...core.model import Model
from ...transforms.unscented import UT
from ...transforms.base import Transform
from ...transforms.taylor import TT1
from ..names import filter_rule

__all__ = ["NonlinearKalmanFilter", "NonlinearKalmanResult", "ConsistencyTest", "MAX_ITERATIONS"]

#: The most Gauss–Newton iterations of the iterated EKF's update (each one is unrolled in the step).
MAX_ITERATIONS = 20
#: How to make a bank's results fit (:data:`~symmon.filters.inputs.MAX_BANK_NUMBERS`).
_SMALLER = "keep fewer arrays (keep=('x',) stores the means only) or filter the runs in smaller banks"


def _warn_undeclared_angle_outputs(h: Model, angle_states: frozenset[int]) -> None:
    """Warn (AngleWarning) for each output of h that depends on angle states only, is not
    2π-periodic in them (θ itself, θ + b, 2θ; not sin θ) and is not declared an angle.

    Such an output measures an angle: its innovation must be wrapped, or a true angle near
    ±π gives innovations near 2π and an inconsistent filter (an ANEES of 46 on a 2-state
    tracker, issue 26), without any other sign.
    """
    angles = {h.inputs[j] for j in angle_states}
    if not angles:
        return
    for i, expr in enumerate(h.outputs):
        states = expr.free_symbols & set(h.inputs)
        if i in h.angle_outputs or not states or not states <= angles:
            continue
        shift = {t: t + 2 * sp.pi for t in states}
        if sp.expand(expr.xreplace(shift) - expr) == 0:  # sin θ, cos θ: continuous across ±π
            continue
        names = ", ".join(sorted(map(str, states)))
        warnings.warn(
            f"h_model {h.name!r}: output {i} ({expr}) depends only on the angle state(s) {names} and is not "
            f"2π-periodic in them, but it is not declared an angle: its innovations are not wrapped, so a "
            f"true angle near ±π gives innovations near 2π and an inconsistent filter; declare it with "
            f"Model(..., angles=[{i}])", AngleWarning, stacklevel=4)


@dataclass(frozen=True, eq=False)
class NonlinearKalmanFilter(Filter):
    """A Kalman filter whose prediction and update are NLTs, compiled to C.

    x_{k+1} = f(x_k, w_k), y_k = h(x_k, e_k); without noise symbols the noises are additive.
    TT1 gives the EKF, TT2 the second-order EKF, the UT the UKF (``UT.cubature()`` the CKF)
    and Gauss–Hermite the Gauss–Hermite filter (module notes).

    Parameters
    ----------
    f_model : Model or SDE
        The dynamics (n inputs, n outputs).  Outputs or inputs declared as angles are angle
        states.  An :class:`~symmon.SDE` (with ``Q=None``) gives its continuous-discrete
        filter instead, a :class:`~symmon.ContinuousDiscreteKalmanFilter` of the same rule
        and ``square_root`` (its ``filter`` takes the measurement ``times=``).
    h_model : Model
        The measurement model (n inputs, n_y outputs; angle outputs wrap the innovation).
    Q : array_like
        Process noise covariance (Cov w, or additive (n, n)).
    R : array_like
        Measurement noise covariance (Cov e, or additive (n_y, n_y)).
    transform : TT1, TT2, UT, GaussHermite, a registered name, or a FilterStrategy, default ``UT.ut1()``
        A name is a filter name (``"ekf"``, ``"ekf2"``, ``"ukf"``, ``"ckf"``, ``"ghkf"``:
        :func:`symmon.filters.names.filter_rule`) or a rule name as in :func:`symmon.propagate`
        (``"tt1"``, ``"ut1"``, ``"gh5"``).
        A transform is used for both updates of every step (the strategy
        :class:`~symmon.filters.gaussian.strategy.RuleStrategy`); :class:`Adaptive` picks one per
        step and run.
    iterations : int, default 1
        With ``TT1()``, the number of linearisations of the measurement update: 1 is the EKF,
        more the iterated EKF (Gauss–Newton steps of the update from the same prior, Bell &
        Cathey 1993; docs/filters.md, "Iterated EKF"), from 1 to :data:`MAX_ITERATIONS`.
    square_root : bool, default False
        Propagate the lower Cholesky factor S of P (P = S Sᵀ) instead of P: the square-root
        form of the same filter (:mod:`symmon.filters.gaussian._sqrtstep`), whose covariances stay
        positive semidefinite where P⁻ − K S Kᵀ loses definiteness to rounding.  Its results
        also hold the factors (:attr:`KalmanResult.P_chol`).

    Attributes
    ----------
    strategy : FilterStrategy
        How the steps run (:mod:`symmon.filters.gaussian.strategy`).

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.symbols("x")
    >>> ekf = sm.NonlinearKalmanFilter(sm.Model([x], [x]), sm.Model([x], [x]), [[1.0]], [[1.0]], sm.TT1())
    >>> res = ekf.filter([[1.0]], sm.Gaussian([0.0], [[1.0]]))
    >>> round(float(res.x[0, 0]), 12), round(float(res.P[0, 0, 0]), 12)
    (0.666666666667, 0.666666666667)
    >>> ekf.filter([[[1.0]], [[2.0]]], sm.Gaussian([0.0], [[1.0]])).x.shape   # a bank of 2 runs
    (2, 1, 1)
    """

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray
    transform: Transform | FilterStrategy | None = None
    iterations: int = 1
    square_root: bool = False
    strategy: FilterStrategy = field(init=False, repr=False)

    def __post_init__(self) -> None:
        f, h = check_state_models(self.f_model, self.h_model)
        Q = as_covariance(self.Q, "Q", dim=f.n_v if f.n_v else f.n_u)
        R = noise_cov(h, self.R, "R")
        transform = UT.ut1() if self.transform is None else filter_rule(self.transform)
        strategy = transform if isinstance(transform, FilterStrategy) else RuleStrategy(transform)
        it = self.iterations
        if isinstance(it, bool) or not isinstance(it, (int, np.integer)) or not 1 <= it <= MAX_ITERATIONS:
            raise SymmonError(f"iterations must be an integer from 1 to {MAX_ITERATIONS}, got {plain_repr(it)}")
        if it > 1 and not (isinstance(strategy, RuleStrategy) and strategy.transform.taylor_order == 1):
            raise SymmonError(f"iterations > 1 is the iterated EKF: it needs transform TT1(), got {self.transform!r}")
        if not isinstance(self.square_root, (bool, np.bool_)):
            raise ArgumentTypeError(f"square_root must be True or False, got {self.square_root!r}")
        if self.square_root and not isinstance(strategy, RuleStrategy):
            raise SymmonError(f"square_root=True needs one transform for every step; {strategy.label()} chooses "
                              "one per step")
        object.__setattr__(self, "square_root", bool(self.square_root))
        object.__setattr__(self, "iterations", int(it))
        object.__setattr__(self, "Q", readonly(Q))
        object.__setattr__(self, "R", readonly(R))
        object.__setattr__(self, "transform", transform)
        object.__setattr__(self, "strategy", strategy)
        strategy.check(self)
        _warn_undeclared_angle_outputs(h, self.angle_states)

    @property
    def dimensions(self) -> tuple[int, int]:
        """The dimensions the two updates integrate over: [x; w] for f and [x; e] for h
        (the state alone for additive noise)."""
        return self.f_model.n_u + self.f_model.n_v, self.h_model.n_u + self.h_model.n_v

    gaussian_mode: ClassVar[bool] = True
    has_smoother: ClassVar[bool] = True
    exportable: ClassVar[bool] = True

    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.f_model.n_u, self.h_model.n_y

    def step_cost(self) -> int:
        """The rule's cost on [x; w] for the prediction and on [x; e] for each update's
        iteration (an adaptive strategy counts as the EKF, its cheapest rule)."""
        rule = self.transform if isinstance(self.transform, Transform) else TT1()
        n_f, n_h = self.dimensions
        return int(rule.cost(n_f)) + self.iterations * int(rule.cost(n_h))

    def as_gaussian_mode(self) -> NonlinearKalmanFilter:
        """Itself: a mode of :class:`~symmon.IMM`."""
        return self

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        n, n_y = self.sizes
        names = self.strategy.stores(keep)
        # A square-root filter keeps the factors of P and P⁻ beside them.
        factors = n * n * len(names & {"P", "P_pred"}) if self.square_root else 0
        return kept_numbers(n, n_y, names) + factors, 0

    def _filter(self, call: FilterCall) -> KalmanResult:
        """The compiled recursion over the checked ``call`` (its strategy's steps)."""
        return self._filter_checked(FilterInputs(call.Y, call.runs, call.keep, call.x0, call.P0, call.truth, call.pv))

    @cached_property
    def params(self) -> tuple:
        """The parameters of the filter: those of f, then those of h that f does not have."""
        return filter_params(self.f_model, self.h_model)

    @cached_property
    def angle_states(self) -> frozenset[int]:
        """State components that are angles: f's angle outputs and f's or h's angle inputs."""
        return frozenset(self.f_model.angle_outputs | self.f_model.angle_inputs | self.h_model.angle_inputs)

    @cached_property
    def method(self) -> str:
        """The filter's name: EKF, IEKF(iterations=...), EKF2, UKF(...), CKF, GHKF(order=...) or Adaptive(...)."""
        label = f"IEKF(iterations={self.iterations})" if self.iterations > 1 else self.strategy.label()
        return "SR-" + label if self.square_root else label

    def smooth(self, ys: ArrayLike, x0: Gaussian | ArrayLike, P0: ArrayLike | None = None, *,
               keep: Iterable[str] | None = None, params: dict | None = None) -> SmootherResult:
        """The RTS smoother of this filter: a forward pass, then the backward pass in C.

        The smoother of the filter's family (:mod:`symmon.filters.gaussian.smoother`): TT1 gives the
        extended RTS smoother, TT2 the second-order one, a UT the unscented RTS smoother
        (Särkkä 2008), Gauss–Hermite the Gauss–Hermite smoother; angle states are wrapped.
        A square-root filter has the square-root smoother
        (:func:`symmon.filters.gaussian.smoother.sqrt_backward_graph`), whose result also holds the
        smoothed factors (``P_chol``).

        Parameters
        ----------
        ys, x0, P0
            As for :meth:`filter`: one run (K, n_y) or a bank (R, K, n_y); NaN marks a
            missing measurement.
        keep : iterable of str, optional
            What the forward pass keeps, as for :meth:`filter` (default: all); ``x`` and ``P``
            are always kept, since the backward pass reads them.
        params : dict, optional
            The parameters' values, as for :meth:`filter`.

        Returns
        -------
        SmootherResult
            ``x`` (K, n) and ``P`` (K, n, n) smoothed ((R, K, ...) for a bank), and
            ``filtered``, the forward pass (its x, P and log-likelihood).

        Raises
        ------
        SymmonError
            For an adaptive filter (it has no one transform to smooth with), or when the
            backward pass produces NaN or inf (a predicted covariance that is singular),
            naming the run and step; the errors of :meth:`filter`.
        """
        if not isinstance(self.strategy, RuleStrategy):
            raise SymmonError(f"smooth needs one transform for every step; {self.method} chooses one per step")
        n = self.f_model.n_u
        kept = check_keep(keep)
        forward = None if kept is None else kept | {"x", "P"}
        n = self.f_model.n_u
        checked = filter_inputs(self, ys, x0, P0, keep=forward, params=params,
                                extra_per_step=n + (2 if self.square_root else 1) * n * n,
                                what="smoother results", advice=_SMALLER)
        fwd = self._filter_checked(checked)  # the forward pass, on the inputs checked once
        bank = fwd.runs is not None
        X = fwd.x if bank else fwd.x[None]
        P = fwd.P if bank else fwd.P[None]
        smoother = compiled_smoother(self.f_model, self.strategy.transform, self.angle_states, self.params,
                                     self.square_root)
        if self.square_root:  # the factors the filter propagated, not a new factorisation of P
            P = fwd.P_chol if bank else fwd.P_chol[None]
        xs, Ps, *chol = smoother(X, P, self.Q, params=checked.params)
        # One sum per array when all is finite (no boolean array of the size of P^s); the
        # entry-by-entry test names the step otherwise.
        bad = None if all_finite(xs, Ps) else ~(np.isfinite(xs).all(axis=-1) & np.isfinite(Ps).all(axis=(-1, -2)))
        if bad is not None and bad.any():
            r, k = np.argwhere(bad)[-1]  # the backward pass runs from the end
            where = f"step {k}" if not bank else f"run {r}, step {k}"
            raise SymmonError(f"{self.method} smoother: NaN or inf at {where} (a predicted covariance is "
                              "singular, or a derivative is undefined there)")
        if not bank:
            xs, Ps, chol = xs[0], Ps[0], [c[0] for c in chol]
        for a in [xs, Ps] + chol:
            a.flags.writeable = False
        return SmootherResult(xs, Ps, fwd, angle_states=tuple(sorted(self.angle_states)), method=self.method,
                              P_chol=chol[0] if chol else None)

    def fit(self, ys: ArrayLike, x0: Gaussian | ArrayLike, start: dict, P0: ArrayLike | None = None, *,
            params: dict | None = None, bounds: dict | None = None, max_iter: int = 200) -> FitResult:
        """Maximum-likelihood estimates of model parameters (:mod:`symmon.filters.gaussian.fit`).

        Maximises the marginal log-likelihood of ``ys`` (summed over the runs of a bank) over
        the parameters named in ``start``, with its exact gradient: CasADi differentiates
        through the filter's compiled step folded over the steps (no finite differences).

        Parameters
        ----------
        ys, x0, P0
            As for :meth:`filter` (NaN marks a missing measurement).
        start : dict
            The parameters to fit and their starting values, e.g. ``{"b": 0.0}``.
        params : dict, optional
            The values of the other parameters (fixed), as for :meth:`filter`.
        bounds : dict, optional
            ``{name: (low, high)}`` for fitted parameters (None for no bound on one side),
            e.g. a noise intensity ``(1e-6, None)``.
        max_iter : int
            Iterations of the optimiser (L-BFGS-B).

        Returns
        -------
        FitResult
            The estimates, their standard errors from the observed information (the exact
            Hessian of the log-likelihood), the covariance, the log-likelihood, the
            iterations, all parameter values, and the filter at the fitted values.

        Raises
        ------
        ModelError
            Unknown, missing or doubly given parameters, or bad bounds or starting values.
        SymmonError
            When the optimiser does not converge, or the information matrix is singular
            (a parameter the data do not identify).
        """
        if not isinstance(self.strategy, RuleStrategy):
            raise SymmonError(f"fit needs one transform for every step; {self.method} chooses one per step")
        return fit_parameters(self, ys, x0, start, P0, params=params, bounds=bounds, max_iter=max_iter)

    def export_c(self, directory: str | os.PathLike, name: str | None = None) -> list[Path]:
        """Write this filter as standalone C99 for an embedded target (docs/export.md).

        ``NAME.c`` and ``NAME.h`` hold ``NAME_predict(x, P)`` and ``NAME_update(x, P, y,
        &loglik)``, in place, with no allocation, no global state and no I/O;
        ``NAME_example.c`` runs them on measurements read from stdin (NaN: missing, skipped
        as :meth:`filter` skips it; the parameter values of each step before its
        measurement), and ``NAME_README.md`` states the interface, the sizes and the model's
        hash; a file of these names that the export did not write is not replaced.  See
        :func:`symmon.filters.gaussian.export.export_filter_c` for the parameters and errors.

        Returns
        -------
        list of Path
            The files written: ``NAME.c``, ``NAME.h``, ``NAME_example.c``, ``NAME_README.md``.
        """
        return export_filter_c(self, directory, name)

    def _nan_cause(self, checked, r: int, k: int) -> str:
        """Where step ``k`` of run ``r`` turned NaN (:mod:`symmon.filters.gaussian.diagnose`): f at the last
        finite estimate, else h at the prediction; "" when neither shows it."""
        x0 = checked.x0 if checked.x0.ndim == 1 else checked.x0[r]
        P0 = checked.P0 if checked.P0.ndim == 2 else checked.P0[r]
        pv = None if checked.params is None else checked.params[r:r + 1, :k + 1]
        values = {} if pv is None else dict(zip((str(s) for s in self.params), pv[0, k]))
        try:
            out, _ = self.strategy.run(self, checked.Y[r:r + 1, :k + 1], x0, P0, None,
                                       **({} if pv is None else {"params": pv}))
            x_prev = x0 if k == 0 else out["x"][0, k - 1]
            cause = locate_nonfinite(self.f_model, "f", x_prev, values)
            x_pred = out["x_pred"][0, k]
            if not cause and np.all(np.isfinite(x_pred)):
                cause = locate_nonfinite(self.h_model, "h", x_pred, values)
            return cause
        except (SymmonError, KeyError, IndexError):  # the diagnosis must not hide the failure itself
            return ""

    def _filter_checked(self, checked) -> KalmanResult:
        """:meth:`filter` on its inputs as :func:`~symmon.filters.inputs.filter_inputs` checked
        them (so that :meth:`smooth` checks them once)."""
        n_y = self.h_model.n_y
        Yb, runs, kept, truth = checked.Y, checked.runs, checked.keep, checked.truth
        extra = {} if checked.params is None else {"params": checked.params}  # a strategy without parameters needs no argument
        if truth is not None and self.strategy.nees_in_step:
            extra["truth"] = truth
        out, choices = self.strategy.run(self, Yb, checked.x0, checked.P0, kept, **extra)
        nees = {k: out.pop(k) for k in ("nees", "nees_trace") if k in out}
        if truth is not None and not nees:  # a strategy that keeps every array: from x and P
            nees = {"x": out["x"], "P": out["P"], "truth": truth}
        first = out.pop("first_nonfinite", None)  # tested in the compiled loop, step by step
        out = {k: v for k, v in out.items() if k == "loglik" or kept is None or k.removesuffix("_chol") in kept}
        if first is None:  # a NaN reaches every later log-likelihood
            first = first_nonfinite(out["loglik"], out.get("x"), out.get("P"))
        if (first >= 0).any():
            k = first[first >= 0].min()  # the first step that failed (later ones may be NaN in every run)
            r = int(np.argmax(first == k))
            where = f"step {k}" if runs is None else f"run {r}, step {k}"
            cause = self._nan_cause(checked, r, int(k))
            raise SymmonError(
                f"{self.method}: the filter produced NaN or inf at {where}"
                + (f": {cause}" if cause else " (the innovation covariance S is singular or not positive definite, "
                   "a covariance lost positive definiteness, or a derivative is undefined there, e.g. sqrt at 0 or "
                   "atan2(0, 0))")
            )
        arrays = {k: v if runs is not None else v[0] for k, v in out.items()}
        if nees:  # after the check above: a NaN state is a failed filter, not a singular P
            nees = {k: v if runs is not None else v[0] for k, v in nees.items()}  # a single run's errors name no run
            arrays["nees_values"] = (step_nees(nees["nees"], nees["nees_trace"]) if "nees" in nees
                                     else nees_of(nees["x"], nees["P"], nees["truth"], sorted(self.angle_states)))
        for v in arrays.values():
            v.flags.writeable = False  # fresh arrays of this call: frozen, not copied
        if choices is not None:
            choices = choices if runs is not None else choices[0]
            choices.flags.writeable = False
        measured = None
        if np.isnan(Yb).any():
            measured = readonly((~np.isnan(Yb if runs is not None else Yb[0])).sum(axis=-1))
        if "nis" in arrays:
            arrays["nis_values"] = arrays.pop("nis")
        return KalmanResult(**arrays, measured=measured, n_y=n_y, n_x=self.f_model.n_u,
                            angle_states=tuple(sorted(self.angle_states)),
                                     method=self.method, choices=choices)
