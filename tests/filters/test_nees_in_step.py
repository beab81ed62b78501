"""The NEES computed inside the compiled filter step (``filter(..., x_true=...)``).

The step's NEES is checked against :meth:`KalmanResult.nees` on the stored x and P (the
same form on the correlation matrix, computed by NumPy), for SX and MX steps, single runs
and banks, an angle state, the C loop and CasADi's VM, the adaptive strategy (which
computes it from x and P); then a lean bank that keeps no state, and the refusals.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ShapeError, SingularMatrixError, SymmonError
from symmon.filters.gaussian.step import compiled_step

#: The step's NEES and NumPy's from the same x and P: the same quadratic form through two
#: factorisations, so they agree to a few condition numbers of the correlation matrix times
#: the rounding unit (1e-13 measured for the 10-state EKF); 1e-10 leaves room for that.
NEES_RTOL = 1e-10

F_CV = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
Q_CV = 0.05 * np.kron(np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]), np.eye(2))
R_RB = np.diag([0.5**2, 0.02**2])
X0 = sm.Gaussian([20.0, 5.0, -1.0, 0.5], np.diag([1.0, 1.0, 0.1, 0.1]))


def stacked(k: int):
    """k constant-velocity targets with range–bearing measurements (4k states; MX from 10)."""
    X, fo, ho = [], [], []
    for i in range(k):
        px, py, vx, vy = sp.symbols(f"px{i} py{i} vx{i} vy{i}", real=True)
        X += [px, py, vx, vy]
        fo += [px + vx, py + vy, vx, vy]
        ho += [sp.sqrt(px**2 + py**2), sp.atan2(py, px)]
    f = sm.Model(X, fo, name=f"nees_cv{k}")
    h = sm.Model(X, ho, name=f"nees_rb{k}", angles=list(range(1, 2 * k, 2)))
    Q, R = np.kron(np.eye(k), Q_CV), np.kron(np.eye(k), R_RB)
    x0 = sm.Gaussian(np.concatenate([X0.mean + [5.0 * i, -3.0 * i, 0, 0] for i in range(k)]), np.kron(np.eye(k), X0.cov))
    return f, h, Q, R, x0


def simulate(f, h, Q, R, x0: sm.Gaussian, K: int, runs: int, seed: int):
    rng = np.random.default_rng(seed)
    F = np.array(sp.Matrix(f.outputs).jacobian(f.inputs), dtype=float)
    hx = sp.lambdify(f.inputs, h.outputs, "numpy")
    x = x0.mean + rng.standard_normal((runs, x0.dim)) @ np.linalg.cholesky(x0.cov).T
    xs, ys = np.empty((runs, K, x0.dim)), np.empty((runs, K, h.n_y))
    for k in range(K):
        x = x @ F.T + rng.standard_normal(x.shape) @ np.linalg.cholesky(Q).T
        xs[:, k] = x
        ys[:, k] = np.stack(hx(*x.T), axis=-1) + rng.standard_normal((runs, h.n_y)) @ np.linalg.cholesky(R).T
    return xs, ys


@pytest.fixture(scope="module", params=[1, 3], ids=["sx4", "mx12"])
def problem(request):
    f, h, Q, R, x0 = stacked(request.param)
    xs, ys = simulate(f, h, Q, R, x0, 20, 5, seed=request.param)
    return f, h, Q, R, x0, xs, ys


@pytest.mark.parametrize("transform", [sm.TT1(), sm.UT(1, 2, 0)], ids=repr)
def test_step_nees_equals_nees_from_x_and_p(problem, transform):
    f, h, Q, R, x0, xs, ys = problem
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, transform)
    res = kf.filter(ys, x0, x_true=xs)
    assert res.nees_values.shape == (5, 20)
    np.testing.assert_allclose(res.nees(), res.nees(xs), rtol=NEES_RTOL)
    one = kf.filter(ys[2], x0, x_true=xs[2])
    assert one.nees().shape == (20,)
    np.testing.assert_allclose(one.nees(), res.nees()[2], rtol=NEES_RTOL)
    np.testing.assert_allclose(res.anees().value, res.anees(xs).value, rtol=NEES_RTOL)


def test_step_nees_of_the_vm_equals_the_c_loop(problem):
    f, h, Q, R, x0, xs, ys = problem
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1())
    step = compiled_step(f, h, kf.transform, kf.angle_states)
    assert step._lib.wait(600) and step.is_compiled  # a large step builds in the background
    c = step(x0.mean, x0.cov, ys, Q, R, truth=xs)
    vm = step(x0.mean, x0.cov, ys, Q, R, use_c=False, truth=xs)
    for name in ("nees", "nees_trace"):
        np.testing.assert_allclose(c[name], vm[name], rtol=NEES_RTOL)


def test_a_lean_bank_keeps_its_nees_without_x_and_p(problem):
    f, h, Q, R, x0, xs, ys = problem
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT(1, 2, 0))
    full = kf.filter(ys, x0)
    lean = kf.filter(ys, x0, keep=("nis",), x_true=xs)
    assert lean.x is None and lean.P is None and lean.n == f.n_u
    np.testing.assert_allclose(lean.nees(), full.nees(xs), rtol=NEES_RTOL)
    test = lean.anees()
    assert test.dof == 5 * f.n_u and test.value.shape == (20,)
    with pytest.raises(SymmonError, match="does not hold x, P"):
        lean.nees(xs)  # a truth other than the step's needs the stored x and P


def test_an_angle_state_error_is_wrapped_in_the_step():
    """A heading state near ±π: the truth just across the cut is a small error, not 2π."""
    th, om = sp.symbols("theta omega", real=True)
    f = sm.Model([th, om], [th + om, om], name="nees_turn", angles=[0])
    h = sm.Model([th, om], [sp.cos(th), sp.sin(th)], name="nees_unit")
    K = 12
    truth = np.column_stack([np.angle(np.exp(1j * (2.6 + 0.15 * np.arange(1, K + 1)))), np.full(K, 0.15)])
    ys = np.column_stack([np.cos(truth[:, 0]), np.sin(truth[:, 0])]) + 0.05 * np.random.default_rng(5).standard_normal((K, 2))
    kf = sm.NonlinearKalmanFilter(f, h, np.diag([1e-3, 1e-4]), 0.05**2 * np.eye(2), sm.TT1())
    res = kf.filter(ys, sm.Gaussian([2.6, 0.1], np.diag([0.05, 0.01])), x_true=truth)
    np.testing.assert_allclose(res.nees(), res.nees(truth), rtol=NEES_RTOL)
    assert res.nees().max() < 50  # an unwrapped error of 2π would be hundreds of standard deviations


def test_the_adaptive_filter_computes_the_nees_from_x_and_p():
    f, h, Q, R, x0 = stacked(1)
    xs, ys = simulate(f, h, Q, R, x0, 8, 2, seed=0)
    res = sm.NonlinearKalmanFilter(f, h, Q, R, sm.Adaptive(0.01)).filter(ys, x0, x_true=xs)
    np.testing.assert_array_equal(res.nees(), res.nees(xs))


@pytest.mark.parametrize("transform", [sm.TT1(), sm.Adaptive(0.01)], ids=["step", "adaptive"])
def test_a_singular_p_is_refused_naming_the_step(transform):
    """A state with no prior variance and no process noise stays known exactly: P singular."""
    a, b = sp.symbols("a b", real=True)
    f = sm.Model([a, b], [a, b], name="nees_static")
    h = sm.Model([a, b], [a + b], name="nees_sum")
    kf = sm.NonlinearKalmanFilter(f, h, np.diag([0.0, 0.1]), [[0.1]], transform)
    with pytest.raises(SingularMatrixError, match=r"state covariance P at step 0 is singular"):
        kf.filter(np.ones((3, 1)), [0.0, 0.0], np.diag([0.0, 1.0]), x_true=np.zeros((3, 2)))


@pytest.mark.parametrize("bad, error, message", [
    (np.zeros((5, 3)), ShapeError, r"x_true must have the shape of x, \(5, 4\), got \(5, 3\)"),
    (np.zeros((2, 5, 4)), ShapeError, r"x_true must have the shape of x, \(5, 4\)"),
    (np.full((5, 4), np.nan), ShapeError, "x_true contains NaN or inf"),
    (np.zeros((5, 4), dtype=complex), ShapeError, "x_true holds complex numbers"),
])
def test_bad_truths_are_refused_before_the_run(bad, error, message):
    f, h, Q, R, x0 = stacked(1)
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1())
    with pytest.raises(error, match=message):
        kf.filter(np.ones((5, 2)), x0, x_true=bad)


def test_nees_without_a_truth_says_what_to_give():
    f, h, Q, R, x0 = stacked(1)
    res = sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1()).filter(np.ones((3, 2)), x0)
    assert res.nees_values is None
    with pytest.raises(SymmonError, match="give x_true, or filter with x_true="):
        res.nees()
