"""Bandit policies as unbatched pure functions (vmap at the call site).

Every policy maps what it knows this round to an action distribution ``π`` over ``K`` arms.
SERN's policy is the maximiser of ``E_π[r̂] + α S(π)`` (Algorithm 1), i.e. the textbook
softmax ``π = softmax(r̂ / α)``; unlike several peer libraries (see README) nothing else is
mixed in. *Index policies* (Thompson sampling, Boltzmann-Gumbel) draw a random index per arm
and play its argmax; their ``π`` is not available in closed form, so they return the one-hot
vector of the arm they chose, an unbiased one-sample estimate of ``π``.

Sampling uses the inverse CDF with a single uniform per round (:func:`sample_icdf`). Gumbel-max
in float32 can essentially never pick an arm whose logit gap exceeds ~20 (DESIGN.md).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from sern_jax.types import Array, Key

__all__ = [
    "POLICY_NAMES",
    "INDEX_POLICIES",
    "PolicyInputs",
    "softmax_probs",
    "greedy_probs",
    "epsilon_greedy_probs",
    "ucb1_probs",
    "thompson_probs",
    "boltzmann_gumbel_probs",
    "exp3_probs",
    "entropy",
    "sample_icdf",
    "policy_probs",
]

POLICY_NAMES = (
    "softmax",
    "greedy",
    "epsilon_greedy",
    "ucb1",
    "thompson",
    "boltzmann_gumbel",
    "exp3",
)
INDEX_POLICIES = ("thompson", "boltzmann_gumbel")


class PolicyInputs(NamedTuple):
    """What a policy may look at in one round (one context row)."""

    r_hat: Array  # [K] reward estimates r̂_a(s_t)
    counts: Array  # [K] pulls of each arm in this context
    sums: Array  # [K] summed rewards of each arm in this context
    gains: Array  # [K] EXP3 importance-weighted cumulative reward estimates
    t: Array  # [] round number, starting at 1


def softmax_probs(r_hat: Array, alpha: Array) -> Array:
    """SERN's policy: ``softmax(r̂ / α)``, the argmax of ``E_π r̂ + α S(π)``.

    Args:
      r_hat: [K] reward estimates.
      alpha: [] temperature α > 0.

    Returns:
      [K] probabilities. The max is subtracted first, so tiny α gives no NaN or inf.
    """
    # Subtract the max *before* dividing: (r̂ − max r̂)/α ≤ 0, so even α = 1e-30 gives exp(−inf)
    # = 0 for the others and exactly 1 at the max, never inf − inf.
    w = jnp.exp((r_hat - jnp.max(r_hat)) / alpha)
    return w / jnp.sum(w)


def greedy_probs(r_hat: Array) -> Array:
    """Uniform over the arms attaining ``max r̂`` (ties broken uniformly, not to arm 0).

    Args:
      r_hat: [K] reward estimates.

    Returns:
      [K] probabilities.
    """
    is_max = (r_hat >= jnp.max(r_hat)).astype(r_hat.dtype)
    return is_max / jnp.sum(is_max)


def epsilon_greedy_probs(r_hat: Array, epsilon: Array) -> Array:
    """``(1 − ε)`` greedy (uniform over ties) plus ``ε`` uniform over all arms.

    Args:
      r_hat: [K] reward estimates.
      epsilon: [] exploration probability in [0, 1].

    Returns:
      [K] probabilities.
    """
    num_arms = r_hat.shape[-1]
    return (1.0 - epsilon) * greedy_probs(r_hat) + epsilon / num_arms


def ucb1_probs(r_hat: Array, counts: Array, t: Array, c: Array) -> Array:
    """UCB1 (Auer et al. 2002): greedy on ``r̂_a + c·sqrt(2 ln t / n_a)``; unpulled arms first.

    Args:
      r_hat: [K] reward estimates (the engine passes the chosen estimator's r̂).
      counts: [K] pulls per arm.
      t: [] round number ≥ 1.
      c: [] bonus multiplier (1 is UCB1).

    Returns:
      [K] probabilities (uniform over the maximisers).
    """
    n = counts.astype(r_hat.dtype)
    bonus = c * jnp.sqrt(2.0 * jnp.log(jnp.maximum(t, 1).astype(r_hat.dtype)) / jnp.maximum(n, 1.0))
    index = jnp.where(n > 0, r_hat + bonus, jnp.inf)
    return greedy_probs(index)


def thompson_probs(key: Key, counts: Array, sums: Array) -> Array:
    """Beta-Bernoulli Thompson sampling with a uniform Beta(1, 1) prior.

    Args:
      key: PRNG key, consumed.
      counts: [K] pulls per arm.
      sums: [K] summed (Bernoulli) rewards per arm.

    Returns:
      [K] one-hot of ``argmax_a θ_a`` with ``θ_a ~ Beta(1 + S_a, 1 + n_a − S_a)``.
    """
    a = 1.0 + sums
    b = 1.0 + counts.astype(sums.dtype) - sums
    theta = jax.random.beta(key, a, b, dtype=sums.dtype)
    return jax.nn.one_hot(jnp.argmax(theta), counts.shape[-1], dtype=sums.dtype)


def boltzmann_gumbel_probs(key: Key, r_hat: Array, counts: Array, c: Array) -> Array:
    """Boltzmann-Gumbel exploration (Cesa-Bianchi, Gentile, Lugosi, Neu 2017).

    Plays ``argmax_a r̂_a + β_a Z_a`` with ``Z_a`` i.i.d. standard Gumbel and
    ``β_a = c / sqrt(n_a)``; arms never pulled are played first (uniformly).

    Args:
      key: PRNG key, consumed.
      r_hat: [K] reward estimates.
      counts: [K] pulls per arm.
      c: [] exploration constant C > 0.

    Returns:
      [K] one-hot of the chosen arm, or uniform over the unpulled arms.
    """
    n = counts.astype(r_hat.dtype)
    z = jax.random.gumbel(key, r_hat.shape, dtype=r_hat.dtype)
    index = r_hat + c / jnp.sqrt(jnp.maximum(n, 1.0)) * z
    unpulled = n <= 0
    onehot = jax.nn.one_hot(jnp.argmax(index), r_hat.shape[-1], dtype=r_hat.dtype)
    return jnp.where(jnp.any(unpulled), greedy_probs(unpulled.astype(r_hat.dtype)), onehot)


def exp3_probs(gains: Array, gamma: Array) -> Array:
    """EXP3 (Auer et al. 2002): ``(1 − γ) softmax(γ G / K) + γ / K``.

    Args:
      gains: [K] importance-weighted cumulative reward estimates ``G_a = Σ 1{a_t=a} R_t / π_t(a)``.
      gamma: [] exploration rate in (0, 1].

    Returns:
      [K] probabilities.
    """
    num_arms = gains.shape[-1]
    return (1.0 - gamma) * softmax_probs(gains, num_arms / gamma) + gamma / num_arms


def entropy(probs: Array) -> Array:
    """Shannon entropy ``S(π) = −Σ π ln π`` (0 ln 0 = 0). [K] -> []."""
    return -jnp.sum(jnp.where(probs > 0, probs * jnp.log(jnp.where(probs > 0, probs, 1.0)), 0.0))


def sample_icdf(u: Array, probs: Array) -> Array:
    """Inverse-CDF sampling with one uniform.

    Args:
      u: [] uniform in [0, 1).
      probs: [K] non-negative weights (need not be normalised).

    Returns:
      [] int32 arm index ``a`` with ``P(a) = probs[a] / Σ probs``. An arm of zero weight is
      never returned.
    """
    cdf = jnp.cumsum(probs)
    arm = jnp.sum(cdf <= u * cdf[-1]).astype(jnp.int32)
    return jnp.minimum(arm, probs.shape[-1] - 1)


def policy_probs(name: str, key: Key, inputs: PolicyInputs, alpha: Array, params) -> Array:
    """Dispatches on the (static) policy name.

    Args:
      name: one of :data:`POLICY_NAMES`.
      key: PRNG key, consumed by the index policies.
      inputs: this round's :class:`PolicyInputs`.
      alpha: [] SERN temperature at this round.
      params: an object with scalar fields ``epsilon``, ``ucb_c``, ``bgc_c``, ``exp3_gamma``.

    Returns:
      [K] action distribution π_t.
    """
    if name == "softmax":
        return softmax_probs(inputs.r_hat, alpha)
    if name == "greedy":
        return greedy_probs(inputs.r_hat)
    if name == "epsilon_greedy":
        return epsilon_greedy_probs(inputs.r_hat, params.epsilon)
    if name == "ucb1":
        return ucb1_probs(inputs.r_hat, inputs.counts, inputs.t, params.ucb_c)
    if name == "thompson":
        return thompson_probs(key, inputs.counts, inputs.sums)
    if name == "boltzmann_gumbel":
        return boltzmann_gumbel_probs(key, inputs.r_hat, inputs.counts, params.bgc_c)
    if name == "exp3":
        return exp3_probs(inputs.gains, params.exp3_gamma)
    raise ValueError(f"unknown policy {name!r}; choose one of {POLICY_NAMES}")
