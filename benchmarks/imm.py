"""Timings of ``sm.IMM``: the fused C loop, the loop over steps, and FilterPy's IMMEstimator.

    python benchmarks/imm.py

a. FilterPy's own test case (Crassidis example 4.6, tests/reference/filterpy_imm.json): two
   6-state constant-acceleration modes, 600 steps, one run. FilterPy's ``IMMEstimator``
   (``predict()`` then ``update(z)`` per step) against ``sm.IMM`` of the same
   ``sm.KalmanFilter``s, the estimates compared in the same run.
b. The modes of docs/imm.md's turning target: a constant-velocity EKF and a coordinated-turn
   CKF on [x, y, ẋ, ẏ, ω], range–bearing, on noisy measurements of a straight approach, 38
   steps, banks of 100 and 1000 runs.

Each symmon case runs twice: the fused loop (the whole recursion of the bank in one compiled
C call) and the loop over steps (each mode's compiled step called per time step on all the
runs, NumPy between the calls: the fallback for an adaptive mode or without a compiler).
Times are the best of five after a warm-up (``time.perf_counter``); the load average is
printed, since the machine may be shared.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from unittest import mock

import numpy as np
import sympy as sp

import symmon as sm

ROOT = Path(__file__).resolve().parents[1]


def best(f, repeats: int = 5) -> float:
    f()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def both(imm, ys, x0, P0=None):
    """(fused time, step-loop time, max relative difference of x)."""
    fused = best(lambda: imm.filter(ys, x0, P0))
    a = imm.filter(ys, x0, P0)
    with mock.patch("symmon.filters.mixture.imm._FusedLoop.native", lambda self: None):
        steps = best(lambda: imm.filter(ys, x0, P0))
        b = imm.filter(ys, x0, P0)
    return fused, steps, float(np.abs(a.x - b.x).max() / np.abs(a.x).max()), a


def filterpy_case():
    from filterpy.kalman import IMMEstimator, KalmanFilter

    d = json.loads((ROOT / "tests" / "reference" / "filterpy_imm.json").read_text())["crassidis"]
    ys = np.array(d["ys"])

    def run():
        fs = []
        for Q, R in zip(d["Q"], d["R"]):
            kf = KalmanFilter(6, 2)
            kf.x, kf.P, kf.F, kf.H = np.array(d["x0"])[:, None], np.array(d["P0"]), np.array(d["F"]), np.array(d["H"])
            kf.Q, kf.R = np.array(Q), np.array(R)
            fs.append(kf)
        bank = IMMEstimator(fs, d["mu0"], np.array(d["transition"]))
        xs = []
        for z in ys:
            bank.predict()
            bank.update(z[:, None])
            xs.append(bank.x_post[:, 0].copy())
        return np.array(xs)

    t_fp = best(run, 3)
    imm = sm.IMM([sm.KalmanFilter(d["F"], Q, d["H"], R) for Q, R in zip(d["Q"], d["R"])], d["transition"], d["mu0"])
    fused, steps, diff, res = both(imm, ys, np.array(d["x0"]), np.array(d["P0"]))
    agree = float(np.abs(res.x - run()).max() / np.abs(res.x).max())
    return t_fp, fused, steps, diff, agree


def turn_case(runs: int):
    T = 2.0
    x, y, vx, vy, w = X = sp.symbols("x y vx vy omega", real=True)
    cv_model = sm.Model(X, [x + T * vx, y + T * vy, vx, vy, 0 * w], name="cv_hold")
    radar = sm.Model(X, [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1], name="radar")
    Q = np.zeros((5, 5))
    Q[:4, :4] = 0.1 * np.kron([[T**3 / 3, T**2 / 2], [T**2 / 2, T]], np.eye(2))
    Qcv, Qct = Q.copy(), Q.copy()
    Qcv[4, 4], Qct[4, 4] = 1e-6, 1e-3
    R = np.diag([20.0**2, 0.002**2])
    cv = sm.NonlinearKalmanFilter(cv_model, radar, Qcv, R, sm.TT1())
    ct = sm.NonlinearKalmanFilter(sm.problems.coordinated_turn(T), radar, Qct, R, sm.UT.cubature())
    imm = sm.IMM([cv, ct], [[0.95, 0.05], [0.05, 0.95]], [0.9, 0.1])
    rng = np.random.default_rng(1)
    r = np.hypot(20000.0, 5000.0) - 150.0 * T * np.arange(38)
    ys = np.stack([r, np.full(38, np.arctan2(5000.0, 20000.0))], axis=-1) + rng.standard_normal((runs, 38, 2)) * [20.0,
                                                                                                                0.002]
    x0 = sm.Gaussian([20000.0, 5000.0, -150.0, 0.0, 0.0], np.diag([400.0, 400.0, 25.0, 25.0, 1e-4]))
    return both(imm, ys, x0)[:3]


if __name__ == "__main__":
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs\n")
    t_fp, fused, steps, diff, agree = filterpy_case()
    print("| case | FilterPy | symmon, fused C loop | symmon, loop over steps | fused vs steps | symmon vs FilterPy |")
    print("|---|---|---|---|---|---|")
    print(f"| a. Crassidis, 2 modes × 600 steps, 1 run | {t_fp * 1e3:.1f} ms | {fused * 1e3:.2f} ms | "
          f"{steps * 1e3:.1f} ms | {diff:.1e} | {agree:.1e} |")
    for runs in (100, 1000):
        fused, steps, diff = turn_case(runs)
        print(f"| b. turn, EKF + CKF × 38 steps, {runs} runs | | {fused * 1e3:.2f} ms | {steps * 1e3:.1f} ms | "
              f"{diff:.1e} | |")
