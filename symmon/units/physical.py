"""Physical units with pint: :class:`UnitModel` and :func:`with_units`.

The variables of a model are given pint units; :meth:`UnitModel.to` converts them, taking
the scale matrices and offsets of the change of units (18) of Straka & Havlík (2024) from
pint, never from a table, and applies :func:`symmon.units.change_units` to the model.

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Section III, eq. (18).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np
import sympy as sp

from ..errors import ArgumentError, ArgumentTypeError, ModelError
from ..core.gaussian import Gaussian
from ..core.model import Model
from ..core.rescale import change_gaussian
from ..errors import UnitError

__all__ = ["UnitModel", "with_units"]

#: A conversion is accepted as affine when f(2) − 2 f(1) + f(0) is this small relative to f.
_AFFINE_RTOL = 1e-9

_PINT_HINT = "pint is needed for physical units: pip install 'symmon[units]' (or pip install pint)"


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
        model = m.change_units(
            sp.Matrix(Su.tolist()) if not np.array_equal(Su, np.eye(m.n_u)) else sp.eye(m.n_u),
            sp.Matrix(ou.tolist()) if ou.any() else sp.zeros(m.n_u, 1),
            sp.Matrix(Sy.tolist()) if not np.array_equal(Sy, np.eye(m.n_y)) else sp.eye(m.n_y),
            sp.Matrix(oy.tolist()) if oy.any() else sp.zeros(m.n_y, 1),
            sp.Matrix(Sv.tolist()) if m.n_v else None,
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
        raise ArgumentError(f"kind must be 'inputs' or 'noise', got {kind!r}")

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
        raise ArgumentTypeError(f"model must be a symmon.Model, got {type(model).__name__}")
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
