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
- :func:`prove_invariance`, :func:`prove_matrix_invariance`: the symbolic proofs of unit
  invariance, defined in :mod:`symmon.invariance` and re-exported here.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV, eqs. (18)–(21), (34)–(43).
"""

from __future__ import annotations

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


# The proofs live in symmon.invariance (imported last: it uses the helpers above).
from .invariance import InvarianceProof as InvarianceProof  # noqa: E402
from .invariance import prove_invariance as prove_invariance  # noqa: E402
from .invariance import prove_matrix_invariance as prove_matrix_invariance  # noqa: E402
