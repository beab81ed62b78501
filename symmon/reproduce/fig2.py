"""Figure 2 of Straka & Havlík (2024): MoNs of the BOT, GMTI and RDCOS problems.

State (44) scaled by α ∈ [0.1, 10]; measurements (45)–(47).  For each problem and α the
joint moments are computed once (Monte Carlo by default), and the unitless MoN with
W^full (43) and W^diag (42) and the original normalised MoN (8) in both unit sets of
Sec. V ([m, rad, m/s] vs [km, deg, km/h] for GMTI; [m, −] vs [km, −] for RDCOS) follow
by exact rescaling of the output moments.  TT2 and UT curves of W^full are drawn beside.

The bearings of BOT and GMTI are declared angles (:data:`ANGLES`), as in Figure 1; over the
prior (44) they stay far from the cut at ±π (at α = 10, GMTI's bearing from the sensor is
5 standard deviations from it), so the declaration changes the MoNs by less than 1e-9.
The curves rise monotonically with α, without a peak: 10 points per decade resolve them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io import check_output_set, write_csv
from ..measures.formula import mon_from_moments
from ..core.problems import GMTI_UNITS, RDCOS_UNITS, bot, gmti, rdcos
from ..propagation.front import propagate
from ..transforms.taylor import TT2
from ..transforms.unscented import UT
from ..transforms.montecarlo import MonteCarlo
from ..transforms.stats import jackknife, moments_of
from .common import (OKABE_ITO, figure_style, label_panels, legend_below, plain_log_ticks, progress_bar,
                     pyplot, save_reproduced, with_angles, with_format)

__all__ = ["OUTPUTS", "run", "curves", "caption", "ALPHAS", "PROBLEMS", "COLUMNS", "ANGLES"]

#: The files :func:`run` writes into its directory, checked before any work
#: (:func:`symmon.io.check_output_set`; the command line checks them with its other outputs).
OUTPUTS = ("fig2.png", "fig2.csv")

#: α grid of Figure 2, [1e-1, 1e1].
ALPHAS = np.logspace(-1, 1, 21)

#: name → (problem factory, output scale of the second unit set: y_alt = y_SI / scale)
PROBLEMS = {
    "BOT": (bot, (1.0,)),
    "GMTI": (gmti, GMTI_UNITS["km-deg-kmh"]),
    "RDCOS": (rdcos, (RDCOS_UNITS["km"], 1.0)),
}


#: The outputs of each problem that are bearings, declared angles (module notes).
ANGLES = {"BOT": [0], "GMTI": [1], "RDCOS": []}


#: The CSV's columns: key of :func:`curves` → header that says what the column holds.
#: "SI units" are [rad] for BOT, [m, rad, m/s] for GMTI, [m, -] for RDCOS; the second set
#: is [km, deg, km/h] for GMTI and [km, -] for RDCOS (Sec. V).
COLUMNS = {
    "problem": "problem: BOT (45) / GMTI (46) / RDCOS (47)",
    "alpha": "alpha (scale of the state covariance (44))",
    "full": "unitless MoN with W^full (43): Monte Carlo",
    "full_se": "unitless MoN with W^full (43): Monte Carlo standard error",
    "diag": "unitless MoN with W^diag (42): Monte Carlo",
    "diag_se": "unitless MoN with W^diag (42): Monte Carlo standard error",
    "orig": "original normalised MoN (8) in SI units: Monte Carlo",
    "orig_se": "original normalised MoN (8) in SI units: Monte Carlo standard error",
    "orig_alt": "original normalised MoN (8) in the second unit set: Monte Carlo",
    "full_tt2": "unitless MoN with W^full (43): TT2",
    "diag_tt2": "unitless MoN with W^diag (42): TT2",
    "orig_tt2": "original normalised MoN (8) in SI units: TT2",
    "full_ut": "unitless MoN with W^full (43): unscented transform ut1",
    "diag_ut": "unitless MoN with W^diag (42): unscented transform ut1",
    "orig_ut": "original normalised MoN (8) in SI units: unscented transform ut1",
}


def _value(Sgg, Sgu, Suu, weight) -> float:
    return float(mon_from_moments(Sgg, Sgu, Suu, weight).value)


def _row(m, Suu, scale) -> dict[str, float]:
    S = np.diag(1.0 / np.asarray(scale))
    return {
        "full": _value(m.cov, m.cross_cov, Suu, "full"),
        "diag": _value(m.cov, m.cross_cov, Suu, "diag"),
        "orig": _value(m.cov, m.cross_cov, Suu, "liu-li"),
        "orig_alt": _value(S @ m.cov @ S, S @ m.cross_cov, Suu, "liu-li"),
    }


def _stderr(m, ny: int, weight: str, angles: list[int]) -> float:
    def val(loo):
        # The replicates hold [y; u; sin y_A; cos y_A]: the circular moments of the bearings.
        _, Cy, Cyu, Cu = moments_of(loo, ny, m.input_cov.shape[0], angles)
        return np.array([_value(a, b, c, weight) for a, b, c in zip(Cy, Cyu, Cu)])

    return float(jackknife(m.replicates, val))


def curves(alphas=ALPHAS, samples: int = 10**6, seed: int = 0, progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """The curves of Figure 2 for each problem: keys full, diag, orig, orig_alt (+ _se, _tt2, _ut)."""
    out: dict[str, dict[str, np.ndarray]] = {}
    jobs = [(name, i, a) for name in PROBLEMS for i, a in enumerate(alphas)]
    for name in PROBLEMS:
        out[name] = {"alpha": np.asarray(alphas, dtype=float)}
    for name, i, a in progress_bar(jobs, "fig2: problems x alpha", progress):
        factory, scale = PROBLEMS[name]
        prob = factory(a)
        model = with_angles(prob.model, ANGLES[name])
        cur = out[name]
        m = propagate(model, prob.u, transform=MonteCarlo(samples, seed=seed))
        for key, val in _row(m, m.input_cov, scale).items():
            cur.setdefault(key, np.empty(len(alphas)))[i] = val
        for w in ("full", "diag", "orig"):
            cur.setdefault(f"{w}_se", np.empty(len(alphas)))[i] = _stderr(m, model.n_y, {"orig": "liu-li"}.get(w, w),
                                                                           ANGLES[name])
        for suffix, tr in (("tt2", TT2()), ("ut", UT.ut1())):
            mt = propagate(model, prob.u, transform=tr)
            for key, val in _row(mt, mt.input_cov, scale).items():
                cur.setdefault(f"{key}_{suffix}", np.empty(len(alphas)))[i] = val
    return out


def intervals(c: dict[str, dict[str, np.ndarray]]) -> dict[str, tuple[float, float]]:
    """The range of the unitless W^full MoN over the α grid, per problem (Sec. V's intervals)."""
    return {name: (float(v["full"].min()), float(v["full"].max())) for name, v in c.items()}


def run(outdir: str | Path = "results", samples: int = 10**6, seed: int = 0, progress: bool = True,
        alphas=ALPHAS, fmt: str = "png") -> list[Path]:
    """Reproduce Figure 2: write ``fig2.png`` (or ``.pdf``, ``.svg``: ``fmt``) and
    ``fig2.csv`` into ``outdir``."""
    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    c = curves(alphas, samples, seed, progress)
    keys = list(COLUMNS)[2:]
    rows = [[name, c[name]["alpha"][i]] + [c[name][k][i] for k in keys]
            for name in c for i in range(len(c[name]["alpha"]))]
    csv = write_csv(outdir / "fig2.csv", list(COLUMNS.values()), rows)
    plt = pyplot()
    with figure_style():
        fig = _plot(plt, c)
    png = save_reproduced(fig, outdir / "fig2.png", fmt, 
                          "Figure 2: MoNs of the BOT, GMTI and RDCOS problems",
                          caption(samples, seed))
    plt.close(fig)
    return [png, csv]


#: W^full by TT2 and by the UT: colour, open marker and the α at which it is drawn (apart
#: from each other and from the Monte Carlo curve's markers).
OTHER_RULES = {"tt2": (OKABE_ITO["bluish green"], "D", (1, 4)), "ut": (OKABE_ITO["reddish purple"], "v", (3, 4))}

#: The second unit set of each problem (Sec. V), as the caption names it; BOT has none.
ALT_UNITS = {"BOT": "", "GMTI": "km, deg, km/h", "RDCOS": "km, –"}


def caption(samples: int = 10**6, seed: int = 0) -> str:
    """The caption of Figure 2 (saved in the PNG's metadata; the README quotes its numbers)."""
    return ("Figure 2 (Straka & Havlík 2024, Sec. V). Measures of nonlinearity of the BOT (45), GMTI (46) "
            "and RDCOS (47) measurements at the state (44) with its covariance scaled by α: the unitless MoN "
            "with W^full (43) (black) and with W^diag (42) (vermillion, squares), and the original "
            "normalised MoN (8) in SI units (blue, circles) and in the second unit set of Sec. V (sky blue, "
            "triangles: [km, deg, km/h] for GMTI, [km, –] for RDCOS). Solid lines: Monte Carlo with "
            f"{samples:,} samples per point (seed {seed}), with their ±2 SE bands, whose width the lower "
            "panels show; dashed (bluish green, diamonds) and dotted (reddish purple, triangles): W^full by TT2 "
            "and by the unscented transform ut1, drawn above the Monte Carlo curve. Panels (a)–(c): the MoNs; "
            "(d)–(f): the Monte Carlo 2 SE. BOT's output "
            "is scalar, so its three MoNs coincide. Bearings are declared angles.")


def _plot(plt, c: dict[str, dict[str, np.ndarray]]):
    """Figure 2: one column per problem, MoNs above and the Monte Carlo 2 SE below; no title."""
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(2, 3, figsize=(7.2, 4.4), sharex=True, sharey="row", height_ratios=[3, 1])
    # Curves that coincide (BOT's three MoNs, a scalar output) put their markers at
    # alternate α, so that each stays visible on the others.
    mark_at = {"full": None, "diag": (0, 3), "orig": (1, 3), "orig_alt": (2, 3)}
    styles = {"full": (OKABE_ITO["black"], None, 1.8), "diag": (OKABE_ITO["vermillion"], "s", 1.2),
              "orig": (OKABE_ITO["blue"], "o", 1.2), "orig_alt": (OKABE_ITO["sky blue"], "^", 1.2)}
    for (ax, ax_se), name in zip(axes.T, c):
        v = c[name]
        a = v["alpha"]
        for key in ("full", "diag", "orig"):
            color, marker, lw = styles[key]
            se = v[f"{key}_se"]
            ax.fill_between(a, v[key] - 2 * se, v[key] + 2 * se, color=color, alpha=0.35, lw=0)
            ax.semilogx(a, v[key], "-", color=color, lw=lw, marker=marker, ms=3.5, markevery=mark_at[key])
            ax_se.semilogx(a, 2 * se, "-", color=color, lw=lw, marker=marker, ms=3.5, markevery=mark_at[key])
        if ALT_UNITS[name]:
            color, marker, lw = styles["orig_alt"]
            ax.semilogx(a, v["orig_alt"], "-", color=color, lw=lw, marker=marker, ms=3.5,
                        markevery=mark_at["orig_alt"])
            ax.text(0.97, 0.04, f"second unit set: {ALT_UNITS[name]}", transform=ax.transAxes, fontsize=6.5,
                    ha="right", va="bottom", color=color)
        # TT2 and the UT follow W^full by Monte Carlo closely: drawn above it, in their own
        # colours, with open markers at other α, so that neither hides nor is hidden.
        for key, ls, (color, marker, every) in (("full_tt2", "--", OTHER_RULES["tt2"]),
                                                 ("full_ut", ":", OTHER_RULES["ut"])):
            ax.semilogx(a, v[key], ls, color=color, lw=1.3, marker=marker, mfc="none", ms=4, markevery=every,
                        zorder=3)
        ax.set_title({"BOT": "BOT (45)", "GMTI": "GMTI (46)", "RDCOS": "RDCOS (47)"}[name], fontsize=9)
        ax.set_ylim(bottom=0)
        ax_se.set_yscale("log")
        plain_log_ticks(ax_se)
        plain_log_ticks(ax_se, "x")
        ax_se.set_xlabel(r"$\alpha$: scale of $P$ (44)")
        if name == "BOT":
            ax.text(0.04, 0.96, "scalar output:\nthe three MoNs coincide", transform=ax.transAxes, fontsize=7,
                    va="top")
    axes[0, 0].set_ylabel("MoN (unitless, 0 = affine)")
    axes[1, 0].set_ylabel("2 SE (MC)")
    handles = [Line2D([], [], color=styles[k][0], marker=styles[k][1], ms=3.5, lw=styles[k][2], label=lab)
               for k, lab in (("full", "unitless, $W^{full}$ (43)"), ("diag", "unitless, $W^{diag}$ (42)"),
                              ("orig", "original (8), SI units"), ("orig_alt", "original (8), second unit set\n(GMTI: km, deg, km/h; RDCOS: km, –)"))]
    handles += [Line2D([], [], color="0.35", ls="-", lw=1.2, label="Monte Carlo, band ±2 SE"),
                Line2D([], [], color=OTHER_RULES["tt2"][0], ls="--", lw=1.3, marker=OTHER_RULES["tt2"][1], mfc="none",
                       ms=4, label="$W^{full}$ by TT2"),
                Line2D([], [], color=OTHER_RULES["ut"][0], ls=":", lw=1.3, marker=OTHER_RULES["ut"][1], mfc="none",
                       ms=4, label="$W^{full}$ by the UT (ut1)")]
    label_panels(axes.ravel())  # row by row
    fig.align_ylabels()
    legend_below(fig, handles, ncol=4, height=0.1)
    return fig
