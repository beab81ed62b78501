"""A component of weight 0 in the Gaussian-sum filter with splitting (issue 47, item 7): with
``prune=0`` it used to be carried, and the merge of two of them divided by their total weight
0, a NaN that ended the run in "NaN or inf ... innovation covariance is singular".  It is
dropped now, in the compiled recursion and in the stepwise NumPy filter alike: a prior's
component of weight 0 before the first step, a weight that underflowed to 0 after an update."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.filters.mixture import gaussian_sum as gs

x1, x2 = sp.symbols("x1 x2", real=True)
CV = sm.Model([x1, x2], [x1 + 0.5 * x2, x2], name="gsfz_cv")
BEARING = sm.Model([x1, x2], [sp.atan2(x2 + 1, x1)], angles=[0], name="gsfz_bearing")
R1 = np.array([[1e-3]])


def _paths(gsf, ys, x0, monkeypatch) -> dict:
    """gsf.filter by the compiled recursion (when a compiler is there) and by the stepwise filter."""
    out = {}
    steps = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states)
    kernel = steps.kernel()
    if kernel is not None and kernel.native.wait():
        out["compiled"] = gsf.filter(ys, x0, keep=("x", "mixture"))
    with monkeypatch.context() as mp:
        mp.setattr(gs.GaussianSumFilter, "_recursion", lambda *args, **kwargs: None)
        out["stepwise"] = gsf.filter(ys, x0, keep=("x", "mixture"))
    return out


@pytest.mark.parametrize("merge", ["runnalls", "salmond"])
@pytest.mark.parametrize("weights", [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
def test_a_prior_component_of_weight_zero_is_dropped(merge, weights, monkeypatch):
    means = [[2.0, 0.3], [1.0, 0.0], [1.5, 0.1]]
    gsf = sm.GaussianSumFilter(CV, BEARING, np.diag([0.05, 0.1]), R1, split=0.1, prune=0.0, max_components=3,
                               merge=merge)
    ys = np.array([[0.1], [0.2], [0.15], [0.1]])
    prior = sm.GaussianMixture(weights, means, [np.eye(2)] * 3)
    alone = sm.Gaussian(means[int(np.argmax(weights))], np.eye(2))  # the one component of weight 1
    for path, res in _paths(gsf, ys, prior, monkeypatch).items():
        ref = _paths(gsf, ys, alone, monkeypatch)[path]
        np.testing.assert_array_equal(res.loglik, ref.loglik, err_msg=path)
        np.testing.assert_array_equal(res.x, ref.x, err_msg=path)
        assert np.all(np.isfinite(res.loglik))


@pytest.mark.parametrize("merge", ["runnalls", "salmond"])
def test_a_weight_that_underflows_to_zero_is_dropped_at_prune_zero(merge, monkeypatch):
    # Two tight components far from the bearings: their likelihoods underflow, their weights
    # are exactly 0 after the first update; carried, they merged with each other (0 / 0).
    gsf = sm.GaussianSumFilter(CV, BEARING, np.diag([1e-4, 1e-4]), R1, split=0.1, prune=0.0, max_components=3,
                               merge=merge)
    ys = np.array([[0.55], [0.5], [0.45], [0.4]])
    prior = sm.GaussianMixture([0.5, 0.25, 0.25], [[2.0, 0.3], [-2.0, -3.0], [-2.1, -3.0]],
                               [np.eye(2), 1e-3 * np.eye(2), 1e-3 * np.eye(2)])
    res = _paths(gsf, ys, prior, monkeypatch)
    for path, r in res.items():
        assert np.all(np.isfinite(r.loglik)), path
        k = np.arange(r.weights.shape[1])
        live = k[None, :] < r.components[:, None]
        assert np.all(r.weights[live] > 0), path  # no component of weight 0 carried
    if "compiled" in res:
        a, b = res["compiled"], res["stepwise"]
        np.testing.assert_array_equal(a.components, b.components)
        np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-10)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-10, atol=1e-12)
