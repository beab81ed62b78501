"""Which filter for this track?  Advice led by the measure of nonlinearity, confirmed by a pilot study.

:func:`advise_filter` answers the filter question for a whole track, where
:func:`symmon.advise` answers the transform question for one prior.  It

1. simulates ``runs`` tracks of the model from ``x0`` (:func:`symmon.simulate`) and runs the
   EKF on a few of them (the *screening*);
2. measures the MoN (W^full, unitless, by TT2: :func:`symmon.nonlinearity`) of the
   transition f and of the measurement h along the track, at :data:`MON_STEPS` steps: at
   the screening filter's own prior (f at its posterior N(x̂_{k|k}, P_{k|k}), h at its
   prediction N(x̂_{k|k−1}, P_{k|k−1})), and at the truth's spread (the same, centred on
   the true state, with the covariance of the screening filter's actual errors over the
   runs), so that a filter whose covariance collapsed cannot hide a nonlinear model;
3. prunes the candidates by that MoN, M = the largest of the four along the track
   (:func:`candidate_menu`): the Kalman filter of a linear model; the EKF always; the
   iterated EKF where h's MoN exceeds √2 · tol (where the EKF is no longer within ``tol``
   on a quadratic: :mod:`symmon.measures.advice`); the UKF, CKF and Gauss–Hermite where
   M exceeds √2 · tol; a square-root form where the screening's covariance is
   ill-conditioned; the Gaussian-sum filter split by the MoN with the component count
   that brings each component's MoN to √2 · tol (:func:`~symmon.measures.advice.filter_advice`)
   where M exceeds √2 · tol; the particle filter, with its particle count, proposal and
   regularisation, where M exceeds :data:`~symmon.measures.advice.GAUSSIAN_MON_LIMIT`;
   an IMM over the given ``modes``; with an SDE as f, its continuous-discrete filters
   (:data:`CD_CANDIDATES`: the CD-EKF always, the CD-CKF where M exceeds √2 · tol; "An SDE
   as f" below);
4. runs the kept candidates on the same simulated tracks (a pilot study: each candidate one
   compiled bank over the runs) and measures each one's RMSE, its time-mean ANEES (the mean
   over the steps of the mean NEES over the runs), whether a run's covariance collapsed
   (singular or non-finite: the filter raises, and the candidate is not credible), and the
   share of its steps flagged by its online credibility (:attr:`KalmanResult.credibility
   <symmon.filters.results.KalmanResult.credibility>`); when none is credible (or every
   credible one is at risk, below), the pruned Gaussian-sum and particle filters are run too;
5. chooses the **cheapest credible candidate whose RMSE is within** :data:`RMSE_MARGIN`
   **(10 %) of the best credible one**.  Credible: the time-mean ANEES lies in
   [0.3 n, 1.5 n] (:data:`ANEES_BAND`) for n states, and no run's covariance collapsed.
   The choice also asks the pilot's verdict to hold on a fresh bank: a credible candidate
   whose :func:`predictive credibility <predictive_credibility>` (the bootstrap probability,
   over the pilot's runs, that a fresh bank of as many runs would be credible) is below
   :data:`CREDIBLE_PROBABILITY` is *at risk* (one divergent run among the pilot's carries
   its time-mean ANEES): the best RMSE and the choice are then taken over the credible
   candidates not at risk, or over all the credible ones when every one is at risk.  The
   reported ``credible`` keeps the definition above.
   Cheapest: a deterministic cost per step, in model evaluations as
   :func:`symmon.advise` counts them (:meth:`symmon.Transform.cost` of f's and of h's
   input dimension), times the components of a Gaussian-sum filter or the modes of an IMM,
   or 2 per particle; ties go to the earlier candidate, so the choice is the same for the
   same seed.  When none is credible, the advice says so and chooses the most accurate.
6. **grows the particle filter** where its accuracy is needed: when the pilot finds the
   menu's particle filter not credible (or at risk, or a run raised) and no steady credible
   candidate has an RMSE within :data:`RMSE_MARGIN` of its own, a particle filter of
   :data:`PF_GROWTH` (4) times the particles joins the candidates (``"pf (N=4000)"``) and
   runs the pilot, at most :data:`PF_GROWTH_STEPS` (3) times (64 times the menu's count).
   A consistent particle filter is credible in expectation (for the exact posterior
   E[NEES] = n); a bootstrap filter of too few particles is not, because in a few runs its
   weights collapse onto one particle and its covariance onto a point, and those runs carry
   the time-mean ANEES (the growth model: N = 1000 gives an ANEES of 10¹⁸ on 200 fresh runs,
   N = 16 000 gives 1.0).  So a credible particle filter one of whose runs fell onto a
   handful of particles (its ESS below :data:`COLLAPSED_ESS` at some step:
   :attr:`FilterCandidate.collapsed`) is *at risk*: its particle count is marginal, and a
   rarer run diverges.  Measured on the growth model over 4 × 256 runs: with N = 4000,
   4–18 runs of 256 fall below an ESS of 5 (2–6 below 1.5) and 0–2 diverge (time-mean NEES
   above 20; ANEES up to 4.7·10⁴), all but one of them at an ESS of 1.0; with 16 000, 1–3
   below 5 and 0–1 diverging (ANEES up to 1.56); with 64 000, 0–1 below 5 and none
   diverging (ANEES 0.93–1.03).  With seed 1, N = 4000 was credible on the pilot's 64 runs
   and a second look of 82 with no run below 1.5, and its ANEES on 200 fresh runs was 17.7.  Neither a proposal nor a kernel replaces the particles there: the
   UKF proposal of 1000 particles still has a run of time-mean NEES 45 among 64 (ANEES 1.7,
   n = 1), and the regularisation (its jitter after resampling) does not change the
   covariance at the update where the weights collapse;
7. takes a **tail look** where at least two candidates are credible: they run on as many
   runs as the pilot's whose initial truths are drawn from the defensive mixture
   (1 − :data:`TAIL_SHARE`) N(x̄0, P0) + TAIL_SHARE N(x̄0, :data:`TAIL_WIDTH`² P0) (half of
   them from a prior twice as wide), each run weighted back to the prior by
   p/((1 − ε) p + ε q) ≤ 2 (:func:`tail_weights`; Hesterberg 1995).  A run whose NEES at its
   last step exceeds the χ²_n quantile of 1 − :data:`LOST_ALPHA` has *lost its track*
   (:func:`lost_track_threshold`: a consistent filter does so once in 10⁶ runs), and so has
   a run whose last covariance is singular or not finite (a particle cloud collapsed onto a
   point where no particle was near the truth: the run is lost, the look goes on); the
   weighted share of such runs estimates the candidate's lost-track probability per run
   (:attr:`FilterCandidate.lost_rate`, the column ``lost`` of the table).  A credible
   candidate whose lost-track probability makes a bank of the advice's runs (the pilot's and
   its second look's, (1 + :data:`SECOND_LOOK`) times the pilot's) hold a lost track with
   probability at least :data:`LOST_BANK_PROBABILITY` (10 %) is *at risk* when another
   credible candidate's does not (a candidate whose tail look raised is at risk on the
   same terms).  Where **no** credible candidate is safe (every one's rate makes such a
   bank likely to hold a lost track), the *relative rule*: a credible candidate whose rate
   is at least :data:`LOST_RATE_RATIO` (3) times the fewest is at risk, and so is one whose
   tail look raised (bearings-only in the test suite's setting, seed 2: the UKF, CKF,
   Gauss–Hermite filter and EKF lose 0.08 per run, the Gaussian-sum filter 0.0022, and the
   advice turned from the UKF, ANEES 9.5 on 40 fresh runs, to the Gaussian-sum filter, 6.17:
   nearer the band [1.2, 6], not in it; the regularised particle filter whose collapsing
   updates are tempered loses none there, and is the advice).
   One lost track among 200 runs carries a time-mean ANEES out of the band
   (range-only localisation: a truth 3.8 prior standard deviations below the sensor's
   line, once in about 1400 runs, given to the mirror mode by the Gaussian-sum filter,
   NEES 1154); plain runs meet such truths too rarely, the prior twice as wide about 55 times
   as often (for n = 2 at a squared Mahalanobis distance of 14.4, q/p = e^{0.375·14.4}/4).  The tail look is skipped (with a note) where a truth of the
   widened prior leaves the model's domain (the simulation diverges) or the budget would
   not hold it;
8. takes a **second look** at the choice: it runs on :data:`SECOND_LOOK` (3) times the
   pilot's runs more (fresh tracks of another seed drawn from ``seed``; at most as many as
   cost the pilot's estimated evaluations, the particle filters grown for it included, and
   within ``budget``), and its row is then over
   all its runs.  Where it is not credible there (or at risk), the choice is taken again
   (a particle filter grown as in 6), and the next choice gets its second look too.  A
   failure in one run of M is seen by R runs with probability 1 − (1 − 1/M)^R: the pilot of
   64 runs and its second look of 192 see a failure in one run of 200 with probability 0.72,
   the pilot alone with 0.27 (``docs/select.md``: rarer failures stay unseen).

The RMSE that the choice compares is unitless: each state's error in units of its prior
standard deviation √(P0)_ii, then the root mean square over the states, runs and steps;
each state's own RMSE, in its units, is in :attr:`FilterCandidate.rmse_states`.  The
ANEES interval reported beside it is the 95 % two-sided χ² interval of one step's ANEES
over the R independent runs, [χ²_{Rn}(0.025), χ²_{Rn}(0.975)] / R (Bar-Shalom, Li &
Kirubarajan 2001, §5.4.2): the time mean varies less than one step's value, so a
consistent filter's time mean lies inside it.

Defensive mixtures: T. Hesterberg, "Weighted average importance sampling and defensive mixture
distributions", Technometrics 37(2), 185–194, 1995.

Measured on the study ``symmon reproduce select`` (pilot of 64 runs, 200 fresh runs, seed 0):
the tail look turns range-only localisation's advice from the Gaussian-sum filter (ANEES
7.64 on the fresh runs, not credible) to the particle filter (1.77, confirmed); on
bearings-only every Gaussian candidate loses tracks in the tail (the UKF and CKF 0.012 per
run, the Gaussian-sum filter 0.0027: truths that start behind the observer), and the
menu's particle filter, regularised there (little process noise) with its collapsing
updates tempered (:class:`~symmon.ParticleFilter`, ``on_collapse="temper"``), loses none:
the advice is that filter, credible on the fresh runs (ANEES 2.99) where the Gaussian-sum
filter, advised before the tempered update, was not (63.9: two runs that the untempered
filter of 2000 particles lost as well, and one of 40 000 kept).  The other four advices are
unchanged (``docs/select.md``).

``budget`` (seconds) bounds the pilot by running fewer tracks: the runs are
budget / (steps · Σ cost · :data:`SECONDS_PER_EVALUATION`), at least :data:`MIN_RUNS` and at
most ``runs``, decided from the cost estimate (never from a clock), so that the choice stays
reproducible; a grown particle filter,
the tail look and the second look run only where the estimate of what is left holds them
(:attr:`FilterAdvice.estimated_seconds` counts them).  Compilation is not in the estimate: a
filter's first call compiles its C once (cached on disk).

**An SDE as f** (``times=`` or ``params["dt"]``, ``Q=None``).  The SDE is discretised over
the measurement intervals (:mod:`symmon.filters.sde_advice`: exact for a linear SDE, else
order 1.5 with the sub-steps that bring a sub-step's MoN within ``tol``), and the menu's
discrete filters filter that model f(x, w; θ, dt), ``dt`` a per-step parameter.  Beside them
the SDE's continuous-discrete filters (:class:`~symmon.ContinuousDiscreteKalmanFilter`: the
moment ODEs integrated between measurements, no discretisation) are candidates: ``"cd-ekf"``
(TT1) always, ``"cd-ckf"`` (the cubature points of the menu's CKF) where M exceeds
√2 · tol, as the sigma-point filters; the caller's ``candidates``
may name ``"cd-"`` and any rule of the class (``"cd-ukf"``, with its integrator's settings).
They filter the same measurements with the same ``params``, the intervals by the ``dt``
route (the same numbers, bit for bit, as ``times=``), and are scored, chosen, looked at in
the tail and a second time, and counted in the budget by the same rules as every candidate:
their cost is their ``step_cost()`` (at least 8 evaluations of the moment equations per
interval and the update), their MoN columns are their own priors' through the discretised
step, as every row's.  On a linear SDE the CD-EKF's moment ODEs are those of the exact
discretisation: its pilot numbers are the Kalman filter's to the integrator's tolerance,
and the cheaper discrete filter of the same RMSE is chosen; where the CD-EKF's RMSE is
within :data:`RMSE_MARGIN` of the best and it is cheaper (the UKF of an 8-sub-step
discretisation of Van der Pol: 42 against its 27), it is chosen, and ``advice.filter`` is
the built continuous-discrete filter (``filter(ys, x0, times=...)`` or
``params={"dt": ...}``).  :attr:`FilterAdvice.sde` holds the discretisation and the MoN of
the flow over the longest interval from x0 (``sm.nonlinearity(sde, x0, dt=...)``) and of
one sub-step, which the head of the table and the CD rows' reasons repeat.  The pilot's truth
is the discretised model's for every candidate; :mod:`symmon.filters.sde_advice` says why that
is good enough for the continuous-discrete ones.

Their time.  The continuous-discrete filter's intervals and updates are one compiled call
per bank (Dormand–Prince 5(4) with scipy's step control, :mod:`symmon.filters.gaussian.continuous`):
measured on white-noise acceleration (12 intervals) and Van der Pol (24), 1.0–1.6·10⁻⁷ s per
unit of ``step_cost()`` against the discrete filters' 0.4–1.2·10⁻⁷ (the adaptive steps take
about 80 evaluations of the moment equations per interval at rtol 1e-6, ``step_cost()``
counts 8, but an evaluation is a few hundred flops in C), so the budget's estimate takes one
rate for all; the default advice took 0.11 s and 1.2 s there (it was 1.7–2.7 s and 30–53 s
while the integrator ran in Python).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import sympy as sp
from scipy import stats

from ..core.angles import wrap_angle
from ..core.gaussian import Gaussian
from ..core.mixture import GaussianMixture
from ..core.model import Model, with_param_values
from ..core.sde import SDE
from ..errors import ArgumentError, ArgumentTypeError, NonFiniteError, SingularMatrixError, SymmonError, plain_repr
from ..measures.advice import DEFAULT_TOL, GAUSSIAN_MON_LIMIT, MAX_GSF_COMPONENTS, cost as transform_cost, filter_advice
from ..measures.mon import nonlinearity
from ..transforms.quadrature import GaussHermite
from ..transforms.taylor import TT1, TT2
from .base import Filter
from .gaussian.continuous import ContinuousDiscreteKalmanFilter
from .gaussian.nonlinear import NonlinearKalmanFilter
from .mixture.imm import IMM
from .registry import filter_entry, make_filter
from .results import quadratic_forms
from .sde_advice import DiscretizedTrack, discretize_track
from .simulation import simulate

__all__ = ["advise_filter", "FilterAdvice", "FilterCandidate", "candidate_menu", "ANEES_BAND", "RMSE_MARGIN",
           "MON_STEPS", "MIN_RUNS", "SECONDS_PER_EVALUATION", "ILL_CONDITIONED", "SCREENING_RUNS", "confirm_advice",
           "Confirmation", "BATCH_RUNS", "predictive_credibility", "CREDIBLE_PROBABILITY", "BOOTSTRAP_SAMPLES",
           "PF_GROWTH", "PF_GROWTH_STEPS", "COLLAPSED_ESS", "SECOND_LOOK", "TAIL_SHARE", "TAIL_WIDTH", "LOST_ALPHA",
           "LOST_BANK_PROBABILITY", "LOST_RATE_RATIO", "lost_track_threshold", "tail_weights", "CD_CANDIDATES"]

#: Credible: the time-mean ANEES within these multiples of the state dimension n.
ANEES_BAND = (0.3, 1.5)
#: A credible candidate whose predictive credibility is below this is at risk (module notes).
CREDIBLE_PROBABILITY = 0.8
#: The bootstrap banks of :func:`predictive_credibility`.
BOOTSTRAP_SAMPLES = 2000
#: The choice is the cheapest credible candidate whose RMSE is within this share of the best credible one.
RMSE_MARGIN = 0.10
#: The steps of the track (evenly spaced, first and last included) where the MoN is evaluated.
MON_STEPS = 12
#: The fewest pilot runs that ``budget`` may leave.
MIN_RUNS = 8
#: The runs of the screening EKF (the first of the pilot's).
SCREENING_RUNS = 16
#: The seconds one model evaluation of a compiled bank is estimated to take, for ``budget``
#: (measured on the banks of a 4-state range–bearing tracker: 0.07–0.4 µs).
SECONDS_PER_EVALUATION = 3e-7
#: A covariance whose correlation matrix has a condition number above this is ill-conditioned:
#: a square-root form joins the candidates.
ILL_CONDITIONED = 1e8
#: The probability that an IMM stays in its mode from one step to the next.
IMM_STAY = 0.95
#: The particle filter's particles: this many per state, within [PF_MIN, PF_MAX].
PF_PER_STATE, PF_MIN, PF_MAX = 500, 1000, 10_000
#: The process noise, relative to the prior covariance (mean eigenvalue of P0⁻¹ Q), below which the
#: particle filter is regularised: little noise would let resampling collapse the cloud.
PF_REGULARISE_BELOW = 1e-2
#: The particle filter grown where the pilot finds it not credible (or at risk): its particles times
#: this, at most this many times (module notes, "The particle filter grown").
PF_GROWTH, PF_GROWTH_STEPS = 4, 3
#: A particle filter's run whose ESS fell below this at some step (a handful of particles) marks
#: its particle count as marginal: the filter is at risk (module notes).
COLLAPSED_ESS = 5.0
#: The second look runs the choice on up to this many times the pilot's runs more (module notes).
SECOND_LOOK = 3
#: The tail look (module notes): its runs' initial truths are drawn from (1 − TAIL_SHARE) N(x̄0, P0) +
#: TAIL_SHARE N(x̄0, TAIL_WIDTH² P0) and weighted back to the prior.
TAIL_SHARE, TAIL_WIDTH = 0.5, 2.0
#: A run whose NEES at its last step exceeds the χ²_n quantile of 1 − LOST_ALPHA has lost its track
#: (module notes).
LOST_ALPHA = 1e-6
#: A credible candidate whose lost-track rate makes a bank of the advice's runs (the pilot's and its
#: second look's) contain a lost track with at least this probability is at risk where another is not.
LOST_BANK_PROBABILITY = 0.1
#: Where no credible candidate is safe in the tail look, one that loses tracks at least this many times as
#: often as the fewest is at risk (module notes, the relative rule).
LOST_RATE_RATIO = 3.0
#: The Gauss–Hermite filter is a candidate while its 3^n_w points per model cost at most this.
GH_MAX_POINTS = 5000


@dataclass(frozen=True, eq=False)
class FilterCandidate:
    """One row of :attr:`FilterAdvice.candidates`.

    Attributes
    ----------
    name : str
        The candidate: a registered filter name (:func:`symmon.filters.registry.filter_names`),
        ``"ukf (square root)"`` or ``"imm"``.
    method : str
        The filter's own name (``"EKF"``, ``"PF(bootstrap, N=2000, systematic)"``, ...).
    settings : dict
        Its settings (those of its registry entry, or ``square_root``, ``modes``).
    kept : bool
        Whether the pilot ran it.
    reason : str
        Why it was kept or dropped.
    cost : int
        Model evaluations per step (module notes).
    mon_f, mon_h : float or None
        The MoN (W^full, unitless) of f and of h at the candidate's own prior, the largest
        along the track; None when not run (or NaN where its covariance was unusable).
    rmse : float or None
        The pilot's RMSE, unitless (each state's error in units of its prior standard deviation).
    rmse_states : ndarray or None
        Each state's RMSE, in its own units.
    anees : float or None
        The time-mean ANEES (unitless).
    anees_interval : tuple of float or None
        Its 95 % χ² interval (module notes).
    credible : bool or None
        ANEES in [0.3 n, 1.5 n] and no covariance collapsed; None when not run.
    credibility : float or None
        The predictive credibility (:func:`predictive_credibility`): the probability that a
        fresh bank of as many runs would be credible, by bootstrap over the runs; None when
        not run (0 when a run failed or its NEES is not finite).
    failure : str
        Why not credible ("" when credible or not run).
    flagged : float or None
        The share of the pilot's steps flagged by the online credibility (windowed NIS, and
        ESS for a particle filter); None when the filter reports no innovations.
    seconds_per_step : float or None
        Measured: the pilot's time divided by runs × steps (its first call compiles too).
    run_nees : ndarray or None
        Each run's time-mean NEES (unitless), from which :attr:`credibility` is estimated.
    runs : int or None
        The runs its numbers are over: the pilot's, and those of its second look (module
        notes); None when not run.
    lost_rate : float or None
        The tail look's estimate of the probability per run (unitless) that the candidate
        loses its track (:func:`lost_track_threshold`), weighted back to the prior (module
        notes); None when it did not run the tail look (or a run of it raised).
    tail_risk : bool
        Credible, but its lost-track rate makes a bank of the advice's runs likely (at least
        :data:`LOST_BANK_PROBABILITY`) to hold a lost track, where another credible
        candidate's does not; or, where no credible candidate's rate is that low, at least
        :data:`LOST_RATE_RATIO` times the fewest (module notes, the relative rule).
    collapsed : int or None
        A particle filter's runs whose weights fell onto a handful of particles at some step
        (ESS below :data:`COLLAPSED_ESS`): a credible particle filter with such runs is at
        risk (module notes); None for the other filters.
    """

    name: str
    method: str
    settings: dict
    kept: bool
    reason: str
    cost: int
    mon_f: float | None = None
    mon_h: float | None = None
    rmse: float | None = None
    rmse_states: np.ndarray | None = None
    anees: float | None = None
    anees_interval: tuple[float, float] | None = None
    credible: bool | None = None
    failure: str = ""
    flagged: float | None = None
    seconds_per_step: float | None = None
    run_nees: np.ndarray | None = field(default=None, repr=False)
    credibility: float | None = None
    runs: int | None = None
    lost_rate: float | None = None
    tail_risk: bool = False
    collapsed: int | None = None

    @property
    def at_risk(self) -> bool:
        """Credible, but its predictive credibility is below :data:`CREDIBLE_PROBABILITY`, or
        it loses tracks in the prior's tail where another credible candidate does not
        (:attr:`tail_risk`), or its particle cloud collapsed in a run (:attr:`collapsed`)."""
        return bool(self.credible) and (self.credibility is None or self.credibility < CREDIBLE_PROBABILITY
                                        or self.tail_risk or bool(self.collapsed))

    def as_dict(self) -> dict:
        """The row as plain numbers and strings (JSON)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["settings"] = {k: (v if isinstance(v, (int, float, str, bool)) else repr(v))
                           for k, v in self.settings.items()}
        if self.rmse_states is not None:
            out["rmse_states"] = [float(v) for v in self.rmse_states]
        if self.anees_interval is not None:
            out["anees_interval"] = [float(v) for v in self.anees_interval]
        if self.run_nees is not None:
            out["run_nees"] = [float(v) for v in self.run_nees]
        out["at_risk"] = self.at_risk
        return out


@dataclass(frozen=True, eq=False)
class FilterAdvice:
    """The result of :func:`advise_filter`.

    Attributes
    ----------
    filter : Filter
        The chosen filter, built and ready: ``advice.filter.filter(ys, x0)``.
    choice : str
        Its candidate name.
    credible : bool
        Whether the choice is credible (False: no candidate was, and the choice is the most accurate).
    recommendation : str
        The one recommendation, in a sentence.
    candidates : tuple of FilterCandidate
        One row per candidate, kept or dropped, in the order of the menu.
    mon : dict
        The screening MoN along the track (unitless, the largest over the steps):
        ``{"f": {"prior": …, "truth": …}, "h": {"prior": …, "truth": …}}``.
    n, steps, runs : int
        States, steps, and the pilot's runs (fewer than asked under ``budget``).
    runs_asked : int
    budget : float or None
    estimated_seconds : float
        The pilot's estimated time (module notes), from which ``runs`` was chosen, with its
        grown particle filters and its second look.
    tol : float
    seed : int
    notes : tuple of str
    second_look : int
        The runs of the second look (module notes) that the choice (and any choice it
        overturned) ran on beyond the pilot's; 0 when there was none.
    tail_look : int
        The runs of the tail look (module notes) that the credible candidates ran on; 0 when
        there was none (fewer than two credible candidates, or the budget would not hold it).
    sde : dict or None
        With an SDE as f: its discretisation (``method``, ``substeps`` per interval), the
        ``longest_interval`` (in the SDE's time unit) and the MoN (W^full, unitless) of the
        flow over it from x0 (``flow_mon``) and of one sub-step (``substep_mon``)
        (:class:`~symmon.filters.sde_advice.DiscretizedTrack`); None for a discrete f.
    """

    filter: Filter
    choice: str
    credible: bool
    recommendation: str
    candidates: tuple[FilterCandidate, ...]
    mon: dict
    n: int
    steps: int
    runs: int
    runs_asked: int
    budget: float | None
    estimated_seconds: float
    tol: float
    seed: int
    notes: tuple[str, ...] = field(default_factory=tuple)
    second_look: int = 0
    tail_look: int = 0
    sde: dict | None = None

    @property
    def chosen(self) -> FilterCandidate:
        """The chosen candidate's row."""
        return next(c for c in self.candidates if c.name == self.choice)

    @property
    def table(self) -> str:
        """The candidates' table, every number with its unit (or unitless)."""
        lines = [" ".join(f"{name:{'<' if i == 0 else '>'}{w}}" for i, (name, _, w) in enumerate(_COLUMNS)) + "  verdict",
                 " ".join(f"{unit:{'<' if i == 0 else '>'}{w}}" for i, (_, unit, w) in enumerate(_COLUMNS))]
        for c in self.candidates:
            mark = "  <- choice" if c.name == self.choice else ""
            if not c.kept:
                cells = [c.name] + ["—"] * 8 + [f"{c.cost:,d}" if c.cost else "—", "—"]
                verdict = f"dropped: {c.reason}"
            else:
                interval = "—" if c.anees_interval is None else f"[{c.anees_interval[0]:.3g}, {c.anees_interval[1]:.3g}]"
                cells = [c.name, _num(c.mon_f, ".3f"), _num(c.mon_h, ".3f"), _num(c.rmse, ".4g"), _num(c.anees, ".4g"),
                         interval, _num(c.credibility, ".2f"), _num(c.lost_rate, ".2g"),
                         _num(None if c.flagged is None else 100 * c.flagged, ".1f"), f"{c.cost:,d}",
                         _num(None if c.seconds_per_step is None else 1e6 * c.seconds_per_step, ".3g")]
                verdict = ("not credible: " + c.failure if not c.credible else
                           ("credible, at risk: its tail look failed" if c.lost_rate is None else
                            f"credible, at risk: loses tracks in the prior's tail ({c.lost_rate:.2g} per run)")
                           if c.tail_risk else
                           f"credible, at risk: its cloud fell onto a handful of particles in {c.collapsed} run(s)"
                           if c.collapsed else
                           f"credible, at risk: P(credible) {_num(c.credibility, '.2f')} < {CREDIBLE_PROBABILITY:g}"
                           if c.at_risk else "credible")
            lines.append(" ".join(f"{cell:{'<' if i == 0 else '>'}{w}}" for i, (cell, (_, _, w))
                                  in enumerate(zip(cells, _COLUMNS))) + f"  {verdict}{mark}")
        return "\n".join(lines)

    def __str__(self) -> str:
        lo, hi = ANEES_BAND
        m = self.mon
        look = "" if not self.second_look else f", a second look at the choice on {self.second_look} more"
        if self.tail_look:
            look = f", a tail look on {self.tail_look} runs from a prior {TAIL_WIDTH:g} times as wide" + look
        budget = "" if self.budget is None else (f", budget {self.budget:g} s (estimated {self.estimated_seconds:.3g} s; "
                                                  f"{self.runs_asked} runs asked)")
        head = (f"filter advice: n = {self.n} states, {self.steps} steps, pilot of {self.runs} simulated runs "
                f"(seed {self.seed}){look}{budget}, tol {self.tol:g} (unitless)\n"
                f"MoN along the track (W^full, unitless, largest over {MON_STEPS} steps): "
                f"f {m['f']['prior']:.3g} at the EKF's prior, {m['f']['truth']:.3g} at the truth's spread; "
                f"h {m['h']['prior']:.3g} at the EKF's prior, {m['h']['truth']:.3g} at the truth's spread\n"
                f"credible: time-mean ANEES in [{lo * self.n:.3g}, {hi * self.n:.3g}] ({lo:g} n, {hi:g} n) and no "
                "run's covariance collapsed; RMSE in prior standard deviations\n"
                f"P(credible): the probability, by bootstrap over the pilot's runs, that a fresh bank of {self.runs} "
                f"runs would be credible; below {CREDIBLE_PROBABILITY:g} a credible candidate is at risk\n"
                f"lost: the tail look's rate of lost tracks per run (NEES at the last step above the χ²_n quantile of "
                f"1 − {LOST_ALPHA:g}), weighted back to the prior\n")
        if self.sde is not None:
            s = self.sde
            head += (f"SDE: the MoN of its flow over the longest interval ({s['longest_interval']:.3g}) from x0 "
                     f"{s['flow_mon']:.3g}, of one of the discretisation's sub-steps {s['substep_mon']:.3g} "
                     f"({s['method']!r}, {s['substeps']} per interval); the cd- rows integrate the SDE's moment "
                     "equations\n")
        notes = "".join(f"\nnote: {n}" for n in self.notes)
        return head + self.table + f"\nrecommendation: {self.recommendation}" + notes

    def __repr__(self) -> str:
        return f"FilterAdvice(choice={self.choice!r}, credible={self.credible}, runs={self.runs}, tol={self.tol:g})"

    def as_dict(self) -> dict:
        """The advice as plain numbers and strings (``symmon advise --filter --json``)."""
        return {"choice": self.choice, "method": self.filter.method, "credible": self.credible,
                "recommendation": self.recommendation, "mon": self.mon, "n": self.n, "steps": self.steps,
                "runs": self.runs, "runs_asked": self.runs_asked, "second_look": self.second_look,
                "tail_look": self.tail_look, "budget": self.budget, "sde": self.sde,
                "estimated_seconds": self.estimated_seconds, "tol": self.tol, "seed": self.seed,
                "anees_band": [ANEES_BAND[0] * self.n, ANEES_BAND[1] * self.n], "rmse_margin": RMSE_MARGIN,
                "credible_probability": CREDIBLE_PROBABILITY,
                "units": {"mon": "unitless", "rmse": "unitless (prior standard deviations)", "anees": "unitless",
                          "run_nees": "unitless", "credibility": "probability", "lost_rate": "probability per run",
                          "flagged": "share of steps", "cost": "model evaluations per step",
                          "seconds_per_step": "seconds per step and run", "flow_mon": "unitless",
                          "substep_mon": "unitless", "longest_interval": "the SDE's time unit"},
                "candidates": [c.as_dict() for c in self.candidates], "notes": list(self.notes)}


#: The table's columns: name, unit, width.
_COLUMNS = (("filter", "", 19), ("MoN f", "(unitless)", 10), ("MoN h", "(unitless)", 10), ("RMSE", "(unitless)", 10),
            ("ANEES", "(unitless)", 10), ("95% interval", "(unitless)", 16), ("P(credible)", "(prob.)", 11),
            ("lost", "(per run)", 9),
            ("NIS flagged", "(% steps)", 11),
            ("cost", "(evals/step)", 12), ("time/step", "(µs/run)", 9))


def _num(v: float | None, fmt: str) -> str:
    if v is None:
        return "—"
    return "nan" if not np.isfinite(v) else format(v, fmt)


# --------------------------------------------------------------------------- the menu
@dataclass(frozen=True)
class _Option:
    """A candidate before the pilot: how to build it, its cost, and the pruning's verdict."""

    name: str
    build: Callable[[], Filter] = field(repr=False)
    settings: dict
    cost: int
    kept: bool
    reason: str
    readmit: bool = False  # run it when no kept candidate is credible


def _estimate(runs: int, steps: int, options: Sequence[_Option]) -> float:
    """The estimated seconds of ``runs`` runs of ``steps`` steps of each of ``options``, for
    ``budget``: runs · steps · Σ cost · :data:`SECONDS_PER_EVALUATION`."""
    return float(runs * steps * sum(o.cost for o in options) * SECONDS_PER_EVALUATION)


def _is_linear(f: Model, h: Model) -> bool:
    """f and h are g(x) = M x with constant M, no noise symbols, no parameters (the ``kf`` entry)."""
    for g in (f, h):
        if g.n_v or g.params:
            return False
        x = list(g.inputs)
        J = sp.Matrix(g.outputs).jacobian(x)
        if J.free_symbols or any(e != 0 for e in sp.Matrix(g.outputs).subs({s: 0 for s in x})):
            return False
    return True


def _gaussian_cost(rule: Any, f: Model, h: Model, h_times: int = 1) -> int:
    return transform_cost(rule, f.n_u + f.n_v) + h_times * transform_cost(rule, h.n_u + h.n_v)


def candidate_menu(f: Model, h: Model, Q: np.ndarray, R: np.ndarray, P0: np.ndarray, mon_f: float, mon_h: float,
                   tol: float, *, modes: Sequence[Any] | None = None, ill_conditioned: bool = False,
                   seed: int = 0, track: DiscretizedTrack | None = None) -> list[_Option]:
    """The candidates for a track whose MoN along it is ``mon_f`` (f) and ``mon_h`` (h), each
    with the pruning's verdict (module notes).

    With ``track`` (an SDE discretised over the measurement intervals, f its model), the
    continuous-discrete filters of the SDE join the menu (module notes).

    Returns
    -------
    list
        One option per candidate, in the order of the table, with its name, settings, cost,
        whether it is kept and why.
    """
    n = f.n_u
    mon = max(mon_f, mon_h)
    lin = math.sqrt(2.0) * tol
    out: list[_Option] = []
    small = f"the MoN {mon:.3g} <= sqrt(2) tol = {lin:.3g} along the track: the EKF's moments are within tol"

    def gaussian(name: str, settings: dict | None = None) -> Callable[[], Filter]:
        return lambda: make_filter(name, f, h, Q, R, tol=tol, settings=settings)

    ekf_cost = _gaussian_cost(TT1(), f, h)
    if _is_linear(f, h):
        out.append(_Option("kf", gaussian("kf"), {}, ekf_cost, True,
                           "f and h are linear: the Kalman filter is exact (its F and H counted as the EKF's Jacobians)"))
    out.append(_Option("ekf", gaussian("ekf"), {}, ekf_cost, True, "the cheapest nonlinear filter (the baseline)"))
    iters = 5
    out.append(_Option("iekf", gaussian("iekf", {"iterations": iters}), {"iterations": iters},
                       _gaussian_cost(TT1(), f, h, iters), mon_h > lin,
                       f"h's MoN {mon_h:.3g} > sqrt(2) tol: iterating the update relinearises h" if mon_h > lin else
                       f"h's MoN {mon_h:.3g} <= sqrt(2) tol: iterating the update cannot help"))
    for name in ("ukf", "ckf", "ghkf"):
        rule = filter_entry(name).rule(tol, {})
        build, settings = gaussian(name), {}
        if name == "ghkf":
            # The tensor grid of order 3 (3^n points), never the sparse grid that GaussHermite
            # falls to, with a warning, above 4 dimensions.
            rule = GaussHermite(3, sparse=False)
            build, settings = (lambda rule=rule: NonlinearKalmanFilter(f, h, Q, R, rule)), {"order": 3, "sparse": False}
        c = _gaussian_cost(rule, f, h)
        if name == "ghkf" and 3 ** (n + max(f.n_v, h.n_v)) > GH_MAX_POINTS:
            out.append(_Option(name, build, settings, c, False, f"its 3^n points cost more than {GH_MAX_POINTS}"))
            continue
        out.append(_Option(name, build, settings, c, mon > lin,
                           f"the MoN {mon:.3g} > sqrt(2) tol: sigma points follow the curvature" if mon > lin else
                           small + ", at a higher cost"))
    if track is not None:  # an SDE: its continuous-discrete filters, on the SDE itself
        out += _continuous_options(track, h, R, tol, mon, lin, small)
    if ill_conditioned:
        base = "ukf" if mon > lin else "ekf"
        rule = filter_entry(base).rule(tol, {})
        out.append(_Option(f"{base} (square root)", lambda: NonlinearKalmanFilter(f, h, Q, R, rule, square_root=True),
                           {"square_root": True}, _gaussian_cost(rule, f, h), True,
                           f"the screening covariance is ill-conditioned (condition number > {ILL_CONDITIONED:.0e})"))
    # The Gaussian-sum filter: split by the MoN, as many components as bring each one's MoN to sqrt(2) tol.
    gsf = filter_advice(max(mon, lin * 1.0000001), None, tol)
    if f.n_v or h.n_v:
        out.append(_Option("gsf", lambda: None, {}, 0, False, "splitting needs additive noises (no noise symbols)"))
    else:
        components = int(gsf.get("max_components", MAX_GSF_COMPONENTS))
        settings = {"transform": "ekf", "split": float(lin), "max_components": components}
        levels = (f"{gsf['levels']} level(s) of 3-splits bring each component's to {lin:.3g}" if gsf["filter"] == "gsf"
                  else f"at most {MAX_GSF_COMPONENTS} components (bringing each one's to {lin:.3g} would need more)")
        out.append(_Option("gsf", gaussian("gsf", settings), settings,
                           components * ekf_cost + _gaussian_cost(TT2(), f, h), mon > lin,
                           f"the MoN {mon:.3g} > sqrt(2) tol: {levels}" if mon > lin else small, readmit=True))
    particles = int(min(PF_MAX, max(PF_MIN, PF_PER_STATE * n)))
    regularise = _little_process_noise(f, Q, P0)
    settings = {"particles": particles, "proposal": "bootstrap", "regularise": regularise, "seed": int(seed)}
    if regularise:  # little process noise: a collapsed cloud cannot spread again, so a collapsing update is tempered
        settings["on_collapse"] = "temper"
    out.append(_Option("pf", gaussian("pf", settings), settings, 2 * particles, mon > GAUSSIAN_MON_LIMIT,
                       (f"the MoN {mon:.3g} > {GAUSSIAN_MON_LIMIT}, where Gaussian filters lose consistency"
                        if mon > GAUSSIAN_MON_LIMIT else
                        f"the MoN {mon:.3g} <= {GAUSSIAN_MON_LIMIT}: Gaussian filters keep their consistency here")
                       + ("; regularised, its collapsing updates tempered: little process noise" if regularise
                          else ""), readmit=True))
    if modes:
        rule = filter_entry("ukf" if mon > lin else "ekf").rule(tol, {})
        models = [(f, Q)] + [_mode(m, i, Q) for i, m in enumerate(modes)]
        M = len(models)
        P = np.full((M, M), (1 - IMM_STAY) / (M - 1)) + np.eye(M) * (IMM_STAY - (1 - IMM_STAY) / (M - 1))

        def imm() -> Filter:
            return IMM([NonlinearKalmanFilter(fm, h, Qm, R, rule) for fm, Qm in models], P, np.full(M, 1.0 / M))

        out.append(_Option("imm", imm, {"modes": M, "rule": rule.filter_label(), "stay": IMM_STAY},
                           M * _gaussian_cost(rule, f, h), True, f"{M} modes given (f and {M - 1} alternative(s))"))
    return out


#: The continuous-discrete candidates of an SDE: name, the rule of its moment equations and update.
CD_CANDIDATES = (("cd-ekf", "ekf"), ("cd-ckf", "ckf"))


def _continuous_filter(track: DiscretizedTrack, h: Model, R: np.ndarray, rule: str,
                       settings: Mapping[str, Any] | None = None) -> ContinuousDiscreteKalmanFilter:
    """The continuous-discrete filter of ``track``'s SDE by ``rule`` ("ekf", "ckf", ...), with
    the integrator's ``settings`` (rtol, atol, max_evaluations, square_root)."""
    return ContinuousDiscreteKalmanFilter(track.sde, h, R, rule, **dict(settings or {}))


def _continuous_options(track: DiscretizedTrack, h: Model, R: np.ndarray, tol: float, mon: float, lin: float,
                        small: str) -> list[_Option]:
    """The continuous-discrete candidates of the SDE (module notes): the CD-EKF always, the
    CD-CKF where the MoN brings in the sigma-point filters; their cost is their own
    ``step_cost()``."""
    out = []
    flow = (f"the flow's MoN over the longest interval ({track.longest:.3g}) from x0 {track.flow_mon:.3g}, the "
            f"discretisation's {track.substeps} sub-step(s) not used")
    for name, rule in CD_CANDIDATES:
        flt = _continuous_filter(track, h, R, rule)
        what = (f"the SDE's moment ODEs integrated between measurements (adaptive RK45, rtol {flt.rtol:g}) by "
                f"{'TT1' if rule == 'ekf' else rule.upper() + ' points'}, no discretisation; {flow}")
        keep = rule == "ekf" or mon > lin
        why = what if rule == "ekf" else (f"the MoN {mon:.3g} > sqrt(2) tol: {what}" if keep else
                                          small + f", at a higher cost ({what})")
        out.append(_Option(name, (lambda flt=flt: flt), {"transform": rule, "rtol": flt.rtol, "atol": flt.atol},
                           flt.step_cost(), keep, why))
    return out


def _mode(m: Any, i: int, Q: np.ndarray) -> tuple[Model, np.ndarray]:
    """``modes[i]``: a Model (with the Q of f) or a (Model, Q) pair."""
    if isinstance(m, Model):
        return m, Q
    if isinstance(m, tuple) and len(m) == 2 and isinstance(m[0], Model):
        return m[0], np.asarray(m[1], dtype=float)
    raise ArgumentTypeError(f"modes[{i}] must be a Model (a transition) or a (Model, Q) pair, got {plain_repr(m)}")


def _little_process_noise(f: Model, Q: np.ndarray, P0: np.ndarray) -> bool:
    """Whether Q is small against the prior (mean eigenvalue of P0⁻¹ Q below
    :data:`PF_REGULARISE_BELOW`) or singular: then the particle filter is regularised."""
    Q = np.asarray(Q, dtype=float)
    if np.linalg.eigvalsh(Q)[0] <= 0:
        return True
    if f.n_v or Q.shape != P0.shape:
        return False
    try:
        return float(np.trace(np.linalg.solve(P0, Q))) / len(Q) < PF_REGULARISE_BELOW
    except np.linalg.LinAlgError:
        return False


# --------------------------------------------------------------------------- the MoN along the track
def _mon_steps(K: int) -> np.ndarray:
    return np.unique(np.linspace(0, K - 1, min(K, MON_STEPS)).round().astype(int))


def _mon(model: Model, m: np.ndarray, C: np.ndarray, v: Gaussian | None) -> float:
    """The MoN (W^full, TT2) of ``model`` at N(m, C); NaN where C is unusable."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return float(nonlinearity(model, Gaussian(m, 0.5 * (C + C.T)), v, weight="full", transform=TT2()).value)
        except (SymmonError, np.linalg.LinAlgError, ValueError, FloatingPointError):
            return float("nan")


def _track_mon(model: Model, means: np.ndarray, covs: np.ndarray, v: Gaussian | None, ks: np.ndarray) -> float:
    """The largest MoN of ``model`` at N(means[k], covs[k]) over the steps ``ks`` (NaN ignored; NaN if all are)."""
    vals = [_mon(model, means[k], covs[k], v) for k in ks]
    finite = [x for x in vals if np.isfinite(x)]
    return max(finite) if finite else float("nan")


def _errors(x: np.ndarray, xs: np.ndarray, angle_states: Sequence[int]) -> np.ndarray:
    e = xs - x
    if angle_states:
        idx = list(angle_states)
        e[..., idx] = wrap_angle(e[..., idx])
    return e


def _ill_conditioned(P: np.ndarray) -> bool:
    d = np.sqrt(np.clip(np.einsum("...ii->...i", P), 1e-300, None))
    corr = P / (d[..., :, None] * d[..., None, :])
    with np.errstate(all="ignore"):
        c = np.linalg.cond(corr)
    return bool(np.any(~(c < ILL_CONDITIONED)))


# --------------------------------------------------------------------------- checks
def _check(f: Any, h: Any, x0: Any, steps: Any, tol: Any, runs: Any, budget: Any, seed: Any) -> None:
    for name, m in (("f", f), ("h", h)):
        if not isinstance(m, Model):
            raise ArgumentTypeError(f"{name} must be a symmon.Model, got {plain_repr(m)}")
    if not isinstance(x0, Gaussian):
        raise ArgumentTypeError(f"x0 must be a Gaussian prior (symmon.Gaussian), got {type(x0).__name__}")
    for name, v, least in (("steps", steps, 2), ("runs", runs, 2)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
            raise ArgumentError(f"{name} must be an integer of at least {least}, got {plain_repr(v)}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 1:
        raise ArgumentError(f"tol must be a number in (0, 1), got {plain_repr(tol)}")
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (int, float))
                               or not np.isfinite(budget) or budget <= 0):
        raise ArgumentError(f"budget must be a positive number of seconds (or None), got {plain_repr(budget)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArgumentError(f"seed must be a non-negative integer, got {plain_repr(seed)}")


#: The settings a continuous-discrete candidate given by the caller may have.
_CD_SETTINGS = ("rtol", "atol", "max_step", "max_evaluations", "square_root")


def _given(candidates: Sequence[Any], f: Model, h: Model, Q: np.ndarray, R: np.ndarray, tol: float,
           track: DiscretizedTrack | None = None) -> list[_Option]:
    """The caller's ``candidates``: registered names or (name, settings) pairs, all kept; with
    an SDE (``track``) also ``"cd-"`` and a rule (``"cd-ekf"``, ``"cd-ckf"``, ``"cd-ukf"``,
    ``"cd-ghkf"``), its continuous-discrete filter."""
    out = []
    for i, c in enumerate(candidates):
        name, settings = (c, {}) if isinstance(c, str) else c if (
            isinstance(c, tuple) and len(c) == 2 and isinstance(c[0], str) and isinstance(c[1], Mapping)) else (None, None)
        if name is None:
            raise ArgumentTypeError(f"candidates[{i}] must be a filter name (e.g. 'ukf') or a (name, settings) pair, "
                                    f"got {plain_repr(c)}")
        settings = dict(settings)
        if name.startswith("cd-"):
            if track is None:
                raise ArgumentError(f"candidates[{i}] = {name!r} is a continuous-discrete filter: it needs an SDE as f")
            unknown = sorted(set(settings) - set(_CD_SETTINGS))
            if unknown:
                raise ArgumentError(f"candidates[{i}] = {name!r}: unknown settings {unknown}; known: "
                                    f"{', '.join(_CD_SETTINGS)}")
            flt = _continuous_filter(track, h, R, name[3:], settings)  # an unknown rule: SymmonError
            out.append(_Option(name if not any(o.name == name for o in out) else f"{name} #{i}",
                               (lambda flt=flt: flt), settings, flt.step_cost(), True, "given by the caller",))
            continue
        entry = filter_entry(name)  # an unknown name: SymmonError listing the known ones
        flt = make_filter(entry.name, f, h, Q, R, tol=tol, settings=settings)
        out.append(_Option(entry.name if not any(o.name == entry.name for o in out) else f"{entry.name} #{i}",
                           (lambda flt=flt: flt), settings, flt.step_cost(), True, "given by the caller"))
    if not out:
        raise ArgumentError("candidates is empty")
    return out


# --------------------------------------------------------------------------- the pilot
def _run(flt: Filter, ys: np.ndarray, xs: np.ndarray, x0: Gaussian, params: dict | None
         ) -> tuple[Any, float, list[str]]:
    """``flt`` over the bank ``ys`` with the truth ``xs``: (result, seconds, warnings)."""
    keep = tuple(k for k in ("x", "P", "x_pred", "P_pred", "nis") if k in flt.keepable)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        res = flt.filter(ys, x0, keep=keep, params=params, x_true=xs)
        seconds = time.perf_counter() - t0
    return res, seconds, sorted({f"{w.category.__name__}: {w.message}" for w in caught})


def _pilot_row(opt: _Option, xs: np.ndarray, ys: np.ndarray, x0: Gaussian, params: dict | None, scale: np.ndarray,
               models: tuple[Model, Model, Gaussian | None, Gaussian | None], ks: np.ndarray, notes: list[str]
               ) -> tuple[FilterCandidate, Filter | None]:
    """One candidate's pilot: its row (and the built filter)."""
    Rr, K, n = xs.shape
    base = dict(name=opt.name, settings=opt.settings, kept=True, reason=opt.reason, cost=opt.cost)
    try:
        flt = opt.build()
    except SymmonError as exc:
        return FilterCandidate(method=opt.name, **{**base, "kept": False, "reason": f"cannot be built: {exc}"}), None
    try:
        res, seconds, caught = _run(flt, ys, xs, x0, params)
    except (SymmonError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return FilterCandidate(method=flt.method, **base, credible=False, credibility=0.0,
                               failure=f"a run failed ({type(exc).__name__}: {exc})"), flt
    notes += [f"{opt.name}: {w}" for w in caught]
    e = _errors(np.asarray(res.x, dtype=float), xs, res.angle_states)
    rmse_states = np.sqrt(np.mean(e**2, axis=(0, 1)))
    rmse = float(np.sqrt(np.mean(np.sum((e / scale) ** 2, axis=-1)) / n))
    nees = np.asarray(res.nees(), dtype=float)
    anees = float(nees.mean())
    run_nees = nees.reshape(Rr, -1).mean(axis=1) if nees.size else None
    interval = tuple(float(q) / Rr for q in stats.chi2.ppf([0.025, 0.975], Rr * n))
    lo, hi = ANEES_BAND[0] * n, ANEES_BAND[1] * n
    failure = ""
    if not np.isfinite(e).all() or (res.P is not None and not np.isfinite(res.P).all()):
        failure = "non-finite estimates"
    elif not lo <= anees <= hi:
        failure = f"ANEES {anees:.3g} {'>' if anees > hi else '<'} {hi if anees > hi else lo:.3g}"
    try:
        flagged = res.credibility.fraction
    except SymmonError:
        flagged = None
    ess = getattr(res, "ess", None)  # a particle filter's: a run whose weights fell onto about one particle
    collapsed = None if ess is None else int((np.asarray(ess).reshape(Rr, -1).min(axis=1) < COLLAPSED_ESS).sum())
    f_model, h_model, v_f, v_h = models
    mon_f = mon_h = None
    if res.x is not None and res.P is not None:
        mon_f = _track_mon(f_model, res.x[0], _first(res.P), v_f, ks)
        xp, Pp = (res.x_pred, res.P_pred) if res.x_pred is not None and res.P_pred is not None else (res.x, res.P)
        mon_h = _track_mon(h_model, xp[0], _first(Pp), v_h, ks)
    return FilterCandidate(method=flt.method, **base, mon_f=mon_f, mon_h=mon_h, rmse=rmse, rmse_states=rmse_states,
                           anees=anees, anees_interval=interval, credible=not failure, failure=failure,
                           flagged=flagged, seconds_per_step=seconds / (Rr * K), run_nees=run_nees, runs=Rr,
                           collapsed=collapsed,
                           credibility=0.0 if failure == "non-finite estimates" or run_nees is None
                           else predictive_credibility(run_nees, n)), flt


def predictive_credibility(run_nees: Any, n: int, *, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> float:
    """The probability that a fresh bank of as many runs would be credible, by bootstrap over the runs.

    The time-mean ANEES of a bank is the mean of its runs' time-mean NEES; a pilot's verdict
    on it rests on its R runs, and one divergent run among them carries it.  This draws
    ``samples`` banks of R runs with replacement from the pilot's runs and returns the share
    whose time-mean ANEES lies in the credible band [0.3 n, 1.5 n] (:data:`ANEES_BAND`): near
    1 when every run is consistent, well below when the verdict hangs on a few runs (one run
    with a huge NEES among 64 is left out of only (1 − 1/64)^64 ≈ 37 % of the banks).  It
    cannot see a divergence the pilot never met: a failure rarer than about 1/R may be absent
    from R runs (``docs/select.md``).

    Parameters
    ----------
    run_nees : array_like, shape (R,)
        Each run's time-mean NEES (unitless), R >= 1.
    n : int
        The state dimension.
    samples : int, default :data:`BOOTSTRAP_SAMPLES`
        Bootstrap banks (at least 1).
    seed : int, default 0
        Of the bootstrap: the same runs, the same probability.

    Returns
    -------
    float
        In [0, 1]; 0 when a run's NEES is not finite (its covariance collapsed).

    Raises
    ------
    ArgumentError
        For an empty or not one-dimensional ``run_nees``, or ``n`` or ``samples`` below 1.

    Examples
    --------
    >>> import numpy as np
    >>> predictive_credibility(np.full(64, 2.0), 2)
    1.0
    >>> predictive_credibility(np.r_[np.full(63, 2.0), 1000.0], 2) < 0.5
    True
    """
    v = np.asarray(run_nees, dtype=float)
    if v.ndim != 1 or v.size == 0:
        raise ArgumentError(f"run_nees must be a non-empty 1-D array of per-run time-mean NEES, got shape {v.shape}")
    for name, k in (("n", n), ("samples", samples)):
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ArgumentError(f"{name} must be a positive integer, got {plain_repr(k)}")
    if not np.isfinite(v).all():
        return 0.0
    lo, hi = ANEES_BAND[0] * n, ANEES_BAND[1] * n
    rng = np.random.default_rng(int(seed))
    R, hits, chunk = v.size, 0, max(1, 2_000_000 // v.size)
    for start in range(0, int(samples), chunk):
        m = v[rng.integers(0, R, (min(chunk, int(samples) - start), R))].mean(axis=1)
        hits += int(np.count_nonzero((m >= lo) & (m <= hi)))
    return hits / int(samples)


def lost_track_threshold(n: int) -> float:
    """The NEES (unitless) at a run's last step above which an n-state filter has lost its track.

    The χ²_n quantile of 1 − :data:`LOST_ALPHA`: one step's NEES of a consistent filter is
    χ²_n, so a consistent filter loses a track by this bound once in 1/LOST_ALPHA runs.  The
    last step's, not the run's time mean: the time mean of correlated steps has no such
    distribution, and a bound on it as nK independent terms flags consistent filters
    (``docs/select.md``); at the last step a filter that gave the truth's mode away (a
    mirror mode, a diverged track) has not recovered it.

    Examples
    --------
    >>> round(lost_track_threshold(2), 1)
    27.6
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ArgumentError(f"n must be a positive integer, got {plain_repr(n)}")
    return float(stats.chi2.isf(LOST_ALPHA, int(n)))


def tail_weights(x0s: Any, x0: Gaussian, *, share: float = TAIL_SHARE, width: float = TAIL_WIDTH) -> np.ndarray:
    """The weights p/((1 − share) p + share q) of initial truths drawn from the defensive mixture.

    p is the prior ``x0`` = N(x̄0, P0), q = N(x̄0, width² P0) (on P0's range where it is
    singular); the weights lie in (0, 1/(1 − share)] and their mean over the mixture's draws
    is 1 (Hesterberg 1995, defensive importance sampling).

    Parameters
    ----------
    x0s : array_like, shape (R, n)
        The initial truths.
    x0 : Gaussian
        The prior.
    share : float, default :data:`TAIL_SHARE`
        In [0, 1).
    width : float, default :data:`TAIL_WIDTH`
        At least 1.

    Returns
    -------
    ndarray, shape (R,)

    Examples
    --------
    >>> import numpy as np
    >>> from symmon.core.gaussian import Gaussian
    >>> w = tail_weights(np.array([[0.0], [4.0]]), Gaussian([0.0], [[1.0]]))
    >>> bool(w[0] > 1.0 > w[1])
    True
    """
    if not 0.0 <= float(share) < 1.0:
        raise ArgumentError(f"share must lie in [0, 1), got {plain_repr(share)}")
    if not float(width) >= 1.0:
        raise ArgumentError(f"width must be at least 1, got {plain_repr(width)}")
    m, P0 = np.asarray(x0.mean, dtype=float), np.asarray(x0.cov, dtype=float)
    X = np.atleast_2d(np.asarray(x0s, dtype=float))
    if X.shape[-1] != m.size:
        raise ArgumentError(f"x0s must have {m.size} columns (the prior's dimension), got shape {X.shape}")
    d = X - m
    d2 = np.einsum("ri,ij,rj->r", d, np.linalg.pinv(P0, hermitian=True), d)
    r = int(np.linalg.matrix_rank(P0, hermitian=True))
    c2 = float(width) ** 2
    log_q_over_p = -0.5 * r * math.log(c2) + 0.5 * d2 * (1.0 - 1.0 / c2)
    return 1.0 / ((1.0 - float(share)) + float(share) * np.exp(np.minimum(log_q_over_p, 700.0)))


def _tail_bank(f: Model, h: Model, Q: np.ndarray, R: np.ndarray, x0: Gaussian, K: int, runs: int,
               params: dict | None, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tail look's runs (module notes): (xs, ys, their initial truths, their weights)."""
    m0, P0 = np.asarray(x0.mean, dtype=float), np.asarray(x0.cov, dtype=float)
    mix = GaussianMixture.from_components([1.0 - TAIL_SHARE, TAIL_SHARE], [x0, Gaussian(m0, TAIL_WIDTH**2 * P0)])
    x0s = mix.sample(runs, np.random.default_rng(seed))  # simulate's first draws, from the same seed
    xs, ys = simulate(f, h, Q, R, mix, K, runs=runs, params=params, seed=seed)
    return xs, ys, x0s, tail_weights(x0s, x0)


def _last_nees(flt: Filter | None, xs: np.ndarray, ys: np.ndarray, x0: Gaussian, params: dict | None
               ) -> np.ndarray | None:
    """Each run's NEES at the last step (R,), or None when the filter raised.

    A run whose last covariance is singular or not finite (a particle cloud collapsed onto a
    point), or whose estimate is not finite, has lost its track: its NEES is +inf."""
    if flt is None:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = flt.filter(ys, x0, keep=("x", "P"), params=params)
    except (SymmonError, np.linalg.LinAlgError, FloatingPointError):
        return None
    R_ = xs.shape[0]
    x = np.asarray(res.x, dtype=float).reshape(R_, -1, xs.shape[-1])[:, -1]
    P = np.asarray(res.P, dtype=float)
    P = P.reshape(R_, -1, *P.shape[-2:])[:, -1] if P.ndim == 4 else np.broadcast_to(P[-1], (R_,) + P.shape[-2:])
    e = _errors(x[:, None], xs[:, -1:], res.angle_states)[:, 0]
    return np.array([_nees_or_inf(e[r], P[r]) for r in range(R_)])


def _nees_or_inf(e: np.ndarray, P: np.ndarray) -> float:
    """eᵀ P⁻¹ e as the filters' NEES computes it (:func:`~symmon.filters.results.quadratic_forms`),
    +inf where e is not finite or P is singular or not finite: a lost track."""
    if not np.isfinite(e).all():
        return math.inf
    try:
        v = float(quadratic_forms(np.asarray(e, dtype=float), np.asarray(P, dtype=float))[()])
    except (SingularMatrixError, NonFiniteError):
        return math.inf
    return v if math.isfinite(v) else math.inf


def _first(P: np.ndarray) -> np.ndarray:
    """The covariances (K, n, n) of the first run of a bank's (R, K, n, n), or those the runs share."""
    return P[0] if P.ndim == 4 else P


def _choose(rows: list[FilterCandidate]) -> tuple[FilterCandidate, bool, str]:
    """The choice (module notes): (row, credible, the recommendation)."""
    ran = [(i, r) for i, r in enumerate(rows) if r.kept and r.rmse is not None and np.isfinite(r.rmse)]
    credible = [(i, r) for i, r in ran if r.credible]
    steady = [(i, r) for i, r in credible if not r.at_risk]
    risky = [r.name for _, r in credible if r.at_risk]
    if steady:
        credible = steady
    if credible:
        best = min(credible, key=lambda t: (t[1].rmse, t[0]))[1]
        within = [(r.cost, i, r) for i, r in credible if r.rmse <= (1 + RMSE_MARGIN) * best.rmse]
        choice = min(within, key=lambda t: (t[0], t[1]))[2]
        if choice is best:
            why = (f"the most accurate credible filter (RMSE {best.rmse:.4g}), and the cheapest within "
                   f"{RMSE_MARGIN:.0%} of it ({choice.cost:,d} evaluations per step)")
        else:
            why = (f"the cheapest credible filter ({choice.cost:,d} evaluations per step) whose RMSE {choice.rmse:.4g} "
                   f"is within {RMSE_MARGIN:.0%} of the best credible one ({best.name}: {best.rmse:.4g}, "
                   f"{best.cost:,d} evaluations per step)")
        if risky and steady:
            why += (f"; at risk, so not compared: {', '.join(risky)} (credible in the pilot; the table's verdicts "
                    "say why)")
        elif risky:
            why += ("; every credible candidate is at risk (the table's verdicts say why): a rare run may diverge, "
                    "check it online")
        return choice, True, f"{choice.name} ({choice.method}): {why}"
    if ran:
        choice = min(ran, key=lambda t: (t[1].rmse, t[0]))[1]
        return choice, False, (f"none of the candidates is credible on this track; {choice.name} ({choice.method}) "
                               f"is the most accurate (RMSE {choice.rmse:.4g}, ANEES {choice.anees:.3g}): do not "
                               "trust its covariance")
    return rows[0], False, "none of the candidates ran on this track: every one failed"


# --------------------------------------------------------------------------- the advice
def advise_filter(f: Model | SDE, h: Model, Q: Any, R: Any, x0: Gaussian, steps: int | None, params: dict | None = None, *,
                  modes: Sequence[Any] | None = None, tol: float = DEFAULT_TOL, runs: int = 64,
                  budget: float | None = None, seed: int = 0,
                  candidates: Sequence[str | tuple[str, Mapping[str, Any]]] | None = None,
                  times: Any = None, t0: float = 0.0) -> FilterAdvice:
    """The filter for a whole track: candidates pruned by the MoN along it, chosen by a pilot study.

    Module notes: the MoN along the track, the candidates and their pruning, the pilot, the
    choice (the cheapest credible candidate whose RMSE is within 10 % of the best credible
    one), the cost, and ``budget``.  :func:`symmon.advise` answers the transform question
    for one prior; this answers the filter question.

    Parameters
    ----------
    f, h : Model
        The dynamics (n → n) and the measurement (n → n_y), as for
        :class:`~symmon.NonlinearKalmanFilter`.  f may be an :class:`~symmon.SDE` (with
        ``Q=None``, and ``times`` or ``params["dt"]``): it is discretised over the intervals,
        its sub-steps chosen by the MoN within ``tol``
        (:func:`symmon.filters.sde_advice.discretize_track`), the discrete candidates filter
        that model, its ``dt`` a per-step parameter (a note says which discretisation), and
        the SDE's continuous-discrete filters join them (module notes, "An SDE as f").
    Q, R : array_like
        Process and measurement noise covariances.
    x0 : Gaussian
        The prior of x_0: the truth of each pilot run is drawn from it, and every filter starts from it.
    steps : int
        K, the steps of a track (at least 2).
    params : dict, optional
        The models' parameter values by name, as for ``filter`` (a number, one per step, or
        one per run and step); the MoN uses each parameter's mean value.
    modes : sequence of Model or (Model, Q), optional
        Alternative transitions: an IMM over f and these joins the candidates.
    tol : float, default 0.01
        The unitless moment tolerance of :func:`symmon.advise`: the MoN above √2 · tol
        brings in the sigma-point filters and the Gaussian-sum filter.
    runs : int, default 64
        The pilot's simulated tracks (at least 2); the choice's second look runs on up to
        :data:`SECOND_LOOK` times as many more.
    budget : float, optional
        Seconds for the pilot: fewer runs when the cost estimate exceeds it, and a grown
        particle filter or a second look only where the estimate of what is left holds them
        (module notes).
    seed : int, default 0
        Of the simulated tracks (and of the particle filter): the same seed, the same advice.
    candidates : sequence of str or (str, dict), optional
        Filters to compare instead of the menu: registered names (``"ukf"``) or
        (name, settings) pairs (``("pf", {"particles": 500})``); all are run, whatever the MoN.
        With an SDE as f also ``"cd-"`` and a rule (``"cd-ekf"``, ``"cd-ckf"``, ...), with
        the settings ``rtol``, ``atol``, ``max_step``, ``max_evaluations``, ``square_root``.
    times, t0 : array_like and float, optional
        With an SDE as f: the measurement times t_1 < … < t_K after ``t0`` (the time of x0).

    Returns
    -------
    FilterAdvice
        ``print(advice)`` shows the table and one recommendation; ``advice.filter`` is the
        chosen filter, built.

    Raises
    ------
    ArgumentError, ArgumentTypeError
        A bad argument, named.
    SymmonError
        Models that do not fit together, bad covariances, an unknown candidate, or a
        simulated truth that diverges (:func:`symmon.simulate`).

    Examples
    --------
    >>> import numpy as np, sympy as sp, symmon as sm
    >>> p, v = sp.symbols("p v")
    >>> f = sm.Model([p, v], [p + v, v])
    >>> h = sm.Model([p, v], [p])
    >>> a = sm.advise_filter(f, h, 0.01 * np.eye(2), [[1.0]], sm.Gaussian([0.0, 1.0], np.eye(2)), 20, runs=16)
    >>> a.choice, a.credible
    ('kf', True)
    """
    track = _sde_track(f, Q, x0, steps, params, times, t0, tol)
    if track is not None:  # an SDE: discretised over the intervals (symmon.filters.sde_advice)
        f, Q, steps, params = track.f, track.Q, track.steps, track.params
    _check(f, h, x0, steps, tol, runs, budget, seed)
    tol, K = float(tol), int(steps)
    Q, R = np.atleast_2d(np.asarray(Q, dtype=float)), np.atleast_2d(np.asarray(R, dtype=float))
    n = f.n_u
    xs_all, ys_all = simulate(f, h, Q, R, x0, K, runs=int(runs), params=params, seed=int(seed))
    notes: list[str] = [] if track is None else [
        f"the SDE is discretised by {track.method!r} with {track.substeps} sub-step(s) per interval (the MoN of a "
        f"sub-step within tol from x0: {track.substep_mon:.3g}; of the flow over the longest interval "
        f"{track.longest:.3g}: {track.flow_mon:.3g}); its filters take params={{'dt': intervals}}, the cd- rows "
        "integrate the SDE's moment equations (params={'dt': intervals} or times=)"]
    P0 = np.asarray(x0.cov, dtype=float)
    scale = np.sqrt(np.diag(P0)).copy()
    spread = xs_all.reshape(-1, n).std(axis=0)
    scale[~(scale > 0)] = np.where(spread > 0, spread, 1.0)[~(scale > 0)]

    # The models for the MoN: parameters at their mean values, noises as N(0, Q) and N(0, R).
    mean_params = None if not params else {k: float(np.mean(v)) for k, v in params.items()}

    def own(model: Model) -> Model:
        if not mean_params or not model.params:
            return model
        names = {str(s) for s in model.params}
        return with_param_values(model, {k: v for k, v in mean_params.items() if k in names})

    f_m, h_m = own(f), own(h)
    v_f = Gaussian(np.zeros(f.n_v), Q) if f.n_v else None
    v_h = Gaussian(np.zeros(h.n_v), R) if h.n_v else None
    ks = _mon_steps(K)

    # The screening: the EKF (else the UKF) on the first runs; the MoN at its prior and at the truth's spread.
    Rs = min(int(runs), SCREENING_RUNS)
    xs_s, ys_s = xs_all[:Rs], ys_all[:Rs]
    screen = None
    for name in ("ekf", "ukf"):
        try:
            flt = make_filter(name, f, h, Q, R, tol=tol)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                screen = flt.filter(ys_s, x0, keep=("x", "P", "x_pred", "P_pred"), params=_sliced(params, Rs, runs))
            break
        except (SymmonError, np.linalg.LinAlgError):
            continue
    if screen is not None:
        e_post = _errors(np.asarray(screen.x), xs_s, screen.angle_states)
        e_pred = _errors(np.asarray(screen.x_pred), xs_s, screen.angle_states)
        C_post = np.einsum("rki,rkj->kij", e_post, e_post) / Rs
        C_pred = np.einsum("rki,rkj->kij", e_pred, e_pred) / Rs
        mon = {"f": {"prior": _track_mon(f_m, screen.x[0], screen.P[0], v_f, ks),
                     "truth": _track_mon(f_m, xs_s[0], C_post, v_f, ks)},
               "h": {"prior": _track_mon(h_m, screen.x_pred[0], screen.P_pred[0], v_h, ks),
                     "truth": _track_mon(h_m, xs_s[0], C_pred, v_h, ks)}}
        ill = _ill_conditioned(np.asarray(screen.P)) or _ill_conditioned(np.asarray(screen.P_pred))
    else:
        notes.append("the screening EKF and UKF both failed: the MoN is at the truth's spread over the runs only")
        C = np.einsum("rki,rkj->kij", xs_s - xs_s.mean(0), xs_s - xs_s.mean(0)) / Rs
        m = xs_s.mean(0)
        mon = {"f": {"prior": float("nan"), "truth": _track_mon(f_m, m, C, v_f, ks)},
               "h": {"prior": float("nan"), "truth": _track_mon(h_m, m, C, v_h, ks)}}
        ill = True
    mon_f = float(np.nanmax([mon["f"]["prior"], mon["f"]["truth"], 0.0]))
    mon_h = float(np.nanmax([mon["h"]["prior"], mon["h"]["truth"], 0.0]))
    if candidates is None:
        options = candidate_menu(f, h, Q, R, P0, mon_f, mon_h, tol, modes=modes, ill_conditioned=ill,
                                 seed=int(seed), track=track)
    else:
        if modes:
            raise ArgumentError("give modes or candidates, not both (an IMM is built from modes)")
        options = _given(candidates, f, h, Q, R, tol, track)

    # The pilot's runs: as many as the budget's cost estimate allows.
    per_run = _estimate(1, K, [o for o in options if o.kept])
    Rp = int(runs)
    if budget is not None:
        Rp = int(min(int(runs), max(MIN_RUNS, math.floor(budget / per_run) if per_run > 0 else int(runs))))
        if Rp * per_run > budget:
            notes.append(f"even the fewest runs ({MIN_RUNS}) are estimated at {Rp * per_run:.3g} s > budget {budget:g} s")
    xs, ys = xs_all[:Rp], ys_all[:Rp]
    pv = _sliced(params, Rp, runs)
    rows: list[FilterCandidate | None] = [None] * len(options)
    built: dict[str, Filter] = {}

    def pilot(i: int) -> None:
        row, flt = _pilot_row(options[i], xs, ys, x0, pv, scale, (f_m, h_m, v_f, v_h), ks, notes)
        rows[i] = row
        if flt is not None:
            built[row.name] = flt

    for i, o in enumerate(options):
        if o.kept:
            pilot(i)
        else:
            rows[i] = FilterCandidate(name=o.name, method=o.name, settings=o.settings, kept=False, reason=o.reason,
                                      cost=o.cost)
    if not any(r.kept and r.credible and not r.at_risk for r in rows):
        again = [i for i, o in enumerate(options) if not o.kept and o.readmit]
        why = ("no kept candidate was credible" if not any(r.kept and r.credible for r in rows) else
               "every credible kept candidate was at risk")
        if again:
            notes.append(f"{why}: the pruned " + ", ".join(options[i].name for i in again) + " ran too")
        for i in again:
            options[i] = dataclasses.replace(options[i], kept=True, reason=options[i].reason + f"; run as {why}")
            pilot(i)
    spent = Rp * per_run

    def affordable(opts: Sequence[_Option], R_: int) -> bool:
        """Whether R_ runs of the options ``opts`` fit in what is left of ``budget`` (by the estimate)."""
        return budget is None or spent + _estimate(R_, K, opts) <= budget

    # The particle filter grown where the pilot (or the second look) found it not credible or at risk.
    menu_pf = next((o for o in options if o.name == "pf"), None)
    most = 0 if candidates is not None or menu_pf is None else \
        int(menu_pf.settings["particles"]) * PF_GROWTH ** PF_GROWTH_STEPS

    pilot_spent = 0.0

    def grow(i: int) -> int | None:
        """Pilot the particle filter of row i with PF_GROWTH times its particles: its row's index, or None."""
        nonlocal spent, pilot_spent
        row, o = rows[i], options[i]
        if not o.name.startswith("pf") or "particles" not in o.settings:
            return None
        N = PF_GROWTH * int(o.settings["particles"])
        if N > most:
            return None
        name = f"pf (N={N})"
        had = next((k for k, p in enumerate(options) if p.name == name), None)
        if had is not None:  # grown and piloted before (the second look came back to a smaller one)
            return had
        settings = {**o.settings, "particles": N}
        why = ("not credible" if not row.credible else "at risk") + f" with {o.settings['particles']} particles"
        grown = _Option(name, (lambda st=settings: make_filter("pf", f, h, Q, R, tol=tol, settings=st)),
                        settings, 2 * N, True, f"{row.name} {why}: {PF_GROWTH} times the particles")
        if not affordable([grown], Rp):
            notes.append(f"{row.name} was not grown to {N} particles: the budget would not hold")
            return None
        options.insert(i + 1, grown)
        rows.insert(i + 1, None)
        spent += _estimate(Rp, K, [grown])
        pilot_spent += _estimate(Rp, K, [grown])  # a pilot, also where the second look asked for it
        pilot(i + 1)
        return i + 1

    def needed(i: int | None) -> bool:
        """Row i is a particle filter not credible (or at risk) whose accuracy no steady credible
        candidate matches within RMSE_MARGIN: more particles are worth a try."""
        r = rows[i] if i is not None else None
        if r is None or r.rmse is None or not np.isfinite(r.rmse) or (r.credible and not r.at_risk):
            return r is not None and r.rmse is None  # a run raised: try more particles
        return not any(c is not None and c is not r and c.credible and not c.at_risk and c.rmse is not None
                       and c.rmse <= (1 + RMSE_MARGIN) * r.rmse for c in rows)

    i = next((j for j, o in enumerate(options) if o.name == "pf" and rows[j] is not None and rows[j].kept), None)
    while needed(i):
        i = grow(i)
    pilot_spent = spent  # the second look costs at most this, and the growth it asks for (module notes)

    # The tail look: the credible candidates on runs whose truths start in the prior's tail (module notes).
    looking = [j for j, r in enumerate(rows) if r is not None and r.kept and r.credible and r.run_nees is not None]
    tail_options = [options[j] for j in looking]
    tail_runs = 0
    tail = None
    if len(looking) >= 2 and affordable(tail_options, Rp):
        tail_seed = int(np.random.SeedSequence([int(seed), 3]).generate_state(1)[0] % 2**31)
        try:
            tail = _tail_bank(f, h, Q, R, x0, K, Rp, pv, tail_seed)
        except SymmonError as exc:  # a truth from the widened prior left the model's domain
            notes.append(f"no tail look: {exc}")
    if tail is not None:
        spent += _estimate(Rp, K, tail_options)
        tail_runs = Rp
        xs_t, ys_t, _, w_tail = tail
        bound = lost_track_threshold(n)
        failed: set[int] = set()
        for j in looking:
            last = _last_nees(built.get(rows[j].name), xs_t, ys_t, x0, pv)
            if last is None:
                failed.add(j)  # a covariance collapsed: the tail lost, its rate unknown
                notes.append(f"the tail look at {rows[j].name} failed: a run raised or its NEES is not finite")
                continue
            lost = last > bound
            rows[j] = dataclasses.replace(rows[j], lost_rate=float(np.sum(w_tail * lost) / Rp))
        bank = (1 + SECOND_LOOK) * Rp

        def likely(r: FilterCandidate) -> bool:
            return 1.0 - (1.0 - r.lost_rate) ** bank >= LOST_BANK_PROBABILITY

        safe = [j for j in looking if rows[j].lost_rate is not None and not likely(rows[j])]
        for j in looking:
            r = rows[j]
            if j in failed and any(k != j for k in safe):
                rows[j] = dataclasses.replace(r, tail_risk=True)
                notes.append(f"{r.name}: its tail look failed, another candidate's did not; at risk")
            elif r.lost_rate is not None and likely(r) and any(k != j for k in safe):
                rows[j] = dataclasses.replace(r, tail_risk=True)
                notes.append(f"{r.name} loses its track on {r.lost_rate:.2g} of the runs (weighted back to the prior) "
                             f"whose truths start in the prior's tail: a bank of {bank} runs holds a lost track with "
                             f"probability {1.0 - (1.0 - r.lost_rate) ** bank:.2f}; at risk")
        rated = [j for j in looking if rows[j].lost_rate is not None]
        if not safe and rated:
            # No candidate is safe: the relative rule (module notes) puts at risk those that lose
            # tracks LOST_RATE_RATIO times as often as the best, and those whose tail look raised.
            least = min(rows[j].lost_rate for j in rated)
            for j in looking:
                r = rows[j]
                if j in failed:
                    rows[j] = dataclasses.replace(r, tail_risk=True)
                    notes.append(f"{r.name}: its tail look failed, another candidate's did not; at risk")
                elif r.lost_rate >= LOST_RATE_RATIO * least:
                    rows[j] = dataclasses.replace(r, tail_risk=True)
                    notes.append(f"{r.name} loses its track on {r.lost_rate:.2g} of the runs (weighted back to the "
                                 f"prior) whose truths start in the prior's tail, at least {LOST_RATE_RATIO:g} times "
                                 f"the fewest ({least:.2g}); no candidate is safe; at risk")

    # The second look: the choice on more runs, the next one where it fails (module notes).
    looked: set[str] = set()
    extra = 0
    xs2 = ys2 = None
    per_run_params = any(np.ndim(v) == 2 and np.shape(v)[0] == int(runs) for v in (params or {}).values())
    while True:
        final = [r for r in rows if r is not None]
        choice, credible, recommendation = _choose(final)
        if not credible or choice.name in looked or choice.run_nees is None:
            break
        j = next(k for k, r in enumerate(rows) if r is choice)
        R2 = int(min(SECOND_LOOK * Rp, math.floor(pilot_spent / _estimate(1, K, [options[j]]))))
        if R2 < MIN_RUNS or not affordable([options[j]], R2):
            notes.append(f"no second look at {choice.name}: "
                         + ("its runs would cost more than the pilot" if R2 < MIN_RUNS else "the budget would not hold"))
            break
        if per_run_params:
            notes.append("no second look: a parameter has values per run, unknown for runs beyond the pilot's")
            break
        if xs2 is None:
            look_seed = int(np.random.SeedSequence([int(seed), 2]).generate_state(1)[0] % 2**31)
            xs2, ys2 = simulate(f, h, Q, R, x0, K, runs=SECOND_LOOK * Rp, params=params, seed=look_seed)
        looked.add(choice.name)
        extra = max(extra, R2)
        spent += _estimate(R2, K, [options[j]])
        more, _ = _pilot_row(options[j], xs2[:R2], ys2[:R2], x0, params, scale, (f_m, h_m, v_f, v_h),
                             np.array([], dtype=int), notes)
        rows[j] = _merged(choice, more, n)
        if rows[j].credible and not rows[j].at_risk:
            # the choice and its reasons stand as the pilot's runs gave them; its row is over all its runs
            final = [r for r in rows if r is not None]
            recommendation += (f"; a second look on {R2} more runs confirms it (ANEES {rows[j].anees:.3g} "
                               f"over {rows[j].runs} runs)")
            choice = rows[j]
            break
        notes.append(f"the second look ({R2} more runs) found {choice.name} "
                     + ("not credible: " + rows[j].failure if not rows[j].credible else "at risk")
                     + ": the choice was taken again")
        g = j
        while needed(g):
            g = grow(g)
    flt = built.get(choice.name)
    if flt is None:  # nothing ran: the EKF, built
        flt = make_filter("ekf", f, h, Q, R, tol=tol)
    return FilterAdvice(flt, choice.name, credible, recommendation, tuple(final), mon, n, K, Rp, int(runs),
                        None if budget is None else float(budget), spent, tol, int(seed), tuple(notes), extra, tail_runs,
                        None if track is None else _flow_summary(track))


def _sde_track(f: Any, Q: Any, x0: Any, steps: Any, params: Any, times: Any, t0: float, tol: float
               ) -> DiscretizedTrack | None:
    """An SDE as f discretised over the intervals (:func:`~symmon.filters.sde_advice.discretize_track`);
    None for a discrete f, which takes no ``times`` nor ``t0``."""
    if isinstance(f, SDE):
        return discretize_track(f, Q, x0, steps, params, times, t0, tol)
    if times is not None or t0 != 0.0:
        raise ArgumentError("times and t0 apply to an SDE as f; a discrete f takes its intervals as a parameter")
    return None


def _flow_summary(track: DiscretizedTrack) -> dict:
    """:attr:`FilterAdvice.sde`: the discretisation and the MoN of the flow."""
    return {"method": track.method, "substeps": track.substeps, "longest_interval": track.longest,
            "flow_mon": track.flow_mon, "substep_mon": track.substep_mon}


def _merged(a: FilterCandidate, b: FilterCandidate, n: int) -> FilterCandidate:
    """Candidate ``a``'s pilot row and ``b``, its second look on more runs, as one row over both."""
    if b.rmse is None or a.rmse is None:  # the second look failed: a run raised
        return dataclasses.replace(a, credible=False, credibility=0.0,
                                   failure=f"second look: {b.failure}", runs=(a.runs or 0) + (b.runs or 0))
    w = np.array([a.runs, b.runs], dtype=float)

    def mean(u: float | None, v: float | None) -> float | None:
        return None if u is None or v is None else float((w[0] * u + w[1] * v) / w.sum())

    rmse = math.sqrt(mean(a.rmse**2, b.rmse**2))
    states = np.sqrt((w[0] * a.rmse_states**2 + w[1] * b.rmse_states**2) / w.sum())
    anees = mean(a.anees, b.anees)
    Rr = int(w.sum())
    lo, hi = ANEES_BAND[0] * n, ANEES_BAND[1] * n
    failure = next((f"second look: {r.failure}" if r is b else r.failure for r in (a, b)
                    if r.failure == "non-finite estimates"), "")
    if not failure and not lo <= anees <= hi:
        failure = (f"ANEES {anees:.3g} {'>' if anees > hi else '<'} {hi if anees > hi else lo:.3g} "
                   f"over the pilot's and the second look's {Rr} runs")
    run_nees = None if a.run_nees is None or b.run_nees is None else np.concatenate([a.run_nees, b.run_nees])
    return dataclasses.replace(
        a, rmse=rmse, rmse_states=states, anees=anees,
        anees_interval=tuple(float(q) / Rr for q in stats.chi2.ppf([0.025, 0.975], Rr * n)),
        credible=not failure, failure=failure,
        flagged=mean(a.flagged, b.flagged),
        seconds_per_step=mean(a.seconds_per_step, b.seconds_per_step), run_nees=run_nees, runs=Rr,
        collapsed=None if a.collapsed is None or b.collapsed is None else a.collapsed + b.collapsed,
        credibility=0.0 if failure == "non-finite estimates" or run_nees is None
        else predictive_credibility(run_nees, n))


def _sliced(params: dict | None, R: int, runs: int) -> dict | None:
    """``params`` for the first R of ``runs`` runs (a per-run-and-step array sliced)."""
    return _rows(params, 0, R, runs)


# --------------------------------------------------------------------------- the advice confirmed on fresh runs
#: The runs of one batch of :func:`confirm_advice` (about a pilot's worth).
BATCH_RUNS = 20


@dataclass(frozen=True, eq=False)
class Confirmation:
    """The result of :func:`confirm_advice`: every candidate of the menu on fresh runs.

    Attributes
    ----------
    choice : str
        The advised candidate's name.
    rows : tuple of FilterCandidate
        One row per candidate that could be built, over all the fresh runs, in the order of
        the menu (its ``reason`` is the pilot's pruning verdict, its MoN columns None): RMSE
        (unitless), ANEES with its 95 % χ² interval, credible, time per step.  A batch that
        failed (a filter raised) makes the candidate not credible, and its runs are left out
        of the RMSE and ANEES (the ``failure`` says which).
    batches : dict
        Per candidate name, one (runs, rmse, anees, credible) tuple per batch of
        :data:`BATCH_RUNS` runs.
    runs, steps, seed : int
        The fresh runs (never the pilot's: another seed), their steps, and their seed.
    """

    choice: str
    rows: tuple[FilterCandidate, ...]
    batches: dict
    runs: int
    steps: int
    seed: int

    @property
    def advised(self) -> FilterCandidate:
        """The advised candidate's row."""
        return next(r for r in self.rows if r.name == self.choice)

    @property
    def best(self) -> FilterCandidate | None:
        """The credible candidate of the least RMSE; when none is credible, the most accurate
        (:attr:`any_credible` says which); None when none ran."""
        ran = [r for r in self.rows if r.rmse is not None]
        credible = [r for r in ran if r.credible]
        return min(credible or ran, key=lambda r: r.rmse) if ran else None

    @property
    def any_credible(self) -> bool:
        """Whether a candidate is credible on the fresh runs."""
        return any(r.credible for r in self.rows)

    @property
    def ratio(self) -> float:
        """The advised RMSE over :attr:`best`'s (NaN when the advice did not run)."""
        best = self.best
        return float("nan") if best is None or self.advised.rmse is None else float(self.advised.rmse / best.rmse)

    @property
    def confirmed(self) -> bool:
        """The advice is credible and its RMSE within :data:`RMSE_MARGIN` of the best credible one's."""
        return bool(self.advised.credible) and bool(self.ratio <= 1 + RMSE_MARGIN)

    def share(self, name: str | None = None) -> float:
        """The share of the batches in which ``name`` (default: the advice) is credible and
        within :data:`RMSE_MARGIN` of the batch's best credible RMSE."""
        name = self.choice if name is None else name
        hits = 0
        for b, (_, rmse, _, ok) in enumerate(self.batches[name]):
            best = [v[b][1] for v in self.batches.values() if v[b][3]]
            hits += bool(ok and best and rmse <= (1 + RMSE_MARGIN) * min(best))
        return hits / len(self.batches[name])


def confirm_advice(advice: FilterAdvice, f: Model | SDE, h: Model, Q: Any, R: Any, x0: Gaussian,
                   params: dict | None = None, *, modes: Sequence[Any] | None = None, runs: int = 200, seed: int = 1,
                   times: Any = None, t0: float = 0.0) -> Confirmation:
    """Check an advice on fresh runs: the advised filter against every candidate of its menu.

    The menu is the one :func:`advise_filter` built for ``advice`` (the same MoN along the
    track, the same square-root option), every candidate that can be built, pruned or not;
    each runs on ``runs`` tracks simulated with ``seed`` (which must differ from the
    pilot's), in batches of :data:`BATCH_RUNS` runs (the particle filter's seed changes
    per batch), each filter once on one run before (its compilation is not in its time).
    RMSE, ANEES and credibility are those of the pilot (module notes), over all runs and
    per batch.  With an SDE as f (and ``times`` or ``params["dt"]`` as for
    :func:`advise_filter`), the SDE is discretised as the advice did, the fresh runs are
    drawn from that model, and the continuous-discrete candidates are on the menu.

    Parameters
    ----------
    advice : FilterAdvice
        What :func:`advise_filter` answered for the same ``f``, ``h``, ``Q``, ``R``, ``x0``,
        ``params``, ``modes``, ``times`` and ``t0`` (its steps, tol and seed are read from it).
    runs : int, default 200
        Fresh runs (at least 2).
    seed : int, default 1
        Of the fresh runs; not the advice's.
    times, t0 : array_like and float, optional
        With an SDE as f: the measurement times, as for :func:`advise_filter`.

    Returns
    -------
    Confirmation

    Raises
    ------
    ArgumentError
        For ``runs`` < 2 or a ``seed`` that is the pilot's.
    ArgumentTypeError
        For an ``advice`` that is not a FilterAdvice.
    """
    if not isinstance(advice, FilterAdvice):
        raise ArgumentTypeError(f"advice must be a FilterAdvice (advise_filter's answer), got {plain_repr(advice)}")
    K = advice.steps
    track = _sde_track(f, Q, x0, None if times is not None else K, params, times, t0, advice.tol)
    if track is not None:
        if track.steps != K:
            raise ArgumentError(f"the times give {track.steps} steps, the advice has {K}")
        f, Q, params = track.f, track.Q, track.params
    _check(f, h, x0, K, advice.tol, runs, None, seed)
    if int(seed) == advice.seed:
        raise ArgumentError(f"seed must differ from the pilot's ({advice.seed}): fresh runs, not the pilot's")
    Q, R = np.atleast_2d(np.asarray(Q, dtype=float)), np.atleast_2d(np.asarray(R, dtype=float))
    runs = int(runs)
    xs_all, ys_all = simulate(f, h, Q, R, x0, K, runs=runs, params=params, seed=int(seed))
    P0 = np.asarray(x0.cov, dtype=float)
    scale = np.sqrt(np.diag(P0)).copy()
    spread = xs_all.reshape(-1, f.n_u).std(axis=0)
    scale[~(scale > 0)] = np.where(spread > 0, spread, 1.0)[~(scale > 0)]
    mon_f = float(np.nanmax([advice.mon["f"]["prior"], advice.mon["f"]["truth"], 0.0]))
    mon_h = float(np.nanmax([advice.mon["h"]["prior"], advice.mon["h"]["truth"], 0.0]))
    ill = any(c.name.endswith("(square root)") for c in advice.candidates)
    size = min(BATCH_RUNS, runs)
    edges = list(range(0, runs - size + 1, size))[1:] + [runs]
    spans = list(zip([0] + edges[:-1], edges))
    none = np.array([], dtype=int)
    per: dict[str, list[tuple[FilterCandidate, float]]] = {}
    menus = [candidate_menu(f, h, Q, R, P0, mon_f, mon_h, advice.tol, modes=modes, ill_conditioned=ill,
                            seed=int(np.random.SeedSequence([int(seed), b]).generate_state(1)[0] % 2**31),
                            track=track)
             for b in range(len(spans))]
    grown = [c for c in advice.candidates if c.kept and c.name.startswith("pf (N=")]
    for menu in menus:  # the particle filters the advice grew, after the menu's, with each batch's seed
        base = next((o for o in menu if o.name == "pf"), None)
        for c in grown:
            st = {**c.settings, "seed": base.settings["seed"] if base is not None else c.settings.get("seed", 0)}
            menu.append(_Option(c.name, (lambda st=st: make_filter("pf", f, h, Q, R, tol=advice.tol, settings=st)),
                                st, c.cost, True, c.reason))
    for i, opt in enumerate(menus[0]):
        try:
            warm = opt.build()
        except SymmonError:
            continue
        if warm is None:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                warm.filter(ys_all[:1], x0, params=_rows(params, 0, 1, runs))
            except (SymmonError, np.linalg.LinAlgError, FloatingPointError):
                pass
        per[opt.name] = []
        for b, (lo, hi) in enumerate(spans):
            row, _ = _pilot_row(menus[b][i], xs_all[lo:hi], ys_all[lo:hi], x0, _rows(params, lo, hi, runs), scale,
                                (f, h, None, None), none, [])
            per[opt.name].append((row, hi - lo))
    n = f.n_u
    rows, batches = [], {}
    for name, parts in per.items():
        batches[name] = [(w, r.rmse, r.anees, bool(r.credible)) for r, w in parts]
        ran = [(r, v) for r, v in parts if r.rmse is not None]
        if not ran:  # every batch failed
            rows.append(dataclasses.replace(parts[0][0], mon_f=None, mon_h=None))
            continue
        w = np.array([v for _, v in ran], dtype=float)
        rmse = float(np.sqrt(np.sum(w * np.array([r.rmse for r, _ in ran]) ** 2) / w.sum()))
        states = np.sqrt(np.sum(w[:, None] * np.array([r.rmse_states for r, _ in ran]) ** 2, axis=0) / w.sum())
        anees = float(np.sum(w * np.array([r.anees for r, _ in ran])) / w.sum())
        lo, hi = ANEES_BAND[0] * n, ANEES_BAND[1] * n
        failed = [(b, r.failure) for b, (r, _) in enumerate(parts)
                  if r.rmse is None or r.failure == "non-finite estimates"]
        failure = "" if not failed else (f"batch {failed[0][0] + 1} of {len(parts)}: {failed[0][1]}" +
                                          (" (its runs left out of the RMSE and ANEES)" if len(ran) < len(parts) else ""))
        if not failure and not lo <= anees <= hi:
            failure = f"ANEES {anees:.3g} {'>' if anees > hi else '<'} {hi if anees > hi else lo:.3g}"
        flagged = [r.flagged for r, _ in ran]
        Rr = int(w.sum())
        run_nees = None if any(r.run_nees is None for r, _ in ran) else np.concatenate([r.run_nees for r, _ in ran])
        rows.append(dataclasses.replace(
            ran[0][0], mon_f=None, mon_h=None, rmse=rmse, rmse_states=states, anees=anees,
            anees_interval=tuple(float(q) / Rr for q in stats.chi2.ppf([0.025, 0.975], Rr * n)),
            credible=not failure, failure=failure,
            flagged=None if None in flagged else float(np.sum(w * np.array(flagged)) / w.sum()),
            seconds_per_step=float(sum(r.seconds_per_step * v for r, v in ran) / w.sum()), run_nees=run_nees,
            credibility=0.0 if failure or run_nees is None else predictive_credibility(run_nees, n)))
    if advice.choice not in per:
        raise SymmonError(f"the advised filter {advice.choice!r} is not on the menu rebuilt from the advice")
    return Confirmation(advice.choice, tuple(rows), batches, runs, K, int(seed))


def _rows(params: dict | None, lo: int, hi: int, runs: int) -> dict | None:
    """``params`` for the runs lo … hi − 1 of ``runs`` (a per-run-and-step array sliced)."""
    if not params:
        return params
    out = {}
    for k, v in params.items():
        a = np.asarray(v, dtype=float)
        out[k] = a[lo:hi] if a.ndim == 2 and a.shape[0] == runs else v
    return out
