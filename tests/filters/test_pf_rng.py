"""The particle filter's C random numbers (symmon/filters/pf_rng.py): xoshiro256++ streams and
a 256-layer ziggurat (Marsaglia & Tsang 2000), drawn through the kernel's ``normals`` entry,
and the moves' interleaved lanes (``symmon_normal_lanes``, the kernel's ``lanes`` entry),
each lane the stream NormalStream draws from its state.

References that do not share the generator: the standard normal's moments and CDF (scipy),
and the ziggurat's own defining property (layers of equal area).  Tolerances: 5 standard
errors of the statistic at the fixed seed (mean: 1/√n, variance: √(2/n), fourth moment:
√(96/n), tail fraction: √(p(1−p)/n)); the Kolmogorov–Smirnov statistic below its 0.1 %
critical value 1.95/√n.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp
from scipy import stats

import symmon as sm
from symmon.compile import has_compiler
from symmon.compile.rng import LANES, NormalStream, ziggurat_edges
from symmon.filters.particle._rng import LANE_TAG, STREAM_TAG, lane_states, stream_states

pytestmark = pytest.mark.skipif(not has_compiler(), reason="the generator is compiled C")
DRAWS = 100_000


@pytest.fixture(scope="module")
def loops():
    x = sp.Symbol("x", real=True)
    f, h = sm.Model([x], [0.5 * x], name="pfr_f"), sm.Model([x], [x], name="pfr_h")
    pf = sm.ParticleFilter(f, h, [[1.0]], [[1.0]], particles=10)
    return pf._bootstrap_kernel.loops()


@pytest.fixture(scope="module")
def normals(loops):
    """The kernel's C function: count normals of one xoshiro state (advanced in place)."""
    def draw(state: np.ndarray, count: int) -> np.ndarray:
        out = np.empty(count)
        loops[1](state.ctypes.data, count, out.ctypes.data)
        return out
    return draw


@pytest.fixture(scope="module")
def lanes(loops):
    """The kernel's C function: groups x LANES normals of LANES states (LANES, 4), lane l's
    in column l (the states advanced in place)."""
    def draw(states: np.ndarray, groups: int) -> np.ndarray:
        assert states.shape == (LANES, 4) and states.flags.c_contiguous
        out = np.empty((groups, LANES))
        loops[2](states.ctypes.data, groups, out.ctypes.data)
        return out
    return draw


def states(seed: int, streams: int) -> np.ndarray:
    return stream_states(np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0]), streams)


def test_the_ziggurat_layers_have_equal_area_and_close():
    x, v = ziggurat_edges()
    f = np.exp(-0.5 * x**2)
    assert x[0] * f[1] == pytest.approx(v, rel=1e-14)  # the base: rectangle to r plus the tail
    areas = x[1:256] * (f[2:257] - f[1:256])  # layer i: width x_i, from f(x_i) up to f(x_(i+1))
    np.testing.assert_allclose(areas, v, rtol=1e-9)
    assert x[256] == 0.0 and np.all(np.diff(x) < 0)


def test_moments_and_ks_of_the_normals(normals):
    z = normals(states(1, 1)[0].copy(), DRAWS)
    n = z.size
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1) < 5 * math.sqrt(2 / n)
    assert abs((z**4).mean() - 3) < 5 * math.sqrt(96 / n)
    assert abs(stats.skew(z)) < 5 * math.sqrt(6 / n)
    assert stats.kstest(z, "norm").statistic < 1.95 / math.sqrt(n)
    # the tail beyond the base layer's edge r (Marsaglia's method) has its normal mass
    r = ziggurat_edges()[0][1]
    p = 2 * stats.norm.sf(r)
    assert abs(np.mean(np.abs(z) > r) - p) < 5 * math.sqrt(p * (1 - p) / n)


def test_streams_are_reproducible_and_independent(normals):
    st = states(2, 3)
    a = normals(st[0].copy(), DRAWS)
    np.testing.assert_array_equal(a, normals(states(2, 3)[0].copy(), DRAWS))  # the same seed, the same draws
    b, c = normals(st[1].copy(), DRAWS), normals(states(3, 1)[0].copy(), DRAWS)
    for u in (b, c):  # another chunk, another seed: uncorrelated, also lagged by one
        assert abs(np.corrcoef(a, u)[0, 1]) < 5 / math.sqrt(DRAWS)
        assert abs(np.corrcoef(a[1:], u[:-1])[0, 1]) < 5 / math.sqrt(DRAWS)
    assert abs(np.corrcoef(a[1:], a[:-1])[0, 1]) < 5 / math.sqrt(DRAWS)  # serially uncorrelated
    # two independent N(0, 1) samples: their difference / √2 is N(0, 1) too
    assert stats.kstest((a - b) / math.sqrt(2), "norm").statistic < 1.95 / math.sqrt(DRAWS)


def test_stream_states_do_not_depend_on_how_many_are_made():
    np.testing.assert_array_equal(states(4, 2), states(4, 7)[:2])
    assert len({tuple(s) for s in states(4, 50)}) == 50
    g = np.random.default_rng(np.random.SeedSequence(4).spawn(1)[0])
    ss = g.bit_generator.seed_seq
    words = np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key + (STREAM_TAG,)).generate_state(8, np.uint64)
    np.testing.assert_array_equal(states(4, 2).ravel(), words)


def test_the_filter_and_monte_carlo_share_one_generator(normals):
    """symmon.compile.rng's NormalStream (Monte Carlo's normals) draws the same numbers from
    a state as the particle filter's kernel: one generator, moved below both users."""
    st = states(6, 1)[0]
    stream = NormalStream(np.random.SeedSequence(0), 0)
    stream.state[:] = st
    np.testing.assert_array_equal(stream.fill(np.empty(5000)), normals(st.copy(), 5000))


def test_each_lane_draws_the_stream_of_its_state(lanes):
    """The vectorised ziggurat (AVX2 where the build has it) gives lane l the numbers the
    scalar generator draws from lane l's state, bit for bit, rejections included (2000
    draws a lane: about 30 leave the layers' core), and leaves each lane's state where the
    scalar generator leaves it."""
    st = lane_states(np.random.default_rng(np.random.SeedSequence(7).spawn(1)[0]), 2)[1].copy()
    ref = []
    for l in range(LANES):
        stream = NormalStream(np.random.SeedSequence(0), 0)
        stream.state[:] = st[l]
        ref.append(stream.fill(np.empty(2000)))
        ref.append(stream.state.copy())
    z = lanes(st, 2000)
    for l in range(LANES):
        np.testing.assert_array_equal(z[:, l], ref[2 * l])
        np.testing.assert_array_equal(st[l], ref[2 * l + 1])


def test_the_lanes_are_independent_normals(lanes):
    st = lane_states(np.random.default_rng(np.random.SeedSequence(8).spawn(1)[0]), 1)[0].copy()
    z = lanes(st, DRAWS // LANES)
    flat = z.ravel()
    n = flat.size
    assert abs(flat.mean()) < 5 / math.sqrt(n)
    assert abs(flat.var() - 1) < 5 * math.sqrt(2 / n)
    assert stats.kstest(flat, "norm").statistic < 1.95 / math.sqrt(n)
    c = np.corrcoef(z.T)[np.triu_indices(LANES, 1)]  # lanes against each other
    assert np.abs(c).max() < 5 / math.sqrt(z.shape[0])


def test_lane_states_are_the_words_of_their_tag():
    g = lambda: np.random.default_rng(np.random.SeedSequence(4).spawn(1)[0])  # noqa: E731
    np.testing.assert_array_equal(lane_states(g(), 2), lane_states(g(), 5)[:2])
    ss = g().bit_generator.seed_seq
    words = np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key + (LANE_TAG,)).generate_state(8 * LANES, np.uint64)
    np.testing.assert_array_equal(lane_states(g(), 2).ravel(), words)
    assert not np.isin(lane_states(g(), 1), stream_states(g(), 4)).any()
