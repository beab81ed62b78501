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
Gauss–Hermite its nodes and Monte Carlo its samples; the measured time is reported
beside.
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..core.angles import wrap_angle
from ..errors import ArgumentTypeError, SymmonError
from ..core.gaussian import Gaussian
from ..core.mixture import Empirical
from ..core.model import Model
from ..propagation.joint import JointMoments
from .mon import nonlinearity
from ..propagation.front import propagate
from ..transforms import TT1, TT2, UT, GaussHermite, MonteCarlo, Transform

__all__ = ["advise", "Advice", "moment_error", "moment_distance", "whiteners", "CANDIDATES", "cost"]

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
MAX_REFERENCE_NODES = 200_000


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
        One per candidate: ``name``, ``transform``, ``error`` (unitless, module notes),
        ``mon`` (the MoN it gives), ``cost`` (evaluations of g), ``seconds`` and
        ``within_tol``.
    reference : str
        The reference transform.
    reference_error : float
        A bound on the reference's own error, in the same unitless measure.
    reference_mon : float
        The MoN by the reference.
    choice : Transform or None
        The cheapest candidate within ``tol``; None when none is.
    tol : float
    weight : str
    notes : tuple of str
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

    @property
    def table(self) -> str:
        """A plain-text table of the candidates."""
        lines = [f"{'transform':<17} {'error':>9} {'MoN':>9} {'cost (g evals)':>15} {'time':>9}  within tol"]
        for r in self.rows:
            mark = "yes" if r["within_tol"] else "no"
            if r["name"] == self.choice_name:
                mark += "  <- choice"
            lines.append(f"{r['name']:<17} {r['error']:>9.2e} {r['mon']:>9.4f} {r['cost']:>15,d} "
                         f"{r['seconds'] * 1e3:>7.1f}ms  {mark}")
        return "\n".join(lines)

    def __str__(self) -> str:
        head = (f"advice for tol = {self.tol:g} (unitless error of the moments; MoN weight {self.weight!r})\n"
                f"reference: {self.reference}, its own error ≤ {self.reference_error:.1e}, "
                f"MoN {self.reference_mon:.4f}\n")
        choice = (f"choice: {self.choice_name}" if self.choice_name is not None
                  else "choice: none of the candidates is within tol")
        return head + self.table + "\n" + choice + "".join(f"\nnote: {n}" for n in self.notes)

    def __repr__(self) -> str:
        return f"Advice(choice={self.choice_name!r}, tol={self.tol:g}, reference={self.reference!r})"


def _reference(model: Model, u: Gaussian, v: Gaussian | None, tol: float, samples: int, seed: int
               ) -> tuple[Transform, str, JointMoments, float, list[str]]:
    notes: list[str] = []
    n_w = model.n_u + model.n_v
    gh = GaussHermite(REFERENCE_ORDER, error_estimate=True)
    nodes = GaussHermite(REFERENCE_ORDER + 2).cost(n_w)
    if nodes <= MAX_REFERENCE_NODES:
        ref = propagate(model, u, v, transform=gh)
        bound = _error_bound(ref, ref.error)
        if bound <= tol / REFERENCE_MARGIN:
            return GaussHermite(REFERENCE_ORDER), f"Gauss-Hermite {REFERENCE_ORDER}", ref, bound, notes
        notes.append(f"Gauss-Hermite {REFERENCE_ORDER} did not converge (error estimate {bound:.1e}): "
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


def advise(model: Model, u: Gaussian, v: Gaussian | None = None, tol: float = 1e-3, weight: Any = "full",
           candidates: Sequence[tuple[str, Transform]] | None = None, samples: int = 10**6,
           seed: int = 0) -> Advice:
    """Estimate the error of each candidate transform's moments and pick the cheapest within ``tol``.

    Parameters
    ----------
    model : Model
    u : Gaussian
    v : Gaussian, optional
        Required when the model has noise symbols.
    tol : float, default 1e-3
        Largest acceptable unitless error (module notes): 1e-3 is a thousandth of a
        standard deviation in the mean, or 0.1 % in the covariances.
    weight : str or ndarray, default "full"
        The MoN weight reported beside each candidate (as in :func:`symmon.nonlinearity`).
    candidates : sequence of (name, Transform), optional
        Default :data:`CANDIDATES`.
    samples, seed : int
        Of the Monte Carlo reference, when Gauss–Hermite does not converge.

    Returns
    -------
    Advice

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x")
    >>> a = sm.advise(sm.Model([x], [3 * x + 1]), sm.Gaussian([1.0], [[0.5]]))
    >>> a.choice_name
    'TT1'
    """
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    if isinstance(u, Empirical):  # particles: every rule gives the same exact weighted sums
        raise ArgumentTypeError("advise ranks transforms for a Gaussian or a GaussianMixture; particles need none: "
                                "use nonlinearity(model, particles), or advise on particles.as_gaussian()")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (0 < tol < 1):
        raise SymmonError(f"tol must be a number in (0, 1), got {tol!r}")
    cands = list(CANDIDATES if candidates is None else candidates)
    if not cands:
        raise SymmonError("candidates is empty")
    n_w = model.n_u + model.n_v
    ref_t, ref_name, ref, ref_err, notes = _reference(model, u, v, tol, samples, seed)
    ref_mon = nonlinearity(model, u, v, weight=weight, transform=ref_t).value
    rows = []
    for name, t in cands:
        if not t.stochastic and cost(t, n_w) > MAX_REFERENCE_NODES:
            notes.append(f"{name} skipped: {cost(t, n_w):,} nodes")
            continue
        t0 = time.perf_counter()
        try:
            res = nonlinearity(model, u, v, weight=weight, transform=t)
        except SymmonError as exc:  # e.g. TT at a point where g is not differentiable
            notes.append(f"{name} failed: {exc}")
            continue
        seconds = time.perf_counter() - t0
        err = moment_error(res.moments, ref)
        rows.append({"name": name, "transform": t, "error": err, "mon": res.value, "cost": cost(t, n_w),
                     "seconds": seconds, "within_tol": err + ref_err <= tol})
    # Ties in cost go to the earlier candidate: the choice must not depend on timing noise.
    ok = [(r["cost"], i) for i, r in enumerate(rows) if r["within_tol"]]
    best = rows[min(ok)[1]] if ok else None
    return Advice(rows, ref_name, ref_err, ref_mon, best["transform"] if best else None,
                  best["name"] if best else None, float(tol), weight, tuple(notes))

