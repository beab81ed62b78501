"""Maximum-likelihood fit of model parameters through the filter's log-likelihood.

The marginal log-likelihood of the measurements, ℓ(θ) = Σ_runs Σ_k log N(ν_k; 0, S_k), is
what the filter step computes (the prediction-error decomposition).  :func:`fit` builds ℓ as
one CasADi graph of the named parameters θ: the filter's own step function (the same graph
as :mod:`symmon.filters.step`) folded over the K steps (``mapaccum``) and mapped over the runs
of a bank, so its gradient and its Hessian are exact (CasADi's algorithmic differentiation
through every step; no finite differences).  SciPy's quasi-Newton method (L-BFGS-B, with
bounds) maximises ℓ; the standard errors are the square roots of the diagonal of the inverse
observed information, I = −∇²ℓ(θ̂) (exact Hessian).

References
----------
J. D. Hamilton, *Time Series Analysis*, Princeton University Press, 1994, §13.4 (the
prediction-error decomposition and maximum likelihood with a Kalman filter).
S. Särkkä, *Bayesian Filtering and Smoothing*, Cambridge University Press, 2013, §12.2
(parameter estimation with Gaussian filters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from scipy import optimize

from ..core.gaussian import float_array
from ..errors import ModelError, SymmonError
from .results import KalmanResult, real_measurements
from .step import _compiled_step

if TYPE_CHECKING:  # pragma: no cover - annotations only
    from .nonlinear import NonlinearKalmanFilter

__all__ = ["FitResult", "fit_parameters", "MAX_ITER"]


@dataclass(frozen=True, eq=False)
class FitResult:
    """The result of :meth:`NonlinearKalmanFilter.fit <symmon.NonlinearKalmanFilter.fit>`.

    Attributes
    ----------
    estimates : dict
        θ̂, by parameter name.
    std_errors : dict
        sqrt(diag(I⁻¹)) with I = −∇²ℓ(θ̂), the observed information (exact Hessian).
    covariance : ndarray, shape (m, m)
        I⁻¹, in the order of ``estimates``.
    log_likelihood : float
        ℓ(θ̂), summed over the runs of a bank.
    iterations : int
        Iterations of the optimiser.
    params : dict
        Every parameter's value at the optimum (the fitted ones and the fixed ones), ready
        for ``kf.filter(..., params=result.params)``.
    filtered : KalmanResult
        The filter at the fitted values.
    at_bound : tuple of str
        Fitted parameters that ended on a bound (their standard errors are then only local).
    """

    estimates: dict
    std_errors: dict
    covariance: np.ndarray
    log_likelihood: float
    iterations: int
    params: dict
    filtered: KalmanResult
    at_bound: tuple = ()
    kf: Any = None

    @property
    def filter(self) -> "NonlinearKalmanFilter":
        """The filter with the fitted values substituted into its models (constant parameters).

        Raises
        ------
        SymmonError
            If a parameter has a value per step or per run (keep ``kf`` and pass ``params``).
        """
        if any(np.ndim(v) for v in self.params.values()):
            raise SymmonError("a parameter has a value per step or per run: use kf.filter(..., params=fit.params)")
        kf = self.kf
        f = kf.f_model.with_params({str(s): self.params[str(s)] for s in kf.f_model.params})
        h = kf.h_model.with_params({str(s): self.params[str(s)] for s in kf.h_model.params})
        # The filter's class: nonlinear imports this module.
        return type(kf)(f, h, kf.Q, kf.R, kf.transform, iterations=kf.iterations, square_root=kf.square_root)

    def __repr__(self) -> str:
        parts = ", ".join(f"{k} = {v:.6g} ± {self.std_errors[k]:.2g}" for k, v in self.estimates.items())
        return f"FitResult({parts}; log-likelihood {self.log_likelihood:.6g}, {self.iterations} iterations)"


def _loglik_graph(kf: "NonlinearKalmanFilter", Y: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                  base: np.ndarray, fitted: list[int]) -> tuple[ca.MX, ca.MX]:
    """θ (the fitted parameters) and ℓ(θ) as an MX graph: the step folded over K, mapped over R."""
    step = _compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states, kf.iterations).f
    runs, K, n_y = Y.shape
    n, n_p = kf.f_model.n_u, base.shape[-1]
    s = ca.MX.sym("s", n + n * n)
    d = ca.MX.sym("d", 2 * n_y + n_p)
    out = step(s[:n], ca.reshape(s[n:], n, n), d[:n_y], ca.DM(kf.Q), ca.DM(kf.R), d[n_y:2 * n_y], d[2 * n_y:])
    one = ca.Function("one_step", [s, d], [ca.vertcat(out[0], ca.vec(out[1])), out[6]])
    acc = one.mapaccum("steps", K)
    S0, D = ca.MX.sym("s0", n + n * n), ca.MX.sym("D", 2 * n_y + n_p, K)
    run_ll = ca.Function("run", [S0, D], [ca.sum2(acc(S0, D)[1])])
    theta = ca.MX.sym("theta", len(fitted))
    measured = ~np.isnan(Y)
    data = np.concatenate([np.where(measured, Y, 0.0), measured.astype(float), base], axis=2)  # (R, K, ·)
    sel = np.zeros((n_p, len(fitted)))
    sel[fitted, np.arange(len(fitted))] = 1.0
    keep = np.ones(2 * n_y + n_p)
    keep[2 * n_y + np.array(fitted, dtype=int)] = 0.0
    # Each run's data columns, with the fitted rows replaced by θ (the same at every step).
    Ds = [ca.diag(ca.DM(keep)) @ ca.DM(data[r].T)
          + ca.repmat(ca.vertcat(ca.DM.zeros(2 * n_y, 1), ca.mtimes(ca.DM(sel), theta)), 1, K) for r in range(runs)]
    x0r = np.broadcast_to(x0, (runs, n))
    P0r = np.broadcast_to(P0, (runs, n, n))
    S0s = ca.horzcat(*[ca.DM(np.concatenate([x0r[r], P0r[r].T.ravel()])) for r in range(runs)])
    total = ca.sum2(run_ll.map(runs)(S0s, ca.horzcat(*Ds)))
    return theta, total


#: The most iterations of the optimiser a fit may ask for.
MAX_ITER = 100_000


def _number(v: Any, what: str) -> float:
    """``v`` as a real number (not NaN), or a ModelError naming ``what``."""
    x = float_array(v, what, ModelError)
    if x.ndim != 0 or np.isnan(x):
        raise ModelError(f"{what} must be a number, got {v!r}")
    return float(x)


def fit_parameters(kf: "NonlinearKalmanFilter", ys, x0, start: dict, P0=None, *, params: dict | None = None,
                   bounds: dict | None = None, max_iter: int = 200, gtol: float = 1e-6) -> FitResult:
    """The maximum-likelihood estimates of the parameters named in ``start``
    (:meth:`NonlinearKalmanFilter.fit`, whose docstring gives the parameters)."""
    names = [str(q) for q in kf.params]
    if not names:
        raise ModelError("the filter's models declare no parameters to fit (Model(..., params=[...]))")
    if not isinstance(start, dict) or not start:
        raise ModelError(f"start must be a dict of starting values of some of {names}, got {start!r}")
    for what, d in (("params", params), ("bounds", bounds)):
        if d is not None and not isinstance(d, dict):
            raise ModelError(f"{what} must be a dict by parameter name, got {type(d).__name__}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or not 1 <= max_iter <= MAX_ITER:
        raise ModelError(f"max_iter must be an integer from 1 to {MAX_ITER}, got {max_iter!r}")
    fitted_names = [str(k) for k in start]
    unknown = sorted(set(fitted_names) - set(names))
    if unknown:
        raise ModelError(f"cannot fit {unknown}: the filter's parameters are {names}")
    fixed = {str(k): v for k, v in (params or {}).items()}
    both = sorted(set(fixed) & set(fitted_names))
    if both:
        raise ModelError(f"parameters {both} are both fitted (start) and fixed (params)")
    theta0 = np.array([_number(start[k], f"the starting value of {k!r}") for k in fitted_names])
    if not np.all(np.isfinite(theta0)):
        raise ModelError("the starting values must be finite")
    lo, hi = np.full(len(theta0), -np.inf), np.full(len(theta0), np.inf)
    for k, b in (bounds or {}).items():
        if str(k) not in fitted_names:
            raise ModelError(f"a bound for {k!r}, which is not fitted (fitted: {fitted_names})")
        if not isinstance(b, (tuple, list)) or len(b) != 2:
            raise ModelError(f"the bound of {k!r} must be a pair (low, high), got {b!r}")
        a, c = (-np.inf if b[0] is None else _number(b[0], f"the low bound of {k!r}"),
                np.inf if b[1] is None else _number(b[1], f"the high bound of {k!r}"))
        if not a < c:
            raise ModelError(f"the bound of {k!r} must have low < high, got {b!r}")
        j = fitted_names.index(str(k))
        lo[j], hi[j] = a, c
    if np.any(theta0 < lo) or np.any(theta0 > hi):
        raise ModelError("the starting values must lie within their bounds")

    Y = real_measurements(ys)
    runs = Y.shape[0] if Y.ndim == 3 else None
    # The filter's own checks of ys, x0, P0 and the parameters, at the starting values.
    first = kf.filter(ys, x0, P0, params={**fixed, **start}, keep=("x",))
    m0, C0 = kf._initial(x0, P0, runs)
    base = kf._param_values({**fixed, **start}, runs, first.steps)
    fitted = [names.index(k) for k in fitted_names]
    theta, total = _loglik_graph(kf, Y.reshape((runs or 1,) + Y.shape[-2:]), m0, C0, base, fitted)
    grad = ca.gradient(total, theta)
    value_grad = ca.Function("loglik_grad", [theta], [total, grad])
    hess = ca.Function("loglik_hess", [theta], [ca.hessian(total, theta)[0]])

    def objective(t: np.ndarray):
        v, g = value_grad(t)
        v, g = float(v), np.asarray(g, dtype=float).ravel()
        if not (math.isfinite(v) and np.all(np.isfinite(g))):
            return np.inf, np.zeros_like(t)  # a step outside the filter's domain: the search backs off
        return -v, -g

    res = optimize.minimize(objective, theta0, jac=True, method="L-BFGS-B",
                            bounds=list(zip(lo, hi)), options={"maxiter": int(max_iter), "gtol": gtol})
    if not res.success or not np.isfinite(res.fun):
        raise SymmonError(f"the maximum-likelihood fit did not converge after {res.nit} iterations: {res.message} "
                          f"(last estimates {dict(zip(fitted_names, res.x))}); try other starting values or bounds")
    info = -np.asarray(hess(res.x), dtype=float)
    info = 0.5 * (info + info.T)
    eig = np.linalg.eigvalsh(info)
    if not np.all(np.isfinite(eig)) or eig[0] <= 1e-12 * max(abs(eig[-1]), 1e-300):
        raise SymmonError(
            f"the observed information matrix at {dict(zip(fitted_names, res.x))} is singular or not positive "
            f"definite (eigenvalues {eig}): a fitted parameter is not identifiable from these data")
    cov = np.linalg.inv(info)
    se = np.sqrt(np.diag(cov))
    estimates = dict(zip(fitted_names, (float(v) for v in res.x)))
    scale = np.maximum(1.0, np.abs(res.x))
    at_bound = tuple(k for j, k in enumerate(fitted_names)
                     if min(abs(res.x[j] - lo[j]), abs(hi[j] - res.x[j])) <= 1e-8 * scale[j])
    all_params = {**fixed, **estimates}
    filtered = kf.filter(ys, x0, P0, params=all_params)
    cov.flags.writeable = False
    return FitResult(estimates, dict(zip(fitted_names, (float(v) for v in se))), cov,
                     float(np.sum(filtered.log_likelihood)), int(res.nit), all_params, filtered, at_bound, kf)
