"""The transform abstraction (issue 14): declared capabilities, the registry, the executor,
and the declared degree of every registered rule checked against exact moments."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import options as cli_options
from symmon.compile import CompiledModel
from symmon.errors import SymmonError
from symmon.compile import compiled
from symmon.transforms import Cubature5, Executor, Transform
from symmon.transforms.registry import make, names, presets

#: Closed-form moments against a rule that is exact for them: rounding only.
EXACT_RTOL = 1e-10

X = sp.symbols("x0:2", real=True)
MU = np.array([0.6, -0.3])
P = np.array([[0.5, 0.15], [0.15, 0.3]])


def _poly(degree: int, rng: np.random.Generator) -> sp.Expr:
    """Every monomial of total degree ≤ ``degree`` in X, with random coefficients."""
    terms = [X[0] ** a * X[1] ** b for a, b in itertools.product(range(degree + 1), repeat=2) if a + b <= degree]
    return sum(float(c) * t for c, t in zip(rng.uniform(-1, 1, len(terms)), terms))


def _moments(tr: Transform, exprs: list, name: str):
    cm = CompiledModel(exprs, list(X), name=name, compiled=False)  # the VM: no C build per random model
    return tr.moments(cm, MU[None], P[None])


def _rtol(tr: Transform) -> float:
    # ut2's weights are ~1/α² = 10⁶: they multiply the rounding of the points (test_transforms.rtol_for).
    return max(EXACT_RTOL, 10 * np.finfo(float).eps / tr.alpha**2) if isinstance(tr, sm.UT) else EXACT_RTOL


DETERMINISTIC = [p.name for p in presets() if not make(p.name).stochastic]


@pytest.mark.parametrize("name", DETERMINISTIC)
def test_every_registered_rule_is_exact_to_its_declared_degree(name):
    """The mean is exact for g of the declared degree d, the covariances for degree ⌊d/2⌋
    (their integrands are products of two outputs): one test for every registered rule."""
    tr = make(name)
    d = int(tr.exact_degree)
    rng = np.random.default_rng(sum(map(ord, name)))
    mean_model = [_poly(d, rng)]
    got, ref = _moments(tr, mean_model, f"arch_mean_{name}"), _moments(sm.Exact(), mean_model, f"arch_mean_{name}")
    scale = max(np.abs(ref.mean).max(), 1.0)
    np.testing.assert_allclose(got.mean, ref.mean, rtol=0, atol=_rtol(tr) * scale)
    cov_model = [_poly(d // 2, rng), _poly(d // 2, rng)]
    got, ref = _moments(tr, cov_model, f"arch_cov_{name}"), _moments(sm.Exact(), cov_model, f"arch_cov_{name}")
    for what in ("cov", "cross_cov"):
        a, b = getattr(got, what), getattr(ref, what)
        np.testing.assert_allclose(a, b, rtol=0, atol=_rtol(tr) * max(np.abs(b).max(), 1.0), err_msg=what)


@pytest.mark.parametrize("name", names())
def test_every_registered_rule_declares_its_cost_and_counts_it(name):
    """The declared cost (advise's cost model) is the evaluations of g one Gaussian takes:
    the points of a point rule or the samples, and for a Taylor rule its one point plus
    the derivatives (each counted as evaluations of g)."""
    tr = make(name, samples=2_000, groups=4)
    m = sm.propagate(sm.Model(list(X), [X[0] * sp.sin(X[1])], name="arch_cost"), sm.Gaussian(MU, P), transform=tr)
    assert m.evaluations == m.info["evaluations"] > 0
    if tr.stochastic or tr.unit_rule(2) is not None:
        assert tr.cost(2) == m.evaluations
    else:
        assert tr.cost(2) > m.evaluations == 1


def test_cubature5_is_gauss_hermite_3_in_one_dimension():
    x = X[0]
    model, u = sm.Model([x], [sp.exp(x) + x**7]), sm.Gaussian([0.2], [[0.7]])
    a, b = sm.propagate(model, u, transform=Cubature5()), sm.propagate(model, u, transform=sm.GaussHermite(3))
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-13)
    np.testing.assert_allclose(a.cov, b.cov, rtol=1e-13)


def test_transform_is_abstract():
    with pytest.raises(TypeError, match="abstract"):
        Transform()


def test_execution_settings_are_not_part_of_the_method():
    """Where Monte Carlo runs is an Executor passed to propagate, never a field of the method."""
    assert not {"workers", "client", "scheduler", "progress"} & {f.name for f in dataclasses.fields(sm.MonteCarlo)}
    with pytest.raises(TypeError):
        sm.MonteCarlo(workers=4)
    assert sm.MonteCarlo(seed=1) != sm.MonteCarlo(seed=2)


def test_an_executor_does_not_change_the_numbers():
    """The same MonteCarlo on one thread, on three, and on a local Dask scheduler given
    as executors: bit for bit the same moments and MoN (general noise: the nested run too)."""
    u_, v_ = sp.symbols("u_ v_", real=True)
    model = sm.Model([u_], [sp.sin(u_ + v_) + u_ * v_**2], noise=[v_], name="arch_exec")
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    mc = sm.MonteCarlo(8_000, seed=2, groups=4)
    runs = [sm.nonlinearity(model, u, v, transform=mc, executor=ex)
            for ex in (Executor(workers=1), Executor(workers=3), Executor(scheduler="synchronous"))]
    for r in runs[1:]:
        assert (r.value, r.stderr) == (runs[0].value, runs[0].stderr)
        np.testing.assert_array_equal(r.moments.cov, runs[0].moments.cov)


def test_executor_refuses_a_bad_worker_count():
    with pytest.raises(SymmonError, match="workers must be >= 1"):
        Executor(workers=0)


def test_registry_names_drive_the_cli():
    assert cli_options.transform_names() == names()
    assert {"tt1", "tt2", "ut1", "ut2", "ct", "gh", "qmc", "mc", "ct5"} <= set(names())
    assert cli_options.transform_from_name("ct5") == Cubature5()
    assert make("mc", samples=1000, seed=3) == sm.MonteCarlo(1000, seed=3)


def test_a_point_rule_declares_its_unit_points_and_a_taylor_rule_none():
    Z, wm, wc = Cubature5().unit_rule(3)
    assert Z.shape == (2 * 9 + 1, 3) and wm.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(np.einsum("n,ni,nj->ij", wm, Z, Z), np.eye(3), atol=1e-14)
    assert sm.TT2().unit_rule(3) is None


def test_moments_one_spelling():
    """The batched result and its single-point view use the same keys."""
    model = sm.Model(list(X), [X[0] * X[1]], name="arch_keys")
    mc = sm.MonteCarlo(4_000, seed=1, groups=4)
    m = sm.propagate(model, sm.Gaussian(MU, P), transform=mc)
    b = mc.moments(compiled(model), MU[None], P[None])
    assert set(m.stderr) == set(b.stderr) == {"mean", "cov", "cross_cov"}
    assert len(m.replicates) == 4 and m.replicates is m.info["groups"]
    np.testing.assert_array_equal(m.cross_cov, b.cross_cov[0])


def test_a_filter_compiles_any_point_rule_from_its_declared_points():
    """Cubature5 is Gauss–Hermite 3 in one dimension: the Kalman filters built from their
    declared unit rules agree to rounding."""
    x = sp.Symbol("x", real=True)
    f = sm.Model([x], [x + 0.1 * sp.sin(x)], name="arch_kf_f")
    h = sm.Model([x], [x**2 / 4 + x], name="arch_kf_h")
    ys = np.array([[0.3], [0.8], [1.1], [0.9]])
    x0 = sm.Gaussian([0.2], [[0.5]])
    a = sm.NonlinearKalmanFilter(f, h, [[0.01]], [[0.1]], Cubature5()).filter(ys, x0)
    b = sm.NonlinearKalmanFilter(f, h, [[0.01]], [[0.1]], sm.GaussHermite(3)).filter(ys, x0)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-12)


def test_nothing_above_the_transforms_tests_for_a_concrete_rule():
    """What a caller needs to know about a rule, the rule declares (docs/architecture.md, the
    Transform contract; issue 38, item 18): no isinstance(t, GaussHermite) outside transforms/."""
    import ast
    from pathlib import Path

    import symmon.transforms as tr

    concrete = {n for n in tr.__all__ if isinstance(getattr(tr, n), type)
                and issubclass(getattr(tr, n), Transform) and getattr(tr, n) is not Transform}
    root = Path(sm.__file__).parent
    bad = []
    for path in sorted(root.rglob("*.py")):
        if path.relative_to(root).parts[0] == "transforms":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and len(node.args) == 2:
                classes = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
                names = {c.attr if isinstance(c, ast.Attribute) else getattr(c, "id", None) for c in classes}
                if names & concrete:
                    bad.append(f"{path.relative_to(root)}:{node.lineno} {sorted(names & concrete)}")
    assert not bad, bad


def test_a_gauss_hermite_grid_left_to_the_dimension_is_made_explicit():
    gh = sm.GaussHermite(5)
    assert gh.for_dimension(3, 10**4) == (sm.GaussHermite(5, sparse=False), "")
    assert gh.for_dimension(8, 10**4) == (sm.GaussHermite(5, sparse=True), "sparse")
    assert sm.GaussHermite(5, sparse=False).for_dimension(8, 10) == (sm.GaussHermite(5, sparse=False), "")
    assert sm.UT.ut1().for_dimension(8, 10) == (sm.UT.ut1(), "")
