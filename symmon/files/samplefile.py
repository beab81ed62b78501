"""Particle files: a weighted sample of a model's inputs as CSV (``--samples-file``).

One row a particle, under a header that names the columns::

    x,y,weight
    1.02,9.7,0.013
    0.98,10.4,0.011

The header holds each of the model's input names once, in any order, and optionally a
column ``weight`` (non-negative, any scale; equal weights without it). Nothing else is
accepted: an unknown or missing column, a row of another length, or a cell that is not a
decimal number is a :class:`~symmon.errors.ModelFileError` naming the file, line and
column. Cells are read by :func:`float` on the stripped text after a whitelist check (no
expression, no ``eval``); ``nan`` and ``inf`` are refused. The file is read like a model
file (regular, UTF-8), of at most :data:`MAX_SAMPLES_BYTES` bytes, but line by line, the
numbers going in blocks of :data:`BLOCK_ROWS` rows straight into float arrays: the memory
it takes is about twice that of the particles as doubles (the blocks and the
:class:`~symmon.core.mixture.Empirical`'s copy), not a multiple of the text (a whole-text
read into lists of Python floats took about 70 times the file's size).
"""

from __future__ import annotations

import csv
import itertools
import math
import os
import re
from pathlib import Path
from typing import BinaryIO, Callable, Iterator

import numpy as np

from ..core.mixture import Empirical
from ..core.model import Model
from ..errors import ModelFileError, SymmonError
from .modelfile import _open_checked

__all__ = ["load_samples_file", "MAX_SAMPLES_BYTES", "MAX_LINE_BYTES", "BLOCK_ROWS", "WEIGHT_COLUMN"]

#: Largest particle file read, in bytes (about 10⁷ particles of two inputs).
MAX_SAMPLES_BYTES = 500_000_000
#: The name of the optional weight column.
WEIGHT_COLUMN = "weight"
#: A decimal number: digits with an optional sign, point and exponent (what float() reads
#: of it is then exact to rounding); nothing else reaches float().
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
#: Longest line of a particle file, in bytes (a row of thousands of inputs).
MAX_LINE_BYTES = 1 << 20
#: Rows parsed into one float block before the next is started.
BLOCK_ROWS = 1 << 14


def load_samples_file(path: str | os.PathLike, model: Model) -> Empirical:
    """Read a particle file (CSV, module notes) into an :class:`~symmon.core.mixture.Empirical`
    over ``model``'s inputs, its columns in the order of ``model.inputs``.

    Raises
    ------
    ModelFileError
        For a file that cannot be read, a bad header, a short or long row, a cell that is
        not a decimal number, a non-finite value, or weights that
        :class:`~symmon.core.mixture.Empirical` refuses (negative, all zero).

    Examples
    --------
    >>> import tempfile, sympy as sp
    >>> x, y = sp.symbols("x y")
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     p = Path(tmp) / "cloud.csv"
    ...     _ = p.write_text("y,x,weight\\n1,2,1\\n3,4,3\\n", encoding="utf-8")
    ...     e = load_samples_file(p, Model([x, y], [x + y]))
    >>> e.samples.tolist(), e.weights.tolist()
    ([[2.0, 1.0], [4.0, 3.0]], [0.25, 0.75])
    """
    path = Path(path)

    def fail(line: int, message: str) -> ModelFileError:
        where = f"{path}: line {line}: " if line else f"{path}: "
        return ModelFileError(where + message, source=str(path), line=line or None, reason=message)

    with _open_checked(path, MAX_SAMPLES_BYTES, "samples file") as fh:
        rows = csv.reader(_lines(fh, fail))
        try:
            header = next(rows)
        except StopIteration:
            raise fail(0, "the samples file is empty: it needs a header naming the columns") from None
        names = [h.strip() for h in header]
        inputs = [s.name for s in model.inputs]
        allowed = set(inputs) | {WEIGHT_COLUMN}
        unknown = [n for n in names if n not in allowed]
        if unknown:
            raise fail(1, f"unknown column {unknown[0]!r}: the header names the inputs {inputs} "
                       f"and optionally {WEIGHT_COLUMN!r}")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise fail(1, f"column {dup[0]!r} appears more than once")
        missing = [n for n in inputs if n not in names]
        if missing:
            raise fail(1, f"no column for the input {missing[0]!r} (the header is {names})")
        # The columns (every one an input or the weight: the header was checked) in the
        # order of the model's inputs, then the weight: each block of
        # rows goes straight into a float array (8 bytes a cell), never a list of floats.
        order = [names.index(n) for n in inputs] + ([names.index(WEIGHT_COLUMN)] if WEIGHT_COLUMN in names else [])
        blocks: list[np.ndarray] = []
        block = np.empty((BLOCK_ROWS, len(order)))
        k = 0
        for row in rows:
            line = rows.line_num
            if not row or all(not c.strip() for c in row):
                continue  # a blank line (e.g. at the end)
            if len(row) != len(names):
                raise fail(line, f"{len(row)} cells, but the header has {len(names)} columns")
            for j, col in enumerate(order):
                c = row[col].strip()
                if not re.fullmatch(_NUMBER, c):
                    raise fail(line, f"column {names[col]!r}: {c[:40]!r} is not a decimal number")
                x = float(c)
                if not math.isfinite(x):
                    raise fail(line, f"column {names[col]!r}: {c[:40]!r} overflows a float")
                block[k, j] = x
            k += 1
            if k == BLOCK_ROWS:
                blocks.append(block)
                block, k = np.empty((BLOCK_ROWS, len(order))), 0
    blocks.append(block[:k])
    if sum(b.shape[0] for b in blocks) == 0:
        raise fail(0, "the samples file has a header but no particles")
    A = blocks[0] if len(blocks) == 1 else np.concatenate(blocks)
    del blocks, block
    n_u = len(inputs)
    try:
        return Empirical(A[:, :n_u], None if A.shape[1] == n_u else A[:, n_u])
    except SymmonError as exc:
        raise fail(0, f"{type(exc).__name__}: {exc}") from None


def _lines(fh: BinaryIO, fail: Callable[[int, str], ModelFileError]) -> Iterator[str]:
    """The lines of the binary file ``fh`` decoded as UTF-8, one at a time, each at most
    :data:`MAX_LINE_BYTES` long, and in all at most :data:`MAX_SAMPLES_BYTES` (the file
    may grow after its size was checked)."""
    total = 0
    for number in itertools.count(1):
        try:
            raw = fh.readline(MAX_LINE_BYTES + 1)
        except OSError as exc:
            raise fail(0, f"samples file cannot be read: {exc.strerror or exc}") from None
        if not raw:
            return
        total += len(raw)
        if total > MAX_SAMPLES_BYTES:
            raise fail(0, f"samples file larger than {MAX_SAMPLES_BYTES} bytes")
        if len(raw) > MAX_LINE_BYTES:
            raise fail(number, f"the line is longer than {MAX_LINE_BYTES} bytes")
        try:
            yield raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise fail(number, f"samples file is not UTF-8 text (byte {exc.start} of the line)") from None
