"""Figure 2 of Straka & Havlík (2024): MoNs of the BOT, GMTI and RDCOS problems.

State (44) scaled by α ∈ [0.1, 10]; measurements (45)–(47).  For each problem and α the
joint moments are computed once (Monte Carlo by default), and the unitless MoN with
W^full (43) and W^diag (42) and the original normalised MoN (8) in both unit sets of
Sec. V ([m, rad, m/s] vs [km, deg, km/h] for GMTI; [m, −] vs [km, −] for RDCOS) follow
by exact rescaling of the output moments.  TT2 and UT curves of W^full are drawn beside.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io import save_figure, write_csv
from ..measures.formula import mon_from_moments
from ..core.problems import GMTI_UNITS, RDCOS_UNITS, bot, gmti, rdcos
from ..propagation.front import propagate
from ..transforms import TT2, UT, MonteCarlo
from ..transforms.stats import jackknife
from .common import ALPHA_LABEL, figure_style, progress_bar, pyplot, samples_text

__all__ = ["run", "curves", "ALPHAS", "PROBLEMS", "COLUMNS"]

#: α grid of Figure 2, [1e-1, 1e1].
ALPHAS = np.logspace(-1, 1, 21)

#: name → (problem factory, output scale of the second unit set: y_alt = y_SI / scale)
PROBLEMS = {
    "BOT": (bot, (1.0,)),
    "GMTI": (gmti, GMTI_UNITS["km-deg-kmh"]),
    "RDCOS": (rdcos, (RDCOS_UNITS["km"], 1.0)),
}


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


def _stderr(m, ny: int, weight: str) -> float:
    def val(loo):
        return np.array([_value(C[:ny, :ny], C[:ny, ny:], C[ny:, ny:], weight) for C in loo.cov])

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
        cur = out[name]
        m = propagate(prob.model, prob.u, transform=MonteCarlo(samples, seed=seed))
        for key, val in _row(m, m.input_cov, scale).items():
            cur.setdefault(key, np.empty(len(alphas)))[i] = val
        for w in ("full", "diag", "orig"):
            cur.setdefault(f"{w}_se", np.empty(len(alphas)))[i] = _stderr(m, prob.model.n_y, {"orig": "liu-li"}.get(w, w))
        for suffix, tr in (("tt2", TT2()), ("ut", UT.ut1())):
            mt = propagate(prob.model, prob.u, transform=tr)
            for key, val in _row(mt, mt.input_cov, scale).items():
                cur.setdefault(f"{key}_{suffix}", np.empty(len(alphas)))[i] = val
    return out


def intervals(c: dict[str, dict[str, np.ndarray]]) -> dict[str, tuple[float, float]]:
    """The range of the unitless W^full MoN over the α grid, per problem (Sec. V's intervals)."""
    return {name: (float(v["full"].min()), float(v["full"].max())) for name, v in c.items()}


def run(outdir: str | Path = "results", samples: int = 10**6, seed: int = 0, progress: bool = True,
        alphas=ALPHAS) -> list[Path]:
    """Reproduce Figure 2: write ``fig2.png`` and ``fig2.csv`` into ``outdir``."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    c = curves(alphas, samples, seed, progress)
    keys = list(COLUMNS)[2:]
    rows = [[name, c[name]["alpha"][i]] + [c[name][k][i] for k in keys]
            for name in c for i in range(len(c[name]["alpha"]))]
    csv = write_csv(outdir / "fig2.csv", list(COLUMNS.values()), rows)
    plt = pyplot()
    with figure_style():
        fig = _plot(plt, c, samples)
    png = save_figure(fig, outdir / "fig2.png", dpi=150)
    plt.close(fig)
    return [png, csv]


#: The second unit set of each problem (Sec. V), for the legends.
ALT_UNITS = {"BOT": "", "GMTI": "km, deg, km/h", "RDCOS": "km, –"}
SI_UNITS = {"BOT": "rad", "GMTI": "m, rad, m/s", "RDCOS": "m, –"}


def _plot(plt, c: dict[str, dict[str, np.ndarray]], samples: int):
    """Figure 2: one panel per problem, MC curves with ±2 SE bands, TT2 and UT beside."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), sharey=True)
    for ax, name in zip(axes, c):
        v = c[name]
        a = v["alpha"]
        for key, color, label in (("full", "tab:green", "unitless, $W^{full}$ (43)"),
                                  ("diag", "tab:red", "unitless, $W^{diag}$ (42)"),
                                  ("orig", "tab:blue", f"original (8), in [{SI_UNITS[name]}]")):
            se = v[f"{key}_se"]
            ax.fill_between(a, v[key] - 2 * se, v[key] + 2 * se, color=color, alpha=0.25, lw=0)
            ax.semilogx(a, v[key], "-", color=color, lw=2 if key != "orig" else 1.2,
                        label=f"{label}: Monte Carlo (band ±2 SE)")
        if ALT_UNITS[name]:
            ax.semilogx(a, v["orig_alt"], "--", color="tab:blue",
                        label=f"original (8), in [{ALT_UNITS[name]}]: Monte Carlo")
        ax.semilogx(a, v["full_tt2"], ":", color="tab:green", lw=1.5, label="unitless, $W^{full}$: TT2")
        ax.semilogx(a, v["full_ut"], "-.", color="tab:green", lw=0.8,
                    label="unitless, $W^{full}$: unscented transform")
        ax.set_title({"BOT": "BOT (45)", "GMTI": "GMTI (46)", "RDCOS": "RDCOS (47)"}[name])
        ax.set_xlabel(ALPHA_LABEL)
        ax.set_ylim(bottom=0)
        if name == "BOT":
            ax.text(0.03, 0.97, "scalar output: the three MoNs coincide\n(one curve hides the others)",
                    transform=ax.transAxes, fontsize=7, va="top")
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, 0.86) if name == "BOT" else (0.0, 1.0), fontsize=6.5)
    axes[0].set_ylabel("measure of nonlinearity (unitless)")
    fig.suptitle("Figure 2: MoNs of the state (44) scaled by α, Monte Carlo with "
                 f"{samples_text(samples)} samples per point")
    fig.tight_layout()
    return fig
