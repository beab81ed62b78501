"""Angles: circular means, wrapped residuals and innovations, and their declaration (issue 8).

The helpers of :mod:`symmon.core.angles`, the declaration of a model's angle outputs, and
the wrapped innovation of conditioning and fusion. How the transforms and what is built on
them handle an angle at the cut ±π is in tests/transforms/test_angle_cut.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.core.angles import (
    angle_diff,
    angle_indices,
    circular_mean,
    innovation,
    unwrap_near,
    wrap_angle,
    wrap_components,
)
from symmon.errors import ModelError, ShapeError, SymmonError

#: Closed forms (one Lemma 7.1 step, one fusion) agree to rounding.
EXACT_TOL = 1e-12

x, y = sp.symbols("x y", real=True)


def polar(angles=None) -> sm.Model:
    return sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar", angles=angles)


# --------------------------------------------------------------------------- helpers
@pytest.mark.parametrize(
    "a, expected",
    [(0.0, 0.0), (np.pi, np.pi), (-np.pi, np.pi), (3 * np.pi, np.pi), (-3 * np.pi, np.pi),
     (1.5 * np.pi, -0.5 * np.pi), (-1.5 * np.pi, 0.5 * np.pi), (2 * np.pi + 0.25, 0.25), (6.2, 6.2 - 2 * np.pi)],
)
def test_wrap_angle_to_half_open_interval(a, expected):
    """(−π, π]: −π maps to +π, the closed end."""
    assert float(wrap_angle(a)) == pytest.approx(expected, abs=EXACT_TOL)


def test_wrap_angle_is_reexported_by_the_transforms():
    from symmon.transforms import wrap_angle as w2

    assert w2 is wrap_angle


@settings(max_examples=100, deadline=None)
@given(st.floats(-50, 50), st.integers(-3, 3), st.integers(-3, 3))
def test_angle_diff_ignores_multiples_of_2pi(a, k, m):
    d = angle_diff(a + 2 * np.pi * k, a + 0.3 + 2 * np.pi * m)
    assert float(d) == pytest.approx(-0.3, abs=1e-9)


def test_circular_mean_across_the_cut():
    """π − 0.1 and −π + 0.1 average to π, not to 0 as real numbers do."""
    assert abs(float(angle_diff(circular_mean([np.pi - 0.1, -np.pi + 0.1]), np.pi))) < EXACT_TOL
    assert abs(np.mean([np.pi - 0.1, -np.pi + 0.1])) < EXACT_TOL  # the naive mean


@pytest.mark.parametrize("shift", [0.0, 2 * np.pi, -4 * np.pi])
@pytest.mark.parametrize("reference", [None, np.pi, 3.0])
def test_circular_mean_weighted_forms(shift, reference):
    """Both forms (atan2 of mean sin/cos; reference + mean wrapped residual) give the mean
    direction of a sample symmetric about it, invariant to 2π shifts of the samples."""
    centre = np.pi - 0.05
    th = centre + np.array([-0.2, 0.2, -0.1, 0.1, 0.0]) + shift
    w = np.array([0.1, 0.1, 0.25, 0.25, 0.3])
    assert abs(float(angle_diff(circular_mean(th, w, reference=reference), centre))) < EXACT_TOL


def test_circular_mean_reference_form_value():
    """r + Σ wₖ wrap(θₖ − r): the residuals about π are −0.1416, 0.1416, −0.0416."""
    got = circular_mean([3.0, -3.0, 3.1], [0.25, 0.25, 0.5], reference=np.pi)
    assert float(got) == pytest.approx(np.pi + 0.5 * (3.1 - np.pi), abs=EXACT_TOL)


def test_circular_mean_negative_weights_sum_one():
    """Unscented weights can be negative; they are normalised by their (positive) sum."""
    th = np.array([np.pi, np.pi - 0.3, -np.pi + 0.3])
    w = np.array([-1.0, 1.0, 1.0])
    assert abs(float(angle_diff(circular_mean(th, w), np.pi))) < EXACT_TOL


def test_circular_mean_along_an_axis():
    th = np.array([[3.1, -3.1], [0.1, 0.3]])  # samples along axis 1
    got = circular_mean(th, axis=1)
    assert abs(float(angle_diff(got[0], np.pi))) < EXACT_TOL
    assert float(got[1]) == pytest.approx(0.2, abs=EXACT_TOL)


@pytest.mark.parametrize(
    "args, kwargs, err, match",
    [
        (([0.0, np.pi],), {}, SymmonError, "undefined"),  # opposite directions cancel
        (([0.1, 0.2], [1.0, -1.0]), {}, SymmonError, "sum to"),
        (([0.1, 0.2], [1.0, 1.0, 1.0]), {}, ShapeError, "weights must have shape"),
        (([],), {}, ShapeError, "empty"),
        (([0.1, np.nan],), {}, ShapeError, "finite"),
    ],
)
def test_circular_mean_errors(args, kwargs, err, match):
    with pytest.raises(err, match=match):
        circular_mean(*args, **kwargs)


def test_innovation_and_unwrap_near():
    assert innovation([10.0, 3.1], [9.0, -3.1], [1]) == pytest.approx([1.0, 6.2 - 2 * np.pi], abs=EXACT_TOL)
    assert unwrap_near([5.0, -3.1], [0.0, 3.1], [1]) == pytest.approx([5.0, 2 * np.pi - 3.1], abs=EXACT_TOL)
    assert wrap_components([7.0, 7.0], [0]) == pytest.approx([7.0 - 2 * np.pi, 7.0], abs=EXACT_TOL)


@pytest.mark.parametrize(
    "angles, match",
    [([2], "out of range"), ([0.5], "integer"), ([1, 1], "duplicate"), ([True], "integer")],
)
def test_angle_indices_errors_name_the_argument(angles, match):
    with pytest.raises(ShapeError, match=f"angles.*{match}|{match}"):
        angle_indices(angles, 2)


def test_angle_indices_negative_and_none():
    assert angle_indices([-1, 0], 3) == (0, 2)
    assert angle_indices(None, 3) == ()


@pytest.mark.parametrize("angles", [1, [1], {1}, np.int64(1), [np.int64(1)]])
def test_model_angle_declarations(angles):
    assert polar(angles).angle_outputs == frozenset({1})


@pytest.mark.parametrize("angles", [[True], [2], ["phi"]])
def test_model_bad_angle_declarations(angles):
    with pytest.raises(ModelError, match="angle"):
        polar(angles)


# --------------------------------------------------------------------------- conditioning and fusion
#: A joint Gaussian of [x; θ]: a state x and an angle θ predicted at −3.1 rad.
JOINT = sm.Gaussian([0.0, -3.1], [[1.0, 0.05], [0.05, 0.01]])
THETA_OBS = 3.1


def test_condition_wraps_the_innovation():
    """θ observed at +3.1 with prediction −3.1: the innovation is 6.2 − 2π ≈ −0.083 rad,
    and x̂ = 0 + (0.05/0.01)(6.2 − 2π), not 0 + 5 · 6.2 = 31 (Lemma 7.1)."""
    g = JOINT.condition([1], [THETA_OBS], angles=[1])
    nu = 2 * THETA_OBS - 2 * np.pi
    assert g.mean[0] == pytest.approx(0.05 / 0.01 * nu, abs=EXACT_TOL)
    assert g.cov[0, 0] == pytest.approx(1.0 - 0.05**2 / 0.01, abs=EXACT_TOL)
    assert abs(g.mean[0]) < 0.5
    # equal to conditioning on the same angle on the prediction's branch
    same = JOINT.condition([1], [THETA_OBS - 2 * np.pi])
    assert g.mean == pytest.approx(same.mean, abs=EXACT_TOL)
    # without the declaration the correction is the 6.2-rad one
    naive = JOINT.condition([1], [THETA_OBS])
    assert naive.mean[0] == pytest.approx(5 * 6.2, abs=EXACT_TOL)


def test_condition_wraps_an_unobserved_angle():
    """θ̂ = 3.1 + K ν passes π: it is returned wrapped to (−π, π]."""
    g0 = sm.Gaussian([3.1, 0.0], [[0.04, 0.02], [0.02, 0.02]])
    g = g0.condition([1], [0.2], angles=[0])
    raw = 3.1 + 0.02 / 0.02 * 0.2
    assert g.mean[0] == pytest.approx(raw - 2 * np.pi, abs=EXACT_TOL)
    assert -np.pi < g.mean[0] <= np.pi


def test_condition_angles_validated():
    with pytest.raises(ShapeError, match="angles"):
        JOINT.condition([1], [THETA_OBS], angles=[2])


def test_fuse_wraps_the_innovation():
    """Estimates at +3.1 (variance 0.01) and −3.1 (variance 0.03): the second is 2π − 3.1
    on the first one's branch, so the fused angle is 3.1 + ¼(2π − 6.2), near π, not near 0."""
    g1, g2 = sm.Gaussian([3.1], [[0.01]]), sm.Gaussian([-3.1], [[0.03]])
    f = sm.fuse(g1, g2, angles=[0])
    expected = 3.1 + 0.25 * (2 * np.pi - 6.2)  # weights 3/4 and 1/4 on 3.1 and 2π − 3.1
    assert float(f.mean[0]) == pytest.approx(float(wrap_angle(expected)), abs=EXACT_TOL)
    assert float(f.cov[0, 0]) == pytest.approx(1 / (1 / 0.01 + 1 / 0.03), abs=EXACT_TOL)
    naive = sm.fuse(g1, g2)
    assert float(naive.mean[0]) == pytest.approx(0.75 * 3.1 - 0.25 * 3.1, abs=EXACT_TOL)


def test_fuse_equal_estimates_across_the_cut_give_pi():
    f = sm.fuse(sm.Gaussian([0.0, 3.1], np.diag([1.0, 0.01])), sm.Gaussian([2.0, -3.1], np.diag([1.0, 0.01])), angles=[1])
    assert f.mean[0] == pytest.approx(1.0, abs=EXACT_TOL)
    assert abs(float(angle_diff(f.mean[1], np.pi))) < EXACT_TOL
    assert -np.pi < f.mean[1] <= np.pi


def test_fuse_angles_validated():
    with pytest.raises(ShapeError, match="angles"):
        sm.fuse(sm.Gaussian([0.0], [[1.0]]), angles=[1])
