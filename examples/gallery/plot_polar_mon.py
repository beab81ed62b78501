"""
Polar coordinates: the MoN by Monte Carlo beside TT2 and the UT
===============================================================

The running example of Straka & Havlík (2024), eqs. (14)–(16): u = [x, y] ~ N([1, 10],
α diag(1, 100)) in km, y = [range, bearing]. We sweep the spread α and compute

* the unitless MoN with W^full (43), the same in every unit;
* the normalised Liu–Li MoN (8) with the bearing in rad and in deg, which is not.

Monte Carlo (with ±2 SE bands) is the reference; TT2 and the UT are the cheap transforms.
The bearing is declared an angle (``angles=[1]``): at large α its samples reach the cut at
±π, and its circular moments count a sample just past the cut as a small deviation. This is
Figure 1 of the paper on a smaller sample (2·10⁴ instead of 10⁶, 19 values of α), computed
by :func:`symmon.reproduce.fig1.curves`, which rescales the moments of the bearing in rad to
any other unit exactly; ``symmon reproduce fig1`` draws the full figure, and
``docs/data/fig1.csv`` holds its data.
"""

import matplotlib.pyplot as plt
import numpy as np

from symmon.reproduce import fig1

alphas = np.unique(np.append(np.logspace(-3, 1, 17), [0.17, 0.25]))   # the paper's α = 0.17 too
c = fig1.curves(alphas, samples=20_000, seed=0, progress=False)

# %%
# The three MoNs against α (Okabe–Ito colours, and a marker per quantity). TT2 follows
# Monte Carlo while α < 10⁻², then falls far below it: over the spread of u the bearing is
# no longer close to quadratic. The UT is low even at small α in two dimensions (its sigma
# points miss the off-diagonal Hessian terms).

fig, ax = plt.subplots(figsize=(7, 4.5))
for key, color, marker, label in (("full", "#000000", None, "unitless, W^full"),
                                  ("liu_rad", "#0072B2", "o", "Liu–Li, bearing in rad"),
                                  ("liu_deg", "#D55E00", "s", "Liu–Li, bearing in deg")):
    se = c[f"{key}_se"]
    ax.fill_between(alphas, c[key] - 2 * se, c[key] + 2 * se, color=color, alpha=0.3, lw=0)
    ax.plot(alphas, c[key], "-", color=color, marker=marker, ms=4, label=f"{label}: MC ± 2 SE")
    if key != "full":
        ax.plot(alphas, c[f"{key}_tt2"], "--", color=color, marker=marker, mfc="white", ms=4, label=f"{label}: TT2")
        ax.plot(alphas, c[f"{key}_ut"], ":", color=color, marker=marker, mfc="white", ms=4, label=f"{label}: UT")
ax.set_xscale("log")
ax.set_xlabel("α (covariance scale)")
ax.set_ylabel("MoN")
ax.set_ylim(0, 1)
ax.legend(fontsize=7, loc="upper left")
plt.show()

# %%
# At α = 0.17 the paper reports about 10 % (rad) and 80 % (deg) for Liu–Li's MoN.

i = int(np.flatnonzero(alphas == 0.17)[0])
for key, label in (("full", "W^full"), ("liu_rad", "Liu–Li, rad"), ("liu_deg", "Liu–Li, deg")):
    print(f"α = {alphas[i]:.3g}, {label:>12}: {c[key][i]:.3f} ± {c[key + '_se'][i]:.3f}")
