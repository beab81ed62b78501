"""advise on a mixture says how its choice relates to its components' (issue 38, item 18)."""

from __future__ import annotations

import sympy as sp

import symmon as sm

X = sp.Symbol("x")


def test_a_mixtures_choice_names_what_its_components_need():
    """g = x² on two narrow components far apart: the spread between them hides TT1's error
    in the mixed moments (TT1 is chosen), but on a component TT1 misses E x² = μ² + σ² by a
    whole standard deviation while TT2 is exact (to rounding) for a quadratic."""
    u = sm.GaussianMixture([0.5, 0.5], [[0.0], [3.0]], [[[0.01]], [[0.01]]])
    a = sm.advise(sm.Model([X], [X**2], name="adv_mix_sq"), u)
    assert a.choice_name == "TT1"
    (note,) = [n for n in a.notes if n.startswith("u is a mixture")]
    assert "TT1 errs up to" in note and "the cheapest within tol is TT2" in note
    rows = {r["name"]: r for r in a.rows}
    assert rows["TT1"]["component_error"] > 0.5 and rows["TT2"]["component_error"] < 1e-10


def test_a_mixture_whose_components_agree_says_so():
    u = sm.GaussianMixture([0.5, 0.5], [[0.0], [3.0]], [[[0.01]], [[0.01]]])
    a = sm.advise(sm.Model([X], [3 * X + 1], name="adv_mix_lin"), u)
    assert a.choice_name == "TT1" and any("TT1 is also within tol on every component" in n for n in a.notes)
