"""The result of a unit-invariance proof, :class:`InvarianceProof`, shared by every route.

:func:`symmon.units.prove_invariance` (the lemma route, :mod:`symmon.units.proofs`, and the
direct route, :mod:`symmon.units.direct`) and :func:`symmon.units.prove_matrix_invariance`
(:mod:`symmon.units.matrix`) all return it: whether M²(g, u) − M²(ḡ, ū) vanishes
under the change of units (18), the difference, and a counterexample when it does not (21), (34).

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (29), (34)–(43).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import sympy as sp


@dataclass(frozen=True)
class InvarianceProof:
    """The outcome of a symbolic unit-invariance check (21), (34).

    Attributes
    ----------
    holds : bool
        True when M²(g, u) − M²(ḡ, ū) is 0 identically in the scales, offsets and moments;
        False when it is provably nonzero (see ``counterexample``).
    difference : sympy.Expr
        The simplified M²(g, u) − M²(ḡ, ū). On the lemma route it is written in generic
        moments (``Sigma_ij`` for Σ_gg, ``D_ij`` for D) and scales (``s_yi``).
    lhs, rhs : sympy.Expr
        M² in the old units and in the new units (same variables as ``difference``).
    weight : str
    transform : str
        ``"tt2"``, ``"ut"``, ``"gh"``, ``"mc"`` for :func:`prove_invariance`, ``"exact"`` for
        :func:`prove_matrix_invariance`.
    statement : str
    symbols : dict
        The symbols of the statement: scales, offsets, moments.
    counterexample : dict or None
        For a failed proof: values of the symbols of ``difference`` at which it is nonzero
        (its value under ``"difference"``), and the model point: ``"mean"``, ``"cov"``, the
        scales ``"S_u"``, ``"o_u"``, ``"S_y"``, ``"o_y"`` and M² computed independently in the
        old (``"lhs"``) and in the new (``"rhs"``) units.
    seconds : float
        Wall time of the proof.
    lemmas : tuple of str
        Names of the lemmas the proof rests on (empty for the direct route).
    assumptions : tuple of str
        Conditions under which the statement is proved.
    """

    holds: bool
    difference: sp.Expr
    lhs: sp.Expr
    rhs: sp.Expr
    weight: str
    transform: str
    statement: str
    symbols: dict = field(repr=False, default_factory=dict)
    counterexample: dict | None = field(repr=False, default=None)
    seconds: float = 0.0
    lemmas: tuple[str, ...] = ()
    assumptions: tuple[str, ...] = ()

    def __bool__(self) -> bool:
        return self.holds

    @property
    def latex(self) -> str:
        """The result as a LaTeX equation (without $ delimiters)."""
        verdict = r"\quad\text{(invariant)}" if self.holds else r"\quad\text{(not invariant)}"
        return (
            r"M^2(\mathbf{g}, \mathbf{u}) - M^2(\bar{\mathbf{g}}, \bar{\mathbf{u}}) = "
            + sp.latex(self.difference) + verdict
        )

    def _repr_latex_(self) -> str:
        return "$" + self.latex + "$"

    def __str__(self) -> str:
        if self.holds:
            tail = "holds: M²(g, u) − M²(ḡ, ū) = 0"
        else:
            d = self.difference
            shown = str(d) if sp.count_ops(d) <= 40 else f"a nonzero expression ({sp.count_ops(d)} operations, see .difference)"
            tail = f"fails: M²(g, u) − M²(ḡ, ū) = {shown}"
            cex = self.counterexample
            if cex is not None and "lhs" in cex:
                tail += (f"; counterexample: M² = {float(cex['lhs']):.10g} in the old units, "
                         f"{float(cex['rhs']):.10g} in the new units with {show_point(cex)}")
            elif cex is not None:
                tail += f"; e.g. {float(cex['difference']):.6g} at a rational point"
        text = f"{self.statement} with weight {self.weight!r} ({self.transform}): {tail} [{self.seconds:.2f} s]"
        if self.lemmas:
            text += "\n  by the lemmas: " + ", ".join(self.lemmas)
        if self.assumptions:
            text += "\n  assuming: " + "; ".join(self.assumptions)
        return text

    def __repr__(self) -> str:
        return f"InvarianceProof(weight={self.weight!r}, transform={self.transform!r}, holds={self.holds})"


def show_point(cex: dict) -> str:
    def fmt(M: Any) -> str:
        M = sp.Matrix(M)
        if M.cols > 1 and M.is_diagonal():
            return "diag(" + ", ".join(str(M[i, i]) for i in range(M.rows)) + ")"
        return "[" + ", ".join(str(x) for x in M) + "]"

    keys = ("S_u", "o_u", "S_y", "o_y", "S_v", "mean", "cov", "noise_cov")
    return ", ".join(f"{k} = {fmt(cex[k])}" for k in keys if k in cex and sp.Matrix(cex[k]).rows)


def _say(progress: bool, message: str) -> None:
    """Print a step of a proof to stderr (``progress=True``; the CLI's ``--progress``)."""
    if progress:
        print(f"prove-invariance: {message}", file=sys.stderr, flush=True)
