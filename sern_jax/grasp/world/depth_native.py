"""The depth camera on native MuJoCo: ``mj_multiRay`` on the CPU, no compile per object.

``depth.render`` (JAX/MJX) bakes each scene's geom types and convex-mesh planes into its
compiled program, so every new object costs a compile. Generating a data set over hundreds
of objects on a CPU would spend most of its time compiling. This module
casts the same rays (``depth.pixel_rays``: one ray per pixel, planar depth) through MuJoCo's
C ray caster instead, which needs no compile; it follows the same visibility rules (geom
groups, excluded body, transparent geoms), so both give the same image (tests compare them).
Sensor noise, when asked for, is the same jitted ``depth`` noise model, applied afterwards
(its program depends on the image shape only).
"""

from __future__ import annotations

import functools

import jax
import mujoco
import numpy as np

from sern_jax.grasp.world import depth as depth_lib

__all__ = ["render_native", "supports"]


def supports(config: depth_lib.CameraConfig) -> bool:
    """Whether ``render_native`` can reproduce ``depth.render`` for this camera config."""
    return len(config.bodyexclude) <= 1


def _rays(config: depth_lib.CameraConfig, params: depth_lib.CameraParams):
    """Ray directions [H*W*3] (float64, flat) and the camera position [3]."""
    rays = np.asarray(depth_lib.pixel_rays(config, params), np.float64).reshape(-1)
    return np.ascontiguousarray(rays), np.asarray(params.pos, np.float64)


@functools.lru_cache(maxsize=4)
def _noise_fn(config: depth_lib.CameraConfig):
    return jax.jit(jax.vmap(lambda k, p, d: depth_lib._noise(config, k, p, d), (0, None, 0)))


def render_native(
    config: depth_lib.CameraConfig,
    model: mujoco.MjModel,
    data: mujoco.MjData,
    params: depth_lib.CameraParams,
    qpos_object: np.ndarray,
    object_qpos_adr: int,
    keys: jax.Array | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth images of one scene with the object at each of P poses.

    Args:
      config: the camera config (``supports(config)`` must hold).
      model, data: the scene; ``data`` holds the rest of the state (gripper parked) and is
        modified (object pose, kinematics).
      params: the camera.
      qpos_object: [P, 7] object poses.
      object_qpos_adr: qpos address of the object's free joint.
      keys: optional [P] keys for sensor noise (None: noise-free).

    Returns:
      (depth [P, H, W] float32 planar depth, geom [P, H, W] int32 ids, -1 = no hit).
    """
    if not supports(config):
        raise ValueError("render_native supports at most one excluded body")
    vec, pnt = _rays(config, params)
    num = vec.size // 3
    group = np.asarray(config.geomgroup, np.uint8)
    body = config.bodyexclude[0] if config.bodyexclude else -1
    poses = np.asarray(qpos_object, np.float64)
    depth = np.empty((len(poses), num), np.float32)
    geom = np.empty((len(poses), num), np.int32)
    gid = np.empty(num, np.int32)
    dist = np.empty(num, np.float64)
    a = object_qpos_adr
    for i, pose in enumerate(poses):
        data.qpos[a : a + 7] = pose
        mujoco.mj_kinematics(model, data)
        mujoco.mj_multiRay(model, data, pnt, vec, group, 1, body, gid, dist, None, num,
                           config.far * 10.0)
        hit = gid >= 0
        depth[i] = np.where(hit, dist, config.far)
        geom[i] = np.where(hit, gid, -1)
    depth = depth.reshape((len(poses),) + config.shape)
    geom = geom.reshape((len(poses),) + config.shape)
    if keys is not None:
        noisy = np.asarray(_noise_fn(config)(keys, params, depth))
        depth = np.where(geom >= 0, noisy, depth).astype(np.float32)
    return depth, geom
