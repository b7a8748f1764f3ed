"""Host-side scene build: table, one object at a resting pose, a parallel-jaw gripper.

``build_scene(spec, seed)`` writes an MJCF string, compiles it with MuJoCo, drops the
object from a random orientation onto the table with native MuJoCo until it rests, and
returns the ``mujoco.MjModel`` with that resting pose stored in ``model.qpos0`` (so
``mujoco.MjData(model)`` / ``mjx.make_data`` start with the object at rest;
:func:`initial_data` also parks the gripper).

Layout (world frame, metres; the table top is the plane z = 0):

* ``table``: plane, geom group 0, material ``table_mat``.
* ``object``: one body with a free joint ``object_free``; geoms ``object_<i>`` in geom
  group 1 (types box / sphere / capsule / mesh only, see ``objects``), material
  ``object_mat``. Its resting pose is near (0, 0) (random offset within ±``xy_jitter``).
* ``palm``: one body with joints ``palm_x``, ``palm_y``, ``palm_z`` (slides along world
  axes, qpos = world position of the palm) and ``palm_yaw`` (hinge about z, qpos = jaw
  yaw), position actuators of the same names. Gravity-compensated. Parked at
  ``PARK_POS`` (above any overhead camera) by :func:`initial_data`.
* two fingers ``finger_a`` / ``finger_b`` on slides along the palm's x axis; joint qpos
  = distance of that pad's inner face from the grasp centre (0 = closed, ``opening/2`` =
  open); position actuators with force limited to ``finger_force`` newtons.
  Pads ``pad_a`` / ``pad_b`` are boxes; gripper geoms are in geom group 3 (exclude
  group 3 when rendering depth).
* The grasp centre (midpoint between the pads' centres) sits ``FINGER_DROP`` below the
  palm origin: a grasp (x, y, z, θ) puts the palm at (x, y, z + FINGER_DROP) with yaw θ.
  θ is the direction of the jaw axis (pad a -> pad b is -x_palm -> +x_palm).
* Cameras: ``overhead`` (0.6 m above the origin, looking down) and ``view`` (oblique).

Collision filtering: the table touches only the object; pads and palm touch only the
object (contype/conaffinity bits), so there are at most (object geoms) x 4 pairs.

Solver: elliptic cones, impratio 10, Newton with >= 5 iterations, semi-implicit Euler
with explicit damping (eulerdamp off), 5 ms, auto-reset off (a diverged native simulation stays NaN and is
reported instead of silently restarting). No ``max_contact_points`` limit. Measured
here: implicitfast, implicit, and Euler with implicit damping all let a small box
dropped on its edge spin up to >1000 rad/s or NaN with impratio 10; explicit Euler did
not (armatures are sized so explicit damping is stable at 5 ms).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import mujoco
import numpy as np

from sern_jax.grasp.world import objects as objects_lib

__all__ = [
    "FINGER_DROP",
    "PAD_HALF",
    "PARK_POS",
    "GROUP_TABLE",
    "GROUP_OBJECT",
    "GROUP_GRIPPER",
    "SceneConfig",
    "SceneIds",
    "scene_xml",
    "scene_config",
    "scene_ids",
    "resting_pose",
    "resting_pose_from_uniforms",
    "build_scene",
    "set_object_pose",
    "object_pose",
    "initial_data",
    "object_points",
    "centred_grasp",
]

FINGER_DROP = 0.06  # grasp centre below the palm origin, metres
PAD_HALF = (0.005, 0.012, 0.02)  # pad half-sizes: thickness (x), width (y), height (z)
PARK_POS = (0.0, 0.0, 1.0)  # palm parking position (x, y, z), out of view
GROUP_TABLE, GROUP_OBJECT, GROUP_GRIPPER = 0, 1, 3
GRIPPER = "Robotiq 2F-85 at its lowest force setting (20 N per finger)"
WEAK_FINGER_FORCE = 6.0  # N per finger: the trial before 2026-11-24, a non-default setting


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Physical and solver settings of the grasp scene (changes compiled code in MJX).

    Attributes:
      timestep: physics step, seconds.
      iterations / ls_iterations: Newton solver (>= 5 iterations: fewer gave NaN in MJX).
        20 / 20 since 2026-11-24: with a 20 N squeeze, 6 / 8 left the solver unconverged
        and outcomes at 5 ms agreed with 1.25 ms in only 93 % of fixed paired trials
        (97 % with 20 / 20, the same as with 50 / 50; ``experiments/trial_checks.py``).
      impratio: frictional-to-normal impedance ratio (elliptic cones).
      opening: maximal jaw opening (distance between the pads' inner faces), metres.
      finger_force: force limit of each finger actuator, newtons. Default 20 N: the
        lowest grip-force setting of a Robotiq 2F-85 (datasheet range 20-235 N; the
        jaw's 8.5 cm stroke is the 2F-85's too). ``WEAK_FINGER_FORCE`` (6 N) is the trial
        the shipped artefacts used before 2026-11-24 (sensitivity cells, history).
      finger_kp: finger position gain, N/m (high, so the squeeze sits at the limit).
      finger_damping: finger joint damping, N s/m.
      palm_kp / palm_damping: x, y, z position gain (N/m) and joint damping (N s/m).
      yaw_kp / yaw_damping: yaw gain (N m/rad) and damping (N m s/rad).
      friction: nominal sliding friction of the object geoms (trials randomise it).
      pad_friction: sliding friction of the pads (MuJoCo uses the max of the pair, so
        the object's friction decides the pad-object contact when it is larger).
      xy_jitter: resting-pose offset range in x and y, metres.
      settle_steps: most native steps to let a dropped object come to rest.
    """

    timestep: float = 0.005
    iterations: int = 20
    ls_iterations: int = 20
    impratio: float = 10.0
    opening: float = 0.085
    finger_force: float = 20.0
    finger_kp: float = 1000.0
    finger_damping: float = 20.0
    palm_kp: float = 4000.0
    palm_damping: float = 200.0
    yaw_kp: float = 50.0
    yaw_damping: float = 5.0
    friction: float = 0.8
    pad_friction: float = 0.3
    xy_jitter: float = 0.02
    settle_steps: int = 600

    def __post_init__(self):
        if not (0 < self.timestep <= 0.02):
            raise ValueError(f"timestep must be in (0, 0.02] s, got {self.timestep}")
        if self.iterations < 1 or self.ls_iterations < 1:
            raise ValueError(
                f"iterations/ls_iterations must be >= 1, got "
                f"{self.iterations}/{self.ls_iterations}"
            )
        if not (0.02 <= self.opening <= 0.2):
            raise ValueError(f"opening must be in [0.02, 0.2] m, got {self.opening}")
        if not (self.finger_force > 0 and self.friction > 0 and self.impratio >= 1):
            raise ValueError(
                "finger_force and friction must be > 0 and impratio >= 1, got "
                f"{self.finger_force}, {self.friction}, {self.impratio}"
            )


class SceneIds(NamedTuple):
    """Indices into a built scene's model (all ints / tuples of ints)."""

    object_body: int
    object_geoms: tuple[int, ...]
    object_qpos: int  # qpos address of the object's free joint (7 values)
    object_dof: int  # dof address of the free joint (6 values)
    table_geom: int
    pad_geoms: tuple[int, int]
    gripper_geoms: tuple[int, ...]
    palm_qpos: tuple[int, int, int, int]  # x, y, z, yaw
    finger_qpos: tuple[int, int]  # finger_a, finger_b
    palm_actuators: tuple[int, int, int, int]  # x, y, z, yaw
    finger_actuators: tuple[int, int]


def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def scene_xml(spec: objects_lib.ObjectSpec, config: SceneConfig = SceneConfig(),
              inertial: tuple | None = None) -> str:
    """The scene's MJCF (object at the origin, identity orientation, not yet dropped).

    ``inertial``: optional (pos [3], quat [4], mass, diaginertia [3]) of the object body,
    written at full precision in place of the inertia MuJoCo derives from the geoms (a
    uniform scene keeps the exact object's inertia this way)."""
    c = config
    body_inertial = ""
    if inertial is not None:
        pos, quat, mass, diag = inertial
        full = lambda v: " ".join(repr(float(x)) for x in np.ravel(v))  # noqa: E731
        body_inertial = (f'<inertial pos="{full(pos)}" quat="{full(quat)}" '
                         f'mass="{float(mass)!r}" diaginertia="{full(diag)}"/>')
    assets, geoms = [], []
    total_volume = spec.volume
    for i, g in enumerate(spec.geoms):
        mass = spec.mass * g.volume / total_volume
        common = (
            f'name="object_{i}" pos="{_fmt(g.pos)}" quat="{_fmt(g.quat)}" '
            f'mass="{mass:.9g}" material="object_mat" group="{GROUP_OBJECT}" '
            f'contype="1" conaffinity="2" condim="3" '
            f'friction="{c.friction:.6g} 0.002 0.0001"'
        )
        if g.type == "mesh":
            assets.append(
                f'<mesh name="object_mesh_{i}" vertex="{_fmt(g.vertex_array.ravel())}"/>'
            )
            geoms.append(f'<geom type="mesh" mesh="object_mesh_{i}" {common}/>')
        else:
            geoms.append(f'<geom type="{g.type}" size="{_fmt(g.size)}" {common}/>')
    half_open = c.opening / 2
    px, py, pz = PAD_HALF
    pad = (
        f'type="box" size="{px} {py} {pz}" material="pad_mat" group="{GROUP_GRIPPER}" '
        f'contype="2" conaffinity="0" condim="4" '
        f'friction="{c.pad_friction:.6g} 0.005 0.0001" mass="0.02"'
    )
    finger_joint = (
        f'type="slide" range="0 {half_open:.6g}" damping="{c.finger_damping:.6g}" '
        'armature="0.05" limited="true"'
    )
    palm_slide = f'type="slide" damping="{c.palm_damping:.6g}" armature="0.1"'
    finger_act = (
        f'kp="{c.finger_kp:.6g}" forcerange="-{c.finger_force:.6g} '
        f'{c.finger_force:.6g}" forcelimited="true" ctrlrange="-0.02 {half_open:.6g}" '
        'ctrllimited="true"'
    )
    return f"""<mujoco model="sern_grasp_{spec.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{c.timestep:.6g}" integrator="Euler" solver="Newton"
          iterations="{c.iterations}" ls_iterations="{c.ls_iterations}" cone="elliptic"
          impratio="{c.impratio:.6g}">
    <flag eulerdamp="disable" autoreset="disable"/>
  </option>
  <visual><global offwidth="640" offheight="480"/></visual>
  <asset>
    <material name="table_mat" rgba="0.55 0.5 0.45 1"/>
    <material name="object_mat" rgba="0.2 0.5 0.8 1"/>
    <material name="pad_mat" rgba="0.8 0.3 0.2 1"/>
    <material name="palm_mat" rgba="0.3 0.3 0.3 1"/>
    {"".join(assets)}
  </asset>
  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    <camera name="overhead" pos="0 0 0.6" xyaxes="1 0 0 0 1 0" fovy="45"/>
    <camera name="view" pos="0.35 -0.35 0.35" xyaxes="0.707 0.707 0 -0.4 0.4 0.825"/>
    <geom name="table" type="plane" size="0.5 0.5 0.01" material="table_mat"
          group="{GROUP_TABLE}" contype="0" conaffinity="1" condim="3"
          friction="0.5 0.005 0.0001"/>
    <body name="object" pos="0 0 0.2">
      <freejoint name="object_free"/>
      {body_inertial}{"".join(geoms)}
    </body>
    <body name="palm" gravcomp="1">
      <joint name="palm_x" axis="1 0 0" {palm_slide}/>
      <joint name="palm_y" axis="0 1 0" {palm_slide}/>
      <joint name="palm_z" axis="0 0 1" {palm_slide}/>
      <joint name="palm_yaw" type="hinge" axis="0 0 1" damping="{c.yaw_damping:.6g}"
             armature="0.05"/>
      <geom name="palm" type="box" size="{half_open + 2 * px:.6g} 0.015 0.01" mass="0.5"
            material="palm_mat" group="{GROUP_GRIPPER}" contype="2" conaffinity="0"
            condim="3"/>
      <body name="finger_a" gravcomp="1">
        <joint name="finger_a" axis="-1 0 0" {finger_joint}/>
        <geom name="finger_a_link" type="box" size="0.004 0.008 {FINGER_DROP / 2:.6g}"
              pos="{-px:.6g} 0 {-FINGER_DROP / 2:.6g}" mass="0.02" material="palm_mat"
              group="{GROUP_GRIPPER}" contype="0" conaffinity="0"/>
        <geom name="pad_a" pos="{-px:.6g} 0 {-FINGER_DROP:.6g}" {pad}/>
      </body>
      <body name="finger_b" gravcomp="1">
        <joint name="finger_b" axis="1 0 0" {finger_joint}/>
        <geom name="finger_b_link" type="box" size="0.004 0.008 {FINGER_DROP / 2:.6g}"
              pos="{px:.6g} 0 {-FINGER_DROP / 2:.6g}" mass="0.02" material="palm_mat"
              group="{GROUP_GRIPPER}" contype="0" conaffinity="0"/>
        <geom name="pad_b" pos="{px:.6g} 0 {-FINGER_DROP:.6g}" {pad}/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="palm_x" joint="palm_x" kp="{c.palm_kp:.6g}"/>
    <position name="palm_y" joint="palm_y" kp="{c.palm_kp:.6g}"/>
    <position name="palm_z" joint="palm_z" kp="{c.palm_kp:.6g}"/>
    <position name="palm_yaw" joint="palm_yaw" kp="{c.yaw_kp:.6g}"/>
    <position name="finger_a" joint="finger_a" {finger_act}/>
    <position name="finger_b" joint="finger_b" {finger_act}/>
  </actuator>
</mujoco>
"""


def scene_config(model: mujoco.MjModel) -> SceneConfig:
    """The ``SceneConfig`` a scene was built with, read back from the compiled model (the
    settling settings ``xy_jitter`` and ``settle_steps`` leave no trace in it and come back
    as their defaults; ``friction`` is the object's current sliding friction)."""
    ids = scene_ids(model)

    def dof(joint_name):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint_name)
        return float(model.dof_damping[model.jnt_dofadr[j]])

    finger = ids.finger_actuators[0]
    jnt = model.actuator_trnid[finger, 0]
    return SceneConfig(
        timestep=float(model.opt.timestep),
        iterations=int(model.opt.iterations),
        ls_iterations=int(model.opt.ls_iterations),
        impratio=float(model.opt.impratio),
        opening=2 * float(model.jnt_range[jnt, 1]),
        finger_force=float(model.actuator_forcerange[finger, 1]),
        finger_kp=float(model.actuator_gainprm[finger, 0]),
        finger_damping=dof("finger_a"),
        palm_kp=float(model.actuator_gainprm[ids.palm_actuators[0], 0]),
        palm_damping=dof("palm_x"),
        yaw_kp=float(model.actuator_gainprm[ids.palm_actuators[3], 0]),
        yaw_damping=dof("palm_yaw"),
        friction=float(model.geom_friction[ids.object_geoms[0], 0]),
        pad_friction=float(model.geom_friction[ids.pad_geoms[0], 0]),
    )


def scene_ids(model: mujoco.MjModel) -> SceneIds:
    """Indices of the object, table, pads, palm and finger joints/actuators."""

    def gid(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)

    def jid(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)

    def aid(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    if body < 0:
        raise ValueError("model is not a grasp scene (no body named 'object')")
    obj_geoms = tuple(int(i) for i in np.flatnonzero(model.geom_bodyid == body))
    free = jid("object_free")
    gripper = tuple(int(i) for i in np.flatnonzero(model.geom_group == GROUP_GRIPPER))
    palm = ("palm_x", "palm_y", "palm_z", "palm_yaw")
    return SceneIds(
        object_body=int(body),
        object_geoms=obj_geoms,
        object_qpos=int(model.jnt_qposadr[free]),
        object_dof=int(model.jnt_dofadr[free]),
        table_geom=gid("table"),
        pad_geoms=(gid("pad_a"), gid("pad_b")),
        gripper_geoms=gripper,
        palm_qpos=tuple(int(model.jnt_qposadr[jid(n)]) for n in palm),
        finger_qpos=tuple(
            int(model.jnt_qposadr[jid(n)]) for n in ("finger_a", "finger_b")
        ),
        palm_actuators=tuple(aid(n) for n in palm),
        finger_actuators=(aid("finger_a"), aid("finger_b")),
    )


def _random_quat(u: np.ndarray) -> np.ndarray:
    """Uniform random unit quaternion (w, x, y, z) from 3 uniforms (Shoemake)."""
    a, b, c = u
    q = np.array(
        [
            math.sqrt(1 - a) * math.sin(2 * math.pi * b),
            math.sqrt(1 - a) * math.cos(2 * math.pi * b),
            math.sqrt(a) * math.sin(2 * math.pi * c),
            math.sqrt(a) * math.cos(2 * math.pi * c),
        ]
    )
    return np.array([q[3], q[0], q[1], q[2]])


def _park_gripper(model: mujoco.MjModel, data: mujoco.MjData, ids: SceneIds) -> None:
    for adr, v in zip(ids.palm_qpos, (*PARK_POS, 0.0)):
        data.qpos[adr] = v
    half_open = float(
        model.jnt_range[model.actuator_trnid[ids.finger_actuators[0], 0], 1]
    )
    for adr in ids.finger_qpos:
        data.qpos[adr] = half_open
    data.ctrl[list(ids.palm_actuators)] = (*PARK_POS, 0.0)
    data.ctrl[list(ids.finger_actuators)] = half_open


def resting_pose(
    model: mujoco.MjModel, seed: int, xy_jitter: float = 0.02, max_steps: int = 600
) -> np.ndarray:
    """Drops the object from a random orientation and returns its resting pose.

    Random orientation (uniform on SO(3)), lowest point 5 mm above the table; simulated
    with native MuJoCo until the object's speed stays below 1 mm/s and 0.01 rad/s for
    0.1 s (at most ``max_steps`` steps); the final x, y are then moved to a random
    offset within ±``xy_jitter`` metres of the origin (a translation keeps it resting).

    Args:
      model: a scene from :func:`build_scene` (or ``scene_xml``).
      seed: int; the draws come from ``jax.random.key(seed)``.
      xy_jitter: half-range of the x, y offset, metres.
      max_steps: most physics steps.

    Returns:
      pose [7]: (x, y, z, qw, qx, qy, qz) of the object body in the world frame.

    Raises:
      ValueError: the object did not come to rest or left the table.
    """
    u = np.asarray(jax.random.uniform(jax.random.key(seed), (5,)), dtype=np.float64)
    return resting_pose_from_uniforms(model, u, xy_jitter, max_steps)


def resting_pose_from_uniforms(
    model: mujoco.MjModel, u: np.ndarray, xy_jitter: float = 0.02, max_steps: int = 600
) -> np.ndarray:
    """:func:`resting_pose` from its five uniforms ``u`` [5] (orientation, x/y offset):
    ``resting_pose(model, seed)`` is this with ``u = uniform(key(seed), (5,))``, so a batch
    of seeds can draw its uniforms in one call (``context``).

    The drop is stepped by ``mujoco.rollout`` in blocks (MuJoCo's C loop, GIL released, so
    threads settle poses on every core) and stops at the same step as the one-step-per-
    iteration loop it replaces, with the same state bit for bit (the same ``mj_step`` on
    the same state, controls and warm start; tests/grasp/test_context_threads.py). A block
    that ``rollout`` stopped early (a MuJoCo warning) is redone by that loop.
    """
    ids = scene_ids(model)
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    _park_gripper(model, data, ids)
    quat = _random_quat(u[:3])
    a = ids.object_qpos
    data.qpos[a : a + 3] = 0.0
    data.qpos[a + 3 : a + 7] = quat
    mujoco.mj_kinematics(model, data)
    lowest = _lowest_point(model, data, ids)
    data.qpos[a + 2] = -lowest + 0.005
    pose = _settle_in_blocks(model, data, ids, max_steps)
    if pose is None:
        pose = _settle_step_by_step(model, data, ids, max_steps)
    if not np.all(np.isfinite(pose)) or pose[2] < -0.01 or pose[2] > 0.2:
        raise ValueError(f"object did not settle on the table (pose {pose})")
    pose[:2] = (u[3:5] * 2 - 1) * xy_jitter
    pose[3:] /= np.linalg.norm(pose[3:])
    return pose


def _calm(v: np.ndarray):
    """The object's twist [..., 6] is below 1 mm/s and 0.01 rad/s."""
    return (np.abs(v[..., :3]).max(-1) < 1e-3) & (np.abs(v[..., 3:]).max(-1) < 1e-2)


def _settle_step_by_step(model, data, ids: SceneIds, max_steps: int) -> np.ndarray:
    """The settling loop, one ``mj_step`` per iteration (modifies ``data``)."""
    a = ids.object_qpos
    still = 0
    for _ in range(max_steps):
        mujoco.mj_step(model, data)
        v = data.qvel[ids.object_dof : ids.object_dof + 6]
        still = still + 1 if _calm(v) else 0
        if still * model.opt.timestep >= 0.1:
            break
    return data.qpos[a : a + 7].copy()


SETTLE_BLOCK = 128  # steps per rollout block while settling (most drops rest in < 128)


def _settle_in_blocks(model, data, ids: SceneIds, max_steps: int,
                      block: int | None = None) -> np.ndarray | None:
    """:func:`_settle_step_by_step` by ``mujoco.rollout`` blocks from ``data``'s state
    (``data`` is not modified); None when a block stopped early (MuJoCo warning)."""
    from mujoco import rollout as mj_rollout

    block = block or SETTLE_BLOCK
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    ctrl = data.ctrl.copy()[None, None]  # [1, 1, nu]: held every step
    warm = data.qacc_warmstart.copy()[None]
    work = mujoco.MjData(model)
    roll = mj_rollout.Rollout(nthread=0)
    a, dof, nq = ids.object_qpos, ids.object_dof, model.nq
    dt = model.opt.timestep
    still, done = 0, 0
    states = None
    while done < max_steps:
        n = min(block, max_steps - done)
        states, _ = roll.rollout(model, work, state[None], ctrl, nstep=n,
                                 initial_warmstart=warm)
        states = states[0]
        # rollout repeats the last state after a warning: time stops advancing
        ran = np.abs(np.diff(np.concatenate([state[:1], states[:, 0]])) - dt) < 0.5 * dt
        if not ran.all():
            return None
        calm = _calm(states[:, 1 + nq + dof : 1 + nq + dof + 6])
        for i, c in enumerate(calm.tolist()):
            still = still + 1 if c else 0
            if still * dt >= 0.1:
                return states[i, 1 + a : 1 + a + 7].copy()
        done += n
        state = states[-1].copy()
        warm = work.qacc_warmstart.copy()[None]
    return states[-1, 1 + a : 1 + a + 7].copy()


_GEOM_NAMES = {
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}


def _geom_local_points(model: mujoco.MjModel, g: int) -> np.ndarray:
    """``objects.geom_points`` of compiled geom ``g`` (its own frame)."""
    kind = _GEOM_NAMES.get(int(model.geom_type[g]))
    if kind is None:
        raise ValueError(f"geom {g} has type {model.geom_type[g]}, not one of {_GEOM_NAMES}")
    verts = None
    if kind == "mesh":
        m = model.geom_dataid[g]
        adr, num = model.mesh_vertadr[m], model.mesh_vertnum[m]
        verts = model.mesh_vert[adr : adr + num]
    return objects_lib.geom_points(kind, model.geom_size[g], verts)


def object_points(model: mujoco.MjModel, data: mujoco.MjData | None = None) -> np.ndarray:
    """World points of the object's geoms, ``[P, 3]`` (``objects.geom_points`` of each).

    Args:
      model: a grasp scene.
      data: its state after kinematics; None = :func:`initial_data` (qpos0's pose).

    Returns:
      float64 ``[P, 3]``: box corners, mesh vertices, low-poly sphere/capsule samples.
    """
    if data is None:
        data = initial_data(model)
    pts = []
    for g in scene_ids(model).object_geoms:
        pos, mat = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3)
        pts.append(_geom_local_points(model, g) @ mat.T + pos)
    return np.concatenate(pts)


def centred_grasp(
    model: mujoco.MjModel, pose: np.ndarray | None = None, num_angles: int = 72
) -> np.ndarray:
    """The grasp across the object's narrowest horizontal side, at its centre of mass.

    θ minimises the horizontal width of :func:`object_points` over ``num_angles`` angles
    in [-π/2, π/2); (x, y, z) is the object's centre of mass.

    Args:
      model: a grasp scene.
      pose: optional [7] object pose (default: the pose in ``model.qpos0``).
      num_angles: angles tried.

    Returns:
      grasp [4] = (x, y, z, θ), float64.
    """
    data = initial_data(model)
    if pose is not None:
        a = scene_ids(model).object_qpos
        data.qpos[a : a + 7] = np.asarray(pose, np.float64)
        mujoco.mj_kinematics(model, data)
    ids = scene_ids(model)
    pts = object_points(model, data)[:, :2]
    best = min(
        (float(np.ptp(pts @ [np.cos(t), np.sin(t)])), float(t))
        for t in np.linspace(-np.pi / 2, np.pi / 2, num_angles, endpoint=False)
    )
    centre = data.xipos[ids.object_body]
    return np.array([centre[0], centre[1], centre[2], best[1]])


def _lowest_point(model, data, ids: SceneIds) -> float:
    """Lowest world z of the object's geoms: the support function along -z (exact for
    boxes, spheres and capsules; the lowest vertex of ``objects.geom_points`` for meshes).
    Boxes keep the closed form rather than the min over corners: the two differ by one
    ulp, and a drop height one ulp off changes the simulated resting pose."""
    lowest = np.inf
    for g in ids.object_geoms:
        pos, mat = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3)
        t, size = model.geom_type[g], model.geom_size[g]
        if t == mujoco.mjtGeom.mjGEOM_SPHERE:
            z = pos[2] - size[0]
        elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            z = pos[2] - abs(mat[2, 2]) * size[1] - size[0]
        elif t == mujoco.mjtGeom.mjGEOM_BOX:
            z = pos[2] - np.abs(mat[2, :]) @ size
        else:  # mesh: its lowest vertex
            z = (_geom_local_points(model, g) @ mat.T + pos)[:, 2].min()
        lowest = min(lowest, float(z))
    return lowest


def build_scene(
    spec: objects_lib.ObjectSpec, seed: int = 0, config: SceneConfig = SceneConfig()
) -> mujoco.MjModel:
    """Builds the grasp scene with the object at a random resting pose.

    Args:
      spec: the object.
      seed: int; the resting pose is ``resting_pose(model, seed)``.
      config: physics and solver settings.

    Returns:
      a compiled ``mujoco.MjModel`` whose ``qpos0`` holds the object's resting pose
      (:func:`initial_data` also parks the gripper open at ``PARK_POS``). Use :func:`scene_ids` for indices and
      :func:`object_pose` for the pose.

    Raises:
      ValueError: the model does not compile or the object does not come to rest.
    """
    if not isinstance(spec, objects_lib.ObjectSpec):
        raise ValueError(f"spec must be an ObjectSpec, got {type(spec).__name__}")
    xml = scene_xml(spec, config)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as e:
        raise ValueError(f"object {spec.name!r} does not compile: {e}") from e
    pose = resting_pose(model, seed, config.xy_jitter, config.settle_steps)
    # Only the free joint's qpos0 changes: slide/hinge joints are measured from their
    # qpos0 in MuJoCo's kinematics, so the gripper joints keep qpos0 = 0.
    set_object_pose(model, pose)
    return model


def set_object_pose(model: mujoco.MjModel, pose: np.ndarray) -> None:
    """Stores ``pose`` [7] as the object's initial pose (``model.qpos0``), in place."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (7,) or not np.all(np.isfinite(pose)):
        raise ValueError(
            f"pose must be 7 finite numbers (x y z qw qx qy qz), got {pose}"
        )
    a = scene_ids(model).object_qpos
    model.qpos0[a : a + 7] = pose


def object_pose(model: mujoco.MjModel) -> np.ndarray:
    """The object's initial (resting) pose [7] = (x, y, z, qw, qx, qy, qz)."""
    a = scene_ids(model).object_qpos
    return model.qpos0[a : a + 7].copy()


def initial_data(model: mujoco.MjModel) -> mujoco.MjData:
    """``MjData`` at ``qpos0`` (object resting, gripper parked), forward-computed."""
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    ids = scene_ids(model)
    _park_gripper(model, data, ids)
    data.qpos[:] = model.qpos0
    mujoco.mj_forward(model, data)
    return data
