"""The Gaussian-sum filter's compiled recursion with splitting (symmon.filters.mixture._kernel)
against the stepwise NumPy filter it replaces: the same mixtures, log-likelihoods, component
counts and splits, for every option (prediction and update splits, Runnalls and Salmond,
pruning, 3 or 5 children, merging back, angles, missing measurements, parameters, banks of runs, what is
kept) and the same error for a component that turns non-finite."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.filters.mixture import gaussian_sum as gs

px, py, th = sp.symbols("px py th", real=True)
x1, x2 = sp.symbols("x1 x2", real=True)
W_, B_ = sp.symbols("w b", real=True)
# A heading that turns by the parameter w (an angle state), seen in bearing (an angle output,
# biased by the parameter b) and range: both stages curved, several outputs.
TURN = sm.Model([px, py, th], [px + 0.5 * sp.cos(th), py + 0.5 * sp.sin(th), th + W_], angles=[2], params=[W_],
                name="gsfk_turn")
RB = sm.Model([px, py, th], [sp.atan2(py, px) + B_, sp.sqrt(px**2 + py**2)], angles=[0], params=[B_],
              name="gsfk_rb")
Q3 = np.diag([0.02, 0.02, 0.05])
R2 = np.diag([1e-3, 0.05])
# A linear prediction and one bearing: only the update splits (the benchmark's case).
CV = sm.Model([x1, x2], [x1 + 0.5 * x2, x2], name="gsfk_cv")
BEARING = sm.Model([x1, x2], [sp.atan2(x2 + 1, x1)], angles=[0], name="gsfk_bearing")
Q2 = np.diag([0.05, 0.1])
R1 = np.array([[1e-3]])

#: Relative agreement of the two paths: the same operations apart from the eigen-decompositions
#: (Jacobi against LAPACK) and the order of a few sums, through a few merges per step.
RTOL = 1e-10


def _compiled(gsf):
    """The compiled recursion of ``gsf``, waited for (skip the module's tests without a compiler)."""
    steps = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states)
    kernel = steps.kernel()
    if kernel is None or not kernel.native.wait():
        pytest.skip("no C compiler: the stepwise filter is the only path")
    return kernel


def _both(gsf, ys, x0, monkeypatch, **kw):
    """(compiled, stepwise) results of gsf.filter."""
    _compiled(gsf)
    a = gsf.filter(ys, x0, **kw)
    with monkeypatch.context() as mp:
        mp.setattr(gs.GaussianSumFilter, "_recursion", lambda *args, **kwargs: None)
        b = gsf.filter(ys, x0, **kw)
    return a, b


def _close(a, b, what) -> None:
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * max(1.0, float(np.abs(b).max())), err_msg=what)


def _same(a, b) -> None:
    assert np.array_equal(a.components, b.components), (a.components, b.components)
    assert np.array_equal(a.splits, b.splits), (a.splits, b.splits)
    assert a.splits.sum() > 0
    _close(a.loglik, b.loglik, "loglik")
    for name in ("x", "P", "weights", "means", "covs"):
        u, v = getattr(a, name), getattr(b, name)
        assert (u is None) == (v is None), name
        if u is not None:
            assert u.shape == v.shape, name
            _close(u, v, name)


@pytest.fixture(scope="module")
def turn_data():
    rng = np.random.default_rng(3)
    R, K = 3, 6
    ys = np.empty((R, K, 2))
    ys[..., 0] = np.arctan2(2.0, 3.0) + rng.normal(0, 0.03, (R, K))
    ys[..., 1] = 3.6 + rng.normal(0, 0.2, (R, K))
    ys[0, 2, 0] = np.nan  # a bearing missing
    ys[1, 4] = np.nan  # a whole step missing
    x0 = sm.GaussianMixture([0.6, 0.4], [[3.0, 2.0, 0.3], [2.5, 2.5, -0.2]],
                            [np.diag([0.8, 0.5, 0.3]), np.diag([0.5, 0.9, 0.2])])
    params = {"w": 0.1, "b": np.linspace(0.0, 0.01, K)}
    return ys, x0, params


@pytest.mark.parametrize("merge, m, prune, mc", [("runnalls", 3, 1e-6, 5), ("salmond", 5, 1e-3, 4),
                                                 ("runnalls", 5, 0.0, 3)])
def test_both_stages_split_as_the_stepwise_filter(merge, m, prune, mc, turn_data, monkeypatch) -> None:
    ys, x0, params = turn_data
    gsf = sm.GaussianSumFilter(TURN, RB, Q3, R2, sm.UT.ut1(), split=0.05, max_components=mc, prune=prune,
                               merge=merge, split_components=m)
    a, b = _both(gsf, ys, x0, monkeypatch, params=params)
    _same(a, b)
    assert (a.components <= mc).all()
    # One run alone is that run of the bank (the runs run on separate threads).
    c = gsf.filter(ys[2], x0, params={"w": 0.1, "b": params["b"]})
    np.testing.assert_array_equal(c.x, a.x[2])


def test_merging_back_as_the_stepwise_filter(turn_data, monkeypatch) -> None:
    """merge_back in the compiled recursion (gsf.c): the same calm components merged back, with
    both stages splitting, an angle state, a parameter per step and missing measurements."""
    ys, _, params = turn_data
    wide = sm.GaussianMixture([0.6, 0.4], [[3.0, 2.0, 0.3], [2.5, 2.5, -0.2]],
                              [np.diag([2.4, 1.5, 0.9]), np.diag([0.5, 0.9, 0.2])])
    kw = dict(split=0.24, max_components=8)
    gsf = sm.GaussianSumFilter(TURN, RB, Q3, R2, sm.UT.ut1(), merge_back=1.0, **kw)
    a, b = _both(gsf, ys, wide, monkeypatch, params=params, keep=("x", "P", "mixture"))
    _same(a, b)
    plain = sm.GaussianSumFilter(TURN, RB, Q3, R2, sm.UT.ut1(), **kw).filter(ys, wide, params=params)
    assert (a.components < plain.components).any() and (a.components <= plain.components).all()


def test_only_the_update_splits_with_a_single_output(monkeypatch) -> None:
    rng = np.random.default_rng(8)
    ys = np.arctan2(1.0, 2.0 + 0.3 * np.arange(8))[:, None] + rng.normal(0, 0.03, (8, 1))
    ys[3] = np.nan
    gsf = sm.GaussianSumFilter(CV, BEARING, Q2, R1, sm.UT.ut1(), split=0.02, max_components=6)
    a, b = _both(gsf, ys, sm.Gaussian([2.0, 0.3], [[1.0, 0.2], [0.2, 0.5]]), monkeypatch)
    _same(a, b)
    a, b = _both(gsf, ys, sm.Gaussian([2.0, 0.3], np.eye(2)), monkeypatch, keep=("x",))
    _same(a, b)
    assert a.P is None and a.weights is None


ROOT = sm.Model([x1, x2], [sp.sqrt(x1)], name="gsfk_root")


@pytest.fixture(scope="module")
def root_gsf():
    """EKF components (TT1) and a measurement sqrt(x1), NaN for x1 < 0."""
    gsf = sm.GaussianSumFilter(CV, ROOT, Q2, R1, sm.TT1(), split=0.01, max_components=4, merge="salmond")
    _compiled(gsf)
    return gsf


def test_ekf_components(root_gsf, monkeypatch) -> None:
    ys = np.sqrt(2.0 + 0.5 * np.arange(6))[:, None] + 0.05
    a, b = _both(root_gsf, ys, sm.Gaussian([2.0, 0.5], [[1.0, 0.2], [0.2, 0.5]]), monkeypatch)
    _same(a, b)


def test_every_component_split_and_merged_back(monkeypatch) -> None:
    # The benchmark's setting: every component's MoN above split, 3M children merged to M.
    rng = np.random.default_rng(2)
    M = 6
    prior = sm.GaussianMixture(np.full(M, 1.0 / M), np.array([3.0, 1.0]) + rng.normal(0, 0.5, (M, 2)),
                               np.stack([np.eye(2) * 0.3] * M))
    ys = np.arctan2(2.0, 3.0)[None, None] + rng.normal(0, 0.03, (10, 1))
    gsf = sm.GaussianSumFilter(CV, BEARING, Q2, R1, sm.UT.ut1(), split=1e-9, max_components=M)
    a, b = _both(gsf, ys, prior, monkeypatch)
    _same(a, b)
    assert (a.splits == M).all() and (a.components == M).all()


def test_a_non_finite_component_is_the_same_error(root_gsf, monkeypatch) -> None:
    # Run 1's measurements (0) drive its components below x1 = 0 (sqrt: NaN); run 0's stay finite.
    ys = np.ones((2, 4, 1))
    ys[1] = 0.0
    x0 = sm.Gaussian([1.0, 0.0], [[0.01, 0.0], [0.0, 0.001]])
    with pytest.raises(sm.SymmonError, match=r"NaN or inf at run 1, step 1") as compiled:
        root_gsf.filter(ys, x0)
    with monkeypatch.context() as mp:
        mp.setattr(gs.GaussianSumFilter, "_recursion", lambda *args, **kwargs: None)
        with pytest.raises(sm.SymmonError) as stepwise:
            root_gsf.filter(ys, x0)
    assert str(compiled.value) == str(stepwise.value)


def test_directions_have_their_largest_entry_positive() -> None:
    rng = np.random.default_rng(4)
    P = np.stack([np.eye(3) + 0.1 * np.diag(rng.uniform(size=3)) for _ in range(20)])
    H = rng.normal(size=(20, 2, 3, 3))
    H = H + np.swapaxes(H, 2, 3)
    for W in (np.ones((20, 1, 1)), np.stack([np.eye(2)] * 20)):
        d = gs.split_directions(P, H[:, :W.shape[1]], W)
        assert (d[np.arange(20), np.abs(d).argmax(axis=1)] > 0).all()


def test_a_calls_numbers_do_not_depend_on_the_builds_timing(tmp_path):
    """A fresh cache under the background policy: the first call waits for the compiled
    recursion instead of running the stepwise filter, which agrees with it to rounding only,
    so the first and a later call give the same numbers bit for bit (the cluster's workers,
    cold, and the client, warm, agree: tests/filters/test_distributed.py)."""
    import os
    import subprocess
    import sys

    from symmon.compile import has_compiler

    if not has_compiler():
        pytest.skip("no C compiler: the stepwise filter is the only path")
    script = (
        "import numpy as np, sympy as sp, symmon as sm\n"
        "from symmon.filters.mixture import gaussian_sum as gs\n"
        "x1, x2 = sp.symbols('x1 x2', real=True)\n"
        "f = sm.Model([x1, x2], [x1 + 0.5 * x2, 0.9 * x2], name='gsf_timing_f')\n"
        "h = sm.Model([x1, x2], [sp.atan2(x2 + 1, x1)], angles=[0], name='gsf_timing_h')\n"
        "x0 = sm.Gaussian([2.0, 0.3], np.eye(2))\n"
        "_, ys = sm.simulate(f, h, 0.05 * np.eye(2), [[1e-3]], x0, 6, seed=2)\n"
        "g = sm.GaussianSumFilter(f, h, 0.05 * np.eye(2), [[1e-3]], sm.UT.ut1(), split=0.02, max_components=6)\n"
        "a = g.filter(ys, x0).x\n"
        "k = gs._component_steps(g.f, g.h, g.transform, g.kf.angle_states).kernel()\n"
        "k.native.wait()\n"
        "b = g.filter(ys, x0).x\n"
        "print(k.native.evaluator, bool(np.array_equal(a, b)))\n")
    env = {**os.environ, "SYMMON_CACHE": str(tmp_path / "cache"), "SYMMON_COMPILE": "background"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["compiled", "True"]
