/* symmon.compile.rng: xoshiro256++ (Blackman & Vigna 2021) and a 256-layer ziggurat
   (Marsaglia & Tsang 2000): static functions, put once in each kernel's source after the
   tables that rng._tables computes and the two macros below (rng.RNG_C). */
#include <stdint.h>
#include <string.h>
#include <math.h>
#if defined(__AVX2__)
#include <immintrin.h>
#endif
#ifndef SYMMON_ZIG_R  /* checked alone: the tables and macros of rng.RNG_C (all zero here) */
#define SYMMON_ZIG_R 3.6541528853610088
#define SYMMON_LANES 8
typedef struct { unsigned long long k; double w; } symmon_zig_layer;
static const symmon_zig_layer symmon_zig_kw[256];
static const double symmon_zig_f[257];
#endif
static inline uint64_t symmon_rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
static inline uint64_t symmon_next(uint64_t* s) {
  const uint64_t r = symmon_rotl(s[0] + s[3], 23) + s[0], t = s[1] << 17;
  s[2] ^= s[0]; s[3] ^= s[1]; s[1] ^= s[2]; s[0] ^= s[3]; s[2] ^= t; s[3] = symmon_rotl(s[3], 45);
  return r;
}
/* (int64_t) first: a signed conversion is one instruction, an unsigned 64-bit one a branch */
static inline double symmon_uniform(uint64_t* s) { return (double) (int64_t) (symmon_next(s) >> 11) * 0x1.0p-53; }
/* -x when neg is 1, x when 0: the sign bit flipped without a branch (a random sign is a
   branch mispredicted half the time: it doubled the cost of a draw); the same bits as -x. */
static inline double symmon_signed(double x, uint64_t neg) {
  uint64_t b; memcpy(&b, &x, sizeof b); b ^= neg << 63; memcpy(&x, &b, sizeof b); return x;
}
/* the rest of a normal whose first word r was just drawn from s: the layer's core, else the
   tail or the wedge, else a new word (symmon_normal is this after one word) */
static inline double symmon_normal_from(uint64_t r, uint64_t* s) {
  for (;;) {
    const int i = (int) (r & 0xff);
    const uint64_t neg = (r >> 8) & 1;
    const uint64_t m = (r >> 9) & 0xfffffffffffffULL;
    const double x = (double) (int64_t) m * symmon_zig_kw[i].w;
    if (m < symmon_zig_kw[i].k) return symmon_signed(x, neg);  /* inside the layer's core */
    if (i == 0) {  /* the tail beyond r (Marsaglia 1964) */
      double a, b;
      do {
        a = -log1p(-symmon_uniform(s)) / SYMMON_ZIG_R;
        b = -log1p(-symmon_uniform(s));
      } while (b + b <= a * a);
      return symmon_signed(SYMMON_ZIG_R + a, neg);
    }
    /* the wedge: a height uniform between the layer's bottom f(x_i) and top f(x_(i+1)) */
    if (symmon_zig_f[i] + (symmon_zig_f[i + 1] - symmon_zig_f[i]) * symmon_uniform(s) < exp(-0.5 * x * x))
      return symmon_signed(x, neg);
    r = symmon_next(s);
  }
}
static inline double symmon_normal(uint64_t* s) { return symmon_normal_from(symmon_next(s), s); }

/* SYMMON_LANES interleaved streams (lanes): s holds word w of lane l at s[w * SYMMON_LANES + l];
   count (a multiple of SYMMON_LANES) normals into out, out[g * SYMMON_LANES + l] lane l's g-th
   number, the numbers symmon_normal draws from lane l's state.  With AVX2: the lanes' states
   in eight registers for the whole count (four xoshiro256++ steps per instruction), the
   layer's core for four lanes at once ((double) m as (2^52 + m) - 2^52, exact for m < 2^52;
   k and w by one 16-byte load a lane); a lane outside its layer's core (about 1.5 %) continues
   alone by symmon_normal_from, through memory. */
#if defined(__AVX2__)
#define SYMMON_XSTEP(s0, s1, s2, s3, r) do { \
    const __m256i sum_ = _mm256_add_epi64(s0, s3), t_ = _mm256_slli_epi64(s1, 17); \
    r = _mm256_add_epi64(_mm256_or_si256(_mm256_slli_epi64(sum_, 23), _mm256_srli_epi64(sum_, 41)), s0); \
    s2 = _mm256_xor_si256(s2, s0); s3 = _mm256_xor_si256(s3, s1); s1 = _mm256_xor_si256(s1, s2); \
    s0 = _mm256_xor_si256(s0, s3); s2 = _mm256_xor_si256(s2, t_); \
    s3 = _mm256_or_si256(_mm256_slli_epi64(s3, 45), _mm256_srli_epi64(s3, 19)); } while (0)
/* the core of four words r into o[0..3]; in: the lanes inside their core (4 bits) */
static inline int symmon_zig_core4(__m256i r, double* o) {
  const __m256i idx = _mm256_and_si256(r, _mm256_set1_epi64x(0xff));
  const __m256i m = _mm256_and_si256(_mm256_srli_epi64(r, 9), _mm256_set1_epi64x(0xfffffffffffffLL));
  const __m128i il = _mm256_castsi256_si128(idx), ih = _mm256_extracti128_si256(idx, 1);
  const __m256i e02 = _mm256_inserti128_si256(_mm256_castsi128_si256(_mm_load_si128((const __m128i*) &symmon_zig_kw[_mm_cvtsi128_si64(il)])),
                                              _mm_load_si128((const __m128i*) &symmon_zig_kw[_mm_cvtsi128_si64(ih)]), 1);
  const __m256i e13 = _mm256_inserti128_si256(_mm256_castsi128_si256(_mm_load_si128((const __m128i*) &symmon_zig_kw[_mm_extract_epi64(il, 1)])),
                                              _mm_load_si128((const __m128i*) &symmon_zig_kw[_mm_extract_epi64(ih, 1)]), 1);
  const __m256i k = _mm256_unpacklo_epi64(e02, e13);
  const __m256d w = _mm256_castsi256_pd(_mm256_unpackhi_epi64(e02, e13));
  const __m256d xm = _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(m, _mm256_set1_epi64x(0x4330000000000000LL))),
                                   _mm256_set1_pd(4503599627370496.0));
  const __m256i sign = _mm256_slli_epi64(_mm256_and_si256(r, _mm256_set1_epi64x(0x100)), 55);
  _mm256_storeu_pd(o, _mm256_xor_pd(_mm256_mul_pd(xm, w), _mm256_castsi256_pd(sign)));
  return _mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(k, m)));
}
#endif
/* The lanes flagged in miss (bit l: lane l), their first words rr[l] just drawn, finished alone
   by symmon_normal_from into out[l], their states in s (word w of lane l at s[w * LANES + l]). */
static inline void symmon_lanes_finish(uint64_t* s, const uint64_t* rr, uint64_t miss, double* out) {
  uint64_t t[4];
  int l, h;
  for (l = 0; miss; ++l, miss >>= 1) {
    if (!(miss & 1)) continue;
    for (h = 0; h < 4; ++h) t[h] = s[h * SYMMON_LANES + l];
    out[l] = symmon_normal_from(rr[l], t);
    for (h = 0; h < 4; ++h) s[h * SYMMON_LANES + l] = t[h];
  }
}
static inline void symmon_normal_lanes(uint64_t* restrict s, double* restrict out, long long count) {
  long long g;
  uint64_t rr[SYMMON_LANES], miss;
#if defined(__AVX2__) && SYMMON_LANES == 8
  __m256i a0 = _mm256_loadu_si256((const __m256i*) s), b0 = _mm256_loadu_si256((const __m256i*) (s + 4));
  __m256i a1 = _mm256_loadu_si256((const __m256i*) (s + 8)), b1 = _mm256_loadu_si256((const __m256i*) (s + 12));
  __m256i a2 = _mm256_loadu_si256((const __m256i*) (s + 16)), b2 = _mm256_loadu_si256((const __m256i*) (s + 20));
  __m256i a3 = _mm256_loadu_si256((const __m256i*) (s + 24)), b3 = _mm256_loadu_si256((const __m256i*) (s + 28));
  for (g = 0; g < count; g += SYMMON_LANES) {
    __m256i ra, rb;
    SYMMON_XSTEP(a0, a1, a2, a3, ra);
    SYMMON_XSTEP(b0, b1, b2, b3, rb);
    miss = (uint64_t) (~symmon_zig_core4(ra, out + g) & 15) | (uint64_t) (~symmon_zig_core4(rb, out + g + 4) & 15) << 4;
    if (!miss) continue;
    _mm256_storeu_si256((__m256i*) s, a0); _mm256_storeu_si256((__m256i*) (s + 4), b0);
    _mm256_storeu_si256((__m256i*) (s + 8), a1); _mm256_storeu_si256((__m256i*) (s + 12), b1);
    _mm256_storeu_si256((__m256i*) (s + 16), a2); _mm256_storeu_si256((__m256i*) (s + 20), b2);
    _mm256_storeu_si256((__m256i*) (s + 24), a3); _mm256_storeu_si256((__m256i*) (s + 28), b3);
    _mm256_storeu_si256((__m256i*) rr, ra); _mm256_storeu_si256((__m256i*) (rr + 4), rb);
    symmon_lanes_finish(s, rr, miss, out + g);
    a0 = _mm256_loadu_si256((const __m256i*) s); b0 = _mm256_loadu_si256((const __m256i*) (s + 4));
    a1 = _mm256_loadu_si256((const __m256i*) (s + 8)); b1 = _mm256_loadu_si256((const __m256i*) (s + 12));
    a2 = _mm256_loadu_si256((const __m256i*) (s + 16)); b2 = _mm256_loadu_si256((const __m256i*) (s + 20));
    a3 = _mm256_loadu_si256((const __m256i*) (s + 24)); b3 = _mm256_loadu_si256((const __m256i*) (s + 28));
  }
  _mm256_storeu_si256((__m256i*) s, a0); _mm256_storeu_si256((__m256i*) (s + 4), b0);
  _mm256_storeu_si256((__m256i*) (s + 8), a1); _mm256_storeu_si256((__m256i*) (s + 12), b1);
  _mm256_storeu_si256((__m256i*) (s + 16), a2); _mm256_storeu_si256((__m256i*) (s + 20), b2);
  _mm256_storeu_si256((__m256i*) (s + 24), a3); _mm256_storeu_si256((__m256i*) (s + 28), b3);
#else
  uint64_t t[4];
  int l, h;
  for (g = 0; g < count; g += SYMMON_LANES) {
    miss = 0;
    for (l = 0; l < SYMMON_LANES; ++l) {
      for (h = 0; h < 4; ++h) t[h] = s[h * SYMMON_LANES + l];
      rr[l] = symmon_next(t);
      for (h = 0; h < 4; ++h) s[h * SYMMON_LANES + l] = t[h];
      {
        const uint64_t m = (rr[l] >> 9) & 0xfffffffffffffULL;
        out[g + l] = symmon_signed((double) (int64_t) m * symmon_zig_kw[rr[l] & 0xff].w, (rr[l] >> 8) & 1);
        if (!(m < symmon_zig_kw[rr[l] & 0xff].k)) miss |= 1ULL << l;
      }
    }
    symmon_lanes_finish(s, rr, miss, out + g);  /* about 1 lane in 70 */
  }
#endif
}
