"""The measure of nonlinearity (MoN) from moments: the formula (25)–(29) and its results.

With Σ_gg = Cov g, Σ_gu = Cov(g, u), Σ_uu = Cov u and Σ_c = Cov_v(E[g | v]),

    M² = tr(W (Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug)),

the weight W chosen by :func:`symmon.measures.weights.resolve`.  How the moments and Σ_c are
computed (the transforms, the nested integration for general noise) is
:mod:`symmon.nonlinearity` and :mod:`symmon.measures.conditional`; this module only evaluates the
formula and holds its results.

References
----------
O. Straka, J. Havlík, "Design of unitless normalized measure of nonlinearity for state
estimation", FUSION 2024. arXiv:2410.13539
Y. Liu, X. R. Li, "Measure of nonlinearity for estimation", IEEE Trans. Signal Process.
63(9), 2015. doi:10.1109/TSP.2015.2405495
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from . import weights as _weights
from ..errors import NonFiniteError
from ..latex import latex_number, latex_text
from ..propagation.joint import JointMoments

__all__ = ["MonParts", "NonlinearityMeasure", "mon_from_moments", "SINGULAR_COND"]

#: Condition number of Σ_uu's correlation matrix (the same in any units of u) above which Σ_uu is
#: treated as singular (a generalised inverse on its range).
SINGULAR_COND = 1e12


@dataclass(frozen=True, eq=False)
class MonParts:
    """The MoN and its parts, from the moments alone (:func:`mon_from_moments`).

    ``float(p)`` and ``p.value`` are M = √max(M², 0).

    Attributes
    ----------
    squared : float
        M² = J_Ab + J_n − E‖g‖²_W (25); may be slightly negative from Monte Carlo noise.
    J_Ab : float
        The deterministic part (26): tr(W(Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug)).
    J_n : float
        The stochastic part: E‖g‖²_W − tr(W Σ_c) (27).
    weight : ndarray
        The weight matrix W used, in the original units.
    weight_name : str
    residual_cov : ndarray
        D = Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug.
    notes : tuple of str
        Remarks, e.g. that Σ_uu was singular and its pseudo-inverse was used.
    """

    squared: float
    J_Ab: float
    J_n: float
    weight: np.ndarray
    weight_name: str
    residual_cov: np.ndarray
    notes: tuple[str, ...] = ()

    @property
    def value(self) -> float:
        """M = √max(M², 0)."""
        return float(np.sqrt(max(self.squared, 0.0)))

    def __float__(self) -> float:
        return self.value

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.value:.6g}, weight={self.weight_name!r})"


@dataclass(frozen=True, eq=False, kw_only=True)
class NonlinearityMeasure(MonParts):
    """A measure of nonlinearity, its parts and what produced it (:func:`symmon.nonlinearity`).

    ``float(m)`` is the value M = √max(M², 0).

    Attributes
    ----------
    squared, J_Ab, J_n, weight, weight_name, residual_cov, notes
        As in :class:`MonParts`.
    transform : Transform
    structure : str
        The model's noise structure (``'none'``, ``'additive'``, ``'multiplicative'``,
        ``'general'``).
    moments : JointMoments
    stderr : float or None
        Monte Carlo standard error of the value: the delete-one-group jackknife, with
        each group left out of the moments and of Σ_c (whose Monte Carlo estimate, nested
        for general noise, has its own error).
    """

    transform: Any
    structure: str
    moments: JointMoments
    stderr: float | None = None
    info: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, parts: MonParts, **context: Any) -> "NonlinearityMeasure":
        """``parts`` with the transform, structure, moments and error bar that produced them."""
        return cls(**{f.name: getattr(parts, f.name) for f in fields(MonParts)}, **context)

    def __repr__(self) -> str:
        se = f" ± {self.stderr:.2g}" if self.stderr is not None else ""
        return f"NonlinearityMeasure({self.value:.6g}{se}, weight={self.weight_name!r}, transform={self.transform!r})"

    def _repr_latex_(self) -> str:
        se = rf" \pm {latex_number(self.stderr, 2)}" if self.stderr is not None else ""
        return (
            rf"$M_{{\text{{{latex_text(self.weight_name)}}}}} = {latex_number(self.value, 6)}{se}"
            rf"\quad\text{{({self.structure} noise, {type(self.transform).__name__})}}$"
        )


def _inv_uu(Suu: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Σ_uu⁻¹, or a generalised inverse when Σ_uu is singular, decided on its correlation matrix
    (the same in any units of u: inputs in mm and in rad are not "singular")."""
    d = np.diag(Suu)
    r = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 0.0)
    corr = r[:, None] * Suu * r[None, :]
    cond = np.linalg.cond(corr) if np.all(d > 0) else np.inf
    if np.isfinite(cond) and cond < SINGULAR_COND:
        return r[:, None] * np.linalg.inv(corr) * r[None, :], ()
    w = np.linalg.eigvalsh(0.5 * (corr + corr.T))
    rank = int(np.sum(w > max(w[-1], 0.0) * 1e-12))
    note = (
        f"Σ_uu is singular (rank {rank} of {Suu.shape[0]}): the pseudo-inverse was used, "
        "i.e. the best affine fit on the informative subspace of u"
    )
    # A generalised inverse in scaled coordinates: Σ_yu G Σ_uy is the same for every one,
    # as Σ_uy lies in the range of Σ_uu.
    return r[:, None] * np.linalg.pinv(corr, rcond=1e-12, hermitian=True) * r[None, :], (note,)


@np.errstate(over="ignore", divide="ignore", invalid="ignore")  # a non-finite result raises below
def mon_from_moments(Sgg: Any, Sgu: Any, Suu: Any, weight: Any = "full", Sc: Any = None,
                     mean: Any = None) -> MonParts:
    """The MoN from the moments (25)–(29).

    Parameters
    ----------
    Sgg : array_like (n_y, n_y)
        Σ_gg = Cov g.
    Sgu : array_like (n_y, n_u)
        Σ_gu = Cov(g, u).
    Suu : array_like (n_u, n_u)
        Σ_uu = Cov u; singular (condition number above :data:`SINGULAR_COND`): its
        pseudo-inverse, and a note says so.
    weight : str, ndarray or weights.GeneralWeight
        As in :func:`symmon.nonlinearity`.
    Sc : array_like (n_y, n_y), optional
        Σ_c = Cov_v(E[g | v]) (28), (29); default 0 (no noise).
    mean : array_like (n_y,), optional
        E g, for J_n = E‖g‖²_W − tr(W Σ_c) (27); default 0.

    Returns
    -------
    MonParts

    Raises
    ------
    NonFiniteError
        If M², J_Ab or J_n is NaN or inf (moments at the edge of the float range: the
        inverse of a subnormal Σ_uu, a weight that overflows).

    Examples
    --------
    >>> from symmon.measures.formula import mon_from_moments
    >>> p = mon_from_moments([[2.0]], [[1.0]], [[1.0]], "liu-li-raw")  # M² = 2 − 1²/1
    >>> p.squared, p.weight_name
    (1.0, 'liu-li-raw')
    """
    Sgg = np.atleast_2d(np.asarray(Sgg, dtype=float))
    Sgu = np.atleast_2d(np.asarray(Sgu, dtype=float))
    Suu = np.atleast_2d(np.asarray(Suu, dtype=float))
    Sc = np.zeros_like(Sgg) if Sc is None else np.atleast_2d(np.asarray(Sc, dtype=float))
    Suu_inv, notes = _inv_uu(Suu)
    W, label = _weights.resolve(weight, Sgg)
    lin = Sgu @ Suu_inv @ Sgu.T
    J_Ab = float(np.trace(W @ (Sgg - lin)))
    mu = np.zeros(Sgg.shape[0]) if mean is None else np.asarray(mean, dtype=float)
    Eg2 = float(np.trace(W @ (Sgg + np.outer(mu, mu))))
    WSc = float(np.trace(W @ Sc))
    D = Sgg - Sc - lin
    # M² = J_Ab + J_n − E‖g‖²_W (25) = J_Ab − tr(W Σ_c): the E‖g‖²_W terms cancel
    # analytically; adding and subtracting them would lose every digit when |E g| ≫ σ.
    if not np.isfinite([J_Ab - WSc, J_Ab, Eg2 - WSc]).all():
        raise NonFiniteError(
            f"the MoN with weight {label!r} is not finite (M² = {J_Ab - WSc:.3g}, J_Ab = {J_Ab:.3g}, "
            f"J_n = {Eg2 - WSc:.3g}): the moments (largest |Σ_gg| {np.max(np.abs(Sgg)):.3g}, smallest "
            f"variance in Σ_uu {np.min(np.diag(Suu)):.3g}) are at the edge of the float range; rescale the units"
        )
    return MonParts(squared=J_Ab - WSc, J_Ab=J_Ab, J_n=Eg2 - WSc, weight=W, weight_name=label,
                    residual_cov=D, notes=notes)

