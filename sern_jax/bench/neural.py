"""Throughput of the neural runner, beside a per-seed Python loop over the same JAX functions.

Workload: the wheel bandit (δ = 0.95 by default), one learner of the registry
(Neural-Linear Thompson by default) on the MLP of :mod:`sern_jax.engine.networks`, updates every
``update_every`` rounds, S seeds × T rounds. Two ways of running it, in one process:

* ``batched``: the program :func:`sern_jax.engine.neural.run_seeds` runs, ``jit(vmap(scan))``
  over seeds, in calls of ``chunk_size`` seeds (default: all in one call), one at a time;
  compile time is measured separately (``.lower().compile()``) and excluded; the figure is
  the median of ``repeats`` runs (padded seeds of a last partial chunk count as computed).
* ``python_loop``: the reference a researcher writes first: one seed at a time, a Python
  loop over rounds calling the jitted ``learner.act`` on each decision and the jitted
  ``learner.update`` after each phase, with the same environment draws (the runner's
  streams); run on ``loop_seeds`` seeds × ``loop_rounds`` rounds (its rate does not depend
  on S, and its cost per round grows with t only through the update's buffer, which has a
  fixed size T).

Both report seed-rounds per second; the ratio is the speed-up. The loop reproduces the
runner's decisions (tests check the actions agree), so the two time the same work.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import contextual_problems as cp
from sern_jax.engine import networks
from sern_jax.engine import neural as nr
from sern_jax.infra import hosts
from sern_jax.learners import base, registry
from sern_jax.engine.simulate import AGENT_STREAM, ENV_STREAM, ROUNDS_STREAM, seed_keys

__all__ = ["NeuralBenchConfig", "build", "python_loop", "run_bench", "machine"]


@dataclasses.dataclass(frozen=True)
class NeuralBenchConfig:
    """The benchmark workload (flags of ``sern bench neural``)."""

    learner: str = "neural_lints"
    delta: float = 0.95
    num_seeds: int = 1000
    horizon: int = 5000
    update_every: int = 50
    hidden: tuple[int, ...] = (50,)
    fit_steps: int = 20
    batch_size: int = 64
    learning_rate: float = 1e-2
    repeats: int = 1
    loop_seeds: int = 2
    loop_rounds: int = 500
    chunk_size: int | None = None

    def __post_init__(self):
        for flag, v, low in (("--seeds", self.num_seeds, 1), ("--horizon", self.horizon, 1),
                             ("--update-every", self.update_every, 1),
                             ("--fit-steps", self.fit_steps, 1),
                             ("--batch-size", self.batch_size, 1),
                             ("--repeats", self.repeats, 0), ("--loop-seeds", self.loop_seeds, 0),
                             ("--loop-rounds", self.loop_rounds, 1)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ValueError(f"{flag} must be an integer >= {low}, got {v!r}")
        if self.horizon % self.update_every:
            raise ValueError(f"--horizon {self.horizon} must be a multiple of --update-every "
                             f"{self.update_every}")
        if self.loop_rounds % self.update_every:
            raise ValueError(f"--loop-rounds {self.loop_rounds} must be a multiple of "
                             f"--update-every {self.update_every}")
        if self.loop_rounds > self.horizon:
            raise ValueError(f"--loop-rounds must be <= --horizon, got {self.loop_rounds}")
        if self.chunk_size is not None and (isinstance(self.chunk_size, bool)
                                            or self.chunk_size < 1):
            raise ValueError(f"--chunk-size must be an integer >= 1, got {self.chunk_size!r}")
        registry.check_names((self.learner,), "--learner")


def build(config: NeuralBenchConfig):
    """(problem, model, learner, run config); validates before anything compiles."""
    problem = cp.wheel(config.delta)
    model = networks.mlp_model(problem.num_arms, problem.context_dim, config.hidden)
    train = base.TrainConfig(horizon=config.horizon, fit_steps=config.fit_steps,
                             batch_size=config.batch_size, learning_rate=config.learning_rate)
    learner = registry.make(config.learner, model, train)
    run_cfg = nr.NeuralRunConfig(horizon=config.horizon, update_every=config.update_every,
                                 num_checkpoints=8)
    return problem, model, learner, run_cfg


def python_loop(problem, model, learner, update_every: int, key, num_rounds: int):
    """One seed, a Python loop over rounds: jitted ``act`` per decision, jitted ``update``
    per phase, the runner's random streams. Returns (actions [num_rounds], Σ regret_rb)."""
    num_arms = problem.num_arms
    key_env = jax.random.fold_in(jax.random.fold_in(key, ENV_STREAM), ROUNDS_STREAM)
    key_agent = jax.random.fold_in(key, AGENT_STREAM)
    key_u = jax.random.fold_in(key_agent, ROUNDS_STREAM)
    key_act = jax.random.fold_in(key_agent, nr.ACT_STREAM)
    key_update = jax.random.fold_in(key_agent, nr.UPDATE_STREAM)
    key_init = jax.random.fold_in(key_agent, nr.INIT_STREAM)
    theta0 = model.init(jax.random.fold_in(key, nr.MODEL_STREAM))
    state = learner.init(key_init, theta0, nr._empty_core_set(problem))
    env = _env_fn(problem)
    act = jax.jit(learner.act)
    update = jax.jit(learner.update)
    valid = jnp.ones((num_arms,), bool)
    actions, regret = [], 0.0
    for p in range(num_rounds // update_every):
        rows, acts, rews = [], [], []
        for t in range(p * update_every, (p + 1) * update_every):
            z, rewards, means, u = env(key_env, key_u, jnp.int32(t))
            obs = base.Obs((z,), valid, u, jnp.int32(t))
            a, probs, _ = act(jax.random.fold_in(key_act, t), state, obs)
            a = int(a)
            regret += float(jnp.max(means) - jnp.dot(probs, means))
            rows.append(z[a])
            acts.append(a)
            rews.append(problem.scale_reward(rewards[a]))
        actions += acts
        batch = base.Batch((jnp.stack(rows),), jnp.asarray(acts, jnp.int32), jnp.stack(rews))
        state = update(jax.random.fold_in(key_update, p), state, batch)
    jax.block_until_ready(state)
    return np.asarray(actions), regret


_ENV_CACHE: dict = {}


def _env_fn(problem):
    """The runner's environment draws for round t, jitted once per problem."""
    cached = _ENV_CACHE.get(id(problem.sample_context))
    if cached is not None and cached[0] is problem.sample_context:
        return cached[1]
    num_arms, d = problem.num_arms, problem.context_dim
    eye = jnp.eye(num_arms, dtype=jnp.float32)

    @jax.jit
    def env(key_env, key_u, t):
        key_t = jax.random.fold_in(key_env, t)
        x = problem.sample_context(jax.random.fold_in(key_t, 0))
        rewards = problem.sample_rewards(jax.random.fold_in(key_t, 1), x)
        z = jnp.concatenate([jnp.broadcast_to(x.astype(jnp.float32), (num_arms, d)), eye], 1)
        u = jax.random.uniform(jax.random.fold_in(key_u, t), (), jnp.float32)
        return z, rewards, problem.expected_rewards(x), u

    _ENV_CACHE[id(problem.sample_context)] = (problem.sample_context, env)
    return env


def machine() -> dict:
    """What the figures were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    cores = hosts.usable_cores()
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None
    return {"cpu": cpu, "cores_usable": cores, "load_average_1min": load,
            "backend": jax.default_backend(),
            "devices": [str(d) for d in jax.devices()]}


def run_bench(config: NeuralBenchConfig, log=None) -> dict:
    """Runs both paths; returns a JSON-ready dict (seed-rounds/s, compile time, speed-up)."""
    problem, model, learner, run_cfg = build(config)
    run = nr.make_run(run_cfg, problem, learner, model)
    out = {"workload": {**dataclasses.asdict(config), "problem": problem.name},
           "machine": machine(), "jax": jax.__version__}
    # ---- batched: compile once (timed separately), then repeats of the compiled calls
    chunk = config.chunk_size or config.num_seeds
    t0 = time.perf_counter()
    compiled = nr._batched(run).lower(
        jax.ShapeDtypeStruct((chunk,), jax.random.key(0).dtype)).compile()
    out["batched_compile_s"] = time.perf_counter() - t0
    root = jax.random.key(0)
    starts = range(0, config.num_seeds, chunk)
    keys = [jax.block_until_ready(seed_keys(root, chunk, a)) for a in starts]
    if config.repeats:
        times, cpu = [], []
        for _ in range(config.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            results = [compiled(k) for k in keys]  # one call at a time (run_seeds' default)
            jax.block_until_ready(results)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            if log:
                log(f"batched: {times[-1]:.1f} s")
        wall = statistics.median(times)
        regret = np.concatenate([np.asarray(r.regret_rb[:, -1]) for r in results])
        out["batched"] = {"seconds": wall, "seed_rounds_per_s":
                          len(starts) * chunk * config.horizon / wall,
                          "cpu_seconds": statistics.median(cpu),
                          "seeds_computed": len(starts) * chunk, "chunk": chunk,
                          "runs": len(times),
                          "regret_rb_T_mean": float(regret[:config.num_seeds].mean())}
    # ---- per-seed Python loop over the same jitted act/update
    if config.loop_seeds:
        keys = seed_keys(jax.random.key(0), config.loop_seeds)
        python_loop(problem, model, learner, config.update_every, keys[0],
                    config.update_every)  # compile act / update / env (not timed)
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(config.loop_seeds):
            python_loop(problem, model, learner, config.update_every, keys[i],
                        config.loop_rounds)
        wall = time.perf_counter() - t0
        out["python_loop"] = {"seconds": wall, "cpu_seconds": time.process_time() - c0,
                              "seeds": config.loop_seeds,
                              "rounds": config.loop_rounds,
                              "seed_rounds_per_s": config.loop_seeds * config.loop_rounds / wall}
        if log:
            log(f"python loop: {wall:.1f} s")
    try:  # the 2 cores are shared: the load over the run, beside the start's
        out["load_average_end"] = list(os.getloadavg())
    except OSError:
        pass
    if "batched" in out and "python_loop" in out:
        out["speedup"] = (out["batched"]["seed_rounds_per_s"]
                          / out["python_loop"]["seed_rounds_per_s"])
    return out
