"""symmon's sparse product in generated C (ckernels.faster_sparse_products): swapped in, and
the same to the bit as CasADi's casadi_mtimes, on random compressed-column patterns with
dense, partly dense and scattered columns, plain and transposed."""

from __future__ import annotations


import casadi as ca
import numpy as np
import pytest

from symmon.compile.ckernels import CASADI_MTIMES, MTIMES_SPARSE, faster_sparse_products
from symmon.compile.compiled import generated_c

from test_ckernels import needs_gcc, run_comparison



def sparse_product_function() -> ca.Function:
    """z = A B + C with A block diagonal (two dense blocks and a scattered corner), B sparse."""
    sa = ca.diagcat(ca.Sparsity.dense(4, 4), ca.Sparsity.dense(3, 3), ca.Sparsity.diag(2))
    sb = ca.Sparsity.banded(9, 1)
    A, B, C = ca.MX.sym("A", sa), ca.MX.sym("B", sb), ca.MX.sym("C", 9, 9)
    return ca.Function("sprod", [A, B, C], [ca.mtimes(A, B) + C, ca.mtimes(A.T, B)])


def test_the_installed_casadis_kernel_is_the_known_one_and_is_swapped():
    # Fails when a CasADi release changes casadi_mtimes: then re-check the replacement
    # against the new definition before updating CASADI_MTIMES.
    code = generated_c(sparse_product_function())
    assert CASADI_MTIMES in code
    fast = faster_sparse_products(code)
    assert MTIMES_SPARSE in fast and CASADI_MTIMES not in fast
    assert fast.count("void casadi_mtimes(") == 1


def test_an_unknown_definition_is_left_alone():
    other = CASADI_MTIMES.replace("w[row_x[kk1]] += x[kk1]*y[kk];", "w[row_x[kk1]] -= x[kk1]*y[kk];")
    assert faster_sparse_products(other) == other
    assert faster_sparse_products("int main(void) { return 0; }") == "int main(void) { return 0; }"


_DRIVER = r"""
#include <stdio.h>
#include <string.h>
typedef double casadi_real;
typedef long long casadi_int;
{orig}
{new}
static unsigned long long s = 88172645463325252ULL;
static unsigned long long next(void) {{ s ^= s << 13; s ^= s >> 7; s ^= s << 17; return s; }}
static double rnd(void) {{ return (double)(next() >> 11) / 9007199254740992.0 - 0.5; }}
/* A random nr x nc pattern: each column empty, dense, a run of consecutive rows, or scattered. */
static casadi_int pattern(casadi_int* sp, casadi_int nr, casadi_int nc) {{
  casadi_int c, r, n = 0, *colind = sp + 2, *row = sp + 3 + nc;
  sp[0] = nr; sp[1] = nc; colind[0] = 0;
  for (c = 0; c < nc; ++c) {{
    int kind = next() % 4;
    casadi_int a = next() % nr, b = a + next() % (nr - a);
    for (r = 0; r < nr; ++r)
      if (kind == 1 || (kind == 2 && r >= a && r <= b) || (kind == 3 && next() % 3 == 0)) row[n++] = r;
    colind[c + 1] = n;
  }}
  return n;
}}
int main(void) {{
  static casadi_int spx[3 + 40 + 1600], spy[3 + 40 + 1600], spz[3 + 40 + 1600];
  static double x[1600], y[1600], z1[1600], z2[1600], w1[40], w2[40];
  const casadi_int sizes[] = {{1, 2, 3, 5, 8, 13, 31}};
  int a, b, c, tr, rep, bad = 0, cases = 0;
  casadi_int i, j, k;
  for (a = 0; a < 7; ++a) for (b = 0; b < 7; ++b) for (c = 0; c < 7; ++c) for (tr = 0; tr < 2; ++tr)
  for (rep = 0; rep < 3; ++rep) {{
    casadi_int n = sizes[a], m = sizes[b], l = sizes[c], nx, ny, nz;
    /* z (n x l) += x y with x n x m, y m x l; or z (m x l) += x' y with x n x m, y n x l */
    nx = pattern(spx, n, m);
    ny = tr ? pattern(spy, n, l) : pattern(spy, m, l);
    /* z's pattern must hold the product's: dense columns, or a random superset */
    if (rep == 0) {{
      casadi_int nrz = tr ? m : n;
      spz[0] = nrz; spz[1] = l; spz[2] = 0;
      for (j = 0; j < l; ++j) {{ for (i = 0; i < nrz; ++i) spz[3 + l + j * nrz + i] = i; spz[3 + j] = (j + 1) * nrz; }}
      nz = nrz * l;
    }} else {{
      /* the product's own pattern, plus random extra rows */
      casadi_int nrz = tr ? m : n, *colind = spz + 2, *row = spz + 3 + l;
      static int mark[40];
      nz = 0; spz[0] = nrz; spz[1] = l; colind[0] = 0;
      for (j = 0; j < l; ++j) {{
        memset(mark, 0, sizeof mark);
        for (k = spy[2 + j]; k < spy[3 + j]; ++k) {{
          casadi_int rr = spy[3 + l + k];
          if (tr) {{ for (i = 0; i < m; ++i) {{ casadi_int e; for (e = spx[2 + i]; e < spx[3 + i]; ++e) if (spx[3 + m + e] == rr) mark[i] = 1; }} }}
          else {{ casadi_int e; for (e = spx[2 + rr]; e < spx[3 + rr]; ++e) mark[spx[3 + m + e]] = 1; }}
        }}
        for (i = 0; i < nrz; ++i) if (mark[i] || next() % 4 == 0) row[nz++] = i;
        colind[j + 1] = nz;
      }}
    }}
    for (i = 0; i < nx; ++i) x[i] = rnd() * 1e3;
    for (i = 0; i < ny; ++i) y[i] = rnd() / 7.0;
    for (i = 0; i < nz; ++i) z1[i] = z2[i] = rnd();
    for (i = 0; i < 40; ++i) w1[i] = w2[i] = 0.0;
    orig_mtimes(x, spx, y, spy, z1, spz, w1, tr);
    casadi_mtimes(x, spx, y, spy, z2, spz, w2, tr);
    if (memcmp(z1, z2, sizeof(double) * nz)) ++bad;
    ++cases;
  }}
  printf("%d %d\n", cases, bad);
  return 0;
}}
"""


@needs_gcc
@pytest.mark.parametrize("opt", ["-O0", "-O3"])
def test_the_swapped_kernel_gives_casadis_products_to_the_bit(tmp_path, opt):
    orig = CASADI_MTIMES.replace("void casadi_mtimes(", "void orig_mtimes(", 1)
    cases, bad = run_comparison(tmp_path, opt, _DRIVER.format(orig=orig, new=MTIMES_SPARSE))
    assert cases == 2 * 3 * 7**3
    assert bad == 0


def test_the_compiled_product_equals_the_vm_to_the_bit():
    from symmon.compile import build_shared_library, has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    f = sparse_product_function()
    so = build_shared_library(faster_sparse_products(generated_c(f)), "sprodtest")
    ext = ca.external("sprod", str(so))
    rng = np.random.default_rng(4)
    args = [ca.DM(f.sparsity_in(i), rng.normal(size=f.nnz_in(i)) * 10.0 ** (2 - i)) for i in range(3)]
    for want, got in zip(f(*args), ext(*args)):
        assert want.sparsity() == got.sparsity()
        assert np.array_equal(np.asarray(got.nonzeros()), np.asarray(want.nonzeros()))
