"""Changes of units, pint integration and the symbolic proof of unit invariance.

A change of units is the affine map (18) of Straka & Havlík (2024)::

    u = S_u ū + o_u,    y = S_y ȳ + o_y,    v = S_v v̄,              (18a–c)

where the barred quantities are expressed in the *new* units and the plain ones in the
*old* units.  The same physical relation in the new units is (20), (35a) (with the
erratum S_v⁻¹, o_v → S_y⁻¹, o_y of REFERENCE.md)::

    ḡ(ū, v̄) = S_y⁻¹ (g(S_u ū + o_u, S_v v̄) − o_y).

Direction convention, used everywhere in this module: **S maps new-unit numbers to
old-unit numbers**.  Column k of S is the old-unit value of one new unit of component k.
Converting a position from m (old) to km (new) gives S = 1000, because 1 km = 1000 m;
converting a bearing from rad to deg gives S = π/180.

Contents
--------
- :func:`change_units`, :func:`change_gaussian`: the model and the distributions in new
  units, with exact sympy matrices (numeric or symbolic).
- :func:`with_units`, :class:`UnitModel`: declare physical units with pint and convert; the
  scale matrices and offsets come from pint, never from a table.
- :func:`prove_invariance`: the measure of nonlinearity (MoN) of a model under its TT2
  closed form, built symbolically in the old and in the new units with symbolic S and o,
  and the difference M²(g, u) − M²(ḡ, ū) simplified: zero for the unitless weights (42),
  (43) and (38)/(41), nonzero for Liu–Li's (6) and (8).
- :func:`prove_matrix_invariance`: the exact statement in matrix form, independent of any
  transform: the moment maps Σ_gg → S_y Σ_gg S_yᵀ, Σ_gu → S_y Σ_gu S_uᵀ,
  Σ_uu → S_u Σ_uu S_uᵀ leave tr(W D) invariant.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (34)–(43).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np
import sympy as sp

from .errors import ModelError, ShapeError, SingularMatrixError, SymmonError
from .gaussian import Gaussian
from .model import Model

__all__ = [
    "UnitError",
    "change_units",
    "change_gaussian",
    "changed_relation",
    "with_units",
    "UnitModel",
    "InvarianceProof",
    "prove_invariance",
    "prove_matrix_invariance",
]

#: Names of the weights understood by the proofs (same names as ``symmon.nonlinearity``).
WEIGHTS = ("full", "diag", "liu-li", "liu-li-raw")

#: Relative tolerance of the numeric positive-definiteness and affinity checks.
_PD_RTOL = 1e-12
#: Differences larger than this (sympy operation count) are not put over a common
#: denominator: the counterexample alone decides them.
_CANCEL_MAX_OPS = 20000
#: A conversion is accepted as affine when f(2) − 2 f(1) + f(0) is this small relative to f.
_AFFINE_RTOL = 1e-9

_PINT_HINT = "pint is needed for physical units: pip install 'symmon[units]' (or pip install pint)"


class UnitError(ModelError):
    """An unknown unit, incompatible dimensions, or a unit declaration that does not fit the model."""


# --------------------------------------------------------------------------------------
# Validation of scale matrices and offsets
# --------------------------------------------------------------------------------------
def _sympify_entry(x: Any, name: str) -> sp.Expr:
    if isinstance(x, str):
        raise ShapeError(f"{name}: entries must be numbers or sympy expressions, not strings ({x!r})")
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            raise ShapeError(f"{name} contains NaN or inf")
        return sp.Float(float(x))
    if isinstance(x, (np.integer,)):
        return sp.Integer(int(x))
    try:
        e = sp.sympify(x, strict=True)
    except sp.SympifyError as exc:
        raise ShapeError(f"{name}: entry {x!r} is not a number or sympy expression") from exc
    if e.has(sp.nan, sp.zoo, sp.oo, -sp.oo):
        raise ShapeError(f"{name} contains NaN or inf")
    return e


def _scale_matrix(S: Any, n: int, name: str) -> sp.Matrix:
    """``S`` as an n×n sympy Matrix: None → I, a scalar → s·I, a vector → diag, a matrix as is.

    Raises
    ------
    ShapeError
        Wrong shape or non-numeric entries.
    SingularMatrixError
        det S is (provably) zero.
    SymmonError
        A numeric S whose symmetric part is not positive definite, or a diagonal entry
        that is provably not positive (a scale must keep the orientation of each axis).
    """
    if S is None:
        return sp.eye(n)
    if isinstance(S, sp.MatrixBase):
        M = sp.Matrix(S)
    else:
        arr = np.asarray(S, dtype=object)
        if arr.ndim == 0:
            M = _sympify_entry(arr.item(), name) * sp.eye(n)
        elif arr.ndim == 1:
            if arr.shape[0] != n:
                raise ShapeError(f"{name} must have {n} diagonal entries, got {arr.shape[0]}")
            M = sp.diag(*[_sympify_entry(x, name) for x in arr])
        elif arr.ndim == 2:
            M = sp.Matrix(arr.shape[0], arr.shape[1], [_sympify_entry(x, name) for x in arr.ravel()])
        else:
            raise ShapeError(f"{name} must be a scalar, a vector or a matrix, got shape {arr.shape}")
    if M.shape != (n, n):
        raise ShapeError(f"{name} must be {n}x{n}, got {M.rows}x{M.cols}")
    M = M.applyfunc(lambda e: _sympify_entry(e, name))
    for i in range(n):
        if M[i, i].is_positive is False:  # only what is provably false (sympy.stats style)
            raise SymmonError(f"{name}[{i},{i}] = {M[i, i]} is not positive: a scale matrix is positive definite (18)")
    if not M.free_symbols:
        A = np.array(M.evalf(), dtype=float)
        sym = 0.5 * (A + A.T)
        scale = float(np.max(np.abs(A)))
        if np.linalg.matrix_rank(A) < n:
            raise SingularMatrixError(f"{name} is singular: a change of units must be invertible (18)")
        if np.linalg.eigvalsh(sym)[0] <= _PD_RTOL * scale:
            raise SymmonError(
                f"{name} is not positive definite (smallest eigenvalue of its symmetric part "
                f"{np.linalg.eigvalsh(sym)[0]:.3g}); (18) requires positive definite scale matrices"
            )
        if M.det() == 0:
            raise SingularMatrixError(f"{name} is singular: a change of units must be invertible (18)")
    else:
        d = sp.cancel(M.det())
        if d == 0:
            raise SingularMatrixError(f"{name} is singular (det = 0 identically): a change of units must be invertible (18)")
    return M


def _offset_vector(o: Any, n: int, name: str) -> sp.Matrix:
    """``o`` as an n×1 sympy Matrix (None → 0; a scalar is accepted for n = 1)."""
    if o is None:
        return sp.zeros(n, 1)
    if isinstance(o, sp.MatrixBase):
        items = list(o)
        if min(o.shape) > 1:
            raise ShapeError(f"{name} must be a vector, got a {o.rows}x{o.cols} matrix")
    else:
        arr = np.asarray(o, dtype=object)
        if arr.ndim == 0:
            arr = arr.reshape(1)
        if arr.ndim != 1:
            raise ShapeError(f"{name} must be a vector, got shape {arr.shape}")
        items = list(arr)
    if len(items) != n:
        raise ShapeError(f"{name} must have length {n}, got {len(items)}")
    return sp.Matrix([_sympify_entry(x, name) for x in items])


def _inverse(M: sp.Matrix) -> sp.Matrix:
    # Diagonal scales (the usual case) are inverted entrywise: no symbolic LU noise.
    if M.is_diagonal():
        return sp.diag(*[1 / M[i, i] for i in range(M.rows)])
    return M.inv().applyfunc(sp.cancel)


def _bar_symbol(s: sp.Symbol, taken: set[str], suffix: str) -> sp.Symbol:
    name = s.name + suffix
    while name in taken:
        name += suffix or "_"
    taken.add(name)
    return sp.Symbol(name, **s.assumptions0)


# --------------------------------------------------------------------------------------
# Change of units of a model and of a Gaussian
# --------------------------------------------------------------------------------------
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
        raise TypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    Su = _scale_matrix(S_u, model.n_u, "S_u")
    ou = _offset_vector(o_u, model.n_u, "o_u")
    Sy = _scale_matrix(S_y, model.n_y, "S_y")
    oy = _offset_vector(o_y, model.n_y, "o_y")
    Sv = _scale_matrix(S_v, model.n_v, "S_v") if model.n_v else sp.zeros(0, 0)
    if model.n_v == 0 and S_v is not None:
        raise ModelError("S_v was given but the model declares no noise symbols")
    return _change_units(model, Su, ou, Sy, oy, Sv, suffix)


@dataclass(frozen=True)
class _Relation:
    """ḡ as plain sympy objects (a Model rejects symbols other than its inputs and noise)."""

    inputs: tuple
    noise: tuple
    outputs: tuple
    name: str


def _changed_parts(model: Model, Su, ou, Sy, oy, Sv, suffix: str) -> tuple[list, list, sp.Matrix]:
    taken = {s.name for s in model.inputs + model.noise} if suffix else set()
    if suffix:
        u_new = [_bar_symbol(s, taken, suffix) for s in model.inputs]
        v_new = [_bar_symbol(s, taken, suffix) for s in model.noise]
    else:
        u_new, v_new = list(model.inputs), list(model.noise)
    repl = dict(zip(model.inputs, Su * sp.Matrix(u_new) + ou))
    if model.n_v:
        repl.update(zip(model.noise, Sv * sp.Matrix(v_new)))
    g = sp.Matrix([e.xreplace(repl) for e in model.outputs])  # simultaneous replacement
    return u_new, v_new, _inverse(Sy) * (g - oy)


def _change_units(model: Model, Su, ou, Sy, oy, Sv, suffix: str) -> Model:
    params = set().union(*(M.free_symbols for M in (Su, ou, Sy, oy, Sv)))
    if params:
        raise ModelError(
            f"symbolic scales or offsets {sorted(map(str, params))} cannot go into a Model, which "
            "accepts only input and noise symbols: use symmon.units.changed_relation for the "
            "symbolic ḡ, or numbers here"
        )
    u_new, v_new, g_bar = _changed_parts(model, Su, ou, Sy, oy, Sv, suffix)
    angles: list = []
    for i in sorted(model.angle_outputs):
        if _unchanged(Sy, oy, i):
            angles.append(i)
    for i in sorted(model.angle_inputs):
        if _unchanged(Su, ou, i):
            angles.append(u_new[i])
    return Model(u_new, list(g_bar), v_new or None, model._name, angles or None)


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
        raise TypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    if model.n_v == 0 and S_v is not None:
        raise ModelError("S_v was given but the model declares no noise symbols")
    Su = _scale_matrix(S_u, model.n_u, "S_u")
    ou = _offset_vector(o_u, model.n_u, "o_u")
    Sy = _scale_matrix(S_y, model.n_y, "S_y")
    oy = _offset_vector(o_y, model.n_y, "o_y")
    Sv = _scale_matrix(S_v, model.n_v, "S_v") if model.n_v else sp.zeros(0, 0)
    u_new, v_new, g = _changed_parts(model, Su, ou, Sy, oy, Sv, suffix)
    return tuple(u_new), tuple(v_new), g


def _unchanged(S: sp.Matrix, o: sp.Matrix, i: int) -> bool:
    row = [S[i, j] for j in range(S.cols)]
    return all(sp.simplify(x - (1 if j == i else 0)) == 0 for j, x in enumerate(row)) and o[i] == 0


def _numeric_matrix(S: Any, n: int, name: str) -> np.ndarray:
    M = _scale_matrix(S, n, name)
    if M.free_symbols:
        raise ShapeError(f"{name} must be numeric to transform a Gaussian, got symbols {sorted(map(str, M.free_symbols))}")
    return np.array(M.evalf(), dtype=float)


def change_gaussian(dist: Gaussian, S: Any, o: Any = None) -> Gaussian:
    """The distribution of the new-unit variable x̄ = S⁻¹ (x − o) given x ~ ``dist``.

    This is the distribution change (35b)–(35c) that matches :func:`change_units`:
    ``dist`` is in the old units, x = S x̄ + o (18), and the result is in the new units,
    N(S⁻¹(m − o), S⁻¹ P S⁻ᵀ). Use ``o=None`` for noise (18c). The inverse change is
    ``change_gaussian(result, S⁻¹, −S⁻¹ o)``.

    Parameters
    ----------
    dist : Gaussian
        x in the old units.
    S : scalar, sequence or matrix
        Numeric scale (positive definite, invertible), same convention as :func:`change_units`.
    o : sequence, optional
        Numeric offset, default 0.

    Returns
    -------
    Gaussian

    Examples
    --------
    >>> change_gaussian(Gaussian([1000.0], [[4.0e4]]), S=1000.0)   # m -> km
    N([1], [[0.04]])
    """
    if not isinstance(dist, Gaussian):
        raise TypeError(f"dist must be a symmon.Gaussian, got {type(dist).__name__}")
    A = _numeric_matrix(S, dist.dim, "S")
    off = _offset_vector(o, dist.dim, "o")
    if off.free_symbols:
        raise ShapeError("o must be numeric to transform a Gaussian")
    ov = np.array(off.evalf(), dtype=float).ravel()
    Ainv = np.linalg.inv(A)
    cov = Ainv @ dist.cov @ Ainv.T
    return Gaussian(Ainv @ (dist.mean - ov), 0.5 * (cov + cov.T))


# --------------------------------------------------------------------------------------
# pint
# --------------------------------------------------------------------------------------
def _pint():
    try:
        import pint
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(_PINT_HINT) from exc
    return pint


@lru_cache(maxsize=1)
def _default_registry():
    return _pint().UnitRegistry()


def _parse_unit(ureg, unit: Any, what: str):
    pint = _pint()
    try:
        return ureg.Unit(unit)
    except pint.errors.UndefinedUnitError as exc:
        raise UnitError(f"unknown unit {unit!r} for {what}: {exc}") from None
    except (ValueError, TypeError, AttributeError, AssertionError) as exc:
        raise UnitError(f"invalid unit {unit!r} for {what}: {exc}") from None


def _conversion(ureg, old, new, what: str, offset: bool) -> tuple[float, float]:
    """(s, o) with old-unit value = s · new-unit value + o, from pint (18)."""
    pint = _pint()
    if old.dimensionality != new.dimensionality:
        raise UnitError(
            f"cannot convert {what} from {old} ({old.dimensionality}) to {new} "
            f"({new.dimensionality}): incompatible dimensions"
        )
    try:
        f0 = float(ureg.Quantity(0.0, new).to(old).magnitude)
        f1 = float(ureg.Quantity(1.0, new).to(old).magnitude)
        f2 = float(ureg.Quantity(2.0, new).to(old).magnitude)
    except pint.errors.PintError as exc:
        raise UnitError(f"pint cannot convert {what} from {old} to {new}: {exc}") from None
    if abs(f2 - 2 * f1 + f0) > _AFFINE_RTOL * max(abs(f0), abs(f1), abs(f2), 1e-300):
        raise UnitError(f"the conversion of {what} from {old} to {new} is not affine (e.g. a logarithmic unit)")
    if f0 == 0.0:
        return f1, 0.0
    # Offset units (degC, degF): the difference of two conversions loses digits near the
    # offset, so take the slope over a long interval.
    big = 1e6
    s = (float(ureg.Quantity(big, new).to(old).magnitude) - f0) / big
    if not offset:
        # Noise is a difference of two values: its scale has no offset (18c).
        return s, 0.0
    return s, f0


def _key_index(key: Any, names: Sequence[str], what: str) -> int:
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        if not 0 <= int(key) < len(names):
            raise UnitError(f"{what} index {key} out of range for {len(names)} {what}")
        return int(key)
    if isinstance(key, sp.Symbol):
        key = key.name
    if isinstance(key, str) and key in names:
        return list(names).index(key)
    raise UnitError(f"unknown {what} {key!r}; known: {list(names)}")


@dataclass(frozen=True)
class UnitModel:
    """A model whose variables carry physical units (pint), convertible with :meth:`to`.

    Build it with :func:`with_units`. ``S_u, o_u, S_y, o_y, S_v`` are the matrices of the
    change (18) that produced this model from its parent (old = parent, new = this), as
    numpy arrays; they are the identity and zero for a model made by :func:`with_units`.

    Attributes
    ----------
    model : Model
        The model in these units.
    units : dict
        ``{"inputs": {name: unit}, "outputs": {name: unit}, "noise": {name: unit}}`` as strings.
    output_names : tuple of str
    """

    model: Model
    output_names: tuple[str, ...]
    _units: tuple[tuple[Any, ...], tuple[Any, ...], tuple[Any, ...]]
    S_u: np.ndarray
    o_u: np.ndarray
    S_y: np.ndarray
    o_y: np.ndarray
    S_v: np.ndarray
    registry: Any = field(repr=False, compare=False, default=None)

    @property
    def units(self) -> dict[str, dict[str, str]]:
        """The unit of every variable, as pint strings."""
        u, y, v = self._units
        return {
            "inputs": {s.name: str(x) for s, x in zip(self.model.inputs, u)},
            "outputs": {n: str(x) for n, x in zip(self.output_names, y)},
            "noise": {s.name: str(x) for s, x in zip(self.model.noise, v)},
        }

    def to(
        self,
        inputs: Mapping[Any, Any] | None = None,
        outputs: Mapping[Any, Any] | None = None,
        noise: Mapping[Any, Any] | None = None,
    ) -> "UnitModel":
        """The same model in other units: the scales and offsets come from pint.

        Parameters
        ----------
        inputs, outputs, noise : dict, optional
            New units by variable name (outputs also by index); variables not named keep
            their units.

        Returns
        -------
        UnitModel
            With ``.model`` = :func:`change_units` of this model (same symbol names) and the
            matrices used: S = magnitude of one new unit in the old unit, o = the old-unit
            value of the new zero (degC → K has o = 273.15).

        Raises
        ------
        UnitError
            Unknown variable or unit, incompatible dimensions.

        Examples
        --------
        >>> import sympy as sp
        >>> x, y = sp.symbols("x y", real=True)
        >>> um = with_units(Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)]),
        ...                 inputs={"x": "m", "y": "m"}, outputs={"r": "m", "phi": "rad"},
        ...                 output_names=["r", "phi"])
        >>> km = um.to(inputs={"x": "km", "y": "km"}, outputs={"r": "km", "phi": "deg"})
        >>> km.S_u.diagonal().tolist(), km.units["outputs"]["phi"]
        ([1000.0, 1000.0], 'degree')
        """
        ureg = self.registry
        m = self.model
        u_old, y_old, v_old = self._units
        u_new, y_new, v_new = list(u_old), list(y_old), list(v_old)
        Su, ou = np.eye(m.n_u), np.zeros(m.n_u)
        Sy, oy = np.eye(m.n_y), np.zeros(m.n_y)
        Sv = np.eye(m.n_v)
        groups = (
            (inputs, [s.name for s in m.inputs], u_new, Su, ou, "input", True),
            (outputs, list(self.output_names), y_new, Sy, oy, "output", True),
            (noise, [s.name for s in m.noise], v_new, Sv, None, "noise", False),
        )
        for spec, names, new_units, S, o, what, has_offset in groups:
            if spec is None:
                continue
            if not isinstance(spec, Mapping):
                raise UnitError(f"{what} units must be given as a dict {{name: unit}}, got {type(spec).__name__}")
            for key, unit in spec.items():
                k = _key_index(key, names, what)
                label = f"{what} {names[k]!r}"
                new = _parse_unit(ureg, unit, label)
                s, off = _conversion(ureg, new_units[k], new, label, has_offset)
                S[k, k] = s
                if o is not None:
                    o[k] = off
                new_units[k] = new
        model = _change_units(
            m,
            sp.Matrix(Su.tolist()) if not np.array_equal(Su, np.eye(m.n_u)) else sp.eye(m.n_u),
            sp.Matrix(ou.tolist()) if ou.any() else sp.zeros(m.n_u, 1),
            sp.Matrix(Sy.tolist()) if not np.array_equal(Sy, np.eye(m.n_y)) else sp.eye(m.n_y),
            sp.Matrix(oy.tolist()) if oy.any() else sp.zeros(m.n_y, 1),
            sp.Matrix(Sv.tolist()) if m.n_v else sp.zeros(0, 0),
            suffix="",
        )
        return UnitModel(model, self.output_names, (tuple(u_new), tuple(y_new), tuple(v_new)),
                         Su, ou, Sy, oy, Sv, ureg)

    def convert_gaussian(self, dist: Gaussian, kind: str = "inputs") -> Gaussian:
        """Convert a distribution from the parent's units to this model's units.

        Parameters
        ----------
        dist : Gaussian
            The inputs u (``kind="inputs"``) or the noise v (``kind="noise"``) in the units
            of the model that :meth:`to` was called on.
        kind : {"inputs", "noise"}

        Returns
        -------
        Gaussian
            ū = S_u⁻¹(u − o_u) or v̄ = S_v⁻¹ v (:func:`change_gaussian`).
        """
        if kind == "inputs":
            return change_gaussian(dist, self.S_u, self.o_u)
        if kind == "noise":
            if self.model.n_v == 0:
                raise ModelError("the model has no noise symbols")
            return change_gaussian(dist, self.S_v)
        raise ValueError(f"kind must be 'inputs' or 'noise', got {kind!r}")

    def __repr__(self) -> str:
        u = self.units
        parts = [f"{k}={v}" for k, v in u.items() if v]
        return f"UnitModel({self.model.name!r}, " + ", ".join(parts) + ")"


def with_units(
    model: Model,
    inputs: Mapping[Any, Any],
    outputs: Mapping[Any, Any] | Sequence[Any],
    noise: Mapping[Any, Any] | None = None,
    *,
    output_names: Sequence[str] | None = None,
    registry: Any = None,
) -> UnitModel:
    """Declare the physical unit of every variable of ``model`` (validated by pint).

    Parameters
    ----------
    model : Model
    inputs : dict
        ``{input name: unit}`` for every input (a pint unit or a string such as ``"km/h"``).
    outputs : dict or sequence
        ``{output index or name: unit}`` for every output, or the units in output order.
    noise : dict, optional
        ``{noise name: unit}`` for every noise symbol (required when the model has noise).
    output_names : sequence of str, optional
        Names of the outputs (default ``y0, y1, ...``), usable as keys.
    registry : pint.UnitRegistry, optional
        Default: one shared registry.

    Returns
    -------
    UnitModel

    Raises
    ------
    UnitError
        An unknown unit or variable, or a variable without a unit.
    ImportError
        pint is not installed (``pip install 'symmon[units]'``).
    """
    if not isinstance(model, Model):
        raise TypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    ureg = registry if registry is not None else _default_registry()
    names = tuple(output_names) if output_names is not None else tuple(f"y{i}" for i in range(model.n_y))
    if len(names) != model.n_y or len(set(names)) != len(names):
        raise UnitError(f"output_names must be {model.n_y} distinct names, got {list(names)}")
    if not isinstance(outputs, Mapping):
        outputs = dict(enumerate(outputs))

    def collect(spec, keys: Sequence[str], what: str) -> tuple:
        spec = spec or {}
        if not isinstance(spec, Mapping):
            raise UnitError(f"{what} units must be a dict {{name: unit}}, got {type(spec).__name__}")
        found: dict[int, Any] = {}
        for key, unit in spec.items():
            k = _key_index(key, keys, what)
            if k in found:
                raise UnitError(f"{what} {keys[k]!r} has two units")
            found[k] = _parse_unit(ureg, unit, f"{what} {keys[k]!r}")
        missing = [keys[k] for k in range(len(keys)) if k not in found]
        if missing:
            raise UnitError(f"no unit given for {what} {missing} (use 'dimensionless' for pure numbers)")
        return tuple(found[k] for k in range(len(keys)))

    units = (
        collect(inputs, [s.name for s in model.inputs], "input"),
        collect(outputs, list(names), "output"),
        collect(noise, [s.name for s in model.noise], "noise"),
    )
    return UnitModel(model, names, units, np.eye(model.n_u), np.zeros(model.n_u),
                     np.eye(model.n_y), np.zeros(model.n_y), np.eye(model.n_v), ureg)


# --------------------------------------------------------------------------------------
# Symbolic proofs of unit invariance
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InvarianceProof:
    """The outcome of a symbolic unit-invariance check (21), (34).

    Attributes
    ----------
    holds : bool
        True when M²(g, u) − M²(ḡ, ū) simplifies to 0 identically in the scales, offsets
        and moments; False when it is provably nonzero (a rational point where it is
        nonzero is in ``counterexample``).
    difference : sympy.Expr
        The simplified M²(g, u) − M²(ḡ, ū).
    lhs, rhs : sympy.Expr
        M² in the old units and in the new units.
    weight : str
    transform : str
        ``"tt2"`` for :func:`prove_invariance`, ``"exact"`` for :func:`prove_matrix_invariance`.
    symbols : dict
        The symbols of the statement: scales, offsets, moments.
    counterexample : dict or None
        For a failed proof, symbol values (exact rationals) at which the difference is nonzero,
        with the value under the key ``"difference"``.
    seconds : float
        Wall time of the proof.
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
            if self.counterexample is not None:
                tail += f"; e.g. {float(self.counterexample['difference']):.6g} at a rational point"
        return f"{self.statement} with weight {self.weight!r} ({self.transform}): {tail} [{self.seconds:.2f} s]"

    def __repr__(self) -> str:
        return f"InvarianceProof(weight={self.weight!r}, transform={self.transform!r}, holds={self.holds})"


def _exact(x: Any, name: str) -> sp.Expr:
    """Numbers to exact sympy numbers (0.17 → 17/100) so that the proof stays exact."""
    if isinstance(x, sp.Basic):
        return x
    if isinstance(x, (bool, np.bool_)):
        raise ShapeError(f"{name}: booleans are not numbers")
    if isinstance(x, (int, np.integer)):
        return sp.Integer(int(x))
    if isinstance(x, (float, np.floating)):
        if not np.isfinite(x):
            raise ShapeError(f"{name} contains NaN or inf")
        return sp.Rational(repr(float(x)))
    return _sympify_entry(x, name)


def _exact_vector(x: Any, n: int, name: str) -> sp.Matrix:
    items = list(x) if isinstance(x, sp.MatrixBase) else list(np.asarray(x, dtype=object).reshape(-1))
    if len(items) != n:
        raise ShapeError(f"{name} must have length {n}, got {len(items)}")
    return sp.Matrix([_exact(e, name) for e in items])


def _exact_cov(P: Any, n: int, name: str) -> sp.Matrix:
    if isinstance(P, sp.MatrixBase):
        M = sp.Matrix(P).applyfunc(lambda e: _exact(e, name))
    else:
        arr = np.asarray(P, dtype=object)
        if arr.ndim == 0 and n == 1:
            arr = arr.reshape(1, 1)
        if arr.ndim != 2:
            raise ShapeError(f"{name} must be a square matrix, got shape {arr.shape}")
        M = sp.Matrix(arr.shape[0], arr.shape[1], [_exact(e, name) for e in arr.ravel()])
    if M.shape != (n, n):
        raise ShapeError(f"{name} must be {n}x{n}, got {M.rows}x{M.cols}")
    if any(sp.simplify(M[i, j] - M[j, i]) != 0 for i in range(n) for j in range(i)):
        raise ShapeError(f"{name} must be symmetric")
    if not M.free_symbols:
        A = np.array(M.evalf(), dtype=float)
        if np.linalg.eigvalsh(A)[0] <= 0:
            raise SingularMatrixError(f"{name} must be positive definite (its inverse enters D)")
    return M


def _sym_matrix(n: int, name: str) -> sp.Matrix:
    return sp.Matrix(n, n, lambda i, j: sp.Symbol(f"{name}_{min(i, j) + 1}{max(i, j) + 1}", real=True))


def _cancel_matrix(M: sp.Matrix) -> sp.Matrix:
    return M.applyfunc(sp.cancel)


def _half_trace_products(H: list[sp.Matrix], P: sp.Matrix) -> sp.Matrix:
    """½ [tr(H_i P H_j P)]_ij: the second-order covariance term of TT2."""
    HP = [h * P for h in H]
    n = len(H)
    return sp.Matrix(n, n, lambda i, j: sp.Rational(1, 2) * (HP[i] * HP[j]).trace())


def _tt2_moments(model: Model | _Relation, mu: sp.Matrix, P: sp.Matrix, R: sp.Matrix) -> tuple[sp.Matrix, sp.Matrix]:
    """Σ_gg and the residual covariance D of the MoN under the TT2 closed form.

    w = [u; v] ~ N([μ; 0], blkdiag(P, R)). TT2 gives Σ_gg ≈ J P_w Jᵀ + ½[tr(H_i P_w H_j P_w)]
    and Σ_gu ≈ J_u P. The residual is D = Σ_gg − Cov(E[g | v]) − Σ_gu Σ_uu⁻¹ Σ_ug
    (REFERENCE.md, general noise); Cov(E[g | v]) is TT2 of g(μ, ·) in v, which vanishes for
    a noise-free model, so that D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug and, for additive noise,
    D = ½[tr(H_i P H_j P)] (29).
    """
    u, v = model.inputs, model.noise
    nu = len(u)
    w = list(u) + list(v)
    point = dict(zip(u, mu))
    point.update({s: sp.Integer(0) for s in v})
    g = sp.Matrix(model.outputs)
    J = g.jacobian(w).xreplace(point)
    H = [sp.hessian(gi, w).xreplace(point) for gi in g]
    Pw = sp.diag(P, R) if v else P
    Sgg = J * Pw * J.T + _half_trace_products(H, Pw)
    Sgu = J[:, :nu] * P
    D = Sgg - Sgu * _cancel_matrix(P.LUsolve(Sgu.T))
    if v:
        Jv = J[:, nu:]
        Hv = [h[nu:, nu:] for h in H]
        D = D - (Jv * R * Jv.T + _half_trace_products(Hv, R))
    return _cancel_matrix(Sgg), _cancel_matrix(D)


@lru_cache(maxsize=32)
def _stage1(model, g_bar, mu, P, R, mu_bar, P_bar, R_bar, Sy):
    """TT2 moments in both unit systems and whether Σ_ḡḡ, D̄ = S_y⁻¹ (Σ_gg, D) S_y⁻¹ (cached:
    the weights share it)."""
    Sgg, D = _tt2_moments(model, sp.Matrix(mu), sp.Matrix(P), sp.Matrix(R))
    Sgg_b, D_b = _tt2_moments(g_bar, sp.Matrix(mu_bar), sp.Matrix(P_bar), sp.Matrix(R_bar))
    Sy_inv = _inverse(sp.Matrix(Sy))
    ny = Sgg.rows
    covariant = all(
        sp.cancel(X_b[i, j] - (Sy_inv * X * Sy_inv)[i, j]) == 0
        for X, X_b in ((Sgg, Sgg_b), (D, D_b)) for i in range(ny) for j in range(ny)
    )
    return Sgg, D, Sgg_b, D_b, covariant


def _weight_label(weight: Any) -> str:
    if isinstance(weight, str):
        if weight not in WEIGHTS:
            raise SymmonError(f"unknown weight {weight!r}: use one of {WEIGHTS}, a sympy Matrix W̄ or a callable")
        return weight
    if isinstance(weight, sp.MatrixBase):
        if weight.rows != weight.cols or (weight - weight.T).applyfunc(sp.simplify) != sp.zeros(*weight.shape):
            raise SymmonError(f"weight W̄ must be a symmetric matrix, got {weight.tolist()}")
        if not weight.free_symbols and not weight.is_positive_definite:
            raise SymmonError("weight W̄ must be positive definite (41)")
        return "matrix W̄ (38)"
    if callable(weight):
        return "callable W̄ (38), (41)"
    raise SymmonError(f"weight must be one of {WEIGHTS}, a sympy Matrix W̄ or a callable, got {type(weight).__name__}")


def _general_weight(weight: Any, Sgg: sp.Matrix, sigma: Sequence[sp.Expr]) -> sp.Matrix:
    """W = S_b⁻¹ W̄ S_b⁻¹ (38) with the base-unit scale S_b = diag(σ), σ_i = √Σ_gg,ii."""
    n = Sgg.rows
    corr = sp.Matrix(n, n, lambda i, j: sp.Integer(1) if i == j else Sgg[i, j] / (sigma[i] * sigma[j]))
    Wb = weight(corr) if callable(weight) and not isinstance(weight, sp.MatrixBase) else weight
    if not isinstance(Wb, sp.MatrixBase):
        raise SymmonError(f"the weight callable must return a sympy Matrix, got {type(Wb).__name__}")
    if Wb.shape != (n, n):
        raise ShapeError(f"weight W̄ must be {n}x{n}, got {Wb.rows}x{Wb.cols}")
    Sbinv = sp.diag(*[1 / s for s in sigma])
    return Sbinv * Wb * Sbinv


def _m2(weight: Any, Sgg: sp.Matrix, D: sp.Matrix, sigma: Sequence[sp.Expr] | None = None) -> sp.Expr:
    """M² = tr(W D) for the weight rule evaluated on Σ_gg, (29) with (6), (8), (42), (43), (38)."""
    n = Sgg.rows
    if weight == "full":
        return sp.cancel(Sgg.LUsolve(D).trace() / n)  # (43): W = Σ_gg⁻¹ / n_y
    if weight == "diag":
        return sp.cancel(sum((D[i, i] / Sgg[i, i] for i in range(n)), sp.Integer(0)) / n)  # (42)
    if weight == "liu-li":
        return sp.cancel(D.trace() / Sgg.trace())  # (8) squared: W = I / tr Σ_gg
    if weight == "liu-li-raw":
        return sp.cancel(D.trace())  # (6): W = I
    W = _general_weight(weight, Sgg, sigma)
    return sp.cancel((W * D).trace())


def _decide(diff: sp.Expr, seed: int = 0) -> tuple[sp.Expr, bool, dict | None]:
    """Simplify a difference; if it is not 0, find an exact rational point where it is not.

    A nonzero value at one admissible point (positive scales, diagonally dominant
    covariances) is a rigorous disproof, whatever the simplifier managed.
    """
    d = sp.cancel(sp.together(diff)) if sp.count_ops(diff) < _CANCEL_MAX_OPS else diff
    if d == 0:
        return sp.Integer(0), True, None
    rng = np.random.default_rng(seed)
    syms = sorted(d.free_symbols, key=str)
    for _ in range(20):
        point = {}
        for s in syms:
            val = sp.Rational(int(rng.integers(1, 20)), int(rng.integers(1, 7)))
            if not s.is_positive and rng.random() < 0.5:
                val = -val
            # Diagonal entries of covariance symbols (P_11, R_22, ...) dominate their row.
            idx = s.name.rsplit("_", 1)[-1]
            if len(idx) == 2 and idx.isdigit() and idx[0] == idx[1]:
                val = abs(val) + 60
            point[s] = val
        val = d.xreplace(point)
        num = sp.N(val, 50)
        if num.is_finite and abs(num) > sp.Float("1e-30"):
            point["difference"] = val if val.is_Rational else num
            return d, False, point
    raise SymmonError(
        "could not decide the invariance: the difference did not simplify to 0 and no point "
        f"where it is nonzero was found ({sp.count_ops(d)} operations)"
    )


def _as_transform_name(transform: Any) -> str:
    name = transform if isinstance(transform, str) else getattr(transform, "name", None)
    if name != "tt2":
        raise SymmonError(
            f"prove_invariance works on the TT2 closed form (transform='tt2'), got {transform!r}; "
            "prove_matrix_invariance states the exact (transform-free) result"
        )
    return name


def prove_invariance(
    model: Model,
    weight: Any = "full",
    transform: Any = "tt2",
    mean: Any = None,
    cov: Any = None,
    noise_cov: Any = None,
) -> InvarianceProof:
    """Prove (or disprove) the unit invariance (21), (34) of the MoN of ``model`` under TT2.

    The MoN is built symbolically twice: for g with u ~ N(μ, P) (and v ~ N(0, R)), and for
    ḡ = :func:`change_units` of g with symbolic positive diagonal S_u, S_y, S_v and
    symbolic offsets o_u, o_y, with ū ~ N(S_u⁻¹(μ − o_u), S_u⁻¹ P S_u⁻¹) and
    v̄ ~ N(0, S_v⁻¹ R S_v⁻¹) (35b), (35c). Each uses the TT2 closed form (derivatives
    from sympy): Σ_gg ≈ J P Jᵀ + ½[tr(H_i P H_j P)], Σ_gu ≈ J P,
    D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug (minus Cov(E[g | v]) when there is noise), and
    M² = tr(W D) (29) with W from its own Σ_gg. The difference M²(g, u) − M²(ḡ, ū) is
    simplified; it is an identity of rational functions wherever the inverses exist.

    Parameters
    ----------
    model : Model
    weight : {"full", "diag", "liu-li", "liu-li-raw"}, sympy Matrix or callable
        ``"full"``: W = Σ_gg⁻¹/n_y (43); ``"diag"``: W = diag(diag Σ_gg)⁻¹/n_y (42);
        ``"liu-li"``: W = I/tr Σ_gg (the square of (8)); ``"liu-li-raw"``: W = I (6).
        A matrix W̄ (in base units, where every output has unit variance) or a callable
        ``corr -> W̄`` of the base-unit covariance Σ_ḡḡ (a correlation matrix) gives
        W = S_b⁻¹ W̄ S_b⁻¹ with S_b = diag(√diag Σ_gg), (38) and (41).
    transform : "tt2" or TT2()
    mean, cov : optional
        Numeric or symbolic mean and covariance of u (a Gaussian may be passed as ``mean``).
        Default: symbols μ and a symmetric P. Numbers are made exact (0.17 → 17/100).
    noise_cov : optional
        Covariance R of v (default: symbols), for a model with noise.

    Returns
    -------
    InvarianceProof

    Examples
    --------
    >>> import sympy as sp
    >>> x, y = sp.symbols("x y", real=True)
    >>> polar = Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)])
    >>> prove_invariance(polar, "full").holds, prove_invariance(polar, "liu-li-raw").holds
    (True, False)
    """
    t0 = time.perf_counter()
    if not isinstance(model, Model):
        raise TypeError(f"model must be a symmon.Model, got {type(model).__name__}")
    label = _weight_label(weight)
    tname = _as_transform_name(transform)
    nu, ny, nv = model.n_u, model.n_y, model.n_v
    if isinstance(mean, Gaussian):
        if cov is None:
            cov = mean.cov
        mean = mean.mean
    mu = (sp.Matrix([sp.Symbol(f"mu_{s.name}", real=True) for s in model.inputs])
          if mean is None else _exact_vector(mean, nu, "mean"))
    P = _sym_matrix(nu, "P") if cov is None else _exact_cov(cov, nu, "cov")
    if nv:
        R = _sym_matrix(nv, "R") if noise_cov is None else _exact_cov(noise_cov, nv, "noise_cov")
    else:
        if noise_cov is not None:
            raise ModelError("noise_cov was given but the model declares no noise symbols")
        R = sp.zeros(0, 0)
    s_u = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.inputs]
    o_u = [sp.Symbol(f"o_{s.name}", real=True) for s in model.inputs]
    s_y = [sp.Symbol(f"s_y{i + 1}", positive=True) for i in range(ny)]
    o_y = [sp.Symbol(f"o_y{i + 1}", real=True) for i in range(ny)]
    s_v = [sp.Symbol(f"s_{s.name}", positive=True) for s in model.noise]
    Su, Sy, Sv = sp.diag(*s_u), sp.diag(*s_y), sp.diag(*s_v) if nv else sp.zeros(0, 0)
    ou, oy = sp.Matrix(o_u), sp.Matrix(o_y)

    ub, vb, gb = _changed_parts(model, Su, ou, Sy, oy, Sv, "_bar")
    g_bar = _Relation(tuple(ub), tuple(vb), tuple(gb), model.name)
    Su_inv = _inverse(Su)
    mu_bar = Su_inv * (mu - ou)
    P_bar = Su_inv * P * Su_inv
    R_bar = (_inverse(Sv) * R * _inverse(Sv)) if nv else R

    # Stage 1: the TT2 moments of ḡ are those of g mapped by the unit change,
    # Σ_ḡḡ = S_y⁻¹ Σ_gg S_y⁻¹ and D̄ = S_y⁻¹ D S_y⁻¹, checked entrywise on the actual
    # expressions (derivatives of ḡ from sympy, evaluated at the mapped mean).
    Sgg, D, Sgg_b, D_b, covariant = _stage1(
        model, g_bar, sp.ImmutableMatrix(mu), sp.ImmutableMatrix(P), sp.ImmutableMatrix(R),
        sp.ImmutableMatrix(mu_bar), sp.ImmutableMatrix(P_bar), sp.ImmutableMatrix(R_bar),
        sp.ImmutableMatrix(Sy),
    )
    Sy_inv = _inverse(Sy)
    # Stage 2: M² of the weight rule, for generic symmetric Σ_gg and D, is (or is not)
    # invariant under that map. Both stages are exact, so together they decide (21).
    G = _sym_matrix(ny, "Sigma")
    E = _sym_matrix(ny, "D")
    if covariant:
        G_b, E_b = Sy_inv * G * Sy_inv, Sy_inv * E * Sy_inv
    else:  # cannot happen for an affine change; decide on the actual expressions instead
        G, E, G_b, E_b = Sgg, D, Sgg_b, D_b
    sigma = sigma_b = None
    if label not in WEIGHTS:
        # Base units have unit variances: S_b = diag(σ), σ_i = √Σ_gg,ii > 0. In the new units
        # σ̄_i = √Σ_ḡḡ,ii = σ_i √(Σ_ḡḡ,ii / Σ_gg,ii), exact because both roots are positive.
        sigma = [sp.Symbol(f"sigma_y{i + 1}", positive=True) for i in range(ny)]
        sigma_b = [sigma[i] * sp.sqrt(sp.cancel(G_b[i, i] / G[i, i])) for i in range(ny)]
    lhs_g = _m2(weight, G, E, sigma)
    rhs_g = _m2(weight, G_b, E_b, sigma_b)
    actual = {G[i, j]: Sgg[i, j] for i in range(ny) for j in range(ny)}
    actual.update({E[i, j]: D[i, j] for i in range(ny) for j in range(ny)})
    d = sp.cancel(sp.together(lhs_g - rhs_g))
    if d == 0:
        diff, holds, cex = sp.Integer(0), True, None
    else:
        diff, holds, cex = _decide(d.xreplace(actual) if covariant else d)
    lhs, rhs = (lhs_g.xreplace(actual), rhs_g.xreplace(actual)) if covariant else (lhs_g, rhs_g)
    symbols = {"S_u": Su, "o_u": ou, "S_y": Sy, "o_y": oy, "S_v": Sv, "mean": mu, "cov": P, "noise_cov": R}
    if sigma is not None:
        symbols["sigma"] = sp.Matrix(sigma)
    return InvarianceProof(
        holds, diff, lhs, rhs, label, tname,
        f"unit invariance of the MoN of {model.name!r} under u = S_u ū + o_u, y = S_y ȳ + o_y, v = S_v v̄ (18)",
        symbols, cex, time.perf_counter() - t0,
    )


def _best_rotation(tr: sp.Trace) -> sp.Expr:
    """tr(A₁⋯A_k) = tr(A_j⋯A_k A₁⋯A_{j−1}): the rotation after which most factors cancel."""
    arg = tr.arg
    if not isinstance(arg, sp.MatMul):
        return tr
    coeff, mats = arg.as_coeff_matrices()
    best = arg
    for k in range(1, len(mats)):
        cand = sp.MatMul(*(mats[k:] + mats[:k])).doit()
        n_c = len(cand.args) if isinstance(cand, sp.MatMul) else 1
        n_b = len(best.as_coeff_matrices()[1]) if isinstance(best, sp.MatMul) else 1
        if n_c < n_b:
            best = cand
    return coeff * sp.Trace(best)


def _reduce(expr: sp.Expr) -> sp.Expr:
    """Matrix-algebra simplification: (ABC)⁻¹ = C⁻¹B⁻¹A⁻¹, X X⁻¹ = I, linearity and cyclicity of tr."""
    e = sp.expand(expr.doit())
    e = e.replace(lambda x: isinstance(x, sp.Trace), _best_rotation)
    return sp.expand(e.doit())


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
            raise ShapeError(f"{name} must be an integer from 1 to 4, got {n!r}")
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
