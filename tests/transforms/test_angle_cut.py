"""Angles at the cut ±π: the transforms, the measure of nonlinearity, JointMoments (issue 8).

The reference for a bearing near the cut ±π is the *same* geometry rotated by π: with
u ↦ −u (mean negated, isotropic covariance unchanged) the bearing becomes θ + π and the
range is unchanged.  Rotating by π maps the points of every symmetric rule (UT sigma
points, the Gauss–Hermite grid) onto the points of the rotated problem with the same
weights, and negates the gradient, so a transform that handles the angle correctly
gives the same covariance (and mean + π, cross-covariance negated) to rounding.  Monte
Carlo gets the same property within its standard error.

The angle helpers and the declarations are tested in tests/core/test_angles.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.angles import angle_diff, wrap_angle
from symmon.errors import AngleWarning, ShapeError
from symmon.core.problems import GMTI_SENSOR, bot, gmti

#: Rotation by π maps rule points onto rule points: only rounding differs.  The moments
#: are O(1e-2..1e3), so 1e-9 (relative, or absolute for MoN values in [0, 1]) is rounding
#: with a margin for the cancellation in M² = tr W(Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug).
ROTATION_TOL = 1e-9
#: Exact identities (the circular mean of the samples, TT2 declared or not) agree to rounding.
EXACT_TOL = 1e-12
#: Monte Carlo bound: 5 standard errors (seeded generator).
N_SE = 5
#: The bearing's spread is σ/r = 100/1000 = 0.1; the approximation error of UT and TT2
#: in the variance is of relative order (σ/r)² = 1e-2 (the fourth-order term), so
#: agreement between transforms is asserted to 5 (σ/r)².
APPROX_RTOL = 5 * 0.1**2

x, y = sp.symbols("x y", real=True)
SIGMA = 100.0
P_XY = np.diag([SIGMA**2, SIGMA**2])
CUT = np.array([-1000.0, 0.0])  # the target behind the sensor: bearing ≈ ±π
ROT = -CUT  # the same geometry rotated by π: bearing ≈ 0

DETERMINISTIC = [
    pytest.param(sm.TT2(), id="tt2"),
    pytest.param(sm.UT.ut1(), id="ut1"),
    pytest.param(sm.UT.ut2(), id="ut2"),
    pytest.param(sm.UT.cubature(), id="cubature"),
    pytest.param(sm.GaussHermite(5), id="gh5"),
    pytest.param(sm.GaussHermite(8), id="gh8"),
]
MC = sm.MonteCarlo(2 * 10**5, seed=3)
#: A Gauss–Hermite rule of high order is the reference of the moments (its error for
#: σ/r = 0.1 is far below Monte Carlo's standard error).
REFERENCE = sm.GaussHermite(12)


def polar(angles=None) -> sm.Model:
    return sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar", angles=angles)


# --------------------------------------------------------------------------- a bearing across the cut
@pytest.fixture(scope="module")
def mc_moments():
    u_cut, u_rot = sm.Gaussian(CUT, P_XY), sm.Gaussian(ROT, P_XY)
    with pytest.warns(AngleWarning, match=r"output 1 \(atan2\(y, x\)\).*angles=\[1\]"):
        plain_cut = sm.propagate(polar(), u_cut, transform=MC)  # undeclared across the cut
    return {
        "plain_cut": plain_cut,
        "plain_rot": sm.propagate(polar(), u_rot, transform=MC),
        "angle_cut": sm.propagate(polar([1]), u_cut, transform=MC),
        "reference_rot": sm.propagate(polar([1]), u_rot, transform=REFERENCE),
    }


def test_mc_without_declaration_is_wrong_by_orders_of_magnitude(mc_moments):
    """Samples near +π and −π: the real-number variance is ≈ π² instead of (σ/r)² ≈ 0.01."""
    wrong = mc_moments["plain_cut"].cov[1, 1]
    right = mc_moments["plain_rot"].cov[1, 1]
    assert wrong / right > 100
    # and the range, which has no cut, is unaffected
    se = mc_moments["plain_cut"].stderr["cov"][0, 0] + mc_moments["plain_rot"].stderr["cov"][0, 0]
    assert abs(mc_moments["plain_cut"].cov[0, 0] - mc_moments["plain_rot"].cov[0, 0]) < N_SE * se


def test_mc_with_declaration_matches_the_rotated_reference(mc_moments):
    """Cov, mean (+π) and cross-covariance (negated) within 5 SE of the rotated geometry."""
    m, ref = mc_moments["angle_cut"], mc_moments["reference_rot"]
    se = m.stderr
    assert np.all(np.abs(m.cov - ref.cov) < N_SE * se["cov"])
    assert np.all(np.abs(m.cross_cov + ref.cross_cov) < N_SE * se["cross_cov"])
    assert abs(m.mean[0] - ref.mean[0]) < N_SE * se["mean"][0]
    assert abs(float(angle_diff(m.mean[1], ref.mean[1] + np.pi))) < N_SE * se["mean"][1]
    assert -np.pi < m.mean[1] <= np.pi


@pytest.mark.parametrize("transform", DETERMINISTIC)
def test_declared_transform_equals_its_rotated_self(transform):
    """Each deterministic transform gives the same moments at the cut as rotated away
    from it (rotation by π is exact), once the bearing is declared an angle."""
    model = polar([1])
    a = sm.propagate(model, sm.Gaussian(CUT, P_XY), transform=transform)
    b = sm.propagate(model, sm.Gaussian(ROT, P_XY), transform=transform)
    scale = np.abs(b.cov).max()
    assert np.abs(a.cov - b.cov).max() < ROTATION_TOL * scale
    assert np.abs(a.cross_cov + b.cross_cov).max() < ROTATION_TOL * np.abs(b.cross_cov).max()
    assert a.mean[0] == pytest.approx(b.mean[0], rel=ROTATION_TOL)
    assert abs(float(angle_diff(a.mean[1], b.mean[1] + np.pi))) < ROTATION_TOL
    assert -np.pi < a.mean[1] <= np.pi


@pytest.mark.parametrize("transform", [p for p in DETERMINISTIC if p.id != "tt2"])
def test_sampling_rules_without_declaration_are_wrong(transform):
    """Without the declaration the points straddle the cut and the variance is O(1) rad²;
    an AngleWarning says so."""
    with pytest.warns(AngleWarning, match=r"output 1 \(atan2\(y, x\)\).*angles=\[1\]"):
        a = sm.propagate(polar(), sm.Gaussian(CUT, P_XY), transform=transform)
    b = sm.propagate(polar(), sm.Gaussian(ROT, P_XY), transform=transform)
    assert a.cov[1, 1] > 100 * b.cov[1, 1]


@pytest.mark.parametrize("transform", DETERMINISTIC)
def test_declared_transforms_agree_with_each_other_at_the_cut(transform):
    """UT, Gauss–Hermite and TT2 at the cut agree with the high-order Gauss–Hermite
    reference of the rotated geometry to their approximation accuracy (σ/r)²."""
    a = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=transform)
    ref = sm.propagate(polar([1]), sm.Gaussian(ROT, P_XY), transform=REFERENCE)
    assert a.cov[1, 1] == pytest.approx(ref.cov[1, 1], rel=APPROX_RTOL)
    assert a.cov[0, 0] == pytest.approx(ref.cov[0, 0], rel=APPROX_RTOL)
    assert abs(float(angle_diff(a.mean[1], ref.mean[1] + np.pi))) < APPROX_RTOL * np.sqrt(ref.cov[1, 1])


def test_mc_and_deterministic_agree_at_the_cut(mc_moments):
    """The bearing variance by MC at the cut is within 5 SE of Gauss–Hermite at the cut."""
    gh = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=REFERENCE)
    m = mc_moments["angle_cut"]
    assert abs(m.cov[1, 1] - gh.cov[1, 1]) < N_SE * m.stderr["cov"][1, 1]


def _mc_samples(tr: sm.MonteCarlo, u: sm.Gaussian) -> np.ndarray:
    """The inputs MonteCarlo draws: one stream per group from SeedSequence.spawn (group_normals)."""
    from symmon.transforms.montecarlo import group_normals

    L = np.linalg.cholesky(u.cov)
    seeds = np.random.SeedSequence(tr.seed).spawn(tr.groups)
    Z = [group_normals(s, n, u.dim) for n, s in zip(tr.sizes(), seeds)]
    return u.mean + np.concatenate(Z) @ L.T


def test_mc_angle_mean_is_the_circular_mean_of_its_samples():
    """As in the UT and Gauss–Hermite rules: the mean is atan2(mean sin, mean cos) and the
    variance is taken about it, with wrapped residuals.  The samples are rebuilt from the
    seed; the estimator differs from Σ wrap(b − μ)²/(n − 1) by δ²/(n − 1) (δ the linear
    minus the circular mean, ~1e-5 here), far below EXACT_TOL."""
    u = sm.Gaussian(CUT + [0.0, 30.0], P_XY)
    tr = sm.MonteCarlo(40_000, seed=5, groups=4, chunk=2**14)
    m = sm.propagate(polar([1]), u, transform=tr)
    W = _mc_samples(tr, u)
    b = np.arctan2(W[:, 1], W[:, 0])
    mu = np.arctan2(np.sin(b).mean(), np.cos(b).mean())
    e = wrap_angle(b - mu)
    r = np.hypot(W[:, 0], W[:, 1])
    assert abs(float(angle_diff(m.mean[1], mu))) < EXACT_TOL
    assert m.cov[1, 1] == pytest.approx(e @ e / (len(e) - 1), rel=EXACT_TOL * 100)
    assert m.cov[0, 1] == pytest.approx(np.cov(r, e)[0, 1], rel=1e-9)
    # The linear mean of the unwrapped samples is a different number (third order).
    assert abs(float(angle_diff(np.mean(mu + e), mu))) > 1e3 * EXACT_TOL


def test_mc_angle_error_bar_at_the_cut_is_not_2pi():
    """Left-out groups put the mean on both sides of ±π: the jackknife must unwrap them."""
    m = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=sm.MonteCarlo(20_000, seed=2))
    sd = np.sqrt(m.cov[1, 1] / 20_000)
    assert abs(abs(m.mean[1]) - np.pi) < 5 * sd  # the mean itself sits on the cut
    assert 0.2 * sd < m.stderr["mean"][1] < 5 * sd


# --------------------------------------------------------------------------- MoN across the cut
def _bot_states():
    """BOT z = atan2(x, y): (−ε, −500) is just across the cut; rotated by π: (ε, 500)."""
    cut = np.array([-1e-3, -500.0, 5.0, 8.7])
    return cut, -cut


def _gmti_states():
    """GMTI bearing atan2(x − s_x, y − s_y): across the cut and rotated by π about s."""
    sx, sy, _ = GMTI_SENSOR
    rel = np.array([-1e-3, -500.0])
    cut = np.array([sx + rel[0], sy + rel[1], 5.0, 8.7])
    rot = np.array([sx - rel[0], sy - rel[1], -5.0, -8.7])  # velocities rotate too: ṙ is kept
    return cut, rot


PROBLEMS = {"bot": (bot, 0, _bot_states), "gmti": (gmti, 1, _gmti_states)}


def _mon(name, alpha, transform, declared=True, where="cut"):
    make, idx, states = PROBLEMS[name]
    p = make(alpha)
    model = p.model.with_angles([idx] if declared else [])
    mean = dict(zip(("cut", "rot"), states()))[where]
    return sm.nonlinearity(model, sm.Gaussian(mean, p.u.cov), weight="full", transform=transform)


@pytest.mark.parametrize("alpha", [1.0, 10.0])
@pytest.mark.parametrize("name", sorted(PROBLEMS))
@pytest.mark.parametrize("transform", [sm.TT2(), sm.UT.ut1(), sm.UT.cubature(), sm.GaussHermite(5)],
                         ids=["tt2", "ut1", "cubature", "gh5"])
def test_mon_across_the_cut_equals_rotated(name, alpha, transform):
    """Straka & Havlík (45), (46): the MoN W^full (43) is the same across the cut as for the
    geometry rotated by π, once the bearing is declared an angle (residuals wrapped)."""
    a = _mon(name, alpha, transform, where="cut")
    b = _mon(name, alpha, transform, where="rot")
    assert abs(a.value - b.value) < ROTATION_TOL
    # D = Σ_gg − Σ_gu Σ_uu⁻¹ Σ_ug is a difference of terms of the size of Σ_gg
    assert np.abs(a.residual_cov - b.residual_cov).max() < ROTATION_TOL * np.abs(b.moments.cov).max()


@pytest.fixture(scope="module")
def mc_mons():
    mc = sm.MonteCarlo(10**5, seed=5)
    out = {}
    for name in PROBLEMS:
        for declared, where in ((True, "cut"), (True, "rot"), (False, "cut")):
            if declared:
                out[(name, declared, where)] = _mon(name, 1.0, mc, declared, where)
                continue
            with pytest.warns(AngleWarning, match="angles="):  # undeclared across the cut
                out[(name, declared, where)] = _mon(name, 1.0, mc, declared, where)
    return out


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_mc_mon_across_the_cut(mc_mons, name):
    """MC: within 5 SE of the rotated geometry when declared; far off when not."""
    a, b = mc_mons[(name, True, "cut")], mc_mons[(name, True, "rot")]
    assert abs(a.value - b.value) < N_SE * np.hypot(a.stderr, b.stderr)
    gh = _mon(name, 1.0, sm.GaussHermite(5), where="rot")
    assert abs(a.value - gh.value) < N_SE * a.stderr
    wrong = mc_mons[(name, False, "cut")]
    assert wrong.value - b.value > 100 * np.hypot(wrong.stderr, b.stderr)


def test_tt2_mon_is_local_and_does_not_see_the_cut():
    """TT2 uses derivatives at the mean, which are smooth across the cut: declared or not,
    its BOT MoN is the same (only the mean is wrapped)."""
    a = _mon("bot", 1.0, sm.TT2(), declared=False)
    b = _mon("bot", 1.0, sm.TT2(), declared=True)
    assert a.value == pytest.approx(b.value, rel=EXACT_TOL)


# --------------------------------------------------------------------------- JointMoments carries the angles
def test_joint_moments_carry_the_angle_declarations():
    m = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=sm.UT.ut1())
    assert m.angles == frozenset({1}) and m.input_angles == frozenset()
    assert m.joint_angles == [3]  # [u; y] = [x, y, r, θ]
    with pytest.warns(AngleWarning):  # undeclared, at the cut
        assert sm.propagate(polar(), sm.Gaussian(CUT, P_XY), transform=sm.UT.ut1()).joint_angles == []


def test_joint_moments_condition_at_the_cut_equals_the_rotated_geometry():
    """The bearing observed just across ±π from its prediction: the posterior of u at the
    cut is the rotated posterior negated (u ↦ −u), only if the innovation is wrapped."""
    model, ut = polar([1]), sm.UT.ut1()
    at_cut = sm.propagate(model, sm.Gaussian(CUT, P_XY), transform=ut)
    rotated = sm.propagate(model, sm.Gaussian(ROT, P_XY), transform=ut)
    y_rot = np.array([1010.0, 0.05])
    y_cut = np.array([1010.0, float(wrap_angle(0.05 + np.pi))])  # −3.09, the prediction is ≈ +π
    a, b = at_cut.condition(y_cut), rotated.condition(y_rot)
    np.testing.assert_allclose(a.mean, -b.mean, rtol=ROTATION_TOL)
    # The off-diagonal is 0 up to rounding (its sign is noise): compare at the matrix's scale.
    np.testing.assert_allclose(a.cov, b.cov, rtol=ROTATION_TOL, atol=ROTATION_TOL * np.abs(b.cov).max())
    # by hand, with the declaration passed explicitly: the same Gaussian
    explicit = at_cut.joint.condition([2, 3], y_cut, angles=at_cut.joint_angles)
    np.testing.assert_array_equal(a.mean, explicit.mean)
    # without it, the 2π-sized innovation throws the estimate ~6 σ·r away
    naive = at_cut.joint.condition([2, 3], y_cut)
    assert np.abs(naive.mean - a.mean).max() > 10 * SIGMA


def test_joint_moments_condition_checks_the_observation():
    m = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=sm.UT.ut1())
    with pytest.raises(ShapeError, match=r"y_observed must have shape \(2,\)"):
        m.condition([1000.0])


def test_quadrature_error_estimate_flags_a_bearing_that_reaches_the_origin():
    """README, known limitations: with u ~ N([−2, 0.3], I) the input reaches the sensor,
    the wrapped bearing jumps inside the domain and Gauss–Hermite does not converge.  Its
    two-order error estimate says so; at the well-posed cut (σ/r = 0.1) it is tiny."""
    gh = sm.GaussHermite(10, sparse=False, error_estimate=True)
    near = sm.propagate(polar([1]), sm.Gaussian([-2.0, 0.3], np.eye(2)), transform=gh)
    mc = sm.propagate(polar([1]), sm.Gaussian([-2.0, 0.3], np.eye(2)), transform=sm.MonteCarlo(10**6, seed=1))
    err = abs(float(angle_diff(near.mean[1], mc.mean[1])))
    assert err > N_SE * mc.stderr["mean"][1]  # Gauss–Hermite is visibly wrong here
    assert near.info["error_estimate"]["mean"][0][1] > 0.3 * err  # and its estimate sees it
    far = sm.propagate(polar([1]), sm.Gaussian(CUT, P_XY), transform=gh)
    assert far.info["error_estimate"]["mean"][0][1] < 1e-6
