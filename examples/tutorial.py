# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # symmon tutorial: nonlinear transformations of random variables
#
# This notebook (jupytext percent format: open it in Jupyter with jupytext, or run it
# as a script, `python examples/tutorial.py`) walks the whole mission of symmon:
#
# 1. declare a model y = g(u) symbolically;
# 2. propagate a Gaussian through it by every transform and check them against Monte
#    Carlo with error bars;
# 3. measure how nonlinear the model is (the MoN of Straka & Havlík, 2024) and see why the
#    unit-invariant weights matter, at α = 0.17;
# 4. read the same model from a TOML model file;
# 5. noise structures (additive, multiplicative, general);
# 6. estimate a position from radar measurements, directly and indirectly (Gustafsson &
#    Hendeby);
# 7. a closed-form MMSE estimator of a distance (Song, Choi & Shin);
# 8. export standalone C code.
#
# Every result is checked with `assert`; sample sizes are small so that it runs in seconds.
# Monte Carlo checks allow 5 standard errors (seeded generators: the run is reproducible).

# %%
import ctypes
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import sympy as sp

import symmon as sm
from symmon.measures.mon import format_table

#: Monte Carlo checks: |estimate − reference| ≤ MC_SIGMAS standard errors.
MC_SIGMAS = 5.0
#: Two closed forms of the same number agree to rounding.
EXACT_TOL = 1e-10
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path("examples").resolve()
WORK = Path(tempfile.mkdtemp(prefix="symmon-tutorial-"))

# %% [markdown]
# ## 1. A model: Cartesian to polar coordinates
#
# The paper's running example, eqs. (14) and (16): u = [x, y] ~ N([1, 10], α diag(1, 100))
# in km, y = [range, bearing]. The bearing is an angle (`angles=[1]`), so its mean is a
# circular mean. In a notebook, `polar` and `u` display as LaTeX.

# %%
x, y = sp.symbols("x y", real=True)
polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar", angles=[1])
alpha = 0.17
u = sm.Gaussian([1.0, 10.0], alpha * np.diag([1.0, 100.0]))
polar, u

# %%
assert polar.structure == "none"                  # no noise symbols: y = g(u)
assert polar._repr_latex_().startswith("$g(x, y) = ")
assert r"\mathcal{N}" in u._repr_latex_()

# %% [markdown]
# ## 2. Moments by every transform, checked against Monte Carlo
#
# TT1 is the linearisation (the EKF's), TT2 adds the Hessian terms, the unscented family and
# Gauss–Hermite use deterministic points, Monte Carlo samples. Each returns a
# `JointMoments` with E y, Cov y and Cov(y, u); Monte Carlo also gives standard errors.

# %%
mc = sm.propagate(polar, u, transform=sm.MonteCarlo(200_000, seed=1))
transforms = {
    "TT1": sm.TT1(), "TT2": sm.TT2(), "UT (ut1)": sm.UT.ut1(), "UT (ut2)": sm.UT.ut2(),
    "cubature": sm.UT.cubature(), "Gauss-Hermite 7": sm.GaussHermite(7),
}
moments = {name: sm.propagate(polar, u, transform=t) for name, t in transforms.items()}
print(f"{'transform':>16} {'E range':>9} {'E bearing':>10} {'var range':>10}")
for name, m in {**moments, "Monte Carlo": mc}.items():
    print(f"{name:>16} {m.mean[0]:9.4f} {m.mean[1]:10.5f} {m.cov[0, 0]:10.4f}")
se = mc.stderr["mean"]
print(f"{'MC std. error':>16} {se[0]:9.4f} {se[1]:10.5f}")

# %%
# Gauss-Hermite with 7 points per axis gets the mean range within the Monte Carlo error bars.
gh = moments["Gauss-Hermite 7"]
assert abs(gh.mean[0] - mc.mean[0]) <= MC_SIGMAS * se[0], (gh.mean, mc.mean, se)
# TT1 ignores the curvature: its mean range is g(E u) = |E u|, visibly below the truth.
assert abs(moments["TT1"].mean[0] - np.sqrt(101)) < EXACT_TOL
assert mc.mean[0] - moments["TT1"].mean[0] > MC_SIGMAS * se[0]
# Every second-order method moves the mean range up, towards Monte Carlo.
for name in ("TT2", "UT (ut1)", "UT (ut2)", "cubature"):
    assert moments["TT1"].mean[0] < moments[name].mean[0] < mc.mean[0] + MC_SIGMAS * se[0], name

# %% [markdown]
# ### Which transform to choose?
#
# The table shows the usual picture: TT1 misses the curvature, the second-order methods
# (TT2, the unscented family) move towards the truth, Gauss–Hermite and Monte Carlo get it.
# How far the cheap transforms can be trusted depends on how nonlinear g is over the spread
# of u, which is what the measure of nonlinearity of the next section quantifies: near 0,
# TT1 (the EKF's linearisation) is enough; as it grows use TT2, the UT or Gauss–Hermite,
# and check them against Monte Carlo with `sm.compare` (or `symmon compare FILE`) and
# Gauss–Hermite's own error estimate, `sm.GaussHermite(order, error_estimate=True)`.
# The user guide's page "Transforms, and how to choose one" (docs/guide/transforms.md) gives
# the details; note that the UT is not a good tool to *measure* nonlinearity in several
# dimensions (its sigma points miss the off-diagonal Hessian terms).

# %%
# Gauss-Hermite's error estimate (order 7 against order 9) bounds its distance to Monte Carlo here.
gh_check = sm.propagate(polar, u, transform=sm.GaussHermite(7, error_estimate=True))
gh_err = gh_check.info["error_estimate"]["mean"][0]
print("Gauss-Hermite 7 error estimate of the mean:", gh_err)
assert abs(gh_check.mean[0] - mc.mean[0]) <= gh_err[0] + MC_SIGMAS * se[0]

# %% [markdown]
# ## 3. The measure of nonlinearity, and why units matter (α = 0.17)
#
# The MoN compares g with its best affine fit, weighted by W. The paper's weight
# W^full = Σ_gg⁻¹/n_y (43) makes it unitless and invariant to changes of units (18); the
# normalised MSE measure of Liu & Li (8) is not: expressing the bearing in degrees instead
# of radians changes its value. `sm.problems.polar(alpha, bearing_unit)` builds both.

# %%
rad, deg = sm.problems.polar(alpha, "rad"), sm.problems.polar(alpha, "deg")
mon = {}
for weight in ("full", "diag", "liu-li"):
    for label, prob in (("rad", rad), ("deg", deg)):
        mon[weight, label] = sm.nonlinearity(prob.model, prob.u, weight=weight, transform=sm.TT2())
    print(f"{weight:>7}: bearing in rad {float(mon[weight, 'rad']):.6f}, in deg {float(mon[weight, 'deg']):.6f}")
mon["full", "rad"]

# %%
# The unitless weights give the same number in any unit (exactly, under TT2) ...
for weight in ("full", "diag"):
    assert abs(mon[weight, "rad"].value - mon[weight, "deg"].value) < EXACT_TOL, weight
# ... the Liu-Li measure does not: in degrees the bearing dominates tr Σ_gg.
assert abs(mon["liu-li", "rad"].value - mon["liu-li", "deg"].value) > 0.1
# All of them lie in [0, 1].
assert all(0.0 <= m.value <= 1.0 for m in mon.values())

# %% [markdown]
# The same comparison with Monte Carlo, whose MoN comes with a jackknife standard error:

# %%
mon_mc = sm.nonlinearity(polar, u, weight="full", transform=sm.MonteCarlo(100_000, seed=2))
mon_mc

# %%
assert mon_mc.stderr is not None and mon_mc.stderr > 0
assert 0.0 < mon_mc.value < 1.0
rows = sm.compare(polar, u, weight="full", transforms=[sm.TT1(), sm.TT2(), sm.GaussHermite(7)])
print(format_table(rows))
assert rows[0]["value"] < EXACT_TOL                # TT1 sees no nonlinearity by construction
assert abs(rows[2]["value"] - mon_mc.value) <= MC_SIGMAS * mon_mc.stderr + 0.02  # GH-7 vs MC (quadrature error)

# %% [markdown]
# Unit invariance can also be *proved* symbolically (TT2 closed form): `sm.units.prove_invariance`
# builds M² in two unit systems with symbolic scales and offsets and simplifies the
# difference to 0 (or shows a point where it is not).

# %%
proof_full = sm.units.prove_invariance(polar, "full", mean=u.mean, cov=u.cov)
proof_liu = sm.units.prove_invariance(polar, "liu-li", mean=u.mean, cov=u.cov)
print(proof_full)
print(proof_liu)
assert proof_full.holds and not proof_liu.holds

# %% [markdown]
# ## 4. The same model from a model file
#
# A model file is TOML; expressions are read by a whitelist parser (never `eval`). The
# command line works on the same files: `symmon propagate examples/polar.toml --json`.

# %%
spec = sm.load_model_file(HERE / "polar.toml")
print(spec.model, spec.u, sep="\n")
from_file = sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.TT2())
assert abs(from_file.value - mon["full", "rad"].value) < EXACT_TOL

evil = WORK / "evil.toml"
evil.write_text('name = "evil"\ninputs = ["x"]\noutputs = ["__import__(\'os\').system(\'echo hi\')"]\n'
                '[u]\nmean = [0]\ncov = 1\n')
try:
    sm.load_model_file(evil)
except sm.modelfile.ModelFileError as exc:
    print("refused:", exc)
    assert "line 3, column" in str(exc) and "not allowed" in str(exc)
else:
    raise AssertionError("a malicious model file was accepted")

# %% [markdown]
# ## 5. Noise structures
#
# Declaring noise symbols makes the structure explicit: additive y = f(u) + v,
# multiplicative y = f(u) + Γ(u) v (noise enters linearly), or general. The MoN then
# separates the deterministic part J_Ab from the stochastic part J_n (25)–(27).

# %%
e_r, e_p = sp.symbols("e_r e_p", real=True)
R = sm.Gaussian([0.0, 0.0], np.diag([0.01, 1e-4]))
rng_ = sp.sqrt(x**2 + y**2)
noisy = {
    "additive": sm.Model([x, y], [rng_ + e_r, sp.atan2(y, x) + e_p], noise=[e_r, e_p], name="additive"),
    "multiplicative": sm.Model([x, y], [rng_ * (1 + e_r), sp.atan2(y, x) + e_p], noise=[e_r, e_p], name="mult"),
    "general": sm.Model([x, y], [sp.sqrt(x**2 + y**2 + e_r**2), sp.atan2(y, x) + e_p], noise=[e_r, e_p], name="gen"),
}
for expected, model in noisy.items():
    res = sm.nonlinearity(model, u, R, weight="full", transform=sm.UT.ut1())
    print(f"{model.structure:>15}: MoN {res.value:.4f}  (J_Ab {res.J_Ab:.4f}, J_n {res.J_n:.4f})")
    assert model.structure == expected
    assert 0.0 <= res.value <= 1.0

# %% [markdown]
# ## 6. Estimation: the radar example
#
# Two radars at p₁ = (0, 0) and p₂ = (200, 0) measure range and bearing to a target near
# (100, 100) (Gustafsson & Hendeby's lecture). The **direct** approach maps each
# measurement through x = h⁻¹(y) with the UT and fuses the two estimates; the
# **indirect** approach conditions a prior on the measurements (Lemma 7.1).

# %%
sensors = [(0.0, 0.0), (200.0, 0.0)]
ys = [sm.Gaussian([100 * np.sqrt(2), b], np.diag([5.0, 0.1])) for b in (np.pi / 4, 3 * np.pi / 4)]
hinvs = [sm.problems.radar_hinv(p) for p in sensors]
direct = sm.estimation.direct(None, list(zip(hinvs, ys)), transform=sm.UT.ut1())
print("direct, sensor 1:", direct.estimates[0])
print("direct, fused:   ", direct.fused)

# %%
# The lecture's printed UT estimate for sensor 1: N([95.1, 95.1], [[954, -854], [-854, 954]]).
assert np.allclose(direct.estimates[0].mean, [95.1, 95.1], atol=0.05)
assert np.allclose(direct.estimates[0].cov, [[954, -854], [-854, 954]], atol=0.5)
# Check against Monte Carlo of h⁻¹(y) with error bars.
mc1 = sm.propagate(hinvs[0], ys[0], transform=sm.MonteCarlo(100_000, seed=3))
assert np.all(np.abs(mc1.mean - [95.1, 95.1]) < MC_SIGMAS * mc1.stderr["mean"] + 0.5)
# Fusion shrinks the uncertainty below either sensor's.
assert np.trace(direct.fused.cov) < min(np.trace(g.cov) for g in direct.estimates)

# %%
prior = sm.Gaussian([100.0, 100.0], 400.0 * np.eye(2))
hs = [sm.problems.radar_h(p) for p in sensors]
steps = [(ys[0].mean, ys[0].cov), (ys[1].mean, ys[1].cov, hs[1])]
indirect = sm.estimation.indirect(hs[0], prior, steps, transform=sm.UT.ut1())
print("indirect posterior:", indirect.posterior)
assert np.trace(indirect.posterior.cov) < np.trace(prior.cov)
assert np.linalg.norm(indirect.posterior.mean - [100.0, 100.0]) < 10.0

# %% [markdown]
# The first indirect step by hand: propagate the prior and the noise through h, then condition
# on the measurement. The moments carry the model's angle declaration, so
# `JointMoments.condition` wraps the bearing's innovation by itself.

# %%
m1 = sm.propagate(hs[0], prior, v=sm.Gaussian([0.0, 0.0], ys[0].cov), transform=sm.UT.ut1())
by_hand = m1.condition(ys[0].mean)
print("by hand:", by_hand, " joint angles:", m1.joint_angles)
assert m1.joint_angles == [3]  # [x1, x2, range, bearing]
assert np.allclose(by_hand.mean, indirect.posteriors[0].mean, rtol=EXACT_TOL, atol=0)
assert np.allclose(by_hand.cov, indirect.posteriors[0].cov, rtol=EXACT_TOL, atol=0)

# %% [markdown]
# ## 7. An MMSE estimator of a distance
#
# Given a Kalman estimate N(x̂, P), the MMSE estimate of |aᵀx + b| is E|aᵀx + b| in closed
# form (Theorem 1); the plug-in |aᵀx̂ + b| is biased. Checked here against Monte Carlo.

# %%
xhat, P = np.array([1.0, -0.5]), np.array([[0.5, 0.1], [0.1, 0.3]])
a, b = np.array([1.0, 2.0]), 0.2
est = sm.mmse.abs_linear(a, b, xhat, P)
mse = sm.mmse.abs_linear_mse(a, b, xhat, P)
samples = sm.Gaussian(xhat, P).sample(200_000, np.random.default_rng(4))
vals = np.abs(samples @ a + b)
mc_mean, mc_se = vals.mean(), vals.std(ddof=1) / np.sqrt(vals.size)
print(f"MMSE {est:.5f}, plug-in {abs(a @ xhat + b):.5f}, Monte Carlo {mc_mean:.5f} ± {mc_se:.5f}")
assert abs(est - mc_mean) <= MC_SIGMAS * mc_se
assert abs(abs(a @ xhat + b) - mc_mean) > MC_SIGMAS * mc_se       # the plug-in is visibly biased
assert abs(mse - vals.var(ddof=1)) <= 0.02 * vals.var()            # the MSE of the estimate, to 2 %

# %% [markdown]
# ## 8. Standalone C code
#
# `export_c` writes g, its Jacobian and the TT2 and UT moment maps as self-contained C
# (only `<math.h>`), e.g. for an embedded filter. If a C compiler is present we compile it
# and check that C and Python agree.

# %%
c_files = sm.export_c(polar, WORK / "c", name="polar")
print("wrote", *[p.name for p in c_files])
assert [p.suffix for p in c_files] == [".c", ".h"]
assert "int polar_tt2_eval(" in c_files[1].read_text()

gcc = shutil.which("gcc")
if gcc is not None:
    so = WORK / "c" / "libpolar.so"
    subprocess.run([gcc, "-O2", "-shared", "-fPIC", "-o", str(so), str(c_files[0]), "-lm"], check=True)
    lib = ctypes.CDLL(str(so))

    def ptr(arr: np.ndarray):
        return arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    m_in, P_in = np.ascontiguousarray(u.mean), np.asfortranarray(u.cov)
    mean_c, cov_c, cross_c = np.zeros(2), np.zeros((2, 2), order="F"), np.zeros((2, 2), order="F")
    assert lib.polar_tt2_eval(ptr(m_in), ptr(P_in), ptr(mean_c), ptr(cov_c), ptr(cross_c)) == 0
    tt2 = moments["TT2"]
    assert np.allclose(mean_c, tt2.mean, rtol=EXACT_TOL, atol=EXACT_TOL)
    assert np.allclose(cov_c, tt2.cov, rtol=EXACT_TOL, atol=EXACT_TOL)
    assert np.allclose(cross_c, tt2.cross_cov, rtol=EXACT_TOL, atol=EXACT_TOL)
    print("C and Python TT2 moments agree")

# %%
shutil.rmtree(WORK)
print("tutorial: all checks passed")
