"""Networks for synthetic contextual problems (neural layer: flax linen).

A candidate (a context x [d] and an arm a of K) is one input row ``z = [x, onehot(a)]``
[d + K], so a learner sees a round as ``Obs.inputs = (z [K, d + K],)`` exactly as it sees a
grasp's 64 candidates, and the same learner modules run on both.

:func:`mlp` is a multi-head MLP in the style of Riquelme et al.'s NeuralLinear: a shared ReLU
trunk φ(x) [h] and one linear head per arm, ``logit(x, a) = w_a·φ(x) + b_a``, ``r̂ = sigmoid``.
Its ``features`` are :class:`~sern_jax.learners.neural_linear.ArmFeatures`: the trunk's φ(x)
[h] and the candidate's arm (one-hot [K]), so ``logit = [φ(x), 1]·(w_a, b_a)`` exactly and
Neural-Linear keeps one Bayesian linear regression per arm on [φ(x), 1], as the original
NeuralLinear does.

:func:`oracle` is the exact estimator r̂ = r(x) (scaled to [0, 1]) with nothing to train: the
negative-control-free reference whose regret has a closed form.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from sern_jax.core.contextual_problems import ContextualBandit
from sern_jax.learners import base, neural_linear
from sern_jax.core.types import Array, Key, Network

__all__ = ["candidate_inputs", "MLP", "mlp", "mlp_model", "oracle_model", "check_input"]


def candidate_inputs(x: Array, num_arms: int) -> Array:
    """One round's candidates: x [d] -> z [K, d + K] (x repeated, then the arm's one-hot)."""
    eye = jnp.eye(num_arms, dtype=x.dtype)
    return jnp.concatenate([jnp.broadcast_to(x, (num_arms, x.shape[-1])), eye], axis=1)


class MLP(nn.Module):
    """Shared ReLU trunk on x, one linear head per arm; returns (logit [...], φ [..., h])."""

    num_arms: int
    context_dim: int
    hidden: Sequence[int] = (50, 50)

    @nn.compact
    def __call__(self, z):
        x = z[..., : self.context_dim]
        onehot = z[..., self.context_dim:]
        h = x
        for width in self.hidden:
            h = nn.relu(nn.Dense(width)(h))
        heads = nn.Dense(self.num_arms)(h)  # [..., K]
        return jnp.sum(heads * onehot, axis=-1), h


def check_input(z_shape, num_arms: int, context_dim: int) -> None:
    """A ``ValueError`` unless z's last axis is d + K (a network that does not fit the
    problem's context shape is refused before compiling)."""
    if len(z_shape) < 1 or z_shape[-1] != context_dim + num_arms:
        raise ValueError(f"--hidden network expects inputs of width d + K = "
                         f"{context_dim} + {num_arms}, got shape {tuple(z_shape)}")


def mlp(num_arms: int, context_dim: int, hidden: Sequence[int] = (50, 50)) -> Network:
    """``Network(init, apply)``: ``init(key) -> params``, ``apply(params, z [..., d+K]) ->
    logit [...]``."""
    if any(int(w) < 1 for w in hidden):
        raise ValueError(f"--hidden widths must be >= 1, got {tuple(hidden)}")
    module = MLP(num_arms, context_dim, tuple(int(w) for w in hidden))

    def init(key: Key):
        return module.init(key, jnp.zeros((1, context_dim + num_arms), jnp.float32))

    def apply(params, z):
        check_input(z.shape, num_arms, context_dim)
        return module.apply(params, z)[0]

    return Network(init, apply)


def mlp_model(num_arms: int, context_dim: int, hidden: Sequence[int] = (50, 50)) -> base.Model:
    """The learners' :class:`~sern_jax.learners.base.Model` over :func:`mlp`."""
    if any(int(w) < 1 for w in hidden):
        raise ValueError(f"--hidden widths must be >= 1, got {tuple(hidden)}")
    module = MLP(num_arms, context_dim, tuple(int(w) for w in hidden))
    net = mlp(num_arms, context_dim, hidden)

    def logits(params, z):
        return net.apply(params, z)

    def apply(params, z):
        return jax.nn.sigmoid(logits(params, z))

    def features(params, z):
        check_input(z.shape, num_arms, context_dim)
        _, h = module.apply(params, z)
        return neural_linear.ArmFeatures(phi=h, arm=z[..., context_dim:])

    return base.Model(init=net.init, apply=apply, logits=logits, features=features)


def oracle_model(problem: ContextualBandit) -> base.Model:
    """r̂(z) = the problem's exact expected reward, scaled to [0, 1]; params: one unused
    scalar (so optimiser steps run and change nothing)."""
    d, k = problem.context_dim, problem.num_arms

    def init(key: Key):
        del key
        return {"unused": jnp.zeros((), jnp.float32)}

    def apply(params, z):
        check_input(z.shape, k, d)
        x, onehot = z[..., :d], z[..., d:]
        flat_x = x.reshape((-1, d))
        r = jax.vmap(problem.expected_rewards)(flat_x).reshape(x.shape[:-1] + (k,))
        r = jnp.sum(problem.scale_reward(r) * onehot, axis=-1)
        return r + 0.0 * params["unused"]

    def logits(params, z):
        r = jnp.clip(apply(params, z), 1e-6, 1 - 1e-6)
        return jnp.log(r) - jnp.log1p(-r)

    def features(params, z):
        del params
        return z[..., d:]

    return base.Model(init=init, apply=apply, logits=logits, features=features)
