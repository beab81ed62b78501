"""The compiled continuous-discrete filter (the Dormand–Prince loop of ``cd_loop.c``) against
what does not share it: solve_ivp's RK45 on the same equations (the Python integrator, whose
steps the C takes), an independent solution at rtol 1e-12, and the exact discretisation of a
linear SDE; its hand-back to Python for a run it cannot integrate.

Tolerances.  The C replicates solve_ivp's RK45 step-size control (its initial step, error norm
and factors), so the two take the same steps and differ by rounding: measured 1e-15 relative
to each array's scale on these problems; 1e-11 allows for another BLAS's rounding (FMA) in the
Python side's products, and is 10⁵ times below the ODE tolerance rtol = 1e-6, which a
different step sequence would show.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate
import sympy as sp

import symmon as sm
from helpers import assert_close_to_scale
from symmon.compile.ccache import has_compiler
from symmon.errors import ArgumentError

pytestmark = pytest.mark.skipif(not has_compiler(), reason="no C compiler: the CD filter integrates by solve_ivp")

x1, x2 = sp.symbols("x1 x2", real=True)
tau = sp.Symbol("tau", real=True)
#: Van der Pol with a state-dependent diffusion (D depends on x: averaged over the points).
VDP = sm.SDE([x1, x2], [x2, (1 - x1**2) * x2 - x1], diffusion=[[0.3, 0], [0, 0.5 + 0.1 * x1**2]], name="vdp_c")
#: A time-varying one: the drift's rate follows the time.
TV = sm.SDE([x1, x2], [x2, -(1 + 0.5 * sp.sin(tau)) * x1 - 0.2 * x2], diffusion=[0, 1], time=tau, name="tv_c")
H = sm.Model([x1, x2], [x1], name="cdc_h")
TIMES = np.cumsum(np.random.default_rng(1).uniform(0.05, 0.6, size=30))
YS = np.stack([2 * np.sin(TIMES), 2 * np.cos(TIMES)])[:, :, None]  # a bank of two runs
X0, P0 = np.array([[1.0, 0.0], [0.5, -0.5]]), np.array([[0.2, 0.05], [0.05, 0.3]])
FORMS = [("ekf", False), ("ekf", True), ("ukf", False), ("ukf", True), ("ckf", False), (sm.GaussHermite(3), True)]


def _pair(sde, transform, square_root, **kw):
    c = sm.ContinuousDiscreteKalmanFilter(sde, H, [[0.1]], transform, square_root=square_root, **kw)
    py = sm.ContinuousDiscreteKalmanFilter(sde, H, [[0.1]], transform, square_root=square_root,
                                           integrator="solve_ivp", **kw)
    return c, py


@pytest.mark.parametrize("sde", [VDP, TV], ids=["vdp", "time-varying"])
@pytest.mark.parametrize("transform, square_root", FORMS)
def test_the_compiled_filter_and_smoother_take_solve_ivps_steps(sde, transform, square_root):
    c, py = _pair(sde, transform, square_root)
    rc = c.filter(YS, X0, P0, times=TIMES)
    assert c.evaluator == "compiled" and py.evaluator == "solve_ivp"
    rp = py.filter(YS, X0, P0, times=TIMES)
    for key in ("x", "P", "x_pred", "P_pred", "innovation", "S"):
        assert_close_to_scale(getattr(rc, key), getattr(rp, key), 1e-11)
    assert rc.log_likelihood == pytest.approx(rp.log_likelihood, rel=1e-11)
    if square_root:
        assert_close_to_scale(rc.P_chol, rp.P_chol, 1e-11)
    sc, sp_ = c.smooth(YS, X0, P0, times=TIMES), py.smooth(YS, X0, P0, times=TIMES)
    assert_close_to_scale(sc.x, sp_.x, 1e-11)
    assert_close_to_scale(sc.P, sp_.P, 1e-11)


def _vdp_rhs(t, z):
    """Eq. (1) for TT1 on VDP, in numpy: dm = a(m), dP = A P + P Aᵀ + L Lᵀ (Q_c = I) at m."""
    m, P = z[:2], z[2:].reshape(2, 2)
    A = np.array([[0.0, 1.0], [-2 * m[0] * m[1] - 1, 1 - m[0] ** 2]])
    L = np.diag([0.3, 0.5 + 0.1 * m[0] ** 2])
    a = np.array([m[1], (1 - m[0] ** 2) * m[1] - m[0]])
    return np.concatenate([a, (A @ P + P @ A.T + L @ L.T).ravel()])


@pytest.mark.parametrize("square_root", [False, True])
def test_one_interval_matches_an_independent_solution_at_rtol_1e_12(square_root):
    """The compiled predict (eq. (1), or eq. (2) for the factor) at rtol 1e-12 against DOP853
    at rtol 1e-13 on the numpy equations: moments of size ~1, so 1e-10 is the tolerance's
    accumulation over the steps with two orders to spare."""
    m0, dt = np.array([1.2, -0.3]), 0.8
    ref = scipy.integrate.solve_ivp(_vdp_rhs, (0, dt), np.concatenate([m0, P0.ravel()]), method="DOP853",
                                    rtol=1e-13, atol=1e-15).y[:, -1]
    c = sm.ContinuousDiscreteKalmanFilter(VDP, H, [[0.1]], "ekf", rtol=1e-12, atol=1e-14, square_root=square_root)
    m, P = c.predict(m0, P0, dt)
    assert c.evaluator == "compiled"
    np.testing.assert_allclose(m, ref[:2], rtol=0, atol=1e-10)
    np.testing.assert_allclose(P, ref[2:].reshape(2, 2), rtol=0, atol=1e-10)
    assert np.abs(P - P0).max() > 0.1  # the interval moves the moments


@pytest.mark.parametrize("transform, square_root", FORMS)
def test_on_a_linear_sde_one_interval_is_the_exact_discretisation(transform, square_root):
    """At rtol 1e-10 against e^{A dt} and Van Loan's Q(dt) (eq. (4)): 1e-8 of the moments' scale."""
    q, th = sp.symbols("q theta", positive=True)
    iou = sm.SDE([x1, x2], [x2, -th * x2], diffusion=[0, 1], spectral_density=q, params=[q, th], name="iou_c")
    kw = dict(rtol=1e-10, atol=1e-12, square_root=square_root)
    c = sm.ContinuousDiscreteKalmanFilter(iou, H, [[0.1]], transform, **kw)
    exact = sm.ContinuousDiscreteKalmanFilter(iou, H, [[0.1]], "ekf", exact=True, **kw)
    m0, Pm = np.array([0.0, 10.0]), np.diag([25.0, 4.0])
    m, P = c.predict(m0, Pm, 2.3, [0.5, 0.7])
    me, Pe = exact.predict(m0, Pm, 2.3, [0.5, 0.7])
    assert c.evaluator == "compiled"
    assert_close_to_scale(m, me, 1e-8)
    assert_close_to_scale(P, Pe, 1e-8)


def test_a_bank_in_shards_gives_the_whole_banks_numbers_bit_for_bit():
    c = sm.ContinuousDiscreteKalmanFilter(VDP, H, [[0.1]], "ukf")
    whole = c.filter(YS, X0, P0, times=TIMES)
    for r in range(2):
        alone = c.filter(YS[r], X0[r], P0, times=TIMES)
        assert np.array_equal(alone.x, whole.x[r]) and np.array_equal(alone.P, whole.P[r])


def test_a_run_the_loop_cannot_integrate_goes_on_in_python():
    """Run 1 starts with a zero variance: the C's Cholesky factor of the points refuses it, and
    solve_ivp's integrator (its square root by eigh) continues the run from that step; run 0
    stays in C.  So run 1 is the Python filter's bit for bit, run 0 to rounding."""
    P0s = np.stack([P0, np.diag([0.2, 0.0])])
    c, py = _pair(VDP, "ukf", False)
    rc, rp = c.filter(YS, X0, P0s, times=TIMES), py.filter(YS, X0, P0s, times=TIMES)
    assert np.array_equal(rc.x[1], rp.x[1]) and np.array_equal(rc.P[1], rp.P[1])
    assert_close_to_scale(rc.x[0], rp.x[0], 1e-11)


def test_the_integrator_is_checked():
    with pytest.raises(ArgumentError, match="integrator must be one of 'auto', 'solve_ivp'"):
        sm.ContinuousDiscreteKalmanFilter(VDP, H, [[0.1]], "ekf", integrator="rk4")
    exact = sm.ContinuousDiscreteKalmanFilter(TV.__class__([x1], [-x1], diffusion=[1]), sm.Model([x1], [x1]),
                                              [[0.1]], "ekf", exact=True)
    assert exact.evaluator == "exact"
