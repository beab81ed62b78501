"""Monte Carlo's fused chunk (rows and their sums in one compiled call, the row loop
vectorised with symmon.compile.vecmath) on the shipped gmti.toml, its bearing an angle.

Reference: the same normals (each group's stream, ``group_normals``) through NumPy and libm (w = m +
Z Lᵀ, np.arctan2, np.hypot, ``wrap_angle``), their moments by ``np.cov``: the kernel differs
only by rounding (atan2 and hypot within 1 ulp of libm's, sums in another order), so the
moments and the MoN agree to 1e-9 relative, far inside their standard errors (~1e-3
relative at 2·10⁵ samples), which the test checks too.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.compile import compiled, has_compiler
from symmon.core.angles import wrap_angle
from symmon.errors import SamplingError
from symmon.files.modelfile import load_model_file
from symmon.transforms.mc_kernel import sample_kernel
from symmon.transforms.montecarlo import group_normals

GMTI = Path(__file__).resolve().parents[2] / "examples" / "gmti.toml"
N = 200_000
pytestmark = pytest.mark.skipif(not has_compiler(), reason="the fused chunk is compiled C")


@pytest.fixture(scope="module")
def spec():
    return load_model_file(GMTI)


@pytest.fixture(scope="module")
def kernel(spec):
    k = sample_kernel(compiled(spec.model), (1,))
    assert k.compiled and k.vectorised  # sqrt, atan2, hypot, floor: all have vector forms
    return k


def numpy_moments(spec, mc: sm.MonteCarlo):
    """E y, Cov y, Cov(y, u) of gmti from the groups' own normals, by NumPy and libm."""
    m, P = np.asarray(spec.u.mean, float), np.asarray(spec.u.cov, float)
    L = np.linalg.cholesky(P)
    W = np.concatenate([m + group_normals(s, n, 4) @ L.T
                        for n, s in zip(mc.sizes(), np.random.SeedSequence(mc.seed).spawn(mc.groups))])
    dx, dy = W[:, 0] - 1000.0, W[:, 1] - 1000.0
    r = np.sqrt(dx**2 + dy**2 + 1e6)
    ref = np.arctan2(m[0] - 1000.0, m[1] - 1000.0)
    b = ref + wrap_angle(np.arctan2(dx, dy) - ref)
    Y = np.column_stack([r, b, (dx * W[:, 2] + dy * W[:, 3]) / r])
    C = np.cov(np.column_stack([Y, W]).T)
    mean, cov = Y.mean(axis=0), C[:3, :3]
    # The bearing's circular mean, and its variance about it (symmon.transforms.stats.moments_of).
    h = np.hypot(dx, dy)
    circ = np.arctan2((dx / h).mean(), (dy / h).mean())
    cov[1, 1] += wrap_angle(mean[1] - circ) ** 2
    mean[1] = circ
    return mean, cov, C[:3, 3:]


def test_the_chunk_sums_equal_the_product_of_its_rows(spec, kernel):
    cm = compiled(spec.model)
    m, L = np.asarray(spec.u.mean, float), np.linalg.cholesky(np.asarray(spec.u.cov, float))
    p = kernel.params(m, L, np.zeros(kernel.n_z), cm.eval_g(m[None])[0])
    Z = np.random.default_rng(0).standard_normal((1000, 4))  # not a multiple of the block or of 16
    A = np.empty((1000, kernel.n_out))
    kernel(Z, p, A)
    S, n_bad, first, _ = kernel.stats(Z, p)
    np.testing.assert_allclose(S, A.T @ A, rtol=1e-12, atol=0)
    assert S[-1, -1] == 1000 and (n_bad, first) == (0, -1)
    assert np.array_equal(S, S.T)


def test_moments_and_mon_equal_numpy_and_libm_on_the_same_normals(spec):
    mc = sm.MonteCarlo(N, seed=3)
    got = sm.propagate(spec.model, spec.u, transform=mc)  # the file declares the bearing an angle
    mean, cov, cross = numpy_moments(spec, mc)
    np.testing.assert_allclose(got.mean, mean, rtol=1e-9)
    np.testing.assert_allclose(got.cov, cov, rtol=1e-9)
    np.testing.assert_allclose(got.cross_cov, cross, rtol=1e-9, atol=1e-9 * np.abs(cross).max())
    # ... and so well inside the standard errors the method reports.
    assert np.all(np.abs(got.mean - mean) < 1e-3 * got.stderr["mean"])


def test_the_same_numbers_for_a_seed_on_one_or_two_threads(spec):
    runs = [sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(N, seed=5),
                            executor=sm.Executor(workers=w))
            for w in (1, 2, 2)]
    assert runs[0].value == runs[1].value == runs[2].value
    assert runs[0].stderr == runs[1].stderr
    other = sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(N, seed=5, chunk=1000))
    assert other.value == pytest.approx(runs[0].value, rel=1e-12)  # other chunks: rounding only


def test_the_mon_of_gmti_is_the_published_value_within_its_error(spec):
    """The MoN of this file (α = 1): 0.04748 ± 0.00003 by 4·10⁶ samples before this kernel
    (benchmarks/RESULTS.md); 2·10⁵ samples here agree within 5 of their standard errors."""
    mon = sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(N, seed=0))
    assert abs(mon.value - 0.04748) < 5 * mon.stderr + 3e-5


@pytest.mark.parametrize("g", ["sqrt", "log"], ids=["vectorised", "libm-rows"])
def test_the_nonfinite_samples_are_counted(g):
    """sqrt has a vector form, log does not (CasADi's C per row): both name the count of
    the chunk's samples where g is NaN, which is the count of negative samples."""
    x = sp.Symbol("x")
    model = sm.Model([x], [getattr(sp, g)(x)])
    k = sample_kernel(compiled(model))
    assert k.vectorised == (g == "sqrt")
    mc = sm.MonteCarlo(1000, seed=0, groups=2)
    w = 2.0 + group_normals(np.random.SeedSequence(0).spawn(2)[0], 500, 1)[:, 0]
    bad = int((w < 0).sum())
    assert 0 < bad < 50
    first = re.escape(repr([float(w[w < 0][0])]))
    with pytest.raises(SamplingError, match=rf"NaN or inf at {bad} of 500 samples.*first bad sample w = {first}"):
        sm.propagate(model, sm.Gaussian([2.0], [[1.0]]), transform=mc, executor=sm.Executor(workers=1))
