"""The hard-set screen values the chosen best candidate on fresh trials (issue 17): an
object whose candidates all succeed 40 % of the time must not qualify, although the
maximum of its 64 eight-trial frequencies averages about 0.8."""

import numpy as np
import pytest

from sern_jax.grasp import objects, pretrain


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
    assert row["hard"] == pretrain.is_hard(row)
    with pytest.raises(ValueError, match="fresh_trials"):
        pretrain.screen(tiny_theta0.network, tiny_theta0.params, [spec], 1, 2,
                        progress=False, fresh_trials=0)
