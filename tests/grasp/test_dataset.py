"""Tests for sern_jax.grasp.model.dataset: D0 generation is deterministic, resumes to the same
shards, refuses a different config in the same directory, and labels only valid slots."""

import dataclasses
import shutil

import jax
import numpy as np
import pytest

from sern_jax.grasp.model import dataset
from sern_jax.grasp.world import objects

TINY = dict(seed=0, num_objects=2, poses_per_object=2, objects_per_shard=1)


def _arrays(path):
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


def _assert_same_shards(dir_a, dir_b, config):
    for pa, pb in zip(dataset.shard_paths(dir_a, config), dataset.shard_paths(dir_b, config)):
        a, b = _arrays(pa), _arrays(pb)
        assert sorted(a) == sorted(b)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{pa.name}:{k}")


def test_generate_is_deterministic(tiny_dataset, tmp_path):
    config, first = tiny_dataset
    summary = dataset.generate(config, tmp_path, progress=False, log=lambda *_: None)
    _assert_same_shards(first, tmp_path, config)
    assert summary["contexts"] == config.num_objects * config.poses_per_object
    assert summary["candidate_slots"] == config.max_grasps
    assert (tmp_path / "summary.json").exists()


def test_interrupted_run_resumes_to_identical_shards(tiny_dataset, tmp_path):
    config, first = tiny_dataset
    resumed = tmp_path / "d0"
    shutil.copytree(first, resumed)
    (resumed / "shard_00001.npz").unlink()  # the run stopped before the last shard
    (resumed / "summary.json").unlink()
    kept = (resumed / "shard_00000.npz").stat().st_mtime_ns
    with pytest.raises(ValueError, match="incomplete"):
        dataset.load(resumed)
    lines = []
    dataset.generate(config, resumed, progress=False, log=lines.append)
    assert "1 already done" in lines[0]
    assert (resumed / "shard_00000.npz").stat().st_mtime_ns == kept  # not redone
    _assert_same_shards(first, resumed, config)


def test_different_config_in_same_dir_is_refused(tiny_dataset, tmp_path):
    config, first = tiny_dataset
    shutil.copytree(first, tmp_path / "d0")
    other = dataclasses.replace(config, seed=1)
    with pytest.raises(ValueError, match="different dataset"):
        dataset.generate(other, tmp_path / "d0", progress=False, log=lambda *_: None)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(ValueError, match="not a directory"):
        dataset.generate(config, a_file, progress=False, log=lambda *_: None)


def test_labels_and_counts(tiny_dataset):
    config, out = tiny_dataset
    loaded_config, data = dataset.load(out)
    assert loaded_config == config
    n = config.num_objects * config.poses_per_object
    assert data["depth"].shape[0] == n and data["valid"].shape == (n, 64)
    np.testing.assert_array_equal(np.unique(data["object_index"]),
                                  np.arange(config.num_objects))
    valid, label, succ = data["valid"], data["label"], data["successes"]
    np.testing.assert_array_equal(label == -1, ~valid)
    assert set(np.unique(label[valid])) <= {0, 1}
    assert (succ >= 0).all() and (succ <= config.trials_per_grasp).all()
    assert (succ[~valid] == 0).all()
    # one trial per grasp: the label is that trial's outcome
    np.testing.assert_array_equal(label[valid], succ[valid])


def test_label_contexts_masks_invalid_slots_and_counts_trials(monkeypatch):
    """With some slots invalid and 3 trials: label -1 exactly there, the first trial's 0/1
    elsewhere, 0 <= successes <= 3 and successes - label <= 2."""
    real = dataset.context_lib.make_contexts

    def knock_out(*args, **kwargs):
        ctx = real(*args, **kwargs)
        valid = np.asarray(ctx.candidates.valid).copy()
        valid[:, ::3] = False
        valid[1, :] = valid[1, :] & (np.arange(valid.shape[1]) < 5)
        return ctx._replace(candidates=ctx.candidates._replace(valid=valid))

    monkeypatch.setattr(dataset.context_lib, "make_contexts", knock_out)
    lc = dataset.label_contexts(jax.random.key(3), objects.make_object("small_box"), 2,
                                num_trials=3)
    valid = lc.valid
    assert 0 < valid.sum() < valid.size
    np.testing.assert_array_equal(lc.label == -1, ~valid)
    assert set(np.unique(lc.label[valid])) <= {0, 1}
    assert (lc.successes[~valid] == 0).all() and (lc.nan_count[~valid] == 0).all()
    assert (lc.successes >= 0).all() and (lc.successes <= 3).all()
    first = lc.label[valid].astype(int)
    rest = lc.successes[valid] - first
    assert (rest >= 0).all() and (rest <= 2).all()


@pytest.mark.parametrize("field, value", [
    ("num_objects", 0), ("poses_per_object", -1), ("trials_per_grasp", 1.5),
    ("objects_per_shard", 0), ("backend", "gpu"), ("seed", -1), ("seed", 2**31),
])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        dataset.DatasetConfig(**{**TINY, field: value})


def test_load_of_a_non_dataset_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="not a dataset directory"):
        dataset.load(tmp_path)


def _damage(path, how):
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                      "random": np.random.default_rng(0).bytes(len(data))}[how])


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_damaged_shard_is_refused_by_load_and_recomputed_by_generate(tiny_dataset, tmp_path,
                                                                      how):
    """A damaged shard is never counted as done: load names it in one line, a rerun of
    generate sets it aside and recomputes the same arrays."""
    from sern_jax.infra import io

    config, first = tiny_dataset
    d0 = tmp_path / "d0"
    shutil.copytree(first, d0)
    shard = d0 / "shard_00001.npz"
    _damage(shard, how)
    with pytest.raises(io.DamagedFileError) as info:
        dataset.load(d0)
    msg = str(info.value)
    assert "\n" not in msg and str(shard) in msg and "sern grasp dataset" in msg
    lines = []
    dataset.generate(config, d0, progress=False, log=lines.append)
    assert any("shard_00001.npz: damaged" in line and "recomputing" in line for line in lines)
    assert any("1 already done" in line for line in lines)
    assert (d0 / "shard_00001.npz.damaged").exists()
    _assert_same_shards(first, d0, config)
    dataset.load(d0)


def test_shard_with_wrong_rows_is_refused(tiny_dataset, tmp_path):
    """A well-formed shard holding another shard's contexts (e.g. copied over it)."""
    from sern_jax.infra import io

    config, first = tiny_dataset
    d0 = tmp_path / "d0"
    shutil.copytree(first, d0)
    arrays = io.load_npz(d0 / "shard_00000.npz")
    io.save_npz(d0 / "shard_00000.npz", **{k: v[:1] for k, v in arrays.items()})
    with pytest.raises(io.DamagedFileError, match="rows"):
        dataset.load(d0)


def test_dataset_run_directory_is_locked(tiny_dataset, tmp_path):
    from sern_jax.infra import io

    config, first = tiny_dataset
    d0 = tmp_path / "d0"
    shutil.copytree(first, d0)
    holder = hold_lock_in_another_process(d0, "another dataset run")
    try:
        with pytest.raises(io.RunLockedError, match="another dataset run"):
            dataset.generate(config, d0, progress=False, log=lambda *_: None)
    finally:
        holder.kill()
        holder.wait()
    dataset.generate(config, d0, progress=False, log=lambda *_: None)  # killed: free again


def hold_lock_in_another_process(run_dir, command):
    """A real second process holding ``io.run_lock(run_dir)``; kill it with SIGKILL."""
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import io\n"
         "with io.run_lock(sys.argv[1], command=sys.argv[2]):\n"
         "    print('locked', flush=True)\n    time.sleep(120)\n", str(run_dir), command],
        stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc
