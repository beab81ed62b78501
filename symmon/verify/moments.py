r"""Symbolic moments of a model under a transform: E y, Cov y and Cov(y, u) as sympy matrices.

What a paper's appendix prints: the moments of y = g(u, v) for u ~ N(μ, P) (and noise
v ~ N(μ_v, P_v), independent of u) as formulas in the symbols of μ and P, with w = [u; v],
μ_w = [μ; μ_v] and P_w = blkdiag(P, P_v), as :func:`symmon.propagate` forms them.  The
rules, in the notation of :mod:`symmon.transforms.taylor` and :mod:`symmon.transforms.unscented`
(g_i the outputs, J the Jacobian and H_i the Hessians at μ_w, by sympy's exact
differentiation of the model's expressions):

(5) TT1:  E y = g(μ_w),  Cov y = J P_w Jᵀ,  Cov(y, w) = J P_w.
(6) TT2:  E y_i = g_i(μ_w) + ½ tr(H_i P_w),
          Cov(y_i, y_j) = J_i P_w J_jᵀ + ½ tr(H_i P_w H_j P_w),  Cov(y, w) = J P_w
          (Gustafsson & Hendeby 2012; the third central moments of a Gaussian vanish).
(7) point rules (the UT family: ut1, ut2, the cubature rule, any α, β, κ): with the rule's
    unit points z_k and weights w_k^m, w_k^c in exact arithmetic
    (:meth:`~symmon.Transform.symbolic_unit_rule`) and the lower Cholesky factor L of P_w,
    computed symbolically block by block,
          X_k = μ_w + L z_k,  Y_k = g(X_k),  E y = Σ w_k^m Y_k,
          Cov y = Σ w_k^c (Y_k − E y)(Y_k − E y)ᵀ,  Cov(y, w) = Σ w_k^c (Y_k − E y)(X_k − μ_w)ᵀ.
(8) exact:  E y_i = E[g_i(w)],  Cov(y_i, y_j) = E[g_i g_j] − E y_i E y_j,
            Cov(y_i, u_k) = E[g_i u_k] − E y_i μ_k,  each by :func:`~symmon.verify.expectation.expect`
            (eqs. (1)–(4)), or :class:`~symmon.errors.ExpectationNotClosedForm`.

Cov(y, u) is the u-block of Cov(y, w).  A symbolic Cholesky factor grows fast with its size:
a dense symbolic block of P_w larger than :data:`MAX_SYMBOLIC_BLOCK` is refused (a
:class:`~symmon.errors.ResourceError`); numeric blocks have no limit.

References
----------
F. Gustafsson, G. Hendeby, "Some relations between extended and unscented Kalman filters",
IEEE Trans. Signal Process. 60(2), 2012. doi:10.1109/TSP.2011.2172431
S. J. Julier, J. K. Uhlmann, "Unscented filtering and nonlinear estimation", Proc. IEEE 92(3),
2004. doi:10.1109/JPROC.2003.823141
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import sympy as sp

from ..core.gaussian import Gaussian
from ..core.model import Model
from ..latex import latex_text
from ..errors import ArgumentError, ArgumentTypeError, ModelError, NonFiniteError, ResourceError
from ..propagation.front import check_transform
from ..transforms.exact import Exact
from ..transforms.base import Transform
from .expectation import as_mean_cov, expect

__all__ = ["SymbolicMoments", "symbolic_moments", "MAX_SYMBOLIC_BLOCK", "MAX_POINTS"]

#: Largest dense block of P_w with symbolic entries whose Cholesky factor is built symbolically.
MAX_SYMBOLIC_BLOCK = 3
#: Most points of a point rule evaluated symbolically.
MAX_POINTS = 64


@dataclass(frozen=True)
class SymbolicMoments:
    """E y, Cov y and Cov(y, u) of a model as sympy matrices, and what they are in.

    Attributes
    ----------
    mean : sympy.Matrix (n_y × 1)
    cov : sympy.Matrix (n_y × n_y)
    cross_cov : sympy.Matrix (n_y × n_u)
        Cov(y, u).
    input_mean, input_cov : sympy.Matrix
        μ and P of u (the symbols created, e.g. ``mu_x`` and ``P_x_y``, or the values given).
    noise_mean, noise_cov : sympy.Matrix
        μ_v and P_v of the noise (empty without noise).
    transform : Transform
    model : Model
    unwrapped : frozenset of int
        Angle outputs whose mean is given unwrapped (TT1 and TT2; the numeric transforms
        wrap it into (−π, π]).
    """

    mean: sp.Matrix
    cov: sp.Matrix
    cross_cov: sp.Matrix
    input_mean: sp.Matrix
    input_cov: sp.Matrix
    noise_mean: sp.Matrix
    noise_cov: sp.Matrix
    transform: Transform
    model: Model
    unwrapped: frozenset = field(default_factory=frozenset)

    @property
    def symbols(self) -> list[sp.Symbol]:
        """The free symbols of the moments, sorted by name."""
        syms = self.mean.free_symbols | self.cov.free_symbols | self.cross_cov.free_symbols
        return sorted(syms, key=str)

    def substitution(self, u: Gaussian, v: Gaussian | None = None) -> dict[sp.Symbol, sp.Expr]:
        """The values of the symbols of μ, P (and μ_v, P_v) at the Gaussians u (and v).

        Raises
        ------
        ArgumentError
            An entry of μ or P was given as an expression, not a symbol, and differs from
            the Gaussian's value; or v is missing for a model with noise.
        """
        if not isinstance(u, Gaussian) or (v is not None and not isinstance(v, Gaussian)):
            raise ArgumentTypeError("u (and v) must be symmon.Gaussian")
        if u.dim != self.model.n_u:
            raise ArgumentError(f"u has dimension {u.dim} but the model has {self.model.n_u} inputs")
        pairs = [(self.input_mean, u.mean), (self.input_cov, u.cov)]
        if self.model.n_v:
            if v is None:
                raise ArgumentError(f"the model has noise {list(map(str, self.model.noise))}: pass v=Gaussian(...)")
            if v.dim != self.model.n_v:
                raise ArgumentError(f"v has dimension {v.dim} but the model has {self.model.n_v} noise symbols")
            pairs += [(self.noise_mean, v.mean), (self.noise_cov, v.cov)]
        elif v is not None:
            raise ArgumentError("v was given but the model declares no noise symbols")
        out: dict[sp.Symbol, sp.Expr] = {}
        for sym, num in pairs:
            flat = np.asarray(num, dtype=float).ravel()
            for e, val in zip(list(sym), flat):
                if isinstance(e, sp.Symbol):
                    out[e] = sp.Float(val, 30)
        for sym, num in pairs:  # entries given as numbers or expressions must match
            flat = np.asarray(num, dtype=float).ravel()
            for e, val in zip(list(sym), flat):
                if isinstance(e, sp.Symbol):
                    continue
                given = e.xreplace(out)
                if given.free_symbols or abs(float(given) - val) > 1e-12 * max(1.0, abs(val)):
                    raise ArgumentError(f"the moments were derived for an entry {e} of the mean or covariance, "
                                        f"the Gaussian has {val}")
        return out

    def evaluate(self, u: Gaussian, v: Gaussian | None = None, digits: int = 30
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """E y, Cov y and Cov(y, u) at the Gaussians u (and v) as float arrays, evaluated
        with ``digits`` significant digits before the conversion.

        Raises
        ------
        ArgumentError
            v is missing (or given for a model without noise), a dimension is wrong, or an
            entry still depends on a symbol the Gaussians do not give (a model parameter).
        NonFiniteError
            An entry is NaN, infinite or complex at these Gaussians (TT1 of the range at
            the origin): never returned as a number.
        """
        sub = self.substitution(u, v)

        def num(M: sp.Matrix, what: str) -> np.ndarray:
            out = np.empty(M.shape)
            for (i, j), e in np.ndenumerate(np.array(M.tolist(), dtype=object).reshape(M.shape)):
                value = sp.N(e.xreplace(sub), digits)
                if value.free_symbols:
                    raise ArgumentError(f"{what}[{i}, {j}] depends on {sorted(map(str, value.free_symbols))}, "
                                        "which the Gaussians do not give (a model parameter?): substitute it first")
                z = complex(value)
                if not (np.isfinite(z.real) and abs(z.imag) <= 1e-25 * max(1.0, abs(z.real))):
                    raise NonFiniteError(f"{what}[{i}, {j}] is {value} at these Gaussians, not a finite real number")
                out[i, j] = z.real
            return out

        return num(self.mean, "mean").ravel(), num(self.cov, "cov"), num(self.cross_cov, "cross_cov")


    def latex(self) -> str:
        r"""E y, Cov y and Cov(y, u) as one LaTeX ``aligned`` block (without ``$``)."""
        label = r"\text{" + latex_text(repr(self.transform)) + "}"
        rows = [(r"\mathrm{E}\,y", self.mean), (r"\mathrm{Cov}\,y", self.cov),
                (r"\mathrm{Cov}(y, u)", self.cross_cov)]
        body = r" \\ ".join(f"{k} &= {sp.latex(v)}" for k, v in rows)
        return r"\begin{aligned}" + body + r"\end{aligned}\quad(" + label + ")"

    def _repr_latex_(self) -> str:
        return f"${self.latex()}$"


# --------------------------------------------------------------------------- the symbols
def _default_mean(names: Sequence[sp.Symbol]) -> list[sp.Symbol]:
    return [sp.Symbol(f"mu_{s}", real=True) for s in names]


def _default_cov(names: Sequence[sp.Symbol]) -> sp.Matrix:
    n = len(names)
    return sp.Matrix(n, n, lambda i, j: sp.Symbol(f"P_{names[min(i, j)]}_{names[max(i, j)]}", real=True))


def _blocks(P: sp.Matrix) -> list[list[int]]:
    """The index sets of the diagonal blocks of P (connected by nonzero entries)."""
    n = P.rows
    seen, out = set(), []
    for start in range(n):
        if start in seen:
            continue
        comp, stack = [], [start]
        seen.add(start)
        while stack:
            i = stack.pop()
            comp.append(i)
            for j in range(n):
                if j not in seen and P[i, j] != 0:
                    seen.add(j)
                    stack.append(j)
        out.append(sorted(comp))
    return out


def symbolic_cholesky(P: sp.Matrix, limit: int = MAX_SYMBOLIC_BLOCK) -> sp.Matrix:
    """The lower Cholesky factor L (L Lᵀ = P) in sympy, block by block.

    Each block of P connected by nonzero entries is factored on its own (a block-diagonal
    P, as u and independent noise give, has a block-diagonal factor).  A symbolic block is
    assumed positive definite.  When the blocks are in order, L is the factor that
    ``numpy.linalg.cholesky`` computes in floats.

    Raises
    ------
    ResourceError
        A block with symbolic entries is larger than ``limit``.
    """
    L = sp.zeros(P.rows, P.cols)
    for idx in _blocks(P):
        B = P.extract(idx, idx)
        if B.free_symbols and len(idx) > limit:
            raise ResourceError(
                f"a symbolic Cholesky factor of a dense {len(idx)} x {len(idx)} covariance block (variables "
                f"{idx}) is too large to be useful (at most {limit}): give numbers for some of its entries, "
                "zeros where variables are independent, or use TT1, TT2 or the exact moments")
        LB = B.cholesky(hermitian=False) if len(idx) > 1 else sp.Matrix([[sp.sqrt(B[0, 0])]])
        for a, i in enumerate(idx):
            for b, j in enumerate(idx):
                L[i, j] = LB[a, b]
    return L


# --------------------------------------------------------------------------- the rules
def _taylor(g: sp.Matrix, w: Sequence[sp.Symbol], mw: sp.Matrix, Pw: sp.Matrix, order: int
            ) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """Eqs. (5) and (6)."""
    at = dict(zip(w, mw))
    J = g.jacobian(list(w)).xreplace(at)
    mean = g.xreplace(at)
    cov = J * Pw * J.T
    if order == 2:
        HP = [sp.hessian(gi, list(w)).xreplace(at) * Pw for gi in g]
        mean = mean + sp.Matrix([hp.trace() / 2 for hp in HP])
        cov = cov + sp.Matrix(len(HP), len(HP), lambda i, j: (HP[i] * HP[j]).trace() / 2)
    return mean, cov, J * Pw


def _point_rule(g: sp.Matrix, w: Sequence[sp.Symbol], mw: sp.Matrix, Pw: sp.Matrix, transform: Transform
                ) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """Eq. (7)."""
    n = len(w)
    rule = transform.symbolic_unit_rule(n)
    if rule is None:  # the rule's own floats: floats stay floats
        Z, wm, wc = transform.unit_rule(n)
        rule = sp.Matrix(Z.tolist()).applyfunc(sp.Float), [sp.Float(v) for v in wm], [sp.Float(v) for v in wc]
    Z, wm, wc = rule
    if Z.rows > MAX_POINTS:
        raise ResourceError(f"{transform!r} has {Z.rows} points in {n} dimensions; symbolic moments "
                            f"evaluate at most {MAX_POINTS}: use TT1, TT2, the UT family or the exact moments")
    L = symbolic_cholesky(Pw)
    X = [mw + L * Z.row(k).T for k in range(Z.rows)]
    Y = [g.xreplace(dict(zip(w, Xk))) for Xk in X]
    mean = sum((wk * Yk for wk, Yk in zip(wm, Y)), sp.zeros(g.rows, 1))
    R = [Yk - mean for Yk in Y]
    cov = sum((wk * Rk * Rk.T for wk, Rk in zip(wc, R)), sp.zeros(g.rows, g.rows))
    cross = sum((wk * Rk * (Xk - mw).T for wk, Rk, Xk in zip(wc, R, X)), sp.zeros(g.rows, n))
    return mean, cov, cross


def _exact(g: sp.Matrix, w: Sequence[sp.Symbol], mw: sp.Matrix, Pw: sp.Matrix, n_u: int
           ) -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """Eq. (8)."""
    ny = g.rows
    mean = sp.Matrix([expect(gi, w, mw, Pw) for gi in g])
    cov = sp.zeros(ny, ny)
    for i in range(ny):
        for j in range(i, ny):
            cov[i, j] = cov[j, i] = sp.expand(expect(g[i] * g[j], w, mw, Pw) - mean[i] * mean[j])
    cross = sp.Matrix(ny, len(w), lambda i, k: sp.expand(expect(g[i] * w[k], w, mw, Pw) - mean[i] * mw[k])
                      if k < n_u else sp.Integer(0))
    return mean, cov, cross


def _is_exact(transform: Transform) -> bool:
    """The exact moments: a deterministic rule exact for every polynomial degree."""
    return transform.exact_degree == float("inf") and not transform.stochastic and not transform.point_rule


def symbolic_moments(model: Model, transform: Any, mean: Any = None, cov: Any = None, *,
                     noise_mean: Any = None, noise_cov: Any = None) -> SymbolicMoments:
    r"""E y, Cov y and Cov(y, u) of y = g(u, v) as sympy matrices in the symbols of μ and P.

    The rules (module :mod:`symmon.verify.moments`): TT1 (5), TT2 (6) with sympy's exact
    derivatives, the UT family and other point rules (7) with sigma points from a symbolic
    Cholesky factor, and the exact moments (8) through :func:`~symmon.verify.expectation.expect`.
    Evaluated at numbers they are what :func:`symmon.propagate` computes with the same
    transform, in exact arithmetic.

    Parameters
    ----------
    model : Model
        y = g(u, v).  Parameters of the model (``Model(params=...)``) stay symbols.
    transform : Transform or str
        TT1(), TT2(), UT(...) (``"ut1"``, ``"ut2"``, ``"ct"``), Exact() (``"exact"``), or
        another deterministic point rule of at most :data:`MAX_POINTS` points.
    mean : sequence of n_u numbers or expressions, optional
        μ; default the symbols ``mu_<input>`` (e.g. ``mu_x``).
    cov : (n_u, n_u) matrix, optional
        P; default the symmetric matrix of symbols ``P_<a>_<b>`` (e.g. ``P_x_x``, ``P_x_y``).
        Zeros make variables independent (and keep a point rule's Cholesky factor small).
    noise_mean : sequence of n_v numbers or expressions, keyword-only, optional
        μ_v; default 0 (the noise is zero mean, :class:`~symmon.Model`).
    noise_cov : (n_v, n_v) matrix, keyword-only, optional
        P_v; default the symbols ``P_<e>_<f>`` of the noise symbols.

    Returns
    -------
    SymbolicMoments
        ``.mean``, ``.cov``, ``.cross_cov``, ``.latex()``, ``.evaluate(u, v)``.

    Raises
    ------
    ArgumentTypeError
        ``model`` is not a Model, or ``transform`` is a stochastic rule (Monte Carlo has no
        symbolic moments).
    ModelError
        A point rule or the exact moments of an angle output (a circular mean and wrapped
        residuals are not closed forms: declare the model without angles,
        ``model.with_angles(())``, for the moments of the unwrapped output).
    ResourceError
        A point rule's dense symbolic covariance block is larger than
        :data:`MAX_SYMBOLIC_BLOCK`, or the rule has more than :data:`MAX_POINTS` points.
    ExpectationNotClosedForm
        The exact moments of an output outside :func:`~symmon.verify.expectation.expect`'s class.

    Examples
    --------
    >>> import sympy as sp, symmon as sm
    >>> x = sp.Symbol("x", real=True)
    >>> m = sm.symbolic_moments(sm.Model([x], [x**2]), sm.TT2())
    >>> m.mean[0], sp.expand(m.cov[0, 0])
    (P_x_x + mu_x**2, 2*P_x_x**2 + 4*P_x_x*mu_x**2)
    """
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    # "exact": the exact moments (8), by name as verify_moments takes them (not a registry preset)
    tr = Exact() if isinstance(transform, str) and transform.lower() == "exact" else check_transform(transform)
    if tr.stochastic:
        raise ArgumentTypeError(f"{tr!r} is stochastic: its moments are random, not formulas; use TT1, TT2, "
                                "a UT rule or the exact moments")
    u, v = model.inputs, model.noise
    mu, P = as_mean_cov(_default_mean(u) if mean is None else mean, _default_cov(u) if cov is None else cov,
                        len(u), u + v)
    if v:
        mv, Pv = as_mean_cov([0] * len(v) if noise_mean is None else noise_mean,
                             _default_cov(v) if noise_cov is None else noise_cov, len(v), u + v)
    else:
        if noise_mean is not None or noise_cov is not None:
            raise ModelError("noise_mean or noise_cov was given but the model declares no noise symbols")
        mv, Pv = sp.zeros(0, 1), sp.zeros(0, 0)
    w = tuple(u) + tuple(v)
    mw = sp.Matrix.vstack(mu, mv)
    Pw = sp.diag(P, Pv) if v else P
    g = sp.Matrix(model.outputs)
    angles = frozenset(model.angle_outputs)
    if tr.taylor_order in (1, 2):
        m, C, X = _taylor(g, w, mw, Pw, tr.taylor_order)
    elif angles:
        raise ModelError(
            f"outputs {sorted(angles)} are declared angles: {tr!r} takes their circular mean and wraps "
            "their residuals, which have no closed form; pass model.with_angles(()) for the moments of "
            "the unwrapped outputs, or use TT1 or TT2")
    elif tr.point_rule:
        m, C, X = _point_rule(g, w, mw, Pw, tr)
    elif _is_exact(tr):
        m, C, X = _exact(g, w, mw, Pw, len(u))
    else:
        raise ArgumentTypeError(f"{tr!r} declares no symbolic form (a Taylor order, a point rule or exact moments)")
    return SymbolicMoments(m, C, X[:, :len(u)], mu, P, mv, Pv, tr, model, angles if tr.taylor_order else frozenset())
