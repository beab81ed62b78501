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
lower bound that needs no log-determinant stands in for it.  With S = f_i P_i + f_j P_j,
f = w/(w_i + w_j) and c = f_i f_j, B_ij = ½ (w_i + w_j) [log det S − f_i log det P_i −
f_j log det P_j + log(1 + c dᵀ S⁻¹ d)], d = m_i − m_j; the bracket's first three terms are
≥ 0 (log det is concave) and log(1 + x) ≥ x/(1 + x), with x ≥ c |d|²/(f_i g_i + f_j g_j) for
any g ≥ the largest eigenvalue of P (the least of its trace and its largest absolute row
sum), so B_ij ≥ ½ (w_i + w_j) N/(D + N), N = w_i w_j |d|², D = (w_i + w_j)(w_i g_i + w_j g_j).
The pair of least key is taken; while it is a bound, its cost replaces it and the search
repeats, so the merges are those of every cost computed.  The rows' least keys sit in a
tournament tree (the pair to merge at its root, a changed row updated in O(log M)).

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

from ..compile import NativeLibrary
from ..core.mixture import mixture_moments
from ..errors import ArgumentError, SymmonError

__all__ = ["MERGE_RULES", "merge_components", "merge_numpy", "merge_runs", "pair_costs", "merge_kernel"]

#: The merging criteria.
MERGE_RULES = ("runnalls", "salmond")

_C = r"""
#include <math.h>
#include <stdlib.h>

/* symmon: greedy Gaussian-mixture reduction (symmon.filters.mixture_merge). */

static double sm_logdet(const double *A, long long n, double *L) {
  /* log det of the symmetric positive definite A (row-major, its lower triangle read) by L D Lᵀ (no square roots):
     log Π d_i, one log per factor of the product kept within the float range; -inf if A is
     not positive definite.  L (n × n) is scratch: its strict lower triangle holds L, its
     upper triangle U_ki = L_ik d_k (one product per term, one reciprocal per pivot: the
     O(M²) pair costs of a merge are mostly this). */
  double prod = 1.0, logs = 0.0;
  for (long long j = 0; j < n; ++j) {
    double d = A[j * n + j];
    for (long long k = 0; k < j; ++k) d -= L[k * n + j] * L[j * n + k];
    if (!(d > 0.0)) return -INFINITY;
    const double r = 1.0 / d;
    for (long long i = j + 1; i < n; ++i) {
      double s = A[i * n + j];
      for (long long k = 0; k < j; ++k) s -= L[k * n + i] * L[j * n + k];
      L[j * n + i] = s;
      L[i * n + j] = s * r;
    }
    prod *= d;
    if (prod > 1e150 || prod < 1e-150) { logs += log(prod); prod = 1.0; }
  }
  return logs + log(prod);
}

static double sm_cost(long long i, long long j, long long n, int salmond, const double *w, const double *m,
                      const double *P, const double *ld, const double *Pinv, double *A, double *L) {
  const double wi = w[i], wj = w[j], ws = wi + wj;
  const double *mi = m + i * n, *mj = m + j * n;
  if (salmond) {
    double q = 0.0;
    for (long long a = 0; a < n; ++a)
      for (long long b = 0; b < n; ++b) q += (mi[a] - mj[a]) * Pinv[a * n + b] * (mi[b] - mj[b]);
    return wi * wj / ws * q;
  }
  const double *Pi = P + i * n * n, *Pj = P + j * n * n;
  const double fi = wi / ws, fj = wj / ws, c = fi * fj;
  for (long long a = 0; a < n; ++a)  /* the lower triangle: all that sm_logdet reads */
    for (long long b = 0; b <= a; ++b)
      A[a * n + b] = fi * Pi[a * n + b] + fj * Pj[a * n + b] + c * (mi[a] - mj[a]) * (mi[b] - mj[b]);
  return 0.5 * (ws * sm_logdet(A, n, L) - (wi * ld[i] + wj * ld[j]));
}

/* An upper bound on the largest eigenvalue of the symmetric P: the least of its trace and its
   largest absolute row sum (Gershgorin); NAN when P is not positive definite (ld not finite). */
static double sm_top(const double *P, long long n, double ld) {
  double tr = 0.0, row = 0.0;
  if (!isfinite(ld)) return NAN;
  for (long long a = 0; a < n; ++a) {
    double s = 0.0;
    tr += P[a * n + a];
    for (long long b = 0; b < n; ++b) s += fabs(P[a * n + b]);
    if (s > row) row = s;
  }
  return tr < row ? tr : row;
}

/* The key of the pair (i, j) in the cost matrix, and ex[i M + j] whether it is the cost.  For
   Runnalls a lower bound that needs no log-determinant stands in for the cost until the pair
   could be the least (Runnalls' B = ws/2 [log det(S + c d d^T) - (fi ld_i + fj ld_j)] with
   S = fi P_i + fj P_j, c = fi fj: log det S >= fi ld_i + fj ld_j by the concavity of log det,
   and log(1 + c d^T S^-1 d) >= x / (1 + x) with x = c |d|^2 / (fi g_i + fj g_j) <= c d^T S^-1 d,
   g >= the largest eigenvalue); the merges are the same as with every cost computed. */
static double sm_key(long long i, long long j, long long n, long long M, int salmond, const double *w,
                     const double *m, const double *P, const double *ld, const double *g, const double *Pinv,
                     double *A, double *L, unsigned char *ex) {
  if (!salmond) {
    /* ws/2 x/(1 + x) = ws/2 N/(D + N), N = w_i w_j |d|^2, D = ws (w_i g_i + w_j g_j): one division */
    const double ws = w[i] + w[j], q = w[i] * g[i] + w[j] * g[j];
    double dd = 0.0;
    for (long long a = 0; a < n; ++a) { const double t = m[i * n + a] - m[j * n + a]; dd += t * t; }
    const double N = w[i] * w[j] * dd, D = ws * q;
    if (q > 0.0 && isfinite(N) && isfinite(D)) { ex[i * M + j] = 0; return 0.5 * ws * N / (D + N) * (1.0 - 1e-9); }
  }
  ex[i * M + j] = 1;
  return sm_cost(i, j, n, salmond, w, m, P, ld, Pinv, A, L);
}

/* a before b in the argmin order of NumPy: a NaN first (the first one), then the least. */
static int sm_before(double a, double b) { return isnan(b) ? 0 : (isnan(a) || a < b); }

/* The first least live cost of row i (columns j > i), into rmin[i], rarg[i] (-1: none). */
static void sm_row(long long i, long long M, const double *cost, const unsigned char *al, double *rmin, long long *rarg) {
  double best = INFINITY;
  long long arg = -1;
  for (long long j = i + 1; j < M; ++j) {  /* sm_before's order: the first NaN is final */
    if (!al[j]) continue;
    const double c = cost[i * M + j];
    if (c != c) { best = c; arg = j; break; }
    if (arg < 0 || c < best) { best = c; arg = j; }
  }
  rmin[i] = best;
  rarg[i] = arg;
}

/* The row of a and b (a's rows before b's; -1: none) whose minimum comes first in sm_before's
   order, a dead row or one without a live pair never. */
static long long sm_win(long long a, long long b, const double *rmin, const long long *rarg, const unsigned char *al) {
  const int va = a >= 0 && al[a] && rarg[a] >= 0, vb = b >= 0 && al[b] && rarg[b] >= 0;
  if (!va) return vb ? b : -1;
  if (!vb) return a;
  return sm_before(rmin[b], rmin[a]) ? b : a;
}

/* Row k's minimum changed: the tournament tree (T leaves, tree[1] the first row of least
   minimum) updated from leaf k up. */
static void sm_tree(long long k, long long T, long long *tree, const double *rmin, const long long *rarg,
                    const unsigned char *al) {
  for (long long p = (T + k) / 2; p >= 1; p /= 2) tree[p] = sm_win(tree[2 * p], tree[2 * p + 1], rmin, rarg, al);
}

/* Reduce each run r (components start[r] .. start[r + 1] - 1 of w (N), m (N, n), P (N, n, n),
   in place) to at most keep components; alive[k] = 0 for a component merged away.  Pinv:
   (R, n, n), Salmond's metric per run.  The least cost of each row of the pair-cost matrix is
   kept, and the rows in a tournament tree of their minima, so finding the pair to merge is a
   look at its root, and a merge rescans only the rows whose minimum it touched.  Returns 0,
   or -1 if memory ran out. */
int sm_gsf_merge(long long R, const long long *start, long long n, long long keep, int salmond,
                 double *w, double *m, double *P, const double *Pinv, unsigned char *alive) {
  for (long long k = 0; k < start[R]; ++k) alive[k] = 1;
  long long Mmax = 0;
  for (long long r = 0; r < R; ++r)
    if (start[r + 1] - start[r] > Mmax) Mmax = start[r + 1] - start[r];
  if (Mmax <= keep) return 0;
  double *cost = malloc(sizeof(double) * (size_t)(Mmax * Mmax + 3 * Mmax + 2 * n * n));
  long long *rarg = malloc(sizeof(long long) * (size_t)Mmax);
  unsigned char *ex = malloc((size_t)(Mmax * Mmax));
  long long T = 1;
  while (T < Mmax) T *= 2;
  long long *tree = malloc(sizeof(long long) * (size_t)(2 * T));
  if (!cost || !rarg || !ex || !tree) { free(cost); free(rarg); free(ex); free(tree); return -1; }
  double *ld = cost + Mmax * Mmax, *rmin = ld + Mmax, *g = rmin + Mmax, *A = g + Mmax, *L = A + n * n;
  for (long long r = 0; r < R; ++r) {
    const long long o = start[r], M = start[r + 1] - start[r];
    if (M <= keep) continue;
    double *wr = w + o, *mr = m + o * n, *Pr = P + o * n * n;
    unsigned char *al = alive + o;
    const double *Pv = Pinv + r * n * n;
    for (long long i = 0; i < M; ++i) {
      ld[i] = salmond ? 0.0 : sm_logdet(Pr + i * n * n, n, L);
      g[i] = salmond ? 0.0 : sm_top(Pr + i * n * n, n, ld[i]);
    }
    for (long long i = 0; i < M; ++i) {
      for (long long j = i + 1; j < M; ++j) cost[i * M + j] = sm_key(i, j, n, M, salmond, wr, mr, Pr, ld, g, Pv, A, L, ex);
      sm_row(i, M, cost, al, rmin, rarg);
    }
    for (long long k = 0; k < T; ++k) tree[T + k] = k < M ? k : -1;
    for (long long p = T - 1; p >= 1; --p) tree[p] = sm_win(tree[2 * p], tree[2 * p + 1], rmin, rarg, al);
    for (long long left = M; left > keep; --left) {
      long long bi = -1, bj = -1;
      for (;;) {  /* the least key (the first row of least minimum); while it is a bound, the cost in its place */
        bi = tree[1];
        if (bi >= 0 && rmin[bi] == INFINITY) bi = -1;
        if (bi < 0 || ex[bi * M + rarg[bi]]) break;
        cost[bi * M + rarg[bi]] = sm_cost(bi, rarg[bi], n, salmond, wr, mr, Pr, ld, Pv, A, L);
        ex[bi * M + rarg[bi]] = 1;
        sm_row(bi, M, cost, al, rmin, rarg);
        sm_tree(bi, T, tree, rmin, rarg, al);
      }
      if (bi >= 0) {
        bj = rarg[bi];
      } else {  /* every live pair costs inf: the first live pair */
        for (long long k = 0; k < M; ++k)
          if (al[k]) { if (bi < 0) bi = k; else { bj = k; break; } }
      }
      const long long i = bi, j = bj;
      const double ws = wr[i] + wr[j], a = wr[i] / ws, b = wr[j] / ws;
      double *mi = mr + i * n, *mj = mr + j * n, *Pi = Pr + i * n * n, *Pj = Pr + j * n * n;
      for (long long u = 0; u < n; ++u) A[u] = a * mi[u] + b * mj[u];  /* the merged mean */
      for (long long u = 0; u < n; ++u)
        for (long long v = 0; v < n; ++v) {
          const double di = (mi[u] - A[u]) * (mi[v] - A[v]), dj = (mj[u] - A[u]) * (mj[v] - A[v]);
          L[u * n + v] = a * Pi[u * n + v] + b * Pj[u * n + v] + a * di + b * dj;
        }
      for (long long u = 0; u < n; ++u) {
        mi[u] = A[u];
        for (long long v = 0; v < n; ++v) Pi[u * n + v] = 0.5 * (L[u * n + v] + L[v * n + u]);
      }
      wr[i] = ws;
      al[j] = 0;
      if (!salmond) { ld[i] = sm_logdet(Pi, n, L); g[i] = sm_top(Pi, n, ld[i]); }
      for (long long k = 0; k < M; ++k) {
        if (!al[k] || k == i) continue;
        cost[k < i ? k * M + i : i * M + k] = sm_key(k < i ? k : i, k < i ? i : k, n, M, salmond, wr, mr, Pr, ld, g, Pv,
                                                     A, L, ex);
      }
      sm_row(i, M, cost, al, rmin, rarg);
      sm_tree(i, T, tree, rmin, rarg, al);
      sm_tree(j, T, tree, rmin, rarg, al);
      for (long long k = 0; k < i; ++k) {  /* rows above i: their cost with i changed */
        if (!al[k]) continue;
        if (rarg[k] == i || rarg[k] == j) sm_row(k, M, cost, al, rmin, rarg);
        else if (sm_before(cost[k * M + i], rmin[k]) || (!sm_before(rmin[k], cost[k * M + i]) && i < rarg[k]))
          { rmin[k] = cost[k * M + i]; rarg[k] = i; }
        else continue;
        sm_tree(k, T, tree, rmin, rarg, al);
      }
      for (long long k = i + 1; k < j; ++k)  /* rows between: only j went away */
        if (al[k] && rarg[k] == j) { sm_row(k, M, cost, al, rmin, rarg); sm_tree(k, T, tree, rmin, rarg, al); }
    }
  }
  free(cost);
  free(rarg);
  free(ex);
  free(tree);
  return 0;
}
"""

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
            _kernel = NativeLibrary(_C, "sm_gsf_merge", _load, stacklevel=3)
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
        ws = w[i] + w[j]
        a, b = w[i] / ws, w[j] / ws
        mm = a * m[i] + b * m[j]
        di, dj = m[i] - mm, m[j] - mm
        PP = a * P[i] + b * P[j] + a * np.outer(di, di) + b * np.outer(dj, dj)
        w[i], m[i], P[i] = ws, mm, 0.5 * (PP + PP.T)
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
    if fn(R, ptr(start), n, keep, int(rule == "salmond"), ptr(w), ptr(m), ptr(P), ptr(Pinv), ptr(alive)):
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
