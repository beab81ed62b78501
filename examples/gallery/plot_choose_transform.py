"""
Choosing a transform: accuracy of the moments as the spread grows
=================================================================

Which transform is accurate enough depends on how nonlinear the model is over the spread of
u. For the polar example (Straka & Havlík 2024, eqs. (14), (16)) we scale the covariance by α
and compare each transform's mean range and bearing variance with Monte Carlo (10⁵ samples,
whose standard error is drawn as a band), beside the MoN with W^full.

While the MoN is small, every transform agrees with Monte Carlo. As it grows, TT1 and TT2 go
first, then the UT. Gauss–Hermite of order 10 lasts longest, but once the spread of u reaches
the origin, where atan2 is singular (α ≳ 0.1), it fails too and only Monte Carlo remains.
Gauss–Hermite's own error estimate (order 10 against 12, ``error_estimate=True``) sees this
coming: drawn dashed, it is larger than the error measured against Monte Carlo wherever that
error rises above the Monte Carlo noise (the grey band).
"""

import matplotlib.pyplot as plt
import numpy as np

import symmon as sm

alphas = np.logspace(-3, 0, 7)
prob = sm.problems.polar(1.0, "rad")
transforms = {"TT1": sm.TT1(), "TT2": sm.TT2(), "UT (ut1)": sm.UT.ut1(), "GH 10": sm.GaussHermite(10)}
means = prob.u.mean[None, :].repeat(len(alphas), axis=0)
covs = alphas[:, None, None] * prob.u.cov[None]

ref = [sm.propagate(prob.model, sm.Gaussian(m, P), transform=sm.MonteCarlo(100_000, seed=0))
       for m, P in zip(means, covs)]
ref_var = np.array([r.cov[1, 1] for r in ref])
ref_se = np.array([r.stderr["cov"][1, 1] for r in ref])
mon = sm.sweep.sweep_alpha(prob.model, prob.u, alphas, weight="full", transform=sm.GaussHermite(10))

# %%
# The relative error of the bearing variance, with the Monte Carlo error band (2 s.e.).

fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
for name, t in transforms.items():
    var = np.array([sm.propagate(prob.model, sm.Gaussian(m, P), transform=t).cov[1, 1]
                    for m, P in zip(means, covs)])
    err = np.abs(var / ref_var - 1)
    line, = ax1.plot(alphas, err, marker="o", ms=3, label=name)
    if isinstance(t, sm.GaussHermite):
        est = [sm.propagate(prob.model, sm.Gaussian(m, P), transform=sm.GaussHermite(t.order, error_estimate=True))
               for m, P in zip(means, covs)]
        rel = np.array([e.error["cov"][1, 1] / e.cov[1, 1] for e in est])
        ax1.plot(alphas, rel, ls="--", color=line.get_color(), label=f"{name}: its error estimate")
    print(f"{name:>9}: relative error of Var(bearing) at α = {alphas[-1]:g}: {err[-1]:.3f}")
ax1.fill_between(alphas, 1e-5, 2 * ref_se / ref_var, color="0.85", label="MC 2 s.e.")
ax1.set_xscale("log")
ax1.set_yscale("log")
ax1.set_ylim(1e-5, 2)
ax1.set_ylabel("|Var / Var_MC − 1|")
ax1.legend(fontsize=7)
ax2.plot(alphas, mon.value, "k-o", ms=3)
ax2.set_ylabel("MoN (W^full, GH 10)")
ax2.set_xlabel("α")
fig.suptitle("Polar example: when the MoN grows, the cheap transforms fail")
plt.show()  # the figure goes into the page; the title's Text object is not printed
