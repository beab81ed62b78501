"""Jackknife groups of particles each hold weight, and a particle file is read in blocks
(issue 38, item 11)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.files import samplefile
from symmon.propagation import particles

x, y, e1 = sp.symbols("x y e1", real=True)
SMOOTH = sm.Model([x, y], [sp.exp(0.3 * x) * y, sp.sin(x) + 0.5 * y**2])
GENERAL = sm.Model([x, y], [sp.exp(x * e1) + y, sp.sin(x * e1)], noise=[e1])
V = sm.Gaussian([0.1], [[0.02]])
#: Sums of the same particles whose weights differ by rounding: 1e-12.
RTOL = 1e-12


@pytest.fixture(scope="module")
def every_20th() -> tuple[sm.Empirical, sm.Empirical]:
    """4000 particles of which only every 20th has weight (all of them in one group of the
    interleaved groups i mod 20), and the same weighted particles alone."""
    rng = np.random.default_rng(38)
    X = rng.normal(size=(4000, 2))
    w = np.zeros(4000)
    w[::20] = rng.uniform(0.5, 1.0, 200)
    return sm.Empirical(X, w), sm.Empirical(X[::20], w[::20])


def test_particles_of_zero_weight_leave_the_groups_and_the_error_bars_as_without_them(every_20th):
    sparse, dense = every_20th
    assert particles.jackknife_groups(sparse) == particles.GROUPS
    a, b = sm.propagate(SMOOTH, sparse), sm.propagate(SMOOTH, dense)
    for k in ("mean", "cov", "cross_cov"):
        assert np.all(np.isfinite(a.stderr[k])) and np.all(a.stderr[k] > 0)
        # The same sums in the same order; the weights differ by the rounding of their
        # normalisation (a sum over 4000 or over 200 of them).
        np.testing.assert_allclose(a.stderr[k], b.stderr[k], rtol=RTOL)
    np.testing.assert_allclose(a.mean, b.mean, rtol=RTOL)
    mon_a, mon_b = sm.nonlinearity(SMOOTH, sparse), sm.nonlinearity(SMOOTH, dense)
    assert np.isfinite(mon_a.stderr) and mon_a.stderr > 0
    assert (mon_a.value, mon_a.stderr) == pytest.approx((mon_b.value, mon_b.stderr), rel=RTOL)


def test_general_noise_groups_of_zero_weight_particles_too(every_20th):
    sparse, dense = every_20th
    a, b = (sm.nonlinearity(GENERAL, u, V, transform=sm.GaussHermite(3)) for u in (sparse, dense))
    assert np.isfinite(a.stderr) and (a.value, a.stderr) == pytest.approx((b.value, b.stderr), rel=RTOL)


def test_fewer_weighted_particles_than_groups_make_fewer_groups():
    w = np.zeros(200)
    w[[3, 50, 77, 120, 199]] = 1.0
    cloud = sm.Empirical(np.random.default_rng(1).normal(size=(200, 2)), w)
    assert particles.jackknife_groups(cloud) == 5
    with pytest.warns(sm.errors.SampleSizeWarning):
        m = sm.propagate(SMOOTH, cloud)
    assert m.info["jackknife_groups"] == 5 and np.all(np.isfinite(m.stderr["cov"]))


def test_a_particle_file_is_read_in_blocks_of_floats(tmp_path, monkeypatch):
    """The peak memory of reading is a small multiple of the particles as doubles (the
    blocks, their concatenation, the Empirical's copies of samples and deviations: at most
    5 copies, plus one block being filled), not of the text: reading the whole text into
    lists of Python floats took about 275 bytes a particle here, and the read of the
    whole file by ``read(limit + 1)`` allocated the 500 MB limit up front."""
    rng = np.random.default_rng(7)
    monkeypatch.setattr(samplefile, "BLOCK_ROWS", 1024, raising=False)  # several blocks of a small file
    N, cols = 8_000, 3
    X = np.round(rng.uniform(0, 9, size=(N, cols)), 2)
    p = tmp_path / "cloud.csv"
    with open(p, "w", encoding="utf-8") as fh:
        fh.write("x,y,weight\n")
        fh.writelines(f"{a:.2f},{b:.2f},{c:.2f}\n" for a, b, c in X)
    model = sm.Model([x, y], [x * y])
    tracemalloc.start()
    try:
        e = sm.load_samples_file(p, model)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(e.samples, X[:, :2])
    np.testing.assert_allclose(e.weights, X[:, 2] / X[:, 2].sum(), rtol=1e-12)
    doubles = N * cols * 8
    assert peak < 5 * doubles + samplefile.BLOCK_ROWS * cols * 8, (peak, doubles)
