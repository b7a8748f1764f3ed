"""The K-armed and finite-context Bernoulli problems as a gymnax-style environment.

:class:`BanditEnv` implements :class:`sern_jax.core.types.Environment` with ``params`` = a
:class:`sern_jax.core.problems.Problem`, so an online learner written against the protocol can be
tested on a bandit with known means, without MuJoCo::

    env = BanditEnv()
    obs, state = env.reset(key_ctx, problem)              # obs: [] int32 context s_t
    reward, state = env.step(key_rew, state, arm, problem)  # reward ~ Bernoulli(r_arm(s_t))

Both functions are pure and unbatched (``jax.vmap`` over keys, states or problems); ``key`` is
consumed. Contexts are i.i.d., so each round is one ``reset`` (draw s_t) and one ``step``
(pull an arm); ``step`` returns the state unchanged. A K-armed bandit is the one-context case
(``obs`` is always 0). The draws follow the engine's convention (``simulate``): one uniform
through the context CDF for ``s_t``, and ``reward = 1{u < r_a(s_t)}``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from sern_jax.core.problems import Problem
from sern_jax.core.types import Array, Key

__all__ = ["BanditState", "BanditEnv"]


class BanditState(NamedTuple):
    """The environment's state between ``reset`` and ``step``."""

    context: Array  # [] int32 index s_t of the current context, in [0, M)


class BanditEnv:
    """A finite-context Bernoulli bandit (``params``: :class:`Problem`), gymnax style.

    Stateless: the instance holds nothing, every value lives in ``params`` and the state.
    """

    def reset(self, key: Key, params: Problem) -> tuple[Array, BanditState]:
        """Draws the context ``s_t ~ params.context_probs``.

        Args:
          key: PRNG key, consumed.
          params: the problem (means [M, K], context_probs [M]).

        Returns:
          ``(obs, state)``: obs [] int32 context index (what a tabular learner sees), and the
          :class:`BanditState`.
        """
        num_contexts = params.context_probs.shape[-1]
        if num_contexts == 1:
            context = jnp.zeros((), jnp.int32)
        else:
            cdf = jnp.cumsum(params.context_probs)
            u = jax.random.uniform(key, (), cdf.dtype)
            context = jnp.minimum(jnp.sum(cdf <= u * cdf[-1]), num_contexts - 1)
            context = context.astype(jnp.int32)
        return context, BanditState(context=context)

    def step(self, key: Key, state: BanditState, action: Array,
             params: Problem) -> tuple[Array, BanditState]:
        """Pulls ``action`` in the current context.

        Args:
          key: PRNG key, consumed.
          state: from :meth:`reset`.
          action: [] int arm index. An index outside ``[0, K)`` (e.g.
            :data:`sern_jax.core.policies.NO_ARM` = -1, what the sampler returns when no arm is
            valid) is "no pull" and earns reward 0.
          params: the problem.

        Returns:
          ``(reward, state)``: reward [] in {0, 1} (dtype of ``params.means``), ``state``
          unchanged.
        """
        mean = self.expected_reward(state, action, params)
        u = jax.random.uniform(key, (), mean.dtype)
        return (u < mean).astype(mean.dtype), state

    def expected_reward(self, state: BanditState, action: Array, params: Problem) -> Array:
        """``r_action(s_t)``, the mean reward of ``action`` in the current context ([]); 0 for
        an index outside ``[0, K)``. For regret accounting in tests."""
        means_row = params.means[state.context]  # [K]
        num_arms = means_row.shape[-1]
        action = jnp.asarray(action)
        pulled = (action >= 0) & (action < num_arms)
        return jnp.where(pulled, means_row[jnp.clip(action, 0, num_arms - 1)], 0.0)

    @staticmethod
    def num_arms(params: Problem) -> int:
        """K (static: from the shape)."""
        return params.means.shape[-1]

    @staticmethod
    def num_contexts(params: Problem) -> int:
        """M (static: from the shape)."""
        return params.means.shape[-2]
