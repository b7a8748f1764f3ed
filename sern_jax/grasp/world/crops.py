"""Rotated depth crops around grasp candidates: the GQ-CNN 2.0 input, in JAX.

GQ-CNN (Dex-Net 2.0, ``GQCnnQualityFunction.grasps_to_tensors``; reference/grasp-anchors.md
§1.2) scales the 640x480 depth image by 1/3, translates the grasp centre to the image centre,
rotates by the grasp angle so that the jaw axis is horizontal, and keeps the central 32x32
pixels; the grasp depth goes to the network as a separate pose input. Our camera
(``depth.CameraConfig``: 96x96, fx = 175 = 525 / 3) already renders at GQ-CNN's 1/3 scale,
so one crop pixel is one image pixel (``CropConfig.scale = 1``).

Geometry. Crop pixel (row r, column c) of an S x S crop has local coordinates

    x = (c - (S - 1) / 2) * scale      (along the jaw axis)
    y = (r - (S - 1) / 2) * scale      (across it)

and samples the image at

    u = u0 + x cos(a) - y sin(a),      v = v0 + x sin(a) + y cos(a),

where (u0, v0) = ``center_px`` (column, row) and a = ``angle_px`` (jaw axis in the image,
from +u towards +v, as ``candidates`` defines it). So the jaw axis runs along the crop's
rows (horizontal), the grasp centre sits at the crop's centre (between its four middle
pixels, S even), and the crop is a rotation of the image by -a about the grasp centre.

Sampling is bilinear (one gather of the four neighbours per crop pixel, the same
arithmetic as ``scipy.ndimage.map_coordinates(order=1)``). Pixels outside the image take
the value of the nearest border pixel ("edge" mode, scipy's ``mode="nearest"``): with the
overhead camera the border sees the table, so off-image pixels read as table depth, not
as the camera's ``far`` value, and a grasp near the border does not see a fake cliff.

Values: ``image = depth - grasp_depth`` (metres; negative = nearer the camera than the grasp
centre, i.e. above it), the grasp depth itself in ``depth``: GQ-CNN's ``legacy_parallel_jaw``
pose input. Everything is pure and jit/vmap-able; ``extract`` handles one image,
``extract_batch`` a batch [B, H, W]. ``validate`` is the host-side check (shapes, NaN)
to call before compiling.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["CropConfig", "Crops", "extract", "extract_batch", "sample_grid", "validate"]


@dataclasses.dataclass(frozen=True)
class CropConfig:
    """Static crop settings.

    Attributes:
      crop_size: S, the crop is S x S pixels (GQ-CNN 2.0: 32).
      scale: image pixels per crop pixel (1.0 for our 1/3-scale camera; 3.0 would crop a
        full-resolution Primesense image the way GQ-CNN does, without its anti-aliasing).
      image_shape: (H, W) the crops expect, or None to accept any; checked at trace time.
    """

    crop_size: int = 32
    scale: float = 1.0
    image_shape: tuple[int, int] | None = None

    def __post_init__(self):
        if not isinstance(self.crop_size, (int, np.integer)) or self.crop_size < 1:
            raise ValueError(f"crop_size must be an int >= 1, got {self.crop_size!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be finite and > 0, got {self.scale!r}")
        if self.image_shape is not None:
            shape = tuple(self.image_shape)
            if len(shape) != 2 or min(shape) < 1:
                raise ValueError(
                    f"image_shape must be (H, W), got {self.image_shape!r}"
                )
            object.__setattr__(self, "image_shape", shape)


class Crops(NamedTuple):
    """Network inputs for K candidates (leading batch axes when batched)."""

    image: (
        jax.Array
    )  # [K, S, S] float32: depth - grasp_depth, metres, jaw axis along rows
    depth: (
        jax.Array
    )  # [K] float32: grasp depth (planar camera depth of the centre), metres


def _unpack(candidates):
    """(center_px, angle_px, grasp_depth) from a Candidates or a 3-tuple."""
    if hasattr(candidates, "center_px"):
        return candidates.center_px, candidates.angle_px, candidates.grasp_depth
    if isinstance(candidates, (tuple, list)) and len(candidates) == 3:
        return tuple(candidates)
    raise ValueError(
        "candidates must be a Candidates or a tuple (center_px [K, 2], angle_px [K], "
        f"grasp_depth [K]); got {type(candidates).__name__}"
    )


def _unpack_checked(depth, candidates, config, batch: bool):
    """``_unpack`` plus the trace-time shape check of ``extract`` / ``extract_batch``."""
    center, angle, gdepth = _unpack(candidates)
    _check_shapes(jnp.shape(depth), jnp.shape(center), jnp.shape(angle), jnp.shape(gdepth),
                  config, batch=batch)
    return center, angle, gdepth


def _check_shapes(depth_shape, center_shape, angle_shape, gdepth_shape, config, batch):
    lead = 1 if batch else 0
    what = "[B, H, W]" if batch else "[H, W]"
    if len(depth_shape) != 2 + lead:
        raise ValueError(f"depth image must be {what}, got shape {tuple(depth_shape)}")
    if min(depth_shape[-2:]) < 2:
        raise ValueError(f"depth image must be at least 2x2, got {tuple(depth_shape)}")
    if config.image_shape is not None and tuple(depth_shape[-2:]) != config.image_shape:
        raise ValueError(
            f"depth image shape {tuple(depth_shape[-2:])} does not match "
            f"CropConfig.image_shape {config.image_shape}"
        )
    b = tuple(depth_shape[:lead])
    if (
        len(center_shape) != lead + 2
        or tuple(center_shape[:lead]) != b
        or center_shape[-1] != 2
    ):
        raise ValueError(
            f"center_px must be {'[B, K, 2]' if batch else '[K, 2]'} matching the image "
            f"batch, got {tuple(center_shape)} for depth {tuple(depth_shape)}"
        )
    k = center_shape[lead]
    for name, shape in (("angle_px", angle_shape), ("grasp_depth", gdepth_shape)):
        if tuple(shape) != b + (k,):
            raise ValueError(
                f"{name} must have shape {b + (k,)} (from center_px), got {tuple(shape)}"
            )


def validate(depth, candidates, config: CropConfig = CropConfig(), batch: bool = False):
    """Host-side check of crop inputs; raises ValueError naming the bad value.

    Checks shapes (as ``extract`` does at trace time) and that the depth image and the
    candidates' centres, angles and depths are finite (NaN depth is an error, not a NaN
    crop). Call it once on concrete arrays before the jitted pipeline.

    Args:
      depth: [H, W] (or [B, H, W] with ``batch``) depth image(s), metres.
      candidates: a ``Candidates`` or (center_px [K, 2], angle_px [K], grasp_depth [K]),
        with a leading [B] when ``batch``.
      config: crop settings.
      batch: whether the inputs carry a leading batch axis.
    """
    center, angle, gdepth = _unpack(candidates)
    depth = np.asarray(depth)
    center, angle, gdepth = (np.asarray(a) for a in (center, angle, gdepth))
    _check_shapes(depth.shape, center.shape, angle.shape, gdepth.shape, config, batch)
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"depth image must be floating point, got dtype {depth.dtype}")
    bad = ~np.isfinite(depth)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"depth image has {int(bad.sum())} non-finite pixel(s), first at {idx}: "
            f"{depth[idx]!r}"
        )
    for name, value in (
        ("center_px", center),
        ("angle_px", angle),
        ("grasp_depth", gdepth),
    ):
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{name} has non-finite values")


def sample_grid(center_px, angle_px, config: CropConfig = CropConfig()):
    """Image coordinates each crop pixel samples.

    Args:
      center_px: [K, 2] grasp centres (u, v) = (column, row), pixels.
      angle_px: [K] jaw-axis angles in the image, radians, from +u towards +v.
      config: crop settings.

    Returns:
      (u, v): each [K, S, S] float32, column and row coordinates in the image.
    """
    s = config.crop_size
    offsets = (jnp.arange(s, dtype=jnp.float32) - (s - 1) / 2) * config.scale
    y, x = jnp.meshgrid(offsets, offsets, indexing="ij")  # [S, S] row, column offsets
    x, y = x[None], y[None]  # [1, S, S]
    cos = jnp.cos(angle_px)[:, None, None]
    sin = jnp.sin(angle_px)[:, None, None]
    u = center_px[:, 0, None, None] + x * cos - y * sin
    v = center_px[:, 1, None, None] + x * sin + y * cos
    return u, v


def _bilinear_edge(image, u, v):
    """Bilinear samples of image [H, W] at (u, v) (any equal shapes), edge mode."""
    height, width = image.shape
    u0 = jnp.floor(u)
    v0 = jnp.floor(v)
    fu = u - u0
    fv = v - v0
    u0 = u0.astype(jnp.int32)
    v0 = v0.astype(jnp.int32)
    flat = image.reshape(-1)

    def at(vi, ui):
        vi = jnp.clip(vi, 0, height - 1)
        ui = jnp.clip(ui, 0, width - 1)
        return jnp.take(flat, vi * width + ui, mode="clip")

    top = at(v0, u0) * (1 - fu) + at(v0, u0 + 1) * fu
    bottom = at(v0 + 1, u0) * (1 - fu) + at(v0 + 1, u0 + 1) * fu
    return top * (1 - fv) + bottom * fv


def extract(depth, candidates, config: CropConfig = CropConfig()) -> Crops:
    """Rotated, depth-relative crops for the K candidates of one image (pure).

    Shapes are checked at trace time; values (NaN) only by ``validate`` on the host.

    Args:
      depth: [H, W] planar depth image, metres.
      candidates: a ``candidates.Candidates`` or (center_px [K, 2] (u, v), angle_px [K]
        radians from +u towards +v, grasp_depth [K] metres).
      config: crop settings.

    Returns:
      Crops(image [K, S, S] = bilinear depth - grasp_depth with the jaw axis horizontal,
      depth [K] = grasp_depth), float32.
    """
    center, angle, gdepth = _unpack_checked(depth, candidates, config, batch=False)
    depth = jnp.asarray(depth, jnp.float32)
    center = jnp.asarray(center, jnp.float32)
    angle = jnp.asarray(angle, jnp.float32)
    gdepth = jnp.asarray(gdepth, jnp.float32)
    u, v = sample_grid(center, angle, config)
    patch = _bilinear_edge(depth, u, v)
    return Crops(image=patch - gdepth[:, None, None], depth=gdepth)


def extract_batch(depth, candidates, config: CropConfig = CropConfig()) -> Crops:
    """``extract`` vmapped over a batch of images.

    Args:
      depth: [B, H, W] depth images, metres.
      candidates: batched Candidates or (center_px [B, K, 2], angle_px [B, K],
        grasp_depth [B, K]).
      config: crop settings.

    Returns:
      Crops(image [B, K, S, S], depth [B, K]).
    """
    center, angle, gdepth = _unpack_checked(depth, candidates, config, batch=True)
    return jax.vmap(lambda d, c, a, g: extract(d, (c, a, g), config))(
        depth, center, angle, gdepth
    )
