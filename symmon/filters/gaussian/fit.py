"""Maximum-likelihood fit of model parameters through the filter's log-likelihood.

The marginal log-likelihood of the measurements, ℓ(θ) = Σ_runs Σ_k log N(ν_k; 0, S_k), is
what the filter step computes (the prediction-error decomposition).  :func:`fit` evaluates ℓ
and its exact gradient and Hessian in the named parameters θ by a C loop over the steps and
runs of a bank (:class:`_CompiledLoglik`) around the filter's own step function (the same
graph as :mod:`symmon.filters.gaussian.step`) and CasADi's derivatives of it (algorithmic
differentiation through every step; no finite differences).

Which mode: the fitted parameters are few and the step's state [x; vec(P)] is large (930
numbers at 30 states), so for a filter of at most :data:`FORWARD_MAX_PARAMS` parameters
the loop runs in **forward mode**: it carries the tangents ∂s_k/∂θ_j of the state along
each parameter through the steps with the state itself, and ∇ℓ is the sum of the ℓ_k
entries of those tangents (Griewank & Walther 2008, §3.1).  One sweep, no tape of the K
states; its cost grows with the number of tangents, the reverse sweep's does not, and at 30
states the forward sweep is the cheaper up to three (:data:`FORWARD_MAX_PARAMS` gives the
times).  For at most :data:`FORWARD_HESSIAN_MAX_PARAMS` parameters the Hessian is the same
forward mode applied to that tangent sweep (forward over forward): the second-order
tangents ∂²s_k/∂θ_i∂θ_j, propagated by d²s_{k+1} = J d²z_k + ∇(J ż_i) ż_j with
ż_j = [∂s_k/∂θ_j; e_j], in one sweep.  Above those numbers the loop runs in reverse mode: a
reverse sweep for the gradient (ibid., §3.2) and a forward-over-reverse sweep per
parameter for the Hessian (ibid., §5.2), whose cost grows only linearly with the number of
parameters.  All modes give the same numbers to rounding.  When the sweeps are long
(:data:`THREAD_WORK`), the columns of the Hessian and of a forward gradient run on the
cores, a part of the fitted parameters each (every sum is that of one thread to the bit).

The loop is built once per filter through the compile policy; until it is, the same ℓ is
one CasADi graph of θ (the step folded over the K steps, ``mapaccum``, and mapped over the
runs, :func:`_loglik_graph`) evaluated on CasADi's VM.  SciPy's quasi-Newton method
(L-BFGS-B, with bounds) maximises ℓ; the standard errors are the square roots of the
diagonal of the inverse observed information, I = −∇²ℓ(θ̂) (exact Hessian).

References
----------
J. D. Hamilton, *Time Series Analysis*, Princeton University Press, 1994, §13.4 (the
prediction-error decomposition and maximum likelihood with a Kalman filter).
S. Särkkä, *Bayesian Filtering and Smoothing*, Cambridge University Press, 2013, §12.2
(parameter estimation with Gaussian filters).
A. Griewank and A. Walther, *Evaluating Derivatives*, 2nd ed., SIAM, 2008, §3.1 (the forward
mode: tangent propagation), §3.2 (the reverse mode) and §5.2 (second derivatives by forward
over reverse).
"""

from __future__ import annotations

import ctypes
import dataclasses
import hashlib
import math
import threading
import warnings
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from scipy import optimize

from ...compile.ccache import NativeLibrary
from ...compile.ckernels import faster_sparse_products
from ...compile.csource import c_defines, c_source
from ...compile.compiled import WorkArrays, cpu_count, even_spans, generated_c, in_threads
from ...core.gaussian import float_array
from ...errors import IdentifiabilityWarning, ModelError, SymmonError, plain_repr
from ...transforms.executor import one_blas_thread
from ..inputs import FilterSpec, check_call
from ..results import KalmanResult
from .step import compiled_step

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
    def filter(self) -> FilterSpec:
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
        return dataclasses.replace(kf, f_model=f, h_model=h)  # the filter's own class, checked anew

    def __repr__(self) -> str:
        parts = ", ".join(f"{k} = {v:.6g} ± {self.std_errors[k]:.2g}" for k, v in self.estimates.items())
        return f"FitResult({parts}; log-likelihood {self.log_likelihood:.6g}, {self.iterations} iterations)"


def _loglik_graph(kf: FilterSpec, Y: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                  base: np.ndarray, fitted: list[int]) -> tuple[ca.MX, ca.MX]:
    """θ (the fitted parameters) and ℓ(θ) as an MX graph: the step folded over K, mapped over R."""
    step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states, kf.iterations).f
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
    data = _step_data(Y, base)  # (R, K, ·)
    sel = np.zeros((n_p, len(fitted)))
    sel[fitted, np.arange(len(fitted))] = 1.0
    keep = np.ones(2 * n_y + n_p)
    keep[2 * n_y + np.array(fitted, dtype=int)] = 0.0
    # Each run's data columns, with the fitted rows replaced by θ (the same at every step).
    Ds = [ca.diag(ca.DM(keep)) @ ca.DM(data[r].T)
          + ca.repmat(ca.vertcat(ca.DM.zeros(2 * n_y, 1), ca.mtimes(ca.DM(sel), theta)), 1, K) for r in range(runs)]
    S0s = ca.DM(_initial_states(x0, P0, runs).T)
    total = ca.sum2(run_ll.map(runs)(S0s, ca.horzcat(*Ds)))
    return theta, total


#: The gradient in forward mode for a filter of at most this many parameters (reverse mode
#: above): each forward sweep carries a tangent per parameter.  At 30 states and K = 100, with
#: two tangents 7.4 ms against 8.9 ms in reverse mode, with three 9.4 ms against 12.4 ms.
FORWARD_MAX_PARAMS = 3
#: The Hessian in forward mode (forward over forward) for a filter of at most this many
#: parameters, forward over reverse above: its cost grows with the square of their number.
#: At 30 states, with two parameters 63 ms against 83 ms; with three 0.73 s (its library is
#: then built at -O0) against 0.12 s.
FORWARD_HESSIAN_MAX_PARAMS = 2

#: Entries of the states swept (runs × K × (n + n²)) from which the columns of the Hessian
#: (and of a forward gradient) run on the cores, a part of the fitted parameters each: at 30
#: states and 100 steps (93 000) a Hessian column costs about 25 ms and a gradient's 5 ms,
#: against a thread's 50 µs; at 10 states (11 000) the whole Hessian takes a few milliseconds.
THREAD_WORK = 1 << 15

class _CompiledLoglik:
    """ℓ and its exact gradient and Hessian in the fitted parameters, as one C loop over the
    steps and runs around the filter's step function and derivatives of it built by CasADi,
    with z = [x; vec(P); y; mask; p] and o = [x⁺; vec(P⁺); ℓ_k] = step(z).

    Forward mode (``fit_forward.c``, a filter of at most :data:`FORWARD_MAX_PARAMS`
    parameters, or ``forward=True``): the step (z ↦ o), the step with its Jacobian times one
    tangent per parameter of the filter (z, Ż ↦ o, J Ż), and the forward derivative of that
    along one tangent ż_j with Ż seeded by the second-order tangents (z, Ż, ż_j, Z̈_j ↦ o, J Ż,
    J Z̈_j + ∇(J Ż) ż_j); the tangents of the states ride along with the states through the
    K steps (Griewank & Walther 2008, §3.1), twice for ∇²ℓ (forward over forward).  Reverse
    mode (``fit_reverse.c``): the step, its Jacobian-vector product (z, ż ↦ J ż), its
    vector-Jacobian product (z, λ ↦ Jᵀλ) and the derivative of that along ż
    (z, ż, λ, λ̇ ↦ (∇(Jᵀλ)) ż + Jᵀλ̇); reverse accumulation through the K steps gives ∇ℓ
    (ibid. §3.2), the same sweep differentiated forward along each fitted parameter gives ∇²ℓ
    (forward-over-reverse, ibid. §5.2).  The module docstring says why forward mode for few
    parameters.

    It does not depend on the data, the parameters fitted or the bank's shape: one build per
    filter, through the compile policy (:class:`symmon.compile.ccache.NativeLibrary`, in the
    background: the VM graph :func:`_loglik_graph` is the fallback), as two libraries: ℓ and
    ∇ℓ, and with the Hessian."""

    def __init__(self, kf: FilterSpec, forward: bool | None = None) -> None:
        step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states, kf.iterations).f
        n, n_y = kf.f_model.n_u, kf.h_model.n_y
        self.ns = n + n * n
        self.n_p = step.size1_in(6)
        self.nd = 2 * n_y + self.n_p
        # Forward mode carries one tangent per parameter of the filter (fitted or not): the
        # gradient up to FORWARD_MAX_PARAMS, the Hessian (whose cost grows with their square)
        # up to FORWARD_HESSIAN_MAX_PARAMS.
        self.forward = self.n_p <= FORWARD_MAX_PARAMS if forward is None else bool(forward)
        self.forward_hessian = self.n_p <= FORWARD_HESSIAN_MAX_PARAMS if forward is None else bool(forward)
        nz, no, M = self.ns + self.nd, self.ns + 1, self.n_p
        key = repr((step.name(), "fit"))
        name = "sm_fit_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        z = ca.MX.sym("z", nz)
        Q, R = ca.MX.sym("Q", step.sparsity_in(3)), ca.MX.sym("R", step.sparsity_in(4))
        s, d = z[:self.ns], z[self.ns:]
        out = step(s[:n], ca.reshape(s[n:], n, n), d[:n_y], Q, R, d[n_y:2 * n_y], d[2 * n_y:])
        o = ca.vertcat(out[0], ca.vec(out[1]), out[6])
        # Two libraries: the value and gradient (every iteration) apart from the Hessian (once
        # per fit, its code several times as large), so that the compile policy builds the
        # first with full optimisation where the whole would be too large for it (docs/compile.md).
        # Each named by its part and mode only, so that the modes mixed share both libraries.
        libs = [(self._forward_code if fwd else self._reverse_code)(f"{name}{part}{'f' if fwd else ''}", z, Q, R, o,
                                                                     part == "h")
                for part, fwd in (("g", self.forward), ("h", self.forward_hessian))]
        self._libs = [NativeLibrary(code, pre, lambda so, pre=pre: self._load(so, pre), stacklevel=3, background=True)
                      for pre, code, _ in libs]
        self.name = name
        self._work = WorkArrays(*(f for _, _, fs in libs for f in fs))
        # The drivers' real work arrays, for either library: [z, zd, zdd, o, od, odd] in
        # forward mode (zdd and odd with M² columns); [z_k for each k] and the tangents [T_k]
        # in reverse mode.
        forward_work = (1 + M + M * M) * (nz + no) if self.forward or self.forward_hessian else 0
        reverse = not (self.forward and self.forward_hessian)
        self._work_size = lambda K: (max(forward_work, K * nz if reverse else 0), K * self.ns if reverse else 1)

    def _reverse_code(self, pre: str, z: ca.MX, Q: ca.MX, R: ca.MX, o: ca.MX, hessian: bool) -> tuple:
        """(library name, C, functions) of a reverse-mode library (``fit_reverse.c``): ℓ and
        ∇ℓ, and with ``hessian`` also ∇²ℓ."""
        nz = self.ns + self.nd
        zd = ca.MX.sym("zd", nz)
        lam, lamd = ca.MX.sym("lam", self.ns + 1), ca.MX.sym("lamd", self.ns + 1)
        vjp = ca.jtimes(o, z, lam, True)
        fs = [ca.Function(f"{pre}_f", [z, Q, R], [o]), ca.Function(f"{pre}_vjp", [z, Q, R, lam], [vjp])]
        if hessian:
            hvp = ca.jtimes(vjp, z, zd) + ca.jtimes(o, z, lamd, True)
            fs += [ca.Function(f"{pre}_jvp", [z, Q, R, zd], [ca.jtimes(o, z, zd)]),
                   ca.Function(f"{pre}_hvp", [z, Q, R, zd, lam, lamd], [vjp, hvp])]
        driver = c_defines(FIT_NAME=pre, FIT_HESSIAN=hessian, FIT_NS=self.ns, FIT_ND=self.nd, FIT_NZ=nz,
                           FIT_SZ_ARG=max(max(f.sz_arg() for f in fs), 6),
                           FIT_SZ_RES=max(max(f.sz_res() for f in fs), 2)) + c_source(__package__, "fit_reverse.c")
        return pre, faster_sparse_products(generated_c(*fs)) + driver, fs

    def _forward_code(self, pre: str, z: ca.MX, Q: ca.MX, R: ca.MX, o: ca.MX, hessian: bool) -> tuple:
        """(library name, C, functions) of a forward-mode library (``fit_forward.c``) with M
        tangents, one per parameter of the filter: the step z ↦ o and its Jacobian times the
        tangents (z, Ż ↦ o, J Ż) for ℓ and ∇ℓ; with ``hessian``, the forward derivative of that
        along one tangent ż_j with Ż seeded by second-order tangents (z, Ż, ż_j, Z̈_j ↦ o, J Ż,
        whose column i is J Z̈_{i+Mj} + ∇(J ż_i) ż_j) for ℓ, ∇ℓ and ∇²ℓ."""
        nz, M = self.ns + self.nd, self.n_p
        Zd = ca.MX.sym("Zd", nz, M)
        jvp = ca.Function(f"{pre}_jvp", [z, Q, R, Zd], [o, ca.jtimes(o, z, Zd)])
        if not hessian:
            # All tangents in one call, or (a part of the columns on a thread) one call per
            # tangent, each with the step again.
            zd1 = ca.MX.sym("zd1", nz)
            fs = [ca.Function(f"{pre}_f", [z, Q, R], [o]), jvp,
                  ca.Function(f"{pre}_jvp1", [z, Q, R, zd1], [o, ca.jtimes(o, z, zd1)])]
        else:
            # CasADi's forward derivative of the jvp along one tangent ż_j, with Ż seeded by
            # the second-order tangents Z̈_{·, M j : M j + M}: one call per fitted parameter
            # (one call for all would be one C function twice as large, beyond the size the
            # compile policy builds at -O3; docs/compile.md).
            zdj, Zddj = ca.MX.sym("zdj", nz), ca.MX.sym("Zddj", nz, M)
            oo, jT = jvp(z, Q, R, Zd)
            zero = [ca.MX(v.size1(), v.size2()) for v in (Q, R)]
            odd = jvp.forward(1)(z, Q, R, Zd, oo, jT, zdj, *zero, Zddj)[1]
            fs = [ca.Function(f"{pre}_hess", [z, Q, R, Zd, zdj, Zddj], [oo, jT, odd])]
        driver = c_defines(FIT_NAME=pre, FIT_HESSIAN=hessian, FIT_NS=self.ns, FIT_ND=self.nd, FIT_NZ=nz,
                           FIT_NO=self.ns + 1, FIT_M=M, FIT_MM=M * M, FIT_MAX_ORDER=1 + hessian,
                           FIT_SZ_ARG=max(max(f.sz_arg() for f in fs), 6),
                           FIT_SZ_RES=max(max(f.sz_res() for f in fs), 3)) + c_source(__package__, "fit_forward.c")
        return pre, faster_sparse_products(generated_c(*fs)) + driver, fs

    @staticmethod
    def _load(so, pre: str):
        run = getattr(ctypes.CDLL(str(so)), f"{pre}_fit")
        run.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_longlong] * 3 + [ctypes.c_void_p] + [ctypes.c_longlong] * 3 \
            + [ctypes.c_void_p] * 5
        run.restype = ctypes.c_int
        return run

    def wait(self) -> bool:
        """Wait for the background builds; True when both libraries are compiled."""
        return all([lib.wait() for lib in self._libs])

    def bind(self, data: np.ndarray, S0: np.ndarray, Q: np.ndarray, R: np.ndarray, fitted: list[int]):
        """``(θ, order) ↦ (ℓ, ∇ℓ, ∇²ℓ)`` (order 0: ℓ only; 1: and ∇ℓ; 2: and ∇²ℓ) on the data
        (runs, K, nd) of the step (:func:`_step_data`) with the parameters ``fitted`` (indices
        among the filter's parameters) set to θ, from the states S0 (:func:`_initial_states`);
        None while the C of the gradient is not available (CasADi's VM, or a build still
        running); order 2 gives None for ∇²ℓ while that of the Hessian is not."""
        run = self._libs[0].get()
        if run is None:
            return None
        runs, K = data.shape[:2]
        data = np.array(data, dtype=float, order="C")
        # The parameters' values are the last rows of the step's data.
        rows = np.ascontiguousarray(self.nd - self.n_p + np.asarray(fitted, dtype=np.int64))
        S0 = np.ascontiguousarray(S0, dtype=float)
        Qc, Rc = np.asfortranarray(Q, dtype=float).ravel(order="F"), np.asfortranarray(R, dtype=float).ravel(order="F")
        m = len(rows)
        # The columns of the Hessian and of a forward gradient on the cores (each part its own
        # work arrays and out, summed), when the sweeps are long enough (THREAD_WORK).
        threads = 1
        if m > 1 and runs * K * self.ns >= THREAD_WORK and threading.current_thread() is threading.main_thread():
            threads = min(m, cpu_count())
        parts = [(j0, j1, *(np.empty(size) for size in self._work_size(K)), np.zeros(1 + m + m * m))
                 for j0, j1 in even_spans(m, threads)]

        def evaluate(theta: np.ndarray, order: int):
            fn = run
            if order == 2:
                fn = self._libs[1].get()
                if fn is None:
                    return None
            data[:, :, rows] = theta

            def part(p: tuple) -> int:
                j0, j1, Z, T, out = p
                out[:] = 0.0
                iw, w = self._work.addresses()
                return fn(data.ctypes.data, S0.ctypes.data, Qc.ctypes.data, Rc.ctypes.data, runs, K, m, rows.ctypes.data,
                          order, j0, j1, Z.ctypes.data, T.ctypes.data, out.ctypes.data, iw, w)

            split = order == 2 or (order == 1 and self.forward)
            if any(in_threads(part, parts if split else [(0, m, *parts[0][2:])])):
                raise SymmonError(f"the compiled log-likelihood {self.name} returned an error")
            # Each entry comes from one part (the others add 0.0): the sum is one call's out.
            out = parts[0][4] if not split or len(parts) == 1 else sum(p[4] for p in parts)
            return out[0], out[1:1 + m].copy(), out[1 + m:].reshape(m, m).copy()

        return evaluate


_loglik_lock = threading.Lock()
_logliks: dict[tuple, _CompiledLoglik] = {}


def compiled_loglik(kf: FilterSpec) -> _CompiledLoglik:
    """The compiled log-likelihood of the filter ``kf`` (:class:`_CompiledLoglik`), built once
    per process (C cached on disk)."""
    key = (kf.f_model, kf.h_model, kf.transform, kf.angle_states, kf.iterations)
    with _loglik_lock:
        c = _logliks.get(key)
        if c is None:
            c = _logliks[key] = _CompiledLoglik(kf)
        return c


def _step_data(Y: np.ndarray, base: np.ndarray) -> np.ndarray:
    """The step's data per run and step: [y (0 where missing); mask; parameter values]."""
    measured = ~np.isnan(Y)
    return np.concatenate([np.where(measured, Y, 0.0), measured.astype(float), base], axis=2)


def _initial_states(x0: np.ndarray, P0: np.ndarray, runs: int) -> np.ndarray:
    """[x0; vec(P0)] per run (column-major vec, CasADi's)."""
    x0r = np.broadcast_to(x0, (runs,) + np.shape(x0)[-1:])
    P0r = np.broadcast_to(P0, (runs,) + np.shape(P0)[-2:])
    return np.concatenate([x0r, np.swapaxes(P0r, -1, -2).reshape(runs, -1)], axis=1)


#: The most iterations of the optimiser a fit may ask for.
MAX_ITER = 100_000


def _number(v: Any, what: str) -> float:
    """``v`` as a real number (not NaN), or a ModelError naming ``what``."""
    x = float_array(v, what, ModelError)
    if x.ndim != 0 or np.isnan(x):
        raise ModelError(f"{what} must be a number, got {plain_repr(v)}")
    return float(x)


def fit_parameters(kf: FilterSpec, ys, x0, start: dict, P0=None, *, params: dict | None = None,
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
        raise ModelError(f"max_iter must be an integer from 1 to {MAX_ITER}, got {plain_repr(max_iter)}")
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
            raise ModelError(f"the bound of {k!r} must be a pair (low, high), got {plain_repr(b)}")
        a, c = (-np.inf if b[0] is None else _number(b[0], f"the low bound of {k!r}"),
                np.inf if b[1] is None else _number(b[1], f"the high bound of {k!r}"))
        if not a < c:
            raise ModelError(f"the bound of {k!r} must have low < high, got {plain_repr(b)}")
        j = fitted_names.index(str(k))
        lo[j], hi[j] = a, c
    if np.any(theta0 < lo) or np.any(theta0 > hi):
        raise ModelError("the starting values must lie within their bounds")

    # The filter's checks of ys, x0, P0 and the parameters, and a run at the starting values.
    checked = check_call(kf, ys, x0, P0, params={**fixed, **start}, keep=("x",))
    kf.filter(ys, x0, P0, params={**fixed, **start}, keep=("x",))
    fitted = [names.index(k) for k in fitted_names]
    evaluate = compiled_loglik(kf).bind(_step_data(checked.Y, checked.pv),
                                        _initial_states(checked.x0, checked.P0, checked.Y.shape[0]), kf.Q, kf.R, fitted)

    def vm_hess(t):
        theta, total = _loglik_graph(kf, checked.Y, checked.x0, checked.P0, checked.pv, fitted)
        return ca.Function("loglik_hess", [theta], [ca.hessian(total, theta)[0]])(t)

    hess = vm_hess
    if evaluate is None:  # no compiled C (yet): the same ℓ as one CasADi graph on its VM
        theta, total = _loglik_graph(kf, checked.Y, checked.x0, checked.P0, checked.pv, fitted)
        value_grad = ca.Function("loglik_grad", [theta], [total, ca.gradient(total, theta)])
    else:
        def value_grad(t):
            return evaluate(np.asarray(t, dtype=float), 1)[:2]

        def hess(t):
            out = evaluate(np.asarray(t, dtype=float), 2)
            return vm_hess(t) if out is None else out[2]

    def objective(t: np.ndarray):
        v, g = value_grad(t)
        v, g = float(v), np.asarray(g, dtype=float).ravel()
        if not (math.isfinite(v) and np.all(np.isfinite(g))):
            return np.inf, np.zeros_like(t)  # a step outside the filter's domain: the search backs off
        return -v, -g

    # One BLAS thread for SciPy's optimiser, whose linear algebra is of size m: a multithreaded
    # OpenBLAS wakes its threads for it, and they spin beside the C loop of the log-likelihood
    # (30 states, 2 cores under load: 0.33 s against 0.18 s a fit).
    with one_blas_thread():
        res = optimize.minimize(objective, theta0, jac=True, method="L-BFGS-B",
                                bounds=list(zip(lo, hi)), options={"maxiter": int(max_iter), "gtol": gtol})
    at = {k: float(v) for k, v in zip(fitted_names, res.x)}  # plain floats in messages, not np.float64(...)
    if not res.success or not np.isfinite(res.fun):
        raise SymmonError(f"the maximum-likelihood fit did not converge after {res.nit} iterations: {res.message} "
                          f"(last estimates {at}); try other starting values or bounds")
    with one_blas_thread():
        info = -np.asarray(hess(res.x), dtype=float)
    info = 0.5 * (info + info.T)
    eig, vec = np.linalg.eigh(info)
    tiny = 1e-12 * max(abs(eig[-1]) if np.all(np.isfinite(eig)) else 0.0, 1e-300)
    if np.all(np.isfinite(eig)) and eig[0] < -tiny:
        # −∇²ℓ has a negative eigenvalue: ℓ curves up along its eigenvector, so the search
        # stopped where the gradient vanishes but ℓ is not a maximum (a symmetric start such as
        # a noise intensity q = 0, where ℓ(q) = ℓ(−q)).
        direction = dict(zip(fitted_names, (float(c) for c in vec[:, 0])))
        raise SymmonError(
            f"the fit stopped at {at}, where the gradient of the log-likelihood vanishes but it is a minimum or a "
            f"saddle, not a maximum (the observed information has the negative eigenvalue {eig[0]:.3g} along "
            f"{direction}): start elsewhere, away from a point of symmetry (e.g. a noise intensity of 0)")
    if not np.all(np.isfinite(eig)) or eig[0] <= tiny:
        raise SymmonError(
            f"the observed information matrix at {at} is singular (eigenvalues {[float(e) for e in eig]}): "
            "a fitted parameter is not identifiable from these data (two parameters that enter only together)")
    cov = np.linalg.inv(info)
    se = np.sqrt(np.diag(cov))
    weak = [(k, float(res.x[j]), float(se[j])) for j, k in enumerate(fitted_names) if se[j] > abs(res.x[j])]
    if weak:
        warnings.warn("weakly identified: " + "; ".join(f"{k} = {v:.6g} has standard error {s:.3g}" for k, v, s in weak)
                      + ", larger than the estimate: the data hardly constrain it (a bias confounded with an "
                      "uncertain initial state, say); fix it with params=, or fit on more informative data",
                      IdentifiabilityWarning, stacklevel=3)
    estimates = dict(zip(fitted_names, (float(v) for v in res.x)))
    scale = np.maximum(1.0, np.abs(res.x))
    at_bound = tuple(k for j, k in enumerate(fitted_names)
                     if min(abs(res.x[j] - lo[j]), abs(hi[j] - res.x[j])) <= 1e-8 * scale[j])
    all_params = {**fixed, **estimates}
    filtered = kf.filter(ys, x0, P0, params=all_params)
    cov.flags.writeable = False
    return FitResult(estimates, dict(zip(fitted_names, (float(v) for v in se))), cov,
                     float(np.sum(filtered.log_likelihood)), int(res.nit), all_params, filtered, at_bound, kf)
