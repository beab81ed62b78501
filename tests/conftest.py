"""Shared fixtures of every test folder (helpers shared as functions are in tests/helpers.py).

The package is imported from the working tree, so the suite runs without installing it.

Two settings keep the suite from depending on the machine it runs on:

- **The compiled-code cache** is the checkout's ``.pytest-symmon-cache/`` (ignored by git),
  never the user's ``~/.cache/symmon``: ``SYMMON_CACHE`` is set in this process's
  environment when the conftest is imported, before any test, so every subprocess a test
  starts with ``os.environ`` inherits it.  One directory for the whole run and all the
  xdist workers (the cache is safe with concurrent processes: atomic installs, a lock
  around eviction), and kept between runs, so a model is compiled once, not once per
  worker or per run; its size is capped like any cache (``SYMMON_CACHE_MAX_MB``).  Where
  symmon would refuse that directory (a checkout others can write), a directory of this
  user's in the temporary directory is used instead.  Tests of the cache itself set their
  own ``SYMMON_CACHE``.
- **Progress lines** (stderr off a terminal, one every ``LINE_INTERVAL`` seconds) come
  only in a test that sets the interval itself: otherwise a run that is slow on a loaded
  machine would print one, and a test that expects an empty stderr would fail.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
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

#: The compiled-code cache of the test run (see the module docstring).
TEST_CACHE = ROOT / ".pytest-symmon-cache"


def _test_cache() -> Path:
    """:data:`TEST_CACHE`, or a directory of this user's in the temporary directory where
    symmon would refuse it (the same choice in every xdist worker)."""
    from symmon.compile.ccache import cache_refusal

    d = TEST_CACHE.resolve()
    if cache_refusal(d) is None:
        return d
    return Path(tempfile.gettempdir(), f"symmon-test-cache-{os.geteuid()}")


os.environ["SYMMON_CACHE"] = str(_test_cache())


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


@pytest.fixture(autouse=True)
def _progress_lines_only_where_asked(monkeypatch):
    """No progress line that depends on the machine's speed: a test that checks them sets
    ``symmon.progress.LINE_INTERVAL`` itself (to 0.0: a line after every item)."""
    from symmon import progress

    monkeypatch.setattr(progress, "LINE_INTERVAL", math.inf)
