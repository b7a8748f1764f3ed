"""sern_jax.grasp.online.learn_units' split and join (the Ray learning run's checkpoints),
on synthetic arrays: no learning run, no Ray (the runs themselves are tests/test_distributed.py's
slow tests)."""

import numpy as np

from sern_jax.infra import io
from sern_jax.grasp.online import checkpoint, learn_units

R, O, Q, S, E = 3, 2, 2, 3, 4  # rounds 0..2, objects, learners, seeds, grasps per phase


def _saved(next_round: int) -> dict:
    """A single-process checkpoint's arrays after round next_round - 1 (later rounds at their
    initial fill), with distinct values in every finished cell."""
    rng = np.random.default_rng(next_round)
    shape = (R + 1, O, Q, S)
    results = checkpoint.RoundResults(
        rng.random(shape), rng.random(shape), rng.random(shape),
        rng.integers(0, 64, shape + (E,)).astype(np.int32), rng.random(shape))
    rewards = rng.integers(0, 2, (R + 1, O, S, Q, E)).astype(np.int8)
    results, rewards = checkpoint.through(results, rewards, next_round)
    return {**results._asdict(), "explore_reward": rewards, "next_round": np.asarray(next_round),
            "fingerprint": np.asarray("f" * 16)}


def _same(a, b):
    return np.array_equal(a, b, equal_nan=np.asarray(a).dtype.kind == "f")


def test_split_then_join_gives_the_run_back(tmp_path):
    saved = _saved(2)
    for o in range(O):
        learn_units._split(saved, o, tmp_path / f"u{o}" / "checkpoint.npz", "f" * 16)
    units = [io.load_npz(tmp_path / f"u{o}" / "checkpoint.npz") for o in range(O)]
    assert [int(u["next_round"]) for u in units] == [2, 2]
    assert units[1]["paper_eval"].shape == (R + 1, 1, Q, S)  # object axis 1, one object each
    results, rewards, next_round = learn_units._join(units)
    assert next_round == 2
    for name in checkpoint.RoundResults._fields:
        assert _same(getattr(results, name), saved[name]), name
    assert _same(rewards, saved["explore_reward"])


def test_join_stops_at_the_round_every_unit_passed(tmp_path):
    """Units at rounds 3 and 2: the joined run is at round 2, the ahead unit's round 2 left out
    (control: that unit's file holds it)."""
    ahead, behind = _saved(3), _saved(2)
    learn_units._split(ahead, 0, tmp_path / "a.npz", "f" * 16)
    learn_units._split(behind, 1, tmp_path / "b.npz", "f" * 16)
    a, b = io.load_npz(tmp_path / "a.npz"), io.load_npz(tmp_path / "b.npz")
    assert (a["explore_action"][2] >= 0).all()  # control: round 2 is in the ahead unit
    results, rewards, next_round = learn_units._join([a, b])
    assert next_round == 2
    assert (results.explore_action[2:] == -1).all() and (rewards[2:] == 0).all()
    assert np.isnan(results.paper_eval[2:]).all()
    assert _same(results.paper_eval[:2, :1], ahead["paper_eval"][:2, :1])
    assert _same(results.paper_eval[:2, 1:], behind["paper_eval"][:2, 1:])
