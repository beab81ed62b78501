"""The ``symmon`` command: same numbers as the Python API, help, exit codes and output files.

Most tests call :func:`symmon.cli.main` in-process (it returns the exit code) and read
stdout/stderr with ``capsys``; two run the installed console script as a subprocess.
"""

from __future__ import annotations

import csv
import importlib
import json
import re
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import symmon as sm
from symmon.cli import parser as cli
from symmon.cli import commands as cli_commands
from symmon.cli import options as cli_options
from symmon.files.modelfile import load_model_file

from helpers import DERIVATIONS, EXAMPLES

#: The CLI prints floats with repr precision through JSON, so it must agree with the API
#: to rounding: both run the same deterministic computation (seeded for Monte Carlo).
CLI_API_RTOL = 1e-12
CLI_API_ATOL = 1e-12
#: Small Monte Carlo runs keep the tests fast; the comparison is exact, not statistical.
MC_SAMPLES = 2000
SUBCOMMANDS = ("propagate", "nonlinearity", "compare", "prove-invariance", "reproduce", "derive", "codegen", "export")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def api_transform(name: str) -> sm.Transform:
    return cli_options.transform_from_name(name, samples=MC_SAMPLES, seed=3)


def assert_close(actual, expected) -> None:
    np.testing.assert_allclose(np.asarray(actual, dtype=float), expected, rtol=CLI_API_RTOL, atol=CLI_API_ATOL)


def no_temp_files(directory: Path) -> bool:
    return not [p for p in directory.iterdir() if p.name.endswith(".tmp")]


# --------------------------------------------------------------------------- same numbers as the API
@pytest.mark.parametrize("example", ["polar", "bot", "gmti", "rdcos", "radar"])
@pytest.mark.parametrize("transform", ["tt2", "ut1", "mc"])
def test_propagate_json_equals_the_python_api(capsys, example, transform):
    path = EXAMPLES / f"{example}.toml"
    code, out, err = run(capsys, "propagate", path, "--transform", transform,
                         "--samples", MC_SAMPLES, "--seed", 3, "--json")
    assert (code, err) == (0, "")
    got = json.loads(out)
    spec = load_model_file(path)
    m = sm.propagate(spec.model, spec.u, spec.v, transform=api_transform(transform))
    assert got["model"] == spec.model.name
    assert_close(got["mean"], m.mean)
    assert_close(got["cov"], m.cov)
    assert_close(got["cross_cov"], m.cross_cov)
    assert (got["stderr"] is None) == (m.stderr is None)
    if m.stderr is not None:
        assert_close(got["stderr"]["mean"], m.stderr["mean"])


@pytest.mark.parametrize("weight", ["full", "diag", "liu-li", "liu-li-raw"])
def test_nonlinearity_json_equals_the_python_api(capsys, weight):
    path = EXAMPLES / "gmti.toml"
    code, out, _ = run(capsys, "nonlinearity", path, "--weight", weight, "--transform", "ut1", "--json")
    assert code == 0
    got = json.loads(out)
    spec = load_model_file(path)
    res = sm.nonlinearity(spec.model, spec.u, spec.v, weight=weight, transform=sm.UT.ut1())
    assert_close([got["value"], got["squared"], got["J_Ab"], got["J_n"]], [res.value, res.squared, res.J_Ab, res.J_n])
    assert got["stderr"] is None


def test_nonlinearity_text_output_has_the_value_and_its_standard_error(capsys):
    path = EXAMPLES / "polar.toml"
    code, out, _ = run(capsys, "nonlinearity", path, "--transform", "mc", "--samples", MC_SAMPLES, "--seed", 3)
    spec = load_model_file(path)
    res = sm.nonlinearity(spec.model, spec.u, None, weight="full", transform=api_transform("mc"))
    assert code == 0
    assert f"= {res.value:.6g} ± {res.stderr:.2g} (MC standard error)" in out


def test_compare_prints_every_transform(capsys):
    code, out, err = run(capsys, "compare", EXAMPLES / "polar.toml", "--samples", MC_SAMPLES)
    assert (code, err) == (0, "")
    rows = {line.split()[0] for line in out.splitlines()[2:2 + len(cli_options.transform_names())]}
    assert rows == set(cli_options.transform_names())
    for name in cli_options.transform_names():
        assert f"{name:>4}: {cli_options.transform_from_name(name, MC_SAMPLES)!r}" in out


def test_compare_json_equals_nonlinearity_per_transform(capsys):
    path = EXAMPLES / "bot.toml"
    code, out, _ = run(capsys, "compare", path, "--weight", "diag", "--samples", MC_SAMPLES, "--seed", 3, "--json")
    assert code == 0
    rows = json.loads(out)["rows"]
    assert [r["name"] for r in rows] == list(cli_options.transform_names())
    spec = load_model_file(path)
    for r in rows:
        res = sm.nonlinearity(spec.model, spec.u, spec.v, weight="diag", transform=api_transform(r["name"]))
        assert_close([r["mon"], *r["mean"]], [res.value, *res.moments.mean])


# --------------------------------------------------------------------------- symmon advise
def test_cli_advise_json_equals_the_api(capsys):
    code = cli.main(["advise", str(EXAMPLES / "bot.toml"), "--tol", "0.001", "--weight", "diag", "--json"])
    out = json.loads(capsys.readouterr().out)
    spec = sm.load_model_file(EXAMPLES / "bot.toml")
    a = sm.advise(spec.model, spec.u, spec.v, tol=1e-3, weight="diag")
    assert code == 0
    assert out["choice"] == a.choice_name and out["reference"] == a.reference and out["weight"] == "diag"
    # Deterministic quadrature: the errors agree to rounding (JSON keeps repr precision).
    for mine, theirs in zip(out["rows"], a.rows):
        assert mine["name"] == theirs["name"]
        assert mine["error"] == pytest.approx(theirs["error"], rel=1e-12, abs=1e-15)
        assert mine["mon"] == pytest.approx(theirs["mon"], rel=1e-12, abs=1e-15)
        assert mine["first_call"] >= 0 and mine["warm"] >= 0  # present; their values are timings
    assert out["reference_mon"] == pytest.approx(a.reference_mon, rel=1e-12) and out["reference_mon_stderr"] is None


def test_advise_and_filter_share_the_default_tolerance():
    """``--tol`` of ``symmon advise`` and of ``symmon filter`` default to the one constant of
    sm.advise and sm.Adaptive."""
    from symmon.measures.advice import DEFAULT_TOL

    parser = cli._parser()
    assert parser.parse_args(["advise", "m.toml"]).tol == DEFAULT_TOL
    assert parser.parse_args(["filter", "f.toml"]).tol == DEFAULT_TOL == sm.Adaptive().tol


def test_cli_advise_prints_the_table_and_refuses_a_bad_tol(capsys):
    assert cli.main(["advise", str(EXAMPLES / "bot.toml")]) == 0
    out = capsys.readouterr().out
    assert "TT2" in out and "<- choice" in out and "reference: Gauss-Hermite" in out
    assert "advice for tol = 0.01 " in out and "first call" in out and "by the reference:" in out
    assert cli.main(["advise", str(EXAMPLES / "polar.toml"), "--tol", "2"]) == 2
    assert "must be a number in (0, 1)" in capsys.readouterr().err


# --------------------------------------------------------------------------- help
def test_top_level_help_lists_every_subcommand(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0
    for name in SUBCOMMANDS:
        assert f"\n    {name}" in out          # the command list
        assert f"symmon {name} " in out        # and an example of it


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_subcommand_help_has_an_example(capsys, name):
    code, out, _ = run(capsys, name, "--help")
    assert code == 0
    assert f"usage: symmon {name}" in out
    examples = out.split("examples:\n", 1)[1]
    assert examples.lstrip().startswith(f"symmon {name} ")


# --------------------------------------------------------------------------- exit codes
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "the following arguments are required: COMMAND"),
        (["frobnicate"], "invalid choice: 'frobnicate'"),
        (["propagate"], "the following arguments are required: file"),
        (["propagate", EXAMPLES / "polar.toml", "--transform", "ekf"], "invalid choice: 'ekf'"),
        (["propagate", EXAMPLES / "polar.toml", "--samples", "0"], "must be a positive integer, got '0'"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--weight", "max"], "invalid choice: 'max'"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "1:2"], "must be A:B:N"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0:2:3"], "needs finite A, B > 0"),
        (["nonlinearity", EXAMPLES / "polar.toml", "--csv", "out.csv"], "--plot and --csv need --alpha-sweep"),
        (["derive", "--all", "remarks"], "not allowed with argument"),
        (["codegen", EXAMPLES / "polar.toml"], "the following arguments are required: -o/--output"),
    ],
)
def test_usage_errors_exit_2_with_the_usage_on_stderr(capsys, argv, message):
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert out == ""
    assert "usage: symmon" in err and message in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["propagate", "{tmp}/missing.toml"], "missing.toml: model file not found"),
        (["nonlinearity", "{tmp}/bad.toml"], "unknown function 'system'"),
        (["compare", "{tmp}"], "model file cannot be read"),
        (["derive", "no_such_derivation"], "unknown derivation name(s) ['no_such_derivation']"),
        (["nonlinearity", "{tmp}/lin.toml"], "Σ_gg is singular"),
    ],
)
def test_model_errors_exit_1_with_the_message_on_stderr(capsys, tmp_path, argv, message):
    (tmp_path / "bad.toml").write_text('name = "bad"\ninputs = ["x"]\noutputs = ["system(x)"]\n[u]\nmean = [0]\ncov = 1\n')
    (tmp_path / "lin.toml").write_text(
        'name = "lin"\ninputs = ["x", "y"]\noutputs = ["x + y", "2*x + 2*y"]\n[u]\nmean = [0, 0]\nstd = [1, 1]\n')
    argv = [str(a).replace("{tmp}", str(tmp_path)) for a in argv]
    code, out, err = run(capsys, *argv)
    assert code == 1
    assert out == ""
    assert err.startswith("symmon: error: ") and message in err


@pytest.mark.parametrize("debug", [False, True])
def test_an_unexpected_exception_is_one_line_unless_debugging(capsys, monkeypatch, debug):
    def broken(args):
        raise RuntimeError("an unforeseen\nfailure")

    parser = cli._parser
    monkeypatch.setattr(cli, "_parser", lambda: _with_func(parser(), broken))
    monkeypatch.setenv("SYMMON_DEBUG", "1" if debug else "0")
    code, out, err = run(capsys, "propagate", EXAMPLES / "polar.toml")
    assert (code, out) == (1, "")
    last = "symmon: internal error: RuntimeError: an unforeseen failure (set SYMMON_DEBUG=1 for the traceback)\n"
    assert err.endswith(last)
    assert ("Traceback (most recent call last)" in err) == debug


def _with_func(parser, func):
    parser.set_defaults(func=func)
    for action in parser._subparsers._group_actions:
        for sub in action.choices.values():
            sub.set_defaults(func=func)
    return parser


def test_cli_exits_1_instead_of_printing_nan(tmp_path, capsys):
    f = tmp_path / "sqrt.toml"
    f.write_text('name = "sqrt"\ninputs = ["x"]\noutputs = ["sqrt(x)"]\n\n[u]\nmean = [-1]\ncov = [[1]]\n')
    code = cli.main(["propagate", str(f), "--transform", "ut1"])
    out, err = capsys.readouterr()
    assert code == 1
    assert "nan" not in out.lower()
    assert "sqrt(x)" in err


def test_cli_alpha_sweep_over_the_float_range_exits_1(capsys):
    code = cli.main(["nonlinearity", str(EXAMPLES / "polar.toml"), "--weight", "liu-li", "--transform", "tt2",
                     "--alpha-sweep", "1e-300:1e300:7"])
    out, err = capsys.readouterr()
    assert code == 1
    assert "nan" not in out.lower()
    assert "not finite" in err or "is inf" in err


# --------------------------------------------------------------------------- output files
def test_alpha_sweep_writes_csv_and_png_atomically(capsys, tmp_path):
    csv_path, png_path = tmp_path / "mon.csv", tmp_path / "mon.png"
    csv_path.write_text("old contents\n")               # replaced whole, never appended to
    code, out, err = run(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--weight", "diag",
                         "--alpha-sweep", "0.01:100:5", "--csv", csv_path, "--plot", png_path)
    assert code == 0
    assert err == ""                                     # no progress bar: stderr is not a terminal
    with open(csv_path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["alpha (scale of the input covariance: P = alpha P0)",
                       "MoN with weight diag (42): W = diag(diag Σ_gg)⁻¹ / n_y, by tt2 [unitless]",
                       "Monte Carlo standard error of the MoN (empty for a deterministic transform)"]
    assert all(r[2] == "" for r in rows[1:])
    spec = load_model_file(EXAMPLES / "polar.toml")
    alphas = np.logspace(-2, 2, 5)
    assert_close([float(r[0]) for r in rows[1:]], alphas)
    expected = [sm.nonlinearity(spec.model, sm.Gaussian(spec.u.mean, a * spec.u.cov), None, weight="diag").value
                for a in alphas]
    assert_close([float(r[1]) for r in rows[1:]], expected)
    assert png_path.read_bytes().startswith(PNG_MAGIC)
    assert f"wrote {csv_path}" in out and f"wrote {png_path}" in out
    assert no_temp_files(tmp_path)


def test_a_sweep_that_fails_midway_writes_nothing(capsys, tmp_path, monkeypatch):
    nl = importlib.import_module("symmon.measures.mon")   # the package attribute is the function

    csv_path = tmp_path / "mon.csv"
    csv_path.write_text("previous results\n")
    real, calls = nl.nonlinearity, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise sm.errors.SingularMatrixError("injected failure at the third alpha")
        return real(*args, **kwargs)

    monkeypatch.setattr(nl, "nonlinearity", failing)
    code, _, err = run(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:10:4",
                       "--csv", csv_path, "--plot", tmp_path / "mon.png")
    assert code == 1 and "injected failure at the third alpha" in err
    assert csv_path.read_text() == "previous results\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mon.csv"]


def test_reproduce_writes_png_and_csv(capsys, tmp_path):
    code, out, _ = run(capsys, "reproduce", "fig1", "--samples", MC_SAMPLES, "--out", tmp_path, "--no-progress")
    assert code == 0
    assert (tmp_path / "fig1.png").read_bytes().startswith(PNG_MAGIC)
    from symmon.reproduce.fig1 import COLUMNS

    header = (tmp_path / "fig1.csv").read_text().splitlines()[0].split(",")
    assert header == list(COLUMNS.values())
    assert f"wrote {tmp_path / 'fig1.png'}" in out
    assert no_temp_files(tmp_path)


TINY_DERIVATION = '''
from _common import Result
NAME = "{name}"
TITLE = "two plus two"
SOURCE = "arithmetic"
def check():
    return Result(name=NAME, title=TITLE, source=SOURCE, passed=(2 + 2 == {value}),
                  details=["2 + 2 == {value}"], latex=["2 + 2 = {value}"])
'''


@pytest.fixture
def derivations(tmp_path, monkeypatch):
    """A derivations directory with the real helper and two one-line checks (fast)."""
    d = tmp_path / "derivations"
    d.mkdir()
    shutil.copy(DERIVATIONS / "_common.py", d / "_common.py")
    (d / "sums.py").write_text(TINY_DERIVATION.format(name="sums", value=4))
    (d / "wrong.py").write_text(TINY_DERIVATION.format(name="wrong", value=5))
    monkeypatch.setenv("SYMMON_DERIVATIONS", str(d))
    return d


def test_derive_name_writes_the_markdown_report(capsys, tmp_path, derivations):
    report = tmp_path / "report.md"
    code, out, _ = run(capsys, "derive", "sums", "--out", report)
    assert code == 0
    text = report.read_text()
    assert text.startswith("# symmon derivations")
    assert "1 of 1 checks passed." in text and "## PASS `sums`: two plus two" in text
    assert "PASS  sums: two plus two" in out


def test_derive_all_fails_with_exit_1_when_a_check_fails(capsys, tmp_path, derivations):
    report = tmp_path / "report.md"
    code, out, _ = run(capsys, "derive", "--all", "--out", report)
    assert code == 1
    assert "1 of 2 checks passed." in report.read_text()
    assert "FAIL  wrong" in out


def test_derive_list(capsys, derivations):
    assert run(capsys, "derive", "--list") == (0, "sums\nwrong\n", "")


def test_codegen_writes_c(capsys, tmp_path):
    outdir = tmp_path / "build" / "polar"                 # created if missing
    code, out, _ = run(capsys, "codegen", EXAMPLES / "polar.toml", "-o", outdir)
    assert code == 0
    assert sorted(p.name for p in outdir.iterdir()) == ["polar.c", "polar.h"]
    header = (outdir / "polar.h").read_text()
    for fn in ("polar_g", "polar_tt2", "polar_ut"):
        assert fn in header
    assert f"wrote {outdir / 'polar.c'}" in out


@pytest.mark.parametrize("name", [None, "rb_ekf"])
def test_export_writes_a_filter(capsys, tmp_path, name):
    outdir = tmp_path / "build" / "rb"                 # created if missing
    code, out, _ = run(capsys, "export", EXAMPLES / "rb_close.toml", "--filter", "ekf", "--out", outdir,
                       *(["--name", name] if name else []))
    prefix = name or "rb_close_ekf"
    assert code == 0
    assert sorted(p.name for p in outdir.iterdir()) == sorted(
        [f"{prefix}_README.md", f"{prefix}.c", f"{prefix}.h", f"{prefix}_example.c"])
    header = (outdir / f"{prefix}.h").read_text()
    assert f"int {prefix}_update(double *x, double *P, const double *y, double *loglik);" in header
    assert "EKF" in header and f"wrote {outdir / (prefix + '.c')}" in out


def test_export_refuses_an_unknown_filter(capsys, tmp_path):
    code, _, err = run(capsys, "export", EXAMPLES / "rb_close.toml", "--filter", "adaptive", "--out", tmp_path / "o")
    assert code == 2 and "must be one of ekf, tt1" in err and "'adaptive'" in err
    assert not (tmp_path / "o").exists()


def test_a_filter_and_its_rule_are_one_name_on_the_command_line(capsys, tmp_path):
    """``ut1`` exports the UKF as ``ukf`` does, and ``--filters`` takes rule names (issue 47, item 11)."""
    texts = []
    for name in ("ukf", "ut1"):
        code, _, _ = run(capsys, "export", EXAMPLES / "rb_close.toml", "--filter", name, "--out", tmp_path / name,
                         "--name", "rb")
        assert code == 0
        texts.append((tmp_path / name / "rb.c").read_text())
    assert texts[0] == texts[1]
    code, out, _ = run(capsys, "filter", EXAMPLES / "rb_close.toml", "--runs", "3", "--filters", "tt1,ukf", "--json")
    assert code == 0 and json.loads(out)
    code, _, err = run(capsys, "filter", EXAMPLES / "rb_close.toml", "--runs", "3", "--filters", "ekf,tt1")
    assert code == 2 and "distinct filters" in err


@pytest.mark.parametrize(("weight", "verdict"), [("full", "holds"), ("diag", "holds"), ("liu-li-raw", "fails")])
def test_prove_invariance(capsys, weight, verdict):
    units = pytest.importorskip("symmon.units")
    if not hasattr(units, "prove_invariance"):
        pytest.skip("symmon.units.prove_invariance is not written yet")
    spec = load_model_file(EXAMPLES / "polar.toml")
    proof = units.prove_invariance(spec.model, weight, mean=spec.u.mean, cov=spec.u.cov)
    code, out, _ = run(capsys, "prove-invariance", EXAMPLES / "polar.toml", "--weight", weight, "--numeric")
    assert code == 0                       # liu-li-raw is known not to be invariant: not an error
    assert proof.holds == (verdict == "holds")
    assert f"with weight '{weight}' (tt2): {verdict}" in out


# --------------------------------------------------------------------------- the installed command
SYMMON = Path(sys.executable).with_name("symmon")


@pytest.mark.skipif(not SYMMON.exists(), reason="the console script is not installed (pip install -e .)")
def test_console_script_prints_json(tmp_path):
    proc = subprocess.run([str(SYMMON), "propagate", str(EXAMPLES / "radar.toml"), "--transform", "ut1", "--json"],
                          capture_output=True, text=True, cwd=tmp_path, env={**os.environ, "MPLBACKEND": "Agg"},
                          check=False)
    assert proc.returncode == 0, proc.stderr
    spec = load_model_file(EXAMPLES / "radar.toml")
    assert_close(json.loads(proc.stdout)["mean"], sm.propagate(spec.model, spec.u, transform=sm.UT.ut1()).mean)


@pytest.mark.skipif(not SYMMON.exists(), reason="the console script is not installed (pip install -e .)")
def test_console_script_exit_code_1_on_a_missing_file(tmp_path):
    proc = subprocess.run([str(SYMMON), "compare", "nope.toml"], capture_output=True, text=True, cwd=tmp_path,
                          check=False)
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert proc.stderr == "symmon: error: nope.toml: model file not found\n"


# --------------------------------------------------------------------------- where Monte Carlo runs
def _mc_json(capsys, *extra: str) -> dict:
    code, out, err = run(capsys, "propagate", EXAMPLES / "gmti.toml", "--transform", "mc",
                         "--samples", MC_SAMPLES, "--seed", 3, "--json", *extra)
    assert code == 0, err
    return json.loads(out)


def _numbers(res: dict) -> dict:
    return {k: v for k, v in res.items() if k != "transform"}


@pytest.mark.parametrize("extra, setting", [
    (("--workers", "1"), "workers=1"), (("--workers", "3"), "workers=3"),
    (("--dask", "synchronous"), "scheduler='synchronous'"), (("--dask", "threads"), "scheduler='threads'"),
], ids=lambda e: " ".join(e) if isinstance(e, tuple) else "")
def test_monte_carlo_backends_give_the_same_numbers(capsys, monkeypatch, extra, setting):
    """Threads or a local Dask scheduler: the same groups, merged in the same order."""
    prop = importlib.import_module("symmon.propagation.front")  # the package re-exports the function under this name
    seen, real = [], prop.propagate
    monkeypatch.setattr(prop, "propagate", lambda *a, **k: seen.append(k["executor"]) or real(*a, **k))
    res = _mc_json(capsys, *extra)
    assert setting in repr(seen[0])  # the option reached the executor, not the transform
    assert _numbers(res) == _numbers(_mc_json(capsys))


def test_dask_scheduler_address_gives_the_same_numbers(capsys):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster:
        with distributed.Client(cluster) as watcher:
            remote = _mc_json(capsys, "--dask", cluster.scheduler_address)
            # the groups ran as tasks on the cluster
            assert "run_group_remote" in watcher.run_on_scheduler(
                lambda dask_scheduler: list(dask_scheduler.task_prefixes))
    assert _numbers(remote) == _numbers(_mc_json(capsys))


def test_dask_scheduler_without_workers_is_an_input_error(capsys):
    """It used to wait forever, silently: now --dask-timeout seconds, said on stderr."""
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as cluster:
        code, out, err = run(capsys, "propagate", EXAMPLES / "gmti.toml", "--transform", "mc",
                             "--samples", MC_SAMPLES, "--dask", cluster.scheduler_address, "--dask-timeout", "0.5")
    assert (code, out) == (1, "")
    assert "has no worker; waiting up to 0.5 s for one" in err
    assert f"symmon: error: the Dask cluster at {cluster.scheduler_address} had no worker for 0.5 s" in err


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "1e9", "soon"])
def test_dask_timeout_must_be_seconds(capsys, value):
    code, _, err = run(capsys, "propagate", EXAMPLES / "gmti.toml", "--dask-timeout", value)
    assert code == 2 and "--dask-timeout: must be seconds, > 0 and at most 86400" in err


def test_dask_target_that_is_neither_a_scheduler_nor_an_address(capsys):
    code, _, err = run(capsys, "propagate", EXAMPLES / "gmti.toml", "--transform", "mc", "--dask", "cluster")
    assert code == 2
    assert "--dask takes threads, processes, synchronous or a scheduler address" in err
    assert "not 'cluster'" in err


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "scheduler.example.org:8786", "tls://[::1]:8786",
                                     "tcp://dask_scheduler:8786",
                                     "ucx://10.0.0.1:13337", "inproc://192.0.2.2/11485/1", "processes"])
def test_valid_dask_targets_are_accepted(address):
    assert cli._dask_target(address) == address


def test_unreachable_dask_scheduler_is_an_input_error(capsys, monkeypatch):
    pytest.importorskip("dask.distributed")
    monkeypatch.setattr(cli_options, "DASK_CONNECT_TIMEOUT", 1)
    code, _, err = run(capsys, "nonlinearity", EXAMPLES / "gmti.toml", "--transform", "mc",
                       "--samples", MC_SAMPLES, "--dask", "tcp://127.0.0.1:9")
    assert code == 1
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9 within 1 s" in err


def test_dask_address_that_cannot_connect_is_an_input_error(capsys):
    # tls:// needs a TLS configuration: the connection fails before any network traffic.
    pytest.importorskip("dask.distributed")
    code, out, err = run(capsys, "propagate", EXAMPLES / "polar.toml", "--transform", "mc",
                         "--samples", MC_SAMPLES, "--dask", "tls://127.0.0.1:9")
    assert (code, out) == (1, "")
    assert err.startswith("symmon: error: cannot connect to the Dask scheduler at tls://127.0.0.1:9: ")


def test_workers_must_be_positive(capsys):
    code, _, err = run(capsys, "compare", EXAMPLES / "gmti.toml", "--workers", "0")
    assert code == 2 and "--workers" in err


def test_groups_reach_monte_carlo_and_are_checked(capsys):
    res = _mc_json(capsys, "--groups", "4")
    assert "groups=4" in res["transform"]
    # fewer groups, a different split of the same seed: different (valid) numbers
    assert res["mean"] != _mc_json(capsys)["mean"]
    code, _, err = run(capsys, "propagate", EXAMPLES / "gmti.toml", "--transform", "mc", "--groups", "1")
    assert code == 1 and "groups >= 2" in err


def test_closed_stdout_stops_quietly(capsys, monkeypatch):
    """``symmon ... | head``: the reader goes away; exit 141 with nothing on stderr."""
    r, w = os.pipe()
    os.close(r)  # nobody reads: every write to w fails with EPIPE

    class ClosedPipe:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self):
            return w

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    code = cli.main(["propagate", str(EXAMPLES / "polar.toml"), "--transform", "tt2"])
    monkeypatch.undo()
    os.close(w)
    assert code == 141
    assert capsys.readouterr().err == ""


# --------------------------------------------------------------------------- counts and progress
@pytest.mark.parametrize(("text", "value"), [("1e6", 10**6), ("1E3", 1000), ("2.5e3", 2500), ("100", 100),
                                             ("1e12", 10**12)])
def test_counts_accept_integral_scientific_notation(text, value):
    assert cli._parser().parse_args(["propagate", "m.toml", "--samples", text]).samples == value


@pytest.mark.parametrize(("text", "message"), [("1.5e0", "must be a positive integer (1e6 is allowed), got '1.5e0'"),
                                                ("1e-3", "got '1e-3'"), ("nan", "got 'nan'"), ("inf", "got 'inf'"),
                                                ("1e13", "must be at most 1,000,000,000,000, got '1e13'"),
                                                ("0e0", "must be a positive integer, got '0e0'")])
def test_counts_refuse_fractions_and_keep_the_limits(capsys, text, message):
    code, _, err = run(capsys, "propagate", EXAMPLES / "polar.toml", "--samples", text)
    assert code == 2 and "argument --samples: must be" in err and message in err


@pytest.mark.parametrize("quiet", [False, True])
def test_long_runs_report_progress_lines_unless_quiet(capsys, monkeypatch, quiet):
    from symmon import progress

    monkeypatch.setattr(progress, "LINE_INTERVAL", 0.0)  # every item is "a few seconds" later
    code, out, err = run(capsys, "nonlinearity", EXAMPLES / "polar.toml", "--alpha-sweep", "0.1:10:3",
                         *(["--quiet"] if quiet else []))
    assert code == 0 and out.count("alpha=") == 3
    if quiet:
        assert err == ""
    else:
        assert err.splitlines() == [f"alpha sweep: {k}/3 done after 0 s" for k in (1, 2, 3)]


# --------------------------------------------------------------------------- units
def test_propagate_prints_a_labelled_table_with_the_files_units(capsys):
    path = EXAMPLES / "gmti.toml"
    code, out, err = run(capsys, "propagate", path)
    assert (code, err) == (0, "")
    spec = load_model_file(path)
    m = sm.propagate(spec.model, spec.u, spec.v, transform=sm.TT2())
    lines = out.splitlines()
    assert lines[1].split() == ["output", "E", "y", "sd", "unit", "expression"]
    for i, unit in enumerate(["m", "rad", "m/s"]):
        cells = lines[2 + i].split()
        assert cells[0] == f"y[{i}]" and cells[3] == unit
        np.testing.assert_allclose([float(cells[1]), float(cells[2])], [m.mean[i], np.sqrt(m.cov[i, i])],
                                   rtol=5e-6)  # printed to 6 significant digits
    assert "Cov y (entry i, j in the unit of y[i] times that of y[j]):" in out
    assert lines[lines.index("Cov(y, u) (entry i, j in the unit of y[i] times that of u[j]):") + 1].split() == [
        "x", "[m]", "y", "[m]", "vx", "[m/s]", "vy", "[m/s]"]
    row = next(line for line in lines if line.startswith("y[1] [rad]") and len(line.split()) == 6)
    np.testing.assert_allclose([float(c) for c in row.split()[2:]], m.cross_cov[1], rtol=5e-6, atol=1e-12)


def test_propagate_json_carries_the_units(capsys):
    code, out, _ = run(capsys, "propagate", EXAMPLES / "rdcos.toml", "--json")
    assert code == 0
    assert json.loads(out)["units"] == {"outputs": ["m", "dimensionless"],
                                        "inputs": {"x": "m", "y": "m", "vx": "m/s", "vy": "m/s"}, "noise": {}}


def test_propagate_without_units_says_so(capsys, tmp_path):
    path = tmp_path / "plain.toml"
    path.write_text('name = "plain"\ninputs = ["x"]\noutputs = ["x**2"]\n[u]\nmean = [1]\ncov = [[0.5]]\n', encoding="utf-8")
    code, out, _ = run(capsys, "propagate", path)
    assert code == 0 and out.splitlines()[2].split()[3] == "-"
    assert "has no [units] table" in out
    code, out, _ = run(capsys, "propagate", path, "--json")
    assert json.loads(out)["units"] == {"outputs": [None], "inputs": {"x": None}, "noise": {}}


@pytest.mark.parametrize(("example", "weight", "unit"), [("gmti", "full", "unitless"), ("gmti", "liu-li", "unitless"),
                                                         ("radar", "liu-li-raw", "m"),
                                                         ("gmti", "liu-li-raw", "mixed units of y: m, rad, m/s")])
def test_nonlinearity_says_the_unit_of_the_mon(capsys, example, weight, unit):
    code, out, _ = run(capsys, "nonlinearity", EXAMPLES / f"{example}.toml", "--weight", weight)
    assert code == 0 and out.rstrip().endswith(f"({unit})")
    code, out, _ = run(capsys, "nonlinearity", EXAMPLES / f"{example}.toml", "--weight", weight, "--json")
    assert json.loads(out)["unit"] == unit


def test_compare_flags_rows_whose_error_bar_exceeds_ten_percent(capsys):
    # 40 samples: the Monte Carlo rows of polar are noise (error bars of 18 % and 34 %).
    code, out, _ = run(capsys, "compare", EXAMPLES / "polar.toml", "--samples", "40", "--json")
    assert code == 0
    rows = {r["name"]: r for r in json.loads(out)["rows"]}
    for r in rows.values():
        rel = None if r["stderr"] is None else r["stderr"] / abs(r["mon"])
        assert r["relative_stderr"] == rel and r["flagged"] == (rel is not None and rel > cli_commands.FLAG_RELATIVE_STDERR)
    assert rows["mc"]["flagged"] and not rows["gh"]["flagged"]
    code, out, _ = run(capsys, "compare", EXAMPLES / "polar.toml", "--samples", "40")
    flagged = [line.split()[0] for line in out.splitlines()[2:10] if line.endswith(" !") or " ! " in line]
    assert flagged == [n for n, r in rows.items() if r["flagged"]]
    assert "! the Monte Carlo error bar exceeds 10% of the MoN" in out


def test_compare_prints_one_number_format_with_units(capsys):
    code, out, _ = run(capsys, "compare", EXAMPLES / "gmti.toml", "--samples", MC_SAMPLES)
    assert code == 0
    lines = out.splitlines()
    assert lines[1].split()[:4] == ["MoN", "MC", "s.e.", "s.e./MoN"] and "E y[0] [m]" in lines[1]
    assert "sd y[2] [m/s]" in lines[1]
    for line in lines[2:10]:
        for cell in line.split()[1:]:
            if cell not in ("-", "!") and not cell.endswith("%"):
                assert cell == f"{float(cell):.6g}"  # every number printed to 6 significant digits
    assert "! the Monte Carlo" not in out  # 2000 samples: every error bar is below 10 %


# --------------------------------------------------------------------------- failed proofs
def test_a_failed_proof_prints_a_short_counterexample_and_out_writes_it_whole(capsys, tmp_path):
    from symmon.units import prove_invariance

    spec = load_model_file(EXAMPLES / "gmti.toml")
    proof = prove_invariance(spec.model, "liu-li", at=(spec.u, spec.v))
    out_file = tmp_path / "proof.txt"
    code, out, _ = run(capsys, "prove-invariance", EXAMPLES / "gmti.toml", "--weight", "liu-li", "--out", out_file)
    assert code == 0  # liu-li is known not to be invariant
    lhs, rhs = float(proof.counterexample["lhs"]), float(proof.counterexample["rhs"])
    assert "with weight 'liu-li' (tt2): fails" in out
    assert (f"counterexample: M² = {lhs:.6g} in the old units and {rhs:.6g} in the new units, "
            f"a difference of {lhs - rhs:.6g}") in out
    assert "at S_u = diag(2, 1/3, 5, 1/7)" in out and "mean = [500, 500, 5, 87/10]" in out
    assert str(proof.difference) not in out  # 125 operations: only in the file
    assert f"(written to {out_file})" in out and f"wrote {out_file}" in out
    text = out_file.read_text(encoding="utf-8")
    assert f"M²(g, u) − M²(ḡ, ū) = {proof.difference}\n" in text
    assert f"M²(g, u) = {proof.lhs}\n" in text and "counterexample:\n" in text
    assert no_temp_files(tmp_path)


def test_a_failed_proof_without_out_says_how_to_get_the_expression(capsys):
    code, out, _ = run(capsys, "prove-invariance", EXAMPLES / "polar.toml", "--weight", "liu-li-raw")
    assert code == 0 and "--out FILE writes it" in out and len(out.splitlines()) == 6


@pytest.mark.parametrize("name", ["nonlinearity", "compare", "prove-invariance", "advise"])
def test_help_names_the_paper_of_each_equation_number(capsys, name):
    code, out, _ = run(capsys, name, "--help")
    text = " ".join(out.split())
    assert code == 0 and "Straka & Havlík 2024, eq. (43)" in text
    for eq in ("(42)", "(8)", "(6)"):
        assert f"eq. {eq}" in text


# --------------------------------------------------------------------------- output paths
def test_an_output_file_is_never_the_input_or_a_read_only_file(tmp_path, capsys):
    """Checked before any computation: the model file survives, a read-only file too."""
    import shutil

    model = tmp_path / "polar.toml"
    shutil.copy(EXAMPLES / "polar.toml", model)
    before = model.read_bytes()
    assert cli.main(["nonlinearity", str(model), "--alpha-sweep", "0.1:1:2", "--csv", str(model)]) == 1
    assert "is the input file" in capsys.readouterr().err and model.read_bytes() == before
    locked = tmp_path / "locked.csv"
    locked.write_text("keep me\n")
    locked.chmod(0o444)
    assert cli.main(["nonlinearity", str(model), "--alpha-sweep", "0.1:1:2", "--csv", str(locked)]) == 1
    assert "read-only" in capsys.readouterr().err and locked.read_text() == "keep me\n"
    assert cli.main(["prove-invariance", str(model), "--out", str(model)]) == 1
    assert "is the input file" in capsys.readouterr().err and model.read_bytes() == before


def test_filter_plot_into_a_missing_directory_is_refused_before_the_bank_runs(tmp_path, capsys, monkeypatch):
    from symmon.files import filterfile

    ran = []
    monkeypatch.setattr(filterfile, "run_bank", lambda *a, **k: ran.append(1))
    code = cli.main(["filter", str(EXAMPLES / "rb_close.toml"), "--runs", "2", "--plot", str(tmp_path / "no" / "x.png")])
    assert code == 1 and not ran and "output directory does not exist" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["filter", "--runs", "100000"], ["filter", "--runs", "80000", "--filters", "ukf", "--smooth"],
                                  ["fit", "--param", "b=0", "--runs", "100000"]], ids=["filter", "smooth", "fit"])
def test_a_bank_beyond_memory_is_refused_before_it_is_simulated(capsys, monkeypatch, argv):
    """runs × steps × (truth, measurements and each filter's results) is bounded before the
    simulation: it used to simulate for seconds, then run out of memory in the filter.  (80000
    runs of one UKF fit the limit, 80000 × 40 × 54 numbers; its smoother's 20 more per step do not.)"""
    from symmon.files import filterfile

    simulated = []
    monkeypatch.setattr(filterfile, "simulate", lambda *a, **k: simulated.append(1))
    scenario = EXAMPLES / ("rb_bias.toml" if argv[0] == "fit" else "rb_close.toml")
    code, out, err = run(capsys, argv[0], scenario, *argv[1:])
    assert (code, out, simulated) == (1, "", [])
    assert "exceeds the limit of 2e+08 (1.5 GiB): use fewer runs, steps or filters" in err


def test_fit_recovers_the_files_parameters(capsys):
    import json

    code, out, _ = run(capsys, "fit", EXAMPLES / "rb_bias.toml", "--param", "b=0", "--param", "q=0.1",
                       "--bound", "q=1e-6:", "--json")
    assert code == 0
    doc = json.loads(out)
    for k in ("b", "q"):  # the truth within 4 standard errors (a fixed seed: a deterministic check)
        assert abs(doc["estimates"][k] - doc["truth"][k]) < 4 * doc["std_errors"][k]
    code, text, _ = run(capsys, "fit", EXAMPLES / "rb_bias.toml", "--param", "b=0", "--runs", "5")
    assert code == 0 and "std. error" in text and text.splitlines()[2].startswith("b ")


@pytest.mark.parametrize("argv, match", [
    (["--param", "b"], "must be NAME=START"),
    (["--param", "b=x"], "must be a number"),
    (["--param", "b=0", "--bound", "q=1"], "must be NAME=LOW:HIGH"),
    (["--param", "zz=1"], "'zz' is not in \\[params\\]"),
    (["--param", "b=0", "--param", "b=1"], "each --param names a different parameter"),
    (["--param", "b=0", "--bound", "q=1e-6:"], "a bound for 'q', which is not fitted"),
])
def test_fit_bad_options_are_clear_errors(capsys, argv, match):
    code, _, err = run(capsys, "fit", EXAMPLES / "rb_bias.toml", *argv)
    assert code in (1, 2) and re.search(match, err), err


def test_fit_refuses_a_parameter_of_the_noise_covariance(capsys):
    code, _, err = run(capsys, "fit", EXAMPLES / "rb_close.toml", "--param", "q=0.1")
    assert code == 1 and "[Q]: uses the parameter 'q', which is kept free" in err
