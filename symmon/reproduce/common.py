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
from pathlib import Path
from typing import Iterable, Iterator

from ..core.model import Model
from ..errors import SymmonError
from ..io import save_figure
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
    "savefig.dpi": 300,
}

#: The figure formats of ``symmon reproduce --format``: PNG (raster, :data:`PNG_DPI`), or
#: PDF and SVG (vector, what a journal asks for).
FORMATS = ("png", "pdf", "svg")
#: The resolution of a reproduced PNG: print quality at the figures' 7.2 in width.
PNG_DPI = 300

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


#: Line styles and markers of curves drawn on one axes, cycled with the colours: two
#: curves that coincide (a filter the adaptive one chose throughout) still show both.
LINESTYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def curve_styles(n: int, points: int) -> list[dict]:
    """Keyword arguments of ``plot`` for n curves of ``points`` points on one axes: Okabe–Ito
    colours, line styles and open markers in turn; each curve's markers at its own points
    (every max(n, points/10)-th, offset by its index, so the markers of coinciding curves
    never fall on each other), and each later curve drawn above the earlier ones with a
    thinner line, so that a curve under another still shows at its edges."""
    colours = [c for name, c in OKABE_ITO.items() if name != "yellow"]  # yellow is faint on white
    step = max(n, points // 10, 1)
    return [{"color": colours[i % len(colours)], "ls": LINESTYLES[i % len(LINESTYLES)],
             "marker": MARKERS[i % len(MARKERS)], "ms": 4.5, "mfc": "none",
             "markevery": (i % step, step), "lw": max(0.8, 2.6 - 0.3 * i), "zorder": 3 + i} for i in range(n)]


def check_format(fmt: str) -> str:
    """``fmt`` if it is one of :data:`FORMATS`, else a SymmonError naming them."""
    if fmt not in FORMATS:
        raise SymmonError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    return fmt


def with_format(names: Iterable[str], fmt: str) -> tuple[str, ...]:
    """The output names of a figure module (``OUTPUTS``, its figures as ``.png``) for the
    figure format ``fmt``."""
    check_format(fmt)
    return tuple(n[:-len(".png")] + "." + fmt if n.endswith(".png") else n for n in names)


def save_reproduced(fig, path: Path, fmt: str = "png", title: str = "", caption: str = "") -> Path:
    """Save a reproduced figure as ``path`` with the suffix of ``fmt``: a PNG at
    :data:`PNG_DPI` dpi, or a vector PDF or SVG; its title and caption go into the file's
    metadata (PNG text chunks, PDF Title and Subject, SVG title and description), and no
    date, so that the same figure gives the same file."""
    check_format(fmt)
    path = Path(path).with_suffix("." + fmt)
    if fmt == "png":
        meta = png_metadata(title, caption) if title else {}
        return save_figure(fig, path, dpi=PNG_DPI, metadata=meta or None)
    if fmt == "pdf":
        meta = {"Title": title, "Subject": caption, "CreationDate": None, "ModDate": None}
    else:
        meta = {"Title": title, "Description": caption, "Date": None}
    return save_figure(fig, path, metadata={k: v for k, v in meta.items() if v != ""})


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
