"""Where g is not smooth: the kinks of ``Abs``, ``Max``, ... and the smooth branch of g near a point.

TT2 and its unit-invariance proofs need g twice differentiable at the mean (Straka & Havlík
2024, Section III: the moments of the second-order Taylor expansion). A model built with
``Abs``, ``sign``, ``Max``, ``Min``, ``Heaviside``, ``floor``, ``ceiling``, ``frac``,
``Mod`` or ``Piecewise`` is smooth except on a set of measure zero, the *kinks*: where an
argument of ``Abs``, ``sign`` or ``Heaviside`` is 0, where two arguments of ``Max`` or
``Min`` tie for the extreme, where an argument of ``floor`` is an integer, on the boundary of
a ``Piecewise`` condition. sympy differentiates those functions into ``sign``,
``Heaviside`` and ``DiracDelta`` (or leaves ``Derivative(floor(x), x)`` unevaluated), which
no numeric evaluator can take at a kink.

Off the kinks g agrees, in a neighbourhood of the point, with one smooth branch:
``Abs(a)`` is ``a`` or ``-a``, ``Max(a, b)`` the larger argument, ``floor(a)`` a constant,
``Piecewise`` the branch whose condition holds. Its value, Jacobian and Hessians at the point
are those of g, and so are the TT2 moments, which depend on nothing else. :func:`localize`
returns that branch, or raises :class:`~symmon.errors.NonSmoothModelError` on a kink (which
side is taken is decided exactly, in rational arithmetic where the point is rational).

References
----------
J. Straka, J. Havlík, "Design of Unitless Normalized Measure of Nonlinearity for State
Estimation", FUSION 2024, arXiv:2410.13539, Sections III–IV.
"""

from __future__ import annotations

from itertools import combinations
from typing import Iterable, Mapping

import sympy as sp

from ..errors import NonSmoothModelError

__all__ = ["NONSMOOTH", "UNDIFFERENTIATED", "nonsmooth_atoms", "kink_text", "localize"]

#: The sympy functions that are not smooth everywhere (kinks or jumps on a set of measure zero).
NONSMOOTH = (sp.Abs, sp.sign, sp.Max, sp.Min, sp.Heaviside, sp.DiracDelta, sp.floor, sp.ceiling,
             sp.frac, sp.Mod, sp.Piecewise)
#: Those whose derivatives sympy leaves unevaluated (``Derivative(floor(x), x)``).
UNDIFFERENTIATED = (sp.floor, sp.ceiling, sp.frac, sp.Mod)

#: Below this magnitude (50-digit evaluation) a kink argument is taken to be 0: the side of
#: the kink cannot be told, so the point is refused rather than guessed.
_ZERO = sp.Float("1e-40")


def nonsmooth_atoms(exprs: Iterable[sp.Expr]) -> list[sp.Expr]:
    """The calls of the functions of :data:`NONSMOOTH` in ``exprs``, outermost first, no repeats."""
    found: list[sp.Expr] = []
    for e in exprs:
        for node in sp.preorder_traversal(sp.sympify(e)):
            if isinstance(node, NONSMOOTH) and node not in found:
                found.append(node)
    return found


def _relationals(cond: sp.Basic) -> list[sp.core.relational.Relational]:
    return [r for r in sp.preorder_traversal(cond) if isinstance(r, sp.core.relational.Relational)]


def kink_text(atom: sp.Expr) -> str:
    """Where ``atom`` is not smooth, in words: ``"x = 0"``, ``"x = y"``, ``"x is an integer"``."""
    if isinstance(atom, (sp.Abs, sp.sign, sp.Heaviside, sp.DiracDelta)):
        return f"{atom.args[0]} = 0"
    if isinstance(atom, (sp.Max, sp.Min)):
        return " or ".join(f"{a} = {b}" for a, b in combinations(atom.args, 2))
    if isinstance(atom, (sp.floor, sp.ceiling, sp.frac)):
        return f"{atom.args[0]} is an integer"
    if isinstance(atom, sp.Mod):
        return f"{atom.args[0]}/{atom.args[1]} is an integer"
    if isinstance(atom, sp.Piecewise):
        edges = [f"{r.lhs} = {r.rhs}" for _, c in atom.args for r in _relationals(c)]
        return " or ".join(edges) if edges else "nowhere"
    return "unknown"


def localize(exprs: Iterable[sp.Expr], point: Mapping[sp.Symbol, sp.Expr], hint: str = "") -> list[sp.Expr]:
    """The smooth branch of each expression near ``point``: g itself in a neighbourhood of it.

    Parameters
    ----------
    exprs : iterable of sympy.Expr
    point : mapping of symbol to number
        Values of every free symbol of ``exprs`` (exact numbers keep the test of the side exact).
    hint : str
        What to do instead, appended to the message of a refusal.

    Returns
    -------
    list of sympy.Expr
        Without any function of :data:`NONSMOOTH`; equal to ``exprs`` near ``point``, with the
        same value and derivatives of every order there.

    Raises
    ------
    NonSmoothModelError
        ``point`` lies on a kink (or too close to one to tell the side), naming the function
        and the kink.
    """
    pt = {s: sp.sympify(v) for s, v in point.items()}
    memo: dict[sp.Basic, sp.Basic] = {}

    def refuse(atom: sp.Expr) -> NonSmoothModelError:
        where = ", ".join(f"{s} = {v}" for s, v in pt.items())
        return NonSmoothModelError(
            f"{atom} is not differentiable at the point ({where}): it has a kink where {kink_text(atom)}"
            + (f"; {hint}" if hint else "")
        )

    def side(a: sp.Expr, atom: sp.Expr) -> int:
        """-1 or +1: the sign of ``a`` at the point; a 0 is a kink of ``atom``."""
        v = a.xreplace(pt)
        if v.free_symbols:
            raise NonSmoothModelError(f"cannot tell the branch of {atom}: {v} has free symbols {sorted(map(str, v.free_symbols))}")
        n = sp.N(v, 50)
        if v == 0 or (n.is_number and abs(n) < _ZERO):
            raise refuse(atom)
        if not n.is_real:
            raise NonSmoothModelError(f"{atom} has a complex argument {n} at the point")
        return 1 if n > 0 else -1

    def integer_part(a: sp.Expr, atom: sp.Expr) -> sp.Integer:
        """floor(a) at the point, refusing an integer a (a jump)."""
        k = sp.floor(sp.N(a.xreplace(pt), 50))
        for edge in (k, k + 1):
            side(a - edge, atom)
        return sp.Integer(k)

    def walk(e: sp.Basic) -> sp.Basic:
        if e in memo:
            return memo[e]
        if not any(isinstance(n, NONSMOOTH) for n in sp.preorder_traversal(e)):
            out = e
        elif isinstance(e, sp.Piecewise):
            out = None
            for expr, cond in e.args:
                for r in _relationals(cond):  # on a boundary of a condition: a kink
                    side(walk(r.lhs - r.rhs), e)
                truth = cond.xreplace(pt)
                if truth not in (sp.true, sp.false):
                    truth = sp.simplify(truth)
                if truth == sp.true:
                    out = walk(expr)
                    break
                if truth != sp.false:
                    raise NonSmoothModelError(f"cannot decide the condition {cond} of {e} at the point")
            if out is None:
                raise NonSmoothModelError(f"{e} is undefined at the point: no condition holds")
        else:
            args = [walk(a) for a in e.args]
            if isinstance(e, sp.Abs):
                out = args[0] * side(args[0], e)
            elif isinstance(e, sp.sign):
                out = sp.Integer(side(args[0], e))
            elif isinstance(e, sp.Heaviside):
                out = sp.Integer(side(args[0], e) > 0)
            elif isinstance(e, sp.DiracDelta):
                side(args[0], e)
                out = sp.Integer(0)
            elif isinstance(e, (sp.Max, sp.Min)):
                # The extreme argument; a tie between it and another is a kink (ties among
                # the others are not: they do not decide the value near the point).
                vals = [sp.N(a.xreplace(pt), 50) for a in args]
                best = (max if isinstance(e, sp.Max) else min)(range(len(args)), key=lambda i: vals[i])
                for j, a in enumerate(args):
                    if j != best and sp.expand(args[best] - a) != 0:
                        side(args[best] - a, e)
                out = args[best]
            elif isinstance(e, sp.floor):
                out = integer_part(args[0], e)
            elif isinstance(e, sp.ceiling):
                out = integer_part(args[0], e) + 1
            elif isinstance(e, sp.frac):
                out = args[0] - integer_part(args[0], e)
            elif isinstance(e, sp.Mod):
                out = args[0] - args[1] * integer_part(args[0] / args[1], e)
            else:
                out = e.func(*args)
        memo[e] = out
        return out

    return [walk(sp.sympify(e)) for e in exprs]
