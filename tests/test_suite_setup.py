"""The test suite's own setup (tests/conftest.py, issue 47, item 12): it compiles into a cache
of its own, shared by the whole run and inherited by subprocesses, and no test depends on how
fast the machine is through the progress lines."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import conftest
from symmon import progress
from symmon.cli import parser as cli
from symmon.compile.ccache import cache_dir

from helpers import EXAMPLES, ROOT


def test_the_suite_compiles_into_its_own_cache_not_the_users():
    assert os.environ["SYMMON_CACHE"] == str(conftest._test_cache())
    assert cache_dir() == Path(os.environ["SYMMON_CACHE"])
    home_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "symmon"
    assert cache_dir() != home_cache.resolve()


def test_the_test_cache_is_the_checkouts_and_ignored_by_git():
    if conftest._test_cache() == conftest.TEST_CACHE.resolve():
        assert conftest.TEST_CACHE.parent == ROOT
    assert f"{conftest.TEST_CACHE.name}/" in (ROOT / ".gitignore").read_text().splitlines()


def test_a_subprocess_inherits_the_test_cache():
    code = "from symmon.compile.ccache import cache_dir; print(cache_dir())"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == os.environ["SYMMON_CACHE"]


def test_a_slow_machine_prints_no_progress_line_in_a_test(capsys, monkeypatch):
    """Every item of the Monte Carlo run seems to take an hour: still an empty stderr."""
    hours = itertools.count(0, 3600.0)
    monkeypatch.setattr(progress.progress_lines, "__defaults__", (lambda: next(hours),))
    code = cli.main(["propagate", str(EXAMPLES / "polar.toml"), "--transform", "mc", "--samples", "2000",
                     "--seed", "3", "--json"])
    out, err = capsys.readouterr()
    assert (code, err) == (0, "")
    assert next(hours) > 3600.0  # the clock was read: the run did report its progress
    assert len(json.loads(out)["mean"]) == 2


def test_a_checkout_symmon_would_refuse_sends_the_test_cache_to_the_temporary_directory(monkeypatch):
    import tempfile

    from symmon.compile import ccache

    monkeypatch.setattr(ccache, "cache_refusal", lambda d: "its parent belongs to another user (uid 1000)")
    assert conftest._test_cache() == Path(tempfile.gettempdir(), f"symmon-test-cache-{os.geteuid()}")
