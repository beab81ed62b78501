"""Figure 1 of Straka & Havlík (2024): the MSE-based MoN depends on the bearing unit.

The polar example (14)–(16): u = [x, y] ~ N([1, 10], α diag(1, 100)) km, y = [range,
bearing].  For each α the joint moments of [y; u] are computed once (Monte Carlo by
default, with common random numbers across α); the normalised Liu–Li MoN (17) is then
evaluated with the bearing in rad, in deg, and in every unit from 0.1 nrad to 10 Grad
(the band), by rescaling the moments exactly.  The unitless MoN with W^full (43) is the
same in every unit.  TT2 and UT curves are drawn beside Monte Carlo.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import AngleWarning
from ..io import save_figure, write_csv
from ..measures.formula import mon_from_moments
from ..core.problems import polar
from ..propagation.front import propagate
from ..transforms import TT2, UT, MonteCarlo
from .common import ALPHA_LABEL, figure_style, progress_bar, pyplot, samples_text

__all__ = ["run", "curves", "ALPHAS", "UNIT_SIZES", "COLUMNS"]

#: α grid of Figure 1, [1e-4, 1e2], with the α = 0.17 that the text quotes.
ALPHAS = np.unique(np.append(np.logspace(-4, 2, 31), 0.17))
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
             "liu_rad_ut", "liu_deg_ut", "liu_rad_se", "liu_deg_se"]
    out = {k: np.empty(len(alphas)) for k in names}
    transforms = {"": MonteCarlo(samples, seed=seed), "_tt2": TT2(), "_ut": UT.ut1()}
    for i, a in enumerate(progress_bar(alphas, "fig1: alpha sweep", progress)):
        prob = polar(a, "rad")
        for suffix, tr in transforms.items():
            with warnings.catch_warnings():
                # The paper's bearing is a real number, not a declared angle; at large α its
                # points straddle ±π, as in the paper: the AngleWarning is no news here.
                warnings.simplefilter("ignore", AngleWarning)
                m = propagate(prob.model, prob.u, transform=tr)
            for unit, size in (("rad", 1.0), ("deg", np.pi / 180)):
                Sgg, Sgu = _scaled(m, size)
                out[f"liu_{unit}{suffix}"][i] = mon_from_moments(Sgg, Sgu, m.input_cov, "liu-li").value
            if suffix == "":
                band = [mon_from_moments(*_scaled(m, s), m.input_cov, "liu-li").value for s in UNIT_SIZES]
                out["band_lo"][i], out["band_hi"][i] = min(band), max(band)
                out["full"][i] = mon_from_moments(m.cov, m.cross_cov, m.input_cov, "full").value
                out["liu_rad_se"][i], out["liu_deg_se"][i] = _liu_se(m, m.input_cov)
    out["alpha"] = np.asarray(alphas, dtype=float)
    return out


def _liu_se(m, Suu) -> tuple[float, float]:
    from ..transforms.stats import jackknife

    res = []
    for size in (1.0, np.pi / 180):
        S = np.diag([1.0, 1.0 / size, 1.0, 1.0])

        def val(loo, S=S):
            return np.array([mon_from_moments(C[:2, :2], C[:2, 2:], C[2:, 2:], "liu-li").value
                             for C in S @ loo.cov @ S])

        res.append(float(jackknife(m.replicates, val)))
    return res[0], res[1]


def run(outdir: str | Path = "results", samples: int = 10**6, seed: int = 0, progress: bool = True,
        alphas=ALPHAS) -> list[Path]:
    """Reproduce Figure 1: write ``fig1.png`` and ``fig1.csv`` into ``outdir``."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    c = curves(alphas, samples, seed, progress)
    csv = write_csv(outdir / "fig1.csv", list(COLUMNS.values()), zip(*[c[k] for k in COLUMNS]))
    plt = pyplot()
    with figure_style():
        fig = _plot(plt, c, samples)
    png = save_figure(fig, outdir / "fig1.png", dpi=150)
    plt.close(fig)
    return [png, csv]


def _plot(plt, c: dict[str, np.ndarray], samples: int):
    """Figure 1 from the curves: MC with ±2 SE bands, TT2 and UT beside, α = 0.17 marked."""
    fig, ax = plt.subplots(figsize=(11, 4.8))
    a = c["alpha"]
    ax.fill_between(a, c["band_lo"], c["band_hi"], color="0.88", lw=0,
                    label="Liu–Li, any bearing unit from 0.1 nrad to 10 Grad")
    for unit, color in (("rad", "tab:blue"), ("deg", "tab:red")):
        mc, se = c[f"liu_{unit}"], c[f"liu_{unit}_se"]
        ax.fill_between(a, mc - 2 * se, mc + 2 * se, color=color, alpha=0.25, lw=0)
        ax.semilogx(a, mc, "-", color=color, label=f"Liu–Li, bearing in {unit}: Monte Carlo (band ±2 SE)")
        ax.semilogx(a, c[f"liu_{unit}_tt2"], ":", color=color, label=f"Liu–Li, bearing in {unit}: TT2")
        ax.semilogx(a, c[f"liu_{unit}_ut"], "--", color=color, lw=0.8,
                    label=f"Liu–Li, bearing in {unit}: unscented transform")
    ax.semilogx(a, c["full"], "-", color="tab:green", lw=2,
                label="unitless, $W^{full}$ (43): the same in every unit (Monte Carlo)")
    ax.axvline(0.17, color="k", lw=0.6, ls="-.")
    ax.annotate(r"$\alpha = 0.17$: the values" "\n" "quoted in Sec. II-B", (0.17, 0.99), xytext=(-4, 0),
                textcoords="offset points", fontsize=7, va="top", ha="right")
    ax.set_xlabel(ALPHA_LABEL + r", $P_0 = \mathrm{diag}(1, 100)$ km$^2$")
    ax.set_ylabel("normalised measure of nonlinearity (unitless, 0 = linear)")
    ax.set_ylim(0, 1.02)
    ax.set_title("Figure 1: the Liu–Li MoN (8) depends on the bearing unit; the unitless MoN does not\n"
                 f"polar example (14)–(16), Monte Carlo with {samples_text(samples)} samples per α")
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    return fig
