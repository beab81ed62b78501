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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from ..core.model import Model
from ..errors import ArgumentError, ArgumentTypeError, NonFiniteError, ShapeError, plain_repr
from .inputs import check_bank_size, param_values
from .statespace import StateSpace

__all__ = ["simulate", "check_count", "check_prior"]


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


def _generator(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArgumentError(f"seed must be a non-negative integer or a numpy.random.Generator, got {seed!r}")
    return np.random.default_rng(int(seed))


def simulate(f: Model, h: Model, Q: ArrayLike, R: ArrayLike, x0: Gaussian | GaussianMixture | Empirical,
             steps: int, runs: int | None = None, params: dict | None = None,
             seed: int | np.random.Generator = 0) -> tuple[np.ndarray, np.ndarray]:
    """True states and measurements of the state-space model (f, h, Q, R).

    The noise conventions are those of :class:`~symmon.NonlinearKalmanFilter`: Q and R are
    the covariances of f's and h's noise symbols (general noise), or of additive noises
    when a model has none; angle states (f's angle outputs, f's or h's angle inputs) and
    angle measurements are wrapped to (−π, π].  f and h run as compiled C over all runs of
    a step at once.

    Parameters
    ----------
    f, h : Model
        The dynamics (n → n) and the measurement (n → n_y).
    Q, R : array_like
        Process and measurement noise covariances (positive semi-definite).
    x0 : Gaussian, GaussianMixture or Empirical
        The distribution of the initial state x_0, drawn once per run (an Empirical is
        resampled by its weights); pass the same ``x0`` to ``filter``.
    steps : int
        K, the number of transitions and measurements.
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

    Returns
    -------
    xs : ndarray, shape (K, n), or (R, K, n)
        x_1 … x_K: ``xs[k]`` is the state after the (k+1)-th transition (module notes).
    ys : ndarray, shape (K, n_y), or (R, K, n_y)
        y_1 … y_K, ``ys[k]`` measured at ``xs[k]``.

    Raises
    ------
    ArgumentError
        For ``steps`` or ``runs`` that are not positive integers, or a bad ``seed``.
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
    """
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
    for k in range(K):
        p = None if pv is None else pv[:, k]
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging truth is refused below
            x = ss.transition(x, rng.standard_normal((N, nq)), p)
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
