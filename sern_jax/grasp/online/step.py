"""One round of Algorithm 1 for grasping, for every (object, learner, seed) copy at once.

One *round* (the paper's Section VI) for every (object, seed, learner):

1. **exploration** (:func:`act`, :func:`explore_trials`): ``explore`` grasps, each on a
   fresh random resting pose of the object: depth image -> 64 candidates -> crops ->
   ``learner.act`` (its distribution over the valid candidates, from
   :mod:`sern_jax.core.policies`) -> one grasp -> a randomised trial -> reward;
2. **update** (:func:`update`): ``learner.update`` with the phase's (crops, actions,
   rewards) (Algorithm 1's learners: append to D, then optax minibatch steps on D ∪ C, C
   the shipped core set);
3. **evaluation** (:func:`evaluate`, :func:`evaluate_lowvar`): ``evaluate`` greedy grasps
   on fresh poses (the paper's noisy 0/20/40/...% figure), plus a low-variance figure: the
   greedy grasp's success probability from ``eval_trials`` trials on each of ``eval_poses``
   fixed poses per seed. Greedy is the argmax of the learner's ``predict`` (the network's r̂
   for Algorithm 1's learners).

Every function here is a function of (learner states, a round's contexts, the run's [O, S]
keys, the round index) to arrays: none starts a thread (a simulator passed in may run its
trials on workers of its own; ``map_fn`` is the caller's), reads or writes a file, or keeps
anything between calls but its compiled programs (cached per learner function), so a round
can be called from a test on its own. Each learner's ``act`` and ``update`` is one jitted
call vmapped over the O x S copies; contexts, crops and trials are shared by the learners,
and every draw comes from the streams of :mod:`sern_jax.grasp.online.keys`. The host loop
(contexts made ahead in threads, the evaluation beside the next round, the checkpoint) is
:mod:`sern_jax.grasp.online.driver`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.analysis import stats
from sern_jax.core import policies as pol
from sern_jax.grasp.online import keys as keys_lib
from sern_jax.grasp.online.config import LearnerError
from sern_jax.grasp.world import candidates as cand_lib
from sern_jax.grasp.world import crops as crops_lib
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import base as lbase

__all__ = [
    "Acted",
    "Contexts",
    "Copies",
    "TrialCounts",
    "act",
    "batched_act",
    "batched_crops",
    "batched_greedy",
    "batched_init",
    "batched_update",
    "check_actions",
    "evaluate",
    "evaluate_lowvar",
    "explore_trials",
    "gather_grasps",
    "greedy_actions",
    "init_states",
    "oracle",
    "predict_fn",
    "pseudo_regret",
    "run_trials",
    "seed_noise",
    "stack_contexts",
    "update",
    "with_crops",
]

# `map`-like: (fn, iterable) -> iterable of results in order (the driver passes a thread
# pool's `map` so that the objects' trials run together; results do not depend on it)
MapFn = Callable


class Copies(NamedTuple):
    """What every round of a run shares: Q learners over O objects x S seeds."""

    learners: tuple[lbase.Learner, ...]  # [Q]
    learner_names: tuple[str, ...]  # [Q] (error messages)
    model: lbase.Model  # the network the learners share (its predict is greedy's default)
    simulators: tuple  # [O] sim.GraspSimulator (or any object with run_trials and config)
    object_names: tuple[str, ...]  # [O] (error messages)
    keys: jax.Array  # [O, S] (object, seed) keys: keys.object_keys


class Contexts(NamedTuple):
    """A round's contexts of every (object, seed), N per copy."""

    poses: np.ndarray  # [O, S, N, 7] resting poses (the trials' object poses)
    depth: np.ndarray  # [O, S, N, H, W] depth images, metres
    candidates: cand_lib.Candidates  # [O, S, N, K, ...]
    crops: crops_lib.Crops | None = None  # [O, S, N, K, ...] (None: not made yet)


class TrialCounts(NamedTuple):
    """Trials the policies asked for, and trials simulated (shared choices run once)."""

    requested: int
    simulated: int


class Acted(NamedTuple):
    """One exploration phase's choices of every learner copy."""

    action: np.ndarray  # [O, S, Q, E] int32 chosen candidate slots (NO_ARM: none valid)
    probs: np.ndarray | None  # [O, S, Q, E, K] the policies' distributions (None: not asked)


# ----------------------------------------------------------------------------- jitted steps


@functools.lru_cache(maxsize=4)
def batched_crops(crop_config: crops_lib.CropConfig):
    """depth [O, S, N, H, W], candidates [O, S, N, K, ...] -> Crops [O, S, N, K, ...]."""
    one = functools.partial(crops_lib.extract_batch, config=crop_config)
    return jax.jit(jax.vmap(jax.vmap(one)))


def _stack(items):
    return jax.tree.map(lambda *xs: np.stack(xs), *items)


def stack_contexts(rows) -> Contexts:
    """One round's contexts from each (object, seed)'s: ``rows[o][s]`` = (poses [N, 7],
    depth [N, H, W], candidates [N, K, ...]) -> Contexts [O, S, N, ...]."""
    poses = np.stack([[e[0] for e in row] for row in rows])
    depth = np.stack([[e[1] for e in row] for row in rows])
    cands = _stack([_stack([e[2] for e in row]) for row in rows])
    return Contexts(poses, depth, cands)


def with_crops(contexts: Contexts) -> Contexts:
    """``contexts`` with their crops (made here where missing)."""
    if contexts.crops is not None:
        return contexts
    crops = batched_crops(crops_lib.CropConfig())(contexts.depth, contexts.candidates)
    return contexts._replace(crops=crops)


def _copy_obs(image, depth, valid, u, t):
    return lbase.Obs((image, depth), valid, u, t)


@functools.lru_cache(maxsize=32)
def batched_act(act_fn, with_probs: bool = True):
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
            action, probs, _ = act_fn(jax.random.fold_in(root, e), state, obs)
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
def batched_greedy(predict):
    """Greedy on the learner's estimate: (state [O, S], image, depth, valid, u) -> action
    [O, S, N] (``sample_icdf(u, greedy_probs(r̂))``: u breaks ties)."""

    def copy(state, image, depth, valid, u):
        def one(image, depth, valid, u):
            r_hat = predict(state, _copy_obs(image, depth, valid, u, jnp.int32(0)))
            return pol.sample_icdf(u, pol.greedy_probs(r_hat, mask=valid), mask=valid)

        return jax.vmap(one)(image, depth, valid, u)

    return jax.jit(jax.vmap(jax.vmap(copy)))


@functools.lru_cache(maxsize=32)
def batched_update(update_fn):
    """update of every copy: (keys [O, S], state [O, S], batch [O, S, E, ...]) -> state."""
    return jax.jit(jax.vmap(jax.vmap(update_fn)))


@functools.lru_cache(maxsize=32)
def batched_init(init_fn):
    """init of every copy: (keys [O, S], θ0, C) -> state [O, S] (θ0 and C shared)."""
    return jax.jit(jax.vmap(jax.vmap(init_fn, (0, None, None)), (0, None, None)))


def predict_fn(learner: lbase.Learner, model: lbase.Model):
    """The learner's estimate r̂ (its ``predict``; the network's output by default)."""
    return learner.predict if learner.predict is not None else lbase.network_predict(model)


# ----------------------------------------------------------------------------- trials


def seed_noise(simulator, keys, num) -> sim_lib.TrialNoise:
    """Trial noise of each seed's key, stacked: fields [S, num, ...]; trial j of seed s is
    ``sample_noise(keys[s], num)[j]``, drawn for all seeds in one jitted call (the same
    values as one eager ``sample_noise`` per seed, tests/grasp/test_context_threads.py;
    eager, each seed would cost a dispatch)."""
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


def run_trials(simulators: Sequence, grasps, poses, noise_keys, n_per_key,
               map_fn: MapFn = map) -> tuple[np.ndarray, TrialCounts]:
    """Runs every object's trials.

    grasps [O, S, Q, N, 4], poses [O, S, N, 7], ``noise_keys[o][s]``: trial j of (o, s) uses
    ``sample_noise(noise_keys[o][s], N)[j]`` for every learner (common random numbers).
    Returns (success [O, S, Q, N] bool, the trials requested and simulated).

    Learners that pick the same grasp in trial j of (o, s) share its pose and its noise, so
    their trials are the same simulation: each distinct (s, j, grasp) runs once and its
    outcome goes to every learner that chose it. MuJoCo is deterministic and a trial does
    not depend on the others in its batch, so this gives the same outcomes bit for bit as
    simulating every copy (tests/grasp/test_runner.py checks both ways).

    ``map_fn`` maps over the objects (a thread pool's ``map`` hands each object's trials
    to its simulator from a thread of its own, so the objects' trials keep the cores busy
    together); each object's outcomes and counts are the serial ones.
    """
    num_o, num_s, num_q, num_n = grasps.shape[:4]
    out = np.zeros((num_o, num_s, num_q, num_n), bool)
    s_i, _, n_i = np.indices((num_s, num_q, num_n)).reshape(3, -1)

    def one(o):
        simulator = simulators[o]
        noise = seed_noise(simulator, noise_keys[o], n_per_key)  # [S, N, ...]
        flat = np.ascontiguousarray(grasps[o].reshape(-1, 4), np.float64)
        key = np.concatenate([s_i[:, None], n_i[:, None], flat.view(np.int64)], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        us, un = s_i[first], n_i[first]
        res = simulator.run_trials(
            flat[first], sim_lib.TrialNoise(*(a[us, un] for a in noise)),
            object_pose=poses[o][us, un])
        out[o] = res.success[inverse.reshape(-1)].reshape(num_s, num_q, num_n)
        return len(flat), len(first)

    done = list(map_fn(one, range(num_o)))
    return out, TrialCounts(sum(d[0] for d in done), sum(d[1] for d in done))


def oracle(simulators: Sequence, cands, poses, num_trials, noise_keys
           ) -> tuple[np.ndarray, TrialCounts]:
    """Success probabilities r_a(s) of every candidate of every context: [O, S, N, K].

    cands: Candidates with leading [O, S, N]; poses [O, S, N, 7]. Trial j of context n of
    (o, s) uses ``sample_noise(noise_keys[o][s], N * M)[n * M + j]`` for every candidate
    (common random numbers across candidates, as ``success_probability``); invalid
    candidates get 0. Returns the probabilities and the trials run.
    """
    valid = np.asarray(cands.valid, bool)
    grasps = np.asarray(cands.grasps, np.float64)
    num_n = valid.shape[2]
    m = num_trials
    out = np.zeros(valid.shape)
    count = 0
    for o, simulator in enumerate(simulators):
        s_i, n_i, k_i = np.nonzero(valid[o])
        if not len(s_i):
            continue
        noise = seed_noise(simulator, noise_keys[o], num_n * m)  # [S, N * M, ...]
        rows_s = np.repeat(s_i, m)
        rows_t = (n_i[:, None] * m + np.arange(m)[None]).reshape(-1)
        res = simulator.run_trials(
            np.repeat(grasps[o][s_i, n_i, k_i], m, axis=0),
            sim_lib.TrialNoise(*(a[rows_s, rows_t] for a in noise)),
            object_pose=np.repeat(np.asarray(poses[o])[s_i, n_i], m, axis=0))
        out[o][s_i, n_i, k_i] = res.success.reshape(-1, m).mean(1)
        count += len(rows_s)
    return out, TrialCounts(count, count)


def gather_grasps(grasps, action):
    """grasps [O, S, N, K, 4], action [O, S, Q, N] -> chosen grasps [O, S, Q, N, 4]
    (an invalid choice, -1, takes slot 0: its trial runs but its outcome is discarded)."""
    g = np.asarray(grasps)
    o, s, q, n = np.indices(action.shape)
    return g[o, s, n, np.maximum(action, 0)]


def check_actions(action, valid, learner_names, object_names, round_index) -> None:
    """A learner must choose a valid candidate whenever one exists: NO_ARM (or an invalid
    slot) with valid candidates is a broken learner, not a failed grasp (``LearnerError``).

    action [O, S, Q, N], valid [O, S, N, K] bool."""
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
            f"learner {learner_names[q]!r} returned {what} on {object_names[o]}, seed {s}, "
            f"round {round_index}, grasp {n} while {int(num_valid[o, s, n])} candidates were "
            "valid; a learner must choose a valid candidate whenever one exists (stopped: "
            "this would have been recorded as a failed grasp)")


# ----------------------------------------------------------------------------- the round


def init_states(copies: Copies, theta0_params, core: lbase.Data) -> list:
    """Every learner's state, [O, S] copies each, from its ``INIT`` stream of round 0."""
    init_keys = keys_lib.stream_keys(copies.keys, keys_lib.INIT, 0)
    return [batched_init(lrn.init)(init_keys, theta0_params, core) for lrn in copies.learners]


def act(copies: Copies, states: Sequence, contexts: Contexts, round_index: int,
        with_probs: bool) -> Acted:
    """Round ``round_index``'s exploration choices (round 1 is the first): every learner
    acts on its state on the E contexts of every copy, with the ``POLICY_UNIFORM`` uniforms
    (shared by the learners) and the ``ACT`` keys. ``with_probs``: also return π (the
    regret accounting needs it)."""
    contexts = with_crops(contexts)
    num_e = contexts.poses.shape[2]
    u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (num_e,))))(
        keys_lib.stream_keys(copies.keys, keys_lib.POLICY_UNIFORM, round_index)))
    crops, cands = contexts.crops, contexts.candidates
    act_root = keys_lib.stream_keys(copies.keys, keys_lib.ACT, round_index)
    t0 = jnp.int32((round_index - 1) * num_e)
    acted = [batched_act(lrn.act, with_probs)(act_root, st, crops.image, crops.depth,
                                              cands.valid, u, t0)
             for lrn, st in zip(copies.learners, states)]
    action = np.stack([np.asarray(a) for a, _ in acted], axis=2)  # [O, S, Q, E]
    probs = np.stack([np.asarray(p) for _, p in acted], axis=2) if with_probs else None
    return Acted(action, probs)


def explore_trials(copies: Copies, contexts: Contexts, action: np.ndarray,
                   round_index: int, map_fn: MapFn = map) -> tuple[np.ndarray, TrialCounts]:
    """The exploration grasps' rewards: success [O, S, Q, E] bool (a choice of no grasp
    fails) from the ``EXPLORE_TRIAL`` stream."""
    grasps = gather_grasps(contexts.candidates.grasps, action)
    success, counts = run_trials(
        copies.simulators, grasps, contexts.poses,
        keys_lib.stream_keys(copies.keys, keys_lib.EXPLORE_TRIAL, round_index),
        contexts.poses.shape[2], map_fn)
    success &= action >= 0
    return success, counts


def pseudo_regret(copies: Copies, contexts: Contexts, probs: np.ndarray, round_index: int,
                  regret_trials: int, regret_grasps: int) -> tuple[np.ndarray, TrialCounts]:
    """The round's pseudo-regret per copy [O, Q, S]: on the first ``regret_grasps`` grasps
    (0: all E), the oracle of ``regret_trials`` trials per candidate chooses the best
    candidate (``ORACLE_TRIAL``) and values every candidate on independent trials
    (``ORACLE_VALUE``); scaled by E / g (``OnlineConfig.regret_trials``)."""
    num_e = contexts.poses.shape[2]
    g = regret_grasps or num_e  # the oracle's grasps: the phase's first g
    sub = jax.tree.map(lambda x: np.asarray(x)[:, :, :g], contexts.candidates)
    (select, count_s), (value, count_v) = (
        oracle(copies.simulators, sub, contexts.poses[:, :, :g], regret_trials,
               keys_lib.stream_keys(copies.keys, stream_id, round_index))
        for stream_id in (keys_lib.ORACLE_TRIAL, keys_lib.ORACLE_VALUE))
    valid = np.asarray(sub.valid, bool)[:, :, None]
    regret = stats.oracle_regret(select[:, :, None], value[:, :, None], probs[..., :g, :],
                                 valid)  # [O, S, Q, g]
    regret = np.where(valid.any(-1), regret, 0.0)  # nothing valid: nothing lost
    counts = TrialCounts(count_s.requested + count_v.requested,
                         count_s.simulated + count_v.simulated)
    return (num_e / g) * regret.sum(-1).transpose(0, 2, 1), counts


def update(copies: Copies, states: Sequence, contexts: Contexts, action: np.ndarray,
           success: np.ndarray, round_index: int) -> list:
    """Every learner's update on the phase's (crop, action, reward) with the ``FIT`` keys:
    action and success [O, S, Q, E]. Returns the new states (dispatched, not waited for)."""
    crops = with_crops(contexts).crops
    image = np.asarray(crops.image)  # [O, S, E, K, c, c]
    cdepth = np.asarray(crops.depth)  # [O, S, E, K]
    o_i, s_i, e_i = np.indices(action[:, :, 0].shape)
    fit_keys = keys_lib.stream_keys(copies.keys, keys_lib.FIT, round_index)
    new = []
    for q, (lrn, state) in enumerate(zip(copies.learners, states)):
        idx = np.maximum(action[:, :, q], 0)
        batch = lbase.Batch((image[o_i, s_i, e_i, idx], cdepth[o_i, s_i, e_i, idx]),
                            action[:, :, q], success[:, :, q].astype(np.float32))
        new.append(batched_update(lrn.update)(fit_keys, state, batch))
    return new


def greedy_actions(copies: Copies, states: Sequence, contexts: Contexts, u) -> np.ndarray:
    """Every learner's greedy choice [O, S, Q, N] on ``contexts`` (u [O, S, N] breaks ties)."""
    crops, cands = with_crops(contexts).crops, contexts.candidates
    return np.stack([np.asarray(batched_greedy(predict_fn(lrn, copies.model))(
        st, crops.image, crops.depth, cands.valid, u))
        for lrn, st in zip(copies.learners, states)], axis=2)


def evaluate(copies: Copies, states: Sequence, contexts: Contexts, round_index: int,
             map_fn: MapFn = map) -> tuple[np.ndarray, TrialCounts]:
    """The paper's evaluation figure [O, Q, S]: the fraction of greedy grasps on
    ``contexts`` (N fresh poses per copy) that succeed, with the ``EVAL_UNIFORM`` uniforms
    and ``EVAL_TRIAL`` trials of round ``round_index``."""
    num = contexts.poses.shape[2]
    u = np.asarray(jax.vmap(jax.vmap(lambda k: jax.random.uniform(k, (num,))))(
        keys_lib.stream_keys(copies.keys, keys_lib.EVAL_UNIFORM, round_index)))
    action = greedy_actions(copies, states, contexts, u)
    grasps = gather_grasps(contexts.candidates.grasps, action)
    success, counts = run_trials(
        copies.simulators, grasps, contexts.poses,
        keys_lib.stream_keys(copies.keys, keys_lib.EVAL_TRIAL, round_index), num, map_fn)
    success &= action >= 0
    return success.mean(-1).transpose(0, 2, 1), counts


def evaluate_lowvar(copies: Copies, states: Sequence, contexts: Contexts, round_index: int,
                    eval_trials: int, map_fn: MapFn = map) -> tuple[np.ndarray, TrialCounts]:
    """The low-variance evaluation figure [O, Q, S]: the greedy grasp's success rate over
    ``eval_trials`` trials (``LOWVAR_TRIAL`` of round ``round_index``) on each of the P
    fixed poses of ``contexts``, averaged over the poses."""
    num_o, num_s, num_p = contexts.poses.shape[:3]
    u0 = np.zeros((num_o, num_s, num_p), np.float32)
    action = greedy_actions(copies, states, contexts, u0)  # [O, S, Q, P]
    grasps = gather_grasps(contexts.candidates.grasps, action)  # [O, S, Q, P, 4]
    m = eval_trials
    rep_grasps = np.repeat(grasps, m, axis=3)
    rep_poses = np.repeat(contexts.poses, m, axis=2)
    success, counts = run_trials(
        copies.simulators, rep_grasps, rep_poses,
        keys_lib.stream_keys(copies.keys, keys_lib.LOWVAR_TRIAL, round_index), num_p * m,
        map_fn)
    success = success.reshape(num_o, num_s, len(copies.learners), num_p, m)
    success &= (action >= 0)[..., None]
    return success.mean((-1, -2)).transpose(0, 2, 1), counts
