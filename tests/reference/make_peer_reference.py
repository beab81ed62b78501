"""Make tests/reference/peers.json: dynamax's log-likelihoods and Stone Soup's iterated update.

    pip install ".[bench]"      # dynamax, JAX, Stone Soup
    python tests/reference/make_peer_reference.py

- ``dynamax``: dynamax's own nonlinear test model (``random_nlgssm_args`` of
  ``dynamax/nonlinear_gaussian_ssm/inference_test_utils.py``: f(z) = sin(W_f [1; z]),
  h(z) = cos(W_h [1; z]), 4 states, 2 emissions, 15 steps, identity covariances), filtered by
  dynamax's EKF, UKF (its default α = √3, β = 2, κ = 1) and Gauss–Hermite filter
  (``conditional_moments_gaussian_filter`` with ``GHKFIntegrals(order=5)``). Stored: the
  weights, the emissions, the filtered means and covariances and ``marginal_loglik``, also of
  the first emission alone. dynamax conditions on y_1 before its first prediction, where symmon
  predicts first: the test starts symmon at dynamax's first filtered state and compares the
  later steps, and the log-likelihood without the first term.
  dynamax adds 1e-9·I to S in its gain solve (``psd_solve``'s ``diagonal_boost``, not in its
  log-likelihood): this script sets that boost to 0, so the gains are the exact ones.
- ``stonesoup``: Stone Soup's own test case of ``IteratedKalmanUpdater``
  (``test_iterated_kalman_updater_convergence``: bearing–range of [x, vx, y, vy] from the
  origin, prediction N([10, 0, 10, 0], 0.5 I), measurement [45°, 14.14]) run to a tolerance
  of 1e-11: the converged Gauss–Newton update. Stone Soup differences the measurement function
  numerically by default (H to about 1e-8); the script gives the model its exact Jacobian.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("peers.json")


def dynamax_case() -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import jax.random as jr
    import dynamax.generalized_gaussian_ssm.inference as ggi
    import dynamax.nonlinear_gaussian_ssm.inference_ekf as ekf
    import dynamax.nonlinear_gaussian_ssm.inference_ukf as ukf
    from dynamax.generalized_gaussian_ssm import GHKFIntegrals, ParamsGGSSM
    from dynamax.nonlinear_gaussian_ssm.inference_test_utils import random_nlgssm_args
    from dynamax.utils.utils import psd_solve
    from tensorflow_probability.substrates.jax.distributions import MultivariateNormalFullCovariance as MVN

    exact = functools.partial(psd_solve, diagonal_boost=0.0)
    for mod in (ekf, ukf, ggi):
        mod.psd_solve = exact
    params, _, emissions = random_nlgssm_args(key=0, num_timesteps=15, state_dim=4, emission_dim=2)
    # The weights of make_nlgssm_params (the same key for both, as there).
    init_key, _ = jr.split(jr.PRNGKey(0), 2)
    Wf = jr.normal(init_key, (4, 8))
    Wh = jr.normal(init_key, (2, 8))
    z = jnp.linspace(-1, 1, 4)
    poly = jnp.concatenate([z**0, z])
    assert jnp.allclose(params.dynamics_function(z), jnp.sin(Wf @ poly))
    assert jnp.allclose(params.emission_function(z), jnp.cos(Wh @ poly))
    out = {"Wf": np.asarray(Wf).tolist(), "Wh": np.asarray(Wh).tolist(),
           "m0": np.asarray(params.initial_mean).tolist(), "P0": np.asarray(params.initial_covariance).tolist(),
           "emissions": np.asarray(emissions).tolist()}
    gg = ParamsGGSSM(initial_mean=params.initial_mean, initial_covariance=params.initial_covariance,
                     dynamics_function=params.dynamics_function, dynamics_covariance=params.dynamics_covariance,
                     emission_mean_function=params.emission_function,
                     emission_cov_function=lambda x: params.emission_covariance,
                     emission_dist=lambda mean, cov: MVN(mean, cov))
    runs = {
        "ekf": lambda y: ekf.extended_kalman_filter(params, y),
        "ukf": lambda y: ukf.unscented_kalman_filter(params, y, ukf.UKFHyperParams()),
        "ghkf": lambda y: ggi.conditional_moments_gaussian_filter(gg, GHKFIntegrals(order=5), y),
    }
    for name, run in runs.items():
        post, first = run(emissions), run(emissions[:1])
        out[name] = {"x": np.asarray(post.filtered_means).tolist(), "P": np.asarray(post.filtered_covariances).tolist(),
                     "loglik": float(post.marginal_loglik), "loglik_first": float(first.marginal_loglik)}
    hp = ukf.UKFHyperParams()
    out["ukf_hyperparams"] = [float(hp.alpha), float(hp.beta), float(hp.kappa)]
    return out


def stonesoup_case() -> dict:
    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.prediction import GaussianStatePrediction
    from stonesoup.updater.kalman import IteratedKalmanUpdater

    class ExactJacobian(CartesianToBearingRange):
        """Stone Soup differences h by default (forward steps of ~2e-7: H to ~1e-8); the
        reference uses the exact Jacobian of bearing atan2(y, x) and range hypot(x, y)."""

        def jacobian(self, state, **kwargs):
            x, y = float(state.state_vector[0, 0]), float(state.state_vector[2, 0])
            r2 = x * x + y * y
            r = np.sqrt(r2)
            return np.array([[-y / r2, 0, x / r2, 0], [x / r, 0, y / r, 0]])

    R = np.diag([np.radians(1), 1])
    model = ExactJacobian(ndim_state=4, mapping=[0, 2], noise_covar=R)
    prior = GaussianStatePrediction(np.array([[10], [0], [10], [0]]), np.eye(4) * 0.5)
    y = np.array([[np.radians(45)], [14.14]])
    updater = IteratedKalmanUpdater(measurement_model=model, tolerance=1e-11, max_iterations=1000)
    post = updater.update(SingleHypothesis(prediction=prior, measurement=Detection(y, measurement_model=model)))
    return {"R": R.tolist(), "x_pred": [10.0, 0.0, 10.0, 0.0], "P_pred": (np.eye(4) * 0.5).tolist(),
            "y": y.ravel().tolist(), "x": np.asarray(post.state_vector, dtype=float).ravel().tolist(),
            "P": np.asarray(post.covar, dtype=float).tolist()}


def main() -> None:
    import dynamax
    import stonesoup

    doc = {"made_by": "tests/reference/make_peer_reference.py", "dynamax": dynamax.__version__,
           "stonesoup": stonesoup.__version__, "dynamax_case": dynamax_case(), "stonesoup_case": stonesoup_case()}
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
