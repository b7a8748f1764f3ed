"""Grasp trials: an initial state plus an open-loop control schedule, run in batches.

A grasp is ``(x, y, z, θ)`` in world metres / radians (array ``[..., 4]``): the grasp
centre (midpoint between the two pads) and the yaw of the jaw axis (see ``scene``).

One trial (``TrialConfig`` defaults, 5 ms steps, 290 steps = 1.45 s simulated):

1. start: palm at the pre-grasp pose ``approach_height`` above the grasp, jaws open,
   object at its resting pose, everything at rest;
2. approach: descend to the grasp in ``approach_steps``, then ``settle_steps`` still;
3. close: finger targets ramp from open to ``close_target`` in ``close_steps`` (each
   finger's force is limited to ``SceneConfig.finger_force``);
4. lift: raise the palm by ``lift_height`` (13 cm) in ``lift_steps``;
5. shake: lateral sinusoid, amplitude ``shake_amplitude`` at ``shake_hz``, across the
   jaw axis, for ``shake_steps``;
6. hold: ``hold_steps`` still.

Success: the trial stayed finite, the object rose at least ``success_lift`` (10 cm)
above its start, and the jaws are not closed on nothing (gap > 2 mm): the object is held
between the fingers above the lift threshold. A trial that diverged (any non-finite
state, |qpos| >= 1e3, |qvel| >= 1e5, or, natively, a MuJoCo instability warning, at
which ``mujoco.rollout`` stops the trial) is flagged ``nan`` and is never a success (it counts as a failure in probabilities, and
``nan`` counts are returned next to them).

Randomisation (why outcomes are Bernoulli), drawn per trial by :func:`sample_noise`:

* friction: sliding friction of the object's geoms ~ U[0.3, 0.8] (pads 0.3, table 0.5;
  MuJoCo takes the larger of a pair, so this is the pad-object and object-table value,
  for draws of at least 0.3 and 0.5 respectively);
* mass: object mass (and inertia) scaled by U[0.8, 1.25];
* execution error of the grasp pose: x, y, z ~ N(0, 2 mm), θ ~ N(0, 0.05 rad), each
  truncated at 2.5 σ.

Backends, one interface (:class:`GraspSimulator`):

* ``"native"``: MuJoCo C via ``mujoco.rollout`` (multi-threaded); the fast CPU path.
* ``"mjx"``: MuJoCo MJX, ``jit(vmap(execute))`` with ``execute = make_execute(config,
  model)`` the pure, unbatched trial ``execute(mx, pose, grasp, trial_params) ->
  TrialOutcome`` (a ``lax.scan`` of ``mjx.step``); the GPU path, and the function to vmap
  or jit inside your own program. The ``mjx.Model`` is an argument, so scenes of the same
  structure share one compiled program; by default MJX runs the scene's uniform model
  (``uniform``: every object as the same number of padded convex mesh parts), so one
  program serves every object, and :class:`UniformBatch` vmaps it over objects too.
  Batches are padded to the next power of two, so each power of two compiles once.

Every trial can start from its own object pose (``run_trials(..., object_pose=[N, 7])``,
e.g. the poses of ``context.make_contexts`` on their shared model).

Every :class:`TrialResult` / :class:`SuccessEstimate` records its ``backend``.
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import functools
import math
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from sern_jax.grasp.world import scene as scene_lib
from sern_jax.infra import hosts

__all__ = [
    "BACKENDS",
    "GRASP_XY_LIMIT",
    "GRASP_Z_RANGE",
    "MIN_GRASP_Z",
    "QPOS_LIMIT",
    "QVEL_LIMIT",
    "CLOSED_GAP",
    "TrialConfig",
    "TrialNoise",
    "TrialResult",
    "TrialOutcome",
    "SuccessEstimate",
    "check_grasps",
    "sample_trial_noise",
    "sample_noise",
    "zero_noise",
    "refine",
    "physics_settings",
    "make_execute",
    "GraspSimulator",
    "UniformBatch",
    "agreement",
]

BACKENDS = ("native", "mjx")
GRASP_XY_LIMIT = 0.5  # |x|, |y| of a grasp must lie on the 1 m table
GRASP_Z_RANGE = (-0.05, 0.5)
MIN_GRASP_Z = scene_lib.PAD_HALF[2] + 0.002  # pads stay 2 mm above the table
QPOS_LIMIT = 1e3  # |qpos| beyond this (m or rad) = diverged
QVEL_LIMIT = 1e5  # |qvel| beyond this = diverged


@dataclasses.dataclass(frozen=True)
class TrialConfig:
    """Control schedule, success rule and randomisation ranges of a grasp trial.

    Attributes:
      approach_height: start height of the grasp centre above the grasp, metres.
      approach_steps: phase length in physics steps, as are settle_steps, close_steps,
        lift_steps, shake_steps and hold_steps.
      close_target: finger target at the end of closing (< 0: squeeze at the force
        limit), metres.
      lift_height: palm lift, metres (>= 0.1).
      shake_amplitude / shake_hz: lateral shake, metres / hertz.
      success_lift: object rise needed for success, metres.
      friction_range: object sliding friction ~ U[lo, hi].
      mass_scale_range: object mass scale ~ U[lo, hi].
      pos_noise_std / yaw_noise_std: execution error σ of x, y, z (m) and θ (rad),
        truncated at 2.5 σ.
    """

    approach_height: float = 0.05
    approach_steps: int = 40
    settle_steps: int = 10
    close_steps: int = 60
    close_target: float = -0.01
    lift_height: float = 0.13
    lift_steps: int = 100
    shake_steps: int = 50
    shake_amplitude: float = 0.01
    shake_hz: float = 4.0
    hold_steps: int = 30
    success_lift: float = 0.10
    friction_range: tuple[float, float] = (0.3, 0.8)
    mass_scale_range: tuple[float, float] = (0.8, 1.25)
    pos_noise_std: float = 0.002
    yaw_noise_std: float = 0.05

    def __post_init__(self):
        steps = (
            self.approach_steps,
            self.settle_steps,
            self.close_steps,
            self.lift_steps,
            self.shake_steps,
            self.hold_steps,
        )
        if min(steps) < 0 or self.close_steps < 1 or self.lift_steps < 1:
            raise ValueError(
                f"phase lengths must be >= 0 (close, lift >= 1), got {steps}"
            )
        if self.lift_height < self.success_lift or self.success_lift <= 0:
            raise ValueError(
                f"need 0 < success_lift <= lift_height, got {self.success_lift}, "
                f"{self.lift_height}"
            )
        for name in ("friction_range", "mass_scale_range"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must satisfy 0 < lo <= hi, got {(lo, hi)}")
        if self.pos_noise_std < 0 or self.yaw_noise_std < 0:
            raise ValueError("noise standard deviations must be >= 0")

    @property
    def num_steps(self) -> int:
        return (
            self.approach_steps
            + self.settle_steps
            + self.close_steps
            + self.lift_steps
            + self.shake_steps
            + self.hold_steps
        )


CLOSED_GAP = 0.002  # metres: a jaw gap at or below this means the jaws closed on nothing


def succeeded(finite, rise, gap, config: TrialConfig):
    """The success rule of every backend (NumPy or JAX arrays alike): the trial stayed
    finite, the object rose at least ``config.success_lift``, and the jaws did not close on
    nothing (gap > ``CLOSED_GAP``)."""
    return finite & (rise >= config.success_lift) & (gap > CLOSED_GAP)


def physics_settings(scene: scene_lib.SceneConfig | None = None,
                     trial: TrialConfig | None = None) -> dict:
    """The simulated world as plain data: the scene (gripper force, frictions, solver,
    step) and the trial (schedule, randomisation). Every run directory's fingerprint
    (D0, θ0, ``sern grasp learn``) includes it, so runs under different trials (e.g.
    the 6 N trial before 2026-11-24 and the 20 N one after) never share a directory.
    None = the defaults."""
    sc = dataclasses.asdict(scene or scene_lib.SceneConfig())
    tr = dataclasses.asdict(trial or TrialConfig())
    return {"scene": sc, "trial": {k: (list(v) if isinstance(v, tuple) else v)
                                   for k, v in tr.items()}}


def refine(config: TrialConfig, factor: int) -> TrialConfig:
    """The same trial in physical time at a ``factor`` times smaller physics step: every
    phase length (in steps) times ``factor``. Pair it with a scene built at
    ``SceneConfig(timestep=timestep / factor)``; the time-step check
    (``experiments/trial_checks.py timestep``) compares outcomes across factors."""
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    names = ("approach_steps", "settle_steps", "close_steps", "lift_steps", "shake_steps",
             "hold_steps")
    return dataclasses.replace(config, **{n: getattr(config, n) * int(factor) for n in names})


class TrialNoise(NamedTuple):
    """Per-trial randomisation: N trials, or one ([] / [4]: make_execute's trial_params)."""

    friction: np.ndarray  # [N] object sliding friction
    mass_scale: np.ndarray  # [N] object mass/inertia scale
    grasp_error: np.ndarray  # [N, 4] added to the commanded grasp (m, m, m, rad)


class TrialResult(NamedTuple):
    """Outcome of N trials."""

    success: np.ndarray  # [N] bool
    nan: np.ndarray  # [N] bool, the state became non-finite (never a success)
    rise: np.ndarray  # [N] object z rise at the end, metres (nan if nan)
    gap: np.ndarray  # [N] final distance between the pads' inner faces, metres
    backend: str


class SuccessEstimate(NamedTuple):
    """Monte Carlo estimate of r_a(s) for K candidates of one context."""

    prob: np.ndarray  # [K] successes / num_trials (0 for invalid candidates)
    successes: np.ndarray  # [K] int
    nan_count: np.ndarray  # [K] int, non-finite trials (counted as failures)
    num_trials: int  # M trials per candidate
    valid: np.ndarray  # [K] bool, candidates that were simulated
    backend: str


# ----------------------------------------------------------------------------- checks


def check_grasps(grasps) -> np.ndarray:
    """Validates a grasp array ``[..., 4]`` (x, y, z, θ); returns it as float64.

    Raises:
      ValueError: wrong shape, non-finite values, or a grasp off the table
        (|x|, |y| > 0.5 m, z outside [-0.05, 0.5] m).
    """
    g = np.asarray(grasps, dtype=np.float64)
    if g.ndim < 1 or g.shape[-1] != 4:
        raise ValueError(
            f"grasps must have shape [..., 4] (x, y, z, theta), got {g.shape}"
        )
    if g.size == 0:
        raise ValueError(f"grasps is empty (shape {g.shape})")
    if not np.all(np.isfinite(g)):
        bad = np.argwhere(~np.isfinite(g))[0]
        raise ValueError(f"grasps contains a non-finite value at index {tuple(bad)}")
    if np.abs(g[..., :2]).max() > GRASP_XY_LIMIT:
        raise ValueError(
            f"grasp x/y must be within ±{GRASP_XY_LIMIT} m, got max "
            f"|x|,|y| = {np.abs(g[..., :2]).max():.3g}"
        )
    z = g[..., 2]
    if z.min() < GRASP_Z_RANGE[0] or z.max() > GRASP_Z_RANGE[1]:
        raise ValueError(
            f"grasp z must be in {GRASP_Z_RANGE} m, got [{z.min():.3g}, {z.max():.3g}]"
        )
    return g


# ----------------------------------------------------------------------------- noise


def sample_trial_noise(key: jax.Array, config: TrialConfig = TrialConfig()) -> TrialNoise:
    """One trial's randomisation (pure; jit and vmap it): the ``trial_params`` of
    :func:`make_execute`.

    Args:
      key: jax.random key (consumed).
      config: ranges.

    Returns:
      TrialNoise of jax scalars friction, mass_scale and a [4] grasp_error.
    """
    c = config
    sigma = jnp.array([c.pos_noise_std] * 3 + [c.yaw_noise_std])
    key_fric, key_mass, key_err = jax.random.split(key, 3)
    fric = jax.random.uniform(
        key_fric, (), minval=c.friction_range[0], maxval=c.friction_range[1]
    )
    mass = jax.random.uniform(
        key_mass, (), minval=c.mass_scale_range[0], maxval=c.mass_scale_range[1]
    )
    err = jax.random.truncated_normal(key_err, -2.5, 2.5, (4,)) * sigma
    return TrialNoise(fric, mass, err)


def sample_noise(
    key: jax.Array, num_trials: int, config: TrialConfig = TrialConfig()
) -> TrialNoise:
    """Draws the randomisation of ``num_trials`` trials (trial i uses fold_in(key, i)).

    Args:
      key: jax.random key (consumed).
      num_trials: N.
      config: ranges.

    Returns:
      TrialNoise with numpy arrays [N], [N], [N, 4]; trial i is
      ``sample_trial_noise(fold_in(key, i), config)``.
    """
    if isinstance(num_trials, bool) or not isinstance(num_trials, (int, np.integer)):
        raise ValueError(f"num_trials must be an int >= 1, got {num_trials!r}")
    if num_trials < 1:
        raise ValueError(f"num_trials must be >= 1, got {num_trials}")
    fric, mass, err = jax.vmap(
        lambda i: sample_trial_noise(jax.random.fold_in(key, i), config)
    )(jnp.arange(num_trials))
    return TrialNoise(
        np.asarray(fric, np.float64),
        np.asarray(mass, np.float64),
        np.asarray(err, np.float64),
    )


def zero_noise(num_trials: int, friction: float = 0.8) -> TrialNoise:
    """No randomisation: nominal friction, nominal mass, exact grasp pose."""
    return TrialNoise(
        np.full(num_trials, friction), np.ones(num_trials), np.zeros((num_trials, 4))
    )


def _check_noise(noise: TrialNoise, n: int) -> None:
    shapes = (
        np.shape(noise.friction),
        np.shape(noise.mass_scale),
        np.shape(noise.grasp_error),
    )
    if shapes != ((n,), (n,), (n, 4)):
        raise ValueError(
            f"noise shapes {shapes} do not match {n} grasps "
            f"(want ({n},), ({n},), ({n}, 4))"
        )
    for name, v in zip(("friction", "mass_scale"), noise[:2]):
        if not np.all(np.isfinite(v)) or np.min(v) <= 0:
            raise ValueError(f"noise.{name} must be finite and > 0")


# ----------------------------------------------------------------------------- schedule


def _schedule(xp, grasp, config: TrialConfig, half_open: float, dt: float):
    """Initial palm/finger qpos [..., 6] and controls [..., T, 6] for grasps [..., 4].

    Actuator order: palm x, y, z, yaw, finger a, finger b (``scene_ids`` order).
    """
    c = config
    x, y = grasp[..., 0:1], grasp[..., 1:2]
    z = xp.maximum(grasp[..., 2:3], MIN_GRASP_Z)
    th = grasp[..., 3:4]
    t = xp.arange(c.num_steps, dtype=grasp.dtype) + 1.0  # target after step t
    t_close = c.approach_steps + c.settle_steps
    t_lift = t_close + c.close_steps
    t_shake = t_lift + c.lift_steps
    t_hold = t_shake + c.shake_steps
    approach = xp.clip(t / max(c.approach_steps, 1), 0.0, 1.0)
    lift = xp.clip((t - t_lift) / c.lift_steps, 0.0, 1.0)
    z_t = z + c.approach_height * (1.0 - approach) + c.lift_height * lift
    shake_on = (t > t_shake) & (t <= t_hold)
    s = xp.where(
        shake_on,
        c.shake_amplitude * xp.sin(2 * math.pi * c.shake_hz * (t - t_shake) * dt),
        0.0,
    )
    close = xp.clip((t - t_close) / c.close_steps, 0.0, 1.0)
    f_t = half_open + (c.close_target - half_open) * close
    ones = xp.ones_like(z_t)
    ctrl = xp.stack(
        [
            x - xp.sin(th) * s,
            y + xp.cos(th) * s,
            z_t + scene_lib.FINGER_DROP,
            th * ones,
            f_t * ones,
            f_t * ones,
        ],
        axis=-1,
    )
    palm0 = xp.concatenate(
        [
            x,
            y,
            z + c.approach_height + scene_lib.FINGER_DROP,
            th,
            xp.full_like(x, half_open),
            xp.full_like(x, half_open),
        ],
        axis=-1,
    )
    return palm0, ctrl


def _half_open(model: mujoco.MjModel, ids: scene_lib.SceneIds) -> float:
    jnt = model.actuator_trnid[ids.finger_actuators[0], 0]
    return float(model.jnt_range[jnt, 1])


# ----------------------------------------------------------------------------- native


class _NativeRunner:
    """``mujoco.rollout`` in tasks of a few trials each, spread over a thread pool that every
    native simulator of the process shares (:func:`_trial_pool`).

    Each task rolls out its trials on the calling worker thread (``nthread=0``: MuJoCo
    steps with the GIL released) with that thread's own ``MjData`` and model copies (one
    per trial slot, holding the trial's friction and mass), so simulators of several
    objects, called from several threads, keep every core busy with no barrier between
    chunks or objects. A trial's outcome depends only on its model, initial state and
    controls (``rollout`` resets the data for each trajectory), so the outcomes are the
    same bit for bit whatever the task size, the thread count or the order
    (tests/grasp/test_runner.py, tests/grasp/test_context_threads.py)."""

    def __init__(self, model, config, num_threads, chunk):
        self.model, self.config, self.chunk = model, config, chunk
        self.threads = num_threads
        self.ids = scene_lib.scene_ids(model)
        self.half_open = _half_open(model, self.ids)
        self.nstate = mujoco.mj_stateSize(
            model, mujoco.mjtState.mjSTATE_FULLPHYSICS
        )
        self.base_mass = float(model.body_mass[self.ids.object_body])
        self.base_inertia = model.body_inertia[self.ids.object_body].copy()
        data = scene_lib.initial_data(model)
        self.state0 = np.empty(self.nstate)
        mujoco.mj_getState(
            model, data, self.state0, mujoco.mjtState.mjSTATE_FULLPHYSICS
        )
        self._local = threading.local()  # per worker thread: MjData, model copies

    def _task_size(self, n: int) -> int:
        """Trials per task: about 8 tasks per thread (load balance), at most 32 and at
        most ``chunk`` (memory: task x steps x state doubles per thread)."""
        return max(1, min(self.chunk, _MAX_TASK, -(-n // (8 * self.threads))))

    def _workspace(self, size: int):
        """This thread's (rollout, data, model copies), at least ``size`` copies."""
        local = self._local
        if not hasattr(local, "data"):
            local.rollout = mj_rollout.Rollout(nthread=0)
            local.data = mujoco.MjData(self.model)
            local.models = []
        while len(local.models) < size:
            local.models.append(copy.copy(self.model))
        return local.rollout, local.data, local.models[:size]

    def _task(self, lo, hi, state0, ctrl, friction, mass_scale):
        """Trials [lo, hi): (nan, rise before the nan rule, gap) for each."""
        ids, q = self.ids, 1
        rollout, data, models = self._workspace(hi - lo)
        for m, f, s in zip(models, friction[lo:hi], mass_scale[lo:hi]):
            m.geom_friction[list(ids.object_geoms), 0] = f
            m.body_mass[ids.object_body] = self.base_mass * s
            m.body_inertia[ids.object_body] = self.base_inertia * s
        state, _ = rollout.rollout(models, data, state0[lo:hi], ctrl[lo:hi])
        nq, nv = self.model.nq, self.model.nv
        qpos_t = state[:, :, q : q + nq]
        qvel_t = state[:, :, q + nq : q + nq + nv]
        # mujoco.rollout stops stepping a trial at a MuJoCo warning (e.g. bad
        # qacc) and repeats its last state: a final time short of the schedule
        # means the trial diverged, even if that state is finite.
        expected_t = self.state0[0] + self.config.num_steps * self.model.opt.timestep
        finite = (
            np.isfinite(state).all(axis=(1, 2))
            & (np.abs(qpos_t) < QPOS_LIMIT).all(axis=(1, 2))
            & (np.abs(qvel_t) < QVEL_LIMIT).all(axis=(1, 2))
            & (np.abs(state[:, -1, 0] - expected_t) < 0.5 * self.model.opt.timestep)
        )
        last = state[:, -1]
        rise = last[:, q + ids.object_qpos + 2] - state0[lo:hi, q + ids.object_qpos + 2]
        gap = last[:, q + ids.finger_qpos[0]] + last[:, q + ids.finger_qpos[1]]
        return ~finite, rise, gap

    def __call__(self, grasps, noise, object_pose):
        ids, n = self.ids, len(grasps)
        palm0, ctrl = _schedule(
            np,
            grasps + noise.grasp_error,
            self.config,
            self.half_open,
            self.model.opt.timestep,
        )
        q = 1  # FULLPHYSICS state: [time, qpos, qvel, act, ...]
        state0 = np.tile(self.state0, (n, 1))
        state0[:, q + np.array(ids.palm_qpos + ids.finger_qpos)] = palm0
        if object_pose is not None:
            state0[:, q + ids.object_qpos : q + ids.object_qpos + 7] = object_pose
        ctrl = np.ascontiguousarray(ctrl)
        size = self._task_size(n)
        bounds = [(lo, min(n, lo + size)) for lo in range(0, n, size)]
        args = (state0, ctrl, noise.friction, noise.mass_scale)
        if self.threads <= 1 or len(bounds) == 1:
            parts = [self._task(lo, hi, *args) for lo, hi in bounds]
        else:
            pool = _trial_pool(self.threads)
            parts = [f.result() for f in
                     [pool.submit(self._task, lo, hi, *args) for lo, hi in bounds]]
        nan, rise, gap = (np.concatenate(x) for x in zip(*parts))
        rise = np.where(nan, np.nan, rise)
        success = succeeded(~nan, rise, gap, self.config)
        return TrialResult(success, nan, rise, gap, "native")


_MAX_TASK = 32  # most trials per native task
_TRIAL_POOLS: dict[int, concurrent.futures.ThreadPoolExecutor] = {}
_TRIAL_POOLS_LOCK = threading.Lock()


def _trial_pool(threads: int) -> concurrent.futures.ThreadPoolExecutor:
    """The process's pool of ``threads`` native trial workers (shared by simulators)."""
    with _TRIAL_POOLS_LOCK:
        if threads not in _TRIAL_POOLS:
            _TRIAL_POOLS[threads] = concurrent.futures.ThreadPoolExecutor(
                threads, thread_name_prefix="sern-trials")
        return _TRIAL_POOLS[threads]


# ----------------------------------------------------------------------------- mjx


class TrialOutcome(NamedTuple):
    """Outcome of one trial from :func:`make_execute` (leading axes when vmapped)."""

    success: jax.Array  # [] bool: finite, rose >= success_lift, jaws not closed on nothing
    finite: jax.Array  # [] bool: every step stayed finite and within the limits
    rise: jax.Array  # [] object z rise at the end, metres (meaningless when not finite)
    gap: jax.Array  # [] final distance between the pads' inner faces, metres


def make_execute(config: TrialConfig, model: mujoco.MjModel, hessian: str = "blocks"):
    """A pure, unbatched MJX grasp trial for scenes shaped like ``model``.

    The scene's structure (indices, finger range, timestep) is read from ``model`` on the
    host; everything else is an argument, so one ``execute`` (and one compiled program)
    serves every scene of the same structure. ``jax.vmap`` it over poses, grasps and
    trial params (``GraspSimulator``'s MJX backend is ``jit(vmap(execute))``).

    Args:
      config: trial schedule and success rule.
      model: a grasp scene (``scene.build_scene`` / ``context.scene_model``).
      hessian: how the Newton solver assembles its constraint Hessian: ``"blocks"``
        (per-contact cone blocks, :mod:`sern_jax.grasp.world.mjx_solver`) or ``"mjx"``
        (MJX's own dense assembly, the reference; same matrix, other summation order).

    Returns:
      ``execute(mx, pose, grasp, trial_params) -> TrialOutcome`` where ``mx`` is
      ``mjx.put_model(model)`` (or a scene of the same structure), ``pose`` [7] the
      object's start pose (x, y, z, qw, qx, qy, qz), ``grasp`` [4] the commanded grasp
      (x, y, z, θ) and ``trial_params`` a :class:`TrialNoise` of scalars (friction,
      mass_scale) and a [4] grasp error (one draw of :func:`sample_trial_noise`). Pure:
      jit and vmap it.
    """
    if not isinstance(config, TrialConfig):
        raise ValueError(f"config must be a TrialConfig, got {type(config).__name__}")
    if not isinstance(model, mujoco.MjModel):
        raise ValueError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    ids = scene_lib.scene_ids(model)
    return _make_execute(
        ids, config, _half_open(model, ids), float(model.opt.timestep), hessian
    )


def _trial_model(mx, ids: scene_lib.SceneIds, pose, palm0, trial_params: TrialNoise):
    """(the model with this trial's object friction and mass, the start qpos [nq]): the
    object at ``pose``, palm and fingers at ``palm0``."""
    obj_geoms = np.asarray(ids.object_geoms)
    palm_idx = np.asarray(ids.palm_qpos + ids.finger_qpos)
    body, qa = ids.object_body, ids.object_qpos
    m = mx.replace(
        geom_friction=mx.geom_friction.at[obj_geoms, 0].set(trial_params.friction),
        body_mass=mx.body_mass.at[body].multiply(trial_params.mass_scale),
        body_inertia=mx.body_inertia.at[body].multiply(trial_params.mass_scale),
    )
    return m, mx.qpos0.at[qa : qa + 7].set(pose).at[palm_idx].set(palm0)


def _still_finite(finite, d):
    """``finite`` and the state ``d`` within QPOS_LIMIT / QVEL_LIMIT (False for NaN too)."""
    return (finite & jnp.all(jnp.abs(d.qpos) < QPOS_LIMIT)
            & jnp.all(jnp.abs(d.qvel) < QVEL_LIMIT))


def _rise_and_gap(d, qpos0, ids: scene_lib.SceneIds):
    """(the object's rise above its start height, the jaw gap) at the state ``d``."""
    qa = ids.object_qpos
    return (d.qpos[qa + 2] - qpos0[qa + 2],
            d.qpos[ids.finger_qpos[0]] + d.qpos[ids.finger_qpos[1]])


@functools.lru_cache(maxsize=16)
def _make_execute(
    ids: scene_lib.SceneIds, config: TrialConfig, half_open: float, timestep: float,
    hessian: str = "blocks",
):
    """make_execute's function, one per static structure (so jit caches are shared)."""
    from sern_jax.grasp.world import mjx_solver
    from sern_jax.grasp.world._mjx import mjx

    def execute(mx, pose, grasp, trial_params: TrialNoise) -> TrialOutcome:
        # MJX's own code relies on NumPy rank promotion (mjx/_src/smooth.py), so it is
        # allowed here even when the caller sets jax_numpy_rank_promotion="raise".
        with jax.numpy_rank_promotion("allow"):
            return _execute(mx, pose, grasp, trial_params)

    def _execute(mx, pose, grasp, trial_params):
        palm0, ctrl = _schedule(
            jnp, grasp + trial_params.grasp_error, config, half_open, timestep
        )
        m, qpos0 = _trial_model(mx, ids, pose, palm0, trial_params)
        d = mjx.make_data(m)
        d = d.replace(qpos=qpos0, ctrl=ctrl[0])

        def step(carry, ctrl_t):
            d, finite = carry
            d = mjx.step(m, d.replace(ctrl=ctrl_t))
            return (d, _still_finite(finite, d)), None

        (d, finite), _ = jax.lax.scan(step, (d, jnp.array(True)), ctrl)
        rise, gap = _rise_and_gap(d, qpos0, ids)
        success = succeeded(finite, rise, gap, config)
        return TrialOutcome(success=success, finite=finite, rise=rise, gap=gap)

    return mjx_solver.block_hessian(execute, hessian)


@functools.lru_cache(maxsize=16)
def _batched_execute(execute):
    """jit(vmap(execute)) over poses, grasps and trial params; the model is shared."""
    return jax.jit(jax.vmap(execute, in_axes=(None, 0, 0, 0)))


class _MjxRunner:
    """MJX backend: ``jit(vmap(make_execute(...)))`` over trials, batches padded to 2^k, or
    run in chunks of exactly ``batch`` trials (the last one padded) when ``batch`` is set.
    By default on the scene's uniform model (``uniform``): one compiled program for every
    object, whatever the batch sizes; with ``shape=None`` on the scene itself (one program
    per object structure)."""

    def __init__(self, model, config, batch=None, shape="auto"):
        from sern_jax.grasp.world._mjx import mjx

        self.model, self.config, self.batch = model, config, batch
        self.ids = scene_lib.scene_ids(model)
        self.pose0 = scene_lib.object_pose(model)
        if shape is None:  # the scene's own structure: one program per object structure
            self.mx = mjx.put_model(model)
            self.program = _batched_execute(make_execute(config, model))
            return
        from sern_jax.grasp.world import uniform

        if shape == "auto":
            shape = uniform.shape_for(model)
        self.uniform = uniform.uniform_scene(model, shape)
        self.mx = uniform.put_uniform(self.uniform, shape)
        self.program = _batched_execute(make_execute(config, self.uniform))

    def __call__(self, grasps, noise, object_pose):
        n = len(grasps)
        if n == 0:
            empty = np.zeros(0)
            return TrialResult(empty.astype(bool), empty.astype(bool), empty, empty, "mjx")
        poses = np.tile(self.pose0, (n, 1)) if object_pose is None else object_pose
        # Pad the batch (repeating trial 0, results dropped) to the next power of two, or
        # to whole chunks of `batch`, so that varying numbers of trials reuse a few (or
        # one) compiled programs.
        size = self.batch or 1 << max(n - 1, 0).bit_length()
        n_pad = -(-max(n, 1) // size) * size
        pad = np.concatenate([np.arange(n), np.zeros(n_pad - n, np.int64)])
        f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
        finite, rise, gap = [], [], []
        for lo in range(0, n_pad, size):
            idx = pad[lo:lo + size]
            params = TrialNoise(*(f32(a[idx]) for a in noise))
            with jax.numpy_rank_promotion("allow"):
                out = self.program(self.mx, f32(poses[idx]), f32(grasps[idx]), params)
            finite.append(np.asarray(out.finite))
            rise.append(np.asarray(out.rise, np.float64))
            gap.append(np.asarray(out.gap, np.float64))
        nan = ~np.concatenate(finite)[:n]
        rise = np.where(nan, np.nan, np.concatenate(rise)[:n])
        gap = np.concatenate(gap)[:n]
        # Decided here in float64, as the native backend does (out.success is the same
        # rule in float32).
        success = succeeded(~nan, rise, gap, self.config)
        return TrialResult(success, nan, rise, gap, "mjx")


# ----------------------------------------------------------------------------- objects x trials


@functools.lru_cache(maxsize=8)
def _objects_program(execute):
    """jit(vmap over objects (model, poses, grasps, params) of vmap over trials)."""
    per_object = jax.vmap(execute, in_axes=(None, 0, 0, 0))
    return jax.jit(jax.vmap(per_object, in_axes=(0, 0, 0, 0)))


class UniformBatch:
    """MJX trials of several objects in one compiled program: ``jit(vmap(vmap(execute)))``
    over objects x trials, on the stacked uniform models of the objects' scenes.

    Args:
      models: exact grasp scenes (``scene.build_scene``), one per object, all built with
        the same ``SceneConfig``.
      config: the trial.
      shape: a ``uniform.UniformShape`` (None: ``uniform.shape_for`` of the object with
        most parts).
      trials: trials per object per compiled call (calls are padded to it, so every call
        runs the one program).
      prepared: optional ``UniformBatch.prepare(model, shape)`` of every model, made ahead
        (e.g. in threads, while another batch runs); None makes them here. A model may
        appear twice (one prepared pair serves both).
      hessian: the Newton Hessian's assembly (:func:`make_execute`): ``"blocks"`` or the
        reference ``"mjx"``.

    Attributes:
      uniform: the uniform ``MjModel`` of each object (native MuJoCo runs them too).
      mx: the stacked ``mjx.Model`` [O, ...].
      compiles: distinct compiled trial programs so far (``_cache_size`` of the jitted
        program, which is shared by every UniformBatch of the same structure).
    """

    def __init__(self, models, config: TrialConfig = TrialConfig(), shape=None,
                 trials: int = 64, prepared=None, hessian: str = "blocks"):
        from sern_jax.grasp.world import uniform

        models = list(models)
        if not models:
            raise ValueError("UniformBatch needs at least one model")
        if shape is None:
            shape = max((uniform.shape_for(m) for m in models), key=lambda s: s.parts)
        if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
            raise ValueError(f"trials must be an int >= 1, got {trials!r}")
        if prepared is None:
            prepared = [self.prepare(m, shape) for m in models]
        prepared = list(prepared)
        if len(prepared) != len(models):
            raise ValueError(f"prepared holds {len(prepared)} pairs for {len(models)} models")
        self.config, self.shape, self.trials = config, shape, trials
        self.uniform = [u for u, _ in prepared]
        self.mx = uniform.stack_models([mx for _, mx in prepared])
        self.program = _objects_program(make_execute(config, self.uniform[0], hessian))
        self.pose0 = np.stack([scene_lib.object_pose(m) for m in self.uniform])

    @staticmethod
    def prepare(model: mujoco.MjModel, shape) -> tuple:
        """The host work of one object (resampled hulls, ``mjx.put_model``): its uniform
        ``MjModel`` and normalized ``mjx.Model`` (``uniform.uniform_scene`` and
        ``uniform.put_uniform`` with ``shape``), for ``UniformBatch(..., prepared=)``."""
        from sern_jax.grasp.world import uniform

        u = uniform.uniform_scene(model, shape)
        return u, uniform.put_uniform(u, shape)

    @property
    def compiles(self) -> int:
        return int(self.program._cache_size())

    def run_trials(self, grasps, noise: TrialNoise, object_pose=None):
        """Runs N trials on each of the O objects.

        Args:
          grasps: [O, N, 4] commanded grasps.
          noise: TrialNoise of [O, N], [O, N], [O, N, 4].
          object_pose: optional [O, N, 7] (or [O, 7]) start poses (default: each uniform
            scene's ``qpos0`` pose).

        Returns:
          list of O ``TrialResult`` (backend ``"mjx"``), decided as ``GraspSimulator``
          decides them.
        """
        o = len(self.uniform)
        g = check_grasps(grasps)
        if g.ndim != 3 or g.shape[0] != o:
            raise ValueError(f"grasps must have shape [{o}, N, 4], got {g.shape}")
        n = g.shape[1]
        for i in range(o):
            _check_noise(TrialNoise(*(a[i] for a in noise)), n)
        if object_pose is None:
            poses = np.broadcast_to(self.pose0[:, None], (o, n, 7))
        else:
            p = np.asarray(object_pose, np.float64)
            poses = np.broadcast_to(p[:, None] if p.ndim == 2 else p, (o, n, 7))
        size = self.trials
        n_pad = -(-max(n, 1) // size) * size
        pad = np.concatenate([np.arange(n), np.zeros(n_pad - n, np.int64)])
        f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
        finite, rise, gap = [], [], []
        for lo in range(0, n_pad, size):
            idx = pad[lo:lo + size]
            params = TrialNoise(*(f32(np.asarray(a)[:, idx]) for a in noise))
            with jax.numpy_rank_promotion("allow"):
                out = self.program(self.mx, f32(poses[:, idx]), f32(g[:, idx]), params)
            finite.append(np.asarray(out.finite))
            rise.append(np.asarray(out.rise, np.float64))
            gap.append(np.asarray(out.gap, np.float64))
        nan = ~np.concatenate(finite, 1)[:, :n]
        rise = np.where(nan, np.nan, np.concatenate(rise, 1)[:, :n])
        gap = np.concatenate(gap, 1)[:, :n]
        success = succeeded(~nan, rise, gap, self.config)
        return [TrialResult(success[i], nan[i], rise[i], gap[i], "mjx")
                for i in range(o)]


# ----------------------------------------------------------------------------- interface


class GraspSimulator:
    """Runs grasp trials on one scene with one backend: a thin host-side wrapper that
    checks inputs and hands them to the native (``mujoco.rollout``) or MJX
    (``jit(vmap(make_execute(...)))``) backend.

    Args:
      model: a scene from ``scene.build_scene`` (its ``qpos0`` is the resting pose).
      backend: ``"native"`` (MuJoCo C, ``mujoco.rollout``) or ``"mjx"``.
      config: trial schedule, success rule and randomisation ranges.
      num_threads: native threads (default: :func:`sern_jax.infra.hosts.cpu_threads`).
      chunk: native trials per rollout call (memory: chunk x steps x state doubles).
      mjx_batch: MJX trials per compiled call (None: each call padded to the next power
        of two, one compile per size; an int: chunks of exactly this many, one compile).
      mjx_shape: the MJX model: ``"auto"`` (default) the scene's uniform model
        (``uniform.uniform_scene`` with ``uniform.shape_for(model)``), so that one compiled
        program serves every object; a ``uniform.UniformShape``; or None for the scene
        itself (its own program; exact primitives and hulls).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        backend: str = "native",
        config: TrialConfig = TrialConfig(),
        num_threads: int | None = None,
        chunk: int = 256,
        mjx_batch: int | None = None,
        mjx_shape="auto",
    ):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if not isinstance(model, mujoco.MjModel):
            raise ValueError(
                f"model must be a mujoco.MjModel, got {type(model).__name__}"
            )
        self.backend, self.config, self.model = backend, config, model
        self.ids = scene_lib.scene_ids(model)
        if backend == "native":
            threads = num_threads or hosts.cpu_threads()
            if threads < 1 or chunk < 1:
                raise ValueError(
                    f"num_threads and chunk must be >= 1, got {threads}, {chunk}"
                )
            self._runner = _NativeRunner(model, config, threads, chunk)
        else:
            if mjx_batch is not None and (isinstance(mjx_batch, bool) or mjx_batch < 1):
                raise ValueError(f"mjx_batch must be an integer >= 1, got {mjx_batch!r}")
            self._runner = _MjxRunner(model, config, mjx_batch, mjx_shape)

    def run_trials(self, grasps, noise: TrialNoise, object_pose=None) -> TrialResult:
        """Runs N trials.

        Args:
          grasps: [N, 4] commanded grasps (x, y, z, θ), world frame.
          noise: per-trial randomisation (``sample_noise`` / ``zero_noise``), N each.
          object_pose: optional [7] or [N, 7] object start pose (default: the scene's
            resting pose in ``model.qpos0``).

        Returns:
          TrialResult with arrays [N] and the backend name.
        """
        g = check_grasps(grasps)
        if g.ndim != 2:
            raise ValueError(f"grasps must have shape [N, 4], got {g.shape}")
        _check_noise(noise, len(g))
        if object_pose is not None:
            object_pose = np.broadcast_to(
                np.asarray(object_pose, np.float64), (len(g), 7)
            )
            if not np.all(np.isfinite(object_pose)):
                raise ValueError("object_pose must be finite")
        return self._runner(g, noise, object_pose)

    def success_probability(
        self, key: jax.Array, grasps, num_trials: int, valid=None, object_pose=None
    ) -> SuccessEstimate:
        """Estimates r_a(s) for each of K candidates by M randomised trials each.

        Trial j of every candidate uses the same noise draw ``fold_in(key, j)``
        (common random numbers across candidates). Non-finite trials count as failures
        and are reported in ``nan_count``. Invalid candidates are not simulated and get
        probability 0.

        Args:
          key: jax.random key (consumed).
          grasps: [K, 4] candidates (x, y, z, θ).
          num_trials: M >= 1.
          valid: optional [K] bool mask.
          object_pose: optional [7] start pose of the object for this context.

        Returns:
          SuccessEstimate with prob [K] = successes / M.
        """
        g = check_grasps(grasps)
        if g.ndim != 2:
            raise ValueError(f"grasps must have shape [K, 4], got {g.shape}")
        if num_trials < 1:
            raise ValueError(f"num_trials must be >= 1, got {num_trials}")
        k = len(g)
        valid = np.ones(k, bool) if valid is None else np.asarray(valid, bool)
        if valid.shape != (k,):
            raise ValueError(f"valid must have shape ({k},), got {valid.shape}")
        noise = sample_noise(key, num_trials, self.config)
        idx = np.flatnonzero(valid)
        successes = np.zeros(k, np.int64)
        nan_count = np.zeros(k, np.int64)
        if len(idx):
            tiled = np.repeat(g[idx], num_trials, axis=0)  # [k_valid * M, 4]
            tnoise = TrialNoise(
                *(np.tile(a, (len(idx),) + (1,) * (a.ndim - 1)) for a in noise)
            )
            res = self.run_trials(tiled, tnoise, object_pose)
            successes[idx] = res.success.reshape(len(idx), num_trials).sum(1)
            nan_count[idx] = res.nan.reshape(len(idx), num_trials).sum(1)
        return SuccessEstimate(
            successes / num_trials,
            successes,
            nan_count,
            num_trials,
            valid,
            self.backend,
        )


def agreement(native: TrialResult, mjx_result: TrialResult) -> dict:
    """Paired agreement of two backends' outcomes on the same trials."""
    a, b = native.success, mjx_result.success
    if a.shape != b.shape:
        raise ValueError(f"paired results differ in shape: {a.shape} vs {b.shape}")
    return {
        "num_trials": int(a.size),
        "agreement": float(np.mean(a == b)),
        f"success_{native.backend}": float(a.mean()),
        f"success_{mjx_result.backend}": float(b.mean()),
        f"nan_{native.backend}": int(native.nan.sum()),
        f"nan_{mjx_result.backend}": int(mjx_result.nan.sum()),
    }
