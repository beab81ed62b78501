"""Safe model files: the TOML schema of a model and its distributions.

A model file declares a :class:`~symmon.core.model.Model`, the Gaussian of its inputs and,
when the model has noise symbols, the Gaussian of the noise::

    # Straka & Havlik (2024), eq. (14) and (16)
    name = "polar"
    inputs = ["x", "y"]                  # identifiers, in the order of u
    outputs = ["sqrt(x**2 + y**2)", "atan2(y, x)"]
    angles = [1]                         # optional: output indices or input names

    [params]                             # optional: named constants for the expressions
    alpha = 0.17

    [u]
    mean = [1, 10]
    cov = [["alpha", 0], [0, "100*alpha"]]   # or std = [...]; a scalar cov for 1-D

    [units]                              # optional: pint unit strings (not checked here)
    x = "km"
    y = "km"
    "outputs[0]" = "km"
    "outputs[1]" = "rad"

A Gaussian mixture (a Gaussian-sum prior, glint noise) is written in the same tables with
``weights``, ``means`` and one of ``covs`` or ``stds``, one entry per component::

    [u]
    weights = [0.5, 0.3, 0.2]            # >= 0, summing to 1
    means = [[1, 10], [2, 20], [4, 40]]
    covs = [[[1, 0], [0, 1]], [[4, 0], [0, 4]], [[16, 0], [0, 16]]]   # or stds = [[1, 1], ...]

Top-level keys: ``name``, ``inputs`` and ``outputs`` and the ``[u]`` table are required;
``noise`` (names of the noise symbols v), ``angles``, ``[params]``, ``[v]`` and ``[units]``
are optional, except that ``[v]`` is required exactly when ``noise`` is given. The tables
``[u]`` and ``[v]`` take ``mean`` and one of ``cov`` (a matrix, or a scalar for one
dimension) or ``std`` (a vector of standard deviations), or for a mixture ``weights``,
``means`` and one of ``covs`` or ``stds`` (at most :data:`MAX_COMPONENTS` components). Their numbers may be TOML numbers
or strings holding a constant expression (``"100*sqrt(2)"``, ``"pi/4"``, ``"100*alpha"``).
``[units]`` keys are input or noise names, or ``"outputs[i]"`` for the i-th output.

Expressions (the outputs, and constant strings in the tables) are read by
:func:`symmon.files.expressions.parse_expression`, a whitelist parser described there; text
from a file is never executed or handed to sympy's string parser.

Hostile files are bounded too: only a regular file is read (a FIFO, device or directory
is refused before it is opened, so reading never blocks), of at most
:data:`MAX_FILE_BYTES` bytes; names have at most :data:`MAX_NAME_LENGTH` characters (the
model's name printable ones); a model has at most :data:`MAX_SYMBOLS` inputs and noise
symbols and :data:`MAX_OUTPUTS` outputs; TOML integers past the float range and arrays
nested too deeply are refused. The time a C compiler takes on a large model is not
bounded here but where models are turned into C code.
"""

# Security note: this module does not use eval, exec, compile, sympify or parse_expr;
# file text reaches sympy only through expressions.parse_expression.

from __future__ import annotations

import json
import keyword
import math
import os
import re
import stat
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Callable, Mapping, Sequence

import numpy as np
import sympy as sp
from sympy.printing.str import StrPrinter

from ..errors import ModelError, SymmonError
from .expressions import (
    CONSTANTS,
    FUNCTIONS,
    MAX_DEPTH,
    MAX_EXPONENT,
    MAX_EXPRESSION_LENGTH,
    MAX_INTEGER_LITERAL,
    MAX_RESULT_DIGITS,
    ModelFileError,
    _char_position,
    _RESERVED,
    parse_expression,
)
from . import expressions as _expressions
from ..core.gaussian import Gaussian
from ..core.mixture import GaussianMixture
from ..core.model import Model

try:
    import tomllib as _toml
except ModuleNotFoundError:  # Python 3.10: the same parser ships as the tomli package
    try:
        import tomli as _toml  # type: ignore[no-redef]
    except ModuleNotFoundError:
        _toml = None  # type: ignore[assignment]

# The expression language's names stay importable from here, where they were first.
__all__ = [
    "ModelSpec",
    "load_model_file",
    "dump_model_file",
    "MAX_FILE_BYTES",
    "MAX_NAME_LENGTH",
    "MAX_SYMBOLS",
    "MAX_OUTPUTS",
    "MAX_COMPONENTS",
    *_expressions.__all__,
]

#: Largest model file read, in bytes.
MAX_FILE_BYTES = 1_000_000
#: Longest name (of the model, an input, a noise symbol or a parameter), in characters.
MAX_NAME_LENGTH = 100
#: Most inputs and noise symbols together, and most outputs, of a model file. The time a
#: C compiler takes on a large model is bounded where models are turned into C code.
MAX_SYMBOLS = 100
MAX_OUTPUTS = 100
#: Most components of a mixture in a model file (each goes through a transform: the
#: work of a file stays bounded).
MAX_COMPONENTS = 1000


# --------------------------------------------------------------------------------------
# Model files
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelSpec:
    """A model read from a model file, with the distributions of its inputs and noise.

    Attributes
    ----------
    model : Model
    u : Gaussian or GaussianMixture
        The distribution of the inputs, in the order of ``model.inputs``.
    v : Gaussian, GaussianMixture or None
        The distribution of the noise, in the order of ``model.noise``; None without noise.
    units : dict of str to str
        Pint unit strings by input or noise name, and by ``"outputs[i]"``.
    path : pathlib.Path
        The file the spec was read from.
    """

    model: Model
    u: Gaussian | GaussianMixture
    v: Gaussian | GaussianMixture | None = None
    units: dict[str, str] = field(default_factory=dict)
    path: Path = Path("<memory>")


_TOP_KEYS = ("name", "inputs", "noise", "outputs", "angles", "params", "u", "v", "units")
_REQUIRED_KEYS = ("name", "inputs", "outputs", "u")
_GAUSS_KEYS = ("mean", "cov", "std")
_MIXTURE_KEYS = ("weights", "means", "covs", "stds")
_EVALF_DIGITS = 30
#: ``{indexed}[i]``: the key of the i-th output in a [units] table.
_INDEXED_UNIT = r"{indexed}\[(0|[1-9][0-9]*)\]"


class _Context:
    """Reading state of one file: its path and raw text, for messages and positions."""

    def __init__(self, path: Path, raw: str) -> None:
        self.path = path
        self.raw = raw

    def error(self, where: str, message: str) -> ModelFileError:
        prefix = f"{self.path}: {where}: " if where else f"{self.path}: "
        return ModelFileError(prefix + message, source=str(self.path), reason=message)

    def locate(self, text: str, anchor: str) -> tuple[int, int]:
        """Line offset and column offset of ``text`` in the file, searched after ``anchor``.

        tomllib gives no positions for values; searching the raw text (first as a quoted
        string, then bare) is a best effort, and (0, 0), positions within the expression,
        when it fails.
        """
        m = re.search(anchor, self.raw, flags=re.MULTILINE)
        if not text or m is None:
            return 0, 0
        found = [i + 1 for q in ('"', "'") if (i := self.raw.find(q + text + q, m.end())) >= 0]
        if not found:
            found = [i for i in [self.raw.find(text, m.end())] if i >= 0]
        if not found:
            return 0, 0
        line, col = _char_position(self.raw, min(found))
        return line - 1, col


def _read(path: Path, limit: int = MAX_FILE_BYTES, what: str = "model file") -> str:
    """The text of a model file (or another input file, ``what``): a regular UTF-8 file of
    at most ``limit`` bytes (MAX_FILE_BYTES for a model file).

    A FIFO, device or directory is refused from its ``stat`` before it is opened (opening
    a FIFO for reading blocks until a writer comes); the file is then opened without
    blocking and checked again on the open descriptor, in case it was swapped meanwhile.
    """
    def fail(reason: str) -> ModelFileError:
        return ModelFileError(f"{path}: {reason}", source=str(path), reason=reason)

    with _open_checked(path, limit, what) as fh:
        try:
            data = fh.read(limit + 1)
        except OSError as exc:
            raise fail(f"{what} cannot be read: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise fail(f"{what} larger than {limit} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise fail(f"{what} is not UTF-8 text (byte {exc.start})") from None


def _open_checked(path: Path, limit: int = MAX_FILE_BYTES, what: str = "model file") -> BinaryIO:
    """The open binary file at ``path`` after the checks of :func:`_read` (regular, at most
    ``limit`` bytes), for a reader that streams it (a particle file)."""
    def fail(reason: str) -> ModelFileError:
        return ModelFileError(f"{path}: {reason}", source=str(path), reason=reason)

    try:
        _check_regular(os.stat(path), fail, limit, what)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        fh = os.fdopen(fd, "rb")
        try:
            _check_regular(os.fstat(fh.fileno()), fail, limit, what)
        except BaseException:
            fh.close()
            raise
        return fh
    except FileNotFoundError:
        raise fail(f"{what} not found") from None
    except PermissionError:
        raise fail(f"{what} cannot be read (permission denied)") from None
    except OSError as exc:
        raise fail(f"{what} cannot be read: {exc.strerror or exc}") from None


def _check_regular(st: os.stat_result, fail: Callable[[str], ModelFileError], limit: int = MAX_FILE_BYTES,
                   what: str = "model file") -> None:
    """Refuse a file that is not regular, or too large, from its stat."""
    if stat.S_ISDIR(st.st_mode):
        raise fail(f"{what} cannot be read: it is a directory")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device, socket or other special file"
        raise fail(f"{what} cannot be read: it is {kind}, not a regular file")
    if st.st_size > limit:
        raise fail(f"{what} larger than {limit} bytes ({st.st_size} bytes)")


def _short(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters: hostile values make long messages."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _check_keys(ctx: _Context, table: Mapping, allowed: Sequence[str], required: Sequence[str], where: str) -> None:
    extra = sorted(set(table) - set(allowed))
    missing = [k for k in required if k not in table]
    if extra or missing:
        parts = []
        if missing:
            parts.append(f"missing key(s) {missing}")
        if extra:
            parts.append(f"unknown key(s) {_short(extra, 200)}")
        raise ctx.error(where, "; ".join(parts) + f"; allowed keys: {', '.join(allowed)}")


def _names(ctx: _Context, value: Any, key: str, seen: dict[str, str]) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ctx.error(key, f"must be a list of names (strings), got {_short(value)}")
    for name in value:
        _check_name(ctx, name, key, seen)
    return list(value)


def _check_name(ctx: _Context, name: str, key: str, seen: dict[str, str]) -> None:
    if len(name) > MAX_NAME_LENGTH:
        raise ctx.error(key, f"{_short(name)}: names are at most {MAX_NAME_LENGTH} characters long")
    if not name.isidentifier() or keyword.iskeyword(name):
        raise ctx.error(key, f"{name!r} is not a valid identifier")
    if unicodedata.normalize("NFKC", name) != name:
        # The Python parser normalises identifiers, so this name could never be used.
        raise ctx.error(key, f"{name!r} is not in Unicode NFKC form; write it as {unicodedata.normalize('NFKC', name)!r}")
    if name.startswith("__"):
        raise ctx.error(key, f"{name!r}: names starting with '__' are not allowed")
    if name in _RESERVED:
        raise ctx.error(key, f"{name!r} is reserved (a function or constant of the expression language)")
    if name in seen:
        raise ctx.error(key, f"duplicate name {name!r} (already declared in {seen[name]})")
    seen[name] = key


def _number(ctx: _Context, value: Any, where: str, params: Mapping[str, sp.Expr], anchor: str) -> float:
    if isinstance(value, bool):
        raise ctx.error(where, f"must be a number, got the boolean {_short(value)}")
    if isinstance(value, (int, float)):
        try:
            x = float(value)
        except OverflowError:  # an integer past the float range (TOML integers are unbounded here)
            raise ctx.error(where, "integer too large for a float (beyond ±1.8e308)") from None
    elif isinstance(value, str):
        line_off, col_off = ctx.locate(value, anchor)
        expr = parse_expression(
            value, params, source=f"{ctx.path}: {where}", line_offset=line_off, col_offset=col_off
        )
        if expr.free_symbols:
            raise ctx.error(where, f"{_short(value)} must be a constant expression, it uses {sorted(map(str, expr.free_symbols))}")
        try:
            # Extra digits, so that the conversion to float rounds once, correctly.
            x = float(expr.evalf(_EVALF_DIGITS))
        except (TypeError, OverflowError):
            raise ctx.error(where, f"{_short(value)} is not a real number ({str(expr.evalf())})") from None
    else:
        raise ctx.error(where, f"must be a number or a constant expression string, got {_short(value)}")
    if not math.isfinite(x):
        raise ctx.error(where, f"must be finite, got {_short(value)}")
    return x


def _distribution(ctx: _Context, table: Any, key: str, dim: int, params: Mapping[str, sp.Expr], what: str
                  ) -> Gaussian | GaussianMixture:
    """The table ``[key]``: a Gaussian (mean, cov or std) or a mixture (weights, means, covs or stds)."""
    if isinstance(table, dict) and any(k in table for k in _MIXTURE_KEYS):
        return _mixture(ctx, table, key, dim, params, what)
    return _gaussian(ctx, table, key, dim, params, what)


def _mixture(ctx: _Context, table: dict, key: str, dim: int, params: Mapping[str, sp.Expr], what: str
             ) -> GaussianMixture:
    where = f"[{key}]"
    if any(k in table for k in _GAUSS_KEYS):
        raise ctx.error(where, "mixes the keys of a Gaussian (mean, cov, std) with those of a mixture "
                        "(weights, means, covs, stds)")
    _check_keys(ctx, table, _MIXTURE_KEYS, ("weights", "means"), where)
    if ("covs" in table) == ("stds" in table):
        raise ctx.error(where, "give exactly one of 'covs' (a covariance per component) or 'stds' "
                        "(standard deviations per component)")
    spread = "covs" if "covs" in table else "stds"
    anchor = rf"^\s*\[{key}\]"
    w_in, m_in, s_in = table["weights"], table["means"], table[spread]
    for name, value in (("weights", w_in), ("means", m_in), (spread, s_in)):
        if not isinstance(value, list) or not value:
            raise ctx.error(where, f"{name} must be a non-empty list, one entry per component, got {_short(value)}")
    K = len(w_in)
    if K > MAX_COMPONENTS:
        raise ctx.error(where, f"{K} components: at most {MAX_COMPONENTS} are accepted")
    if len(m_in) != K or len(s_in) != K:
        raise ctx.error(where, f"weights, means and {spread} must have one entry per component: "
                        f"got {K}, {len(m_in)} and {len(s_in)}")
    weights = [_number(ctx, x, f"{where}.weights[{k}]", params, anchor) for k, x in enumerate(w_in)]
    comps = [_gaussian(ctx, {"mean": m, spread[:-1]: c}, key, dim, params, what, where=f"{where} component {k}")
             for k, (m, c) in enumerate(zip(m_in, s_in))]
    try:
        return GaussianMixture.from_components(weights, comps)
    except SymmonError as exc:  # WeightError
        raise ctx.error(where, f"{type(exc).__name__}: {exc}") from None


def _gaussian(ctx: _Context, table: Any, key: str, dim: int, params: Mapping[str, sp.Expr], what: str,
              where: str | None = None) -> Gaussian:
    where = f"[{key}]" if where is None else where
    if not isinstance(table, dict):
        raise ctx.error(where, f"must be a table with keys {', '.join(_GAUSS_KEYS)} (a Gaussian) or "
                        f"{', '.join(_MIXTURE_KEYS)} (a mixture), got {_short(table)}")
    _check_keys(ctx, table, _GAUSS_KEYS, ("mean",), where)
    if ("cov" in table) == ("std" in table):
        raise ctx.error(where, "give exactly one of 'cov' (covariance) or 'std' (standard deviations)")
    anchor = rf"^\s*\[{key}\]"

    def vector(value: Any, name: str) -> np.ndarray:
        items = value if isinstance(value, list) else [value]
        return np.array([_number(ctx, x, f"{where}.{name}[{i}]", params, anchor) for i, x in enumerate(items)])

    mean = vector(table["mean"], "mean")
    if mean.shape[0] != dim:
        raise ctx.error(where, f"mean has length {mean.shape[0]} but there are {dim} {what}")
    try:
        if "std" in table:
            std = vector(table["std"], "std")
            if std.shape[0] != dim:
                raise ctx.error(where, f"std has length {std.shape[0]} but there are {dim} {what}")
            return Gaussian.from_std(mean, std)
        cov_in = table["cov"]
        if isinstance(cov_in, list):
            if not all(isinstance(row, list) for row in cov_in):
                raise ctx.error(where, f"cov must be a matrix (a list of rows), got {_short(cov_in)}")
            if len(cov_in) != dim or any(len(row) != dim for row in cov_in):
                shape = f"{len(cov_in)} rows of lengths {[len(r) for r in cov_in]}"
                raise ctx.error(where, f"cov must be {dim}x{dim} for {dim} {what}, got {shape}")
            cov = np.array(
                [[_number(ctx, x, f"{where}.cov[{i}][{j}]", params, anchor) for j, x in enumerate(row)]
                 for i, row in enumerate(cov_in)]
            ).reshape(dim, dim)
        else:
            if dim != 1:
                raise ctx.error(where, f"a scalar cov is only allowed in one dimension; there are {dim} {what}")
            cov = np.array([[_number(ctx, cov_in, f"{where}.cov", params, anchor)]])
        return Gaussian(mean, cov)
    except ModelFileError:
        raise
    except SymmonError as exc:  # ShapeError, CovarianceError from Gaussian
        raise ctx.error(where, f"{type(exc).__name__}: {exc}") from None


def _params(ctx: _Context, table: Any, seen: dict[str, str]) -> dict[str, sp.Expr]:
    """The [params] table as sympy numbers, by name."""
    if not isinstance(table, dict):
        raise ctx.error("params", f"must be a table of numbers, got {_short(table)}")
    params: dict[str, sp.Expr] = {}
    for name, value in table.items():
        _check_name(ctx, name, "[params]", seen)
        where = f"[params].{name}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ctx.error(where, f"must be a number, got {_short(value)}")
        if isinstance(value, int):
            if abs(value) > MAX_INTEGER_LITERAL:
                raise ctx.error(where, f"integer too large (more than {MAX_INTEGER_LITERAL:.0e})")
            params[name] = sp.Integer(value)
        else:
            if not math.isfinite(value):
                raise ctx.error(where, f"must be finite, got {_short(value)}")
            params[name] = sp.Float(value)
    return params


def _angles(ctx: _Context, value: Any, n_outputs: int, inputs: list[sp.Symbol]) -> list[int | sp.Symbol]:
    """The angles list as output indices and input symbols, for :class:`Model`."""
    if not isinstance(value, list):
        raise ctx.error("angles", f"must be a list of output indices or input names, got {_short(value)}")
    by_name = {s.name: s for s in inputs}
    angles: list[int | sp.Symbol] = []
    for a in value:
        if isinstance(a, int) and not isinstance(a, bool):
            if not 0 <= a < n_outputs:
                raise ctx.error("angles", f"output index {a} out of range for {n_outputs} outputs")
            angles.append(a)
        elif isinstance(a, str) and a in by_name:
            angles.append(by_name[a])
        else:
            raise ctx.error("angles", f"{_short(a)} is neither an output index nor an input name ({', '.join(by_name)})")
    return angles


def _units(ctx: _Context, table: Any, n_outputs: int, names: list[str], indexed: str = "outputs",
           named: str = "input and noise names") -> dict[str, str]:
    """The [units] table: keys are declared ``names`` or ``{indexed}[i]`` for output i
    (model files: ``outputs[i]``; scenario files: ``measurements[i]``)."""
    if not isinstance(table, dict):
        raise ctx.error("units", f"must be a table of unit strings, got {_short(table)}")
    units: dict[str, str] = {}
    for key, unit in table.items():
        m = re.fullmatch(_INDEXED_UNIT.format(indexed=indexed), key)
        if m is not None:
            if len(m.group(1)) > len(str(n_outputs)) or int(m.group(1)) >= n_outputs:  # length first: no huge int()
                raise ctx.error("[units]", f"{_short(key)}: there are only {n_outputs} {indexed}")
        elif key not in names:
            raise ctx.error(
                "[units]", f"unknown key {key!r}; allowed: {named}, or '{indexed}[i]' for an output"
            )
        if not isinstance(unit, str) or not unit.strip():
            raise ctx.error(f"[units].{key}", f"must be a non-empty unit string, got {_short(unit)}")
        units[key] = unit
    return units


def read_toml(path: str | Path, what: str) -> tuple[Path, "_Context", dict]:
    """Read and parse a TOML file with the checks of :func:`load_model_file`.

    Returns the path, the error context (file name, line numbers) and the document.
    """
    if _toml is None:
        raise ImportError(f"reading {what} on Python 3.10 needs the 'tomli' package (pip install tomli)")
    path = Path(path)
    raw = _read(path)
    ctx = _Context(path, raw)
    try:
        doc = _toml.loads(raw)
    except (_toml.TOMLDecodeError, ValueError) as exc:  # ValueError: an integer of over 4300 digits
        # The message of tomllib ends with "(at line L, column C)".
        raise ModelFileError(f"{path}: invalid TOML: {exc}", source=str(path), reason=str(exc)) from None
    except RecursionError:
        reason = "arrays or tables nested too deeply"
        raise ModelFileError(f"{path}: invalid TOML: {reason}", source=str(path), reason=reason) from None
    return path, ctx, doc


def load_model_file(path: str | os.PathLike) -> ModelSpec:
    """Read a model file (TOML) into a :class:`ModelSpec`.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    ModelSpec

    Raises
    ------
    ModelFileError
        With the file name, for a missing or unreadable file, invalid TOML (with its
        line and column), missing or unknown keys, wrong types, invalid or duplicate
        names, refused expressions (with line and column), dimension mismatches, and
        ``noise`` without ``[v]`` (or ``[v]`` without ``noise``).
    ImportError
        On Python 3.10 without the ``tomli`` package.

    Examples
    --------
    >>> import tempfile
    >>> text = '''
    ... name = "polar"
    ... inputs = ["x", "y"]
    ... outputs = ["hypot(x, y)", "atan2(y, x)"]
    ... [u]
    ... mean = [1, 10]
    ... std = [0.5, 5]
    ... '''
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "polar.toml"
    ...     _ = path.write_text(text, encoding="utf-8")
    ...     spec = load_model_file(path)
    >>> spec.model.outputs
    (sqrt(x**2 + y**2), atan2(y, x))
    >>> spec.u
    N([1, 10], [[0.25, 0], [0, 25]])
    """
    path, ctx, doc = read_toml(path, "model files")
    _check_keys(ctx, doc, _TOP_KEYS, _REQUIRED_KEYS, "")

    name = doc["name"]
    if not isinstance(name, str) or not name.strip():
        raise ctx.error("name", f"must be a non-empty string, got {name!r}")
    if len(name) > MAX_NAME_LENGTH or not name.isprintable():
        # The name is printed in reports and written into generated C comments.
        raise ctx.error("name", f"must be at most {MAX_NAME_LENGTH} printable characters (no control characters)")

    seen: dict[str, str] = {}
    input_names = _names(ctx, doc["inputs"], "inputs", seen)
    if not input_names:
        raise ctx.error("inputs", "at least one input is required")
    noise_names = _names(ctx, doc.get("noise", []), "noise", seen)
    if len(input_names) + len(noise_names) > MAX_SYMBOLS:
        raise ctx.error("inputs", f"{len(input_names)} inputs and {len(noise_names)} noise symbols: "
                        f"at most {MAX_SYMBOLS} in all are accepted")

    params = _params(ctx, doc.get("params", {}), seen)

    u_syms = [sp.Symbol(n, real=True) for n in input_names]
    v_syms = [sp.Symbol(n, real=True) for n in noise_names]
    env: dict[str, sp.Expr] = {**params, **{s.name: s for s in u_syms + v_syms}}

    outputs_raw = doc["outputs"]
    if not isinstance(outputs_raw, list) or not outputs_raw or not all(isinstance(o, str) for o in outputs_raw):
        raise ctx.error("outputs", f"must be a non-empty list of expression strings, got {_short(outputs_raw)}")
    if len(outputs_raw) > MAX_OUTPUTS:
        raise ctx.error("outputs", f"{len(outputs_raw)} outputs: at most {MAX_OUTPUTS} are accepted")
    outputs = []
    for i, text in enumerate(outputs_raw):
        line_off, col_off = ctx.locate(text, r"^\s*outputs\s*=")
        outputs.append(
            parse_expression(text, env, source=f"{path}: outputs[{i}]", line_offset=line_off, col_offset=col_off)
        )

    angles = _angles(ctx, doc.get("angles", []), len(outputs), u_syms)
    try:
        model = Model(u_syms, outputs, noise=v_syms or None, name=name, angles=angles)
    except ModelError as exc:
        raise ctx.error("model", str(exc)) from None

    u = _distribution(ctx, doc["u"], "u", len(u_syms), params, "inputs")
    v = None
    if noise_names and "v" not in doc:
        raise ctx.error("[v]", f"noise {noise_names} is declared, so a [v] table (its Gaussian) is required")
    if "v" in doc:
        if not noise_names:
            raise ctx.error("[v]", "a [v] table needs noise symbols: declare them with noise = [...] and use them in outputs")
        v = _distribution(ctx, doc["v"], "v", len(v_syms), params, "noise symbols")

    units = _units(ctx, doc.get("units", {}), len(outputs), input_names + noise_names)
    return ModelSpec(model=model, u=u, v=v, units=units, path=path)


# --------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------


class _FilePrinter(StrPrinter):
    """sympy's str printer, with floats written so that they read back bit for bit."""

    def _print_Float(self, expr: sp.Float) -> str:
        if expr._prec <= 53:
            return repr(float(expr))
        return super()._print_Float(expr)


def _toml_str(s: str) -> str:
    # JSON string escapes are a subset of TOML basic-string escapes.
    return json.dumps(s, ensure_ascii=False)


def _toml_float(x: float) -> str:
    return repr(float(x))


def _toml_key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _toml_str(k)


def _matrix(P: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(_toml_float(x) for x in row) + "]" for row in P) + "]"


def _gaussian_table(key: str, g: Gaussian | GaussianMixture) -> list[str]:
    if isinstance(g, GaussianMixture):
        return [f"[{key}]", "weights = [" + ", ".join(_toml_float(w) for w in g.weights) + "]",
                "means = [" + ", ".join("[" + ", ".join(_toml_float(x) for x in m) + "]" for m in g.means) + "]",
                "covs = [" + ", ".join(_matrix(P) for P in g.covs) + "]", ""]
    mean = ", ".join(_toml_float(x) for x in g.mean)
    rows = ", ".join("[" + ", ".join(_toml_float(x) for x in row) + "]" for row in g.cov)
    return [f"[{key}]", f"mean = [{mean}]", f"cov = [{rows}]", ""]


def dump_model_file(spec: ModelSpec) -> str:
    """Write a :class:`ModelSpec` as model-file TOML text that :func:`load_model_file` reads back.

    Expressions are written with sympy's string printer (floats with all their digits)
    and checked by parsing them back; parameters appear substituted by their values.

    Parameters
    ----------
    spec : ModelSpec

    Returns
    -------
    str

    Raises
    ------
    ModelFileError
        If a name cannot be written (not an identifier, or reserved) or an output
        would not read back as the same expression.

    Examples
    --------
    >>> x = sp.Symbol("x", real=True)
    >>> print(dump_model_file(ModelSpec(Model([x], [x**2 / 2]), Gaussian([0], 1))), end="")
    name = "model"
    inputs = ["x"]
    outputs = [
        "x**2/2",
    ]
    <BLANKLINE>
    [u]
    mean = [0.0]
    cov = [[1.0]]
    """
    model = spec.model
    names = [s.name for s in model.inputs + model.noise]
    seen: dict[str, str] = {}
    ctx = _Context(spec.path, "")
    for n in names:
        _check_name(ctx, n, "dump", seen)
    env = {s.name: s for s in model.inputs + model.noise}
    printer = _FilePrinter()
    out_texts = []
    for i, expr in enumerate(model.outputs):
        text = printer.doprint(expr)
        again = parse_expression(text, env, source=f"dump: outputs[{i}]")
        if again != expr:
            raise ModelFileError(
                f"dump: outputs[{i}] would not read back unchanged: {expr} was written as {text!r}, read as {again}",
                source="dump", reason="round trip",
            )
        out_texts.append(text)

    lines = [f"name = {_toml_str(model.name)}"]
    lines.append("inputs = [" + ", ".join(_toml_str(s.name) for s in model.inputs) + "]")
    if model.noise:
        lines.append("noise = [" + ", ".join(_toml_str(s.name) for s in model.noise) + "]")
    lines.append("outputs = [")
    lines.extend(f"    {_toml_str(t)}," for t in out_texts)
    lines.append("]")
    angles = [str(i) for i in sorted(model.angle_outputs)]
    angles += [_toml_str(model.inputs[i].name) for i in sorted(model.angle_inputs)]
    if angles:
        lines.append("angles = [" + ", ".join(angles) + "]")
    lines.append("")
    lines.extend(_gaussian_table("u", spec.u))
    if spec.v is not None:
        lines.extend(_gaussian_table("v", spec.v))
    if spec.units:
        lines.append("[units]")
        lines.extend(f"{_toml_key(k)} = {_toml_str(v)}" for k, v in spec.units.items())
        lines.append("")
    return "\n".join(lines)
