"""The on-disk C cache heals, its directory is safe, compiles can be interrupted (issues 12, 13).

Most checks run a fresh Python in a subprocess: the compiler choice is cached per process,
warnings are given once per process, and signals must reach a process of their own.
"""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import symmon.compile.ccache as cc
from symmon.compile import has_compiler

from helpers import ROOT

#: Seconds a subprocess gets to start, compile a tiny model, or die after a signal.
SUBPROCESS_TIMEOUT = 120

needs_cc = pytest.mark.skipif(not has_compiler(), reason="no C compiler")

# Evaluates a model compiled under the name "cachetest" (argv[1] picks its outputs) and
# prints its values and the evaluator that ran.
SCRIPT = """
import sys
import numpy as np, sympy as sp
from symmon.compile import CompiledModel
x, y = sp.symbols("x y", real=True)
shift = int(sys.argv[1]) if len(sys.argv) > 1 else 0
cm = CompiledModel([x * y + shift, sp.exp(x)], [x, y], name="cachetest", compiled=True)
print(repr(cm.eval_g(np.array([[1.0, 2.0], [3.0, 4.0]])).tolist()))
print(cm.evaluator)
"""
EXPECTED = repr([[2.0, float(np.exp(1.0))], [12.0, float(np.exp(3.0))]])


def run(env_extra: dict[str, str], *args: str, script: str = SCRIPT) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SYMMON_", "XDG_CACHE"))}
    env.update(env_extra)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], env=env,
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)


def libraries(d: Path) -> list[Path]:
    return sorted(d.glob("sm_cachetest_*_g_*.so"))




# --------------------------------------------------------------------------- damaged entries
@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    """A cache holding the model, and one holding the model plus 1 under the same symbols."""
    if not has_compiler():
        pytest.skip("no C compiler")
    dirs = {}
    for shift in ("0", "1"):
        d = dirs[shift] = tmp_path_factory.mktemp(f"cache{shift}")
        res = run({"SYMMON_CACHE": str(d)}, shift)
        assert res.returncode == 0, res.stderr
        assert res.stdout.splitlines()[1] == "compiled"
    assert res.stdout.splitlines()[0] != EXPECTED
    return dirs


def sidecar(so: Path) -> Path:
    return so.with_name(so.name + ".sha256")


@pytest.mark.parametrize("damage", ["truncate", "empty", "swap", "swap-with-checksum", "no-checksum"])
def test_damaged_entry_is_rebuilt(tmp_path, built, damage):
    shutil.copytree(built["0"], tmp_path, dirs_exist_ok=True)
    so, = libraries(tmp_path)
    digest = sidecar(so).read_text()
    plus_one, = libraries(built["1"])
    if damage == "truncate":  # was a Bus error (exit 135) on every later run
        so.write_bytes(so.read_bytes()[: so.stat().st_size // 2])
    elif damage == "empty":
        so.write_bytes(b"")
    elif damage == "no-checksum":
        sidecar(so).unlink()
    else:  # a valid library with the same symbol that adds 1: was loaded silently
        so.write_bytes(plus_one.read_bytes())
        if damage == "swap-with-checksum":  # the pair copied under this entry's name
            sidecar(so).write_text(sidecar(plus_one).read_text())
    res = run({"SYMMON_CACHE": str(tmp_path)})
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [EXPECTED, "compiled"]
    assert "is damaged" in res.stderr and "rebuilding" in res.stderr
    assert libraries(tmp_path) == [so] and sidecar(so).read_text() == digest
    assert not list(tmp_path.glob(".build-*"))


def test_verified_entry_loads_quietly(built):
    res = run({"SYMMON_CACHE": str(built["0"])})
    assert res.returncode == 0 and res.stdout.splitlines() == [EXPECTED, "compiled"] and res.stderr == ""


# --------------------------------------------------------------------------- untrusted entries
def _loosen(so: Path, how: str) -> str:
    """Make the entry ``so`` one that someone else could have written; returns the reason
    the warning must give."""
    if how == "group-writable library":
        so.chmod(0o775)
        return f"{so.name} is group-writable"
    if how == "world-writable checksum":
        sidecar(so).chmod(0o666)
        return f"{sidecar(so).name} is world-writable"
    if how == "library of another user":
        os.chown(so, 65534, 65534)
        return f"{so.name} belongs to another user (uid 65534)"
    assert how == "symlinked library"
    real = so.with_name("elsewhere.so")
    so.rename(real)
    so.symlink_to(real)
    return f"{so.name} is not a regular file"


def _listing(d: Path) -> list[tuple[str, int, int, bytes]]:
    return sorted((p.name, p.lstat().st_mode, p.lstat().st_uid, p.read_bytes()) for p in d.iterdir())


@pytest.mark.parametrize("how", ["group-writable library", "world-writable checksum", "symlinked library"])
def test_distrusted_entries(tmp_path, how):
    """Each way an entry may have been written by someone else, in process (the next test
    runs the whole load in a fresh Python)."""
    so = tmp_path / "sm_f_0123.so"
    so.write_bytes(b"library")
    sidecar(so).write_text(f"{cc.sha256_file(so)}  {so.name}\n")
    assert cc._distrust(so) is None
    why = _loosen(so, how)
    assert cc._distrust(so) == why


@pytest.mark.parametrize("how", [
    "group-writable library",
    pytest.param("library of another user", marks=pytest.mark.skipif(
        os.geteuid() != 0, reason="needs root to give a file to another user")),
])
def test_untrusted_entry_is_not_loaded(tmp_path, built, how):
    """A matching checksum says nothing about who wrote the pair: an entry someone else
    could have written is left alone, and the library is built privately instead."""
    shutil.copytree(built["0"], tmp_path, dirs_exist_ok=True)
    so, = libraries(tmp_path)
    # The planted library is the model plus 1, with a checksum that matches it.
    so.write_bytes(libraries(built["1"])[0].read_bytes())
    sidecar(so).write_text(f"{cc.sha256_file(so)}  {so.name}\n")
    why = _loosen(so, how)
    before = _listing(tmp_path)
    res = run({"SYMMON_CACHE": str(tmp_path)})
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [EXPECTED, "compiled"]
    assert f"not loading the cached library {so}: {why}; building it in" in res.stderr, res.stderr
    assert _listing(tmp_path) == before


def test_entry_of_another_user_is_distrusted(tmp_path, monkeypatch):
    """The owner check, for any user: the process pretends to be someone else."""
    so = tmp_path / "sm_f_0123.so"
    so.write_bytes(b"library")
    sidecar(so).write_text(f"{cc.sha256_file(so)}  {so.name}\n")
    assert cc._distrust(so) is None
    monkeypatch.setattr(cc.os, "geteuid", lambda: so.stat().st_uid + 1)
    assert cc._distrust(so) == f"{so.name} belongs to another user (uid {so.stat().st_uid})"


@needs_cc
def test_untrusted_entry_is_built_privately(tmp_path, monkeypatch):
    """In process: the path handed to the loader is in the private directory, warned once."""
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    code = "int f(void) { return 1; }"
    so = cc._entry(code, "sm_trust", cc.OPT_SYNC, pytest.fail)
    so.write_bytes(b"planted")
    so.chmod(0o664)
    warned: list[str] = []
    private = cc._entry(code, "sm_trust", cc.OPT_SYNC, warned.append)
    assert private == cc._private_dir() / so.name and len(warned) == 1
    assert cc._entry(code, "sm_trust", cc.OPT_SYNC, warned.append) == private and len(warned) == 1
    assert cc._load_or_build(code, "sm_trust", cc.OPT_SYNC, lambda p: p, pytest.fail) == private
    assert cc._verify(private) is None and so.read_bytes() == b"planted"


def test_installed_entry_is_private_whatever_the_umask(tmp_path):
    built_so = tmp_path / "f.so"
    old = os.umask(0o002)
    try:
        built_so.write_bytes(b"library")
        cc.ccbuild.install(built_so, tmp_path / "sm_f_0123.so")
    finally:
        os.umask(old)
    assert cc._distrust(tmp_path / "sm_f_0123.so") is None
    assert cc._verify(tmp_path / "sm_f_0123.so") is None


# --------------------------------------------------------------------------- the directory
def _fallback_run(env: dict[str, str]) -> subprocess.CompletedProcess:
    res = run(env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == EXPECTED
    return res


@needs_cc
def test_unwritable_directory_falls_back(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache's parent should be")
    res = _fallback_run({"SYMMON_CACHE": str(blocker / "cache")})
    assert res.stdout.splitlines()[1] == "compiled"
    assert "not using the cache directory" in res.stderr and "cannot be created" in res.stderr


@needs_cc
@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only directory")
def test_read_only_directory_falls_back(tmp_path):
    d = tmp_path / "ro"
    d.mkdir(mode=0o500)
    res = _fallback_run({"SYMMON_CACHE": str(d)})
    assert "not writable" in res.stderr and not list(d.iterdir())


@needs_cc
@pytest.mark.parametrize("mode, why", [(0o777, "world-writable"), (0o770, "group-writable")])
def test_a_directory_others_can_write_is_refused(tmp_path, mode, why):
    """Anyone else who can write there could plant a library with a matching checksum:
    the cache goes to a private directory instead."""
    d = tmp_path / "shared"
    d.mkdir()
    d.chmod(mode)
    res = _fallback_run({"SYMMON_CACHE": str(d)})
    assert res.stdout.splitlines()[1] == "compiled"
    assert why in res.stderr and not list(d.iterdir())


@needs_cc
@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a directory to another user")
def test_directory_of_another_user_is_refused(tmp_path):
    d = tmp_path / "theirs"
    d.mkdir(mode=0o755)
    os.chown(d, 65534, 65534)
    res = _fallback_run({"SYMMON_CACHE": str(d)})
    assert "belongs to another user" in res.stderr and not list(d.iterdir())


def test_symlinks_are_resolved_and_their_target_checked(tmp_path, monkeypatch):
    target = tmp_path / "target"
    target.mkdir(mode=0o700)
    link = tmp_path / "link"
    link.symlink_to(target)
    monkeypatch.setenv("SYMMON_CACHE", str(link))
    assert cc.cache_dir() == target  # later paths cannot be redirected by the link
    target.chmod(0o770)
    with pytest.warns(RuntimeWarning, match=f"not using the cache directory {target}: it is group-writable"):
        assert cc.cache_dir() == cc._private_dir()


@pytest.mark.parametrize("mode, refused", [(0o777, True), (0o775, True), (0o1777, False), (0o755, False)])
def test_a_parent_others_can_write_is_refused(tmp_path, mode, refused):
    """Whoever can write the parent can rename the cache away and put their own in its
    place, unless the sticky bit (/tmp's) keeps them to their own files."""
    parent = tmp_path / "parent"
    parent.mkdir()
    parent.chmod(mode)
    why = cc.cache_refusal(parent / "cache")
    if refused:
        assert why == f"its parent {parent} is {'world' if mode & 0o002 else 'group'}-writable " \
                      "(someone else could replace the cache)"
    else:
        assert why is None


@pytest.mark.parametrize("configured", ["/", "/usr", "/etc", "/var", "/usr/lib/symmon-test-cache",
                                        "/usr/local/share/symmon-test-cache", "link to /usr", "link to /"])
def test_root_refuses_a_system_directory(tmp_path, monkeypatch, configured):
    """As root every directory is writable and owned: the system's own are refused by
    path (after resolving symlinks), before anything is created there."""
    if configured.startswith("link to "):
        link = tmp_path / "cache"
        link.symlink_to(configured.removeprefix("link to "))
        configured = str(link)
    created = not Path(configured).exists()
    monkeypatch.setattr(cc.os, "geteuid", lambda: 0)
    assert cc.cache_refusal(Path(configured).resolve()) == \
        "it is a system directory, where symmon running as root caches nothing"
    assert not created or not Path(configured).exists()


@pytest.mark.parametrize("path, system", [("/var/cache/symmon", False), ("/root/.cache/symmon", False),
                                          ("/opt/symmon/cache", False), ("/home", True), ("/lib64", True),
                                          ("/sys/kernel", True), ("/tmp", True)])
def test_system_paths(path, system):
    assert cc.is_system_path(Path(path)) is system


@needs_cc
def test_directory_is_created_private(tmp_path):
    d = tmp_path / "a" / "cache"
    res = run({"SYMMON_CACHE": str(d)})
    assert res.returncode == 0 and res.stdout.splitlines() == [EXPECTED, "compiled"], res.stderr
    assert stat.S_IMODE(d.stat().st_mode) == 0o700


@needs_cc
@pytest.mark.skipif(Path("/.cache").exists(), reason="/.cache exists already")
def test_empty_home_does_not_create_a_root_cache(tmp_path):
    res = run({"HOME": "", "TMPDIR": str(tmp_path)})
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [EXPECTED, "compiled"] and res.stderr == ""
    assert not Path("/.cache").exists()
    assert not list(tmp_path.iterdir())  # the private directory is removed at exit


def test_cache_dir_follows_xdg_and_home(tmp_path, monkeypatch):
    monkeypatch.delenv("SYMMON_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cc.cache_dir() == tmp_path / "xdg" / "symmon"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cc.cache_dir() == tmp_path / "home" / ".cache" / "symmon"


@needs_cc
def test_key_covers_the_compiler_version_and_target(monkeypatch):
    before = cc._entry("int f(void) { return 1; }", "f", "-O2", print).name
    monkeypatch.setattr(cc, "_compiler_identity", lambda cmd: "gcc 99\nriscv64-linux-gnu")
    assert cc._entry("int f(void) { return 1; }", "f", "-O2", print).name != before
    assert "riscv64" not in before and cc._compiler_identity.__name__ == "<lambda>"


@needs_cc
def test_builds_target_this_cpu_and_key_on_it(monkeypatch):
    """-march=native where the compiler takes it, with what it expands to in the key: a cache
    shared by two CPUs keeps an entry for each."""
    flags, expansion = cc.native_target(cc._compiler())
    assert flags == ("-march=native",) and expansion  # gcc and clang both take it
    before = cc._entry("int f(void) { return 1; }", "f", "-O2", print).name
    monkeypatch.setattr(cc, "native_target", lambda cmd: (("-march=native",), "-march=other-cpu"))
    assert cc._entry("int f(void) { return 1; }", "f", "-O2", print).name != before


NO_NATIVE_CC = """#!/bin/sh
# The real compiler, except that it refuses -march=native (as a cross compiler might).
case "$1" in -march=native) echo "cc: error: unrecognized -march=native" >&2; exit 1;; esac
for a in "$@"; do [ "$a" = "-march=native" ] && { echo "asked for -march=native" >&2; exit 1; }; done
exec REAL "$@"
"""


@needs_cc
def test_a_compiler_without_march_native_builds_for_its_default_target(tmp_path):
    fake = tmp_path / "cc-no-native"
    fake.write_text(NO_NATIVE_CC.replace("REAL", shutil.which("gcc") or shutil.which("cc")))
    fake.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("SYMMON_")}
    env.update(CC=str(fake), SYMMON_CACHE=str(tmp_path / "cache"), SYMMON_COMPILE="sync",
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    script = textwrap.dedent("""
        import numpy as np, sympy as sp
        import symmon.compile.ccache as cc
        from symmon.compile import CompiledModel
        x, y = sp.symbols("x y")
        cm = CompiledModel([x * y + 1], [x, y], name="no_native", compiled=True)
        print(cc.native_target(cc._compiler()), cm.eval_g(np.ones((2, 2))).ravel().tolist(), cm.evaluator)
    """)
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["((),", "'')", "[2.0,", "2.0]", "compiled"]


# --------------------------------------------------------------------------- interrupts
FAKE_CC = """#!/bin/sh
# A compiler that never finishes: it records its pid and that of a child (like cc1), then waits.
case "$1" in --version) echo "fake-cc 1.0"; exit 0;; -dumpmachine) echo "x86_64-fake-linux-gnu"; exit 0;;
  -march=native) exit 1;; esac  # the target probe (ccache.native_target): not supported
echo $$ > "$FAKE_CC_DIR/driver.pid"
sleep 600 &
echo $! > "$FAKE_CC_DIR/child.pid"
wait
"""

# Starts a compile with the fake compiler; in the background mode it then waits for it.
SLOW_SCRIPT = """
import logging, signal, sys, time
import numpy as np, sympy as sp
from symmon.compile import CompiledModel
logging.basicConfig(level=logging.INFO, format="%(name)s %(message)s")
if sys.argv[1] == "own-handler":  # a program with its own SIGINT handler: symmon keeps it
    def own(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGINT, own)
x, y = sp.symbols("x y", real=True)
cm = CompiledModel([x * y], [x, y], name="slow", compiled=True)
print(cm.eval_g(np.ones((3, 2))).ravel().tolist(), cm.evaluator, flush=True)
if sys.argv[1] in ("sleep", "own-handler"):  # until SIGTERM or SIGINT
    time.sleep(600)
if sys.argv[1] == "catch":  # until SIGINT, then exit with 130 as the symmon command does
    try:
        time.sleep(600)
    except KeyboardInterrupt:
        sys.exit(130)
if sys.argv[1] == "exit":  # until the test says so, then exit normally
    sys.stdin.readline()
"""


def alive(pid: int) -> bool:
    """True if the process exists and is not a zombie."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return False
    return fields[0] != "Z"


def slow_env(tmp_path: Path, compiler: str, mode: str, cache: Path) -> dict[str, str]:
    """The environment of SLOW_SCRIPT: ``compiler`` (a script text) as $CC."""
    fake = tmp_path / "fake-cc"
    fake.write_text(compiler)
    fake.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("SYMMON_")}
    env.update(CC=str(fake), FAKE_CC_DIR=str(tmp_path), SYMMON_CACHE=str(cache), SYMMON_COMPILE=mode,
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    return env


def start_slow_compile(tmp_path: Path, mode: str, arg: str, cache: Path | None = None,
                       **env_extra: str) -> tuple[subprocess.Popen, Path, list[int]]:
    """A Python compiling with the fake compiler; returns once the compiler's child runs.

    ``cache`` is where the build directory must appear (default: ``$SYMMON_CACHE``).
    """
    env = slow_env(tmp_path, FAKE_CC, mode, tmp_path / "cache")
    env.update(env_extra)
    cache = Path(env["SYMMON_CACHE"]) if cache is None else cache
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(SLOW_SCRIPT), arg], env=env, text=True,
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    while not (tmp_path / "child.pid").exists() or not (tmp_path / "child.pid").read_text().strip():
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < deadline, "the fake compiler did not start"
        time.sleep(0.05)
    # The fake compiler runs before Popen has returned in the parent; a signal inside Popen
    # itself would lose the child's pid (a window of microseconds for a real Ctrl-C).
    time.sleep(1.0)
    pids = [int((tmp_path / f).read_text()) for f in ("driver.pid", "child.pid")]
    assert all(alive(pid) for pid in pids)
    assert list(cache.glob("**/.build-*/f.c"))  # the compile's temporary directory exists now
    return p, cache, pids


def assert_dead(pids: list[int]) -> None:
    deadline = time.monotonic() + 10
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)  # SIGKILL is asynchronous
    assert not any(alive(pid) for pid in pids), "the compiler or its child survived"


def assert_cleaned_up(cache: Path, pids: list[int]) -> None:
    assert_dead(pids)
    assert not list(cache.glob(".build-*")), "the temporary directory survived"


needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


@needs_proc
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_during_a_compile_kills_the_compiler(tmp_path, sig):
    p, cache, pids = start_slow_compile(tmp_path, "sync", "-")
    p.send_signal(sig)
    out, err = p.communicate(timeout=SUBPROCESS_TIMEOUT)
    assert p.returncode != 0 and out == ""
    if sig == signal.SIGTERM:
        assert p.returncode == 128 + signal.SIGTERM, err
    else:
        assert "KeyboardInterrupt" in err
    assert_cleaned_up(cache, pids)


@needs_proc
@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT", "SIGINT-caught", "SIGINT-own-handler"])
def test_interrupt_kills_the_background_build(tmp_path, how):
    """An interrupted run leaves no build behind, whether or not the program catches it."""
    arg = {"SIGTERM": "sleep", "SIGINT": "sleep", "SIGINT-caught": "catch", "SIGINT-own-handler": "own-handler"}[how]
    p, cache, pids = start_slow_compile(tmp_path, "background", arg)
    p.send_signal(signal.SIGTERM if how == "SIGTERM" else signal.SIGINT)
    out, err = p.communicate(timeout=SUBPROCESS_TIMEOUT)
    assert out == "[1.0, 1.0, 1.0] vm (C build running)\n"
    # SIGTERM's default action would leave the compiler running; an uncaught
    # KeyboardInterrupt ends Python with SIGINT.
    expected = {"SIGTERM": 128 + signal.SIGTERM, "SIGINT-caught": 130}.get(how, -signal.SIGINT)
    assert p.returncode == expected, err
    assert "evaluating on CasADi's VM while it compiles" in err
    assert_cleaned_up(cache, pids)
    assert not list(cache.glob("*.so*"))


def session_of(pid: int) -> tuple[int, int, int]:
    """(parent pid, session id, controlling terminal) of a process, from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[1]), int(fields[3]), int(fields[4])


@needs_proc
def test_normal_exit_leaves_the_background_build_running(tmp_path):
    """The build process outlives the Python: its own session, no terminal, stdin /dev/null."""
    p, cache, pids = start_slow_compile(tmp_path, "background", "exit")
    out, err = p.communicate("done\n", timeout=SUBPROCESS_TIMEOUT)
    assert p.returncode == 0 and out == "[1.0, 1.0, 1.0] vm (C build running)\n", err
    builder, _, _ = session_of(pids[0])
    try:
        assert all(alive(pid) for pid in pids)
        assert session_of(builder)[1:] == (builder, 0)  # a session leader without a terminal
        assert "ccbuild.py" in Path(f"/proc/{builder}/cmdline").read_text()
        assert os.readlink(f"/proc/{builder}/fd/0") == os.devnull
        assert list(cache.glob(".build-*/f.c"))
    finally:
        os.killpg(builder, signal.SIGKILL)  # the fake compiler would wait for 10 minutes
    assert_dead(pids)


@needs_proc
def test_build_into_a_private_directory_is_killed_at_exit(tmp_path):
    """Nobody would read a private temporary cache: a normal exit kills its builds too."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)  # refused: the cache goes to a private directory under TMPDIR
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    p, _, pids = start_slow_compile(tmp_path, "background", "exit", cache=tmp,
                                    SYMMON_CACHE=str(shared), TMPDIR=str(tmp))
    private, = tmp.glob("symmon-cache-*")
    assert list(private.glob(".build-*/f.c"))
    out, err = p.communicate("done\n", timeout=SUBPROCESS_TIMEOUT)
    assert p.returncode == 0 and "world-writable" in err
    assert_dead(pids)
    assert not list(tmp.iterdir()) and not list(shared.iterdir())


# A compiler, held until the test creates $FAKE_CC_DIR/gate (at most 2 minutes), so that
# the Python which started the build has exited before the build ends.
GATED_CC = """#!/bin/sh
case "$1" in --version|-dumpmachine|-march=native) exec REAL "$@";; esac
n=0
while [ ! -e "$FAKE_CC_DIR/gate" ] && [ $n -lt 1200 ]; do sleep 0.1; n=$((n + 1)); done
exec REAL "$@"
"""

# A compiler that fails with a message.
BROKEN_CC = """#!/bin/sh
case "$1" in --version) echo "broken-cc 1.0"; exit 0;; -dumpmachine) echo "x86_64-broken-linux-gnu"; exit 0;;
  -march=native) exit 1;; esac
echo "broken-cc: error: f.c: cannot compile this" >&2
exit 1
"""


def exit_before_the_build_ends(tmp_path: Path, compiler: str, runs: int = 1) -> tuple[dict[str, str], Path]:
    """Run SLOW_SCRIPT ``runs`` times in the background mode with ``compiler`` held by a
    gate until the runs have ended normally; then open the gate and wait for the build
    directories to go.  Returns the environment and the cache directory."""
    cache = tmp_path / "cache"
    env = slow_env(tmp_path, GATED_CC.replace("REAL", compiler), "background", cache)
    for _ in range(runs):
        # A build holding the run's stdout or stderr would make this wait for the build
        # too (and time out, the gate being closed).
        res = subprocess.run([sys.executable, "-c", textwrap.dedent(SLOW_SCRIPT), "-"], env=env,
                             capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
        assert res.returncode == 0 and res.stdout == "[1.0, 1.0, 1.0] vm (C build running)\n", res.stderr
        assert "continues after exit" in res.stderr
    assert len(list(cache.glob(".build-*/f.c"))) == runs and not list(cache.glob("*.so*"))
    (tmp_path / "gate").touch()
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    while list(cache.glob(".build-*")) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not list(cache.glob(".build-*")), "the build did not end"
    return env, cache


@needs_cc
def test_normal_exit_lets_the_background_build_fill_the_cache(tmp_path):
    real = shutil.which("gcc") or shutil.which("cc")
    if real is None:
        pytest.skip("no gcc or cc on PATH")
    # Two runs, whose builds race to install the same entry when the gate opens.
    env, cache = exit_before_the_build_ends(tmp_path, real, runs=2)
    so, = cache.glob("*.so")
    assert cc._verify(so) is None and sorted(cache.iterdir()) == [so, sidecar(so)]
    again = subprocess.run([sys.executable, "-c", textwrap.dedent(SLOW_SCRIPT), "-"], env=env,
                           capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    assert again.returncode == 0 and again.stdout == "[1.0, 1.0, 1.0] compiled\n", again.stderr
    assert "loaded from the cache" in again.stderr


def test_failed_build_after_exit_leaves_nothing(tmp_path):
    broken = tmp_path / "broken-cc"
    broken.write_text(BROKEN_CC)
    broken.chmod(0o755)
    _, cache = exit_before_the_build_ends(tmp_path, str(broken))
    assert not list(cache.iterdir())


def test_failed_build_is_reported_and_leaves_nothing(tmp_path):
    cache = tmp_path / "cache"
    env = slow_env(tmp_path, BROKEN_CC, "sync", cache)
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(SLOW_SCRIPT), "-"], env=env,
                         capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    assert res.returncode == 0 and res.stdout == "[1.0, 1.0, 1.0] vm\n", res.stderr
    assert "compiling sm_slow" in res.stderr and "failed, using the CasADi VM" in res.stderr
    assert "fake-cc exited with status 1:\nbroken-cc: error: f.c: cannot compile this" in res.stderr
    assert not list(cache.iterdir())


@needs_proc
def test_sigterm_handler_is_transparent_without_a_compile(tmp_path):
    """The CLI installs the handler for good: with no compile running, SIGTERM acts as before."""
    script = "import sys, time; from symmon.compile.ccache import catch_sigterm; catch_sigterm(); print('ready', flush=True); time.sleep(600)"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline() == "ready\n"
    p.send_signal(signal.SIGTERM)
    p.communicate(timeout=SUBPROCESS_TIMEOUT)
    assert p.returncode == -signal.SIGTERM
