"""The bandit engine: ``lax.scan`` over rounds for one seed, summaries on a log grid.

``make_run(config)`` returns ``run(key, params) -> RunOutput`` for one seed: types, validation,
the scan and the diagnostics live here. Running many seeds (``vmap`` over per-seed keys
``fold_in(root, i)`` from :func:`seed_keys`, chunking, threads, device meshes, copies to the
host) is :func:`sern_jax.engine.drive.run_seeds`; this module imports neither ``executor`` nor
``fast_softmax``.

Memory never grows with S×T×K: the run is an outer ``scan`` over G checkpoints with an inner
``fori_loop`` over the rounds between them; only O(S·G·K) summaries are kept.

Random streams per seed (STYLE.md §3): the environment (contexts, reward uniforms) draws from
``fold_in(seed_key, ENV_STREAM)`` and the agent (arm uniform, estimator/policy noise) from
``fold_in(seed_key, AGENT_STREAM)``; each purpose then folds its sub-stream id into its parent
once (:data:`ROUNDS_STREAM`, :data:`PROBLEM_STREAM`, :data:`EST_NOISE_STREAM`,
:data:`POLICY_NOISE_STREAM`) and round ``t`` uses ``fold_in(sub_stream, t)``. Different policies
therefore see the same contexts and the same reward uniforms (common random numbers), and any
other runner (``fast_softmax``) reproduces these draws from the public ids.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import estimators as est_lib
from sern_jax.core import policies as pol_lib
from sern_jax.core import problems as prob_lib
from sern_jax.core import schedules
from sern_jax.core.types import Array, Key

__all__ = [
    "ENV_STREAM",
    "AGENT_STREAM",
    "ROUNDS_STREAM",
    "PROBLEM_STREAM",
    "EST_NOISE_STREAM",
    "POLICY_NOISE_STREAM",
    "RunConfig",
    "RunParams",
    "Diagnostics",
    "RunOutput",
    "default_params",
    "checkpoint_times",
    "make_run",
    "seed_keys",
    "validate",
    "kahan_add",
]

ENV_STREAM = 0
AGENT_STREAM = 1
# Sub-streams: each is folded into its parent stream once, then per round with fold_in(·, t),
# so no two purposes ever share a key.
ROUNDS_STREAM = 0  # env: context + reward uniforms / agent: arm uniform
PROBLEM_STREAM = 1  # env: random means (folded into the env stream)
EST_NOISE_STREAM = 1  # agent: oracle estimator noise (folded into the agent stream)
POLICY_NOISE_STREAM = 2  # agent: index-policy noise (folded into the agent stream)


_MAX_HORIZON = 2**31 - 1  # rounds are int32 inside the scan
_MAX_HORIZON_F32 = 2**24  # float32 integers (reward sums, pull counts) are exact up to 2^24


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Static configuration: anything that changes the compiled program.

    Attributes:
      policy: one of ``policies.POLICY_NAMES``.
      estimator: one of ``estimators.ESTIMATOR_NAMES``.
      schedule: α schedule kind, one of ``schedules.SCHEDULE_NAMES``.
      num_arms: K ≥ 2.
      horizon: T ≥ 1.
      num_contexts: M ≥ 1 (1 = K-armed bandit).
      num_checkpoints: requested size of the log-spaced grid of t (duplicates removed).
      clip: clip r̂ to [0, 1].
      dtype: ``"float32"`` or ``"float64"`` (the latter inside ``jax.enable_x64()``).
      diagnostics: also accumulate the per-round quantities of Theorem 3 (:class:`Diagnostics`).
      random_means: draw each seed's means i.i.d. U[0, 1] from its environment stream (the
        problem's shape is kept, its means ignored): a new random instance per seed.
    """

    policy: str = "softmax"
    estimator: str = "addhalf"
    schedule: str = "constant"
    num_arms: int = 10
    horizon: int = 1000
    num_contexts: int = 1
    num_checkpoints: int = 32
    clip: bool = True
    dtype: str = "float32"
    diagnostics: bool = False
    random_means: bool = False

    @property
    def jnp_dtype(self):
        return jnp.float64 if self.dtype == "float64" else jnp.float32


class RunParams(NamedTuple):
    """Traced parameters: sweeping any of them is a ``vmap``, never a recompile."""

    alpha0: Array  # [] SERN temperature α0 (α itself for the constant schedule)
    p: Array  # [] schedule exponent p
    epsilon: Array  # [] ε of ε-greedy
    ucb_c: Array  # [] UCB1 bonus multiplier
    bgc_c: Array  # [] Boltzmann-Gumbel constant C
    exp3_gamma: Array  # [] EXP3 exploration rate γ
    oracle: est_lib.OracleParams  # β, ε, q_c, pinned arm of the oracle estimators
    problem: prob_lib.Problem  # means [M, K], context_probs [M]


class Diagnostics(NamedTuple):
    """Cumulative sums at each checkpoint (Theorem 3's ingredients); all [G]."""

    err_best: Array  # Σ_τ |r̂_{a*}(s_τ) − r_{a*}(s_τ)|, a* the paper's best arm
    err_rb: Array  # Σ_τ Σ_a π_τ(a)|r̂_a(s_τ) − r_a(s_τ)|
    err_chosen: Array  # Σ_τ |r̂_{a_τ}(s_τ) − r_{a_τ}(s_τ)|
    inv_sqrt_best: Array  # Σ_τ (n_{a*}(τ−1) + 1)^{-1/2}
    inv_sqrt_rb: Array  # Σ_τ Σ_a π_τ(a)(n_a(τ−1) + 1)^{-1/2}
    inv_sqrt_chosen: Array  # Σ_τ (n_{a_τ}(τ−1) + 1)^{-1/2}
    misid: Array  # Σ_τ 1{â*_{τ−1} ≠ a*}; ties count as misidentified
    entropy: Array  # Σ_τ S(π_τ)
    inv_sqrt_all: Array  # Σ_τ Σ_a (n_a(τ−1) + 1)^{-1/2} (all arms, unweighted)
    misid_strict: Array  # Σ_τ 1{r̄̂_{a*} < max_{a≠a*} r̄̂_a − 1e-12}: ties count as identified


class RunOutput(NamedTuple):
    """Per-seed summaries after round t_g of each checkpoint g."""

    regret: Array  # [G] standard pseudo-regret Σ_τ (max_a r_a(s_τ) − r_{a_τ}(s_τ))
    regret_paper: Array  # [G] the paper's: Σ_τ (max_a E_s r_a(s) − r_{a_τ}(s_τ))
    regret_rb: Array  # [G] Rao–Blackwellised standard: Σ_τ (max_a r_a(s_τ) − Σ_a π_τ(a) r_a(s_τ))
    regret_rb_paper: Array  # [G] Rao–Blackwellised paper's regret
    counts: Array  # [G, K] int32 N_a(t)
    compensator: Array  # [G, K] A_a(t) = Σ_{τ≤t} π_τ(a)
    min_prob: Array  # [G] min over τ ≤ t and arms of π_τ(a)
    diag: Optional[Diagnostics]  # [G] each, or None without config.diagnostics


def default_params(config: RunConfig, problem: prob_lib.Problem, **overrides) -> RunParams:
    """RunParams with sensible defaults, cast to the config dtype.

    Defaults: α0 = 1, p = 0.3, ε = 0.1, UCB c = 1, Boltzmann-Gumbel C = 1, EXP3 γ = 0.1,
    β = 0.5, oracle ε = 0.01, flip q_c = 0.5, pinned arm = last arm.
    Any field (and ``beta``, ``oracle_eps``, ``flip_q``, ``pinned_arm``) can be overridden.
    """
    dtype = config.jnp_dtype
    oracle_fields = {"beta": 0.5, "oracle_eps": 0.01, "flip_q": 0.5,
                     "pinned_arm": config.num_arms - 1}
    fields = {"alpha0": 1.0, "p": 0.3, "epsilon": 0.1, "ucb_c": 1.0, "bgc_c": 1.0,
              "exp3_gamma": 0.1}
    for k, v in overrides.items():
        if k in oracle_fields:
            oracle_fields[k] = v
        elif k in fields:
            fields[k] = v
        else:
            raise ValueError(f"unknown parameter {k!r}; known: "
                             f"{sorted(fields) + sorted(oracle_fields)}")
    oracle = est_lib.OracleParams(
        beta=jnp.asarray(oracle_fields["beta"], dtype),
        oracle_eps=jnp.asarray(oracle_fields["oracle_eps"], dtype),
        flip_q=jnp.asarray(oracle_fields["flip_q"], dtype),
        pinned_arm=jnp.asarray(oracle_fields["pinned_arm"], jnp.int32),
    )
    problem = prob_lib.Problem(jnp.asarray(problem.means, dtype),
                               jnp.asarray(problem.context_probs, dtype))
    return RunParams(oracle=oracle, problem=problem,
                     **{k: jnp.asarray(v, dtype) for k, v in fields.items()})


def checkpoint_times(config: RunConfig) -> np.ndarray:
    """Log-spaced checkpoint rounds: unique ints in [1, T], increasing, last equal to T.

    Returns:
      [G] int64 numpy array (G ≤ ``config.num_checkpoints``).
    """
    horizon = config.horizon
    g = max(1, min(config.num_checkpoints, horizon))
    grid = np.unique(np.round(np.geomspace(1, horizon, g)).astype(np.int64))
    grid = grid[(grid >= 1) & (grid <= horizon)]
    if grid[-1] != horizon:
        grid = np.append(grid, horizon)
    return grid


def validate(config: RunConfig, params: RunParams | None = None, num_seeds: int = 1) -> None:
    """Host-side validation; raises ``ValueError`` naming the bad value, before any compile."""
    if config.policy not in pol_lib.POLICY_NAMES:
        raise ValueError(f"unknown policy {config.policy!r}; choose one of {pol_lib.POLICY_NAMES}")
    if config.estimator not in est_lib.ESTIMATOR_NAMES:
        raise ValueError(
            f"unknown estimator {config.estimator!r}; choose one of {est_lib.ESTIMATOR_NAMES}"
        )
    if config.schedule not in schedules.SCHEDULE_NAMES:
        raise ValueError(
            f"unknown schedule {config.schedule!r}; choose one of {schedules.SCHEDULE_NAMES}"
        )
    for name, value, low in (("num_arms (K)", config.num_arms, 2),
                             ("horizon (T)", config.horizon, 1),
                             ("num_contexts (M)", config.num_contexts, 1),
                             ("num_checkpoints", config.num_checkpoints, 1),
                             ("num_seeds (S)", num_seeds, 1)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if config.dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {config.dtype!r}")
    if config.horizon > _MAX_HORIZON:
        raise ValueError(f"horizon (T) must be <= {_MAX_HORIZON} (int32 round counters), "
                         f"got {config.horizon}")
    if config.dtype == "float32" and config.horizon > _MAX_HORIZON_F32:
        raise ValueError(
            f"horizon (T) = {config.horizon} exceeds 2^24 = {_MAX_HORIZON_F32}, past which "
            f"float32 reward sums and counts are no longer exact; use float64 (--float64)")
    if config.dtype == "float64" and not jax.config.jax_enable_x64:
        raise ValueError("dtype='float64' needs x64: run inside `with jax.enable_x64():`")
    if params is None:
        return
    prob_lib.validate_problem(params.problem, config.num_arms, config.num_contexts)
    _check_scalar("alpha0", params.alpha0, batched_ok=True)
    schedules.validate_schedule(config.schedule, config.horizon, _show(params.alpha0),
                                _show(params.p))
    if config.policy == "softmax":
        # exp((r̂ − max r̂)/α) needs a normal α: a subnormal one flushes to 0 and gives NaN
        with np.errstate(all="ignore"):
            alpha = schedules.alpha_of_horizon(config.schedule, config.horizon,
                                               np.asarray(params.alpha0, np.float64),
                                               np.asarray(params.p, np.float64))
        tiny = float(np.finfo(config.dtype).tiny)
        if np.any(~(alpha >= tiny)):
            raise ValueError(
                f"softmax temperature α(T) = {_show(alpha)} is below the smallest normal "
                f"{config.dtype} ({tiny:.3g}); use float64 or the greedy policy (the α → 0 "
                f"limit)")
    eps = np.asarray(params.epsilon, np.float64)
    if np.any(~np.isfinite(eps)) or np.any((eps < 0) | (eps > 1)):
        raise ValueError(f"epsilon must lie in [0, 1], got {_show(params.epsilon)}")
    gamma = np.asarray(params.exp3_gamma, np.float64)
    if config.policy == "exp3" and (np.any(~np.isfinite(gamma)) or np.any((gamma <= 0) | (gamma > 1))):
        raise ValueError(f"exp3_gamma must lie in (0, 1], got {_show(params.exp3_gamma)}")
    for name in ("ucb_c", "bgc_c"):
        v = np.asarray(getattr(params, name), np.float64)
        if np.any(~np.isfinite(v)) or np.any(v < 0):
            raise ValueError(f"{name} must be finite and >= 0, got {_show(v)}")
    o = params.oracle
    beta = np.asarray(o.beta, np.float64)
    if np.any(~np.isfinite(beta)) or np.any(beta < 0):
        raise ValueError(f"beta must be finite and >= 0, got {_show(o.beta)}")
    oe = np.asarray(o.oracle_eps, np.float64)
    if np.any(~np.isfinite(oe)) or np.any((oe < 0) | (oe > 1)):
        raise ValueError(f"oracle_eps must lie in [0, 1], got {_show(o.oracle_eps)}")
    fq = np.asarray(o.flip_q, np.float64)
    if np.any(~np.isfinite(fq)) or np.any((fq < 0) | (fq > 1)):
        raise ValueError(f"flip_q must lie in [0, 1], got {_show(o.flip_q)}")
    pa = np.asarray(o.pinned_arm)
    if np.any((pa < 0) | (pa >= config.num_arms)):
        raise ValueError(f"pinned_arm must lie in [0, {config.num_arms - 1}], got {_show(o.pinned_arm)}")


def _show(value):
    """A parameter as a plain number (or list) for messages, not ``Array(0., dtype=...)``."""
    arr = np.asarray(value)
    return arr.item() if arr.ndim == 0 else arr.tolist()


def _check_scalar(name, value, batched_ok=False):
    arr = np.asarray(value, np.float64)
    if arr.ndim != 0 and not batched_ok:
        raise ValueError(f"{name} must be a scalar, got shape {arr.shape}")
    if np.any(np.isnan(arr)):
        raise ValueError(f"{name} is NaN")


def kahan_add(total: Array, err: Array, x: Array) -> tuple[Array, Array]:
    """One step of Kahan (compensated) summation: ``(total, err)`` after adding ``x``.

    ``total − err`` is the running sum; the error stays O(ε) instead of growing with the
    number of terms: a float32 sum of 2^24 small increments no longer stalls once the total's
    spacing exceeds the increment (naively ``R_T`` saturated at 2^20 for T = 2·10^7).

    Args:
      total: [...] running sum.
      err: [...] compensation, the low-order part lost so far (start at 0).
      x: [...] the increment.

    Returns:
      ``(total, err)`` updated.
    """
    y = x - err
    t = total + y
    return t, (t - total) - y


class _Carry(NamedTuple):
    est: est_lib.EstimatorState
    regret: Array  # [4] standard, paper, rb, rb_paper (Kahan sums)
    regret_err: Array  # [4] Kahan compensation of ``regret``
    compensator: Array  # [K] (Kahan sum)
    compensator_err: Array  # [K] Kahan compensation of ``compensator``
    min_prob: Array  # []
    diag: Array  # [8] or [0]


def make_run(config: RunConfig) -> Callable[[Key, RunParams], RunOutput]:
    """Builds the single-seed runner.

    Args:
      config: static :class:`RunConfig` (validated here).

    Returns:
      ``run(key, params) -> RunOutput``: key is consumed; outputs on ``checkpoint_times(config)``.
    """
    validate(config)
    dtype = config.jnp_dtype
    num_arms, num_contexts = config.num_arms, config.num_contexts
    estimator = est_lib.make_estimator(config.estimator, clip=config.clip)
    grid = checkpoint_times(config)
    starts = np.concatenate([[0], grid[:-1]]).astype(np.int32)  # rounds [start, end) 0-based
    ends = grid.astype(np.int32)
    needs_est_noise = config.estimator in ("rademacher", "gauss", "flip")
    needs_pol_noise = config.policy in pol_lib.INDEX_POLICIES
    num_diag = len(Diagnostics._fields) if config.diagnostics else 0

    def run(key: Key, params: RunParams) -> RunOutput:
        key_env = jax.random.fold_in(key, ENV_STREAM)
        key_agent = jax.random.fold_in(key, AGENT_STREAM)
        key_est = jax.random.fold_in(key_agent, EST_NOISE_STREAM)
        key_pol = jax.random.fold_in(key_agent, POLICY_NOISE_STREAM)
        key_problem = jax.random.fold_in(key_env, PROBLEM_STREAM)
        key_env = jax.random.fold_in(key_env, ROUNDS_STREAM)
        key_agent = jax.random.fold_in(key_agent, ROUNDS_STREAM)
        del key
        problem = params.problem
        if config.random_means:
            problem = problem._replace(means=jax.random.uniform(
                key_problem, problem.means.shape, dtype))
        means = problem.means  # [M, K]
        ctx_cdf = jnp.cumsum(problem.context_probs)
        mean_r = prob_lib.mean_rewards(problem)  # [K]
        mu_star = jnp.max(mean_r)
        a_star = jnp.argmax(mean_r)
        alpha = schedules.alpha_t(config.schedule, 0, config.horizon, params.alpha0, params.p)

        def round_body(t, carry: _Carry) -> _Carry:
            # ---- environment draws: context and reward uniform (common random numbers)
            u_env = jax.random.uniform(jax.random.fold_in(key_env, t), (2,), dtype)
            if num_contexts == 1:
                context = jnp.zeros((), jnp.int32)
                means_row = means[0]
            else:
                context = jnp.minimum(jnp.sum(ctx_cdf <= u_env[0] * ctx_cdf[-1]),
                                      num_contexts - 1).astype(jnp.int32)
                means_row = means[context]
            # ---- agent: estimate, policy, sample
            u_arm = jax.random.uniform(jax.random.fold_in(key_agent, t), (), dtype)
            k_est = jax.random.fold_in(key_est, t) if needs_est_noise else key_est
            est = carry.est
            if config.diagnostics and num_contexts > 1:
                r_hat_all = jax.vmap(
                    lambda c, row: estimator.predict(jax.random.fold_in(k_est, c), est, c,
                                                     row, params.oracle)
                )(jnp.arange(num_contexts), means)  # [M, K]
                r_hat = r_hat_all[context]
            else:
                r_hat = estimator.predict(jax.random.fold_in(k_est, context), est, context,
                                          means_row, params.oracle)
                r_hat_all = r_hat[None, :]
            row = (lambda x: x[0]) if num_contexts == 1 else (lambda x: x[context])
            inputs = pol_lib.PolicyInputs(r_hat=r_hat, counts=row(est.counts),
                                          sums=row(est.sums), gains=est.gains,
                                          t=(t + 1).astype(jnp.int32))
            k_pol = jax.random.fold_in(key_pol, t) if needs_pol_noise else key_pol
            probs = pol_lib.policy_probs(config.policy, k_pol, inputs, alpha, params)
            arm = pol_lib.sample_icdf(u_arm, probs)
            reward = (u_env[1] < means_row[arm]).astype(dtype)
            # ---- regret accounting
            best_here = jnp.max(means_row)
            r_arm = means_row[arm]
            r_pi = jnp.dot(probs, means_row)
            regret, regret_err = kahan_add(carry.regret, carry.regret_err, jnp.stack(
                [best_here - r_arm, mu_star - r_arm, best_here - r_pi, mu_star - r_pi]))
            comp, comp_err = kahan_add(carry.compensator, carry.compensator_err, probs)
            diag = carry.diag
            if config.diagnostics:
                err = jnp.abs(r_hat - means_row)
                inv_sqrt = 1.0 / jnp.sqrt(est.arm_counts.astype(dtype) + 1.0)
                r_bar = problem.context_probs @ r_hat_all  # [K]
                others = jnp.where(jnp.arange(num_arms) == a_star, -jnp.inf, r_bar)
                misid = (r_bar[a_star] <= jnp.max(others)).astype(dtype)
                misid_strict = (r_bar[a_star] < jnp.max(others) - 1e-12).astype(dtype)
                diag = diag + jnp.stack([
                    err[a_star], jnp.dot(probs, err), err[arm],
                    inv_sqrt[a_star], jnp.dot(probs, inv_sqrt), inv_sqrt[arm],
                    misid, pol_lib.entropy(probs), jnp.sum(inv_sqrt), misid_strict])
            new_est = estimator.update(est, context, arm, reward, jnp.maximum(probs[arm], 1e-30))
            return _Carry(new_est, regret, regret_err, comp, comp_err,
                          jnp.minimum(carry.min_prob, jnp.min(probs)), diag)

        def segment(carry: _Carry, bounds):
            lo, hi = bounds
            carry = jax.lax.fori_loop(lo, hi, round_body, carry)
            out = (carry.regret - carry.regret_err, carry.est.arm_counts,
                   carry.compensator - carry.compensator_err, carry.min_prob, carry.diag)
            return carry, out

        carry0 = _Carry(
            est=estimator.init(num_contexts, num_arms, dtype),
            regret=jnp.zeros((4,), dtype),
            regret_err=jnp.zeros((4,), dtype),
            compensator=jnp.zeros((num_arms,), dtype),
            compensator_err=jnp.zeros((num_arms,), dtype),
            min_prob=jnp.asarray(1.0, dtype),
            diag=jnp.zeros((num_diag,), dtype),
        )
        _, (regret, counts, comp, min_prob, diag) = jax.lax.scan(
            segment, carry0, (jnp.asarray(starts), jnp.asarray(ends)))
        diag_out = Diagnostics(*[diag[:, i] for i in range(num_diag)]) if config.diagnostics else None
        return RunOutput(regret=regret[:, 0], regret_paper=regret[:, 1], regret_rb=regret[:, 2],
                         regret_rb_paper=regret[:, 3], counts=counts, compensator=comp,
                         min_prob=min_prob, diag=diag_out)

    return run


def seed_keys(root: Key, num_seeds: int, start: int = 0) -> Array:
    """Per-seed keys ``fold_in(root, i)`` for i in [start, start + num_seeds). Returns [S]."""
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(
        jnp.arange(start, start + num_seeds, dtype=jnp.uint32))
