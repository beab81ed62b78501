"""Exact reference of the square-root filter's ill-conditioned case: a constant-acceleration
tracker with a diffuse prior (P0 = 1e12 I), noise-free position and velocity, a tiny process
noise on the acceleration (1e-20) and precise position measurements (R = 1e-6), 10⁴ steps.

The Kalman filter is run in mpmath at 60 digits (the standard recursion, whose cancellation
is harmless at that precision) and x, P are stored at the steps of ``STEPS``.  Run from the
repository root: ``python tests/reference/make_sqrt_reference.py`` (about a minute).
"""

from __future__ import annotations

import json
from pathlib import Path

import mpmath as mp
import numpy as np

K = 10_000
P0, Q_ACC, R_POS = 1e12, 1e-20, 1e-6
F = [[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]]
X0 = [0.0, 1.0, 0.0]
STEPS = list(range(10)) + list(range(99, K, 100))


def measurements() -> np.ndarray:
    """y_k = p(t) + √R sin(1.7 t), t = 1 … K, p(t) = t + 5e-4 t²: deterministic, so that the
    test rebuilds them without a random generator."""
    t = np.arange(1, K + 1, dtype=float)
    return (t + 5e-4 * t**2 + np.sqrt(R_POS) * np.sin(1.7 * t))[:, None]


def reference(ys: np.ndarray, dps: int = 60) -> dict:
    mp.mp.dps = dps
    Fm = mp.matrix(F)
    H = mp.matrix([[1, 0, 0]])
    Q = mp.diag([0, 0, mp.mpf(Q_ACC)])
    R = mp.mpf(R_POS)
    x = mp.matrix(X0)
    P = mp.eye(3) * mp.mpf(P0)
    out = {"x": [], "P": []}
    for k, y in enumerate(ys[:, 0]):
        x = Fm * x
        P = Fm * P * Fm.T + Q
        S = (H * P * H.T)[0, 0] + R
        G = P * H.T / S
        x = x + G * (mp.mpf(float(y)) - (H * x)[0, 0])
        P = P - G * S * G.T
        P = (P + P.T) / 2
        if k in STEPS:
            out["x"].append([float(a) for a in x])
            out["P"].append([[float(P[i, j]) for j in range(3)] for i in range(3)])
    return out


if __name__ == "__main__":
    data = {"K": K, "P0": P0, "Q_acc": Q_ACC, "R": R_POS, "steps": STEPS, **reference(measurements())}
    path = Path(__file__).with_name("sqrt_filter.json")
    path.write_text(json.dumps(data))
    print(f"wrote {path}")
