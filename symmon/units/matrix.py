"""The exact, transform-free unit invariance of tr(W D) in matrix form.

:func:`prove_matrix_invariance` proves, for any transform, that M² = tr(W D) (29) is
unchanged when the moments map exactly under (18) (Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu
S_uᵀ, Σ_uu → S_u Σ_uu S_uᵀ): for the weight (43) with full invertible scales, for (42) with
positive diagonal scales; and it refutes Liu–Li's (6), (8) at an exact rational point.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

import time

import numpy as np
import sympy as sp

from ..errors import ShapeError, SymmonError, plain_repr
from .proof import InvarianceProof
from .lemmas import _reduce, _sym_matrix
from ..measures.weights import NAMED as WEIGHTS

__all__ = ["prove_matrix_invariance"]


def _matrix_counterexample(d: sp.Expr, explicit: dict, scales: str, seed: int = 0) -> dict:
    """An exact rational point (moments positive definite, scales invertible) where d ≠ 0."""
    rng = np.random.default_rng(seed)
    for _ in range(20):
        point = {}
        for M, X in explicit.items():
            n, m = X.shape
            A = sp.Matrix(n, m, lambda i, j: sp.Rational(int(rng.integers(-9, 10)), int(rng.integers(1, 5))))
            if M.name in ("Sigma_gg", "Sigma_uu"):
                A = A * A.T + 3 * sp.eye(n)  # symmetric positive definite
            elif M.name in ("S_y", "S_u"):
                A = (A * A.T + sp.eye(n)) if scales == "full" else sp.diag(*[abs(A[i, i]) + 1 for i in range(n)])
            point[M] = sp.ImmutableMatrix(A)
        entries = {X[i, j]: point[M][i, j] for M, X in explicit.items()
                   for i in range(X.rows) for j in range(X.cols) if X[i, j].is_Symbol}
        val = sp.nsimplify(sp.sympify(d.subs(point).doit()).xreplace(entries))
        if val.is_Rational and val != 0:
            out = {str(k): v for k, v in point.items()}
            out["difference"] = val
            return out
    raise SymmonError(f"could not decide: {d} did not simplify to 0 but vanished at every test point")


def prove_matrix_invariance(n_u: int, n_y: int, weight: str = "full", scales: str | None = None) -> InvarianceProof:
    """The exact unit invariance of tr(W D) in matrix form, for any transform.

    Under the change (18) the moments map as Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu S_uᵀ,
    Σ_uu → S_u Σ_uu S_uᵀ (exactly, without any approximation), so
    D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug → S_y D S_yᵀ. This function proves that M² = tr(W D),
    with W computed by the weight rule from the mapped Σ_gg, is unchanged: for
    ``"full"`` (43) with full invertible S_y, S_u; for ``"diag"`` (42) with positive diagonal
    scales; and it shows the failure of ``"liu-li"`` (8) and ``"liu-li-raw"`` (6).

    The base moments are full symbolic n×n matrices (symmetric where they must be) and the
    scales full symbolic matrices (or positive diagonal ones). The proof first reduces the
    mapped expression with exact matrix algebra ((ABC)⁻¹ = C⁻¹B⁻¹A⁻¹, X X⁻¹ = I, and the
    linearity and cyclicity of the trace), which is valid for every size, then evaluates the
    weights that act entrywise (42), (8), (6) on the explicit n×n entries. A failure is
    certified by an exact rational point at which the difference is nonzero.

    Parameters
    ----------
    n_u, n_y : int
        Sizes of u and y (1 to 4: the explicit entries grow quickly).
    weight : {"full", "diag", "liu-li", "liu-li-raw"}
    scales : {"full", "diagonal"}, optional
        Default: ``"full"`` for ``"full"`` and the Liu–Li weights, ``"diagonal"`` for ``"diag"``
        (which is not invariant under a full S_y: it ignores correlations).

    Returns
    -------
    InvarianceProof

    Examples
    --------
    >>> prove_matrix_invariance(2, 2, "full").holds
    True
    """
    t0 = time.perf_counter()
    for n, name in ((n_u, "n_u"), (n_y, "n_y")):
        if not isinstance(n, (int, np.integer)) or not 1 <= n <= 4:
            raise ShapeError(f"{name} must be an integer from 1 to 4, got {plain_repr(n)}")
    if weight not in WEIGHTS:
        raise SymmonError(f"weight must be one of {WEIGHTS}, got {weight!r}")
    if scales is None:
        scales = "diagonal" if weight == "diag" else "full"
    if scales not in ("full", "diagonal"):
        raise SymmonError(f"scales must be 'full' or 'diagonal', got {scales!r}")
    n_u, n_y = int(n_u), int(n_y)
    # Explicit entries of the base-unit moments and of the scales.
    Gx = _sym_matrix(n_y, "G")
    Ux = _sym_matrix(n_u, "U")
    Cx = sp.Matrix(n_y, n_u, lambda i, j: sp.Symbol(f"C_{i + 1}{j + 1}", real=True))
    if scales == "full":
        Syx = sp.Matrix(n_y, n_y, lambda i, j: sp.Symbol(f"a_{i + 1}{j + 1}", real=True))
        Sux = sp.Matrix(n_u, n_u, lambda i, j: sp.Symbol(f"b_{i + 1}{j + 1}", real=True))
    else:
        Syx = sp.diag(*[sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(n_y)])
        Sux = sp.diag(*[sp.Symbol(f"s_u{i + 1}", positive=True) for i in range(n_u)])
    # The same as matrix symbols, for the dimension-free reduction.
    G = sp.MatrixSymbol("Sigma_gg", n_y, n_y)
    U = sp.MatrixSymbol("Sigma_uu", n_u, n_u)
    C = sp.MatrixSymbol("Sigma_gu", n_y, n_u)
    Sy = sp.MatrixSymbol("S_y", n_y, n_y)
    Su = sp.MatrixSymbol("S_u", n_u, n_u)
    explicit = {G: sp.ImmutableMatrix(Gx), U: sp.ImmutableMatrix(Ux), C: sp.ImmutableMatrix(Cx),
                Sy: sp.ImmutableMatrix(Syx), Su: sp.ImmutableMatrix(Sux)}

    def m2(Gm, Cm, Um):
        D = _reduce(Gm - Cm * Um.I * Cm.T)
        if weight == "full":
            return _reduce(sp.Trace(Gm.I * D) / n_y)  # (43)
        if weight == "liu-li":
            return _reduce(sp.Trace(D)) / _reduce(sp.Trace(Gm))  # (8)
        if weight == "liu-li-raw":
            return _reduce(sp.Trace(D))  # (6)
        # (42) acts on the entries: evaluate them explicitly, term by term.
        Ge = sp.Matrix(Gm.subs(explicit).doit())
        De = sp.Matrix(D.subs(explicit).doit())
        return [sp.cancel(De[i, i] / Ge[i, i] / n_y) for i in range(n_y)]

    lhs = m2(Sy * G * Sy.T, Sy * C * Su.T, Su * U * Su.T)  # old units: mapped moments
    rhs = m2(G, C, U)  # base units
    if weight == "diag":
        d = sp.cancel(sp.together(sum(a - b for a, b in zip(lhs, rhs))))
        lhs, rhs = sp.Add(*lhs), sp.Add(*rhs)
    else:
        d = _reduce(lhs - rhs)
        if d != 0:
            d = sp.simplify(d)
    if d == 0:
        diff, holds, cex = sp.Integer(0), True, None
    else:
        diff, holds = d, False
        cex = _matrix_counterexample(d, explicit, scales)
    symbols = {"Sigma_gg": Gx, "Sigma_gu": Cx, "Sigma_uu": Ux, "S_y": Syx, "S_u": Sux}
    return InvarianceProof(
        holds, diff, lhs, rhs, weight, "exact",
        f"unit invariance of tr(W D) under Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu S_uᵀ, "
        f"Σ_uu → S_u Σ_uu S_uᵀ ({scales} S, n_u={n_u}, n_y={n_y})",
        symbols, cex, time.perf_counter() - t0,
    )
