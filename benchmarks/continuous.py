"""The continuous-discrete EKF and UKF against cd-dynamax's (jax.jit, vmap for a bank): first
call, warm, CPU and wall time, growth with n.

    python benchmarks/continuous.py [--sizes 4,8,16,32,64,128] [--timeout 600] [--out benchmarks/RESULTS.md]

Problems: white-noise acceleration in d dimensions (n = 2d states: dp = v dt, dv = dβ, Q_c = I;
the positions measured, R = 0.1 I), and Van der Pol (μ = 1, Q_c = 0.05 I, x₁ measured; n = 2).
K = 50 irregular intervals (uniform on [0.05, 0.5]); a bank of R = 10 runs.  Both sides
integrate the same moment ODEs by adaptive Dormand–Prince 5(4) to rtol 1e-6, atol 1e-9
(symmon's defaults; cd-dynamax: diffrax's Dopri5 with a PID controller at those tolerances)
and apply the same update.

Each (side, filter, problem) runs in its own subprocess, so that its first call is a first call:
symmon into a fresh cache (the filter built, its C loop generated and compiled), cd-dynamax its
``jax.jit`` trace and XLA compile.  Warm: the best of ``--repeat`` calls.  CPU: the process's
CPU time over the same calls (both cores count).  "before": symmon's Python integrator
(``integrator="solve_ivp"``), one run, warm.  Ratios are peer / symmon (> 1: symmon faster).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
HEADING = "## Continuous-discrete filters"
K, RUNS, RTOL, ATOL = 50, 10, 1e-6, 1e-9


def data(problem: str, n: int, seed: int = 0):
    """(times (K,), ys (RUNS, K, n_y), m0, P0) of a problem."""
    import numpy as np

    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.05, 0.5, K))
    if problem == "wna":
        d = n // 2
        m0, P0 = np.zeros(n), np.eye(n)
        ys = np.empty((RUNS, K, d))
        for r in range(RUNS):
            x, now = rng.multivariate_normal(m0, P0), 0.0
            for k, tk in enumerate(times):
                h = tk - now
                p, v = x[:d], x[d:]
                # the exact discretisation of white-noise acceleration (Q_c = I)
                cov = np.array([[h**3 / 3, h**2 / 2], [h**2 / 2, h]])
                w = rng.multivariate_normal(np.zeros(2), cov, size=d)
                x = np.concatenate([p + h * v + w[:, 0], v + w[:, 1]])
                now = tk
                ys[r, k] = x[:d] + np.sqrt(0.1) * rng.standard_normal(d)
        return times, ys, m0, P0
    m0, P0 = np.array([2.0, 0.0]), 0.1 * np.eye(2)
    ys = np.empty((RUNS, K, 1))
    for r in range(RUNS):
        x, now, dd = rng.multivariate_normal(m0, P0), 0.0, 1e-3
        for k, tk in enumerate(times):
            while now < tk - 1e-12:
                h = min(dd, tk - now)
                x = x + h * np.array([x[1], (1 - x[0] ** 2) * x[1] - x[0]]) + np.sqrt(0.05 * h) * rng.standard_normal(2)
                now += h
            ys[r, k] = x[0] + np.sqrt(0.1) * rng.standard_normal()
    return times, ys, m0, P0


def _cpu() -> float:
    """CPU time of this process and its finished children (the C compiler)."""
    import resource

    return time.process_time() + resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime


def _timed(fn, repeat: int) -> tuple[float, float]:
    """(best wall, CPU of that call) over ``repeat`` calls after one warm-up."""
    fn()
    best = (float("inf"), 0.0)
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        w, c = time.perf_counter() - w0, time.process_time() - c0
        best = min(best, (w, c))
    return best


def symmon_worker(label: str, problem: str, n: int, repeat: int) -> dict:
    os.environ["SYMMON_CACHE"] = tempfile.mkdtemp(prefix="symmon-bench-cd-")
    import numpy as np
    import sympy as sp

    import symmon as sm

    times, ys, m0, P0 = data(problem, n)
    w0, c0 = time.perf_counter(), _cpu()
    if problem == "wna":
        d = n // 2
        xs = sp.symbols(f"x0:{n}", real=True)
        sde = sm.SDE(list(xs), list(xs[d:]) + [0] * d, diffusion=np.vstack([np.zeros((d, d)), np.eye(d)]).tolist(),
                     name=f"wna{n}")
        h = sm.Model(list(xs), list(xs[:d]), name=f"wna{n}_h")
    else:
        x1, x2 = sp.symbols("x1 x2", real=True)
        sde = sm.SDE([x1, x2], [x2, (1 - x1**2) * x2 - x1], diffusion=np.eye(2).tolist(),
                     spectral_density=(0.05 * np.eye(2)).tolist(), name="vdp")
        h = sm.Model([x1, x2], [x1], name="vdp_h")
    R = 0.1 * np.eye(h.n_y)
    rule = sm.UT(float(np.sqrt(3.0)), 2.0, 1.0) if label == "ukf" else "ekf"  # cd-dynamax's UKF defaults
    cd = sm.ContinuousDiscreteKalmanFilter(sde, h, R, rule, rtol=RTOL, atol=ATOL)
    cd.filter(ys[0], m0, P0, times=times)
    first = (time.perf_counter() - w0, _cpu() - c0)
    cd.wait_compiled()  # a large loop builds in the background, on solve_ivp meanwhile
    built = (time.perf_counter() - w0, _cpu() - c0)
    out = {"first": first, "built": built, "evaluator": cd.evaluator,
           "one": _timed(lambda: cd.filter(ys[0], m0, P0, times=times), repeat),
           "bank": _timed(lambda: cd.filter(ys, m0, P0, times=times), repeat)}
    if n <= 16:
        py = sm.ContinuousDiscreteKalmanFilter(sde, h, R, rule, rtol=RTOL, atol=ATOL, integrator="solve_ivp")
        out["before"] = _timed(lambda: py.filter(ys[0], m0, P0, times=times), 1)
    out["x_last"] = np.asarray(cd.filter(ys[0], m0, P0, times=times).x[-1]).tolist()
    return out


def dynamax_worker(label: str, problem: str, n: int, repeat: int) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_platform_name", "cpu")
    import diffrax as dfx
    import jax.numpy as jnp
    import jax.random as jr
    import numpy as np
    from cd_dynamax import ContDiscreteNonlinearGaussianSSM, EKFHyperParams, UKFHyperParams, cdnlgssm_filter
    from cd_dynamax.dynamax.parameters import ParameterProperties
    from cd_dynamax.src.continuous_discrete_nonlinear_gaussian_ssm.cdnlgssm_utils import LearnableLinear

    sys.path.insert(0, str(HERE.parent / "tests" / "reference"))
    from make_cd_dynamax_reference import nonlinear_params  # the stored reference's builder, one copy

    times, ys, m0, P0 = data(problem, n)
    w0, c0 = time.perf_counter(), _cpu()
    props = ParameterProperties()
    if problem == "wna":
        d = n // 2
        A = np.zeros((n, n))
        A[:d, d:] = np.eye(d)
        drift = {"params": LearnableLinear(weights=jnp.asarray(A), bias=jnp.zeros(n)),
                 "props": LearnableLinear(weights=props, bias=props)}
        # square L (its UKF needs n noise dimensions): L Q_c Lᵀ = blkdiag(0, I) as on symmon's side
        L, Qc = np.diag([0.0] * d + [1.0] * d), np.eye(n)
        H = np.hstack([np.eye(d), np.zeros((d, d))])
    else:
        from cd_dynamax.src.utils.physics_based_models import LearnableVanDerPol

        drift = {"params": LearnableVanDerPol(mu=jnp.asarray(1.0)), "props": LearnableVanDerPol(mu=props)}
        L, Qc, H = np.eye(2), 0.05 * np.eye(2), np.array([[1.0, 0.0]])
    R = 0.1 * np.eye(H.shape[0])
    model = ContDiscreteNonlinearGaussianSSM(state_dim=n, emission_dim=H.shape[0])
    params = nonlinear_params(model, jr.PRNGKey(0), m0, P0, drift, L, Qc, H, R)
    s = {"solver": dfx.Dopri5(), "stepsize_controller": dfx.PIDController(rtol=RTOL, atol=ATOL), "dt0": 1e-3,
         "max_steps": 100_000}
    hyper = (EKFHyperParams(state_order="first", emission_order="first", diffeqsolve_settings=s) if label == "ekf"
             else UKFHyperParams(diffeqsolve_settings=s))
    t = jnp.asarray(times)[:, None]

    def one(y):
        return cdnlgssm_filter(params, y, t_emissions=t, filter_hyperparams=hyper).filtered_means

    f1 = jax.jit(one)
    fb = jax.jit(jax.vmap(one))
    Y = jnp.asarray(ys)
    f1(Y[0]).block_until_ready()
    first = (time.perf_counter() - w0, _cpu() - c0)
    out = {"first": first, "one": _timed(lambda: f1(Y[0]).block_until_ready(), repeat)}
    try:
        out["bank"] = _timed(lambda: fb(Y).block_until_ready(), repeat)
    except Exception as exc:  # noqa: BLE001  (a vmap the library does not allow is reported, not fatal)
        out["bank_error"] = str(exc).splitlines()[0][:200]
    out["x_last"] = np.asarray(f1(Y[0])[-1]).tolist()
    return out


def run_worker(side: str, label: str, problem: str, n: int, repeat: int, timeout: float, python: str) -> dict:
    sys.path.insert(0, str(HERE))
    from filters import run_json_worker

    exe = sys.executable
    try:
        sys.executable = python
        return run_json_worker([__file__, "--worker", side, label, problem, str(n), str(repeat)], timeout)
    finally:
        sys.executable = exe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=5, help=argparse.SUPPRESS)
    ap.add_argument("--sizes", default="4,8,16,32,64,128")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per subprocess")
    ap.add_argument("--peer-python", default=sys.executable,
                    help="the Python with cd-dynamax, JAX and diffrax (the bench extra)")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    a = ap.parse_args()
    if a.worker:
        side, label, problem, n, repeat = a.worker
        fn = symmon_worker if side == "symmon" else dynamax_worker
        print(json.dumps(fn(label, problem, int(n), int(repeat))))
        return
    sys.path.insert(0, str(HERE))
    import numpy as np
    from filters import publish
    from peers import exponent
    from report import fmt
    from smoothers import ratio

    load0 = os.getloadavg()[0]
    plan = [(lab, "vdp", 2) for lab in ("ekf", "ukf")]
    plan += [(lab, "wna", int(n)) for lab in ("ekf", "ukf") for n in a.sizes.split(",") if n]
    res = {}
    for label, problem, n in plan:
        for side in ("symmon", "cd-dynamax"):
            py = sys.executable if side == "symmon" else a.peer_python
            res[side, label, problem, n] = r = run_worker(side, label, problem, n, a.repeat, a.timeout, py)
            print(side, label, problem, n, {k: v for k, v in r.items() if k != "x_last"}, flush=True)
    load1 = os.getloadavg()[0]

    def cell(r: dict, key: str, i: int = 0) -> str:
        if "timeout" in r:
            return f"> {r['timeout']:.0f} s"
        if "error" in r:
            return "error"
        v = r.get(key)
        return fmt(v[i]) if v else "–"

    def rat(d: dict, s: dict, key: str) -> str:
        return ratio(d[key][0], s[key][0]) if d.get(key) and s.get(key) else "–"

    lines = [HEADING, "",
             f"Generated by `python benchmarks/continuous.py` (its docstring says what runs): K = {K} irregular "
             f"intervals, banks of {RUNS} runs, rtol {RTOL:g} and atol {ATOL:g} on both sides, each measurement in its "
             f"own subprocess. Times are wall (CPU in parentheses: the process's and its compiler's, both cores "
             f"counted). First: symmon's filter built and its first call into a fresh cache (a large C loop builds in "
             f"the background meanwhile, the call on solve_ivp; C in: when the build is done), and warm times "
             f"after the build, cd-dynamax traced and compiled by jax.jit. Ratios: cd-dynamax / "
             f"symmon, warm wall (> 1: symmon faster). UKF: α = √3, β = 2, κ = 1 on both sides. The last column: the "
             f"last filtered means' largest difference, one run. before: symmon's solve_ivp path (one run, warm). "
             f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, NumPy "
             f"{np.__version__}; load average (1 min) before / after: {load0:.2f} / {load1:.2f}.", ""]
    for label in ("ekf", "ukf"):
        lines += [f"### CD-{label.upper()}", "",
                  "| problem | n | first: symmon / cd-dynamax | one run: symmon / cd-dynamax | bank: symmon / cd-dynamax "
                  "| cd-dynamax / symmon: first, one, bank | before (solve_ivp) / symmon, one run | "
                  "max \\|x_K − x_K'\\| |",
                  "|---|---|---|---|---|---|---|---|"]
        cols: dict[str, list] = {}
        for (lab, problem, n) in [p for p in plan if p[0] == label]:
            s, d = res["symmon", lab, problem, n], res["cd-dynamax", lab, problem, n]
            diff = (f"{np.abs(np.subtract(s['x_last'], d['x_last'])).max():.1e}"
                    if s.get("x_last") and d.get("x_last") else "–")
            before = ratio(s["before"][0], s["one"][0]) if s.get("before") and s.get("one") else "–"
            lines.append(
                f"| {'Van der Pol' if problem == 'vdp' else 'WNA'} | {n} "
                f"| {cell(s, 'first')} ({cell(s, 'first', 1)}); C in {cell(s, 'built')} / {cell(d, 'first')} "
                f"({cell(d, 'first', 1)}) "
                f"| {cell(s, 'one')} ({cell(s, 'one', 1)}) / {cell(d, 'one')} ({cell(d, 'one', 1)}) "
                f"| {cell(s, 'bank')} ({cell(s, 'bank', 1)}) / "
                f"{cell(d, 'bank') if 'bank_error' not in d else 'no vmap'} "
                f"| {rat(d, s, 'first')}, {rat(d, s, 'one')}, {rat(d, s, 'bank')} | {before} | {diff} |")
            if problem == "wna":
                for side, r in (("symmon", s), ("cd-dynamax", d)):
                    if r.get("one"):
                        cols.setdefault(side, []).append((n, r["one"][0]))
        if cols:
            lines += ["", "Growth exponent p of the warm one-run time ∝ nᵖ (WNA, n ≥ 8): " + "; ".join(
                f"{k} {exponent([a for a, _ in v if a >= 8], [b for a, b in v if a >= 8])}" for k, v in cols.items())
                + ".", ""]
    publish(lines, a.out, HEADING)


if __name__ == "__main__":
    main()
