"""A filter that fails (a NaN or inf in x, P or the log-likelihood) is an error naming the
first step that failed and its run.  The compiled loop tests every step as it goes
(``check_finite``) and stops a run that failed; CasADi's VM path reports the same steps from
its arrays (:func:`~symmon.filters.gaussian.step.first_nonfinite`)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import SymmonError
from symmon.filters.gaussian.step import compiled_step, first_nonfinite

HUGE = 1.7e308  # its square overflows: the log-likelihood of that step is -inf


def scalar_filter(transform) -> sm.NonlinearKalmanFilter:
    x = sp.Symbol("x", real=True)
    f = sm.Model([x], [x], name="fail_walk")
    h = sm.Model([x], [sp.sinh(x / 10)], name="fail_sinh")
    return sm.NonlinearKalmanFilter(f, h, [[0.01]], [[0.1]], transform)


def bank(fail_at: dict[int, int], runs: int = 4, K: int = 12) -> np.ndarray:
    """Measurements of ``runs`` runs, with a huge one at run r, step k for each {r: k}."""
    Y = 0.1 * np.sin(np.arange(runs * K, dtype=float)).reshape(runs, K, 1)
    for r, k in fail_at.items():
        Y[r, k, 0] = HUGE
    return Y


@pytest.mark.parametrize("transform", [sm.TT1(), sm.UT(1, 2, 0)], ids=["ekf", "ukf"])
def test_compiled_loop_and_vm_report_the_same_first_failures(transform):
    kf = scalar_filter(transform)
    step = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)
    step._lib.wait()
    Y = bank({1: 3, 3: 7})
    args = (np.zeros(1), np.eye(1), Y, kf.Q, kf.R)
    c = step(*args, check_finite=True)["first_nonfinite"]
    vm = step(*args, check_finite=True, use_c=False)["first_nonfinite"]
    assert c.tolist() == [-1, 3, -1, 7]
    assert vm.tolist() == c.tolist()
    # Not asked for: no entry, and every step of every run is computed.
    out = step(*args)
    assert "first_nonfinite" not in out
    assert not np.isfinite(out["loglik"][1, 3]) and np.isfinite(out["loglik"][0]).all()


def test_filter_names_the_earliest_step_and_its_run():
    kf = scalar_filter(sm.TT1())
    # Run 0 fails at step 9, run 2 at step 2: step 2 is the first to fail.
    with pytest.raises(SymmonError, match=r"the filter produced NaN or inf at run 2, step 2 "):
        kf.filter(bank({0: 9, 2: 2}), [0.0], [[1.0]], keep=("nis",))
    # Two runs failing at the same step: the first run is named.
    with pytest.raises(SymmonError, match=r"at run 1, step 4 "):
        kf.filter(bank({3: 4, 1: 4}), [0.0], [[1.0]])
    with pytest.raises(SymmonError, match=r"the filter produced NaN or inf at step 5 "):
        kf.filter(bank({0: 5}, runs=1)[0], [0.0], [[1.0]])
    assert np.isfinite(kf.filter(bank({}), [0.0], [[1.0]]).loglik).all()


def test_first_nonfinite_of_arrays():
    loglik = np.zeros((3, 5))
    x, P = np.zeros((3, 5, 2)), np.zeros((3, 5, 2, 2))
    loglik[0, 4] = -np.inf
    x[1, 2, 1] = np.nan
    P[1, 1, 0, 1] = np.inf
    P[2, 3, 1, 1] = np.nan
    assert first_nonfinite(loglik, x, P).tolist() == [4, 1, 3]
    assert first_nonfinite(loglik, x, None).tolist() == [4, 2, -1]
    assert first_nonfinite(loglik, None, None).tolist() == [4, -1, -1]
