"""Algorithm 1 for grasping: online fine-tuning of the quality network by SERN and its peers.

One *round* (the paper's Section VI) for every (object, seed, policy) at once:

1. **exploration**: ``explore`` grasps, each on a fresh random resting pose of the object:
   depth image -> 64 candidates -> crops -> r̂ = θ's success probabilities -> the policy's
   distribution over the *valid* candidates -> one grasp -> a randomised trial -> reward,
   stored with its crop in the policy's own data set D;
2. **update**: θ is trained (optax, a few minibatch steps) on D ∪ C, C the shipped core set;
3. **evaluation**: ``evaluate`` greedy grasps on fresh poses (the paper's noisy 0/20/40/...%
   figure), plus a low-variance figure: the greedy grasp's success probability from
   ``eval_trials`` trials on each of ``eval_poses`` fixed poses per seed.

Round 0 evaluates θ0 before any learning (the baseline the paper's Table I leaves out).

Policies (choices come from :mod:`sern_jax.policies` with the candidates' validity mask):
``sern`` softmax(r̂/α) with the paper's α = 0.05; ``sern_log`` softmax with Algorithm 1's
α = α0/ln(T^p), T = rounds × explore; ``egreedy`` ε-greedy (ε = 0.1); ``greedy``.

Batching: everything from depth image to policy is one jitted call over objects × seeds ×
policies × grasps; the θ updates are one jitted call vmapped over the O × S × Q parameter
copies. Physics runs on the native MuJoCo backend (CPU) or MJX.

Common random numbers: within a seed, every policy sees the same poses, the same candidate
sets, the same policy uniform and the same trial randomisation (friction, mass, execution
error), so policy comparisons are paired. Keys: object ``o`` (by name, CRC32) and seed ``s``
use ``key_os = fold_in(fold_in(key(seed), crc32(name)), s)``; each stream below is
``fold_in(key_os, STREAM)``, then ``fold_in(., round)``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
import zlib
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from sern_jax import io
from sern_jax import policies as pol
from sern_jax import schedules, stats
from sern_jax.grasp import artifacts
from sern_jax.grasp import candidates as cand_lib
from sern_jax.grasp import context as context_lib
from sern_jax.grasp import crops as crops_lib
from sern_jax.grasp import depth as depth_lib
from sern_jax.grasp import objects as objects_lib
from sern_jax.grasp import quality_net as qn
from sern_jax.grasp import sim as sim_lib

__all__ = [
    "POLICIES",
    "OnlineConfig",
    "RoundResults",
    "object_key",
    "copies_network",
    "make_choose",
    "run",
    "run_fingerprint",
    "table_rows",
    "AskTell",
    "AskTellState",
]

POLICIES = ("sern", "sern_log", "egreedy", "greedy")
MJX_BATCH = 2048  # MJX trials per compiled call: one compile per object on a GPU
CHECKPOINT_VERSION = 3  # bump when the checkpoint's contents change (3: pseudo_regret)
EXPLORE_CONTEXT, EXPLORE_TRIAL, POLICY_UNIFORM, FIT = 0, 1, 2, 3
EVAL_CONTEXT, EVAL_TRIAL, EVAL_UNIFORM, LOWVAR_CONTEXT, LOWVAR_TRIAL = 4, 5, 6, 7, 8
ORACLE_TRIAL = 9


@dataclasses.dataclass(frozen=True)
class OnlineConfig:
    """The online learning experiment (defaults: the paper's Section VI setting).

    Attributes:
      policies: subset of ``POLICIES``.
      num_seeds: S independent runs per (object, policy).
      rounds: R rounds of exploration + update + evaluation.
      explore: grasps per exploration phase (paper: 20).
      evaluate: greedy grasps per evaluation phase (paper: 5).
      alpha: SERN's temperature (paper: 0.05).
      epsilon: ε of ε-greedy (paper: 0.1).
      alpha0, p: Algorithm 1's schedule α = α0/ln(T^p) for ``sern_log``.
      fit_steps, batch_size, learning_rate: the optax (Adam) update after each exploration.
      loss: ``"bce"`` (default) or ``"l1"`` (the printed Algorithm 1, a negative control).
      core_set: ``"dpp"`` (shipped), ``"random"`` (same size, uniform from D0's sample) or
        ``"none"``.
      eval_poses, eval_trials: the low-variance evaluation (0 poses = off).
      regret_trials: M > 0 turns on regret accounting: every valid candidate of every
        exploration context is simulated M times (the oracle r_a(s) ~ successes / M) and
        each round's pseudo-regret sum_e [max_a r_a(s_e) - sum_a pi(a|s_e) r_a(s_e)] is
        recorded per policy (costly: 64 x M trials per exploration grasp, shared by the
        policies). 0 = off.
      seed: root seed.
      backend: physics backend for trials.
    """

    policies: tuple[str, ...] = ("sern", "egreedy", "greedy")
    num_seeds: int = 5
    rounds: int = 5
    explore: int = 20
    evaluate: int = 5
    alpha: float = 0.05
    epsilon: float = 0.1
    alpha0: float = 1.0
    p: float = 0.3
    fit_steps: int = 40
    batch_size: int = 32
    learning_rate: float = 3e-4
    loss: str = "bce"
    core_set: str = "dpp"
    eval_poses: int = 4
    eval_trials: int = 8
    regret_trials: int = 0
    seed: int = 0
    backend: str = "native"

    def __post_init__(self):
        pols = tuple(self.policies)
        object.__setattr__(self, "policies", pols)
        if not pols:
            raise ValueError(f"policies must not be empty; choose from {POLICIES}")
        for name in pols:
            if name not in POLICIES:
                raise ValueError(f"unknown policy {name!r}; choose from {', '.join(POLICIES)}")
        if len(set(pols)) != len(pols):
            raise ValueError(f"policies must not repeat, got {pols}")
        for name in ("num_seeds", "rounds", "explore", "evaluate", "fit_steps", "batch_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("eval_poses", "eval_trials", "regret_trials"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        if self.num_seeds * self.rounds * self.explore > 10_000_000:
            raise ValueError("num_seeds x rounds x explore exceeds 10M grasps per object")
        if not (np.isfinite(self.alpha) and self.alpha > 0):
            raise ValueError(f"alpha must be > 0, got {self.alpha!r}")
        if not (np.isfinite(self.epsilon) and 0 <= self.epsilon <= 1):
            raise ValueError(f"epsilon must be in [0, 1], got {self.epsilon!r}")
        if not (np.isfinite(self.alpha0) and self.alpha0 > 0):
            raise ValueError(f"alpha0 must be > 0, got {self.alpha0!r}")
        if not (0 < self.p < 1):
            raise ValueError(f"p must be in (0, 1), got {self.p!r}")
        if not (np.isfinite(self.learning_rate) and self.learning_rate > 0):
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate!r}")
        if self.loss not in qn.LOSSES:
            raise ValueError(f"loss must be one of {qn.LOSSES}, got {self.loss!r}")
        if self.core_set not in ("dpp", "random", "none"):
            raise ValueError(f"core_set must be dpp, random or none, got {self.core_set!r}")
        if self.backend not in sim_lib.BACKENDS:
            raise ValueError(f"backend must be one of {sim_lib.BACKENDS}, got {self.backend!r}")
        if not 0 <= int(self.seed) < 2**31:
            raise ValueError(f"seed must be in [0, 2**31), got {self.seed}")
        if self.eval_trials == 0 and self.eval_poses > 0:
            raise ValueError("eval_trials must be >= 1 when eval_poses > 0")

    @property
    def horizon(self) -> int:
        """T of Algorithm 1's schedule: exploration grasps over the whole run."""
        return self.rounds * self.explore

    def policy_alpha(self, name: str) -> float:
        """The temperature a softmax policy uses (NaN for the others)."""
        if name == "sern":
            return float(self.alpha)
        if name == "sern_log":
            return float(schedules.alpha_of_horizon("log", self.horizon, self.alpha0, self.p))
        return float("nan")

    def fingerprint(self) -> str:
        d = dataclasses.asdict(self)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- keys


def object_key(root: jax.Array, name: str, seed_index: int) -> jax.Array:
    """The key of (object, seed): independent of which other objects run beside it."""
    return jax.random.fold_in(
        jax.random.fold_in(root, zlib.crc32(name.encode()) & 0x7FFFFFFF), seed_index)


def _stream(key_os: jax.Array, stream: int, round_index: int) -> jax.Array:
    return jax.random.fold_in(jax.random.fold_in(key_os, stream), round_index)


# ----------------------------------------------------------------------------- jitted steps


def _policy_probs(name: str, r_hat, valid, alpha, epsilon):
    if name in ("sern", "sern_log"):
        return pol.softmax_probs(r_hat, alpha, mask=valid)
    if name == "egreedy":
        return pol.epsilon_greedy_probs(r_hat, epsilon, mask=valid)
    return pol.greedy_probs(r_hat, mask=valid)


def make_choose(network, policies: tuple[str, ...], crop_config=crops_lib.CropConfig()):
    """The jitted step from depth images to chosen grasps, for every policy copy.

    Returns ``choose(params, depth, candidates, u, alphas, epsilon)``:
      params: network params with leading [Q] (one copy per policy);
      depth: [N, H, W] images; candidates: Candidates with leading [N] (K slots);
      u: [N] uniforms (shared by the policies: common random numbers);
      alphas: [Q] temperatures; epsilon: [].
    and returns (action [Q, N] int32 candidate index, -1 if no candidate is valid;
    r_hat [Q, N, K]; probs [Q, N, K]; crops image [N, K, S, S] and depth [N, K]).
    The caller vmaps it over objects and seeds.
    """

    def choose(params, depth, candidates, u, alphas, epsilon):
        crops = crops_lib.extract_batch(depth, candidates, crop_config)
        valid = candidates.valid
        actions, r_hats, probs_all = [], [], []
        for q, name in enumerate(policies):
            p_q = jax.tree.map(lambda x, q=q: x[q], params)
            r_hat = network.apply(p_q, crops.image, crops.depth)  # [N, K]
            probs = jax.vmap(lambda r, m: _policy_probs(name, r, m, alphas[q], epsilon))(
                r_hat, valid)
            actions.append(jax.vmap(lambda uu, pp, m: pol.sample_icdf(uu, pp, mask=m))(
                u, probs, valid))
            r_hats.append(r_hat)
            probs_all.append(probs)
        return jnp.stack(actions), jnp.stack(r_hats), jnp.stack(probs_all), crops

    return choose


@functools.lru_cache(maxsize=4)
def copies_network(config: qn.QualityNetConfig) -> qn.QualityNetwork:
    """θ0's network as the learner computes it: the same function and parameters, with
    convolutions as im2col matmuls (``qn.make_quality_network(conv="im2col")``), which
    run ~5x faster than XLA's convolution when vmapped over the O x S x Q parameter
    copies on CPU. :class:`AskTell` uses it too, so both make the same choices."""
    return qn.make_quality_network(config, conv="im2col")


@functools.lru_cache(maxsize=16)
def _batched_choose(network, policies, crop_config):
    # params [O, S, Q, ...]; depth [O, S, N, H, W]; candidates [O, S, N, K, ...];
    # u [O, S, N]; alphas [Q]; epsilon [].
    one = make_choose(network, policies, crop_config)
    per_seed = jax.vmap(one, (0, 0, 0, 0, None, None))
    return jax.jit(jax.vmap(per_seed, (0, 0, 0, 0, None, None)))


def _fit_settings(config: OnlineConfig) -> tuple:
    """What the compiled update depends on (not seeds, objects, α or policies)."""
    return (config.learning_rate, config.loss, config.batch_size, config.fit_steps)


def _fit_one(network, settings: tuple):
    """One copy's update: ``fit(key, params, opt_state, buffer, core)`` on D ∪ C."""
    learning_rate, loss, batch_size, fit_steps = settings
    optimizer = optax.adam(learning_rate)
    fit = qn.make_fit(network, optimizer, loss=loss, batch_size=batch_size,
                      num_steps=fit_steps)

    def one(key, params, opt_state, buffer, core):
        data = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), buffer, core)
        return fit(key, params, opt_state, data)

    return one, optimizer


@functools.lru_cache(maxsize=8)
def _batched_fit(network, settings: tuple):
    one, optimizer = _fit_one(network, settings)
    # keys [O, S]; params/opt_state [O, S, Q]; buffer [O, S, Q, cap]; core shared.
    over_q = jax.vmap(one, (None, 0, 0, 0, None))
    over_s = jax.vmap(over_q, (0, 0, 0, 0, None))
    return jax.jit(jax.vmap(over_s, (0, 0, 0, 0, None))), optimizer


# ----------------------------------------------------------------------------- results


class RoundResults(NamedTuple):
    """Success figures with axes [R + 1, O, Q, S] (round 0 = θ0 before learning)."""

    paper_eval: np.ndarray  # fraction of `evaluate` greedy grasps that succeeded
    lowvar_eval: np.ndarray  # mean greedy success probability over the fixed eval poses
    explore_success: np.ndarray  # fraction of exploration grasps that succeeded (round 0: NaN)
    explore_action: np.ndarray  # [R + 1, O, Q, S, E] chosen candidate slots (-1: none valid)
    # Expected successes lost to the best candidate over the round's exploration grasps,
    # under the policy's distribution and the oracle of `regret_trials` trials per
    # candidate (NaN: round 0, or accounting off).
    pseudo_regret: np.ndarray  # [R + 1, O, Q, S]


def table_rows(objects: list[str], policies: tuple[str, ...], paper_eval: np.ndarray,
               lowvar_eval: np.ndarray | None = None,
               pseudo_regret: np.ndarray | None = None) -> list[dict]:
    """Table I rows: per object and policy, round 1..R success mean ± std over seeds (%),
    Max over rounds and Imprv = (r_R - r_1)/r_1 (the paper's definition).

    ``std`` is the population standard deviation over seeds (ddof 0, as it always was);
    ``sd`` is the sample standard deviation (ddof 1) and ``se`` = sd / √S, the statistic
    the paper's Table I prints in parentheses (``experiments/paper_table1.py``); None
    with one seed."""
    rows = []
    for o, name in enumerate(objects):
        for q, policy in enumerate(policies):
            x = 100.0 * paper_eval[1:, o, q, :]  # [R, S]
            mean, std = x.mean(1), x.std(1)
            spread = stats.t_interval(x, axis=1)  # sd (ddof 1) and se over the seeds
            r1, rr = mean[0], mean[-1]
            row = {
                "object": name,
                "policy": policy,
                "theta0": float(100.0 * paper_eval[0, o, q, :].mean()),
                "rounds": [float(v) for v in mean],
                "std": [float(v) for v in std],
                "sd": [float(v) if np.isfinite(v) else None for v in spread.sd],
                "se": [float(v) if np.isfinite(v) else None for v in spread.se],
                "max": float(mean.max()),
                "imprv": float((rr - r1) / r1) if r1 > 0 else None,
            }
            if lowvar_eval is not None and np.isfinite(lowvar_eval).all():
                lv = 100.0 * lowvar_eval[:, o, q, :]
                row["lowvar_rounds"] = [float(v) for v in lv.mean(1)]
                row["lowvar_std"] = [float(v) for v in lv.std(1)]
            if pseudo_regret is not None and np.isfinite(pseudo_regret[1:]).all():
                pr = pseudo_regret[1:, o, q, :]  # [R, S]
                row["pseudo_regret"] = [float(v) for v in pr.mean(1)]
                row["pseudo_regret_std"] = [float(v) for v in pr.std(1)]
            rows.append(row)
    return rows


# ----------------------------------------------------------------------------- the run


def run_fingerprint(config: OnlineConfig, specs: list[objects_lib.ObjectSpec],
                    theta0) -> str:
    """What determines a run's results: the config, the objects (names and geometry, so
    the same mesh file at another scale is another run) and θ0."""
    objects = [(s.name, repr(s)) for s in specs]
    text = (f"v{CHECKPOINT_VERSION}" + config.fingerprint() + json.dumps(objects)
            + theta0.fingerprint)
    return hashlib.sha256(text.encode()).hexdigest()[:16]



def _contexts(key, spec, num, model, config=context_lib.ContextConfig()):
    """Contexts of one object as numpy (poses [n, 7], depth [n, H, W], candidates [n, K])."""
    ctx = context_lib.make_contexts(key, spec, num, config, model=model)
    return ctx.poses, ctx.depth, ctx.candidates


def _stack(items):
    return jax.tree.map(lambda *xs: np.stack(xs), *items)


def _seed_noise(simulator, keys, num) -> sim_lib.TrialNoise:
    """Trial noise of each seed's key, stacked: fields [S, num, ...]; trial j of seed s is
    ``sample_noise(keys[s], num)[j]``."""
    draws = [sim_lib.sample_noise(k, num, simulator.config) for k in keys]
    return sim_lib.TrialNoise(*(np.stack([np.asarray(d[f]) for d in draws])
                                for f in range(len(sim_lib.TrialNoise._fields))))


def _run_trials(simulators, grasps, poses, noise_keys, n_per_key, counts=None):
    """Runs every object's trials.

    grasps [O, S, Q, N, 4], poses [O, S, N, 7], noise_keys[o][s]: trial j of (o, s) uses
    ``sample_noise(noise_keys[o][s], N)[j]`` for every policy (common random numbers).
    Returns success [O, S, Q, N] bool.

    Policies that pick the same grasp in trial j of (o, s) share its pose and its noise, so
    their trials are the same simulation: each distinct (s, j, grasp) runs once and its
    outcome goes to every policy that chose it. MuJoCo is deterministic and a trial does
    not depend on the others in its batch, so this gives the same outcomes bit for bit as
    simulating every copy (tests/grasp/test_online.py checks both ways). ``counts``, a
    dict, accumulates ``requested`` and ``simulated`` trials.
    """
    num_o, num_s, num_q, num_n = grasps.shape[:4]
    out = np.zeros((num_o, num_s, num_q, num_n), bool)
    s_i, _, n_i = np.indices((num_s, num_q, num_n)).reshape(3, -1)
    for o, simulator in enumerate(simulators):
        noise = _seed_noise(simulator, noise_keys[o], n_per_key)  # [S, N, ...]
        flat = np.ascontiguousarray(grasps[o].reshape(-1, 4), np.float64)
        key = np.concatenate([s_i[:, None], n_i[:, None], flat.view(np.int64)], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        us, un = s_i[first], n_i[first]
        res = simulator.run_trials(
            flat[first], sim_lib.TrialNoise(*(a[us, un] for a in noise)),
            object_pose=poses[o][us, un])
        out[o] = res.success[inverse.reshape(-1)].reshape(num_s, num_q, num_n)
        if counts is not None:
            counts["requested"] = counts.get("requested", 0) + len(flat)
            counts["simulated"] = counts.get("simulated", 0) + len(first)
    return out


def run(
    config: OnlineConfig,
    specs: list[objects_lib.ObjectSpec],
    out_dir: str | Path,
    *,
    theta0: artifacts.Theta0 | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    context_config: context_lib.ContextConfig | None = None,
    trial_config: sim_lib.TrialConfig | None = None,
) -> dict:
    """Runs (or resumes) the online learning experiment; returns the results dict.

    ``context_config`` (scene physics such as the finger force and pad friction, depth
    noise) and ``trial_config`` (the trial's randomisation) choose the simulated world;
    None = the defaults every shipped result uses. A non-default world enters the run's
    fingerprint (the defaults leave existing fingerprints unchanged).

    The state after each finished round is saved to ``out_dir/checkpoint.npz``: rerunning
    the same command resumes after the last finished round and gives the same table.
    """
    out_dir = Path(out_dir)
    names = [s.name for s in specs]
    if not names:
        raise ValueError("no objects given")
    if len(set(names)) != len(names):
        raise ValueError(f"objects must be distinct, got {names}")
    theta0 = theta0 or artifacts.load_theta0()
    network = copies_network(theta0.network.config)
    core = artifacts.core_set_data(config.core_set, theta0)
    num_o, num_q, num_s = len(specs), len(config.policies), config.num_seeds
    num_r, num_e = config.rounds, config.explore
    fingerprint = run_fingerprint(config, specs, theta0)
    context_config = context_config or context_lib.ContextConfig()
    trial_config = trial_config or sim_lib.TrialConfig()
    if (context_config, trial_config) != (context_lib.ContextConfig(), sim_lib.TrialConfig()):
        fingerprint = hashlib.sha256(
            (fingerprint + repr(context_config) + repr(trial_config)).encode()).hexdigest()[:16]

    root = jax.random.key(config.seed)
    keys_os = [[object_key(root, n, s) for s in range(num_s)] for n in names]
    models = [context_lib.scene_model(spec, context_config) for spec in specs]
    simulators = [sim_lib.GraspSimulator(m, backend=config.backend, config=trial_config,
                                         mjx_batch=MJX_BATCH) for m in models]
    alphas = jnp.asarray([config.policy_alpha(n) for n in config.policies], jnp.float32)
    epsilon = jnp.float32(config.epsilon)
    choose = _batched_choose(network, config.policies, crops_lib.CropConfig())
    greedy = _batched_choose(network, ("greedy",) * num_q, crops_lib.CropConfig())
    fit, optimizer = _batched_fit(network, _fit_settings(config))

    # State: parameter copies [O, S, Q], optimiser states, buffers D [O, S, Q, R*E].
    tile = lambda x: jnp.broadcast_to(x, (num_o, num_s, num_q) + x.shape)  # noqa: E731
    params = jax.tree.map(tile, theta0.params)
    opt_state = jax.tree.map(tile, qn.init_opt_state(optimizer, theta0.params))
    cap = num_r * num_e
    crop = crops_lib.CropConfig().crop_size
    buffer = qn.TrainData(
        image=np.zeros((num_o, num_s, num_q, cap, crop, crop), np.float32),
        depth=np.zeros((num_o, num_s, num_q, cap), np.float32),
        label=np.zeros((num_o, num_s, num_q, cap), np.float32),
        weight=np.zeros((num_o, num_s, num_q, cap), np.float32),
    )
    shape = (num_r + 1, num_o, num_q, num_s)
    results = RoundResults(np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan),
                           np.full(shape + (num_e,), -1, np.int32), np.full(shape, np.nan))
    timings = {k: 0.0 for k in ("contexts", "choose", "trials", "update", "evaluate")}
    if config.regret_trials:
        timings["oracle"] = 0.0
    trial_counts = {"requested": 0, "simulated": 0}  # this invocation (not resumed rounds)
    start_round = 0

    ckpt = out_dir / "checkpoint.npz"
    if ckpt.exists():
        saved = io.load_npz(ckpt)
        if str(saved["fingerprint"]) != fingerprint:
            raise ValueError(f"{out_dir} holds a different learning run; choose another --out "
                             "or delete it")
        params = artifacts.tree_from_arrays(saved, params, "p")
        opt_state = artifacts.tree_from_arrays(saved, opt_state, "o")
        buffer = qn.TrainData(*(saved[f"buffer_{f}"] for f in qn.TrainData._fields))
        results = RoundResults(*(saved[f] for f in RoundResults._fields))
        start_round = int(saved["next_round"])
        log(f"resuming {out_dir} at round {start_round}")
    out_dir.mkdir(parents=True, exist_ok=True)

    # The fixed low-variance evaluation poses of each (object, seed).
    lowvar = None
    if config.eval_poses:
        lowvar = [[_contexts(_stream(keys_os[o][s], LOWVAR_CONTEXT, 0), specs[o],
                             config.eval_poses, models[o], context_config)
                   for s in range(num_s)]
                  for o in range(num_o)]

    from tqdm.auto import tqdm

    bar = tqdm(total=num_r + 1, initial=start_round, unit="round", desc="learn",
               disable=not progress)

    def evaluate(r, params):
        t = time.perf_counter()
        ev = [[_contexts(_stream(keys_os[o][s], EVAL_CONTEXT, r), specs[o], config.evaluate,
                         models[o], context_config) for s in range(num_s)]
              for o in range(num_o)]
        poses = np.stack([[e[0] for e in row] for row in ev])
        depth = np.stack([[e[1] for e in row] for row in ev])
        cands = _stack([_stack([e[2] for e in row]) for row in ev])
        u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (config.evaluate,))))(
            jnp.stack([jnp.stack([_stream(k, EVAL_UNIFORM, r) for k in row])
                       for row in keys_os])))
        action, *_ = greedy(params, depth, cands, u, alphas, epsilon)
        action = np.asarray(action)  # [O, S, Q, N]
        grasps = _gather(cands.grasps, action)
        success = _run_trials(simulators, grasps, poses,
                              [[_stream(k, EVAL_TRIAL, r) for k in row] for row in keys_os],
                              config.evaluate, trial_counts)
        success &= action >= 0
        results.paper_eval[r] = success.mean(-1).transpose(0, 2, 1)
        if lowvar is not None:
            poses = np.stack([[e[0] for e in row] for row in lowvar])
            depth = np.stack([[e[1] for e in row] for row in lowvar])
            cands = _stack([_stack([e[2] for e in row]) for row in lowvar])
            u0 = np.zeros(poses.shape[:3], np.float32)
            action, *_ = greedy(params, depth, cands, u0, alphas, epsilon)
            action = np.asarray(action)  # [O, S, Q, P]
            grasps = _gather(cands.grasps, action)  # [O, S, Q, P, 4]
            m = config.eval_trials
            rep_grasps = np.repeat(grasps, m, axis=3)
            rep_poses = np.repeat(poses, m, axis=2)
            success = _run_trials(
                simulators, rep_grasps, rep_poses,
                [[_stream(k, LOWVAR_TRIAL, r) for k in row] for row in keys_os],
                config.eval_poses * m, trial_counts)
            success = success.reshape(num_o, num_s, num_q, config.eval_poses, m)
            success &= (action >= 0)[..., None]
            results.lowvar_eval[r] = success.mean((-1, -2)).transpose(0, 2, 1)
        timings["evaluate"] += time.perf_counter() - t

    if start_round == 0:
        evaluate(0, params)
        _save(ckpt, fingerprint, params, opt_state, buffer, results, 1)
        start_round = 1
        bar.update(1)

    for r in range(start_round, num_r + 1):
        # 1. exploration
        t = time.perf_counter()
        ex = [[_contexts(_stream(keys_os[o][s], EXPLORE_CONTEXT, r), specs[o], num_e,
                         models[o], context_config) for s in range(num_s)]
              for o in range(num_o)]
        poses = np.stack([[e[0] for e in row] for row in ex])  # [O, S, E, 7]
        depth = np.stack([[e[1] for e in row] for row in ex])
        cands = _stack([_stack([e[2] for e in row]) for row in ex])
        timings["contexts"] += time.perf_counter() - t
        t = time.perf_counter()
        u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (num_e,))))(
            jnp.stack([jnp.stack([_stream(k, POLICY_UNIFORM, r) for k in row])
                       for row in keys_os])))
        action, _, probs, crops = choose(params, depth, cands, u, alphas, epsilon)
        action = np.asarray(action)  # [O, S, Q, E]
        timings["choose"] += time.perf_counter() - t
        t = time.perf_counter()
        grasps = _gather(cands.grasps, action)
        success = _run_trials(simulators, grasps, poses,
                              [[_stream(k, EXPLORE_TRIAL, r) for k in row] for row in keys_os],
                              num_e, trial_counts)
        success &= action >= 0
        timings["trials"] += time.perf_counter() - t
        results.explore_success[r] = success.mean(-1).transpose(0, 2, 1)
        results.explore_action[r] = action.transpose(0, 2, 1, 3)
        if config.regret_trials:
            t = time.perf_counter()
            oracle = _oracle(simulators, cands, poses, config.regret_trials,
                             [[_stream(k, ORACLE_TRIAL, r) for k in row] for row in keys_os],
                             trial_counts)  # [O, S, E, K]
            expected = (np.asarray(probs, np.float64) * oracle[:, :, None]).sum(-1)
            regret = oracle.max(-1)[:, :, None] - expected  # [O, S, Q, E]
            results.pseudo_regret[r] = regret.sum(-1).transpose(0, 2, 1)
            timings["oracle"] += time.perf_counter() - t
        # store (crop, reward) of each chosen grasp
        t = time.perf_counter()
        idx = np.maximum(action, 0)
        image = np.asarray(crops.image)  # [O, S, E, K, c, c]
        cdepth = np.asarray(crops.depth)  # [O, S, E, K]
        o_i, s_i, q_i, e_i = np.indices(action.shape)
        sl = slice((r - 1) * num_e, r * num_e)
        buffer.image[:, :, :, sl] = image[o_i, s_i, e_i, idx]
        buffer.depth[:, :, :, sl] = cdepth[o_i, s_i, e_i, idx]
        buffer.label[:, :, :, sl] = success
        buffer.weight[:, :, :, sl] = action >= 0
        # 2. update on D ∪ C
        fit_keys = jnp.stack([jnp.stack([_stream(k, FIT, r) for k in row]) for row in keys_os])
        params, opt_state, _ = fit(fit_keys, params, opt_state, buffer, core)
        jax.block_until_ready(params)
        timings["update"] += time.perf_counter() - t
        # 3. evaluation
        evaluate(r, params)
        _save(ckpt, fingerprint, params, opt_state, buffer, results, r + 1)
        bar.update(1)
    bar.close()
    rows = table_rows(names, config.policies, results.paper_eval,
                      results.lowvar_eval if config.eval_poses else None,
                      results.pseudo_regret if config.regret_trials else None)
    return {"table": rows, "results": results, "timings": timings,
            "trial_counts": trial_counts, "objects": names,
            "fingerprint": fingerprint, "config": config}


def _oracle(simulators, cands, poses, num_trials, noise_keys, counts):
    """Success probabilities r_a(s) of every candidate of every context: [O, S, N, K].

    cands: Candidates with leading [O, S, N]; poses [O, S, N, 7]. Trial j of context n of
    (o, s) uses ``sample_noise(noise_keys[o][s], N * M)[n * M + j]`` for every candidate
    (common random numbers across candidates, as ``success_probability``); invalid
    candidates get 0.
    """
    valid = np.asarray(cands.valid, bool)
    grasps = np.asarray(cands.grasps, np.float64)
    num_o, num_s, num_n, num_k = valid.shape
    m = num_trials
    out = np.zeros(valid.shape)
    for o, simulator in enumerate(simulators):
        s_i, n_i, k_i = np.nonzero(valid[o])
        if not len(s_i):
            continue
        noise = _seed_noise(simulator, noise_keys[o], num_n * m)  # [S, N * M, ...]
        rows_s = np.repeat(s_i, m)
        rows_t = (n_i[:, None] * m + np.arange(m)[None]).reshape(-1)
        res = simulator.run_trials(
            np.repeat(grasps[o][s_i, n_i, k_i], m, axis=0),
            sim_lib.TrialNoise(*(a[rows_s, rows_t] for a in noise)),
            object_pose=np.repeat(np.asarray(poses[o])[s_i, n_i], m, axis=0))
        out[o][s_i, n_i, k_i] = res.success.reshape(-1, m).mean(1)
        counts["requested"] += len(rows_s)
        counts["simulated"] += len(rows_s)
    return out


def _gather(grasps, action):
    """grasps [O, S, N, K, 4], action [O, S, Q, N] -> chosen grasps [O, S, Q, N, 4]
    (an invalid choice, -1, takes slot 0: its trial runs but its outcome is discarded)."""
    g = np.asarray(grasps)
    o, s, q, n = np.indices(action.shape)
    return g[o, s, n, np.maximum(action, 0)]


def _save(path, fingerprint, params, opt_state, buffer, results, next_round):
    arrays = artifacts.tree_arrays(params, "p") | artifacts.tree_arrays(opt_state, "o")
    arrays.update({f"buffer_{f}": np.asarray(getattr(buffer, f)) for f in buffer._fields})
    arrays.update({f: np.asarray(getattr(results, f)) for f in results._fields})
    io.save_npz(path, fingerprint=np.asarray(fingerprint), next_round=np.asarray(next_round),
                **arrays)


# ----------------------------------------------------------------------------- ask / tell


class AskTellState(NamedTuple):
    """Everything a robot loop must keep between grasps (save it with :meth:`AskTell.save`)."""

    params: qn.QualityParams  # the current network θ
    opt_state: object  # Adam state over params.net
    buffer: qn.TrainData  # D: [rounds * explore] rows (weight 0 = empty)
    round_index: int  # 1-based round of the next grasp
    grasp_index: int  # grasps told in this round
    pending: tuple | None  # (slot, crop image [S, S], crop depth []) of the last ask


class AskTell:
    """Algorithm 1 for a real robot loop: ``ask`` for a grasp, execute it, ``tell`` the reward.

    One learner = one (object, seed, policy) copy of :func:`run`, with the same keys: given
    the same depth images it asks for the same grasps and, told the same rewards, makes the
    same updates as the batched run (tests/grasp/test_asktell.py drives both with the
    simulator). After every ``config.explore`` tells it updates θ on D ∪ C.

    Args:
      config: the experiment settings (policies, rounds, explore, α, ε, fit settings).
      policy: one of ``POLICIES``.
      object_name: the name whose CRC32 keys the streams (as in :func:`run`).
      seed_index: which seed of :func:`run` this learner is.
      theta0: the pretrained network (default: the shipped one).
    """

    def __init__(self, config: OnlineConfig, policy: str = "sern", object_name: str = "object",
                 seed_index: int = 0, theta0: artifacts.Theta0 | None = None):
        if policy not in POLICIES:
            raise ValueError(f"unknown policy {policy!r}; choose from {', '.join(POLICIES)}")
        if seed_index < 0:
            raise ValueError(f"seed_index must be >= 0, got {seed_index}")
        self.config, self.policy = config, policy
        self.theta0 = theta0 or artifacts.load_theta0()
        self.network = copies_network(self.theta0.network.config)
        self.key_os = object_key(jax.random.key(config.seed), object_name, seed_index)
        self.core = artifacts.core_set_data(config.core_set, self.theta0)
        self.context_config = context_lib.ContextConfig()
        self.camera = None
        self._choose = jax.jit(make_choose(self.network, (policy,), crops_lib.CropConfig()))
        self._greedy = jax.jit(make_choose(self.network, ("greedy",), crops_lib.CropConfig()))
        one, self.optimizer = _fit_one(self.network, _fit_settings(config))
        self._fit = jax.jit(one)
        self._sample = jax.jit(lambda k, d, p: cand_lib.sample(
            self.context_config.candidates, k, d, p))
        self.alpha = jnp.asarray([config.policy_alpha(policy)], jnp.float32)

    def init(self) -> AskTellState:
        """θ0, an empty D, round 1."""
        cap = self.config.rounds * self.config.explore
        s = self.network.config.crop_size
        buffer = qn.TrainData(np.zeros((cap, s, s), np.float32), np.zeros(cap, np.float32),
                              np.zeros(cap, np.float32), np.zeros(cap, np.float32))
        return AskTellState(self.theta0.params,
                            qn.init_opt_state(self.optimizer, self.theta0.params),
                            buffer, 1, 0, None)

    def candidates(self, state: AskTellState, depth_image, camera=None):
        """The 64 candidates the learner samples on ``depth_image`` for its next grasp (the
        same key as :func:`run`'s context of that grasp)."""
        camera = camera if camera is not None else depth_lib.overhead_params(
            self.context_config.camera)
        key_ctx = jax.random.fold_in(
            _stream(self.key_os, EXPLORE_CONTEXT, state.round_index), state.grasp_index)
        key = jax.random.fold_in(key_ctx, context_lib.CANDIDATE_STREAM)
        return jax.tree.map(np.asarray, self._sample(key, jnp.asarray(depth_image), camera))

    def ask(self, state: AskTellState, depth_image, candidates=None, camera=None):
        """The grasp to try on ``depth_image`` [H, W] (planar depth, metres).

        Returns:
          (grasp [4] (x, y, z, θ) world frame, state); grasp is None when no candidate is
          valid (nothing to try: take another image).
        """
        if state.round_index > self.config.rounds:
            raise ValueError(f"all {self.config.rounds} rounds are done")
        if state.pending is not None:
            raise ValueError("tell() the reward of the last grasp before asking again")
        depth_image = np.asarray(depth_image, np.float32)
        if depth_image.ndim != 2 or not np.all(np.isfinite(depth_image)):
            raise ValueError(f"depth_image must be a finite [H, W] array, got shape "
                             f"{depth_image.shape}")
        cands = candidates if candidates is not None else self.candidates(
            state, depth_image, camera)
        u = jax.random.uniform(_stream(self.key_os, POLICY_UNIFORM, state.round_index),
                               (self.config.explore,))[state.grasp_index]
        params = jax.tree.map(lambda x: x[None], state.params)
        batch = jax.tree.map(lambda x: jnp.asarray(x)[None], cands)
        action, _, _, crops = self._choose(params, jnp.asarray(depth_image)[None], batch,
                                           u[None], self.alpha, jnp.float32(self.config.epsilon))
        slot = int(action[0, 0])
        if slot < 0:
            # No valid candidate: this grasp slot passes with nothing stored, exactly as in
            # the batched run (weight 0), so the two stay in step.
            return None, self._advance(state._replace(pending=None), None, 0.0)
        pending = (slot, np.asarray(crops.image[0, slot]), float(crops.depth[0, slot]))
        return np.asarray(cands.grasps[slot]), state._replace(pending=pending)

    def tell(self, state: AskTellState, grasp, reward) -> AskTellState:
        """Stores (crop, reward) of the asked grasp; updates θ after each round's last one."""
        if state.pending is None:
            raise ValueError("tell() without a pending ask()")
        if reward not in (0, 1, 0.0, 1.0, True, False):
            raise ValueError(f"reward must be 0 or 1, got {reward!r}")
        return self._advance(state._replace(pending=None), state.pending, float(reward))

    def _advance(self, state: AskTellState, stored, reward: float) -> AskTellState:
        """Stores (crop, reward) in this grasp's row (nothing when ``stored`` is None), moves
        to the next grasp, and updates θ on D ∪ C after the round's last one."""
        row = (state.round_index - 1) * self.config.explore + state.grasp_index
        buf = qn.TrainData(*(np.array(a) for a in state.buffer))
        if stored is not None:
            _, image, depth = stored
            buf.image[row], buf.depth[row] = image, depth
            buf.label[row], buf.weight[row] = reward, 1.0
        state = state._replace(buffer=buf, grasp_index=state.grasp_index + 1)
        if state.grasp_index == self.config.explore:
            key = _stream(self.key_os, FIT, state.round_index)
            params, opt_state, _ = self._fit(key, state.params, state.opt_state, buf, self.core)
            state = state._replace(params=params, opt_state=opt_state, grasp_index=0,
                                   round_index=state.round_index + 1)
        return state

    def best(self, state: AskTellState, depth_image, candidates=None, camera=None):
        """The greedy grasp (evaluation: no exploration, nothing stored)."""
        cands = candidates if candidates is not None else self.candidates(
            state, depth_image, camera)
        params = jax.tree.map(lambda x: x[None], state.params)
        batch = jax.tree.map(lambda x: jnp.asarray(x)[None], cands)
        action, *_ = self._greedy(params, jnp.asarray(depth_image, jnp.float32)[None], batch,
                                  jnp.zeros(1), self.alpha, jnp.float32(0))
        slot = int(action[0, 0])
        return None if slot < 0 else np.asarray(cands.grasps[slot])

    def identity(self) -> str:
        """What a saved state belongs to: config, policy, object/seed keys and θ0."""
        text = "|".join([self.config.fingerprint(), self.policy,
                         str(jax.random.key_data(self.key_os).tolist()),
                         self.theta0.fingerprint])
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def save(self, state: AskTellState, path: str | Path) -> None:
        """Writes the state to ``path`` (.npz, atomically), tagged with :meth:`identity`."""
        arrays = (artifacts.tree_arrays(state.params, "p")
                  | artifacts.tree_arrays(state.opt_state, "o"))
        arrays.update({f"buffer_{f}": np.asarray(getattr(state.buffer, f))
                       for f in qn.TrainData._fields})
        if state.pending is not None:
            arrays.update(pending_slot=np.asarray(state.pending[0]),
                          pending_image=state.pending[1], pending_depth=np.asarray(state.pending[2]))
        io.save_npz(path, round_index=np.asarray(state.round_index),
                    grasp_index=np.asarray(state.grasp_index),
                    identity=np.asarray(self.identity()), **arrays)

    def load(self, path: str | Path) -> AskTellState:
        """Reads a state written by :meth:`save` (for this learner's network)."""
        saved = io.load_npz(path)
        if str(saved.get("identity", "")) != self.identity():
            raise ValueError(f"{path} was saved by a learner with another config, policy, "
                             "object, seed or θ0; make the learner with the settings it was "
                             "saved with")
        template = self.init()
        params = artifacts.tree_from_arrays(saved, template.params, "p")
        opt_state = artifacts.tree_from_arrays(saved, template.opt_state, "o")
        buffer = qn.TrainData(*(saved[f"buffer_{f}"] for f in qn.TrainData._fields))
        pending = None
        if "pending_slot" in saved:
            pending = (int(saved["pending_slot"]), saved["pending_image"],
                       float(saved["pending_depth"]))
        return AskTellState(params, opt_state, buffer, int(saved["round_index"]),
                            int(saved["grasp_index"]), pending)
