"""Choosing the filter, and being right: :func:`symmon.advise_filter` on six scenarios of the literature.

For each scenario the advice is asked once, as a user would (:func:`symmon.advise_filter`,
a pilot of ``pilot`` simulated runs, seed ``seed``); then the advised filter and every
candidate of the advice's menu, pruned or not, run on ``runs`` **fresh** runs, simulated
with another seed (:func:`symmon.filters.selection.confirm_advice`), and the table says
whether the advice is credible there (time-mean ANEES in [0.3 n, 1.5 n], no covariance
collapsed; the pilot's predictive credibility, the bootstrap probability that a fresh bank
would be credible, :func:`symmon.filters.selection.predictive_credibility`, is in the CSV), how its RMSE compares with the best credible candidate's (within 10 %?), in how
many batches of 20 fresh runs both hold, and what it cost (model evaluations per step, and
the measured time per step and run, compilation excluded; the pilot's own wall time).

The scenarios (:data:`SCENARIOS`; each one's truth drawn from its Gaussian prior by
:func:`symmon.simulate`, as the pilot draws it):

``range_bearing``
    A constant-velocity target passing 1 km from a range–bearing sensor (T = 1 s, 40 steps,
    range noise 2 m, bearing 0.02 rad): near-linear, the textbook case of the EKF (Bar-Shalom,
    Li & Kirubarajan 2001, §5.5 and ch. 10); every Gaussian filter is credible and as
    accurate, so the cheapest, the EKF, must be chosen.
``ungm``
    The univariate nonstationary growth model, x_k = x/2 + 25 x/(1 + x²) + 8 cos(1.2 k) + w,
    y = x²/20 + e, Q = 10, R = 1, x_0 ~ N(0, 5), 50 steps (Kitagawa 1996; Gordon, Salmond &
    Smith 1993; Arulampalam et al. 2002); k enters f as a per-step parameter.
``bearings_only``
    Bearings-only tracking after Arulampalam & Ristic (2000): the scenario of
    ``symmon reproduce bot`` (:func:`symmon.reproduce.bot.scenario`), from its Gaussian prior.
``range_only``
    Range-only localisation of a slowly moving target (random walk, q = 100 m² per step) from
    a sensor that crosses 2 km along the x axis in 20 steps (range noise 100 m), the prior
    N([0, 150] m, diag(200², 300²) m²) straddling the sensor's line: the likelihood is mirror
    symmetric about the line, so the posterior is bimodal (range-only tracking: Ristic,
    Arulampalam & Gordon 2004, ch. 7; the geometry is ours).
``falling_body``
    The vertically falling body of Athans, Wishner & Bertolini (1968), used here in place of
    the 5-state re-entry of Julier & Uhlmann (2004, §V-C) as its 3-state analogue: altitude,
    downward speed and an unknown ballistic coefficient, ẋ₁ = −x₂, ẋ₂ = −e^{−γ x₁} x₂² x₃,
    ẋ₃ = 0, γ = 5·10⁻⁵ ft⁻¹, integrated by two Euler steps per second; a radar 10⁵ ft away
    at 10⁵ ft altitude measures the range (noise 100 ft), 60 s; x_0 ~ N([3·10⁵ ft,
    2·10⁴ ft/s, 10⁻³], diag(10⁶, 4·10⁶, 4·10⁻⁸)) (the original's truth and P0 for position
    and speed; a ballistic-coefficient spread that keeps the truth positive) with a small
    process noise.
``coordinated_turn``
    A target turning at an unknown, slowly varying rate (the coordinated-turn model with the
    turn rate a state, Bar-Shalom, Li & Kirubarajan 2001, §11.7; polar velocity, T = 1 s,
    60 steps) from a range–bearing radar 5 km away, with an IMM of two modes (``modes=``:
    the quiescent model and a manoeuvring one of larger speed and turn-rate noise; ibid. §11.6).

Files written to ``outdir``: ``select.csv`` (one row per scenario and candidate,
:data:`COLUMNS`) and ``select.png`` (per scenario: each candidate's RMSE over the best
credible one, its ANEES over n against the credible band, and its time per step; the advice
ringed).

References
----------
M. Athans, R. P. Wishner, A. Bertolini, "Suboptimal state estimation for continuous-time
nonlinear systems from discrete noisy measurements", IEEE Trans. Automatic Control 13(5),
1968. doi:10.1109/TAC.1968.1098980
S. J. Julier, J. K. Uhlmann, "Unscented filtering and nonlinear estimation", Proc. IEEE 92(3),
2004. doi:10.1109/JPROC.2003.823141
G. Kitagawa, "Monte Carlo filter and smoother for non-Gaussian nonlinear state space models",
J. Comput. Graph. Stat. 5(1), 1996.
N. J. Gordon, D. J. Salmond, A. F. M. Smith, "Novel approach to nonlinear/non-Gaussian Bayesian
state estimation", IEE Proc. F 140(2), 1993.
M. S. Arulampalam, S. Maskell, N. Gordon, T. Clapp, "A tutorial on particle filters for online
nonlinear/non-Gaussian Bayesian tracking", IEEE Trans. Signal Process. 50(2), 2002.
M. S. Arulampalam, B. Ristic, "Comparison of the particle filter with range-parameterised and
modified polar EKFs for angle-only tracking", Proc. SPIE 4048, 2000.
B. Ristic, S. Arulampalam, N. Gordon, *Beyond the Kalman Filter: Particle Filters for Tracking
Applications*, Artech House, 2004.
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley, 2001.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import sympy as sp

from ..core.gaussian import Gaussian
from ..core.model import Model
from ..errors import ArgumentError, plain_repr
from ..filters.selection import ANEES_BAND, RMSE_MARGIN, Confirmation, FilterAdvice, advise_filter, confirm_advice
from ..io import check_output_set, write_csv
from . import bot
from .common import figure_style, filter_style, label_panels, plain_log_ticks, progress_bar, save_reproduced, with_format

__all__ = ["OUTPUTS", "SCENARIOS", "LABELS", "COLUMNS", "RUNS", "PILOT_RUNS", "FRESH_SEED", "Scenario", "scenario",
           "study", "rows", "run"]

#: The files :func:`run` writes into its directory.
OUTPUTS = ("select.png", "select.csv")
#: The scenarios, in the order of the table and the figure.
SCENARIOS = ("range_bearing", "ungm", "bearings_only", "range_only", "falling_body", "coordinated_turn")
#: Their names in the figure.
LABELS = {"range_bearing": "near-linear range–bearing", "ungm": "growth model (UNGM)",
          "bearings_only": "bearings-only", "range_only": "range-only (bimodal)",
          "falling_body": "falling body", "coordinated_turn": "coordinated turn (IMM)"}
#: Default fresh runs per scenario and the pilot's runs.
RUNS, PILOT_RUNS = 200, 64
#: The fresh runs' seed is the pilot's plus this.
FRESH_SEED = 1000
#: The columns of ``select.csv``.
COLUMNS = ("scenario", "candidate", "method", "advised", "pilot_kept", "pilot_rmse", "pilot_anees", "pilot_credible",
           "pilot_credibility", "pilot_lost_rate", "pilot_runs", "pilot_seconds", "runs", "rmse", "rmse_ratio", "anees", "anees_lower", "anees_upper", "anees_band_lower",
           "anees_band_upper", "credible", "failure", "reference_credible", "within_margin", "batches", "batch_share", "cost_evals_per_step",
           "seconds_per_step", "advice_credible", "advice_confirmed")


@dataclass(frozen=True)
class Scenario:
    """One scenario: the arguments of :func:`symmon.advise_filter` (module notes)."""

    name: str
    f: Model
    h: Model
    Q: np.ndarray
    R: np.ndarray
    x0: Gaussian
    steps: int
    params: dict | None = None
    modes: tuple | None = None


def _range_bearing(steps: int | None) -> Scenario:
    px, py, vx, vy = sp.symbols("px py vx vy", real=True)
    f = Model([px, py, vx, vy], [px + vx, py + vy, vx, vy], name="select_rb_f")
    h = Model([px, py, vx, vy], [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="select_rb_h")
    Q = 0.01 * np.kron([[1 / 3, 1 / 2], [1 / 2, 1.0]], np.eye(2))
    x0 = Gaussian([-200.0, 1000.0, 0.0, -5.0], np.diag([25.0, 25.0, 0.25, 0.25]))
    return Scenario("range_bearing", f, h, Q, np.diag([4.0, 0.02**2]), x0, steps or 40)


def _ungm(steps: int | None) -> Scenario:
    x, k = sp.symbols("x k", real=True)
    f = Model([x], [x / 2 + 25 * x / (1 + x**2) + 8 * sp.cos(sp.Rational(6, 5) * k)], params=[k], name="select_ungm_f")
    h = Model([x], [x**2 / 20], name="select_ungm_h")
    K = steps or 50
    return Scenario("ungm", f, h, np.array([[10.0]]), np.array([[1.0]]), Gaussian([0.0], [[5.0]]), K,
                    {"k": np.arange(1, K + 1, dtype=float)})


def _bearings_only(steps: int | None) -> Scenario:
    sc = bot.scenario(steps or 40)
    return Scenario("bearings_only", sc.f, sc.h, sc.Q, sc.R, sc.x0, sc.steps, {"dvx": sc.dv[:, 0], "dvy": sc.dv[:, 1]})


def _range_only(steps: int | None) -> Scenario:
    px, py, sx, sy = sp.symbols("px py sx sy", real=True)
    f = Model([px, py], [px, py], name="select_ro_f")
    h = Model([px, py], [sp.sqrt((px - sx) ** 2 + (py - sy) ** 2)], params=[sx, sy], name="select_ro_h")
    K = steps or 20
    sensor = -1000.0 + 2000.0 / K * np.arange(1, K + 1)
    return Scenario("range_only", f, h, 100.0 * np.eye(2), np.array([[100.0**2]]),
                    Gaussian([0.0, 150.0], np.diag([200.0**2, 300.0**2])), K, {"sx": sensor, "sy": np.zeros(K)})


def _falling_body(steps: int | None) -> Scenario:
    x1, x2, x3 = sp.symbols("x1 x2 x3", real=True)
    gamma, substeps = sp.Rational(5, 100000), 2
    s = [x1, x2, x3]
    dt = sp.Rational(1, substeps)
    for _ in range(substeps):
        a, b, c = s
        s = [a - dt * b, b - dt * sp.exp(-gamma * a) * b**2 * c, c]
    f = Model([x1, x2, x3], s, name="select_fall_f")
    h = Model([x1, x2, x3], [sp.sqrt(10**10 + (x1 - 10**5) ** 2)], name="select_fall_h")
    x0 = Gaussian([3e5, 2e4, 1e-3], np.diag([1e6, 4e6, (2e-4) ** 2]))
    return Scenario("falling_body", f, h, np.diag([1e-2, 1e-2, 1e-12]), np.array([[1e4]]), x0, steps or 60)


def _coordinated_turn(steps: int | None) -> Scenario:
    px, py, s, th, w = sp.symbols("px py s th w", real=True)
    f = Model([px, py, s, th, w], [px + s * sp.cos(th + w / 2), py + s * sp.sin(th + w / 2), s, th + w, w],
              angles=[3], name="select_ct_f")
    h = Model([px, py, s, th, w], [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name="select_ct_h")
    quiet = np.diag([0.1, 0.1, 0.1, 1e-6, 1e-6])
    manoeuvre = np.diag([0.1, 0.1, 1.0, 1e-4, 1e-3])
    x0 = Gaussian([5000.0, 0.0, 100.0, math.pi / 2, 0.0], np.diag([100.0, 100.0, 25.0, 0.01, 0.03**2]))
    return Scenario("coordinated_turn", f, h, quiet, np.diag([100.0, 2e-3**2]), x0, steps or 60,
                    modes=((f, manoeuvre),))


_BUILDERS: dict[str, Callable[[int | None], Scenario]] = {
    "range_bearing": _range_bearing, "ungm": _ungm, "bearings_only": _bearings_only, "range_only": _range_only,
    "falling_body": _falling_body, "coordinated_turn": _coordinated_turn}


def scenario(name: str, steps: int | None = None) -> Scenario:
    """The scenario ``name`` of :data:`SCENARIOS` (module notes), with ``steps`` steps (default: its own)."""
    if name not in _BUILDERS:
        raise ArgumentError(f"name must be one of {', '.join(SCENARIOS)}, got {plain_repr(name)}")
    return _BUILDERS[name](steps)


def study(runs: int = RUNS, pilot: int = PILOT_RUNS, seed: int = 0, steps: int | None = None,
          names: tuple[str, ...] = SCENARIOS, progress: bool = True) -> dict[str, Any]:
    """The advice and its confirmation on fresh runs for each scenario (module notes).

    Returns a dict with ``runs``, ``pilot``, ``seed`` and per scenario name in
    ``scenarios[name]``: the ``scenario``, the ``advice`` (a FilterAdvice), the
    ``pilot_seconds`` (its wall time) and the ``confirmation`` (a Confirmation).
    """
    out: dict[str, Any] = {"runs": runs, "pilot": pilot, "seed": seed, "scenarios": {}}
    for name in progress_bar(names, "select", progress):
        sc = scenario(name, steps)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the advice's notes keep them
            advice = advise_filter(sc.f, sc.h, sc.Q, sc.R, sc.x0, sc.steps, sc.params, modes=sc.modes, runs=pilot,
                                   seed=seed)
        seconds = time.perf_counter() - t0
        conf = confirm_advice(advice, sc.f, sc.h, sc.Q, sc.R, sc.x0, sc.params, modes=sc.modes, runs=runs,
                              seed=seed + FRESH_SEED)
        out["scenarios"][name] = {"scenario": sc, "advice": advice, "pilot_seconds": seconds, "confirmation": conf}
    return out


def rows(st: dict[str, Any]) -> list[list]:
    """The rows of ``select.csv`` (:data:`COLUMNS`)."""
    out = []
    for name, d in st["scenarios"].items():
        a: FilterAdvice = d["advice"]
        c: Confirmation = d["confirmation"]
        best = c.best
        pilot = {r.name: r for r in a.candidates}
        lo, hi = ANEES_BAND[0] * a.n, ANEES_BAND[1] * a.n
        for r in c.rows:
            p = pilot.get(r.name)
            ran = p is not None and p.kept and p.rmse is not None
            ratio = None if best is None or r.rmse is None else float(r.rmse / best.rmse)
            interval = r.anees_interval or (None, None)
            out.append([name, r.name, r.method, int(r.name == c.choice), int(ran),
                        p.rmse if ran else None, p.anees if ran else None,
                        None if not ran else int(bool(p.credible)), p.credibility if ran else None,
                        p.lost_rate if ran else None, p.runs if ran else None,
                        d["pilot_seconds"], c.runs, r.rmse, ratio,
                        r.anees, interval[0], interval[1], lo, hi, int(bool(r.credible)), r.failure,
                        int(c.any_credible),
                        None if ratio is None else int(ratio <= 1 + RMSE_MARGIN), len(c.batches[r.name]),
                        c.share(r.name), r.cost, r.seconds_per_step, int(bool(c.advised.credible)), int(c.confirmed)])
    return out


def caption(st: dict[str, Any]) -> str:
    """The figure's caption (PNG metadata and docs)."""
    return (f"The filter advised by symmon.advise_filter (pilot of {st['pilot']} runs, seed {st['seed']}) against every "
            f"candidate on {st['runs']} fresh runs (seed {st['seed'] + FRESH_SEED}), per scenario. (a) RMSE over the "
            "best credible candidate's (*: none is credible on the fresh runs; over the most accurate one's); dashed: "
            "1.1, the 10 % margin; (b) time-mean ANEES over the state dimension n, with the credible band [0.3, 1.5] "
            f"(grey); values above {ANEES_AXIS_TOP:g} drawn at the axis' end as triangles; (c) measured time per step "
            "and run, compilation excluded. Ringed: the advice; open and faded markers: not credible on the fresh runs.")


#: The right end of the figure's ANEES axis (over n); larger values are drawn at it, as a triangle.
ANEES_AXIS_TOP = 1e3
#: The left end of the figure's ANEES axis (over n).
ANEES_AXIS_BOTTOM = 0.1


def _plot(st: dict[str, Any], path: Path, fmt: str = "png") -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    names = list(st["scenarios"])
    fig = Figure(figsize=(7.2, 1.3 + 0.6 * len(names)), layout="constrained")
    FigureCanvasAgg(fig)
    ax_r, ax_a, ax_t = fig.subplots(1, 3, sharey=True)
    seen: dict[str, Line2D] = {}
    for j, name in enumerate(names):
        c: Confirmation = st["scenarios"][name]["confirmation"]
        best, n = c.best, st["scenarios"][name]["advice"].n
        y0, m = len(names) - 1 - j, len(c.rows)
        for i, r in enumerate(c.rows):
            if r.rmse is None or best is None:
                continue
            y = y0 + 0.6 * (i - (m - 1) / 2) / max(m - 1, 1)
            look = filter_style(r.name.split(" ")[0], 1)
            kw = dict(color=look["color"], marker=look["marker"], ms=5, ls="none", zorder=4,
                      mfc=look["color"] if r.credible else "none", alpha=1.0 if r.credible else 0.45)
            anees = r.anees / n
            for ax, x, off in ((ax_r, r.rmse / best.rmse, False), (ax_a, min(max(anees, ANEES_AXIS_BOTTOM), ANEES_AXIS_TOP), anees > ANEES_AXIS_TOP),
                               (ax_t, 1e6 * r.seconds_per_step, False)):
                ax.plot([x], [y], **({**kw, "marker": ">"} if off else kw), clip_on=False)
                if r.name == c.choice:
                    ax.plot([x], [y], marker="o", ms=11, mfc="none", mec="0.15", mew=1.0, ls="none", zorder=5,
                            clip_on=False)
            key = r.name.split(" ")[0]
            if key not in seen:
                seen[key] = Line2D([], [], color=kw["color"], marker=look["marker"], ls="none", ms=5,
                                   label=_LEGEND.get(key, key.upper()))
    seen["advice"] = Line2D([], [], marker="o", ms=10, mfc="none", mec="0.15", ls="none", label="the advice")
    seen["open"] = Line2D([], [], marker="s", ms=5, mfc="none", mec="0.4", alpha=0.45, ls="none",
                          label="open, faded: not credible")
    ax_r.axvline(1 + RMSE_MARGIN, color="0.3", lw=0.8, ls=(0, (4, 2)))
    ax_r.axvline(1.0, color="0.6", lw=0.6)
    ax_a.axvspan(*ANEES_BAND, color="0.85", zorder=0, lw=0)
    for ax in (ax_r, ax_a, ax_t):
        ax.set_xscale("log")
    ax_a.set_xlim(ANEES_AXIS_BOTTOM, ANEES_AXIS_TOP)
    for ax in (ax_r, ax_a, ax_t):
        plain_log_ticks(ax, "x")
        ax.grid(axis="y", visible=False)
        for j in range(len(names) - 1):
            ax.axhline(j + 0.5, color="0.85", lw=0.6)
    none = {n for n in names if not st["scenarios"][n]["confirmation"].any_credible}
    ax_r.set_yticks(range(len(names)), [LABELS[n] + (" *" if n in none else "") for n in reversed(names)])
    ax_r.set_ylim(-0.6, len(names) - 0.4)
    ax_r.set_xlabel("RMSE / best credible RMSE")
    ax_a.set_xlabel("time-mean ANEES / n")
    ax_t.set_xlabel("time per step and run [µs]")
    fig.legend(handles=list(seen.values()), loc="outside lower center", ncol=6, frameon=False)
    label_panels((ax_r, ax_a, ax_t))
    return save_reproduced(fig, path, fmt, "Choosing the filter", caption(st))


#: The legend's names of the candidates, where not their upper-case names.
_LEGEND = {"ghkf": "GHKF", "gsf": "GSF (MoN split)", "pf": "PF"}


def _count(value: Any, name: str, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise ArgumentError(f"{name} must be an integer >= {least}, got {plain_repr(value)}")
    return int(value)


@figure_style()
def run(outdir: Path, runs: int = RUNS, seed: int = 0, pilot: int = PILOT_RUNS, steps: int | None = None,
        progress: bool = True, fmt: str = "png") -> list[Path]:
    """Run the study and write ``select.png`` and ``select.csv`` (module notes).

    Parameters
    ----------
    outdir : Path
        Output directory (created if missing).
    runs : int, default :data:`RUNS`
        Fresh runs per scenario (at least 2).
    seed : int, default 0
        The pilot's seed; the fresh runs' is ``seed`` + :data:`FRESH_SEED`.
    pilot : int, default :data:`PILOT_RUNS`
        The pilot's runs (at least 2).
    steps : int, optional
        Steps of every scenario (default: each one's own; at least 2): a reduced setting.
    progress : bool, default True
    fmt : {"png", "pdf", "svg"}, default "png"

    Returns
    -------
    list of Path
    """
    runs = _count(runs, "runs", 2)
    pilot = _count(pilot, "pilot", 2)
    seed = _count(seed, "seed", 0)
    if steps is not None:
        steps = _count(steps, "steps", 2)
    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    st = study(runs, pilot, seed, steps, progress=progress)
    return [_plot(st, outdir / "select.png", fmt), write_csv(outdir / "select.csv", COLUMNS, rows(st))]
