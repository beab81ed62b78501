"""The transform template and the registry: rules register themselves when their classes
are created, declare their capabilities, and cannot skip the checks of Transform.moments.

These tests create rule classes at run time; each first replaces the registry's table with
a copy (the private ``registry._PRESETS``), so that no test rule stays registered."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled
from symmon.errors import CovarianceError, NonFiniteError, ShapeError, SymmonError
from symmon.transforms import Moments, Transform, registry
from symmon.transforms.registry import make, names

X = sp.symbols("x0:2", real=True)


def test_registry_refuses_unknown_and_duplicate_names(monkeypatch):
    monkeypatch.setattr(registry, "_PRESETS", dict(registry._PRESETS))  # class creation registers: undo it
    with pytest.raises(SymmonError, match="unknown transform 'nope'"):
        make("nope")
    with pytest.raises(SymmonError, match="already registered"):
        _point_rule_class("Again", {"tt1": ("again", lambda **_: sm.TT1())})
    with pytest.raises(SymmonError, match="lower-case word"):
        _point_rule_class("BadName", {"Bad Name": ("no", lambda **_: sm.TT1())})


def _point_rule_class(name: str, presets: dict, **body):
    """A minimal concrete rule (the mean point only), created at run time."""
    def _moments(self, cm, means, covs, angles, executor):
        Y = cm.eval_g(means)
        K, n_y = Y.shape
        return Moments(Y, np.zeros((K, n_y, n_y)), np.zeros((K, n_y, means.shape[1])), evaluations=K)

    ns = {"exact_degree": 1, "name": name.lower(), "presets": presets, "_moments": _moments,
          "cost": lambda self, n_w: 1, **body}
    return dataclass(frozen=True)(type(name, (Transform,), ns))


def test_a_rule_registers_itself_when_its_class_is_created(monkeypatch):
    monkeypatch.setattr(registry, "_PRESETS", dict(registry._PRESETS))
    cls = _point_rule_class("MeanPoint", {"meanpoint": ("g at the mean", lambda **_: cls())})
    assert names()[-1] == "meanpoint" and make("meanpoint") == cls()
    m = sm.propagate(sm.Model(list(X), [X[0] + X[1]]), sm.Gaussian([1.0, 2.0], np.eye(2)), transform=cls())
    assert float(m.mean[0]) == 3.0


@pytest.mark.parametrize("body, missing", [
    ({"cost": Transform.cost}, "cost"),
    ({"stochastic": True}, "replicate_stats, nested_stats"),
])
def test_a_rule_missing_a_declared_capability_fails_when_its_class_is_created(body, missing):
    with pytest.raises(TypeError, match=f"does not declare {missing}"):
        _point_rule_class("Incomplete", {}, **body)


def test_a_rule_cannot_override_the_checked_moments():
    with pytest.raises(TypeError, match="implement the hook _moments"):
        _point_rule_class("Unchecked", {}, moments=lambda self, *a, **k: None)


def test_the_template_checks_every_call_of_a_rule(monkeypatch):
    """No caller can skip the checks: a bad batch is refused before the hook, a NaN after it."""
    cm = compiled(sm.Model(list(X), [X[0] * X[1]], name="arch_template"))
    with pytest.raises(ShapeError, match="needs means"):
        sm.TT2().moments(cm, np.zeros((1, 3)), np.zeros((1, 3, 3)))
    with pytest.raises(CovarianceError):
        sm.TT2().moments(cm, np.zeros((1, 2)), -np.eye(2)[None])
    monkeypatch.setattr(registry, "_PRESETS", dict(registry._PRESETS))
    nan_rule = _point_rule_class("NanRule", {}, _moments=lambda self, cm, m, P, a, e: Moments(
        np.full((1, 1), np.nan), np.zeros((1, 1, 1)), np.zeros((1, 1, 2)), evaluations=1))
    with pytest.raises(NonFiniteError, match="E y"):
        nan_rule().moments(cm, np.zeros((1, 2)), np.eye(2)[None])


def test_a_point_rule_declares_itself_and_its_points_together(monkeypatch):
    monkeypatch.setattr(registry, "_PRESETS", dict(registry._PRESETS))
    with pytest.raises(TypeError, match="does not declare unit_rule"):
        _point_rule_class("NoPoints", {}, point_rule=True)
    with pytest.raises(TypeError, match="does not declare point_rule = True"):
        _point_rule_class("Undeclared", {}, unit_rule=lambda self, n: None)
    assert [t.point_rule for t in (sm.UT(), sm.GaussHermite(), sm.Cubature5(), sm.TT2(), sm.MonteCarlo(1000))] == \
        [True, True, True, False, False]
