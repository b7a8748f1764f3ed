"""Tests for sern_jax.grasp.world.crops: geometry, scipy parity on real images, batching, bad input."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from sern_jax.grasp.world import candidates as cd
from sern_jax.grasp.world import crops
from sern_jax.grasp.world import depth as dp

_CAMERA = dp.CameraConfig()  # 96 x 96 at GQ-CNN's 1/3 scale
_CONFIG = crops.CropConfig()
_S = _CONFIG.crop_size
# Parity tolerance against scipy (float64 coordinates) for float32 bilinear sampling of
# depths ~0.6 m: coordinate rounding (~1e-5 px) times depth steps (~0.05 m/px) plus float32
# rounding of the depth values: well under 1e-5 m.
_ATOL = 1e-5


@pytest.fixture(scope="module")
def real_images():
    """Two rendered scenes (small box, T shape) with their 64 sampled candidates each."""
    from sern_jax.grasp.world import objects, scene

    params = dp.overhead_params(_CAMERA)
    render = jax.jit(lambda m, d, p: dp.render(_CAMERA, m, d, p))
    sample = jax.jit(lambda k, d, p: cd.sample(cd.CandidateConfig(), k, d, p))
    images, cands = [], []
    for i, name in enumerate(("small_box", "t_shape")):
        model = scene.build_scene(objects.make_object(name), seed=i)
        data = scene.initial_data(model)
        image = render(dp.camera_model(model), dp.geom_poses(data), params).depth
        cands.append(sample(jax.random.key(i), image, params))
        images.append(np.asarray(image))
    return np.stack(images), jax.tree.map(lambda *x: np.stack(x), *cands)


def _scipy_affine(image, center, angle, size=_S):
    """Reference: one scipy affine_transform per crop (float64, order 1, edge mode)."""
    cos, sin = math.cos(angle), math.sin(angle)
    half = (size - 1) / 2
    # input (row, col) = M @ (r, c) + offset; row = v0 + x sin + y cos, col = u0 + x cos - y sin
    matrix = np.array([[cos, sin], [-sin, cos]])
    offset = np.array([center[1], center[0]]) - matrix @ np.array([half, half])
    return ndimage.affine_transform(
        image.astype(np.float64),
        matrix,
        offset,
        output_shape=(size, size),
        order=1,
        mode="nearest",
    )


def _scipy_rotate(image, center, angle, size=_S):
    """Reference: edge-padded window around a half-integer centre, ndimage.rotate, crop.

    The window is 2*size pixels wide with the grasp centre at its array centre, so a
    single bilinear ndimage.rotate about the array centre followed by a central crop is
    the GQ-CNN recipe (translate, rotate, crop) with one interpolation.
    """
    n = 2 * size
    u0, v0 = center
    top, left = round(v0 - (n - 1) / 2), round(u0 - (n - 1) / 2)
    padded = np.pad(image.astype(np.float64), n, mode="edge")
    window = padded[top + n : top + 2 * n, left + n : left + 2 * n]
    # ndimage.rotate turns content counter-clockwise in (row-down, col-right) display by
    # +angle; content at image angle a (from +u towards +v) must go to angle 0: rotate by +a.
    rotated = ndimage.rotate(
        window, math.degrees(angle), reshape=False, order=1, mode="nearest"
    )
    lo = (n - size) // 2
    return rotated[lo : lo + size, lo : lo + size]


def test_matches_scipy_on_real_images(real_images):
    images, cands = real_images
    assert bool(np.all(cands.valid)), "fixture should give valid candidates"
    out = jax.jit(lambda d, c: crops.extract_batch(d, c))(images, cands)
    assert out.image.shape == (2, 64, _S, _S) and out.image.dtype == jnp.float32
    np.testing.assert_array_equal(out.depth, cands.grasp_depth)
    image = np.asarray(out.image)
    for b in range(2):
        for k in range(0, 64, 7):
            ref = _scipy_affine(images[b], cands.center_px[b, k], cands.angle_px[b, k])
            np.testing.assert_allclose(
                image[b, k], ref - cands.grasp_depth[b, k], rtol=0, atol=_ATOL
            )
    # The crops see the object: depth relative to the grasp spans centimetres.
    assert np.ptp(image[0, 0]) > 0.01


def test_matches_scipy_rotate_at_half_integer_centres(real_images):
    images, cands = real_images
    centres = np.floor(cands.center_px[0, :8]) + 0.5
    angles = cands.angle_px[0, :8]
    gdepth = cands.grasp_depth[0, :8]
    out = jax.jit(crops.extract)(images[0], (centres, angles, gdepth))
    for k in range(8):
        ref = _scipy_rotate(images[0], centres[k], angles[k]) - gdepth[k]
        np.testing.assert_allclose(np.asarray(out.image[k]), ref, rtol=0, atol=_ATOL)


def _edge_image(angle, centre=(47.3, 44.6), size=96):
    """Smooth depth step through `centre` along image angle `angle` (from +u to +v).

    Pixels on the +v side of the line (left normal (-sin, cos)) are 10 cm nearer. The
    tanh profile (6 px) keeps bilinear interpolation error below ~1.5e-4 m.
    """
    v, u = np.mgrid[0:size, 0:size].astype(np.float64)
    dist = -(u - centre[0]) * math.sin(angle) + (v - centre[1]) * math.cos(angle)
    return (0.55 - 0.05 * np.tanh(dist / 6.0)).astype(np.float32), np.array(centre)


@pytest.mark.parametrize("angle", [0.0, 0.4, -1.1, 2.5])
def test_edge_at_known_angle_comes_out_horizontal(angle):
    image, centre = _edge_image(angle)
    extract = jax.jit(crops.extract)
    out = extract(image, (centre[None], jnp.array([angle]), jnp.array([0.55])))
    crop = np.asarray(out.image[0])
    # Constant along rows (the jaw axis), and equal to the edge profile across them.
    y = np.arange(_S) - (_S - 1) / 2
    profile = -0.05 * np.tanh(y / 6.0)
    np.testing.assert_allclose(
        crop, np.broadcast_to(profile[:, None], crop.shape), rtol=0, atol=3e-4
    )
    assert crop[-1].mean() < crop[0].mean() - 0.05  # +v side (bottom rows) is nearer
    # Rotating the edge by angle and cropping at angle gives the unrotated crop.
    flat, _ = _edge_image(0.0)
    ref = extract(flat, (centre[None], jnp.array([0.0]), jnp.array([0.55])))
    np.testing.assert_allclose(crop, np.asarray(ref.image[0]), rtol=0, atol=3e-4)
    # Power: the wrong angle gives a tilted edge that is not constant along rows.
    off = extract(image, (centre[None], jnp.array([angle + 0.3]), jnp.array([0.55])))
    assert np.abs(np.asarray(off.image[0]) - crop).max() > 0.01


def test_edge_mode_outside_the_image():
    image = np.arange(96 * 96, dtype=np.float32).reshape(96, 96) / 1e4 + 0.5
    out = jax.jit(crops.extract)(
        image, (jnp.array([[0.0, 0.0]]), jnp.zeros(1), jnp.zeros(1))
    )
    crop = np.asarray(out.image[0])
    half = (
        _S // 2
    )  # crop pixel half maps to image pixel 0.5: rows/cols < half are off-image
    np.testing.assert_allclose(crop[:half, :half], image[0, 0], atol=1e-6)
    np.testing.assert_allclose(
        crop[:half, half:],
        np.broadcast_to(
            _scipy_affine(image, (0.0, 0.0), 0.0)[0, half:], (half, _S - half)
        ),
        atol=1e-6,
    )
    assert np.all(np.isfinite(crop))


def test_batched_equals_unbatched(real_images):
    images, cands = real_images
    batched = jax.jit(crops.extract_batch)(images, cands)
    for b in range(2):
        one = jax.jit(crops.extract)(
            images[b], jax.tree.map(lambda x, b=b: x[b], cands)
        )
        np.testing.assert_allclose(batched.image[b], one.image, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(batched.depth[b], one.depth)


def test_bad_input_is_a_clear_error(real_images):
    images, cands = real_images
    one = jax.tree.map(lambda x: x[0], cands)
    crops.validate(images[0], one)  # good input passes
    crops.validate(images, cands, batch=True)
    nan = images[0].copy()
    nan[3, 4] = np.nan
    with pytest.raises(ValueError, match=r"non-finite pixel.*\(3, 4\)"):
        crops.validate(nan, one)
    with pytest.raises(ValueError, match="depth image must be"):
        crops.validate(images[0, 0], one)
    with pytest.raises(ValueError, match="depth image must be"):
        crops.extract(images, one)  # [B, H, W] to the unbatched function, at trace time
    with pytest.raises(ValueError, match="does not match CropConfig.image_shape"):
        crops.extract(images[0, :50], one, crops.CropConfig(image_shape=(96, 96)))
    with pytest.raises(ValueError, match="angle_px must have shape"):
        crops.extract(images[0], (one.center_px, one.angle_px[:5], one.grasp_depth))
    with pytest.raises(ValueError, match="grasp_depth has non-finite"):
        crops.validate(
            images[0], (one.center_px, one.angle_px, np.full(64, np.nan, np.float32))
        )
    with pytest.raises(ValueError, match="crop_size"):
        crops.CropConfig(crop_size=0)
