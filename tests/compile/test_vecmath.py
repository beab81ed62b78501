"""The vectorised atan2 and hypot of symmon.compile.vecmath: within 1 ulp, and the same bits
whatever the vector width.

Reference: x86's 64-bit-mantissa long double (libm's atan2l and hypotl, about 2⁻¹¹ ulp of
a double from the exact value) on a fixed sample of 2·10⁵ argument pairs of mixed
magnitudes, and mpmath at 60 digits on 2000 of them.  The bound asserted is the 1 ulp of
the issue's bar; the measured maximum is 0.502 ulp for atan2 and 0.500 for hypot (libm's
own: 0.521 and 0.558 on the same sample).
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess

import casadi as ca
import mpmath
import numpy as np
import pytest

from symmon.compile import build_shared_library, has_compiler
from symmon.compile.ccache import CFLAGS
from symmon.compile.vecmath import EXP_HIGH, EXP_LOW, VECMATH_C, vector_rows

needs_gcc = pytest.mark.skipif(not has_compiler() or shutil.which("gcc") is None, reason="no C compiler")

_LOOPS = VECMATH_C + """
void v_atan2(const double* restrict y, const double* restrict x, double* restrict o, long n) {
  for (long i = 0; i < n; ++i) o[i] = sm_atan2(y[i], x[i]);
}
void v_hypot(const double* restrict y, const double* restrict x, double* restrict o, long n) {
  for (long i = 0; i < n; ++i) o[i] = sm_hypot(y[i], x[i]);
}
/* exp of x (y unused: the signature of the others), and its range flag */
void v_exp(const double* restrict y, const double* restrict x, double* restrict o, long n) {
  for (long i = 0; i < n; ++i) o[i] = sm_exp(x[i]);
}
void v_expok(const double* restrict y, const double* restrict x, double* restrict o, long n) {
  for (long i = 0; i < n; ++i) o[i] = sm_exp_ordinary(x[i]);
}
"""


def _functions(so):
    lib = ctypes.CDLL(str(so))
    out = {}
    for name in ("v_atan2", "v_hypot", "v_exp", "v_expok"):
        fn = getattr(lib, name)
        fn.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_long]
        out[name[2:]] = fn
    return out


def _call(fn, y, x):
    o = np.empty_like(x)
    fn(y.ctypes.data, x.ctypes.data, o.ctypes.data, x.size)
    return o


@pytest.fixture(scope="module")
def vec():
    if not has_compiler():
        pytest.skip("no C compiler")
    return _functions(build_shared_library(_LOOPS, "vecmath_test"))


def sample(n: int = 200_000, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of mixed signs and magnitudes (10^±8), a quarter of them of the same scale."""
    rng = np.random.default_rng(seed)
    y = rng.standard_normal(n) * 10.0 ** rng.uniform(-8, 8, n)
    x = rng.standard_normal(n) * 10.0 ** rng.uniform(-8, 8, n)
    q = n // 4
    y[:q], x[:q] = rng.standard_normal(q), rng.standard_normal(q)
    return y, x


def ulps(value: np.ndarray, exact) -> np.ndarray:
    """|value − exact| in ulps of the double nearest the exact value."""
    exact = np.asarray(exact, dtype=np.longdouble)
    return np.abs(value.astype(np.longdouble) - exact) / np.spacing(np.abs(exact.astype(float))).astype(np.longdouble)


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 63, reason="needs x86's 64-bit-mantissa long double")
@pytest.mark.parametrize("name", ["atan2", "hypot"])
def test_within_one_ulp_of_long_double(vec, name):
    y, x = sample()
    ref = getattr(np, "arctan2" if name == "atan2" else "hypot")(y.astype(np.longdouble), x.astype(np.longdouble))
    err = ulps(_call(vec[name], y, x), ref)
    assert err.max() <= 1.0
    assert err.mean() < 0.26  # rounded: an error of 1/4 ulp on average


@pytest.mark.parametrize("name", ["atan2", "hypot"])
def test_within_one_ulp_of_mpmath(vec, name):
    y, x = (a[:2000].copy() for a in sample())
    out = _call(vec[name], y, x)
    with mpmath.workdps(60):
        f = mpmath.atan2 if name == "atan2" else mpmath.hypot
        exact = [f(mpmath.mpf(float(a)), mpmath.mpf(float(b))) for a, b in zip(y, x)]
        err = [abs(mpmath.mpf(float(o)) - e) / np.spacing(abs(float(e))) for o, e in zip(out, exact)]
    assert float(max(err)) <= 1.0


def test_quadrants_and_edges_of_the_reduction(vec):
    """Every octant, |y| = |x|, t at the table's knots k/8 and between, and arguments near
    the ordinary range's ends: libm's values to 1 ulp."""
    t = np.concatenate([np.arange(0, 65) / 64, [1e-300, 1e-20, 1e-8, 1 - 2**-52]])
    y = np.concatenate([s * t * m for s in (1, -1) for m in (1.0, 2.0**-499, 2.0**499)])
    x = np.concatenate([s * np.ones_like(t) * m for s in (1, -1) for m in (1.0, 2.0**-499, 2.0**499)])
    y, x = np.concatenate([y, x, -y]), np.concatenate([x, y, -x])
    ok = (np.abs(y) >= 2.0**-500) & (np.abs(x) >= 2.0**-500)  # the vector path's range
    y, x = y[ok], x[ok]
    np.testing.assert_array_less(ulps(_call(vec["atan2"], y, x), np.arctan2(y.astype(np.longdouble), x)), 1.0 + 1e-12)
    np.testing.assert_array_less(ulps(_call(vec["hypot"], y, x), np.hypot(y.astype(np.longdouble), x)), 1.0 + 1e-12)


@needs_gcc
def test_the_same_bits_scalar_and_vectorised(vec, tmp_path):
    """-O0 (scalar code, fma by libm) against the build's -O3 with this CPU's vector
    instructions: IEEE operations in the same order give the same bits in every lane."""
    src, so = tmp_path / "v.c", tmp_path / "v.so"
    src.write_text(_LOOPS)
    subprocess.run(["gcc", "-O0", *CFLAGS, str(src), "-o", str(so), "-lm"], check=True)
    scalar = _functions(so)
    y, x = (a[:20_000].copy() for a in sample(seed=11))
    for name in ("atan2", "hypot", "exp"):
        assert np.array_equal(_call(scalar[name], y, x), _call(vec[name], y, x))


def test_vector_rows_takes_arithmetic_atan2_and_hypot_and_refuses_libm_functions():
    z, p = ca.SX.sym("z", 2), ca.SX.sym("p", 1)
    ok = ca.Function("ok", [z, p], [ca.vertcat(ca.atan2(z[0], z[1]), ca.hypot(z[0], p), ca.floor(z[0] / 3),
                                               ca.if_else(z[0] < z[1], ca.sqrt(z[1] ** 2), 1.5))])
    code = vector_rows(ok, "ok_vec", 2, 16)
    assert code is not None and "sm_atan2" in code and "sm_hypot" in code and "ok &= sm_ordinary" in code
    for fn in (ca.sin, ca.exp, ca.log):
        assert vector_rows(ca.Function("no", [z, p], [fn(z[0]) + p]), "no_vec", 2, 16) is None


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 63, reason="needs x86's 64-bit-mantissa long double")
def test_exp_within_one_ulp_of_long_double(vec):
    """10⁶ arguments: uniform over the whole range [−708, 709], over [−40, 0] (the particle
    filter's log-weights less their maximum), and near the reduction's edges (k ± 1/2) ln 2
    and 0; measured maximum 0.63 ulp, mean 0.23 (NumPy's exp: 0.50, 0.23)."""
    rng = np.random.default_rng(3)
    k = rng.integers(-1000, 1000, 100_000)
    x = np.concatenate([rng.uniform(-EXP_LOW, EXP_HIGH, 500_000), rng.uniform(-40, 0, 300_000),
                        (k + 0.5) * np.log(2) * (1 + rng.uniform(-1e-15, 1e-15, k.size)),
                        rng.standard_normal(100_000) * 10.0 ** rng.uniform(-300, -1, 100_000),
                        [-EXP_LOW, EXP_HIGH, 0.0, -0.0, np.log(2) / 2, -np.log(2) / 2]])
    x = x[(x >= -EXP_LOW) & (x <= EXP_HIGH)]
    assert x.size > 999_000
    err = ulps(_call(vec["exp"], x, x), np.exp(x.astype(np.longdouble)))
    assert err.max() <= 1.0
    assert err.mean() < 0.26


def test_exp_range_flag(vec):
    """sm_exp_ordinary: 1 on [−EXP_LOW, EXP_HIGH], 0 beyond and for NaN (the caller's libm
    fallback), where sm_exp's scale would leave the normal numbers."""
    x = np.array([-EXP_LOW, EXP_HIGH, 0.0, -EXP_LOW - 1e-9, EXP_HIGH + 1e-9, -np.inf, np.inf, np.nan, -1e5])
    np.testing.assert_array_equal(_call(vec["expok"], x, x), [1, 1, 1, 0, 0, 0, 0, 0, 0])


def _rows_of(f: ca.Function, n_in: int, ld: int, tag: str):
    """The vector loop of f, built, as a function of the rows Z (n, n_in) and p."""
    code = vector_rows(f, f"{tag}_vec", n_in, ld)
    assert code is not None
    so = build_shared_library(VECMATH_C + code.replace(f"static int {tag}_vec", f"int {tag}_vec"), tag)
    fn = getattr(ctypes.CDLL(str(so)), f"{tag}_vec")
    fn.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_longlong, ctypes.c_void_p]
    fn.restype = ctypes.c_int

    def call(Z, p):
        Z, p = np.ascontiguousarray(Z, dtype=float), np.ascontiguousarray(p, dtype=float)
        out, odd = np.zeros((f.nnz_out(0), ld)), np.zeros(ld, dtype=np.uint8)
        bad = fn(Z.ctypes.data, p.ctypes.data, out.ctypes.data, Z.shape[0], odd.ctypes.data)
        return out[:, :Z.shape[0]].T, odd[:Z.shape[0]].astype(bool), bad

    return code, call


def test_vector_rows_evaluates_the_parameters_functions_once_before_the_loop():
    """cos(1.2 p0), p1^2.5 and atan2(p0, p1), functions of the parameters only, are computed
    before the row loop (by libm's cos and pow, as CasADi's C), so a row with a libm function
    of the parameters has a vector loop; a libm function of the row still has none."""
    z, p = ca.SX.sym("z", 2), ca.SX.sym("p", 2)
    out = ca.vertcat(z[0] / 2 + 25 * z[0] / (1 + z[0] ** 2) + 8 * ca.cos(1.2 * p[0]),
                     z[1] * p[1] ** 2.5 + ca.atan2(p[0], p[1]), ca.sqrt(p[0] * p[0]), ca.exp(p[1]))
    f = ca.Function("hoist", [z, p], [out], {"cse": True})
    code = vector_rows(f, "hoist_vec", 2, 16)
    assert code is not None
    loop = code.index("for (i = 0;")
    for call in ("cos(", "pow(", "sm_atan2(", "exp("):
        assert call in code[:loop] and call not in code[loop:], call
    assert "ok0 &= sm_ordinary" in code[:loop]
    assert vector_rows(ca.Function("no", [z, p], [ca.cos(z[0]) + ca.cos(p[0])]), "no_vec", 2, 16) is None


@needs_gcc
def test_vector_rows_hoisted_are_the_numbers_of_casadi_per_row():
    """The numbers of the loop with the hoisted functions: CasADi's, bit for bit (libm's
    cos, exp and pow once instead of per row; arithmetic in the same order); a parameter
    that makes the hoisted atan2's argument zero flags every row."""
    z, p = ca.SX.sym("z", 2), ca.SX.sym("p", 3)
    out = ca.vertcat(z[0] / 2 + 25 * z[0] / (1 + z[0] ** 2) + 8 * ca.cos(1.2 * p[0]),
                     z[1] * ca.exp(p[1]) - p[1] ** 2.5, ca.atan2(p[2], p[1]) * z[0], ca.hypot(z[0], z[1]))
    f = ca.Function("hoistn", [z, p], [out], {"cse": True})
    _, call = _rows_of(f, 2, 16, "hoistn")
    rng = np.random.default_rng(1)
    Z = rng.standard_normal((13, 2)) * 5
    for pv in ([3.0, 0.7, 1.5], [17.0, 2.5, -0.3]):
        got, odd, bad = call(Z, pv)
        want = np.array(f.map(13)(Z.T, ca.DM(pv))).T
        np.testing.assert_array_equal(got[:, :3], want[:, :3])
        np.testing.assert_allclose(got[:, 3], want[:, 3], rtol=2.3e-16)  # sm_hypot: within 1 ulp
        assert bad == 0 and not odd.any()
    _, odd, bad = call(Z, [1.0, 0.7, 0.0])
    assert bad == 13 and odd.all()
