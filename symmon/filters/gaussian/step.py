"""The compiled step of the nonlinear Kalman filters: one predict + update, and its run loop in C.

The model is x_{k+1} = f(x_k, w_k), y_k = h(x_k, e_k), w_k ~ N(0, Q), e_k ~ N(0, R).  The
time update is an NLT of f and the measurement update the indirect step of Gustafsson &
Hendeby (Lemma 7.1); the transform (a Taylor rule or a point rule) computes both NLTs.
With noise symbols (general noise) the rule runs on the augmented vector [x; w] with
covariance blkdiag(P, Q) (resp. [x; e], blkdiag(P⁻, R)); with additive noise Q and R are
added to the covariances.  One step reads

    x⁻ = E f,  P⁻ = Cov f (+ Q),
    ŷ = E h,  S = Cov h (+ R),  P^{xy} = Cov(x, h),
    ν = y − ŷ,  K = P^{xy} S⁻¹,  x⁺ = x⁻ + K ν,  P⁺ = P⁻ − K S Kᵀ.

Angles (Crouse 2015): the angle outputs of h get a circular or wrapped mean, wrapped
residuals and a wrapped innovation; the angle states the same in the time update, and x⁺
is wrapped.

The whole step, from the sigma points (or the Taylor terms) to the wrapped update, is one
CasADi function of (x, P, y, Q, R), built from the models' SX graphs with a symbolic Cholesky
factor (the moment formulas of :mod:`symmon.codegen.symbolic`): straight-line SX for small
filters, and from :data:`~symmon.codegen.symbolic.MX_FROM` variables on an MX graph whose matrix products, map over
the points and solve are loops in C.  Its C code goes through the compile policy of every
generated function (cached on disk, ``docs/compile.md``), and a C loop around it runs all
the steps of all the runs of a filter bank in one call; without a compiler, or while a large
step builds in the background, the step runs on CasADi's virtual machine.  From
:data:`~symmon.filters.gaussian._ekfstep.C_EKF_FROM` states on, the C loop of a TT1 or TT2 step (EKF, IEKF, EKF2)
with additive noise calls the hand-written C step of :mod:`symmon.filters.gaussian._ekfstep` around CasADi's
model pieces instead (the MX step remains the VM's); from
:data:`~symmon.filters.gaussian._ekfstep.C_SQRT_EKF_FROM` states on, a square-root TT1 step (SR-EKF, SR-IEKF)
with additive noise likewise calls the C square-root step of :func:`~symmon.filters.gaussian._ekfstep.sqrt_ekf_c`, and
from :data:`~symmon.filters.gaussian._ukfstep.C_SQRT_UKF_FROM` states on a square-root point-rule step (SR-UKF,
square-root cubature) with additive noise and non-negative weights that of :func:`~symmon.filters.gaussian._ukfstep.sqrt_ukf_c`.  :class:`symmon.NonlinearKalmanFilter` (:mod:`symmon.filters`)
and the adaptive filter (:mod:`symmon.filters.gaussian.adaptive`) run it.

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
D. F. Crouse, "Cubature/unscented/sigma point Kalman filtering with angular measurement
models", FUSION 2015 (wrapped residuals).
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import threading
from typing import Any, Iterable

import casadi as ca
import numpy as np

from ...compile.ccache import NativeLibrary
from ...compile.ckernels import STOPPED
from ...compile.csource import c_defines, c_file
from ...compile.compiled import (WorkArrays, compiled, compiled_with_params, cpu_count, even_spans, generated_c,
                                 padded, run_stoppable)
from ...errors import SymmonError
from ...core.model import Model
from ...codegen.symbolic import graph_kind, moments, tril_inverse, wrap_entries
from ...transforms.base import Transform
from ..inputs import filter_params
from ._ekfstep import C_EKF_FROM, C_SQRT_EKF_FROM, ekf_c, ekf_pieces, sqrt_ekf_c
from ._ukfstep import c_sqrt_ukf_applies, sqrt_ukf_c, sqrt_ukf_kind, sqrt_ukf_pieces
from ._sqrtstep import covariance_of, factor_of, noise_factor, sqrt_nees_graph, sqrt_predict_graph, sqrt_update_graph

#: Names of the outputs of the step function, in order.
_OUTPUTS = ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik", "nis")


def sym(A):
    """A exactly symmetric: its lower triangle mirrored, so that rounding leaves no asymmetry.

    One gather of the n² entries, where the average (A + Aᵀ)/2 takes three passes (a
    transpose, a sum, a scaling); on the matrices of a filter step, symmetric up to rounding,
    the two differ by rounding only."""
    n = A.shape[0]
    lower = [max(i, j) + min(i, j) * n for j in range(n) for i in range(n)]  # column-major
    return ca.reshape(ca.densify(A).nz[lower], n, n)


def step_kind(f: Model, h: Model, transform: Transform):
    """SX or MX for the step of (f, h, transform), and the Cholesky factor that goes with it."""
    dims = (f.n_u + f.n_v, f.n_u + h.n_v)
    points = max(len(transform.unit_rule(d)[0]) for d in dims) if transform.point_rule else 0
    return graph_kind(max(dims), points)


def model_moments(model: Model, m, P, transform: Transform, angles, chol, p=None):
    """E g, Cov g, Cov(g, w) of the model at N(m, P), its parameters p (their values, a
    symbol of the graph) fixed: :func:`symmon.codegen.symbolic.moments`."""
    if model.n_p:
        return moments(compiled_with_params(model), m, P, transform, angles, chol, p)
    return moments(compiled(model), m, P, transform, angles, chol)


def select_params(model: Model, names: tuple, p):
    """The entries of the filter's parameter vector p (named ``names``) that ``model`` uses,
    found by name (:func:`filter_params`: one name, one parameter)."""
    if not model.n_p:
        return None
    keys = [str(q) for q in names]
    return ca.vertcat(*[p[keys.index(str(s))] for s in model.params])


def predict_graph(f: Model, transform: Transform, angle_states: frozenset[int], x, P, Q, chol, p=None,
                  cross: bool = False):
    """The time update: x⁻ = E f, P⁻ = Cov f (+ Q), the NLT of f (on [x; w] with general noise),
    with f's parameters ``p``; with ``cross``, also Cov(x⁻, x) (n × n), for the smoother."""
    kind = type(x)
    n = x.shape[0]
    if f.n_v:
        mean, cov, cxw = model_moments(f, ca.vertcat(x, kind.zeros(f.n_v)), ca.diagcat(P, Q), transform,
                                       angle_states, chol, p)
        cxw = cxw[:, :n]
    else:
        mean, cov, cxw = model_moments(f, x, P, transform, angle_states, chol, p)
        cov = cov + Q
    if cross:
        return wrap_entries(mean, angle_states), sym(cov), cxw
    return wrap_entries(mean, angle_states), sym(cov)


def update_graph(h: Model, transform: Transform, angle_states: frozenset[int], x_pred, P_pred, y, R, chol,
                 mask=None, p=None, iterations: int = 1):
    """The measurement update, Lemma 7.1 on the NLT of h at N(x⁻, P⁻): (x⁺, P⁺, ν, S, log N(ν; 0, S), NIS νᵀS⁻¹ν).

    ``mask`` (n_y, 1 for a measured component and 0 for a missing one; None: all measured)
    restricts the update to the measured block: with D = diag(mask), ν̃ = D ν,
    S̃ = D S D + (I − D) and P̃^{xy} = P^{xy} D (Cov(y, x) with zero rows), the gain P̃^{xy} S̃⁻¹
    has zero columns for the missing components and is the gain of the measured block
    elsewhere, so x⁺ and P⁺ are those of the update on the measured components only, and
    log N(ν̃; 0, S̃) (with the 2π term counted for the measured ones) their log-likelihood;
    nothing measured is a pure prediction with log-likelihood 0.  A missing component must be
    finite in ``y`` (the caller writes 0), so that no NaN enters the products.  ``p``: the
    values of h's parameters.

    ``iterations`` > 1 (TT1 only) is the iterated EKF (Bell & Cathey 1993): Gauss–Newton
    steps x_{i+1} = x⁻ + K_i (y − h(x_i) − H_i (x⁻ − x_i)), K_i = P⁻ H_iᵀ S_i⁻¹ with h
    linearised at x_i (x_0 = x⁻; H_i (x⁻ − x_i) = P^{xy}_i P⁻⁻¹ (x⁻ − x_i)), and P⁺ = P⁻ − K S Kᵀ
    of the last one; ν, S and the log-likelihood are those at x⁻ (the prediction errors).
    """
    kind, n, n_y = type(x_pred), x_pred.shape[0], h.n_y
    y_angles = frozenset(h.angle_outputs)

    def linearised(m):
        if h.n_v:
            y_hat, S, cross = model_moments(h, ca.vertcat(m, kind.zeros(h.n_v)), ca.diagcat(P_pred, R),
                                            transform, y_angles, chol, p)
            cross = cross[:, :n]
        else:
            y_hat, S, cross = model_moments(h, m, P_pred, transform, y_angles, chol, p)
            S = S + R
        return y_hat, sym(S), cross

    def masked(nu, S, cross):
        if mask is None:
            return nu, S, cross
        # D S D and D Cov(y, x) (rows of the missing components zero) entrywise, not as
        # products with the diagonal D (a sparse product, slower than the whole update).
        return (mask * nu, S * ca.mtimes(mask, mask.T) + ca.diag(1 - mask),
                cross * ca.repmat(mask, 1, cross.shape[1]))

    def whitened(S, cross):
        # With L Lᵀ = S and W = L⁻¹ P^{yx}: K = P^{xy} S⁻¹ = Wᵀ L⁻¹ and K S Kᵀ = Wᵀ W, from one
        # factor (a zero pivot gives a zero row of L⁻¹, and log det S = −inf below).
        L = chol(S)
        inv = tril_inverse(L)
        return L, inv, ca.mtimes(inv, cross)

    y_hat, S, cross = linearised(x_pred)
    nu, S, cross = masked(wrap_entries(y - y_hat, y_angles), S, cross)
    measured = n_y if mask is None else ca.sum1(mask)
    L, inv, W = whitened(S, cross)
    # K ν = Wᵀ (L⁻¹ ν): the whitened innovation serves the NIS too, and the gain (n × n_y,
    # n n_y² operations) is never formed.
    white = ca.mtimes(inv, nu)
    x_i = x_pred + ca.mtimes(W.T, white)
    W_i = W
    for _ in range(iterations - 1):
        y_hat_i, S_i, cross_i = linearised(x_i)
        step_back = ca.mtimes(cross_i, ca.solve(P_pred, x_pred - x_i))  # H_i (x⁻ − x_i)
        r_i, S_i, cross_i = masked(wrap_entries(y - y_hat_i, y_angles) - step_back, S_i, cross_i)
        _, inv_i, W_i = whitened(S_i, cross_i)
        x_i = x_pred + ca.mtimes(W_i.T, ca.mtimes(inv_i, r_i))
    x_new = wrap_entries(x_i, angle_states)
    P_new = sym(ca.mac(-W_i.T, W_i, P_pred))  # P⁻ − WᵀW, accumulated into a copy of P⁻
    # log N(ν; 0, S) = −(νᵀ S⁻¹ ν + log det S + m log 2π)/2, with νᵀ S⁻¹ ν = |L⁻¹ ν|²: NaN when
    # S is not positive definite (a negative pivot), +inf when it is singular.
    nis = ca.dot(white, white)
    log_det = 2 * ca.sum1(ca.log(ca.diag(L)))
    loglik = -0.5 * (nis + log_det + measured * math.log(2 * math.pi))
    return x_new, P_new, nu, S, loglik, nis




def _step_function(f: Model, h: Model, transform: Transform, angle_states: frozenset[int],
                   name: str, iterations: int = 1, square_root: bool = False) -> ca.Function:
    """(x, P, y, Q, R, mask, p) ↦ (x⁺, P⁺, x⁻, P⁻, ν, S, log-likelihood, NIS): one predict + update
    step, on the measured components of y (``mask``, :func:`update_graph`), with the values p
    of the parameters (:func:`filter_params`; size 0 without).  With ``square_root``, P, Q, R,
    P⁺ and P⁻ are lower Cholesky factors (:mod:`symmon.filters.gaussian._sqrtstep`); S is still the
    innovation covariance."""
    n, n_y = f.n_u, h.n_y
    nq, nr = f.n_v or n, h.n_v or n_y
    names = filter_params(f, h)
    kind, chol = step_kind(f, h, transform)
    x, P, y = kind.sym("x", n), kind.sym("P", n, n), kind.sym("y", n_y)
    Q, R, mask = kind.sym("Q", nq, nq), kind.sym("R", nr, nr), kind.sym("mask", n_y)
    p = kind.sym("p", len(names))
    if square_root:
        # SX: the factors' upper triangles are structural zeros (the loop's factors are lower
        # triangular), so that no product or reflection works on them.
        Sf, Qf, Rf = (ca.tril(a) for a in (P, Q, R)) if kind is ca.SX else (P, Q, R)
        x_pred, P_pred = sqrt_predict_graph(f, transform, angle_states, x, Sf, Qf, select_params(f, names, p))
        x_new, P_new, nu, Sy, loglik, nis = sqrt_update_graph(h, transform, angle_states, x_pred, P_pred, y, Rf,
                                                              mask, select_params(h, names, p), iterations)
        S = ca.mtimes(Sy, Sy.T)
    else:
        x_pred, P_pred = predict_graph(f, transform, angle_states, x, P, Q, chol, select_params(f, names, p))
        # The NIS comes with the step, so that a lean bank need not keep ν and S.
        x_new, P_new, nu, S, loglik, nis = update_graph(h, transform, angle_states, x_pred, P_pred, y, R, chol,
                                                        mask, select_params(h, names, p), iterations)
    outs = [ca.densify(a) for a in (x_new, P_new, x_pred, P_pred, nu, S, loglik, nis)]
    return ca.Function(name, [x, P, y, Q, R, mask, p], outs, ["x", "P", "y", "Q", "R", "mask", "p"],
                       ["x_new", "P_new", "x_pred", "P_pred", "innovation", "S", "loglik", "nis"],
                       {"cse": True})


def nees_graph(x, P, truth, angle_states: Iterable[int], chol):
    """(ε, t): the NEES ε = eᵀ P⁻¹ e of the error e = truth − x (angle entries wrapped), and
    t = tr Ρ⁻¹, for the singularity test of :func:`symmon.filters.results.step_nees`.

    As :meth:`symmon.KalmanResult.nees`, the form is computed on the correlation matrix
    Ρ = P / σσᵀ (σ = √diag P), ε = |L⁻¹ (e / σ)|² with L Lᵀ = Ρ, so that it is the same in any
    units; t = |L⁻¹|²_F.  A zero, negative or NaN pivot makes t infinite (a zero pivot would
    otherwise drop its component from ε), and a zero variance makes both NaN.
    """
    e = wrap_entries(truth - x, angle_states)
    r = 1 / ca.sqrt(ca.diag(P))
    L = chol(P * ca.mtimes(r, r.T))
    inv = tril_inverse(L)
    z = ca.mtimes(inv, e * r)
    return ca.dot(z, z), ca.sumsqr(inv) / ca.mmin(ca.diag(L) > 0)


def _nees_function(f: Model, h: Model, transform: Transform, angle_states: frozenset[int], name: str,
                   square_root: bool = False) -> ca.Function:
    """(x, P, truth) ↦ (NEES, tr Ρ⁻¹) of one step's estimate (:func:`nees_graph`), of the kind
    (SX or MX) of the filter's step; with ``square_root``, P is its lower Cholesky factor."""
    kind, chol = step_kind(f, h, transform)
    n = f.n_u
    x, P, t = kind.sym("x", n), kind.sym("P", n, n), kind.sym("truth", n)
    outs = sqrt_nees_graph(x, P, t, angle_states) if square_root else nees_graph(x, P, t, angle_states, chol)
    return ca.Function(name, [x, P, t], list(outs), ["x", "P", "truth"], ["nees", "trace"], {"cse": True})


class CompiledLoop:
    """A step function ``f`` with its C loop ``{name}_run`` over the steps and runs of a bank,
    built by the compile policy of every generated function (docs/compile.md): a small one now,
    a large one in the background while CasADi's VM evaluates.  The filter step and the
    smoother's backward step are two of them.

    Parameters
    ----------
    f : casadi.Function
    code : str
        The C of ``f`` and its loop.
    argtypes : list
        The ctypes argument types of ``{name}_run``.
    stacklevel : int
        For the warnings of a build, counted from the subclass's constructor (one frame up
        from here: the NativeLibrary gets one more).
    also : tuple of casadi.Function
        Other functions in ``code`` that the loop calls (their work arrays are shared).
    background : bool
        Build in the background whatever the size of ``code`` (``f`` on CasADi's VM meanwhile).
    """

    def __init__(self, f: ca.Function, code: str, argtypes: list, stacklevel: int = 4,
                 also: tuple[ca.Function, ...] = (), background: bool = False) -> None:
        self.f = f
        self._work = WorkArrays(f, *also)
        self._argtypes = argtypes
        # Without a compiler, compiled() has already warned (once) while the step was built.
        self._lib = NativeLibrary(code, f.name(), self._load, stacklevel=stacklevel + 1, background=background)

    def _load(self, so):
        run = getattr(ctypes.CDLL(str(so)), f"{self.f.name()}_run")
        run.argtypes = self._argtypes
        run.restype = ctypes.c_int
        return run

    @property
    def is_compiled(self) -> bool:
        return self._lib.get() is not None

    @property
    def evaluator(self) -> str:
        """``"compiled"``, ``"vm"`` or ``"vm (C build running)"`` (docs/compile.md)."""
        return self._lib.evaluator

    def run_chunks(self, part, chunks: list, what: str, long: bool = False) -> None:
        """``part(chunk, stop)`` for each chunk of runs, on one thread per chunk (ctypes
        releases the GIL in the C call, so they run in parallel); ``stop`` is the address of
        the flag the C loops poll between steps (its ``stop`` argument, ``step_loop.c``).
        A Ctrl-C (KeyboardInterrupt) of the waiting thread sets it and waits for the loops,
        which end at their next step, before it propagates: no loop of an interrupted bank
        keeps running in the shared pool for the next call to queue behind.  ``long``
        (:func:`long_bank`): a single chunk on the main thread runs on the pool too, so that
        a Ctrl-C stops it (:func:`~symmon.compile.compiled.run_stoppable`).

        Raises
        ------
        SymmonError
            If a chunk's C loop returned an error, naming ``what``.
        """
        codes = run_stoppable(part, chunks, long)
        if any(codes):
            raise SymmonError(f"the compiled {what} {self.f.name()} returned an error")


class _CompiledStep(CompiledLoop):
    """The step function of one (f, h, transform), as C with a run loop or on CasADi's VM."""

    def __init__(self, f: Model, h: Model, transform: Transform, angle_states: frozenset[int],
                 iterations: int = 1, square_root: bool = False) -> None:
        key = repr((f.key, h.key, transform, sorted(angle_states), sorted(h.angle_outputs))
                   + ((iterations,) if iterations > 1 else ()) + (("square_root",) if square_root else ()))
        name = "sm_nkf_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        fn = _step_function(f, h, transform, angle_states, name, iterations, square_root)
        self.nees_f = _nees_function(f, h, transform, angle_states, name + "nees_of", square_root)
        self.square_root = square_root
        self.n, self.n_y = n, n_y = f.n_u, h.n_y
        self.n_p = len(filter_params(f, h))
        self._shapes = {"x": (n,), "P": (n, n), "x_pred": (n,), "P_pred": (n, n),
                        "innovation": (n_y,), "S": (n_y, n_y), "loglik": (), "nis": ()}
        # A larger EKF, IEKF or EKF2 (TT1 or TT2, additive noise) runs the C step of
        # symmon.filters.gaussian._ekfstep around CasADi's model pieces; the MX step fn stays for CasADi's
        # VM (and the fit, the IMM).
        self.c_ekf = (transform.taylor_order in (1, 2) and not square_root and not f.n_v and not h.n_v
                      and n >= C_EKF_FROM)
        # The square-root EKF (TT1, additive noise) likewise, the factor arithmetic of
        # _sqrtstep in C (sqrt_ekf_step.c).
        self.c_sqrt_ekf = (transform.taylor_order == 1 and square_root and not f.n_v and not h.n_v
                           and n >= C_SQRT_EKF_FROM)
        # The square-root UKF (a point rule with non-negative weights, additive noise): the
        # factor arithmetic in C around CasADi's sigma-point pieces (sqrt_ukf_step.c).
        self.c_sqrt_ukf = square_root and c_sqrt_ukf_applies(f, h, transform, iterations)
        if self.c_sqrt_ukf:
            names = filter_params(f, h)
            kind = sqrt_ukf_kind(n)
            xs, ys, ps = kind.sym("x", n), kind.sym("y", n_y), kind.sym("p", len(names))
            pieces, ks = sqrt_ukf_pieces(f, h, transform, angle_states, select_params(f, names, ps),
                                        select_params(h, names, ps), xs, ys, ps, name)
            funcs = (self.nees_f,) + pieces
            ukf_code, scratch = sqrt_ukf_c(name, n, n_y, ks, bool(angle_states), pieces)
            code, step, s = generated_c(*funcs) + ukf_code, f"{name}_sqrt_ukf", "s"
        elif self.c_ekf or self.c_sqrt_ekf:
            names = filter_params(f, h)
            xs, ys, ps = ca.SX.sym("x", n), ca.SX.sym("y", n_y), ca.SX.sym("p", len(names))
            pieces, pattern = ekf_pieces(f, h, angle_states, select_params(f, names, ps),
                                         select_params(h, names, ps), xs, ys, ps, name,
                                         transform.taylor_order)
            funcs = (self.nees_f,) + pieces
            if self.c_sqrt_ekf:
                ekf_code, scratch = sqrt_ekf_c(name, n, n_y, pattern, iterations)
                step = f"{name}_sqrt_ekf"
            else:
                ekf_code, scratch = ekf_c(name, n, n_y, pattern, iterations)
                step = f"{name}_ekf"
            code, s = generated_c(*funcs) + ekf_code, "s"
        else:
            funcs, scratch = (fn, self.nees_f), 0
            code, step, s = generated_c(*funcs), name, 0
        # The run loop (step_loop.c): for each run, K steps, each reading the previous step's output.
        code += c_defines(
            KFL_NAME=name, KFL_STEP=step, KFL_S=s, KFL_NEES=f"{name}nees_of",
            KFL_SZ_ARG=max(max(g.sz_arg() for g in funcs), 7), KFL_SZ_RES=max(max(g.sz_res() for g in funcs), 8),
            KFL_N=self.n, KFL_NN=self.n * self.n, KFL_N_Y=self.n_y, KFL_N_P=self.n_p, KFL_SCRATCH=scratch,
            KFL_STOPPED=STOPPED) + c_file(__package__, "step_loop.c")
        argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong]
                    + [ctypes.c_void_p] * 8 + [ctypes.c_longlong] * 2 + [ctypes.c_void_p] * 4)
        super().__init__(fn, code, argtypes, also=funcs)

    def __call__(self, x0: np.ndarray, P0: np.ndarray, Y: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 use_c: bool = True, keep: frozenset[str] | None = None,
                 params: np.ndarray | None = None, truth: np.ndarray | None = None,
                 check_finite: bool = False, factored: bool = False) -> dict[str, np.ndarray]:
        """Run the bank: x0 (n,) or (runs, n), P0 (n, n) or (runs, n, n), Y (runs, K, n_y), and
        the parameters' values (runs, K, n_p) (None: no parameters).

        Returns the outputs of every step, (runs, K, ...) each, or only those named in
        ``keep`` (the others are not stored, so a bank of long runs of a large state need
        not hold its P⁻, say).  A NaN in Y is a missing measurement: the step updates on the
        measured components (:func:`update_graph`).  With the true states ``truth``
        (runs, K, n), also ``"nees"`` and ``"nees_trace"`` of each step (:func:`nees_graph`),
        computed right after the step, so that neither x nor P need be kept for them.  With
        ``check_finite``, also ``"first_nonfinite"`` (runs,): the first step of each run whose
        x, P or log-likelihood is not finite, or -1 (the C loop tests every step as it goes,
        and stops a run that failed, so the kept arrays need no second pass).

        A square-root step (:mod:`symmon.filters.gaussian._sqrtstep`) reads P0, Q and R as covariances
        and factors them once (with ``factored``, P0 is already the lower factor S₀ of P0); its
        kept ``P`` and ``P_pred`` are S Sᵀ, with the factors S themselves as ``P_chol`` and
        ``P_pred_chol``."""
        if self.square_root:
            # The loop reads each factor transposed (column-major), C-contiguous.
            U0 = np.ascontiguousarray(np.swapaxes(P0, -1, -2), dtype=float) if factored else factor_of(P0)
            out = self._run(x0, U0, Y, noise_factor(Q).T, noise_factor(R).T, use_c, keep, params, truth,
                            check_finite)
            for k in ("P", "P_pred"):
                if k in out:
                    out[k], out[k + "_chol"] = covariance_of(out[k])
            return out
        return self._run(x0, P0, Y, Q, R, use_c, keep, params, truth, check_finite)

    def _run(self, x0, P0, Y, Q, R, use_c, keep, params, truth, check_finite) -> dict[str, np.ndarray]:
        """:meth:`__call__` on the step's own inputs (factors for a square-root step)."""
        runs, K = Y.shape[:2]
        n = self.n
        shapes = self._shapes
        kept = set(shapes) if keep is None else set(keep)
        Y = np.asarray(Y, dtype=float)
        measured = ~np.isnan(Y)
        mask = np.ascontiguousarray(measured, dtype=float)
        Y = np.ascontiguousarray(np.where(measured, Y, 0.0))
        if params is None:
            if self.n_p:
                raise SymmonError("the filter step needs the values of its parameters")
            params = np.zeros((runs, K, 1))  # a valid pointer; no entry is read
        params = np.ascontiguousarray(params, dtype=float)
        if truth is not None:
            truth = np.ascontiguousarray(truth, dtype=float)
            kept |= {"nees", "nees_trace"}
        run = self._lib.get() if use_c else None
        if run is None:
            full = self._vm(x0, P0, Y, Q, R, mask, params[..., :self.n_p], truth)
            out = {k: v for k, v in full.items() if k in kept}
            if check_finite:
                out["first_nonfinite"] = first_nonfinite(full["loglik"], full["x"], full["P"])
            return out
        # A kept output: its (runs, K, ...) block; x and P when not kept: two slots per thread
        # of the bank (the next step reads them), on the thread's own cache lines; any
        # other: not written.
        per_step = [math.prod(s) for s in shapes.values()]
        chunks = chunk_runs(runs, K, x0.shape[-1])
        blocks = {k: np.empty((runs, K) + s) if k in kept
                  else [padded(2 * math.prod(s)) for _ in chunks] if k in ("x", "P") else None
                  for k, s in shapes.items()}
        strides = np.array([z if k in kept else 0 for k, z in zip(shapes, per_step)], dtype=np.int64)
        for k in ("nees", "nees_trace"):  # outs[8], outs[9] of the C loop
            blocks[k] = np.empty((runs, K)) if truth is not None else None
        # CasADi is column-major: the symmetric P, Q, R, S need no transposition, and a C
        # row (runs, n) is a column-major (n, runs).
        x0 = np.ascontiguousarray(x0, dtype=float)
        P0 = np.ascontiguousarray(P0, dtype=float)
        Q, R = np.ascontiguousarray(Q, dtype=float), np.ascontiguousarray(R, dtype=float)
        x_step = n if x0.ndim == 2 else 0
        P_step = n * n if P0.ndim == 3 else 0
        failed = np.empty(runs, dtype=np.int64) if check_finite else None

        def part(c: int, stop: int) -> int:
            a, b = chunks[c]
            outs = (ctypes.c_void_p * len(blocks))(*[
                None if blk is None else blk[a].ctypes.data if k in kept else blk[c].ctypes.data
                for k, blk in blocks.items()])
            iw, w = self._work.addresses()  # one per thread
            return run(x0.ctypes.data + 8 * a * x_step, x_step, P0.ctypes.data + 8 * a * P_step, P_step,
                       Y[a].ctypes.data, Q.ctypes.data, R.ctypes.data, mask[a].ctypes.data,
                       params[a].ctypes.data, None if truth is None else truth[a].ctypes.data, outs,
                       strides.ctypes.data, b - a, K, iw, w, None if failed is None else failed[a:].ctypes.data, stop)

        self.run_chunks(part, list(range(len(chunks))), "filter step", long_bank(runs, K, n))
        out = {k: b for k, b in blocks.items() if k in kept}
        if failed is not None:
            out["first_nonfinite"] = failed
        return out

    def _vm(self, x0, P0, Y: np.ndarray, Q, R, mask: np.ndarray, params: np.ndarray,
            truth: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Every output of every step on CasADi's VM: one mapped call per step over the runs
        (and, with ``truth``, of the NEES function)."""
        runs, K = Y.shape[:2]
        n = self.n
        shapes = self._shapes
        out = {k: np.empty((runs, K) + s) for k, s in shapes.items()}
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
            yk, mk, pk = (np.ascontiguousarray(a[:, k]) for a in (Y, mask, params))
            for i, a in enumerate((x, P, yk, Qb, Rb, mk, pk)):
                fb.set_arg(i, memoryview(a))
            for i, name in enumerate(_OUTPUTS):
                fb.set_res(i, memoryview(step[name]))
            ev()
            for name in _OUTPUTS:
                out[name][:, k] = step[name]
            x, P = step["x"].copy(), step["P"].copy()
        if truth is not None:
            N = runs * K
            gm = self.nees_f.map(N, "serial")
            # A mapped matrix input is the matrices side by side, n × (N n), each the step's
            # output as CasADi wrote it (column-major: the transpose of the C-order block; the
            # same for a symmetric P, the factor S itself for a square-root step).
            Ps = out["P"].reshape(N, n, n).transpose(2, 0, 1).reshape(n, N * n)
            vals = gm(out["x"].reshape(N, n).T, Ps, truth.reshape(N, n).T)
            out["nees"], out["nees_trace"] = (np.asarray(v).reshape(runs, K) for v in vals)
        return out


def first_nonfinite(loglik: np.ndarray, x: np.ndarray | None, P: np.ndarray | None) -> np.ndarray:
    """The first step of each run (runs, K, ...) whose log-likelihood, x or P (None: not
    tested) is not finite, or -1: what the C loop of :class:`_CompiledStep` reports as it goes."""
    bad = ~np.isfinite(loglik)
    if x is not None:
        bad |= ~np.isfinite(x).all(axis=-1)
    if P is not None:
        bad |= ~np.isfinite(P).all(axis=(-1, -2))
    return np.where(bad.any(axis=1), bad.argmax(axis=1), -1)


#: Least work of a thread, in steps × n³ (n states): 2000 steps of a 4-state filter, about a
#: millisecond; a 10-state step costs about 20 times a 4-state one, a 30-state one 200 times.
MIN_WORK_PER_THREAD = 2000 * 4**3


def chunk_runs(runs: int, K: int, n: int) -> list[tuple[int, int]]:
    """The runs [a, b) of each thread: one per CPU, as long as each gets enough work
    (:data:`MIN_WORK_PER_THREAD`) for the runs × K steps of an n-state filter."""
    return even_spans(runs, min(cpu_count(), runs, (runs * K * n**3) // MIN_WORK_PER_THREAD))


def long_bank(runs: int, K: int, n: int) -> bool:
    """Whether the runs × K steps of an n-state filter take long enough (tens of
    milliseconds: 50 threads' :data:`MIN_WORK_PER_THREAD`, a state of fewer than 4 counted as
    4, the cost of a small step being its overhead) that a single chunk on the main thread
    is worth handing to the pool, for a Ctrl-C to stop it (:meth:`CompiledLoop.run_chunks`)."""
    return runs * K * max(n, 4) ** 3 >= 50 * MIN_WORK_PER_THREAD


_steps: dict[tuple, _CompiledStep] = {}
_steps_lock = threading.Lock()


def compiled_step(f: Model, h: Model, transform: Transform, angle_states: frozenset[int],
                   iterations: int = 1, square_root: bool = False) -> _CompiledStep:
    """The compiled step of (f, h, transform), built once per process (C cached on disk);
    ``iterations`` > 1: the iterated EKF's update (:func:`update_graph`); ``square_root``:
    the square-root form (:mod:`symmon.filters.gaussian._sqrtstep`)."""
    key = (f, h, transform, angle_states, iterations, square_root)
    with _steps_lock:
        step = _steps.get(key)
        if step is None:
            step = _steps[key] = _CompiledStep(f, h, transform, angle_states, iterations, square_root)
        return step


def filterable(transform: Any) -> bool:
    """A rule a filter can compile: a Taylor rule or a point rule (declared capabilities)."""
    return isinstance(transform, Transform) and (transform.taylor_order is not None or transform.point_rule)


def check_dimensions(transform: Transform, dims: Iterable[int]) -> None:
    """Build a point rule's unit points for each dimension a filter uses (the state, with
    the noise appended for general noise), so that a rule undefined there (a UT with
    n + λ ≤ 0, a grid beyond its size limit) is refused when the filter is made.

    Raises
    ------
    SymmonError
        From the rule, naming the dimension.
    """
    if transform.point_rule:
        for n in sorted(set(dims)):
            transform.unit_rule(n)
