#ifndef SYMMON_ZIG_R  /* checked alone: the generator comes first in the library's source */
#include "rng.c"
#endif
/* symmon.compile.rng: n normals of the stream s (advanced in place) into out. */
#if defined(_WIN32)
#define SYMMON_RNG_EXPORT __declspec(dllexport)
#else
#define SYMMON_RNG_EXPORT __attribute__((visibility("default")))
#endif
SYMMON_RNG_EXPORT void symmon_rng_normals(uint64_t* s, long long n, double* out) {
  long long i;
  for (i = 0; i < n; ++i) out[i] = symmon_normal(s);
}
