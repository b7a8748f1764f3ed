"""The batched runner for neural learners on exact-reward problems: ``jit(vmap(scan))``.

``make_run(config, problem, learner, model)`` returns ``run(key, params=None) ->
NeuralRunOutput`` for one seed; :func:`run_seeds` vmaps it over seeds ``fold_in(key(seed), i)``
(the tabular engine's :func:`sern_jax.engine.simulate.seed_keys`) in fixed-shape chunks,
through the one seed driver (:mod:`sern_jax.engine.drive`), so seed i gives the same result
alone or among 10,000. ``params``: the problem's traced parameters
(``contextual_problems.WheelParams``: δ), so a δ sweep is one compiled program
(``run_seeds(run, ..., params=WheelParams(δ))``); None: the problem's own values, closed
over.

One seed carries its learner's :class:`~sern_jax.learners.base.LearnerState` (network
parameters, optimiser state, a fixed-size buffer of ``T`` rows, learner extras) through a
``lax.scan``. The rounds come in phases of ``E = update_every`` decisions (Algorithm 1's
exploration phases): the E decisions of a phase act on the same state (vmapped, as the grasp
runner does), then ``learner.update`` appends them to the buffer and takes its minibatch
optimiser steps. Outputs are cumulative sums at checkpoints on phase ends (a log grid).

Random streams per seed key (STYLE.md §3, the ids of :mod:`sern_jax.engine.simulate`):

* environment ``fold_in(key, ENV_STREAM)`` → ``ROUNDS_STREAM`` → round t: the context
  (``fold_in(·, 0)``) and one draw of every arm's reward (``fold_in(·, 1)``). Learners run on
  the same seed see the same contexts and the same reward of each arm (common random numbers).
* ``fold_in(key, MODEL_STREAM)``: θ0, the network's initial parameters, shared by learners.
* agent ``fold_in(key, AGENT_STREAM)`` → ``ROUNDS_STREAM`` → round t: the inverse-CDF uniform
  ``Obs.u`` (shared by learners); → :data:`ACT_STREAM` → t: ``act``'s key; →
  :data:`UPDATE_STREAM` → phase: ``update``'s key; → :data:`INIT_STREAM`: ``init``'s key.

Regret (in the problem's units; the learners see rewards scaled to [0, 1]):
``regret`` = Σ_t max_a r_a(x_t) − r_{a_t}(x_t) (standard pseudo-regret, realised arm),
``regret_paper`` = Σ_t max_a E_x r_a(x) − r_{a_t}(x_t) (the paper's definition),
``regret_rb`` / ``regret_rb_paper`` the same with Σ_a π_t(a) r_a(x_t) for r_{a_t}(x_t)
(Rao–Blackwellised; an index learner's π is its one-hot). Field names match
:class:`sern_jax.engine.simulate.RunOutput`, so the regret experiment's files read the same.

This module imports jax, numpy, the core, the learners' interface and the seed driver; the
network comes in as a ``Model``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import policies as pol
from sern_jax.core.contextual_problems import ContextualBandit
from sern_jax.core.types import Array, Key
from sern_jax.engine import drive
from sern_jax.engine import plan as plan_lib
from sern_jax.engine.simulate import AGENT_STREAM, ENV_STREAM, ROUNDS_STREAM, kahan_add
from sern_jax.learners import base

__all__ = [
    "MODEL_STREAM",
    "ACT_STREAM",
    "UPDATE_STREAM",
    "INIT_STREAM",
    "NeuralRunConfig",
    "NeuralRunOutput",
    "checkpoint_phases",
    "checkpoint_times",
    "make_run",
    "run_seeds",
    "uniform_learner",
    "validate",
]

MODEL_STREAM = 2  # fold_in(seed_key, ·): θ0, shared by every learner of the seed
ACT_STREAM = 3  # agent sub-streams (ROUNDS_STREAM = 0 is the inverse-CDF uniform)
UPDATE_STREAM = 4
INIT_STREAM = 5


@dataclasses.dataclass(frozen=True)
class NeuralRunConfig:
    """Static configuration (changes the compiled program).

    Attributes:
      horizon: T, rounds; a multiple of ``update_every``.
      update_every: E, decisions per phase; the learner updates after each phase.
      num_checkpoints: requested size of the log grid of phase ends (duplicates removed).
      diagnostics: also accumulate the estimator's error at the chosen and at the best arm
        and (n_a + 1)^{-1/2} sums (Assumption 3 / Theorem 3 ingredients, :class:`NeuralDiag`),
        and, on a problem with finitely many contexts, the estimator's error on every
        (context, arm) at each checkpoint beside the pulls n_{s,a} (Assumption 3 per context).
    """

    horizon: int = 1000
    update_every: int = 50
    num_checkpoints: int = 16
    diagnostics: bool = False

    @property
    def num_phases(self) -> int:
        return self.horizon // self.update_every


class NeuralDiag(NamedTuple):
    """Per-seed sums at each checkpoint (scaled [0, 1] units), all [G].

    ``inv_sqrt_chosen`` / ``inv_sqrt_best`` use the pull counts at the start of each update
    phase (``update_every`` rounds), not N(t−1) at every round: counts only grow within a
    phase, so each term is ≥ Theorem 3's (N(t−1) + 1)^{−1/2} and a bound built on them is
    conservative (larger)."""

    err_chosen: Array  # Σ_t |r̂_{a_t}(x_t) − r_{a_t}(x_t)|
    err_best: Array  # Σ_t |r̂_{a*_t}(x_t) − r_{a*_t}(x_t)|, a*_t = argmax_a r_a(x_t)
    err_rb: Array  # Σ_t Σ_a π_t(a) |r̂_a(x_t) − r_a(x_t)|
    inv_sqrt_chosen: Array  # Σ_t (n_{a_t}(phase start) + 1)^{-1/2}
    table_err: Array  # [G, M, K] |r̂_a(s) − r_a(s)| at the checkpoint (M = 0: no table)
    table_counts: Array  # [G, M, K] int32 n_{s,a}: pulls of arm a in context s so far
    inv_sqrt_best: Array  # Σ_t (n_{a*}(phase start) + 1)^{-1/2}, a* = argmax_a E_x r_a(x)
    misid: Array  # Σ_t 1{â*_t ≠ a*}, â*_t = argmax_a mean_s r̂_a(s) over the finite
    #               problem's contexts with the acting state (0 without a context table)


class NeuralRunOutput(NamedTuple):
    """Per-seed summaries after round t_g of each checkpoint g (regret in problem units)."""

    regret: Array  # [G]
    regret_paper: Array  # [G]
    regret_rb: Array  # [G]
    regret_rb_paper: Array  # [G]
    counts: Array  # [G, K] int32 N_a(t)
    compensator: Array  # [G, K] Σ_{τ≤t} π_τ(a)
    min_prob: Array  # [G] min over τ ≤ t and arms of π_τ(a)
    diag: Optional[NeuralDiag]  # [G] each, or None without config.diagnostics


def validate(config: NeuralRunConfig, num_seeds: int = 1) -> None:
    """Host-side checks naming the flag; raises ``ValueError`` before any compile."""
    for flag, value, low in (("--horizon", config.horizon, 1),
                             ("--update-every", config.update_every, 1),
                             ("--checkpoints", config.num_checkpoints, 1),
                             ("--seeds", num_seeds, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{flag} must be an integer >= {low}, got {value!r}")
    if config.horizon % config.update_every:
        raise ValueError(f"--horizon {config.horizon} must be a multiple of --update-every "
                         f"{config.update_every} (rounds come in whole phases)")
    if config.horizon > 2**24:
        raise ValueError(f"--horizon must be <= 2^24 (float32 counts), got {config.horizon}")


def checkpoint_phases(config: NeuralRunConfig) -> np.ndarray:
    """Phases (1-based counts of finished phases) at which outputs are recorded: [G] ints,
    log-spaced in [1, P], increasing, last = P."""
    p = config.num_phases
    g = max(1, min(config.num_checkpoints, p))
    grid = np.unique(np.round(np.geomspace(1, p, g)).astype(np.int64))
    if grid[-1] != p:
        grid = np.append(grid, p)
    return grid


def checkpoint_times(config: NeuralRunConfig) -> np.ndarray:
    """Rounds t_g = phases × E of the checkpoints: [G] int64."""
    return checkpoint_phases(config) * config.update_every


def uniform_learner(num_arms: int) -> base.Learner:
    """Uniform: every valid arm with equal probability (Riquelme et al.'s normaliser); no
    network, no update (its state is an empty ``LearnerState``)."""

    def init(key, theta0, core_set):
        del key, theta0, core_set
        return base.LearnerState((), (), (), ())

    def act(key, state, obs):
        del key
        probs = obs.valid.astype(jnp.float32) / jnp.maximum(jnp.sum(obs.valid), 1)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    def update(key, state, batch):
        del key, batch
        return state

    def predict(state, obs):
        del state
        return jnp.full(obs.valid.shape, 0.5, jnp.float32)

    return base.Learner(init, act, update, predict)


class _Carry(NamedTuple):
    state: base.LearnerState
    sums: Array  # [4] regret sums (Kahan)
    sums_err: Array  # [4]
    counts: Array  # [K] int32
    comp: Array  # [K] float32 (Kahan)
    comp_err: Array  # [K]
    min_prob: Array  # []
    diag: Array  # [4] or [0] (Kahan-free: O(T) terms of size <= 1, far below 2^24)
    table_counts: Array  # [M, K] int32 (M = 0 without diagnostics or a finite problem)


def _empty_core_set(problem: ContextualBandit) -> base.Data:
    width = problem.context_dim + problem.num_arms
    return base.Data((jnp.zeros((0, width), jnp.float32),), jnp.zeros((0,), jnp.float32),
                     jnp.zeros((0,), jnp.float32))


def make_run(config: NeuralRunConfig, problem: ContextualBandit, learner: base.Learner,
             model: base.Model) -> Callable[[Key], NeuralRunOutput]:
    """The single-seed runner ``run(key) -> NeuralRunOutput`` (``key`` is consumed).

    Args:
      config: static configuration (validated here).
      problem: the contextual problem (its functions are closed over).
      learner: any ``Learner(init, act, update)`` of :mod:`sern_jax.learners` (its
        ``TrainConfig.horizon`` must be ≥ T: the buffer holds every round), or
        :func:`uniform_learner`.
      model: the network the learner was built on; ``model.init(key)`` gives θ0.
    """
    validate(config)
    num_arms, d = problem.num_arms, problem.context_dim
    e = config.update_every
    phases = checkpoint_phases(config)
    starts = np.concatenate([[0], phases[:-1]]).astype(np.int32)
    ends = phases.astype(np.int32)
    mu_star = float(np.max(problem.arm_means))
    lo, hi = problem.reward_range
    num_diag = 6 if config.diagnostics else 0
    a_star = int(np.argmax(problem.arm_means))  # the paper's a* (first of ties)
    table = (problem.contexts if config.diagnostics and problem.contexts is not None
             else np.zeros((0, d)))
    num_table = table.shape[0]
    table_x = jnp.asarray(table, jnp.float32)  # [M, d]
    predict = learner.predict or base.network_predict(model)
    core = _empty_core_set(problem)
    theta_shape = jax.eval_shape(model.init, jax.random.key(0))
    z_shape = jax.ShapeDtypeStruct((num_arms, d + num_arms), jnp.float32)
    out_shape = jax.eval_shape(model.apply, theta_shape, z_shape)  # raises if z cannot fit
    if out_shape.shape != (num_arms,):
        raise ValueError(f"the network maps a round's candidates [K, d + K] = "
                         f"{z_shape.shape} to shape {out_shape.shape}, not [K] = ({num_arms},)")
    state_shape = jax.eval_shape(learner.init, jax.random.key(0), theta_shape, core)
    if isinstance(state_shape.buffer, base.Buffer) and \
            state_shape.buffer.reward.shape[0] < config.horizon:
        raise ValueError(f"--horizon {config.horizon} exceeds the learner's buffer of "
                         f"{state_shape.buffer.reward.shape[0]} rows (TrainConfig.horizon)")
    eye = jnp.eye(num_arms, dtype=jnp.float32)

    def run(key: Key, params=None) -> NeuralRunOutput:
        if params is None:  # the problem's own values, closed over (constants)
            fns, mu_star_t = problem, mu_star
        else:  # traced: one program for every value
            if config.diagnostics:
                raise ValueError("diagnostics use the problem's own parameters: run(key) "
                                 "without params")
            fns = problem.bind(params)
            mu_star_t = fns.mu_star
        key_env = jax.random.fold_in(jax.random.fold_in(key, ENV_STREAM), ROUNDS_STREAM)
        key_agent = jax.random.fold_in(key, AGENT_STREAM)
        key_u = jax.random.fold_in(key_agent, ROUNDS_STREAM)
        key_act = jax.random.fold_in(key_agent, ACT_STREAM)
        key_update = jax.random.fold_in(key_agent, UPDATE_STREAM)
        key_init = jax.random.fold_in(key_agent, INIT_STREAM)
        theta0 = model.init(jax.random.fold_in(key, MODEL_STREAM))
        del key
        state0 = learner.init(key_init, theta0, core)

        def decide(state, t):
            """One decision at round t (0-based) on the phase's state."""
            key_t = jax.random.fold_in(key_env, t)
            x = fns.sample_context(jax.random.fold_in(key_t, 0))
            rewards = fns.sample_rewards(jax.random.fold_in(key_t, 1), x)  # [K]
            means = fns.expected_rewards(x)  # [K]
            z = jnp.concatenate([jnp.broadcast_to(x.astype(jnp.float32), (num_arms, d)), eye],
                                axis=1)
            obs = base.Obs(inputs=(z,), valid=jnp.ones((num_arms,), bool),
                           u=jax.random.uniform(jax.random.fold_in(key_u, t), (), jnp.float32),
                           t=t.astype(jnp.int32))
            action, probs, _ = learner.act(jax.random.fold_in(key_act, t), state, obs)
            a = jnp.maximum(action, 0)
            best = jnp.max(means)
            r_pi = jnp.dot(probs, means)
            increments = jnp.stack([best - means[a], mu_star_t - means[a], best - r_pi,
                                    mu_star_t - r_pi])
            if config.diagnostics:
                scaled = problem.scale_reward(means)
                err = jnp.abs(predict(state, obs) - scaled)
                diag = (err[a], err[jnp.argmax(means)], jnp.dot(probs, err))
            else:
                diag = ()
            reward = problem.scale_reward(rewards[a])
            if num_table:
                ctx = jnp.argmin(jnp.sum(jnp.abs(table_x - x[None, :]), axis=1))
            else:
                ctx = jnp.zeros((), jnp.int32)
            return z[a], action, reward, probs, increments, diag, ctx

        def phase(p, carry: _Carry) -> _Carry:
            ts = p * e + jnp.arange(e)
            z, action, reward, probs, inc, diag, ctx = jax.vmap(decide, (None, 0))(
                carry.state, ts)
            batch = base.Batch(inputs=(z,), action=action.astype(jnp.int32), reward=reward)
            state = learner.update(jax.random.fold_in(key_update, p), carry.state, batch)
            sums, sums_err = kahan_add(carry.sums, carry.sums_err, jnp.sum(inc, axis=0))
            comp, comp_err = kahan_add(carry.comp, carry.comp_err, jnp.sum(probs, axis=0))
            chosen = jax.nn.one_hot(action, num_arms, dtype=jnp.int32)  # NO_ARM: zeros
            new_diag = carry.diag
            if config.diagnostics:
                inv_sqrt = 1.0 / jnp.sqrt(carry.counts.astype(jnp.float32) + 1.0)
                if num_table:  # â* of the state that acted in this phase
                    r_hat = table_predictions(carry.state)  # [M, K]
                    misid = (jnp.argmax(jnp.mean(r_hat, axis=0)) != a_star).astype(jnp.float32)
                else:
                    misid = jnp.zeros((), jnp.float32)
                new_diag = carry.diag + jnp.stack([
                    jnp.sum(diag[0]), jnp.sum(diag[1]), jnp.sum(diag[2]),
                    jnp.sum(inv_sqrt[jnp.maximum(action, 0)]), e * inv_sqrt[a_star],
                    e * misid])
            table_counts = carry.table_counts
            if num_table:
                table_counts = table_counts.at[ctx].add(chosen)
            return _Carry(state, sums, sums_err, carry.counts + jnp.sum(chosen, axis=0),
                          comp, comp_err, jnp.minimum(carry.min_prob, jnp.min(probs)),
                          new_diag, table_counts)

        def table_predictions(state):
            """r̂ [M, K] on every context of the table with ``state``."""
            def one(x):
                z = jnp.concatenate([jnp.broadcast_to(x, (num_arms, d)), eye], axis=1)
                obs = base.Obs(inputs=(z,), valid=jnp.ones((num_arms,), bool),
                               u=jnp.zeros((), jnp.float32), t=jnp.zeros((), jnp.int32))
                return predict(state, obs)
            return jax.vmap(one)(table_x)

        def table_errors(state):
            """|r̂ − r| [M, K] on every context (scaled units) with the current state."""
            truth = jax.vmap(lambda x: problem.scale_reward(fns.expected_rewards(x)))(table_x)
            return jnp.abs(table_predictions(state) - truth)

        def segment(carry: _Carry, bounds):
            lo_p, hi_p = bounds
            carry = jax.lax.fori_loop(lo_p, hi_p, phase, carry)
            errs = (table_errors(carry.state) if num_table
                    else jnp.zeros((0, num_arms), jnp.float32))
            return carry, (carry.sums - carry.sums_err, carry.counts,
                           carry.comp - carry.comp_err, carry.min_prob, carry.diag,
                           errs, carry.table_counts)

        carry0 = _Carry(state0, jnp.zeros((4,), jnp.float32), jnp.zeros((4,), jnp.float32),
                        jnp.zeros((num_arms,), jnp.int32), jnp.zeros((num_arms,), jnp.float32),
                        jnp.zeros((num_arms,), jnp.float32), jnp.ones((), jnp.float32),
                        jnp.zeros((num_diag,), jnp.float32),
                        jnp.zeros((num_table, num_arms), jnp.int32))
        _, (sums, counts, comp, min_prob, diag, errs, tcounts) = jax.lax.scan(
            segment, carry0, (jnp.asarray(starts), jnp.asarray(ends)))
        diag_out = (NeuralDiag(*[diag[:, i] for i in range(4)], errs, tcounts, diag[:, 4],
                               diag[:, 5]) if config.diagnostics else None)
        return NeuralRunOutput(regret=sums[:, 0], regret_paper=sums[:, 1],
                               regret_rb=sums[:, 2], regret_rb_paper=sums[:, 3],
                               counts=counts, compensator=comp, min_prob=min_prob,
                               diag=diag_out)

    del lo, hi
    return run


_JIT_CACHE: dict = {}


def _batched(run: Callable, traced: bool = False) -> Callable:
    """``jit(vmap(run))`` (``traced``: ``jit(vmap(run, (0, None)))`` over (keys, params)), one
    per ``run`` object (one compilation per call shape: a new value of the traced params
    reuses it)."""
    fn = _JIT_CACHE.get((id(run), traced))
    if fn is None or fn[0] is not run:
        fn = (run, jax.jit(jax.vmap(run, (0, None)) if traced else jax.vmap(run)))
        _JIT_CACHE[(id(run), traced)] = fn
    return fn[1]


def run_seeds(run: Callable[[Key], NeuralRunOutput], seed: int = 0, num_seeds: int = 100, *,
              first_seed: int = 0, chunk_size: int | None = None, workers: int | None = None,
              progress: Callable[[int], None] | None = None,
              params=None) -> NeuralRunOutput:
    """Runs seeds ``first_seed … first_seed + num_seeds − 1`` of ``run`` (from
    :func:`make_run`); numpy outputs with a leading [S] axis.

    Every call has ``chunk_size`` seeds (the last one padded), so any ``num_seeds`` shares
    one compilation; seed i uses ``fold_in(key(seed), i)`` whatever the chunking. Calls run
    ``workers`` at a time from host threads (default 1: one call at a time, which XLA
    parallelises inside; see :func:`sern_jax.engine.plan.plan_neural`), through the tabular
    engine's seed driver (:func:`sern_jax.engine.drive.run_plan`).

    ``params``: the problem's traced parameters (e.g. ``WheelParams(δ)``), passed to every
    call as an argument of the compiled program, so other values reuse the compilation;
    None: ``run(key)`` with the problem's own values.
    """
    plan = plan_lib.plan_neural(_batched(run, params is not None), num_seeds,
                                first_seed=first_seed, chunk_size=chunk_size,
                                workers=workers, params=params)
    return drive.run_plan(plan, seed, progress)
