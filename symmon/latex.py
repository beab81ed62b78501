"""Numbers and text for the notebook displays (``_repr_latex_``)."""

from __future__ import annotations

import numpy as np

__all__ = ["latex_number", "latex_text"]


def latex_number(x: float, digits: int = 4) -> str:
    """A float as LaTeX math: ``1.5 \\cdot 10^{-7}`` rather than Python's ``1.5e-07``."""
    x = float(x)
    if np.isnan(x):
        return r"\mathrm{NaN}"
    if np.isinf(x):
        return r"\infty" if x > 0 else r"-\infty"
    text = f"{x:.{digits}g}"
    if "e" not in text:
        return text
    mantissa, exponent = text.split("e")
    return rf"{mantissa} \cdot 10^{{{int(exponent)}}}"


def latex_text(s: str) -> str:
    """Escape LaTeX's special characters for use inside ``\\text{...}``."""
    table = {"\\": r"\textbackslash{}", "{": r"\{", "}": r"\}", "$": r"\$", "&": r"\&", "#": r"\#",
             "%": r"\%", "_": r"\_", "^": r"\^{}", "~": r"\~{}"}
    return "".join(table.get(c, c) for c in s)
