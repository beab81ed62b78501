"""A Ctrl-C stops the compiled loops of the particle filter, the Gaussian-sum filter with
splitting and the IMM (issue 47, item 5), as it stops the Kalman bank's
(test_bank_interrupt.py): each loop polls the stop flag of
:func:`symmon.compile.compiled.run_stoppable` between its steps (the particle filter also
before each chunk of a step's moves, and every one of its threads leaves at the step's
barrier), returns :data:`~symmon.compile.ckernels.STOPPED`, and the KeyboardInterrupt
propagates without a result; the next call is unaffected.

Three checks per filter, none on wall time:

* the flag set by another thread once the loop has written its first step's output: the
  loop stops after far fewer than its K steps (the steps it wrote are counted);
* the flag set before the loop starts: it stops at its first step (the particle filter
  before it moves a single particle);
* a real SIGINT to the waiting (main) thread: as in test_bank_interrupt.py, the wrapped C
  function holds its loop back until the interrupted caller has set the flag, so the order
  is fixed whatever the load of the machine; the filter raises KeyboardInterrupt, and the
  next call gives the numbers of a fresh filter.
"""

from __future__ import annotations

import ctypes
import signal
import threading
import time

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile.ckernels import STOPPED
from symmon.compile.compiled import run_stoppable
from symmon.filters.mixture import gaussian_sum as gs

#: Seconds a helper thread waits at most for what it watches (it only bounds a broken test).
PATIENCE = 60.0


def _doubles(address: int, count: int) -> np.ndarray:
    """The ``count`` doubles at ``address`` (an output block of a running C loop), as a view."""
    return np.frombuffer((ctypes.c_double * count).from_address(address), dtype=float)


def _set(flag: int) -> None:
    ctypes.c_int.from_address(flag).value = 1


def _is_set(flag: int) -> bool:
    return bool(ctypes.c_int.from_address(flag).value)


class Watch:
    """A wrapper of a loop's ctypes function ``real`` for one call: ``outputs(args)`` gives
    the (address, count) of a per-step output that the loop writes step by step (filled with
    NaN here before the loop runs), ``steps(block)`` the steps it wrote.  ``when`` is
    ``"running"`` (another thread sets the flag once the first step is written), ``"before"``
    (the flag set before the loop starts) or ``"interrupt"`` (the loop held back until the
    interrupted caller set the flag).  ``codes`` and ``done`` record each call."""

    def __init__(self, real, outputs, steps, when: str) -> None:
        self.real, self.outputs, self.steps, self.when = real, outputs, steps, when
        self.codes: list[int] = []
        self.done: list[int] = []
        self.started = threading.Semaphore(0)
        self.before = self.after = None  # what a test does with the arguments before and after the call

    def __call__(self, *args):
        flag = args[-1]
        assert isinstance(flag, int) and flag, "the loop is given the stop flag's address"
        block = _doubles(*self.outputs(args))
        block[:] = np.nan
        if self.before is not None:
            self.before(args)
        watcher = None
        if self.when == "before":
            _set(flag)
        elif self.when == "running":
            def watch() -> None:
                end = time.monotonic() + PATIENCE
                while np.isnan(block[0]) and time.monotonic() < end:
                    time.sleep(0.0005)
                _set(flag)
            watcher = threading.Thread(target=watch)
            watcher.start()
        else:
            self.started.release()
            end = time.monotonic() + PATIENCE
            while not _is_set(flag) and time.monotonic() < end:
                time.sleep(0.001)
        code = self.real(*args)
        if watcher is not None:
            watcher.join()
        self.codes.append(code)
        self.done.append(self.steps(block))
        if self.after is not None:
            self.after(args)
        return code


def interrupt_when_started(watch: Watch, call) -> None:
    """``call()`` with a SIGINT sent to this (the main) thread once the wrapped loop started:
    asserts that it raises KeyboardInterrupt."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    main = threading.get_ident()

    def send() -> None:
        if watch.started.acquire(timeout=PATIENCE):
            signal.pthread_kill(main, signal.SIGINT)

    sender = threading.Thread(target=send)
    sender.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            call()
    finally:
        sender.join()
        signal.signal(signal.SIGINT, old)


def _same(a, b, names) -> None:
    for name in names:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


# ------------------------------------------------------------------ the particle filter
x, v = sp.symbols("x v", real=True)
PF_F = sm.Model([x, v], [x + 0.1 * v, v - 0.1 * sp.sin(x)], name="stop_pf_f")
PF_H = sm.Model([x, v], [sp.sin(x) + v], name="stop_pf_h")
PF_Q, PF_R = np.diag([0.01, 0.02]), np.array([[0.1]])
PF_X0 = sm.Gaussian([0.1, 0.0], np.eye(2))
#: Particles of a run of one thread, and of one on several (MIN_THREAD_NUMBERS: 2^15 numbers).
PF_ONE, PF_MANY = 500, 20_000


def _pf(N: int) -> sm.ParticleFilter:
    pf = sm.ParticleFilter(PF_F, PF_H, PF_Q, PF_R, particles=N, seed=3)
    kern = pf._bootstrap_kernel
    if not (kern._native.wait() and kern.loops() is not None):
        pytest.skip("no C compiler: the particle filter runs its NumPy steps")
    return pf


def _pf_watch(pf, monkeypatch, when: str) -> Watch:
    kern = pf._bootstrap_kernel
    real = kern.loops()
    # PFK_RUN(P, K, N, X0, Xn0, ..., o_ll (19), ...): o_ll holds K log-likelihoods
    watch = Watch(real[0], lambda a: (a[19], a[1]), lambda blk: int(np.count_nonzero(~np.isnan(blk))), when)
    monkeypatch.setattr(kern, "loops", lambda: (watch, *real[1:]))
    return watch


@pytest.mark.parametrize("N", [PF_ONE, PF_MANY], ids=["one thread", "threads"])
def test_the_particle_filter_stops_part_way(N, monkeypatch):
    pf = _pf(N)
    K = 20_000 if N == PF_ONE else 4_000  # seconds of steps
    watch = _pf_watch(pf, monkeypatch, "running")
    with pytest.raises(KeyboardInterrupt):
        pf.filter(np.zeros((K, 1)), PF_X0, keep=("x",))
    assert watch.codes == [STOPPED]
    assert 1 <= watch.done[0] < K // 2


def test_the_particle_filter_moves_nothing_once_stopped(monkeypatch):
    pf = _pf(PF_MANY)
    watch = _pf_watch(pf, monkeypatch, "before")
    moved = []
    # Xn0 (argument 4, N x n) receives the moved particles: it stays NaN while no chunk moves
    watch.before = lambda a: _doubles(a[4], 2 * a[2]).fill(np.nan)
    watch.after = lambda a: moved.append(int(np.count_nonzero(~np.isnan(_doubles(a[4], 2 * a[2])))))
    with pytest.raises(KeyboardInterrupt):
        pf.filter(np.zeros((50, 1)), PF_X0)
    assert watch.codes == [STOPPED] and watch.done == [0]
    assert moved == [0]


@pytest.mark.parametrize("N", [PF_ONE, PF_MANY], ids=["one thread", "threads"])
def test_ctrl_c_stops_a_particle_filter_run(N, monkeypatch):
    pf = _pf(N)
    with monkeypatch.context() as mp:
        watch = _pf_watch(pf, mp, "interrupt")
        interrupt_when_started(watch, lambda: pf.filter(np.zeros((5_000, 1)), PF_X0))
    assert watch.codes == [STOPPED] and watch.done == [0]
    ys = np.random.default_rng(0).normal(size=(20, 1))
    _same(pf.filter(ys, PF_X0), _pf(N).filter(ys, PF_X0), ("loglik", "ess", "x", "final_particles"))


# ------------------------------------------------------------------ the Gaussian-sum filter
x1, x2 = sp.symbols("x1 x2", real=True)
CV = sm.Model([x1, x2], [x1 + 0.5 * x2, x2], name="stop_gsf_cv")
BEARING = sm.Model([x1, x2], [sp.atan2(x2 + 1, x1)], angles=[0], name="stop_gsf_bearing")
GSF_X0 = sm.Gaussian([2.0, 0.3], np.eye(2))


def _gsf() -> sm.GaussianSumFilter:
    gsf = sm.GaussianSumFilter(CV, BEARING, np.diag([0.05, 0.1]), np.array([[1e-3]]), split=0.05, max_components=8)
    kernel = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states).kernel()
    if kernel is None or not kernel.native.wait() or kernel.loop() is None:
        pytest.skip("no C compiler: the Gaussian-sum filter runs its stepwise NumPy filter")
    return gsf


def _gsf_watch(gsf, monkeypatch, when: str) -> Watch:
    kernel = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states).kernel()
    # sm_gsfk_run(r0, r1, K, ..., o_ll (15), ...): the runs' K log-likelihoods
    watch = Watch(kernel.loop(), lambda a: (a[15] + 8 * a[0] * a[2], (a[1] - a[0]) * a[2]),
                  lambda blk: int(np.count_nonzero(~np.isnan(blk))), when)
    monkeypatch.setattr(kernel, "loop", lambda: watch)
    return watch


def _bearings(K: int) -> np.ndarray:
    return np.random.default_rng(1).normal(0.3, 0.3, size=(K, 1))


def test_the_gaussian_sum_filter_stops_part_way(monkeypatch):
    gsf = _gsf()
    K = 50_000
    watch = _gsf_watch(gsf, monkeypatch, "running")
    with pytest.raises(KeyboardInterrupt):
        gsf.filter(_bearings(K), GSF_X0, keep=("x",))
    assert watch.codes == [STOPPED]
    assert 1 <= watch.done[0] < K // 2


def test_the_gaussian_sum_filter_stops_at_its_first_step(monkeypatch):
    gsf = _gsf()
    watch = _gsf_watch(gsf, monkeypatch, "before")
    with pytest.raises(KeyboardInterrupt):
        gsf.filter(_bearings(50), GSF_X0)
    assert watch.codes == [STOPPED] and watch.done == [0]


def test_ctrl_c_stops_a_gaussian_sum_filter_run(monkeypatch):
    gsf = _gsf()
    with monkeypatch.context() as mp:
        watch = _gsf_watch(gsf, mp, "interrupt")
        interrupt_when_started(watch, lambda: gsf.filter(_bearings(5_000), GSF_X0))
    assert watch.codes == [STOPPED] and watch.done == [0]
    ys = _bearings(20)
    _same(gsf.filter(ys, GSF_X0), _gsf().filter(ys, GSF_X0), ("loglik", "x", "P", "components", "splits"))


# ------------------------------------------------------------------ the IMM
th = sp.Symbol("th", real=True)
#: Sines enough that a step of the fused loop takes tens of microseconds (K of them: seconds).
SLOW = sum(1e-6 * sp.sin((i + 1) * th + i) for i in range(150))
IMM_H = sm.Model([th], [th + SLOW], name="stop_imm_h")


def _imm() -> sm.IMM:
    modes = [sm.NonlinearKalmanFilter(sm.Model([th], [th + d + SLOW], name=f"stop_imm_{i}"), IMM_H, [[1e-4]], [[0.01]],
                                      sm.UT.ut1()) for i, d in enumerate((0.01, -0.01))]
    imm = sm.IMM(modes, [[0.9, 0.1], [0.1, 0.9]], [0.5, 0.5])
    loop = imm._fused_loop()
    if not (loop._lib.wait(600) and loop.native() is not None):
        pytest.skip("no C compiler: the IMM calls its modes' steps from Python")
    return imm


def _imm_watch(imm, monkeypatch, when: str) -> Watch:
    loop = imm._fused_loop()
    M = len(imm.filters)
    # run(..., outs (12), runs (13), K (14), ...): outs[7] holds mu, (runs, K, M)
    watch = Watch(loop.native(), lambda a: (a[12][7], a[13] * a[14] * M),
                  lambda blk: int(np.count_nonzero(~np.isnan(blk))) // M, when)
    monkeypatch.setattr(loop, "native", lambda: watch)
    return watch


def test_the_imm_stops_part_way(monkeypatch):
    imm = _imm()
    K = 50_000
    watch = _imm_watch(imm, monkeypatch, "running")
    with pytest.raises(KeyboardInterrupt):
        imm.filter(np.zeros((K, 1)), np.zeros(1), np.eye(1))
    assert watch.codes == [STOPPED]
    assert 1 <= watch.done[0] < K // 2


def test_the_imm_stops_at_its_first_step(monkeypatch):
    imm = _imm()
    watch = _imm_watch(imm, monkeypatch, "before")
    with pytest.raises(KeyboardInterrupt):
        imm.filter(np.zeros((50, 1)), np.zeros(1), np.eye(1))
    assert watch.codes == [STOPPED] and watch.done == [0]


def test_ctrl_c_stops_an_imm_run(monkeypatch):
    imm = _imm()
    with monkeypatch.context() as mp:
        watch = _imm_watch(imm, mp, "interrupt")
        # long enough (long_bank) that the one run goes to the pool, the main thread waiting
        interrupt_when_started(watch, lambda: imm.filter(np.zeros((60_000, 1)), np.zeros(1), np.eye(1)))
    assert watch.codes == [STOPPED] and watch.done == [0]
    ys = np.random.default_rng(2).normal(0.0, 0.1, size=(20, 1))
    _same(imm.filter(ys, np.zeros(1), np.eye(1)), _imm().filter(ys, np.zeros(1), np.eye(1)),
          ("x", "P", "loglik", "mode_probabilities"))


# ------------------------------------------------------------------ run_stoppable
def test_one_long_loop_runs_off_the_main_thread_and_a_short_one_on_it():
    where = []

    def part(item, stop):
        assert isinstance(stop, int) and not _is_set(stop)
        where.append(threading.current_thread() is threading.main_thread())
        return 0

    assert run_stoppable(part, [0]) == [0] and run_stoppable(part, [0], long=True) == [0]
    assert where == [True, False]  # a Ctrl-C reaches the main thread while the long one runs


def test_a_loop_that_saw_its_flag_leaves_no_result():
    def part(item, stop):
        _set(stop)  # as another thread would
        return STOPPED

    with pytest.raises(KeyboardInterrupt):
        run_stoppable(part, [0, 1])
