"""Where does the EKF lose consistency, and does the measure of nonlinearity predict it?

Two tracking problems, each a bank of Monte Carlo runs filtered by the EKF (TT1), the
second-order EKF (TT2), the UKF (``UT.ut1()``), the CKF, the Gauss–Hermite filter (order 3)
and the adaptive filter (:class:`symmon.Adaptive`, tol 0.01):

(a) **bearings-only tracking** of a constant-velocity target from an observer that
    manoeuvres (three legs of constant velocity).  The state is relative,
    x = [target − observer position; target − observer velocity], so that the models do
    not change with time: the observer's known change of velocity at the start of a leg
    shifts the relative velocity of the truth and of every filter's estimate.
(b) **range–bearing tracking** of a constant-velocity target passing 20 m from the sensor,
    behind it: the bearing goes through ±π at closest approach, where the range is
    comparable to the position uncertainty.

Both dynamics are linear, so every filter's time update is exact and the filters differ
only in the measurement update.  The MoN along the trajectory is the full-weight MoN
(Straka & Havlík 2024, eq. (43), TT2) of the measurement y = h(x) + e at each run's EKF
prior N(x̂_{k|k−1}, P_{k|k−1}) and e ~ N(0, R), over the first :data:`MON_RUNS` runs
(median and 10–90 % band); the same without the noise e is shown beside.

Files written to ``outdir``: ``tracking_bot.png``, ``tracking_rb.png`` (ANEES, ANIS,
position RMSE (and the smoothed RMSE of each filter's RTS smoother, dotted), MoN and the adaptive
filter's choices on one time axis),
``tracking_summary.csv`` (one row per scenario and filter), ``tracking_steps.csv``
(one row per scenario and step) and ``tracking_events.csv``: each run whose EKF NEES
exceeds :data:`EVENT_NEES`, with the first such step, that run's MoN there and two steps
before, where that MoN lies among the per-run MoN values of the first :data:`MON_RUNS`
runs at all steps (its quantile), the adaptive filter's choice and NEES there, and the
true range.

NEES and NIS are averaged over the runs at each step and compared with their two-sided
95 % χ² intervals (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp

from ..core.angles import wrap_angle
from ..errors import SymmonError, plain_repr
from ..files.filterfile import filter_transform
from ..filters.gaussian.nonlinear import NonlinearKalmanFilter, NonlinearKalmanResult
from ..core.gaussian import Gaussian
from ..io import check_output_set, write_csv
from ..core.model import Model
from ..measures.mon import nonlinearity
from ..compile.compiled import compiled
from .common import (figure_style, filter_style, label_panels, legend_outside, plain_log_ticks,
                     progress_bar, save_reproduced, with_format)

__all__ = ["OUTPUTS", "run", "Scenario", "scenarios", "FILTER_NAMES", "MON_RUNS", "TOL", "LABELS", "caption"]

#: The files :func:`run` writes into its directory, checked before any work
#: (:func:`symmon.io.check_output_set`; the command line checks them with its other outputs).
OUTPUTS = ("tracking_bot.png", "tracking_rb.png", "tracking_summary.csv", "tracking_steps.csv",
           "tracking_events.csv")

#: The filters compared, by their names in :mod:`symmon.filters.registry`.
FILTER_NAMES = ("ekf", "ekf2", "ukf", "ckf", "gh", "adaptive")
#: The adaptive filter's tolerance (unitless moment error).
TOL = 1e-2
#: Runs over which the MoN along the trajectory is computed (it is per run and per step).
MON_RUNS = 100
#: Confidence of the χ² intervals.
CONFIDENCE = 0.95
#: A run "loses consistency" at the first step where its EKF NEES exceeds this (the 95 %
#: point of χ²(4) is 9.5; 30 is beyond the 99.999 % point, 27.9).
EVENT_NEES = 30.0


@dataclass(frozen=True)
class Scenario:
    """A tracking problem: linear dynamics F, additive noises, a prior, known state shifts.

    ``shifts`` maps a step k to a vector added to the state (truth and estimates) before
    the prediction to step k: the observer's manoeuvres in relative coordinates.
    """

    name: str
    title: str
    f: Model
    h: Model
    h_noisy: Model
    Q: np.ndarray
    R: np.ndarray
    x0: Gaussian
    steps: int
    shifts: dict[int, np.ndarray] = field(default_factory=dict)


def _cv(T: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant velocity in 2-D: F and the discretised white-noise acceleration Q
    (Bar-Shalom et al. 2001, §6.2.2) with power spectral density q."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = T
    Q = q * np.kron(np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]]), np.eye(2))
    return F, Q


def _models(name: str, F: np.ndarray, outputs, angles: list[int]) -> tuple[Model, Model, Model]:
    rx, ry, vx, vy = X = sp.symbols("rx ry vx vy", real=True)
    f = Model(list(X), list(sp.Matrix(F) * sp.Matrix(X)), name=f"{name}_f")
    ys = outputs(rx, ry)
    h = Model(list(X), ys, name=f"{name}_h", angles=angles)
    e = sp.symbols(f"e0:{len(ys)}", real=True)
    h_noisy = Model(list(X), [y + ei for y, ei in zip(ys, e)], noise=list(e), name=f"{name}_hn", angles=angles)
    return f, h, h_noisy


def scenarios() -> tuple[Scenario, Scenario]:
    """(a) bearings-only from a manoeuvring observer, (b) range–bearing passing behind."""
    # (a) T = 10 s; the observer at 5 m/s heads east, then 120°, then east again.
    T = 10.0
    F, Q = _cv(T, 1e-4)
    f, h, hn = _models("bot", F, lambda rx, ry: [sp.atan2(ry, rx)], [0])
    v_obs = [5.0 * np.array([np.cos(a), np.sin(a)]) for a in np.radians([0.0, 120.0, 0.0])]
    legs = (20, 40)
    # The relative velocity is v_target − v_observer: a new leg subtracts the change of v_observer.
    shifts = {k: np.r_[0.0, 0.0, -(v_obs[i + 1] - v_obs[i])] for i, k in enumerate(legs)}
    # Target 5 km away at bearing ~53°, moving at 3 m/s; the observer's initial velocity is
    # folded into the relative velocity.
    x0 = Gaussian(np.r_[3000.0, 4000.0, np.array([-3.0, 0.0]) - v_obs[0]],
                  np.diag([1000.0**2, 1000.0**2, 2.0**2, 2.0**2]))
    bot = Scenario("bot", "(a) bearings-only, manoeuvring observer (turns at k = 20, 40)", f, h, hn, Q,
                   np.array([[np.radians(1.0) ** 2]]), x0, 60, shifts)
    # (b) T = 1 s; the target moves south at 5 m/s along x = −20 m, so it passes 20 m behind
    # the sensor (bearing π) at k ≈ 20.
    F, Q = _cv(1.0, 0.01)
    f, h, hn = _models("rb", F, lambda rx, ry: [sp.sqrt(rx**2 + ry**2), sp.atan2(ry, rx)], [1])
    rb = Scenario("rb", "(b) range-bearing, target passing 20 m behind the sensor", f, h, hn, Q,
                  np.diag([2.0**2, 0.02**2]), Gaussian([-20.0, 100.0, 0.0, -5.0], np.diag([25.0, 25.0, 0.25, 0.25])),
                  40)
    return bot, rb


def simulate(sc: Scenario, runs: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """True relative states (runs, K, 4) and measurements (runs, K, n_y), angles wrapped."""
    F = np.asarray(sp.Matrix(sc.f.outputs).jacobian(sc.f.inputs), dtype=float)
    Lq = np.linalg.cholesky(sc.Q)
    Lr = np.linalg.cholesky(sc.R)
    x = sc.x0.mean + rng.standard_normal((runs, 4)) @ sc.x0.sqrt_cov().T
    xs, ys = np.empty((runs, sc.steps, 4)), np.empty((runs, sc.steps, sc.h.n_y))
    ch, angles = compiled(sc.h), sorted(sc.h.angle_outputs)
    for k in range(sc.steps):
        if k in sc.shifts:
            x = x + sc.shifts[k]
        x = x @ F.T + rng.standard_normal((runs, 4)) @ Lq.T
        y = ch.eval_g(x) + rng.standard_normal((runs, sc.h.n_y)) @ Lr.T
        y[:, angles] = wrap_angle(y[:, angles])
        xs[:, k], ys[:, k] = x, y
    return xs, ys


def filter_bank(sc: Scenario, name: str, ys: np.ndarray, smooth: bool = False):
    """Filter the bank leg by leg: between legs the estimate is shifted as the truth.

    With ``smooth``, also the RTS smoother of each leg (a leg's smoother uses that leg's
    measurements: the observer's manoeuvres bound the smoothing windows); returns
    (filtered, smoothed x) then, the latter None for the adaptive filter."""
    kf = NonlinearKalmanFilter(sc.f, sc.h, sc.Q, sc.R, filter_transform(name, TOL))
    asked, smooth = smooth, smooth and name != "adaptive"
    bounds = [0, *sorted(sc.shifts), sc.steps]
    parts: list[NonlinearKalmanResult] = []
    smoothed = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        x0, P0 = (sc.x0, None) if not parts else (parts[-1].x[:, -1] + sc.shifts[a], parts[-1].P[:, -1])
        if smooth:
            sres = kf.smooth(ys[:, a:b], x0, P0)
            res = sres.filtered
            smoothed.append(sres.x)
        else:
            res = kf.filter(ys[:, a:b], x0, P0)
        parts.append(res)
    keys = ("x", "P", "x_pred", "P_pred", "innovation", "S", "loglik")
    arrays = {k: np.concatenate([getattr(p, k) for p in parts], axis=1) for k in keys}
    choices = None if parts[0].choices is None else np.concatenate([p.choices for p in parts], axis=1)
    out = NonlinearKalmanResult(**arrays, method=parts[0].method, choices=choices)
    if not asked:
        return out
    return out, (np.concatenate(smoothed, axis=1) if smoothed else None)


def mon_along(sc: Scenario, res: NonlinearKalmanResult, runs: int, noisy: bool) -> np.ndarray:
    """The full-weight MoN (TT2) of the measurement at each run's prior: (runs, K)."""
    model = sc.h_noisy if noisy else sc.h
    v = Gaussian(np.zeros(sc.h.n_y), sc.R) if noisy else None
    out = np.empty((runs, sc.steps))
    for r in range(runs):
        for k in range(sc.steps):
            out[r, k] = nonlinearity(model, Gaussian(res.x_pred[r, k], res.P_pred[r, k]), v, weight="full").value
    return out


def _position_rmse(xs: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(np.sum((xs[..., :2] - x[..., :2]) ** 2, axis=-1), axis=0))


def study(sc: Scenario, runs: int, seed: int, progress: bool = True) -> dict[str, Any]:
    """Simulate, filter with every filter, and compute the statistics of one scenario."""
    rng = np.random.default_rng(seed)
    xs, ys = simulate(sc, runs, rng)
    out: dict[str, Any] = {"filters": {}, "failed": {}}
    for name in progress_bar(FILTER_NAMES, sc.name, progress):
        try:
            res, x_smooth = filter_bank(sc, name, ys, smooth=True)
        except SymmonError as exc:  # a filter that diverged: reported, not plotted
            out["failed"][name] = str(exc)
            continue
        out["filters"][name] = {"result": res, "anees": res.anees(xs, CONFIDENCE), "anis": res.anis(CONFIDENCE),
                                "rmse": _position_rmse(xs, res.x),
                                "rmse_smoothed": None if x_smooth is None else _position_rmse(xs, x_smooth)}
    ekf = out["filters"].get("ekf")
    m = min(runs, MON_RUNS)
    if ekf is not None:
        out["mon"] = mon_along(sc, ekf["result"], m, noisy=True)
        out["mon_clean"] = mon_along(sc, ekf["result"], m, noisy=False)
        out["events"] = _events(sc, ekf["result"], xs, out["filters"].get("adaptive"), out["mon"])
    return out


def _events(sc: Scenario, ekf: NonlinearKalmanResult, xs: np.ndarray, adaptive: dict | None,
            mon: np.ndarray) -> list[list]:
    """Each run whose EKF NEES exceeds :data:`EVENT_NEES`: the first such step, the MoN of
    that run at its EKF prior there and two steps before, the share of the per-run MoN
    values ``mon`` (all runs and steps) below it, and the adaptive filter's choice."""
    nees = ekf.nees(xs)
    v = Gaussian(np.zeros(sc.h.n_y), sc.R)
    rows = []
    for r in np.flatnonzero((nees > EVENT_NEES).any(axis=1)):
        k = int(np.argmax(nees[r] > EVENT_NEES))
        mons = [nonlinearity(sc.h_noisy, Gaussian(ekf.x_pred[r, j], ekf.P_pred[r, j]), v, weight="full").value
                if j >= 0 else float("nan") for j in (k - 2, k - 1, k)]
        choice = "" if adaptive is None else str(adaptive["result"].choices[r, k])
        ad_nees = float("nan") if adaptive is None else float(adaptive["result"].nees(xs)[r, k])
        rng = float(np.hypot(*xs[r, k, :2]))
        rows.append([sc.name, int(r), k + 1, float(nees[r, k]), *mons, float(np.mean(mon < mons[-1])),
                     choice, ad_nees, rng])
    return rows


#: The filters' names in the figures' legends.
LABELS = {"ekf": "EKF", "ekf2": "EKF2", "ukf": "UKF", "ckf": "CKF", "gh": "GH", "adaptive": "adaptive"}
#: The MoN along the trajectory, with and without the noise: (key, colour, marker, line style,
#: label); in greys, as the Okabe–Ito colours are the filters'.
MON_CURVES = (("mon", "0.15", "o", "-", "MoN of h(x) + e"),
              ("mon_clean", "0.45", "s", "--", "MoN of h(x), no noise"))


def caption(sc: Scenario, runs: int) -> str:
    """The caption of a tracking figure (saved in the PNG's metadata; docs/tracking.md)."""
    return (f"{sc.title}: {runs} Monte Carlo runs. (a) average NEES and (b) average NIS with their two-sided "
            "95 % chi-square intervals (grey); (c) position RMSE, each filter's RTS smoother dotted in its colour; "
            "(d) full-weight MoN (Straka & Havlík 2024, (43), TT2) of the measurement at each run's EKF prior, "
            "median and 10-90 % of the runs; (e) the adaptive filter's choices, share of runs. Each filter has one "
            "colour, marker and line style in every panel; dotted vertical lines: the observer's turns.")


def _figure(sc: Scenario, st: dict[str, Any]):
    """The figure of one scenario: five panels on one time axis, legends right of them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(7.5, 10.5), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(5, 1, sharex=True)
    k = np.arange(1, sc.steps + 1)
    filters = st["filters"]
    for name, d in filters.items():
        style = filter_style(name, sc.steps)
        label = LABELS.get(name, name)
        axes[0].semilogy(k, d["anees"].value, label=label, **style)
        axes[1].semilogy(k, d["anis"].value, **style)
        axes[2].semilogy(k, d["rmse"], **style)
        if d["rmse_smoothed"] is not None:  # its RTS smoother: thin, dotted, in the filter's colour
            axes[2].semilogy(k, d["rmse_smoothed"], ls=(0, (1, 1)), lw=0.8, color=style["color"],
                             zorder=style["zorder"])
    if filters:
        any_ = next(iter(filters.values()))
        for ax, t in ((axes[0], any_["anees"]), (axes[1], any_["anis"])):
            ax.axhspan(t.lower, t.upper, color="0.85", zorder=0, label="95 % χ² interval")
    axes[0].set_ylabel("average NEES\n(expected 4)")
    axes[1].set_ylabel(f"average NIS\n(expected {sc.h.n_y})")
    axes[2].set_ylabel("position RMSE [m]")
    legend_outside(axes[0])
    legend_outside(axes[1])
    legend_outside(axes[2], handles=[Line2D([], [], color="0.35", lw=1.2, label="filter"),
                                     Line2D([], [], color="0.35", lw=0.8, ls=(0, (1, 1)), label="its RTS smoother")])
    if "mon" in st:
        for key, color, marker, ls, label in MON_CURVES:
            q10, q50, q90 = np.percentile(st[key], [10, 50, 90], axis=0)
            axes[3].plot(k, q50, color=color, ls=ls, marker=marker, ms=3.5, mfc="none", markevery=5,
                         label=f"{label}: median")
            axes[3].fill_between(k, q10, q90, color=color, alpha=0.2, lw=0, label="10–90 % of runs")
        axes[3].set_yscale("log")
        axes[3].set_ylabel("MoN (full weight)\nat the EKF prior")
        legend_outside(axes[3])
    if "adaptive" in filters:
        ch = filters["adaptive"]["result"].choices
        for name in np.unique(ch):
            if name:  # "": a step not run
                axes[4].plot(k, np.mean(ch == name, axis=0), label=str(name), **filter_style(str(name), sc.steps))
        axes[4].set_ylabel("adaptive filter:\nshare of runs")
        legend_outside(axes[4], title="its choice")
    for ax in axes[:4]:
        if ax.get_yscale() == "log":
            plain_log_ticks(ax)
    for kk in sorted(sc.shifts):
        for ax in axes:
            ax.axvline(kk + 0.5, color="0.5", ls=":", lw=1)
    axes[-1].set_xlabel("step k")
    label_panels(axes)
    return fig


def _plot(sc: Scenario, st: dict[str, Any], runs: int, path: Path, fmt: str = "png") -> Path:
    return save_reproduced(_figure(sc, st), path, fmt, f"Tracking: {sc.title}", caption(sc, runs))


def _rms(rmse: np.ndarray | None) -> float | None:
    """The RMSE over the steps, or None (an empty CSV field) when there is none."""
    return None if rmse is None else float(np.sqrt(np.mean(rmse**2)))


@figure_style()
def run(outdir: Path, runs: int = 500, seed: int = 0, progress: bool = True,
        fmt: str = "png") -> list[Path]:
    """Run both scenarios and write the figures and tables (module notes).

    Parameters
    ----------
    outdir : Path
        Output directory (created if missing).
    runs : int, default 500
        Monte Carlo runs per scenario (at least 2).
    seed : int, default 0
        Seed; each scenario draws from its own spawned stream.
    progress : bool, default True

    Returns
    -------
    list of Path
    """
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 2:
        raise SymmonError(f"runs must be an integer >= 2, got {plain_repr(runs)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SymmonError(f"seed must be a non-negative integer, got {plain_repr(seed)}")
    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    seeds = np.random.SeedSequence(seed).spawn(2)
    summary, steps, figures, events = [], [], [], []
    for sc, ss in zip(scenarios(), seeds):
        st = study(sc, runs, int(ss.generate_state(1)[0]), progress)
        figures.append(_plot(sc, st, runs, outdir / f"tracking_{sc.name}.png", fmt))
        events += st.get("events", [])
        for name, d in st["filters"].items():
            a, b, res = d["anees"], d["anis"], d["result"]
            choices = "" if res.choices is None else " ".join(
                f"{c}:{n}" for c, n in zip(*np.unique(res.choices, return_counts=True)))
            summary.append([sc.name, name, runs, sc.steps, float(np.mean(a.value)), float(np.max(a.value)),
                            float(np.mean(a.inside)), float(np.mean(b.value)), float(np.mean(b.inside)),
                            float(np.sqrt(np.mean(d["rmse"] ** 2))), _rms(d["rmse_smoothed"]), choices, ""])
        for name, err in st["failed"].items():
            summary.append([sc.name, name, runs, sc.steps] + [float("nan")] * 7 + ["", err])
        names = list(st["filters"])
        for k in range(sc.steps):
            row = [sc.name, k + 1]
            for name in names:
                d = st["filters"][name]
                sm_k = None if d["rmse_smoothed"] is None else float(d["rmse_smoothed"][k])
                row += [float(d["anees"].value[k]), float(d["anis"].value[k]), float(d["rmse"][k]), sm_k]
            if "mon" in st:
                row += [float(np.median(st["mon"][:, k])), float(np.median(st["mon_clean"][:, k]))]
            if "adaptive" in st["filters"]:
                row.append(float(np.mean(st["filters"]["adaptive"]["result"].choices[:, k] != "EKF")))
            steps.append((names, row))
    header = ["scenario", "filter", "runs", "steps", "anees_mean", "anees_max", "anees_share_inside",
              "anis_mean", "anis_share_inside", "position_rmse", "position_rmse_smoothed", "adaptive_choices", "error"]
    files = [write_csv(outdir / "tracking_summary.csv", header, summary)]
    # One step table: the columns of the filters of the first scenario (both run the same).
    names = steps[0][0] if steps else []
    step_header = ["scenario", "k"] + [f"{n}_{s}" for n in names for s in ("anees", "anis", "rmse", "rmse_smoothed")]
    step_header += ["mon_median", "mon_clean_median", "adaptive_share_not_ekf"]
    files.append(write_csv(outdir / "tracking_steps.csv", step_header, [r for _, r in steps]))
    files.append(write_csv(outdir / "tracking_events.csv",
                           ["scenario", "run", "k", "ekf_nees", "mon_k_minus_2", "mon_k_minus_1", "mon_k",
                            "mon_k_quantile", "adaptive_choice", "adaptive_nees", "true_range"], events))
    return figures + files
