"""Bandit policies as unbatched pure functions (vmap at the call site).

Every policy maps what it knows this round to an action distribution ``π`` over ``K`` arms.
SERN's policy is the maximiser of ``E_π[r̂] + α S(π)`` (Algorithm 1), i.e. the textbook
softmax ``π = softmax(r̂ / α)``; unlike several peer libraries, nothing else is
mixed in. *Index policies* (Thompson sampling, Boltzmann-Gumbel) draw a random index per arm
and play its argmax; their ``π`` is not available in closed form, so they return the one-hot
vector of the arm they chose, an unbiased one-sample estimate of ``π``.

Sampling uses the inverse CDF with a single uniform per round (:func:`sample_icdf`). Gumbel-max
in float32 can essentially never pick an arm whose logit gap exceeds ~20 (DESIGN.md).

**Validity masks.** :func:`softmax_probs`, :func:`greedy_probs`, :func:`epsilon_greedy_probs`,
:func:`ucb1_probs`, :func:`policy_probs` and :func:`sample_icdf` take an optional ``mask``
(bool, the estimates' shape ``[K]``; ``None`` = every arm valid, and then the results are
bit-identical to the unmasked code). An invalid arm gets probability exactly 0 and is never
sampled, and whatever its estimate holds (NaN, ±inf, garbage from a padded slot) is ignored;
on the valid arms each policy equals the unmasked policy applied to the valid sub-vector.
*Nothing valid* is defined, not NaN: the policies return all-zero probabilities and
:func:`sample_icdf` returns :data:`NO_ARM` (= -1). Callers outside ``jit`` should reject such
masks up front with :func:`check_mask`, which raises a ``ValueError`` naming the bad row.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import prng
from sern_jax.core.types import Array, Key

__all__ = [
    "POLICY_NAMES",
    "INDEX_POLICIES",
    "MASKABLE_POLICIES",
    "NO_ARM",
    "check_mask",
    "PolicyInputs",
    "softmax_probs",
    "greedy_probs",
    "epsilon_greedy_probs",
    "normalized_probs",
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
MASKABLE_POLICIES = ("softmax", "greedy", "epsilon_greedy", "ucb1")  # accept ``mask``

NO_ARM = -1  # what sample_icdf returns when no arm has positive weight (nothing valid)


class PolicyInputs(NamedTuple):
    """What a policy may look at in one round (one context row)."""

    r_hat: Array  # [K] reward estimates r̂_a(s_t)
    counts: Array  # [K] pulls of each arm in this context
    sums: Array  # [K] summed rewards of each arm in this context
    gains: Array  # [K] EXP3 importance-weighted cumulative reward estimates
    t: Array  # [] round number, starting at 1


def softmax_probs(r_hat: Array, alpha: Array, mask: Array | None = None) -> Array:
    """SERN's policy: ``softmax(r̂ / α)``, the argmax of ``E_π r̂ + α S(π)``.

    Args:
      r_hat: [K] reward estimates.
      alpha: [] temperature α > 0.
      mask: [K] bool validity (None: all valid). Invalid arms get probability 0 and their
        estimates are ignored; the valid arms get ``softmax(r̂[mask] / α)``.

    Returns:
      [K] probabilities. The max is subtracted first, so tiny α gives no NaN or inf. If the
      largest valid estimate is not finite (every valid estimate is -inf, or some are +inf) the
      limit is returned: uniform over the valid arms attaining it, i.e. :func:`greedy_probs`.
      With no valid arm: all zeros.
    """
    if mask is not None:
        r_hat = jnp.where(mask, r_hat, -jnp.inf)
    top = jnp.max(r_hat)
    # A non-finite max (every valid estimate -inf, nothing valid, or some +inf) would give
    # -inf - -inf or inf - inf = NaN below: replace the estimates by the limit as α -> 0 of the
    # ties, 0 at the (valid) arms attaining the max and -inf elsewhere, and shift by 0.
    finite = jnp.isfinite(top)
    ties = r_hat == top
    if mask is not None:
        ties = ties & mask
    r_hat = jnp.where(finite, r_hat, jnp.where(ties, 0.0, -jnp.inf))
    # Subtract the max *before* dividing: (r̂ − max r̂)/α ≤ 0, so even α = 1e-30 gives exp(−inf)
    # = 0 for the others and exactly 1 at the max, never inf − inf.
    w = jnp.exp((r_hat - jnp.where(finite, top, 0.0)) / alpha)
    if mask is None:
        return w / jnp.sum(w)  # Σw ≥ 1 (the max's term is 1); bit-identical to the old graph
    total = jnp.sum(w)  # 0 only when no arm is valid
    return w / jnp.where(total > 0, total, 1.0)


def greedy_probs(r_hat: Array, mask: Array | None = None) -> Array:
    """Uniform over the arms attaining ``max r̂`` (ties broken uniformly, not to arm 0).

    Args:
      r_hat: [K] reward estimates.
      mask: [K] bool validity (None: all valid). Uniform over the valid maximisers; invalid
        arms get 0 whatever their estimate.

    Returns:
      [K] probabilities; all zeros when no arm is valid.
    """
    if mask is None:
        is_max = (r_hat >= jnp.max(r_hat)).astype(r_hat.dtype)
        return is_max / jnp.sum(is_max)
    r_hat = jnp.where(mask, r_hat, -jnp.inf)
    is_max = ((r_hat >= jnp.max(r_hat)) & mask).astype(r_hat.dtype)
    total = jnp.sum(is_max)
    return is_max / jnp.where(total > 0, total, 1.0)


def epsilon_greedy_probs(r_hat: Array, epsilon: Array, mask: Array | None = None) -> Array:
    """``(1 − ε)`` greedy (uniform over ties) plus ``ε`` uniform over all (valid) arms.

    Args:
      r_hat: [K] reward estimates.
      epsilon: [] exploration probability in [0, 1].
      mask: [K] bool validity (None: all valid). Both the greedy part and the ``ε`` part are
        spread over the valid arms only.

    Returns:
      [K] probabilities; all zeros when no arm is valid.
    """
    if mask is None:
        num_arms = r_hat.shape[-1]
        return (1.0 - epsilon) * greedy_probs(r_hat) + epsilon / num_arms
    valid = mask.astype(r_hat.dtype)
    num_valid = jnp.sum(valid)
    explore = valid / jnp.where(num_valid > 0, num_valid, 1.0)
    return (1.0 - epsilon) * greedy_probs(r_hat, mask) + epsilon * explore


def normalized_probs(r_hat: Array, mask: Array | None = None) -> Array:
    """"Normalized probability" exploration: ``π(a) = r̂_a / Σ_b r̂_b`` over the (valid) arms.

    The exploration the SERN paper cites as [13] (Berscheid, Rühr, Kröger 2019): each grasp
    is tried with probability proportional to its estimated success probability. The
    estimates must be success probabilities (r̂ ≥ 0); a negative or NaN estimate counts as 0.

    Args:
      r_hat: [K] reward estimates, ≥ 0.
      mask: [K] bool validity (None: all valid). Invalid arms get 0 whatever their estimate.

    Returns:
      [K] probabilities. If some valid estimate is +inf, uniform over those (the limit); if
      every valid estimate is 0, uniform over the valid arms; all zeros when none is valid.
    """
    valid = jnp.ones(r_hat.shape, bool) if mask is None else mask
    inf = valid & (r_hat == jnp.inf)
    w = jnp.where(valid & jnp.isfinite(r_hat) & (r_hat > 0), r_hat, 0.0)
    w = jnp.where(jnp.any(inf), inf.astype(r_hat.dtype), w)
    total = jnp.sum(w)
    w = jnp.where(total > 0, w, valid.astype(r_hat.dtype))
    total = jnp.sum(w)  # 0 only when no arm is valid
    return w / jnp.where(total > 0, total, 1.0)


def ucb1_probs(r_hat: Array, counts: Array, t: Array, c: Array,
               mask: Array | None = None) -> Array:
    """UCB1 (Auer et al. 2002): greedy on ``r̂_a + c·sqrt(2 ln t / n_a)``; unpulled arms first.

    Args:
      r_hat: [K] reward estimates (the engine passes the chosen estimator's r̂).
      counts: [K] pulls per arm.
      t: [] round number ≥ 1.
      c: [] bonus multiplier (1 is UCB1).
      mask: [K] bool validity (None: all valid); unpulled invalid arms are not played first.

    Returns:
      [K] probabilities (uniform over the (valid) maximisers; all zeros when none is valid).
    """
    n = counts.astype(r_hat.dtype)
    bonus = c * jnp.sqrt(2.0 * jnp.log(jnp.maximum(t, 1).astype(r_hat.dtype)) / jnp.maximum(n, 1.0))
    index = jnp.where(n > 0, r_hat + bonus, jnp.inf)
    return greedy_probs(index, mask)


def thompson_probs(key: Key, counts: Array, sums: Array) -> Array:
    """Beta-Bernoulli Thompson sampling with a uniform Beta(1, 1) prior.

    Args:
      key: PRNG key, consumed.
      counts: [K] pulls per arm.
      sums: [K] summed (Bernoulli) rewards per arm.

    Returns:
      [K] one-hot of ``argmax_a θ_a`` with ``θ_a ~ Beta(1 + S_a, 1 + n_a − S_a)``, drawn by
      :func:`sern_jax.core.prng.sample_beta` (exact; order statistics when a parameter is 1 or 2,
      Cheng's BB otherwise, rejected lanes retried alone; ``jax.random.beta``'s per-element
      rejection loop serialised the lanes under ``vmap``).
    """
    a = 1.0 + sums
    b = 1.0 + counts.astype(sums.dtype) - sums
    theta = prng.sample_beta(key, a, b)
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


def sample_icdf(u: Array, probs: Array, mask: Array | None = None) -> Array:
    """Inverse-CDF sampling with one uniform.

    Args:
      u: [] uniform in [0, 1).
      probs: [K] non-negative weights (need not be normalised).
      mask: [K] bool validity (None: all valid); invalid arms are treated as weight 0.

    Returns:
      [] int32 arm index ``a`` with ``P(a) = w[a] / Σ w``, ``w = where(mask, probs, 0)``. An
      arm of zero (or NaN) weight is never returned, for any ``u`` in [0, 1) and whatever the
      float rounding of the cumulative sum (a ``u`` that lands past the last positive arm's
      cdf gives that arm). When no arm has positive weight (nothing valid, all-zero or NaN
      ``probs``) it returns :data:`NO_ARM` = -1; note that ``x[-1]`` indexes the *last*
      element, so callers that may see an empty mask must test ``arm >= 0``.
    """
    # The first arm of positive weight whose cdf exceeds u·Σw. On a monotone cumsum this is
    # exactly #{a : cdf_a <= u·Σw}, the previous formula, so unmasked results are unchanged;
    # unlike a count it can never land on a zero-weight arm when rounding (a tree-ordered
    # cumsum on accelerators, u·Σw rounding up to Σw) makes the cdf flat or non-monotone.
    num_arms = probs.shape[-1]
    weights = probs if mask is None else jnp.where(mask, probs, 0.0)
    positive = weights > 0
    cdf = jnp.cumsum(weights)
    index = jnp.arange(num_arms, dtype=jnp.int32)
    first = jnp.min(jnp.where((cdf > u * cdf[-1]) & positive, index, num_arms))
    last = jnp.max(jnp.where(positive, index, NO_ARM))  # NO_ARM when nothing is positive
    return jnp.where(first < num_arms, first, last).astype(jnp.int32)


def check_mask(mask, num_arms: int | None = None) -> np.ndarray:
    """Host-side validation of a validity mask; call it outside ``jit``.

    The traced policies accept any mask (nothing valid gives all-zero probabilities and
    :data:`NO_ARM`); this helper is for callers that want that case to be an error.

    Args:
      mask: [..., K] bool array; each row (last axis) is one decision's valid arms.
      num_arms: expected K, or None.

    Returns:
      The mask as a numpy bool array.

    Raises:
      ValueError: the mask is not boolean, has no arm axis or the wrong K, or some row has no
        valid arm (the first such row is named).
    """
    m = np.asarray(mask)
    if m.dtype != np.bool_:
        raise ValueError(f"mask must be a boolean array, got dtype {m.dtype}")
    if m.ndim == 0:
        raise ValueError("mask must have shape [..., K] (one entry per arm), got a scalar")
    if num_arms is not None and m.shape[-1] != num_arms:
        raise ValueError(f"mask has K={m.shape[-1]} arms but {num_arms} were expected "
                         f"(mask shape {m.shape})")
    empty = ~np.any(m, axis=-1)
    if np.any(empty):
        if m.ndim == 1:
            raise ValueError(f"mask has no valid arm: all {m.shape[-1]} entries are False")
        row = tuple(int(i) for i in np.argwhere(empty)[0])
        raise ValueError(f"mask has no valid arm in row {row} ({int(empty.sum())} of "
                         f"{empty.size} rows are all False; mask shape {m.shape})")
    return m


def policy_probs(name: str, key: Key, inputs: PolicyInputs, alpha: Array, params,
                 mask: Array | None = None) -> Array:
    """Dispatches on the (static) policy name.

    Args:
      name: one of :data:`POLICY_NAMES`.
      key: PRNG key, consumed by the index policies.
      inputs: this round's :class:`PolicyInputs`.
      alpha: [] SERN temperature at this round.
      params: an object with scalar fields ``epsilon``, ``ucb_c``, ``bgc_c``, ``exp3_gamma``.
      mask: [K] bool validity, or None (all valid). Only the policies in
        :data:`MASKABLE_POLICIES` take one.

    Returns:
      [K] action distribution π_t.

    Raises:
      ValueError: an unknown policy, or a mask for a policy that cannot take one.
    """
    if name not in POLICY_NAMES:
        raise ValueError(f"unknown policy {name!r}; choose one of {POLICY_NAMES}")
    if mask is not None and name not in MASKABLE_POLICIES:
        raise ValueError(f"policy {name!r} does not take a validity mask; "
                         f"the ones that do are {MASKABLE_POLICIES}")
    if name == "softmax":
        return softmax_probs(inputs.r_hat, alpha, mask)
    if name == "greedy":
        return greedy_probs(inputs.r_hat, mask)
    if name == "epsilon_greedy":
        return epsilon_greedy_probs(inputs.r_hat, params.epsilon, mask)
    if name == "ucb1":
        return ucb1_probs(inputs.r_hat, inputs.counts, inputs.t, params.ucb_c, mask)
    if name == "thompson":
        return thompson_probs(key, inputs.counts, inputs.sums)
    if name == "boltzmann_gumbel":
        return boltzmann_gumbel_probs(key, inputs.r_hat, inputs.counts, params.bgc_c)
    return exp3_probs(inputs.gains, params.exp3_gamma)
