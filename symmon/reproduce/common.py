"""Shared pieces of the reproduction commands: progress bars, the plotting backend and style.

Every figure the package draws (``symmon reproduce`` and the ``--plot`` of the other
commands) follows one style, kept here: no title (the caption, ``fig1.caption()``
and ``fig2.caption()``, goes into the PNG's metadata and the documentation); PNGs at
:data:`PNG_DPI` dpi; the legend outside the axes (:func:`legend_outside`), so that it never
covers a curve; plain tick labels on log axes (0.2, 3, 100, not 2×10⁻¹:
:func:`plain_log_ticks`); panel letters (:func:`label_panels`); colours from the Okabe–Ito
palette, which stays distinct under the common colour-vision deficiencies, each curve also
differing by its line style or marker, so that no distinction rests on colour alone; and one
colour, marker and line style per filter (:data:`FILTER_STYLES`), the same in every panel
and every figure.

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


#: One look per filter, by its name in ``symmon filter`` and the reproductions: an
#: Okabe–Ito colour, a marker and a line style, the same in every panel and figure. Two
#: filters share a colour only with another marker and line style (``gsf`` is the MoN-split
#: Gaussian-sum filter of ``symmon filter``, ``mon_gsf`` of ``symmon reproduce bot``).
FILTER_STYLES: dict[str, tuple[str, str, str]] = {
    "ekf": ("vermillion", "o", "-"),
    "ekf2": ("orange", "s", "--"),
    "ukf": ("blue", "^", "-."),
    "ckf": ("sky blue", "D", ":"),
    "gh": ("reddish purple", "v", "--"),
    "adaptive": ("black", "*", "-"),
    "gsf": ("bluish green", "h", "-"),
    "mon_gsf": ("bluish green", "h", "-"),
    "rp_gsf": ("sky blue", "<", "-."),
    "pf": ("black", "x", ":"),
    "rpf": ("orange", ">", "--"),
    "iekf": ("orange", "P", ":"),
    "imm": ("reddish purple", "X", "-"),
}
#: The filters' labels (``filter_label`` of a transform, the adaptive filter's choices) by
#: their short names in :data:`FILTER_STYLES`.
FILTER_LABELS = {"ghkf": "gh"}
#: The look of a filter name not in :data:`FILTER_STYLES` (a custom rule of the adaptive filter).
OTHER_FILTER = ("grey", ".", (0, (3, 1, 1, 1)))


def filter_key(name: str) -> str | None:
    """The key of :data:`FILTER_STYLES` of a filter ``name`` (``"EKF"``, ``"ukf"``,
    ``"GHKF(order=3)"``, ``"UKF(alpha=1, …)"``), or None when it has none."""
    key = str(name).split("(", 1)[0].strip().lower()
    key = FILTER_LABELS.get(key, key)
    return key if key in FILTER_STYLES else None


def filter_style(name: str, points: int) -> dict:
    """Keyword arguments of ``plot`` for the filter ``name`` on a curve of ``points`` points:
    its colour, marker and line style (:data:`FILTER_STYLES`), open markers at every
    max(11, points/10)-th point, offset by the filter's place in the table (the markers of two
    curves that coincide, the adaptive filter on the rule it chose, never fall on each
    other), and each later filter drawn above the earlier ones with a thinner line, so that a
    curve under another still shows at its edges. A name not in the table gets
    :data:`OTHER_FILTER`."""
    key = filter_key(name)
    i = list(FILTER_STYLES).index(key) if key is not None else len(FILTER_STYLES)
    colour, marker, ls = FILTER_STYLES[key] if key is not None else OTHER_FILTER
    step = max(len(FILTER_STYLES) + 1, points // 10, 1)
    return {"color": OKABE_ITO.get(colour, colour), "ls": ls, "marker": marker, "ms": 4.5, "mfc": "none",
            "markevery": (i % step, step), "lw": max(0.8, 2.4 - 0.12 * i), "zorder": 3 + i}


def legend_outside(ax, **kwargs):
    """The legend of ``ax`` to the right of its axes, top-aligned: outside the data area, so
    that it covers no curve (``kwargs`` go to ``ax.legend``)."""
    opts = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}
    return ax.legend(**{**opts, **kwargs})


def plain_log_ticks(ax, axis: str = "y") -> None:
    """Plain numbers (0.2, 3, 100; 1e-05 far from 1) on the log ``axis`` of ``ax``, not
    matplotlib's 2×10⁻¹: the major ticks all labelled, the minor ones where matplotlib would
    label them (some of 2 … 9 when the axis spans less than a decade)."""
    from matplotlib.ticker import LogFormatter

    class Plain(LogFormatter):
        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    target = ax.yaxis if axis == "y" else ax.xaxis
    target.set_major_formatter(Plain(labelOnlyBase=False))
    target.set_minor_formatter(Plain(labelOnlyBase=False, minor_thresholds=(1, 0.4)))


def legend_below(fig, handles, ncol: int, height: float):
    """One legend of ``handles`` under all the axes of ``fig``, in ``ncol`` columns: the axes
    are laid out above the bottom ``height`` (a fraction of the figure), the legend in it."""
    fig.tight_layout(rect=(0, height, 1, 1))
    return fig.legend(handles=handles, loc="lower center", ncol=ncol, frameon=False, bbox_to_anchor=(0.5, 0.0))


def label_panels(axes, names: Iterable[str] = (), size: float = 9) -> None:
    """Panel letters (a), (b), … above the top left corner of each of ``axes``, in order,
    each followed by its name in ``names``, if given (what a title would say)."""
    names = list(names)
    for i, (letter, ax) in enumerate(zip("abcdefghijklmnopqrstuvwxyz", axes)):
        name = f" {names[i]}" if i < len(names) else ""
        ax.text(0.0, 1.03, f"({letter})", transform=ax.transAxes, fontsize=size, fontweight="bold",
                ha="left", va="bottom")
        if name:
            ax.annotate(name, (0.0, 1.03), xycoords="axes fraction", xytext=(2.2 * size, 0),
                        textcoords="offset points", fontsize=size - 1, ha="left", va="bottom")


def save_plot(fig, path) -> Path:
    """Save a figure of a command's ``--plot`` (any format of :func:`symmon.io.save_figure`),
    a raster one at :data:`PNG_DPI` dpi."""
    return save_figure(fig, path, dpi=PNG_DPI)


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
