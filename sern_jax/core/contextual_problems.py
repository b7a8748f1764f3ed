"""Contextual bandits with continuous contexts whose expected rewards are known exactly.

A problem is a :class:`ContextualBandit`: pure, unbatched functions of a context ``x`` [d]
(vmap at the call site) plus what the regret accounting needs. Three problems:

* :func:`wheel`: the wheel bandit of Riquelme, Tucker & Snoek 2018 ("Deep Bayesian Bandits
  Showdown", arXiv:1802.09127), as published in ``tensorflow/models``
  ``research/deep_contextual_bandits/bandits/data/synthetic_data_sampler.py``
  (``sample_wheel_bandit_data``) with the benchmark's constants from google/edward2's wheel
  generator (``get_wheel_data``): 2-D contexts uniform in the unit disc; 5 arms; every arm
  pays ``N(mean_v[j], std_v[j])`` with ``mean_v = [1.0, 1.0, 1.0, 1.0, 1.2]`` and
  ``std_v = 0.01`` (the tensorflow/models example script uses 0.05; ``noise_sd`` sets it), except
  that when ``‖x‖ ≥ δ`` the arm of x's quadrant pays ``N(50, 0.01)``:
  (x0 > 0, x1 > 0) → arm 0, (x0 > 0, x1 ≤ 0) → arm 1, (x0 ≤ 0, x1 > 0) → arm 2, else arm 3.
  The reference draws contexts by rejection from [-1, 1]²; we draw the same distribution in
  closed form (radius √U1, angle 2πU2), which has a fixed shape under ``jit``.
* :func:`finite`: M fixed contexts (random Gaussian features, the network's input) with a
  random Bernoulli mean table whose Assumption-1 gap is exactly Δ2 in every context
  (``problems.contextual_with_gap``): nonlinear in the features, Theorem 4's T* defined.
* :func:`linear`: contexts uniform on the unit sphere of R^d, Bernoulli rewards with mean
  ``(1 + x·θ_a)/2``, θ_a unit vectors: linear in (1, x), so Neural-Linear meets LinUCB.

Rewards in the problem's own units (the wheel's 50) are what regret is measured in. The
learners of :mod:`sern_jax.learners` fit r̂ ∈ [0, 1] with a cross-entropy loss, so they are
given ``scale_reward(r) = clip((r − lo)/(hi − lo), 0, 1)`` with ``reward_range = (lo, hi)``:
(0, 1) for the Bernoulli problems (no change); for the wheel (0, 50 + 10·σ_large), so that a
draw is clipped only beyond 10 standard deviations (probability < 1e-22) and the scaled
expected reward is the scaled mean up to that.

Traced problem parameters. A problem may carry ``params`` (a NamedTuple of arrays, the
wheel's :class:`WheelParams` (δ)) and ``bind(params) -> BoundProblem``, the same functions
with the parameters as traced values. The runner's ``run(key, params)`` then takes δ as an
argument, so one compiled program serves a δ sweep (``neural_runner.run_seeds(...,
params=...)``); without ``params`` it closes over the problem's own values, as before.

Core module: jax and numpy only. Keys are consumed.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import problems as prob_lib
from sern_jax.core.types import Array, Key

__all__ = [
    "PROBLEM_NAMES",
    "WHEEL_DELTAS",
    "BoundProblem",
    "ContextualBandit",
    "WheelParams",
    "wheel",
    "wheel_expected_rewards",
    "wheel_optimal_arm",
    "finite",
    "linear",
    "make_problem",
]

PROBLEM_NAMES = ("wheel", "finite", "linear")
WHEEL_DELTAS = (0.5, 0.7, 0.9, 0.95, 0.99)  # Riquelme et al.'s (and edward2's) δ grid

_WHEEL_MEAN_V = (1.0, 1.0, 1.0, 1.0, 1.2)
_WHEEL_MU_LARGE = 50.0
_WHEEL_STD_LARGE = 0.01


class WheelParams(NamedTuple):
    """The wheel's traced parameter."""

    delta: Array  # [] float32 δ ∈ (0, 1)


class BoundProblem(NamedTuple):
    """A problem's functions with its parameters bound as traced values (``bind(params)``)."""

    sample_context: Callable[[Key], Array]
    expected_rewards: Callable[[Array], Array]
    sample_rewards: Callable[[Key, Array], Array]
    mu_star: Array  # [] max_a E_x r_a(x) (the paper's comparator), traced


class ContextualBandit(NamedTuple):
    """A contextual bandit as pure functions of one context (closed over its constants).

    ``num_arms``, ``context_dim`` and the callables are static (closed over by the runner).
    """

    name: str
    num_arms: int  # K
    context_dim: int  # d
    sample_context: Callable[[Key], Array]  # key -> x [d]
    expected_rewards: Callable[[Array], Array]  # x [d] -> r(x) [K], exact
    sample_rewards: Callable[[Key, Array], Array]  # key, x [d] -> one draw of every arm [K]
    reward_range: tuple  # (lo, hi): scale_reward maps it onto [0, 1]
    arm_means: np.ndarray  # [K] float64 E_x r_a(x), exact (the paper's regret uses max of it)
    gap2: float | None  # Assumption 1's Δ2 = min_x (best − second best), where it is > 0
    contexts: np.ndarray | None = None  # [M, d] the finite problem's contexts (else None)
    params: NamedTuple | None = None  # traceable parameters (wheel: WheelParams), or None
    bind: Callable | None = None  # params -> BoundProblem (None: no traced parameters)

    def scale_reward(self, reward: Array) -> Array:
        """Rewards in the problem's units -> [0, 1] (what the learners fit)."""
        lo, hi = self.reward_range
        return jnp.clip((reward - lo) / (hi - lo), 0.0, 1.0)


def _check_arms(flag: str, num_arms) -> int:
    if isinstance(num_arms, bool) or not isinstance(num_arms, (int, np.integer)) or num_arms < 2:
        raise ValueError(f"{flag} must be an integer >= 2 (a bandit needs two arms), "
                         f"got {num_arms!r}")
    return int(num_arms)


def _check_open_unit(flag: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{flag} must be a number in (0, 1), got {value!r}")
    v = float(value)
    if not 0.0 < v < 1.0:  # also refuses NaN
        raise ValueError(f"{flag} must lie in (0, 1), got {value!r}")
    return v


def _check_nonneg(flag: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{flag} must be a finite number >= 0, got {value!r}")
    return v


# ----------------------------------------------------------------------------- wheel


def _wheel_quadrant_arm(x: Array) -> Array:
    """The arm of x's quadrant, as in the reference's if/else: [d=2] -> [] int32."""
    right = x[0] > 0
    up = x[1] > 0
    return jnp.where(right, jnp.where(up, 0, 1), jnp.where(up, 2, 3)).astype(jnp.int32)


def wheel_expected_rewards(x: Array, delta) -> Array:
    """The wheel's exact expected rewards r(x) [5] at x [2]: ``mean_v``, with the quadrant
    arm's mean replaced by 50 when ‖x‖ ≥ δ."""
    base = jnp.asarray(_WHEEL_MEAN_V, jnp.result_type(x.dtype, jnp.float32))
    outer = jnp.sqrt(jnp.sum(x * x)) >= delta
    big = outer & (jnp.arange(5) == _wheel_quadrant_arm(x))
    return jnp.where(big, jnp.asarray(_WHEEL_MU_LARGE, base.dtype), base)


def wheel_optimal_arm(x: Array, delta) -> Array:
    """The optimal arm: 4 (mean 1.2) inside the disc of radius δ, the quadrant's arm outside."""
    outer = jnp.sqrt(jnp.sum(x * x)) >= delta
    return jnp.where(outer, _wheel_quadrant_arm(x), 4).astype(jnp.int32)


def wheel(delta: float, noise_sd: float = 0.01, dtype=jnp.float32) -> ContextualBandit:
    """Riquelme et al.'s wheel bandit with exploration parameter ``delta`` ∈ (0, 1).

    Args:
      delta: δ, the inner disc's radius (``--delta``); the paper's grid is ``WHEEL_DELTAS``.
      noise_sd: the small arms' Gaussian reward sd (``std_v``; 0.01 as in the benchmark);
        the large reward's sd is 0.01 always (``std_large``).
      dtype: float dtype of contexts and rewards.

    Returns:
      The problem. ``arm_means``: arms 0–3 pay 1 + 49·(1 − δ²)/4 on average (P(‖x‖ ≥ δ) =
      1 − δ² for x uniform in the unit disc, a quarter of it per quadrant), arm 4 pays 1.2.
    """
    delta = _check_open_unit("--delta", delta)
    noise_sd = _check_nonneg("--noise-sd", noise_sd)
    q = (1.0 - delta * delta) / 4.0
    arm_means = np.array([1.0 + (_WHEEL_MU_LARGE - 1.0) * q] * 4 + [1.2])
    fns = _wheel_functions(delta, noise_sd, dtype)
    return ContextualBandit(
        name=f"wheel(delta={delta:g})", num_arms=5, context_dim=2,
        sample_context=fns.sample_context, expected_rewards=fns.expected_rewards,
        sample_rewards=fns.sample_rewards,
        reward_range=(0.0, _WHEEL_MU_LARGE + 10.0 * _WHEEL_STD_LARGE),
        arm_means=arm_means, gap2=None,
        params=WheelParams(np.float32(delta)),
        bind=lambda params: _wheel_functions(params.delta, noise_sd, dtype))


def _wheel_functions(delta, noise_sd: float, dtype) -> BoundProblem:
    """The wheel's functions for δ (a Python float: a constant; an array: traced)."""

    def sample_context(key: Key) -> Array:
        key_r, key_angle = jax.random.split(key)
        radius = jnp.sqrt(jax.random.uniform(key_r, (), dtype))
        angle = jax.random.uniform(key_angle, (), dtype) * (2.0 * math.pi)
        return jnp.stack([radius * jnp.cos(angle), radius * jnp.sin(angle)])

    def expected_rewards(x: Array) -> Array:
        return wheel_expected_rewards(x, delta).astype(dtype)

    def sample_rewards(key: Key, x: Array) -> Array:
        means = expected_rewards(x)
        sd = jnp.where(means == _WHEEL_MU_LARGE, _WHEEL_STD_LARGE, noise_sd).astype(dtype)
        return means + sd * jax.random.normal(key, (5,), dtype)

    # max(1 + 49 (1 − δ²)/4, 1.2): arms 0–3 on average, or arm 4
    mu_star = jnp.maximum(1.0 + (_WHEEL_MU_LARGE - 1.0) * (1.0 - delta * delta) / 4.0, 1.2)
    return BoundProblem(sample_context, expected_rewards, sample_rewards, mu_star)


# ----------------------------------------------------------------------------- finite


def finite(key: Key, num_contexts: int = 10, num_arms: int = 5, gap: float = 0.1,
           context_dim: int = 4, dtype=jnp.float32) -> ContextualBandit:
    """M fixed contexts with Gaussian features [M, d] and a Bernoulli mean table [M, K]
    whose gap between the best and second-best arm is exactly ``gap`` in every context.

    Args:
      key: the problem's key (consumed): features and the table (fixed across seeds).
      num_contexts: M ≥ 1 (``--contexts``), drawn uniformly each round.
      num_arms: K ≥ 2 (``--arms``).
      gap: Δ2 ∈ (0, 1) (``--gap``).
      context_dim: d ≥ 1, the features' dimension (the network's input).
    """
    num_arms = _check_arms("--arms", num_arms)
    gap = _check_open_unit("--gap", gap)
    if isinstance(num_contexts, bool) or not isinstance(num_contexts, (int, np.integer)) \
            or num_contexts < 1:
        raise ValueError(f"--contexts must be an integer >= 1, got {num_contexts!r}")
    if isinstance(context_dim, bool) or not isinstance(context_dim, (int, np.integer)) \
            or context_dim < 1:
        raise ValueError(f"--context-dim must be an integer >= 1, got {context_dim!r}")
    key_table, key_feat = jax.random.split(key)
    table = prob_lib.contextual_with_gap(key_table, num_contexts, num_arms, gap, dtype).means
    features = jax.random.normal(key_feat, (num_contexts, context_dim), dtype)
    table_np = np.asarray(table, np.float64)
    top2 = np.sort(table_np, axis=1)[:, -2:]
    return finite_from_table(table_np, np.asarray(features), dtype,
                             gap2=float(np.min(top2[:, 1] - top2[:, 0])))


def finite_from_table(means, features, dtype=jnp.float32, gap2=None) -> ContextualBandit:
    """A finite-context Bernoulli problem from its mean table [M, K] and features [M, d]
    (uniform context distribution). Used by :func:`finite` and by exact-oracle tests."""
    means = np.asarray(means, np.float64)
    features = np.asarray(features, np.float64)
    if means.ndim != 2 or features.ndim != 2 or features.shape[0] != means.shape[0]:
        raise ValueError(f"means [M, K] and features [M, d] must agree, got {means.shape} "
                         f"and {features.shape}")
    m, k = means.shape
    _check_arms("--arms", k)
    if np.any(~np.isfinite(means)) or np.any((means < 0) | (means > 1)):
        raise ValueError("finite problem means must lie in [0, 1]")
    table = jnp.asarray(means, dtype)
    feats = jnp.asarray(features, dtype)

    def index(x: Array) -> Array:  # the context whose features x are (exact match)
        return jnp.argmin(jnp.sum(jnp.abs(feats - x[None, :]), axis=1))

    def sample_context(key: Key) -> Array:
        return feats[jax.random.randint(key, (), 0, m)]

    def expected_rewards(x: Array) -> Array:
        return table[index(x)]

    def sample_rewards(key: Key, x: Array) -> Array:
        u = jax.random.uniform(key, (k,), dtype)
        return (u < expected_rewards(x)).astype(dtype)

    if gap2 is None:
        top2 = np.sort(means, axis=1)[:, -2:] if k >= 2 else None
        gap2 = float(np.min(top2[:, 1] - top2[:, 0]))
    return ContextualBandit(
        name=f"finite(M={m}, K={k})", num_arms=k, context_dim=features.shape[1],
        sample_context=sample_context, expected_rewards=expected_rewards,
        sample_rewards=sample_rewards, reward_range=(0.0, 1.0),
        arm_means=means.mean(axis=0), gap2=gap2 if gap2 > 0 else None,
        contexts=np.asarray(feats, np.float64))


# ----------------------------------------------------------------------------- linear


def linear(key: Key, num_arms: int = 5, context_dim: int = 4,
           dtype=jnp.float32) -> ContextualBandit:
    """Contexts uniform on the unit sphere of R^d; arm a pays Bernoulli((1 + x·θ_a)/2),
    θ_a uniform on the sphere (drawn once from ``key``)."""
    num_arms = _check_arms("--arms", num_arms)
    if isinstance(context_dim, bool) or not isinstance(context_dim, (int, np.integer)) \
            or context_dim < 1:
        raise ValueError(f"--context-dim must be an integer >= 1, got {context_dim!r}")
    theta = jax.random.normal(key, (num_arms, context_dim), jnp.float32)
    theta = np.asarray(theta / jnp.linalg.norm(theta, axis=1, keepdims=True), np.float64)
    theta_j = jnp.asarray(theta, dtype)

    def sample_context(key: Key) -> Array:
        z = jax.random.normal(key, (context_dim,), dtype)
        return z / jnp.maximum(jnp.linalg.norm(z), 1e-12)

    def expected_rewards(x: Array) -> Array:
        return jnp.clip(0.5 * (1.0 + theta_j @ x), 0.0, 1.0)

    def sample_rewards(key: Key, x: Array) -> Array:
        u = jax.random.uniform(key, (num_arms,), dtype)
        return (u < expected_rewards(x)).astype(dtype)

    return ContextualBandit(
        name=f"linear(K={num_arms}, d={context_dim})", num_arms=num_arms,
        context_dim=context_dim, sample_context=sample_context,
        expected_rewards=expected_rewards, sample_rewards=sample_rewards,
        reward_range=(0.0, 1.0), arm_means=np.full(num_arms, 0.5), gap2=None)


def make_problem(name: str, *, delta: float = 0.95, num_arms: int = 5,
                 num_contexts: int = 10, gap: float = 0.1, context_dim: int = 4,
                 noise_sd: float = 0.01, seed: int = 0) -> ContextualBandit:
    """The problem ``name`` (``--problem``) from command-line values; bad values raise a
    one-line ``ValueError`` naming the flag. ``seed`` fixes the finite/linear instance."""
    if name not in PROBLEM_NAMES:
        raise ValueError(f"--problem must be one of {', '.join(PROBLEM_NAMES)}, got {name!r}")
    if name == "wheel":
        if num_arms != 5:
            raise ValueError(f"--arms: the wheel bandit has 5 arms, got {num_arms!r}")
        return wheel(delta, noise_sd)
    key = jax.random.fold_in(jax.random.key(seed), 10_007)
    if name == "finite":
        return finite(key, num_contexts, num_arms, gap, context_dim)
    return linear(key, num_arms, context_dim)
