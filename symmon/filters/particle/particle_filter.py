"""The particle filter: sequential importance resampling over the compiled models.

The model is that of :class:`~symmon.NonlinearKalmanFilter`: x_{k+1} = f(x_k, w_k),
y_k = h(x_k, e_k), w_k ~ N(0, Q), e_k ~ N(0, R), the noises additive without noise symbols.
Each of N particles x^i carries a log-weight; a step

1. draws x_k^i from the proposal q(x_k | x_{k−1}^i, y_k): the transition itself (the
   bootstrap filter, Gordon et al. 1993, §3), or N(m^i, Σ^i), the posterior of one EKF or
   UKF step from the particle, N(x_{k−1}^i, 0), with y_k: a Gaussian approximation of the
   optimal proposal p(x_k | x_{k−1}^i, y_k) by local linearisation (Doucet, Godsill &
   Andrieu 2000, §II.D.2; the extended and unscented particle filters of van der Merwe et
   al. 2000, §3–4, run the same per-particle step but start it from a covariance P^i that
   each particle carries, which broadens the proposal beyond the optimal one — exact for a
   linear Gaussian model from P = 0 — and costs N·n² numbers);
2. updates the log-weights by log p(y_k | x_k^i) + log p(x_k^i | x_{k−1}^i) − log q(x_k^i | ·)
   (the last two cancel for the bootstrap proposal; Doucet et al. 2000, eq. (11)), in log
   space, so that no weight underflows;
3. adds log Σ_i W_{k−1}^i exp(increment^i), with W the normalised weights before the step,
   to the log-likelihood: the estimate Σ_k log(mean weight) whose exponential is unbiased
   for the marginal likelihood p(y_1 … y_K) (Del Moral 2004, Thm. 7.4.2; Andrieu, Doucet &
   Holenstein 2010, §4.1);
4. reports the weighted mean and covariance (a circular mean, and deviations wrapped, for
   angle states) and the effective sample size ESS = 1 / Σ_i W_i², and resamples
   (systematic, stratified or multinomial; Douc, Cappé & Moulines 2005) when the ESS falls
   to ``ess_threshold`` · N.

With ``regularise=True``, after each resampling every particle moves by h_opt · L ε,
ε ~ N(0, I), L the Cholesky factor of the weighted covariance before the resampling (the
post-regularised filter of Musso, Oudjane & Le Gland 2001).

**Acting on a collapse.**  The ESS of each step is the filter's own degeneracy flag: below
the floor max(:data:`DEGENERATE_ESS`, ``collapse_fraction`` · N) the cloud is collapsing onto
a few particles (the per-step, earlier form of :meth:`ParticleResult.check_credibility`'s ESS
band: by the time the windowed ESS is below 2 % of N, the weighted covariance that the kernel
spreads the copies by no longer spans the posterior; :data:`COLLAPSE_FRACTION`).
Resampling then only copies those few (the bootstrap move adds the process noise, which
does not spread them when Q is small), so with ``on_collapse`` the filter resamples at such
a step (whatever ``ess_threshold``) and moves the copies by a kernel, with m and C the
weighted mean and covariance before the resampling, L Lᵀ = C and h = h_opt:

- ``"shrink"`` (Liu & West 2001, §10.3.3): x ← m + a (x − m) + h L ε, a = √(1 − h²).  Each
  copy is shrunk towards the mean before its jitter, so the cloud keeps its mean and
  covariance, a² C + h² C = C (in expectation over the resampling and ε; exactly for a cloud
  whose ε have zero mean, unit covariance and no correlation with x − m,
  :func:`shrink_kernel`), where the plain jitter inflates C by (1 + h²) at every collapse;
- ``"jitter"``: x ← x + h L ε, the regularisation's move at the collapsing steps only;
- ``"temper"``, a tempered update (progressive correction, Oudjane & Musso 2000, with the
  moves of an SMC sampler, Del Moral, Doucet & Jasra 2006, §3.3): where the step's likelihood
  would collapse the cloud, it is applied in stages p(y | x)^{δ_1}, p(y | x)^{δ_2}, …,
  δ_1 + δ_2 + … = 1, each δ_j the largest that keeps the ESS at :data:`TEMPER_ESS` · N
  (bisection; Jasra et al. 2011); after each stage the cloud is resampled and moved by
  :data:`TEMPER_MOVES` random-walk Metropolis steps (proposal x + (2.38/√n) L ε, L L ᵀ the
  stage's weighted covariance; Roberts & Rosenthal 2001) invariant for the tempered
  posterior N(x; x̂⁻, P⁻) p(y | x)^{δ_1 + … + δ_j}, with x̂⁻, P⁻ the predicted cloud's
  weighted mean and covariance; the rest of the power re-weights the moved particles, and
  after :data:`TEMPER_STAGES` stages the last takes what remains.  A measurement far in the
  tail of the predicted cloud (a truth several standard deviations out) then draws the
  cloud to it, where a single update leaves all the weight on one particle.  At such a step
  the predicted density is thus taken as its Gaussian moment match (exact from a Gaussian
  prior at the first step, and for a Gaussian predicted density; a kernel that keeps only
  the cloud's moments, as ``"shrink"``, drifts from the tempered posterior stage by stage:
  tests/filters/test_particle_temper.py).  The step's log-likelihood is the sum of the
  stages' log mean weights.  The bootstrap proposal only; this option runs the NumPy
  recursion (the compiled kernel has no staged update).

:attr:`ParticleResult.rejuvenated` says at which steps (``ess`` the ESS of every step, before
the resampling: for ``"temper"``, that of the last stage's weights).

The K bootstrap steps of a run are one call of generated C (:mod:`symmon.filters.particle._kernel`:
the transition and the log-likelihood, the exponentials, sums, mean and ESS, the kept
moments, the resampling walk with its gather, the regularisation; threads over particle
chunks), which draws its normals and uniforms itself (:mod:`symmon.filters.particle._rng`).  The
NumPy loop of :meth:`filter` remains for the EKF/UKF proposals, a measurement noise map
Γ(x) that depends on the state, and while no C is available; it draws from the runs'
NumPy Generators (so the two paths give different particles for a seed, with the same
law; fed the same draws, the same particles: tests/filters/test_particle_kernel.py).  The
EKF/UKF proposal runs the filters' compiled predict + update step
(:mod:`symmon.filters.gaussian.step`) over the particles as a bank, and f and h as compiled C over
all particles of all runs of a step at once
(:meth:`~symmon.compile.CompiledModel.eval_g`).  A missing measurement (NaN) leaves its
component out of the likelihood (a row of NaN: the step only predicts).  Every run of a
bank has its own random stream (``SeedSequence(seed).spawn(runs)``), so run r of a bank is
the same whatever the other runs.

References
----------
N. J. Gordon, D. J. Salmond, A. F. M. Smith, "Novel approach to nonlinear/non-Gaussian
Bayesian state estimation", IEE Proc. F 140(2), 1993. doi:10.1049/ip-f-2.1993.0015
R. van der Merwe, A. Doucet, N. de Freitas, E. Wan, "The unscented particle filter",
Tech. Rep. CUED/F-INFENG/TR 380, Cambridge University, 2000 (NIPS 13, 2001).
A. Doucet, S. Godsill, C. Andrieu, "On sequential Monte Carlo sampling methods for Bayesian
filtering", Statistics and Computing 10, 2000. doi:10.1023/A:1008935410038
R. Douc, O. Cappé, E. Moulines, "Comparison of resampling schemes for particle filtering",
ISPA 2005. doi:10.1109/ISPA.2005.195385
P. Del Moral, *Feynman–Kac Formulae*, Springer, 2004.
C. Andrieu, A. Doucet, R. Holenstein, "Particle Markov chain Monte Carlo methods", JRSS B
72(3), 2010. doi:10.1111/j.1467-9868.2009.00736.x
C. Musso, N. Oudjane, F. Le Gland, "Improving regularised particle filters", in A. Doucet,
N. de Freitas, N. Gordon (eds.), *Sequential Monte Carlo Methods in Practice*, Springer,
2001, ch. 12. doi:10.1007/978-1-4757-3437-9_12
N. Oudjane, C. Musso, "Progressive correction for regularized particle filters", Proc. 3rd
Int. Conf. on Information Fusion (FUSION 2000), 2000.
P. Del Moral, A. Doucet, A. Jasra, "Sequential Monte Carlo samplers", JRSS B 68(3), 2006.
doi:10.1111/j.1467-9868.2006.00553.x
A. Jasra, D. A. Stephens, A. Doucet, T. Tsagaris, "Inference for Lévy-driven stochastic
volatility models via adaptive sequential Monte Carlo", Scand. J. Stat. 38(1), 2011.
G. O. Roberts, J. S. Rosenthal, "Optimal scaling for various Metropolis–Hastings
algorithms", Statistical Science 16(4), 2001.
J. Liu, M. West, "Combined parameter and state estimation in simulation-based filtering", in
A. Doucet, N. de Freitas, N. Gordon (eds.), *Sequential Monte Carlo Methods in Practice*,
Springer, 2001, ch. 10. doi:10.1007/978-1-4757-3437-9_10
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar, Iterable

import numpy as np
import scipy.linalg
import sympy as sp

from ...compile.compiled import compiled_with_params
from ...compile.compiled import row_spans, run_stoppable
from ...core.angles import wrap_angle
from ...core.gaussian import Gaussian
from ...core.model import Model
from ...errors import ArgumentError, DegeneracyWarning, ModelError, NonFiniteError, ShapeError, SymmonError, plain_repr
from ...transforms.taylor import TT1
from ...transforms.unscented import UT
from ..bank import run_streams
from ..base import Filter
from ..gaussian.nonlinear import NonlinearKalmanFilter
from ..inputs import FilterCall, check_bank_size, kept_numbers, param_values
from ..results import CREDIBILITY_CONFIDENCE, CREDIBILITY_WINDOW, Credibility, KalmanResult, moving_sum, nees_of
from ..samples import circular_means, prior_samples, semidefinite_cholesky, weighted_moments
from ..simulation import check_count, check_prior
from ._kernel import MIN_THREAD_NUMBERS, BootstrapKernel, bootstrap_kernel, whitening
from ._rng import CHUNK, lane_states, stream_states
from ..statespace import StateSpace, rows_times

__all__ = ["ParticleFilter", "ParticleResult", "resample", "PROPOSALS", "RESAMPLERS", "DEGENERATE_ESS",
           "DEGENERATE_FRACTION", "ON_COLLAPSE", "COLLAPSE_FRACTION", "TEMPER_ESS", "TEMPER_STAGES", "TEMPER_MOVES",
           "shrink_kernel"]

#: The proposals: the transition (bootstrap), or one EKF / UKF step per particle.
PROPOSALS = ("bootstrap", "ekf", "ukf")
#: The resampling schemes (Douc, Cappé & Moulines 2005).
RESAMPLERS = ("systematic", "stratified", "multinomial")
#: Numbers drawn and moved (N K (n + n_q)) from which a single compiled run, on the main
#: thread, goes to the thread pool, so that a Ctrl-C stops it at once (about 20 ms of steps
#: and more; a shorter run stays: the hand-over costs a few tenths of a millisecond).
LONG_RUN_NUMBERS = 1 << 22
#: An effective sample size below this counts as a collapse to one particle (a DegeneracyWarning).
DEGENERATE_ESS = 1.5
#: The share of the particles below which a particle filter's windowed mean ESS flags its
#: step as degenerate (:meth:`ParticleResult.check_credibility`; at least :data:`DEGENERATE_ESS`).
DEGENERATE_FRACTION = 0.02
#: What a particle filter does at a step whose ESS says the cloud is collapsing (module notes):
#: nothing (None), or resample and move the copies by one of these kernels.
ON_COLLAPSE = ("shrink", "jitter", "temper")
#: The default share of the particles below which one step's ESS counts as a collapse for
#: ``on_collapse`` (module notes): above the credibility band's floor, which flags a cloud
#: already down to a few particles (a windowed mean below 2 % of N), because the kernel needs a
#: weighted covariance that still spans the posterior; half the default resampling threshold.
COLLAPSE_FRACTION = 0.25
#: The share of the particles whose ESS each stage of ``on_collapse="temper"`` keeps
#: (module notes): the default resampling threshold, so a stage's resampling is an ordinary one.
TEMPER_ESS = 0.5
#: The most stages of one tempered update; the last applies the rest of the likelihood.
TEMPER_STAGES = 64
#: The random-walk Metropolis steps after each stage of a tempered update.
TEMPER_MOVES = 5
_LOG_2PI = math.log(2 * math.pi)


def resample(weights: np.ndarray, method: str, rng: np.random.Generator | Iterable[np.random.Generator]) -> np.ndarray:
    """Indices of the particles drawn by ``method`` from the normalised ``weights``.

    Systematic: one uniform u, points (u + i)/N; stratified: one uniform per stratum,
    (u_i + i)/N; multinomial: N independent uniforms (sorted).  Each point picks the
    particle whose cumulative weight interval, of length N·w_i on the scale of the points,
    holds it (Douc et al. 2005, §2).  So the number of copies of particle i differs from
    N·w_i by less than 1 for systematic resampling (points one apart) and by less than 2
    for stratified resampling (one point per unit stratum, two strata cut by the ends);
    every scheme is unbiased, E copies = N·w_i.

    Parameters
    ----------
    weights : ndarray, shape (N,) or (R, N)
        Non-negative weights summing to 1 along the last axis.
    method : {"systematic", "stratified", "multinomial"}
    rng : Generator, or one per row of ``weights``

    Returns
    -------
    ndarray of int, the shape of ``weights``
    """
    if method not in RESAMPLERS:
        raise ArgumentError(f"resample must be one of {RESAMPLERS}, got {method!r}")
    W = np.atleast_2d(np.asarray(weights, dtype=float))
    R, N = W.shape
    rngs = [rng] * R if isinstance(rng, np.random.Generator) else list(rng)
    if len(rngs) != R:
        raise ShapeError(f"resample needs one generator per row of weights ({R}), got {len(rngs)}")
    return pick(W, np.stack([resampling_points(method, g, N) for g in rngs])).reshape(np.shape(weights))


def shrink_kernel(X: np.ndarray, mean: np.ndarray, chol: np.ndarray, bandwidth: float, eps: np.ndarray,
                  angle_states: Iterable[int] = ()) -> np.ndarray:
    """Liu & West's (2001) shrink-then-jitter move of particles X (N, n): x ← m + a (x − m) + h L ε,
    a = √(1 − h²), for the mean m (n,), the Cholesky factor L (n, n) of the covariance C the
    cloud is to keep, h = ``bandwidth`` in [0, 1] and the normals ε = ``eps`` (N, n); angle
    states' deviations and results wrapped to (−π, π].

    The moved cloud's mean is m + a (x̄ − m) + h L ε̄ and its covariance a² Cov x + h² L Cov ε Lᵀ
    plus the cross terms: m and C exactly when the cloud has mean m and covariance C and the ε
    have zero mean, unit covariance and no correlation with x (in expectation otherwise).

    Returns
    -------
    ndarray, shape (N, n): a new array.
    """
    X, m, L, eps = (np.asarray(a, dtype=float) for a in (X, mean, chol, eps))
    h = float(bandwidth)
    if not 0 <= h <= 1:
        raise ArgumentError(f"bandwidth must lie in [0, 1] (a² = 1 − h²), got {plain_repr(bandwidth)}")
    ang = sorted(angle_states)
    d = X - m
    if ang:
        d[:, ang] = wrap_angle(d[:, ang])
    out = m + math.sqrt(1.0 - h * h) * d + h * rows_times(eps, L)
    if ang:
        out[:, ang] = wrap_angle(out[:, ang])
    return out


def pick(W: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The particle indices (R, N) picked by the ascending points u (R, N) on [0, N) from the
    normalised weights W (R, N): the cumulative weight interval holding each point
    (:func:`resample`)."""
    R, N = W.shape
    cum = np.cumsum(W, axis=1) * N
    cum[:, -1] = N  # rounding must not leave the last point beyond the sum
    # One search over the runs side by side: row r's points and sums shifted by r·N.
    shift = (np.arange(R) * N)[:, None]
    idx = np.searchsorted((cum + shift).ravel(), (u + shift).ravel(), side="right").reshape(R, N) - shift
    return np.minimum(idx, N - 1)


def resampling_points(method: str, rng: np.random.Generator, N: int) -> np.ndarray:
    """The N ascending points in [0, N) of one resampling by ``method`` (:func:`resample`),
    drawn from ``rng``: u + i (systematic), u_i + i (stratified), N · sorted uniforms
    (multinomial)."""
    if method == "systematic":
        return rng.random(1) + np.arange(N)
    if method == "stratified":
        return rng.random(N) + np.arange(N)
    return np.sort(rng.random(N)) * N


@dataclass(frozen=True, eq=False)
class ParticleResult(KalmanResult):
    """The result of :meth:`ParticleFilter.filter`: the Kalman filters' result
    (:class:`~symmon.filters.results.KalmanResult`: ``x`` and ``P`` are the weighted mean and
    covariance of the particles after each update, ``x_pred`` and ``P_pred`` those of the
    prediction, ``innovation`` and ``S`` the mean and covariance of the predicted measurement
    mixture, ``loglik`` the log of each step's mean weight, NEES, NIS, ANEES), plus

    Attributes
    ----------
    ess : ndarray, shape (K,) or (R, K)
        The effective sample size 1 / Σ_i W_i² after each update (before resampling).
    resampled : ndarray of bool, shape (K,) or (R, K)
        Whether the particles were resampled after the update of that step.
    rejuvenated : ndarray of bool, shape (K,) or (R, K)
        Whether that step's ESS fell below the collapse floor and the filter, with
        ``on_collapse``, resampled and moved the particles by its kernel (all False without).
    particles : int
        N.
    final_particles : ndarray, shape (N, n) or (R, N, n)
        The particles after the last step (after its resampling and regularisation, if
        any), e.g. to count their distinct values or to continue from them.
    final_log_weights : ndarray, shape (N,) or (R, N)
        Their normalised log-weights (−log N after a resampling).
    """

    ess: np.ndarray | None = None
    resampled: np.ndarray | None = None
    rejuvenated: np.ndarray | None = None
    particles: int = 0
    final_particles: np.ndarray | None = None
    final_log_weights: np.ndarray | None = None

    def check_credibility(self, window: int = CREDIBILITY_WINDOW,
                          confidence: float = CREDIBILITY_CONFIDENCE) -> Credibility:
        """The steps flagged as not credible (:meth:`KalmanResult.check_credibility`): where
        the windowed mean NIS leaves its χ² band, or the mean effective sample size over the
        same window falls below max(:data:`DEGENERATE_ESS`, :data:`DEGENERATE_FRACTION` · N)
        particles, a cloud degenerating to a few particles."""
        base = super().check_credibility(window, confidence)
        ess = moving_sum(np.asarray(self.ess, dtype=float), window) / np.minimum(np.arange(1, self.steps + 1), window)
        floor = max(DEGENERATE_ESS, DEGENERATE_FRACTION * self.particles)
        flags = base.steps | (ess < floor)
        flags.flags.writeable = False
        ess.flags.writeable = False
        return Credibility(flags, base.statistic, base.band, base.window, base.confidence, ess, float(floor))

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return (f"ParticleResult({self.method}, {runs}steps={self.steps}, n={self.n}, "
                f"mean ESS {float(self.ess.mean()):.4g} of {self.particles})")


@dataclass(frozen=True, eq=False)
class ParticleFilter(Filter):
    """A particle filter (sequential importance resampling) on the compiled models.

    Parameters
    ----------
    f_model, h_model : Model
        The dynamics (n → n) and the measurement (n → n_y), as for
        :class:`~symmon.NonlinearKalmanFilter` (angle states and outputs wrapped).  The
        measurement noise must enter h affinely (y = h(x, 0) + Γ(x) e, which holds for
        additive noise), so that p(y | x) is Gaussian; the process noise may enter f in
        any way for the bootstrap proposal.
    Q, R : array_like
        Process and measurement noise covariances (of the noise symbols, or additive).
    particles : int, default 1000
        N, per run.
    proposal : {"bootstrap", "ekf", "ukf"}
        The transition, or one EKF (``TT1``) or UKF (``UT.ut1()``) step per particle from
        N(x^i, 0) with the new measurement (module notes); the latter two need additive
        process noise with Q positive definite (the transition density p(x_k | x_{k−1}) in
        the weights).
    resample : {"systematic", "stratified", "multinomial"}
    ess_threshold : float in [0, 1], default 0.5
        Resample when ESS ≤ ``ess_threshold`` · N (1: at every step; 0: never).
    seed : int, default 0
        The seed of every ``filter`` call (``SeedSequence(seed).spawn(runs)``): the same
        call gives the same numbers, whatever the number of threads or shards.  The
        compiled bootstrap recursion draws its normals and resampling uniforms in C
        (xoshiro256++ streams and a ziggurat, :mod:`symmon.filters.particle._rng`); the NumPy path
        (the EKF/UKF proposals, a state-dependent Γ(x), no compiler) draws from NumPy's
        Generator: the two give different particles for a seed, with the same law.  So a call
        waits for a background build of its compiled step rather than take the NumPy path
        meanwhile: a seed's particles do not depend on whether the build had finished.
    regularise : bool, default False
        The post-regularised particle filter (Musso, Oudjane & Le Gland 2001):
        after each resampling every particle moves by h_opt · L ε, ε ~ N(0, I), L the
        Cholesky factor of the weighted particle covariance before the resampling and
        h_opt = :attr:`bandwidth` (angle states wrapped): a draw from a Gaussian-kernel
        density estimate of the posterior, which restores the diversity that resampling
        removes when the process noise is small.
    on_collapse : {None, "shrink", "jitter", "temper"}, default None
        At a step whose ESS falls below max(:data:`DEGENERATE_ESS`, ``collapse_fraction`` · N),
        resample and move the copies by Liu & West's (2001) shrink-then-jitter kernel, which
        keeps the cloud's mean and covariance (``"shrink"``), or by the regularisation's
        jitter, which inflates it (``"jitter"``); or apply that step's likelihood in stages,
        moving the cloud by Metropolis steps between them (``"temper"``, a tempered update;
        the bootstrap proposal only, on the NumPy recursion); None: nothing beyond
        the usual resampling (module notes, "Acting on a collapse").  At such a step
        ``"shrink"`` replaces the jitter of ``regularise``.
    collapse_fraction : float in (0, 1), default :data:`COLLAPSE_FRACTION`
        The share of N below which a step's ESS counts as a collapse (``on_collapse`` acts
        there; ``collapse_floor``).

    Raises
    ------
    ArgumentError
        For a bad ``particles``, ``proposal``, ``resample``, ``ess_threshold`` or ``seed``,
        or a proposal that needs additive process noise without it.
    ModelError
        When h is not affine in its noise symbols (no Gaussian likelihood).
    ShapeError, CovarianceError
        As :class:`~symmon.NonlinearKalmanFilter`, and for an R whose likelihood is
        singular.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> f, h = sm.Model([x], [0.9 * x]), sm.Model([x], [x])
    >>> xs, ys = sm.simulate(f, h, [[0.5]], [[0.1]], sm.Gaussian([0.0], [[1.0]]), 20, seed=1)
    >>> res = sm.ParticleFilter(f, h, [[0.5]], [[0.1]], particles=2000).filter(ys, sm.Gaussian([0.0], [[1.0]]))
    >>> res.x.shape, res.ess.shape
    ((20, 1), (20,))
    """

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray
    particles: int = 1000
    proposal: str = "bootstrap"
    resample: str = "systematic"
    ess_threshold: float = 0.5
    seed: int = 0
    regularise: bool = False
    on_collapse: str | None = None
    collapse_fraction: float = COLLAPSE_FRACTION
    space: StateSpace = field(init=False, repr=False)

    def __post_init__(self) -> None:
        ss = StateSpace(self.f_model, self.h_model, self.Q, self.R)
        object.__setattr__(self, "space", ss)
        object.__setattr__(self, "Q", ss.Q)
        object.__setattr__(self, "R", ss.R)
        object.__setattr__(self, "particles", check_count(self.particles, "particles"))
        if self.proposal not in PROPOSALS:
            raise ArgumentError(f"proposal must be one of {PROPOSALS}, got {self.proposal!r}")
        if self.resample not in RESAMPLERS:
            raise ArgumentError(f"resample must be one of {RESAMPLERS}, got {self.resample!r}")
        t = self.ess_threshold
        if isinstance(t, bool) or not isinstance(t, (int, float, np.floating, np.integer)) or not 0 <= t <= 1:
            raise ArgumentError(f"ess_threshold must be a number in [0, 1], got {plain_repr(t)}")
        object.__setattr__(self, "ess_threshold", float(t))
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ArgumentError(f"seed must be a non-negative integer, got {plain_repr(self.seed)}")
        if not isinstance(self.regularise, (bool, np.bool_)):
            raise ArgumentError(f"regularise must be True or False, got {self.regularise!r}")
        object.__setattr__(self, "regularise", bool(self.regularise))
        if self.on_collapse is not None and self.on_collapse not in ON_COLLAPSE:
            raise ArgumentError(f"on_collapse must be None or one of {ON_COLLAPSE}, got {self.on_collapse!r}")
        c = self.collapse_fraction
        if isinstance(c, bool) or not isinstance(c, (int, float, np.floating, np.integer)) or not 0 < c < 1:
            raise ArgumentError(f"collapse_fraction must be a share of the particles in (0, 1), got {plain_repr(c)}")
        object.__setattr__(self, "collapse_fraction", float(c))
        if self.on_collapse == "shrink" and self.bandwidth > 1:  # N = 1, n = 1: h_opt > 1, no a² = 1 − h²
            raise ArgumentError("on_collapse='shrink' needs at least 2 particles (a kernel bandwidth below 1)")
        if self.on_collapse == "temper" and self.proposal != "bootstrap":
            raise ArgumentError("on_collapse='temper' tempers the likelihood of the bootstrap proposal; with "
                                f"proposal={self.proposal!r} use on_collapse='shrink' or None")
        _ = self._noise_map  # refuse an h not affine in its noise, and a singular likelihood, now
        if self.proposal != "bootstrap":
            if self.f_model.n_v:
                raise ArgumentError(f"proposal={self.proposal!r} weighs by the transition density N(x'; f(x), Q): "
                                    "it needs additive process noise (f without noise symbols); use "
                                    "proposal='bootstrap' for f's noise symbols")
            try:
                np.linalg.cholesky(self.Q)
            except np.linalg.LinAlgError:
                raise ArgumentError(f"proposal={self.proposal!r} needs a positive definite Q (the transition "
                                    "density); use proposal='bootstrap' for a singular Q") from None

    # ------------------------------------------------------------------ set-up
    @property
    def method(self) -> str:
        """The filter's name, e.g. ``PF(bootstrap, N=1000, systematic)``."""
        reg = ", regularised" if self.regularise else ""
        col = "" if self.on_collapse is None else f", on_collapse={self.on_collapse}"
        return f"PF({self.proposal}, N={self.particles}, {self.resample}{reg}{col})"

    @property
    def bandwidth(self) -> float:
        """h_opt = (4 / (N (n + 2)))^(1/(n+4)), the bandwidth of the Gaussian kernel that
        minimises the mean integrated squared error for a Gaussian density (Musso, Oudjane &
        Le Gland 2001, ch. 12 of Doucet et al., *Sequential Monte Carlo Methods in Practice*); the jitter of ``regularise=True`` is h_opt · L ε."""
        n = self.space.n
        return (4.0 / (self.particles * (n + 2))) ** (1.0 / (n + 4))

    @property
    def collapse_floor(self) -> float:
        """The ESS below which a step counts as a collapse: max(:data:`DEGENERATE_ESS`,
        ``collapse_fraction`` · N) (``on_collapse`` acts there)."""
        return max(DEGENERATE_ESS, self.collapse_fraction * self.particles)

    @property
    def params(self) -> tuple:
        """The parameters of the models (f's, then h's that f does not have)."""
        return self.space.params

    @cached_property
    def _noise_map(self) -> np.ndarray | None:
        """Γ = ∂h/∂e when it is constant (None: it depends on x or a parameter, or no noise
        symbols, Γ = I); refuses an h that is not affine in e."""
        h = self.h_model
        if not h.n_v:
            self._whitening(np.asarray(self.R), "R")
            return None
        J = sp.Matrix(h.outputs).jacobian(sp.Matrix(h.noise))
        if any(J.has(e) for e in h.noise):
            raise ModelError(f"h_model {h.name!r} is not affine in its noise symbols {[str(e) for e in h.noise]}: "
                             "the particle filter needs the likelihood p(y | x), Gaussian when y = h(x, 0) + Γ(x) e; "
                             "write the noise additively")
        if J.free_symbols:
            return None
        G = np.array(J.tolist(), dtype=float)
        self._whitening(G @ self.R @ G.T, "the measurement covariance Γ R Γᵀ")
        return G

    @staticmethod
    def _whitening(S: np.ndarray, what: str) -> np.ndarray:
        try:
            return np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise ShapeError(f"{what} is singular: the likelihood p(y | x) has no density; give every measured "
                             "component some noise") from None

    @cached_property
    def _kf(self) -> NonlinearKalmanFilter | None:
        """The Gaussian filter whose compiled step is the proposal (None: bootstrap)."""
        if self.proposal == "bootstrap":
            return None
        rule = TT1() if self.proposal == "ekf" else UT.ut1()
        return NonlinearKalmanFilter(self.f_model, self.h_model, self.Q, self.R, rule)

    # ------------------------------------------------------------------ pieces of a step
    def _loglik(self, X: np.ndarray, Y: np.ndarray, p: np.ndarray | None):
        """log p(y | x) of each particle, (R, N), h(x, 0) (R, N, n_y) and the covariance of
        y given x, Γ R Γᵀ ((n_y, n_y), or (R, N, n_y, n_y) when Γ depends on x); Y (R, n_y)
        with NaN for a missing component (left out), p (R, n_p) or None."""
        R_, N, n = X.shape
        ss, h = self.space, self.h_model
        flat = X.reshape(-1, n)
        prow = None if p is None else np.repeat(p, N, axis=0)
        if h.n_v and self._noise_map is None:  # Γ(x): the Jacobian in e at e = 0
            cm = compiled_with_params(h)
            W = [flat, np.zeros((flat.shape[0], h.n_v))]
            if h.n_p:
                W.append(prow[:, [ss.params.index(s) for s in h.params]])
            Hx, J_nz, _ = cm.eval_derivatives(np.hstack(W))
            G = cm.dense_jacobian(J_nz)[:, :, n:n + h.n_v]
            S_all = (G @ self.R @ G.transpose(0, 2, 1)).reshape(R_, N, h.n_y, h.n_y)
        else:
            Hx = ss.evaluate(h, flat, None, prow)
            G = np.eye(h.n_y) if self._noise_map is None else self._noise_map
            S_all = G @ self.R @ G.T
        Hx = Hx.reshape(R_, N, h.n_y)
        if ss.angle_outputs:
            Hx[..., list(ss.angle_outputs)] = wrap_angle(Hx[..., list(ss.angle_outputs)])
        nu = Y[:, None, :] - Hx
        if ss.angle_outputs:
            nu[..., list(ss.angle_outputs)] = wrap_angle(nu[..., list(ss.angle_outputs)])
        ll = np.zeros((R_, N))
        measured = ~np.isnan(Y)
        for pattern in np.unique(measured, axis=0):
            runs = np.flatnonzero((measured == pattern).all(axis=1))
            m = np.flatnonzero(pattern)
            if m.size == 0:
                continue
            v = nu[runs][..., m]
            if S_all.ndim == 2:  # one S for every particle: one factor
                L = self._whitening(S_all[np.ix_(m, m)], "the measurement covariance")
                z = np.einsum("ij,rnj->rni", np.linalg.inv(L), v)  # no BLAS (statespace.rows_times)
                log_det = 2 * np.log(np.diag(L)).sum()
            else:
                S = S_all[runs][..., m[:, None], m[None, :]]
                try:
                    L = np.linalg.cholesky(S)
                except np.linalg.LinAlgError:
                    raise NonFiniteError("the measurement covariance Γ(x) R Γ(x)ᵀ of a particle is singular: "
                                         "its likelihood has no density") from None
                z = np.linalg.solve(L, v[..., None])[..., 0]
                log_det = 2 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=-1)
            ll[runs] = -0.5 * ((z * z).sum(axis=-1) + log_det + m.size * _LOG_2PI)
        return ll, Hx, S_all

    def _moments(self, X: np.ndarray, W: np.ndarray, cov: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The weighted mean and covariance of particles X (R, N, n) with weights W (R, N)
        (:func:`~symmon.filters.samples.weighted_moments`, angle states circular)."""
        return weighted_moments(X, W, self.space.angle_states, cov)

    def _tempered(self, X: np.ndarray, logW: np.ndarray, inc: np.ndarray, y: np.ndarray, p: np.ndarray | None,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
        """One run's tempered update (module notes): the predicted particles X (N, n) with the
        normalised log-weights ``logW`` and the log-likelihoods ``inc`` of the measurement
        ``y`` (parameters ``p``) → the moved particles, their unnormalised log-weights for
        the rest of the likelihood, and the sum of the stages' log mean weights."""
        N, n, ang = self.particles, self.space.n, sorted(self.space.angle_states)
        target = TEMPER_ESS * N
        m0, C0 = (a[0] for a in weighted_moments(X[None], np.exp(logW)[None], ang))
        L0 = semidefinite_cholesky(C0)  # the predicted cloud's Gaussian (on the span of its factor)
        keep = np.abs(np.diag(L0)) > 0
        white = scipy.linalg.solve_triangular(L0[np.ix_(keep, keep)], np.eye(int(keep.sum())), lower=True)
        lik = lambda Z: self._loglik(Z[None], y[None], None if p is None else p[None])[0][0]  # noqa: E731

        def log_prior(Z: np.ndarray) -> np.ndarray:
            d = Z - m0
            if ang:
                d[:, ang] = wrap_angle(d[:, ang])
            u = rows_times(d[:, keep], white)  # a solve per call took 5 ms for 2000 rows
            return -0.5 * (u * u).sum(axis=1)

        def ess(t: np.ndarray) -> float:
            e = np.exp(t - t.max())
            return float(e.sum() ** 2 / (e @ e))

        done, staged = 0.0, 0.0
        for _ in range(TEMPER_STAGES):
            rest = 1.0 - done
            if ess(logW + rest * inc) >= target:
                break
            lo, hi = 0.0, rest  # the largest power whose weights keep the target ESS
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if ess(logW + mid * inc) >= target else (lo, mid)
            power = max(lo, rest * 2.0**-40)  # a step forward even where one particle dominates at once
            t = logW + power * inc
            top = t.max()
            lse = top + math.log(np.exp(t - top).sum())
            W = np.exp(t - lse)
            staged += lse
            done += power
            _, C = weighted_moments(X[None], W[None], ang)
            step = 2.38 / math.sqrt(n) * semidefinite_cholesky(C[0])
            idx = pick(W[None], resampling_points(self.resample, rng, N)[None])[0]
            X, inc = X[idx], inc[idx]
            lp = log_prior(X)
            for _ in range(TEMPER_MOVES):  # random-walk Metropolis for N(m0, C0) p(y | x)^done
                Z = self.space.wrap_states(X + rows_times(rng.standard_normal((N, n)), step))
                inc_z, lp_z = lik(Z), log_prior(Z)
                with np.errstate(invalid="ignore"):  # -inf - -inf: a proposal of zero likelihood, refused
                    take = np.log(rng.random(N)) < lp_z - lp + done * (inc_z - inc)
                X[take], inc[take], lp[take] = Z[take], inc_z[take], lp_z[take]
            logW = np.full(N, -math.log(N))
        return X, logW + (1.0 - done) * inc, staged

    def _measurement_moments(self, Hx: np.ndarray, W: np.ndarray, Y: np.ndarray,
                             S_noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The innovation y − ŷ and its covariance S of the predicted measurement mixture
        Σ_i W_i N(ŷ_i, S_i), ŷ_i = ``Hx[:, i]`` and S_i = ``S_noise`` (one for all, or per
        particle); missing components: 0 and a unit diagonal entry (as the Kalman filters)."""
        mean = np.einsum("rn,rni->ri", W, Hx)
        ang = list(self.space.angle_outputs)
        if ang:
            A = Hx[..., ang]
            mean[:, ang] = circular_means(W, A)
        D = Hx - mean[:, None, :]
        if ang:
            D[..., ang] = wrap_angle(D[..., ang])
        noise = S_noise if S_noise.ndim == 2 else np.einsum("rn,rnij->rij", W, S_noise)
        return self._innovation_moments(mean, np.einsum("rni,rnj->rij", D * W[..., None], D), Y, noise)

    def _innovation_moments(self, mean: np.ndarray, spread: np.ndarray, Y: np.ndarray,
                            noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The innovation y − ŷ (wrapped for angle outputs) and S = spread + noise, from the
        mixture's mean ŷ (R, n_y) and the covariance of its means ``spread`` (R, n_y, n_y);
        missing components: 0 and a unit diagonal entry (as the Kalman filters)."""
        missing = np.isnan(Y)
        ang = list(self.space.angle_outputs)
        S = spread + noise
        nu = Y - mean
        if ang:
            nu[:, ang] = wrap_angle(nu[:, ang])
        if missing.any():
            nu[missing] = 0.0
            S = np.where(missing[:, :, None] | missing[:, None, :], 0.0, S)
            r, i = np.nonzero(missing)
            S[r, i, i] = 1.0
        return nu, 0.5 * (S + S.transpose(0, 2, 1))

    # ------------------------------------------------------------------ the filter
    random: ClassVar[bool] = True
    takes_covariance: ClassVar[bool] = False

    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.space.n, self.space.n_y

    def step_cost(self) -> int:
        """f and h at each particle (a tempered update's stages, which depend on the data, not
        counted: 5 evaluations of h per particle and stage, at the collapsing steps only)."""
        return 2 * self.particles

    def _check_prior(self, x0: Any, P0: None, runs: int | None) -> tuple[Any, None]:
        return check_prior(x0, self.space.n), None

    def _check_params(self, params: dict | None, runs: int | None, steps: int) -> np.ndarray | None:
        return param_values(self.space.params, params, runs, steps, who="the models")

    def _numbers(self, keep: frozenset[str] | None) -> tuple[int, int]:
        n, n_y = self.sizes
        return kept_numbers(n, n_y, self.keepable if keep is None else keep) + 2, 0  # and the ESS

    def _filter(self, call: FilterCall) -> ParticleResult:
        """The recursion over the checked ``call`` (:meth:`filter`; predict, then update,
        for each measurement; ``ys[k]`` is y_{k+1}).

        The prior x0 is a Gaussian, a GaussianMixture or an Empirical: the N particles of
        each run are drawn from it (an Empirical is resampled by its weights).  ``keep``
        names arrays among ``"x"``, ``"P"``, ``"x_pred"``, ``"P_pred"``, ``"innovation"``,
        ``"S"`` and ``"nis"``; the log-likelihood and the ESS are always kept, and the
        predicted moments cost a pass over the particles.  Run r draws from the stream of
        run ``call.first_run + r`` (:func:`~symmon.filters.bank.run_streams`), so a bank
        filtered in pieces gives the numbers of the whole bank.

        Raises
        ------
        NonFiniteError
            A particle or weight became NaN or inf (the model overflows), or every particle
            of a run has zero likelihood, naming the run and step.
        SymmonError
            An EKF/UKF proposal step failed (a singular covariance).
        ResourceError
            The particles would exceed :data:`~symmon.filters.inputs.MAX_BANK_NUMBERS` numbers.

        Warns
        -----
        DegeneracyWarning
            When the ESS fell below :data:`DEGENERATE_ESS` (about one particle) at some step.
        """
        ss, N = self.space, self.particles
        n, n_y = ss.n, ss.n_y
        Y, bank, first_run = call.measurements, call.runs, call.first_run
        Rr, K = bank or 1, call.steps
        Yb = call.Y
        names = frozenset(self.keepable) if call.keep is None else call.keep
        carried = n + (n * n + 2 * n_y + n_y * n_y if self._kf is not None else 0)  # and the proposal's step
        check_bank_size(Rr, N, 3 * carried + n_y + 2, f"{self.method} particles", "use fewer particles or runs")
        x0, truth, pv = call.x0, call.truth, call.pv

        kern = self._bootstrap_kernel
        loops = None if kern is None else kern.built_loops()  # a seed's numbers whatever the build's timing
        replay = getattr(self, "_replay", None)  # a test's draws for both paths (test_particle_kernel)
        # The compiled path draws a Gaussian prior in C, from the runs' xoshiro streams (unless
        # replaying: the two paths then share NumPy's prior draws).
        prior_c = loops is not None and replay is None and isinstance(x0, Gaussian)
        # NumPy's streams of the runs, where NumPy draws (the compiled path needs only their seeds)
        rngs = None if prior_c else run_streams(self.seed, Rr, first_run)
        X = (np.empty((Rr, N, n)) if prior_c
             else ss.wrap_states(np.stack([prior_samples(x0, N, g) for g in rngs])))
        logW = np.full((Rr, N), -math.log(N)) if loops is None else None  # the compiled path returns its own
        want = lambda *k: any(a in names for a in k)  # noqa: E731
        out = {k: np.empty((Rr, K) + s) for k, s in (("x", (n,)), ("P", (n, n)), ("x_pred", (n,)),
                                                     ("P_pred", (n, n)), ("innovation", (n_y,)),
                                                     ("S", (n_y, n_y)), ("nis", ())) if k in names}
        loglik, ess, resampled = np.empty((Rr, K)), np.empty((Rr, K)), np.zeros((Rr, K), dtype=bool)
        rejuvenated = np.zeros((Rr, K), dtype=bool)
        nees = np.empty((Rr, K)) if truth is not None else None
        nq = ss.Lq.shape[0]
        if loops is not None:  # the compiled step (pf_kernel); the loop below is its NumPy twin
            X, logW = self._run_compiled(kern, loops, X, Yb, pv, first_run, names, out, loglik, ess, resampled,
                                         rejuvenated, nees, truth, bank, x0 if prior_c else None)
        for k in range(K if loops is None else 0):
            y, p = Yb[:, k], (None if pv is None else pv[:, k])
            Wprev = np.exp(logW)
            with np.errstate(over="ignore", invalid="ignore"):  # a non-finite particle is refused below
                if self._kf is None:
                    Z = (replay["z"][:, k].reshape(-1, nq) if replay is not None
                         else np.concatenate([g.standard_normal((N, nq)) for g in rngs]))
                    X = ss.transition(X.reshape(-1, n), Z, None if p is None else np.repeat(p, N, axis=0))
                    X = X.reshape(Rr, N, n)
                    inc, prior_h, S_noise = self._loglik(X, y, p)
                    prior_x = X
                else:
                    X, inc, prior_x, prior_h, S_noise = self._proposal_step(X, y, p, rngs, k, bank, want)
            total = logW + inc
            top = total.max(axis=1)
            bad = ~np.isfinite(top) | ~np.isfinite(X).all(axis=(1, 2))
            if bad.any():
                raise self._not_finite(k, int(np.flatnonzero(bad)[0]), bank)
            staged = np.zeros(Rr)  # the log mean weights of a tempered update's stages
            if self.on_collapse == "temper":
                e = np.exp(total - top[:, None])
                tempered = np.flatnonzero(e.sum(axis=1) ** 2 / (e * e).sum(axis=1) < self.collapse_floor)
                if tempered.size:
                    X = X.copy()  # prior_x keeps the predicted cloud
                for r in tempered:
                    X[r], total[r], staged[r] = self._tempered(X[r], logW[r], inc[r], y[r],
                                                               None if p is None else p[r], rngs[r])
                    rejuvenated[r, k] = True
                top = total.max(axis=1)
                if not np.isfinite(top).all():  # the moved cloud far from the measurement again
                    raise self._not_finite(k, int(np.flatnonzero(~np.isfinite(top))[0]), bank)
            lse = top + np.log(np.exp(total - top[:, None]).sum(axis=1))
            loglik[:, k] = lse + staged  # log Σ W_{k−1} exp(inc): logW is normalised
            logW = total - lse[:, None]
            W = np.exp(logW)
            ess[:, k] = 1.0 / (W * W).sum(axis=1)
            collapsed = np.zeros(Rr, dtype=bool)  # resampled and moved by the collapse's kernel now
            if self.on_collapse in ("shrink", "jitter"):
                collapsed = rejuvenated[:, k] = ess[:, k] < self.collapse_floor
            redo = np.flatnonzero((ess[:, k] <= self.ess_threshold * N) | collapsed)
            moved = self.regularise or collapsed.any()  # a kernel moves some run's particles
            spread = None  # the weighted mean and covariance, which the kernels take
            if want("x", "P") or truth is not None or (moved and redo.size):
                m, C = spread = self._moments(X, W, cov="P" in out or truth is not None or moved)
                if "x" in out:
                    out["x"][:, k] = m
                if "P" in out:
                    out["P"][:, k] = C
                if truth is not None:
                    nees[:, k] = nees_of(m[:, None], C[:, None], truth[:, k:k + 1], ss.angle_states)[:, 0]
            if want("x_pred", "P_pred"):
                m, C = self._moments(prior_x, Wprev, cov="P_pred" in out)
                if C is not None and self._kf is not None:
                    C = C + self.Q  # prior_x holds f(x_{k−1}) for a proposal
                if "x_pred" in out:
                    out["x_pred"][:, k] = m
                if "P_pred" in out:
                    out["P_pred"][:, k] = C
            if want("innovation", "S", "nis"):
                _store_measurement(out, k, *self._measurement_moments(prior_h, Wprev, y, S_noise))
            if redo.size:
                pts = (replay["u"][redo, k] if replay is not None
                       else np.stack([resampling_points(self.resample, rngs[r], N) for r in redo]))
                idx = pick(W[redo], pts)
                X[redo] = np.take_along_axis(X[redo], idx[..., None], axis=1)
                for r in redo:
                    if not (self.regularise or collapsed[r]):
                        continue
                    eps = replay["j"][r, k] if replay is not None else rngs[r].standard_normal((N, n))
                    L = semidefinite_cholesky(spread[1][r])
                    X[r] = (shrink_kernel(X[r], spread[0][r], L, self.bandwidth, eps, ss.angle_states)
                            if collapsed[r] and self.on_collapse == "shrink"
                            else ss.wrap_states(X[r] + self.bandwidth * rows_times(eps, L)))
                logW[redo] = -math.log(N)
                resampled[redo, k] = True

        collapsed = ess < DEGENERATE_ESS
        if collapsed.any():
            r, k = (int(i) for i in np.argwhere(collapsed)[0])
            where = f"step {k}" if bank is None else f"run {r}, step {k}"
            warnings.warn(f"{self.method}: the weights collapsed to about one particle (ESS < {DEGENERATE_ESS}) at "
                          f"{int(collapsed.sum())} step(s), first at {where}: the estimates there are one particle's; "
                          "use more particles, proposal='ekf'/'ukf', or check the noise covariances",
                          DegeneracyWarning, stacklevel=2)
        arrays = {k: v if bank is not None else v[0] for k, v in out.items()}
        if "nis" in arrays:
            arrays["nis_values"] = arrays.pop("nis")
        extra = {"loglik": loglik, "ess": ess, "resampled": resampled, "rejuvenated": rejuvenated, "final_particles": X,
                 "final_log_weights": logW}
        if nees is not None:
            extra["nees_values"] = nees
        arrays.update({k: v if bank is not None else v[0] for k, v in extra.items()})
        for v in arrays.values():
            v.flags.writeable = False
        measured = None
        if np.isnan(Y).any():
            measured = (~np.isnan(Y)).sum(axis=-1)
            measured.flags.writeable = False
        return ParticleResult(**arrays, measured=measured, n_y=n_y, n_x=n, angle_states=ss.angle_states,
                              method=self.method, particles=N)

    @cached_property
    def _stream_cache(self) -> dict:
        """The C streams' initial states by (runs, first run, streams), a few kept."""
        return {}

    def _stream_states(self, runs: int, first: int, chunks: int) -> np.ndarray:
        """A fresh copy of the xoshiro states of runs ``first`` … of this filter's seed, per run
        the words of its chunks' streams, the resampling stream and the chunks' lanes
        (:mod:`~symmon.filters.particle._rng`; the C advances them in place).  Hashing the seeds
        takes a tenth of a millisecond a call: kept."""
        key = (runs, first, chunks)
        st = self._stream_cache.get(key)
        if st is None:
            st = np.stack([np.concatenate([stream_states(g, chunks + 1).ravel(), lane_states(g, chunks).ravel()])
                           for g in run_streams(self.seed, runs, first)])
            if len(self._stream_cache) < 8:
                self._stream_cache[key] = st
        return st.copy()

    @cached_property
    def _whitenings(self) -> dict:
        """The compiled path's whitenings of Γ R Γᵀ by pattern of measured components."""
        return {}

    @cached_property
    def _bootstrap_kernel(self) -> BootstrapKernel | None:
        """The compiled bootstrap step (:mod:`symmon.filters.particle._kernel`), or None where it does
        not apply: another proposal, a Γ(x) that depends on the state, or a tempered
        update (no staged update in C)."""
        h = self.h_model
        if self.proposal != "bootstrap" or (h.n_v and self._noise_map is None) or self.on_collapse == "temper":
            return None
        ss = self.space
        return bootstrap_kernel(self.f_model, h, ss.params, ss.Lq, ss.angle_states, ss.angle_outputs)

    def _not_finite(self, k: int, r: int, bank) -> NonFiniteError:
        where = f"step {k}" if bank is None else f"run {r}, step {k}"
        return NonFiniteError(f"{self.method}: at {where} a particle or its weight is NaN or inf, or every "
                              "particle has zero likelihood (the model overflows there, or the measurement "
                              "is far from every particle: use more particles or another proposal)")

    def _run_compiled(self, kern, loops, X, Yb, pv, first_run, names, out, loglik, ess, resampled, rejuvenated, nees,
                      truth, bank, prior=None):
        """The K bootstrap steps of each run in one compiled call (pf_kernel's module notes),
        the runs of a bank on threads; the normals and resampling uniforms drawn in C from the
        runs' xoshiro streams (:mod:`symmon.filters.particle._rng`), or replayed (``_replay``); with
        a Gaussian ``prior``, X is drawn from it in C too (the first normals of the streams)."""
        run = loops[0]
        ss, N = self.space, self.particles
        Rr, K, n_y = Yb.shape
        n = ss.n
        S_noise = self._noise_cov
        Lq = np.asarray(ss.Lq)
        cache = self._whitenings  # (A, c) per pattern of measured components, once per filter

        def white(mask: np.ndarray) -> tuple[np.ndarray, float]:
            key = mask.tobytes()
            if key not in cache:
                cache[key] = whitening(S_noise, mask)
            return cache[key]

        P = kern.pack(pv, Lq, Yb, white)
        want_h = any(a in names for a in ("innovation", "S", "nis"))
        need_x = "x" in names or truth is not None
        need_P = "P" in names or truth is not None
        arr = {"x": out["x"] if "x" in out else (np.empty((Rr, K, n)) if need_x else None),
               "P": out["P"] if "P" in out else (np.empty((Rr, K, n, n)) if need_P else None),
               "x_pred": out.get("x_pred"), "P_pred": out.get("P_pred"),
               "hm": np.empty((Rr, K, n_y)) if want_h else None, "hS": np.empty((Rr, K, n_y, n_y)) if want_h else None}
        X = np.ascontiguousarray(X)
        chunks = -(-N // CHUNK)
        st = self._stream_states(Rr, first_run, chunks)
        # threads over particle chunks for one run (in C; for enough work a step), over runs
        # for a bank (here)
        T = 1 if Rr > 1 or N * (n + kern.n_q) < MIN_THREAD_NUMBERS else len(row_spans(N, CHUNK))
        isz, wsz = kern.f.sz_iw() + 1, kern.f.sz_w() + 1
        # The work arrays of a run, one block (one address to take, a few microseconds each):
        # Xn (N x n); t, e, lw, the points (N each); Hx (N x n_y, when kept); part (chunks x
        # (4 + 2n), twice: by step parity); the T threads' iw (int64) and w; the step's
        # resampled flags (K).
        sizes = (N * n, N, N, N, N, N * n_y if want_h else 0, 2 * chunks * (4 + 2 * n), T * isz, T * wsz, K)
        offs = [0, *itertools.accumulate(sizes)]
        block = np.empty((Rr, offs[-1]))
        base, run_bytes = block.ctypes.data, 8 * offs[-1]
        at = lambda j: (base + 8 * offs[j], run_bytes) if sizes[j] else (0, 0)  # noqa: E731
        replay = getattr(self, "_replay", None)
        m0, L0, opt, fl = self._kernel_constants(prior)
        fail = np.zeros(Rr, dtype=np.int64)
        # Per-run arrays: (address of run 0, bytes per run); 0 for an output not wanted.
        addr = lambda a: (a.ctypes.data, a.nbytes // Rr) if a is not None else (0, 0)  # noqa: E731
        per_run = [addr(P), addr(X), *map(at, range(7)), addr(st)]
        outs = [addr(loglik), addr(ess), at(9), *map(addr, (arr["x"], arr["P"], arr["x_pred"], arr["P_pred"],
                                                            arr["hm"], arr["hS"])), at(7), at(8)]
        shared = (m0, L0, opt.ctypes.data, fl.ctypes.data)

        def one(r: int, stop: int) -> int:
            rp = [0, 0, 0]
            if replay is not None:  # kept alive by ``keep`` during the call
                keep = [np.ascontiguousarray(replay[key][r], dtype=float) for key in ("z", "u", "j")]
                rp = [a.ctypes.data for a in keep]
            a = [base + r * step if base else 0 for base, step in per_run]
            o = [base + r * step if base else 0 for base, step in outs]
            return run(a[0], K, N, *a[1:], *rp, *shared, *o, isz, wsz, T, fail.ctypes.data + 8 * r, stop)

        # the runs on the pool (a Ctrl-C stops their loops: run_stoppable); one long run there too
        codes = run_stoppable(one, range(Rr), long=N * K * (n + kern.n_q) >= LONG_RUN_NUMBERS)
        for r, c in enumerate(codes):
            if c == 1:
                raise SymmonError(f"{self.method}: the compiled step {kern.f.name()} returned an error")
            if c == 3:
                raise self._not_finite(int(fail[r]), r, bank)
        loglik[np.isnan(Yb).all(axis=2)] = 0.0  # no measurement: log Σ W = 0 exactly
        resampled[:] = block[:, offs[9]:offs[10]] > 0
        rejuvenated[:] = block[:, offs[9]:offs[10]] == 2  # resampled at a collapse, moved by its kernel
        if truth is not None:
            nees[:] = nees_of(arr["x"], arr["P"], truth, ss.angle_states)
        if want_h:
            nu, S = self._innovation_moments(arr["hm"].reshape(Rr * K, n_y), arr["hS"].reshape(Rr * K, n_y, n_y),
                                             Yb.reshape(Rr * K, n_y), S_noise)
            for k in range(K):
                _store_measurement(out, k, nu.reshape(Rr, K, n_y)[:, k], S.reshape(Rr, K, n_y, n_y)[:, k])
        return X, block[:, offs[3]:offs[4]].copy()

    def _kernel_constants(self, prior: Gaussian | None) -> tuple[int, int, np.ndarray, np.ndarray]:
        """The addresses of the prior's mean and square root (0 without a prior), and the
        kernel's opt and fl (``NAME_run``'s notes), kept for the last prior (a Gaussian is
        immutable: the same object has the same factor)."""
        held = self.__dict__.get("_held_constants")
        if held is None or held[0] is not prior:
            m0 = L0 = None
            if prior is not None:
                m0 = np.ascontiguousarray(prior.mean, dtype=float)
                L0 = np.ascontiguousarray(prior.sqrt_cov(), dtype=float)
            diag = L0 is not None and np.count_nonzero(L0) == np.count_nonzero(np.diag(L0))
            oc = {None: 0, "jitter": 1, "shrink": 2}[self.on_collapse]  # pf_kernel's opt[3]
            h = self.bandwidth
            opt = np.array([RESAMPLERS.index(self.resample), int(self.regularise), int(diag), oc], dtype=np.int64)
            fl = np.array([self.ess_threshold * self.particles, h, self.collapse_floor, math.sqrt(1.0 - h * h)])
            held = (prior, m0, L0, opt, fl)
            object.__setattr__(self, "_held_constants", held)  # a frozen dataclass: a cache, not state
        _, m0, L0, opt, fl = held
        return (0 if m0 is None else m0.ctypes.data, 0 if L0 is None else L0.ctypes.data, opt, fl)

    @cached_property
    def _noise_cov(self) -> np.ndarray:
        """Γ R Γᵀ of the compiled path (Γ constant, or I)."""
        G = np.eye(self.space.n_y) if self._noise_map is None else self._noise_map
        return G @ self.R @ G.T

    def _proposal_step(self, X, y, p, rngs, k, bank, want):
        """One EKF/UKF-proposal step (module notes): the Gaussian filter's compiled step from
        N(x^i, 0) with y gives N(m^i, Σ^i); x'^i ~ N(m^i, Σ^i), and the log-weight increment
        log p(y | x') + log N(x'; f(x), Q) − log N(x'; m, Σ).

        Returns the particles, the increments, f(x) (the predicted means) and the
        predicted measurements ŷ^i and S^i of each particle's step (None unless wanted)."""
        ss, N, kf = self.space, self.particles, self._kf
        Rr, _, n = X.shape
        flat = X.reshape(-1, n)
        Yrep = np.repeat(y, N, axis=0)[:, None, :]
        prow = None if p is None else np.repeat(p, N, axis=0)
        predicted = want("innovation", "S", "nis")
        keep = frozenset({"x", "P"} | ({"innovation", "S"} if predicted else set()))
        out, _ = kf.strategy.run(kf, Yrep, flat, np.zeros((n, n)), keep, params=None if prow is None else prow[:, None, :])
        failed = out.pop("first_nonfinite")
        if (failed >= 0).any():
            i = int(np.flatnonzero(failed >= 0)[0])
            where = f"step {k}" if bank is None else f"run {i // N}, step {k}"
            raise SymmonError(f"{self.method}: the {kf.method} proposal of particle {i % N} failed at {where} (its "
                              "covariance lost positive definiteness, or S is singular)")
        m, Sig = out["x"][:, 0], out["P"][:, 0]
        try:
            L = np.linalg.cholesky(Sig)
        except np.linalg.LinAlgError:
            raise SymmonError(f"{self.method}: a proposal covariance of step {k} is not positive definite "
                              "(a particle's Gaussian step lost definiteness); use proposal='bootstrap'") from None
        Z = np.concatenate([g.standard_normal((N, n)) for g in rngs])
        Xn = ss.wrap_states(m + np.einsum("nij,nj->ni", L, Z))
        log_q = -0.5 * (Z * Z).sum(axis=1) - np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=1)
        fx = ss.transition(flat, None, prow)
        d = Xn - fx
        if ss.angle_states:
            d[:, list(ss.angle_states)] = wrap_angle(d[:, list(ss.angle_states)])
        Lq = np.linalg.cholesky(self.Q)
        zq = rows_times(d, np.linalg.inv(Lq))
        log_f = -0.5 * (zq * zq).sum(axis=1) - np.log(np.diag(Lq)).sum()  # the 2π terms cancel with log_q's
        Xn = Xn.reshape(Rr, N, n)
        ll, _, _ = self._loglik(Xn, y, p)
        inc = ll + (log_f - log_q).reshape(Rr, N)
        y_hat = S_i = None
        if predicted:  # ŷ^i = y − ν^i (a missing component: any finite value, left out)
            y_hat = (np.where(np.isnan(Yrep[:, 0]), 0.0, Yrep[:, 0]) - out["innovation"][:, 0]).reshape(Rr, N, -1)
            S_i = out["S"][:, 0].reshape(Rr, N, ss.n_y, ss.n_y)
        return Xn, inc, fx.reshape(Rr, N, n), y_hat, S_i


def _store_measurement(out: dict, k: int, nu: np.ndarray, S: np.ndarray) -> None:
    """Write step ``k``'s innovation, its covariance and the NIS into the kept arrays of ``out``."""
    if "innovation" in out:
        out["innovation"][:, k] = nu
    if "S" in out:
        out["S"][:, k] = S
    if "nis" in out:
        out["nis"][:, k] = np.einsum("ri,ri->r", nu, np.linalg.solve(S, nu[..., None])[..., 0])
