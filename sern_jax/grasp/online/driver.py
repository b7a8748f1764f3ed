"""Algorithm 1 for grasping, batched: the host loop of ``sern grasp learn``.

:func:`run` drives :mod:`sern_jax.grasp.online.step`'s round (exploration, update,
evaluation of every (object, learner, seed) copy at once) over the run's rounds, as brax's
``train`` drives its ``training_step``: it makes the contexts ahead of need in threads,
runs each round's evaluation beside the next round, writes the checkpoint
(:mod:`sern_jax.grasp.online.checkpoint`) and shows progress. Round 0 evaluates θ0 before
any learning (the baseline the paper's Table I leaves out). Learners are
``sern_jax.learners`` triples named in ``OnlineConfig.policies``
(:mod:`sern_jax.grasp.online.config`); physics runs on the native MuJoCo backend (CPU) or
MJX.

Overlap: round r's evaluation needs only the states after round r's update, and round
r + 1's exploration needs the same states and nothing the evaluation makes, so the
evaluation runs in a thread of its own while the main thread explores and updates round
r + 1 (their trials share the native trial workers, their forward passes the device).
Every output is keyed by stream, pose and grasp (:mod:`sern_jax.grasp.online.keys`), never
by order, so the results are those of running the phases one after another, bit for bit
(``DriverOptions(overlap_evaluation=False)``; tests/grasp/test_runner.py). The checkpoint
is written when a round's evaluation ends and holds that round and the ones before it only.

Contexts: every (object, seed)'s batch of contexts is made in threads of its own (MuJoCo's
settling and ray casting and JAX's sampler release the GIL; each batch has its own MjData
and keys, the models are only read), so the batches of a round use the cores instead of
one. A batch is made in two stages: its resting poses settle (native MuJoCo, CPU only) in a
settling thread, then a batch thread renders the depth images and samples the candidates
(the device, and on a GPU one compile per object and batch size). Each batch settles its
poses in its own thread (``threads=1``) rather than in a nested pool. The settling threads
run at a lower CPU priority (``context.lower_priority``, on a many-core host): they work
ahead of need, and the main thread, the evaluation, the trial workers and the compiles come
first. With ``settle_ahead`` every batch's poses are queued to settle when the run starts,
in the order the run queues the batches, so the settling threads fill the cores that the
first compiles leave idle and later rounds only render; otherwise a batch's poses are queued
with the batch. Same keys, same poses: results unchanged.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import checkpoint
from sern_jax.grasp.online import config as config_lib
from sern_jax.grasp.online import keys as keys_lib
from sern_jax.grasp.online import step
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import base as lbase

__all__ = [
    "DriverOptions",
    "context_order",
    "contexts",
    "contexts_of_stream",
    "poses_of_stream",
    "run",
]


@dataclasses.dataclass(frozen=True)
class DriverOptions:
    """How :func:`run` schedules its work; the results do not depend on it (tested).

    Attributes:
      overlap_evaluation: round r's evaluation runs in a thread of its own beside round
        r + 1's exploration and update; False runs the phases one after another (the
        reference the tests compare with: the same results and checkpoints, bit for bit).
      max_queued_evaluations: most evaluations queued at once (each holds its round's
        learner states): the main thread explores at most this many rounds ahead of the
        evaluation thread.
      settle_ahead: every batch's resting poses are queued to settle when the run starts;
        None: on a many-core host (``context.many_cores``), the other behaviour elsewhere.
    """

    overlap_evaluation: bool = True
    max_queued_evaluations: int = 2
    settle_ahead: bool | None = None

    def __post_init__(self):
        if not isinstance(self.overlap_evaluation, bool):
            raise ValueError(f"overlap_evaluation must be a bool, got "
                             f"{self.overlap_evaluation!r}")
        n = self.max_queued_evaluations
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"max_queued_evaluations must be an integer >= 1, got {n!r}")
        if self.settle_ahead is not None and not isinstance(self.settle_ahead, bool):
            raise ValueError(f"settle_ahead must be a bool or None, got {self.settle_ahead!r}")

    @property
    def queue_limit(self) -> int:
        """Evaluations queued at once (1 where they do not overlap)."""
        return self.max_queued_evaluations if self.overlap_evaluation else 1


# ----------------------------------------------------------------------------- contexts


def contexts(key, spec, num, model, config=context_lib.ContextConfig(), poses=None,
             threads=None):
    """Contexts of one object as numpy (poses [n, 7], depth [n, H, W], candidates [n, K]);
    ``poses``: their resting poses where settled ahead; ``threads``: the threads that
    settle them otherwise (``context.make_contexts``)."""
    ctx = context_lib.make_contexts(key, spec, num, config, model=model, poses=poses,
                                    threads=threads)
    return ctx.poses, ctx.depth, ctx.candidates


def poses_of_stream(key_os, stream_id, r, num, model, config):
    """``context.resting_poses`` of ``keys.stream(key_os, stream_id, r)``, settled in the
    calling thread: a batch's settling stage, in a settling thread."""
    return context_lib.resting_poses(keys_lib.stream(key_os, stream_id, r), num, model,
                                     config, threads=1)


def contexts_of_stream(key_os, stream_id, r, spec, num, model, config, settled=None):
    """:func:`contexts` of ``keys.stream(key_os, stream_id, r)`` in the calling (batch)
    thread, the key derived there rather than by the main thread that queues the batch;
    ``settled``: a future of the batch's resting poses (:func:`poses_of_stream`), waited
    for here."""
    poses = None if settled is None else settled.result()
    return contexts(keys_lib.stream(key_os, stream_id, r), spec, num, model, config, poses,
                    threads=1)


def context_order(config: config_lib.OnlineConfig, start_round: int
                  ) -> list[tuple[int, int, int]]:
    """The order the run queues its batches of contexts, as (stream, round, size): the
    fixed low-variance evaluation poses, round 0's evaluation contexts, round 1's
    exploration contexts, then each round's evaluation and the next round's exploration
    contexts (a resumed run: its replay's exploration contexts first). On a GPU each batch
    size of each object is a compile of its own, made in that order, so the evaluations,
    the longer chain of the two threads, start first."""
    need = [(keys_lib.LOWVAR_CONTEXT, 0, config.eval_poses)] if config.eval_poses else []
    if start_round == 0:
        need.append((keys_lib.EVAL_CONTEXT, 0, config.evaluate))
    need += [(keys_lib.EXPLORE_CONTEXT, r, config.explore)
             for r in range(1, max(start_round, 1) + 1)]
    for r in range(max(start_round, 1), config.rounds + 1):
        need += [(keys_lib.EVAL_CONTEXT, r, config.evaluate),
                 (keys_lib.EXPLORE_CONTEXT, r + 1, config.explore)]
    return [n for n in need if n[1] <= config.rounds]


class _ContextQueue:
    """The run's batches of contexts, made ahead of need in two pools of threads (module
    docstring): settling threads for the resting poses, batch threads for the rest."""

    def __init__(self, keys_os, specs, models, context_config, sizes: dict[str, int],
                 num_rounds: int):
        self._keys_os, self._specs, self._models = keys_os, specs, models
        self._context_config, self._sizes, self._num_rounds = context_config, sizes, num_rounds
        self._streams = {"explore": keys_lib.EXPLORE_CONTEXT, "eval": keys_lib.EVAL_CONTEXT}
        shape = (len(keys_os), len(keys_os[0]))
        threads = max(1, min(shape[0] * shape[1], context_lib.context_threads()))
        self._batches = concurrent.futures.ThreadPoolExecutor(
            threads, thread_name_prefix="sern-context-batch")
        self._settlers = concurrent.futures.ThreadPoolExecutor(
            threads, thread_name_prefix="sern-context-settle",
            initializer=context_lib.lower_priority)
        self._settling = {}  # (stream, r) -> [O][S] futures of resting poses [N, 7]
        self._pending = {}  # (kind, r) -> [O][S] futures of contexts

    def settle(self, stream_id: int, r: int, num: int) -> None:
        """Queues the resting poses of batch (stream_id, r) to settle (once)."""
        if (stream_id, r) not in self._settling:
            self._settling[(stream_id, r)] = [
                [self._settlers.submit(poses_of_stream, key, stream_id, r, num, model,
                                       self._context_config) for key in row]
                for row, model in zip(self._keys_os, self._models)]

    def submit(self, stream_id: int, r: int, num: int) -> list:
        """Queues batch (stream_id, r) of every (object, seed): [O][S] futures."""
        self.settle(stream_id, r, num)
        settled = self._settling.pop((stream_id, r))
        return [[self._batches.submit(contexts_of_stream, key, stream_id, r, spec, num, model,
                                      self._context_config, poses)
                 for key, poses in zip(row, settled_row)]
                for row, spec, model, settled_row in zip(self._keys_os, self._specs,
                                                         self._models, settled)]

    def prefetch(self, kind: str, r: int) -> None:
        """Queues the ``kind`` ("explore" or "eval") contexts of round r (once)."""
        if r <= self._num_rounds and (kind, r) not in self._pending:
            self._pending[(kind, r)] = self.submit(self._streams[kind], r, self._sizes[kind])

    def take(self, kind: str, r: int) -> list:
        """The queued jobs of (kind, r), queued now if they were not."""
        self.prefetch(kind, r)
        return self._pending.pop((kind, r))

    @staticmethod
    def gather(jobs) -> step.Contexts:
        """The contexts of [O][S] jobs, stacked [O, S, N, ...] (waits for them)."""
        return step.stack_contexts([[job.result() for job in row] for row in jobs])

    def close(self) -> None:
        self._batches.shutdown(wait=False, cancel_futures=True)
        self._settlers.shutdown(wait=False, cancel_futures=True)


# ----------------------------------------------------------------------------- host state


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


class _Meters:
    """Seconds per phase and trial counts of this call; the main and the evaluation thread
    both add to them (under a lock)."""

    def __init__(self, phases):
        self.timings = {k: 0.0 for k in phases}
        self.trial_counts = {"requested": 0, "simulated": 0}  # not resumed rounds
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def phase(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            with self._lock:
                self.timings[name] += time.perf_counter() - t

    def count(self, counts: step.TrialCounts) -> None:
        with self._lock:
            self.trial_counts["requested"] += counts.requested
            self.trial_counts["simulated"] += counts.simulated


class _Evaluations:
    """The evaluations, one after another in a thread of their own, beside the main
    thread's exploration (module docstring). After one fails, none runs (each saves the
    checkpoint through its round: a later checkpoint would claim the failed round)."""

    def __init__(self, options: DriverOptions, meters: _Meters):
        self._options, self._meters = options, meters
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sern-evaluate")
        self._queued = []  # futures queued and not yet waited for, in round order
        self._failed = threading.Event()

    def submit(self, r: int, fn: Callable, *args) -> None:
        """Queues ``fn(*args)``, round r's evaluation, once fewer than the options' limit
        are queued (each holds its round's learner states)."""
        while len(self._queued) >= self._options.queue_limit:
            with self._meters.phase("wait"):
                self._queued.pop(0).result()
        self._queued.append(self._pool.submit(self._guarded, r, fn, *args))
        if not self._options.overlap_evaluation:
            self.wait_all()

    def _guarded(self, r: int, fn: Callable, *args) -> None:
        if self._failed.is_set():
            raise concurrent.futures.CancelledError(f"round {r}: an earlier evaluation failed")
        try:
            fn(*args)
        except BaseException:
            self._failed.set()
            raise

    def wait_all(self) -> None:
        with self._meters.phase("wait"):
            while self._queued:
                self._queued.pop(0).result()

    def raise_failed(self) -> None:
        """A queued evaluation's error, raised in the main thread as soon as it is known."""
        for job in self._queued:
            if job.done() and job.exception() is not None:
                job.result()

    def settle_after(self, err: BaseException) -> None:
        """After the main thread stopped with ``err``: the rounds already explored keep
        their evaluations, which finish and save (on an interrupt only the one running:
        those not started are dropped); their own errors give way to ``err``."""
        for job in self._queued:
            if isinstance(err, KeyboardInterrupt):
                job.cancel()
        for job in self._queued:
            if not job.cancelled():
                try:
                    job.result()
                except BaseException:
                    pass

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


# ----------------------------------------------------------------------------- the run


class _Setup(NamedTuple):
    """A run's fixed inputs, checked: what :func:`run` derives before any round."""

    config: config_lib.OnlineConfig
    specs: tuple[objects_lib.ObjectSpec, ...]  # [O]
    seeds: tuple[int, ...]  # [S] seed indices
    fingerprint: str
    theta0: artifacts.Theta0
    core: lbase.Data  # the core set C
    copies: step.Copies
    keys_os: list  # [O][S] (object, seed) keys (the context batches')
    scene_models: list  # [O] scene models
    context_config: context_lib.ContextConfig


def _setup(config, specs, theta0, context_config, trial_config, learners, seed_indices
           ) -> _Setup:
    """Checks the inputs and builds the run's learners, keys, scenes and simulators."""
    names = [s.name for s in specs]
    if not names:
        raise ValueError("no objects given")
    if len(set(names)) != len(names):
        raise ValueError(f"objects must be distinct, got {names}")
    theta0 = theta0 or artifacts.load_theta0()
    model = config_lib.quality_model(config_lib.copies_network(theta0.network.config))
    seeds = config_lib.check_seed_indices(config, seed_indices)
    context_config = context_config or context_lib.ContextConfig()
    trial_config = trial_config or sim_lib.TrialConfig()
    custom = dict(learners or {})
    fingerprint = config_lib.extend_fingerprint(
        config_lib.run_fingerprint(config, specs, theta0), config, seeds, context_config,
        trial_config, tuple(custom))
    chosen = tuple(custom.get(n) or config_lib.make_learner(config, n, model)
                   for n in config.policies)
    root = jax.random.key(config.seed)
    keys_os = [[keys_lib.object_key(root, n, s) for s in seeds] for n in names]
    scene_models = [context_lib.scene_model(spec, context_config) for spec in specs]
    simulators = tuple(sim_lib.GraspSimulator(m, backend=config.backend, config=trial_config,
                                              mjx_batch=config_lib.MJX_BATCH)
                       for m in scene_models)
    keys_arr = jax.numpy.stack([jax.numpy.stack(row) for row in keys_os])  # [O, S]
    copies = step.Copies(chosen, tuple(config.policies), model, simulators, tuple(names),
                         keys_arr)
    return _Setup(config, tuple(specs), seeds, fingerprint, theta0,
                  config_lib.core_data(config.core_set, theta0), copies, keys_os,
                  scene_models, context_config)


class _Loop:
    """One call of :func:`run` from its first round on: the learners' states, the results,
    the context queue, the evaluation thread, timings and progress."""

    def __init__(self, setup: _Setup, options: DriverOptions, out_dir: Path, start_round: int,
                 results: checkpoint.RoundResults, rewards: np.ndarray, log, bar,
                 progress: bool, t_run: float):
        self.setup, self.options, self.out_dir = setup, options, out_dir
        self.results, self.rewards, self.t_run = results, rewards, t_run
        self.log, self.bar, self.progress = log, bar, progress
        config = setup.config
        self.copies = setup.copies
        phases = ("contexts", "choose", "trials", "update", "evaluate", "wait")
        self.meters = _Meters(phases + (("oracle",) if config.regret_trials else ()))
        num_o = len(setup.specs)
        self.trial_map = _object_pool().map if num_o > 1 else map
        self.states = step.init_states(self.copies, setup.theta0.params, setup.core)
        self.queue = _ContextQueue(setup.keys_os, setup.specs, setup.scene_models,
                                   setup.context_config,
                                   {"explore": config.explore, "eval": config.evaluate},
                                   config.rounds)
        self.evaluations = _Evaluations(options, self.meters)
        ahead = context_lib.many_cores() if options.settle_ahead is None else options.settle_ahead
        if ahead and start_round <= config.rounds:  # (a finished run needs none)
            for stream_id, r, num in context_order(config, start_round):
                self.queue.settle(stream_id, r, num)
        # the fixed low-variance poses: queued first, gathered when the first evaluation
        # needs them
        self._lowvar_jobs = (self.queue.submit(keys_lib.LOWVAR_CONTEXT, 0, config.eval_poses)
                             if config.eval_poses and start_round <= config.rounds else None)
        self._lowvar = None

    def close(self) -> None:
        self.evaluations.close()
        self.queue.close()

    def contexts(self, kind: str, r: int, jobs=None) -> step.Contexts:
        with self.meters.phase("contexts"):
            return self.queue.gather(self.queue.take(kind, r) if jobs is None else jobs)

    def _lowvar_contexts(self) -> step.Contexts:
        if self._lowvar is None:  # (the evaluation thread only)
            self._lowvar = step.with_crops(self.queue.gather(self._lowvar_jobs))
        return self._lowvar

    def evaluate_and_save(self, r: int, states: list, jobs) -> None:
        """Round r's evaluation of ``states`` (the learners' states after round r's
        update) on the contexts of ``jobs``, then the checkpoint through round r; runs in
        the evaluation thread."""
        config, copies = self.setup.config, self.copies
        ctx = self.contexts("eval", r, jobs)
        with self.meters.phase("evaluate"):
            paper, counts = step.evaluate(copies, states, ctx, r, self.trial_map)
            self.meters.count(counts)
            self.results.paper_eval[r] = paper
            if config.eval_poses:
                lowvar, counts = step.evaluate_lowvar(copies, states, self._lowvar_contexts(),
                                                      r, config.eval_trials, self.trial_map)
                self.meters.count(counts)
                self.results.lowvar_eval[r] = lowvar
        checkpoint.save(self.out_dir / checkpoint.CHECKPOINT, self.setup.fingerprint,
                        *checkpoint.through(self.results, self.rewards, r + 1), r + 1)
        self.bar.update(1)
        if not self.progress:  # a line per round where there is no bar (device logs)
            self.log(f"round {r}/{config.rounds} saved at "
                     f"{time.perf_counter() - self.t_run:.0f} s; "
                     + ", ".join(f"{k} {v:.0f} s" for k, v in self.meters.timings.items()))

    def queue_evaluation(self, r: int) -> None:
        self.evaluations.submit(r, self.evaluate_and_save, r, list(self.states),
                                self.queue.take("eval", r))

    def update(self, r: int, ctx: step.Contexts, action, success) -> None:
        """Every learner's update on round r's (crop, action, reward); action and success
        [O, S, Q, E]."""
        with self.meters.phase("update"):
            self.states = step.update(self.copies, self.states, ctx, action, success, r)
            jax.block_until_ready(self.states)

    def replay(self, start_round: int) -> None:
        """The learners' states after round start_round - 1, rebuilt from the checkpoint:
        each finished round's update on its recomputed contexts and saved choices and
        rewards (the computation of the uninterrupted run)."""
        t = time.perf_counter()
        for r in range(1, start_round):
            ctx = step.with_crops(self.contexts("explore", r))
            self.queue.prefetch("explore", r + 1)
            self.update(r, ctx, self.results.explore_action[r].transpose(0, 2, 1, 3),
                        self.rewards[r] > 0)
        self.log(f"replayed rounds 1..{start_round - 1} in {time.perf_counter() - t:.1f} s")

    def explore_round(self, r: int) -> None:
        """Round r (>= 1): exploration, update, and its evaluation queued."""
        config, copies, meters = self.setup.config, self.copies, self.meters
        self.evaluations.raise_failed()
        ctx = self.contexts("explore", r)
        self.queue.prefetch("eval", r)
        self.queue.prefetch("explore", r + 1)
        with meters.phase("choose"):
            ctx = step.with_crops(ctx)
            # π itself is needed only by the regret accounting (its pseudo-regret)
            acted = step.act(copies, self.states, ctx, r, bool(config.regret_trials))
        step.check_actions(acted.action, np.asarray(ctx.candidates.valid, bool),
                           copies.learner_names, copies.object_names, r)
        with meters.phase("trials"):
            success, counts = step.explore_trials(copies, ctx, acted.action, r,
                                                  self.trial_map)
            meters.count(counts)
        self.results.explore_success[r] = success.mean(-1).transpose(0, 2, 1)
        self.results.explore_action[r] = acted.action.transpose(0, 2, 1, 3)
        self.rewards[r] = success
        if config.regret_trials:
            with meters.phase("oracle"):
                regret, counts = step.pseudo_regret(copies, ctx, acted.probs, r,
                                                    config.regret_trials, config.regret_grasps)
                meters.count(counts)
            self.results.pseudo_regret[r] = regret
        self.update(r, ctx, acted.action, success)
        self.queue_evaluation(r)

    def rounds(self, start_round: int) -> None:
        """Rounds start_round..R and their evaluations (round 0's where start_round is 0)."""
        num_r = self.setup.config.rounds
        if start_round == 0:
            self.queue.prefetch("eval", 0)
            self.queue.prefetch("explore", 1)
            self.queue_evaluation(0)
            start_round = 1
        if 1 < start_round <= num_r:
            self.replay(start_round)
        try:
            for r in range(start_round, num_r + 1):
                self.explore_round(r)
            self.evaluations.wait_all()
        except BaseException as err:
            # keep the rounds already explored: their evaluations finish and save their
            # checkpoints before the context pools stop
            self.evaluations.settle_after(err)
            raise


def run(
    config: config_lib.OnlineConfig,
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
    options: DriverOptions | None = None,
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

    ``options`` (:class:`DriverOptions`; None: the defaults) schedules the work: the
    evaluation beside the next round or not, how far ahead, when poses settle. The results
    and checkpoints are the same bits whatever they are.

    After each finished round ``out_dir/checkpoint.npz`` saves the results and every
    exploration grasp's reward (kilobytes: no learner state). Rerunning the same command
    resumes after the last finished round: the learners' states are rebuilt by replaying
    init and each finished round's update on the same inputs (the exploration contexts
    recomputed from their keys, the saved choices and rewards), which is the computation
    of the uninterrupted run, so it gives the same results (tests/grasp/test_runner.py).
    A run that had already finished returns its results with ``states`` None (nothing is
    replayed).

    Returns:
      {"table": Table I rows (``checkpoint.table_rows``), "results": RoundResults
      [R + 1, O, Q, S], "timings": seconds per phase, "trial_counts": trials requested and
      simulated in this call, "objects", "seed_indices", "fingerprint", "config", "states":
      each learner's final state [O, S] (None: finished before this call)}.
    """
    t_run = time.perf_counter()
    options = DriverOptions() if options is None else options
    if not isinstance(options, DriverOptions):
        raise ValueError(f"options must be a DriverOptions, got {type(options).__name__}")
    setup = _setup(config, specs, theta0, context_config, trial_config, learners,
                   seed_indices)
    out_dir = Path(out_dir)
    results, rewards = checkpoint.empty_results(config.rounds, len(specs),
                                                len(config.policies), len(setup.seeds),
                                                config.explore)
    start_round = 0
    saved = checkpoint.load(out_dir / checkpoint.CHECKPOINT, setup.fingerprint, out_dir)
    if saved is not None:
        results, rewards, start_round = saved
        log(f"resuming {out_dir} at round {start_round}")
    out_dir.mkdir(parents=True, exist_ok=True)

    from tqdm.auto import tqdm

    bar = tqdm(total=config.rounds + 1, initial=start_round, unit="round", desc="learn",
               disable=not progress)
    loop = None
    try:
        loop = _Loop(setup, options, out_dir, start_round, results, rewards, log, bar,
                     progress, t_run)
        loop.rounds(start_round)
    finally:
        bar.close()
        if loop is not None:
            loop.close()
    rows = checkpoint.table_rows([s.name for s in specs], config.policies, results.paper_eval,
                                 results.lowvar_eval if config.eval_poses else None,
                                 results.pseudo_regret if config.regret_trials else None)
    return {"table": rows, "results": results, "timings": loop.meters.timings,
            "trial_counts": loop.meters.trial_counts, "objects": [s.name for s in specs],
            "seed_indices": setup.seeds, "fingerprint": setup.fingerprint, "config": config,
            "states": None if start_round > config.rounds else loop.states}
