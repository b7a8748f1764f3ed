"""The synthetic-context MLP: Network(init, apply), the learners' Model, and Neural-Linear's
features (the logit is exactly linear in them); the exact oracle model."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import contextual_problems as cp
from sern_jax.engine import networks


def test_logit_is_linear_in_the_features():
    model = networks.mlp_model(3, 2, (6, 5))
    params = model.init(jax.random.key(0))
    x = jnp.asarray([0.3, -0.4])
    z = networks.candidate_inputs(x, 3)  # [K, d + K]
    assert z.shape == (3, 5)
    feats = model.features(params, z)  # per-arm: φ(x) [K, h], the arm's one-hot [K, K]
    assert feats.phi.shape == (3, 5) and feats.arm.shape == (3, 3)
    np.testing.assert_array_equal(feats.arm, np.eye(3))
    head = params["params"]["Dense_2"]
    w = jnp.concatenate([head["kernel"], head["bias"][None, :]], axis=0)  # [h + 1, K]
    phi1 = jnp.concatenate([feats.phi, jnp.ones((3, 1))], axis=1)  # [K, h + 1]
    np.testing.assert_allclose(jnp.sum((phi1 @ w) * feats.arm, axis=1),
                               model.logits(params, z), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(model.apply(params, z), jax.nn.sigmoid(model.logits(params, z)),
                               rtol=1e-6)
    # per-seed copies: vmapped init gives distinct parameters per key
    many = jax.vmap(model.init)(jax.random.split(jax.random.key(1), 3))
    assert not np.allclose(many["params"]["Dense_0"]["kernel"][0],
                           many["params"]["Dense_0"]["kernel"][1])


def test_oracle_model_is_exact_and_shape_errors_name_the_flag():
    problem = cp.wheel(0.5)
    model = networks.oracle_model(problem)
    params = model.init(jax.random.key(0))
    x = jnp.asarray([0.6, 0.6])  # outer, arm 0 pays 50
    z = networks.candidate_inputs(x, 5)
    np.testing.assert_allclose(model.apply(params, z) * 50.1, [50, 1, 1, 1, 1.2], rtol=1e-5)
    net = networks.mlp(5, 2, (4,))
    with pytest.raises(ValueError, match="--hidden"):
        net.apply(net.init(jax.random.key(0)), jnp.zeros((5, 6)))
    with pytest.raises(ValueError, match="--hidden"):
        networks.mlp(5, 2, (0,))
