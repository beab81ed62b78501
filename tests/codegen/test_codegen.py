"""C export: the generated code compiles without CasADi and reproduces symmon's numbers.

The exported library is compiled with gcc in a temporary directory, loaded with ctypes and
compared with :func:`symmon.propagation.front` (TT2, UT) and the compiled CasADi model (g, J).
Models: GMTI, Straka & Havlík (2024) eq. (46) with s = [1e3, 1e3, 1e3]; the polar model
(bearing declared as an angle); polar with multiplicative range noise (w = [u; v]).
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import symmon as sm
from symmon.codegen.export import export_c, moment_functions
from symmon.errors import SymmonError
from symmon.compile import compiled

from helpers import EXAMPLES

#: C and Python evaluate the same expression graphs in a different order of operations:
#: the results agree to rounding, relative to the scale of each array.
C_RTOL = 1e-12

GCC = shutil.which("gcc")
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not found")
#: The warnings an embedded code base builds with.
STRICT = ("-Wall", "-Wextra", "-Werror", "-pedantic")


# --------------------------------------------------------------------------- models
def gmti_model() -> sm.Model:
    """GMTI measurement (46): range, bearing atan2(x − sx, y − sy), range rate."""
    x, y, vx, vy = sp.symbols("x y vx vy", real=True)
    sx, sy, sz = 1e3, 1e3, 1e3
    r = sp.sqrt((x - sx) ** 2 + (y - sy) ** 2 + sz**2)
    return sm.Model([x, y, vx, vy], [r, sp.atan2(x - sx, y - sy), ((x - sx) * vx + (y - sy) * vy) / r],
                    name="gmti")


def polar_model() -> sm.Model:
    x, y = sp.symbols("x y", real=True)
    return sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name="polar", angles=[1])


def polar_noise_model() -> sm.Model:
    x, y, er, eb = sp.symbols("x y e_r e_b", real=True)
    return sm.Model([x, y], [sp.sqrt(x**2 + y**2) * (1 + er), sp.atan2(y, x) + eb], noise=[er, eb],
                    name="polar noise", angles=[1])


def _correlated(std: np.ndarray, rho: float) -> np.ndarray:
    """diag(std)·C·diag(std) with C_ij = rho^|i−j| (positive definite for |rho| < 1)."""
    n = len(std)
    C = rho ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    return std[:, None] * C * std[None, :]


GMTI_MEAN = np.array([500.0, 500.0, 5.0, 8.7])
GMTI_BASE = np.diag([1e3, 1e3, 1.0, 1.0])
POLAR_MEAN = np.array([1.0, 10.0])
POLAR_COV = 0.17 * np.diag([1.0, 100.0])
NOISE_COV = np.diag([1e-4, 1e-3])

# (model factory, u mean, u cov, v cov or None)
CASES = {
    "gmti-0.1": (gmti_model, GMTI_MEAN, 0.1 * GMTI_BASE, None),
    "gmti-10": (gmti_model, GMTI_MEAN, 10.0 * GMTI_BASE, None),
    "gmti-corr": (gmti_model, GMTI_MEAN, _correlated(np.sqrt([1e3, 1e3, 1.0, 1.0]), 0.6), None),
    "polar": (polar_model, POLAR_MEAN, POLAR_COV, None),
    "polar-corr": (polar_model, POLAR_MEAN, _correlated(np.sqrt([0.17, 17.0]), -0.5), None),
    "polar-noise": (polar_noise_model, POLAR_MEAN, POLAR_COV, NOISE_COV),
}
MODELS = {"gmti": gmti_model, "polar": polar_model, "polar-noise": polar_noise_model}
UTS = {"ut1": sm.UT.ut1(), "ut2": sm.UT.ut2(), "cubature": sm.UT.cubature()}


def _model_key(factory) -> str:
    return {v: k for k, v in MODELS.items()}[factory]


def assert_close(actual, desired, what: str, amplification: float = 1.0) -> None:
    desired = np.asarray(desired, dtype=float)
    scale = max(1.0, float(np.abs(desired).max()))
    tol = C_RTOL * amplification
    np.testing.assert_allclose(actual, desired, rtol=tol, atol=tol * scale, err_msg=what)


def ut_amplification(ut: sm.UT, n: int) -> float:
    """Rounding amplification of a weighted sum of sigma points: Σ|w| (≈ 2/α² for ut2).

    With α = 10⁻³ the weights are ~10⁶ with alternating sign, so results that agree to
    rounding in each term differ by ~10⁶ ulp after the sum; scale the tolerance by it.
    """
    wm, wc, _ = ut.weights(n)
    return float(max(np.abs(wm).sum(), np.abs(wc).sum()))


# --------------------------------------------------------------------------- compiled library
class Lib:
    """ctypes view of an exported, compiled model."""

    def __init__(self, so: Path, prefix: str, n_w: int, n_y: int) -> None:
        self.dll = ctypes.CDLL(str(so))
        self.prefix, self.n_w, self.n_y = prefix, n_w, n_y

    @staticmethod
    def _p(a: np.ndarray):
        return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def _call(self, fn: str, ins: list[np.ndarray], shapes: list[tuple[int, int]]) -> list[np.ndarray]:
        # Column-major in and out: a C-ordered copy of Aᵀ is A in Fortran order.
        cin = [np.ascontiguousarray(np.atleast_2d(a).T, dtype=float) for a in ins]
        outs = [np.full(r * c, np.nan) for r, c in shapes]
        rc = getattr(self.dll, f"{self.prefix}_{fn}_eval")(*[self._p(a) for a in cin], *[self._p(o) for o in outs])
        assert rc == 0
        return [o.reshape(shape, order="F") for o, shape in zip(outs, shapes)]

    def g(self, w):
        return self._call("g", [np.asarray(w, float)[:, None]], [(self.n_y, 1)])[0].ravel()

    def jac(self, w):
        return self._call("jac", [np.asarray(w, float)[:, None]], [(self.n_y, self.n_w)])[0]

    def moments(self, which: str, m, P):
        mean, cov, cross = self._call(which, [np.asarray(m, float)[:, None], np.asarray(P, float)],
                                      [(self.n_y, 1), (self.n_y, self.n_y), (self.n_y, self.n_w)])
        return mean.ravel(), cov, cross


def _build(outdir: Path, model: sm.Model, ut: sm.UT, name: str) -> Lib:
    c_file, _ = export_c(model, outdir, name=name, ut=ut)
    so = outdir / f"lib{name}.so"
    subprocess.run([GCC, "-O2", "-shared", "-fPIC", str(c_file), "-o", str(so), "-lm"], check=True,
                   capture_output=True)
    return Lib(so, name, model.n_u + model.n_v, model.n_y)


@pytest.fixture(scope="module")
def libs(tmp_path_factory):
    """One compiled library per (model, UT preset), built on first use."""
    cache: dict[tuple[str, str], Lib] = {}

    def get(model_key: str, ut_key: str = "ut1") -> Lib:
        key = (model_key, ut_key)
        if key not in cache:
            name = f"{model_key.replace('-', '_')}_{ut_key}"
            cache[key] = _build(tmp_path_factory.mktemp(name), MODELS[model_key](), UTS[ut_key], name)
        return cache[key]

    return get


def _propagate(case: str, transform):
    factory, m, P, R = CASES[case]
    model = factory()
    v = None if R is None else sm.Gaussian(np.zeros(len(R)), R)
    res = sm.propagate(model, sm.Gaussian(m, P), v=v, transform=transform)
    mw = m if R is None else np.concatenate([m, np.zeros(len(R))])
    Pw = P if R is None else np.block([[P, np.zeros((len(m), len(R)))], [np.zeros((len(R), len(m))), R]])
    cross = np.hstack([res.cross_cov, res.noise_cross_cov]) if R is not None else res.cross_cov
    return model, mw, Pw, (res.mean, res.cov, cross)


# --------------------------------------------------------------------------- C vs Python
@needs_gcc
@pytest.mark.parametrize("case", sorted(CASES))
def test_c_g_and_jacobian_match_compiled_model(libs, case):
    factory, m, P, R = CASES[case]
    model = factory()
    lib = libs(_model_key(factory))
    rng = np.random.default_rng(7)
    n_w = lib.n_w
    W = np.concatenate([m, np.zeros(n_w - len(m))]) + rng.standard_normal((5, n_w)) * 0.1
    cm = compiled(model)
    y, J, _ = cm.eval_gjh(W)
    for k in range(len(W)):
        assert_close(lib.g(W[k]), y[k], f"g at row {k}")
        assert_close(lib.jac(W[k]), J[k], f"J at row {k}")


@needs_gcc
@pytest.mark.parametrize("case", sorted(CASES))
def test_c_tt2_matches_propagate(libs, case):
    model, mw, Pw, expected = _propagate(case, sm.TT2())
    got = libs(_model_key(CASES[case][0])).moments("tt2", mw, Pw)
    for a, b, what in zip(got, expected, ("mean", "cov", "cross")):
        assert_close(a, b, f"TT2 {what}")


@needs_gcc
@pytest.mark.parametrize("ut_key", sorted(UTS))
@pytest.mark.parametrize("case", sorted(CASES))
def test_c_ut_matches_propagate(libs, case, ut_key):
    model, mw, Pw, expected = _propagate(case, UTS[ut_key])
    got = libs(_model_key(CASES[case][0]), ut_key).moments("ut", mw, Pw)
    amp = ut_amplification(UTS[ut_key], len(mw))
    for a, b, what in zip(got, expected, ("mean", "cov", "cross")):
        assert_close(a, b, f"UT {ut_key} {what}", amp)


@needs_gcc
def test_c_ut_with_a_zero_variance_matches_propagate(libs):
    # A PSD covariance with an exactly zero variance: the zero pivot gives a zero column.
    P = np.diag([1e3, 1e3, 0.0, 1.0])
    model = gmti_model()
    res = sm.propagate(model, sm.Gaussian(GMTI_MEAN, P), transform=sm.UT.cubature())
    mean, cov, cross = libs("gmti", "cubature").moments("ut", GMTI_MEAN, P)
    assert_close(mean, res.mean, "mean")
    assert_close(cov, res.cov, "cov")
    assert_close(cross, res.cross_cov, "cross")


@needs_gcc
def test_c_ut_of_an_indefinite_covariance_is_nan(libs):
    P = np.diag([1e3, -1.0, 1.0, 1.0])
    mean, cov, cross = libs("gmti").moments("ut", GMTI_MEAN, P)
    assert np.isnan(mean).all() and np.isnan(cov).all()


@needs_gcc
def test_c_outputs_may_be_null(libs):
    lib = libs("gmti")
    mean = np.full(3, np.nan)
    m = np.ascontiguousarray(GMTI_MEAN)
    P = np.ascontiguousarray(GMTI_BASE.T)
    null = ctypes.POINTER(ctypes.c_double)()
    rc = lib.dll.gmti_ut1_tt2_eval(Lib._p(m), Lib._p(P), Lib._p(mean), null, null)
    assert rc == 0
    assert_close(mean, sm.propagate(gmti_model(), sm.Gaussian(GMTI_MEAN, GMTI_BASE), transform=sm.TT2()).mean, "mean")


@needs_gcc
def test_casadi_calling_convention_with_work_sizes(libs):
    """The raw CasADi API: name(arg, res, iw, w, mem) with arrays sized by name_work."""
    lib = libs("gmti")
    dll = lib.dll
    assert dll.gmti_ut1_casadi_int_size() == 8 and dll.gmti_ut1_casadi_real_size() == 8
    cint = ctypes.c_longlong
    sizes = [cint() for _ in range(4)]
    assert dll.gmti_ut1_ut_work(*[ctypes.byref(s) for s in sizes]) == 0
    sz_arg, sz_res, sz_iw, sz_w = (max(1, s.value) for s in sizes)
    dbl_p = ctypes.POINTER(ctypes.c_double)
    P = 0.1 * GMTI_BASE
    m = np.ascontiguousarray(GMTI_MEAN)
    Pf = np.ascontiguousarray(P.T)
    out = [np.full(3, np.nan), np.full(9, np.nan), np.full(12, np.nan)]
    arg = (dbl_p * sz_arg)(Lib._p(m), Lib._p(Pf))
    res = (dbl_p * sz_res)(*[Lib._p(o) for o in out])
    iw = (cint * sz_iw)()
    w = (ctypes.c_double * sz_w)()
    assert dll.gmti_ut1_ut(arg, res, iw, w, 0) == 0
    expected = sm.propagate(gmti_model(), sm.Gaussian(GMTI_MEAN, P), transform=sm.UT.ut1())
    assert_close(out[0], expected.mean, "mean")
    assert_close(out[1].reshape(3, 3, order="F"), expected.cov, "cov")
    assert_close(out[2].reshape(3, 4, order="F"), expected.cross_cov, "cross")


# --------------------------------------------------------------------------- the SX maps
@pytest.mark.parametrize("transform", ["tt2", "ut1"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_sx_moment_maps_match_propagate(case, transform):
    tr = sm.TT2() if transform == "tt2" else sm.UT.ut1()
    model, mw, Pw, expected = _propagate(case, tr)
    fs = moment_functions(model, ut=sm.UT.ut1())
    got = [np.array(a) for a in fs["tt2" if transform == "tt2" else "ut"](mw, Pw)]
    for a, b, what in zip(got, expected, ("mean", "cov", "cross")):
        assert_close(a.reshape(np.shape(b)), b, what)


# --------------------------------------------------------------------------- the files
@needs_gcc
def test_source_is_self_contained_and_compiles(tmp_path):
    paths = export_c(gmti_model(), tmp_path)
    assert [p.name for p in paths] == ["gmti.c", "gmti.h"]
    for p in paths:
        text = p.read_text()
        assert "#include <casadi" not in text and '#include "casadi' not in text
    # Only the C library: no include path, strict C99 without a warning, object file only.
    res = subprocess.run([GCC, "-O2", "-std=c99", *STRICT, "-c", str(paths[0]), "-o", str(tmp_path / "gmti.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    # The header compiles on its own and declares the plain wrappers.
    probe = tmp_path / "probe.c"
    probe.write_text('#include "gmti.h"\nint main(void) { double w[4] = {0}, y[3]; return gmti_g_eval(w, y); }\n')
    res = subprocess.run([GCC, "-O2", "-c", str(probe), "-o", str(tmp_path / "probe.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gmti.c", "gmti.h", "gmti.o", "probe.c", "probe.o"]


def test_header_documents_the_signatures(tmp_path):
    _, h = export_c(gmti_model(), tmp_path, ut=sm.UT(alpha=0.5, beta=2.0, kappa=1.0))
    text = h.read_text()
    head = text[: text.index("*/")]
    for needle in ("COLUMN-MAJOR", "int gmti_g_eval(const double* w, double* y);", "int gmti_jac_eval",
                   "int gmti_tt2_eval", "int gmti_ut_eval", "alpha = 0.5, beta = 2.0, kappa = 1.0",
                   "w = [x, y, vx, vy]", "NAME_work", "gmti_ut}"):
        assert needle in head
    assert "int gmti_ut_eval(const casadi_real* m, const casadi_real* P, casadi_real* mean" in text


def test_model_name_becomes_an_identifier(tmp_path):
    paths = export_c(polar_noise_model(), tmp_path)
    assert [p.name for p in paths] == ["polar_noise.c", "polar_noise.h"]


def test_export_replaces_existing_files(tmp_path):
    export_c(polar_model(), tmp_path, ut=sm.UT.ut1())
    export_c(polar_model(), tmp_path, ut=sm.UT.cubature())
    assert "kappa = 0.0" in (tmp_path / "polar.h").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["polar.c", "polar.h"]


@pytest.mark.parametrize("name", ["1abc", "a-b", "", "x y"])
def test_bad_name_is_rejected(tmp_path, name):
    with pytest.raises(SymmonError, match="name"):
        export_c(polar_model(), tmp_path, name=name)


def test_bad_ut_is_rejected(tmp_path):
    with pytest.raises(SymmonError, match="ut must be"):
        export_c(polar_model(), tmp_path, ut=sm.TT2())


@pytest.mark.parametrize("ut", ["tt1", sm.TT1(), sm.MonteCarlo(n=100, seed=0), 3], ids=repr)
def test_ut_must_be_a_point_rule(tmp_path, ut):
    with pytest.raises(SymmonError, match="ut must be a point rule"):
        export_c(polar_model(), tmp_path, ut=ut)


@pytest.mark.parametrize("case", ["gmti-corr", "polar", "polar-noise"])
def test_any_point_rule_exports(case):
    """The ut map of a rule that is not a UT: Gauss–Hermite of order 3, from its declared points."""
    tr = sm.GaussHermite(3)
    model, mw, Pw, expected = _propagate(case, tr)
    got = [np.array(a) for a in moment_functions(model, ut=tr)["ut"](mw, Pw)]
    for a, b, what in zip(got, expected, ("mean", "cov", "cross")):
        assert_close(a.reshape(np.shape(b)), b, what)


def test_header_names_any_point_rule(tmp_path):
    _, h = export_c(polar_model(), tmp_path, ut=sm.GaussHermite(3))
    assert "ut: GaussHermite(order=3" in h.read_text() and "9 points" in h.read_text()


def test_non_model_is_rejected(tmp_path):
    with pytest.raises(TypeError, match="model"):
        export_c("polar", tmp_path)


# --------------------------------------------------------------------------- hostile names
#: Pieces that try to leave the header comment: close it, open another, splice lines
#: (backslash-newline, the trigraph ??/), start a preprocessor line, or hide in non-ASCII.
HOSTILE = ["*/", "/*", "*", "/", "\\", "\n", "\r", "??/", "??", "?", "#define symmon_injected 1\n",
           "//", '"', "'", "\u2028", "é", "\x00", "\t", " "]
INJECTED = "symmon_injected"
PAYLOAD = f"*/ int {INJECTED}(void) {{ return 42; }} /*"


def _defined_symbols(obj: Path) -> set[str]:
    res = subprocess.run(["nm", "--defined-only", "-j", str(obj)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return set(res.stdout.split())


def _compile_probe(tmp_path: Path, header: Path) -> Path:
    """An object file of a C file that includes the header (trigraphs on, as in C89)."""
    probe = tmp_path / "probe.c"
    probe.write_text(f'#include "{header.name}"\nint probe(void) {{ return 0; }}\n')
    obj = tmp_path / "probe.o"
    res = subprocess.run([GCC, "-std=c99", "-trigraphs", "-c", str(probe), "-o", str(obj)],
                         capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    return obj


@needs_gcc
@pytest.mark.skipif(shutil.which("nm") is None, reason="nm not found")
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(parts=st.lists(st.one_of(st.sampled_from(HOSTILE), st.text(max_size=6)), max_size=8),
       where=st.integers(0, 8))
def test_hostile_model_name_cannot_inject_code(tmp_path_factory, parts, where):
    tmp_path = tmp_path_factory.mktemp("hostile")
    parts.insert(min(where, len(parts)), PAYLOAD)
    name = "".join(parts)
    x, y = sp.symbols("x y", real=True)
    model = sm.Model([x, y], [sp.sqrt(x**2 + y**2), sp.atan2(y, x)], name=name)
    c_path, h_path = export_c(model, tmp_path)
    text = h_path.read_text()
    comment = text[: text.index("*/") + 2]
    # The first "*/" closes symmon's own comment, after its last line; nothing escapes it.
    assert comment.startswith("/*\n") and comment.endswith("gcc -O2 -c NAME.c\n */")
    assert comment.count("/*") == 1 and "??" not in comment and comment.isascii()
    assert all(not ln.endswith("\\") for ln in comment.splitlines())
    assert INJECTED not in _defined_symbols(_compile_probe(tmp_path, h_path))
    assert model.name == name  # shown as written


@needs_gcc
def test_the_issue_name_gives_no_symbol(tmp_path):
    """The name of the report (issue 12) through the CLI: the header defines nothing."""
    from symmon.cli.parser import main

    toml = (EXAMPLES / "polar.toml").read_text()
    name = "aaaa" * 10 + f" {PAYLOAD} "
    model_file = tmp_path / "m.toml"
    model_file.write_text(toml.replace('name = "polar"', f'name = "{name}"'))
    assert main(["codegen", str(model_file), "-o", str(tmp_path / "out")]) == 0
    header, = (tmp_path / "out").glob("*.h")
    assert INJECTED not in _defined_symbols(_compile_probe(tmp_path / "out", header))


@pytest.mark.parametrize("name", ["polar (rad)", "a_", "range & bearing", "_", "9lives", "Ångström", "casadi"])
def test_free_text_model_names_export(tmp_path, name):
    x, y = sp.symbols("x y", real=True)
    paths = export_c(sm.Model([x, y], [x * y], name=name), tmp_path)
    prefix = paths[0].stem
    assert prefix.isidentifier() and prefix.isascii() and "__" not in prefix and not prefix.endswith("_")


@pytest.mark.parametrize("name", ["a__b", "a_", "_a", "casadi_f", "x" * 64])
def test_explicit_name_must_suit_casadi(tmp_path, name):
    with pytest.raises(SymmonError, match="name must be a C identifier"):
        export_c(polar_model(), tmp_path, name=name)


@needs_gcc
@pytest.mark.skipif(shutil.which("nm") is None, reason="nm not found")
def test_hostile_symbol_names_cannot_inject_code(tmp_path):
    """Symbol names are listed in the header comment too (w = [...])."""
    a, b = sp.Symbol(PAYLOAD), sp.Symbol("b??/\n#define x")
    _, h_path = export_c(sm.Model([a, b], [a * b], name="sym"), tmp_path)
    assert INJECTED not in _defined_symbols(_compile_probe(tmp_path, h_path))
    assert "w = [*\\/ int symmon_injected(void)" in h_path.read_text()
