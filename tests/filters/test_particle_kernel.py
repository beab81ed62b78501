"""The compiled bootstrap recursion of sm.ParticleFilter (symmon/filters/pf_kernel.py) against
its NumPy twin, the loop of ParticleFilter.filter that runs for the other proposals, and the
C random numbers (symmon/filters/pf_rng.py).

The compiled path draws its normals and resampling uniforms in C; given the same draws
(``_replay``: the move normals, the resampling points and the regularisation's normals, fed
to both paths) the two must give the same particles: every output agrees to rounding (1e-9
absolute on means of order 10, far below the Monte Carlo error of ~1e-2 at N = 400, and far
above the 1e-13 the two differ by in summation order), and the resampling decisions agree
exactly.  The cases cover what the kernel compiles in: a full (non-diagonal) Q whose factor
has every nonzero, f with noise symbols, a parameter per step, an angle state and an angle
output, missing components and a missing step, a bank of runs, each resampling scheme, the
regularisation, and the kernels of ``on_collapse`` (Liu & West's shrink, the jitter).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import has_compiler
from symmon.filters.bank import constructor_args
from symmon.filters.particle.particle_filter import resampling_points
from symmon.filters.particle._kernel import whitening
from symmon.filters.particle._kernel import MIN_THREAD_NUMBERS
from symmon.filters.particle._rng import CHUNK

pytestmark = pytest.mark.skipif(not has_compiler(), reason="the compiled step needs a C compiler")

x1, x2, th, a, w1, w2 = sp.symbols("x1 x2 th a w1 w2", real=True)
F = sm.Model([x1, x2, th], [x1 + a * x2 + w1, 0.9 * x2 + w2, th + 0.1 * x2], angles=[2], noise=[w1, w2],
             params=[a], name="pfk_f")
H = sm.Model([x1, x2, th], [sp.atan2(x2 + 3, x1 + 5), x1 + x2, sp.cos(th)], angles=[0], name="pfk_h")
Q = np.array([[0.2, 0.05], [0.05, 0.1]])
R = np.diag([0.01, 0.5, 0.05])
X0 = sm.Gaussian([0.0, 1.0, 3.0], np.diag([1.0, 0.5, 0.1]))
K = 6
# Enough particles for several C threads on the main thread (n + n_q = 5 numbers each), many chunks
N_THREADS = max(3 * CHUNK, MIN_THREAD_NUMBERS // 5) + 100


def numpy_twin(pf: sm.ParticleFilter) -> sm.ParticleFilter:
    """The same filter with the compiled step switched off (its cached kernel set to None)."""
    twin = sm.ParticleFilter(**constructor_args(pf))
    twin.__dict__["_bootstrap_kernel"] = None
    return twin


@pytest.fixture(scope="module")
def data():
    xs, ys = sm.simulate(F, H, Q, R, X0, K, runs=2, params={"a": 0.5}, seed=3)
    ys = ys.copy()
    ys[0, 2, 1] = np.nan  # one missing component
    ys[1, 4] = np.nan  # a step without a measurement
    return xs, ys


def replay(pf: sm.ParticleFilter, runs: int, seed: int) -> dict:
    """Draws for both paths: move normals, ascending resampling points of the filter's
    scheme on [0, N), jitter normals."""
    g = np.random.default_rng(seed)
    N, nq, n = pf.particles, pf.space.Lq.shape[0], pf.space.n
    z = g.standard_normal((runs, K, N, nq))
    u = np.array([[resampling_points(pf.resample, g, N) for _ in range(K)] for _ in range(runs)])
    return {"z": z, "u": u, "j": g.standard_normal((runs, K, N, n))}


@pytest.mark.parametrize("method, threshold, reg, collapse", [("systematic", 0.7, False, None),
                                                               ("stratified", 1.0, True, None),
                                                               ("multinomial", 0.5, False, None),
                                                               ("systematic", 0.3, False, "shrink"),
                                                               ("stratified", 0.3, True, "shrink"),
                                                               ("systematic", 0.3, False, "jitter")])
def test_the_compiled_step_equals_its_numpy_twin(data, method, threshold, reg, collapse):
    xs, ys = data
    pf = sm.ParticleFilter(F, H, Q, R, particles=400, resample=method, ess_threshold=threshold, seed=7,
                           regularise=reg, on_collapse=collapse, collapse_fraction=0.5)
    # built now: a C above ccache.BACKGROUND_BYTES builds in the background (a fresh cache)
    assert pf._bootstrap_kernel is not None and pf._bootstrap_kernel._native.wait(600)
    assert pf._bootstrap_kernel.loops() is not None
    twin = numpy_twin(pf)
    draws = replay(pf, 2, 11)
    object.__setattr__(pf, "_replay", draws)
    object.__setattr__(twin, "_replay", draws)
    params = {"a": np.tile(np.linspace(0.4, 0.6, K), (2, 1))}
    got = pf.filter(ys, X0, params=params, x_true=xs)
    ref = twin.filter(ys, X0, params=params, x_true=xs)
    np.testing.assert_array_equal(got.resampled, ref.resampled)
    np.testing.assert_array_equal(got.rejuvenated, ref.rejuvenated)
    assert got.resampled.any() and (threshold == 1.0 or not got.resampled.all())
    # with on_collapse, some steps below the floor moved by the kernel, some above it not
    assert got.rejuvenated.any() == (collapse is not None) and not got.rejuvenated.all()
    for name in ("x", "P", "x_pred", "P_pred", "innovation", "S", "nis_values", "nees_values", "loglik", "ess",
                 "final_particles", "final_log_weights"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-9, atol=1e-9, err_msg=name)
    assert np.all(got.loglik[1, 4] == 0.0)  # no measurement: log Σ W = 0 exactly
    assert np.all(np.abs(got.x[..., 2]) <= np.pi)


@pytest.mark.parametrize("reg", [True, False])
def test_the_numbers_of_a_seed_do_not_depend_on_the_threads(reg):
    """N_THREADS particles are many streams of CHUNK particles: on the main thread the run
    uses min(CPUs, chunks) C threads, which claim the chunks of its moves and walks in turn,
    on another thread one (row_spans); the result is the same bit for bit (every reduction is
    per chunk, in chunk order), with and without regularisation, over steps with and without
    a resampling (the log-weights then carried by the next move)."""
    xs, ys = sm.simulate(F, H, Q, R, X0, K, params={"a": 0.5}, seed=4)
    pf = sm.ParticleFilter(F, H, Q, R, particles=N_THREADS, ess_threshold=0.5, seed=5, regularise=reg)
    main = pf.filter(ys, X0, params={"a": 0.5})
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("r", pf.filter(ys, X0, params={"a": 0.5})))
    t.start()
    t.join()
    other = box["r"]
    for name in ("x", "P", "x_pred", "P_pred", "loglik", "ess", "innovation", "final_particles", "final_log_weights"):
        np.testing.assert_array_equal(getattr(main, name), getattr(other, name), err_msg=name)
    assert main.resampled.any() and not main.resampled[-1]  # the last log-weights t - lse


def test_keeping_only_the_mean_gives_the_same_mean(data):
    xs, ys = data
    pf = sm.ParticleFilter(F, H, Q, R, particles=300, seed=2)
    full = pf.filter(ys, X0, params={"a": 0.5})
    only = pf.filter(ys, X0, params={"a": 0.5}, keep=("x",))
    np.testing.assert_allclose(only.x, full.x, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(only.loglik, full.loglik)


def test_a_non_finite_particle_names_the_run_and_step():
    x = sp.Symbol("x", real=True)
    f = sm.Model([x], [sp.exp(x)], name="pfk_exp")
    h = sm.Model([x], [x], name="pfk_id")
    with pytest.raises(sm.errors.NonFiniteError, match="step 2"):
        sm.ParticleFilter(f, h, [[1e-4]], [[1e10]], particles=50).filter(np.zeros((4, 1)), sm.Gaussian([3.0], [[1e-6]]))


def test_whitening_embeds_the_measured_block():
    S = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.0]])
    A, c = whitening(S, np.array([True, False, True]))
    m = [0, 2]
    np.testing.assert_allclose(A[np.ix_(m, m)].T @ A[np.ix_(m, m)], np.linalg.inv(S[np.ix_(m, m)]), atol=1e-14)
    assert np.all(A[1] == 0) and np.all(A[:, 1] == 0)
    np.testing.assert_allclose(c, -0.5 * (np.log(np.linalg.det(S[np.ix_(m, m)])) + 2 * np.log(2 * np.pi)), rtol=1e-14)
    assert whitening(S, np.zeros(3, dtype=bool))[1] == 0.0


def test_the_pick_read_through_indices_gives_the_particles():
    """Without regularisation the kernel keeps a resampling's pick as indices (the next move
    reads through them) and copies the particles only at the end: with resampling at every
    step (the last included) on many chunks, the final particles, the mean and the
    log-likelihood equal the NumPy twin's (which gathers the rows) to rounding, and the
    multi-threaded run equals the one-thread run bit for bit."""
    xs, ys = sm.simulate(F, H, Q, R, X0, K, params={"a": 0.5}, seed=6)
    pf = sm.ParticleFilter(F, H, Q, R, particles=N_THREADS, ess_threshold=1.0, seed=8)
    twin = numpy_twin(pf)
    draws = {k: v[:1] for k, v in replay(pf, 1, 12).items()}
    object.__setattr__(pf, "_replay", draws)
    object.__setattr__(twin, "_replay", draws)
    got = pf.filter(ys, X0, params={"a": 0.5})
    ref = twin.filter(ys, X0, params={"a": 0.5})
    assert got.resampled.all()
    for name in ("final_particles", "final_log_weights", "x", "loglik"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-9, atol=1e-9, err_msg=name)
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("r", pf.filter(ys, X0, params={"a": 0.5})))
    t.start()
    t.join()
    for name in ("final_particles", "x", "loglik"):
        np.testing.assert_array_equal(getattr(got, name), getattr(box["r"], name), err_msg=name)


@pytest.fixture(scope="module")
def pick():
    """The kernel's resampling walk over N weights for given ascending points (``pts``), or
    for the systematic points pt + i (``pts`` None: the walk by particle)."""
    fn = sm.ParticleFilter(F, H, Q, R, particles=10)._bootstrap_kernel.loops()[3]

    def walk(e: np.ndarray, pt: float, pts: np.ndarray | None = None) -> np.ndarray:
        idx = np.full(len(e), -1, dtype=np.int64)
        assert fn(e.ctypes.data, len(e), 0 if pts is None else pts.ctypes.data, pt, idx.ctypes.data) == 0
        return idx
    return walk


def _weights(case: str, g: np.random.Generator) -> np.ndarray:
    N = 3 * CHUNK + 77  # several chunks, the last one short
    if case == "random":
        return g.exponential(size=N)
    if case == "sparse":  # most weights zero, whole chunks among them
        e = np.where(g.random(N) < 0.05, g.exponential(size=N), 0.0)
        e[CHUNK:2 * CHUNK] = 0.0
        return e
    if case == "one":  # degenerate: every point on one particle
        e = np.zeros(N)
        e[CHUNK + 5] = 1.0
        return e
    if case == "uniform":  # the cumulative weights fall exactly on the points (ties)
        return np.ones(N)
    if case == "spread":  # weights over 600 orders of magnitude
        return np.exp(g.uniform(-700.0, 0.0, N))
    return g.exponential(size=1)  # one particle


@pytest.mark.parametrize("case", ["random", "sparse", "one", "uniform", "spread", "single"])
@pytest.mark.parametrize("pt", [0.0, 0.37, 1.0 - 2.0**-53])
def test_the_systematic_walk_by_particle_equals_the_search_by_point(pick, case, pt):
    """Systematic points pt + i go by particle (each particle's points found at once), other
    schemes' by point; given the points pt + i as an array the search by point must make
    the same picks, ties included; and the picks are systematic resampling's: particle j is
    drawn ⌊N W_j⌋ or ⌈N W_j⌉ times (to rounding) and the picks ascend."""
    e = _weights(case, np.random.default_rng(len(case)))
    N = len(e)
    got = pick(e, pt)
    ref = pick(e, pt, pt + np.arange(N, dtype=float))
    np.testing.assert_array_equal(got, ref)
    assert np.all(np.diff(got) >= 0) and got.min() >= 0 and got.max() < N
    counts = np.bincount(got, minlength=N)
    expected = N * e / e.sum()
    assert np.all(np.abs(counts - expected) < 1 + 1e-9 * N)
