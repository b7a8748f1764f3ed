"""Grasp-quality network: a slimmed GQ-CNN in Flax linen, its losses and its training.

Layout (after Dex-Net 2.0's GQ-CNN, ``cfg/train_dex-net_2.0.yaml``; reference/
grasp-anchors.md §1.1 and §6): an image stream of two conv stages on the 32x32 depth crop
(``crops.extract``), a pose stream (one dense layer) on the grasp depth, a merged fully
connected layer and the output. GQ-CNN ends in a 2-way softmax; we use one logit and a
sigmoid (the same model: softmax of (0, z) is sigmoid(z)), so r̂ = P(success) ∈ [0, 1] as
Theorem 1 needs.

Slimming (``QualityNetConfig()`` defaults). GQ-CNN has 5.44M parameters (4.2M in its
first fc layer) and 132M multiply-adds per grasp (``param_count`` / ``flops_per_grasp``
of ``GQCNN_2_0``, counted from the layer shapes: 264M FLOPs): ~10^4 times too slow for
scoring 64 candidates within one simulated trial (~1.8 ms on 2 CPU cores). The defaults
keep the layout (stage 1: two convs at 32->8 px, stage 2: two convs at 4 px, fc on the
image, pose layer, merged fc) but replace pooling by strides, drop LRN and shrink widths:
stage 1 = a 4x4/4 "patchify" conv x8 + 3x3 x8, stage 2 = 3x3/2 x16 + 3x3 x16, fc 32,
pose 8, merge 32: 13,793 parameters and 0.22 MFLOP (110k multiply-adds) per grasp,
1/1200 of GQ-CNN. The patchify stem matters more than the FLOPs: XLA's CPU convolution
with one input channel is slow, a reshape + matmul is not (``sern bench grasp`` measures
the network's rates: :func:`sern_jax.bench.grasp.quality_net_benchmark`).

Parameters. ``init(key)`` returns ``QualityParams(net, normalizer)``: ``net`` is the flax
variables dict, ``normalizer`` a ``Normalizer`` of four scalars (GQ-CNN's ``im_mean,
im_std, pose_mean, pose_std``) applied inside the network: ``(image - image_mean) /
image_std``, ``(depth - depth_mean) / depth_std``. The normalizer travels with the weights
(one pytree to save, vmap and ship) but is *not* trained: ``apply`` stops its gradient and
the optimizer state covers ``params.net`` only (``opt_state = optimizer.init(params.net)``,
or ``init_opt_state``). ``fit_normalizer(images, depths)`` computes it from data; ``init``
uses the identity (0, 1, 0, 1) unless given one. Normalised inputs are clipped to
``±input_clip`` (NaN -> 0) so the output is finite and in [0, 1] for *every* input,
including far pixels (the camera's ``far`` depth) and absurd depths.

Training. ``bce_loss`` (the default) and ``l1_loss`` take logits, 0/1 labels and
per-example weights (0 = padding of a fixed-capacity buffer). ``make_fit`` returns a pure
``fit(key, params, opt_state, data)`` that runs ``num_steps`` optimizer steps in one
``lax.scan``, each on a minibatch drawn with replacement with probability proportional to
``data.weight``; it vmaps over parameter copies (one per object × policy × seed in the
online learner). ``make_train_step`` is one step on a given minibatch for host-side
pretraining loops over shards.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from sern_jax.core.types import Network
from sern_jax.learners import base as lbase
from sern_jax.learners.base import LOSSES, bce_loss, l1_loss

__all__ = [
    "CONV_IMPLS",
    "GQCNN_2_0",
    "LOSSES",
    "Normalizer",
    "QualityNetConfig",
    "QualityNetwork",
    "QualityParams",
    "TrainData",
    "bce_loss",
    "fit_normalizer",
    "flops_per_grasp",
    "init_opt_state",
    "l1_loss",
    "learner_model",
    "make_fit",
    "make_quality_network",
    "make_train_step",
    "param_count",
]


@dataclasses.dataclass(frozen=True)
class QualityNetConfig:
    """Static network shape (everything that changes compiled code).

    Attributes:
      crop_size: S, input crops are S x S (GQ-CNN 2.0: 32).
      conv_features: output channels of the four convolutions; the first two form stage 1,
        the last two stage 2 (GQ-CNN: 64, 64, 64, 64).
      conv_kernels: square kernel sizes (GQ-CNN: 7, 5, 3, 3).
      conv_strides: strides (GQ-CNN: 1 everywhere, with pooling instead).
      conv_pools: max-pool window/stride after each conv, 1 = none (GQ-CNN: 1, 2, 1, 2).
      fc_features: width of the image stream's fc layer (GQ-CNN fc3: 1024).
      pose_features: width of the pose stream's layer on the grasp depth (GQ-CNN pc1: 16).
      merge_features: width of the merged layer, the penultimate features d used by the
        DPP core set (GQ-CNN fc4: 1024).
      input_clip: normalised inputs are clipped to [-input_clip, input_clip].
    """

    crop_size: int = 32
    conv_features: tuple[int, ...] = (8, 8, 16, 16)
    conv_kernels: tuple[int, ...] = (4, 3, 3, 3)
    conv_strides: tuple[int, ...] = (4, 1, 2, 1)
    conv_pools: tuple[int, ...] = (1, 1, 1, 1)
    fc_features: int = 32
    pose_features: int = 8
    merge_features: int = 32
    input_clip: float = 10.0

    def __post_init__(self):
        n = len(self.conv_features)
        for name in ("conv_kernels", "conv_strides", "conv_pools"):
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"QualityNetConfig.{name} has {len(getattr(self, name))} entries, "
                    f"conv_features has {n}"
                )
        ints = (
            [("crop_size", self.crop_size)]
            + [("conv_features", v) for v in self.conv_features]
            + [("conv_kernels", v) for v in self.conv_kernels]
            + [("conv_strides", v) for v in self.conv_strides]
            + [("conv_pools", v) for v in self.conv_pools]
            + [
                (n_, getattr(self, n_))
                for n_ in ("fc_features", "pose_features", "merge_features")
            ]
        )
        for name, value in ints:
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(
                    f"QualityNetConfig.{name} must be ints >= 1, got {value!r}"
                )
        if not (math.isfinite(self.input_clip) and self.input_clip > 0):
            raise ValueError(
                f"input_clip must be finite and > 0, got {self.input_clip!r}"
            )

    @property
    def feature_dim(self) -> int:
        """d, the width of ``features`` (the merged layer)."""
        return self.merge_features


# GQ-CNN 2.0's layout in this config's terms (for the parameter and FLOP comparison; LRN
# has no parameters and is not counted; one logit instead of the 2-way softmax).
GQCNN_2_0 = QualityNetConfig(
    conv_features=(64, 64, 64, 64),
    conv_kernels=(7, 5, 3, 3),
    conv_strides=(1, 1, 1, 1),
    conv_pools=(1, 2, 1, 2),
    fc_features=1024,
    pose_features=16,
    merge_features=1024,
)


class Normalizer(NamedTuple):
    """Scalar input standardisation (GQ-CNN's im_mean/im_std/pose_mean/pose_std)."""

    image_mean: jax.Array  # [] mean of crop pixels (depth - grasp depth), metres
    image_std: jax.Array  # [] std of crop pixels, metres
    depth_mean: jax.Array  # [] mean grasp depth, metres
    depth_std: jax.Array  # [] std of grasp depth, metres


def _identity_normalizer() -> Normalizer:
    return Normalizer(*(jnp.asarray(v, jnp.float32) for v in (0.0, 1.0, 0.0, 1.0)))


class QualityParams(NamedTuple):
    """Everything ``apply`` needs: trained weights and the (untrained) normalizer."""

    net: Any  # flax variables {"params": ...}
    normalizer: Normalizer


class TrainData(NamedTuple):
    """A (fixed-capacity) labelled grasp buffer."""

    image: jax.Array  # [N, S, S] crops (crops.Crops.image), metres
    depth: jax.Array  # [N] grasp depths, metres
    label: jax.Array  # [N] rewards in {0, 1} (float)
    weight: jax.Array  # [N] >= 0; sampling weight, 0 = empty slot


def fit_normalizer(images, depths, min_std: float = 1e-3) -> Normalizer:
    """Normalizer from training inputs (host side; float64 accumulation).

    Args:
      images: [N, S, S] crops (depth - grasp depth), metres.
      depths: [N] grasp depths, metres.
      min_std: floor on both stds (a constant input must not divide by zero), metres.

    Returns:
      Normalizer of float32 scalars.
    """
    images = np.asarray(images, np.float64)
    depths = np.asarray(depths, np.float64)
    if images.size == 0 or depths.size == 0:
        raise ValueError("fit_normalizer needs at least one image and one depth")
    if not (np.all(np.isfinite(images)) and np.all(np.isfinite(depths))):
        raise ValueError("fit_normalizer: images and depths must be finite")
    vals = (
        images.mean(),
        max(images.std(), min_std),
        depths.mean(),
        max(depths.std(), min_std),
    )
    return Normalizer(*(jnp.asarray(v, jnp.float32) for v in vals))


def _same_conv_im2col(x: jax.Array, kernel: jax.Array, stride: int) -> jax.Array:
    """XLA's SAME convolution (NHWC input, HWIO kernel) as strided slices + one matmul.

    The same sums as ``lax.conv_general_dilated(..., "SAME")`` (up to float rounding
    order). Written this way because the online learner vmaps the network over parameter
    copies: a vmapped convolution becomes a grouped convolution, which XLA's CPU backend
    runs several times slower than the batched matmul a vmapped im2col becomes.
    """
    n, height, width, c = x.shape
    k, features = kernel.shape[0], kernel.shape[-1]
    out_h, out_w = -(-height // stride), -(-width // stride)
    pad_h = max((out_h - 1) * stride + k - height, 0)
    pad_w = max((out_w - 1) * stride + k - width, 0)
    x = jnp.pad(x, ((0, 0), (pad_h // 2, pad_h - pad_h // 2),
                    (pad_w // 2, pad_w - pad_w // 2), (0, 0)))
    span_h, span_w = (out_h - 1) * stride + 1, (out_w - 1) * stride + 1
    patches = jnp.concatenate(
        [x[:, i:i + span_h:stride, j:j + span_w:stride, :]
         for i in range(k) for j in range(k)], axis=-1)  # [n, out_h, out_w, k*k*c]
    return patches @ kernel.reshape(k * k * c, features)


CONV_IMPLS = ("xla", "im2col")


class _Conv(nn.Module):
    """SAME conv with nn.Conv's parameter layout (kernel HWIO, bias).

    A conv whose kernel equals its stride (and divides the input) is computed as
    space-to-depth + one matmul: the same numbers, several times faster than XLA's CPU
    convolution with one input channel.
    """

    features: int
    kernel_size: int
    stride: int
    impl: str = "xla"

    @nn.compact
    def __call__(self, x):
        k = self.kernel_size
        kernel = self.param(
            "kernel", nn.initializers.lecun_normal(), (k, k, x.shape[-1], self.features)
        )
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        n, height, width, c = x.shape
        if k == self.stride and height % k == 0 and width % k == 0:
            # Non-overlapping patches ("patchify"): space-to-depth and one matmul, the
            # same as the SAME conv (no padding is needed) and much faster on CPU.
            x = x.reshape(n, height // k, k, width // k, k, c).transpose(
                0, 1, 3, 2, 4, 5
            )
            return (
                x.reshape(n, height // k, width // k, k * k * c)
                @ kernel.reshape(k * k * c, self.features)
                + bias[None, None, None]
            )
        if self.impl == "im2col":
            y = _same_conv_im2col(x, kernel, self.stride)
        else:
            y = jax.lax.conv_general_dilated(
                x,
                kernel,
                (self.stride,) * 2,
                "SAME",
                dimension_numbers=("NHWC", "HWIO", "NHWC"),
            )
        return y + bias[None, None, None]


class _GQCNN(nn.Module):
    """The two-stream network on normalised, flat inputs: [n, S, S], [n] -> ([n], [n, d])."""

    config: QualityNetConfig
    conv: str = "xla"

    @nn.compact
    def __call__(self, image, depth):
        c = self.config
        x = image[..., None]  # [n, S, S, 1]
        for i, (f, k, s, p) in enumerate(
            zip(c.conv_features, c.conv_kernels, c.conv_strides, c.conv_pools)
        ):
            x = nn.relu(_Conv(f, k, s, self.conv, name=f"conv{i}")(x))
            if p > 1:
                x = nn.max_pool(x, (p, p), strides=(p, p), padding="SAME")
        x = x.reshape(x.shape[0], -1)
        x = nn.relu(nn.Dense(c.fc_features, name="fc_image")(x))
        z = nn.relu(nn.Dense(c.pose_features, name="fc_pose")(depth[:, None]))
        h = nn.relu(
            nn.Dense(c.merge_features, name="fc_merge")(jnp.concatenate([x, z], -1))
        )
        logit = nn.Dense(1, name="out")(h)[:, 0]
        return logit, h


class QualityNetwork(NamedTuple):
    """The quality network's pure functions (``.network`` is the plain ``Network`` pair).

    All take ``params: QualityParams``, crops ``image [..., S, S]`` and ``depth [...]``
    with any equal leading shape, and are pure (vmap over ``params`` for copies).
    """

    init: Callable[..., QualityParams]  # init(key, normalizer=None) -> QualityParams
    apply: Callable[..., jax.Array]  # apply(params, image, depth) -> P(success) [...]
    logits: Callable[..., jax.Array]  # logits(params, image, depth) -> [...]
    features: Callable[..., jax.Array]  # features(params, image, depth) -> [..., d]
    config: QualityNetConfig

    @property
    def network(self) -> Network:
        return Network(self.init, self.apply)


def make_quality_network(
    config: QualityNetConfig = QualityNetConfig(), conv: str = "xla"
) -> QualityNetwork:
    """Builds the quality network's ``init``/``apply`` (plus ``logits``, ``features``).

    ``init(key, normalizer=None) -> QualityParams`` consumes ``key``; ``normalizer``
    defaults to the identity. ``apply(params, image [..., S, S], depth [...])`` returns
    r̂ = sigmoid(logit) ∈ [0, 1], shape [...]; ``logits`` the logit; ``features`` the
    penultimate (merged) layer [..., d], d = ``config.merge_features``, for the DPP.

    Args:
      config: static network shape.
      conv: how the overlapping convolutions are computed, the same function either
        way (equal up to float rounding order, same parameters): ``"xla"``
        (``lax.conv_general_dilated``: fastest for one set of parameters, the default)
        or ``"im2col"`` (strided slices + matmul: ~5x faster when vmapped over parameter
        copies, where XLA's CPU backend turns the convolution into a slow grouped one;
        the online learner uses it).

    Returns:
      QualityNetwork(init, apply, logits, features, config).
    """
    if conv not in CONV_IMPLS:
        raise ValueError(f"conv must be one of {CONV_IMPLS}, got {conv!r}")
    module = _GQCNN(config, conv)
    s = config.crop_size

    shapes = jax.eval_shape(
        module.init,
        jax.random.key(0),
        jnp.zeros((1, s, s), jnp.float32),
        jnp.zeros((1,)),
    )
    leaves, treedef = jax.tree.flatten(shapes)
    sizes = [math.prod(x.shape) for x in leaves]

    def init_net(key):
        # LeCun-normal kernels (std 1/sqrt(fan_in), untruncated), zero biases, drawn as
        # one normal vector: flax's per-layer truncated-normal draws compile to ~8x more
        # XLA code (seconds per init on a loaded 2-core machine).
        flat = jax.random.normal(key, (sum(sizes),), jnp.float32)
        out, start = [], 0
        for leaf, size in zip(leaves, sizes):
            if leaf.ndim == 1:  # bias
                out.append(jnp.zeros(leaf.shape, leaf.dtype))
            else:
                fan_in = math.prod(leaf.shape[:-1])
                w = flat[start : start + size].reshape(leaf.shape)
                out.append((w / math.sqrt(fan_in)).astype(leaf.dtype))
            start += size
        return jax.tree.unflatten(treedef, out)

    init_net = jax.jit(init_net)

    def init(key: jax.Array, normalizer: Normalizer | None = None) -> QualityParams:
        net = init_net(key)
        if normalizer is None:
            normalizer = _identity_normalizer()
        normalizer = Normalizer(*(jnp.asarray(v, jnp.float32) for v in normalizer))
        return QualityParams(net=net, normalizer=normalizer)

    def _forward(params: QualityParams, image, depth):
        image = jnp.asarray(image, jnp.float32)
        depth = jnp.asarray(depth, jnp.float32)
        if image.shape[-2:] != (s, s):
            raise ValueError(f"crops must be [..., {s}, {s}], got shape {image.shape}")
        lead = image.shape[:-2]
        if depth.shape != lead:
            raise ValueError(
                f"depth shape {depth.shape} must equal the crops' leading shape {lead}"
            )
        norm = jax.tree.map(jax.lax.stop_gradient, params.normalizer)
        clip = config.input_clip

        def standardise(x, mean, std):
            x = (x - mean) / std
            return jnp.clip(
                jnp.nan_to_num(x, nan=0.0, posinf=clip, neginf=-clip), -clip, clip
            )

        image = standardise(image, norm.image_mean, norm.image_std).reshape(-1, s, s)
        depth = standardise(depth, norm.depth_mean, norm.depth_std).reshape(-1)
        logit, h = module.apply(params.net, image, depth)
        return logit.reshape(lead), h.reshape(lead + (h.shape[-1],))

    def logits(params, image, depth):
        return _forward(params, image, depth)[0]

    def apply(params, image, depth):
        return jax.nn.sigmoid(logits(params, image, depth))

    def features(params, image, depth):
        return _forward(params, image, depth)[1]

    return QualityNetwork(init, apply, logits, features, config)


# ----------------------------------------------------------------------------- cost


def _layer_shapes(config: QualityNetConfig):
    """[(kind, macs, params)] per layer, from the shapes (SAME padding, pools ceil)."""
    rows = []
    size, cin = config.crop_size, 1
    for f, k, st, p in zip(
        config.conv_features,
        config.conv_kernels,
        config.conv_strides,
        config.conv_pools,
    ):
        size = -(-size // st)
        rows.append(("conv", size * size * k * k * cin * f, k * k * cin * f + f))
        size = -(-size // p)
        cin = f
    flat = size * size * cin
    m = config.merge_features
    rows.append(
        (
            "fc_image",
            flat * config.fc_features,
            flat * config.fc_features + config.fc_features,
        )
    )
    rows.append(("fc_pose", config.pose_features, 2 * config.pose_features))
    merge_in = config.fc_features + config.pose_features
    rows.append(("fc_merge", merge_in * m, merge_in * m + m))
    rows.append(("out", m, m + 1))
    return rows


def param_count(config: QualityNetConfig) -> int:
    """Number of trained parameters (weights + biases; the 4 normalizer scalars excluded)."""
    return int(sum(r[2] for r in _layer_shapes(config)))


def flops_per_grasp(config: QualityNetConfig) -> int:
    """Floating-point operations of one forward pass per grasp, = 2 x multiply-adds.

    Counted analytically from the layer shapes: convolutions (output pixels x k² x C_in x
    C_out, SAME padding counted as full windows) and dense layers; biases, ReLUs, pools and
    the normalisation are not counted (< 2 % here). GQCNN_2_0: ~264M FLOPs (132M MACs).
    """
    return int(2 * sum(r[1] for r in _layer_shapes(config)))


# ----------------------------------------------------------------------------- losses
#
# The losses are the learners' (:mod:`sern_jax.learners.base`): ``bce_loss`` (the default, a
# proper scoring rule) and ``l1_loss`` (Algorithm 1's printed loss, a negative control).

# ----------------------------------------------------------------------------- training


def init_opt_state(optimizer: optax.GradientTransformation, params: QualityParams):
    """Optimizer state for the trained weights only (``params.net``, not the normalizer)."""
    return optimizer.init(params.net)


def _check_data(data: TrainData, s: int) -> None:
    n = data.image.shape[0] if data.image.ndim else None
    if data.image.ndim != 3 or data.image.shape[1:] != (s, s):
        raise ValueError(
            f"TrainData.image must be [N, {s}, {s}], got {data.image.shape}"
        )
    for name in ("depth", "label", "weight"):
        shape = getattr(data, name).shape
        if shape != (n,):
            raise ValueError(f"TrainData.{name} must be [{n}], got {shape}")


def _net(params: QualityParams):
    return params.net


def _with_net(params: QualityParams, net) -> QualityParams:
    return QualityParams(net, params.normalizer)


def learner_model(network: QualityNetwork) -> lbase.Model:
    """The quality network as a learner's :class:`~sern_jax.learners.base.Model`: inputs
    (crop image [..., S, S], grasp depth [...]); only ``params.net`` is trained (the input
    normaliser is not)."""
    return lbase.Model(network.init, network.apply, network.logits, network.features,
                       trainable=_net, merge=_with_net)


def make_train_step(
    network: QualityNetwork,
    optimizer: optax.GradientTransformation,
    loss: str | Callable = "bce",
):
    """One optimizer step on a given minibatch (for host-side pretraining loops).

    Args:
      network: from ``make_quality_network``.
      optimizer: an optax transformation over ``params.net``.
      loss: "bce" (default), "l1", or a callable (logits, labels, weights) -> [].

    Returns:
      ``train_step(params, opt_state, batch: TrainData) -> (params, opt_state, loss)``,
      pure (jit it); the loss is the batch's weighted mean before the update, and rows
      with weight 0 (padding of a last, short shard) contribute nothing. The learners' step
      (:func:`sern_jax.learners.base.make_train_step`) on :func:`learner_model`.
    """
    step = lbase.make_train_step(learner_model(network), optimizer, loss)
    s = network.config.crop_size

    def train_step(params: QualityParams, opt_state, batch: TrainData):
        _check_data(batch, s)
        return step(params, opt_state, (batch.image, batch.depth), batch.label, batch.weight)

    return train_step


def make_fit(
    network: QualityNetwork,
    optimizer: optax.GradientTransformation,
    loss: str | Callable = "bce",
    batch_size: int = 64,
    num_steps: int = 16,
):
    """``num_steps`` minibatch steps in one ``lax.scan``: pure, jit- and vmap-able.

    The learners' weighted-minibatch fit (:func:`sern_jax.learners.base.make_fit`) on
    :func:`learner_model`, over a :class:`TrainData` buffer.

    Args:
      network: from ``make_quality_network``.
      optimizer: an optax transformation over ``params.net``.
      loss: "bce" (default), "l1", or a callable (logits, labels, weights) -> [].
      batch_size: rows per minibatch (static).
      num_steps: optimizer steps per call (static).

    Returns:
      ``fit(key, params, opt_state, data: TrainData) -> (params, opt_state, mean_loss)``.
      ``key`` is consumed. Each step draws ``batch_size`` rows with replacement with
      probability ``weight / sum(weight)`` (inverse CDF, so zero-weight rows are never
      drawn) and takes one step on their unweighted mean loss: in expectation the
      weighted-mean loss of the buffer. ``mean_loss`` is the mean over steps of the
      minibatch loss before each update. With all weights 0 nothing changes and
      ``mean_loss`` is 0. vmap ``fit`` over (key, params, opt_state[, data]) to train
      independent copies.
    """
    fit = lbase.make_fit(learner_model(network), optimizer, loss, batch_size, num_steps)
    s = network.config.crop_size

    def fit_buffer(key: jax.Array, params: QualityParams, opt_state, data: TrainData):
        _check_data(data, s)
        rows = lbase.Data((data.image, data.depth), data.label, data.weight)
        return fit(key, params, opt_state, rows)

    return fit_buffer
