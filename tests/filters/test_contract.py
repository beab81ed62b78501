"""The filter contract (issue 49): every filter subclasses ``symmon.filters.base.Filter``, whose
final ``filter`` checks the inputs once, hands banks to an executor once and calls the family's
``_filter``; the registry names every filter once, for Python, scenario files and the CLI.

The generic checks run every registered filter class through the same calls: shapes of a single
run and of a bank, missing rows, parameters, bad input, pickling, and a bank in shards equal bit
for bit to the whole bank.
"""

from __future__ import annotations

import pickle
import re

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.errors import ArgumentError, ModelError, ShapeError, SymmonError
from symmon.filters.bank import filter_bank
from symmon.filters.base import Filter, filter_classes
from symmon.filters.names import RULE_FILTERS, filter_rule
from symmon.filters.registry import FilterEntry, filter_entry, filter_names, make_filter, register

x, v, a = sp.symbols("x v a", real=True)
#: A constant-velocity target with a gain parameter a in its dynamics, and its position measured.
F_MODEL = sm.Model([x, v], [x + a * v, v], params=[a], name="contract_f")
H_MODEL = sm.Model([x, v], [x], name="contract_h")
Q, R = 0.01 * np.eye(2), np.array([[0.5]])
PRIOR = sm.Gaussian([0.0, 1.0], np.eye(2))
K, RUNS = 6, 4


def _filters() -> dict[str, Filter]:
    """One filter of each registered class (the linear one without parameters)."""
    lin_f = sm.Model([x, v], [x + v, v], name="contract_lin_f")
    kf = sm.KalmanFilter([[1.0, 1.0], [0.0, 1.0]], Q, [[1.0, 0.0]], R)
    ekf = sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, Q, R, "ekf")
    quiet = sm.NonlinearKalmanFilter(lin_f, H_MODEL, 1e-4 * np.eye(2), R, "ekf")
    return {
        "KalmanFilter": kf,
        "NonlinearKalmanFilter": ekf,
        "ParticleFilter": sm.ParticleFilter(F_MODEL, H_MODEL, Q, R, particles=200, seed=3),
        "GaussianSumFilter": sm.GaussianSumFilter(F_MODEL, H_MODEL, Q, R, "ekf"),
        "IMM": sm.IMM([quiet, kf], [[0.9, 0.1], [0.1, 0.9]], [0.5, 0.5]),
        "EnsembleKalmanFilter": sm.EnsembleKalmanFilter(F_MODEL, H_MODEL, Q, R, members=50, seed=2),
        # The SDE of F_MODEL: dx = a v dt, dv = dβ; its interval dt is a per-step parameter.
        "ContinuousDiscreteKalmanFilter": sm.ContinuousDiscreteKalmanFilter(
            sm.SDE([x, v], [a * v, 0], diffusion=[0, 1], spectral_density=0.01, params=[a]), H_MODEL, R, "ekf"),
    }


FILTERS = _filters()
NAMES = sorted(FILTERS)


def _params(filt: Filter, runs: int | None = None) -> dict | None:
    if not filt.params:
        return None
    values = {"a": np.linspace(0.9, 1.1, K) if runs is None else np.linspace(0.9, 1.1, runs * K).reshape(runs, K)}
    if "dt" in {str(s) for s in filt.params}:  # a continuous-discrete filter: the intervals, irregular
        values["dt"] = np.linspace(0.5, 1.5, K)
    return values


def _data(runs: int | None, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    xs, ys = sm.simulate(F_MODEL.with_params({"a": 1.0}), H_MODEL, Q, R, PRIOR, K, runs=runs, seed=seed)
    return np.asarray(xs), np.asarray(ys)


def test_every_filter_class_is_covered_here():
    """A filter added to symmon is added to these checks (or this test says which is missing)."""
    assert set(filter_classes()) <= set(FILTERS)


@pytest.mark.parametrize("name", NAMES)
def test_a_single_run_and_a_bank_have_the_shapes_of_the_contract(name):
    filt = FILTERS[name]
    n, n_y = filt.sizes
    xs, ys = _data(None)
    one = filt.filter(ys, PRIOR, params=_params(filt), x_true=xs)
    assert one.x.shape == (K, n) and one.loglik.shape == (K,) and one.runs is None
    assert np.all(np.isfinite(one.nees())) and one.nees().shape == (K,)
    xb, yb = _data(RUNS)
    bank = filt.filter(yb, PRIOR, params=_params(filt, RUNS), x_true=xb)
    assert bank.x.shape == (RUNS, K, n) and bank.runs == RUNS and bank.nees().shape == (RUNS, K)


@pytest.mark.parametrize("name", NAMES)
def test_a_row_of_nan_only_predicts(name):
    filt = FILTERS[name]
    xs, ys = _data(None)
    ys = ys.copy()
    ys[2] = np.nan
    res = filt.filter(ys, PRIOR, params=_params(filt))
    assert res.loglik[2] == 0.0 and np.all(np.isfinite(res.x))


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("call, error, match", [
    (dict(ys=np.ones((K, 3))), ShapeError, r"ys must have shape"),
    (dict(ys=np.full((K, 1), np.inf)), ShapeError, "ys contains inf"),
    (dict(keep="gain"), ArgumentError, r"keep names \['gain'\]"),
    (dict(x_true=np.zeros((K + 1, 2))), ShapeError, "x_true"),
    (dict(first_run=-1), ArgumentError, "first_run must be a non-negative integer"),
    (dict(params={"b": 1.0}), ModelError, "params|parameters"),
])
def test_bad_input_gets_the_same_clear_error_from_every_filter(name, call, error, match):
    filt = FILTERS[name]
    _, ys = _data(None)
    kw = {"ys": ys, "params": _params(filt), **call}
    with pytest.raises(error, match=match):
        filt.filter(kw.pop("ys"), PRIOR, **kw)


@pytest.mark.parametrize("name", NAMES)
def test_a_string_keeps_one_array(name):
    filt = FILTERS[name]
    _, ys = _data(None)
    res = filt.filter(ys, PRIOR, params=_params(filt), keep="x")
    assert res.x is not None and res.P is None


@pytest.mark.parametrize("name", NAMES)
def test_a_bank_in_shards_is_the_whole_bank_bit_for_bit(name):
    filt = FILTERS[name]
    xb, yb = _data(RUNS)
    whole = filt.filter(yb, PRIOR, params=_params(filt, RUNS), x_true=xb)
    shards = filt.filter(yb, PRIOR, params=_params(filt, RUNS), x_true=xb,
                         executor=sm.Executor(scheduler="synchronous"))
    assert type(shards) is type(whole)
    for field in ("x", "loglik", "nees_values"):
        np.testing.assert_array_equal(getattr(shards, field), getattr(whole, field))


def test_a_random_filter_continues_a_larger_bank_from_first_run():
    """The pieces of a bank, each from its first run, are the whole bank (issue 47, item 6),
    with an executor too."""
    pf = FILTERS["ParticleFilter"]
    _, yb = _data(RUNS)
    p = _params(pf, RUNS)
    whole = pf.filter(yb, PRIOR, params=p)
    tail = {"a": p["a"][1:]}
    alone = pf.filter(yb[1:], PRIOR, params=tail, first_run=1)
    sharded = pf.filter(yb[1:], PRIOR, params=tail, first_run=1, executor=sm.Executor(scheduler="synchronous"))
    np.testing.assert_array_equal(alone.x, whole.x[1:])
    np.testing.assert_array_equal(sharded.x, whole.x[1:])
    with pytest.raises(ArgumentError, match="draws none"):
        FILTERS["NonlinearKalmanFilter"].filter(yb, PRIOR, params=p, first_run=1)


@pytest.mark.parametrize("name", NAMES)
def test_a_filter_pickles_to_the_same_numbers(name):
    filt = FILTERS[name]
    _, ys = _data(None)
    again = pickle.loads(pickle.dumps(filt))
    np.testing.assert_array_equal(again.filter(ys, PRIOR, params=_params(filt)).x,
                                  filt.filter(ys, PRIOR, params=_params(filt)).x)


# ------------------------------------------------------------------ measurement times
#: Irregular measurement times after T0, and a bank's own times (one row per run).
T0 = 0.25
TIMES = T0 + np.cumsum(np.linspace(0.5, 1.5, K))
RUN_TIMES = T0 + np.cumsum(np.linspace(0.4, 1.6, RUNS * K).reshape(RUNS, K), axis=1)


def _no_dt(params: dict | None) -> dict | None:
    return None if params is None else {k: v for k, v in params.items() if k != "dt"}


@pytest.mark.parametrize("name", [n for n in NAMES if not FILTERS[n].continuous_time])
@pytest.mark.parametrize("kw, given", [(dict(times=TIMES), "times"), (dict(t0=1.0), "t0"),
                                       (dict(times=TIMES, t0=T0), "times")])
def test_a_discrete_filter_refuses_times_saying_it_is_discrete(name, kw, given):
    filt = FILTERS[name]
    _, ys = _data(None)
    with pytest.raises(ArgumentError, match=rf"{re.escape(filt.method)} is a discrete-time filter: it takes no "
                                            rf"{given}.*ContinuousDiscreteKalmanFilter.*per-step dt"):
        filt.filter(ys, PRIOR, params=_params(filt), **kw)


def test_only_the_continuous_discrete_filter_takes_times():
    assert [n for n in NAMES if FILTERS[n].continuous_time] == ["ContinuousDiscreteKalmanFilter"]
    assert not Filter.continuous_time


@pytest.mark.parametrize("name", [n for n in NAMES if FILTERS[n].continuous_time])
def test_times_give_the_numbers_of_their_intervals_bit_for_bit(name):
    """``times`` after ``t0`` and ``params["dt"]`` = their intervals are one call: one run, and
    a bank with one row of times per run, whole and in shards."""
    filt = FILTERS[name]
    xs, ys = _data(None)
    by_dt = filt.filter(ys, PRIOR, params={**_params(filt), "dt": np.diff(TIMES, prepend=T0)}, x_true=xs)
    by_times = filt.filter(ys, PRIOR, params=_no_dt(_params(filt)), x_true=xs, times=TIMES, t0=T0)
    for field in ("x", "P", "loglik", "nees_values"):
        np.testing.assert_array_equal(getattr(by_times, field), getattr(by_dt, field))
    xb, yb = _data(RUNS)
    p = _no_dt(_params(filt, RUNS))
    whole_dt = filt.filter(yb, PRIOR, params={**p, "dt": np.diff(RUN_TIMES, axis=1, prepend=T0)}, x_true=xb)
    whole = filt.filter(yb, PRIOR, params=p, x_true=xb, times=RUN_TIMES, t0=T0)
    for shards in (2, RUNS):
        sharded = filter_bank(filt, sm.Executor(scheduler="synchronous"), yb, shards=shards, x0=PRIOR, params=p,
                              x_true=xb, times=RUN_TIMES, t0=T0)
        for field in ("x", "P", "loglik", "nees_values"):
            np.testing.assert_array_equal(getattr(sharded, field), getattr(whole, field))
    for field in ("x", "P", "loglik", "nees_values"):
        np.testing.assert_array_equal(getattr(whole, field), getattr(whole_dt, field))
    assert not np.allclose(whole.x[0], whole.x[1])  # the runs' own times (and data) matter
    shared = filt.filter(yb, PRIOR, params=p, times=TIMES, t0=T0)  # one row of times for all runs
    np.testing.assert_array_equal(shared.x[2], filt.filter(yb[2], PRIOR, params={"a": p["a"][2]}, times=TIMES,
                                                           t0=T0).x)


@pytest.mark.parametrize("name", [n for n in NAMES if FILTERS[n].continuous_time])
@pytest.mark.parametrize("kw, match", [
    (dict(times=TIMES[::-1]), r"times must be strictly increasing: times\[1\] = .* follows times\[0\]"),
    (dict(times=TIMES, t0=TIMES[0]), r"times must be after t0 = .*: times\[0\]"),
    (dict(times=np.where(np.arange(K) == 3, np.nan, TIMES)), r"times must be finite: times\[3\] = nan"),
    (dict(times=TIMES[:-1]), rf"times must be .* shape \({K},\); got shape \({K - 1},\)"),
    (dict(times=TIMES[None]), r"times must be .* 1-D"),
    (dict(times=TIMES, t0="0"), "t0 must be a finite number"),
    (dict(t0=1.0), "t0 .* applies only with times"),
    (dict(times=TIMES, params_dt=True), r"times or by params\['dt'\], not both"),
])
def test_bad_times_are_refused_naming_the_argument_and_the_index(name, kw, match):
    filt = FILTERS[name]
    _, ys = _data(None)
    params = _params(filt) if kw.pop("params_dt", False) else _no_dt(_params(filt))
    with pytest.raises(ArgumentError, match=match):
        filt.filter(ys, PRIOR, params=params, **kw)


@pytest.mark.parametrize("name", [n for n in NAMES if FILTERS[n].continuous_time])
def test_a_bank_s_times_are_refused_by_run_and_index(name):
    filt = FILTERS[name]
    _, yb = _data(RUNS)
    p = _no_dt(_params(filt, RUNS))
    bad = RUN_TIMES.copy()
    bad[2, 4] = bad[2, 3]
    with pytest.raises(ArgumentError, match=r"strictly increasing: times\[2, 4\] = .* follows times\[2, 3\]"):
        filt.filter(yb, PRIOR, params=p, times=bad)
    with pytest.raises(ArgumentError, match=rf"or one row of them per run, shape \({RUNS}, {K}\); got shape "
                                            rf"\({RUNS - 1}, {K}\)"):
        filt.filter(yb, PRIOR, params=p, times=RUN_TIMES[1:])


def test_capabilities_are_declared_not_discovered():
    assert FILTERS["ParticleFilter"].random and not FILTERS["NonlinearKalmanFilter"].random
    assert sm.NonlinearKalmanFilter.has_smoother and sm.NonlinearKalmanFilter.exportable
    assert sm.KalmanFilter.gaussian_mode and not sm.ParticleFilter.gaussian_mode
    assert sm.GaussianSumFilter.keepable == ("x", "P", "mixture")
    with pytest.raises(ArgumentError, match="not P0"):
        FILTERS["ParticleFilter"].filter(_data(None)[1], PRIOR.mean, PRIOR.cov, params=_params(FILTERS["ParticleFilter"]))


def test_a_filter_that_overrides_the_template_or_misdeclares_is_refused_at_its_class_statement():
    with pytest.raises(TypeError, match="overrides Filter.filter"):
        class Bad(Filter):  # noqa: F841
            def filter(self, ys, x0):
                return None
    with pytest.raises(TypeError, match="has_smoother but has no smooth"):
        class NoSmoother(Filter):  # noqa: F841
            has_smoother = True
    with pytest.raises(TypeError, match="random must be a bool"):
        class NotBool(Filter):  # noqa: F841
            random = 1


def test_imm_takes_any_gaussian_mode_by_its_declaration():
    with pytest.raises(TypeError, match="Gaussian filter that IMM can mix"):
        sm.IMM([FILTERS["ParticleFilter"], FILTERS["KalmanFilter"]], np.eye(2), [0.5, 0.5])


# ------------------------------------------------------------------------- the registry
@pytest.mark.parametrize("filter_name, rule_name", sorted(RULE_FILTERS.items()))
def test_a_filter_name_and_its_rule_name_are_one_filter_in_python(filter_name, rule_name):
    by_filter = sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, Q, R, filter_name)
    by_rule = sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, Q, R, rule_name)
    assert by_filter.transform == by_rule.transform == filter_rule(rule_name)
    assert by_filter.method == by_rule.method


def test_an_unknown_name_lists_filters_and_rules():
    with pytest.raises(SymmonError, match=r"unknown filter or rule 'kalman'; filters: ekf.*rules: tt1"):
        filter_rule("kalman")
    with pytest.raises(SymmonError, match=r"unknown filter 'kalman'; known: kf, ekf, tt1"):
        filter_entry("kalman")


@pytest.mark.parametrize("name", filter_names(scenario=True))
def test_every_scenario_filter_builds_from_its_name_and_aliases(name):
    entry = filter_entry(name)
    lin_f = sm.Model([x, v], [x + v, v], name="contract_lin_f")
    for alias in (name, *entry.aliases, name.upper()):
        filt = make_filter(alias, lin_f, H_MODEL, Q, R)
        assert isinstance(filt, entry.kind) and isinstance(filt, Filter)


def test_the_registry_checks_settings_and_what_a_model_can_give():
    with pytest.raises(SymmonError, match=r"unknown settings \['speed'\]"):
        make_filter("pf", F_MODEL, H_MODEL, Q, R, settings={"speed": 1})
    with pytest.raises(SymmonError, match="setting 'particles' must be int"):
        make_filter("pf", F_MODEL, H_MODEL, Q, R, settings={"particles": 2.5})
    assert make_filter("rpf", F_MODEL, H_MODEL, Q, R).regularise
    assert make_filter("iekf", F_MODEL, H_MODEL, Q, R, settings={"iterations": 3}).iterations == 3
    with pytest.raises(ModelError, match="'kf' needs a linear dynamics"):
        make_filter("kf", sm.Model([x, v], [x + v**2, v]), H_MODEL, Q, R)
    with pytest.raises(SymmonError, match="one filter per mode"):
        make_filter("imm", F_MODEL, H_MODEL, Q, R)


def test_the_linear_kf_entry_is_the_kalman_filter_of_the_model():
    lin_f = sm.Model([x, v], [x + v, v], name="contract_lin_f")
    kf = make_filter("kf", lin_f, H_MODEL, Q, R)
    np.testing.assert_array_equal(kf.F, [[1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_array_equal(kf.H, [[1.0, 0.0]])


def test_a_name_is_registered_once():
    with pytest.raises(SymmonError, match="'tt1' is 'ekf''s already"):
        register(FilterEntry("other", "clash", sm.NonlinearKalmanFilter, lambda *a: None, aliases=("tt1",)))
    with pytest.raises(SymmonError, match="subclass of symmon.filters.base.Filter"):
        register(FilterEntry("other", "not a filter", dict, lambda *a: None))


@pytest.mark.parametrize("name", NAMES)
def test_every_filter_declares_its_cost_per_step(name):
    """The deterministic cost a choice between filters compares (advise_filter), declared by
    each filter, never read off its class."""
    cost = FILTERS[name].step_cost()
    assert isinstance(cost, int) and cost > 0


def test_the_costs_order_the_families_as_their_work():
    ekf = FILTERS["NonlinearKalmanFilter"]
    assert FILTERS["ParticleFilter"].step_cost() == 2 * 200
    assert FILTERS["EnsembleKalmanFilter"].step_cost() == 2 * 50
    assert FILTERS["GaussianSumFilter"].step_cost() >= FILTERS["GaussianSumFilter"].max_components * ekf.step_cost()
    assert FILTERS["IMM"].step_cost() == sum(m.step_cost() for m in FILTERS["IMM"].filters)
    ukf = sm.NonlinearKalmanFilter(F_MODEL, H_MODEL, Q, R, "ukf")
    assert ukf.step_cost() == sm.UT.ut1().cost(2) + sm.UT.ut1().cost(2) > ekf.step_cost()
    # A continuous-discrete filter evaluates its moment equations at least 8 times an interval
    # (RK45: the start, the first step's choice, six stages): more than its discrete twin.
    from symmon.filters.gaussian.continuous import MIN_EVALUATIONS
    cd = FILTERS["ContinuousDiscreteKalmanFilter"]
    rule = int(cd.transform.cost(cd.sizes[0]))
    assert MIN_EVALUATIONS == 8 and cd.step_cost() == 9 * rule > 2 * rule


# ------------------------------------------------------------------------- the smoothers
@pytest.mark.parametrize("name", [n for n in NAMES if FILTERS[n].has_smoother])
def test_a_smoother_ends_at_the_filter_and_smooths_a_bank_run_by_run(name):
    """Every filter that declares ``has_smoother``: ``smooth`` takes the filter's call, its
    last step is the filtered one, and a bank's runs are smoothed alone."""
    filt = FILTERS[name]
    n = filt.sizes[0]
    _, ys = _data(None)
    one = filt.smooth(ys, PRIOR, params=_params(filt))
    assert one.x.shape == (K, n) and one.P.shape == (K, n, n)
    np.testing.assert_allclose(one.x[-1], one.filtered.x[-1], rtol=1e-12)
    assert np.abs(one.x[0] - one.filtered.x[0]).max() > 0  # the backward pass moved the first step
    _, yb = _data(RUNS)
    p = _params(filt, RUNS)
    bank = filt.smooth(yb, PRIOR, params=p)
    assert bank.x.shape == (RUNS, K, n)
    more = {"first_run": 2} if filt.random else {}  # a random filter's run 2 draws from stream 2
    alone = filt.smooth(yb[2], PRIOR, params=None if p is None else {k: (v[2] if np.ndim(v) == 2 else v)
                                                                     for k, v in p.items()}, **more)
    np.testing.assert_allclose(alone.x, bank.x[2], rtol=1e-12, atol=1e-12)


def test_the_smoothers_are_declared():
    assert [n for n in NAMES if FILTERS[n].has_smoother] == ["ContinuousDiscreteKalmanFilter",
                                                             "EnsembleKalmanFilter", "NonlinearKalmanFilter"]
