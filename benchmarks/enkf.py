"""Timings of symmon's ensemble Kalman filters against a hand-vectorised NumPy EnKF/ETKF (and
DAPPER's, when a Python with DAPPER is given), in one run.

    python benchmarks/enkf.py [--quick] [--out benchmarks/RESULTS.md] [--dapper PYTHON]

The model, the same in all: Lorenz-96 with n = 4 … 128 states (F = 8), one RK4 step of
dt = 0.05 a step, every state observed with variance 1, no model noise (the set-up of Sakov &
Oke 2008 at other sizes); N = 40 members; a bank of R = 10 runs of K = 100 steps from the
prior N(x_spun, 0.001 I).  ``kind="sqrt"`` with inflation 1.01 and ``kind="stochastic"`` with
1.06.  The NumPy filters (:func:`numpy_enkf`) run the same algorithm written directly: RK4 on
the (R·N, n) members, the same analyses batched over the runs, ``keep=("x",)`` in symmon.
The NumPy filter runs on one BLAS thread, as symmon's recursion does.  Times per step, best of 3 warm calls (wall time and process CPU time, all threads); symmon's
first call apart: its first filter call in a fresh compiled-code cache, including the build
of the sympy RK4 model (``sm.Model``) and its compilation.  DAPPER (``--dapper`` names a
Python that imports it: a throwaway virtual environment, never a dependency of symmon) runs
its ``EnKF('Sqrt' | 'PertObs', N=40)`` on its own Lorenz-96 for one run, timed in that
process (one BLAS thread too; its ``assimilate`` also computes its statistics at each step).  Ratios: peer / symmon (> 1: symmon faster).  The machine may be shared: the load
average is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
os.environ.setdefault("SYMMON_CACHE", tempfile.mkdtemp(prefix="symmon-bench-enkf-"))

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

import symmon as sm  # noqa: E402
from report import fmt, write_section  # noqa: E402

HEADING = "## Ensemble Kalman filters"
FORCING, DT, MEMBERS, RUNS = 8.0, 0.05, 40, 10
CASES = (("sqrt", 1.01), ("stochastic", 1.06))
# The NumPy filter runs on one OpenBLAS thread, as symmon's recursion does (one_blas_thread):
# on this shared 2-core machine OpenBLAS's threads spin between the small products and
# factors of a step (n = 128: a 128 × 128 Cholesky factor took 0.4 s, 3 ms on one thread).
PEER_BLAS_THREADS = 1


def lorenz96_model(n: int) -> tuple[sm.Model, sm.Model]:
    """One RK4 step of Lorenz-96 as sympy models f and h = identity."""
    x = sp.symbols(f"x0:{n}", real=True)

    def d(v):
        return [(v[(i + 1) % n] - v[i - 2]) * v[i - 1] - v[i] + FORCING for i in range(n)]

    k1 = d(x)
    k2 = d([x[i] + DT / 2 * k1[i] for i in range(n)])
    k3 = d([x[i] + DT / 2 * k2[i] for i in range(n)])
    k4 = d([x[i] + DT * k3[i] for i in range(n)])
    f = sm.Model(list(x), [x[i] + DT / 6 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]) for i in range(n)],
                 name=f"bench_l96_{n}")
    return f, sm.Model(list(x), list(x), name=f"bench_l96_obs_{n}")


def rk4(X: np.ndarray) -> np.ndarray:
    """One RK4 step of Lorenz-96 on the rows of X."""
    def d(v):
        return (np.roll(v, -1, axis=-1) - np.roll(v, 2, axis=-1)) * np.roll(v, 1, axis=-1) - v + FORCING

    k1 = d(X)
    k2 = d(X + DT / 2 * k1)
    k3 = d(X + DT / 2 * k2)
    k4 = d(X + DT * k3)
    return X + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def numpy_enkf(ys: np.ndarray, m0: np.ndarray, P0: np.ndarray, kind: str, infl: float, seed: int = 0) -> np.ndarray:
    """The hand-vectorised ensemble filter: ys (R, K, n) of H = I, R = I; its analysis means."""
    rng = np.random.default_rng(seed)
    Rr, K, n = ys.shape
    N = MEMBERS
    E = m0 + rng.standard_normal((Rr, N, n)) @ np.linalg.cholesky(P0).T
    out = np.empty((Rr, K, n))
    for k in range(K):
        E = rk4(E.reshape(-1, n)).reshape(Rr, N, n)
        mu = E.mean(axis=1, keepdims=True)
        A = infl * (E - mu)
        E = mu + A
        S = A.transpose(0, 2, 1) @ A / (N - 1) + np.eye(n)  # H = I: Y = A
        if kind == "stochastic":
            D = rng.standard_normal((Rr, N, n))
            D -= D.mean(axis=1, keepdims=True)
            Kg = np.linalg.solve(S, A.transpose(0, 2, 1) @ A / (N - 1)).transpose(0, 2, 1)
            E = E + (ys[:, k, None, :] + D - E) @ Kg.transpose(0, 2, 1)
        else:
            Y = A / np.sqrt(N - 1)  # R = I: no whitening
            lam, V = np.linalg.eigh(Y @ Y.transpose(0, 2, 1))  # N × N
            lam = np.maximum(lam, 0.0)
            nu = ys[:, k] - mu[:, 0]
            w = V @ ((V.transpose(0, 2, 1) @ (Y @ nu[..., None])) / (1 + lam)[..., None])
            T = (V / np.sqrt(1 + lam)[:, None, :]) @ V.transpose(0, 2, 1)
            E = mu + (w.transpose(0, 2, 1) @ A)[:, :1] / np.sqrt(N - 1) + T @ A
        out[:, k] = E.mean(axis=1)
    return out


def wall_cpu(fn) -> tuple[float, float]:
    t, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t, time.process_time() - c


def best(fn, reps: int) -> tuple[float, float]:
    w, c = np.inf, np.inf
    for _ in range(reps):
        a, b = wall_cpu(fn)
        w, c = min(w, a), min(c, b)
    return w, c


DAPPER_SCRIPT = r"""
import json, sys, time
import numpy as np
import dapper.mods as modelling, dapper.da_methods as da
from dapper.mods.Lorenz96 import step, x0
n, K, N = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
try:
    tseq = modelling.Chronology(0.05, dko=1, Ko=K, BurnIn=0)
except TypeError:  # DAPPER before 1.3 names them dkObs, KObs
    tseq = modelling.Chronology(0.05, dkObs=1, KObs=K, BurnIn=0)
Dyn = {"M": n, "model": step, "noise": 0}
X0 = modelling.GaussRV(mu=x0(n), C=0.001)
Obs = modelling.Id_Obs(n); Obs["noise"] = 1
HMM = modelling.HiddenMarkovModel(Dyn, Obs, tseq, X0)
xx, yy = HMM.simulate()
out = {}
for name, upd, infl in (("sqrt", "Sqrt", 1.01), ("stochastic", "PertObs", 1.06)):
    best = np.inf
    for _ in range(3):
        xp = da.EnKF(upd, N=N, infl=infl)
        t = time.perf_counter(); xp.assimilate(HMM, xx, yy); best = min(best, time.perf_counter() - t)
    out[name] = best / K
print(json.dumps(out))
"""


def dapper_times(python: str, n: int, K: int) -> dict | None:
    """DAPPER's seconds per step (one run) in ``python``, or None when it fails."""
    try:
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        done = subprocess.run([python, "-c", DAPPER_SCRIPT, str(n), str(K), str(MEMBERS)], capture_output=True,
                              text=True, timeout=900, env=env)
        return json.loads(done.stdout.strip().splitlines()[-1])
    except Exception as exc:  # a peer's failure is reported, not fatal
        print(f"DAPPER at n = {n}: {exc}; {getattr(locals().get('done'), 'stderr', '')[-500:]}", file=sys.stderr)
        return None




def run(quick: bool, dapper: str | None) -> str:
    K = 20 if quick else 100
    sizes = (4, 16, 64) if quick else (4, 8, 16, 32, 64, 128)
    load0 = os.getloadavg()[0]
    rows = []
    for n in sizes:
        t0 = time.perf_counter()
        f, h = lorenz96_model(n)
        build = time.perf_counter() - t0
        start = np.full(n, FORCING)
        start[0] += 0.01
        spin = start[None]
        for _ in range(500):
            spin = rk4(spin)
        prior = sm.Gaussian(spin[0], 1e-3 * np.eye(n))
        Q, R = np.zeros((n, n)), np.eye(n)
        xs, ys = sm.simulate(f, h, Q, R, prior, K, runs=RUNS, seed=1)  # compiles f and h
        first_model = time.perf_counter() - t0
        peer = dapper_times(dapper, n, K) if dapper else None
        for kind, infl in CASES:
            filt = sm.EnsembleKalmanFilter(f, h, Q, R, members=MEMBERS, kind=kind, inflation=infl)
            t = time.perf_counter()
            res = filt.filter(ys, prior, keep=("x",))
            first = time.perf_counter() - t
            w_sm, c_sm = best(lambda: filt.filter(ys, prior, keep=("x",)), 3)
            w_np, c_np = best(lambda: numpy_enkf(ys, prior.mean, prior.cov, kind, infl), 3)
            a = np.sqrt(((res.x - xs) ** 2).mean(axis=-1))[:, K // 2:].mean()
            b = np.sqrt(((numpy_enkf(ys, prior.mean, prior.cov, kind, infl) - xs) ** 2).mean(axis=-1))[:, K // 2:].mean()
            d = None if peer is None else peer[kind]
            rows.append((n, kind, build, first_model, first, w_sm / K, c_sm / K, w_np / K, c_np / K, d, a, b))
            print(rows[-1], flush=True)
    load1 = os.getloadavg()[0]
    lines = [HEADING, "",
             "Generated by `python benchmarks/enkf.py` (its docstring gives the set-up): Lorenz-96 (RK4, dt = 0.05, "
             f"every state observed, R = I, Q = 0), N = {MEMBERS} members, a bank of R = {RUNS} runs of K = {K} steps; "
             "per-step times of the whole bank (best of 3 warm calls; wall and process CPU, all threads; BLAS on one "
             "thread in symmon's recursion and in the NumPy filter). "
             "'model build' is the sympy RK4 model, 'first model call' adds `sm.simulate`'s compilation of f and h "
             "in a fresh cache; 'first filter call' follows it. DAPPER: one run (not a bank), its own Lorenz-96, "
             "per step. Ratios: peer / symmon (> 1: symmon faster). RMSE: the analysis RMSE over the second half "
             f"of the steps, symmon's and NumPy's (Monte Carlo, their own draws). x86_64, {os.cpu_count()} cores; "
             f"load average before / after: {load0:.2f} / {load1:.2f}.", "",
             "| n | filter | model build | first model call | first filter call | symmon / step | NumPy / step | "
             "NumPy / symmon | CPU / step: symmon, NumPy | DAPPER / step (1 run) | RMSE symmon, NumPy |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, kind, build, fm, first, ws, cs, wn, cn, d, a, b in rows:
        name = f"ETKF(infl {CASES[0][1]})" if kind == "sqrt" else f"EnKF(infl {CASES[1][1]})"
        dap = "not run" if d is None else fmt(d)
        lines.append(f"| {n} | {name} | {fmt(build)} | {fmt(fm)} | {fmt(first)} | {fmt(ws)} | {fmt(wn)} | "
                     f"{wn / ws:.2f}× | {fmt(cs)}, {fmt(cn)} | {dap} | {a:.3f}, {b:.3f} |")
    return "\n".join(lines) + "\n"




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="K = 20, n = 4, 16, 64")
    parser.add_argument("--out", type=Path, help="write the section into this Markdown file")
    parser.add_argument("--dapper", help="a Python interpreter that imports DAPPER (a throwaway venv)")
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits
    with threadpool_limits(PEER_BLAS_THREADS):  # the NumPy filter's products (symmon limits its own)
        text = run(args.quick, args.dapper)
    print(text)
    if args.out:
        write_section(args.out, text)


if __name__ == "__main__":
    main()
