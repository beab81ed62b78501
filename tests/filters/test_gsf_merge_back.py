"""The Gaussian-sum filter follows the MoN down as well as up (issue 48, item 2): it splits
where a component's MoN exceeds ``split`` and, with ``merge_back``, merges calm components
(MoN below split/2) back while their Runnalls cost is below the threshold, in the compiled
recursion (gsf.c) and in the stepwise filter alike: the same numbers to 1e-12 on a scalar
model (no eigen-decompositions to differ), the same components per step, and every split and
merge-back keeps the mixture's mean and covariance to 1e-12 inside the filter."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.mixture import mixture_moments
from symmon.errors import ArgumentError
from symmon.filters.mixture import gaussian_sum as gs
from symmon.filters.mixture.gaussian_sum import split_components, split_directions
from symmon.filters.mixture.merge import merge_below, pair_costs

x, c = sp.symbols("x c", real=True)
# A random walk measured through x + c x²: curved while c ≠ 0, linear once c = 0.
F = sm.Model([x], [x], name="mb_rw")
H = sm.Model([x], [x + c * x**2], params=[c], name="mb_quad")
K, BEND = 30, 8
CURVE = np.where(np.arange(K) < BEND, 0.4, 0.0)
PRIOR = sm.Gaussian([0.0], [[4.0]])
#: The two paths' agreement on the scalar model, and the moments kept by a split or a merge.
EXACT = 1e-12


def _paths(gsf, ys, **kw):
    """(compiled, stepwise) results of ``gsf.filter``; skips without a compiler."""
    kernel = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states).kernel()
    if kernel is None or not kernel.native.wait():
        pytest.skip("no C compiler: the stepwise filter is the only path")
    a = gsf.filter(ys, PRIOR, **kw)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(gs.GaussianSumFilter, "_recursion", lambda *args, **kwargs: None)
        b = gsf.filter(ys, PRIOR, **kw)
    return a, b


def _close(a, b, what):
    np.testing.assert_allclose(a, b, rtol=0, atol=EXACT * max(1.0, float(np.abs(b).max())), err_msg=what)


def _gsf(merge_back=None):
    return sm.GaussianSumFilter(F, H, [[0.01]], [[0.25]], sm.TT1(), split=0.05, max_components=16,
                                merge_back=merge_back)


@pytest.fixture(scope="module")
def track():
    return sm.simulate(F, H, [[0.01]], [[0.25]], PRIOR, K, runs=6, params={"c": CURVE}, seed=2)


def test_the_mixture_falls_back_to_one_component_on_the_linear_stretch(track):
    xs, ys = track
    back = _gsf(1e-3).filter(ys, PRIOR, params={"c": CURVE}, keep=("x", "P", "mixture"))
    kept = _gsf().filter(ys, PRIOR, params={"c": CURVE}, keep=("x", "P", "mixture"))
    # it split on the curved stretch, as without merging back ...
    assert (back.splits[:, :BEND].sum(axis=1) > 0).all()
    assert (back.components[:, :BEND].max(axis=1) > 1).sum() >= 4
    # ... and is one Gaussian again well into the linear stretch, where the other keeps its components
    assert (back.components[:, -5:] == 1).all()
    assert (kept.components[:, -1] > 1).sum() >= 3
    assert "merge_back=0.001" in back.method and "merge_back" not in kept.method
    # one Gaussian of the same moments: the estimates agree with the unmerged filter's
    np.testing.assert_allclose(back.x[:, -1], kept.x[:, -1], rtol=0, atol=1e-3)


def test_the_compiled_recursion_merges_back_as_the_stepwise_filter(track):
    xs, ys = track
    a, b = _paths(_gsf(1e-3), ys, params={"c": CURVE}, keep=("x", "P", "mixture"))
    assert np.array_equal(a.components, b.components) and np.array_equal(a.splits, b.splits)
    for name in ("x", "P", "loglik", "weights", "means", "covs"):
        u, v = getattr(a, name), getattr(b, name)
        assert u.shape == v.shape, name
        _close(u, v, name)
    # components per step in both: it grew on the curved stretch and came back to one
    assert a.components[:, :BEND].max() > 3 and (a.components[:, -5:] == 1).all()


@pytest.mark.parametrize("stepwise", [False, True], ids=["compiled", "stepwise"])
def test_each_merge_back_keeps_the_mixtures_mean_and_covariance_in_the_filter(track, stepwise):
    """Up to the first step where a run merges back, the filter equals the one that does not;
    at that step the merged mixture's moments (the step's x and P) are the unmerged ones."""
    xs, ys = track
    pair = [_paths(g, ys, params={"c": CURVE}) for g in (_gsf(1e-3), _gsf())]
    back, kept = (p[int(stepwise)] for p in pair)
    merged = 0
    for r in range(len(ys)):
        differ = np.flatnonzero(back.components[r] != kept.components[r])
        if not len(differ):
            continue
        k = differ[0]
        assert back.components[r, k] < kept.components[r, k]
        _close(back.x[r, :k + 1], kept.x[r, :k + 1], "x")
        _close(back.P[r, :k + 1], kept.P[r, :k + 1], "P")
        merged += 1
    assert merged >= 4


@pytest.mark.parametrize("stepwise", [False, True], ids=["compiled", "stepwise"])
def test_each_split_keeps_the_mixtures_mean_and_covariance_in_the_filter(track, stepwise):
    """With the first measurement missing, the first step is a linear prediction and the split
    of every component by the MoN of h: the mixture's moments are the unsplit filter's."""
    xs, ys = track
    ys = ys.copy()
    ys[:, 0] = np.nan
    split = _paths(_gsf(), ys, params={"c": CURVE})[int(stepwise)]
    plain = sm.GaussianSumFilter(F, H, [[0.01]], [[0.25]], sm.TT1()).filter(ys, PRIOR, params={"c": CURVE})
    assert (split.splits[:, 0] == 1).all() and (split.components[:, 0] == 3).all()
    _close(split.x[:, 0], plain.x[:, 0], "x")
    _close(split.P[:, 0], plain.P[:, 0], "P")


def test_a_split_keeps_the_mixtures_mean_and_covariance_to_1e_12() -> None:
    rng = np.random.default_rng(4)
    n, N = 3, 20
    A = rng.standard_normal((N, n, n))
    covs = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(n)
    means = rng.standard_normal((N, n))
    H2 = rng.standard_normal((N, 2, n, n))
    H2 = H2 + np.swapaxes(H2, 2, 3)
    d = split_directions(covs, H2, np.broadcast_to(np.eye(2), (N, 2, 2)).copy())
    for m in (3, 5):
        w, mu, P = split_components(means, covs, d, m)
        for i in range(N):
            mean, cov = mixture_moments(w, mu[i], P[i])
            np.testing.assert_allclose(mean, means[i], rtol=0, atol=1e-12 * (1 + np.abs(means[i]).max()))
            np.testing.assert_allclose(cov, covs[i], rtol=0, atol=1e-12 * np.abs(covs[i]).max())


def test_merging_back_keeps_the_mixtures_mean_and_covariance_and_only_merges_calm_pairs() -> None:
    rng = np.random.default_rng(5)
    M, n = 6, 2
    w = rng.uniform(0.5, 1.0, M)
    w /= w.sum()
    m = 0.01 * rng.standard_normal((M, n))
    m[0] += 5.0  # far from the others: costly to merge
    A = rng.standard_normal((M, n, n))
    P = A @ np.swapaxes(A, 1, 2) + np.eye(n)
    calm = np.array([True, True, True, True, True, False])
    w2, m2, P2, calm2 = merge_below(w, m, P, 0.05, calm)
    before, after = mixture_moments(w, m, P), mixture_moments(w2, m2, P2)
    np.testing.assert_allclose(after[0], before[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(after[1], before[1], rtol=0, atol=1e-12)
    assert len(w2) < M and not calm2[-1] and np.array_equal(m2[-1], m[-1])  # the restless one untouched
    assert np.array_equal(m2[0], m[0])  # the far one too: its cost is above the threshold
    # what is left of the calm ones costs at least the threshold to merge
    idx = np.flatnonzero(calm2)
    a, b = np.triu_indices(len(idx), 1)
    ld = np.linalg.slogdet(P2)[1]
    assert (pair_costs(w2, m2, P2, ld, idx[a], idx[b], "runnalls", None) >= 0.05).all()


@pytest.mark.parametrize("kwargs, match", [({"merge_back": -1.0}, "merge_back"), ({"merge_back": True}, "merge_back"),
                                           ({"merge_back": 1e-3, "split": None}, "needs split")])
def test_bad_merge_back_is_named(kwargs, match) -> None:
    with pytest.raises(ArgumentError, match=match):
        sm.GaussianSumFilter(F, H, [[0.01]], [[0.25]], sm.TT1(), **{"split": 0.05, **kwargs})


def test_the_registry_builds_a_merge_back_filter() -> None:
    from symmon.filters.registry import make_filter

    flt = make_filter("gsf", F, H, [[0.01]], [[0.25]], settings={"transform": "ekf", "split": 0.05, "merge_back": 1e-3})
    assert flt.merge_back == 1e-3
