"""The univariate Gaussian splits of the Gaussian-sum filter: N(0, 1) as a few narrower components.

symmon's Gaussian-sum filter (``symmon/filters/gaussian_sum.py``) replaces a component whose
measure of nonlinearity is too large by m = 3 or 5 components along one direction, from a
table of univariate splits of N(0, 1)

    N(x; 0, 1) ≈ Σ_i w_i N(x; μ_i, σ²),   μ_i = (i − (m − 1)/2) δ,

computed here, once, and stored in ``symmon/core/mixture.py`` (``SPLITS``).  The split is symmetric
(w_i = w_{m−1−i}), so its mean is 0 exactly, and δ is not a free parameter: it is fixed by
the variance, σ² + Σ_i w_i μ_i² = 1, so the mixture keeps the mean and the covariance of the
component exactly (the filter computes δ from the stored σ and w).  The free parameters σ and
the weights minimise, as in DeMars, Bishop & Jah (2013), the L2 distance to N(0, 1) plus a
penalty λσ (λ = 10⁻³) that keeps the components narrow; the L2 distance is in closed form,
∫ N(x; a, A) N(x; b, B) dx = N(a; b, A + B).

Checked here:

1. the optimiser's table reproduces the stored numbers' defining properties: weights positive
   and summing to 1, variance 1 and mean 0 exactly (to 1e-15), σ < 1;
2. the L2 distance of each split to N(0, 1) is small (below 1e-4) and smaller than that of a
   neighbouring split (σ moved by ±0.01 with the weights re-optimised): a stationary point;
3. the mixture's fourth moment, 3σ⁴ + 6σ² Σ w μ² + Σ w μ⁴, is within 15 % of N(0, 1)'s 3.

Run as a program, it prints the table in the form the module stores.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from _common import Checker, Result, main

NAME = "gaussian_split"
TITLE = "Univariate Gaussian splits with exact mean and variance (the Gaussian-sum filter's table)"
SOURCE = ("docs/filters.md (Gaussian-sum filter); the L2 cost with a penalty on sigma after DeMars, Bishop & Jah, "
          "J. Guid. Control Dyn. 36(4), 2013")

#: The penalty on σ of the cost L2 + λσ.
LAMBDA = 1e-3
#: The splits tabulated: components per split.
SIZES = (3, 5)


def _normal(d, v):
    return np.exp(-0.5 * d * d / v) / np.sqrt(2 * np.pi * v)


def l2_distance(w: np.ndarray, mu: np.ndarray, sigma: float) -> float:
    """∫ (N(x; 0, 1) − Σ_i w_i N(x; μ_i, σ²))² dx in closed form."""
    pq = np.sum(w * _normal(mu, 1 + sigma**2))
    qq = np.sum(w[:, None] * w[None, :] * _normal(mu[:, None] - mu[None, :], 2 * sigma**2))
    return float(_normal(0.0, 2.0) - 2 * pq + qq)


def components(m: int, sigma: float, outer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights and means of the symmetric split with σ and the weights of one side's outer
    components (nearest first); the centre weight makes them sum to 1 and δ makes the variance 1."""
    idx = np.arange(1, (m - 1) // 2 + 1)
    outer = np.abs(np.asarray(outer, dtype=float))
    delta = np.sqrt((1 - sigma**2) / (2 * np.sum(outer * idx**2)))
    w = np.concatenate([outer[::-1], [1 - 2 * outer.sum()], outer])
    mu = np.concatenate([-idx[::-1], [0], idx]) * delta
    return w, mu


def _best(m: int, sigma: float | None = None) -> tuple[float, np.ndarray, float]:
    """(σ, outer weights, cost) minimising L2 + λσ, over σ too unless it is given."""
    half = (m - 1) // 2

    def cost(x):
        s = sigma if sigma is not None else x[0]
        o = x if sigma is not None else x[1:]
        if not 0.05 < s < 0.99 or 2 * np.abs(o).sum() >= 1:
            return 1.0
        return l2_distance(*components(m, s, o), s) + LAMBDA * s

    # Smooth in (σ, weights): a quasi-Newton method from a few starts (Nelder–Mead took minutes).
    best = None
    starts = [None] if sigma is not None else (0.4, 0.6, 0.8)
    bounds = ([] if sigma is not None else [(0.1, 0.95)]) + [(1e-4, 0.5 / half - 1e-4)] * half
    for s0 in starts:
        x0 = np.full(half, 0.6 / (m - 1)) if sigma is not None else np.r_[s0, np.full(half, 0.6 / (m - 1))]
        r = minimize(cost, x0, method="L-BFGS-B", bounds=bounds, options={"ftol": 1e-16, "gtol": 1e-12,
                                                                           "maxiter": 5000})
        if best is None or r.fun < best.fun:
            best = r
    s = sigma if sigma is not None else float(best.x[0])
    outer = np.abs(best.x if sigma is not None else best.x[1:])
    return s, outer, float(best.fun)


def split_table() -> dict[int, tuple[float, tuple[float, ...]]]:
    """{m: (σ, outer weights)} for each size in :data:`SIZES`."""
    return {m: (s, tuple(float(v) for v in o)) for m in SIZES for s, o, _ in [_best(m)]}


def check() -> Result:
    ck = Checker(NAME, TITLE, SOURCE)
    for m, (s, outer) in split_table().items():
        w, mu = components(m, s, np.array(outer))
        ck.claim(f"m = {m}: weights positive, summing to 1", bool((w > 0).all()) and abs(w.sum() - 1) < 1e-15)
        ck.claim(f"m = {m}: mean 0 and variance 1 exactly", abs(w @ mu) < 1e-15 and abs(s**2 + w @ mu**2 - 1) < 1e-15)
        ck.claim(f"m = {m}: the components are narrower (sigma < 1)", 0 < s < 1, f"sigma = {s:.10f}")
        d = l2_distance(w, mu, s)
        ck.claim(f"m = {m}: L2 distance to N(0, 1) below 1e-4", d < 1e-4, f"{d:.3e}")
        near = [_best(m, s + e)[2] for e in (-0.01, 0.01)]
        ck.claim(f"m = {m}: a minimum of L2 + lambda sigma in sigma", all(c > d + LAMBDA * s for c in near))
        m4 = 3 * s**4 + 6 * s**2 * (w @ mu**2) + w @ mu**4
        ck.claim(f"m = {m}: fourth moment within 15 % of 3", abs(m4 - 3) < 0.45, f"{m4:.4f}")
        ck.note(f"m = {m}: sigma = {s!r}, outer weights = {outer!r}, delta = {mu[-1] / ((m - 1) // 2)!r}")
    return ck.result()


if __name__ == "__main__":
    main(check)
