/* symmon: the Gaussian-sum filter's recursion with splitting (symmon.filters.mixture._kernel). */
#ifndef SMG_N  /* checked alone: example macros (SplitKernel defines them), and what comes before */
#include "../../compile/casadi_alone.h"
#include "merge.c"
#define SMG_PREDICT gsf_predict
#define SMG_UPDATE gsf_update
#define SMG_MON_F gsf_mon_f
#define SMG_MON_H gsf_mon_h
#define SMG_SZ_ARG 6
#define SMG_SZ_RES 3
#define SMG_ROW 40
#define SMG_SC_DIR 400
#define SMG_SC_MORE 200
#define SMG_N 2
#define SMG_STOPPED 2
int SMG_PREDICT(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int SMG_UPDATE(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int SMG_MON_F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int SMG_MON_H(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
#endif
#include <string.h>
#define SMG_TIE 1e-9
#define SMG_PI 3.141592653589793115997963468544

/* wrap_angle: numpy.mod(a + pi, 2 pi) - pi, +pi kept (numpy's floored remainder). */
static double smg_wrap(double a) {
  const double b = 2 * SMG_PI;
  double mod = fmod(a + SMG_PI, b), o;
  if (mod != 0) { if (mod < 0) mod += b; } else mod = 0.0;
  o = mod - SMG_PI;
  return o == -SMG_PI ? SMG_PI : o;
}

/* The eigenvalues (ascending) and eigenvectors (the columns of V, row-major) of the symmetric
   n x n A, whose lower triangle is read: cyclic Jacobi rotations.  a: n x n scratch. */
static void smg_eig(int n, const double* A, double* lam, double* V, double* a) {
  int i, j, k, p, q, sweep;
  for (i = 0; i < n; ++i)
    for (j = 0; j < n; ++j) { a[i * n + j] = i >= j ? A[i * n + j] : A[j * n + i]; V[i * n + j] = i == j; }
  for (sweep = 0; sweep < 60; ++sweep) {
    double off = 0, tot = 0;
    for (i = 0; i < n * n; ++i) tot += a[i] * a[i];
    for (i = 0; i < n; ++i) for (j = 0; j < n; ++j) if (i != j) off += a[i * n + j] * a[i * n + j];
    int turned = 0;
    if (!(off > 1e-34 * tot)) break;
    for (p = 0; p < n - 1; ++p)
      for (q = p + 1; q < n; ++q) {
        const double apq = a[p * n + q];
        double theta, t, c, s;
        /* an entry below the rounding of its diagonal changes nothing (Golub & Van Loan's
           threshold Jacobi): zero it without a rotation */
        if (fabs(apq) <= 1e-18 * (fabs(a[p * n + p]) + fabs(a[q * n + q]))) { a[p * n + q] = a[q * n + p] = 0; continue; }
        turned = 1;
        theta = (a[q * n + q] - a[p * n + p]) / (2 * apq);
        t = 1 / (fabs(theta) + sqrt(theta * theta + 1));
        if (theta < 0) t = -t;
        c = 1 / sqrt(t * t + 1);
        s = t * c;
        for (k = 0; k < n; ++k) {
          const double akp = a[k * n + p], akq = a[k * n + q];
          a[k * n + p] = c * akp - s * akq; a[k * n + q] = s * akp + c * akq;
        }
        for (k = 0; k < n; ++k) {
          const double apk = a[p * n + k], aqk = a[q * n + k];
          a[p * n + k] = c * apk - s * aqk; a[q * n + k] = s * apk + c * aqk;
        }
        a[p * n + q] = a[q * n + p] = 0;
        for (k = 0; k < n; ++k) {
          const double vkp = V[k * n + p], vkq = V[k * n + q];
          V[k * n + p] = c * vkp - s * vkq; V[k * n + q] = s * vkp + c * vkq;
        }
      }
    if (!turned) break;
  }
  for (i = 0; i < n; ++i) lam[i] = a[i * n + i];
  for (i = 0; i < n - 1; ++i) {  /* ascending, stable */
    k = i;
    for (j = i + 1; j < n; ++j) if (lam[j] < lam[k]) k = j;
    if (k == i) continue;
    { double t = lam[i]; lam[i] = lam[k]; lam[k] = t; }
    for (j = 0; j < n; ++j) { double t = V[j * n + i]; V[j * n + i] = V[j * n + k]; V[j * n + k] = t; }
  }
}

/* The first index of the non-negative a[0 .. n) within TIE of the largest (_first_max). */
static int smg_first_max(int n, const double* a) {
  double top = a[0];
  int i;
  for (i = 1; i < n; ++i) if (a[i] > top || a[i] != a[i]) top = a[i];
  for (i = 0; i < n; ++i) if (a[i] >= (1.0 - SMG_TIE) * top) return i;
  return 0;
}

typedef struct {
  int n, ny, np, ms, Mk, cap, salmond, curved[2];
  double split, prune, sigma, back;
  const double *omega, *mu, *Q, *R;
  const int* ang;
  double *w, *x, *P, *w2, *x2, *P2, *mon, *W, *H, *ll, *z, *cg, *D, *sc;
  long long *start;
  unsigned char *alive, *calm;
  double* ld;
  casadi_int* iw;
  casadi_real* wk;
} smg_ctx;

/* The direction d (n) to split N(., P) along for Hessians H (ny, n, n) and weight W (ny, ny):
   split_directions of one component (symmon.filters.mixture.gaussian_sum). */
static void smg_direction(smg_ctx* c, int ny, const double* P, const double* H, const double* W, double* d) {
  const int n = SMG_N;  /* c->n as a constant: the small loops unrolled, the same operations */
  const int nm = n > ny ? n : ny;
  double *lam = c->sc, *V = lam + n, *S = V + n * n, *T = S + n * n, *SHS = T + nm * nm, *G = SHS + ny * n * n,
         *gl = G + ny * n * n, *gv = gl + n, *a = gv + n * n, *wl = a + n * n + ny * ny, *wv = wl + ny,
         *C = wv + ny * ny, *lead = C + ny * ny, *share = lead + ny * n, *vec = share + ny + n;
  int i, j, k, b, best;
  if (ny == 1) {
    /* One output: d = S a does not depend on the square root S of P (S U, U orthogonal, gives
       G' = U^T G U and a' = U^T a), so the Cholesky factor serves (zero columns past a
       non-positive pivot); the axes of S are candidates only for several outputs. */
    for (i = 0; i < n * n; ++i) S[i] = 0;
    for (j = 0; j < n; ++j) {
      double dj = P[j * n + j];
      for (k = 0; k < j; ++k) dj -= S[j * n + k] * S[j * n + k];
      if (!(dj > 0)) continue;
      S[j * n + j] = sqrt(dj);
      for (i = j + 1; i < n; ++i) {
        double s = P[i * n + j];
        for (k = 0; k < j; ++k) s -= S[i * n + k] * S[j * n + k];
        S[i * n + j] = s / S[j * n + j];
      }
    }
  } else {
    smg_eig(n, P, lam, V, a);
    for (i = 0; i < n; ++i)
      for (j = 0; j < n; ++j) S[i * n + j] = V[i * n + j] * sqrt(lam[j] > 0 ? lam[j] : 0.0);
  }
  for (k = 0; k < ny; ++k) {  /* (S^T H_k) S */
    const double* Hk = H + k * n * n;
    for (i = 0; i < n; ++i)
      for (j = 0; j < n; ++j) { double s = 0; for (b = 0; b < n; ++b) s += S[b * n + i] * Hk[b * n + j]; T[i * n + j] = s; }
    for (i = 0; i < n; ++i)
      for (j = 0; j < n; ++j) { double s = 0; for (b = 0; b < n; ++b) s += T[i * n + b] * S[b * n + j]; SHS[k * n * n + i * n + j] = s; }
  }
  if (ny == 1) {
    const double c0 = sqrt(W[0] > 0 ? W[0] : 0.0);
    for (i = 0; i < n * n; ++i) G[i] = c0 * SHS[i];
    for (i = 0; i < n; ++i) for (j = 0; j < n; ++j) T[i * n + j] = 0.5 * (G[i * n + j] + G[j * n + i]);
    smg_eig(n, T, gl, gv, a);
    for (i = 0; i < n; ++i) share[i] = fabs(gl[i]);
    best = smg_first_max(n, share);
    for (i = 0; i < n; ++i) vec[i] = gv[i * n + best];
  } else {
    for (i = 0; i < ny; ++i) for (j = 0; j < ny; ++j) T[i * ny + j] = 0.5 * (W[i * ny + j] + W[j * ny + i]);
    smg_eig(ny, T, wl, wv, a);
    for (k = 0; k < ny; ++k)
      for (i = 0; i < ny; ++i) C[k * ny + i] = wv[i * ny + k] * sqrt(wl[k] > 0 ? wl[k] : 0.0);
    for (k = 0; k < ny; ++k) {
      double* Gk = G + k * n * n;
      for (b = 0; b < n * n; ++b) { double s = 0; for (i = 0; i < ny; ++i) s += C[k * ny + i] * SHS[i * n * n + b]; T[b] = s; }
      for (i = 0; i < n; ++i) for (j = 0; j < n; ++j) Gk[i * n + j] = 0.5 * (T[i * n + j] + T[j * n + i]);
      smg_eig(n, Gk, gl, gv, a);
      for (i = 0; i < n; ++i) share[i] = fabs(gl[i]);
      best = smg_first_max(n, share);
      for (i = 0; i < n; ++i) lead[k * n + i] = gv[i * n + best];
    }
    for (b = 0; b < ny + n; ++b) {  /* the candidates: the leading eigenvectors, then the axes */
      double tot = 0;
      for (i = 0; i < n; ++i) vec[i] = b < ny ? lead[b * n + i] : (double) (i == b - ny);
      for (k = 0; k < ny; ++k) {
        const double* Gk = G + k * n * n;
        double q = 0;
        for (i = 0; i < n; ++i) for (j = 0; j < n; ++j) q += vec[i] * Gk[i * n + j] * vec[j];
        tot += q * q;
      }
      share[b] = tot;
    }
    best = smg_first_max(ny + n, share);
    for (i = 0; i < n; ++i) vec[i] = best < ny ? lead[best * n + i] : (double) (i == best - ny);
  }
  for (i = 0; i < n; ++i) { double s = 0; for (j = 0; j < n; ++j) s += S[i * n + j] * vec[j]; d[i] = s; }
  for (i = 0; i < n; ++i) share[i] = fabs(d[i]);
  best = smg_first_max(n, share);  /* the sign: the largest entry (the first within TIE) positive */
  if (d[best] < 0) for (i = 0; i < n; ++i) d[i] = -d[i];
}

/* pinv(A, rcond=1e-12, hermitian=True) of the symmetric m x m A into out. */
static void smg_pinv(smg_ctx* c, int m, const double* A, double* out) {
  double *lam = c->sc, *V = lam + m, *a = V + m * m, top = 0;
  int i, j, k;
  smg_eig(m, A, lam, V, a);
  for (k = 0; k < m; ++k) if (fabs(lam[k]) > top) top = fabs(lam[k]);
  for (i = 0; i < m * m; ++i) out[i] = 0;
  for (k = m - 1; k >= 0; --k) {
    if (!(fabs(lam[k]) > 1e-12 * top)) continue;
    for (i = 0; i < m; ++i) for (j = 0; j < m; ++j) out[i * m + j] += V[i * m + k] / lam[k] * V[j * m + k];
  }
}

static int smg_mon_call(smg_ctx* c, int which, const double* z, double* cg, double* D, double* H) {
  const casadi_real* arg[SMG_SZ_ARG];
  casadi_real* res[SMG_SZ_RES];
  arg[0] = z; res[0] = cg; res[1] = D; res[2] = H;
  return which ? SMG_MON_H(arg, res, c->iw, c->wk, 0) : SMG_MON_F(arg, res, c->iw, c->wk, 0);
}

/* The MoN of f (which 0, noise Q) or h (1, noise R) at the N components of one run into
   c->mon, their weights into c->W and Hessians into c->H (GaussianSumFilter._mons); returns
   how many exceed split (*err: a generated function failed). */
static int smg_mons(smg_ctx* c, int which, int N, const double* p, int* err) {
  const int n = SMG_N, ny = which ? c->ny : SMG_N;
  const double* noise = which ? c->R : c->Q;
  double *A, *r, *corr, *pc;
  int i, a, b, nover = 0;
  for (i = 0; i < N; ++i) {
    double m2 = 0;
    double* Wi = c->W + i * ny * ny;
    memcpy(c->z, c->x + i * n, n * sizeof(double));
    memcpy(c->z + n, c->P + i * n * n, n * n * sizeof(double));
    if (c->np) memcpy(c->z + n + n * n, p, c->np * sizeof(double));
    if (smg_mon_call(c, which, c->z, c->cg, c->D, c->H + i * ny * n * n)) { *err = 1; return 0; }
    /* the weight W = Sigma_yy^-1 / ny through the correlation matrix (_corr_inverse) */
    A = c->sc + SMG_SC_DIR;  /* clear of smg_pinv's scratch at c->sc */
    r = A + ny * ny; corr = r + ny; pc = corr + ny * ny;
    for (a = 0; a < ny * ny; ++a) A[a] = c->cg[a] + noise[a];
    for (a = 0; a < ny; ++a) r[a] = 1.0 / sqrt(A[a * ny + a]);
    if (ny == 1) Wi[0] = r[0] * r[0];
    else {
      for (a = 0; a < ny; ++a) for (b = 0; b < ny; ++b) corr[a * ny + b] = r[a] * A[a * ny + b] * r[b];
      smg_pinv(c, ny, corr, pc);
      for (a = 0; a < ny; ++a) for (b = 0; b < ny; ++b) Wi[a * ny + b] = r[a] * pc[a * ny + b] * r[b] / ny;
    }
    for (a = 0; a < ny; ++a) for (b = 0; b < ny; ++b) m2 += Wi[a * ny + b] * c->D[b * ny + a];
    c->mon[i] = m2 > 0 ? sqrt(m2) : (m2 != m2 ? m2 : 0.0);
    if (c->mon[i] > c->split) ++nover;
  }
  return nover;
}

/* Split the N components of one run whose MoN of f (which 0, noise Q) or h (1, noise R) exceeds
   split (the largest first while there is room below cap): the new count; *ns the splits. */
static int smg_split(smg_ctx* c, int which, int N, const double* p, int* ns, int* err) {
  const int n = SMG_N, ny = which ? c->ny : SMG_N, ms = c->ms;
  int i, j, a, b, nover, allowed, count = 0;
  *ns = 0;
  nover = smg_mons(c, which, N, p, err);
  if (*err || !nover) return N;
  allowed = N + nover * (ms - 1) <= c->cap ? nover : (c->cap >= N ? (c->cap - N) / (ms - 1) : 0);
  for (i = 0; i < N; ++i) {  /* chosen: among the allowed largest MoNs (ties: the first) */
    int rank = 0;
    c->alive[i] = 0;
    if (!(c->mon[i] > c->split)) continue;
    for (j = 0; j < N; ++j)
      if (c->mon[j] > c->split && (c->mon[j] > c->mon[i] || (c->mon[j] == c->mon[i] && j < i))) ++rank;
    c->alive[i] = rank < allowed;
    count += c->alive[i];
  }
  if (!count) return N;
  {
    int o = 0, q;
    const double k1 = 1.0 - c->sigma * c->sigma;
    double* d = c->sc + SMG_SC_DIR;
    for (i = 0; i < N; ++i) {
      const double *xi = c->x + i * n, *Pi = c->P + i * n * n;
      if (!c->alive[i]) {
        c->w2[o] = c->w[i];
        memcpy(c->x2 + o * n, xi, n * sizeof(double));
        memcpy(c->P2 + o * n * n, Pi, n * n * sizeof(double));
        ++o;
        continue;
      }
      smg_direction(c, ny, Pi, c->H + i * ny * n * n, c->W + i * ny * ny, d);
      for (q = 0; q < ms; ++q, ++o) {
        double* Po = c->P2 + o * n * n;
        c->w2[o] = c->w[i] * c->omega[q];
        for (a = 0; a < n; ++a) c->x2[o * n + a] = xi[a] + c->mu[q] * d[a];
        for (a = 0; a < n; ++a)
          for (b = 0; b < n; ++b) Po[a * n + b] = Pi[a * n + b] - k1 * (d[a] * d[b]);
        for (a = 0; a < n; ++a)
          for (b = 0; b < a; ++b) Po[a * n + b] = Po[b * n + a] = 0.5 * (Po[a * n + b] + Po[b * n + a]);
      }
    }
    for (i = 0; i < o; ++i)
      for (a = 0; a < n; ++a) if (c->ang[a]) c->x2[i * n + a] = smg_wrap(c->x2[i * n + a]);
    { double* t = c->w; c->w = c->w2; c->w2 = t; }
    { double* t = c->x; c->x = c->x2; c->x2 = t; }
    { double* t = c->P; c->P = c->P2; c->P2 = t; }
    *ns = count;
    return o;
  }
}

/* Keep the components i < N with alive[i], in order; returns how many. */
static int smg_compact(smg_ctx* c, int n, int N) {
  int i, o = 0;
  for (i = 0; i < N; ++i) {
    if (!c->alive[i]) continue;
    if (o != i) {
      c->w[o] = c->w[i];
      memcpy(c->x + o * n, c->x + i * n, n * sizeof(double));
      memcpy(c->P + o * n * n, c->P + i * n * n, n * n * sizeof(double));
    }
    ++o;
  }
  return o;
}
/* Merge back the calm components of one run (GaussianSumFilter._merge_back, merge.merge_below):
   calm where the MoN of f and of h (those curved) at the component, with the next step's
   parameters p, are below split / 2; then, while two calm components are left, the first pair
   (i, j), i < j, of least Runnalls cost is merged into i if that cost is below back (a NaN
   cost stops, as numpy's argmin takes the first NaN).  Returns the new count. */
static int smg_merge_back(smg_ctx* c, int N, const double* p, int* err) {
  const int n = SMG_N;
  double *A = c->sc + SMG_SC_DIR, *L = A + n * n;
  int i, j, a, ncalm = 0;
  for (i = 0; i < N; ++i) c->calm[i] = 1;
  for (a = 0; a < 2; ++a) {
    if (!c->curved[a]) continue;
    smg_mons(c, a, N, p, err);
    if (*err) return N;
    for (i = 0; i < N; ++i) c->calm[i] &= c->mon[i] < 0.5 * c->split;
  }
  for (i = 0; i < N; ++i) ncalm += c->calm[i];
  if (ncalm < 2) return N;
  for (i = 0; i < N; ++i) {
    c->alive[i] = 1;
    c->ld[i] = c->calm[i] ? sm_logdet(c->P + i * n * n, n, L) : 0.0;
  }
  for (; ncalm >= 2; --ncalm) {
    int bi = -1, bj = -1, nan = 0;
    double best = INFINITY;
    for (i = 0; i < N && !nan; ++i) {
      if (!c->alive[i] || !c->calm[i]) continue;
      for (j = i + 1; j < N; ++j) {
        double cost;
        if (!c->alive[j] || !c->calm[j]) continue;
        cost = sm_cost(i, j, n, 0, c->w, c->x, c->P, c->ld, 0, A, L);
        if (cost != cost) { nan = 1; break; }
        if (bi < 0 || cost < best) { best = cost; bi = i; bj = j; }
      }
    }
    if (nan || bi < 0 || !(best < c->back)) break;
    sm_merge_pair(bi, bj, n, c->w, c->x, c->P, A, L);
    c->ld[bi] = sm_logdet(c->P + bi * n * n, n, L);
    c->alive[bj] = 0;
  }
  N = smg_compact(c, n, N);
  for (i = 0; i < N; ++i)
    for (a = 0; a < n; ++a) if (c->ang[a]) c->x[i * n + a] = smg_wrap(c->x[i * n + a]);
  return N;
}

static int smg_finite(const double* a, int m) {
  int i;
  for (i = 0; i < m; ++i) if (!isfinite(a[i])) return 0;
  return 1;
}

/* symmon: the K steps of the runs r0 .. r1 - 1 (module notes).  Y, mask: (R, K, ny) (missing:
   0 and 0); prm: (R, K, np); w0, m0, P0: the M0 prior components; opt = [n, ny, np, ms, Mk,
   salmond, curved_f, curved_h, M0]; fl = [split, prune, sigma, merge_back (0: none)]; table = [omega (ms), mu (ms)];
   ang: (n) flags of the angle states; outputs (R, K, ...) or NULL; fail (R): the step of a
   non-finite component (-1: none); stop: a flag another thread may set (NULL: none), polled
   before each step.  Returns 0, 1 when a generated function failed, -1 out of memory,
   SMG_STOPPED when the flag stopped the runs (their outputs part way). */
CASADI_SYMBOL_EXPORT int sm_gsfk_run(casadi_int r0, casadi_int r1, casadi_int K, const casadi_int* opt,
    const double* fl, const double* table, const int* ang, const double* Q, const double* R,
    const double* w0, const double* m0, const double* P0, const double* Y, const double* mask,
    const double* prm, double* o_ll, long long* o_comp, long long* o_split, double* o_x, double* o_P,
    double* o_w, double* o_m, double* o_C, long long* fail, casadi_int* iw, casadi_real* wk,
    const volatile int* stop) {
  smg_ctx c;
  /* n = opt[0], the dimension the kernel is built for: a constant, so that the loops over it unroll */
  const int n = SMG_N, ny = (int) opt[1], M0 = (int) opt[8], nym = n > ny ? n : ny;
  int cap, ret = 0;
  casadi_int r, k;
  double* buf;
  size_t tot;
  c.n = n; c.ny = ny; c.np = (int) opt[2]; c.ms = (int) opt[3]; c.Mk = (int) opt[4]; c.salmond = (int) opt[5];
  c.curved[0] = (int) opt[6]; c.curved[1] = (int) opt[7];
  c.split = fl[0]; c.prune = fl[1]; c.sigma = fl[2]; c.back = fl[3];
  c.omega = table; c.mu = table + c.ms; c.Q = Q; c.R = R; c.ang = ang; c.iw = iw; c.wk = wk;
  c.cap = cap = c.Mk * c.ms;
  if (M0 > cap) cap = M0;
  tot = (size_t) cap * (2 + 2 * n + 2 * n * n + 2 + nym * nym + nym * n * n) + SMG_ROW + 2 * nym * nym
        + SMG_SC_DIR + SMG_SC_MORE;
  buf = malloc(sizeof(double) * tot);
  c.start = malloc(sizeof(long long) * 2);
  c.alive = malloc((size_t) cap + 1);
  c.calm = malloc((size_t) cap + 1);
  c.ld = malloc(sizeof(double) * ((size_t) cap + 1));
  if (!buf || !c.start || !c.alive || !c.calm || !c.ld) {
    free(buf); free(c.start); free(c.alive); free(c.calm); free(c.ld);
    return -1;
  }
  c.w = buf; c.w2 = c.w + cap; c.x = c.w2 + cap; c.x2 = c.x + cap * n; c.P = c.x2 + cap * n;
  c.P2 = c.P + cap * n * n; c.mon = c.P2 + cap * n * n; c.ll = c.mon + cap; c.W = c.ll + cap;
  c.H = c.W + cap * nym * nym; c.z = c.H + cap * nym * n * n; c.cg = c.z + SMG_ROW; c.D = c.cg + nym * nym;
  c.sc = c.D + nym * nym;
  for (r = r0; r < r1 && !ret; ++r) {
    int N = M0, i, a, b;
    memcpy(c.w, w0, M0 * sizeof(double));
    memcpy(c.x, m0, M0 * n * sizeof(double));
    memcpy(c.P, P0, M0 * n * n * sizeof(double));
    fail[r] = -1;
    for (k = 0; k < K; ++k) {
      const double* p = prm + (r * K + k) * c.np;
      const double *yk = Y + (r * K + k) * ny, *mk = mask + (r * K + k) * ny;
      const casadi_real* arg[SMG_SZ_ARG];
      casadi_real* res[SMG_SZ_RES];
      int ns, err = 0, bad = 0;
      double top, s, tw;
      if (stop && *stop) { ret = SMG_STOPPED; break; }
      o_split[r * K + k] = 0;
      if (c.curved[0]) {
        N = smg_split(&c, 0, N, p, &ns, &err);
        o_split[r * K + k] += ns;
      }
      for (i = 0; i < N && !err; ++i) {  /* the prediction */
        double* z = c.z;
        memcpy(z, c.x + i * n, n * sizeof(double)); z += n;
        memcpy(z, c.P + i * n * n, n * n * sizeof(double)); z += n * n;
        memcpy(z, Q, n * n * sizeof(double)); z += n * n;
        if (c.np) memcpy(z, p, c.np * sizeof(double));
        arg[0] = c.z; res[0] = c.x + i * n; res[1] = c.P + i * n * n;
        if (SMG_PREDICT(arg, res, c.iw, c.wk, 0)) err = 1;
      }
      if (c.curved[1] && !err) {
        N = smg_split(&c, 1, N, p, &ns, &err);
        o_split[r * K + k] += ns;
      }
      for (i = 0; i < N && !err; ++i) {  /* the update */
        double* z = c.z;
        memcpy(z, c.x + i * n, n * sizeof(double)); z += n;
        memcpy(z, c.P + i * n * n, n * n * sizeof(double)); z += n * n;
        memcpy(z, yk, ny * sizeof(double)); z += ny;
        memcpy(z, R, ny * ny * sizeof(double)); z += ny * ny;
        memcpy(z, mk, ny * sizeof(double)); z += ny;
        if (c.np) memcpy(z, p, c.np * sizeof(double));
        arg[0] = c.z; res[0] = c.x + i * n; res[1] = c.P + i * n * n; res[2] = c.ll + i;
        if (SMG_UPDATE(arg, res, c.iw, c.wk, 0)) err = 1;
        if (!isfinite(c.ll[i]) || !smg_finite(c.x + i * n, n) || !smg_finite(c.P + i * n * n, n * n)) bad = 1;
      }
      if (err) { ret = 1; break; }
      if (bad) { fail[r] = k; break; }
      /* log sum_i w_i N(nu_i; 0, S_i), then the normalised weights */
      for (i = 0; i < N; ++i) c.ll[i] += log(c.w[i]);
      top = c.ll[0];
      for (i = 1; i < N; ++i) if (c.ll[i] > top) top = c.ll[i];
      s = 0;
      for (i = 0; i < N; ++i) s += exp(c.ll[i] - top);
      s = top + log(s);
      o_ll[r * K + k] = s;
      for (i = 0; i < N; ++i) c.w[i] = exp(c.ll[i] - s);
      /* prune (the heaviest stays), merge down to Mk, renormalise */
      top = c.w[0];
      for (i = 1; i < N; ++i) if (c.w[i] > top) top = c.w[i];
      /* weight 0: dropped even at prune 0 (a merge of two would divide by their total) */
      for (i = 0; i < N; ++i) c.alive[i] = (c.w[i] >= c.prune && c.w[i] > 0) || c.w[i] == top;
      N = smg_compact(&c, n, N);
      if (N > c.Mk) {
        double* Pinv = c.sc + SMG_SC_DIR;
        if (c.salmond) {  /* _metric: the inverse of the mixture's covariance, by correlations */
          double *mean = Pinv + n * n, *C = mean + n, *rr = C + n * n, *pc = rr + n, ws = 0;
          for (i = 0; i < N; ++i) ws += c.w[i];
          for (a = 0; a < n; ++a) { mean[a] = 0; for (i = 0; i < N; ++i) mean[a] += c.w[i] / ws * c.x[i * n + a]; }
          for (a = 0; a < n; ++a)
            for (b = 0; b < n; ++b) {
              double v = 0, u = 0;
              for (i = 0; i < N; ++i) v += c.w[i] / ws * c.P[i * n * n + a * n + b];
              for (i = 0; i < N; ++i) u += (c.x[i * n + a] - mean[a]) * (c.w[i] / ws) * (c.x[i * n + b] - mean[b]);
              C[a * n + b] = v + u;
            }
          for (a = 0; a < n; ++a) for (b = 0; b < a; ++b) C[a * n + b] = C[b * n + a] = 0.5 * (C[a * n + b] + C[b * n + a]);
          for (a = 0; a < n; ++a) rr[a] = 1.0 / sqrt(C[a * n + a]);
          for (a = 0; a < n; ++a) for (b = 0; b < n; ++b) C[a * n + b] = rr[a] * C[a * n + b] * rr[b];
          smg_pinv(&c, n, C, pc);
          for (a = 0; a < n; ++a) for (b = 0; b < n; ++b) Pinv[a * n + b] = rr[a] * pc[a * n + b] * rr[b];
        }
        c.start[0] = 0; c.start[1] = N;
        if (sm_gsf_merge(1, c.start, n, c.Mk, c.salmond, c.w, c.x, c.P, Pinv, c.alive)) { ret = -1; break; }
        N = smg_compact(&c, n, N);
      }
      tw = 0;
      for (i = 0; i < N; ++i) tw += c.w[i];
      for (i = 0; i < N; ++i) c.w[i] /= tw;
      if (c.back > 0 && N >= 2) {  /* merge back, with the next step's parameters */
        N = smg_merge_back(&c, N, prm + (r * K + (k + 1 < K ? k + 1 : K - 1)) * c.np, &err);
        if (err) { ret = 1; break; }
      }
      /* the step's outputs: the moment-matched mean and covariance, the mixture */
      o_comp[r * K + k] = N;
      {
        double* xm = c.sc + SMG_SC_DIR, *dv = xm + n, *Pm = dv + n;
        for (a = 0; a < n; ++a) { xm[a] = 0; for (i = 0; i < N; ++i) xm[a] += c.w[i] * c.x[i * n + a]; }
        if (o_x) memcpy(o_x + (r * K + k) * n, xm, n * sizeof(double));
        if (o_P) {
          for (a = 0; a < n * n; ++a) Pm[a] = 0;
          for (i = 0; i < N; ++i) {
            for (a = 0; a < n; ++a) dv[a] = c.x[i * n + a] - xm[a];
            for (a = 0; a < n; ++a)
              for (b = 0; b < n; ++b) Pm[a * n + b] += c.w[i] * (c.P[i * n * n + a * n + b] + dv[a] * dv[b]);
          }
          for (a = 0; a < n; ++a)
            for (b = 0; b < n; ++b) o_P[(r * K + k) * n * n + a * n + b] = 0.5 * (Pm[a * n + b] + Pm[b * n + a]);
        }
        if (o_w) {
          memcpy(o_w + (r * K + k) * c.Mk, c.w, N * sizeof(double));
          memcpy(o_m + (r * K + k) * c.Mk * n, c.x, N * n * sizeof(double));
          memcpy(o_C + (r * K + k) * c.Mk * n * n, c.P, N * n * n * sizeof(double));
        }
      }
    }
  }
  free(buf); free(c.start); free(c.alive); free(c.calm); free(c.ld);
  return ret;
}
