"""
Radar estimation: direct and indirect approaches, TT1 vs UT vs Monte Carlo
==========================================================================

The example of Gustafsson & Hendeby's lecture *Parameter Estimation using Nonlinear
Transformations*: two radars at p₁ = (0, 0) and p₂ = (200, 0) measure range and bearing,
R = diag(5, 0.1), of a target at (100, 100).

* **Direct**: each measurement through x = h⁻¹(y) (an NLT of N(y, R)), then the fusion formula.
* **Indirect**: a prior N([100, 100], 400 I), the NLT of [x; h(x, e)], and conditioning on y
  (Lemma 7.1), one sensor after the other.

The bearing noise (0.1 rad², about 18° standard deviation) makes h⁻¹ strongly nonlinear: the
samples of h⁻¹(y) form a banana that TT1's ellipse misses and the UT's follows in the mean.
"""

import matplotlib.pyplot as plt
import numpy as np

import symmon as sm

sensors = [(0.0, 0.0), (200.0, 0.0)]
ys = [sm.Gaussian([100 * np.sqrt(2), b], np.diag([5.0, 0.1])) for b in (np.pi / 4, 3 * np.pi / 4)]
hinvs = [sm.problems.radar_hinv(p) for p in sensors]

direct = {name: sm.estimation.direct(None, list(zip(hinvs, ys)), transform=t)
          for name, t in (("TT1", sm.TT1()), ("UT", sm.UT.ut1()))}
for name, res in direct.items():
    print(f"direct {name}: sensor 1 {res.estimates[0]}, fused {res.fused}")

prior = sm.Gaussian([100.0, 100.0], 400.0 * np.eye(2))
hs = [sm.problems.radar_h(p) for p in sensors]
steps = [(ys[0].mean, ys[0].cov), (ys[1].mean, ys[1].cov, hs[1])]
for name, t in (("TT1", sm.TT1()), ("UT", sm.UT.ut1())):
    print(f"indirect {name}: {sm.estimation.indirect(hs[0], prior, steps, transform=t).posterior}")


# %%
# The samples of h⁻¹(y) for each sensor, with the 2σ ellipses of the TT1 and UT estimates.

def ellipse(g: sm.Gaussian, k: float = 2.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 200)
    return g.mean[:, None] + k * g.sqrt_cov() @ np.vstack([np.cos(t), np.sin(t)])


fig, ax = plt.subplots(figsize=(6, 6))
rng = np.random.default_rng(0)
for p, y in zip(sensors, ys):
    r, phi = y.sample(2000, rng).T
    ax.plot(p[0] + r * np.cos(phi), p[1] + r * np.sin(phi), ".", ms=1, color="0.6")
for (name, res), c in zip(direct.items(), ("tab:blue", "tab:red")):
    for g in res.estimates:
        ax.plot(*ellipse(g), color=c, lw=1, label=f"{name}, one sensor" if g is res.estimates[0] else None)
    ax.plot(*ellipse(res.fused), color=c, lw=2, ls="--", label=f"{name}, fused")
ax.plot([100], [100], "k+", ms=12, label="target")
ax.plot(*np.array(sensors).T, "k^", label="radars")
ax.set_aspect("equal")
ax.set_xlim(-100, 300)
ax.set_ylim(-100, 300)
ax.legend(fontsize=8, loc="lower right")
ax.set_title("Direct approach: h⁻¹(y) samples and 2σ ellipses")
plt.show()  # the figure goes into the page; the title's Text object is not printed

# %%
# Monte Carlo of h⁻¹(y) for sensor 1, with standard errors: the UT's mean is within them,
# TT1's (the point (100, 100)) is not.

mc = sm.propagate(hinvs[0], ys[0], transform=sm.MonteCarlo(100_000, seed=3))
print("MC mean", mc.mean, "± ", mc.stderr["mean"])
print("UT mean", direct["UT"].estimates[0].mean, " TT1 mean", direct["TT1"].estimates[0].mean)
