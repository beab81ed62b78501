"""The ``symmon`` command: model files in, moments, measures of nonlinearity and reports out.

A user who never writes Python declares a model in a TOML file (:mod:`symmon.modelfile`)
and runs, e.g.::

    symmon propagate examples/polar.toml --transform ut1 --json
    symmon nonlinearity examples/gmti.toml --weight full --alpha-sweep 0.01:100:9 --csv mon.csv
    symmon compare examples/polar.toml

Exit codes: 0 on success, 2 on a usage error (bad options; argparse prints the usage),
1 on a model or input error (a bad model file, a singular covariance, an unwritable output
path, a result that is not finite, ...), 130 when interrupted, 141 when the reader of stdout
goes away (``| head``). An unexpected exception is reported in one line with exit code 1;
set the environment variable ``SYMMON_DEBUG=1`` to see its traceback.

Options are checked when they are parsed, before any computation: the sizes have declared
limits (:data:`MAX_SAMPLES`, :data:`MAX_ORDER`, :data:`MAX_GROUPS`, :data:`MAX_WORKERS`,
:data:`MAX_SWEEP_POINTS`), a ``--dask`` address must have a known scheme, a host and a port,
``--plot`` a figure format matplotlib writes, and output paths must name regular files (or
directories) that can be written. Error messages go to stderr, results to stdout. Every
output file is written atomically through :mod:`symmon.io` (temporary file, then rename),
so an existing file is replaced whole or left untouched. Progress goes to stderr: a bar on a
terminal, a line every few seconds otherwise (:mod:`symmon.progress`); ``--quiet`` hides it.
Counts (``--samples``, ``--runs``, ...) may be written ``1e6`` when they are integers.

:func:`main` returns the exit code instead of exiting, so it can be called in-process.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import ipaddress
import json
import math
import os
import re
import sys
import traceback
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from .ccache import catch_sigterm
from .errors import SymmonError
from .progress import LINE_INTERVAL, silenced

__all__ = ["main", "transform_from_name", "TRANSFORM_NAMES", "WEIGHT_NAMES", "FIGURES"]

#: The paper whose equation numbers the help cites.
SH24 = "Straka & Havlík 2024"
WEIGHT_NAMES = ("full", "diag", "liu-li", "liu-li-raw")
FIGURES = ("fig1", "fig2", "radar", "mmse", "tracking")

_EXAMPLES = {
    "propagate": ["symmon propagate examples/polar.toml --transform ut1 --json",
                  "symmon propagate examples/bot.toml --transform mc --samples 100000 --seed 1",
                  "symmon propagate examples/gmti.toml --transform mc --samples 1000000000 --dask tcp://scheduler:8786"],
    "nonlinearity": ["symmon nonlinearity examples/polar.toml --weight full --transform tt2",
                     "symmon nonlinearity examples/gmti.toml --weight full --transform mc --samples 100000 "
                     "--alpha-sweep 0.01:100:9 --csv mon.csv --plot mon.png"],
    "compare": ["symmon compare examples/polar.toml --samples 100000",
                "symmon compare examples/rdcos.toml --weight diag --json"],
    "prove-invariance": ["symmon prove-invariance examples/polar.toml --weight full",
                         "symmon prove-invariance examples/gmti.toml --weight diag --numeric"],
    "reproduce": ["symmon reproduce fig1 --samples 10000000 --out results",
                  "symmon reproduce all --samples 100000"],
    "derive": ["symmon derive --all --out derivations.md", "symmon derive --list"],
    "codegen": ["symmon codegen examples/gmti.toml -o build/gmti"],
    "filter": ["symmon filter examples/rb_close.toml --runs 500 --plot nees.png",
               "symmon filter examples/rb_close.toml --filters ekf,ukf,adaptive --tol 0.01 --json"],
    "advise": ["symmon advise examples/bot.toml --tol 0.001",
               "symmon advise examples/polar.toml --weight diag --json"],
}


class _UsageError(Exception):
    """A combination of options that argparse cannot check by itself (exit code 2)."""


def transform_from_name(name: str, samples: int = 10**6, seed: int = 0, order: int = 5, groups: int = 16):
    """A transform from its registered short name (:mod:`symmon.transforms.registry`).

    Parameters
    ----------
    name : str
        One of :data:`TRANSFORM_NAMES`: ``tt1``, ``tt2``, ``ut1``, ``ut2``, ``ct``, ``gh``,
        ``qmc``, ``mc`` and any rule registered since.
    samples, seed : int
        Monte Carlo sample count and seed (``mc`` and ``qmc`` only).
    order : int
        Gauss-Hermite order per dimension (``gh`` only).
    groups : int
        In how many independent groups Monte Carlo runs (``mc`` and ``qmc`` only; see
        :class:`symmon.MonteCarlo`).  Where they run is the command's executor.

    Returns
    -------
    Transform

    Raises
    ------
    SymmonError
        For an unknown name.
    """
    from .transforms.registry import make

    return make(name, samples=samples, seed=seed, order=order, groups=groups)


def _transform_names() -> tuple[str, ...]:
    from .transforms.registry import names  # imports the transforms: only when needed

    return names()


def __getattr__(attr: str) -> Any:
    if attr == "TRANSFORM_NAMES":  # short names of the transforms, in the order ``compare`` lists them
        return _transform_names()
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


#: Local Dask schedulers that ``--dask`` accepts by name; anything else is an address.
DASK_LOCAL = ("threads", "processes", "synchronous")
#: Network schemes of a ``--dask`` address (besides in-process ``inproc://``).
DASK_SCHEMES = ("tcp", "tls", "ucx")

# Declared limits of the options: past them a run would not fit in memory or in a day.
#: Monte Carlo samples (``--samples``); samples are drawn in chunks, so this bounds time only.
MAX_SAMPLES = 10**12
#: Largest seed (``--seed``): numpy's SeedSequence takes non-negative integers.
MAX_SEED = 2**64 - 1
#: Gauss-Hermite points per dimension (``--order``).
MAX_ORDER = 100
#: Monte Carlo groups (``--groups``) and threads (``--workers``).
MAX_GROUPS = 1024
#: Most Monte Carlo runs of a filter study (each run keeps its whole trajectory).
MAX_RUNS = 10**5
MAX_WORKERS = 1024
#: Points of ``--alpha-sweep``: each is a full MoN computation.
MAX_SWEEP_POINTS = 1000
#: Fewest ``reproduce --samples``: two per Monte Carlo group of the figures (16 groups).
REPRODUCE_MIN_SAMPLES = 32
#: Seconds to wait for a Dask scheduler at ``--dask ADDRESS``.
DASK_CONNECT_TIMEOUT = 10


@contextlib.contextmanager
def _executor(args: argparse.Namespace) -> Iterator[Any]:
    """The :class:`~symmon.Executor` of ``--workers`` and ``--dask``, with progress; a
    Client to a ``--dask`` address is connected for the command and closed after it."""
    from .transforms.executor import Executor

    target = args.dask
    if target is None or target in DASK_LOCAL:
        yield Executor(workers=args.workers, scheduler=target, progress=True)
        return
    # An address, checked by _dask_target when the arguments were parsed.
    from .transforms.executor import connect_dask

    try:
        client = connect_dask(target, DASK_CONNECT_TIMEOUT)  # bounds the handshake too
    except SymmonError:
        raise
    except Exception as exc:  # tls:// without a TLS configuration, ucx:// without ucx-py, ...
        raise SymmonError(f"cannot connect to the Dask scheduler at {target}: "
                          f"{type(exc).__name__}: {exc}") from exc
    try:
        yield Executor(workers=args.workers, client=client, progress=True)
    finally:
        client.close()


def _load(path: str):
    from .modelfile import load_model_file

    return load_model_file(path)


def _jsonable(a: Any) -> Any:
    """Arrays and floats as JSON values; NaN and inf become null (strict JSON has neither)."""
    if a is None:
        return None
    if isinstance(a, (list, tuple)):
        return [_jsonable(x) for x in a]
    arr = np.asarray(a)
    if arr.ndim == 0:
        x = arr.item()
        if isinstance(x, float) and not math.isfinite(x):
            return None
        return x
    return [_jsonable(x) for x in arr]


def _finite(name: str, value: Any) -> Any:
    """``value``, after checking that every number in it is finite (None passes).

    A NaN or inf is an error, never a printed result: the command exits 1 naming the quantity.
    """
    if value is not None and not np.all(np.isfinite(np.asarray(value, dtype=float))):
        raise SymmonError(f"{name} is not finite (it contains NaN or inf); no result is printed")
    return value


def _print_json(obj: dict) -> None:
    print(json.dumps(obj, indent=2, allow_nan=False))


# --------------------------------------------------------------------------- units
#: Widest expression printed in an output table; longer ones are cut with "…" (``--json`` has them whole).
EXPR_WIDTH = 60


def _units_of(spec) -> dict[str, Any]:
    """The file's ``[units]`` by role: a unit (or None) per output, input and noise symbol."""
    m, units = spec.model, spec.units
    return {"outputs": [units.get(f"outputs[{i}]") for i in range(m.n_y)],
            "inputs": {str(s): units.get(str(s)) for s in m.inputs},
            "noise": {str(s): units.get(str(s)) for s in m.noise}}


def _label(name: str, unit: str | None) -> str:
    return f"{name} [{unit}]" if unit else name


def _short(text: str, width: int = EXPR_WIDTH) -> str:
    return text if len(text) <= width else text[:width - 1] + "…"


def _num(x: float) -> str:
    """One number format for every table: 6 significant digits, exponent only when needed."""
    return f"{x:.6g}"


def _grid(title: str, rows: Sequence[str], cols: Sequence[str], values: np.ndarray) -> list[str]:
    """A labelled matrix: a header of column labels, then one labelled line per row."""
    first = max(len(r) for r in rows)
    cells = [[_num(v) for v in row] for row in np.atleast_2d(values)]
    widths = [max(len(c), *(len(r[j]) for r in cells)) for j, c in enumerate(cols)]
    lines = [title, " " * first + "".join(f"  {c:>{w}}" for c, w in zip(cols, widths))]
    lines += [f"{r:<{first}}" + "".join(f"  {c:>{w}}" for c, w in zip(cells_r, widths))
              for r, cells_r in zip(rows, cells)]
    return lines


def _moments_text(spec, m) -> list[str]:
    """E y with its standard deviation and unit per output, then Cov y and Cov(y, u), labelled."""
    units = _units_of(spec)
    ys = [f"y[{i}]" for i in range(spec.model.n_y)]
    sd = np.sqrt(np.clip(np.diag(m.cov), 0.0, None))
    se = None if m.stderr is None else np.asarray(m.stderr["mean"], dtype=float)
    head = ["output", "E y", "sd", *(["MC s.e."] if se is not None else []), "unit", "expression"]
    rows = [[y, _num(m.mean[i]), _num(sd[i]), *([_num(se[i])] if se is not None else []),
             units["outputs"][i] or "-", _short(str(e))] for i, (y, e) in enumerate(zip(ys, spec.model.outputs))]
    widths = [max(len(r[j]) for r in [head, *rows]) for j in range(len(head))]
    lines = ["  ".join(f"{c:<{w}}" if j in (0, len(head) - 2, len(head) - 1) else f"{c:>{w}}"
                       for j, (c, w) in enumerate(zip(r, widths))).rstrip() for r in [head, *rows]]
    ylab = [_label(y, u) for y, u in zip(ys, units["outputs"])]
    ulab = [_label(k, u) for k, u in units["inputs"].items()]
    lines += _grid("Cov y (entry i, j in the unit of y[i] times that of y[j]):", ylab, ylab, m.cov)
    lines += _grid("Cov(y, u) (entry i, j in the unit of y[i] times that of u[j]):", ylab, ulab, m.cross_cov)
    if not any(units["outputs"]) and not any(units["inputs"].values()):
        lines.append("(the file has no [units] table: the numbers are in the model's own units)")
    return lines


def _mon_unit(spec, weight: str) -> str:
    """What the MoN is measured in: nothing, except for the raw Liu–Li MoN (6) (W = I)."""
    if weight != "liu-li-raw":
        return "unitless"
    units = [u or "?" for u in _units_of(spec)["outputs"]]
    if len(set(units)) == 1 and units[0] != "?":
        return units[0]  # √tr of a covariance of outputs that share one unit
    return "mixed units of y: " + ", ".join(units)


# --------------------------------------------------------------------------- commands
def cmd_propagate(args: argparse.Namespace) -> int:
    """``symmon propagate``: E y, Cov y and Cov(y, u) by one transform."""
    from .propagate import propagate

    spec = _load(args.file)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order, args.groups)
    with _executor(args) as ex:
        m = propagate(spec.model, spec.u, spec.v, transform=tr, executor=ex)
    for name, value in (("E y", m.mean), ("Cov y", m.cov), ("Cov(y, u)", m.cross_cov),
                        *((f"the standard error of {k}", v) for k, v in (m.stderr or {}).items())):
        _finite(name, value)
    if args.json:
        out = {
            "model": spec.model.name, "inputs": [str(s) for s in spec.model.inputs],
            "outputs": [str(e) for e in spec.model.outputs], "units": _units_of(spec), "transform": repr(tr),
            "mean": _jsonable(m.mean), "cov": _jsonable(m.cov), "cross_cov": _jsonable(m.cross_cov),
            "stderr": None if m.stderr is None else {k: _jsonable(v) for k, v in m.stderr.items()},
        }
        _print_json(out)
        return 0
    print(f"{spec.model.name} by {tr!r}")
    print("\n".join(_moments_text(spec, m)))
    return 0


def _sweep(text: str) -> np.ndarray:
    """argparse type of ``--alpha-sweep A:B:N``: N log-spaced scalings from A to B."""
    parts = text.split(":")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"must be A:B:N (N log-spaced alphas from A to B), got {text!r}")
    try:
        a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be A:B:N with numbers A, B and an integer N, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)) or a <= 0 or b <= 0 or n < 1:
        raise argparse.ArgumentTypeError(f"needs finite A, B > 0 and N >= 1, got {text!r}")
    if n > MAX_SWEEP_POINTS:
        raise argparse.ArgumentTypeError(f"N must be at most {MAX_SWEEP_POINTS}, got {text!r}")
    return np.logspace(np.log10(a), np.log10(b), n)


def _count(text: str) -> int | None:
    """The integer that ``text`` writes, in plain or scientific notation (``1e6``), else None.

    Exact decimal arithmetic: ``1.5e0`` is not an integer and ``1e6`` is exactly 10⁶.
    """
    try:
        return int(text)
    except ValueError:
        pass
    try:
        d = Decimal(text.strip())
    except InvalidOperation:
        return None
    if not d.is_finite() or d != d.to_integral_value() or d.adjusted() > 100:  # 1e999999 stays a string
        return None
    return int(d)


def _int_in(lo: int, hi: int) -> Callable[[str], int]:
    """argparse type: an integer from ``lo`` to ``hi``, also in scientific notation (``1e6``);
    the bound keeps memory and time in reach."""
    def parse(text: str) -> int:
        what = "a positive integer" if lo == 1 else f"an integer >= {lo}"
        n = _count(text)
        if n is None:
            raise argparse.ArgumentTypeError(f"must be {what} (1e6 is allowed), got {text!r}")
        if n < lo:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        if n > hi:
            raise argparse.ArgumentTypeError(f"must be at most {hi:,}, got {text!r}")
        return n

    return parse


_samples = _int_in(1, MAX_SAMPLES)
_seed = _int_in(0, MAX_SEED)


def _dask_target(text: str) -> str:
    """argparse type of ``--dask``: a local scheduler name or a scheduler address.

    An address is ``[tcp|tls|ucx://]host:port`` with a port from 1 to 65535 (a bracketed
    IPv6 host is allowed), or an in-process ``inproc://host/pid/n`` address.
    """
    if text in DASK_LOCAL:
        return text
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text
    if scheme == "inproc" and re.fullmatch(r"[^/\s]+/[0-9]+/[0-9]+", rest):
        return text
    usage = (f"--dask takes {', '.join(DASK_LOCAL)} or a scheduler address such as tcp://host:8786, "
             f"not {text!r}")
    form = f"in {text!r} (an address is [{'|'.join(DASK_SCHEMES)}://]host:port)"
    if scheme not in DASK_SCHEMES:
        raise argparse.ArgumentTypeError(f"unknown scheme {scheme!r} {form}")
    host, colon, port = rest.rpartition(":")
    if not colon or not host:
        raise argparse.ArgumentTypeError(usage)
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid IPv6 host {host!r} {form}") from None
    elif not re.fullmatch(r"[A-Za-z0-9_]([A-Za-z0-9_.-]*[A-Za-z0-9_])?", host):  # '_': container names
        raise argparse.ArgumentTypeError(f"invalid host {host!r} {form}")
    if not (port.isascii() and port.isdigit() and len(port) <= 5 and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"the port must be a number from 1 to 65535, got {port!r} {form}")
    return text


def _output_path(text: str) -> str:
    """argparse type of an output file or directory: not empty (checked on disk later)."""
    if not text:
        raise argparse.ArgumentTypeError("must be a file name, got an empty string")
    return text


def _plot_path(text: str) -> str:
    """argparse type of ``--plot``: a file name whose suffix is a format matplotlib writes."""
    from .io import OutputPathError, plot_format

    try:
        plot_format(_output_path(text))
    except OutputPathError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _measure_json(res) -> dict:
    return {"value": res.value, "squared": res.squared, "J_Ab": res.J_Ab, "J_n": res.J_n,
            "stderr": _jsonable(res.stderr), "weight": res.weight_name, "structure": res.structure,
            "transform": repr(res.transform), "notes": list(res.notes)}


def _finite_measure(res, where: str):
    """The MoN result ``res``, after checking that its numbers are finite."""
    for name, value in (("the MoN", res.value), ("the squared MoN", res.squared), ("J_Ab", res.J_Ab),
                        ("J_n", res.J_n), ("the standard error of the MoN", res.stderr)):
        _finite(name + where, value)
    return res


def _check_output_files(*paths: str | None) -> None:
    """Refuse output files that cannot be written, before any computation."""
    from .io import check_output_file

    for p in paths:
        if p is not None:
            check_output_file(p)


def cmd_nonlinearity(args: argparse.Namespace) -> int:
    """``symmon nonlinearity``: the MoN of a model file, once or over a sweep of α."""
    if args.alpha_sweep is None and (args.plot or args.csv):
        raise _UsageError("--plot and --csv need --alpha-sweep")
    _check_output_files(args.csv, args.plot)
    if args.csv and args.plot and os.path.realpath(args.csv) == os.path.realpath(args.plot):
        raise _UsageError(f"--csv and --plot name the same file: {args.csv}")
    if args.plot and importlib.util.find_spec("matplotlib") is None:
        raise SymmonError("--plot needs matplotlib: pip install 'symmon[plot]'")
    with _executor(args) as ex:
        return _nonlinearity(args, ex)


def _nonlinearity(args: argparse.Namespace, ex: Any) -> int:
    from .gaussian import Gaussian
    from .io import save_figure, write_csv
    from .nonlinearity import nonlinearity
    from .reproduce._common import progress_bar, pyplot

    spec = _load(args.file)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order, args.groups)
    unit = _mon_unit(spec, args.weight)
    if args.alpha_sweep is None:
        res = _finite_measure(nonlinearity(spec.model, spec.u, spec.v, weight=args.weight, transform=tr,
                                           executor=ex), "")
        if args.json:
            _print_json({"model": spec.model.name, **_measure_json(res), "unit": unit})
            return 0
        se = f" ± {res.stderr:.2g} (MC standard error)" if res.stderr is not None else ""
        print(f"{spec.model.name}: MoN[{args.weight}] by {tr!r} = {res.value:.6g}{se} ({unit})")
        for note in res.notes:
            print(f"note: {note}")
        return 0
    # Σ_uu ← α Σ_uu, as in the papers' figures (the noise covariance is kept).
    rows, notes = [], []
    for a in progress_bar(args.alpha_sweep, "alpha sweep", not args.no_progress):
        res = nonlinearity(spec.model, Gaussian(spec.u.mean, a * spec.u.cov), spec.v, weight=args.weight,
                           transform=tr, executor=ex)
        _finite_measure(res, f" at alpha={a:.6g}")
        rows.append((float(a), res.value, res.stderr))  # stderr None: not a Monte Carlo transform
        notes.extend(n for n in res.notes if n not in notes)
    # Compute everything first, then write: a failure midway leaves no partial file.
    written = []
    if args.csv:
        written.append(write_csv(args.csv, ["alpha", "mon", "stderr"], rows))
    if args.plot:
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogx([r[0] for r in rows], [r[1] for r in rows], "o-")
        ax.set_xlabel(r"$\alpha$ (input covariance scale, unitless)")
        ax.set_ylabel(f"MoN ({args.weight}, {args.transform}) [{unit}]")
        ax.set_title(spec.model.name)
        fig.tight_layout()
        try:
            written.append(save_figure(fig, args.plot, dpi=120))
        finally:
            plt.close(fig)
    if args.json:
        _print_json({"model": spec.model.name, "weight": args.weight, "transform": repr(tr),
                     "alpha": [r[0] for r in rows], "mon": [r[1] for r in rows],
                     "stderr": _jsonable([r[2] for r in rows]), "unit": unit, "notes": notes,
                     "files": [str(p) for p in written]})
        return 0
    print(f"{spec.model.name}: MoN[{args.weight}] by {tr!r} ({unit}) over alpha, the scale of Cov u")
    for a, value, se in rows:
        print(f"alpha={a:.4g}  MoN={value:.6g}" + ("" if se is None else f" ± {se:.2g}"))
    for note in notes:
        print(f"note: {note}")
    for p in written:
        print(f"wrote {p}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """``symmon compare``: the MoN and the moments by every transform, as one table."""
    from .nonlinearity import nonlinearity
    from .reproduce._common import progress_bar

    spec = _load(args.file)
    rows = []
    with _executor(args) as ex:
        for name in progress_bar(_transform_names(), "transforms", not args.no_progress):
            tr = transform_from_name(name, args.samples, args.seed, args.order, args.groups)
            res = _finite_measure(nonlinearity(spec.model, spec.u, spec.v, weight=args.weight, transform=tr,
                                               executor=ex), f" by {name}")
            m = res.moments
            for what, value in (("E y", m.mean), ("Cov y", m.cov), ("Cov(y, u)", m.cross_cov)):
                _finite(f"{what} by {name}", value)
            rows.append({"name": name, "transform": repr(tr), "mon": res.value, "stderr": res.stderr,
                         "evaluations": m.evaluations, "mean": m.mean, "cov": m.cov,
                         "cross_cov": m.cross_cov, "notes": res.notes})
    for r in rows:
        r["relative_stderr"] = _relative(r["stderr"], r["mon"])
        r["flagged"] = r["relative_stderr"] is not None and r["relative_stderr"] > FLAG_RELATIVE_STDERR
    if args.json:
        _print_json({"model": spec.model.name, "weight": args.weight, "flag_relative_stderr": FLAG_RELATIVE_STDERR,
                     "units": _units_of(spec), "rows": [
            {k: (_jsonable(v) if k not in ("name", "transform", "evaluations", "flagged") else v) for k, v in r.items()}
            for r in rows]})
        return 0
    print(f"{spec.model.name}: MoN with weight {args.weight!r} ({_mon_unit(spec, args.weight)}) "
          "and the moments by every transform")
    units = _units_of(spec)["outputs"]
    head = ["", "MoN", "MC s.e.", "s.e./MoN",
            *(_label(f"E y[{i}]", u) for i, u in enumerate(units)), *(_label(f"sd y[{i}]", u) for i, u in enumerate(units))]
    table = [head]
    for r in rows:
        rel = r["relative_stderr"]
        table.append([r["name"], _num(r["mon"]), "-" if r["stderr"] is None else _num(r["stderr"]),
                      "-" if rel is None else f"{100 * rel:.2g}%" + (" !" if r["flagged"] else ""),
                      *map(_num, r["mean"]), *map(_num, np.sqrt(np.clip(np.diag(r["cov"]), 0.0, None)))])
    widths = [max(len(t[j]) for t in table) for j in range(len(head))]
    for t in table:
        print("  ".join(f"{c:>{w}}" for c, w in zip(t, widths)))
    if any(r["flagged"] for r in rows):
        print(f"! the Monte Carlo error bar exceeds {FLAG_RELATIVE_STDERR:.0%} of the MoN: "
              "that row is noise, not a value; raise --samples")
    print("\ntransforms:")
    for r in rows:
        print(f"{r['name']:>4}: {r['transform']}")
    notes = sorted({n for r in rows for n in r["notes"]})
    for note in notes:
        print(f"note: {note}")
    return 0


#: ``compare`` flags a row whose Monte Carlo standard error exceeds this share of its MoN.
FLAG_RELATIVE_STDERR = 0.10


def _relative(stderr: float | None, value: float) -> float | None:
    """stderr / |value| (inf for a zero value with an error bar), None without an error bar."""
    if stderr is None:
        return None
    return stderr / abs(value) if value != 0 else (0.0 if stderr == 0 else math.inf)


def cmd_prove(args: argparse.Namespace) -> int:
    """``symmon prove-invariance``: the symbolic unit-invariance proof of the MoN."""
    from .io import atomic_write_text
    from .units import prove_invariance

    _check_output_files(args.out)
    spec = _load(args.file)
    # --numeric: the file's distributions, made exact: a proof for this u (and v) only.
    moments = dict(mean=spec.u.mean, cov=spec.u.cov, noise_cov=None if spec.v is None else spec.v.cov) if args.numeric else {}
    proof = prove_invariance(spec.model, args.weight, route=args.route, budget=args.budget, progress=True,
                             at=(spec.u, spec.v), **moments)  # a refutation at the file's distribution
    print(proof if proof.holds else _refutation_text(proof, args.out))
    if args.out:
        print(f"wrote {atomic_write_text(args.out, _proof_report(proof))}")
    # liu-li and liu-li-raw are known not to be invariant: a "does not hold" is the expected answer.
    return 0 if proof.holds or args.weight in ("liu-li", "liu-li-raw") else 1


def _refutation_text(proof, out: str | None) -> str:
    """A failed proof in a few lines: the counterexample (where the two sides differ, and by
    how much) instead of the whole difference, which ``--out`` writes."""
    import sympy as sp

    from .invariance import _show_point

    lines = [f"{proof.statement} with weight {proof.weight!r} ({proof.transform}): fails [{proof.seconds:.2f} s]"]
    cex = proof.counterexample or {}
    if "lhs" in cex:
        lhs, rhs = float(cex["lhs"]), float(cex["rhs"])
        rel = f" ({100 * abs(lhs - rhs) / abs(lhs):.2g} % of M²)" if lhs else ""
        lines.append(f"  counterexample: M² = {_num(lhs)} in the old units and {_num(rhs)} in the new units, "
                     f"a difference of {_num(lhs - rhs)}{rel}")
        lines.append(f"  at {_show_point(cex)}")
    elif "difference" in cex:
        lines.append(f"  counterexample: M²(g, u) − M²(ḡ, ū) = {_num(float(cex['difference']))} at a rational point")
    size = sp.count_ops(proof.difference)
    where = f"written to {out}" if out else "--out FILE writes it"
    lines.append(f"  M²(g, u) − M²(ḡ, ū) is a nonzero expression of {size} operations ({where})")
    if proof.lemmas:
        lines.append("  by the lemmas: " + ", ".join(proof.lemmas))
    if proof.assumptions:
        lines.append("  assuming: " + "; ".join(proof.assumptions))
    return "\n".join(lines)


def _proof_report(proof) -> str:
    """Everything a proof found, whole: the verdict, M² on both sides, their difference and
    the counterexample point with every value."""
    lines = [str(proof), "", f"M²(g, u) = {proof.lhs}", "", f"M²(ḡ, ū) = {proof.rhs}", "",
             f"M²(g, u) − M²(ḡ, ū) = {proof.difference}"]
    if proof.counterexample:
        lines += ["", "counterexample:"] + [f"  {k} = {v}" for k, v in proof.counterexample.items()]
    return "\n".join(lines) + "\n"


def cmd_reproduce(args: argparse.Namespace) -> int:
    """``symmon reproduce``: a figure of the papers as PNG + CSV."""
    from .io import check_output_dir

    which = FIGURES if args.figure == "all" else (args.figure,)
    check_output_dir(args.out)
    out = Path(args.out)
    for name in which:
        mod = importlib.import_module(f".reproduce.{name}", __package__)
        kwargs: dict[str, Any] = {"seed": args.seed, "progress": not args.no_progress}
        if args.samples is not None and name != "tracking":
            kwargs["runs" if name == "mmse" else "samples"] = args.samples
        if args.runs is not None and name in ("mmse", "tracking"):
            kwargs["runs"] = args.runs
        for p in mod.run(out, **kwargs):
            print(f"wrote {p}")
    return 0


def cmd_derive(args: argparse.Namespace) -> int:
    """``symmon derive``: run derivation scripts and write a Markdown report."""
    from . import derive
    from .io import atomic_write_text, check_output_file

    if args.list:
        for name in derive.require_available():
            print(name)
        return 0
    check_output_file(args.out)
    names = None if args.all or not args.name else [args.name]
    results = derive.run(names)
    path = atomic_write_text(args.out, derive.report_markdown(results))
    for r in results:
        print(f"{'PASS' if r.passed else 'FAIL'}  {r.name}: {r.title}")
    print(f"wrote {path}")
    return 0 if all(r.passed for r in results) else 1


def cmd_codegen(args: argparse.Namespace) -> int:
    """``symmon codegen``: standalone C code for g, J and the TT2 and UT moments."""
    from .codegen import export_c
    from .io import check_output_dir

    check_output_dir(args.output)
    spec = _load(args.file)
    for p in export_c(spec.model, args.output, args.name):
        print(f"wrote {p}")
    return 0


# --------------------------------------------------------------------------- filter and advise
_DEFAULT_FILTERS = "ekf,ekf2,ukf,ckf,gh,adaptive"


def _filter_names(text: str) -> list[str]:
    """argparse type of ``--filters``: known, distinct short names."""
    from .filterfile import FILTERS

    names = [t.strip() for t in text.split(",") if t.strip()]
    known = tuple(FILTERS) + ("adaptive",)
    bad = [t for t in names if t not in known]
    if not names or bad or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"must be distinct names among {', '.join(known)}, got {text!r}")
    return names


def _unit_interval(text: str) -> float:
    """argparse type of a number in (0, 1)."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}") from None
    if not 0.0 < x < 1.0:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}")
    return x


def cmd_filter(args: argparse.Namespace) -> int:
    """``symmon filter``: a bank of runs of each filter on a scenario; ANEES, ANIS, RMSE."""
    from .filterfile import load_filter_file, run_bank, simulate

    spec = load_filter_file(args.file)
    xs, ys = simulate(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, args.runs, args.seed)
    rows = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, args.filters, args.tol, args.confidence)
    states = [str(s) for s in spec.f.inputs]
    written = [_filter_plot(spec, rows, states, args.plot)] if args.plot else []
    if args.json:
        _print_json({"scenario": spec.name, "runs": args.runs, "steps": spec.steps, "seed": args.seed,
                     "states": states, "filters": [_bank_json(r) for r in rows],
                     "files": [str(p) for p in written]})
        return 0
    ok = [r for r in rows if r.result is not None]
    if ok:
        a, b = ok[0].anees, ok[0].anis
        print(f"{spec.name}: {args.runs} runs of {spec.steps} steps (seed {args.seed}); per-step averages over the "
              f"runs with {a.confidence:.0%} chi-square intervals: ANEES [{a.lower:.3g}, {a.upper:.3g}] "
              f"(n = {len(states)}), ANIS [{b.lower:.3g}, {b.upper:.3g}] (n_y = {spec.h.n_y})")
    print(f"{'filter':<9} {'ANEES':>9} {'inside':>7} {'ANIS':>9} {'inside':>7}  RMSE ({', '.join(states)})")
    for r in rows:
        if r.result is None:
            print(f"{r.name:<9} failed: {r.error}")
            continue
        rmse = np.sqrt(np.mean(r.rmse**2, axis=0))
        print(f"{r.name:<9} {float(np.mean(r.anees.value)):>9.4g} {float(np.mean(r.anees.inside)):>7.0%} "
              f"{float(np.mean(r.anis.value)):>9.4g} {float(np.mean(r.anis.inside)):>7.0%}  "
              + ", ".join(f"{v:.4g}" for v in rmse))
    print("ANEES, ANIS: time averages of the per-step values; inside: the share of steps inside the interval; "
          "RMSE: over runs and steps")
    for p in written:
        print(f"wrote {p}")
    return 0


def _bank_json(r) -> dict:
    if r.result is None:
        return {"name": r.name, "error": r.error}
    out = {"name": r.name, "method": r.result.method,
           "anees": _jsonable(r.anees.value), "anis": _jsonable(r.anis.value),
           "anees_bounds": [r.anees.lower, r.anees.upper], "anis_bounds": [r.anis.lower, r.anis.upper],
           "rmse": _jsonable(r.rmse)}
    if r.result.choices is not None:
        names, counts = np.unique(r.result.choices, return_counts=True)
        out["choices"] = {str(k): int(v) for k, v in zip(names, counts)}
    return out


def _filter_plot(spec, rows, states: list[str], path: str) -> Path:
    """NEES, NIS (log scale, with the χ² intervals) and RMSE per step, one line per filter."""
    from .io import save_figure
    from .reproduce._common import figure_style, pyplot

    plt = pyplot()
    with figure_style():
        fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
        try:
            k = np.arange(1, spec.steps + 1)
            for r in rows:
                if r.result is None:
                    continue
                axes[0].semilogy(k, r.anees.value, label=r.name)
                axes[1].semilogy(k, r.anis.value, label=r.name)
                axes[2].semilogy(k, np.sqrt(np.sum(r.rmse**2, axis=1)), label=r.name)
            ok = [r for r in rows if r.result is not None]
            if ok:
                for ax, t, what in ((axes[0], ok[0].anees, "NEES"), (axes[1], ok[0].anis, "NIS")):
                    ax.axhspan(t.lower, t.upper, color="0.85", label=f"{t.confidence:.0%} interval")
                    ax.set_ylabel(f"average {what}")
            axes[0].set_title(f"{spec.name}: {ok[0].result.runs if ok else 0} Monte Carlo runs")
            axes[2].set_ylabel(f"RMSE of ({', '.join(states)})\n(norm over components)")
            axes[2].set_xlabel("step k")
            axes[0].legend(ncol=3)
            fig.tight_layout()
            return save_figure(fig, path)
        finally:
            plt.close(fig)


def cmd_advise(args: argparse.Namespace) -> int:
    """``symmon advise``: the advice of :func:`symmon.advise` for a model file."""
    from .advise import advise

    spec = _load(args.file)
    a = advise(spec.model, spec.u, spec.v, tol=args.tol, weight=args.weight, samples=args.samples, seed=args.seed)
    if args.json:
        _print_json({"model": spec.model.name, "tol": a.tol, "weight": args.weight, "choice": a.choice_name,
                     "reference": a.reference, "reference_error": a.reference_error,
                     "reference_mon": a.reference_mon, "notes": list(a.notes),
                     "rows": [{k: (repr(v) if k == "transform" else v) for k, v in r.items()} for r in a.rows]})
        return 0
    print(f"{spec.model.name}: {a}")
    return 0


# --------------------------------------------------------------------------- parser
def _parser() -> argparse.ArgumentParser:
    summary = "\n".join(f"  {ex}" for exs in _EXAMPLES.values() for ex in exs)
    p = argparse.ArgumentParser(
        prog="symmon",
        description="Nonlinear transformations of random variables: moments, measures of "
        "nonlinearity, unit invariance, C code and the papers' figures, from TOML model files "
        "(see symmon.modelfile for the format; examples/ holds the papers' models).",
        epilog=f"examples:\n{summary}\n\nexit codes: 0 success, 1 model or input error, 2 usage error",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from . import __version__

    p.add_argument("--version", action="version", version=f"symmon {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name: str, help_: str) -> argparse.ArgumentParser:
        examples = "\n".join(f"  {ex}" for ex in _EXAMPLES[name])
        sp = sub.add_parser(name, help=help_, description=help_, epilog=f"examples:\n{examples}",
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        sp.set_defaults(subparser=sp)
        return sp

    def transform_opts(sp: argparse.ArgumentParser, samples: int) -> None:
        sp.add_argument("--transform", choices=_transform_names(), default="tt2",
                        help="tt1/tt2: Taylor; ut1/ut2/ct: unscented and cubature; gh: Gauss-Hermite; "
                        "mc/qmc: (quasi) Monte Carlo (default tt2)")
        rule_opts(sp, samples)

    def rule_opts(sp: argparse.ArgumentParser, samples: int) -> None:
        """The settings of the Monte Carlo and Gauss-Hermite rules, and where MC runs."""
        sp.add_argument("--samples", type=_samples, default=samples,
                        help=f"Monte Carlo samples (default {samples})")
        sp.add_argument("--seed", type=_seed, default=0, help="Monte Carlo seed, >= 0 (default 0)")
        sp.add_argument("--order", type=_int_in(1, MAX_ORDER), default=5,
                        help=f"Gauss-Hermite order, at most {MAX_ORDER} (default 5)")
        sp.add_argument("--groups", type=_int_in(1, MAX_GROUPS), default=16,
                        help="Monte Carlo groups: independent streams, one task each; the error bars "
                        "come from them (default 16, at least 2)")
        sp.add_argument("--workers", type=_int_in(1, MAX_WORKERS), default=None,
                        help="Monte Carlo threads (default: the number of CPUs)")
        sp.add_argument("--dask", metavar="TARGET", type=_dask_target, default=None,
                        help=f"run the Monte Carlo groups on Dask: {', '.join(DASK_LOCAL)}, or a scheduler "
                        "address such as tcp://host:8786 (needs the 'dask' extra); same result for the same seed")

    def quiet_opt(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("-q", "--quiet", "--no-progress", dest="no_progress", action="store_true",
                        help="no progress on stderr (otherwise a bar on a terminal, a line every "
                        f"{LINE_INTERVAL:g} s elsewhere)")

    def weight_opt(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--weight", choices=WEIGHT_NAMES, default="full",
                        help=f"full: W = Σ_gg⁻¹/n_y, {SH24}, eq. (43); diag: W = diag(Σ_gg)⁻¹/n_y, eq. (42); "
                        "liu-li: the normalised Liu–Li MoN, eq. (8); liu-li-raw: the Liu–Li MSE MoN, eq. (6), "
                        "which has the outputs' units (default full)")

    sp = add("propagate", "moments of a model file by a transform: E y, Cov y, Cov(y, u)")
    sp.add_argument("file", help="TOML model file")
    transform_opts(sp, 10**6)
    sp.add_argument("--json", action="store_true", help="print JSON (full float precision)")
    quiet_opt(sp)
    sp.set_defaults(func=cmd_propagate)

    sp = add("nonlinearity", "the measure of nonlinearity (MoN) of a model file")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    transform_opts(sp, 10**6)
    sp.add_argument("--alpha-sweep", metavar="A:B:N", type=_sweep,
                    help="scale the input covariance by N log-spaced alphas from A to B")
    sp.add_argument("--plot", metavar="PNG", type=_plot_path,
                    help="with --alpha-sweep: write the MoN curve (atomically; .png, .pdf, .svg, ...)")
    sp.add_argument("--csv", metavar="CSV", type=_output_path,
                    help="with --alpha-sweep: write alpha, mon, stderr (atomically)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    quiet_opt(sp)
    sp.set_defaults(func=cmd_nonlinearity)

    sp = add("compare", "the MoN and the moments by every transform, as a table")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    rule_opts(sp, 10**5)
    sp.add_argument("--json", action="store_true", help="print JSON")
    quiet_opt(sp)
    sp.set_defaults(func=cmd_compare)

    sp = add("prove-invariance", "prove the unit invariance of the MoN symbolically (TT2 closed form) under "
             f"the change of units of {SH24}, eq. (18); exit code 1 if a unit-invariant weight fails; a failure "
             "prints a counterexample")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    sp.add_argument("--numeric", action="store_true",
                    help="use the file's mean and covariances instead of symbols (checks regularity there)")
    sp.add_argument("--route", choices=("lemmas", "direct"), default="lemmas",
                    help="lemmas: model-independent lemmas plus per-model checks (seconds); direct: expand M² "
                         "symbolically (small models only, stopped after --budget)")
    sp.add_argument("--budget", type=float, default=10.0, metavar="SECONDS",
                    help="wall-clock limit of the direct route (default 10)")
    sp.add_argument("--out", type=_output_path, default=None, metavar="FILE",
                    help="write the whole proof: M² in both units, their difference and the counterexample")
    sp.set_defaults(func=cmd_prove)

    sp = add("reproduce", f"reproduce a figure of the papers (PNG + CSV): fig1 and fig2 of {SH24}; radar: the "
             "radar example of Gustafsson & Hendeby's lecture 'Parameter Estimation using Nonlinear "
             "Transformations'; mmse: Shin et al. 2020, Sections 4.3 and 7; tracking: EKF consistency against "
             "the MoN (docs/tracking.md)")
    sp.add_argument("figure", choices=FIGURES + ("all",))
    sp.add_argument("--samples", type=_int_in(REPRODUCE_MIN_SAMPLES, MAX_SAMPLES), default=None,
                    help=f"Monte Carlo samples, at least {REPRODUCE_MIN_SAMPLES} (default 10^6; the paper "
                    "used 10^7); for mmse: runs")
    sp.add_argument("--seed", type=_seed, default=0, help="seed, >= 0 (default 0)")
    sp.add_argument("--out", type=_output_path, default="results", help="output directory (default ./results)")
    quiet_opt(sp)
    sp.add_argument("--runs", type=_int_in(1, MAX_RUNS), default=None,
                    help="Monte Carlo runs of mmse and tracking (default: theirs, 1000 and 500)")
    sp.set_defaults(func=cmd_reproduce)

    sp = add("derive", "run the derivation scripts (derivations/) and write a Markdown report")
    g = sp.add_mutually_exclusive_group()
    g.add_argument("--all", action="store_true", help="run every derivation (the default)")
    g.add_argument("--list", action="store_true", help="list the derivation names and exit")
    g.add_argument("name", nargs="?", help="one derivation, by name (see --list)")
    sp.add_argument("--out", type=_output_path, default="derivations-report.md",
                    help="report file (default derivations-report.md)")
    sp.set_defaults(func=cmd_derive)

    sp = add("codegen", "export standalone C code (g, J, TT2 and UT moments)")
    sp.add_argument("file", help="TOML model file")
    sp.add_argument("-o", "--output", type=_output_path, required=True, metavar="DIR",
                    help="output directory (created if missing)")
    sp.add_argument("--name", default=None, help="C prefix and file name (default: the model's name)")
    sp.set_defaults(func=cmd_codegen)

    sp = add("filter", "Monte Carlo runs of nonlinear Kalman filters on a filter scenario file: "
             "NEES, NIS (with chi-square bounds) and RMSE")
    sp.add_argument("file", help="TOML filter scenario (see symmon.filterfile)")
    sp.add_argument("--runs", type=_int_in(1, MAX_RUNS), default=100, help="Monte Carlo runs (default 100)")
    sp.add_argument("--seed", type=_seed, default=0, help="seed of the truth and measurements, >= 0 (default 0)")
    sp.add_argument("--filters", type=_filter_names, default=_filter_names(_DEFAULT_FILTERS),
                    help=f"comma-separated: ekf, ekf2, ukf, ckf, gh, adaptive (default {_DEFAULT_FILTERS})")
    sp.add_argument("--tol", type=_unit_interval, default=1e-2,
                    help="the adaptive filter's tolerance (unitless moment error, default 0.01)")
    sp.add_argument("--confidence", type=_unit_interval, default=0.95,
                    help="of the chi-square intervals (default 0.95)")
    sp.add_argument("--plot", metavar="PNG", type=_plot_path, help="write NEES, NIS and RMSE over time (atomically)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=cmd_filter)

    sp = add("advise", "which transform is good enough for a model file: every candidate's moment "
             "error against a reference, its MoN and cost, and the cheapest within tol")
    sp.add_argument("file", help="TOML model file")
    sp.add_argument("--tol", type=_unit_interval, default=1e-3,
                    help="largest unitless moment error (default 0.001)")
    weight_opt(sp)
    sp.add_argument("--samples", type=_samples, default=10**6,
                    help="samples of the Monte Carlo reference, when Gauss-Hermite does not converge (default 10^6)")
    sp.add_argument("--seed", type=_seed, default=0, help="seed of the Monte Carlo reference, >= 0 (default 0)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=cmd_advise)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``symmon`` command and return its exit code.

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments after the program name; ``sys.argv[1:]`` when omitted.

    Returns
    -------
    int
        0 on success, 1 on a model or input error (or an unexpected exception, reported in
        one line; ``SYMMON_DEBUG=1`` prints its traceback), 2 on a usage error, 130 if
        interrupted, 141 if the reader of stdout went away.
    """
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) and usage errors (2); argparse printed them
        return exc.code if isinstance(exc.code, int) else 2
    catch_sigterm()  # SIGTERM during a compile exits through Python, which kills the compiler
    try:
        with silenced() if getattr(args, "no_progress", False) else contextlib.nullcontext():
            code = int(args.func(args))
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        # The reader of stdout went away (``| head``): stop quietly, like other tools.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except _UsageError as exc:
        args.subparser.print_usage(sys.stderr)
        print(f"symmon {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except (SymmonError, OSError) as exc:
        print(f"symmon: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("symmon: interrupted; no output file was half-written", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, or an input no check foresaw: one line, the traceback on request
        if os.environ.get("SYMMON_DEBUG", "0") not in ("", "0"):
            traceback.print_exc()
        what = "out of memory" if isinstance(exc, MemoryError) else " ".join(str(exc).split())
        print(f"symmon: internal error: {type(exc).__name__}: {what} "
              "(set SYMMON_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
