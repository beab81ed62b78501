"""Time-varying SDEs, dx = a(x, t) dt + L(x, t) dβ: the declaration and the discretisations.

The reference is the closed form of a linear SDE with a forcing and a diffusion in t,

    dx = (−x + sin t) dt + σ (1 + t) dβ,

whose mean and variance from (m0, P0) at a to b are

    m(b) = e^{−(b−a)} m0 + ∫_a^b e^{−(b−s)} sin s ds,
    P(b) = e^{−2(b−a)} P0 + σ² ∫_a^b e^{−2(b−s)} (1 + s)² ds,

both integrals by their antiderivatives (checked here by differentiation): no discretisation
shares them.  Every discretisation of this SDE is affine in x and w, so its mean and variance
over N steps are computed exactly from its coefficients (no Monte Carlo), and their errors
fall at the methods' orders in the step.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import DiscretizationError, ModelError

from helpers import forced_moments as closed_form, forced_sde

FORCED = forced_sde()
x, t = FORCED.states[0], FORCED.time
s_ = sp.Symbol("sigma", positive=True)


def test_the_antiderivatives_of_the_closed_form_are_right():
    """d/ds of each antiderivative is its integrand, exactly."""
    s, b = sp.symbols("s b", real=True)
    mean_part = sp.exp(-(b - s)) * (sp.sin(s) - sp.cos(s)) / 2
    assert sp.simplify(sp.diff(mean_part, s) - sp.exp(-(b - s)) * sp.sin(s)) == 0
    var_part = sp.exp(2 * s) * ((1 + s) ** 2 / 2 - (1 + s) / 2 + sp.Rational(1, 4))
    assert sp.simplify(sp.diff(var_part, s) - sp.exp(2 * s) * (1 + s) ** 2) == 0


def test_the_time_symbol_is_declared_and_checked():
    assert FORCED.time == t and not FORCED.is_time_invariant and FORCED.is_linear
    A, b = FORCED.linear_parts
    assert A == sp.Matrix([[-1]]) and b == sp.Matrix([sp.sin(t)])
    # Declared but unused: time-invariant, and discretised as before (no parameter t).
    plain = sm.SDE([x], [-x], time=t)
    assert plain.is_time_invariant and plain.discretize("euler").params == (sp.Symbol("dt", positive=True),)
    assert sm.SDE([x], [-x]).time is None and "time=t" in repr(FORCED)
    with pytest.raises(ModelError, match="unknown symbols"):
        sm.SDE([x], [-x + sp.sin(t)])                         # t not declared
    with pytest.raises(ModelError, match="also a state or a parameter"):
        sm.SDE([x], [-x], time=x)
    with pytest.raises(ModelError, match="also a state or a parameter"):
        sm.SDE([x], [-s_ * x], params=[s_], time=s_)
    with pytest.raises(ModelError, match="must be a sympy Symbol"):
        sm.SDE([x], [-x], time="t")
    with pytest.raises(ModelError, match="Q_c must be constant"):
        sm.SDE([x], [-x], spectral_density=1 + t ** 2, time=t)


def test_exact_refuses_a_time_varying_sde_naming_the_alternatives():
    for call in (lambda: FORCED.discretize("exact"), FORCED.noise_cov, FORCED.transition_matrix):
        with pytest.raises(DiscretizationError, match="time-invariant SDE.*'rk4', 'taylor1.5'"):
            call()
    with pytest.raises(ModelError, match="or the time symbol"):
        FORCED.discretize("euler", dt=t)


@pytest.mark.parametrize("method", ["euler", "rk4", "taylor1.5", "local_linear"])
def test_the_step_start_time_is_a_parameter_and_the_substeps_advance_it(method):
    """f(x, w; t, dt) with N sub-steps is N one-sub-step maps, sub-step j at t + j dt/N:
    evaluated at numbers, to rounding."""
    f1 = FORCED.discretize(method)
    f4 = FORCED.discretize(method, substeps=4)
    assert [str(p) for p in f1.params] == ["t", "dt"] == [str(p) for p in f4.params]
    rng = np.random.default_rng(1)
    w = rng.standard_normal(f4.n_v)
    t0, dt, x0 = 1.3, 0.8, 0.4
    composed = float(f4.outputs[0].subs({x: x0, t: t0, sp.Symbol("dt", positive=True): dt,
                                         **dict(zip(f4.noise, w))}).evalf(30))
    cur, per = x0, f1.n_v
    for j in range(4):
        cur = float(f1.outputs[0].subs({x: cur, t: t0 + j * dt / 4, sp.Symbol("dt", positive=True): dt / 4,
                                        **dict(zip(f1.noise, w[j * per:(j + 1) * per]))}).evalf(30))
    assert composed == pytest.approx(cur, rel=1e-12)


def _affine_steps(model: sm.Model):
    """(α, β, γ) of f = α x + β + γᵀ w as numeric functions of (t, dt)."""
    out = model.outputs[0]
    dt = next(p for p in model.params if str(p) == "dt")
    zero = {x: 0, **{w: 0 for w in model.noise}}
    alpha = sp.lambdify((t, dt), sp.diff(out, x).subs(zero))
    beta = sp.lambdify((t, dt), out.subs(zero))
    gamma = [sp.lambdify((t, dt), sp.diff(out, w).subs(zero)) for w in model.noise]
    assert all(sp.diff(out, v, 2) == 0 for v in (x, *model.noise))  # affine: exact moments below
    return alpha, beta, gamma


#: (mean order, variance order) in the step h: Euler 1 and 1; the order-1.5 scheme's mean is
#: its second-order Taylor step (with ∂a/∂t in L⁰a) and its variance holds ∂b/∂t (ΔW h − ΔZ),
#: 2 and 2 (without that term the variance's order is 1: measured 1.04); RK4's mean 4, its
#: noise the linearised flow's with L at the mid-time, 2; the local linearisation in x and t,
#: 2 and 2.  Measured slopes between N = 32 and 64: 1.008/1.011, 2.037/1.978, 4.008/1.999,
#: 2.013/2.000.
ORDERS = {"euler": (1, 1), "taylor1.5": (2, 2), "rk4": (4, 2), "local_linear": (2, 2)}


@pytest.mark.parametrize("method", sorted(ORDERS))
def test_the_discretisations_converge_to_the_closed_form_at_their_orders(method):
    """Over [0.4, 2.4] in N = 8 … 64 steps: the exact moments of the discretised chain
    against the closed form; the slopes of log2 |error| between successive N within 0.15 of
    the order (the measured ones are within 0.04 at the finest pair; 0.16 at the coarsest)."""
    alpha, beta, gamma = _affine_steps(FORCED.discretize(method))
    a, b, m0, P0 = 0.4, 2.4, 0.3, 0.2
    mc, Pc = closed_form(m0, P0, a, b)
    errors = []
    for N in (8, 16, 32, 64):
        h = (b - a) / N
        m, P = m0, P0
        for j in range(N):
            tj = a + j * h
            A = alpha(tj, h)
            m, P = A * m + beta(tj, h), A * A * P + sum(g(tj, h) ** 2 for g in gamma)
        errors.append((abs(m - mc), abs(P - Pc)))
    errors = np.array(errors)
    slopes = np.log2(errors[:-1] / errors[1:])
    order_m, order_P = ORDERS[method]
    assert np.all(np.abs(slopes[1:, 0] - order_m) < 0.15), slopes
    assert np.all(np.abs(slopes[1:, 1] - order_P) < 0.15), slopes
