"""The continuous-discrete Gaussian filters: an SDE between measurement times, discrete
measurements at them.

The state follows dx = a(x) dt + L(x) dβ, E[dβ dβᵀ] = Q_c dt (:class:`~symmon.SDE`), and is
measured at times t_1 < t_2 < … as y_k = h(x(t_k), e_k), e_k ~ N(0, R).  Between two
measurements the filter integrates the moment equations of the Gaussian approximation
N(m(t), P(t)) (Särkkä 2007; Särkkä & Solin 2019, §9.1),

    dm/dt = E[a(x)],
    dP/dt = E[a(x) (x − m)ᵀ] + E[(x − m) a(x)ᵀ] + E[L(x) Q_c L(x)ᵀ],

with the expectations over N(m, P) by the filter's rule:

- TT1 (``"ekf"``), the continuous-discrete EKF: dm/dt = a(m), dP/dt = A P + P Aᵀ + L Q_c Lᵀ
  with A = ∂a/∂x and L at m;
- a point rule (``"ukf"``, ``"ckf"``, ``"ghkf"``, any rule with a unit rule): the sigma-point
  form, points χᵢ = m + S zᵢ (S Sᵀ = P), dm/dt = Σ wᵢᵐ a(χᵢ),
  dP/dt = C + Cᵀ + Σ wᵢᵐ L Q_c Lᵀ(χᵢ) with C = Σ wᵢᶜ (χᵢ − m)(a(χᵢ) − dm/dt)ᵀ.

a(x), its Jacobian and L Q_c Lᵀ are one compiled CasADi model of the SDE's symbols
(:func:`symmon.compile.compiled.compiled_with_params`).  The equations are integrated by
``scipy.integrate.solve_ivp`` (explicit Runge–Kutta 4(5), adaptive steps, ``rtol`` and
``atol``); an interval that needs more than ``max_evaluations`` evaluations of the right-hand
side (a stiff or diverging drift), or whose moments turn NaN or inf, raises
:class:`~symmon.errors.SymmonError` naming the step, the run and the state.  The measurement
update at each t_k is that of :class:`~symmon.NonlinearKalmanFilter` with the same rule
(missing components, angles and the log-likelihood as there).

Measurement times.  The filter declares ``continuous_time``: ``filter(ys, x0, times=ts)``
takes the measurement times t_1 < … < t_K (after ``t0``, the time of ``x0``, default 0; (K,),
or (R, K) per run for a bank), and the interval before measurement k is t_k − t_{k−1}
(t_0 = ``t0``).  The alternative is the per-step parameter ``dt`` (``params={"dt": steps}``:
a number for regular sampling, one per step (K,) or one per run and step (R, K) for
irregular times, strictly positive; ``x0`` is then at t = 0); the two routes give the same
numbers bit for bit for the same intervals, and giving both is refused.  The SDE is
time-invariant, so an interval's moments depend on its length only.

Banks: each run is integrated on its own (its own adaptive steps, so that a bank filtered in
shards gives the whole bank's numbers bit for bit); the measurement updates of all the runs
are one compiled call per step.

References
----------
S. Särkkä, "On unscented Kalman filtering for state estimation of continuous-time nonlinear
systems", IEEE Trans. Autom. Control 52(9), 2007. doi:10.1109/TAC.2007.904453
S. Särkkä, A. Solin, *Applied Stochastic Differential Equations*, Cambridge University Press,
2019, ch. 9 and 10.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import scipy.integrate
import sympy as sp

from ...compile.compiled import CompiledModel, compiled_with_params
from ...core.arrays import readonly
from ...core.checks import check_model
from ...core.model import Model
from ...core.sde import SDE
from ...errors import ArgumentError, ArgumentTypeError, ModelError, ShapeError, SymmonError, plain_repr
from ...transforms.base import batch_sqrt
from ...transforms.base import Transform
from ..base import Filter
from ..inputs import FilterCall, filter_params, param_values
from ..names import filter_rule
from ..results import KalmanResult, nees_of
from .nonlinear import NonlinearKalmanFilter

__all__ = ["ContinuousDiscreteKalmanFilter", "DT", "MAX_EVALUATIONS"]

#: The name of the per-step parameter that gives the interval before each measurement.
DT = "dt"
#: The default bound on the evaluations of the moment equations' right-hand side per interval.
MAX_EVALUATIONS = 20_000


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
        The dynamics dx = a(x) dt + L(x) dβ with spectral density Q_c; its angle states are
        the filter's.
    h : Model
        The measurement model, with the SDE's states as inputs (n inputs, n_y outputs).
    R : array_like
        Measurement noise covariance (Cov e, or additive (n_y, n_y)).
    transform : str or Transform, default ``"ekf"``
        The rule of the expectations and of the update: ``"ekf"`` (TT1: the CD-EKF),
        ``"ukf"``, ``"ckf"``, ``"ghkf"``, or a rule with points (``UT(...)``,
        ``GaussHermite(order)``).
    rtol, atol : float, default 1e-6 and 1e-9
        The tolerances of the adaptive integrator (``scipy.integrate.solve_ivp``) on m and P.
    max_step : float, optional
        The largest integration step (default: unbounded).
    max_evaluations : int, default :data:`MAX_EVALUATIONS`
        The most evaluations of the right-hand side in one interval; beyond it the filter
        raises (a stiff or diverging drift) instead of running on.

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
    update: NonlinearKalmanFilter = field(init=False, repr=False)
    drift_model: Model = field(init=False, repr=False)
    points: tuple | None = field(init=False, repr=False)

    has_smoother: ClassVar[bool] = False
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
        states = list(sde.states)
        # The update: the NonlinearKalmanFilter of the same rule whose prediction is the identity
        # without noise (exact for every rule), so that its update, likelihood, missing
        # components and angles are the discrete filter's.
        ident = Model(states, states, name=f"{sde.name}_identity", angles=sorted(sde.angles))
        update = NonlinearKalmanFilter(ident, h, np.zeros((sde.n, sde.n)), self.R, tr)
        D = sde.diffusion * sde.spectral_density * sde.diffusion.T
        drift = Model(states, list(sde.drift) + list(D), name=f"{sde.name}_moments", params=list(sde.params))
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
        """The rule's cost for one evaluation of the moment equations and for the update: a
        lower bound (the adaptive integrator evaluates them as often as its tolerance needs)."""
        return int(self.transform.cost(self.sizes[0])) + int(self.transform.cost(self.sizes[0]))

    @property
    def params(self) -> tuple:
        """The SDE's parameters, then ``dt``, then h's that the SDE has not."""
        dt = sp.Symbol(DT, positive=True)
        return filter_params(Model(list(self.sde.states), list(self.sde.states), params=[*self.sde.params, dt]),
                             self.h)

    @property
    def method(self) -> str:
        """``CD-`` and the discrete filter's name: CD-EKF, CD-CKF, CD-UKF(…), CD-GHKF(…)."""
        return "CD-" + self.update.method

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

    def moment_derivatives(self, m: np.ndarray, P: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(dm/dt, dP/dt) at the Gaussian N(m, P) with the SDE's parameters ``theta``, by the
        filter's rule (module notes)."""
        n = self.sde.n
        cm = self.compiled_drift
        if self.transform.taylor_order == 1:  # TT1: a(m) and its Jacobian
            W = np.concatenate([m, theta])[None]
            g, J_nz, _ = cm.eval_derivatives(W)
            A = cm.dense_jacobian(J_nz)[0, :n, :n]
            dP = A @ P
            return g[0, :n], dP + dP.T + g[0, n:].reshape(n, n)
        Z, wm, wc = self.points
        X = m + Z @ batch_sqrt(P[None])[0].T
        W = np.concatenate([X, np.broadcast_to(theta, (X.shape[0], theta.shape[0]))], axis=1)
        G = cm.eval_g(np.ascontiguousarray(W))
        a = G[:, :n]
        dm = wm @ a
        C = (X - m).T @ (wc[:, None] * (a - dm))
        return dm, C + C.T + (wm @ G[:, n:]).reshape(n, n)

    def predict(self, m: np.ndarray, P: np.ndarray, dt: float, theta: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """The moments (m, P) integrated over an interval ``dt`` from (m, P).

        Raises
        ------
        SymmonError
            More than ``max_evaluations`` evaluations (a stiff or diverging drift), a failed
            step-size control, or moments that turn NaN or inf, naming the time and the mean.
        """
        try:
            return self._integrate(np.asarray(m, float), np.asarray(P, float), float(dt),
                                   np.zeros(0) if theta is None else np.asarray(theta, float))
        except _Stop as stop:
            raise SymmonError(self._stopped(stop, dt, "")) from None

    def _integrate(self, m: np.ndarray, P: np.ndarray, dt: float, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = self.sde.n
        count = [0]

        def rhs(t: float, z: np.ndarray) -> np.ndarray:
            count[0] += 1
            mt = z[:n]
            if count[0] > self.max_evaluations:
                raise _Stop(f"more than max_evaluations = {self.max_evaluations} evaluations of the moment "
                            "equations (a stiff or diverging drift)", t, mt)
            Pt = z[n:].reshape(n, n)
            if not np.all(np.isfinite(z)):
                raise _Stop("the moments turned NaN or inf", t, mt)
            try:
                dm, dP = self.moment_derivatives(mt, 0.5 * (Pt + Pt.T), theta)
            except (np.linalg.LinAlgError, SymmonError) as exc:
                raise _Stop(f"the covariance is no longer one ({exc})", t, mt) from None
            out = np.concatenate([dm, dP.ravel()])
            if not np.all(np.isfinite(out)):
                raise _Stop("the drift or its Jacobian is NaN or inf", t, mt)
            return out

        z0 = np.concatenate([m, P.ravel()])
        sol = scipy.integrate.solve_ivp(rhs, (0.0, dt), z0, method="RK45", rtol=self.rtol, atol=self.atol,
                                        max_step=np.inf if self.max_step is None else self.max_step)
        if not sol.success:
            raise _Stop(f"the integrator failed: {sol.message}", float(sol.t[-1]), sol.y[:n, -1])
        z = sol.y[:, -1]
        if not np.all(np.isfinite(z)):
            raise _Stop("the moments turned NaN or inf", float(sol.t[-1]), z[:n])
        P1 = z[n:].reshape(n, n)
        return z[:n], 0.5 * (P1 + P1.T)

    def _stopped(self, stop: _Stop, dt: float, where: str) -> str:
        state = np.array2string(np.asarray(stop.m), precision=6)
        return (f"{self.method}: the prediction {where}over an interval dt = {dt:.6g} stopped at t = {stop.t:.6g} "
                f"into it, at the mean {state}: {stop.why}; shorten the interval, raise max_evaluations, "
                "or discretise the SDE (sde.discretize('local_linear', substeps=...)) for a discrete filter")

    # ----------------------------------------------------------------- the recursion
    def _filter(self, call: FilterCall) -> KalmanResult:
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
        out = {k: np.empty((R, K) + s) for k, s in (("x", (n,)), ("P", (n, n)), ("x_pred", (n,)),
                                                     ("P_pred", (n, n)), ("innovation", (n_y,)),
                                                     ("S", (n_y, n_y)), ("nis", ()), ("loglik", ()))}
        for k in range(K):
            for r in range(R):
                dt = float(pv[r, k, j_dt])
                try:
                    m[r], P[r] = self._integrate(m[r], P[r], dt, pv[r, k, :n_theta])
                except _Stop as stop:
                    where = f"to step {k} " if runs is None else f"to step {k} of run {r} "
                    raise SymmonError(self._stopped(stop, dt, where)) from None
            params = {s: pv[:, k, c][:, None] for s, c in zip(h_names, h_cols)} or None
            step = self.update.filter(Y[:, k:k + 1], m, P, params=params)
            for key in out:
                value = step.nis_values if key == "nis" else getattr(step, key)
                out[key][:, k] = value[:, 0]
            m, P = out["x"][:, k].copy(), out["P"][:, k].copy()
        nees = None if call.truth is None else nees_of(out["x"], out["P"], call.truth, sorted(self.angle_states))
        kept = call.keep
        arrays = {key: v for key, v in out.items() if key == "loglik" or kept is None or key in kept}
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
                            method=self.method)
