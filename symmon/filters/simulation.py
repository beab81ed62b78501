"""True states and measurements drawn from the symbolic models: the truth of a filter study.

:func:`simulate` draws x_0 from its distribution, then for k = 1 … K

    x_k = f(x_{k−1}, w_k),   y_k = h(x_k, e_k),   w_k ~ N(0, Q),  e_k ~ N(0, R),

(x_k = f(x_{k−1}) + w_k and y_k = h(x_k) + e_k for a model without noise symbols), the
conventions of :class:`~symmon.NonlinearKalmanFilter`, whose ``filter(ys, x0)`` reads
``ys[k]`` as y_{k+1}, measured after its (k+1)-th prediction from x0.  So ``xs[k]`` is
x_{k+1}, the state after the (k+1)-th transition (x_0 itself is not returned), ``ys[k]`` its
measurement, and ``filter(ys, x0, x_true=xs)`` compares each estimate with its own state.
The parameters of step k (an irregular time step dt_k, a control input) enter both the
transition to ``xs[k]`` and the measurement ``ys[k]``, as in the filters' step k.

**Continuous-time dynamics.**  ``f`` may be an :class:`~symmon.core.sde.SDE`: the truth is
then drawn by the exact transition of a linear time-invariant SDE (``sde.discretize("exact")``:
e^{A dt} and Van Loan's Q(dt), whatever the step) and otherwise by the strong order-1.5
Itô–Taylor scheme (``"taylor1.5"``) with ``substeps`` sub-steps per interval (default
:data:`TRUTH_SUBSTEPS`).  The measurement times are ``times`` (strictly increasing, after
``t0``, the time of x_0), so step k lasts dt_k = t_k − t_{k−1}; without ``times`` the step is
the parameter ``dt`` of ``params``.  ``Q`` is None: the noise comes from the SDE.  A
time-varying SDE (a time symbol in its drift or diffusion) is drawn by the order-1.5 scheme
at the absolute time: step k starts at t_{k−1} (``t0``, then the times; without ``times``,
the cumulative sum of the steps from 0) and its sub-step j at t_{k−1} + j dt_k/substeps.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

import weakref

from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from ..core.model import Model
from ..core.sde import SDE
from ..errors import DiscretizationError
from ..errors import ArgumentError, ArgumentTypeError, NonFiniteError, ShapeError, plain_repr
from .inputs import check_bank_size, measurement_times, param_values, time_intervals
from .statespace import StateSpace

__all__ = ["simulate", "check_count", "check_prior", "check_times", "truth_model", "TRUTH_SUBSTEPS"]

#: Sub-steps per interval of the order-1.5 scheme that simulates a nonlinear SDE's truth.
TRUTH_SUBSTEPS = 4
#: The name of the step parameter of a discretised SDE (``symmon.core.discretize.default_dt``).
DT = "dt"

# The discretised models of an SDE by (method, substeps), kept while the SDE lives: sympy
# derives a model once per SDE, not once per call.
_TRUTH_MODELS: "weakref.WeakKeyDictionary[SDE, dict]" = weakref.WeakKeyDictionary()


def check_count(value, name: str, optional: bool = False) -> int | None:
    """A positive integer (or None when ``optional``), else an :class:`ArgumentError` naming it."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ArgumentError(f"{name} must be a positive integer{' or None' if optional else ''}, got {plain_repr(value)}")
    return int(value)


def check_prior(x0, n: int, name: str = "x0") -> Gaussian | GaussianMixture | Empirical:
    """``x0`` if it is a Gaussian, a GaussianMixture or an Empirical of dimension n."""
    if not isinstance(x0, (Gaussian, GaussianMixture, Empirical)):
        raise ArgumentTypeError(f"{name} must be a symmon.Gaussian, GaussianMixture or Empirical (the distribution "
                                f"of x_0), got {type(x0).__name__}")
    if x0.dim != n:
        raise ShapeError(f"{name} has dimension {x0.dim}, but the state has {n}")
    return x0


def check_times(times, t0: float = 0.0, name: str = "times") -> np.ndarray:
    """The steps dt_k = t_k − t_{k−1} (t_{-1} = t0) of measurement times, shape (K,)
    (:func:`~symmon.filters.inputs.measurement_times`, then its intervals).

    Raises
    ------
    ArgumentError
        For times that are not a non-empty 1-D sequence of finite numbers, strictly
        increasing and after ``t0``, or a ``t0`` that is not a finite number.
    """
    return time_intervals(measurement_times(times, t0, name=name), t0)


def truth_model(sde: SDE) -> Model:
    """The discretised SDE that :func:`simulate` draws the truth with, its step the parameter
    ``dt`` (and, for a time-varying SDE, its time symbol, the step's start): ``"exact"`` for
    a linear time-invariant SDE whose closed form sympy gives, else one sub-step of
    ``"taylor1.5"``, which :func:`simulate` applies ``substeps`` times per interval
    (the same draws as ``sde.discretize("taylor1.5", substeps=substeps)``, here without
    compiling a model per number of sub-steps).

    Raises
    ------
    DiscretizationError
        For a nonlinear SDE whose diffusion depends on the states (the order-1.5 scheme
        needs additive noise).
    """
    models = _TRUTH_MODELS.setdefault(sde, {})
    if sde.is_linear and sde.is_time_invariant:
        if "exact" not in models:
            try:
                models["exact"] = sde.discretize("exact")
            except DiscretizationError:
                models["exact"] = None  # no closed form: the order-1.5 scheme below
        if models["exact"] is not None:
            return models["exact"]
    if "taylor1.5" not in models:
        models["taylor1.5"] = sde.discretize("taylor1.5")
    return models["taylor1.5"]


def _sde_inputs(f, Q, steps, params, times, t0, substeps):
    """(model, Q, steps, params, sub-steps) for :func:`simulate`: an SDE discretised with its
    steps from ``times``, or a Model with ``times`` as its ``dt`` parameter."""
    sub = 1
    if isinstance(f, SDE):
        if Q is not None:
            raise ArgumentError("Q must be None when f is an SDE: the process noise comes from its diffusion "
                                "and spectral density")
        substeps = TRUTH_SUBSTEPS if substeps is None else check_count(substeps, "substeps")
        model = truth_model(f)
        sub = 1 if model is _TRUTH_MODELS[f].get("exact") else substeps
        Q = np.eye(model.n_v) if model.n_v else np.zeros((model.n_u, model.n_u))
    else:
        if substeps is not None:
            raise ArgumentError("substeps applies to an SDE as f (its order-1.5 truth), not to a Model")
        model = f
    if times is None:
        if t0 != 0.0:
            raise ArgumentError("t0 applies only with times")
        if isinstance(f, SDE):
            _check_steps(params)
            params = _with_starts(f, params, None, 0.0, steps)
        return model, Q, steps, params, sub
    if not isinstance(model, Model) or DT not in {str(s) for s in model.params}:
        raise ArgumentError(f"times needs an SDE as f, or a Model with a parameter {DT!r} (a discretised SDE)")
    dts = check_times(times, t0)
    if steps is not None and check_count(steps, "steps") != dts.size:
        raise ArgumentError(f"steps ({steps}) must be len(times) ({dts.size}) when times are given")
    if params is not None and not isinstance(params, dict):
        raise ArgumentTypeError(f"params must be a dict of parameter values by name, got {type(params).__name__}")
    if params and DT in params:
        raise ArgumentError(f"give the steps by times or by params[{DT!r}], not both")
    params = {**(params or {}), DT: dts}
    if isinstance(f, SDE):
        params = _with_starts(f, params, np.asarray(times, dtype=float), float(t0), int(dts.size))
    return model, Q, int(dts.size), params, sub


def _with_starts(sde: SDE, params: dict, times: np.ndarray | None, t0: float, steps) -> dict:
    """``params`` with the start time of each step under the name of a time-varying SDE's
    time symbol: ``t0`` and the times before each, or (without times) the cumulative sums
    of ``params["dt"]`` from 0 (k dt for one number and ``steps``); ``params`` itself for a
    time-invariant SDE.

    Raises
    ------
    ArgumentError
        ``params`` giving the time itself.
    """
    if sde.is_time_invariant:
        return params
    name = str(sde.time)
    if name in params:
        raise ArgumentError(f"params must not give {name!r}, the time of the SDE: it is the start of each step, "
                            "from times (and t0) or the cumulative sum of the steps")
    if times is not None:
        starts = np.concatenate([[t0], times[:-1]])
    else:
        dt = np.asarray(params[DT], dtype=float)
        if dt.ndim == 0:
            dt = np.full(check_count(steps, "steps"), float(dt))
        starts = np.concatenate([np.zeros(dt.shape[:-1] + (1,)), np.cumsum(dt, axis=-1)[..., :-1]], axis=-1)
    return {**params, name: starts}


def _check_steps(params) -> None:
    """An SDE without ``times``: ``params["dt"]`` must give its steps, positive and finite."""
    if not isinstance(params, dict) or DT not in params:
        raise ArgumentError(f"an SDE as f needs its steps: times=[t_1, ..., t_K], or params[{DT!r}]")
    try:
        dt = np.asarray(params[DT], dtype=float)
    except (TypeError, ValueError):
        return  # the parameters' own check names the fault
    if not np.all(np.isfinite(dt) & (dt > 0)):
        raise ArgumentError(f"params[{DT!r}] must be positive and finite (the steps), got {plain_repr(params[DT])}")


def _generator(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArgumentError(f"seed must be a non-negative integer or a numpy.random.Generator, got {seed!r}")
    return np.random.default_rng(int(seed))


def simulate(f: Model | SDE, h: Model, Q: ArrayLike | None, R: ArrayLike,
             x0: Gaussian | GaussianMixture | Empirical, steps: int | None = None, runs: int | None = None,
             params: dict | None = None, seed: int | np.random.Generator = 0, *, times: ArrayLike | None = None,
             t0: float = 0.0, substeps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """True states and measurements of the state-space model (f, h, Q, R).

    The noise conventions are those of :class:`~symmon.NonlinearKalmanFilter`: Q and R are
    the covariances of f's and h's noise symbols (general noise), or of additive noises
    when a model has none; angle states (f's angle outputs, f's or h's angle inputs) and
    angle measurements are wrapped to (−π, π].  f and h run as compiled C over all runs of
    a step at once.

    Parameters
    ----------
    f : Model or SDE
        The dynamics (n → n), or a continuous-time SDE (module notes).
    h : Model
        The measurement (n → n_y).
    Q, R : array_like
        Process and measurement noise covariances (positive semi-definite); ``Q`` is None
        for an SDE.
    x0 : Gaussian, GaussianMixture or Empirical
        The distribution of the initial state x_0 (at ``t0``), drawn once per run (an
        Empirical is resampled by its weights); pass the same ``x0`` to ``filter``.
    steps : int, optional
        K, the number of transitions and measurements; required unless ``times`` are given
        (then K = len(times), and a ``steps`` given must equal it).
    runs : int, optional
        R independent runs (a bank): a leading axis on the results.  Default: one run.
    params : dict, optional
        The values of the models' parameters by name, as for ``filter``: a number, one per
        step (K,), or with ``runs`` one per run and step (R, K).  Step k's value enters the
        transition to ``xs[k]`` and the measurement ``ys[k]``.
    seed : int or numpy.random.Generator, default 0
        The same seed gives the same runs.  The draws are, in order: x_0 of every run, then
        for each step the process noise of every run and the measurement noise of every run
        (standard normal rows times a square root of Q, resp. R).
    times : array_like, shape (K,), optional
        Measurement times t_1 < … < t_K after ``t0``, in the SDE's time unit: step k lasts
        t_k − t_{k−1}.  For an SDE, or a Model with a parameter ``dt`` (a discretised SDE);
        instead of ``params["dt"]``.
    t0 : float, default 0
        The time of x_0 (with ``times``).
    substeps : int, optional
        Sub-steps per interval of the order-1.5 truth of a nonlinear SDE (default
        :data:`TRUTH_SUBSTEPS`; the exact transition of a linear SDE has none).

    Returns
    -------
    xs : ndarray, shape (K, n), or (R, K, n)
        x_1 … x_K: ``xs[k]`` is the state after the (k+1)-th transition (module notes).
    ys : ndarray, shape (K, n_y), or (R, K, n_y)
        y_1 … y_K, ``ys[k]`` measured at ``xs[k]``.

    Raises
    ------
    ArgumentError
        For ``steps`` or ``runs`` that are not positive integers, or a bad ``seed``; for
        ``times`` that are not strictly increasing after ``t0``, a ``steps`` other than
        their number, a ``dt`` given twice, a ``Q`` with an SDE, or ``times`` or
        ``substeps`` where they do not apply.
    ArgumentTypeError
        For a model that is not a Model, or an ``x0`` that is not a distribution.
    ShapeError, CovarianceError, ModelError
        For models that do not fit together, bad covariances, or parameters missing,
        unknown or of the wrong shape.
    ResourceError
        When R × K × (n + n_y) exceeds :data:`~symmon.filters.results.MAX_BANK_NUMBERS`.
    NonFiniteError
        When the truth diverges (a state or a measurement is NaN or inf), naming the run
        and step: a NaN would read as a missing measurement to the filters.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> xs, ys = sm.simulate(sm.Model([x], [0.9 * x]), sm.Model([x], [x]), [[0.1]], [[0.01]],
    ...                      sm.Gaussian([1.0], [[0.0]]), steps=5, runs=3, seed=1)
    >>> xs.shape, ys.shape
    ((3, 5, 1), (3, 5, 1))
    >>> ou = sm.SDE([x], [-x], diffusion=[0.5])
    >>> xs, ys = sm.simulate(ou, sm.Model([x], [x]), None, [[0.01]], sm.Gaussian([1.0], [[0.0]]),
    ...                      times=[0.5, 1.25, 3.0], seed=1)
    >>> xs.shape
    (3, 1)
    """
    sub = 1
    f_sde = f if isinstance(f, SDE) else None
    if isinstance(f, SDE) or times is not None or substeps is not None or t0 != 0.0:
        f, Q, steps, params, sub = _sde_inputs(f, Q, steps, params, times, t0, substeps)
    ss = StateSpace(f, h, Q, R)
    K = check_count(steps, "steps")
    bank = check_count(runs, "runs", optional=True)
    x0 = check_prior(x0, ss.n)
    rng = _generator(seed)
    N = bank or 1
    check_bank_size(N, K, ss.n + ss.n_y, "the simulated states and measurements", "simulate fewer runs or steps")
    pv = param_values(ss.params, params, bank, K, who="the models")
    nq, nr = ss.Lq.shape[0], ss.Lr.shape[0]
    xs, ys = np.empty((N, K, ss.n)), np.empty((N, K, ss.n_y))
    x = ss.wrap_states(np.array(x0.sample(N, rng), dtype=float))
    if sub > 1:  # an SDE's order-1.5 truth: sub-steps of dt/sub, the noise of all drawn at once
        names = [str(s) for s in ss.params]
        i_dt = names.index(DT)
        # A time-varying SDE's sub-step j starts at t + j dt/sub.
        i_t = names.index(str(f_sde.time)) if f_sde is not None and not f_sde.is_time_invariant else None
    for k in range(K):
        p = None if pv is None else pv[:, k]
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging truth is refused below
            if sub == 1:
                x = ss.transition(x, rng.standard_normal((N, nq)), p)
            else:
                Z = rng.standard_normal((N, sub * nq))
                ph = p.copy()
                ph[:, i_dt] /= sub
                for j in range(sub):
                    if i_t is not None:
                        ph[:, i_t] = p[:, i_t] + j * ph[:, i_dt]
                    x = ss.transition(x, Z[:, j * nq:(j + 1) * nq], ph)
            y = ss.measure(x, rng.standard_normal((N, nr)), p)
        xs[:, k], ys[:, k] = x, y
        bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            where = f"run {r} has" if bank else "the run has"
            raise NonFiniteError(
                f"the simulated truth diverged: {where} a non-finite state or measurement at step {k + 1} "
                f"(xs index {k}, x = {x[r].tolist()}): the dynamics are unstable over this many steps, or the "
                "noise too large")
    if bank is None:
        return xs[0], ys[0]
    return xs, ys
