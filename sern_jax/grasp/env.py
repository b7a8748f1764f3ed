"""The grasp contextual bandit as a gymnax-style functional environment.

``reset(key, params) -> (obs, state)`` draws a context (one resting pose of the object: its
64 candidates' crops and validity); ``step(key, state, action, params) -> (reward, state)``
draws the grasp's outcome. Both are pure JAX, unbatched, jittable and vmappable, so users
plug in their own agents and run thousands of them at once, like any JAX environment.

Physics does not run inside ``step``: a MuJoCo rollout cannot be traced on a CPU. The
environment's params tabulate the simulator instead. :func:`make_params` simulates a pool
of contexts (``context.make_contexts``) and estimates every valid candidate's success
probability from ``num_trials`` randomised trials (``GraspSimulator.success_probability``);
``step`` then draws Bernoulli(p̂). The table is also the oracle a regret computation needs
(:func:`expected_reward`, :func:`best_reward`). For outcomes from live physics, use
:func:`runner.run` (native MuJoCo or MJX trials per grasp).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.grasp import context as context_lib
from sern_jax.grasp import crops as crops_lib
from sern_jax.grasp import objects as objects_lib
from sern_jax.grasp import sim as sim_lib
from sern_jax.policies import NO_ARM
from sern_jax.types import Array, Key

__all__ = ["GraspEnvParams", "GraspObs", "GraspState", "GraspEnv", "make_params",
           "expected_reward", "best_reward"]


class GraspEnvParams(NamedTuple):
    """A pool of C contexts of one object (K = 64 candidate slots)."""

    image: Array  # [C, K, S, S] crops (depth - grasp depth), metres
    depth: Array  # [C, K] grasp depths, metres
    valid: Array  # [C, K] bool
    success_prob: Array  # [C, K] simulated success frequency (0 for invalid slots)
    grasps: Array  # [C, K, 4] (x, y, z, θ), world frame


class GraspObs(NamedTuple):
    """What an agent sees in one round."""

    image: Array  # [K, S, S]
    depth: Array  # [K]
    valid: Array  # [K] bool


class GraspState(NamedTuple):
    context: Array  # [] int32 index into the pool


class GraspEnv:
    """Pure ``reset``/``step`` over a :class:`GraspEnvParams` pool (``types.Environment``)."""

    def reset(self, key: Key, params: GraspEnvParams) -> tuple[GraspObs, GraspState]:
        """Draws a context uniformly from the pool; ``key`` is consumed."""
        c = jax.random.randint(key, (), 0, params.valid.shape[0])
        obs = GraspObs(params.image[c], params.depth[c], params.valid[c])
        return obs, GraspState(c.astype(jnp.int32))

    def step(self, key: Key, state: GraspState, action: Array, params: GraspEnvParams):
        """The outcome of grasp ``action`` (0/1, float32); an invalid slot or ``NO_ARM``
        earns 0. The state is unchanged (one grasp per context, as in the paper)."""
        p = expected_reward(state, action, params)
        reward = (jax.random.uniform(key) < p).astype(jnp.float32)
        return reward, state


def expected_reward(state: GraspState, action: Array, params: GraspEnvParams) -> Array:
    """r_a(s): the tabulated success probability of ``action`` (0 if invalid / NO_ARM)."""
    num_k = params.valid.shape[1]
    a = jnp.clip(action, 0, num_k - 1)
    ok = (action != NO_ARM) & (action >= 0) & (action < num_k) & params.valid[state.context, a]
    return jnp.where(ok, params.success_prob[state.context, a], 0.0)


def best_reward(state: GraspState, params: GraspEnvParams) -> Array:
    """max_a r_a(s) over the valid candidates of the context."""
    p = jnp.where(params.valid[state.context], params.success_prob[state.context], 0.0)
    return jnp.max(p)


def make_params(
    key: Key,
    spec: objects_lib.ObjectSpec,
    num_contexts: int,
    num_trials: int = 16,
    config: context_lib.ContextConfig = context_lib.ContextConfig(),
    backend: str = "native",
) -> GraspEnvParams:
    """Simulates a pool of contexts and tabulates every candidate's success probability.

    Args:
      key: consumed; contexts use ``fold_in(key, 0)``, trials ``fold_in(key, 1 + c)``.
      spec: the object.
      num_contexts: C resting poses.
      num_trials: randomised trials per valid candidate (the table's resolution is 1/M).
      config: context settings.
      backend: simulator backend.

    Returns:
      GraspEnvParams with jnp arrays.
    """
    if num_contexts < 1 or num_trials < 1:
        raise ValueError(f"num_contexts and num_trials must be >= 1, got {num_contexts}, "
                         f"{num_trials}")
    ctx = context_lib.make_contexts(jax.random.fold_in(key, 0), spec, num_contexts, config)
    simulator = sim_lib.GraspSimulator(ctx.model, backend=backend)
    cands = ctx.candidates
    probs = np.zeros(np.shape(cands.valid), np.float32)
    for c in range(num_contexts):
        est = simulator.success_probability(
            jax.random.fold_in(key, 1 + c), cands.grasps[c], num_trials,
            valid=cands.valid[c], object_pose=ctx.poses[c])
        probs[c] = est.prob
    crops = crops_lib.extract_batch(jnp.asarray(ctx.depth), cands)
    return GraspEnvParams(image=crops.image, depth=crops.depth,
                          valid=jnp.asarray(cands.valid), success_prob=jnp.asarray(probs),
                          grasps=jnp.asarray(cands.grasps))
