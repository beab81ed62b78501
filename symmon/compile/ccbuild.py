"""The build process of one cache entry: run the compiler, install the library.

:mod:`symmon.compile.ccache` runs this file as a script, with the same Python, in a new session
(process group) and in the entry's temporary build directory::

    python -I ccbuild.py BUILD_DIR TARGET CPU_SECONDS MEMORY_BYTES CC ARG...

It runs ``CC ARG...`` in ``BUILD_DIR`` (which holds ``f.c``; the command writes
``f.so``) under resource limits that the compiler's own children (``cc1``, ``as``)
inherit: at most ``CPU_SECONDS`` of CPU time (SIGXCPU ends a process beyond it) and
``MEMORY_BYTES`` of address space (an allocation beyond it fails, and the compiler stops
with "out of memory"), so that a huge source ends in a failed build rather than a
compiler running for an hour or taken by the out-of-memory killer.  Where this process's
own limits are lower (``ulimit -v`` below 8 GiB), the compiler gets those
(:func:`effective_limits`).  It then installs ``f.so`` as ``TARGET`` with its checksum (:func:`install`), and
removes ``BUILD_DIR`` whether the build succeeded or not.  Because the whole build
happens in this process, a background build can outlive the Python that started it:
after a normal exit it still fills the cache for the next run, while an interrupt kills
its process group (compiler included).  On failure it writes the reason to its stdout,
for the caller (if it is still there).

The script imports only the standard library (it starts in milliseconds), and ``-I``
keeps symmon's own directory off ``sys.path`` (``symmon/io.py`` would shadow ``io``).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
try:
    import fcntl
except ImportError:  # not on Windows: no locks there
    fcntl = None  # type: ignore[assignment]
try:
    import resource
except ImportError:  # not on Windows: no limits there
    resource = None  # type: ignore[assignment]
import shlex
import shutil
import stat
import subprocess
import sys
from pathlib import Path
from typing import Iterator

#: Characters of the compiler's output kept in the failure message.
OUTPUT_TAIL = 2000


def sha256_file(path: Path) -> str:
    """The sha256 hex digest of the file ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def checksum_path(so: Path) -> Path:
    """The checksum file beside the library ``so`` (``sha256sum`` format)."""
    return so.with_name(so.name + ".sha256")


@contextlib.contextmanager
def cache_lock(directory: Path, exclusive: bool = False, wait: bool = True) -> Iterator[bool]:
    """Hold the lock of the cache ``directory`` (``flock`` on the directory itself, no file).

    Shared (``exclusive=False``) while an entry is installed, or checked and loaded; exclusive
    while entries are removed (eviction, ``symmon cache clear``), so that no entry is removed
    between its checksum and its library, nor between a reader's check and its load.

    Parameters
    ----------
    directory : Path
        The cache directory.
    exclusive : bool
        An exclusive lock instead of a shared one.
    wait : bool
        Wait for the lock; with False, yield False at once when another process holds it.

    Yields
    ------
    bool
        True while the lock is held (or the system has none: no ``fcntl``, or a file system
        that refuses ``flock``, where the readers' own checks are all that is left); False
        only when ``wait`` is False and the lock is taken.
    """
    fd = -1
    held = True
    if fcntl is not None:
        try:
            fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            fd = -1
    try:
        if fd >= 0:
            try:
                fcntl.flock(fd, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | (0 if wait else fcntl.LOCK_NB))
            except BlockingIOError:
                held = False
            except OSError:
                pass  # no locks on this file system: go on unlocked
        yield held
    finally:
        if fd >= 0:
            os.close(fd)  # releases the lock


def install(built: Path, so: Path) -> None:
    """Move the library ``built`` to the cache entry ``so``, with its checksum, atomically.

    The checksum is written beside ``built`` (same file system as the entry) and moved
    into place first: a reader that sees the new library sees its checksum.  Neither is
    left group- or world-writable (a umask of 002 would make them so).  Two
    processes installing the same entry each move complete files, the last one wins.
    Both moves happen under the cache's shared lock (:func:`cache_lock`), so that an
    eviction cannot remove the new checksum between them.
    """
    staged = checksum_path(built)
    staged.write_text(f"{sha256_file(built)}  {so.name}\n")
    for path in (built, staged):  # whatever the umask: an entry others can write is not loaded
        os.chmod(path, stat.S_IMODE(os.stat(path).st_mode) & ~0o022)
    with cache_lock(so.parent):
        os.replace(staged, checksum_path(so))
        os.replace(built, so)


def _report(message: str) -> None:
    """Write ``message`` to stdout unbuffered; nobody may read it any more (parent gone)."""
    try:
        os.write(sys.stdout.fileno(), message.encode(errors="replace"))
    except (OSError, ValueError):
        pass


def effective_limits(cpu_seconds: int, memory_bytes: int) -> tuple[int, int]:
    """The limits the compiler gets: the build's, or this process's own where they are lower
    (``ulimit -t``, ``ulimit -v`` below the build's 8 GiB): a process may lower its limits
    but not raise them past the hard ones, so asking for more fails in the child before the
    compiler starts, and every build would fail.  Unchanged where there are no limits."""
    if resource is None:
        return cpu_seconds, memory_bytes

    def lower(which: int, wanted: int) -> int:
        soft, hard = resource.getrlimit(which)
        for own in (soft, hard):
            if own != resource.RLIM_INFINITY and own >= 0:
                wanted = min(wanted, own)
        return wanted

    # SIGKILL comes 5 s after the soft CPU limit: leave room for it under a hard one.
    cpu_hard = resource.getrlimit(resource.RLIMIT_CPU)[1]
    cpu = lower(resource.RLIMIT_CPU, cpu_seconds)
    if cpu_hard != resource.RLIM_INFINITY and cpu_hard >= 0:
        cpu = max(1, min(cpu, cpu_hard - 5))
    return cpu, lower(resource.RLIMIT_AS, memory_bytes)


def limiter(cpu_seconds: int, memory_bytes: int):
    """The ``preexec_fn`` that sets the limits of the compiler (None where there are none);
    give it :func:`effective_limits`."""
    if resource is None:
        return None
    cpu_hard = resource.getrlimit(resource.RLIMIT_CPU)[1]
    cpu_kill = cpu_seconds + 5 if cpu_hard == resource.RLIM_INFINITY else min(cpu_seconds + 5, cpu_hard)

    def limit() -> None:
        # SIGXCPU at the soft limit; SIGKILL at the hard one, should SIGXCPU be ignored.
        resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_kill))
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    return limit


def main(argv: list[str]) -> int:
    """Build and install; return the exit status (0 when the entry is installed)."""
    build_dir, target = Path(argv[0]), Path(argv[1])
    cpu_seconds, memory_bytes, cmd = int(argv[2]), int(argv[3]), argv[4:]
    cpu_seconds, memory_bytes = effective_limits(cpu_seconds, memory_bytes)
    try:
        # The compiler writes into a pipe that this process reads to its end: it never
        # gets SIGPIPE, even when the process that started this build has exited.
        res = subprocess.run(cmd, cwd=build_dir, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, errors="replace",
                             preexec_fn=limiter(cpu_seconds, memory_bytes))
        if res.returncode != 0:
            _report(f"{shlex.join(cmd[:1])} exited with status {res.returncode}:\n{res.stdout[-OUTPUT_TAIL:].rstrip()}\n"
                    f"(the build's limits: {cpu_seconds} s of CPU, {memory_bytes >> 20} MiB of memory; "
                    "SYMMON_BUILD_SECONDS and SYMMON_BUILD_MEMORY_MB set them)")
            return 1
        install(build_dir / "f.so", target)
        return 0
    except (OSError, subprocess.SubprocessError, ValueError) as exc:  # ValueError: setrlimit in the child
        _report(f"the build of {target.name} failed: {type(exc).__name__}: {exc} (the build's limits: "
                f"{cpu_seconds} s of CPU, {memory_bytes >> 20} MiB of memory)")
        return 1
    finally:
        shutil.rmtree(build_dir, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
