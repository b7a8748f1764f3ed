"""One grasp context from an object spec and a key: scene, resting pose, depth, candidates.

This is the one path ``object spec + key -> scene -> resting pose -> depth image -> K
antipodal candidates`` that ``sern grasp show``, ``sern grasp bench``, the dataset
generator and the online learner all call:

* :func:`make_context` ``(key, spec, config) -> GraspContext``: one context (its own scene,
  ``model.qpos0`` holding the pose).
* :func:`make_contexts` ``(key, spec, num_poses, config, model=None) -> GraspContexts``:
  ``P`` resting poses of one object in one shared scene, their depth images and candidate
  sets rendered and sampled in one jitted batch. Pose ``i`` equals
  ``make_context(jax.random.fold_in(key, i), spec, config)``.

Randomness (the STYLE.md stream convention): context ``i`` of ``make_contexts`` uses
``key_i = fold_in(key, i)``; from ``key_i`` the resting-pose seed, the depth noise and
the candidate sampling are drawn from ``fold_in(key_i, POSE_STREAM)``,
``fold_in(key_i, DEPTH_NOISE_STREAM)`` and ``fold_in(key_i, CANDIDATE_STREAM)``. The
resting pose is simulated by native MuJoCo (``scene.resting_pose``, an int seed): the
seed is 31 random bits of the pose stream.

Threads: the resting poses of a batch (native MuJoCo, which releases the GIL while it steps)
settle in a thread pool of :func:`context_threads` threads, each pose in its own ``MjData``
with its own seed, so the poses, and everything computed from them, are the serial ones bit
for bit (tested); ``SERN_CONTEXT_THREADS=1``, or ``threads=1`` in a call, settles them one
after another in the calling thread (what a caller that makes many batches in threads of its
own, the online driver, asks for). Nothing here depends on which thread calls.

Compiled code: one jitted ``render + sample`` function per (camera, candidate, noise)
configuration, cached at module level, so calls with the same configuration, the same
number of poses and scenes of the same structure never recompile. (The ray caster reads the
geom types and convex-mesh planes on the host at trace time, so a scene of a different
structure -- another geom type, another mesh -- is traced once more on first use.)
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import os
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from sern_jax.grasp.world import candidates as cand_lib
from sern_jax.grasp.world import depth as depth_lib
from sern_jax.grasp.world import depth_native
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import scene as scene_lib
from sern_jax.infra import hosts

__all__ = [
    "POSE_STREAM",
    "DEPTH_NOISE_STREAM",
    "CANDIDATE_STREAM",
    "RENDERERS",
    "ContextConfig",
    "GraspContext",
    "GraspContexts",
    "pose_seeds",
    "make_context",
    "make_contexts",
    "resting_poses",
    "scene_model",
    "copy_model",
    "context_threads",
    "lower_priority",
    "many_cores",
]

POSE_STREAM = 0  # fold_in id: resting-pose seed
DEPTH_NOISE_STREAM = 1  # fold_in id: depth sensor noise
CANDIDATE_STREAM = 2  # fold_in id: antipodal candidate sampling
RENDERERS = ("auto", "native", "jax")


@dataclasses.dataclass(frozen=True)
class ContextConfig:
    """Static settings of a grasp context (defaults: what ``sern grasp show`` uses).

    Attributes:
      camera: depth camera (image size, intrinsics, noise defaults); the camera looks
        straight down at the origin (``depth.overhead_params``).
      candidates: antipodal sampler (K = ``num_candidates`` slots).
      scene: physics and solver settings of the scene (and the resting-pose drop).
      noise: whether to add depth sensor noise (off by default: every shipped result is
        noise-free); ``camera.noise_model`` picks Dex-Net-style noise (default) or a
        RealSense D435-like model (range-dependent Gaussian noise, missing pixels filled by
        ``depth.inpaint``).
      renderer: ``"jax"`` (``depth.render``, MJX ray casting: the GPU path; compiles once
        per scene structure, i.e. per object), ``"native"`` (``depth_native``: MuJoCo's C
        ray caster, no compile per object, the CPU path) or ``"auto"`` (native on a CPU
        backend, jax otherwise). Both give the same image (tests/grasp/test_context.py).
    """

    camera: depth_lib.CameraConfig = depth_lib.CameraConfig()
    candidates: cand_lib.CandidateConfig = cand_lib.CandidateConfig()
    scene: scene_lib.SceneConfig = scene_lib.SceneConfig()
    noise: bool = False
    renderer: str = "auto"

    def __post_init__(self):
        if self.renderer not in RENDERERS:
            raise ValueError(
                f"ContextConfig.renderer must be one of {RENDERERS}, got {self.renderer!r}"
            )
        for name, cls in (
            ("camera", depth_lib.CameraConfig),
            ("candidates", cand_lib.CandidateConfig),
            ("scene", scene_lib.SceneConfig),
        ):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(
                    f"ContextConfig.{name} must be a {cls.__name__}, "
                    f"got {type(getattr(self, name)).__name__}"
                )
        if not isinstance(self.noise, bool):
            raise ValueError(f"ContextConfig.noise must be a bool, got {self.noise!r}")


class GraspContext(NamedTuple):
    """One grasp context (numpy leaves)."""

    model: mujoco.MjModel  # the scene; model.qpos0 holds `pose`
    pose: np.ndarray  # [7] object resting pose (x, y, z, qw, qx, qy, qz), world frame
    depth: np.ndarray  # [H, W] float32 planar depth, metres
    camera: depth_lib.CameraParams  # the overhead camera that took `depth`
    candidates: cand_lib.Candidates  # K slots ([K, 4] grasps, [K] valid, ...)


class GraspContexts(NamedTuple):
    """P grasp contexts of one object in one shared scene (numpy leaves)."""

    model: mujoco.MjModel  # the shared scene, not modified: pass poses[i] as object_pose
    poses: np.ndarray  # [P, 7] object resting poses (x, y, z, qw, qx, qy, qz)
    depth: np.ndarray  # [P, H, W] float32 planar depth, metres
    camera: depth_lib.CameraParams  # one overhead camera, shared (unbatched leaves)
    candidates: cand_lib.Candidates  # leaves with a leading [P]: grasps [P, K, 4], ...

    def context(self, i: int) -> GraspContext:
        """Context ``i`` alone, with its own copy of the model (qpos0 = ``poses[i]``)."""
        model = copy_model(self.model)
        scene_lib.set_object_pose(model, self.poses[i])
        return GraspContext(
            model=model,
            pose=self.poses[i],
            depth=self.depth[i],
            camera=self.camera,
            candidates=jax.tree.map(lambda x: x[i], self.candidates),
        )


def copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """An independent copy of a MuJoCo model (``set_object_pose`` edits in place)."""
    import copy

    return copy.copy(model)


def scene_model(
    spec: objects_lib.ObjectSpec, config: ContextConfig = ContextConfig()
) -> mujoco.MjModel:
    """The compiled scene of ``spec`` with the object not yet dropped (pass as ``model``).

    Raises:
      ValueError: ``spec`` is not an ObjectSpec or does not compile.
    """
    if not isinstance(spec, objects_lib.ObjectSpec):
        raise ValueError(f"spec must be an ObjectSpec, got {type(spec).__name__}")
    try:
        return mujoco.MjModel.from_xml_string(scene_lib.scene_xml(spec, config.scene))
    except ValueError as e:
        raise ValueError(f"object {spec.name!r} does not compile: {e}") from e


@functools.partial(jax.jit, static_argnums=1)
def _keys(key: jax.Array, num: int):
    """Per-context keys fold_in(key, i) for i < num: [num]."""
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(num))


@jax.jit
def _streams(keys: jax.Array):
    """Seeds and keys of the three streams of each context key in ``keys`` [P]."""

    def one(k):
        seed = jax.random.bits(jax.random.fold_in(k, POSE_STREAM), (), jnp.uint32)
        return (
            (seed >> 1).astype(jnp.int32),  # 31 bits: a non-negative int32
            jax.random.fold_in(k, DEPTH_NOISE_STREAM),
            jax.random.fold_in(k, CANDIDATE_STREAM),
        )

    return jax.vmap(one)(keys)


def pose_seeds(keys: jax.Array) -> np.ndarray:
    """The ``scene.resting_pose`` seed of each context key: keys [P] -> int [P]."""
    return np.asarray(_streams(keys)[0]).astype(np.int64)


@functools.lru_cache(maxsize=None)
def _pipeline(
    camera: depth_lib.CameraConfig, candidates: cand_lib.CandidateConfig, noise: bool
):
    """jit(vmap(render -> sample)) over poses; one per static configuration (JAX renderer)."""

    def one(m, poses, params, key_noise, key_cand):
        image = depth_lib.render(
            camera, m, poses, params, key_noise if noise else None
        )
        cands = cand_lib.sample(candidates, key_cand, image.depth, params)
        return image.depth, cands

    return jax.jit(jax.vmap(one, (None, 0, None, 0, 0)))


@functools.lru_cache(maxsize=None)
def _sampler(candidates: cand_lib.CandidateConfig):
    """jit(vmap(sample)) over images: its program depends on the image shape only."""
    return jax.jit(
        jax.vmap(lambda k, d, p: cand_lib.sample(candidates, k, d, p), (0, 0, None))
    )


def _renderer(config: ContextConfig) -> str:
    if config.renderer != "auto":
        return config.renderer
    native_ok = depth_native.supports(config.camera)
    return "native" if native_ok and jax.default_backend() == "cpu" else "jax"


def _geom_poses(model: mujoco.MjModel, poses: np.ndarray) -> depth_lib.GeomPoses:
    """Geom poses [P, ngeom, ...] of the scene with the object at each pose, gripper parked."""
    data = scene_lib.initial_data(model)
    a = scene_lib.scene_ids(model).object_qpos
    xpos = np.empty((len(poses), model.ngeom, 3), np.float32)
    xmat = np.empty((len(poses), model.ngeom, 3, 3), np.float32)
    for i, pose in enumerate(poses):
        data.qpos[a : a + 7] = pose
        mujoco.mj_kinematics(model, data)
        xpos[i] = data.geom_xpos
        xmat[i] = data.geom_xmat.reshape(-1, 3, 3)
    return depth_lib.GeomPoses(geom_xpos=xpos, geom_xmat=xmat)


def context_threads() -> int:
    """Threads that settle the resting poses of one batch (:func:`sern_jax.infra.hosts.context_threads`)."""
    return hosts.context_threads()


BACKGROUND_NICE = 10  # niceness of the context threads (made ahead of need)
BACKGROUND_NICE_MIN_CORES = hosts.MANY_CORES  # ... on hosts with at least this many usable cores


def many_cores() -> bool:
    """Whether this host counts as many-core (:func:`sern_jax.infra.hosts.many_cores`, at
    ``BACKGROUND_NICE_MIN_CORES`` cores): where work made ahead of need runs at a lower
    priority (:func:`lower_priority`)."""
    return hosts.many_cores()


def lower_priority() -> None:
    """Lowers the calling thread's CPU priority to niceness ``BACKGROUND_NICE`` (Linux: a
    thread's own niceness; elsewhere, or if refused, nothing happens) on a host with at
    least ``BACKGROUND_NICE_MIN_CORES`` usable cores. The threads that make contexts ahead
    of need call it, so on a many-core host (16 context threads) the cores go first to the
    threads the run waits on (the main thread's compiles and dispatch, the trial workers);
    idle cores still make contexts. On a few shared cores it is left off: there niceness
    would hand the cores to other processes' work while the run waits for its contexts.
    Scheduling only: results are the same."""
    try:
        if not many_cores():
            return
        tid = threading.get_native_id()
        current = os.getpriority(os.PRIO_PROCESS, tid)
        if current < BACKGROUND_NICE:
            os.setpriority(os.PRIO_PROCESS, tid, BACKGROUND_NICE)
    except (AttributeError, OSError):
        pass


_POOLS: dict[int, concurrent.futures.ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _pool(threads: int) -> concurrent.futures.ThreadPoolExecutor:
    with _POOLS_LOCK:
        if threads not in _POOLS:
            _POOLS[threads] = concurrent.futures.ThreadPoolExecutor(
                threads, thread_name_prefix="sern-context", initializer=lower_priority)
        return _POOLS[threads]


@jax.jit
def _pose_uniforms(seeds: jax.Array) -> jax.Array:
    """``scene.resting_pose``'s five uniforms of every seed [P] -> [P, 5]: the same draws
    as ``uniform(key(seed), (5,))`` one seed at a time (threefry bits and exact float ops;
    tests/grasp/test_context_threads.py), in one call instead of one per pose."""
    return jax.vmap(lambda s: jax.random.uniform(jax.random.key(s), (5,)))(seeds)


def _resting_poses(model: mujoco.MjModel, seeds: np.ndarray, config: ContextConfig,
                   threads: int | None = None) -> np.ndarray:
    """``scene.resting_pose`` of every seed [P] -> poses [P, 7], in ``threads`` threads
    (None: :func:`context_threads`; 1: in the calling thread). Same values either way: each
    pose has its own MjData and seed; the model is only read."""
    seeds = np.asarray(seeds)
    u = np.asarray(_pose_uniforms(jnp.asarray(seeds, jnp.int32)), np.float64)

    def one(i):
        return scene_lib.resting_pose_from_uniforms(
            model, u[i], config.scene.xy_jitter, config.scene.settle_steps)

    threads = min(len(seeds), context_threads() if threads is None else threads)
    if threads <= 1:
        return np.stack([one(i) for i in range(len(seeds))])
    return np.stack(list(_pool(threads).map(one, range(len(seeds)))))  # in order


_CAMERA_MODELS: dict = {}
_CAMERA_MODELS_LOCK = threading.Lock()


def _camera_model(model: mujoco.MjModel):
    """``depth.camera_model(model)``, kept per model contents (the MJB bytes' digest, so an
    edited model is another entry): ``mjx.put_model`` is slow Python work on every call, and
    the online driver renders every (object, seed) batch of every round in one scene."""
    import hashlib

    buf = np.empty(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    digest = hashlib.blake2b(buf.tobytes(), digest_size=16).digest()
    with _CAMERA_MODELS_LOCK:
        hit = _CAMERA_MODELS.get(digest)
    if hit is None:
        hit = depth_lib.camera_model(model)
        with _CAMERA_MODELS_LOCK:
            if len(_CAMERA_MODELS) >= 64:
                _CAMERA_MODELS.pop(next(iter(_CAMERA_MODELS)))
            _CAMERA_MODELS[digest] = hit
    return hit


def _contexts(
    keys: jax.Array,
    model: mujoco.MjModel,
    config: ContextConfig,
    poses: np.ndarray | None = None,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray, depth_lib.CameraParams, cand_lib.Candidates]:
    """Poses, depth, camera and candidates for context keys [P] in one scene (``poses``:
    the keys' resting poses where already settled, :func:`resting_poses`; ``threads``:
    the settling threads otherwise)."""
    seeds, keys_noise, keys_cand = _streams(keys)
    if poses is None:
        poses = _resting_poses(model, np.asarray(seeds), config, threads)
    params = depth_lib.overhead_params(config.camera)
    if _renderer(config) == "native":
        # MuJoCo's C ray caster: the same image as depth.render (tests compare them) with
        # no compile per object; only the candidate sampler is jitted (once per shape).
        depth, _ = depth_native.render_native(
            config.camera, model, scene_lib.initial_data(model), params, poses,
            scene_lib.scene_ids(model).object_qpos, keys_noise if config.noise else None)
        cands = _sampler(config.candidates)(keys_cand, depth, params)
    else:
        m = _camera_model(model)
        fn = _pipeline(config.camera, config.candidates, config.noise)
        depth, cands = fn(m, _geom_poses(model, poses), params, keys_noise, keys_cand)
    to_np = functools.partial(jax.tree.map, np.asarray)
    return poses, np.asarray(depth), to_np(params), to_np(cands)


def make_context(
    key: jax.Array,
    spec: objects_lib.ObjectSpec,
    config: ContextConfig = ContextConfig(),
) -> GraspContext:
    """One grasp context: the object at a random resting pose, its depth image, K grasps.

    Args:
      key: PRNG key; consumed (pose seed, depth noise and candidates come from its
        ``POSE_STREAM``, ``DEPTH_NOISE_STREAM`` and ``CANDIDATE_STREAM`` fold-ins).
      spec: the object.
      config: camera, candidate and scene settings, depth noise on/off.

    Returns:
      GraspContext(model [its own scene, qpos0 = pose], pose [7], depth [H, W], camera,
      candidates [K slots]).

    Raises:
      ValueError: bad spec / config, the object does not compile or does not come to rest.
    """
    _check_key(key)
    if not isinstance(config, ContextConfig):
        raise ValueError(f"config must be a ContextConfig, got {type(config).__name__}")
    model = scene_model(spec, config)
    poses, depth, camera, cands = _contexts(key[None], model, config)
    scene_lib.set_object_pose(model, poses[0])
    return GraspContext(
        model=model,
        pose=poses[0],
        depth=depth[0],
        camera=camera,
        candidates=jax.tree.map(lambda x: x[0], cands),
    )


def resting_poses(
    key: jax.Array,
    num_poses: int,
    model: mujoco.MjModel,
    config: ContextConfig = ContextConfig(),
    *,
    threads: int | None = None,
) -> np.ndarray:
    """The resting poses [P, 7] of ``make_contexts(key, spec, num_poses, config, model)``:
    the batch's first stage (native MuJoCo on the CPU), so that a caller can settle poses
    ahead of rendering them and pass them back as ``make_contexts(..., poses=)``.

    ``threads``: how many threads settle them (None: :func:`context_threads`, in a pool of
    this module; 1: one after another in the calling thread, what a caller that already
    runs many batches in threads of its own asks for). The poses do not depend on it."""
    _check_key(key)
    _check_threads(threads)
    seeds = _streams(_keys(key, int(num_poses)))[0]
    return _resting_poses(model, np.asarray(seeds), config, threads)


def make_contexts(
    key: jax.Array,
    spec: objects_lib.ObjectSpec,
    num_poses: int,
    config: ContextConfig = ContextConfig(),
    model: mujoco.MjModel | None = None,
    poses: np.ndarray | None = None,
    *,
    threads: int | None = None,
) -> GraspContexts:
    """``num_poses`` grasp contexts of one object, rendered and sampled in one batch.

    Context ``i`` equals ``make_context(jax.random.fold_in(key, i), spec, config)`` (same
    pose, depth and candidates; float leaves within float32 batching noise).

    Args:
      key: PRNG key; consumed. Context ``i`` uses ``fold_in(key, i)``.
      spec: the object.
      num_poses: P >= 1.
      config: camera, candidate and scene settings, depth noise on/off.
      model: optional scene of ``spec`` to reuse (``scene_model(spec, config)`` or a
        ``scene.build_scene`` result; not modified). None builds ``scene_model``. Its
        qpos0 is no particular pose: give the simulator ``poses[i]`` as ``object_pose``.
      poses: optional [P, 7] ``resting_poses(key, num_poses, model, config)``, settled
        ahead (the contexts are then the same as without it, bit for bit); None settles
        them here.
      threads: the threads that settle the poses here (None: :func:`context_threads`;
        1: in the calling thread); the contexts do not depend on it.

    Returns:
      GraspContexts(model [shared], poses [P, 7], depth [P, H, W], camera, candidates
      [P, K, ...]).

    Raises:
      ValueError: bad arguments, or an object that does not compile or come to rest.
    """
    _check_key(key)
    if not isinstance(config, ContextConfig):
        raise ValueError(f"config must be a ContextConfig, got {type(config).__name__}")
    if isinstance(num_poses, bool) or not isinstance(num_poses, (int, np.integer)):
        raise ValueError(f"num_poses must be an int >= 1, got {num_poses!r}")
    if num_poses < 1:
        raise ValueError(f"num_poses must be >= 1, got {num_poses}")
    if model is None:
        model = scene_model(spec, config)
    elif not isinstance(model, mujoco.MjModel):
        raise ValueError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    else:
        scene_lib.scene_ids(model)  # raises if it is not a grasp scene
    if poses is not None:
        poses = np.asarray(poses)
        if (poses.shape != (num_poses, 7) or poses.dtype != np.float64
                or not np.all(np.isfinite(poses))):
            raise ValueError(f"poses must be finite float64 with shape ({num_poses}, 7) "
                             f"(resting_poses of the same key), got {poses.dtype} "
                             f"{poses.shape}")
    _check_threads(threads)
    poses, depth, camera, cands = _contexts(_keys(key, int(num_poses)), model, config, poses,
                                            threads)
    return GraspContexts(
        model=model, poses=poses, depth=depth, camera=camera, candidates=cands
    )


def _check_key(key) -> None:
    if not (
        isinstance(key, jax.Array)
        and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        and key.shape == ()
    ):
        raise ValueError(
            "key must be one typed PRNG key (jax.random.key(seed)), got "
            f"{getattr(key, 'dtype', type(key).__name__)} "
            f"shape {getattr(key, 'shape', None)}"
        )


def _check_threads(threads) -> None:
    if threads is not None and (isinstance(threads, bool)
                                or not isinstance(threads, (int, np.integer)) or threads < 1):
        raise ValueError(f"threads must be an int >= 1 or None, got {threads!r}")
