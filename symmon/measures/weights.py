"""Weight matrices of the measures of nonlinearity (Straka & Havlík 2024, Sec. IV-C).

In base units (unit variances, diag Σ_ḡḡ = 1) the admissible weights form the set (41):
W̄ = V Y Vᵀ with Σ_ḡḡ = V Λ Vᵀ, Y ≻ 0 and [Y]_ii = α_i/λ_i, α_i > 0, Σ α_i = 1, which is
exactly the set of positive definite W̄ with tr(W̄ Σ_ḡḡ) = 1.  In the original units
W = S_y⁻¹ W̄ S_y⁻¹ (38), with S_y = diag(√diag Σ_gg).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike

from ..errors import ShapeError, SingularMatrixError, SymmonError

__all__ = ["NAMED", "NAMED_WEIGHTS", "NamedWeight", "GeneralWeight", "general", "base_scale",
           "check_admissible", "resolve", "weighted_trace"]


@dataclass(frozen=True)
class NamedWeight:
    """A weight rule known by name: W as a function of the output covariance Σ_gg.

    Attributes
    ----------
    name : str
    equation : str
        Its equation in Straka & Havlík (2024).
    formula : str
        W in terms of Σ_gg and the number of outputs n_y.
    unit_invariant : bool
        Whether the measure with this weight is invariant to changes of units (Sec. IV);
        Liu and Li's weights (6), (8) are not.
    """

    name: str
    equation: str
    formula: str
    unit_invariant: bool


#: The named weights, the one table used by the measures, the proofs and the command line.
NAMED_WEIGHTS: Mapping[str, NamedWeight] = {w.name: w for w in (
    NamedWeight("full", "(43)", "W = Σ_gg⁻¹ / n_y", True),
    NamedWeight("diag", "(42)", "W = diag(diag Σ_gg)⁻¹ / n_y", True),
    NamedWeight("liu-li", "(8)", "W = I / tr Σ_gg", False),
    NamedWeight("liu-li-raw", "(6)", "W = I", False),
)}

#: Names accepted by :func:`symmon.nonlinearity` and :func:`symmon.units.prove_invariance`.
NAMED = tuple(NAMED_WEIGHTS)

#: Tolerance of the normalisation tr(W̄ Σ_ḡḡ) = 1 of the set (41).
NORMALIZATION_TOL = 1e-8


#: A correlation matrix with a smallest eigenvalue at or below this is singular: the test of
#: W^full's Σ_gg, the same in any units of the outputs (issue 26: not a test on Σ_gg's own
#: eigenvalues, whose scale is the units').
SINGULAR_CORR = 1e-12


def base_scale(Sgg: np.ndarray) -> np.ndarray:
    """S_y = diag(√diag Σ_gg): the scale to base units, where each output has unit variance."""
    d = np.diag(Sgg)
    zero = np.flatnonzero(d <= 0)
    if zero.size:
        raise SingularMatrixError(
            f"outputs {zero.tolist()} have zero variance: base units (unit variances) do not exist"
        )
    return np.diag(np.sqrt(d))


def check_admissible(Wbar: np.ndarray, corr: np.ndarray) -> None:
    """Raise unless W̄ is symmetric positive definite with tr(W̄ Σ_ḡḡ) = 1, i.e. in the set (41)."""
    if Wbar.shape != corr.shape:
        raise ShapeError(f"weight must be {corr.shape[0]}x{corr.shape[0]}, got {Wbar.shape}")
    if not np.allclose(Wbar, Wbar.T, rtol=0, atol=1e-12 * max(1.0, np.abs(Wbar).max())):
        raise SymmonError("weight W̄ is not symmetric")
    if np.linalg.eigvalsh(0.5 * (Wbar + Wbar.T))[0] <= 0:
        raise SymmonError("weight W̄ is not positive definite, so it is not in the set (41)")
    t = float(np.trace(Wbar @ corr))
    if abs(t - 1) > NORMALIZATION_TOL:
        raise SymmonError(
            f"weight W̄ is not in the set (41): tr(W̄ Σ_ḡḡ) = {t:.10g}, not 1 "
            "(build one with symmon.measures.weights.general)"
        )


@dataclass(frozen=True)
class GeneralWeight:
    """A weight of the set (41), parametrised by α and the off-diagonal part of Y.

    The matrix depends on Σ_ḡḡ, so it is resolved when the moments are known.
    """

    alphas: tuple[float, ...]
    offdiag: np.ndarray | None = None

    def matrix(self, corr: np.ndarray) -> np.ndarray:
        """W̄ = V Y Vᵀ for the correlation matrix Σ_ḡḡ (41)."""
        n = corr.shape[0]
        if len(self.alphas) != n:
            raise ShapeError(f"general weight has {len(self.alphas)} alphas for {n} outputs")
        lam, V = np.linalg.eigh(corr)
        if lam[0] <= 0:
            raise SingularMatrixError("Σ_ḡḡ is singular: the set (41) needs λ_i > 0")
        Y = np.zeros((n, n)) if self.offdiag is None else np.array(self.offdiag, dtype=float)
        np.fill_diagonal(Y, np.asarray(self.alphas) / lam)
        if np.linalg.eigvalsh(Y)[0] <= 0:
            raise SymmonError("Y of (41) is not positive definite: reduce the off-diagonal entries")
        return V @ Y @ V.T

    def __repr__(self) -> str:
        off = "" if self.offdiag is None else f", offdiag={np.round(self.offdiag, 6).tolist()}"
        return f"GeneralWeight(alphas={self.alphas}{off})"


def general(alphas: ArrayLike, offdiag: ArrayLike | None = None) -> GeneralWeight:
    """A general unitless weight W̄ of the set (41).

    Parameters
    ----------
    alphas : array_like, shape (n_y,)
        α_i > 0 with Σ α_i = 1.
    offdiag : array_like, shape (n_y, n_y), optional
        Symmetric off-diagonal entries of Y (its diagonal is ignored); Y must stay ≻ 0.

    Examples
    --------
    >>> w = general([0.5, 0.5])
    >>> bool(np.isclose(np.trace(w.matrix(np.array([[1.0, 0.3], [0.3, 1.0]])) @ [[1.0, 0.3], [0.3, 1.0]]), 1))
    True
    """
    a = np.asarray(alphas, dtype=float)
    if a.ndim != 1 or a.size == 0:
        raise ShapeError(f"alphas must be a non-empty vector, got shape {a.shape}")
    if np.any(a <= 0) or not np.all(np.isfinite(a)):
        raise SymmonError(f"alphas must be positive and finite, got {a.tolist()}")
    if abs(a.sum() - 1) > NORMALIZATION_TOL:
        raise SymmonError(f"alphas must sum to 1 (Appendix B), got sum {a.sum():.10g}")
    off = None
    if offdiag is not None:
        off = np.array(offdiag, dtype=float)
        if off.shape != (a.size, a.size):
            raise ShapeError(f"offdiag must be {a.size}x{a.size}, got {off.shape}")
        if not np.allclose(off, off.T):
            raise SymmonError("offdiag must be symmetric")
    return GeneralWeight(tuple(a.tolist()), off)


def resolve(weight, Sgg: np.ndarray) -> tuple[np.ndarray, str]:
    """The weight matrix W in the original units for the output covariance Σ_gg.

    Returns
    -------
    W : ndarray
    label : str
    """
    n = Sgg.shape[0]
    if isinstance(weight, str):
        if weight == "liu-li-raw":
            return np.eye(n), weight  # (6), Remark 2
        if weight == "liu-li":
            t = np.trace(Sgg)
            if t <= 0:
                raise SingularMatrixError("tr Σ_gg = 0: the normalised Liu–Li MoN (8) is undefined")
            return np.eye(n) / t, weight  # (8), Remark 2
        if weight == "diag":
            S = base_scale(Sgg)
            return np.linalg.inv(S @ S) / n, weight  # (42)
        if weight == "full":
            # Decided on the correlation matrix, which a change of the outputs' units leaves
            # alone (a test on Σ_gg itself called a range in mm and a bearing in rad singular).
            d = np.diag(Sgg)
            if np.any(d <= 0):
                zero = np.flatnonzero(d <= 0)
                raise SingularMatrixError(
                    f"Σ_gg is singular: outputs {zero.tolist()} have no variance, so W^full = Σ_gg⁻¹/n_y "
                    "(43) does not exist")
            r = 1.0 / np.sqrt(d)
            corr = r[:, None] * Sgg * r[None, :]
            lam, V = np.linalg.eigh(0.5 * (corr + corr.T))
            if lam[0] <= SINGULAR_CORR:
                a = r * V[:, 0]  # the null direction in the outputs' own units, unit length
                a = a / np.linalg.norm(a)
                combo = " + ".join(f"{c:.3g}*y{i}" for i, c in enumerate(a) if abs(c) > 1e-6)
                raise SingularMatrixError(
                    f"Σ_gg is singular (smallest eigenvalue of its correlation matrix {lam[0]:.3g}): the output "
                    f"combination {combo} has no variance, so W^full = Σ_gg⁻¹/n_y (43) does not exist; "
                    "use weight='diag'"
                )
            return r[:, None] * np.linalg.inv(corr) * r[None, :] / n, weight  # (43), in the units of y
        raise SymmonError(f"unknown weight {weight!r}: use one of {NAMED}, a matrix W̄ or weights.general(...)")
    S = base_scale(Sgg)
    Sinv = np.linalg.inv(S)
    corr = Sinv @ Sgg @ Sinv
    if isinstance(weight, GeneralWeight):
        Wbar = weight.matrix(corr)
        label = "general"
    else:
        Wbar = np.asarray(weight, dtype=float)
        if Wbar.ndim != 2:
            raise ShapeError(f"weight matrix must be 2-D, got shape {Wbar.shape}")
        label = "matrix"
    check_admissible(Wbar, corr)
    return Sinv @ Wbar @ Sinv, label  # (38)


def weighted_trace(name: str, Sgg: Any, D: Any) -> Any:
    """M² = tr(W D) (29) for the named weight W of Σ_gg, without forming W.

    Works on numpy arrays and on sympy matrices alike (the proofs of
    :mod:`symmon.units.proofs` call it with symbols); :func:`resolve` gives the same W.

    Parameters
    ----------
    name : {"full", "diag", "liu-li", "liu-li-raw"}
    Sgg, D : ndarray or sympy Matrix, shape (n_y, n_y)
        The output covariance Σ_gg and the matrix D of the measure.

    Examples
    --------
    >>> float(weighted_trace("diag", np.diag([4.0, 1.0]), np.diag([2.0, 1.0])))
    0.75
    """
    n = Sgg.shape[0]
    d = [D[i, i] for i in range(n)]
    if name == "full":  # (43): W = Σ_gg⁻¹ / n_y
        X = Sgg.LUsolve(D) if isinstance(Sgg, sp.MatrixBase) else np.linalg.solve(Sgg, D)
        return sum(X[i, i] for i in range(n)) / n
    if name == "diag":  # (42): W = diag(diag Σ_gg)⁻¹ / n_y
        return sum(d[i] / Sgg[i, i] for i in range(n)) / n
    if name == "liu-li":  # (8) squared: W = I / tr Σ_gg
        return sum(d) / sum(Sgg[i, i] for i in range(n))
    if name == "liu-li-raw":  # (6): W = I
        return sum(d)
    raise SymmonError(f"unknown weight {name!r}: use one of {NAMED}")
