"""The ``symmon`` command.

Exit codes: 0 on success, 2 on a usage error, 1 on a model or input error (the message
goes to stderr).  Every output file is written atomically.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .errors import SymmonError

__all__ = ["main", "transform_from_name", "TRANSFORM_NAMES"]

TRANSFORM_NAMES = ("tt1", "tt2", "ut1", "ut2", "ct", "gh", "mc", "qmc")
WEIGHT_NAMES = ("full", "diag", "liu-li", "liu-li-raw")
FIGURES = ("fig1", "fig2", "radar", "mmse")


def transform_from_name(name: str, samples: int = 10**6, seed: int = 0, order: int = 5):
    """A transform from its short name (``tt1``, ``tt2``, ``ut1``, ``ut2``, ``ct``, ``gh``, ``mc``, ``qmc``)."""
    from . import transforms as t

    table: dict[str, Callable] = {
        "tt1": t.TT1, "tt2": t.TT2, "ut1": t.UT.ut1, "ut2": t.UT.ut2, "ct": t.UT.cubature,
        "gh": lambda: t.GaussHermite(order),
        "mc": lambda: t.MonteCarlo(samples, seed=seed),
        "qmc": lambda: t.MonteCarlo(samples, seed=seed, qmc=True),
    }
    if name not in table:
        raise SymmonError(f"unknown transform {name!r}; use one of {TRANSFORM_NAMES}")
    return table[name]()


def _load(path: str):
    from .modelfile import load_model_file

    return load_model_file(path)


def _arr(a) -> list:
    return np.asarray(a).tolist()


# --------------------------------------------------------------------------- commands
def cmd_propagate(args) -> int:
    from .propagate import propagate

    spec = _load(args.file)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order)
    m = propagate(spec.model, spec.u, spec.v, tr)
    if args.json:
        out = {"model": spec.model.name, "transform": repr(tr), "mean": _arr(m.mean),
               "cov": _arr(m.cov), "cross_cov": _arr(m.cross_cov)}
        if m.stderr is not None:
            out["stderr"] = {k: _arr(v) for k, v in m.stderr.items()}
        print(json.dumps(out, indent=2))
    else:
        print(f"{spec.model.name} by {tr!r}")
        print(f"E y  = {m.mean}")
        print(f"Cov y =\n{m.cov}")
        print(f"Cov(y, u) =\n{m.cross_cov}")
        if m.stderr is not None:
            print(f"standard error of E y = {m.stderr['mean']}")
    return 0


def _parse_sweep(text: str) -> np.ndarray:
    parts = text.split(":")
    if len(parts) != 3:
        raise SymmonError(f"--alpha-sweep must be A:B:N (log-spaced from A to B), got {text!r}")
    try:
        a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError as exc:
        raise SymmonError(f"--alpha-sweep must be A:B:N with numbers, got {text!r}") from exc
    if a <= 0 or b <= 0 or n < 1:
        raise SymmonError(f"--alpha-sweep needs A, B > 0 and N >= 1, got {text!r}")
    return np.logspace(np.log10(a), np.log10(b), n)


def cmd_nonlinearity(args) -> int:
    from .gaussian import Gaussian
    from .io import save_figure, write_csv
    from .nonlinearity import nonlinearity
    from .reproduce._common import progress_bar, pyplot

    spec = _load(args.file)
    tr = transform_from_name(args.transform, args.samples, args.seed, args.order)
    if args.alpha_sweep is None:
        if args.plot or args.csv:
            raise SymmonError("--plot and --csv need --alpha-sweep")
        res = nonlinearity(spec.model, spec.u, spec.v, args.weight, tr)
        se = f" ± {res.stderr:.2g} (MC standard error)" if res.stderr is not None else ""
        print(f"{spec.model.name}: MoN[{args.weight}] by {tr!r} = {res.value:.6g}{se}")
        for note in res.notes:
            print(f"note: {note}")
        return 0
    alphas = _parse_sweep(args.alpha_sweep)
    rows = []
    for a in progress_bar(alphas, "alpha sweep", not args.no_progress):
        u = Gaussian(spec.u.mean, a * spec.u.cov)
        res = nonlinearity(spec.model, u, spec.v, args.weight, tr)
        rows.append((float(a), res.value, res.stderr if res.stderr is not None else float("nan")))
        print(f"alpha={a:.4g}  MoN={res.value:.6g}")
    if args.csv:
        write_csv(args.csv, ["alpha", "mon", "stderr"], rows)
    if args.plot:
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogx([r[0] for r in rows], [r[1] for r in rows], "o-")
        ax.set_xlabel(r"$\alpha$ (input covariance scale)")
        ax.set_ylabel(f"MoN ({args.weight}, {args.transform})")
        ax.set_title(spec.model.name)
        fig.tight_layout()
        save_figure(fig, args.plot, dpi=120)
        plt.close(fig)
    return 0


def cmd_compare(args) -> int:
    from .nonlinearity import compare, format_table
    from .propagate import propagate

    spec = _load(args.file)
    names = ["tt1", "tt2", "ut1", "ut2", "ct", "gh", "qmc", "mc"]
    trs = [transform_from_name(n, args.samples, args.seed, args.order) for n in names]
    print(f"{spec.model.name}: MoN with weight {args.weight!r}")
    print(format_table(compare(spec.model, spec.u, spec.v, args.weight, trs)))
    print("\nmoments:")
    for n, t in zip(names, trs):
        m = propagate(spec.model, spec.u, spec.v, t)
        print(f"{n:>4}: E y = {np.array2string(m.mean, precision=6)}  diag Cov y = {np.array2string(np.diag(m.cov), precision=6)}")
    return 0


def cmd_prove(args) -> int:
    from .units import prove_invariance

    spec = _load(args.file)
    proof = prove_invariance(spec.model, args.weight)
    print(proof)
    return 0 if proof.holds or args.weight in ("liu-li", "liu-li-raw") else 1


def cmd_reproduce(args) -> int:
    import importlib

    which = FIGURES if args.figure == "all" else (args.figure,)
    out = Path(args.out)
    for name in which:
        mod = importlib.import_module(f".reproduce.{name}", __package__)
        kwargs = {"seed": args.seed, "progress": not args.no_progress}
        if args.samples is not None:
            kwargs["runs" if name == "mmse" else "samples"] = args.samples
        paths = mod.run(out, **kwargs)
        for p in paths:
            print(f"wrote {p}")
    return 0


def cmd_derive(args) -> int:
    from . import derive
    from .io import atomic_write_text

    names = None if args.all or not args.name else [args.name]
    results = derive.run(names)
    report = derive.report_markdown(results)
    atomic_write_text(args.out, report)
    failed = [r.name for r in results if not r.passed]
    for r in results:
        print(f"{'PASS' if r.passed else 'FAIL'}  {r.name}: {r.title}")
    print(f"wrote {args.out}")
    return 1 if failed else 0


def cmd_codegen(args) -> int:
    from .codegen import export_c

    spec = _load(args.file)
    Path(args.output).mkdir(parents=True, exist_ok=True)
    for p in export_c(spec.model, args.output):
        print(f"wrote {p}")
    return 0


# --------------------------------------------------------------------------- parser
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="symmon",
        description="Nonlinear transformations of random variables: moments, measures of "
        "nonlinearity, unit invariance, and the papers' figures.",
        epilog="Example: symmon reproduce fig1   (Figure 1 of Straka & Havlik 2024 into ./results)",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name, help_, example):
        sp = sub.add_parser(name, help=help_, description=help_, epilog=f"Example: {example}",
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        return sp

    def transform_opts(sp, default="tt2"):
        sp.add_argument("--transform", choices=TRANSFORM_NAMES, default=default)
        sp.add_argument("--samples", type=int, default=10**6, help="Monte Carlo samples")
        sp.add_argument("--seed", type=int, default=0)
        sp.add_argument("--order", type=int, default=5, help="Gauss-Hermite order")

    sp = add("propagate", "moments of a model file by a transform", "symmon propagate examples/polar.toml --transform ut1 --json")
    sp.add_argument("file")
    transform_opts(sp)
    sp.add_argument("--json", action="store_true", help="print JSON")
    sp.set_defaults(func=cmd_propagate)

    sp = add("nonlinearity", "the measure of nonlinearity of a model file",
             "symmon nonlinearity examples/gmti.toml --weight full --transform mc --alpha-sweep 0.1:10:11 --csv mon.csv --plot mon.png")
    sp.add_argument("file")
    sp.add_argument("--weight", choices=WEIGHT_NAMES, default="full")
    transform_opts(sp)
    sp.add_argument("--alpha-sweep", metavar="A:B:N", help="scale the input covariance by N log-spaced alphas")
    sp.add_argument("--plot", metavar="PNG")
    sp.add_argument("--csv", metavar="CSV")
    sp.add_argument("--no-progress", action="store_true")
    sp.set_defaults(func=cmd_nonlinearity)

    sp = add("compare", "the MoN and the moments by every transform", "symmon compare examples/polar.toml --samples 100000")
    sp.add_argument("file")
    sp.add_argument("--weight", choices=WEIGHT_NAMES, default="full")
    sp.add_argument("--samples", type=int, default=10**5)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--order", type=int, default=5)
    sp.set_defaults(func=cmd_compare)

    sp = add("prove-invariance", "prove the unit invariance of the MoN symbolically (TT2 closed form)",
             "symmon prove-invariance examples/polar.toml --weight full")
    sp.add_argument("file")
    sp.add_argument("--weight", choices=WEIGHT_NAMES, default="full")
    sp.set_defaults(func=cmd_prove)

    sp = add("reproduce", "reproduce a figure of the papers (PNG + CSV)", "symmon reproduce fig1 --samples 10000000 --out results")
    sp.add_argument("figure", choices=FIGURES + ("all",))
    sp.add_argument("--samples", type=int, default=None,
                    help="Monte Carlo samples (default 10^6; the paper used 10^7); for mmse: runs")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", default="results", help="output directory (default ./results)")
    sp.add_argument("--no-progress", action="store_true")
    sp.set_defaults(func=cmd_reproduce)

    sp = add("derive", "run the derivation scripts and write a Markdown report", "symmon derive --all --out derivations.md")
    g = sp.add_mutually_exclusive_group()
    g.add_argument("--all", action="store_true")
    g.add_argument("name", nargs="?")
    sp.add_argument("--out", default="derivations-report.md")
    sp.set_defaults(func=cmd_derive)

    sp = add("codegen", "export standalone C code (g, J, TT2 and UT moments)", "symmon codegen examples/gmti.toml -o build/gmti")
    sp.add_argument("file")
    sp.add_argument("-o", "--output", required=True)
    sp.set_defaults(func=cmd_codegen)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``symmon`` command; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (SymmonError, OSError) as exc:
        print(f"symmon: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("symmon: interrupted; no output file was half-written", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
