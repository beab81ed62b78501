"""Trace a NumPy-style Python function into sympy expressions.

A FilterPy or Stone Soup user has the measurement and motion models as Python functions,
``hx(x)`` or ``fx(x, dt)``, written with ``np.sqrt``, ``np.arctan2``, arithmetic, indexing
and ``np.array([...])``.  :func:`trace` calls such a function once on symbolic values and
returns the sympy expressions of its outputs, so that :meth:`symmon.Model.from_function`
builds the same :class:`~symmon.Model` as a sympy declaration.

The function receives NumPy object arrays whose entries are :class:`Traced` values.  A
Traced value supports the arithmetic operators and the NumPy ufuncs listed in
:data:`SUPPORTED`, both on scalars (``np.sqrt(x[0])``) and on arrays (``np.sin(x)``);
NumPy's own code built on them (``F @ x``, ``np.dot``, ``x.sum()``, slicing) works too.
Anything that needs a number (``float(x[0])``, ``math.sqrt``, ``if x[0] > 0``) raises an
:class:`~symmon.errors.UnsupportedFunctionError` naming the operation: the traced value
has no number yet.
"""

from __future__ import annotations

import numbers
from typing import Any, Callable, Sequence

import numpy as np
import sympy as sp

from ..errors import ModelError, UnsupportedFunctionError
from .symbols import as_symbols

__all__ = ["Traced", "trace", "SUPPORTED"]


def _hypot(a, b):
    return sp.sqrt(a**2 + b**2)


#: NumPy ufuncs a traced function may call, and their sympy counterparts.
_UFUNCS: dict[np.ufunc, Callable[..., sp.Expr]] = {
    np.add: lambda a, b: a + b,
    np.subtract: lambda a, b: a - b,
    np.multiply: lambda a, b: a * b,
    np.true_divide: lambda a, b: a / b,
    np.power: lambda a, b: a**b,
    np.float_power: lambda a, b: a**b,
    np.negative: lambda a: -a,
    np.positive: lambda a: a,
    np.reciprocal: lambda a: 1 / a,
    np.square: lambda a: a**2,
    np.sqrt: sp.sqrt,
    np.cbrt: lambda a: sp.real_root(a, 3),
    np.exp: sp.exp,
    np.expm1: lambda a: sp.exp(a) - 1,
    np.log: sp.log,
    np.log1p: lambda a: sp.log(1 + a),
    np.log2: lambda a: sp.log(a, 2),
    np.log10: lambda a: sp.log(a, 10),
    np.sin: sp.sin, np.cos: sp.cos, np.tan: sp.tan,
    np.arcsin: sp.asin, np.arccos: sp.acos, np.arctan: sp.atan,
    np.sinh: sp.sinh, np.cosh: sp.cosh, np.tanh: sp.tanh,
    np.arcsinh: sp.asinh, np.arccosh: sp.acosh, np.arctanh: sp.atanh,
    np.arctan2: sp.atan2,
    np.hypot: _hypot,
    np.absolute: sp.Abs,
    np.sign: sp.sign,
    np.floor: sp.floor,
    np.ceil: sp.ceiling,
    np.maximum: sp.Max, np.fmax: sp.Max,
    np.minimum: sp.Min, np.fmin: sp.Min,
    np.deg2rad: lambda a: a * sp.pi / 180,
    np.rad2deg: lambda a: a * 180 / sp.pi,
}
_UFUNCS[np.radians] = _UFUNCS[np.deg2rad]
_UFUNCS[np.degrees] = _UFUNCS[np.rad2deg]

#: Names of the supported NumPy functions, for messages and documentation.
SUPPORTED: tuple[str, ...] = tuple(sorted({f"np.{u.__name__}" for u in _UFUNCS}))


def _unsupported(what: str) -> UnsupportedFunctionError:
    return UnsupportedFunctionError(
        f"{what} is not supported in a traced model function: the inputs are symbols, not "
        f"numbers. Use arithmetic, indexing, np.array([...]) and the NumPy functions "
        f"{', '.join(SUPPORTED)}"
    )


def _to_sympy(a: Any) -> sp.Expr:
    """A Traced value or a real number as a sympy expression (floats kept bit for bit)."""
    if isinstance(a, Traced):
        return a.expr
    if isinstance(a, (bool, np.bool_)):
        raise _unsupported("a boolean operand")
    if isinstance(a, numbers.Integral):
        return sp.Integer(int(a))
    if isinstance(a, numbers.Real):
        x = float(a)
        if not np.isfinite(x):
            raise ModelError(f"the traced function uses the non-finite constant {x}")
        # The shortest decimal that rounds back to x: what the user wrote (dt = 0.1 → 1/10),
        # and float() of it is x again, bit for bit.
        return sp.Rational(repr(x))
    raise _unsupported(f"an operand of type {type(a).__name__}")


def _apply(ufunc: np.ufunc, args: Sequence[Any]) -> Any:
    """Apply ``ufunc`` to scalars or (object) arrays of Traced values and numbers."""
    fn = _UFUNCS.get(ufunc)
    if fn is None:
        raise _unsupported(f"np.{ufunc.__name__}")
    if any(isinstance(a, np.ndarray) and a.ndim > 0 for a in args):
        elementwise = np.frompyfunc(lambda *xs: _apply(ufunc, xs), len(args), 1)
        return elementwise(*[np.asarray(a, dtype=object) if isinstance(a, np.ndarray) else a for a in args])
    return Traced(fn(*[_to_sympy(a) for a in args]))


class Traced:
    """A symbolic scalar that behaves like a float under NumPy-style code.

    Attributes
    ----------
    expr : sympy.Expr
        The expression built so far.
    """

    __slots__ = ("expr",)
    # NumPy defers binary operators with a Traced operand to Traced's methods.
    __array_priority__ = 1000

    def __init__(self, expr: sp.Expr) -> None:
        self.expr = expr

    def __repr__(self) -> str:
        return f"Traced({self.expr})"

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> Any:
        if method != "__call__" or kwargs:
            raise _unsupported(f"np.{ufunc.__name__}.{method}" if method != "__call__"
                               else f"np.{ufunc.__name__} with {sorted(kwargs)}")
        return _apply(ufunc, inputs)

    # Arithmetic; each returns NotImplemented for operands it does not know, so that
    # NumPy arrays take over (elementwise through __array_ufunc__).
    def _binary(self, other: Any, ufunc: np.ufunc, reflected: bool = False) -> Any:
        if isinstance(other, np.ndarray) and other.ndim > 0:
            return NotImplemented
        args = (other, self) if reflected else (self, other)
        return _apply(ufunc, args)

    def __add__(self, o): return self._binary(o, np.add)
    def __radd__(self, o): return self._binary(o, np.add, True)
    def __sub__(self, o): return self._binary(o, np.subtract)
    def __rsub__(self, o): return self._binary(o, np.subtract, True)
    def __mul__(self, o): return self._binary(o, np.multiply)
    def __rmul__(self, o): return self._binary(o, np.multiply, True)
    def __truediv__(self, o): return self._binary(o, np.true_divide)
    def __rtruediv__(self, o): return self._binary(o, np.true_divide, True)
    def __pow__(self, o): return self._binary(o, np.power)
    def __rpow__(self, o): return self._binary(o, np.power, True)
    def __neg__(self): return Traced(-self.expr)
    def __pos__(self): return self
    def __abs__(self): return Traced(sp.Abs(self.expr))

    def _refuse(self, *_: Any) -> Any:
        raise _unsupported("a comparison or branch on an input (if/while, <, ==, bool())")

    __lt__ = __le__ = __gt__ = __ge__ = __eq__ = __ne__ = _refuse
    __bool__ = _refuse
    __hash__ = None  # type: ignore[assignment]

    def __float__(self) -> float:
        raise _unsupported("converting an input to a number (float(), math.*, int())")

    __int__ = __index__ = __complex__ = __float__  # type: ignore[assignment]

    def __floordiv__(self, o): raise _unsupported("floor division //")
    __rfloordiv__ = __mod__ = __rmod__ = __floordiv__


# NumPy calls a method of the same name on each element of an object array
# (np.sqrt(x) with x an object array calls x[i].sqrt()).
for _uf in _UFUNCS:
    if _uf.nin == 1 and not hasattr(Traced, _uf.__name__):
        setattr(Traced, _uf.__name__, (lambda uf: lambda self: _apply(uf, (self,)))(_uf))
    elif _uf.nin == 2 and not hasattr(Traced, _uf.__name__):
        setattr(Traced, _uf.__name__, (lambda uf: lambda self, other: _apply(uf, (self, other)))(_uf))


def trace(fn: Callable[..., Any], inputs: Sequence[Any], noise: Sequence[Any] | None = None,
          args: Sequence[Any] = ()) -> tuple[tuple[sp.Symbol, ...], tuple[sp.Symbol, ...], tuple[sp.Expr, ...]]:
    """Call ``fn`` on symbolic inputs and return the sympy expressions of its outputs.

    Parameters
    ----------
    fn : callable
        ``fn(x, *args)``, or ``fn(x, v, *args)`` when ``noise`` is given, with ``x`` (and
        ``v``) 1-D arrays; it returns a scalar or a 1-D array-like of outputs.
    inputs, noise : sequence of str or sympy.Symbol
        Names of the components of ``x`` and ``v``.
    args : sequence
        Further (numeric) arguments passed to ``fn``, such as FilterPy's ``dt``.

    Returns
    -------
    inputs, noise, outputs : tuples of sympy objects

    Raises
    ------
    UnsupportedFunctionError
        Naming the operation that cannot be traced.

    Examples
    --------
    >>> import numpy as np
    >>> def hx(x):
    ...     return np.array([np.sqrt(x[0]**2 + x[1]**2), np.arctan2(x[1], x[0])])
    >>> trace(hx, ["px", "py"])[2]
    (sqrt(px**2 + py**2), atan2(py, px))
    """
    if not callable(fn):
        raise ModelError(f"fn must be callable, got {type(fn).__name__}")
    u = as_symbols(inputs, "inputs")
    v = as_symbols(noise, "noise")
    if not u:
        raise ModelError("a model needs at least one input")
    x = np.array([Traced(s) for s in u], dtype=object)
    call = [x] + ([np.array([Traced(s) for s in v], dtype=object)] if v else []) + list(args)
    out = fn(*call)
    try:
        flat = np.asarray(out, dtype=object).ravel()
    except (TypeError, ValueError) as exc:
        raise ModelError(f"the traced function returned {type(out).__name__}, not an array of outputs") from exc
    if flat.size == 0:
        raise ModelError("the traced function returned no outputs")
    return u, v, tuple(_to_sympy(e) for e in flat)
