"""The weights recursion of a Gaussian sum without splitting (gsf_kernel.bank_weights): the C
loop against the NumPy one and against the closed form of the weights."""

import numpy as np
import pytest
from scipy.special import logsumexp

from symmon.compile import has_compiler
from symmon.filters.mixture import _kernel as gsf_kernel


class _NoCompiler:
    def get(self):
        return None


def _numpy(logw0, ll, monkeypatch):
    with monkeypatch.context() as mp:
        mp.setattr(gsf_kernel, "_weights", _NoCompiler())
        return gsf_kernel.bank_weights(logw0, ll)


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(3)
    R, M, K = 3, 11, 40  # M > 8: NumPy's sum is pairwise there, the C one in order
    return np.log(rng.dirichlet(np.ones(M))), rng.normal(-4.0, 3.0, (R, M, K))


def test_the_weights_are_the_normalised_products_of_the_likelihoods(case, monkeypatch):
    logw0, ll = case
    for logw, step in (gsf_kernel.bank_weights(logw0, ll), _numpy(logw0, ll, monkeypatch)):
        A = logw0[None, :, None] + np.cumsum(ll, axis=2)  # log w0 + Σ_{j≤k} ℓ_j, (R, M, K)
        lse = logsumexp(A, axis=1)  # (R, K): Σ_{j≤k} of the steps' log-likelihoods
        # Closed form by another route (sums over up to 40 steps of |ℓ| ≲ 15): 1e-10.
        np.testing.assert_allclose(np.moveaxis(logw, 1, 2), A - lse[:, None], rtol=0, atol=1e-10)
        np.testing.assert_allclose(np.cumsum(step, axis=1), lse, rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(np.exp(logw).sum(axis=2), 1.0, rtol=0, atol=1e-13)


def test_the_c_loop_equals_the_numpy_loop_to_rounding(case, monkeypatch):
    logw0, ll = case
    logw, step = gsf_kernel.bank_weights(logw0, ll)
    ref_w, ref_s = _numpy(logw0, ll, monkeypatch)
    # The same operations; exp, log and the sum's order differ by an ulp or so per step.
    np.testing.assert_allclose(logw, ref_w, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(step, ref_s, rtol=1e-13, atol=0)
    if has_compiler():
        assert gsf_kernel._weights.get() is not None  # the C loop ran


def test_one_component_keeps_its_likelihood_exactly(monkeypatch):
    ll = np.random.default_rng(1).normal(-3.0, 2.0, (2, 1, 25))
    for logw, step in (gsf_kernel.bank_weights(np.zeros(1), ll), _numpy(np.zeros(1), ll, monkeypatch)):
        assert np.array_equal(step, ll[:, 0]) and not logw.any()


def test_a_nan_propagates_from_its_step_on_in_its_run_only(case, monkeypatch):
    logw0, ll = case
    bad = ll.copy()
    bad[1, 4, 7] = np.nan
    for logw, step in (gsf_kernel.bank_weights(logw0, bad), _numpy(logw0, bad, monkeypatch)):
        assert np.isnan(step[1, 7:]).all() and np.isfinite(step[1, :7]).all()
        assert np.isfinite(step[[0, 2]]).all() and np.isfinite(logw[[0, 2]]).all()
