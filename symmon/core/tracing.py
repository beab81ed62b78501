"""Trace a NumPy-style Python function into sympy expressions.

A FilterPy or Stone Soup user has the measurement and motion models as Python functions,
``hx(x)`` or ``fx(x, dt)``, written with ``np.sqrt``, ``np.arctan2``, arithmetic, indexing
and ``np.array([...])``.  :func:`trace` calls such a function once on symbolic values and
returns the sympy expressions of its outputs, so that :meth:`symmon.Model.from_function`
builds the same :class:`~symmon.Model` as a sympy declaration.

The function receives NumPy object arrays of :class:`Traced` values.  What it may do with
them is listed in :data:`SUPPORTED` (each entry is tested against NumPy):

- arithmetic ``+ - * / **``, unary ``-``, ``abs()``, ``@``, indexing and slicing, and
  the NumPy ufuncs of the list, on scalars (``np.sqrt(x[0])``) and on arrays
  (``np.sin(x)``);
- the NumPy functions of the list (``np.array``, ``np.dot``, ``np.sum``,
  ``np.linalg.norm``, ...) and SciPy's ``scipy.special.erf`` and ``erfc``;
- branches on values: a comparison (``x[0] > 0``, ``x > 0``) is a :class:`Condition`
  (a sympy relation; combine them with ``&``, ``|`` and ``~``), ``np.where(cond, a, b)``
  is a sympy ``Piecewise``, ``np.fmax`` / ``np.fmin`` are ``Max`` and ``Min``,
  ``np.abs`` and ``np.sign`` are ``Abs`` and ``sign``; CasADi compiles them to
  ``if_else``, ``fmax``, ``fmin``, ``fabs`` and ``sign``.  A condition in arithmetic is 1
  or 0, as a NumPy bool is.
- ``np.var`` and ``np.std`` (``axis`` one axis or None, ``ddof``, ``keepdims``), as NumPy
  defines them; ``np.round``, ``np.around``, ``np.rint``, ``np.trunc`` and ``round()`` are
  refused (a step of zero derivative; ``np.floor`` and ``np.ceil`` are there for a step).

NaN as in NumPy: ``np.maximum``, ``np.minimum``, ``np.clip``, ``np.max`` and ``np.min``
give NaN where an argument is NaN (a Piecewise whose last branch is NaN, which neither
comparison reaches), ``np.fmax`` and ``np.fmin`` drop it (C's ``fmax``).  A NaN of
``np.sqrt``, ``np.log`` or ``np.arcsin`` outside their domain reaches the output as in NumPy,
unless sympy removed the subexpression by an identity that holds where it is defined
(``a - a`` is 0, ``0 * a`` is 0, ``np.exp(np.log(a))`` is ``a``): there symmon's value is the
identity's where NumPy's is NaN.

NumPy code built on these works too (``x.sum()``, ``np.hstack``, ``F @ x``).  Comparisons
and the functions that compare (``np.maximum``, ``np.clip``, ``np.sign``, ``np.max``) work on
traced scalars and on the arrays computed from ``x`` (``x``, ``x[1:]``, ``x - s``,
``F @ x``); on an array built with ``np.array([...])`` NumPy compares the entries itself
and cannot, so apply them to the entries (the other ufuncs work on it, but for
``np.float_power`` and ``scipy.special.erf``/``erfc``, which NumPy has no object loop of).
A traced loop (``for _ in range(500): x = x + dt * f(x)``) is an expression DAG: it is
walked once per distinct node (:mod:`symmon.core.dag`), never as a tree.

Anything else raises an :class:`~symmon.errors.UnsupportedFunctionError` that names the
operation by its qualified name (``np.fmod``, ``np.sort``, ``scipy.special.gamma``) and says
what to write instead: a Python ``if`` on a traced comparison (it is not a bool),
``float(x[0])`` and ``math.sqrt`` (the value is a symbol, not a number).  Reading an entry
past the declared names (``x[2]`` with two names in ``inputs=``) is a
:class:`~symmon.errors.ModelError` that says how many names to give.
"""

from __future__ import annotations

import contextvars
import functools
import inspect
import numbers
import re
import sys
import threading
import traceback
from typing import Any, Callable, Sequence

import numpy as np
import sympy as sp
from sympy.core.cache import clear_cache
from sympy.functions.elementary.piecewise import ExprCondPair

from ..errors import ModelError, UnsupportedFunctionError
from .symbols import as_symbols

__all__ = ["Traced", "Condition", "trace", "SUPPORTED"]


def _hypot(a, b):
    return sp.sqrt(a**2 + b**2)


def _piecewise_of(*pairs: tuple[sp.Basic, sp.Basic]) -> sp.Piecewise:
    """``Piecewise(*pairs)`` as given, each condition kept.

    sympy's Piecewise rewrites a condition that holds a Piecewise into ``ITE`` form by
    folding the branches (a walk of the whole condition, exponential on a traced loop),
    which drops a NaN branch: ``max(NaN, 1) >= 2`` would become ``1 >= 2``.
    """
    return sp.Basic.__new__(sp.Piecewise, *[sp.Tuple.__new__(ExprCondPair, sp.sympify(e), c) for e, c in pairs])


def _nan_max(a, b):
    """NumPy's ``np.maximum``: the larger, NaN where either is NaN.

    sympy's ``Max`` compiles to C's ``fmax``, which drops a NaN (``np.fmax``).  Here a NaN
    fails both comparisons and takes the last branch; the Piecewise is built as it is
    (:func:`_piecewise_of`), since sympy would merge ``a < b`` into the ``True`` of the
    complement of ``a >= b`` (it holds for every real number, not for NaN).  A comparison sympy decides (``x**2 >= 0``)
    picks its branch.
    """
    ge = sp.Ge(a, b)
    if ge in (sp.true, sp.false):
        return a if ge is sp.true else b
    # Unevaluated relations too: sympy folds a comparison of a Piecewise into its branches.
    return _piecewise_of((a, sp.Ge(a, b, evaluate=False)), (b, sp.Lt(a, b, evaluate=False)), (sp.nan, sp.true))


def _nan_min(a, b):
    """NumPy's ``np.minimum``: the smaller, NaN where either is NaN (see :func:`_nan_max`)."""
    le = sp.Le(a, b)
    if le in (sp.true, sp.false):
        return a if le is sp.true else b
    return _piecewise_of((a, sp.Le(a, b, evaluate=False)), (b, sp.Gt(a, b, evaluate=False)), (sp.nan, sp.true))


def _clip(a, lo, hi):
    # np.clip is minimum(maximum(a, lo), hi): NaN in, NaN out.
    return _nan_min(_nan_max(a, lo), hi)


#: NumPy ufuncs that give a value, and their sympy counterparts.
_VALUES: dict[np.ufunc, Callable[..., sp.Expr]] = {
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
    # np.maximum / np.minimum propagate NaN, np.fmax / np.fmin drop it (Max, Min: fmax, fmin).
    np.maximum: _nan_max, np.fmax: sp.Max,
    np.minimum: _nan_min, np.fmin: sp.Min,
    np.conjugate: lambda a: a,  # traced values are real (NumPy's np.var calls it)
    np.deg2rad: lambda a: a * sp.pi / 180,
    np.rad2deg: lambda a: a * 180 / sp.pi,
}
_VALUES[np.radians] = _VALUES[np.deg2rad]
_VALUES[np.degrees] = _VALUES[np.rad2deg]


def _clip_ufunc() -> np.ufunc | None:
    """The ufunc behind ``np.clip`` and ``ndarray.clip`` (not in NumPy's namespace)."""
    core = getattr(np, "_core", None) or getattr(np, "core", None)
    clip = getattr(getattr(core, "umath", None), "clip", None)
    return clip if isinstance(clip, np.ufunc) else None


_CLIP = _clip_ufunc()
if _CLIP is not None:
    _VALUES[_CLIP] = _clip

#: Comparisons: ufuncs that give a :class:`Condition`.
_COMPARISONS: dict[np.ufunc, Callable[..., sp.Basic]] = {
    np.greater: sp.Gt, np.greater_equal: sp.Ge, np.less: sp.Lt, np.less_equal: sp.Le,
    np.equal: sp.Eq, np.not_equal: sp.Ne,
}


def _xor(a, b):
    # CasADi has no Xor: written with And, Or and Not, which it compiles.
    return sp.Or(sp.And(a, sp.Not(b)), sp.And(sp.Not(a), b))


#: Logical ufuncs on conditions (a traced number is true where it is not 0, as in NumPy).
_LOGICAL: dict[np.ufunc, Callable[..., sp.Basic]] = {
    np.logical_and: sp.And, np.logical_or: sp.Or, np.logical_not: sp.Not, np.logical_xor: _xor,
}
#: ``&``, ``|``, ``^`` and ``~`` of arrays of conditions; only on conditions and bools.
_BITWISE: dict[np.ufunc, Callable[..., sp.Basic]] = {
    np.bitwise_and: sp.And, np.bitwise_or: sp.Or, np.bitwise_xor: _xor, np.invert: sp.Not,
}
#: Ufuncs whose NumPy object loop only multiplies and adds the entries: NumPy runs them.
_DELEGATED: frozenset[np.ufunc] = frozenset({np.matmul})


@functools.lru_cache(maxsize=None)
def _scipy_values() -> dict:
    """The SciPy ufuncs a traced function may call (scipy.special is loaded when it calls one)."""
    special = sys.modules.get("scipy.special")
    if special is None:  # pragma: no cover - a SciPy ufunc implies scipy.special is loaded
        return {}
    return {special.erf: sp.erf, special.erfc: lambda a: 1 - sp.erf(a)}


def _numpy_names(ufuncs) -> set[str]:
    """Every public name NumPy gives to the ufuncs (``np.abs`` and ``np.absolute``)."""
    return {f"np.{name}" for name, obj in vars(np).items()
            if not name.startswith("_") and isinstance(obj, np.ufunc) and obj in ufuncs}


#: NumPy and SciPy functions that are not ufuncs; each is tested (tests/core/test_tracing.py).
_FUNCTIONS = ("np.array", "np.asarray", "np.clip", "np.concatenate", "np.cumsum", "np.dot",
              "np.hstack", "np.inner", "np.linalg.norm", "np.max", "np.mean", "np.min",
              "np.outer", "np.prod", "np.stack", "np.std", "np.sum", "np.var", "np.vstack", "np.where")

#: Every NumPy and SciPy function a traced function may call: the ufuncs under all their
#: NumPy names (``np.abs`` and ``np.absolute``), comparisons, logical functions, the NumPy
#: functions above and ``scipy.special.erf`` / ``erfc``.
SUPPORTED: tuple[str, ...] = tuple(sorted(
    _numpy_names({**_VALUES, **_COMPARISONS, **_LOGICAL, **dict.fromkeys(_DELEGATED)})
    | set(_FUNCTIONS) | {"scipy.special.erf", "scipy.special.erfc"}))


# --------------------------------------------------------------------------- names and errors
def _alias(module: str) -> str:
    return "np" + module[len("numpy"):] if module == "numpy" or module.startswith("numpy.") else module


def _public_module(module: str) -> str:
    """``numpy._core.fromnumeric`` → ``numpy``, ``scipy.linalg._matfuncs`` → ``scipy.linalg``."""
    parts = []
    for p in module.split("."):
        if p.startswith("_"):
            break
        parts.append(p)
    return ".".join(parts) or module


def _qualified_name(obj: Any) -> str:
    """The name a user writes for a NumPy or SciPy function or ufunc: ``np.fmod``,
    ``np.linalg.norm``, ``scipy.special.erf``."""
    name = getattr(obj, "__name__", None) or type(obj).__name__
    for module in ("numpy", "numpy.linalg", "scipy.special"):
        mod = sys.modules.get(module)
        if mod is not None and getattr(mod, name, None) is obj:
            also = sorted(f"{_alias(module)}.{k}" for k, o in vars(mod).items()
                          if o is obj and k != name and not k.startswith("_"))
            return f"{_alias(module)}.{name}" + (f" (also {', '.join(also)})" if also else "")
    module = getattr(obj, "__module__", None)
    if module:
        return f"{_alias(_public_module(module))}.{name}"
    return f"the ufunc {name}" if isinstance(obj, np.ufunc) else name


def _code_of(obj: Any):
    for _ in range(4):  # a dispatcher, its implementation, a wrapper ...
        code = getattr(obj, "__code__", None)
        if code is not None:
            return code
        obj = getattr(obj, "_implementation", None) or getattr(obj, "__wrapped__", None)
    return None


def _frame_name(frame) -> str | None:
    """The public name of the NumPy/SciPy function running in ``frame``, if it has one."""
    module = frame.f_globals.get("__name__", "")
    public = _public_module(module)
    obj = getattr(sys.modules.get(public), frame.f_code.co_name, None)
    if obj is not None and _code_of(obj) is frame.f_code:
        return f"{_alias(public)}.{frame.f_code.co_name}"
    return None


_SUPPORTED_ADVICE = ("The functions a traced model function may call are "
                     "symmon.core.tracing.SUPPORTED: " + ", ".join(SUPPORTED)
                     + "; anything else can be declared with sympy, Model(inputs, outputs)")
_BRANCH_ADVICE = ("a comparison such as x[0] > 0 is a symbolic condition, not True or False. "
                  "Write the branch as np.where(cond, a, b) (both a and b are traced; combine "
                  "conditions with &, | and ~), use np.maximum, np.minimum, np.clip, np.abs or "
                  "np.sign, or declare the model with sympy Piecewise")
_NUMBER_ADVICE = ("the inputs are symbols, not numbers. Use the NumPy functions (np.sqrt, not "
                  "math.sqrt), and build arrays with np.array([...]) or np.zeros(n, dtype=object)")


def _refusal(subject: str, why: str, inside: str | None = None) -> UnsupportedFunctionError:
    """``subject is not supported in a traced model function: why``; ``inside`` is the
    phrase a NumPy function that met this error inside gives (``it converts ...``)."""
    err = UnsupportedFunctionError(f"{subject} is not supported in a traced model function: {why}")
    err.inside = inside or f"it uses {subject}, which is not supported"
    err.why = why
    return err


def _unknown(subject: str) -> UnsupportedFunctionError:
    return _refusal(subject, f"it has no sympy counterpart here. {_SUPPORTED_ADVICE}",
                    f"it calls {subject}, which has no sympy counterpart here")


def _branch() -> UnsupportedFunctionError:
    return _refusal(
        "deciding a traced comparison as True or False (Python if, while, and, or, not, bool(), "
        "max(), min(), or a NumPy loop that compares the entries of an array built with "
        "np.array([...]))", _BRANCH_ADVICE, "it compares traced values")


def _number() -> UnsupportedFunctionError:
    return _refusal(
        "converting a traced value to a number (float(), int(), math.sqrt and the other math "
        "functions, storing it in a float array such as np.zeros(n))", _NUMBER_ADVICE,
        "it converts traced values to numbers")


def _renamed(name: str, exc: BaseException) -> UnsupportedFunctionError:
    """The error of the NumPy or SciPy function ``name`` that failed inside with ``exc``."""
    if isinstance(exc, UnsupportedFunctionError) and hasattr(exc, "inside"):
        why = f"{exc.inside}; {exc.why}"
    else:
        why = (f"it fails on traced values ({type(exc).__name__}: {exc}). {_SUPPORTED_ADVICE}")
    err = _refusal(name, why)
    err.named = True
    return err


# --------------------------------------------------------------------------- values
def _to_sympy(a: Any) -> sp.Expr:
    """A traced value or a real number as a sympy expression (floats kept bit for bit);
    a condition is 1 where it holds and 0 elsewhere, as a NumPy bool in arithmetic."""
    if isinstance(a, np.ndarray) and a.ndim == 0:
        a = a[()]
    if isinstance(a, Condition):
        if a.expr in (sp.true, sp.false):
            return sp.Integer(1 if a.expr is sp.true else 0)
        return _piecewise_of((sp.Integer(1), a.expr), (sp.Integer(0), sp.true))
    if isinstance(a, Traced):
        return a.expr
    if isinstance(a, (bool, np.bool_)):
        raise _refusal("a boolean operand", "write the number 1 or 0, or a traced comparison")
    if isinstance(a, numbers.Integral):
        return sp.Integer(int(a))
    if isinstance(a, numbers.Real):
        x = float(a)
        if not np.isfinite(x):
            raise ModelError(f"the traced function uses the non-finite constant {x}")
        # The shortest decimal that rounds back to x: what the user wrote (dt = 0.1 → 1/10),
        # and float() of it is x again, bit for bit.
        return sp.Rational(repr(x))
    raise _refusal(f"an operand of type {type(a).__name__}",
                   "the operands are traced values and real numbers")


def _to_condition(a: Any, strict: bool = False) -> sp.Basic:
    """A condition, a bool, or (unless ``strict``) a traced value or number as a sympy
    boolean; a number is true where it is not 0, as in NumPy."""
    if isinstance(a, np.ndarray) and a.ndim == 0:
        a = a[()]
    if isinstance(a, Condition):
        return a.expr
    if isinstance(a, (bool, np.bool_)):
        return sp.true if a else sp.false
    if strict:
        raise _refusal(f"&, |, ^ or ~ of {type(a).__name__}",
                       "they combine conditions; for numbers use np.logical_and, np.logical_or, "
                       "np.logical_xor or np.logical_not")
    return sp.Ne(_to_sympy(a), 0)


def _plain(a: Any) -> Any:
    return a.view(np.ndarray) if isinstance(a, _TracedArray) else a


def _operand(a: Any) -> Any:
    """``a`` for an object ufunc of ours: a plain array, a traced scalar in a 0-d object
    array (else NumPy would hand the call back to it), a number as it is."""
    if isinstance(a, np.ndarray):
        return a.view(np.ndarray)
    if isinstance(a, (Traced, list, tuple)):
        return np.asarray(a, dtype=object) if not isinstance(a, Traced) else _zero_d(a)
    return a


def _zero_d(a: Any) -> np.ndarray:
    arr = np.empty((), dtype=object)
    arr[()] = a
    return arr


def _wrap(result: Any) -> Any:
    """An object array as a :class:`_TracedArray`, so that NumPy keeps calling back."""
    if isinstance(result, np.ndarray) and result.dtype == object and not isinstance(result, _TracedArray):
        return result.view(_TracedArray)
    if isinstance(result, tuple):
        return tuple(_wrap(r) for r in result)
    return result


def _lookup(ufunc: np.ufunc) -> tuple[str, Callable] | None:
    for kind, table in (("value", _VALUES), ("compare", _COMPARISONS), ("logic", _LOGICAL),
                        ("bitwise", _BITWISE), ("value", _scipy_values())):
        fn = table.get(ufunc)
        if fn is not None:
            return kind, fn
    return None


def _apply(ufunc: np.ufunc, args: Sequence[Any]) -> Any:
    """Apply ``ufunc`` to scalars or (object) arrays of traced values and numbers."""
    found = _lookup(ufunc)
    if found is None:
        raise _unknown(_qualified_name(ufunc))
    if any(isinstance(a, np.ndarray) and a.ndim > 0 for a in args):
        return _elementwise(ufunc)(*[_operand(a) for a in args])
    kind, fn = found
    if kind == "value":
        return Traced(fn(*[_to_sympy(a) for a in args]))
    if kind == "compare":
        return Condition(fn(*[_to_sympy(a) for a in args]))
    return Condition(fn(*[_to_condition(a, strict=kind == "bitwise") for a in args]))


@functools.lru_cache(maxsize=None)
def _elementwise(ufunc: np.ufunc) -> np.ufunc:
    """``ufunc`` as an object ufunc of traced values, with NumPy's broadcasting, ``reduce``
    and ``accumulate``."""
    return np.frompyfunc(lambda *xs: _apply(ufunc, xs), ufunc.nin, 1)


def _ufunc_override(ufunc: np.ufunc, method: str, inputs: Sequence[Any], kwargs: dict) -> Any:
    """``__array_ufunc__`` of traced scalars and arrays."""
    kwargs = dict(kwargs)
    out = kwargs.pop("out", None)
    if kwargs.get("dtype", None) in (None, object, np.dtype(object)):
        kwargs.pop("dtype", None)
    # NumPy's own functions pass these (np.var divides with casting="unsafe", subok=False):
    # on object arrays they choose a dtype or an array type, never a value.
    for k in ("casting", "subok", "order"):
        kwargs.pop(k, None)
    if kwargs.get("where", None) is True:
        kwargs.pop("where")
    plain = [_operand(a) for a in inputs]
    if method == "__call__":
        if kwargs:
            raise _refusal(f"{_qualified_name(ufunc)} with {sorted(kwargs)}", "call it without these arguments")
        if ufunc in _DELEGATED:
            result = ufunc(*plain)
        else:
            result = _apply(ufunc, plain)
    elif method in ("reduce", "accumulate", "reduceat", "outer") and ufunc.nin == 2 and _lookup(ufunc):
        if (method == "reduce" and ufunc.identity is not None and isinstance(plain[0], np.ndarray)
                and plain[0].size == 0):
            kwargs.setdefault("initial", ufunc.identity)
        result = getattr(_elementwise(ufunc), method)(*plain, **kwargs)
    else:
        raise _unknown(f"{_qualified_name(ufunc)}.{method}")
    if out is not None:
        if len(out) != 1:
            raise _refusal(f"{_qualified_name(ufunc)} with several out= arrays", "call it without out=")
        out[0][...] = result
        return out[0]
    return _wrap(result)


def _where(condition, *values, **kwargs):
    """``np.where(cond, a, b)``: a sympy Piecewise, entry by entry."""
    if len(values) != 2 or kwargs:
        raise _refusal("np.where(cond) without both a and b (the indices where cond holds)",
                       "they depend on the values. Use np.where(cond, a, b)")
    return _wrap(_piecewise(*[_operand(a) for a in (condition, *values)]))


def _piece(c, a, b):
    cond = _to_condition(c)
    if cond in (sp.true, sp.false):
        return Traced(_to_sympy(a) if cond is sp.true else _to_sympy(b))
    return Traced(_piecewise_of((_to_sympy(a), cond), (_to_sympy(b), sp.true)))


_piecewise = np.frompyfunc(_piece, 3, 1)


def _absent(v: Any) -> bool:
    return v is None or v is getattr(np, "_NoValue", None)


def _clip_function(a, a_min=None, a_max=None, out=None, **kwargs):
    """``np.clip(a, a_min, a_max)``: ``np.minimum(np.maximum(a, a_min), a_max)``."""
    lo, hi = kwargs.pop("min", None), kwargs.pop("max", None)
    a_min = lo if _absent(a_min) else a_min
    a_max = hi if _absent(a_max) else a_max
    if not _absent(out) or kwargs:
        raise _refusal(f"np.clip with {sorted(kwargs) or ['out']}", "call np.clip(a, a_min, a_max)")
    r = _plain(a)
    if not _absent(a_min):
        r = _apply(np.maximum, (r, _plain(a_min)))
    if not _absent(a_max):
        r = _apply(np.minimum, (r, _plain(a_max)))
    return _wrap(r)


def _var_function(a, axis=None, dtype=None, out=None, ddof=0, keepdims=False, *, where=True, mean=None,
                  correction=None, _root=False):
    """``np.var`` (and, with ``_root``, ``np.std``): the mean of the squared deviations
    from the mean over ``axis``, divided by N − ddof, exactly as NumPy defines it."""
    name = "np.std" if _root else "np.var"
    if not (_absent(out) and _absent(mean) and (where is True or _absent(where))
            and dtype in (None, object, float)):
        raise _refusal(f"{name} with out=, where=, mean= or an integer dtype",
                       f"call {name}(a, axis=..., ddof=..., keepdims=...)")
    if not _absent(correction):
        if ddof != 0:
            raise ValueError(f"{name}: ddof and correction can't be provided simultaneously.")
        ddof = correction
    arr = _wrap(np.asarray(a, dtype=object))
    mean_ = np.mean(arr, axis=axis, keepdims=True)  # NumPy checks the axis
    axes = range(arr.ndim) if axis is None else (axis,) if isinstance(axis, numbers.Integral) else axis
    count = int(np.prod([arr.shape[k] for k in axes]))
    if count - ddof <= 0:
        raise _refusal(f"{name} with ddof={ddof} of {count} entries", "NumPy divides by N - ddof <= 0 "
                       "(a NaN or infinity with a warning): give fewer degrees of freedom")
    centred = arr - mean_
    var = np.sum(centred * centred, axis=axis, keepdims=keepdims) / (count - ddof)
    return _wrap(np.sqrt(var) if _root else var)


def _std_function(*args, **kwargs):
    """``np.std``: the square root of ``np.var``."""
    return _var_function(*args, _root=True, **kwargs)


_ROUND_WHY = ("rounding is a step function of the value: its derivative is 0 wherever it "
              "is defined, so every linearising transform would see no spread. Round the "
              "numbers outside the model, or write the step you mean with np.floor "
              "(np.floor(a + 0.5) rounds halves up; NumPy rounds them to even)")


def _round_function(a, decimals=0, out=None):
    raise _refusal("np.round (also np.around)", _ROUND_WHY)


#: NumPy functions with an implementation of their own for traced values.
_SPECIAL: dict[Callable, Callable] = {np.where: _where, np.clip: _clip_function, np.var: _var_function,
                                      np.std: _std_function, np.round: _round_function}
if getattr(np, "around", np.round) is not np.round:
    _SPECIAL[np.around] = _round_function
#: Depth of nested NumPy functions: the outermost one names a failure inside.
_DEPTH: contextvars.ContextVar[int] = contextvars.ContextVar("symmon_trace_depth", default=0)


def _function_override(func: Callable, args: Sequence[Any], kwargs: dict) -> Any:
    """``__array_function__`` of traced scalars and arrays: NumPy's implementation, with a
    failure inside reported under the function's name."""
    special = _SPECIAL.get(func)
    if special is not None:
        return special(*args, **kwargs)
    name = _qualified_name(func)
    impl = getattr(func, "_implementation", None) or getattr(func, "__wrapped__", None)
    if impl is None:  # pragma: no cover - every NumPy dispatcher has its implementation
        raise _unknown(name)
    depth = _DEPTH.get()
    token = _DEPTH.set(depth + 1)
    try:
        return _wrap(impl(*args, **kwargs))
    except (UnsupportedFunctionError, TypeError, AttributeError, ValueError) as exc:
        if depth or getattr(exc, "named", False):
            raise
        raise _renamed(name, exc) from exc
    finally:
        _DEPTH.reset(token)


# --------------------------------------------------------------------------- traced values
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

    def __init__(self, expr: sp.Basic) -> None:
        self.expr = expr

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.expr})"

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> Any:
        return _ufunc_override(ufunc, method, inputs, kwargs)

    def __array_function__(self, func: Callable, types: Any, args: Sequence[Any], kwargs: dict) -> Any:
        return _function_override(func, args, kwargs)

    # Arithmetic; each returns NotImplemented for an array operand, so that NumPy arrays
    # take over (elementwise through __array_ufunc__).
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
    def __neg__(self): return _apply(np.negative, (self,))
    def __pos__(self): return self
    def __abs__(self): return _apply(np.absolute, (self,))

    # Comparisons are conditions (sympy relations), not bools.
    def __lt__(self, o): return self._binary(o, np.less)
    def __le__(self, o): return self._binary(o, np.less_equal)
    def __gt__(self, o): return self._binary(o, np.greater)
    def __ge__(self, o): return self._binary(o, np.greater_equal)
    def __eq__(self, o): return self._binary(o, np.equal)  # type: ignore[override]
    def __ne__(self, o): return self._binary(o, np.not_equal)  # type: ignore[override]
    __hash__ = None  # type: ignore[assignment]

    def __bool__(self) -> bool:
        return bool(Condition(_to_condition(self)))

    def __float__(self) -> float:
        raise _number()

    __int__ = __index__ = __complex__ = __float__  # type: ignore[assignment]

    def __floordiv__(self, o): raise _refusal("floor division //", "write np.floor(a / b)")
    __rfloordiv__ = __mod__ = __rmod__ = __floordiv__

    # math.floor / math.ceil, and NumPy's loops of np.floor / np.ceil over an object
    # array built with np.array([...]) (they call math.floor on each entry).
    def __floor__(self): return _apply(np.floor, (self,))
    def __ceil__(self): return _apply(np.ceil, (self,))

    def __trunc__(self): raise _refusal("np.trunc (also np.fix, math.trunc)", _ROUND_WHY)

    def __round__(self, ndigits=None): raise _refusal("round() (also np.round)", _ROUND_WHY)


class Condition(Traced):
    """A traced comparison such as ``x[0] > 0``: a sympy relation, not a Python bool.

    ``np.where(cond, a, b)`` turns it into a ``Piecewise``; ``&``, ``|``, ``^`` and ``~``
    combine conditions; in arithmetic it is 1 where it holds and 0 elsewhere.  Python's
    ``if``, ``and``, ``or``, ``not`` and ``bool()`` need True or False and raise an
    :class:`~symmon.errors.UnsupportedFunctionError`, unless sympy decides the relation
    for every value (``x[0]**2 + 1 > 0``).

    Attributes
    ----------
    expr : sympy.Basic
        The relation (``x > 0``), or a combination of relations with And, Or and Not.

    Examples
    --------
    >>> import numpy as np
    >>> x = sp.Symbol("x", real=True)
    >>> np.where(Traced(x) > 0, Traced(x), 0).expr
    Piecewise((x, x > 0), (0, True))
    """

    __slots__ = ()

    def __bool__(self) -> bool:
        if self.expr in (sp.true, sp.false):
            return self.expr is sp.true
        raise _branch()

    def _logical(self, other: Any, ufunc: np.ufunc, reflected: bool = False) -> Any:
        if isinstance(other, np.ndarray) and other.ndim > 0:
            return NotImplemented
        return _apply(ufunc, (other, self) if reflected else (self, other))

    def __and__(self, o): return self._logical(o, np.bitwise_and)
    def __rand__(self, o): return self._logical(o, np.bitwise_and, True)
    def __or__(self, o): return self._logical(o, np.bitwise_or)
    def __ror__(self, o): return self._logical(o, np.bitwise_or, True)
    def __xor__(self, o): return self._logical(o, np.bitwise_xor)
    def __rxor__(self, o): return self._logical(o, np.bitwise_xor, True)
    def __invert__(self): return _apply(np.invert, (self,))


# NumPy's object loops call a method of the ufunc's name on each entry of an object array
# (np.sqrt(a) calls a[i].sqrt()).
for _uf in list(_VALUES) + list(_LOGICAL):
    if _uf.nin == 1 and not hasattr(Traced, _uf.__name__):
        setattr(Traced, _uf.__name__, (lambda uf: lambda self: _apply(uf, (self,)))(_uf))
    elif _uf.nin == 2 and not hasattr(Traced, _uf.__name__):
        setattr(Traced, _uf.__name__, (lambda uf: lambda self, other: _apply(uf, (self, other)))(_uf))
# Any other ufunc's loop over an array built with np.array([...]) finds a method that
# refuses it by name (not NumPy's TypeError "... has no callable rint method").
for _uf in {obj for obj in vars(np).values() if isinstance(obj, np.ufunc)}:
    if not hasattr(Traced, _uf.__name__) and _uf.__name__.isidentifier():
        setattr(Traced, _uf.__name__, (lambda uf: lambda self, *rest: _apply(uf, (self, *rest)))(_uf))


class _Source:
    """The names behind one argument of the traced function (``x`` or ``v``), and the
    entries read past them, shared by the arguments of one trace."""

    def __init__(self, label: str, keyword: str, names: tuple[sp.Symbol, ...], misses: list) -> None:
        self.label, self.keyword, self.names, self.misses = label, keyword, names, misses

    def read(self, key: Any) -> Any:
        """The entry or entries ``key`` when some lie past the names (placeholders, and
        the read recorded), else None: NumPy indexes as usual."""
        k = key[0] if isinstance(key, tuple) and len(key) == 1 else key
        n = len(self.names)
        if isinstance(k, (int, np.integer)) and not isinstance(k, (bool, np.bool_)):
            return None if -n <= int(k) < n else self._miss(int(k))
        if isinstance(k, (list, np.ndarray)):
            try:
                idx = np.asarray(k)
            except (TypeError, ValueError):
                return None
            if idx.dtype.kind in "iu" and idx.size and ((idx < -n) | (idx >= n)).any():
                out = np.empty(idx.shape, dtype=object)
                for pos, j in np.ndenumerate(idx):
                    j = int(j)
                    out[pos] = Traced(self.names[j]) if -n <= j < n else self._miss(j)
                return out.view(_TracedArray)
        return None

    def _miss(self, k: int) -> "Traced":
        self.misses.append((self, k))
        return Traced(sp.Dummy(f"{self.label}[{k}]", real=True))


class _TracedArray(np.ndarray):
    """An object array of traced values that keeps its type through NumPy's ufuncs and
    functions, so that comparisons, ``np.where`` and ``np.maximum`` on it are traced."""

    def __array_finalize__(self, obj: Any) -> None:
        self._source = None  # only the argument itself checks its indices, not a view

    def __array_ufunc__(self, ufunc: np.ufunc, method: str, *inputs: Any, **kwargs: Any) -> Any:
        return _ufunc_override(ufunc, method, inputs, kwargs)

    def __array_function__(self, func: Callable, types: Any, args: Sequence[Any], kwargs: dict) -> Any:
        return _function_override(func, args, kwargs)

    def __getitem__(self, key: Any) -> Any:
        if any(isinstance(k, np.ndarray) and k.dtype == object or isinstance(k, Traced)
               for k in (key if isinstance(key, tuple) else (key,))):
            raise _refusal(
                "indexing with traced values (x[x > 0], x[i] with a traced i)",
                "which entries are read would depend on the values. Write the selection as "
                "np.where(cond, a, b), or declare the model with sympy Piecewise")
        if self._source is not None:
            hit = self._source.read(key)
            if hit is not None:
                return hit
        return super().__getitem__(key)

    def __iter__(self):
        # NumPy iterates by indexing until IndexError; the argument's reads past its
        # names give placeholders instead, so it iterates over its entries.
        if self._source is not None:
            return iter(self.view(np.ndarray))
        return super().__iter__()


def _argument(source: _Source) -> _TracedArray:
    arr = np.array([Traced(s) for s in source.names], dtype=object).view(_TracedArray)
    arr._source = source
    return arr


# --------------------------------------------------------------------------- trace
def _labels(fn: Callable, count: int) -> tuple[list[str], inspect.Signature | None]:
    """The names of ``fn``'s first ``count`` parameters (``x``, ``v`` if unknown) and its
    signature."""
    labels = ["x", "v"][:count]
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return labels, None
    positional = [p.name for p in sig.parameters.values()
                  if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return [positional[i] if i < len(positional) else labels[i] for i in range(count)], sig


def _misses_error(who: str, misses: list) -> ModelError:
    parts = []
    for source in dict.fromkeys(s for s, _ in misses):
        ks = sorted({k for s, k in misses if s is source}, key=lambda k: (k < 0, abs(k)))
        need = max(k + 1 if k >= 0 else -k for k in ks)
        n = len(source.names)
        given = f"{n} symbol{'' if n == 1 else 's'}" + (f" ({', '.join(map(str, source.names))})" if n else "")
        least = "at least " if any(k < 0 for k in ks) else ""
        parts.append(f"{who} reads {' and '.join(f'{source.label}[{k}]' for k in ks)} but "
                     f"{source.keyword}= names {given}: give {least}{need} names, one for each "
                     f"entry of {source.label}")
    return ModelError("; ".join(parts))


def _library_failure(exc: BaseException) -> UnsupportedFunctionError | None:
    """``exc`` raised inside a NumPy or SciPy function the traced function called, reported
    under that function's name; None if it did not come from one."""
    if getattr(exc, "named", False) or not isinstance(exc, (UnsupportedFunctionError, TypeError, AttributeError,
                                                             ValueError)):
        return None
    frames = [f for f, _ in traceback.walk_tb(exc.__traceback__)
              if f.f_globals.get("__name__", "").partition(".")[0] in ("numpy", "scipy")]
    if not frames:
        return None
    for f in frames:
        name = _frame_name(f)
        if name is not None:
            return _renamed(name, exc)
    f = frames[0]
    code = f.f_code
    return _renamed(f"{_alias(f.f_globals['__name__'])}.{getattr(code, 'co_qualname', code.co_name)}", exc)


#: The stack and the recursion limit of the thread that runs a traced function.  sympy's
#: evaluation asks properties such as ``is_number`` recursively, as deep as the expression
#: (``y = sin(y) + cos(y)`` 500 times is 1000 levels of three to five frames each, Python's
#: default limit is 1000 frames): a recursion that is linear, but deeper than the default.
TRACE_STACK_BYTES = 512 * 2**20
TRACE_RECURSION_LIMIT = 100_000
_deep_lock = threading.Lock()
_deep_runs = [0, 0]  # traces running, the recursion limit before the first


def _deep_call(fn: Callable[..., Any], args: Sequence[Any]) -> Any:
    """``fn(*args)`` in a thread with a stack of :data:`TRACE_STACK_BYTES` and a recursion
    limit of :data:`TRACE_RECURSION_LIMIT` (restored when the last trace ends), in a copy
    of the caller's context (``np.errstate`` holds)."""
    result: dict[str, Any] = {}

    def run() -> None:
        try:
            result["out"] = fn(*args)
        except BaseException as exc:  # re-raised in the caller, traceback and all
            result["exc"] = exc

    ctx = contextvars.copy_context()
    with _deep_lock:
        if _deep_runs[0] == 0:
            _deep_runs[1] = sys.getrecursionlimit()
            sys.setrecursionlimit(max(_deep_runs[1], TRACE_RECURSION_LIMIT))
        _deep_runs[0] += 1
        old = threading.stack_size()
        try:
            threading.stack_size(TRACE_STACK_BYTES)
            worker = threading.Thread(target=ctx.run, args=(run,), name="symmon-trace", daemon=True)
            worker.start()  # the stack size applies to the threads started while it is set
        finally:
            threading.stack_size(old)
    try:
        worker.join()
    finally:
        with _deep_lock:
            _deep_runs[0] -= 1
            if _deep_runs[0] == 0:
                sys.setrecursionlimit(_deep_runs[1])
    if "exc" in result:
        raise result["exc"]
    return result["out"]


def _ufunc_type_error(exc: BaseException) -> UnsupportedFunctionError | None:
    """NumPy's TypeError for a ufunc without a loop for object arrays (``np.isnan`` of an
    array built with ``np.array([...])``), raised in C, as the ufunc's refusal."""
    match = re.search(r"ufunc '(\w+)'", str(exc)) if isinstance(exc, TypeError) else None
    special = sys.modules.get("scipy.special")
    ufunc = next((u for u in (getattr(m, match.group(1), None) for m in (np, special) if m is not None)
                  if isinstance(u, np.ufunc)), None) if match else None
    if not isinstance(ufunc, np.ufunc):
        return None
    if _lookup(ufunc) is not None:
        err = _refusal(f"{_qualified_name(ufunc)} of an array built with np.array([...])",
                       "NumPy has no loop of it for object arrays. Apply it to the entries, or to an "
                       "array computed from x (x, x[1:], F @ x)")
    else:
        err = _unknown(_qualified_name(ufunc))
    err.named = True
    return err


def trace(fn: Callable[..., Any], inputs: Sequence[Any], noise: Sequence[Any] | None = None,
          args: Sequence[Any] = ()) -> tuple[tuple[sp.Symbol, ...], tuple[sp.Symbol, ...], tuple[sp.Expr, ...]]:
    """Call ``fn`` on symbolic inputs and return the sympy expressions of its outputs.

    Parameters
    ----------
    fn : callable
        ``fn(x, *args)``, or ``fn(x, v, *args)`` when ``noise`` is given, with ``x`` (and
        ``v``) 1-D arrays; it returns a scalar or a 1-D array-like of outputs.  It may use
        the operations and functions of :data:`SUPPORTED` (see the module's docstring).
    inputs, noise : sequence of str or sympy.Symbol
        Names of the components of ``x`` and ``v``: one name for each entry the function
        reads.
    args : sequence
        Further (numeric) arguments passed to ``fn``, such as FilterPy's ``dt``.

    Returns
    -------
    inputs, noise, outputs : tuples of sympy objects

    Raises
    ------
    UnsupportedFunctionError
        Naming the operation that cannot be traced (``np.fmod``, ``scipy.special.gamma``,
        ``float(x[0])``, a Python ``if`` on a traced comparison) and what to write instead.
    ModelError
        If ``fn`` reads an entry past the names (``x[2]`` with two names in ``inputs``),
        saying how many names to give; if ``fn`` cannot be called with these arguments.

    Examples
    --------
    >>> import numpy as np
    >>> def hx(x):
    ...     return np.array([np.sqrt(x[0]**2 + x[1]**2), np.arctan2(x[1], x[0])])
    >>> trace(hx, ["px", "py"])[2]
    (sqrt(px**2 + py**2), atan2(py, px))
    >>> trace(lambda x: np.where(x[0] > 0, x[0], -2 * x[0]), ["a"])[2]
    (Piecewise((a, a > 0), (-2*a, True)),)
    >>> trace(lambda x: x[0] + x[2], ["a", "b"])
    Traceback (most recent call last):
      ...
    symmon.errors.ModelError: the function reads x[2] but inputs= names 2 symbols (a, b): give 3 names, one for each entry of x
    """
    if not callable(fn):
        raise ModelError(f"fn must be callable, got {type(fn).__name__}")
    u = as_symbols(inputs, "inputs")
    v = as_symbols(noise, "noise")
    if not u:
        raise ModelError("a model needs at least one input")
    fname = getattr(fn, "__name__", None)
    who = "the function" if fname in (None, "<lambda>") else f"the function {fname}"
    labels, sig = _labels(fn, 2 if v else 1)
    misses: list = []
    sources = [_Source(labels[0], "inputs", u, misses)] + ([_Source(labels[1], "noise", v, misses)] if v else [])
    call = [_argument(s) for s in sources] + list(args)
    # sympy's cache of expressions may hold an earlier trace's copies of the same
    # subexpressions; a lookup compares the copies by walking them as trees, exponential
    # for a traced loop.  Within one trace, every node is built from the nodes before it.
    clear_cache()
    if sig is not None:
        try:
            sig.bind(*call)
        except TypeError as exc:
            shown = ", ".join(labels + [repr(a) for a in args])
            raise ModelError(
                f"{who} cannot be called as {fname or 'fn'}({shown}): {exc}. from_function calls "
                f"fn(x, *args), or fn(x, v, *args) when noise= names the noise; give the further "
                f"arguments with args=(...)") from exc
    try:
        out = _deep_call(fn, call)
    except Exception as exc:
        if misses:
            raise _misses_error(who, misses) from exc
        named = _library_failure(exc) or _ufunc_type_error(exc)
        if named is not None:
            raise named from exc
        if isinstance(exc, IndexError) or (isinstance(exc, ValueError) and "values to unpack" in str(exc)):
            held = " and ".join(f"{s.label} holds the {len(s.names)} name{'' if len(s.names) == 1 else 's'} "
                                f"of {s.keyword}= ({', '.join(map(str, s.names))})" for s in sources)
            raise ModelError(f"{who} raised {type(exc).__name__}: {exc} ({held}; if the function "
                             f"reads more entries, give one name for each)") from exc
        raise
    if misses:
        raise _misses_error(who, misses)
    try:
        flat = np.asarray(out, dtype=object).ravel()
    except (TypeError, ValueError) as exc:
        raise ModelError(f"the traced function returned {type(out).__name__}, not an array of outputs") from exc
    if flat.size == 0:
        raise ModelError("the traced function returned no outputs")
    return u, v, tuple(_to_sympy(e) for e in flat)
