"""Helpers shared by the test modules: paths of the checkout and a few test inputs.

The tests sit in folders named for the subpackage they test (tests/core, tests/cli, ...);
``pythonpath = ["tests"]`` in pyproject.toml makes this module importable from all of
them as ``from helpers import ...``, and the paths below do not depend on how deep a test
module is. Fixtures are in tests/conftest.py.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import sympy as sp

import symmon as sm

#: The checkout: the parent of tests/.
ROOT = Path(__file__).resolve().parents[1]
#: The example model and scenario files (examples/*.toml, the tutorial).
EXAMPLES = ROOT / "examples"
#: The derivation scripts run by symmon.derive.
DERIVATIONS = ROOT / "derivations"
#: Printed reference numbers of the lecture (tests/reference/*.json).
REFERENCE_DIR = ROOT / "tests" / "reference"


def checkout_environment() -> dict[str, str]:
    """The environment of a subprocess that imports the package of this checkout and draws
    nothing on screen (the runs of the README's and the docs' code blocks)."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": path}


def radar_model(sensor: tuple[float, float]) -> sm.Model:
    """The direct model x = p + [r cos φ, r sin φ] of a sensor at p (lecture, radar example)."""
    r, phi = sp.symbols("r phi", real=True)
    return sm.Model([r, phi], [sensor[0] + r * sp.cos(phi), sensor[1] + r * sp.sin(phi)], name="radar_direct")


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    """A random symmetric positive definite matrix with eigenvalues in [0.1, 1]·scale."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return scale * (Q * rng.uniform(0.1, 1.0, n)) @ Q.T


def random_gaussian(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random mean and covariance of dimension n, the covariance well conditioned."""
    A = rng.normal(size=(n, n)) / np.sqrt(n)
    return rng.normal(size=n), 0.2 * (A @ A.T) + 0.05 * np.eye(n)


def sparse_ring(n: int) -> sm.Model:
    """Output i depends on x_i, x_{i+1}, x_{i+2} (mod n): the sparse model of issue 12."""
    x = sp.symbols(f"x0:{n}", real=True)
    out = [sp.sqrt(x[i] ** 2 + x[(i + 1) % n] ** 2 + 1) + sp.sin(x[i] * x[(i + 2) % n]) for i in range(n)]
    return sm.Model(list(x), out, name=f"ring{n}")


def assert_close_to_scale(actual, expected, rtol: float) -> None:
    """``actual`` equals ``expected`` to ``rtol`` relative, entries near zero judged against the
    largest entry of ``expected`` (an absolute tolerance of rtol · max |expected|)."""
    expected = np.asarray(expected)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * np.abs(expected).max())


def turning_targets(targets: int, turn: sp.Rational, tag: str):
    """Coordinated-turn targets (px, py, v, heading th an angle state, range bias b) turning at
    ``turn`` rad per unit of dt, with range and bearing of each from a sensor at (s, 0): f's
    parameter dt, h's s.  Returns (f, h, X, dt, s)."""
    dt, s = sp.symbols("dt s", real=True)
    blocks = [sp.symbols(f"px{i} py{i} v{i} th{i} b{i}", real=True) for i in range(targets)]
    X = [v for blk in blocks for v in blk]
    f_out, h_out = [], []
    for px, py, v, th, b in blocks:
        f_out += [px + dt * v * sp.cos(th), py + dt * v * sp.sin(th), v, th + dt * turn, b]
        h_out += [sp.sqrt((px - s) ** 2 + py**2) + b, sp.atan2(py, px - s)]
    f = sm.Model(X, f_out, angles=[5 * i + 3 for i in range(targets)], params=[dt], name=f"ct {tag}")
    h = sm.Model(X, h_out, angles=[2 * i + 1 for i in range(targets)], params=[s], name=f"rb {tag}")
    return f, h, X, dt, s


#: σ of :func:`forced_sde`.
FORCED_SIGMA = 0.3


def forced_sde() -> sm.SDE:
    """dx = (−x + sin t) dt + σ (1 + t) dβ: a linear time-varying SDE with a closed form
    (:func:`forced_moments`)."""
    x, t = sp.symbols("x t", real=True)
    return sm.SDE([x], [-x + sp.sin(t)], diffusion=[FORCED_SIGMA * (1 + t)], time=t, name="forced")


def forced_moments(m0: float, P0: float, a: float, b: float) -> tuple[float, float]:
    """The mean and variance at b of :func:`forced_sde` from (m0, P0) at a:
    m(b) = e^{−(b−a)} m0 + ∫_a^b e^{−(b−s)} sin s ds, P(b) = e^{−2(b−a)} P0 + σ² ∫_a^b
    e^{−2(b−s)} (1 + s)² ds, by their antiderivatives (tests/core/test_sde_time.py checks
    them by differentiation)."""
    c = (np.sin(b) - np.cos(b)) / 2 - np.exp(-(b - a)) * (np.sin(a) - np.cos(a)) / 2
    def E(s):
        return np.exp(2 * s) * ((1 + s) ** 2 / 2 - (1 + s) / 2 + 0.25)
    return (np.exp(-(b - a)) * m0 + c,
            np.exp(-2 * (b - a)) * P0 + FORCED_SIGMA ** 2 * np.exp(-2 * b) * (E(b) - E(a)))
