"""The Rauch–Tung–Striebel smoother of the nonlinear Kalman filters, compiled to C.

After the forward pass of a filter (:mod:`symmon.filters.gaussian.step`) gives the filtered
N(x_k, P_k), k = 1 … K, the backward pass of the Gaussian RTS smoother (Särkkä 2008, the
unscented RTS smoother; Särkkä 2013, Algorithm 9.3 for any Gaussian filter) reads, from
x^s_K = x_K, P^s_K = P_K down to k = 1:

    x⁻_{k+1}, P⁻_{k+1}, C_{k+1} = the NLT of f at N(x_k, P_k) (plus Q),
    C_{k+1} = Cov(x_k, x_{k+1}),  G_k = C_{k+1} (P⁻_{k+1})⁻¹,
    x^s_k = x_k + G_k (x^s_{k+1} − x⁻_{k+1}),
    P^s_k = P_k + G_k (P^s_{k+1} − P⁻_{k+1}) G_kᵀ.

The transform of the filter computes the NLT, so the smoother is of the same family: TT1
gives the extended RTS smoother (C = P Fᵀ with F the Jacobian of f), TT2 the second-order
one, a UT the unscented RTS smoother, Gauss–Hermite the Gauss–Hermite smoother.  With
general noise the NLT runs on [x; w] with blkdiag(P, Q) and C is its x block.  Angle
states: the difference x^s_{k+1} − x⁻_{k+1} is wrapped, and x^s_k is wrapped.

The backward step is one CasADi function of (x_k, P_k, x^s_{k+1}, P^s_{k+1}, Q), built
from the same time-update graph as the filter step (it recomputes x⁻, P⁻ and C rather
than storing C in the forward pass), and a C loop runs it over the steps and the runs of
a bank; it goes through the same compile policy as the filter step.  The gain comes from the
Cholesky factor of the prediction, P⁻ = L Lᵀ, as G = (C L⁻ᵀ) L⁻¹ (the blocked factor and
inverse of :mod:`symmon.codegen.symbolic`, whose products are loops in C), not from a
general solve: the same G to rounding, several times faster at n = 30.  Where the time update
is TT1's closed form with additive noise (the EKF; a UT on affine dynamics without angle
states), from :data:`~symmon.filters.gaussian._ekfstep.C_EKF_FROM` states on, the loop calls the C
backward step of :mod:`symmon.filters.gaussian._ekfsmooth` instead, around CasADi's pieces of f (the
CasADi function stays for the VM).

References
----------
S. Särkkä, "Unscented Rauch–Tung–Striebel smoother", IEEE Trans. Autom. Control 53(3),
2008. doi:10.1109/TAC.2008.919531
S. Särkkä, *Bayesian Filtering and Smoothing*, Cambridge University Press, 2013, ch. 8–9.
"""

from __future__ import annotations

import ctypes
import hashlib
import threading

import casadi as ca
import numpy as np

from ...codegen.sqrtform import gain_factor, residual_factor
from ...codegen.symbolic import graph_kind, tril_inverse, wrap_entries
from ...compile.compiled import generated_c
from ...core.model import Model
from ...errors import SymmonError
from ...transforms.base import Transform
from ...compile.ckernels import STOPPED
from ...compile.csource import c_defines, c_file
from ._ekfsmooth import backward_c, backward_in_c, backward_pieces
from ._sqrtstep import covariance_of, noise_factor, sqrt_predict_graph
from .step import CompiledLoop, chunk_runs, long_bank, predict_graph, select_params, sym

__all__ = ["compiled_smoother", "sqrt_backward_graph"]


def _backward_function(f: Model, transform: Transform, angle_states: frozenset[int], names: tuple,
                       name: str, square_root: bool = False) -> ca.Function:
    """(x_k, P_k, x^s_{k+1}, P^s_{k+1}, Q, p_{k+1}) ↦ (x^s_k, P^s_k): one backward step (module
    notes), with the parameter values of the prediction to step k + 1; with ``square_root``
    the P's and Q are lower Cholesky factors (:func:`sqrt_backward_graph`)."""
    n, nq = f.n_u, f.n_v or f.n_u
    dim = n + f.n_v
    points = len(transform.unit_rule(dim)[0]) if transform.point_rule else 0
    kind, chol = graph_kind(dim, points)
    x, P = kind.sym("x", n), kind.sym("P", n, n)
    xs, Ps, Q, p = kind.sym("xs", n), kind.sym("Ps", n, n), kind.sym("Q", nq, nq), kind.sym("p", len(names))
    if square_root:
        x_s, P_s = sqrt_backward_graph(f, transform, angle_states, x, P, xs, Ps, Q, select_params(f, names, p))
    else:
        x_pred, P_pred, cross = predict_graph(f, transform, angle_states, x, P, Q, chol,
                                              select_params(f, names, p), cross=True)
        # G = C P⁻⁻¹ with C = crossᵀ, by the factor P⁻ = L Lᵀ: G = (C L⁻ᵀ) L⁻¹, products of
        # the blocked factor and its inverse (loops in C) in place of a general solve.
        L = chol(P_pred)
        inv = tril_inverse(L)
        # A zero pivot (P⁻ singular) gives a zero column where the solve gave inf: keep the
        # inf, so that the smoother reports a singular prediction rather than a number.
        gain = ca.mtimes(ca.mtimes(cross.T, inv.T), inv) + ca.if_else(ca.mmin(ca.diag(L)) > 0, 0, ca.inf)
        x_s = wrap_entries(x + ca.mtimes(gain, wrap_entries(xs - x_pred, angle_states)), angle_states)
        P_s = sym(P + ca.mtimes(ca.mtimes(gain, Ps - P_pred), gain.T))
    return ca.Function(name, [x, P, xs, Ps, Q, p], [ca.densify(x_s), ca.densify(P_s)],
                       ["x", "P", "xs", "Ps", "Q", "p"], ["x_smooth", "P_smooth"],
                       {"cse": True})


def sqrt_backward_graph(f: Model, transform: Transform, angle_states: frozenset[int], x, S, xs, Ss, Q_sqrt, p=None):
    """One backward step in square-root form: (x^s_k, S^s_k) from the factors S_k, S^s_{k+1}.

    The joint columns (Y, X) of [x_{k+1}; x_k] (the time update's,
    :func:`symmon.filters.gaussian._sqrtstep.sqrt_predict_graph`) give the gain as the measurement
    update does with f for h and Q for R: S⁻ = tria(Y), G = C S⁻⁻ᵀ S⁻⁻¹ = C (P⁻)⁻¹
    (:func:`symmon.codegen.sqrtform.gain_factor`), and (X − G Y)(X − G Y)ᵀ = P − G P⁻ Gᵀ, so
    P^s = P + G (P^s_{k+1} − P⁻) Gᵀ (Särkkä 2013, eq. (8.6)) is the sum of squares
    tria([X − G Y, G S^s_{k+1}]) (:func:`symmon.codegen.sqrtform.residual_factor`), where the
    standard form adds a difference."""
    x_pred, cols = sqrt_predict_graph(f, transform, angle_states, x, S, Q_sqrt, p, joint=True)
    _, _, gain = gain_factor(*cols)
    x_s = wrap_entries(x + ca.mtimes(gain, wrap_entries(xs - x_pred, angle_states)), angle_states)
    return x_s, residual_factor(cols.W, cols.Y, gain, cols.Wn, cols.Yn, extra=ca.mtimes(gain, Ss))


class _CompiledSmoother(CompiledLoop):
    """The backward step of one (f, transform), as C with its loop or on CasADi's VM."""

    def __init__(self, f: Model, transform: Transform, angle_states: frozenset[int], names: tuple = (),
                 square_root: bool = False) -> None:
        key = repr((f.key, names, transform, sorted(angle_states)) + (("square_root",) if square_root else ()))
        name = "sm_rts_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        fn = _backward_function(f, transform, angle_states, names, name, square_root)
        self.square_root = square_root
        self.n, self.n_p = f.n_u, len(names)
        # A TT1 time update with additive noise from C_EKF_FROM states on: the C backward step of
        # symmon.filters.gaussian._ekfsmooth around CasADi's pieces of f; the MX step fn stays for the VM.
        self.c_backward = backward_in_c(f, transform, angle_states, square_root)
        if self.c_backward:
            xs, ps = ca.SX.sym("x", self.n), ca.SX.sym("p", self.n_p)
            funcs, pattern = backward_pieces(f, angle_states, select_params(f, names, ps), xs, ps, name)
            step_code, scratch = backward_c(name, self.n, pattern)
            code, step, s = generated_c(*funcs) + step_code, f"{name}_bwd", "s"
        else:
            funcs, scratch = (fn,), 0
            code, step, s = generated_c(fn), name, 0
        # The backward loop (rts_loop.c): for each run, x^s_K = x_K, then K − 1 steps down to the first.
        code += c_defines(
            RTL_NAME=name, RTL_STEP=step, RTL_S=s, RTL_SZ_ARG=max(max(g.sz_arg() for g in funcs), 6),
            RTL_SZ_RES=max(max(g.sz_res() for g in funcs), 2), RTL_N=self.n, RTL_NN=self.n * self.n,
            RTL_N_P=self.n_p, RTL_SCRATCH=scratch, RTL_STOPPED=STOPPED) + c_file(__package__, "rts_loop.c")
        # The C backward step is small (16-20 KB at n = 10-30) but its gcc run would still be most of
        # a first call: it builds in the background while the MX step runs on the VM.
        super().__init__(fn, code, [ctypes.c_void_p] * 6 + [ctypes.c_longlong] * 2 + [ctypes.c_void_p] * 3,
                         also=funcs, background=self.c_backward)

    def __call__(self, x: np.ndarray, P: np.ndarray, Q: np.ndarray, use_c: bool = True,
                 params: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Smooth the filtered x (runs, K, n), P (runs, K, n, n), with the filter's parameter
        values (runs, K, n_p) (None: no parameters); returns (x^s, P^s) alike.

        A square-root smoother reads the filter's lower factors S (P = S Sᵀ) as ``P`` and
        returns (x^s, P^s, S^s)."""
        if self.square_root:
            xs, Us = self._run(x, np.ascontiguousarray(np.swapaxes(P, -1, -2)), noise_factor(Q).T, use_c, params)
            return (xs,) + covariance_of(Us)
        return self._run(x, P, Q, use_c, params)

    def _run(self, x, P, Q, use_c, params):
        """:meth:`__call__` on the step's own inputs (factors, transposed, for a square-root one)."""
        runs, K = x.shape[:2]
        x = np.ascontiguousarray(x, dtype=float)
        P = np.ascontiguousarray(P, dtype=float)
        Q = np.ascontiguousarray(Q, dtype=float)
        if params is None:
            if self.n_p:
                raise SymmonError("the smoother step needs the values of the parameters")
            params = np.zeros((runs, K, 1))  # a valid pointer; no entry is read
        params = np.ascontiguousarray(params, dtype=float)
        xs, Ps = np.empty_like(x), np.empty_like(P)
        run = self._lib.get() if use_c else None
        if run is None:
            return self._vm(x, P, Q, params[..., :self.n_p], xs, Ps)

        def part(c: tuple[int, int], stop: int) -> int:
            a, b = c
            iw, w = self._work.addresses()  # one per thread
            return run(x[a].ctypes.data, P[a].ctypes.data, Q.ctypes.data, params[a].ctypes.data, xs[a].ctypes.data,
                       Ps[a].ctypes.data, b - a, K, iw, w, stop)

        self.run_chunks(part, chunk_runs(runs, K, self.n), "smoother step", long_bank(runs, K, self.n))
        return xs, Ps

    def _vm(self, x, P, Q, params, xs, Ps):
        """The backward pass on CasADi's VM: one mapped call per step over the runs."""
        runs, K = x.shape[:2]
        fm = self.f.map(runs, "serial") if runs > 1 else self.f
        fb, ev = fm.buffer()
        Qb = np.ascontiguousarray(np.broadcast_to(Q, (runs,) + Q.shape))
        xs[:, -1], Ps[:, -1] = x[:, -1], P[:, -1]
        out_x, out_P = np.empty((runs, self.n)), np.empty((runs, self.n, self.n))
        for k in range(K - 2, -1, -1):
            args = [np.ascontiguousarray(a) for a in (x[:, k], P[:, k], xs[:, k + 1], Ps[:, k + 1])] + [Qb]
            args.append(np.ascontiguousarray(params[:, k + 1]))
            for i, a in enumerate(args):
                fb.set_arg(i, memoryview(a))
            fb.set_res(0, memoryview(out_x))
            fb.set_res(1, memoryview(out_P))
            ev()
            xs[:, k], Ps[:, k] = out_x, out_P
        return xs, Ps


_smoothers: dict[tuple, _CompiledSmoother] = {}
_lock = threading.Lock()


def compiled_smoother(f: Model, transform: Transform, angle_states: frozenset[int],
                      names: tuple = (), square_root: bool = False) -> _CompiledSmoother:
    """The compiled backward step of (f, transform), built once per process (C cached on disk);
    ``names`` are the filter's parameters (:func:`symmon.filters.gaussian.step.filter_params`);
    ``square_root``: the square-root smoother (:func:`sqrt_backward_graph`)."""
    key = (f, transform, angle_states, tuple(names), square_root)
    with _lock:
        s = _smoothers.get(key)
        if s is None:
            s = _smoothers[key] = _CompiledSmoother(f, transform, angle_states, tuple(names), square_root)
        return s
