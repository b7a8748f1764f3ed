"""Shared types: array aliases, the ``Network(init, apply)`` pair and the environment protocol.

Legend for shapes in docstrings: ``S`` seeds, ``T`` horizon, ``G`` checkpoints, ``K`` arms
(grasp candidates), ``M`` contexts, ``H, W`` pixels, ``d`` features.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Protocol, runtime_checkable

import jax

Array = jax.Array
Key = jax.Array
Params = Any  # a pytree of arrays (network weights, environment parameters)


class Network(NamedTuple):
    """A network as a pure pair (brax style): ``params = init(key, x)``, ``y = apply(params, x)``.

    ``init(key, *inputs) -> params`` consumes ``key``; ``apply(params, *inputs) -> outputs`` is
    pure, so ``jax.vmap`` over ``params`` gives independent copies (one per seed / policy).
    """

    init: Callable[..., Params]
    apply: Callable[..., Any]


@runtime_checkable
class Environment(Protocol):
    """A contextual bandit as a gymnax-style pure environment.

    ``reset(key, params) -> (obs, state)`` draws a context; ``step(key, state, action, params)
    -> (reward, state)`` draws the reward of ``action`` in that context. Both are pure and
    unbatched (vmap at the call site); ``key`` is consumed. ``isinstance(env, Environment)``
    checks that the two methods exist. Implementations: ``bandit_env.BanditEnv`` (params = a
    ``problems.Problem``: K-armed and finite-context Bernoulli bandits, no MuJoCo).
    """

    def reset(self, key: Key, params: Params) -> tuple[Any, Any]: ...

    def step(self, key: Key, state: Any, action: Array, params: Params) -> tuple[Array, Any]: ...


__all__ = ["Array", "Key", "Params", "Network", "Environment"]
