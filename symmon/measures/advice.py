"""Which transform is good enough here? The moments of every candidate against a reference.

A measure of nonlinearity exists to choose an estimator.  :func:`advise` computes the
moments of y = g(u, v) by each candidate transform (TT1, TT2, the unscented family,
Gauss–Hermite, Monte Carlo), compares them with the most accurate affordable reference,
and picks the cheapest candidate whose error is within a tolerance.

The reference is Gauss–Hermite of order 7 (a sparse grid above 4 dimensions) when its
two-order error estimate (order 9, :func:`symmon.quadrature_error`) shows it converged to
well within the tolerance; otherwise Monte Carlo, whose jackknife standard error bounds
the reference's own error.

The error is unitless, like the normalised MoN of Straka & Havlík (2024): differences are
measured in the reference's own standard deviations,

    e = max( ‖L_y⁻¹ Δμ‖, ‖L_y⁻¹ ΔΣ_yy L_y⁻ᵀ‖₂, ‖L_y⁻¹ ΔΣ_yu L_u⁻ᵀ‖₂ ),

with L_y L_yᵀ = Cov y and L_u L_uᵀ = Cov u of the reference, so e = 0.01 means the mean is
off by 1 % of a standard deviation, or the covariance by 1 % relative.  It does not change
with the units of u or y.

The cost of a candidate is counted in evaluations of g: TT1 needs g and J (1 + n_w),
TT2 g, J and H (1 + n_w + n_w(n_w + 1)/2), the unscented family 2 n_w + 1 points,
Gauss–Hermite its nodes and Monte Carlo its samples.  Beside it, two measured times of the
candidate's moments (:func:`symmon.propagate`): the *first call*, which includes compiling
what the rule needs and the reference and the earlier candidates have not compiled yet (the
derivatives of g, C code), and the *warm* time, the median of up to :data:`WARM_REPEATS`
further calls.  The choice never depends on the times.

The tolerance: :data:`DEFAULT_TOL` = 0.01 is the default of :func:`advise` and of the
adaptive filter (:class:`symmon.Adaptive`): 1 % of a standard deviation in the mean, 1 % relative in the
covariances.  Read against the MoN (Straka & Havlík 2024): with W^full (43), M² (25), (29)
is the share of the output's variance, whitened and averaged over its n_y components, that
the best affine approximation A u + b ((9), (10)) leaves unexplained; it is 1 − R², the
multivariate coefficient of determination (Remark 1), and lies in [0, 1] (33).  For a
scalar quadratic g the EKF's (TT1's) error in this measure is exactly M/√2 (its mean misses
½ tr(H P); its variance is off by M² relative), so the default keeps the EKF where
M ≤ √2 · 0.01 ≈ 0.014.  Why 0.01 and not tighter or looser: docs/guide/advise.md.

**The transform question only.**  :func:`advise` answers which rule carries this prior's
moments within ``tol``; which *filter* to run along a track is the question of
:func:`symmon.advise_filter`, which measures the MoN along a simulated track and confirms
its choice by a pilot study (the printout of :func:`advise` names no filter).

**Beyond Gaussian filters.**  The advice keeps, as data, a first guess at a filter for this
one prior (:attr:`Advice.filter`, not printed; :func:`symmon.advise_filter` decides).  A
Gaussian filter with the chosen rule while a candidate is within ``tol`` and the reference's
MoN is at most :data:`GAUSSIAN_MON_LIMIT` (0.15: in the tracking study of docs/tracking.md,
the EKF lost consistency at a closest approach at MoN 0.15–0.59, and never below 0.045).
Otherwise no single Gaussian follows the model, and the advice is a Gaussian-sum filter
(:class:`symmon.GaussianSumFilter`) whose MoN-driven splitting brings each component's MoN
to √2 · tol, where the EKF is within ``tol`` on a quadratic (above): a split of a component
into 3 (``symmon.core.mixture.SPLITS``) scales its variance along the most curved direction
by σ² ≈ 0.53, and with it a quadratic's MoN along that direction, so L = ⌈log(M/(√2 tol)) /
log(1/σ²)⌉ levels of splits and 3^L components are needed (a scalar quadratic: exact); above
:data:`MAX_GSF_COMPONENTS` components, a particle filter (:class:`symmon.ParticleFilter`).
These counts are the splitting's arithmetic on the reference's MoN, an estimate for one
prior, not a guarantee along a track: the bearings-only study (``symmon reproduce bot``,
docs/bot.md) measures where each filter keeps its credibility.
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..core.angles import wrap_angle
from ..errors import ArgumentTypeError, SymmonError, plain_repr
from ..core.gaussian import Gaussian
from ..core.mixture import SPLITS, Empirical, GaussianMixture
from ..core.model import Model, with_param_values
from ..propagation.joint import JointMoments
from .mon import nonlinearity
from ..propagation.front import propagate
from ..transforms.taylor import TT1, TT2
from ..transforms.unscented import UT
from ..transforms.quadrature import GaussHermite
from ..transforms.montecarlo import MonteCarlo
from ..transforms.base import Transform
from ..transforms.registry import names as transform_names, resolve

__all__ = ["advise", "Advice", "moment_error", "moment_distance", "whiteners", "CANDIDATES", "cost",
           "DEFAULT_TOL", "GAUSSIAN_MON_LIMIT", "MAX_GSF_COMPONENTS", "filter_advice"]

#: The default tolerance of :func:`advise` and of :class:`symmon.Adaptive`, in the unitless
#: error of the moments (module notes): 1 % of a standard deviation in the mean, 1 %
#: relative in the covariances; the EKF passes on a scalar quadratic while its MoN (43) is
#: at most √2 · 0.01.  Justified in docs/guide/advise.md.
DEFAULT_TOL = 1e-2

#: The MoN (W^full) above which no single Gaussian is advised, whatever the moment errors: the
#: least MoN at which the EKF of docs/tracking.md lost consistency at a closest approach.
GAUSSIAN_MON_LIMIT = 0.15
#: The most components of an advised Gaussian-sum filter (4 levels of 3-splits); beyond, a
#: particle filter.
MAX_GSF_COMPONENTS = 81

#: The candidates, by name, in the order of the table.
CANDIDATES: tuple[tuple[str, Transform], ...] = (
    ("TT1", TT1()),
    ("TT2", TT2()),
    ("UT ut1", UT.ut1()),
    ("UT ut2", UT.ut2()),
    ("cubature", UT.cubature()),
    ("Gauss-Hermite 3", GaussHermite(3)),
    ("Gauss-Hermite 5", GaussHermite(5)),
    ("Monte Carlo 1e5", MonteCarlo(10**5, seed=0)),
)

#: The reference Gauss–Hermite order (its error estimate uses order + 2).
REFERENCE_ORDER = 7
#: The reference must be this many times more accurate than the tolerance.
REFERENCE_MARGIN = 10.0
#: Above this many nodes the Gauss–Hermite reference is not affordable: Monte Carlo instead.
#: A Gauss–Hermite rule (reference or candidate) whose tensor grid is within it uses the
#: tensor grid; above it, the sparse grid.
MAX_REFERENCE_NODES = 200_000
#: Warm calls timed after the first call of each candidate (their median is reported) ...
WARM_REPEATS = 3
#: ... unless they take longer than this many seconds together: a slow candidate is timed fewer times.
WARM_BUDGET_S = 1.0


def whiteners(C: np.ndarray) -> np.ndarray:
    """Batched A_k with A_k C_k A_kᵀ = I on the range of each C_k (K, d, d).

    A pseudo-inverse square root: rows for the null space of C_k are zero.  The
    eigen-decomposition is of the correlation matrix, so that the rank decision does not
    depend on the units of the components.
    """
    d = np.sqrt(np.clip(np.einsum("...ii->...i", C), 0.0, None))
    D = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Rm = D[:, :, None] * C * D[:, None, :]
    lam, V = np.linalg.eigh(0.5 * (Rm + np.swapaxes(Rm, 1, 2)))
    inv = np.where(lam > lam[:, -1:] * 1e-12, 1.0 / np.sqrt(np.clip(lam, 1e-300, None)), 0.0)
    return np.swapaxes(V * inv[:, None, :], 1, 2) * D[:, None, :]


def moment_distance(a: Any, b: Any, Ay: np.ndarray, Aw: np.ndarray, angles: frozenset[int]) -> np.ndarray:
    """The unitless distance (module notes) of batched moments ``a`` and ``b`` (K,).

    ``a`` and ``b`` have ``mean`` (K, n_y), ``cov`` (K, n_y, n_y) and ``cross_cov``
    (K, n_y, n_w); ``Ay`` and ``Aw`` are :func:`whiteners` of Cov y and of the input
    covariance; angle outputs' mean differences are wrapped.
    """
    dmu = a.mean - b.mean
    if angles:
        idx = sorted(angles)
        dmu[:, idx] = wrap_angle(dmu[:, idx])
    e_mean = np.linalg.norm(np.einsum("rij,rj->ri", Ay, dmu), axis=-1)
    e_cov = np.linalg.norm(Ay @ (a.cov - b.cov) @ np.swapaxes(Ay, 1, 2), 2, axis=(1, 2))
    e_cross = np.linalg.norm(Ay @ (a.cross_cov - b.cross_cov) @ np.swapaxes(Aw, 1, 2), 2, axis=(1, 2))
    return np.maximum(e_mean, np.maximum(e_cov, e_cross))


def _reference_whiteners(ref: JointMoments) -> tuple[np.ndarray, np.ndarray]:
    """:func:`whiteners` of the reference's Cov y and Cov u; an error if either is zero."""
    out = []
    for C, what in ((ref.cov, "covariance Cov y"), (ref.input.cov, "input covariance Cov u")):
        if not (np.diag(C) > 0).any():
            raise SymmonError(f"the reference {what} is zero: the error cannot be measured in its units")
        out.append(whiteners(C[None]))
    return out[0], out[1]


def moment_error(m: JointMoments, ref: JointMoments) -> float:
    """The unitless error of the moments ``m`` against ``ref`` (module notes).

    Parameters
    ----------
    m, ref : JointMoments
        Of the same model and input.

    Returns
    -------
    float
        max of the whitened mean, covariance and cross-covariance differences.
    """
    Ay, Au = _reference_whiteners(ref)

    def one(x: JointMoments) -> SimpleNamespace:  # a batch of one
        return SimpleNamespace(mean=x.mean[None], cov=x.cov[None], cross_cov=x.cross_cov[None])

    return float(moment_distance(one(m), one(ref), Ay, Au, ref.angles)[0])


def _error_bound(ref: JointMoments, err: dict[str, np.ndarray]) -> float:
    """The unitless size of an error bound given entrywise (mean, cov, cross_cov)."""
    Ay, Au = (A[0] for A in _reference_whiteners(ref))
    e_mean = np.linalg.norm(Ay @ np.abs(err["mean"]))
    # |A E Aᵀ|₂ ≤ ‖ |A| |E| |A|ᵀ ‖₂ for an entrywise bound |E|.
    e_cov = np.linalg.norm(np.abs(Ay) @ np.abs(err["cov"]) @ np.abs(Ay).T, 2)
    e_cross = np.linalg.norm(np.abs(Ay) @ np.abs(err["cross_cov"]) @ np.abs(Au).T, 2)
    return float(max(e_mean, e_cov, e_cross))


def cost(transform: Transform, n_w: int) -> int:
    """The cost of ``transform`` in evaluations of g (module notes): its declared
    :meth:`~symmon.Transform.cost`."""
    try:
        return int(transform.cost(n_w))
    except NotImplementedError:
        raise SymmonError(f"no cost model for {transform!r}") from None


@dataclass(frozen=True)
class Advice:
    """The result of :func:`advise`.

    Attributes
    ----------
    rows : list of dict
        One per candidate, in the order of the candidates: ``name``, ``transform`` (as run:
        a Gauss–Hermite rule with its grid made explicit), ``error`` (the unitless error of
        its moments against the reference, module notes), ``cost`` (evaluations of g),
        ``first_call`` (seconds, compilation included), ``warm`` (seconds, the median of
        the warm calls), ``seconds`` (the same as ``warm``), ``mon`` (the MoN that this
        candidate's own moments give; not in the table, whose MoN is the reference's) and
        ``within_tol``; for a :class:`~symmon.GaussianMixture` u also ``component_error``
        (the worst error over its components, each against the reference rule on that
        component) and ``worst_component``, and a note says how the choice relates to
        the components' (the mixed moments can hide a component's error).
    reference : str
        The reference transform.
    reference_error : float
        A bound on the reference's own error, in the same unitless measure.
    reference_mon : float
        The MoN (25)–(29) with ``weight``, by the reference: the one MoN of the advice.
    choice : Transform or None
        The cheapest candidate within ``tol``; None when none is.
    choice_name : str or None
    tol : float
    weight : str or ndarray
    notes : tuple of str
    reference_mon_stderr : float or None
        The Monte Carlo standard error of ``reference_mon``; None for a Gauss–Hermite
        reference.
    filter : dict
        The filter advised (module notes): ``{"filter": "gaussian", "transform": choice}``,
        ``{"filter": "gsf", "transform": TT1(), "split": √2 tol, "max_components": 3^L,
        "levels": L}`` or ``{"filter": "pf"}``, with ``"reason"``: why (:func:`filter_advice`).
    """

    rows: list[dict]
    reference: str
    reference_error: float
    reference_mon: float
    choice: Transform | None
    choice_name: str | None
    tol: float
    weight: Any
    notes: tuple[str, ...] = field(default_factory=tuple)
    reference_mon_stderr: float | None = None
    filter: dict = field(default_factory=dict)

    @property
    def filter_name(self) -> str:
        """The advised filter in words: ``NonlinearKalmanFilter(UKF(...))``,
        ``GaussianSumFilter(EKF, split=0.0141, max_components=27)`` or ``ParticleFilter``."""
        kind = self.filter.get("filter")
        if kind == "gaussian":
            return f"NonlinearKalmanFilter({self.filter['transform'].filter_label()})"
        if kind == "gsf":
            return (f"GaussianSumFilter({self.filter['transform'].filter_label()}, split={self.filter['split']:.3g}, "
                    f"max_components={self.filter['max_components']})")
        return "ParticleFilter"

    @property
    def table(self) -> str:
        """A plain-text table of the candidates: error, cost, first-call and warm time, within tol."""
        lines = [f"{'transform':<25} {'error':>9} {'cost (g evals)':>15} {'first call':>11} {'warm':>10}  within tol"]
        for r in self.rows:
            mark = "yes" if r["within_tol"] else "no"
            if r["name"] == self.choice_name:
                mark += "  <- choice"
            lines.append(f"{r['name']:<25} {r['error']:>9.2e} {r['cost']:>15,d} {_ms(r['first_call']):>11} "
                         f"{_ms(r['warm']):>10}  {mark}")
        return "\n".join(lines)

    def __str__(self) -> str:
        se = f" ± {2 * self.reference_mon_stderr:.1e} (2 SE)" if self.reference_mon_stderr is not None else ""
        head = (f"advice for tol = {self.tol:g} (unitless error of the moments, in standard deviations)\n"
                f"reference: {self.reference}, its own error ≤ {self.reference_error:.1e}\n"
                f"MoN (weight {_weight_text(self.weight)}) by the reference: {self.reference_mon:.4f}{se}\n")
        choice = (f"choice: {self.choice_name}" if self.choice_name is not None
                  else "choice: none of the candidates is within tol")
        return head + self.table + "\n" + choice + "".join(f"\nnote: {n}" for n in self.notes)

    def __repr__(self) -> str:
        return f"Advice(choice={self.choice_name!r}, tol={self.tol:g}, reference={self.reference!r})"


def filter_advice(mon: float, choice: Transform | None, tol: float) -> dict:
    """The filter for a model whose reference MoN (W^full) is ``mon``, when ``choice`` is the
    cheapest rule within ``tol`` (None: none is): module notes.

    Examples
    --------
    >>> from symmon.measures.advice import filter_advice
    >>> from symmon import TT1
    >>> filter_advice(0.01, TT1(), 0.01)["filter"]
    'gaussian'
    >>> a = filter_advice(0.05, None, 0.01)
    >>> a["filter"], a["levels"], a["max_components"]
    ('gsf', 3, 27)
    >>> filter_advice(0.9, None, 0.01)["filter"]
    'pf'
    """
    if choice is not None and mon <= GAUSSIAN_MON_LIMIT:
        return {"filter": "gaussian", "transform": choice,
                "reason": f"a Gaussian rule is within tol and the MoN {mon:.3g} <= {GAUSSIAN_MON_LIMIT}"}
    why = (f"the MoN {mon:.3g} > {GAUSSIAN_MON_LIMIT}, where Gaussian filters lose consistency"
           if mon > GAUSSIAN_MON_LIMIT else "no Gaussian rule is within tol")
    target = np.sqrt(2.0) * tol
    sigma = SPLITS[3][0]
    levels = max(1, int(np.ceil(np.log(mon / target) / np.log(1.0 / sigma**2)))) if mon > target else 1
    if 3**levels > MAX_GSF_COMPONENTS:
        return {"filter": "pf", "reason": f"{why}; splitting to MoN {target:.3g} needs {3**levels} components "
                                          f"(> {MAX_GSF_COMPONENTS})"}
    return {"filter": "gsf", "transform": TT1(), "split": float(target), "max_components": 3**levels,
            "levels": levels, "reason": f"{why}; {levels} level(s) of 3-splits bring each component's MoN to "
                                        f"{target:.3g}"}


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms" if seconds < 10 else f"{seconds:.1f} s"


def _weight_text(weight: Any) -> str:
    return repr(weight) if isinstance(weight, str) else "matrix"


def _gauss_hermite(order: int, n_w: int, error_estimate: bool = False) -> GaussHermite:
    """Gauss–Hermite of ``order`` in ``n_w`` dimensions on an explicit grid: the tensor grid
    while it (and the order + 2 rule of its error estimate) is affordable, else the sparse grid."""
    return GaussHermite(order, error_estimate=error_estimate).for_dimension(n_w, MAX_REFERENCE_NODES)[0]


def _candidate(item: Any, i: int) -> tuple[str, Transform]:
    """``candidates[i]`` of :func:`advise` as a (name, Transform) pair: a registered name,
    a Transform or such a pair."""
    if isinstance(item, str):
        try:
            return item, resolve(item)
        except SymmonError:
            raise SymmonError(f"candidates[{i}]: unknown transform name {item!r}; the names are "
                              f"{', '.join(transform_names())} (or gh<order>, e.g. 'gh5')") from None
    if isinstance(item, Transform):
        return repr(item), item
    if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str) and isinstance(item[1], Transform):
        return item
    raise ArgumentTypeError(f"candidates[{i}] must be a transform name (e.g. 'ut1'), a Transform or a "
                            f"(name, Transform) pair, got {plain_repr(item)}")


def _explicit(name: str, t: Transform, n_w: int) -> tuple[str, Transform]:
    """A candidate with its dimension-dependent choices made (:meth:`Transform.for_dimension`:
    Gauss–Hermite's grid), the choice named in its name, e.g. " (sparse)"."""
    t, choice = t.for_dimension(n_w, MAX_REFERENCE_NODES)
    return (f"{name} ({choice})" if choice else name), t


def _reference(model: Model, u: Gaussian, v: Gaussian | None, tol: float, samples: int, seed: int
               ) -> tuple[Transform, str, JointMoments, float, list[str]]:
    notes: list[str] = []
    n_w = model.n_u + model.n_v
    gh = _gauss_hermite(REFERENCE_ORDER, n_w, error_estimate=True)
    nodes = GaussHermite(REFERENCE_ORDER + 2, sparse=gh.sparse).cost(n_w)
    grid = " (sparse)" if gh.sparse else ""
    if nodes <= MAX_REFERENCE_NODES:
        ref = propagate(model, u, v, transform=gh)
        bound = _error_bound(ref, ref.error)
        if bound <= tol / REFERENCE_MARGIN:
            return (GaussHermite(REFERENCE_ORDER, sparse=gh.sparse), f"Gauss-Hermite {REFERENCE_ORDER}{grid}",
                    ref, bound, notes)
        notes.append(f"Gauss-Hermite {REFERENCE_ORDER}{grid} did not converge (error estimate {bound:.1e}): "
                     "Monte Carlo is the reference")
    else:
        notes.append(f"Gauss-Hermite {REFERENCE_ORDER + 2} needs {nodes:,} nodes: Monte Carlo is the reference")
    mc = MonteCarlo(samples, seed=seed)
    ref = propagate(model, u, v, transform=mc)
    bound = 2.0 * _error_bound(ref, ref.stderr)
    if bound > tol:
        notes.append(f"the Monte Carlo reference is only good to {bound:.1e} (2 SE) > tol: "
                     "raise samples to resolve tol")
    return mc, f"Monte Carlo {mc.n:.0e} samples (seed {mc.seed})", ref, bound, notes


def _components_note(model: Model, u: GaussianMixture, v, rows: list[dict], ref_t: Transform, ref_err: float,
                     tol: float, best: dict | None) -> str:
    """How the choice for a mixture's moments relates to its components': each row gets
    ``component_error``, its worst error over the components of ``u`` (each against the
    reference rule on that component), and the note names the cheapest candidate within
    ``tol`` on every component.  The mixed moments can hide a component's error (the
    spread between the components dominates their covariance), so a per-component use, such
    as a Gaussian-sum filter, may need a richer rule than the mixture's moments."""
    refs = [propagate(model, c, v, transform=ref_t) for c in u.components]
    for r in rows:
        errs = [moment_error(propagate(model, c, v, transform=r["transform"]), ref) for c, ref in zip(u.components, refs)]
        r["component_error"] = max(errs)
        r["worst_component"] = int(np.argmax(errs))
    ok = [(r["cost"], i) for i, r in enumerate(rows) if r["component_error"] + ref_err <= tol]
    each = rows[min(ok)[1]] if ok else None
    head = (f"u is a mixture of {len(u.components)} components: the choice is for its mixed moments, where the "
            "spread between the components can hide their own errors; ")
    if each is None:
        return head + f"on its components no candidate is within tol {tol:g}"
    if best is not None and each is best:
        return head + f"{each['name']} is also within tol on every component (worst error {each['component_error']:.1e})"
    told = ("" if best is None else f"{best['name']} errs up to {best['component_error']:.1e} on component "
            f"{best['worst_component']}; ")
    return head + told + (f"component by component (a Gaussian-sum filter, a propagate per component) the cheapest "
                          f"within tol is {each['name']} (worst error {each['component_error']:.1e})")


def _timed(model: Model, u: Gaussian, v: Gaussian | None, t: Transform) -> tuple[JointMoments, float, float]:
    """The moments by ``t``, the time of this first call and the median time of the warm calls."""
    t0 = time.perf_counter()
    m = propagate(model, u, v, transform=t)
    first = time.perf_counter() - t0
    warm: list[float] = []
    while len(warm) < WARM_REPEATS and sum(warm) < WARM_BUDGET_S:
        t0 = time.perf_counter()
        propagate(model, u, v, transform=t)
        warm.append(time.perf_counter() - t0)
    return m, first, float(np.median(warm))


def advise(model: Model, u: Gaussian, v: Gaussian | None = None, tol: float = DEFAULT_TOL, weight: Any = "full",
           candidates: Sequence[str | Transform | tuple[str, Transform]] | None = None, samples: int = 10**6,
           seed: int = 0, params: dict | None = None) -> Advice:
    """Estimate the error of each candidate transform's moments and pick the cheapest within ``tol``.

    The reference is Gauss–Hermite of order 7 when its two-order error estimate (order 9)
    is within ``tol`` / :data:`REFERENCE_MARGIN`, else Monte Carlo.  A candidate is within
    ``tol`` when its error plus the reference's own error bound is; the choice is the
    cheapest such candidate in evaluations of g (ties to the earlier one), never the
    fastest, so that it does not depend on timing noise.

    Parameters
    ----------
    model : Model
    u : Gaussian
    v : Gaussian, optional
        Required when the model has noise symbols.
    tol : float, default :data:`DEFAULT_TOL` (0.01)
        Largest acceptable unitless error (module notes): 0.01 is 1 % of a standard
        deviation in the mean, or 1 % in the covariances; the default of
        :class:`symmon.Adaptive` too, so that the advice and the adaptive filter decide
        alike on the same prior.
    weight : str or ndarray, default "full"
        The weight of the reference's MoN (as in :func:`symmon.nonlinearity`): W^full (43)
        by default.
    candidates : sequence of str, Transform or (name, Transform), optional
        Default :data:`CANDIDATES`.  Each is a transform's registered name (``"ut1"``,
        ``"gh5"``: :func:`symmon.transforms.registry.resolve`; the table names it so), a
        Transform (named by its ``repr``), or a pair of a table name and a Transform.  A
        Gauss–Hermite candidate with ``sparse=None`` runs on
        the tensor grid while it has at most :data:`MAX_REFERENCE_NODES` nodes, else on the
        sparse grid (its name then ends in " (sparse)").
    samples, seed : int
        Of the Monte Carlo reference, when Gauss–Hermite does not converge.

    params : dict, optional
        Values of the model's parameters (``Model(params=...)``), substituted before the
        model is compiled (:meth:`symmon.Model.with_params`).

    Returns
    -------
    Advice
        ``str(advice)`` prints the reference, its MoN, the table (error, cost, first-call
        and warm time of each candidate) and the choice of transform: the transform question
        only.  For the filter to run along a track use :func:`symmon.advise_filter`;
        ``advice.filter`` keeps this one prior's first guess (module notes).

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> a = sm.advise(sm.Model([x], [3 * x + 1]), sm.Gaussian([1.0], [[0.5]]))
    >>> a.choice_name, a.tol, a.filter_name
    ('TT1', 0.01, 'NonlinearKalmanFilter(EKF)')
    """
    model = with_param_values(model, params)
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    if isinstance(u, Empirical):  # particles: every rule gives the same exact weighted sums
        raise ArgumentTypeError("advise ranks transforms for a Gaussian or a GaussianMixture; particles need none: "
                                "use nonlinearity(model, particles), or advise on particles.as_gaussian()")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (0 < tol < 1):
        raise SymmonError(f"tol must be a number in (0, 1), got {plain_repr(tol)}")
    cands = list(CANDIDATES) if candidates is None else [_candidate(c, i) for i, c in enumerate(candidates)]
    if not cands:
        raise SymmonError("candidates is empty")
    n_w = model.n_u + model.n_v
    ref_t, ref_name, ref, ref_err, notes = _reference(model, u, v, tol, samples, seed)
    ref_mon = nonlinearity(model, u, v, weight=weight, transform=ref_t)
    rows = []
    for name, t in (_explicit(name, t, n_w) for name, t in cands):
        if not t.stochastic and cost(t, n_w) > MAX_REFERENCE_NODES:
            notes.append(f"{name} skipped: {cost(t, n_w):,} nodes")
            continue
        try:
            m, first, warm = _timed(model, u, v, t)
            mon = nonlinearity(model, u, v, weight=weight, transform=t).value
        except SymmonError as exc:  # e.g. TT at a point where g is not differentiable
            notes.append(f"{name} failed: {exc}")
            continue
        err = moment_error(m, ref)
        rows.append({"name": name, "transform": t, "error": err, "cost": cost(t, n_w), "first_call": first,
                     "warm": warm, "seconds": warm, "mon": mon, "within_tol": err + ref_err <= tol})
    # Ties in cost go to the earlier candidate: the choice must not depend on timing noise.
    ok = [(r["cost"], i) for i, r in enumerate(rows) if r["within_tol"]]
    best = rows[min(ok)[1]] if ok else None
    if isinstance(u, GaussianMixture):
        notes.append(_components_note(model, u, v, rows, ref_t, ref_err, tol, best))
    choice = best["transform"] if best else None
    return Advice(rows, ref_name, ref_err, ref_mon.value, choice, best["name"] if best else None, float(tol), weight,
                  tuple(notes), ref_mon.stderr, filter_advice(ref_mon.value, choice, float(tol)))
