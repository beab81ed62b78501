"""The Gaussian-sum filter's cost per component against the Gaussian filter's step.

    python benchmarks/gsf.py [--quick]

A constant-velocity target in 2-D seen by a bearing sensor at the origin (n = 4 states,
one angle measurement), K = 200 steps (50 with ``--quick``), the UKF (``UT.ut1()``) as the
component filter.

- **base step**: ``NonlinearKalmanFilter.filter`` of one run, warm, per step;
- **GSF, no splitting** (``split=None``, the components as one bank of the compiled loop):
  M = 4, 16, 64 prior components, warm, per step and component;
- **GSF, splitting on** (``split=1e-9``: every component's MoN is computed, every component
  is split into 3 before its update, and the 3M components are merged back to
  ``max_components`` = M after it): the compiled recursion (``symmon/filters/gsf_kernel.py``,
  all K steps in one C call), and for comparison the stepwise Python/NumPy filter it
  replaces (``stepwise``, the path taken without a compiler).

Targets (issue 35): a GSF step ≤ 1.5 × (components × base step), without splitting
(components = M) and with it (components = 3M after the split).  Times are the best of
``REPEATS`` warm calls by the wall clock and by the CPU time (the machine may be shared: the
load average is printed), and the first call of each configuration (compiling its steps and
its recursion, unless in symmon's compile cache; a C build larger than the policy's
background threshold runs behind the stepwise filter, and is waited for before the warm calls).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import sympy as sp

import symmon as sm
from report import best_wall_cpu
from symmon.filters.mixture import gaussian_sum as gs

REPEATS = 5  # --repeats


def _models():
    px, py, vx, vy = X = sp.symbols("px py vx vy", real=True)
    f = sm.Model(list(X), [px + vx, py + vy, vx, vy], name="bench_gsf_f")
    h = sm.Model(list(X), [sp.atan2(py, px)], name="bench_gsf_h", angles=[0])
    return f, h, np.diag([0.01, 0.01, 1e-3, 1e-3]), np.array([[1e-4]])


def _timed(fn) -> tuple[float, float]:
    """(best wall, best CPU) of REPEATS calls.  On a loaded machine a long call is preempted
    where a short one is not, so the wall-clock ratio of a long GSF call to a short base call
    overstates the cost; the CPU time does not see the other processes (the calls here run
    on one thread)."""
    return best_wall_cpu(fn, REPEATS)


def _stepwise(gsf, ys, prior):
    """The stepwise filter's call (what ``filter`` runs without the compiled recursion)."""
    w0, m0, P0 = gsf._prior(prior)
    Y = np.asarray(ys, dtype=float)[None]
    return lambda: gsf._stepwise(Y, w0, m0, P0, None, {"x", "P"})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=REPEATS, help="warm calls per configuration (best of)")
    args = ap.parse_args()
    globals()["REPEATS"] = args.repeats
    K = 50 if args.quick else 200
    f, h, Q, R = _models()
    x0 = sm.Gaussian([20.0, 30.0, -1.0, 0.0], np.diag([4.0, 4.0, 0.1, 0.1]))
    _, ys = sm.simulate(f, h, Q, R, x0, K, seed=0)
    print(f"load average before: {' '.join(f'{a:.2f}' for a in os.getloadavg())}")
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    kf.filter(ys, x0)
    base, base_cpu = _timed(lambda: kf.filter(ys, x0))
    base, base_cpu = base / K, base_cpu / K
    print(f"base UKF step: {base * 1e6:.2f} µs wall, {base_cpu * 1e6:.2f} µs CPU  (K = {K})")
    print(f"{'M':>4} {'mode':<9} {'first call s':>12} {'µs/step':>9} {'comps':>6} {'/ (M × base)':>13} "
          f"{'/ (comps × base)':>17} {'CPU µs/step':>12} {'CPU / (comps × base)':>21}")
    rng = np.random.default_rng(0)
    for M in (4, 16, 64):
        prior = sm.GaussianMixture(np.full(M, 1.0 / M), x0.mean + rng.normal(0, 1, (M, 4)) * [2, 2, 0.3, 0.3],
                                   np.stack([x0.cov / 4] * M))
        for mode, split in (("bank", None), ("split", 1e-9), ("stepwise", 1e-9)):
            gsf = sm.GaussianSumFilter(f, h, Q, R, sm.UT.ut1(), split=split, max_components=M)
            call = (lambda: gsf.filter(ys, prior, keep=("x", "P"))) if mode != "stepwise" else _stepwise(gsf, ys, prior)
            t0 = time.perf_counter()
            call()
            first = time.perf_counter() - t0
            if mode == "split":  # a background build of the recursion: wait for it
                gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states).kernel().native.wait()
                call()
            t, c = _timed(call)
            res = gsf.filter(ys[:2], prior, keep=("x",))
            comps = M + int(res.splits[-1]) * (gsf.split_components - 1)  # components after the split
            t, c = t / K, c / K
            print(f"{M:>4} {mode:<9} {first:>12.3f} {t * 1e6:>9.1f} {comps:>6} {t / (M * base):>13.2f} "
                  f"{t / (comps * base):>17.2f} {c * 1e6:>12.1f} {c / (comps * base_cpu):>21.2f}")
    print(f"load average after: {' '.join(f'{a:.2f}' for a in os.getloadavg())}")


if __name__ == "__main__":
    main()
