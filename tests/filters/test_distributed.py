"""Banks of filter runs in shards on Dask (issue 35, item 6): the sharded result is the
unsharded one bit for bit, for every filter, on a cluster of two worker processes, the
synchronous scheduler and threads; the particle filter's streams belong to the runs, not to
the shards; errors name the run in the whole bank; a cluster without workers is an error
in bounded time."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import warnings

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon import cli
from symmon.errors import ArgumentError, DegeneracyWarning, ShapeError, SymmonError
from symmon.filters.bank import filter_bank, run_streams, shard_bounds

distributed = pytest.importorskip("dask.distributed")

x, a = sp.symbols("x a")
#: The univariate nonstationary growth model (scalar: cheap to compile and to filter).
F = sm.Model([x], [x / 2 + 25 * x / (1 + x**2)])
H = sm.Model([x], [x**2 / 20])
Q, R = [[1.0]], [[1.0]]
X0 = sm.Gaussian([0.1], [[1.0]])
RUNS, STEPS = 7, 8

FILTERS = {
    "ekf": lambda: sm.NonlinearKalmanFilter(F, H, Q, R, sm.TT1()),
    "adaptive": lambda: sm.NonlinearKalmanFilter(F, H, Q, R, sm.Adaptive(tol=0.05)),
    "pf": lambda: sm.ParticleFilter(F, H, Q, R, particles=200, seed=4),
    "gsf": lambda: sm.GaussianSumFilter(F, H, Q, R, sm.TT1()),
    "gsf-split": lambda: sm.GaussianSumFilter(F, H, Q, R, sm.TT1(), split=0.3, max_components=6),
    "kf": lambda: sm.KalmanFilter([[0.9]], [[1.0]], [[1.0]], [[1.0]]),
}


@pytest.fixture(scope="module")
def bank():
    return sm.simulate(F, H, Q, R, X0, STEPS, runs=RUNS, seed=3)


@pytest.fixture(scope="module")
def filters():
    return {k: make() for k, make in FILTERS.items()}


def _kwargs(name, xs):
    """The truth for the filters that take it (their NEES is then part of the result)."""
    return {"x_true": xs} if name in ("ekf", "adaptive", "pf") else {}


@pytest.fixture(scope="module")
def reference(bank, filters):
    xs, ys = bank
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegeneracyWarning)  # a PF run may collapse once: the same in shards
        return {k: f.filter(ys, X0, **_kwargs(k, xs)) for k, f in filters.items()}


@contextlib.contextmanager
def _quiet_distributed():
    """Only the known-harmless start-up/shut-down warning of a slow file system."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Creating scratch directories is taking", category=UserWarning)
        yield


@pytest.fixture(scope="module")
def client():
    """Two worker processes: every task's filter is pickled and rebuilt in another process."""
    with _quiet_distributed():
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
        cl = distributed.Client(cluster)
    yield cl
    with _quiet_distributed():
        cl.close()
        cluster.close()


def assert_same(a, b) -> None:
    """Every field equal, arrays bit for bit (shape, dtype, values, NaN where NaN)."""
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if isinstance(va, np.ndarray):
            assert va.shape == vb.shape and va.dtype == vb.dtype, f.name
            assert np.array_equal(va, vb, equal_nan=va.dtype.kind == "f"), f.name
            assert not vb.flags.writeable, f.name
        else:
            assert va == vb, f.name


def _sharded(filt, name, ex, ys, xs, shards=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegeneracyWarning)
        return filter_bank(filt, ex, ys, shards=shards, x0=X0, **_kwargs(name, xs))


@pytest.mark.parametrize("name", list(FILTERS))
def test_cluster_shards_equal_one_process_bit_for_bit(name, client, bank, filters, reference):
    xs, ys = bank
    ex = sm.Executor(client=client)
    assert_same(reference[name], _sharded(filters[name], name, ex, ys, xs, shards=3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegeneracyWarning)
        got = filters[name].filter(ys, X0, executor=ex, **_kwargs(name, xs))  # one shard per worker thread
    assert_same(reference[name], got)
    if name != "kf":  # the bank's consistency statistics are those of one process
        np.testing.assert_array_equal(got.anees(xs).value, reference[name].anees(xs).value)


@pytest.mark.parametrize("name", list(FILTERS))
def test_any_sharding_on_the_synchronous_scheduler_and_threads_is_the_same(name, bank, filters, reference):
    xs, ys = bank
    for shards in (2, RUNS):
        assert_same(reference[name], _sharded(filters[name], name, sm.Executor(scheduler="synchronous"), ys, xs, shards))
    assert_same(reference[name], _sharded(filters[name], name, sm.Executor(workers=2), ys, xs, 3))


def test_a_single_run_is_one_task(bank, filters):
    xs, ys = bank
    ekf = filters["ekf"]
    assert_same(ekf.filter(ys[2], X0, x_true=xs[2]),
                ekf.filter(ys[2], X0, x_true=xs[2], executor=sm.Executor(scheduler="synchronous")))


def test_particle_streams_belong_to_the_runs_not_the_shards(bank, filters, reference):
    """Run r draws from child r of SeedSequence(seed): filtered alone with first_run=r it is
    row r of the bank; another seed gives other particles."""
    xs, ys = bank
    pf, ref = filters["pf"], reference["pf"]
    for r in (0, 5):
        alone = pf.filter(ys[r:r + 1], X0, x_true=xs[r:r + 1], first_run=r)
        np.testing.assert_array_equal(alone.x[0], ref.x[r])
        np.testing.assert_array_equal(alone.loglik[0], ref.loglik[r])
    other = dataclasses.replace(pf, seed=5).filter(ys, X0)
    assert not np.array_equal(other.x, ref.x)
    # The children a … of the seed, without making the first ones (spawn keys = run indices).
    whole = np.random.SeedSequence(4).spawn(6)
    assert [g.bit_generator.seed_seq.spawn_key for g in run_streams(4, 2, 4)] == [s.spawn_key for s in whole[4:]]
    assert run_streams(4, 2, 4)[1].random() == np.random.Generator(np.random.PCG64(whole[5])).random()
    with pytest.raises(ArgumentError, match="first_run must be a non-negative integer"):
        pf.filter(ys, X0, first_run=-1)


def test_per_run_inputs_are_cut_with_the_runs_and_errors_name_the_bank_run():
    """x0 (R, n), P0 (R, n, n) and parameters (R, K) go with their runs; a step that fails in
    run 5 is named run 5, not its index inside its shard."""
    f = sm.Model([x], [a * x], params=[a])
    ekf = sm.NonlinearKalmanFilter(f, sm.Model([x], [x]), Q, R, sm.TT1())
    rng = np.random.default_rng(0)
    ys = rng.normal(size=(RUNS, 5, 1))
    x0 = rng.normal(size=(RUNS, 1))
    P0 = rng.uniform(0.5, 2.0, size=(RUNS, 1, 1))
    gain = rng.uniform(0.5, 1.0, size=(RUNS, 5))
    ex = sm.Executor(scheduler="synchronous")
    ref = ekf.filter(ys, x0, P0, params={"a": gain})
    assert_same(ref, filter_bank(ekf, ex, ys, shards=3, x0=x0, P0=P0, params={"a": gain}))
    assert_same(ekf.filter(ys, x0, P0, params={"a": 0.9}),
                ekf.filter(ys, x0, P0, params={"a": 0.9}, executor=ex))  # a shared value stays whole
    gain[5, 2:] = 1e300  # run 5 overflows from step 2 on
    with pytest.raises(SymmonError) as whole:
        ekf.filter(ys, x0, P0, params={"a": gain})
    with pytest.raises(SymmonError) as sharded:
        filter_bank(ekf, ex, ys, shards=3, x0=x0, P0=P0, params={"a": gain})  # run 5 is run 1 of shard 3
    assert "run 5, step 2" in str(whole.value)
    assert str(sharded.value) == str(whole.value)
    with pytest.raises(ShapeError, match="x0 has 6 runs .* but ys has 7"):
        ekf.filter(ys, x0[:6], P0, params={"a": 0.9}, executor=ex)
    with pytest.raises(ShapeError, match="parameter 'a' has 3 runs"):
        ekf.filter(ys, x0, P0, params={"a": gain[:3]}, executor=ex)


def test_bad_shards_and_executor(bank, filters):
    _, ys = bank
    ekf = filters["ekf"]
    for bad in (0, RUNS + 1, 2.0, True):
        with pytest.raises(ArgumentError, match="shards must be an integer from 1 to 7"):
            filter_bank(ekf, sm.Executor(scheduler="synchronous"), ys, shards=bad, x0=X0)
    with pytest.raises(ArgumentError, match="executor must be a symmon.Executor"):
        ekf.filter(ys, X0, executor="synchronous")
    assert shard_bounds(7, 3) == [(0, 2), (2, 4), (4, 7)]


def test_a_worker_process_warning_comes_back_naming_the_bank_run(client):
    """A particle filter that collapses in a worker process warns here, with the bank's run."""
    xs, ys = sm.simulate(F, H, Q, [[1e-6]], X0, 3, runs=4, seed=2)
    pf = sm.ParticleFilter(F, H, Q, [[1e-6]], particles=20, seed=1)
    ex = sm.Executor(client=client)
    with pytest.warns(DegeneracyWarning) as caught:
        filter_bank(pf, ex, ys, shards=2, x0=X0)
    runs = {int(w.message.args[0].split("first at run ")[1].split(",")[0]) for w in caught
            if "first at run" in str(w.message)}
    assert runs & {2, 3}, [str(w.message) for w in caught]  # the second shard's runs, by their bank index


def test_no_worker_is_a_bounded_error(bank, filters, capsys):
    _, ys = bank
    with _quiet_distributed():
        cluster = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0")
        cl = distributed.Client(cluster)
    try:
        ex = sm.Executor(client=cl, worker_timeout=0.5, progress=True)
        with pytest.raises(SymmonError, match=r"had no worker for 0.5 s, with 2 of 2 EKF shards of runs unfinished"):
            filter_bank(filters["ekf"], ex, ys, shards=2, x0=X0)
        assert "has no worker; waiting up to 0.5 s" in capsys.readouterr().err
        assert not cl.futures  # cancelled, not left on the scheduler
    finally:
        with _quiet_distributed():
            cl.close()
            cluster.close()


def test_progress_off_a_terminal_counts_the_shards(bank, filters, capsys, monkeypatch):
    from symmon import progress

    monkeypatch.setattr(progress, "LINE_INTERVAL", 0.0)
    _, ys = bank
    filter_bank(filters["ekf"], sm.Executor(scheduler="synchronous", progress=True), ys, shards=3, x0=X0)
    lines = [l for l in capsys.readouterr().err.splitlines() if l.startswith("EKF shards of runs:")]
    assert [l.split()[4] for l in lines] == ["1/3", "2/3", "3/3"]


SCENARIO = """
name = "rb"
states = ["px", "py", "vx", "vy"]
dynamics = ["px + vx", "py + vy", "vx", "vy"]
measurements = ["hypot(px, py)", "atan2(py, px)"]
angles = [1]
steps = 4
[Q]
std = [0.1, 0.1, 0.05, 0.05]
[R]
std = [1.0, 0.02]
[x0]
mean = [-20, 50, 0, -2]
std = [2, 2, 0.2, 0.2]
[pf]
particles = 300
"""


def test_cli_dask_gives_the_same_json(tmp_path, capsys):
    p = tmp_path / "s.toml"
    p.write_text(SCENARIO)
    args = ["filter", str(p), "--runs", "5", "--filters", "ekf,gsf,pf", "--json", "-q"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegeneracyWarning)  # a PF run may collapse at its first step: both times
        assert cli.main(args) == 0
        plain = json.loads(capsys.readouterr().out)
        assert cli.main(args + ["--dask", "synchronous"]) == 0
        assert json.loads(capsys.readouterr().out) == plain
    assert all(f.get("error") is None for f in plain["filters"]), plain["filters"]


def test_priors_pickle_to_workers_bit_for_bit():
    """The immutable priors travel to worker processes: the same bits, read-only again."""
    import pickle

    g = sm.Gaussian([0.1, -2.0], [[2.0, 0.3], [0.3, 1.0]])
    m = sm.GaussianMixture([0.25, 0.75], [[0.0], [1.0]], [[[1.0]], [[2.0]]])
    e = sm.Empirical(np.arange(6.0).reshape(3, 2), [0.2, 0.3, 0.5])
    for prior, arrays in ((g, ("mean", "cov")), (m, ("weights", "means", "covs", "mean", "cov")),
                          (e, ("samples", "weights", "mean", "cov"))):
        back = pickle.loads(pickle.dumps(prior))
        assert type(back) is type(prior)
        for name in arrays:
            np.testing.assert_array_equal(getattr(back, name), getattr(prior, name))
            assert not getattr(back, name).flags.writeable
        with pytest.raises(AttributeError, match="immutable"):
            back.x = 1
