"""Symbols of a model's declaration: names or sympy Symbols, as one validated tuple."""

from __future__ import annotations

from typing import Iterable

import sympy as sp

from ..errors import ModelError

__all__ = ["as_symbols"]


def as_symbols(items: Iterable | None, what: str) -> tuple[sp.Symbol, ...]:
    """``items`` (None, one symbol or name, or a sequence of them) as a tuple of sympy Symbols;
    a name becomes a real Symbol.  ``what`` names the argument in the error."""
    if items is None:
        return ()
    if isinstance(items, (sp.Basic, str)):
        items = [items]
    out = []
    for s in items:
        if isinstance(s, str):
            s = sp.Symbol(s, real=True)
        if not isinstance(s, sp.Symbol):
            raise ModelError(f"{what} must be sympy Symbols, got {s!r} ({type(s).__name__})")
        out.append(s)
    return tuple(out)
