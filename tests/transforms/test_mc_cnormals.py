"""Monte Carlo's normals drawn in C (symmon.compile.rng: xoshiro256++ and a ziggurat) inside
the fused chunk: the same numbers as the stream's own fill, per group, whoever draws them.

References: ``NormalStream.fill`` of the same stream (the chunk's sums from those normals
must be the same bits: the same C, the same order), NumPy's SFC64 generator without a
compiler, and the moments of N(0, 1) (5 standard errors at the fixed seed: mean 1/√n,
variance √(2/n)).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import symmon as sm
from symmon.compile import compiled, has_compiler
from symmon.compile.rng import NormalStream
from symmon.files.modelfile import load_model_file
from symmon.transforms.mc_kernel import sample_kernel
from symmon.transforms.montecarlo import MC_STREAM_TAG, group_generator, group_normals, normals_source

GMTI = Path(__file__).resolve().parents[2] / "examples" / "gmti.toml"
pytestmark = pytest.mark.skipif(not has_compiler(), reason="symmon's normals are compiled C")


@pytest.fixture(scope="module")
def spec():
    return load_model_file(GMTI)


def test_the_chunk_draws_the_normals_of_its_stream(spec):
    cm = compiled(spec.model)
    k = sample_kernel(cm, (1,))
    m, L = np.asarray(spec.u.mean, float), np.linalg.cholesky(np.asarray(spec.u.cov, float))
    p = k.params(m, L, np.zeros(k.n_z), cm.eval_g(m[None])[0])
    seq = np.random.SeedSequence(11)
    drawn, filled = NormalStream(seq, MC_STREAM_TAG), NormalStream(seq, MC_STREAM_TAG)
    chunk = k.chunk_stats(k.workspace())
    for n in (1000, 257, 3):  # not multiples of the block: the stream runs on across calls
        S, bad, first, _ = chunk.draw(drawn, p, n)
        Z = filled.fill(np.empty((n, 4)))
        S_ref, *_ = chunk(Z, p)
        assert np.array_equal(S, S_ref) and (bad, first) == (0, -1) and S[-1, -1] == n
        assert np.array_equal(drawn.state, filled.state)


def test_a_stream_is_its_seed_and_tag_and_peek_does_not_advance():
    seq = np.random.SeedSequence(5).spawn(3)[2]
    a, b = NormalStream(seq, MC_STREAM_TAG), NormalStream(seq, MC_STREAM_TAG)
    head = a.peek(np.empty(3))
    assert np.array_equal(a.fill(np.empty(10))[:3], head)
    assert np.array_equal(b.fill(np.empty(4))[:3], head)  # another stream object, the same numbers
    other = NormalStream(seq, MC_STREAM_TAG + 1).fill(np.empty(10))
    assert not np.array_equal(other, NormalStream(seq, MC_STREAM_TAG).fill(np.empty(10)))


def test_the_normals_have_the_moments_of_n01():
    z = NormalStream(np.random.SeedSequence(2), MC_STREAM_TAG).fill(np.empty(200_000))
    n = z.size
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1) < 5 * math.sqrt(2 / n)


def test_group_normals_replay_a_run(spec):
    """The first group's normals from ``group_normals``: a run on one group's worth of
    samples equals the plain moments of those samples (to rounding)."""
    mc = sm.MonteCarlo(4000, seed=9, groups=2, chunk=1000)
    cm = compiled(spec.model)
    groups = mc.group_stats(cm, np.asarray(spec.u.mean, float), np.asarray(spec.u.cov, float))
    L = np.linalg.cholesky(np.asarray(spec.u.cov, float))
    W = np.asarray(spec.u.mean, float) + group_normals(np.random.SeedSequence(9).spawn(2)[0], 2000, 4) @ L.T
    np.testing.assert_allclose(groups[0].mean[3:7], W.mean(axis=0), rtol=1e-12, atol=1e-12)


def test_without_a_compiler_the_groups_draw_from_sfc64(spec, monkeypatch):
    """Under ``SYMMON_COMPILE=never`` the normals are each group's SFC64 stream (another
    sample of the same distribution: the MoN agrees within 5 standard errors)."""
    assert normals_source() == "c"
    c_run = sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(40_000, seed=1))
    monkeypatch.setenv("SYMMON_COMPILE", "never")
    assert normals_source() == "numpy" and normals_source(qmc=True) == "qmc"
    seq = np.random.SeedSequence(4)
    np.testing.assert_array_equal(group_normals(seq, 10, 2), group_generator(seq).standard_normal((10, 2)))
    with pytest.raises(sm.SymmonError, match="C compiler"):
        NormalStream(seq, MC_STREAM_TAG)
    vm = sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(40_000, seed=1))
    assert vm.value != c_run.value
    assert abs(vm.value - c_run.value) < 5 * math.hypot(vm.stderr, c_run.stderr)
