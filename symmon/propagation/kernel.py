"""The moments of a batch of Gaussians by a point rule, in compiled C (:func:`propagate_many`).

For the K Gaussians of a batch, a point rule (the UT family, the cubature rules,
Gauss–Hermite's tensor grid) in NumPy builds (K, N, n) arrays of points, evaluates g on
them, and sums weighted products of (K, N, n_y) residuals.  Here one CasADi function
(m, P) ↦ (E y, Cov y, Cov(w, y), p) does the whole rule for one Gaussian, from the moment
graphs the filters compile (:func:`symmon.codegen.symbolic.moments`: the Cholesky factor,
the map of g over the points, the weighted sums as matrix products), with p the smallest
pivot of its Cholesky factor; a C loop runs it over the batch, split over threads.  So
there are no temporaries of K N n numbers, and the validation of the batch uses the rule's
own factor: a Gaussian whose factor fails (p ≤ 0 or NaN: a singular or indefinite
covariance) sends the whole batch through the NumPy rule, which takes a singular
covariance's square root by eigh and names an indefinite one.

The kernel is built in the background (the compile policy, docs/compile.md) while the NumPy
rule answers, so no call waits for the compiler; its results are those of the NumPy rule up
to rounding (the sums run in another order).  It is used for batches of at least
:data:`MIN_BATCH` Gaussians, for rules whose covariance weights are all non-negative (a
rule with negative weights needs the scale of its sums for the definiteness test:
``Moments.cov_scale``), and for models with no undeclared angle output (whose points the
NumPy rule inspects for the cut at ±π).
"""

from __future__ import annotations

import ctypes
import hashlib
import threading
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

from ..codegen.symbolic import graph_kind, moments
from ..compile.ccache import NativeLibrary
from ..compile.csource import c_defines, c_file
from ..compile.compiled import CompiledModel, WorkArrays, generated_c, in_threads, model_key, row_spans
from ..core.gaussian import SYMMETRY_RTOL
from ..transforms.base import Moments, Transform, likely_angles

__all__ = ["MIN_BATCH", "batch_kernel", "kernel_moments"]

#: The smallest batch the kernel takes: below it the NumPy rule's temporaries are small.
MIN_BATCH = 64
#: Gaussians per thread, at least.
MIN_PER_THREAD = 32

#: The loop over a batch of Gaussians (batch_kernel.c) after the rule's generated C.
_LOOP = c_file(__package__, "batch_kernel.c")


def _moment_function(cm: CompiledModel, transform: Transform, angles: frozenset[int], name: str) -> ca.Function:
    """(m, P) ↦ (E y, Cov y, Cov(w, y), p) of the rule at N(m, (P + Pᵀ)/2), with p the
    smallest pivot of its Cholesky factor (the symmetry test of :class:`~symmon.Gaussian`
    is in the C loop, ``_LOOP``); Cov(w, y) n × n_y, so that its column-major entries are
    the row-major (n_y, n) Cov(y, w) of a batch."""
    n = cm.n_w
    kind, chol = graph_kind(n, len(transform.unit_rule(n)[0]))
    m, P_in = kind.sym("m", n), kind.sym("P", n, n)
    P = 0.5 * (P_in + P_in.T)
    factors = []

    def recorded(A):
        L = chol(A)
        factors.append(L)
        return L

    mean, cov, cross = moments(cm, m, P, transform, angles, recorded)
    L = factors[0] if factors else chol(P)  # an affine g takes TT1's closed forms: no points, no factor
    pivot = ca.mmin(ca.diag(L))
    cov = 0.5 * (cov + cov.T)  # exactly symmetric, as the NumPy rule's
    outs = [ca.densify(a) for a in (mean, cov, cross.T, pivot)]
    return ca.Function(name, [m, P_in], outs, ["m", "P"], ["mean", "cov", "cross_t", "pivot"],
                       {"cse": True})


def _load(name: str) -> Callable[[Path], Callable]:
    def load(path: Path):
        fn = getattr(ctypes.CDLL(str(path)), f"{name}_batch")
        fn.argtypes = [ctypes.c_void_p] * 6 + [ctypes.c_longlong] + [ctypes.c_void_p] * 2
        fn.restype = ctypes.c_int
        return fn
    return load


class BatchKernel:
    """The compiled moments of one (model, point rule, angle outputs) over a batch."""

    def __init__(self, cm: CompiledModel, transform: Transform, angles: frozenset[int]) -> None:
        # The model by its structural hash: printing a traced loop's outputs takes exponential time.
        key = repr((model_key(cm.source_exprs, cm.symbols), transform, sorted(angles)))
        self.name = name = "sm_batch_" + hashlib.sha1(key.encode()).hexdigest()[:12]
        self.f = f = _moment_function(cm, transform, angles, name)
        self.n, self.n_y = cm.n_w, cm.n_y
        self.points = len(transform.unit_rule(cm.n_w)[0])
        n, n_y = self.n, self.n_y
        code = generated_c(f) + c_defines(
            PBK_F=name, PBK_FINITE=f"{name}_finite", PBK_BATCH=f"{name}_batch", PBK_SZ_ARG=max(f.sz_arg(), 2),
            PBK_SZ_RES=max(f.sz_res(), 4), PBK_N=n, PBK_NN=n * n, PBK_N_Y=n_y, PBK_NYY=n_y * n_y, PBK_NNY=n * n_y) + _LOOP
        self._lib = NativeLibrary(code, name, _load(name), stacklevel=4, background=True)
        self._work = WorkArrays(f)

    @property
    def evaluator(self) -> str:
        """``"compiled"``, ``"vm"`` or ``"vm (C build running)"`` (the NumPy rule runs while not compiled)."""
        return self._lib.evaluator

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the background build; True when the compiled kernel is in."""
        return self._lib.wait(timeout)

    def __call__(self, M: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """(E y (K, n_y), Cov y (K, n_y, n_y), Cov(y, w) (K, n_y, n), checks (K, 3)) of the
        batch M (K, n), P (K, n, n) (checks: the smallest pivot and the asymmetry of each
        P, and 1 where all of that Gaussian's inputs and moments are finite, else 0:
        ``_LOOP``), or None while the kernel is not compiled."""
        run = self._lib.get()
        if run is None:
            return None
        K = M.shape[0]
        M, P = np.ascontiguousarray(M, dtype=float), np.ascontiguousarray(P, dtype=float)
        out = (np.empty((K, self.n_y)), np.empty((K, self.n_y, self.n_y)), np.empty((K, self.n_y, self.n)),
               np.empty((K, 3)))

        def part(ab: tuple[int, int]) -> int:
            a, b = ab
            iw, w = self._work.addresses()
            return run(M[a:].ctypes.data, P[a:].ctypes.data, *(o[a:].ctypes.data for o in out), b - a, iw, w)

        if any(in_threads(part, row_spans(K, MIN_PER_THREAD))):
            raise RuntimeError(f"the compiled batch moments {self.name} returned an error")
        return out


_kernels: dict[tuple, BatchKernel | None] = {}
_lock = threading.Lock()


def batch_kernel(cm: CompiledModel, transform: Transform, angles: frozenset[int], K: int) -> BatchKernel | None:
    """The kernel of (cm, transform, angles) for a batch of K Gaussians (built once per
    process, its C cached on disk), or None where the NumPy rule must run: a batch below
    :data:`MIN_BATCH`, a rule that is not a point rule or has a negative covariance weight,
    a model with an undeclared angle output, or no compiled evaluation (``cm.compiled``)."""
    if K < MIN_BATCH or not cm.compiled or not transform.point_rule or transform.taylor_order is not None:
        return None
    key = (cm, transform, angles)
    with _lock:  # decided once per key: the rule's points and the angle hint are not rebuilt per call
        if key not in _kernels:
            rule = transform.unit_rule(cm.n_w)
            takes = rule is not None and not np.any(np.asarray(rule[2]) < 0) and not likely_angles(cm, angles)
            _kernels[key] = BatchKernel(cm, transform, angles) if takes else None
        return _kernels[key]


def kernel_moments(kernel: BatchKernel, cm: CompiledModel, transform: Transform, M: np.ndarray, P: np.ndarray
                   ) -> Moments | None:
    """The moments of the batch (M, P) by the compiled kernel, or None when the NumPy rule
    must run (and check the batch, naming any culprit): the kernel is still being built, or
    some input or moment is not finite, or some covariance is asymmetric beyond
    ``SYMMETRY_RTOL`` or has a Cholesky factor that failed (singular or indefinite).

    Cov y needs no test of definiteness: with non-negative weights it is a sum of
    positive semi-definite terms (:func:`batch_kernel` takes no other rule).
    """
    out = kernel(M, P)
    if out is None:
        return None
    mean, cov, cross, checks = out
    # Any doubt (a non-finite input or moment, too asymmetric, a failed factor): the NumPy
    # rule checks the batch again and names the culprit.
    if not (np.all(checks[:, 2] == 1) and np.all(checks[:, 0] > 0) and np.all(checks[:, 1] <= SYMMETRY_RTOL)):
        return None
    return Moments(mean, cov, cross, evaluations=M.shape[0] * kernel.points,
                   details={"evaluator": "compiled batch kernel"})
