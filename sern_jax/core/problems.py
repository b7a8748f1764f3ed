"""Bandit problems: Bernoulli K-armed, and finite-context contextual bandits.

A problem is a :class:`Problem` pytree of traced arrays, so problems can vary across a vmapped
batch without recompiling. A K-armed bandit is the special case of one context.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core.types import Array, Key

__all__ = [
    "Problem",
    "bernoulli",
    "contextual",
    "random_bernoulli",
    "contextual_with_gap",
    "best_arm",
    "mean_rewards",
    "gap2",
    "validate_problem",
]


class Problem(NamedTuple):
    """A finite-context Bernoulli bandit with i.i.d. contexts."""

    means: Array  # [M, K] r_a(s): success probability of arm a in context s
    context_probs: Array  # [M] distribution of the i.i.d. contexts s_t


def bernoulli(means, dtype=jnp.float32) -> Problem:
    """K-armed Bernoulli bandit (one context).

    Args:
      means: [K] success probabilities in [0, 1].
      dtype: float dtype of the arrays.

    Returns:
      A :class:`Problem` with ``means`` [1, K] and ``context_probs`` [1].
    """
    m = np.asarray(means, dtype=np.float64)
    if m.ndim != 1:
        raise ValueError(f"bernoulli() needs means of shape [K], got shape {m.shape}")
    return contextual(m[None, :], None, dtype=dtype)


def contextual(means, context_probs=None, dtype=jnp.float32) -> Problem:
    """Finite-context contextual bandit.

    Args:
      means: [M, K] success probabilities in [0, 1].
      context_probs: [M] context distribution (uniform when None).
      dtype: float dtype of the arrays.

    Returns:
      A validated :class:`Problem`.
    """
    m = np.asarray(means, dtype=np.float64)
    if m.ndim != 2:
        raise ValueError(f"contextual() needs means of shape [M, K], got shape {m.shape}")
    if context_probs is None:
        q = np.full(m.shape[0], 1.0 / m.shape[0])
    else:
        q = np.asarray(context_probs, dtype=np.float64)
    problem = Problem(jnp.asarray(m, dtype=dtype), jnp.asarray(q, dtype=dtype))
    validate_problem(problem)
    return problem


def random_bernoulli(key: Key, num_arms: int, dtype=jnp.float32) -> Problem:
    """K-armed Bernoulli bandit with means drawn i.i.d. from U[0, 1].

    Args:
      key: PRNG key, consumed.
      num_arms: K.
      dtype: float dtype.

    Returns:
      A :class:`Problem` with one context.
    """
    means = jax.random.uniform(key, (1, num_arms), dtype=dtype)
    return Problem(means, jnp.ones((1,), dtype=dtype))


def contextual_with_gap(
    key: Key, num_contexts: int, num_arms: int, gap: float, dtype=jnp.float32
) -> Problem:
    """Random contextual bandit whose Assumption-1 gap Δ2 equals ``gap`` exactly.

    In every context the best arm (a random one) has mean ``b ~ U[gap, 1]``, one other arm has
    ``b − gap`` and the rest lie uniformly in ``[0, b − gap]``. So ``min_s Δ2(s) = gap``.

    Args:
      key: PRNG key, consumed.
      num_contexts: M.
      num_arms: K ≥ 2.
      gap: Δ2 in (0, 1).
      dtype: float dtype.

    Returns:
      A :class:`Problem` with uniform context probabilities.
    """
    if not 0.0 < float(gap) < 1.0:  # also refuses NaN
        raise ValueError(f"gap must lie in (0, 1), got {float(gap)!r}")
    key_best, key_rest, key_perm = jax.random.split(key, 3)
    best = jax.random.uniform(key_best, (num_contexts, 1), dtype, minval=gap, maxval=1.0)
    rest = jax.random.uniform(key_rest, (num_contexts, num_arms - 2), dtype) * (best - gap)
    row = jnp.concatenate([best, best - gap, rest], axis=1)  # [M, K], arm 0 best
    perm_keys = jax.random.split(key_perm, num_contexts)
    means = jax.vmap(jax.random.permutation)(perm_keys, row)
    return Problem(means, jnp.full((num_contexts,), 1.0 / num_contexts, dtype))


def mean_rewards(problem: Problem) -> Array:
    """``E_s r_a(s)`` for every arm. Returns [K]."""
    return problem.context_probs @ problem.means


def best_arm(problem: Problem) -> Array:
    """The paper's best arm ``a* = argmax_a E_s r_a(s)``. Returns [] int32."""
    return jnp.argmax(mean_rewards(problem)).astype(jnp.int32)


def gap2(problem: Problem) -> Array:
    """Assumption 1's ``Δ2 = min_s (max_a r_a(s) − second max_a r_a(s))``. Returns []."""
    top2 = jax.lax.top_k(problem.means, 2)[0]
    return jnp.min(top2[:, 0] - top2[:, 1])


def validate_problem(problem: Problem, num_arms: int | None = None,
                     num_contexts: int | None = None) -> None:
    """Host-side checks; raises ``ValueError`` naming the bad value."""
    means = np.asarray(problem.means, dtype=np.float64)
    probs = np.asarray(problem.context_probs, dtype=np.float64)
    if means.ndim != 2:
        raise ValueError(f"problem.means must have shape [M, K], got {means.shape}")
    m, k = means.shape
    if k < 2:
        raise ValueError(f"a bandit needs K >= 2 arms, got K={k}")
    if num_arms is not None and k != num_arms:
        raise ValueError(f"problem has K={k} arms but the config says num_arms={num_arms}")
    if num_contexts is not None and m != num_contexts:
        raise ValueError(
            f"problem has M={m} contexts but the config says num_contexts={num_contexts}"
        )
    if np.any(np.isnan(means)):
        bad = np.argwhere(np.isnan(means))[0]
        raise ValueError(f"problem.means contains NaN (first at context {bad[0]}, arm {bad[1]})")
    if np.any((means < 0) | (means > 1)):
        bad = np.argwhere((means < 0) | (means > 1))[0]
        raise ValueError(
            f"problem.means must lie in [0, 1]; means[{bad[0]}, {bad[1]}] = "
            f"{means[bad[0], bad[1]]!r}"
        )
    if probs.shape != (m,):
        raise ValueError(f"context_probs must have shape [{m}], got {probs.shape}")
    if np.any(~np.isfinite(probs)) or np.any(probs < 0) or abs(probs.sum() - 1.0) > 1e-5:
        raise ValueError(f"context_probs must be a probability vector, got {probs!r}")
