"""How nonlinear is a step of an SDE (issue 50, item 5): ``sm.nonlinearity(sde, prior, dt=...)``
is the unitless MoN of the flow map x(t) ↦ x(t + dt) with its noise."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, SymmonError
from symmon.measures.mon import FLOW_SUBSTEPS, choose_substeps, flow_model

p, v = sp.symbols("p v", real=True)
q = sp.Symbol("q", positive=True)
theta = sp.Symbol("theta", positive=True)
IOU = sm.SDE([p, v], [v, -theta * v], diffusion=[0, 1], spectral_density=q, params=[q, theta])
x1, x2 = sp.symbols("x1 x2", real=True)
VDP = sm.SDE([x1, x2], [x2, 1.5 * (1 - x1**2) * x2 - x1], diffusion=[0, 0.4], name="vdp")
VDP_PRIOR = sm.Gaussian([1.2, -0.3], [[0.09, 0.02], [0.02, 0.16]])


@pytest.mark.parametrize("transform", [None, sm.UT.cubature()])
def test_the_flow_of_a_linear_sde_is_affine(transform):
    """MoN 0 to rounding: a point rule sees no residual beyond the float error of its sums
    (M² ~ 1e-16, so M ~ 1e-8); TT2 sees zero Hessians."""
    prior = sm.Gaussian([0.0, 1.0], np.diag([1.0, 0.5]))
    mon = sm.nonlinearity(IOU, prior, dt=0.7, params={"q": 0.5, "theta": 0.7}, transform=transform)
    assert 0.0 <= float(mon) < 1e-6


def test_the_flow_of_a_nonlinear_sde_is_more_nonlinear_over_longer_steps():
    mons = [float(sm.nonlinearity(VDP, VDP_PRIOR, dt=dt)) for dt in (0.05, 0.2, 0.5, 1.0)]
    assert np.all(np.diff(mons) > 0), mons
    assert mons[0] > 0.01 and mons[-1] < 1.0  # unitless, in [0, 1]


def test_the_flow_is_the_discretisation_at_the_step():
    model, values = flow_model(VDP, 0.3)
    assert values == {"dt": 0.3}
    assert model.n_v == 2 * FLOW_SUBSTEPS  # taylor1.5: ξ₁ and ξ₂ of each sub-step
    euler, _ = flow_model(VDP, 0.3, method="euler", substeps=2)
    assert euler.n_v == 2
    direct = sm.nonlinearity(model, VDP_PRIOR, sm.Gaussian(np.zeros(model.n_v), np.eye(model.n_v)), params=values)
    assert float(sm.nonlinearity(VDP, VDP_PRIOR, dt=0.3)) == float(direct)


@pytest.mark.parametrize("kwargs, match", [
    (dict(dt=0.0), "dt .*positive"),
    (dict(dt=None), "dt .*positive"),
    (dict(dt=0.1, v=sm.Gaussian([0.0], [[1.0]])), "v must not be given"),
    (dict(dt=0.1, params={"dt": 0.2}), "must not give 'dt'"),
])
def test_bad_flow_arguments_are_refused(kwargs, match):
    with pytest.raises(ArgumentError, match=match):
        sm.nonlinearity(VDP, VDP_PRIOR, **kwargs)


def test_a_model_takes_no_step():
    with pytest.raises(ArgumentError, match="for the flow of an SDE"):
        sm.nonlinearity(sm.Model([x1], [x1**2]), sm.Gaussian([0.0], [[1.0]]), dt=0.1)


# --------------------------------------------------------------------------- sub-steps by the MoN
def test_choose_substeps_gives_the_fewest_that_bring_a_sub_step_within_tol():
    """N is the smallest power of two with the sub-step's MoN ≤ tol: N/2 sub-steps exceed it."""
    tol, dt = 0.1, 0.8
    N = choose_substeps(VDP, VDP_PRIOR, dt, tol)
    assert N >= 2
    assert float(sm.nonlinearity(VDP, VDP_PRIOR, dt=dt / N, substeps=1)) <= tol
    assert float(sm.nonlinearity(VDP, VDP_PRIOR, dt=dt / (N // 2), substeps=1)) > tol
    # a stricter tolerance or a longer step needs more sub-steps
    assert choose_substeps(VDP, VDP_PRIOR, dt, tol / 4) > N
    assert choose_substeps(VDP, VDP_PRIOR, 2 * dt, tol) == 2 * N


def test_choose_substeps_of_a_linear_sde_is_one():
    prior = sm.Gaussian([0.0, 1.0], np.diag([1.0, 0.5]))
    assert choose_substeps(IOU, prior, 5.0, 1e-6, {"q": 0.5, "theta": 0.7}) == 1


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tol": 0.0}, ArgumentError, "tol must be a positive"),
    ({"max_substeps": 0}, ArgumentError, "max_substeps must be"),
    ({"dt": -1.0}, ArgumentError, "dt"),
    ({"tol": 1e-6, "max_substeps": 2}, SymmonError, "above tol"),
])
def test_choose_substeps_refuses_bad_arguments_and_says_when_no_n_is_enough(kwargs, error, match):
    args = {"dt": 0.8, **kwargs}
    with pytest.raises(error, match=match):
        choose_substeps(VDP, VDP_PRIOR, **args)
