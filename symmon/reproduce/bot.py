"""Bearings-only tracking after Arulampalam & Ristic (2000): Gaussian, Gaussian-sum and particle filters.

A constant-velocity target is tracked by its bearings alone from an observer that turns
once, in the setting of Arulampalam & Ristic (2000) and Ristic, Arulampalam & Gordon (2004,
ch. 6) (the MoN paper's reference [24]): T = 1 min, 40 scans, bearing noise 1.5°, an
observer at 5 kn on course 140° that turns to course 20° between scans 13 and 17, a target
at 5 km and bearing 0° moving at 4 kn on course −140°, white-noise acceleration of
q = 1.6·10⁻⁶ km²/min³.  The state is relative (target minus observer, east and north,
metres and m/s), x = [rx, ry, vx, vy]; the observer's known change of velocity before the
prediction to scan k enters f as the parameters ``dvx``, ``dvy`` (zero outside the turn):

    x_k = F (x_{k−1} − [0, 0, dvx_k, dvy_k]) + w_k,   y_k = atan2(rx_k, ry_k) + e_k

(the bearing clockwise from north).  The prior of x_0 is the Gaussian of the reference's
polar prior — range 5 km ± 2 km, bearing ± 1.5°, speed 4 kn ± 2 kn, course ± π/√12 — moment
matched by the unscented transform (:func:`prior`); the truth of every run is drawn from it
by :func:`symmon.simulate`.

The filters, each on the same runs:

* ``ekf`` and ``ukf``: :class:`symmon.NonlinearKalmanFilter` with ``TT1()`` and ``UT.ut1()``;
* ``rp_gsf``: the range-parameterised EKF bank of the reference as a
  :class:`symmon.GaussianSumFilter` of EKF components without splitting, from the mixture
  :func:`range_parameterised_prior` (:data:`RP_COMPONENTS` components spread geometrically in
  range along the prior's bearing, each with a constant coefficient of variation, weighted by
  the prior's range density; Peach 1995);
* ``mon_gsf``: a :class:`symmon.GaussianSumFilter` of EKF components from the single
  Gaussian prior, a component split whenever its unitless MoN (W^full) exceeds
  :data:`SPLIT` (at most :data:`MAX_COMPONENTS` components);
* ``pf``: the bootstrap :class:`symmon.ParticleFilter` (systematic resampling at ESS ≤ N/2);
* ``rpf``: the same with ``regularise=True``, the post-regularised particle filter of Musso,
  Oudjane & Le Gland (2001): after each resampling a Gaussian-kernel jitter h_opt · L ε
  (L the Cholesky factor of the weighted particle covariance), which keeps the particles
  distinct under this small process noise.

Statistics against the scan k: the position RMSE over the runs, the ANEES (n = 4) with its
two-sided 95 % χ² interval [χ²_{4R}(0.025), χ²_{4R}(0.975)]/R (Bar-Shalom, Li & Kirubarajan
2001, §5.4.2), and the unitless MoN of the measurement y = h(x) + e (Straka & Havlík 2024,
eqs. (25), (29), (43), TT2) at each filter's prior of scan k: at N(x̂_{k|k−1}, P_{k|k−1}) for
the EKF, the UKF and the particle filter (its particles' weighted mean and covariance), and
for the Gaussian sums the weight-averaged MoN of their components predicted to scan k (the
MoN each component's EKF update meets).  :func:`mon_tt2` computes it in one batch from h's
compiled gradient and Hessian.

Files written to ``outdir``: ``bot.png`` (the geometry, the RMSE, the ANEES and the MoN) and
``bot_steps.csv`` (one row per scan and filter).

References
----------
M. S. Arulampalam, B. Ristic, "Comparison of the particle filter with range-parameterised and
modified polar EKFs for angle-only tracking", Proc. SPIE 4048, 2000. doi:10.1117/12.391979
B. Ristic, S. Arulampalam, N. Gordon, *Beyond the Kalman Filter: Particle Filters for
Tracking Applications*, Artech House, 2004, ch. 6.
C. Musso, N. Oudjane, F. Le Gland, "Improving regularised particle filters", in A. Doucet,
N. de Freitas, N. Gordon (eds.), *Sequential Monte Carlo Methods in Practice*, Springer,
2001, ch. 12.
N. Peach, "Bearings-only tracking using a set of range-parameterised extended Kalman
filters", IEE Proc. Control Theory Appl. 142(1), 1995.
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp
from scipy import stats

from ..compile.compiled import compiled
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical, GaussianMixture
from ..core.model import Model
from ..errors import ArgumentError, DegeneracyWarning, plain_repr
from ..filters.mixture.gaussian_sum import GaussianSumFilter
from ..filters.gaussian.nonlinear import NonlinearKalmanFilter
from ..filters.particle.particle_filter import ParticleFilter
from ..filters.simulation import simulate
from ..io import check_output_set, write_csv
from ..transforms.taylor import TT1
from ..transforms.unscented import UT
from .common import (figure_style, filter_style, label_panels, plain_log_ticks, progress_bar,
                     save_reproduced, with_format)

__all__ = ["OUTPUTS", "FILTER_NAMES", "LABELS", "Scenario", "scenario", "prior", "range_parameterised_prior",
           "mon_tt2", "chi2_band", "study", "run", "RUNS", "PARTICLES", "SPLIT", "MAX_COMPONENTS",
           "RP_COMPONENTS", "CONFIDENCE", "STEP_COLUMNS"]

#: The files :func:`run` writes into its directory.
OUTPUTS = ("bot.png", "bot_steps.csv")
#: The filters, in the order of the tables and the legend.
FILTER_NAMES = ("ekf", "ukf", "rp_gsf", "mon_gsf", "pf", "rpf")
#: Their names in the figure.
LABELS = {"ekf": "EKF", "ukf": "UKF", "rp_gsf": "range-parameterised GSF", "mon_gsf": "MoN-split GSF",
          "pf": "bootstrap PF", "rpf": "regularised PF"}
#: Default Monte Carlo runs and particles per run.
RUNS, PARTICLES = 200, 2000
#: The MoN-split GSF splits a component whose MoN (W^full) exceeds this; at most this many components.
SPLIT, MAX_COMPONENTS = 0.1, 16
#: Components of the range-parameterised prior.
RP_COMPONENTS = 6
#: The top of the figure's ANEES axis.
ANEES_AXIS_TOP = 1e3
#: Confidence of the χ² intervals.
CONFIDENCE = 0.95
#: The columns of ``bot_steps.csv``.
STEP_COLUMNS = ("filter", "k", "runs", "position_rmse", "anees", "anees_lower", "anees_upper", "anees_inside",
                "mon_median", "mon_q10", "mon_q90", "components_mean", "ess_mean", "collapsed_runs")
#: A run's particle weights have collapsed at a scan whose ESS is below this.
COLLAPSED_ESS = 1.5

KNOT = 1852.0 / 3600.0  # m/s
#: Draws of the polar prior (:func:`prior`) and its least range [m].
PRIOR_SAMPLES, R_MIN = 100_000, 1000.0


@dataclass(frozen=True)
class Scenario:
    """The models, noises, prior and the observer's manoeuvre (module notes)."""

    f: Model
    h: Model
    Q: np.ndarray
    R: np.ndarray
    F: np.ndarray
    x0: Gaussian  # the Gaussian filters' prior: the moments of ``truth``
    truth: Empirical  # the distribution of x_0 drawn by every run, the particle filter's prior
    steps: int
    T: float
    dv: np.ndarray  # (K, 2): the observer's change of velocity before the prediction to scan k
    observer: np.ndarray  # (K + 1, 2): its positions at scans 0 … K


def _course(speed: float, deg: float) -> np.ndarray:
    """East and north velocity of a course (degrees clockwise from north)."""
    a = math.radians(deg)
    return speed * np.array([math.sin(a), math.cos(a)])


def prior(v_observer: np.ndarray, samples: int = PRIOR_SAMPLES, seed: int = 0, r: float = 5000.0,
          bearing: float = 0.0, speed: float = 4 * KNOT, course: float = -140.0, sd_r: float = 2000.0,
          sd_bearing: float = math.radians(1.5), sd_speed: float = 2 * KNOT,
          sd_course: float = math.pi / math.sqrt(12), r_min: float = R_MIN) -> tuple[Empirical, Gaussian]:
    """The reference's polar prior in relative Cartesian coordinates: a sample and its Gaussian.

    Range N(r, sd_r²) truncated to r ≥ ``r_min`` (no target behind or on the observer),
    bearing (from north), target speed and course independent Gaussians, mapped to
    [r sin b, r cos b, s sin c − vox, s cos c − voy].  Returns ``samples`` equally weighted
    draws (the truth's distribution and the particle filter's prior) and the Gaussian of
    their sample mean and covariance (the Gaussian filters' prior)."""
    rng = np.random.default_rng(seed)
    rr = stats.truncnorm.rvs((r_min - r) / sd_r, np.inf, loc=r, scale=sd_r, size=samples, random_state=rng)
    b = bearing + sd_bearing * rng.standard_normal(samples)
    s = speed + sd_speed * rng.standard_normal(samples)
    c = math.radians(course) + sd_course * rng.standard_normal(samples)
    vo = np.asarray(v_observer, dtype=float)
    X = np.column_stack([rr * np.sin(b), rr * np.cos(b), s * np.sin(c) - vo[0], s * np.cos(c) - vo[1]])
    return Empirical(X), Gaussian(X.mean(axis=0), np.cov(X.T))


def scenario(steps: int = 40) -> Scenario:
    """The scenario of the module notes (``steps`` scans; the turn at scans 13–17)."""
    T, K = 60.0, int(steps)
    q = 1.6e-6 * 1e6 / 60.0**3  # 1.6e-6 km²/min³ in m²/s³
    F = np.eye(4)
    F[0, 2] = F[1, 3] = T
    Q = q * np.kron(np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]]), np.eye(2))
    X = sp.symbols("rx ry vx vy", real=True)
    dvx, dvy = sp.symbols("dvx dvy", real=True)
    xs = sp.Matrix(X) - sp.Matrix([0, 0, dvx, dvy])
    f = Model(list(X), list(sp.Matrix(F) * xs), params=[dvx, dvy], name="bot_f")
    h = Model(list(X), [sp.atan2(X[0], X[1])], name="bot_h", angles=[0])
    # The observer: 5 kn, course 140° up to scan 13, 20° from scan 17, turning evenly between.
    courses = np.interp(np.arange(K + 1), [0, 13, 17, K], [140.0, 140.0, 20.0, 20.0])
    v_obs = np.array([_course(5 * KNOT, c) for c in courses])
    dv = np.diff(v_obs, axis=0)  # before the prediction to scan k = 1 … K: v_obs[k] − v_obs[k − 1]
    observer = np.vstack([np.zeros(2), np.cumsum(T * v_obs[1:], axis=0)])
    truth, x0 = prior(v_obs[0])
    return Scenario(f, h, Q, np.array([[math.radians(1.5) ** 2]]), F, x0, truth, K, T, dv, observer)


def range_parameterised_prior(x0: Gaussian, components: int = RP_COMPONENTS, r_min: float = 1000.0,
                              r_max: float = 11000.0) -> GaussianMixture:
    """A range-parameterised mixture (Peach 1995) of the Gaussian prior ``x0``.

    Ranges r_j geometric in [r_min, r_max] along the bearing of x0's mean, ratio
    ρ = (r_max/r_min)^{1/(N−1)}; component j has the range standard deviation of a uniform
    over [r_j/√ρ, r_j √ρ], σ_j = r_j (√ρ − 1/√ρ)/√12 (a constant coefficient of variation),
    the cross-range standard deviation r_j σ_θ (σ_θ: x0's bearing spread at its mean range),
    x0's velocity block, and the weight ∝ x0's range density at r_j times the interval's width.
    """
    n = int(components)
    if n < 2:
        raise ArgumentError(f"components must be an integer >= 2, got {plain_repr(components)}")
    m, P = np.asarray(x0.mean, dtype=float), np.asarray(x0.cov, dtype=float)
    r0 = float(np.hypot(*m[:2]))
    u = m[:2] / r0  # the line of sight
    t = np.array([u[1], -u[0]])  # across it
    sd_r = math.sqrt(u @ P[:2, :2] @ u)
    sd_theta = math.sqrt(t @ P[:2, :2] @ t) / r0
    rho = (r_max / r_min) ** (1.0 / (n - 1))
    r = r_min * rho ** np.arange(n)
    width = r * (math.sqrt(rho) - 1 / math.sqrt(rho))
    w = stats.norm.pdf(r, r0, sd_r) * width
    means, covs = np.empty((n, 4)), np.empty((n, 4, 4))
    B = np.column_stack([u, t])
    for j in range(n):
        means[j] = np.r_[r[j] * u, m[2:]]
        covs[j] = P.copy()
        covs[j][:2, :2] = B @ np.diag([(width[j] / math.sqrt(12)) ** 2, (r[j] * sd_theta) ** 2]) @ B.T
        covs[j][:2, 2:] = covs[j][2:, :2] = 0.0  # position and velocity independent, as in the polar prior
    return GaussianMixture(w / w.sum(), means, covs)


def mon_tt2(h: Model, R: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The unitless MoN (W^full, TT2) of y = h(x) + e, e ~ N(0, R), at N(mean_i, cov_i), batched.

    With h's gradient J and Hessians H_l at the mean (compiled C), TT2 gives
    Cov(h, x) = J P and Cov h = J P Jᵀ + ½ [tr(H_l P H_m P)]; then M² = tr(W (Σ_gg − Σ_c −
    Σ_gu Σ_uu⁻¹ Σ_ug)) with Σ_gg = Cov h + R, Σ_c = R, W = Σ_gg⁻¹/n_y (Straka & Havlík 2024,
    eqs. (25), (29), (43)), so M² = tr(W · ½ [tr(H_l P H_m P)]).

    Parameters
    ----------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)

    Returns
    -------
    ndarray, shape (...)
    """
    mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
    shape, n = mean.shape[:-1], mean.shape[-1]
    x, P = mean.reshape(-1, n), cov.reshape(-1, n, n)
    _, J, H = compiled(h).eval_gjh(x)
    J, H = J[:, :, :n], H[:, :, :n, :n]
    HP = np.einsum("Nlab,Nbc->Nlac", H, P)
    second = 0.5 * np.einsum("Nlab,Nmba->Nlm", HP, HP)
    S = np.einsum("Nla,Nab,Nmb->Nlm", J, P, J) + second + R
    W = np.linalg.inv(S) / h.n_y
    M2 = np.einsum("Nlm,Nml->N", W, second)
    return np.sqrt(np.clip(M2, 0.0, None)).reshape(shape)


def chi2_band(runs: int, dim: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The two-sided χ² interval of an average of ``runs`` NEES of dimension ``dim``
    (Bar-Shalom et al. 2001, (5.4.2-9))."""
    a = 1.0 - confidence
    return (float(stats.chi2.ppf(a / 2, runs * dim) / runs), float(stats.chi2.ppf(1 - a / 2, runs * dim) / runs))


def _predicted_components(sc: Scenario, res, prior_mix: GaussianMixture | Gaussian) -> tuple:
    """The weights, means and covariances of each step's prior mixture: the previous
    posterior components (the prior at scan 1) through the linear f."""
    R, K = res.components.shape
    if isinstance(prior_mix, Gaussian):
        w0, m0, P0 = np.ones(1), np.asarray(prior_mix.mean)[None], np.asarray(prior_mix.cov)[None]
    else:
        w0, m0, P0 = np.asarray(prior_mix.weights), np.asarray(prior_mix.means), np.asarray(prior_mix.covs)
    M = max(res.weights.shape[-1], len(w0))
    w = np.zeros((R, K, M))
    m = np.zeros((R, K, M, 4))
    P = np.tile(np.eye(4), (R, K, M, 1, 1))
    w[:, 0, :len(w0)], m[:, 0, :len(w0)], P[:, 0, :len(w0)] = w0, m0, P0
    Mr = res.weights.shape[-1]
    w[:, 1:, :Mr], m[:, 1:, :Mr], P[:, 1:, :Mr] = res.weights[:, :-1], res.means[:, :-1], res.covs[:, :-1]
    shift = np.zeros((K, 4))
    shift[:, 2:] = sc.dv
    m = (m - shift[None, :, None, :]) @ sc.F.T
    P = sc.F @ P @ sc.F.T + sc.Q
    return w, m, P


def study(runs: int = RUNS, particles: int = PARTICLES, seed: int = 0, steps: int = 40,
          progress: bool = True) -> dict[str, Any]:
    """Simulate ``runs`` runs and filter them with every filter (module notes).

    Returns a dict with the scenario ``sc``, the truth ``xs``, and per filter in
    ``filters[name]``: ``rmse`` (K,), ``anees`` (a ConsistencyTest), ``mon`` (runs, K),
    ``components`` (runs, K) for the Gaussian sums, and ``result``.
    """
    sc = scenario(steps)
    params = {"dvx": sc.dv[:, 0], "dvy": sc.dv[:, 1]}
    s_sim, s_pf = np.random.SeedSequence(seed).spawn(2)
    xs, ys = simulate(sc.f, sc.h, sc.Q, sc.R, sc.truth, sc.steps, runs=runs, params=params,
                      seed=np.random.default_rng(s_sim))
    rp = range_parameterised_prior(sc.x0)
    makers = {
        "ekf": lambda: (NonlinearKalmanFilter(sc.f, sc.h, sc.Q, sc.R, TT1()), sc.x0),
        "ukf": lambda: (NonlinearKalmanFilter(sc.f, sc.h, sc.Q, sc.R, UT.ut1()), sc.x0),
        "rp_gsf": lambda: (GaussianSumFilter(sc.f, sc.h, sc.Q, sc.R, TT1(), max_components=RP_COMPONENTS), rp),
        "mon_gsf": lambda: (GaussianSumFilter(sc.f, sc.h, sc.Q, sc.R, TT1(), split=SPLIT,
                                              max_components=MAX_COMPONENTS), sc.x0),
        "pf": lambda: (ParticleFilter(sc.f, sc.h, sc.Q, sc.R, particles=particles,
                                      seed=int(s_pf.generate_state(1)[0] % 2**31)), sc.truth),
        "rpf": lambda: (ParticleFilter(sc.f, sc.h, sc.Q, sc.R, particles=particles, regularise=True,
                                       seed=int(s_pf.generate_state(1)[0] % 2**31)), sc.truth),
    }
    out: dict[str, Any] = {"sc": sc, "xs": xs, "ys": ys, "runs": runs, "particles": particles, "seed": seed,
                           "filters": {}}
    for name in progress_bar(FILTER_NAMES, "bot", progress):
        flt, x0 = makers[name]()
        with warnings.catch_warnings():
            # A collapse of the particle weights is reported per scan in the table (ESS,
            # collapsed runs), not as a warning.
            warnings.simplefilter("ignore", DegeneracyWarning)
            res = flt.filter(ys, x0, params=params)
        d: dict[str, Any] = {"result": res, "anees": res.anees(xs, CONFIDENCE),
                             "rmse": np.sqrt(np.mean(np.sum((xs[..., :2] - res.x[..., :2]) ** 2, axis=-1), axis=0))}
        if name in ("rp_gsf", "mon_gsf"):
            w, m, P = _predicted_components(sc, res, x0)
            used = w > 0  # the empty slots of a run with fewer components than the most
            mon = np.zeros(w.shape)
            mon[used] = mon_tt2(sc.h, sc.R, m[used], P[used])
            d["mon"] = np.sum(w * mon, axis=-1)
            d["components"] = res.components
        else:
            d["mon"] = mon_tt2(sc.h, sc.R, res.x_pred, res.P_pred)
        if name in ("pf", "rpf"):
            d["ess"] = res.ess
        out["filters"][name] = d
    return out


def step_rows(st: dict[str, Any]) -> list[list]:
    """The rows of ``bot_steps.csv`` (:data:`STEP_COLUMNS`)."""
    rows = []
    for name, d in st["filters"].items():
        a = d["anees"]
        lo, hi = np.broadcast_to(a.lower, a.value.shape), np.broadcast_to(a.upper, a.value.shape)
        q10, q50, q90 = np.percentile(d["mon"], [10, 50, 90], axis=0)
        comps = d["components"].mean(axis=0) if "components" in d else np.ones_like(a.value)
        ess = d.get("ess")
        for k in range(len(a.value)):
            pf = [None, None] if ess is None else [float(ess[:, k].mean()), int(np.sum(ess[:, k] < COLLAPSED_ESS))]
            rows.append([name, k + 1, st["runs"], float(d["rmse"][k]), float(a.value[k]), float(lo[k]),
                         float(hi[k]), int(a.inside[k]), float(q50[k]), float(q10[k]), float(q90[k]),
                         float(comps[k]), *pf])
    return rows



def caption(st: dict[str, Any]) -> str:
    """The figure's caption (PNG metadata and docs)."""
    return (f"Bearings-only tracking after Arulampalam & Ristic (2000): {st['runs']} Monte Carlo runs, seed "
            f"{st['seed']}, bootstrap and regularised particle filters with {st['particles']} particles. (a) observer and target tracks "
            "(nominal target; triangle: the observer at scan 0); (b) position RMSE; (c) ANEES with its two-sided 95 % chi-square interval (grey); "
            "values above 1000 are off the axis (the table has them); (d) unitless MoN (W^full, TT2) of the bearing at each filter's prior, median over the runs. "
            "Each filter has one colour, marker and line style in every panel; grey span: the observer's turn.")


def _plot(st: dict[str, Any], path: Path, fmt: str = "png") -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    sc = st["sc"]
    fig = Figure(figsize=(7.2, 6.0), layout="constrained")
    FigureCanvasAgg(fig)
    (ax_g, ax_r), (ax_a, ax_m) = fig.subplots(2, 2)
    k = np.arange(1, sc.steps + 1)
    obs = sc.observer / 1000
    # The nominal target: the prior's mean range and bearing, the reference's speed and course.
    t = sc.T * np.arange(sc.steps + 1)[:, None]
    tgt = (np.array([0.0, 5000.0]) + t * _course(4 * KNOT, -140.0)) / 1000
    # The tracks in greys: the Okabe–Ito colours are the filters'.
    ax_g.plot(obs[:, 0], obs[:, 1], color="0.2", marker=".", ms=3, label="observer")
    ax_g.plot(tgt[:, 0], tgt[:, 1], color="0.55", ls="--", marker=".", ms=3, label="target (nominal)")
    ax_g.plot(*tgt[0], "o", color="0.55", ms=4)
    ax_g.plot(*obs[0], "k^", ms=5)
    ax_g.set_xlabel("east [km]")
    ax_g.set_ylabel("north [km]")
    ax_g.set_aspect("equal", adjustable="datalim")
    for name, d in st["filters"].items():
        kw = {**filter_style(name, sc.steps), "ms": 3.5, "label": LABELS[name]}
        ax_r.plot(k, d["rmse"] / 1000, **kw)
        ax_a.semilogy(k, d["anees"].value, **kw)
        ax_m.semilogy(k, np.maximum(np.median(d["mon"], axis=0), 1e-4), **kw)
    a = next(iter(st["filters"].values()))["anees"]
    lo, hi = np.broadcast_to(a.lower, k.shape), np.broadcast_to(a.upper, k.shape)
    ax_a.fill_between(k, lo, hi, color="0.8", zorder=0, label="95 % χ² interval")
    ax_a.axhline(4.0, color="0.5", lw=0.8)
    ax_m.axhline(SPLIT, color="0.3", lw=0.8, ls=(0, (4, 2)))
    ax_m.text(sc.steps, SPLIT * 1.04, "split level", fontsize=7, color="0.3", ha="right",
              va="bottom")
    # The axis shows the band and the filters near it; larger values are drawn off the axis.
    top = ANEES_AXIS_TOP
    ax_a.set_ylim(1.0, top)
    plain_log_ticks(ax_a)  # 1, 10, 100, 1000 and 0.03, 0.1, 0.2: plain numbers
    plain_log_ticks(ax_m)
    off = [LABELS[n] for n, d in st["filters"].items() if np.max(d["anees"].value) > top]
    if off:
        ax_a.text(0.02, 0.97, f"above {top:.0f} (off the axis): " + ", ".join(off), transform=ax_a.transAxes,
                  fontsize=7, va="top")
    for ax in (ax_r, ax_a, ax_m):
        ax.axvspan(13, 17, color="0.5", alpha=0.12, lw=0)
        ax.set_xlabel("scan k (T = 1 min)")
    ax_r.set_ylabel("position RMSE [km]")
    ax_r.set_ylim(bottom=0)
    ax_a.set_ylabel("ANEES (n = 4)")
    ax_m.set_ylabel("MoN of the bearing at the prior")
    # One legend under the panels: the tracks, the filters (one look each in every panel), the band.
    handles = ax_g.get_legend_handles_labels()[0] + ax_a.get_legend_handles_labels()[0]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, frameon=False)
    label_panels((ax_g, ax_r, ax_a, ax_m))
    return save_reproduced(fig, path, fmt, "Bearings-only tracking", caption(st))


def _count(value, name: str, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise ArgumentError(f"{name} must be an integer >= {least}, got {plain_repr(value)}")
    return int(value)


@figure_style()
def run(outdir: Path, runs: int = RUNS, seed: int = 0, particles: int = PARTICLES, progress: bool = True,
        fmt: str = "png") -> list[Path]:
    """Run the study and write ``bot.png`` and ``bot_steps.csv`` (module notes).

    Parameters
    ----------
    outdir : Path
        Output directory (created if missing).
    runs : int, default :data:`RUNS`
        Monte Carlo runs (at least 2).
    seed : int, default 0
    particles : int, default :data:`PARTICLES`
        Particles of the particle filter (at least 10).
    progress : bool, default True
    fmt : {"png", "pdf", "svg"}, default "png"
        The figure's format (a PNG at 300 dpi, or vector).

    Returns
    -------
    list of Path
    """
    runs = _count(runs, "runs", 2)
    particles = _count(particles, "particles", 10)
    seed = _count(seed, "seed", 0)
    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    st = study(runs, particles, seed, progress=progress)
    return [_plot(st, outdir / "bot.png", fmt), write_csv(outdir / "bot_steps.csv", STEP_COLUMNS, step_rows(st))]
