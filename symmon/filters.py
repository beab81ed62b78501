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
added to the covariances.  One step reads

    x⁻ = E f,  P⁻ = Cov f (+ Q),
    ŷ = E h,  S = Cov h (+ R),  P^{xy} = Cov(x, h),
    ν = y − ŷ,  K = P^{xy} S⁻¹,  x⁺ = x⁻ + K ν,  P⁺ = P⁻ − K S Kᵀ.

Angles: the outputs of h that the model declares as angles get a circular mean
atan2(Σ wᵢ sin, Σ wᵢ cos) (point rules) or a wrapped mean (TT1, TT2), wrapped residuals and a
wrapped innovation; the *angle states* (the outputs of f declared as angles, or the inputs of f
or h declared as angles) get the same treatment in the time update, and x⁺ is wrapped.

The whole step, from the sigma points (or the Taylor terms) to the wrapped update, is one
CasADi function of (x, P, y, Q, R), built from the models' SX graphs with a symbolic Cholesky
factor (the moment formulas of :mod:`symmon.symbolic_moments`, in SX).  Its C code is compiled once (cached on disk), and a C loop around it runs all the
steps of all the runs of a filter bank in one call.

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
"""

from __future__ import annotations

import ctypes
import hashlib
import itertools
import math
import threading
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from .advise import cost, moment_distance, whiteners
from .angles import wrap_angle
from .compile import build_shared_library, generated_c, has_compiler
from .errors import ShapeError, SymmonError
from .estimation import _check_gaussian, _check_model, _noise_cov, _readonly
from .gaussian import Gaussian, as_covariance
from .model import Model
from .propagate import compiled
from .symbolic_moments import moments, wrap_entries
from .transforms import TT1, TT2, UT, GaussHermite, Transform

__all__ = ["NonlinearKalmanFilter", "NonlinearKalmanResult", "ConsistencyTest", "Adaptive"]

#: Names of the outputs of the step function, in order.
_OUTPUTS = ("x", "P", "x_pred", "P_pred", "innovation", "S")


# --------------------------------------------------------------------------- the step
def _sym(A: ca.SX) -> ca.SX:
    return 0.5 * (A + A.T)


def _step_function(f: Model, h: Model, transform: Transform, angle_states: frozenset[int],
                   name: str) -> ca.Function:
    """(x, P, y, Q, R) ↦ (x⁺, P⁺, x⁻, P⁻, ν, S): one predict + update step (module notes)."""
    n, n_y = f.n_u, h.n_y
    nq, nr = f.n_v or n, h.n_v or n_y
    x, P, y = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("y", n_y)
    Q, R = ca.SX.sym("Q", nq, nq), ca.SX.sym("R", nr, nr)
    # Time update: the NLT of f, on [x; w] with general noise.
    if f.n_v:
        mean, cov, _ = moments(compiled(f), ca.vertcat(x, ca.SX.zeros(nq)), ca.diagcat(P, Q), transform,
                               angle_states)
    else:
        mean, cov, _ = moments(compiled(f), x, P, transform, angle_states)
        cov = cov + Q
    x_pred, P_pred = wrap_entries(mean, angle_states), _sym(cov)
    # Measurement update: the NLT of h at N(x⁻, P⁻), then Lemma 7.1.
    y_angles = frozenset(h.angle_outputs)
    if h.n_v:
        y_hat, S, cross = moments(compiled(h), ca.vertcat(x_pred, ca.SX.zeros(nr)), ca.diagcat(P_pred, R),
                                  transform, y_angles)
        cross = cross[:, :n]
    else:
        y_hat, S, cross = moments(compiled(h), x_pred, P_pred, transform, y_angles)
        S = S + R
    S = _sym(S)
    nu = wrap_entries(y - y_hat, y_angles)
    gain = ca.solve(S, cross).T  # K = P^{xy} S⁻¹, S symmetric
    x_new = wrap_entries(x_pred + ca.mtimes(gain, nu), angle_states)
    P_new = _sym(P_pred - ca.mtimes(ca.mtimes(gain, S), gain.T))
    outs = [ca.densify(a) for a in (x_new, P_new, x_pred, P_pred, nu, S)]
    return ca.Function(name, [x, P, y, Q, R], outs, ["x", "P", "y", "Q", "R"],
                       ["x_new", "P_new", "x_pred", "P_pred", "innovation", "S"],
                       {"cse": True})


# The run loop: for each run, K steps, each reading the previous step's output.  casadi_int
# is CasADi's default, long long.  x0/P0 advance by x0_step/P0_step per run (0: shared).
_DRIVER = """
/* symmon: a bank of runs of the filter step {name}. */
CASADI_SYMBOL_EXPORT int {name}_run(const casadi_real* x0, casadi_int x0_step,
    const casadi_real* P0, casadi_int P0_step, const casadi_real* y,
    const casadi_real* Q, const casadi_real* R, casadi_real* xs, casadi_real* Ps,
    casadi_real* xps, casadi_real* Pps, casadi_real* nus, casadi_real* Ss,
    casadi_int runs, casadi_int K, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int r, k, i;
  for (r = 0; r < runs; ++r) {{
    const casadi_real* x = x0 + r * x0_step;
    const casadi_real* P = P0 + r * P0_step;
    for (k = 0; k < K; ++k) {{
      i = r * K + k;
      arg[0] = x; arg[1] = P; arg[2] = y + i * {n_y}; arg[3] = Q; arg[4] = R;
      res[0] = xs + i * {n}; res[1] = Ps + i * {nn}; res[2] = xps + i * {n};
      res[3] = Pps + i * {nn}; res[4] = nus + i * {n_y}; res[5] = Ss + i * {nyy};
      if ({name}(arg, res, iw, w, 0)) return 1;
      x = res[0];
      P = res[1];
    }}
  }}
  return 0;
}}
"""


class _CompiledStep:
    """The step function of one (f, h, transform), as C with a run loop or on CasADi's VM."""

    def __init__(self, f: Model, h: Model, transform: Transform, angle_states: frozenset[int]) -> None:
        key = repr((f.outputs, f.inputs, f.noise, h.outputs, h.inputs, h.noise, transform,
                    sorted(angle_states), sorted(h.angle_outputs)))
        name = "sm_nkf_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        self.f = _step_function(f, h, transform, angle_states, name)
        self.n, self.n_y = n, n_y = f.n_u, h.n_y
        self._shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n),
                        "innovation": (n_y,), "S": (n_y, n_y)}
        # Without a compiler, compiled() has already warned (once) while the step was built.
        self._run = self._load() if has_compiler() else None
        self._local = threading.local()

    def _load(self):
        f = self.f
        name = f.name()
        code = generated_c(f) + _DRIVER.format(
            name=name, sz_arg=max(f.sz_arg(), 5), sz_res=max(f.sz_res(), 6),
            n=self.n, nn=self.n * self.n, n_y=self.n_y, nyy=self.n_y * self.n_y,
        )
        so = build_shared_library(code, name, stacklevel=5)
        if so is None:
            return None
        run = getattr(ctypes.CDLL(str(so)), f"{name}_run")
        run.argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong]
                        + [ctypes.c_void_p] * 9 + [ctypes.c_longlong] * 2 + [ctypes.c_void_p] * 2)
        run.restype = ctypes.c_int
        return run

    def _workspace(self) -> tuple[int, int]:
        """Addresses of this thread's work arrays (integer, real), made once per thread."""
        ws = getattr(self._local, "ws", None)
        if ws is None:
            ws = self._local.ws = (np.zeros(max(self.f.sz_iw(), 1), dtype=np.int64),
                                   np.zeros(max(self.f.sz_w(), 1)))
        return ws[0].ctypes.data, ws[1].ctypes.data

    @property
    def is_compiled(self) -> bool:
        return self._run is not None

    def __call__(self, x0: np.ndarray, P0: np.ndarray, Y: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 use_c: bool = True) -> dict[str, np.ndarray]:
        """Run the bank: x0 (n,) or (runs, n), P0 (n, n) or (runs, n, n), Y (runs, K, n_y)."""
        runs, K = Y.shape[:2]
        n, n_y = self.n, self.n_y
        shapes = self._shapes
        sizes = [runs * K * math.prod(s) for s in shapes.values()]
        # One block for all outputs and one for the inputs: a few pointers per call.
        buf = np.empty(sum(sizes))
        ends = list(itertools.accumulate(sizes))
        out = {k: buf[e - z: e].reshape((runs, K) + s) for (k, s), z, e in zip(shapes.items(), sizes, ends)}
        # CasADi is column-major: the symmetric P, Q, R, S need no transposition, and a C
        # row (runs, n) is a column-major (n, runs).
        Y = np.ascontiguousarray(Y, dtype=float)
        if use_c and self._run is not None:
            parts = [np.ravel(a) for a in (x0, P0, Q, R)]
            inp = np.concatenate(parts).astype(float, copy=False)
            at = [8 * i for i in itertools.accumulate([0] + [a.size for a in parts])]  # byte offsets
            a_in, a_out = inp.ctypes.data, buf.ctypes.data
            iw, w = self._workspace()
            err = self._run(a_in, n if np.ndim(x0) == 2 else 0, a_in + at[1], n * n if np.ndim(P0) == 3 else 0,
                            Y.ctypes.data, a_in + at[2], a_in + at[3],
                            *(a_out + 8 * int(e - z) for z, e in zip(sizes, ends)), runs, K, iw, w)
            if err:
                raise SymmonError(f"the compiled filter step {self.f.name()} returned an error")
            return out
        x0, P0 = np.asarray(x0, dtype=float), np.asarray(P0, dtype=float)
        Q, R = np.asarray(Q, dtype=float), np.asarray(R, dtype=float)
        # CasADi's VM: one mapped call per step over all runs, through buffers.
        fm = self.f.map(runs, "serial") if runs > 1 else self.f
        fb, ev = fm.buffer()
        x = np.ascontiguousarray(np.broadcast_to(x0, (runs, n)))
        P = np.ascontiguousarray(np.broadcast_to(P0, (runs, n, n)))
        Qb = np.ascontiguousarray(np.broadcast_to(Q, (runs,) + Q.shape))
        Rb = np.ascontiguousarray(np.broadcast_to(R, (runs,) + R.shape))
        step = {k: np.empty((runs,) + s) for k, s in shapes.items()}
        for k in range(K):
            yk = np.ascontiguousarray(Y[:, k])
            for i, a in enumerate((x, P, yk, Qb, Rb)):
                fb.set_arg(i, memoryview(a))
            for i, name in enumerate(_OUTPUTS):
                fb.set_res(i, memoryview(step[name]))
            ev()
            for name in _OUTPUTS:
                out[name][:, k] = step[name]
            x, P = step["x"].copy(), step["P"].copy()
        return out


_steps: dict[tuple, _CompiledStep] = {}
_steps_lock = threading.Lock()


def _compiled_step(f: Model, h: Model, transform: Transform, angle_states: frozenset[int]) -> _CompiledStep:
    """The compiled step of (f, h, transform), built once per process (C cached on disk)."""
    key = (f, h, transform, angle_states)
    with _steps_lock:
        step = _steps.get(key)
        if step is None:
            step = _steps[key] = _CompiledStep(f, h, transform, angle_states)
        return step


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class ConsistencyTest:
    """An averaged NEES or NIS with its two-sided χ² acceptance interval.

    With N independent terms of dimension d averaged, N·value ~ χ²(N d) for a consistent
    filter (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2), so the interval is
    [χ²_{Nd}(α/2), χ²_{Nd}(1 − α/2)] / N with α = 1 − ``confidence``.

    Attributes
    ----------
    value : ndarray
        The average: shape (K,) over the runs of a bank at each step; shape () over the
        K steps of a single run.
    lower, upper : float
        The bounds of the interval.
    dof : int
        N·d.
    confidence : float
    """

    value: np.ndarray
    lower: float
    upper: float
    dof: int
    confidence: float

    @property
    def inside(self) -> np.ndarray:
        """Whether each value lies in [lower, upper]."""
        return (self.value >= self.lower) & (self.value <= self.upper)

    def __repr__(self) -> str:
        frac = float(np.mean(self.inside))
        v = np.asarray(self.value)
        shown = f"{float(v):.4g}" if v.ndim == 0 else f"mean {float(v.mean()):.4g} over {v.size} steps"
        return (f"ConsistencyTest({shown}, {self.confidence:.0%} interval [{self.lower:.4g}, "
                f"{self.upper:.4g}], dof {self.dof}, {frac:.0%} inside)")


def _consistency(stat: np.ndarray, d: int, confidence: float) -> ConsistencyTest:
    """Average ``stat`` (K,) over K steps or (R, K) over the R runs; χ² bounds (§5.4.2)."""
    if not 0.0 < confidence < 1.0:
        raise SymmonError(f"confidence must lie in (0, 1), got {confidence!r}")
    value = stat.mean(axis=0)
    N = stat.shape[0]
    dof = N * d
    lo, hi = stats.chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof) / N
    return ConsistencyTest(_readonly(value), float(lo), float(hi), int(dof), float(confidence))


def _quadratic_forms(e: np.ndarray, C: np.ndarray) -> np.ndarray:
    """eᵀ C⁻¹ e for batches e (..., d), C (..., d, d), by a solve."""
    return np.einsum("...i,...i->...", e, np.linalg.solve(C, e[..., None])[..., 0])


@dataclass(frozen=True, eq=False)
class NonlinearKalmanResult:
    """Output of :meth:`NonlinearKalmanFilter.filter`.

    Shapes are for one run; a bank of R runs adds a leading axis R to every array
    (``x`` is (R, K, n), ``P`` is (R, K, n, n)).

    Attributes
    ----------
    x : ndarray, shape (K, n)
        Filtered means x̂_{k|k}.
    P : ndarray, shape (K, n, n)
        Filtered covariances P_{k|k}.
    x_pred : ndarray, shape (K, n)
        Predicted means x̂_{k|k−1}.
    P_pred : ndarray, shape (K, n, n)
        Predicted covariances P_{k|k−1}.
    innovation : ndarray, shape (K, n_y)
        Innovations ν_k = y_k − ŷ_{k|k−1} (angle components wrapped).
    S : ndarray, shape (K, n_y, n_y)
        Innovation covariances S_k.
    angle_states : tuple of int
        State components that are angles (their estimation errors are wrapped).
    method : str
        The filter, e.g. ``"UKF(alpha=1, beta=0, kappa=None)"``.
    choices : ndarray of str, shape (K,) or (R, K), or None
        For an :class:`Adaptive` filter: the filter used at each step (of each run), e.g.
        ``"EKF"`` or ``"CKF"``; None for a fixed transform.
    """

    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray
    P_pred: np.ndarray
    innovation: np.ndarray
    S: np.ndarray
    angle_states: tuple[int, ...] = ()
    method: str = ""
    choices: np.ndarray | None = None

    @property
    def runs(self) -> int | None:
        """Number of runs of a bank; None for a single run."""
        return int(self.x.shape[0]) if self.x.ndim == 3 else None

    def estimate(self, k: int, run: int | None = None) -> Gaussian:
        """N(x̂_{k|k}, P_{k|k}) at step k (0-based), of run ``run`` for a bank."""
        if (run is None) != (self.runs is None):
            raise ShapeError("give run= for a bank of runs, and only then")
        x, P = (self.x, self.P) if run is None else (self.x[run], self.P[run])
        return Gaussian(x[k], P[k])

    def nees(self, x_true: ArrayLike) -> np.ndarray:
        """Normalised estimation error squared ε_k = (x_k − x̂_k)ᵀ P_k⁻¹ (x_k − x̂_k).

        Parameters
        ----------
        x_true : array_like, shape of ``x``
            The true states x_k ((K, n), or (R, K, n) for a bank).

        Returns
        -------
        ndarray, shape (K,) or (R, K)
        """
        X = np.asarray(x_true, dtype=float)
        if X.shape != self.x.shape:
            raise ShapeError(f"x_true must have the shape of x, {self.x.shape}, got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ShapeError("x_true contains NaN or inf")
        e = X - self.x
        if self.angle_states:
            idx = list(self.angle_states)
            e[..., idx] = wrap_angle(e[..., idx])
        return _quadratic_forms(e, self.P)

    def nis(self) -> np.ndarray:
        """Normalised innovation squared ν_kᵀ S_k⁻¹ ν_k, shape (K,) or (R, K)."""
        return _quadratic_forms(self.innovation, self.S)

    def anees(self, x_true: ArrayLike, confidence: float = 0.95) -> ConsistencyTest:
        """Average NEES with its χ² interval: per step over the runs of a bank, or over the
        steps of a single run (Bar-Shalom et al. 2001, §5.4.2)."""
        return _consistency(self.nees(x_true), self.x.shape[-1], confidence)

    def anis(self, confidence: float = 0.95) -> ConsistencyTest:
        """Average NIS with its χ² interval, averaged as :meth:`anees`."""
        return _consistency(self.nis(), self.innovation.shape[-1], confidence)

    def __repr__(self) -> str:
        n, n_y = self.x.shape[-1], self.innovation.shape[-1]
        K = self.x.shape[-2]
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return (f"NonlinearKalmanResult({self.method}, {runs}steps={K}, n={n}, n_y={n_y}, "
                f"mean NIS {float(self.nis().mean()):.4g} (expected {n_y}))")



# --------------------------------------------------------------------------- adaptive
@dataclass(frozen=True)
class Adaptive:
    """A filter option that picks, at each step of each run, the cheapest adequate transform.

    Pass it as the ``transform`` of :class:`NonlinearKalmanFilter`.  At step k the filter
    decides twice, on the Gaussians the step transforms:

    1. the time update: f at N(x̂_{k−1|k−1}, P_{k−1|k−1}) (with N(0, Q) appended for
       general noise);
    2. the measurement update: h at the prior N(x⁻, P⁻) that the transform chosen in 1
       predicts.

    Each decision takes the candidates in the order of their cost in evaluations of g
    (:func:`symmon.advise.cost`, ties to the earlier candidate) and picks the first whose
    estimated error is at most ``tol``, in the unitless measure of
    :func:`symmon.advise.moment_error`, with the covariance that the filter compares the
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
    tol : float, default 0.01
        Largest acceptable unitless error, in (0, 1).
    candidates : tuple of TT1, TT2, UT or GaussHermite
        Default TT1 (EKF), TT2 (second-order EKF), ``UT.cubature()`` (CKF) and
        GaussHermite(3).
    reference : UT or GaussHermite, default GaussHermite(5)
    """

    tol: float = 1e-2
    candidates: tuple = (TT1(), TT2(), UT.cubature(), GaussHermite(3))
    reference: Transform = GaussHermite(5)

    def __post_init__(self) -> None:
        if isinstance(self.tol, bool) or not isinstance(self.tol, (int, float)) or not 0 < self.tol < 1:
            raise SymmonError(f"tol must be a number in (0, 1), got {self.tol!r}")
        cands = tuple(self.candidates)
        if not cands:
            raise SymmonError("candidates is empty")
        for t in cands + (self.reference,):
            if not _filterable(t):
                raise SymmonError(f"Adaptive candidates and reference must be TT1, TT2, UT or GaussHermite "
                                  f"(a Taylor or point rule), got {t!r}")
        object.__setattr__(self, "candidates", cands)

    def __repr__(self) -> str:
        return f"Adaptive(tol={self.tol:g}, candidates=[{', '.join(t.filter_label() for t in self.candidates)}])"


def _decide(model: Model, m: np.ndarray, C: np.ndarray, add: np.ndarray | None, angles: frozenset[int],
            order: list[Transform], reference: Transform, tol: float):
    """Index (into ``order``) of each run's choice, and the mean and covariance it gives.

    ``add`` is the additive noise covariance (added to Cov g), None with noise symbols.
    """
    cm = compiled(model)
    plus = (lambda c: c) if add is None else (lambda c: c + add)
    t1 = TT1().batch(cm, m, C, angles)
    Aw = whiteners(C)
    choice = np.full(m.shape[0], len(order) - 1)
    mean, cov = t1.mean.copy(), plus(t1.cov)  # overwritten unless TT1 is the choice or the fallback
    open_ = np.ones(m.shape[0], dtype=bool)
    i1 = next((i for i, t in enumerate(order) if t.taylor_order == 1), None)
    if i1 is not None:  # TT1 is the cheapest: its closed-form test comes first
        t2 = TT2().batch(cm, m, C, angles)
        ok = moment_distance(t1, t2, whiteners(plus(t2.cov)), Aw, angles) <= tol
        choice[ok] = i1
        open_ = ~ok
    rest = np.flatnonzero(open_)
    if rest.size:
        ms, Cs, Aws = m[rest], C[rest], Aw[rest]
        ref = reference.batch(cm, ms, Cs, angles)
        Ay = whiteners(plus(ref.cov))
        left = np.ones(rest.size, dtype=bool)
        for i, t in enumerate(order):
            if t.taylor_order == 1:
                continue
            b = t.batch(cm, ms, Cs, angles)
            ok = (moment_distance(b, ref, Ay, Aws, angles) <= tol) & left
            if i == len(order) - 1:
                ok = left  # the most expensive candidate is the fallback
            choice[rest[ok]] = i
            mean[rest[ok]], cov[rest[ok]] = b.mean[ok], plus(b.cov)[ok]
            left &= ~ok
    return choice, mean, cov


def _adaptive_run(kf: "NonlinearKalmanFilter", Y: np.ndarray, x0: np.ndarray, P0: np.ndarray):
    """The adaptive filter (:class:`Adaptive`) on a bank Y (R, K, n_y): outputs and choices."""
    ad: Adaptive = kf.transform
    f, h = kf.f_model, kf.h_model
    runs, K = Y.shape[:2]
    n, n_y = f.n_u, h.n_y

    order = sorted(ad.candidates, key=lambda t: cost(t, n))  # stable: ties keep the given order
    names = np.array([t.filter_label() for t in order])
    steps = [_compiled_step(f, h, t, kf.angle_states) for t in order]
    shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n), "innovation": (n_y,), "S": (n_y, n_y)}
    out = {key: np.full((runs, K) + s, np.nan) for key, s in shapes.items()}  # NaN after a failure
    chosen = np.empty((runs, K), dtype=int)
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
    return out, names[chosen]


# --------------------------------------------------------------------------- the filter
def _filterable(transform: Any) -> bool:
    """A rule a filter can compile: a Taylor rule or a point rule (declared capabilities)."""
    return isinstance(transform, Transform) and (transform.taylor_order is not None or transform.unit_rule(1) is not None)


@dataclass(frozen=True, eq=False)
class NonlinearKalmanFilter:
    """A Kalman filter whose prediction and update are NLTs, compiled to C.

    x_{k+1} = f(x_k, w_k), y_k = h(x_k, e_k); without noise symbols the noises are additive.
    TT1 gives the EKF, TT2 the second-order EKF, the UT the UKF (``UT.cubature()`` the CKF)
    and Gauss–Hermite the Gauss–Hermite filter (module notes).

    Parameters
    ----------
    f_model : Model
        The dynamics (n inputs, n outputs).  Outputs or inputs declared as angles are angle
        states.
    h_model : Model
        The measurement model (n inputs, n_y outputs; angle outputs wrap the innovation).
    Q : array_like
        Process noise covariance (Cov w, or additive (n, n)).
    R : array_like
        Measurement noise covariance (Cov e, or additive (n_y, n_y)).
    transform : TT1, TT2, UT, GaussHermite or Adaptive, default ``UT.ut1()``
        Used for both steps; :class:`Adaptive` picks one per step and run.

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
    transform: Transform | None = None
    _step: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        f = _check_model(self.f_model, "f_model")
        h = _check_model(self.h_model, "h_model")
        if f.n_y != f.n_u:
            raise ShapeError(f"f_model must map the state to itself: {f.n_u} inputs, {f.n_y} outputs")
        if h.n_u != f.n_u:
            raise ShapeError(f"h_model has {h.n_u} inputs but f_model has {f.n_u} states")
        Q = as_covariance(self.Q, "Q", dim=f.n_v if f.n_v else f.n_u)
        R = _noise_cov(h, self.R, "R")
        transform = UT.ut1() if self.transform is None else self.transform
        if not isinstance(transform, (Transform, Adaptive)):
            raise TypeError(f"transform must be a symmon transform, got {transform!r}")
        if not (isinstance(transform, Adaptive) or _filterable(transform)):
            raise SymmonError(
                f"transform must be TT1, TT2, UT or GaussHermite (a Taylor or point rule) for a Kalman filter, "
                f"got {transform!r}"
            )
        object.__setattr__(self, "Q", _readonly(Q))
        object.__setattr__(self, "R", _readonly(R))
        object.__setattr__(self, "transform", transform)

    @cached_property
    def angle_states(self) -> frozenset[int]:
        """State components that are angles: f's angle outputs and f's or h's angle inputs."""
        return frozenset(self.f_model.angle_outputs | self.f_model.angle_inputs | self.h_model.angle_inputs)

    @cached_property
    def method(self) -> str:
        """The filter's name: EKF, EKF2, UKF(...), CKF, GHKF(order=...) or Adaptive(...)."""
        if isinstance(self.transform, Adaptive):
            return repr(self.transform)
        return self.transform.filter_label()

    def _compiled(self) -> _CompiledStep:
        if self._step is None:
            object.__setattr__(self, "_step", _compiled_step(self.f_model, self.h_model, self.transform,
                                                             self.angle_states))
        return self._step

    def _initial(self, x0: Gaussian | ArrayLike, P0: ArrayLike | None, runs: int | None):
        """Validated initial mean(s) and covariance."""
        n = self.f_model.n_u
        if isinstance(x0, Gaussian):
            if P0 is not None:
                raise ShapeError("P0 must not be given with a Gaussian x0 (it carries its covariance)")
            _check_gaussian(x0, "x0", dim=n)
            return np.asarray(x0.mean, dtype=float), np.asarray(x0.cov, dtype=float)
        if P0 is None:
            raise TypeError("x0 must be a symmon.Gaussian, or a mean given together with P0")
        m = np.asarray(x0, dtype=float)
        if not (m.shape == (n,) or (runs is not None and m.shape == (runs, n))):
            want = f"({n},)" + ("" if runs is None else f" or ({runs}, {n})")
            raise ShapeError(f"x0 must have shape {want}, got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ShapeError("x0 contains NaN or inf")
        C = np.asarray(P0, dtype=float)
        if runs is not None and C.shape == (runs, n, n):  # one covariance per run
            for r in range(runs):
                as_covariance(C[r], f"P0[{r}]", dim=n)
            return m, C
        return m, as_covariance(P0, "P0", dim=n)

    def filter(self, ys: ArrayLike, x0: Gaussian | ArrayLike, P0: ArrayLike | None = None) -> NonlinearKalmanResult:
        """Predict, then update, for each measurement (the convention of :class:`KalmanFilter`).

        Parameters
        ----------
        ys : array_like, shape (K, n_y) or (R, K, n_y)
            Measurements y_1 … y_K; a leading axis filters R independent runs (a bank) in
            one compiled call.
        x0 : Gaussian, or array_like of shape (n,) or (R, n)
            The state x_0 before the first prediction: a Gaussian, or its mean (one for all
            runs, or one per run) with ``P0``.
        P0 : array_like, shape (n, n) or (R, n, n), optional
            Covariance of x_0 when ``x0`` is a mean (one for all runs, or one per run: a
            bank continued after a known jump of the state, e.g. an observer's manoeuvre).

        Returns
        -------
        NonlinearKalmanResult
            Arrays with a leading axis R for a bank.

        Raises
        ------
        ShapeError
            Bad shapes or non-finite data.
        SymmonError
            The filter produced NaN or inf (a singular S, or a covariance that lost
            positive definiteness), naming the run and step.
        """
        n_y = self.h_model.n_y
        Y = np.asarray(ys, dtype=float)
        if Y.ndim not in (2, 3) or Y.shape[-1] != n_y or Y.shape[-2] == 0 or Y.shape[0] == 0:
            raise ShapeError(f"ys must have shape (K, {n_y}) or (R, K, {n_y}) with K >= 1, got {Y.shape}")
        if not np.all(np.isfinite(Y)):
            raise ShapeError("ys contains NaN or inf")
        runs = Y.shape[0] if Y.ndim == 3 else None
        m0, C0 = self._initial(x0, P0, runs)
        Yb = Y.reshape((runs or 1,) + Y.shape[-2:])
        choices = None
        if isinstance(self.transform, Adaptive):
            out, choices = _adaptive_run(self, Yb, m0, C0)
        else:
            out = self._compiled()(m0, C0, Yb, self.Q, self.R)
        bad = ~np.isfinite(out["x"]).all(axis=-1) | ~np.isfinite(out["P"]).all(axis=(-1, -2))
        if bad.any():
            r, k = np.argwhere(bad)[0]
            where = f"step {k}" if runs is None else f"run {r}, step {k}"
            raise SymmonError(
                f"{self.method}: the filter produced NaN or inf at {where} (the innovation "
                "covariance S is singular, a covariance lost positive definiteness, or a "
                "derivative is undefined there, e.g. sqrt at 0 or atan2(0, 0))"
            )
        arrays = {k: v if runs is not None else v[0] for k, v in out.items()}
        for v in arrays.values():
            v.flags.writeable = False  # fresh arrays of this call: frozen, not copied
        if choices is not None:
            choices = choices if runs is not None else choices[0]
            choices.flags.writeable = False
        return NonlinearKalmanResult(**arrays, angle_states=tuple(sorted(self.angle_states)),
                                     method=self.method, choices=choices)
