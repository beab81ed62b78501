"""Shared fixtures: the lecture's radar model and a few distributions.

The package is imported from the working tree, so the suite runs without installing it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import settings

# Every property test sees the same examples on every run (no example database, a seed
# derived from the test): a suite that passed once passes again, and a rare input that
# makes sympy or a solver slow cannot turn up on one CI run only.
settings.register_profile("symmon", derandomize=True, database=None)
settings.load_profile("symmon")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without `pip install -e .`
    sys.path.insert(0, str(ROOT))

import symmon as sm  # noqa: E402

REFERENCE = Path(__file__).parent / "reference"


@pytest.fixture(scope="session")
def lecture_radar() -> dict:
    """The printed numbers of the lecture's radar example (tests/reference/lecture_radar.json)."""
    return json.loads((REFERENCE / "lecture_radar.json").read_text())


def radar_model(sensor: tuple[float, float]) -> sm.Model:
    """The direct model x = p + [r cos φ, r sin φ] of a sensor at p (lecture, radar example)."""
    r, phi = sp.symbols("r phi", real=True)
    return sm.Model([r, phi], [sensor[0] + r * sp.cos(phi), sensor[1] + r * sp.sin(phi)], name="radar_direct")


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every random test input is reproducible."""
    return np.random.default_rng(20240917)


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    """A random symmetric positive definite matrix with eigenvalues in [0.1, 1]·scale."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return scale * (Q * rng.uniform(0.1, 1.0, n)) @ Q.T


@pytest.fixture(autouse=True)
def _fresh_angle_warnings():
    """Each test starts (and leaves) with no AngleWarning issued: the warning comes once
    per model and output in a process, which would make a test depend on the ones before."""
    from symmon.transforms.base import _ANGLE_WARNED

    _ANGLE_WARNED.clear()
    yield
    _ANGLE_WARNED.clear()
