"""The compiled continuous-discrete filter: the moment ODEs of every interval and the update of
every step, for all the runs of a bank, in one C call (``cd_loop.c``).

The C integrates each interval by the Dormand–Prince 5(4) pair with solve_ivp's RK45 control
(its steps up to rounding), around CasADi's C of the drift's pieces: ``{name}_a`` (x, θ) ↦ a,
``{name}_aj`` (x, θ) ↦ (a, the nonzeros of ∂a/∂x) for TT1, ``{name}_d`` (x, θ) ↦ L Q_c Lᵀ; the
rule's products with P or S (eqs. (1)–(3), (6) of :mod:`symmon.filters.gaussian.continuous`)
are loops of the C file, so that the generated code grows with the model, not with n³.  The
update ``{name}`` is the discrete filter's update graph (:func:`~symmon.filters.gaussian.step.update_graph`,
or :func:`~symmon.filters.gaussian._sqrtstep.sqrt_update_graph`) at the integrated moments.
A run whose interval or update fails is handed back (``failed``): the caller continues it in
Python from that step, which continues it or names the failure.
"""

from __future__ import annotations

import ctypes
import hashlib
import threading

import casadi as ca
import numpy as np
import sympy as sp

from ...codegen.symbolic import wrap_entries
from ...compile.ckernels import STOPPED
from ...compile.compiled import generated_c, to_casadi
from ...compile.csource import c_defines, c_file
from ...core.model import Model
from ...transforms.base import Transform
from ._sqrtstep import noise_factor, sqrt_update_graph
from .step import CompiledLoop, chunk_runs, long_bank, select_params, step_kind, sym, update_graph

#: The outputs of the C loop, in the order of its ``outs`` argument.
OUTPUTS = ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis", "loglik", "P_chol", "P_pred_chol", "Phi", "Qt")
#: The fewest RHS evaluations of an interval (solve_ivp's and the C's): the start, the choice of
#: the first step, and six per accepted step.
_EVALS = 8


def _pieces(states: list, drift: list, noise: list, tparams: list, name: str) -> tuple:
    """The SX functions of the drift: (a, a with its Jacobian's nonzeros, D), the Jacobian's
    CSC pattern, and whether D depends on x."""
    n = len(states)
    x, th = ca.SX.sym("x", n), ca.SX.sym("th", max(len(tparams), 1))
    w = ca.vertcat(x, th[:len(tparams)])
    exprs = to_casadi(list(drift) + list(noise), list(states) + list(tparams), w)
    a, D = ca.densify(ca.vertcat(*exprs[:n])), ca.densify(ca.vertcat(*exprs[n:]))
    J = ca.jacobian(a, x)
    nz = J.nonzeros()
    opts = {"cse": True}
    fa = ca.Function(f"{name}_a", [x, th], [a], opts)
    faj = ca.Function(f"{name}_aj", [x, th], [a, ca.vertcat(*nz) if nz else ca.SX.zeros(1)], opts)
    fd = ca.Function(f"{name}_d", [x, th], [D], opts)
    sp_ = J.sparsity()
    return (fa, faj, fd), list(sp_.colind()), list(sp_.row()) or [0], len(nz), bool(ca.depends_on(D, x))


def _update_function(ident: Model, h: Model, transform: Transform, angle_states: frozenset[int], names: tuple,
                     square_root: bool, name: str) -> ca.Function:
    """(m, P, y, R, mask, p) ↦ (x⁺, P⁺, x⁻, ν, S, log-likelihood, NIS): the update at the
    integrated moments (x⁻ = m with the angle states wrapped, P⁻ = P symmetrised); with
    ``square_root`` P, R and P⁺ are lower factors (column-major)."""
    n, n_y = ident.n_u, h.n_y
    nr = h.n_v or n_y
    kind, chol = step_kind(ident, h, transform)
    x, P, y = kind.sym("x", n), kind.sym("P", n, n), kind.sym("y", n_y)
    R, mask, p = kind.sym("R", nr, nr), kind.sym("mask", n_y), kind.sym("p", max(len(names), 1))
    xw = wrap_entries(x, angle_states)
    ph = select_params(h, names, p)
    if square_root:
        Sf, Rf = (ca.tril(P), ca.tril(R)) if kind is ca.SX else (P, R)
        x_new, P_new, nu, Sy, loglik, nis = sqrt_update_graph(h, transform, angle_states, xw, Sf, y, Rf, mask, ph)
        S = ca.mtimes(Sy, Sy.T)
    else:
        x_new, P_new, nu, S, loglik, nis = update_graph(h, transform, angle_states, xw, sym(P), y, R, chol, mask, ph)
    outs = [ca.densify(v) for v in (x_new, P_new, xw, nu, S, loglik, nis)]
    return ca.Function(name, [x, P, y, R, mask, p], outs, {"cse": True})


class CompiledCD(CompiledLoop):
    """The C loop of one continuous-discrete filter (its drift, h, rule, angles and form).

    Parameters
    ----------
    states, drift, noise, tparams
        The SDE's states, its drift a, the entries of L Q_c Lᵀ (row by row) and the drift's
        parameters (the SDE's, then its time for a time-varying SDE).
    ident : Model
        The update's identity prediction model (for the update graph's kind).
    h, transform, angle_states, names
        The measurement model, the rule, the filter's angle states and the update's
        parameter names.
    square_root : bool
    time_varying : bool
        The drift's last parameter is the time, which the C sets at each evaluation.
    points : tuple or None
        The rule's unit points and weights (None: TT1).
    """

    def __init__(self, states: list, drift: list, noise: list, tparams: list, ident: Model, h: Model,
                 transform: Transform, angle_states: frozenset[int], names: tuple, square_root: bool,
                 time_varying: bool, points: tuple | None) -> None:
        key = repr((tuple(map(sp.srepr, drift)), tuple(map(sp.srepr, noise)), tuple(map(str, states)),
                    tuple(map(str, tparams)), h.key, transform, sorted(angle_states), tuple(map(str, names)),
                    square_root, time_varying))
        name = "sm_cd_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        n = len(states)
        self.n, self.n_y, self.square_root, self.n_names = n, h.n_y, square_root, len(names)
        self.n_th = max(len(tparams), 1)
        pieces, jcol, jrow, jnnz, dx = _pieces(states, drift, noise, tparams, name)
        upd = _update_function(ident, h, transform, angle_states, names, square_root, name)
        funcs = pieces + (upd,)
        if points is None:
            Z, wm, wc = np.zeros((1, n)), np.zeros(1), np.zeros(1)
        else:
            Z, wm, wc = (np.ascontiguousarray(a, dtype=float) for a in points)
        self._rule = (Z, wm, wc, np.array(jcol, dtype=np.int64), np.array(jrow, dtype=np.int64))
        code = generated_c(*funcs) + c_defines(
            CDK_NAME=name, CDK_N=n, CDK_NY=h.n_y, CDK_NTH=self.n_th, CDK_NP=max(len(names), 1),
            CDK_TV=time_varying, CDK_POINTS=0 if points is None else len(wm), CDK_SQRT=square_root, CDK_DX=dx,
            CDK_JNNZ=max(jnnz, 1), CDK_A=pieces[0].name(), CDK_AJ=pieces[1].name(), CDK_D=pieces[2].name(),
            CDK_UPD=name, CDK_SZ_ARG=max(max(f.sz_arg() for f in funcs), 6),
            CDK_SZ_RES=max(max(f.sz_res() for f in funcs), 7), CDK_STOPPED=STOPPED) + c_file(__package__, "cd_loop.c")
        vp, ll = ctypes.c_void_p, ctypes.c_longlong
        argtypes = [vp, ll, vp, ll] + [vp] * 13 + [ll, ll, vp, ll, ll] + [vp] * 4
        super().__init__(upd, code, argtypes, also=funcs)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for a background C build; True when the compiled loop is in use."""
        return self._lib.wait(timeout)

    def __call__(self, m0: np.ndarray, P0: np.ndarray, Y: np.ndarray, th: np.ndarray, p: np.ndarray,
                 dts: np.ndarray, starts: np.ndarray, R: np.ndarray, out: dict, tol: tuple[float, float, float],
                 max_evaluations: int, transition: bool) -> np.ndarray | None:
        """Run the bank in C, writing ``out`` (arrays (runs, K, ...) by :data:`OUTPUTS` name;
        a missing one is not written): m0 (runs, n), P0 (runs, n, n; lower factors in the
        square-root form), Y (runs, K, n_y) with NaN for missing, th (runs, K, n_θ) the SDE's
        parameters, p (runs, K, ·) the update's, dts and starts (runs, K), R the update's
        noise covariance.  Returns ``failed`` (runs,): the step at which each run stopped, or
        -1; None when the C is not (yet) built (the caller integrates in Python)."""
        run = self._lib.get()
        if run is None:
            return None
        runs, K = Y.shape[:2]
        measured = ~np.isnan(Y)
        mask = np.ascontiguousarray(measured, dtype=float)
        Yc = np.ascontiguousarray(np.where(measured, Y, 0.0))
        thv = np.zeros((runs, K, self.n_th))
        thv[..., :th.shape[-1]] = th
        pv = np.zeros((runs, K, max(self.n_names, 1)))
        pv[..., :p.shape[-1]] = p
        Rf = np.ascontiguousarray(noise_factor(R).T if self.square_root else R, dtype=float)
        m0, P0 = np.ascontiguousarray(m0, dtype=float), np.ascontiguousarray(P0, dtype=float)
        dts, starts = np.ascontiguousarray(dts, dtype=float), np.ascontiguousarray(starts, dtype=float)
        tolv = np.array(tol, dtype=float)
        Z, wm, wc, jcol, jrow = self._rule
        failed = np.full(runs, -1, dtype=np.int64)
        chunks = chunk_runs(runs, K * _EVALS, self.n)
        n = self.n

        def part(c: int, stop: int) -> int:
            a, b = chunks[c]
            outs = (ctypes.c_void_p * len(OUTPUTS))(*[out[k][a:b].ctypes.data if out.get(k) is not None else None
                                                      for k in OUTPUTS])
            iw, w = self._work.addresses()
            return run(m0[a:b].ctypes.data, n, P0[a:b].ctypes.data, n * n, Yc[a:b].ctypes.data,
                       mask[a:b].ctypes.data, pv[a:b].ctypes.data, thv[a:b].ctypes.data, dts[a:b].ctypes.data,
                       starts[a:b].ctypes.data, Rf.ctypes.data, Z.ctypes.data, wm.ctypes.data, wc.ctypes.data,
                       jcol.ctypes.data, jrow.ctypes.data, tolv.ctypes.data, int(max_evaluations), int(transition),
                       outs, b - a, K, iw, w, failed[a:b].ctypes.data, stop)

        self.run_chunks(part, list(range(len(chunks))), "continuous-discrete filter",
                        long_bank(runs, K * _EVALS, n))
        return failed


_kernels: dict[tuple, CompiledCD] = {}
_kernels_lock = threading.Lock()


def compiled_cd(key: tuple, *args) -> CompiledCD:
    """The :class:`CompiledCD` of ``args``, built once per process for ``key`` (hashable, and
    naming all that the arguments are); its C is cached on disk."""
    with _kernels_lock:
        kernel = _kernels.get(key)
        if kernel is None:
            kernel = _kernels[key] = CompiledCD(*args)
        return kernel
