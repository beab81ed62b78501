"""advise_filter with an SDE as f (issue 50): discretised over the measurement intervals, the
sub-steps chosen by the MoN (symmon.filters.sde_advice)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError
from symmon.filters.sde_advice import discretize_track
from symmon.measures.mon import choose_substeps

p, v = sp.symbols("p v", real=True)
q = sp.Symbol("q", positive=True)
WNA = sm.SDE([p, v], [v, 0], diffusion=[0, 1], spectral_density=q, params=[q], name="wna")
H = sm.Model([p, v], [p])
X0 = sm.Gaussian([0.0, 1.0], np.diag([1.0, 0.25]))
TIMES = np.cumsum(np.random.default_rng(2).uniform(0.5, 2.0, 12))

x1, x2 = sp.symbols("x1 x2", real=True)
VDP = sm.SDE([x1, x2], [x2, (1 - x1**2) * x2 - x1], diffusion=[0, 0.3], name="vdp")
VDP_H = sm.Model([x1, x2], [x1])
VDP_X0 = sm.Gaussian([1.5, 0.0], 0.05 * np.eye(2))


def test_a_linear_sde_is_advised_as_its_exact_discretisation_at_the_times():
    """The discrete rows, bit for bit, of advise_filter on the exact discretisation with the
    intervals as per-step dt: the route changes nothing but the input, and adds the
    continuous-discrete rows."""
    a = sm.advise_filter(WNA, H, None, [[0.5]], X0, None, {"q": 0.3}, times=TIMES, runs=16, seed=1)
    f = WNA.discretize("exact")
    b = sm.advise_filter(f, H, np.eye(f.n_v), [[0.5]], X0, len(TIMES), {"q": 0.3, "dt": np.diff(TIMES, prepend=0.0)},
                         runs=16, seed=1)
    assert a.choice == b.choice and a.steps == len(TIMES)
    assert [c.name for c in a.candidates if not c.name.startswith("cd-")] == [c.name for c in b.candidates]
    R = a.runs
    for c in b.candidates:  # the pilot's runs (the choice's second look is longer where the menu costs more)
        if c.kept:
            np.testing.assert_array_equal(next(r for r in a.candidates if r.name == c.name).run_nees[:R],
                                          c.run_nees[:R])
    assert any("'exact' with 1 sub-step" in n for n in a.notes)
    assert a.sde == {"method": "exact", "substeps": 1, "longest_interval": float(np.max(np.diff(TIMES, prepend=0.0))),
                     "flow_mon": 0.0, "substep_mon": 0.0} and b.sde is None


def test_a_nonlinear_sde_gets_the_substeps_its_mon_asks_for():
    track = discretize_track(VDP, None, VDP_X0, None, times=TIMES[:6] / 2, tol=0.1)
    longest = float(np.max(np.diff(TIMES[:6] / 2, prepend=0.0)))
    assert track.method == "taylor1.5" and track.steps == 6
    assert track.substeps == choose_substeps(VDP, VDP_X0, longest, 0.1) > 1
    assert track.f.n_v == 2 * track.substeps          # ξ₁, ξ₂ of each sub-step
    np.testing.assert_array_equal(track.params["dt"], np.diff(TIMES[:6] / 2, prepend=0.0))
    a = sm.advise_filter(VDP, VDP_H, None, [[0.05]], VDP_X0, None, times=TIMES[:6] / 2, tol=0.1, runs=8, seed=0,
                         candidates=["ekf", "ukf"])
    assert any(f"'taylor1.5' with {track.substeps} sub-step" in n for n in a.notes)
    res = a.filter.filter(np.zeros((6, 1)), VDP_X0, params=track.params)
    assert res.x.shape == (6, 2)


def test_intervals_by_params_dt_as_without_times():
    a = discretize_track(WNA, None, X0, 4, {"q": 0.3, "dt": 0.5})
    b = discretize_track(WNA, None, X0, None, {"q": 0.3}, times=[0.5, 1.0, 1.5, 2.0])
    np.testing.assert_array_equal(a.params["dt"], b.params["dt"])
    assert a.steps == b.steps == 4


@pytest.mark.parametrize("call, match", [
    (lambda: discretize_track(WNA, np.eye(2), X0, None, times=TIMES), "Q must be None"),
    (lambda: discretize_track(WNA, None, X0, None, {"dt": 1.0}, times=TIMES), "not both"),
    (lambda: discretize_track(WNA, None, X0, 3, times=TIMES), "len\\(times\\)"),
    (lambda: discretize_track(WNA, None, X0, None, times=[1.0, 0.5]), "times"),
    (lambda: discretize_track(WNA, None, X0, None, times=[0.5, 1.0], t0=0.7), "times"),
    (lambda: discretize_track(WNA, None, X0, 3, {"q": 0.3}), "times=\\[t_1"),
    (lambda: discretize_track(WNA, None, X0, 3, {"dt": [1.0, -1.0, 1.0]}), "positive"),
    (lambda: sm.advise_filter(WNA.discretize("exact"), H, np.eye(2), [[0.5]], X0, 3, times=TIMES[:3]),
     "times and t0 apply to an SDE"),
])
def test_bad_times_and_intervals_are_refused_by_name(call, match):
    with pytest.raises(ArgumentError, match=match):
        call()
