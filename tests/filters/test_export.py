"""The exported filter (symmon.filters.gaussian.export): C99 built with gcc, run on a recorded track.

Each filter family is exported, built with ``-std=c99 -O2 -Wall -Wextra -Werror -pedantic``
(and with clang where it is installed), and its example program is driven over a recorded
measurement sequence of a target passing behind the sensor (the bearing goes through ±π).
The estimates, covariances and log-likelihood must equal ``kf.filter``'s to 1e-9 relative:
the same CasADi graphs in another evaluation order (MX in the export, SX in the filter below
10 variables), so they differ only by rounding.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.codegen.export import strict_c
from symmon.errors import OutputPathError, SymmonError
from symmon.filters.gaussian.export import ERROR_CODES

GCC = shutil.which("gcc")
CLANG = shutil.which("clang")
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not found")
STRICT = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic")
#: Same graphs, another evaluation order: rounding only (module notes).
RTOL = 1e-9
T = 1.0
STEPS = 40


def cv_models(name: str = "range bearing"):
    px, py, vx, vy = sp.symbols("px py vx vy", real=True)
    f = sm.Model([px, py, vx, vy], [px + T * vx, py + T * vy, vx, vy], name="cv")
    h = sm.Model([px, py, vx, vy], [sp.sqrt(px**2 + py**2), sp.atan2(py, px)], angles=[1], name=name)
    q = 0.01
    Q = q * np.array([[T**3 / 3, 0, T**2 / 2, 0], [0, T**3 / 3, 0, T**2 / 2],
                      [T**2 / 2, 0, T, 0], [0, T**2 / 2, 0, T]])
    R = np.diag([2.0**2, 0.02**2])
    return f, h, Q, R


def turn_models():
    """General noise, an angle state: heading th, speed v, noises in both models."""
    px, py, th, v, a, om, er, eb = sp.symbols("px py th v a om e_r e_b", real=True)
    f = sm.Model([px, py, th, v], [px + T * v * sp.cos(th), py + T * v * sp.sin(th), th + T * om, v + T * a],
                 noise=[a, om], angles=[2], name="unicycle")
    h = sm.Model([px, py, th, v], [sp.sqrt(px**2 + py**2) * (1 + er), sp.atan2(py, px) + eb],
                 noise=[er, eb], angles=[1], name="rb noise")
    return f, h, np.diag([0.05**2, 0.02**2]), np.diag([0.01**2, 0.02**2])


X0 = np.array([-20.0, 100.0, 0.0, -5.0])
P0 = np.diag([25.0, 25.0, 0.25, 0.25])
X0_TURN = np.array([-20.0, 100.0, -np.pi / 2, 5.0])
P0_TURN = np.diag([25.0, 25.0, 0.01, 0.25])


def record(f: sm.Model, h: sm.Model, Q, R, x0, seed: int = 3) -> np.ndarray:
    """Measurements of one simulated run (the filter file's simulator)."""
    from symmon.files.filterfile import simulate

    _, ys = simulate(f, h, Q, R, sm.Gaussian(x0, np.diag(np.full(len(x0), 1e-12))), STEPS, 1, seed)
    return ys[0]


def build(directory: Path, prefix: str, compiler: str = "gcc") -> Path:
    exe = directory / f"{prefix}_example"
    res = subprocess.run([shutil.which(compiler), *STRICT, f"{prefix}.c", f"{prefix}_example.c", "-lm", "-o", str(exe)],
                         cwd=directory, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return exe


def run_example(exe: Path, x0, P0, ys, params=None) -> tuple[int, np.ndarray]:
    """The example's output on x0, P0 and per step the parameter values (``params`` (K, NP), or
    one row for every step) and the measurement (NaN written ``nan``: missing)."""
    steps = np.asarray(ys, dtype=float)
    if params is not None:
        steps = np.hstack([np.broadcast_to(np.asarray(params, dtype=float), (len(ys), np.shape(params)[-1])), steps])
    text = " ".join(repr(float(v)) for v in [*x0, *np.ravel(P0)]) + "\n"
    text += "\n".join(" ".join(repr(float(v)) for v in row) for row in steps) + "\n"
    res = subprocess.run([str(exe)], input=text, capture_output=True, text=True)
    rows = np.array([[float(v) for v in line.split()] for line in res.stdout.splitlines()])
    return res.returncode, rows


def check_against_filter(kf, rows, ys, x0, P0, params=None):
    n = kf.f_model.n_u
    ref = kf.filter(ys, x0, P0, params=params)
    assert rows.shape == (len(ys), 2 + n + n * n + 1)
    assert (rows[:, 1] == 0).all()
    np.testing.assert_allclose(rows[:, 2:2 + n], ref.x, rtol=RTOL, atol=RTOL * np.abs(ref.x).max())
    np.testing.assert_allclose(rows[:, 2 + n:-1].reshape(-1, n, n), ref.P, rtol=RTOL,
                               atol=RTOL * np.abs(ref.P).max())
    np.testing.assert_allclose(rows[:, -1], np.cumsum(ref.loglik), rtol=RTOL, atol=RTOL)
    assert rows[-1, -1] == pytest.approx(ref.log_likelihood, rel=RTOL)


FAMILIES = {"ekf": sm.TT1(), "ekf2": sm.TT2(), "ukf": sm.UT.ut1(), "ckf": sm.UT.cubature(),
            "ghkf": sm.GaussHermite(3)}


@needs_gcc
@pytest.mark.parametrize("family", FAMILIES)
def test_export_equals_the_filter_behind_the_sensor(tmp_path, family):
    f, h, Q, R = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, FAMILIES[family])
    ys = record(f, h, Q, R, X0)
    assert np.abs(np.diff(ys[:, 1])).max() > np.pi  # the bearing wraps through ±π
    paths = kf.export_c(tmp_path)
    prefix = f"range_bearing_{family}"
    assert [p.name for p in paths] == [f"{prefix}.c", f"{prefix}.h", f"{prefix}_example.c", f"{prefix}_README.md"]
    code, rows = run_example(build(tmp_path, prefix), X0, P0, ys)
    assert code == 0
    check_against_filter(kf, rows, ys, X0, P0)


@needs_gcc
@pytest.mark.parametrize("family", ["ekf", "ukf"])
def test_export_with_general_noise_and_an_angle_state(tmp_path, family):
    f, h, Q, R = turn_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, FAMILIES[family])
    assert kf.angle_states == {2}
    ys = record(f, h, Q, R, X0_TURN)
    kf.export_c(tmp_path, name="turn")
    code, rows = run_example(build(tmp_path, "turn"), X0_TURN, P0_TURN, ys)
    assert code == 0
    assert np.all(np.abs(rows[:, 4]) <= np.pi)  # the heading is wrapped
    check_against_filter(kf, rows, ys, X0_TURN, P0_TURN)


@needs_gcc
@pytest.mark.parametrize("family", ["ekf", "ukf"])
def test_export_with_parameters(tmp_path, family):
    """A time step in f and a range bias in h: p is an argument of both functions."""
    px, py, vx, vy, dt, b = sp.symbols("px py vx vy dt b", real=True)
    f = sm.Model([px, py, vx, vy], [px + dt * vx, py + dt * vy, vx, vy], params=[dt], name="cv dt")
    h = sm.Model([px, py, vx, vy], [sp.sqrt(px**2 + py**2) + b, sp.atan2(py, px)], angles=[1], params=[b],
                 name="rb bias")
    _, _, Q, R = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, FAMILIES[family])
    ys = record(*cv_models()[:2], Q, R, X0)
    ys[:, 0] += 0.8
    kf.export_c(tmp_path, name="rbp")
    header = (tmp_path / "rbp.h").read_text()
    assert "#define RBP_NP 2" in header and "parameters p = [dt, b]" in header
    assert "int rbp_predict(double *x, double *P, const double *p);" in header
    assert "int rbp_update(double *x, double *P, const double *p, const double *y, double *loglik);" in header
    code, rows = run_example(build(tmp_path, "rbp"), X0, P0, ys, params=[(1.0, 0.8)])
    assert code == 0
    check_against_filter(kf, rows, ys, X0, P0, params={"dt": 1.0, "b": 0.8})
    code, rows = run_example(tmp_path / "rbp_example", X0, P0, ys, params=[(1.0, np.nan)])
    assert code == 1 and rows[0, 1] == ERROR_CODES["ERR_PARAM"][0]  # at the first step


@needs_gcc
def test_only_the_functions_whose_model_has_parameters_take_them(tmp_path):
    px, py, vx, vy, b = sp.symbols("px py vx vy b", real=True)
    f, _, Q, R = cv_models()
    h = sm.Model([px, py, vx, vy], [sp.sqrt(px**2 + py**2) + b, sp.atan2(py, px)], angles=[1], params=[b],
                 name="rb bias")
    sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1()).export_c(tmp_path, name="hb")
    header = (tmp_path / "hb.h").read_text()
    assert "int hb_predict(double *x, double *P);" in header
    assert "int hb_update(double *x, double *P, const double *p, const double *y, double *loglik);" in header
    build(tmp_path, "hb")


@pytest.mark.skipif(CLANG is None, reason="clang not found")
def test_export_builds_with_clang(tmp_path):
    f, h, Q, R = cv_models()
    sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1()).export_c(tmp_path, name="rb")
    build(tmp_path, "rb", "clang")


@needs_gcc
@pytest.mark.skipif(shutil.which("nm") is None, reason="nm not found")
def test_embedded_constraints(tmp_path):
    """No allocation, no I/O, no global mutable state, only <math.h> and <string.h>."""
    f, h, Q, R = cv_models()
    paths = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1()).export_c(tmp_path, name="rb")
    for p in paths[:2]:
        includes = set(re.findall(r"#include\s*(\S+)", p.read_text()))
        assert includes <= {"<math.h>", "<string.h>", '"rb.h"'}, includes
    obj = tmp_path / "rb.o"
    res = subprocess.run([GCC, *STRICT, "-c", "rb.c", "-o", str(obj)], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    symbols = subprocess.run(["nm", str(obj)], capture_output=True, text=True, check=True).stdout.split("\n")
    undefined = {ln.split()[-1] for ln in symbols if re.match(r"\s+U ", ln)}
    # gcc on a glibc target fuses sin(a) and cos(a) into one sincos call; the source has only
    # the <math.h> functions (a compiler for a target without sincos calls them apart).
    assert "sincos" not in paths[0].read_text()
    assert undefined <= {"sqrt", "sin", "cos", "sincos", "atan2", "log", "fmin", "fmax", "floor", "memcpy",
                         "memset", "fabs", "exp", "pow", "tan", "atan", "hypot"}, undefined
    # Writable data (D, B, d, b: data and bss) is global mutable state.
    writable = [ln for ln in symbols if re.match(r"\S*\s+[DdBb] ", ln)]
    assert not writable, writable
    header = paths[1].read_text()
    for macro in ("RB_NX 4", "RB_NY 2", "RB_OK 0", "RB_PREDICT_STACK_BYTES", "RB_UPDATE_STACK_BYTES"):
        assert f"#define {macro}" in header


ERROR_DRIVER = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "rb.h"

static void report(const char *what, int code, const double *x, const double *x0, const double *P,
                   const double *P0, double ll) {
  int same = memcmp(x, x0, sizeof(double) * RB_NX) == 0 && memcmp(P, P0, sizeof(double) * RB_NX * RB_NX) == 0
             && ll == 0.0;
  printf("%s %d %d\n", what, code, same);
}

int main(void) {
  double x[RB_NX] = {-20, 100, 0, -5}, P[RB_NX * RB_NX] = {0}, y[RB_NY] = {100, 1.7};
  double x0[RB_NX], P0[RB_NX * RB_NX], ll = 0;
  int i;
  for (i = 0; i < RB_NX; ++i) P[i * RB_NX + i] = 1;
  memcpy(x0, x, sizeof x); memcpy(P0, P, sizeof P);
  y[1] = INFINITY;
  report("inf_y", rb_update(x, P, y, &ll), x, x0, P, P0, ll);
  y[0] = NAN; y[1] = NAN;  /* nothing measured: OK, and x, P, loglik as they were */
  report("nan_y", rb_update(x, P, y, &ll), x, x0, P, P0, ll);
  y[0] = 100; y[1] = NAN;  /* the range alone updates */
  report("nan_bearing", rb_update(x, P, y, &ll), x, x0, P, P0, ll);
  memcpy(x, x0, sizeof x); memcpy(P, P0, sizeof P); ll = 0;
  y[1] = 1.7;
  x[0] = INFINITY; memcpy(x0, x, sizeof x);
  report("inf_x", rb_update(x, P, y, &ll), x, x0, P, P0, ll);
  x[0] = -20; memcpy(x0, x, sizeof x);
  for (i = 0; i < RB_NX; ++i) P[i * RB_NX + i] = -100;  /* indefinite: S is too */
  memcpy(P0, P, sizeof P);
  report("indefinite_S", rb_update(x, P, y, &ll), x, x0, P, P0, ll);
  report("indefinite_P", rb_predict(x, P), x, x0, P, P0, ll);
  for (i = 0; i < RB_NX; ++i) P[i * RB_NX + i] = 1;
  memcpy(P0, P, sizeof P);
  report("ok", rb_predict(x, P), x, x0, P, P0, ll);
  return 0;
}
"""


@needs_gcc
@pytest.mark.parametrize("family", ["ekf", "ukf"])
def test_error_codes_leave_the_state_unchanged(tmp_path, family):
    f, h, Q, R = cv_models()
    sm.NonlinearKalmanFilter(f, h, Q, R, FAMILIES[family]).export_c(tmp_path, name="rb")
    (tmp_path / "driver.c").write_text(ERROR_DRIVER)
    res = subprocess.run([GCC, *STRICT, "rb.c", "driver.c", "-lm", "-o", "driver"], cwd=tmp_path,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    out = subprocess.run([str(tmp_path / "driver")], capture_output=True, text=True, check=True).stdout
    got = {w: (int(c), int(s)) for w, c, s in (line.split() for line in out.splitlines())}
    codes = {k: c for k, (c, _) in ERROR_CODES.items()}
    assert got["inf_y"] == (codes["ERR_MEASUREMENT"], 1)
    assert got["nan_y"] == (codes["OK"], 1)  # a missing measurement: the update leaves the prediction
    assert got["nan_bearing"] == (codes["OK"], 0)  # the measured range updates
    assert got["inf_x"] == (codes["ERR_STATE"], 1)
    assert got["indefinite_S"] == (codes["ERR_S"], 1)
    assert got["indefinite_P"] == (codes["ERR_P"], 1)
    assert got["ok"] == (codes["OK"], 0)  # a successful step changes x and P


@needs_gcc
def test_example_stops_at_the_first_error(tmp_path):
    f, h, Q, R = cv_models()
    sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1()).export_c(tmp_path, name="rb")
    ys = record(f, h, Q, R, X0)[:5].copy()
    ys[3, 0] = np.inf
    code, rows = run_example(build(tmp_path, "rb"), X0, P0, ys)
    assert code == 1 and rows.shape[0] == 4
    assert rows[3, 1] == ERROR_CODES["ERR_MEASUREMENT"][0]


def test_readme_and_header_describe_the_export(tmp_path):
    f, h, Q, R = cv_models(name="range */ bearing")  # the name cannot end the comment
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    c, hdr, example, readme = kf.export_c(tmp_path, name="rb")
    text = readme.read_text()
    assert f"symmon {sm.__version__}" in text and re.search(r"model hash .*`[0-9a-f]{64}`", text)
    assert "int rb_predict(double *x, double *P);" in text and "RB_ERR_S" in text
    head = hdr.read_text()
    # The first "*/" closes symmon's comment, after its last line; the name is escaped in it.
    assert head.index("*/") > head.index("Build: cc -std=c99")
    assert "measurement h: range *\\/ bearing" in head


def test_the_hash_changes_with_the_noise(tmp_path):
    f, h, Q, R = cv_models()
    sm.NonlinearKalmanFilter(f, h, Q, R).export_c(tmp_path / "a", name="rb")
    sm.NonlinearKalmanFilter(f, h, 2 * Q, R).export_c(tmp_path / "b", name="rb")
    digest = [re.search(r"`([0-9a-f]{64})`", (tmp_path / d / "rb_README.md").read_text()).group(1) for d in "ab"]
    assert digest[0] != digest[1]


def test_adaptive_filter_is_refused(tmp_path):
    f, h, Q, R = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.Adaptive(0.01))
    with pytest.raises(SymmonError, match="one transform for every step"):
        kf.export_c(tmp_path)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["a__b", "a_", "_a", "casadi_f", "x" * 64, "1x"])
def test_bad_names_are_refused(tmp_path, name):
    f, h, Q, R = cv_models()
    with pytest.raises(SymmonError, match="name must be a C identifier"):
        sm.NonlinearKalmanFilter(f, h, Q, R).export_c(tmp_path, name=name)


def test_output_directory_that_is_a_file(tmp_path):
    f, h, Q, R = cv_models()
    target = tmp_path / "file"
    target.write_text("x")
    with pytest.raises(OutputPathError):
        sm.NonlinearKalmanFilter(f, h, Q, R).export_c(target)
    assert target.read_text() == "x"


def test_strict_c_casts_only_unused_parameters():
    src = ("static int f(const double* a, double* b, int mem) {\n  b[0] = a[0];\n  return 0;\n}\n"
           "double g(double x) { return 1.0;}\n"
           "int h(void) {\n  return 0;\n}\n"
           "  if (x) {\n")
    out = strict_c(src).splitlines()
    assert out[0] == "static int f(const double* a, double* b, int mem) { (void)mem;"
    assert out[4] == "double g(double x) { (void)x; return 1.0;}"
    assert out[5] == "int h(void) {"
    assert out[-1] == "  if (x) {"


def test_export_needs_a_filter(tmp_path):
    from symmon.errors import ArgumentTypeError
    from symmon.filters.gaussian.export import export_filter_c

    with pytest.raises(ArgumentTypeError, match="NonlinearKalmanFilter"):
        export_filter_c(sm.TT1(), tmp_path)


def gappy(ys: np.ndarray) -> np.ndarray:
    """``ys`` with two rows missing (the second one at the first step) and two components missing."""
    ys = ys.copy()
    ys[[0, 7]] = np.nan
    ys[3, 1] = ys[12, 0] = np.nan
    return ys


@needs_gcc
@pytest.mark.parametrize("family", ["ekf", "iekf", "ukf"])
def test_export_runs_recorded_data_with_gaps_and_a_step_per_row(tmp_path, family):
    """Issue 38, item 1: NaN rows and NaN components are skipped as kf.filter skips them, and an
    irregular dt (and a drifting bias) is read at every step; x, P and the log-likelihood
    equal kf.filter's to 1e-9."""
    px, py, vx, vy, dt, b = sp.symbols("px py vx vy dt b", real=True)
    f = sm.Model([px, py, vx, vy], [px + dt * vx, py + dt * vy, vx, vy], params=[dt], name="cv dt")
    h = sm.Model([px, py, vx, vy], [sp.sqrt(px**2 + py**2) + b, sp.atan2(py, px)], angles=[1], params=[b],
                 name="rb bias")
    _, _, Q, R = cv_models()
    transform, iterations = (sm.TT1(), 3) if family == "iekf" else (FAMILIES[family], 1)
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, transform, iterations=iterations)
    ys = gappy(record(*cv_models()[:2], Q, R, X0))
    steps = np.random.default_rng(5).uniform(0.5, 1.5, len(ys))
    bias = np.linspace(0.0, 1.0, len(ys))
    kf.export_c(tmp_path, name="gaps")
    code, rows = run_example(build(tmp_path, "gaps"), X0, P0, ys, params=np.column_stack([steps, bias]))
    assert code == 0
    check_against_filter(kf, rows, ys, X0, P0, params={"dt": steps, "b": bias})
    assert rows[0, -1] == 0.0 and rows[7, -1] == rows[6, -1]  # nothing measured: no log-likelihood


@needs_gcc
def test_the_exported_update_skips_the_missing_components_itself(tmp_path):
    """The library function, not only the example: NaN in y is a missing component."""
    f, h, Q, R = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R, sm.UT.ut1())
    kf.export_c(tmp_path, name="rb")
    ys = gappy(record(f, h, Q, R, X0))
    code, rows = run_example(build(tmp_path, "rb"), X0, P0, ys)
    assert code == 0
    check_against_filter(kf, rows, ys, X0, P0)


def test_the_export_replaces_only_files_it_wrote(tmp_path):
    """Issue 38, item 2: the README is NAME_README.md, a user's README.md stays, and a file of an
    export's name that the export did not write is refused, before anything is written."""
    f, h, Q, R = cv_models()
    kf = sm.NonlinearKalmanFilter(f, h, Q, R)
    (tmp_path / "README.md").write_text("my project\n")
    paths = kf.export_c(tmp_path, name="rb")
    assert (tmp_path / "README.md").read_text() == "my project\n" and paths[-1].name == "rb_README.md"
    assert kf.export_c(tmp_path, name="rb") == paths  # its own files are replaced
    (tmp_path / "other_README.md").write_text("notes\n")
    with pytest.raises(OutputPathError, match=r"other_README\.md, which symmon's export did not write"):
        kf.export_c(tmp_path, name="other")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["README.md", "other_README.md", *(p.name for p in paths)])
    assert (tmp_path / "other_README.md").read_text() == "notes\n"


def test_the_hash_covers_the_iterations_and_the_title_the_resolved_kappa(tmp_path):
    """Issue 38, item 3: the EKF and the IEKF of one model differ in code and in hash; the title's
    κ is the one the body states (κ = 3 − n resolved, not None)."""
    f, h, Q, R = cv_models()
    digest = []
    for d, it in (("a", 1), ("b", 3)):
        sm.NonlinearKalmanFilter(f, h, Q, R, sm.TT1(), iterations=it).export_c(tmp_path / d, name="rb")
        digest.append(re.search(r"`([0-9a-f]{64})`", (tmp_path / d / "rb_README.md").read_text()).group(1))
    assert digest[0] != digest[1]
    assert "3 iterations" in (tmp_path / "b" / "rb_README.md").read_text()
    turn = turn_models()  # general noise: [x; w] has 6 dimensions, [x; e] also 6
    sm.NonlinearKalmanFilter(*cv_models()[:2], Q, R, sm.UT.ut1()).export_c(tmp_path / "c", name="rb")
    text = (tmp_path / "c" / "rb_README.md").read_text()
    title = text.splitlines()[0]
    assert title == "# rb: an exported UKF(alpha = 1.0, beta = 0.0, kappa = -1.0) filter"
    assert "- transform: `alpha = 1.0, beta = 0.0, kappa = -1.0`" in text and "None" not in text
    f2, h2, Q2, R2 = turn
    h_one = sm.Model(h2.inputs, [h2.outputs[0]], noise=[h2.noise[0]], name="range noise")  # [x; e]: 5 dimensions
    sm.NonlinearKalmanFilter(f2, h_one, Q2, R2[:1, :1], sm.UT.ut1()).export_c(tmp_path / "d", name="rb")
    text = (tmp_path / "d" / "rb_README.md").read_text()
    assert ("time update alpha = 1.0, beta = 0.0, kappa = -3.0; measurement update alpha = 1.0, beta = 0.0, "
            "kappa = -2.0") in text.splitlines()[0]
