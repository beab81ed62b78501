"""Reproduce the radar example of Gustafsson & Hendeby's lecture *Parameter Estimation using
Nonlinear Transformations* (slides "Radar Example: ...").

Two radars at p₁ = [0, 0] and p₂ = [200, 0] measure range and bearing of a target near
[100, 100]: y = (r, φ) with r ~ N(100√2, 5) and φ ~ N(π/4, 0.1) (left sensor) or
N(3π/4, 0.1) (right sensor); the second argument of N is a variance.

- **Monte Carlo**: samples of x = h⁻¹(y) = p + r [cos φ, sin φ], the "banana" of each sensor.
- **Direct approach with UT** (SigSys ``uteval(y, hinv, 'ut1', [], p)``): the sigma points in
  (r, φ), the transformed sigma points, the fitted N(x̂_k, P_k) (``Nhat1``, ``Nhat2``) and their
  fusion.
- **Indirect approach with TT1** (SigSys ``tt1eval`` and ``condition``): prior N([100; 100], 400 I);
  the joint model of the lecture's code, z = [x; hypot(x − p) + e_r; atan2(x₂ − p₂, x₁ − p₁) + e_φ],
  with e_k = N(0, Cov y_k) and conditioning on E y_k ("exact measurement statistics"):
  ``Xhat1`` after the left sensor, ``Xhat2`` after both. The same is repeated with the
  statistics of the Monte Carlo samples of y (``Xhat1_sampled``, ``Xhat2_sampled``), to show how
  sampled statistics move the result (see the note below).

Files written to ``outdir``: ``radar_mc.png``, ``radar_direct_ut.png``,
``radar_indirect_tt1.png`` and ``radar_estimates.csv`` (one row per Gaussian: name, method,
x1, x2, P11, P12, P22, at full precision).

Note
----
With exact measurement statistics the innovation of both sensors is zero (the prior mean maps
exactly to E y_k), so TT1 keeps the mean at [100, 100] and the symmetric geometry makes the
final covariance 4.926·I with a zero off-diagonal. The lecture prints
``Xhat2 = N([99.6;100],[4.93,0.0121;0.0121,4.93])``: the diagonal agrees, the 99.6 and the
0.0121 do not, and they cannot come from the stated computation (a zero innovation cannot
move the mean). Statistics estimated from samples of y give deviations of that size.

Run ``python -m symmon.reproduce.radar OUTDIR`` to write the files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..errors import ArgumentError, plain_repr
from ..estimation import nlt as estimation
from ..core.gaussian import Gaussian
from ..io import check_output_set, write_csv
from ..core.model import Model
from ..core.problems import radar_h, radar_hinv
from ..compile.compiled import compiled
from ..transforms.taylor import TT1
from ..transforms.unscented import UT
from .common import OKABE_ITO, figure_style, label_panels, legend_outside, save_reproduced, with_format

__all__ = ["OUTPUTS", "run", "SENSORS", "RANGE_VAR", "BEARING_VAR", "PRIOR", "hinv_model", "h_model", "measurement"]

#: The files :func:`run` writes into its directory, checked before any work
#: (:func:`symmon.io.check_output_set`; the command line checks them with its other outputs).
OUTPUTS = ("radar_mc.png", "radar_direct_ut.png", "radar_indirect_tt1.png", "radar_estimates.csv")

#: Sensor positions p₁ (left, "S1") and p₂ (right, "S2").
SENSORS = ((0.0, 0.0), (200.0, 0.0))
#: The mean bearing of each sensor to the target.
BEARINGS = (np.pi / 4, 3 * np.pi / 4)
#: Variances of the range and bearing (SigSys ``ndist`` takes variances).
RANGE_VAR = 5.0
BEARING_VAR = 0.1
#: The prior of the indirect approach, N([100; 100], 400 I).
PRIOR = Gaussian([100.0, 100.0], 400.0 * np.eye(2))
#: Confidence level of the plotted ellipses.
ELLIPSE_LEVEL = 0.95


def hinv_model(p: tuple[float, float]) -> Model:
    """x = h⁻¹(y) = p + [r cos φ, r sin φ] (the lecture's ``hinv``), inputs (r, φ)."""
    return radar_hinv(p)


def h_model(p: tuple[float, float]) -> Model:
    """y = [hypot(x − p) + e_r; atan2(x₂ − p₂, x₁ − p₁) + e_φ], the lecture's ``g`` without the
    pass-through of x (the joint [x; y] is built by :func:`symmon.estimation.indirect`)."""
    return radar_h(p)


def measurement(sensor: int) -> Gaussian:
    """The distribution of y = (r, φ) of sensor 0 (left) or 1 (right)."""
    return Gaussian([100.0 * np.sqrt(2.0), BEARINGS[sensor]], np.diag([RANGE_VAR, BEARING_VAR]))


def _ellipse(g: Gaussian, level: float = ELLIPSE_LEVEL, n: int = 200) -> np.ndarray:
    """Points (n, 2) of the ``level`` confidence ellipse of a 2-D Gaussian."""
    from scipy.stats import chi2

    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)])
    return (g.mean[:, None] + np.sqrt(chi2.ppf(level, 2)) * g.sqrt_cov() @ circle).T


def _row(name: str, method: str, g: Gaussian) -> list:
    return [name, method, float(g.mean[0]), float(g.mean[1]),
            float(g.cov[0, 0]), float(g.cov[0, 1]), float(g.cov[1, 1])]


#: The colours of the two sensors' quantities, and of the fused or conditioned estimate.
COLOURS = (OKABE_ITO["blue"], OKABE_ITO["vermillion"])
FUSED = OKABE_ITO["black"]


def _sensors(ax) -> None:
    for (px, py), c, label in zip(SENSORS, COLOURS, ("S1", "S2")):
        ax.plot(px, py, ".", color=c, markersize=15)
        ax.annotate(label, (px, py), textcoords="offset points", xytext=(4, 4))


def _figure(ncols: int = 1):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.5 * ncols, 5.0), layout="constrained")
    FigureCanvasAgg(fig)  # the Agg backend, without pyplot's global state
    axes = [fig.add_subplot(1, ncols, i + 1) for i in range(ncols)]
    return fig, axes


@figure_style()
def run(outdir: Path, samples: int = 10_000, seed: int = 0, progress: bool = True,
        fmt: str = "png") -> list[Path]:
    """Reproduce the lecture's radar example: Monte Carlo, direct UT, indirect TT1.

    Parameters
    ----------
    outdir : Path
        Output directory (created if missing).
    samples : int, default 10000
        Monte Carlo samples of y per sensor (at least 2).
    seed : int, default 0
        Seed of the samples; each sensor draws from its own spawned stream.
    progress : bool, default True
        Show a tqdm progress bar (only when stderr is a terminal).

    Returns
    -------
    list of Path
        ``radar_mc.png``, ``radar_direct_ut.png``, ``radar_indirect_tt1.png`` and
        ``radar_estimates.csv``.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 2:
        raise ArgumentError(f"samples must be an integer >= 2, got {plain_repr(samples)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ArgumentError(f"seed must be a non-negative integer, got {plain_repr(seed)}")
    from tqdm import tqdm

    outdir = Path(outdir)
    check_output_set(outdir, with_format(OUTPUTS, fmt))  # a read-only file refuses the run before its work
    outdir.mkdir(parents=True, exist_ok=True)
    ys = [measurement(0), measurement(1)]
    hinvs = [hinv_model(p) for p in SENSORS]
    hs = [h_model(p) for p in SENSORS]
    colors = COLOURS
    rows: list[list] = []
    written: list[Path] = []
    disable = (not progress) or not sys.stderr.isatty()
    with tqdm(total=5, desc="radar reproduction", disable=disable) as bar:
        # Monte Carlo: samples of y and their images under h⁻¹ (the "banana").
        streams = np.random.SeedSequence(seed).spawn(2)
        y_samples = [y.sample(int(samples), np.random.default_rng(s)) for y, s in zip(ys, streams)]
        x_samples = [compiled(m).eval_g(Y) for m, Y in zip(hinvs, y_samples)]
        for k, X in enumerate(x_samples):
            rows.append(_row(f"MC{k + 1}", f"monte carlo ({samples} samples)", Gaussian(X.mean(0), np.cov(X.T))))
        fig, (ax,) = _figure()
        _sensors(ax)
        for X, c in zip(x_samples, colors):
            ax.plot(X[:, 0], X[:, 1], ".", color=c, markersize=1, alpha=0.3)
        ax.set(xlabel="position x₁ (length unit of r)", ylabel="position x₂ (length unit of r)", aspect="equal")
        written.append(save_reproduced(fig, outdir / "radar_mc.png", fmt, "Radar example: Monte Carlo",
                                       f"Monte Carlo samples of x = h⁻¹(y), {samples:,} per sensor (S1 blue, S2 "
                                       "vermillion)."))
        bar.update()

        # Direct approach with UT (ut1), as SigSys uteval(y, hinv, 'ut1', [], p).
        ut = UT.ut1()
        res_d = estimation.direct(None, list(zip(hinvs, ys)), transform=ut)
        # The sigma points of each y and their images under h⁻¹ (the rule's public points).
        sigma = [ut.sigma_points(y.mean[None], y.cov[None])[0] for y in ys]
        images = [compiled(m).eval_g(S) for m, S in zip(hinvs, sigma)]
        rows += [_row("Nhat1", "direct ut1", res_d.estimates[0]), _row("Nhat2", "direct ut1", res_d.estimates[1]),
                 _row("fused", "direct ut1 + fusion", res_d.fused)]
        fig, (ax_y, ax_x) = _figure(2)
        for y, S, c, mk in zip(ys, sigma, colors, ("x", "d")):
            e = _ellipse(y)
            ax_y.plot(e[:, 0], e[:, 1], "-", color=c)
            ax_y.plot(S[:, 0], S[:, 1], mk, color=c)
        ax_y.set(xlabel="range r (the lecture gives no unit)", ylabel="bearing φ [rad]")
        _sensors(ax_x)
        for g, fS, c, mk in zip(res_d.estimates, images, colors, ("x", "d")):
            e = _ellipse(g)
            ax_x.plot(e[:, 0], e[:, 1], "-", color=c)
            ax_x.plot(fS[:, 0], fS[:, 1], mk, color=c)
        e = _ellipse(res_d.fused)
        ax_x.plot(e[:, 0], e[:, 1], "--", color=FUSED)
        ax_x.set(xlabel="position x₁ (length unit of r)", ylabel="position x₂ (length unit of r)", aspect="equal")
        label_panels((ax_y, ax_x))
        written.append(save_reproduced(
            fig, outdir / "radar_direct_ut.png", fmt, "Radar example: direct approach with the UT",
            f"(a) y = (r, φ) of each sensor (S1 blue, crosses; S2 vermillion, diamonds): {ELLIPSE_LEVEL:.0%} "
            f"confidence ellipses and the sigma points; (b) h⁻¹ of the sigma points, N(x̂ₖ, Pₖ) and their "
            f"fusion (black, dashed), {ELLIPSE_LEVEL:.0%} ellipses."))
        bar.update()

        # Indirect approach with TT1 and exact measurement statistics: e_k = N(0, Cov y_k),
        # condition on E y_k (the lecture's tt1eval / condition).
        steps = [ys[0], (ys[1].mean, ys[1].cov, hs[1])]
        res_i = estimation.indirect(hs[0], PRIOR, steps, transform=TT1())
        Xhat1, Xhat2 = res_i.posteriors
        rows += [_row("Xhat0", "prior", PRIOR), _row("Xhat1", "indirect tt1", Xhat1),
                 _row("Xhat2", "indirect tt1", Xhat2)]
        bar.update()

        # The same with the statistics of the Monte Carlo samples of y.
        sampled = [Gaussian(Y.mean(0), np.cov(Y.T)) for Y in y_samples]
        res_s = estimation.indirect(hs[0], PRIOR, [sampled[0], (sampled[1].mean, sampled[1].cov, hs[1])],
                                    transform=TT1())
        rows += [_row("Xhat1_sampled", "indirect tt1, sampled y statistics", res_s.posteriors[0]),
                 _row("Xhat2_sampled", "indirect tt1, sampled y statistics", res_s.posteriors[1])]
        fig, (ax,) = _figure()
        _sensors(ax)
        looks = (("0.45", "-"), (COLOURS[0], "--"), (FUSED, "-."))
        for g, (c, ls), label in zip((PRIOR, Xhat1, Xhat2), looks, ("prior", "prior + left", "prior + all")):
            e = _ellipse(g)
            ax.plot(e[:, 0], e[:, 1], ls, color=c, label=label)
            ax.plot(*g.mean, "+", color=c)
        legend_outside(ax)
        ax.set(xlabel="position x₁ (length unit of r)", ylabel="position x₂ (length unit of r)", aspect="equal")
        written.append(save_reproduced(fig, outdir / "radar_indirect_tt1.png", fmt,
                                       "Radar example: indirect approach with TT1",
                                       f"Indirect approach with TT1: {ELLIPSE_LEVEL:.0%} confidence ellipses of the "
                                       "prior and of the posteriors given the left and both sensors."))
        bar.update()

        header = ["name", "method", "x1", "x2", "P11", "P12", "P22"]
        written.append(write_csv(outdir / "radar_estimates.csv", header, rows))
        bar.update()
    return written


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m symmon.reproduce.radar OUTDIR [--samples N] [--seed S]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outdir", type=Path)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for path in run(args.outdir, args.samples, args.seed):
        print(path)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
