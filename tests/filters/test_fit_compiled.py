"""The compiled log-likelihood of the fit (symmon.filters.gaussian.fit._CompiledLoglik).

The C loop folds the same step function as the VM graph (_loglik_graph) over the steps and
runs, so its value agrees to rounding (1e-12 relative); its gradient and Hessian are CasADi's
derivatives of that step, in forward mode (tangents carried through the steps, the default
for a filter of few parameters) or reverse mode (a reverse sweep, and forward over reverse
for the Hessian), so both agree with ca.gradient / ca.hessian of the VM graph, and with each
other, to rounding (1e-10 relative to the largest entry: sums of a few thousand terms of
mixed sign).  The model is tests/filters/test_fit.py's
(a range bias b and a noise intensity q, the bearing an angle); the bank has missing
components and a missing step.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import symmon as sm
from symmon.filters.gaussian import fit as fitmod
from symmon.filters.inputs import check_call

from test_fit import X0, data, kf


def bank():
    """3 runs of 20 steps with a missing component and a missing step."""
    _, ys = data(5, runs=3, K=20)
    ys[0, 3, 1] = np.nan  # one component
    ys[1, 7] = np.nan  # a whole step
    return ys


@pytest.fixture(scope="module", params=["TT1", "UT", "TT1 reverse"])
def problem(request):
    k = kf(sm.UT.ut1() if request.param == "UT" else sm.TT1())
    if request.param.endswith("reverse"):
        compiled = fitmod._CompiledLoglik(k, forward=False)
    else:
        compiled = fitmod.compiled_loglik(k)
        assert compiled.forward and compiled.forward_hessian  # two parameters: forward mode
    assert compiled.wait()  # both libraries built (the fit itself does not wait)
    return k, bank(), compiled


@pytest.mark.parametrize("fitted", [[0, 1], [1]])
def test_value_gradient_and_hessian_are_the_vm_graphs(problem, fitted):
    k, ys, compiled = problem
    values = {"q": 0.25, "b": 1.0}
    checked = check_call(k, ys, X0, None, params=values)
    ev = compiled.bind(fitmod._step_data(checked.Y, checked.pv),
                       fitmod._initial_states(checked.x0, checked.P0, ys.shape[0]), k.Q, k.R, fitted)
    theta, total = fitmod._loglik_graph(k, checked.Y, checked.x0, checked.P0, checked.pv, fitted)
    vm = ca.Function("vm", [theta], [total, ca.gradient(total, theta), ca.hessian(total, theta)[0]])
    names = [str(s) for s in k.params]
    for t in ([values[names[j]] for j in fitted], [0.31 + 0.2 * j for j in range(len(fitted))]):
        t = np.array(t, dtype=float)
        value, grad, hess = ev(t, 2)
        v0, g0, _ = ev(t, 0)
        v1, g1, _ = ev(t, 1)
        ref_v, ref_g, ref_h = (np.asarray(a, dtype=float) for a in vm(t))
        assert value == pytest.approx(float(ref_v.item()), rel=1e-12)
        assert v0 == value and v1 == value and np.all(g0 == 0.0)  # order 0: the value only
        np.testing.assert_allclose(grad, ref_g.ravel(), rtol=0, atol=1e-10 * np.max(np.abs(ref_g)))
        np.testing.assert_array_equal(g1, grad)
        np.testing.assert_allclose(hess, ref_h, rtol=0, atol=1e-10 * np.max(np.abs(ref_h)))
        np.testing.assert_allclose(hess, hess.T, rtol=0, atol=1e-10 * np.max(np.abs(ref_h)))


def test_the_fit_on_the_compiled_loglik_is_the_fit_on_the_vm(problem, monkeypatch):
    """The same estimates, standard errors and log-likelihood with and without the C (the
    optimiser sees gradients equal to rounding, so its iterates agree to well below gtol)."""
    k, _, compiled = problem
    _, ys = data(7, runs=10)
    ys[2, 4] = np.nan
    monkeypatch.setattr(fitmod, "compiled_loglik", lambda kf: compiled)  # this mode's library
    fast = k.fit(ys, X0, {"q": 0.1, "b": 0.0}, bounds={"q": (1e-6, None)})
    monkeypatch.setattr(fitmod._CompiledLoglik, "bind", lambda self, *a: None)
    slow = k.fit(ys, X0, {"q": 0.1, "b": 0.0}, bounds={"q": (1e-6, None)})
    assert fast.iterations == slow.iterations
    for name in ("q", "b"):
        assert fast.estimates[name] == pytest.approx(slow.estimates[name], rel=1e-9)
        assert fast.std_errors[name] == pytest.approx(slow.std_errors[name], rel=1e-8)
    assert fast.log_likelihood == pytest.approx(slow.log_likelihood, rel=1e-12)


def test_one_library_per_filter_whatever_the_data():
    k = kf()
    assert fitmod.compiled_loglik(k) is fitmod.compiled_loglik(kf())
    assert fitmod.compiled_loglik(kf(sm.UT.ut1())) is not fitmod.compiled_loglik(k)


@pytest.fixture(scope="module")
def both_modes():
    """The EKF's compiled log-likelihood in forward mode (its default) and in reverse mode."""
    k = kf()
    fwd, rev = fitmod.compiled_loglik(k), fitmod._CompiledLoglik(k, forward=False)
    assert fwd.forward and fwd.forward_hessian and not (rev.forward or rev.forward_hessian)
    assert fwd.wait() and rev.wait()
    return k, fwd, rev


@pytest.mark.parametrize("fitted", [[0, 1], [1, 0], [0]])
def test_forward_and_reverse_modes_agree(both_modes, fitted):
    """ℓ to the bit (the same steps), ∇ℓ and ∇²ℓ to rounding, for each subset and order of the
    fitted parameters (a tangent per parameter of the filter: the unfitted ones carry zeros)."""
    k, fwd, rev = both_modes
    ys = bank()
    checked = check_call(k, ys, X0, None, params={"q": 0.25, "b": 1.0})
    args = (fitmod._step_data(checked.Y, checked.pv), fitmod._initial_states(checked.x0, checked.P0, ys.shape[0]),
            k.Q, k.R, fitted)
    ev_f, ev_r = fwd.bind(*args), rev.bind(*args)
    for t in (np.full(len(fitted), 0.4), np.linspace(0.2, 1.3, len(fitted))):
        (vf, gf, hf), (vr, gr, hr) = ev_f(t, 2), ev_r(t, 2)
        assert vf == vr
        np.testing.assert_allclose(gf, gr, rtol=0, atol=1e-10 * np.max(np.abs(gr)))
        np.testing.assert_allclose(hf, hr, rtol=0, atol=1e-10 * np.max(np.abs(hr)))
        np.testing.assert_array_equal(hf, hf.T)  # both triangles from the same sums
        np.testing.assert_array_equal(ev_f(t, 1)[1], gf)  # the gradient sweep is the Hessian's first order


def test_the_mode_follows_the_number_of_parameters(monkeypatch):
    k = kf()  # two parameters
    assert fitmod.compiled_loglik(k).forward
    monkeypatch.setattr(fitmod, "FORWARD_HESSIAN_MAX_PARAMS", 1)
    mixed = fitmod._CompiledLoglik(k)  # a forward gradient, the Hessian forward over reverse
    assert mixed.forward and not mixed.forward_hessian
    monkeypatch.setattr(fitmod, "FORWARD_MAX_PARAMS", 1)
    rev = fitmod._CompiledLoglik(k)
    assert not (rev.forward or rev.forward_hessian)
    stems = [[lib.stem for lib in c._libs] for c in (rev, mixed, fitmod.compiled_loglik(k))]
    assert stems[0] == [lib.stem for lib in fitmod._CompiledLoglik(k, forward=False)._libs]
    assert mixed.forward and stems[1] == [stems[2][0], stems[0][1]]  # the modes' own libraries
    assert len(set(stems[0] + stems[2])) == 4


def test_a_forward_gradient_with_a_reverse_hessian(both_modes, monkeypatch):
    """The libraries of the two modes mixed (the default for three parameters): the same
    numbers as either mode alone (the same libraries), the work arrays large enough for both
    drivers."""
    k, fwd, rev = both_modes
    monkeypatch.setattr(fitmod, "FORWARD_HESSIAN_MAX_PARAMS", 1)
    mixed = fitmod._CompiledLoglik(k)
    assert mixed.wait()
    ys = bank()
    checked = check_call(k, ys, X0, None, params={"q": 0.25, "b": 1.0})
    args = (fitmod._step_data(checked.Y, checked.pv), fitmod._initial_states(checked.x0, checked.P0, ys.shape[0]),
            k.Q, k.R, [1, 0])
    t = np.array([0.7, 0.2])
    ev, ev_f, ev_r = mixed.bind(*args), fwd.bind(*args), rev.bind(*args)
    v1, g1, _ = ev(t, 1)
    v2, g2, h2 = ev(t, 2)
    assert v1 == ev_f(t, 1)[0] and np.array_equal(g1, ev_f(t, 1)[1])  # the forward library
    assert v2 == ev_r(t, 2)[0] and np.array_equal(g2, ev_r(t, 2)[1]) and np.array_equal(h2, ev_r(t, 2)[2])


def test_the_optimiser_runs_on_one_blas_thread(monkeypatch):
    """SciPy's L-BFGS-B runs under one BLAS thread (an OpenBLAS woken for its size-m algebra
    spins beside the C loop), and the limit is lifted afterwards."""
    import threadpoolctl

    k = kf()
    _, ys = data(7, runs=10)  # the fit of test_the_fit_on_the_compiled_loglik_is_the_fit_on_the_vm
    before = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    seen = []
    minimize = fitmod.optimize.minimize

    def spy(*a, **kw):
        seen.append([i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"])
        return minimize(*a, **kw)

    monkeypatch.setattr(fitmod.optimize, "minimize", spy)
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):  # two threads, whatever the machine
        k.fit(ys, X0, {"q": 0.2, "b": 0.5}, bounds={"q": (1e-6, None)})
        after = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    assert seen and all(n == 1 for n in seen[0])
    assert after == [2] * len(after)
    assert [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"] == before


@pytest.mark.parametrize("mode", ["forward", "reverse"])
def test_the_columns_on_threads_are_one_calls(both_modes, monkeypatch, mode):
    """With the columns of the Hessian (and of a forward gradient) split over threads (each
    part its own work and out), ℓ, ∇ℓ and ∇²ℓ are those of one call to the bit: every entry
    comes from exactly one part, and a tangent's column is the same sums alone or with others."""
    k, fwd, rev = both_modes
    compiled = fwd if mode == "forward" else rev
    ys = bank()
    checked = check_call(k, ys, X0, None, params={"q": 0.25, "b": 1.0})
    args = (fitmod._step_data(checked.Y, checked.pv), fitmod._initial_states(checked.x0, checked.P0, ys.shape[0]),
            k.Q, k.R, [1, 0])
    one = compiled.bind(*args)
    monkeypatch.setattr(fitmod, "THREAD_WORK", 0)
    monkeypatch.setattr(fitmod, "cpu_count", lambda: 2)
    split = compiled.bind(*args)
    t = np.array([0.7, 0.2])
    for order in (0, 1, 2):
        (v1, g1, h1), (v2, g2, h2) = one(t, order), split(t, order)
        assert v1 == v2 and np.array_equal(g1, g2) and np.array_equal(h1, h2)
    assert np.all(h2 != 0)  # both parts' columns are in
    np.testing.assert_allclose(h2, h2.T, rtol=1e-10)
