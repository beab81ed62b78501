"""The C compiler, the on-disk cache of shared libraries, and the compile policy.

symmon generates C code with CasADi and compiles it into a shared library, once per
content: the library is cached on disk and loaded by later runs.  This module owns
everything between "here is C source" and "here is a loaded library":

- **Cache directory** (:func:`cache_dir`): ``$SYMMON_CACHE``, else
  ``$XDG_CACHE_HOME/symmon``, else ``$HOME/.cache/symmon``, symlinks resolved.  It is
  created mode 0700.  A directory that is group- or world-writable or belongs to another
  user is refused, and so is one whose parent someone else could write (without the
  sticky bit) or that cannot be created or written, and, for root, one in the system's
  own directories (``/``, ``/usr``, ``/etc``, ...); symmon then uses a private temporary
  directory for the rest of the process (removed at exit), with a warning.
- **Entries**: ``STEM_KEY.so`` and, beside it, ``STEM_KEY.so.sha256`` in
  ``sha256sum`` format.  KEY hashes the source, the flags, the CasADi version and the
  compiler's path, ``--version`` output and target (``-dumpmachine``).  Right before a
  library is loaded, both files must be regular files of this user that nobody else can
  write: an entry that is not is left alone, and the library is built in the private
  directory instead, with a warning.  Then its sha256 is checked against the file beside
  it (which names the entry, so a pair copied under another key fails too); a mismatch,
  a missing checksum or a load failure gives a warning and a rebuild.
- **Size**: at most ``$SYMMON_CACHE_MAX_MB`` MiB (:data:`CACHE_MAX_MB` by default, 0 for no
  cap).  A load records the entry's use (its modification time); after a build the least
  recently used entries are evicted (:func:`evict`), never the new one nor a library this
  process loaded.  Installs, loads and removals take the directory's ``flock``
  (:func:`symmon.compile.ccbuild.cache_lock`): shared to install or load, exclusive to
  remove.  :func:`cache_info` and :func:`clear_cache` are ``symmon cache [clear]``.
- **Builds**: each runs as one build process (:mod:`symmon.compile.ccbuild`: the compiler, then
  the checksum and the atomic install) in a new session (process group) and in a
  temporary directory inside the cache.  On KeyboardInterrupt or SIGTERM the whole group
  (``cc1``, ``as``) is killed and the directory removed.  A background build still
  running when the interpreter exits normally is left to finish: it installs its library
  for the next run.  After an interrupt, and into a private temporary cache directory,
  it is killed at exit instead.
- **Policy** (``$SYMMON_COMPILE``): ``auto`` (default) compiles C of up to
  :data:`BACKGROUND_BYTES` at once with -O3, and larger C in a background thread (-O3,
  or -O0 above :data:`HUGE_BYTES` unless split into small functions,
  :func:`background_level`) while CasADi's virtual machine evaluates, then swaps the
  library in; ``sync`` always waits for the compiler (-O3); ``background`` always
  builds in the background; ``never`` uses the virtual machine only (as does
  ``SYMMON_NO_COMPILE=1``).  ``docs/compile.md`` gives the measurements behind the
  thresholds.
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import re
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable, Generic, Iterable, TypeVar

import casadi as ca

from . import ccbuild
from .ccbuild import cache_lock, checksum_path, sha256_file
from ..errors import BuildError, SymmonError

__all__ = ["cache_dir", "has_compiler", "compile_mode", "build_shared_library", "NativeLibrary",
           "catch_sigterm", "build_limits", "BACKGROUND_BYTES", "CFLAGS", "native_target",
           "CACHE_MAX_MB", "cache_limit", "CacheEntry", "CacheInfo", "cache_entries", "cache_info",
           "evict", "clear_cache", "cache_refusal"]

log = logging.getLogger(__name__)

#: Flags of every build.  No -ffast-math (it breaks NaN) and no FMA contraction, so that
#: compiled code rounds like CasADi's virtual machine.  Of fast math's parts only the two
#: that change no number: no errno from libm (sqrt becomes the bare instruction, which
#: gcc can vectorise) and no trapping math (no floating-point traps: gcc may then compute
#: both sides of a select, which vectorises the branch-free loops of symmon.compile.vecmath).
CFLAGS = ("-fPIC", "-shared", "-fno-fast-math", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math")
#: Optimisation of a build, whether the caller waits for it or not.  -O1 would compile
#: straight-line SX no faster and run the loops of MX code 3x slower than -O2; -O3
#: vectorises those loops (without reassociating a sum: the results are the same to the
#: bit) and runs the filter steps 1.3-1.6x faster, and builds straight-line SX as fast as
#: -O2 (docs/compile.md).
OPT_SYNC = "-O3"
#: Generated C larger than this (bytes) is compiled in the background under the ``auto``
#: policy: gcc -O2 takes 1-4 s for it on 2 busy cores (docs/compile.md, "Threshold").
BACKGROUND_BYTES = 64_000
#: Above this size gcc -O2 takes minutes (its time grows faster than the code) while
#: -O0 takes seconds and still evaluates 3-4x faster than the VM: background at -O0.
OPT_HUGE = "-O0"
HUGE_BYTES = 300_000
#: gcc's time grows faster than the code within one function, about linearly over many: C above
#: HUGE_BYTES made of functions of at most this size each, and at most SPLIT_BYTES in all (the
#: forward-over-reverse derivatives of an MX filter step, many functions of under 100 KB) is
#: still built at -O3 in the background, in a few tens of seconds (docs/compile.md).
SPLIT_FUNCTION_BYTES = 150_000
SPLIT_BYTES = 1_500_000
MODES = ("auto", "sync", "background", "never")

_lock = threading.Lock()
_warned: set[str] = set()


def largest_function_bytes(code: str) -> int:
    """The size in bytes of the largest top-level block of C ``code``: the text between two lines
    that start with the ``}`` closing a function (or an array), CasADi's layout and symmon's.
    C in another layout counts as one block, the whole file (the safe side)."""
    return max(len(part.encode()) for part in re.split(r"\n}[^\n]*\n", code))


def background_level(code: str) -> str:
    """The optimisation of a background build of ``code``: -O3, or -O0 for C above
    :data:`HUGE_BYTES` unless it is split into functions of at most
    :data:`SPLIT_FUNCTION_BYTES` and is at most :data:`SPLIT_BYTES` in all."""
    size = len(code.encode())
    if size <= HUGE_BYTES or (size <= SPLIT_BYTES and largest_function_bytes(code) <= SPLIT_FUNCTION_BYTES):
        return OPT_SYNC
    return OPT_HUGE


def _warn_once(key: str, message: str, stacklevel: int) -> None:
    """``warnings.warn`` a RuntimeWarning once per process for ``key``."""
    with _lock:
        if key in _warned:
            return
        _warned.add(key)
    warnings.warn(message, RuntimeWarning, stacklevel=stacklevel + 1)


# --------------------------------------------------------------------------- policy and compiler
def compile_mode() -> str:
    """The compile policy: ``$SYMMON_COMPILE`` (auto, sync, background, never).

    ``SYMMON_NO_COMPILE`` set to anything non-empty means ``never``.

    Raises
    ------
    SymmonError
        If ``SYMMON_COMPILE`` holds another value.
    """
    if os.environ.get("SYMMON_NO_COMPILE"):
        return "never"
    mode = os.environ.get("SYMMON_COMPILE", "auto").strip().lower() or "auto"
    if mode not in MODES:
        raise SymmonError(f"SYMMON_COMPILE must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


@lru_cache(maxsize=1)
def _compiler() -> tuple[str, ...] | None:
    """The compiler command: ``$CC`` (split like a shell would), else gcc, else cc."""
    cc = os.environ.get("CC", "").strip()
    if cc:
        return tuple(shlex.split(cc))
    found = shutil.which("gcc") or shutil.which("cc")
    return (found,) if found else None


@lru_cache(maxsize=4)
def native_target(cc: tuple[str, ...]) -> tuple[tuple[str, ...], str]:
    """``(("-march=native",), what it expands to)`` when the compiler takes the flag, else
    ``((), "")``; once per process.

    The builds are for this machine's cache, so they use its CPU's widest vector registers:
    the dense products of a 64-state batch kernel run 1.5x faster with AVX2/AVX-512 than with
    the SSE2 of the default target.  With no FMA contraction and no -ffast-math, vector code
    rounds as scalar code does, so the numbers stay those of CasADi's VM to the bit.  What the
    flag expands to (``-###``: the CPU and its instruction sets) is part of the cache key, so
    a cache shared by machines with different CPUs keeps one entry per CPU.
    """
    try:
        res = subprocess.run([*cc, "-march=native", "-###", "-E", "-x", "c", os.devnull], capture_output=True,
                             text=True, timeout=60, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired):
        return (), ""
    if res.returncode != 0:
        return (), ""
    return ("-march=native",), res.stdout + res.stderr


@lru_cache(maxsize=4)
def _compiler_identity(cc: tuple[str, ...]) -> str:
    """``cc --version`` and ``cc -dumpmachine`` output, once per process (part of the key)."""
    parts = []
    for flag in ("--version", "-dumpmachine"):
        try:
            res = subprocess.run([*cc, flag], capture_output=True, text=True, timeout=60,
                                 stdin=subprocess.DEVNULL)
            parts.append(f"{res.returncode}\n{res.stdout}")
        except (OSError, subprocess.TimeoutExpired) as exc:
            parts.append(f"error {exc}")
    return "\n".join(parts)


def has_compiler() -> bool:
    """True when a C compiler is found and compilation is not disabled."""
    return compile_mode() != "never" and _compiler() is not None


def warn_no_compiler(stacklevel: int) -> None:
    """Warn, once per process, that CasADi's virtual machine is used instead of C."""
    _warn_once("no-compiler",
               "symmon: no C compiler found (or SYMMON_NO_COMPILE / SYMMON_COMPILE=never set); "
               "using CasADi's virtual machine, which is several times slower",
               stacklevel=stacklevel + 1)


# --------------------------------------------------------------------------- cache directory
_private: Path | None = None


def _private_dir() -> Path:
    """A temporary directory of this process only (mode 0700), removed at exit."""
    global _private
    with _lock:
        if _private is None:
            _private = Path(tempfile.mkdtemp(prefix="symmon-cache-"))  # removed by _at_exit
        return _private


def _configured_dir() -> Path | None:
    """The directory the environment asks for, or None when it names none."""
    for var, sub in (("SYMMON_CACHE", ()), ("XDG_CACHE_HOME", ("symmon",)), ("HOME", (".cache", "symmon"))):
        value = os.environ.get(var, "")
        # An empty or relative HOME must not put the cache in / or in the working directory.
        if value and os.path.isabs(value):
            return Path(value, *sub)
        if var == "SYMMON_CACHE" and value:
            return Path(value).absolute()
    return None


#: For root, a cache in (or below) these trees is refused: they hold the system's own files.
SYSTEM_TREES = tuple(map(Path, ("/bin", "/boot", "/dev", "/etc", "/lib", "/lib32", "/lib64", "/libx32",
                                "/proc", "/run", "/sbin", "/sys", "/usr")))
#: ... and so is a cache that *is* one of these (a subdirectory, like /var/cache/symmon, is fine).
SYSTEM_DIRS = tuple(map(Path, ("/", "/home", "/media", "/mnt", "/opt", "/root", "/srv", "/tmp", "/var",
                               "/var/cache", "/var/lib", "/var/tmp")))


def is_system_path(d: Path) -> bool:
    """Whether the resolved directory ``d`` is one of the system's (see :data:`SYSTEM_TREES`)."""
    return d in SYSTEM_DIRS or any(d == t or t in d.parents for t in SYSTEM_TREES)


def _writable_by_others(mode: int) -> str | None:
    """``"world-writable"``, ``"group-writable"`` or None, for a file's ``st_mode``."""
    if mode & stat.S_IWOTH:
        return "world-writable"
    if mode & stat.S_IWGRP:
        return "group-writable"
    return None


def _parent_refusal(d: Path) -> str | None:
    """Why a parent of ``d`` would let someone else replace ``d`` (None if none would)."""
    uid = os.geteuid()
    for parent in d.parents:
        try:
            st = parent.stat()
        except OSError as exc:
            return f"its parent {parent} cannot be examined ({exc.strerror or exc})"
        if st.st_uid not in (0, uid):
            return f"its parent {parent} belongs to another user (uid {st.st_uid})"
        loose = _writable_by_others(st.st_mode)
        if loose and not st.st_mode & stat.S_ISVTX:  # /tmp's sticky bit: only the owner renames
            return f"its parent {parent} is {loose} (someone else could replace the cache)"
    return None


def cache_refusal(d: Path) -> str | None:
    """Why the resolved directory ``d`` cannot hold the cache (None if it can); creates it
    mode 0700, unless it is a system directory of root's.

    :func:`cache_dir` falls back to a private directory, with a warning, for such a
    directory; a caller that chooses ``$SYMMON_CACHE`` (a test suite) can ask first.
    """
    if os.geteuid() == 0 and is_system_path(d):
        return "it is a system directory, where symmon running as root caches nothing"
    try:
        d.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = d.lstat()  # resolved: a symlink here now was planted since
    except OSError as exc:
        return f"it cannot be created ({exc.strerror or exc})"
    if not stat.S_ISDIR(st.st_mode):
        return "it is not a directory"
    # Anyone who can write here can plant a library (and its checksum) that this process
    # would load: the checksum proves integrity, not who wrote the entry.
    loose = _writable_by_others(st.st_mode)
    if loose:
        return f"it is {loose}"
    if st.st_uid != os.geteuid():
        return f"it belongs to another user (uid {st.st_uid})"
    if not os.access(d, os.W_OK | os.X_OK):
        return "it is not writable"
    return _parent_refusal(d)


def cache_dir() -> Path:
    """The directory of the compiled-library cache, checked (see the module docstring).

    Returns the resolved path (no symlink in it).  Falls back, with a warning once per
    directory, to a private temporary directory when the configured one is unusable,
    and silently when the environment names none (``HOME`` empty or unset and no
    ``SYMMON_CACHE``).
    """
    d = _configured_dir()
    if d is None:
        return _private_dir()
    d = d.resolve()
    why = cache_refusal(d)
    if why is None:
        return d
    fallback = _private_dir()
    _warn_once(f"dir:{d}", f"symmon: not using the cache directory {d}: {why}; "
               f"compiled code goes to {fallback} for this process only", stacklevel=3)
    return fallback


# --------------------------------------------------------------------------- entries
def _distrust(so: Path) -> str | None:
    """Why the entry ``so`` may not be this user's alone (None when both of its files, if
    present, are regular files of this user that nobody else can write)."""
    for path in (so, checksum_path(so)):
        try:
            st = path.lstat()
        except FileNotFoundError:
            continue
        except OSError as exc:
            return f"{path.name} cannot be examined ({exc.strerror or exc})"
        if not stat.S_ISREG(st.st_mode):
            return f"{path.name} is not a regular file"
        if st.st_uid != os.geteuid():
            return f"{path.name} belongs to another user (uid {st.st_uid})"
        loose = _writable_by_others(st.st_mode)
        if loose:
            return f"{path.name} is {loose}"
    return None


def _verify(so: Path) -> str | None:
    """Why the entry ``so`` must not be loaded (None when its checksum matches)."""
    try:
        recorded = checksum_path(so).read_text().split()
    except OSError:
        return "its checksum file is missing"
    if len(recorded) != 2 or recorded[1] != so.name:
        return "its checksum file is malformed or names another entry"
    try:
        actual = sha256_file(so)
    except OSError as exc:
        return f"it cannot be read ({exc.strerror or exc})"
    return None if actual == recorded[0] else "its sha256 does not match the checksum beside it"


def _remove_entry(so: Path) -> None:
    """Remove the entry ``so``: its checksum first, then the library.  A file already gone
    (another process removed it) is no error.  An entry cut in two by a concurrent install
    can then only be a checksum without its library, which the next build replaces; a
    library without its checksum would be reported as damaged."""
    for p in (checksum_path(so), so):
        try:
            p.unlink()
        except FileNotFoundError:
            pass


#: Libraries loaded by this process (resolved paths): eviction leaves them in place.
_loaded: set[Path] = set()


def _open_entry(so: Path, load: Callable[[Path], T]) -> tuple[T | None, str | None]:
    """Check and load the entry ``so`` under the cache's shared lock, and record its use.

    Returns ``(object, None)`` when loaded, ``(None, None)`` when there is no such entry (or
    another process removed it meanwhile: a build follows, without a warning), and
    ``(None, why)`` when it is damaged.  A loaded entry's modification time is set to now:
    the least recently used entries are evicted first (:func:`evict`), and access times
    are not reliable (``noatime``, ``relatime``).
    """
    if not so.exists():
        return None, None
    with cache_lock(so.parent):
        if not so.exists():
            return None, None
        why = _verify(so)
        if why is None:
            try:
                obj = load(so)
            except (OSError, RuntimeError) as exc:
                why = f"loading it failed ({exc})"
            else:
                _touch(so)
                with _lock:
                    _loaded.add(so)
                return obj, None
        if not so.exists():  # gone meanwhile: only where the file system has no locks
            return None, None
        return None, why


def _touch(so: Path) -> None:
    """Record a use of the entry ``so`` (its modification time); a read-only cache is no error."""
    try:
        os.utime(so)
    except OSError:
        pass


# --------------------------------------------------------------------------- size and eviction
#: The default cap of the cache's size in MiB (``$SYMMON_CACHE_MAX_MB``): a small model's
#: entries take tens of KiB, a run of symmon's own test suite leaves about 40 MB.
CACHE_MAX_MB = 500


def cache_limit() -> int | None:
    """The cap of the cache's size in bytes: ``$SYMMON_CACHE_MAX_MB`` MiB (default
    :data:`CACHE_MAX_MB`), or None for no cap (``SYMMON_CACHE_MAX_MB=0``).

    Raises
    ------
    SymmonError
        If ``SYMMON_CACHE_MAX_MB`` is not a whole number >= 0.
    """
    text = os.environ.get("SYMMON_CACHE_MAX_MB", "").strip()
    if not text:
        return CACHE_MAX_MB << 20
    if not re.fullmatch(r"[0-9]+", text):
        raise SymmonError(f"SYMMON_CACHE_MAX_MB must be a whole number of MiB (0: no limit), got {text!r}")
    mb = int(text)
    return None if mb == 0 else mb << 20


@dataclass(frozen=True)
class CacheEntry:
    """One entry of the cache: a library and its checksum file.

    Attributes
    ----------
    path : Path
        The library (``STEM_KEY.so``).
    size : int
        Bytes of the library and its checksum file.
    last_used : float
        When it was built or last loaded (its modification time, seconds since the epoch).
    """

    path: Path
    size: int
    last_used: float


@dataclass(frozen=True)
class CacheInfo:
    """What :func:`cache_info` reports: the directory, its entries, their size and the cap.

    Attributes
    ----------
    directory : Path
        The cache directory (:func:`cache_dir`).
    entries : tuple of CacheEntry
        The entries, most recently used first.
    size : int
        Bytes of all entries.
    limit : int or None
        The cap in bytes (:func:`cache_limit`), None for none.
    builds : int
        Builds running now (their ``.build-*`` directories, which are not entries).
    """

    directory: Path
    entries: tuple[CacheEntry, ...]
    size: int
    limit: int | None
    builds: int


def cache_entries(d: Path) -> list[CacheEntry]:
    """The entries of the cache directory ``d``, least recently used first.

    A library is an entry when it is a regular file named ``*.so``; its checksum file counts
    in its size.  A file that vanishes while it is listed (another process evicted it) is
    skipped.
    """
    out = []
    try:
        names = [e.name for e in os.scandir(d) if e.name.endswith(".so") and not e.name.startswith(".")]
    except FileNotFoundError:
        return []
    for name in names:
        so = d / name
        try:
            st = so.lstat()
        except FileNotFoundError:
            continue
        if not stat.S_ISREG(st.st_mode):
            continue
        try:
            extra = checksum_path(so).lstat().st_size
        except FileNotFoundError:
            extra = 0
        out.append(CacheEntry(so, st.st_size + extra, st.st_mtime))
    out.sort(key=lambda e: (e.last_used, e.path.name))
    return out


def cache_info() -> CacheInfo:
    """The cache directory, its entries (most recently used first), their size and the cap.

    Raises
    ------
    SymmonError
        If ``SYMMON_CACHE_MAX_MB`` is invalid (:func:`cache_limit`).
    """
    limit = cache_limit()
    d = cache_dir()
    entries = cache_entries(d)
    builds = sum(1 for p in d.glob(".build-*") if p.is_dir())
    return CacheInfo(d, tuple(reversed(entries)), sum(e.size for e in entries), limit, builds)


def evict(d: Path, limit: int | None, keep: Iterable[Path] = ()) -> list[Path]:
    """Remove the least recently used entries of ``d`` until their size is at most ``limit``.

    Never removes an entry of ``keep`` (the one just built) nor a library loaded by this
    process.  Runs under the cache's exclusive lock, without waiting: when another process
    is installing or loading an entry, nothing is evicted now (the next build tries again).
    An entry that another process removes meanwhile counts as removed.

    Parameters
    ----------
    d : Path
        The cache directory.
    limit : int or None
        The cap in bytes; None: no cap, nothing is removed.
    keep : iterable of Path
        Entries (libraries) that must stay.

    Returns
    -------
    list of Path
        The libraries removed, least recently used first.
    """
    if limit is None:
        return []
    kept = set(keep)
    with _lock:
        kept |= _loaded
    removed: list[Path] = []
    with cache_lock(d, exclusive=True, wait=False) as held:
        if not held:
            return removed
        entries = cache_entries(d)
        total = sum(e.size for e in entries)
        for e in entries:
            if total <= limit:
                break
            if e.path in kept:
                continue
            _remove_entry(e.path)
            total -= e.size
            removed.append(e.path)
    if removed:
        log.info("symmon: evicted %d least recently used entries from %s (cap %d MiB)", len(removed), d,
                 limit >> 20)
    return removed


def clear_cache() -> tuple[int, int, int]:
    """Remove every entry of the cache directory, and the directories of builds killed
    long ago (older than :data:`STALE_BUILD_SECONDS`).

    Waits for the cache's exclusive lock, so that no entry is removed while another process
    installs it or checks it before loading it.  Builds running now are left alone: they
    install their entries when they end.  A library another process has loaded stays mapped
    in that process (removing a file does not unmap it).

    Returns
    -------
    tuple of int
        (entries removed, bytes freed, builds running left alone).
    """
    d = cache_dir()
    with cache_lock(d, exclusive=True):
        entries = cache_entries(d)
        for e in entries:
            _remove_entry(e.path)
        for orphan in d.glob("*.so.sha256"):  # a checksum whose library was removed
            if not orphan.with_suffix("").exists():
                orphan.unlink(missing_ok=True)
        _remove_stale_builds(d)
        builds = sum(1 for p in d.glob(".build-*") if p.is_dir())
    return len(entries), sum(e.size for e in entries), builds


# --------------------------------------------------------------------------- compiler runs
#: Build process groups running now, with their temporary directories; the number of
#: threads between "about to start a build" and its registration here; and background
#: threads that have not registered their build yet.
_running: dict[subprocess.Popen, Path] = {}
_starting = 0
_preparing: set[threading.Thread] = set()
_shutting_down = False
#: Set by the handlers of :func:`catch_sigterm`: SIGINT or SIGTERM reached this process.
_interrupted = False


def _kill(p: subprocess.Popen) -> None:
    """Kill the build's whole process group (build process, cc1, as, ...) and reap it."""
    if p.returncode is None:
        try:
            os.killpg(p.pid, signal.SIGKILL)  # start_new_session: the group id is the pid
        except (ProcessLookupError, PermissionError):
            pass
    p.wait()


def _compiling() -> bool:
    with _lock:
        return bool(_running or _preparing) or _starting > 0


def _on_sigterm(signum, frame) -> None:
    """SIGTERM while symmon compiles: exit through Python, so the compiler is killed."""
    global _interrupted
    if _compiling():
        _interrupted = True
        raise SystemExit(128 + signum)
    # No compile runs: behave as if this handler were not here.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGTERM)


def _on_sigint(signum, frame) -> None:
    """Ctrl-C: note it for the exit handler, then raise KeyboardInterrupt as Python does."""
    global _interrupted
    _interrupted = True
    signal.default_int_handler(signum, frame)


def _was_interrupted() -> bool:
    """Whether this process ends because of Ctrl-C or SIGTERM rather than normally.

    The exit status is not visible to an exit handler, hence the flag set by the signal
    handlers: it also counts a KeyboardInterrupt that the program caught before exiting
    (the ``symmon`` command returns 130).  A KeyboardInterrupt that ended the program
    while another SIGINT handler was installed shows in ``sys.last_value``.
    """
    return _interrupted or isinstance(getattr(sys, "last_value", None), KeyboardInterrupt)


def catch_sigterm() -> None:
    """Turn SIGTERM into SystemExit while compiles run, and note SIGINT.

    Installed from the main thread only (Python's rule), and only over the default
    handlers.  When no compile runs the SIGTERM handler restores the default action and
    re-sends the signal, so the process ends as it would have; a compile running in any
    thread makes it raise ``SystemExit(143)``, whose exit handlers kill the build's
    process group.  The SIGINT handler raises KeyboardInterrupt as before, and marks the
    process as interrupted: its background builds are then killed at exit too.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _on_sigterm)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_sigint)


def _run_compiler(cmd: list[str], tmp: Path) -> None:
    """Run the build process ``cmd`` in its own session; kill the group if this thread
    is interrupted.

    Its stdin is /dev/null and its stdout a pipe that it writes to only when it fails,
    so it needs nothing from this process: when this process exits normally, the build
    runs on (a new session has no controlling terminal, hence no SIGHUP).
    """
    global _starting
    with _lock:
        if _shutting_down:
            raise BuildError("the interpreter is exiting")
        _starting += 1
    p = None
    try:
        p = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, errors="replace",
                             start_new_session=True, cwd=tmp)
    finally:
        with _lock:
            _starting -= 1
            if p is not None:
                _running[p] = tmp
                _preparing.discard(threading.current_thread())
    try:
        out, _ = p.communicate()
    except BaseException:  # KeyboardInterrupt, SystemExit from SIGTERM: no orphan cc1
        _kill(p)
        raise
    finally:
        with _lock:
            _running.pop(p, None)
    if p.returncode != 0:
        raise BuildError(out.strip() or f"the build process exited with status {p.returncode}")


#: Seconds the exit handler waits for builds that are being started.
_EXIT_GRACE = 5.0


def _wait_until(done: Callable[[], bool], deadline: float) -> None:
    while time.monotonic() < deadline:
        with _lock:
            if done():
                return
        time.sleep(0.01)


@atexit.register
def _at_exit() -> None:
    """At exit: kill the builds that must not outlive this process, remove their
    temporary directories, then the private cache directory if one was made.

    After a normal exit a build still running (a background build) is left to finish
    and install its library for the next run.  After an interrupt every build is killed,
    as is a build into the private directory, which nobody would read.
    """
    global _shutting_down
    interrupted = _was_interrupted()
    deadline = time.monotonic() + _EXIT_GRACE
    if not interrupted:  # a run that ends at once has started background builds: let them start
        _wait_until(lambda: not _preparing and not _starting, deadline)
    with _lock:
        _shutting_down = True
    _wait_until(lambda: not _starting, deadline)
    with _lock:
        running = list(_running.items())
    for p, tmp in running:
        if interrupted or (_private is not None and tmp.parent == _private):
            _kill(p)
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            log.info("symmon: a C build (%s) continues after exit, to fill the cache", tmp)
    if _private is not None:
        shutil.rmtree(_private, ignore_errors=True)


#: A build directory this old was left by a process killed with SIGKILL: remove it.
STALE_BUILD_SECONDS = 24 * 3600


def _remove_stale_builds(d: Path) -> None:
    now = time.time()
    for old in d.glob(".build-*"):
        try:
            if now - old.stat().st_mtime > STALE_BUILD_SECONDS:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass


#: CPU seconds a compiler may take (``$SYMMON_BUILD_SECONDS``): the largest code the policy
#: compiles at -O2 (300 KB) takes about 15 s; past the limit the build fails and the VM stays.
BUILD_SECONDS = 600
#: Memory (MiB) a compiler may take (``$SYMMON_BUILD_MEMORY_MB``): at most half the machine's
#: memory and 8 GiB, so that a compiler is refused memory before the system's
#: out-of-memory killer takes it or anything else.
BUILD_MEMORY_MB = 8192


def build_limits() -> tuple[int, int]:
    """(CPU seconds, bytes of address space) of each compiler run, from
    ``$SYMMON_BUILD_SECONDS`` and ``$SYMMON_BUILD_MEMORY_MB`` (defaults :data:`BUILD_SECONDS`,
    and :data:`BUILD_MEMORY_MB` or half the physical memory, whichever is less).

    Raises
    ------
    SymmonError
        If either variable is not a positive integer.
    """
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") >> 20
    except (ValueError, OSError, AttributeError):
        physical = 2 * BUILD_MEMORY_MB
    values = []
    for var, default in (("SYMMON_BUILD_SECONDS", BUILD_SECONDS),
                         ("SYMMON_BUILD_MEMORY_MB", min(BUILD_MEMORY_MB, physical // 2))):
        text = os.environ.get(var, "").strip()
        if not text:
            values.append(default)
            continue
        if not re.fullmatch(r"[0-9]+", text) or int(text) <= 0:
            raise SymmonError(f"{var} must be a positive whole number, got {text!r}")
        values.append(int(text))
    return values[0], values[1] << 20


def _build(code: str, so: Path, opt: str) -> None:
    """Compile ``code`` into the cache entry ``so`` and its checksum, atomically.

    A build process (:mod:`symmon.compile.ccbuild`) runs the compiler and installs the entry
    itself, so that a background build can finish after this process has exited.
    """
    cc = _compiler()
    assert cc is not None
    if not sys.executable:
        raise BuildError("no Python executable (sys.executable is empty) to run the build")
    _remove_stale_builds(so.parent)
    tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=so.parent))
    try:
        (tmp / "f.c").write_text(code)
        seconds, memory = build_limits()
        _run_compiler([sys.executable, "-I", ccbuild.__file__, str(tmp), str(so), str(seconds), str(memory),
                       *cc, opt, *CFLAGS, *native_target(cc)[0], "f.c", "-o", "f.so", "-lm"], tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the build process removed it, unless killed


def _entry(code: str, stem: str, opt: str, warn: Callable[[str], None]) -> Path:
    """The path of ``code`` compiled with ``opt`` (not necessarily present): in the cache,
    or, when the cache's entry is not trusted (:func:`_distrust`), in the private
    directory, after a warning through ``warn`` (once per entry and process)."""
    cc = _compiler()
    assert cc is not None
    key = hashlib.sha256("\0".join(
        [code, opt, *CFLAGS, ca.__version__, shlex.join(cc), _compiler_identity(cc), native_target(cc)[1]]).encode()
    ).hexdigest()[:24]
    so = cache_dir() / f"{stem}_{key}.so"
    why = _distrust(so)
    if why is None:
        return so
    private = _private_dir() / so.name
    with _lock:
        first = f"entry:{so}" not in _warned
        _warned.add(f"entry:{so}")
    if first:
        warn(f"symmon: not loading the cached library {so}: {why}; building it in {private.parent} "
             f"for this process only (remove the entry to have it cached again)")
    return private


T = TypeVar("T")


def _load_or_build(code: str, stem: str, opt: str, load: Callable[[Path], T], warn: Callable[[str], None],
                   limit: int | None = None) -> T:
    """Load the verified cache entry of ``code``; build it when missing or bad.

    A bad entry (checksum or load failure) is reported through ``warn``, removed and
    rebuilt once.  After a build, the least recently used entries beyond ``limit`` bytes
    are evicted (:func:`evict`; None: no cap).  Raises BuildError, or OSError/RuntimeError
    from ``load``.
    """
    so = _entry(code, stem, opt, warn)
    obj, why = _open_entry(so, load)
    if obj is not None:
        return obj
    if why is not None:
        warn(f"symmon: the cached library {so} is damaged ({why}); rebuilding it")
        _remove_entry(so)
    _build(code, so, opt)
    with cache_lock(so.parent):  # no eviction between the install and the load
        obj = load(so)
    with _lock:
        _loaded.add(so)
    try:
        evict(so.parent, limit, keep=[so])
    except OSError as exc:  # a full cache is no reason to fail a build
        log.warning("symmon: could not evict old entries from %s: %s", so.parent, exc)
    return obj


def build_shared_library(code: str, stem: str, stacklevel: int = 2) -> Path | None:
    """Compile C source to a verified shared library in the cache, now.

    Returns its path, or None after a warning when no compiler is available or the
    build fails (``stacklevel`` as in ``warnings.warn``, counted from this function).

    Raises
    ------
    SymmonError
        If ``SYMMON_COMPILE`` or ``SYMMON_CACHE_MAX_MB`` is invalid.
    """
    if not has_compiler():
        warn_no_compiler(stacklevel=stacklevel + 1)
        return None
    limit = cache_limit()
    catch_sigterm()
    try:
        return _load_or_build(code, stem, OPT_SYNC, lambda p: p,
                              lambda msg: warnings.warn(msg, RuntimeWarning, stacklevel=stacklevel + 2), limit)
    except BuildError as exc:
        warnings.warn(f"symmon: compiling {stem} failed, using the CasADi VM:\n{exc}", RuntimeWarning,
                      stacklevel=stacklevel)
        return None


# --------------------------------------------------------------------------- a library in use
class NativeLibrary(Generic[T]):
    """The compiled form of one generated C source, as the policy provides it.

    :meth:`get` returns the loaded object (``load(path)``), or None while the caller
    must use CasADi's virtual machine: no compiler, ``never`` policy, a failed build, or
    a background build still running.  A background build swaps the object in under a
    lock when it is ready; each :meth:`get` sees either the old or the new state.

    Parameters
    ----------
    code : str
        Complete C source.
    stem : str
        A C identifier naming the library (the file name starts with it).
    load : callable
        Path of a verified library → the object callers use (e.g. a ctypes function).
    stacklevel : int
        For the warnings of a build the caller waits for, counted from the constructor.
    background : bool
        Build in the background whatever the size of the code, under the ``auto`` policy:
        for a caller with a fallback of its own, which should never wait for the compiler.
    """

    def __init__(self, code: str, stem: str, load: Callable[[Path], T], stacklevel: int = 2,
                 background: bool = False) -> None:
        self.stem = stem
        self.code_bytes = len(code.encode())
        self._obj: T | None = None
        self._state = "vm"
        self._lock = threading.Lock()
        self._done = threading.Event()  # set when no build is pending
        mode = compile_mode()
        self._limit = cache_limit()
        if mode == "never" or _compiler() is None:
            log.info("symmon: %s: evaluating on CasADi's VM (SYMMON_COMPILE=%s, compiler %s)",
                     stem, mode, "found" if _compiler() else "not found")
            self._done.set()
            return
        # A verified library of any optimisation level costs nothing to load: take the best.
        for opt in (OPT_SYNC, OPT_HUGE):
            so = _entry(code, stem, opt,
                        lambda msg: warnings.warn(msg, RuntimeWarning, stacklevel=stacklevel + 2))
            obj, _ = _open_entry(so, load)
            if obj is not None:  # a damaged -O3 entry is rebuilt below, with a warning
                self._obj, self._state = obj, "compiled"
                log.info("symmon: %s: compiled C (%s) loaded from the cache", stem, opt)
                self._done.set()
                return
        background = mode == "background" or (mode == "auto" and (background or self.code_bytes > BACKGROUND_BYTES))
        if not background:
            self._sync(code, OPT_SYNC, load, stacklevel + 1)
            self._done.set()
            return
        opt = background_level(code)
        self._state = "building"
        catch_sigterm()
        log.info("symmon: %s: %d bytes of C; evaluating on CasADi's VM while it compiles (%s) "
                 "in the background", stem, self.code_bytes, opt)
        thread = threading.Thread(target=self._background, args=(code, opt, load), daemon=True,
                                  name=f"symmon-cc-{stem}")
        with _lock:
            _preparing.add(thread)
        thread.start()

    def _sync(self, code: str, opt: str, load: Callable[[Path], T], stacklevel: int) -> None:
        catch_sigterm()
        t0 = time.perf_counter()
        try:
            obj = _load_or_build(code, self.stem, opt, load,
                                 lambda msg: warnings.warn(msg, RuntimeWarning, stacklevel=stacklevel + 2),
                                 self._limit)
        except (BuildError, OSError, RuntimeError) as exc:
            warnings.warn(f"symmon: compiling {self.stem} failed, using the CasADi VM:\n{exc}",
                          RuntimeWarning, stacklevel=stacklevel + 1)
            return
        self._obj, self._state = obj, "compiled"
        log.info("symmon: %s: compiled C ready in %.2f s (%s)", self.stem, time.perf_counter() - t0, opt)

    def _background(self, code: str, opt: str, load: Callable[[Path], T]) -> None:
        t0 = time.perf_counter()
        try:
            obj = _load_or_build(code, self.stem, opt, load, log.warning, self._limit)
        except BaseException as exc:  # a thread must not die with a traceback on stderr
            with self._lock:
                self._state = "vm"
            if not _shutting_down:
                log.warning("symmon: background compile of %s failed; staying on CasADi's VM: %s",
                            self.stem, exc)
        else:
            with self._lock:
                self._obj, self._state = obj, "compiled"
            log.info("symmon: %s: background C build done in %.1f s; now evaluating compiled code",
                     self.stem, time.perf_counter() - t0)
        finally:
            with _lock:  # when no build process was needed (another process built the entry)
                _preparing.discard(threading.current_thread())
            self._done.set()

    def get(self) -> T | None:
        """The loaded object, or None to use CasADi's virtual machine."""
        with self._lock:
            return self._obj

    @property
    def evaluator(self) -> str:
        """``"compiled"``, ``"vm"`` or ``"vm (C build running)"``."""
        with self._lock:
            return {"compiled": "compiled", "vm": "vm", "building": "vm (C build running)"}[self._state]

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for a background build to end; True when compiled code is in use."""
        self._done.wait(timeout)
        return self.get() is not None
