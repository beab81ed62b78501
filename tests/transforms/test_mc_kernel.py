"""The compiled sampling kernel of Monte Carlo: the same numbers as the plain path.

Reference: w = m + Z Lᵀ with NumPy, g by the model's batched evaluator, angles unwrapped
with ``wrap_angle``.  The kernel reorders the same arithmetic (L z summed in C instead
of BLAS), so the tolerance is rounding: a few ulps of the scale of each column.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.angles import wrap_angle
from symmon.compile import CompiledModel, has_compiler
from symmon.errors import SamplingError, ShapeError
from symmon.core.problems import bot, gmti
from symmon.compile import compiled
from symmon.core.angles import wrap_casadi
from symmon.transforms.mc_kernel import FUSE_MAX_NW, SampleKernel, sample_kernel

#: A reordered sum of 4 products and one evaluation of g: a few ulps of the column scale.
ROUNDING = 1e-13

PROBLEM = gmti(1.0)


def reference(cm, Z, mean, L, shift, ref, angles):
    W = mean + Z @ L.T
    Y = cm.eval_g(W)
    A = list(angles)
    for i in A:
        Y[:, i] = ref[i] + wrap_angle(Y[:, i] - ref[i])
    z = np.column_stack([Y, W, np.sin(Y[:, A]), np.cos(Y[:, A])])
    return np.column_stack([z - shift, np.ones(len(Z))])


def assert_rows_close(A, B):
    scale = np.maximum(np.abs(B).max(axis=0), 1.0)
    np.testing.assert_array_less(np.abs(A - B), np.broadcast_to(ROUNDING * scale, A.shape))


@pytest.mark.parametrize("angles", [(), (1,)], ids=["plain", "bearing-wrapped"])
@pytest.mark.parametrize("vm", [False, True], ids=["compiled", "vm"])
def test_kernel_rows_equal_the_plain_computation(angles, vm):
    cm = compiled(PROBLEM.model)
    if vm:
        cm = CompiledModel(cm.source_exprs, cm.symbols, name="kernel_vm", compiled=False)
    k = SampleKernel(cm, angles)
    assert k.compiled == (not vm and has_compiler())
    rng = np.random.default_rng(0)
    Z = rng.standard_normal((1000, cm.n_w))
    mean, L = PROBLEM.u.mean, np.linalg.cholesky(PROBLEM.u.cov)
    shift = rng.standard_normal(cm.n_y + cm.n_w + 2 * len(angles))
    assert k.n_out == len(shift) + 1
    # A reference bearing opposite the true one: every sample crosses the cut and is unwrapped.
    ref = cm.eval_g(mean[None])[0] + np.array([0.0, np.pi, 0.0])
    A = np.empty((len(Z), k.n_out))
    k(Z, k.params(mean, L, shift, ref), A)
    assert_rows_close(A, reference(cm, Z, mean, L, shift, ref, angles))
    if angles:
        y1 = A[:, 1] + shift[1]
        assert np.all(np.abs(y1 - ref[1]) <= np.pi)


@pytest.mark.parametrize("vm", [False, True], ids=["compiled", "vm"])
def test_large_model_maps_by_blas_and_gives_the_same_rows(vm):
    """Above FUSE_MAX_NW inputs w = m + L z is a BLAS product: same rows, C free of n_w² terms."""
    n = FUSE_MAX_NW + 4
    x = sp.symbols(f"x0:{n}", real=True)
    out = [sp.sqrt(x[i] ** 2 + x[(i + 1) % n] ** 2 + 1) + sp.sin(x[i] * x[(i + 2) % n]) for i in range(n)]
    cm = CompiledModel(out, x, name="kernel_blas", compiled=not vm and has_compiler())
    k = SampleKernel(cm, ())
    assert not k.fused and k.f.size1_in(1) == k.n_z + cm.n_y  # the kernel's parameters hold no m, L
    rng = np.random.default_rng(1)
    Z = rng.standard_normal((700, n))
    mean = rng.standard_normal(n)
    L = np.linalg.cholesky(0.2 * np.eye(n) + 0.05)
    shift = rng.standard_normal(k.n_z)
    ref = cm.eval_g(mean[None])[0]
    A = np.empty((len(Z), k.n_out))
    k(Z, k.params(mean, L, shift, ref), A)
    assert_rows_close(A, reference(cm, Z, mean, L, shift, ref, ()))


def test_wrap_in_the_kernel_is_wrap_angle():
    import casadi as ca

    a = ca.SX.sym("a")
    f = ca.Function("w", [a], [wrap_casadi(a)])
    x = np.concatenate([np.linspace(-20, 20, 4001), np.pi * np.arange(-7, 8), [np.nextafter(np.pi, 4)]])
    got = np.array(f.map(len(x))(x[None])).ravel()
    # Floor-based and np.mod agree except by rounding in (a + π) mod 2π; both give (−π, π].
    np.testing.assert_allclose(got, wrap_angle(x), rtol=0, atol=8 * np.finfo(float).eps * 20)
    assert np.all((got > -np.pi) & (got <= np.pi))


def test_monte_carlo_on_the_vm_equals_the_compiled_kernel():
    cm = compiled(PROBLEM.model)
    vm = CompiledModel(cm.source_exprs, cm.symbols, name="mc_vm", compiled=False)
    mc = sm.MonteCarlo(20_000, seed=3, groups=4)
    a = mc.moments(cm, PROBLEM.u.mean[None], PROBLEM.u.cov[None])
    b = mc.moments(vm, PROBLEM.u.mean[None], PROBLEM.u.cov[None])
    for name in ("mean", "cov", "cross_cov"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12 * max(np.abs(y).max(), 1.0), err_msg=name)


def test_kernels_are_built_once_per_model_and_angle_set():
    cm = compiled(bot(1.0).model)
    assert sample_kernel(cm, (0,)) is sample_kernel(cm, [0])
    assert sample_kernel(cm, ()) is not sample_kernel(cm, (0,))


@pytest.mark.parametrize("case", ["Z", "p", "out", "fortran", "float32", "readonly", "work"])
def test_kernel_rejects_bad_arrays(case):
    cm = compiled(PROBLEM.model)
    k = sample_kernel(cm)
    Z, out = np.zeros((8, cm.n_w)), np.zeros((8, k.n_out))
    p = k.params(PROBLEM.u.mean, np.eye(cm.n_w), np.zeros(k.n_z), np.zeros(cm.n_y))
    work = None
    if case == "Z":
        Z = np.zeros((8, cm.n_w + 1))
    elif case == "p":
        p = p[:-1]
    elif case == "out":
        out = np.zeros((7, k.n_out))
    elif case == "fortran":
        Z = np.asfortranarray(Z)
    elif case == "float32":
        Z = Z.astype(np.float32)
    elif case == "readonly":
        out.flags.writeable = False
    elif case == "work":
        if not k.compiled:
            pytest.skip("the VM takes no work arrays")
        work = (np.zeros(k.f.sz_iw() + 1, dtype=np.int32), np.zeros(0))
    with pytest.raises(ShapeError, match="sampling kernel"):
        k(Z, p, out, work)


def test_overflowing_second_moments_are_reported():
    x = sp.Symbol("x", real=True)
    model = sm.Model([x], [1e200 * x])
    with pytest.raises(SamplingError, match="overflow"):
        sm.propagate(model, sm.Gaussian([0.0], [[1.0]]), transform=sm.MonteCarlo(1000, seed=0, groups=2))


def test_the_sine_and_cosine_of_a_bearing_are_its_direction_cosines():
    """sin and cos of an output atan2(a, b) are a / r and b / r (r = hypot(a, b)): within a
    few ulps of sin(atan2) and cos(atan2), with (0, 1) at a = b = 0 where atan2 is 0; an
    angle output that is not atan2 itself keeps sin and cos."""
    import casadi as ca

    from symmon.core.angles import circle_point

    w = ca.SX.sym("w", 3)
    bearing = ca.atan2(w[0], w[1])
    f = ca.Function("cp", [w], [ca.vertcat(*circle_point(bearing), *circle_point(bearing + w[2]))])
    rng = np.random.default_rng(4)
    W = np.vstack([rng.standard_normal((500, 3)) * 10.0 ** rng.integers(-150, 150, (500, 1)), [0.0, 0.0, 0.3],
                   [0.0, -2.0, 0.0], [1e-300, 1e-300, 0.0], [1e300, -1e300, 0.0]])
    out = np.array(f.map(len(W))(W.T)).T
    plain = ca.Function("plain", [w], [ca.vertcat(ca.sin(bearing), ca.cos(bearing), ca.sin(bearing + w[2]),
                                                  ca.cos(bearing + w[2]))])
    ref = np.array(plain.map(len(W))(W.T)).T
    np.testing.assert_allclose(out[:, :2], ref[:, :2], rtol=0, atol=4e-16)  # two ulps of 1
    np.testing.assert_array_equal(out[:, 2:], ref[:, 2:])  # not atan2 itself: sin and cos
    assert tuple(out[-4, :2]) == (0.0, 1.0)
