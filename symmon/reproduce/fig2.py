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
from ..nonlinearity import mon_from_moments
from ..problems import GMTI_UNITS, RDCOS_UNITS, bot, gmti, rdcos
from ..propagate import propagate
from ..transforms import TT2, UT, MonteCarlo
from ..transforms.montecarlo import jackknife
from ._common import progress_bar, pyplot

__all__ = ["run", "curves", "ALPHAS", "PROBLEMS"]

#: α grid of Figure 2, [1e-1, 1e1].
ALPHAS = np.logspace(-1, 1, 21)

#: name → (problem factory, output scale of the second unit set: y_alt = y_SI / scale)
PROBLEMS = {
    "BOT": (bot, (1.0,)),
    "GMTI": (gmti, GMTI_UNITS["km-deg-kmh"]),
    "RDCOS": (rdcos, (RDCOS_UNITS["km"], 1.0)),
}


def _value(Sgg, Sgu, Suu, weight) -> float:
    return float(np.sqrt(max(mon_from_moments(Sgg, Sgu, Suu, weight)["squared"], 0.0)))


def _row(m, Suu, scale) -> dict[str, float]:
    S = np.diag(1.0 / np.asarray(scale))
    return {
        "full": _value(m.cov, m.cross_cov, Suu, "full"),
        "diag": _value(m.cov, m.cross_cov, Suu, "diag"),
        "orig": _value(m.cov, m.cross_cov, Suu, "liu-li"),
        "orig_alt": _value(S @ m.cov @ S, S @ m.cross_cov, Suu, "liu-li"),
    }


def _stderr(m, ny: int, weight: str) -> float:
    def val(s):
        C = s.cov
        return _value(C[:ny, :ny], C[:ny, ny:], C[ny:, ny:], weight)

    return float(jackknife(m.info["groups"], val))


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
    keys = ["full", "full_se", "diag", "diag_se", "orig", "orig_se", "orig_alt",
            "full_tt2", "diag_tt2", "orig_tt2", "full_ut", "diag_ut", "orig_ut"]
    rows = [[name, c[name]["alpha"][i]] + [c[name][k][i] for k in keys]
            for name in c for i in range(len(c[name]["alpha"]))]
    csv = write_csv(outdir / "fig2.csv", ["problem", "alpha"] + keys, rows)
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    alt = {"BOT": "", "GMTI": "[km, deg, km/h]", "RDCOS": "[km, −]"}
    for ax, name in zip(axes, c):
        v = c[name]
        ax.semilogx(v["alpha"], v["full"], "g-", lw=2, label="unitless $W^{full}$ (MC)")
        ax.semilogx(v["alpha"], v["diag"], "r-", lw=2, label="unitless $W^{diag}$ (MC)")
        ax.semilogx(v["alpha"], v["orig"], "b-", label="orig (8), SI units (MC)")
        if alt[name]:
            ax.semilogx(v["alpha"], v["orig_alt"], "b--", label=f"orig (8), {alt[name]} (MC)")
        ax.semilogx(v["alpha"], v["full_tt2"], "g:", label="$W^{full}$, TT2")
        ax.semilogx(v["alpha"], v["full_ut"], "g-.", lw=0.8, label="$W^{full}$, UT")
        ax.set_title(name)
        ax.set_xlabel(r"$\alpha$")
        ax.set_ylim(bottom=0)
    axes[0].set_ylabel("MoN")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Figure 2: BOT (45), GMTI (46), RDCOS (47); MC {samples:.0e} samples")
    fig.tight_layout()
    png = save_figure(fig, outdir / "fig2.png", dpi=150)
    plt.close(fig)
    return [png, csv]
