"""The lean path of one propagate call: what each shortcut must keep.

The per-call work of :func:`symmon.propagate` was cut (issue 21) by: finite tests by one
dot product (``core.arrays.all_finite``), array addresses from the buffer
(``compile.compiled.address``), one compiled call for a small batch, and
``JointMoments.of`` taking the first Gaussian's blocks directly.  Each is tested here
against the slower way it replaced.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled
from symmon.compile.compiled import address
from symmon.core.arrays import DOT_MAX, all_finite
from symmon.errors import ArgumentError
from symmon.propagation.joint import JointMoments

x, y, v = sp.symbols("x y v")


@pytest.mark.parametrize("arrays, expected", [
    ((np.array([1.0, -2.0, 3.0]),), True),
    ((np.array([1e200, -1e250]),), True),  # Σ a² overflows: decided entry by entry
    ((np.array([1.0, np.nan]),), False),
    ((np.array([np.inf, 1.0]),), False),
    ((np.array([-np.inf]),), False),
    ((np.array([1e300, np.nan]),), False),
    ((np.zeros((0, 3)),), True),
    ((np.ones((2, 2)), np.array([[1.0, np.inf]])), False),
    ((np.ones((2, 2)), np.ones(3)), True),
])
def test_all_finite_agrees_with_isfinite(arrays, expected):
    assert all_finite(*arrays) is expected
    assert expected == all(bool(np.isfinite(a).all()) for a in arrays)


def _big(value: float | None = None, at: int = 0, fill: float = 1.0) -> np.ndarray:
    a = np.full(DOT_MAX + 1000, fill)
    if value is not None:
        a[at] = value
    return a


@pytest.mark.parametrize("array, expected", [
    (_big(), True),
    (_big(np.nan, 17), False),
    (_big(np.inf, DOT_MAX + 999), False),
    (_big(-np.inf, 3), False),
    (_big(fill=1e305), True),  # Σ a overflows: decided entry by entry
    (_big(np.nan, 5, fill=1e305), False),
    (np.concatenate([_big(np.inf), _big(-np.inf)]), False),  # inf − inf: NaN, not a cancellation
])
def test_all_finite_sums_an_array_beyond_the_dot_product_size(array, expected):
    assert array.size > DOT_MAX  # the summed path, which wakes no BLAS thread
    assert all_finite(array) is expected
    assert expected == bool(np.isfinite(array).all())


def test_address_is_the_data_pointer_for_writable_read_only_and_empty_arrays():
    a = np.arange(6.0)
    assert address(a) == a.ctypes.data
    assert address(a[2:]) == a.ctypes.data + 16
    ro = np.arange(4.0)
    ro.setflags(write=False)
    assert address(ro) == ro.ctypes.data  # from_buffer refuses it: the fallback
    empty = np.empty(0)
    assert address(empty) == empty.ctypes.data


def test_small_and_split_batches_evaluate_alike():
    """One compiled call for a small batch, and threaded spans for a large one: g the same."""
    cm = compiled(sm.Model([x, y], [sp.sin(x) * y, x**2 + y], name="overhead_rows"))
    cm.wait_compiled(120)
    W = np.random.default_rng(0).normal(size=(5000, 2))
    big = cm.eval_g(W)
    small = np.vstack([cm.eval_g(W[k:k + 3]) for k in range(0, 30, 3)])
    np.testing.assert_array_equal(small, big[:30])
    np.testing.assert_allclose(big, np.column_stack([np.sin(W[:, 0]) * W[:, 1], W[:, 0] ** 2 + W[:, 1]]),
                               rtol=1e-15, atol=1e-15)


def test_of_takes_the_u_and_v_blocks_as_split_does():
    model = sm.Model([x, y], [x * y + v, sp.exp(x) * v], noise=[v], name="overhead_noise")
    u, nv = sm.Gaussian([0.3, 1.2], [[0.2, 0.05], [0.05, 0.1]]), sm.Gaussian([0.0], [[0.01]])
    tr = sm.GaussHermite(order=3, error_estimate=True)
    m = sm.propagate(model, u, nv, transform=tr)
    cm = compiled(model)
    mw = np.concatenate([u.mean, nv.mean])[None]
    Pw = np.zeros((1, 3, 3))
    Pw[0, :2, :2], Pw[0, 2:, 2:] = u.cov, nv.cov
    s = tr.moments(cm, mw, Pw).split(2)
    for name in ("mean", "cov", "cross_cov", "noise_cross_cov"):
        np.testing.assert_array_equal(getattr(m, name), getattr(s, name)[0])
    assert m.cross_cov.shape == (2, 2) and m.noise_cross_cov.shape == (2, 1)
    est = m.info["error_estimate"]
    assert est["cross_cov"].shape == (1, 2, 2)  # Cov(y, u) only, as the split batch's
    np.testing.assert_array_equal(est["cross_cov"], s.error["cross_cov"])
    np.testing.assert_array_equal(m.error["cross_cov"], s.error["cross_cov"][0])


def test_of_refuses_moments_that_are_already_split():
    cm = compiled(sm.Model([x], [x**2], name="overhead_split"))
    b = sm.TT2().moments(cm, np.zeros((1, 1)), np.ones((1, 1, 1))).split(1)
    with pytest.raises(ArgumentError, match="already split"):
        JointMoments.of(b, sm.Gaussian([0.0], [[1.0]]), 1, sm.TT2())


def test_results_are_read_only_and_own_their_arrays():
    u = sm.Gaussian([1.0, 2.0], [[1.0, 0.2], [0.2, 0.5]])
    m = sm.propagate(sm.Model([x, y], [x * y], name="overhead_ro"), u, transform=sm.UT())
    for name in ("mean", "cov", "cross_cov", "noise_cross_cov", "input_cov"):
        assert not getattr(m, name).flags.writeable, name
    assert m.input_cov is u.cov  # the input's own read-only array: a Gaussian is immutable
    assert not u.mean.flags.writeable and not u.cov.flags.writeable  # the rules wrote nothing into them


def test_angles_given_as_numpy_integers_become_ints():
    u = sm.Gaussian([1.0], [[1.0]])
    m = JointMoments(np.zeros(1), np.ones((1, 1)), np.zeros((1, 1)), u, sm.TT1(),
                     angles={np.int64(0)}, input_angles=[np.int32(0)])
    assert m.angles == frozenset({0}) and all(type(i) is int for i in m.angles | m.input_angles)


def test_ut2_sums_of_opposite_points_cancel_exactly():
    """ut2's weights are about ±1e6: its mean of an odd g at 0 is 0 exactly, not |w g| eps
    (a matmul with fused multiply-adds gave 2.4e186 for g = 1e200 x)."""
    m = sm.propagate(sm.Model([x], [sp.Float(1e100) * x]), sm.Gaussian([0.0], [[1.0]]), transform=sm.UT.ut2())
    assert m.mean[0] == 0.0
