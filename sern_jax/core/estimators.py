"""Reward estimators r̂_a(s) as optax-style ``(init, update, predict)`` triples of pure functions.

All estimators share one tabular sufficient statistic (:class:`EstimatorState`): counts and
reward sums per (context, arm), pulls per arm over all contexts (Assumption 3's ``n_a``), and
EXP3's importance-weighted gains. They differ in ``predict``.

Which form of Assumption 3 (``E|r̂_a − r_a| < β/√(n_a+1)``) each satisfies (audit §2.1):

========== ===================================================== ==============================
name       r̂                                                     Assumption 3
========== ===================================================== ==============================
exact      r                                                     trivially (β = 0)
addhalf    (S + ½)/(n + 1)                                        fixed n only; β = ½ + ε
mean       S/n, ½ at n = 0                                        fixed n only; β = 1/√2 + ε
adv        r_{a*} − (1−ε)β/√(n+1), others r_a + (1−ε)β/√(n+1)    almost surely, worst case
adv_low    r_{worst} − (1−ε)β/√(n+1), others r_a + (1−ε)β/√(n+1) almost surely; with clip=False its
                                                                 r̂ range exceeds 1 (breaks Thm 1)
rademacher r_a + ξ(1−ε)β/√(n+1), ξ = ±1 fresh each round          almost surely
gauss      r_a + σ_n ξ, σ_n = (1−ε)β/(√(2/π)√(n+1)), ξ ~ N(0,1)  conditional mean only
flip       1 − r_a w.p. q_n = q_c/√(n+1), else r_a                conditional mean only, heavy tail
pinned     0 for ``pinned_arm``, 1 for every other arm            not an A3 estimator (Thm 1–2 worst case)
l1median   sample median of the 0/1 rewards (Algorithm 1's L1)   FAILS: tends to 1{r > ½}
l1argmax   1 − l1median: Algorithm 1's argmax of the L1 loss, as   FAILS: tends to 1{r < ½}
           printed (the error-maximising fit)
========== ===================================================== ==============================

For the tabular estimators ``n`` is the (context, arm) count; for the oracles it is ``n_a``,
the pulls of arm ``a`` over all contexts. ``adv`` treats the per-context best arm as ``a*``.
With ``clip=True`` (the default) every r̂ is clipped to [0, 1], which can only shrink the error,
so the A3 forms above survive clipping; Theorem 1 needs r̂ ∈ [0, 1] (audit §3.5).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from sern_jax.core.types import Array, Key

__all__ = [
    "ESTIMATOR_NAMES",
    "ORACLE_NAMES",
    "LOCAL_ESTIMATORS",
    "TABULAR_ESTIMATORS",
    "tabular_rhat",
    "EstimatorState",
    "Estimator",
    "OracleParams",
    "make_estimator",
    "init_state",
    "update_state",
]

ESTIMATOR_NAMES = (
    "exact",
    "addhalf",
    "mean",
    "adv",
    "adv_low",
    "rademacher",
    "gauss",
    "flip",
    "pinned",
    "l1median",
    "l1argmax",
)
ORACLE_NAMES = ("exact", "adv", "adv_low", "rademacher", "gauss", "flip", "pinned")
# Estimators whose r̂ in a context changes only for the pulled arm of that context.
LOCAL_ESTIMATORS = ("exact", "addhalf", "mean", "pinned", "l1median", "l1argmax")


# Estimators whose r̂ is a function of one cell's (count, reward sum) alone.
TABULAR_ESTIMATORS = ("addhalf", "mean", "l1median", "l1argmax")


def tabular_rhat(name: str, counts: Array, sums: Array, dtype) -> Array:
    """r̂ of the tabular estimators from counts and reward sums (elementwise, any shape).

    Shared by :func:`make_estimator` and ``fast_softmax`` (which evaluates one arm at a time).
    """
    n = counts.astype(dtype)
    if name == "addhalf":
        return (sums + 0.5) / (n + 1.0)
    if name == "mean":
        return jnp.where(n > 0, sums / jnp.maximum(n, 1.0), 0.5)
    if name in ("l1median", "l1argmax"):
        # argmin_x Σ|R_i − x| over 0/1 rewards: 1 if more ones, 0 if more zeros, ½ on ties
        # (the midpoint of the set of minimisers) and at n = 0. Σ|R_i − x| is linear in x
        # on [0, 1], so its argmax (Algorithm 1 as printed) is the mirror image, 1 − median.
        twice = 2.0 * sums
        median = jnp.where(twice > n, 1.0, jnp.where(twice < n, 0.0, 0.5)).astype(dtype)
        return median if name == "l1median" else 1.0 - median
    raise ValueError(f"{name!r} is not a tabular estimator; choose one of {TABULAR_ESTIMATORS}")


class EstimatorState(NamedTuple):
    """Tabular sufficient statistics shared by all estimators."""

    counts: Array  # [M, K] int32 pulls of arm a in context s
    sums: Array  # [M, K] float summed rewards of arm a in context s
    arm_counts: Array  # [K] int32 n_a: pulls of arm a over all contexts
    gains: Array  # [K] float EXP3 gains Σ 1{a_t = a} R_t / π_t(a)


class OracleParams(NamedTuple):
    """Traced parameters of the oracle estimators (ignored by the others)."""

    beta: Array  # [] β of Assumption 3
    oracle_eps: Array  # [] ε in (1 − ε)β, > 0 because A3 is strict
    flip_q: Array  # [] q_c of the flip oracle
    pinned_arm: Array  # [] int32 arm pinned to r̂ = 0 by ``pinned``


class Estimator(NamedTuple):
    """``init(num_contexts, num_arms, dtype)``, ``update(state, context, arm, reward, prob)``,
    ``predict(key, state, context, means_row, oracle_params) -> r̂ [K]``."""

    init: Callable[..., EstimatorState]
    update: Callable[..., EstimatorState]
    predict: Callable[..., Array]


def init_state(num_contexts: int, num_arms: int, dtype=jnp.float32) -> EstimatorState:
    """Empty statistics. Returns an :class:`EstimatorState`."""
    return EstimatorState(
        counts=jnp.zeros((num_contexts, num_arms), jnp.int32),
        sums=jnp.zeros((num_contexts, num_arms), dtype),
        arm_counts=jnp.zeros((num_arms,), jnp.int32),
        gains=jnp.zeros((num_arms,), dtype),
    )


def update_state(
    state: EstimatorState, context: Array, arm: Array, reward: Array, prob: Array
) -> EstimatorState:
    """Adds one observation ``(s, a, R)``; ``prob`` is π_t(a) (used by EXP3's gains).

    Uses one-hot adds rather than scatters: under ``vmap`` on CPU they fuse into one pass.

    Args:
      state: current statistics.
      context: [] int32 context index s_t.
      arm: [] int32 arm a_t.
      reward: [] float reward R_t ∈ {0, 1}.
      prob: [] float π_t(a_t) > 0.

    Returns:
      The updated :class:`EstimatorState`.
    """
    num_contexts, num_arms = state.counts.shape
    arm_hot = jax.nn.one_hot(arm, num_arms, dtype=state.sums.dtype)  # [K]
    if num_contexts == 1:
        cell_hot = arm_hot[None, :]
    else:
        ctx_hot = jax.nn.one_hot(context, num_contexts, dtype=state.sums.dtype)
        cell_hot = ctx_hot[:, None] * arm_hot[None, :]  # [M, K]
    return EstimatorState(
        counts=state.counts + cell_hot.astype(jnp.int32),
        sums=state.sums + cell_hot * reward,
        arm_counts=state.arm_counts + arm_hot.astype(jnp.int32),
        gains=state.gains + arm_hot * (reward / prob),
    )


def _oracle_scale(arm_counts: Array, params: OracleParams, dtype) -> Array:
    n = arm_counts.astype(dtype)
    return (1.0 - params.oracle_eps) * params.beta / jnp.sqrt(n + 1.0)


def make_estimator(name: str, clip: bool = True) -> Estimator:
    """Builds the named estimator.

    Args:
      name: one of :data:`ESTIMATOR_NAMES`.
      clip: clip r̂ to [0, 1] (set False only for checks that need the unclipped oracle).

    Returns:
      An :class:`Estimator` whose ``predict(key, state, context, means_row, params)`` takes a
      PRNG key (consumed by the random oracles), the statistics, the context index, the true
      means of that context [K] (used only by the oracles) and :class:`OracleParams`.
    """
    if name not in ESTIMATOR_NAMES:
        raise ValueError(f"unknown estimator {name!r}; choose one of {ESTIMATOR_NAMES}")

    def raw_predict(key: Key, state: EstimatorState, context: Array, means_row: Array,
                    params: OracleParams) -> Array:
        dtype = state.sums.dtype
        num_arms = state.counts.shape[-1]
        if state.counts.shape[0] == 1:
            counts, sums = state.counts[0], state.sums[0]
        else:
            counts, sums = state.counts[context], state.sums[context]
        if name == "exact":
            return means_row
        if name in TABULAR_ESTIMATORS:
            return tabular_rhat(name, counts, sums, dtype)
        if name == "pinned":
            return jnp.where(jnp.arange(num_arms) == params.pinned_arm, 0.0, 1.0).astype(dtype)
        scale = _oracle_scale(state.arm_counts, params, dtype)
        if name == "adv":
            best = jnp.arange(num_arms) == jnp.argmax(means_row)
            return means_row + jnp.where(best, -scale, scale)
        if name == "adv_low":
            worst = jnp.arange(num_arms) == jnp.argmin(means_row)
            return means_row + jnp.where(worst, -scale, scale)
        if name == "rademacher":
            xi = jax.random.rademacher(key, (num_arms,), dtype=dtype)
            return means_row + xi * scale
        if name == "gauss":
            xi = jax.random.normal(key, (num_arms,), dtype=dtype)
            return means_row + xi * scale / jnp.sqrt(2.0 / jnp.pi)
        if name == "flip":
            q = params.flip_q / jnp.sqrt(state.arm_counts.astype(dtype) + 1.0)
            flip = jax.random.uniform(key, (num_arms,), dtype=dtype) < q
            return jnp.where(flip, 1.0 - means_row, means_row)
        raise AssertionError(name)

    def predict(key, state, context, means_row, params):
        r_hat = raw_predict(key, state, context, means_row, params)
        return jnp.clip(r_hat, 0.0, 1.0) if clip else r_hat

    return Estimator(init=init_state, update=update_state, predict=predict)
