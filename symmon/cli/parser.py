"""The ``symmon`` command: model files in, moments, measures of nonlinearity and reports out.

A user who never writes Python declares a model in a TOML file (:mod:`symmon.files.modelfile`)
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
directories) that can be written: every output option is registered (``output_opt``) and
checked by one function, ``commands.check_outputs``, before the command runs. Error messages go to stderr, results to stdout. Every
output file is written atomically through :mod:`symmon.io` (temporary file, then rename),
so an existing file is replaced whole or left untouched. Progress goes to stderr: a bar on a
terminal, a line every few seconds otherwise (:mod:`symmon.progress`); ``--quiet`` hides it.
Counts (``--samples``, ``--runs``, ...) may be written ``1e6`` when they are integers.

:func:`main` returns the exit code instead of exiting, so it can be called in-process.  This
module is the entry point: the options, their checks, the parser and :func:`main`; the commands
are in :mod:`symmon.cli.commands`, the printing of their results in :mod:`symmon.cli.output`.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import math
import os
import re
import sys
import traceback
from decimal import Decimal, InvalidOperation
from typing import Callable, Sequence

import numpy as np

from ..version import __version__
from ..compile.ccache import catch_sigterm
from ..errors import OutputPathError, SymmonError, UsageError
from ..filters.registry import filter_entry, filter_names
from ..core.discretize import METHODS as SDE_METHODS
from ..measures.advice import DEFAULT_TOL  # one default for advise and the adaptive filter
from ..io import plot_format
from ..reproduce.common import FORMATS
from ..transforms.executor import MAX_WORKER_TIMEOUT, WORKER_TIMEOUT
from ..transforms.registry import DEFAULT  # the API's default transform is the command's
from . import commands
from ..progress import LINE_INTERVAL, silenced

from .options import (
    DASK_LOCAL,
    DASK_SCHEMES,
    FIGURES,
    MAX_GROUPS,
    MAX_ORDER,
    MAX_PARTICLES,
    MAX_RUNS,
    MAX_SAMPLES,
    MAX_SEED,
    MAX_SWEEP_POINTS,
    MAX_VERIFY_POINTS,
    MAX_WORKERS,
    REPRODUCE_MIN_SAMPLES,
    SH24,
    WEIGHT_NAMES,
    transform_names,
)

__all__ = ["main"]

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
    "verify": ["symmon verify examples/verify/lemma1.toml", "symmon verify examples/verify/lemma1.toml --json --points 16"],
    "codegen": ["symmon codegen examples/gmti.toml -o build/gmti"],
    "fit": ["symmon fit examples/rb_bias.toml --param b=0 --param q=0.1 --bound q=1e-6:",
            "symmon fit examples/rb_bias.toml --param b=0 --runs 50 --json"],
    "export": ["symmon export examples/rb_close.toml --filter ukf --out c_export/rb_ukf",
               "symmon export examples/rb_close.toml --filter ekf --out c_export/rb_ekf --name rb_ekf"],
    "filter": ["symmon filter examples/rb_close.toml --runs 500 --plot nees.png",
               "symmon filter examples/rb_close.toml --filters ekf,ukf,adaptive --tol 0.01 --json",
               "symmon filter examples/rb_close.toml --filters ekf,ukf --smooth"],
    "discretize": ["symmon discretize examples/wna_sde.toml --method exact",
                   "symmon discretize examples/wna_sde.toml --json"],
    "cache": ["symmon cache", "symmon cache --json", "symmon cache clear"],
    "advise": ["symmon advise examples/bot.toml --tol 0.001",
               "symmon advise examples/rb_close.toml --filter --runs 32",
               "symmon advise examples/bot.toml --samples-file particles.csv",
               "symmon advise examples/polar.toml --weight diag --json"],
}


# --------------------------------------------------------------------------- option types
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
    try:
        plot_format(_output_path(text))
    except OutputPathError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


_DEFAULT_FILTERS = "ekf,ekf2,ukf,ckf,gh,adaptive"


def _param_start(text: str) -> tuple[str, float]:
    """argparse type of ``--param NAME=START``."""
    name, sep, value = text.partition("=")
    if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name.strip()):
        raise argparse.ArgumentTypeError(f"must be NAME=START, e.g. b=0, got {text!r}")
    try:
        start = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"the starting value must be a number, got {text!r}") from None
    if not math.isfinite(start):
        raise argparse.ArgumentTypeError(f"the starting value must be finite, got {text!r}")
    return name.strip(), start


def _param_bound(text: str) -> tuple[str, tuple[float | None, float | None]]:
    """argparse type of ``--bound NAME=LOW:HIGH`` (either side may be empty)."""
    name, sep, value = text.partition("=")
    parts = value.split(":")
    if not sep or len(parts) != 2 or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name.strip()):
        raise argparse.ArgumentTypeError(f"must be NAME=LOW:HIGH, e.g. q=1e-6: , got {text!r}")
    try:
        lo, hi = (float(p) if p.strip() else None for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"the bounds must be numbers, got {text!r}") from None
    if any(v is not None and math.isnan(v) for v in (lo, hi)):
        raise argparse.ArgumentTypeError(f"the bounds must not be NaN, got {text!r}")
    return name.strip(), (lo, hi)


def _filter_names(text: str) -> list[str]:
    """argparse type of ``--filters``: known, distinct short names."""
    names = [t.strip().lower() for t in text.split(",") if t.strip()]
    known = filter_names(aliases=True, scenario=True)
    bad = [t for t in names if t not in known]
    # "ekf" and "tt1" are one filter: distinct filters, not distinct spellings
    if not names or bad or len({filter_entry(t).name for t in names}) != len(names):
        raise argparse.ArgumentTypeError(f"must be distinct filters among {', '.join(known)}, got {text!r}")
    return names


def _filter_help() -> str:
    """The filters of a scenario file, each with its aliases and summary (the registry's)."""
    parts = []
    for name in filter_names(scenario=True):
        e = filter_entry(name)
        alias = f" ({'/'.join(e.aliases)})" if e.aliases else ""
        table = f"; settings in [{name}]" if e.settings else ""
        parts.append(f"{name}{alias}: {e.summary}{table}")
    return "; ".join(parts)


def _rule_filter(text: str) -> str:
    """argparse type of ``--filter`` of export and fit: a Gaussian filter of one rule."""
    name = text.strip().lower()
    if name not in filter_names(aliases=True, exportable=True):
        raise argparse.ArgumentTypeError(f"must be one of {', '.join(filter_names(aliases=True, exportable=True))}, "
                                         f"got {text!r}")
    return name


def _seconds(text: str) -> float:
    """argparse type of a positive, finite number of seconds."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}") from None
    if not (x > 0 and x < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}")
    return x


def _unit_interval(text: str) -> float:
    """argparse type of a number in (0, 1)."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}") from None
    if not 0.0 < x < 1.0:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}")
    return x


def _dask_seconds(text: str) -> float:
    """argparse type of ``--dask-timeout``: seconds, > 0 and at most a day."""
    try:
        t = float(text)
    except ValueError:
        t = math.nan
    if not 0.0 < t <= MAX_WORKER_TIMEOUT:
        raise argparse.ArgumentTypeError(f"must be seconds, > 0 and at most {MAX_WORKER_TIMEOUT:g}, got {text!r}")
    return t


# --------------------------------------------------------------------------- parser
def _parser() -> argparse.ArgumentParser:
    summary = "\n".join(f"  {ex}" for exs in _EXAMPLES.values() for ex in exs)
    p = argparse.ArgumentParser(
        prog="symmon",
        description="Nonlinear transformations of random variables: moments, measures of "
        "nonlinearity, unit invariance, C code and the papers' figures, from TOML model files "
        "(see symmon.files.modelfile for the format; examples/ holds the papers' models).",
        epilog=f"examples:\n{summary}\n\nexit codes: 0 success, 1 model or input error, 2 usage error",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"symmon {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name: str, help_: str) -> argparse.ArgumentParser:
        examples = "\n".join(f"  {ex}" for ex in _EXAMPLES[name])
        sp = sub.add_parser(name, help=help_, description=help_, epilog=f"examples:\n{examples}",
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        sp.set_defaults(subparser=sp)
        return sp

    def output_opt(sp: argparse.ArgumentParser, *flags: str, kind: str, **kwargs) -> None:
        """An output option of ``kind`` "file", "figure" (a file in a format matplotlib
        writes) or "dir": :func:`main` checks every one (``commands.check_outputs``) before
        the command does any work."""
        action = sp.add_argument(*flags, type=_plot_path if kind == "figure" else _output_path, **kwargs)
        registered = tuple(sp.get_default("outputs") or ())
        sp.set_defaults(outputs=registered + ((action.dest, "dir" if kind == "dir" else "file", flags[-1]),))

    def transform_opts(sp: argparse.ArgumentParser, samples: int) -> None:
        sp.add_argument("--transform", choices=transform_names(), default=DEFAULT,
                        help="tt1/tt2: Taylor; ut1/ut2/ct: unscented and cubature; gh: Gauss-Hermite; "
                        f"mc/qmc: (quasi) Monte Carlo (default {DEFAULT}, as in the Python API)")
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
        dask_opts(sp, "the Monte Carlo groups")

    def dask_opts(sp: argparse.ArgumentParser, what: str) -> None:
        """``--dask`` and ``--dask-timeout``: where ``what`` runs (:func:`executor_of`)."""
        sp.add_argument("--dask", metavar="TARGET", type=_dask_target, default=None,
                        help=f"run {what} on Dask: {', '.join(DASK_LOCAL)}, or a scheduler "
                        "address such as tcp://host:8786 (needs the 'dask' extra); same result for the same seed")
        sp.add_argument("--dask-timeout", metavar="SECONDS", type=_dask_seconds, default=WORKER_TIMEOUT,
                        help="with a --dask address: how long to wait for a worker when the cluster has "
                        f"none (at the start, or after the last one died) before stopping with an error "
                        f"(default {WORKER_TIMEOUT:g})")

    def quiet_opt(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("-q", "--quiet", "--no-progress", dest="no_progress", action="store_true",
                        help="no progress on stderr (otherwise a bar on a terminal, a line every "
                        f"{LINE_INTERVAL:g} s elsewhere)")

    def weight_opt(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--weight", choices=WEIGHT_NAMES, default="full",
                        help=f"full: W = Σ_gg⁻¹/n_y, {SH24}, eq. (43); diag: W = diag(Σ_gg)⁻¹/n_y, eq. (42); "
                        "liu-li: the normalised Liu–Li MoN, eq. (8); liu-li-raw: the Liu–Li MSE MoN, eq. (6), "
                        "which has the outputs' units (default full)")

    def samples_opt(sp: argparse.ArgumentParser, what: str) -> None:
        sp.add_argument("--samples-file", metavar="CSV", default=None,
                        help="particles for u instead of the file's [u]: a CSV with a header naming the "
                        f"model's inputs and an optional 'weight' column, one row a particle; {what}")

    sp = add("propagate", "moments of a model file by a transform: E y, Cov y, Cov(y, u)")
    sp.add_argument("file", help="TOML model file")
    transform_opts(sp, 10**6)
    samples_opt(sp, "the weighted moments of y over them (the transform only integrates non-additive noise)")
    sp.add_argument("--json", action="store_true", help="print JSON (full float precision)")
    quiet_opt(sp)
    sp.set_defaults(func=commands.cmd_propagate)

    sp = add("nonlinearity", "the measure of nonlinearity (MoN) of a model file")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    transform_opts(sp, 10**6)
    samples_opt(sp, "the MoN over them with a jackknife standard error")
    sp.add_argument("--alpha-sweep", metavar="A:B:N", type=_sweep,
                    help="scale the input covariance by N log-spaced alphas from A to B")
    output_opt(sp, "--plot", kind="figure", metavar="PNG",
               help="with --alpha-sweep: write the MoN curve (atomically; .png, .pdf, .svg, ...)")
    output_opt(sp, "--csv", kind="file", metavar="CSV", help="with --alpha-sweep: write alpha, mon, stderr (atomically)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    quiet_opt(sp)
    sp.set_defaults(func=commands.cmd_nonlinearity)

    sp = add("compare", "the MoN and the moments by every transform, as a table")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    rule_opts(sp, 10**5)
    sp.add_argument("--json", action="store_true", help="print JSON")
    quiet_opt(sp)
    sp.set_defaults(func=commands.cmd_compare)

    sp = add("prove-invariance", "prove the unit invariance of the MoN symbolically (TT2 closed form, or a point rule with "
             "--transform) under "
             f"the change of units of {SH24}, eq. (18); exit code 1 if a unit-invariant weight fails; a failure "
             "prints a counterexample")
    sp.add_argument("file", help="TOML model file")
    weight_opt(sp)
    sp.add_argument("--numeric", action="store_true",
                    help="use the file's mean and covariances instead of symbols (checks regularity there)")
    sp.add_argument("--transform", choices=("tt2", "ut", "gh", "mc"), default="tt2",
                    help="the moments whose MoN is proved invariant: tt2 (default; needs g twice differentiable "
                         "at the mean), or a point rule, which evaluates g only (ut: UT family, gh: Gauss-Hermite, "
                         "mc: Monte Carlo; models without noise or with additive noise, lemma route)")
    sp.add_argument("--route", choices=("lemmas", "direct"), default="lemmas",
                    help="lemmas: model-independent lemmas plus per-model checks (seconds); direct: expand M² "
                         "symbolically (small models only, stopped after --budget)")
    sp.add_argument("--budget", type=float, default=10.0, metavar="SECONDS",
                    help="wall-clock limit of the direct route (default 10)")
    output_opt(sp, "--out", kind="file", default=None, metavar="FILE",
               help="write the whole proof: M² in both units, their difference and the counterexample")
    sp.set_defaults(func=commands.cmd_prove)

    sp = add("reproduce", f"reproduce a figure of the papers (PNG + CSV): fig1 and fig2 of {SH24}; radar: the "
             "radar example of Gustafsson & Hendeby's lecture 'Parameter Estimation using Nonlinear "
             "Transformations'; mmse: Shin et al. 2020, Sections 4.3 and 7; tracking: EKF consistency against "
             "the MoN (docs/tracking.md); bot: bearings-only tracking after Arulampalam & Ristic 2000 with the "
             "EKF, UKF, Gaussian-sum and particle filters (docs/bot.md); select: sm.advise_filter on six scenarios of the "
             "literature, its advice against every candidate on fresh runs (docs/select.md)")
    sp.add_argument("figure", choices=FIGURES + ("all",))
    sp.add_argument("--samples", type=_int_in(REPRODUCE_MIN_SAMPLES, MAX_SAMPLES), default=None,
                    help=f"Monte Carlo samples, at least {REPRODUCE_MIN_SAMPLES} (default 10^6; the paper "
                    "used 10^7); for mmse: runs")
    sp.add_argument("--seed", type=_seed, default=0, help="seed, >= 0 (default 0)")
    output_opt(sp, "--out", kind="dir", default="results", help="output directory (default ./results)")
    quiet_opt(sp)
    sp.add_argument("--runs", type=_int_in(1, MAX_RUNS), default=None,
                    help="Monte Carlo runs of mmse, tracking and bot, fresh runs per scenario of select "
                         "(default: theirs, 1000, 500, 200 and 200)")
    sp.add_argument("--particles", type=_int_in(10, MAX_PARTICLES), default=None,
                    help="particles per run of bot's particle filter, at least 10 (default 2000)")
    sp.add_argument("--format", choices=FORMATS, default="png",
                    help="figure format: png (300 dpi, default), or pdf and svg (vector, for a journal)")
    sp.set_defaults(func=commands.cmd_reproduce)

    sp = add("derive", "run the derivation scripts (derivations/) and write a Markdown report")
    g = sp.add_mutually_exclusive_group()
    g.add_argument("--all", action="store_true", help="run every derivation (the default)")
    g.add_argument("--list", action="store_true", help="list the derivation names and exit")
    g.add_argument("name", nargs="?", help="one derivation, by name (see --list)")
    output_opt(sp, "--out", kind="file", default="derivations-report.md", help="report file (default derivations-report.md)")
    sp.set_defaults(func=commands.cmd_derive)

    sp = add("verify", "check the claims of a derivation file (docs/reference/derivationfile.md): each is proved "
             "(exact simplification), refuted (an exact counterexample) or consistent (random points within a "
             "reference's error bound); exit code 1 if a claim is refuted or misses the verdict it expects")
    sp.add_argument("file", help="TOML derivation file")
    sp.add_argument("--points", type=_int_in(1, MAX_VERIFY_POINTS), default=8,
                    help=f"random points per claim, 1 to {MAX_VERIFY_POINTS} (default 8; at most 4 against a numeric reference)")
    sp.add_argument("--seed", type=_seed, default=0, help="seed of the random points, >= 0 (default 0)")
    sp.add_argument("--json", action="store_true", help="print the certificates as JSON")
    sp.set_defaults(func=commands.cmd_verify)

    sp = add("codegen", "export standalone C code (g, J, TT2 and UT moments)")
    sp.add_argument("file", help="TOML model file")
    output_opt(sp, "-o", "--output", kind="dir", required=True, metavar="DIR", help="output directory (created if missing)")
    sp.add_argument("--name", default=None, help="C prefix and file name (default: the model's name)")
    sp.set_defaults(func=commands.cmd_codegen)

    sp = add("fit", "maximum-likelihood fit of a filter scenario's parameters from simulated runs: estimates "
             "with standard errors (exact gradient and Hessian of the log-likelihood)")
    sp.add_argument("file", help="TOML filter scenario (see symmon.files.filterfile)")
    sp.add_argument("--param", type=_param_start, action="append", required=True, metavar="NAME=START",
                    help="a [params] entry to fit and its starting value (repeat for several); the file's "
                    "values are the truth of the simulated runs")
    sp.add_argument("--bound", type=_param_bound, action="append", default=[], metavar="NAME=LOW:HIGH",
                    help="bounds of a fitted parameter; either side may be empty (q=1e-6:)")
    sp.add_argument("--filter", type=_rule_filter, default="ekf",
                    help=f"the filter: {', '.join(filter_names(aliases=True, exportable=True))} (default ekf)")
    sp.add_argument("--runs", type=_int_in(1, MAX_RUNS), default=20, help="simulated runs (default 20)")
    sp.add_argument("--seed", type=_seed, default=0, help="seed of the simulation, >= 0 (default 0)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=commands.cmd_fit)

    sp = add("export", "export a filter of a filter scenario file as standalone C99 for an embedded "
             "target: NAME.c, NAME.h, an example program and NAME_README.md (docs/export.md)")
    sp.add_argument("file", help="TOML filter scenario (see symmon.files.filterfile)")
    sp.add_argument("--filter", type=_rule_filter, default="ukf",
                    help=f"the filter: {', '.join(filter_names(aliases=True, exportable=True))} (default ukf)")
    output_opt(sp, "--out", kind="dir", required=True, metavar="DIR", help="output directory (created if missing)")
    sp.add_argument("--name", default=None,
                    help="C prefix and file name, a C identifier (default: the measurement model's name and the filter)")
    sp.set_defaults(func=commands.cmd_export)

    sp = add("filter", "Monte Carlo runs of nonlinear Kalman filters on a filter scenario file: "
             "NEES, NIS (with chi-square bounds) and RMSE")
    sp.add_argument("file", help="TOML filter scenario (see symmon.files.filterfile)")
    sp.add_argument("--runs", type=_int_in(1, MAX_RUNS), default=100, help="Monte Carlo runs (default 100)")
    sp.add_argument("--seed", type=_seed, default=0, help="seed of the truth and measurements, >= 0 (default 0)")
    sp.add_argument("--filters", type=_filter_names, default=_filter_names(_DEFAULT_FILTERS),
                    help=f"comma-separated names: {_filter_help()} (default {_DEFAULT_FILTERS})")
    sp.add_argument("--tol", type=_unit_interval, default=DEFAULT_TOL,
                    help=f"the adaptive filter's tolerance (unitless moment error, default {DEFAULT_TOL:g}, "
                         "as symmon advise)")
    sp.add_argument("--confidence", type=_unit_interval, default=0.95,
                    help="of the chi-square intervals (default 0.95)")
    sp.add_argument("--smooth", action="store_true",
                    help="also run each filter's RTS smoother and report its ANEES and RMSE")
    dask_opts(sp, "each filter's runs, in shards of runs (one task per thread of the cluster)")
    sp.set_defaults(workers=None)
    quiet_opt(sp)
    output_opt(sp, "--plot", kind="figure", metavar="PNG", help="write NEES, NIS and RMSE over time (atomically)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=commands.cmd_filter)

    sp = add("discretize", "the discretisation of a filter scenario's [sde] table: F(dt) = e^{A dt} and Q(dt) by "
             "Van Loan's integral for the exact method (symbolic, in LaTeX too, and at the file's dt), or the "
             "transition f(x, w; dt) of an approximate method; with the time unit, which scales Q_c")
    sp.add_argument("file", help="TOML filter scenario with an [sde] table (see symmon.files.filterfile)")
    sp.add_argument("--method", choices=SDE_METHODS, default=None,
                    help="the discretisation (default: the file's [sde].method)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=commands.cmd_discretize)

    sp = add("advise", "which transform is good enough for a model file: every candidate's moment "
             "error against a reference, its cost and times, the reference's MoN, and the cheapest within tol; "
             "with --filter, which filter for a filter scenario file's track (symmon.advise_filter: the MoN "
             "along the track, a pilot study, the cheapest credible filter within 10 %% of the best RMSE)")
    sp.add_argument("file", help="TOML model file, or with --filter a TOML filter scenario (see symmon.files.filterfile)")
    sp.add_argument("--filter", action="store_true",
                    help="FILE is a filter scenario: advise the filter for its track (table and one recommendation)")
    sp.add_argument("--runs", type=_int_in(2, MAX_RUNS), default=64,
                    help="with --filter: simulated runs of the pilot study (default 64)")
    sp.add_argument("--budget", type=_seconds, default=None, metavar="SECONDS",
                    help="with --filter: seconds for the pilot; fewer runs when its cost estimate exceeds them")
    sp.add_argument("--tol", type=_unit_interval, default=DEFAULT_TOL,
                    help=f"largest unitless moment error (default {DEFAULT_TOL:g}, as the adaptive filter)")
    weight_opt(sp)
    sp.add_argument("--samples", type=_samples, default=10**6,
                    help="samples of the Monte Carlo reference, when Gauss-Hermite does not converge (default 10^6)")
    sp.add_argument("--seed", type=_seed, default=0,
                    help="seed of the Monte Carlo reference, or with --filter of the simulated runs, >= 0 (default 0)")
    samples_opt(sp, "the MoN over them, and the candidates ranked on their moment-matched Gaussian, "
                "the one a Kalman-type filter would carry")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=commands.cmd_advise)

    sp = add("cache", "the cache of compiled C code: its directory, size, entries and size cap "
             "(SYMMON_CACHE, SYMMON_CACHE_MAX_MB; docs/compile.md), or clear it")
    sp.add_argument("action", nargs="?", choices=("show", "clear"), default="show",
                    help="show (default): the directory, size, number of entries and the cap; clear: remove "
                    "every entry (builds running now are left to finish; a library loaded by a running "
                    "program stays in use there)")
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=commands.cmd_cache)
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
        commands.check_outputs(args)  # every output option, before the command does any work
        with silenced() if getattr(args, "no_progress", False) else contextlib.nullcontext():
            code = int(args.func(args))
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        # The reader of stdout went away (``| head``): stop quietly, like other tools.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except UsageError as exc:
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
