"""Stochastic differential equations dx = a(x, t, θ) dt + L(x, t, θ) dβ, declared with sympy.

β is a Brownian motion with spectral density (diffusion matrix) Q_c: E[dβ dβᵀ] = Q_c dt.
The declaration is validated as a :class:`~symmon.core.model.Model` is: the shapes, the
symbols, a symmetric positive semi-definite Q_c and a diffusion L with as many columns as Q_c.
Its discretisation into a ``Model`` x_{k+1} = f(x_k, w_k; dt), w_k ~ N(0, I), is
:mod:`symmon.core.discretize` (:meth:`SDE.discretize`, :meth:`SDE.noise_cov`).

The equations are time-invariant unless a time symbol is declared (``time=t``) and a(·) or
L(·) use it; Q_c never depends on t.  A time-varying SDE is discretised with the start time
of each step as a parameter (its "exact" discretisation is refused: a time-varying linear
SDE has no single e^{A dt}).  The time unit is the user's: Q_c is a density per unit of
time, so measuring dt in seconds or in milliseconds changes Q_c by the same factor.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np
import sympy as sp

from ..errors import CovarianceError, DiscretizationError, ModelError, ShapeError, plain_repr
from . import dag
from .discretize import default_dt, discretize, exact_transition
from .symbols import as_symbols

__all__ = ["SDE"]


def _as_matrix(value, what: str) -> sp.Matrix:
    if isinstance(value, str):
        raise ModelError(f"{what} must be sympy expressions or numbers, not a string")
    try:
        if isinstance(value, sp.MatrixBase):
            return sp.Matrix(value)
        arr = value.tolist() if isinstance(value, np.ndarray) else value
        if isinstance(arr, (list, tuple)) and arr and not isinstance(arr[0], (list, tuple)):
            arr = [[e] for e in arr]  # a 1-D sequence is a column
        if not isinstance(arr, (list, tuple)):
            arr = [[arr]]
        if any(isinstance(e, str) for row in arr for e in row):
            raise ModelError(f"{what} must be sympy expressions or numbers, not strings "
                             "(use symmon.files.modelfile to parse text safely)")
        return sp.Matrix([[sp.sympify(e, strict=True) for e in row] for row in arr])
    except (sp.SympifyError, TypeError, ValueError) as exc:
        raise ModelError(f"{what} must be a matrix of sympy expressions or numbers: {exc}") from None


class SDE:
    """A stochastic differential equation dx = a(x, t, θ) dt + L(x, t, θ) dβ.

    Parameters
    ----------
    states : sequence of sympy.Symbol or str
        The state x, n symbols.
    drift : sequence of sympy.Expr
        a(x, t, θ), n expressions in the states, the parameters and the time symbol.
    diffusion : matrix-like, optional
        L(x, t, θ), shape (n, m); a 1-D sequence is one column.  Default: the identity (m = n).
    spectral_density : matrix-like or scalar, optional
        Q_c, shape (m, m), symmetric positive semi-definite, constant (parameters allowed,
        states not); a scalar q stands for q I.  Default: the identity.
    params : sequence of sympy.Symbol, optional
        Parameters θ (an intensity q, a turn rate ω, a time constant): declared as for
        ``Model`` and kept as parameters by the discretisation.
    angles : iterable of sympy.Symbol or int, optional
        States that are angles (symbols or indices): wrapped by the filters.
    name : str, optional
    time : sympy.Symbol, optional
        The time symbol t, which the drift and L may use (a time-varying SDE); neither a
        state nor a parameter, and not in Q_c.  Default None: no time symbol.

    Raises
    ------
    ModelError
        For duplicate or unknown symbols (the drift and L may use only the states, the
        parameters and the time symbol, Q_c only the parameters), a time symbol that is not a
        sympy Symbol or is a state or a parameter, a drift of another length than the states,
        or a text where an expression is expected.
    ShapeError
        For an L with another number of rows than states or of columns than Q_c, or a
        non-square Q_c.
    CovarianceError
        For a Q_c that is not symmetric or provably not positive semi-definite (a numeric
        Q_c with a negative eigenvalue, a symbolic one with a negative diagonal entry).

    Examples
    --------
    >>> import sympy as sp
    >>> p, v, q = sp.symbols("p v q", real=True)
    >>> wna = SDE([p, v], [v, 0], diffusion=[0, 1], spectral_density=q, params=[q])
    >>> wna.is_linear, wna.n, wna.m
    (True, 2, 1)
    >>> t = sp.Symbol("t", real=True)
    >>> forced = SDE([p], [-p + sp.sin(t)], diffusion=[q], params=[q], time=t)
    >>> forced.is_time_invariant, forced.is_linear
    (False, True)
    """

    def __init__(
        self,
        states: Sequence[sp.Symbol],
        drift: Sequence[sp.Expr] | sp.Expr,
        diffusion=None,
        spectral_density=None,
        params: Sequence[sp.Symbol] = (),
        angles: Iterable = (),
        name: str | None = None,
        time: sp.Symbol | None = None,
    ) -> None:
        x = as_symbols(states, "states")
        p = as_symbols(params, "params")
        if time is not None and not isinstance(time, sp.Symbol):
            raise ModelError(f"time must be a sympy Symbol (the time t of a(x, t) and L(x, t)) or None, "
                             f"got {plain_repr(time)}")
        if not x:
            raise ModelError("an SDE needs at least one state symbol")
        for group, what in ((x, "states"), (p, "params")):
            dup = {s for s in group if group.count(s) > 1}
            if dup:
                raise ModelError(f"duplicate symbols in {what}: {sorted(map(str, dup))}")
        both = set(x) & set(p)
        if both:
            raise ModelError(f"symbols declared both as states and params: {sorted(map(str, both))}")
        if time is not None and (time in x or time in p or str(time) in {str(s) for s in (*x, *p)}):
            raise ModelError(f"the time symbol {time} is also a state or a parameter (or has the name of one): "
                             "it must be its own symbol")
        n = len(x)
        a = _as_matrix(drift, "drift")
        if a.shape[1] != 1 and a.shape[0] == 1:
            a = a.T
        if a.shape != (n, 1):
            raise ModelError(f"drift must have one expression per state ({n}), got shape {a.shape}")
        L = sp.eye(n) if diffusion is None else _as_matrix(diffusion, "diffusion")
        if L.shape[0] != n:
            raise ShapeError(f"diffusion must have one row per state ({n}), got shape {L.shape}")
        m = L.shape[1]
        if spectral_density is None:
            Qc = sp.eye(m)
        elif not isinstance(spectral_density, (list, tuple, np.ndarray, sp.MatrixBase)):
            Qc = _as_matrix(spectral_density, "spectral_density")[0, 0] * sp.eye(m)
        else:
            Qc = _as_matrix(spectral_density, "spectral_density")
            if Qc.shape[1] == 1 and Qc.shape[0] > 1 and not isinstance(spectral_density, sp.MatrixBase):
                raise ShapeError(f"spectral_density must be a square matrix, got shape {Qc.shape}")
        if Qc.shape[0] != Qc.shape[1]:
            raise ShapeError(f"spectral_density must be a square matrix, got shape {Qc.shape}")
        if Qc.shape[0] != m:
            raise ShapeError(
                f"diffusion has {m} columns but spectral_density is {Qc.shape[0]}x{Qc.shape[1]}: "
                "L needs one column per component of the Brownian motion")
        known = set(x) | set(p) | ({time} if time is not None else set())
        for what, mat, allowed in (("drift", a, known), ("diffusion", L, known), ("spectral_density", Qc, set(p))):
            for e in mat:
                unknown = dag.free_symbols(e) - allowed
                if unknown:
                    extra = " (Q_c must be constant: states and time are not allowed)" \
                        if what == "spectral_density" else ""
                    declared = f", time {time}" if time is not None else ""
                    raise ModelError(
                        f"{what} entry {dag.bounded_str(e)} uses unknown symbols {sorted(map(str, unknown))}; "
                        f"declared states {[str(s) for s in x]}, params {[str(s) for s in p]}{declared}{extra}")
        _check_psd(Qc)
        self._x, self._p, self._a, self._L, self._Qc, self._name = x, p, a, L, Qc, name
        self._t = time
        self._angles = self._resolve_angles(angles)

    def _resolve_angles(self, angles) -> frozenset[int]:
        if isinstance(angles, (int, np.integer, sp.Symbol)):
            angles = (angles,)
        out = set()
        for ang in angles or ():
            if isinstance(ang, (int, np.integer)) and not isinstance(ang, (bool, np.bool_)):
                if not 0 <= int(ang) < len(self._x):
                    raise ModelError(f"angle state index {ang} out of range for {len(self._x)} states")
                out.add(int(ang))
            elif isinstance(ang, sp.Symbol) and ang in self._x:
                out.add(self._x.index(ang))
            else:
                raise ModelError(f"angles must be state indices or state symbols, got {plain_repr(ang)}")
        return frozenset(out)

    # --- the declaration ------------------------------------------------------
    @property
    def states(self) -> tuple[sp.Symbol, ...]:
        """The state symbols x."""
        return self._x

    @property
    def params(self) -> tuple[sp.Symbol, ...]:
        """The parameter symbols θ."""
        return self._p

    @property
    def time(self) -> sp.Symbol | None:
        """The declared time symbol t (None if there is none)."""
        return self._t

    @property
    def is_time_invariant(self) -> bool:
        """Whether a(·) and L(·) are free of the time symbol (always, without one)."""
        t = self._t
        return t is None or not any(t in dag.free_symbols(e) for e in (*self._a, *self._L))

    def check_time_invariant(self, what: str) -> None:
        """Refuse a time-varying SDE where ``what`` (a method, a route) needs a time-invariant one.

        Raises
        ------
        DiscretizationError
            Naming ``what`` and the time symbol.
        """
        if not self.is_time_invariant:
            raise DiscretizationError(
                f"{what} needs a time-invariant SDE, but {self.name!r} depends on its time symbol {self._t} "
                "(a time-varying linear SDE has no single e^(A dt)): discretise it by 'local_linear', 'rk4', "
                "'taylor1.5' or 'euler' (the start time of each step a parameter), or filter it with "
                "sm.ContinuousDiscreteKalmanFilter(sde, h, R, 'ekf'), which integrates with the absolute time")

    @property
    def drift(self) -> sp.Matrix:
        """a(x, t, θ), shape (n, 1)."""
        return self._a

    @property
    def diffusion(self) -> sp.Matrix:
        """L(x, t, θ), shape (n, m)."""
        return self._L

    @property
    def spectral_density(self) -> sp.Matrix:
        """Q_c, shape (m, m)."""
        return self._Qc

    @property
    def angles(self) -> frozenset[int]:
        """Indices of the states that are angles."""
        return self._angles

    @property
    def name(self) -> str:
        return self._name or "sde"

    @property
    def n(self) -> int:
        """The number of states."""
        return len(self._x)

    @property
    def m(self) -> int:
        """The dimension of the Brownian motion β (the columns of L)."""
        return self._L.shape[1]

    @property
    def additive(self) -> bool:
        """Whether L is free of the states (additive noise)."""
        return not any(dag.free_symbols(e) & set(self._x) for e in self._L)

    @property
    def jacobian(self) -> sp.Matrix:
        """∂a/∂x, shape (n, n)."""
        return self._a.jacobian(sp.Matrix(self._x))

    @property
    def is_linear(self) -> bool:
        """Whether the drift is affine in x (a = A x + b with A, b free of x) and L is constant
        in x.  A, b and L may depend on the time symbol: the ``"exact"`` discretisation needs
        a linear *and* time-invariant SDE (:attr:`is_time_invariant`)."""
        J = self.jacobian
        xs = set(self._x)
        return self.additive and not any(dag.free_symbols(e) & xs for e in J)

    @property
    def linear_parts(self) -> tuple[sp.Matrix, sp.Matrix]:
        """(A, b) of a linear drift a = A x + b (functions of t for a time-varying SDE).

        Raises
        ------
        DiscretizationError
            If the drift is not affine in x or L depends on x.
        """
        if not self.is_linear:
            raise DiscretizationError(
                f"SDE {self.name!r} is not linear (its drift is not affine in the states "
                "or its diffusion depends on them)")
        A = self.jacobian
        b = self._a.subs({s: 0 for s in self._x})
        return A, b

    # --- discretisation ---------------------------------------------------------
    def noise_cov(self, dt: sp.Symbol | None = None) -> sp.Matrix:
        """Q(dt) = ∫₀^dt e^{A s} L Q_c Lᵀ e^{Aᵀ s} ds (Van Loan), in closed form.

        Parameters
        ----------
        dt : sympy.Symbol or number, optional
            The step; default ``Symbol("dt", positive=True)``.

        Raises
        ------
        DiscretizationError
            For an SDE that is not linear and time-invariant, or an integral that sympy
            cannot give in closed form within the time limit.

        Examples
        --------
        >>> import sympy as sp
        >>> p, v, q = sp.symbols("p v q", positive=True)
        >>> SDE([p, v], [v, 0], [0, 1], q, params=[q]).noise_cov()
        Matrix([
        [dt**3*q/3, dt**2*q/2],
        [dt**2*q/2,      dt*q]])
        """
        return exact_transition(self, default_dt() if dt is None else dt)[2]

    def transition_matrix(self, dt: sp.Symbol | None = None) -> sp.Matrix:
        """F(dt) = e^{A dt} of a linear SDE, in closed form (see :meth:`noise_cov`)."""
        return exact_transition(self, default_dt() if dt is None else dt)[0]

    def discretize(self, method: str = "exact", dt: sp.Symbol | None = None, substeps: int = 1):
        """The transition over a step dt as a :class:`~symmon.core.model.Model`.

        See :func:`symmon.core.discretize.discretize` for the methods.

        Examples
        --------
        >>> import sympy as sp
        >>> x, theta = sp.symbols("x theta", positive=True)
        >>> f = SDE([x], [-theta * x], params=[theta]).discretize("exact")
        >>> f.params
        (theta, dt)
        >>> t = sp.Symbol("t", real=True)
        >>> SDE([x], [-theta * x + sp.cos(t)], params=[theta], time=t).discretize("euler").params
        (theta, t, dt)
        """
        return discretize(self, method, dt=dt, substeps=substeps)

    def __repr__(self) -> str:
        return (f"SDE({self.name!r}, states={[str(s) for s in self._x]}, "
                f"drift={[dag.bounded_str(e) for e in self._a]}, m={self.m}"
                + (f", params={[str(s) for s in self._p]}" if self._p else "")
                + (f", time={self._t}" if self._t is not None else "") + ")")


def _check_psd(Qc: sp.Matrix) -> None:
    """Symmetric, and positive semi-definite where that can be decided: numerically for a
    numeric Q_c, by a negative diagonal entry or 2x2 minor for a symbolic one (sympy.stats'
    rule: raise only when the condition is provably false)."""
    m = Qc.shape[0]
    for i in range(m):
        for j in range(i + 1, m):
            if sp.simplify(Qc[i, j] - Qc[j, i]) != 0:
                raise CovarianceError(
                    f"spectral_density must be symmetric: entry ({i}, {j}) is {Qc[i, j]}, entry ({j}, {i}) is {Qc[j, i]}")
    if not Qc.free_symbols:
        vals = np.array(Qc.evalf(), dtype=float)
        if not np.all(np.isfinite(vals)):
            raise CovarianceError("spectral_density must be finite")
        eig = np.linalg.eigvalsh(vals) if m else np.zeros(0)
        if m and eig.min() < -1e-12 * max(1.0, np.abs(eig).max()):
            raise CovarianceError(
                f"spectral_density must be positive semi-definite, its smallest eigenvalue is {eig.min():.3g}")
        return
    for i in range(m):
        if Qc[i, i].is_negative:
            raise CovarianceError(f"spectral_density entry ({i}, {i}) is negative: {Qc[i, i]}")
        for j in range(i + 1, m):
            if (Qc[i, i] * Qc[j, j] - Qc[i, j] ** 2).is_negative:
                raise CovarianceError(
                    f"spectral_density is not positive semi-definite: the minor of rows {i} and {j} is negative")
