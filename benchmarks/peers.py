"""symmon against its fastest peers at real sizes, in one run: filters and batched moments.

    pip install ".[bench]"
    python benchmarks/peers.py [--quick] [--sizes 4,10,20,30,64] [--out benchmarks/RESULTS.md]

**Filters.** Range–bearing trackers of n states (``benchmarks/filters.py``: n = 4 one target;
n = 5k, k targets with a range bias each, stacked), K = 100 steps:

- **symmon**: ``NonlinearKalmanFilter`` with ``UT(1, 2, 0)`` and ``TT1()``; one run and a bank
  of R runs in one ``filter(ys, x0, keep=("x", "P"))`` call; the first call into a fresh cache
  (building the step and compiling it, or starting on CasADi's VM while the C builds in the
  background: the time until the C is in is given too);
- **dynamax**: ``unscented_kalman_filter`` / ``extended_kalman_filter`` under ``jax.jit`` (one run)
  and ``jax.jit(jax.vmap(...))`` (the bank), float64, asked for the filtered means and
  covariances only; first call (trace and XLA compile) and warm;
- **NumPy**: a hand-vectorised UKF bank (every run at once: batched Cholesky, sigma points,
  einsum moments, batched solve), with the circular mean and wrapped residuals of the
  bearings as symmon;
- **FilterPy**: ``UnscentedKalmanFilter`` one run (a Python loop over steps).

**Monte Carlo.** The W^full MoN of ``examples/gmti.toml`` (the bearing an angle) by
``MonteCarlo(N)``, against numba ``parallel=True`` computing the same sample statistics,
and the machine's limit: 4 normals a sample from NumPy's fastest generator on every core.

**Moments.** ``propagate_many`` of K = 10⁴ Gaussians through the sparse model of
``benchmarks/scale.py`` (y_i = sqrt(x_i² + x_{i+1}² + 1) + sin(x_i x_{i+2})), UT and TT2,
against ``jax.jit(jax.vmap(...))`` of the same UT (Cholesky, 2n + 1 points, weighted sums)
and TT2 (``jax.jacfwd``, ``jax.hessian``).  symmon's UT of a batch runs its compiled batch
kernel (``symmon.propagation.kernel``) once that is built in the background; the first
call runs the NumPy rule meanwhile.

Ratios are peer time / symmon time (> 1: symmon faster); times are the best of several
repeats after a warm-up.  Peers that are not installed are skipped with a note.  Growth
exponents p (cost ∝ nᵖ) are least-squares fits over n ≥ 10.  The estimates are compared
(maximum relative difference of the filtered means against symmon's).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
os.environ.setdefault("SYMMON_CACHE", tempfile.mkdtemp(prefix="symmon-bench-peers-"))

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

import symmon as sm  # noqa: E402
from report import best_wall_cpu  # noqa: E402
from symmon.compile import compiled  # noqa: E402
from symmon.propagation.kernel import batch_kernel  # noqa: E402
from filters import ALPHA, BETA, KAPPA, best, cv_range_bearing, rel_diff, targets, wrap, publish  # noqa: E402
from scale import sparse_model  # noqa: E402
from smoothers import fmt, ratio  # noqa: E402

HEADING = "## Peers at real sizes"
#: Seconds of repeats of a warm filter call (both sides alike): a fast call is timed warm.
MIN_TIME = 1.0


def problem(n: int):
    return cv_range_bearing() if n == 4 else targets(max(1, round(n / 5)))


# --------------------------------------------------------------------------- symmon
TRANSFORMS = {"ukf": lambda: sm.UT(ALPHA, BETA, KAPPA), "ekf": sm.TT1}


def symmon_filters(p, ys, repeat, labels=("ukf", "ekf"), wait=None):
    from symmon.filters.gaussian.step import compiled_step

    x0 = sm.Gaussian(p.x0, p.P0)
    out = {}
    for label in labels:
        transform = TRANSFORMS[label]()
        kf = sm.NonlinearKalmanFilter(p.f_model, p.h_model, p.Q, p.R, transform)
        t0 = time.perf_counter()
        kf.filter(ys[0], x0, keep=("x", "P"))
        first = time.perf_counter() - t0
        lib = compiled_step(kf.f_model, kf.h_model, kf.transform, kf.angle_states)._lib
        if not lib.wait(wait):
            out[label] = {"first": first, "built": None}
            continue
        out[label] = {
            "first": first, "built": time.perf_counter() - t0,
            "one": best(lambda: kf.filter(ys[0], x0, keep=("x", "P")), repeat, MIN_TIME),
            "bank": best(lambda: kf.filter(ys, x0, keep=("x", "P")), max(1, repeat // 2), MIN_TIME),
            "x": kf.filter(ys, x0, keep=("x", "P")).x,
        }
    return out


# --------------------------------------------------------------------------- dynamax
def dynamax_filters(p, ys, repeat, labels=("ukf", "ekf")):
    try:
        import jax
        from dynamax.nonlinear_gaussian_ssm import (ParamsNLGSSM, UKFHyperParams, extended_kalman_filter,
                                                    unscented_kalman_filter)
    except ImportError:
        return None
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    F = jnp.asarray(p.F)
    h = sp.lambdify([p.f_model.inputs], p.h_model.outputs, "jax")
    # dynamax updates before it predicts: start it at the first prediction, as symmon starts at x0.
    params = ParamsNLGSSM(initial_mean=jnp.asarray(p.F @ p.x0), initial_covariance=jnp.asarray(p.F @ p.P0 @ p.F.T + p.Q),
                          dynamics_function=lambda x: F @ x, dynamics_covariance=jnp.asarray(p.Q),
                          emission_function=lambda x: jnp.stack(h(x)), emission_covariance=jnp.asarray(p.R))
    hp = UKFHyperParams(alpha=ALPHA, beta=BETA, kappa=KAPPA)
    fields = ["filtered_means", "filtered_covariances"]
    runs = {
        "ukf": lambda y: unscented_kalman_filter(params, y, hp, output_fields=fields).filtered_means,
        "ekf": lambda y: extended_kalman_filter(params, y, output_fields=fields).filtered_means,
    }
    y1, yR = jnp.asarray(ys[0]), jnp.asarray(ys)
    out = {}
    for label in labels:
        run = runs[label]
        one, bank = jax.jit(run), jax.jit(jax.vmap(run))
        t0 = time.perf_counter()
        one(y1).block_until_ready()
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        xR = bank(yR).block_until_ready()
        first_bank = time.perf_counter() - t0
        out[label] = {"first": first, "first_bank": first_bank,
                      "one": best(lambda: one(y1).block_until_ready(), repeat, MIN_TIME),
                      "bank": best(lambda: bank(yR).block_until_ready(), max(1, repeat // 2), MIN_TIME),
                      "x": np.asarray(xR)}
    return out


# --------------------------------------------------------------------------- NumPy
def ut_weights(n: int):
    """Mean and covariance weights and the scale √(n + λ) of ``UT(ALPHA, BETA, KAPPA)``, written
    out here so that the peers do not take them from symmon."""
    lam = ALPHA**2 * (n + KAPPA) - n
    wm = np.full(2 * n + 1, 1 / (2 * (n + lam)))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1 - ALPHA**2 + BETA
    return wm, wc, np.sqrt(n + lam)


def batched_update(xp, Pp, yp, S, C, y, ang):
    """The Kalman update of every run at once (gain by a batched solve, the angle outputs'
    innovations wrapped, P⁺ symmetrised), shared by the NumPy UKF and EKF banks."""
    G = np.linalg.solve(S, C.transpose(0, 2, 1)).transpose(0, 2, 1)
    nu = y - yp
    nu[:, ang] = wrap(nu[:, ang])
    P = Pp - G @ S @ G.transpose(0, 2, 1)
    return xp + np.einsum("rab,rb->ra", G, nu), 0.5 * (P + P.transpose(0, 2, 1))


def numpy_ukf_bank(p, ys):
    """Every run at once: the UKF (``UT(1, 2, 0)``) of symmon with batched NumPy."""
    runs, K, _ = ys.shape
    n = p.n
    wm, wc, c = ut_weights(n)
    hx = sp.lambdify(p.f_model.inputs, p.h_model.outputs, "numpy")
    ang = list(p.angles)

    def points(x, P):
        L = c * np.linalg.cholesky(P)  # (R, n, n), columns are the offsets
        off = np.concatenate([np.zeros((runs, n, 1)), L, -L], axis=2).transpose(0, 2, 1)
        return x[:, None, :] + off  # (R, 2n+1, n)

    def mean(Y, angles):
        m = Y[:, 0] + np.einsum("j,rjk->rk", wm, Y - Y[:, :1])
        if angles:
            m[:, angles] = np.arctan2(np.einsum("j,rjk->rk", wm, np.sin(Y[..., angles])),
                                      np.einsum("j,rjk->rk", wm, np.cos(Y[..., angles])))
        return m

    x = np.broadcast_to(p.x0, (runs, n)).copy()
    P = np.broadcast_to(p.P0, (runs, n, n)).copy()
    xs, Ps = np.empty((runs, K, n)), np.empty((runs, K, n, n))
    for k in range(K):
        X = points(x, P) @ p.F.T
        xp = mean(X, [])
        D = X - xp[:, None]
        Pp = np.einsum("j,rja,rjb->rab", wc, D, D) + p.Q
        X = points(xp, Pp)
        Y = np.stack(np.broadcast_arrays(*hx(*np.moveaxis(X, -1, 0))), axis=-1)
        yp = mean(Y, ang)
        dY = Y - yp[:, None]
        dY[..., ang] = wrap(dY[..., ang])
        S = np.einsum("j,rja,rjb->rab", wc, dY, dY) + p.R
        C = np.einsum("j,rja,rjb->rab", wc, X - xp[:, None], dY)
        x, P = batched_update(xp, Pp, yp, S, C, ys[:, k], ang)
        xs[:, k], Ps[:, k] = x, P
    return xs, Ps


def numpy_ekf_bank(p, ys):
    """Every run at once: the EKF (TT1) of symmon with batched NumPy (the Jacobian of h
    lambdified from sympy, batched solve), the bearings' innovations wrapped."""
    runs, K, _ = ys.shape
    n = p.n
    X = p.f_model.inputs
    hx = sp.lambdify(X, p.h_model.outputs, "numpy")
    Hx = sp.lambdify(X, list(sp.Matrix(p.h_model.outputs).jacobian(X)), "numpy")  # row-major entries
    ang = list(p.angles)
    x = np.broadcast_to(p.x0, (runs, n)).copy()
    P = np.broadcast_to(p.P0, (runs, n, n)).copy()
    xs, Ps = np.empty((runs, K, n)), np.empty((runs, K, n, n))
    for k in range(K):
        xp = x @ p.F.T
        Pp = p.F @ P @ p.F.T + p.Q
        cols = np.moveaxis(xp, -1, 0)
        yp = np.stack(np.broadcast_arrays(*hx(*cols)), axis=-1)
        yp[:, ang] = wrap(yp[:, ang])
        H = np.stack([np.broadcast_to(e, (runs,)) for e in Hx(*cols)], axis=-1).reshape(runs, p.n_y, n)
        C = Pp @ H.transpose(0, 2, 1)
        S = H @ C + p.R
        x, P = batched_update(xp, Pp, yp, S, C, ys[:, k], ang)
        xs[:, k], Ps[:, k] = x, P
    return xs, Ps


def filterpy_one(p, ys, repeat):
    try:
        import filterpy  # noqa: F401
    except ImportError:
        return None
    return best(lambda: p.filterpy_ukf(ys[0]), max(1, repeat // 3))


# --------------------------------------------------------------------------- moments
def moment_batch(n: int, K: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(K, n))
    A = rng.normal(size=(K, n, n)) / np.sqrt(n)
    covs = 0.05 * (A @ A.transpose(0, 2, 1) + np.eye(n))
    return means, covs


def symmon_moments(n, means, covs, repeat):
    model = sparse_model(n)
    out = {}
    for label, transform in (("ut", sm.UT(ALPHA, BETA, KAPPA)), ("tt2", sm.TT2())):
        t0 = time.perf_counter()
        sm.propagate_many(model, (means, covs), transform=transform)
        first = time.perf_counter() - t0
        compiled(model).wait_compiled(600)
        kernel = batch_kernel(compiled(model), transform, frozenset(), len(means))  # the point rules' batch kernel
        if kernel is not None:
            kernel.wait(600)
        built = time.perf_counter() - t0
        res = sm.propagate_many(model, (means, covs), transform=transform)
        out[label] = {"first": first, "built": built,
                      "warm": best(lambda: sm.propagate_many(model, (means, covs), transform=transform), repeat),
                      "mean": np.asarray(res.mean)}
    single = sm.Gaussian(means[0], covs[0])
    out["propagate_us"] = 1e6 * best(lambda: sm.propagate(model, single, transform=sm.UT(ALPHA, BETA, KAPPA)), 20 * repeat)
    return out


def jax_moments(n, means, covs, repeat):
    try:
        import jax
    except ImportError:
        return None
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    idx = np.arange(n)
    i1, i2 = (idx + 1) % n, (idx + 2) % n

    def g(x):
        return jnp.sqrt(x**2 + x[i1] ** 2 + 1) + jnp.sin(x * x[i2])

    wm, wc, c = ut_weights(n)

    def ut(m, P):
        L = c * jnp.linalg.cholesky(P)
        X = jnp.concatenate([m[None], m + L.T, m - L.T])
        Y = jax.vmap(g)(X)
        mu = wm @ Y
        D = Y - mu
        return mu, (D.T * wc) @ D

    def tt2(m, P):
        J = jax.jacfwd(g)(m)
        H = jax.hessian(g)(m)  # (n_y, n, n)
        HP = H @ P
        mu = g(m) + 0.5 * jnp.trace(HP, axis1=1, axis2=2)
        cov = J @ P @ J.T + 0.5 * jnp.einsum("iab,jba->ij", HP, HP)
        return mu, cov

    M, C = jnp.asarray(means), jnp.asarray(covs)
    out = {}
    for label, rule in (("ut", ut), ("tt2", tt2)):
        f = jax.jit(jax.vmap(rule))
        t0 = time.perf_counter()
        try:
            mu = f(M, C)[0].block_until_ready()
        except Exception as exc:  # XLA's RESOURCE_EXHAUSTED: the vmapped Hessians of a large batch
            if "RESOURCE_EXHAUSTED" not in str(exc):
                raise
            out[label] = {"oom": str(exc).split("\n")[0][:120]}
            continue
        first = time.perf_counter() - t0
        out[label] = {"first": first, "warm": best(lambda: f(M, C)[0].block_until_ready(), repeat), "mean": np.asarray(mu)}
    one = jax.jit(ut)
    one(M[0], C[0])[0].block_until_ready()
    out["propagate_us"] = 1e6 * best(lambda: one(M[0], C[0])[0].block_until_ready(), 20 * repeat)
    return out


# --------------------------------------------------------------------------- Monte Carlo
GMTI = HERE.parent / "examples" / "gmti.toml"


def timed(fn, repeat: int) -> tuple[float, float]:
    """Best wall time and best CPU time (all threads of the process) of ``repeat`` calls,
    after one warm-up call.  On a machine shared with other jobs the CPU time is the steadier
    measure: it does not count the time the threads wait for a core."""
    fn()
    return best_wall_cpu(fn, repeat)


def mc_floor(N: int, repeat: int) -> dict:
    """The machine's limit for N samples of 4 normals: NumPy's fastest generator (SFC64,
    ziggurat) filling the normals on one core, divided by the cores (wall); and the CPU
    time of those normals on one core (``cpu``)."""
    gen = np.random.Generator(np.random.SFC64(0))
    buf = np.empty((N // 4, 4))
    wall, cpu = timed(lambda: gen.standard_normal(out=buf), repeat)
    out = {"wall": 4 * wall / (os.cpu_count() or 1), "cpu": 4 * cpu}
    # symmon's own generator (symmon.compile.rng: xoshiro256++ and a ziggurat), the one its
    # compiled chunk draws from, filling the same buffer: a lower floor than NumPy's.
    from symmon.compile.rng import NormalStream

    if NormalStream.available():
        stream = NormalStream(np.random.SeedSequence(0), 0)
        c_wall, c_cpu = timed(lambda: stream.fill(buf), repeat)
        out.update(c_wall=4 * c_wall / (os.cpu_count() or 1), c_cpu=4 * c_cpu)
    return out


def symmon_mc(N: int, repeat: int):
    from symmon.files.modelfile import load_model_file

    spec = load_model_file(GMTI)
    run = lambda: sm.nonlinearity(spec.model, spec.u, weight="full", transform=sm.MonteCarlo(N, seed=0))  # noqa: E731
    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0
    mon = run()
    warm, cpu = timed(run, repeat)
    return {"first": first, "warm": warm, "cpu": cpu, "mon": float(mon.value), "se": float(mon.stderr)}


def numba_mc(N: int, repeat: int):
    """GMTI by Monte Carlo with numba ``parallel=True``: the same samples' statistics as
    symmon's kernel (y with the bearing unwrapped around a reference, u, and the bearing's
    sine and cosine; their sums and cross-products per thread), then the MoN W^full from
    the covariances, in NumPy."""
    try:
        import numba
    except ImportError:
        return None
    from numba import njit, prange

    from symmon.files.modelfile import load_model_file

    spec = load_model_file(GMTI)
    m, L = np.asarray(spec.u.mean, dtype=float), np.linalg.cholesky(spec.u.cov)
    sx, sy, sz = 1000.0, 1000.0, 1000.0  # the file's [params]
    ref = float(np.arctan2(m[0] - sx, m[1] - sy))

    @njit(parallel=True, cache=False)
    def stats(n_per, threads, m, L, ref):
        S = np.zeros((threads, 10, 10))
        for t in prange(threads):
            a = np.empty(10)
            z = np.empty(4)
            for _ in range(n_per):
                for j in range(4):
                    z[j] = np.random.standard_normal()
                x = m[0] + L[0, 0] * z[0]
                y = m[1] + L[1, 0] * z[0] + L[1, 1] * z[1]
                vx = m[2] + L[2, 0] * z[0] + L[2, 1] * z[1] + L[2, 2] * z[2]
                vy = m[3] + L[3, 0] * z[0] + L[3, 1] * z[1] + L[3, 2] * z[2] + L[3, 3] * z[3]
                dx, dy = x - sx, y - sy
                r = np.sqrt(dx * dx + dy * dy + sz * sz)
                b = np.arctan2(dx, dy)
                d = b - ref
                b = ref + d - 2 * np.pi * np.floor((d + np.pi) / (2 * np.pi))
                h = np.hypot(dx, dy)
                a[0], a[1], a[2] = r, b, (dx * vx + dy * vy) / r
                a[3], a[4], a[5], a[6] = x, y, vx, vy
                a[7], a[8], a[9] = dx / h, dy / h, 1.0
                for i in range(10):
                    for k in range(10):
                        S[t, i, k] += a[i] * a[k]
        return S.sum(axis=0)

    threads = numba.get_num_threads()

    def run():
        S = stats(N // threads, threads, m, L, ref)
        n = S[9, 9]
        mean = S[9, :9] / n
        C = (S[:9, :9] - n * np.outer(mean, mean)) / (n - 1)  # no shift: fine at these magnitudes
        Sgg, Sgu, Suu = C[:3, :3], C[:3, 3:7], C[3:7, 3:7]
        D = Sgg - Sgu @ np.linalg.solve(Suu, Sgu.T)
        return float(np.sqrt(np.trace(np.linalg.solve(Sgg, D)) / 3))

    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0  # includes numba's compile
    warm, cpu = timed(run, repeat)
    return {"first": first, "warm": warm, "cpu": cpu, "mon": run(), "threads": threads}


def monte_carlo(N: int, repeat: int, rounds: int = 3):
    """The limit, symmon and numba in turn, ``rounds`` times (so that all three see the same
    load), each cell the best over the rounds."""
    out = [mc_floor(N, repeat), symmon_mc(N, repeat), numba_mc(N, repeat)]
    for _ in range(rounds - 1):
        again = [mc_floor(N, repeat), symmon_mc(N, repeat), numba_mc(N, repeat)]
        for old, new in zip(out, again):
            for k in ("wall", "warm", "cpu", "c_wall", "c_cpu"):
                if old is not None and k in old:
                    old[k] = min(old[k], new[k])
    return out


def mc_lines(N_mc: int, floor: dict, smc: dict, nmc: dict | None, load: tuple[float, float]) -> list[str]:
    """The Monte Carlo subsection of the report."""
    lines = ["### Monte Carlo", "",
             f"The W^full MoN of `examples/gmti.toml` (the bearing declared an angle) by Monte Carlo with "
             f"{N_mc:.0e} samples: symmon `nonlinearity(..., transform=MonteCarlo(N))` against numba "
             f"`parallel=True` computing the same statistics ({(nmc or {}).get('threads', '—')} threads); the "
             f"machine's limit is NumPy's SFC64 normals, 4 a sample, on {os.cpu_count()} cores: {fmt(floor['wall'])} "
             f"(CPU time of the normals: {fmt(floor['cpu'])}). Limit, symmon and numba run in turn, best of each; "
             f"load average before / after: {load[0]:.2f} / {load[1]:.2f}. *Share by CPU* is the normals' CPU "
             "time over the run's CPU time (all threads): the share of the limit on an idle machine, measured "
             "without counting the time the threads wait for a core on a shared one."
             + (f" symmon draws its normals itself, in the compiled chunk (xoshiro256++ and a ziggurat, "
                f"`symmon.compile.rng`), at {floor['c_cpu'] / floor['cpu']:.2f} of NumPy's cost: the same 4N "
                f"normals take {fmt(floor['c_cpu'])} of CPU there ({fmt(floor['c_wall'])} on {os.cpu_count()} "
                f"cores), so against its own generator symmon's share by CPU is "
                f"{floor['c_cpu'] / smc['cpu']:.0%}; the NumPy-normals limit is then no bound on symmon's run "
                "(a generator faster than NumPy's can pass it)." if "c_cpu" in floor else ""), "",
             "| | first call | warm | CPU time | share of the limit (wall) | share by CPU | MoN |",
             "|---|---|---|---|---|---|---|",
             f"| symmon | {fmt(smc['first'])} | {fmt(smc['warm'])} | {fmt(smc['cpu'])} | {floor['wall'] / smc['warm']:.0%} "
             f"| {floor['cpu'] / smc['cpu']:.0%} | {smc['mon']:.5f} ± {smc['se']:.5f} |"]
    if nmc:
        lines.append(f"| numba | {fmt(nmc['first'])} | {fmt(nmc['warm'])} | {fmt(nmc['cpu'])} "
                     f"| {floor['wall'] / nmc['warm']:.0%} | {floor['cpu'] / nmc['cpu']:.0%} | {nmc['mon']:.5f} |")
        lines += ["", f"numba / symmon: {ratio(nmc['warm'], smc['warm'])} (warm), "
                  f"{ratio(nmc['cpu'], smc['cpu'])} (CPU time)."]
    else:
        lines += ["", "numba is not installed here: its row is left out."]
    return lines


def write_subsection(path: Path, text: str, heading: str) -> None:
    """Replace the subsection ``heading`` (### ...) of ``path``, up to the next heading."""
    import re

    old = path.read_text()
    pat = re.compile(rf"^{re.escape(heading)}\n.*?(?=^##|\Z)", re.S | re.M)
    if not pat.search(old):
        raise SystemExit(f"{path} has no subsection {heading!r}: run the full benchmark once")
    path.write_text(pat.sub(lambda _: text + "\n\n", old, count=1))


# --------------------------------------------------------------------------- report
def exponent(ns, ts):
    pts = [(n, t) for n, t in zip(ns, ts) if n >= 10 and t]
    if len(pts) < 2:
        return "—"
    a = np.polyfit(np.log([n for n, _ in pts]), np.log([t for _, t in pts]), 1)[0]
    return f"{a:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer runs and repeats")
    ap.add_argument("--sizes", default="4,10,20,30,64", help="state dimensions of the filter table")
    ap.add_argument("--moment-sizes", default="16,64", help="input dimensions of the moment table")
    ap.add_argument("--out", type=Path, default=None, help="write the section into this Markdown file")
    ap.add_argument("--only", choices=["mc"], default=None,
                    help="only the Monte Carlo subsection (with --out: replaces that subsection)")
    a = ap.parse_args()
    K, R, repeat, KM = (50, 50, 3, 2000) if a.quick else (100, 300, 5, 10_000)
    N_mc = 10**6 if a.quick else 4 * 10**6
    if a.only == "mc":
        load0 = os.getloadavg()[0]
        floor, smc, nmc = monte_carlo(N_mc, repeat)
        text = "\n".join(mc_lines(N_mc, floor, smc, nmc, (load0, os.getloadavg()[0])))
        print(text)
        if a.out:
            write_subsection(a.out, text, "### Monte Carlo")
        return
    sizes = [int(s) for s in a.sizes.split(",")]
    load0 = os.getloadavg()[0]
    rows = []
    for n in sizes:
        p = problem(n)
        _, ys = p.simulate(K, R, seed=0)
        s = symmon_filters(p, ys, repeat)
        d = dynamax_filters(p, ys, repeat)
        t0 = time.perf_counter()
        xs_np, _ = numpy_ukf_bank(p, ys)
        t_np = time.perf_counter() - t0
        t_np = min(t_np, best(lambda: numpy_ukf_bank(p, ys), max(1, repeat // 3)))
        fp = filterpy_one(p, ys, repeat)
        xs_npe, _ = numpy_ekf_bank(p, ys)
        t_npe = best(lambda: numpy_ekf_bank(p, ys), max(1, repeat // 3))
        rows.append((p.n, s, d, t_np, rel_diff(xs_np, s["ukf"]["x"]), fp, t_npe, rel_diff(xs_npe, s["ekf"]["x"])))
        print(p.n, {k: {kk: v for kk, v in s[k].items() if kk != "x"} for k in s}, flush=True)
    mrows = []
    for n in (int(s) for s in a.moment_sizes.split(",")):
        means, covs = moment_batch(n, KM)
        s = symmon_moments(n, means, covs, repeat)
        j = jax_moments(n, means, covs, repeat)
        mrows.append((n, s, j))
        print("moments", n, {k: v if k == "propagate_us" else {kk: vv for kk, vv in v.items() if kk != "mean"}
                             for k, v in s.items()}, flush=True)
    mc_load0 = os.getloadavg()[0]
    floor, smc, nmc = monte_carlo(N_mc, repeat)
    mc_load = (mc_load0, os.getloadavg()[0])
    print("mc", smc, nmc, floor, flush=True)
    load1 = os.getloadavg()[0]
    import casadi

    lines = [HEADING, "",
             f"Generated by `python benchmarks/peers.py`{' --quick' if a.quick else ''} (the module docstring says what "
             f"each column runs): K = {K} steps, banks of R = {R} runs; moments of {KM} Gaussians. Ratios: peer / "
             "symmon (> 1: symmon faster). First calls build into a fresh cache (symmon: in parentheses, the time "
             "until the background C build is in) or trace and compile (JAX). dynamax has no angle handling (its "
             "bearing is averaged as a number), so its estimates differ from symmon's at the level of the bearing "
             "variance, and by much more in a run whose bearing crosses ±π: its agreement is the median over the runs; "
             f"the NumPy bank agrees to rounding. {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}, NumPy {np.__version__}, CasADi {casadi.__version__}; load average "
             f"before / after: {load0:.2f} / {load1:.2f}.", "",
             "### Filters", "",
             "| n | symmon UKF first (C in) | dynamax UKF first (one / bank) | UKF one run: symmon / dynamax / FilterPy "
             "| UKF bank: symmon / dynamax / NumPy | EKF bank: symmon / dynamax | dynamax / symmon: UKF one, UKF bank, "
             "EKF bank | NumPy / symmon | FilterPy / symmon | agreement (dynamax, NumPy) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for n, s, d, t_np, agree_np, fp, *_ in rows:
        du, de = (d or {}).get("ukf", {}), (d or {}).get("ekf", {})
        agree_d = "—" if not du else f"{np.median([rel_diff(a, b) for a, b in zip(du['x'], s['ukf']['x'])]):.1e}"
        lines.append(
            f"| {n} | {fmt(s['ukf']['first'])} ({fmt(s['ukf']['built'])}) | {fmt(du.get('first'))} / "
            f"{fmt(du.get('first_bank'))} | {fmt(s['ukf']['one'])} / {fmt(du.get('one'))} / {fmt(fp)} "
            f"| {fmt(s['ukf']['bank'])} / {fmt(du.get('bank'))} / {fmt(t_np)} | {fmt(s['ekf']['bank'])} / "
            f"{fmt(de.get('bank'))} | {ratio(du.get('one'), s['ukf']['one'])}, {ratio(du.get('bank'), s['ukf']['bank'])}, "
            f"{ratio(de.get('bank'), s['ekf']['bank'])} | {ratio(t_np, s['ukf']['bank'])} | {ratio(fp, s['ukf']['one'])} "
            f"| {agree_d}, {agree_np:.1e} |")
    lines += ["", "### EKF", "",
              "The same trackers with `TT1()` (symmon), `extended_kalman_filter` (dynamax) and a hand-vectorised "
              "NumPy EKF bank (batched products and solve, the bearings' innovations wrapped).", "",
              "| n | symmon EKF first (C in) | dynamax EKF first (one / bank) | EKF one run: symmon / dynamax "
              "| EKF bank: symmon / dynamax / NumPy | dynamax / symmon: one run, bank | NumPy / symmon (bank) "
              "| agreement (NumPy) |",
              "|---|---|---|---|---|---|---|---|"]
    for n, s, d, _, _, _, t_npe, agree_npe in rows:
        de = (d or {}).get("ekf", {})
        lines.append(
            f"| {n} | {fmt(s['ekf']['first'])} ({fmt(s['ekf']['built'])}) | {fmt(de.get('first'))} / "
            f"{fmt(de.get('first_bank'))} | {fmt(s['ekf']['one'])} / {fmt(de.get('one'))} "
            f"| {fmt(s['ekf']['bank'])} / {fmt(de.get('bank'))} / {fmt(t_npe)} "
            f"| {ratio(de.get('one'), s['ekf']['one'])}, {ratio(de.get('bank'), s['ekf']['bank'])} "
            f"| {ratio(t_npe, s['ekf']['bank'])} | {agree_npe:.1e} |")
    ns = [r[0] for r in rows]
    cols = {
        "symmon UKF one run": [r[1]["ukf"]["one"] for r in rows],
        "symmon UKF bank": [r[1]["ukf"]["bank"] for r in rows],
        "symmon EKF bank": [r[1]["ekf"]["bank"] for r in rows],
        "dynamax UKF one run": [(r[2] or {}).get("ukf", {}).get("one") for r in rows],
        "dynamax UKF bank": [(r[2] or {}).get("ukf", {}).get("bank") for r in rows],
        "dynamax EKF bank": [(r[2] or {}).get("ekf", {}).get("bank") for r in rows],
        "NumPy UKF bank": [r[3] for r in rows],
        "symmon EKF one run": [r[1]["ekf"]["one"] for r in rows],
        "dynamax EKF one run": [(r[2] or {}).get("ekf", {}).get("one") for r in rows],
        "NumPy EKF bank": [r[6] for r in rows],
    }
    lines += ["", "Growth exponent p of cost ∝ nᵖ (n ≥ 10): " + "; ".join(f"{k} {exponent(ns, v)}" for k, v in cols.items())
              + "."]
    if any(r[2] is None for r in rows):
        lines += ["", "dynamax (JAX) is not installed here: its columns are empty."]
    lines += ["", "### Moments of a batch", "",
              "| n | UT: symmon / jax.vmap (first calls; symmon: and its batch kernel in) | TT2: symmon / jax.vmap (first call) | jax / symmon: UT, TT2 "
              "| one `propagate` (UT): symmon / jitted JAX | agreement of E y (UT, TT2) |",
              "|---|---|---|---|---|---|"]
    for n, s, j in mrows:
        j = j or {}
        ju, jt = j.get("ut", {}), j.get("tt2", {})
        agree = ", ".join("—" if "mean" not in jj else f"{rel_diff(s[k]['mean'], jj['mean']):.1e}"
                          for k, jj in (("ut", ju), ("tt2", jt)))
        lines.append(
            f"| {n} | {fmt(s['ut']['warm'])} / {fmt(ju.get('warm'))} ({fmt(s['ut']['first'])}, C in {fmt(s['ut']['built'])} "
            f"/ {fmt(ju.get('first'))}) "
            f"| {fmt(s['tt2']['warm'])} / {fmt(jt.get('warm'))} ({fmt(s['tt2']['first'])} / {fmt(jt.get('first'))}) "
            f"| {ratio(ju.get('warm'), s['ut']['warm'])}, {ratio(jt.get('warm'), s['tt2']['warm'])} "
            f"| {s['propagate_us']:.0f} µs / {j.get('propagate_us', float('nan')):.0f} µs | {agree} |")
    oom = [(n, k) for n, _, j in mrows for k in ("ut", "tt2") if "oom" in (j or {}).get(k, {})]
    if oom:
        lines += ["", "jax.vmap ran out of memory (XLA RESOURCE_EXHAUSTED: it holds the whole batch's Hessians) for "
                  + ", ".join(f"{k.upper()} at n = {n}" for n, k in oom) + ": those cells are empty."]
    lines += [""] + mc_lines(N_mc, floor, smc, nmc, mc_load)
    publish(lines, a.out, HEADING)


if __name__ == "__main__":
    main()
