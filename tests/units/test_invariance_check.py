"""The proofs' high-precision TT2 (mpmath, at an exact rational point) is the TT2 of the
transforms: the same Σ_gg, and the same residual D as the measure of nonlinearity."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.units.check import _jets, _rational_point, _tt2_numeric

# Both sides evaluate one closed form; the float64 side rounds, relative to the largest entry.
FLOAT_RTOL = 1e-12

x, y, v = sp.symbols("x y v", real=True)
MODELS = {
    "polar": sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="ic_polar"),
    "general noise": sm.Model([x, y], [x * sp.exp(v) + y**2, sp.sin(x * y) + v**2], noise=[v], name="ic_general"),
}


def _float(M) -> np.ndarray:
    return np.array(M.tolist(), dtype=float)


@pytest.mark.parametrize("name", list(MODELS))
def test_mpmath_tt2_equals_the_transform(name):
    model = MODELS[name]
    mu, P, R = _rational_point(model, seed=1)
    Sgg, D = _tt2_numeric(_jets(model.inputs, model.noise, model.outputs), model.n_u, model.n_v, mu, P, R)
    u = sm.Gaussian(_float(mu).ravel(), _float(P))
    noise = sm.Gaussian(np.zeros(model.n_v), _float(R)) if model.n_v else None
    m = sm.propagate(model, u, noise, transform=sm.TT2())
    scale = np.abs(m.cov).max()
    np.testing.assert_allclose(_float(Sgg), m.cov, rtol=0, atol=FLOAT_RTOL * scale)
    res = sm.nonlinearity(model, u, noise, transform=sm.TT2())
    np.testing.assert_allclose(_float(D), res.residual_cov, rtol=0, atol=FLOAT_RTOL * scale)
