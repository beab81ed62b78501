"""Error messages show numbers plainly (issue 47, item 9).

Under NumPy ≥ 2 the ``repr`` of a NumPy number is ``np.float64(0.9)``, and messages that
interpolated a value with ``!r`` printed that ("row 0 of transition sums to np.float64(0.9)").
Each case below is ordinary bad input, often with NumPy numbers (as they come out of an
array), to a Gaussian or mixture, a covariance check, a transform, a filter's inputs or a
measure: its message holds the plain numbers and no ``np.`` nor ``array(``.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import PLAIN_MAX_ENTRIES, SymmonError, plain_repr

x, y = sp.symbols("x y")
px, vx = sp.symbols("px vx")
PRODUCT = sm.Model([x, y], [x * y], name="product")
F = sm.Model([px, vx], [px + vx, vx], name="cv")
H = sm.Model([px, vx], [sp.sqrt(1 + px**2)], name="range")
Q, R = 0.01 * np.eye(2), np.array([[0.1]])
U = sm.Gaussian([1.0, 2.0], np.eye(2))
f64, i64 = np.float64, np.int64


def ukf() -> sm.NonlinearKalmanFilter:
    return sm.NonlinearKalmanFilter(F, H, Q, R, sm.UT.ut1())


#: (id, the call, plain texts its message holds).
CASES = [
    ("gaussian-asymmetric", lambda: sm.Gaussian([0, 0], np.array([[1, 0.5], [0.4, 1]])), ["0.1"]),
    ("gaussian-indefinite", lambda: sm.Gaussian([0, 0], np.diag([1.0, -0.9])), ["-0.9"]),
    ("gaussian-nan-mean", lambda: sm.Gaussian(np.array([0.0, np.nan]), np.eye(2)), ["nan"]),
    ("gaussian-sample-n", lambda: U.sample(f64(2.5)), ["got 2.5"]),
    ("gaussian-sample-rng", lambda: U.sample(3, rng=i64(-1)), ["got -1"]),
    ("mixture-sum", lambda: sm.GaussianMixture(np.array([0.5, 0.4]), [[0, 0], [1, 1]], [np.eye(2)] * 2),
     ["sum to 0.9"]),
    ("mixture-negative", lambda: sm.GaussianMixture(np.array([1.5, -0.5]), [[0, 0], [1, 1]], [np.eye(2)] * 2),
     ["-0.5"]),
    ("mixture-sample-n", lambda: sm.GaussianMixture([1.0], [[0, 0]], [np.eye(2)]).sample(f64(2.5)), ["got 2.5"]),
    ("model-angles", lambda: sm.Model([x, y], [x], angles=[f64(0.5)]), ["got 0.5"]),
    ("ut-alpha", lambda: sm.UT(alpha=f64(-1.0)), ["-1"]),
    ("ut-kappa", lambda: sm.propagate(PRODUCT, U, transform=sm.UT(alpha=f64(1.0), beta=f64(2.0), kappa=f64(-2.0))),
     ["alpha=1.0, kappa=-2.0"]),
    ("gauss-hermite-order", lambda: sm.GaussHermite(order=i64(0)), ["got 0"]),
    ("gauss-hermite-float", lambda: sm.GaussHermite(order=f64(2.5)), ["got 2.5"]),
    ("monte-carlo-seed", lambda: sm.MonteCarlo(n=1000, seed=i64(-1)), ["got -1"]),
    ("monte-carlo-chunk", lambda: sm.MonteCarlo(n=1000, chunk=f64(0.5)), ["got 0.5"]),
    ("executor-workers", lambda: sm.Executor(workers=i64(0)), ["got 0"]),
    ("advise-tol", lambda: sm.advise(PRODUCT, U, tol=f64(1.5)), ["got 1.5"]),
    ("kf-noise", lambda: sm.NonlinearKalmanFilter(F, H, Q, -R, sm.UT.ut1()), ["-0.1"]),
    ("kf-iterations", lambda: sm.NonlinearKalmanFilter(F, H, Q, R, sm.TT1(), iterations=i64(0)), ["got 0"]),
    ("kf-P0", lambda: ukf().filter(np.zeros((3, 1)), np.zeros(2), -np.eye(2)), ["-1"]),
    ("kf-confidence", lambda: ukf().filter(np.zeros((3, 1)), U).anees(np.zeros((3, 2)), confidence=f64(1.5)),
     ["got 1.5"]),
    ("adaptive-tol", lambda: sm.Adaptive(tol=f64(1.5)), ["got 1.5"]),
    ("pf-seed", lambda: sm.ParticleFilter(F, H, Q, R, seed=i64(-1)), ["got -1"]),
    ("gsf-max-components", lambda: sm.GaussianSumFilter(F, H, Q, R, max_components=i64(0)), ["got 0"]),
    ("filter-first-run", lambda: ukf().filter(np.zeros((3, 1)), U, first_run=i64(-2)), ["got -2"]),
    ("kf-simulate-runs", lambda: sm.KalmanFilter(1.0, 1.0, 1.0, 1.0).simulate(3, [0.0], np.random.default_rng(0),
                                                                               runs=i64(0)), ["got 0"]),
    ("pf-ess", lambda: sm.ParticleFilter(F, H, Q, R, particles=100, ess_threshold=f64(1.5)), ["got 1.5"]),
    ("pf-particles", lambda: sm.ParticleFilter(F, H, Q, R, particles=f64(10.5)), ["got 10.5"]),
    ("gsf-split", lambda: sm.GaussianSumFilter(F, H, Q, R, split=f64(1.5)), ["got 1.5"]),
    ("gsf-prune", lambda: sm.GaussianSumFilter(F, H, Q, R, prune=f64(1.5)), ["got 1.5"]),
    ("imm-transition", lambda: sm.IMM((ukf(), ukf()), np.array([[0.5, 0.4], [0.5, 0.5]]), np.array([0.5, 0.5])),
     ["sums to 0.9"]),
    ("imm-probabilities", lambda: sm.IMM((ukf(), ukf()), np.eye(2), np.array([0.5, 0.4])), ["sums to 0.9"]),
    ("simulate-steps", lambda: sm.simulate(F, H, Q, R, U, steps=f64(10.5)), ["got 10.5"]),
    ("simulate-runs", lambda: sm.simulate(F, H, Q, R, U, steps=3, runs=i64(0)), ["got 0"]),
]


@pytest.mark.parametrize("call, plain", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_messages_show_plain_numbers(call, plain):
    with pytest.raises(SymmonError) as info:
        call()
    message = str(info.value)
    assert "np." not in message and "array(" not in message, message
    for text in plain:
        assert text in message, message


def test_plain_repr():
    assert plain_repr(f64(0.9)) == "0.9" and plain_repr(i64(-1)) == "-1" and plain_repr(np.bool_(True)) == "True"
    assert plain_repr(np.array([[0.5, 0.4]])) == "[[0.5, 0.4]]" and plain_repr(np.array(2.5)) == "2.5"
    assert plain_repr((f64(1.0), 2)) == "(1.0, 2)" and plain_repr([i64(3)]) == "[3]" and plain_repr((i64(1),)) == "(1,)"
    assert plain_repr("ut1") == "'ut1'" and plain_repr(None) == "None" and plain_repr(x) == "x"
    assert plain_repr(np.zeros((PLAIN_MAX_ENTRIES + 1, 1))) == f"an array of shape ({PLAIN_MAX_ENTRIES + 1}, 1)"
