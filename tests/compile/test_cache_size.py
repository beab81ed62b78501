"""The size of the compiled-code cache: its entries, the cap and least-recently-used eviction,
``clear``, and the lock that keeps both safe with concurrent processes (issue 47, item 13).

Most tests use small fake entries (a library file and its checksum) with chosen modification
times, the times eviction orders by; the others build tiny real libraries.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

import symmon.compile.ccache as cc
from symmon.compile import ccbuild, has_compiler
from symmon.errors import SymmonError

needs_cc = pytest.mark.skipif(not has_compiler(), reason="no C compiler")

MIB = 1 << 20
#: Modification times (seconds since the epoch) of fake entries: the older, the sooner evicted.
T0 = 1_000_000_000


def fake_entry(d: Path, name: str, size: int, used: float) -> Path:
    """A cache entry ``name.so`` of ``size`` bytes (sparse) with its checksum, last used at ``used``."""
    so = d / f"{name}.so"
    with open(so, "wb") as fh:
        fh.truncate(size)
    ccbuild.checksum_path(so).write_text(f"{ccbuild.sha256_file(so)}  {so.name}\n")
    os.utime(so, (used, used))
    return so


def entry_size(so: Path) -> int:
    return so.stat().st_size + ccbuild.checksum_path(so).stat().st_size


def present(so: Path) -> bool:
    return so.exists() and ccbuild.checksum_path(so).exists()


def gone(so: Path) -> bool:
    return not so.exists() and not ccbuild.checksum_path(so).exists()


# --------------------------------------------------------------------------- the cap
@pytest.mark.parametrize(("text", "limit"), [("", cc.CACHE_MAX_MB * MIB), ("12", 12 * MIB), (" 3 ", 3 * MIB),
                                             ("0", None)])
def test_the_cap_is_symmon_cache_max_mb_in_mib_and_zero_means_none(monkeypatch, text, limit):
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", text)
    assert cc.cache_limit() == limit


def test_the_default_cap_applies_without_the_variable(monkeypatch):
    monkeypatch.delenv("SYMMON_CACHE_MAX_MB", raising=False)
    assert cc.cache_limit() == 500 * MIB


@pytest.mark.parametrize("text", ["-1", "1.5", "abc", "1e3", "0x10", "12 MB"])
def test_a_bad_cap_is_an_error_naming_the_variable(monkeypatch, text):
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", text)
    with pytest.raises(SymmonError, match=rf"SYMMON_CACHE_MAX_MB must be a whole number of MiB \(0: no limit\), "
                                          rf"got '{text.strip()}'"):
        cc.cache_limit()


def test_a_bad_cap_stops_a_compile_before_it_builds(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "lots")
    monkeypatch.setattr(cc, "_build", lambda *a: pytest.fail("built despite the bad cap"))
    with pytest.raises(SymmonError, match="SYMMON_CACHE_MAX_MB"):
        cc.NativeLibrary("int f(void) { return 1; }", "sm_badcap", lambda p: p)
    if has_compiler():
        with pytest.raises(SymmonError, match="SYMMON_CACHE_MAX_MB"):
            cc.build_shared_library("int f(void) { return 1; }", "sm_badcap")
    assert not list(tmp_path.glob("*.so"))


# --------------------------------------------------------------------------- entries and sizes
def test_entries_are_listed_least_recently_used_first_with_their_checksums(tmp_path):
    new = fake_entry(tmp_path, "sm_new_0", 3000, T0 + 20)
    old = fake_entry(tmp_path, "sm_old_0", 1000, T0)
    mid = fake_entry(tmp_path, "sm_mid_0", 2000, T0 + 10)
    (tmp_path / ".build-abc").mkdir()                                 # a build running: not an entry
    (tmp_path / ".build-abc" / "f.so").write_bytes(b"x" * 100)
    (tmp_path / "sm_orphan_0.so.sha256").write_text("0" * 64 + "  sm_orphan_0.so\n")  # no library
    (tmp_path / "notes.txt").write_text("not an entry")
    (tmp_path / "sm_link_0.so").symlink_to(old)                        # not a regular file
    entries = cc.cache_entries(tmp_path)
    assert [e.path for e in entries] == [old, mid, new]
    assert [e.size for e in entries] == [entry_size(old), entry_size(mid), entry_size(new)]
    assert entries[0].size == 1000 + len(f"{'0' * 64}  sm_old_0.so\n")
    assert [e.last_used for e in entries] == [T0, T0 + 10, T0 + 20]


def test_cache_info_reports_the_directory_size_entries_cap_and_builds(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "7")
    a = fake_entry(tmp_path, "sm_a_0", 1000, T0)
    b = fake_entry(tmp_path, "sm_b_0", 500, T0 + 1)
    (tmp_path / ".build-x").mkdir()
    info = cc.cache_info()
    assert info.directory == tmp_path.resolve()
    assert [e.path.name for e in info.entries] == [b.name, a.name]   # most recently used first
    assert info.size == entry_size(a) + entry_size(b)
    assert (info.limit, info.builds) == (7 * MIB, 1)


def test_an_empty_cache_has_no_entries(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path / "new"))
    info = cc.cache_info()
    assert (info.entries, info.size, info.builds) == ((), 0, 0)


# --------------------------------------------------------------------------- eviction
def test_eviction_removes_the_least_recently_used_entries_until_under_the_cap(tmp_path):
    entries = [fake_entry(tmp_path, f"sm_e{i}_0", 1000, T0 + i) for i in (3, 0, 2, 1)]
    by_age = sorted(entries, key=lambda so: so.stat().st_mtime)
    cap = entry_size(by_age[2]) + entry_size(by_age[3]) + 10          # room for the two newest
    removed = cc.evict(tmp_path, cap)
    assert removed == by_age[:2]
    assert all(gone(so) for so in by_age[:2]) and all(present(so) for so in by_age[2:])
    assert sum(e.size for e in cc.cache_entries(tmp_path)) <= cap


def test_eviction_stops_as_soon_as_the_cache_fits(tmp_path):
    old = fake_entry(tmp_path, "sm_old_0", 4000, T0)
    small = [fake_entry(tmp_path, f"sm_s{i}_0", 100, T0 + 1 + i) for i in range(3)]
    cap = sum(entry_size(so) for so in small)                         # the big old one alone must go
    assert cc.evict(tmp_path, cap) == [old]
    assert all(present(so) for so in small)


def test_eviction_keeps_the_new_entry_and_the_libraries_loaded_here(tmp_path, monkeypatch):
    old_loaded = fake_entry(tmp_path, "sm_loaded_0", 1000, T0)
    old = fake_entry(tmp_path, "sm_old_0", 1000, T0 + 1)
    just_built = fake_entry(tmp_path, "sm_built_0", 1000, T0 + 2)
    monkeypatch.setattr(cc, "_loaded", {old_loaded})
    assert cc.evict(tmp_path, 0, keep=[just_built]) == [old]           # a cap below even the new entry
    assert present(old_loaded) and present(just_built) and gone(old)


def test_no_cap_evicts_nothing(tmp_path):
    so = fake_entry(tmp_path, "sm_a_0", 10 * MIB, T0)
    assert cc.evict(tmp_path, None) == [] and present(so)


@pytest.mark.parametrize("vanished", ["both", "library", "checksum"])
def test_eviction_tolerates_entries_another_process_removes_meanwhile(tmp_path, monkeypatch, vanished):
    first = fake_entry(tmp_path, "sm_first_0", 1000, T0)
    second = fake_entry(tmp_path, "sm_second_0", 1000, T0 + 1)
    newest = fake_entry(tmp_path, "sm_newest_0", 1000, T0 + 2)
    listed = cc.cache_entries

    def listed_then_removed(d):
        out = listed(d)  # another process evicts the oldest entry right after this one listed it
        if vanished in ("both", "checksum"):
            ccbuild.checksum_path(first).unlink()
        if vanished in ("both", "library"):
            first.unlink()
        return out

    monkeypatch.setattr(cc, "cache_entries", listed_then_removed)
    assert cc.evict(tmp_path, entry_size(newest)) == [first, second]
    assert gone(first) and gone(second) and present(newest)


def test_eviction_does_not_wait_for_a_process_that_holds_the_lock(tmp_path):
    so = fake_entry(tmp_path, "sm_a_0", 1000, T0)
    with ccbuild.cache_lock(tmp_path) as held:                        # another reader, loading an entry
        assert held
        assert cc.evict(tmp_path, 0) == []
    assert present(so)
    assert cc.evict(tmp_path, 0) == [so]


def test_a_lock_holder_excludes_the_other_kind(tmp_path):
    with ccbuild.cache_lock(tmp_path, exclusive=True) as held:
        assert held
        with ccbuild.cache_lock(tmp_path, wait=False) as reader:
            assert not reader
    with ccbuild.cache_lock(tmp_path) as held, ccbuild.cache_lock(tmp_path, wait=False) as other:
        assert held and other                                          # readers share it
        with ccbuild.cache_lock(tmp_path, exclusive=True, wait=False) as remover:
            assert not remover


def test_install_moves_both_files_under_the_shared_lock(tmp_path, monkeypatch):
    built = tmp_path / "build" / "f.so"
    built.parent.mkdir()
    built.write_bytes(b"library")
    exclusive_possible = []
    real_replace = os.replace

    def replace(src, dst):
        with ccbuild.cache_lock(tmp_path, exclusive=True, wait=False) as held:
            exclusive_possible.append(held)
        real_replace(src, dst)

    monkeypatch.setattr(ccbuild.os, "replace", replace)
    ccbuild.install(built, tmp_path / "sm_f_0.so")
    monkeypatch.undo()
    assert exclusive_possible == [False, False]
    assert cc._verify(tmp_path / "sm_f_0.so") is None


def test_an_entry_removed_while_it_is_opened_is_built_again_without_a_warning(tmp_path):
    so = fake_entry(tmp_path, "sm_a_0", 100, T0)

    def load(path):  # another process (on a file system without locks) removed it meanwhile
        cc._remove_entry(path)
        raise OSError(f"{path}: cannot open shared object file")

    assert cc._open_entry(so, load) == (None, None)
    damaged = fake_entry(tmp_path, "sm_b_0", 100, T0)
    assert cc._open_entry(damaged, lambda p: (_ for _ in ()).throw(OSError("bad ELF"))) == \
        (None, "loading it failed (bad ELF)")


# --------------------------------------------------------------------------- clear
def test_clear_removes_every_entry_but_not_the_builds_running(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    entries = [fake_entry(tmp_path, f"sm_e{i}_0", 1000, T0 + i) for i in range(3)]
    freed = sum(entry_size(so) for so in entries)
    orphan = tmp_path / "sm_orphan_0.so.sha256"
    orphan.write_text("0" * 64 + "  sm_orphan_0.so\n")
    running = tmp_path / ".build-now"
    running.mkdir()
    (running / "f.c").write_text("int f(void) { return 1; }\n")
    stale = tmp_path / ".build-killed"
    stale.mkdir()
    old = time.time() - cc.STALE_BUILD_SECONDS - 60
    os.utime(stale, (old, old))
    assert cc.clear_cache() == (3, freed, 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".build-now"]
    assert (running / "f.c").exists()
    assert cc.clear_cache() == (0, 0, 1)


def test_clear_removes_entries_under_the_exclusive_lock(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    fake_entry(tmp_path, "sm_a_0", 100, T0)
    reader_possible = []
    remove = cc._remove_entry

    def removing(so):
        with ccbuild.cache_lock(tmp_path, wait=False) as held:
            reader_possible.append(held)
        remove(so)

    monkeypatch.setattr(cc, "_remove_entry", removing)
    assert cc.clear_cache()[0] == 1 and reader_possible == [False]


# --------------------------------------------------------------------------- with real builds
TINY = "int sm_tiny_{n}(void) {{ return {n}; }}\n"


@needs_cc
def test_loading_an_entry_marks_it_recently_used(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    so = cc.build_shared_library(TINY.format(n=1), "sm_tiny")
    assert so is not None and so.parent == tmp_path.resolve()
    os.utime(so, (T0, T0))
    before = time.time() - 1
    with pytest.MonkeyPatch.context() as m:
        m.setattr(cc, "_build", lambda *a: pytest.fail("the entry was built again"))
        assert cc.build_shared_library(TINY.format(n=1), "sm_tiny") == so
    assert so.stat().st_mtime >= before


@needs_cc
def test_a_build_evicts_the_least_recently_used_entries_beyond_the_cap(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "1")
    d = tmp_path.resolve()
    big_old = fake_entry(d, "sm_bigold_0", MIB // 2, T0)
    big_newer = fake_entry(d, "sm_bignewer_0", MIB // 2, T0 + 10)
    so = cc.build_shared_library(TINY.format(n=2), "sm_tiny")
    assert so is not None and present(so)
    assert gone(big_old) and present(big_newer)
    assert sum(e.size for e in cc.cache_entries(d)) <= MIB


@needs_cc
def test_a_cap_smaller_than_the_new_entry_keeps_the_new_entry(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    monkeypatch.setenv("SYMMON_CACHE_MAX_MB", "1")
    d = tmp_path.resolve()
    old = fake_entry(d, "sm_old_0", 2 * MIB, T0)
    so = cc.build_shared_library(TINY.format(n=3), "sm_tiny")
    assert so is not None and present(so) and gone(old)
    assert [e.path for e in cc.cache_entries(d)] == [so]
