"""Algorithm 1 for grasping, batched: any registered learner fine-tunes θ0 on every object ×
seed at once (``sern grasp learn``).

One *round* (the paper's Section VI) for every (object, seed, learner):

1. **exploration**: ``explore`` grasps, each on a fresh random resting pose of the object:
   depth image -> 64 candidates -> crops -> ``learner.act`` (its distribution over the valid
   candidates, from :mod:`sern_jax.core.policies`) -> one grasp -> a randomised trial -> reward;
2. **update**: ``learner.update`` with the phase's (crops, actions, rewards) (Algorithm 1's
   learners: append to D, then optax minibatch steps on D ∪ C, C the shipped core set);
3. **evaluation**: ``evaluate`` greedy grasps on fresh poses (the paper's noisy 0/20/40/...%
   figure), plus a low-variance figure: the greedy grasp's success probability from
   ``eval_trials`` trials on each of ``eval_poses`` fixed poses per seed. Greedy is the
   argmax of the learner's ``predict`` (the network's r̂ for Algorithm 1's learners).

Round 0 evaluates θ0 before any learning (the baseline the paper's Table I leaves out).

Learners are ``sern_jax.learners`` triples, named in ``OnlineConfig.policies`` (the registry:
``sern``, ``sern_log``, ``egreedy``, ``greedy``, ...). Each learner's ``act`` and ``update`` are
one jitted call vmapped over the O × S copies (learners with the same update share its
compile); contexts, crops and trials are shared by the learners. Physics runs on the native
MuJoCo backend (CPU) or MJX.

Overlap: round r's evaluation needs only the states after round r's update, and round r + 1's
exploration needs the same states and nothing the evaluation makes, so the evaluation runs in
a thread of its own while the main thread explores and updates round r + 1 (their trials share
the native trial workers, their forward passes the device). Every output is keyed by stream,
pose and grasp, never by order, so the results are those of running the phases one after
another, bit for bit (tests/grasp/test_runner.py). The checkpoint is written when a round's
evaluation ends and holds that round and the ones before it only.

Common random numbers: within a seed, every learner sees the same poses, the same candidate
sets, the same inverse-CDF uniform and the same trial randomisation (friction, mass,
execution error), so comparisons are paired. Keys: object ``o`` (by name, CRC32) and seed
``s`` use ``key_os = fold_in(fold_in(key(seed), crc32(name)), s)``; each stream below is
``fold_in(key_os, STREAM)``, then ``fold_in(., round)`` (then ``fold_in(., grasp)`` for
``ACT``). The ask/tell robot loop (:mod:`sern_jax.grasp.online.asktell`) uses the same keys.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import hashlib
import json
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.infra import io
from sern_jax.analysis import stats
from sern_jax.core import policies as pol
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import crops as crops_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.model import quality_net as qn
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import base as lbase
from sern_jax.learners import registry

__all__ = [
    "LearnerError",
    "OnlineConfig",
    "RoundResults",
    "copies_network",
    "core_data",
    "make_learner",
    "object_key",
    "quality_model",
    "run",
    "run_fingerprint",
    "table_rows",
    "train_config",
]

MJX_BATCH = 2048  # MJX trials per compiled call: one compile per object on a GPU
CHECKPOINT_VERSION = 5  # bump when the checkpoint's contents change (5: results + rewards,
#                        learner states rebuilt by replaying the updates on resume)
EXPLORE_CONTEXT, EXPLORE_TRIAL, POLICY_UNIFORM, FIT = 0, 1, 2, 3
EVAL_CONTEXT, EVAL_TRIAL, EVAL_UNIFORM, LOWVAR_CONTEXT, LOWVAR_TRIAL = 4, 5, 6, 7, 8
ORACLE_TRIAL = 9  # the oracle's selection trials (its argmax)
INIT, ACT = 10, 11  # the learner's init key and act keys (unused by SERN, ε-greedy, greedy)
ORACLE_VALUE = 12  # the oracle's valuation trials, independent of the selection

# OnlineConfig fields that are learner hyperparameters (the registry's configs read them)
_HYPER_FIELDS = ("alpha", "epsilon", "alpha0", "p")


@dataclasses.dataclass(frozen=True)
class OnlineConfig:
    """The online learning experiment (defaults: the paper's Section VI setting).

    Attributes:
      policies: learner names (``registry.names()``).
      num_seeds: S independent runs per (object, learner).
      rounds: R rounds of exploration + update + evaluation.
      explore: grasps per exploration phase (paper: 20).
      evaluate: greedy grasps per evaluation phase (paper: 5).
      alpha: SERN's temperature (paper: 0.05).
      epsilon: ε of ε-greedy (paper: 0.1).
      alpha0, p: Algorithm 1's schedule α = α0/ln(T^p) for ``sern_log``.
      hyper: other learners' hyperparameters as sorted (name, value) pairs (fields of their
        registry configs; missing ones take the configs' defaults).
      fit_steps, batch_size, learning_rate: the optax (Adam) update after each exploration.
      loss: ``"bce"`` (default) or ``"l1"`` (the printed Algorithm 1, a negative control).
      core_set: ``"dpp"`` (shipped), ``"random"`` (same size, uniform from D0's sample) or
        ``"none"``.
      eval_poses, eval_trials: the low-variance evaluation (0 poses = off).
      regret_trials: M > 0 turns on regret accounting: every valid candidate of every
        exploration context is simulated M times to choose the best candidate a* (the
        argmax of its frequencies) and M more, independent, times to value every candidate
        (v_a ~ successes / M); each round's pseudo-regret sum_e [v_{a*}(s_e) -
        sum_a pi(a|s_e) v_a(s_e)] is recorded per learner (``stats.oracle_regret``: the
        max and its value from the same trials would add the upward bias of a maximum of
        noisy frequencies). Costly: 2 x 64 x M trials per exploration grasp, shared by the
        learners. 0 = off.
      regret_grasps: g > 0 runs the oracle on the first g exploration grasps of each phase
        only and records (explore / g) x their pseudo-regret: an unbiased estimate of the
        phase's (its grasps are i.i.d.: fresh poses, one learner state per phase) at g /
        explore of the oracle's cost. 0 = every grasp.
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
    regret_grasps: int = 0
    seed: int = 0
    backend: str = "native"
    hyper: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "policies", registry.check_names(self.policies, "--policies"))
        known = registry.hyperparameters()
        hyper = dict(self.hyper)
        for k in hyper:
            if k not in known or k in _HYPER_FIELDS:
                raise ValueError(f"hyper: {k!r} is not another learner's hyperparameter; "
                                 f"known: {', '.join(sorted(set(known) - set(_HYPER_FIELDS)))}")
        # canonical: defaults dropped, sorted (the same run has one fingerprint)
        hyper = tuple(sorted((str(k), v) for k, v in hyper.items()
                             if not (type(v) is type(known[k].default)
                                     and v == known[k].default)))
        object.__setattr__(self, "hyper", hyper)
        for name in ("num_seeds", "rounds", "explore", "evaluate", "fit_steps", "batch_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("eval_poses", "eval_trials", "regret_trials", "regret_grasps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        if self.regret_grasps > self.explore:
            raise ValueError(f"regret_grasps must be <= explore ({self.explore}), got "
                             f"{self.regret_grasps}")
        if self.num_seeds * self.rounds * self.explore > 10_000_000:
            raise ValueError("num_seeds x rounds x explore exceeds 10M grasps per object")
        # every registered learner's config is built, so a bad value of any flag is refused
        # (naming its flag) whether or not its learner runs
        for name in registry.names():
            registry.make_config(name, self.hyperparameters())
        if self.core_set not in ("dpp", "random", "none"):
            raise ValueError(f"core_set must be dpp, random or none, got {self.core_set!r}")
        if self.backend not in sim_lib.BACKENDS:
            raise ValueError(f"backend must be one of {sim_lib.BACKENDS}, got {self.backend!r}")
        if not 0 <= int(self.seed) < 2**31:
            raise ValueError(f"seed must be in [0, 2**31), got {self.seed}")
        if self.eval_trials == 0 and self.eval_poses > 0:
            raise ValueError("eval_trials must be >= 1 when eval_poses > 0")
        self.train_config()  # fit_steps, batch_size, learning_rate, loss
        for name in self.policies:  # horizon-dependent settings (sern_log's α)
            registry.make(name, _PROBE_MODEL, self.train_config(), self.learner_config(name))

    @property
    def horizon(self) -> int:
        """T of Algorithm 1's schedule: exploration grasps over the whole run."""
        return self.rounds * self.explore

    def hyperparameters(self) -> dict:
        """Every learner hyperparameter of this run by field name."""
        return {**{k: getattr(self, k) for k in _HYPER_FIELDS}, **dict(self.hyper)}

    def learner_config(self, name: str):
        """Learner ``name``'s registry config with this run's hyperparameters."""
        return registry.make_config(name, self.hyperparameters())

    def train_config(self) -> lbase.TrainConfig:
        return lbase.TrainConfig(horizon=self.horizon, fit_steps=self.fit_steps,
                                 batch_size=self.batch_size,
                                 learning_rate=self.learning_rate, loss=self.loss)

    def fingerprint(self) -> str:
        d = dataclasses.asdict(self)
        if "ensemble_ts" in self.policies:
            # ensemble_ts's layout defaulted to whole networks until 0c123bc made shared heads
            # the default; ``hyper`` drops defaults, so a whole-network run made then and a
            # shared-heads run made now would share a fingerprint and resume into each other.
            # Fingerprint "networks" as absent (those old directories keep theirs) and spell
            # "shared" out.
            hyper = dict(d["hyper"])
            hyper.pop("ensemble_heads", None)
            if self.learner_config("ensemble_ts").ensemble_heads == "shared":
                hyper["ensemble_heads"] = "shared"
            d["hyper"] = tuple(sorted(hyper.items()))
        if not d["hyper"]:
            del d["hyper"]  # runs from before the field keep their fingerprint
        if not d["regret_grasps"]:
            del d["regret_grasps"]
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


class LearnerError(RuntimeError):
    """A learner broke the interface's contract (e.g. chose no grasp while some were valid)."""


# ----------------------------------------------------------------------------- learners


def _net(params: qn.QualityParams):
    return params.net


def _with_net(params: qn.QualityParams, net) -> qn.QualityParams:
    return qn.QualityParams(net, params.normalizer)


@functools.lru_cache(maxsize=4)
def copies_network(config: qn.QualityNetConfig) -> qn.QualityNetwork:
    """θ0's network as the learner computes it: the same function and parameters, with
    convolutions as im2col matmuls (``qn.make_quality_network(conv="im2col")``), which
    run ~5x faster than XLA's convolution when vmapped over the O x S parameter copies on
    CPU. The ask/tell loop uses it too, so both make the same choices."""
    return qn.make_quality_network(config, conv="im2col")


@functools.lru_cache(maxsize=4)
def quality_model(network: qn.QualityNetwork) -> lbase.Model:
    """The quality network as a learner's :class:`~sern_jax.learners.base.Model`: inputs
    (crop image [..., S, S], grasp depth [...]); the input normaliser is not trained."""
    return lbase.Model(network.init, network.apply, network.logits, network.features,
                       trainable=_net, merge=_with_net)


def _probe_network(params, x):
    return x


_PROBE_MODEL = lbase.Model(_probe_network, _probe_network, _probe_network, _probe_network)


def train_config(config: OnlineConfig) -> lbase.TrainConfig:
    return config.train_config()


@functools.lru_cache(maxsize=64)
def _cached_learner(name, model, train, learner_config) -> lbase.Learner:
    return registry.make(name, model, train, learner_config)


def make_learner(config: OnlineConfig, name: str, model: lbase.Model) -> lbase.Learner:
    """Learner ``name`` of the run (the same object for the same settings: compiles are
    shared between runs in one process)."""
    return _cached_learner(name, model, config.train_config(), config.learner_config(name))


def core_data(kind: str, theta0: artifacts.Theta0) -> lbase.Data:
    """The core set C as the learners' ``Data`` (inputs: crop image, grasp depth)."""
    c = artifacts.core_set_data(kind, theta0)
    return lbase.Data((c.image, c.depth), c.label, c.weight)


# ----------------------------------------------------------------------------- keys


def object_key(root: jax.Array, name: str, seed_index: int) -> jax.Array:
    """The key of (object, seed): independent of which other objects run beside it."""
    return jax.random.fold_in(
        jax.random.fold_in(root, zlib.crc32(name.encode()) & 0x7FFFFFFF), seed_index)


def _stream(key_os: jax.Array, stream: int, round_index: int) -> jax.Array:
    return jax.random.fold_in(jax.random.fold_in(key_os, stream), round_index)


def _stream_keys(keys_os, stream: int, round_index: int) -> jax.Array:
    """[O, S] keys of one stream and round: ``_stream`` of every (object, seed) key, in one
    jitted call (threefry: the same keys as one eager ``_stream`` per copy, tested; eager,
    the 2 x O x S fold-ins cost the main thread a dispatch each). ``keys_os``: [O, S] keys,
    or lists of keys."""
    if not isinstance(keys_os, jax.Array):
        keys_os = jnp.stack([jnp.stack(list(row)) for row in keys_os])
    return _fold_streams(keys_os, jnp.uint32(stream), jnp.uint32(round_index))


@jax.jit
def _fold_streams(keys, stream, round_index):
    return jax.vmap(jax.vmap(lambda k: _stream(k, stream, round_index)))(keys)


def _poses_of_stream(key_os, stream, r, num, model, config):
    """``context.resting_poses`` of ``_stream(key_os, stream, r)``: a batch's settling
    stage, in a settling thread."""
    return context_lib.resting_poses(_stream(key_os, stream, r), num, model, config)


def _contexts_of_stream(key_os, stream, r, spec, num, model, config, settled=None):
    """:func:`_contexts` of ``_stream(key_os, stream, r)``, the key derived in the calling
    (batch) thread rather than by the main thread that queues the batch; ``settled``: a
    future of the batch's resting poses (:func:`_poses_of_stream`), waited for here."""
    poses = None if settled is None else settled.result()
    return _contexts(_stream(key_os, stream, r), spec, num, model, config, poses)


# ----------------------------------------------------------------------------- jitted steps


@functools.lru_cache(maxsize=4)
def _batched_crops(crop_config: crops_lib.CropConfig):
    # depth [O, S, N, H, W]; candidates [O, S, N, K, ...] -> Crops [O, S, N, K, ...]
    one = functools.partial(crops_lib.extract_batch, config=crop_config)
    return jax.jit(jax.vmap(jax.vmap(one)))


def _copy_obs(image, depth, valid, u, t):
    return lbase.Obs((image, depth), valid, u, t)


@functools.lru_cache(maxsize=32)
def _batched_act(act, with_probs: bool = True):
    """act over one phase of every copy: (act_root [O, S] keys, state [O, S], image
    [O, S, N, K, c, c], depth [O, S, N, K], valid [O, S, N, K], u [O, S, N], t0 [])
    -> (action [O, S, N], probs [O, S, N, K]); every grasp of the phase acts on the same
    state (the runners' phase semantics, see learners.base).

    ``with_probs=False`` returns ``(action, None)``: the jitted function does not output
    the distribution, so XLA drops whatever only the distribution needed (ensemble TS's
    other members' forwards). The actions are the same computation either way."""

    def copy(root, state, image, depth, valid, u, t0):
        def one(e, image, depth, valid, u):
            obs = _copy_obs(image, depth, valid, u, t0 + e)
            action, probs, _ = act(jax.random.fold_in(root, e), state, obs)
            return action, probs

        num = u.shape[0]
        return jax.vmap(one)(jnp.arange(num, dtype=jnp.int32), image, depth, valid, u)

    over_s = jax.vmap(copy, (0, 0, 0, 0, 0, 0, None))
    batched = jax.vmap(over_s, (0, 0, 0, 0, 0, 0, None))
    if with_probs:
        return jax.jit(batched)
    actions = jax.jit(lambda *args: batched(*args)[0])
    return lambda *args: (actions(*args), None)


@functools.lru_cache(maxsize=32)
def _batched_greedy(predict):
    """Greedy on the learner's estimate: (state [O, S], image, depth, valid, u) -> action
    [O, S, N] (``sample_icdf(u, greedy_probs(r̂))``: u breaks ties)."""

    def copy(state, image, depth, valid, u):
        def one(image, depth, valid, u):
            r_hat = predict(state, _copy_obs(image, depth, valid, u, jnp.int32(0)))
            return pol.sample_icdf(u, pol.greedy_probs(r_hat, mask=valid), mask=valid)

        return jax.vmap(one)(image, depth, valid, u)

    return jax.jit(jax.vmap(jax.vmap(copy)))


@functools.lru_cache(maxsize=32)
def _batched_update(update):
    # keys [O, S]; state [O, S]; batch [O, S, E, ...]
    return jax.jit(jax.vmap(jax.vmap(update)))


@functools.lru_cache(maxsize=32)
def _batched_init(init):
    # keys [O, S]; θ0 and C shared
    return jax.jit(jax.vmap(jax.vmap(init, (0, None, None)), (0, None, None)))


def _predict(learner: lbase.Learner, model: lbase.Model):
    return learner.predict if learner.predict is not None else lbase.network_predict(model)


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
                # Student-t 95 % intervals over the seeds (n - 1 dof), per round and for the
                # run's total; None with one seed
                ci, total = stats.t_interval(pr, axis=1), stats.t_interval(pr.sum(0))
                row["pseudo_regret_sd"] = _finite_list(ci.sd)
                row["pseudo_regret_se"] = _finite_list(ci.se)
                row["pseudo_regret_ci95"] = [
                    [float(lo), float(hi)] if np.isfinite(lo) else None
                    for lo, hi in zip(ci.lower, ci.upper)]
                row["pseudo_regret_total"] = float(total.mean)
                row["pseudo_regret_total_ci95"] = (
                    [float(total.lower), float(total.upper)] if np.isfinite(total.lower)
                    else None)
            rows.append(row)
    return rows


def _finite_list(values) -> list:
    return [float(v) if np.isfinite(v) else None for v in values]


# ----------------------------------------------------------------------------- the run


def run_fingerprint(config: OnlineConfig, specs: list[objects_lib.ObjectSpec],
                    theta0) -> str:
    """What determines a run's results: the config, the objects (names and geometry, so
    the same mesh file at another scale is another run), θ0, and the default simulated
    world (``sim.physics_settings()``: a change of the default trial, e.g. 6 N -> 20 N
    fingers on 2026-11-24, is another run; a non-default world is hashed on top in
    :func:`run`)."""
    objects = [(s.name, repr(s)) for s in specs]
    text = (f"v{CHECKPOINT_VERSION}" + config.fingerprint() + json.dumps(objects)
            + theta0.fingerprint + json.dumps(sim_lib.physics_settings(), sort_keys=True))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _contexts(key, spec, num, model, config=context_lib.ContextConfig(), poses=None):
    """Contexts of one object as numpy (poses [n, 7], depth [n, H, W], candidates [n, K]);
    ``poses``: their resting poses where settled ahead."""
    ctx = context_lib.make_contexts(key, spec, num, config, model=model, poses=poses)
    return ctx.poses, ctx.depth, ctx.candidates


def _stack(items):
    return jax.tree.map(lambda *xs: np.stack(xs), *items)


def _stack_contexts(rows):
    poses = np.stack([[e[0] for e in row] for row in rows])
    depth = np.stack([[e[1] for e in row] for row in rows])
    cands = _stack([_stack([e[2] for e in row]) for row in rows])
    return poses, depth, cands


def _seed_noise(simulator, keys, num) -> sim_lib.TrialNoise:
    """Trial noise of each seed's key, stacked: fields [S, num, ...]; trial j of seed s is
    ``sample_noise(keys[s], num)[j]``, drawn for all seeds in one jitted call (the same
    values as one eager ``sample_noise`` per seed, tests/grasp/test_context_threads.py;
    eager, a call cost ~16 ms of dispatch, 120 of them per phase in the strong setting)."""
    keys = keys if isinstance(keys, jax.Array) else jnp.stack(list(keys))
    fric, mass, err = _noise_program(simulator.config, int(num))(keys)
    return sim_lib.TrialNoise(np.asarray(fric, np.float64), np.asarray(mass, np.float64),
                              np.asarray(err, np.float64))


@functools.lru_cache(maxsize=32)
def _noise_program(config: sim_lib.TrialConfig, num: int):
    """keys [S] -> TrialNoise fields [S, num, ...]: ``sim.sample_noise`` for every key."""

    def one(key):
        return jax.vmap(lambda i: sim_lib.sample_trial_noise(jax.random.fold_in(key, i),
                                                             config))(jnp.arange(num))

    return jax.jit(jax.vmap(one))


def _run_trials(simulators, grasps, poses, noise_keys, n_per_key, counts=None):
    """Runs every object's trials.

    grasps [O, S, Q, N, 4], poses [O, S, N, 7], noise_keys[o][s]: trial j of (o, s) uses
    ``sample_noise(noise_keys[o][s], N)[j]`` for every learner (common random numbers).
    Returns success [O, S, Q, N] bool.

    Learners that pick the same grasp in trial j of (o, s) share its pose and its noise, so
    their trials are the same simulation: each distinct (s, j, grasp) runs once and its
    outcome goes to every learner that chose it. MuJoCo is deterministic and a trial does
    not depend on the others in its batch, so this gives the same outcomes bit for bit as
    simulating every copy (tests/grasp/test_online.py checks both ways). ``counts``, a
    dict, accumulates ``requested`` and ``simulated`` trials.

    The objects' trials are handed to their simulators from threads of their own (native
    simulators share one pool of trial workers, so every object's trials keep the cores
    busy together); each object's outcomes and counts are the serial ones.
    """
    num_o, num_s, num_q, num_n = grasps.shape[:4]
    out = np.zeros((num_o, num_s, num_q, num_n), bool)
    s_i, _, n_i = np.indices((num_s, num_q, num_n)).reshape(3, -1)

    def one(o):
        simulator = simulators[o]
        noise = _seed_noise(simulator, noise_keys[o], n_per_key)  # [S, N, ...]
        flat = np.ascontiguousarray(grasps[o].reshape(-1, 4), np.float64)
        key = np.concatenate([s_i[:, None], n_i[:, None], flat.view(np.int64)], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        us, un = s_i[first], n_i[first]
        res = simulator.run_trials(
            flat[first], sim_lib.TrialNoise(*(a[us, un] for a in noise)),
            object_pose=poses[o][us, un])
        out[o] = res.success[inverse.reshape(-1)].reshape(num_s, num_q, num_n)
        return len(flat), len(first)

    if num_o > 1:
        done = list(_object_pool().map(one, range(num_o)))
    else:
        done = [one(o) for o in range(num_o)]
    if counts is not None:
        with _COUNTS_LOCK:  # the evaluation thread and the main thread both count
            for requested, simulated in done:
                counts["requested"] = counts.get("requested", 0) + requested
                counts["simulated"] = counts.get("simulated", 0) + simulated
    return out


_COUNTS_LOCK = threading.Lock()

# Whether a round's evaluation runs beside the next round's exploration (the module
# docstring); False runs the phases one after another (the reference the tests compare with:
# the same results and checkpoints, bit for bit).
OVERLAP_EVALUATION = True
# Most evaluations queued at once (each holds its round's learner states): the main thread
# explores at most this many rounds ahead of the evaluation thread.
MAX_QUEUED_EVALUATIONS = 2
# Whether every batch's resting poses are queued to settle when the run starts (see run);
# None: on a many-core host (context.many_cores), the other behaviour elsewhere.
SETTLE_AHEAD: bool | None = None


def _object_pool() -> concurrent.futures.ThreadPoolExecutor:
    """Threads that hand each object's trials to its simulator (they mostly wait); one per
    process, made under a lock (the main and the evaluation thread may ask at once)."""
    with _OBJECT_POOL_LOCK:
        if not _OBJECT_POOL:
            _OBJECT_POOL.append(concurrent.futures.ThreadPoolExecutor(
                16, thread_name_prefix="sern-object-trials"))
        return _OBJECT_POOL[0]


_OBJECT_POOL: list = []
_OBJECT_POOL_LOCK = threading.Lock()


def _check_actions(action, valid, names, specs, round_index):
    """A learner must choose a valid candidate whenever one exists: NO_ARM (or an invalid
    slot) with valid candidates is a broken learner, not a failed grasp."""
    num_valid = valid.sum(-1)  # [O, S, N]
    num_k = valid.shape[-1]
    in_range = (action >= 0) & (action < num_k)
    chosen_ok = np.take_along_axis(valid[:, :, None], np.clip(action, 0, num_k - 1)[..., None],
                                   -1)[..., 0] & in_range  # [O, S, Q, N]
    bad = ~chosen_ok & ((action != pol.NO_ARM) | (num_valid[:, :, None] > 0))
    if bad.any():
        o, s, q, n = (int(i[0]) for i in np.nonzero(bad))
        what = "no grasp (NO_ARM)" if action[o, s, q, n] == pol.NO_ARM else (
            f"candidate {int(action[o, s, q, n])}, not a valid slot,")
        raise LearnerError(
            f"learner {names[q]!r} returned {what} on {specs[o].name}, seed {s}, round "
            f"{round_index}, grasp {n} while {int(num_valid[o, s, n])} candidates were valid; "
            "a learner must choose a valid candidate whenever one exists (stopped: this "
            "would have been recorded as a failed grasp)")


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
    learners: dict[str, lbase.Learner] | None = None,
    seed_indices: tuple[int, ...] | None = None,
) -> dict:
    """Runs (or resumes) the online learning experiment; returns the results dict.

    ``seed_indices`` runs only those seeds of ``config.num_seeds`` (distinct, each in
    ``0 .. num_seeds - 1``; None = all, in order): the copies of seed ``s`` get seed
    ``s``'s keys whatever else runs, and the seed axis of every output follows the given
    order. A subset is another run directory (it enters the fingerprint).

    ``context_config`` (scene physics such as the finger force and pad friction, depth
    noise) and ``trial_config`` (the trial's randomisation) choose the simulated world;
    None = the defaults every shipped result uses. A non-default world enters the run's
    fingerprint (the defaults leave existing fingerprints unchanged).

    ``learners`` (name -> Learner) replaces registered learners of those names (a learner
    being developed, a test's toy); by default each name in ``config.policies`` is built
    from the registry over θ0's network.

    After each finished round ``out_dir/checkpoint.npz`` saves the results and every
    exploration grasp's reward (kilobytes: no learner state). Rerunning the same command
    resumes after the last finished round: the learners' states are rebuilt by replaying
    init and each finished round's update on the same inputs (the exploration contexts
    recomputed from their keys, the saved choices and rewards), which is the computation
    of the uninterrupted run, so it gives the same results (tests/grasp/test_runner.py).
    A run that had already finished returns its results with ``states`` None (nothing is
    replayed).
    """
    t_run = time.perf_counter()
    out_dir = Path(out_dir)
    names = [s.name for s in specs]
    if not names:
        raise ValueError("no objects given")
    if len(set(names)) != len(names):
        raise ValueError(f"objects must be distinct, got {names}")
    theta0 = theta0 or artifacts.load_theta0()
    model = quality_model(copies_network(theta0.network.config))
    core = core_data(config.core_set, theta0)
    num_o, num_q = len(specs), len(config.policies)
    num_r, num_e = config.rounds, config.explore
    seeds = tuple(range(config.num_seeds)) if seed_indices is None else tuple(seed_indices)
    if (not seeds or len(set(seeds)) != len(seeds)
            or not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool)
                       and 0 <= i < config.num_seeds for i in seeds)):
        raise ValueError(f"seed_indices must be distinct integers in 0..{config.num_seeds - 1}"
                         f", got {seed_indices!r}")
    seeds = tuple(int(i) for i in seeds)
    num_s = len(seeds)
    fingerprint = run_fingerprint(config, specs, theta0)
    if seeds != tuple(range(config.num_seeds)):  # a subset (or order) is another run
        fingerprint = hashlib.sha256(
            (fingerprint + "seeds" + repr(seeds)).encode()).hexdigest()[:16]
    context_config = context_config or context_lib.ContextConfig()
    trial_config = trial_config or sim_lib.TrialConfig()
    if (context_config, trial_config) != (context_lib.ContextConfig(), sim_lib.TrialConfig()):
        fingerprint = hashlib.sha256(
            (fingerprint + repr(context_config) + repr(trial_config)).encode()).hexdigest()[:16]
    custom = dict(learners or {})
    if custom:  # a learner from outside the registry is another run
        fingerprint = hashlib.sha256((fingerprint + repr(sorted(custom))).encode()
                                     ).hexdigest()[:16]
    chosen = [custom.get(n) or make_learner(config, n, model) for n in config.policies]

    root = jax.random.key(config.seed)
    keys_os = [[object_key(root, n, s) for s in seeds] for n in names]
    keys_arr = jnp.stack([jnp.stack(row) for row in keys_os])  # [O, S]
    models = [context_lib.scene_model(spec, context_config) for spec in specs]
    simulators = [sim_lib.GraspSimulator(m, backend=config.backend, config=trial_config,
                                         mjx_batch=MJX_BATCH) for m in models]
    crops_fn = _batched_crops(crops_lib.CropConfig())

    # One state per learner, each with leading [O, S] copies.
    states = [_batched_init(lrn.init)(_stream_keys(keys_arr, INIT, 0), theta0.params, core)
              for lrn in chosen]
    shape = (num_r + 1, num_o, num_q, num_s)
    results = RoundResults(np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan),
                           np.full(shape + (num_e,), -1, np.int32), np.full(shape, np.nan))
    rewards = np.zeros((num_r + 1, num_o, num_s, num_q, num_e), np.int8)  # per grasp
    timings = {k: 0.0 for k in ("contexts", "choose", "trials", "update", "evaluate", "wait")}
    if config.regret_trials:
        timings["oracle"] = 0.0
    trial_counts = {"requested": 0, "simulated": 0}  # this invocation (not resumed rounds)
    start_round = 0

    ckpt = out_dir / "checkpoint.npz"
    if ckpt.exists():
        saved = io.load_npz(ckpt, advice="delete it (or choose another --out) and rerun")
        if str(saved.get("fingerprint", "")) != fingerprint:
            raise ValueError(f"{out_dir} holds a different learning run; choose another --out "
                             "or delete it")
        results = RoundResults(*(saved[f] for f in RoundResults._fields))
        rewards = np.asarray(saved["explore_reward"], np.int8)
        start_round = int(saved["next_round"])
        log(f"resuming {out_dir} at round {start_round}")
    out_dir.mkdir(parents=True, exist_ok=True)

    # Every (object, seed)'s batch of contexts is made in threads of its own (MuJoCo's
    # settling and ray casting and JAX's sampler release the GIL; each batch has its own
    # MjData and keys, the models are only read), so the batches of a round use the cores
    # instead of one. A batch is made in two stages: its resting poses settle (native
    # MuJoCo, CPU only) in a settling thread, then a batch thread renders the depth images
    # and samples the candidates (the device, and on a GPU one compile per object and batch
    # size). The threads' names start with "sern-context", so a batch settles its poses in
    # its own thread (context._resting_poses) rather than in a nested pool. The settling
    # threads run at a lower CPU priority (context.lower_priority, on a many-core host):
    # they work ahead of need, and the main thread, the evaluation, the trial workers and
    # the compiles come first. On a many-core host (context.many_cores) every batch's poses
    # are queued to settle when the run starts, in the order the run queues the batches, so
    # the settling threads fill the cores that the first compiles leave idle and later
    # rounds only render; elsewhere a batch's poses are queued with the batch. Same keys,
    # same poses: results unchanged.
    threads = max(1, min(num_o * num_s, context_lib.context_threads()))
    batches = concurrent.futures.ThreadPoolExecutor(
        threads, thread_name_prefix="sern-context-batch")
    settlers = concurrent.futures.ThreadPoolExecutor(
        threads, thread_name_prefix="sern-context-settle",
        initializer=context_lib.lower_priority)
    settling = {}  # (stream, r) -> [O][S] futures of resting poses [N, 7]

    def settle(stream, r, num):
        if (stream, r) not in settling:
            settling[(stream, r)] = [
                [settlers.submit(_poses_of_stream, keys_os[o][s], stream, r, num, models[o],
                                 context_config) for s in range(num_s)] for o in range(num_o)]

    def submit_contexts(stream, r, num):
        settle(stream, r, num)
        settled = settling.pop((stream, r))
        return [[batches.submit(_contexts_of_stream, keys_os[o][s], stream, r, specs[o], num,
                                models[o], context_config, settled[o][s])
                 for s in range(num_s)] for o in range(num_o)]

    def gather(jobs):
        return _stack_contexts([[job.result() for job in row] for row in jobs])

    # The order the batches are queued in (and, on a many-core host, their poses settled
    # in, all at the start): the fixed low-variance evaluation poses, round 0's evaluation
    # contexts, round 1's exploration contexts, then each round's evaluation and the next
    # round's exploration contexts as soon as the round's exploration contexts are taken
    # (a resumed run: its replay's exploration contexts before). On a GPU each batch size of
    # each object is a compile of its own, made in that order, so the evaluations, the
    # longer chain of the two threads, start first.
    need = [(LOWVAR_CONTEXT, 0, config.eval_poses)] if config.eval_poses else []
    need += ([(EVAL_CONTEXT, 0, config.evaluate)] if start_round == 0 else []) + [
        (EXPLORE_CONTEXT, r, num_e) for r in range(1, max(start_round, 1) + 1)]
    for r in range(max(start_round, 1), num_r + 1):
        need += [(EVAL_CONTEXT, r, config.evaluate), (EXPLORE_CONTEXT, r + 1, num_e)]
    ahead = context_lib.many_cores() if SETTLE_AHEAD is None else SETTLE_AHEAD
    if ahead and start_round <= num_r:  # (a finished run needs none)
        for stream, r, num in need:
            if r <= num_r:
                settle(stream, r, num)

    # The fixed low-variance evaluation poses of each (object, seed): queued first, gathered
    # when the first evaluation needs them.
    lowvar_jobs = (submit_contexts(LOWVAR_CONTEXT, 0, config.eval_poses)
                   if config.eval_poses and start_round <= num_r else None)
    lowvar_made = []

    def lowvar_contexts():
        if not lowvar_made:
            lv = gather(lowvar_jobs)
            lowvar_made.append(lv + (crops_fn(lv[1], lv[2]),))
        return lowvar_made[0]

    from tqdm.auto import tqdm

    bar = tqdm(total=num_r + 1, initial=start_round, unit="round", desc="learn",
               disable=not progress)

    def greedy_actions(states, crops, cands, u):
        return np.stack([np.asarray(_batched_greedy(_predict(lrn, model))(
            st, crops.image, crops.depth, cands.valid, u)) for lrn, st in zip(chosen, states)],
            axis=2)  # [O, S, Q, N]

    # Contexts (resting-pose drops, rendering, candidates) are made ahead of need in the
    # batch threads while the main thread runs trials and the learners, in the order above.
    # They depend on their keys only, so results are unchanged; the simulators run on
    # copies of the scene models and only read them.
    pending = {}
    streams = {"explore": EXPLORE_CONTEXT, "eval": EVAL_CONTEXT}
    sizes = {"explore": num_e, "eval": config.evaluate}

    def prefetch(kind, r):
        if r <= num_r and (kind, r) not in pending:
            pending[(kind, r)] = submit_contexts(streams[kind], r, sizes[kind])  # [O, S, N]


    timing_lock = threading.Lock()  # the evaluation thread adds to timings too

    def tick(phase, t):
        with timing_lock:
            timings[phase] += time.perf_counter() - t

    def take(kind, r):
        """The queued context jobs of (kind, r) (queued now if they were not)."""
        prefetch(kind, r)
        return pending.pop((kind, r))

    def contexts(kind, r, jobs=None):
        t = time.perf_counter()
        out = gather(take(kind, r) if jobs is None else jobs)
        tick("contexts", t)
        return out

    def evaluate(r, states, jobs):
        """Round r's evaluation of ``states`` (a list of the learners' states after round
        r's update) on the contexts of ``jobs``; runs in the evaluation thread."""
        poses, depth, cands = contexts("eval", r, jobs)
        t = time.perf_counter()
        u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (config.evaluate,))))(
            _stream_keys(keys_arr, EVAL_UNIFORM, r)))
        action = greedy_actions(states, crops_fn(depth, cands), cands, u)
        grasps = _gather(cands.grasps, action)
        success = _run_trials(simulators, grasps, poses,
                              _stream_keys(keys_arr, EVAL_TRIAL, r),
                              config.evaluate, trial_counts)
        success &= action >= 0
        results.paper_eval[r] = success.mean(-1).transpose(0, 2, 1)
        if config.eval_poses:
            poses, depth, cands, crops = lowvar_contexts()
            u0 = np.zeros(poses.shape[:3], np.float32)
            action = greedy_actions(states, crops, cands, u0)  # [O, S, Q, P]
            grasps = _gather(cands.grasps, action)  # [O, S, Q, P, 4]
            m = config.eval_trials
            rep_grasps = np.repeat(grasps, m, axis=3)
            rep_poses = np.repeat(poses, m, axis=2)
            success = _run_trials(
                simulators, rep_grasps, rep_poses,
                _stream_keys(keys_arr, LOWVAR_TRIAL, r),
                config.eval_poses * m, trial_counts)
            success = success.reshape(num_o, num_s, num_q, config.eval_poses, m)
            success &= (action >= 0)[..., None]
            results.lowvar_eval[r] = success.mean((-1, -2)).transpose(0, 2, 1)
        tick("evaluate", t)

    # The evaluations run one after another in a thread of their own, beside the main
    # thread's exploration (module docstring); each saves the checkpoint through its round.
    # After one fails, none runs or saves (a later checkpoint would claim the failed round).
    evaluator = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sern-evaluate")
    queued = []  # futures of the evaluations queued and not yet waited for, in round order
    failed = threading.Event()

    def evaluate_and_save(r, states, jobs):
        if failed.is_set():
            raise concurrent.futures.CancelledError(f"round {r}: an earlier evaluation failed")
        try:
            evaluate(r, states, jobs)
            _save(ckpt, fingerprint, *_through(results, rewards, r + 1), r + 1)
        except BaseException:
            failed.set()
            raise
        bar.update(1)
        if not progress:  # a line per round where there is no bar (device logs)
            log(f"round {r}/{num_r} saved at {time.perf_counter() - t_run:.0f} s; "
                + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()))

    def queue_evaluation(r):
        # at most MAX_QUEUED_EVALUATIONS queued: each holds its round's learner states
        while len(queued) >= (MAX_QUEUED_EVALUATIONS if OVERLAP_EVALUATION else 1):
            t = time.perf_counter()
            queued.pop(0).result()
            tick("wait", t)
        queued.append(evaluator.submit(evaluate_and_save, r, list(states), take("eval", r)))
        if not OVERLAP_EVALUATION:
            wait_evaluations()

    def wait_evaluations():
        t = time.perf_counter()
        try:
            while queued:
                queued.pop(0).result()
        finally:
            tick("wait", t)

    def raise_failed_evaluation():
        """A queued evaluation's error, raised in the main thread as soon as it is known."""
        for job in queued:
            if job.done() and job.exception() is not None:
                job.result()

    if start_round == 0:
        prefetch("eval", 0)
        prefetch("explore", 1)
        queue_evaluation(0)
        start_round = 1

    def explore_contexts(r):
        out = contexts("explore", r)
        prefetch("eval", r)
        prefetch("explore", r + 1)
        return out

    def update_all(r, crops, action, success):
        """Every learner's update on the phase's (crop, action, reward): action and success
        [O, S, Q, E]."""
        t = time.perf_counter()
        image = np.asarray(crops.image)  # [O, S, E, K, c, c]
        cdepth = np.asarray(crops.depth)  # [O, S, E, K]
        o_i, s_i, e_i = np.indices(action[:, :, 0].shape)
        fit_keys = _stream_keys(keys_arr, FIT, r)
        for q, lrn in enumerate(chosen):
            idx = np.maximum(action[:, :, q], 0)
            batch = lbase.Batch((image[o_i, s_i, e_i, idx], cdepth[o_i, s_i, e_i, idx]),
                                action[:, :, q], success[:, :, q].astype(np.float32))
            states[q] = _batched_update(lrn.update)(fit_keys, states[q], batch)
        jax.block_until_ready(states)
        timings["update"] += time.perf_counter() - t

    if 1 < start_round <= num_r:  # replay: the learners' states after round start_round - 1
        t = time.perf_counter()
        for r in range(1, start_round):
            _, depth, cands = contexts("explore", r)
            prefetch("explore", r + 1)
            update_all(r, crops_fn(depth, cands),
                       results.explore_action[r].transpose(0, 2, 1, 3), rewards[r] > 0)
        log(f"replayed rounds 1..{start_round - 1} in {time.perf_counter() - t:.1f} s")

    def explore_round(r):
        raise_failed_evaluation()
        # 1. exploration
        poses, depth, cands = explore_contexts(r)
        t = time.perf_counter()
        u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (num_e,))))(
            _stream_keys(keys_arr, POLICY_UNIFORM, r)))
        crops = crops_fn(depth, cands)
        act_root = _stream_keys(keys_arr, ACT, r)
        t0 = jnp.int32((r - 1) * num_e)
        # π itself is needed only by the regret accounting (its pseudo-regret)
        with_probs = bool(config.regret_trials)
        acted = [_batched_act(lrn.act, with_probs)(act_root, st, crops.image, crops.depth,
                                                   cands.valid, u, t0)
                 for lrn, st in zip(chosen, states)]
        action = np.stack([np.asarray(a) for a, _ in acted], axis=2)  # [O, S, Q, E]
        if with_probs:
            probs = np.stack([np.asarray(p) for _, p in acted], axis=2)  # [O, S, Q, E, K]
        timings["choose"] += time.perf_counter() - t
        _check_actions(action, np.asarray(cands.valid, bool), config.policies, specs, r)
        t = time.perf_counter()
        grasps = _gather(cands.grasps, action)
        success = _run_trials(simulators, grasps, poses,
                              _stream_keys(keys_arr, EXPLORE_TRIAL, r),
                              num_e, trial_counts)
        success &= action >= 0
        timings["trials"] += time.perf_counter() - t
        results.explore_success[r] = success.mean(-1).transpose(0, 2, 1)
        results.explore_action[r] = action.transpose(0, 2, 1, 3)
        rewards[r] = success
        if config.regret_trials:
            t = time.perf_counter()
            g = config.regret_grasps or num_e  # the oracle's grasps: the phase's first g
            sub = jax.tree.map(lambda x: np.asarray(x)[:, :, :g], cands)
            select, value = (
                _oracle(simulators, sub, poses[:, :, :g], config.regret_trials,
                        _stream_keys(keys_arr, stream, r),
                        trial_counts)[:, :, None]  # [O, S, 1, g, K]
                for stream in (ORACLE_TRIAL, ORACLE_VALUE))
            valid = np.asarray(sub.valid, bool)[:, :, None]
            regret = stats.oracle_regret(select, value, probs[..., :g, :], valid)  # [O,S,Q,g]
            regret = np.where(valid.any(-1), regret, 0.0)  # nothing valid: nothing lost
            results.pseudo_regret[r] = (num_e / g) * regret.sum(-1).transpose(0, 2, 1)
            timings["oracle"] += time.perf_counter() - t
        # 2. update on the phase's (crop, action, reward)
        update_all(r, crops, action, success)
        # 3. evaluation, in the evaluation thread
        queue_evaluation(r)

    try:
        for r in range(start_round, num_r + 1):
            explore_round(r)
        wait_evaluations()
    except BaseException as err:
        # Keep the rounds already explored: their evaluations finish and save their
        # checkpoints before the context pools stop (on an interrupt, only the one running:
        # those not started are dropped).
        for job in queued:
            if isinstance(err, KeyboardInterrupt):
                job.cancel()
        for job in queued:
            if not job.cancelled():
                try:
                    job.result()
                except BaseException:  # the evaluation failed too: the first error is raised
                    pass
        raise
    finally:
        evaluator.shutdown(wait=False, cancel_futures=True)
        bar.close()
        batches.shutdown(wait=False, cancel_futures=True)
        settlers.shutdown(wait=False, cancel_futures=True)
    rows = table_rows(names, config.policies, results.paper_eval,
                      results.lowvar_eval if config.eval_poses else None,
                      results.pseudo_regret if config.regret_trials else None)
    if start_round > num_r:  # finished before this call: nothing replayed, no states
        states = None
    return {"table": rows, "results": results, "timings": timings,
            "trial_counts": trial_counts, "objects": names, "seed_indices": seeds,
            "fingerprint": fingerprint, "config": config, "states": states}


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
        with _COUNTS_LOCK:  # the evaluation thread counts too
            counts["requested"] += len(rows_s)
            counts["simulated"] += len(rows_s)
    return out


def _gather(grasps, action):
    """grasps [O, S, N, K, 4], action [O, S, Q, N] -> chosen grasps [O, S, Q, N, 4]
    (an invalid choice, -1, takes slot 0: its trial runs but its outcome is discarded)."""
    g = np.asarray(grasps)
    o, s, q, n = np.indices(action.shape)
    return g[o, s, n, np.maximum(action, 0)]


# ----------------------------------------------------------------------------- checkpoints


def state_arrays(state: lbase.LearnerState, prefix: str, horizon: int) -> dict:
    """A learner state's leaves as ``{prefix + i: array}``, the buffer cut to its D rows
    (rows [0, T) on the buffer's row axis, after any leading copy axes; C is rebuilt from
    the core set on load)."""
    lead = state.buffer.count.ndim

    def cut(x):
        return np.asarray(x)[(slice(None),) * lead + (slice(0, horizon),)]

    buf = state.buffer
    short = state._replace(buffer=buf._replace(inputs=tuple(cut(x) for x in buf.inputs),
                                               reward=cut(buf.reward), weight=cut(buf.weight)))
    return artifacts.tree_arrays(short, prefix)


def _state_from_arrays(saved: dict, prefix: str, template: lbase.LearnerState,
                       horizon: int) -> lbase.LearnerState:
    """The inverse of :func:`state_arrays`: ``template`` (a fresh state of the same learner)
    gives the structure and the core-set rows."""
    lead = template.buffer.count.ndim
    row = (slice(None),) * lead

    def short(x):
        return x[row + (slice(0, horizon),)]

    buf = template.buffer
    short_template = template._replace(buffer=buf._replace(
        inputs=tuple(short(x) for x in buf.inputs), reward=short(buf.reward),
        weight=short(buf.weight)))
    keys = [k for k in saved if k.startswith(prefix)]
    if len(keys) != len(jax.tree.leaves(short_template)):
        raise ValueError(f"the checkpoint's state {prefix!r} does not fit this learner")
    loaded = artifacts.tree_from_arrays(saved, short_template, prefix)

    def full(d, t):
        return jnp.concatenate([jnp.asarray(d, t.dtype), t[row + (slice(horizon, None),)]],
                               axis=lead)

    lb = loaded.buffer
    return loaded._replace(buffer=lb._replace(
        inputs=tuple(full(d, t) for d, t in zip(lb.inputs, buf.inputs)),
        reward=full(lb.reward, buf.reward), weight=full(lb.weight, buf.weight)))


def _through(results: RoundResults, rewards: np.ndarray, next_round: int):
    """Copies of ``results`` and ``rewards`` holding rounds ``< next_round`` only, later
    rounds at their initial fill (NaN, action -1, reward 0): what the checkpoint of a run
    that has finished those rounds holds, whatever the main thread has done since (and what
    ``learn_units`` joins its units' checkpoints to)."""
    def cut(a, fill):
        a = np.array(a, copy=True)
        a[next_round:] = fill
        return a

    fills = {"explore_action": -1}
    return (RoundResults(*(cut(getattr(results, f), fills.get(f, np.nan))
                           for f in RoundResults._fields)),
            cut(rewards, 0))


def _save(path, fingerprint, results, rewards, next_round):
    """The run's checkpoint: results, every exploration grasp's reward (int8 [R + 1, O, S,
    Q, E]) and the next round; the learner states are rebuilt on resume (:func:`run`)."""
    arrays = {f: np.asarray(getattr(results, f)) for f in results._fields}
    io.save_npz(path, fingerprint=np.asarray(fingerprint), next_round=np.asarray(next_round),
                explore_reward=np.asarray(rewards, np.int8), **arrays)
