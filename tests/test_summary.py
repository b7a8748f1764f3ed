"""On-device summaries over seeds: ``run_seeds(..., summary=True)`` equals the NumPy
reduction of the per-seed arrays, chunks merge exactly, and a seed's contribution does not
depend on how many seeds ran beside it or how they were chunked."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import problems
from sern_jax.engine import drive as executor
from sern_jax.engine import simulate as sim
from sern_jax.engine import summary as summary_lib

CFG = sim.RunConfig(num_arms=6, horizon=300, num_checkpoints=8, random_means=True)
PARAMS = sim.default_params(CFG, problems.bernoulli([0.5] * 6), alpha0=0.1)
NUM = 150


@pytest.fixture(scope="module")
def per_seed():
    return executor.run_seeds(CFG, PARAMS, seed=5, num_seeds=NUM, chunk_size=64)


@pytest.fixture(scope="module")
def summary():
    return executor.run_seeds(CFG, PARAMS, seed=5, num_seeds=NUM, chunk_size=64, summary=True)


def test_summary_equals_numpy_reduction_of_per_seed_arrays(per_seed, summary):
    assert summary.num_seeds == NUM
    for field in summary_lib.SUMMARY_FIELDS:
        x = getattr(per_seed, field)
        s = getattr(summary, field)
        x64 = x.astype(np.float64)
        scale = 1.0 + np.abs(x64).max()
        np.testing.assert_allclose(s.mean, x64.mean(0), rtol=1e-6, atol=1e-6 * scale,
                                   err_msg=field)
        np.testing.assert_allclose(s.var, x64.var(0, ddof=1), rtol=1e-5,
                                   atol=1e-6 * scale**2, err_msg=field)
        np.testing.assert_array_equal(s.min, x64.min(0), err_msg=field)
        np.testing.assert_array_equal(s.max, x64.max(0), err_msg=field)
        if s.hist is None:
            continue
        assert s.hist.sum(-1).min() == s.hist.sum(-1).max() == NUM
        widths = np.diff(s.edges, axis=-1).max(-1)  # [G] widest bin per checkpoint
        widths = widths.reshape(widths.shape + (1,) * (x.ndim - 2))
        for q in summary_lib.SUMMARY_QUANTILES:
            exact = np.quantile(x, q, axis=0, method="inverted_cdf")
            got = getattr(summary, field).quantile(q)
            assert np.all(got.lo <= exact) and np.all(exact <= got.hi), (field, q)
            assert np.all(got.lo <= got.estimate) and np.all(got.estimate <= got.hi)
            assert np.all(got.hi - got.lo <= widths + 1e-9), (field, q)
    with pytest.raises(ValueError, match="no histogram"):
        summary.compensator.quantile(0.5)


def test_quantile_bracket_control_fails_on_shifted_values(per_seed, summary):
    # negative control: the bracket is tight enough to exclude a visibly wrong quantile
    x = per_seed.regret_rb[:, -1]
    got = summary.regret_rb.quantile(0.5)
    wrong = np.quantile(x, 0.75, method="inverted_cdf")
    assert not got.lo[-1] <= wrong <= got.hi[-1]


def test_chunk_merge_equals_one_chunk(summary):
    one = executor.run_seeds(CFG, PARAMS, seed=5, num_seeds=NUM, chunk_size=NUM, summary=True)
    for field in summary_lib.SUMMARY_FIELDS:
        a, b = getattr(one, field), getattr(summary, field)
        scale = 1.0 + np.abs(a.max).max()
        np.testing.assert_allclose(a.mean, b.mean, rtol=1e-6, atol=1e-6 * scale)
        np.testing.assert_allclose(a.m2, b.m2, rtol=1e-5, atol=1e-6 * scale**2)
        np.testing.assert_array_equal(a.min, b.min)
        np.testing.assert_array_equal(a.max, b.max)
        if a.hist is not None:
            np.testing.assert_array_equal(a.hist, b.hist)


def test_seed_count_independence(summary):
    # seeds [0, 40) and [40, 150) run as separate invocations (first_seed) and merged equal
    # the 150-seed run: padding seeds never count, and seed i is the same among any number
    head = executor.run_seeds(CFG, PARAMS, seed=5, num_seeds=40, chunk_size=64, summary=True)
    tail = executor.run_seeds(CFG, PARAMS, seed=5, num_seeds=NUM - 40, first_seed=40,
                              chunk_size=64, summary=True)
    merged = summary_lib.merge_summaries([head, tail])
    assert head.num_seeds == 40 and merged.num_seeds == NUM
    np.testing.assert_array_equal(merged.counts.hist, summary.counts.hist)
    np.testing.assert_array_equal(merged.regret_rb.min, summary.regret_rb.min)
    np.testing.assert_allclose(merged.regret_rb.mean, summary.regret_rb.mean, rtol=1e-6)
    np.testing.assert_allclose(merged.counts.m2, summary.counts.m2, rtol=1e-5, atol=1e-6)
    # and a different subset differs (the comparison can fail)
    assert not np.allclose(head.regret_rb.mean, summary.regret_rb.mean, rtol=1e-3)


def test_summary_arrays_round_trip(summary):
    back = summary_lib.summary_from_arrays(summary_lib.summary_arrays(summary, "p__"), "p__")
    for a, b in zip(back, summary):
        assert a.count == b.count
        np.testing.assert_array_equal(a.mean, b.mean)
        assert (a.hist is None) == (b.hist is None)


def test_compensated_sum_keeps_what_a_float32_sum_loses():
    x = np.concatenate([[2.0**24], np.ones(4096)]).astype(np.float32)
    exact = 2.0**24 + 4096  # representable in float32 (even)
    naive = np.float32(0)
    for v in x:  # sequential float32: every +1 rounds back to 2^24
        naive = np.float32(naive + v)
    assert float(naive) == 2.0**24  # the control fails
    assert float(jax.jit(summary_lib.compensated_sum)(jnp.asarray(x))) == exact
    y = jnp.full((2**20 + 3,), 1e-3, jnp.float32)
    got = float(jax.jit(summary_lib.compensated_sum)(y))
    assert abs(got - (2**20 + 3) * float(np.float32(1e-3))) <= 1e-6 * got
