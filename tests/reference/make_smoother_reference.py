"""Make tests/reference/filterpy_rts.json: FilterPy's RTS smoothers and missing measurements.

    pip install ".[bench]"   # FilterPy
    python tests/reference/make_smoother_reference.py

Two problems, each with its measurements stored beside the results, so the test reads the
same data (tests/filters/test_smoother.py):

- ``cv``: a constant-velocity target passing behind a range–bearing sensor (the bearing goes
  through ±π). FilterPy's ``UnscentedKalmanFilter`` (Merwe points α = 1, β = 2, κ = 0, with an
  angle-aware measurement mean and residual) and its ``rts_smoother``; and FilterPy's linear
  ``KalmanFilter.rts_smoother`` run on the EKF's filtered output (the dynamics are linear, so
  the extended RTS smoother is that smoother).
- ``missing``: the ``cv`` track with four rows not measured, FilterPy's UKF with
  ``update(None)`` on them.
- ``heading``: a target with a heading state through ±π and additive noise, seen in range and
  bearing; the UKF and its ``rts_smoother`` with angle-aware state mean and residual.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter, KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

OUT = Path(__file__).with_name("filterpy_rts.json")
K = 40


def wrap(a):
    return np.mod(np.asarray(a) + np.pi, 2 * np.pi) - np.pi


def hx(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def residual_z(a, b):
    d = np.asarray(a, dtype=float) - b
    d[1] = wrap(d[1])
    return d


def z_mean(sigmas, Wm):
    m = sigmas[0] + Wm @ (sigmas - sigmas[0])
    m[1] = np.arctan2(Wm @ np.sin(sigmas[:, 1]), Wm @ np.cos(sigmas[:, 1]))
    return m


def cv() -> dict:
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 1.0
    Q = 0.01 * np.array([[1 / 3, 0, 1 / 2, 0], [0, 1 / 3, 0, 1 / 2], [1 / 2, 0, 1, 0], [0, 1 / 2, 0, 1]])
    R = np.diag([2.0**2, 0.02**2])
    x0, P0 = np.array([-20.0, 100.0, 0.0, -5.0]), np.diag([25.0, 25.0, 0.25, 0.25])
    rng = np.random.default_rng(11)
    x, ys = x0.copy(), []
    for _ in range(K):
        x = F @ x + rng.multivariate_normal(np.zeros(4), Q)
        ys.append(wrap_y(hx(x) + rng.multivariate_normal(np.zeros(2), R)))
    ys = np.array(ys)
    ukf = UnscentedKalmanFilter(4, 2, 1.0, hx, lambda s, dt: F @ s, MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0),
                                z_mean_fn=z_mean, residual_z=residual_z)
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), Q, R
    Xs, Ps = ukf.batch_filter(ys)[:2]
    ukf_x, ukf_P, _ = ukf.rts_smoother(Xs, Ps)
    ekf = ExtendedKalmanFilter(4, 2)
    ekf.x, ekf.P, ekf.F, ekf.Q, ekf.R = x0.copy(), P0.copy(), F, Q, R

    def H(s):
        r2 = s[0] ** 2 + s[1] ** 2
        r = np.sqrt(r2)
        return np.array([[s[0] / r, s[1] / r, 0, 0], [-s[1] / r2, s[0] / r2, 0, 0]])

    ex, eP = [], []
    for y in ys:
        ekf.predict()
        ekf.update(y, H, hx, residual=residual_z)
        ex.append(ekf.x.copy())
        eP.append(ekf.P.copy())
    kf = KalmanFilter(4, 2)
    kf.F, kf.Q = F, Q
    ekf_x, ekf_P = kf.rts_smoother(np.array(ex), np.array(eP))[:2]
    return {"F": F.tolist(), "Q": Q.tolist(), "R": R.tolist(), "x0": x0.tolist(), "P0": P0.tolist(),
            "ys": ys.tolist(), "ukf_filtered_x": Xs.tolist(), "ukf_x": ukf_x.tolist(), "ukf_P": ukf_P.tolist(),
            "ekf_filtered_x": np.array(ex).tolist(), "ekf_x": ekf_x.tolist(), "ekf_P": ekf_P.tolist()}


def wrap_y(y):
    y = np.array(y, dtype=float)
    y[1] = wrap(y[1])
    return y


def heading() -> dict:
    """x = [px, py, th, v]: px += v cos th, py += v sin th, th += 0.3 (a turn), v constant."""
    def fx(s, dt=1.0):
        return np.array([s[0] + s[3] * np.cos(s[2]), s[1] + s[3] * np.sin(s[2]), wrap(s[2] + 0.3), s[3]])

    def residual_x(a, b):
        d = np.asarray(a, dtype=float) - b
        d[2] = wrap(d[2])
        return d

    def x_mean(sigmas, Wm):
        m = sigmas[0] + Wm @ residual_sigmas(sigmas)
        m[2] = np.arctan2(Wm @ np.sin(sigmas[:, 2]), Wm @ np.cos(sigmas[:, 2]))
        return m

    def residual_sigmas(sigmas):
        d = sigmas - sigmas[0]
        d[:, 2] = wrap(d[:, 2])
        return d

    Q = np.diag([0.05, 0.05, 0.01**2, 0.01**2])
    R = np.diag([0.5**2, 0.01**2])
    x0, P0 = np.array([30.0, 10.0, 2.5, 2.0]), np.diag([1.0, 1.0, 0.01, 0.04])
    rng = np.random.default_rng(12)
    x, ys = x0.copy(), []
    for _ in range(K):
        x = fx(x) + rng.multivariate_normal(np.zeros(4), Q)
        x[2] = wrap(x[2])
        ys.append(wrap_y(hx(x) + rng.multivariate_normal(np.zeros(2), R)))
    ys = np.array(ys)
    ukf = UnscentedKalmanFilter(4, 2, 1.0, hx, fx, MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0, subtract=residual_x),
                                x_mean_fn=x_mean, z_mean_fn=z_mean, residual_x=residual_x, residual_z=residual_z)
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), Q, R
    Xs, Ps = ukf.batch_filter(ys)[:2]
    xs, Ps_s, _ = ukf.rts_smoother(Xs, Ps)
    return {"Q": Q.tolist(), "R": R.tolist(), "x0": x0.tolist(), "P0": P0.tolist(), "ys": ys.tolist(),
            "ukf_filtered_x": Xs.tolist(), "ukf_x": xs.tolist(), "ukf_P": Ps_s.tolist()}


#: Steps of the ``cv`` track whose measurement is missing (FilterPy: ``update(None)``).
MISSING = [4, 5, 17, 30]


def missing() -> dict:
    """The ``cv`` track with rows :data:`MISSING` not measured: FilterPy's UKF with ``update(None)``."""
    d = cv()
    F, Q, R = np.array(d["F"]), np.array(d["Q"]), np.array(d["R"])
    ukf = UnscentedKalmanFilter(4, 2, 1.0, hx, lambda s, dt: F @ s, MerweScaledSigmaPoints(4, 1.0, 2.0, 0.0),
                                z_mean_fn=z_mean, residual_z=residual_z)
    ukf.x, ukf.P, ukf.Q, ukf.R = np.array(d["x0"]), np.array(d["P0"]), Q, R
    xs, Ps = [], []
    for k, y in enumerate(d["ys"]):
        ukf.predict()
        ukf.update(None if k in MISSING else np.array(y))
        xs.append(ukf.x.copy())
        Ps.append(ukf.P.copy())
    return {"rows": MISSING, "ukf_x": np.array(xs).tolist(), "ukf_P": np.array(Ps).tolist()}


def main() -> None:
    import filterpy

    doc = {"made_by": "tests/reference/make_smoother_reference.py", "filterpy": filterpy.__version__,
           "cv": cv(), "heading": heading(), "missing": missing()}
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
