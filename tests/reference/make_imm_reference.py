"""Make tests/reference/filterpy_imm.json: FilterPy's ``IMMEstimator`` on its own linear cases.

    pip install ".[bench]"   # FilterPy
    python tests/reference/make_imm_reference.py

The measurements are stored beside the results, so that the test (tests/filters/test_imm.py)
reads the same data. Each case runs FilterPy's ``IMMEstimator`` as ``predict()`` then
``update(z)`` at each step (symmon's order: x0 is the state before the first prediction) and
stores, after each update, the combined ``x_post`` and ``P_post``, the mode probabilities
``mu``, each mode's ``x`` (``docstring``) and the step's log-likelihood log Σ_j c̄_j Λ_j (c̄ = ``cbar`` before
the update, Λ_j each filter's ``likelihood``; FilterPy does not sum it itself).

- ``crassidis``: ``test_imm`` of filterpy/kalman/tests/test_imm.py (Crassidis, *Optimal
  Estimation of Dynamic Systems*, example 4.6): a target that accelerates from step 400,
  positions measured with σ = 100; two constant-acceleration modes on
  [x, vx, ax, y, vy, ay], one with process noise and one without, transition 0.97/0.03,
  P0 = 1e-12 I. FilterPy's test draws the noise unseeded; here NumPy's global generator is
  seeded (``np.random.seed(36)``). P is stored every 50 steps and the modes' x not (the file
  stays small).
- ``docstring``: the example of ``IMMEstimator``'s docstring: two ``kinematic_kf(2, 2)``
  filters (positions measured, so ``dim_z=2``), the second without process noise, on a
  target moving along the diagonal with unit-variance noise, 30 steps; everything stored (the
  mode without process noise has a P whose condition number grows as k⁴, 10⁸ by step 40, and
  the rounding differences of the two implementations with it: 30 steps keep them below 1e-10).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from filterpy.common import kinematic_kf
from filterpy.kalman import IMMEstimator, KalmanFilter

OUT = Path(__file__).with_name("filterpy_imm.json")


def run(bank: IMMEstimator, zs: np.ndarray, P_every: int, modes: bool) -> dict:
    xs, Ps, mus, mode_x, logliks = [], {}, [], [], []
    for k, z in enumerate(zs):
        bank.predict()
        cbar = bank.cbar.copy()  # c̄_j of this step (computed at the end of the last update)
        bank.update(z[:, None])
        xs.append(bank.x_post[:, 0].tolist())
        if k % P_every == 0 or k == len(zs) - 1:
            Ps[k] = bank.P_post.tolist()
        mus.append(bank.mu.tolist())
        mode_x.append([f.x[:, 0].tolist() for f in bank.filters])
        logliks.append(float(np.log(np.sum(cbar * bank.likelihood))))
    out = {"x": xs, "P_steps": sorted(Ps), "P": [Ps[k] for k in sorted(Ps)], "mu": mus, "loglik": logliks}
    return out | ({"mode_x": mode_x} if modes else {})


def crassidis() -> dict:
    """filterpy/kalman/tests/test_imm.py::test_imm, seeded."""
    np.random.seed(36)
    r, dt, N = 100.0, 1.0, 600
    phi_sim = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1]])
    gam = np.array([[dt**2 / 2, 0], [dt, 0], [0, dt**2 / 2], [0, dt]])
    x = np.array([[2000, 0, 10000, -15.0]]).T
    simxs = []
    for i in range(N):
        x = phi_sim @ x
        if i >= 400:
            x += gam @ np.array([[0.075, 0.075]]).T
        simxs.append(x)
    simxs = np.array(simxs)
    zs = np.zeros((N, 2))
    for i in range(N):
        zs[i, 0] = simxs[i, 0, 0] + np.random.randn() * r
        zs[i, 1] = simxs[i, 2, 0] + np.random.randn() * r
    ca, cano = KalmanFilter(6, 2), KalmanFilter(6, 2)
    dt2 = dt**2 / 2
    ca.F = np.array([[1, dt, dt2, 0, 0, 0], [0, 1, dt, 0, 0, 0], [0, 0, 1, 0, 0, 0],
                     [0, 0, 0, 1, dt, dt2], [0, 0, 0, 0, 1, dt], [0, 0, 0, 0, 0, 1]])
    cano.F = ca.F.copy()
    ca.x = np.array([[2000.0, 0, 0, 10000, -15, 0]]).T
    cano.x = ca.x.copy()
    ca.P *= 1.0e-12
    cano.P *= 1.0e-12
    ca.R *= r**2
    cano.R *= r**2
    cano.Q *= 0
    q = np.array([[0.05, 0.125, 1.0 / 6], [0.125, 1 / 3, 0.5], [1.0 / 6, 0.5, 1.0]]) * 1.0e-3
    ca.Q[0:3, 0:3] = q
    ca.Q[3:6, 3:6] = q
    ca.H = np.array([[1, 0, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0]])
    cano.H = ca.H.copy()
    trans = np.array([[0.97, 0.03], [0.03, 0.97]])
    case = {"x0": ca.x[:, 0].tolist(), "P0": ca.P.tolist(), "F": ca.F.tolist(), "H": ca.H.tolist(),
            "Q": [ca.Q.tolist(), cano.Q.tolist()], "R": [ca.R.tolist(), cano.R.tolist()],
            "transition": trans.tolist(), "mu0": [0.5, 0.5], "ys": zs.tolist()}
    case.update(run(IMMEstimator([ca, cano], (0.5, 0.5), trans), zs, 50, False))
    return case


def docstring() -> dict:
    """The example of IMMEstimator's docstring, with two measured positions."""
    rng = np.random.default_rng(36)
    kf1, kf2 = kinematic_kf(2, 2, dim_z=2), kinematic_kf(2, 2, dim_z=2)
    kf2.Q *= 0
    trans = np.array([[0.97, 0.03], [0.03, 0.97]])
    case = {"x0": kf1.x[:, 0].tolist(), "P0": kf1.P.tolist(), "F": kf1.F.tolist(), "H": kf1.H.tolist(),
            "Q": [kf1.Q.tolist(), kf2.Q.tolist()], "R": [kf1.R.tolist(), kf2.R.tolist()],
            "transition": trans.tolist(), "mu0": [0.5, 0.5]}
    zs = np.array([[i + rng.standard_normal() * np.sqrt(kf1.R[0, 0]), i + rng.standard_normal() * np.sqrt(kf1.R[1, 1])]
                   for i in range(30)])
    case["ys"] = zs.tolist()
    case.update(run(IMMEstimator([kf1, kf2], [0.5, 0.5], trans), zs, 1, True))
    return case


if __name__ == "__main__":
    OUT.write_text(json.dumps({"crassidis": crassidis(), "docstring": docstring()}))
    print(f"wrote {OUT} ({OUT.stat().st_size // 1024} KiB)")
