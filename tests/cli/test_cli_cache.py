"""``symmon cache``: the compiled-code cache's directory, size, entries and cap, and ``clear``
(issue 47, item 13).  Each test has a cache directory of its own with fake entries."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from symmon.cli import parser as cli
from symmon.compile import ccbuild

MIB = 1 << 20
T0 = 1_000_000_000


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def fake_entry(d: Path, name: str, size: int, used: float) -> Path:
    so = d / f"{name}.so"
    so.write_bytes(b"\0" * size)
    ccbuild.checksum_path(so).write_text(f"{ccbuild.sha256_file(so)}  {so.name}\n")
    os.utime(so, (used, used))
    return so


def entry_size(so: Path) -> int:
    return so.stat().st_size + ccbuild.checksum_path(so).stat().st_size


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    d = tmp_path / "cache"
    d.mkdir(mode=0o700)
    monkeypatch.setenv("SYMMON_CACHE", str(d))
    monkeypatch.delenv("SYMMON_CACHE_MAX_MB", raising=False)
    return d.resolve()


def test_cache_json_reports_directory_size_entries_and_cap(capsys, cache, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "64")
    old = fake_entry(cache, "sm_old_0", 3000, T0)
    new = fake_entry(cache, "sm_new_0", 1000, T0 + 3600)
    (cache / ".build-running").mkdir()
    code, out, err = run(capsys, "cache", "--json")
    assert (code, err) == (0, "")
    got = json.loads(out)
    assert got["directory"] == str(cache)
    assert got["entries"] == 2 and got["size_bytes"] == entry_size(old) + entry_size(new)
    assert got["limit_bytes"] == 64 * MIB and got["builds_running"] == 1
    assert [lib["name"] for lib in got["libraries"]] == [new.name, old.name]   # most recently used first
    assert [lib["bytes"] for lib in got["libraries"]] == [entry_size(new), entry_size(old)]
    assert got["libraries"][1]["last_used"] == "2001-09-09T01:46:40+00:00"


def test_cache_prints_a_summary(capsys, cache):
    fake_entry(cache, "sm_a_0", 2 * MIB, T0)
    code, out, err = run(capsys, "cache")
    assert (code, err) == (0, "")
    assert out.splitlines() == [f"directory  {cache}", "size       2 MiB", "entries    1",
                                "cap        500 MiB (SYMMON_CACHE_MAX_MB; the least recently used entries go first)",
                                "builds     0 running"]
    assert run(capsys, "cache", "show")[1] == out


def test_cache_with_no_cap_says_so(capsys, cache, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "0")
    code, out, _ = run(capsys, "cache")
    assert code == 0 and "cap        none (SYMMON_CACHE_MAX_MB=0)" in out.splitlines()
    code, out, _ = run(capsys, "cache", "--json")
    assert code == 0 and json.loads(out)["limit_bytes"] is None


def test_cache_clear_removes_the_entries_and_leaves_running_builds(capsys, cache):
    entries = [fake_entry(cache, f"sm_e{i}_0", 1000, T0 + i) for i in range(2)]
    freed = sum(entry_size(so) for so in entries)
    (cache / ".build-running").mkdir()
    code, out, err = run(capsys, "cache", "clear")
    assert (code, err) == (0, "")
    assert out == f"removed 2 entries ({freed / 1024:.3g} KiB) from {cache}; 1 build(s) running now left to finish\n"
    assert sorted(p.name for p in cache.iterdir()) == [".build-running"]
    code, out, _ = run(capsys, "cache", "--json")
    assert code == 0 and json.loads(out)["entries"] == 0


def test_cache_clear_json(capsys, cache):
    so = fake_entry(cache, "sm_a_0", 100, T0)
    size = entry_size(so)
    code, out, _ = run(capsys, "cache", "clear", "--json")
    assert code == 0
    assert json.loads(out) == {"directory": str(cache), "removed": 1, "bytes_freed": size, "builds_running": 0}


@pytest.mark.parametrize("action", [[], ["clear"]])
def test_a_bad_cap_is_an_error(capsys, cache, monkeypatch, action):
    so = fake_entry(cache, "sm_a_0", 100, T0)
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "1.5")
    code, out, err = run(capsys, "cache", *action)
    assert (code, out) == (1, "")
    assert err == "symmon: error: SYMMON_CACHE_MAX_MB must be a whole number of MiB (0: no limit), got '1.5'\n"
    assert so.exists()


def test_an_unknown_action_is_a_usage_error(capsys, cache):
    code, _, err = run(capsys, "cache", "purge")
    assert code == 2 and "invalid choice: 'purge'" in err
