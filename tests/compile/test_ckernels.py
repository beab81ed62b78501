"""symmon's dense product in generated C: swapped in, and the same to the bit as CasADi's."""

from __future__ import annotations

import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from symmon.compile.ckernels import CASADI_MTIMES_DENSE, MTIMES_DENSE, faster_kernels
from symmon.compile.compiled import generated_c

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc")


def dense_product_function() -> ca.Function:
    A, B, C = ca.MX.sym("A", 5, 7), ca.MX.sym("B", 7, 3), ca.MX.sym("C", 5, 3)
    return ca.Function("prod", [A, B, C], [ca.mac(A, B, C)])


def test_the_installed_casadis_kernel_is_the_known_one_and_is_swapped():
    # Fails when a CasADi release changes casadi_mtimes_dense: then re-check the
    # replacement against the new definition before updating CASADI_MTIMES_DENSE.
    code = generated_c(dense_product_function())
    assert MTIMES_DENSE in code
    assert CASADI_MTIMES_DENSE not in code
    assert code.count("void casadi_mtimes_dense(") == 1


def test_an_unknown_definition_is_left_alone():
    other = CASADI_MTIMES_DENSE.replace("z[j + i*nrow_x] +=", "z[j + i*nrow_x] -=")
    assert faster_kernels(other) == other
    assert faster_kernels("int main(void) { return 0; }") == "int main(void) { return 0; }"


_DRIVER = r"""
#include <stdio.h>
#include <string.h>
typedef double casadi_real;
typedef long long casadi_int;
{orig}
{new}
static unsigned long long s = 88172645463325252ULL;
static double rnd(void) {{ s ^= s << 13; s ^= s >> 7; s ^= s << 17; return (double)(s >> 11) / 9007199254740992.0 - 0.5; }}
int main(void) {{
  static double x[80 * 80], y[80 * 80], z1[80 * 80], z2[80 * 80];
  const int sizes[] = {{1, 2, 3, 4, 5, 7, 8, 9, 12, 30, 61}};
  int a, b, c, tr, i, bad = 0, cases = 0;
  for (a = 0; a < 11; ++a) for (b = 0; b < 11; ++b) for (c = 0; c < 11; ++c) for (tr = 0; tr < 2; ++tr) {{
    int nr = sizes[a], nc = sizes[b], ny = sizes[c];
    int nz = tr ? nc * ny : nr * ny, nyv = tr ? nr * ny : nc * ny;
    for (i = 0; i < nr * nc; ++i) x[i] = rnd() * 1e3;
    for (i = 0; i < nyv; ++i) y[i] = rnd() / 7.0;
    for (i = 0; i < nz; ++i) z1[i] = z2[i] = rnd();
    orig_mtimes_dense(x, nr, nc, y, ny, z1, tr);
    casadi_mtimes_dense(x, nr, nc, y, ny, z2, tr);
    if (memcmp(z1, z2, sizeof(double) * nz)) ++bad;
    ++cases;
  }}
  printf("%d %d\n", cases, bad);
  return 0;
}}
"""


def run_comparison(tmp_path, opt: str, code: str) -> tuple[int, int]:
    """Compile ``code`` (a driver that compares a kernel with CasADi's and prints its cases
    and mismatches) at ``opt`` without FMA contraction, run it: (cases, mismatches)."""
    src, exe = tmp_path / "k.c", tmp_path / "k"
    src.write_text(code)
    subprocess.run(["gcc", "-std=c99", opt, "-fno-fast-math", "-ffp-contract=off", str(src), "-o", str(exe)],
                   check=True)
    cases, bad = map(int, subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split())
    return cases, bad


@needs_gcc
@pytest.mark.parametrize("opt", ["-O0", "-O2"])
def test_the_swapped_kernel_gives_casadis_products_to_the_bit(tmp_path, opt):
    orig = CASADI_MTIMES_DENSE.replace("casadi_mtimes_dense(", "orig_mtimes_dense(", 1)
    cases, bad = run_comparison(tmp_path, opt, _DRIVER.format(orig=orig, new=MTIMES_DENSE))
    assert cases == 2 * 11**3
    assert bad == 0


def test_the_compiled_product_equals_the_vm_to_the_bit(tmp_path):
    from symmon.compile import build_shared_library, has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    f = dense_product_function()
    so = build_shared_library(generated_c(f), "prodtest")
    ext = ca.external("prod", str(so))
    rng = np.random.default_rng(3)
    A, B, C = rng.normal(size=(5, 7)) * 1e3, rng.normal(size=(7, 3)) / 7, rng.normal(size=(5, 3))
    want = np.asarray(f(A, B, C))
    got = np.asarray(ext(A, B, C))
    assert np.array_equal(got, want)
