"""Where a filter's NaN comes from: the model (f or h), the output and the operation.

When a compiled step produces NaN or inf, :meth:`NonlinearKalmanFilter.filter
<symmon.NonlinearKalmanFilter.filter>` evaluates f at the last finite estimate and h at the
prediction, each output and its derivatives by the states, and walks the first one that is
not a finite real number down to the operation whose arguments are finite but whose value is
not: ``1/om`` at ``om = 0`` in a coordinated turn's sin(ω dt)/ω, ``sqrt`` of a negative
number, ``log`` of 0.  The step's other causes (an S that is not positive definite) remain
when nothing is found.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from ...core.model import Model

__all__ = ["locate_nonfinite", "MAX_NODES"]

#: The largest expression (in nodes) that is walked: a traced model of millions of nodes is not.
MAX_NODES = 20_000


def _value(expr: sp.Expr, subs: dict) -> complex | None:
    """``expr`` at ``subs`` as a complex number (None: not a number, e.g. unevaluated)."""
    try:
        return complex(sp.N(expr.xreplace(subs)))
    except (TypeError, ValueError):
        return None


def _bad(z: complex | None) -> bool:
    return z is not None and (not (np.isfinite(z.real) and np.isfinite(z.imag)) or abs(z.imag) > 1e-12 * max(1.0, abs(z.real)))


def _text(z: complex) -> str:
    if not (np.isfinite(z.real) and np.isfinite(z.imag)):
        return "not finite (NaN or inf)"
    return f"not real ({z:.6g})"


def _operation(expr: sp.Expr, subs: dict) -> str:
    """The innermost subexpression of ``expr`` whose arguments are finite reals but whose value
    is not, described with its arguments' values."""
    node = expr
    while True:
        inner = next((a for a in node.args if isinstance(a, sp.Expr) and not a.is_Atom and _bad(_value(a, subs))), None)
        if inner is None:
            break
        node = inner
    args = [a for a in node.free_symbols if a in subs]
    at = ", ".join(f"{a} = {float(subs[a]):.6g}" for a in sorted(args, key=str))
    if node.is_Pow and node.exp.is_negative and _value(node.base, subs) == 0:
        what = "a division by zero"
    elif node.is_Pow and node.exp == sp.Rational(1, 2):
        what = "sqrt of a negative number"
    elif isinstance(node, sp.log):
        what = "log of a number ≤ 0"
    else:
        what = f"{node.func.__name__} undefined"
    return f"{what}: {node}" + (f" at {at}" if at else "")


def locate_nonfinite(model: Model, which: str, point: np.ndarray, params: dict[str, float]) -> str:
    """A sentence naming the first output of ``model`` (or derivative of one by a state) that is
    not a finite real number at the state ``point`` (noise at 0), and the operation; "" when
    every one is finite, or the model is too large to walk (:data:`MAX_NODES`)."""
    subs = {s: sp.Float(float(v)) for s, v in zip(model.inputs, point)}
    subs.update({s: sp.Float(0.0) for s in model.noise})
    subs.update({s: sp.Float(float(params[str(s)])) for s in model.params if str(s) in params})
    state = ", ".join(f"{s} = {float(v):.6g}" for s, v in zip(model.inputs, point))
    for i, expr in enumerate(model.outputs):
        if sp.count_ops(expr) > MAX_NODES:
            return ""
        z = _value(expr, subs)
        if _bad(z):
            return (f"{which} {model.name!r}, output {i} ({expr}), is {_text(z)} at the state [{state}]: "
                    f"{_operation(expr, subs)}")
        for s in model.inputs:
            d = sp.diff(expr, s)
            z = _value(d, subs)
            if _bad(z):
                return (f"the derivative of {which} {model.name!r}, output {i} ({expr}), by {s} is {_text(z)} at the "
                        f"state [{state}]: {_operation(d, subs)}")
    return ""
