"""The exported C filter (``NonlinearKalmanFilter.export_c``) against the Python filter and FilterPy.

    python benchmarks/export.py [--quick] [--out benchmarks/RESULTS.md]

For n = 4, 10, 30 states (n = 4: one constant-velocity target seen in range and bearing;
n = 10 and 30: 2 and 6 such targets, each with a range bias, measured by one sensor), the
UKF (``UT(1, 2, 0)``) and the EKF are exported and built with ``gcc -std=c99 -O2``, and
timed:

- **export** (Python, building the CasADi graphs and writing the C), **build** (gcc -O2 of
  ``NAME.c``) and the size of ``NAME.c``;
- **exported C per step**: ``NAME_predict`` + ``NAME_update`` in a loop in C over K
  recorded measurements (a C main, ``clock_gettime``; no Python);
- **symmon per step**: ``kf.filter(ys, x0, P0)`` over the same K steps, warm, and its first
  call into a fresh cache;
- **FilterPy per step**: ``UnscentedKalmanFilter`` / ``ExtendedKalmanFilter`` with the same
  angle-aware mean and residual, a Python loop.

Ratios are peer time / exported-C time (> 1: the export is faster).  The estimates of the
export are compared with ``kf.filter`` (maximum relative difference) in the same run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
os.environ.setdefault("SYMMON_CACHE", tempfile.mkdtemp(prefix="symmon-bench-export-"))

import numpy as np  # noqa: E402

import symmon as sm  # noqa: E402
from filters import Problem, best, cv_range_bearing, rel_diff, targets  # noqa: E402
from report import write_section  # noqa: E402

HEADING = "## Exported C filter"

BENCH_MAIN = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "{P}.h"

/* stdin: x0, P0, K, then K measurements; argv[1]: repeats.  Prints ns per step, then x_K. */
int main(int argc, char **argv) {{
  double x0[{P_}_NX], P0[{P_}_NX * {P_}_NX], x[{P_}_NX], P[{P_}_NX * {P_}_NX], ll, *ys;
  double best = 1e300, t;
  long K, k, i, r, repeats = argc > 1 ? atol(argv[1]) : 5;
  struct timespec a, b;
  for (i = 0; i < {P_}_NX; ++i) if (scanf("%lf", &x0[i]) != 1) return 2;
  for (i = 0; i < {P_}_NX * {P_}_NX; ++i) if (scanf("%lf", &P0[i]) != 1) return 2;
  if (scanf("%ld", &K) != 1) return 2;
  ys = malloc(sizeof(double) * K * {P_}_NY);
  for (i = 0; i < K * {P_}_NY; ++i) if (scanf("%lf", &ys[i]) != 1) return 2;
  for (r = 0; r < repeats; ++r) {{
    memcpy(x, x0, sizeof x); memcpy(P, P0, sizeof P); ll = 0;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (k = 0; k < K; ++k) {{
      if ({P}_predict(x, P) || {P}_update(x, P, ys + k * {P_}_NY, &ll)) return 1;
    }}
    clock_gettime(CLOCK_MONOTONIC, &b);
    t = (b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec);
    if (t < best) best = t;
  }}
  printf("%.6g\n", best / K);
  for (i = 0; i < {P_}_NX; ++i) printf("%.17g ", x[i]);
  printf("\n");
  free(ys);
  return 0;
}}
"""


def c_per_step(exe: Path, p: Problem, ys: np.ndarray, repeats: int) -> tuple[float, np.ndarray]:
    text = " ".join([*(repr(float(v)) for v in [*p.x0, *p.P0.ravel()]), str(len(ys)),
                     *(repr(float(v)) for v in ys.ravel())])
    out = subprocess.run([str(exe), str(repeats)], input=text, capture_output=True, text=True, check=True)
    lines = out.stdout.splitlines()
    return float(lines[0]) * 1e-9, np.array([float(v) for v in lines[1].split()])


def one(p: Problem, family: str, K: int, repeat: int, tmp: Path) -> dict:
    transform = {"UKF": sm.UT(1.0, 2.0, 0.0), "EKF": sm.TT1()}[family]
    kf = sm.NonlinearKalmanFilter(p.f_model, p.h_model, p.Q, p.R, transform)
    _, ys = p.simulate(K, 1, seed=0)
    ys = ys[0]
    d = tmp / f"{p.name}_{family}"
    t0 = time.perf_counter()
    kf.export_c(d, name="kf")
    t_export = time.perf_counter() - t0
    (d / "bench.c").write_text(BENCH_MAIN.format(P="kf", P_="KF"))
    t0 = time.perf_counter()
    subprocess.run(["gcc", "-std=c99", "-O2", "-c", "kf.c"], cwd=d, check=True)
    t_build = time.perf_counter() - t0
    subprocess.run(["gcc", "-std=c99", "-O2", "kf.o", "bench.c", "-lm", "-o", "bench"], cwd=d, check=True)
    t_c, x_c = c_per_step(d / "bench", p, ys, max(repeat, 3))
    t0 = time.perf_counter()
    ref = kf.filter(ys, p.x0, p.P0)
    t_first = time.perf_counter() - t0
    # A large step runs on CasADi's VM while its C builds in the background: time the C.
    from symmon.filters.gaussian.step import compiled_step

    compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)._lib.wait()
    t_py = best(lambda: kf.filter(ys, p.x0, p.P0), repeat) / K
    Kp = min(K, 200)  # FilterPy is a Python loop: fewer steps
    fp = p.filterpy_ukf if family == "UKF" else p.filterpy_ekf
    t_fp = best(lambda: fp(ys[:Kp]), max(1, repeat // 2)) / Kp
    return {"n": p.n, "family": family, "export": t_export, "build": t_build,
            "size": (d / "kf.c").stat().st_size, "c": t_c, "py": t_py, "first": t_first, "fp": t_fp,
            "agree": rel_diff(x_c, ref.x[-1])}


def fmt_t(t: float) -> str:
    return f"{t * 1e6:.2f} µs" if t < 1e-3 else f"{t * 1e3:.2f} ms" if t < 1 else f"{t:.2f} s"


def report(rows: list[dict], K: int, load: tuple[str, str]) -> str:
    import casadi
    import filterpy

    lines = [
        HEADING,
        "",
        "Generated by `python benchmarks/export.py`: the UKF (`UT(1, 2, 0)`) and the EKF exported with "
        "`kf.export_c` and built with `gcc -std=c99 -O2`; per-step time of `NAME_predict` + `NAME_update` in a "
        f"C loop over K = {K} recorded steps, against `kf.filter` over the same steps (warm; first call into a "
        "fresh cache apart) and FilterPy's filters (a Python loop, ≤ 200 steps). n = 4: one target in range and "
        "bearing; n = 10, 30: 2 and 6 targets with a range bias each.",
        "",
        f"Python {sys.version.split()[0]}, NumPy {np.__version__}, CasADi {casadi.__version__}, FilterPy "
        f"{filterpy.__version__}, gcc; load average before / after: {load[0]} / {load[1]}.",
        "",
        "| n | filter | export | gcc -O2 | NAME.c | exported C / step | symmon `filter` / step | first `filter` call "
        "| FilterPy / step | symmon / C | FilterPy / C | agreement |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['n']} | {r['family']} | {fmt_t(r['export'])} | {fmt_t(r['build'])} | {r['size'] / 1024:.0f} KiB "
            f"| {fmt_t(r['c'])} | {fmt_t(r['py'])} | {fmt_t(r['first'])} | {fmt_t(r['fp'])} "
            f"| {r['py'] / r['c']:.2f}× | {r['fp'] / r['c']:.0f}× | {r['agree']:.1e} |")
    sizes = [(r["n"], r["size"]) for r in rows if r["family"] == "UKF"]
    if len(sizes) > 1:
        slope = np.polyfit(np.log([s[0] for s in sizes]), np.log([s[1] for s in sizes]), 1)[0]
        lines += ["", f"The UKF's C grows about n^{slope:.1f} in size (fitted over n = "
                  f"{', '.join(str(s[0]) for s in sizes)})."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps and repeats")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    a = ap.parse_args()
    if shutil.which("gcc") is None:
        sys.exit("gcc not found: the exported C cannot be built")
    K, repeat = (200, 3) if a.quick else (1000, 7)
    load0 = "%.2f" % os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for p in (cv_range_bearing(), targets(2), targets(6)):
            for family in ("UKF", "EKF"):
                rows.append(one(p, family, K, repeat, Path(tmp)))
                print(rows[-1], flush=True)
    text = report(rows, K, (load0, "%.2f" % os.getloadavg()[0]))
    print(text)
    if a.out:
        write_section(a.out, text, HEADING)


if __name__ == "__main__":
    main()
