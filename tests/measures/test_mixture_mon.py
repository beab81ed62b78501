"""The measure of nonlinearity of a Gaussian-mixture input or noise (issue 24).

The MoN (25)–(29) of Straka & Havlík (FUSION 2024) is defined for any known densities of
u and v; for a mixture it is formed from the mixture's joint moments.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy import integrate, stats

import symmon as sm
from symmon.core.rescale import change_gaussian
from symmon.errors import ArgumentError
from symmon.measures.conditional import conditional_cov
from symmon.transforms.stats import Stats, jackknife, merge_all, moments_of

#: Monte Carlo checks: 5 standard errors (jackknife over the sample's groups).
N_SE = 5.0
#: Unit changes with diagonal S_u map every rule's points exactly (the Cholesky factor of
#: S⁻¹PS⁻ᵀ is S⁻¹L): the MoN agrees to rounding, amplified by the inverses of Σ_uu and Σ_gg.
INVARIANCE_RTOL = 1e-9
#: Gauss–Hermite of order 12 per component on the smooth test model: converged far below
#: the Monte Carlo standard errors it is compared with (orders 10 and 12 agree to 1e-9).
GH = sm.GaussHermite(order=12)

x, y, e1, e2 = sp.symbols("x y e1 e2", real=True)
SMOOTH = sm.Model([x, y], [sp.exp(0.3 * x) * y, sp.sin(x) + 0.5 * y**2])
B = np.array([[1.0, 0.0], [0.5, 2.0]])
ADDITIVE = sm.Model([x, y], [sp.exp(0.3 * x) * y + e1, sp.sin(x) + 0.5 * y**2 + 0.5 * e1 + 2 * e2], noise=[e1, e2])
U = sm.GaussianMixture([0.3, 0.45, 0.25], [[0.0, 1.0], [1.5, -0.5], [-1.0, 0.5]],
                       [[[0.3, 0.1], [0.1, 0.2]], 0.1 * np.eye(2), [[0.2, -0.05], [-0.05, 0.4]]])
V = sm.GaussianMixture([0.8, 0.2], [[0.0, 0.0], [0.3, -0.1]], [0.01 * np.eye(2), [[0.2, 0.05], [0.05, 0.1]]])


def smooth(X: np.ndarray) -> np.ndarray:
    return np.column_stack([np.exp(0.3 * X[:, 0]) * X[:, 1], np.sin(X[:, 0]) + 0.5 * X[:, 1] ** 2])


def sample_mon(Y: np.ndarray, X: np.ndarray, weight: str, Sc: np.ndarray | None = None, groups: int = 20):
    """The MoN of a sample's moments and its jackknife standard error over ``groups`` groups."""
    ny, nu = Y.shape[1], X.shape[1]
    parts = [Stats.of(z) for z in np.array_split(np.hstack([Y, X]), groups)]

    def mon(s: Stats) -> np.ndarray:
        _, cyy, cyw, cww = moments_of(s, ny, nu)
        if cyy.ndim == 2:
            return np.array(sm.mon_from_moments(cyy, cyw, cww, weight, Sc).value)
        return np.array([sm.mon_from_moments(a, b, c, weight, Sc).value for a, b, c in zip(cyy, cyw, cww)])

    return float(mon(merge_all(parts))), float(jackknife(parts, mon))


@pytest.mark.parametrize("weight", ["full", "diag"])
def test_mixture_mon_equals_the_mon_of_a_large_sample(weight, rng):
    X = U.sample(400_000, rng)
    value, se = sample_mon(smooth(X), X, weight)
    mon = sm.nonlinearity(SMOOTH, U, weight=weight, transform=GH)
    assert 0 < mon.value < 1 and se > 0
    assert abs(mon.value - value) < N_SE * se


def test_mixture_mon_with_additive_mixture_noise_equals_the_sample_mon(rng):
    n = 400_000
    X, E = U.sample(n, rng), V.sample(n, rng)
    Sc = B @ V.cov @ B.T  # (29): Cov_v E[g | v] = B Σ_vv Bᵀ, Σ_vv the mixture's covariance
    value, se = sample_mon(smooth(X) + E @ B.T, X, "full", Sc)
    mon = sm.nonlinearity(ADDITIVE, U, V, transform=GH)
    assert ADDITIVE.structure == "additive"
    assert abs(mon.value - value) < N_SE * se


def test_monte_carlo_mixture_mon_has_an_honest_error_bar():
    mc = sm.nonlinearity(SMOOTH, U, transform=sm.MonteCarlo(n=50_000, seed=3))
    assert mc.stderr is not None and mc.stderr > 0
    assert abs(mc.value - sm.nonlinearity(SMOOTH, U, transform=GH).value) < N_SE * mc.stderr


def test_tt1_of_a_mixture_is_not_zero():
    # One linearisation per component is piecewise affine, not affine: the mixture sees it.
    assert sm.nonlinearity(SMOOTH, U, transform=sm.TT1()).value > 0.1


def one(g: sm.Gaussian) -> sm.GaussianMixture:
    return sm.GaussianMixture([1.0], g.mean[None], g.cov[None])


@pytest.mark.parametrize(("model", "args"), [(SMOOTH, (U.components[1],)), (ADDITIVE, (U.components[1], V.components[1]))],
                         ids=["noise-free", "additive"])
def test_one_component_mixture_mon_equals_the_gaussian_mon(model, args):
    a = sm.nonlinearity(model, *args, transform=sm.UT.ut1())
    b = sm.nonlinearity(model, *map(one, args), transform=sm.UT.ut1())
    assert b.value == pytest.approx(a.value, rel=1e-12)


def test_general_noise_conditional_term_against_quadrature():
    """Σ_c = Var_v E[g | v] of g = exp(x e) (general noise) with mixtures of u and v:
    E_k[exp(x e) | e] = exp(μ_k e + P_k e²/2) in closed form, and the variance over the
    mixture of e by adaptive quadrature (scipy), an independent method."""
    u = sm.GaussianMixture([0.4, 0.6], [0.5, 1.0], [0.04, 0.09])
    v = sm.GaussianMixture([0.7, 0.3], [0.0, 0.2], [0.01, 0.04])
    model = sm.Model([x], [sp.exp(x * e1)], noise=[e1])
    assert model.structure == "general"

    def h(e):
        return sum(w * np.exp(m * e + P * e**2 / 2) for w, m, P in zip(u.weights, u.means[:, 0], u.covs[:, 0, 0]))

    def p(e):
        return sum(w * stats.norm.pdf(e, m, np.sqrt(P)) for w, m, P in zip(v.weights, v.means[:, 0], v.covs[:, 0, 0]))

    m1 = integrate.quad(lambda e: h(e) * p(e), -3, 3, epsabs=1e-14, epsrel=1e-13)[0]
    m2 = integrate.quad(lambda e: h(e) ** 2 * p(e), -3, 3, epsabs=1e-14, epsrel=1e-13)[0]
    Sc = conditional_cov(model, u, v, sm.GaussHermite(order=10))
    # The outer rule (Gauss–Hermite of order 5 per component, exact to degree 9) on a
    # function this smooth over σ ≤ 0.2, and the inner one of order 10: below 1e-9 relative.
    assert Sc[0, 0] == pytest.approx(m2 - m1**2, rel=1e-9)


def test_multiplicative_noise_mixture_matches_the_general_formula():
    """(28) with mixtures, π̄ Σ_γγ π̄ᵀ, equals the general nested formula of the module notes
    on the same model written so that the structure is not recognised."""
    mult = sm.Model([x, y], [x + y * e1, sp.sin(x) + x * y * e2], noise=[e1, e2])
    assert mult.structure == "multiplicative"
    from symmon.measures.conditional import _general_cov_mixture
    rule = sm.GaussHermite(order=6)
    np.testing.assert_allclose(conditional_cov(mult, U, V, rule), _general_cov_mixture(mult, U, V, rule),
                               rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize(("weight", "S_y"), [("full", [[3.0, 1.0], [0.0, 0.2]]), ("diag", np.diag([3.0, 0.2]))])
def test_unit_invariance_for_mixtures(weight, S_y):
    """(42) is invariant under diagonal output scalings, (43) under any invertible S_y."""
    S_u, o_u = np.diag([2.0, 0.5]), np.array([1.0, -3.0])
    S_v = np.diag([0.1, 4.0])
    for model, args in ((SMOOTH, (U,)), (ADDITIVE, (U, V))):
        ref = sm.nonlinearity(model, *args, weight=weight, transform=sm.GaussHermite(order=6))
        bar = sm.core.change_units(model, S_u=S_u, o_u=o_u, S_y=S_y, o_y=[5.0, -1.0],
                                   S_v=S_v if model.n_v else None)
        new = [change_gaussian(U, S_u, o_u)] + ([change_gaussian(V, S_v)] if model.n_v else [])
        m = sm.nonlinearity(bar, *new, weight=weight, transform=sm.GaussHermite(order=6))
        assert m.value == pytest.approx(ref.value, rel=INVARIANCE_RTOL)


def test_compare_takes_a_mixture():
    rows = sm.compare(SMOOTH, U, transforms=[sm.TT2(), sm.UT.ut1(), GH])
    assert [r["transform"] for r in rows] == ["TT2()", "UT.ut1()", repr(GH)]
    assert all(0 < r["value"] < 1 for r in rows)


def test_monte_carlo_with_a_mixture_and_general_noise_is_refused():
    model = sm.Model([x], [sp.exp(x * e1)], noise=[e1])
    with pytest.raises(ArgumentError, match="use a deterministic transform"):
        sm.nonlinearity(model, sm.GaussianMixture([1.0], [0.5], [0.1]), sm.Gaussian([0.0], [[0.1]]),
                        transform=sm.MonteCarlo(n=1000, seed=0))


def test_sweep_states_takes_mixtures_for_a_deterministic_rule():
    g = sm.Gaussian([0.5, 0.5], 0.2 * np.eye(2))
    r = sm.sweep.sweep_states(SMOOTH, [U, g], transform=sm.UT.ut1())
    for k, d in enumerate((U, g)):
        assert r.value[k] == pytest.approx(sm.nonlinearity(SMOOTH, d, transform=sm.UT.ut1()).value, rel=1e-12)


def test_what_takes_no_mixture_or_particles_says_so():
    from symmon.errors import ArgumentTypeError
    with pytest.raises(ArgumentTypeError, match="u must be a list of K Gaussians"):
        sm.sweep.sweep_states(SMOOTH, [U], transform=sm.MonteCarlo(n=1000, seed=0))
    with pytest.raises(ArgumentTypeError, match="sweep_alpha takes a GaussianMixture with a deterministic"):
        sm.sweep.sweep_alpha(SMOOTH, U, [0.5, 1.0], transform=sm.MonteCarlo(n=1000, seed=0))
    with pytest.raises(ArgumentTypeError, match="u must be a symmon.Gaussian or GaussianMixture"):
        sm.sweep.sweep_alpha(SMOOTH, sm.Empirical(U.sample(50, 0)), [0.5, 1.0])
    with pytest.raises(ArgumentTypeError, match="particles need none"):
        sm.advise(SMOOTH, sm.Empirical(U.sample(500, 0)))
