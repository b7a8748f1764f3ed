"""SERN: softmax exploration over the network's r̂, π = softmax(r̂ / α) over the valid
candidates (the maximiser of E_π r̂ + α S(π); ``policies.softmax_probs``).

Two learners: ``sern`` with a fixed temperature α (the paper's experiments: α = 0.05) and
``sern_log`` with Algorithm 1's α = α0 / ln(T^p), T the run's horizon. Both update by
Algorithm 1's optax step on D ∪ C (``base.make_neural_update``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sern_jax.core import policies as pol
from sern_jax.core import schedules
from sern_jax.learners import base

__all__ = ["SernConfig", "SernLogConfig", "sern", "sern_log"]


@dataclasses.dataclass(frozen=True)
class SernConfig:
    """``sern``'s hyperparameter."""

    alpha: float = dataclasses.field(default=0.05, metadata={
        "flag": "--alpha", "help": "sern's softmax temperature α (paper: 0.05)"})

    def __post_init__(self):
        base.check_positive("--alpha", self.alpha)


@dataclasses.dataclass(frozen=True)
class SernLogConfig:
    """``sern_log``'s hyperparameters: α = α0 / ln(T^p) (Algorithm 1)."""

    alpha0: float = dataclasses.field(default=1.0, metadata={
        "flag": "--alpha0", "help": "sern_log's α0 in α = α0/ln(T^p)"})
    p: float = dataclasses.field(default=0.3, metadata={
        "flag": "--p", "help": "sern_log's p in α = α0/ln(T^p), in (0, 1)"})

    def __post_init__(self):
        base.check_positive("--alpha0", self.alpha0)
        p = base.check_positive("--p", self.p)
        if not p < 1:
            raise ValueError(f"--p must be in (0, 1), got {self.p!r}")

    def alpha(self, horizon: int) -> float:
        """α of a run of ``horizon`` exploration decisions (float64 on the host)."""
        if horizon < 2:
            raise ValueError(f"sern_log needs a horizon T >= 2 (ln T > 0), got {horizon}")
        alpha = float(schedules.alpha_of_horizon("log", horizon, self.alpha0, self.p))
        return base.check_positive(f"sern_log's alpha = --alpha0/ln(T^--p) at T={horizon}",
                                   alpha)


def _softmax(r_hat, valid, state, obs):
    del obs
    return pol.softmax_probs(r_hat, state.extra.alpha, mask=valid)


def _make(model: base.Model, train: base.TrainConfig, alpha: float) -> base.Learner:
    extra = base.PolicyExtra(np.float32(alpha), np.float32(0.0))
    return base.Learner(
        init=base.make_neural_init(model, train, lambda key: extra),
        act=base.policy_act(model, _softmax),
        update=base.make_neural_update(model, train),
        predict=base.network_predict(model))


def sern(model: base.Model, train: base.TrainConfig,
         config: SernConfig = SernConfig()) -> base.Learner:
    """SERN with a fixed temperature ``config.alpha``."""
    return _make(model, train, config.alpha)


def sern_log(model: base.Model, train: base.TrainConfig,
             config: SernLogConfig = SernLogConfig()) -> base.Learner:
    """SERN with Algorithm 1's α = α0 / ln(T^p), T = ``train.horizon``."""
    return _make(model, train, config.alpha(train.horizon))
