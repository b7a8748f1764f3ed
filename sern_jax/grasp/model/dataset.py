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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import numpy as np

from sern_jax.infra import io
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import sim as sim_lib

__all__ = [
    "CONTEXT_STREAM",
    "TRIAL_STREAM",
    "DatasetConfig",
    "LabelledContexts",
    "label_contexts",
    "generate",
    "load",
    "dataset_objects",
    "shard_paths",
    "write_shard",
]

CONTEXT_STREAM = 0
TRIAL_STREAM = 1
MJX_BATCH = 8192  # MJX trials per compiled call: one program for every object's trials
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
    context_config: context_lib.ContextConfig = context_lib.ContextConfig(renderer="native"),
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

    Returns:
      LabelledContexts with leading axis P.
    """
    if num_poses < 1 or num_trials < 1:
        raise ValueError(f"num_poses and num_trials must be >= 1, got {num_poses}, {num_trials}")
    key_ctx = jax.random.fold_in(key, CONTEXT_STREAM)
    key_trials = jax.random.fold_in(key, TRIAL_STREAM)
    ctx = context_lib.make_contexts(key_ctx, spec, num_poses, context_config)
    cands = ctx.candidates
    valid = np.asarray(cands.valid, bool)  # [P, K]
    grasps = np.asarray(cands.grasps, np.float64)
    num_p, num_k = valid.shape
    successes = np.zeros((num_p, num_k), np.int32)
    nan_count = np.zeros((num_p, num_k), np.int32)
    first = np.full((num_p, num_k), -1, np.int8)
    pi, ki = np.nonzero(valid)
    if len(pi):
        simulator = sim_lib.GraspSimulator(ctx.model, backend=backend, mjx_batch=MJX_BATCH)
        n = len(pi)
        # trial j of context p uses the draw fold_in(key_trials, p * num_trials + j) for
        # every candidate of that context.
        noise = sim_lib.sample_noise(key_trials, num_p * num_trials, simulator.config)
        idx = (pi[:, None] * num_trials + np.arange(num_trials)[None, :]).reshape(-1)
        tnoise = sim_lib.TrialNoise(*(np.asarray(a)[idx] for a in noise))
        res = simulator.run_trials(
            np.repeat(grasps[pi, ki], num_trials, axis=0), tnoise,
            object_pose=np.repeat(np.asarray(ctx.poses)[pi], num_trials, axis=0))
        succ = res.success.reshape(n, num_trials)
        successes[pi, ki] = succ.sum(1)
        nan_count[pi, ki] = res.nan.reshape(n, num_trials).sum(1)
        first[pi, ki] = succ[:, 0].astype(np.int8)
    return LabelledContexts(
        pose=np.asarray(ctx.poses, np.float64),
        depth=np.asarray(ctx.depth, np.float32),
        grasps=grasps.astype(np.float32),
        valid=valid,
        center_px=np.asarray(cands.center_px, np.float32),
        angle_px=np.asarray(cands.angle_px, np.float32),
        grasp_depth=np.asarray(cands.grasp_depth, np.float32),
        successes=successes,
        nan_count=nan_count,
        label=first,
    )


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
) -> dict:
    """Generates (or resumes) D0 into ``out_dir``; returns the summary dict.

    Finished shards are kept: an interrupted run resumes at the first missing shard and
    gives the same files as an uninterrupted one. Existing shards are verified first; a
    damaged one is set aside and recomputed (``io.npz_unit_done``). The directory is locked
    (``io.run_lock``) while this runs: a second process gets ``io.RunLockedError``.
    ``ray``: a ``sern_jax.infra.distributed.RayConfig`` computes the missing shards as Ray tasks
    (:func:`write_shard`, the function this process calls without it: the same files).
    """
    out_dir = Path(out_dir)
    _check_dir(out_dir, config)
    specs = dataset_objects(config)
    with io.run_lock(out_dir):
        _check_dir(out_dir, config)  # again, under the lock
        return _generate(config, out_dir, specs, progress, log, ray)


def write_shard(config: DatasetConfig, shard: int, specs, out_dir: str | Path,
                on_object: Callable[[], None] | None = None) -> None:
    """Simulates shard ``shard`` (objects ``specs``, the shard's slice of
    :func:`dataset_objects`) and saves it atomically: the unit of work of D0, run in this
    process or as a Ray task."""
    root = jax.random.key(config.seed)
    lo = shard * config.objects_per_shard
    parts = []
    for i, spec in zip(range(lo, lo + len(specs)), specs):
        key = jax.random.fold_in(root, i)
        lc = label_contexts(key, spec, config.poses_per_object, config.trials_per_grasp,
                            config.backend)
        parts.append((i, lc))
        if on_object is not None:
            on_object()
    arrays = {
        "object_index": np.concatenate(
            [np.full(len(lc.pose), i, np.int32) for i, lc in parts]),
        **{f: np.concatenate([getattr(lc, f) for _, lc in parts])
           for f in LabelledContexts._fields},
    }
    io.save_npz(shard_paths(out_dir, config)[shard], **arrays)


def _generate(config, out_dir: Path, specs, progress: bool, log, ray=None) -> dict:
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
        for s in todo:
            write_shard(config, s, specs[s * per:(s + 1) * per], out_dir,
                        on_object=lambda: bar.update(1))
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
