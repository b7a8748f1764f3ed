"""ε-greedy over the network's r̂: (1 − ε) greedy (ties uniform) + ε uniform over the valid
candidates (``policies.epsilon_greedy_probs``); the paper's peer with ε = 0.1."""

from __future__ import annotations

import dataclasses

import numpy as np

from sern_jax.core import policies as pol
from sern_jax.learners import base

__all__ = ["EGreedyConfig", "egreedy"]


@dataclasses.dataclass(frozen=True)
class EGreedyConfig:
    epsilon: float = dataclasses.field(default=0.1, metadata={
        "flag": "--epsilon", "help": "egreedy's exploration probability ε (paper: 0.1)"})

    def __post_init__(self):
        base.check_probability("--epsilon", self.epsilon)


def _probs(r_hat, valid, state, obs):
    del obs
    return pol.epsilon_greedy_probs(r_hat, state.extra.epsilon, mask=valid)


def egreedy(model: base.Model, train: base.TrainConfig,
            config: EGreedyConfig = EGreedyConfig()) -> base.Learner:
    extra = base.PolicyExtra(np.float32(1.0), np.float32(config.epsilon))  # α unused
    return base.Learner(
        init=base.make_neural_init(model, train, lambda key: extra),
        act=base.policy_act(model, _probs),
        update=base.make_neural_update(model, train),
        predict=base.network_predict(model))
