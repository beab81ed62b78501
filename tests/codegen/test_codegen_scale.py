"""export_c on larger models: its moment maps equal propagate, and its C stays small.

The exported TT2 takes the block path (H_i[S_i, S_i] on the structural nonzeros) for the
sparse ring model of issue 12 and the dense path for a radar model with a dense quadratic
form; the C of the block path is compiled by gcc and called through ctypes. The TT2 of the
transforms at scale is in tests/transforms/test_scale.py.
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess

import numpy as np
import pytest
import sympy as sp

import symmon as sm

from helpers import random_gaussian, sparse_ring

#: The exported code and propagate sum the same products in a different order: rounding only.
SUM_RTOL = 1e-12


# --------------------------------------------------------------------------- export_c at scale
def radar_and_quadratic(n: int) -> sm.Model:
    """Range, bearing (an angle) and range rate of the first four states, and a dense
    quadratic form of all n: Hessians dense on every input."""
    x = sp.symbols(f"x0:{n}", real=True)
    r = sp.sqrt(x[0] ** 2 + x[1] ** 2)
    q = sp.Add(*[x[i] * x[j] * sp.Rational(2 if i != j else 1, (1 + j - i) * n) for i in range(n) for j in range(i, n)])
    return sm.Model(list(x), [r, sp.atan2(x[1], x[0]), (x[0] * x[2] + x[1] * x[3]) / r, q],
                    name=f"radar{n}", angles=[1])


@pytest.mark.parametrize("factory", [sparse_ring, radar_and_quadratic], ids=["blocks", "dense"])
def test_exported_moment_maps_match_propagate(factory):
    """The MX moment maps of export_c: the block path (ring) and the dense path (radar)."""
    from symmon.codegen.export import moment_functions

    n = 12
    model = factory(n)
    rng = np.random.default_rng(12)
    m, P = random_gaussian(n, rng)
    m[:4] = [30.0, 40.0, 1.0, -2.0]
    u = sm.Gaussian(m, P)
    fs = moment_functions(model, ut=sm.UT.cubature())
    for key, tr in (("tt2", sm.TT2()), ("ut", sm.UT.cubature())):
        ref = sm.propagate(model, u, transform=tr)
        got = [np.array(a) for a in fs[key](m, P)]
        for a, b in zip(got, (ref.mean, ref.cov, ref.cross_cov)):
            np.testing.assert_allclose(a.reshape(np.shape(b)), b, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(b).max())


def test_exported_code_grows_with_the_nonzeros(tmp_path):
    """export_c's C of the ring model: MX loops, so doubling n less than triples it
    (the unrolled SX products with P grew like n_y² n², 16× per doubling)."""
    from symmon.codegen.export import export_c

    size = {n: export_c(sparse_ring(n), tmp_path / str(n))[0].stat().st_size for n in (16, 32)}
    assert size[32] < 3 * size[16], size


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not found")
def test_compiled_block_path_matches_propagate(tmp_path):
    """The C of the block path (ring model), compiled by gcc and called through ctypes."""
    from symmon.codegen.export import export_c

    n = 12
    model = sparse_ring(n)
    c_file, _ = export_c(model, tmp_path, name="ring", ut=sm.UT.cubature())
    so = tmp_path / "libring.so"
    subprocess.run(["gcc", "-O2", "-shared", "-fPIC", str(c_file), "-o", str(so), "-lm"], check=True,
                   capture_output=True)
    dll = ctypes.CDLL(str(so))
    m, P = random_gaussian(n, np.random.default_rng(3))
    ptr = ctypes.POINTER(ctypes.c_double)
    for fn, tr in (("ring_tt2_eval", sm.TT2()), ("ring_ut_eval", sm.UT.cubature())):
        outs = [np.full(k, np.nan) for k in (n, n * n, n * n)]
        # Column-major arrays: P is symmetric, the outputs are read back in Fortran order.
        args = [np.ascontiguousarray(m), np.ascontiguousarray(P.T)] + outs
        assert getattr(dll, fn)(*[a.ctypes.data_as(ptr) for a in args]) == 0
        ref = sm.propagate(model, sm.Gaussian(m, P), transform=tr)
        for got, want in zip(outs, (ref.mean, ref.cov, ref.cross_cov)):
            got = got.reshape(np.shape(want), order="F")
            np.testing.assert_allclose(got, want, rtol=SUM_RTOL, atol=SUM_RTOL * np.abs(want).max())
