"""Tests for sern_jax.grasp.world.sim: outcomes, NaN handling, batching, input checks, parity."""

import copy

import jax
import numpy as np
import pytest

from sern_jax.grasp.world import sim

MJX_BATCH = 8  # must match tests/grasp/conftest.py


def test_centred_grasp_succeeds_and_far_grasp_never(native_sim, centred_grasp):
    m = 48
    est = native_sim.success_probability(
        jax.random.key(0), np.stack([centred_grasp, centred_grasp + [0.1, 0, 0, 0]]), m)
    assert est.backend == "native" and est.num_trials == m
    assert est.prob[0] >= 0.8, est
    assert est.successes[1] == 0, est
    assert est.nan_count.sum() == 0


def test_native_batched_equals_unbatched(native_sim, paired_trials):
    grasps, noise = paired_trials
    batch = native_sim.run_trials(grasps, noise)
    for i in (0, 3, 5):
        one = native_sim.run_trials(grasps[i : i + 1],
                                    sim.TrialNoise(*(a[i : i + 1] for a in noise)))
        assert one.success[0] == batch.success[i]
        np.testing.assert_allclose(one.rise[0], batch.rise[i], atol=1e-9)


def test_success_probability_uses_common_noise_and_mask(native_sim, centred_grasp):
    grasps = np.stack([centred_grasp, centred_grasp])
    est = native_sim.success_probability(jax.random.key(1), grasps, 8,
                                         valid=np.array([True, False]))
    assert est.prob[1] == 0 and not est.valid[1]
    again = native_sim.success_probability(jax.random.key(1), grasps[:1], 8)
    assert again.successes[0] == est.successes[0]  # same key, same trials


def _unstable(model):
    """A copy whose palm z actuator gain makes explicit Euler diverge."""
    bad = copy.copy(model)
    bad.actuator_gainprm[2, 0] = 1e9
    bad.actuator_biasprm[2, 1] = -1e9
    return bad


def test_nan_trials_are_flagged_never_success(box_model, centred_grasp):
    simulator = sim.GraspSimulator(_unstable(box_model), "native", num_threads=1)
    est = simulator.success_probability(jax.random.key(0), centred_grasp[None], 4)
    assert est.nan_count[0] == 4 and est.successes[0] == 0 and est.prob[0] == 0
    res = simulator.run_trials(centred_grasp[None], sim.zero_noise(1))
    assert res.nan[0] and not res.success[0] and np.isnan(res.rise[0])


@pytest.mark.parametrize("bad, match", [
    (np.zeros((2, 3)), "shape"),
    (np.array([[0.0, 0.0, np.nan, 0.0]]), "non-finite"),
    (np.array([[2.0, 0.0, 0.05, 0.0]]), "x/y"),
    (np.array([[0.0, 0.0, 3.0, 0.0]]), "z"),
    (np.zeros((0, 4)), "empty"),
])
def test_bad_grasp_arrays_raise(native_sim, bad, match):
    with pytest.raises(ValueError, match=match):
        native_sim.run_trials(bad, sim.zero_noise(max(len(bad), 1)))


def test_bad_settings_raise(box_model, native_sim, centred_grasp):
    with pytest.raises(ValueError, match="backend"):
        sim.GraspSimulator(box_model, "gazebo")
    with pytest.raises(ValueError, match="noise shapes"):
        native_sim.run_trials(centred_grasp[None], sim.zero_noise(2))
    with pytest.raises(ValueError, match="num_trials"):
        native_sim.success_probability(jax.random.key(0), centred_grasp[None], 0)
    with pytest.raises(ValueError, match="success_lift"):
        sim.TrialConfig(lift_height=0.05)


def test_mjx_matches_native_on_paired_trials(mjx_sim, native_sim, paired_trials):
    grasps, noise = paired_trials
    native = native_sim.run_trials(grasps, noise)
    mjx = mjx_sim.run_trials(grasps, noise)
    stats = sim.agreement(native, mjx)
    assert mjx.backend == "mjx" and native.backend == "native"
    assert stats["agreement"] >= (MJX_BATCH - 1) / MJX_BATCH, stats
    assert mjx.success[0] and native.success[0]  # the centred grasp
    assert not mjx.success[5] and not native.success[5]  # 10 cm away
    assert not mjx.nan.any()


def test_mjx_result_does_not_depend_on_batch_neighbours(mjx_sim, paired_trials):
    grasps, noise = paired_trials
    base = mjx_sim.run_trials(grasps, noise)
    perm = np.roll(np.arange(MJX_BATCH), 3)
    rolled = mjx_sim.run_trials(grasps[perm], sim.TrialNoise(*(a[perm] for a in noise)))
    np.testing.assert_array_equal(rolled.success, base.success[perm])
    np.testing.assert_allclose(rolled.rise, base.rise[perm], atol=1e-6)


def test_mjx_flags_nan(box_model, mjx_sim, paired_trials):
    grasps, noise = paired_trials
    unstable = sim.GraspSimulator(_unstable(box_model), "mjx",  # same program, new model
                                  mjx_shape=None)
    res = unstable.run_trials(grasps, noise)
    assert res.nan.all() and not res.success.any()


@pytest.mark.slow
def test_backends_agree_over_objects():
    """Paired native/MJX outcomes agree on >= 90% of trials (one MJX compile/object)."""
    from sern_jax.bench import grasp as bench

    result = bench.measure_agreement(["small_box", "sphere", "capsule", "l_shape"], 32)
    assert result["agreement"] >= 0.9, result
    for stats in result["objects"].values():
        assert stats["nan_native"] == 0 and stats["nan_mjx"] == 0, stats


def test_mjx_fixed_batch_runs_chunks_of_one_program(box_model, mjx_sim, paired_trials):
    """mjx_batch: 13 trials run as two chunks of MJX_BATCH (the last padded), the same
    compiled program as ``mjx_sim``, with the results of running them alone."""
    grasps, noise = paired_trials
    MJX_BATCH = len(grasps)  # noqa: N806 (conftest's batch: the fixture's program)
    base = mjx_sim.run_trials(grasps, noise)
    fixed = sim.GraspSimulator(box_model, "mjx", mjx_batch=MJX_BATCH, mjx_shape=None)
    idx = np.concatenate([np.arange(MJX_BATCH), np.arange(5)])
    res = fixed.run_trials(grasps[idx], sim.TrialNoise(*(a[idx] for a in noise)))
    assert res.success.shape == (MJX_BATCH + 5,)
    np.testing.assert_array_equal(res.success, base.success[idx])
    np.testing.assert_allclose(res.rise, base.rise[idx], atol=1e-6)
    with pytest.raises(ValueError, match="mjx_batch"):
        sim.GraspSimulator(box_model, "mjx", mjx_batch=0)


def test_mjx_pads_odd_batches_without_changing_results(mjx_sim, paired_trials):
    grasps, noise = paired_trials
    base = mjx_sim.run_trials(grasps, noise)
    five = mjx_sim.run_trials(grasps[:5], sim.TrialNoise(*(a[:5] for a in noise)))
    assert five.success.shape == (5,)  # padded to 8: the same compiled program
    np.testing.assert_array_equal(five.success, base.success[:5])
    np.testing.assert_allclose(five.rise, base.rise[:5], atol=1e-6)


def test_success_rule_at_its_edges_on_numpy_and_jax_arrays():
    """``sim.succeeded``: a rise of exactly ``success_lift`` counts, a gap of exactly
    ``CLOSED_GAP`` (jaws shut on nothing) does not, a diverged trial never does; NumPy and
    JAX arrays give the same answers (the native and MJX paths both call it)."""
    config = sim.TrialConfig()
    lift, closed = config.success_lift, sim.CLOSED_GAP
    finite = np.array([True, True, True, True, False, True])
    rise = np.array([lift, lift - 1e-6, lift, 0.2, 0.2, np.nan])
    gap = np.array([0.03, 0.03, closed, closed + 1e-6, 0.03, 0.03])
    expected = np.array([True, False, False, True, False, False])
    np.testing.assert_array_equal(sim.succeeded(finite, rise, gap, config), expected)
    as_jax = sim.succeeded(*(jax.numpy.asarray(a) for a in (finite, rise, gap)), config)
    np.testing.assert_array_equal(np.asarray(as_jax), expected)
