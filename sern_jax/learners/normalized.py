"""Normalized-probability exploration: ``π(a) = r̂_a / Σ_b r̂_b`` over the valid candidates
(``policies.normalized_probs``), the exploration the SERN paper cites as [13] (Berscheid,
Rühr, Kröger 2019, "Improving data efficiency of self-supervised learning for robotic
grasping"): "normalized probability method whose probability is obtained by normalizing the
grasp quality". No hyperparameter (so no knob to tune); the network is fine-tuned by the
same optax update as every learner."""

from __future__ import annotations

import dataclasses

from sern_jax.core import policies as pol
from sern_jax.learners import base

__all__ = ["NormalizedConfig", "normalized"]


@dataclasses.dataclass(frozen=True)
class NormalizedConfig:
    """No hyperparameters."""


def _probs(r_hat, valid, state, obs):
    del state, obs
    return pol.normalized_probs(r_hat, mask=valid)


def normalized(model: base.Model, train: base.TrainConfig,
               config: NormalizedConfig = NormalizedConfig()) -> base.Learner:
    del config
    return base.Learner(
        init=base.make_neural_init(model, train, lambda key: ()),
        act=base.policy_act(model, _probs),
        update=base.make_neural_update(model, train),
        predict=base.network_predict(model))
