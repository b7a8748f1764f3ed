"""Problems with exact expected rewards: the wheel bandit against its published definition
(tensorflow/models ``sample_wheel_bandit_data``), region by region; the finite and linear
problems' bookkeeping; bad parameters are one-line ValueErrors naming the flag."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import contextual_problems as cp


def _reference_wheel(x, delta):
    """The published sampler's rule, transcribed: (expected rewards [5], optimal arm)."""
    mean_v = [1.0, 1.0, 1.0, 1.0, 1.2]
    r = list(mean_v)
    if np.linalg.norm(x) >= delta:
        if x[0] > 0:
            arm = 0 if x[1] > 0 else 1
        else:
            arm = 2 if x[1] > 0 else 3
        r[arm] = 50.0
        return r, arm
    return r, int(np.argmax(mean_v))


@pytest.mark.parametrize("delta", cp.WHEEL_DELTAS)
def test_wheel_means_and_optimal_arm_region_by_region(delta):
    # one point well inside each region: the inner disc and the four outer quadrant sectors
    r_out = (delta + 1.0) / 2
    c = r_out / np.sqrt(2)
    points = {"inner": ([0.5 * delta * 0.6, -0.5 * delta * 0.6], [1, 1, 1, 1, 1.2], 4),
              "q0 (x0>0, x1>0)": ([c, c], [50, 1, 1, 1, 1.2], 0),
              "q1 (x0>0, x1<=0)": ([c, -c], [1, 50, 1, 1, 1.2], 1),
              "q2 (x0<=0, x1>0)": ([-c, c], [1, 1, 50, 1, 1.2], 2),
              "q3 (x0<=0, x1<=0)": ([-c, -c], [1, 1, 1, 50, 1.2], 3)}
    for name, (x, means, arm) in points.items():
        x = jnp.asarray(x, jnp.float32)
        np.testing.assert_allclose(cp.wheel_expected_rewards(x, delta), means, err_msg=name)
        assert int(cp.wheel_optimal_arm(x, delta)) == arm, name
    # the boundary ‖x‖ = δ belongs to the outer region (the reference's ``>=``) and x1 = 0 to
    # the lower quadrant (its ``x1 > 0`` test)
    x = np.array([delta, 0.0], np.float64)
    with jax.enable_x64():
        assert int(cp.wheel_optimal_arm(jnp.asarray(x), delta)) == 1


def test_wheel_matches_the_reference_rule_on_random_points():
    problem = cp.wheel(0.7)
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(4000))
    xs = np.asarray(jax.vmap(problem.sample_context)(keys))
    means = np.asarray(jax.vmap(problem.expected_rewards)(xs))
    opt = np.asarray(jax.vmap(lambda x: cp.wheel_optimal_arm(x, 0.7))(xs))
    for x, m, a in zip(xs, means, opt):
        ref_m, ref_a = _reference_wheel(x, 0.7)
        np.testing.assert_allclose(m, ref_m)
        assert a == ref_a == int(np.argmax(m))


def test_wheel_contexts_uniform_in_the_disc_and_exact_arm_means():
    delta = 0.5
    problem = cp.wheel(delta)
    n = 20_000
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(1), i))(jnp.arange(n))
    xs = np.asarray(jax.vmap(problem.sample_context)(keys), np.float64)
    norms = np.linalg.norm(xs, axis=1)
    assert norms.max() <= 1.0 + 1e-6
    # uniform in the disc: P(‖x‖ < ρ) = ρ² (5 SE of a proportion)
    for rho in (0.3, 0.5, 0.9):
        p = rho * rho
        assert abs(np.mean(norms < rho) - p) <= 5 * np.sqrt(p * (1 - p) / n)
    # each quadrant a quarter
    q = np.mean((xs[:, 0] > 0) & (xs[:, 1] > 0))
    assert abs(q - 0.25) <= 5 * np.sqrt(0.25 * 0.75 / n)
    # exact E_x r_a(x) against Monte Carlo (5 SE)
    means = np.asarray(jax.vmap(problem.expected_rewards)(xs), np.float64)
    se = means.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(means.mean(0) - problem.arm_means) <= 5 * se + 1e-6)
    np.testing.assert_allclose(problem.arm_means[:4], 1 + 49 * (1 - delta ** 2) / 4)


def test_wheel_reward_noise_is_gaussian_with_the_published_sd():
    problem = cp.wheel(0.9, noise_sd=0.01)
    x = jnp.asarray([0.0, 0.99])  # outer, quadrant x0 <= 0, x1 > 0 -> arm 2 pays 50
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(2), i))(jnp.arange(5000))
    r = np.asarray(jax.vmap(problem.sample_rewards, (0, None))(keys, x), np.float64)
    np.testing.assert_allclose(r.mean(0), [1, 1, 50, 1, 1.2], atol=5 * 0.01 / np.sqrt(5000) + 1e-5)
    np.testing.assert_allclose(r.std(0), 0.01, rtol=0.05)
    scaled = np.asarray(problem.scale_reward(jnp.asarray(r)))
    assert scaled.min() >= 0 and scaled.max() <= 1


def test_finite_problem_has_the_gap_and_linear_problem_is_linear():
    p = cp.finite(jax.random.key(0), num_contexts=6, num_arms=4, gap=0.2, context_dim=3)
    assert p.gap2 == pytest.approx(0.2, abs=1e-6)
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(4), i))(jnp.arange(64))
    xs = jax.vmap(p.sample_context)(keys)
    means = np.asarray(jax.vmap(p.expected_rewards)(xs))
    assert means.shape == (64, 4) and np.all((means >= 0) & (means <= 1))
    lin = cp.linear(jax.random.key(0), num_arms=3, context_dim=5)
    x = jax.vmap(lin.sample_context)(keys[:8])
    m = np.asarray(jax.vmap(lin.expected_rewards)(x))
    # (1 + x·θ)/2 is affine in x: m(x) + m(-x) = 1
    np.testing.assert_allclose(m + np.asarray(jax.vmap(lin.expected_rewards)(-x)), 1.0,
                               atol=1e-6)


@pytest.mark.parametrize("call, flag", [
    (lambda: cp.wheel(0.0), "--delta"),
    (lambda: cp.wheel(1.0), "--delta"),
    (lambda: cp.wheel(-0.5), "--delta"),
    (lambda: cp.wheel(float("nan")), "--delta"),
    (lambda: cp.make_problem("wheel", delta=1.5), "--delta"),
    (lambda: cp.make_problem("wheel", num_arms=4), "--arms"),
    (lambda: cp.make_problem("finite", num_arms=1), "--arms"),
    (lambda: cp.make_problem("linear", num_arms=1), "--arms"),
    (lambda: cp.make_problem("finite", gap=1.0), "--gap"),
    (lambda: cp.make_problem("finite", num_contexts=0), "--contexts"),
    (lambda: cp.make_problem("nope"), "--problem"),
])
def test_bad_parameters_are_one_line_errors_naming_the_flag(call, flag):
    with pytest.raises(ValueError) as info:
        call()
    assert flag in str(info.value) and "\n" not in str(info.value)
