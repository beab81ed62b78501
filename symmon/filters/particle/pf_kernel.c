/* symmon: the recursion of one run of the bootstrap particle filter
   (symmon.filters.particle._kernel, whose module notes describe it).  casadi_int is long long
   (CasADi's default).  The library holds one kernel: its static names are short (pfk_*: the
   C's size decides a background build), the exported ones carry the kernel's name (PFK_RUN,
   ...).  BootstrapKernel puts before this file the random numbers (symmon.compile.rng), the
   generated C of the step PFK_F, the vectorised functions (symmon.compile.vecmath), the row loop
   PFK_VEC when there is one (PFK_VECTORISED), and the PFK_ macros; it strips the comments. */
#ifndef PFK_NX  /* checked alone: example macros, and what comes before this file */
#define _POSIX_C_SOURCE 200112L  /* clock_gettime and pthreads under -std=c99 (the builds use gcc's default) */
#include "../../compile/casadi_alone.h"
#include "../../compile/rng.c"
#define PFK_F pfk_model
#define PFK_VEC pfk_model_vec
#define PFK_NORMALS pfk_model_normals
#define PFK_LANES pfk_model_lanes
#define PFK_RUN pfk_model_run
#define PFK_PICK pfk_model_pick
#define PFK_SOLO pfk_model_solo
#define PFK_VECTORISED 1
#define PFK_ANGLES 1
#define PFK_NX 2
#define PFK_NQ 2
#define PFK_NY 1
#define PFK_N_P 8
#define PFK_DM 2
#define PFK_CHUNK 4096
#define PFK_AX 1, 0
#define PFK_AY 0
#define PFK_BLOCK 256
#define PFK_LD 264
#define PFK_NR 4
#define PFK_NO 4
#define PFK_O_MASK 3
#define PFK_O_A 4
#define PFK_SZ_ARG 3
#define PFK_SZ_RES 3
#define PFK_STOPPED 2
int PFK_F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int PFK_VEC(const double* restrict z, const double* restrict p, double* restrict out, long long n,
            unsigned char* restrict odd);
double sm_exp(double x);
int sm_exp_ordinary(double x);
#endif
#include <stdio.h>
#include <string.h>
#include <stdlib.h>
#include <unistd.h>
#include <pthread.h>
#include <sched.h>
#include <time.h>
static const int pfk_ax[PFK_NX] = {PFK_AX};
static const int pfk_ay[PFK_NY] = {PFK_AY};

static double pfk_wrap(double a) {  /* wrap_angle: (-pi, pi] */
  const double two_pi = 2 * 3.14159265358979311600, s = a + 3.14159265358979311600;
  const double o = s - two_pi * floor(s / two_pi) - 3.14159265358979311600;
  return o == -3.14159265358979311600 ? 3.14159265358979311600 : o;
}

/* The weighted mean (circular for flagged components) and, with cov, the covariance of the
   rows of X (N x d) with weights w summing to s (ParticleFilter._moments). */
static void pfk_mom(const casadi_real* X, casadi_int N, int d, const casadi_real* w, casadi_real s,
    const int* ang, casadi_real* mean, casadi_real* cov) {
  casadi_real a1[PFK_DM], a2[PFK_DM], dv[PFK_DM], wi;
  casadi_int i;
  int a, b;
  const casadi_real* xi;
  for (a = 0; a < d; ++a) a1[a] = a2[a] = 0;
  for (i = 0; i < N; ++i) {
    wi = w[i];
    xi = X + i * d;
    for (a = 0; a < d; ++a) {
      if (ang[a]) { a1[a] += wi * sin(xi[a]); a2[a] += wi * cos(xi[a]); }
      else a1[a] += wi * xi[a];
    }
  }
  for (a = 0; a < d; ++a) mean[a] = ang[a] ? atan2(a1[a], a2[a]) : a1[a] / s;
  if (!cov) return;
  for (a = 0; a < d * d; ++a) cov[a] = 0;
  for (i = 0; i < N; ++i) {
    wi = w[i];
    xi = X + i * d;
    for (a = 0; a < d; ++a) dv[a] = ang[a] ? pfk_wrap(xi[a] - mean[a]) : xi[a] - mean[a];
    for (a = 0; a < d; ++a) for (b = 0; b <= a; ++b) cov[a * d + b] += wi * dv[a] * dv[b];
  }
  for (a = 0; a < d; ++a) for (b = 0; b <= a; ++b) cov[b * d + a] = cov[a * d + b] = cov[a * d + b] / s;
}

/* The lower Cholesky factor of a positive semidefinite C (n x n): a pivot <= 0 gives a zero
   column (the directions without spread get no kernel jitter). */
static void pfk_chol(const casadi_real* C, casadi_real* L) {
  int i, j, k;
  casadi_real d;
  for (i = 0; i < PFK_NX * PFK_NX; ++i) L[i] = 0;
  for (j = 0; j < PFK_NX; ++j) {
    d = C[j * PFK_NX + j];
    for (k = 0; k < j; ++k) d -= L[j * PFK_NX + k] * L[j * PFK_NX + k];
    if (!(d > 1e-14 * C[j * PFK_NX + j]) || !(d > 0)) continue;
    L[j * PFK_NX + j] = sqrt(d);
    for (i = j + 1; i < PFK_NX; ++i) {
      d = C[i * PFK_NX + j];
      for (k = 0; k < j; ++k) d -= L[i * PFK_NX + k] * L[j * PFK_NX + k];
      L[i * PFK_NX + j] = d / L[j * PFK_NX + j];
    }
  }
}

/* count normals of stream s into out (a loop of its own: the state stays in registers). */
static __attribute__((noinline)) void pfk_draw(uint64_t* s, casadi_int count, casadi_real* out) {
  casadi_int i;
  uint64_t sl[4];
  memcpy(sl, s, sizeof sl);  /* the state in registers, not memory, while it runs */
  for (i = 0; i < count; ++i) out[i] = symmon_normal(sl);
  memcpy(s, sl, sizeof sl);
}

/* symmon: count normals of stream s into out (tests of the generator). */
CASADI_SYMBOL_EXPORT void PFK_NORMALS(unsigned long long* s, casadi_int count, casadi_real* out) {
  pfk_draw((uint64_t*) s, count, out);
}

/* A chunk's lanes, lane by lane (as in st), to and from symmon_normal_lanes's word order. */
static void pfk_lanes_in(const uint64_t* st, uint64_t* ls) {
  int l, w;
  for (l = 0; l < SYMMON_LANES; ++l) for (w = 0; w < 4; ++w) ls[w * SYMMON_LANES + l] = st[l * 4 + w];
}
static void pfk_lanes_out(const uint64_t* ls, uint64_t* st) {
  int l, w;
  for (l = 0; l < SYMMON_LANES; ++l) for (w = 0; w < 4; ++w) st[l * 4 + w] = ls[w * SYMMON_LANES + l];
}

/* symmon: groups x SYMMON_LANES normals of lanes s into out, lane l's at out[g * LANES + l] (tests). */
CASADI_SYMBOL_EXPORT void PFK_LANES(unsigned long long* s, casadi_int groups, casadi_real* out) {
  uint64_t ls[4 * SYMMON_LANES];
  pfk_lanes_in((uint64_t*) s, ls);
  symmon_normal_lanes(ls, out, groups * SYMMON_LANES);
  pfk_lanes_out(ls, (uint64_t*) s);
}

/* A barrier of the T threads: a spin of up to pfk_SPIN_NS, then a mutex and condition
   (macOS has no pthread_barrier); the last to arrive resets the count, then publishes the
   new generation under the mutex (no lost wake-up).  The spin outlasts a step's imbalance
   between threads (tens of microseconds at 10^4 particles): a thread put to sleep wakes tens
   of microseconds late in a virtual machine, and its core may go to another process
   meanwhile (OpenMP runtimes spin for 0.2 ms and more before they sleep).  The spin yields
   the CPU every 32 turns: when the kernel puts both threads on one CPU (as it may after the
   process slept), a spin that did not yield kept the other thread off the CPU for the whole
   0.2 ms at every barrier (benchmarks/RESULTS.md, "Particle filter kernel").
   It returns whether the run is to stop: the last thread to arrive reads the stop flag
   (NULL: never) and publishes it with the new generation, so every thread leaves a barrier
   with the same answer (a thread reads it before it arrives at the next barrier, which
   cannot open before, so no later generation overwrites it first). */
#if defined(__x86_64__) || defined(__i386__)
#define pfk_PAUSE() __builtin_ia32_pause()
#else
#define pfk_PAUSE() ((void) 0)
#endif
#define pfk_SPIN_NS 200000L
typedef struct {
  pthread_mutex_t mu; pthread_cond_t cv; int count, T, halt; unsigned gen; const volatile int* stop;
} pfk_barrier;
static int pfk_bwait(pfk_barrier* b) {
  unsigned g;
  long i;
  struct timespec t0, t1;
  if (b->T == 1) return b->stop && *b->stop;
  g = __atomic_load_n(&b->gen, __ATOMIC_ACQUIRE);
  if (__atomic_add_fetch(&b->count, 1, __ATOMIC_ACQ_REL) == b->T) {
    __atomic_store_n(&b->count, 0, __ATOMIC_RELAXED);
    b->halt = b->stop && *b->stop;  /* published by the release of gen below */
    pthread_mutex_lock(&b->mu);
    __atomic_store_n(&b->gen, g + 1u, __ATOMIC_RELEASE);
    pthread_cond_broadcast(&b->cv);
    pthread_mutex_unlock(&b->mu);
    return b->halt;
  }
  clock_gettime(CLOCK_MONOTONIC, &t0);
  for (i = 1;; ++i) {  /* spin for at most pfk_SPIN_NS (the clock every 32 turns) */
    if (__atomic_load_n(&b->gen, __ATOMIC_ACQUIRE) != g) return b->halt;
    pfk_PAUSE();
    if (i % 32) continue;
    sched_yield();
    clock_gettime(CLOCK_MONOTONIC, &t1);
    if ((t1.tv_sec - t0.tv_sec) * 1000000000L + (t1.tv_nsec - t0.tv_nsec) > pfk_SPIN_NS) break;
  }
  pthread_mutex_lock(&b->mu);
  while (__atomic_load_n(&b->gen, __ATOMIC_ACQUIRE) == g) pthread_cond_wait(&b->cv, &b->mu);
  pthread_mutex_unlock(&b->mu);
  return b->halt;
}

/* The fallback to one thread.  Two threads are slower than one where the other core is busy:
   a thread made by the call may wait milliseconds for a CPU while the other waits for it at
   the step's first barrier, and a thread taken off its CPU holding a chunk keeps the other
   waiting (benchmarks/RESULTS.md, "Particle filter: two threads").  So each thread notes,
   for its moves of a step, when it started (wall), the CPU time they took and when it
   reached the barrier; after the barrier every thread reads the same notes and computes the
   efficiency so far, E = sum of the threads' CPU times / (T x sum of the spans from thread
   0's start to the last arrival), over the steps so far (a speed-up of T E at most: E < 1/2
   is slower than one thread); when E < pfk_solo_eff (0.6) the run goes on in thread 0 alone
   (the others leave after that barrier).  All threads take the same decision from the same
   numbers, and the numbers of a run depend neither on T nor on who took which chunk, so
   neither on the fallback. */
static double pfk_solo_eff = 0.6;  /* PFK_SOLO sets it (tests) */
static double pfk_now(clockid_t clk) {
  struct timespec t;
  clock_gettime(clk, &t);
  return (double) t.tv_sec * 1e9 + (double) t.tv_nsec;
}
/* notes: per thread [start, CPU, arrival] (ns); sums: [CPU, spans] of the steps so far */
static int pfk_solo(const double (*notes)[3], int T, double* sums) {
  double last = notes[0][2];
  int tau;
  for (tau = 0; tau < T; ++tau) {
    sums[0] += notes[tau][1];
    if (notes[tau][2] > last) last = notes[tau][2];
  }
  sums[1] += last - notes[0][0];
  return sums[0] < pfk_solo_eff * T * sums[1];
}

static double pfk_join_ns = 200000;  /* how long thread 0 waits for the others to join (pfk_join) */
static int pfk_check_idle = 1;  /* whether a run looks for idle CPUs first (pfk_idle_cpus) */

/* symmon (tests, benchmarks): the efficiency below which a run goes on in one thread (above
   1: every run of several threads goes on alone after its first step's moves; 0: never), how
   long thread 0 waits for the threads it made to join (ns), and whether a run looks for idle
   CPUs first; returns the former efficiency. */
CASADI_SYMBOL_EXPORT double PFK_SOLO(double eff, double join_ns, int check_idle) {
  const double was = pfk_solo_eff;
  pfk_solo_eff = eff;
  pfk_join_ns = join_ns;
  pfk_check_idle = check_idle;
  return was;
}

/* The CPUs idle now, by the machine's CPUs less its runnable tasks (this thread one of them;
   /proc/loadavg's fourth field, an instant count), or -1 where that is not known: a run takes
   a thread more than this only where a CPU is free, else it starts none (~10 us a call; a run
   of several threads is at least tens of microseconds a step).  pfk_join and pfk_solo catch
   what this instant misses. */
static long pfk_idle_cpus(void) {
#ifdef __linux__
  FILE* f = fopen("/proc/loadavg", "r");
  long running = 0, cpus = sysconf(_SC_NPROCESSORS_ONLN);
  int got = f ? fscanf(f, "%*f %*f %*f %ld", &running) : 0;
  if (f) fclose(f);
  return got == 1 && cpus > 0 ? (cpus > running ? cpus - running : 0) : -1;
#else
  return -1;
#endif
}

/* Per chunk of CHUNK particles: [max t, bad, sum e, sum e^2, sum e x (or sin), sum e cos]. */
#define pfk_PW (4 + 2 * PFK_NX)
/* r_q = exp(m_q - m): a chunk's exponentials about its maximum m_q to the step's m (0 for a
   chunk of zero weights, m_q = -inf) */
#define pfk_RATIO(mq, m) ((mq) == -INFINITY ? 0.0 : exp((mq) - (m)))
/* Doubles of a thread's buffers (the body's notes). */
#define pfk_BUF (PFK_LD * PFK_NR + PFK_LD * PFK_NO + 2 * PFK_LD + PFK_NO + PFK_BLOCK / 8 + 1)

typedef struct {
  const casadi_real* P; casadi_int K, N, nch; casadi_real *X0, *Xn0, *t, *e, *lw, *sc, *hx, *part;
  unsigned long long* st; const casadi_real *zext, *uext, *jext, *m0, *L0; const casadi_int* opt; const casadi_real* fl;
  casadi_real *o_ll, *o_ess, *o_res, *o_x, *o_P, *o_xp, *o_Pp, *o_hm, *o_hS, *cov, *L;
  casadi_real mu[PFK_NX];  /* the weighted mean the shrink kernel shrinks towards */
  casadi_int *fail, *idx; pfk_barrier bar; int T; pthread_mutex_t gate;
  /* each thread's notes of its moves of a step (pfk_solo), by step parity (a thread writes
     step k + 2's only after every thread has read step k's at step k + 1's barrier) */
  double notes[2][64][3];
  casadi_int cnt[2][2];  /* the next chunk to claim, by step parity: the moves', the walks' */
} pfk_ctx;

/* Systematic resampling's points are pt + i, i = 0 ... N - 1, not stored (the serial fill and
   the walk's reads of N numbers saved); other schemes' are an array.
   The lowest i in [p, hi) with the systematic point pt + i >= v (hi if none): the guess
   ceil(v - pt), moved until the points' own comparisons hold on both sides (it is off by
   one only where v is within rounding of a point), so the index a search by those
   comparisons finds, without branches that depend on the weights. */
static inline casadi_int pfk_first(casadi_real pt, casadi_real v, casadi_int p, casadi_int hi) {
  const casadi_real g = ceil(v - pt);
  casadi_int i;
  /* the guess inside (p, hi) and both comparisons holding: the loops below would keep it
     (g - 1 is exact, the double of i - 1), without the conversions of i */
  if (g > (casadi_real) p && g < (casadi_real) hi && !(pt + (g - 1) >= v) && !(pt + g < v)) return (casadi_int) g;
  i = g <= (casadi_real) p ? p : g >= (casadi_real) hi ? hi : (casadi_int) g;
  while (i > p && pt + (casadi_real) (i - 1) >= v) --i;
  while (i < hi && pt + (casadi_real) i < v) ++i;
  return i;
}

/* The lowest index i in [0, N) of the ascending points with point i >= v (N if none). */
static casadi_int pfk_lower(const casadi_real* sc, casadi_real pt, casadi_int N, casadi_real v) {
  casadi_int lo = 0, hi = N, mid;
  if (!sc) return pfk_first(pt, v, 0, N);
  while (lo < hi) { mid = (lo + hi) / 2; if (sc[mid] < v) lo = mid + 1; else hi = mid; }
  return lo;
}

/* The picks of input chunk q: it holds the points in [S_q, S_(q+1)) x scale, S_q = off
   the sum of e over the chunks before it (part: the chunks' [m_q, -, sum e', ...], e_i =
   exp(m_q - m) e'_i, or e_i = e[i] when esc); point i (pts[i], or pt + i for systematic
   points, pts NULL) takes the first particle j of its chunk whose cumulative weight exceeds
   it (the chunk's last if none): idx[i] = j, or row j of Xn copied to row i of X (X not NULL).
   Systematic points go by particle (its points [i, b) at once; b from lo, not from i, so
   that no chain of dependences runs through i), other points by point; the same picks. */
static void pfk_pick_chunk(const casadi_real* e, const casadi_real* part, casadi_real m, int esc, casadi_int N,
    casadi_int nch, casadi_int q, casadi_real off, casadi_real scale, const casadi_real* pts, casadi_real pt,
    casadi_int* restrict idx, casadi_real* X, const casadi_real* Xn) {
  const casadi_int end = (q + 1) * PFK_CHUNK < N ? (q + 1) * PFK_CHUNK : N;
  const casadi_int lo = q == 0 ? 0 : pfk_lower(pts, pt, N, off * scale);
  casadi_real r = esc ? 1 : pfk_RATIO(part[q * pfk_PW], m), cum;  /* e_i = r e[i] */
  casadi_int i, j = q * PFK_CHUNK, b, hi;
  cum = (off + r * e[j]) * scale;
  off += pfk_RATIO(part[q * pfk_PW], m) * part[q * pfk_PW + 2];
  hi = q == nch - 1 ? N : pfk_lower(pts, pt, N, off * scale);
  r *= scale;
  if (pts) {
    for (i = lo; i < hi; ++i) {
      while (cum <= pts[i] && j < end - 1) cum += e[++j] * r;
      if (X) memcpy(X + i * PFK_NX, Xn + j * PFK_NX, PFK_NX * sizeof(casadi_real));
      else idx[i] = j;
    }
    return;
  }
  for (i = lo; i < hi; cum += e[++j] * r) {  /* b = hi at j = end - 1: j stays in the chunk */
    b = j < end - 1 ? pfk_first(pt, cum, lo, hi) : hi;
    if (X) for (; i < b; ++i) memcpy(X + i * PFK_NX, Xn + j * PFK_NX, PFK_NX * sizeof(casadi_real));
    else if (b - i <= 4 && i + 4 <= hi) {  /* four stores (one vector); later particles overwrite the extra */
      idx[i] = idx[i + 1] = idx[i + 2] = idx[i + 3] = j;
      i = b;
    } else for (; i < b; ++i) idx[i] = j;
    if (i >= hi) break;
  }
}

/* The picks of every chunk in chunk order (off: the sum of the chunks before, as the body's). */
static void pfk_picks(const casadi_real* e, const casadi_real* part, casadi_real m, int esc, casadi_int N,
    casadi_int nch, casadi_real scale, const casadi_real* pts, casadi_real pt, casadi_int* restrict idx) {
  casadi_real off = 0;
  casadi_int q;
  for (q = 0; q < nch; ++q) {
    pfk_pick_chunk(e, part, m, esc, N, nch, q, off, scale, pts, pt, idx, 0, 0);
    off += pfk_RATIO(part[q * pfk_PW], m) * part[q * pfk_PW + 2];
  }
}

/* symmon: the picks of N weights e (chunks of CHUNK, each chunk's sum in chunk order) for the
   ascending points pts on [0, N), or pt + i when pts is NULL, into idx (tests: the two walks
   give the same picks). */
CASADI_SYMBOL_EXPORT int PFK_PICK(const casadi_real* e, casadi_int N, const casadi_real* pts, casadi_real pt,
    casadi_int* idx) {
  const casadi_int nch = (N + PFK_CHUNK - 1) / PFK_CHUNK;
  casadi_real* part = (casadi_real*) calloc(nch * pfk_PW, sizeof(casadi_real));
  casadi_real s = 0;
  casadi_int q, i;
  if (!part) return 1;
  for (q = 0; q < nch; ++q) {
    for (i = q * PFK_CHUNK; i < N && i < (q + 1) * PFK_CHUNK; ++i) part[q * pfk_PW + 2] += e[i];
    s += part[q * pfk_PW + 2];
  }
  pfk_picks(e, part, 0, 1, N, nch, (casadi_real) N / s, pts, pt, idx);
  free(part);
  return 0;
}

/* Thread tau's share of the K steps: the moves and the walks by chunks claimed in turn (a
   thread that is ahead takes more: the threads' cores need not run at one speed, nor do the
   walks' chunks hold as many points), the other passes by its fixed chunks [c0, c1); every
   reduction is by chunk, in chunk order, so the numbers depend neither on T nor on who took
   which chunk.  offs: nch numbers, the sum of e over the chunks before each. */
static int pfk_body(pfk_ctx* c, int tau, casadi_int* iw, casadi_real* w, casadi_real* buf, casadi_real* offs) {
  const casadi_int N = c->N, nch = c->nch;
  casadi_int c0 = nch * tau / c->T, c1 = nch * (tau + 1) / c->T;
  casadi_int a0 = c0 * PFK_CHUNK, a1 = c1 * PFK_CHUNK < N ? c1 * PFK_CHUNK : N;
  int T = c->T;  /* the threads now (pfk_solo) */
  double sums[2] = {0, 0}, w0 = 0, u0 = 0;
  const casadi_real* arg[PFK_SZ_ARG];
  casadi_real* res[PFK_SZ_RES];
  casadi_real *X = c->X0, *Xn = c->Xn0, *tmp, *xi, *pc;
  const casadi_real* pk;
  casadi_real ti, m, mq, r, s, s2, lse, lsp = 0, ei, cum, zr[PFK_NQ], eps[PFK_NX], sx[PFK_NX], sn[PFK_NX], cs[PFK_NX];
  const casadi_real log_n = log((casadi_real) N);
  /* rsl: this thread's copy of the resampling stream; every thread draws a systematic
     resampling's point from it (no barrier), tau 0 the others, and writes it back at the end */
  uint64_t* rs = (uint64_t*) c->st + 4 * nch, ls[4 * SYMMON_LANES], rsl[4];
  casadi_int i, j, k, q, a, b, bad, redo, end, b0, nb;
  /* this thread's buffers: the rows [x, z] of a block and its outputs [x', nu, h] by columns,
     A nu and |A nu|^2 of one component, one row, the vector loop's flags */
  casadi_real *rb = buf, *blk = rb + PFK_LD * PFK_NR, *wz = blk + PFK_LD * PFK_NO, *acc = wz + PFK_LD, *row = acc + PFK_LD;
  unsigned char* odd = (unsigned char*) (row + PFK_NO);
  const int want_pred = c->o_xp || c->o_Pp || c->o_hm, reg = (int) c->opt[1], oc = (int) c->opt[3];
  /* gath: the particle i is X's row idx[i] (the last resampling's pick, not copied: the next
     move reads through idx, which saves the gather's pass over memory) */
  int gath = 0;
  memcpy(rsl, rs, sizeof rsl);
  /* uni: every log-weight is -log N (after a resampling, and at the start), not stored in lw:
     the pass that wrote them and the move's reads saved; lw written at the end */
  int uni = 1, esc, sysm = !c->uext && c->opt[0] == 0;
  /* col: the step's ESS below the collapse floor (with on_collapse: resampled, then moved by its
     kernel); jit: the particles move by a kernel after this step's resampling */
  int col, jit;
  casadi_real psys = 0;
  casadi_real* part;
  if (c->m0) for (q = c0; q < c1; ++q) {  /* the prior x0 = m + L z, z the first normals of chunk q's stream */
    end = (q + 1) * PFK_CHUNK < N ? (q + 1) * PFK_CHUNK : N;
    pfk_draw((uint64_t*) c->st + 4 * q, (end - q * PFK_CHUNK) * PFK_NX, X + q * PFK_CHUNK * PFK_NX);
    for (i = q * PFK_CHUNK; i < end; ++i) {
      xi = X + i * PFK_NX;
      memcpy(eps, xi, sizeof eps);
      for (a = 0; a < PFK_NX; ++a) {
        if (c->opt[2]) ei = c->L0[a * PFK_NX + a] * eps[a];  /* a diagonal L */
        else for (ei = 0, b = 0; b < PFK_NX; ++b) ei += c->L0[a * PFK_NX + b] * eps[b];
        xi[a] = ei + c->m0[a];
        if (pfk_ax[a]) xi[a] = pfk_wrap(xi[a]);
      }
    }
  }
  if (c->m0) pfk_bwait(&c->bar);  /* the moves read any chunk's prior */
  for (k = 0; k < c->K; ++k) {
    if (T > 1) { w0 = pfk_now(CLOCK_MONOTONIC); u0 = pfk_now(CLOCK_THREAD_CPUTIME_ID); }
    arg[2] = pk = c->P + k * PFK_N_P;
    part = c->part + (k & 1) * nch * pfk_PW;  /* by parity: a thread's next move may write
                                                     its chunks' sums while another reads these */
    for (;;) {  /* move and weigh, chunk q (claimed), in blocks of PFK_BLOCK particles */
      uint64_t* lq;
      if (c->bar.stop && *c->bar.stop) break;  /* no more chunks: the barrier below stops the run */
      q = __atomic_fetch_add(&c->cnt[k & 1][0], 1, __ATOMIC_RELAXED);
      if (q >= nch) break;
      lq = (uint64_t*) c->st + 4 * (nch + 1) + 4 * SYMMON_LANES * q;  /* chunk q's lanes */
      pfk_lanes_in(lq, ls);
      end = (q + 1) * PFK_CHUNK < N ? (q + 1) * PFK_CHUNK : N;
      m = -INFINITY;
      bad = 0;
      for (b0 = q * PFK_CHUNK; b0 < end; b0 += PFK_BLOCK) {
        nb = end - b0 < PFK_BLOCK ? end - b0 : PFK_BLOCK;
        /* the rows [x_i, z_i] by columns; the normals column by column from the chunk's
           lanes (particle i from lane i mod SYMMON_LANES; a last group past nb fills the
           column's spare rows: ld >= 8 ceil(nb / 8)) */
        for (i = 0; i < nb; ++i) {
          const casadi_real* xr = X + (gath ? c->idx[b0 + i] : b0 + i) * PFK_NX;
          for (j = 0; j < PFK_NX; ++j) rb[j * PFK_LD + i] = xr[j];
        }
        if (c->zext) {
          for (i = 0; i < nb; ++i) for (j = 0; j < PFK_NQ; ++j) rb[(PFK_NX + j) * PFK_LD + i] = c->zext[(k * N + b0 + i) * PFK_NQ + j];
        } else {
          for (j = 0; j < PFK_NQ; ++j) symmon_normal_lanes(ls, rb + (PFK_NX + j) * PFK_LD, (nb + SYMMON_LANES - 1) / SYMMON_LANES * SYMMON_LANES);
        }
#if PFK_VECTORISED
        if (PFK_VEC(rb, arg[2], blk, nb, odd)) for (i = 0; i < nb; ++i) {
          if (!odd[i]) continue;
          for (j = 0; j < PFK_NQ; ++j) zr[j] = rb[(PFK_NX + j) * PFK_LD + i];
          arg[0] = X + (gath ? c->idx[b0 + i] : b0 + i) * PFK_NX; arg[1] = zr;
          res[0] = row; res[1] = row + PFK_NX; res[2] = row + PFK_NX + PFK_NY;
          if (PFK_F(arg, res, iw, w, 0)) bad = 2;
          for (j = 0; j < PFK_NO; ++j) blk[j * PFK_LD + i] = row[j];
        }
#else
        for (i = 0; i < nb; ++i) {
          for (j = 0; j < PFK_NQ; ++j) zr[j] = rb[(PFK_NX + j) * PFK_LD + i];
          arg[0] = X + (gath ? c->idx[b0 + i] : b0 + i) * PFK_NX; arg[1] = zr;
          res[0] = row; res[1] = row + PFK_NX; res[2] = row + PFK_NX + PFK_NY;
          if (PFK_F(arg, res, iw, w, 0)) bad = 2;
          for (j = 0; j < PFK_NO; ++j) blk[j * PFK_LD + i] = row[j];
        }
#endif
        /* the log-density c - |A nu|^2 / 2 of the measured components (another's nu, maybe
           not finite, never enters), A = pk[o_A ...] by columns, by loops over the block */
        for (i = 0; i < nb; ++i) acc[i] = 0;
        for (a = 0; a < PFK_NY; ++a) {
          if (pk[PFK_O_MASK + a] == 0) continue;
          for (i = 0; i < nb; ++i) wz[i] = 0;
          for (b = 0; b < PFK_NY; ++b) {
            const casadi_real A_ab = pk[PFK_O_A + b * PFK_NY + a], *nu = blk + (PFK_NX + b) * PFK_LD;
            if (pk[PFK_O_MASK + b] == 0) continue;
            for (i = 0; i < nb; ++i) wz[i] += A_ab * nu[i];
          }
          for (i = 0; i < nb; ++i) acc[i] += wz[i] * wz[i];
        }
        for (i = 0; i < nb; ++i) {
          xi = Xn + (b0 + i) * PFK_NX;
          for (j = 0; j < PFK_NX; ++j) xi[j] = blk[j * PFK_LD + i];
          if (c->hx) for (j = 0; j < PFK_NY; ++j) c->hx[(b0 + i) * PFK_NY + j] = blk[(PFK_NX + PFK_NY + j) * PFK_LD + i];
          /* the last step's log-weight t - lse, kept in lw (the predicted moments, the end) */
          ti = (uni ? -log_n : (c->lw[b0 + i] = c->t[b0 + i] - lsp)) + (-0.5 * acc[i] + pk[PFK_N_P - 1]);
          c->t[b0 + i] = ti;
          if (ti != ti || ti == INFINITY) bad |= 1;
          for (j = 0; j < PFK_NX; ++j) if (!isfinite(xi[j])) bad |= 1;
          if (ti > m) m = ti;
        }
      }
      pfk_lanes_out(ls, lq);
      /* the chunk's exponentials e'_i = exp(t_i - m_q) about its own maximum m_q and their
         sums, while its x' and t are in the cache (the step's maximum scales them after the
         barrier, exactly as exp(m_q - max t)); by vecmath's sm_exp (within 1 ulp,
         vectorised), an argument beyond its range by libm's exp */
      b0 = q * PFK_CHUNK;
      mq = m == -INFINITY ? 0 : m;  /* every t_i = -inf: e' = 0 */
      {
        const casadi_real* restrict tq = c->t;
        casadi_real* restrict eq = c->e;
        for (i = b0; i < end; ++i) eq[i] = sm_exp(tq[i] - mq);
      }
      s = 0; s2 = 0;
      for (j = 0; j < PFK_NX; ++j) sx[j] = cs[j] = 0;
      for (i = b0; i < end; ++i) {
        ei = c->e[i];
        if (!sm_exp_ordinary(c->t[i] - mq)) c->e[i] = ei = exp(c->t[i] - mq);
        s += ei;
        s2 += ei * ei;
        xi = Xn + i * PFK_NX;
#if PFK_ANGLES
        for (j = 0; j < PFK_NX; ++j) {
          if (pfk_ax[j]) { sx[j] += ei * sin(xi[j]); cs[j] += ei * cos(xi[j]); }
          else sx[j] += ei * xi[j];
        }
#else
        for (j = 0; j < PFK_NX; ++j) sx[j] += ei * xi[j];
#endif
      }
      pc = part + q * pfk_PW;
      pc[0] = m;
      pc[1] = (casadi_real) bad;
      pc[2] = s; pc[3] = s2;
      for (j = 0; j < PFK_NX; ++j) { pc[4 + j] = sx[j]; pc[4 + PFK_NX + j] = cs[j]; }
    }
    /* the step's stop: seen by every thread at this barrier (a thread that stopped claiming
       chunks saw the flag set, and the last to arrive reads it after that) */
    if (T > 1) {
      c->notes[k & 1][tau][0] = w0;
      c->notes[k & 1][tau][1] = pfk_now(CLOCK_THREAD_CPUTIME_ID) - u0;
      c->notes[k & 1][tau][2] = pfk_now(CLOCK_MONOTONIC);
    }
    if (pfk_bwait(&c->bar)) return PFK_STOPPED;
    if (T > 1 && pfk_solo((const double (*)[3]) c->notes[k & 1], T, sums)) {  /* one thread from here on (pfk_solo) */
      if (tau > 0) return 0;
      T = c->bar.T = 1;
      c0 = 0; c1 = nch; a0 = 0; a1 = N;
    }
    if (tau == 0) c->cnt[k & 1][0] = 0;  /* every claim of this step is over; the next is at k + 2 */
    m = -INFINITY;
    bad = 0;
    for (q = 0; q < nch; ++q) {
      if (part[q * pfk_PW] > m) m = part[q * pfk_PW];
      bad |= (casadi_int) part[q * pfk_PW + 1];
    }
    if (bad & 2) return 1;
    if (bad || !isfinite(m)) { if (tau == 0) *c->fail = k; return 3; }
    if (want_pred) {  /* the predicted moments, with the weights before the update */
      for (i = a0; i < a1; ++i) c->sc[i] = exp(uni ? -log_n : c->lw[i]);
      pfk_bwait(&c->bar);
      if (tau == 0) {
        if (c->o_xp || c->o_Pp) pfk_mom(Xn, N, PFK_NX, c->sc, 1.0, pfk_ax, c->o_xp ? c->o_xp + k * PFK_NX : sn,
                                           c->o_Pp ? c->o_Pp + k * PFK_NX * PFK_NX : 0);
        if (c->o_hm) pfk_mom(c->hx, N, PFK_NY, c->sc, 1.0, pfk_ay, c->o_hm + k * PFK_NY, c->o_hS + k * PFK_NY * PFK_NY);
      }
    }
    /* the chunks' sums scaled by r_q = exp(m_q - m) (e_i = r_q e'_i), added in chunk order */
    s = 0; s2 = 0;
    for (j = 0; j < PFK_NX; ++j) sx[j] = cs[j] = 0;
    for (q = 0; q < nch; ++q) {
      pc = part + q * pfk_PW;
      r = pfk_RATIO(pc[0], m);
      offs[q] = s;
      s += r * pc[2]; s2 += r * r * pc[3];
      for (j = 0; j < PFK_NX; ++j) { sx[j] += r * pc[4 + j]; cs[j] += r * pc[4 + PFK_NX + j]; }
    }
    col = oc && s * s / s2 < c->fl[2];
    jit = reg || col;
    esc = c->o_P || jit;
    if (esc) {  /* e_i itself, for the covariance about the mean (tau 0, after the barrier) */
      for (q = c0; q < c1; ++q) {
        end = (q + 1) * PFK_CHUNK < N ? (q + 1) * PFK_CHUNK : N;
        r = pfk_RATIO(part[q * pfk_PW], m);
        for (i = q * PFK_CHUNK; i < end; ++i) c->e[i] *= r;
      }
      pfk_bwait(&c->bar);
    }
    lse = m + log(s);
    redo = s * s / s2 <= c->fl[0] || col;
    if (tau == 0) {
      c->o_ll[k] = lse;
      c->o_ess[k] = s * s / s2;
      c->o_res[k] = redo ? (col ? 2 : 1) : 0;  /* 2: resampled and moved by the collapse's kernel */
      if (c->o_x) for (j = 0; j < PFK_NX; ++j) c->o_x[k * PFK_NX + j] = pfk_ax[j] ? atan2(sx[j], cs[j]) : sx[j] / s;
      if (c->o_P || (redo && jit))  /* the covariance about the mean */
        pfk_mom(Xn, N, PFK_NX, c->e, s, pfk_ax, c->mu, c->o_P ? c->o_P + k * PFK_NX * PFK_NX : c->cov);
    }
    /* tau 0 reads e, hx, sc of every chunk above: the next move writes them */
    if (want_pred || esc) pfk_bwait(&c->bar);
    if (!redo) {  /* the log-weights t - lse: by the next move (lw), or at the end */
      lsp = lse;
      uni = 0;
      tmp = X; X = Xn; Xn = tmp;
      gath = 0;
      continue;
    }
    if (sysm) psys = symmon_uniform(rsl);  /* the points psys + i, not stored */
    if (tau == 0) {  /* resampling points, ascending on [0, N) */
      casadi_real* sc = c->sc;
      if (c->uext) memcpy(sc, c->uext + k * N, N * sizeof(casadi_real));
      else if (c->opt[0] == 1) { for (i = 0; i < N; ++i) sc[i] = symmon_uniform(rsl) + (casadi_real) i; }
      else if (c->opt[0] == 2) {  /* sorted uniforms as normalised sums of exponential spacings */
        cum = 0;
        for (i = 0; i < N; ++i) { cum += -log1p(-symmon_uniform(rsl)); sc[i] = cum; }
        cum += -log1p(-symmon_uniform(rsl));
        for (i = 0; i < N; ++i) sc[i] *= (casadi_real) N / cum;
      }
      if (jit) pfk_chol(c->o_P ? c->o_P + k * PFK_NX * PFK_NX : c->cov, c->L);
    }
    if (!sysm || jit) pfk_bwait(&c->bar);
    for (;;) {  /* the walk along the cumulative weights, by input chunk (claimed) */
      q = __atomic_fetch_add(&c->cnt[k & 1][1], 1, __ATOMIC_RELAXED);
      if (q >= nch) break;
      pfk_pick_chunk(c->e, part, m, esc, N, nch, q, offs[q], (casadi_real) N / s, sysm ? 0 : c->sc, psys, c->idx,
                     jit ? X : 0, Xn);
    }
    pfk_bwait(&c->bar);
    if (tau == 0) c->cnt[k & 1][1] = 0;
    uni = 1;
    if (!jit) {  /* the moved particles, read through idx by the next move */
      tmp = X; X = Xn; Xn = tmp;
      gath = 1;
      continue;
    }
    /* regularisation: x += h L eps (Musso, Oudjane & Le Gland 2001); at a collapse with the
       shrink kernel (Liu & West 2001) x = mu + a (x - mu) + h L eps, a^2 + h^2 = 1 */
    for (q = c0; q < c1; ++q) {
      uint64_t* sg = (uint64_t*) c->st + 4 * q, sl[4];
      memcpy(sl, sg, sizeof sl);
      end = (q + 1) * PFK_CHUNK < N ? (q + 1) * PFK_CHUNK : N;
      for (i = q * PFK_CHUNK; i < end; ++i) {
        if (c->jext) memcpy(eps, c->jext + (k * N + i) * PFK_NX, PFK_NX * sizeof(casadi_real));
        else for (j = 0; j < PFK_NX; ++j) eps[j] = symmon_normal(sl);
        xi = X + i * PFK_NX;
        for (a = 0; a < PFK_NX; ++a) {
          ei = 0;
          for (b = 0; b <= a; ++b) ei += c->L[a * PFK_NX + b] * eps[b];
          if (col && oc == 2) {
            cum = pfk_ax[a] ? pfk_wrap(xi[a] - c->mu[a]) : xi[a] - c->mu[a];
            xi[a] = c->mu[a] + c->fl[3] * cum + c->fl[1] * ei;
          } else xi[a] += c->fl[1] * ei;
          if (pfk_ax[a]) xi[a] = pfk_wrap(xi[a]);
        }
      }
      memcpy(sg, sl, sizeof sl);
    }
    pfk_bwait(&c->bar);  /* the next move reads any chunk */
  }
  for (i = a0; i < a1; ++i) c->lw[i] = uni ? -log_n : c->t[i] - lsp;
  if (gath) {  /* the last pick, copied into the other buffer (other threads read X's rows) */
    for (i = a0; i < a1; ++i) memcpy(Xn + i * PFK_NX, X + c->idx[i] * PFK_NX, PFK_NX * sizeof(casadi_real));
    tmp = X; X = Xn; Xn = tmp;
    pfk_bwait(&c->bar);
  }
  if (X != c->X0) memcpy(c->X0 + a0 * PFK_NX, X + a0 * PFK_NX, (a1 - a0) * PFK_NX * sizeof(casadi_real));  /* own rows */
  if (tau == 0) memcpy(rs, rsl, sizeof rsl);
  return 0;
}

typedef struct { pfk_ctx* c; int tau; casadi_int* iw; casadi_real* w; casadi_real* buf; casadi_real* offs; int ret; } pfk_arg;

/* The threads a run makes join it only if they start in time: on a busy machine a new thread
   may wait milliseconds for a CPU, and thread 0 would wait for it at the first barrier.  So
   thread 0 waits at most pfk_join_ns (0.2 ms) for them, then closes the run: a thread that starts
   later leaves at once, and the run goes on with those that joined (the numbers do not
   depend on T).  The threads are detached; what a latecomer reads is this struct on the heap
   (not the run's frame, which may be gone), freed by the last of its users; thread 0 waits
   for the threads that joined to count themselves done. */
#define pfk_CLOSED 0x40000000
typedef struct { int state, refs, done; pfk_ctx* c; pfk_arg* args; } pfk_join;
static void pfk_release(pfk_join* js) {
  if (__atomic_sub_fetch(&js->refs, 1, __ATOMIC_ACQ_REL) == 0) free(js);
}
static void* pfk_thread(void* p) {
  pfk_join* js = (pfk_join*) p;
  pfk_arg* a;
  int s = __atomic_load_n(&js->state, __ATOMIC_ACQUIRE);
  do {
    if (s & pfk_CLOSED) { pfk_release(js); return 0; }  /* too late: the run goes on without it */
  } while (!__atomic_compare_exchange_n(&js->state, &s, s + 1, 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE));
  a = js->args + s + 1;  /* the j-th to join is thread j */
  pthread_mutex_lock(&js->c->gate);  /* wait until T is final */
  pthread_mutex_unlock(&js->c->gate);
  a->ret = pfk_body(a->c, a->tau, a->iw, a->w, a->buf, a->offs);
  __atomic_add_fetch(&js->done, 1, __ATOMIC_RELEASE);  /* its last use of the run's frame */
  pfk_release(js);
  return 0;
}

/* symmon: the K steps of the bootstrap filter for one run on T threads over particle chunks
   (module notes).  P: K rows of the call's parameters; X holds the N initial particles (on
   return: the final ones, and lw their normalised log-weights); Xn,
   t, e, lw, sc: work (N x n, N, N, N, N); hx: N x ny or NULL; part: 2 ceil(N / CHUNK) x
   (4 + 2n); st: ceil(N / CHUNK) + 1 xoshiro states (the chunks', then the resampling
   stream), then SYMMON_LANES per chunk (the move's normals, lane by lane); zext, uext, jext: replayed move normals (K x N x nq), resampling points (K x N,
   ascending in [0, N)) and jitter normals (K x N x nx), or NULL to draw; m0, L0: the mean
   and square root (n x n, row-major) of a Gaussian prior to draw X from (the first normals
   of each chunk's stream), or NULL (X given); opt = [scheme (0 systematic, 1 stratified,
   2 multinomial), regularise, L0 diagonal, on_collapse (0 none, 1 jitter, 2 shrink)]; fl = [ESS
   threshold x N, bandwidth h, the collapse's ESS floor, the shrink a]; o_res: 1 resampled, 2
   resampled at a collapse and moved by its kernel; outputs per step (NULL: not wanted); iw, w: T work arrays of isz, wsz; stop:
   a flag another thread may set (NULL: none), polled between chunks of the moves and seen
   by every thread at the step's first barrier.  Returns 0; 1 when a generated function
   failed; 3 when a particle or weight turned non-finite (fail: the step); PFK_STOPPED when
   the flag stopped the run (its outputs part way). */
CASADI_SYMBOL_EXPORT int PFK_RUN(const casadi_real* P, casadi_int K, casadi_int N, casadi_real* X0,
    casadi_real* Xn0, casadi_real* t, casadi_real* e, casadi_real* lw, casadi_real* sc, casadi_real* hx,
    casadi_real* part, unsigned long long* st, const casadi_real* zext, const casadi_real* uext,
    const casadi_real* jext, const casadi_real* m0, const casadi_real* L0, const casadi_int* opt, const casadi_real* fl, casadi_real* o_ll, casadi_real* o_ess,
    casadi_real* o_res, casadi_real* o_x, casadi_real* o_P, casadi_real* o_xp, casadi_real* o_Pp,
    casadi_real* o_hm, casadi_real* o_hS, casadi_int* iw, casadi_real* w, casadi_int isz, casadi_int wsz,
    casadi_int T, casadi_int* fail, const volatile int* stop) {
  pfk_ctx c;
  pfk_arg args[64];
  pthread_t th[64];
  casadi_real cov[PFK_NX * PFK_NX], L[PFK_NX * PFK_NX];
  int tau, ret = 0, started = 0, joined;
  casadi_real* buf;
  pfk_join* js;
  pthread_attr_t attr;
  struct timespec t0, t1;
  long spin;
  c.P = P; c.K = K; c.N = N; c.nch = (N + PFK_CHUNK - 1) / PFK_CHUNK;
  c.X0 = X0; c.Xn0 = Xn0; c.t = t; c.e = e; c.lw = lw; c.sc = sc; c.hx = hx; c.part = part; c.st = st;
  c.zext = zext; c.uext = uext; c.jext = jext; c.m0 = m0; c.L0 = L0; c.opt = opt; c.fl = fl; c.o_ll = o_ll; c.o_ess = o_ess;
  c.o_res = o_res; c.o_x = o_x; c.o_P = o_P; c.o_xp = o_xp; c.o_Pp = o_Pp; c.o_hm = o_hm; c.o_hS = o_hS;
  c.cov = cov; c.L = L; c.fail = fail;
  memset(c.cnt, 0, sizeof c.cnt);
  c.idx = (casadi_int*) malloc((N > 0 ? N : 1) * sizeof(casadi_int));
  if (!c.idx) return 1;
  if (T > c.nch) T = c.nch;
  if (T > 64) T = 64;
  if (T > 1 && pfk_check_idle) {  /* no threads where the other CPUs are busy */
    const long idle = pfk_idle_cpus();
    if (idle >= 0 && T > idle + 1) T = idle + 1;
  }
  if (T < 1) T = 1;
  c.T = (int) T;
  buf = (casadi_real*) malloc(T * (pfk_BUF + c.nch) * sizeof(casadi_real));
  js = (pfk_join*) calloc(1, sizeof(pfk_join));
  if (!buf || !js) { free(buf); free(js); free(c.idx); return 1; }
  c.bar.T = (int) T; c.bar.count = 0; c.bar.gen = 0; c.bar.halt = 0; c.bar.stop = stop;
  pthread_mutex_init(&c.bar.mu, 0);
  pthread_cond_init(&c.bar.cv, 0);
  pthread_mutex_init(&c.gate, 0);
  pthread_mutex_lock(&c.gate);
  for (tau = 0; tau < T; ++tau) {
    args[tau].c = &c; args[tau].tau = tau; args[tau].iw = iw + tau * isz; args[tau].w = w + tau * wsz;
    args[tau].ret = 0; args[tau].buf = buf + tau * pfk_BUF; args[tau].offs = buf + T * pfk_BUF + tau * c.nch;
  }
  js->c = &c; js->args = args; js->refs = (int) T;  /* the T - 1 threads and this one */
  pthread_attr_init(&attr);
  pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
  for (tau = 1; tau < T; ++tau) {
    if (pthread_create(&th[tau], &attr, pfk_thread, js)) break;
    started = tau;
  }
  pthread_attr_destroy(&attr);
  if (started < T - 1) __atomic_sub_fetch(&js->refs, (int) (T - 1 - started), __ATOMIC_ACQ_REL);
  clock_gettime(CLOCK_MONOTONIC, &t0);
  for (spin = 1; __atomic_load_n(&js->state, __ATOMIC_ACQUIRE) < started; ++spin) {  /* pfk_join_ns at most */
    pfk_PAUSE();
    if (spin % 32) continue;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    if ((double) (t1.tv_sec - t0.tv_sec) * 1e9 + (double) (t1.tv_nsec - t0.tv_nsec) >= pfk_join_ns) break;
  }
  joined = __atomic_fetch_or(&js->state, pfk_CLOSED, __ATOMIC_ACQ_REL) & ~pfk_CLOSED;
  c.T = c.bar.T = joined + 1;  /* those that joined in time (and could be made) */
  pthread_mutex_unlock(&c.gate);
  args[0].ret = pfk_body(&c, 0, args[0].iw, args[0].w, args[0].buf, args[0].offs);
  while (__atomic_load_n(&js->done, __ATOMIC_ACQUIRE) < joined) sched_yield();
  pfk_release(js);
  pthread_mutex_destroy(&c.bar.mu);
  pthread_cond_destroy(&c.bar.cv);
  pthread_mutex_destroy(&c.gate);
  free(buf);
  free(c.idx);
  for (tau = 0; tau <= joined; ++tau) if (args[tau].ret > ret) ret = args[tau].ret;
  return ret;
}
