"""The continuous-discrete Gaussian filters: an SDE between measurement times, discrete
measurements at them.

The state follows dx = a(x, t) dt + L(x, t) dβ, E[dβ dβᵀ] = Q_c dt (:class:`~symmon.SDE`), and is
measured at times t_1 < t_2 < … as y_k = h(x(t_k), e_k), e_k ~ N(0, R).  Between two
measurements the filter integrates the moment equations of the Gaussian approximation
N(m(t), P(t)) (Särkkä 2007; Särkkä & Solin 2019, §9.1),

    dm/dt = E[a(x)],
    dP/dt = E[a(x) (x − m)ᵀ] + E[(x − m) a(x)ᵀ] + E[L(x) Q_c L(x)ᵀ],                   (1)

with the expectations over N(m, P) by the filter's rule:

- TT1 (``"ekf"``), the continuous-discrete EKF: dm/dt = a(m), dP/dt = A P + P Aᵀ + L Q_c Lᵀ
  with A = ∂a/∂x and L at m;
- a point rule (``"ukf"``, ``"ckf"``, ``"ghkf"``, any rule with a unit rule): the sigma-point
  form, points χᵢ = m + S zᵢ (S Sᵀ = P), dm/dt = Σ wᵢᵐ a(χᵢ),
  dP/dt = C + Cᵀ + Σ wᵢᵐ L Q_c Lᵀ(χᵢ) with C = Σ wᵢᶜ (χᵢ − m)(a(χᵢ) − dm/dt)ᵀ.

Square-root form (``square_root=True``).  The lower Cholesky factor S of P follows

    dS/dt = S Φ(S⁻¹ (dP/dt) S⁻ᵀ),   Φ(M) = the lower triangle of M with half its diagonal,    (2)

(Särkkä 2007, §IV; Kulikov & Kulikova 2014): S Φ(M) + Φ(M)ᵀ Sᵀ = S M Sᵀ = dP/dt, and S stays
lower triangular.  S⁻¹ (dP/dt) S⁻ᵀ is formed from S alone (the points are m + S zᵢ, so
S⁻¹ C S⁻ᵀ = Σ wᵢᶜ zᵢ (S⁻¹(a(χᵢ) − dm/dt))ᵀ; for TT1, S⁻¹ A S), so P is never formed nor factored
again; the update is the compiled square-root step of
:class:`~symmon.NonlinearKalmanFilter` (``square_root=True``) on that factor, and the results
hold the factors (``P_chol``, ``P_pred_chol``).  It needs P > 0 (S invertible).

Transitions and the smoother.  For the smoother, the forward pass also integrates the
transition Φ(t) of the interval from t_{k−1},

    dΦ/dt = Â(t) Φ,  Φ(t_{k−1}) = I,  Â = E[(a(x) − dm/dt)(x − m)ᵀ] P⁻¹,                   (3)

Â the statistical linearisation of the drift (A = ∂a/∂x at m for TT1, Σ wᵢᶜ (a(χᵢ) − dm/dt) zᵢᵀ S⁻¹
for a point rule), so that C_k = Cov(x(t_{k−1}), x(t_k)) = P_{k−1} Φᵀ in the Gaussian
approximation (Särkkä & Sarmavuori 2013; Särkkä & Solin 2019, §10.3).  On a linear SDE,
Φ = e^{A dt} exactly.

Exact prediction (``exact=True``, the :class:`~symmon.KalmanFilter` of a linear SDE).  With
a = A x + b and L constant, the moments over an interval dt are the exact discretisation

    m⁻ = F m + c,  P⁻ = F P Fᵀ + Q(dt),  F = e^{A dt},  c = ∫₀^dt e^{A s} b ds,
    Q(dt) = ∫₀^dt e^{A s} L Q_c Lᵀ e^{Aᵀ s} ds,                                           (4)

F and c from one matrix exponential of [[A, b], [0, 0]] dt, Q(dt) by Van Loan's
(:func:`symmon.core.discretize.van_loan_numeric`), at the parameters' values of each step;
in square-root form S⁻ = tria([F S, √Q(dt)]).  No integrator runs.

The RTS smoother (:meth:`ContinuousDiscreteKalmanFilter.smooth`).  From x^s_K = x_K,
P^s_K = P_K down to k = 1, with the stored x⁻, P⁻ and Φ of each interval,

    G_k = P_k Φ_{k+1}ᵀ (P⁻_{k+1})⁻¹,
    x^s_k = x_k + G_k (x^s_{k+1} − x⁻_{k+1}),  P^s_k = P_k + G_k (P^s_{k+1} − P⁻_{k+1}) G_kᵀ,  (5)

the discrete-time Gaussian RTS smoother (Särkkä 2013, Algorithm 9.3) with the cross-covariance
of (3); on a linear SDE, that of the exact discretisation.

The square-root smoother (``square_root=True``).  Φ and P follow the same Â: for every rule
dP/dt = Â P + P Âᵀ + D with D = E[L Q_c Lᵀ] (for a point rule C = E[(x − m)(a − ā)ᵀ] = P Âᵀ), so
the interval's effective noise Q̃ = P⁻ − Φ P Φᵀ solves

    dQ̃/dt = Â Q̃ + Q̃ Âᵀ + D,  Q̃(t_{k−1}) = 0,  i.e.  Q̃ = ∫ Φ(t_k, s) D(s) Φ(t_k, s)ᵀ ds ⪰ 0,    (6)

and the forward pass integrates it beside Φ (no difference P⁻ − Φ P Φᵀ is formed; with
``exact`` it is Van Loan's Q(dt)).  The joint Gaussian of (x_k, x_{k+1}) then has the factor
columns X = [S_k, 0] and Y = [Φ S_k, Q̃^{1/2}] (P⁻ = Y Yᵀ, C = X Yᵀ = P_k Φᵀ), and the backward
step is the residual form of the discrete square-root smoother
(:func:`symmon.filters.gaussian.smoother.sqrt_backward_graph`): with S⁻ = tria(Y) and
G = C S⁻⁻ᵀ S⁻⁻¹ (two triangular solves),

    S^s_k = tria([(I − G Φ) S_k,  −G Q̃^{1/2},  G S^s_{k+1}]),                                (7)

the factor of (I − G Φ) P_k (I − G Φ)ᵀ + G Q̃ Gᵀ + G P^s_{k+1} Gᵀ = P_k + G (P^s_{k+1} − P⁻) Gᵀ, a
sum of squares where (5) adds a difference.  The result holds the factors (``P_chol``), as the
discrete square-root smoother's does.

a(x), its Jacobian and L Q_c Lᵀ are one compiled CasADi model of the SDE's symbols
(:func:`symmon.compile.compiled.compiled_with_params`).  The equations are integrated by the
Dormand–Prince 5(4) pair with adaptive steps (``rtol`` and ``atol``): with a C compiler, in one
C call for the whole bank (:mod:`symmon.filters.gaussian._cdkernel`, ``cd_loop.c``: the
intervals and the updates of every run, with the step-size control of
``scipy.integrate.solve_ivp``'s RK45 step for step, so that the two take the same steps up to
rounding); else, with ``integrator="solve_ivp"``, and for a run the C hands back (an interval
it could not integrate, an update that is not finite) from that step on, by
``scipy.integrate.solve_ivp`` (RK45).  An interval that needs more than ``max_evaluations``
evaluations of the right-hand side (a stiff or diverging drift), or whose moments turn NaN or
inf, raises :class:`~symmon.errors.SymmonError` naming the step, the run and the state.  The measurement
update at each t_k is that of :class:`~symmon.NonlinearKalmanFilter` with the same rule
(missing components, angles and the log-likelihood as there).

Measurement times.  The filter declares ``continuous_time``: ``filter(ys, x0, times=ts)``
takes the measurement times t_1 < … < t_K (after ``t0``, the time of ``x0``, default 0; (K,),
or (R, K) per run for a bank), and the interval before measurement k is t_k − t_{k−1}
(t_0 = ``t0``).  The alternative is the per-step parameter ``dt`` (``params={"dt": steps}``:
a number for regular sampling, one per step (K,) or one per run and step (R, K) for
irregular times, strictly positive; ``x0`` is then at t = 0); giving both is refused.

Time.  For a time-invariant SDE an interval's moments depend on its length only: each is
integrated over [0, dt], and the two routes give the same numbers bit for bit for the same
intervals.  A time-varying SDE (a(x, t), L(x, t): :attr:`SDE.is_time_invariant` false) is
integrated over the absolute interval [t_{k−1}, t_k], t the compiled drift's last parameter:
its start is ``t0`` and the measurement times before it with ``times`` (per run for a bank),
and the cumulative sum of the intervals from 0 on the ``dt`` route, so the two routes agree
to the rounding of that sum.  The exact prediction (4) and ``sm.KalmanFilter(sde, ...)``
refuse a time-varying SDE: it has no single e^{A dt}.

Banks: each run is integrated on its own (its own adaptive steps, so that a bank filtered in
shards gives the whole bank's numbers bit for bit); in C the runs are spread over threads, on
solve_ivp the measurement updates of all the runs are one compiled call per step.

References
----------
S. Särkkä, "On unscented Kalman filtering for state estimation of continuous-time nonlinear
systems", IEEE Trans. Autom. Control 52(9), 2007. doi:10.1109/TAC.2007.904453
S. Särkkä, A. Solin, *Applied Stochastic Differential Equations*, Cambridge University Press,
2019, ch. 9 and 10.
S. Särkkä, J. Sarmavuori, "Gaussian filtering and smoothing for continuous-discrete dynamic
systems", Signal Processing 93(2), 2013. doi:10.1016/j.sigpro.2012.09.002
S. Särkkä, *Bayesian Filtering and Smoothing*, Cambridge University Press, 2013, ch. 9.
G. Yu. Kulikov, M. V. Kulikova, "Accurate numerical implementation of the continuous-discrete
extended Kalman filter", IEEE Trans. Autom. Control 59(1), 2014. doi:10.1109/TAC.2013.2272136
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable

import numpy as np
import scipy.integrate
import scipy.linalg
import sympy as sp
from numpy.typing import ArrayLike

from ...compile.ccache import has_compiler
from ...compile.compiled import CompiledModel, compiled_with_params
from ...core.angles import wrap_components
from ...core.arrays import all_finite, readonly
from ...core.gaussian import matrix_sqrt
from ...core.checks import check_model
from ...core.model import Model
from ...core.discretize import van_loan_numeric
from ...core.sde import SDE
from ...errors import (ArgumentError, ArgumentTypeError, CovarianceError, ModelError, ShapeError, SymmonError,
                       plain_repr)
from ...transforms.base import batch_sqrt
from ...transforms.base import Transform
from ..base import Filter, register_sde_builder
from ..inputs import FilterCall, check_call, filter_params, param_values
from ..names import filter_rule
from ..results import KalmanResult, SmootherResult, nees_of
from ._sqrtstep import noise_factor
from .nonlinear import NonlinearKalmanFilter
from ._cdkernel import CompiledCD, compiled_cd
from .step import compiled_step

__all__ = ["ContinuousDiscreteKalmanFilter", "DT", "INTEGRATORS", "MAX_EVALUATIONS", "continuous_filter",
           "continuous_kalman_filter"]

#: The name of the per-step parameter that gives the interval before each measurement.
DT = "dt"
#: The integrators: ``"auto"``, the compiled Dormand–Prince loop in C where the compile policy
#: gives C (else solve_ivp), or ``"solve_ivp"`` always.
INTEGRATORS = ("auto", "solve_ivp")
#: The default bound on the evaluations of the moment equations' right-hand side per interval.
MAX_EVALUATIONS = 20_000
#: The fewest evaluations of the right-hand side in an interval: solve_ivp's RK45 evaluates it
#: at the start, once more to choose its first step, and six times per accepted step.
MIN_EVALUATIONS = 8


class _Stop(Exception):
    """The integration of one interval stopped: why, at which time and mean."""

    def __init__(self, why: str, t: float, m: np.ndarray) -> None:
        super().__init__(why)
        self.why, self.t, self.m = why, t, m


def _positive(value: Any, what: str, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value) or value <= 0:
        raise SymmonError(f"{what} must be a positive finite number, got {plain_repr(value)}")
    return float(value)


@dataclass(frozen=True, eq=False)
class ContinuousDiscreteKalmanFilter(Filter):
    """A continuous-discrete Gaussian filter: the moment ODEs of an SDE between measurements,
    the Kalman update at each (module notes).

    Parameters
    ----------
    sde : SDE
        The dynamics dx = a(x, t) dt + L(x, t) dβ with spectral density Q_c; its angle states
        are the filter's.  A time-varying SDE is integrated with the absolute time (module
        notes).
    h : Model
        The measurement model, with the SDE's states as inputs (n inputs, n_y outputs).
    R : array_like
        Measurement noise covariance (Cov e, or additive (n_y, n_y)).
    transform : str or Transform, default ``"ekf"``
        The rule of the expectations and of the update: ``"ekf"`` (TT1: the CD-EKF),
        ``"ukf"``, ``"ckf"``, ``"ghkf"``, or a rule with points (``UT(...)``,
        ``GaussHermite(order)``).
    rtol, atol : float, default 1e-6 and 1e-9
        The tolerances of the adaptive integrator (Dormand–Prince 5(4), in C or by
        ``scipy.integrate.solve_ivp``) on m and P.
    max_step : float, optional
        The largest integration step (default: unbounded).
    max_evaluations : int, default :data:`MAX_EVALUATIONS`
        The most evaluations of the right-hand side in one interval; beyond it the filter
        raises (a stiff or diverging drift) instead of running on.
    square_root : bool, default False
        Propagate the lower Cholesky factor S of P (eq. (2) of the module notes) and update
        it by the square-root step of :class:`~symmon.NonlinearKalmanFilter`: the same filter
        to the integrator's tolerance, whose covariances stay positive definite; the results
        also hold the factors (``P_chol``, ``P_pred_chol``).  P0 must be positive definite.
    exact : bool, default False
        For a linear time-invariant SDE (a = A x + b, L constant): predict by the exact transition (eq. (4):
        e^{A dt} and Van Loan's Q(dt) at each interval) instead of integrating; with TT1 this
        is the Kalman filter of the SDE (``sm.KalmanFilter(sde, None, H, R)`` builds it).
    integrator : {"auto", "solve_ivp"}, default ``"auto"``
        ``"auto"``: the compiled Dormand–Prince loop where the compile policy gives C (module
        notes), else ``scipy.integrate.solve_ivp``; ``"solve_ivp"``: always the latter.  Both
        take the same steps, up to rounding.

    Notes
    -----
    The parameters are the SDE's, then ``dt`` (the interval before each measurement,
    strictly positive, irregular allowed), then h's that the SDE has not.  The intervals
    come from ``filter(..., times=ts, t0=...)`` (``x0`` is the state at ``t0``, default 0)
    or from ``params={"dt": ...}`` (``x0`` at t = 0), not from both.

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> ou = sm.SDE([x], [-x], diffusion=[1])
    >>> cd = sm.ContinuousDiscreteKalmanFilter(ou, sm.Model([x], [x]), [[1.0]])
    >>> res = cd.filter([[1.0], [0.5]], [0.0], [[1.0]], times=[0.5, 2.0])
    >>> res.x.shape, cd.params
    ((2, 1), (dt,))
    >>> same = cd.filter([[1.0], [0.5]], [0.0], [[1.0]], params={"dt": [0.5, 1.5]})
    >>> bool((same.x == res.x).all())
    True
    """

    sde: SDE
    h: Model
    R: np.ndarray
    transform: Any = "ekf"
    rtol: float = 1e-6
    atol: float = 1e-9
    max_step: float | None = None
    max_evaluations: int = MAX_EVALUATIONS
    square_root: bool = False
    exact: bool = False
    integrator: str = "auto"
    update: NonlinearKalmanFilter = field(init=False, repr=False)
    drift_model: Model = field(init=False, repr=False)
    points: tuple | None = field(init=False, repr=False)

    has_smoother: ClassVar[bool] = True
    exportable: ClassVar[bool] = False
    gaussian_mode: ClassVar[bool] = False
    continuous_time: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if not isinstance(self.sde, SDE):
            raise ArgumentTypeError(f"sde must be a symmon.SDE, got {type(self.sde).__name__} "
                                    "(a discrete model f goes to NonlinearKalmanFilter)")
        h = check_model(self.h, "h")
        sde = self.sde
        if h.n_u != sde.n:
            raise ShapeError(f"h has {h.n_u} inputs but the SDE has {sde.n} states")
        if DT in {str(s) for s in sde.params}:
            raise ModelError(f"the SDE declares a parameter named {DT!r}, the name of the filter's interval "
                             "between measurements: rename it")
        tr = filter_rule(self.transform)
        if not isinstance(tr, Transform) or (tr.taylor_order != 1 and tr.unit_rule(1) is None):
            raise SymmonError(f"transform must be TT1 ('ekf') or a rule with points ('ukf', 'ckf', 'ghkf', "
                              f"UT(...), GaussHermite(...)), got {self.transform!r}")
        for name in ("rtol", "atol"):
            object.__setattr__(self, name, _positive(getattr(self, name), name))
        object.__setattr__(self, "max_step", _positive(self.max_step, "max_step", allow_none=True))
        me = self.max_evaluations
        if isinstance(me, (bool, np.bool_)) or not isinstance(me, (int, np.integer)) or me < 10:
            raise SymmonError(f"max_evaluations must be an integer of at least 10, got {plain_repr(me)}")
        object.__setattr__(self, "max_evaluations", int(me))
        for name in ("square_root", "exact"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ArgumentTypeError(f"{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        if self.integrator not in INTEGRATORS:
            raise ArgumentError(f"integrator must be one of {', '.join(map(repr, INTEGRATORS))}, "
                                f"got {plain_repr(self.integrator)}")
        if self.exact and not (sde.is_linear and sde.is_time_invariant):
            raise ModelError(f"exact=True needs a linear time-invariant SDE (a = A x + b, L constant); SDE {sde.name!r} "
                             "is not: integrate its moment equations (exact=False)")
        states = list(sde.states)
        # The update: the NonlinearKalmanFilter of the same rule whose prediction is the identity
        # without noise (exact for every rule), so that its update, likelihood, missing
        # components and angles are the discrete filter's.
        ident = Model(states, states, name=f"{sde.name}_identity", angles=sorted(sde.angles))
        update = NonlinearKalmanFilter(ident, h, np.zeros((sde.n, sde.n)), self.R, tr, square_root=self.square_root)
        D = sde.diffusion * sde.spectral_density * sde.diffusion.T
        # A time-varying SDE's time is the compiled drift's last parameter.
        tparams = list(sde.params) + ([] if sde.is_time_invariant else [sde.time])
        drift = Model(states, list(sde.drift) + list(D), name=f"{sde.name}_moments", params=tparams)
        object.__setattr__(self, "transform", tr)
        object.__setattr__(self, "R", update.R)
        object.__setattr__(self, "update", update)
        object.__setattr__(self, "drift_model", drift)
        # A point rule's unit points and weights, made once (None for TT1).
        object.__setattr__(self, "points", None if tr.taylor_order == 1 else tr.unit_rule(sde.n))

    # ----------------------------------------------------------------- the contract
    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.sde.n, self.h.n_y

    def step_cost(self) -> int:
        """The rule's cost for the evaluations of the moment equations over one interval and for
        the update: a lower bound, :data:`MIN_EVALUATIONS` evaluations (one accepted step of the
        Runge–Kutta 4(5) pair, its first evaluation and the initial step's choice); the adaptive
        integrator evaluates them as often as its tolerance needs.  With ``exact`` (a linear SDE,
        no integrator) one evaluation."""
        rule = int(self.transform.cost(self.sizes[0]))
        return (1 if self.exact else MIN_EVALUATIONS) * rule + rule

    @property
    def params(self) -> tuple:
        """The SDE's parameters, then ``dt``, then h's that the SDE has not."""
        dt = sp.Symbol(DT, positive=True)
        return filter_params(Model(list(self.sde.states), list(self.sde.states), params=[*self.sde.params, dt]),
                             self.h)

    @property
    def method(self) -> str:
        """``CD-`` and the discrete filter's name: CD-EKF, CD-CKF, CD-UKF(…), CD-GHKF(…), with
        ``SR-`` in the square-root form (CD-SR-EKF); CD-KF for the exact prediction with TT1."""
        label = self.update.method
        if self.exact and self.transform.taylor_order == 1:
            label = label.replace("EKF", "KF")
        return "CD-" + label

    @property
    def angle_states(self) -> frozenset[int]:
        """The SDE's angle states and h's angle inputs."""
        return self.update.angle_states

    def _check_params(self, params: dict | None, runs: int | None, steps: int,
                      intervals: np.ndarray | None = None) -> Any:
        """The parameter values (R, K, n_p), with the ``dt`` column the intervals of
        ``times`` when they are given (``intervals``), else ``params["dt"]``.

        Raises
        ------
        ArgumentError
            ``dt`` given in ``params`` together with ``times``.
        ModelError, ShapeError
            Missing or unknown parameters (without times, ``dt`` is one), bad values, or an
            interval that is not strictly positive (naming the step and run).
        """
        mapping = params is None or isinstance(params, dict)  # otherwise param_values names the fault
        has_dt = isinstance(params, dict) and DT in {str(k) for k in params}
        if intervals is not None and has_dt:
            raise ArgumentError(f"give the intervals by times or by params[{DT!r}], not both (times gives "
                                f"{DT} = t_k − t_(k−1), with t0 the time of x0)")
        if intervals is not None and mapping:
            params = {**(params or {}), DT: intervals}
        elif intervals is None and mapping and not has_dt:
            raise ModelError(f"{self.method} needs the measurement times: filter(ys, x0, times=[t_1, ..., t_K]) "
                             f"(x0 at t0, default 0), or the intervals params[{DT!r}] = t_k − t_(k−1); "
                             f"its parameters are {[str(s) for s in self.params]}")
        pv = param_values(self.params, params, runs, steps)
        j = [str(s) for s in self.params].index(DT)
        dts = pv[..., j]
        if not np.all(dts > 0):
            r, k = (int(i) for i in np.argwhere(~(dts > 0))[0])
            where = f"step {k}" if runs is None else f"run {r}, step {k}"
            raise ShapeError(f"parameter {DT!r} (the interval before each measurement) must be strictly positive, "
                             f"got {float(dts[r, k])!r} at {where}")
        return pv

    # ----------------------------------------------------------------- the moments
    @property
    def compiled_drift(self) -> CompiledModel:
        """a(x) and L Q_c Lᵀ (row by row) as one compiled model of [x; θ]."""
        return compiled_with_params(self.drift_model)

    def _rule(self, m: np.ndarray, S: np.ndarray | None, P: np.ndarray | None, theta: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(dm/dt, C, D, Y, Z) at N(m, S Sᵀ) (or N(m, P)): C = E[(x − m)(a − dm/dt)ᵀ], D = E[L Q_c Lᵀ],
        and for a point rule the weighted deviations Y = wᶜ (a(χᵢ) − dm/dt) and the unit points
        Z (χᵢ = m + S zᵢ); for TT1, Y = A = ∂a/∂x at m and Z = None."""
        n = self.sde.n
        cm = self.compiled_drift
        if self.transform.taylor_order == 1:  # TT1: a(m) and its Jacobian
            g, J_nz, _ = cm.eval_derivatives(np.concatenate([m, theta])[None])
            A = cm.dense_jacobian(J_nz)[0, :n, :n]
            C = (A @ P).T if P is not None else (A @ S @ S.T).T
            return g[0, :n], C, g[0, n:].reshape(n, n), A, None
        Z, wm, wc = self.points
        if S is None:
            S = batch_sqrt(P[None])[0]
        X = m + Z @ S.T
        G = cm.eval_g(np.ascontiguousarray(np.concatenate([X, np.broadcast_to(theta, (X.shape[0], theta.shape[0]))],
                                                          axis=1)))
        a = G[:, :n]
        dm = wm @ a
        Y = wc[:, None] * (a - dm)
        return dm, (X - m).T @ Y, (wm @ G[:, n:]).reshape(n, n), Y, Z

    def _theta(self, theta: Any, t: float | None, who: str) -> np.ndarray:
        """The compiled drift's parameters: the SDE's ``theta``, and the time ``t`` after them
        for a time-varying SDE (which needs it)."""
        th = np.zeros(0) if theta is None else np.asarray(theta, float).ravel()
        if self.time_invariant:
            return th
        if t is None or isinstance(t, (bool, np.bool_)) or not np.isfinite(t):
            raise ArgumentError(f"{who}: the SDE {self.sde.name!r} depends on its time {self.sde.time}, so the time "
                                f"is needed: t=... (a finite number), got {plain_repr(t)}")
        return np.append(th, float(t))

    @property
    def time_invariant(self) -> bool:
        """Whether the SDE is time-invariant (else the moment equations take the absolute time)."""
        return self.sde.is_time_invariant

    def moment_derivatives(self, m: np.ndarray, P: np.ndarray, theta: np.ndarray | None = None,
                           t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(dm/dt, dP/dt) of eq. (1) at the Gaussian N(m, P) with the SDE's parameters
        ``theta`` (at the time ``t``, needed for a time-varying SDE), by the filter's rule
        (module notes)."""
        th = self._theta(theta, t, "moment_derivatives")
        dm, C, D, _, _ = self._rule(np.asarray(m, float), None, np.asarray(P, float), th)
        return dm, C + C.T + D

    def factor_derivative(self, m: np.ndarray, S: np.ndarray, theta: np.ndarray | None = None,
                          t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(dm/dt, dS/dt) of the square-root form, eq. (2): dS/dt = S Φ(S⁻¹ (dP/dt) S⁻ᵀ) with Φ the
        lower triangle and half the diagonal, S lower triangular with a positive diagonal
        (at the time ``t``, needed for a time-varying SDE).

        S⁻¹ (dP/dt) S⁻ᵀ is formed from the factor without P: S⁻¹ A S + (S⁻¹ A S)ᵀ + S⁻¹ D S⁻ᵀ
        for TT1, Zᵀ (S⁻¹ Y)ᵀ + its transpose + S⁻¹ D S⁻ᵀ for a point rule (χᵢ − m = S zᵢ).

        Raises
        ------
        numpy.linalg.LinAlgError
            S is singular (a state without variance: the square-root form needs P > 0)."""
        th = self._theta(theta, t, "factor_derivative")
        dm, dS, _, _, _ = self._factor_rates(np.asarray(m, float), np.asarray(S, float), th)
        return dm, dS

    def _factor_rates(self, m: np.ndarray, S: np.ndarray, theta: np.ndarray) -> tuple:
        """(dm/dt, dS/dt, Y, Z, D): :meth:`factor_derivative` and the rule's Y, Z and D (:meth:`_rule`)."""
        dm, _, D, Y, Z = self._rule(m, S, None, theta)
        if np.any(np.diag(S) <= 0):
            raise np.linalg.LinAlgError("the factor S has a zero on its diagonal (P is singular)")
        # S⁻¹ by numpy (a small dense inverse: scipy's triangular solve calls cost milliseconds
        # each through its own BLAS threads on a busy machine).
        Si = np.linalg.inv(S)
        Dw = Si @ D @ Si.T
        Cw = Si @ Y @ S if Z is None else Z.T @ (Y @ Si.T)
        N = Cw + Cw.T + 0.5 * (Dw + Dw.T)
        Phi = np.tril(N)
        Phi[np.diag_indices_from(Phi)] *= 0.5
        return dm, S @ Phi, Y, Z, D

    @staticmethod
    def _linear_drift(S: np.ndarray | None, Y: np.ndarray, Z: np.ndarray | None) -> np.ndarray:
        """Â = E[(a − ā)(x − m)ᵀ] P⁻¹ of eq. (3): A (= Y) for TT1, Yᵀ Z S⁻¹ for a point rule
        (χᵢ − m = S zᵢ with the points' square root S of P, any one; a pseudo-inverse where an
        integrator's trial step made P singular, whose step its error control then rejects)."""
        if Z is None:
            return Y
        try:
            Si = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            Si = np.linalg.pinv(S)
        return Y.T @ Z @ Si

    def predict(self, m: np.ndarray, P: np.ndarray, dt: float, theta: np.ndarray | None = None,
                t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The moments (m, P) after an interval ``dt`` from (m, P): eq. (1) integrated (eq. (2)
        with ``square_root``), or the exact transition (4) with ``exact``.  For a time-varying
        SDE, ``t`` is the interval's start time (required): it is integrated over [t, t + dt].

        Raises
        ------
        ArgumentError
            A time-varying SDE without ``t``.
        SymmonError
            More than ``max_evaluations`` evaluations (a stiff or diverging drift), a failed
            step-size control, or moments that turn NaN or inf, naming the time and the mean.
        """
        m, P = np.asarray(m, float), np.asarray(P, float)
        th = self._theta(theta, t, "predict")
        if not self.time_invariant:
            th = th[:-1]  # _integrate appends the running time
        # The compiled loop over one interval with nothing measured (its x⁻ wraps angle states,
        # which this method does not: those stay on solve_ivp); a failure is named below.
        moments = None if self.angle_states else self._compiled_interval(m, P, float(dt), th, t)
        if moments is not None:
            return moments
        try:
            m1, P1, S1, _, _ = self._predict(m, P, np.linalg.cholesky(P) if self.square_root else None, float(dt), th,
                                          t_start=0.0 if t is None else float(t))
            return m1, P1
        except np.linalg.LinAlgError as exc:
            raise SymmonError(self._stopped(_Stop(f"the covariance is not positive definite ({exc})", 0.0, m),
                                            dt, "")) from None
        except _Stop as stop:
            raise SymmonError(self._stopped(stop, dt, "")) from None

    def _compiled_interval(self, m: np.ndarray, P: np.ndarray, dt: float, theta: np.ndarray,
                           t: float | None) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`predict` by the compiled loop (a step whose measurement is missing), or None
        (no compiled loop, a bad argument, or a stopped interval: :meth:`predict` goes on)."""
        n, n_y = self.sizes
        names = [str(s) for s in self.params]
        if self._kernel() is None or m.shape != (n,) or P.shape != (n, n) or theta.shape != (len(self.sde.params),) \
                or not (np.isfinite(dt) and dt > 0):
            return None
        pv = np.zeros((1, 1, len(names)))
        pv[0, 0, :len(theta)] = theta
        pv[0, 0, names.index(DT)] = dt
        try:
            cov = np.linalg.cholesky(P)[None] if self.square_root else P[None].copy()
        except np.linalg.LinAlgError:
            return None
        shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n), "innovation": (n_y,), "S": (n_y, n_y),
                  "nis": (), "loglik": ()}
        if self.square_root:
            shapes.update(P_chol=(n, n), P_pred_chol=(n, n))
        out = {k: np.empty((1, 1) + v) for k, v in shapes.items()}
        failed = self._compiled_pass(m[None].copy(), cov, np.full((1, 1, n_y), np.nan), pv,
                                     np.array([[0.0 if t is None else float(t)]]), out, None, None, False)
        if failed is None or failed[0] >= 0:
            return None
        return out["x_pred"][0, 0], out["P_pred"][0, 0]

    def _predict(self, m: np.ndarray, P: np.ndarray, S: np.ndarray | None, dt: float, theta: np.ndarray,
                 transition: bool = False, t_start: float = 0.0) -> tuple:
        """(m, P, S, Φ, Q̃) after ``dt`` from the time ``t_start`` (read for a time-varying SDE
        only): S the factor (square-root form, else None), Φ the transition of eq. (3) when
        ``transition`` (else None), and in the square-root form with ``transition`` the
        interval's effective noise Q̃ = P⁻ − Φ P Φᵀ of eq. (6) (else None)."""
        if self.exact:
            return self._exact(m, P, S, dt, theta)
        return self._integrate(m, P, S, dt, theta, transition, t_start)

    def _exact(self, m, P, S, dt, theta):
        """Eq. (4): F = e^{A dt}, c = ∫₀^dt e^{A s} b ds from one exponential, Q(dt) by Van Loan
        (Q̃ of eq. (6) in the square-root form)."""
        n = self.sde.n
        cm = self.compiled_drift
        g, J_nz, _ = cm.eval_derivatives(np.concatenate([np.zeros(n), theta])[None])
        A, b, D = cm.dense_jacobian(J_nz)[0, :n, :n], g[0, :n], g[0, n:].reshape(n, n)
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n] = A, b
        E = scipy.linalg.expm(M * dt)
        F, c = E[:n, :n], E[:n, n]
        _, Q = van_loan_numeric(A, D, dt)
        m1 = F @ m + c
        if S is not None:  # S⁻ = tria([F S, √Q(dt)]): the factor of F P Fᵀ + Q(dt), no difference formed
            S1 = _tria(np.hstack([F @ S, noise_factor(Q)]))
            return m1, S1 @ S1.T, S1, F, Q
        P1 = F @ P @ F.T + Q
        return m1, 0.5 * (P1 + P1.T), None, F, None

    def _integrate(self, m, P, S, dt, theta, transition=False, t_start=0.0):
        n = self.sde.n
        sqrt = S is not None
        tril = np.tril_indices(n)
        n_cov = len(tril[0]) if sqrt else n * n
        count = [0]
        # A time-invariant SDE is integrated over [0, dt] (its moments depend on dt alone, and
        # the times and dt routes give the same numbers bit for bit); a time-varying one over
        # [t_start, t_start + dt], the time the drift's last parameter.
        varying = not self.time_invariant
        t_lo = float(t_start) if varying else 0.0
        theta_t = np.append(theta, t_lo) if varying else theta

        def rhs(t_abs: float, z: np.ndarray) -> np.ndarray:
            count[0] += 1
            t = t_abs - t_lo  # the time into the interval, for the messages
            if varying:
                theta_t[-1] = t_abs
            theta = theta_t
            mt = z[:n]
            if count[0] > self.max_evaluations:
                raise _Stop(f"more than max_evaluations = {self.max_evaluations} evaluations of the moment "
                            "equations (a stiff or diverging drift)", t, mt)
            if not np.all(np.isfinite(z)):
                raise _Stop("the moments turned NaN or inf", t, mt)
            try:
                if sqrt:
                    St = np.zeros((n, n))
                    St[tril] = z[n:n + n_cov]
                    dm, dS, Y, Z, D = self._factor_rates(mt, St, theta)
                    parts = [dm, dS[tril]]
                    Pt = None
                else:
                    Pt = z[n:n + n_cov].reshape(n, n)
                    Pt = 0.5 * (Pt + Pt.T)
                    St = None if self.points is None else batch_sqrt(Pt[None])[0]  # the points' square root
                    dm, C, D, Y, Z = self._rule(mt, St, Pt, theta)
                    parts = [dm, (C + C.T + D).ravel()]
                if transition:
                    Ahat = self._linear_drift(St, Y, Z)
                    parts.append((Ahat @ z[n + n_cov:n + n_cov + n * n].reshape(n, n)).ravel())
                    if sqrt:  # eq. (6): dQ̃/dt = Â Q̃ + Q̃ Âᵀ + D, from Q̃ = 0
                        Qt = z[n + n_cov + n * n:].reshape(n, n)
                        parts.append((Ahat @ Qt + Qt @ Ahat.T + D).ravel())
            except (np.linalg.LinAlgError, SymmonError) as exc:
                raise _Stop(f"the covariance is no longer one ({exc})", t, mt) from None
            out = np.concatenate(parts)
            if not np.all(np.isfinite(out)):
                raise _Stop("the drift or its Jacobian is NaN or inf", t, mt)
            return out

        z0 = [m, S[tril] if sqrt else P.ravel()] + ([np.eye(n).ravel()] if transition else []) \
            + ([np.zeros(n * n)] if transition and sqrt else [])
        sol = scipy.integrate.solve_ivp(rhs, (t_lo, t_lo + dt), np.concatenate(z0), method="RK45", rtol=self.rtol,
                                        atol=self.atol, max_step=np.inf if self.max_step is None else self.max_step)
        if not sol.success:
            raise _Stop(f"the integrator failed: {sol.message}", float(sol.t[-1]) - t_lo, sol.y[:n, -1])
        z = sol.y[:, -1]
        if not np.all(np.isfinite(z)):
            raise _Stop("the moments turned NaN or inf", float(sol.t[-1]) - t_lo, z[:n])
        Phi = z[n + n_cov:n + n_cov + n * n].reshape(n, n) if transition else None
        if sqrt:
            S1 = np.zeros((n, n))
            S1[tril] = z[n:n + n_cov]
            if np.any(np.diag(S1) <= 0):
                raise _Stop("the factor S lost its positive diagonal", float(sol.t[-1]) - t_lo, z[:n])
            Qt = z[n + n_cov + n * n:].reshape(n, n) if transition else None
            return z[:n], S1 @ S1.T, S1, Phi, None if Qt is None else 0.5 * (Qt + Qt.T)
        P1 = z[n:n + n_cov].reshape(n, n)
        return z[:n], 0.5 * (P1 + P1.T), None, Phi, None

    def _stopped(self, stop: _Stop, dt: float, where: str) -> str:
        state = np.array2string(np.asarray(stop.m), precision=6)
        return (f"{self.method}: the prediction {where}over an interval dt = {dt:.6g} stopped at t = {stop.t:.6g} "
                f"into it, at the mean {state}: {stop.why}; shorten the interval, raise max_evaluations, "
                "or discretise the SDE (sde.discretize('local_linear', substeps=...)) for a discrete filter")

    # ----------------------------------------------------------------- the recursion
    def _filter(self, call: FilterCall) -> KalmanResult:
        return self._recursion(call)[0]

    def _recursion(self, call: FilterCall, transition: bool = False) -> tuple:
        """The filter's result, and with ``transition`` the transitions Φ (R, K, n, n) of eq. (3)
        over each interval and, in the square-root form, their effective noises Q̃ of eq. (6)
        (for the smoother; else None)."""
        n, n_y = self.sizes
        Y, runs, pv = call.Y, call.runs, call.pv
        R, K = Y.shape[0], Y.shape[1]
        names = [str(s) for s in self.params]
        j_dt = names.index(DT)
        n_theta = len(self.sde.params)
        h_names = [str(s) for s in self.update.params]
        h_cols = [names.index(s) for s in h_names]
        m = np.broadcast_to(call.x0, (R, n)).copy()
        P = np.broadcast_to(call.P0, (R, n, n)).copy()
        S = None
        if self.square_root:
            S = np.empty((R, n, n))
            for r in range(R):
                try:
                    S[r] = np.linalg.cholesky(P[r])
                except np.linalg.LinAlgError:
                    raise CovarianceError(f"{self.method}: P0{'' if runs is None else f' of run {r}'} must be positive "
                                          "definite (the square-root form integrates its Cholesky factor)") from None
        shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n), "innovation": (n_y,),
                  "S": (n_y, n_y), "nis": (), "loglik": ()}
        if self.square_root:
            shapes.update(P_chol=(n, n), P_pred_chol=(n, n))
        out = {k: np.empty((R, K) + s) for k, s in shapes.items()}
        Phi = np.empty((R, K, n, n)) if transition else None
        Qt = np.empty((R, K, n, n)) if transition and self.square_root else None
        starts = self._starts(call, pv[..., j_dt])
        # The compiled loop runs the whole bank; a run it hands back (failed[r] = k) goes on in
        # Python from step k, from the state its step k − 1 left (which names a failure).
        first = np.zeros(R, dtype=np.int64)
        failed = self._compiled_pass(m, S if S is not None else P, Y, pv, starts, out, Phi, Qt, transition)
        if failed is not None:
            first = np.where(failed < 0, K, failed)
            for r in np.flatnonzero((failed > 0)):
                k = failed[r] - 1
                m[r], P[r] = out["x"][r, k], out["P"][r, k]
                if S is not None:
                    S[r] = out["P_chol"][r, k]
        for k in range(int(first.min()) if R else K, K):
            rows = np.flatnonzero(first <= k)
            for r in rows:
                dt = float(pv[r, k, j_dt])
                try:
                    m[r], P[r], S_r, Phi_r, Qt_r = self._predict(m[r], P[r], None if S is None else S[r], dt,
                                                           pv[r, k, :n_theta], transition, float(starts[r, k]))
                except (_Stop, np.linalg.LinAlgError) as stop:
                    if not isinstance(stop, _Stop):
                        stop = _Stop(f"the covariance is not positive definite ({stop})", 0.0, m[r])
                    where = f"to step {k} " if runs is None else f"to step {k} of run {r} "
                    raise SymmonError(self._stopped(stop, dt, where)) from None
                if S is not None:
                    S[r] = S_r
                if transition:
                    Phi[r, k] = Phi_r
                    if Qt is not None:
                        Qt[r, k] = Qt_r
            params = {s: pv[rows, k, c][:, None] for s, c in zip(h_names, h_cols)} or None
            step = self._update(Y[rows, k:k + 1], m[rows], (P if S is None else S)[rows], params, k, runs, rows)
            for key in out:
                out[key][rows, k] = step[key][:, 0]
            m[rows], P[rows] = out["x"][rows, k], out["P"][rows, k]
            if S is not None:
                S[rows] = out["P_chol"][rows, k]
        nees = None if call.truth is None else nees_of(out["x"], out["P"], call.truth, sorted(self.angle_states))
        kept = call.keep
        arrays = {key: v for key, v in out.items()
                  if key == "loglik" or kept is None or key.removesuffix("_chol") in kept}
        if nees is not None:
            arrays["nees_values"] = nees
        if runs is None:
            arrays = {key: v[0] for key, v in arrays.items()}
        for v in arrays.values():
            v.flags.writeable = False
        measured = None
        if np.isnan(Y).any():
            measured = readonly((~np.isnan(Y if runs is not None else Y[0])).sum(axis=-1))
        arrays["nis_values"] = arrays.pop("nis", None)
        return KalmanResult(**arrays, measured=measured, n_y=n_y, n_x=n, angle_states=tuple(sorted(self.angle_states)),
                            method=self.method), Phi, Qt

    def _kernel(self) -> CompiledCD | None:
        """The compiled loop of this filter (:mod:`symmon.filters.gaussian._cdkernel`), or None:
        ``integrator="solve_ivp"``, the exact prediction, or no compiler (the compile policy)."""
        if self.integrator == "solve_ivp" or self.exact or not has_compiler():
            return None
        sde, upd = self.sde, self.update
        tparams = list(self.drift_model.params)
        key = (self.drift_model, self.h, self.transform, self.angle_states, self.square_root)
        return compiled_cd(key, list(sde.states), list(sde.drift), list(self.drift_model.outputs[sde.n:]), tparams,
                           upd.f_model, upd.h_model, self.transform, self.angle_states, tuple(upd.params),
                           self.square_root, not self.time_invariant, self.points)

    @property
    def evaluator(self) -> str:
        """What integrates the moment equations: ``"compiled"`` (the Dormand–Prince loop in C
        over the whole bank), ``"solve_ivp"`` (Python: ``integrator="solve_ivp"``, no compiler,
        or the exact prediction, ``"exact"``) or ``"solve_ivp (C build running)"``."""
        if self.exact:
            return "exact"
        kernel = self._kernel()
        if kernel is None:
            return "solve_ivp"
        return {"compiled": "compiled", "vm": "solve_ivp"}.get(kernel.evaluator, "solve_ivp (C build running)")

    def wait_compiled(self, timeout: float | None = None) -> str:
        """Wait for the compiled loop's C build, if one runs in the background (at most
        ``timeout`` seconds); :attr:`evaluator` then."""
        kernel = self._kernel()
        if kernel is not None:
            kernel.wait(timeout)
        return self.evaluator

    def _compiled_pass(self, m: np.ndarray, P: np.ndarray, Y: np.ndarray, pv: np.ndarray, starts: np.ndarray,
                       out: dict, Phi: np.ndarray | None, Qt: np.ndarray | None, transition: bool) -> np.ndarray | None:
        """Every run and step in the compiled loop, written into ``out``, ``Phi`` and ``Qt``
        (``P``: the factors in the square-root form); the step at which each run stopped
        (or -1), or None when there is no compiled loop (yet)."""
        kernel = self._kernel()
        if kernel is None:
            return None
        names = [str(s) for s in self.params]
        n_theta = len(self.sde.params)
        h_cols = [names.index(str(s)) for s in self.update.params]
        arrays = dict(out, Phi=Phi, Qt=Qt)
        if self.square_root:
            arrays["P"] = arrays["P_pred"] = None  # formed from the factors below
        tol = (self.rtol, self.atol, np.inf if self.max_step is None else self.max_step)
        failed = kernel(m, P, Y, pv[..., :n_theta], pv[..., h_cols], pv[..., names.index(DT)], starts, self.update.R,
                        arrays, tol, self.max_evaluations, transition)
        if failed is not None and self.square_root:
            for key in ("P", "P_pred"):
                Sk = out[key + "_chol"]
                out[key][...] = np.matmul(Sk, np.swapaxes(Sk, -1, -2))
        return failed

    def _starts(self, call: FilterCall, dts: np.ndarray) -> np.ndarray:
        """The start time t_{k−1} of each interval, (R, K): ``t0`` and the measurement times
        before each when the call has times, else the cumulative sums of the intervals ``dts``
        (R, K) from 0 (the ``dt`` route: x0 at t = 0).  Zeros for a time-invariant SDE, whose
        moments do not read them."""
        R, K = dts.shape
        if self.time_invariant:
            return np.zeros((R, K))
        if call.times is not None:
            T = np.broadcast_to(np.asarray(call.times, float), (R, K))
            return np.concatenate([np.full((R, 1), float(call.t0)), T[:, :-1]], axis=1)
        return np.concatenate([np.zeros((R, 1)), np.cumsum(dts, axis=1)[:, :-1]], axis=1)

    def _update(self, Y: np.ndarray, m: np.ndarray, P: np.ndarray, params: dict | None, k: int,
                runs: int | None, rows: np.ndarray) -> dict[str, np.ndarray]:
        """The measurement update of the runs ``rows`` at step ``k`` (the identity's prediction,
        then the discrete filter's update); ``P`` the factors S in the square-root form, which the
        compiled square-root step reads as they are (no covariance formed and factored again)."""
        upd = self.update
        if not self.square_root:
            step = upd.filter(Y, m, P, params=params)
            return {key: (step.nis_values if key == "nis" else getattr(step, key)) for key in
                    ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis", "loglik")}
        compiled = compiled_step(upd.f_model, upd.h_model, upd.transform, upd.angle_states, 1, True)
        pv = None
        if upd.params:
            pv = np.stack([np.asarray(params[str(s)], float) for s in upd.params], axis=-1)
        out = compiled(m, P, Y, upd.Q, upd.R, params=pv, check_finite=True, factored=True)
        bad = out.pop("first_nonfinite")
        if (bad >= 0).any():
            r = int(rows[np.argmax(bad >= 0)])
            where = f"step {k}" if runs is None else f"run {r}, step {k}"
            raise SymmonError(f"{self.method}: the update produced NaN or inf at {where} (the innovation covariance "
                              "is singular, or h is undefined at the prediction)")
        return out

    # ----------------------------------------------------------------- the smoother
    def smooth(self, ys: ArrayLike, x0: Any, P0: ArrayLike | None = None, *, keep: Iterable[str] | str | None = None,
               params: dict | None = None, times: ArrayLike | None = None, t0: float = 0.0) -> SmootherResult:
        """The Rauch–Tung–Striebel smoother of this filter: a forward pass that integrates the
        transition Φ of each interval with the moments (eq. (3)), then the discrete backward
        pass (5) on the stored x, P, x⁻, P⁻ and Φ.

        On a linear SDE, Φ is e^{A dt} and C = P Φᵀ the exact cross-covariance, so this is the
        RTS smoother of the exact discretisation (to the integrator's tolerance); on a
        nonlinear one it is the Gaussian smoother with the statistically linearised flow
        (the CD-EKF's Jacobian for TT1).  The forward pass integrates Φ beside the moments,
        so its adaptive steps (and its numbers, within the tolerance) can differ from
        :meth:`filter`'s; ``filtered`` holds that pass.  In the square-root form the forward
        pass also integrates each interval's effective noise Q̃ (eq. (6)) and the backward
        pass is eq. (7) on the factors, returning them (``P_chol``) as
        :meth:`NonlinearKalmanFilter.smooth <symmon.NonlinearKalmanFilter.smooth>` does.

        Parameters
        ----------
        ys, x0, P0, params, times, t0
            As for :meth:`filter`.
        keep : str or iterable of str, optional
            What the forward pass keeps, as for :meth:`filter` (default: all); ``x``, ``P``,
            ``x_pred`` and ``P_pred`` are always kept, since the backward pass reads them.

        Returns
        -------
        SmootherResult
            ``x`` (K, n) and ``P`` (K, n, n) smoothed ((R, K, ...) for a bank),
            ``filtered``, the forward pass, and in the square-root form ``P_chol``, the
            smoothed lower factors (P = S Sᵀ; None otherwise).

        Raises
        ------
        SymmonError
            A singular predicted covariance (naming the run and step), and the errors of
            :meth:`filter`.
        """
        kept = None if keep is None else frozenset([keep] if isinstance(keep, str) else keep)
        forward = None if kept is None else kept | {"x", "P", "x_pred", "P_pred"}
        call = check_call(self, ys, x0, P0, keep=forward, params=params, times=times, t0=t0)
        fwd, Phi, Qt = self._recursion(call, transition=True)
        bank = fwd.runs is not None
        x, P, xp, Pp = (getattr(fwd, a) if bank else getattr(fwd, a)[None] for a in ("x", "P", "x_pred", "P_pred"))
        angles = sorted(self.angle_states)
        xs, Ps = x.copy(), P.copy()
        K = x.shape[1]
        Ss = None
        if self.square_root:
            S = fwd.P_chol if bank else fwd.P_chol[None]
            Ss = S.copy()
        for r in range(x.shape[0]):
            for k in range(K - 2, -1, -1):
                if Ss is not None:
                    try:
                        xs[r, k], Ss[r, k] = self._sqrt_backward(x[r, k], S[r, k], xp[r, k + 1], Phi[r, k + 1],
                                                                 Qt[r, k + 1], xs[r, k + 1], Ss[r, k + 1], angles)
                    except (np.linalg.LinAlgError, CovarianceError):
                        where = f"step {k}" if not bank else f"run {r}, step {k}"
                        raise SymmonError(f"{self.method} smoother: the predicted covariance of step {k + 1} is "
                                          f"singular (at {where})") from None
                    Ps[r, k] = Ss[r, k] @ Ss[r, k].T
                    continue
                C = P[r, k] @ Phi[r, k + 1].T  # Cov(x_k, x_{k+1}⁻) of eq. (5)
                try:
                    G = np.linalg.solve(Pp[r, k + 1], C.T).T
                except np.linalg.LinAlgError:
                    where = f"step {k}" if not bank else f"run {r}, step {k}"
                    raise SymmonError(f"{self.method} smoother: the predicted covariance of step {k + 1} is singular "
                                      f"(at {where})") from None
                d = wrap_components(xs[r, k + 1] - xp[r, k + 1], angles) if angles else xs[r, k + 1] - xp[r, k + 1]
                xs[r, k] = x[r, k] + G @ d
                if angles:
                    xs[r, k] = wrap_components(xs[r, k], angles)
                Psk = P[r, k] + G @ (Ps[r, k + 1] - Pp[r, k + 1]) @ G.T
                Ps[r, k] = 0.5 * (Psk + Psk.T)
        if not all_finite(xs, Ps):
            raise SymmonError(f"{self.method} smoother: NaN or inf in the backward pass")
        if not bank:
            xs, Ps, Ss = xs[0], Ps[0], None if Ss is None else Ss[0]
        for a in (xs, Ps, Ss):
            if a is not None:
                a.flags.writeable = False
        return SmootherResult(xs, Ps, fwd, angle_states=tuple(angles), method=self.method, P_chol=Ss)

    @staticmethod
    def _sqrt_backward(x: np.ndarray, S: np.ndarray, x_pred: np.ndarray, Phi: np.ndarray, Qt: np.ndarray,
                       xs_next: np.ndarray, Ss_next: np.ndarray, angles: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """One backward step of eq. (7): (x^s_k, S^s_k) from the filtered factor S_k, the
        interval's Φ and Q̃, and the next smoothed (x^s_{k+1}, S^s_{k+1}).

        Raises
        ------
        numpy.linalg.LinAlgError
            A singular predicted factor tria(Y)."""
        A = Phi @ S
        Qf = matrix_sqrt(Qt)
        Y = np.hstack([A, Qf])  # the joint columns of x_{k+1}; those of x_k are [S, 0]
        Sy = _tria(Y)
        if np.any(np.diag(Sy) <= 0):
            raise np.linalg.LinAlgError("the predicted factor has a zero on its diagonal")
        # G = C (Sy Syᵀ)⁻¹ with C = S Aᵀ = P Φᵀ: two triangular solves, no inverse of P⁻.
        G = scipy.linalg.solve_triangular(Sy, scipy.linalg.solve_triangular(Sy, A @ S.T, lower=True),
                                          lower=True, trans="T").T
        d = xs_next - x_pred
        if angles:
            d = wrap_components(d, angles)
        xs = x + G @ d
        if angles:
            xs = wrap_components(xs, angles)
        return xs, _tria(np.hstack([S - G @ A, -G @ Qf, G @ Ss_next]))


def _tria(A: np.ndarray) -> np.ndarray:
    """The lower triangular L with L Lᵀ = A Aᵀ and a non-negative diagonal (a QR of Aᵀ)."""
    r = np.linalg.qr(A.T, mode="r")
    L = r[:A.shape[0]].T
    return L * np.where(np.diag(L) < 0, -1.0, 1.0)


def continuous_filter(sde: SDE, h_model: Model, Q: Any = None, R: Any = None, transform: Any = None,
                      iterations: int = 1, square_root: bool = False, **settings: Any) -> ContinuousDiscreteKalmanFilter:
    """``sm.NonlinearKalmanFilter(sde, h, None, R, transform)``: the continuous-discrete filter
    of the SDE with the discrete filter's spelling (its default rule, ``UT.ut1()``; the
    integrator's settings, ``rtol=`` …, as keywords).

    Raises
    ------
    ArgumentError
        ``Q`` given (the SDE's diffusion and spectral density give the noise), or
        ``iterations`` other than 1 (no iterated update of an SDE).
    """
    if Q is not None:
        raise ArgumentError(f"Q must be None for an SDE: its noise is the SDE's diffusion and spectral density "
                            f"(SDE {sde.name!r}), integrated over each interval; got Q = {plain_repr(Q)}")
    if not (isinstance(iterations, (int, np.integer)) and not isinstance(iterations, bool) and iterations == 1):
        raise ArgumentError(f"iterations must be 1 for an SDE (the continuous-discrete filters have no iterated "
                            f"update), got {plain_repr(iterations)}")
    if transform is None:
        from ...transforms.unscented import UT  # the discrete filter's default rule
        transform = UT.ut1()
    return ContinuousDiscreteKalmanFilter(sde, h_model, R, transform, square_root=square_root, **settings)


def continuous_kalman_filter(sde: SDE, Q: Any = None, H: Any = None, R: Any = None,
                             **settings: Any) -> ContinuousDiscreteKalmanFilter:
    """``sm.KalmanFilter(sde, None, H, R)``: the Kalman filter of a linear SDE measured by the
    matrix H, by the exact transition over each interval (eq. (4); ``exact=True``, TT1).

    Raises
    ------
    ArgumentError
        ``Q`` given (the SDE gives the noise).
    ModelError
        A nonlinear SDE (its CD-EKF is ``sm.NonlinearKalmanFilter(sde, h, None, R, "ekf")``).
    ShapeError
        H not (n_y, n) with n the SDE's states.
    """
    if Q is not None:
        raise ArgumentError(f"Q must be None for an SDE: its noise is the SDE's diffusion and spectral density "
                            f"(SDE {sde.name!r}), Q(dt) by Van Loan at each interval; got Q = {plain_repr(Q)}")
    if not sde.is_linear:
        raise ModelError(f"KalmanFilter needs a linear SDE (a = A x + b, L constant); SDE {sde.name!r} is not: its "
                         "continuous-discrete EKF is sm.NonlinearKalmanFilter(sde, h, None, R, 'ekf')")
    if not sde.is_time_invariant:
        raise ModelError(f"KalmanFilter of an SDE takes the exact transition e^(A dt), which a time-varying SDE "
                         f"({sde.name!r} depends on {sde.time}) has not: its continuous-discrete EKF, "
                         "sm.NonlinearKalmanFilter(sde, h, None, R, 'ekf'), integrates the moment equations with the "
                         "absolute time (exact for a linear SDE to the integrator's tolerance)")
    Hm = np.atleast_2d(np.asarray(H, dtype=float)) if H is not None else None
    if Hm is None or Hm.ndim != 2 or Hm.shape[1] != sde.n or not np.all(np.isfinite(Hm)):
        raise ShapeError(f"H must be a finite (n_y, {sde.n}) matrix for an SDE of {sde.n} states, got "
                         f"{plain_repr(H)}")
    states = sp.Matrix(sde.states)
    h = Model(list(sde.states), list(sp.Matrix(Hm.tolist()) * states), name=f"{sde.name}_H")
    return ContinuousDiscreteKalmanFilter(sde, h, R, "ekf", exact=True, **settings)


# NonlinearKalmanFilter(sde, ...) and KalmanFilter(sde, ...) build these (Filter.__new__).
register_sde_builder("NonlinearKalmanFilter", continuous_filter)
register_sde_builder("KalmanFilter", continuous_kalman_filter)
