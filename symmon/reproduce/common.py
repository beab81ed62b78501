"""Shared pieces of the reproduction commands: progress bars, the plotting backend and style."""

from __future__ import annotations

import contextlib
import math
from typing import Iterator

from ..progress import progress_bar as progress_bar

#: One look for every reproduced figure: readable sizes, light grid, no top/right frame.
STYLE = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 7.5,
    "legend.framealpha": 0.9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "savefig.dpi": 150,
}

#: The x-axis label of the α sweeps: α multiplies the input covariance of the paper's model.
ALPHA_LABEL = r"$\alpha$: scale of the input covariance, $P = \alpha\,P_0$"


@contextlib.contextmanager
def figure_style() -> Iterator[None]:
    """Apply :data:`STYLE` while a figure is drawn (matplotlib's global state is restored)."""
    import matplotlib

    with matplotlib.rc_context(STYLE):
        yield


def samples_text(n: int) -> str:
    """A sample count for a title: 10⁶ for powers of ten, 250,000 otherwise."""
    n = int(n)
    k = round(math.log10(n)) if n > 0 else 0
    if n > 0 and 10**k == n:
        sup = str(k).translate(str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹"))
        return f"10{sup}"
    return f"{n:,}"


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (a clear error if missing)."""
    try:
        import matplotlib
    except ImportError as exc:
        raise RuntimeError("plots need matplotlib: pip install 'symmon[plot]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
