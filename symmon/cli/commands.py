"""The commands of ``symmon``: one function per subcommand, ``cmd_<name>(args) -> exit code``.

:mod:`symmon.cli` parses the options (checked before any computation) and calls one of these;
they load the model file, compute, and print or write through :mod:`symmon.cli.output`.
The heavy modules are imported inside each command, so ``symmon --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ModelError, UsageError
from .options import FIGURES, executor_of, transform_from_name, transform_names
from .output import (
    _bank_json,
    _bytes_text,
    _filter_plot,
    _finite,
    _finite_measure,
    _jsonable,
    _label,
    _measure_json,
    _moments_text,
    _mon_unit,
    _num,
    _print_json,
    _proof_report,
    _refutation_text,
    _units_of,
)
from ..errors import SymmonError

#: ``compare`` flags a row whose Monte Carlo standard error exceeds this share of its MoN.
FLAG_RELATIVE_STDERR = 0.10


def _load(path: str):
    from ..files.modelfile import load_model_file

    return load_model_file(path)


def _inputs(args: argparse.Namespace, spec) -> Any:
    """The distribution of u: the particles of ``--samples-file`` if given, else the file's [u]."""
    if getattr(args, "samples_file", None) is None:
        return spec.u
    from ..files.samplefile import load_samples_file

    return load_samples_file(args.samples_file, spec.model)


def _inputs_read(args: argparse.Namespace) -> list[str]:
    """The files the command reads (an output must be none of them)."""
    paths = [getattr(args, k, None) for k in ("file", "samples_file")]
    if args.command == "derive":  # the scripts it imports
        from .. import derive

        d = derive.derivations_dir()
        paths += [str(p) for p in d.glob("*.py")] if d.is_dir() else []
    return [p for p in paths if p is not None]


def check_outputs(args: argparse.Namespace) -> None:
    """Check every output option of the command, before it does any work.

    The parser registers each output option (``outputs``: destination, kind, flag).  A file
    must be new or a writable regular file, in an existing writable directory, and none of
    the files the command reads; a directory must exist or be creatable, and each file the
    command will write in it (``reproduce``: every figure's files) is checked as a file; no
    two options may name the same file.  The writes themselves are atomic (:mod:`symmon.io`).

    Raises
    ------
    OutputPathError, OSError
        For a path that cannot be written (exit 1).
    UsageError
        When two output options name the same file (exit 2).
    """
    from ..io import check_output_dir, check_output_file

    if getattr(args, "list", False):  # derive --list writes nothing
        return
    inputs = tuple(_inputs_read(args))
    seen: dict[Path, str] = {}
    for dest, kind, flag in getattr(args, "outputs", ()):
        value = getattr(args, dest, None)
        if value is None:
            continue
        real = check_output_dir(value) if kind == "dir" else check_output_file(value, inputs)
        if real in seen:
            raise UsageError(f"{flag} and {seen[real]} name the same file: {value}")
        seen[real] = flag
        if kind == "dir" and real.is_dir():  # the files the command will write in it, now
            for name in _files_in_dir(args):
                seen[check_output_file(real / name, inputs)] = flag


def _files_in_dir(args: argparse.Namespace) -> tuple[str, ...]:
    """The names of the files a command writes into its output directory, where it knows them
    before any work (``reproduce``: each figure's ``OUTPUTS``)."""
    if args.command != "reproduce":
        return ()
    which = FIGURES if args.figure == "all" else (args.figure,)
    from ..reproduce.common import with_format

    return tuple(n for name in which
                 for n in with_format(importlib.import_module(f"symmon.reproduce.{name}").OUTPUTS, args.format))


def cmd_propagate(args: argparse.Namespace) -> int:
    """``symmon propagate``: E y, Cov y and Cov(y, u) by one transform."""
    from ..propagation.front import propagate

    spec = _load(args.file)
    u = _inputs(args, spec)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order, args.groups)
    with executor_of(args) as ex:
        m = propagate(spec.model, u, spec.v, transform=tr, executor=ex)
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


def cmd_nonlinearity(args: argparse.Namespace) -> int:
    """``symmon nonlinearity``: the MoN of a model file, once or over a sweep of α."""
    if args.alpha_sweep is None and (args.plot or args.csv):
        raise UsageError("--plot and --csv need --alpha-sweep")
    if args.alpha_sweep is not None and args.samples_file is not None:
        raise UsageError("--alpha-sweep scales a Gaussian [u]; it cannot scale the particles of --samples-file")
    if args.plot and importlib.util.find_spec("matplotlib") is None:
        raise SymmonError("--plot needs matplotlib: pip install 'symmon[plot]'")
    with executor_of(args) as ex:
        return _nonlinearity(args, ex)


def _sweep_header(weight: str, transform: str, unit: str) -> list[str]:
    """Column names of the α-sweep CSV that say what each column holds."""
    from ..measures.weights import NAMED_WEIGHTS

    w = NAMED_WEIGHTS[weight]
    mon = f"MoN with weight {w.name} {w.equation}: {w.formula}, by {transform} [{unit}]"
    return ["alpha (scale of the input covariance: P = alpha P0)", mon,
            "Monte Carlo standard error of the MoN (empty for a deterministic transform)"]


def _sweep_plot(rows: list[tuple], args: argparse.Namespace, unit: str, name: str) -> Path:
    """The figure of ``nonlinearity --alpha-sweep --plot``: the MoN against α, with ±2 SE
    error bars where the transform has a standard error (Monte Carlo), in the package's
    figure style (no title: the model's name is in the legend; 300 dpi)."""
    from ..reproduce.common import OKABE_ITO, figure_style, legend_outside, plain_log_ticks, pyplot, save_plot

    plt = pyplot()
    with figure_style():
        fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
        try:
            a = np.array([r[0] for r in rows])
            mon = np.array([r[1] for r in rows])
            se = [r[2] for r in rows]
            errors = None if any(s is None for s in se) else 2 * np.array(se, dtype=float)
            ax.errorbar(a, mon, yerr=errors, color=OKABE_ITO["blue"], marker="o", ms=4, mfc="none", capsize=2,
                        label=f"{name}, by {args.transform}" + (", ±2 SE" if errors is not None else ""))
            ax.set_xscale("log")
            plain_log_ticks(ax, "x")
            ax.set_xlabel(r"$\alpha$ (input covariance scale, unitless)")
            ax.set_ylabel(f"MoN ({args.weight}) [{unit}]")
            legend_outside(ax)
            return save_plot(fig, args.plot)
        finally:
            plt.close(fig)


def _nonlinearity(args: argparse.Namespace, ex: Any) -> int:
    from ..core.gaussian import Gaussian
    from ..io import write_csv
    from ..measures.mon import nonlinearity
    from ..reproduce.common import progress_bar

    spec = _load(args.file)
    u = _inputs(args, spec)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order, args.groups)
    unit = _mon_unit(spec, args.weight)
    if args.alpha_sweep is None:
        res = _finite_measure(nonlinearity(spec.model, u, spec.v, weight=args.weight, transform=tr,
                                           executor=ex), "")
        if args.json:
            _print_json({"model": spec.model.name, **_measure_json(res), "unit": unit})
            return 0
        kind = "jackknife standard error of the particles" if args.samples_file else "MC standard error"
        se = f" ± {res.stderr:.2g} ({kind})" if res.stderr is not None else ""
        by = f"over {u!r}" if args.samples_file else f"by {tr!r}"
        print(f"{spec.model.name}: MoN[{args.weight}] {by} = {res.value:.6g}{se} ({unit})")
        for note in res.notes:
            print(f"note: {note}")
        return 0
    # Σ_uu ← α Σ_uu, as in the papers' figures (the noise covariance is kept).
    if not isinstance(spec.u, Gaussian):
        raise UsageError("--alpha-sweep scales the covariance of a Gaussian [u]; this file's [u] is a mixture")
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
        written.append(write_csv(args.csv, _sweep_header(args.weight, args.transform, unit), rows))
    if args.plot:
        written.append(_sweep_plot(rows, args, unit, spec.model.name))
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
    from ..measures.mon import nonlinearity
    from ..reproduce.common import progress_bar

    spec = _load(args.file)
    rows = []
    with executor_of(args) as ex:
        for name in progress_bar(transform_names(), "transforms", not args.no_progress):
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


def _relative(stderr: float | None, value: float) -> float | None:
    """stderr / |value| (inf for a zero value with an error bar), None without an error bar."""
    if stderr is None:
        return None
    return stderr / abs(value) if value != 0 else (0.0 if stderr == 0 else math.inf)


def cmd_prove(args: argparse.Namespace) -> int:
    """``symmon prove-invariance``: the symbolic unit-invariance proof of the MoN."""
    from ..io import atomic_write_text
    from ..units.proofs import prove_invariance

    spec = _load(args.file)
    # --numeric: the file's distributions, made exact: a proof for this u (and v) only.
    moments = dict(mean=spec.u.mean, cov=spec.u.cov, noise_cov=None if spec.v is None else spec.v.cov) if args.numeric else {}
    # The proof is of a Gaussian's MoN; a mixture in the file is checked at its moment-matched
    # Gaussian (the invariance of a mixture's MoN is tested numerically, docs/guide/mixtures.md).
    from ..core.mixture import GaussianMixture

    at = tuple(d.as_gaussian() if isinstance(d, GaussianMixture) else d for d in (spec.u, spec.v))
    proof = prove_invariance(spec.model, args.weight, args.transform, route=args.route, budget=args.budget, progress=True,
                             at=at, **moments)  # a refutation at the file's distribution
    print(proof if proof.holds else _refutation_text(proof, args.out))
    if args.out:
        print(f"wrote {atomic_write_text(args.out, _proof_report(proof))}")
    # liu-li and liu-li-raw are known not to be invariant: a "does not hold" is the expected answer.
    return 0 if proof.holds or args.weight in ("liu-li", "liu-li-raw") else 1


def cmd_reproduce(args: argparse.Namespace) -> int:
    """``symmon reproduce``: a figure of the papers as PNG (or PDF, SVG: ``--format``) + CSV."""
    which = FIGURES if args.figure == "all" else (args.figure,)
    out = Path(args.out)
    for name in which:
        mod = importlib.import_module(f"symmon.reproduce.{name}")
        kwargs: dict[str, Any] = {"seed": args.seed, "progress": not args.no_progress, "fmt": args.format}
        if args.samples is not None and name not in ("tracking", "bot", "select"):
            kwargs["runs" if name == "mmse" else "samples"] = args.samples
        if args.runs is not None and name in ("mmse", "tracking", "bot", "select"):
            kwargs["runs"] = args.runs
        if args.particles is not None and name == "bot":
            kwargs["particles"] = args.particles
        if name == "fig1":  # its numbers beside the paper's (Sec. II-B)
            kwargs["report"] = print
        for p in mod.run(out, **kwargs):
            print(f"wrote {p}")
    return 0


def cmd_derive(args: argparse.Namespace) -> int:
    """``symmon derive``: run derivation scripts and write a Markdown report."""
    from .. import derive
    from ..io import atomic_write_text

    if args.list:
        for name in derive.require_available():
            print(name)
        return 0
    names = None if args.all or not args.name else [args.name]
    results = derive.run(names)
    path = atomic_write_text(args.out, derive.report_markdown(results))
    for r in results:
        print(f"{'PASS' if r.passed else 'FAIL'}  {r.name}: {r.title}")
    print(f"wrote {path}")
    return 0 if all(r.passed for r in results) else 1


def cmd_verify(args: argparse.Namespace) -> int:
    """``symmon verify``: check every claim of a derivation file; 1 if one is refuted (or misses its
    expected verdict)."""
    from ..files.derivationfile import load_derivation_file

    spec = load_derivation_file(args.file)
    rows, ok = [], True
    if not args.json:
        print(f"{spec.title}" + (f" ({spec.source})" if spec.source else ""))
    for claim in spec.claims:
        v = claim.check(args.points, args.seed)
        passes = claim.passes(v)
        ok &= passes
        rows.append({"name": claim.name, "kind": claim.kind, "expected": claim.expected, "passes": passes,
                     **v.to_dict()})
        if not args.json:
            wanted = f", expected {claim.expected}" if claim.expected else ""
            print(f"\n{'PASS' if passes else 'FAIL'}  {claim.name}: {v.verdict}{wanted}")
            print("  " + str(v).replace("\n", "\n  "))
    if args.json:
        _print_json({"file": str(spec.path), "title": spec.title, "source": spec.source, "passed": ok, "claims": rows})
    else:
        counts = {k: sum(r["verdict"] == k for r in rows) for k in ("proved", "consistent", "refuted")}
        print(f"\n{len(rows)} claims: " + ", ".join(f"{n} {k}" for k, n in counts.items())
              + f"; {'all pass' if ok else 'FAILED'}")
    return 0 if ok else 1


def cmd_codegen(args: argparse.Namespace) -> int:
    """``symmon codegen``: standalone C code for g, J and the TT2 and UT moments."""
    from ..codegen.export import export_c

    spec = _load(args.file)
    for p in export_c(spec.model, args.output, args.name):
        print(f"wrote {p}")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    """``symmon fit``: maximum-likelihood estimates of a scenario's parameters from simulated runs."""
    from ..files.filterfile import check_bank, load_filter_file, make_filter, simulate_scenario

    start = dict(args.param)
    if len(start) != len(args.param):
        raise ModelError("each --param names a different parameter")
    spec = load_filter_file(args.file, free=list(start))
    check_bank(spec, args.runs, [args.filter])  # the simulation and the fit's filter at its estimates
    truth = {n: spec.params[n] for n in start}
    steps = spec.step_params or None  # the intervals of irregular [sde] times
    if steps:  # the truth's values and the intervals, as the parameters of the simulation
        _, ys = simulate_scenario(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, args.runs, args.seed,
                                  params={**truth, **steps})
    else:
        f_true, h_true = (m.with_params({str(s): truth[str(s)] for s in m.params}) for m in (spec.f, spec.h))
        _, ys = simulate_scenario(f_true, h_true, spec.Q, spec.R, spec.x0, spec.steps, args.runs, args.seed)
    kf = make_filter(args.filter, spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    res = kf.fit(ys, spec.x0, start, params=steps, bounds=dict(args.bound))
    if args.json:
        _print_json({"scenario": spec.name, "filter": kf.method, "runs": args.runs, "steps": spec.steps,
                     "seed": args.seed, "start": start, "truth": truth, "estimates": res.estimates,
                     "std_errors": res.std_errors, "log_likelihood": res.log_likelihood,
                     "iterations": res.iterations, "at_bound": list(res.at_bound)})
        return 0
    print(f"{spec.name}: {kf.method} on {args.runs} simulated runs of {spec.steps} steps (seed {args.seed}); "
          f"log-likelihood {res.log_likelihood:.6g} after {res.iterations} iterations")
    print(f"{'parameter':<12} {'estimate':>12} {'std. error':>11} {'truth':>10} {'start':>10}")
    for n, v in res.estimates.items():
        flag = "  (at a bound)" if n in res.at_bound else ""
        print(f"{n:<12} {v:>12.6g} {res.std_errors[n]:>11.3g} {truth[n]:>10.6g} {start[n]:>10.6g}{flag}")
    print("std. error: from the observed information (the exact Hessian of the log-likelihood); truth: the "
          "file's value, which simulated the runs")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """``symmon export``: one filter of a scenario file as standalone C (docs/export.md)."""
    from ..files.filterfile import load_filter_file, make_filter
    from ..compile.cnames import c_identifier

    spec = load_filter_file(args.file)
    kf = make_filter(args.filter, spec.f, spec.h, spec.Q, spec.R, settings=spec.settings)
    name = args.name or f"{c_identifier(spec.name, hashed=False)}_{args.filter}"
    for p in kf.export_c(args.out, name):
        print(f"wrote {p}")
    return 0


def cmd_filter(args: argparse.Namespace) -> int:
    """``symmon filter``: a bank of runs of each filter on a scenario; ANEES, ANIS, RMSE."""
    from ..files.filterfile import check_bank, load_filter_file, run_bank, simulate_scenario

    spec = load_filter_file(args.file)
    check_bank(spec, args.runs, args.filters, args.smooth)  # before anything is simulated
    xs, ys = simulate_scenario(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, args.runs, args.seed,
                               params=spec.step_params)  # the intervals of irregular [sde] times
    with executor_of(args) as ex:  # --dask: the banks in shards on Dask, the same numbers
        rows = run_bank(spec.f, spec.h, spec.Q, spec.R, spec.x0, xs, ys, args.filters, args.tol, args.confidence,
                        smooth=args.smooth, settings=spec.settings, executor=ex if args.dask else None,
                        params=spec.step_params)
    states = [str(s) for s in spec.f.inputs]
    written = [_filter_plot(spec, rows, states, args.plot)] if args.plot else []
    if args.json:
        _print_json({"scenario": spec.name, "runs": args.runs, "steps": spec.steps, "seed": args.seed,
                     "states": states, "units": spec.units, "filters": [_bank_json(r) for r in rows],
                     "files": [str(p) for p in written]})
        return 0
    ok = [r for r in rows if r.result is not None and r.anis is not None]
    if ok:
        a, b = ok[0].anees, ok[0].anis
        print(f"{spec.name}: {args.runs} runs of {spec.steps} steps (seed {args.seed}); per-step averages over the "
              f"runs with {a.confidence:.0%} chi-square intervals: ANEES [{a.lower:.3g}, {a.upper:.3g}] "
              f"(n = {len(states)}), ANIS [{b.lower:.3g}, {b.upper:.3g}] (n_y = {spec.h.n_y})")
    labelled = [f"{s} [{spec.unit(s)}]" if spec.unit(s) else s for s in states]
    print(f"{'filter':<9} {'ANEES':>9} {'inside':>7} {'ANIS':>9} {'inside':>7} {'log-lik':>10}  "
          f"RMSE ({', '.join(labelled)})")
    for r in rows:
        if r.result is None:
            print(f"{r.name:<9} failed: {r.error}")
            continue
        rmse = np.sqrt(np.mean(r.rmse**2, axis=0))
        anis = (f"{'-':>9} {'-':>7}" if r.anis is None else  # a Gaussian-sum filter: no ANIS
                f"{float(np.mean(r.anis.value)):>9.4g} {float(np.mean(r.anis.inside)):>7.0%}")
        print(f"{r.name:<9} {float(np.mean(r.anees.value)):>9.4g} {float(np.mean(r.anees.inside)):>7.0%} {anis} "
              f"{float(np.mean(r.result.log_likelihood)):>10.6g}  " + ", ".join(f"{v:.4g}" for v in rmse))
        if args.smooth:
            if r.smoothed is None:
                print(f"{' smoothed':<9} (no RTS smoother for the adaptive filter)")
            else:
                s_rmse = np.sqrt(np.mean(r.smoothed_rmse**2, axis=0))
                print(f"{' smoothed':<9} {float(np.mean(r.smoothed_anees.value)):>9.4g} "
                      f"{float(np.mean(r.smoothed_anees.inside)):>7.0%} {'':>9} {'':>7} {'':>10}  "
                      + ", ".join(f"{v:.4g}" for v in s_rmse))
    print("ANEES, ANIS: time averages of the per-step values; inside: the share of steps inside the interval; "
          "log-lik: the mean over the runs of the log-likelihood of a run's measurements; RMSE: over runs and steps"
          + ("; smoothed: the filter's RTS smoother (its ANEES has the filter's interval)" if args.smooth else ""))
    for p in written:
        print(f"wrote {p}")
    return 0


def _matrix_rows(M) -> list[list[str]]:
    return [[str(M[i, j]) for j in range(M.shape[1])] for i in range(M.shape[0])]


def cmd_discretize(args: argparse.Namespace) -> int:
    """``symmon discretize``: F(dt) and Q(dt) of a scenario's [sde] table, symbolic and at its dt."""
    import sympy as sp

    from ..core.discretize import default_dt, exact_transition
    from ..files.filterfile import load_filter_file

    spec = load_filter_file(args.file)
    if spec.sde is None:
        raise ModelError(f"{spec.path}: has no [sde] table: nothing to discretize (its dynamics are discrete)")
    table, sde = spec.sde, spec.sde.sde
    method = args.method or table.method
    dt = default_dt()
    states = [str(s) for s in sde.states]
    unit = table.time_unit
    values = {s: spec.params[str(s)] for s in sde.params}
    values[dt] = table.dt

    def numeric(M) -> list[list[float]]:
        return np.array(M.subs(values).evalf(), dtype=float).tolist()

    out: dict[str, Any] = {
        "scenario": spec.name, "file": str(spec.path), "method": method, "dt_symbol": str(dt), "dt": table.dt,
        "time_unit": unit, "states": states, "units": {s: spec.unit(s) for s in states if spec.unit(s)},
        "params": {str(s): spec.params[str(s)] for s in sde.params},
        "drift": [str(e) for e in sde.drift], "diffusion": _matrix_rows(sde.diffusion),
        "spectral_density": _matrix_rows(sde.spectral_density)}
    if method == "exact":
        F, c, Q = exact_transition(sde, dt)
        out.update(F=_matrix_rows(F), c=[str(e) for e in c], Q=_matrix_rows(Q),
                   latex={"F": sp.latex(F), "c": sp.latex(c), "Q": sp.latex(Q)},
                   F_at_dt=numeric(F), c_at_dt=[r[0] for r in numeric(c)], Q_at_dt=numeric(Q))
    else:
        f = sde.discretize(method, dt=dt, substeps=table.substeps)
        g = sp.Matrix(f.outputs)
        out.update(transition=[str(e) for e in f.outputs], noise=[str(w) for w in f.noise],
                   substeps=table.substeps, latex={"transition": sp.latex(g)})
    per = unit or "time unit"
    scale = (f"the time unit scales Q_c: Q_c is a density per {per}, so the same process with dt in a unit "
             "1000 times smaller (ms for s) has a Q_c 1000 times smaller, and its F and Q(dt) at the same "
             "physical step are unchanged")
    out["time_unit_note"] = scale
    if args.json:
        _print_json(out)
        return 0
    labelled = [f"{s} [{spec.unit(s)}]" if spec.unit(s) else s for s in states]
    print(f"{spec.name}: {method!r} discretisation of dx = a(x) dt + L dβ, E[dβ dβᵀ] = Q_c dt, over a step dt")
    print(f"states: {', '.join(labelled)}"
          + (f"; params: {', '.join(f'{k} = {v:g}' for k, v in out['params'].items())}" if out["params"] else ""))
    print(f"time unit: {unit or 'not declared ([sde].time_unit)'}; {scale}")
    if method == "exact":
        for label, M, key in (("F(dt) = e^{A dt}", F, "F"), ("c(dt) = ∫₀^dt e^{A s} ds b", c, "c"),
                              ("Q(dt) = ∫₀^dt e^{A s} L Q_c Lᵀ e^{Aᵀ s} ds (Van Loan)", Q, "Q")):
            if key == "c" and all(e == 0 for e in c):
                continue
            print(f"\n{label}:")
            print("  " + sp.pretty(M, use_unicode=True).replace("\n", "\n  "))
            print(f"  LaTeX: {out['latex'][key]}")
        longest = " (the longest of the file's intervals)" if table.intervals else ""
        print(f"\nat dt = {table.dt:g}{' ' + unit if unit else ''}{longest} with the file's params:")
        for key in ("F", "Q"):
            text = np.array2string(np.array(out[f"{key}_at_dt"]), precision=6, separator=", ")
            print(f"  {key} = " + text.replace("\n", "\n      "))
        if out["units"]:
            print("units: F[i, j] has the unit of state i over that of state j, Q[i, j] the unit of state i "
                  "times that of state j")
    else:
        print(f"\nx(t + dt) = f(x, w; dt), w = ({', '.join(out['noise'])}) ~ N(0, I), {table.substeps} sub-step(s):")
        for s_, e in zip(states, out["transition"]):
            print(f"  {s_}: {e}")
        print(f"  LaTeX: {out['latex']['transition']}")
    return 0


def cmd_advise(args: argparse.Namespace) -> int:
    """``symmon advise``: the advice of :func:`symmon.advise` for a model file.

    With ``--samples-file`` the MoN is that of the particles (with its jackknife standard
    error), and the candidates are ranked on the particles' moment-matched Gaussian: the
    N(mean, cov) a Kalman-type filter would carry in place of the cloud.
    """
    from ..measures.advice import advise
    from ..measures.mon import nonlinearity

    if args.filter:
        return _advise_filter(args)
    spec = _load(args.file)
    u = _inputs(args, spec)
    cloud = None
    if args.samples_file is not None:
        cloud = nonlinearity(spec.model, u, spec.v, weight=args.weight)
        u = u.as_gaussian()
    a = advise(spec.model, u, spec.v, tol=args.tol, weight=args.weight, samples=args.samples, seed=args.seed)
    particles = None if cloud is None else {
        "particles": cloud.moments.input.n_samples, "ess": cloud.moments.input.ess, "mon": cloud.value,
        "mon_stderr": cloud.stderr}
    if args.json:
        _print_json({"model": spec.model.name, "tol": a.tol, "weight": args.weight, "choice": a.choice_name,
                     "reference": a.reference, "reference_error": a.reference_error,
                     "reference_mon": a.reference_mon, "reference_mon_stderr": a.reference_mon_stderr,
                     "notes": list(a.notes), "samples": particles,
                     "rows": [{k: (repr(v) if k == "transform" else v) for k, v in r.items()} for r in a.rows]})
        return 0
    if cloud is not None:
        se = "" if cloud.stderr is None else f" ± {cloud.stderr:.2g}"
        print(f"{spec.model.name}: MoN[{args.weight}] over {cloud.moments.input!r} = {cloud.value:.4f}{se}; "
              "the candidates below are ranked on its moment-matched Gaussian N(mean, cov)")
    print(f"{spec.model.name}: {a}")
    return 0


def _advise_filter(args: argparse.Namespace) -> int:
    """``symmon advise FILE --filter``: :func:`symmon.advise_filter` on a filter scenario file."""
    from ..files.filterfile import load_filter_file
    from ..filters.selection import advise_filter

    if args.samples_file is not None:
        raise SymmonError("--samples-file is for a model file; --filter simulates the scenario's own runs")
    spec = load_filter_file(args.file)
    a = advise_filter(spec.f, spec.h, spec.Q, spec.R, spec.x0, spec.steps, tol=args.tol, runs=args.runs,
                      budget=args.budget, seed=args.seed)
    if args.json:
        _print_json({"scenario": spec.name, **a.as_dict()})
        return 0
    print(f"{spec.name}: {a}")
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    """``symmon cache``: the compiled-code cache's directory, size, entries and cap; ``clear``."""
    from ..compile.ccache import cache_info, cache_limit, clear_cache

    if args.action == "clear":
        cache_limit()  # a bad SYMMON_CACHE_MAX_MB is reported here too
        removed, freed, builds = clear_cache()
        directory = cache_info().directory
        if args.json:
            _print_json({"directory": str(directory), "removed": removed, "bytes_freed": freed,
                         "builds_running": builds})
            return 0
        running = f"; {builds} build(s) running now left to finish" if builds else ""
        print(f"removed {removed} entries ({_bytes_text(freed)}) from {directory}{running}")
        return 0
    info = cache_info()
    if args.json:
        _print_json({"directory": str(info.directory), "entries": len(info.entries), "size_bytes": info.size,
                     "limit_bytes": info.limit, "builds_running": info.builds,
                     "libraries": [{"name": e.path.name, "bytes": e.size, "last_used": _utc(e.last_used)}
                                   for e in info.entries]})
        return 0
    cap = ("none (SYMMON_CACHE_MAX_MB=0)" if info.limit is None else
           f"{_bytes_text(info.limit)} (SYMMON_CACHE_MAX_MB; the least recently used entries go first)")
    print(f"directory  {info.directory}")
    print(f"size       {_bytes_text(info.size)}")
    print(f"entries    {len(info.entries)}")
    print(f"cap        {cap}")
    print(f"builds     {info.builds} running")
    return 0


def _utc(t: float) -> str:
    """Seconds since the epoch as an ISO 8601 UTC time, to the second."""
    import datetime

    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc).isoformat(timespec="seconds")
