"""NeuralUCB (Zhou, Li, Gu 2020) with the diagonal approximation of its gradient covariance,
as in the authors' released code (uclaml/NeuralUCB, ``learner_diag.py``).

For each candidate, ``g = ∇_θ r̂(x; θ)`` (the gradient of the network's output with respect
to its trained parameters, P numbers) and the index

    U_a = r̂_a + sqrt(λ ν Σ_p g_p² / Z_p),     Z = λ 1 + Σ_{played} g ⊙ g   (diagonal of Z),

played greedily over the valid candidates (ties uniform, by the shared ``obs.u``). Defaults
from the released code: λ = 0.001 (``--ucb-lambda``), ν = 1 (``--nu``), Z0 = λ 1.

What we chose. Z accumulates the gradients of the candidates the learner played, at the
parameters it played them with, as in the paper; the core set (training data the learner
did not choose) is not in Z. The runners act on a whole exploration phase with one state
(a batched bandit, like NeuralTS's ``--delay``), so Z takes the phase's E gradients in
``update``, before the network's optax step, rather than after each grasp; the network is
fine-tuned by the same update as every learner (the released code runs SGD with weight
decay λ to convergence instead). ``act`` needs K per-candidate gradients (K backward passes,
run one candidate after another to bound memory), which is what this learner costs over
SERN (the round-time benchmark in ``experiments.grasp_baselines bench``).

``probs`` is the one-hot of the played candidate's ties (π of an argmax policy).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from sern_jax.core import policies as pol
from sern_jax.learners import base
from sern_jax.core.types import Array, Key

__all__ = ["NeuralUCBConfig", "NeuralUCBExtra", "candidate_gradients", "candidate_widths",
           "neural_ucb"]


@dataclasses.dataclass(frozen=True)
class NeuralUCBConfig:
    """``neural_ucb``'s hyperparameters."""

    ucb_lambda: float = dataclasses.field(default=0.001, metadata={
        "flag": "--ucb-lambda", "help": "neural_ucb: λ, Z0 = λ·1 (Zhou et al. 2020's "
        "code: 0.001)"})
    nu: float = dataclasses.field(default=1.0, metadata={
        "flag": "--nu", "help": "neural_ucb: ν, the width's scale (Zhou et al. 2020's "
        "code: 1)"})

    def __post_init__(self):
        base.check_positive("--ucb-lambda", self.ucb_lambda)
        base.check_positive("--nu", self.nu)


class NeuralUCBExtra(NamedTuple):
    z_diag: Array  # [P] float32 diagonal of Z over the trained parameters
    ucb_lambda: Array  # [] float32 λ
    nu: Array  # [] float32 ν


def _row_gradient(model: base.Model, params, row: tuple) -> Array:
    """``∇_θ r̂`` of one candidate (``row``: each input without its K axis), flattened [P]."""
    g = jax.grad(lambda tr: model.apply(model.merge(params, tr), *row))(
        model.trainable(params))
    return ravel_pytree(g)[0]


def candidate_gradients(model: base.Model, params, inputs: tuple) -> Array:
    """``∇_θ r̂`` of every row of ``inputs`` (each [K, ...]) over ``model.trainable(params)``,
    flattened: [K, P] (one backward pass per row; for small K and P: ``act`` never holds
    all K gradients, see :func:`candidate_widths`)."""
    return jax.vmap(lambda *row: _row_gradient(model, params, row))(*inputs)


def candidate_widths(model: base.Model, params, inputs: tuple, scale: Array) -> Array:
    """``Σ_p scale_p g_p²`` of every row of ``inputs`` (each [K, ...]): [K]. The rows run
    one after another (``lax.map``), so memory holds one gradient [P] per lane, not K
    (vmapped over a phase's grasps and the copies, all K would be O × S × E × K × P)."""

    def one(row):
        g = _row_gradient(model, params, row)
        return jnp.sum(scale * g * g)

    return jax.lax.map(one, inputs)


def _squared_gradients(model: base.Model, params, inputs: tuple) -> Array:
    """``g ⊙ g`` of every row of ``inputs`` (each [E, ...]), one row at a time: [E, P]."""
    return jax.lax.map(lambda row: jnp.square(_row_gradient(model, params, row)), inputs)


def neural_ucb(model: base.Model, train: base.TrainConfig,
               config: NeuralUCBConfig = NeuralUCBConfig()) -> base.Learner:
    """NeuralUCB with a diagonal Z."""
    neural_init = base.make_neural_init(model, train, lambda key: ())
    neural_update = base.make_neural_update(model, train)

    def init(key: Key, theta0, core_set: base.Data) -> base.LearnerState:
        state = neural_init(key, theta0, core_set)
        size = ravel_pytree(model.trainable(theta0))[0].shape[0]
        lam = jnp.float32(config.ucb_lambda)
        return state._replace(extra=NeuralUCBExtra(jnp.full((size,), lam, jnp.float32), lam,
                                                   jnp.float32(config.nu)))

    def act(key: Key, state: base.LearnerState, obs: base.Obs):
        del key
        ex = state.extra
        r_hat = model.apply(state.params, *obs.inputs)  # [K]
        width = jnp.sqrt(candidate_widths(model, state.params, obs.inputs,
                                          ex.ucb_lambda * ex.nu / ex.z_diag))
        probs = pol.greedy_probs(r_hat + width, mask=obs.valid)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    def update(key: Key, state: base.LearnerState, batch: base.Batch) -> base.LearnerState:
        g2 = _squared_gradients(model, state.params, batch.inputs)  # [E, P], θ as played
        played = (batch.action >= 0).astype(jnp.float32)
        z_diag = state.extra.z_diag + jnp.sum(played[:, None] * g2, axis=0)
        state = state._replace(extra=state.extra._replace(z_diag=z_diag))
        return neural_update(key, state, batch)

    return base.Learner(init, act, update, base.network_predict(model))
