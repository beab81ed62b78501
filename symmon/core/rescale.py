"""Changes of units of a model and of a Gaussian: the affine map (18) applied to g, (20) and
(35a), and to the distributions, (35b)–(35c).

The validation of the scales and offsets and the substitution itself are in
:mod:`symmon.core.affine`; this module holds the public functions.
See :mod:`symmon.units` for the conventions (S maps new-unit numbers to old-unit numbers).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import sympy as sp

from ..errors import ArgumentTypeError, ModelError, ShapeError
from .affine import changed_parts, offset_vector, scale_matrix
from .gaussian import Gaussian
from .mixture import Empirical, GaussianMixture
from .model import Model

__all__ = ["change_units", "changed_relation", "change_gaussian"]


def change_units(
    model: Model,
    S_u: Any = None,
    o_u: Any = None,
    S_y: Any = None,
    o_y: Any = None,
    S_v: Any = None,
    *,
    suffix: str = "_bar",
) -> Model:
    """The same physical relation in new units, (20) and the corrected (35a).

    With u = S_u ū + o_u, y = S_y ȳ + o_y and v = S_v v̄ (18), the model in the new
    units is ḡ(ū, v̄) = S_y⁻¹ (g(S_u ū + o_u, S_v v̄) − o_y).

    Parameters
    ----------
    model : Model
        y = g(u, v) in the old units.
    S_u, S_y, S_v : scalar, sequence or matrix, optional
        Scale matrices (numeric or sympy; a sequence is a diagonal, a scalar s means s·I);
        column k holds the old-unit value of one new unit of component k. Default I.
    o_u, o_y : sequence, optional
        Offsets: the old-unit values of the new-unit zero. Default 0. The noise has no
        offset (zero mean in every unit system, footnote 4 of the paper).
    suffix : str, default "_bar"
        Appended to the names of the new input and noise symbols (ū is ``x_bar``). With
        ``suffix=""`` the old symbols are reused for the new-unit variables.

    Returns
    -------
    Model
        ḡ with inputs ū and noise v̄. Angle declarations are kept only for components whose
        units are unchanged, because angle wrapping is done in radians.

    Raises
    ------
    ShapeError, SingularMatrixError, SymmonError
        Wrong shapes, singular or (where numeric) non positive definite scales.

    Examples
    --------
    >>> import sympy as sp
    >>> x, y = sp.symbols("x y", real=True)
    >>> polar = Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    >>> change_units(polar, S_y=[1, sp.pi / 180]).outputs[1]   # bearing rad -> deg
    180*atan2(y_bar, x_bar)/pi
    """
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    return model.change_units(S_u, o_u, S_y, o_y, S_v, suffix=suffix)


def changed_relation(
    model: Model,
    S_u: Any = None,
    o_u: Any = None,
    S_y: Any = None,
    o_y: Any = None,
    S_v: Any = None,
    *,
    suffix: str = "_bar",
) -> tuple[tuple[sp.Symbol, ...], tuple[sp.Symbol, ...], sp.Matrix]:
    """ḡ(ū, v̄) = S_y⁻¹(g(S_u ū + o_u, S_v v̄) − o_y) (20), (35a) with symbolic scales allowed.

    Same arguments as :func:`change_units`, but the result is ``(ū, v̄, ḡ)`` (symbols and a
    column Matrix), because a :class:`Model` accepts no symbols besides its inputs and noise.

    Examples
    --------
    >>> import sympy as sp
    >>> x = sp.Symbol("x", real=True); s, o = sp.symbols("s o", positive=True)
    >>> changed_relation(Model([x], [x**2]), S_u=s, o_u=[o])[2]
    Matrix([[(o + s*x_bar)**2]])
    """
    if not isinstance(model, Model):
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    if model.n_v == 0 and S_v is not None:
        raise ModelError("S_v was given but the model declares no noise symbols")
    Su = scale_matrix(S_u, model.n_u, "S_u")
    ou = offset_vector(o_u, model.n_u, "o_u")
    Sy = scale_matrix(S_y, model.n_y, "S_y")
    oy = offset_vector(o_y, model.n_y, "o_y")
    Sv = scale_matrix(S_v, model.n_v, "S_v") if model.n_v else sp.zeros(0, 0)
    u_new, v_new, g = changed_parts(model, Su, ou, Sy, oy, Sv, suffix)
    return tuple(u_new), tuple(v_new), g


def _numeric_matrix(S: Any, n: int, name: str) -> np.ndarray:
    M = scale_matrix(S, n, name)
    if M.free_symbols:
        raise ShapeError(f"{name} must be numeric to transform a Gaussian, got symbols {sorted(map(str, M.free_symbols))}")
    return np.array(M.evalf(), dtype=float)


def change_gaussian(dist: Gaussian | GaussianMixture | Empirical, S: Any, o: Any = None
                    ) -> Gaussian | GaussianMixture | Empirical:
    """The distribution of the new-unit variable x̄ = S⁻¹ (x − o) given x ~ ``dist``.

    This is the distribution change (35b)–(35c) that matches :func:`change_units`:
    ``dist`` is in the old units, x = S x̄ + o (18), and the result is in the new units,
    N(S⁻¹(m − o), S⁻¹ P S⁻ᵀ). Use ``o=None`` for noise (18c). The inverse change is
    ``change_gaussian(result, S⁻¹, −S⁻¹ o)``.  A :class:`~symmon.core.mixture.GaussianMixture`
    is mapped component by component (same weights), an
    :class:`~symmon.core.mixture.Empirical` particle by particle.

    Parameters
    ----------
    dist : Gaussian, GaussianMixture or Empirical
        x in the old units.
    S : scalar, sequence or matrix
        Numeric scale (positive definite, invertible), same convention as :func:`change_units`.
    o : sequence, optional
        Numeric offset, default 0.

    Returns
    -------
    Gaussian, GaussianMixture or Empirical
        The same kind as ``dist``.

    Examples
    --------
    >>> change_gaussian(Gaussian([1000.0], [[4.0e4]]), S=1000.0)   # m -> km
    N([1], [[0.04]])
    """
    if isinstance(dist, GaussianMixture):
        return GaussianMixture.from_components(dist.weights, [change_gaussian(g, S, o) for g in dist.components])
    if isinstance(dist, Empirical):
        A = _numeric_matrix(S, dist.dim, "S")
        off = offset_vector(o, dist.dim, "o")
        if off.free_symbols:
            raise ShapeError("o must be numeric to transform a distribution")
        ov = np.array(off.evalf(), dtype=float).ravel()
        return Empirical(np.linalg.solve(A, (dist.samples - ov).T).T, dist.weights)
    if not isinstance(dist, Gaussian):
        raise ArgumentTypeError(f"dist must be a symmon.Gaussian, GaussianMixture or Empirical, got {type(dist).__name__}")
    A = _numeric_matrix(S, dist.dim, "S")
    off = offset_vector(o, dist.dim, "o")
    if off.free_symbols:
        raise ShapeError("o must be numeric to transform a Gaussian")
    ov = np.array(off.evalf(), dtype=float).ravel()
    Ainv = np.linalg.inv(A)
    cov = Ainv @ dist.cov @ Ainv.T
    return Gaussian(Ainv @ (dist.mean - ov), 0.5 * (cov + cov.T))
