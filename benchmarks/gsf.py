"""The Gaussian-sum filter's cost per component against the Gaussian filter's step.

    python benchmarks/gsf.py [--quick]

A constant-velocity target in 2-D seen by a bearing sensor at the origin (n = 4 states,
one angle measurement), K = 200 steps, the UKF (``UT.ut1()``) as the component filter.

- **base step**: ``NonlinearKalmanFilter.filter`` of one run, warm, per step;
- **GSF, no splitting** (``split=None``, the components as one bank of the compiled loop):
  M = 4, 16, 64 prior components, warm, per step and component;
- **GSF, splitting on** (``split=1e-9``, every component's MoN is computed at both stages, the
  components split and merged back to ``max_components`` = M each step; the Python-driven
  stepwise filter): per step and component.

The target of issue 35 is a GSF step ≤ 1.5 × (components × base step).  Times are the best of
``REPEATS`` warm calls.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import sympy as sp

import symmon as sm

REPEATS = 5


def _models():
    px, py, vx, vy = X = sp.symbols("px py vx vy", real=True)
    f = sm.Model(list(X), [px + vx, py + vy, vx, vy], name="bench_gsf_f")
    h = sm.Model(list(X), [sp.atan2(py, px)], name="bench_gsf_h", angles=[0])
    return f, h, np.diag([0.01, 0.01, 1e-3, 1e-3]), np.array([[1e-4]])


def best(fn) -> float:
    fn()  # warm: compiled, cached
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    K = 50 if args.quick else 200
    f, h, Q, R = _models()
    x0 = sm.Gaussian([20.0, 30.0, -1.0, 0.0], np.diag([4.0, 4.0, 0.1, 0.1]))
    _, ys = sm.simulate(f, h, Q, R, x0, K, seed=0)
    base = best(lambda: sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1()).filter(ys, x0)) / K
    print(f"base UKF step: {base * 1e6:.2f} µs  (K = {K})")
    print(f"{'M':>4} {'mode':<10} {'µs/step':>10} {'µs/step/comp':>13} {'ratio to M × base':>18}")
    rng = np.random.default_rng(0)
    for M in (4, 16, 64):
        prior = sm.GaussianMixture(np.full(M, 1.0 / M), x0.mean + rng.normal(0, 1, (M, 4)) * [2, 2, 0.3, 0.3],
                                   np.stack([x0.cov / 4] * M))
        for mode, split in (("bank", None), ("split", 1e-9)):
            gsf = sm.GaussianSumFilter(f, h, Q, R, sm.UT.ut1(), split=split, max_components=M)
            t = best(lambda: gsf.filter(ys, prior, keep=("x", "P"))) / K
            print(f"{M:>4} {mode:<10} {t * 1e6:>10.1f} {t / M * 1e6:>13.2f} {t / (M * base):>18.2f}")


if __name__ == "__main__":
    main()
