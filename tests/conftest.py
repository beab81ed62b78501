"""Shared fixtures of every test folder (helpers shared as functions are in tests/helpers.py).

The package is imported from the working tree, so the suite runs without installing it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

# Every property test sees the same examples on every run (no example database, a seed
# derived from the test): a suite that passed once passes again, and a rare input that
# makes sympy or a solver slow cannot turn up on one CI run only.
settings.register_profile("symmon", derandomize=True, database=None)
settings.load_profile("symmon")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without `pip install -e .`
    sys.path.insert(0, str(ROOT))

from helpers import REFERENCE_DIR  # noqa: E402


@pytest.fixture(scope="session")
def lecture_radar() -> dict:
    """The printed numbers of the lecture's radar example (tests/reference/lecture_radar.json)."""
    return json.loads((REFERENCE_DIR / "lecture_radar.json").read_text())


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every random test input is reproducible."""
    return np.random.default_rng(20240917)


@pytest.fixture(autouse=True)
def _fresh_angle_warnings():
    """Each test starts (and leaves) with no AngleWarning issued: the warning comes once
    per model and output in a process, which would make a test depend on the ones before."""
    from symmon.transforms.base import reset_warnings

    reset_warnings()
    yield
    reset_warnings()
