"""Greedy: the valid candidate of highest r̂ (ties uniform, ``policies.greedy_probs``); no
exploration beyond the network's own changes. The paper's second peer."""

from __future__ import annotations

import dataclasses

import numpy as np

from sern_jax.core import policies as pol
from sern_jax.learners import base

__all__ = ["GreedyConfig", "greedy"]


@dataclasses.dataclass(frozen=True)
class GreedyConfig:
    """No hyperparameters."""


def _probs(r_hat, valid, state, obs):
    del state, obs
    return pol.greedy_probs(r_hat, mask=valid)


def greedy(model: base.Model, train: base.TrainConfig,
           config: GreedyConfig = GreedyConfig()) -> base.Learner:
    del config
    extra = base.PolicyExtra(np.float32(1.0), np.float32(0.0))
    return base.Learner(
        init=base.make_neural_init(model, train, lambda key: extra),
        act=base.policy_act(model, _probs),
        update=base.make_neural_update(model, train),
        predict=base.network_predict(model))
