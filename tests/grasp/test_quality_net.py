"""Tests for sern_jax.grasp.model.quality_net: shapes and cost, outputs, losses, fit, batching."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from sern_jax.grasp.model import quality_net as qn

_CONFIG = qn.QualityNetConfig()
_S = _CONFIG.crop_size
_N = 256  # buffer rows of the shared training problem
_STEPS = 40
_BATCH = 64


@functools.partial(jax.jit, static_argnums=1)
def _bars(key, n):
    """Separable synthetic crops: label 1 = a horizontal bar across the jaws, 0 = vertical.

    Both classes have the same pixel statistics (a 6-px bar 3 cm above the grasp plus
    5 mm noise), so only the spatial layout separates them.
    """
    key_lab, key_noise, key_depth = jax.random.split(key, 3)
    labels = jax.random.bernoulli(key_lab, 0.5, (n,)).astype(jnp.float32)
    bar = jnp.zeros((_S, _S)).at[13:19, :].set(-0.03)
    images = jnp.where(labels[:, None, None] > 0, bar, bar.T)
    images = images + 0.005 * jax.random.normal(key_noise, (n, _S, _S))
    depths = jax.random.uniform(key_depth, (n,), minval=0.56, maxval=0.6)
    return qn.TrainData(images, depths, labels, jnp.ones((n,)))


@pytest.fixture(scope="module")
def setup():
    net = qn.make_quality_network(_CONFIG)
    optimizer = optax.adam(1e-2)
    raw_fit = qn.make_fit(net, optimizer, "bce", batch_size=_BATCH, num_steps=_STEPS)
    data = _bars(jax.random.key(1), _N)
    norm = qn.fit_normalizer(data.image, data.depth)
    return net, optimizer, jax.jit(raw_fit), data, norm, raw_fit


def test_param_and_flop_counts():
    net = qn.make_quality_network(_CONFIG)
    params = net.init(jax.random.key(0))
    leaves = jax.tree.leaves(params.net)
    assert sum(x.size for x in leaves) == qn.param_count(_CONFIG)
    # GQ-CNN 2.0 golden numbers from its layer shapes (SAME padding, 1 logit):
    # conv1_1 7*7*1*64+64 = 3,200; conv1_2 5*5*64*64+64 = 102,464; conv2_x 3*3*64*64+64
    # = 36,928 each; fc3 (8*8*64)*1024+1024 = 4,195,328; pc1 16+16 = 32; fc4 (1024+16)*1024
    # +1024 = 1,065,984; out 1024+1 = 1,025.  Sum: 5,441,889.
    assert qn.param_count(qn.GQCNN_2_0) == 5_441_889
    # MACs: 32*32*49*64 = 3,211,264; 32*32*25*64*64 = 104,857,600; 2 x 16*16*9*64*64 =
    # 18,874,368; 4096*1024 = 4,194,304; 16; 1040*1024 = 1,064,960; 1024.
    # Sum 132,203,536 MACs = 264,407,072 FLOPs.
    assert qn.flops_per_grasp(qn.GQCNN_2_0) == 264_407_072
    # Ours: 8*8*16*8 + 8*8*72*8 + 4*4*72*16 + 4*4*144*16 + 256*32 + 8 + 40*32 + 32
    # = 8,192 + 36,864 + 18,432 + 36,864 + 8,192 + 8 + 1,280 + 32 = 109,864 MACs.
    assert qn.flops_per_grasp(_CONFIG) == 2 * 109_864 <= 300_000
    assert net.network.init is net.init and net.network.apply is net.apply
    # LeCun-normal init: kernel std ~ 1/sqrt(fan_in), zero biases.
    kernel = params.net["params"]["fc_image"]["kernel"]  # [256, 32]
    assert abs(float(kernel.std()) * 16 - 1) < 0.1
    assert float(jnp.abs(params.net["params"]["fc_image"]["bias"]).max()) == 0


def test_shapes_and_features(setup):
    net, _, _, data, norm, _ = setup
    params = net.init(jax.random.key(0), norm)
    image = data.image[:12].reshape(3, 4, _S, _S)
    depth = data.depth[:12].reshape(3, 4)
    apply = jax.jit(net.apply)
    prob = apply(params, image, depth)
    feats = jax.jit(net.features)(params, image, depth)
    assert prob.shape == (3, 4) and feats.shape == (3, 4, _CONFIG.feature_dim)
    np.testing.assert_allclose(
        prob,
        jax.nn.sigmoid(jax.jit(net.logits)(params, image, depth)),
        rtol=1e-6,
        atol=1e-7,
    )
    one = apply(params, image[1, 2], depth[1, 2])  # unbatched crop
    assert one.shape == ()
    np.testing.assert_allclose(one, prob[1, 2], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="crops must be"):
        net.apply(params, image[..., :16], depth)
    with pytest.raises(ValueError, match="depth shape"):
        net.apply(params, image, depth[0])


def test_output_in_unit_interval_for_extreme_inputs(setup):
    net, _, _, _, norm, _ = setup
    apply = jax.jit(net.apply)
    big = np.float32(3e38)
    images = jnp.stack(
        [
            jnp.zeros((_S, _S)),
            jnp.full((_S, _S), big),
            jnp.full((_S, _S), -big),
            jnp.full((_S, _S), jnp.inf),
            jnp.full((_S, _S), jnp.nan),
            jnp.full((_S, _S), 1.4),  # a miss: far depth 2 m minus a 0.6 m grasp
        ]
    )
    depths = jnp.array([0.0, big, -big, jnp.inf, jnp.nan, 0.6])
    for seed in range(3):
        for normalizer in (None, norm):
            params = net.init(jax.random.key(seed), normalizer)
            # Scale the weights up so that logits would overflow without the input clip.
            params = params._replace(net=jax.tree.map(lambda w: 30.0 * w, params.net))
            prob = np.asarray(apply(params, images, depths))
            assert np.all(np.isfinite(prob)) and np.all((prob >= 0) & (prob <= 1)), prob


def test_losses():
    logits = jnp.array([-3.0, 0.0, 2.0, 50.0, -50.0])
    labels = jnp.array([0.0, 1.0, 1.0, 0.0, 1.0])
    p = jax.nn.sigmoid(logits)
    # BCE: -y log p - (1 - y) log(1 - p), stable at |logit| = 50 (log-sigmoid forms).
    exact = np.array(
        [np.log1p(np.exp(-3.0)), np.log(2.0), np.log1p(np.exp(-2.0)), 50.0, 50.0]
    )
    np.testing.assert_allclose(qn.bce_loss(logits, labels), exact.mean(), rtol=1e-5)
    weights = jnp.array([1.0, 0.0, 2.0, 0.0, 0.0])
    np.testing.assert_allclose(
        qn.bce_loss(logits, labels, weights), (exact[0] + 2 * exact[2]) / 3, rtol=1e-5
    )
    np.testing.assert_allclose(
        qn.l1_loss(logits, labels, weights),
        (float(p[0]) + 2 * (1 - float(p[2]))) / 3,
        rtol=1e-5,
    )
    assert float(qn.bce_loss(logits, labels, jnp.zeros(5))) == 0.0
    assert np.isfinite(
        float(qn.bce_loss(jnp.array([1e4, -1e4]), jnp.array([0.0, 1.0])))
    )
    # Negative control: fit one constant r̂ to Bernoulli(0.3) rewards. BCE recovers the
    # frequency 0.3; L1 goes to the median, 0 (r̂ < 0.05), not a probability.
    rewards = jnp.array([1.0] * 3 + [0.0] * 7)
    for loss, check in (
        (qn.bce_loss, lambda r: abs(r - 0.3) < 0.01),
        (qn.l1_loss, lambda r: r < 0.05),
    ):
        grad = jax.jit(jax.grad(lambda z, loss=loss: loss(jnp.full(10, z), rewards)))
        z = jnp.float32(0.0)
        for _ in range(500):
            z = z - 1.0 * grad(z)
        assert check(float(jax.nn.sigmoid(z))), (
            loss.__name__,
            float(jax.nn.sigmoid(z)),
        )
    with pytest.raises(ValueError, match="unknown loss"):
        qn.make_fit(qn.make_quality_network(_CONFIG), optax.adam(1e-3), "hinge")


def test_fit_learns_a_separable_problem(setup):
    net, optimizer, fit, data, norm, _ = setup
    params = net.init(jax.random.key(0), norm)
    opt_state = qn.init_opt_state(optimizer, params)
    key = jax.random.key(2)
    losses = []
    for i in range(4):
        params, opt_state, loss = fit(
            jax.random.fold_in(key, i), params, opt_state, data
        )
        losses.append(float(loss))
    test = _bars(jax.random.key(99), 512)
    prob = jax.jit(net.apply)(params, test.image, test.depth)
    accuracy = float(jnp.mean((prob > 0.5) == (test.label > 0)))
    assert accuracy > 0.95, (accuracy, losses)
    assert losses[-1] < losses[0]
    # The normalizer is carried, not trained.
    for a, b in zip(params.normalizer, norm):
        assert float(a) == float(b)
    # No recompile: the second and later calls with the same shapes reuse the program.
    assert fit._cache_size() == 1


def test_failures_on_one_crop_lower_its_score(setup):
    net, optimizer, fit, data, norm, _ = setup
    params = net.init(jax.random.key(3), norm)
    target = 17
    before = float(net.apply(params, data.image[target], data.depth[target]))
    # Only row `target` has weight (label 0); every other row says success but has
    # weight 0, so a masking bug would raise the score instead.
    told = data._replace(
        label=jnp.ones(_N).at[target].set(0.0),
        weight=jnp.zeros(_N).at[target].set(1.0),
    )
    params2, _, loss = fit(
        jax.random.key(4), params, qn.init_opt_state(optimizer, params), told
    )
    after = float(net.apply(params2, data.image[target], data.depth[target]))
    assert after < before - 0.2 and after < 0.2, (before, after)
    assert float(loss) > 0
    # An empty buffer (all weights 0) changes nothing.
    empty = data._replace(weight=jnp.zeros(_N))
    params3, _, loss3 = fit(
        jax.random.key(4), params, qn.init_opt_state(optimizer, params), empty
    )
    jax.tree.map(np.testing.assert_array_equal, params3, params)
    assert float(loss3) == 0.0


def test_vmapped_copies_equal_unbatched(setup):
    net, optimizer, fit, data, norm, raw_fit = setup
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(5), i))(jnp.arange(3))
    key_init = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    key_fit = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    params = jax.vmap(lambda k: net.init(k, norm))(key_init)
    opt_state = jax.vmap(lambda p: qn.init_opt_state(optimizer, p))(params)
    out = jax.jit(jax.vmap(raw_fit, (0, 0, 0, None)))(key_fit, params, opt_state, data)
    apply = jax.jit(net.apply)
    for i in range(3):
        one = fit(
            key_fit[i],
            jax.tree.map(lambda x, i=i: x[i], params),
            jax.tree.map(lambda x, i=i: x[i], opt_state),
            data,
        )
        # Loss and predictions: 1e-5 (float32 batched vs unbatched, STYLE.md's 1e-6
        # loosened for 40 steps). Weights: 1e-4 absolute, because Adam divides by
        # sqrt(v): a last-bit difference in a near-zero gradient of the vmapped
        # (grouped) convolution becomes a visible difference in that weight's step.
        np.testing.assert_allclose(out[2][i], one[2], rtol=1e-5, atol=1e-6)
        p_i = jax.tree.map(lambda x, i=i: x[i], out[0])
        np.testing.assert_allclose(
            apply(p_i, data.image[:64], data.depth[:64]),
            apply(one[0], data.image[:64], data.depth[:64]),
            rtol=0,
            atol=1e-5,
        )
        jax.tree.map(
            lambda a, b, i=i: np.testing.assert_allclose(a[i], b, rtol=0, atol=1e-4),
            out[:2],
            one[:2],
        )
    # Seed diversity: the copies differ.
    w = out[0].net["params"]["out"]["kernel"]
    assert float(jnp.abs(w[0] - w[1]).max()) > 1e-3


def test_train_step_ignores_padding(setup):
    net, optimizer, _, data, norm, _ = setup
    step = jax.jit(qn.make_train_step(net, optimizer))
    params = net.init(jax.random.key(6), norm)
    opt_state = qn.init_opt_state(optimizer, params)
    batch = jax.tree.map(lambda x: x[:32], data)
    padded = qn.TrainData(
        jnp.concatenate([batch.image, jnp.full((8, _S, _S), 7.0)]),
        jnp.concatenate([batch.depth, jnp.full(8, 9.0)]),
        jnp.concatenate([batch.label, jnp.ones(8)]),
        jnp.concatenate([batch.weight, jnp.zeros(8)]),
    )
    a = step(params, opt_state, batch)
    b = step(params, opt_state, padded)
    jax.tree.map(
        lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6), a, b
    )
    with pytest.raises(ValueError, match="TrainData.label"):
        step(params, opt_state, batch._replace(label=batch.label[:5]))


def test_fit_normalizer_and_benchmark_keys():
    norm = qn.fit_normalizer(np.full((4, _S, _S), 0.01), np.array([0.5, 0.6, 0.7, 0.6]))
    assert float(norm.image_mean) == pytest.approx(0.01)
    assert float(norm.image_std) == pytest.approx(1e-3)  # the floor for a constant
    assert float(norm.depth_mean) == pytest.approx(0.6)
    with pytest.raises(ValueError, match="finite"):
        qn.fit_normalizer(np.full((2, _S, _S), np.nan), np.ones(2))
    with pytest.raises(ValueError, match="conv_kernels"):
        qn.QualityNetConfig(conv_kernels=(3,))


@pytest.mark.parametrize("height,kernel,stride,cin", [
    (8, 3, 1, 8), (8, 3, 2, 8), (7, 3, 2, 3), (9, 4, 3, 2), (5, 5, 1, 1), (6, 2, 4, 2)])
def test_im2col_conv_equals_xla_same_conv(height, kernel, stride, cin):
    x = jax.random.normal(jax.random.key(height * 7 + kernel), (3, height, height + 1, cin))
    k = jax.random.normal(jax.random.key(stride), (kernel, kernel, cin, 5))
    want = jax.lax.conv_general_dilated(
        x, k, (stride, stride), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC"))
    got = qn._same_conv_im2col(x, k, stride)
    assert got.shape == want.shape
    # float32 sums in another order: relative to the values (up to ~25 here; jax 0.11's XLA
    # differed by 1.1e-5 = 5e-7 relative near 22), with an absolute floor for values near 0
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-5)
    # Control: a transposed kernel is a different convolution, and the check sees it.
    assert float(jnp.abs(qn._same_conv_im2col(x, k.transpose(1, 0, 2, 3), stride)
                         - want).max()) > 1e-2


def test_conv_impls_give_the_same_network(setup):
    net, _, _, data, norm, _ = setup
    other = qn.make_quality_network(_CONFIG, conv="im2col")
    params = net.init(jax.random.key(3), norm)
    want = net.apply(params, data.image[:64], data.depth[:64])
    got = other.apply(params, data.image[:64], data.depth[:64])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    np.testing.assert_allclose(other.features(params, data.image[:8], data.depth[:8]),
                               net.features(params, data.image[:8], data.depth[:8]),
                               rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="conv must be one of"):
        qn.make_quality_network(_CONFIG, conv="fft")
