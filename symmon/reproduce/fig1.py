"""Figure 1 of Straka & Havlík (2024): the MSE-based MoN depends on the bearing unit.

The polar example (14)–(16): u = [x, y] ~ N([1, 10], α diag(1, 100)) km, y = [range,
bearing].  For each α the joint moments of [y; u] are computed once (Monte Carlo by
default, with common random numbers across α); the normalised Liu–Li MoN (17) is then
evaluated with the bearing in rad, in deg, and in every unit from 0.1 nrad to 10 Grad
(the band), by rescaling the moments exactly.  The unitless MoN with W^full (43) is the
same in every unit.  TT2 and UT curves are drawn beside Monte Carlo.

The bearing is declared an angle (:data:`MODEL`): its mean is circular and its deviations
are wrapped, so that at large α, where the samples straddle the cut at ±π, a sample just
past the cut counts as a small deviation, not as one of almost 2π.  Where no sample
reaches the cut (α ≲ 0.3, the α = 0.17 of Sec. II-B included) this changes nothing.

:func:`headline` gives the numbers that Sec. II-B quotes, beside the paper's (the normalised
MoN at α = 0.17 in rad and in deg), and the range of the unitless MoN; ``symmon reproduce
fig1`` prints them before the files it wrote.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..io import check_output_set, write_csv
from ..measures.formula import mon_from_moments
from ..core.problems import polar
from ..propagation.front import propagate
from ..transforms.taylor import TT2
from ..transforms.unscented import UT
from ..transforms.montecarlo import MonteCarlo
from ..transforms.stats import jackknife, moments_of
from .common import (ALPHA_LABEL, OKABE_ITO, figure_style, label_panels, legend_below, plain_log_ticks,
                     progress_bar, pyplot, save_reproduced, with_angles, with_format)

__all__ = ["OUTPUTS", "run", "curves", "caption", "headline", "ALPHAS", "UNIT_SIZES", "COLUMNS", "MODEL",
           "PAPER_ALPHA", "PAPER_LIU_LI"]

#: The files :func:`run` writes into its directory, checked before any work
#: (:func:`symmon.io.check_output_set`; the command line checks them with its other outputs).
OUTPUTS = ("fig1.png", "fig1.csv")

#: α grid of Figure 1, [1e-4, 1e2]: 6 points per decade, 24 per decade over [1e-2, 1], where
#: the deg curve rises from 0.08 to its peak near α = 0.25 and falls again, and the α = 0.17
#: that the text quotes.
ALPHAS = np.unique(np.concatenate([np.logspace(-4, 2, 37), np.logspace(-2, 0, 49), [0.17]]).round(12))

#: The α at which Sec. II-B quotes the normalised MoN (17), and the values it quotes there
#: (Straka & Havlík 2024, Sec. II-B: "10 %" with the bearing in rad, "80 %" in deg).
PAPER_ALPHA = 0.17
PAPER_LIU_LI = {"rad": 0.10, "deg": 0.80}

#: The polar model (16), bearing in rad, with the bearing declared an angle (module notes).
MODEL = with_angles(polar().model, [1])
#: Bearing unit sizes in rad: from 0.1 nrad to 10 Grad.
UNIT_SIZES = np.logspace(-10, 10, 81)


#: The CSV's columns: key of :func:`curves` → header that says what the column holds.
COLUMNS = {
    "alpha": "alpha (scale of the input covariance: P = alpha P0)",
    "liu_rad": "Liu-Li normalised MoN (8) with the bearing in rad: Monte Carlo",
    "liu_rad_se": "Liu-Li normalised MoN (8) with the bearing in rad: Monte Carlo standard error",
    "liu_deg": "Liu-Li normalised MoN (8) with the bearing in deg: Monte Carlo",
    "liu_deg_se": "Liu-Li normalised MoN (8) with the bearing in deg: Monte Carlo standard error",
    "band_lo": "Liu-Li normalised MoN (8): least over bearing units 0.1 nrad to 10 Grad (Monte Carlo)",
    "band_hi": "Liu-Li normalised MoN (8): greatest over bearing units 0.1 nrad to 10 Grad (Monte Carlo)",
    "full": "unitless MoN with W^full (43): Monte Carlo",
    "full_se": "unitless MoN with W^full (43): Monte Carlo standard error",
    "liu_rad_tt2": "Liu-Li normalised MoN (8) with the bearing in rad: TT2",
    "liu_deg_tt2": "Liu-Li normalised MoN (8) with the bearing in deg: TT2",
    "liu_rad_ut": "Liu-Li normalised MoN (8) with the bearing in rad: unscented transform ut1",
    "liu_deg_ut": "Liu-Li normalised MoN (8) with the bearing in deg: unscented transform ut1",
}


def _scaled(m, size: float):
    """Moments with the bearing expressed in a unit of ``size`` rad: y₂ → y₂ / size."""
    S = np.diag([1.0, 1.0 / size])
    return S @ m.cov @ S, S @ m.cross_cov


def curves(alphas=ALPHAS, samples: int = 10**6, seed: int = 0, progress: bool = True) -> dict[str, np.ndarray]:
    """The curves of Figure 1 (plus the unitless W^full MoN and TT2/UT curves)."""
    names = ["liu_rad", "liu_deg", "band_lo", "band_hi", "full", "liu_rad_tt2", "liu_deg_tt2",
             "liu_rad_ut", "liu_deg_ut", "liu_rad_se", "liu_deg_se", "full_se"]
    out = {k: np.empty(len(alphas)) for k in names}
    transforms = {"": MonteCarlo(samples, seed=seed), "_tt2": TT2(), "_ut": UT.ut1()}
    for i, a in enumerate(progress_bar(alphas, "fig1: alpha sweep", progress)):
        u = polar(a, "rad").u
        for suffix, tr in transforms.items():
            m = propagate(MODEL, u, transform=tr)
            for unit, size in (("rad", 1.0), ("deg", np.pi / 180)):
                Sgg, Sgu = _scaled(m, size)
                out[f"liu_{unit}{suffix}"][i] = mon_from_moments(Sgg, Sgu, m.input_cov, "liu-li").value
            if suffix == "":
                band = [mon_from_moments(*_scaled(m, s), m.input_cov, "liu-li").value for s in UNIT_SIZES]
                out["band_lo"][i], out["band_hi"][i] = min(band), max(band)
                out["full"][i] = mon_from_moments(m.cov, m.cross_cov, m.input_cov, "full").value
                out["liu_rad_se"][i], out["liu_deg_se"][i], out["full_se"][i] = _stderrs(m)
    out["alpha"] = np.asarray(alphas, dtype=float)
    return out


def _stderrs(m) -> tuple[float, float, float]:
    """Jackknife standard errors of the Liu–Li MoN in rad and in deg and of the W^full MoN."""
    res = []
    for size, weight in ((1.0, "liu-li"), (np.pi / 180, "liu-li"), (1.0, "full")):
        S = np.diag([1.0, 1.0 / size])

        def val(loo, S=S, weight=weight):
            # The replicates hold [y; u; sin y₂; cos y₂]: the circular moments of the bearing.
            _, Cy, Cyu, Cu = moments_of(loo, 2, 2, sorted(MODEL.angle_outputs))
            return np.array([mon_from_moments(S @ a @ S, S @ b, c, weight).value for a, b, c in zip(Cy, Cyu, Cu)])

        res.append(float(jackknife(m.replicates, val)))
    return res[0], res[1], res[2]


def caption(samples: int = 10**6, seed: int = 0) -> str:
    """The caption of Figure 1 (saved in the PNG's metadata; the README and the docs quote it)."""
    return ("Figure 1 (Straka & Havlík 2024, polar example (14)–(16)). The normalised MSE-based MoN "
            "(8), (17) of y = [range, bearing] against the spread α of u ~ N([1, 10] km, α diag(1, 100) km²), "
            "with the bearing in rad (blue, circles) and in deg (vermillion, squares); grey: its range over "
            "every bearing unit from 0.1 nrad to 10 Grad. Black: the unitless MoN with W^full (43), the same "
            "in every unit. Solid lines: Monte Carlo with "
            f"{samples:,} samples per α (seed {seed}, common random numbers across α), with their ±2 SE "
            "bands, whose width the lower panel shows; dashed: TT2; dotted: the unscented transform ut1 "
            "(open markers). Panel (a): the MoNs; (b): the Monte Carlo 2 SE. The bearing is declared an "
            "angle (circular mean, wrapped deviations). The dash-dotted line marks α = 0.17, where Sec. II-B "
            "quotes 10 % (rad) and 80 % (deg).")


def headline(c: dict[str, np.ndarray], samples: int = 10**6, seed: int = 0) -> list[str]:
    """The numbers of Figure 1 that Sec. II-B quotes, beside the paper's, as lines of text.

    At the α of the curves ``c`` nearest :data:`PAPER_ALPHA` (0.17 on :data:`ALPHAS`): the
    normalised Liu–Li MoN (17) with the bearing in rad and in deg, with their Monte Carlo
    2 SE, beside :data:`PAPER_LIU_LI`, and its range over every bearing unit; then the range
    of the unitless MoN with W^full (43) over the α of ``c``, the same in every unit (the
    paper's Figure 1 does not show it).

    Parameters
    ----------
    c : dict of numpy.ndarray
        The curves of :func:`curves`.
    samples, seed : int
        The Monte Carlo samples per α and the seed of ``c`` (named in the first line).

    Returns
    -------
    list of str
    """
    a = np.asarray(c["alpha"], dtype=float)
    i = int(np.argmin(np.abs(np.log(a / PAPER_ALPHA))))
    at = "" if a[i] == PAPER_ALPHA else f" (the grid's nearest to the paper's {PAPER_ALPHA:g})"
    lines = [f"Figure 1 (Sec. II-B) at alpha = {a[i]:.4g}{at}: Monte Carlo, {samples:,} samples per alpha, "
             f"seed {seed}"]
    for unit in ("rad", "deg"):
        value, se = c[f"liu_{unit}"][i], c[f"liu_{unit}_se"][i]
        lines.append(f"  normalised Liu-Li MoN (17), bearing in {unit}: {value:.3f} ± {2 * se:.3f} (2 SE); "
                     f"paper: {100 * PAPER_LIU_LI[unit]:.0f} %")
    lines.append(f"  normalised Liu-Li MoN (17), any bearing unit from 0.1 nrad to 10 Grad: {c['band_lo'][i]:.3f} "
                 f"to {c['band_hi'][i]:.3f}")
    lines.append(f"  unitless MoN with W^full (43), any unit: {c['full'][i]:.3f} ± {2 * c['full_se'][i]:.3f} (2 SE)")
    full = c["full"]
    lines.append(f"unitless MoN with W^full (43) over alpha in [{a.min():g}, {a.max():g}]: {full.min():.3f} to "
                 f"{full.max():.3f}, the same in every unit (the paper's Figure 1 does not show it)")
    return lines


def run(outdir: str | Path = "results", samples: int = 10**6, seed: int = 0, progress: bool = True,
        alphas=ALPHAS, fmt: str = "png", report: Callable[[str], Any] | None = None) -> list[Path]:
    """Reproduce Figure 1: write ``fig1.png`` (or ``.pdf``, ``.svg``: ``fmt``) and
    ``fig1.csv`` into ``outdir``; ``report`` (``print`` on the command line), if given, is
    called with each line of :func:`headline`, after the files are written."""
    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    c = curves(alphas, samples, seed, progress)
    csv = write_csv(outdir / "fig1.csv", list(COLUMNS.values()), zip(*[c[k] for k in COLUMNS]))
    plt = pyplot()
    with figure_style():
        fig = _plot(plt, c)
    png = save_reproduced(fig, outdir / "fig1.png", fmt, 
                          "Figure 1: the MSE-based MoN and the bearing unit",
                          caption(samples, seed))
    plt.close(fig)
    if report is not None:
        for line in headline(c, samples, seed):
            report(line)
    return [png, csv]


def _plot(plt, c: dict[str, np.ndarray]):
    """Figure 1 from the curves: MoNs above, the Monte Carlo 2 SE below; no title (the caption)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig, (ax, ax_se) = plt.subplots(2, 1, figsize=(7.0, 6.5), sharex=True, height_ratios=[3.2, 1])
    a = c["alpha"]
    ax.fill_between(a, c["band_lo"], c["band_hi"], color="0.87", lw=0)
    quantities = (("liu_rad", OKABE_ITO["blue"], "o", "Liu–Li (8), bearing in rad"),
                  ("liu_deg", OKABE_ITO["vermillion"], "s", "Liu–Li (8), bearing in deg"),
                  ("full", OKABE_ITO["black"], None, "unitless, $W^{full}$ (43), any unit"))
    marks = dict(markevery=0.06, ms=3.5)
    for key, color, marker, _ in quantities:
        mc, se = c[key], c[f"{key}_se"]
        ax.fill_between(a, mc - 2 * se, mc + 2 * se, color=color, alpha=0.35, lw=0)
        ax.semilogx(a, mc, "-", color=color, lw=1.8 if marker is None else 1.2, marker=marker, **marks)
        if key != "full":
            for suffix, ls in (("_tt2", "--"), ("_ut", ":")):
                ax.semilogx(a, c[key + suffix], ls, color=color, lw=1.1, marker=marker, mfc="white", **marks)
        ax_se.semilogx(a, 2 * se, "-", color=color, lw=1.2, marker=marker, **marks)
    for axis in (ax, ax_se):
        axis.axvline(0.17, color="0.3", lw=0.7, ls="-.")
    ax.annotate(r"$\alpha = 0.17$ (Sec. II-B)", (0.17, 1.0), xytext=(3, 0), textcoords="offset points",
                fontsize=7, va="top", ha="left")
    handles = [Patch(color="0.87", label="Liu–Li (8), any bearing unit, 0.1 nrad to 10 Grad")]
    handles += [Line2D([], [], color=col, marker=mk, ms=3.5, lw=1.8 if mk is None else 1.2, label=lab)
                for _, col, mk, lab in quantities]
    # One legend under both panels: what is drawn, and by which rule.
    handles += [Line2D([], [], color="0.35", ls="-", lw=1.2, label="Monte Carlo, band ±2 SE"),
             Line2D([], [], color="0.35", ls="--", lw=1.1, mfc="white", marker="o", ms=3.5, label="TT2"),
             Line2D([], [], color="0.35", ls=":", lw=1.1, mfc="white", marker="o", ms=3.5,
                    label="unscented transform (ut1)")]
    ax.set_ylabel("normalised MoN (0 = affine)")
    ax.set_ylim(0, 1.02)
    ax_se.set_yscale("log")
    plain_log_ticks(ax_se)
    plain_log_ticks(ax_se, "x")
    ax_se.set_ylabel("2 SE (Monte Carlo)")
    ax_se.set_xlabel(ALPHA_LABEL + r", $P_0 = \mathrm{diag}(1, 100)$ km$^2$")
    ax.set_xlim(a.min(), a.max())
    label_panels((ax, ax_se))
    fig.align_ylabels()
    legend_below(fig, handles, ncol=2, height=0.13)
    return fig
