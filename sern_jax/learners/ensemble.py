"""Bootstrapped-ensemble Thompson sampling (Osband et al. 2016; the Showdown's BootRMS).

M members started from θ0, each fine-tuned by the common optax update on its own bootstrap
weights of D ∪ C; at every decision one member is drawn uniformly (from ``act``'s key) and
its argmax over the valid candidates is played (ties: uniform, by the shared ``obs.u``).

Two layouts (``--ensemble-heads``). ``shared``, the default: Bootstrapped DQN's (Osband et
al. 2016), one network θ and M linear heads on its last hidden features, about one
network's cost per round (:func:`_shared_heads`). ``networks``: M whole network copies
(Riquelme et al. 2018's BootRMS), M forwards per greedy evaluation and M fits per update.
Shared heads is the default: it is the layout of the paper this learner follows, and the
one whose round costs about one network's, like SERN's, at M >= 3.

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
q = 3 models, p = 0.95); Bootstrapped DQN uses K = 10 heads. The comparison tunes M over
3, 5 and 10 (``experiments/grasp_baselines.py``, GRID).

``probs`` is π exactly: the mixture ``(1/M) Σ_m greedy_probs(r̂_m, mask)`` (each member's
argmax, ties uniform, with probability 1/M), so pseudo-regret is computed under the policy's
own distribution. Greedy evaluation (``predict``) uses the members' mean r̂.

State (``networks``): ``params`` / ``opt_state`` hold member 0 (so whatever reads
``state.params`` as one network sees a genuine member), ``extra.params`` /
``extra.opt_state`` members 1..M-1 stacked on a leading axis [M - 1, ...],
``extra.weights`` the bootstrap weights [M, T + |C|].

Cost (``networks``). ``act`` computes the action from the drawn member's forward alone and
π from all M, so a caller that does not output π (the grasp runner without regret
accounting) runs one forward per decision; ``update`` fits the M members as one vmapped
computation; greedy evaluation needs all M. ``shared`` (the default) costs about one
network per decision, update and evaluation (:func:`_shared_heads`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from sern_jax.core import policies as pol
from sern_jax.core.types import Array, Key
from sern_jax.learners import base
from sern_jax.learners.neural_linear import ArmFeatures

__all__ = ["BOOTSTRAPS", "HEADS", "EnsembleConfig", "EnsembleExtra", "Heads",
           "SharedHeadsExtra", "bootstrap_weights", "ensemble_ts", "head_features"]

BOOTSTRAPS = ("bernoulli", "poisson")
HEADS = ("networks", "shared")


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
    ensemble_heads: str = dataclasses.field(default="shared", metadata={
        "flag": "--ensemble-heads", "help": "ensemble_ts: shared (the default: one "
        "network, M linear heads on its last hidden features, Bootstrapped DQN's layout, "
        "Osband et al. 2016; about one network's cost) or networks (M whole network "
        "copies, Riquelme et al. 2018's BootRMS; M forwards and fits)"})

    def __post_init__(self):
        m = self.ensemble_size
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= 1024:
            raise ValueError(f"--ensemble-size must be an integer in [1, 1024], got {m!r}")
        if self.bootstrap not in BOOTSTRAPS:
            raise ValueError(f"--bootstrap must be one of {', '.join(BOOTSTRAPS)}, "
                             f"got {self.bootstrap!r}")
        if self.ensemble_heads not in HEADS:
            raise ValueError(f"--ensemble-heads must be one of {', '.join(HEADS)}, "
                             f"got {self.ensemble_heads!r}")
        p = base.check_probability("--bootstrap-p", self.bootstrap_p)
        if p == 0.0:
            raise ValueError(f"--bootstrap-p must be > 0 (a member with no data never "
                             f"learns), got {self.bootstrap_p!r}")


class Heads(NamedTuple):
    """``shared``'s member heads on the network's last hidden features [d]."""

    w: Array  # [M, d] float32, zero at init (every member starts at θ0)
    b: Array  # [M] float32


class SharedHeadsExtra(NamedTuple):
    heads: Heads  # the M members' heads (trained with θ by one Adam; see opt_state)
    weights: Array  # [M, T + |C|] float32 bootstrap weights of every row of D ∪ C


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


def head_features(features) -> Array:
    """What the shared layout's member heads read, [..., d]: ``model.features`` as they are,
    or, for a network with one linear head per arm (:class:`ArmFeatures`: the trunk's φ
    [..., h] and the arm's one-hot [..., G]), the block features onehot(arm) ⊗ φ
    [..., G·h], so each member adds one linear head per arm on the trunk, as the network's
    own heads are (a head on φ alone would add the same logit to every arm of a round)."""
    if isinstance(features, ArmFeatures):
        phi, arm = features.phi, jnp.asarray(features.arm, features.phi.dtype)
        block = arm[..., :, None] * phi[..., None, :]  # [..., G, h]
        return block.reshape(block.shape[:-2] + (block.shape[-2] * block.shape[-1],))
    return features


def ensemble_ts(model: base.Model, train: base.TrainConfig,
                config: EnsembleConfig = EnsembleConfig()) -> base.Learner:
    """Thompson sampling over a bootstrapped ensemble of ``config.ensemble_size`` members
    (``config.ensemble_heads``: M whole networks, or one network with M heads)."""
    if config.ensemble_heads == "shared":
        return _shared_heads(model, train, config)
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
        # The action needs only the drawn member's forward; π (the mixture) needs all M.
        # Computed apart, so a caller that drops ``probs`` (the runner without regret
        # accounting) lets XLA remove the other members' forwards: 1 forward per decision
        # instead of M, the same action (tests/learners: equal to the all-member argmax).
        m = jax.random.randint(key, (), 0, num_m)
        params, _ = members(state)
        drawn = model.apply(jax.tree.map(lambda x: x[m], params), *obs.inputs)  # [K]
        action = pol.sample_icdf(obs.u, pol.greedy_probs(drawn, mask=obs.valid),
                                 mask=obs.valid)
        r_hat = member_r_hat(state, obs)
        greedy = jax.vmap(lambda r: pol.greedy_probs(r, mask=obs.valid))(r_hat)  # [M, K]
        return action, jnp.mean(greedy, axis=0), state

    def predict(state: base.LearnerState, obs: base.Obs) -> Array:
        return jnp.mean(member_r_hat(state, obs), axis=0)

    return base.Learner(init, act, update, predict)


def _shared_heads(model: base.Model, train: base.TrainConfig,
                  config: EnsembleConfig) -> base.Learner:
    """``--ensemble-heads shared``: Bootstrapped DQN's layout (Osband et al. 2016), one
    network θ and M linear heads on its last hidden features φ(x):
    logit_m(x) = logit_θ(x) + φ_θ(x)·w_m + b_m, heads zero at init (every member starts
    at θ0, as in ``networks``). Each of ``train.fit_steps`` Adam steps draws ONE minibatch
    from D ∪ C (rows ∝ weight, as every learner's fit) and member m's loss is that
    minibatch's loss weighted by its bootstrap weights of the rows (Bootstrapped DQN's
    masks; Poisson counts as weights); θ and the heads take the gradient of the members'
    mean loss, with one Adam. A decision costs one forward (the M heads are a [d, M]
    product), an update one network's fit: about SERN's cost, where ``networks`` costs M
    forwards per evaluation and M fits. The members share θ, so they are more alike than
    M independent networks: another learner than ``networks``, with other results.

    State: ``params`` is θ (the shared network, not a member), ``opt_state`` Adam's over
    ``(model.trainable(θ), heads)``, ``extra`` :class:`SharedHeadsExtra`."""
    num_m = int(config.ensemble_size)
    optimizer = optax.adam(train.learning_rate)
    loss_fn = base.LOSSES[train.loss]
    num_steps, batch_size = train.fit_steps, train.batch_size

    def member_logits(params, heads: Heads, inputs) -> Array:
        """[M, ...]: every member's logit on inputs with leading shape [...]."""
        logit = model.logits(params, *inputs)  # [...]
        phi = head_features(model.features(params, *inputs))  # [..., d]
        b = jnp.reshape(heads.b, (num_m,) + (1,) * logit.ndim)
        return logit[None] + jnp.moveaxis(phi @ heads.w.T, -1, 0) + b

    def init(key: Key, theta0, core_set: base.Data) -> base.LearnerState:
        buffer = base.empty_buffer(core_set, train.horizon)
        d = jax.eval_shape(lambda p, *x: head_features(model.features(p, *x)), theta0,
                           *(x[:1] for x in core_set.inputs)).shape[-1]
        heads = Heads(jnp.zeros((num_m, d), jnp.float32), jnp.zeros((num_m,), jnp.float32))
        weights = bootstrap_weights(key, num_m, buffer.weight.shape[0], config.bootstrap,
                                    config.bootstrap_p)
        return base.LearnerState(theta0, optimizer.init((model.trainable(theta0), heads)),
                                 buffer, SharedHeadsExtra(heads, weights))

    def update(key: Key, state: base.LearnerState, batch: base.Batch) -> base.LearnerState:
        buffer = base.append(state.buffer, batch)  # D ∪ C, weights 1 (0: empty, NO_ARM)
        n = buffer.weight.shape[0]
        cdf = jnp.cumsum(jnp.maximum(buffer.weight, 0.0))
        total = cdf[-1]
        has_data = total > 0
        u = jax.random.uniform(key, (num_steps, batch_size)) * total
        idx = jnp.clip(jnp.searchsorted(cdf, u, side="right"), 0, n - 1)
        masks = state.extra.weights  # [M, N]

        def step(carry, idx_t):
            params, heads, opt_state = carry
            inputs = tuple(x[idx_t] for x in buffer.inputs)
            label = jnp.broadcast_to(buffer.reward[idx_t], (num_m, batch_size))

            def objective(trained):
                net, hd = trained
                lg = member_logits(model.merge(params, net), hd, inputs)  # [M, B]
                return jnp.mean(jax.vmap(loss_fn)(lg, label, masks[:, idx_t]))

            trained = (model.trainable(params), heads)
            value, grads = jax.value_and_grad(objective)(trained)
            updates, new_opt = optimizer.update(grads, opt_state, trained)
            net, new_heads = optax.apply_updates(trained, updates)
            new = (model.merge(params, net), new_heads, new_opt)
            keep = jax.tree.map(lambda a, b: jnp.where(has_data, a, b), new, carry)
            return keep, value

        (params, heads, opt_state), _ = jax.lax.scan(
            step, (state.params, state.extra.heads, state.opt_state), idx)
        return state._replace(params=params, opt_state=opt_state, buffer=buffer,
                              extra=state.extra._replace(heads=heads))

    def member_r_hat(state: base.LearnerState, obs: base.Obs) -> Array:
        return jax.nn.sigmoid(member_logits(state.params, state.extra.heads, obs.inputs))

    def act(key: Key, state: base.LearnerState, obs: base.Obs):
        r_hat = member_r_hat(state, obs)  # [M, K]: one forward, M heads
        greedy = jax.vmap(lambda r: pol.greedy_probs(r, mask=obs.valid))(r_hat)  # [M, K]
        m = jax.random.randint(key, (), 0, num_m)
        action = pol.sample_icdf(obs.u, greedy[m], mask=obs.valid)
        return action, jnp.mean(greedy, axis=0), state

    def predict(state: base.LearnerState, obs: base.Obs) -> Array:
        return jnp.mean(member_r_hat(state, obs), axis=0)

    return base.Learner(init, act, update, predict)
