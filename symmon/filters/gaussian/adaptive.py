"""The adaptive nonlinear Kalman filter: at each step of each run, the cheapest adequate transform.

:class:`Adaptive` is a filter strategy (:mod:`symmon.filters.gaussian.strategy`), passed as the
``transform`` of :class:`symmon.NonlinearKalmanFilter`: at every step, for the time update and then for the
measurement update, the candidates are taken in the order of their cost and the first whose
estimated error (the unitless measure of :func:`symmon.measures.advice.moment_error`) is within the
tolerance is chosen; the step itself is the compiled step (:mod:`symmon.filters.gaussian.step`) of
the more expensive of the two choices.  The errors are estimated against TT2 (for TT1) and
against a Gauss–Hermite reference (Ito & Xiong 2000), as in :func:`symmon.quadrature_error`.

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
K. Ito, K. Xiong, "Gaussian filters for nonlinear filtering problems", IEEE Trans. Autom.
Control 45(5), 2000 (the Gauss–Hermite filter). doi:10.1109/9.855552
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...measures.advice import DEFAULT_TOL, cost, moment_distance, whiteners
from ...core.angles import wrap_angle
from ...errors import SymmonError, plain_repr
from .step import compiled_step, filterable, check_dimensions
from ..inputs import KEEPABLE, FilterSpec
from .strategy import FilterStrategy
from ...transforms.registry import resolve
from ...core.model import Model
from ...compile.compiled import compiled
from ...transforms.taylor import TT1, TT2
from ...transforms.unscented import UT
from ...transforms.quadrature import GaussHermite
from ...transforms.base import Transform

__all__ = ["Adaptive"]


@dataclass(frozen=True)
class Adaptive(FilterStrategy):
    """A filter strategy that picks, at each step of each run, the cheapest adequate transform.

    Pass it as the ``transform`` of :class:`NonlinearKalmanFilter`.  At step k the filter
    decides twice, on the Gaussians the step transforms:

    1. the time update: f at N(x̂_{k−1|k−1}, P_{k−1|k−1}) (with N(0, Q) appended for
       general noise);
    2. the measurement update: h at the prior N(x⁻, P⁻) that the transform chosen in 1
       predicts.

    Each decision takes the candidates in the order of their cost in evaluations of g
    (:func:`symmon.measures.advice.cost`, ties to the earlier candidate) and picks the first whose
    estimated error is at most ``tol``, in the unitless measure of
    :func:`symmon.measures.advice.moment_error`, with the covariance that the filter compares the
    moments with (P⁻ = Cov f + Q in the time update, S = Cov h + R in the measurement
    update) as the unit:

    - TT1's error is estimated by its distance to TT2, whose terms are closed forms (the
      mean ½ tr(H_i P) and the covariance ½ tr(H_i P H_j P) of the TT2 MoN): no
      quadrature at all when the model is nearly linear over the prior;
    - the other candidates' errors by their distance to ``reference`` (Gauss–Hermite of
      order 5), computed only for the runs where TT1 failed; for GH3 this is its
      two-order error estimate (GH3 against GH5, cf. :func:`symmon.quadrature_error`).

    When no candidate is within ``tol``, the most expensive one is used.  The step runs
    the compiled filter step (both updates) of the more expensive of the two choices, and
    that choice is recorded in :attr:`NonlinearKalmanResult.choices` per step and per run:
    the runs of a bank decide independently, each on its own prior.

    Limitation: TT1's test sees only second-order terms.  Where the Hessian of g vanishes
    at the mean but higher derivatives do not (an odd function at its centre) TT1 passes
    the test although it may be off; the advice of :func:`symmon.advise` against a
    converged reference catches that case.

    Parameters
    ----------
    tol : float, default :data:`symmon.measures.advice.DEFAULT_TOL` (0.01)
        Largest acceptable unitless error, in (0, 1): the default of :func:`symmon.advise`
        too, so that both decide alike on the same prior (why 0.01: the notes of
        :mod:`symmon.measures.advice`).
    candidates : tuple of TT1, TT2, UT or GaussHermite
        Default TT1 (EKF), TT2 (second-order EKF), ``UT.cubature()`` (CKF) and
        GaussHermite(3).
    reference : UT or GaussHermite, default GaussHermite(5)
    """

    tol: float = DEFAULT_TOL
    candidates: tuple = (TT1(), TT2(), UT.cubature(), GaussHermite(3))
    reference: Transform = GaussHermite(5)

    def __post_init__(self) -> None:
        if isinstance(self.tol, bool) or not isinstance(self.tol, (int, float)) or not 0 < self.tol < 1:
            raise SymmonError(f"tol must be a number in (0, 1), got {plain_repr(self.tol)}")
        cands = tuple(resolve(t) for t in self.candidates)
        object.__setattr__(self, "reference", resolve(self.reference))
        if not cands:
            raise SymmonError("candidates is empty")
        for t in cands + (self.reference,):
            if not filterable(t):
                raise SymmonError(f"Adaptive candidates and reference must be TT1, TT2, UT or GaussHermite "
                                  f"(a Taylor or point rule), got {t!r}")
        object.__setattr__(self, "candidates", cands)

    def __repr__(self) -> str:
        return f"Adaptive(tol={self.tol:g}, candidates=[{', '.join(t.filter_label() for t in self.candidates)}])"

    def label(self) -> str:
        return repr(self)

    def check(self, kf):
        if kf.params:
            raise SymmonError(
                f"Adaptive decides on moments evaluated outside the compiled step, which do not take model "
                f"parameters ({[str(s) for s in kf.params]}): give their values with model.with_params({{...}})")
        for t in self.candidates + (self.reference,):
            check_dimensions(t, kf.dimensions)

    def stores(self, keep):
        return frozenset(KEEPABLE)  # every array: the next decision reads x and P

    def run(self, kf, Y, x0, P0, keep=None):
        return _adaptive_run(self, kf, Y, x0, P0)  # every output: the next decision reads x and P


def _decide(model: Model, m: np.ndarray, C: np.ndarray, add: np.ndarray | None, angles: frozenset[int],
            order: list[Transform], reference: Transform, tol: float):
    """Index (into ``order``) of each run's choice, and the mean and covariance it gives.

    ``add`` is the additive noise covariance (added to Cov g), None with noise symbols.
    """
    cm = compiled(model)
    plus = (lambda c: c) if add is None else (lambda c: c + add)
    t1 = TT1().moments(cm, m, C, angles)
    Aw = whiteners(C)
    choice = np.full(m.shape[0], len(order) - 1)
    mean, cov = t1.mean.copy(), plus(t1.cov)  # overwritten unless TT1 is the choice or the fallback
    open_ = np.ones(m.shape[0], dtype=bool)
    i1 = next((i for i, t in enumerate(order) if t.taylor_order == 1), None)
    if i1 is not None:  # TT1 is the cheapest: its closed-form test comes first
        t2 = TT2().moments(cm, m, C, angles)
        ok = moment_distance(t1, t2, whiteners(plus(t2.cov)), Aw, angles) <= tol
        choice[ok] = i1
        open_ = ~ok
    rest = np.flatnonzero(open_)
    if rest.size:
        ms, Cs, Aws = m[rest], C[rest], Aw[rest]
        ref = reference.moments(cm, ms, Cs, angles)
        Ay = whiteners(plus(ref.cov))
        left = np.ones(rest.size, dtype=bool)
        for i, t in enumerate(order):
            if t.taylor_order == 1:
                continue
            b = t.moments(cm, ms, Cs, angles)
            ok = (moment_distance(b, ref, Ay, Aws, angles) <= tol) & left
            if i == len(order) - 1:
                ok = left  # the most expensive candidate is the fallback
            choice[rest[ok]] = i
            mean[rest[ok]], cov[rest[ok]] = b.mean[ok], plus(b.cov)[ok]
            left &= ~ok
    return choice, mean, cov


def _adaptive_run(ad: Adaptive, kf: FilterSpec, Y: np.ndarray, x0: np.ndarray, P0: np.ndarray):
    """The adaptive filter (:class:`Adaptive`) on a bank Y (R, K, n_y): outputs and choices."""
    f, h = kf.f_model, kf.h_model
    runs, K = Y.shape[:2]
    n, n_y = f.n_u, h.n_y

    order = sorted(ad.candidates, key=lambda t: cost(t, n))  # stable: ties keep the given order
    names = np.array([t.filter_label() for t in order])
    steps = [compiled_step(f, h, t, kf.angle_states) for t in order]
    shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n), "innovation": (n_y,), "S": (n_y, n_y),
              "loglik": (), "nis": ()}
    out = {key: np.full((runs, K) + s, np.nan) for key, s in shapes.items()}  # NaN after a failure
    chosen = np.full((runs, K), -1)  # -1: a step not run (after a failure), labelled ""
    x = np.ascontiguousarray(np.broadcast_to(x0, (runs, n)), dtype=float)
    P = np.ascontiguousarray(np.broadcast_to(P0, (runs, n, n)), dtype=float)
    states, y_angles = kf.angle_states, frozenset(h.angle_outputs)
    for k in range(K):
        if f.n_v:
            nq = f.n_v
            m = np.concatenate([x, np.zeros((runs, nq))], axis=1)
            C = np.zeros((runs, n + nq, n + nq))
            C[:, :n, :n], C[:, n:, n:] = P, kf.Q
            cf, xp, Pp = _decide(f, m, C, None, states, order, ad.reference, ad.tol)
        else:
            cf, xp, Pp = _decide(f, x, P, kf.Q, states, order, ad.reference, ad.tol)
        if states:
            idx = sorted(states)
            xp[:, idx] = wrap_angle(xp[:, idx])
        Pp = 0.5 * (Pp + np.swapaxes(Pp, 1, 2))
        if h.n_v:
            nr = h.n_v
            m = np.concatenate([xp, np.zeros((runs, nr))], axis=1)
            C = np.zeros((runs, n + nr, n + nr))
            C[:, :n, :n], C[:, n:, n:] = Pp, kf.R
            ch = _decide(h, m, C, None, y_angles, order, ad.reference, ad.tol)[0]
        else:
            ch = _decide(h, xp, Pp, kf.R, y_angles, order, ad.reference, ad.tol)[0]
        c = np.maximum(cf, ch)
        chosen[:, k] = c
        for i in np.unique(c):
            sel = np.flatnonzero(c == i)
            o = steps[i](x[sel], P[sel], Y[sel, k:k + 1], kf.Q, kf.R)
            for key, v in o.items():
                out[key][sel, k] = v[:, 0]
        x, P = out["x"][:, k].copy(), out["P"][:, k].copy()
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            break  # the caller names the run and step
    return out, np.where(chosen >= 0, names[np.maximum(chosen, 0)], "")
