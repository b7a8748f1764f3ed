"""Antipodal 4-DoF grasp candidates from a depth image, Dex-Net 2.0 style, fixed K.

Sampler (after gqcnn ``AntipodalDepthImageGraspSampler._sample_antipodal_grasps``, see
reference/grasp-anchors.md §1.3), with fixed shapes so that it jits and vmaps:

1. Gaussian-blur the depth image (``blur_sigma`` px); edge pixels are those whose blurred
   depth gradient exceeds ``grad_thresh`` metres per pixel (optionally inside ``mask``).
   Unlike Dex-Net we keep only the near side of a depth step (raw depth <= blurred depth),
   so that contacts lie on the object rather than on the table beside it.
2. The 2-D surface normal at an edge pixel is the normalised depth gradient; it points from
   the nearer surface (the object) to the farther one (the table): outwards.
3. Draw ``num_edge_samples`` edge pixels uniformly without replacement (Gumbel top-k).
4. Keep a pair (p1, p2) when the normals are opposite (n1 . n2 < -cos(arctan mu)), each
   normal lies within the friction cone around the line joining the contacts
   (n1 . (p1 - p2)/|p1 - p2| > cos(arctan mu), and the same for n2), and the contact
   width in metres is in [min_width, max_width].
5. Draw K of the kept pairs uniformly without replacement (Gumbel top-k over the pair
   matrix); slots beyond the number of kept pairs are invalid (``valid`` False, values 0).
6. Grasp depth: depth at the centre pixel plus U[depth_offset_min, depth_offset_max] along
   the optical axis (Dex-Net: 5 mm to 4 cm), then lifted if needed so that the grasp
   centre stays ``min_height`` above the table plane z = ``table_z``.

Grasp convention (what ``sim`` executes), all in the world frame:

* ``grasps[k] = (x, y, z, theta)``.
* (x, y): midpoint of the two contact points in the table plane, metres. Each contact is
  its edge pixel deprojected at that pixel's depth (a point on the object, within about
  two pixels of its silhouette).
* z: world height of the grasp centre, i.e. of the jaw-closing axis: the fingers' contact
  pads should be centred at this height when they close. metres.
* theta: angle of the jaw-closing axis (the line from one contact to the other) in the
  table plane, measured from world +x towards world +y, wrapped to [-pi/2, pi/2) (the jaw
  is symmetric, so theta and theta + pi are the same grasp).
* ``width``: distance between the two contacts in the table plane, metres (the gripper
  opens to its full opening before closing; width is information, not a command).

The camera must look (nearly) straight down for a top-down 4-DoF grasp to make sense; with
``depth.overhead_params`` it does exactly. ``endpoints`` are the contact pixels (u, v) for
drawing; ``center_px`` / ``angle_px`` / ``grasp_depth`` are the image-space grasp a
GQ-CNN-style crop needs (angle of the jaw axis in the image, from +u towards +v, and the
planar camera depth of the grasp centre).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.grasp.world import depth as depth_lib

__all__ = ["CandidateConfig", "Candidates", "sample", "make_sampler"]


@dataclasses.dataclass(frozen=True)
class CandidateConfig:
    """Static sampler settings.

    Attributes:
      num_candidates: K, the fixed number of grasp slots per image.
      num_edge_samples: edge pixels drawn per image; pairs are formed among these (N^2).
      blur_sigma: Gaussian blur before the gradient, pixels (Dex-Net: 1.0).
      grad_thresh: edge threshold on the blurred depth gradient, metres per pixel
        (Dex-Net: 0.0025 on its 2x-downsampled image).
      friction_coef: mu of the friction cone (Dex-Net: 0.8, half-angle 38.7 degrees).
      min_width: smallest contact width kept, metres.
      max_width: largest contact width kept, metres: the 8.5 cm opening less 5 mm clearance.
      depth_offset_min: smallest grasp depth below the centre surface, metres.
      depth_offset_max: largest grasp depth below the centre surface, metres.
      table_z: world height of the table plane, metres.
      min_height: lowest grasp-centre height above the table, metres; 2.2 cm = the
        scene's pad half-height (2 cm) + 2 mm, the same floor ``sim`` applies.
      boundary_margin: grasp centres closer than this to the border (pixels) are invalid.
    """

    num_candidates: int = 64
    num_edge_samples: int = 256
    blur_sigma: float = 1.0
    grad_thresh: float = 0.0025
    friction_coef: float = 0.8
    min_width: float = 0.0
    max_width: float = 0.08
    depth_offset_min: float = 0.005
    depth_offset_max: float = 0.04
    table_z: float = 0.0
    min_height: float = 0.022
    boundary_margin: int = 0

    def __post_init__(self):
        for name in ("num_candidates", "num_edge_samples"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(
                    f"CandidateConfig.{name} must be an int >= 1, got {value!r}"
                )
        if (
            self.num_candidates
            > self.num_edge_samples * (self.num_edge_samples - 1) // 2
        ):
            raise ValueError(
                f"num_candidates={self.num_candidates} exceeds the number of pairs of "
                f"num_edge_samples={self.num_edge_samples}"
            )
        if (
            not isinstance(self.boundary_margin, (int, np.integer))
            or self.boundary_margin < 0
        ):
            raise ValueError(
                f"boundary_margin must be an int >= 0, got {self.boundary_margin!r}"
            )
        for name in ("blur_sigma", "min_width", "depth_offset_min", "min_height"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(
                    f"CandidateConfig.{name} must be finite and >= 0, got {value!r}"
                )
        for name in ("grad_thresh", "friction_coef", "max_width"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(
                    f"CandidateConfig.{name} must be finite and > 0, got {value!r}"
                )
        if self.min_width > self.max_width:
            raise ValueError(f"min_width={self.min_width} > max_width={self.max_width}")
        if not self.depth_offset_min <= self.depth_offset_max:
            raise ValueError(
                f"depth_offset_min={self.depth_offset_min} > "
                f"depth_offset_max={self.depth_offset_max}"
            )
        if not math.isfinite(self.table_z):
            raise ValueError(f"table_z must be finite, got {self.table_z!r}")

    @property
    def cos_cone(self) -> float:
        """cos(arctan(mu)): the friction-cone threshold on unit-vector dot products."""
        return math.cos(math.atan(self.friction_coef))


class Candidates(NamedTuple):
    """K grasp candidates of one image (leading batch axes when batched)."""

    grasps: jax.Array  # [K, 4] (x, y, z, theta): world metres, radians in [-pi/2, pi/2)
    valid: jax.Array  # [K] bool; invalid slots hold zeros
    width: jax.Array  # [K] contact distance in the table plane, metres
    endpoints: (
        jax.Array
    )  # [K, 2, 2] the two contact pixels, each (u, v) = (column, row)
    center_px: jax.Array  # [K, 2] grasp centre pixel (u, v), float
    angle_px: jax.Array  # [K] jaw axis angle in the image, radians, from +u towards +v
    grasp_depth: jax.Array  # [K] planar camera depth of the grasp centre, metres


_NEAR_TOL = 1e-5  # metres; float32 slack of the near-side test on planar slopes


def _blur(image: jax.Array, sigma: float) -> jax.Array:
    """Separable Gaussian blur with edge padding (the image keeps its shape)."""
    if sigma <= 0:
        return image
    radius = max(1, int(math.ceil(3 * sigma)))
    x = np.arange(-radius, radius + 1, dtype=np.float32)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel = jnp.asarray(kernel / kernel.sum())
    padded = jnp.pad(image, radius, mode="edge")
    rows = jax.vmap(lambda r: jnp.convolve(r, kernel, mode="valid"))(padded)
    return jax.vmap(lambda c: jnp.convolve(c, kernel, mode="valid"), 1, 1)(rows)


def _wrap_half_pi(angle: jax.Array) -> jax.Array:
    """Wraps angles to [-pi/2, pi/2)."""
    return jnp.mod(angle + jnp.pi / 2, jnp.pi) - jnp.pi / 2


def _check_image(config_shape, depth, mask, batched: bool) -> None:
    want = 3 if batched else 2
    shape = tuple(np.shape(depth))
    if len(shape) != want:
        what = "[B, H, W]" if batched else "[H, W]"
        raise ValueError(f"depth image must be {what}, got shape {shape}")
    if min(shape[-2:]) < 3:
        raise ValueError(f"depth image must be at least 3x3, got shape {shape}")
    if config_shape is not None and shape[-2:] != tuple(config_shape):
        raise ValueError(
            f"depth image shape {shape[-2:]} does not match the sampler's {tuple(config_shape)}"
        )
    if not jnp.issubdtype(jnp.result_type(depth), jnp.floating):
        raise ValueError(
            f"depth image must be floating point, got dtype {jnp.result_type(depth)}"
        )
    if mask is not None and tuple(np.shape(mask)) != shape:
        raise ValueError(
            f"mask shape {tuple(np.shape(mask))} does not match depth shape {shape}"
        )


def sample(
    config: CandidateConfig,
    key: jax.Array,
    depth: jax.Array,
    params: depth_lib.CameraParams,
    mask: jax.Array | None = None,
) -> Candidates:
    """Samples K antipodal grasps from one depth image (pure; jit/vmap at the call site).

    Args:
      config: static sampler settings.
      key: PRNG key; consumed.
      depth: [H, W] planar depth image, metres (e.g. ``depth.render(...).depth``).
      params: the camera that took the image.
      mask: optional [H, W] bool; edges only where True (e.g. the object's pixels).

    Returns:
      Candidates with K = config.num_candidates slots.
    """
    _check_image(None, depth, mask, batched=False)
    height, width = depth.shape
    n = config.num_edge_samples
    key_edges, key_pairs, key_depth = jax.random.split(key, 3)
    del key
    depth = depth.astype(jnp.float32)

    # 1-2. edges and outward normals ([dv, du] = gradient along rows, columns).
    blurred = _blur(depth, config.blur_sigma)
    grad_v, grad_u = jnp.gradient(blurred)
    magnitude = jnp.sqrt(grad_u**2 + grad_v**2)
    # Near side only: at a depth step the blurred band straddles object and table; keep the
    # object's half (raw depth no farther than its blurred neighbourhood), so that contacts
    # lie on the object. On smooth slopes raw == blurred and both sides stay.
    edge = (magnitude > config.grad_thresh) & (depth <= blurred + _NEAR_TOL)
    if mask is not None:
        edge &= mask.astype(bool)

    # 3. N edge pixels uniformly without replacement.
    flat_edge = edge.reshape(-1)
    gumbel = jax.random.gumbel(key_edges, flat_edge.shape)
    _, pix = jax.lax.top_k(jnp.where(flat_edge, gumbel, -jnp.inf), n)  # [N]
    pix_ok = flat_edge[pix]  # [N]
    rows, cols = pix // width, pix % width
    uv = jnp.stack([cols, rows], axis=-1).astype(jnp.float32)  # [N, 2]
    normal = jnp.stack([grad_u.reshape(-1)[pix], grad_v.reshape(-1)[pix]], axis=-1)
    normal = normal / jnp.maximum(
        jnp.linalg.norm(normal, axis=-1, keepdims=True), 1e-12
    )

    contact = depth_lib.deproject(
        params, uv, depth.reshape(-1)[pix]
    )  # [N, 3] on the object

    # 4. pair tests on the N x N matrix (upper triangle: each unordered pair once).
    diff = uv[:, None, :] - uv[None, :, :]  # [N, N, 2] p_i - p_j
    dist_px = jnp.linalg.norm(diff, axis=-1)
    line = diff / jnp.maximum(dist_px, 1e-12)[..., None]
    cos_cone = config.cos_cone
    opposite = (normal @ normal.T) < -cos_cone
    cone_i = jnp.einsum("ic,ijc->ij", normal, line) > cos_cone
    cone_j = jnp.einsum("jc,ijc->ij", normal, -line) > cos_cone
    width_m = jnp.linalg.norm(contact[:, None, :2] - contact[None, :, :2], axis=-1)
    upper = np.triu(np.ones((n, n), dtype=bool), k=1)
    centre_uv = 0.5 * (uv[:, None, :] + uv[None, :, :])  # [N, N, 2]
    margin = config.boundary_margin
    inside = (
        (centre_uv[..., 0] >= margin)
        & (centre_uv[..., 0] <= width - 1 - margin)
        & (centre_uv[..., 1] >= margin)
        & (centre_uv[..., 1] <= height - 1 - margin)
    )
    keep = (
        upper
        & pix_ok[:, None]
        & pix_ok[None, :]
        & (dist_px > 0)
        & opposite
        & cone_i
        & cone_j
        & (width_m >= config.min_width)
        & (width_m <= config.max_width)
        & inside
    )

    # 5. K kept pairs uniformly without replacement.
    k = config.num_candidates
    flat_keep = keep.reshape(-1)
    gumbel = jax.random.gumbel(key_pairs, flat_keep.shape)
    _, pair = jax.lax.top_k(jnp.where(flat_keep, gumbel, -jnp.inf), k)  # [K]
    valid = flat_keep[pair]
    i, j = pair // n, pair % n

    # 6. the grasp itself.
    c1, c2 = contact[i], contact[j]  # [K, 3]
    centre_px = 0.5 * (uv[i] + uv[j])  # [K, 2]
    centre_pix = jnp.round(centre_px).astype(jnp.int32)
    centre_depth = depth[centre_pix[:, 1], centre_pix[:, 0]]
    offset = jax.random.uniform(
        key_depth, (k,), minval=config.depth_offset_min, maxval=config.depth_offset_max
    )
    grasp_point = depth_lib.deproject(
        params, centre_px, centre_depth + offset
    )  # [K, 3]
    xy = 0.5 * (c1[:, :2] + c2[:, :2])
    z = jnp.maximum(grasp_point[:, 2], config.table_z + config.min_height)
    axis = c2[:, :2] - c1[:, :2]
    theta = _wrap_half_pi(jnp.arctan2(axis[:, 1], axis[:, 0]))
    grasps = jnp.concatenate([xy, z[:, None], theta[:, None]], axis=-1)
    world_centre = jnp.concatenate([xy, z[:, None]], axis=-1)
    centre_uv_out, grasp_depth = depth_lib.project(params, world_centre)
    axis_px = uv[j] - uv[i]
    angle_px = jnp.arctan2(axis_px[:, 1], axis_px[:, 0])
    width_k = jnp.linalg.norm(axis, axis=-1)
    endpoints = jnp.stack([uv[i], uv[j]], axis=1)  # [K, 2, 2]

    def zero(x):
        return jnp.where(valid.reshape((k,) + (1,) * (x.ndim - 1)), x, 0).astype(
            x.dtype
        )

    return Candidates(
        grasps=zero(grasps),
        valid=valid,
        width=zero(width_k),
        endpoints=zero(endpoints),
        center_px=zero(centre_uv_out),
        angle_px=zero(angle_px),
        grasp_depth=zero(grasp_depth),
    )


def make_sampler(config: CandidateConfig, image_shape: tuple[int, int] | None = None):
    """A jitted sampler batched over images, with input checks before any compile.

    Args:
      config: static sampler settings.
      image_shape: optional (H, W) every image must have.

    Returns:
      fn(keys [B], depth [B, H, W], params, mask=None [B, H, W]) -> Candidates with leading
      axis B. ``params`` is one CameraParams shared by all images, or one with a leading
      batch axis B on every leaf.
    """
    shared = jax.jit(
        jax.vmap(lambda k, d, p, m: sample(config, k, d, p, m), (0, 0, None, 0))
    )
    per_image = jax.jit(
        jax.vmap(lambda k, d, p, m: sample(config, k, d, p, m), (0, 0, 0, 0))
    )
    shared_nomask = jax.jit(
        jax.vmap(lambda k, d, p: sample(config, k, d, p), (0, 0, None))
    )
    per_image_nomask = jax.jit(
        jax.vmap(lambda k, d, p: sample(config, k, d, p), (0, 0, 0))
    )

    def run(keys, depth, params, mask=None):
        _check_image(image_shape, depth, mask, batched=True)
        batch = np.shape(depth)[0]
        if tuple(np.shape(keys))[:1] != (batch,):
            raise ValueError(
                f"need one key per image: keys shape {np.shape(keys)}, "
                f"depth batch {batch}"
            )
        fx_ndim = np.ndim(params.fx)
        if fx_ndim not in (0, 1) or (fx_ndim == 1 and np.shape(params.fx)[0] != batch):
            raise ValueError(
                f"camera params must be shared or batched over {batch} images, "
                f"got fx shape {np.shape(params.fx)}"
            )
        if mask is None:
            fn = shared_nomask if fx_ndim == 0 else per_image_nomask
            return fn(keys, depth, params)
        fn = shared if fx_ndim == 0 else per_image
        return fn(keys, depth, params, mask)

    return run
