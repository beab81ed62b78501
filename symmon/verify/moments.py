"""Symbolic moments of a model under a transform (first subset: TT1)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import sympy as sp

from ..core.model import Model

__all__ = ["SymbolicMoments", "symbolic_moments"]


@dataclass(frozen=True)
class SymbolicMoments:
    """E y, Cov y and Cov(y, u) as sympy matrices in the symbols of μ and P."""

    mean: sp.Matrix
    cov: sp.Matrix
    cross_cov: sp.Matrix
    input_mean: sp.Matrix
    input_cov: sp.Matrix
    transform: Any
    model: Model

    def latex(self) -> str:
        """The three moments as LaTeX."""
        return (r"\mathrm{E}\,y = " + sp.latex(self.mean) + r",\quad \mathrm{Cov}\,y = " + sp.latex(self.cov)
                + r",\quad \mathrm{Cov}(y, u) = " + sp.latex(self.cross_cov))


def symbolic_moments(model: Model, transform: Any, mean: Any = None, cov: Any = None) -> SymbolicMoments:
    """E y, Cov y and Cov(y, u) of y = g(u) as sympy matrices (first subset: TT1).

    Parameters
    ----------
    model : Model
    transform : TT1
    mean, cov : optional symbols or values of μ and P; default symbols mu_x, P_x_y.
    """
    u = model.inputs
    n = len(u)
    mu = sp.Matrix([sp.Symbol(f"mu_{s}", real=True) for s in u]) if mean is None else sp.Matrix(list(mean))
    if cov is None:
        P = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"P_{u[min(i, j)]}_{u[max(i, j)]}", real=True))
    else:
        P = sp.Matrix(cov)
    g = sp.Matrix(model.outputs)
    at = dict(zip(u, mu))
    J = g.jacobian(u).xreplace(at)
    return SymbolicMoments(g.xreplace(at), J * P * J.T, J * P, mu, P, transform, model)
