"""The paper's two peers with their exploration decaying over grasps: ``egreedy_decay``
(ε-greedy, ``policies.epsilon_greedy_probs``) and ``sern_decay`` (softmax,
``policies.softmax_probs``). ``t`` = 1, 2, ... counts the run's exploration decisions
(``obs.t + 1``), so the schedule runs across rounds.

* ``egreedy_decay``: ε_t = min(1, ε0 / t), the ε_n-greedy of Auer, Cesa-Bianchi, Fischer
  (2002), whose ε_n = min(1, cK/(d²n)) gives logarithmic regret; ε0 stands for cK/d²
  (``--decay-epsilon0``). Their constants (c > 5, d below the gap, K = 64) would keep
  ε = 1 for over a thousand grasps, far past our 100-grasp runs; the default ε0 = 1
  explores Σ_t ε_t ≈ 5.2 random grasps in 100 (fixed ε = 0.1: 10), front-loaded.
* ``sern_decay``: α_t = α0 / log2(1 + t): α0 at the first grasp, then the 1/ln t rate of
  GLIE Boltzmann exploration (Singh et al. 2000); α0 is ``--decay-alpha0``, default 0.1
  (α = 0.1, 0.05, 0.025, 0.015 at t = 1, 3, 15, 100: the paper's fixed α = 0.05 is
  reached at the third grasp). Algorithm 1's α0/ln(T^p) is ``sern_log`` (constant in t).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp

from sern_jax.core import policies as pol
from sern_jax.learners import base
from sern_jax.core.types import Array

__all__ = [
    "DecayExtra",
    "EGreedyDecayConfig",
    "SernDecayConfig",
    "alpha_at",
    "check_schedule",
    "egreedy_decay",
    "epsilon_at",
    "sern_decay",
]


@dataclasses.dataclass(frozen=True)
class EGreedyDecayConfig:
    decay_epsilon0: float = dataclasses.field(default=1.0, metadata={
        "flag": "--decay-epsilon0", "help": "egreedy_decay: ε_t = min(1, ε0/t) at the t-th "
        "exploration grasp (Auer et al. 2002's ε_n-greedy)"})

    def __post_init__(self):
        base.check_positive("--decay-epsilon0", self.decay_epsilon0)


@dataclasses.dataclass(frozen=True)
class SernDecayConfig:
    decay_alpha0: float = dataclasses.field(default=0.1, metadata={
        "flag": "--decay-alpha0", "help": "sern_decay: α_t = α0/log2(1 + t) at the t-th "
        "exploration grasp"})

    def __post_init__(self):
        base.check_positive("--decay-alpha0", self.decay_alpha0)


class DecayExtra(NamedTuple):
    scale0: Array  # [] float32: ε0 or α0 (traced)


def epsilon_at(epsilon0: Array, t: Array) -> Array:
    """ε_t = min(1, ε0 / t), t ≥ 1 (float32 [])."""
    return jnp.minimum(1.0, epsilon0 / jnp.maximum(t, 1).astype(jnp.float32))


def alpha_at(alpha0: Array, t: Array) -> Array:
    """α_t = α0 / log2(1 + t), t ≥ 1 (float32 [])."""
    return alpha0 / jnp.log2(1.0 + jnp.maximum(t, 1).astype(jnp.float32))


def _egreedy(r_hat, valid, state, obs):
    return pol.epsilon_greedy_probs(r_hat, epsilon_at(state.extra.scale0, obs.t + 1),
                                    mask=valid)


def _softmax(r_hat, valid, state, obs):
    return pol.softmax_probs(r_hat, alpha_at(state.extra.scale0, obs.t + 1), mask=valid)


def _make(model, train, probs_fn, scale0: float) -> base.Learner:
    extra = DecayExtra(jnp.float32(scale0))
    return base.Learner(
        init=base.make_neural_init(model, train, lambda key: extra),
        act=base.policy_act(model, probs_fn),
        update=base.make_neural_update(model, train),
        predict=base.network_predict(model))


def check_schedule(flag: str, scale0: float, horizon: int, kind: str) -> None:
    """Every value the schedule takes over ``horizon`` decisions must be a normal float32,
    the bound the flag itself gets (``--decay-alpha0 1.1754944e-38`` is one, but α_T =
    α0/log2(1 + T) is not): its smallest value, at t = T (both schedules decrease in t),
    checked on the host in float64 before anything compiles; ``ValueError`` naming
    ``flag``."""
    import math

    t = max(int(horizon), 1)
    last = scale0 / math.log2(1.0 + t) if kind == "alpha" else min(1.0, scale0 / t)
    name = "α_T = α0/log2(1 + T)" if kind == "alpha" else "ε_T = min(1, ε0/T)"
    if not last >= base.FLOAT32_TINY:
        raise ValueError(f"{flag} {scale0:g} gives {name} = {last:.3g} at the last decision "
                         f"(T = {t}), below float32's smallest normal "
                         f"({base.FLOAT32_TINY:.8g}); use a larger {flag}")


def egreedy_decay(model: base.Model, train: base.TrainConfig,
                  config: EGreedyDecayConfig = EGreedyDecayConfig()) -> base.Learner:
    """ε-greedy with ε_t = min(1, ε0/t)."""
    check_schedule("--decay-epsilon0", config.decay_epsilon0, train.horizon, "epsilon")
    return _make(model, train, _egreedy, config.decay_epsilon0)


def sern_decay(model: base.Model, train: base.TrainConfig,
               config: SernDecayConfig = SernDecayConfig()) -> base.Learner:
    """SERN with α_t = α0/log2(1 + t)."""
    check_schedule("--decay-alpha0", config.decay_alpha0, train.horizon, "alpha")
    return _make(model, train, _softmax, config.decay_alpha0)
