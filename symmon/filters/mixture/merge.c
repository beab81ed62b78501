#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <limits.h>

#ifdef SM_MERGE_N  /* the dimension a constant (the Gaussian-sum filter's kernel): its small loops
                      unroll, with the same operations in the same order; the argument n unused */
#define SM_MERGE_LINKAGE static
#define SM_MERGE_NARG n_dim_
#define n ((long long) SM_MERGE_N)
#else
#define SM_MERGE_LINKAGE
#define SM_MERGE_NARG n
#endif

/* symmon: greedy Gaussian-mixture reduction (symmon.filters.mixture.merge). */

static double sm_logdet(const double *A, long long SM_MERGE_NARG, double *L) {
  /* log det of the symmetric positive definite A (row-major, its lower triangle read) by L D Lᵀ (no square roots):
     log Π d_i, one log per factor of the product kept within the float range; -inf if A is
     not positive definite.  L (n × n) is scratch: its strict lower triangle holds L, its
     upper triangle U_ki = L_ik d_k (one product per term, one reciprocal per pivot), its
     diagonal 1/d (for sm_add_inverse). */
  double prod = 1.0, logs = 0.0;
  for (long long j = 0; j < n; ++j) {
    double d = A[j * n + j];
    for (long long k = 0; k < j; ++k) d -= L[k * n + j] * L[j * n + k];
    if (!(d > 0.0)) return -INFINITY;
    const double r = 1.0 / d;
    L[j * n + j] = r;
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

static double sm_cost(long long i, long long j, long long SM_MERGE_NARG, int salmond, const double *w, const double *m,
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
  double d[n];
  for (long long a = 0; a < n; ++a) d[a] = mi[a] - mj[a];
  for (long long a = 0; a < n; ++a)  /* the lower triangle: all that sm_logdet reads */
    for (long long b = 0; b <= a; ++b) A[a * n + b] = fi * Pi[a * n + b] + fj * Pj[a * n + b] + c * d[a] * d[b];
  return 0.5 * (ws * sm_logdet(A, n, L) - (wi * ld[i] + wj * ld[j]));
}

/* Replace component i of (w, m, P) by the moment-matched merge of i and j.  A, L: n x n scratch. */
static void sm_merge_pair(long long i, long long j, long long SM_MERGE_NARG, double *w, double *m, double *P, double *A, double *L) {
  const double ws = w[i] + w[j], a = w[i] / ws, b = w[j] / ws;
  double *mi = m + i * n, *mj = m + j * n, *Pi = P + i * n * n, *Pj = P + j * n * n;
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
  w[i] = ws;
}

/* The lower Cholesky factor G of the symmetric A (lower triangles; G may be A: in place).
   Returns 0 at a pivot that is not positive and finite (A not positive definite). */
static int sm_cholesky(const double *A, long long SM_MERGE_NARG, double *G) {
  for (long long j = 0; j < n; ++j) {
    double d = A[j * n + j];
    for (long long k = 0; k < j; ++k) d -= G[j * n + k] * G[j * n + k];
    if (!(d > 0.0) || !isfinite(d)) return 0;
    d = sqrt(d);
    G[j * n + j] = d;
    for (long long i = j + 1; i < n; ++i) {
      double s = A[i * n + j];
      for (long long k = 0; k < j; ++k) s -= G[i * n + k] * G[j * n + k];
      G[i * n + j] = s / d;
    }
  }
  return 1;
}

/* The inverse X (full) of the symmetric positive definite A (its lower triangle read), by
   Cholesky: A = G G^T, X = G^-T G^-1.  Returns 0 if A is not positive definite.  G: n x n scratch. */
static int sm_spd_inverse(const double *A, long long SM_MERGE_NARG, double *X, double *G) {
  if (!sm_cholesky(A, n, G)) return 0;
  for (long long b = 0; b < n; ++b)  /* X's column b: G^-1 e_b by forward substitution, in X's row b */
    for (long long a = 0; a < n; ++a) {
      double s = a == b ? 1.0 : 0.0;
      for (long long k = b; k < a; ++k) s -= G[a * n + k] * X[b * n + k];
      X[b * n + a] = a < b ? 0.0 : s / G[a * n + a];
    }
  for (long long a = 0; a < n; ++a)  /* X = (G^-1)^T G^-1 from the rows of G^-T kept in X: lower triangle into G */
    for (long long b = 0; b <= a; ++b) {
      double s = 0.0;
      for (long long k = a; k < n; ++k) s += X[a * n + k] * X[b * n + k];
      G[a * n + b] = s;
    }
  for (long long a = 0; a < n; ++a)
    for (long long b = 0; b <= a; ++b) X[a * n + b] = X[b * n + a] = G[a * n + b];
  return 1;
}

/* C += w P^-1 (its lower triangle), from sm_logdet's factors of P in L: P^-1 = Y^T D^-1 Y with
   Y = L^-1 (L unit lower triangular, its strict lower triangle; D^-1 on its diagonal), so that
   the harmonic mean of sm_whiten costs no factorisation of its own.  Y: n x n scratch. */
static void sm_add_inverse(const double *L, long long SM_MERGE_NARG, double w, double *C, double *Y) {
  for (long long a = 0; a < n; ++a) {  /* Y by forward substitution: L Y = I */
    Y[a * n + a] = 1.0;
    for (long long b = 0; b < a; ++b) {
      double t = -L[a * n + b];
      for (long long k = b + 1; k < a; ++k) t -= L[a * n + k] * Y[k * n + b];
      Y[a * n + b] = t;
    }
  }
  for (long long a = 0; a < n; ++a)
    for (long long b = 0; b <= a; ++b) {
      double t = 0.0;
      for (long long k = a; k < n; ++k) t += Y[k * n + a] * L[k * n + k] * Y[k * n + b];
      C[a * n + b] += w * t;
    }
}

/* The whitening W (n x n, lower triangular) of the bound's metric: W = L^-1 S, with T the
   weighted harmonic mean of the covariances of the components whose bound holds, T^-1 = C/sw,
   C = sum_k w_k P_k^-1 (its lower triangle, sm_add_inverse) and sw = sum_k w_k (a few wide
   components do not inflate it, so that the others' W P W^T stay near the identity), S =
   diag(T)^-1/2 and S T S = L L^T.  The diagonal S alone when S T S is ill-conditioned (n
   |L^-1|_F^2, an upper bound on its condition number, above 1e4: the rounding of W d and W P W^T
   then stays far below the bound's margin), the identity when T is not positive definite.  C
   is overwritten; Li, X, G: n x n scratch. */
static void sm_whiten(long long SM_MERGE_NARG, double sw, double *W, double *C, double *Li, double *X, double *G) {
  double fro = 0.0;
  for (long long a = 0; a < n * n; ++a) W[a] = 0.0;
  for (long long a = 0; a < n; ++a) W[a * n + a] = 1.0;
  if (!(sw > 0.0) || !isfinite(sw)) return;
  for (long long a = 0; a < n * n; ++a) C[a] /= sw;
  if (!sm_spd_inverse(C, n, X, G)) return;  /* X = T */
  for (long long a = 0; a < n; ++a) Li[a] = 1.0 / sqrt(X[a * n + a]);  /* S, kept in Li's first row */
  for (long long a = 0; a < n; ++a) if (!(Li[a] > 0.0) || !isfinite(Li[a])) return;
  for (long long a = 0; a < n; ++a) W[a * n + a] = Li[a];
  for (long long a = 0; a < n; ++a)  /* S T S, lower triangle, unit diagonal */
    for (long long b = 0; b <= a; ++b) C[a * n + b] = Li[a] * X[a * n + b] * Li[b];
  if (!sm_cholesky(C, n, C)) return;  /* in place: C's lower triangle becomes L */
  for (long long a = 0; a < n; ++a)  /* Li = L^-1 (lower triangular), by columns */
    for (long long b = 0; b < n; ++b) {
      double s = a == b ? 1.0 : 0.0;
      if (b > a) { Li[a * n + b] = 0.0; continue; }
      for (long long k = b; k < a; ++k) s -= C[a * n + k] * Li[k * n + b];
      Li[a * n + b] = s / C[a * n + a];
      fro += Li[a * n + b] * Li[a * n + b];
    }
  if (!(n * fro <= 1e4)) return;  /* W = S */
  for (long long a = 0; a < n; ++a)
    for (long long b = 0; b <= a; ++b) Li[a * n + b] *= W[b * n + b];
  for (long long a = 0; a < n; ++a)
    for (long long b = 0; b < n; ++b) W[a * n + b] = b <= a ? Li[a * n + b] : 0.0;
}

/* An upper bound on the largest eigenvalue of W P W^T (P symmetric, its lower triangle read; W
   lower triangular): the least of its trace and its largest absolute row sum (Gershgorin).
   NAN when the bound does not hold for the component (!ok: P not positive definite, or its
   weight negative or not finite).  T, Q: n x n scratch. */
static double sm_top(const double *P, long long SM_MERGE_NARG, int ok, const double *W, double *T, double *Q) {
  double tr = 0.0, row = 0.0;
  if (!ok) return NAN;
  for (long long a = 0; a < n; ++a)  /* Q = P, symmetric from its lower triangle */
    for (long long b = 0; b <= a; ++b) Q[a * n + b] = Q[b * n + a] = P[a * n + b];
  for (long long a = 0; a < n; ++a)  /* T = W P */
    for (long long b = 0; b < n; ++b) {
      double s = 0.0;
      for (long long c = 0; c <= a; ++c) s += W[a * n + c] * Q[c * n + b];
      T[a * n + b] = s;
    }
  for (long long a = 0; a < n; ++a)  /* Q = T W^T, its lower triangle, then mirrored */
    for (long long b = 0; b <= a; ++b) {
      double s = 0.0;
      for (long long c = 0; c <= b; ++c) s += T[a * n + c] * W[b * n + c];
      Q[a * n + b] = Q[b * n + a] = s;
    }
  for (long long a = 0; a < n; ++a) {
    double s = 0.0;
    tr += Q[a * n + a];
    for (long long b = 0; b < n; ++b) s += fabs(Q[a * n + b]);
    if (s > row) row = s;
  }
  return tr < row ? tr : row;
}

/* Component k's whitened mean u[a M + k] = (W (m_k - c))_a, c a common centre, and du[k] >= the
   Euclidean norm of its rounding error ((n + 2) eps |W| |m_k - c|, summed), so that
   |u_i - u_j| - du_i - du_j <= |W (m_i - m_j)| (the keys' lower bound on it). */
static void sm_wmean(long long k, long long SM_MERGE_NARG, long long M, const double *m, const double *c, const double *W,
                     double *u, double *du) {
  double err = 0.0;
  for (long long a = 0; a < n; ++a) {
    double s = 0.0, t = 0.0;
    for (long long b = 0; b <= a; ++b) {
      const double v = m[k * n + b] - c[b];
      s += W[a * n + b] * v;
      t += fabs(W[a * n + b]) * fabs(v);
    }
    u[a * M + k] = s;
    err += t;
  }
  du[k] = (double) (n + 2) * 2.3e-16 * err;
}

/* Whether component k's keys are finite: its bound holds (g finite) and its weight, whitened mean,
   g and s are below 1e50, so that no product in a key overflows. */
static int sm_sane(long long k, long long SM_MERGE_NARG, long long M, const double *w, const double *g, const double *u,
                   const double *du, const double *s) {
  int ok = fabs(w[k]) < 1e50 && fabs(g[k]) < 1e50 && fabs(du[k]) < 1e50 && fabs(s[k]) < 1e50;
  for (long long a = 0; a < n; ++a) ok &= fabs(u[a * M + k]) < 1e50;
  return ok;
}

/* The bound keys of the pairs (i, j), j0 <= j < j1, into out[j - j0] (NaN where the bound does
   not hold: module notes).  u, du: sm_wmean's; ald = |log det P|; s = (det P / det P_ref)^(1/2n)
   (Minkowski's term).  One loop over j, its inner loop over the state's dimension: with n a
   constant it unrolls and the compiler vectorises the loop over j. */
static void sm_keys(long long i, long long j0, long long j1, long long SM_MERGE_NARG, long long M, const double *restrict u,
                    const double *restrict du, const double *restrict w, const double *restrict g,
                    const double *restrict ald, const double *restrict s, double *restrict out) {
  const double wi = w[i], gi = g[i], ai = ald[i], di = du[i], si = s[i];
  for (long long j = j0; j < j1; ++j) {
    double dd = 0.0;  /* |u_i - u_j|^2, then a lower bound on |W (m_i - m_j)|^2: with e = du_i + du_j,
                         (|x| - e)^2 >= (1 - 1e-9) |x|^2 - 1e9 e^2 */
#pragma GCC unroll 16
    for (long long a = 0; a < n; ++a) {
      const double x = u[a * M + i] - u[a * M + j];
      dd += x * x;
    }
    const double err = di + du[j];
    dd = dd * (1.0 - 1e-9) - 1e9 * (err * err);
    dd = dd < 0.0 ? 0.0 : dd;
    /* ws N / (2 D + N), N = w_i w_j dd, D = ws (w_i g_i + w_j g_j): the log(1 + x) term;
       ws n E / F, E = w_i w_j (s_i - s_j)^2, F = 2 (w_i s_i + w_j s_j)^2 + E: Minkowski's term */
    const double wj = w[j], ws = wi + wj, N = wi * wj * dd, D = ws * (wi * gi + wj * g[j]);
    const double ds = si - s[j], h = wi * si + wj * s[j], E = wi * wj * (ds * ds), F = 2.0 * (h * h) + E;
    out[j - j0] = ws * (N / (2.0 * D + N) + (double) n * (E / F)) * (1.0 - 1e-9)
                  - 1e-9 * ws * ((double) n + (ai + ald[j]));
  }
}

/* a before b in the argmin order of NumPy: a NaN first, then the least. */
static int sm_before(double a, double b) { return isnan(b) ? 0 : (isnan(a) || a < b); }

typedef double sm_v4d __attribute__((vector_size(32)));
typedef long long sm_v4l __attribute__((vector_size(32)));

/* The first least valid key of row i into rmin[i], rarg[i]: the first NaN if there is one (when
   nanm: the row may hold one); rarg[i] = -1 when none is below +inf.  The key of column j is
   valid when sig[j] < sig[i] (sm_gsf_merge); columns before from are never valid.  Four lanes
   of running minima and their first columns, then the least of the lanes (the first column on
   a tie). */
static void sm_row(long long i, long long from, long long M, const double *cost, const double *sig, double *rmin,
                   long long *rarg, int nanm) {
  const double *c = cost + i * M, si = sig[i];
  double best = INFINITY;
  long long arg = -1, j = from;
  int nan = 0;
  if (M - j >= 8) {
    const sm_v4d inf = {INFINITY, INFINITY, INFINITY, INFINITY}, s4 = {si, si, si, si};
    /* two sets of lanes (columns j..j+3 and j+4..j+7 of every 8), so that the compare-and-select
       chain of one set overlaps the other's */
    sm_v4d vb = inf, vb2 = inf;
    sm_v4l vi = {-1, -1, -1, -1}, vi2 = vi, idx = {j, j + 1, j + 2, j + 3}, vn = {0, 0, 0, 0};
    const sm_v4l four = {4, 4, 4, 4}, eight = {8, 8, 8, 8};
    for (; M - from >= 64 && j + 8 <= M; j += 8) {  /* a short row: one set (its second would not repay its lanes) */
      sm_v4d x, s, x2, s2;
      memcpy(&x, c + j, sizeof x);
      memcpy(&s, sig + j, sizeof s);
      memcpy(&x2, c + j + 4, sizeof x2);
      memcpy(&s2, sig + j + 4, sizeof s2);
      const sm_v4l ok = (sm_v4l) (s < s4), lt = (sm_v4l) (x < vb) & ok;
      const sm_v4l ok2 = (sm_v4l) (s2 < s4), lt2 = (sm_v4l) (x2 < vb2) & ok2;
      if (nanm) vn |= ((sm_v4l) (x != x) & ok) | ((sm_v4l) (x2 != x2) & ok2);
      vb = (sm_v4d) ((lt & (sm_v4l) x) | (~lt & (sm_v4l) vb));
      vi = (lt & idx) | (~lt & vi);
      vb2 = (sm_v4d) ((lt2 & (sm_v4l) x2) | (~lt2 & (sm_v4l) vb2));
      vi2 = (lt2 & (idx + four)) | (~lt2 & vi2);
      idx += eight;
    }
    for (; j + 4 <= M; j += 4) {
      sm_v4d x, s;
      memcpy(&x, c + j, sizeof x);
      memcpy(&s, sig + j, sizeof s);
      const sm_v4l ok = (sm_v4l) (s < s4), lt = (sm_v4l) (x < vb) & ok;
      if (nanm) vn |= (sm_v4l) (x != x) & ok;
      vb = (sm_v4d) ((lt & (sm_v4l) x) | (~lt & (sm_v4l) vb));
      vi = (lt & idx) | (~lt & vi);
      idx += four;
    }
    for (int l = 0; l < 4; ++l) {
      nan |= vn[l] != 0;
      if (vi[l] >= 0 && (vb[l] < best || (vb[l] == best && vi[l] < arg))) { best = vb[l]; arg = vi[l]; }
      if (vi2[l] >= 0 && (vb2[l] < best || (vb2[l] == best && vi2[l] < arg))) { best = vb2[l]; arg = vi2[l]; }
    }
  }
  for (; j < M; ++j) {
    const double x = c[j];
    if (!(sig[j] < si)) continue;
    if (x != x) nan = 1;
    else if (x < best) { best = x; arg = j; }
  }
  if (nan)
    for (j = from; j < M; ++j)
      if (sig[j] < si && c[j] != c[j]) { best = c[j]; arg = j; break; }
  rmin[i] = best;
  rarg[i] = arg;
}

/* The tournament tree over the rows, T leaves (leaf T + k: row k) and at node p the least of the
   leaves below it: its key nk[p], its pair's rank nr[p] (i M + j, i < j) and its row nw[p], in
   the order of the key (sm_before's: a NaN first, as -inf with its rank less 2^62), then of the
   pair; a dead row, or one without a candidate, as (+inf, LLONG_MAX).  A key is kept as the
   integer that orders as the double does (sm_ord), so that the tree compares only integers. */
static long long sm_ord(double x) {
  long long b;
  x += 0.0;  /* -0 as +0: they compare equal as doubles */
  memcpy(&b, &x, sizeof b);
  return b < 0 ? b ^ LLONG_MAX : b;  /* a negative double's magnitude bits reversed */
}

static void sm_leaf(long long k, long long T, long long M, const double *rmin, const long long *rarg,
                    const unsigned char *al, long long *nk, long long *nr, long long *nw) {
  const long long p = T + k, a = k < M ? rarg[k] : -1;
  nw[p] = k;
  if (a < 0 || !al[k]) { nk[p] = sm_ord(INFINITY); nr[p] = LLONG_MAX; return; }
  const long long rank = k < a ? k * M + a : a * M + k;
  if (rmin[k] != rmin[k]) { nk[p] = sm_ord(-INFINITY); nr[p] = rank - ((long long) 1 << 62); }
  else { nk[p] = sm_ord(rmin[k]); nr[p] = rank; }
}

/* Node p from its children (the left one on a tie). */
static void sm_node(long long p, long long *nk, long long *nr, long long *nw) {
  const long long l = 2 * p, r = l + 1;
  const long long b = l + ((nk[r] < nk[l]) | ((nk[r] == nk[l]) & (nr[r] < nr[l])));
  nk[p] = nk[b];
  nr[p] = nr[b];
  nw[p] = nw[b];
}

/* Row k's minimum changed: its leaf and the nodes above it, up to the root (no test whether a
   node stays: a branch that costs more than the levels it saves).  The climbing winner is
   carried in registers and met only by the sibling at each level (sm_node's order), so that a
   level's loads do not wait for the level below; the selection by masks (a branch there is
   mispredicted half the time). */
static void sm_tree(long long k, long long T, long long M, const double *rmin, const long long *rarg,
                    const unsigned char *al, long long *nk, long long *nr, long long *nw) {
  sm_leaf(k, T, M, rmin, rarg, al, nk, nr, nw);
  long long p = T + k, key = nk[p], rank = nr[p], who = k;
  for (; p > 1; p >>= 1) {
    const long long s = p ^ 1, q = p >> 1, ks = nk[s], rs = nr[s];
    /* the sibling wins when before the climber (a pair lives in one row, so ranks differ but for
       rows without a candidate, whose order does not matter) */
    const long long win = -(long long) ((ks < key) | ((ks == key) & (rs < rank)));
    key = (ks & win) | (key & ~win);
    rank = (rs & win) | (rank & ~win);
    who = (nw[s] & win) | (who & ~win);
    nk[q] = key;
    nr[q] = rank;
    nw[q] = who;
  }
}

/* The reference the search must equal: every live pair's cost computed at every merge, the
   first least (sm_before's order, pairs (i, j), i < j, in the order of i, then j) merged.
   O(M^3): for tests. */
static void sm_exhaustive(long long M, long long SM_MERGE_NARG, long long keep, int salmond, double *w, double *m, double *P,
                          const double *Pinv, unsigned char *al, double *ld, double *A, double *L) {
  for (long long i = 0; i < M; ++i) ld[i] = salmond ? 0.0 : sm_logdet(P + i * n * n, n, L);
  for (long long left = M; left > keep; --left) {
    long long bi = -1, bj = -1;
    double best = INFINITY;
    for (long long i = 0; i < M; ++i)
      for (long long j = i + 1; j < M && al[i]; ++j) {
        if (!al[j]) continue;
        const double c = sm_cost(i, j, n, salmond, w, m, P, ld, Pinv, A, L);
        if (bi < 0 || sm_before(c, best)) { best = c; bi = i; bj = j; }
      }
    sm_merge_pair(bi, bj, n, w, m, P, A, L);
    al[bj] = 0;
    if (!salmond) ld[bi] = sm_logdet(P + bi * n * n, n, L);
  }
}

/* Reduce each run r (components start[r] .. start[r + 1] - 1 of w (N), m (N, n), P (N, n, n),
   in place) to at most keep components; alive[k] = 0 for a component merged away.  flags: 1
   Salmond (else Runnalls), 2 the exhaustive reference (sm_exhaustive).  Pinv: (R, n, n),
   Salmond's metric per run.

   The key of a pair is its cost or (Runnalls) a lower bound on it, and each pair's key sits in
   one row of the M x M matrix cost: in row i of component i, whose row was computed last.  A
   component's stamp sig (M - i at first, then a count from M + 1 when a merge changes it, +inf
   when it is merged away) says when: the key in row i, column j is valid when sig[j] <
   sig[i].  At first row i holds the pairs (i, j), j > i; a merge into i recomputes row i for
   every j, one contiguous row, and rescans the rows whose least pair had i or j, nothing else.
   Each row's first least valid key is kept, and the rows in a tournament tree ordered by key,
   then by pair, so the first least pair is at its root; while its key is a bound, its cost
   replaces it.  Returns 0, or -1 if memory ran out. */
SM_MERGE_LINKAGE int sm_gsf_merge(long long R, const long long *start, long long SM_MERGE_NARG, long long keep, int flags,
                 double *w, double *m, double *P, const double *Pinv, unsigned char *alive) {
  const int salmond = flags & 1, exhaustive = flags & 2;
  for (long long k = 0; k < start[R]; ++k) alive[k] = 1;
  long long Mmax = 0;
  for (long long r = 0; r < R; ++r)
    if (start[r + 1] - start[r] > Mmax) Mmax = start[r + 1] - start[r];
  if (Mmax <= keep) return 0;
  double *cost = malloc(sizeof(double) * (size_t)(Mmax * Mmax + (10 + n) * Mmax + 5 * n * n + n));
  long long *rarg = malloc(sizeof(long long) * (size_t)Mmax);
  unsigned char *ex = malloc((size_t)(Mmax * Mmax + Mmax)), *stale = ex + Mmax * Mmax;
  long long T = 1;
  while (T < Mmax) T *= 2;
  long long *tree = malloc(sizeof(long long) * (size_t)(6 * T)), *nr = tree, *nw = tree + 2 * T;
  long long *nk = tree + 4 * T;
  if (!cost || !rarg || !ex || !tree) { free(cost); free(rarg); free(ex); free(tree); return -1; }
  double *ld = cost + Mmax * Mmax, *rmin = ld + Mmax, *g = rmin + Mmax, *ald = g + Mmax, *ok = ald + Mmax,
         *sig = ok + Mmax, *from = sig + Mmax, *du = from + Mmax, *sd = du + Mmax, *mt = sd + Mmax,
         *A = mt + n * Mmax, *L = A + n * n, *W = L + n * n,
         *C = W + n * n, *Li = C + n * n, *cen = Li + n * n;
  for (long long r = 0; r < R; ++r) {
    const long long o = start[r], M = start[r + 1] - start[r];
    if (M <= keep) continue;
    double *wr = w + o, *mr = m + o * n, *Pr = P + o * n * n, stamp = (double) M;
    unsigned char *al = alive + o;
    const double *Pv = Pinv + r * n * n;
    if (exhaustive) { sm_exhaustive(M, n, keep, salmond, wr, mr, Pr, Pv, al, ld, A, L); continue; }
    /* nanm: a key or cost may be NaN (Salmond's costs, a component whose bound does not hold or
       whose numbers could overflow a key, a NaN cost), so that the rows' scans look for one */
    int nanm = salmond;
    double ldc = 0.0, swh = 0.0;
    for (long long a = 0; a < n * n; ++a) C[a] = 0.0;
    for (long long i = 0; i < M; ++i) {
      ld[i] = salmond ? 0.0 : sm_logdet(Pr + i * n * n, n, L);
      ok[i] = isfinite(ld[i]) && wr[i] >= 0.0 && isfinite(wr[i]);
      if (!salmond && ok[i]) { sm_add_inverse(L, n, wr[i], C, Li); swh += wr[i]; }
      ald[i] = fabs(ld[i]);
      sig[i] = (double) (M - i);
      from[i] = (double) (i + 1);
      stale[i] = 0;
    }
    if (!salmond) {
      double sw = 0.0;  /* the centre of the whitened means: the weighted mean of the ok means */
      for (long long a = 0; a < n; ++a) cen[a] = 0.0;
      for (long long i = 0; i < M; ++i) {
        int fin = ok[i] != 0.0;
        for (long long a = 0; a < n; ++a) fin &= isfinite(mr[i * n + a]);
        if (!fin) continue;
        sw += wr[i];
        for (long long a = 0; a < n; ++a) cen[a] += wr[i] * mr[i * n + a];
      }
      for (long long a = 0; a < n; ++a) cen[a] = sw > 0.0 && isfinite(cen[a] / sw) ? cen[a] / sw : 0.0;
      sm_whiten(n, swh, W, C, Li, A, L);
      double nok = 0.0;  /* the reference of Minkowski's s: the mean log det of the ok components */
      ldc = 0.0;
      for (long long i = 0; i < M; ++i)
        if (ok[i]) { ldc += ld[i]; nok += 1.0; }
      ldc = nok > 0.0 ? ldc / nok : 0.0;
      for (long long i = 0; i < M; ++i) {
        sd[i] = exp((ld[i] - ldc) / (double) (2 * n));
        g[i] = sm_top(Pr + i * n * n, n, ok[i] != 0.0, W, C, Li);
        sm_wmean(i, n, M, mr, cen, W, mt, du);
        nanm |= !sm_sane(i, n, M, wr, g, mt, du, sd);
      }
    }
    for (long long i = 0; i < M; ++i) {
      if (salmond) {
        for (long long j = i + 1; j < M; ++j) cost[i * M + j] = sm_cost(i, j, n, 1, wr, mr, Pr, ld, Pv, A, L);
        memset(ex + i * M, 1, (size_t) M);
      } else {
        sm_keys(i, i + 1, M, n, M, mt, du, wr, g, ald, sd, cost + i * M + i + 1);
        memset(ex + i * M, 0, (size_t) M);
      }
      sm_row(i, i + 1, M, cost, sig, rmin, rarg, nanm);
    }
    for (long long k = 0; k < T; ++k) sm_leaf(k, T, M, rmin, rarg, al, nk, nr, nw);
    for (long long p = T - 1; p >= 1; --p) sm_node(p, nk, nr, nw);
    for (long long left = M; left > keep; --left) {
      long long bi = -1, i = -1, j = -1;
      for (;;) {  /* the first least pair; while its key is a bound, its cost in its place */
        bi = nr[1] == LLONG_MAX ? -1 : nw[1];
        if (bi < 0) break;
        if (stale[bi]) {  /* its least pair went away: a lower bound until now */
          stale[bi] = 0;
          sm_row(bi, (long long) from[bi], M, cost, sig, rmin, rarg, nanm);
          sm_tree(bi, T, M, rmin, rarg, al, nk, nr, nw);
          continue;
        }
        const long long bj = rarg[bi];
        i = bi < bj ? bi : bj;
        j = bi < bj ? bj : bi;
        if (ex[bi * M + bj]) break;
        const double e = cost[bi * M + bj] = sm_cost(i, j, n, salmond, wr, mr, Pr, ld, Pv, A, L);
        ex[bi * M + bj] = 1;
        nanm |= e != e;
        sm_row(bi, (long long) from[bi], M, cost, sig, rmin, rarg, nanm);
        sm_tree(bi, T, M, rmin, rarg, al, nk, nr, nw);
      }
      if (bi < 0) {  /* every live pair costs inf: the first live pair */
        i = j = -1;
        for (long long k = 0; k < M; ++k)
          if (al[k]) { if (i < 0) i = k; else { j = k; break; } }
      }
      sm_merge_pair(i, j, n, wr, mr, Pr, A, L);
      al[j] = 0;
      rarg[j] = -1;
      sig[j] = INFINITY;
      sig[i] = stamp += 1.0;
      from[i] = 0.0;
      if (salmond) {
        for (long long k = 0; k < M; ++k)
          cost[i * M + k] = al[k] && k != i ? sm_cost(k < i ? k : i, k < i ? i : k, n, 1, wr, mr, Pr, ld, Pv, A, L)
                                            : INFINITY;
      } else {
        ld[i] = sm_logdet(Pr + i * n * n, n, L);
        ok[i] = isfinite(ld[i]) && wr[i] >= 0.0 && isfinite(wr[i]);
        ald[i] = fabs(ld[i]);
        sd[i] = exp((ld[i] - ldc) / (double) (2 * n));
        g[i] = sm_top(Pr + i * n * n, n, ok[i] != 0.0, W, C, Li);
        sm_wmean(i, n, M, mr, cen, W, mt, du);
        nanm |= !sm_sane(i, n, M, wr, g, mt, du, sd);
        sm_keys(i, 0, M, n, M, mt, du, wr, g, ald, sd, cost + i * M);
        memset(ex + i * M, 0, (size_t) M);
      }
      sm_row(i, 0, M, cost, sig, rmin, rarg, nanm);
      stale[i] = 0;
      sm_tree(i, T, M, rmin, rarg, al, nk, nr, nw);
      sm_tree(j, T, M, rmin, rarg, al, nk, nr, nw);
      for (long long k = 0; k < M; ++k)  /* the rows whose least pair had i or j (a dead row's rarg is -1) */
        stale[k] |= (rarg[k] == i) | (rarg[k] == j);
    }
  }
  free(cost);
  free(rarg);
  free(ex);
  free(tree);
  return 0;
}
#ifdef SM_MERGE_N
#undef n
#endif
