"""The learner interface: an exploration strategy as a triple of pure functions.

A learner is ``Learner(init, act, update)`` (optax / gymnax style) over ONE copy (one object
and seed of a grasp run, one seed of a synthetic run), unbatched; the runners vmap it::

    state = learner.init(key, theta0, core_set)            # LearnerState
    action, probs, state = learner.act(key, state, obs)    # one decision over K candidates
    state = learner.update(key, state, batch)              # after an exploration phase

Learners take their network as an argument (:class:`Model`: ``Network(init, apply)`` plus the
logits the loss is on and the features Neural-Linear uses) and assume nothing about what a
candidate is: in grasping ``Obs.inputs`` is the 64 candidates' (crop image [K, S, S], grasp
depth [K]); on a synthetic problem it is a [K, d] context. Distributions over candidates come
from :mod:`sern_jax.core.policies` with the validity mask; the draw is ``policies.sample_icdf``
with the uniform ``Obs.u``, which the runners share between learners (common random
numbers: paired comparisons). Randomness a learner needs beyond that (a Thompson draw, an
ensemble member) comes from the ``key`` of ``act``; ``key`` is consumed.

Phases. Algorithm 1 alternates exploration phases (``act`` on E contexts) and updates. The
runners call ``act`` on the same state for every decision of a phase (vmapped over them, as
one robot batch), so a learner changes its state in ``update``; what a per-decision schedule
needs is in ``Obs.t``. ``act`` still returns a state (the interface's shape), and the runners
keep the state from before the phase.

The core imports jax, numpy and optax only: never flax or mujoco (DESIGN.md).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from sern_jax.core import policies as pol
from sern_jax.core.types import Array, Key, Params

__all__ = [
    "FLOAT32_TINY",
    "LOSSES",
    "Batch",
    "Buffer",
    "Data",
    "Learner",
    "LearnerState",
    "Model",
    "Obs",
    "PolicyExtra",
    "TrainConfig",
    "append",
    "bce_loss",
    "check_positive",
    "check_probability",
    "empty_buffer",
    "l1_loss",
    "loss_function",
    "make_fit",
    "make_neural_init",
    "make_neural_update",
    "make_train_step",
    "network_predict",
    "policy_act",
]

FLOAT32_TINY = float(np.finfo(np.float32).tiny)  # smallest normal float32, 1.1754944e-38


# ----------------------------------------------------------------------------- types


def _identity(params):
    return params


def _replace_all(params, trained):
    del params
    return trained


class Model(NamedTuple):
    """The network a learner fine-tunes, as pure functions of ``(params, *inputs)``.

    ``inputs`` is a tuple of arrays with equal leading shape [...] (one row per candidate):
    ``apply`` returns r̂ ∈ [0, 1] of shape [...], ``logits`` the logit the loss is on, and
    ``features`` the last hidden layer [..., d] (Neural-Linear's features, the DPP's).
    ``trainable(params)`` is the part the optimiser trains and ``merge(params, trained)``
    puts it back (the quality network keeps its input normaliser fixed:
    ``trainable = lambda p: p.net``); by default all of ``params`` is trained.
    """

    init: Callable[..., Params]  # init(key, ...) -> params (Network's; learners get θ0)
    apply: Callable[..., Array]  # apply(params, *inputs) -> r̂ [...]
    logits: Callable[..., Array]  # logits(params, *inputs) -> [...]
    features: Callable[..., Array]  # features(params, *inputs) -> [..., d]
    trainable: Callable[[Params], Any] = _identity
    merge: Callable[[Params, Any], Params] = _replace_all


class Obs(NamedTuple):
    """What a learner sees at one decision (K candidates)."""

    inputs: tuple  # the network's inputs per candidate, each [K, ...] (grasp: image, depth)
    valid: Array  # [K] bool: which candidates may be chosen
    u: Array  # [] float32 in [0, 1): the inverse-CDF uniform (shared by learners)
    t: Array  # [] int32: exploration decisions before this one in the run (0-based)


class Batch(NamedTuple):
    """One exploration phase's outcomes, as ``update`` gets them (E decisions)."""

    inputs: tuple  # the chosen candidates' inputs, each [E, ...] (NO_ARM rows: any values)
    action: Array  # [E] int32 chosen candidate, policies.NO_ARM (-1) when none was valid
    reward: Array  # [E] float32 reward (0 where action is NO_ARM)


class Data(NamedTuple):
    """Labelled rows a network trains on (the core set C; a buffer's rows)."""

    inputs: tuple  # each [N, ...]
    reward: Array  # [N] float32 labels in [0, 1]
    weight: Array  # [N] float32 >= 0 sampling weight; 0 = an empty row


class Buffer(NamedTuple):
    """A learner's data D ∪ C: rows [0, T) hold D in arrival order (T = the horizon),
    rows [T, T + |C|) the core set C (weight 1)."""

    inputs: tuple  # each [T + |C|, ...]
    reward: Array  # [T + |C|] float32
    weight: Array  # [T + |C|] float32 (1 stored, 0 empty or nothing valid)
    count: Array  # [] int32: D rows written (the next batch goes to rows count..count+E)


class LearnerState(NamedTuple):
    """One copy's state (the runners add leading [O, S] axes)."""

    params: Params  # network parameters θ (a pytree)
    opt_state: Any  # optax state over model.trainable(params)
    buffer: Buffer  # D ∪ C
    extra: Any  # learner-specific: hyperparameters as float32 [] arrays (traced, so
    #              sweeps are vmaps), a posterior (mean [d], precision [d, d]), ensemble, ...


class Learner(NamedTuple):
    """An exploration strategy: pure, unbatched functions over one copy."""

    init: Callable[[Key, Params, Data], LearnerState]  # (key, θ0, core set C)
    act: Callable[[Key, LearnerState, Obs], tuple[Array, Array, LearnerState]]
    #   -> (action [] int32, NO_ARM only when nothing is valid; probs [K], 0 on invalid
    #       slots, summing to 1 over the valid ones (an index policy: its one-hot); state)
    update: Callable[[Key, LearnerState, Batch], LearnerState]  # after each phase
    predict: Callable[[LearnerState, Obs], Array] | None = None
    #   the learner's point estimate r̂ [K] for greedy evaluation (None: model.apply)


class PolicyExtra(NamedTuple):
    """``extra`` of the learners whose policy is a function of r̂ (sern, sern_log, egreedy,
    greedy): one state structure, so the runners compile their shared update once."""

    alpha: Array  # [] float32 softmax temperature (traced: a sweep over α is a vmap)
    epsilon: Array  # [] float32 ε-greedy's exploration probability


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """What every neural learner shares: its buffer and the optax update after each phase
    (Adam on minibatches drawn from D ∪ C).

    Attributes:
      horizon: T, exploration decisions over the whole run (the buffer holds T rows of D;
        Algorithm 1's α schedule uses it).
      fit_steps, batch_size, learning_rate: Adam steps per update, rows per step, step size.
      loss: ``"bce"`` (a proper scoring rule: r̂ estimates P(success)) or ``"l1"`` (the
        printed Algorithm 1, a negative control).
    """

    horizon: int
    fit_steps: int = 40
    batch_size: int = 32
    learning_rate: float = 3e-4
    loss: str = "bce"

    def __post_init__(self):
        # named as `sern grasp learn` spells them (batch_size, learning_rate: no flag)
        for name, flag in (("horizon", "--rounds x --explore"), ("fit_steps", "--fit-steps"),
                           ("batch_size", "batch_size")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{flag} must be an integer >= 1, got {v!r}")
        check_positive("learning_rate", self.learning_rate)
        if self.loss not in LOSSES:
            raise ValueError(f"--loss must be one of {tuple(LOSSES)}, got {self.loss!r}")


# ----------------------------------------------------------------------------- validation


def _as_float(flag: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{flag} must be a number, got {value!r}")
    return float(value)


def check_positive(flag: str, value) -> float:
    """``value`` as a float, or a ``ValueError`` naming ``flag``: it must be finite and a
    normal float32 (>= 1.18e-38 and < 3.4e38), since the learners compute in float32."""
    v = _as_float(flag, value)
    with np.errstate(over="ignore"):
        finite32 = bool(np.isfinite(np.float32(v)))
    if not (np.isfinite(v) and finite32 and v >= FLOAT32_TINY):
        raise ValueError(f"{flag} must be a finite number >= {FLOAT32_TINY:.8g} (float32's "
                         f"smallest normal) and < 3.4e38, got {value!r}")
    return v


def check_probability(flag: str, value) -> float:
    """``value`` in [0, 1] as a float: 0 exactly, or at least float32's smallest normal."""
    v = _as_float(flag, value)
    if not (np.isfinite(v) and 0.0 <= v <= 1.0 and (v == 0.0 or v >= FLOAT32_TINY)):
        raise ValueError(f"{flag} must be in [0, 1] (0 or >= {FLOAT32_TINY:.8g}, float32's "
                         f"smallest normal), got {value!r}")
    return v


# ----------------------------------------------------------------------------- losses


def _weighted_mean(values, weights):
    if weights is None:
        return jnp.mean(values)
    weights = jnp.asarray(weights, values.dtype)
    return jnp.sum(weights * values) / jnp.maximum(jnp.sum(weights), 1e-12)


def bce_loss(logits, labels, weights=None):
    """Weighted binary cross-entropy on logits (the default loss).

    BCE is a strictly proper scoring rule for Bernoulli outcomes: its expected value is
    minimised by r̂ = P(reward = 1 | x), so the network estimates a success probability,
    which the softmax policy and the theory (r̂ ∈ [0, 1] as an expected reward) need.
    Computed stably from logits (``optax.sigmoid_binary_cross_entropy``).

    Args:
      logits: [N] network logits.
      labels: [N] rewards in {0, 1} (or frequencies in [0, 1]).
      weights: optional [N] >= 0 per-example weights (0 = padding).

    Returns:
      [] sum(w * loss) / sum(w) (0 when all weights are 0).
    """
    labels = jnp.asarray(labels, logits.dtype)
    return _weighted_mean(optax.sigmoid_binary_cross_entropy(logits, labels), weights)


def l1_loss(logits, labels, weights=None):
    """Weighted L1 loss |R - r̂| with r̂ = sigmoid(logit): the printed Algorithm 1's loss.

    Kept as a negative control only. The expected L1 loss is minimised by the conditional
    *median* of R, and the median of a Bernoulli(p) reward is 0 or 1 (1 iff p > 1/2), so
    L1 drives r̂ towards 0/1 votes rather than the success probability p; its gradient is
    also flat in the error size. BCE is the default for that reason.

    Args:
      logits: [N] network logits.
      labels: [N] rewards in {0, 1}.
      weights: optional [N] >= 0 per-example weights (0 = padding).

    Returns:
      [] sum(w * |R - r̂|) / sum(w).
    """
    labels = jnp.asarray(labels, logits.dtype)
    return _weighted_mean(jnp.abs(labels - jax.nn.sigmoid(logits)), weights)


LOSSES = {"bce": bce_loss, "l1": l1_loss}


# ----------------------------------------------------------------------------- training


def loss_function(loss) -> Callable:
    """``loss`` as a function: a name of :data:`LOSSES` or a callable ``(logits, labels,
    weights) -> []``; an unknown name is a ``ValueError``."""
    if callable(loss):
        return loss
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; known: {sorted(LOSSES)}")
    return LOSSES[loss]


def make_train_step(model: Model, optimizer: optax.GradientTransformation, loss="bce"):
    """One optimiser step on a given minibatch.

    Returns ``train_step(params, opt_state, inputs, labels, weights) -> (params, opt_state,
    loss)``, pure: ``inputs`` a tuple of [B, ...] arrays (``model``'s), ``labels`` and
    ``weights`` [B]; the loss is the minibatch's weighted mean before the update, and rows of
    weight 0 contribute nothing. ``opt_state`` is over ``model.trainable(params)``.
    """
    loss_fn = loss_function(loss)

    def train_step(params, opt_state, inputs, labels, weights):
        def objective(trained):
            return loss_fn(model.logits(model.merge(params, trained), *inputs), labels, weights)

        trained = model.trainable(params)
        value, grads = jax.value_and_grad(objective)(trained)
        updates, opt_state = optimizer.update(grads, opt_state, trained)
        return model.merge(params, optax.apply_updates(trained, updates)), opt_state, value

    return train_step


def make_fit(model: Model, optimizer: optax.GradientTransformation, loss="bce",
             batch_size: int = 64, num_steps: int = 16):
    """``num_steps`` minibatch optimiser steps in one ``lax.scan``: pure, jit- and vmap-able.

    The one weighted-minibatch fit: the learners' update and the quality network's training
    (:func:`sern_jax.grasp.model.quality_net.make_fit`) both run it.

    Returns ``fit(key, params, opt_state, data: Data) -> (params, opt_state, mean_loss)``;
    ``key`` is consumed. Each step draws ``batch_size`` rows with replacement with
    probability ``weight / sum(weight)`` (inverse CDF: zero-weight rows are never drawn) and
    takes one step on their unweighted mean loss: in expectation the weighted-mean loss of
    the data. ``mean_loss`` is the mean over steps of the minibatch loss before each update.
    With all weights 0 nothing changes and ``mean_loss`` is 0. ``opt_state`` is over
    ``model.trainable(params)``. vmap ``fit`` over (key, params, opt_state[, data]) to train
    independent copies.
    """
    if not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
        raise ValueError(f"batch_size must be an int >= 1, got {batch_size!r}")
    if not isinstance(num_steps, (int, np.integer)) or num_steps < 1:
        raise ValueError(f"num_steps must be an int >= 1, got {num_steps!r}")
    train_step = make_train_step(model, optimizer, loss)

    def fit(key: Key, params, opt_state, data: Data):
        n = data.weight.shape[0]
        weight = jnp.maximum(jnp.asarray(data.weight, jnp.float32), 0.0)
        cdf = jnp.cumsum(weight)
        total = cdf[-1]
        has_data = total > 0
        u = jax.random.uniform(key, (num_steps, batch_size)) * total
        idx = jnp.clip(jnp.searchsorted(cdf, u, side="right"), 0, n - 1)
        ones = jnp.broadcast_to(has_data.astype(jnp.float32), (batch_size,))

        def body(carry, idx_t):
            params, opt_state = carry
            inputs = tuple(x[idx_t] for x in data.inputs)
            new_params, new_opt_state, value = train_step(
                params, opt_state, inputs, data.reward[idx_t], ones)
            keep = lambda new, old: jax.tree.map(
                lambda a, b: jnp.where(has_data, a, b), new, old)
            return (keep(new_params, params), keep(new_opt_state, opt_state)), value

        (params, opt_state), values = jax.lax.scan(body, (params, opt_state), idx)
        return params, opt_state, jnp.mean(values)

    return fit


def empty_buffer(core_set: Data, horizon: int) -> Buffer:
    """``horizon`` empty rows of D followed by the core set C."""
    inputs = tuple(jnp.concatenate([jnp.zeros((horizon,) + c.shape[1:], c.dtype), c])
                   for c in core_set.inputs)
    reward = jnp.concatenate([jnp.zeros(horizon, jnp.float32),
                              jnp.asarray(core_set.reward, jnp.float32)])
    weight = jnp.concatenate([jnp.zeros(horizon, jnp.float32),
                              jnp.asarray(core_set.weight, jnp.float32)])
    return Buffer(inputs, reward, weight, jnp.zeros((), jnp.int32))


def append(buffer: Buffer, batch: Batch) -> Buffer:
    """Writes the phase's E rows at ``buffer.count`` (weight 1, or 0 where the action is
    NO_ARM). The caller keeps ``count + E <= T`` (the runners check it before compiling:
    a traced write past T would be clamped onto the last rows)."""
    at = buffer.count

    def put(rows, new):
        return jax.lax.dynamic_update_slice_in_dim(rows, new.astype(rows.dtype), at, 0)

    inputs = tuple(put(r, n) for r, n in zip(buffer.inputs, batch.inputs))
    weight = (batch.action >= 0).astype(jnp.float32)
    return Buffer(inputs, put(buffer.reward, batch.reward), put(buffer.weight, weight),
                  at + batch.action.shape[0])


@functools.lru_cache(maxsize=32)
def network_predict(model: Model):
    """``predict(state, obs) -> r̂ [K]``: the network's estimate (greedy evaluation). Cached:
    learners over one model share the function (and the runners its compile)."""

    def predict(state: LearnerState, obs: Obs) -> Array:
        return model.apply(state.params, *obs.inputs)

    return predict


def make_neural_init(model: Model, train: TrainConfig, extra_fn: Callable[[Key], Any]):
    """``init(key, θ0, C)``: θ0, a fresh Adam state, an empty D before C, ``extra_fn(key)``."""
    optimizer = _optimizer(train.learning_rate)

    def init(key: Key, theta0: Params, core_set: Data) -> LearnerState:
        return LearnerState(theta0, optimizer.init(model.trainable(theta0)),
                            empty_buffer(core_set, train.horizon), extra_fn(key))

    return init


@functools.cache
def _optimizer(learning_rate: float) -> optax.GradientTransformation:
    return optax.adam(learning_rate)


@functools.lru_cache(maxsize=32)
def make_neural_update(model: Model, train: TrainConfig):
    """Algorithm 1's update: append the phase to D, then ``train.fit_steps`` Adam steps on
    D ∪ C with the whole ``key``. Cached, so learners with the same model and TrainConfig
    share one function (the runners compile it once)."""
    fit = make_fit(model, _optimizer(train.learning_rate), train.loss, train.batch_size,
                   train.fit_steps)

    def update(key: Key, state: LearnerState, batch: Batch) -> LearnerState:
        buffer = append(state.buffer, batch)
        data = Data(buffer.inputs, buffer.reward, buffer.weight)
        params, opt_state, _ = fit(key, state.params, state.opt_state, data)
        return state._replace(params=params, opt_state=opt_state, buffer=buffer)

    return update


def policy_act(model: Model, probs_fn: Callable[[Array, Array, LearnerState, Obs], Array]):
    """``act`` of a learner whose distribution is a function of the network's r̂:
    ``probs = probs_fn(r_hat [K], valid [K], state, obs)`` (a :mod:`sern_jax.core.policies`
    function with the mask), drawn by ``sample_icdf(obs.u, probs, mask)``. ``key`` unused."""

    def act(key: Key, state: LearnerState, obs: Obs):
        del key
        r_hat = model.apply(state.params, *obs.inputs)
        probs = probs_fn(r_hat, obs.valid, state, obs)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    return act
