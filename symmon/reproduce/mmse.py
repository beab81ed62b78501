"""Reproduce the simulations of the distance paper (Sections 4.3.1, 4.3.2 and 7).

Each experiment is two-stage, as in the paper: a Kalman filter
(:class:`symmon.filters.gaussian.linear.KalmanFilter`) gives :math:`\\hat x_k, P_k`, and a second stage turns them
into a distance or angle estimate. The optimal (MMSE, :mod:`symmon.estimation.mmse`) or composite estimator
is compared with the simple plug-in estimator :math:`f(\\hat x_k)` by the RMSE over Monte Carlo
runs at each time step, and by the average of that RMSE over a time interval (the paper's
"average RMSE"). All runs are simulated and filtered at once (the filter covariances do not
depend on the data), so simulating the default 1000 runs takes about a second; drawing the
three figures takes a few more.

Parameters
----------
The paper's numerical parameters were lost in extraction; the ones below were chosen to show
each regime the paper describes. All noises are Gaussian; ``q`` are process noise variances,
``r`` measurement noise variances, ``rho`` the correlation of the two measurement noises.

**Section 4.3.1** (eqs. (18)-(21)): scalar random walk :math:`x_{k+1} = x_k + w_k`,
:math:`y_k = x_k + v_k`, known initial state (:math:`P_0 = 0`), K = 50 steps; distance to the
origin :math:`|x_k|`. Remark 2 says the two estimators agree when :math:`|\\hat x_k|` is large
compared with :math:`\\sqrt{P_k}`, where :math:`P_\\infty = (-q + \\sqrt{q^2 + 4qr})/2`.

=====  ======  =====  =====  ===========  =====================================================
case   q       r      x0     P_inf        why
=====  ======  =====  =====  ===========  =====================================================
1a     0.01    0.1    0      0.027        small noise, near the origin: the estimators differ
1b     0.01    0.1    10     0.027        small noise, far from the origin: they coincide
2      0.01    1      0      0.095        measurement noise dominates: strong difference
3      1       1      0      0.618        large process noise: the walk leaves the origin,
                                          so the difference shrinks over time
=====  ======  =====  =====  ===========  =====================================================

**Section 4.3.2** (eqs. (22)-(24)): two points on a line, each a random walk, both positions
measured with correlated noises (rho = 0.5), K = 50; distance :math:`|x_{1,k} - x_{2,k}|`
estimated by Theorem 1 with :math:`a = (1, -1)`. Initial state :math:`N(m_0, P_0)`.

=====  ============  ==========  ==========  ======  ==================================
case   q1, q2        r1, r2      m0          P0      scenario (paper)
=====  ============  ==========  ==========  ======  ==================================
fig8   0.01, 0.01    0.1, 0.1    (0, 10)     0.1 I   points far apart (Figure 8): equal
1      0, 0          1, 1        (0, 0.3)    0.1 I   both fixed, unknown positions
2      0, 0.01       0.1, 0.1    (0, 0)      0       first fixed, second moves slowly
3      0.1, 0.1      1, 1        (0, 0)      0       both move with medium noise
=====  ============  ==========  ==========  ======  ==================================

**Section 7**: the two coordinates of Section 4.3.2 become the position :math:`x_k \\in R^2`
of one object (rho = 0.5, K = 100). Estimated: range :math:`\\|x_k\\|` (composite
:func:`symmon.estimation.mmse.norm` vs :math:`\\|\\hat x_k\\|`), bearing :math:`\\operatorname{atan2}(x_2,
x_1)` (composite = simple, :func:`symmon.estimation.mmse.bearing`; errors wrapped to :math:`(-\\pi, \\pi]`),
and the cosine of the angle between :math:`x_k` and :math:`x_{k-1}` (composite
:func:`symmon.estimation.mmse.cosine_angle` vs the plug-in). The pair :math:`(x_k, x_{k-1})` is estimated
jointly given :math:`y_{1:k}` by a Kalman filter on the augmented state
:math:`[x_k; x_{k-1}]`, whose cross-covariance block gives :math:`P_{xy}`; this is the exact
conditional distribution (fixed-lag smoothing of :math:`x_{k-1}`), where the paper's eq. (55)
pairs the filtered estimates of the two times. The cosine is averaged over the subintervals
k = 1..50 and 51..100.

=========  ==============  ==============  ========  ========
scenario   q1, q2          r1, r2          m0        P0
=========  ==============  ==============  ========  ========
medium     0.1, 0.1        1, 1            (1, 1)    2 I
small      0.001, 0.001    0.01, 0.01      (3, 2)    0.01 I
=========  ==============  ==============  ========  ========

"medium" keeps the object within a few noise standard deviations of the origin, where the
composite estimators help; "small" is the limit the paper names (variances tending to zero),
where composite and simple estimators converge.

Outputs (in ``outdir``): ``mmse_sec431_rmse.csv``, ``mmse_sec432_rmse.csv``,
``mmse_sec7_rmse.csv`` (RMSE per time step), ``mmse_summary.csv`` (average RMSEs over
``k_from..k_to``; ``avg_rmse_proposed`` is the optimal MMSE estimator in Section 4.3 and the
composite one in Section 7) and one PNG per section. The Section 4.3 tables also give the *predicted* RMSE: the root of the run-average
of the closed-form conditional MSE (:func:`symmon.estimation.mmse.abs_linear_mse`; for the simple estimator
plus its squared distance from the MMSE estimate), a check of the MSE formulas.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ArgumentError, plain_repr
from ..estimation import mmse
from ..io import check_output_set, write_csv
from ..filters.gaussian.linear import KalmanFilter
from .common import OKABE_ITO, figure_style, label_panels, pyplot, save_reproduced, with_format

__all__ = [
    "OUTPUTS",
    "ScalarCase",
    "TwoPointCase",
    "PlaneCase",
    "SEC431_CASES",
    "SEC432_CASES",
    "SEC7_CASES",
    "run",
]

#: The files :func:`run` writes into its directory, checked before any work
#: (:func:`symmon.io.check_output_set`; the command line checks them with its other outputs).
OUTPUTS = ("mmse_sec431_rmse.csv", "mmse_sec431.png", "mmse_sec432_rmse.csv", "mmse_sec432.png",
           "mmse_sec7_rmse.csv", "mmse_sec7.png", "mmse_summary.csv")


@dataclass(frozen=True)
class ScalarCase:
    """Section 4.3.1: scalar random walk with known initial state ``x0``."""

    name: str
    q: float
    r: float
    x0: float
    K: int = 50

    @property
    def params(self) -> str:
        return f"q={self.q} r={self.r} x0={self.x0} P0=0 K={self.K}"


@dataclass(frozen=True)
class TwoPointCase:
    """Section 4.3.2: two random walks on a line, correlated measurement noises."""

    name: str
    q: tuple[float, float]
    r: tuple[float, float]
    m0: tuple[float, float]
    p0: float
    rho: float = 0.5
    K: int = 50

    @property
    def params(self) -> str:
        return f"q={self.q} r={self.r} rho={self.rho} m0={self.m0} P0={self.p0}*I K={self.K}"


@dataclass(frozen=True)
class PlaneCase:
    """Section 7: 2-D random-walk position; the angle is between x_k and x_{k-1}."""

    name: str
    q: tuple[float, float]
    r: tuple[float, float]
    m0: tuple[float, float]
    p0: float
    rho: float = 0.5
    K: int = 100
    split: int = 50  # last step of the first subinterval

    @property
    def params(self) -> str:
        return f"q={self.q} r={self.r} rho={self.rho} m0={self.m0} P0={self.p0}*I K={self.K}"


SEC431_CASES = (
    ScalarCase("1a", q=0.01, r=0.1, x0=0.0),
    ScalarCase("1b", q=0.01, r=0.1, x0=10.0),
    ScalarCase("2", q=0.01, r=1.0, x0=0.0),
    ScalarCase("3", q=1.0, r=1.0, x0=0.0),
)
SEC432_CASES = (
    TwoPointCase("fig8", q=(0.01, 0.01), r=(0.1, 0.1), m0=(0.0, 10.0), p0=0.1),
    TwoPointCase("1", q=(0.0, 0.0), r=(1.0, 1.0), m0=(0.0, 0.3), p0=0.1),
    TwoPointCase("2", q=(0.0, 0.01), r=(0.1, 0.1), m0=(0.0, 0.0), p0=0.0),
    TwoPointCase("3", q=(0.1, 0.1), r=(1.0, 1.0), m0=(0.0, 0.0), p0=0.0),
)
SEC7_CASES = (
    PlaneCase("medium", q=(0.1, 0.1), r=(1.0, 1.0), m0=(1.0, 1.0), p0=2.0),
    PlaneCase("small", q=(0.001, 0.001), r=(0.01, 0.01), m0=(3.0, 2.0), p0=0.01),
)


def _rmse(err: np.ndarray) -> np.ndarray:
    """RMSE over the runs (axis 0) at each time step."""
    return np.sqrt(np.mean(err * err, axis=0))


def _correlated(r: tuple[float, float], rho: float) -> np.ndarray:
    c = rho * np.sqrt(r[0] * r[1])
    return np.array([[r[0], c], [c, r[1]]])


def _abs_experiment(
    kf: KalmanFilter, a: np.ndarray, m0: np.ndarray, P0: np.ndarray, K: int, runs: int,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """|aᵀx_k| by Theorem 1 and by the plug-in, over ``runs`` runs of the model ``kf``."""
    random_start = bool(np.any(P0))
    states, ys = kf.simulate(K, m0, rng, P0=P0 if random_start else None, runs=runs)
    res = kf.filter(ys, m0, P0)
    truth = np.abs(states @ a)
    optimal = mmse.abs_linear(a, 0.0, res.x, res.P)
    simple = np.abs(res.x @ a)
    mse_opt = mmse.abs_linear_mse(a, 0.0, res.x, res.P)
    return {
        "rmse_optimal": _rmse(optimal - truth),
        "rmse_simple": _rmse(simple - truth),
        # Conditional MSEs averaged over the data: the unconditional MSE, from the formulas.
        "rmse_optimal_predicted": np.sqrt(np.mean(mse_opt, axis=0)),
        "rmse_simple_predicted": np.sqrt(np.mean(mse_opt + (optimal - simple) ** 2, axis=0)),
    }


def _sec431(case: ScalarCase, runs: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    kf = KalmanFilter(F=1.0, Q=case.q, H=1.0, R=case.r)
    return _abs_experiment(kf, np.ones(1), np.array([case.x0]), np.zeros((1, 1)), case.K, runs, rng)


def _sec432(case: TwoPointCase, runs: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    kf = KalmanFilter(F=np.eye(2), Q=np.diag(case.q), H=np.eye(2), R=_correlated(case.r, case.rho))
    P0 = case.p0 * np.eye(2)
    return _abs_experiment(kf, np.array([1.0, -1.0]), np.array(case.m0), P0, case.K, runs, rng)


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angle difference wrapped to [-pi, pi)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _sec7(case: PlaneCase, runs: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    I, Z = np.eye(2), np.zeros((2, 2))
    # Augmented state z_k = [x_k; x_{k-1}]: the filter then gives the joint Gaussian of the
    # two positions given y_{1:k}, including their cross-covariance.
    kf = KalmanFilter(
        F=np.block([[I, Z], [I, Z]]),
        Q=np.block([[np.diag(case.q), Z], [Z, Z]]),
        H=np.hstack([I, Z]),
        R=_correlated(case.r, case.rho),
    )
    m0 = np.r_[case.m0, case.m0]  # the lagged block of z_0 is replaced after one step
    P0 = case.p0 * np.block([[I, I], [I, I]])
    states, ys = kf.simulate(case.K, m0, rng, P0=P0 if case.p0 > 0 else None, runs=runs)
    res = kf.filter(ys, m0, P0)
    cur, lag = slice(0, 2), slice(2, 4)
    x, y = states[..., cur], states[..., lag]
    xh, yh = res.x[..., cur], res.x[..., lag]
    Pxx, Pyy, Pxy = res.cross_cov(cur, cur), res.cross_cov(lag, lag), res.cross_cov(cur, lag)

    def cos(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.sum(u * v, axis=-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))

    true_range = np.linalg.norm(x, axis=-1)
    true_bearing = np.arctan2(x[..., 1], x[..., 0])
    true_cos = cos(x, y)
    range_c = mmse.norm(xh, Pxx)
    range_s = np.linalg.norm(xh, axis=-1)
    bearing_c = mmse.bearing(xh, Pxx)
    bearing_s = np.arctan2(xh[..., 1], xh[..., 0])
    cos_c = mmse.cosine_angle(xh, yh, Pxx, Pyy, Pxy)
    cos_s = cos(xh, yh)
    return {
        "range_composite": _rmse(range_c - true_range),
        "range_simple": _rmse(range_s - true_range),
        "bearing_composite": _rmse(_wrap(bearing_c - true_bearing)),
        "bearing_simple": _rmse(_wrap(bearing_s - true_bearing)),
        "cosine_composite": _rmse(cos_c - true_cos),
        "cosine_simple": _rmse(cos_s - true_cos),
        # One run for the trajectory panel (as the paper's Figure 10(a)).
        "example_true_range": true_range[0],
        "example_range_composite": range_c[0],
        "example_range_simple": range_s[0],
        "steady_P": res.P[-1, :2, :2],
    }


def _per_step_rows(name: str, data: dict[str, np.ndarray], keys: tuple[str, ...]) -> list[list[Any]]:
    K = data[keys[0]].shape[0]
    return [[name, k + 1, *(float(data[key][k]) for key in keys)] for k in range(K)]


#: The estimators' looks in every MMSE figure: (colour, line style, marker).
LOOKS = {"optimal": (OKABE_ITO["blue"], "-", "o"), "composite": (OKABE_ITO["blue"], "-", "o"),
         "simple": (OKABE_ITO["vermillion"], "--", "s"), "predicted": ("0.45", ":", None),
         "true": (OKABE_ITO["black"], "-", None)}


def _look(name: str, points: int, label: str) -> dict:
    colour, ls, marker = LOOKS[name]
    return {"color": colour, "ls": ls, "marker": marker, "ms": 3.5, "mfc": "none",
            # the simple estimator's markers between the others': the curves often coincide
            "markevery": (max(1, points // 10) // 2 if name == "simple" else 0, max(1, points // 10)), "label": label}


def _figure_abs(plt: Any, cases: tuple, results: dict[str, dict[str, np.ndarray]]) -> Any:
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.4), sharex=True)
    # Fixed margins: a layout engine would draw every figure twice.
    fig.subplots_adjust(left=0.08, right=0.98, top=0.94, bottom=0.14, hspace=0.25, wspace=0.22)
    for ax, case in zip(axes.ravel(), cases):
        data = results[case.name]
        k = np.arange(1, data["rmse_optimal"].shape[0] + 1)
        ax.plot(k, data["rmse_optimal"], **_look("optimal", k.size, "optimal (MMSE)"))
        ax.plot(k, data["rmse_simple"], **_look("simple", k.size, "simple |plug-in|"))
        ax.plot(k, data["rmse_optimal_predicted"], **_look("predicted", k.size, "optimal, predicted"))
        ax.set_xlabel("time step k")
        ax.set_ylabel("RMSE of the distance estimate\n(over the Monte Carlo runs)")
    label_panels(axes.ravel(), [f"case {c.name}" for c in cases])
    fig.legend(handles=axes.ravel()[0].get_lines(), loc="lower center", ncol=3, frameon=False)
    return fig


def _caption_abs(title: str, cases: tuple) -> str:
    return f"{title}. " + "; ".join(f"({x}) case {c.name}: {c.params}" for x, c in zip("abcd", cases)) + "."


def _figure_sec7(plt: Any, results: dict[str, dict[str, np.ndarray]]) -> Any:
    fig, axes = plt.subplots(len(SEC7_CASES), 4, figsize=(15, 3.8 * len(SEC7_CASES)))
    fig.subplots_adjust(left=0.05, right=0.99, top=0.93, bottom=0.14, hspace=0.4, wspace=0.25)
    axes = np.atleast_2d(axes)
    names = []
    for row, case in zip(axes, SEC7_CASES):
        data = results[case.name]
        k = np.arange(1, case.K + 1)
        row[0].plot(k, data["example_true_range"], **_look("true", k.size, "true"))
        row[0].plot(k, data["example_range_composite"], **_look("composite", k.size, "composite"))
        row[0].plot(k, data["example_range_simple"], **_look("simple", k.size, "simple"))
        names.append(f"{case.name}: range, one run")
        row[0].set_ylabel("range to the origin")
        for ax, q, label in zip(row[1:], ("range", "bearing", "cosine"), ("range", "bearing [rad]", "cos angle(x_k, x_{k-1})")):
            ax.plot(k, data[f"{q}_composite"], **_look("composite", k.size, "composite"))
            ax.plot(k, data[f"{q}_simple"], **_look("simple", k.size, "simple"))
            names.append(f"{case.name}: RMSE of {label}")
            ax.set_ylabel(f"RMSE of the {label} estimate")
        for ax in row:
            ax.set_xlabel("time step k")
    label_panels(axes.ravel(), names)
    fig.legend(handles=axes[0, 0].get_lines(), loc="lower center", ncol=3, frameon=False)
    return fig


SEC7_CAPTION = "Section 7: motion in a plane; " + "; ".join(f"{c.name}: {c.params}" for c in SEC7_CASES) + "."


@figure_style()
def run(outdir: Path, runs: int = 1000, seed: int = 0, progress: bool = True,
        fmt: str = "png") -> list[Path]:
    """Run the Section 4.3.1, 4.3.2 and 7 simulations and write tables and plots.

    Parameters
    ----------
    outdir : Path
        Output directory (created if missing).
    runs : int, default 1000
        Monte Carlo runs per case (the paper uses 1000); at least 2.
    seed : int, default 0
        Seed of the random numbers; each case gets its own stream spawned from it, so a case's
        results do not depend on the others.
    progress : bool, default True
        Show a tqdm progress bar (only when stdout is a terminal).

    Returns
    -------
    list of Path
        The files written: four CSV tables and three PNG figures.
    """
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 2:
        raise ArgumentError(f"runs must be an integer >= 2, got {plain_repr(runs)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArgumentError(f"seed must be a non-negative integer, got {plain_repr(seed)}")
    plt = pyplot()  # files only; never open a window
    from tqdm import tqdm

    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    cases: list[tuple[str, Any]] = (
        [("4.3.1", c) for c in SEC431_CASES] + [("4.3.2", c) for c in SEC432_CASES] + [("7", c) for c in SEC7_CASES]
    )
    streams = np.random.SeedSequence(seed).spawn(len(cases))
    experiments = {"4.3.1": _sec431, "4.3.2": _sec432, "7": _sec7}
    results: dict[str, dict[str, dict[str, np.ndarray]]] = {"4.3.1": {}, "4.3.2": {}, "7": {}}
    disable = (not progress) or not sys.stdout.isatty()
    with tqdm(total=len(cases) + 3, desc="mmse reproduction", disable=disable) as bar:
        for (section, case), stream in zip(cases, streams):
            results[section][case.name] = experiments[section](case, int(runs), np.random.default_rng(stream))
            bar.update()

        written: list[Path] = []
        abs_keys = ("rmse_optimal", "rmse_simple", "rmse_optimal_predicted", "rmse_simple_predicted")
        summary: list[list[Any]] = []
        for section, tag, section_cases in (("4.3.1", "sec431", SEC431_CASES), ("4.3.2", "sec432", SEC432_CASES)):
            rows = [r for c in section_cases for r in _per_step_rows(c.name, results[section][c.name], abs_keys)]
            written.append(write_csv(outdir / f"mmse_{tag}_rmse.csv", ["case", "k", *abs_keys], rows))
            for c in section_cases:
                d = results[section][c.name]
                summary.append([section, c.name, "distance", 1, c.K, float(d["rmse_optimal"].mean()),
                                float(d["rmse_simple"].mean()), c.params])
            title = {"4.3.1": "Section 4.3.1: |x_k|, scalar random walk",
                     "4.3.2": "Section 4.3.2: |x1_k - x2_k|, two points on a line"}[section]
            fig = _figure_abs(plt, section_cases, results[section])
            written.append(save_reproduced(fig, outdir / f"mmse_{tag}.png", fmt, title,
                                           _caption_abs(f"{title} ({runs} runs)", section_cases)))
            plt.close(fig)
            bar.update()

        q7 = ("range", "bearing", "cosine")
        keys7 = tuple(f"{q}_{e}" for q in q7 for e in ("composite", "simple"))
        rows7 = [r for c in SEC7_CASES for r in _per_step_rows(c.name, results["7"][c.name], keys7)]
        written.append(write_csv(outdir / "mmse_sec7_rmse.csv", ["case", "k", *keys7], rows7))
        for c in SEC7_CASES:
            d = results["7"][c.name]
            intervals = {"range": [(1, c.K)], "bearing": [(1, c.K)], "cosine": [(1, c.split), (c.split + 1, c.K)]}
            for q in q7:
                for lo, hi in intervals[q]:
                    summary.append(["7", c.name, q, lo, hi, float(d[f"{q}_composite"][lo - 1:hi].mean()),
                                    float(d[f"{q}_simple"][lo - 1:hi].mean()), c.params])
        fig = _figure_sec7(plt, results["7"])
        written.append(save_reproduced(fig, outdir / "mmse_sec7.png", fmt, "Section 7: motion in a plane",
                                       f"{SEC7_CAPTION} {runs} runs."))
        plt.close(fig)
        bar.update()

        header = ["section", "case", "quantity", "k_from", "k_to", "avg_rmse_proposed", "avg_rmse_simple", "parameters"]
        written.append(write_csv(outdir / "mmse_summary.csv", header, summary))
        bar.update()
    return written
