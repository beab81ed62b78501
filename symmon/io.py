"""Atomic output files: write to a temporary file beside the target, then rename.

An existing file is either left untouched or replaced whole; it is never half-overwritten.
Only regular files are written: a symbolic link is followed to its target (the link
stays a link), and a directory, a device, a FIFO or a socket is refused with an
:class:`OutputPathError` before anything is written. The replaced file keeps its
permission bits. :func:`check_output_file`, :func:`check_output_dir` and
:func:`check_output_set` run the same checks without writing, so that a command can refuse
a bad path before its heavy work, and a set of files written together before any of them.
"""

from __future__ import annotations

import csv
import io
import os
import stat
import tempfile
from pathlib import Path
from typing import Any, Iterable, Sequence

from .errors import OutputPathError

__all__ = [
    "OutputPathError",
    "check_output_file",
    "check_output_dir",
    "check_output_set",
    "atomic_write_bytes",
    "atomic_write_text",
    "write_csv",
    "save_figure",
    "plot_format",
    "PLOT_FORMATS",
]

#: Figure formats :func:`save_figure` writes: those matplotlib writes with Pillow alone
#: (pgf needs LaTeX; avif and webp depend on how Pillow was built).
PLOT_FORMATS = ("png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff")


def _kind(mode: int) -> str:
    """What a file is, in words (for a path that is not the kind wanted)."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISREG, "a file"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_output_file(path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """The file that writing ``path`` replaces, after checking that it may be written.

    Parameters
    ----------
    path : str or os.PathLike
        The output file; a symbolic link is followed to its final target.
    inputs : iterable of paths, optional
        The files the command reads: the output must be none of them.

    Returns
    -------
    pathlib.Path
        The real path of the target (symbolic links resolved).

    Raises
    ------
    OutputPathError
        If ``path`` is empty, the target exists and is not a regular file, is read-only
        (no write permission bit: the atomic rename would replace it anyway), or is one of
        ``inputs``.
    FileNotFoundError
        If the target's directory does not exist (or is not a directory).
    PermissionError
        If the target's directory is not writable.
    """
    if not os.fspath(path):
        raise OutputPathError("output file name is empty")
    real = Path(os.path.realpath(path))
    try:
        mode = real.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None
    shown = f"{path} (-> {real})" if str(real) != os.path.abspath(path) else str(path)
    if mode is not None and not stat.S_ISREG(mode):
        raise OutputPathError(f"output file {shown} is {_kind(mode)}; only regular files are written")
    for source in inputs:
        if source is not None and os.path.realpath(source) == str(real):
            raise OutputPathError(f"output file {shown} is the input file {source}: writing it would lose the input")
    if mode is not None and not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        raise OutputPathError(f"output file {shown} is read-only; make it writable or choose another name")
    if not real.parent.is_dir():
        raise FileNotFoundError(f"output directory does not exist: {Path(path).parent}")
    if not os.access(real.parent, os.W_OK | os.X_OK):
        raise PermissionError(f"output directory is not writable: {real.parent}")
    return real


def check_output_dir(path: str | os.PathLike) -> Path:
    """Check that ``path`` is a directory, or can be created as one; return its real path.

    Raises
    ------
    OutputPathError
        If ``path`` is empty, or it exists and is not a directory.
    FileNotFoundError
        If an existing ancestor of ``path`` is not a directory (so it cannot be created).
    """
    if not os.fspath(path):
        raise OutputPathError("output directory name is empty")
    real = Path(os.path.realpath(path))
    if real.exists():
        if not real.is_dir():
            raise OutputPathError(f"output directory {path} is {_kind(real.stat().st_mode)}, not a directory")
        return real
    ancestor = real.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise FileNotFoundError(f"cannot create the output directory {path}: {ancestor} is not a directory")
    return real


def check_output_set(directory: str | os.PathLike, names: Iterable[str]) -> Path:
    """Check a directory (:func:`check_output_dir`) and each file ``names`` in it
    (:func:`check_output_file`), for files written together: one that cannot be written
    refuses the set before any of them is (no half-written set of files).

    Returns
    -------
    pathlib.Path
        The real path of the directory (which may not exist yet).
    """
    real = check_output_dir(directory)
    if real.is_dir():
        for name in names:
            check_output_file(real / name)
    return real


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and return the path.

    The data go to a temporary file in the directory of the real target, which then
    replaces the target in one rename; a symbolic link ``path`` keeps pointing to it.

    Raises
    ------
    OutputPathError
        If ``path`` is empty or names a directory, device, FIFO or socket.
    OSError
        If the directory does not exist or is not writable; the target is untouched.
    """
    real = check_output_file(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{real.name}.", suffix=".tmp", dir=real.parent)
    try:
        # mkstemp creates 0600; give the file the mode of the target, or the umask default.
        try:
            mode = real.stat().st_mode & 0o777  # rwx bits only: never copy setuid/setgid
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, real)
    except BaseException:
        # Interrupted or failed: remove the temporary file, keep the old target.
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def write_csv(path: str | os.PathLike, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> Path:
    """Write a CSV file atomically, with full float precision (``repr``); None is an empty field."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([repr(float(x)) if isinstance(x, float) else x for x in row])
    return atomic_write_text(path, buf.getvalue())


def plot_format(path: str | os.PathLike) -> str:
    """The figure format of ``path`` from its suffix (PNG without one).

    Raises
    ------
    OutputPathError
        If the suffix is not one of :data:`PLOT_FORMATS`.
    """
    suffix = Path(path).suffix.lstrip(".").lower()
    fmt = suffix or "png"
    if fmt not in PLOT_FORMATS:
        raise OutputPathError(f"cannot write a figure as {suffix!r} ({path}); use one of: {', '.join(PLOT_FORMATS)}")
    return fmt


def save_figure(fig: Any, path: str | os.PathLike, **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically (format from the suffix, PNG by default)."""
    fmt = plot_format(path)
    check_output_file(path)  # refuse a bad target before drawing
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, **kwargs)
    return atomic_write_bytes(path, buf.getvalue())
