"""An SDE as the dynamics of :func:`symmon.advise_filter`: its discretisation over the
measurement intervals, with the sub-steps chosen by the step's measure of nonlinearity.

The candidate filters of :func:`~symmon.filters.selection.advise_filter` are discrete: they
filter a Model f(x, w; dt) with the interval ``dt`` a per-step parameter.  An SDE given as f
is discretised here:

- a linear time-invariant SDE by ``"exact"`` (e^{A dt} and Van Loan's Q(dt), one sub-step);
  where sympy has no closed form, by ``"local_linear"``;
- a nonlinear one by ``"taylor1.5"`` (additive noise) or ``"euler"`` (a diffusion L(x)), with
  N sub-steps per interval from :func:`symmon.measures.mon.choose_substeps`: the fewest
  (a power of two) for which the MoN of the flow over (longest interval)/N from the prior
  x0 is within the advice's ``tol``, so that every sub-step is nearly affine where the track
  starts.

The intervals come from ``times`` (strictly increasing, after ``t0``: t_k − t_{k−1}) or from
``params["dt"]`` (a number, or one per step), as for :func:`symmon.simulate`; ``Q`` is None
(the noise is the SDE's; the discretised model's noise symbols have Q = I).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.model import Model
from ..core.sde import SDE
from ..errors import ArgumentError, DiscretizationError, plain_repr
from ..measures.mon import choose_substeps
from .simulation import DT, check_count, check_times

__all__ = ["DiscretizedTrack", "discretize_track"]


@dataclass(frozen=True)
class DiscretizedTrack:
    """An SDE made a discrete filtering problem (module notes).

    Attributes
    ----------
    f : Model
        The discretised SDE, f(x, w; θ, dt).
    Q : ndarray
        The covariance of its noise symbols, the identity.
    steps : int
        K, the number of measurements.
    params : dict
        The given parameter values with ``dt``, the interval before each measurement (K,).
    method : str
        The discretisation.
    substeps : int
        Its sub-steps per interval.
    """

    f: Model
    Q: np.ndarray
    steps: int
    params: dict
    method: str
    substeps: int


def _intervals(steps: Any, params: dict | None, times: Any, t0: float) -> tuple[int, dict]:
    if params is not None and not isinstance(params, dict):
        raise ArgumentError(f"params must be a dict of parameter values by name, got {type(params).__name__}")
    params = dict(params or {})
    if times is not None:
        if DT in params:
            raise ArgumentError(f"give the intervals by times or by params[{DT!r}], not both")
        dts = check_times(times, t0)
        if steps is not None and check_count(steps, "steps") != dts.size:
            raise ArgumentError(f"steps ({steps}) must be len(times) ({dts.size}) when times are given")
        return int(dts.size), {**params, DT: dts}
    if t0 != 0.0:
        raise ArgumentError("t0 applies only with times")
    if DT not in params:
        raise ArgumentError(f"an SDE as f needs its measurement times: times=[t_1, ..., t_K], or params[{DT!r}]")
    K = check_count(steps, "steps")
    dts = np.broadcast_to(np.asarray(params[DT], dtype=float), (K,)) if np.ndim(params[DT]) == 0 \
        else np.asarray(params[DT], dtype=float)
    if dts.shape != (K,) or not np.all(np.isfinite(dts) & (dts > 0)):
        raise ArgumentError(f"params[{DT!r}] must be a positive number or one per step ({K}), "
                            f"got {plain_repr(params[DT])}")
    return K, {**params, DT: dts}


def discretize_track(sde: SDE, Q: Any, x0: Gaussian, steps: int | None, params: dict | None = None,
                     times: Any = None, t0: float = 0.0, tol: float = 0.01) -> DiscretizedTrack:
    """The SDE ``sde`` discretised for a track of measurements (module notes).

    Parameters
    ----------
    sde : SDE
    Q : None
        The noise is the SDE's: anything else is refused.
    x0 : Gaussian
        The prior of x at ``t0``, where the MoN of the flow is taken.
    steps : int or None
        K; with ``times``, None or ``len(times)``.
    params : dict, optional
        The SDE's parameter values; without ``times``, ``params["dt"]`` gives the intervals.
    times : array_like, optional
        The measurement times t_1 < … < t_K, after ``t0``.
    t0 : float, default 0
        The time of x0.
    tol : float, default 0.01
        The MoN one sub-step may have (:func:`~symmon.measures.mon.choose_substeps`).

    Returns
    -------
    DiscretizedTrack

    Raises
    ------
    ArgumentError
        A Q that is not None, bad times or intervals, or both given.
    DiscretizationError
        A time-varying SDE: the sub-steps are chosen by the MoN of the flow, which does not
        see how fast a(x, t) changes with t.
    """
    if not sde.is_time_invariant:
        raise DiscretizationError(
            f"the advice discretises an SDE with the sub-steps its measure of nonlinearity asks for, which does not "
            f"see the time variation of {sde.name!r} (its drift or diffusion uses {sde.time}): discretise it yourself "
            "(sde.discretize('rk4' or 'taylor1.5', substeps=...), whose parameters include the start time "
            f"{sde.time} of each step) and advise on that model, or filter the SDE with "
            "sm.ContinuousDiscreteKalmanFilter")
    if Q is not None:
        raise ArgumentError("Q must be None when f is an SDE: the process noise comes from its diffusion and "
                            "spectral density")
    if not isinstance(x0, Gaussian):
        raise ArgumentError(f"x0 must be a symmon.Gaussian (the prior of x at t0), got {type(x0).__name__}")
    K, params = _intervals(steps, params, times, t0)
    own = {k: float(np.mean(v)) for k, v in params.items() if k in {str(s) for s in sde.params}}
    f, method, N = None, "exact", 1
    if sde.is_linear:  # time-invariant here
        try:
            f = sde.discretize("exact")
        except DiscretizationError:
            method = "local_linear"
    else:
        method = "taylor1.5" if sde.additive else "euler"
    if f is None:
        if not sde.is_linear:
            N = choose_substeps(sde, x0, float(np.max(params[DT])), tol, own or None)
        f = sde.discretize(method, substeps=N)
    Qw = np.eye(f.n_v) if f.n_v else np.zeros((f.n_u, f.n_u))
    return DiscretizedTrack(f, Qw, K, params, method, N)
