"""Exact Gaussian moments of polynomial models (Isserlis' theorem).

With w = μ + L z, z ~ N(0, I), each output is a polynomial in z; the moments of a
monomial Π z_k^{a_k} are Π (a_k − 1)!! when every a_k is even and 0 otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import sympy as sp

from ..errors import ModelError
from .base import Moments, Transform, batch_sqrt

__all__ = ["Exact"]


def _double_factorial_odd(a: int) -> int:
    out = 1
    for k in range(a - 1, 0, -2):
        out *= k
    return out


def _expect(poly: sp.Poly) -> float:
    total = 0.0
    for monom, coeff in poly.terms():
        if all(a % 2 == 0 for a in monom):
            m = 1
            for a in monom:
                m *= _double_factorial_odd(a)
            total += float(coeff) * m
    return total


@dataclass(frozen=True)
class Exact(Transform):
    """Exact mean, covariance and cross-covariance for polynomial g.

    Raises
    ------
    ModelError
        If an output is not a polynomial in the inputs and noise.
    """

    exact_degree: ClassVar[float] = float("inf")
    name: ClassVar[str] = "exact"

    def cost(self, n_w: int) -> int:
        """No evaluations of g: the moments are symbolic."""
        return 0

    def _moments(self, cm, means, covs, angles, executor):
        if angles:
            raise ModelError("Exact moments are not defined for angle outputs (wrapping is not polynomial)")
        exprs = [sp.sympify(e) for e in cm.source_exprs]
        syms = cm.symbols
        for i, e in enumerate(exprs):
            if not e.is_polynomial(*syms):
                raise ModelError(f"Exact() needs polynomial outputs; output {i} ({e}) is not polynomial")
        K, n = means.shape
        z = sp.symbols(f"z0:{n}")
        L = batch_sqrt(covs)
        out_m, out_c, out_x, out_s = [], [], [], []
        for k in range(K):
            w = [float(means[k, i]) + sum(float(L[k, i, j]) * z[j] for j in range(n)) for i in range(n)]
            sub = dict(zip(syms, w))
            P = [sp.Poly(sp.expand(e.subs(sub)), *z) for e in exprs]
            Wp = [sp.Poly(wi, *z) for wi in w]
            m = np.array([_expect(p) for p in P])
            ny = len(P)
            C = np.empty((ny, ny))
            for i in range(ny):
                for j in range(i, ny):
                    C[i, j] = C[j, i] = _expect(P[i] * P[j]) - m[i] * m[j]
            # The rounding scale of C (Moments.cov_scale): E |P_i|² with the absolute values of
            # the coefficients bounds every term the entries of row i were summed from.
            absolute = [sp.Poly.from_dict({mono: abs(c) for mono, c in p.terms()}, *z) for p in P]
            out_s.append([_expect(p * p) for p in absolute])
            X = np.array([[_expect(P[i] * Wp[j]) - m[i] * means[k, j] for j in range(n)] for i in range(ny)])
            out_m.append(m)
            out_c.append(C)
            out_x.append(X)
        return Moments(np.array(out_m), np.array(out_c), np.array(out_x), evaluations=0,
                       cov_scale=np.array(out_s, dtype=float))
