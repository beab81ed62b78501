"""The particle filter's compiled recursion by blocks (symmon/filters/pf_kernel.py): the
vectorised move and weigh (symmon.compile.vecmath's row loop, for models whose operations
all have vector forms), its fallback to CasADi's function for the rows it flags, the
whitening in the driver, the select-free angle wrap, and the Gaussian prior drawn in C.

The vectorised loop uses vecmath's atan2 and hypot (within 1 ulp of libm's), so it agrees
with the per-particle CasADi path to rounding: 1e-9 absolute on means of order 10 (the
difference is a few ulp per step, far below the Monte Carlo error); a row the loop flags is
recomputed by CasADi's function, so with every row flagged the two agree bit for bit.
"""

from __future__ import annotations

import math
import threading

import casadi as ca
import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import has_compiler
from symmon.core.angles import wrap_casadi
from symmon.filters.particle._kernel import MIN_THREAD_NUMBERS, BootstrapKernel, _wrap
from symmon.filters.particle._rng import CHUNK

pytestmark = pytest.mark.skipif(not has_compiler(), reason="the compiled step needs a C compiler")

x1, x2, th, a, b, w1, w2 = sp.symbols("x1 x2 th a b w1 w2", real=True)
# Arithmetic, atan2 and sqrt only (every operation has a vector form), an angle state and two angle outputs.
F = sm.Model([x1, x2, th], [x1 + a * x2 + w1, 0.9 * x2 + w2, th + 0.1 * x2], angles=[2], noise=[w1, w2],
             params=[a], name="pfv_f")
H = sm.Model([x1, x2, th], [sp.atan2(x2 + 3, x1 + 5), sp.sqrt(x1 ** 2 + x2 ** 2 + 1), th], angles=[0, 2],
             name="pfv_h")
# atan2(x2, b x1) with b = 0: every row has a zero argument, which the vector loop flags.
H0 = sm.Model([x1, x2, th], [sp.atan2(x2, b * x1), x1 + x2], angles=[0], params=[b], name="pfv_h0")
Q = np.array([[0.2, 0.05], [0.05, 0.1]])
R = np.diag([0.01, 0.5, 0.05])
X0 = sm.Gaussian([0.0, 1.0, 3.0], np.diag([1.0, 0.5, 0.1]))
K = 5
N = 2 * CHUNK + 300  # several streams, blocks of 256 and a partial block


def with_kernel(pf: sm.ParticleFilter, vectorise: bool) -> sm.ParticleFilter:
    """``pf`` with its compiled step built with or without the vector loop."""
    ss = pf.space
    pf.__dict__["_bootstrap_kernel"] = BootstrapKernel(pf.f_model, pf.h_model, ss.params, np.asarray(ss.Lq) != 0,
                                                       ss.angle_states, ss.angle_outputs, vectorise=vectorise)
    # built now: a C above ccache.BACKGROUND_BYTES builds in the background, and a call
    # meanwhile takes the NumPy path (other draws)
    assert pf.__dict__["_bootstrap_kernel"]._native.wait(600)
    return pf


@pytest.fixture(scope="module")
def ys():
    _, y = sm.simulate(F, H, Q, R, X0, K, runs=2, params={"a": 0.5}, seed=3)
    y = y.copy()
    y[0, 2, 1] = np.nan  # a missing component
    y[1, 3] = np.nan  # a step without a measurement
    return y


def test_the_vector_loop_agrees_with_casadi_per_particle(ys):
    pfs = [with_kernel(sm.ParticleFilter(F, H, Q, R, particles=N, ess_threshold=0.7, seed=7), v) for v in (True, False)]
    assert pfs[0]._bootstrap_kernel.vectorised and not pfs[1]._bootstrap_kernel.vectorised
    vec, ref = (pf.filter(ys, X0, params={"a": 0.5}) for pf in pfs)
    for name in ("x", "P", "loglik", "ess", "innovation", "S"):
        np.testing.assert_allclose(getattr(vec, name), getattr(ref, name), rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_array_equal(vec.resampled, ref.resampled)
    assert vec.resampled.any() and np.all(vec.loglik[1, 3] == 0.0)


def test_a_model_with_another_operation_has_no_vector_loop():
    h = sm.Model([x1, x2, th], [sp.cos(th), x1], name="pfv_hcos")
    assert not sm.ParticleFilter(F, h, Q, np.eye(2), particles=10)._bootstrap_kernel.vectorised


def test_a_libm_function_of_the_parameters_keeps_the_vector_loop_bit_for_bit():
    """The growth model's 8 cos(1.2 k), k a per-step parameter, is evaluated once per step
    before the vector loop (symmon.compile.vecmath.vector_rows): the model has a vector loop,
    and with no atan2 or hypot in it its numbers are those of CasADi's function per particle,
    bit for bit."""
    x, k = sp.symbols("x k", real=True)
    f = sm.Model([x], [x / 2 + 25 * x / (1 + x**2) + 8 * sp.cos(sp.Rational(6, 5) * k)], params=[k], name="pfv_ungm_f")
    h = sm.Model([x], [x**2 / 20], name="pfv_ungm_h")
    steps, prior = 12, sm.Gaussian([0.0], [[5.0]])
    params = {"k": np.arange(1, steps + 1, dtype=float)}
    _, y = sm.simulate(f, h, [[10.0]], [[1.0]], prior, steps, params=params, seed=4)
    pfs = [with_kernel(sm.ParticleFilter(f, h, [[10.0]], [[1.0]], particles=N, ess_threshold=0.6, seed=9), v)
           for v in (True, False)]
    assert pfs[0]._bootstrap_kernel.vectorised and not pfs[1]._bootstrap_kernel.vectorised
    vec, ref = (pf.filter(y, prior, params=params, keep=("x", "P")) for pf in pfs)
    for name in ("x", "P", "loglik", "ess", "resampled", "final_particles"):
        np.testing.assert_array_equal(getattr(vec, name), getattr(ref, name), err_msg=name)


def test_flagged_rows_are_recomputed_by_casadi():
    """With b = 0 every row's atan2 has a zero argument: the vector loop flags them all and
    CasADi's function (libm) recomputes them, so the result is the per-particle path's, bit
    for bit."""
    R0 = np.diag([0.05, 0.5])
    _, y = sm.simulate(F, H0, Q, R0, X0, K, params={"a": 0.5, "b": 0.0}, seed=1)
    pfs = [with_kernel(sm.ParticleFilter(F, H0, Q, R0, particles=700, seed=2), v) for v in (True, False)]
    assert pfs[0]._bootstrap_kernel.vectorised
    vec, ref = (pf.filter(y, X0, params={"a": 0.5, "b": 0.0}, keep=("x", "P")) for pf in pfs)
    for name in ("x", "P", "loglik", "ess", "final_particles"):
        np.testing.assert_array_equal(getattr(vec, name), getattr(ref, name), err_msg=name)


def test_the_vector_loop_does_not_depend_on_the_threads(ys):
    """On the main thread the run uses min(CPUs, chunks) C threads, on another thread one."""
    pf = sm.ParticleFilter(F, H, Q, R, particles=N, ess_threshold=0.8, seed=5, regularise=True)
    main = pf.filter(ys[0], X0, params={"a": 0.5})
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("r", pf.filter(ys[0], X0, params={"a": 0.5})))
    t.start()
    t.join()
    for name in ("x", "P", "loglik", "ess", "innovation", "final_particles"):
        np.testing.assert_array_equal(getattr(main, name), getattr(box["r"], name), err_msg=name)


def test_the_wrap_without_select_is_wrap_casadi_to_the_bit():
    v = ca.SX.sym("v")
    ours, ref = ca.Function("w1", [v], [_wrap(v)]), ca.Function("w2", [v], [wrap_casadi(v)])
    pi = math.pi
    special = [-pi, pi, 3 * pi, -3 * pi, 5 * pi, 0.0, -0.0, np.nextafter(-pi, 0), np.nextafter(pi, 4), 2 * pi,
               -2 * pi, 1e-300, -1e-300, 1e15, -1e15, 1e300, np.inf, -np.inf, np.nan]
    vals = np.concatenate([special, np.random.default_rng(0).uniform(-60, 60, 5000),
                           (2 * np.arange(-40, 41) + 1) * pi])
    got, want = (np.array(fn(ca.DM(vals))).ravel() for fn in (ours, ref))
    np.testing.assert_array_equal(got, want)
    assert np.array_equal(np.signbit(got), np.signbit(want))


@pytest.mark.parametrize("cov", [np.array([[1.0, 0.6], [0.6, 2.0]]), np.diag([0.5, 3.0])])
def test_the_prior_drawn_in_c_has_the_prior_moments(cov):
    """A step without a measurement and a negligible Q: the final particles are the prior's
    draws (no resampling); their mean and covariance within 5 standard errors."""
    f = sm.Model([x1, x2], [x1, x2], name="pfv_id")
    h = sm.Model([x1, x2], [x1], name="pfv_h1")
    n_p, mean = 4000, np.array([2.0, -1.0])
    pf = sm.ParticleFilter(f, h, 1e-20 * np.eye(2), [[1.0]], particles=n_p, seed=11)
    parts = pf.filter(np.full((1, 1), np.nan), sm.Gaussian(mean, cov), keep=("x",)).final_particles
    assert not pf.filter(np.full((1, 1), np.nan), sm.Gaussian(mean, cov), keep=("x",)).resampled.any()
    se_mean = np.sqrt(np.diag(cov) / n_p)
    np.testing.assert_array_less(np.abs(parts.mean(axis=0) - mean), 5 * se_mean)
    C = np.cov(parts.T)
    se_cov = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov ** 2) / n_p)
    np.testing.assert_array_less(np.abs(C - cov), 5 * se_cov)


def test_a_missing_component_that_is_not_finite_is_ignored():
    """h's second output overflows (exp(800 x1) = inf) but is never measured: the weights
    are those of the filter with the first output alone, bit for bit."""
    f = sm.Model([x1, x2], [x1 + 0.1 * x2, x2], name="pfv_f2")
    h2 = sm.Model([x1, x2], [x1, sp.exp(800 * x1)], name="pfv_hexp")
    h1 = sm.Model([x1, x2], [x1], name="pfv_h1b")
    prior = sm.Gaussian([1.0, 0.0], np.diag([0.01, 0.01]))
    y = np.column_stack([np.linspace(1.0, 1.2, 4), np.full(4, np.nan)])
    Qa = 0.01 * np.eye(2)
    both = sm.ParticleFilter(f, h2, Qa, np.diag([0.1, 1.0]), particles=500, seed=3).filter(y, prior, keep=("x",))
    one = sm.ParticleFilter(f, h1, Qa, [[0.1]], particles=500, seed=3).filter(y[:, :1], prior, keep=("x",))
    for name in ("x", "loglik", "ess", "final_particles"):
        np.testing.assert_array_equal(getattr(both, name), getattr(one, name), err_msg=name)


def test_the_fallback_to_one_thread_keeps_the_numbers(ys):
    """A run of several threads that falls back to one (pf_kernel.c's pfk_solo: forced here
    after the first step's moves by an efficiency above 1), or whose threads find it closed
    (no wait for them to join: it may run alone from the start), gives the numbers of the run
    that never falls back, bit for bit: the final particles and log-weights of every chunk
    too."""
    n_two = 32 * CHUNK  # N (n + n_q) >= MIN_THREAD_NUMBERS: two threads (on a machine of two CPUs or more)
    assert n_two * 5 >= MIN_THREAD_NUMBERS
    pf = sm.ParticleFilter(F, H, Q, R, particles=n_two, ess_threshold=0.5, seed=5)
    solo = pf._bootstrap_kernel.built_loops()[4]
    runs = []
    # two threads (a wait of 10 s to join, busy CPUs or not) and never alone; another run's
    # streams (other numbers in the work arrays); alone from the second step; no wait to join
    for share, wait, first in ((0.0, 1e10, 0), (0.0, 1e10, 3), (2.0, 1e10, 0), (0.0, 1e10, 3), (0.0, 0.0, 0)):
        was = solo(share, wait, 0)
        try:
            runs.append(pf.filter(ys[0], X0, params={"a": 0.5}, keep=("x", "P"), first_run=first))
        finally:
            solo(was, 2e5, 1)
        assert was == 0.6
    ref = runs[0]
    assert ref.resampled.any() and not ref.resampled.all()
    for run in (runs[2], runs[4]):
        for name in ("x", "P", "loglik", "ess", "resampled", "final_particles", "final_log_weights"):
            np.testing.assert_array_equal(getattr(run, name), getattr(ref, name), err_msg=name)
