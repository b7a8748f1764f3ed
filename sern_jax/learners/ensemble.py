"""Bootstrapped-ensemble Thompson sampling (Osband et al.; the Showdown's BootRMS).

M members, each a copy of the network started from θ0 and fine-tuned by the common optax
update on its own bootstrap weights of D ∪ C; at every decision one member is drawn
uniformly (from ``act``'s key) and its argmax over the valid candidates is played (ties:
uniform, by the shared ``obs.u``).

Bootstrap weights (``--bootstrap``): ``bernoulli`` (each row kept in a member's data with
probability ``--bootstrap-p``, weight 0 or 1: the Showdown's BootRMS, p = 0.95, and
Bootstrapped DQN's masks) or ``poisson`` (weight ~ Poisson(1): the classic online
bootstrap; ``--bootstrap-p`` unused). A row's weights are drawn once per member when the
learner starts (fold_in of the init key), for every row of D (filled later) and of C, so
each member keeps its bootstrap sample as D grows. The minibatch sampler draws rows with
probability ∝ weight (``base.make_fit``), so a weight-2 row counts twice.

What we chose. Members start identical (θ0, as every learner) and differ only through
their bootstrap weights and minibatch draws: the first phase is greedy on θ0, and the
members part from the first update on (Osband et al. start members from independent random
initialisations, which a fine-tuning learner does not have). Defaults are the Showdown's
(``hparams_rms`` in tensorflow/models ``research/deep_contextual_bandits/example_main.py``:
q = 3 models, p = 0.95); Bootstrapped DQN uses K = 10 heads.

``probs`` is π exactly: the mixture ``(1/M) Σ_m greedy_probs(r̂_m, mask)`` (each member's
argmax, ties uniform, with probability 1/M), so pseudo-regret is computed under the policy's
own distribution. Greedy evaluation (``predict``) uses the members' mean r̂.

State: ``params`` / ``opt_state`` hold member 0 (so whatever reads ``state.params`` as one
network sees a genuine member), ``extra.params`` / ``extra.opt_state`` members 1..M-1
stacked on a leading axis [M - 1, ...], ``extra.weights`` the bootstrap weights
[M, T + |C|].
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from sern_jax import policies as pol
from sern_jax.learners import base
from sern_jax.types import Array, Key

__all__ = ["BOOTSTRAPS", "EnsembleConfig", "EnsembleExtra", "bootstrap_weights",
           "ensemble_ts"]

BOOTSTRAPS = ("bernoulli", "poisson")


@dataclasses.dataclass(frozen=True)
class EnsembleConfig:
    """``ensemble_ts``'s hyperparameters."""

    ensemble_size: int = dataclasses.field(default=3, metadata={
        "flag": "--ensemble-size", "help": "ensemble_ts: members M, each a network copy "
        "(Riquelme et al. 2018's BootRMS: 3)"})
    bootstrap: str = dataclasses.field(default="bernoulli", metadata={
        "flag": "--bootstrap", "help": "ensemble_ts: bootstrap weights, bernoulli "
        "(0/1 masks) or poisson (Poisson(1) counts)"})
    bootstrap_p: float = dataclasses.field(default=0.95, metadata={
        "flag": "--bootstrap-p", "help": "ensemble_ts: probability a row is in a member's "
        "data, bernoulli only (Riquelme et al. 2018: 0.95)"})

    def __post_init__(self):
        m = self.ensemble_size
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= 1024:
            raise ValueError(f"--ensemble-size must be an integer in [1, 1024], got {m!r}")
        if self.bootstrap not in BOOTSTRAPS:
            raise ValueError(f"--bootstrap must be one of {', '.join(BOOTSTRAPS)}, "
                             f"got {self.bootstrap!r}")
        p = base.check_probability("--bootstrap-p", self.bootstrap_p)
        if p == 0.0:
            raise ValueError(f"--bootstrap-p must be > 0 (a member with no data never "
                             f"learns), got {self.bootstrap_p!r}")


class EnsembleExtra(NamedTuple):
    params: object  # members 1..M-1 stacked: leaves [M - 1, ...] (member 0 is state.params)
    opt_state: object  # their optax states, leaves [M - 1, ...]
    weights: Array  # [M, T + |C|] float32 bootstrap weights of every row of D ∪ C


def bootstrap_weights(key: Key, num_members: int, num_rows: int, kind: str,
                      p: float) -> Array:
    """[M, N] float32 weights: Bernoulli(p) in {0, 1} or Poisson(1) counts. key consumed."""
    if kind == "bernoulli":
        return jax.random.bernoulli(key, p, (num_members, num_rows)).astype(jnp.float32)
    if kind == "poisson":
        return jax.random.poisson(key, 1.0, (num_members, num_rows)).astype(jnp.float32)
    raise ValueError(f"--bootstrap must be one of {', '.join(BOOTSTRAPS)}, got {kind!r}")


def ensemble_ts(model: base.Model, train: base.TrainConfig,
                config: EnsembleConfig = EnsembleConfig()) -> base.Learner:
    """Thompson sampling over a bootstrapped ensemble of ``config.ensemble_size`` members."""
    num_m = int(config.ensemble_size)
    one_init = base.make_neural_init(model, train, lambda key: ())
    fit = base.make_fit(model, optax.adam(train.learning_rate), train.loss,
                        train.batch_size, train.fit_steps)

    def init(key: Key, theta0, core_set: base.Data) -> base.LearnerState:
        state = one_init(key, theta0, core_set)
        rows = state.buffer.weight.shape[0]
        weights = bootstrap_weights(key, num_m, rows, config.bootstrap, config.bootstrap_p)
        stack = lambda x: jnp.broadcast_to(x, (num_m - 1,) + jnp.shape(x))
        return state._replace(extra=EnsembleExtra(jax.tree.map(stack, state.params),
                                                  jax.tree.map(stack, state.opt_state),
                                                  weights))

    def members(state: base.LearnerState):
        """(params, opt_state) of all M members, leaves [M, ...]."""
        join = lambda a, b: jnp.concatenate([a[None], b])
        return (jax.tree.map(join, state.params, state.extra.params),
                jax.tree.map(join, state.opt_state, state.extra.opt_state))

    def update(key: Key, state: base.LearnerState, batch: base.Batch) -> base.LearnerState:
        buffer = base.append(state.buffer, batch)  # D ∪ C, weights 1 (0: empty, NO_ARM)

        def member(m, params, opt_state, weights):
            # One member's Adam steps on its bootstrap weights of D ∪ C, its own key.
            data = base.Data(buffer.inputs, buffer.reward, buffer.weight * weights)
            params, opt_state, _ = fit(jax.random.fold_in(key, m), params, opt_state, data)
            return params, opt_state

        params, opt_state = jax.vmap(member)(jnp.arange(num_m), *members(state),
                                             state.extra.weights)
        first = lambda x: x[0]
        rest = lambda x: x[1:]
        extra = state.extra._replace(params=jax.tree.map(rest, params),
                                     opt_state=jax.tree.map(rest, opt_state))
        return state._replace(params=jax.tree.map(first, params),
                              opt_state=jax.tree.map(first, opt_state), buffer=buffer,
                              extra=extra)

    def member_r_hat(state: base.LearnerState, obs: base.Obs) -> Array:
        params, _ = members(state)
        return jax.vmap(lambda p: model.apply(p, *obs.inputs))(params)  # [M, K]

    def act(key: Key, state: base.LearnerState, obs: base.Obs):
        r_hat = member_r_hat(state, obs)
        greedy = jax.vmap(lambda r: pol.greedy_probs(r, mask=obs.valid))(r_hat)  # [M, K]
        m = jax.random.randint(key, (), 0, num_m)
        action = pol.sample_icdf(obs.u, greedy[m], mask=obs.valid)
        return action, jnp.mean(greedy, axis=0), state

    def predict(state: base.LearnerState, obs: base.Obs) -> Array:
        return jnp.mean(member_r_hat(state, obs), axis=0)

    return base.Learner(init, act, update, predict)
