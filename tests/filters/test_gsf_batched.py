"""The Gaussian-sum filter's batched splitting path against the per-component computations it
replaces: the MoN of every component in one compiled call against ``sm.nonlinearity`` of that
component, the stacked split directions and splits against a loop over components, and the
incremental (NumPy and C) merges against a merge that recomputes every pair cost each time."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

import symmon as sm
from symmon.core.mixture import mixture_moments
from symmon.filters.mixture import gaussian_sum as gs
from symmon.filters.mixture.merge import merge_components, merge_kernel, merge_numpy, merge_runs

from helpers import random_spd

x1, x2, x3 = sp.symbols("x1 x2 x3", real=True)
E1, E2 = sp.symbols("e1 e2")
F3 = sm.Model([x1, x2, x3], [x1 + 0.5 * x2, x2 + x1 * x3, sp.sin(2 * x3)], name="gsfb_f")
H2 = sm.Model([x1, x2, x3], [sp.atan2(x2 + 1, x1), x1**2 / 8 + x3], name="gsfb_h", angles=[0])
Q3 = np.diag([0.05, 0.1, 0.02])
R2 = np.diag([1e-3, 0.2])


def _noisy(model: sm.Model, noise: list) -> sm.Model:
    return sm.Model(model.inputs, [g + e for g, e in zip(model.outputs, noise)], noise=noise,
                    angles=list(model.angle_outputs))


@pytest.fixture(scope="module")
def components():
    rng = np.random.default_rng(11)
    N = 6
    x = np.column_stack([rng.uniform(1.0, 3.0, N), rng.uniform(-1.0, 1.0, N), rng.uniform(-1.0, 1.0, N)])
    P = np.stack([0.3 * random_spd(rng, 3) for _ in range(N)])
    gsf = sm.GaussianSumFilter(F3, H2, Q3, R2, sm.UT.ut1(), split=0.1)
    steps = gs._component_steps(gsf.f, gsf.h, gsf.transform, gsf.kf.angle_states)
    return gsf, steps, x, P


@pytest.mark.parametrize("which", ["f", "h"])
def test_the_batched_mon_is_nonlinearity_of_each_component(which, components) -> None:
    gsf, steps, x, P = components
    model, noise = (F3, Q3) if which == "f" else (H2, R2)
    mon, W, H = gsf._mons(which, steps, x, P, np.zeros((len(x), 0)), noise)
    syms = list(sp.symbols(f"v0:{model.n_y}"))
    noisy = _noisy(model, syms)
    ref_H = sm.compile.compiled(model).eval_gjh(x)[2]
    for i in range(len(x)):
        ref = sm.nonlinearity(noisy, sm.Gaussian(x[i], P[i]), sm.Gaussian(np.zeros(model.n_y), noise),
                              weight="full", transform=sm.TT2())
        # D by ½ tr(H_i P H_j P) against Σ_gg − Σ_c − Σ_gu Σ_uu⁻¹ Σ_ug: both exact for TT2, apart
        # by rounding of that difference (relative eps / M², M² ≥ 1e-3 here).
        assert ref.squared > 1e-3
        assert mon[i] == pytest.approx(ref.value, rel=1e-12, abs=0)
        np.testing.assert_allclose(W[i], ref.weight, rtol=1e-12, atol=0)
        np.testing.assert_allclose(H[i], ref_H[i][:, :3, :3], rtol=1e-14, atol=1e-14)


def _reference_direction(cov, hessians, weight):
    """The per-component split direction as the filter computed it before batching."""
    lam, V = np.linalg.eigh(cov)
    S = V * np.sqrt(np.clip(lam, 0.0, None))
    wl, wv = np.linalg.eigh(0.5 * (weight + weight.T))
    C = (wv * np.sqrt(np.clip(wl, 0.0, None))).T
    G = np.einsum("ki,ab,iac,cd->kbd", C, S, hessians, S)
    G = 0.5 * (G + np.swapaxes(G, 1, 2))
    gl, gv = np.linalg.eigh(G)
    lead = gv[np.arange(len(G)), :, np.argmax(np.abs(gl), axis=1)]
    cands = np.vstack([lead, np.eye(len(cov))])
    share = (np.einsum("ca,kab,cb->ck", cands, G, cands) ** 2).sum(axis=1)
    return S @ cands[int(np.argmax(share))]


@pytest.mark.parametrize("n_y", [1, 2, 3])
def test_batched_split_directions_and_splits_are_the_per_component_ones(n_y) -> None:
    rng = np.random.default_rng(20 + n_y)
    N, n = 40, 4
    covs = np.stack([random_spd(rng, n) for _ in range(N)])
    H = rng.normal(size=(N, n_y, n, n))
    H = 0.5 * (H + np.swapaxes(H, 2, 3))
    W = np.stack([random_spd(rng, n_y) for _ in range(N)])
    means = rng.normal(size=(N, n))
    d = gs.split_directions(covs, H, W)
    for m in sorted(gs.SPLITS):
        w, cm, cP = gs.split_components(means, covs, d, m)
        for i in range(N):
            ref = _reference_direction(covs[i], H[i], W[i])
            # An eigenvector's sign is free: d and −d give the same split (children reversed).
            sign = np.sign(ref @ d[i])
            np.testing.assert_allclose(d[i], sign * ref, rtol=0, atol=1e-12 * np.linalg.norm(ref))
            rw, rm, rP = gs.split_component(means[i], covs[i], d[i], m)
            np.testing.assert_array_equal(w, rw)
            np.testing.assert_array_equal(cm[i], rm)
            np.testing.assert_array_equal(cP[i], rP)
            mm, PP = mixture_moments(w, cm[i], cP[i])
            np.testing.assert_allclose(mm, means[i], rtol=0, atol=1e-12)
            np.testing.assert_allclose(PP, covs[i], rtol=0, atol=1e-12 * np.abs(covs[i]).max())


def test_a_tie_of_directions_is_broken_by_order_not_rounding() -> None:
    # atan2 is harmonic: its Hessian has eigenvalues ±λ, so with an isotropic spread the two
    # curvature directions tie exactly; the first eigenvalue (−λ) is taken, whatever the rounding.
    x = np.array([[3.0, 4.0]])
    H = sm.compile.compiled(sm.Model([x1, x2], [sp.atan2(x2, x1)])).eval_gjh(x)[2]  # (1, 1, 2, 2)
    for scale in (1.0, 1.0 + 1e-15, 1.0 - 1e-15):
        P = np.eye(2) * scale
        d = gs.split_directions(P[None], H, np.ones((1, 1, 1)))[0]
        ev, V = np.linalg.eigh(H[0, 0])
        assert abs(abs(d @ V[:, 0]) - 1.0) < 1e-12, (d, V)


def _reference_merge(w, m, P, keep, rule):
    """Runnalls' / Salmond's greedy merge recomputing every pair cost after each merge."""
    w, m, P = w.copy(), m.copy(), P.copy()
    if rule == "salmond":
        C = mixture_moments(w / w.sum(), m, P)[1]
        Pinv = np.linalg.inv(C)
    while len(w) > keep:
        iu, ju = np.triu_indices(len(w), 1)
        wi, wj = w[iu], w[ju]
        ws = wi + wj
        d = m[iu] - m[ju]
        if rule == "runnalls":
            Pij = (wi[:, None, None] * P[iu] + wj[:, None, None] * P[ju]) / ws[:, None, None] \
                + (wi * wj / ws**2)[:, None, None] * d[:, :, None] * d[:, None, :]
            ld = np.linalg.slogdet(P)[1]
            cost = 0.5 * (ws * np.linalg.slogdet(Pij)[1] - wi * ld[iu] - wj * ld[ju])
        else:
            cost = wi * wj / ws * np.einsum("ka,ab,kb->k", d, Pinv, d)
        k = int(np.argmin(cost))
        i, j = int(iu[k]), int(ju[k])
        mm, PP = mixture_moments(np.array([w[i], w[j]]) / (w[i] + w[j]), m[[i, j]], P[[i, j]])
        w[i], m[i], P[i] = w[i] + w[j], mm, PP
        w, m, P = np.delete(w, j), np.delete(m, j, axis=0), np.delete(P, j, axis=0)
    return w, m, P


def _random_mixture(rng, M, n):
    w = rng.dirichlet(np.ones(M))
    m = rng.normal(0.0, 1.0, (M, n))
    P = np.stack([random_spd(rng, n) for _ in range(M)])
    return w, m, P


@pytest.mark.parametrize("rule", ["runnalls", "salmond"])
def test_incremental_merges_equal_the_recomputing_reference(rule) -> None:
    rng = np.random.default_rng(5)
    paths = [False] + ([True] if merge_kernel() is not None else [])
    for trial in range(40):
        M, n = int(rng.integers(2, 25)), int(rng.integers(1, 5))
        keep = int(rng.integers(1, M + 1))
        w, m, P = _random_mixture(rng, M, n)
        ref = _reference_merge(w, m, P, keep, rule)
        for native in paths:
            got = merge_components(w, m, P, keep, rule, native=native)
            assert len(got[0]) == len(ref[0]) == min(M, keep)
            for a, b in zip(got, ref):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()),
                                           err_msg=f"trial {trial}, native={native}")
            mm, PP = mixture_moments(got[0], got[1], got[2])
            m0, P0 = mixture_moments(w, m, P)
            np.testing.assert_allclose(mm, m0, rtol=0, atol=1e-12)
            np.testing.assert_allclose(PP, P0, rtol=0, atol=1e-12 * np.abs(P0).max())


def test_merge_runs_of_a_bank_is_each_runs_merge() -> None:
    rng = np.random.default_rng(6)
    sizes = [5, 1, 9, 3, 12]
    parts = [_random_mixture(rng, M, 3) for M in sizes]
    run = np.repeat(np.arange(len(sizes)), sizes)
    w, m, P = (np.concatenate([p[i] for p in parts]) for i in range(3))
    for native in (True, False):
        a, b, c = w.copy(), m.copy(), P.copy()
        left = merge_runs(run, a, b, c, 4, "runnalls", native=native)
        assert np.bincount(run[left]).tolist() == [min(s, 4) for s in sizes]
        for r, (pw, pm, pP) in enumerate(parts):
            ref = merge_numpy(pw, pm, pP, 4, "runnalls")
            sel = left & (run == r)
            for x, y in zip((a[sel], b[sel], c[sel]), ref):
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-12 * max(1.0, np.abs(y).max()))
