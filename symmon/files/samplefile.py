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
file (regular, UTF-8), of at most :data:`MAX_SAMPLES_BYTES` bytes.
"""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path

import numpy as np

from ..core.mixture import Empirical
from ..core.model import Model
from ..errors import ModelFileError, SymmonError
from .modelfile import _read

__all__ = ["load_samples_file", "MAX_SAMPLES_BYTES", "WEIGHT_COLUMN"]

#: Largest particle file read, in bytes (about 10⁷ particles of two inputs).
MAX_SAMPLES_BYTES = 500_000_000
#: The name of the optional weight column.
WEIGHT_COLUMN = "weight"
#: A decimal number: digits with an optional sign, point and exponent (what float() reads
#: of it is then exact to rounding); nothing else reaches float().
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"


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
    text = _read(path, MAX_SAMPLES_BYTES, "samples file")

    def fail(line: int, message: str) -> ModelFileError:
        where = f"{path}: line {line}: " if line else f"{path}: "
        return ModelFileError(where + message, source=str(path), line=line or None, reason=message)

    rows = csv.reader(io.StringIO(text))
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
    order = [names.index(n) for n in inputs]
    w_col = names.index(WEIGHT_COLUMN) if WEIGHT_COLUMN in names else None
    values: list[list[float]] = []
    for row in rows:
        line = rows.line_num
        if not row or all(not c.strip() for c in row):
            continue  # a blank line (e.g. at the end)
        if len(row) != len(names):
            raise fail(line, f"{len(row)} cells, but the header has {len(names)} columns")
        parsed = []
        for j, cell in enumerate(row):
            c = cell.strip()
            if not re.fullmatch(_NUMBER, c):
                raise fail(line, f"column {names[j]!r}: {c[:40]!r} is not a decimal number")
            x = float(c)
            if not np.isfinite(x):
                raise fail(line, f"column {names[j]!r}: {c[:40]!r} overflows a float")
            parsed.append(x)
        values.append(parsed)
    if not values:
        raise fail(0, "the samples file has a header but no particles")
    A = np.array(values)
    try:
        return Empirical(A[:, order], None if w_col is None else A[:, w_col])
    except SymmonError as exc:
        raise fail(0, f"{type(exc).__name__}: {exc}") from None
