"""The Gaussian-sum filter's recursion with splitting, the K steps of a run in one C call.

:meth:`GaussianSumFilter.filter <symmon.GaussianSumFilter.filter>` with ``split`` set runs,
per step and run, the stages of :mod:`symmon.filters.mixture.gaussian_sum` (its module notes give the
formulas): the MoN of f at every component (TT2, W^full; Straka & Havlík 2024, eqs. (25),
(29), (43)), the split of those above ``split`` along their most curved direction, the
prediction, the MoN of h at the predicted components and their split, the update, the
log-likelihood, pruning and the greedy Runnalls or Salmond merge, and with ``merge_back``
the merging back of the calm components (their MoN of f and h below split/2 with the next
step's parameters; the first pair of least Runnalls cost while it is below ``merge_back``).  ``sm_gsfk_run`` does all
of that for all K steps of a range of runs without returning to Python: the four compiled
graphs of the stepwise filter (prediction, update, the MoN of f and of h with the Hessians,
CasADi's generated C), the merge kernel of :mod:`symmon.filters.mixture.merge`, and in C
here the MoN's weight (the inverse of the correlation matrix of Σ_yy, a pseudo-inverse
through its eigen-decomposition, as ``numpy.linalg.pinv(..., hermitian=True)``), the split
decision, the direction and the split.

The eigen-decompositions (of P, of the weight and of the whitened curvatures G_k, n ≤ a few
dozen) are cyclic Jacobi rotations (Golub & Van Loan 2013, §8.5), eigenvalues ascending as
LAPACK's; the direction d = S a does not depend on the choice of the square root S of P
or the signs of the eigenvectors except for its own sign, which both paths fix the same way
(:func:`~symmon.filters.mixture.gaussian_sum.split_directions`: the entry of largest magnitude,
the first within TIE, positive).  The results equal the stepwise NumPy path's to rounding.
The C is built for the state's dimension (``SMG_N``, and the merge kernel's n): its small
loops unroll, with the same operations in the same order (no FMA contraction in symmon's
builds), so the results do not depend on it.

References
----------
G. H. Golub, C. F. Van Loan, *Matrix Computations*, 4th ed., Johns Hopkins, 2013, §8.5.
"""

from __future__ import annotations

import ctypes
import threading

import casadi as ca
import numpy as np

from ...compile.ccache import NativeLibrary
from ...compile.ckernels import STOPPED
from ...compile.compiled import WorkArrays, generated_c, row_spans, run_stoppable
from ...compile.csource import c_defines, c_file
from .merge import MERGE_C

__all__ = ["SplitKernel", "bank_weights", "result_arrays"]

#: The recursion (``gsf.c``), after the generated graphs, the merge kernel and the SMG_ macros.
_BODY = c_file(__package__, "gsf.c")


def result_arrays(R: int, K: int, n: int, Mk: int, kept) -> dict[str, np.ndarray]:
    """The outputs of the splitting filter for R runs of K steps, n states and at most Mk
    components, both paths alike: the log-likelihood, the components and splits per step,
    and what ``kept`` names of x, P and the mixture (zero-padded to Mk components)."""
    out = {"loglik": np.empty((R, K)), "components": np.empty((R, K), dtype=np.int64),
           "splits": np.zeros((R, K), dtype=np.int64)}
    if "x" in kept:
        out["x"] = np.empty((R, K, n))
    if "P" in kept:
        out["P"] = np.empty((R, K, n, n))
    if "mixture" in kept:
        out.update(weights=np.zeros((R, K, Mk)), means=np.zeros((R, K, Mk, n)), covs=np.zeros((R, K, Mk, n, n)))
    return out


#: Steps × components (the runs' K steps of at most ``max_components``) from which a single
#: run of the recursion, on the main thread, goes to the thread pool, so that a Ctrl-C stops
#: it at once (a few tens of milliseconds of steps and more).
LONG_STEPS = 10_000


class SplitKernel:
    """The compiled recursion of the Gaussian-sum filter with splitting (module notes), for the
    four generated graphs of its stepwise filter: ``predict`` (x, P, Q, p) ↦ (x⁻, P⁻),
    ``update`` (x⁻, P⁻, y, R, mask, p) ↦ (x, P, log N(ν; 0, S)), and ``mon_f``, ``mon_h``
    (x, P, p) ↦ (Cov g, D, the Hessians), each of one packed row."""

    def __init__(self, predict: ca.Function, update: ca.Function, mon_f: ca.Function, mon_h: ca.Function,
                 n: int, n_y: int, n_p: int, stem: str) -> None:
        self.n, self.n_y, self.n_p = n, n_y, n_p
        fns = (predict, update, mon_f, mon_h)
        nym = max(n, n_y)
        row = max(f.nnz_in(0) for f in fns)
        # Scratch of smg_direction / smg_pinv (at the start) and of the stages after them.
        sc_dir = 6 * n + 6 * n * n + 2 * nym * n * n + 4 * nym * nym + nym * n + 2 * nym + 8
        sc_more = 4 * n * n + 4 * n + 4 * nym * nym + 4 * nym + 8
        defines = c_defines(SMG_PREDICT=predict.name(), SMG_UPDATE=update.name(), SMG_MON_F=mon_f.name(),
                            SMG_MON_H=mon_h.name(), SMG_SZ_ARG=max(max(f.sz_arg() for f in fns), 1),
                            SMG_SZ_RES=max(max(f.sz_res() for f in fns), 3), SMG_ROW=row, SMG_SC_DIR=sc_dir,
                            SMG_SC_MORE=sc_more, SMG_N=n, SMG_STOPPED=STOPPED)
        # The merge kernel of mixture_merge with the state's dimension a constant (its loops
        # unrolled and its loops over the pairs vectorised: the merge is most of a step at
        # M ≥ 16), the same operations in the same order (no FMA contraction in symmon's
        # builds), so the same merges to the bit.  Every function takes n as "long long n,".
        merge = c_defines(SM_MERGE_N=n) + MERGE_C
        code = generated_c(*fns) + merge + defines + _BODY
        self._work = WorkArrays(*fns)

        def load(so):
            fn = ctypes.CDLL(str(so)).sm_gsfk_run
            fn.argtypes = [ctypes.c_longlong] * 3 + [ctypes.c_void_p] * 24
            fn.restype = ctypes.c_int
            return fn

        self.native = NativeLibrary(code, stem, load, stacklevel=5)

    def loop(self):
        """The ctypes function, or None (no compiler, or its build is still running)."""
        return self.native.get()

    def run(self, fn, Y: np.ndarray, w0: np.ndarray, m0: np.ndarray, P0: np.ndarray, params: np.ndarray,
            Q: np.ndarray, R: np.ndarray, *, split: float, prune: float, max_components: int, m: int,
            salmond: bool, curved: tuple[bool, bool], table: tuple[np.ndarray, np.ndarray, float],
            angle_states: tuple[int, ...], kept: set[str], merge_back: float | None = None
            ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """All steps of all runs: Y (R, K, n_y) with NaN for missing, the prior (w0, m0, P0),
        params (R, K, n_p), ``merge_back`` the Runnalls cost below which calm components merge
        back after each step (None: never); the outputs of :meth:`GaussianSumFilter._stepwise
        <symmon.GaussianSumFilter>` and fail (R,), the step of each run where a component
        turned non-finite (-1: none).  The runs are shared among threads.

        Raises
        ------
        KeyboardInterrupt
            On a Ctrl-C while the loops run: they stop before their next step
            (:func:`~symmon.compile.compiled.run_stoppable`), and no result is returned."""
        Rr, K, n_y = Y.shape
        n, Mk = self.n, max_components
        measured = ~np.isnan(Y)
        Yz = np.ascontiguousarray(np.where(measured, Y, 0.0))
        mask = np.ascontiguousarray(measured, dtype=float)
        prm = np.ascontiguousarray(params, dtype=float).reshape(Rr, K, self.n_p)
        if self.n_p == 0:
            prm = np.zeros((Rr, K, 1))
        c = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731
        w0, m0, P0, Q, R = c(w0), c(m0), c(P0), c(Q), c(R)
        opt = np.array([n, n_y, self.n_p, m, Mk, int(salmond), int(curved[0]), int(curved[1]), len(w0)],
                       dtype=np.int64)
        fl = np.array([split, prune, table[2], 0.0 if merge_back is None else merge_back])
        tab = np.concatenate([table[0], table[1]])
        ang = np.array([int(i in angle_states) for i in range(n)], dtype=np.intc)
        out = result_arrays(Rr, K, n, Mk, kept)
        fail = np.full(Rr, -1, dtype=np.int64)
        ptr = lambda name: out[name].ctypes.data if name in out else None  # noqa: E731

        def part(span: tuple[int, int], stop: int) -> int:
            iw, wk = self._work.addresses()
            return fn(span[0], span[1], K, opt.ctypes.data, fl.ctypes.data, tab.ctypes.data, ang.ctypes.data,
                      Q.ctypes.data, R.ctypes.data, w0.ctypes.data, m0.ctypes.data, P0.ctypes.data, Yz.ctypes.data,
                      mask.ctypes.data, prm.ctypes.data, ptr("loglik"), ptr("components"), ptr("splits"), ptr("x"),
                      ptr("P"), ptr("weights"), ptr("means"), ptr("covs"), fail.ctypes.data, iw, wk, stop)

        # a Ctrl-C stops the loops before their next step; one run of many steps goes to the
        # pool too (a step of a few components takes tens of microseconds)
        codes = run_stoppable(part, row_spans(Rr, 1), long=Rr * K * Mk >= LONG_STEPS)
        if any(code < 0 for code in codes):
            raise MemoryError("the Gaussian-sum filter's compiled recursion could not allocate its components")
        if any(codes):
            raise RuntimeError("a compiled step of the Gaussian-sum filter returned an error")
        return out, fail


# The weights of a Gaussian sum without splitting: its components are independent filters, and
# only the normalised log-weights recur, step by step (Alspach & Sorenson 1972).
_WEIGHTS_C = c_file(__package__, "gsf_weights.c")

_weights: NativeLibrary | None = None
_weights_lock = threading.Lock()


def _load_weights(so):
    fn = ctypes.CDLL(str(so)).sm_gsf_weights
    fn.argtypes = [ctypes.c_longlong] * 3 + [ctypes.c_void_p] * 4
    fn.restype = ctypes.c_int
    return fn


def bank_weights(logw0: np.ndarray, ll: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalised log-weights (R, K, M) and the log-likelihood per step (R, K) of a
    Gaussian sum whose M components are independent filters with the log-likelihood
    increments ``ll`` (R, M, K) and the prior log-weights ``logw0`` (M,): per step,
    a = prev + ll_k, ℓ_k = log Σ exp(a) (by its maximum), prev = a − ℓ_k.

    One C loop (a few ns a component and step) when a compiler is available, else the same
    recursion in NumPy, one step at a time; the two agree to rounding (exp and log of
    the C library against NumPy's)."""
    R, M, K = ll.shape
    ll = np.ascontiguousarray(ll, dtype=float)
    logw0 = np.ascontiguousarray(np.broadcast_to(logw0, (M,)), dtype=float)
    global _weights
    with _weights_lock:
        if _weights is None:
            _weights = NativeLibrary(_WEIGHTS_C, "sm_gsf_weights", _load_weights, stacklevel=3)
    fn = _weights.get()
    logw, step_ll = np.empty((R, K, M)), np.empty((R, K))
    if fn is not None:
        fn(R, M, K, logw0.ctypes.data, ll.ctypes.data, logw.ctypes.data, step_ll.ctypes.data)
        return logw, step_ll
    prev = np.broadcast_to(logw0, (R, M))
    for k in range(K):
        a = prev + ll[:, :, k]
        top = a.max(axis=1, keepdims=True)
        step_ll[:, k] = top[:, 0] + np.log(np.exp(a - top).sum(axis=1))
        prev = a - step_ll[:, k:k + 1]
        logw[:, k] = prev
    return logw, step_ll
