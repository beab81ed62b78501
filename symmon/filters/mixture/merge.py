"""Greedy reduction of Gaussian mixtures: Runnalls' (2007) and Salmond's (1990) pair merging.

While a run's mixture Σ_i w_i N(m_i, P_i) has more than ``keep`` components, the pair
(i, j) of least cost is replaced by its moment-matched Gaussian (which keeps the mixture's
mean and covariance):

    w = w_i + w_j,  m = (w_i m_i + w_j m_j)/w,
    P = Σ_{k ∈ {i, j}} (w_k/w) (P_k + (m_k − m)(m_k − m)ᵀ).

The costs are Runnalls' upper bound on the Kullback–Leibler discrimination of the merge
(Runnalls 2007, eq. (21)),

    B_ij = ½[(w_i + w_j) log det P_ij − w_i log det P_i − w_j log det P_j],

with P_ij the covariance of the merged pair, or Salmond's distance
w_i w_j/(w_i + w_j) (m_i − m_j)ᵀ P⁻¹ (m_i − m_j) in the metric of the mixture's covariance P
before the reduction.  The greedy search computes the costs of all M(M − 1)/2 pairs once;
after merging (i, j) into i only the M − 2 costs of the pairs with i change, so M − keep
merges cost O(M² + (M − keep) M) pair costs (Runnalls 2007, Sec. V) rather than
recomputing all pairs per merge.  Ties go to the first pair (i, j), i < j, in the order of the
components as they stand.

Two implementations give the same merges: :func:`merge_numpy`, the pair costs as stacked
NumPy expressions and the greedy loop in Python; and a C kernel (one call for all runs of a
bank, the log-determinants by L D Lᵀ) that :func:`merge_runs` uses when a compiler is
available (symmon.compile's policy, ``SYMMON_COMPILE``).  Their costs differ by rounding
(L D Lᵀ against LU), so they agree to rounding except where two pair costs tie to the
last bits.

The C kernel computes a Runnalls cost only for a pair that could be the least: until then a
lower bound that needs no log-determinant stands in for it (its key).  With S = f_i P_i +
f_j P_j, f = w/(w_i + w_j), c = f_i f_j and d = m_i − m_j,

    B_ij = ½ (w_i + w_j) [log det S − f_i log det P_i − f_j log det P_j + log(1 + x)],
    x = c dᵀ S⁻¹ d;

the first three terms of the bracket (J) are ≥ n log(1 + y), y = f_i f_j (s_i − s_j)²/(f_i s_i +
f_j s_j)², s_k = (det P_k)^(1/2n): Minkowski's determinant inequality, det(S)^(1/n) ≥ f_i
det(P_i)^(1/n) + f_j det(P_j)^(1/n), and the weighted geometric mean below the power mean of
order ½, (det P_i)^(f_i/n) (det P_j)^(f_j/n) ≤ (f_i s_i + f_j s_j)² (so pairs of components of
very different sizes get a bound without a log-determinant); log(1 + x) ≥ 2x/(2 + x) (x ≥ 0;
the derivative of the difference is x²/((1 + x)(2 + x)²)), and x ≥ c |W d|²/(f_i g_i + f_j g_j)
for any invertible W with g ≥ the largest eigenvalue of W P Wᵀ (then S ≤ (f_i g_i + f_j g_j)
(WᵀW)⁻¹).  W whitens the weighted harmonic mean T of the covariances, T⁻¹ = Σ_k w_k P_k⁻¹/Σ_k
w_k (W = L⁻¹ diag(T)^-½ with L the Cholesky factor of the scaled T, the diagonal scaling alone
when that is ill-conditioned), so that a pair's bound does not suffer from states in different
units or correlated states, nor from a few wide components (an arithmetic mean, inflated along
the directions in which they are wide, would shrink |W d| for every pair apart along those);
the harmonic mean comes from the L D Lᵀ factors of the log-determinants.  g is the least of the
trace and the largest absolute row sum of W P Wᵀ.  So

    B_ij ≥ (w_i + w_j) [N/(2D + N) + n E/F],  N = w_i w_j |W d|²,  D = (w_i + w_j)(w_i g_i + w_j g_j),
    E = w_i w_j (s_i − s_j)²,  F = 2 (w_i s_i + w_j s_j)² + E,

computed from whitened means W (m_k − c) stored once per component (with an allowance for
their rounding), the s relative to the run's mean log-determinant, and lowered by a margin
(1e-9 relative, and 1e-9 (w_i + w_j)(n + |log det P_i| + |log det P_j|) absolute) that covers
the rounding of the key and of the cost (n E/F moves by at most ½ per unit of error in a
log-determinant).  On the merges of a Gaussian-sum filter's bank (benchmarks/gsf.py, 192
components merged to 64) about 430 pairs' costs are computed a call for the 128 merges, of the
18 336 pairs at first (about 830 without Minkowski's term and with the arithmetic mean).  A
component whose bound does not hold (a covariance that is not positive definite, a weight that
is not positive) gets NaN keys, which come first and so have their costs computed before any
merge.

The pair of least key (sm_before's order, then the first pair) is taken; while its key is a
bound, its cost replaces it and the search repeats.  Every key is at most its pair's cost, so
the merges are those of the exhaustive search, every live pair's cost computed at every merge
(the kernel's reference mode, ``flags`` 2: O(M³), for the tests): the first pair of least cost
is never passed over.  The keys sit in an M × M matrix, each pair's in one row: the row of the
component whose row was computed last.  A component's stamp (M − i at first, a count from
M + 1 when a merge changes it, +inf when it is merged away) says which: the key in row i,
column j is valid when stamp_j < stamp_i.  At first row i holds the pairs (i, j), j > i; a
merge into i recomputes row i for every j (one contiguous row, a loop the compiler vectorises)
and nothing else is written.  Each row's first least valid key is kept (a vectorised scan, two
sets of lanes so that their compare-and-select chains overlap); a row whose least pair went
away keeps its old minimum as a lower bound until it comes to the top, and is rescanned then.
The rows sit in a tournament tree ordered by key, then by pair; a row's walk to the root
carries its winner in registers and compares only integers (the keys as integers that order as
the doubles do), with no branch on the data.  Per merge that is O(M) keys and a few O(M) scans,
O(M²) for the reduction, against the exhaustive search's O(M³) costs.  What a merge call costs
then (M = 64 above, per call): the keys ~1/4 (~36 000, vectorised), the row scans ~1/4 (~970
over ~135 000 columns), the tree ~1/8 (~910 walks), the costs and log-determinants ~1/8.

References
----------
A. R. Runnalls, "Kullback–Leibler approach to Gaussian mixture reduction", IEEE Trans.
Aerosp. Electron. Syst. 43(3), 2007. doi:10.1109/TAES.2007.4383588
D. J. Salmond, "Mixture reduction algorithms for target tracking in clutter", Proc. SPIE
1305, 1990.
"""

from __future__ import annotations

import ctypes
import threading

import numpy as np

from ...compile.ccache import NativeLibrary
from ...compile.csource import c_file
from ...core.mixture import mixture_moments
from ...errors import ArgumentError, SymmonError

__all__ = ["MERGE_C", "MERGE_RULES", "merge_components", "merge_numpy", "merge_runs", "pair_costs", "merge_kernel",
           "merge_below"]

#: The merging criteria.
MERGE_RULES = ("runnalls", "salmond")

#: The C of the merge kernel (``merge.c``; with ``SM_MERGE_N`` defined, the Gaussian-sum filter's
#: kernel takes it for a fixed dimension).
MERGE_C = c_file(__package__, "merge.c")

_kernel: NativeLibrary | None = None
_kernel_lock = threading.Lock()


def _load(so):
    fn = ctypes.CDLL(str(so)).sm_gsf_merge
    fn.argtypes = [ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_int] \
        + [ctypes.c_void_p] * 5
    fn.restype = ctypes.c_int
    return fn


def merge_kernel():
    """The ctypes function of the C merge kernel, or None (no compiler, ``SYMMON_COMPILE=never``
    or a failed build: the caller takes :func:`merge_numpy`)."""
    global _kernel
    with _kernel_lock:
        if _kernel is None:
            _kernel = NativeLibrary(MERGE_C, "sm_gsf_merge", _load, stacklevel=3)
    return _kernel.get()


def _check_rule(rule: str) -> None:
    if rule not in MERGE_RULES:
        raise ArgumentError(f"merge must be one of {MERGE_RULES}, got {rule!r}")


def _metric(w: np.ndarray, m: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Salmond's metric: the inverse of the mixture's covariance, through its correlation
    matrix (states in different units are not "singular"), a pseudo-inverse where singular."""
    C = mixture_moments(w / w.sum(), m, P)[1]
    r = 1.0 / np.sqrt(np.diag(C))
    return r[:, None] * np.linalg.pinv(r[:, None] * C * r[None, :], rcond=1e-12, hermitian=True) * r[None, :]


def pair_costs(w: np.ndarray, m: np.ndarray, P: np.ndarray, ld: np.ndarray | None, a: np.ndarray, b: np.ndarray,
               rule: str, Pinv: np.ndarray | None) -> np.ndarray:
    """The merging costs of the pairs (a[k], b[k]) (module notes), one stacked expression:
    Runnalls' bound with ld the log-determinants of the P, or Salmond's distance in the metric
    Pinv; symmetric in the pair to the bit."""
    wi, wj = w[a], w[b]
    ws = wi + wj
    d = m[a] - m[b]
    if rule == "runnalls":
        Pij = (wi[:, None, None] * P[a] + wj[:, None, None] * P[b]) / ws[:, None, None] \
            + (wi * wj / ws**2)[:, None, None] * d[:, :, None] * d[:, None, :]
        return 0.5 * (ws * np.linalg.slogdet(Pij)[1] - (wi * ld[a] + wj * ld[b]))
    return wi * wj / ws * np.einsum("ka,ab,kb->k", d, Pinv, d)


def _merge_pair(w: np.ndarray, m: np.ndarray, P: np.ndarray, i: int, j: int) -> None:
    """Component i becomes the moment-matched Gaussian of the pair (i, j), in place."""
    ws = w[i] + w[j]
    a, b = w[i] / ws, w[j] / ws
    mm = a * m[i] + b * m[j]
    di, dj = m[i] - mm, m[j] - mm
    PP = a * P[i] + b * P[j] + a * np.outer(di, di) + b * np.outer(dj, dj)
    w[i], m[i], P[i] = ws, mm, 0.5 * (PP + PP.T)


def merge_numpy(w: np.ndarray, m: np.ndarray, P: np.ndarray, keep: int, rule: str = "runnalls"
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One mixture reduced to at most ``keep`` components in NumPy (module notes): the pair
    costs computed once, then per merge only the pairs of the merged component."""
    _check_rule(rule)
    w, m, P = (np.array(a, dtype=float) for a in (w, m, P))
    M = len(w)
    if M <= keep:
        return w, m, P
    Pinv = _metric(w, m, P) if rule == "salmond" else None
    ld = np.linalg.slogdet(P)[1] if rule == "runnalls" else None
    cost = np.full((M, M), np.inf)  # cost[i, j] of the live pair i < j; inf elsewhere
    iu, ju = np.triu_indices(M, 1)
    cost[iu, ju] = pair_costs(w, m, P, ld, iu, ju, rule, Pinv)
    alive = np.ones(M, dtype=bool)
    for _ in range(M - keep):
        i, j = divmod(int(np.argmin(cost)), M)
        if not i < j or cost[i, j] == np.inf:
            # Every live pair costs inf (the argmin landed on a filler inf): the first live pair.
            i, j = (int(a) for a in np.flatnonzero(alive)[:2])
        _merge_pair(w, m, P, i, j)
        alive[j] = False
        cost[j, :] = cost[:, j] = np.inf
        if ld is not None:
            ld[i] = np.linalg.slogdet(P[i])[1]
        others = np.flatnonzero(alive)
        others = others[others != i]
        c = pair_costs(w, m, P, ld, others, np.full(len(others), i), rule, Pinv)
        lo = others < i
        cost[others[lo], i] = c[lo]
        cost[i, others[~lo]] = c[~lo]
    return w[alive], m[alive], P[alive]


def merge_runs(run: np.ndarray, w: np.ndarray, m: np.ndarray, P: np.ndarray, keep: int, rule: str = "runnalls",
               native: bool = True) -> np.ndarray:
    """Reduce every run of a bank to at most ``keep`` components, in place: ``run`` (N,) the
    non-decreasing run index of each component of w (N,), m (N, n), P (N, n, n).  Returns the
    mask of the components left (the merged ones hold the merged moments).  One call of the
    C kernel for all runs when it is available and ``native``; else :func:`merge_numpy` per
    run that needs it."""
    return _merge_runs(run, w, m, P, keep, rule, native, exhaustive=False)


def _merge_runs(run, w, m, P, keep, rule, native, exhaustive):
    """:func:`merge_runs`; ``exhaustive``: the C kernel's reference search instead (every live
    pair's cost at every merge, O(M³); module notes), the one the greedy search must equal."""
    _check_rule(rule)
    R = int(run[-1]) + 1 if len(run) else 0
    counts = np.bincount(run, minlength=R)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    alive = np.ones(len(w), dtype=np.uint8)
    over = np.flatnonzero(counts > keep)
    if not len(over):
        return alive.astype(bool)
    n = m.shape[1]
    fn = merge_kernel() if native else None
    if fn is None:
        for r in over:
            a, b = start[r], start[r + 1]
            wr, mr, Pr = merge_numpy(w[a:b], m[a:b], P[a:b], keep, rule)
            k = len(wr)
            w[a:a + k], m[a:a + k], P[a:a + k] = wr, mr, Pr
            alive[a + k:b] = 0
        return alive.astype(bool)
    Pinv = np.zeros((R, n, n) if rule == "salmond" else 1)
    if rule == "salmond":
        for r in over:
            Pinv[r] = _metric(w[start[r]:start[r + 1]], m[start[r]:start[r + 1]], P[start[r]:start[r + 1]])
    for a in (w, m, P):
        if not (a.flags.c_contiguous and a.dtype == np.float64):
            raise SymmonError("merge_runs works in place on C-contiguous float64 arrays")
    ptr = lambda a: a.ctypes.data  # noqa: E731  (an int: c_void_p accepts it, cheaper than data_as)
    flags = int(rule == "salmond") | (2 if exhaustive else 0)
    if fn(R, ptr(start), n, keep, flags, ptr(w), ptr(m), ptr(P), ptr(Pinv), ptr(alive)):
        raise MemoryError("the mixture merge could not allocate its cost matrix")
    return alive.astype(bool)


def merge_components(w: np.ndarray, m: np.ndarray, P: np.ndarray, keep: int, rule: str = "runnalls",
                     native: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge pairs of the mixture (w (M,), m (M, n), P (M, n, n)) until at most ``keep``
    components are left, the pair of least Runnalls (2007) or Salmond (1990) cost first
    (module notes); the inputs are not changed.  ``native``: the C kernel where available."""
    _check_rule(rule)
    w, m, P = (np.array(a, dtype=float, order="C") for a in (w, m, P))
    alive = merge_runs(np.zeros(len(w), dtype=np.intp), w, m, P, keep, rule, native)
    return w[alive], m[alive], P[alive]


def merge_below(w: np.ndarray, m: np.ndarray, P: np.ndarray, threshold: float, calm: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merge pairs of the ``calm`` components of one mixture while the least Runnalls (2007)
    cost B_ij among them is below ``threshold`` (the first pair of least cost first; the
    merged component is calm), each merge the moment-matched Gaussian of the pair (which
    keeps the mixture's mean and covariance).  The inputs are not changed.

    Returns
    -------
    w (M',), m (M', n), P (M', n, n), calm (M',)
        The mixture after the merges, in the order of its first components.
    """
    w, m, P = (np.array(a, dtype=float) for a in (w, m, P))
    calm = np.array(calm, dtype=bool)
    alive = np.ones(len(w), dtype=bool)
    ld = np.linalg.slogdet(P)[1]
    while True:
        idx = np.flatnonzero(alive & calm)
        if len(idx) < 2:
            break
        iu, ju = np.triu_indices(len(idx), 1)
        a, b = idx[iu], idx[ju]
        cost = pair_costs(w, m, P, ld, a, b, "runnalls", None)
        best = int(np.argmin(cost))
        if not cost[best] < threshold:
            break
        i, j = int(a[best]), int(b[best])
        _merge_pair(w, m, P, i, j)
        ld[i] = np.linalg.slogdet(P[i])[1]
        alive[j] = False
    return w[alive], m[alive], P[alive], calm[alive]
