"""The compiled recursion of the bootstrap particle filter: the K steps of a run in one C call.

For the bootstrap proposal (Gordon et al. 1993, §3) a step of :class:`~symmon.ParticleFilter`
is, per particle i of a run with log-weight ℓ_i (normalised) and standard normal draws z_i,

    x'_i = f(x_i, L_Q z_i)            (or f(x_i) + L_Q z_i for additive noise; angles wrapped),
    t_i  = ℓ_i + log N(y; h(x'_i), Γ R Γᵀ)   over the measured components of y,

then the log-sum-exp of t (the step's log-likelihood increment, Doucet et al. 2000, eq. (11)),
the normalised weights W_i = exp(t_i − lse), the weighted mean Σ W_i x'_i, the effective
sample size 1 / Σ W_i², and, when the ESS is low, a resampling with the gather of the
chosen particles (and, for the regularised filter, the kernel jitter h L ε).

``NAME_run`` does all K steps of one run without returning to Python.  Per step:

1. move and weigh, by blocks of :data:`BLOCK` particles: the block's normals from the
   :data:`~symmon.compile.rng.LANES` interleaved xoshiro streams (lanes) of its chunk of
   :data:`~symmon.filters.particle._rng.CHUNK` particles, drawn column by column, LANES particles
   at a time, by the vectorised ziggurat ``symmon_normal_lanes`` of :mod:`symmon.compile.rng`
   (particle i of a block takes lane i mod LANES; each lane's numbers are the scalar
   generator's from its state; until 2026-12-04 one stream per chunk, particle by
   particle, drew them: a seed's particles changed then), the rows [x_i, z_i] stored by
   columns; then the
   transition, the measurement and the wrapped innovation ν_i of every row, by the
   vectorised loop of :func:`symmon.compile.vecmath.vector_rows` where f and h have one
   (a row it flags recomputed by CasADi's function), else by CasADi's function per
   particle; then the whitening A ν_i by the inverse Cholesky factor A of the measured
   block of Γ R Γᵀ (embedded with zero rows and columns for the missing components, whose
   ν_i, finite or not, never enter) and the log-density, by loops over the block; writing
   x'_i, t_i and each chunk's maximum m_q of t and a flag for a non-finite particle or
   weight; then, while the chunk's x' and t are in the cache, e'_i = exp(t_i − m_q) (by
   :mod:`symmon.compile.vecmath`'s vectorised exp, within 1 ulp) and the chunk's Σ e'_i,
   Σ e'_i², Σ e'_i x'_i (sines and cosines for angle states); no exponential overflows;
2. after the barrier, with m = max t, e_i = r_q e'_i for r_q = exp(m_q − m): the chunks'
   sums scaled by r_q (r_q² for Σ e²) are added in chunk order, so the result does not
   depend on the threads (until 2026-12-04 a second pass over x' and t computed
   exp(t_i − m) itself: the moments then differed by rounding); e itself is rescaled only
   for the covariance and the regularisation;
3. the covariance and the predicted moments when kept (a pass each);
4. on resampling: the points (systematic: u + i, not stored, u drawn by every thread
   from its copy of the resampling stream, so no barrier; stratified, or sorted uniforms
   as normalised sums of exponential spacings for multinomial: O(N), no sort), then the walk along the
   cumulative weights c_j by input chunk (points ascending: O(N), no binary search).  For
   systematic points it goes by particle: particle j takes the points from the last one's
   end to the first i with u + i >= c_j, i = ⌈c_j − u⌉ moved until the points' own
   comparisons hold (a guess off by one only within rounding), so no branch depends on the
   weights and no chain of dependences runs from one particle to the next (the walk went from
   ~12 to ~6 ns a particle, 2026-12-04); other schemes go point by point, each chunk finding
   its first point by bisection; both make the same picks (tested).  The regularisation's
   jitter by output chunk.
   Without regularisation the pick is kept as indices and the next move reads the moved
   particles through them (the rows are copied once, at the end of the run), which saves
   the gather's read and write of the N x n particles each step.  After a resampling the
   log-weights, all −log N, are a flag, not written.

A single run runs on T threads (pthreads made by the call, a barrier at each reduction);
the moves and the walks go by chunks that the threads claim in turn from a counter (a
thread that is ahead takes more: the two cores of a virtual machine need not run at one
speed, and a walk's chunk holds as many points as its share of the weight; with fixed
ranges a step of 10⁵ particles of 4 states spent ~10 % of its threads' time at the barriers,
and the best of four runs went from 2.3 to 1.85 ms a step, 10⁴ of 20 states 687 → 571 µs), the
other passes by fixed contiguous chunk ranges; the C of a run never waits on Python's
thread pool.  After a step without resampling the log-weights t_i − lse are written by the
next move (which reads t_i before it overwrites it), or at the end.
The chunk's own stream draws a Gaussian prior and the regularisation's jitter.
``_replay`` (tests) feeds given normals and points instead of drawing them.  A Gaussian
prior is drawn in C too, x_0 = m + L z from the first normals of each chunk's stream.
"""

from __future__ import annotations

import ctypes
import math
import re
import threading
from typing import Sequence

import casadi as ca
import numpy as np

from ...compile import NativeLibrary, compiled_with_params
from ...compile.compiled import WorkArrays, generated_c
from ...compile.vecmath import VECMATH_C, vector_rows
from ...core.model import Model
from ...compile.rng import LANES, RNG_C
from ._rng import CHUNK

__all__ = ["BootstrapKernel", "bootstrap_kernel", "BLOCK", "MIN_THREAD_NUMBERS"]

_LOG_2PI = math.log(2 * math.pi)

# The recursion of one run.  casadi_int is long long (CasADi's default).  The library holds one
# kernel: its static names are short (pfk_*; the C's size decides a background build), the
# exported ones carry the kernel's name.
_DRIVER = """
#include <string.h>
#include <stdlib.h>
#include <pthread.h>
#include <sched.h>
#include <time.h>
static const int pfk_ax[{nx}] = {{{ax}}};
static const int pfk_ay[{ny}] = {{{ay}}};

static double pfk_wrap(double a) {{  /* wrap_angle: (-pi, pi] */
  const double two_pi = 2 * 3.14159265358979311600, s = a + 3.14159265358979311600;
  const double o = s - two_pi * floor(s / two_pi) - 3.14159265358979311600;
  return o == -3.14159265358979311600 ? 3.14159265358979311600 : o;
}}

/* The weighted mean (circular for flagged components) and, with cov, the covariance of the
   rows of X (N x d) with weights w summing to s (ParticleFilter._moments). */
static void pfk_mom(const casadi_real* X, casadi_int N, int d, const casadi_real* w, casadi_real s,
    const int* ang, casadi_real* mean, casadi_real* cov) {{
  casadi_real a1[{dm}], a2[{dm}], dv[{dm}], wi;
  casadi_int i;
  int a, b;
  const casadi_real* xi;
  for (a = 0; a < d; ++a) a1[a] = a2[a] = 0;
  for (i = 0; i < N; ++i) {{
    wi = w[i];
    xi = X + i * d;
    for (a = 0; a < d; ++a) {{
      if (ang[a]) {{ a1[a] += wi * sin(xi[a]); a2[a] += wi * cos(xi[a]); }}
      else a1[a] += wi * xi[a];
    }}
  }}
  for (a = 0; a < d; ++a) mean[a] = ang[a] ? atan2(a1[a], a2[a]) : a1[a] / s;
  if (!cov) return;
  for (a = 0; a < d * d; ++a) cov[a] = 0;
  for (i = 0; i < N; ++i) {{
    wi = w[i];
    xi = X + i * d;
    for (a = 0; a < d; ++a) dv[a] = ang[a] ? pfk_wrap(xi[a] - mean[a]) : xi[a] - mean[a];
    for (a = 0; a < d; ++a) for (b = 0; b <= a; ++b) cov[a * d + b] += wi * dv[a] * dv[b];
  }}
  for (a = 0; a < d; ++a) for (b = 0; b <= a; ++b) cov[b * d + a] = cov[a * d + b] = cov[a * d + b] / s;
}}

/* The lower Cholesky factor of a positive semidefinite C (n x n): a pivot <= 0 gives a zero
   column (the directions without spread get no kernel jitter). */
static void pfk_chol(const casadi_real* C, casadi_real* L) {{
  int i, j, k;
  casadi_real d;
  for (i = 0; i < {nx} * {nx}; ++i) L[i] = 0;
  for (j = 0; j < {nx}; ++j) {{
    d = C[j * {nx} + j];
    for (k = 0; k < j; ++k) d -= L[j * {nx} + k] * L[j * {nx} + k];
    if (!(d > 1e-14 * C[j * {nx} + j]) || !(d > 0)) continue;
    L[j * {nx} + j] = sqrt(d);
    for (i = j + 1; i < {nx}; ++i) {{
      d = C[i * {nx} + j];
      for (k = 0; k < j; ++k) d -= L[i * {nx} + k] * L[j * {nx} + k];
      L[i * {nx} + j] = d / L[j * {nx} + j];
    }}
  }}
}}

/* count normals of stream s into out (a loop of its own: the state stays in registers). */
static __attribute__((noinline)) void pfk_draw(uint64_t* s, casadi_int count, casadi_real* out) {{
  casadi_int i;
  uint64_t sl[4];
  memcpy(sl, s, sizeof sl);  /* the state in registers, not memory, while it runs */
  for (i = 0; i < count; ++i) out[i] = symmon_normal(sl);
  memcpy(s, sl, sizeof sl);
}}

/* symmon: count normals of stream s into out (tests of the generator). */
CASADI_SYMBOL_EXPORT void {name}_normals(unsigned long long* s, casadi_int count, casadi_real* out) {{
  pfk_draw((uint64_t*) s, count, out);
}}

/* A chunk's lanes, lane by lane (as in st), to and from symmon_normal_lanes's word order. */
static void pfk_lanes_in(const uint64_t* st, uint64_t* ls) {{
  int l, w;
  for (l = 0; l < SYMMON_LANES; ++l) for (w = 0; w < 4; ++w) ls[w * SYMMON_LANES + l] = st[l * 4 + w];
}}
static void pfk_lanes_out(const uint64_t* ls, uint64_t* st) {{
  int l, w;
  for (l = 0; l < SYMMON_LANES; ++l) for (w = 0; w < 4; ++w) st[l * 4 + w] = ls[w * SYMMON_LANES + l];
}}

/* symmon: groups x SYMMON_LANES normals of lanes s into out, lane l's at out[g * LANES + l] (tests). */
CASADI_SYMBOL_EXPORT void {name}_lanes(unsigned long long* s, casadi_int groups, casadi_real* out) {{
  uint64_t ls[4 * SYMMON_LANES];
  pfk_lanes_in((uint64_t*) s, ls);
  symmon_normal_lanes(ls, out, groups * SYMMON_LANES);
  pfk_lanes_out(ls, (uint64_t*) s);
}}

/* A barrier of the T threads: a spin of up to pfk_SPIN_NS, then a mutex and condition
   (macOS has no pthread_barrier); the last to arrive resets the count, then publishes the
   new generation under the mutex (no lost wake-up).  The spin outlasts a step's imbalance
   between threads (tens of microseconds at 10^4 particles): a thread put to sleep wakes tens
   of microseconds late in a virtual machine, and its core may go to another process
   meanwhile (OpenMP runtimes spin for 0.2 ms and more before they sleep).  The spin yields
   the CPU every 32 turns: when the kernel puts both threads on one CPU (as it may after the
   process slept), a spin that did not yield kept the other thread off the CPU for the whole
   0.2 ms at every barrier (the median step of 10^3 particles of 20 states after a 16 ms
   sleep: 0.56 ms without the yield, 0.17 ms with it; 2026-12-04). */
#if defined(__x86_64__) || defined(__i386__)
#define pfk_PAUSE() __builtin_ia32_pause()
#else
#define pfk_PAUSE() ((void) 0)
#endif
#define pfk_SPIN_NS 200000L
typedef struct {{ pthread_mutex_t mu; pthread_cond_t cv; int count, T; unsigned gen; }} pfk_barrier;
static void pfk_bwait(pfk_barrier* b) {{
  unsigned g;
  long i;
  struct timespec t0, t1;
  if (b->T == 1) return;
  g = __atomic_load_n(&b->gen, __ATOMIC_ACQUIRE);
  if (__atomic_add_fetch(&b->count, 1, __ATOMIC_ACQ_REL) == b->T) {{
    __atomic_store_n(&b->count, 0, __ATOMIC_RELAXED);
    pthread_mutex_lock(&b->mu);
    __atomic_store_n(&b->gen, g + 1u, __ATOMIC_RELEASE);
    pthread_cond_broadcast(&b->cv);
    pthread_mutex_unlock(&b->mu);
    return;
  }}
  clock_gettime(CLOCK_MONOTONIC, &t0);
  for (i = 1;; ++i) {{  /* spin for at most pfk_SPIN_NS (the clock every 32 turns) */
    if (__atomic_load_n(&b->gen, __ATOMIC_ACQUIRE) != g) return;
    pfk_PAUSE();
    if (i % 32) continue;
    sched_yield();
    clock_gettime(CLOCK_MONOTONIC, &t1);
    if ((t1.tv_sec - t0.tv_sec) * 1000000000L + (t1.tv_nsec - t0.tv_nsec) > pfk_SPIN_NS) break;
  }}
  pthread_mutex_lock(&b->mu);
  while (__atomic_load_n(&b->gen, __ATOMIC_ACQUIRE) == g) pthread_cond_wait(&b->cv, &b->mu);
  pthread_mutex_unlock(&b->mu);
}}

/* Per chunk of CHUNK particles: [max t, bad, sum e, sum e^2, sum e x (or sin), sum e cos]. */
#define pfk_PW (4 + 2 * {nx})
/* r_q = exp(m_q - m): a chunk's exponentials about its maximum m_q to the step's m (0 for a
   chunk of zero weights, m_q = -inf) */
#define pfk_RATIO(mq, m) ((mq) == -INFINITY ? 0.0 : exp((mq) - (m)))
/* Doubles of a thread's buffers (the body's notes). */
#define pfk_BUF ({ld} * {nr} + {ld} * {no} + 2 * {ld} + {no} + {block} / 8 + 1)

typedef struct {{
  const casadi_real* P; casadi_int K, N, nch; casadi_real *X0, *Xn0, *t, *e, *lw, *sc, *hx, *part;
  unsigned long long* st; const casadi_real *zext, *uext, *jext, *m0, *L0; const casadi_int* opt; const casadi_real* fl;
  casadi_real *o_ll, *o_ess, *o_res, *o_x, *o_P, *o_xp, *o_Pp, *o_hm, *o_hS, *cov, *L;
  casadi_int *fail, *idx; pfk_barrier bar; int T; pthread_mutex_t gate;
  casadi_int cnt[2][2];  /* the next chunk to claim, by step parity: the moves', the walks' */
}} pfk_ctx;

/* Systematic resampling's points are pt + i, i = 0 ... N - 1, not stored (the serial fill and
   the walk's reads of N numbers saved); other schemes' are an array.
   The lowest i in [p, hi) with the systematic point pt + i >= v (hi if none): the guess
   ceil(v - pt), moved until the points' own comparisons hold on both sides (it is off by
   one only where v is within rounding of a point), so the index a search by those
   comparisons finds, without branches that depend on the weights. */
static inline casadi_int pfk_first(casadi_real pt, casadi_real v, casadi_int p, casadi_int hi) {{
  const casadi_real g = ceil(v - pt);
  casadi_int i = g <= (casadi_real) p ? p : g >= (casadi_real) hi ? hi : (casadi_int) g;
  while (i > p && pt + (casadi_real) (i - 1) >= v) --i;
  while (i < hi && pt + (casadi_real) i < v) ++i;
  return i;
}}

/* The lowest index i in [0, N) of the ascending points with point i >= v (N if none). */
static casadi_int pfk_lower(const casadi_real* sc, casadi_real pt, casadi_int N, casadi_real v) {{
  casadi_int lo = 0, hi = N, mid;
  if (!sc) return pfk_first(pt, v, 0, N);
  while (lo < hi) {{ mid = (lo + hi) / 2; if (sc[mid] < v) lo = mid + 1; else hi = mid; }}
  return lo;
}}

/* The picks of input chunk q: it holds the points in [S_q, S_(q+1)) x scale, S_q = off
   the sum of e over the chunks before it (part: the chunks' [m_q, -, sum e', ...], e_i =
   exp(m_q - m) e'_i, or e_i = e[i] when esc); point i (pts[i], or pt + i for systematic
   points, pts NULL) takes the first particle j of its chunk whose cumulative weight exceeds
   it (the chunk's last if none): idx[i] = j, or row j of Xn copied to row i of X (X not NULL).
   Systematic points go by particle (its points [i, b) at once; b from lo, not from i, so
   that no chain of dependences runs through i), other points by point; the same picks. */
static void pfk_pick_chunk(const casadi_real* e, const casadi_real* part, casadi_real m, int esc, casadi_int N,
    casadi_int nch, casadi_int q, casadi_real off, casadi_real scale, const casadi_real* pts, casadi_real pt,
    casadi_int* restrict idx, casadi_real* X, const casadi_real* Xn) {{
  const casadi_int end = (q + 1) * {chunk} < N ? (q + 1) * {chunk} : N;
  const casadi_int lo = q == 0 ? 0 : pfk_lower(pts, pt, N, off * scale);
  casadi_real r = esc ? 1 : pfk_RATIO(part[q * pfk_PW], m), cum;  /* e_i = r e[i] */
  casadi_int i, j = q * {chunk}, b, hi;
  cum = (off + r * e[j]) * scale;
  off += pfk_RATIO(part[q * pfk_PW], m) * part[q * pfk_PW + 2];
  hi = q == nch - 1 ? N : pfk_lower(pts, pt, N, off * scale);
  r *= scale;
  if (pts) {{
    for (i = lo; i < hi; ++i) {{
      while (cum <= pts[i] && j < end - 1) cum += e[++j] * r;
      if (X) memcpy(X + i * {nx}, Xn + j * {nx}, {nx} * sizeof(casadi_real));
      else idx[i] = j;
    }}
    return;
  }}
  for (i = lo; i < hi; cum += e[++j] * r) {{  /* b = hi at j = end - 1: j stays in the chunk */
    b = j < end - 1 ? pfk_first(pt, cum, lo, hi) : hi;
    if (X) for (; i < b; ++i) memcpy(X + i * {nx}, Xn + j * {nx}, {nx} * sizeof(casadi_real));
    else if (b - i <= 4 && i + 4 <= hi) {{  /* four stores (one vector); later particles overwrite the extra */
      idx[i] = idx[i + 1] = idx[i + 2] = idx[i + 3] = j;
      i = b;
    }} else for (; i < b; ++i) idx[i] = j;
    if (i >= hi) break;
  }}
}}

/* The picks of every chunk in chunk order (off: the sum of the chunks before, as the body's). */
static void pfk_picks(const casadi_real* e, const casadi_real* part, casadi_real m, int esc, casadi_int N,
    casadi_int nch, casadi_real scale, const casadi_real* pts, casadi_real pt, casadi_int* restrict idx) {{
  casadi_real off = 0;
  casadi_int q;
  for (q = 0; q < nch; ++q) {{
    pfk_pick_chunk(e, part, m, esc, N, nch, q, off, scale, pts, pt, idx, 0, 0);
    off += pfk_RATIO(part[q * pfk_PW], m) * part[q * pfk_PW + 2];
  }}
}}

/* symmon: the picks of N weights e (chunks of CHUNK, each chunk's sum in chunk order) for the
   ascending points pts on [0, N), or pt + i when pts is NULL, into idx (tests: the two walks
   give the same picks). */
CASADI_SYMBOL_EXPORT int {name}_pick(const casadi_real* e, casadi_int N, const casadi_real* pts, casadi_real pt,
    casadi_int* idx) {{
  const casadi_int nch = (N + {chunk} - 1) / {chunk};
  casadi_real* part = (casadi_real*) calloc(nch * pfk_PW, sizeof(casadi_real));
  casadi_real s = 0;
  casadi_int q, i;
  if (!part) return 1;
  for (q = 0; q < nch; ++q) {{
    for (i = q * {chunk}; i < N && i < (q + 1) * {chunk}; ++i) part[q * pfk_PW + 2] += e[i];
    s += part[q * pfk_PW + 2];
  }}
  pfk_picks(e, part, 0, 1, N, nch, (casadi_real) N / s, pts, pt, idx);
  free(part);
  return 0;
}}

/* Thread tau's share of the K steps: the moves and the walks by chunks claimed in turn (a
   thread that is ahead takes more: the threads' cores need not run at one speed, nor do the
   walks' chunks hold as many points), the other passes by its fixed chunks [c0, c1); every
   reduction is by chunk, in chunk order, so the numbers depend neither on T nor on who took
   which chunk.  offs: nch numbers, the sum of e over the chunks before each. */
static int pfk_body(pfk_ctx* c, int tau, casadi_int* iw, casadi_real* w, casadi_real* buf, casadi_real* offs) {{
  const casadi_int N = c->N, nch = c->nch, c0 = nch * tau / c->T, c1 = nch * (tau + 1) / c->T;
  const casadi_int a0 = c0 * {chunk}, a1 = c1 * {chunk} < N ? c1 * {chunk} : N;
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_real *X = c->X0, *Xn = c->Xn0, *tmp, *xi, *pc;
  const casadi_real* pk;
  casadi_real ti, m, mq, r, s, s2, lse, lsp = 0, ei, cum, zr[{nq}], eps[{nx}], sx[{nx}], sn[{nx}], cs[{nx}];
  const casadi_real log_n = log((casadi_real) N);
  /* rsl: this thread's copy of the resampling stream; every thread draws a systematic
     resampling's point from it (no barrier), tau 0 the others, and writes it back at the end */
  uint64_t* rs = (uint64_t*) c->st + 4 * nch, ls[4 * SYMMON_LANES], rsl[4];
  casadi_int i, j, k, q, a, b, bad, redo, end, b0, nb;
  /* this thread's buffers: the rows [x, z] of a block and its outputs [x', nu, h] by columns,
     A nu and |A nu|^2 of one component, one row, the vector loop's flags */
  casadi_real *rb = buf, *blk = rb + {ld} * {nr}, *wz = blk + {ld} * {no}, *acc = wz + {ld}, *row = acc + {ld};
  unsigned char* odd = (unsigned char*) (row + {no});
  const int want_pred = c->o_xp || c->o_Pp || c->o_hm, reg = (int) c->opt[1];
  /* gath: the particle i is X's row idx[i] (the last resampling's pick, not copied: the next
     move reads through idx, which saves the gather's pass over memory) */
  int gath = 0;
  memcpy(rsl, rs, sizeof rsl);
  /* uni: every log-weight is -log N (after a resampling, and at the start), not stored in lw:
     the pass that wrote them and the move's reads saved; lw written at the end */
  int uni = 1, esc, sysm = !c->uext && c->opt[0] == 0;
  casadi_real psys = 0;
  casadi_real* part;
  if (c->m0) for (q = c0; q < c1; ++q) {{  /* the prior x0 = m + L z, z the first normals of chunk q's stream */
    end = (q + 1) * {chunk} < N ? (q + 1) * {chunk} : N;
    pfk_draw((uint64_t*) c->st + 4 * q, (end - q * {chunk}) * {nx}, X + q * {chunk} * {nx});
    for (i = q * {chunk}; i < end; ++i) {{
      xi = X + i * {nx};
      memcpy(eps, xi, sizeof eps);
      for (a = 0; a < {nx}; ++a) {{
        if (c->opt[2]) ei = c->L0[a * {nx} + a] * eps[a];  /* a diagonal L */
        else for (ei = 0, b = 0; b < {nx}; ++b) ei += c->L0[a * {nx} + b] * eps[b];
        xi[a] = ei + c->m0[a];
        if (pfk_ax[a]) xi[a] = pfk_wrap(xi[a]);
      }}
    }}
  }}
  if (c->m0) pfk_bwait(&c->bar);  /* the moves read any chunk's prior */
  for (k = 0; k < c->K; ++k) {{
    arg[2] = pk = c->P + k * {n_p};
    part = c->part + (k & 1) * nch * pfk_PW;  /* by parity: a thread's next move may write
                                                     its chunks' sums while another reads these */
    for (;;) {{  /* move and weigh, chunk q (claimed), in blocks of {block} particles */
      uint64_t* lq;
      q = __atomic_fetch_add(&c->cnt[k & 1][0], 1, __ATOMIC_RELAXED);
      if (q >= nch) break;
      lq = (uint64_t*) c->st + 4 * (nch + 1) + 4 * SYMMON_LANES * q;  /* chunk q's lanes */
      pfk_lanes_in(lq, ls);
      end = (q + 1) * {chunk} < N ? (q + 1) * {chunk} : N;
      m = -INFINITY;
      bad = 0;
      for (b0 = q * {chunk}; b0 < end; b0 += {block}) {{
        nb = end - b0 < {block} ? end - b0 : {block};
        /* the rows [x_i, z_i] by columns; the normals column by column from the chunk's
           lanes (particle i from lane i mod SYMMON_LANES; a last group past nb fills the
           column's spare rows: ld >= 8 ceil(nb / 8)) */
        for (i = 0; i < nb; ++i) {{
          const casadi_real* xr = X + (gath ? c->idx[b0 + i] : b0 + i) * {nx};
          for (j = 0; j < {nx}; ++j) rb[j * {ld} + i] = xr[j];
        }}
        if (c->zext) {{
          for (i = 0; i < nb; ++i) for (j = 0; j < {nq}; ++j) rb[({nx} + j) * {ld} + i] = c->zext[(k * N + b0 + i) * {nq} + j];
        }} else {{
          for (j = 0; j < {nq}; ++j) symmon_normal_lanes(ls, rb + ({nx} + j) * {ld}, (nb + SYMMON_LANES - 1) / SYMMON_LANES * SYMMON_LANES);
        }}
        {fill}
        /* the log-density c - |A nu|^2 / 2 of the measured components (another's nu, maybe
           not finite, never enters), A = pk[o_A ...] by columns, by loops over the block */
        for (i = 0; i < nb; ++i) acc[i] = 0;
        for (a = 0; a < {ny}; ++a) {{
          if (pk[{o_mask} + a] == 0) continue;
          for (i = 0; i < nb; ++i) wz[i] = 0;
          for (b = 0; b < {ny}; ++b) {{
            const casadi_real A_ab = pk[{o_A} + b * {ny} + a], *nu = blk + ({nx} + b) * {ld};
            if (pk[{o_mask} + b] == 0) continue;
            for (i = 0; i < nb; ++i) wz[i] += A_ab * nu[i];
          }}
          for (i = 0; i < nb; ++i) acc[i] += wz[i] * wz[i];
        }}
        for (i = 0; i < nb; ++i) {{
          xi = Xn + (b0 + i) * {nx};
          for (j = 0; j < {nx}; ++j) xi[j] = blk[j * {ld} + i];
          if (c->hx) for (j = 0; j < {ny}; ++j) c->hx[(b0 + i) * {ny} + j] = blk[({nx} + {ny} + j) * {ld} + i];
          /* the last step's log-weight t - lse, kept in lw (the predicted moments, the end) */
          ti = (uni ? -log_n : (c->lw[b0 + i] = c->t[b0 + i] - lsp)) + (-0.5 * acc[i] + pk[{n_p} - 1]);
          c->t[b0 + i] = ti;
          if (ti != ti || ti == INFINITY) bad |= 1;
          for (j = 0; j < {nx}; ++j) if (!isfinite(xi[j])) bad |= 1;
          if (ti > m) m = ti;
        }}
      }}
      pfk_lanes_out(ls, lq);
      /* the chunk's exponentials e'_i = exp(t_i - m_q) about its own maximum m_q and their
         sums, while its x' and t are in the cache (the step's maximum scales them after the
         barrier, exactly as exp(m_q - max t)); by vecmath's sm_exp (within 1 ulp,
         vectorised), an argument beyond its range by libm's exp */
      b0 = q * {chunk};
      mq = m == -INFINITY ? 0 : m;  /* every t_i = -inf: e' = 0 */
      {{
        const casadi_real* restrict tq = c->t;
        casadi_real* restrict eq = c->e;
        for (i = b0; i < end; ++i) eq[i] = sm_exp(tq[i] - mq);
      }}
      s = 0; s2 = 0;
      for (j = 0; j < {nx}; ++j) sx[j] = cs[j] = 0;
      for (i = b0; i < end; ++i) {{
        ei = c->e[i];
        if (!sm_exp_ordinary(c->t[i] - mq)) c->e[i] = ei = exp(c->t[i] - mq);
        s += ei;
        s2 += ei * ei;
        xi = Xn + i * {nx};
        {wsum}
      }}
      pc = part + q * pfk_PW;
      pc[0] = m;
      pc[1] = (casadi_real) bad;
      pc[2] = s; pc[3] = s2;
      for (j = 0; j < {nx}; ++j) {{ pc[4 + j] = sx[j]; pc[4 + {nx} + j] = cs[j]; }}
    }}
    pfk_bwait(&c->bar);
    if (tau == 0) c->cnt[k & 1][0] = 0;  /* every claim of this step is over; the next is at k + 2 */
    m = -INFINITY;
    bad = 0;
    for (q = 0; q < nch; ++q) {{
      if (part[q * pfk_PW] > m) m = part[q * pfk_PW];
      bad |= (casadi_int) part[q * pfk_PW + 1];
    }}
    if (bad & 2) return 1;
    if (bad || !isfinite(m)) {{ if (tau == 0) *c->fail = k; return 2; }}
    if (want_pred) {{  /* the predicted moments, with the weights before the update */
      for (i = a0; i < a1; ++i) c->sc[i] = exp(uni ? -log_n : c->lw[i]);
      pfk_bwait(&c->bar);
      if (tau == 0) {{
        if (c->o_xp || c->o_Pp) pfk_mom(Xn, N, {nx}, c->sc, 1.0, pfk_ax, c->o_xp ? c->o_xp + k * {nx} : sn,
                                           c->o_Pp ? c->o_Pp + k * {nx} * {nx} : 0);
        if (c->o_hm) pfk_mom(c->hx, N, {ny}, c->sc, 1.0, pfk_ay, c->o_hm + k * {ny}, c->o_hS + k * {ny} * {ny});
      }}
    }}
    /* the chunks' sums scaled by r_q = exp(m_q - m) (e_i = r_q e'_i), added in chunk order */
    s = 0; s2 = 0;
    for (j = 0; j < {nx}; ++j) sx[j] = cs[j] = 0;
    for (q = 0; q < nch; ++q) {{
      pc = part + q * pfk_PW;
      r = pfk_RATIO(pc[0], m);
      offs[q] = s;
      s += r * pc[2]; s2 += r * r * pc[3];
      for (j = 0; j < {nx}; ++j) {{ sx[j] += r * pc[4 + j]; cs[j] += r * pc[4 + {nx} + j]; }}
    }}
    esc = c->o_P || reg;
    if (esc) {{  /* e_i itself, for the covariance about the mean (tau 0, after the barrier) */
      for (q = c0; q < c1; ++q) {{
        end = (q + 1) * {chunk} < N ? (q + 1) * {chunk} : N;
        r = pfk_RATIO(part[q * pfk_PW], m);
        for (i = q * {chunk}; i < end; ++i) c->e[i] *= r;
      }}
      pfk_bwait(&c->bar);
    }}
    lse = m + log(s);
    redo = s * s / s2 <= c->fl[0];
    if (tau == 0) {{
      c->o_ll[k] = lse;
      c->o_ess[k] = s * s / s2;
      c->o_res[k] = (casadi_real) redo;
      if (c->o_x) for (j = 0; j < {nx}; ++j) c->o_x[k * {nx} + j] = pfk_ax[j] ? atan2(sx[j], cs[j]) : sx[j] / s;
      if (c->o_P || (redo && reg))  /* the covariance about the mean */
        pfk_mom(Xn, N, {nx}, c->e, s, pfk_ax, sn, c->o_P ? c->o_P + k * {nx} * {nx} : c->cov);
    }}
    /* tau 0 reads e, hx, sc of every chunk above: the next move writes them */
    if (want_pred || esc) pfk_bwait(&c->bar);
    if (!redo) {{  /* the log-weights t - lse: by the next move (lw), or at the end */
      lsp = lse;
      uni = 0;
      tmp = X; X = Xn; Xn = tmp;
      gath = 0;
      continue;
    }}
    if (sysm) psys = symmon_uniform(rsl);  /* the points psys + i, not stored */
    if (tau == 0) {{  /* resampling points, ascending on [0, N) */
      casadi_real* sc = c->sc;
      if (c->uext) memcpy(sc, c->uext + k * N, N * sizeof(casadi_real));
      else if (c->opt[0] == 1) {{ for (i = 0; i < N; ++i) sc[i] = symmon_uniform(rsl) + (casadi_real) i; }}
      else if (c->opt[0] == 2) {{  /* sorted uniforms as normalised sums of exponential spacings */
        cum = 0;
        for (i = 0; i < N; ++i) {{ cum += -log1p(-symmon_uniform(rsl)); sc[i] = cum; }}
        cum += -log1p(-symmon_uniform(rsl));
        for (i = 0; i < N; ++i) sc[i] *= (casadi_real) N / cum;
      }}
      if (reg) pfk_chol(c->o_P ? c->o_P + k * {nx} * {nx} : c->cov, c->L);
    }}
    if (!sysm || reg) pfk_bwait(&c->bar);
    for (;;) {{  /* the walk along the cumulative weights, by input chunk (claimed) */
      q = __atomic_fetch_add(&c->cnt[k & 1][1], 1, __ATOMIC_RELAXED);
      if (q >= nch) break;
      pfk_pick_chunk(c->e, part, m, esc, N, nch, q, offs[q], (casadi_real) N / s, sysm ? 0 : c->sc, psys, c->idx,
                     reg ? X : 0, Xn);
    }}
    pfk_bwait(&c->bar);
    if (tau == 0) c->cnt[k & 1][1] = 0;
    uni = 1;
    if (!reg) {{  /* the moved particles, read through idx by the next move */
      tmp = X; X = Xn; Xn = tmp;
      gath = 1;
      continue;
    }}
    for (q = c0; q < c1; ++q) {{  /* regularisation: x += h L eps (Musso, Oudjane & Le Gland 2001) */
      uint64_t* sg = (uint64_t*) c->st + 4 * q, sl[4];
      memcpy(sl, sg, sizeof sl);
      end = (q + 1) * {chunk} < N ? (q + 1) * {chunk} : N;
      for (i = q * {chunk}; i < end; ++i) {{
        if (c->jext) memcpy(eps, c->jext + (k * N + i) * {nx}, {nx} * sizeof(casadi_real));
        else for (j = 0; j < {nx}; ++j) eps[j] = symmon_normal(sl);
        xi = X + i * {nx};
        for (a = 0; a < {nx}; ++a) {{
          ei = 0;
          for (b = 0; b <= a; ++b) ei += c->L[a * {nx} + b] * eps[b];
          xi[a] += c->fl[1] * ei;
          if (pfk_ax[a]) xi[a] = pfk_wrap(xi[a]);
        }}
      }}
      memcpy(sg, sl, sizeof sl);
    }}
    pfk_bwait(&c->bar);  /* the next move reads any chunk */
  }}
  for (i = a0; i < a1; ++i) c->lw[i] = uni ? -log_n : c->t[i] - lsp;
  if (gath) {{  /* the last pick, copied into the other buffer (other threads read X's rows) */
    for (i = a0; i < a1; ++i) memcpy(Xn + i * {nx}, X + c->idx[i] * {nx}, {nx} * sizeof(casadi_real));
    tmp = X; X = Xn; Xn = tmp;
    pfk_bwait(&c->bar);
  }}
  if (X != c->X0) memcpy(c->X0 + a0 * {nx}, X + a0 * {nx}, (a1 - a0) * {nx} * sizeof(casadi_real));  /* own rows */
  if (tau == 0) memcpy(rs, rsl, sizeof rsl);
  return 0;
}}

typedef struct {{ pfk_ctx* c; int tau; casadi_int* iw; casadi_real* w; casadi_real* buf; casadi_real* offs; int ret; }} pfk_arg;
static void* pfk_thread(void* p) {{
  pfk_arg* a = (pfk_arg*) p;
  pthread_mutex_lock(&a->c->gate);  /* wait until every thread is made and T is final */
  pthread_mutex_unlock(&a->c->gate);
  a->ret = pfk_body(a->c, a->tau, a->iw, a->w, a->buf, a->offs);
  return 0;
}}

/* symmon: the K steps of the bootstrap filter for one run on T threads over particle chunks
   (module notes).  P: K rows of the call's parameters; X holds the N initial particles (on
   return: the final ones, and lw their normalised log-weights); Xn,
   t, e, lw, sc: work (N x n, N, N, N, N); hx: N x ny or NULL; part: 2 ceil(N / CHUNK) x
   (4 + 2n); st: ceil(N / CHUNK) + 1 xoshiro states (the chunks', then the resampling
   stream), then SYMMON_LANES per chunk (the move's normals, lane by lane); zext, uext, jext: replayed move normals (K x N x nq), resampling points (K x N,
   ascending in [0, N)) and jitter normals (K x N x nx), or NULL to draw; m0, L0: the mean
   and square root (n x n, row-major) of a Gaussian prior to draw X from (the first normals
   of each chunk's stream), or NULL (X given); opt = [scheme (0 systematic, 1 stratified,
   2 multinomial), regularise, L0 diagonal]; fl = [ESS threshold x N,
   bandwidth h]; outputs per step (NULL: not wanted); iw, w: T work arrays of isz, wsz. */
CASADI_SYMBOL_EXPORT int {name}_run(const casadi_real* P, casadi_int K, casadi_int N, casadi_real* X0,
    casadi_real* Xn0, casadi_real* t, casadi_real* e, casadi_real* lw, casadi_real* sc, casadi_real* hx,
    casadi_real* part, unsigned long long* st, const casadi_real* zext, const casadi_real* uext,
    const casadi_real* jext, const casadi_real* m0, const casadi_real* L0, const casadi_int* opt, const casadi_real* fl, casadi_real* o_ll, casadi_real* o_ess,
    casadi_real* o_res, casadi_real* o_x, casadi_real* o_P, casadi_real* o_xp, casadi_real* o_Pp,
    casadi_real* o_hm, casadi_real* o_hS, casadi_int* iw, casadi_real* w, casadi_int isz, casadi_int wsz,
    casadi_int T, casadi_int* fail) {{
  pfk_ctx c;
  pfk_arg args[64];
  pthread_t th[64];
  casadi_real cov[{nx} * {nx}], L[{nx} * {nx}];
  int tau, ret = 0, started = 0;
  casadi_real* buf;
  c.P = P; c.K = K; c.N = N; c.nch = (N + {chunk} - 1) / {chunk};
  c.X0 = X0; c.Xn0 = Xn0; c.t = t; c.e = e; c.lw = lw; c.sc = sc; c.hx = hx; c.part = part; c.st = st;
  c.zext = zext; c.uext = uext; c.jext = jext; c.m0 = m0; c.L0 = L0; c.opt = opt; c.fl = fl; c.o_ll = o_ll; c.o_ess = o_ess;
  c.o_res = o_res; c.o_x = o_x; c.o_P = o_P; c.o_xp = o_xp; c.o_Pp = o_Pp; c.o_hm = o_hm; c.o_hS = o_hS;
  c.cov = cov; c.L = L; c.fail = fail;
  memset(c.cnt, 0, sizeof c.cnt);
  c.idx = (casadi_int*) malloc((N > 0 ? N : 1) * sizeof(casadi_int));
  if (!c.idx) return 1;
  if (T > c.nch) T = c.nch;
  if (T > 64) T = 64;
  if (T < 1) T = 1;
  c.T = (int) T;
  buf = (casadi_real*) malloc(T * (pfk_BUF + c.nch) * sizeof(casadi_real));
  if (!buf) {{ free(c.idx); return 1; }}
  c.bar.T = (int) T; c.bar.count = 0; c.bar.gen = 0;
  pthread_mutex_init(&c.bar.mu, 0);
  pthread_cond_init(&c.bar.cv, 0);
  pthread_mutex_init(&c.gate, 0);
  pthread_mutex_lock(&c.gate);
  for (tau = 0; tau < T; ++tau) {{
    args[tau].c = &c; args[tau].tau = tau; args[tau].iw = iw + tau * isz; args[tau].w = w + tau * wsz;
    args[tau].ret = 0; args[tau].buf = buf + tau * pfk_BUF; args[tau].offs = buf + T * pfk_BUF + tau * c.nch;
  }}
  for (tau = 1; tau < T; ++tau) {{
    if (pthread_create(&th[tau], 0, pfk_thread, &args[tau])) break;
    started = tau;
  }}
  c.T = c.bar.T = started + 1;  /* fewer threads if one could not be made */
  pthread_mutex_unlock(&c.gate);
  pfk_thread(&args[0]);
  for (tau = 1; tau <= started; ++tau) pthread_join(th[tau], 0);
  pthread_mutex_destroy(&c.bar.mu);
  pthread_cond_destroy(&c.bar.cv);
  pthread_mutex_destroy(&c.gate);
  free(buf);
  free(c.idx);
  for (tau = 0; tau <= started; ++tau) if (args[tau].ret > ret) ret = args[tau].ret;
  return ret;
}}
"""


# The C as compiled: the driver without its comments (they are for the reader of this file;
# the library's size, which decides a background build, is the code's).
_DRIVER_C = re.sub(r"/\*.*?\*/", "", _DRIVER, flags=re.S)

#: Particles per block of the move and weigh (the rows of a block by columns fit in L2).
BLOCK = 256
#: A run takes several threads (over its chunks) only from N (n + n_q) numbers drawn and
#: moved a step on: below, a step is tens of microseconds, and the barriers and the
#: threads' start would take a good part of what a second core saves.
MIN_THREAD_NUMBERS = 1 << 15
#: The column stride of a block's buffers: not a power of two, so that the columns of a row
#: (written one after another by the rows' loop) do not all fall in one set of the L1 cache;
#: at least BLOCK rounded up to LANES (the normals' last group of a block fills spare rows).
LD = BLOCK + 8
assert LD >= -(-BLOCK // LANES) * LANES
# The move of a block of nb rows rb = [x_i, z_i] into blk (by columns: x'_i, the wrapped
# innovation ν_i, h(x'_i)): by the vectorised loop {name}_vec when f and h have one
# (symmon.compile.vecmath: arithmetic, sqrt, atan2, hypot, within 1 ulp), a row it flags
# (an atan2 or hypot argument that is zero, inf, NaN or beyond 2^±500) recomputed by
# CasADi's function (libm); else by CasADi's function row by row.
_ROW = """
          for (j = 0; j < {nq}; ++j) zr[j] = rb[({nx} + j) * {ld} + i];
          arg[0] = X + (gath ? c->idx[b0 + i] : b0 + i) * {nx}; arg[1] = zr;
          res[0] = row; res[1] = row + {nx}; res[2] = row + {nx} + {ny};
          if ({name}(arg, res, iw, w, 0)) bad = 2;
          for (j = 0; j < {no}; ++j) blk[j * {ld} + i] = row[j];"""
# The weighted sums of a particle's states (sines and cosines for angle states); without
# angle states a loop without a branch, which gcc vectorises (the same operations).
_WSUM = "for (j = 0; j < {nx}; ++j) sx[j] += ei * xi[j];"
_WSUM_ANGLES = """for (j = 0; j < {nx}; ++j) {{
          if (pfk_ax[j]) {{ sx[j] += ei * sin(xi[j]); cs[j] += ei * cos(xi[j]); }}
          else sx[j] += ei * xi[j];
        }}"""
_FILL = {
    True: "if ({name}_vec(rb, arg[2], blk, nb, odd)) for (i = 0; i < nb; ++i) {{\n          if (!odd[i]) continue;"
          + _ROW + "\n        }}",
    False: "for (i = 0; i < nb; ++i) {{" + _ROW + "\n        }}",
}


class BootstrapKernel:
    """The three compiled loops of a bootstrap step for the models f and h (module notes).

    Parameters
    ----------
    f_model, h_model : Model
    params : the filter's parameter names (f's, then h's that f does not have)
    Lq_pattern : bool (d, n_q), the structural nonzeros of L_Q (d: f's noise symbols, or n),
        n_q the draws per particle
    angle_states, angle_outputs : wrapped components
    vectorise : bool, default True
        Move and weigh through :func:`~symmon.compile.vecmath.vector_rows`'s loop where f
        and h have one (False: CasADi's function per particle, for comparisons)

    Notes
    -----
    The parameters of a call (one run) are packed by :meth:`pack`:
    p = [θ (the filter's parameters), the nonzeros of L_Q (column-major), y (missing: 0), mask (1: measured),
    vec(A) (column-major), c], with A the inverse Cholesky factor of the measured block of
    Γ R Γᵀ embedded with zeros and c = −(log det + m log 2π)/2 for the m measured components.
    """

    def __init__(self, f_model: Model, h_model: Model, params: Sequence, Lq_pattern: np.ndarray,
                 angle_states: Sequence[int], angle_outputs: Sequence[int], vectorise: bool = True) -> None:
        cf, ch = compiled_with_params(f_model), compiled_with_params(h_model)
        n, ny, npar = f_model.n_u, h_model.n_y, len(params)
        self.n, self.n_y, self.n_par = n, ny, npar
        # L_Q enters by its structural nonzeros only (a block-diagonal Q of 5 targets: 40 of
        # 400 products per particle), as parameters, so one C serves every Q of that pattern.
        self.Lq_pattern = pattern = np.asarray(Lq_pattern, dtype=bool)
        d, n_q = pattern.shape  # d: f's noise symbols, or n for additive noise
        self.n_q, nnz = n_q, int(pattern.sum())
        x, z = ca.SX.sym("x", n), ca.SX.sym("z", n_q)
        p = ca.SX.sym("p", npar + nnz + 2 * ny + ny * ny + 1)
        theta = p[:npar]
        col, row = np.nonzero(pattern.T)  # the nonzeros in column-major order, as CasADi stores them
        Lq = ca.SX(ca.Sparsity.triplet(d, n_q, row.tolist(), col.tolist()), p[npar:npar + nnz])
        o = npar + nnz
        y = p[o:o + ny]  # then the mask, vec(A) and c, which the C reads (pack's notes)
        self._o_mask, self._o_A = o + ny, o + 2 * ny

        def of(model: Model, cm, state, noise):
            th = [theta[list(params).index(s)] for s in model.params]
            return ca.substitute(cm.y_sx, cm.w_sx, ca.vertcat(state, *noise, *th))

        noise = ca.mtimes(Lq, z)
        xn = of(f_model, cf, x, [noise]) if f_model.n_v else of(f_model, cf, x, []) + noise
        xn = ca.vertcat(*[_wrap(xn[i]) if i in angle_states else xn[i] for i in range(n)])
        hx = of(h_model, ch, xn, [ca.SX.zeros(h_model.n_v)] if h_model.n_v else [])
        hx = ca.vertcat(*[_wrap(hx[i]) if i in angle_outputs else hx[i] for i in range(ny)])
        # the innovation, wrapped; the C whitens its measured components (a select on the
        # mask here would keep gcc from vectorising the row loop)
        nu = y - hx
        nu = ca.vertcat(*[_wrap(nu[i]) if i in angle_outputs else nu[i] for i in range(ny)])
        name = f"{cf.tag}_{ch.tag}_pfb" + "".join(f"_s{i}" for i in angle_states) + "".join(
            f"_o{i}" for i in angle_outputs)
        self.f = ca.Function(name, [x, z, p], [ca.densify(xn), ca.densify(nu), ca.densify(hx)], ["x", "z", "p"],
                             ["xn", "nu", "hx"], {"cse": True})
        self.n_p = p.numel()
        self._work = WorkArrays(self.f)
        self.angle_states = tuple(angle_states)
        # The same map as one output [x', ν, h(x')] of the rows [x, z] of a block
        # stored by columns, for the vectorised loop (None: an operation without a vector
        # form, e.g. sin): vector_rows reads input j of row i at z[i * n_in + j], so the
        # row's input is a vector whose entry j * LD is the row's entry j, with n_in = 1.
        cols = ca.SX.sym("r", (n + n_q - 1) * LD + 1)
        at = ca.vertcat(*[cols[j * LD] for j in range(n + n_q)])
        out = ca.substitute(ca.vertcat(xn, nu, hx), ca.vertcat(x, z), at)
        row = ca.Function(f"{name}_row", [cols, p], [out], {"cse": True})
        vec = vector_rows(row, f"{name}_vec", 1, LD) if vectorise else None
        #: True when the move and weigh run through the vectorised loop (module notes).
        self.vectorised = vec is not None
        flags = lambda idx, d: ", ".join("1" if i in idx else "0" for i in range(d))  # noqa: E731
        fmt = dict(name=name, sz_arg=max(self.f.sz_arg(), 3), sz_res=max(self.f.sz_res(), 3), nx=n, nq=max(n_q, 1),
                   ny=ny, n_p=self.n_p, dm=max(n, ny), chunk=CHUNK, ax=flags(angle_states, n),
                   ay=flags(angle_outputs, ny), block=BLOCK, ld=LD, nr=n + max(n_q, 1), no=n + 2 * ny,
                   o_mask=self._o_mask, o_A=self._o_A)
        fmt["fill"] = _FILL[self.vectorised].format(**fmt)
        fmt["wsum"] = (_WSUM_ANGLES if angle_states else _WSUM).format(**fmt)
        code = RNG_C + generated_c(self.f) + VECMATH_C + (vec or "") + _DRIVER_C.format(**fmt)

        def load(so):
            lib = ctypes.CDLL(str(so))
            run = getattr(lib, f"{name}_run")
            run.argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong] + [ctypes.c_void_p] * 27
                            + [ctypes.c_longlong] * 3 + [ctypes.c_void_p])
            run.restype = ctypes.c_int
            normals = getattr(lib, f"{name}_normals")
            normals.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
            normals.restype = None
            lanes = getattr(lib, f"{name}_lanes")
            lanes.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
            lanes.restype = None
            pick = getattr(lib, f"{name}_pick")
            pick.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]
            pick.restype = ctypes.c_int
            return run, normals, lanes, pick

        self._native: NativeLibrary = cf.native_library(code, name, load, stacklevel=4)
        self._Lq_size = nnz

    def loops(self):
        """The ctypes functions (run, normals, lanes, pick), or None while the C is not there (no
        compiler, or a background build running: the caller takes the NumPy path)."""
        return self._native.get()

    def pack(self, theta: np.ndarray | None, Lq: np.ndarray, Y: np.ndarray, white) -> np.ndarray:
        """The parameter vectors (R, K, n_p) of every run and step (class notes): θ (R, K,
        n_par) or None, L_Q, the measurements Y (R, K, n_y) with NaN for missing, and
        ``white(mask)`` → (A, c), the whitening of the measured components ``mask``."""
        R, K, ny = Y.shape
        p = np.zeros((R, K, self.n_p))
        o = self.n_par
        if o:
            p[..., :o] = theta
        p[..., o:o + self._Lq_size] = Lq.T[self.Lq_pattern.T]
        o += self._Lq_size
        measured = ~np.isnan(Y)
        p[..., o:o + ny] = np.where(measured, Y, 0.0)
        p[..., o + ny:o + 2 * ny] = measured
        o += 2 * ny
        flat = p.reshape(-1, self.n_p)
        if measured.all():  # the common case: one pattern
            A, c = white(np.ones(ny, dtype=bool))
            flat[:, o:o + ny * ny] = A.ravel(order="F")
            flat[:, -1] = c
            return p
        codes = np.packbits(measured.reshape(-1, ny), axis=1, bitorder="little")
        codes = codes.view(np.dtype((np.void, codes.shape[1]))).ravel()
        for code in np.unique(codes):
            rows = codes == code
            A, c = white(measured.reshape(-1, ny)[np.argmax(rows)])
            flat[rows, o:o + ny * ny] = A.ravel(order="F")
            flat[rows, -1] = c
        return p

    def work(self) -> tuple[int, int]:
        """This thread's work arrays (addresses)."""
        return self._work.addresses()


def _wrap(a: ca.SX) -> ca.SX:
    """:func:`symmon.core.angles.wrap_casadi` without its select, the same number to the bit.

    o = (a + π) − 2π ⌊(a + π)/2π⌋ − π lies in [−π, π] up to rounding (a little below −π
    for large |a|); d = o + π is exact near −π (Sterbenz), so d = 0 exactly where o = −π,
    and else 0 < |d| < 8, where ⌈|d|/8⌉ = 1.  Hence o + (1 − ⌈|d|/8⌉) 2π is o (o is never
    −0: x − π is +0 at zero, so o + 0 = o) or −π + 2π = π exactly (2π is π doubled); a NaN
    stays NaN.  gcc vectorises a loop with this form, not one with a select on a
    comparison (symmon.compile.vecmath's row loop).
    """
    two_pi = 2 * np.pi
    s = a + np.pi
    out = s - two_pi * ca.floor(s / two_pi) - np.pi
    return out + (1 - ca.ceil(ca.fabs(out + np.pi) / 8)) * two_pi


_kernels: dict[tuple, BootstrapKernel] = {}
_lock = threading.Lock()


def bootstrap_kernel(f_model: Model, h_model: Model, params: Sequence, Lq: np.ndarray,
                     angle_states: Sequence[int], angle_outputs: Sequence[int]) -> BootstrapKernel:
    """The kernel of these models for the nonzero pattern of ``Lq``, built once per process
    (by the models' structural keys and the pattern)."""
    pattern = np.asarray(Lq) != 0
    key = (f_model.key, h_model.key, tuple(str(s) for s in params), pattern.shape, pattern.tobytes(),
           tuple(angle_states), tuple(angle_outputs))
    with _lock:
        k = _kernels.get(key)
        if k is None:
            k = _kernels[key] = BootstrapKernel(f_model, h_model, params, pattern, angle_states, angle_outputs)
        return k


def whitening(S: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, float]:
    """A (n_y, n_y): the inverse Cholesky factor of S's measured block embedded with zeros,
    and c = −(log det S_m + m log 2π) / 2; S_m must be positive definite (checked by the
    filter when it is built)."""
    m = np.flatnonzero(measured)
    A = np.zeros_like(S)
    if m.size == 0:
        return A, 0.0
    L = np.linalg.cholesky(S[np.ix_(m, m)])
    A[np.ix_(m, m)] = np.linalg.inv(L)
    return A, float(-0.5 * (2 * np.log(np.diag(L)).sum() + m.size * _LOG_2PI))
