"""The hard-set screen values the chosen best candidate on fresh trials: an
object whose candidates all succeed 40 % of the time must not qualify, although the
maximum of its 64 eight-trial frequencies averages about 0.8."""

import numpy as np
import pytest

from sern_jax.grasp.world import objects
from sern_jax.grasp.model import pretrain


def _synthetic_rows(num_objects, p=0.4, poses=8, k=64, trials=8, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(num_objects):
        select = rng.binomial(trials, p, (poses, k)) / trials
        valid = np.ones((poses, k), bool)
        pick = np.argmax(select, axis=1)
        true = np.full((poses, k), p)
        fresh = rng.binomial(trials, true[np.arange(poses), pick]) / trials  # new trials
        row = {"greedy_success": float(rng.binomial(poses * trials, p) / (poses * trials))}
        row.update(pretrain.best_candidate_estimates(select, valid, fresh))
        rows.append(row)
    return rows


def test_all_candidates_at_040_never_qualify():
    rows = _synthetic_rows(200)
    biased = np.array([r["best_success"] for r in rows])
    fresh = np.array([r["best_success_fresh"] for r in rows])
    # control: the old rule (max of the same trials) sees ~0.8 and often calls it hard
    assert biased.mean() > 0.77
    old_rule = [r["greedy_success"] <= 0.6 and r["best_success"] >= 0.8 for r in rows]
    assert np.mean(old_rule) > 0.3
    # the rule on fresh trials: unbiased (~0.4) and never hard
    assert abs(fresh.mean() - 0.4) < 5 * fresh.std() / np.sqrt(len(fresh))
    assert not any(pretrain.is_hard(r) for r in rows)


def test_a_truly_good_candidate_still_qualifies():
    # one candidate per pose succeeds 95 % of the time, the rest 40 %: hard by the rule
    rng = np.random.default_rng(1)
    poses, k, trials = 8, 64, 16
    true = np.full((poses, k), 0.4)
    true[:, 7] = 0.95
    select = rng.binomial(trials, true) / trials
    pick = np.argmax(select, axis=1)
    fresh = rng.binomial(trials, true[np.arange(poses), pick]) / trials
    row = {"greedy_success": 0.4}
    row.update(pretrain.best_candidate_estimates(select, np.ones_like(select, bool), fresh))
    assert row["best_success_fresh"] >= 0.8 and pretrain.is_hard(row)


def test_screen_rows_carry_the_fresh_estimate(tiny_theta0):
    spec = objects.make_object("small_box")
    (row,) = pretrain.screen(tiny_theta0.network, tiny_theta0.params, [spec], num_poses=1,
                             num_trials=2, progress=False)
    assert row["fresh_trials"] == 2 and len(row["best_fresh_per_pose"]) == 1
    assert 0.0 <= row["best_success_fresh"] <= 1.0
    assert row["hard"] == pretrain.is_hard(row) and row["hard_rule"] == "fresh"
    assert 0.0 <= row["best_success_lcb"] <= 1.0 and row["lcb_level"] == pretrain.LCB_LEVEL
    with pytest.raises(ValueError, match="fresh_trials"):
        pretrain.screen(tiny_theta0.network, tiny_theta0.params, [spec], 1, 2,
                        progress=False, fresh_trials=0)


# --- The lower-confidence-bound variant of the rule (pretrain.best_candidate_lcb) ---


def _lcb_rows(true, num_objects, trials, seed):
    """Screen rows of synthetic objects whose candidates succeed with probabilities
    ``true`` [P, K]; θ0's greedy success is drawn at the same 0.4 (so only the best
    candidate's half of the rule can decide)."""
    rng = np.random.default_rng(seed)
    poses, k = true.shape
    rows = []
    for _ in range(num_objects):
        successes = rng.binomial(trials, true)
        row = {"greedy_success": float(rng.binomial(poses * trials, 0.4) / (poses * trials))}
        row.update(pretrain.best_candidate_estimates(successes / trials,
                                                     np.ones((poses, k), bool),
                                                     np.full(poses, np.nan)))
        row.update(pretrain.best_candidate_lcb(successes, trials, np.ones((poses, k), bool)))
        rows.append(row)
    return rows


@pytest.mark.parametrize("trials", [8, 64])
def test_lcb_rule_never_qualifies_candidates_at_040(trials):
    rows = _lcb_rows(np.full((8, 64), 0.4), 100, trials, seed=trials)
    lcb = np.array([r["best_success_lcb"] for r in rows])
    # a lower bound on the best's true success 0.4 (simultaneous 95 %): at or below it
    assert np.mean(lcb <= 0.4) >= 0.95 and lcb.max() < 0.5
    assert not any(pretrain.is_hard(r, "lcb") for r in rows)
    # control: the biased maximum of the same trials calls a good share of them hard at 8
    if trials == 8:
        assert np.mean([r["greedy_success"] <= 0.6 and r["best_success"] >= 0.8
                        for r in rows]) > 0.3


def test_lcb_rule_lets_a_truly_good_candidate_qualify_with_enough_trials():
    true = np.full((8, 64), 0.4)
    true[:, 5] = 0.98
    rows = _lcb_rows(true, 20, 128, seed=3)
    assert all(pretrain.is_hard(r, "lcb") for r in rows)
    # ... and not with 8 trials, where a perfect record bounds only ((1 - 0.95) / 512)^(1/8)
    rows8 = _lcb_rows(true, 20, 8, seed=4)
    assert max(r["best_success_lcb"] for r in rows8) <= (0.05 / 512) ** (1 / 8) + 1e-12
    assert not any(pretrain.is_hard(r, "lcb") for r in rows8)


def test_lcb_is_the_bonferroni_clopper_pearson_bound():
    from sern_jax.analysis import stats

    successes = np.array([[8, 5, 0], [3, 7, 1]])
    valid = np.array([[True, True, True], [True, False, True]])
    out = pretrain.best_candidate_lcb(successes, 8, valid, level=0.9)
    lo, _ = stats.clopper_pearson(successes, 8, level=1 - 0.1 / 5, side="lower")
    want = np.mean([lo[0].max(), max(lo[1, 0], lo[1, 2])])
    assert out["best_success_lcb"] == pytest.approx(want, rel=1e-9)
    assert out["lcb_level"] == 0.9
    row = {"greedy_success": 0.3, "best_success": 1.0, "best_success_fresh": 0.9}
    with pytest.raises(ValueError, match="best_success_lcb"):
        pretrain.is_hard(row, "lcb")
    with pytest.raises(ValueError, match="rule"):
        pretrain.is_hard(row, "max")
    with pytest.raises(ValueError, match="trials"):
        pretrain.best_candidate_lcb(np.array([[9]]), 8, np.array([[True]]))
