"""Monte Carlo groups at scale (issues 12 and 13): the O(G) jackknife equals the brute-force
one; Ctrl-C or a failing group stops a run at the next chunk; the settings have declared
limits; a Dask scheduler that never answers times out.

The delete-one-group statistics are the merged total with one group taken out (Chan's
merge run backwards).  The reference kept here is the definition: merge the other G − 1
groups, for each of the G groups (O(G²)).  Both are exact formulas evaluated in a
different order, so they agree to rounding; 1e-10 of each entry's scale leaves a margin
of ~10⁵ over the ~1e-15 per operation.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.cli import parser as cli
from symmon.cli import options as cli_options
from symmon.core.angles import wrap_angle
from symmon.errors import SymmonError
from symmon.measures.conditional import conditional_cov_replicates
from symmon.measures.formula import mon_from_moments
from symmon.transforms.montecarlo import MC_INNER
from symmon.compile import compiled
from symmon.transforms.executor import connect_dask, dask_compute, run_groups, stop_point
from symmon.transforms.montecarlo import MAX_CHUNK, MAX_GROUPS, MAX_SAMPLES
from symmon.transforms.stats import Stats, jackknife_se, leave_one_out, leave_one_out_stack, merge_all, moments_of

from helpers import ROOT


#: Reverse merge vs merging the others: both exact, rounding only (see the module notes).
LOO_RTOL = 1e-10

x, y, v1 = sp.symbols("x y v1", real=True)


def reference_leave_one_out(groups: list[Stats]) -> list[Stats]:
    """The definition, O(G²): merge every group but group i, for each i."""
    return [merge_all([g for j, g in enumerate(groups) if j != i]) for i in range(len(groups))]


def assert_stats_close(got: Stats, want: Stats) -> None:
    """Equal counts; mean within LOO_RTOL of |mean| + σ, M2 within LOO_RTOL of √(M2_ii M2_jj)."""
    assert got.n == want.n
    sd = np.sqrt(np.diag(want.m2))
    np.testing.assert_array_less(np.abs(got.mean - want.mean), LOO_RTOL * (np.abs(want.mean) + sd / np.sqrt(want.n)))
    np.testing.assert_array_less(np.abs(got.m2 - want.m2), LOO_RTOL * np.outer(sd, sd))


def _random_groups(G: int, seed: int) -> list[Stats]:
    """G groups of unequal sizes, correlated columns and a large offset (|mean| ≫ σ)."""
    rng = np.random.default_rng(seed)
    A = np.array([[1.0, 0.0, 0.0], [0.8, 0.3, 0.0], [-2.0, 0.5, 1e-3]])
    return [Stats.of(rng.normal(size=(int(n), 3)) @ A.T + [1e4, -3.0, 0.2])
            for n in rng.integers(2, 50, size=G)]


@pytest.mark.parametrize("G", [2, 3, 17, 200])
def test_leave_one_out_equals_merging_the_other_groups(G):
    groups = _random_groups(G, seed=G)
    got = leave_one_out(groups)
    for a, b in zip(got, reference_leave_one_out(groups)):
        assert_stats_close(a, b)
    # The stack holds the same numbers, and takes the total when the caller has it.
    stack = leave_one_out_stack(groups, merge_all(groups))
    np.testing.assert_array_equal(stack.n, [s.n for s in got])
    np.testing.assert_array_equal(stack.m2, np.stack([s.m2 for s in got]))


def test_leave_one_out_needs_two_groups_with_samples_outside_each():
    one = _random_groups(1, seed=0)
    with pytest.raises(SymmonError, match="at least 2 groups"):
        leave_one_out(one)
    empty = Stats(0, np.zeros(3), np.zeros((3, 3)))
    with pytest.raises(SymmonError, match="samples outside every group"):
        leave_one_out([one[0], empty])


def test_stacked_moments_equal_the_moments_of_each():
    """moments_of on a stack (leading axis G) is moments_of on each, angles included."""
    groups = [Stats.of(np.random.default_rng(s).normal(size=(40, 6))) for s in range(5)]
    stack = leave_one_out_stack(groups)
    batched = moments_of(stack, 2, 2, [1])
    for i, s in enumerate(leave_one_out(groups)):
        for got, want in zip(batched, moments_of(s, 2, 2, [1])):
            np.testing.assert_array_equal(got[i], want)


def _reference_moment_se(groups: list[Stats], ny: int, nw: int, angles: list[int]) -> np.ndarray:
    """The jackknife of (E y, Cov y, Cov(y, w)) as it was computed group by group."""
    mu = moments_of(merge_all(groups), ny, nw, angles)[0]
    rows = []
    for s in reference_leave_one_out(groups):
        m, c, xc, _ = moments_of(s, ny, nw, angles)
        m[angles] = wrap_angle(m[angles] - mu[angles])
        rows.append(np.concatenate([m, c.ravel(), xc.ravel()]))
    return jackknife_se(np.array(rows))


@pytest.mark.parametrize("mean", [[-1.0, 0.01], [1.0, 0.5]], ids=["bearing-at-the-cut", "bearing-inside"])
def test_monte_carlo_error_bars_equal_the_brute_force_jackknife(mean):
    """With an angle output (circular mean): at the cut ±π the left-out means fall on
    both sides of it, which the jackknife must unwrap."""
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1], name="mc_groups_polar")
    u = sm.Gaussian(mean, 0.3 * np.eye(2))
    m = sm.propagate(polar, u, transform=sm.MonteCarlo(30_000, seed=4, groups=23))
    want = _reference_moment_se(m.info["groups"], 2, 2, [1])
    got = np.concatenate([m.stderr["mean"], m.stderr["cov"].ravel(), m.stderr["cross_cov"].ravel()])
    np.testing.assert_allclose(got, want, rtol=LOO_RTOL)


def test_mon_error_bar_equals_the_brute_force_jackknife():
    """The MoN's error bar: group i left out of the moments, O(G), equals the definition."""
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], angles=[1], name="mc_groups_polar")
    u = sm.Gaussian([-1.0, 0.01], 0.3 * np.eye(2))
    res = sm.nonlinearity(polar, u, transform=sm.MonteCarlo(30_000, seed=4, groups=23))
    vals = []
    for s in reference_leave_one_out(res.moments.info["groups"]):
        _, cyy, cyw, cww = moments_of(s, 2, 2, [1])
        vals.append(mon_from_moments(cyy, cyw, cww, "full").value)
    assert res.stderr == pytest.approx(float(jackknife_se(np.array(vals))), rel=LOO_RTOL)


def test_nested_sigma_c_left_out_equals_the_brute_force_one():
    """General noise: Σ_c with group i left out of the nested Monte Carlo (O(G)) equals
    Σ_c recomputed from the other groups."""
    model = sm.Model([x], [sp.sin(x + v1) + x * v1**2], noise=[v1], name="mc_groups_general")
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    mc = sm.MonteCarlo(40_000, seed=6, groups=9)
    Sc, loo = conditional_cov_replicates(model, u, v, mc)
    nested = mc.nested_stats(compiled(model), u.mean, u.cov, v.mean, v.cov)

    def sc(parts):
        st = merge_all([p[0] for p in parts])
        return st.cov - sum(p[1] for p in parts) / st.n / MC_INNER

    np.testing.assert_array_equal(Sc, sc(nested))
    for i in range(mc.groups):
        want = sc([g for j, g in enumerate(nested) if j != i])
        np.testing.assert_allclose(loo[i], want, rtol=LOO_RTOL)


# --------------------------------------------------------------------------- stopping (issue 12)
#: The interrupted run would take minutes (10¹¹ samples); a stop waits for one chunk per
#: thread (milliseconds), so this bound only separates "stopped" from "ran on".
STOP_WITHIN_S = 20

_INTERRUPTED_RUN = textwrap.dedent(
    """
    import sys, threading
    sys.path.insert(0, sys.argv[1])
    from symmon import cli
    from symmon.transforms import montecarlo

    run_group, started = montecarlo._run_group, threading.Event()

    def announcing(cm, job, stop=None):  # tell the test when sampling has begun
        if not started.is_set():
            started.set()
            print("sampling", flush=True)
        return run_group(cm, job, stop)

    montecarlo._run_group = announcing
    sys.exit(cli.main(sys.argv[2:]))
    """
)


@pytest.mark.parametrize("args", [
    ("nonlinearity", "--groups", "16"),
    ("propagate", "--groups", "3", "--workers", "1"),
], ids=["threads", "one-thread"])
def test_ctrl_c_stops_a_long_monte_carlo_run(args):
    """SIGINT during sampling: the CLI exits 130 without waiting for the groups."""
    cmd, *opts = args
    proc = subprocess.Popen(
        [sys.executable, "-c", _INTERRUPTED_RUN, str(ROOT), cmd, str(ROOT / "examples" / "gmti.toml"),
         "--transform", "mc", "--samples", "100000000000", *opts],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "sampling"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=STOP_WITHIN_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "interrupted" in err


def test_a_failing_group_stops_the_others():
    """One group raises: the running groups end at their next chunk, queued ones never
    start, and the caller gets the group's error."""
    finished = []

    def group(j: int, stop: threading.Event) -> int:
        if j == 0:
            raise SymmonError("group 0 fails")
        for _ in range(STOP_WITHIN_S * 1000):  # "chunks" of 1 ms
            stop_point(stop)
            time.sleep(1e-3)
        finished.append(j)
        return j

    with pytest.raises(SymmonError, match="group 0 fails"):
        run_groups(group, list(range(20)), workers=3)
    assert finished == []


# --------------------------------------------------------------------------- validation (issue 13)
@pytest.mark.parametrize(("kw", "match"), [
    (dict(seed=-1), "seed must be a non-negative integer or None, got -1"),
    (dict(seed=0.5), "seed must be a non-negative integer or None, got 0.5"),
    (dict(seed=True), "seed must be a non-negative integer or None, got True"),
    (dict(groups=MAX_GROUPS + 1, n=10**7), r"groups = 100001 is above the limit 10\*\*5"),
    (dict(n=MAX_SAMPLES + 1), r"n = 9007199254740993 is above the limit 2\*\*53"),
    (dict(chunk=MAX_CHUNK + 1), r"chunk = 1048577 is above the limit 2\*\*20"),
    (dict(n=2**40, groups=16, qmc=True), r"at most 2\*\*30 points per group, .* needs 68719476736"),
    (dict(n=1.5e5 + 0.5), "n must be a positive integer, got 150000.5"),
])
def test_monte_carlo_limits(kw, match):
    """Each setting is checked when the transform is made, before any work or memory."""
    with pytest.raises(SymmonError, match=match):
        sm.MonteCarlo(**kw)


@pytest.mark.parametrize("workers", [0, True, 2.5])
def test_executor_refuses_a_bad_thread_count(workers):
    """Where the groups run is the executor's setting (no longer the transform's)."""
    with pytest.raises(SymmonError, match=f"workers must be >= 1, got {workers!r}"):
        sm.Executor(workers=workers)


def test_an_integral_float_count_is_a_count():
    """MonteCarlo(n=1e6) is the integer 10**6 (issue 16): same transform, same numbers."""
    mc = sm.MonteCarlo(n=1e6, groups=16.0)
    assert mc == sm.MonteCarlo(n=10**6) and type(mc.n) is int and type(mc.groups) is int


def test_the_limits_themselves_are_accepted():
    sm.MonteCarlo(n=MAX_SAMPLES, groups=MAX_GROUPS, chunk=MAX_CHUNK, seed=np.uint64(2**63))
    sm.MonteCarlo(n=2**34, groups=16, qmc=True)  # 2**30 per group


def test_seed_none_draws_a_seed_that_repeats_the_run():
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2)], name="mc_groups_seed")
    u = sm.Gaussian([1.0, 2.0], np.eye(2))
    fresh = sm.MonteCarlo(2_000, seed=None, groups=4)
    assert isinstance(fresh.seed, int) and fresh.seed >= 0 and f"seed={fresh.seed}" in repr(fresh)
    again = sm.propagate(polar, u, transform=sm.MonteCarlo(2_000, seed=fresh.seed, groups=4))
    np.testing.assert_array_equal(sm.propagate(polar, u, transform=fresh).cov, again.cov)


def test_a_group_smaller_than_a_chunk_allocates_only_its_samples():
    """chunk is a cap per kernel call, not an allocation: 2**20 rows for 100 samples would
    be ~100 MB per thread; the result is the same as with the default chunk."""
    polar = sm.Model([x, y], [sp.sqrt(x**2 + y**2)], name="mc_groups_seed")
    u = sm.Gaussian([1.0, 2.0], np.eye(2))
    big = sm.propagate(polar, u, transform=sm.MonteCarlo(400, seed=1, groups=4, chunk=MAX_CHUNK))
    small = sm.propagate(polar, u, transform=sm.MonteCarlo(400, seed=1, groups=4))
    np.testing.assert_array_equal(big.cov, small.cov)


@pytest.fixture
def silent_server():
    """A TCP server that accepts connections and never says a word, on a thread."""
    srv = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):  # the fixture closed the socket
            while True:
                accepted.append(srv.accept()[0])

    threading.Thread(target=serve, daemon=True).start()
    yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    srv.close()
    for c in accepted:
        c.close()


def test_a_scheduler_that_never_answers_times_out(silent_server, capsys, monkeypatch):
    """distributed's own timeout covers the TCP connection, not the handshake after it:
    without connect_dask this call would wait forever (it is bounded by the timeouts)."""
    pytest.importorskip("distributed")
    with pytest.raises(SymmonError, match="accepted but nothing answered in another 0.5 s"):
        connect_dask(silent_server, timeout=0.5)
    monkeypatch.setattr(cli_options, "DASK_CONNECT_TIMEOUT", 0.5)
    code = cli.main(["propagate", str(ROOT / "examples" / "gmti.toml"), "--transform", "mc",
                     "--samples", "1000", "--dask", silent_server])
    assert code == 1
    assert f"cannot reach the Dask scheduler at {silent_server} within 0.5 s" in capsys.readouterr().err


@pytest.mark.parametrize("workers", [2, 5])
def test_nested_monte_carlo_on_threads_equals_one_thread(workers):
    """General noise: the nested groups run on the engine's threads, same numbers."""
    model = sm.Model([x], [sp.sin(x + v1) + x * v1**2], noise=[v1], name="mc_groups_general")
    u, v = sm.Gaussian([0.4], [[0.5]]), sm.Gaussian([0.0], [[0.3]])
    mc = sm.MonteCarlo(60_000, seed=8, groups=7)
    one = sm.nonlinearity(model, u, v, transform=mc, executor=sm.Executor(workers=1))
    many = sm.nonlinearity(model, u, v, transform=mc, executor=sm.Executor(workers=workers))
    assert (many.squared, many.stderr) == (one.squared, one.stderr)


def test_an_interrupted_dask_run_cancels_its_pending_tasks():
    """Ctrl-C while waiting for a cluster's tasks: the futures are cancelled, the interrupt propagates."""

    class Future:
        status = "pending"

        def __init__(self, task):
            self.task = task

        def add_done_callback(self, fn):
            pass  # it never finishes

    class Client:
        cancelled = None
        looks = 0

        def compute(self, tasks):
            return [Future(t) for t in tasks]

        def nthreads(self):
            # The watch looks at the workers when nothing finishes: Ctrl-C at its second look.
            self.looks += 1
            if self.looks > 1:
                raise KeyboardInterrupt
            return {"tcp://worker:1": 1}

        def cancel(self, futures):
            self.cancelled = [f.task for f in futures]

    client = Client()
    with pytest.raises(KeyboardInterrupt):
        dask_compute(["a", "b"], client, worker_timeout=0.2)
    assert client.cancelled == ["a", "b"]
