"""An SDE as the dynamics of :func:`symmon.advise_filter`: its discretisation over the
measurement intervals, with the sub-steps chosen by the step's measure of nonlinearity.

Most candidate filters of :func:`~symmon.filters.selection.advise_filter` are discrete: they
filter a Model f(x, w; dt) with the interval ``dt`` a per-step parameter.  An SDE given as f
is discretised here for them (its continuous-discrete filters join the menu beside them and
integrate the SDE itself: :mod:`symmon.filters.selection`):

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

The track also carries the MoN of the flow where it is cheap (one compiled model each, about
0.1 s): :attr:`DiscretizedTrack.flow_mon`, ``sm.nonlinearity(sde, x0, dt=longest)`` (the flow
over the longest interval from the prior, :func:`~symmon.measures.mon.flow_model`'s four
sub-steps), and :attr:`DiscretizedTrack.substep_mon`, that of one sub-step of the chosen N
(one order-1.5 step over longest/N, the value :func:`~symmon.measures.mon.choose_substeps`
brought within ``tol``).  A linear SDE's flow is affine: both are 0, not computed.

The truth of the advice's pilot is drawn from the discretised model, and the advice's
continuous-discrete candidates (:func:`symmon.advise_filter`, module notes of
:mod:`symmon.filters.selection`) integrate the SDE's own moment equations against it.  For a
linear SDE the exact discretisation draws the SDE's law exactly.  For a nonlinear one the
order-1.5 scheme's law differs from the SDE's by its weak error over the sub-steps the MoN
chose.  Measured on Van der Pol (the drift (x₂, (1 − x₁²) x₂ − x₁), diffusion (0, 0.3), x1
measured with R = 0.05, six irregular intervals up to 0.86, x0 = N((1.5, 0), 0.05 I),
tol 0.1: 8 sub-steps), 256 runs on the advice's truth and 256 on a truth of 8 times as many
sub-steps: the RMSE (unitless) and ANEES of the EKF, CKF, CD-EKF and CD-CKF move by less than
one Monte Carlo standard error (the CD-CKF's RMSE 0.944 ± 0.022 to 0.956 ± 0.021, its ANEES
1.95 ± 0.08 to 2.00 ± 0.08; the EKF's 0.966 ± 0.025 to 0.971 ± 0.024), and each CD filter
stays ahead of the discrete filter of its rule on both.  So the truth is good enough for the
pilot: it favours neither the discrete filters (which filter the very model that drew it)
nor the continuous-discrete ones, at the sub-steps the MoN chose.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.model import Model
from ..core.sde import SDE
from ..errors import ArgumentError, DiscretizationError, plain_repr
from ..measures.mon import choose_substeps, nonlinearity
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
    sde : SDE
        The SDE itself (for the continuous-discrete candidates).
    longest : float
        The longest interval, in the SDE's time unit.
    flow_mon : float
        The MoN (W^full, unitless) of the SDE's flow over ``longest`` from the prior (module
        notes); 0 for a linear SDE.
    substep_mon : float
        The MoN (unitless) of one sub-step's flow over ``longest / substeps`` from the prior,
        within the advice's tol; 0 for a linear SDE.
    """

    f: Model
    Q: np.ndarray
    steps: int
    params: dict
    method: str
    substeps: int
    sde: SDE
    longest: float = 0.0
    flow_mon: float = 0.0
    substep_mon: float = 0.0


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
    longest = float(np.max(params[DT]))
    flow = sub = 0.0  # a linear SDE's flow is affine
    if sde.is_linear:  # time-invariant here
        try:
            f = sde.discretize("exact")
        except DiscretizationError:
            method = "local_linear"
    else:
        method = "taylor1.5" if sde.additive else "euler"
    if f is None:
        if not sde.is_linear:
            N = choose_substeps(sde, x0, longest, tol, own or None)
            flow = float(nonlinearity(sde, x0, dt=longest, params=own or None))
            sub = float(nonlinearity(sde, x0, dt=longest / N, params=own or None, substeps=1))
        f = sde.discretize(method, substeps=N)
    Qw = np.eye(f.n_v) if f.n_v else np.zeros((f.n_u, f.n_u))
    return DiscretizedTrack(f, Qw, K, params, method, N, sde, longest, flow, sub)
