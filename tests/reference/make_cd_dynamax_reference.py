"""Make tests/reference/cd_dynamax.json: cd-dynamax's continuous-discrete filters on two of its
own models, at irregular measurement times.

    pip install ".[bench]"      # cd-dynamax (with JAX, diffrax), CPU only
    python tests/reference/make_cd_dynamax_reference.py

(cd-dynamax 0.5.0 from PyPI, in a venv of its own: it pins its JAX.)

- ``linear``: the model of cd-dynamax's ``tests/test_cdnlgssm_filter_linear_TRegular.py``:
  2 states, 6 emissions, dx = −0.1 x dt + 0.1 dβ with Q_c = 0.1 I, y = H x + e with
  H ~ N(0, 1) drawn by its key (``jr.PRNGKey(0)`` split, the first half), R = 0.1 I,
  x_0 ~ N(0, I); here at 30 irregular times (gaps uniform in [0.2, 2]). Filtered by its
  continuous-discrete Kalman filter (``cdlgssm_filter``), its CD-EKF (``state_order="first"``)
  and its CD-UKF (its default α = √3, β = 2, κ = 1) of the same model written as a nonlinear
  one (``LearnableLinear`` drift and emission), as that test does.
- ``vanderpol``: its Van der Pol drift (``LearnableVanDerPol`` of
  ``cd_dynamax/src/utils/physics_based_models.py``, μ = 1: dx₁ = x₂ dt,
  dx₂ = (μ(1 − x₁²)x₂ − x₁) dt, plus L dβ with L = I, Q_c = 0.05 I); x₁ measured with
  R = 0.1, x_0 ~ N([2, 0], 0.1 I), 25 irregular times (gaps uniform in [0.1, 0.5]); the
  measurements simulated here by Euler–Maruyama on a fine grid (seed 3). Its ``adjust_rhs``
  clips the drift only outside |x| ≤ 10 and |a| ≤ 1000, which no trajectory or sigma point
  here reaches. Filtered by its CD-EKF and CD-UKF.

Every moment ODE is solved by diffrax's Dopri5 with an adaptive PID controller at
rtol = 1e-10, atol = 1e-12 (cd-dynamax's default is a constant step of 0.01), in double
precision. Stored: the model, the times and emissions, and of each filter the filtered means
and covariances and ``marginal_loglik``. cd-dynamax conditions on the first emission before
its first prediction (at t_1, with no interval before it) where symmon predicts first: the
test starts symmon from cd-dynamax's first filtered state at t_1 and compares the later
steps, and the log-likelihood without the first emission's term (which the test computes).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("cd_dynamax.json")
RTOL, ATOL = 1e-10, 1e-12


def _settings():
    import diffrax as dfx

    return {"solver": dfx.Dopri5(), "stepsize_controller": dfx.PIDController(rtol=RTOL, atol=ATOL),
            "dt0": 1e-3, "max_steps": 100_000}


def _posterior(post) -> dict:
    return {"means": np.asarray(post.filtered_means).tolist(),
            "covariances": np.asarray(post.filtered_covariances).tolist(),
            "marginal_loglik": float(post.marginal_loglik)}


def nonlinear_params(model, key, m0, P0, drift, L, Qc, H, R):
    """cd-dynamax's parameters of a nonlinear model: the prior N(m0, P0), ``drift`` (its params/props
    dict), the diffusion L with spectral density Qc, a linear emission H with noise R, all fixed
    (benchmarks/continuous.py builds its peer with it too)."""
    from cd_dynamax.dynamax.parameters import ParameterProperties
    from cd_dynamax.src.continuous_discrete_nonlinear_gaussian_ssm.cdnlgssm_utils import (
        LearnableLinear, LearnableMatrix, LearnableVector)
    import jax.numpy as jnp

    props = ParameterProperties()
    params, _ = model.initialize(
        key,
        initial_mean={"params": LearnableVector(params=jnp.asarray(m0)), "props": LearnableVector(params=props)},
        initial_cov={"params": LearnableMatrix(params=jnp.asarray(P0)), "props": LearnableMatrix(params=props)},
        dynamics_drift=drift,
        dynamics_diffusion_coefficient={"params": LearnableMatrix(params=jnp.asarray(L)),
                                        "props": LearnableMatrix(params=props)},
        dynamics_diffusion_cov={"params": LearnableMatrix(params=jnp.asarray(Qc)),
                                "props": LearnableMatrix(params=props)},
        dynamics_approx_order=1.0,
        emission_function={"params": LearnableLinear(weights=jnp.asarray(H), bias=jnp.zeros(H.shape[0])),
                           "props": LearnableLinear(weights=props, bias=props)},
        emission_cov={"params": LearnableMatrix(params=jnp.asarray(R)), "props": LearnableMatrix(params=props)},
    )
    return params


def _ekf_ukf(params, ys, t) -> dict:
    from cd_dynamax import EKFHyperParams, UKFHyperParams, cdnlgssm_filter

    s = _settings()
    out = {}
    for name, hyper in (("ekf", EKFHyperParams(state_order="first", emission_order="first", diffeqsolve_settings=s)),
                        ("ukf", UKFHyperParams(diffeqsolve_settings=s))):
        out[name] = _posterior(cdnlgssm_filter(params, ys, t_emissions=t, filter_hyperparams=hyper))
    return out


def linear_case() -> dict:
    import jax.numpy as jnp
    import jax.random as jr
    from cd_dynamax import ContDiscreteLinearGaussianSSM, ContDiscreteNonlinearGaussianSSM
    from cd_dynamax.dynamax.parameters import ParameterProperties
    from cd_dynamax.src.continuous_discrete_linear_gaussian_ssm.inference import KFHyperParams
    from cd_dynamax.src.continuous_discrete_linear_gaussian_ssm.models import cdlgssm_filter
    from cd_dynamax.src.continuous_discrete_nonlinear_gaussian_ssm.cdnlgssm_utils import LearnableLinear

    n, n_y, K = 2, 6, 30
    key1, key2 = jr.split(jr.PRNGKey(0))
    H = np.asarray(jr.normal(key1, (n_y, n)))
    A, L, Qc, R = -0.1 * np.eye(n), 0.1 * np.eye(n), 0.1 * np.eye(n), 0.1 * np.eye(n_y)
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.2, 2.0, K))
    t = jnp.asarray(times)[:, None]
    props = ParameterProperties()
    model = ContDiscreteLinearGaussianSSM(state_dim=n, emission_dim=n_y, has_dynamics_bias=True,
                                          has_emissions_bias=True)
    params, _ = model.initialize(
        key1,
        initial_mean={"params": jnp.zeros(n), "props": props},
        initial_cov={"params": jnp.eye(n), "props": props},
        dynamics_weights={"params": jnp.asarray(A), "props": props},
        dynamics_bias={"params": jnp.zeros(n), "props": props},
        dynamics_diffusion_coefficient={"params": jnp.asarray(L), "props": props},
        dynamics_diffusion_cov={"params": jnp.asarray(Qc), "props": props},
        emission_weights={"params": jnp.asarray(H), "props": props},
        emission_bias={"params": jnp.zeros(n_y), "props": props},
        emission_cov={"params": jnp.asarray(R), "props": props},
    )
    _, ys = model.sample(params, key2, num_timesteps=K, t_emissions=t)
    kf = cdlgssm_filter(params, ys, t, filter_hyperparams=KFHyperParams(diffeqsolve_settings=_settings()))
    nl = ContDiscreteNonlinearGaussianSSM(state_dim=n, emission_dim=n_y)
    drift = {"params": LearnableLinear(weights=jnp.asarray(A), bias=jnp.zeros(n)),
             "props": LearnableLinear(weights=props, bias=props)}
    nl_params = nonlinear_params(nl, key1, np.zeros(n), np.eye(n), drift, L, Qc, H, R)
    return {"A": A.tolist(), "L": L.tolist(), "Qc": Qc.tolist(), "H": H.tolist(), "R": R.tolist(),
            "m0": [0.0] * n, "P0": np.eye(n).tolist(), "times": times.tolist(),
            "emissions": np.asarray(ys).tolist(), "kf": _posterior(kf), **_ekf_ukf(nl_params, ys, t)}


def vanderpol_case() -> dict:
    import jax.numpy as jnp
    import jax.random as jr
    from cd_dynamax import ContDiscreteNonlinearGaussianSSM
    from cd_dynamax.dynamax.parameters import ParameterProperties
    from cd_dynamax.src.utils.physics_based_models import LearnableVanDerPol

    mu, q, K = 1.0, 0.05, 25
    m0, P0 = np.array([2.0, 0.0]), 0.1 * np.eye(2)
    H, R = np.array([[1.0, 0.0]]), np.array([[0.1]])
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.1, 0.5, K))
    # The measurements: Euler–Maruyama on a grid of 1e-4 from x_0 ~ N(m0, P0).
    x = rng.multivariate_normal(m0, P0)
    ys, now, d = [], 0.0, 1e-4
    for tk in times:
        while now < tk - 1e-12:
            h = min(d, tk - now)
            x = x + h * np.array([x[1], mu * (1 - x[0] ** 2) * x[1] - x[0]]) + np.sqrt(q * h) * rng.standard_normal(2)
            now += h
        ys.append(H @ x + np.sqrt(R[0, 0]) * rng.standard_normal(1))
    ys = jnp.asarray(np.array(ys))
    props = ParameterProperties()
    drift = {"params": LearnableVanDerPol(mu=jnp.asarray(mu)), "props": LearnableVanDerPol(mu=props)}
    model = ContDiscreteNonlinearGaussianSSM(state_dim=2, emission_dim=1)
    params = nonlinear_params(model, jr.PRNGKey(0), m0, P0, drift, np.eye(2), q * np.eye(2), H, R)
    return {"mu": mu, "Qc": (q * np.eye(2)).tolist(), "H": H.tolist(), "R": R.tolist(), "m0": m0.tolist(),
            "P0": P0.tolist(), "times": times.tolist(), "emissions": np.asarray(ys).tolist(),
            **_ekf_ukf(params, ys, jnp.asarray(times)[:, None])}


def main() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_platform_name", "cpu")
    import cd_dynamax

    out = {"cd_dynamax_version": getattr(cd_dynamax, "__version__", "0.5.0"), "jax_version": jax.__version__,
           "rtol": RTOL, "atol": ATOL, "linear": linear_case(), "vanderpol": vanderpol_case()}
    OUT.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
