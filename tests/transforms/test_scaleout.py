"""Scale-out of Monte Carlo: Dask equals single-process, shards merge exactly, memory is flat.

For the same seed every group draws the same stream (``SeedSequence(seed).spawn(G)``),
computes its statistics with the same code, and the groups merge in group order: the
result is bit-identical whether the groups run in one thread, a thread pool, a Dask local
scheduler or a ``LocalCluster`` of processes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import pickle
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.core.problems import gmti
from symmon.compile import compiled
from symmon.measures.sweep import sweep_alpha
from symmon.transforms import montecarlo
from symmon.transforms.montecarlo import group_normals
from symmon.transforms.stats import Stats, merge_all

from helpers import ROOT


#: Reordered sums (chunking, merging) of O(10⁶) terms: a few ulps per term, well below 1e-12.
REORDER_RTOL = 1e-12
#: Peak-memory growth allowed from 3·10⁶ to 3·10⁷ samples (the statistics are O(d²)).
RSS_GROWTH_MB = 50
#: The issue's bound on the peak at 3·10⁷ samples.
RSS_PEAK_MB = 300

MOMENTS = ("mean", "cov", "cross_cov")
PROBLEM = gmti(1.0)
MC = sm.MonteCarlo(2 * 10**5, seed=11, groups=8)


def assert_identical(a, b) -> None:
    """Two propagate results equal bit for bit, error bars included."""
    for k in MOMENTS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
        np.testing.assert_array_equal(a.stderr[k], b.stderr[k], err_msg=f"stderr {k}")


def assert_equal_to_rounding(a, b) -> None:
    """Equal up to reordered sums: each entry within REORDER_RTOL of its own scale, σ_i
    (plus |mean|) for a mean and σ_i σ_j for a covariance.

    The rounding error of a sum is relative to Σ|terms| ≈ n σ_i σ_j, not to the sum:
    QMC balances the samples so well that some sample cross-covariances are 1e-5 of
    σ_i σ_j, and relative to themselves they carry 1e5 times the rounding.
    """
    sy, su = np.sqrt(np.diag(b.cov)), np.sqrt(np.diag(b.input_cov))
    scales = {"mean": np.abs(b.mean) + sy, "cov": np.outer(sy, sy), "cross_cov": np.outer(sy, su)}
    for k in MOMENTS:
        err = np.abs(getattr(a, k) - getattr(b, k))
        np.testing.assert_array_less(err, REORDER_RTOL * scales[k], err_msg=k)


@pytest.fixture(scope="module")
def local():
    return sm.propagate(PROBLEM.model, PROBLEM.u, transform=MC)


@contextlib.contextmanager
def _quiet_distributed():
    """Ignore the one known-harmless distributed warning, during start-up and shutdown only.

    With the web server on a free port no warning fires here; on a slow file system
    distributed warns that creating its scratch directories takes long.  The filter is
    local to these calls: the tests themselves run under pytest's ``error`` filter.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Creating scratch directories is taking", category=UserWarning)
        yield


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("dask.distributed")
    with _quiet_distributed():
        # ":0": a free port.  None still starts the scheduler's HTTP server on 8787, which
        # another run on the machine may hold ("Port 8787 is already in use" warning).
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
        cl = distributed.Client(cluster)
    yield cl
    with _quiet_distributed():
        cl.close()
        cluster.close()
    assert cluster.status.name == "closed"


# --------------------------------------------------------------------------- Dask = single process
def test_local_cluster_equals_single_process(client, local):
    got = sm.propagate(PROBLEM.model, PROBLEM.u, transform=MC, executor=sm.Executor(client=client))
    assert got.info["n_samples"] == local.info["n_samples"] == MC.n
    assert_identical(got, local)


@pytest.mark.parametrize("scheduler", ["synchronous", "threads", "processes"])
def test_dask_schedulers_equal_single_process(scheduler, local):
    got = sm.propagate(PROBLEM.model, PROBLEM.u, transform=MC, executor=sm.Executor(scheduler=scheduler))
    assert_identical(got, local)


@pytest.mark.parametrize("workers", [1, 2, 5])
def test_thread_count_does_not_change_the_result(workers, local):
    got = sm.propagate(PROBLEM.model, PROBLEM.u, transform=MC, executor=sm.Executor(workers=workers))
    assert_identical(got, local)


def test_local_cluster_alpha_sweep_equals_local_sweep(client):
    alphas = [0.3, 1.0, 3.0]
    tr = sm.MonteCarlo(4 * 10**4, seed=2, groups=8)
    here = sweep_alpha(PROBLEM.model, PROBLEM.u, alphas, transform=tr)
    there = sweep_alpha(PROBLEM.model, PROBLEM.u, alphas, transform=tr, executor=sm.Executor(client=client))
    for k in ("value", "squared", "stderr", "mean", "cov", "cross_cov"):
        np.testing.assert_array_equal(getattr(there, k), getattr(here, k), err_msg=k)


def test_remote_tasks_receive_no_casadi_objects(monkeypatch, local):
    # Record exactly what the Dask path ships to a worker: the payload must be sympy and
    # numpy only (the worker recompiles), never a CasADi Function or SX.
    shipped: list[bytes] = []
    original = montecarlo._run_group_remote

    def recording(outputs, symbols, job):
        shipped.append(pickle.dumps((outputs, symbols, job)))
        return original(outputs, symbols, job)

    monkeypatch.setattr(montecarlo, "_run_group_remote", recording)
    got = sm.propagate(PROBLEM.model, PROBLEM.u, transform=MC, executor=sm.Executor(scheduler="synchronous"))
    assert len(shipped) == MC.groups
    assert all(b"casadi" not in blob for blob in shipped)
    assert_identical(got, local)
    # The model itself, after it has been compiled in this process, still pickles without CasADi.
    assert b"casadi" not in pickle.dumps(PROBLEM.model)


# --------------------------------------------------------------------------- exact merging
def test_merged_group_statistics_equal_the_concatenated_samples():
    # Regenerate every group's samples from its spawned seed, concatenate them, and compare
    # the one-shot statistics with the chunked-and-merged ones of MonteCarlo.
    x, y = sp.symbols("x y", real=True)
    model = sm.Model([x, y], [x * y + sp.sin(x), y**2 - x], name="scaleout_merge")
    mean = np.array([0.4, -1.0])
    cov = np.array([[0.5, 0.2], [0.2, 0.8]])
    tr = sm.MonteCarlo(30_011, seed=7, groups=5, chunk=1000)
    cm = compiled(model)
    groups = tr.group_stats(cm, mean, cov)
    L = np.linalg.cholesky(cov)
    parts = []
    for n_g, seed in zip(tr.sizes(), np.random.SeedSequence(7).spawn(5)):
        W = mean + group_normals(seed, n_g, 2) @ L.T
        parts.append(np.hstack([cm.eval_g(W), W]))
    whole = Stats.of(np.vstack(parts))
    merged = merge_all(groups)
    assert merged.n == whole.n == 30_011
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=REORDER_RTOL)
    np.testing.assert_allclose(merged.m2, whole.m2, rtol=REORDER_RTOL)


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(1, 399), max_size=6, unique=True), seed=st.integers(0, 2**32 - 1))
def test_merge_of_any_sharding_equals_the_whole(cuts, seed):
    Z = np.random.default_rng(seed).normal(size=(400, 3)) * [1.0, 20.0, 1e-2] + [5.0, -3.0, 0.1]
    shards = [Stats.of(s) for s in np.split(Z, sorted(cuts))]
    merged, whole = merge_all(shards), Stats.of(Z)
    assert merged.n == whole.n
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=REORDER_RTOL, atol=1e-15)
    # Rounding is relative to √(M2_ii M2_jj), not to the entry: a sample cross-product near
    # 0 (columns scaled by 20 and 1e-2) carries the rounding of the large terms it sums.
    sd = np.sqrt(np.diag(whole.m2))
    np.testing.assert_array_less(np.abs(merged.m2 - whole.m2), REORDER_RTOL * np.outer(sd, sd))


# --------------------------------------------------------------------------- chunking and memory
@pytest.mark.parametrize("qmc", [False, True], ids=["plain", "qmc"])
@pytest.mark.parametrize("chunk", [512, 3000, 8192])
def test_chunk_size_does_not_change_the_result(qmc, chunk):
    base = dict(n=2**16, seed=4, groups=4, qmc=qmc)
    one_shot = sm.propagate(PROBLEM.model, PROBLEM.u, transform=sm.MonteCarlo(**base, chunk=2**16))
    chunked = sm.propagate(PROBLEM.model, PROBLEM.u, transform=sm.MonteCarlo(**base, chunk=chunk))
    assert_equal_to_rounding(chunked, one_shot)


_RSS_SCRIPT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, sys.argv[2])
    import sympy as sp, symmon as sm
    # ru_maxrss can carry the parent's peak across fork/exec; the kernel's high-water mark,
    # reset here, measures this process only.
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    x = sp.Symbol("x", real=True)  # one input: memory is about n, not about the model
    model = sm.Model([x], [sp.sin(x) + x**2], name="scaleout_rss")
    u = sm.Gaussian([0.5], [[1.0]])
    m = sm.propagate(model, u, transform=sm.MonteCarlo(int(float(sys.argv[1])), seed=0))
    assert m.info["n_samples"] == int(float(sys.argv[1]))
    with open("/proc/self/status") as fh:
        print([line.split()[1] for line in fh if line.startswith("VmHWM")][0])  # KiB
    """
)


def _peak_rss_mb(n: float) -> float:
    out = subprocess.run([sys.executable, "-c", _RSS_SCRIPT, str(n), str(ROOT)],
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1]) / 1024


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses /proc/self (Linux)")
def test_peak_memory_does_not_grow_with_n():
    small, big = _peak_rss_mb(3e6), _peak_rss_mb(3e7)
    assert big - small < RSS_GROWTH_MB, (small, big)
    assert big < RSS_PEAK_MB, big


# --------------------------------------------------------------------------- randomised QMC
#: RQMC must beat plain MC's error bars by at least this factor on a smooth model at the
#: same n (measured at n = 2^14: ~45x for the mean, 6-12x for the covariance and the
#: cross-covariance, whose integrands are products and rougher; RQMC's rate is ~n^-1 vs n^-1/2).
RQMC_GAIN = 5
N_SE = 5


def test_randomised_qmc_error_bars_are_much_smaller_than_plain_mc():
    a, b = sp.symbols("a b", real=True)
    model = sm.Model([a, b], [sp.exp(a / 2) * sp.cos(b), a * b + sp.sin(a)], name="scaleout_smooth")
    u = sm.Gaussian([0.2, 0.5], [[0.5, 0.1], [0.1, 0.3]])
    truth = sm.propagate(model, u, transform=sm.GaussHermite(20))  # converged to ~1e-14
    plain = sm.propagate(model, u, transform=sm.MonteCarlo(2**14, seed=3, groups=16))
    rqmc = sm.propagate(model, u, transform=sm.MonteCarlo(2**14, seed=3, groups=16, qmc=True))
    assert rqmc.info["n_samples"] == plain.info["n_samples"] == 2**14
    for k in MOMENTS:
        assert np.all(rqmc.stderr[k] > 0), k
        np.testing.assert_array_less(RQMC_GAIN * rqmc.stderr[k], plain.stderr[k], err_msg=k)
        np.testing.assert_array_less(np.abs(getattr(rqmc, k) - getattr(truth, k)), N_SE * rqmc.stderr[k], err_msg=k)


def test_blas_runs_one_thread_inside_symmons_workers():
    """Inside the thread pool each worker sees one BLAS thread; the setting comes back after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from symmon.transforms.executor import run_groups

    def blas_threads() -> list[int]:
        return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]

    with threadpool_limits(limits=2, user_api="blas"):  # a known setting outside, whatever the machine
        before = blas_threads()
        seen = run_groups(lambda job, stop: blas_threads(), [0, 1, 2], workers=2)
        assert seen == [[1] * len(before)] * 3
        assert blas_threads() == before


@pytest.mark.parametrize("outside", ["default", "user limit"])
def test_overlapping_runs_from_two_threads_restore_the_blas_setting(outside):
    """Two Monte Carlo runs from two Python threads, the first to start the first to end
    (issue 38, item 12): BLAS is at one thread while either runs and at its own setting
    after both; restoring per run left it at one thread for good (and the second run at
    the machine's threads once the first had ended).  Under a user's own limit in the
    main thread, threadpoolctl ≥ 3.6 ignored the runs' limits (only the thread that set
    the last limit may change it)."""
    import contextlib
    import threading

    from threadpoolctl import threadpool_info, threadpool_limits

    from symmon.transforms.executor import run_groups

    def blas_threads() -> list[int]:
        return [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]

    a_inside, b_inside, a_done = threading.Event(), threading.Event(), threading.Event()
    seen: dict[str, list] = {}

    def run_a() -> None:
        def job(_, stop):
            a_inside.set()
            assert b_inside.wait(30)
            return blas_threads()
        seen["a"] = run_groups(job, [0], workers=1)

    def run_b() -> None:
        def job(_, stop):
            b_inside.set()
            assert a_done.wait(30)
            return blas_threads()
        seen["b"] = run_groups(job, [0], workers=1)

    if outside == "default" and max(blas_threads(), default=1) < 2:
        pytest.skip("BLAS runs one thread here already: nothing to restore")
    with (threadpool_limits(limits=2, user_api="blas") if outside == "user limit" else contextlib.nullcontext()):
        before = blas_threads()
        ta, tb = threading.Thread(target=run_a), threading.Thread(target=run_b)
        ta.start()
        assert a_inside.wait(30)
        tb.start()
        ta.join(30)
        seen["between"] = blas_threads()  # a has ended, b still runs
        a_done.set()
        tb.join(30)
        after = blas_threads()
    ones = [1] * len(before)
    assert seen["a"] == [ones] and seen["b"] == [ones] and seen["between"] == ones
    assert after == before


@pytest.mark.parametrize("where", ["threads", "synchronous", "client"])
def test_dask_runs_report_progress_per_finished_group(where, capsys, monkeypatch, request):
    """Off a terminal, a line per finished group (the interval set to 0), as the thread pool."""
    from symmon import progress

    monkeypatch.setattr(progress, "LINE_INTERVAL", 0.0)
    ex = (sm.Executor(client=request.getfixturevalue("client"), progress=True) if where == "client"
          else sm.Executor(scheduler=where, progress=True))
    mc = sm.MonteCarlo(4000, seed=1, groups=4)
    sm.propagate(PROBLEM.model, PROBLEM.u, transform=mc, executor=ex)
    lines = [l for l in capsys.readouterr().err.splitlines() if l.startswith("Monte Carlo groups:")]
    assert [l.split()[3] for l in lines] == ["1/4", "2/4", "3/4", "4/4"]
    with progress.silenced():
        sm.propagate(PROBLEM.model, PROBLEM.u, transform=mc, executor=ex)
    assert "Monte Carlo groups" not in capsys.readouterr().err
