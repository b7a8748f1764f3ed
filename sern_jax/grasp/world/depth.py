"""Pinhole depth camera: one ``mjx.ray`` per pixel, vmapped, batched over scenes.

The camera follows the OpenCV pinhole convention. Camera axes, as columns of
``CameraParams.rot`` (camera-to-world rotation):

* x_c: image right (increasing column u),
* y_c: image down (increasing row v),
* z_c: optical axis (into the scene).

Pixel (row v, column u) sees the ray ``pos + t * rot @ [(u - cx)/fx, (v - cy)/fy, 1]``.
Because that direction has a unit z_c component, the ray parameter ``t`` at the hit is the
*planar* depth (distance along the optical axis), which is what Dex-Net/GQ-CNN call depth.
Pixel centres sit at integer (u, v), so ``cx = (width - 1) / 2`` centres the image.

The default overhead camera (``overhead_params``) looks straight down (z_c = -z_world) with
x_c = +x_world, hence y_c = -y_world: image right is world +x, image *up* is world +y.

Two known gaps of MJX's ray (mujoco-mjx 3.17.0, ``mjx/_src/ray.py``) are closed here:

* **Cylinders.** ``mjx.ray`` has no CYLINDER entry in ``_RAY_FUNC`` and silently sees
  through cylinder geoms. We intersect cylinder geoms ourselves with an exact analytic
  ray-cylinder test (round side + both flat caps, the same maths as MuJoCo's native
  ``mju_rayGeom``), apply the same filters as ``mjx.ray`` (geomgroup, bodyexclude,
  static, alpha) and keep the nearer of the two hits.
* **No materials.** ``mjx.ray`` evaluates ``m.mat_rgba[m.geom_matid, 3]``; with zero materials
  that gathers from an empty array and fails. When ``m.mat_rgba`` has no rows we give the
  model one opaque default material row. No geom references it (all ``geom_matid == -1``),
  so visibility is still decided by ``geom_rgba`` alone, exactly as in native MuJoCo.

``camera_model(mj_model)`` additionally switches every collision off in the copy it puts on
the device, so scenes whose physics MJX cannot collide (e.g. cylinder vs box) still render.

Rays that hit nothing get ``CameraConfig.far`` as depth and geom id -1.

Sensor noise (optional, keyed) follows Dex-Net 2.0's augmentation: a multiplicative gamma
factor per image (shape ``gamma_shape``, mean 1) and additive spatially correlated Gaussian
noise (i.i.d. N(0, gp_sigma^2) on a grid ``gp_scale`` times coarser, bilinearly upsampled).
``CameraConfig(noise_model="realsense")`` replaces it by a stereo-camera model like an Intel
RealSense D435's: Gaussian depth noise whose standard deviation grows with the square of the
range, σ(z) = rs_sigma0 + rs_sigma2 · z² (the stereo error law z² · subpixel / (focal ·
baseline); with the D435's 50 mm baseline, a ~450 px focal length at 848 × 480 and 0.08
subpixel, about 1.3 mm at 0.6 m), and missing pixels ("holes": rate ``rs_dropout``, and
``rs_edge_dropout`` next to depth jumps larger than ``rs_edge_jump``, where stereo matching
fails in occlusion shadows). A robot's pipeline fills holes before use; so does the model
(``inpaint``: each missing pixel takes the mean of its valid 3 × 3 neighbours, repeated
``rs_inpaint_steps`` times; what is still missing takes the image's farthest valid depth).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from sern_jax.grasp.world._mjx import mjx

__all__ = [
    "CameraConfig",
    "CameraParams",
    "GeomPoses",
    "DepthImage",
    "geom_poses",
    "overhead_params",
    "camera_model",
    "ensure_material",
    "pixel_rays",
    "deproject",
    "project",
    "render",
    "make_renderer",
    "inpaint",
    "NOISE_MODELS",
]

NOISE_MODELS = ("dexnet", "realsense")
_CYLINDER = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
_MESH = int(mujoco.mjtGeom.mjGEOM_MESH)


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Static camera settings (anything that changes compiled code, plus defaults).

    Attributes:
        height: image rows H.
        width: image columns W.
        fx: default focal length in pixels along u (becomes a traced param).
        fy: default focal length in pixels along v.
        cx: default principal point column; None = (width - 1) / 2.
        cy: default principal point row; None = (height - 1) / 2.
        distance: default camera height above the target point, metres.
        far: depth reported for rays that hit nothing, metres.
        geomgroup: MuJoCo geom-group mask (6 ints, 1 = visible); () = all groups visible.
            The default hides group 3, where ``scene`` puts the gripper.
        bodyexclude: body ids whose geoms the camera ignores (e.g. the gripper's bodies).
        gamma_shape: default shape of the multiplicative gamma noise (Dex-Net: 1000).
        gp_sigma: default std of the correlated additive noise, metres (Dex-Net: 0.005).
        gp_scale: the correlated noise lives on a grid this many times coarser than the image.
        fast_convex_mesh: intersect convex mesh geoms as polyhedra (face half-spaces)
            instead of mjx.ray's triangle-by-triangle test; same surface, much faster.
        noise_model: ``"dexnet"`` (gamma gain + correlated field, above) or
            ``"realsense"`` (range-dependent Gaussian noise + missing pixels, inpainted).
        rs_sigma0, rs_sigma2: RealSense-like noise σ(z) = rs_sigma0 + rs_sigma2 · z², metres.
        rs_dropout: probability that a pixel is missing.
        rs_edge_dropout: probability that a pixel beside a depth jump is missing.
        rs_edge_jump: depth difference to a 4-neighbour that marks a jump, metres.
        rs_inpaint_steps: 3 × 3 fill passes over missing pixels.
    """

    height: int = 96
    width: int = 96
    fx: float = 175.0
    fy: float = 175.0
    cx: float | None = None
    cy: float | None = None
    distance: float = 0.6
    far: float = 2.0
    geomgroup: tuple[int, ...] = (1, 1, 1, 0, 1, 1)
    bodyexclude: tuple[int, ...] = ()
    gamma_shape: float = 1000.0
    gp_sigma: float = 0.005
    gp_scale: int = 4
    fast_convex_mesh: bool = True
    noise_model: str = "dexnet"
    rs_sigma0: float = 0.0002
    rs_sigma2: float = 0.0036
    rs_dropout: float = 0.01
    rs_edge_dropout: float = 0.3
    rs_edge_jump: float = 0.01
    rs_inpaint_steps: int = 6

    def __post_init__(self):
        if self.noise_model not in NOISE_MODELS:
            raise ValueError(
                f"CameraConfig.noise_model must be one of {NOISE_MODELS}, "
                f"got {self.noise_model!r}"
            )
        if (
            self.rs_sigma0 < 0
            or self.rs_sigma2 < 0
            or not 0 <= self.rs_dropout <= 1
            or not 0 <= self.rs_edge_dropout <= 1
            or self.rs_edge_jump <= 0
            or self.rs_inpaint_steps < 0
        ):
            raise ValueError(
                "RealSense noise settings need sigmas >= 0, dropout rates in [0, 1], "
                "rs_edge_jump > 0 and rs_inpaint_steps >= 0"
            )
        for name in ("height", "width", "gp_scale"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(
                    f"CameraConfig.{name} must be a positive int, got {value!r}"
                )
        for name in ("fx", "fy", "distance", "far"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(
                    f"CameraConfig.{name} must be finite and > 0, got {value!r}"
                )
        if self.gamma_shape < 0 or self.gp_sigma < 0:
            raise ValueError(
                f"noise settings must be >= 0, got gamma_shape={self.gamma_shape!r}, "
                f"gp_sigma={self.gp_sigma!r}"
            )
        if self.geomgroup and len(self.geomgroup) != mujoco.mjNGROUP:
            raise ValueError(
                f"CameraConfig.geomgroup needs {mujoco.mjNGROUP} entries or none, "
                f"got {self.geomgroup!r}"
            )

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def principal_point(self) -> tuple[float, float]:
        cx = (self.width - 1) / 2 if self.cx is None else self.cx
        cy = (self.height - 1) / 2 if self.cy is None else self.cy
        return cx, cy


class CameraParams(NamedTuple):
    """Traced camera parameters (vmap them to sweep intrinsics or poses)."""

    fx: jax.Array  # [] focal length along u, pixels
    fy: jax.Array  # [] focal length along v, pixels
    cx: jax.Array  # [] principal point column
    cy: jax.Array  # [] principal point row
    pos: jax.Array  # [3] camera centre, world frame, metres
    rot: (
        jax.Array
    )  # [3, 3] camera-to-world; columns x_c (right), y_c (down), z_c (axis)
    gamma_shape: jax.Array  # [] multiplicative gamma noise shape; 0 disables it
    gp_sigma: jax.Array  # [] correlated additive noise std, metres; 0 disables it


class GeomPoses(NamedTuple):
    """The part of mjx.Data a camera reads; an mjx.Data works in its place too."""

    geom_xpos: jax.Array  # [ngeom, 3] geom positions, world frame
    geom_xmat: jax.Array  # [ngeom, 3, 3] geom orientations, world frame


def geom_poses(mj_data: mujoco.MjData) -> GeomPoses:
    """Geom poses of a native MjData (call mj_forward/mj_kinematics first)."""
    xmat = np.asarray(mj_data.geom_xmat, dtype=np.float32).reshape(-1, 3, 3)
    return GeomPoses(
        geom_xpos=jnp.asarray(mj_data.geom_xpos, dtype=jnp.float32),
        geom_xmat=jnp.asarray(xmat),
    )


class DepthImage(NamedTuple):
    """A rendered depth image."""

    depth: jax.Array  # [H, W] float32 planar depth along the optical axis, metres
    geom: jax.Array  # [H, W] int32 id of the geom each pixel sees, -1 for none


# Looking straight down: x_c = +x_w, y_c = -y_w, z_c = -z_w.
_OVERHEAD_ROT = np.array(
    [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], dtype=np.float32
)


def overhead_params(config: CameraConfig, target=(0.0, 0.0, 0.0)) -> CameraParams:
    """Camera `config.distance` straight above `target`, image right = world +x.

    Args:
        config: camera config (intrinsics and noise defaults).
        target: [3] world point the optical axis passes through.

    Returns:
        CameraParams with float32 leaves.
    """
    target = np.asarray(target, dtype=np.float32)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target must be 3 finite numbers, got {target!r}")
    cx, cy = config.principal_point

    def f32(v):
        return jnp.asarray(v, dtype=jnp.float32)

    return CameraParams(
        fx=f32(config.fx),
        fy=f32(config.fy),
        cx=f32(cx),
        cy=f32(cy),
        pos=f32(target + np.array([0.0, 0.0, config.distance], np.float32)),
        rot=f32(_OVERHEAD_ROT),
        gamma_shape=f32(config.gamma_shape),
        gp_sigma=f32(config.gp_sigma),
    )


def camera_model(mj_model: mujoco.MjModel) -> mjx.Model:
    """Puts a copy of `mj_model` on the device for rendering only.

    Collisions are switched off in the copy (the camera never collides), so a scene whose
    geoms MJX cannot collide (cylinders against boxes, say) still renders; a model without
    materials gets one default material row (see the module docstring).

    Args:
        mj_model: the scene.

    Returns:
        An mjx.Model to pass to `render`.
    """
    if not isinstance(mj_model, mujoco.MjModel):
        raise ValueError(
            f"camera_model needs a mujoco.MjModel, got {type(mj_model).__name__}"
        )
    model = copy.copy(mj_model)
    model.geom_contype[:] = 0
    model.geom_conaffinity[:] = 0
    try:
        m = mjx.put_model(model)
    except NotImplementedError as e:  # explicit <contact><pair>s survive the switch-off
        raise ValueError(
            f"camera_model: MJX cannot take this model ({e}); "
            f"explicit contact pairs: {model.npair}"
        ) from e
    return ensure_material(m)


def ensure_material(m: mjx.Model) -> mjx.Model:
    """Adds one opaque default material row when `m` has none (mjx.ray needs one)."""
    if m.mat_rgba.shape[0] == 0:
        m = m.replace(mat_rgba=jnp.ones((1, 4), dtype=jnp.float32))
    return m


def pixel_rays(config: CameraConfig, params: CameraParams) -> jax.Array:
    """World-frame ray directions with unit optical-axis component.

    Returns:
        [H, W, 3] directions; pos + t * dir is the point at planar depth t.
    """
    v, u = jnp.meshgrid(
        jnp.arange(config.height, dtype=jnp.float32),
        jnp.arange(config.width, dtype=jnp.float32),
        indexing="ij",
    )
    cam = jnp.stack(
        [(u - params.cx) / params.fx, (v - params.cy) / params.fy, jnp.ones_like(u)],
        axis=-1,
    )  # [H, W, 3]
    return cam @ params.rot.T


def deproject(params: CameraParams, uv: jax.Array, depth: jax.Array) -> jax.Array:
    """World points at pixel coordinates `uv` and planar depth `depth`.

    Args:
        params: camera params.
        uv: [..., 2] (column u, row v), float pixels.
        depth: [...] planar depth, metres.

    Returns:
        [..., 3] world points.
    """
    cam = jnp.stack(
        [
            (uv[..., 0] - params.cx) / params.fx,
            (uv[..., 1] - params.cy) / params.fy,
            jnp.ones_like(uv[..., 0]),
        ],
        axis=-1,
    )
    pos = params.pos.reshape((1,) * (cam.ndim - 1) + (3,))
    return pos + depth[..., None] * (cam @ params.rot.T)


def project(params: CameraParams, points: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Pixel coordinates and planar depth of world points.

    Args:
        params: camera params.
        points: [..., 3] world points.

    Returns:
        (uv [..., 2] as (column, row), depth [...]).
    """
    pos = params.pos.reshape((1,) * (points.ndim - 1) + (3,))
    cam = (points - pos) @ params.rot  # [..., 3] camera frame
    z = cam[..., 2]
    uv = jnp.stack(
        [
            params.fx * cam[..., 0] / z + params.cx,
            params.fy * cam[..., 1] / z + params.cy,
        ],
        axis=-1,
    )
    return uv, z


def _geom_filter(m: mjx.Model, config: CameraConfig) -> np.ndarray:
    """Static per-geom mask, the same rules as mjx.ray (flg_static=True)."""
    keep = np.ones(m.ngeom, dtype=bool)
    for body in config.bodyexclude:
        keep &= np.asarray(m.geom_bodyid) != body
    if config.geomgroup:
        group = np.asarray(config.geomgroup, dtype=bool)
        keep &= group[np.clip(np.asarray(m.geom_group), 0, mujoco.mjNGROUP - 1)]
    return keep


def _ray_cylinder(size: jax.Array, pnt: jax.Array, vec: jax.Array) -> jax.Array:
    """Ray parameter of the first hit with a z-aligned cylinder, inf for none (local frame).

    Args:
        size: [>=2] radius, half-height.
        pnt: [3] ray origin in the cylinder frame.
        vec: [3] ray direction in the cylinder frame (any length).

    Returns:
        [] smallest t >= 0 with pnt + t vec on the surface, or inf.
    """
    radius, half = size[0], size[1]
    # Round side: |(pnt + t vec)_xy|^2 = r^2, i.e. a t^2 + 2 b t + c = 0.
    a = vec[0] * vec[0] + vec[1] * vec[1]
    b = vec[0] * pnt[0] + vec[1] * pnt[1]
    c = pnt[0] * pnt[0] + pnt[1] * pnt[1] - radius * radius
    det = b * b - a * c
    safe_a = jnp.where(a > mujoco.mjMINVAL, a, 1.0)
    sq = jnp.sqrt(jnp.maximum(det, 0.0))
    ok = (a > mujoco.mjMINVAL) & (det >= mujoco.mjMINVAL)
    side = jnp.inf
    for root in ((-b - sq) / safe_a, (-b + sq) / safe_a):
        z = pnt[2] + root * vec[2]
        good = ok & (root >= 0) & (jnp.abs(z) <= half)
        side = jnp.minimum(side, jnp.where(good, root, jnp.inf))
    # Flat caps z = +-half.
    safe_vz = jnp.where(jnp.abs(vec[2]) > mujoco.mjMINVAL, vec[2], 1.0)
    best = side
    for cap in (half, -half):
        t = (cap - pnt[2]) / safe_vz
        x, y = pnt[0] + t * vec[0], pnt[1] + t * vec[1]
        good = (jnp.abs(vec[2]) > mujoco.mjMINVAL) & (t >= 0)
        good &= x * x + y * y <= radius * radius
        best = jnp.minimum(best, jnp.where(good, t, jnp.inf))
    return best


def _convex_planes(m: mjx.Model, geom: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Face planes (n . x <= d, outward unit n) of a mesh geom, or None if not convex.

    Runs on the host at trace time. Coplanar triangles share one plane.
    """
    mesh = int(np.asarray(m.geom_dataid)[geom])
    vertadr = np.append(np.asarray(m.mesh_vertadr), np.asarray(m.mesh_vert).shape[0])
    faceadr = np.append(np.asarray(m.mesh_faceadr), np.asarray(m.mesh_face).shape[0])
    vert = np.asarray(m.mesh_vert, np.float64)[vertadr[mesh] : vertadr[mesh + 1]]
    face = np.asarray(m.mesh_face)[faceadr[mesh] : faceadr[mesh + 1]]
    if len(face) < 4:
        return None
    tri = vert[face]  # [F, 3, 3]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-14
    normal = normal[ok] / norm[ok, None]
    offset = np.einsum("fi,fi->f", normal, tri[ok, 0])
    flip = normal @ vert.mean(axis=0) > offset  # orient outwards (centroid inside)
    normal[flip], offset[flip] = -normal[flip], -offset[flip]
    scale = float(np.ptp(vert, axis=0).max())
    if np.any(vert @ normal.T - offset > 1e-6 * scale):
        return None  # some vertex outside some face plane: not convex
    planes = np.unique(np.round(np.c_[normal, offset / scale], 7), axis=0)
    return planes[:, :3], planes[:, 3] * scale


def _ray_convex(
    normal: jax.Array, offset: jax.Array, pnt: jax.Array, vec: jax.Array
) -> jax.Array:
    """Ray parameter of the first hit with a convex polyhedron {x: n . x <= d}, or inf.

    Args:
      normal: [F, 3] outward unit face normals (all-zero rows are padding).
      offset: [F] plane offsets (1 for padding rows).
      pnt: [3] ray origin, polyhedron frame.
      vec: [3] ray direction, polyhedron frame.

    Returns:
      [] entry parameter (exit parameter if the origin is inside), inf for a miss.
    """
    denom = normal @ vec  # [F]
    num = offset - normal @ pnt  # [F], >= 0 where the origin is inside that plane
    entering = denom < -mujoco.mjMINVAL
    exiting = denom > mujoco.mjMINVAL
    t = num / jnp.where(entering | exiting, denom, 1.0)
    t_enter = jnp.max(jnp.where(entering, t, -jnp.inf))
    t_exit = jnp.min(jnp.where(exiting, t, jnp.inf))
    parallel_outside = jnp.any(~entering & ~exiting & (num < 0))
    hit = (t_enter <= t_exit) & (t_exit >= 0) & ~parallel_outside
    return jnp.where(hit, jnp.where(t_enter >= 0, t_enter, t_exit), jnp.inf)


def _visible(m: mjx.Model, ids: np.ndarray) -> jax.Array:
    """Visibility as in mjx.ray and native mj_ray: a geom with a material is hidden when
    the material's alpha is 0, one without when its own rgba alpha is 0."""
    matid = m.geom_matid[ids]
    return jnp.where(
        matid >= 0, m.mat_rgba[jnp.maximum(matid, 0), 3] != 0, m.geom_rgba[ids, 3] != 0
    )


def _local(d, ids: np.ndarray, pnt: jax.Array, vec: jax.Array):
    """The ray in the frames of geoms `ids`: ([G, 3], [G, 3])."""
    xmat, xpos = d.geom_xmat[ids], d.geom_xpos[ids]  # [G, 3, 3], [G, 3]
    lpnt = jnp.einsum("gji,gj->gi", xmat, pnt[None, :] - xpos)
    lvec = jnp.einsum("gji,j->gi", xmat, vec)
    return lpnt, lvec


def _cast(
    config: CameraConfig,
    m: mjx.Model,
    d: mjx.Data | GeomPoses,
    pnt: jax.Array,
    vec: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """One ray: our cylinder and convex-mesh tests, mjx.ray for every other geom."""
    keep = _geom_filter(m, config)
    gtype = np.asarray(m.geom_type)
    cyl = np.nonzero(keep & (gtype == _CYLINDER))[0]
    convex, planes = [], []
    if config.fast_convex_mesh:
        for g in np.nonzero(keep & (gtype == _MESH))[0]:
            hull = _convex_planes(m, g)
            if hull is not None:
                convex.append(g)
                planes.append(hull)
    convex = np.asarray(convex, dtype=np.int64)
    by_mjx = keep.copy()
    by_mjx[cyl] = False
    by_mjx[convex] = False

    hits, ids = [], []
    if by_mjx.any():
        # The filter is already decided above: hand mjx.ray a model whose geom groups say
        # "cast" (0) or "skip" (5). Its mesh path broadcasts implicitly ([3, 3] - [3]).
        m_ray = m.replace(geom_group=np.where(by_mjx, 0, 5).astype(np.int32))
        with jax.numpy_rank_promotion("allow"):
            dist, geom = mjx.ray(m_ray, d, pnt, vec, geomgroup=(1, 1, 1, 1, 1, 0))
        hits.append(jnp.where(geom < 0, jnp.inf, dist)[None])
        ids.append(geom.astype(jnp.int32)[None])
    if cyl.size:
        lpnt, lvec = _local(d, cyl, pnt, vec)
        t = jax.vmap(_ray_cylinder)(m.geom_size[cyl], lpnt, lvec)  # [C]
        hits.append(jnp.where(_visible(m, cyl), t, jnp.inf))
        ids.append(jnp.asarray(cyl, dtype=jnp.int32))
    if convex.size:
        most = max(len(n) for n, _ in planes)
        normal = np.zeros((len(convex), most, 3), np.float32)
        offset = np.ones((len(convex), most), np.float32)
        for i, (n, o) in enumerate(planes):
            normal[i, : len(n)], offset[i, : len(o)] = n, o
        lpnt, lvec = _local(d, convex, pnt, vec)
        t = jax.vmap(_ray_convex)(jnp.asarray(normal), jnp.asarray(offset), lpnt, lvec)
        hits.append(jnp.where(_visible(m, convex), t, jnp.inf))
        ids.append(jnp.asarray(convex, dtype=jnp.int32))
    if not hits:
        return jnp.array(jnp.inf), jnp.array(-1, dtype=jnp.int32)
    hits, ids = jnp.concatenate(hits), jnp.concatenate(ids)
    best = jnp.argmin(hits)
    return hits[best], jnp.where(jnp.isfinite(hits[best]), ids[best], -1)


def _box3(x: jax.Array) -> jax.Array:
    """Sum over each pixel's 3 × 3 neighbourhood (zero padding) of a [H, W] array."""
    p = jnp.pad(x, 1)
    h, w = x.shape
    return sum(p[i : i + h, j : j + w] for i in range(3) for j in range(3))


def inpaint(depth: jax.Array, missing: jax.Array, steps: int) -> jax.Array:
    """Fills missing pixels of a [H, W] depth image: ``steps`` passes in which each missing
    pixel with a valid 3 × 3 neighbour takes their mean; pixels still missing after that
    take the image's farthest valid depth (the background). Pure; static ``steps``."""
    valid = ~missing
    for _ in range(steps):
        num = _box3(jnp.where(valid, depth, 0.0))
        cnt = _box3(valid.astype(depth.dtype))
        fill = (~valid) & (cnt > 0)
        depth = jnp.where(fill, num / jnp.maximum(cnt, 1.0), depth)
        valid = valid | fill
    background = jnp.max(jnp.where(valid, depth, -jnp.inf))
    return jnp.where(valid, depth, background)


def _noise_realsense(
    config: CameraConfig, key: jax.Array, depth: jax.Array
) -> jax.Array:
    """RealSense-like noise on a [H, W] depth image (module doc); key is consumed."""
    key_gauss, key_drop = jax.random.split(key)
    sigma = config.rs_sigma0 + config.rs_sigma2 * depth**2
    noisy = depth + sigma * jax.random.normal(key_gauss, depth.shape, dtype=depth.dtype)
    p = jnp.pad(depth, 1, mode="edge")
    h, w = depth.shape
    jump = jnp.max(
        jnp.stack(
            [
                jnp.abs(p[1 : h + 1, 1 : w + 1] - p[i : i + h, j : j + w])
                for i, j in ((0, 1), (2, 1), (1, 0), (1, 2))
            ]
        ),
        axis=0,
    )
    rate = jnp.where(jump > config.rs_edge_jump, config.rs_edge_dropout, config.rs_dropout)
    missing = jax.random.uniform(key_drop, depth.shape) < rate
    return inpaint(noisy, missing, config.rs_inpaint_steps)


def _noise(
    config: CameraConfig, key: jax.Array, params: CameraParams, depth: jax.Array
) -> jax.Array:
    """Sensor noise on a [H, W] depth image (``config.noise_model``); key is consumed."""
    if config.noise_model == "realsense":
        return _noise_realsense(config, key, depth)
    key_gamma, key_gp = jax.random.split(key)
    shape = params.gamma_shape
    safe_shape = jnp.where(shape > 0, shape, 1.0)
    gamma = jax.random.gamma(key_gamma, safe_shape) / safe_shape
    gain = jnp.where(shape > 0, gamma, 1.0)
    coarse = (
        math.ceil(config.height / config.gp_scale),
        math.ceil(config.width / config.gp_scale),
    )
    field = jax.random.normal(key_gp, coarse, dtype=jnp.float32)
    field = jax.image.resize(field, config.shape, method="bilinear")
    return depth * gain + params.gp_sigma * field


def render(
    config: CameraConfig,
    m: mjx.Model,
    d: mjx.Data | GeomPoses,
    params: CameraParams,
    key: jax.Array | None = None,
) -> DepthImage:
    """Renders one depth image (jit and vmap it; see `make_renderer`).

    Args:
        config: static camera config.
        m: mjx.Model of the scene (`camera_model` gives a render-only one); geom sizes may be
            batched by the caller's vmap.
        d: mjx.Data after kinematics, or GeomPoses (only `geom_xpos`, `geom_xmat` are read).
        params: camera params.
        key: optional PRNG key for sensor noise; consumed. None = noise-free. (The one
            function of the package whose key is not its first traced argument: it is
            optional, and noise-free callers pass none.)

    Returns:
        DepthImage with depth [H, W] and geom ids [H, W].
    """
    m = ensure_material(m)
    rays = pixel_rays(config, params).reshape(-1, 3)  # [H*W, 3]
    dist, geom = jax.vmap(lambda vec: _cast(config, m, d, params.pos, vec))(rays)
    hit = jnp.isfinite(dist)
    depth = jnp.where(hit, dist, config.far).reshape(config.shape).astype(jnp.float32)
    geom = jnp.where(hit, geom, -1).reshape(config.shape)
    if key is not None:
        depth = jnp.where(geom >= 0, _noise(config, key, params, depth), depth)
    return DepthImage(depth=depth, geom=geom)


def make_renderer(config: CameraConfig, noise: bool = False):
    """A jitted renderer batched over scenes.

    Args:
        config: static camera config.
        noise: whether the returned function takes keys and adds sensor noise.

    Returns:
        fn(m, d, params) -> DepthImage with leaves [B, H, W], or with ``noise``
        fn(keys, m, d, params) (keys first, as everywhere in the package); `d`, `params`
        (and keys) carry a leading batch axis B, `m` is shared. To batch primitive sizes as
        well, vmap `render` yourself with an in_axes tree for `m`.
    """
    if noise:
        batched = jax.vmap(
            lambda k, m, d, p: render(config, m, d, p, k), (0, None, 0, 0)
        )
    else:
        batched = jax.vmap(lambda m, d, p: render(config, m, d, p), (None, 0, 0))
    return jax.jit(batched)
