"""The ensemble Kalman filters: perturbed observations (EnKF) and the deterministic square root (ETKF).

The model is that of :class:`~symmon.NonlinearKalmanFilter`: x_{k+1} = f(x_k, w_k),
y_k = h(x_k, e_k), w_k ~ N(0, Q), e_k ~ N(0, R) (additive noises without noise symbols;
the measurement noise must enter h affinely with a constant map Γ, y = h(x, 0) + Γ e).
N members x^i carry the distribution; a step

1. propagates each member by the compiled f with its own process noise L_Q z^i (no draw
   when Q = 0): f runs once on the R·N rows of all runs of a bank;
2. inflates the forecast anomalies x^i − x̄ by the factor λ = ``inflation`` (the covariance
   by λ²; the convention of DAPPER's ``infl``);
3. with the measured components m of y_k (a missing one is NaN; none measured: no update,
   log-likelihood 0), the forecast measurements ŷ^i = h(x^i) give the Gaussian
   approximation of the predicted measurement, N(ȳ, S) with S = Y Yᵀ/(N − 1) + Γ R Γᵀ
   (Y the anomalies of ŷ^i), whence the innovation ν = y − ȳ, its NIS νᵀ S⁻¹ ν and the
   log-likelihood term log N(ν; 0, S);
4. updates the members:

   - ``kind="stochastic"`` (Burgers, van Leeuwen & Evensen 1998; Evensen 2003, §4):
     x^i ← x^i + K (y + ε^i − ŷ^i), K = A Yᵀ/(N − 1) S⁻¹ with A the state anomalies and
     ε^i ~ N(0, Γ R Γᵀ) drawn for each member, centred over the members (as DAPPER's
     ``PertObs``), so that the analysis mean is the Kalman update of the forecast mean with
     the ensemble's gain.  ``localisation`` multiplies K entrywise by a taper ρ (n × n_y);
   - ``kind="sqrt"``, the ensemble transform Kalman filter (Bishop, Etherton & Majumdar
     2001, in the symmetric form of Hunt, Kostelich & Szunyogh 2007, §2.3): with
     Ỹ = L_R⁻¹ Y/√(N − 1), P̃ = (I + ỸᵀỸ)⁻¹ (N × N), the mean moves by A P̃ ỸᵀL_R⁻¹ν/√(N − 1)
     and the anomalies become P̃^{1/2} A (the symmetric square root, which keeps their mean
     at zero).  No random number is drawn in the update.  When the forecast ensemble's
     sample mean and covariance are a Kalman prior and h is linear, the analysis mean and
     sample covariance are the Kalman update exactly (tests/filters/test_enkf.py).

   Both work from the thin singular value decomposition Ỹ = U Σ Wᵀ of the whitened spread
   (L_R⁻¹ made once per pattern of measured components): S⁻¹ = L_R⁻ᵀ (I − U Σ²(I + Σ²)⁻¹ Uᵀ)
   L_R⁻¹, and the NIS and log det S = log det R + Σ log(1 + σ²) by the matrix determinant
   lemma, O(d² N) a run for d ≤ N measured components, with no d × d factor and no N × N
   eigenproblem; without localisation the stochastic update is the members' N × N
   combination D S⁻¹ Yᵀ A/(N − 1) of the anomalies.

The filtered moments are the members' sample mean (circular for angle states) and sample
covariance (divisor N − 1, deviations wrapped); so P is singular when N ≤ n, and the NEES
(``x_true=``) then refuses it.  Angle states are wrapped after each propagation and update,
angle outputs' innovations (of the mean and of each member) are wrapped.

Every run of a bank draws from its own stream (:func:`~symmon.filters.bank.run_streams`):
first its N prior members, then at each step the process noise and, for the stochastic
filter, the measurement perturbations of its measured components; so run r of a bank is the
same whatever the other runs and however the bank is sharded.

:meth:`EnsembleKalmanFilter.smooth` is the ensemble Rauch–Tung–Striebel smoother (Raanes
2016, eq. (13)): x^i_{k|K} = x^i_{k|k} + A_{k|k} A_{k+1|k}⁺ (x^i_{k+1|K} − x^i_{k+1|k}), with
A⁺ the pseudo-inverse of the (inflated) forecast anomalies; on a linear model without
process noise and N > n it is the RTS smoother of the ensemble's moments.

Localisation of the ETKF needs the local analyses of the LETKF (Hunt et al. 2007, §2.3),
which are not implemented: ``kind="sqrt"`` refuses ``localisation``.

References
----------
G. Burgers, P. J. van Leeuwen, G. Evensen, "Analysis scheme in the ensemble Kalman filter",
Mon. Wea. Rev. 126, 1998. doi:10.1175/1520-0493(1998)126<1719:ASITEK>2.0.CO;2
G. Evensen, "The ensemble Kalman filter: theoretical formulation and practical
implementation", Ocean Dynamics 53, 2003. doi:10.1007/s10236-003-0036-9
C. H. Bishop, B. J. Etherton, S. J. Majumdar, "Adaptive sampling with the ensemble transform
Kalman filter. Part I", Mon. Wea. Rev. 129, 2001. doi:10.1175/1520-0493(2001)129<0420:ASWTET>2.0.CO;2
B. R. Hunt, E. J. Kostelich, I. Szunyogh, "Efficient data assimilation for spatiotemporal
chaos: a local ensemble transform Kalman filter", Physica D 230, 2007.
doi:10.1016/j.physd.2006.11.008
P. Sakov, P. R. Oke, "A deterministic formulation of the ensemble Kalman filter: an
alternative to ensemble square root filters", Tellus A 60, 2008.
doi:10.1111/j.1600-0870.2007.00299.x
P. N. Raanes, "On the ensemble Rauch–Tung–Striebel smoother and its equivalence to the
ensemble Kalman smoother", Q. J. R. Meteorol. Soc. 142, 2016. doi:10.1002/qj.2728
G. Gaspari, S. E. Cohn, "Construction of correlation functions in two and three
dimensions", Q. J. R. Meteorol. Soc. 125, 1999. doi:10.1002/qj.49712555417
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar, Iterable

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike

from ...core.angles import wrap_angle
from ...core.arrays import readonly
from ...core.gaussian import float_array, matrix_sqrt
from ...core.mixture import Empirical, GaussianMixture
from ...core.model import Model
from ...errors import ArgumentError, CovarianceError, ModelError, NonFiniteError, ShapeError, plain_repr
from ...transforms.executor import one_blas_thread
from ..bank import run_streams
from ..base import Filter
from ..inputs import FilterCall, check_bank_size, check_call, initial_state, param_values
from ..results import KalmanResult, SmootherResult, nees_of
from ..statespace import StateSpace

__all__ = ["EnsembleKalmanFilter", "EnsembleResult", "KINDS", "gaspari_cohn"]

#: The analyses: perturbed observations, or the deterministic square root (ETKF).
KINDS = ("stochastic", "sqrt")
_LOG_2PI = math.log(2 * math.pi)
#: Singular values of the forecast anomalies below this fraction of the largest count as
#: zero in the smoother's pseudo-inverse (the anomalies have rank at most N − 1).
PINV_RCOND = 1e-10


def gaspari_cohn(distance: ArrayLike, radius: float) -> np.ndarray:
    """The compactly supported fifth-order taper of Gaspari & Cohn (1999, eq. (4.10)): 1 at
    distance 0, 0 beyond 2·``radius``; ``radius`` is its half-width c.

    Examples
    --------
    >>> gaspari_cohn([0.0, 1.0, 2.0], 1.0).round(4).tolist()
    [1.0, 0.2083, 0.0]
    """
    if isinstance(radius, bool) or not isinstance(radius, (int, float, np.integer, np.floating)) \
            or not math.isfinite(radius) or radius <= 0:
        raise ArgumentError(f"radius must be a positive number, got {plain_repr(radius)}")
    r = np.abs(float_array(distance, "distance")) / float(radius)
    out = np.zeros_like(r)
    a = r <= 1
    b = (r > 1) & (r < 2)
    ra, rb = r[a], r[b]
    out[a] = -0.25 * ra**5 + 0.5 * ra**4 + 0.625 * ra**3 - 5 / 3 * ra**2 + 1
    out[b] = rb**5 / 12 - 0.5 * rb**4 + 0.625 * rb**3 + 5 / 3 * rb**2 - 5 * rb + 4 - 2 / 3 / rb
    return out


@dataclass(frozen=True, eq=False)
class EnsembleResult(KalmanResult):
    """The result of :meth:`EnsembleKalmanFilter.filter`: the Kalman filters' result
    (:class:`~symmon.filters.results.KalmanResult`: ``x`` and ``P`` are the members' sample
    mean and covariance after each update, ``x_pred`` and ``P_pred`` those of the inflated
    forecast, ``innovation`` and ``S`` the Gaussian approximation of the predicted
    measurement, ``loglik`` log N(ν; 0, S) of each step, NEES, NIS, ANEES), plus

    Attributes
    ----------
    members : int
        N.
    final_ensemble : ndarray, shape (N, n) or (R, N, n)
        The members after the last update, e.g. to continue from them (as an
        :class:`~symmon.Empirical` prior).
    """

    members: int = 0
    final_ensemble: np.ndarray | None = None

    def __repr__(self) -> str:
        runs = "" if self.runs is None else f"runs={self.runs}, "
        return f"EnsembleResult({self.method}, {runs}steps={self.steps}, n={self.n}, members={self.members})"


@dataclass(frozen=True, eq=False)
class EnsembleKalmanFilter(Filter):
    """An ensemble Kalman filter on the compiled models: perturbed observations or the ETKF.

    Parameters
    ----------
    f_model, h_model : Model
        The dynamics (n → n) and the measurement (n → n_y), as for
        :class:`~symmon.NonlinearKalmanFilter` (angle states and outputs wrapped).  The
        measurement noise must enter h as y = h(x, 0) + Γ e with Γ constant (additive noise
        without noise symbols); the process noise may enter f in any way.
    Q, R : array_like
        Process and measurement noise covariances (of the noise symbols, or additive); Q may
        be zero (a perfect model, no draw), Γ R Γᵀ must be positive definite.
    members : int, default 100
        N ≥ 2, per run.
    kind : {"stochastic", "sqrt"}
        Perturbed observations (Burgers et al. 1998; Evensen 2003) or the deterministic
        ensemble transform filter (Bishop et al. 2001; Hunt et al. 2007) (module notes).
    inflation : float, default 1.0
        λ ≥ 1: the forecast anomalies are multiplied by λ before each update (the
        covariance by λ²).
    localisation : array_like of shape (n, n_y), or callable, optional
        A taper ρ multiplied entrywise into the gain of the stochastic filter (ρ ∘ K): ρ[i, j]
        weighs measurement j's correction of state i.  A callable is called once as
        ``localisation(i, j)`` with the integer grids i (n, 1) and j (1, n_y) and returns ρ
        (e.g. ``lambda i, j: gaspari_cohn(abs(i - j), 4.0)`` for states observed in place).
        Refused with ``kind="sqrt"`` (that needs the local analyses of the LETKF).
    seed : int, default 0
        The seed of every ``filter`` call: run r draws from child ``first_run + r`` of
        ``SeedSequence(seed)``.

    Raises
    ------
    ArgumentError
        For a bad ``members``, ``kind``, ``inflation``, ``localisation`` or ``seed``.
    ModelError
        When h is not affine in its noise symbols with a constant map.
    ShapeError, CovarianceError
        As :class:`~symmon.NonlinearKalmanFilter`; a singular Γ R Γᵀ.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> f, h = sm.Model([x], [0.9 * x]), sm.Model([x], [x])
    >>> xs, ys = sm.simulate(f, h, [[0.5]], [[0.1]], sm.Gaussian([0.0], [[1.0]]), 20, seed=1)
    >>> enkf = sm.EnsembleKalmanFilter(f, h, [[0.5]], [[0.1]], members=50, kind="sqrt")
    >>> res = enkf.filter(ys, sm.Gaussian([0.0], [[1.0]]))
    >>> res.x.shape, res.final_ensemble.shape, enkf.method
    ((20, 1), (50, 1), 'ETKF(N=50)')
    """

    f_model: Model
    h_model: Model
    Q: np.ndarray
    R: np.ndarray
    members: int = 100
    kind: str = "stochastic"
    inflation: float = 1.0
    localisation: Any = None
    seed: int = 0
    space: StateSpace = field(init=False, repr=False)

    random: ClassVar[bool] = True
    has_smoother: ClassVar[bool] = True
    takes_covariance: ClassVar[bool] = True

    def __post_init__(self) -> None:
        ss = StateSpace(self.f_model, self.h_model, self.Q, self.R)
        object.__setattr__(self, "space", ss)
        object.__setattr__(self, "Q", ss.Q)
        object.__setattr__(self, "R", ss.R)
        N = self.members
        if isinstance(N, (bool, np.bool_)) or not isinstance(N, (int, np.integer)) or N < 2:
            raise ArgumentError(f"members must be an integer of at least 2 (a sample covariance), got {plain_repr(N)}")
        object.__setattr__(self, "members", int(N))
        if not isinstance(self.kind, str) or self.kind not in KINDS:
            raise ArgumentError(f"kind must be one of {KINDS}, got {plain_repr(self.kind)}")
        lam = self.inflation
        if isinstance(lam, (bool, np.bool_)) or not isinstance(lam, (int, float, np.integer, np.floating)) \
                or not math.isfinite(lam) or lam < 1:
            raise ArgumentError(f"inflation must be a finite number of at least 1 (the factor of the forecast "
                                f"anomalies), got {plain_repr(lam)}")
        object.__setattr__(self, "inflation", float(lam))
        if isinstance(self.seed, (bool, np.bool_)) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ArgumentError(f"seed must be a non-negative integer, got {plain_repr(self.seed)}")
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "localisation", self._taper(self.localisation))
        _ = self._noise_cov  # refuse an h not affine in its noise, and a singular Γ R Γᵀ, now

    def _taper(self, loc: Any) -> np.ndarray | None:
        """The localisation as a read-only (n, n_y) taper, checked (None: none)."""
        if loc is None:
            return None
        if self.kind == "sqrt":
            raise ArgumentError("localisation is for kind='stochastic': the square-root filter would need the "
                                "local analyses of the LETKF, which symmon does not implement")
        n, n_y = self.sizes
        if callable(loc):
            i, j = np.arange(n)[:, None], np.arange(n_y)[None, :]
            try:
                loc = loc(i, j)
            except Exception as exc:
                raise ArgumentError(f"localisation(i, j) failed on the index grids (n, 1) and (1, n_y): {exc}") from exc
        rho = float_array(loc, "localisation", ArgumentError)
        if rho.shape != (n, n_y):
            raise ArgumentError(f"localisation must be a taper of shape (n, n_y) = ({n}, {n_y}), got {rho.shape}")
        if not np.all(np.isfinite(rho)) or np.any(rho < 0):
            raise ArgumentError("localisation must hold finite non-negative weights")
        return readonly(rho)

    # ------------------------------------------------------------------ set-up
    @property
    def sizes(self) -> tuple[int, int]:
        """(n, n_y): the state's and the measurement's dimensions."""
        return self.space.n, self.space.n_y

    def step_cost(self) -> int:
        """f and h at each member."""
        return 2 * self.members

    @property
    def params(self) -> tuple:
        """The parameters of the models (f's, then h's that f does not have)."""
        return self.space.params

    @property
    def method(self) -> str:
        """The filter's name, e.g. ``EnKF(N=40, inflation=1.06)`` or ``ETKF(N=40)``."""
        name = "EnKF" if self.kind == "stochastic" else "ETKF"
        extra = f", inflation={self.inflation:g}" if self.inflation != 1.0 else ""
        extra += ", localised" if self.localisation is not None else ""
        return f"{name}(N={self.members}{extra})"

    @cached_property
    def _noise_cov(self) -> np.ndarray:
        """Γ R Γᵀ, the covariance of the measurement given the state (Γ = ∂h/∂e, constant;
        I without noise symbols), checked positive definite."""
        h = self.h_model
        if h.n_v:
            J = sp.Matrix(h.outputs).jacobian(sp.Matrix(h.noise))
            if J.free_symbols:
                raise ModelError(f"h_model {h.name!r} must be y = h(x, 0) + Γ e with a constant Γ (the ensemble "
                                 f"filters' Gaussian likelihood); its ∂h/∂e depends on {sorted(map(str, J.free_symbols))}"
                                 "; write the noise additively")
            G = np.array(J.tolist(), dtype=float)
            S = G @ np.asarray(self.R) @ G.T
        else:
            S = np.array(self.R, dtype=float)
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise CovarianceError("the measurement covariance Γ R Γᵀ (R for additive noise) is singular: the "
                                  "ensemble update inverts it; give every measured component some noise") from None
        return readonly(S)

    # ------------------------------------------------------------------ the contract's hooks
    def _check_prior(self, x0: Any, P0: ArrayLike | None, runs: int | None) -> tuple[Any, np.ndarray | None]:
        """A GaussianMixture or an Empirical as given (P0 refused); a Gaussian, or a mean (n,)
        or (R, n) with P0 (n, n) or (R, n, n), as (mean, covariance)."""
        if isinstance(x0, (GaussianMixture, Empirical)):
            if P0 is not None:
                raise ShapeError("P0 must not be given with a GaussianMixture or Empirical x0")
            if x0.dim != self.space.n:
                raise ShapeError(f"x0 has dimension {x0.dim}, but the state has {self.space.n}")
            return x0, None
        return initial_state(self.space.n, x0, P0, runs)

    def _check_params(self, params: dict | None, runs: int | None, steps: int) -> np.ndarray | None:
        return param_values(self.space.params, params, runs, steps, who="the models")

    def _filter(self, call: FilterCall) -> EnsembleResult:
        """The recursion over the checked ``call`` (:meth:`filter`; module notes): forecast,
        inflate, update, for each measurement (``ys[k]`` is y_{k+1}).

        Raises
        ------
        NonFiniteError
            A member became NaN or inf (the model overflows), or S is not positive definite,
            naming the run and step.
        SingularMatrixError
            With ``x_true``, when the sample covariance is singular (N ≤ n).
        """
        return self._run(call, False)[0]

    # ------------------------------------------------------------------ the recursion
    def _prior_members(self, call: FilterCall, rngs: list[np.random.Generator]) -> np.ndarray:
        """The N members of each run drawn from the prior, (R, N, n): a Gaussian's from its
        mean and a square root of its covariance (per run when given per run); an Empirical
        of exactly N equally weighted samples is the ensemble itself (no draw), another is
        resampled by its weights; a GaussianMixture's by ``sample``."""
        N, n = self.members, self.space.n
        x0, P0 = call.x0, call.P0
        if P0 is None:
            if isinstance(x0, Empirical) and x0.n_samples == N and np.all(x0.weights == x0.weights[0]):
                return np.repeat(np.asarray(x0.samples, dtype=float)[None], len(rngs), axis=0)
            return np.stack([np.asarray(x0.sample(N, g), dtype=float) for g in rngs])
        m = np.broadcast_to(np.asarray(x0, dtype=float), (len(rngs), n))
        Ls = [matrix_sqrt(P0)] * len(rngs) if P0.ndim == 2 else [matrix_sqrt(C) for C in P0]
        return np.stack([m[r] + g.standard_normal((N, n)) @ Ls[r].T for r, g in enumerate(rngs)])

    def _moments(self, X: np.ndarray, angles: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The sample mean (circular for ``angles``) and the anomalies (wrapped) of members
        X (R, N, m)."""
        mean = X.mean(axis=1)
        idx = list(angles)
        if idx:
            A = X[..., idx]
            mean[:, idx] = np.arctan2(np.sin(A).mean(axis=1), np.cos(A).mean(axis=1))
        D = X - mean[:, None, :]
        if idx:
            D[..., idx] = wrap_angle(D[..., idx])
        return mean, D

    def _covariance(self, D: np.ndarray) -> np.ndarray:
        """The sample covariance Dᵀ D / (N − 1) of anomalies D (R, N, m), symmetric."""
        C = np.matmul(D.transpose(0, 2, 1), D) / (self.members - 1)
        return 0.5 * (C + C.transpose(0, 2, 1))

    def _not_finite(self, what: str, k: int, r: int, bank: int | None) -> NonFiniteError:
        where = f"step {k}" if bank is None else f"run {r}, step {k}"
        return NonFiniteError(f"{self.method}: at {where} {what} (the model overflows there; check the noise "
                              "covariances, the inflation and the prior)")

    def _run(self, call: FilterCall, store: bool) -> tuple[EnsembleResult, np.ndarray | None, np.ndarray | None]:
        """The forward pass; with ``store``, also every step's analysis and (inflated)
        forecast ensembles, (R, K, N, n) each, for the smoother."""
        ss, N = self.space, self.members
        n, n_y = ss.n, ss.n_y
        bank, Yb, pv, truth = call.runs, call.Y, call.pv, call.truth
        Rr, K = Yb.shape[0], call.steps
        check_bank_size(Rr, N, 4 * n + 2 * n_y, f"{self.method} members", "use fewer members or runs")
        names = frozenset(self.keepable) if call.keep is None else call.keep
        rngs = run_streams(self.seed, Rr, call.first_run)
        X = ss.wrap_states(self._prior_members(call, rngs))
        if not np.all(np.isfinite(X)):
            raise ShapeError("x0 gives members that are NaN or inf")
        out = {k: np.empty((Rr, K) + s) for k, s in (("x", (n,)), ("P", (n, n)), ("x_pred", (n,)),
                                                     ("P_pred", (n, n)), ("innovation", (n_y,)),
                                                     ("S", (n_y, n_y)), ("nis", ())) if k in names}
        loglik = np.zeros((Rr, K))
        nees = np.empty((Rr, K)) if truth is not None else None
        Ea = np.empty((Rr, K, N, n)) if store else None
        Ef = np.empty((Rr, K, N, n)) if store else None
        # BLAS on one thread: its threads, spinning between the small products and factors of
        # a step, would oversubscribe the cores beside the compiled f's (n = 128: 0.4 s a
        # 128 × 128 Cholesky factor on a loaded 2-core machine, 3 ms on one thread)
        with one_blas_thread(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # refused below
            for k in range(K):
                X = self._step(k, X, Yb, pv, rngs, out, loglik, nees, truth, Ea, Ef, names, bank)
        arrays = {k: v if bank is not None else v[0] for k, v in out.items()}
        if "nis" in arrays:
            arrays["nis_values"] = arrays.pop("nis")
        extra = {"loglik": loglik, "final_ensemble": X}
        if nees is not None:
            extra["nees_values"] = nees
        arrays.update({k: v if bank is not None else v[0] for k, v in extra.items()})
        for v in arrays.values():
            v.flags.writeable = False
        measured_n = None
        measured_all = ~np.isnan(Yb)
        if not measured_all.all():
            measured_n = measured_all.sum(axis=-1)
            measured_n = measured_n if bank is not None else measured_n[0]
            measured_n.flags.writeable = False
        res = EnsembleResult(**arrays, measured=measured_n, n_y=n_y, n_x=n, angle_states=ss.angle_states,
                             method=self.method, members=N)
        return res, Ea, Ef

    def _step(self, k, X, Yb, pv, rngs, out, loglik, nees, truth, Ea, Ef, names, bank) -> np.ndarray:
        """Step ``k`` of the recursion for every run: forecast, inflate, update; writes the
        kept arrays; returns the analysed members."""
        ss, N, lam = self.space, self.members, self.inflation
        n, n_y = ss.n, ss.n_y
        Rr = Yb.shape[0]
        noisy = bool(np.any(np.asarray(ss.Lq)))
        nq = ss.Lq.shape[0]
        Rn = self._noise_cov
        rho = self.localisation
        angle_y = list(ss.angle_outputs)
        store = Ea is not None
        y = Yb[:, k]
        prow = None if pv is None else np.repeat(pv[:, k], N, axis=0)
        Z = np.concatenate([g.standard_normal((N, nq)) for g in rngs]) if noisy else None
        Xf = ss.transition(X.reshape(-1, n), Z, prow).reshape(Rr, N, n)
        self._check_finite(Xf, "a forecast member is NaN or inf", k, bank)
        mf, Af = self._moments(Xf, ss.angle_states)
        if lam != 1.0:
            Af *= lam
            Xf = ss.wrap_states(mf[:, None, :] + Af)
            self._check_finite(Xf, "an inflated forecast member is NaN or inf", k, bank)
        if store:
            Ef[:, k] = Xf
        if "x_pred" in out:
            out["x_pred"][:, k] = mf
        if "P_pred" in out:
            out["P_pred"][:, k] = C = self._covariance(Af)
            self._check_finite(C, "the forecast covariance overflows", k, bank)
        HX = ss.measure(Xf.reshape(-1, n), None, prow).reshape(Rr, N, n_y)
        self._check_finite(HX, "a member's predicted measurement is NaN or inf", k, bank)
        ym, Ay = self._moments(HX, ss.angle_outputs)
        nu = y - ym
        if angle_y:
            nu[:, angle_y] = wrap_angle(nu[:, angle_y])
        Xa = Xf.copy()
        want_S = "S" in out or "nis" in out
        S_full = self._covariance(Ay) + Rn if want_S else None
        measured = ~np.isnan(y)
        for runs, m in _groups(measured):
            if m.size == 0:
                if "nis" in out:
                    out["nis"][runs, k] = 0.0
                continue
            c = slice(None) if m.size == n_y else m  # the measured components (a view when all are)
            Xa[runs] = self._update(Xf[runs], mf[runs], Af[runs], HX[runs][..., c], Ay[runs][..., c], y[runs][:, c],
                                    nu[runs][:, c], m, Rn[np.ix_(m, m)], None if rho is None else rho[:, c],
                                    [rngs[r] for r in np.arange(Rr)[runs]], loglik, out.get("nis"),
                                    np.arange(Rr)[runs], k, bank)
        Xa = ss.wrap_states(Xa)
        self._check_finite(Xa, "an analysed member is NaN or inf", k, bank)
        if store:
            Ea[:, k] = Xa
        if "innovation" in out or "S" in out:
            missing = ~measured
            v = np.where(missing, 0.0, nu)
            if "innovation" in out:
                out["innovation"][:, k] = v
            if "S" in out:
                S = np.where(missing[:, :, None] | missing[:, None, :], 0.0, S_full)
                r_, i_ = np.nonzero(missing)
                S[r_, i_, i_] = 1.0
                out["S"][:, k] = S
        if any(a in names for a in ("x", "P")) or truth is not None:
            ma, Aa = self._moments(Xa, ss.angle_states)
            Pa = self._covariance(Aa) if ("P" in out or truth is not None) else None
            if "x" in out:
                out["x"][:, k] = ma
            if Pa is not None:
                self._check_finite(Pa, "the analysis covariance overflows", k, bank)
            if "P" in out:
                out["P"][:, k] = Pa
            if truth is not None:
                nees[:, k] = nees_of(ma[:, None], Pa[:, None], truth[:, k:k + 1], ss.angle_states)[:, 0]
        return Xa

    def _check_finite(self, X: np.ndarray, what: str, k: int, bank: int | None,
                      runs: np.ndarray | None = None) -> None:
        """Refuse NaN or inf in X (R, ...) at step k, naming the first such run (of ``runs``
        when X holds those runs only)."""
        bad = ~np.isfinite(X).all(axis=tuple(range(1, X.ndim)))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise self._not_finite(what, k, r if runs is None else int(runs[r]), bank)

    def _update(self, Xf, mf, Af, HX, Ay, y, nu, m, Rm, rho, rngs, loglik, nis, runs, k, bank) -> np.ndarray:
        """The analysis of the runs ``runs`` that measured the components ``m`` (module notes);
        writes their log-likelihood terms (and NIS) at step ``k``; returns their members."""
        N = self.members
        Lr, Li, logdet_r = self._whitening(m, Rm)
        angle_y = [j for j, c in enumerate(m) if c in self.space.angle_outputs]
        Yw = np.matmul(Li, Ay.transpose(0, 2, 1)) / math.sqrt(N - 1)  # Ỹ = L_R⁻¹ Y / √(N − 1), (r, d, N)
        vw = np.matmul(Li, nu[..., None])[..., 0]  # L_R⁻¹ ν, (r, d)
        self._check_finite(Yw, "the spread of the predicted measurements overflows", k, bank, runs)
        # Ỹ = U Σ Wᵀ (thin): S = L_R (I + Ỹ Ỹᵀ) L_Rᵀ, so S⁻¹ = L_R⁻ᵀ (I − U diag(σ²/(1+σ²)) Uᵀ) L_R⁻¹,
        # νᵀ S⁻¹ ν = |L_R⁻¹ν|² − Σ σ²/(1+σ²) (Uᵀ L_R⁻¹ν)² and log det S = log det R + Σ log(1 + σ²)
        # (the matrix determinant lemma): O(d² N) for d ≤ N, no d × d factor per run
        U, sig, Wt = np.linalg.svd(Yw, full_matrices=False)
        s2 = sig * sig
        b = np.matmul(U.transpose(0, 2, 1), vw[..., None])[..., 0]  # Uᵀ L_R⁻¹ ν
        self._likelihood(loglik, nis, runs, k, (vw * vw).sum(axis=1) - (s2 / (1.0 + s2) * b * b).sum(axis=1),
                         logdet_r + np.log1p(s2).sum(axis=1), m.size, bank)
        if self.kind == "stochastic":
            E = np.stack([g.standard_normal((N, m.size)) for g in rngs]) @ Lr.T
            E -= E.mean(axis=1, keepdims=True)
            D = y[:, None, :] + E - HX  # each member's innovation
            if angle_y:
                D[..., angle_y] = wrap_angle(D[..., angle_y])
            Ut = U.transpose(0, 2, 1)

            def s_inv(V: np.ndarray) -> np.ndarray:  # S⁻¹ V for V (r, d, c)
                Vw = np.matmul(Li, V)
                Vw = Vw - np.matmul(U, (s2 / (1.0 + s2))[..., None] * np.matmul(Ut, Vw))
                return np.matmul(Li.T, Vw)

            d, n = m.size, Af.shape[2]
            if rho is None and N * (d + n) < d * d + 2 * d * n:  # fewer members than states and outputs:
                # in the members' space, D S⁻¹ Yᵀ A / (N − 1) (Y the anomalies of h), O(N² (d + n))
                G = np.matmul(s_inv(D.transpose(0, 2, 1)).transpose(0, 2, 1), Ay.transpose(0, 2, 1))
                return Xf + np.matmul(G, Af) / (N - 1)
            Kg = np.matmul(s_inv(Ay.transpose(0, 2, 1)), Af).transpose(0, 2, 1) / (N - 1)  # K = P Hᵀ S⁻¹ (r, n, d)
            if rho is not None:
                Kg = Kg * rho
            return Xf + np.matmul(D, Kg.transpose(0, 2, 1))
        # ETKF (Hunt et al. 2007, §2.3), in the members' space: P̃ = I − W diag(σ²/(1+σ²)) Wᵀ and
        # P̃^{1/2} = I + W diag(1/√(1+σ²) − 1) Wᵀ, not the N × N eigenproblem
        w = np.matmul(Wt.transpose(0, 2, 1), (sig / (1.0 + s2) * b)[..., None])[..., 0]  # P̃ Ỹᵀ L_R⁻¹ ν
        shrink = 1.0 / np.sqrt(1.0 + s2) - 1.0
        TA = Af + np.matmul(Wt.transpose(0, 2, 1), shrink[..., None] * np.matmul(Wt, Af))  # P̃^{1/2} A
        mean = mf + np.matmul(w[:, None, :], Af)[:, 0] / math.sqrt(N - 1)
        return mean[:, None, :] + TA

    def _likelihood(self, loglik, nis, runs, k, q, logdet, d, bank) -> None:
        """Write log N(ν; 0, S) from q = νᵀ S⁻¹ ν and log det S (and the NIS q) at step k;
        refuse one that is not finite (S overflows)."""
        ll = -0.5 * (q + logdet + d * _LOG_2PI)
        self._check_finite(ll[:, None], "the innovation covariance S overflows", k, bank, runs)
        loglik[runs, k] = ll
        if nis is not None:
            nis[runs, k] = q

    @cached_property
    def _whitenings(self) -> dict:
        """(L_R, L_R⁻¹, log det R) by the measured components' pattern, a few kept."""
        return {}

    def _whitening(self, m: np.ndarray, Rm: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """L_R with L_R L_Rᵀ = R of the components ``m``, its inverse and log det R (made once
        per pattern: R is constant)."""
        key = m.tobytes()
        got = self._whitenings.get(key)
        if got is None:
            Lr = np.linalg.cholesky(Rm)
            got = (Lr, np.linalg.inv(Lr), float(2 * np.log(np.diag(Lr)).sum()))
            if len(self._whitenings) < 64:
                self._whitenings[key] = got
        return got

    # ------------------------------------------------------------------ the smoother
    def smooth(self, ys: ArrayLike, x0: Any, P0: ArrayLike | None = None, *, keep: Iterable[str] | str | None = None,
               params: dict | None = None, first_run: int = 0) -> SmootherResult:
        """The ensemble Rauch–Tung–Striebel smoother (Raanes 2016; module notes): the
        forward pass of :meth:`filter`, then each member moved backwards by
        x^i_{k|K} = x^i_{k|k} + A_{k|k} A_{k+1|k}⁺ (x^i_{k+1|K} − x^i_{k+1|k}).

        Parameters
        ----------
        ys, x0, P0, keep, params, first_run
            As for :meth:`filter` (the forward pass keeps ``x`` and ``P`` too).

        Returns
        -------
        SmootherResult
            ``x`` (K, n) and ``P`` (K, n, n), the smoothed members' sample mean and
            covariance ((R, K, ...) for a bank), and ``filtered``, the forward pass.

        Raises
        ------
        ResourceError
            The stored ensembles (2 · R · K · N · n numbers) would exceed the bound.
        """
        call = check_call(self, ys, x0, P0, keep=keep, params=params, first_run=first_run)
        if call.keep is not None:
            call = _with_keep(call, call.keep | {"x", "P"})
        n, N = self.space.n, self.members
        Rr, K = call.Y.shape[0], call.steps
        check_bank_size(Rr, K, 2 * N * n + n + n * n, f"{self.method} smoother ensembles",
                        "use fewer members, steps or runs")
        filtered, Ea, Ef = self._run(call, True)
        angles = self.space.angle_states
        xs, Ps = np.empty((Rr, K, n)), np.empty((Rr, K, n, n))
        Es = Ea[:, K - 1]
        with one_blas_thread():
            self._backward(Ea, Ef, Es, xs, Ps)
        if call.runs is None:
            xs, Ps = xs[0], Ps[0]
        return SmootherResult(readonly(xs), readonly(Ps), filtered, angle_states=angles,
                              method=f"{self.method} RTS smoother")

    def _backward(self, Ea: np.ndarray, Ef: np.ndarray, Es: np.ndarray, xs: np.ndarray, Ps: np.ndarray) -> None:
        """The smoother's backward pass from the last analysis ensemble ``Es``: writes the
        smoothed moments of every step into ``xs`` and ``Ps``."""
        angles = self.space.angle_states
        K = Ea.shape[1]
        for k in range(K - 1, -1, -1):
            if k < K - 1:
                _, Aa = self._moments(Ea[:, k], angles)
                _, Af = self._moments(Ef[:, k + 1], angles)
                D = Es - Ef[:, k + 1]
                if angles:
                    D[..., list(angles)] = wrap_angle(D[..., list(angles)])
                J = np.linalg.pinv(Af, rcond=PINV_RCOND)  # (R, n, N)
                Es = self.space.wrap_states(Ea[:, k] + np.matmul(np.matmul(D, J), Aa))
            xs[:, k], A = self._moments(Es, angles)
            Ps[:, k] = self._covariance(A)


def _groups(measured: np.ndarray) -> list[tuple[slice | np.ndarray, np.ndarray]]:
    """The runs that measured the same components, and those components, from the mask
    (R, n_y) of one step; all runs at once (a slice: no copies) when every one measured all."""
    if measured.all():
        return [(slice(None), np.arange(measured.shape[1]))]
    out = []
    for pattern in np.unique(measured, axis=0):
        out.append((np.flatnonzero((measured == pattern).all(axis=1)), np.flatnonzero(pattern)))
    return out


def _with_keep(call: FilterCall, keep: frozenset[str]) -> FilterCall:
    """``call`` keeping ``keep``."""
    return dataclasses.replace(call, keep=keep)
