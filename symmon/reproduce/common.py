"""Shared pieces of the reproduction commands: progress bars, the plotting backend and style.

The figures are drawn as a journal prints them: no title (the caption, :data:`fig1.CAPTION`
and :data:`fig2.CAPTION`, goes into the PNG's metadata and the documentation), the legend
inside the axes or below them, and colours from the Okabe–Ito palette, which stays distinct
under the common colour-vision deficiencies; each curve also differs by its line style or
marker, so that no distinction rests on colour alone.

References
----------
M. Okabe, K. Ito, "Color Universal Design (CUD): how to make figures and presentations that
are friendly to colorblind people", J*FLY, 2008. https://jfly.uni-koeln.de/color/
"""

from __future__ import annotations

import contextlib
import math
from typing import Iterator

from ..core.model import Model
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

#: The Okabe–Ito palette (Okabe & Ito 2008), by name.
OKABE_ITO = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky blue": "#56B4E9",
    "bluish green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish purple": "#CC79A7",
}

#: The x-axis label of the α sweeps: α multiplies the input covariance of the paper's model.
ALPHA_LABEL = r"$\alpha$: scale of the input covariance, $P = \alpha\,P_0$"


@contextlib.contextmanager
def figure_style() -> Iterator[None]:
    """Apply :data:`STYLE` while a figure is drawn (matplotlib's global state is restored)."""
    import matplotlib

    with matplotlib.rc_context(STYLE):
        yield


def with_angles(model: Model, angles: list[int]) -> Model:
    """``model`` with the outputs ``angles`` declared angles (the papers' bearings are plain
    atan2 expressions): circular means and wrapped deviations where samples reach ±π."""
    return Model(model.inputs, model.outputs, name=f"{model.name}_angle", angles=angles or None)


def png_metadata(title: str, caption: str) -> dict[str, str]:
    """PNG text chunks of a reproduced figure: its title and its caption (``Description``)."""
    return {"Title": title, "Description": caption}


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
