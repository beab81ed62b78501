/* symmon: the compiled chunk of Monte Carlo (symmon.transforms.mc_kernel): blocks of MCK_BLOCK
   rows, each computed into a block by columns (blk, MCK_BLOCK x MCK_N_OUT, after CasADi's work
   array w), by the vectorised loop MCK_VEC when g has one (MCK_VECTORISED; symmon.compile.vecmath:
   a row it flags, an atan2 or hypot argument that is zero, inf, NaN or beyond 2^+-500, is
   recomputed by CasADi's function, that is, by libm) or else by CasADi's function MCK_F row by
   row.  MCK_ROWS writes the rows out; MCK_STATS sums the blocks' cross-products into S
   (n_out x n_out, symmetric): per entry, sixteen partial sums over the rows i = 0, 1, ..., 15
   (mod 16) added in a fixed order (four vectors of AVX2: their additions do not wait for each
   other), so the numbers do not depend on the vector width, and gcc vectorises them.  Rows with
   a value that is not finite are counted (bad[0]) and the first is named (bad[1]).
   SampleKernel puts before this file the random numbers (symmon.compile.rng), the generated C
   of MCK_F, the vectorised functions and MCK_VEC when there is one, and the MCK_ macros. */
#ifndef MCK_F  /* checked alone: example macros, and what comes before this file */
#include "../compile/casadi_alone.h"
#include "../compile/rng.c"
#define MCK_F mck_model
#define MCK_VEC mck_model_vec
#define MCK_BLOCK_FN mck_model_block
#define MCK_ROWS mck_model_rows
#define MCK_SUMS mck_model_sums
#define MCK_START mck_model_start
#define MCK_SYMMETRIC mck_model_symmetric
#define MCK_STATS mck_model_stats
#define MCK_DRAW_STATS mck_model_draw_stats
#define MCK_VECTORISED 1
#define MCK_BLOCK 256
#define MCK_N_IN 2
#define MCK_N_OUT 5
#define MCK_SZ_ARG 2
#define MCK_SZ_RES 1
#define MCK_SZ_W 10
int MCK_F(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);
int MCK_VEC(const double* restrict z, const double* restrict p, double* restrict out, long long n,
            unsigned char* restrict odd);
#endif
/* symmon: the rows of m <= MCK_BLOCK samples z into blk (by columns); p is shared by every row. */
static int MCK_BLOCK_FN(const casadi_real* z, const casadi_real* p, casadi_int m, casadi_real* blk,
    casadi_int* iw, casadi_real* w) {
  const casadi_real* arg[MCK_SZ_ARG];
  casadi_real* res[MCK_SZ_RES];
  casadi_real* row = blk + MCK_BLOCK * MCK_N_OUT;
  unsigned char odd[MCK_BLOCK];
  casadi_int i, k;
  (void) odd;
  arg[1] = p;
#if MCK_VECTORISED
  if (MCK_VEC(z, p, blk, m, odd) == 0) return 0;
  for (i = 0; i < m; ++i) {
    if (!odd[i]) continue;
    arg[0] = z + i * MCK_N_IN; res[0] = row;
    if (MCK_F(arg, res, iw, w, 0)) return 1;
    for (k = 0; k < MCK_N_OUT; ++k) blk[k * MCK_BLOCK + i] = row[k];
  }
#else
  for (i = 0; i < m; ++i) {
    arg[0] = z + i * MCK_N_IN; res[0] = row;
    if (MCK_F(arg, res, iw, w, 0)) return 1;
    for (k = 0; k < MCK_N_OUT; ++k) blk[k * MCK_BLOCK + i] = row[k];
  }
#endif
  return 0;
}
/* symmon: the rows of n samples z (n × MCK_N_IN) into out (n × MCK_N_OUT). */
CASADI_SYMBOL_EXPORT int MCK_ROWS(const casadi_real* z, const casadi_real* p,
    casadi_real* out, casadi_int n, casadi_int* iw, casadi_real* w) {
  casadi_real* blk = w + MCK_SZ_W;
  casadi_int b, i, k, m;
  for (b = 0; b < n; b += MCK_BLOCK) {
    m = n - b < MCK_BLOCK ? n - b : MCK_BLOCK;
    if (MCK_BLOCK_FN(z + b * MCK_N_IN, p, m, blk, iw, w)) return 1;
    for (i = 0; i < m; ++i)
      for (k = 0; k < MCK_N_OUT; ++k) out[(b + i) * MCK_N_OUT + k] = blk[k * MCK_BLOCK + i];
  }
  return 0;
}
/* symmon: add the cross-products of the rows of m <= MCK_BLOCK samples z (rows b, b + 1, ...) to S
   (upper triangle); count the rows with a value that is not finite in bad, and copy the first
   one's z to zbad (x - x == 0 exactly when x is finite). */
static int MCK_SUMS(const casadi_real* z, const casadi_real* p, casadi_int m, casadi_int b,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {
  casadi_real* blk = w + MCK_SZ_W;
  unsigned char fin[MCK_BLOCK];
  casadi_int i, j, k, r;
  if (MCK_BLOCK_FN(z, p, m, blk, iw, w)) return 1;
  for (r = 0; r < m; ++r) fin[r] = 1;
  for (k = 0; k < MCK_N_OUT; ++k) {
    const casadi_real* c = blk + k * MCK_BLOCK;
    for (r = 0; r < m; ++r) fin[r] &= (c[r] - c[r] == 0);
  }
  for (r = 0; r < m; ++r)
    if (!fin[r]) {
      if (bad[1] < 0) { bad[1] = b + r; for (k = 0; k < MCK_N_IN; ++k) zbad[k] = z[r * MCK_N_IN + k]; }
      bad[0]++;
    }
  for (r = m; r < (m + 15) / 16 * 16; ++r)  /* pad the last block to 16 rows with zeros */
    for (k = 0; k < MCK_N_OUT; ++k) blk[k * MCK_BLOCK + r] = 0;
  for (i = 0; i < MCK_N_OUT; ++i) {
    const casadi_real* ci = blk + i * MCK_BLOCK;
    for (j = i; j < MCK_N_OUT; ++j) {
      const casadi_real* cj = blk + j * MCK_BLOCK;
      casadi_real s[16] = {0}, t[8];
      for (r = 0; r < m; r += 16)
        for (k = 0; k < 16; ++k) s[k] += ci[r + k] * cj[r + k];
      for (k = 0; k < 8; ++k) t[k] = s[k] + s[k + 8];
      S[i * MCK_N_OUT + j] += ((t[0] + t[4]) + (t[2] + t[6])) + ((t[1] + t[5]) + (t[3] + t[7]));
    }
  }
  return 0;
}
static void MCK_START(casadi_real* S, long long* bad) {
  casadi_int i;
  bad[0] = 0; bad[1] = -1;
  for (i = 0; i < MCK_N_OUT * MCK_N_OUT; ++i) S[i] = 0;
}
static void MCK_SYMMETRIC(casadi_real* S) {
  casadi_int i, j;
  for (i = 0; i < MCK_N_OUT; ++i)
    for (j = 0; j < i; ++j) S[i * MCK_N_OUT + j] = S[j * MCK_N_OUT + i];
}
/* symmon: S = the cross-products of the rows of n samples z (n_out × n_out); bad = (count, first
   index) of the rows with a value that is not finite, zbad the first one's z. */
CASADI_SYMBOL_EXPORT int MCK_STATS(const casadi_real* z, const casadi_real* p, casadi_int n,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {
  casadi_int b, m;
  MCK_START(S, bad);
  for (b = 0; b < n; b += MCK_BLOCK) {
    m = n - b < MCK_BLOCK ? n - b : MCK_BLOCK;
    if (MCK_SUMS(z + b * MCK_N_IN, p, m, b, S, bad, zbad, iw, w)) return 1;
  }
  MCK_SYMMETRIC(S);
  return 0;
}
/* symmon: MCK_STATS of n samples drawn here, a block at a time, from the xoshiro256++ stream
   s (symmon.compile.rng, advanced in place): the normals of a row in order, row after row,
   as NormalStream.fill writes them; no normal leaves the L1 cache. */
CASADI_SYMBOL_EXPORT int MCK_DRAW_STATS(uint64_t* s, const casadi_real* p, casadi_int n,
    casadi_real* S, long long* bad, casadi_real* zbad, casadi_int* iw, casadi_real* w) {
  casadi_real* z = w + MCK_SZ_W + (MCK_BLOCK + 1) * MCK_N_OUT;
  casadi_int b, i, m;
  MCK_START(S, bad);
  for (b = 0; b < n; b += MCK_BLOCK) {
    m = n - b < MCK_BLOCK ? n - b : MCK_BLOCK;
    for (i = 0; i < m * MCK_N_IN; ++i) z[i] = symmon_normal(s);
    if (MCK_SUMS(z, p, m, b, S, bad, zbad, iw, w)) return 1;
  }
  MCK_SYMMETRIC(S);
  return 0;
}
