"""sympy → CasADi conversion, CasADi derivatives, compiled vs VM evaluation, the C cache."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import casadi as ca
import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import special

from symmon.compile import CompiledModel, to_casadi
from symmon.errors import UnsupportedFunctionError

from helpers import ROOT

#: Elementary functions in double precision: a few ulps, relative.
EVAL_RTOL = 1e-12
#: Derivatives: CasADi AD against sympy's symbolic diff evaluated numerically.
DERIV_RTOL = 1e-10

#: Seconds for a subprocess or a background build of a small model.
SUBPROCESS_TIMEOUT = 120

x, y, z = sp.symbols("x y z", real=True)
SYMS = (x, y, z)

# (sympy expression, numpy function of (x, y, z), sampler of valid points)
_POS = lambda r, n: np.column_stack([r.uniform(0.2, 3.0, n), r.uniform(0.2, 3.0, n), r.uniform(0.2, 3.0, n)])  # noqa: E731
_ANY = lambda r, n: r.uniform(-3.0, 3.0, (n, 3))  # noqa: E731
_UNIT = lambda r, n: r.uniform(-0.95, 0.95, (n, 3))  # noqa: E731

CASES = {
    "add": (x + y - z + 2, lambda a, b, c: a + b - c + 2, _ANY),
    "mul": (3 * x * y * z, lambda a, b, c: 3 * a * b * c, _ANY),
    "div": (x / (y + 4), lambda a, b, c: a / (b + 4), _ANY),
    "int_pow": (x**3 - y**-2, lambda a, b, c: a**3 - b**-2.0, _POS),
    "rational_pow": (x ** sp.Rational(2, 3) + y ** sp.Rational(-3, 2), lambda a, b, c: a ** (2 / 3) + b**-1.5, _POS),
    "symbolic_pow": (x**y, lambda a, b, c: a**b, _POS),
    "sqrt": (sp.sqrt(x**2 + y**2) + 1 / sp.sqrt(z), lambda a, b, c: np.sqrt(a**2 + b**2) + 1 / np.sqrt(c), _POS),
    "exp": (sp.exp(-x * y), lambda a, b, c: np.exp(-a * b), _ANY),
    "log": (sp.log(x) + sp.log(y, 10), lambda a, b, c: np.log(a) + np.log10(b), _POS),
    "trig": (sp.sin(x) * sp.cos(y) + sp.tan(z), lambda a, b, c: np.sin(a) * np.cos(b) + np.tan(c), _UNIT),
    "reciprocal_trig": (sp.cot(x) + sp.sec(y) + sp.csc(z), lambda a, b, c: 1 / np.tan(a) + 1 / np.cos(b) + 1 / np.sin(c), _POS),
    "inverse_trig": (sp.asin(x) + sp.acos(y) + sp.atan(3 * z), lambda a, b, c: np.arcsin(a) + np.arccos(b) + np.arctan(3 * c), _UNIT),
    "atan2": (sp.atan2(y, x), lambda a, b, c: np.arctan2(b, a), _ANY),
    "hyperbolic": (sp.sinh(x) + sp.cosh(y) * sp.tanh(z), lambda a, b, c: np.sinh(a) + np.cosh(b) * np.tanh(c), _ANY),
    "inverse_hyperbolic": (sp.asinh(x) + sp.acosh(y + 4) + sp.atanh(z / 4), lambda a, b, c: np.arcsinh(a) + np.arccosh(b + 4) + np.arctanh(c / 4), _ANY),
    "abs_sign": (sp.Abs(x) * sp.sign(y), lambda a, b, c: np.abs(a) * np.sign(b), _ANY),
    "min_max": (sp.Max(x, y, z) - sp.Min(x, 2 * y), lambda a, b, c: np.maximum(np.maximum(a, b), c) - np.minimum(a, 2 * b), _ANY),
    "piecewise": (
        sp.Piecewise((x**2, x < 0), (sp.sin(y), (x < 1) & (y > 0)), (z, True)),
        lambda a, b, c: np.where(a < 0, a**2, np.where((a < 1) & (b > 0), np.sin(b), c)),
        _ANY,
    ),
    "constants": (sp.pi * x + sp.E + sp.Rational(1, 3), lambda a, b, c: np.pi * a + np.e + 1 / 3, _ANY),
    "erf_floor": (sp.erf(x) + sp.floor(y) + sp.ceiling(z), lambda a, b, c: special.erf(a) + np.floor(b) + np.ceil(c), _ANY),
}


@pytest.fixture(scope="module")
def points_rng():
    return np.random.default_rng(1)


@pytest.mark.parametrize("case", sorted(CASES))
def test_converter_against_numpy(case, points_rng):
    expr, ref, sampler = CASES[case]
    W = sampler(points_rng, 200)
    cm = CompiledModel([expr], SYMS, name=f"conv_{case}", compiled=False)
    got = cm.eval_g(W)[:, 0]
    np.testing.assert_allclose(got, ref(W[:, 0], W[:, 1], W[:, 2]), rtol=EVAL_RTOL, atol=1e-14)


@pytest.mark.parametrize(
    ("expr", "name"),
    [(sp.gamma(x), "gamma"), (sp.besselj(0, x), "besselj"), (sp.zeta(x), "zeta"), (x + sp.I, "ImaginaryUnit")],
)
def test_unsupported_function_is_named(expr, name):
    with pytest.raises(UnsupportedFunctionError, match=name):
        CompiledModel([expr], [x], compiled=False)


def test_unsupported_function_is_a_model_error():
    with pytest.raises(ValueError):
        CompiledModel([sp.loggamma(x)], [x], compiled=False)


def test_to_casadi_rejects_undeclared_symbols():
    import casadi as ca

    with pytest.raises(UnsupportedFunctionError, match="unknown symbol y"):
        to_casadi([x + y], [x], ca.SX.sym("w", 1))


# --------------------------------------------------------------------------- derivatives
DERIV_MODELS = {
    "polar": [sp.sqrt(x**2 + y**2), sp.atan2(y, x)],
    "mixed": [sp.sin(x) * y + sp.exp(sp.Rational(1, 10) * z), x * y * z / (1 + y**2), sp.log(1 + x**2) * sp.cos(z)],
}


@pytest.mark.parametrize("name", sorted(DERIV_MODELS))
def test_casadi_derivatives_match_sympy(name, points_rng):
    exprs = DERIV_MODELS[name]
    cm = CompiledModel(exprs, SYMS, name=f"deriv_{name}", compiled=False)
    W = points_rng.uniform(0.3, 2.0, (25, 3))
    y_ca, J_ca, H_ca = cm.eval_gjh(W)
    G = sp.Matrix(exprs)
    Jsym = G.jacobian(SYMS)
    Hsym = [sp.hessian(e, SYMS) for e in exprs]
    f_g = sp.lambdify(SYMS, G, "numpy")
    f_J = sp.lambdify(SYMS, Jsym, "numpy")
    f_H = sp.lambdify(SYMS, Hsym, "numpy")
    for k, w in enumerate(W):
        np.testing.assert_allclose(y_ca[k], np.asarray(f_g(*w), float).ravel(), rtol=DERIV_RTOL)
        np.testing.assert_allclose(J_ca[k], np.asarray(f_J(*w), float), rtol=DERIV_RTOL, atol=1e-13)
        np.testing.assert_allclose(H_ca[k], np.asarray(f_H(*w), float), rtol=DERIV_RTOL, atol=1e-13)


def test_eval_gjh_layout_is_row_major_per_point():
    # Asymmetric Jacobian and Hessian entries catch a transposed reshape.
    cm = CompiledModel([x**2 * y, 5 * z + x * z**3], SYMS, name="layout", compiled=False)
    _, J, H = cm.eval_gjh(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_array_equal(J[0], [[4.0, 1.0, 0.0], [27.0, 0.0, 5.0 + 27.0]])
    np.testing.assert_array_equal(H[0, 0], [[4.0, 2.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(H[0, 1], [[0.0, 0.0, 27.0], [0.0, 0.0, 0.0], [27.0, 0.0, 18.0]])


# --------------------------------------------------------------------------- compiled vs VM
@pytest.mark.parametrize("n_points", [1, 7, 8192 + 5])  # exact-size map, and chunks plus a padded tail
def test_compiled_and_vm_agree(n_points, points_rng):
    exprs = DERIV_MODELS["mixed"]
    c = CompiledModel(exprs, SYMS, name="cmp_c", compiled=True)
    vm = CompiledModel(exprs, SYMS, name="cmp_vm", compiled=False)
    if not c.compiled:
        pytest.skip("no C compiler")
    W = points_rng.uniform(0.3, 2.0, (n_points, 3))
    np.testing.assert_allclose(c.eval_g(W), vm.eval_g(W), rtol=EVAL_RTOL)
    for a, b in zip(c.eval_gjh(W[:50]), vm.eval_gjh(W[:50])):
        np.testing.assert_allclose(a, b, rtol=EVAL_RTOL, atol=1e-14)


def test_row_spans_split_a_large_batch_on_the_main_thread_only():
    import threading

    from symmon.compile.compiled import MIN_ROWS_PER_THREAD, cpu_count, row_spans

    assert row_spans(10) == [(0, 10)]
    N = 4 * MIN_ROWS_PER_THREAD + 3
    spans = row_spans(N)
    assert len(spans) == min(cpu_count(), 4)
    assert spans[0][0] == 0 and spans[-1][1] == N and all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    inside: list = []
    t = threading.Thread(target=lambda: inside.append(row_spans(N)))
    t.start()
    t.join()
    assert inside == [[(0, N)]]  # a worker thread's pool already uses the cores


def test_cpu_count_is_read_once_and_at_most_the_affinity_mask(monkeypatch):
    """os.cpu_count() counts the machine's CPUs; a process confined to some (a container, a
    batch job) gets at most those: a compiled loop starts no more threads than can run."""
    from symmon.compile.compiled import MIN_ROWS_PER_THREAD, cpu_count, row_spans

    calls: list = []
    monkeypatch.setattr(os, "cpu_count", lambda: calls.append(1) or 3)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 5}, raising=False)
    assert cpu_count() == 3 and cpu_count() == 3 and len(calls) == 1
    assert len(row_spans(8 * MIN_ROWS_PER_THREAD)) == 3 and len(calls) == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {4}, raising=False)
    assert cpu_count() == 1 and len(row_spans(8 * MIN_ROWS_PER_THREAD)) == 1
    monkeypatch.setattr(os, "cpu_count", lambda: None)  # os.cpu_count's "unknown"
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    assert cpu_count() == 1
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)  # macOS and Windows have none
    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert cpu_count() == 6



def test_compiled_loops_share_one_pool_whose_threads_keep_their_work_arrays():
    """A call starts no thread: the pool's threads serve every call, so each keeps its work
    arrays; the arrays of two threads are on their own cache lines."""
    import threading
    import time

    from symmon.compile.compiled import CACHE_LINE, WorkArrays, in_threads

    a = ca.SX.sym("a", 3)
    work = WorkArrays(ca.Function("wa", [a], [ca.sin(a) * a]))
    seen: dict[int, tuple[int, int]] = {}

    def part(_):
        time.sleep(0.01)  # so that both items do not run on one thread
        seen.setdefault(threading.get_ident(), work.addresses())
        assert seen[threading.get_ident()] == work.addresses()
        return 0

    def pool_threads() -> set[int]:
        return {t.ident for t in threading.enumerate() if t.name.startswith("symmon-c")}

    # The pool's size is the CPU count when it was made (another test may have patched it):
    # warm it with more items than it has threads, then a call must start none.
    assert in_threads(part, list(range(8))) == [0] * 8
    before = pool_threads()
    assert in_threads(part, list(range(8))) == [0] * 8
    assert pool_threads() == before and set(seen) <= before  # the same threads, the same arrays
    for iw, w in seen.values():
        assert iw % CACHE_LINE == 0 and w % CACHE_LINE == 0


def test_padded_arrays_own_their_cache_lines():
    from symmon.compile.compiled import CACHE_LINE, padded

    for n in (1, 7, 8, 9, 100):
        for dtype in (np.float64, np.int64):
            a = padded(n, dtype)
            assert a.shape == (n,) and a.dtype == dtype and not a.any()
            assert a.ctypes.data % CACHE_LINE == 0
            end = a.ctypes.data + a.nbytes  # the rest of the last line belongs to a
            assert a.base.ctypes.data + a.base.nbytes >= -(-end // CACHE_LINE) * CACHE_LINE


def test_a_forked_child_makes_its_own_pool():
    if not hasattr(os, "fork"):
        pytest.skip("no fork")
    from symmon.compile.compiled import in_threads

    import signal
    import warnings

    assert in_threads(lambda i: i, [0, 1]) == [0, 1]  # the parent's pool exists
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # Python >= 3.12: fork of a threaded process
        pid = os.fork()
    if pid == 0:  # the child: a pool without threads would hang here, until the alarm
        signal.alarm(60)
        os._exit(0 if in_threads(lambda i: i + 1, [0, 1]) == [1, 2] else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_a_batch_split_over_threads_equals_one_row_at_a_time(points_rng):
    """The spans of a parallel evaluation write their own rows: the same numbers as one call per row."""
    from symmon.compile.compiled import MIN_ROWS_PER_THREAD

    c = CompiledModel(DERIV_MODELS["mixed"], SYMS, name="cmp_threads", compiled=True)
    if not c.compiled:
        pytest.skip("no C compiler")
    W = points_rng.uniform(0.3, 2.0, (2 * MIN_ROWS_PER_THREAD + 11, 3))
    whole = c.eval_g(W)
    picks = [0, MIN_ROWS_PER_THREAD - 1, MIN_ROWS_PER_THREAD, MIN_ROWS_PER_THREAD + 6, len(W) - 1]
    np.testing.assert_array_equal(whole[picks], np.vstack([c.eval_g(W[i:i + 1]) for i in picks]))


def test_batch_shape_is_checked():
    from symmon.errors import ShapeError

    cm = CompiledModel([x * y], [x, y], name="shape", compiled=False)
    with pytest.raises(ShapeError, match=r"batch must have shape \(N, 2\)"):
        cm.eval_g(np.zeros((4, 3)))


# --------------------------------------------------------------------------- subprocesses
def _run(script: str, env_extra: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.update(env_extra)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], env=env, capture_output=True, text=True, timeout=120)


def test_no_compile_warns_exactly_once(tmp_path):
    script = """
    import warnings
    import numpy as np, sympy as sp, symmon as sm
    x, y = sp.symbols("x y")
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        u = sm.Gaussian([1.0, 2.0], np.eye(2))
        sm.propagate(sm.Model([x, y], [x * y]), u, transform=sm.UT.ut1())
        sm.propagate(sm.Model([x, y], [x + sp.sin(y)]), u, transform=sm.GaussHermite(3))
    msgs = [str(w.message) for w in rec if issubclass(w.category, RuntimeWarning)]
    print(len(rec), len(msgs))
    print(msgs[0] if msgs else "")
    """
    res = _run(script, {"SYMMON_NO_COMPILE": "1", "SYMMON_CACHE": str(tmp_path)})
    assert res.returncode == 0, res.stderr
    counts, message = res.stdout.splitlines()[:2]
    assert counts == "1 1"
    assert "no C compiler" in message and "SYMMON_NO_COMPILE" in message
    assert not list(tmp_path.glob("*.so"))


def test_disk_cache_is_keyed_by_content_and_reused(tmp_path):
    from symmon.compile import has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    script = """
    import sys
    import numpy as np, sympy as sp, symmon as sm, symmon.compile.ccache as sc
    x, y = sp.symbols("x y")
    u = sm.Gaussian([1.0, 2.0], np.eye(2))
    run = sc._run_compiler
    if sys.argv[-1] == "second":  # a cache hit must not run the compiler again
        def fail(*a, **k):
            raise AssertionError("compiler invoked despite a cached library")
        sc._run_compiler = fail
    m = sm.propagate(sm.Model([x, y], [x * y, sp.exp(x)]), u, transform=sm.UT.ut1())
    print(repr(m.mean.tolist()))
    if sys.argv[-1] == "second":  # different content: a new library
        sc._run_compiler = run
        sm.propagate(sm.Model([x, y], [x * y, sp.exp(y)]), u, transform=sm.UT.ut1())
    """
    env = {"SYMMON_CACHE": str(tmp_path)}
    first = _run(script, env, "first")
    assert first.returncode == 0, first.stderr
    # The file (inode) and its bytes: a load sets the modification time (the entry's last use).
    libs = {p.name: (p.stat().st_ino, p.read_bytes()) for p in tmp_path.glob("*.so")}
    assert libs, "no shared library in the cache"
    second = _run(script, env, "second")
    assert second.returncode == 0, second.stderr
    assert second.stdout == first.stdout
    after = {p.name: (p.stat().st_ino, p.read_bytes()) for p in tmp_path.glob("*.so")}
    assert {k: after[k] for k in libs} == libs  # reused, not rewritten (an install is a new file)
    assert len(after) > len(libs)


# --------------------------------------------------------------------------- names
@pytest.mark.parametrize("name", ["polar (rad)", "a_", "range & bearing", "a__b", "9", "", "Ångström", "null", "jac"])
def test_ordinary_names_compile(name):
    """Issue 13: these crashed in CasADi ("non-consecutive underscores")."""
    import symmon as sm

    model = sm.Model([x, y], [x * y, x + y], name=name)
    m = sm.propagate(model, sm.Gaussian([1.0, 2.0], np.eye(2)), transform=sm.TT2())
    np.testing.assert_allclose(m.mean, [2.0, 3.0], rtol=EVAL_RTOL)
    assert model.name == (name or "model")


@settings(max_examples=40, deadline=None)
@given(st.text(st.characters(blacklist_categories=("Cs",)), max_size=80))
def test_any_text_is_a_valid_function_name(text):
    from symmon.compile.cnames import HASH_DIGITS, MAX_STEM, c_identifier, is_casadi_name

    tag = c_identifier(text)
    assert is_casadi_name(tag) and len(tag) <= MAX_STEM + 1 + HASH_DIGITS
    assert c_identifier(text + "!") != tag  # unique through the hash of the original
    cm = CompiledModel([x * y], [x, y], name=text, compiled=False)  # CasADi accepts every name
    assert cm.name == text and cm.g.name() == f"{cm.tag}_g"


# --------------------------------------------------------------------------- compile policy
#: The VM and the compiled row loop run the same operations in the same order, and the
#: build disables FMA contraction: equal to the last bit, asked to 1e-15 relative.
VM_C_RTOL = 1e-15


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SYMMON_CACHE", str(tmp_path))
    return tmp_path


def _count_builds(monkeypatch) -> list[list[str]]:
    import symmon.compile.ccache as cc

    calls: list[list[str]] = []
    real = cc._run_compiler

    def counting(cmd, tmp):
        calls.append(cmd)
        return real(cmd, tmp)

    monkeypatch.setattr(cc, "_run_compiler", counting)
    return calls


@pytest.mark.parametrize("mode", ["sync", "background"])
def test_vm_and_compiled_agree_to_the_last_bits(mode, fresh_cache, monkeypatch, points_rng):
    from symmon.compile import has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    monkeypatch.setenv("SYMMON_COMPILE", mode)
    exprs = DERIV_MODELS["mixed"] + DERIV_MODELS["polar"]
    c = CompiledModel(exprs, SYMS, name=f"bits_{mode}", compiled=True)
    vm = CompiledModel(exprs, SYMS, name=f"bits_{mode}_vm", compiled=False)
    W = points_rng.uniform(0.3, 2.0, (8192 + 7, 3))
    first = (c.eval_g(W[:5]), *c.eval_gjh(W[:5]))
    assert c.evaluator == ("compiled" if mode == "sync" else "vm (C build running)")
    assert c.wait_compiled(SUBPROCESS_TIMEOUT) == "compiled" and vm.evaluator == "none"
    for a, b in zip(first, (c.eval_g(W[:5]), *c.eval_gjh(W[:5]))):  # before and after the swap
        np.testing.assert_allclose(a, b, rtol=VM_C_RTOL, atol=0)
    np.testing.assert_allclose(c.eval_g(W), vm.eval_g(W), rtol=VM_C_RTOL, atol=0)
    for a, b in zip(c.eval_gjh(W), vm.eval_gjh(W)):
        np.testing.assert_allclose(a, b, rtol=VM_C_RTOL, atol=0)
    assert vm.evaluator == "vm"


def test_one_compile_whatever_the_batch_sizes(fresh_cache, monkeypatch, points_rng):
    from symmon.compile import has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    monkeypatch.setenv("SYMMON_COMPILE", "sync")
    builds = _count_builds(monkeypatch)
    c = CompiledModel(DERIV_MODELS["mixed"], SYMS, name="sizes", compiled=True)
    vm = CompiledModel(DERIV_MODELS["mixed"], SYMS, name="sizes_vm", compiled=False)
    for n in (1, 2, 3, 7, 100, 1000, 8192, 8193, 20000):
        W = points_rng.uniform(0.3, 2.0, (n, 3))
        np.testing.assert_allclose(c.eval_g(W), vm.eval_g(W), rtol=VM_C_RTOL, atol=0)
    assert len(builds) == 1 and c.evaluator == "compiled"


def test_never_uses_the_vm(fresh_cache, monkeypatch):
    monkeypatch.setenv("SYMMON_COMPILE", "never")
    builds = _count_builds(monkeypatch)
    cm = CompiledModel([x * y], [x, y], name="never", compiled=False)
    cm.eval_g(np.ones((4, 2)))
    assert cm.evaluator == "vm" and not builds and not list(fresh_cache.iterdir())


def test_background_build_is_logged(fresh_cache, monkeypatch, caplog):
    from symmon.compile import has_compiler

    if not has_compiler():
        pytest.skip("no C compiler")
    monkeypatch.setenv("SYMMON_COMPILE", "background")
    caplog.set_level("INFO", logger="symmon")
    cm = CompiledModel([x * y, sp.sin(x)], [x, y], name="logged", compiled=True)
    cm.eval_g(np.ones((2, 2)))
    assert cm.wait_compiled(SUBPROCESS_TIMEOUT) == "compiled"
    text = caplog.text
    assert "evaluating on CasADi's VM while it compiles" in text and "background C build done" in text


def test_bad_compile_mode_is_named(monkeypatch):
    from symmon.compile.ccache import compile_mode
    from symmon.errors import SymmonError

    monkeypatch.setenv("SYMMON_COMPILE", "fast")
    with pytest.raises(SymmonError, match="SYMMON_COMPILE must be one of auto, sync, background, never"):
        compile_mode()


def test_propagate_reports_the_evaluator():
    import symmon as sm

    m = sm.propagate(sm.Model([x, y], [x * y]), sm.Gaussian([1.0, 2.0], np.eye(2)), transform=sm.UT.ut1())
    assert m.info["evaluator"] in ("compiled", "vm")


@pytest.mark.parametrize("command", [["propagate", "--transform", "ut1"], ["nonlinearity", "--weight", "full", "--transform", "tt2"],
                                     ["compare", "--samples", "1000"], ["codegen", "-o", "OUT"]],
                         ids=lambda c: c[0])
@pytest.mark.parametrize("name", ["polar (rad)", "a_", "range & bearing"])
def test_every_command_takes_an_ordinary_name(tmp_path, command, name, capsys):
    """Issue 13: these names crashed every command with CasADi's "Function name is not valid"."""
    from symmon.cli.parser import main

    toml = (ROOT / "examples" / "polar.toml").read_text()
    model_file = tmp_path / "m.toml"
    model_file.write_text(toml.replace('name = "polar"', f'name = "{name}"'))
    args = [a.replace("OUT", str(tmp_path / "out")) for a in command]
    assert main([args[0], str(model_file), *args[1:]]) == 0
    out = capsys.readouterr().out
    assert name in out or command[0] == "codegen"
