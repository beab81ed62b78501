"""The compiled batch moments of point rules (symmon.propagation.kernel), behind propagate_many.

The kernel's moments are checked against the NumPy rule (``Transform.moments``, which
shares no code with it: the points, the evaluation and the sums are NumPy there, one
CasADi graph here) on SX and MX kernels, with angles and general noise; then the batches
that must go to the NumPy rule (a singular, indefinite, asymmetric or non-finite input,
an overflow), and the rules and models the kernel does not take.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled
from symmon.errors import CovarianceError, NonFiniteError, ShapeError
from symmon.propagation.kernel import MIN_BATCH, batch_kernel

#: The kernel and the NumPy rule sum the same terms in another order: agreement to a few
#: hundred roundings of the largest term (1.6e-15 relative measured at n = 16); 1e-12.
RTOL = 1e-12


def close(a, b):
    scale = max(np.max(np.abs(b)), 1e-300)
    return np.max(np.abs(a - b)) <= RTOL * scale


def batch(n: int, K: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((K, n, n)) / np.sqrt(n)
    return rng.standard_normal((K, n)), 0.05 * (A @ A.transpose(0, 2, 1) + np.eye(n))


def ring(n: int, name: str) -> sm.Model:
    x = sp.symbols(f"x0:{n}", real=True)
    return sm.Model(list(x), [sp.sqrt(x[i] ** 2 + x[(i + 1) % n] ** 2 + 1) + sp.sin(x[i] * x[(i + 2) % n])
                              for i in range(n)], name=name)


def kernel_of(model: sm.Model, transform, K: int):
    kernel = batch_kernel(compiled(model), transform, frozenset(model.angle_outputs), K)
    assert kernel is not None and kernel.wait(600), "the kernel builds"
    return kernel


def numpy_rule(model, transform, M, P):
    return transform.moments(compiled(model), M, P, model.angle_outputs)


@pytest.mark.parametrize("n, transform", [(3, sm.UT(1, 2, 0)), (3, sm.UT.cubature()), (3, sm.GaussHermite(3, sparse=False)),
                                          (12, sm.UT(1, 2, 0))], ids=["ut-sx", "cubature-sx", "gh-sx", "ut-mx"])
def test_kernel_moments_equal_the_numpy_rule(n, transform):
    model = ring(n, f"kern_ring{n}")
    M, P = batch(n, MIN_BATCH + 5)
    kernel_of(model, transform, len(M))
    b = sm.propagate_many(model, (M, P), transform=transform)
    assert b.details["evaluator"] == "compiled batch kernel"
    ref = numpy_rule(model, transform, M, P)
    assert close(b.mean, ref.mean) and close(b.cov, ref.cov) and close(b.cross_cov, ref.cross_cov)
    np.testing.assert_array_equal(b.cov, np.swapaxes(b.cov, 1, 2))
    assert b.evaluations == ref.evaluations


def test_angle_outputs_and_general_noise_go_through_the_kernel():
    e = sp.Symbol("e", real=True)
    px, py = sp.symbols("px py", real=True)
    model = sm.Model([px, py], [sp.sqrt(px**2 + py**2) * (1 + e), sp.atan2(py, px) + e], noise=[e],
                     name="kern_polar", angles=[1])
    rng = np.random.default_rng(3)
    K = 2 * MIN_BATCH
    us = [sm.Gaussian([-3.0 + 0.1 * rng.standard_normal(), 0.05 * rng.standard_normal()], 0.2 * np.eye(2))
          for _ in range(K)]  # bearings near ±π: the circular mean matters
    v = sm.Gaussian([0.0], [[0.01]])
    ut = sm.UT(1, 2, 0)
    cm = compiled(model)
    assert batch_kernel(cm, ut, frozenset([1]), K).wait(600)
    b = sm.propagate_many(model, us, v, transform=ut)
    assert b.details["evaluator"] == "compiled batch kernel"
    M = np.array([np.r_[u.mean, 0.0] for u in us])
    P = np.array([np.block([[u.cov, np.zeros((2, 1))], [np.zeros((1, 2)), v.cov]]) for u in us])
    ref = numpy_rule(model, ut, M, P)
    assert close(b.mean, ref.mean) and close(b.cov, ref.cov)
    assert np.abs(b.mean[:, 1]).min() > 3.0  # the bearing's mean stays near ±π


def test_a_singular_covariance_sends_the_batch_to_the_numpy_rule():
    model = ring(3, "kern_singular")
    ut = sm.UT(1, 2, 0)
    M, P = batch(3, MIN_BATCH)
    P[7] = np.diag([1.0, 0.0, 0.5])  # positive semi-definite: a valid, degenerate Gaussian
    kernel_of(model, ut, len(M))
    b = sm.propagate_many(model, (M, P), transform=ut)
    assert "sigma_points" in b.details  # the NumPy rule, whose square root handles it
    ref = numpy_rule(model, ut, M, P)
    np.testing.assert_array_equal(b.mean, ref.mean)


@pytest.mark.parametrize("spoil, error, message", [
    (lambda M, P: P.__setitem__(5, -np.eye(3)), CovarianceError, r"covs\[5\]"),
    (lambda M, P: P.__setitem__((9, 0, 1), P[9, 0, 1] + 1.0), CovarianceError, r"covs\[9\]"),
    (lambda M, P: M.__setitem__((4, 2), np.nan), ShapeError, r"means\[4\]"),
])
def test_a_bad_batch_is_named_by_the_numpy_rule(spoil, error, message):
    model = ring(3, "kern_bad")
    ut = sm.UT(1, 2, 0)
    M, P = batch(3, MIN_BATCH)
    kernel_of(model, ut, len(M))
    spoil(M, P)
    with pytest.raises(error, match=message):
        sm.propagate_many(model, (M, P), transform=ut)


def test_the_kernel_flags_each_gaussian_with_a_non_finite_input_or_moment():
    x = sp.Symbol("x", real=True)
    model = sm.Model([x], [sp.atan(x) + sp.exp(x / 400)], name="kern_finite")  # bounded in x → −∞
    ut = sm.UT(1, 2, 0)
    M, P = np.zeros((MIN_BATCH, 1)), np.ones((MIN_BATCH, 1, 1))
    M[3] = -np.inf  # g(−∞) is finite: only the test of the input catches it
    P[8] = np.nan
    M[11] = 3e5  # exp(750): the moments overflow
    kernel = kernel_of(model, ut, len(M))
    mean, cov, cross, checks = kernel(M, P)
    assert checks.shape == (MIN_BATCH, 3)
    np.testing.assert_array_equal(np.flatnonzero(checks[:, 2] == 0), [3, 8, 11])
    fine = np.setdiff1d(np.arange(MIN_BATCH), [3, 8, 11])
    assert np.isfinite(mean[fine]).all() and np.all(checks[fine, 2] == 1)
    with pytest.raises(ShapeError, match=r"means\[3\]"):
        sm.propagate_many(model, (M, P), transform=ut)  # the NumPy rule names the first culprit


def test_an_overflow_is_named_by_the_numpy_rule():
    x = sp.Symbol("x", real=True)
    model = sm.Model([x], [sp.exp(x)], name="kern_overflow")
    ut = sm.UT(1, 2, 0)
    M, P = np.zeros((MIN_BATCH, 1)), np.ones((MIN_BATCH, 1, 1))
    M[3] = 700.0  # exp(700 + c) squared overflows
    kernel_of(model, ut, len(M))
    with pytest.raises(NonFiniteError, match="overflow"):
        sm.propagate_many(model, (M, P), transform=ut)


def test_rules_and_models_the_kernel_does_not_take():
    model = ring(4, "kern_rules")
    cm = compiled(model)
    K = MIN_BATCH
    assert batch_kernel(cm, sm.UT(1, 2, 0), frozenset(), K - 1) is None  # a small batch
    assert batch_kernel(cm, sm.TT2(), frozenset(), K) is None  # not a point rule
    assert batch_kernel(cm, sm.UT.ut1(), frozenset(), K) is None  # a negative covariance weight at n = 4
    px, py = sp.symbols("px py", real=True)
    undeclared = sm.Model([px, py], [sp.atan2(py, px)], name="kern_undeclared")
    assert batch_kernel(compiled(undeclared), sm.UT(1, 2, 0), frozenset(), K) is None  # its points are inspected


def test_without_a_compiler_the_numpy_rule_answers():
    from symmon.compile.compiled import CompiledModel

    model = ring(3, "kern_vm")
    vm = CompiledModel(list(model.outputs), list(model.inputs), name="kern_vm_only", compiled=False)
    assert batch_kernel(vm, sm.UT(1, 2, 0), frozenset(), 10 * MIN_BATCH) is None
