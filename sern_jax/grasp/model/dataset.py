"""Pretraining data D0 from the simulator: labelled grasps of many objects, stored in shards.

A *context* is one resting pose of one object: its depth image and the 64 antipodal candidates
sampled on it (``context.make_contexts``). D0 holds, for every context, the depth image, the
candidates and **one Bernoulli outcome per valid candidate**: one randomised trial, as a robot
would see it (``label`` 1 = success, 0 = failure, -1 = invalid slot, not simulated). That is the
label GQ-CNN is trained on; success *frequencies* over many trials are what the held-out
evaluation of ``pretrain`` compares against (:func:`label_contexts` with ``num_trials > 1``).

Crops are not stored: they are a cheap, deterministic function of the depth image and the
candidate (``crops.extract``), so a shard keeps the raw observation (images of 96×96 float32,
compressed) and the pretraining code crops on the fly.

Layout of a dataset directory::

    config.json          the DatasetConfig and its fingerprint (a rerun must match it)
    shard_00000.npz      objects [i*objects_per_shard, (i+1)*objects_per_shard)
    ...
    summary.json         counts and class balance, written when every shard exists
    .sern.lock           the run-directory lock (``io.run_lock``): one writer at a time

Shards are verified npz files (``io.save_npz``: zip CRCs and a SHA-256 inside). A rerun
re-reads every existing shard: a damaged one (truncated, empty, overwritten) is moved aside to
``shard_XXXXX.npz.damaged``, reported as ``damaged -> recomputing`` and simulated again (a
shard is deterministic, so the recomputed file holds the same arrays). :func:`load` refuses a
damaged shard in one line naming it.

Randomness: object i is ``objects.sample_population(seed, ...)[i]``; its contexts use
``fold_in(fold_in(key(seed), i), CONTEXT_STREAM)`` and its trials
``fold_in(fold_in(key(seed), i), TRIAL_STREAM)`` (:func:`label_contexts` on
``fold_in(key(seed), i)``), so a shard's content does not depend on how many shards ran
before it or on an interrupt.

Backends: ``"native"`` labels one object after another (:func:`label_contexts`). ``"mjx"``
labels a whole shard at once (:func:`label_shards_mjx`): the shard's contexts are made on the
host in a thread pool, then every valid trial of the shard runs in one
``sim.UniformBatch`` call of a fixed shape (objects ``objects_per_shard``, trials
``poses_per_object * 64 * trials_per_grasp`` per object, padded with repeats whose results are
dropped), so every shard runs the same one compiled program; the next shard's contexts are made
while this shard's trials run. The draws are those of :func:`label_contexts`.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path
from typing import Callable, Iterator, NamedTuple, Sequence

import jax
import numpy as np

from sern_jax.infra import hosts, io
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import sim as sim_lib

__all__ = [
    "CONTEXT_STREAM",
    "TRIAL_STREAM",
    "DatasetConfig",
    "LabelledContexts",
    "label_contexts",
    "label_shards_mjx",
    "generate",
    "load",
    "dataset_objects",
    "shard_paths",
    "write_shard",
]

CONTEXT_STREAM = 0
TRIAL_STREAM = 1
MJX_BATCH = 8192  # MJX trials per compiled call of label_contexts: one program for all
# The MJX shard path (label_shards_mjx): its version is part of an MJX dataset's fingerprint
# (a shard's trials run as one objects x trials program, whose float32 results may differ in
# the last bits from one object's trials run alone).
MJX_SHARD_PROGRAM = "shard-objects-x-trials-1"
MJX_CALL_TRIALS = 65_536  # most trials (objects x trials) of one compiled MJX shard call
_CONTEXT_CONFIG = context_lib.ContextConfig(renderer="native")
_SHARD_KEYS = ("object_index", "pose", "depth", "grasps", "valid", "center_px",
               "angle_px", "grasp_depth", "label", "successes", "nan_count")


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """What D0 is made of.

    Attributes:
      seed: population seed (objects, poses, candidates and trial noise all follow from it).
      num_objects: procedural training objects (``objects.POPULATION_KINDS``).
      poses_per_object: resting poses (contexts) per object.
      trials_per_grasp: randomised trials per valid candidate; 1 = one Bernoulli label as a
        robot would see it (D0's default), more = success frequencies (evaluation sets).
      objects_per_shard: objects per saved shard (the unit of resume).
      backend: ``"native"`` (MuJoCo C, CPU) or ``"mjx"`` (GPU).
    """

    seed: int = 0
    num_objects: int = 200
    poses_per_object: int = 16
    trials_per_grasp: int = 1
    objects_per_shard: int = 10
    backend: str = "native"

    def __post_init__(self):
        for name in ("num_objects", "poses_per_object", "trials_per_grasp",
                     "objects_per_shard"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.backend not in sim_lib.BACKENDS:
            raise ValueError(f"backend must be one of {sim_lib.BACKENDS}, got {self.backend!r}")
        if not 0 <= int(self.seed) < 2**31:
            raise ValueError(f"seed must be in [0, 2**31), got {self.seed}")
        if self.num_objects * self.poses_per_object > 10_000_000:
            raise ValueError(
                f"{self.num_objects} objects x {self.poses_per_object} poses is "
                f"{self.num_objects * self.poses_per_object:,} contexts; the limit is 10M")

    @property
    def num_shards(self) -> int:
        return math.ceil(self.num_objects / self.objects_per_shard)

    @property
    def max_grasps(self) -> int:
        """Candidate slots (an upper bound on labelled grasps: invalid slots get none)."""
        return self.num_objects * self.poses_per_object * 64

    def fingerprint(self) -> str:
        """Hash of everything that determines the shards (not the backend's speed): this
        config and the simulated world it is labelled in (``sim.physics_settings()``: the
        default scene and trial), so a D0 made under another trial is another dataset."""
        d = dataclasses.asdict(self)
        d["physics"] = sim_lib.physics_settings()
        if self.backend == "mjx":  # MJX trials run on the uniform scenes: their version too
            from sern_jax.grasp.world import uniform

            d["mjx_program"] = uniform.MJX_PROGRAM
            d["mjx_shard_program"] = MJX_SHARD_PROGRAM
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


class LabelledContexts(NamedTuple):
    """P contexts of one object with their outcomes (numpy; K = 64 candidate slots)."""

    pose: np.ndarray  # [P, 7] object resting pose
    depth: np.ndarray  # [P, H, W] depth image, metres
    grasps: np.ndarray  # [P, K, 4] (x, y, z, θ)
    valid: np.ndarray  # [P, K] bool
    center_px: np.ndarray  # [P, K, 2] grasp centre pixel (u, v)
    angle_px: np.ndarray  # [P, K] jaw axis angle in the image
    grasp_depth: np.ndarray  # [P, K] planar depth of the grasp centre
    successes: np.ndarray  # [P, K] successes out of trials_per_grasp (0 for invalid)
    nan_count: np.ndarray  # [P, K] diverged trials (counted as failures)
    label: np.ndarray  # [P, K] int8: one outcome (first trial) 1/0, -1 = invalid


def dataset_objects(config: DatasetConfig) -> list[objects_lib.ObjectSpec]:
    """The training objects of ``config`` (procedural population, seed ``config.seed``)."""
    return objects_lib.sample_population(config.seed, config.num_objects)


def label_contexts(
    key: jax.Array,
    spec: objects_lib.ObjectSpec,
    num_poses: int,
    num_trials: int = 1,
    backend: str = "native",
    context_config: context_lib.ContextConfig = _CONTEXT_CONFIG,
    trial: sim_lib.TrialConfig = sim_lib.TrialConfig(),
) -> LabelledContexts:
    """Simulates the candidates of ``num_poses`` resting poses of one object.

    Args:
      key: consumed; contexts use ``fold_in(key, CONTEXT_STREAM)``, trials
        ``fold_in(key, TRIAL_STREAM)``.
      spec: the object.
      num_poses: P contexts (resting poses).
      num_trials: randomised trials per valid candidate (trial j of every candidate of a
        context shares one noise draw: common random numbers).
      backend: simulator backend.
      context_config: camera / candidate / scene settings (default: the native renderer,
        which gives the same images on every backend without a compile per object).
      trial: the trial (D0 uses the default).

    Returns:
      LabelledContexts with leading axis P.
    """
    if num_poses < 1 or num_trials < 1:
        raise ValueError(f"num_poses and num_trials must be >= 1, got {num_poses}, {num_trials}")
    key_ctx = jax.random.fold_in(key, CONTEXT_STREAM)
    key_trials = jax.random.fold_in(key, TRIAL_STREAM)
    ctx = context_lib.make_contexts(key_ctx, spec, num_poses, context_config)
    return _label_trials(ctx, key_trials, num_trials, backend, trial)


class _TrialPlan(NamedTuple):
    """The trials of one object's contexts: n valid candidates x M trials, in the order
    (candidate, trial)."""

    pi: np.ndarray  # [n] context of each valid candidate
    ki: np.ndarray  # [n] slot of each valid candidate
    grasps: np.ndarray  # [n * M, 4] commanded grasps
    noise: sim_lib.TrialNoise  # [n * M] draws
    poses: np.ndarray  # [n * M, 7] object start poses


def _trial_plan(ctx, key_trials: jax.Array, num_trials: int,
                trial: sim_lib.TrialConfig) -> _TrialPlan:
    """Trial j of every valid candidate of context p uses the draw
    ``fold_in(key_trials, p * num_trials + j)`` (common random numbers in a context)."""
    valid = np.asarray(ctx.candidates.valid, bool)  # [P, K]
    grasps = np.asarray(ctx.candidates.grasps, np.float64)
    pi, ki = np.nonzero(valid)
    if not len(pi):
        return _TrialPlan(pi, ki, np.zeros((0, 4)), sim_lib.zero_noise(0),
                          np.zeros((0, 7)))
    num_p = valid.shape[0]
    noise = sim_lib.sample_noise(key_trials, num_p * num_trials, trial)
    idx = (pi[:, None] * num_trials + np.arange(num_trials)[None, :]).reshape(-1)
    return _TrialPlan(
        pi, ki, np.repeat(grasps[pi, ki], num_trials, axis=0),
        sim_lib.TrialNoise(*(np.asarray(a)[idx] for a in noise)),
        np.repeat(np.asarray(ctx.poses)[pi], num_trials, axis=0))


def _labelled(ctx, plan: _TrialPlan, res: sim_lib.TrialResult | None,
              num_trials: int) -> LabelledContexts:
    """LabelledContexts of ``ctx`` from the results of its plan's trials (None: no valid
    candidate, nothing simulated)."""
    cands = ctx.candidates
    valid = np.asarray(cands.valid, bool)
    num_p, num_k = valid.shape
    successes = np.zeros((num_p, num_k), np.int32)
    nan_count = np.zeros((num_p, num_k), np.int32)
    first = np.full((num_p, num_k), -1, np.int8)
    pi, ki = plan.pi, plan.ki
    if len(pi):
        n = len(pi)
        succ = res.success.reshape(n, num_trials)
        successes[pi, ki] = succ.sum(1)
        nan_count[pi, ki] = res.nan.reshape(n, num_trials).sum(1)
        first[pi, ki] = succ[:, 0].astype(np.int8)
    return LabelledContexts(
        pose=np.asarray(ctx.poses, np.float64),
        depth=np.asarray(ctx.depth, np.float32),
        grasps=np.asarray(cands.grasps, np.float64).astype(np.float32),
        valid=valid,
        center_px=np.asarray(cands.center_px, np.float32),
        angle_px=np.asarray(cands.angle_px, np.float32),
        grasp_depth=np.asarray(cands.grasp_depth, np.float32),
        successes=successes,
        nan_count=nan_count,
        label=first,
    )


def _label_trials(ctx, key_trials: jax.Array, num_trials: int, backend: str,
                  trial: sim_lib.TrialConfig) -> LabelledContexts:
    """Runs the trials of one object's contexts on ``backend`` (one simulator per object)."""
    plan = _trial_plan(ctx, key_trials, num_trials, trial)
    res = None
    if len(plan.pi):
        simulator = sim_lib.GraspSimulator(ctx.model, backend=backend, config=trial,
                                           mjx_batch=MJX_BATCH)
        res = simulator.run_trials(plan.grasps, plan.noise, object_pose=plan.poses)
    return _labelled(ctx, plan, res, num_trials)


# ----------------------------------------------------------------------------- MJX shards


class _Prepared(NamedTuple):
    """One object of an MJX shard, made on the host."""

    index: int  # object index in the dataset
    ctx: context_lib.GraspContexts
    plan: _TrialPlan
    uniform: tuple  # sim.UniformBatch.prepare(ctx.model, shape)


def _prepare_object(root: jax.Array, index: int, spec, config: DatasetConfig,
                    trial: sim_lib.TrialConfig, shape, threads: int,
                    context_config: context_lib.ContextConfig = _CONTEXT_CONFIG) -> _Prepared:
    key = jax.random.fold_in(root, index)
    key_ctx = jax.random.fold_in(key, CONTEXT_STREAM)
    key_trials = jax.random.fold_in(key, TRIAL_STREAM)
    ctx = context_lib.make_contexts(key_ctx, spec, config.poses_per_object, context_config,
                                    threads=threads)
    plan = _trial_plan(ctx, key_trials, config.trials_per_grasp, trial)
    return _Prepared(index, ctx, plan, sim_lib.UniformBatch.prepare(ctx.model, shape))


def _shard_call_shape(config: DatasetConfig, num_candidates: int) -> tuple[int, int, int]:
    """(objects, trials per object, trials per object per compiled call) of every MJX shard
    call of ``config``: fixed for the whole dataset, so one compiled program serves all."""
    objects = config.objects_per_shard
    trials = config.poses_per_object * num_candidates * config.trials_per_grasp
    calls = -(-objects * trials // MJX_CALL_TRIALS)
    return objects, trials, -(-trials // calls)


def _run_mjx_shard(prepared: list[_Prepared], config: DatasetConfig, trial: sim_lib.TrialConfig,
                   shape) -> tuple[list[LabelledContexts], tuple[int, int] | None]:
    """Every valid trial of a shard's objects in one ``UniformBatch`` of the dataset's fixed
    shape; returns the objects' LabelledContexts and the number of compiled trial programs
    before and after the call (None: nothing to simulate)."""
    num_k = np.shape(prepared[0].ctx.candidates.valid)[1]
    num_o, num_t, per_call = _shard_call_shape(config, num_k)
    m = config.trials_per_grasp
    if not any(len(p.plan.pi) for p in prepared):  # nothing to simulate
        return [_labelled(p.ctx, p.plan, None, m) for p in prepared], None
    # A short last shard is padded with copies of its first object, each object's trials
    # with copies of its first trial; their results are dropped. An object without a valid
    # candidate runs a fixed grasp above the table centre (results dropped too).
    rows = prepared + [prepared[0]] * (num_o - len(prepared))
    grasps = np.empty((num_o, num_t, 4))
    poses = np.empty((num_o, num_t, 7))
    noise = sim_lib.TrialNoise(np.empty((num_o, num_t)), np.empty((num_o, num_t)),
                               np.empty((num_o, num_t, 4)))
    for o, p in enumerate(rows):
        n = len(p.plan.grasps)
        if n:
            idx = np.concatenate([np.arange(n), np.zeros(num_t - n, np.int64)])
            grasps[o], poses[o] = p.plan.grasps[idx], p.plan.poses[idx]
            for dst, src in zip(noise, p.plan.noise):
                dst[o] = src[idx]
        else:
            grasps[o] = (0.0, 0.0, 0.1, 0.0)
            poses[o] = np.asarray(p.ctx.poses)[0]
            for dst, src in zip(noise, sim_lib.zero_noise(num_t)):
                dst[o] = src
    batch = sim_lib.UniformBatch([p.ctx.model for p in rows], trial, shape,
                                 trials=per_call, prepared=[p.uniform for p in rows])
    before = batch.compiles
    results = batch.run_trials(grasps, noise, poses)
    out = []
    for p, res in zip(prepared, results):
        n = len(p.plan.grasps)
        res = sim_lib.TrialResult(*(a[:n] for a in res[:4]), res.backend)
        out.append(_labelled(p.ctx, p.plan, res if n else None, m))
    return out, (before, batch.compiles)


def label_shards_mjx(
    config: DatasetConfig,
    shards: Sequence[int],
    shard_specs: Sequence[Sequence[objects_lib.ObjectSpec]],
    *,
    trial: sim_lib.TrialConfig = sim_lib.TrialConfig(),
    shape=None,
    context_config: context_lib.ContextConfig = _CONTEXT_CONFIG,
    threads: int | None = None,
    stats: list | None = None,
) -> Iterator[tuple[int, list[tuple[int, LabelledContexts]]]]:
    """Labels shards on the MJX backend, one compiled trial program for all of them.

    A shard's contexts (and each object's uniform scene) are made on the host in a pool of
    ``threads`` threads (None: ``hosts.context_threads()``), the objects side by side; then
    every valid trial of the shard runs in one ``sim.UniformBatch`` call of the dataset's
    fixed shape (:func:`_shard_call_shape`). While shard s's trials run, shard s+1's
    contexts are made in a background thread. The draws are :func:`label_contexts`'s: the
    labels mean the same, object for object.

    Args:
      config: the dataset (backend ``"mjx"``).
      shards: shard numbers, in the order to label them.
      shard_specs: each shard's objects (its slice of :func:`dataset_objects`).
      trial: the trial (D0 uses the default).
      shape: the ``uniform.UniformShape`` of every object (None: the default, 4 parts).
      context_config: camera / candidate / scene settings (D0: the native renderer).
      threads: host threads for the contexts.
      stats: optional list that receives one dict per shard: shard, objects, trials (valid
        trials run), contexts_s (host: contexts and uniform scenes), trials_s (the trial
        program, incl. a compile), waited_s (time spent waiting for the contexts),
        seconds (wall, from the previous shard's end), compiled (trial programs compiled
        for this shard: 1 for the first shard of a process, then 0) and compiles (compiled
        programs of the trial function so far; None where nothing was simulated).

    Yields:
      ``(shard, [(object index, LabelledContexts), ...])`` in the order of ``shards``.
    """
    from sern_jax.grasp.world import uniform

    if config.backend != "mjx":
        raise ValueError(f"label_shards_mjx labels an MJX dataset, got backend "
                         f"{config.backend!r} (native: write_shard)")
    shards, shard_specs = list(shards), [list(s) for s in shard_specs]
    if len(shards) != len(shard_specs):
        raise ValueError(f"{len(shards)} shards but {len(shard_specs)} lists of objects")
    if not shards:
        return
    shape = uniform.UniformShape() if shape is None else shape
    root = jax.random.key(config.seed)
    total = threads or hosts.context_threads()
    workers = max(1, min(config.objects_per_shard, total))
    inner = -(-total // workers)  # the cores left over settle poses of one object

    def build(s, specs, pool):
        t0 = time.perf_counter()
        lo = s * config.objects_per_shard
        futures = [pool.submit(_prepare_object, root, lo + j, spec, config, trial, shape,
                               inner, context_config) for j, spec in enumerate(specs)]
        return [f.result() for f in futures], time.perf_counter() - t0

    with concurrent.futures.ThreadPoolExecutor(
            workers, thread_name_prefix="sern-d0-objects",
            initializer=context_lib.lower_priority) as pool, \
            concurrent.futures.ThreadPoolExecutor(
                1, thread_name_prefix="sern-d0-ahead") as ahead:
        pending = ahead.submit(build, shards[0], shard_specs[0], pool)
        t_prev = time.perf_counter()
        for n, s in enumerate(shards):
            t0 = time.perf_counter()
            prepared, contexts_s = pending.result()
            waited = time.perf_counter() - t0
            if n + 1 < len(shards):
                pending = ahead.submit(build, shards[n + 1], shard_specs[n + 1], pool)
            t1 = time.perf_counter()
            labelled, compiles = _run_mjx_shard(prepared, config, trial, shape)
            compiled = 0 if compiles is None else compiles[1] - compiles[0]
            t2 = time.perf_counter()
            if stats is not None:
                stats.append({
                    "shard": s, "objects": len(prepared),
                    "trials": int(sum(len(p.plan.grasps) for p in prepared)),
                    "contexts_s": contexts_s, "trials_s": t2 - t1, "waited_s": waited,
                    "seconds": t2 - t_prev, "compiled": compiled,
                    "compiles": None if compiles is None else compiles[1]})
            t_prev = t2
            yield s, [(p.index, lc) for p, lc in zip(prepared, labelled)]


def shard_paths(out_dir: str | Path, config: DatasetConfig) -> list[Path]:
    return [Path(out_dir) / f"shard_{i:05d}.npz" for i in range(config.num_shards)]


def _check_dir(out_dir: Path, config: DatasetConfig) -> None:
    cfg_path = out_dir / "config.json"
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"--out {out_dir} exists and is not a directory")
    if cfg_path.exists():
        from sern_jax.infra import validate

        old = validate.read_json_object(cfg_path, what="dataset config",
                                        advice="choose another --out or delete it")
        if old.get("fingerprint") != config.fingerprint():
            raise ValueError(
                f"{out_dir} holds a different dataset (config {old.get('config')}); "
                "choose another --out or delete it")


def generate(
    config: DatasetConfig,
    out_dir: str | Path,
    *,
    progress: bool = True,
    log: Callable[[str], None] = print,
    ray=None,
    stats: list | None = None,
) -> dict:
    """Generates (or resumes) D0 into ``out_dir``; returns the summary dict.

    Finished shards are kept: an interrupted run resumes at the first missing shard and
    gives the same files as an uninterrupted one. Existing shards are verified first; a
    damaged one is set aside and recomputed (``io.npz_unit_done``). The directory is locked
    (``io.run_lock``) while this runs: a second process gets ``io.RunLockedError``.
    ``ray``: a ``sern_jax.infra.distributed.RayConfig`` computes the missing shards as Ray tasks
    (:func:`write_shard`, the function this process calls without it: the same files).
    ``stats``: optional list that receives one timing dict per shard computed in this
    process (:func:`write_shard`; the MJX backend: :func:`label_shards_mjx`'s).
    """
    out_dir = Path(out_dir)
    _check_dir(out_dir, config)
    specs = dataset_objects(config)
    with io.run_lock(out_dir):
        _check_dir(out_dir, config)  # again, under the lock
        return _generate(config, out_dir, specs, progress, log, ray, stats)


def write_shard(config: DatasetConfig, shard: int, specs, out_dir: str | Path,
                on_object: Callable[[], None] | None = None, stats: list | None = None) -> None:
    """Simulates shard ``shard`` (objects ``specs``, the shard's slice of
    :func:`dataset_objects`) and saves it atomically: the unit of work of D0, run in this
    process or as a Ray task. ``stats``: optional list that receives the shard's timings (as
    :func:`label_shards_mjx`'s)."""
    if config.backend == "mjx":
        for _, parts in label_shards_mjx(config, [shard], [specs], stats=stats):
            _save_shard(config, shard, parts, out_dir)
            for _ in parts:
                if on_object is not None:
                    on_object()
        return
    root = jax.random.key(config.seed)
    lo = shard * config.objects_per_shard
    parts = []
    t_start = time.perf_counter()
    contexts_s = trials_s = 0.0
    trials = 0
    for i, spec in zip(range(lo, lo + len(specs)), specs):
        key = jax.random.fold_in(root, i)
        t0 = time.perf_counter()
        ctx = context_lib.make_contexts(jax.random.fold_in(key, CONTEXT_STREAM), spec,
                                        config.poses_per_object, _CONTEXT_CONFIG)
        t1 = time.perf_counter()
        lc = _label_trials(ctx, jax.random.fold_in(key, TRIAL_STREAM),
                           config.trials_per_grasp, config.backend, sim_lib.TrialConfig())
        contexts_s += t1 - t0
        trials_s += time.perf_counter() - t1
        trials += int(lc.valid.sum()) * config.trials_per_grasp
        parts.append((i, lc))
        if on_object is not None:
            on_object()
    if stats is not None:
        stats.append({"shard": shard, "objects": len(parts), "trials": trials,
                      "contexts_s": contexts_s, "trials_s": trials_s,
                      "seconds": time.perf_counter() - t_start})
    _save_shard(config, shard, parts, out_dir)


def _save_shard(config: DatasetConfig, shard: int, parts, out_dir: str | Path) -> None:
    arrays = {
        "object_index": np.concatenate(
            [np.full(len(lc.pose), i, np.int32) for i, lc in parts]),
        **{f: np.concatenate([getattr(lc, f) for _, lc in parts])
           for f in LabelledContexts._fields},
    }
    io.save_npz(shard_paths(out_dir, config)[shard], **arrays)


def _generate(config, out_dir: Path, specs, progress: bool, log, ray=None,
              stats=None) -> dict:
    io.save_json(out_dir / "config.json",
                 {"config": config, "fingerprint": config.fingerprint(),
                  "physics": sim_lib.physics_settings(),
                  "label": "one Bernoulli outcome per valid candidate (first trial); "
                           "successes = count over trials_per_grasp"})
    paths = shard_paths(out_dir, config)
    todo = [i for i, p in enumerate(paths) if not io.npz_unit_done(p, log)]
    log(f"D0: {config.num_objects} objects x {config.poses_per_object} poses x 64 "
        f"candidates ({config.max_grasps:,} slots) in {config.num_shards} shards; "
        f"{config.num_shards - len(todo)} already done")
    from tqdm.auto import tqdm

    done = sum(min(config.objects_per_shard, config.num_objects - i * config.objects_per_shard)
               for i in range(config.num_shards) if i not in todo)
    t0 = time.perf_counter()
    per = config.objects_per_shard
    if ray is not None:
        from sern_jax.infra import distributed

        distributed.run_units(
            [distributed.Unit(paths[s].name, write_shard,
                              (config, s, specs[s * per:(s + 1) * per],
                               str(out_dir.resolve())))
             for s in todo], ray, out_dir, log=log, progress=progress, desc="shards")
    else:
        bar = tqdm(total=config.num_objects, initial=done, unit="obj", desc="dataset",
                   disable=not progress)
        if config.backend == "mjx":  # one program for every shard, contexts made ahead
            for s, parts in label_shards_mjx(config, todo,
                                             [specs[s * per:(s + 1) * per] for s in todo],
                                             stats=stats):
                _save_shard(config, s, parts, out_dir)
                bar.update(len(parts))
        else:
            for s in todo:
                write_shard(config, s, specs[s * per:(s + 1) * per], out_dir,
                            on_object=lambda: bar.update(1), stats=stats)
        bar.close()
    summary = summarize(out_dir, config)
    summary["seconds_this_run"] = time.perf_counter() - t0
    io.save_json(out_dir / "summary.json", summary)
    return summary


def read_config(cfg_path: str | Path) -> tuple[DatasetConfig, str | None]:
    """A D0 ``config.json``: its :class:`DatasetConfig` and stored fingerprint, checked
    against its schema (a JSON object with a ``config`` object of the config's fields), else
    one line naming the file (``ValueError``)."""
    from sern_jax.infra import validate

    advice = "rerun `sern grasp dataset` with the flags that made it"
    raw = validate.read_json_object(cfg_path, {"config": dict}, what="dataset config",
                                    advice=advice)
    try:
        config = DatasetConfig(**raw["config"])
    except (TypeError, ValueError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{cfg_path} is not a dataset's config ({first}); {advice}") \
            from None
    stored = raw.get("fingerprint")
    return config, (stored if isinstance(stored, str) else None)


def load(out_dir: str | Path) -> tuple[DatasetConfig, dict[str, np.ndarray]]:
    """Loads every shard of a finished dataset; arrays concatenated over contexts."""
    out_dir = Path(out_dir)
    cfg_path = out_dir / "config.json"
    if not cfg_path.exists():
        raise ValueError(f"{out_dir} is not a dataset directory (no config.json); "
                         "make one with `sern grasp dataset --out DIR`")
    config, stored = read_config(cfg_path)
    if stored != config.fingerprint():
        raise ValueError(
            f"{out_dir} was labelled in another simulated world (fingerprint {stored}, this "
            f"code's trial gives {config.fingerprint()}: the gripper or trial settings "
            "changed, e.g. the default finger force, 6 N -> 20 N); regenerate it with `sern grasp "
            "dataset --out NEW_DIR`")
    paths = shard_paths(out_dir, config)
    missing = [p.name for p in paths if not p.exists()]
    if missing:
        raise ValueError(f"{out_dir} is incomplete ({len(missing)} of {len(paths)} shards "
                         f"missing, e.g. {missing[0]}); rerun `sern grasp dataset` with the "
                         "same flags to finish it")
    advice = (f"rerun `sern grasp dataset --out {out_dir}` with the same flags to recompute "
              "it")
    shards = []
    for s, p in enumerate(paths):
        shard = io.load_npz(p, advice=advice)
        lo = s * config.objects_per_shard
        hi = min(lo + config.objects_per_shard, config.num_objects)
        missing = [k for k in _SHARD_KEYS if k not in shard]
        if missing:
            raise io.DamagedFileError(p, f"no {missing[0]!r} array", advice)
        rows = (hi - lo) * config.poses_per_object
        bad = [k for k in _SHARD_KEYS if shard[k].shape[:1] != (rows,)]
        if bad:
            raise io.DamagedFileError(
                p, f"{bad[0]} has {shard[bad[0]].shape[0] if shard[bad[0]].ndim else 0} rows, "
                   f"not the {rows} contexts of objects {lo}-{hi - 1}", advice)
        shards.append(shard)
    return config, {k: np.concatenate([s[k] for s in shards]) for k in _SHARD_KEYS}


def summarize(out_dir: str | Path, config: DatasetConfig) -> dict:
    """Counts and class balance of a finished dataset."""
    _, data = load(out_dir)
    valid = data["valid"]
    labels = data["label"][valid]
    freq = data["successes"][valid] / config.trials_per_grasp
    return {
        "contexts": int(valid.shape[0]),
        "candidate_slots": int(valid.size),
        "labelled_grasps": int(valid.sum()),
        "valid_fraction": float(valid.mean()),
        "positive_fraction": float(labels.mean()) if labels.size else float("nan"),
        "mean_success_frequency": float(freq.mean()) if freq.size else float("nan"),
        "diverged_trials": int(data["nan_count"].sum()),
        "objects": int(config.num_objects),
    }
