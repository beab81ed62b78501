"""The maximum-likelihood fit against dynamax's log-likelihood under jax.value_and_grad + SciPy.

    pip install ".[bench]"
    python benchmarks/fit.py [--quick] [--out benchmarks/RESULTS.md]

The problem: n = 4, 10, 30 states (one constant-velocity target; 2 and 6 targets with a
range-bias state each, benchmarks/filters.py), K = 100 steps, one run; two parameters, the
process-noise intensity q (the motion is x_{k+1} = F x_k + q L w_k with L Lᵀ the benchmark's
Q, so the process noise is q² Q) and a range bias b of the sensor (added to every range).
The data are simulated at q = 1, b = 1.5; both fits start at q = 0.5, b = 0.

- **symmon**: ``kf.fit(ys, x0, {"q": 0.5, "b": 0.0}, bounds={"q": (1e-6, None)})`` with the
  EKF (``TT1()``): L-BFGS-B on the exact gradient of the log-likelihood (CasADi), then the
  standard errors from its exact Hessian and a filter run at the estimates;
- **dynamax**: the same L-BFGS-B (SciPy, the same start, bounds and ``gtol``) on
  ``jax.jit(jax.value_and_grad(-loglik))`` (the optimiser on one BLAS thread, as symmon's) with ``loglik(θ)`` the ``marginal_loglik`` of
  ``extended_kalman_filter`` (float64), then the standard errors from a central difference
  (step 1e-5) of that exact gradient at the optimum (symmon's come from its exact Hessian;
  ``jax.hessian`` through the scan takes 40 s to compile at n = 4, 4 min at n = 30).

Both first calls build from nothing (symmon into a fresh cache; JAX traces and compiles);
warm times (wall and CPU) are the best of a few repeats, symmon and dynamax interleaved.  dynamax has no
angle handling, so the bearing is not declared an angle in symmon's model: the two
log-likelihoods are then the same function (neither wraps the bearing's innovation), checked
at the start, and the estimates must agree to the optimiser's tolerance.
Ratios are dynamax time / symmon time (> 1: symmon faster).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
os.environ.setdefault("SYMMON_CACHE", tempfile.mkdtemp(prefix="symmon-bench-fit-"))

import numpy as np  # noqa: E402
import threadpoolctl  # noqa: E402
import sympy as sp  # noqa: E402

import symmon as sm  # noqa: E402
from filters import cv_range_bearing, targets, publish  # noqa: E402

HEADING = "## Maximum-likelihood fit"
TRUTH = {"q": 1.0, "b": 1.5}
START = {"q": 0.5, "b": 0.0}
GTOL = 1e-6


class FitProblem:
    """A benchmark problem of benchmarks/filters.py with q and b as model parameters."""

    def __init__(self, p) -> None:
        self.p, self.n, self.n_y = p, p.n, p.n_y
        X = list(p.f_model.inputs)
        q, b = sp.symbols("q b", real=True)
        w = sp.symbols(f"w0:{p.n}", real=True)
        self.L = np.linalg.cholesky(p.Q)
        motion = sp.Matrix(p.F) * sp.Matrix(X) + q * sp.Matrix(self.L) * sp.Matrix(w)
        self.f = sm.Model(X, list(motion), noise=list(w), params=[q], name=f"fitbench_{p.name}_f")
        h = list(p.h_model.outputs)
        h = [e + b if i % 2 == 0 else e for i, e in enumerate(h)]  # b on every range
        self.h = sm.Model(X, h, params=[b], name=f"fitbench_{p.name}_h")  # no angle: see the notes
        self.hx = sp.lambdify([X], p.h_model.outputs, "numpy")

    def simulate(self, K: int, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        p = self.p
        Lq, Lr = TRUTH["q"] * self.L, np.linalg.cholesky(p.R)
        x = p.x0 + np.linalg.cholesky(p.P0) @ rng.standard_normal(self.n)
        ys = np.empty((K, self.n_y))
        for k in range(K):
            x = p.F @ x + Lq @ rng.standard_normal(self.n)
            y = np.array(self.hx(x), dtype=float)
            y[0::2] += TRUTH["b"]
            ys[k] = y + Lr @ rng.standard_normal(self.n_y)
        return ys

    def kf(self):
        return sm.NonlinearKalmanFilter(self.f, self.h, np.eye(self.n), self.p.R, sm.TT1())


def symmon_fit(fp: FitProblem, ys: np.ndarray):
    kf = fp.kf()
    return kf.fit(ys, sm.Gaussian(fp.p.x0, fp.p.P0), dict(START), bounds={"q": (1e-6, None)})


def dynamax_fit(fp: FitProblem, ys: np.ndarray):
    """The peer's fit: returns a function that runs it (estimates, standard errors, ℓ, nit)
    and ℓ at the start."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from dynamax.nonlinear_gaussian_ssm import ParamsNLGSSM
    from dynamax.nonlinear_gaussian_ssm.inference_ekf import extended_kalman_filter
    from scipy import optimize

    p = fp.p
    F, Q, R = jnp.asarray(p.F), jnp.asarray(p.Q), jnp.asarray(p.R)
    x0, P0, y = jnp.asarray(p.x0), jnp.asarray(p.P0), jnp.asarray(ys)
    biased = p.n % 5 == 0  # the stacked targets carry a range-bias state (state 4 of each block)

    def h(x, b):
        out = []
        for i in range(p.n_y // 2):
            base = 5 * i if biased else 0
            px, py = x[base], x[base + 1]
            bias = x[base + 4] if biased else 0.0
            out += [jnp.sqrt(px**2 + py**2) + bias + b, jnp.arctan2(py, px)]
        return jnp.stack(out)

    def loglik(theta):
        q, b = theta[0], theta[1]
        # dynamax updates before predicting: start it at symmon's first prediction.
        params = ParamsNLGSSM(initial_mean=F @ x0, initial_covariance=F @ P0 @ F.T + q**2 * Q,
                              dynamics_function=lambda x: F @ x, dynamics_covariance=q**2 * Q,
                              emission_function=lambda x: h(x, b), emission_covariance=R)
        return extended_kalman_filter(params, y, output_fields=[]).marginal_loglik

    vg = jax.jit(jax.value_and_grad(lambda t: -loglik(t)))

    def hess(t, h=1e-5):
        # A central difference of the exact gradient: jax.hessian (forward over reverse through
        # the scan) takes 40 s to compile at n = 4 and 4 min at n = 30.
        cols = [(np.asarray(vg(t + h * e)[1]) - np.asarray(vg(t - h * e)[1])) / (2 * h) for e in np.eye(len(t))]
        return np.column_stack(cols)

    def run():
        def obj(t):
            v, g = vg(jnp.asarray(t))
            return float(v), np.asarray(g, dtype=float)

        # One BLAS thread, as symmon's fit runs its optimiser: OpenBLAS's threads would wake for
        # L-BFGS-B's size-2 algebra and spin beside the jitted calls, inflating dynamax's time.
        with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
            res = optimize.minimize(obj, np.array([START["q"], START["b"]]), jac=True, method="L-BFGS-B",
                                    bounds=[(1e-6, None), (None, None)], options={"maxiter": 200, "gtol": GTOL})
            info = np.asarray(hess(res.x))  # of −ℓ: the observed information
        se = np.sqrt(np.diag(np.linalg.inv(info)))
        return res.x, se, -res.fun, res.nit

    return run, lambda t: float(loglik(jnp.asarray(t)))


def timed(fn) -> tuple[float, float]:
    """Wall and CPU time (``time.process_time``: all threads) of one call, after a warm-up call."""
    fn()
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def fmt(t):
    return f"{t * 1e3:.1f} ms" if t < 1 else f"{t:.2f} s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    a = ap.parse_args()
    K, repeat = 100, (2 if a.quick else 5)
    load0 = "%.2f" % os.getloadavg()[0]
    rows = []
    for p in (cv_range_bearing(), targets(2), targets(6)):
        fp = FitProblem(p)
        ys = fp.simulate(K, seed=1)
        t0 = time.perf_counter()
        s = symmon_fit(fp, ys)
        s_first = time.perf_counter() - t0
        # The first fit runs on CasADi's VM while the compiled log-likelihood builds in the
        # background (the compile policy); the warm fits below use the C.
        from symmon.filters.gaussian.fit import compiled_loglik
        from symmon.filters.gaussian.step import compiled_step

        kf = fp.kf()
        compiled_loglik(kf).wait()
        compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)._lib.wait()
        s_built = time.perf_counter() - t0
        t0 = time.perf_counter()
        run, ll = dynamax_fit(fp, ys)
        d = run()
        d_first = time.perf_counter() - t0
        ll_s = float(np.sum(fp.kf().filter(ys, sm.Gaussian(p.x0, p.P0), params=START).log_likelihood))
        ll_d = ll(np.array([START["q"], START["b"]]))
        s_warm = d_warm = s_cpu = d_cpu = np.inf
        for _ in range(repeat):  # interleaved: both see the same load
            (w, c), (wd, cd) = timed(lambda: symmon_fit(fp, ys)), timed(run)
            s_warm, s_cpu, d_warm, d_cpu = min(s_warm, w), min(s_cpu, c), min(d_warm, wd), min(d_cpu, cd)
        est_s = np.array([s.estimates["q"], s.estimates["b"]])
        se_s = np.array([s.std_errors["q"], s.std_errors["b"]])
        row = dict(n=p.n, s_first=s_first, s_built=s_built, d_first=d_first, s_warm=s_warm, d_warm=d_warm,
                   s_cpu=s_cpu, d_cpu=d_cpu,
                   ll_start=abs(ll_s - ll_d) / abs(ll_d), est=np.max(np.abs(est_s - d[0]) / se_s),
                   se=np.max(np.abs(se_s / d[1] - 1)), ll_opt=(s.log_likelihood - d[2]) / abs(d[2]),
                   nit=(s.iterations, d[3]), est_s=est_s, se_s=se_s)
        rows.append(row)
        print(row, flush=True)
    lines = [HEADING, "",
             f"Generated by `python benchmarks/fit.py`: the EKF's maximum-likelihood fit of a process-noise intensity q "
             f"and a range bias b (truth q = {TRUTH['q']:g}, b = {TRUTH['b']:g}; start q = {START['q']:g}, "
             f"b = {START['b']:g}) on one run of K = {K} steps; symmon's `kf.fit` against dynamax's "
             "`extended_kalman_filter(...).marginal_loglik` under `jax.jit(jax.value_and_grad)` and the same SciPy "
             f"L-BFGS-B (gtol {GTOL:g}), plus the standard errors from a central difference of that gradient (symmon: its exact Hessian), float64. The "
             "bearing is not declared an angle (dynamax has none), so both compute the same function, unwrapped. First calls build "
             "from nothing (symmon into a fresh cache, on CasADi's VM while the C builds in the background, in "
             "parentheses until it is done; JAX traces and compiles); warm: best of "
             f"{repeat}, interleaved, wall and CPU time (`time.process_time`, all threads: what a loaded machine "
             "leaves comparable). Ratio: dynamax / symmon (> 1: symmon faster). Agreement: ℓ at the start "
             "(relative), the estimates (largest difference in standard errors), the standard errors (relative), "
             f"ℓ at the optimum (symmon − dynamax, relative). Load average before / after: {load0} / {os.getloadavg()[0]:.2f}.",
             "",
             "| n | symmon first (C built) / warm | dynamax first / warm | dynamax / symmon: first, warm | warm CPU: symmon, "
             "dynamax, ratio | iterations (symmon, dynamax) | estimates q, b ± SE | agreement: ℓ(start), θ̂ / SE, SE, Δℓ(θ̂) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        est = ", ".join(f"{v:.4f} ± {e:.2g}" for v, e in zip(r["est_s"], r["se_s"]))
        lines.append(f"| {r['n']} | {fmt(r['s_first'])} ({fmt(r['s_built'])}) / {fmt(r['s_warm'])} | {fmt(r['d_first'])} / {fmt(r['d_warm'])} "
                     f"| {r['d_first'] / r['s_first']:.2f}×, {r['d_warm'] / r['s_warm']:.2f}× "
                     f"| {fmt(r['s_cpu'])}, {fmt(r['d_cpu'])}, {r['d_cpu'] / r['s_cpu']:.2f}× | {r['nit'][0]}, {r['nit'][1]} "
                     f"| {est} | {r['ll_start']:.1e}, {r['est']:.1e}, {r['se']:.1e}, {r['ll_opt']:.1e} |")
    publish(lines, a.out, HEADING)


if __name__ == "__main__":
    main()
